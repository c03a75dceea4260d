"""Transports by URL: real sockets and pseudo-terminals; USB faked only at the pyusb boundary."""

from __future__ import annotations

import fcntl
import io
import os
import select
import socket
import struct
import sys
import termios
import threading
import time
import types
from typing import Any

import pytest

from missing_link import BadURL, Board, LinkLost, TransportBroken, TransportClosed, open_board
from missing_link.board.runtime import BoardRuntime
from missing_link.testing import wait_for
from missing_link.transport import FdTransport, open_transport
from missing_link.transport import usb as usb_transport
from missing_link.transport.spy import SpyTransport
from missing_link.virtual import make_sim

Serve = Any


@pytest.mark.parametrize(
    ("url", "msg"),
    [
        ("COM3", "not a board URL"),
        ("nope://x", "unknown transport 'nope'"),
        ("tcp://127.0.0.1", "expected tcp://HOST:PORT"),
        ("tcp://127.0.0.1:99999", "bad port"),
        ("serial://", "expected serial:///dev/DEVICE"),
        ("serial:///dev/ttyX?baud=fast", "baud must be a number"),
        ("unix://", "expected unix:///path"),
    ],
)
def test_bad_urls_say_what_is_wrong(url: str, msg: str) -> None:
    with pytest.raises(BadURL, match=msg):
        open_transport(url)


def test_unreachable_endpoints_are_broken_not_bad() -> None:
    with pytest.raises(TransportBroken, match="cannot connect"):
        open_transport("tcp://127.0.0.1:1")
    with pytest.raises(TransportBroken, match="cannot open"):
        open_transport("serial:///dev/does-not-exist")


@pytest.mark.parametrize("listen", ["tcp://127.0.0.1:0", "pty", "unix"])
def test_real_links(serve: Serve, listen: str, tmp_path: Any) -> None:
    if listen == "unix":
        listen = f"unix://{tmp_path}/board.sock"
    server = serve("thesis", listen)
    if listen == "pty":
        assert server.url.startswith("serial:///dev/pts/")
    with open_board(server.url) as board:
        payload = bytes(range(256))[:255]  # every special byte escaped on a real link
        for _ in range(20):
            assert board.call("a2jEcho", payload).payload == payload
        assert board.link_stats().bad_checksums == 0


def test_socket_closed_vs_broken(serve: Serve) -> None:
    server = serve("thesis", "tcp://127.0.0.1:0")
    t = open_transport(server.url)
    t.close()
    with pytest.raises(TransportClosed):
        t.read(0.1)
    t = open_transport(server.url)
    server.stop()
    # "closed" when the board had accepted us; "reset" when the listener closed with our
    # connection still in its backlog (the board had not yet seen the first host go)
    with pytest.raises(TransportBroken, match=r"other side closed|reset"):
        for _ in range(100):
            t.read(0.1)
    t.close()


def test_pty_survives_host_reconnect(serve: Serve) -> None:
    server = serve("thesis", "pty")
    for _ in range(3):
        with open_board(server.url) as board:
            assert board.call("a2jEcho", b"again").payload == b"again"


def test_spy_dumps_both_directions(serve: Serve) -> None:
    server = serve("thesis")
    out = io.StringIO()
    spy = SpyTransport(open_transport(server.url), out)
    board = Board(spy)
    try:
        board.call_index(board_index := 4, b"\x12hi", "a2jEcho")
    finally:
        board.close()
    text = out.getvalue()
    assert board_index == 4
    assert "TX 9 bytes" in text and "12 00 04 03 7d 11 68 69 78" in text
    assert "RX" in text
    assert open_transport("spy+" + server.url).url.startswith("spy+memory://")


# ---- USB: a fake pyusb whose device is a board runtime ------------------------------------------
class FakeUSBError(Exception):
    pass


class FakeUSBTimeout(FakeUSBError):
    pass


class FakeEndpoint:
    def __init__(self, address: int, dev: FakeDevice) -> None:
        self.bEndpointAddress = address
        self.dev = dev

    def write(self, data: bytes, timeout: int) -> int:
        self.dev.out_transfers.append(bytes(data))
        if self.dev.unplugged:
            raise FakeUSBError("[Errno 19] No such device")
        self.dev.runtime.feed(bytes(data))
        return len(data)

    def read(self, size: int, timeout: int) -> bytes:
        if self.dev.unplugged:
            raise FakeUSBError("[Errno 19] No such device")
        self.dev.runtime.poll()
        self.dev.pending += self.dev.runtime.take_output()
        if not self.dev.pending:
            raise FakeUSBTimeout("timeout")
        chunk, self.dev.pending = self.dev.pending[:size], self.dev.pending[size:]
        return chunk


class FakeInterface:
    def __init__(self, dev: FakeDevice, triple: tuple[int, int, int], number: int) -> None:
        self.bInterfaceClass, self.bInterfaceSubClass, self.bInterfaceProtocol = triple
        self.bInterfaceNumber = number
        self.eps = [FakeEndpoint(0x81, dev), FakeEndpoint(0x02, dev)]

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self.eps)


class FakeDevice:
    def __init__(self, runtime: BoardRuntime, serial: str, bus: int, address: int) -> None:
        self.runtime = runtime
        self.serial_number = serial
        self.bus, self.address = bus, address
        self.idVendor, self.idProduct = 0x6666, 0xCAFE
        self.pending = b""
        self.unplugged = False
        self.claimed = False
        self.out_transfers: list[bytes] = []
        # A composite device: a SyncUSB interface first, then the J2A one.
        self.config = [
            FakeInterface(self, (0xFF, 0x00, 0x00), 0),
            FakeInterface(self, (0xFF, 0x12, 0xEF), 1),
        ]

    def get_active_configuration(self) -> list[FakeInterface]:
        return self.config

    def is_kernel_driver_active(self, n: int) -> bool:
        return False


def fake_usb(devices: list[FakeDevice]) -> Any:
    def find(find_all: bool, custom_match: Any) -> list[FakeDevice]:
        return [d for d in devices if custom_match(d)]

    def claim(dev: FakeDevice, n: int) -> None:
        assert n == 1
        dev.claimed = True

    def release(dev: FakeDevice, n: int) -> None:
        dev.claimed = False

    core = types.SimpleNamespace(find=find, USBError=FakeUSBError, USBTimeoutError=FakeUSBTimeout)
    util = types.SimpleNamespace(
        claim_interface=claim, release_interface=release, dispose_resources=lambda d: None
    )
    return types.SimpleNamespace(core=core, util=util)


def test_usb_board_through_pyusb_boundary() -> None:
    dev = FakeDevice(make_sim("thesis", seed=3), "A1", 1, 7)
    other = FakeDevice(make_sim("rangers", seed=3), "B2", 1, 9)
    usb = fake_usb([dev, other])
    t = usb_transport.open_usb("usb://?serial=A1", {"serial": "A1"}, usb=usb)
    board = Board(t)
    try:
        board.handshake()
        assert board.properties["board.name"] == "thesis" and dev.claimed
        assert board.call("a2jEcho", b"usb").payload == b"usb"
        # one OUT transfer per frame
        assert all(f[0] == 0x12 for f in dev.out_transfers)
        dev.unplugged = True
        with pytest.raises(LinkLost) as err:
            board.call("a2jEcho", b"gone")
        assert err.value.broken and "board unplugged?" in str(err.value)
    finally:
        board.close()
    assert not dev.claimed


def test_usb_selection_errors() -> None:
    devs = [FakeDevice(make_sim("thesis"), "A1", 1, 7), FakeDevice(make_sim("thesis"), "A2", 2, 3)]
    usb = fake_usb(devs)
    with pytest.raises(BadURL, match="2 J2A boards match, pick one with"):
        usb_transport.open_usb("usb://", {}, usb=usb)
    assert usb_transport.open_usb("usb://2:3", {}, usb=usb)._dev is devs[1]
    with pytest.raises(TransportBroken, match="no USB device with a J2A interface"):
        usb_transport.open_usb("usb://?serial=zz", {"serial": "zz"}, usb=usb)
    with pytest.raises(BadURL, match="BUS:ADDR"):
        usb_transport.open_usb("usb://x", {}, usb=usb)


def test_pty_raw_mode_keeps_special_bytes(serve: Serve) -> None:
    server = serve("thesis", "pty")
    path = server.url[len("serial://") :]
    assert os.path.exists(path)
    with open_board(server.url) as board:
        tricky = b"\x11\x12\x13\x03\x04\x1a\x7d\xed\r\n\x00\xff"
        assert board.call("a2jEcho", tricky).payload == tricky


@pytest.mark.skipif(sys.platform != "linux", reason="SO_TIMESTAMPNS is Linux's")
def test_tcp_reads_are_stamped_when_the_bytes_arrived_not_when_read() -> None:
    """The kernel's receive stamp is clock sync's t4 over TCP: after the bytes were sent (causal)
    and before the read that took them (the reader's wake-up is not in it), while a clock
    exchange is in flight; other reads take the cheaper plain recv and are stamped after it."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    t = open_transport(f"tcp://127.0.0.1:{listener.getsockname()[1]}")
    peer, _ = listener.accept()
    try:
        early = 0
        t.count_arrivals = True  # a clock exchange in flight
        for _ in range(5):
            sent = time.monotonic_ns()
            peer.sendall(b"\x7e" * 40)
            time.sleep(0.02)  # the reader is late
            before_read = time.monotonic_ns()
            data, rx_ns, _first = t.read_stamped(1.0)
            assert data == b"\x7e" * 40
            assert sent <= rx_ns  # causal, kernel stamp or not
            early += rx_ns < before_read
        # The kernel turns receive stamping on a little after the first socket asks (a deferred
        # static key): the first segments may come unstamped, and then our own stamp is used.
        assert early >= 3
        t.count_arrivals = False  # no exchange in flight: stamped after the read
        sent = time.monotonic_ns()
        peer.sendall(b"\x7e" * 40)
        time.sleep(0.02)
        before_read = time.monotonic_ns()
        data, rx_ns, first_rx_ns = t.read_stamped(1.0)
        assert data == b"\x7e" * 40
        assert rx_ns >= before_read and first_rx_ns == 0
    finally:
        t.close()
        peer.close()
        listener.close()


@pytest.mark.skipif(sys.platform != "linux", reason="a pty")
def test_serial_reads_are_stamped_when_the_driver_counted_the_bytes() -> None:
    """Over a serial port (here a pty), while a clock exchange is in flight, t4 is taken when
    the driver reported the bytes waiting, before pyserial's read (a select and a read in
    Python), and after they were written."""
    master, slave = os.openpty()
    t = open_transport(f"serial://{os.ttyname(slave)}")
    t.count_arrivals = True
    port = t.port  # type: ignore[attr-defined]
    plain_read = port.read
    read_started: list[int] = []

    def recording_read(n: int) -> bytes:
        read_started.append(time.monotonic_ns())
        return plain_read(n)

    port.read = recording_read
    try:
        for _ in range(3):
            sent = time.monotonic_ns()
            os.write(master, b"\x7e" * 40)
            time.sleep(0.02)
            data, rx_ns, _first = t.read_stamped(1.0)
            assert data == b"\x7e" * 40
            assert sent <= rx_ns < read_started[-1]
    finally:
        t.close()
        os.close(master)
        os.close(slave)


@pytest.mark.skipif(sys.platform != "linux", reason="a pty")
def _waiting(fd: int) -> int:
    """The bytes waiting to be read on a tty's ``fd`` (FIONREAD)."""
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]  # type: ignore[no-any-return]


def test_bytes_counted_at_the_wake_are_stamped_then_and_only_they() -> None:
    """While a clock exchange is in flight the reader counts the bytes waiting as its wait
    returns: those get that moment as t4, and the read takes exactly them; bytes that came
    after the count are read next, with a stamp after they were written."""
    master, slave = os.openpty()
    t = open_transport(f"serial://{os.ttyname(slave)}")
    try:
        os.write(master, b"\x7e" * 10)
        # a pty hands bytes on from its master in the kernel's own time (a busy machine: later
        # than 20 ms): wait until the board's side has them all, by their count, not a sleep
        assert wait_for(lambda: _waiting(slave) == 10, 10, 0.001)
        t.count_arrivals = True
        t.count_arrived()
        counted_by = time.monotonic_ns()
        os.write(master, b"\x7f" * 5)  # arrives after the count
        second_sent = time.monotonic_ns()
        assert wait_for(lambda: _waiting(slave) == 15, 10, 0.001)
        assert isinstance(t, FdTransport)
        data, rx_ns, first_rx_ns = t.read_ready()
        assert data == b"\x7e" * 10
        assert rx_ns <= counted_by  # stamped at the count, before the second write
        assert first_rx_ns == 0  # (the count was not told when a wait returned)
        data, rx_ns, first_rx_ns = t.read_stamped(1.0)
        assert data == b"\x7f" * 5
        assert rx_ns >= second_sent
        assert 0 < first_rx_ns <= rx_ns  # its own wait returned when the first byte was there
    finally:
        t.close()
        os.close(master)
        os.close(slave)


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="a pty; SO_TIMESTAMPNS")
@pytest.mark.parametrize("shared_loop", [False, True])
@pytest.mark.parametrize("link", ["pty", "tcp"])
def test_a_clock_reply_heading_a_read_is_stamped_at_the_wake_and_stays_causal(
    shared_loop: bool, link: str
) -> None:
    """A clock reply that starts the read is stamped when the wait returned (``head_ns``), not
    at the byte count after the host's own work; against a board process whose clock is this
    machine's CLOCK_MONOTONIC (in µs), that stamp is never before the board sent the reply,
    on a board's own reader thread and on the daemon's shared I/O loop.  Over TCP both ends
    take the kernel's receive stamps (the virtual board's t2 too): still causal."""
    from missing_link.host.reactor import Reactor
    from missing_link.virtual.process import start_board_process, stop_process

    proc, url = start_board_process("rate", 3, "pty" if link == "pty" else "tcp://127.0.0.1:0")
    reactor = Reactor().start() if shared_loop else None
    board = Board(open_transport(url), timeout=1.0, reactor=reactor)
    try:
        board.handshake()
        heads = 0
        for _ in range(60):
            board.link.transport.count_arrivals = True
            result = board.call_future("a2jClock", b"").result(2.0)
            board.link.transport.count_arrivals = False
            t2, t3 = (int.from_bytes(result.payload[i : i + 8], "little") for i in (0, 8))
            assert result.sent_ns <= (t2 + 1) * 1000  # the request was sent before it arrived
            assert t3 * 1000 <= result.recv_ns
            if result.head_ns:
                heads += 1
                assert t3 * 1000 <= result.head_ns < result.recv_ns  # causal, and earlier
            time.sleep(0.01)
        if link == "pty":
            assert heads >= 30  # the reply headed almost every read
        else:
            assert heads == 0  # (TCP: the kernel's stamp is earlier still)
        ex = board.clock_exchange(1.0)  # and the exchange takes the tighter stamp
        assert ex.t3 * 1000 <= ex.t4 and ex.down_min_ns == 0
    finally:
        board.close()
        if reactor is not None:
            reactor.stop()
        stop_process(proc)


@pytest.mark.skipif(sys.platform != "linux", reason="a pty")
def test_a_serial_write_into_a_full_buffer_waits_for_the_board_to_read() -> None:
    """A board that reads slower than the host writes (a UART; simavr's pty under load) fills
    the port's buffer: the write waits for room and goes on (it failed at once with EAGAIN,
    and the link ended); a board that takes nothing for the port's write timeout fails it,
    saying so."""
    master, slave = os.openpty()
    t = open_transport(f"serial://{os.ttyname(slave)}")
    data = bytes(range(256)) * 1024  # 256 KiB: many times a pty's buffer
    ended: list[BaseException | None] = []

    def write() -> None:
        try:
            t.write(data)
            ended.append(None)
        except BaseException as e:  # noqa: BLE001 - the test reports it
            ended.append(e)

    writer = threading.Thread(target=write)
    try:
        writer.start()
        # the board reads nothing until the port is full (a write that did not wait has ended)
        assert wait_for(lambda: ended or not select.select([], [slave], [], 0)[1])
        got = bytearray()
        while len(got) < len(data) and select.select([master], [], [], 5.0)[0]:
            got += os.read(master, 4096)  # a page at a time: the writer waits between
        writer.join(5.0)
        assert ended == [None] and bytes(got) == data
        t.write_timeout = 0.2  # (the port's, 2 s by default)
        with pytest.raises(TransportBroken, match=r"the board took nothing for 0\.2 s"):
            t.write(data)  # nothing reads now
    finally:
        t.close()
        os.close(master)
        os.close(slave)
