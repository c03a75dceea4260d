"""Byte links to boards, opened by URL: tcp, unix, serial, usb, memory; ``spy+`` dumps traffic,
``signed+`` seals and checks every record.

- :mod:`.base` - the :class:`Transport` interface (a read returns its bytes, or with
  ``read_stamped`` the bytes and when they arrived) and :class:`FdTransport` (descriptor links)
- :mod:`.registry` - schemes -> the module that opens them, imported on first use
- :mod:`.sockets` (tcp, unix), :mod:`.serialport`, :mod:`.usb` (original 2014 boards),
  :mod:`.in_process` (``memory://``), :mod:`.spy` (hex dump of any of them), :mod:`.signed`
  (signed records over any of them)
"""

from .base import FdTransport, Received, Transport
from .registry import check_url, open_transport, register_transport

__all__ = [
    "FdTransport",
    "Received",
    "Transport",
    "check_url",
    "open_transport",
    "register_transport",
]
