"""Typos say so (issue 45.4): a configured name that matches nothing once the boards are up is
said once with the nearest name that is there, and an unknown key in the configuration or a
board file gets "did you mean" too.  Before, a ``[joints]`` state naming ``rig/wheell``, a
``[boards.rigg.ros.wheel]`` table or a joint on a board that never comes ran silently (exit 0,
no joint)."""

from __future__ import annotations

import logging
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config
from missing_link.daemon.names import NameCheck
from missing_link.deploy.boardfile import check_board
from missing_link.errors import ConfigError

from .helpers import wait_for

Serve = Callable[..., Any]

TYPOS = """
[boards.rigg.ros.wheel]
counts_per_rev = 2000
[boards.thesis.ros.quadd]
frame_id = "wheels"
[boards.thesis.config]
"dist_irr.rate_hz" = 10
[joints.left]
state = "thesis/quad/0"
[joints.steer]
state = "thesis/servoo"
command = "thesis/servo"
[joints.far]
state = "ghost/wheel"
[remap]
"/thesis/dist_us" = "/sonar"
"/thesiss/dist_ir" = "/ir"
"""


def test_names_that_match_nothing_are_said_once_each_with_the_nearest() -> None:
    check = NameCheck(parse_config(tomllib.loads(TYPOS), "robot.toml"))
    up = {"thesis": ["quad", "dist_ir", "dist_us", "servo", "trigger"]}
    first = check.check(up, all_up=False)  # (another board may still come: only what is up)
    assert first == [
        "[boards.thesis.ros.quadd]: board thesis has no transducer 'quadd' (did you mean "
        "'quad'?) (it has dist_ir, dist_us, quad, servo, trigger)",
        "[joints.steer] state = 'thesis/servoo': board thesis has no transducer 'servoo' (did "
        "you mean 'servo'?) (it has dist_ir, dist_us, quad, servo, trigger)",
    ]
    later = check.check(up, all_up=True)
    assert later == [
        "[boards.rigg.ros.wheel]: no board 'rigg' is up (every board is up: thesis)",
        "[joints.far] state = 'ghost/wheel': no board 'ghost' is up (every board is up: thesis)",
        "[remap] '/thesiss/dist_ir': no board 'thesiss' is up (did you mean 'thesis'?) (every "
        "board is up: thesis)",
    ]
    assert check.check(up, all_up=True) == []  # once


def test_a_running_daemon_says_its_typos(serve: Serve, caplog: pytest.LogCaptureFixture) -> None:
    server = serve("thesis")
    doc = tomllib.loads(f'[daemon]\ndiagnostics_period = 0.05\n[[board]]\nurl = "{server.url}"\n'
                        + TYPOS)  # fmt: skip
    with (
        caplog.at_level(logging.WARNING, logger="missing_link.daemon.names"),
        Daemon(parse_config(doc, "robot.toml")) as d,
    ):
        assert d.wait_until_up(10)
        assert wait_for(lambda: "'ghost'" in caplog.text, 10), caplog.text
        assert wait_for(lambda: "did you mean 'servo'" in caplog.text, 10), caplog.text
        assert "dist_irr.rate_hz: no such key on thesis (did you mean 'dist_ir.rate_hz'?)" in (
            caplog.text
        )  # (the board's own keys: the session's check, said as it connects)
        # (all six said before the count: one check logs its lines one by one, and 'ghost' is
        # not its last; counted between two of them, the last looked like a round after)
        assert wait_for(lambda: len(caplog.records) >= 6, 10), caplog.text
        n = len(caplog.records)
        assert not wait_for(lambda: len(caplog.records) > n, 0.3)  # (the rounds after: quiet)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 6 and len(set(said)) == 6, said  # (5 names, 1 key: each once)


def test_a_subscription_to_no_topic_names_the_nearest(serve: Serve) -> None:
    server = serve("thesis")
    doc = tomllib.loads(f'[[board]]\nurl = "{server.url}"\n')
    with Daemon(parse_config(doc)) as d:
        assert d.wait_until_up(10)
        with pytest.raises(KeyError, match=r"did you mean '/thesis/dist_ir'\?"):
            d.subscribe("/thesis/dist_irr", lambda u: None)


@pytest.mark.parametrize(
    ("toml", "said"),
    [
        (
            '[daemon]\npublisher = ["bus"]',
            "daemon.publisher: unknown key (did you mean 'publishers'?)",
        ),
        ('[daemon]\npublishers = ["zenho"]', "unknown publisher 'zenho' (did you mean 'zenoh'?)"),
        ("[zenho]\nmode = 'peer'", "zenho: unknown table (did you mean 'zenoh'?)"),
        ("[zenoh]\ncomands = false", "[zenoh].comands: unknown key (did you mean 'commands'?)"),
        (
            "[boards.rig.cnofig]\n'a.b' = 1",
            "boards.rig.cnofig: unknown key (did you mean 'config'?)",
        ),
        (
            "[boards.rig.ros.wheel]\ncount_per_rev = 1",
            "unknown key (did you mean 'counts_per_rev'?)",
        ),
        ("[joints.j]\nstat = 'a/b'", "joints.j.stat: unknown key (did you mean 'state'?)"),
        ("[discover]\nport = []", "discover.port: unknown key (did you mean 'ports'?)"),
        (
            "[[board]]\nurl = 'tcp://127.0.0.1:1'\ntimout = 2",
            "unknown key (did you mean 'timeout'?)",
        ),
    ],
)
def test_an_unknown_key_names_the_nearest(toml: str, said: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(tomllib.loads(toml), "robot.toml")
    assert said in str(e.value), str(e.value)


RIG = Path(__file__).resolve().parent.parent / "examples" / "boards" / "thesis-rig.py"


@pytest.mark.parametrize(
    ("change", "said"),
    [
        (lambda b: b.update(transducer=b.pop("transducers")), "did you mean 'transducers'?"),
        (
            lambda b: b["transducers"][0].update(pin_aa=4),
            "has no option 'pin_aa' (did you mean 'pin_a'?)",
        ),
        (lambda b: b["transducers"][0].update(driver="quadratur"), "(did you mean 'quadrature'?)"),
        (lambda b: b["buses"]["i2c0"].update(sdaa=4), "unknown key 'sdaa' (did you mean 'sda'?)"),
        (lambda b: b.update(link={"kind": "usb", "baud": 9600}), "(did you mean 'baudrate'?)"),
    ],
)
def test_a_board_files_unknown_key_names_the_nearest(
    change: Callable[[dict[str, Any]], None], said: str
) -> None:
    import ast

    tree = ast.parse(RIG.read_text())
    board = next(ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign))
    change(board)
    with pytest.raises(ConfigError) as e:
        check_board(board, "mybot.py")
    assert said in str(e.value), str(e.value)
