"""``missing-link update TARGET BOARDFILE``: a board's firmware updated where it is mounted, over
its link (docs/hardware.md, "Updates over the link").

TARGET is a board URL, or the name (or URL) of a board a running daemon holds: the daemon then
does the update on the link it holds (its control endpoint, daemon/control/updates.py), never fought
for the port, and its other boards go on publishing.

MicroPython boards: the board file's firmware (the files ``flash`` copies: the runtime, the
drivers it uses, the board file; flash.py) is packed into an image (host/update.py) that goes
over J2A into the board's staging slot, is checked, switched to on trial and confirmed once the
board is back with it (board/update.py, board/boot.py).  AVR boards: the image is built (make,
stamped: avr.py) and written with avrdude through the Arduino bootloader, over the serial link
only; a daemon that holds the board lets go of its port meanwhile and takes it back; then the
board must state the image's fw.hash.  There is no way back on AVR: the bootloader stays, and
`flash` over USB writes another image."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ..daemon.control.endpoint import ask, default_control_path
from ..errors import BoardError, MissingLinkError
from ..host.board import Board
from ..host.update import (
    NOT_SWITCHED,
    UPDATED,
    Image,
    Outcome,
    Reconnect,
    Report,
    Target,
    UpdateFailed,
    Updater,
    UpdateRefused,
    image_of,
)
from .avr import build_stamped, run_avrdude
from .boardfile import BoardFile
from .flash import LIB, micropython_files
from .heap import check_fit

#: the default model a MicroPython board states (board/firmware.py)
MPY_MODEL = "missing-link micropython board"
#: what an update through a daemon may take in all (s): the transfer, the trial, the way back
DAEMON_S = 900.0
#: how long an AVR board has to answer with its new firmware after avrdude (s)
AVR_BACK_S = 60.0
#: how long a daemon lets go of an AVR board's port at most (its update takes it back before)
AVR_RELEASE_S = 300


def micropython_image(bf: BoardFile) -> Image:
    """The image of ``bf``'s firmware: the runtime and drivers ``flash`` would copy, and the
    board file (the key and main.py stay: a key goes over USB only, main.py is the boot
    loader).  A board file whose firmware cannot fit the board's heap is refused first, as
    ``flash`` refuses it (heap.py: DoesNotFit, with the numbers)."""
    check_fit(bf)
    files = [
        (c.remote, c.local.read_bytes())
        for c in micropython_files(bf)
        if c.remote.startswith(LIB) or c.remote == "board.py"
    ]
    link = bf.board.get("link", {})
    return image_of(files, str(bf.board.get("fw_version", "0.2.0")), str(link.get("key_file", "")))


def target_of(bf: BoardFile, board_id: str | None) -> Target:
    model = str(bf.board.get("model", "" if bf.is_avr else MPY_MODEL))
    return Target(model=model, mcu=bf.mcu, board_id=board_id or "")


def daemon_holding(target: str) -> str | None:
    """The control endpoint of a running daemon that holds ``target`` (None: none does)."""
    path = default_control_path()
    if not os.path.exists(path):
        return None
    try:
        found = ask(path, {"op": "find", "board": target}, 5.0)
    except (OSError, ValueError):
        return None
    return None if "error" in found else path


# ---- MicroPython ---------------------------------------------------------------------------
def update_direct(
    url: str, image: Image, target: Target, trial_s: int, report: Report, timeout: float
) -> Outcome:
    """Update the board at ``url`` on a link of this process's own."""
    boards = [Board.open(url, timeout=timeout)]

    def reconnect(deadline: float) -> Board:
        for b in boards:
            b.close()
        last: Exception | None = None
        while time.monotonic() < deadline:
            try:
                boards.append(Board.open(url, timeout=timeout))
                return boards[-1]
            except MissingLinkError as e:
                last = e
                time.sleep(0.3)
        raise BoardError(url, f"no answer: {last}")

    try:
        updater = Updater(image, target, trial_s=trial_s, report=report)
        return updater.run(boards[0], reconnect)
    finally:
        for b in boards:
            b.close()


def update_via_daemon(
    path: str, board: str, image: Image, target: Target, trial_s: int, report: Report
) -> Outcome:
    """Have the daemon at ``path`` update ``board`` on the link it holds (the image goes in a
    file of the endpoint's own directory, mode 0600: it is over a request's size)."""
    fd, name = tempfile.mkstemp(prefix="update-", suffix=".mlfw", dir=os.path.dirname(path))
    with os.fdopen(fd, "wb") as f:
        f.write(image.data)
    request = {"op": "update", "board": board, "image": name, "version": image.version,
               "key_file": image.key_file, "trial_s": trial_s,
               "target": target.to_json()}  # fmt: skip
    try:
        with _Progress(path, board, report):
            answer = _ask(path, request, DAEMON_S)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(name)
    return Outcome.from_json(answer["outcome"])


def _ask(path: str, request: dict[str, Any], timeout: float) -> dict[str, Any]:
    try:
        answer = ask(path, request, timeout)
    except (OSError, ValueError) as e:
        raise BoardError(str(request["board"]), f"the daemon at {path} did not answer: {e}") from e
    if "error" in answer:
        kind = UpdateRefused if answer.get("kind") == "refused" else UpdateFailed
        raise kind(str(answer["error"]))
    return answer


class _Progress:
    """The daemon's ``update`` status of a board, asked every 0.2 s while the update runs."""

    def __init__(self, path: str, board: str, report: Report) -> None:
        self.path, self.board, self.report = path, board, report
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="update:progress", daemon=True)

    def __enter__(self) -> _Progress:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            try:
                got = ask(self.path, {"op": "update_status", "board": self.board}, 2.0)
            except (OSError, ValueError):
                continue
            u = got.get("update")
            if isinstance(u, dict) and not self._stop.is_set():
                self.report(str(u.get("state", "")), int(u.get("done", 0)), int(u.get("total", 0)))


# ---- AVR -----------------------------------------------------------------------------------
def serial_port(url: str, board: str) -> str:
    """The serial port of an AVR board's URL; UpdateRefused for any other link."""
    parts = urlsplit(url)
    if parts.scheme != "serial" or not parts.path:
        raise UpdateRefused(
            f"{board}: an AVR board is updated through its bootloader (avrdude) over its serial "
            f"link; {url} is not one (a network link cannot reach the bootloader): update it "
            "over USB"
        )
    return parts.path


def update_avr(
    bf: BoardFile,
    where: str,
    target: Target,
    report: Report,
    say: Callable[[str], None],
    *,
    daemon: str | None = None,
    timeout: float = 1.0,
) -> Outcome:
    """``where``: the board's URL, or (``daemon``: its control endpoint) its name there."""
    t0 = time.monotonic()
    report("checking", 0, 0)
    if daemon is None:
        serial_port(where, where)  # (a network URL is refused before anything is opened)
    props, url = _avr_identity(where, daemon, timeout)
    name = props.get("board.name", where)
    port = serial_port(url, name)
    _check_avr(name, props, target)
    old = (props.get("fw.version", ""), props.get("fw.hash", ""))
    with tempfile.TemporaryDirectory(prefix="missing-link-update-") as tmp:
        report("building", 0, 0)
        hex_path, fw_hash = build_stamped(bf, Path(tmp), say)
        size = hex_path.stat().st_size
        report("writing", 0, size)
        if daemon is None:
            run_avrdude(bf, port, hex_path)
        else:
            _ask(daemon, {"op": "release", "board": where, "seconds": AVR_RELEASE_S}, 30.0)
            try:
                run_avrdude(bf, port, hex_path)
            finally:
                _ask(daemon, {"op": "retake", "board": where}, 10.0)
    report("checking", size, size)
    now = _avr_back(where, daemon, url, fw_hash, timeout)
    state = UPDATED if now[1] == fw_hash else NOT_SWITCHED
    why = "" if state == UPDATED else f"avrdude wrote it, the board states fw.hash {now[1]}"
    report("done" if state == UPDATED else state, size, size)
    return Outcome(name, url, state, old[0], old[1], now[0], now[1], size,
                   time.monotonic() - t0, "flash", why, fw_hash)  # fmt: skip


def _avr_identity(where: str, daemon: str | None, timeout: float) -> tuple[dict[str, str], str]:
    if daemon is not None:
        info = _ask(daemon, {"op": "info", "board": where}, 30.0)
        return dict(info["properties"]), str(info["url"])
    with Board.open(where, timeout=timeout, describe=False) as b:
        return dict(b.properties), where


def _check_avr(name: str, props: dict[str, str], target: Target) -> None:
    if target.board_id and props.get("board.id") != target.board_id:
        raise UpdateRefused(f"{name}: board.id {props.get('board.id')!r}, not "
                            f"{target.board_id!r} as named (--id)")  # fmt: skip
    if target.model and props.get("board.model") != target.model:
        raise UpdateRefused(f"{name}: board.model {props.get('board.model')!r}, the board "
                            f"file says {target.model!r}: another kind of board?")  # fmt: skip


def _avr_back(
    where: str, daemon: str | None, url: str, fw_hash: str, timeout: float
) -> tuple[str, str]:
    """(fw.version, fw.hash) once the board answers with fw_hash, or what it states at the
    deadline (BoardError when it does not answer at all)."""
    deadline = time.monotonic() + AVR_BACK_S
    seen: tuple[str, str] | None = None
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            props, _ = _avr_identity(where, daemon, timeout)
            seen = (props.get("fw.version", ""), props.get("fw.hash", ""))
            if seen[1] == fw_hash:
                return seen
        except MissingLinkError as e:
            last = e
        time.sleep(0.5)
    if seen is None:
        raise BoardError(url, f"no J2A answer within {AVR_BACK_S:g} s after avrdude: {last}")
    return seen


def outcome_json(o: Outcome) -> str:
    return json.dumps(o.to_json())


__all__ = ["Reconnect", "daemon_holding", "micropython_image", "target_of", "update_avr",
           "update_direct", "update_via_daemon"]  # fmt: skip
