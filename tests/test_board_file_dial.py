"""A board file as a virtual board that dials its daemon (issue 36.3: ``missing-link board --file
F --dial tcp://HOST:PORT``, either runtime: board/dial.py's backoff over the runtime's own link
code) and that is the same board whatever port or link it comes on (issue 36.1: its simulated
chip's id kept in its ``--flash DIR``, else from ``--seed``).  Every board is a ``missing-link
board`` process of its own, as a user starts it; the daemon runs in this process."""

from __future__ import annotations

import hashlib
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import IO, Any

import pytest

from missing_link.cli.main import main
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, parse_config
from missing_link.daemon.session.status import SessionState
from missing_link.errors import ConfigError
from missing_link.virtual.boardfile import CHIP_ID_FILE, chip_id
from missing_link.virtual.process import reap

from .helpers import ML, ml, wait_for

ROOT = Path(__file__).resolve().parent.parent
ESP32_DIAL = ROOT / "examples" / "boards" / "esp32-dial.py"
RUNTIMES = ("cpython", pytest.param("micropython", marks=pytest.mark.micropython))
SMALL = """BOARD = {
    "name": "small",
    "mcu": "rp2040",
    "transducers": [
        {"name": "dist_ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 26, "rate_hz": 20},
        {"name": "servo", "id": 1, "driver": "servo", "pin": 13, "call": "a2j_set_servo"},
    ],
}
"""


class Board:
    """``missing-link board --file FILE --runtime RUNTIME ARGS...`` until kill() or stop(); its
    first line (``LISTENING URL`` or ``DIALING URL``) read; stderr to a file."""

    def __init__(self, tmp: Path, file: Path, runtime: str, *args: str) -> None:
        self.err_path = tmp / f"{file.stem}-{runtime}-{time.monotonic_ns()}.err"
        self._err: IO[str] = self.err_path.open("w")
        cmd = [*ML, "board", "--file", str(file), "--runtime", runtime, *args]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._err, text=True)
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()  # type: ignore[union-attr]
        try:
            self.line = lines.get(timeout=60).strip()
        except queue.Empty:
            self.line = ""
        if not self.line.startswith(("LISTENING ", "DIALING ")):
            self.kill()
            raise AssertionError(f"{file.name} ({runtime}): {self.line!r} {self.stderr()}")
        self.url = self.line.split()[1]

    def stderr(self) -> str:
        return self.err_path.read_text()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self._end()

    def kill(self) -> None:
        """SIGKILL: the process is gone at once, as a board whose power was cut."""
        if self.proc.poll() is None:
            self.proc.kill()
        self._end()

    def _end(self) -> int:
        code = reap(self.proc, 15)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._err.close()
        return code


def listening(listen: str, doc: dict[str, Any]) -> Daemon:
    cfg = parse_config(doc)
    cfg.listen = listen
    return Daemon(cfg)


def samples(d: Daemon, name: str) -> int:
    return next((s["samples"] for s in d.status() if s["board"] == name), 0)


# ---- a board file that dials ------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_board_file_dials_in_and_comes_back_as_itself(runtime: str, tmp_path: Path) -> None:
    """examples/boards/esp32-dial.py (a signed link that dials 192.168.1.10:7000) with --dial
    dials the daemon on loopback instead, its key in its flash; the config names it by its
    chip's id.  Killed and restarted on the same flash, it dials again and comes back in the
    same session, under the same name."""
    flash = tmp_path / "flash"
    flash.mkdir()
    key = flash / "mlkey.bin"
    assert ml("key", "new", str(key)).returncode == 0
    ident = chip_id(flash, 0).hex()  # (the board's: made now, kept in its flash)
    with listening(f"signed+tcp://127.0.0.1:0?key={key}", {"boards": {"left": {"id": ident}}}) as d:
        assert d.dialins is not None
        url = f"tcp://127.0.0.1:{d.dialins.listener.port}"
        # (no world: its Sharp ranger then reads its part's 800 mm, never N/A)
        args = ("--dial", url, "--flash", str(flash), "--world", "none")
        board = Board(tmp_path, ESP32_DIAL, runtime, *args)
        try:
            assert board.line == f"DIALING {url}"
            assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 30), d.status()
            (s,) = d.sessions
            assert s.name == "left" and s.identity.board_id == ident
            (st,) = d.status()
            assert st["address"].startswith("signed+tcp://127.0.0.1:") and st["signed_records"]
            assert wait_for(lambda: samples(d, "left") > 3, 10), d.status()
            board.kill()
            assert wait_for(lambda: s.state != SessionState.UP, 10)
            board = Board(tmp_path, ESP32_DIAL, runtime, *args)
            assert wait_for(lambda: s.state == SessionState.UP and s.connects == 2, 30), d.status()
            assert [x.name for x in d.sessions] == ["left"] and s.identity.board_id == ident
            before = samples(d, "left")
            assert wait_for(lambda: samples(d, "left") > before, 10)
        finally:
            board.kill()


# ---- who a board file's board is ---------------------------------------------------------------
def test_a_chip_id_is_made_once_per_flash_and_else_seeded(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    first = chip_id(a, 0)
    assert len(first) == 8 and chip_id(a, 5) == first  # kept: the flash's, whatever the seed
    assert (a / CHIP_ID_FILE).read_text() == first.hex() + "\n"
    assert chip_id(b, 0) != first  # another flash, another chip
    seeded = hashlib.sha256(b"missing-link sim board 3").digest()[:8]  # host.mjs --seed 3's
    assert chip_id(None, 3) == seeded != chip_id(None, 4)
    (b / CHIP_ID_FILE).write_text("not a chip\n")
    with pytest.raises(ConfigError, match=r"\.chip_id is not a chip id \(16 hex digits\)"):
        chip_id(b, 0)


def test_seed_and_flash_and_a_dial_that_is_not_tcp_are_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    small = tmp_path / "small.py"
    small.write_text(SMALL)
    for argv, words in (
        (["--listen", "tcp://127.0.0.1:0", "--flash", str(tmp_path), "--seed", "2"], "--seed"),
        (["--dial", "unix:///tmp/daemon.sock"], "'unix:///tmp/daemon.sock': dial tcp://HOST:PORT"),
        (["--dial", "tcp://127.0.0.1"], "dial tcp://HOST:PORT"),
    ):
        assert main(["board", "--file", str(small), *argv]) == 2
        out, err = capsys.readouterr()
        assert out == "" and len(err.splitlines()) == 1 and words in err, err


def board_ids(d: Daemon) -> dict[str, str]:
    return {s["board_id"]: s["board"] for s in d.status()}


@pytest.mark.slow
@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_board_file_is_the_same_board_on_the_same_flash(runtime: str, tmp_path: Path) -> None:
    """Two flashes, two boards: each its own chip id, made at its first run; restarted on the
    same flash (on another port) the board states the same id, and the config names it by that
    id whatever URL it comes on.  Without --flash, --seed gives the id (host.mjs --seed's)."""
    small = tmp_path / "small.py"
    small.write_text(SMALL)
    a, b = tmp_path / "a", tmp_path / "b"
    listen = ("--listen", "tcp://127.0.0.1:0")
    boards = [Board(tmp_path, small, runtime, *listen, "--flash", str(f)) for f in (a, b)]
    try:
        ids = [(f / CHIP_ID_FILE).read_text().strip() for f in (a, b)]
        assert ids[0] != ids[1]
        cfg = parse_config({"boards": {"left": {"id": ids[0]}}})
        cfg.boards = [BoardSpec(x.url) for x in boards]
        with Daemon(cfg) as d:
            assert d.wait_until_up(20), d.status()
            assert board_ids(d) == {ids[0]: "left", ids[1]: "small"}
        boards[0].stop()
        boards[0] = Board(tmp_path, small, runtime, *listen, "--flash", str(a))  # restarted
        boards.append(Board(tmp_path, small, runtime, *listen, "--seed", "9"))
        cfg = parse_config({"boards": {"left": {"id": ids[0]}}})
        cfg.boards = [BoardSpec(x.url) for x in boards[::-1]]  # (other ports, another order)
        with Daemon(cfg) as d:
            assert d.wait_until_up(20), d.status()
            seeded = hashlib.sha256(b"missing-link sim board 9").digest()[:8].hex()
            names = board_ids(d)
            assert set(names) == {*ids, seeded} and names[ids[0]] == "left"
    finally:
        for x in boards:
            x.kill()
