"""A board's handshake: what the host reads of a board before anything else, and checks (a
board is untrusted): its function mapping (opcode 0, or ``a2jGetMappingMany`` when it does not
fit a frame), its properties and its transducer descriptors, all within one deadline on the
board's clock and each within a size cap.  Errors name the board and the field.

It runs on a board (:class:`~missing_link.host.board.Board`, ``Board.handshake``) through what
:class:`Handshaken` names: a first call by index, a many-read by name, the fields it fills."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from ..errors import BoardError, CallTimeout
from ..j2a import BlobError, parse_mapping, parse_properties
from ..j2a.blobs import mapping_index
from .clock import Clock
from .results import CallResult

if TYPE_CHECKING:
    from ..descriptors import Transducer

#: the whole handshake (mapping, properties, descriptors) must end within this (s)
HANDSHAKE_TIMEOUT = 5.0
#: caps on what a board may send during the handshake (bytes): a board is untrusted
MAX_MAPPING = 16 << 10
MAX_PROPERTIES = 16 << 10
MAX_TRANSDS = 64 << 10


class Handshaken(Protocol):
    """What the handshake reads a board through, and fills in."""

    functions: list[str]
    index: dict[str, int]
    properties: dict[str, str]
    transducers: list[Transducer] | None
    transds_text: str | None

    @property
    def name(self) -> str: ...
    @property
    def url(self) -> str: ...
    @property
    def timeout(self) -> float: ...
    @property
    def clock(self) -> Clock: ...
    def call_index(
        self, index: int, payload: bytes, label: str, timeout: float | None = None
    ) -> CallResult: ...
    def read_many(
        self, name: str, *, max_bytes: int, timeout: float | None, deadline: float | None
    ) -> bytes: ...


def handshake(board: Handshaken, *, describe: bool = True, deadline: float | None = None) -> None:
    """Read ``board``'s mapping, properties and (``describe``) descriptors, all by
    ``deadline`` (the board clock's s; default: ``HANDSHAKE_TIMEOUT`` from now)."""
    clock = board.clock
    if deadline is None:
        deadline = clock.monotonic() + HANDSHAKE_TIMEOUT
    total = deadline - clock.monotonic()

    def left(what: str) -> float:
        remaining = deadline - clock.monotonic()
        if remaining <= 0:
            raise CallTimeout(board.name, what, f"handshake not done within {total:.1f} s")
        return remaining

    def read(name: str, cap: int) -> bytes:  # (a blob of the handshake: its cap, the deadline)
        return board.read_many(
            name, max_bytes=cap, timeout=min(board.timeout, left(name)), deadline=deadline
        )

    # First contact: ask again on a timeout (a board still booting, stale bytes in a pty).
    while True:
        try:
            first = board.call_index(
                0, b"", "a2jGetMapping", min(board.timeout, left("a2jGetMapping"))
            )
            break
        except CallTimeout:
            left("a2jGetMapping")
    blob = first.payload
    # An original board wraps past 255 bytes; a new one stops at a name boundary and offers
    # the full table through a2jGetMappingMany.
    head = blob[: blob.rfind(b"\0") + 1] if b"\0" in blob else b""
    try:
        names = parse_mapping(head)
        # (what fits one frame, until the full table is read: it names a2jGetMappingMany,
        # which tells a Part 2 board, whose a2jMany serves offsets past 255)
        board.functions, board.index = names, mapping_index(names)
        if "a2jGetMappingMany" in names:
            full = read("a2jGetMappingMany", MAX_MAPPING)
            names = parse_mapping(full)
        board.functions = names
        board.index = mapping_index(names)
    except BlobError as e:
        raise BoardError(board.url, f"bad function mapping: {e}") from e

    if "a2jGetProperties" in board.index:
        raw = read("a2jGetProperties", MAX_PROPERTIES)
        try:
            board.properties = parse_properties(raw)
        except BlobError as e:
            raise BoardError(board.url, f"bad properties: {e}") from e
        _check_properties(board.name, board.properties)
    if describe and "a2jGetTransds" in board.index:
        raw = read("a2jGetTransds", MAX_TRANSDS)
        try:
            board.transds_text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise BoardError(board.name, f"transducer descriptors are not UTF-8: {e}") from e
        from ..descriptors import parse_transds

        board.transducers = parse_transds(board.transds_text, board.name)


def _check_properties(board: str, props: dict[str, str]) -> None:
    """Range-check the numbers a board states about itself (they steer the host)."""
    res = props.get("clock.res_us")
    if res is not None:
        try:
            value = int(res)
        except ValueError:
            value = 0
        if not 1 <= value <= 1_000_000:
            raise BoardError(
                board, f"property clock.res_us = {res!r}: expected whole µs in 1..1000000"
            )
