"""Boards configured while they run (docs/configuration.md): the J2A functions byte for byte, all
or nothing, saved on the board so that a power cut in the middle of a save leaves the old or the
new configuration, the host's checks and what it does with a board that answers garbage."""

from __future__ import annotations

import itertools
import struct
from pathlib import Path
from typing import Any

import pytest

from missing_link.board.config import crc16
from missing_link.board.store import FileStore
from missing_link.errors import BoardError, ConfigError
from missing_link.host.board import Board
from missing_link.host.config import ConfigRefused, NotConfigurable, parse_keys
from missing_link.j2a.codec import SOF, FrameDecoder, encode_frame
from missing_link.testing import FakeBoardClock, call_runtime
from missing_link.virtual import make_sim

from .helpers import wait_for
from .vectors import CONFIG_KEYS, CONFIG_VECTORS

ROOT = Path(__file__).resolve().parent.parent
SETUP = ROOT / "tests" / "micropython" / "setup_config.py"


def config_board(path: Path) -> dict[str, Any]:
    """The golden-vector board of tests/micropython/setup_config.py, on CPython: the very code
    the MicroPython test runs (``mlboard`` is ``missing_link.board`` here)."""
    src = SETUP.read_text().replace("mlboard", "missing_link.board")
    ns: dict[str, Any] = {"__name__": "setup_config", "CONFIG_PATH": str(path)}
    exec(compile(src, str(SETUP), "exec"), ns)
    return ns


def test_golden_vectors(tmp_path: Path) -> None:
    ns = config_board(tmp_path / "cfg.bin")
    assert ns["rt"].config.keys_blob() == CONFIG_KEYS
    for case, request, reply in CONFIG_VECTORS:
        assert bytes.fromhex(ns["_step"](request.hex())) == reply, case


def test_a_saved_configuration_is_applied_at_boot_and_only_for_its_board_file(
    tmp_path: Path,
) -> None:
    path = tmp_path / "cfg.bin"
    ns = config_board(path)
    step = ns["_step"]
    for _case, request, _reply in CONFIG_VECTORS[:7]:  # ... mode slow, rate 10, disabled, saved
        step(request.hex())
    step("REBOOT")
    rt = ns["rt"]
    assert rt.config.values() == [False, 10.0, "slow", 2]
    assert rt.config.state & 3 == 3  # saved, and loaded at boot
    assert not rt.transducers[0].enabled
    # a record of another board file (another key table) is not applied
    rec = bytearray(path.read_bytes())
    rec[4] ^= 0xFF  # the schema crc
    rec[-2:] = struct.pack("<H", crc16(bytes(rec[:-2])))
    path.write_bytes(bytes(rec))
    step("REBOOT")
    assert ns["rt"].config.values() == [True, 100.0, "fast", 2]


@pytest.mark.parametrize("cut", ["bytes 0", "bytes 1", "bytes 12", "bytes 24", "rename"])
def test_a_power_cut_in_a_save_leaves_the_old_or_the_new_configuration(
    tmp_path: Path, cut: str
) -> None:
    """The record is written to a temporary file and renamed over the old one: power lost after
    any number of the new record's bytes, or before the rename, leaves the old record."""
    ns = config_board(tmp_path / "cfg.bin")
    step = ns["_step"]
    f = ns["rt"].index
    rate = lambda v: struct.pack("<f", v)  # noqa: E731
    set_ = lambda seq, payload: encode_frame(SOF, seq, f["a2jConfigSet"], payload).hex()  # noqa: E731
    assert step(set_(1, b"\x01\x01" + rate(20.0)))  # saved: rate 20
    step("CUTRENAME" if cut == "rename" else f"CUT {cut.split()[1]}")
    assert step(set_(2, b"\x01\x01" + rate(30.0))) == "CUT"  # power lost during the save
    step("REBOOT")
    assert ns["rt"].config.values()[1] == 20.0  # the old configuration, whole
    assert ns["rt"].config.state & 3 == 3


def test_a_save_that_lost_power_between_remove_and_rename_keeps_the_new_one(
    tmp_path: Path,
) -> None:
    """On FAT a rename cannot replace a file: the old one is removed first.  Power lost between
    the two leaves only the new record, under the temporary name: it is read from there."""
    path = tmp_path / "cfg.bin"
    ns = config_board(path)
    rt = ns["rt"]
    rt.config.apply([(rt.config.keys[1], 40.0)])
    assert rt.config.save() is None
    rt.config.apply([(rt.config.keys[1], 50.0)])
    store = rt.config.store
    store.os = type(
        "FatOs",
        (),
        {"rename": staticmethod(_fat_rename), "remove": staticmethod(_stop_after_remove)},
    )()
    with pytest.raises(KeyboardInterrupt):
        store.write(rt.config.record())
    assert not path.exists() and Path(store.tmp).exists()
    ns["_step"]("REBOOT")
    assert ns["rt"].config.values()[1] == 50.0


def _fat_rename(a: str, b: str) -> None:
    if Path(b).exists():
        raise OSError("exists")
    Path(a).rename(b)


def _stop_after_remove(p: str) -> None:
    Path(p).unlink()
    raise KeyboardInterrupt  # the power went here


def test_file_store_survives_a_torn_temporary_file(tmp_path: Path) -> None:
    store = FileStore(str(tmp_path / "cfg.bin"))
    assert store.read() is None
    store.write(b"new record")
    Path(store.tmp).write_bytes(b"torn")  # a later save that died while writing
    assert store.read() == b"new record"


def test_the_host_checks_before_it_sends_and_says_what_is_allowed(serve: Any) -> None:
    rt = make_sim("thesis", 1)
    server = serve(rt, "tcp://127.0.0.1:0")
    with Board.open(server.url) as board:
        calls = board.link.conn.stats.requests
        cases = {
            "dist_ir.rate_hz": ("30", "0.1..26"),
            "dist_ir.enabled": ("maybe", "true or false"),
            "servo.min_deg": ("1.5", "a whole number"),
            "dist_us.groups": ("2", "read-only"),
            "sonar.rate_hz": ("2", "transducers: quad, dist_ir"),
            "dist_ir.rate": ("2", "dist_ir has: dist_ir.aligned, dist_ir.enabled, dist_ir.ph"),
        }
        board.settings.keys()  # (the table is read once)
        calls = board.link.conn.stats.requests
        for key, (value, said) in cases.items():
            with pytest.raises(ConfigError, match=said):
                board.configure({"dist_ir.rate_hz": 5, key: value})
        assert board.link.conn.stats.requests == calls  # nothing was sent
        assert board.config()["dist_ir.rate_hz"] == 25.0
        # the board refuses a combination: nothing changed, the board's reason
        with pytest.raises(ConfigRefused, match="min_deg < max_deg"):
            board.configure({"servo.min_deg": 40, "servo.max_deg": 30, "dist_ir.rate_hz": 5})
        assert board.config()["dist_ir.rate_hz"] == 25.0
        got = board.configure({"servo.min_deg": -30, "servo.max_deg": 30})
        assert (got["servo.min_deg"], got["servo.max_deg"]) == (-30, 30)


def test_a_disabled_transducer_sends_nothing_and_its_actuator_refuses(serve: Any) -> None:
    rt = make_sim("thesis", 1)
    server = serve(rt, "tcp://127.0.0.1:0")
    with Board.open(server.url) as board:
        seen: list[int] = []
        board.on_sif(None, lambda sif, now: seen.append(sif.cmd))
        board.configure({"dist_ir.enabled": False, "servo.enabled": "off"})
        seen.clear()
        # two dist_us SIFs from later polls than the configure: every older SIF is here
        wait_for(lambda: seen.count(2) >= 2)
        seen.clear()
        # ~0.5 s of the board's time: dist_us sends 75 SIFs/s (dist_ir 25 had it been on)
        wait_for(lambda: seen.count(2) >= 36)
        assert 1 not in seen and 2 in seen  # no dist_ir SIF; dist_us goes on
        result = board.call("a2j_set_servo", b"\x10")
        assert result.code == 0xFF and b"disabled" in result.payload
        board.configure({"dist_ir.enabled": True})
        wait_for(lambda: 1 in seen)
        assert 1 in seen


def test_a_new_rate_shows_within_one_period() -> None:
    """On the board's own time (a FakeBoardClock the test turns, the runtime polled at each
    deadline it asks for, as the board's loop sleeps until then): the first sample at a new
    rate comes within one period of the change, then one a period."""
    clock = FakeBoardClock()
    rt = make_sim("rate", 1, rate_hz=20.0, clock=clock)
    rate = next(k for k in parse_keys(rt.config.keys_blob(), "rate") if k.name == "signal.rate_hz")
    stamps: list[int] = []

    def run(us: int) -> None:
        end = clock.us + us
        while clock.us < end:
            due = rt.next_deadline_us()  # (None: a look every 50 ms, as the server's loop)
            clock.us = min(end, clock.us + 50_000 if due is None else max(clock.us + 1, due))
            rt.poll()
            for sif in FrameDecoder().feed(b"".join(rt.take_frames()[1])):
                stamps.append(struct.unpack_from("<Q", sif.payload)[0])

    def configure(hz: float) -> int:
        answer = call_runtime(rt, "a2jConfigSet", bytes((0, rate.index)) + rate.to_wire(hz))
        assert answer == (0, b""), answer
        return clock.us

    run(200_000)
    assert len(stamps) >= 3
    changed = configure(200)
    run(200_000)
    after = [s for s in stamps if s > changed]
    assert 0 < after[0] - changed <= 5_000  # the new period (5 ms)
    # (on the old samples' phase: the first gap may be shorter)
    assert 0 < after[1] - after[0] <= 5_000
    assert {b - a for a, b in itertools.pairwise(after[1:])} == {5_000}
    changed = configure(2)
    run(1_200_000)
    later = [s for s in stamps if s > changed]
    assert 0 < later[0] - changed <= 5_000  # (the sample already due: the old period's)
    assert {b - a for a, b in itertools.pairwise(later)} == {500_000} and len(later) == 3


def test_the_2014_firmware_is_not_configurable_and_keeps_working(serve: Any) -> None:
    rt = make_sim("original", 1)
    server = serve(rt, "tcp://127.0.0.1:0")
    with Board.open(server.url) as board:
        with pytest.raises(NotConfigurable, match="2014 firmware"):
            board.config()
        assert board.call("a2jEcho", b"ok").payload == b"ok"


@pytest.mark.parametrize(
    ("blob", "said"),
    [
        (b"config/2\n", "not config/1"),
        (b"config/1\nx;bool;1;;\n", "not transducer.key"),
        (b"config/1\na.b;float;1;5..1;\n", "limits"),
        (b"config/1\na.b;enum;c;a|b;\n", "enum"),
        (b"config/1\na.b;enum;a;a|\x1b[2Jb;\n", "not printable"),  # (issue 43.6)
        (b"config/1\na.b;int;1;0..9\n", "line 2"),
        (b"config/1\na.b;int;1e400;0..9;\n", "default"),  # (issue 43.8: OverflowError)
        (b"config/1\na.b;float;-inf;0..9;\n", "default"),
        (b"config/1\na.b;bool;1;;\na.b;bool;1;;\n", "twice"),
        (b"\xff\xfe", "not UTF-8"),
        (b"config/1\n" + b"a.b;bool;1;;\n" * 3000, "over"),
    ],
)
def test_a_key_table_from_a_board_is_checked(blob: bytes, said: str) -> None:
    with pytest.raises(BoardError, match=said):
        parse_keys(blob, "hostile")


def test_a_board_answering_garbage_is_an_error_and_the_session_lives(serve: Any) -> None:
    """A board whose a2jConfigGet answers a reply that does not fit its table: a clear error
    naming the board, nothing changed; the daemon publishes its samples all the same."""
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config

    rt = make_sim("thesis", 1)
    rt.functions[rt.index["a2jConfigGet"]] = ("a2jConfigGet", 0, lambda p: (0, b"\x00\x09\x00"))
    server = serve(rt, "tcp://127.0.0.1:0")
    with Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        got: list[object] = []
        d.subscribe("/thesis/quad", got.append)
        assert d.wait_until_up(10)
        st = d.status()[0]
        assert "configuration unreadable" in st["warnings"], st
        with pytest.raises(BoardError, match="does not fit"):
            d.configure("thesis", {"dist_ir.rate_hz": 5})
        assert wait_for(lambda: got, 5) and d.status()[0]["state"] == "up"
