"""Patch or fail: a benchmark that changes what the code under test does (a probe schedule, a
clock) patches it through here.  A patch whose target is gone, or is no longer used by the code
under test, would measure the unpatched code and say nothing: here it stops the bench with one
line saying which patch and why."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


class PatchMissed(SystemExit):
    """What a bench patched is not there, or was never used: its figures would be wrong."""


def _where(owner: object) -> str:
    return str(getattr(owner, "__name__", type(owner).__name__))


@contextmanager
def patched(owner: object, name: str, value: Any, *, must_be_called: bool = True) -> Iterator[None]:
    """``owner.name = value`` for the ``with`` block, put back after.  PatchMissed when
    ``owner`` has no ``name`` (renamed, moved: the patch would land nowhere) and, for a callable
    ``value`` with ``must_be_called``, when nothing called it inside the block (the code under
    test took its value from somewhere else)."""
    if not hasattr(owner, name):
        raise PatchMissed(
            f"bench: {_where(owner)}.{name} is gone: patching it would change nothing "
            "(update the bench to where it lives now)"
        )
    old = getattr(owner, name)
    calls = [0]
    if must_be_called and callable(value):
        inner: Callable[..., Any] = value

        def counted(*args: Any, **kwargs: Any) -> Any:
            calls[0] += 1
            return inner(*args, **kwargs)

        setattr(owner, name, counted)
    else:
        setattr(owner, name, value)
    try:
        yield
    finally:
        setattr(owner, name, old)
    if must_be_called and callable(value) and calls[0] == 0:
        raise PatchMissed(
            f"bench: {_where(owner)}.{name} was patched and never called: the code under test "
            "no longer takes it from there, so the figures are the unpatched code's"
        )


def replace(owner: object, name: str, value: Any) -> None:
    """``owner.name = value`` for an attribute that must already exist (a bench that sets
    state on an object it built): PatchMissed when it does not."""
    if not hasattr(owner, name):
        raise PatchMissed(f"bench: {_where(owner)} has no {name}: setting it would change nothing")
    setattr(owner, name, value)
