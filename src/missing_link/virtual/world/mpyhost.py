"""The simulator's side inside MicroPython (host.mjs loads it as `simworld.mpyhost`): the
firmware from the board file on a link whose bytes the node host moves, with the world's
devices made from the same board file (parts.py).  The MicroPython subset only.

host.mjs imports the board file and the firmware (`mlboard`, as on a device) and hands them to
start(): nothing here names a module outside the world.  node's TCP connections are the link's
(SimServer: as link.py's TcpServer on a device, and its SocketNet when the board dials:
{"kind": "tcp", "dial": "HOST:PORT"}, board/dial.py): _open(n), _feed(n, hex), _closed(n) say
what happened to connection n; _tick() runs one firmware step and returns what to send, close
and dial ("n:hex", "-n" and "+n:HOST:PORT", space-separated); _ctl(src, sim_us) runs test code
against WORLD and returns repr() of `result` (reboot() restarts the firmware on the same
filesystem and devices).  The board's filesystem (its flash: a saved configuration, a key) is
the current directory.

A board that starts from its flash (start_flash(), flashboot.py: host.mjs --flash DIR with a
main.py) takes firmware updates: between steps, _tick() asks the updater whether the board
should restart (after an update's switch, a trial not confirmed in time), and restart() starts
it from the flash again, as a board's reset does (every connection ends); so does a firmware on
trial that raises, and machine.reset().

Fast mode (host.mjs --fast, simtime.py): _step(now, ns, inputs) feeds the connections' bytes
and runs _tick at simulated µs `now` (and `ns` below it), charging the step's own cost and its
bytes (simcost.py), and tells the host what it needs to move the clock on with report(SLEPT,
NS, REQ, AT, CHARGED, CLK0, AUTO, DUE) (µs the clock moved in the step and the ns left over;
collections it asked for (simgc.py), where, µs into the step, and what they were charged, ns;
the board clock at the step's start; whether the allocator collects as it returns (simgc.py,
--heap); µs to the drivers' next deadline, -1 none): a call into node with small ints, which
makes no garbage (a string of them made the firmware's heap pay ~40 bytes more a step).  After
a step that collected, _settle() says what the collection took (ns), and with --heap
_heap_used() and _heap_live() the bytes in use as it began and live after it.  The simulator's
own reads of the board clock are free.
"""

from . import devices, machine, simcost, simgc, simtime
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
        simtime.charge_ns(simcost.BYTE_IN_NS * len(data))  # (fast mode: what decoding costs)
        return bytes(data)

    def send(self, n, data):
        if n not in self.rx or n in self.ended:
            return False
        simtime.charge_ns(simcost.BYTE_OUT_NS * len(data))  # (fast mode: what encoding cost)
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
boot = None  # flashboot.py, for a board that starts from its flash (start_flash)
spare = None  # --heap: room held back so that a MemoryError can still be said (heap.mjs)
report = None  # fast mode: how a step tells the host its figures (host.mjs: small ints, no garbage)


def release():
    # The firmware failed (a MemoryError, perhaps): the room held back goes to the interpreter
    # at once (a list cleared shrinks its array), so the error can be told to node: this port
    # converts it in a heap where nothing has been collected yet, and hangs if it cannot.
    if spare is not None:
        spare.clear()


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
    if boot is not None:
        boot.attach(fw.runtime, _sim["board"])


def start_flash(flashboot, absent=()):
    # The board starts from its flash (flashboot.py: as main.py on a device), its parts those
    # of the first board file that loads (the wiring stays whatever firmware runs)
    global boot
    boot = flashboot
    _sim.update(absent=absent, populated=False)
    restart()


def restart():
    # A reset: every connection ends, the board starts from its flash again; a firmware on
    # trial that raises restarts it once more (and it goes back: board/boot.py).
    for n in list(wire.rx) + list(wire.dialing):
        wire.drop(n)
    del wire.new[:]
    del wire.ended[:]
    for _ in range(4):
        try:
            board, mlboard = boot.load()
            if not _sim["populated"]:
                populate(board, _sim["absent"])
                _sim["populated"] = True
            link = _link(mlboard, board.get("link", {}))
            _sim.update(board=board, mlboard=mlboard, link=link, stopped=False)
            reboot()
            return
        except Exception as e:  # noqa: BLE001 - on trial: noted, back at the next start
            if not boot.crashed(e):
                raise
            print("the firmware on trial raised %s: %s; restarting" % (type(e).__name__, e))
    raise RuntimeError("the board did not start from its flash")


def _restart_due():
    # the updater's restart, if due: what the board drives goes safe, the host hears why
    upd = boot.updater if boot is not None else None
    why = upd.due(_free(_sim["rt"].clock)) if upd is not None else None
    if why:
        upd.before_restart(why)
        out = _sim["rt"].take_output()
        if out:
            _sim["link"].write(out)
        restart()
    return bool(why)


def _free(read):
    # the simulator reads the board's clock: no charge (simtime.py)
    simtime.free = True
    try:
        return read()
    finally:
        simtime.free = False


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
        if not _restart_due():
            _sim["fw"].step()
    except _sim["mlboard"].firmware.BreakIn:
        _sim["stopped"] = True
        return "BREAK"
    except SystemExit:  # machine.reset()
        if boot is None:
            release()
            raise
        restart()
    except Exception as e:  # noqa: BLE001 - raised again unless on trial (then it goes back)
        if boot is None or not boot.crashed(e):
            release()
            raise
        restart()
    except BaseException:
        release()
        raise
    if not wire.out:
        return ""  # (no garbage made for nothing: under --heap it is the firmware's to hold)
    out = " ".join(wire.out)
    wire.out = []
    return out


def _step(now, ns, inputs):
    # One fast-mode step at simulated µs `now` (wrapped) and `ns` below it, with what came from
    # the connections ("n:hex" and "-n" for closed, as _feed and _closed; all within the step,
    # so nothing runs in the interpreter between two steps but the collection the last one left)
    simtime.set_now(now, ns)
    simgc.begin_step()
    if not _sim["stopped"]:  # (the turn's own work, at its start)
        simtime.charge_ns(simcost.turn_ns(len(_sim["rt"].transducers)))
    for tok in inputs.split() if inputs else ():
        if tok[0] == "-":
            _closed(int(tok[1:]))
        else:
            i = tok.index(":")
            _feed(int(tok[:i]), tok[i + 1 :])
    clk0 = _free(_sim["rt"].clock) if not _sim["stopped"] else 0
    out = _tick()
    due = -1 if _sim["stopped"] else _due_us()
    auto = simgc.end_step() if simgc.watch else 0
    gc = simgc
    report(simtime.slept(), simtime.ns(), gc.requested, gc.at, gc.charged, clk0, auto, due)
    return out


def _settle():
    # after a step whose collection ran as it returned: what it took, ns (simgc.py)
    return simgc.settle()


def _heap_used():
    # ... then the bytes in use as it began (--heap: simgc.py)
    return simgc.used()


def _heap_live():
    # ... and the bytes live after it
    return simgc.live_bytes()


def _due_us():
    rt = _sim["rt"]
    simtime.free = True
    try:
        due = rt.next_deadline_us()
        return -1 if due is None else max(0, due - rt.clock())
    finally:
        simtime.free = False


def _ctl(src, sim_us=None):
    env = {
        "sim_us": sim_us,  # fast mode: simulated µs since the start (host.mjs)
        "WORLD": WORLD,
        "fw": _sim["fw"],
        "rt": _sim["rt"],
        "machine": machine,
        "devices": devices,
        "reboot": reboot,
        "restart": restart,
        "slot": boot.slot() if boot is not None else "",
        "result": None,
    }
    simtime.free = True  # (a test's reads of the clock are not the board's work)
    before = simgc.allocated() if simgc.watch else 0
    try:
        exec(src, env)
        return repr(env["result"])
    finally:
        simtime.free = False
        simgc.not_the_firmwares(before)


def _ident():
    import sys

    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s" % (sys.implementation.name, version)
