"""A board on TCP that reads nothing fails the host's write after its write timeout; one that
reads slowly but steadily does not (transport/base.FdTransport.write)."""

from __future__ import annotations

import socket
import threading

import pytest

from missing_link import TransportBroken
from missing_link.transport import open_transport
from missing_link.transport.sockets import SocketTransport


def test_a_tcp_board_that_reads_nothing_fails_the_write_not_the_host() -> None:
    """A board on TCP that stops reading (hung, hostile) filled the socket's buffer and the
    host's write waited on it for good (a blocking send); it fails after the write timeout
    now, as a serial port's does."""
    server = socket.create_server(("127.0.0.1", 0))
    server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # (small: full sooner)
    port = server.getsockname()[1]
    t = open_transport(f"tcp://127.0.0.1:{port}")
    peer, _ = server.accept()
    server.close()
    assert isinstance(t, SocketTransport)
    t.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    data = bytes(range(256)) * 4096  # 1 MiB: many times the two sockets' buffers
    try:
        t.write_timeout = 0.2
        with pytest.raises(TransportBroken, match=r"the board took nothing for 0\.2 s"):
            t.write(data)  # nothing reads
    finally:
        t.close()
        peer.close()


def test_a_tcp_board_that_reads_slowly_but_steadily_is_waited_for() -> None:
    """A board that reads a little at a time is not one that reads nothing: a TCP socket is
    writable again only once a third of its buffer is free, which a board opening its window
    by a couple of KiB at a time took longer than the write timeout to give, and the write
    failed saying it took nothing while it took 512 bytes every 20 ms."""
    server = socket.create_server(("127.0.0.1", 0))
    server.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)  # (its window: small steps)
    t = open_transport(f"tcp://127.0.0.1:{server.getsockname()[1]}")
    peer, _ = server.accept()
    server.close()
    assert isinstance(t, SocketTransport)
    t.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 32768)
    size = t.sock.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF)
    size += peer.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) + 4096  # (more than both hold)
    data = bytes(range(256)) * (size // 256)
    taken = bytearray()
    done = threading.Event()

    def board() -> None:  # reads 512 bytes every 20 ms until it has them all
        while len(taken) < len(data) and not done.wait(0.02):
            taken.extend(peer.recv(512))

    reader = threading.Thread(target=board, daemon=True)
    reader.start()
    try:
        t.write_timeout = 0.5
        t.write(data)
        reader.join(10)
        assert bytes(taken) == data
    finally:
        done.set()
        t.close()
        peer.close()
