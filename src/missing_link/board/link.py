# The board's side of the backbone link on a microcontroller: USB CDC (the REPL's stdin/stdout),
# a UART, or TCP on a network (an ESP32 on WiFi: the network is the user's boot.py's to join).
# read() -> bytes available now (or None), write(bytes), wait(µs): sleep until input or the
# timeout, close(): hand the port back to the REPL.  A TCP link with a `key_file` carries signed
# records (signing.py): on a network, a board with a key takes nothing unsigned, and keeps the
# host that proved the key whoever else connects.
#
# On TCP the board either listens ({"kind": "tcp", "port": 5000}: TcpServer, the host connects)
# or dials ({"kind": "tcp", "dial": "HOST:PORT"}: DialServer, the board connects to a daemon
# that runs `missing-link run --listen`, as a micro-ROS client dials its agent, and again with
# backoff whenever the connection ends).  Both are the same connection table to TcpLink and
# SignedLink: who connects changes, not who speaks J2A or who proves the key (docs/signing.md).

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


class _Sockets:
    # A table of open TCP connections by number: recv(n) -> the bytes there now, None (none
    # yet) or b"" (closed: forgotten), send(n, data) -> False when it failed (then closed),
    # drop(n), wait(µs): until input or the timeout.  Blocking sockets, read only when a poll
    # says there are bytes; a send that cannot go out within SEND_S closes the connection (a
    # host that vanished must not stall the firmware's loop, and with it the failsafe).
    SEND_S = 0.5
    RECV_BYTES = 512  # what one recv takes at most (a board's RAM)

    def __init__(self):
        import select

        self._select = select
        self._conns = {}
        self._next = 1

    def _number(self):
        n = self._next
        self._next += 1
        return n

    def _ready(self, sock, ms=0):
        p = self._select.poll()
        p.register(sock, self._select.POLLIN)
        return bool(p.poll(ms))

    def recv(self, n):
        conn = self._conns.get(n)
        if conn is None:
            return b""
        if not self._ready(conn):
            return None
        try:
            data = conn.recv(self.RECV_BYTES)
        except OSError:
            data = b""
        if not data:
            self.drop(n)
        return data

    def send(self, n, data):
        conn = self._conns.get(n)
        if conn is None:
            return False
        try:
            conn.sendall(data)
        except OSError:
            self.drop(n)
            return False
        return True

    def drop(self, n):
        conn = self._conns.pop(n, None)
        if conn is not None:
            conn.close()

    def take(self, n):
        # connection n's socket, handed over (a virtual board reads it in its own loop)
        return self._conns.pop(n, None)

    def _wait_on(self, socks, us):
        p = self._select.poll()
        for sock in socks:
            p.register(sock, self._select.POLLIN)
        p.poll(max(0, us // 1000))

    def wait(self, us):
        self._wait_on(list(self._conns.values()), us)

    def close(self):
        for n in list(self._conns):
            self.drop(n)


class TcpServer(_Sockets):
    # Connections on one TCP port, by number: accept() -> a new connection's number or None,
    # and the table's recv, send, drop, wait (above); close().  `listener`: a listening socket
    # made elsewhere (a virtual board's, virtual/boardfile.py) instead of one on `port`.
    def __init__(self, port=5000, host="0.0.0.0", listener=None):
        super().__init__()
        if listener is None:
            import socket

            listener = socket.socket()
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(socket.getaddrinfo(host, port)[0][-1])
            listener.listen(2)
        self._srv = listener

    def accept(self):
        if not self._ready(self._srv):
            return None
        try:
            conn, _addr = self._srv.accept()
        except OSError:  # (out of sockets: the client is gone again)
            return None
        conn.settimeout(self.SEND_S)
        self._accepted(conn)
        n = self._number()
        self._conns[n] = conn
        return n

    def _accepted(self, conn):
        pass  # (what a server of a host's own adds to a new connection)

    def wait(self, us):
        socks = list(self._conns.values())
        socks.append(self._srv)
        self._wait_on(socks, us)

    def close(self):
        super().close()
        self._srv.close()


# errno of a connect that goes on in the background: EINPROGRESS (Linux 115, lwIP 119), EAGAIN
_IN_PROGRESS = (115, 119, 11)


class SocketNet(_Sockets):
    # Outgoing TCP connections by number, none of them blocking the loop: connect(host, port)
    # -> n at once; connected(n) -> True once it is up, False while on its way, None when it
    # failed (forgotten); then the table's recv, send, drop, wait.  The host is an address
    # (a name would be a DNS lookup, which blocks).
    def __init__(self):
        import socket

        super().__init__()
        self._socket = socket
        self._dialing = {}  # n -> socket on its way (None: failed at once)

    def connect(self, host, port):
        n = self._number()
        sock = self._socket.socket()
        try:
            addr = self._socket.getaddrinfo(host, port)[0][-1]
            sock.setblocking(False)
            sock.connect(addr)
        except OSError as e:
            if (e.args[0] if e.args else 0) not in _IN_PROGRESS:
                sock.close()
                sock = None
        self._dialing[n] = sock
        return n

    def connected(self, n):
        if n in self._conns:
            return True
        sock = self._dialing.get(n)
        if sock is None:
            self._dialing.pop(n, None)
            return None
        sel = self._select
        p = sel.poll()
        p.register(sock, sel.POLLOUT)
        ev = p.poll(0)
        if not ev:
            return False
        del self._dialing[n]
        flags = ev[0][1]
        if flags & (sel.POLLERR | sel.POLLHUP) or _refused(sock):
            sock.close()
            return None
        sock.setblocking(True)
        sock.settimeout(self.SEND_S)
        self._conns[n] = sock
        return True

    def drop(self, n):
        sock = self._dialing.pop(n, None)
        if sock is not None:
            sock.close()
        super().drop(n)

    def close(self):
        for n in list(self._dialing):
            self.drop(n)
        super().close()


def _refused(sock):
    # a connect that failed, said by the socket (CPython's SO_ERROR; MicroPython says it with
    # POLLERR/POLLHUP, and has no getsockopt)
    getsockopt = getattr(sock, "getsockopt", None)
    if getsockopt is None:
        return False
    import socket

    return bool(getsockopt(socket.SOL_SOCKET, socket.SO_ERROR))


class TcpLink:
    # Plain J2A on a TCP port (a board without a key): one host at a time, and a new connection
    # replaces the old one (the host reconnected).  Anyone who reaches the port is that host:
    # a board on a network takes a key (signing.py), whose link keeps its host.
    def __init__(self, port=5000, host="0.0.0.0", server=None):
        self.server = server if server is not None else TcpServer(port, host)
        self._conn = None

    def read(self):
        n = self.server.accept()
        if n is not None:
            if self._conn is not None:
                self.server.drop(self._conn)
            self._conn = n
        if self._conn is None:
            return None
        data = self.server.recv(self._conn)
        if data is not None and not data:  # the host closed: wait for the next
            self._conn = None
            return None
        return data

    def write(self, data):
        if self._conn is not None and not self.server.send(self._conn, data):
            self._conn = None  # (nobody listening: like a UART with nothing attached)

    def wait(self, us):
        self.server.wait(us)

    def close(self):
        self.server.close()


class FileCounter:
    # an integer kept in a file (a board's boot count, where it has no RNG)
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


def random_source(cfg):
    # n -> n fresh random bytes for a connection's challenge (signing.py): the port's RNG
    # (os.urandom: hardware on ESP32 and RP2040); on a port without one, bytes that are at
    # least never the same twice: the boot count (kept in `boot_file`), a counter, the clock
    # and random's state, hashed
    try:
        import os

        os.urandom(1)
        return os.urandom
    except (ImportError, AttributeError, OSError):
        pass
    import hashlib
    import random
    import time

    boots = FileCounter(cfg.get("boot_file", "mlboots.txt"))
    boot = (boots.load() or 0) + 1
    boots.save(boot)
    made = [0]

    def fresh(n):
        made[0] += 1
        seed = "%d %d %d %d" % (boot, made[0], time.ticks_us(), random.getrandbits(32))
        return hashlib.sha256(seed.encode()).digest()[:n]

    return fresh


def read_key(key_file):
    with open(key_file, "rb") as f:
        key = f.read()
    text = key.strip()
    if len(text) == 64:  # (missing-link key new writes hex; a raw 32-byte key works too)
        key = bytes.fromhex(text.decode())
    return key


def network_link(server, cfg, clock_ms):
    # a board on a network port: signed records when the board file names a key (signing.py),
    # else plain J2A (TcpLink)
    key_file = cfg.get("key_file")
    if not key_file:
        return TcpLink(server=server)
    from .signing import SignedLink

    return SignedLink(server, read_key(key_file), clock_ms, random_source(cfg))


def open_link(cfg, machine):
    kind = cfg.get("kind", "usb")
    if kind == "tcp":
        from .clock import default_clock

        clock = default_clock()  # (extended to 64 bit: ticks_ms wraps in 12 days)

        def clock_ms():
            return clock() // 1000

        if cfg.get("dial"):
            from .dial import dial_server

            return network_link(dial_server(SocketNet(), cfg, clock_ms), cfg, clock_ms)
        return network_link(TcpServer(cfg.get("port", 5000)), cfg, clock_ms)
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
