"""The daemon's health besides its boards: one row per publisher, the control endpoint, the
listener for boards that dial in, the daemon's own threads and the log (``Daemon.
publisher_status``, ``/diagnostics``, the run summary).  A row that cannot be made is itself a
row (ERROR, counted), never an exception that hides the others."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from ..logs import ErrorCounts
from ..logs import counts as log_counts
from ..publishers.base import Publisher
from .control.allowlist import CommandGate
from .control.endpoint import ControlServer


def publisher_rows(
    publishers: Iterable[Publisher],
    commands: CommandGate,
    control: ControlServer | None,
    own: list[tuple[str, ErrorCounts]],
    extra: list[dict[str, Any]],
) -> list[dict[str, Any]]:
    """Per publisher: level, error, dropped and what it has to say; the control endpoint's row
    (commands refused on no face are shown too); ``extra`` rows (the listener); each of the
    daemon's own threads (``own``) once it caught something; the log's held-back lines."""
    out = []
    for p in publishers:
        try:
            st = p.status()
            if p.takes_commands is not None:
                st["commands_refused"] = commands.refused.get(p.name, 0)
            if "errors" not in st:  # (a publisher of an application's, not on the base's)
                st.update(p.faults.to_json())
            out.append(st)
        except Exception as e:  # noqa: BLE001 - a broken status must not hide the others:
            p.faults.caught("status", e)  # shown as ERROR, counted, its traceback said once
            out.append({"publisher": p.name, "level": 2, "message": f"status failed: {e}",
                        **p.faults.to_json()})  # fmt: skip
    paths = {k: v for k, v in commands.refused.items() if k in ("api", "control")}
    if control is not None or paths:  # commands refused on no face: still shown
        got = control.status() if control is not None else {}
        bugs = got.get("errors", 0)
        out.append({"publisher": "control", "level": 1 if bugs else 0,
                    "message": "errors caught" if bugs else "ok", **got,
                    "commands_refused": sum(paths.values())})  # fmt: skip
    out.extend(extra)
    for part, faults in own:
        if faults.total:  # (the daemon's own threads: shown once they caught something)
            out.append({"publisher": part, "level": 1, "message": "errors caught",
                        **faults.to_json()})  # fmt: skip
    held = log_counts()
    if held["lines_held_back"] or held["tracebacks_folded"]:
        out.append({"publisher": "log", "level": 0, "message": "ok", **held})
    return out
