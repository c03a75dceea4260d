"""The house's rules of size and habit: no file over MAX_LINES lines (the package's Python and
JavaScript, bench/, tests/, the firmware's C), no function over 80 (in src/ and bench/), tests
that start processes marked slow, every module saying what it owns, every package imported
declared.  (The import structure, the rooms and their floors: tests/test_architecture.py.)
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src" / "missing_link"
BENCH = ROOT / "bench"
TESTS = ROOT / "tests"
FIRMWARE = SRC / "firmware"

MAX_LINES = 450

#: what the size rule covers, and what it leaves out: vendored or minified code (not ours to
#: split) and what a build or a tool puts in the tree
SIZED = [(SRC, "*.py"), (SRC, "*.mjs"), (SRC, "*.js"), (BENCH, "*.py"), (TESTS, "*.py"),
         (TESTS, "*.mjs"), (FIRMWARE, "*.c"), (FIRMWARE, "*.h")]  # fmt: skip

NOT_SIZED_NAMES = ("uPlot*", "*.min.js")

NOT_SIZED_DIRS = {"build", "node_modules", "__pycache__"}

MAX_FUNCTION_LINES = 80


def sized_files() -> list[Path]:
    """Every file the size rule covers (``SIZED``, less ``NOT_SIZED_*``)."""
    return sorted(
        p
        for top, pattern in SIZED
        for p in top.rglob(pattern)
        if not any(p.match(n) for n in NOT_SIZED_NAMES)
        and not NOT_SIZED_DIRS & set(p.relative_to(top).parts)
    )


def test_no_file_over_450_lines() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in sized_files()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, f"files over {MAX_LINES} lines: {long}"


def test_the_size_rule_sees_every_kind_of_file() -> None:
    seen = {str(p.relative_to(ROOT)) for p in sized_files()}
    for path in (
        "src/missing_link/daemon/service.py",
        "src/missing_link/virtual/world/host.mjs",
        "src/missing_link/publishers/web_static/console.js",
        "bench/bench_codec.py",
        "tests/test_architecture.py",
        "tests/micropython/setup_board.py",
        "tests/micropython/serial_board.mjs",
        "src/missing_link/firmware/avr/sim/rig_sim.c",
        "src/missing_link/firmware/avr/src/runtime.h",
    ):
        assert path in seen, path
    assert not any("uPlot" in p for p in seen)


def long_functions(paths: list[Path], limit: int = MAX_FUNCTION_LINES) -> dict[str, int]:
    """``file:line name`` -> lines, for every function (methods and nested ones too) longer
    than ``limit``, counted from its ``def`` (decorators aside) to its last line."""
    found = {}
    for path in paths:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > limit:
                    found[f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"] = n
    return found


#: ``path name`` of a function over the limit left for now, and why (take it out when it is split)
WAIVED: dict[str, str] = {}


def test_no_function_over_80_lines() -> None:
    long = long_functions([*SRC.rglob("*.py"), *BENCH.glob("*.py")])
    left = {k: n for k, n in long.items() if f"{k.split(':')[0]} {k.split()[-1]}" not in WAIVED}
    assert not left, f"functions over {MAX_FUNCTION_LINES} lines: {left}"
    gone = {w for w in WAIVED if not any(w == f"{k.split(':')[0]} {k.split()[-1]}" for k in long)}
    assert not gone, f"waived but no longer over the limit (take them out of WAIVED): {gone}"


def test_the_function_walk_counts_what_it_should() -> None:
    tmp = ROOT / ".pytest_cache" / "arch_probe"
    tmp.mkdir(parents=True, exist_ok=True)
    path = tmp / "long.py"
    body = "\n".join(f"        x{i} = {i}" for i in range(79))
    path.write_text(
        f"@dec\ndef short():\n    pass\n\nclass C:\n    def long(self):\n{body}\n"
        "        async def inner():\n            pass\n"
    )
    # long: def + 79 lines + 2 of inner = 82; inner 2; short 2
    assert long_functions([path]) == {".pytest_cache/arch_probe/long.py:6 long": 82}
    assert long_functions([path], limit=1) == {
        ".pytest_cache/arch_probe/long.py:2 short": 2,
        ".pytest_cache/arch_probe/long.py:6 long": 82,
        ".pytest_cache/arch_probe/long.py:86 inner": 2,
    }


#: what starts another process or a real component, by the name a test uses for it (helpers.py,
#: conftest.py), and subprocess's verbs
#: (the runtime fixture, board_runtime and what uses it: start_board, thesis, marks its own
#: MicroPython and AVR params slow; its CPython one runs in this process)
STARTS_PROCESSES = {
    *("board_process", "start_board_process", "ml", "ML", "FirmwareSim", "HexLinePipe"),
    *("AvrSim", "avr_rig", "avr_build", "uno_rig", "SerialBoard", "sync_playwright", "ROS2_PY"),
    *("MicroPythonSim", "ProcessBoard"),
}

SUBPROCESS = {"run", "Popen", "check_output", "check_call", "call"}

#: quick children that make check keeps: a bare interpreter that imports the package
QUICK_CHILDREN = {"test_architecture.py::test_the_face_imports_nothing_at_run_time",
                  "test_house_rules.py::test_the_core_runs_without_the_extras"}  # fmt: skip


def unmarked_process_tests(path: Path) -> list[str]:
    """The tests of ``path`` that start a process (themselves, or through a function or fixture
    of their module) without the ``slow`` mark (their own, or the module's ``pytestmark``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    funcs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
    module_slow = any(
        isinstance(n, ast.Assign | ast.AugAssign)
        and "pytestmark" in ast.unparse(n)
        and "slow" in ast.unparse(n)
        for n in tree.body
    )

    def starts(name: str, seen: frozenset[str] = frozenset()) -> bool:
        fn = funcs[name]
        used = {a.arg for a in fn.args.args + fn.args.kwonlyargs}
        for node in ast.walk(fn):
            if isinstance(node, ast.Name):
                used.add(node.id)
            elif isinstance(node, ast.Attribute):
                if ast.unparse(node.value) == "subprocess" and node.attr in SUBPROCESS:
                    return True
                used.add(node.attr)
        if used & STARTS_PROCESSES:
            return True
        inner = (used & set(funcs)) - seen - {name}
        return any(starts(n, seen | {name}) for n in inner)

    out = []
    for name, fn in funcs.items():
        marked = module_slow or any("slow" in ast.unparse(d) for d in fn.decorator_list)
        key = f"{path.name}::{name}"
        if name.startswith("test_") and not marked and key not in QUICK_CHILDREN and starts(name):
            out.append(key)
    return out


def test_tests_that_start_processes_are_marked_slow() -> None:
    """``make check`` runs the tests not marked slow: none of them may start a board process,
    MicroPython, simavr, ROS or a browser (docs/development.md)."""
    here = Path(__file__).resolve().parent
    found = [t for p in sorted(here.glob("test_*.py")) for t in unmarked_process_tests(p)]
    assert not found, f"tests that start processes, not marked slow: {found}"


@pytest.mark.parametrize(
    ("source", "unmarked"),
    [
        ("def test_a():\n    ml('info')\n", ["probe.py::test_a"]),
        ("import pytest\n@pytest.mark.slow\ndef test_a():\n    ml('info')\n", []),
        ("def helper():\n    subprocess.Popen(['x'])\ndef test_a():\n    helper()\n", None),
        ("def fix(avr_rig):\n    return 1\ndef test_a(fix):\n    pass\n", None),
        ("pytestmark = [pytest.mark.slow]\ndef test_a(board_process):\n    pass\n", []),
        ("def test_a(serve):\n    serve('thesis')\n", []),
    ],
)
def test_the_process_walk_sees_helpers_and_fixtures(
    source: str, unmarked: list[str] | None, tmp_path: Path
) -> None:
    # (each case its own file: xdist's workers run the cases at once, and one shared probe.py
    # was read by one case while another wrote it)
    path = tmp_path / "probe.py"
    path.write_text(source)
    assert unmarked_process_tests(path) == (["probe.py::test_a"] if unmarked is None else unmarked)


#: imported where the environment provides them (ROS installs), never installed by pip
PROVIDED_BY_ROS = {"rclpy", "rcl_interfaces", "rospy", "genpy", "rosgraph", "roslib"}


def test_every_imported_package_is_declared() -> None:
    """What the package imports from outside the standard library is a declared dependency."""
    import tomllib
    from importlib.metadata import packages_distributions, requires

    declared = {
        r.split(";")[0].split("[")[0].split("<")[0].split(">")[0].split("=")[0].strip().lower()
        for r in requires("missing-link") or []
        if "extra ==" not in r
    }
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert declared == {
        d.split(";")[0].split("<")[0].split(">")[0].split("=")[0].strip().lower()
        for d in project["dependencies"]
    }, "the installed metadata is stale: reinstall (make venv)"
    extras = {
        d.split(";")[0].split("[")[0].split("<")[0].split(">")[0].split("=")[0].strip().lower()
        for name, deps in project.get("optional-dependencies", {}).items()
        if name != "dev"
        for d in deps
    }
    dists = packages_distributions()
    missing = {}
    for path in SRC.rglob("*.py"):
        if "board" in path.relative_to(SRC).parts[:1]:
            continue  # the board runtime runs on MicroPython: only its own and built-in modules
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                if (
                    top in sys.stdlib_module_names
                    or top in PROVIDED_BY_ROS
                    or top == "missing_link"
                ):
                    continue
                owners = {d.lower() for d in dists.get(top, [])}
                if not owners & (declared | extras):
                    missing[top] = str(path.relative_to(ROOT))
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


#: what the faces that are extras import (pyproject's web, zenoh: the core runs without them)
EXTRAS_ONLY = ("websockets", "zenoh", "xxhash")


def test_the_core_runs_without_the_extras() -> None:
    """The core is light: without the web and zenoh extras the CLI, the daemon and the core faces
    (bus, console, mcap) load and start; a face that needs an extra says which."""
    probe = (
        "import sys\n"
        f"for m in {EXTRAS_ONLY!r}: sys.modules[m] = None  # (as if not installed)\n"
        "import missing_link.cli.main\n"
        "from missing_link.daemon import Config, Daemon\n"
        "from missing_link.publishers.base import PublisherError\n"
        "from missing_link.publishers.registry import make_publisher\n"
        "import tempfile\n"
        "with tempfile.TemporaryDirectory() as tmp:\n"
        "    cfg = Config(publishers=['bus', 'console', 'mcap'],\n"
        "                 publisher_options={'mcap': {'path': tmp}})\n"
        "    with Daemon(cfg) as d:\n"
        "        print(sorted(p.name for p in d.publishers))\n"
        "try:\n"
        "    make_publisher('web', {})\n"
        "except PublisherError as e:\n"
        "    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    first, second = r.stdout.splitlines()[:2]
    assert first == "['bus', 'console', 'mcap']"
    assert "missing-link[web]" in second, second


def test_every_module_says_what_it_owns() -> None:
    """A docstring at the top of every module; the board runtime (MicroPython, where a docstring
    costs RAM) opens with a comment instead."""
    silent = []
    for path in SRC.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if path.relative_to(SRC).parts[0] in ("board", "examples"):  # (examples: board files)
            if not text.startswith("#"):
                silent.append(str(path.relative_to(ROOT)))
        elif not ast.get_docstring(ast.parse(text)):
            silent.append(str(path.relative_to(ROOT)))
    assert not silent, f"modules that do not say what they own: {silent}"
