"""Every board of a recording, played back at once (``missing-link replay``): one
:class:`~missing_link.virtual.replay.ReplayRuntime` per board, each behind its own listener
(``BoardServer``) on a thread of its own, all on one timeline (so the boards keep their
recorded timing against each other), with a feeder thread each reading its samples ahead."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from ..errors import BadURL
from .recording import RecordedBoard, RecordingError, open_recording
from .replay import NOBODY, Feeder, ReplayRuntime
from .replay_clock import Clock, Timeline
from .server import BoardServer


class _Server(BoardServer):
    """A board server that tells its replayed board whether a host is there and how much
    output waits for it, so that samples wait rather than be shed or sent to nobody: a replay
    keeps every sample it can."""

    runtime: ReplayRuntime

    def _turn(self, data: bytes, rx_us: int | None = None) -> tuple[bytes, list[bytes]]:
        link, rt = self._link, self.runtime
        if self.connections != rt.hosts:
            rt.new_host(self.connections)
        if link is None and self._listener is not None:
            rt.backlog = NOBODY  # (a socket listener without its host: wait for the next)
        else:
            rt.backlog = link.queued if link is not None else 0
        return super()._turn(data, rx_us)


@dataclass
class ReplayedBoard:
    recorded: RecordedBoard
    runtime: ReplayRuntime
    server: BoardServer
    feeder: Feeder
    error: str = ""  #: why its server ended, if it ended by itself
    thread: threading.Thread = field(init=False)

    def __post_init__(self) -> None:
        self.thread = threading.Thread(target=self.serve, name=f"replay:{self.name}", daemon=True)

    def serve(self) -> None:
        """The board's server until stopped; what ends it otherwise is kept (``error``)."""
        try:
            self.server.serve_forever()
        except Exception as e:  # noqa: BLE001 - said by the replay, which then fails
            self.error = f"{self.name} stopped serving: {type(e).__name__}: {e}"
        else:
            if not self.server.stopping:
                self.error = f"{self.name} stopped serving"

    @property
    def name(self) -> str:
        return self.recorded.name

    def summary(self) -> str:
        rt, st = self.runtime, self.feeder.stats
        cmds = sum(rt.commands.values())
        detail = ", ".join(f"{k} {v}" for k, v in sorted(rt.commands.items()))
        extra = [f"{n} {what}" for n, what in (
            (rt.late, "late"), (rt.withheld, "withheld (disabled)"),
            (st.unstamped, "without board stamps (not replayed)"),
            (st.unmatched, "stamps without their sample"), (st.damaged, "damaged records"),
            (rt.bad, "that could not be played (skipped)"),
        ) if n]  # fmt: skip
        return (
            f"{self.name}: {rt.sent} SIFs sent in {rt.passes + int(rt.finished)} pass(es)"
            + (f" ({', '.join(extra)})" if extra else "")
            + f", {cmds} command(s) taken{f' ({detail})' if detail else ''}"
            + f", {rt.exchanges} clock exchanges answered"
        )


class Replay:
    def __init__(
        self,
        paths: list[str],
        *,
        rate: float = 1.0,
        loop: bool = False,
        listen: str = "pty",
        boards: list[str] | None = None,
        lead_s: float = 1.0,
    ) -> None:
        """Read the recording and bind every board's listener; ``start()`` serves them.
        RecordingError (and OSError from a listener) when that cannot be done."""
        self.listen = listen
        self.recording = rec = open_recording(paths)
        chosen = boards or list(rec.boards)
        unknown = [b for b in chosen if b not in rec.boards]
        if unknown:
            raise RecordingError(
                f"no board {', '.join(unknown)} in the recording (it has {', '.join(rec.boards)})"
            )
        picked = [rec.boards[b] for b in dict.fromkeys(chosen)]
        if len(picked) > 1 and listen.startswith("tcp://") and not listen.endswith(":0"):
            raise BadURL(f"{len(picked)} boards need --listen tcp://HOST:0 (a port each)")
        spans = [(b.first_ns, b.last_ns) for b in picked if b.first_ns is not None]
        if not spans or not any(b.samples for b in picked):
            raise RecordingError(f"{rec.files[0]}: no samples with board stamps to replay")
        first, end = min(a for a, _ in spans), max(e for _, e in spans)
        self.span_s = (end - first) / 1e9
        self.timeline = Timeline(first, end, rate, lead_s, loop, time.monotonic_ns())
        self.boards: list[ReplayedBoard] = []
        try:
            for b in picked:
                self.boards.append(self._board(b, first, len(picked)))
        except BaseException:
            self.stop()
            raise

    def _board(self, b: RecordedBoard, first: int, boards: int) -> ReplayedBoard:
        epoch = dict(b.description.properties).get("clock.epoch", "")
        model = b.clock.model(b.anchor or (first, 0), epoch)
        feeder = Feeder(self.recording, b.name, self.timeline.loop, boards)
        runtime = ReplayRuntime(b, Clock(model, self.timeline), feeder)
        return ReplayedBoard(b, runtime, _Server(runtime, self.listen), feeder)

    def start(self) -> Replay:
        for b in self.boards:
            b.feeder.thread.start()
        for b in self.boards:
            b.thread.start()
        return self

    @property
    def finished(self) -> bool:
        """Every board has sent its last SIF (never, with ``loop``)."""
        return all(b.runtime.finished for b in self.boards)

    def errors(self) -> list[str]:
        """What went wrong, said once each: a feed that broke, a record that could not be
        played, a board that stopped serving (the replay then ends, and fails)."""
        out = [b.feeder.error for b in self.boards if b.feeder.error]
        out += [f"{b.name}: {b.runtime.said}" for b in self.boards if b.runtime.said]
        return out + [b.error for b in self.boards if b.error]

    def stopped_serving(self) -> bool:
        """A board's server ended by itself (the replay cannot go on as recorded)."""
        return any(b.error for b in self.boards)

    def position_s(self) -> float:
        """Seconds of the recording played in this pass (0 before the hosts came)."""
        if not self.timeline.started:
            return 0.0
        _k, h = self.timeline.at(time.monotonic_ns())
        return min(max(0.0, (h - self.timeline.first) / 1e9), self.span_s)

    def stop(self, timeout: float = 2.0) -> None:
        for b in self.boards:
            b.server.stop()
            b.feeder.stop()
        for b in self.boards:
            if b.thread.is_alive():
                b.thread.join(timeout)
