"""``ros2``: every transducer on ROS 2 through rclpy, so whatever RMW the environment selects
(Fast DDS, Cyclone DDS, Connext, Zenoh) carries it, with ``ROS_DOMAIN_ID``, the discovery range
and ROS security settings taken from the environment as every ROS 2 node takes them.

Theory of operation
-------------------
One node per daemon (``node``, default ``missing_link``), on a context of its own, spun by an
executor thread (it only serves the actuator subscriptions).  Each topic gets an rclpy publisher
of its message class, and every update is published as the CDR bytes the daemon already made
(rclpy publishes serialized messages as they are): no message objects on the sample path.

* Standard types (``sensor_msgs/msg/Range``, ``JointState``, ``diagnostic_msgs/msg/
  DiagnosticArray`` on ``/diagnostics``) come with every ROS 2 install.
* Thesis-format types (``missing_link_msgs/msg/DistIr``) need the package ``create-msgs`` writes,
  built (``missing-link create-msgs URL --ros 2 --build PREFIX``): rclpy has no runtime types.
  The daemon finds it on ``PYTHONPATH`` (a sourced ``PREFIX/setup`` or colcon workspace) or
  through ``prefix`` (``[ros2] prefix = "PREFIX"`` or ``MISSING_LINK_ROS2_PREFIX``).  Types
  that are not built are skipped, said once for them all with how to build them (and not a
  fault: the status stays OK, since standard types are what most users want); standard types
  and diagnostics go out.  A built type whose fields differ from the board's descriptor
  (the board changed since the build) is refused, never sent wrong.
* Actuators: ``/<board>/<name>/cmd`` is subscribed with the thesis type (raw CDR, decoded with
  rosbags) and goes through the daemon's latest-wins path.
* Boards' logs (docs/board-log.md): every line on ``/rosout`` as ``rcl_interfaces/msg/Log``,
  ``name`` the board, with rcl's rosout QoS (``ros/logmsgs.py``).
* Boards' run-time configuration: every key is a parameter ``<board>.<transducer>.<key>`` of
  the node, with its range (``ros2_params.py``); a refused set is an unsuccessful result.
* QoS: reliable, volatile, keep last ``depth`` (10): a default subscriber and a sensor-data
  (best-effort) subscriber both match.  An actuator's state topics are transient local, keep
  last 1: a late subscriber that asks for transient local gets the current state (the board
  reports it only when it changes); a volatile one matches too.
"""

from __future__ import annotations

import ctypes
import glob
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..ros.diagnostics import DIAG_TOPIC, DIAG_TYPE
from ..ros.logmsgs import ROS2_LOG, ROSOUT, rosout_cdr
from ..ros.msgs import ROS_TYPES
from ..ros.standard import FrameId
from ..topics import Command, Topic, Update
from .base import ApplyConfig, PublisherError
from .ros2_params import RosParameters
from .rosbase import RosPublisher
from .zenoh_config import takes_commands

log = logging.getLogger(__name__)
#: what turns this face's commands on (said once with the first refusal: allowlist.py)
COMMANDS_HOW = (
    "DDS may reach the network: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST keeps it on this host "
    "and turns them on, or [ros2] commands = true in --config; docs/security.md"
)

#: how rosidl names our primitive types in get_fields_and_field_types()
_IDL = {"float32": "float", "float64": "double", "bool": "boolean"}


def expected_fields(t: Any) -> dict[str, str]:
    ros = ROS_TYPES[t.dtype]
    return {
        "times": "sequence<builtin_interfaces/Time>",
        "values": f"sequence<{_IDL.get(ros, ros)}>",
    }


def add_prefix(prefix: str) -> None:
    """Make a package installed under ``prefix`` (cmake --install) importable in this process:
    its Python path, and its C libraries loaded by absolute path (the dynamic loader's path was
    fixed when the process started)."""
    py = os.path.join(prefix, "lib", f"python{sys.version_info[0]}.{sys.version_info[1]}")
    for site in (os.path.join(py, "site-packages"), os.path.join(py, "dist-packages")):
        if os.path.isdir(site) and site not in sys.path:
            sys.path.insert(0, site)
    libs = sorted(glob.glob(os.path.join(prefix, "lib", "lib*__rosidl_*.so")))
    # generator_c first: every other type-support library needs its symbols
    libs.sort(key=lambda p: (0 if "rosidl_generator_c" in p else 1, p))
    for lib in libs:
        ctypes.CDLL(lib, mode=ctypes.RTLD_GLOBAL)


class Ros2Publisher(RosPublisher):
    name = "ros2"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        opts = options or {}
        try:
            import rclpy
            from rclpy.executors import SingleThreadedExecutor
            from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        except ImportError as e:
            raise PublisherError(
                "ros2 needs rclpy: source your ROS 2 installation (apt: /opt/ros/<distro>/"
                "setup.bash) or pip install ros-kilted-rclpy ros-kilted-rmw-fastrtps-cpp "
                f"ros-kilted-sensor-msgs ros-kilted-diagnostic-msgs ({e})"
            ) from None
        prefix = str(opts.get("prefix") or os.environ.get("MISSING_LINK_ROS2_PREFIX", ""))
        for p in filter(None, prefix.split(os.pathsep)):
            add_prefix(p)
        self.rclpy = rclpy
        # DDS reaches the network unless told to stay on the host: commands from this face by
        # default only then (daemon/control/allowlist.py)
        local = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() in ("LOCALHOST", "OFF")
        local = local or os.environ.get("ROS_LOCALHOST_ONLY") == "1"
        self.takes_commands = takes_commands(opts.get("commands"), local, "[ros2]")
        self.commands_how = COMMANDS_HOW
        distro = str(opts.get("distro") or os.environ.get("ROS_DISTRO") or "kilted")
        super().__init__(distro if distro in ("humble", "jazzy", "kilted") else "kilted")
        self.qos = QoSProfile(
            depth=int(opts.get("depth", 10)),
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.VOLATILE,
        )
        # an actuator's state: the board reports it only when it changes, so it is kept for
        # late subscribers (a volatile subscriber matches too)
        self.state_qos = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        try:
            self.node = rclpy.create_node(
                str(opts.get("node", "missing_link")), context=self.context
            )
        except Exception:  # (broad, raised again: the context must not outlive a failed start)
            rclpy.shutdown(context=self.context)
            raise
        self.params = RosParameters(self.node)  # boards' run-time configuration
        self._frames: dict[str, FrameId] = {}  # "<board>.<transducer>.frame_id" -> FrameId
        self._frame_setting = threading.local()
        self.node.add_on_set_parameters_callback(self._on_frame_set)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._pubs: dict[str, Any] = {}
        self._subs: dict[str, Any] = {}
        self.published = 0
        self.dropped = 0
        self.missing_types: dict[str, str] = {}  # type name -> why it is not published
        #: thesis-format types not built (create-msgs): their topics go out as standard types
        #: only, which is what a user of standard types wants; said once, not a fault
        self.not_built: list[str] = []
        self.error = ""
        diag_cls = self._msg_class(DIAG_TYPE)
        assert diag_cls is not None, "diagnostic_msgs is part of every ROS 2 install"
        self._diag = self.node.create_publisher(diag_cls, DIAG_TOPIC, self.qos)
        # the boards' logs, as every node's log goes out (rcl's rosout QoS: transient local)
        from rclpy.qos import qos_profile_rosout_default

        log_cls = self._msg_class(ROS2_LOG)
        assert log_cls is not None, "rcl_interfaces comes with rclpy"
        self._rosout = self.node.create_publisher(log_cls, ROSOUT, qos_profile_rosout_default)
        self._spin = threading.Thread(target=self._spin_executor, name="ros2-executor", daemon=True)
        self._spin.start()

    def _spin_executor(self) -> None:
        try:
            self.executor.spin()
        except Exception as e:  # noqa: BLE001 - the executor's thread ends: ERROR in the status
            if not self._closed:  # (and counted, said); while closing it is how spin ends
                self.error = f"executor stopped: {e}"
                self.faults.caught("executor", e)

    # ---- types -------------------------------------------------------------------------------
    def _msg_class(self, type_name: str) -> Any | None:
        pkg, _msg, name = type_name.split("/")
        try:
            module = __import__(f"{pkg}.msg", fromlist=[name])
            return getattr(module, name)
        except (ImportError, AttributeError):
            return None

    def _class_for(self, topic: Topic) -> Any | None:
        cls = self._msg_class(topic.type_name)
        if topic.standard:
            if cls is None:
                self._missing(topic.type_name, "its package is not installed")
            return cls
        if cls is None:
            self._not_built(topic)
            return None
        want = expected_fields(topic.transducer)
        have = dict(cls.get_fields_and_field_types())
        if have != want:
            self._missing(
                topic.type_name,
                f"the built type has {have}, the board describes {want}: rebuild it "
                "(create-msgs --build) before publishing",
            )
            return None
        return cls

    def _not_built(self, topic: Topic) -> None:
        if topic.type_name in self.not_built:
            return
        self.not_built.append(topic.type_name)
        if len(self.not_built) == 1:  # (once for them all: a board has many)
            log.warning(
                "ros2: %s and the other thesis-format topics go out in their standard types "
                "only: their own types are not built (for them too: missing-link create-msgs "
                "<board URL> --ros 2 --build PREFIX, then [ros2] prefix = PREFIX or "
                "MISSING_LINK_ROS2_PREFIX; [daemon] thesis_types = false: none, unsaid)",
                topic.name,
            )

    def _missing(self, type_name: str, why: str) -> None:
        if type_name not in self.missing_types:
            self.missing_types[type_name] = why
            log.warning("ros2: %s is not published: %s", type_name, why)

    # ---- the publisher interface -------------------------------------------------------------
    def add_topic(self, topic: Topic) -> None:
        cls = self._class_for(topic)
        if cls is None:
            return
        if topic.frame is not None:
            self._frame_parameter(topic)
        with self._lock:
            if self._closed or topic.name in self._pubs:
                return
            qos = self.state_qos if topic.transducer.is_actuator else self.qos
            self._pubs[topic.name] = self.node.create_publisher(cls, topic.name, qos)

    def add_command_topic(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        """A command topic: of the thesis type, each message a ``Command`` to the handler; of a
        standard type (``std_msgs/msg/Float64`` per actuator, the robot's ``JointState``
        commands), the message itself, decoded by rosbags."""
        cls = self._class_for(topic)
        if cls is None:
            return
        type_name, standard = topic.type_name, topic.standard
        if not standard:
            topic.register_type(self.typestore)  # to decode commands

        def on_command(raw: bytes) -> None:
            try:
                msg: Any = self.typestore.deserialize_cdr(raw, type_name)
                # (a Command's times[0]: when to act)
                deliver(msg if standard else Command.from_message(msg, time.time_ns()))
            except Exception as e:  # noqa: BLE001 - a bad command is counted, never fatal
                self.dropped += 1
                log.warning("ros2: command on %s refused: %s", name, e)

        with self._lock:
            if self._closed or name in self._subs:
                return
            self._subs[name] = self.node.create_subscription(
                cls, name, on_command, self.qos, raw=True
            )

    def _frame_parameter(self, topic: Topic) -> None:
        """``<board>.<transducer>.frame_id``: a string parameter of the node that sets the
        frame id of the transducer's standard messages, and follows a change made elsewhere
        (``Daemon.set_frame_id``).  After a reconnect the value set here is kept."""
        frame = topic.frame
        assert frame is not None
        name = f"{topic.board}.{topic.transducer.name}.frame_id"
        with self._lock:
            known = self._frames.get(name)
            if self._closed or known is frame:
                return
            self._frames[name] = frame
        if known is None:
            from rcl_interfaces.msg import ParameterDescriptor

            what = f"frame_id of {name[: -len('.frame_id')]}'s standard messages"
            self._frame_quiet(lambda: self.node.declare_parameter(
                name, frame.value, ParameterDescriptor(description=what)))  # fmt: skip
        else:
            value = str(self.node.get_parameter(name).value)
            if value != frame.value and known.set_at_run_time:
                frame.set(value)  # (a reconnect: the value set at run time is kept)
        frame.listeners.append(lambda value: self._frame_follow(name, value))

    def _frame_quiet(self, fn: Callable[[], Any]) -> None:
        self._frame_setting.on = True  # (not a change from a client: not handed back)
        try:
            fn()
        finally:
            self._frame_setting.on = False

    def _frame_follow(self, name: str, value: str) -> None:
        from rclpy.parameter import Parameter

        if self._closed or getattr(self._frame_setting, "on", False):
            return
        if self.node.get_parameter(name).value != value:
            self._frame_quiet(lambda: self.node.set_parameters([Parameter(name, value=value)]))

    def _on_frame_set(self, params: list[Any]) -> Any:
        from rcl_interfaces.msg import SetParametersResult

        if getattr(self._frame_setting, "on", False):
            return SetParametersResult(successful=True)
        for p in params:
            frame = self._frames.get(p.name)
            if frame is None:
                continue  # (a board's configuration key: ros2_params.py)
            self._frame_setting.on = True  # (its listener must not set it again)
            try:
                frame.set(p.value)
            except ValueError as e:
                return SetParametersResult(successful=False, reason=str(e))
            finally:
                self._frame_setting.on = False
        return SetParametersResult(successful=True)

    def add_config(
        self, board: str, keys: list[ConfigKey], values: dict[str, Value], apply: ApplyConfig
    ) -> None:
        with self._lock:
            if not self._closed:
                self.params.add_board(board, keys, values, apply)

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        if not self._closed:
            self.params.follow(board, values)

    def publish(self, update: Update) -> None:
        pub = self._pubs.get(update.topic.name)
        if pub is None or self._closed:
            return
        # encoded out here: an encoder that raises is a bug, counted by kind by the fan-out
        # (faults), never a drop
        cdr = update.cdr
        try:
            pub.publish(cdr)
        except TypeError:  # (what we handed it: a bug, for the fan-out to count)
            raise
        except Exception:  # noqa: BLE001 - rclpy refused (shutting down): a drop, counted
            self.dropped += 1
            return
        self.published += 1

    def log(self, line: LogLine) -> None:
        if self._closed:
            return
        cdr = rosout_cdr(
            self.typestore, line.host_ns, line.level, line.board, line.text, line.source
        )
        try:
            self._rosout.publish(cdr)
        except TypeError:  # (what we handed it: a bug, for the fan-out to count)
            raise
        except Exception:  # noqa: BLE001 - rclpy refused (shutting down): a drop, counted
            self.dropped += 1

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        try:
            self._diag.publish(cdr)
        except Exception:  # noqa: BLE001 - rclpy refused (shutting down): counted
            self.dropped += 1

    def status(self) -> dict[str, Any]:
        out = super().status()
        out.update(published=self.published, topics=len(self._pubs))
        if self.not_built and not self.error and not self.missing_types:
            out["message"] = (
                f"ok; {len(self.not_built)} thesis-format type(s) not built (create-msgs "
                "--build): their topics go out in standard types only"
            )
        if self.missing_types and not self.error:
            out.update(
                level=1,
                message=f"{len(self.missing_types)} type(s) not published: "
                + "; ".join(f"{k}: {v}" for k, v in self.missing_types.items()),
            )
        return out

    def shutdown(self) -> None:
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            self.rclpy.shutdown(context=self.context)
        self._spin.join(2.0)
