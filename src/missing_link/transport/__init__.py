"""Byte links to boards, opened by URL: tcp, unix, serial, usb, memory; ``spy+`` dumps traffic.

- :mod:`.base` - the :class:`Transport` interface and :class:`FdTransport` (descriptor links)
- :mod:`.registry` - schemes -> the module that opens them, imported on first use
- :mod:`.sockets` (tcp, unix), :mod:`.serialport`, :mod:`.usb` (original 2014 boards),
  :mod:`.memory` (in-process), :mod:`.spy` (hex dump of any of them)
"""

from .base import FdTransport, Transport
from .registry import check_url, open_transport, register_transport

__all__ = ["FdTransport", "Transport", "check_url", "open_transport", "register_transport"]
