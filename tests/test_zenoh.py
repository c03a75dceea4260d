"""ROS 2 through Zenoh: an independent consumer process (plain zenoh + rosbags) receives and
decodes our samples, sees the graph, and drives a servo; and the same across a Zenoh router with
the daemon, the board and the consumer each in their own process.  Loopback only, no multicast."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.publishers.zenoh import attachment, data_key, dds_type
from missing_link.topics import Update
from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ML, free_port, wait_for

HERE = Path(__file__).resolve().parent
LISTENER = HERE / "ros2_listener.py"
QUAD = "builtin_interfaces/Time[] times\\nint16[] values"
SERVO = "builtin_interfaces/Time[] times\\nint8[] values"
SIGNAL = "builtin_interfaces/Time[] times\\nint32[] values"


def run_listener(connect: str, *args: str, mode: str = "peer", timeout: float = 60) -> list[dict]:
    out = subprocess.run(
        [sys.executable, str(LISTENER), "--connect", connect, "--mode", mode, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert out.returncode == 0, out.stderr
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def test_wire_format_helpers() -> None:
    assert dds_type("sensor_msgs/msg/Range") == "sensor_msgs::msg::dds_::Range_"
    assert data_key(0, "/mcu/range", "sensor_msgs/msg/Range", "RIHS01_ab") == (
        "0/mcu/range/sensor_msgs::msg::dds_::Range_/RIHS01_ab"
    )
    att = attachment(7, 1_700_000_000_123_456_789, bytes(range(16)))
    assert len(att) == 33 and att[16] == 16 and att[17:] == bytes(range(16))


def zenoh_config(url: str, port: int) -> Config:
    """One board, the bus and a zenoh peer listening on ``port`` (loopback), connecting nowhere."""
    return Config(
        boards=[BoardSpec(url)],
        publishers=["bus", "zenoh"],
        publisher_options={"zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "connect": []}},
    )


@pytest.mark.slow
def test_independent_ros2_consumer_receives_decodes_and_commands(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve("thesis", "tcp://127.0.0.1:0")
    port = free_port()
    cfg = zenoh_config(server.url, port)
    with Daemon(cfg) as d:
        assert d.wait_until_up(10)
        lines = run_listener(
            f"tcp/127.0.0.1:{port}",
            *("--topic", "/thesis/quad", "--type", "missing_link_msgs/msg/Quad"),
            *("--msgdef", QUAD, "--count", "5"),
            *("--command", "/thesis/servo/cmd", "--command-type", "missing_link_msgs/msg/Servo"),
            *("--command-msgdef", SERVO, "--command-value", "50"),
        )
        wait_for(lambda: d.sessions[0].commands != 0, 5)
        commands = d.sessions[0].commands
        zpub = next(p for p in d.publishers if p.name == "zenoh")
    samples = [x["sample"] for x in lines if "sample" in x]
    assert len(samples) == 5
    typehash = zpub.typestore.hash_rihs01("missing_link_msgs/msg/Quad")
    for s in samples:
        assert s["key"] == f"0/thesis/quad/missing_link_msgs::msg::dds_::Quad_/{typehash}"
        assert s["encap"] == "00010000"
        assert s["attachment_len"] == 33 and s["gid_len"] == 16
        assert s["source_ns"] == max(s["times"])  # the board's measurement time, synchronised
        assert 0 <= s["rx_ns"] - s["source_ns"] < 2_000_000_000
    seqs = [s["seq"] for s in samples]
    assert seqs == sorted(seqs) and len(set(seqs)) == 5
    graph = next(x["graph"] for x in lines if "graph" in x)
    assert any("/NN/%/%/missing_link" in k for k in graph)
    assert any(
        "/MP/%/%/missing_link/%thesis%quad/missing_link_msgs::msg::dds_::Quad_/" in k for k in graph
    )
    assert any("/MS/%/%/missing_link/%thesis%servo%cmd/" in k for k in graph)
    assert any("%diagnostics/diagnostic_msgs::msg::dds_::DiagnosticArray_" in k for k in graph)
    # QoS with durability written out (volatile = 2), as rmw_zenoh reads it before and after
    # its default changed (PR #521): reliable (default), volatile, keep last 10
    (quad_token,) = [k for k in graph if "/MP/" in k and "%thesis%quad/" in k]
    assert quad_token.endswith("/:2:,10:,:,:,,")
    # the gid is XXH3-128 of the liveliness token, low 64 bits first (rmw_zenoh's Entity)
    import xxhash

    assert (
        samples[0]["gid"]
        == xxhash.xxh3_128(quad_token.encode()).intdigest().to_bytes(16, "little").hex()
    )
    assert commands >= 1  # the consumer's command reached the board's a2j_set_servo


@pytest.mark.slow
def test_a_late_subscriber_gets_the_actuators_state(serve) -> None:  # type: ignore[no-untyped-def]
    """The servo reports its state only when it changes; a transient-local subscriber that
    joins later still gets it (rmw_zenoh's way: an advanced publisher's cache)."""
    server = serve("thesis", "tcp://127.0.0.1:0")
    port = free_port()
    cfg = zenoh_config(server.url, port)
    with Daemon(cfg) as d:
        assert d.wait_until_up(10)
        states: list[Update] = []
        d.subscribe("/thesis/servo", states.append, queue=0)
        d.send("/thesis/servo/cmd", 37)
        # (the virtual servo moves there step by step)
        assert wait_for(lambda: states and states[-1].values == [37], 10)
        time.sleep(0.5)  # well after the state went out: only a cache can give it now
        lines = run_listener(
            f"tcp/127.0.0.1:{port}",
            *("--topic", "/thesis/servo", "--type", "missing_link_msgs/msg/Servo"),
            *("--msgdef", SERVO, "--count", "1", "--timeout", "10", "--history"),
        )
        graph = next(x["graph"] for x in lines if "graph" in x)
    samples = [x["sample"] for x in lines if "sample" in x]
    assert [s["values"] for s in samples] == [[37]]
    (token,) = [k for k in graph if "/MP/" in k and "%thesis%servo/" in k]
    assert token.endswith("/:1:,1:,:,:,,")  # transient local, keep last 1


@pytest.mark.slow
def test_three_processes_through_a_router(tmp_path: Path) -> None:
    """Router, board + daemon (``missing-link run``) and consumer: separate processes, as on
    separate machines; the consumer knows only the router's address."""
    rport = free_port()
    router = subprocess.Popen(
        [*ML, "router", "--listen", f"tcp/127.0.0.1:{rport}"],
        stdout=subprocess.PIPE,
        text=True,
    )
    board, url = start_board_process("rate", 0, "pty", extra=["--rate", "200"])
    daemon = None
    try:
        assert router.stdout is not None and router.stdout.readline().startswith("READY")
        conf = tmp_path / "ml.toml"
        conf.write_text(
            f'[daemon]\npublishers = ["zenoh"]\n\n[[board]]\nurl = "{url}"\n\n'
            f'[zenoh]\nconnect = ["tcp/127.0.0.1:{rport}"]\n'
        )
        daemon = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "missing_link",
                "run",
                "--config",
                str(conf),
                "--duration",
                "40",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        lines = run_listener(
            f"tcp/127.0.0.1:{rport}",
            *("--topic", "/rate/signal", "--type", "missing_link_msgs/msg/Signal"),
            *("--msgdef", SIGNAL, "--count", "20"),
            mode="client",
        )
    finally:
        if daemon is not None:
            daemon.terminate()
            daemon.wait(10)
        stop_process(board)
        router.terminate()
        router.wait(10)
    samples = [x["sample"] for x in lines if "sample" in x]
    assert len(samples) == 20
    values = [s["values"][0] for s in samples]
    assert values == sorted(values)  # the counter, in order
    assert all(s["attachment_len"] == 33 for s in samples)
    graph = next(x["graph"] for x in lines if "graph" in x)
    assert any("%rate%signal" in k for k in graph)


@pytest.mark.parametrize("distro", ["humble", "kilted"])
def test_distro_sets_the_type_hash_slot(distro: str) -> None:
    from missing_link.publishers.zenoh import type_hash
    from missing_link.ros.msgs import typestore_for

    ts = typestore_for(distro)
    h = type_hash(ts, "sensor_msgs/msg/Range", distro)
    assert h == "TypeHashNotSupported" if distro == "humble" else h.startswith("RIHS01_")


TRIGGER = "builtin_interfaces/Time[] times\\nuint16[] values"


@pytest.mark.slow
def test_a_command_with_a_future_stamp_acts_at_that_host_time(serve) -> None:  # type: ignore[no-untyped-def]
    """A plain zenoh + rosbags consumer sends a thesis-format command whose times[0] is a host
    time 400 ms ahead: the board's trigger fires then (board/timing.py), reported as a sample
    whose host time is that time, not when the command arrived."""
    server = serve("aligned", "tcp://127.0.0.1:0")
    port = free_port()
    with Daemon(zenoh_config(server.url, port)) as d:
        assert d.wait_until_up(10)
        fired: list[Update] = []
        d.subscribe("/aligned/trigger", fired.append, queue=0)
        lines = run_listener(
            f"tcp/127.0.0.1:{port}",
            *("--topic", "/aligned/signal", "--type", "missing_link_msgs/msg/Signal"),
            *("--msgdef", SIGNAL, "--count", "1"),
            *(
                "--command",
                "/aligned/trigger/cmd",
                "--command-type",
                "missing_link_msgs/msg/Trigger",
            ),
            *("--command-msgdef", TRIGGER, "--command-value", "25", "--command-dtype", "uint16"),
            *("--command-count", "1", "--command-at-ms", "400"),
        )
        at = next(x["command_at_ns"] for x in lines if "command_at_ns" in x)
        wait_for(lambda: fired, 5)
        status = d.status()[0]
    assert len(fired) == 1, fired
    u = fired[0]
    assert u.values == [25]
    # the board acted at the tick the pushed map gave (within that map's bound of the truth),
    # published through the map of now (within its bound): twice the bound, at most
    assert abs(u.host_ns[0] - at) <= 2 * u.bound_ns + 1000, (u.host_ns[0] - at, u.bound_ns)
    assert u.recv_ns / 1e9 > 0 and status["commands"] == 1


@pytest.mark.slow  # (seconds of real time)
def test_rejected_commands_are_counted_on_diagnostics(serve) -> None:  # type: ignore[no-untyped-def]
    """Commands that do not decode (an attacker's, a client with another message type) were
    counted in the publisher but shown nowhere: ~6,000 in one run, invisible.  Now they are
    ``commands_rejected`` in the publisher's status and on ``/diagnostics`` (what the daemon's
    allow-list refuses is ``commands_refused``, beside it)."""
    import zenoh
    from rosbags.typesys import Stores, get_typestore

    server = serve("thesis", "tcp://127.0.0.1:0")
    port = free_port()
    with Daemon(zenoh_config(server.url, port)) as d:
        assert d.wait_until_up(10)
        zp = next(p for p in d.publishers if p.name == "zenoh")
        servo = "missing_link_msgs/msg/Servo"
        key = data_key(0, "/thesis/servo/cmd", servo, zp.typestore.hash_rihs01(servo))  # type: ignore[attr-defined]
        diag_key = data_key(
            0, "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray",
            zp.typestore.hash_rihs01("diagnostic_msgs/msg/DiagnosticArray"),  # type: ignore[attr-defined]
        )  # fmt: skip
        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps("peer"))
        cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        diags: list[bytes] = []
        with zenoh.open(cfg) as client:
            sub = client.declare_subscriber(diag_key, lambda s: diags.append(bytes(s.payload)))
            pub = client.declare_publisher(key)
            # (until the daemon's subscriber is known here)
            wait_for(lambda: pub.matching_status.matching, 10)
            for k in range(50):
                pub.put(b"\x00\x01\x00\x00" + bytes([k % 7]) * (k % 5))  # not a Servo
            wait_for(lambda: zp.command_errors >= 50, 10)  # type: ignore[attr-defined]
            st = next(s for s in d.publisher_status() if s["publisher"] == "zenoh")
            seen = len(diags)
            wait_for(lambda: len(diags) >= seen + 2, 15)  # a /diagnostics round after the last
            pub.undeclare()
            sub.undeclare()
    assert st["commands_rejected"] == 50 and st["commands"] == 0, st
    ts = get_typestore(Stores.ROS2_JAZZY)
    last = ts.deserialize_cdr(diags[-1], "diagnostic_msgs/msg/DiagnosticArray")
    mine = next(s for s in last.status if s.name == "missing_link publisher: zenoh")
    assert {kv.key: kv.value for kv in mine.values}["commands_rejected"] == "50"
