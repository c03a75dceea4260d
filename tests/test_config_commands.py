"""An actuator's run-time configuration is a command (docs/security.md): a servo re-clamps the
pulse it holds to new limits, ``failsafe_ms = 0`` turns its failsafe off.  A set, reset or save
that would change an actuator's keys needs the face's ``commands`` and the allow-list, on every
face: ``Daemon.configure`` ("api"), the control endpoint, the web console, and any face the
daemon offers the keys to (ROS 2 parameters: fanout.py hands each face its own ``apply``)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import websockets

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.control.allowlist import CommandRefused
from missing_link.daemon.control.endpoint import ask
from missing_link.host.config import Value, actuators_changed, parse_keys
from missing_link.publishers.base import Publisher
from missing_link.publishers.web import WebPublisher
from missing_link.topics import Update
from missing_link.virtual import make_sim

KEYS = parse_keys(
    b"config/1\nquad.enabled;bool;1;;\nservo.enabled;bool;1;;\n"
    b"servo.failsafe_ms;int;500;0..60000;\nservo.min_deg;float;-90;-90..90;\n"
    b"servo.safe;enum;hold;hold|limp|centre;\nservo.model;int;3;0..9;ro\n",
    "b",
)
NOW: dict[str, Value] = {
    "quad.enabled": True, "servo.enabled": True, "servo.failsafe_ms": 500,
    "servo.min_deg": -90.0, "servo.safe": "hold", "servo.model": 3,
}  # fmt: skip


def test_which_actuators_a_change_changes() -> None:
    servo = {"servo"}
    assert actuators_changed(KEYS, servo, NOW, {"quad.enabled": "off"}) == []
    assert actuators_changed(KEYS, servo, NOW, {"servo.failsafe_ms": "0"}) == ["servo"]
    assert actuators_changed(KEYS, servo, NOW, {"servo.min_deg": -89.9}) == ["servo"]
    # the values it has already (as the board keeps them: a float32) change nothing
    assert actuators_changed(KEYS, servo, NOW, {"servo.min_deg": "-90", "servo.safe": "hold",
                                                "servo.enabled": 1}) == []  # fmt: skip
    assert actuators_changed(KEYS, set(), NOW, {"servo.failsafe_ms": 0}) == []  # not an actuator
    # a reset changes what differs from the defaults; a save, what the board boots with
    assert actuators_changed(KEYS, servo, NOW, None) == []
    moved = {**NOW, "servo.failsafe_ms": 0}
    assert actuators_changed(KEYS, servo, moved, None) == ["servo"]
    assert actuators_changed(KEYS, servo, moved, {"quad.enabled": 0}) == []
    assert actuators_changed(KEYS, servo, moved, {"quad.enabled": 0}, save=True) == ["servo"]
    assert actuators_changed(KEYS, servo, NOW, {"quad.enabled": 0}, save=True) == []


class ParamFace(Publisher):
    """A face that offers the keys as ROS 2 parameters do (``add_config``'s ``apply``)."""

    name = "params"

    def __init__(self, takes_commands: bool) -> None:
        self.takes_commands = takes_commands
        self.apply: dict[str, Callable[[dict[str, object]], dict[str, Value]]] = {}

    def publish(self, update: Update) -> None:
        pass

    def add_config(self, board: str, keys: Any, values: Any, apply: Any) -> None:
        self.apply[board] = apply


@contextmanager
def rig(
    serve: Any, tmp_path: Path, allowed: list[str], storage: bool = False
) -> Iterator[tuple[Daemon, Any, Any]]:
    """encoder_servo under a daemon with the allow-list ``allowed``, the web console and a
    parameter face with commands off, and the control endpoint (``storage``: the board keeps
    a saved configuration, in a file of ``tmp_path``)."""
    kw = {"config_file": str(tmp_path / "board.cfg")} if storage else {}
    b = serve(make_sim("encoder_servo", seed=1, **kw))
    cfg = Config(
        boards=[BoardSpec(b.url, name="rig")],
        publishers=["bus", "web"],
        publisher_options={"web": {"port": 0, "commands": False}},
        commands=allowed,
        control=str(tmp_path / "control.sock"),
    )
    params = ParamFace(takes_commands=False)
    with Daemon(cfg, extra_publishers=[params]) as d:
        web = next(p for p in d.publishers if isinstance(p, WebPublisher))
        assert web.server.attached  # (the daemon started it with its verbs)
        assert d.wait_until_up(10)
        yield d, web, params


def _web(face: WebPublisher, op: dict[str, Any]) -> dict[str, Any]:
    async def go() -> dict[str, Any]:
        url = face.url.replace("http", "ws") + "ws"
        async with websockets.connect(
            url, additional_headers={"Origin": face.url.rstrip("/")}
        ) as ws:
            await asyncio.wait_for(ws.recv(), 10)  # (hello)
            await ws.send(json.dumps({"id": 1, "board": "rig", **op}))
            while (m := json.loads(await asyncio.wait_for(ws.recv(), 10)))["op"] != "reply":
                pass
            return m

    return asyncio.run(go())


def _refused(d: Daemon) -> dict[str, int]:
    return dict(d.commands.refused)


def test_no_face_changes_an_actuator_under_an_empty_allow_list(serve: Any, tmp_path: Path) -> None:
    with rig(serve, tmp_path, []) as (d, web, params):
        before = d.board_config("rig")
        with pytest.raises(CommandRefused, match=r"servo are commands.*/rig/servo/cmd"):
            d.configure("rig", {"servo.failsafe_ms": 0})
        with pytest.raises(CommandRefused):
            d.configure("rig", {"servo.min_deg": -80, "quad.enabled": False})  # (all or none)
        got = ask(str(tmp_path / "control.sock"),
                  {"op": "config", "board": "rig", "set": {"servo.max_deg": 80}})  # fmt: skip
        assert got["kind"] == "refused" and "servo are commands" in got["error"], got
        reply = _web(web, {"op": "config", "set": {"servo.failsafe_ms": "0"}})
        assert reply["ok"] is False and "commands are off on web" in reply["text"], reply
        with pytest.raises(CommandRefused, match="commands are off on params"):
            params.apply["rig"]({"servo.safe": "limp"})
        assert d.board_config("rig") == before  # nothing reached the board
        assert _refused(d) == {"api": 2, "control": 1, "web": 1, "params": 1}
        rows = {r["publisher"]: r for r in d.publisher_status()}
        assert rows["web"]["commands_refused"] == 1 and rows["params"]["commands_refused"] == 1
        # what is not an actuator's, or changes nothing, is no command
        assert (
            d.configure("rig", {"quad.enabled": False, "servo.min_deg": -90})["quad.enabled"]
            is False
        )
        assert _web(web, {"op": "config", "set": {"quad.enabled": True}})["ok"] is True
        assert params.apply["rig"]({"quad.enabled": False})["quad.enabled"] is False


def test_a_face_without_commands_may_not_change_what_one_with_them_set(
    serve: Any, tmp_path: Path
) -> None:
    with rig(serve, tmp_path, ["/rig/servo/cmd"]) as (d, web, params):
        d.configure("rig", {"servo.failsafe_ms": 250})  # the API and the control endpoint may
        got = ask(str(tmp_path / "control.sock"),
                  {"op": "config", "board": "rig", "set": {"servo.max_deg": 80}})  # fmt: skip
        assert got["values"]["servo.max_deg"] == 80, got
        # a reset back to the defaults, or a save of what they set, is a change of the servo
        assert _web(web, {"op": "reset"})["ok"] is False
        assert (
            _web(web, {"op": "config", "set": {"quad.enabled": False}, "save": True})["ok"] is False
        )
        with pytest.raises(CommandRefused):
            params.apply["rig"]({"servo.failsafe_ms": 250, "servo.enabled": False})
        assert d.board_config("rig")["servo.failsafe_ms"] == 250
        assert _refused(d) == {"web": 2, "params": 1}
        d.reset_config("rig")  # (the API: allowed)
        assert d.board_config("rig")["servo.failsafe_ms"] == 500
        assert _web(web, {"op": "reset"})["ok"] is True  # (nothing of the servo changes now)


def test_what_a_viewer_cannot_set_it_cannot_erase(serve: Any, tmp_path: Path) -> None:
    """(issue 43.11: a web console with commands off, under a list that admitted only the API's
    change, reset with erase and so wiped the servo's saved configuration: its guard compared
    the values now with the defaults and never saw ``erase_saved``)"""
    with rig(serve, tmp_path, ["/rig/servo/cmd"], storage=True) as (d, web, _params):
        d.configure("rig", {"servo.failsafe_ms": 250}, save=True)  # the operator's, kept
        d.reset_config("rig")  # back to the defaults now; the saved record still holds 250
        sock = str(tmp_path / "control.sock")
        saved = ask(sock, {"op": "config", "board": "rig"})["state"]
        assert saved & 1, saved  # (ST_SAVED)
        reply = _web(web, {"op": "reset", "erase": True})
        assert reply["ok"] is False and "servo are commands" in reply["text"], reply
        assert ask(sock, {"op": "config", "board": "rig"})["state"] == saved  # kept
        assert _refused(d) == {"web": 1}
        assert actuators_changed(KEYS, {"servo"}, NOW, None, erase=True) == ["servo"]
        d.reset_config("rig", erase_saved=True)  # (the API, which the list admits: erased)
        assert not ask(sock, {"op": "config", "board": "rig"})["state"] & 1
