"""The robot-level ``sensor_msgs/msg/JointState`` in and out (``[joints]``; docs/ros.md): what
ros2_control's topic-based hardware interface (``joint_state_topic_hardware_interface``) reads
and writes, so a robot of several boards is one ros2_control system without C++.

Theory of operation
-------------------
Each joint of the configuration names where its state comes from (``state``: a transducer, or
one channel of it) and the actuator its commands go to (``command``).  Both publish their own
standard ``JointState`` (``ros/standard/joints.py``: radians, rad/s, duty as effort); this
component hears those on the daemon's fan-out like any publisher and keeps the latest position,
velocity and effort of every joint: a field comes from the state source, or from the command
source where the state source has none (an encoder's position and velocity, its motor's duty).

Out (``state_topic``, default ``/joint_states``): one message per sample of a source, holding
the joints that sample feeds, stamped with that sample's host time: every joint is stamped by
its own board (a JointState has one stamp; consumers keep the latest of each joint, as
robot_state_publisher and the topic-based interface do).  Every array has one entry per name,
NaN where a joint has no such field.

In (``command_topic``, default ``/joint_commands``, offered on every face through the
allow-list like any command topic): a JointState routed by joint name to the actuator's
standard command (``/<board>/<actuator>/command``, SI units), so the allow-list and the
actuator's own checks hold for it too.  A joint takes one field, its ``interface``: by default
position for a servo and a stepper in position mode, velocity for a stepper in velocity mode,
effort (the duty) for an H-bridge.  An array as long as ``name`` is read by index; a shorter
one holds, in order, the values of the joints that take that field (as the topic-based
interface writes them).  A ``header.stamp`` in the future makes a timed command (the board acts
then; docs/timesync.md).  What cannot be routed (an unknown joint, a field it does not take, a
board that is down, a value the actuator refuses) is counted per kind and said once per kind
(never once per text: a peer that makes up joint names must not grow what is remembered).

Commands stop: a joint driven by velocity or effort that hears nothing for ``command_timeout``
after its last command acts is stopped (0 sent once), as a controller's command timeout would;
position joints hold.  A timed command acts later than it arrives, so its act time is what the
timeout counts from; and a velocity or effort stamped more than ``command_timeout`` ahead is
refused: the watchdog never has to wait on a command that is not yet running.  The
boards' own failsafe is unchanged: when the host is gone, they make their actuators safe.

``JointRouter`` is the pure part (time passed in); ``Joints`` the shell: a ``Publisher`` on
the fan-out, and a thread for the command timeout.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..descriptors import Transducer
from ..host.clock import SYSTEM_CLOCK, Clock
from ..host.config import Value
from ..publishers.base import DaemonApi, Publisher
from ..ros.standard import HBRIDGE, JOINT_STATE, STEPPER, command_kind
from ..ros.standard.joints import joint_state_cdr
from ..text import safe_text
from ..topics import Command, Topic, Update
from .control.allowlist import CommandRefused
from .ros_config import JointsConfig, JointSpec

log = logging.getLogger(__name__)

POSITION, VELOCITY, EFFORT = "position", "velocity", "effort"
FIELDS = (POSITION, VELOCITY, EFFORT)
NAN = math.nan
#: (the actuator's descriptor, its board's run-time configuration) or None: not up
Lookup = Callable[[str, str], "tuple[Transducer, Mapping[str, Value]] | None"]


class Refusal(str):
    """Why a joint's command was not routed (the text), and its ``kind``: what a refusal is
    counted and said once per."""

    kind: str

    def __new__(cls, kind: str, text: str) -> Refusal:
        self = super().__new__(cls, text)
        self.kind = kind
        return self


def interface_of(spec: JointSpec, t: Transducer, settings: Mapping[str, Value]) -> str:
    """The field a joint's actuator takes (ValueError when it cannot take the configured one)."""
    kind = command_kind(t)
    mode = settings.get(f"{t.name}.mode", "position")
    default = {STEPPER: VELOCITY if mode == "velocity" else POSITION, HBRIDGE: EFFORT}
    wanted = spec.interface or default.get(kind or "", POSITION)
    if kind == STEPPER and wanted != (VELOCITY if mode == "velocity" else POSITION):
        raise ValueError(
            f"{spec.name}: a {wanted} command for stepper {t.name} in {mode} mode "
            f"(set {t.name}.mode = {'velocity' if wanted == VELOCITY else 'position'})"
        )
    if kind == HBRIDGE and wanted != EFFORT:
        raise ValueError(
            f"{spec.name}: H-bridge {t.name} takes effort (its duty, -1..1); a {wanted} loop "
            "belongs in a controller that commands effort"
        )
    if kind not in (STEPPER, HBRIDGE) and wanted != POSITION:
        raise ValueError(f"{spec.name}: {t.name} takes position (rad), not {wanted}")
    return wanted


class JointRouter:
    """The joints' latest state, and where a JointState command goes (no I/O, no clock)."""

    def __init__(self, spec: JointsConfig, remap: Mapping[str, str]) -> None:
        self.spec = spec
        self.names = [j.name for j in spec.joints]
        self.index = {j.name: k for k, j in enumerate(spec.joints)}
        n = len(spec.joints)
        #: per joint and source role (0 state, 1 command): latest (position, velocity, effort)
        self.latest = [[[NAN] * 3, [NAN] * 3] for _ in range(n)]
        #: a source's JointState topic -> [(joint, channel, role)]
        self.sources: dict[str, list[tuple[int, int, int]]] = {}
        self.targets: list[tuple[str, str, str] | None] = []  # (board, actuator, command topic)
        for k, j in enumerate(spec.joints):
            for role, ref in enumerate((j.state, j.command)):
                if ref is None or (role == 1 and ref == j.state):
                    continue
                board, name, *ch = ref.split("/")
                topic = remap.get(f"/{board}/{name}", f"/{board}/{name}") + "/joint_states"
                self.sources.setdefault(topic, []).append((k, int(ch[0]) if ch else 0, role))
            target = None
            if j.command is not None:
                board, name = j.command.split("/")
                topic = remap.get(f"/{board}/{name}", f"/{board}/{name}") + "/command"
                target = (board, name, topic)
            self.targets.append(target)
        self.last_command: dict[int, float] = {}  # joint -> when it was last commanded (s)
        self.stopped: set[int] = set()

    def on_state(self, topic: str, fields: Iterable[Any]) -> list[int]:
        """A source's JointState (position, velocity, effort arrays): the joints it updated."""
        arrays = [list(a) for a in fields]
        touched = []
        for k, ch, role in self.sources.get(topic, ()):
            values = self.latest[k][role]
            for f, arr in enumerate(arrays):
                if ch < len(arr):
                    values[f] = float(arr[ch])
            touched.append(k)
        return touched

    def joint(self, k: int) -> tuple[float, float, float]:
        state, command = self.latest[k]
        p, v, e = (s if not math.isnan(s) else c for s, c in zip(state, command, strict=True))
        return p, v, e

    def route(
        self, msg: Any, now_ns: int, now_s: float, interface: Callable[[int], str]
    ) -> tuple[list[tuple[str, Command]], list[Refusal]]:
        """A JointState command -> ([(command topic, Command in SI)], [why each joint that
        could not be routed was not]).  ``interface(k)``: the field joint k takes (raises
        ValueError saying why it cannot take one)."""
        names = [str(n) for n in _get(msg, "name")]
        at = _stamp_ns(msg)
        timed = at if at is not None and at > now_ns else None
        out: list[tuple[str, Command]] = []
        errors: list[Refusal] = []
        taken: dict[str, list[int]] = {f: [] for f in FIELDS}
        wants: dict[int, str] = {}
        for i, name in enumerate(names):
            k = self.index.get(name)
            if k is None or self.targets[k] is None:
                errors.append(
                    Refusal("unknown joint", f"{name}: no such joint takes commands ([joints])")
                )
                continue
            try:
                wants[i] = interface(k)
            except ValueError as e:
                errors.append(Refusal("interface", str(e)))
                continue
            taken[wants[i]].append(i)
        columns = {f: _column(msg, f, len(names), taken[f]) for f in FIELDS}
        for i, field in wants.items():
            k = self.index[names[i]]
            column = columns[field]
            value = column.get(i) if column is not None else None
            if value is None or not math.isfinite(value):
                errors.append(Refusal("no value", f"{names[i]}: no {field} in the command"))
                continue
            if field != POSITION:
                why = self._watched(k, (timed - now_ns) / 1e9 if timed else 0.0, now_s)
                if why is not None:
                    errors.append(Refusal("stamp ahead", f"{names[i]}: a {field} {why}"))
                    continue
            target = self.targets[k]
            assert target is not None
            out.append((target[2], Command([value], timed)))
        for f in FIELDS:
            if columns[f] is None:
                errors.append(
                    Refusal("length", f"{f} has {len(_get(msg, f))} values for {len(names)} names")
                )
        return out, errors

    def _watched(self, k: int, ahead_s: float, now_s: float) -> str | None:
        """A velocity or effort command for joint k that acts ``ahead_s`` from now: the
        timeout counts from when it acts (None), or why it is refused (too far ahead)."""
        timeout = self.spec.command_timeout
        if timeout > 0 and ahead_s > timeout:
            return (
                f"command stamped {ahead_s:.3g} s ahead: at most command_timeout "
                f"({timeout:g} s) ahead, or it would run on after the timeout stopped it"
            )
        acts = now_s + ahead_s
        self.last_command[k] = max(self.last_command.get(k, acts), acts)
        self.stopped.discard(k)
        return None

    def expired(self, now_s: float) -> list[tuple[int, str]]:
        """Joints driven by velocity or effort with no command for ``command_timeout``: (joint,
        its command topic), each once until it is commanded again."""
        timeout = self.spec.command_timeout
        out = []
        for k, last in self.last_command.items():
            target = self.targets[k]
            if timeout > 0 and k not in self.stopped and now_s - last > timeout and target:
                self.stopped.add(k)
                out.append((k, target[2]))
        return out


def _get(msg: Any, field: str) -> Any:
    got = msg.get(field, ()) if isinstance(msg, Mapping) else getattr(msg, field, ())
    return () if got is None else got


def _stamp_ns(msg: Any) -> int | None:
    header = msg.get("header") if isinstance(msg, Mapping) else getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    sec = getattr(stamp, "sec", getattr(stamp, "secs", 0))
    nsec = getattr(stamp, "nanosec", getattr(stamp, "nsecs", 0))
    return int(sec) * 1_000_000_000 + int(nsec)


def _column(msg: Any, field: str, n: int, takers: list[int]) -> dict[int, float] | None:
    """Name index -> value of one field: by index when it has a value per name, else in order
    over the names that take it; None: a length that fits neither."""
    arr = [float(v) for v in _get(msg, field)]
    if len(arr) == n:
        return dict(enumerate(arr))
    if len(arr) == len(takers):
        return dict(zip(takers, arr, strict=True))
    return {} if not arr else None


class Joints(Publisher):
    """The shell: hears the sources on the fan-out, publishes the robot-level JointState,
    routes commands (through the in-process bus: ``send``) and stops what goes unattended."""

    name = "joints"

    def __init__(
        self,
        spec: JointsConfig,
        remap: Mapping[str, str],
        typestore: Any,
        emit: Callable[[Update], None],
        send: Callable[[str, Any], None],
        lookup: Lookup,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        self.spec = spec
        self.clock = clock  #: the daemon's: when a joint's command goes stale
        self.router = JointRouter(spec, remap)
        self.typestore = typestore
        self._emit, self._send, self._lookup = emit, send, lookup
        n = len(spec.joints)
        t = Transducer("joint_states", 0, "joints", "robot", max(1, n), "double", NAN,
                       {"kind": "sensor", "unit": "rad"})  # fmt: skip
        self.state_topic = Topic.standard_type(spec.state_topic, "robot", t, JOINT_STATE, typestore)
        self.command_topic = Topic.standard_type(
            spec.command_topic, "robot", t, JOINT_STATE, typestore
        )
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._said: set[str] = set()  #: the kinds of refusal said (one line each)
        self.refusals: dict[str, int] = {}  #: refusals by kind
        self.published = 0
        self.commands = 0
        self.commands_refused = 0
        self.command_timeouts = 0

    def start(self, api: DaemonApi) -> None:
        api.declare(self.state_topic)
        api.add_command(self.spec.command_topic, self.command_topic, self.on_command)
        if self.spec.command_timeout > 0:
            self._thread = threading.Thread(target=self._watch, name="joints", daemon=True)
            self._thread.start()

    # ---- state out (a board's reading thread) --------------------------------------------------
    def publish(self, update: Update) -> None:
        if update.topic.name not in self.router.sources:
            return
        msg = self.typestore.deserialize_cdr(update.cdr, JOINT_STATE)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            touched = self.router.on_state(update.topic.name, (msg.position, msg.velocity,
                                                               msg.effort))  # fmt: skip
            fields = [self.router.joint(k) for k in touched]
            positions = [self.router.joint(k)[0] for k in range(len(self.router.names))]
        if not touched:
            return
        names = [self.router.names[k] for k in touched]
        columns = tuple(list(col) for col in zip(*fields, strict=True))
        cdr = joint_state_cdr(stamp, "", names, (columns[0], columns[1], columns[2]))
        n = len(positions)
        self._emit(
            Update.build(
                topic=self.state_topic,
                board_us=[0] * n,
                host_ns=[stamp] * n,
                values=positions,
                seq=0,
                lost=0,
                recv_ns=update.recv_ns,
                cdr=cdr,
                stamp_ns=stamp,
                bound_ns=update.bound_ns,
                est_error_ns=update.est_error_ns,
                clock_flags=update.clock_flags,
            )
        )
        self.published += 1

    # ---- commands in (a face's thread) ---------------------------------------------------------
    def on_command(self, msg: Any) -> None:
        with self._lock:
            now = self.clock
            routed, errors = self.router.route(msg, now.realtime_ns(), now.monotonic(), self._iface)
        for topic, command in routed:
            try:
                self._send(topic, command)
                self.commands += 1
            except KeyError:
                errors.append(Refusal("board down", f"{topic}: its board is not up"))
            except CommandRefused as e:  # (the allow-list: nothing was sent)
                errors.append(Refusal("not allowed", str(e)))
            except ValueError as e:
                errors.append(Refusal("value", str(e)))
        for why in errors:
            self._refused(why)

    def _iface(self, k: int) -> str:
        spec = self.spec.joints[k]
        target = self.router.targets[k]
        assert target is not None
        got = self._lookup(target[0], target[1])
        if got is None:
            raise ValueError(f"{spec.name}: {target[0]}/{target[1]} is not up")
        return interface_of(spec, *got)

    def _refused(self, why: Refusal) -> None:
        self.commands_refused += 1
        self.refusals[why.kind] = self.refusals.get(why.kind, 0) + 1
        if why.kind not in self._said:  # (each kind once: a controller repeats it, and a peer
            self._said.add(why.kind)  # that makes names up must not grow this)
            log.warning("joints: command refused: %s (said once per kind; all counted)",
                        safe_text(why, 200))  # fmt: skip

    # ---- commands stop -------------------------------------------------------------------------
    def _watch(self) -> None:
        period = max(0.01, self.spec.command_timeout / 4)
        while not self._stop.wait(period):
            with self._lock:
                expired = self.router.expired(self.clock.monotonic())
            for k, topic in expired:
                self.command_timeouts += 1
                log.warning("joints: no command for %s in %g s: stopped",
                            self.router.names[k], self.spec.command_timeout)  # fmt: skip
                try:
                    self._send(topic, Command([0.0]))
                except (KeyError, ValueError) as e:
                    log.warning("joints: %s could not be stopped: %s", self.router.names[k], e)

    def close(self) -> None:
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(1.0)

    def status(self) -> dict[str, Any]:
        return {
            **super().status(),
            "joints": len(self.router.names),
            "published": self.published,
            "commands": self.commands,
            "commands_refused": self.commands_refused,
            "refused_by_kind": dict(self.refusals),
            "command_timeouts": self.command_timeouts,
        }
