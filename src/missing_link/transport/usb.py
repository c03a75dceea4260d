"""``usb://[BUS:ADDR][?serial=S]``: original J2A USB boards through pyusb + libusb-1.0 (spec 1.9).

A board is found by its J2A interface (class/subclass/protocol 0xFF/0x12/0xEF), never by VID/PID.
The byte stream is the frame stream: one OUT transfer per frame on endpoint 0x02, IN endpoint 0x81
read continuously in 64-byte packets (a short packet ends a transfer).

Verified here only against a fake at the pyusb boundary (tests/test_transports.py); see
docs/hardware.md for using a real board and what has not been verified.
"""

from __future__ import annotations

import threading
from typing import Any
from urllib.parse import urlsplit

from ..errors import BadURL, TransportBroken, TransportClosed
from .base import Transport

J2A_CLASS = (0xFF, 0x12, 0xEF)
EP_IN = 0x81
EP_OUT = 0x02
PACKET = 64
READ_SIZE = PACKET * 16


def _usb_core() -> Any:
    try:
        import usb.core
        import usb.util
    except ImportError as e:  # pragma: no cover - pyusb is a dependency
        raise TransportBroken(f"usb:// needs pyusb: {e}") from e
    return usb


def j2a_interface(dev: Any) -> Any | None:
    """The J2A interface of ``dev`` (active configuration), or None."""
    try:
        cfg = dev.get_active_configuration()
    except Exception:  # noqa: BLE001 - pyusb/backends raise various errors for unconfigured devices
        try:  # (an answer, not an error: such a device is not a J2A board)
            cfg = next(iter(dev))
        except Exception:  # noqa: BLE001 - same: such a device has no interface to offer
            return None
    for intf in cfg:
        triple = (intf.bInterfaceClass, intf.bInterfaceSubClass, intf.bInterfaceProtocol)
        if triple == J2A_CLASS:
            return intf
    return None


def _describe(dev: Any) -> str:
    return f"bus {dev.bus} address {dev.address} ({dev.idVendor:04x}:{dev.idProduct:04x})"


def find_boards(usb: Any | None = None) -> list[Any]:
    usb = usb or _usb_core()
    try:
        found = usb.core.find(find_all=True, custom_match=lambda d: j2a_interface(d) is not None)
        return list(found)
    except Exception as e:  # noqa: BLE001 - NoBackendError, USBError: say what to install
        if type(e).__name__ == "NoBackendError":
            raise TransportBroken(
                "usb:// needs libusb (Debian: apt install libusb-1.0-0); pyusb found no backend"
            ) from None
        raise TransportBroken(f"usb:// cannot list USB devices: {e}") from None


class USBTransport(Transport):
    def __init__(self, url: str, dev: Any, usb: Any) -> None:
        self.url = url
        self._usb = usb
        self._dev = dev
        self._closed = False
        self._wlock = threading.Lock()
        intf = j2a_interface(dev)
        if intf is None:
            raise TransportBroken(f"{url}: {_describe(dev)} has no J2A interface")
        self._intf = intf.bInterfaceNumber
        try:
            if dev.is_kernel_driver_active(self._intf):
                dev.detach_kernel_driver(self._intf)
        except (NotImplementedError, usb.core.USBError):  # (no driver to detach here: the
            pass  # claim below says whether the interface is ours)
        try:
            usb.util.claim_interface(dev, self._intf)
        except usb.core.USBError as e:
            raise TransportBroken(
                f"{url}: cannot claim the J2A interface of {_describe(dev)}: {e} "
                "(permissions? see docs/hardware.md for a udev rule)"
            ) from e
        eps = {ep.bEndpointAddress: ep for ep in intf}
        if EP_IN not in eps or EP_OUT not in eps:
            raise TransportBroken(
                f"{url}: J2A interface lacks endpoints 0x81/0x02 (has {sorted(eps)})"
            )
        self._in: Any = eps[EP_IN]
        self._out: Any = eps[EP_OUT]

    def _fail(self, op: str, e: Exception) -> TransportBroken:
        return TransportBroken(f"{self.url}: USB {op} failed: {e} (board unplugged?)")

    def read(self, timeout: float | None) -> bytes:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")
        ms = 0 if timeout is None else max(1, int(timeout * 1000))
        try:
            data = self._in.read(READ_SIZE, timeout=ms)
        except self._usb.core.USBTimeoutError:
            return b""
        except self._usb.core.USBError as e:
            if self._closed:
                raise TransportClosed(f"{self.url}: transport closed on this side") from e
            raise self._fail("read", e) from e
        return bytes(data)

    def write(self, data: bytes) -> None:
        self.write_frames([data])

    def write_frames(self, frames: list[bytes]) -> None:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")
        with self._wlock:
            for frame in frames:  # one OUT transfer per frame (spec 1.9)
                try:
                    self._out.write(frame, timeout=1000)
                except self._usb.core.USBError as e:
                    raise self._fail("write", e) from e

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._usb.util.release_interface(self._dev, self._intf)
            self._usb.util.dispose_resources(self._dev)
        except Exception:  # noqa: BLE001 - the device may already be gone (unplugged: why the
            pass  # link closes); closing must not fail, and the link's end is said already


def open_usb(url: str, query: dict[str, str], usb: Any | None = None) -> USBTransport:
    usb = usb or _usb_core()
    where = urlsplit(url).netloc
    boards = find_boards(usb)
    if where:
        try:
            bus_s, addr_s = where.split(":")
            bus, addr = int(bus_s), int(addr_s)
        except ValueError as e:
            raise BadURL(f"{url!r}: expected usb://BUS:ADDR (decimal), got {where!r}") from e
        boards = [d for d in boards if d.bus == bus and d.address == addr]
    if "serial" in query:
        boards = [d for d in boards if usb_serial(d) == query["serial"]]
    if not boards:
        raise TransportBroken(
            f"{url}: no USB device with a J2A interface (0xFF/0x12/0xEF) found"
            + (f" matching {where or ''} {query}" if where or query else "")
        )
    if len(boards) > 1:
        names = "; ".join(f"{_describe(d)} serial={usb_serial(d)!r}" for d in boards)
        raise BadURL(f"{url}: {len(boards)} J2A boards match, pick one with ?serial=: {names}")
    return USBTransport(url, boards[0], usb)


def usb_serial(dev: Any) -> str | None:
    try:
        return str(dev.serial_number) if dev.serial_number is not None else None
    except Exception:  # noqa: BLE001 - string descriptors need permissions some users lack:
        return None  # an answer (serial unknown), not an error
