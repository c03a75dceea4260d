# A board that dials its host: one TCP connection out to a daemon that runs `missing-link run
# --listen` (as a micro-ROS client dials its agent), made again with backoff whenever it ends.
#
# Theory of operation
# -------------------
# DialServer stands behind the interface of link.py's TcpServer (accept, recv, send, drop,
# wait, close), so TcpLink and SignedLink take the connection the board made as one that came
# in: who connects changes, not who speaks J2A (the board still answers) or who proves the key
# (the host still greets, docs/signing.md).  It holds at most one connection of `net`
# (link.py's SocketNet on a device, the simulator's connections under node):
#
#     idle --due--> dialing --up--> up --ended--> idle (again after the backoff)
#                      \--refused, or not up within CONNECT_MS--> idle
#
# A connection ends when the host closes it, a send fails, or the link drops it (a signed link
# drops a host that does not prove the key).  The backoff doubles from BACKOFF_MIN_MS to
# BACKOFF_MAX_MS and is back at the minimum after a connection that lasted STEADY_MS: a daemon
# that is down is not hammered, one that restarted is reached again within seconds, and a
# daemon that refuses the board (accept = "known") hears from it every 8 s at most.
# Pure: the clock (ms) and the connections are handed in.  MicroPython subset.


class DialServer:
    # One connection out to HOST:PORT over `net`, behind TcpServer's interface (the theory
    # above): accept() -> its number once it is up.  `dials` and `connects` count attempts and
    # connections made.
    BACKOFF_MIN_MS = 250
    BACKOFF_MAX_MS = 8000
    STEADY_MS = 10000
    CONNECT_MS = 5000

    def __init__(self, net, host, port, clock_ms):
        self.net = net
        self.host = host
        self.port = port
        self._clock_ms = clock_ms
        self._conn = None
        self._up = False
        self._since = 0  # when the connection was started (dialing) or came up
        self._next_ms = clock_ms()  # the first dial at once
        self._backoff = self.BACKOFF_MIN_MS
        self.dials = 0
        self.connects = 0

    def accept(self):
        now = self._clock_ms()
        if self._conn is None:
            if now - self._next_ms >= 0:
                self._conn = self.net.connect(self.host, self.port)
                self._up = False
                self._since = now
                self.dials += 1
            return None
        if self._up:
            return None
        state = self.net.connected(self._conn)
        if state:
            self._up = True
            self._since = now
            self.connects += 1
            return self._conn
        if state is None or now - self._since > self.CONNECT_MS:
            self._ended(self._conn)
        return None

    def _ended(self, n):
        if n != self._conn:
            return
        now = self._clock_ms()
        steady = self._up and now - self._since >= self.STEADY_MS
        self.net.drop(n)
        self._conn = None
        if steady:
            self._backoff = self.BACKOFF_MIN_MS
        self._next_ms = now + self._backoff
        self._backoff = min(self._backoff * 2, self.BACKOFF_MAX_MS)

    def recv(self, n):
        data = self.net.recv(n)
        if data is not None and not data:
            self._ended(n)
        return data

    def send(self, n, data):
        if self.net.send(n, data):
            return True
        self._ended(n)
        return False

    def drop(self, n):
        self._ended(n)

    def wait(self, us):
        if self._conn is None or not self._up:  # (dialing: come back for the next step)
            us = min(us, 20000)
        self.net.wait(us)

    def close(self):
        self.net.close()


def dial_address(text):
    # "HOST:PORT" of a board file's link (`dial`) -> (host, port)
    text = str(text)
    at = text.rfind(":")
    host, port = text[:at], text[at + 1 :]
    if at <= 0 or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError("link dial must be 'HOST:PORT', not %r" % (text,))
    return host, int(port)


def dial_server(net, cfg, clock_ms):
    host, port = dial_address(cfg["dial"])
    return DialServer(net, host, port, clock_ms)
