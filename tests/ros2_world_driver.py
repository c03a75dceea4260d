"""An independent ROS 2 node that drives a differential-drive robot and measures it (rclpy and the
message packages only; nothing from missing_link): the wheels' duty as effort on
/joint_commands (ros2_control's topic-based interface), stamped a little ahead so that both
wheels act at the same instant, and what it measures from the standard topics the robot's
daemon publishes; one JSON object out.

    python ros2_world_driver.py --board rover --seconds 120

Phases, each waiting for what it needs (never a fixed sleep), the commands sent every 0.1 s
while a phase runs (as a controller publishes every cycle):
  rest      the IMU's acceleration, the forward ranger, the wheels' positions, the compass, a fix;
  straight  both motors at --drive until the wheels have rolled --distance m (--wheel-radius),
            the wheels' velocities and the gyro's z while the drive is steady: where both motors'
            own state (the duty each acts at, published stamped when it acted) has held --drive
            for --settle s (a busy host's board makes its motors safe mid-drive and refuses a
            timed command come past its instant, so one wheel may start again a command later
            than the other: a wall-clock window is not steady); stopped: the ranger, the
            wheels, a fix again;
  turn      left motor back, right forward (--turn) until the gyro's z integrates to --angle
            degrees; stopped: the gyro's integral over the whole turn and the compass's heading
            followed over it.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import time
from typing import Any

import rclpy
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import Imu, JointState, MagneticField, NavSatFix, Range


def stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Driver:
    def __init__(self, a: argparse.Namespace) -> None:
        self.a = a
        self.node = rclpy.create_node("world_driver")
        b = a.board
        keys = ("imu", "wl", "wr", "range", "mag", "fix", "ml", "mr")
        self.got: dict[str, list[Any]] = {k: [] for k in keys}
        for key, cls, topic in (
            ("imu", Imu, f"/{b}/imu/imu"), ("wl", JointState, f"/{b}/wheel_l/joint_states"),
            ("wr", JointState, f"/{b}/wheel_r/joint_states"), ("range", Range, f"/{b}/sonar/range"),
            ("mag", MagneticField, f"/{b}/compass/field"), ("fix", NavSatFix, f"/{b}/gps/fix"),
        ):  # fmt: skip
            self.node.create_subscription(cls, topic, lambda m, k=key: self.got[k].append(m),
                                          qos_profile_sensor_data)  # fmt: skip
        for key, side in (("ml", "l"), ("mr", "r")):
            # (reliable: a motor's every change of duty is what the steady drive is found from)
            self.node.create_subscription(JointState, f"/{b}/motor_{side}/joint_states",
                                          lambda m, k=key: self.got[k].append(m),
                                          QoSProfile(depth=100))  # fmt: skip
        self.joints = self.node.create_publisher(JointState, "/joint_commands", 10)
        self.cmd = (0.0, 0.0)
        self.next_cmd = 0.0
        self.deadline = time.monotonic() + a.seconds

    def spin_until(self, done: Any, what: str) -> None:
        while not done():
            if time.monotonic() > self.deadline:
                raise SystemExit(f"timed out waiting for {what}: {self.counts()}")
            rclpy.spin_once(self.node, timeout_sec=0.02)
            if time.monotonic() >= self.next_cmd and self.joints.get_subscription_count():
                self.next_cmd = time.monotonic() + 0.1
                m = JointState(name=["left_wheel", "right_wheel"], effort=list(self.cmd))
                at = self.node.get_clock().now().nanoseconds + int(self.a.lead * 1e9)
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(at, 10**9)
                self.joints.publish(m)

    def counts(self) -> dict[str, int]:
        return {k: len(v) for k, v in self.got.items()}

    def since(self, key: str, t: float) -> list[Any]:
        return [m for m in self.got[key] if stamp(m) > t]

    def stopped_at(self, t: float) -> float | None:
        """When both wheels stood still for good (three samples on), after host time t."""
        at = t
        for k in ("wl", "wr"):
            run = []
            for m in self.since(k, t):
                run = [*run, m] if m.velocity[0] == 0 else []
            if len(run) < 3:
                return None
            at = max(at, stamp(run[0]))
        return at

    def settled(self, t: float, n: int = 10, ranger: bool = True) -> bool:
        """The wheels standing still after host time t, and since then n samples of each sensor
        (the ranger's too, when it is to see a wall) and a fix."""
        still = self.stopped_at(t)
        if still is None:
            return False
        keys = ("imu", "range", "mag") if ranger else ("imu", "mag")
        fix = len(self.since("fix", still)) >= 1
        return fix and all(len(self.since(k, still)) >= n for k in keys)

    def snapshot(self, t: float) -> dict[str, Any]:
        t = self.stopped_at(t) or t
        ranges = [m.range for m in self.since("range", t)[-10:]] or [math.nan]
        mag = self.since("mag", t)[-10:]
        fix = self.since("fix", t)[-1]
        return {
            "range_m": statistics.fmean(ranges), "range_n": len(ranges),
            "resolution_m": 0.003,  # (HC-SR04: its datasheet's 3 mm)
            "wheels_rad": [self.got[k][-1].position[0] for k in ("wl", "wr")],
            "field": [statistics.fmean(m.magnetic_field.x for m in mag),
                      statistics.fmean(m.magnetic_field.y for m in mag)],
            "fix": [fix.latitude, fix.longitude],
        }  # fmt: skip

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def rest(self) -> dict[str, Any]:
        t = self.now()
        self.spin_until(lambda: self.settled(t, 50), "samples at rest")
        acc = [m.linear_acceleration for m in self.since("imu", t)]
        mean = [statistics.fmean(getattr(v, k) for v in acc) for k in "xyz"]
        return {"accel_mean": mean, "accel_norm": math.hypot(*mean), **self.snapshot(t)}

    def straight(self, before: dict[str, Any]) -> dict[str, Any]:
        t0 = self.now()
        self.cmd = (self.a.drive, self.a.drive)
        target = self.a.distance / self.a.wheel_radius
        start = before["wheels_rad"]

        def rolled() -> float:
            if not (self.since("wl", t0) and self.since("wr", t0)):
                return 0.0
            return min(self.got[k][-1].position[0] - start[i] for i, k in enumerate(("wl", "wr")))

        self.spin_until(lambda: rolled() >= target, "the wheels to roll")
        t1 = self.now()
        self.cmd = (0.0, 0.0)
        self.spin_until(lambda: self.settled(t1 + 0.5), "the robot to stop")
        spans = self.steady(t0, t1, self.a.drive)
        pairs = self._velocity_pairs(spans)
        gz = [m.angular_velocity.z for m in self.got["imu"] if within(spans, stamp(m))]
        return {"velocity_pairs": pairs, "gyro_z": gz, "steady": spans,
                **self.snapshot(t1 + 0.5)}  # fmt: skip

    def steady(self, t0: float, t1: float, duty: float) -> list[list[float]]:
        """The spans of (t0, t1] where both motors have acted at ``duty`` for --settle s (each
        motor's state, stamped when it acted: a command, or the board making it safe)."""
        changes = sorted(
            (stamp(m), k, m.effort[0] if len(m.effort) else math.nan)
            for k in ("ml", "mr") for m in self.got[k]
        )  # fmt: skip
        duties = {"ml": math.nan, "mr": math.nan}
        spans: list[list[float]] = []
        since = None  # when both last came to ``duty``
        for t, k, e in [*changes, (math.inf, "", math.nan)]:
            done = spans[-1][1] if spans else t0  # (a span goes on past a repeated duty)
            start = t1 if since is None else max(since + self.a.settle, done)
            if min(t, t1) > start:
                spans.append([start, min(t, t1)])
            if k:
                duties[k] = e
            both = all(abs(d - duty) < 1e-3 for d in duties.values())
            since = (since if since is not None else t) if both else None
        return spans

    def _velocity_pairs(self, spans: list[list[float]]) -> list[list[float]]:
        """(left, right, stamp) velocities of the two wheels' samples nearest in time (each is
        stamped at its newest edge: within one period) in the steady spans."""
        right = [(stamp(m), m.velocity[0]) for m in self.got["wr"] if within(spans, stamp(m))]
        pairs = []
        for m in self.got["wl"]:
            t = stamp(m)
            near = min(right, key=lambda r: abs(r[0] - t), default=None)
            ok = within(spans, t) and not math.isnan(m.velocity[0])
            if ok and near and abs(near[0] - t) < 0.01:
                pairs.append([m.velocity[0], near[1], t])
        return [p for p in pairs if not math.isnan(p[1])]

    def turn(self) -> dict[str, Any]:
        t0 = self.now()
        self.cmd = (-self.a.turn, self.a.turn)
        goal = math.radians(self.a.angle)
        self.spin_until(lambda: integral(self.since("imu", t0)) >= goal, "the turn")
        t1 = self.now()
        self.cmd = (0.0, 0.0)
        self.spin_until(lambda: self.settled(t1 + 0.5, ranger=False), "the robot to stop turning")
        imu = self.since("imu", t0)
        gz = [m.angular_velocity.z for m in imu if stamp(m) <= t1]
        # the compass's heading, followed sample by sample (a turn may pass half a circle):
        # the field turns the other way in the body's axes
        heads = [math.atan2(m.magnetic_field.y, m.magnetic_field.x) for m in self.since("mag", t0)]
        compass = -sum(math.remainder(b - a, 2 * math.pi) for a, b in itertools.pairwise(heads))
        return {"gyro_integral": integral(imu), "gyro_z_min": min(gz), "gyro_z_max": max(gz),
                "gyro_gaps": gaps(imu), "compass_turn": compass,
                "imu_gap_s": max(stamp(b) - stamp(a) for a, b in itertools.pairwise(imu)),
                **self.snapshot(t1 + 0.5)}  # fmt: skip


def within(spans: list[list[float]], t: float) -> bool:
    return any(a < t <= b for a, b in spans)


def integral(imu: list[Any]) -> float:
    """The gyro's z integrated over the samples' stamps (trapezoids)."""
    out = 0.0
    for a, b in itertools.pairwise(imu):
        out += (a.angular_velocity.z + b.angular_velocity.z) / 2 * (stamp(b) - stamp(a))
    return out


def brief(m: Any) -> list[float]:
    if isinstance(m, Imu):
        return [m.angular_velocity.z, m.linear_acceleration.x]
    if isinstance(m, JointState):  # (a motor's: its duty as effort)
        return [*m.position[:1], *m.velocity[:1], *m.effort[:1]]
    if isinstance(m, Range):
        return [m.range]
    if isinstance(m, MagneticField):
        return [m.magnetic_field.x, m.magnetic_field.y]
    return [m.latitude, m.longitude]


def gaps(imu: list[Any]) -> float:
    """How far the trapezoids can be from the rate's true integral where it changed between two
    samples (a rate that moved monotonically between them: half the gap times the change)."""
    return sum(abs(b.angular_velocity.z - a.angular_velocity.z) * (stamp(b) - stamp(a)) / 2
               for a, b in itertools.pairwise(imu))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--board", default="rover")
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--wheel-radius", type=float, default=0.033)
    ap.add_argument("--drive", type=float, default=0.6)
    ap.add_argument("--distance", type=float, default=1.0)
    ap.add_argument("--turn", type=float, default=0.4)
    ap.add_argument("--angle", type=float, default=90.0)
    ap.add_argument("--lead", type=float, default=0.4, help="s a command is stamped ahead")
    # (the bridges' ramp, 0.15 s to 0.6 at 4/s, then five of the drive's 0.1 s time constants)
    ap.add_argument("--settle", type=float, default=0.65, help="s from a duty to a steady drive")
    ap.add_argument("--dump", help="a JSON file for every IMU and compass sample")
    a = ap.parse_args()
    rclpy.init()
    d = Driver(a)
    out: dict[str, Any] = {}
    try:
        out["rest"] = d.rest()
        out["straight"] = d.straight(out["rest"])
        out["turn"] = d.turn()
        out["counts"] = d.counts()
        if a.dump:  # (every sample, for a look at a failure)
            with open(a.dump, "w") as f:
                json.dump({k: [[stamp(m), *brief(m)] for m in v] for k, v in d.got.items()}, f)
    finally:
        d.node.destroy_node()
        rclpy.shutdown()
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
