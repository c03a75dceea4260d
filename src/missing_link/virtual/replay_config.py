"""A recorded board's run-time configuration, served by its replay (virtual/replay.py): the
recorded key table and values with the board's own rules (board/config.py: all or none, limits,
read-only keys), following the changes the recording's host made.  Every configuration record
was checked where the recording was read (recording.py's ``check_config``), so each value here
is one its key takes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..board.config import Key, RuntimeConfig, crc16
from ..board.runtime import BoardRuntime
from ..host.config import ConfigKey, Value, natural, parse_keys
from ..ros.board_record import ConfigRecord
from .recording import RecordedBoard


@dataclass
class Channel:
    """A replayed transducer as configuration and actuator calls see it."""

    name: str
    enabled: bool = True
    driver: Any = None  # (board/config.py asks a key's driver for check_config: none here)


class ReplayConfig(RuntimeConfig):  # type: ignore[misc]
    """The recorded key table and values, served with the board's own rules (board/config.py:
    all or none, limits, read-only keys); no storage, so a save is refused, saying so."""

    def __init__(self, runtime: BoardRuntime, keys: list[Any]) -> None:  # (no super: no drivers)
        self.rt = runtime
        self.store = None
        self.keys = keys
        self.changes = 0
        self.state = 0
        self.schema_crc = crc16(self.keys_blob())
        runtime.add_blob_function("a2jConfigKeys", self.keys_blob)
        runtime.add_function("a2jConfigGet", self._get)
        runtime.add_function("a2jConfigSet", self._set)
        runtime.add_function("a2jConfigReset", self._reset)

    def follow(self, record: ConfigRecord) -> None:
        """Take the values of a recorded configuration (a change the recording's host made)."""
        given = dict(zip(record.names, record.values, strict=True))
        for k in self.keys:
            text = given.get(k.name)
            if text is not None:
                k.put(_value(k.kind, text))


def config_keys(board: RecordedBoard, channels: dict[str, Channel]) -> list[Any]:
    """The board-side keys of the recorded configuration, at their recorded values."""
    rec = board.config
    assert rec is not None
    table = parse_keys(rec.keys.encode(), board.name)
    values = dict(zip(rec.names, rec.values, strict=True))
    out = []
    for ck in table:
        ch = channels.setdefault(ck.transducer, Channel(ck.transducer))
        text = values.get(ck.name)
        out.append(_key(ck, ch, ck.default if text is None else _value(ck.kind, text)))
    return out


def _value(kind: str, text: str) -> Value:
    if kind == "bool":
        return text in ("true", "1")
    if kind == "int":
        return int(float(text))
    if kind == "float":
        return float(text)
    return natural(text)


def _key(ck: ConfigKey, ch: Channel, value: Value) -> Any:
    held = [value]

    def put(v: Any) -> None:
        held[0] = v
        if ck.key == "enabled":
            ch.enabled = bool(v)

    if ck.kind == "enum":
        limits: Any = tuple(natural(c) for c in ck.choices)
    elif ck.kind == "int":
        assert ck.lo is not None and ck.hi is not None
        limits = (int(ck.lo), int(ck.hi))
    else:
        limits = None if ck.kind == "bool" else (ck.lo, ck.hi)
    put(value)
    key = Key(ch, ck.key, ck.kind, limits, ck.read_only, lambda: held[0], put)
    key.default = ck.default
    return key
