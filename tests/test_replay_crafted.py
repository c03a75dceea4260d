"""A crafted recording cannot crash ``replay`` (issue 43.8): a real recording (two virtual
boards, a configuration change on the way: test_replay.py's) rewritten with the ``mcap``
package's own writer (tests/replay_craft.py), its configuration records given values no board
could have had.  Before, ``failsafe_ms = "1e400"`` in the first record was an OverflowError
traceback, and in a later change it ended the board's thread where the change was due, while
the process went on to exit 0 having sent a part of the samples.  Now such a record is counted
and skipped where the recording is read (the replay says so), what still cannot be played is
counted and skipped where it is played, and a replay whose board stopped serving ends and exits
non-zero."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from missing_link.cli.common import EXIT_FAIL
from missing_link.cli.replay import _serve
from missing_link.ros.board_record import (
    CONFIG_TYPE,
    DESCRIPTION_TYPE,
    STAMPS_TYPE,
    ConfigRecord,
    config_cdr,
    config_from_cdr,
    description_cdr,
    description_from_cdr,
)
from missing_link.ros.clock import ClockRecord
from missing_link.virtual import recording
from missing_link.virtual.recording import PairStats, open_recording, recorded_sifs
from missing_link.virtual.replay_clock import KNOT_NS, ClockKnots
from missing_link.virtual.replay_serve import Replay

from .replay_craft import craft
from .test_replay import recorded, replay_and_record  # noqa: F401 - (recorded: a fixture)

pytestmark = pytest.mark.slow  # (the recording: seconds of real time)
Edit = Callable[[ConfigRecord], ConfigRecord]


def _value(key: str, value: str) -> Edit:
    def edit(c: ConfigRecord) -> ConfigRecord:
        values = tuple(value if n == key else v for n, v in zip(c.names, c.values, strict=True))
        return ConfigRecord(c.board, c.keys, c.names, values)

    return edit


def _keys(edit_text: Callable[[str], str]) -> Edit:
    return lambda c: ConfigRecord(c.board, edit_text(c.keys), c.names, c.values)


def crafted(src: Path, dest: Path, board: str, which: int, edit: Edit) -> Path:
    """``src`` with the ``which``-th configuration record of ``board`` (0: as the recording
    began; -1: its last change) changed by ``edit``."""
    seen: list[int] = []
    total = sum(1 for c in _configs(src) if c.board == board)
    at = which % total

    def rewrite(kind: str, topic: str, t: int, data: bytes) -> list[tuple[str, int, bytes]]:
        if kind == CONFIG_TYPE:
            c = config_from_cdr(data)
            if c.board == board:
                seen.append(t)
                if len(seen) - 1 == at:
                    data = config_cdr(edit(c))
        return [(topic, t, data)]

    return craft(src, dest, rewrite)


def _configs(src: Path) -> list[ConfigRecord]:
    out: list[ConfigRecord] = []

    def keep(kind: str, topic: str, t: int, data: bytes) -> list[tuple[str, int, bytes]]:
        if kind == CONFIG_TYPE:
            out.append(config_from_cdr(data))
        return []

    craft(src, src.parent / "scratch.mcap", keep)
    return out


BAD: dict[str, tuple[str, Edit]] = {
    "failsafe_ms 1e400": ("board_a", _value("servo.failsafe_ms", "1e400")),
    "failsafe_ms -1e400": ("board_a", _value("servo.failsafe_ms", "-1e400")),
    "failsafe_ms nan": ("board_a", _value("servo.failsafe_ms", "nan")),
    "failsafe_ms 400 digits": ("board_a", _value("servo.failsafe_ms", "9" * 400)),
    "failsafe_ms 0.5": ("board_a", _value("servo.failsafe_ms", "0.5")),
    "safe not a choice": ("board_a", _value("servo.safe", "\x1b[2Jevil")),
    "rate_hz inf": ("board_b", _value("dist_ir.rate_hz", "inf")),
    "a default of 1e400": ("board_a", _keys(lambda k: k.replace(";500;", ";1e400;", 1))),
    "a key table of junk": ("board_b", _keys(lambda k: "config/1\nx;y\n")),
}


@pytest.mark.parametrize("which", [0, -1], ids=["first", "last"])
@pytest.mark.parametrize("bad", sorted(BAD))
def test_a_bad_configuration_record_is_counted_and_skipped(
    recorded: Path,  # noqa: F811 - (the fixture)
    tmp_path: Path,
    bad: str,
    which: int,
) -> None:
    board, edit = BAD[bad]
    path = crafted(recorded, tmp_path / "crafted.mcap", board, which, edit)
    rec = open_recording([str(path)])  # (before: OverflowError for the first record)
    assert rec.damaged == 1, bad
    assert all(c.board != board or not _is(c, edit) for _t, c in rec.boards[board].configs)


def _is(c: ConfigRecord, edit: Edit) -> bool:
    return edit(c) == c  # (a record the edit would not change is not the crafted one)


@pytest.mark.parametrize(
    ("board", "which", "key"),
    [("board_a", 0, "servo.failsafe_ms"), ("board_b", -1, "dist_ir.rate_hz")],
    ids=["first", "a change"],
)
def test_a_bad_record_costs_the_replay_nothing_else(
    recorded: Path,  # noqa: F811 - (the fixture)
    tmp_path: Path,
    board: str,
    which: int,
    key: str,
) -> None:
    """board_a's first configuration, or the change of board_b's rate, crafted to 1e400:
    every sample of both boards is played (before: the first was a traceback; the change
    ended board_b's thread where it was due, a part of its samples sent)."""
    path = crafted(recorded, tmp_path / "crafted.mcap", board, which, _value(key, "1e400"))
    replay, again = replay_and_record(path, tmp_path / "again")
    assert replay.recording.damaged == 1
    for b in replay.boards:
        assert b.runtime.sent == b.recorded.samples and not b.error, b.summary()
    assert again  # (and a daemon recorded them: replay_and_record waited for every one)


@pytest.mark.parametrize("prop", ["board.model", "clock.epoch", "other"])
def test_a_description_no_board_could_give_is_counted_and_skipped(
    recorded: Path,  # noqa: F811 - (the fixture)
    tmp_path: Path,
    prop: str,
) -> None:
    """A NUL in a property of board_b's description (which its replay would serve as the board's
    own): board_b is left out, counted, and board_a is replayed (before: ValueError from the
    replayed board's runtime for the whole replay)."""

    def edit(kind: str, topic: str, t: int, data: bytes) -> list[tuple[str, int, bytes]]:
        if kind == DESCRIPTION_TYPE:
            d = description_from_cdr(data)
            if d.board == "board_b":
                props = (*((k, v) for k, v in d.properties if k != prop), (prop, "a\0b"))
                data = description_cdr(replace(d, properties=props))
        return [(topic, t, data)]

    path = craft(recorded, tmp_path / "crafted.mcap", edit)
    rec = open_recording([str(path)])
    assert rec.damaged >= 1 and list(rec.boards) == ["board_a"]
    replay = Replay([str(path)], listen="tcp://127.0.0.1:0")
    replay.stop()
    assert [b.name for b in replay.boards] == ["board_a"]


def test_a_replay_whose_board_stopped_serving_ends_and_fails(
    recorded: Path,  # noqa: F811 - (the fixture)
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Whatever ends a board's server (here: a bug in its runtime, hit by the host's input)
    ends the replay, said, with EXIT_FAIL (before: the process went on, and exited 0).  The
    fault comes with the host's first bytes, so the board serves until a host is connected:
    a fault at the first turn closed the listener before the test could connect (1 in 20
    beside a busy process)."""
    replay = Replay([str(recorded)], listen="tcp://127.0.0.1:0", lead_s=0.5)
    board = replay.boards[0]

    def broken(*_a: Any) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(board.runtime, "feed", broken)
    replay.start()
    try:
        host, port = board.server.url.split("//")[1].split(":")
        with socket.create_connection((host, int(port))) as s:
            s.sendall(b"\x12\x00\x00\x00\x00")  # (any input: the board feeds it to its runtime)
            assert _serve(replay, threading.Event()) == EXIT_FAIL
            assert s.recv(1) == b"", "the stopped board's connection is still open"
    finally:
        replay.stop()
    assert not board.thread.is_alive()
    err = capsys.readouterr().err
    assert f"{board.name} stopped serving: RuntimeError: a bug" in err, err


def without_stamps(kind: str, topic: str, t: int, data: bytes) -> list[tuple[str, int, bytes]]:
    return [] if kind == STAMPS_TYPE else [(topic, t, data)]


def _played(path: Path, board: str) -> tuple[list[tuple[Any, ...]], PairStats]:
    stats = PairStats()
    rec = open_recording([str(path)])
    out = [(s.log_ns, s.seq, s.board_us, s.raw) for s in recorded_sifs(rec, board, stats)]
    return out, stats


def test_samples_stream_in_bounded_memory_whatever_the_file_holds(
    recorded: Path,  # noqa: F811 - (the fixture)
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """(issue 43.10: a recording whose samples have no board stamps was held whole: 7.8 MB
    made 202 MB; bench/bench_replay.py measures it)"""
    full, st = _played(recorded, "board_b")
    assert full and st.unstamped == st.unmatched == 0
    bare = craft(recorded, tmp_path / "bare.mcap", without_stamps)
    monkeypatch.setattr(recording, "MAX_WAITING", 100)
    got, st = _played(bare, "board_b")
    assert got == [] and st.unstamped == len(full) and st.held_max == 100
    # fewer than a chunk's samples may wait: what cannot wait is given up, with its other
    # half, and every pair played is a true one
    monkeypatch.setattr(recording, "MAX_WAITING", 10)
    got, st = _played(recorded, "board_b")
    assert got and set(got) <= set(full), "a sample paired with another's stamps"
    assert len(got) + st.unstamped == len(full) and st.held_max == 10


def test_the_boards_wait_within_one_budget(
    recorded: Path,  # noqa: F811 - (the fixture)
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Each board's feeder reads the file on its own thread: the places for samples waiting
    for their stamps are counted for all of them together (a file of many boards whose stamps
    never come holds MAX_WAITING samples, not as many a board), and given back whatever ends
    a pass."""
    monkeypatch.setattr(recording, "MAX_WAITING", 10)
    rec = open_recording([str(recorded)])
    st_a, st_b = PairStats(), PairStats()
    a = recorded_sifs(rec, "board_a", st_a)
    next(a)  # (suspended at a pair: the samples that still wait hold their places)
    held_a = rec.waiting.taken
    assert 0 < held_a <= 10
    list(recorded_sifs(rec, "board_b", st_b))
    assert st_b.held_max <= 10 - held_a and rec.waiting.taken == held_a
    a.close()
    assert rec.waiting.taken == 0
    st_b = PairStats()  # (board_b alone: every place its own)
    assert list(recorded_sifs(rec, "board_b", st_b)) and st_b.held_max == 10


def test_a_recorded_clock_costs_its_knots_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Clock records come one by one into knots (one per stretch of KNOT_NS per boot), at most
    MAX_KNOTS of them: a recording of any length, or one of nothing but clock records, holds
    no more."""
    monkeypatch.setattr(ClockKnots, "MAX_KNOTS", 50)
    knots = ClockKnots()
    step = KNOT_NS // 4
    for i in range(1000):  # (four exchanges a stretch: 250 stretches, one boot)
        t = i * step
        knots.add(ClockRecord(t, t // 1000, t // 1000 + 5, t + 20_000, 10_000, 10_000,
                              t // 1000, t, 0.0, 100.0, 10.0, 8, "ep", 0))  # fmt: skip
    assert knots.knots == 50 and knots.left_out == 1000 - 50 * 4
    model = knots.model((0, 0))
    assert len(model.boots) == 1 and len(model.boots[0].knots_h) == 50
