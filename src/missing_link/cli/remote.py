"""A board reached through a running daemon (its control endpoint, daemon/control/endpoint.py)
instead of its own link: ``info``, ``call`` and ``config`` use it when a daemon holds the board, by
board name or URL, so they never fight the daemon for a port."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from ..closing import Closing
from ..daemon.control.endpoint import ask, default_control_path
from ..errors import BadURL, BoardError, ConfigError
from ..host.board import Board
from ..host.link import CallResult

if TYPE_CHECKING:
    from ..descriptors import Transducer


class RemoteBoard(Closing):
    """What the CLI asks of a board, answered by the daemon that holds it."""

    def __init__(self, path: str, board: str, timeout: float) -> None:
        self.path = path
        self.target = board
        self.timeout = timeout
        info = self._ask({"op": "info"})
        self.name: str = info["name"]
        self.url: str = info["url"]
        self.is_original: bool = info["original"]
        self.functions: list[str] = [f["name"] for f in info["functions"]]
        self.properties: dict[str, str] = info["properties"]
        self.configurable: bool = info.get("configurable", False)
        text = info.get("transds_text")
        self.transds_text: str | None = text
        self.transducers: list[Transducer] | None = None
        if text is not None:
            from ..descriptors import parse_transds

            self.transducers = parse_transds(text, self.name)
        self._info = info

    def _ask(self, request: dict[str, Any]) -> dict[str, Any]:
        try:
            answer = ask(self.path, {**request, "board": self.target}, self.timeout + 30)
        except (OSError, ValueError) as e:
            raise BoardError(self.target, f"the daemon at {self.path} did not answer: {e}") from e
        if "error" in answer:
            from ..host.config import ConfigRefused, NotConfigurable

            kind = answer.get("kind")
            text = str(answer["error"])
            if kind == "unconfigurable":
                raise NotConfigurable(self.target, text)
            if kind == "refused":
                raise ConfigRefused(text)
            if kind == "usage":
                raise ConfigError(text)
            raise BoardError(self.target, text)
        return answer

    def describe(self) -> dict[str, Any]:
        return {k: v for k, v in self._info.items() if k != "transds_text"}

    def call(self, name: str, payload: bytes = b"", timeout: float | None = None) -> CallResult:
        got = self._ask(
            {"op": "call", "function": name, "payload": payload.hex(), "timeout": timeout}
        )
        return CallResult(int(got["code"]), bytes.fromhex(got["payload"]))

    def config_request(
        self,
        values: Mapping[str, object] | None = None,
        *,
        save: bool = False,
        reset: bool = False,
        erase: bool = False,
    ) -> dict[str, Any]:
        """{"values", "keys" (value, default, allowed per key), "state"} after the change."""
        return self._ask(
            {"op": "config", "set": dict(values or {}), "save": save, "reset": reset,
             "erase": erase}
        )  # fmt: skip

    def close(self) -> None:
        pass


def reach(target: str, timeout: float, *, describe: bool = True) -> Board | RemoteBoard:
    """The board ``target`` (a URL, or a board name a daemon holds): through the daemon that
    holds it if one does, else on its own link (``describe``: read its transducer descriptors,
    which a call that does not pack a value does without: on a UART they take longest)."""
    path = default_control_path()
    if os.path.exists(path):
        try:
            found = ask(path, {"op": "find", "board": target}, 5.0)
        except (OSError, ValueError):
            found = {"error": "no daemon"}
        if "error" not in found:
            return RemoteBoard(path, target, timeout)
    if "://" not in target:
        raise BadURL(
            f"{target!r} is not a board URL (serial:///dev/ttyACM0, tcp://HOST:PORT, ...), and "
            f"no running daemon holds a board of that name (control endpoint {path})"
        )
    return Board.open(target, timeout=timeout, describe=describe)
