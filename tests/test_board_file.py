"""Any board file as a virtual board (issue 35.1): ``missing-link board --file BOARDFILE`` runs
the board file's firmware - on CPython, or under the real MicroPython in node - with every part
simulated from its datasheet (virtual/world/), and a daemon that knows nothing of it lists its
transducers and gets samples.  ``--absent`` unplugs parts, ``--flash DIR`` keeps the board's
flash between runs, and bad input is one line with exit 2.  Every board here is a ``missing-link
board`` process of its own, as a user starts it."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.deploy.boardfile import load_board_file
from missing_link.topics import Update
from missing_link.virtual.process import reap

from .helpers import ML, ml, wait_for

ROOT = Path(__file__).resolve().parent.parent
BOARDS = sorted((ROOT / "examples" / "boards").glob("*.py"))
RUNTIMES = ("cpython", pytest.param("micropython", marks=pytest.mark.micropython))
MPY_PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript"
#: drivers that report only when something changes (a switch: its level at boot goes out before
#: any host is there); every other sensor reports by itself
ON_CHANGE = {"digital"}


class BoardProcess:
    """``missing-link board --file FILE --runtime RUNTIME ...`` until close(); its stderr goes to
    a file (the firmware's prints must never fill a pipe nobody reads)."""

    def __init__(
        self, tmp: Path, file: Path, runtime: str, *extra: str, listen: str = "tcp://127.0.0.1:0"
    ) -> None:
        if runtime == "micropython" and not MPY_PKG.exists():
            pytest.fail("node and the npm MicroPython package are required: run `make node`")
        self.err_path = tmp / f"{file.stem}-{runtime}-{time.monotonic_ns()}.err"
        self._err: IO[str] = self.err_path.open("w")
        cmd = [*ML, "board", "--file", str(file)]
        cmd += ["--runtime", runtime, "--listen", listen, *extra]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._err, text=True)
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()  # type: ignore[union-attr]
        try:
            line = lines.get(timeout=60)
        except queue.Empty:
            line = ""
        if not line.startswith("LISTENING "):
            self.close()
            raise AssertionError(
                f"{file.name} ({runtime}) did not come up: {line!r} {self.stderr()}"
            )
        self.url = line.split()[1]

    def stderr(self) -> str:
        return self.err_path.read_text()

    def stop(self) -> int:
        """SIGTERM, as a user's Ctrl-C or a service manager: the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return reap(self.proc, 15)

    def close(self) -> None:
        self.stop()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._err.close()


def board_url(b: BoardProcess, flash: Path | None, file: Path) -> str:
    key = load_board_file(file).board.get("link", {}).get("key_file")
    return f"signed+{b.url}?key={flash / key}" if key and flash else b.url


@pytest.fixture(scope="module", params=RUNTIMES)
def every_board(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[str, list[tuple[Path, BoardProcess, str]]]]:
    """Every file in examples/boards/ as a virtual board under one runtime, all at once (the
    signed one with its key in its flash)."""
    runtime = request.param
    tmp = tmp_path_factory.mktemp(f"boards-{runtime}")
    near = tmp / "near.toml"  # (a small room: every ranger has a wall in reach, docs/world.md)
    near.write_text("[room]\nwalls = [[[-1.3, -1.3], [1.3, -1.3]], [[1.3, -1.3], [1.3, 1.3]], "
                    "[[1.3, 1.3], [-1.3, 1.3]], [[-1.3, 1.3], [-1.3, -1.3]]]\n")  # fmt: skip
    started: list[tuple[Path, BoardProcess, str]] = []
    t0 = time.monotonic()
    try:
        for file in BOARDS:
            flash = tmp / f"flash-{file.stem}"
            flash.mkdir()
            key = load_board_file(file).board.get("link", {}).get("key_file")
            if key:
                assert ml("key", "new", str(flash / key)).returncode == 0
            b = BoardProcess(tmp, file, runtime, "--flash", str(flash), "--world", str(near))
            started.append((file, b, board_url(b, flash, file)))
        print(f"{runtime}: {len(started)} boards up in {time.monotonic() - t0:.2f} s")
        yield runtime, started
    finally:
        for _f, b, _u in started:
            b.close()


@pytest.mark.slow
def test_every_example_board_file_serves_a_daemon(
    every_board: tuple[str, list[tuple[Path, BoardProcess, str]]],
) -> None:
    """A daemon lists every board's transducers as the board file names them, and gets samples
    from every sensor that reports by itself, AVR board files included (their drivers have the
    same names in the Python runtime)."""
    runtime, boards = every_board
    specs = [BoardSpec(url, timeout=3.0, handshake_timeout=20.0) for _f, _b, url in boards]
    got: dict[str, list[Update]] = {}
    t0 = time.monotonic()
    with Daemon(Config(boards=specs)) as d:
        assert d.wait_until_up(60), [(s.board, s.error) for s in d.snapshots()]
        up_s = time.monotonic() - t0
        d.subscribe("/**", lambda u: got.setdefault(u.topic.name, []).append(u), queue=0)
        want = {}
        for file, _b, _u in boards:
            bf = load_board_file(file)
            (session,) = [s for s in d.sessions if s.name == bf.name]
            listed = sorted(t.transducer.name for t in session.topics.values())
            assert listed == sorted(t["name"] for t in bf.transducers), file.name
            for t in bf.transducers:
                if t["driver"] not in ON_CHANGE and "call" not in t:
                    want[f"/{bf.name}/{t['name']}"] = file.name
        assert wait_for(lambda: set(want) <= set(got), 20), sorted(set(want) - set(got))
        for topic in want:
            assert any(v is not None for u in got[topic] for v in u.values), topic
    print(f"{runtime}: daemon up on {len(boards)} boards in {up_s:.2f} s")
    for _f, b, _u in boards:
        assert b.proc.poll() is None, b.stderr()


@pytest.mark.slow
@pytest.mark.parametrize("runtime", RUNTIMES)
def test_an_absent_part_is_na_and_the_rest_is_served(runtime: str, tmp_path: Path) -> None:
    """--absent tof,gps: the VL53L0X does not acknowledge (its topic N/A), the GPS sends
    nothing; the compass and the sonar go on (no world: the parts' own defaults)."""
    rover = ROOT / "examples" / "boards" / "rover.py"
    b = BoardProcess(tmp_path, rover, runtime, "--absent", "tof,gps", "--world", "none")
    try:
        with Daemon(Config(boards=[BoardSpec(b.url, timeout=3.0, handshake_timeout=20.0)])) as d:
            assert d.wait_until_up(30)
            got: dict[str, list[Update]] = {}
            d.subscribe("/rover/*", lambda u: got.setdefault(u.topic.name, []).append(u), queue=0)
            assert wait_for(
                lambda: all(
                    len(got.get(f"/rover/{n}", [])) >= 3 for n in ("tof", "compass", "sonar")
                ),
                10,
            )
            assert all(u.values == [None] for u in got["/rover/tof"])
            assert got["/rover/sonar"][-1].values == [1000]  # the HC-SR04 model's 1 m
            assert got["/rover/compass"][-1].values[0] is not None
            time.sleep(1.5)  # past a GPS second: nothing came
            assert "/rover/gps" not in got
    finally:
        b.close()
    assert b.proc.returncode == 0, b.stderr()


@pytest.mark.slow
@pytest.mark.parametrize("runtime", RUNTIMES)
def test_a_saved_configuration_survives_a_restart_on_the_same_flash(
    runtime: str, tmp_path: Path
) -> None:
    """config --save on one run; the next run on the same --flash DIR boots with it (and over
    a pty: the board's URL is serial:///dev/pts/N, as a USB board's)."""
    rig = ROOT / "examples" / "boards" / "thesis-rig.py"
    flash = tmp_path / "flash"
    b = BoardProcess(tmp_path, rig, runtime, "--flash", str(flash), listen="pty")
    try:
        assert b.url.startswith("serial:///dev/pts/")
        r = ml("config", b.url, "dist_ir.rate_hz=7", "imu.accel_g=8", "--save", "--timeout", "5")
        assert r.returncode == 0, r.stderr
    finally:
        b.close()
    assert b.proc.returncode == 0, b.stderr()
    assert (flash / "mlconfig.bin").is_file()
    b = BoardProcess(tmp_path, rig, runtime, "--flash", str(flash), listen="pty")
    try:
        r = ml("config", b.url, "--timeout", "5")
        assert r.returncode == 0, r.stderr
        assert "dist_ir.rate_hz    = 7" in r.stdout and "imu.accel_g        = 8" in r.stdout
    finally:
        b.close()
    b = BoardProcess(tmp_path, rig, runtime)  # another flash (none given): the defaults
    try:
        r = ml("config", b.url, "--timeout", "5")
        assert "dist_ir.rate_hz    = 25" in r.stdout, r.stdout + r.stderr
    finally:
        b.close()


# ---- bad input: one line, exit 2, nothing started ------------------------------------------
def _one_line_exit_2(r: subprocess.CompletedProcess[str], *words: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("missing-link: error: "), r.stderr
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.slow
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path) -> None:
    rover = str(ROOT / "examples" / "boards" / "rover.py")
    listen = ("--listen", "tcp://127.0.0.1:0")
    _one_line_exit_2(
        ml("board", "--file", str(tmp_path / "nope.py"), *listen), "nope.py", "cannot read"
    )
    bad = tmp_path / "bad.py"
    bad.write_text(
        "BOARD = {'name': 'x', 'transducers': [{'name': 'a', 'id': 0, 'driver': 'warp'}]}\n"
    )
    _one_line_exit_2(ml("board", "--file", str(bad), *listen), "bad.py", "warp")
    bad.write_text("BOARD = {\n")
    _one_line_exit_2(ml("board", "--file", str(bad), *listen), "bad.py", "not Python")
    _one_line_exit_2(
        ml("board", "--file", rover, "--absent", "tof,wings", *listen), "--absent wings", "tof"
    )
    _one_line_exit_2(ml("board", "--file", rover, "--rate", "5", *listen), "--rate", "--sim")
    _one_line_exit_2(
        ml("board", "--sim", "thesis", "--flash", str(tmp_path), *listen), "--flash", "--file"
    )
    _one_line_exit_2(ml("board", "--file", rover, "--sim", "thesis", *listen), "--sim", "--file")
    _one_line_exit_2(ml("board", "--file", rover, "--runtime", "pascal", *listen), "pascal")
    wifi = str(ROOT / "examples" / "boards" / "esp32-wifi.py")
    _one_line_exit_2(ml("board", "--file", wifi, *listen), "key_file mlkey.bin", "--flash DIR")
    _one_line_exit_2(
        ml("board", "--file", wifi, "--flash", str(tmp_path), *listen), str(tmp_path / "mlkey.bin")
    )
    assert ml("key", "new", str(tmp_path / "mlkey.bin")).returncode == 0
    pty = ("--listen", "pty")
    _one_line_exit_2(ml("board", "--file", wifi, "--flash", str(tmp_path), *pty), "signed", "pty")
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    _one_line_exit_2(
        ml("board", "--file", rover, "--flash", str(a_file), *listen), "not a directory"
    )
    _one_line_exit_2(
        ml("board", "--file", rover, "--runtime", "micropython", "--listen", "unix:///tmp/x.sock"),
        "tcp://127.0.0.1:PORT or pty",
    )


@pytest.mark.slow
def test_micropython_without_node_says_make_node(tmp_path: Path) -> None:
    """No node on the PATH: one line saying `make node`, exit 2, before anything starts."""
    env = {**os.environ, "PATH": str(tmp_path)}  # (python itself is run by its full path)
    r = ml(
        "board",
        "--file",
        str(ROOT / "examples" / "boards" / "rover.py"),
        "--runtime",
        "micropython",
        "--listen",
        "tcp://127.0.0.1:0",
        env=env,
    )
    _one_line_exit_2(r, "Node.js", "make node")
