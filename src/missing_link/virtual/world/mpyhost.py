"""The simulator's side inside MicroPython (host.mjs loads it as `simworld.mpyhost`): the
firmware from the board file on a link whose bytes the node host moves, with the world's
devices made from the same board file (parts.py).  The MicroPython subset only.

host.mjs imports the board file and the firmware (`mlboard`, as on a device) and hands them to
start(): nothing here names a module outside the world.  node's TCP connections are the link's
(SimServer: as link.py's TcpServer on a device): _open(n), _feed(n, hex), _closed(n) say what
happened to connection n; _tick() runs one firmware step and returns what to send and close
("n:hex" and "-n", space-separated); _ctl(src) runs test code against WORLD and returns repr()
of `result` (reboot() restarts the firmware on the same filesystem and devices).  The board's
filesystem (its flash: a saved configuration, a key) is the current directory.
"""

from . import devices, machine
from .machine import WORLD
from .parts import populate


class SimServer:
    # the TcpServer interface (link.py) over the connections node moves the bytes of
    def __init__(self):
        self.new = []
        self.rx = {}  # open connection -> bytes received
        self.ended = []  # closed by the client (what they sent is read first)
        self.out = []  # "n:hex" to send, "-n" to close

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
        if self.rx.pop(n, None) is not None:
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
    if board.get("link", {}).get("key_file"):  # a network board: signed records (signing.py)
        clock = mlboard.clock.default_clock()
        link = mlboard.link.network_link(wire, board["link"], lambda: clock() // 1000)
    else:  # one host at a time, the newest (a cable has one)
        link = mlboard.link.TcpLink(server=wire)
    _sim.update(board=board, mlboard=mlboard, link=link, stopped=False)
    reboot()


def reboot():
    # The board restarts: its firmware is built again from the board file, on the same
    # filesystem (a configuration saved there is applied) and the same simulated devices.
    fw = _sim["mlboard"].firmware.Firmware(_sim["board"], machine, _sim["link"])
    _sim.update(fw=fw, rt=fw.runtime)


def _open(n):
    wire.new.append(n)
    wire.rx[n] = bytearray()


def _feed(n, h):
    if n in wire.rx:
        wire.rx[n].extend(bytes.fromhex(h))


def _closed(n):
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
