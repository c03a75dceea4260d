"""Where the daemon accepts boards that dial in: ``run --listen URL``, ``[daemon] listen``.

``tcp://ADDR:PORT`` takes plain J2A, on a loopback address only; any other address needs
``signed+tcp://ADDR:PORT?key=FILE``: a board that dials in is known by the id it states, and
whoever reaches the port could state any id and command the actuators behind it
(docs/signing.md, "Boards that dial in").
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from ..errors import BadURL
from ..transport.sockets import parse_host_port

#: addresses a listener may take unsigned J2A on (boards that dial in; docs/signing.md)
LOOPBACK = ("127.0.0.1", "::1", "localhost")


@dataclass(frozen=True)
class ListenSpec:
    """Where the daemon accepts boards that dial in (``run --listen``, ``[daemon] listen``)."""

    url: str  #: as given (``tcp://ADDR:PORT``, ``signed+tcp://ADDR:PORT?key=FILE``)
    host: str
    port: int
    key_file: str | None  #: signed records (board/signing.py) with this key

    @property
    def loopback(self) -> bool:
        return self.host in LOOPBACK or self.host.startswith("127.")


def parse_listen(url: str) -> ListenSpec:
    """``tcp://ADDR:PORT`` (loopback only) or ``signed+tcp://ADDR:PORT?key=FILE``; ``BadURL``
    saying what is wrong (signing is required off loopback: whoever reaches the port would
    otherwise command the board that dials in)."""
    usage = "listen on tcp://ADDR:PORT or signed+tcp://ADDR:PORT?key=FILE"
    host, port = parse_host_port(url, usage, schemes=("tcp", "signed+tcp"))
    parts = urlsplit(url)
    signed = parts.scheme == "signed+tcp"
    keys = parse_qs(parts.query).get("key", [])
    if signed and not keys:
        raise BadURL(f"{url!r}: signed+ needs ?key=FILE (the boards' signing key)")
    spec = ListenSpec(url, host, port, keys[-1] if signed else None)
    if not signed and not spec.loopback:
        raise BadURL(
            f"{url!r}: boards that dial in off loopback must sign: listen on "
            f"signed+tcp://{parts.netloc}?key=FILE (docs/signing.md)"
        )
    if spec.key_file is not None:
        from ..transport.signed import load_key

        load_key(spec.key_file)  # (BadURL naming the file: a usage error, found at once)
    return spec
