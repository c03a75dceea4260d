# The board's side of the backbone link on a microcontroller: USB CDC (the REPL's stdin/stdout),
# a UART, or TCP on a network (an ESP32 on WiFi: the network is the user's boot.py's to join).
# read() -> bytes available now (or None), write(bytes), wait(µs): sleep until input or the
# timeout, close(): hand the port back to the REPL.  A link with a `key_file` carries signed
# records (signing.py): on a network, a board with a key takes nothing unsigned.

import sys


class StdioLink:
    # USB CDC on rp2/esp32-s2/s3 (and the UART REPL on plain esp32): sys.stdin/stdout in binary.
    # Ctrl-C is turned off so a 0x03 in a frame does not interrupt the firmware; see firmware.py
    # for the way back to the REPL.
    def __init__(self):
        import select

        import micropython

        micropython.kbd_intr(-1)
        self._micropython = micropython
        self._in = sys.stdin.buffer
        self._out = sys.stdout.buffer
        self._poll = select.poll()
        self._poll.register(sys.stdin, select.POLLIN)

    def read(self):
        data = bytearray()
        while len(data) < 256 and self._poll.poll(0):
            data.extend(self._in.read(1))
        return bytes(data) if data else None

    def write(self, data):
        self._out.write(data)

    def wait(self, us):
        self._poll.poll(max(0, us // 1000))

    def close(self):
        self._micropython.kbd_intr(3)


class UartLink:
    def __init__(self, machine, uart_id=0, baudrate=115200, tx=None, rx=None, rxbuf=1024):
        kw = {"baudrate": baudrate, "rxbuf": rxbuf}
        if tx is not None:
            kw["tx"] = machine.Pin(tx)
        if rx is not None:
            kw["rx"] = machine.Pin(rx)
        self._uart = machine.UART(uart_id, **kw)
        import time

        self._time = time

    def read(self):
        n = self._uart.any()
        return self._uart.read(n) if n else None

    def write(self, data):
        self._uart.write(data)

    def wait(self, us):
        # The UART has no poll on every port: sleep in short slices, at most 1 ms late.
        t = self._time
        end = t.ticks_add(t.ticks_us(), us)
        while not self._uart.any():
            left = t.ticks_diff(end, t.ticks_us())
            if left <= 0:
                break
            t.sleep_us(min(1000, left))

    def close(self):
        self._uart.deinit()


class TcpLink:
    # One host at a time on a TCP port (a new connection replaces the old one: the host
    # reconnected).  Blocking sockets, read only when a poll says there are bytes.
    def __init__(self, port=5000, host="0.0.0.0"):
        import select
        import socket

        self._select = select
        self._srv = socket.socket()
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind(socket.getaddrinfo(host, port)[0][-1])
        self._srv.listen(1)
        self._conn = None

    def _ready(self, sock, ms=0):
        p = self._select.poll()
        p.register(sock, self._select.POLLIN)
        return bool(p.poll(ms))

    def _drop(self):
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def read(self):
        if self._ready(self._srv):
            conn, _addr = self._srv.accept()
            self._drop()
            self._conn = conn
        if self._conn is None or not self._ready(self._conn):
            return None
        try:
            data = self._conn.recv(512)
        except OSError:
            data = b""
        if not data:  # the host closed: wait for the next
            self._drop()
            return None
        return data

    def write(self, data):
        if self._conn is None:
            return  # nobody listening: like a UART with nothing attached
        try:
            self._conn.sendall(data)
        except OSError:
            self._drop()

    def wait(self, us):
        p = self._select.poll()
        p.register(self._srv, self._select.POLLIN)
        if self._conn is not None:
            p.register(self._conn, self._select.POLLIN)
        p.poll(max(0, us // 1000))

    def close(self):
        self._drop()
        self._srv.close()


class FileCounter:
    # an integer kept in a file (a board's boot count, the newest host timestamp)
    def __init__(self, path):
        self.path = path

    def load(self):
        try:
            with open(self.path) as f:
                return int(f.read())
        except (OSError, ValueError):
            return None

    def save(self, value):
        tmp = self.path + ".tmp"
        with open(tmp, "w") as f:
            f.write(str(value))
        import os

        os.rename(tmp, self.path)


def signed(link, cfg, clock_ms):
    # the link in signed records when the board file names a key (signing.py), else itself
    key_file = cfg.get("key_file")
    if not key_file:
        return link
    from .signing import SignedLink

    with open(key_file, "rb") as f:
        key = f.read()
    text = key.strip()
    if len(text) == 64:  # (missing-link key new writes hex; a raw 32-byte key works too)
        key = bytes.fromhex(text.decode())
    boots = FileCounter(cfg.get("boot_file", "mlboots.txt"))
    n = (boots.load() or 0) + 1
    boots.save(n)
    newest = FileCounter(cfg.get("replay_file", "mlreplay.txt"))
    return SignedLink(link, key, clock_ms, n, newest)


def open_link(cfg, machine):
    kind = cfg.get("kind", "usb")
    if kind == "tcp":
        from .clock import default_clock

        clock = default_clock()  # (extended to 64 bit: ticks_ms wraps in 12 days)
        return signed(TcpLink(cfg.get("port", 5000)), cfg, lambda: clock() // 1000)
    if kind == "usb":
        return StdioLink()
    if kind == "uart":
        return UartLink(
            machine,
            cfg.get("id", 0),
            cfg.get("baudrate", 115200),
            cfg.get("tx"),
            cfg.get("rx"),
            cfg.get("rxbuf", 1024),
        )
    raise ValueError("link kind must be usb, uart or tcp, not %s" % kind)
