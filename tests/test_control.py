"""The local control endpoint (daemon/control/endpoint.py) is ours and stays up: an endpoint another
user made is refused by the daemon and by its clients, running out of descriptors is survived,
hostile requests (deep nesting, NaN, Infinity, huge numbers, idle clients) get a bounded answer,
and a control call keeps the daemon's allow-list of commands (daemon/control/allowlist.py)."""

from __future__ import annotations

import json
import logging
import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.control.allowlist import CommandRefused
from missing_link.daemon.control.endpoint import (
    MAX_CALL_TIMEOUT,
    MAX_CLIENTS,
    ControlServer,
    NotOurs,
    ask,
    call_timeout,
    check_endpoint,
)
from missing_link.daemon.session.status import SessionState
from missing_link.errors import ConfigError, MissingLinkError
from missing_link.topics import Update
from missing_link.virtual import make_sim

from .helpers import ml, wait_for

Serve = Callable[..., Any]
FIND = {"op": "find", "board": "x"}
NOBODY = 65534


def found(r: dict[str, Any]) -> dict[str, Any]:
    return {"name": "x", "url": "memory://x", "state": "up"}


# ---- ours --------------------------------------------------------------------------------------
def test_an_endpoint_that_is_not_ours_is_refused(tmp_path: Path, caplog: Any) -> None:
    d = tmp_path / "ml"
    d.mkdir(mode=0o700)
    path = str(d / "control.sock")
    check_endpoint(path)  # ours, and nothing there yet
    with pytest.raises(NotOurs, match=r"belongs to uid \d+, not to you \(uid 4242\)"):
        check_endpoint(path, uid=4242)  # as seen by another user: not theirs
    d.chmod(0o777)  # anyone may put a socket there
    with pytest.raises(NotOurs, match=r"others may write to .* \(mode 777\)"):
        check_endpoint(path)
    with pytest.raises(NotOurs, match="others may write"):
        ControlServer(path, {"find": found})
    with caplog.at_level(logging.WARNING), Daemon(Config(control=path)) as daemon:
        assert daemon.control is None  # the daemon runs, without that endpoint, and says why
    assert "others may write" in caplog.text
    d.chmod(0o700)
    link = tmp_path / "link"
    link.symlink_to(d)  # a link can be swapped for another directory after the check
    with pytest.raises(NotOurs, match="is not a directory"):
        check_endpoint(str(link / "control.sock"))
    (d / "control.sock").write_text("")
    with pytest.raises(NotOurs, match="not a socket"):
        ask(path, FIND, 1.0)


@pytest.mark.skipif(os.getuid() != 0, reason="making another user's files needs root")
def test_the_endpoint_makes_no_directory_but_its_own(tmp_path: Path) -> None:
    """Only the per-user runtime directory is made for the socket: a control path anywhere
    else needs its directory to exist (no mkdir -p on a path from a config or the API)."""
    where = tmp_path / "a" / "b" / "control.sock"
    with pytest.raises(MissingLinkError, match="make it first"):
        ControlServer(str(where), {})
    assert not (tmp_path / "a").exists()


@pytest.mark.slow
def test_another_users_endpoint_is_never_asked_nor_used(tmp_path: Path) -> None:
    """Another user made the directory first and answers on it with lies: the client asks
    nothing there, and the daemon does not bind there (it runs without the endpoint)."""
    tmp_path.chmod(0o755)
    d = tmp_path / "missing-link-victim"
    d.mkdir(mode=0o755)
    path = str(d / "control.sock")
    liar = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    liar.bind(path)
    liar.listen(1)
    liar.settimeout(0.5)
    os.chown(d, NOBODY, NOBODY)
    os.chown(path, NOBODY, NOBODY)
    try:
        with pytest.raises(NotOurs, match=f"belongs to uid {NOBODY}, not to you"):
            ask(path, {"op": "call", "board": "robot", "function": "a2jEcho"})
        with pytest.raises(socket.timeout):
            liar.accept()  # nothing was sent to it
        with pytest.raises(NotOurs, match=f"belongs to uid {NOBODY}"):
            ControlServer(path, {"find": found})
        os.chown(d, 0, 0)  # our directory, but a socket someone else put there
        with pytest.raises(NotOurs, match=f"the socket belongs to uid {NOBODY}"):
            ask(path, FIND, 1.0)
        env = {**os.environ, "MISSING_LINK_CONTROL": path}
        cli = ml("call", "robot", "a2jEcho", timeout=30, env=env)
        assert cli.returncode != 0 and "Traceback" not in cli.stderr
        assert "the socket belongs to uid" in cli.stderr and len(cli.stderr.splitlines()) == 1
    finally:
        liar.close()


# ---- up ----------------------------------------------------------------------------------------
CHILD = """
import os, resource, sys, threading
from missing_link.daemon.control.endpoint import ControlServer
from missing_link.testing import wait_for
resource.setrlimit(resource.RLIMIT_NOFILE, (64, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
server = ControlServer(sys.argv[1], {"find": lambda r: {"name": "x", "url": "u", "state": "up"}})
print("READY", flush=True)
held = []
for line in sys.stdin:
    if line.strip() == "fill":
        wait_for(lambda: threading.active_count() <= 2, 10, 0.01)  # (the last client's closed)
        try:
            while True:
                held.append(os.open(os.devnull, os.O_RDONLY))
        except OSError:
            print("FULL", flush=True)
    elif line.strip() == "free":
        wait_for(lambda: server.accept_errors, 10, 0.01)
        for fd in held:
            os.close(fd)
        held.clear()
        print("FREED", server.accept_errors, flush=True)
"""


@pytest.mark.slow
def test_the_endpoint_recovers_once_descriptors_are_free(tmp_path: Path) -> None:
    """Every descriptor of the daemon's process taken: accepting fails (EMFILE) and is tried
    again, so the endpoint answers once some are free.  (A thread blocked in accept holds one
    descriptor in reserve: the first client takes it, the next accept finds none.)"""
    path = str(tmp_path / "c.sock")
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, path],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert child.stdin is not None and child.stdout is not None

    def say(line: str) -> str:
        assert child.stdin is not None and child.stdout is not None
        child.stdin.write(line + "\n")
        child.stdin.flush()
        return child.stdout.readline()

    first = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        assert child.stdout.readline() == "READY\n"
        assert ask(path, FIND, 5.0)["name"] == "x"
        assert say("fill") == "FULL\n"
        first.connect(path)  # accepted into the reserve; the next accept fails (EMFILE)
        freed = say("free").split()
        assert freed[0] == "FREED" and int(freed[1]) >= 1, freed  # it failed, and counted it
        assert ask(path, FIND, 10.0)["name"] == "x"  # ... and it answers again
    finally:
        first.close()
        child.kill()
        child.wait(5)
        for f in (child.stdin, child.stdout, child.stderr):
            if f is not None:
                f.close()


def raw(path: str, data: bytes, timeout: float = 10.0) -> dict[str, Any] | None:
    """``data`` sent as it is; the answer, or None when the connection closed without one."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(path)
        s.sendall(data)
        got = b""
        while chunk := s.recv(65536):
            got += chunk
    return json.loads(got) if got else None


@pytest.fixture
def held(serve: Serve, tmp_path: Path) -> Any:
    server = serve(make_sim("thesis", seed=5, name="thesis"))
    path = str(tmp_path / "c.sock")
    with Daemon(Config(boards=[BoardSpec(server.url)], control=path, commands=["/nothing"])) as d:
        assert d.wait_until_up(10)
        yield d, path


def test_hostile_requests_are_answered_and_the_endpoint_stays(held: Any) -> None:
    d, path = held
    echo = '{"op": "call", "board": "thesis", "function": "a2jEcho", "payload": "01", '
    deep = b"[" * 200_000 + b"]" * 200_000 + b"\n"
    assert raw(path, deep[:60_000] + b"\n") == {
        "error": "not a control request (ops: find, info, call, config, update, update_status, "
        "release, retake)", "kind": "usage",
    }  # fmt: skip
    for timeout in (
        "NaN",
        "Infinity",
        "-Infinity",
        "1e999",
        "0",
        "-1",
        '"10"',
        "true",
        "1" + "0" * 400,
    ):
        got = raw(path, (echo + f'"timeout": {timeout}}}\n').encode())
        assert got is not None and got["kind"] == "usage", (timeout, got)
    got = raw(path, (echo + '"timeout": 1e308}\n').encode())  # clamped to 60 s
    assert got == {"code": 0xBA, "payload": "01"}
    assert d.control.refused >= 5
    assert ask(path, {"op": "find", "board": "thesis"})["state"] == "up"
    # fields missing or of the wrong type, a payload not hex: usage errors that say which
    for request, why in (({"op": "find"}, "find: board: missing"),
                         ({"op": "info", "board": {"a": 1}}, "info: board: expected text"),
                         ({"op": "call", "board": "thesis"}, "call: function: missing"),
                         ({"op": "call", "board": "thesis", "function": "a2jEcho",
                           "payload": "zz"}, "call: payload: expected hex digits")):  # fmt: skip
        got = ask(path, request)
        assert got["kind"] == "usage" and got["error"].startswith(why), (request, got)
    assert d.control.faults.total == 0  # (refusals, not bugs: no traceback, no internal error)


def test_call_timeouts_are_checked_and_clamped() -> None:
    assert call_timeout(None) is None and call_timeout(2) == 2.0
    assert call_timeout(1e308) == call_timeout(61.0) == MAX_CALL_TIMEOUT
    for bad in (float("nan"), float("inf"), 0, -1.0, "10", True, [1], 10**400, -(10**400)):
        with pytest.raises(ConfigError, match="timeout"):
            call_timeout(bad)


@pytest.mark.slow  # (seconds of real time)
def test_idle_clients_do_not_lock_others_out(held: Any) -> None:
    _d, path = held
    idle = []
    for _ in range(MAX_CLIENTS):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(path)  # and never a byte
        idle.append(s)
    try:
        t0 = time.monotonic()
        answers: list[dict[str, Any]] = []

        def answered() -> bool:
            answers.append(ask(path, {"op": "find", "board": "thesis"}, 5.0))
            return "error" not in answers[-1]  # (else turned away: busy)

        assert wait_for(answered, 15)  # (30 s once: each idle client held a slot that long)
        assert any("busy" in a.get("error", "") for a in answers)  # turned away meanwhile
        print(f"answered again after {time.monotonic() - t0:.2f} s")
        for s in idle:
            s.settimeout(5)
            assert s.recv(1) == b""  # each idle one was let go
    finally:
        for s in idle:
            s.close()


# ---- the allow-list ----------------------------------------------------------------------------
@pytest.mark.slow
def test_a_control_call_keeps_the_allow_list(held: Any) -> None:
    d, path = held
    servo: list[Update] = []
    d.subscribe("/thesis/servo", servo.append, queue=0)
    b = d.sessions[0].board
    call = {"op": "call", "board": "thesis", "function": "a2j_set_servo", "payload": "28"}
    got = ask(path, call)
    assert got["kind"] == "refused" and "/thesis/servo/cmd" in got["error"], got
    timed = struct.pack("<qB", time.time_ns() + 10**9, b.index["a2j_set_servo"]) + b"\x28"
    got = ask(path, {**call, "function": "a2jAt", "payload": timed.hex()})
    assert got["kind"] == "refused", got  # a2jAt would call it later: the same
    with pytest.raises(CommandRefused, match="/thesis/servo/cmd"):
        d.call("thesis", "a2j_set_servo", b"\x28")
    with pytest.raises(CommandRefused):
        d.send("/thesis/servo/cmd", 40)
    assert ask(path, {**call, "function": "a2jEcho"})["code"] == 0xBA  # moving nothing: fine
    env = {**os.environ, "MISSING_LINK_CONTROL": path}
    cli = ml("call", "thesis", "a2j_set_servo", "--value", "40", timeout=30, env=env)
    assert cli.returncode != 0 and "not in [daemon] commands" in cli.stderr
    assert "Traceback" not in cli.stderr
    time.sleep(0.3)
    assert servo == [] and d.status()[0]["commands"] == 0  # nothing moved
    (control,) = [p for p in d.publisher_status() if p["publisher"] == "control"]
    assert control["commands_refused"] == 4  # control: 3, api: 1 (the bus counts its own)
    assert d.commands.refused["bus"] == 1


def test_status_keys_stay_as_documented(held: Any) -> None:
    """The typed status gives the plain dict the faces read, key for key, in order."""
    d, _path = held
    assert wait_for(lambda: "failsafe_trips" in d.status()[0])
    st = d.status()[0]
    assert list(st)[:10] == ["board", "url", "state", "level", "message", "error", "serial",
                             "connects", "failures", "stale_links"]  # fmt: skip
    assert st["state"] == "up" and type(st["state"]) is str and type(st["level"]) is int
    assert list(st)[10:19] == ["frames", "bad_checksums", "bad_escapes", "cut_frames", "junk_bytes",
                               "lost_sifs", "timeouts", "late_replies", "unheard_sifs"]  # fmt: skip
    assert {"commands", "command_errors", "values_refused", "timed_within_us", "rtt_us", "warnings",
            "clock_epoch", "map_pushes", "configurable", "aligned", "failsafe_trips",
            "failsafe_last_trip_ms", "sync_state", "log_warn", "log_dropped", "log_faults",
            } <= set(st)  # fmt: skip
    assert len(st) == 76  # (a thesis board: with its failsafe; 74 without one)
    snap = d.snapshots()[0]  # the same, typed
    assert (
        list(snap.to_json()) == list(st) and snap.state == SessionState.UP and snap.link.frames > 0
    )
    assert json.loads(json.dumps(st)) == st  # plain JSON
