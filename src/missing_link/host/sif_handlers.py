"""A link's SIF handlers: who hears which SIFs (by command, or every SIF), called inline on the
thread that reads the board, in the order they were added.  A handler's exception is a bug
(a board's data is checked before it gets there): counted by kind, it never ends the reading.
A SIF nobody listens for is counted (``unheard``: a board streams from its boot, the host
handshakes first)."""

from __future__ import annotations

from collections.abc import Callable

from ..j2a import SifReceived

#: handler(sif, host time it was received, s on the link's clock)
SifHandler = Callable[[SifReceived, float], None]
#: (kind, exception, what it was doing): where a caught exception is counted
Caught = Callable[[str, BaseException, str], None]


def named(fn: object) -> str:
    """A callable as a log line names it: ``SamplePath.on_sif``."""
    return str(getattr(fn, "__qualname__", None) or repr(fn))


class SifHandlers:
    def __init__(self, caught: Caught) -> None:
        self._caught = caught
        self.by_cmd: dict[int, list[SifHandler]] = {}
        self.every: list[SifHandler] = []
        self.unheard = 0  #: SIFs no handler took (LinkStats.unheard_sifs; the reading thread's)

    def add(self, cmd: int | None, handler: SifHandler) -> None:
        """``handler`` for SIFs with ``cmd`` (None: every SIF); the caller holds the link's lock."""
        if cmd is None:
            self.every.append(handler)
        else:
            self.by_cmd.setdefault(cmd, []).append(handler)

    def failed(self, handler: SifHandler, e: BaseException) -> None:
        """``handler`` raised: counted by kind, said once (the link delivers SIFs inline, on
        the sample path: host/link.py's ``_dispatch``)."""
        self._caught("SIF handler", e, f"SIF handler {named(handler)}")
