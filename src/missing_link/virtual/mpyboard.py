"""Any board file as a virtual board under MicroPython: our real firmware in the real
interpreter (1.27, WebAssembly port from npm, under Node.js: world/host.mjs) on the simulated
world of world/, its link on a TCP port of this machine.

Theory of operation
-------------------
:class:`MicroPythonBoard` starts ``node host.mjs BOARDFILE`` and waits for its ``LISTEN``
line; the board is then up.  Node serves the firmware's link on ``--listen``'s TCP port, or
with ``dial`` the firmware dials the daemon (host.mjs --dial: board/dial.py, its backoff).  For
``pty`` this process opens the pseudo-terminal and relays its bytes to one connection of its
own to node's port on 127.0.0.1, kept for the board's life: the firmware sees one host on a
cable, as on USB CDC.  When the firmware restarts (an update's switch) node ends that
connection; the relay connects again and the pty stays, as a USB board that resets comes back
on the same port.  Node's stdin stays open (it is the simulator's control channel; closing
it powers the board off) and its stderr (the firmware's prints, the interpreter's errors) is
this process's.  ``CRASH`` or ``BREAK`` on node's stdout means the firmware stopped (an
exception, the break to the REPL): serve_forever() raises :class:`FirmwareStopped`.

Node and the npm package are found before anything starts (:func:`find_micropython`): the
package in ``node_modules`` of the current directory or one above it, or of the checkout this
module is in (``make node`` puts it there).

With ``flash`` (``--flash DIR``) holding a main.py (``board --file`` flashes DIR first:
deploy/flashdir.py) the board starts from its flash, as a board does, and takes updates
(``missing-link update``); otherwise the runtime and the board file are loaded as they are.
"""

from __future__ import annotations

import os
import queue
import select
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Collection
from pathlib import Path
from urllib.parse import urlsplit

from ..errors import BadURL, ConfigError, MissingLinkError
from .boardfile import Pty, dial_target
from .process import hang_up, reap
from .world_mpy import NodeWorld

HOST_MJS = Path(__file__).resolve().parent / "world" / "host.mjs"
MPY_ENTRY = Path("@micropython") / "micropython-webassembly-pyscript" / "micropython.mjs"
START_TIMEOUT_S = 60.0


class FirmwareStopped(MissingLinkError):
    """The firmware under MicroPython stopped (an exception, the break to the REPL)."""


def find_micropython() -> tuple[str, Path]:
    """(node, the npm MicroPython module); ConfigError saying `make node` if either is missing."""
    node = shutil.which("node")
    places = [Path.cwd(), *Path.cwd().parents, *Path(__file__).resolve().parents]
    entries = [p / "node_modules" / MPY_ENTRY for p in places]
    entry = next((e for e in entries if e.exists()), None)
    if node is None:
        raise ConfigError("--runtime micropython needs Node.js (node): run `make node`")
    if entry is None:
        raise ConfigError(
            "--runtime micropython needs MicroPython from npm in node_modules here or above: "
            "run `make node` (a checkout) or `npm install "
            "@micropython/micropython-webassembly-pyscript@1.27.0`"
        )
    return node, entry


def _tcp_address(listen: str) -> tuple[str, int]:
    if not listen.startswith("tcp://"):
        raise BadURL(
            f"cannot listen on {listen!r} under MicroPython: use tcp://127.0.0.1:PORT or pty"
        )
    parts = urlsplit(listen)
    try:
        return parts.hostname or "127.0.0.1", parts.port or 0
    except ValueError as e:
        raise BadURL(f"{listen!r}: bad port") from e


class MicroPythonBoard:
    """The board file at ``board_file`` under MicroPython, served on ``listen`` (tcp or pty);
    ``flash``: the board's filesystem on disk; ``absent``: parts left unplugged; ``dial``: the
    board connects out to ``listen`` (tcp://HOST:PORT: host.mjs --dial, board/dial.py) instead;
    ``chip``: the simulated chip's id (boardfile.chip_id); ``world``: the world beside the
    firmware (world_mpy.py; None: none); ``heap``: a board's fixed heap in bytes (host.mjs
    --heap: a Pico's is 209936; None: the port's own)."""

    def __init__(
        self,
        board_file: Path,
        listen: str,
        flash: Path | None,
        absent: Collection[str] = (),
        *,
        dial: bool = False,
        chip: bytes | None = None,
        world: NodeWorld | None = None,
        heap: int | None = None,
    ) -> None:
        node, entry = find_micropython()
        pty = listen in ("pty", "pty://") and not dial
        host, port = ("127.0.0.1", 0) if pty or dial else _tcp_address(listen)
        cmd = [node, str(HOST_MJS), str(board_file), "--port", str(port), "--host", host]
        cmd += ["--mpy", str(entry)]
        # (--listen or --dial says where the board is, whatever its board file's link says)
        cmd += ["--dial", dial_target(listen)] if dial else ["--no-dial"]
        if chip is not None:
            cmd += ["--chip-id", chip.hex()]
        if flash is not None:
            cmd += ["--flash", str(flash)]
        if absent:
            cmd += ["--absent", ",".join(absent)]
        if heap is not None:
            cmd += ["--heap", str(heap)]
        if world is not None:  # (the world beside the firmware, here: world_mpy.py)
            cmd += world.node_args()
        self.world_hand = world
        self._relay: _PtyRelay | None = None
        # (a session of its own: a terminal's Ctrl-C is this process's to handle, not node's)
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
            pass_fds=world.pass_fds if world is not None else (),
        )
        if world is not None:
            world.started()
        self.lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._pump, name="board:node", daemon=True).start()
        try:
            first = self.lines.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            first = None
        if first is None or not first.startswith("LISTEN "):
            self.close()
            raise MissingLinkError(f"the firmware did not start under MicroPython (got {first!r})")
        _, node_port, self.ident = first.split(" ", 2)
        if pty:
            self._relay = _PtyRelay(int(node_port))
            self.url = self._relay.url
        elif dial:
            self.url = f"dial {listen}"
        else:
            self.url = f"tcp://{host}:{node_port}"

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def serve_forever(self) -> None:
        """Until stop() (returns) or the firmware stops (FirmwareStopped)."""
        relay = None
        if self._relay is not None:
            relay = threading.Thread(target=self._relay.run, name="board:pty", daemon=True)
            self._relay.running = True
            relay.start()
        try:
            while True:
                line = self.lines.get()
                if line is None:
                    code = self.proc.wait()
                    if code != 0:
                        raise FirmwareStopped(f"the MicroPython host ended (exit {code})")
                    return
                if line in ("CRASH", "BREAK"):
                    why = "an exception (above)" if line == "CRASH" else "the break to the REPL"
                    raise FirmwareStopped(f"the firmware stopped under MicroPython: {why}")
        finally:
            self.close()
            if relay is not None:
                relay.join(2)

    def stop(self) -> None:
        """Power off: node's stdin closes and node ends (the flash is on disk already)."""
        hang_up(self.proc)

    def close(self) -> None:
        self.stop()
        if self._relay is not None:
            self._relay.stop()
        reap(self.proc)


class _PtyRelay:
    """A pseudo-terminal whose bytes go to and from one connection to node's port: the
    firmware sees one host on a cable; hosts that open and close the pty are not seen."""

    #: how long a restarting firmware (an update's switch, a trial given up) may take to serve
    #: its link again before the relay gives up: the board is gone
    RESTART_S = 30.0

    def __init__(self, port: int) -> None:
        self.pty = Pty()
        self.url = self.pty.url
        self.port = port
        self.sock = self._connect(5.0)
        self.wake_r, self.wake_w = os.pipe()
        self.running = False
        self._lock = threading.Lock()  # (stop() and the relay's own end may meet)

    def _connect(self, timeout: float) -> socket.socket:
        sock = socket.create_connection(("127.0.0.1", self.port), timeout=timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(Pty.SEND_S)
        return sock

    def _restarted(self) -> bool:
        """Node closed the connection: the firmware restarted (node's port stays), as a USB
        board that resets comes back on the same port.  What a host writes meanwhile is lost,
        as to a board that is not there.  False when stopped or the board never came back."""
        self.sock.close()
        deadline = time.monotonic() + self.RESTART_S
        while time.monotonic() < deadline:
            if select.select([self.wake_r], [], [], 0.1)[0]:
                return False
            self.pty.read()
            try:
                self.sock = self._connect(1.0)
                return True
            except OSError:
                continue
        return False

    def run(self) -> None:
        try:
            while True:
                sock = self.sock.fileno()
                ready, _, _ = select.select([self.pty.master, sock, self.wake_r], [], [])
                if self.wake_r in ready:
                    return
                if sock in ready:
                    try:
                        data = self.sock.recv(4096)
                    except ConnectionResetError:  # (node destroyed it with bytes unread)
                        data = b""
                    if not data:
                        if self._restarted():
                            continue
                        return  # stopped, or the board is gone
                    self.pty.write(data)
                if self.pty.master in ready:
                    got = self.pty.read()
                    if got:
                        self.sock.sendall(got)
        except OSError:  # (node gone, or a send it did not take within SEND_S)
            return
        finally:
            self.close()

    def stop(self) -> None:
        if not self.running:  # (never started: nothing to wake)
            self.close()
            return
        with self._lock:
            if self.wake_w >= 0:
                os.write(self.wake_w, b"x")

    def close(self) -> None:
        with self._lock:
            if self.wake_r >= 0:
                self.sock.close()
                self.pty.close()
                os.close(self.wake_r)
                os.close(self.wake_w)
                self.wake_r = self.wake_w = -1
