"""Board files: one Python dict (``BOARD = {...}``) describing a sensor board - its name, link,
buses and transducers with their drivers - read by the board's firmware (MicroPython imports
it as ``board.py``) and by the host (``flash``, ``gen-firmware``), which parses it as a literal
without running it and checks every entry against the driver it names."""

from __future__ import annotations

import ast
import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..board.drivers import DRIVERS, driver_class
from ..board.dtypes import DTYPES
from ..board.firmware import RESERVED
from ..errors import ConfigError
from ..text import is_token

MCUS = ("rp2040", "esp32", "esp32s3", "atmega328p", "atmega2560", "atmega32u4")
AVR_MCUS = ("atmega328p", "atmega2560", "atmega32u4")


@dataclass(frozen=True)
class BoardFile:
    path: Path
    board: dict[str, Any]

    @property
    def name(self) -> str:
        return str(self.board["name"])

    @property
    def mcu(self) -> str:
        return str(self.board.get("mcu", "rp2040"))

    @property
    def is_avr(self) -> bool:
        return self.mcu in AVR_MCUS

    @property
    def transducers(self) -> list[dict[str, Any]]:
        return list(self.board["transducers"])

    def drivers(self) -> list[str]:
        return sorted({t["driver"] for t in self.transducers})


def load_board_file(path: str | Path) -> BoardFile:
    """Parse and check a board file; every problem is a ConfigError naming the file and entry."""
    p = Path(path)
    where = str(p)
    try:
        tree = ast.parse(p.read_text(encoding="utf-8"), filename=where)
    except OSError as e:
        raise ConfigError(f"{where}: cannot read: {e.strerror or e}") from None
    except SyntaxError as e:
        raise ConfigError(f"{where}:{e.lineno}: not Python: {e.msg}") from None
    value = None
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and len(node.targets) == 1
            and isinstance(node.targets[0], ast.Name)
            and node.targets[0].id == "BOARD"
        ):
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                raise ConfigError(
                    f"{where}:{node.lineno}: BOARD must be a literal (dicts, lists, numbers, "
                    "strings): the host reads it without running it"
                ) from None
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: no `BOARD = {{...}}` dict")
    check_board(value, where)
    return BoardFile(p, value)


def check_board(board: dict[str, Any], where: str) -> None:
    name = board.get("name")
    if not isinstance(name, str) or not is_token(name):
        raise ConfigError(f"{where}: name must be a topic token like 'front' (got {name!r})")
    mcu = board.get("mcu", "rp2040")
    if mcu not in MCUS:
        raise ConfigError(f"{where}: mcu {mcu!r} is not one of {', '.join(MCUS)}")
    link = board.get("link", {"kind": "usb"})
    if not isinstance(link, dict) or link.get("kind", "usb") not in ("usb", "uart", "tcp"):
        raise ConfigError(
            f"{where}: link must be {{'kind': 'usb'}}, {{'kind': 'uart', ...}} or "
            "{'kind': 'tcp', 'port': 5000, 'key_file': 'mlkey.bin'}"
        )
    if link.get("kind") == "tcp" and mcu in AVR_MCUS:
        raise ConfigError(f"{where}: the AVR runtime has no network link (tcp)")
    buses = board.get("buses", {})
    if not isinstance(buses, dict):
        raise ConfigError(f"{where}: buses must be a dict of name -> settings")
    entries = board.get("transducers")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}: transducers must be a non-empty list")
    names: set[str] = set()
    ids: set[int] = set()
    for k, t in enumerate(entries):
        at = f"{where}: transducers[{k}]"
        if not isinstance(t, dict):
            raise ConfigError(f"{at}: must be a dict")
        tname = t.get("name")
        if not isinstance(tname, str) or not is_token(tname):
            raise ConfigError(f"{at}: name must be a topic token (got {tname!r})")
        at = f"{where}: {tname}"
        tid = t.get("id")
        if not isinstance(tid, int) or not 0 <= tid <= 239:
            raise ConfigError(f"{at}: id must be 0..239 (got {tid!r})")
        if tname in names or tid in ids:
            raise ConfigError(f"{at}: name or id used twice")
        names.add(tname)
        ids.add(tid)
        drv = t.get("driver")
        if drv not in DRIVERS:
            raise ConfigError(f"{at}: driver {drv!r} is not one of {', '.join(sorted(DRIVERS))}")
        if "dtype" in t and t["dtype"] not in DTYPES:
            raise ConfigError(f"{at}: dtype {t['dtype']!r} is not a J2A type")
        if "bus" in t and t["bus"] not in buses:
            raise ConfigError(f"{at}: bus {t['bus']!r} is not in buses")
        cls = driver_class(drv)
        params = inspect.signature(cls.__init__).parameters
        accepted = [n for n in params if n not in ("self", "machine", "clock", "i2c")]
        required = [
            n
            for n, prm in params.items()
            if n in accepted and prm.default is inspect.Parameter.empty
        ]
        options = [key for key in t if key not in RESERVED]
        for key in options:
            if key not in accepted:
                raise ConfigError(
                    f"{at}: driver {drv} has no option {key!r} (options: {', '.join(accepted)})"
                )
        for key in required:
            if key not in t:
                raise ConfigError(f"{at}: driver {drv} needs {key!r}")
        if "i2c" in params and "bus" not in t:
            raise ConfigError(f"{at}: driver {drv} is on I2C: give its bus")
