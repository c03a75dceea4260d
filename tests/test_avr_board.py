"""Any AVR board file in simavr from the CLI (issue 46.5): ``missing-link board --file F
--runtime avr --listen URL`` builds the firmware for the file's MCU (kept in a cache by the hash
of what went into it: deploy/avrsim.py) and runs it with its parts simulated at its pins
(virtual/avrboard.py), as ``--runtime micropython`` does; one-line errors for what cannot
run."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from missing_link.deploy.avrsim import rig_parts
from missing_link.deploy.boardfile import load_board_file
from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import ML, board_process, ml

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
IMU = ROOT / "tests" / "boards" / "imu-uno.py"


@pytest.fixture(autouse=True)
def cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Builds kept for this session's tests only (the CLI's cache: $XDG_CACHE_HOME)."""
    where = tmp_path_factory.getbasetemp() / "xdg-cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(where))
    return where / "missing-link" / "avr"


def first_value(url: str, tid: int, na: bool = False) -> tuple[float | int | None, ...]:
    """The values of the first SIF of transducer ``tid`` from the board at ``url`` (one with
    a value, unless ``na``: a Sharp's first reading after power-up is N/A, warming up)."""
    got: list[tuple[float | int | None, ...]] = []
    done = threading.Event()
    with Board(open_transport(url), timeout=5.0) as board:
        board.handshake()
        assert board.transducers is not None
        t = next(t for t in board.transducers if t.id == tid)

        def on(sif, _rx) -> None:  # type: ignore[no-untyped-def]
            values = tuple(v for _stamp, v in t.decode(sif.payload))
            if na or any(v is not None for v in values):
                got.append(values)
                done.set()

        board.on_sif(tid, on)
        assert done.wait(20.0), f"no SIF from {t.name}"
    return got[0]


@pytest.mark.avr
@pytest.mark.slow
def test_the_thesis_rig_runs_built_once_then_from_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # (a cache of its own: built here)
    cache = tmp_path / "missing-link" / "avr"
    # (no world: the rig's own parts, the Sharp's target at 800 mm, the encoder still)
    with board_process("--file", str(UNO), "--runtime", "avr", "--world", "none") as url:
        assert url.startswith("tcp://127.0.0.1:")
        r = ml("info", url, "--json")
        assert r.returncode == 0, r.stderr
        (ir,) = first_value(url, 1)  # the Sharp, 800 mm away (its rig part at ADC0)
        assert ir == pytest.approx(800, abs=15)
    built = sorted(p.name for p in cache.iterdir())
    assert [n[:3] for n in built] == ["fw-", "rig"]
    mtime = (cache / built[0] / "uno_rig" / "firmware.elf").stat().st_mtime
    t0 = time.monotonic()
    with board_process("--file", str(UNO), "--runtime", "avr", "--world", "none") as url:
        assert time.monotonic() - t0 < 30  # (no build: ~1 s to the listening line)
        (count,) = first_value(url, 0)  # the encoder at rest
        assert count == 0
    assert sorted(p.name for p in cache.iterdir()) == built
    assert (cache / built[0] / "uno_rig" / "firmware.elf").stat().st_mtime == mtime


@pytest.mark.avr
@pytest.mark.slow
def test_a_pty_an_absent_part_and_the_eeprom_kept_in_the_flash(tmp_path: Path) -> None:
    flash = tmp_path / "flash"
    cmd = [*ML, "board", "--file", str(IMU), "--runtime", "avr", "--listen", "pty",
           "--absent", "sonar", "--flash", str(flash), "--world", "none"]  # fmt: skip
    for run in range(2):
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert p.stdout is not None
            line = p.stdout.readline()
            assert line.startswith("LISTENING serial:///dev/pts/"), line
            url = line.split()[1]
            with Board(open_transport(url), timeout=5.0) as board:
                board.handshake()
                if run == 0:  # the IMU's range set and saved (the EEPROM: flash/eeprom.bin)
                    board.configure({"imu.accel_g": 8}, save=True)
                else:
                    assert board.config()["imu.accel_g"] == 8
            imu = first_value(url, 0)
            at_rest = math.hypot(*(float(v or 0) for v in imu[:3]))
            assert at_rest == pytest.approx(9.80665, abs=0.01)
            (sonar,) = first_value(url, 1, na=True)  # no SRF02 on the bus: N/A
            assert sonar is None
        finally:
            p.terminate()
            assert p.wait(10) == 0, p.stderr.read() if p.stderr else ""
            for f in (p.stdout, p.stderr):
                if f is not None:
                    f.close()
    assert (flash / "eeprom.bin").stat().st_size == 1024


_OUT_OF_DESCRIPTORS = textwrap.dedent("""
    import json, os, socket, sys, threading, time
    from pathlib import Path
    sys.path.insert(0, sys.argv[2])
    from descriptors import none_left
    from missing_link.deploy.avrsim import build
    from missing_link.deploy.boardfile import load_board_file
    from missing_link.j2a.codec import SOF, Frame, FrameDecoder, encode_frame
    from missing_link.logs import install
    from missing_link.virtual.avrboard import AvrBoard

    install(sys.stderr)  # (as the CLI does: warnings on stderr)
    sim = build(load_board_file(Path(sys.argv[1])), "avr-0123456789ab")
    board = AvrBoard(sim.command(None), "tcp://127.0.0.1:0")
    serving = threading.Thread(target=board.serve_forever, daemon=True)
    serving.start()
    failures = lambda: getattr(getattr(board, "accept_failures", None), "count", 0)  # (or none)
    while board.pty not in {os.path.realpath(f"/proc/self/fd/{fd}")
                            for fd in os.listdir("/proc/self/fd")}:
        assert serving.is_alive(), "the relay ended before it opened the pty"
        time.sleep(0.01)  # (the relay opens the pty first: its own start, not the case here)
    host = socket.socket()  # (made now: it needs no descriptor of the board's to connect)
    with none_left():
        addr, port = board.url.removeprefix("tcp://").rsplit(":", 1)
        host.connect((addr, int(port)))
        deadline = time.monotonic() + 20
        while serving.is_alive() and not failures():
            assert time.monotonic() < deadline, "the board neither failed an accept nor ended"
            time.sleep(0.01)
    host.settimeout(20)
    host.sendall(encode_frame(SOF, 7, 0))  # a2jGetMapping: every board answers it
    decoder, answered = FrameDecoder(), False
    try:
        while not answered:
            data = host.recv(4096)
            if not data:
                break
            answered = any(isinstance(f, Frame) and f.kind == SOF and f.seq == 7
                           for f in decoder.feed(data))
    except OSError:
        pass
    out = {"answered": answered, "accept_errors": failures()}
    board.stop()
    serving.join(10)
    print(json.dumps(out))
""")


@pytest.mark.avr
@pytest.mark.slow
def test_an_avr_board_out_of_descriptors_goes_on_serving() -> None:
    """The relay's accept() failing (EMFILE) ended it with a traceback, the AVR powered off.
    Now it is counted and said once, the listener rests, and the host waiting in the backlog
    is taken once descriptors are free.  A child process: the limit is per process."""
    run = subprocess.run(
        [sys.executable, "-c", _OUT_OF_DESCRIPTORS, str(UNO), str(Path(__file__).parent)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout)
    assert out["answered"], run.stderr[-2000:]
    assert out["accept_errors"] >= 1
    assert run.stderr.count("accept failed (Too many open files)") == 1, run.stderr
    assert "accepts failed" in run.stderr, run.stderr  # (the count, as it stops)


def test_the_rigs_parts_are_the_board_files_at_its_pins() -> None:
    rover = load_board_file(ROOT / "examples" / "boards" / "rover-mega.py")
    parts = rig_parts(rover)
    assert "gps E4" in parts  # PPS on D2: PE4
    assert "motor 0 A0" in parts and "motor 1 A1" in parts  # OC0A/OC0B, DIR on D22/D23
    assert "stepper A4 A5 A6" in parts and "hcsr04 A2 B0" in parts
    # the wheels on port K, each turned by its motor; the IMU on the TWI; the pack at 7.4 V
    assert {"quadrature K0 K1", "quadrature K2 K3", "wheel 0 0 400 2", "wheel 1 1 400 2"} <= set(
        parts
    )
    assert "mpu6050 0x68" in parts and f"ain 0 {round(7.4 * 3300 / 13300 * 1000)}" in parts
    assert rig_parts(rover, absent=("sonar",)).count("hcsr04 A2 B0") == 0
    uno = rig_parts(load_board_file(UNO))
    assert uno == ["quadrature D2 D3", "sharp 0", "srf02 0x70"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--dial", "tcp://127.0.0.1:9"], "an AVR board's link is its UART"),
        (["--listen", "tcp://127.0.0.1:0", "--file-of", "rover.py"], "mcu 'rp2040' is not an AVR"),
    ],
)  # fmt: skip
def test_what_cannot_run_in_simavr_is_one_line(args: list[str], said: str) -> None:
    board = UNO
    if "--file-of" in args:
        board = ROOT / "examples" / "boards" / args[-1]
        args = args[:-2]
    r = ml("board", "--file", str(board), "--runtime", "avr", *args, timeout=60)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert said in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_without_avr_gcc_it_says_where_to_get_it(tmp_path: Path) -> None:
    bin_dir = tmp_path / "bin"  # a PATH with make and cc but no avr-gcc
    bin_dir.mkdir()
    for tool in ("make", "cc"):
        found = subprocess.run(["which", tool], capture_output=True, text=True).stdout.strip()
        (bin_dir / tool).symlink_to(found)
    env = {**os.environ, "PATH": str(bin_dir)}
    r = ml("board", "--file", str(UNO), "--runtime", "avr", "--listen", "pty", env=env)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "needs avr-gcc, avr-objcopy" in r.stderr and "scripts/system-deps.sh" in r.stderr


@pytest.mark.avr
@pytest.mark.slow
def test_a_board_file_too_big_for_its_mcu_is_refused_with_the_numbers(tmp_path: Path) -> None:
    from .test_fit import UNO_AND_A_MOTOR

    bf = tmp_path / "uno_motor.py"
    bf.write_text(UNO_AND_A_MOTOR)
    r = ml("board", "--file", str(bf), "--runtime", "avr", "--listen", "pty", timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "does not fit the atmega328p" in r.stderr


@pytest.mark.avr
def test_a_tick_line_the_rig_refuses_goes_to_the_world_not_to_the_control_queue() -> None:
    """The rig's refusal of a world's tick line ("error tick: WHY ...": sim/world.c) is the
    world's to hear: put in the control queue instead, the world never heard again and every
    later control line was answered with the one before's (adversary, issue 47.6)."""
    from missing_link.deploy.avrsim import build
    from missing_link.virtual.avrboard import AvrBoard

    sim = build(load_board_file(ROOT / "examples" / "boards" / "rover-mega.py"), "avr-0123456789ab")
    board = AvrBoard(sim.command(None), "tcp://127.0.0.1:0")
    heard: list[str] = []
    board.on_tick = heard.append
    try:
        board.ctl_post("tick motor|1e6")  # (a time the rig's strict parse refuses)
        first, second = board.ctl("stats"), board.ctl("stats")
        assert first.startswith("stats ") and second.startswith("stats "), (first, second)
        assert len(heard) == 1 and heard[0].startswith("error tick: "), heard
    finally:
        board.close()
