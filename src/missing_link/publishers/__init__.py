"""Publishers, chosen by name: ``bus`` (in-process), ``mcap`` (rosbag2 + MCAP), ``console``,
``zenoh`` (ROS 2 via rmw_zenoh's wire format), ``foxglove`` (live WebSocket), ``ros1`` (rospy).
More arrive as plugins through the ``missing_link.publishers`` entry-point group."""

from . import bus, console, foxglove, mcap, ros1, ros2, zenoh  # noqa: F401 - register the built-in publishers
from .base import Publisher, available_publishers, make_publisher, register_publisher
from .bus import Bus, Subscription
from .console import ConsolePublisher
from .mcap import McapPublisher, recover_bag

__all__ = [
    "Bus",
    "ConsolePublisher",
    "McapPublisher",
    "Publisher",
    "Subscription",
    "available_publishers",
    "make_publisher",
    "recover_bag",
    "register_publisher",
]
