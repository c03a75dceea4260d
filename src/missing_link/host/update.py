"""A firmware update over a board's J2A link, the host's side.  The board's side is
board/update.py and board/boot.py (their "Theory of operation" says what each step does on the
board); deploy/update.py makes the image from a board file and runs this on a board it opened,
daemon/control/updates.py on a board the daemon holds.

Theory of operation
-------------------
:func:`image_of` packs a firmware's files (the runtime's and the board file: what a slot holds)
into the MLFW1 image the board stages, with its SHA-256 and the fw.hash its files make
(board/identity.py).  :meth:`Updater.run` takes one board through the steps, each a J2A call::

    check -> a2jFwBegin -> a2jFwStage (a2jMany) -> a2jFwSwitch -> restart -> reconnect -> confirm

``check`` refuses before a byte of the image is sent (:class:`UpdateRefused`): a board whose
firmware takes no update (no ``a2jFwInfo``), one on trial, one whose identity is not the one
named (``board.id``, ``board.model``, the board file's ``mcu``), an update that would turn the
link's signing off or reach a board that signs over a link that does not, one that does not fit
the room the board says its flash has.  A step the board refuses, or a link that fails before
the switch, ends the update with the old firmware running (nothing was switched, said so).  After
the switch the board restarts; ``reconnect`` (the caller's: open the URL again, or wait for the
daemon's session) gives a board that completed a handshake.  Stating the image's fw.hash, it is
confirmed (``a2jFwConfirm``); stating the old one, it went back, and ``a2jFwInfo`` says why; not
back within the trial time plus ``COME_BACK_S``, it is reported so.  Every step's state goes to
``report(state, done, total)`` (the daemon's status key ``update``; a progress bar), and the end
is an :class:`Outcome`: old and new version and hash, bytes, seconds, what happened.
"""

from __future__ import annotations

import hashlib
import math
import struct
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from ..board.identity import BOARD_FILE, FirmwareHash
from ..errors import MissingLinkError
from ..j2a import BlobError, parse_properties
from ..text import safe_text
from .board import Board

IMAGE_MAGIC = b"MLFW1\n"
MAX_IMAGE = 4 << 20  #: the board's cap too (board/update.py)
LIB = "lib/mlboard/"
#: the time a board has to confirm a new firmware, by default (s), and what a2jFwSwitch takes
TRIAL_S = 30
TRIAL_RANGE = (5, 3600)
#: beyond the trial time: how long a board may take to come back (a restart, a reconnect)
COME_BACK_S = 30.0
#: a filesystem's block: every file takes whole blocks (littlefs on rp2 and esp32: 4 KiB)
BLOCK = 4096

T = TypeVar("T")
Report = Callable[[str, int, int], None]
Reconnect = Callable[[float], Board]

UPDATED = "updated"  #: the new firmware runs, confirmed
WENT_BACK = "went back"  #: it ran and was not confirmed, or raised: the old one runs
NOT_SWITCHED = "not switched"  #: the update ended before the switch: the old one runs
NOT_BACK = "not back"  #: switched, and no board came back in time


class UpdateRefused(MissingLinkError):
    """Refused before a byte of the image was sent: nothing on the board changed."""


class UpdateFailed(MissingLinkError):
    """The update ended without the new firmware running (the message says what runs)."""


@dataclass(frozen=True)
class Image:
    """A firmware as the board stages it: the files of a slot, packed (MLFW1)."""

    files: tuple[tuple[str, bytes], ...]
    data: bytes
    sha256: str
    fw_hash: str
    version: str = ""
    key_file: str = ""  #: a key the new board file's link reads (it must be on the board)

    def footprint(self) -> int:
        """Bytes of flash the slot takes: each file in whole blocks, and a block per folder."""
        folders = {p.rsplit("/", 1)[0] for p, _ in self.files if "/" in p}
        blocks = sum(math.ceil(len(b) / BLOCK) or 1 for _, b in self.files) + len(folders) + 2
        return blocks * BLOCK


def image_of(files: Sequence[tuple[str, bytes]], version: str = "", key_file: str = "") -> Image:
    """The image of a slot's files: (path in the slot, bytes): ``lib/mlboard/...`` and
    ``board.py``."""
    h = FirmwareHash()
    parts = [IMAGE_MAGIC]
    for path, data in sorted(files):
        if path != BOARD_FILE and not (path.startswith(LIB) and path.endswith(".py")):
            raise ValueError(f"{path}: a slot holds lib/mlboard/**.py and board.py only")
        h.add(path.removeprefix(LIB), len(data), [data])
        parts += [path.encode(), b"\0", str(len(data)).encode(), b"\0", data]
    parts.append(b"\0")
    blob = b"".join(parts)
    if len(blob) > MAX_IMAGE:
        raise ValueError(f"the image is {len(blob)} bytes, over the {MAX_IMAGE} a board takes")
    return Image(tuple(sorted(files)), blob, hashlib.sha256(blob).hexdigest(), h.digest(),
                 version, key_file)  # fmt: skip


@dataclass(frozen=True)
class Target:
    """Who the board must be (the new board file's model and mcu; ``board_id`` if named)."""

    model: str
    mcu: str
    board_id: str = ""

    def to_json(self) -> dict[str, str]:
        """As a client asks a daemon for the update (``missing-link update`` -> the control
        endpoint: daemon/control/updates.py)."""
        return {"model": self.model, "mcu": self.mcu, "board_id": self.board_id}

    @classmethod
    def from_json(cls, d: Mapping[str, object]) -> Target:
        return cls(**{k: str(v) for k, v in d.items()})


@dataclass(frozen=True)
class Outcome:
    board: str
    url: str
    state: str  #: UPDATED, WENT_BACK, NOT_SWITCHED, NOT_BACK
    old_version: str
    old_hash: str
    new_version: str
    new_hash: str
    size: int
    seconds: float
    slot: str = ""
    why: str = ""
    sent_hash: str = ""  #: the fw.hash of what was sent (new_hash: what runs at the end)

    @property
    def ok(self) -> bool:
        return self.state == UPDATED

    def summary(self) -> str:
        moved = f"{self.size / 1024:.1f} KiB in {self.seconds:.1f} s"
        old = f"{self.old_version} {self.old_hash}"
        new = f"{self.new_version} {self.new_hash}"
        if self.ok:
            return f"{self.board}: updated {old} -> {new} ({moved}, slot {self.slot}, confirmed)"
        return (f"{self.board}: {self.state}: {self.why}; it runs {new} (was {old}; sent "
                f"fw.hash {self.sent_hash}, {moved})")  # fmt: skip

    def to_json(self) -> dict[str, object]:
        """As the daemon answers an update (``from_json`` reads it back in the client)."""
        return {"board": self.board, "url": self.url, "state": self.state,
                "old_version": self.old_version, "old_hash": self.old_hash,
                "new_version": self.new_version, "new_hash": self.new_hash,
                "sent_hash": self.sent_hash, "bytes": self.size,
                "seconds": round(self.seconds, 3), "slot": self.slot, "why": self.why}  # fmt: skip

    @classmethod
    def from_json(cls, o: Mapping[str, Any]) -> Outcome:
        return cls(o["board"], o["url"], o["state"], o["old_version"], o["old_hash"],
                   o["new_version"], o["new_hash"], o["bytes"], o["seconds"], o["slot"],
                   o["why"], o["sent_hash"])  # fmt: skip


def read_info(board: Board) -> dict[str, str]:
    """What ``a2jFwInfo`` says (UpdateRefused for a firmware without it)."""
    if "a2jFwInfo" not in board.index:
        raise UpdateRefused(
            f"{board.name}: its firmware takes no update over the link (no a2jFwInfo): flash "
            "this version once over USB (missing-link flash)"
        )
    try:
        return parse_properties(board.read_many("a2jFwInfo", max_bytes=4096))
    except BlobError as e:
        raise UpdateFailed(f"{board.name}: a2jFwInfo: {e}") from None


def is_signed(board: Board) -> bool:
    """Does the host reach the board over signed J2A (docs/signing.md)?"""
    return board.url.split("://", 1)[0].startswith("signed+")


def check(board: Board, info: dict[str, str], image: Image, target: Target) -> None:
    """Everything that refuses the update before a byte of it is sent (UpdateRefused)."""
    name, props = board.name, board.properties
    if info.get("state") != "ok":
        raise UpdateRefused(f"{name}: its firmware is on trial (not confirmed): it takes no "
                            "update until it is confirmed or has gone back")  # fmt: skip
    if target.board_id and props.get("board.id") != target.board_id:
        raise UpdateRefused(f"{name}: board.id {props.get('board.id')!r}, not "
                            f"{target.board_id!r} as named (--id)")  # fmt: skip
    if props.get("board.model") != target.model:
        raise UpdateRefused(f"{name}: board.model {props.get('board.model')!r}, the board "
                            f"file says {target.model!r}: another kind of board?")  # fmt: skip
    if info.get("mcu") != target.mcu:
        raise UpdateRefused(f"{name}: its firmware was made for mcu {info.get('mcu')!r}, the "
                            f"board file says {target.mcu!r}")  # fmt: skip
    signing = "a2jLinkStats" in board.index  # (a board whose link signs)
    if signing and not image.key_file:
        raise UpdateRefused(f"{name}: its link signs, the new board file's link has no "
                            "key_file: the update would make it take unsigned J2A")  # fmt: skip
    if (signing or image.key_file) and not is_signed(board):
        raise UpdateRefused(f"{name}: an unsigned update to a board that requires signing: "
                            "use signed+tcp://HOST:PORT?key=FILE (docs/signing.md)")  # fmt: skip
    room = info.get("room", "")
    if room.isdigit() and image.footprint() > int(room):
        raise UpdateRefused(f"{name}: the update takes about {image.footprint()} bytes of "
                            f"flash, the board has {room} free for it")  # fmt: skip


class Updater:
    """One update of one board (see the module's theory of operation)."""

    def __init__(
        self,
        image: Image,
        target: Target,
        *,
        trial_s: int = TRIAL_S,
        report: Report | None = None,
        clock: Callable[[], float] = time.monotonic,
        chunk_timeout: float = 5.0,
    ) -> None:
        if not TRIAL_RANGE[0] <= trial_s <= TRIAL_RANGE[1]:
            raise ValueError(f"trial time {trial_s} s: {TRIAL_RANGE[0]}..{TRIAL_RANGE[1]}")
        self.image = image
        self.target = target
        self.trial_s = trial_s
        self.report: Report = report or (lambda state, done, total: None)
        self.clock = clock
        self.chunk_timeout = chunk_timeout

    def run(self, board: Board, reconnect: Reconnect) -> Outcome:
        """Update ``board``; ``reconnect(deadline)`` gives the board on a new link (a new
        handshake), another at each call, by ``deadline`` on ``clock``, or raises; the one
        whose clock.epoch is new is the board after its restart."""
        t0 = self.clock()
        total = len(self.image.data)
        self.report("checking", 0, total)
        info = read_info(board)
        check(board, info, self.image, self.target)
        old = (board.properties.get("fw.version", ""), board.properties.get("fw.hash", ""))
        slot = self._begin(board)
        self._stage(board, old, t0)
        answered = self._switch(board)
        self.report("restarting", total, total)
        deadline = self.clock() + self.trial_s + COME_BACK_S
        try:
            back = self._restarted(reconnect, deadline, board.properties.get("clock.epoch"))
        except MissingLinkError as e:
            why = f"no board back within {self.trial_s + COME_BACK_S:g} s after the switch: {e}"
            return self._outcome(board, NOT_BACK, old, old, t0, slot, why)
        return self._settle(back, old, slot, t0, answered)

    def _restarted(self, reconnect: Reconnect, deadline: float, epoch: str | None) -> Board:
        """The board once it is back from its restart: a new clock.epoch (a board reached
        again before it restarted is the same boot: asked again)."""
        while True:
            back = reconnect(deadline)
            if back.properties.get("clock.epoch") != epoch or self.clock() >= deadline:
                return back
            time.sleep(0.1)

    def _begin(self, board: Board) -> str:
        img = self.image
        fields = [("size", str(len(img.data))), ("sha256", img.sha256), ("fw.hash", img.fw_hash)]
        if img.key_file:
            fields.append(("key_file", img.key_file))
        payload = b"".join(k.encode() + b"\0" + v.encode() + b"\0" for k, v in fields)
        got = board.call("a2jFwBegin", payload)
        if got.code != 0:
            raise UpdateRefused(f"{board.name}: the board refused the update: {_text(got.payload)}")
        return _text(got.payload)

    def _stage(self, board: Board, old: tuple[str, str], t0: float) -> None:
        total, sent = len(self.image.data), [0]

        def progress(done: int, _total: int | None) -> None:
            sent[0] = done
            self.report("sending", done, total)

        try:
            status = board.write_many(
                "a2jFwStage", self.image.data, progress=progress, timeout=self.chunk_timeout
            )
        except MissingLinkError as e:
            self.report("failed", sent[0], total)
            raise UpdateFailed(
                f"{board.name}: the link failed after {sent[0]} of {total} bytes ({e}); nothing "
                f"was switched: the board still runs {old[0]} {old[1]}"
            ) from None
        if status != 0:
            why = _safe(lambda: read_info(board).get("error", "")) or f"status {status:#04x}"
            self.report("failed", sent[0], total)
            raise UpdateFailed(
                f"{board.name}: the board refused the image ({why}); nothing was switched: it "
                f"still runs {old[0]} {old[1]}"
            )
        self.report("sent", total, total)

    def _switch(self, board: Board) -> bool:
        """True when the board answered (else it may or may not have switched)."""
        total = len(self.image.data)
        self.report("switching", total, total)
        try:
            got = board.call("a2jFwSwitch", struct.pack("<H", self.trial_s))
        except MissingLinkError:
            return False  # (the reply was lost: whether it switched is found out once back)
        if got.code != 0:
            raise UpdateFailed(f"{board.name}: the board did not switch: {_text(got.payload)}")
        return True

    def _settle(
        self, back: Board, old: tuple[str, str], slot: str, t0: float, answered: bool
    ) -> Outcome:
        total = len(self.image.data)
        now = (back.properties.get("fw.version", ""), back.properties.get("fw.hash", ""))
        if now[1] == self.image.fw_hash:
            self.report("confirming", total, total)
            got = back.call("a2jFwConfirm")
            if got.code != 0:
                why = f"it did not take the confirmation: {_text(got.payload)}; it goes back"
                return self._outcome(back, WENT_BACK, old, now, t0, slot, why)
            return self._outcome(back, UPDATED, old, now, t0, slot)
        info = _safe(lambda: read_info(back)) or {}
        if info.get("rolled") == slot and info.get("slot") != slot:
            why = info.get("why") or "it was not confirmed"
            return self._outcome(back, WENT_BACK, old, now, t0, slot, why)
        why = "the board came back with the old firmware" + (
            "" if answered else " (the switch was not answered: it did not switch)"
        )
        return self._outcome(back, NOT_SWITCHED, old, now, t0, slot, why)

    def _outcome(
        self,
        board: Board,
        state: str,
        old: tuple[str, str],
        now: tuple[str, str],
        t0: float,
        slot: str,
        why: str = "",
    ) -> Outcome:
        total = len(self.image.data)
        self.report("done" if state == UPDATED else state, total, total)
        return Outcome(board.name, board.url, state, old[0], old[1], now[0], now[1], total,
                       self.clock() - t0, slot, why, self.image.fw_hash)  # fmt: skip


def _text(payload: bytes) -> str:
    """What a board said, as text (it is quoted in errors, logs and the terminal)."""
    return safe_text(payload.decode("utf-8", "replace").strip("\0").strip(), 200)


def _safe(fn: Callable[[], T]) -> T | None:
    try:
        return fn()
    except MissingLinkError:
        return None


def parse_image(blob: bytes) -> list[tuple[str, bytes]]:
    """The files of an MLFW1 image (ValueError for what is not one): what a daemon handed an
    image file checks it with, packing it again (image_of)."""
    if not blob.startswith(IMAGE_MAGIC) or len(blob) > MAX_IMAGE:
        raise ValueError("not an MLFW1 image (or over the size a board takes)")
    files: list[tuple[str, bytes]] = []
    at = len(IMAGE_MAGIC)
    while True:
        end = blob.index(b"\0", at)
        path = blob[at:end].decode()
        if not path:
            if end + 1 != len(blob):
                raise ValueError("bytes after the image's end")
            return files
        size_end = blob.index(b"\0", end + 1)
        size = int(blob[end + 1 : size_end].decode())
        data = blob[size_end + 1 : size_end + 1 + size]
        if len(data) != size:
            raise ValueError(f"{path}: the image ends inside it")
        files.append((path, data))
        at = size_end + 1 + size
