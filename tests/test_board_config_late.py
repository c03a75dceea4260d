"""A board that answers its configuration late when it connects (a busy board or host): the
session asks again on the same link, and ends with the configuration the file asks for."""

from __future__ import annotations

import time
from typing import Any

import pytest

from missing_link.virtual import make_sim

from .helpers import wait_for


@pytest.mark.parametrize("late_call", ["a2jConfigGet", "a2jConfigSet"])
def test_a_board_that_answers_its_configuration_late_is_asked_again(
    serve: Any, late_call: str
) -> None:
    """Its first a2jConfigGet (the read) or a2jConfigSet (the config file's keys) answers after
    twice the call's timeout (the board is busy): the session asks again on the same link and
    has the configuration, the file's keys applied.  Before, the link ran its whole life without
    them, said only as a warning (a replay's recording under load lost /board_b/config), and a
    late set left the keys' values on every face the ones from before (aa589ab, ead7385)."""
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config

    rt = make_sim("thesis", 1)
    name, kind, call = rt.functions[rt.index[late_call]]
    late: list[bytes] = []

    def first_late(payload: bytes) -> Any:
        if not late:
            late.append(payload)
            time.sleep(1.0)  # (twice the call's timeout: it cannot be in time, however busy)
        return call(payload)

    rt.functions[rt.index[late_call]] = (name, kind, first_late)
    server = serve(rt, "tcp://127.0.0.1:0")
    cfg = Config(boards=[BoardSpec(server.url, timeout=0.5)])
    cfg.board_config = {"thesis": {"dist_ir.rate_hz": 5}}
    with Daemon(cfg) as d:
        assert wait_for(lambda: d.status()[0]["state"] == "up", 30), d.status()
        st = d.status()[0]
        assert late and st["connects"] == 1 and st["failures"] == 0, st
        assert "dist_ir.rate_hz=5" in st["config"] and not st["warnings"], st
    assert rt.config.values()[[k.name for k in rt.config.keys].index("dist_ir.rate_hz")] == 5.0


def test_a_board_that_never_answers_its_configuration_in_time_still_publishes(
    serve: Any,
) -> None:
    """Every a2jConfigGet of this board answers after its call's timeout (a configuration
    function that hangs a while; the board is otherwise well): after asking for as long as a
    handshake may take, the session says so and publishes the board, as it does one that
    answers them with garbage.  Before, every connect failed after the handshake's time and
    the session backed off and connected again, for good: not one sample of the board's."""
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config

    rt = make_sim("thesis", 1)
    name, kind, get = rt.functions[rt.index["a2jConfigGet"]]
    asked: list[bytes] = []

    def always_late(payload: bytes) -> Any:
        asked.append(payload)
        time.sleep(0.6)  # (beyond the call's timeout: never in time, however fast the host)
        return get(payload)

    rt.functions[rt.index["a2jConfigGet"]] = (name, kind, always_late)
    server = serve(rt, "tcp://127.0.0.1:0")
    cfg = Config(boards=[BoardSpec(server.url, timeout=0.3, handshake_timeout=1.0)])
    got: list[object] = []
    with Daemon(cfg) as d:
        d.subscribe("/thesis/dist_ir", got.append)
        assert wait_for(lambda: d.status()[0]["state"] == "up", 30), d.status()
        st = d.status()[0]
        assert len(asked) >= 2 and st["connects"] == 1 and st["failures"] == 0, st
        assert "run-time configuration unread: no answer in time" in st["warnings"], st
        assert wait_for(lambda: got, 10)
