"""Board links by URL: a table of schemes, each naming the module and the function that opens
it, imported on first use (as python-can names its back ends), so opening a ``tcp://`` board
never loads pyserial or pyusb.  Third-party transports register through the
``missing_link.transports`` entry-point group or :func:`register_transport`; ``spy+`` in front of
any URL wraps it in :class:`~missing_link.transport.spy.SpyTransport`, ``signed+`` (with
``?key=FILE``) in :class:`~missing_link.transport.signed.SignedTransport`."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from urllib.parse import parse_qs, parse_qsl, urlsplit, urlunsplit

from ..errors import BadURL
from .base import Transport

Factory = Callable[[str, dict[str, str]], Transport]

#: scheme -> (module, function(url, query) -> Transport)
BUILTIN: dict[str, tuple[str, str]] = {
    "tcp": ("missing_link.transport.sockets", "open_tcp"),
    "unix": ("missing_link.transport.sockets", "open_unix"),
    "serial": ("missing_link.transport.serialport", "open_serial"),
    "usb": ("missing_link.transport.usb", "open_usb"),
    "memory": ("missing_link.transport.in_process", "open_memory"),
}
_SPY = ("missing_link.transport.spy", "SpyTransport")
_SIGNED = ("missing_link.transport.signed", "SignedTransport")
_REGISTERED: dict[str, Factory] = {}  # register_transport() and loaded entry points


def register_transport(scheme: str, factory: Factory) -> None:
    """Make ``scheme://`` URLs open with ``factory(url, query)``."""
    _REGISTERED[scheme] = factory


def query_dict(url: str) -> dict[str, str]:
    q = parse_qs(urlsplit(url).query, keep_blank_values=True)
    return {k: v[-1] for k, v in q.items()}


def _scheme(url: str) -> str:
    scheme = url.split("://", 1)[0] if "://" in url else ""
    if not scheme:
        raise BadURL(
            f"{url!r} is not a board URL (expected e.g. tcp://HOST:PORT or serial:///dev/X)"
        )
    return scheme


def _plugin(scheme: str) -> Factory | None:
    """A third-party transport from the entry points (looked up only for unknown schemes)."""
    from importlib.metadata import entry_points

    for ep in entry_points(group="missing_link.transports"):
        if ep.name == scheme:
            factory: Factory = ep.load()
            register_transport(scheme, factory)
            return factory
    return None


def _unknown(url: str, scheme: str) -> BadURL:
    known = ", ".join(sorted({*BUILTIN, *_REGISTERED}))
    return BadURL(f"{url!r}: unknown transport {scheme!r} (known: {known}, and spy+ prefix)")


def _unsigned(url: str) -> tuple[str, str]:
    """``signed+URL?key=FILE`` -> (URL without the key, the key file); BadURL without one."""
    parts = urlsplit(url[len("signed+") :])
    query = [(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True)]
    keys = [v for k, v in query if k == "key"]
    if not keys or not keys[-1]:
        raise BadURL(f"{url!r}: signed+ needs ?key=FILE (the board's signing key)")
    rest = "&".join(f"{k}={v}" for k, v in query if k != "key")
    return urlunsplit(parts._replace(query=rest)), keys[-1]


def check_url(url: str) -> str:
    """The URL's scheme if a transport for it exists; ``BadURL`` (a usage error) otherwise.
    Errors that retrying cannot fix are found here, before any connection attempt."""
    if url.startswith("spy+"):
        return check_url(url[4:])
    if url.startswith("signed+"):
        inner, key = _unsigned(url)
        module = importlib.import_module(_SIGNED[0])
        module.load_key(key)  # (a missing or malformed key is the user's to fix, not a retry's)
        return check_url(inner)
    scheme = _scheme(url)
    if scheme not in BUILTIN and scheme not in _REGISTERED and _plugin(scheme) is None:
        raise _unknown(url, scheme)
    return scheme


def _factory(url: str, scheme: str) -> Factory:
    factory = _REGISTERED.get(scheme)
    if factory is not None:
        return factory
    if scheme in BUILTIN:
        module, name = BUILTIN[scheme]
        loaded: Factory = getattr(importlib.import_module(module), name)
        return loaded
    factory = _plugin(scheme)
    if factory is None:
        raise _unknown(url, scheme)
    return factory


def open_transport(url: str) -> Transport:
    """Open a board link by URL: ``tcp://127.0.0.1:5000``, ``serial:///dev/ttyACM0?baud=115200``,
    ``usb://``, ``unix:///tmp/board.sock``, ``memory://name``; prefix ``spy+`` to dump traffic,
    ``signed+`` (with ``?key=FILE``) for a board on a network link that signs (docs/signing.md)."""
    if url.startswith("spy+"):
        module, name = _SPY
        spy: Callable[[Transport], Transport] = getattr(importlib.import_module(module), name)
        return spy(open_transport(url[4:]))
    if url.startswith("signed+"):
        inner, key = _unsigned(url)
        mod = importlib.import_module(_SIGNED[0])
        signed: Transport = getattr(mod, _SIGNED[1])(open_transport(inner), mod.load_key(key))
        return signed
    return _factory(url, _scheme(url))(url, query_dict(url))
