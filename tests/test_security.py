"""Who may watch and who may move the robot (docs/security.md), tried as an attacker would:
examples/security/make-certs.sh's mutual-TLS setup against real Zenoh client sessions in
processes of their own that import nothing of ours (tests/ros2_listener.py: eclipse-zenoh and
rosbags); commands opt-in per face and the daemon's allow-list; what network clients may write
into our logs."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, parse_config
from missing_link.daemon.control.allowlist import CommandRefused
from missing_link.errors import ConfigError
from missing_link.logs import SafeLog
from missing_link.publishers.zenoh_config import loopback_only
from missing_link.topics import Update

from .helpers import ML, board_process, free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
LISTENER = Path(__file__).with_name("ros2_listener.py")
MAKE_CERTS = ROOT / "examples" / "security" / "make-certs.sh"
DIST_IR = "builtin_interfaces/Time[] times\\nuint16[] values"
SERVO = "builtin_interfaces/Time[] times\\nint8[] values"


def listener(config: Path, *args: str, timeout: float = 60) -> tuple[int, list[dict]]:
    out = subprocess.run(
        [sys.executable, str(LISTENER), "--config", str(config), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return out.returncode, [json.loads(x) for x in out.stdout.splitlines() if x.startswith("{")]


def samples(lines: list[dict]) -> list[dict]:
    return [x["sample"] for x in lines if "sample" in x]


def watch_ir(config: Path, count: int = 2, timeout: float = 8) -> tuple[int, list[dict]]:
    return listener(
        config,
        *("--topic", "/thesis/dist_ir", "--type", "missing_link_msgs/msg/DistIr"),
        *("--msgdef", DIST_IR, "--count", str(count), "--timeout", str(timeout)),
    )


def servo_state(config: Path) -> list[list[int]]:
    """The servo's latest state, as a late transient-local subscriber gets it (none: never)."""
    _, lines = listener(
        config,
        *("--topic", "/thesis/servo", "--type", "missing_link_msgs/msg/Servo"),
        *("--msgdef", SERVO, "--count", "1", "--timeout", "4", "--history"),
    )
    return [s["values"] for s in samples(lines)]


def command(config: Path, value: int) -> list[dict]:
    _, lines = listener(
        config,
        *("--topic", "/thesis/dist_ir", "--type", "missing_link_msgs/msg/DistIr"),
        *("--msgdef", DIST_IR, "--count", "1", "--timeout", "10"),
        *("--command", "/thesis/servo/cmd", "--command-type", "missing_link_msgs/msg/Servo"),
        *("--command-msgdef", SERVO, "--command-value", str(value), "--command-count", "3"),
    )
    return lines


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    """A thesis board behind a daemon run with make-certs.sh's daemon.toml; (ours, another CA)."""
    port = free_port()
    ours, other = tmp_path_factory.mktemp("certs"), tmp_path_factory.mktemp("other-ca")
    for d in (ours, other):
        subprocess.run(["sh", str(MAKE_CERTS), str(d), str(port)], check=True, capture_output=True)
    with board_process("--sim", "thesis") as url:
        p = subprocess.Popen(
            [*ML, "run", "--config", str(ours / "daemon.toml"),
             url],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            # up when the operator sees samples
            assert wait_for(lambda: len(samples(watch_ir(ours / "operator.json5", 1)[1])) == 1, 60)
            yield ours, other
        finally:
            p.terminate()
            p.wait(10)


@pytest.mark.slow
def test_the_setup_files_are_complete(secured: tuple[Path, Path]) -> None:
    ours, _ = secured
    cfg = parse_config(__import__("tomllib").loads((ours / "daemon.toml").read_text()))
    assert cfg.publisher_options["zenoh"]["listen"][0].startswith("tls/127.0.0.1:")
    for name in ("daemon.json5", "operator.json5", "viewer.json5"):
        text = (ours / name).read_text()
        assert str(ours) in text  # absolute paths: usable from anywhere
    assert oct((ours / "ca.key").stat().st_mode)[-3:] == "600"


@pytest.mark.slow
def test_a_client_without_a_certificate_gets_nothing(secured: tuple[Path, Path]) -> None:
    ours, _ = secured
    bare = ours.parent / "bare.json5"
    text = (ours / "viewer.json5").read_text()
    keep = [x for x in text.splitlines() if "connect_private_key" not in x]
    bare.write_text("\n".join(x for x in keep if "connect_certificate" not in x))
    code, lines = watch_ir(bare, timeout=4)
    assert code != 0 or samples(lines) == []


@pytest.mark.slow
def test_a_certificate_from_another_ca_gets_nothing(secured: tuple[Path, Path]) -> None:
    _, other = secured
    code, lines = watch_ir(other / "operator.json5", timeout=4)
    assert code != 0 or samples(lines) == []


@pytest.mark.slow
def test_the_viewer_sees_everything_but_cannot_command(secured: tuple[Path, Path]) -> None:
    ours, _ = secured
    code, lines = watch_ir(ours / "viewer.json5")
    assert code == 0 and len(samples(lines)) == 2  # it sees the data
    lines = command(ours / "viewer.json5", 40)
    assert any("command_at_ns" in x for x in lines)  # it did try
    time.sleep(1.0)
    assert servo_state(ours / "operator.json5") == []  # the servo never moved


@pytest.mark.slow
def test_the_operator_commands(secured: tuple[Path, Path]) -> None:
    ours, _ = secured
    command(ours / "operator.json5", 40)
    assert wait_for(lambda: servo_state(ours / "operator.json5") == [[40]], 20)


# ---- commands opt-in per face, the allow-list ---------------------------------------------------
def test_loopback_decides_the_default() -> None:
    assert loopback_only(["tcp/127.0.0.1:7447", "tls/[::1]:7448", "tcp/localhost:1"])
    assert not loopback_only(["tcp/127.0.0.1:7447", "tcp/0.0.0.0:7447"])
    assert not loopback_only(["tcp/192.168.1.5:7447"])


@pytest.mark.slow
def test_a_face_off_and_the_allow_list_refuse_and_count() -> None:
    port = free_port()
    with board_process("--sim", "thesis") as url:
        cfg = Config(
            boards=[BoardSpec(url)],
            publishers=["bus", "zenoh"],
            publisher_options={
                "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "connect": [], "commands": False}
            },
            commands=["/thesis/trigger/cmd"],  # the servo is not on the list
        )
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            states: list[Update] = []
            d.subscribe("/thesis/servo", states.append, queue=0)
            with pytest.raises(CommandRefused, match="not in \\[daemon\\] commands"):
                d.send("/thesis/servo/cmd", 30)  # in-process: the allow-list still applies
            lines = subprocess.run(
                [sys.executable, str(LISTENER), "--connect", f"tcp/127.0.0.1:{port}",
                 "--topic", "/thesis/dist_ir", "--type", "missing_link_msgs/msg/DistIr",
                 "--msgdef", DIST_IR, "--count", "1", "--command", "/thesis/servo/cmd",
                 "--command-type", "missing_link_msgs/msg/Servo", "--command-msgdef", SERVO,
                 "--command-value", "40", "--command-count", "3"],
                capture_output=True, text=True, timeout=60,
            ).stdout  # fmt: skip
            assert '"command_at_ns"' in lines
            assert wait_for(lambda: _refused(d) == {"bus": 1, "zenoh": 3}, 10), _refused(d)
            time.sleep(0.5)
            assert states == [] and d.status()[0]["commands"] == 0


def _refused(d: Daemon) -> dict[str, int]:
    return {s["publisher"]: s["commands_refused"] for s in d.publisher_status()
            if s.get("commands_refused")}  # fmt: skip


def test_commands_option_must_be_a_bool() -> None:
    with pytest.raises(ConfigError, match=r"\[zenoh\]\.commands: expected true or false"):
        Daemon(Config(publishers=["zenoh"], publisher_options={"zenoh": {"commands": "yes"}}))
    with pytest.raises(ConfigError, match=r"daemon\.commands"):
        parse_config({"daemon": {"commands": ["servo"]}})


# ---- what a network client may write into our logs ----------------------------------------------
def test_log_lines_are_made_safe_and_rate_limited() -> None:
    now = [0.0]
    f = SafeLog(burst=3, window_s=10, clock=lambda: now[0])
    records = []
    for i in range(10):
        r = logging.LogRecord(
            "missing_link.x",
            logging.WARNING,
            "",
            0,
            "bad name %r",
            (f"n\x1b[2J{i}\nmissing-link: forged",),
            None,
        )
        if f.filter(r):
            records.append(r.getMessage())
    assert len(records) == 3 and SafeLog.suppressed >= 7
    assert all("\x1b" not in m and "\n" not in m for m in records)
    now[0] = 11.0
    r = logging.LogRecord("missing_link.x", logging.WARNING, "", 0, "bad name %r", ("ok",), None)
    assert f.filter(r) and "7 more like this in the last 10 s held back" in r.getMessage()
    long = logging.LogRecord("missing_link.y", logging.WARNING, "", 0, "%s", ("x" * 5000,), None)
    assert f.filter(long) and len(long.getMessage()) == 500


# ---- the Foxglove view: who may look, what a client may say -----------------------------------
@pytest.mark.slow
def test_the_foxglove_view_checks_origins_and_drops_what_it_does_not_serve(
    caplog: pytest.LogCaptureFixture,
) -> None:
    import asyncio

    import websockets

    from .test_foxglove import _client

    async def refused(url: str, origin: str) -> int:
        try:
            async with websockets.connect(url, origin=origin, subprotocols=["foxglove.sdk.v1"]):  # type: ignore[arg-type, list-item]
                return 0
        except websockets.exceptions.InvalidStatus as e:
            return int(e.response.status_code)

    async def noise(url: str) -> None:
        async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
            await ws.send("\x1b[2J\nmissing-link: error: forged line")
            await ws.send(json.dumps({"op": "\x1b[31mclientAdvertise", "channels": []}))
            await ws.send(b"\x02\x00\x00\x00\x00binary client publish")
            await asyncio.sleep(0.3)

    with board_process("--sim", "thesis") as url:
        cfg = Config(
            boards=[BoardSpec(url)],
            publishers=["bus", "foxglove"],
            publisher_options={"foxglove": {"port": 0, "origins": ["https://app.foxglove.dev"]}},
        )
        with Daemon(cfg) as d, caplog.at_level(logging.WARNING):
            assert d.wait_until_up(10)
            fox = next(p for p in d.publishers if p.name == "foxglove")
            assert asyncio.run(refused(fox.url, "http://evil.example")) == 403
            assert asyncio.run(refused(fox.url, "https://app.foxglove.dev")) == 0  # allowed
            asyncio.run(noise(fox.url))
            ch, payload, _topics = asyncio.run(_client(fox.url, "/thesis/dist_ir"))  # no Origin
            st = fox.status()
    assert ch["schemaEncoding"] == "ros2msg" and payload
    assert st["origins_refused"] == 1 and st["client_messages_dropped"] == 3
    logged = "\n".join(r.getMessage() for r in caplog.records)
    assert "http://evil.example" in logged and "forged" not in logged
