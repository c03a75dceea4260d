"""Publishers: the faces every transducer's topic is published on, chosen by name.

- :mod:`.base` - the :class:`Publisher` interface; :mod:`.rosbase` - the ROS-flavoured ones' base
- :mod:`.registry` - names -> module and class, imported on first use; what each needs
- :mod:`.bus` (in-process), :mod:`.console`, :mod:`.mcap` (rosbag2 + MCAP; :mod:`.recover`
  salvages a dead recording), :mod:`.zenoh` (ROS 2 via rmw_zenoh's wire format), :mod:`.ros2`
  (rclpy), :mod:`.ros1` (rospy), :mod:`.foxglove` (live WebSocket), :mod:`.web` (the device
  console in a browser; :mod:`.gate`: the front door both share)

More arrive as plugins through the ``missing_link.publishers`` entry-point group.
"""

from .base import Publisher, PublisherError
from .registry import (
    available_publishers,
    known_publishers,
    make_publisher,
    register_publisher,
    unavailable,
)

__all__ = [
    "Publisher",
    "PublisherError",
    "available_publishers",
    "known_publishers",
    "make_publisher",
    "register_publisher",
    "unavailable",
]
