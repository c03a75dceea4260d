"""``with thing:`` closes ``thing`` at the end, however the block ends: the context-manager
protocol written once for what holds a link, a socket or a process (a Transport, a Board, a
runtime board of the testing kit, a board reached through the daemon)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Self


class Closing(ABC):
    """``with x:`` is ``x``, and ``x.close()`` at the block's end."""

    @abstractmethod
    def close(self) -> None:
        """Let go of what it holds."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
