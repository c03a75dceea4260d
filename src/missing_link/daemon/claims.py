"""Names the daemon's boards must agree on: one board per topic name, one layout per type name.
(``create-msgs`` names a package's types with the same claims, so they match.)

* A board name is held by one owner (a session): a second board that calls itself ``robot``
  publishes as ``robot_2``, and the warning says who holds ``robot``.  An owner keeps its name
  while it reconnects and gives it up only for a new one, or with :meth:`Claims.release`.
* A configured name belongs to its configured id (``[boards.arm] id = "real-arm-1"``): a board
  of another id that asks for ``arm`` (its ``board.name``), even first, gets ``arm_2``, said
  once; the configuration and joint routing that follow the name stay with the real arm
  (issue 43.3: a board that dialed in first took the name, and the real arm became ``arm_2``).
* A message type name is held by one definition: a second board whose ``temp`` differs gets
  ``<Board>Temp`` (``BoardBTemp``), so no recording ever holds two layouts under one name.
* A ``board.id`` is stated by one board at a time: two connected boards that state the same id
  (a serial flashed twice, a copied EEPROM) are both kept and shown, each warned with the
  other's URL (:meth:`Claims.id_conflict`), since either may be the one the config means.

Thread-safe; every claim returns ``(granted, warning or None)``.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping

from ..descriptors import Transducer
from ..errors import BoardError
from ..ros.msgs import msg_name, msgdef, type_name
from ..text import slug


def board_token(
    configured: str | None, properties: dict[str, str], url: str
) -> tuple[str, str | None]:
    """The topic token a board publishes under: its configured name, else its ``board.name``
    made a token (``board-a`` -> ``board_a``, with a warning).  ``BoardError`` when it has
    none that can be one."""
    if configured:
        return configured, None  # validated by the config
    raw = properties.get("board.name", "")
    if not raw:
        raise BoardError(
            url, 'the board states no board.name; name it with name = "..." in its [[board]] table'
        )
    token = slug(raw)
    if not token:
        raise BoardError(
            url,
            f"board.name {raw!r} gives no topic name (no ASCII letters or digits); name it "
            'with name = "..." in its [[board]] table',
        )
    if token != raw:
        return token, f"board.name {raw!r} is not a topic token: published as {token!r}"
    return token, None


class Claims:
    def __init__(self, package: str, reserved: Mapping[str, str] | None = None) -> None:
        """``reserved``: configured name -> the board.id it belongs to (``[boards.NAME] id``)."""
        self.package = package
        self.reserved = dict(reserved or {})
        self._lock = threading.Lock()
        self._names: dict[str, tuple[object, str]] = {}  # name -> (owner, owner's URL)
        self._types: dict[str, str] = {}  # message type name -> its definition
        self._ids: dict[object, tuple[str, str]] = {}  # owner -> (board.id, owner's URL)

    def name(
        self, owner: object, wanted: str, url: str, board_id: str | None = None
    ) -> tuple[str, str | None]:
        """The topic name ``owner`` publishes under: ``wanted``, or ``wanted_2``, ... when
        another board holds it (said loudly: two boards must not merge into one set of
        topics), or when it is configured for another board.id than ``board_id`` (the id
        ``owner``'s board states; None: a name the configuration gives its URL, not checked)."""
        with self._lock:
            for held in [n for n, (o, _) in self._names.items() if o is owner]:
                del self._names[held]
            candidate, k = wanted, 1
            while candidate in self._names or self._not_for(candidate, board_id):
                k += 1
                candidate = f"{wanted}_{k}"
            self._names[candidate] = (owner, url)
            holder = self._names[wanted][1] if wanted in self._names else ""
        if candidate == wanted:
            return candidate, None
        if self._not_for(wanted, board_id):
            why = f"belongs to board.id {self.reserved[wanted]!r} ([boards.{wanted}] id)"
        else:
            why = f"is taken by {holder}"
        return candidate, f"board name {wanted!r} {why}: published as {candidate!r}"

    def _not_for(self, name: str, board_id: str | None) -> bool:
        """``name`` is configured for another id than ``board_id``."""
        mine = self.reserved.get(name)
        return board_id is not None and mine is not None and mine != board_id

    def release(self, owner: object) -> None:
        """``owner`` is gone (its board was removed): its name is free again."""
        with self._lock:
            for held in [n for n, (o, _) in self._names.items() if o is owner]:
                del self._names[held]
            self._ids.pop(owner, None)

    def claim_id(self, owner: object, board_id: str, url: str) -> str | None:
        """``owner``'s board states ``board_id`` (while it is connected); a warning when another
        connected board states it too."""
        with self._lock:
            if board_id:
                self._ids[owner] = (board_id, url)
            else:
                self._ids.pop(owner, None)
        return self.id_conflict(owner)

    def release_id(self, owner: object) -> None:
        """``owner``'s board is gone: it states no id now."""
        with self._lock:
            self._ids.pop(owner, None)

    def id_conflict(self, owner: object) -> str | None:
        """A warning when another connected board states ``owner``'s board.id, else None."""
        with self._lock:
            mine = self._ids.get(owner)
            others = [
                u for o, (i, u) in self._ids.items() if mine and i == mine[0] and o is not owner
            ]
        if mine is None or not others:
            return None
        return (
            f"board.id {mine[0]!r} is stated by another connected board too "
            f"({', '.join(others)}): both are shown; an id is meant to be one board's"
        )

    def hold(self, type_name: str, definition: str) -> None:
        """``type_name`` is taken by ``definition`` already (a package built earlier)."""
        with self._lock:
            self._types.setdefault(type_name, definition)

    def type(self, board: str, t: Transducer) -> tuple[str, str | None]:
        """The message type for ``t``: its plain name unless another definition holds that,
        then qualified by the board (``BoardBTemp``): one name, one layout, everywhere."""
        definition = msgdef(t, 2)
        plain = type_name(t, self.package)
        with self._lock:
            held = self._types.setdefault(plain, definition)
            if held == definition:
                return plain, None
            base = f"{self.package}/msg/{msg_name(board)}{msg_name(t)}"
            candidate, k = base, 1
            while self._types.setdefault(candidate, definition) != definition:
                k += 1
                candidate = f"{base}{k}"
        return candidate, (
            f"{t.name}: type {plain} is already defined differently by another board: "
            f"published as {candidate}"
        )
