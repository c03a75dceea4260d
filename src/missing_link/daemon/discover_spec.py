"""Which serial ports ``run --auto`` probes for boards (``[discover]``, ``--usb-id``): a port as
the system lists it, the USB identities of our firmware's boards, and the match of the two
(intake/discovery.py probes what matches; config.py reads the table)."""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field


@dataclass(frozen=True)
class PortInfo:
    device: str
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    description: str = ""


#: USB identities our firmware's boards enumerate with, probed by default (docs/hardware.md):
#: MicroPython on an RP2040 (Pico, Pico W) and on an ESP32-S2/S3 with native USB.  A board
#: behind a USB-UART bridge (an Arduino, an ESP32 DevKit's CP210x/CH340, an FTDI cable) shares
#: its VID:PID with motor controllers, GPS receivers and 3D printers: it is probed only when
#: listed (``--usb-id``, ``[discover] ids``).  Original 2014 boards are found by their J2A USB
#: interface (``usb://``), whatever their VID:PID.
KNOWN_J2A_IDS: tuple[tuple[int, int | None], ...] = ((0x2E8A, 0x0005), (0x303A, 0x4001))


def parse_usb_id(text: str) -> tuple[int, int | None]:
    """``2E8A:0005`` (hex) or ``2341:*`` (any PID of that vendor) -> (vid, pid or None)."""
    vid, sep, pid = text.strip().partition(":")
    try:
        if not sep:
            raise ValueError
        v = int(vid, 16)
        p = None if pid == "*" else int(pid, 16)
    except ValueError:
        raise ValueError(f"{text!r} is not a USB id like 2E8A:0005 or 2341:*") from None
    if not 0 <= v <= 0xFFFF or not (p is None or 0 <= p <= 0xFFFF):
        raise ValueError(f"{text!r}: VID and PID are 16-bit (0000..FFFF)")
    return v, p


@dataclass
class DiscoverSpec:
    ports: list[str] = field(
        default_factory=lambda: ["/dev/ttyACM*", "/dev/ttyUSB*", "usb://*"]
    )  #: device globs; usb://* = USB devices with the J2A interface
    #: USB identities that are probed (vid, pid or None for any): known J2A boards by default
    ids: list[tuple[int, int | None]] = field(default_factory=lambda: list(KNOWN_J2A_IDS))
    vid: int | None = None  #: only this vendor (with ``pid``: only this product)
    pid: int | None = None
    serial: str | None = None  #: glob on the USB serial number
    any_usb: bool = False  #: probe every USB serial port, whatever its VID:PID (not ``ids``)
    usb_only: bool = True  #: only ports with a USB VID (not on-board UARTs)
    interval: float = 1.0  #: s between listings
    probe_timeout: float = 3.0  #: s for a new port to answer the J2A handshake
    uart_baud: int = 0  #: set when the boards sit behind UART bridges (see BoardSpec)

    def matches(self, p: PortInfo) -> bool:
        if not any(fnmatch.fnmatchcase(p.device, g) for g in self.ports):
            return False
        if self.serial is not None and not fnmatch.fnmatchcase(p.serial_number or "", self.serial):
            return False
        if p.device.startswith("usb://"):
            return True  # listed because it has the J2A interface (2014 boards)
        if self.usb_only and p.vid is None:
            return False
        if self.vid is not None:  # an explicit vendor (and product): that one only
            return p.vid == self.vid and (self.pid is None or p.pid == self.pid)
        if self.any_usb:
            return self.pid is None or p.pid == self.pid
        return any(p.vid == v and (q is None or p.pid == q) for v, q in self.ids)

    def describe(self) -> str:
        """What is probed, for the user (one line)."""
        if self.vid is not None:
            who = f"USB {self.vid:04X}:" + ("*" if self.pid is None else f"{self.pid:04X}")
        elif self.any_usb:
            who = "every USB serial port"
        else:
            who = "USB " + ", ".join(
                f"{v:04X}:" + ("*" if q is None else f"{q:04X}") for v, q in self.ids
            )
        return f"{' '.join(self.ports)} ({who}{', serial ' + self.serial if self.serial else ''})"
