"""The daemon: topics from descriptors, the bus, actuators, reconnects, diagnostics, recording
read back by independent readers (rosbags AnyReader and the mcap library), crash recovery."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from missing_link.daemon import Daemon, connect
from missing_link.daemon.config import BoardSpec, Config, ConfigError, load_config, parse_config
from missing_link.topics import Update
from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ML, ml, wait_for

Serve = Any


def test_two_lines_give_an_application_its_board(serve: Serve) -> None:
    server = serve("thesis")
    robot = connect(server.url)
    try:
        got: list[Update] = []
        robot.subscribe("/thesis/dist_ir", got.append)
        assert wait_for(lambda: len(got) >= 5)
        u = got[-1]
        assert u.topic.type_name == "missing_link_msgs/msg/DistIr"
        assert len(u.values) == 8 and len(u.board_us) == 8
        assert all(v is None or 200 <= v <= 1500 for v in u.values)
        assert all((ns == 0) == (v is None) for ns, v in zip(u.host_ns, u.values, strict=True))
        assert sorted(robot.bus.topics) == [
            "/thesis/dist_ir",
            "/thesis/dist_ir/range",
            "/thesis/dist_us",
            "/thesis/dist_us/range",
            "/thesis/quad",
            "/thesis/quad/joint_states",
            "/thesis/servo",
            "/thesis/servo/joint_states",
            "/thesis/trigger",
        ]
        assert robot.bus.command_topics == ["/thesis/servo/cmd", "/thesis/servo/command"]
    finally:
        robot.stop()


def test_actuator_command_reaches_the_board(serve: Serve) -> None:
    server = serve("thesis")
    with Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        assert d.wait_until_up()
        seen: list[int] = []
        d.subscribe("/thesis/servo", lambda u: seen.append(u.values[0]))
        d.send("/thesis/servo/cmd", -100)
        # The servo reports its position while it slews to the commanded -100.
        assert wait_for(lambda: seen and seen[-1] == -100, 5)
        assert d.status()[0]["commands"] == 1
        with pytest.raises(ValueError, match=r"servo: 500 is beyond int8_t \(-128..127\)"):
            d.send("/thesis/servo/cmd", 500)
        with pytest.raises(KeyError, match="no actuator listens on '/thesis/quad/cmd'"):
            d.send("/thesis/quad/cmd", 1)


def test_pattern_subscription_and_remap(serve: Serve) -> None:
    server = serve("thesis")
    cfg = Config(boards=[BoardSpec(server.url, name="front")], remap={"/front/quad": "/wheels"})
    with Daemon(cfg) as d:
        names: set[str] = set()
        d.subscribe("/front/*", lambda u: names.add(u.topic.name))
        wheels: list[Update] = []
        d.subscribe("/wheels", wheels.append)
        assert wait_for(lambda: {"/front/dist_ir", "/front/dist_us"} <= names and wheels)
        assert "/front/quad" not in names


@pytest.mark.slow
def test_broken_board_does_not_stop_others_and_reconnects(serve: Serve) -> None:
    good = serve("rangers")
    proc, url = start_board_process("encoder_servo", 2, "tcp://127.0.0.1:0")
    port = url.rsplit(":", 1)[1]
    cfg = Config(boards=[BoardSpec(good.url), BoardSpec(url)], backoff_min=0.05, backoff_max=0.2)
    try:
        with Daemon(cfg) as d:
            assert d.wait_until_up()
            counts = {"ir": 0}
            d.subscribe("/board_b/dist_ir", lambda u: counts.__setitem__("ir", counts["ir"] + 1))
            proc.kill()  # board A disappears
            proc.wait()
            assert wait_for(lambda: d.status()[1]["state"] in ("backoff", "connecting"))
            before = counts["ir"]
            assert wait_for(lambda: counts["ir"] > before + 5)  # board B carries on
            assert d.status()[0]["state"] == "up"
            proc, url2 = start_board_process("encoder_servo", 2, f"tcp://127.0.0.1:{port}")
            assert url2 == url
            assert wait_for(
                lambda: d.status()[1]["state"] == "up" and d.status()[1]["connects"] == 2
            )
            assert "link lost" in d.status()[1]["error"] or d.status()[1]["error"] == ""
    finally:
        stop_process(proc)


def test_original_board_with_host_descriptors(serve: Serve) -> None:
    server = serve("original")
    cfg = Config(boards=[BoardSpec(server.url, descriptors="examples/original-board.toml")])
    with Daemon(cfg) as d:
        got: list[Update] = []
        d.subscribe("/original/quad", got.append)
        assert wait_for(lambda: len(got) > 3)
    cfg = Config(boards=[BoardSpec(server.url)], backoff_min=0.05)
    with Daemon(cfg) as d:
        assert wait_for(lambda: "without descriptors" in d.status()[0]["error"])


def test_recording_read_back_by_independent_readers(serve: Serve, tmp_path: Path) -> None:
    server = serve("thesis")
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "mcap"],
        publisher_options={"mcap": {"path": str(tmp_path)}},
        diagnostics_period=0.2,
    )
    with Daemon(cfg) as d:
        counts: dict[str, int] = {}
        d.subscribe(
            "/thesis/*", lambda u: counts.__setitem__(u.topic.name, counts.get(u.topic.name, 0) + 1)
        )
        assert wait_for(lambda: counts.get("/thesis/dist_us", 0) > 20)
        mcap = d.publishers[1]
    (bag,) = mcap.bags  # type: ignore[attr-defined]
    store = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([bag], default_typestore=store) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics["/thesis/dist_us"] == "missing_link_msgs/msg/DistUs"
        assert topics["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
        n = 0
        for conn, _ts, raw in reader.messages(
            [c for c in reader.connections if c.topic == "/thesis/dist_us"]
        ):
            msg = reader.deserialize(raw, conn.msgtype)
            assert len(msg.values) == 12 and len(msg.times) == 12
            n += 1
        assert n == mcap.messages_by_topic["/thesis/dist_us"]  # type: ignore[attr-defined]
    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as f:
        reader2 = make_reader(f)
        summary = reader2.get_summary()
        assert summary is not None
        schemas = {s.name for s in summary.schemas.values()}
        assert "missing_link_msgs/msg/Quad" in schemas
        assert reader2.get_header().profile == "ros2"


@pytest.mark.slow
def test_crashed_recording_is_recovered(tmp_path: Path) -> None:
    """A daemon process killed with SIGKILL mid-recording: recover salvages its messages."""
    proc, url = start_board_process("thesis", 4, "pty")
    rec = tmp_path / "rec"
    try:
        daemon = subprocess.Popen(
            [*ML, "run", url, "--record", str(rec), "-p", "bus"],
            stderr=subprocess.PIPE,
            text=True,
        )
        assert wait_for(
            lambda: (
                any(rec.glob("*/*.mcap"))
                and max(f.stat().st_size for f in rec.glob("*/*.mcap")) > 200_000
            ),
            30,
        )
        daemon.send_signal(signal.SIGKILL)
        daemon.wait(10)
    finally:
        stop_process(proc)
    (bag,) = [p for p in rec.iterdir() if p.is_dir()]
    assert not (bag / "metadata.yaml").exists()  # the writer never finished
    r = ml("recover", str(bag), timeout=60)
    assert r.returncode == 0, r.stderr
    count = int(r.stdout.split()[1])
    assert count > 100
    out = Path(str(bag) + "_recovered")
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert reader.message_count == count
        conn = next(c for c in reader.connections if c.topic == "/thesis/quad")
        _c, _t, raw = next(reader.messages([conn]))
        assert len(reader.deserialize(raw, conn.msgtype).values) == 2


@pytest.mark.slow
def test_clean_shutdown_on_sigterm_writes_complete_bag(tmp_path: Path) -> None:
    proc, url = start_board_process("rangers", 4, "pty")
    rec = tmp_path / "rec"
    try:
        r = ml("run", url, "--record", str(rec), "--duration", "1.5", timeout=60)
    finally:
        stop_process(proc)
    assert r.returncode == 0, r.stderr
    assert "recorded" in r.stderr
    (bag,) = [p for p in rec.iterdir() if p.is_dir()]
    assert (bag / "metadata.yaml").exists()


@pytest.mark.parametrize(
    ("text", "msg"),
    [
        ("[daemon]\npublisher = ['bus']\n", "daemon.publisher: unknown key"),
        ("[daemon]\ndistro = 'rolling'\n", "daemon.distro: 'rolling' is not one of"),
        ("[daemon]\npublishers = ['zenohh']\n", "unknown publisher 'zenohh'"),
        ("[[board]]\nname = 'x'\n", "[[board]] #1: missing url"),
        (
            "[[board]]\nurl = 'tcp://x:1'\ntimeout = 'fast'\n",
            "[[board]] #1.timeout: expected a number",
        ),
        ("[remap]\n'/a' = 'b'\n", "is not a topic name"),
        ("[mcapp]\npath = 'x'\n", "mcapp: unknown table"),
        ("[daemon\n", "not valid TOML"),
    ],
)
def test_config_errors_name_file_and_key(tmp_path: Path, text: str, msg: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(str(path))
    assert str(err.value).startswith(str(path)) and msg in str(err.value)


def test_example_config_is_valid() -> None:
    cfg = load_config("examples/missing-link.toml")
    assert [b.url for b in cfg.boards][1] == "usb://?serial=J2A-0001"
    assert cfg.publisher_options["mcap"]["rotate_mb"] == 1024
    assert cfg.probe_budget == 100.0 and cfg.boards[0].batch_ms == 2.0  # the defaults, said
    assert parse_config({}).publishers == ["bus"]


def test_mcap_rotation(serve: Serve, tmp_path: Path) -> None:
    server = serve("thesis")
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "mcap"],
        publisher_options={"mcap": {"path": str(tmp_path), "rotate_mb": 0.05}},
    )
    with Daemon(cfg) as d:
        mcap = d.publishers[1]
        assert wait_for(lambda: len(mcap.bags) >= 3, 15)  # type: ignore[attr-defined]
    for bag in mcap.bags:  # type: ignore[attr-defined]
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            assert reader.message_count > 0


def test_no_threads_left_after_stop(serve: Serve) -> None:
    server = serve("thesis")
    with Daemon(Config(boards=[BoardSpec(server.url)], publishers=["bus", "console"])) as d:
        assert d.wait_until_up()
    left = [
        t.name
        for t in threading.enumerate()
        if t.name.startswith(("session:", "j2a:", "diagnostics", "mcap"))
    ]
    assert not left


def test_pattern_subscription_after_topics_exist(serve: Serve) -> None:
    server = serve("thesis")
    with Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        assert d.wait_until_up()
        names: set[str] = set()
        d.subscribe("/thesis/dist_*", lambda u: names.add(u.topic.name))
        deep: set[str] = set()
        d.subscribe("/thesis/**/range", lambda u: deep.add(u.topic.name))
        assert wait_for(lambda: names == {"/thesis/dist_ir", "/thesis/dist_us"} and len(deep) == 2)
        assert deep == {"/thesis/dist_ir/range", "/thesis/dist_us/range"}


def test_standard_types_one_message_per_channel(serve: Serve, tmp_path: Path) -> None:
    server = serve("thesis")
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "mcap"],
        publisher_options={"mcap": {"path": str(tmp_path)}},
    )
    store = get_typestore(Stores.ROS2_JAZZY)
    with Daemon(cfg) as d:
        ir: list[Update] = []
        us: list[Update] = []
        servo: list[Update] = []
        d.subscribe("/thesis/dist_ir/range", ir.append)
        d.subscribe("/thesis/dist_us/range", us.append)
        d.subscribe("/thesis/servo/joint_states", servo.append)
        assert d.wait_until_up()
        d.send("/thesis/servo/cmd", 127)
        assert wait_for(lambda: len(ir) > 20 and len(us) > 20 and servo)
        mcap = d.publishers[1]
    frames = set()
    for u in ir[:20]:
        msg = store.deserialize_cdr(u.cdr, "sensor_msgs/msg/Range")
        assert msg.radiation_type == 1  # INFRARED
        assert (msg.min_range, msg.max_range) == (pytest.approx(0.2), pytest.approx(1.5))
        assert msg.range == pytest.approx(u.values[0] / 1000)
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == u.host_ns[0]
        frames.add(msg.header.frame_id)
    assert frames <= {f"thesis/dist_ir/{k}" for k in range(8)} and len(frames) > 1
    assert store.deserialize_cdr(us[0].cdr, "sensor_msgs/msg/Range").radiation_type == 0
    joint = store.deserialize_cdr(servo[-1].cdr, "sensor_msgs/msg/JointState")
    assert joint.name == ["thesis/servo"]
    (bag,) = mcap.bags  # type: ignore[attr-defined]
    with AnyReader([bag], default_typestore=store) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/thesis/dist_ir/range"] == "sensor_msgs/msg/Range"
        assert types["/thesis/servo/joint_states"] == "sensor_msgs/msg/JointState"


def test_unsupported_standard_type_is_reported_not_fatal(serve: Serve, tmp_path: Path) -> None:
    server = serve("original")
    desc = tmp_path / "d.toml"
    desc.write_text(
        '[[transducer]]\nname="quad"\nid=13\nprefix="quad"\nmodel="HEDS-6500"\nchan_count=1\n'
        'type="int16_t"\nna=-1\nros="sensor_msgs/msg/LaserScan"\n'
    )
    with Daemon(Config(boards=[BoardSpec(server.url, descriptors=str(desc))])) as d:
        got: list[Update] = []
        d.subscribe("/original/quad", got.append)
        assert wait_for(lambda: len(got) > 2)
        assert "ros=sensor_msgs/msg/LaserScan is not supported" in d.status()[0]["warnings"]


def test_all_na_update_is_logged_at_host_realtime() -> None:
    """An update whose channels are all N/A still gets a CLOCK_REALTIME log time."""
    import struct

    from missing_link.daemon import BoardSession
    from missing_link.descriptors import parse_transds
    from missing_link.j2a import SifReceived
    from missing_link.topics import Topic

    d = Daemon(Config())
    session = BoardSession(d.session_context(), BoardSpec("memory://unused"))
    (t,) = parse_transds("transds/1\nx,1,p,M,2,int16_t,-1\n")
    topic = Topic.for_transducer("/b/x", "b", t, "missing_link_msgs")
    session.path.topics[1] = topic
    d.bus.add_topic(topic)
    got: list[Update] = []
    d.subscribe("/b/x", got.append, queue=0)  # inline: the update is there when on_sif returns
    before = time.time_ns()
    session.path.on_sif(SifReceived(1, 0, struct.pack("<QhQh", 5, -1, 6, -1), 0), time.monotonic())
    after = time.time_ns()
    (u,) = got
    assert u.values == [None, None] and u.host_ns == [0, 0]
    assert before - 10**7 <= u.stamp_ns <= after + 10**7
    # after a sample: just after it, where the board sent it (its arrival, late on a busy
    # machine, could come after the next sample's measurement)
    session.path.on_sif(SifReceived(1, 1, struct.pack("<QhQh", 7, 3, 8, 4), 0), time.monotonic())
    time.sleep(0.01)
    session.path.on_sif(SifReceived(1, 2, struct.pack("<QhQh", 9, -1, 9, -1), 0), time.monotonic())
    measured, na = got[-2:]
    assert na.host_ns == [0, 0] and na.stamp_ns == measured.stamp_ns + 1


def test_a_topics_first_all_na_sample_is_logged_when_the_board_assembled_it() -> None:
    """A topic's first sample, all N/A, that arrives late (a busy host read it together with
    the next one) is logged where the board put it, before that next sample's measurement:
    it took its arrival, and a log-time reader (a replay's recording read back) put it after."""
    import struct

    from missing_link.daemon import BoardSession
    from missing_link.descriptors import parse_transds
    from missing_link.j2a import SifReceived
    from missing_link.timesync.exchange import Exchange
    from missing_link.timesync.sync import ClockSync, SyncOptions
    from missing_link.topics import Topic

    d = Daemon(Config())
    session = BoardSession(d.session_context(), BoardSpec("memory://unused"))
    (t,) = parse_transds("transds/1\nquad,1,p,M,1,int16_t,-1\n")
    topic = Topic.for_transducer("/b/quad", "b", t, "missing_link_msgs")
    session.path.topics[1] = topic
    session.path.realtime_offset_ns = 0  # (host times on the monotonic clock, as the map's)
    sync = ClockSync(SyncOptions(), seed=1)
    base = time.monotonic_ns() - 10**9  # the board's clock: the host's, in µs
    sync.start(base / 1e9)
    for k in range(12):  # (a clock map from exchanges of 120 µs)
        t1 = base + k * 10**7
        sync.on_exchange(Exchange(t1, t1 // 1000 + 50, t1 // 1000 + 60, t1 + 120_000), t1 / 1e9)
    session.path.sync = sync
    d.bus.add_topic(topic)
    got: list[Update] = []
    d.subscribe("/b/quad", got.append, queue=0)
    assembled, measured = base // 1000 + 200_000, base // 1000 + 300_000  # board µs
    now = time.monotonic()  # both read now, long after either
    session.path.on_sif(SifReceived(1, 0, struct.pack("<Qh", assembled, -1), 0), now)
    session.path.on_sif(SifReceived(1, 1, struct.pack("<Qh", measured, 5), 0), now)
    na, sample = got
    assert na.values == [None] and sample.values == [5]
    assert na.stamp_ns < sample.stamp_ns < int(now * 1e9)
    assert abs(na.stamp_ns - assembled * 1000) < 10**6  # (the map's error: µs)
