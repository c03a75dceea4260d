"""Names in the configuration that match nothing once the boards are up: a typo says so once,
with the nearest name that is there ("did you mean"), instead of a joint that never appears.

Theory of operation
-------------------
The configuration names boards and transducers in several places: ``[boards.<board>.ros.
<transducer>]`` (host-side keys of the standard types), ``[boards.<board>.config]`` (its
run-time keys: their names the session checks against the board's own table when it connects,
with "did you mean" too), ``[joints.<joint>]`` ``state`` and ``command``
(``"<board>/<transducer>[/<channel>]"``) and ``[remap]`` (``"/<board>/<transducer>"``).  None of
them can be checked when the file is read: the boards say what they are only when they connect.
So the daemon hands ``check`` the boards that are up (each with its transducers' names) every
diagnostics round:

* a reference to a transducer of a board that is up, which that board does not have, is said at
  once (the board told us everything it has);
* a reference to a board that is not up is said only when every board there will be is up
  (``all_up``: the daemon's boards all up, none being discovered): a board that is merely late
  is not a typo, and one that never comes is (a joint naming it would never appear).

Each reference is said once (a line on the daemon's log, naming the file's table and key), with
the nearest name of what is there; nothing is refused: the rest of the configuration runs.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from ..text import did_you_mean
from .config import Config

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Ref:
    """One place the configuration names a board (and a transducer of it)."""

    where: str  #: the table and key, as the user wrote it
    board: str
    transducer: str | None = None


def references(cfg: Config) -> list[Ref]:
    """Every board and transducer name the configuration uses, where it uses it."""
    out: list[Ref] = []
    for board, table in cfg.ros.items():
        out += [Ref(f"[boards.{board}.ros.{t}]", board, t) for t in table]
    for board, values in cfg.board_config.items():  # (its keys: the session checks them)
        if values:
            out.append(Ref(f"[boards.{board}.config]", board))
    if cfg.joints is not None:
        for j in cfg.joints.joints:
            for key, ref in (("state", j.state), ("command", j.command)):
                if ref is not None:
                    board, transducer = ref.split("/")[:2]
                    out.append(Ref(f"[joints.{j.name}] {key} = {ref!r}", board, transducer))
    for old in cfg.remap:
        parts = old.strip("/").split("/")
        if len(parts) == 2:  # (a transducer's topic; a longer one is not a board's own)
            out.append(Ref(f"[remap] {old!r}", parts[0], parts[1]))
    return out


class NameCheck:
    def __init__(self, cfg: Config) -> None:
        self.refs = references(cfg)
        self._said: set[Ref] = set()

    def check(self, up: Mapping[str, Iterable[str]], all_up: bool) -> list[str]:
        """``up``: board name -> its transducers' names, for the boards up now; ``all_up``:
        every board there will be is up.  Says (and returns) what matches nothing, each once."""
        lines = []
        for ref in self.refs:
            if ref in self._said:
                continue
            line = self._unmatched(ref, up, all_up)
            if line is not None:
                self._said.add(ref)
                lines.append(line)
                log.warning("%s", line)
        return lines

    @staticmethod
    def _unmatched(ref: Ref, up: Mapping[str, Iterable[str]], all_up: bool) -> str | None:
        if ref.board in up:
            names = list(up[ref.board])
            if ref.transducer is None or ref.transducer in names:
                return None
            return (
                f"{ref.where}: board {ref.board} has no transducer {ref.transducer!r}"
                f"{did_you_mean(ref.transducer, names)} (it has {', '.join(sorted(names))})"
            )
        if not all_up:
            return None  # (it may be late: said once every board is up)
        boards = ", ".join(sorted(up)) or "none"
        return (
            f"{ref.where}: no board {ref.board!r} is up{did_you_mean(ref.board, up)} "
            f"(every board is up: {boards})"
        )
