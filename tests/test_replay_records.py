"""``missing-link replay``: what a recording keeps for it (descriptions, configuration, board
stamps, commands: their CDR against rosbags, their place in the file) and the recorded clock as
a function again.  (Real replays: test_replay.py.)"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from missing_link.descriptors import parse_transds
from missing_link.publishers.mcap import McapPublisher
from missing_link.ros.board_record import (
    MESSAGES,
    STAMPS_TYPE,
    BoardDescription,
    ConfigRecord,
    StampsRecord,
    config_cdr,
    config_from_cdr,
    description_cdr,
    description_from_cdr,
    stamps_cdr,
    stamps_from_cdr,
    stamps_size,
)
from missing_link.ros.clock import (
    CLOCK_MSG,
    CLOCK_TYPE,
    ClockRecord,
    clock_record_cdr,
    clock_record_from_cdr,
)
from missing_link.topics import Topic, Update
from missing_link.virtual.replay_clock import Clock, ClockModel, Timeline

STORE = get_typestore(Stores.ROS2_JAZZY)
for _name, _text in {**MESSAGES, CLOCK_TYPE: CLOCK_MSG}.items():
    STORE.register(get_types_from_msg(_text, _name))
OURS = (*MESSAGES, CLOCK_TYPE, "diagnostic_msgs/msg/DiagnosticArray")

text = st.text(max_size=30)
names = st.lists(text, max_size=6)


# ---- the records ------------------------------------------------------------------------------
@given(text, text, names, st.lists(st.tuples(text, text), max_size=5), text, names)
def test_a_description_is_the_cdr_rosbags_reads(
    board: str, url: str, fns: list[str], props: list[Any], transds: str, tops: list[str]
) -> None:
    d = BoardDescription(board, url, tuple(fns), tuple(props), transds, tuple(tops))
    cdr = description_cdr(d)
    msg = STORE.deserialize_cdr(cdr, "missing_link_msgs/msg/BoardDescription")
    same = d.board.encode("utf-8", "replace").decode() == d.board
    if same and all(s.encode("utf-8", "replace").decode() == s for s in [url, transds, *fns]):
        assert (msg.board, msg.url, list(msg.functions), msg.transds) == (board, url, fns, transds)
        assert list(zip(msg.property_keys, msg.property_values, strict=True)) == props
        assert description_from_cdr(cdr) == d
        assert bytes(STORE.serialize_cdr(msg, "missing_link_msgs/msg/BoardDescription")) == cdr


@given(text, text, st.lists(st.tuples(text, text), max_size=6))
def test_a_configuration_is_the_cdr_rosbags_reads(board: str, keys: str, kv: list[Any]) -> None:
    c = ConfigRecord(board, keys, tuple(k for k, _ in kv), tuple(v for _, v in kv))
    cdr = config_cdr(c)
    msg = STORE.deserialize_cdr(cdr, "missing_link_msgs/msg/BoardConfig")
    assert len(msg.names) == len(msg.values) == len(kv)
    if all(s.encode("utf-8", "replace").decode() == s for s in [board, keys, *sum(kv, ())]):
        assert config_from_cdr(cdr) == c
        assert bytes(STORE.serialize_cdr(msg, "missing_link_msgs/msg/BoardConfig")) == cdr


@given(
    st.lists(st.tuples(st.integers(0, 2), st.integers(0, 255), st.integers(0, 2**64 - 1),
                       st.integers(-1, 2**63 - 1)), max_size=40),
)  # fmt: skip
def test_stamps_are_the_cdr_rosbags_reads(rows: list[tuple[int, int, int, int]]) -> None:
    s = StampsRecord("b", ("/b/x", "/b/y", "/b/z"), tuple(r[0] for r in rows),
                     tuple(r[1] for r in rows), tuple(r[2] for r in rows),
                     tuple(r[3] for r in rows))  # fmt: skip
    cdr = stamps_cdr(s)
    msg = STORE.deserialize_cdr(cdr, STAMPS_TYPE)
    assert list(msg.topic) == list(s.topic) and list(msg.board_us) == list(s.board_us)
    assert list(msg.bound_ns) == list(s.bound_ns)
    assert list(msg.seq) == list(s.seq) and stamps_from_cdr(cdr) == s
    assert bytes(STORE.serialize_cdr(msg, STAMPS_TYPE)) == cdr
    assert len(cdr) <= stamps_size("b", s.topics, len(rows), len(rows))


def test_stamps_recorded_before_the_bounds_were_kept_read() -> None:
    """A recording from before the samples' bounds were kept (no bound_ns at the end) replays:
    its stamps read with no bounds; bounds that do not fit the samples are a ValueError."""
    s = StampsRecord("b", ("/b/x",), (0, 0), (7, 8), (100, 200))
    old = stamps_cdr(s)[:-4]  # (the empty bound_ns array's count)
    assert stamps_from_cdr(old) == s and s.bound_ns == ()
    with pytest.raises(ValueError, match="bounds"):
        stamps_from_cdr(stamps_cdr(StampsRecord("b", ("/b/x",), (0, 0), (7, 8), (1, 2), (5,))))


@given(st.binary(max_size=80))
def test_damaged_records_are_a_value_error(data: bytes) -> None:
    for decode in (description_from_cdr, config_from_cdr, stamps_from_cdr, clock_record_from_cdr):
        try:
            decode(b"\x00\x01\x00\x00" + data)
        except ValueError:
            pass


def test_the_clock_record_reads_back() -> None:
    r = ClockRecord(1, 2, 3, 4, 5, 6, 7, 8, 9.5, 10.5, 11.5, 12, "e6f1", 2)
    assert clock_record_from_cdr(clock_record_cdr(r)) == r


# ---- the recorded clock -----------------------------------------------------------------------
def exchanges(truth: Any, hosts: list[float], epoch: str = "ep") -> list[ClockRecord]:
    """Clean exchanges against ``truth(host ns) -> board µs`` (40 µs each way), without
    estimates: the model makes its knots of their midpoints."""
    out = []
    for h in hosts:
        b = truth(h + 40_000)
        out.append(ClockRecord(round(h), math.floor(b), math.floor(b) + 5, round(h + 85_000),
                               0, 0, 0, 0, 0.0, -1.0, -1.0, 0, epoch, 0))  # fmt: skip
    return out


def test_a_recorded_clock_plays_back_with_its_offset_skew_and_reset() -> None:
    t0 = 1.7e18
    skew = 80e-6

    def before(h: float) -> float:
        return 5e9 + (h - t0) / 1e3 * (1 + skew)

    reset = t0 + 10e9

    def after(h: float) -> float:  # restarted at 0, the same crystal
        return (h - reset) / 1e3 * (1 + skew)

    hosts = [t0 + k * 0.25e9 for k in range(40)]  # 0 .. 9.75 s
    later = [reset + 0.3e9 + k * 0.25e9 for k in range(40)]
    model = ClockModel.from_records(exchanges(before, hosts) + exchanges(after, later), (0, 0))
    assert len(model.boots) == 2
    for h in (t0, t0 + 3.3e9, t0 + 9.9e9):
        assert abs(model.board_at(h) - before(h)) < 60  # µs: half the round trip at most
    for h in (reset + 1e9, reset + 9e9, reset + 20e9):  # (and beyond: at the recorded rate)
        assert abs(model.board_at(h) - after(h)) < 60
    assert reset - 0.1e9 <= model.boots[1].start_h <= reset + 0.3e9
    rate = (model.board_at(t0 + 8e9) - model.board_at(t0 + 2e9)) / 6e6
    assert abs(rate - (1 + skew)) < 5e-6

    timeline = Timeline(int(t0), int(t0 + 20e9), 4.0, 0.5, loop=True, now_ns=0)
    timeline.start(1_000)
    clock = Clock(model, timeline)
    m0 = 1_000 + 0.5e9
    assert timeline.at(int(m0)) == (0, t0)
    k, boot, b = clock.read(int(m0 + 1e9))  # 4 s of recording: pressed 4 times towards t0
    assert (k, boot) == (0, 0) and abs(b - (before(t0) + (before(t0 + 4e9) - before(t0)) / 4)) < 60
    k, boot, _ = clock.read(int(m0 + 3e9))  # 12 s: after the reset
    assert (k, boot) == (0, 1) and clock.epoch(0, 1) == "ep+1"
    k, boot, _ = clock.read(int(m0 + 5.5e9))  # 22 s: the second pass, a new boot again
    assert (k, boot) == (1, 0) and clock.epoch(1, 0) == "ep.1" != clock.epoch(0, 0)


# ---- the recorder -----------------------------------------------------------------------------
def test_each_samples_clock_bound_is_recorded_with_its_stamps(tmp_path: Path) -> None:
    """A recording keeps the hard bound each sample was published with (``Update.bound_ns``,
    -1 without a map), next to its board stamps: the clock record's bound is the estimate's, not
    the published map's, which can be ms from it while it slews (issue 42)."""
    (t,) = parse_transds("transds/1\nsonar,2,srf,SRF02,2,uint32_t,0\n")
    topic = Topic.for_transducer("/b/sonar", "b", t, "missing_link_msgs")
    pub = McapPublisher({"path": str(tmp_path)})
    pub.add_topic(topic)
    bounds = [-1, 1_234_567, 40_000]
    for i, bound in enumerate(bounds):
        pub.publish(Update.build(topic=topic, board_us=[i * 10, i * 10 + 1],
                                 host_ns=[10**18 + i * 10_000] * 2, values=[i, i], seq=i,
                                 lost=0, recv_ns=i, bound_ns=bound))  # fmt: skip
    pub.close()
    with AnyReader(list(pub.bags), default_typestore=STORE) as reader:
        conns = [c for c in reader.connections if c.topic == "/b/stamps"]
        got = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    assert [int(b) for m in got for b in m.bound_ns] == bounds
    assert [int(b) for m in got for b in m.board_us] == [0, 1, 10, 11, 20, 21]


def test_a_bound_outside_int64_is_packed_within_it(tmp_path: Path) -> None:
    """Every value is checked against its type before it is packed: a bound past int64 (or
    below -1, or not an int) is recorded as the most (or none), never a recording that fails."""
    (t,) = parse_transds("transds/1\nsonar,2,srf,SRF02,1,uint32_t,0\n")
    topic = Topic.for_transducer("/b/sonar", "b", t, "missing_link_msgs")
    pub = McapPublisher({"path": str(tmp_path)})
    pub.add_topic(topic)
    for i, bound in enumerate([5, 2**63, -7, 2**64 + 3]):
        pub.publish(Update.build(topic=topic, board_us=[i], host_ns=[10**18 + i], values=[i],
                                 seq=i, lost=0, recv_ns=i, bound_ns=bound))  # fmt: skip
    pub.close()
    assert pub.dropped == 0
    with AnyReader(list(pub.bags), default_typestore=STORE) as reader:
        conns = [c for c in reader.connections if c.topic == "/b/stamps"]
        got = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    assert [int(b) for m in got for b in m.bound_ns] == [5, 2**63 - 1, -1, 2**63 - 1]


def test_stamps_stay_in_the_chunk_of_their_samples(tmp_path: Path) -> None:
    """Past rosbags' 1 MiB chunks: every chunk holds its samples' stamps, so a file cut anywhere
    keeps both or neither."""
    (t,) = parse_transds("transds/1\nsonar,2,srf,SRF02,12,uint32_t,0\n")
    topic = Topic.for_transducer("/b/sonar", "b", t, "missing_link_msgs")
    pub = McapPublisher({"path": str(tmp_path), "chunk_s": 3600})
    pub.add_topic(topic)
    n = 30_000  # ~5 MiB of samples and stamps
    for i in range(n):
        pub.publish(
            Update.build(
                topic=topic,
                board_us=[i * 7 + c for c in range(12)],
                host_ns=[10**18 + i * 1000] * 12,
                values=[i % 5000 + c for c in range(12)],
                seq=i & 0xFF,
                lost=0,
                recv_ns=i,
            )
        )
    pub.close()
    assert pub.dropped == 0 and pub.messages_by_topic["/b/sonar"] == n
    (f,) = pub.bags[0].glob("*.mcap")
    chunks = 0
    channels: dict[int, str] = {}
    with open(f, "rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if not isinstance(record, Chunk):
                if hasattr(record, "topic"):
                    channels[record.id] = record.topic
                continue
            chunks += 1
            inside = breakup_chunk(record)
            for r in inside:
                if hasattr(r, "topic"):
                    channels[r.id] = r.topic
            msgs = [r for r in inside if isinstance(r, Message)]
            samples = sum(channels[m.channel_id] == "/b/sonar" for m in msgs)
            stamped = sum(len(stamps_from_cdr(m.data).topic) for m in msgs
                          if channels[m.channel_id] == "/b/stamps")  # fmt: skip
            assert samples == stamped, f"chunk {chunks}: {samples} samples, {stamped} stamped"
    assert chunks >= 4
