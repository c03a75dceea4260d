"""The sample path across board boots: which boot a handshake is of, when one failed."""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import cast

from missing_link.daemon.session.sample_path import SamplePath
from missing_link.descriptors import parse_transds
from missing_link.host.board import Board
from missing_link.topics import Topic, Update

from .test_daemon_parts import SeqLink


def test_a_new_boot_whose_first_handshake_failed_is_not_taken_as_the_old_one() -> None:
    """The boot a handshake is of is the path's (``boot``, set when its count is in), which a
    handshake that failed before the count leaves: the next one, of the new boot, takes on
    neither the old boot's seq nor its count, and publishes what both of them held.  (The
    session's epoch was set before the count: 4864 of the new boot's 5000 SIFs before it counted
    lost.)"""
    (t,) = parse_transds("transds/1\nx,1,p,M,1,int16_t,-1\n")
    topic = Topic.for_transducer("/b/x", "b", t, "missing_link_msgs")
    now = time.monotonic()
    published: list[Update] = []
    path = SamplePath(published.append, realtime_offset_ns=0)
    path.topics[1] = topic
    link = SeqLink()

    def handshake(epoch: str) -> tuple[Board, bool]:  # (as the session tells the same boot)
        props = {"clock.epoch": epoch}
        board = cast(Board, SimpleNamespace(index={}, properties=props, timeout=1.0, link=link))
        same = epoch == path.boot
        path.listen(board, same)
        return board, same

    board, same = handshake("old")
    path.resume(board, same, count=0)
    for n in range(10):  # the old boot's 10
        path.on_sif(link.sif(n), now)
    link.expected = None  # the board restarted (a new link) and sent 5000 before it
    handshake("new")
    for n in range(5000, 5003):  # the new boot's first handshake: its count call timed out
        path.on_sif(link.sif(n), now)
    board, same = handshake("new")
    for n in range(5003, 5005):
        path.on_sif(link.sif(n), now)
    assert not same
    path.resume(board, same, count=5005)
    assert len(published) == 10 + 5  # what both handshakes held, in order
    assert [u.values[0] for u in published[10:]] == list(range(5000, 5005))
    assert path.counters()["outage_lost_sifs"] == 0 == link.lost  # (a new boot's first)
