"""ROS 1 through rospy (Debian's ``ros-core``/``python3-rospy``; see ``scripts/system-deps.sh``).

Thesis-format types are generated at runtime from the descriptors (``time[] times`` + the
values array, ``genpy.dynamic``: no catkin build); standard types (``sensor_msgs/Range``,
``sensor_msgs/JointState``) use the installed ROS 1 message classes, filled field by field from
the ROS 2 layout (so Jazzy's extra ``Range.variance`` is simply not sent).  ``/diagnostics`` goes
out as ``diagnostic_msgs/DiagnosticArray``; the boards' logs on ``/rosout`` as
``rosgraph_msgs/Log`` (``name`` the board).

rospy lives in Debian's system Python; when this interpreter is a different build of the same
Python minor version (a venv from pyenv, say), Debian's ``dist-packages`` is appended to
``sys.path`` so rospy and its pure-Python helpers import, while everything the venv has wins.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable
from typing import Any

from ..errors import MissingLinkError
from ..host.board_log import LogLine
from ..ros.diagnostics import status_label, status_level, status_message
from ..ros.logmsgs import ROS1_LOG, ROSOUT, ros1_level
from ..ros.msgs import ROS_TYPES
from ..topics import Command, Topic, Update
from .registry import DEBIAN_DIST, debian_rospy
from .rosbase import RosPublisher
from .zenoh_config import loopback_only, takes_commands

log = logging.getLogger(__name__)


def import_rospy() -> Any:
    try:
        import rospy
    except ImportError:
        if not debian_rospy():
            raise MissingLinkError(
                "the ros1 publisher needs rospy: run scripts/system-deps.sh --ros1 "
                "(Debian's ros-core and python3-rospy)"
            ) from None
        sys.path.append(DEBIAN_DIST)
        import rospy
    return rospy


class Ros1Publisher(RosPublisher):
    name = "ros1"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        opts = dict(options or {})
        master = str(
            opts.get("master_uri", os.environ.get("ROS_MASTER_URI", "http://127.0.0.1:11311"))
        )
        os.environ["ROS_MASTER_URI"] = master
        os.environ.setdefault("ROS_IP", str(opts.get("ros_ip", "127.0.0.1")))
        # commands only where this node and its master are on loopback alone
        # (daemon/control/allowlist.py)
        here = os.environ.get("ROS_IP") or os.environ.get("ROS_HOSTNAME", "")
        master_host = master.split("://", 1)[-1].rsplit(":", 1)[0]
        self.takes_commands = takes_commands(
            opts.get("commands"), loopback_only([f"tcp/{here}:0", f"tcp/{master_host}:0"]), "[ros1]"
        )
        self.commands_how = (
            "ROS_IP or the master is off loopback: [ros1] commands = true in --config turns "
            "them on; docs/security.md"
        )
        self.rospy = rospy = import_rospy()
        import genpy.dynamic
        import rosgraph
        import roslib.message

        self._dynamic = genpy.dynamic.generate_dynamic
        self._get_class = roslib.message.get_message_class
        if not rosgraph.is_master_online(master):
            raise MissingLinkError(f"ros1: no ROS master at {master} (start roscore)")
        rospy.init_node(str(opts.get("node", "missing_link")), disable_signals=True)
        self.queue_size = int(opts.get("queue_size", 100))
        super().__init__(str(opts.get("distro", "jazzy")))
        self._pubs: dict[str, tuple[Any, Any, Topic]] = {}
        self._subs: dict[str, Any] = {}
        self.commands = 0
        self.published = 0
        diag = self._get_class("diagnostic_msgs/DiagnosticArray")
        if diag is None:
            raise MissingLinkError(
                "ros1: diagnostic_msgs is missing: run scripts/system-deps.sh --ros1"
            )
        self._diag = (rospy.Publisher("/diagnostics", diag, queue_size=10), diag)
        # the boards' logs, where every ROS 1 node's log goes (rospy's own class)
        rosout = self._get_class(ROS1_LOG)
        self._rosout = (rospy.Publisher(ROSOUT, rosout, queue_size=100), rosout)
        log.info("ros1: node up, master %s", master)

    def add_topic(self, topic: Topic) -> None:
        with self._lock:
            if self._closed or topic.name in self._pubs:
                return
            if topic.standard:
                pkg, _, name = topic.type_name.split("/")
                cls = self._get_class(f"{pkg}/{name}")
                if cls is None:
                    log.warning(
                        "ros1: no ROS 1 class for %s; %s not published", topic.type_name, topic.name
                    )
                    return
            else:
                cls = self._thesis_class(topic)
            # an actuator's state is latched: the board reports it only when it changes, and a
            # late subscriber gets the current one
            latch = topic.transducer.is_actuator
            pub = self.rospy.Publisher(topic.name, cls, queue_size=self.queue_size, latch=latch)
            self._pubs[topic.name] = (pub, cls, topic)

    def _thesis_class(self, topic: Topic) -> Any:
        """The thesis-format type, generated at runtime; its name is the daemon's (qualified
        by board where two boards define it differently), so ROS 1 never sees a clash."""
        pkg, _, name = topic.type_name.split("/")
        text = f"time[] times\n{ROS_TYPES[topic.transducer.dtype]}[] values\n"
        return self._dynamic(f"{pkg}/{name}", text)[f"{pkg}/{name}"]

    def add_command_topic(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        """``/<board>/<name>/cmd``: a ROS 1 node drives the actuator.  In the thesis type each
        message is a ``Command`` to the handler; of a standard type (``std_msgs/Float64`` per
        actuator, the robot's ``sensor_msgs/JointState`` commands), the ROS 1 message itself."""
        standard = topic.standard
        cls: Any = None
        if standard:
            pkg, _, type_ = topic.type_name.split("/")
            cls = self._get_class(f"{pkg}/{type_}")
            if cls is None:
                log.warning(
                    "ros1: no ROS 1 class for %s; %s takes no commands", topic.type_name, name
                )
                return
        with self._lock:
            if self._closed or name in self._subs:
                return
            if not standard:
                cls = self._thesis_class(topic)

            def on_command(msg: Any) -> None:  # rospy's thread: hand over, never raise
                try:
                    if standard:
                        deliver(msg)
                    else:  # (times[0] in the future: timed; else now)
                        at = msg.times[0].to_nsec() if msg.times else 0
                        deliver(Command(list(msg.values), at if at > time.time_ns() else None))
                    self.commands += 1
                except Exception as e:  # noqa: BLE001 - a bad command is counted, not fatal
                    self.dropped += 1
                    log.warning("ros1: command on %s refused: %s", name, e)

            self._subs[name] = self.rospy.Subscriber(name, cls, on_command, queue_size=10)

    def publish(self, update: Update) -> None:
        entry = self._pubs.get(update.topic.name)
        if entry is None or self._closed:
            return
        pub, cls, topic = entry
        Time = self.rospy.Time
        if topic.standard:
            msg = _to_ros1(self.typestore.deserialize_cdr(update.cdr, topic.type_name), cls, Time)
        else:
            na = topic.transducer.na  # the declared N/A value keeps a missing channel's slot
            values = [na if v is None else v for v in update.values]
            msg = cls(times=[Time(h // 10**9, h % 10**9) for h in update.host_ns], values=values)
        pub.publish(msg)
        self.published += 1

    def log(self, line: LogLine) -> None:
        if self._closed:
            return
        pub, cls = self._rosout
        msg = cls(level=ros1_level(line.level), name=line.board, msg=line.text, file="")
        msg.function = line.source
        msg.header.stamp = self.rospy.Time(line.host_ns // 10**9, line.host_ns % 10**9)
        pub.publish(msg)

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        if self._closed:
            return
        pub, cls = self._diag
        DS = self._get_class("diagnostic_msgs/DiagnosticStatus")
        KV = self._get_class("diagnostic_msgs/KeyValue")
        msg = cls()
        msg.header.stamp = self.rospy.Time(now_ns // 10**9, now_ns % 10**9)
        for s in status:
            msg.status.append(
                DS(
                    level=status_level(s),
                    name=status_label(s),
                    message=status_message(s),
                    hardware_id=str(s.get("serial", "")),
                    values=[KV(key=str(k), value=str(v)) for k, v in s.items() if k != "board"],
                )
            )
        pub.publish(msg)

    def shutdown(self) -> None:
        for pub, _, _ in self._pubs.values():
            pub.unregister()
        for sub in self._subs.values():
            sub.unregister()
        self._diag[0].unregister()
        self._rosout[0].unregister()
        self.rospy.signal_shutdown("missing-link daemon closed")


def _to_ros1(src: Any, cls: Any, Time: Any) -> Any:
    """Fill a ROS 1 message of ``cls`` from a rosbags ROS 2 object, field by field by name."""
    msg = cls()
    for slot, kind in zip(cls.__slots__, cls._slot_types, strict=True):
        if not hasattr(src, slot):
            continue  # e.g. Header.seq (ROS 1 only)
        value = getattr(src, slot)
        if kind == "time":
            value = Time(value.sec, value.nanosec)
        elif "/" in kind and not kind.endswith("]"):
            value = _to_ros1(value, type(getattr(msg, slot)), Time)
        elif hasattr(value, "tolist"):
            value = value.tolist()
        setattr(msg, slot, value)
    return msg
