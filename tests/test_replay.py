"""``missing-link replay``: a recording played back as the boards that made it.

Real replays: in-process (a daemon records real virtual boards, the replay serves them over
TCP, a second daemon records the replay) and, marked slow, the demo in its own processes over
ptys: recorded, replayed at 1x and 10x, and cut by SIGKILL, recovered and replayed.  (What a
recording keeps for a replay, and the recorded clock: test_replay_records.py.)"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.descriptors import parse_transds
from missing_link.j2a.codec import SOF, encode_frame
from missing_link.publishers.mcap import McapPublisher
from missing_link.topics import Topic, Update
from missing_link.virtual import make_sim, start_board_thread
from missing_link.virtual import replay as replay_mod
from missing_link.virtual.faults import FaultRelay, Faults
from missing_link.virtual.replay import BACKLOG, NOBODY, READY_EXCHANGES
from missing_link.virtual.replay_serve import Replay

from .helpers import ml, wait_for
from .test_replay_records import STORE


# ---- real replays, in-process -----------------------------------------------------------------
def read_bag(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    """Topic -> [(log time, message)] with rosbags' reader (shares nothing with ours)."""
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([bag], default_typestore=STORE) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def values(bag: dict[str, list[tuple[int, Any]]]) -> dict[str, list[tuple[Any, ...]]]:
    """Per thesis-format topic the values in order (N/A: the N/A value, as recorded)."""
    return {
        topic: [tuple(v.item() for v in m.values) for _t, m in msgs]
        for topic, msgs in bag.items()
        if msgs and hasattr(msgs[0][1], "values") and hasattr(msgs[0][1], "times")
        and not topic.endswith("/cmd")
    }  # fmt: skip


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Two real virtual boards over TCP, recorded for about two seconds by a real daemon, with
    servo commands and a configuration change on the way."""
    out = tmp_path_factory.mktemp("original")
    servers = [start_board_thread(make_sim(s, seed=3), "tcp://127.0.0.1:0")[0]
               for s in ("encoder_servo", "rangers")]  # fmt: skip
    cfg = Config(boards=[BoardSpec(s.url) for s in servers], publishers=["bus", "mcap"],
                 publisher_options={"mcap": {"path": str(out), "prefix": "orig"}})  # fmt: skip
    try:
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            for k in range(8):
                d.send("/board_a/servo/cmd", 10 * k)
                time.sleep(0.12)
            d.configure("board_b", {"dist_ir.rate_hz": 20})
            time.sleep(1.0)
    finally:
        for s in servers:
            s.stop()
    (bag,) = out.glob("orig_*")
    yield bag


def replay_and_record(
    bag: Path, out: Path, *, then: Any = None, **kw: Any
) -> tuple[Replay, dict[str, list[tuple[int, Any]]]]:
    """Replay ``bag`` over TCP and record it with a real daemon until every sample is in."""
    replay = Replay([str(bag)], listen="tcp://127.0.0.1:0", lead_s=0.5, **kw).start()
    cfg = Config(boards=[BoardSpec(b.server.url) for b in replay.boards],
                 publishers=["bus", "mcap"],
                 publisher_options={"mcap": {"path": str(out), "prefix": "again"}})  # fmt: skip
    try:
        with Daemon(cfg) as d:
            assert d.wait_until_up(10), d.status()
            if then is not None:
                then(d, replay)
            assert wait_for(lambda: replay.finished, 30), [b.summary() for b in replay.boards]
            sent = sum(b.runtime.sent for b in replay.boards)
            assert wait_for(lambda: _sifs_in(d) >= sent, 10), (sent, d.status())
    finally:
        replay.stop()
    (again,) = out.glob("again_*")
    return replay, read_bag(again)


def _sifs_in(d: Daemon) -> int:
    """SIFs the daemon published on thesis topics (frames minus call replies would be rougher)."""
    mcap = next(p for p in d.publishers if p.name == "mcap")
    by_topic: dict[str, int] = getattr(mcap, "messages_by_topic", {})
    return sum(n for t, n in by_topic.items() if t.count("/") == 2 and not t.endswith(
        ("/clock", "/stamps", "/description", "/config")))  # fmt: skip


@pytest.mark.slow  # (seconds of real time)
def test_a_replay_is_the_recording_again(recorded: Path, tmp_path: Path) -> None:
    original = read_bag(recorded)

    def command(d: Daemon, replay: Replay) -> None:
        runtime = next(b for b in replay.boards if b.name == "board_a").runtime
        for want, v in enumerate((40, -40, 7), 1):  # an application's commands reach the servo
            d.send("/board_a/servo/cmd", v)
            assert wait_for(lambda n=want: runtime.commands.get("servo", 0) >= n, 5)

    replay, again = replay_and_record(recorded, tmp_path, then=command)
    before, after = values(original), values(again)
    assert set(before) == set(after) and len(before) >= 4
    for topic in before:
        assert after[topic] == before[topic], topic
    # the standard types a replay derives again: as many
    for topic in ("/board_a/servo/joint_states", "/board_b/dist_ir/range"):
        assert len(again[topic]) == len(original[topic]) > 0
    # the board as it was: descriptions (functions, properties, descriptors), configuration
    for board in ("board_a", "board_b"):
        (_, d1), *_ = original[f"/{board}/description"]
        (_, d2), *_ = again[f"/{board}/description"]
        assert list(d2.functions) == list(d1.functions)
        assert list(d2.property_values) == list(d1.property_values)  # (the epoch too)
        assert d2.transds == d1.transds
    assert again["/board_b/config"][0][1].values == original["/board_b/config"][0][1].values
    changed = original["/board_b/config"][-1][1]  # (the change to 20 Hz)
    assert dict(zip(changed.names, changed.values, strict=True))["dist_ir.rate_hz"] == "20.0"
    # commands: the originals stay in the original, the new ones are in the new recording
    assert [m.values[0] for _t, m in original["/board_a/servo/cmd"]] == [10 * k for k in range(8)]
    assert [m.values[0] for _t, m in again["/board_a/servo/cmd"]] == [40, -40, 7]
    summary = {b.name: b.summary() for b in replay.boards}
    assert "3 command(s) taken (servo 3)" in summary["board_a"], summary


@pytest.mark.slow  # (seconds of real time)
def test_a_replayed_board_takes_configuration_and_says_what_it_cannot(
    recorded: Path, tmp_path: Path
) -> None:
    got: dict[str, Any] = {}

    def configure(d: Daemon, replay: Replay) -> None:
        got["before"] = d.board_config("board_b")
        # the change the recording's host made, at its time
        assert wait_for(lambda: d.board_config("board_b")["dist_ir.rate_hz"] == 20, 10)
        got["after"] = d.configure("board_b", {"dist_us.enabled": False, "dist_ir.rate_hz": 5})
        got["fn"] = d.call("board_b", "a2jConfigSet", b"\x01")  # a save: no storage
        got["trigger"] = d.call("board_b", "setTrigger", bytes(8))

    replay, again = replay_and_record(recorded, tmp_path, then=configure, boards=["board_b"])
    (board,) = replay.boards
    assert got["before"]["dist_ir.rate_hz"] == 25  # as recorded when it began
    assert got["after"]["dist_us.enabled"] is False and got["after"]["dist_ir.rate_hz"] == 5
    assert got["fn"].code == 1 and b"no storage" in got["fn"].payload
    assert got["trigger"].code == 0xFF and b"not reproduced" in got["trigger"].payload
    assert board.runtime.withheld > 0  # the disabled transducer's samples were not sent
    original = values(read_bag(recorded))
    assert len(values(again)["/board_b/dist_us"]) < len(original["/board_b/dist_us"])
    # what was sent is what was recorded, in order: the rate changed nothing in the samples
    assert values(again)["/board_b/dist_ir"] == original["/board_b/dist_ir"]


@pytest.mark.slow  # (seconds of real time)
def test_faults_in_front_of_a_replayed_board(recorded: Path) -> None:
    """The fault relay between the daemon and a replayed board: damage is counted, the board
    stays up and samples go on (values are not compared: a damaged frame passes the 8-bit
    checksum once in 256)."""
    replay = Replay([str(recorded)], listen="tcp://127.0.0.1:0", boards=["board_a"],
                    lead_s=0.3).start()  # fmt: skip
    got: list[Update] = []
    try:
        relay = FaultRelay(replay.boards[0].server.url, Faults(corrupt=3e-4, seed=5))
        with relay, Daemon(Config(boards=[BoardSpec(relay.url)], publishers=["bus"])) as d:
            # before it is up: a reply the relay damaged costs the daemon its 1 s call timeout,
            # and the samples it publishes meanwhile must not go to nobody
            d.subscribe("/board_a/quad", got.append, queue=0)
            assert d.wait_until_up(10)
            assert wait_for(lambda: replay.finished, 30)
            status = d.status()[0]
    finally:
        replay.stop()
    assert relay.corrupted > 0
    assert status["bad_checksums"] + status["bad_escapes"] + status["cut_frames"] > 0, status
    assert got and status["state"] == "up", status


@contextmanager
def turned_replay(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[tuple[Any, list[int], Callable[[str], list[bytes]]]]:
    """The recording's board_a as a replay on a fake clock (``now[0]``: its monotonic ns), all
    of it read ahead and its own thread not started: ``turn(name)`` feeds a call of ``name``,
    polls once and gives the SIFs that went."""
    now = [10**15]
    monkeypatch.setattr(replay_mod, "time", SimpleNamespace(monotonic_ns=lambda: now[0]))
    replay = Replay([str(recorded)], listen="tcp://127.0.0.1:0", boards=["board_a"], lead_s=0.3)
    (board,) = replay.boards
    rt = board.runtime
    board.feeder.thread.start()  # (the board's own thread is not: this test turns it)
    try:
        assert wait_for(lambda: not board.feeder.thread.is_alive(), 10)  # (all read ahead)

        def turn(name: str) -> list[bytes]:
            rt.feed(encode_frame(SOF, 1, rt.index[name]))
            rt.poll()
            return list(rt.take_frames()[1])

        yield rt, now, turn
    finally:
        replay.stop()


@pytest.mark.slow  # (the recording)
def test_a_host_that_came_back_late_gets_its_lead_before_samples(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A daemon whose handshake lost a reply comes back after the recording's start (its 1 s
    call timeout, a new connection): samples are due when it has synced, but it takes none
    until it listens (it reads the board's count of SIFs then: what comes earlier is dropped).
    The board holds them until then, then sends them, late, in order, as fast as it reads
    them.  (A fake clock.)"""
    with turned_replay(recorded, monkeypatch) as (rt, now, turn):
        rt.new_host(1)
        assert turn("a2jGetMapping") == []  # the recording starts 0.3 s after this
        rt.backlog, now[0] = NOBODY, now[0] + 1_100_000_000  # no reply: it went, 1.1 s on
        rt.poll()
        assert rt.take_frames()[1] == []
        rt.new_host(2)
        rt.backlog = 0
        assert turn("a2jGetMapping") == []
        assert [sif for _ in range(READY_EXCHANGES) for sif in turn("a2jClock")] == []
        now[0] += 300_000_000
        rt.poll()
        assert rt.take_frames()[1] == [] and rt.sent == 0
        turns = [turn("a2jSifCount")]  # it listens: what is due goes, paced by what the host
        rt.backlog = 0  # reads (the link's queue would shed the rest)
        while sifs := (rt.poll(), rt.take_frames()[1])[1]:
            turns.append(sifs)
            rt.backlog = 0  # (it read them)
        assert all(sum(map(len, sifs[:-1])) <= BACKLOG for sifs in turns), len(turns)
        assert sum(map(len, turns)) == rt.sent and 0 < rt.late < rt.sent  # (due 0..1.1 s ago)


@pytest.mark.slow  # (the recording)
def test_samples_wait_until_the_host_listens_however_slow_it_is(
    recorded: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A daemon listens for SIFs from before it reads the board's count (a2jSifCount): the
    board sends none before that, however long the daemon's setup takes after it has synced (a
    busy machine: the demo's replay once started at other values), and all that are due right
    after.  A handshake again on the same pty (its hosts come and go unseen) is a new host,
    which waits too.  (A fake clock.)"""
    with turned_replay(recorded, monkeypatch) as (rt, now, turn):
        rt.new_host(1)
        rt.backlog = 0
        assert turn("a2jGetMapping") == []
        assert [sif for _ in range(READY_EXCHANGES) for sif in turn("a2jClock")] == []
        now[0] += 5_000_000_000  # synced, its lead long over: its setup takes seconds
        assert turn("a2jGetProperties") == [] and rt.sent == 0
        assert turn("a2jSifCount") != []  # it listens: what is due goes
        sent, rt.backlog = rt.sent, 0  # (it read them)
        assert turn("a2jGetMapping") == []  # (a host again, on the same pty)
        assert [sif for _ in range(READY_EXCHANGES) for sif in turn("a2jClock")] == []
        now[0] += 2_000_000_000
        assert turn("a2jClock") == [] and rt.sent == sent
        assert turn("a2jSifCount") != []


@pytest.mark.slow  # (seconds of real time)
def test_a_looped_replay_is_a_board_that_restarts(recorded: Path, tmp_path: Path) -> None:
    replay = Replay([str(recorded)], listen="tcp://127.0.0.1:0", boards=["board_b"], rate=4,
                    loop=True, lead_s=0.3).start()  # fmt: skip
    try:
        with Daemon(Config(boards=[BoardSpec(replay.boards[0].server.url)])) as d:
            assert d.wait_until_up(10)
            runtime = replay.boards[0].runtime
            assert wait_for(lambda: runtime.passes >= 2, 20), runtime.passes
            assert wait_for(lambda: d.status()[0].get("sync_resets", 0) >= 1, 10), d.status()
            assert d.status()[0]["state"] == "up"
    finally:
        replay.stop()
    assert not replay.finished


# ---- the command line -------------------------------------------------------------------------
def one_line(r: subprocess.CompletedProcess[str], code: int) -> str:
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    (line,) = [ln for ln in r.stderr.splitlines() if ln.startswith("missing-link: error:")]
    return line


@pytest.mark.slow
def test_what_cannot_be_replayed_is_one_line(recorded: Path, tmp_path: Path) -> None:
    assert "no such file" in one_line(ml("replay", str(tmp_path / "nothing")), 2)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    assert "not an MCAP file" in one_line(ml("replay", str(junk)), 2)
    assert "no board nope" in one_line(ml("replay", str(recorded), "--board", "nope"), 2)
    r = ml("replay", str(recorded), "--listen", "tcp://127.0.0.1:5")
    assert "tcp://HOST:0" in one_line(r, 2)
    r = ml("replay", str(recorded), "--rate", "0")
    assert r.returncode == 2 and "must be a number > 0" in r.stderr
    # a recording made without what a replay needs
    (t,) = parse_transds("transds/1\nx,0,p,M,1,int32_t,-1\n")
    topic = Topic.for_transducer("/b/x", "b", t, "missing_link_msgs")
    pub = McapPublisher({"path": str(tmp_path / "plain"), "replay": False})
    pub.add_topic(topic)
    pub.publish(
        Update.build(
            topic=topic, board_us=[1], host_ns=[10**18], values=[5], seq=0, lost=0, recv_ns=0
        )
    )
    pub.close()
    assert "no board description" in one_line(ml("replay", str(pub.bags[0])), 2)
