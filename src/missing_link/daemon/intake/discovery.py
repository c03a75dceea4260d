"""Discovery and hotplug: boards are found as their serial ports appear and dropped when they
vanish, without touching the other boards.

Theory of operation
-------------------
An *enumerator* lists the serial ports now present (pyserial's ``list_ports``: device, USB
VID/PID, serial number).  ``PortMatcher`` keeps the ports it has seen and, fed a new listing,
says which matching ports appeared and which vanished (pure code: a listing in, changes out).
A port matches when its device path matches one of ``ports`` (globs) and, where given, its
VID, PID and serial number (glob) match; by default any USB serial port (one with a VID) whose
device is ``/dev/ttyACM*`` or ``/dev/ttyUSB*``, and any USB device with the J2A interface
triple (listed as ``usb://BUS:ADDR``; original 2014 boards).

``DiscoveryService`` (the shell) polls the enumerator every ``interval`` s.  A port that
appears is *probed*: opened as a J2A link and handshaken within ``probe_timeout``; a board
that answers gets a session of its own (named by its ``board.name``, as any board); a port
that does not answer (a GPS, a modem) is remembered as "not J2A" and left alone until it
vanishes.  A port that vanishes ends its session at once (the device file is gone; waiting
for the link timeout would only log errors).  The listing (every ``interval``, 1 s) is the one
source of truth, the same on every system; where pyudev works, udev's events (a tty or USB
device added or removed) only *kick* the loop to list at once, so a board is up as soon as it
enumerates.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from typing import Any

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.clock import SYSTEM_CLOCK, Clock
from ...logs import ErrorCounts
from ..config import BoardSpec
from ..discover_spec import DiscoverSpec, PortInfo

log = logging.getLogger("missing_link.discovery")


def serial_ports() -> list[PortInfo]:
    """The serial ports present now (pyserial)."""
    from serial.tools import list_ports

    return [
        PortInfo(p.device, p.vid, p.pid, p.serial_number, p.description or "")
        for p in list_ports.comports()
    ]


class PortMatcher:
    """Matching ports in, (appeared, vanished) out.  Pure."""

    def __init__(self, spec: DiscoverSpec) -> None:
        self.spec = spec
        self.present: dict[str, PortInfo] = {}

    def update(self, listing: Iterable[PortInfo]) -> tuple[list[PortInfo], list[PortInfo]]:
        now = {p.device: p for p in listing if self.spec.matches(p)}
        appeared = [p for d, p in now.items() if self.present.get(d) != p]
        vanished = [p for d, p in self.present.items() if d not in now or now[d] != p]
        self.present = now
        return appeared, vanished


def usb_ports(usb: Any | None = None) -> list[PortInfo]:
    """USB devices with a J2A interface (0xFF/0x12/0xEF: original 2014 boards), as
    ``usb://BUS:ADDR`` "ports" (pyusb; needs libusb)."""
    from ...transport.usb import find_boards, usb_serial

    return [
        PortInfo(f"usb://{d.bus}:{d.address}", d.idVendor, d.idProduct, usb_serial(d), "J2A USB")
        for d in find_boards(usb)
    ]


def all_ports() -> list[PortInfo]:
    """Serial ports, and J2A USB devices where libusb is present."""
    ports = serial_ports()
    try:
        ports += usb_ports()
    except MissingLinkError as e:  # no libusb: serial ports only, said once
        if not _said_no_usb:
            _said_no_usb.append(True)
            log.warning("discovery: not listing USB devices: %s", e)
    return ports


_said_no_usb: list[bool] = []

Enumerator = Callable[[], list[PortInfo]]


class DiscoveryService:
    """Polls the enumerator and adds/removes the daemon's boards (one thread), through the two
    callables it is handed (``Daemon.add_board`` and ``Daemon.remove_board``)."""

    def __init__(
        self,
        spec: DiscoverSpec,
        enumerate_ports: Enumerator,
        add_board: Callable[[BoardSpec], object],
        remove_board: Callable[[str], object],
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        self.clock = clock  #: the daemon's: a probe's deadlines
        self.add_board = add_board
        self.remove_board = remove_board
        self.spec = spec
        self.enumerate = enumerate_ports
        self.matcher = PortMatcher(spec)
        self.not_j2a: dict[str, str] = {}  # device -> why the probe failed
        self.boards: dict[str, str] = {}  # device -> URL of its session
        self.appeared = self.vanished = self.scan_errors = 0
        #: listings that failed, by kind (the daemon's status shows them)
        self.faults = ErrorCounts(log, "discovery")
        self._stop = threading.Event()
        self._kick = threading.Event()
        self._thread = threading.Thread(target=self._run, name="discovery", daemon=True)
        self._observer: Any = None
        self.events = "polling"  #: "udev" when udev events kick the listing

    def start(self) -> None:
        self._watch_udev()
        self._thread.start()

    def kick(self) -> None:
        """List the ports now (a device was added or removed)."""
        self._kick.set()

    def _watch_udev(self) -> None:
        try:
            import pyudev  # type: ignore[import-untyped]

            monitor = pyudev.Monitor.from_netlink(pyudev.Context())
            monitor.filter_by("tty")
            monitor.filter_by("usb")
            self._observer = pyudev.MonitorObserver(monitor, callback=lambda _dev: self.kick())
            self._observer.start()
            self.events = "udev"
        except Exception as e:  # noqa: BLE001 - no pyudev/libudev/netlink: poll (said once,
            # and the status's events says "polling")
            log.info("discovery: no udev events (%s): listing every %g s", e, self.spec.interval)

    def stop(self, timeout: float = 1.0) -> None:
        self._stop.set()
        self._kick.set()
        if self._observer is not None:
            try:
                self._observer.stop()
            except Exception as e:  # noqa: BLE001 - stopping must not fail the daemon's stop
                self.faults.caught("stopping udev events", e)
        if self._thread.is_alive():
            self._thread.join(timeout)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.scan()
            except Exception as e:  # noqa: BLE001 - discovery must outlive any one listing:
                self.scan_errors += 1  # counted by kind, the first of each said
                self.faults.caught("listing ports", e)
            self._kick.wait(self.spec.interval)
            self._kick.clear()

    def scan(self) -> None:
        appeared, vanished = self.matcher.update(self.enumerate())
        for p in vanished:
            self.vanished += 1
            self.not_j2a.pop(p.device, None)
            url = self.boards.pop(p.device, None)
            if url is not None:
                log.warning("discovery: %s vanished: its board session ends", p.device)
                self.remove_board(url)
        for p in appeared:
            if self._stop.is_set():
                return
            self.appeared += 1
            url = p.device if "://" in p.device else f"serial://{p.device}"
            why = self.probe(url)
            if why is not None:
                self.not_j2a[p.device] = why
                log.info("discovery: %s is not a J2A board (%s): left alone", p.device, why)
                continue
            self.boards[p.device] = url
            log.warning("discovery: J2A board on %s (%s)", p.device, p.description or "serial")
            self.add_board(BoardSpec(url, uart_baud=self.spec.uart_baud))

    def probe(self, url: str) -> str | None:
        """None when a J2A board answers on ``url``, else why not."""
        try:
            board = Board.open(url, timeout=min(1.0, self.spec.probe_timeout), clock=self.clock)
        except MissingLinkError as e:
            return str(e)
        try:
            board.handshake(deadline=board.clock.monotonic() + self.spec.probe_timeout)
        except MissingLinkError as e:
            return str(e)
        finally:
            board.close()
        return None

    def status(self) -> dict[str, Any]:
        return {
            "events": self.events,
            "ports": sorted(self.matcher.present),
            "boards": dict(self.boards),
            "not_j2a": dict(self.not_j2a),
            "appeared": self.appeared,
            "vanished": self.vanished,
            "scan_errors": self.scan_errors,
        }
