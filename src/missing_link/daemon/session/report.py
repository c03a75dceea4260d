"""What a board session reports: its diagnostic level and message, its status (typed, and as
the plain dict of ``Daemon.status()`` and ``/diagnostics``), counters cumulative over every
link.  :class:`~missing_link.daemon.session.session.BoardSession` is a ``SessionReport``; what
the report reads of it is named below."""

from __future__ import annotations

from typing import Any

from ...host.board import Board
from ...host.results import LinkStats
from ...logs import ErrorCounts
from ..config import BoardSpec
from .actuators import Actuators
from .alignment import aligned
from .clock import SessionClock
from .context import SessionContext
from .reads import BoardReads
from .run_config import RunConfig
from .sample_path import SamplePath
from .status import Identity, Level, SessionState, SessionStatus, session_level


class SessionReport:
    name: str
    spec: BoardSpec
    ctx: SessionContext
    state: SessionState
    error: str
    warnings: list[str]
    board: Board | None
    identity: Identity
    epoch: str
    connects: int
    failures: int
    stale_links: int
    past_links: LinkStats
    rtt_us: float | None
    faults: ErrorCounts
    path: SamplePath
    actuators: Actuators
    clock: SessionClock
    run_config: RunConfig
    reads: BoardReads
    update_status: dict[str, Any] | None

    def level(self) -> tuple[Level, str]:
        """Diagnostic level and message: ERROR when not up, WARN when up with warnings."""
        return session_level(self.state, self.error, self._warnings_now(), self.faults.total)

    def _warnings_now(self) -> list[str]:
        """The warnings, and while it lasts, another connected board with this board's id."""
        twice = self.ctx.claims.id_conflict(self)
        return [*self.warnings, twice] if twice else self.warnings

    def snapshot(self) -> SessionStatus:
        """The session's status now, typed; counters are cumulative over every connection."""
        b = self.board
        level, message = self.level()
        sync = self.clock.sync
        return SessionStatus(
            board=self.name,
            url=self.spec.url,
            state=self.state,
            level=level,
            message=message,
            error=self.error,
            serial=b.properties.get("board.serial", "") if b else "",
            connects=self.connects,
            failures=self.failures,
            stale_links=self.stale_links,
            link=self.past_links + b.link_stats() if b is not None else self.past_links,
            samples=self.path.counters(),
            commands=self.actuators.commands,
            command_errors=self.actuators.command_errors,
            values_refused=self.actuators.values_refused,
            timed_within_ns=self.actuators.timed_within_ns,
            errors=self.faults.to_json(),
            rtt_us=round(self.rtt_us) if self.rtt_us is not None else None,
            warnings="; ".join(self._warnings_now()),
            clock_epoch=self.epoch,
            map_pushes=self.clock.map_pushes,
            config=self.run_config.status(),
            aligned=aligned(self.path.grid, self.path.topics),
            align_info=self.reads.alignment.status,
            failsafe=self.reads.failsafe.status,
            memory=self.reads.memory.status,
            sync=sync.status() if sync is not None else None,
            identity=self.identity,
            update=self.update_status,
        )

    def status(self) -> dict[str, Any]:
        """``snapshot()`` as the plain dict of ``Daemon.status()`` and ``/diagnostics``."""
        return self.snapshot().to_json()
