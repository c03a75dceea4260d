"""Closing a board ends its reader thread whatever the other side of its line does: silent,
gone, or not reading (its input full, so a write fails with EAGAIN).  A pty stands in for the
serial line an AVR simulator serves (rig_sim's), without the simulator."""

from __future__ import annotations

import errno
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from missing_link import Board
from missing_link.errors import MissingLinkError, TransportBroken
from missing_link.transport import open_transport

from .helpers import wait_for

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="a pty")


@contextmanager
def pty_board() -> Iterator[tuple[Board, int]]:
    """A board on the slave side of a pty (no handshake: only its link and reader), and the
    master, the board's side of the line; the master is closed after, unless the test did."""
    master, slave = os.openpty()
    board = Board(open_transport(f"serial://{os.ttyname(slave)}"), timeout=1.0)
    try:
        yield board, master
    finally:
        board.close()
        os.close(slave)
        try:
            os.close(master)
        except OSError as e:  # (the test closed it: the other side gone)
            assert e.errno == errno.EBADF


def reader(board: Board) -> threading.Thread:
    thread = board.link._thread
    assert thread is not None and thread.is_alive()
    return thread


def test_close_ends_the_reader_of_a_silent_line() -> None:
    with pty_board() as (board, _master):
        thread = reader(board)
        board.close()
        assert not thread.is_alive()


def test_the_reader_ends_when_the_other_side_is_gone_and_close_after_is_quiet() -> None:
    with pty_board() as (board, master):
        thread = reader(board)
        os.close(master)  # the simulator ended: the pty hangs up (EIO)
        assert wait_for(lambda: not thread.is_alive(), 10)
        with pytest.raises(MissingLinkError):
            board.call("a2jEcho")
        board.close()


def test_close_ends_the_reader_when_the_other_side_reads_nothing() -> None:
    """The line's buffer full (the board does not read): a write fails at once (EAGAIN, said
    as TransportBroken, never a block), and close still ends the reader."""
    with pty_board() as (board, _master):
        thread = reader(board)
        transport = board.link.transport
        with pytest.raises(TransportBroken, match="write failed"):
            for _ in range(10_000):
                transport.write(b"\x12\x00" * 512)
        board.close()
        assert not thread.is_alive()
