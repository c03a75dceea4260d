"""Benchmarks cannot silently do nothing: every name a bench imports exists, a patch whose
target is gone or unused stops the bench, and the clock-sync recorder really probes at the
50 Hz it claims (its patch once landed on a name the daemon no longer read, for weeks)."""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from itertools import pairwise
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench"
sys.path.insert(0, str(BENCH))

from _patch import PatchMissed, patched, replace  # noqa: E402


def _ours(module: str) -> bool:
    """missing_link's modules and the benches' own (others: other environments, e.g. rclpy,
    and the board's side under MicroPython)."""
    return module.split(".")[0] == "missing_link" or (BENCH / f"{module}.py").exists()


def _top_level_names(path: Path) -> set[str]:
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
    return names


def _check_from(module: str, names: list[str]) -> list[str]:
    """What of ``from module import names`` does not exist ([] when all do)."""
    local = BENCH / f"{module}.py"
    if local.exists():  # a bench module: read, not run (some run their measurement on import)
        return [f"{module}.{n}" for n in names if n not in _top_level_names(local)]
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        return [f"{module} ({e})"]
    missing = []
    for n in names:
        if hasattr(mod, n):
            continue
        try:
            importlib.import_module(f"{module}.{n}")
        except ImportError:
            missing.append(f"{module}.{n}")
    return missing


def test_every_name_a_bench_imports_exists() -> None:
    """Module level and inside functions (a lazy import breaks only when that part runs)."""
    missing = []
    for path in sorted(BENCH.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                if _ours(node.module):
                    got = _check_from(node.module, [a.name for a in node.names])
                    missing += [f"{path.name}: {m}" for m in got]
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("missing_link"):
                        try:
                            importlib.import_module(a.name)
                        except ImportError as e:
                            missing.append(f"{path.name}: {a.name} ({e})")
    assert not missing, missing


def test_a_patch_that_lands_nowhere_stops_the_bench() -> None:
    import missing_link.daemon.session.session as session

    # the recorder's old target: SyncOptions left the session for session_clock.py
    with (
        pytest.raises(PatchMissed, match=r"session\.SyncOptions is gone"),
        patched(session, "SyncOptions", lambda **kw: None),
    ):
        pass
    owner = SimpleNamespace(f=lambda: 1, state=0)
    with (
        pytest.raises(PatchMissed, match="patched and never called"),
        patched(owner, "f", lambda: 2),
    ):
        pass  # (the code under test took its value from somewhere else)
    with patched(owner, "f", lambda: 2):
        assert owner.f() == 2
    assert owner.f() == 1  # put back
    with pytest.raises(PatchMissed, match="has no topic"):
        replace(owner, "topic", {})
    replace(owner, "state", 5)
    assert owner.state == 5


@pytest.mark.slow
def test_the_recorder_probes_at_50_hz_and_its_recording_replays(tmp_path: Path) -> None:
    def bench(*args: str) -> str:
        r = subprocess.run(
            [sys.executable, str(BENCH / "replay_timesync.py"), *args],
            capture_output=True,
            text=True,
            timeout=180,
        )
        assert r.returncode == 0, r.stderr
        return r.stdout

    bench("record", "--runs", "1", "--seconds", "4", "--out", str(tmp_path))
    doc = json.loads((tmp_path / "run100.json").read_text())
    # the sync's own schedule, not a rate against wall time (a busy machine probes late, fewer)
    assert doc["interval_ms"] == 20.0, f"the sync probed every {doc['interval_ms']} ms, not 20"
    ex = doc["exchanges"]
    assert len(ex) >= 2 and all(a[3] <= b[0] for a, b in pairwise(ex))  # one at a time
    assert "| run100 |" in bench("floors", "--in", str(tmp_path))
    assert "| missing-link (default) |" in bench("replay", "--in", str(tmp_path))
