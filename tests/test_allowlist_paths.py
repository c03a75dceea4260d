"""``[daemon] commands`` holds on every path that changes what an actuator does or lets go of a
board (issue 43.7), through the control endpoint as ``missing-link call``, ``update`` and the
AVR update's ``release`` send them: a plain call of ``a2jConfigSet`` or ``a2jConfigReset`` (also
wrapped in an ``a2jMany``), an ``update`` and a ``release`` pass only where the list admits
every actuator of the board.  Before, ``call thesis a2jConfigSet`` set ``servo.failsafe_ms = 0``
and ``release`` let go of the port under a list that admitted nothing."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.control.allowlist import called_function
from missing_link.daemon.control.endpoint import ask
from missing_link.j2a.blobs import many_request
from missing_link.virtual import make_sim

Serve = Callable[..., Any]


@contextmanager
def held(serve: Serve, tmp_path: Path, allowed: list[str]) -> Iterator[tuple[Daemon, str]]:
    board = serve(make_sim("thesis", seed=5, config_file=str(tmp_path / "board.cfg")))
    path = str(tmp_path / "c.sock")
    with Daemon(Config(boards=[BoardSpec(board.url)], control=path, commands=allowed)) as d:
        assert d.wait_until_up(10)
        yield d, path


def _calls(d: Daemon) -> dict[str, dict[str, Any]]:
    """The raw requests: a set of the servo's failsafe_ms to 0, a reset that erases, the same
    set inside an a2jMany."""
    b = d.session("thesis").board
    assert b is not None
    table = b.settings.keys()  # (a method: the board's key table)
    key = next(k for k in table if k.name == "servo.failsafe_ms")
    put = bytes((0, key.index)) + key.to_wire(0)
    many = many_request(b.index["a2jConfigSet"], 0, 0, put)
    return {
        "set": {"function": "a2jConfigSet", "payload": put.hex()},
        "reset": {"function": "a2jConfigReset", "payload": "01"},
        "many": {"function": "a2jMany", "payload": many.hex()},
    }


def call(path: str, req: dict[str, Any]) -> dict[str, Any]:
    return ask(path, {"op": "call", "board": "thesis", **req}, 10.0)


def test_nothing_that_changes_the_servo_passes_a_list_without_it(
    serve: Serve, tmp_path: Path
) -> None:
    with held(serve, tmp_path, ["/nothing"]) as (d, path):
        for what, req in _calls(d).items():
            got = call(path, req)
            assert got.get("kind") == "refused", (what, got)
            assert "/thesis/servo/cmd" in got["error"], got
        got = ask(path, {"op": "release", "board": "thesis", "seconds": 5})
        assert got.get("kind") == "refused" and "release of its port" in got["error"], got
        got = ask(path, {"op": "update", "board": "thesis", "image": str(tmp_path / "x.mlfw")})
        assert got.get("kind") == "refused" and "firmware update" in got["error"], got
        assert d.board_config("thesis")["servo.failsafe_ms"] == 500  # nothing reached it
        assert d.status()[0]["state"] == "up" and d.status()[0]["connects"] == 1  # held
        (control,) = [p for p in d.publisher_status() if p["publisher"] == "control"]
        assert control["commands_refused"] == 5
        # a call of nothing that moves or reconfigures is no command
        assert call(path, {"function": "a2jEcho", "payload": "01"})["code"] == 0xBA


def test_a_list_that_admits_the_servo_lets_the_same_through(serve: Serve, tmp_path: Path) -> None:
    with held(serve, tmp_path, ["/thesis/servo/cmd"]) as (d, path):
        got = call(path, _calls(d)["set"])
        assert got["code"] == 0, got
        assert d.board_config("thesis")["servo.failsafe_ms"] == 0
        got = ask(path, {"op": "release", "board": "thesis", "seconds": 5})
        assert got.get("seconds") == 5, got
        assert ask(path, {"op": "retake", "board": "thesis"})["state"]


def test_the_function_a_call_ends_up_running() -> None:
    fns = ["a2jGetMapping", "a2jMany", "a2jAt", "a2jConfigSet", "servo"]
    at = (1).to_bytes(8, "little")
    assert called_function("a2jMany", bytes((3, 0)), fns) == "a2jConfigSet"
    assert called_function("a2jAt", at + bytes((4, 7)), fns) == "servo"
    assert called_function("a2jAt", at + bytes((2,)) + at + bytes((4, 7)), fns) == "servo"
    assert called_function("a2jMany", bytes((9,)), fns) == "a2jMany"  # (no such target)
    assert called_function("a2jEcho", b"\x03", fns) == "a2jEcho"
