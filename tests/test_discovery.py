"""Discovery and hotplug at the enumerator boundary: board processes on real pseudo-terminals
appear in and vanish from a port listing; the daemon probes, starts and ends sessions, and
never disturbs the boards that stay."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable, Iterator

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import Config, ConfigError, parse_config
from missing_link.daemon.discover_spec import DiscoverSpec, PortInfo, parse_usb_id
from missing_link.daemon.intake.discovery import PortMatcher
from missing_link.daemon.session.status import SessionState
from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ml, wait_for

PICO = 0x2E8A


def all_up(d: Daemon) -> bool:
    return bool(d.sessions) and all(s.state == SessionState.UP for s in d.sessions)


def test_matcher_reports_appeared_and_vanished_ports() -> None:
    m = PortMatcher(DiscoverSpec(vid=PICO, serial="E66*"))
    a = PortInfo("/dev/ttyACM0", PICO, 5, "E6605838")
    other_vid = PortInfo("/dev/ttyACM1", 0x0403, 0x6001, "E66")
    not_usb = PortInfo("/dev/ttyS0")
    wrong_serial = PortInfo("/dev/ttyACM2", PICO, 5, "XYZ")
    assert m.update([a, other_vid, not_usb, wrong_serial]) == ([a], [])
    assert m.update([a]) == ([], [])
    b = PortInfo("/dev/ttyACM0", PICO, 5, "E66ffff")  # another board on the same device path
    assert m.update([b]) == ([b], [a])
    assert m.update([]) == ([], [b])


class Ports:
    """What the enumerator lists now: the test plugs and unplugs."""

    def __init__(self) -> None:
        self.now: dict[str, PortInfo] = {}

    def plug(self, device: str, vid: int = PICO, serial: str = "E660") -> None:
        self.now[device] = PortInfo(device, vid, 5, serial, "Board in FS mode")

    def unplug(self, device: str) -> None:
        del self.now[device]

    def __call__(self) -> list[PortInfo]:
        return list(self.now.values())


@pytest.fixture
def boards() -> Iterator[Callable[[str], tuple[subprocess.Popen[str], str]]]:
    procs: list[subprocess.Popen[str]] = []

    def start(name: str) -> tuple[subprocess.Popen[str], str]:
        proc, url = start_board_process("rate", len(procs), "pty", name=name)
        procs.append(proc)
        return proc, url[len("serial://") :]

    yield start
    for p in procs:
        stop_process(p)


@pytest.mark.slow
def test_boards_appear_vanish_and_come_back(boards) -> None:  # type: ignore[no-untyped-def]
    ports = Ports()
    spec = DiscoverSpec(ports=["/dev/pts/*"], vid=PICO, interval=0.1, probe_timeout=1.0)
    master, slave = os.openpty()  # a serial device that never answers (a GPS, a modem)
    try:
        with Daemon(Config(discover=spec), enumerate_ports=ports) as d:
            assert d.discovery is not None
            pa, dev_a = boards("left")
            ports.plug(dev_a)
            ports.plug("/dev/pts/9999", vid=0x0403)  # another vendor: never even probed
            assert wait_for(lambda: [s.name for s in d.sessions] == ["left"] and all_up(d))
            ports.plug(os.ttyname(slave))
            assert wait_for(lambda: os.ttyname(slave) in d.discovery.not_j2a, 10)  # type: ignore[union-attr]
            _pb, dev_b = boards("right")
            ports.plug(dev_b)
            assert wait_for(lambda: len(d.sessions) == 2 and all_up(d))
            right = next(s for s in d.sessions if s.name == "right")
            before = right.status()["samples"]
            # unplug the left board: its session ends, the right one runs on untouched
            ports.unplug(dev_a)
            stop_process(pa)
            assert wait_for(lambda: [s.name for s in d.sessions] == ["right"])
            assert wait_for(lambda: right.status()["samples"] > before + 20)
            assert right.status()["connects"] == 1 and right.state == SessionState.UP
            # plugged in again (a new pty, as a re-enumerated device may get): up again, same name
            _pa2, dev_a2 = boards("left")
            ports.plug(dev_a2)
            assert wait_for(lambda: sorted(s.name for s in d.sessions) == ["left", "right"])
            assert wait_for(lambda: all_up(d))
            st = d.discovery.status()
            assert st["appeared"] == 4 and st["vanished"] == 1  # the other vendor never matched
            assert "/dev/pts/9999" not in st["not_j2a"]
    finally:
        os.close(master)
        os.close(slave)


def test_discover_table_in_the_config() -> None:
    cfg = parse_config({"discover": {"ports": ["/dev/ttyACM*"], "vid": 0x2E8A, "interval": 2}})
    assert cfg.discover is not None and cfg.discover.vid == PICO and cfg.discover.interval == 2.0
    with pytest.raises(ConfigError, match=r"discover\.vid: 70000 is outside 0\.\.65535"):
        parse_config({"discover": {"vid": 70000}})
    with pytest.raises(ConfigError, match=r"discover\.pattern: unknown key"):
        parse_config({"discover": {"pattern": "x"}})


@pytest.mark.slow
def test_run_auto_with_no_boards_runs_and_ends_cleanly() -> None:
    r = ml("run", "--auto", "--duration", "1.5", timeout=60)
    assert r.returncode == 0, r.stderr
    assert "discovering boards on /dev/ttyACM* /dev/ttyUSB* usb://*" in r.stderr


def test_usb_devices_with_the_j2a_interface_are_listed() -> None:
    from missing_link.daemon.intake.discovery import usb_ports
    from missing_link.virtual import make_sim

    from .test_transports import FakeDevice, fake_usb

    devs = [FakeDevice(make_sim("thesis"), "A1", 1, 7), FakeDevice(make_sim("rangers"), "B2", 2, 3)]
    ports = usb_ports(fake_usb(devs))
    assert [(p.device, p.vid, p.serial_number) for p in ports] == [
        ("usb://1:7", 0x6666, "A1"),
        ("usb://2:3", 0x6666, "B2"),
    ]
    assert PortMatcher(DiscoverSpec()).update(ports)[0] == ports  # matched by default


@pytest.mark.slow
def test_a_kick_lists_at_once_and_udev_events_are_watched(boards) -> None:  # type: ignore[no-untyped-def]
    """With a 30 s listing interval a board still comes up at once when something kicks the
    loop (what udev's add/remove events do through pyudev; a container sends none, so the kick
    is driven here and the observer is only checked to be running)."""
    ports = Ports()
    spec = DiscoverSpec(ports=["/dev/pts/*"], vid=PICO, interval=30.0, probe_timeout=1.0)
    with Daemon(Config(discover=spec), enumerate_ports=ports) as d:
        assert d.discovery is not None
        assert d.discovery.status()["events"] == "udev"  # pyudev and libudev are installed
        _p, dev = boards("kicked")
        ports.plug(dev)
        d.discovery.kick()
        assert wait_for(lambda: all_up(d), 10)


def test_by_default_only_known_j2a_boards_are_probed() -> None:
    """A motor controller, a GPS or a 3D printer behind a USB-UART bridge is left alone unless
    the user lists its USB id; our firmware's boards and 2014 boards are probed."""
    pico = PortInfo("/dev/ttyACM0", 0x2E8A, 0x0005, "E660")
    esp32s3 = PortInfo("/dev/ttyACM1", 0x303A, 0x4001, "F1")
    ftdi = PortInfo("/dev/ttyUSB0", 0x0403, 0x6001, "A9")
    arduino = PortInfo("/dev/ttyACM2", 0x2341, 0x0043, "85")
    original = PortInfo("usb://1:7", 0x6666, 0xCAFE, "X")
    everything = [pico, esp32s3, ftdi, arduino, original]
    assert PortMatcher(DiscoverSpec()).update(everything)[0] == [pico, esp32s3, original]
    listed = DiscoverSpec(ids=[parse_usb_id("2341:*")])
    assert PortMatcher(listed).update(everything)[0] == [arduino, original]
    assert PortMatcher(DiscoverSpec(any_usb=True)).update(everything)[0] == everything
    cfg = parse_config({"discover": {"ids": ["0403:6001", "2341:*"]}})
    assert cfg.discover is not None and cfg.discover.ids == [(0x0403, 0x6001), (0x2341, None)]
    with pytest.raises(ConfigError, match=r"discover\.ids: 'nope' is not a USB id"):
        parse_config({"discover": {"ids": ["nope"]}})


@pytest.mark.slow
def test_run_auto_takes_the_filters_and_says_what_it_probes() -> None:
    r = ml(
        "run",
        "--auto",
        "--usb-id",
        "2341:*",
        "--port",
        "/dev/ttyACM*",
        "--duration",
        "0.5",
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "discovering boards on /dev/ttyACM* (USB 2341:*)" in r.stderr
    r = ml("run", "--auto", "--usb-id", "zz", "--duration", "1", timeout=60)
    assert r.returncode == 2 and "--usb-id 'zz' is not a USB id" in r.stderr


@pytest.mark.slow
def test_opening_a_serial_port_keeps_dtr_when_it_closes(boards) -> None:  # type: ignore[no-untyped-def]
    """HUPCL is cleared on open, so closing (a probe, a reconnect) leaves DTR as it is and the
    next open makes no edge (a pty carries no DTR line: the flag is what can be checked here)."""
    import termios

    from missing_link.transport import open_transport

    _p, dev = boards("dtr")
    t = open_transport(f"serial://{dev}")
    try:
        assert not termios.tcgetattr(t.fileno())[2] & termios.HUPCL  # type: ignore[attr-defined]
    finally:
        t.close()
    fd = os.open(dev, os.O_RDWR | os.O_NOCTTY)
    try:
        assert not termios.tcgetattr(fd)[2] & termios.HUPCL  # still clear after our close
    finally:
        os.close(fd)
