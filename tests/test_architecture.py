"""The house keeps its shape: no import circle, imports only downward, every room on its floor
(sizes and habits: tests/test_house_rules.py).

Every import counts (module level, inside functions, under ``TYPE_CHECKING``): a circle that is
lazy at run time is still a circle for the reader.  The rooms, from the ground up (a room may
import its own modules and any room on a lower floor, never one above):

0. core: ``version``, ``errors``, ``text``, ``lazy``, ``delegate``, ``closing``, ``descriptors``,
   ``j2a/``, ``timesync/``, ``board/`` (one floor: its rooms import each other, without a circle)
1. ``transport/`` (bytes by URL), ``ros/`` (ROS vocabulary, no I/O), ``world/`` (the world a
   virtual robot lives in: pure, no I/O)
2. ``host/`` (one board from the host), ``topics`` (what the daemon hands publishers)
3. ``publishers/``
4. ``daemon/`` (many boards -> topics), in rooms of its own, from the ground up (``DAEMON_FLOORS``):
   its configuration (``paths``, ``listen_spec``, ``discover_spec``, ``ros_config``, ``claims``;
   then ``config``),
   ``session/`` (one board), ``intake/`` (boards coming in) and ``control/`` (who steers), then
   the daemon's own modules (``fanout``, ``health``, ``joints``, ``board_api``, ``names``) and at
   the top ``service``
5. ``virtual/`` (simulated boards, links, clocks), ``deploy/`` (board files, flashing, firmware)
6. ``cli/`` (the command line), ``testing/`` (fakes for tests, shipped with the library)

The package's face (``missing_link/__init__.py``) names its public API lazily, by string, so
``import missing_link`` loads nothing it does not use; it imports rooms only for type checkers.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src" / "missing_link"
BENCH = ROOT / "bench"
TESTS = ROOT / "tests"

FLOORS = {
    "version": 0,
    "errors": 0,
    "text": 0,
    "logs": 0,
    "lazy": 0,
    "delegate": 0,
    "closing": 0,
    "descriptors": 0,
    "j2a": 0,
    "timesync": 0,
    "board": 0,
    "transport": 1,
    "ros": 1,
    "world": 1,
    "host": 2,
    "topics": 2,
    "publishers": 3,
    "daemon": 4,
    "virtual": 5,
    "deploy": 5,
    "cli": 6,
    "testing": 6,
    "__main__": 7,
}
#: the daemon's rooms (a module, or a folder of them), from the ground up: a room imports its own
#: modules and rooms on a lower floor, never one beside or above it
DAEMON_FLOORS = {
    "paths": 0,
    "listen_spec": 0,
    "discover_spec": 0,
    "ros_config": 0,
    "claims": 0,
    "config": 1,
    "session": 2,
    "intake": 3,
    "control": 3,
    "fanout": 4,
    "health": 4,
    "joints": 4,
    "board_api": 4,
    "names": 4,
    "service": 5,
}
#: registries name their plugins by string and import them on first use
REGISTRIES = {
    "missing_link.transport.registry": "missing_link.transport.",
    "missing_link.transport": "missing_link.transport.",
    "missing_link.publishers.registry": "missing_link.publishers.",
    "missing_link.publishers": "missing_link.publishers.",
}
REGISTRY_MAY_IMPORT = {"missing_link.transport.base", "missing_link.publishers.base"}


def module_name(path: Path, top: Path = SRC) -> str:
    rel = path.relative_to(top.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


#: package data that happens to be Python: the example board files (BOARD = {...}, read by the
#: host as a literal, never imported)
DATA = SRC / "examples"


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(SRC.rglob("*.py")) if DATA not in p.parents}


def _type_only(tree: ast.Module) -> set[ast.AST]:
    """The import statements under ``if TYPE_CHECKING:``."""
    out: set[ast.AST] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for stmt in node.body:
                out |= set(ast.walk(stmt))
    return out


def imports_of(name: str, path: Path, known: set[str], *, run_time_only: bool = False) -> set[str]:
    """Every module of the tree that ``path`` imports, wherever the import stands
    (``run_time_only``: leave out what stands under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    skip = _type_only(tree) if run_time_only else set()
    out: set[str] = set()
    for node in ast.walk(tree):
        if node in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in known:
                    out.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in known:
                    out.add(sub)
                elif target in known:
                    out.add(target)
    out.discard(name)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imports_of(name, path, known) for name, path in mods.items()}


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_no_import_circle_in_the_package() -> None:
    found = circles(graph())
    assert not found, "import circles: " + "; ".join(" <-> ".join(c) for c in found)


def test_every_room_has_a_floor() -> None:
    rooms = {room(m) for m in modules()} - {"__init__"}
    assert rooms <= set(FLOORS), f"rooms without a floor: {sorted(rooms - set(FLOORS))}"


def test_the_face_imports_nothing_at_run_time() -> None:
    mods = modules()
    eager = imports_of("missing_link", mods["missing_link"], set(mods), run_time_only=True)
    assert not eager, f"missing_link/__init__.py imports {eager}: name them lazily"
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, missing_link; print(sorted(sys.modules))"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    inside = [m.strip("[]',") for m in loaded if m.strip("[]',").startswith("missing_link.")]
    assert not inside, f"import missing_link loads {inside}"


def test_imports_only_go_down() -> None:
    bad = []
    for mod, targets in graph().items():
        here = room(mod)
        if here == "__init__":
            continue  # the face: type-only imports (test_the_face_imports_nothing_at_run_time)
        for target in targets:
            there = room(target)
            if there == "__init__":
                bad.append(f"{mod} -> missing_link (the face)")
            elif there != here and FLOORS[there] >= FLOORS[here] > 0:  # (the core: one floor)
                bad.append(f"{mod} (floor {FLOORS[here]}) -> {target} (floor {FLOORS[there]})")
    assert not bad, "imports that run up or sideways:\n" + "\n".join(sorted(bad))


def daemon_room(module: str) -> str | None:
    """The daemon's room of ``module`` (None: not in the daemon, or its face)."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "daemon" else None


def test_every_room_of_the_daemon_has_a_floor() -> None:
    rooms = {r for m in modules() if (r := daemon_room(m)) is not None}
    assert rooms == set(DAEMON_FLOORS), (
        f"update DAEMON_FLOORS: {sorted(rooms ^ set(DAEMON_FLOORS))}"
    )


def test_imports_only_go_down_inside_the_daemon() -> None:
    bad = []
    for mod, targets in graph().items():
        here = daemon_room(mod)
        if here is None:
            continue
        for target in targets:
            there = daemon_room(target)
            if target == "missing_link.daemon":
                bad.append(f"{mod} -> missing_link.daemon (the face)")
            elif (
                there is not None and there != here and DAEMON_FLOORS[there] >= DAEMON_FLOORS[here]
            ):
                floors = f"floor {DAEMON_FLOORS[here]} -> {DAEMON_FLOORS[there]}"
                bad.append(f"{mod} -> {target} ({floors})")
    assert not bad, "imports that run up or sideways in the daemon:\n" + "\n".join(sorted(bad))


def test_core_imports_only_the_core() -> None:
    core = {r for r, f in FLOORS.items() if f == 0}
    for mod, targets in graph().items():
        if room(mod) in core:
            outside = {t for t in targets if room(t) not in core}
            assert not outside, f"{mod} (core) imports {outside}"


def test_no_child_of_the_daemon_imports_its_service() -> None:
    service = {"missing_link.daemon", "missing_link.daemon.service"}
    for mod, targets in graph().items():
        if mod.startswith("missing_link.daemon.") and mod not in service:
            assert not targets & service, f"{mod} imports the daemon's service: {targets & service}"


def test_no_registry_imports_its_plugins() -> None:
    g = graph()
    for registry, plugins in REGISTRIES.items():
        assert registry in g, f"{registry} is gone: update REGISTRIES"
        imported = {t for t in g[registry] if t.startswith(plugins)} - REGISTRY_MAY_IMPORT
        imported -= set(REGISTRIES)
        assert not imported, f"{registry} imports its plugins {imported}: name them by string"


def test_no_circle_among_the_benchmarks() -> None:
    names = {p.stem for p in BENCH.glob("*.py")}
    edges: dict[str, set[str]] = {}
    for p in BENCH.glob("*.py"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        got: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                got |= {a.name for a in node.names if a.name in names}
            elif isinstance(node, ast.ImportFrom) and node.module in names:
                got.add(node.module)
        edges[p.stem] = got - {p.stem}
    found = circles(edges)
    assert not found, "import circles in bench/: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_walk_sees_every_kind_of_import() -> None:
    """The walk itself: lazy, type-only and relative imports all count."""
    src = (
        "from __future__ import annotations\n"
        "from typing import TYPE_CHECKING\n"
        "from .b import x\n"
        "if TYPE_CHECKING:\n    from ..c import y\n"
        "def f():\n    from . import d\n"
    )
    tmp = ROOT / ".pytest_cache" / "arch_probe"
    (tmp / "p" / "q").mkdir(parents=True, exist_ok=True)
    path = tmp / "p" / "q" / "a.py"
    path.write_text(src)
    known = {"p.q.b", "p.c", "p.q.d", "p.q"}
    assert imports_of("p.q.a", path, known) == {"p.q.b", "p.c", "p.q.d"}
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def room_table() -> set[str]:
    """Every path the room table of docs/development.md names (``dir/`` (``a.py``, ...) names
    ``dir/a.py``, ...), from the package's folder (or the repository's)."""
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    rows = [line for line in text.split("## Rooms", 1)[1].split("\n## ", 1)[0].splitlines()]
    named: set[str] = set()
    for row in rows:
        if not row.startswith("|") or row.startswith("|---"):
            continue
        where = row.rstrip(" |").rsplit("|", 1)[-1]
        for folder, inner in re.findall(r"`([\w/]+/)`(?: \(([^)]*)\))?", where):
            named.add(folder)
            named |= {folder + n for n in re.findall(r"`([\w.]+)`", inner)}
        alone = re.sub(r"`[\w/]+/` \([^)]*\)", "", where)  # (the names in a folder's brackets)
        named |= set(re.findall(r"`([\w/]+\.\w+)`", alone))
    return {n.removeprefix("src/missing_link/") for n in named}


def test_the_room_table_names_every_room_and_only_what_is_there() -> None:
    named = room_table()
    gone = sorted(n for n in named if not (SRC / n).exists() and not (ROOT / n).exists())
    assert not gone, f"docs/development.md names what is not there: {gone}"
    unnamed = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC)
        if rel.name == "__init__.py" or rel.parts[0] in ("__main__.py", "version.py"):
            continue
        daemon = rel.parts[0] == "daemon"  # (the daemon's modules each by name)
        folders = {"/".join(rel.parts[: i + 1]) + "/" for i in range(len(rel.parts) - 1)}
        if str(rel) not in named and (daemon or not folders & named):
            unnamed.append(str(rel))
    assert not unnamed, f"docs/development.md's room table does not name: {unnamed}"
