"""A board's log line as ROS messages (docs/board-log.md).  Pure: values in, CDR bytes out, with
a rosbags typestore (the same one a face already holds).

* ``/rosout`` on ROS 2 (rclpy and Zenoh): ``rcl_interfaces/msg/Log``, ``name`` the board, the
  line's levels as they are (DEBUG 10 ... FATAL 50), ``function`` the transducer it is about;
  its QoS as rcl's rosout publishers have it (reliable, transient local, keep last 1000,
  lifespan 10 s), so ``ros2 topic echo /rosout`` and rqt_console see it like any node's.
* ``/rosout`` on ROS 1: ``rosgraph_msgs/Log`` (levels 1, 2, 4, 8, 16), filled by the ROS 1 face
  with rospy's own class (``ros1_level``).
* ``/<board>/log`` in recordings: ``foxglove_msgs/msg/Log``, the ROS 2 form of Foxglove's
  ``foxglove.Log`` schema (timestamp, level 1..5, message, name, file, line: the same fields),
  which Foxglove's Log panel reads; a rosbag2 recording keeps every topic in ROS 2 CDR, so the
  schema is the ROS 2 one, under the name Foxglove's documentation gives for it.
"""

from __future__ import annotations

from collections.abc import Container
from typing import Any

ROSOUT = "/rosout"
ROS2_LOG = "rcl_interfaces/msg/Log"
ROS1_LOG = "rosgraph_msgs/Log"
FOXGLOVE_LOG = "foxglove_msgs/msg/Log"
#: foxglove_msgs/msg/Log as the Foxglove SDK generates it (docs.foxglove.dev, "Log")
FOXGLOVE_LOG_MSG = """\
builtin_interfaces/Time timestamp
uint8 UNKNOWN=0
uint8 DEBUG=1
uint8 INFO=2
uint8 WARNING=3
uint8 ERROR=4
uint8 FATAL=5
uint8 level
string message
string name
string file
uint32 line
"""
#: rcl's rosout QoS (rmw_zenoh's key expression form): reliable, transient local, keep last
#: 1000, lifespan 10 s
ROSOUT_QOS = ":1:,1000:,:10,0:,,"
ROSOUT_DEPTH = 1000

_ROS1 = {10: 1, 20: 2, 30: 4, 40: 8, 50: 16}
_FOXGLOVE = {10: 1, 20: 2, 30: 3, 40: 4, 50: 5}


def log_topic(board: str, taken: Container[str] = ()) -> str:
    """A board's log topic in recordings and on the bus: ``/<board>/log``, or
    ``/<board>/board_log`` when a transducer of the board is called ``log``."""
    name = f"/{board}/log"
    return f"/{board}/board_log" if name in taken else name


def ros1_level(level: int) -> int:
    """rosgraph_msgs/Log's level for a ROS 2 level (DEBUG 1, INFO 2, WARN 4, ERROR 8, FATAL 16)."""
    return _ROS1.get(level, 16 if level > 40 else 1)


def foxglove_level(level: int) -> int:
    return _FOXGLOVE.get(level, 0)


def _time(typestore: Any, ns: int) -> Any:
    sec, nsec = divmod(ns, 1_000_000_000)
    return typestore.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def rosout_cdr(
    typestore: Any, stamp_ns: int, level: int, name: str, msg: str, function: str = ""
) -> bytes:
    """One ``rcl_interfaces/msg/Log`` (CDR): a board's line on ``/rosout``."""
    cls = typestore.types[ROS2_LOG]
    log = cls(
        stamp=_time(typestore, stamp_ns),
        level=level,
        name=name,
        msg=msg,
        file="",
        function=function,
        line=0,
    )
    return bytes(typestore.serialize_cdr(log, ROS2_LOG))


def register_foxglove_log(typestore: Any) -> None:
    """Make ``foxglove_msgs/msg/Log`` known to a typestore (once)."""
    if FOXGLOVE_LOG not in typestore.types:
        from rosbags.typesys import get_types_from_msg

        typestore.register(get_types_from_msg(FOXGLOVE_LOG_MSG, FOXGLOVE_LOG))


def foxglove_log_cdr(
    typestore: Any, stamp_ns: int, level: int, name: str, message: str, file: str = ""
) -> bytes:
    """One ``foxglove_msgs/msg/Log`` (CDR): a board's line in a recording."""
    register_foxglove_log(typestore)
    log = typestore.types[FOXGLOVE_LOG](
        timestamp=_time(typestore, stamp_ns),
        level=foxglove_level(level),
        message=message,
        name=name,
        file=file,
        line=0,
    )
    return bytes(typestore.serialize_cdr(log, FOXGLOVE_LOG))
