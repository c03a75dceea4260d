"""Command values at and beyond their actuator's type, from every in-process face (issue 43.1):
``Daemon.send`` on the thesis-format ``/cmd`` (now and timed), a ``Float64`` on ``/command``
and a ``/joint_commands`` effort, against a CPython board with actuators of every kind of type
(a float32 H-bridge, a double, the thesis rig's int8 servo, a uint16 and an int64).

Before, a float beyond a float32 (1e39 raw, 1e300 as a Float64 or a joint's effort) passed the
check and raised ``OverflowError`` where it was packed, which ended the board's session (a
reconnect; once a second kept every sensor of the board down), and a timed one left the
board's timed path stuck for good ("64 timed commands wait already").  Now a value meets its
type where it arrives (``Transducer.refusal``): refused with a ValueError, counted in the
session's ``values_refused`` (status, ``/diagnostics``), said once per actuator, never queued.
The faces over the network: tests/test_command_edges_faces.py; the boards themselves:
tests/test_command_edges_boards.py."""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from missing_link.board.dtypes import DTYPES
from missing_link.board.transducer import Transducer as BoardTransducer
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, parse_config
from missing_link.descriptors import Transducer
from missing_link.topics import Command
from missing_link.virtual import make_sim

from .helpers import wait_for

Serve = Callable[..., Any]
F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
F32_END = 2.0**128 - 2.0**103  # (FLT_MAX and half its last step: rounds to infinity)


# ---- the check itself: refused exactly when the value does not fit its type ---------------------


def _t(dtype: str, na: float) -> Transducer:
    return Transducer("x", 0, "p", "m", 1, dtype, na, {"kind": "actuator", "call": "f"})


def _packs(fmt: str, value: object) -> bool:
    try:
        struct.pack("<" + fmt, value)
    except (struct.error, OverflowError):
        return False
    return True


@given(
    dtype=st.sampled_from(sorted(DTYPES)),
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(min_value=-(2**70), max_value=2**70),
        st.sampled_from([2**128, -(2**1024), 10**400, F32_MAX, -F32_MAX, 3.4028235e38,
                         3.40282357e38, F32_END, math.nextafter(F32_END, 0)]),
    ),
)  # fmt: skip
def test_a_value_is_refused_exactly_when_its_type_cannot_hold_it(dtype: str, value: Any) -> None:
    code, _size, lo, hi = DTYPES[dtype]
    na = math.nan if dtype in ("float", "double") else lo
    t = _t(dtype, na)
    if dtype in ("float", "double"):
        fits = _packs(code, value) and not (isinstance(value, float) and not math.isfinite(value))
    else:
        fits = isinstance(value, int) and lo <= value <= hi
    fits = fits and value != na
    assert (t.refusal(value) is None) == fits, (dtype, value, t.refusal(value))
    if fits:
        assert t.pack_command(value) == struct.pack("<" + code, value)
    else:
        with pytest.raises(ValueError, match=r"^x: "):  # (never OverflowError, struct.error)
            t.pack_command(value)


# ---- every in-process face, against a board with every kind of actuator --------------------------


class Recorder:
    """A board-side actuator that keeps what it was sent (the payload, unpacked)."""

    def __init__(self, fmt: str) -> None:
        self.fmt = fmt
        self.got: list[Any] = []

    def set_cb(self, fn: Any) -> None:
        pass

    def command(self, payload: bytes) -> tuple[int, bytes]:
        (value,) = struct.unpack("<" + self.fmt, payload)
        self.got.append(value)
        return 0, b""


ACTUATORS = {  # name: (type, N/A, options)
    "motor": ("float", math.nan, {"unit": "duty"}),  # an H-bridge: its /command is the duty
    "arm": ("double", math.nan, {}),
    "level": ("uint16_t", 0, {}),
    "big": ("int64_t", -(2**63), {}),
}


def _board() -> tuple[Any, dict[str, Recorder]]:
    rt = make_sim("thesis", seed=4)
    kept: dict[str, Recorder] = {}
    for i, (name, (dtype, na, extra)) in enumerate(ACTUATORS.items()):
        rec = kept[name] = Recorder(DTYPES[dtype][0])
        opts = {"kind": "actuator", "call": f"a2j_{name}", **extra}
        t = BoardTransducer(name, 20 + i, name, "test", 1, dtype, na, **opts)
        rt.add_function(f"a2j_{name}", rt.gated(t, rec.command))
        rt.add_transducer(t, rec)
    return rt, kept


#: (topic, value, refused?)
RAW = [
    ("/thesis/motor/cmd", 1e39, True),
    ("/thesis/motor/cmd", -3.40282357e38, True),
    ("/thesis/motor/cmd", math.inf, True),
    ("/thesis/motor/cmd", math.nan, True),
    ("/thesis/motor/cmd", 10**400, True),
    ("/thesis/motor/cmd", F32_MAX, False),
    ("/thesis/motor/cmd", 3.4028235e38, False),
    ("/thesis/motor/cmd", 5e-324, False),  # (a float32 holds it as 0.0)
    ("/thesis/arm/cmd", 1e308, False),
    ("/thesis/arm/cmd", -math.inf, True),
    ("/thesis/arm/cmd", 10**400, True),
    ("/thesis/servo/cmd", 127, False),
    ("/thesis/servo/cmd", 128, True),
    ("/thesis/servo/cmd", -128, True),  # (its N/A)
    ("/thesis/servo/cmd", 2.5, True),
    ("/thesis/level/cmd", -1, True),
    ("/thesis/level/cmd", 65536, True),
    ("/thesis/level/cmd", 65535, False),
    ("/thesis/big/cmd", 2**63, True),
    ("/thesis/big/cmd", -(2**63) + 1, False),
]


@pytest.fixture
def robot(serve: Serve) -> Iterator[tuple[Daemon, dict[str, Recorder]]]:
    rt, kept = _board()
    server = serve(rt)
    cfg = parse_config(
        {"board": [{"url": server.url}], "joints": {"wheel": {"command": "thesis/motor"}}}
    )
    with Daemon(cfg) as d:
        assert d.wait_until_up(), d.failures()
        yield d, kept


def _session_kept(d: Daemon) -> None:
    (s,) = d.status()
    assert s["state"] == "up" and s["connects"] == 1, s  # (before: a reconnect per value)


def test_every_raw_edge_is_refused_or_sent_as_its_type_says(
    robot: tuple[Daemon, dict[str, Recorder]], caplog: pytest.LogCaptureFixture
) -> None:
    d, kept = robot
    caplog.set_level(logging.WARNING)
    refused = 0
    for topic, value, no in RAW:
        if no:
            with pytest.raises(ValueError, match=topic.split("/")[2] + ": "):
                d.send(topic, value)
            refused += 1
        else:
            d.send(topic, value)
            name = topic.split("/")[2]
            rec = kept.get(name)
            if rec is not None:
                want = struct.unpack("<" + rec.fmt, struct.pack("<" + rec.fmt, value))[0]
                assert wait_for(lambda r=rec, w=want: r.got and r.got[-1] == w, 5), (topic, value)
    _session_kept(d)
    assert d.status()[0]["values_refused"] == refused
    said = [r.getMessage() for r in caplog.records if "refused, not sent" in r.getMessage()]
    assert len(said) == len({t.split("/")[2] for t, _v, no in RAW if no}), said  # once each


def test_standard_and_joint_commands_beyond_the_type_are_refused(
    robot: tuple[Daemon, dict[str, Recorder]],
) -> None:
    d, kept = robot
    with pytest.raises(ValueError, match="beyond a float"):
        d.send("/thesis/motor/command", 1e300)
    with pytest.raises(ValueError, match="not finite"):
        d.send("/thesis/motor/command", math.inf)
    with pytest.raises(ValueError, match="beyond int8_t"):
        d.send("/thesis/servo/command", 1e300)  # (rad: rounded to an int beyond int8)
    d.bus.send("/joint_commands", {"name": ["wheel"], "effort": [1e300]})
    d.bus.send("/joint_commands", {"name": ["wheel"], "effort": [-1e39]})
    joints = next(p for p in d.publisher_status() if p.get("publisher") == "joints")
    assert joints["commands_refused"] == 2, joints
    d.send("/thesis/motor/command", 0.25)  # and what the type holds still goes
    assert wait_for(lambda: kept["motor"].got[-1:] == [0.25], 5)
    _session_kept(d)
    assert d.status()[0]["values_refused"] == 5


def test_refused_timed_commands_never_stick_the_timed_path(
    robot: tuple[Daemon, dict[str, Recorder]],
) -> None:
    """(before: the first timed 1e39 raised in the map's callback, the batch never ended, and
    every later timed command was "64 timed commands wait already")"""
    d, kept = robot
    at = time.time_ns() + 300_000_000
    for _ in range(100):
        with pytest.raises(ValueError, match="beyond a float"):
            d.bus.send("/thesis/motor/cmd", Command([1e39], at))
    tick = d.send("/thesis/motor/cmd", 0.5, at_ns=time.time_ns() + 300_000_000)
    assert tick is not None and tick > 0
    assert wait_for(lambda: kept["motor"].got[-1:] == [0.5], 5)
    _session_kept(d)


def test_a_call_that_raises_ends_neither_the_session_nor_the_timed_batch(serve: Serve) -> None:
    """Whatever a command's call raises (here: a link whose write fails with an error of no
    kind we expect) is counted where it is started; the supervisor goes on."""
    rt, kept = _board()
    server = serve(rt)
    with Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        assert d.wait_until_up(), d.failures()
        (s,) = d.sessions
        real = s.actuators._call
        failing = [True]

        def call(board: Any, name: str, payload: bytes) -> Any:
            if failing[0]:
                raise RuntimeError("a bug")
            return real(board, name, payload)

        s.actuators._call = call
        d.send("/thesis/motor/cmd", 0.5)
        with pytest.raises(RuntimeError, match="a bug"):
            d.send("/thesis/motor/cmd", 0.75, at_ns=time.time_ns() + 300_000_000)
        assert wait_for(lambda: d.status()[0]["command_errors"] >= 1, 5)
        failing[0] = False
        d.send("/thesis/motor/cmd", 0.25, at_ns=time.time_ns() + 300_000_000)
        assert wait_for(lambda: kept["motor"].got[-1:] == [0.25], 5)
        _session_kept(d)


def test_a_timed_command_beyond_a_host_time_is_refused(
    robot: tuple[Daemon, dict[str, Recorder]],
) -> None:
    """(found attacking the fixed faces: an ``at_ns`` beyond an int64 was queued and failed
    where it was packed, the caller told a struct.error)"""
    d, kept = robot
    for at in (1 << 63, 1 << 64, -1, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="not a host time"):
            d.bus.send("/thesis/motor/cmd", Command([0.5], at))
    tick = d.send("/thesis/motor/cmd", 0.25, at_ns=time.time_ns() + 300_000_000)
    assert tick is not None and wait_for(lambda: kept["motor"].got[-1:] == [0.25], 5)
