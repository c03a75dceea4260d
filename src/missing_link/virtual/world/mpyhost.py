"""The simulator's side inside MicroPython (host.mjs loads it as `simworld.mpyhost`): the
firmware from the board file on a link whose bytes the node host moves, with the world's
devices made from the same board file (parts.py).  The MicroPython subset only.

host.mjs imports the board file and the firmware (`mlboard`, as on a device) and hands them to
start(): nothing here names a module outside the world.  node's TCP connections are the link's
(SimServer: as link.py's TcpServer on a device, and its SocketNet when the board dials:
{"kind": "tcp", "dial": "HOST:PORT"}, board/dial.py): _open(n), _feed(n, hex), _closed(n) say
what happened to connection n; _tick() runs one firmware step and returns what to send, close
and dial ("n:hex", "-n" and "+n:HOST:PORT", space-separated); _ctl(src) runs test code
against WORLD and returns repr() of `result` (reboot() restarts the firmware on the same
filesystem and devices).  The board's filesystem (its flash: a saved configuration, a key) is
the current directory.
"""

from . import devices, machine
from .machine import WORLD
from .parts import populate


class SimServer:
    # the TcpServer interface (link.py) over the connections node moves the bytes of; and
    # SocketNet's connect/connected, whose connections node makes (numbered from DIALED, apart
    # from those it accepts)
    DIALED = 1 << 20

    def __init__(self):
        self.new = []
        self.rx = {}  # open connection -> bytes received
        self.ended = []  # closed by the client (what they sent is read first)
        self.out = []  # "n:hex" to send, "-n" to close, "+n:HOST:PORT" to dial
        self.dialing = {}  # n -> True while node makes the connection
        self._dials = self.DIALED

    def connect(self, host, port):
        n = self._dials
        self._dials += 1
        self.dialing[n] = True
        self.out.append("+%d:%s:%d" % (n, host, port))
        return n

    def connected(self, n):
        if n in self.rx:
            return True
        return False if n in self.dialing else None

    def accept(self):
        return self.new.pop(0) if self.new else None

    def recv(self, n):
        data = self.rx.get(n)
        if data is None:
            return b""
        if not data:
            if n in self.ended:
                self.ended.remove(n)
                del self.rx[n]
                return b""
            return None
        self.rx[n] = bytearray()
        return bytes(data)

    def send(self, n, data):
        if n not in self.rx or n in self.ended:
            return False
        self.out.append("%d:%s" % (n, bytes(data).hex()))
        return True

    def drop(self, n):
        if self.rx.pop(n, None) is not None or self.dialing.pop(n, None):
            self.out.append("-%d" % n)

    def wait(self, us):
        pass

    def close(self):
        pass


wire = SimServer()  # node's connections
_sim = {}  # what start() made: board, mlboard, link, fw, rt, stopped


def start(board, mlboard, absent=()):
    # The world from the board file, less its absent parts; the firmware on node's connections.
    populate(board, absent)
    link = _link(mlboard, board.get("link", {}))
    _sim.update(board=board, mlboard=mlboard, link=link, stopped=False)
    reboot()


def _link(mlboard, cfg):
    # as open_link on a device, over node's connections: a board that dials (dial.py) or
    # listens; signed records when it has a key (signing.py), else one host at a time, the
    # newest (a cable has one)
    clock = mlboard.clock.default_clock()

    def clock_ms():
        return clock() // 1000

    if cfg.get("dial"):
        server = mlboard.dial.dial_server(wire, cfg, clock_ms)
        return mlboard.link.network_link(server, cfg, clock_ms)
    return mlboard.link.network_link(wire, cfg, clock_ms)


def reboot():
    # The board restarts: its firmware is built again from the board file, on the same
    # filesystem (a configuration saved there is applied) and the same simulated devices.
    fw = _sim["mlboard"].firmware.Firmware(_sim["board"], machine, _sim["link"])
    _sim.update(fw=fw, rt=fw.runtime)


def _open(n):
    if wire.dialing.pop(n, None):  # (a connection the board made: up)
        wire.rx[n] = bytearray()
        return
    wire.new.append(n)
    wire.rx[n] = bytearray()


def _feed(n, h):
    if n in wire.rx:
        wire.rx[n].extend(bytes.fromhex(h))


def _closed(n):
    if wire.dialing.pop(n, None):  # (a dial that failed: the board tries again later)
        return
    if n in wire.rx:
        wire.ended.append(n)


def _tick():
    if _sim["stopped"]:
        return ""
    try:
        _sim["fw"].step()
    except _sim["mlboard"].firmware.BreakIn:
        _sim["stopped"] = True
        return "BREAK"
    out = " ".join(wire.out)
    wire.out = []
    return out


def _due_us():
    rt = _sim["rt"]
    due = rt.next_deadline_us()
    return -1 if due is None else max(0, due - rt.clock())


def _ctl(src):
    env = {
        "WORLD": WORLD,
        "fw": _sim["fw"],
        "rt": _sim["rt"],
        "machine": machine,
        "devices": devices,
        "reboot": reboot,
        "result": None,
    }
    exec(src, env)
    return repr(env["result"])


def _ident():
    import sys

    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s" % (sys.implementation.name, version)
