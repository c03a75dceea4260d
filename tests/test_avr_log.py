"""The board's log on AVR machine code (issue 36.2; firmware/avr/src/log.c): the thesis rig's
SRF02 taken off the bus in simavr is said once - WARN, ``sonar: not answering`` - and then only
counted on the board (``a2jLogInfo``, the daemon's ``log_faults``); put back, it ranges again."""

from __future__ import annotations

import struct

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.host.board_log import LogLine, parse_info
from missing_link.topics import Update

from .helpers import AvrSim, wait_for

pytestmark = pytest.mark.avr


def faults(d: Daemon) -> dict[tuple[int, int], int]:
    info = parse_info(d.call("uno_rig", "a2jLogInfo").payload)
    return {(s, k): n for s, k, n in info.faults}


@pytest.mark.slow
def test_an_absent_srf02_is_said_once_then_counted(uno_rig: AvrSim) -> None:
    cfg = Config(boards=[BoardSpec(uno_rig.url, timeout=2.0, uart_baud=115200)])
    with Daemon(cfg) as d:
        lines: list[LogLine] = []
        sonar: list[Update] = []
        d.subscribe_logs(lines.append)
        d.subscribe("/uno_rig/sonar", sonar.append)
        assert d.wait_until_up(20), d.status()
        assert wait_for(lambda: sonar and sonar[-1].values[0] is not None, 10)
        assert lines == [] and faults(d) == {}  # nothing wrong yet
        assert uno_rig.ctl("srf02_absent 1") == "ok"
        sid = 2  # the sonar's transducer id (thesis-rig-uno.py)
        assert wait_for(lambda: faults(d).get((sid, 1), 0) >= 5, 10)  # 15 Hz: counted on
        absent = [x for x in lines if x.kind == "not answering"]
        assert len(absent) == 1  # said once
        (line,) = absent
        assert (line.level_name, line.source, line.text) == (
            "WARN",
            "sonar",
            "sonar: not answering",
        )
        assert not line.earlier and line.board_us > 0  # said live, stamped by the board
        assert sonar[-1].values[0] is None  # (and its samples are N/A)
        # the daemon's own reading of the counts, once a diagnostics period
        assert wait_for(lambda: "sonar not answering x" in d.status()[0]["log_faults"], 10)
        assert uno_rig.ctl("srf02_absent 0") == "ok"
        n = len(sonar)
        assert wait_for(lambda: len(sonar) > n + 2 and sonar[-1].values[0] is not None, 10)
        assert len([x for x in lines if x.kind == "not answering"]) == 1
        said, dropped = struct.unpack("<II", d.call("uno_rig", "a2jLogInfo").payload[:8])
        assert said == len(lines) and dropped == 0  # every line the board said, heard
