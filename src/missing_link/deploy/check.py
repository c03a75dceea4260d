"""After flashing: does the board answer J2A as its board file says (name and transducers)?"""

from __future__ import annotations

import time

from ..errors import MissingLinkError
from ..host.board import Board
from .boardfile import BoardFile


class FlashError(MissingLinkError):
    """Copying, building or verifying the firmware failed."""


def verify(
    url: str, bf: BoardFile, timeout: float = 15.0, expect: dict[str, str] | None = None
) -> str:
    """Open the board as J2A (waiting for it to come back after the reset) and compare name and
    transducers with the board file, and properties with ``expect`` (``fw.hash``: what was
    flashed).  Returns a one-line summary; raises FlashError."""
    deadline = time.monotonic() + timeout
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            board = Board.open(url, timeout=2.0)
        except MissingLinkError as e:
            last = e
            time.sleep(0.5)
            continue
        try:
            board.handshake()
            name = board.properties.get("board.name")
            got = {(t.name, t.id) for t in board.transducers or []}
            want = {(t["name"], t["id"]) for t in bf.transducers}
            if name != bf.name or got != want:
                raise FlashError(
                    f"{url}: the board answers as {name!r} with {sorted(got)}, "
                    f"the board file says {bf.name!r} with {sorted(want)}"
                )
            for key, value in (expect or {}).items():
                if board.properties.get(key) != value:
                    raise FlashError(
                        f"{url}: the board says {key} {board.properties.get(key)!r}, "
                        f"{value!r} was flashed"
                    )
            ident = "".join(f", {k} {v}" for k, v in (expect or {}).items())
            return (
                f"{url}: {name} answers J2A with {len(got)} transducers as the board file says "
                f"(board.id {board.properties.get('board.id', '(none)')}{ident})"
            )
        except FlashError:
            raise
        except MissingLinkError as e:
            last = e
            time.sleep(0.5)
        finally:
            board.close()
    raise FlashError(f"{url}: no J2A answer within {timeout:g} s after flashing: {last}")
