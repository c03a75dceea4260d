"""Byte links to boards, opened by URL: tcp, unix, serial, usb, memory; ``spy+`` dumps traffic."""

from . import memory, serialport, sockets, usb  # noqa: F401 - register the URL schemes
from .base import FdTransport, Transport, check_url, open_transport, register_transport
from .memory import MemoryListener, MemoryTransport, memory_pair
from .spy import SpyTransport

__all__ = [
    "FdTransport",
    "MemoryListener",
    "MemoryTransport",
    "SpyTransport",
    "Transport",
    "check_url",
    "memory_pair",
    "open_transport",
    "register_transport",
]
