"""What a commanding peer cannot do through ``/joint_commands`` (daemon/joints.py): keep a motor
running past ``command_timeout`` with a stamp in the future, or grow the daemon's memory with
joint names it makes up.  On virtual time, and one shell test (Joints) without a daemon."""

from __future__ import annotations

import time
import tracemalloc
from types import SimpleNamespace
from typing import Any

import pytest

from missing_link.daemon.joints import Joints
from missing_link.daemon.ros_config import JointsConfig, JointSpec
from missing_link.ros.msgs import typestore_for

from .test_joints import NOW, iface, router, stamp


def _effort(at_ns: int, value: float = 0.5) -> Any:
    return SimpleNamespace(header=stamp(at_ns), name=["left_wheel"], position=[], velocity=[],
                           effort=[value])  # fmt: skip


def test_a_timed_effort_is_watched_from_when_it_acts() -> None:
    r = router()  # command_timeout 0.5 s
    out, errors = r.route(_effort(NOW + 400_000_000), NOW, 10.0, iface(r))
    assert errors == [] and out[0][1].at_ns == NOW + 400_000_000
    assert r.expired(10.6) == []  # it acts at 10.4: stopped 0.5 s after that, not before
    assert r.expired(10.95) == [(0, "/rover/motor_l/command")]
    # a command now after a timed one does not shorten the watch of the timed one
    r.route(_effort(NOW + 400_000_000), NOW, 20.0, iface(r))
    r.route(_effort(0), NOW, 20.1, iface(r))
    assert r.expired(20.65) == [] and r.expired(20.95) != []


def test_an_effort_or_velocity_stamped_beyond_the_timeout_is_refused() -> None:
    r = router()
    out, errors = r.route(_effort(NOW + 3_000_000_000), NOW, 10.0, iface(r))
    assert out == [] and len(errors) == 1 and errors[0].kind == "stamp ahead"
    assert "3 s ahead" in errors[0] and "command_timeout (0.5 s)" in errors[0]
    assert r.expired(100.0) == []  # (nothing was sent, nothing to stop)
    # a position joint holds where it is sent: its stamp may be as far ahead as the board takes
    far = SimpleNamespace(header=stamp(NOW + 3_000_000_000), name=["pan"], position=[0.1])
    out, errors = r.route(far, NOW, 10.0, iface(r))
    assert errors == [] and out[0][1].at_ns == NOW + 3_000_000_000
    # without a command timeout nothing is stopped, so nothing is refused for its stamp
    off = router(r"""
[joints]
command_timeout = 0
[joints.left_wheel]
command = "rover/motor_l"
""")
    out, errors = off.route(_effort(NOW + 3_000_000_000), NOW, 10.0, iface(off))
    assert errors == [] and len(out) == 1


def test_made_up_joint_names_do_not_grow_what_is_remembered() -> None:
    spec = JointsConfig(joints=[JointSpec("pan", "rig/servo", "rig/servo")])
    j = Joints(spec, {}, typestore_for("jazzy"), lambda u: None, lambda t, c: None,
               lambda b, n: None)  # fmt: skip
    tracemalloc.start()
    try:
        j.on_command({"name": ["warm-up"], "position": [0.0]})
        before = tracemalloc.take_snapshot()
        for i in range(300):  # 300 messages of 50 made-up names of 200 characters
            j.on_command({"name": [f"{i:06d}-{k:03d}" + "x" * 190 for k in range(50)],
                          "position": [0.0] * 50})  # fmt: skip
        after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename"))
    assert j.commands_refused == 1 + 300 * 50
    assert j.status()["refused_by_kind"] == {"unknown joint": 1 + 300 * 50}
    assert len(j._said) <= 8, j._said
    assert grown < 300_000, f"{grown} bytes kept for 15,000 refusals"  # (3 MB of names went by)


@pytest.mark.slow  # (a daemon and the rover's virtual firmware; seconds of real time)
def test_on_the_rover_a_stamp_beyond_the_timeout_never_reaches_the_motor() -> None:
    """The attack, end to end: an effort stamped 3 s ahead, then silence, used to be queued on
    the board and run the motor after the watchdog's stop.  Now it is refused before the board
    (counted by kind); one stamped within the timeout runs when due and is stopped after it."""
    import tomllib

    from rosbags.typesys import Stores, get_typestore

    from missing_link.daemon import Daemon
    from missing_link.daemon.config import parse_config

    from .helpers import wait_for
    from .standard_boards import ROVER, virtual_board

    T = get_typestore(Stores.ROS2_JAZZY).types
    rover = virtual_board(ROVER)
    motor = "result = WORLD.devices['motor_l'].state()"
    toml = f"""
[daemon]
publishers = ["bus"]
[[board]]
url = "{rover.url}"
timeout = 2.0
[joints]
command_timeout = 0.5
[joints.left_wheel]
state = "rover/wheel_l"
command = "rover/motor_l"
"""

    def effort(ahead_ns: int) -> Any:
        at = time.time_ns() + ahead_ns
        stamp = T["builtin_interfaces/msg/Time"](sec=at // 10**9, nanosec=at % 10**9)
        return T["sensor_msgs/msg/JointState"](header=T["std_msgs/msg/Header"](
            stamp=stamp, frame_id=""), name=["left_wheel"], position=[], velocity=[],
            effort=[0.5])  # fmt: skip

    def joints(d: Daemon) -> dict[str, Any]:
        return next(p for p in d.publisher_status() if p["publisher"] == "joints")

    try:
        with Daemon(parse_config(tomllib.loads(toml))) as d:
            assert d.wait_until_up(20)
            assert wait_for(lambda: d.status()[0]["map_pushes"] > 0, 10)  # (the board maps time)
            d.bus.send("/joint_commands", effort(3_000_000_000))
            assert wait_for(lambda: joints(d)["refused_by_kind"] == {"stamp ahead": 1}, 10)
            assert joints(d)["commands"] == 0  # (nothing went to the board)
            d.bus.send("/joint_commands", effort(300_000_000))
            assert wait_for(lambda: rover.ctl(motor)[0] == 0.5, 10), rover.ctl(motor)
            assert wait_for(lambda: joints(d)["command_timeouts"] == 1, 10), joints(d)
            assert wait_for(lambda: rover.ctl(motor)[0] == 0.0, 10), rover.ctl(motor)
    finally:
        rover.close()
