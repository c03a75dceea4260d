"""Any board file as a virtual board on CPython: the board's own firmware (board/firmware.py's
Firmware, its drivers, its run loop, its link code: signed records too) on the simulated world
of world/ (a `machine` module with the parts of the board file simulated from their
datasheets), served on ``tcp://HOST:PORT``, ``unix:///PATH`` or ``pty``.

Theory of operation
-------------------
The firmware runs as on a device: ``Firmware.run()`` steps the runtime and sleeps on its link
until input or the drivers' next deadline, at the pace of the host's clock (the board clock is
CLOCK_MONOTONIC in µs, and the simulated devices keep the same time).  Its link is what the
board file's link would be on a network board: link.py's TcpLink (one host at a time, the
newest) or, with a ``key_file``, SignedLink, over a :class:`SocketServer` that has link.py's
TcpServer interface on a socket of this machine; or, for ``pty``, a :class:`PtyLink` (USB CDC:
one host, who may close and reopen the port unseen).  A board file's own link kind and port
are not used: ``--listen`` says where the board is.  With ``dial=True`` the board connects out
to ``tcp://HOST:PORT`` (a daemon that runs ``run --listen``) as a board whose link dials does on
a device: board/dial.py's DialServer (its backoff) over :class:`DialNet`, link.py's SocketNet
with the power switch, in place of the SocketServer; TcpLink or SignedLink above it as before.

Who the board is: its simulated chip's ``machine.unique_id()`` (board.id), from
:func:`chip_id`: made once at random and kept in the flash directory when the caller names one
(a real chip's id is fixed: restarting on the same flash is the same board), else from a seed.

The flash is a directory: the saved configuration (the board file's ``config_file``) and the
link's files (``key_file``, ``boot_file``) live there, kept between runs when the caller names
one (``--flash DIR``), else in a directory that goes with the process.

:meth:`BoardFileBoard.stop` is the power switch: the next turn of the loop raises
:class:`PowerOff` from the link, the firmware makes its actuators safe on the way out
(firmware.py) and :meth:`serve_forever` returns.  Whatever else ends the firmware (a driver's
exception) leaves serve_forever with it.  The world is one per process (world/machine.py's
WORLD): one board file per process.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import tty
from collections.abc import Collection
from pathlib import Path
from typing import Any, Protocol

from ..board.dial import dial_server
from ..board.firmware import Firmware
from ..board.link import SocketNet, TcpServer, network_link
from ..board.store import FileStore
from ..errors import ConfigError, MissingLinkError
from ..world.spec import WorldSpec
from ..world.world import World
from .listen import dial_address, listen_socket
from .world import machine
from .world.parts import populate
from .world_cpython import BoardClock, CPythonWorld, WorldAtTheLink
from .worldlink import WorldLink

LINK_FILES = ("key_file", "boot_file", "replay_file")
#: the simulated chip's id in the flash directory (16 hex digits), made at its first run
CHIP_ID_FILE = ".chip_id"


class ListenError(MissingLinkError):
    """The listener could not be made (the port is taken, the path is not writable)."""


class PowerOff(BaseException):
    """The board's power was switched off (stop()): not an error of the firmware's."""


class Power:
    """On until off(); a pipe wakes the loop's wait when it goes off."""

    def __init__(self) -> None:
        self.on = True
        self.wake_r, self.wake_w = os.pipe()
        os.set_blocking(self.wake_r, False)
        os.set_blocking(self.wake_w, False)

    def check(self) -> None:
        if not self.on:
            raise PowerOff()

    def off(self) -> None:
        self.on = False
        try:
            os.write(self.wake_w, b"x")
        except OSError:  # (the pipe is full: it wakes anyway)
            pass

    def close(self) -> None:
        os.close(self.wake_r)
        os.close(self.wake_w)


def _wait(fds: list[int], power: Power, us: int) -> list[int]:
    ready, _, _ = select.select([*fds, power.wake_r], [], [], max(0, us) / 1e6)
    return ready


class SocketServer(TcpServer):  # type: ignore[misc]
    """link.py's TcpServer on a listening socket of this machine (tcp or unix: listen.py), with
    the power switch: its waits wake on it and accept() checks it.  Its connections send at once
    (TCP_NODELAY) and a recv takes what a host's buffers hold, not a board's 512 bytes."""

    RECV_BYTES = 4096

    def __init__(self, listener: socket.socket, power: Power) -> None:
        super().__init__(listener=listener)
        self.power = power

    def accept(self) -> int | None:
        self.power.check()
        n: int | None = super().accept()
        return n

    def _accepted(self, conn: socket.socket) -> None:
        if conn.family == socket.AF_INET:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _ready(self, sock: socket.socket, ms: int = 0) -> bool:
        return sock.fileno() in _wait([sock.fileno()], self.power, ms * 1000)

    def _wait_on(self, socks: list[socket.socket], us: int) -> None:
        _wait([s.fileno() for s in socks], self.power, us)

    def close(self) -> None:
        path = self._srv.getsockname() if self._srv.family == socket.AF_UNIX else None
        super().close()
        if path:
            try:
                os.unlink(path)
            except OSError:
                pass


class DialNet(SocketNet):  # type: ignore[misc]
    """link.py's SocketNet (a device's outgoing connections: board/dial.py dials over it) with
    the power switch: its waits wake on it and every look at the network checks it.  Its
    connections send at once (TCP_NODELAY: a frame is small, clock sync wants it out now)."""

    def __init__(self, power: Power) -> None:
        super().__init__()
        self.power = power

    def connect(self, host: str, port: int) -> int:
        self.power.check()
        n: int = super().connect(host, port)
        return n

    def connected(self, n: int) -> bool | None:
        self.power.check()
        up: bool | None = super().connected(n)
        sock = self._conns.get(n) if up else None
        if sock is not None and sock.family == socket.AF_INET:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return up

    def recv(self, n: int) -> bytes | None:
        self.power.check()
        data: bytes | None = super().recv(n)
        return data

    def wait(self, us: int) -> None:
        _wait([sock.fileno() for sock in self._conns.values()], self.power, us)
        self.power.check()


def dial_target(url: str) -> str:
    """``tcp://HOST:PORT`` -> the ``HOST:PORT`` a board file's link dials (board/dial.py);
    BadURL for anything else."""
    host, port = dial_address(url)
    return f"{host}:{port}"


def chip_id(flash: Path | None, seed: int) -> bytes:
    """The simulated chip's ``machine.unique_id()`` (8 bytes): kept in ``flash`` (made at random
    the first time, as a chip's is fixed at the factory), or without a flash the seeded one
    (world/machine.py: ``host.mjs --seed``'s).  ConfigError when the flash's is not one."""
    if flash is None:
        raw: bytes = machine.seeded_unique_id(seed)
        return raw
    path = flash / CHIP_ID_FILE
    if not path.exists():
        tmp = flash / f"{CHIP_ID_FILE}.{os.getpid()}"
        tmp.write_text(os.urandom(8).hex() + "\n")
        try:
            os.link(tmp, path)  # (atomic: two boards started on one flash get one id)
        except FileExistsError:
            pass
        finally:
            tmp.unlink()
    text = path.read_text().strip()
    if len(text) != 16 or any(c not in "0123456789abcdef" for c in text):
        raise ConfigError(
            f"--flash {flash}: {CHIP_ID_FILE} is not a chip id (16 hex digits): remove it and "
            "the board gets a new one"
        )
    return bytes.fromhex(text)


class Pty:
    """A pseudo-terminal whose far end hosts open as ``serial:///dev/pts/N``, both ends raw at
    once (a cooked pty echoes the board's frames back).  The far end is kept open, so a host
    closing the port is not an end of file; output a host does not read waits up to SEND_S,
    then is dropped (counted), as on a port with nobody reading."""

    SEND_S = 0.5

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self._slave)
        os.set_blocking(self.master, False)
        self.url = f"serial://{os.ttyname(self._slave)}"
        self.dropped = 0

    def read(self) -> bytes | None:
        try:
            return os.read(self.master, 4096) or None
        except BlockingIOError:
            return None
        except OSError as e:
            if e.errno == errno.EIO:  # no host has the port open
                return None
            raise

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.master, view) :]
            except BlockingIOError:
                _, ready, _ = select.select([], [self.master], [], self.SEND_S)
                if not ready:
                    self.dropped += len(view)
                    return

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


class PtyLink(Pty):
    """The board's link on a pty, as a board's USB CDC port: one host at a time."""

    def __init__(self, power: Power) -> None:
        super().__init__()
        self.power = power

    def read(self) -> bytes | None:
        self.power.check()
        return super().read()

    def wait(self, us: int) -> None:
        _wait([self.master], self.power, us)


class _Link(Protocol):
    def read(self) -> bytes | None: ...
    def write(self, data: bytes) -> None: ...
    def wait(self, us: int) -> None: ...
    def close(self) -> None: ...


def listener(url: str) -> tuple[socket.socket, str]:
    """A listening socket for ``tcp://HOST:PORT`` (0: any free port) or ``unix:///PATH``, and the
    URL a host opens; BadURL for anything else, ListenError when it cannot be bound."""
    try:
        return listen_socket(url, 2, "pty")
    except OSError as e:
        raise ListenError(f"cannot listen on {url}: {e.strerror or e}") from None


def flash_files(board: dict[str, Any], flash: Path) -> dict[str, Any]:
    """The board file's link settings with its files (key, boot count) in the flash; a key
    the link names but the flash lacks is a ConfigError saying how to make one."""
    link = dict(board.get("link", {}))
    for key in LINK_FILES:
        if key in link:
            link[key] = str(flash / link[key])
    key_file = link.get("key_file")
    if key_file and not Path(key_file).is_file():
        raise ConfigError(
            f"the board file's link is signed: put its key in the flash "
            f"(missing-link key new {key_file}), or use --flash DIR with {Path(key_file).name}"
        )
    return link


class BoardFileBoard:
    """``board`` (a checked board file's dict) on the simulated world, served on ``listen``;
    ``url`` is what a host opens.  ``flash``: the board's flash directory; ``absent``: the
    transducer names whose parts are left unplugged (world/parts.py); ``dial``: connect out
    to ``listen`` (``tcp://HOST:PORT``) instead, ``url`` is then ``dial tcp://HOST:PORT``;
    ``chip``: the simulated chip's id (:func:`chip_id`), else the world's; ``world``: the world
    the robot lives in (missing_link/world, beside the firmware: world_cpython.py), seeded by
    ``seed``; None: none, the parts read what they are set to."""

    def __init__(
        self,
        board: dict[str, Any],
        listen: str,
        flash: Path,
        absent: Collection[str] = (),
        *,
        dial: bool = False,
        chip: bytes | None = None,
        world: WorldSpec | None = None,
        seed: int = 0,
    ) -> None:
        if machine.WORLD.devices or machine.WORLD.pins:
            raise RuntimeError("one board file per process: the simulated world is taken")
        link_cfg = flash_files(board, flash)
        if listen in ("pty", "pty://") and link_cfg.get("key_file"):
            raise ConfigError(
                "a board file with a signed link (key_file) is served on tcp or unix, not pty"
            )
        target = dial_target(listen) if dial else None
        populate(board, set(absent))
        if chip is not None:
            machine.WORLD.unique_id = chip
        clock = BoardClock()
        self.world: CPythonWorld | None = None
        if world is not None:  # (world_cpython.py: beside the firmware, at its link)
            model = World(world, board, clock(), seed)
            self.world = CPythonWorld(WorldLink(model, board, set(absent)), clock)
        self.world_hand = self.world.link if self.world is not None else None
        self.power = Power()
        self._closed = False
        self.link: _Link | None = None
        try:
            if listen in ("pty", "pty://") and not dial:
                pty = PtyLink(self.power)
                self.link, self.url = pty, pty.url
            else:  # (the firmware's clock stays the BoardClock: an edge's handler reads its time)

                def clock_ms() -> int:
                    ms: int = clock() // 1000
                    return ms

                if target is not None:  # (as a device whose link dials: board/dial.py)
                    server: Any = dial_server(DialNet(self.power), {"dial": target}, clock_ms)
                    self.url = f"dial {listen}"
                else:
                    sock, self.url = listener(listen)
                    server = SocketServer(sock, self.power)
                self.link = network_link(server, link_cfg, clock_ms)
            store = FileStore(str(flash / board.get("config_file", "mlconfig.bin")))
            link: Any = self.link if self.world is None else WorldAtTheLink(self.link, self.world)
            self.firmware = Firmware(board, machine, link, clock=clock, store=store)
        except BaseException:
            self.close()
            raise

    def serve_forever(self) -> None:
        """Run the firmware until stop() (returns) or until it stops on its own (raises)."""
        try:
            self.firmware.run()
        except PowerOff:
            pass
        finally:
            self.close()

    def stop(self) -> None:
        self.power.off()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self.link is not None:
                self.link.close()
            self.power.close()
