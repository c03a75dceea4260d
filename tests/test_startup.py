"""Start-up stays light (issue 33.6): what ``import missing_link`` and a one-off
``missing-link call`` load, checked by module name, not by the clock (docs/performance.md has
the times).  Each probe runs in a fresh interpreter: this process has imported everything."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.slow  # (every test here starts a process: make check skips them)

Serve = Callable[..., Any]

#: what a one-off command must not pay for: the daemon's service and sessions, clock sync's
#: numpy, the publishers and their libraries, the live view's rich, asyncio
HEAVY = (
    "numpy",
    "rosbags",
    "zenoh",
    "mcap",
    "foxglove",
    "foxglove_websocket",
    "websockets",
    "rich",
    "asyncio",
    "rclpy",
    "rospy",
    "tomllib",
    "missing_link.daemon.service",
    "missing_link.daemon.session.session",
    "missing_link.timesync.estimator",
    "missing_link.publishers",
    "missing_link.virtual",
)

PROBE = """
import json, sys
stages = {}
import missing_link
stages["import missing_link"] = sorted(sys.modules)
from missing_link.cli.main import build_parser, main
build_parser().parse_args(["call", "tcp://127.0.0.1:1", "a2jEcho"])
stages["parse a call"] = sorted(sys.modules)
code = main(["call", sys.argv[1], "a2jEcho"])
stages["call"] = sorted(sys.modules)
print(json.dumps({"code": code, "stages": stages}))
"""


def loaded_heavy(modules: list[str]) -> list[str]:
    """The heavy ones among ``modules`` (a package once, not each of its modules)."""
    return sorted(
        {
            m if m in HEAVY else m.split(".")[0]
            for m in modules
            if m in HEAVY or m.split(".")[0] in HEAVY
        }
    )


def test_a_one_off_call_loads_nothing_heavy(serve: Serve, tmp_path: Path) -> None:
    server = serve("thesis", listen="tcp://127.0.0.1:0")
    env = {**os.environ, "MISSING_LINK_CONTROL": str(tmp_path / "no-daemon.sock")}
    r = subprocess.run(
        [sys.executable, "-c", PROBE, server.url],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("return 0xba")  # the call went through, to the board and back
    got = json.loads(lines[-1])
    assert got["code"] == 0
    for stage, modules in got["stages"].items():
        assert not loaded_heavy(modules), f"{stage} loads {loaded_heavy(modules)}"
    first = got["stages"]["import missing_link"]
    assert [m for m in first if m.startswith("missing_link.")] == []
    assert "typing" not in first  # (a name used later pays for it)
    parse = got["stages"]["parse a call"]
    assert "missing_link.host.board" not in parse  # the command's code: only when it runs
    # a call that packs no --value reads no descriptors and sets no keys: neither is loaded
    call = got["stages"]["call"]
    assert "missing_link.descriptors" not in call and "missing_link.host.config" not in call


def test_building_every_command_parser_loads_no_command_code() -> None:
    probe = (
        "import sys\n"
        "from missing_link.cli.main import build_parser\n"
        "build_parser().parse_args(['info', 'tcp://127.0.0.1:1'])\n"
        "print(' '.join(sorted(sys.modules)))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True
    )
    modules = r.stdout.split()
    assert not loaded_heavy(modules)
    commands = {"talk", "configure", "msgs", "run", "deploy", "virtual", "router", "demo", "rig"}
    assert not [m for m in modules if m.rsplit(".", 1)[-1] in commands and "cli" in m]
