from __future__ import annotations

import ast
import itertools
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from missing_link.board.runtime import BoardRuntime
from missing_link.testing import RuntimeBoard, build_avr
from missing_link.virtual import BoardServer, make_sim, start_board_thread

from .helpers import AvrRig, AvrSim, j2a_threads

pytest_plugins = ["missing_link.testing.pytest_plugin"]

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
ROVER_MEGA = ROOT / "examples" / "boards" / "rover-mega.py"

_names = itertools.count()

# Hypothesis's deadline (200 ms an example) and its too_slow health check are wall-clock
# thresholds: a busy machine fails them, not the code (test_codec's round trip did, at a load
# of 15 on two cores).  The examples' number bounds a property test's work instead.
settings.register_profile(
    "missing-link", deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("missing-link")

#: Under pytest-xdist (make unit: -n auto --dist loadgroup) the tests of a group run in one
#: worker, one after another: ``quiet``, those that measure timing against the host's clock or
#: need the machine to themselves (the soaks in a Pico's heap, simavr's timed edges, clock sync,
#: the benchmarks' probe rate); ``faces``, those that run ROS 2 (DDS discovery on this host),
#: ROS 1 or Zenoh sessions next to each other.  A module whose tests share a module-scoped
#: fixture (a build, a daemon, a browser) is a group of its own: set up once.
SERIAL = {
    "quiet": {"test_memory.py", "test_fastclock.py", "test_avr_timing.py", "test_bench.py",
              "test_timesync_board.py"},
    "faces": {"test_ros2.py", "test_standard_ros2.py", "test_gps_time_ros2.py", "test_ros1.py",
              "test_board_log_ros.py", "test_standard_faces.py", "test_command_edges_faces.py",
              "test_command_refusals.py", "test_zenoh.py"},
}  # fmt: skip
#: The work units that take longest (measured: docs/development.md, "The suite's time"), handed
#: out first, longest first (as collected: pytest_configure), so that no worker is left with
#: one of them at the end while the others idle; the rest follow by their number of tests.
LONG_FIRST = ("quiet", "test_world_ros2.py", "faces", "test_update_powercut.py", "test_install.py",
              "test_update_mpy.py", "test_web_update.py")  # fmt: skip


def _one_at_a_time(parse: Callable[..., ast.AST]) -> Callable[..., ast.AST]:
    lock = threading.RLock()

    def parse_alone(*args: Any, **kw: Any) -> ast.AST:
        with lock:
            return parse(*args, **kw)

    return parse_alone


def pytest_configure(config: pytest.Config) -> None:
    """The daemon's default control endpoint and runtime files in a directory of this run's
    (each pytest-xdist worker its own), not the user's: tests run side by side, and beside
    other runs on the same machine.

    And ast.parse one thread at a time: CPython 3.11 keeps the AST constructor's recursion
    count per interpreter, so two threads that parse at once (a board's thread formatting a
    traceback, whose carets 3.11 finds with ast.parse, while pytest renders a failure) make
    one of them raise SystemError "AST constructor recursion depth mismatch": a worker of
    pytest-xdist ended with it, and the rest of its tests with it."""
    # pytest-xdist hands out the work units in the order collected (_longest_first), not by
    # their number of tests
    config.option.loadscopereorder = False
    if not getattr(ast.parse, "__wrapped__", None):
        alone = _one_at_a_time(ast.parse)
        alone.__wrapped__ = ast.parse  # type: ignore[attr-defined]
        ast.parse = alone  # type: ignore[assignment]
    run = tempfile.mkdtemp(prefix="ml-tests-run-")
    config.stash[_RUN_DIR] = (run, os.environ.get("XDG_RUNTIME_DIR"))
    os.environ["XDG_RUNTIME_DIR"] = run


def pytest_unconfigure(config: pytest.Config) -> None:
    run, before = config.stash.get(_RUN_DIR, (None, None))
    if run is None:
        return
    if before is None:
        os.environ.pop("XDG_RUNTIME_DIR", None)
    else:
        os.environ["XDG_RUNTIME_DIR"] = before
    shutil.rmtree(run, ignore_errors=True)


_RUN_DIR = pytest.StashKey[tuple[str, str | None]]()


@pytest.hookimpl(tryfirst=True)  # (before pytest-xdist's, which reads the groups)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        module = item.path.name
        group = next((g for g, modules in SERIAL.items() if module in modules), None)
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs.values() if info is not None else []
        if group is None and any(d.scope == "module" for ds in defs for d in ds):
            group = module
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
        item.stash[_UNIT] = group or item.nodeid
    if os.environ.get("PYTEST_XDIST_WORKER"):  # (one process: the order as collected)
        items[:] = _longest_first(items)


_UNIT = pytest.StashKey[str]()


def _longest_first(items: list[pytest.Item]) -> list[pytest.Item]:
    """``items`` by work unit (a group, else one test): the units in LONG_FIRST (a group, or a
    module's tests) first, then by their number of tests, most first (pytest-xdist's own
    order); each unit's tests in the order collected."""
    units: dict[str, list[pytest.Item]] = {}
    for item in items:
        units.setdefault(item.stash[_UNIT], []).append(item)

    def rank(unit: str) -> tuple[int, int]:
        name = unit if unit in LONG_FIRST else units[unit][0].path.name  # (a group, a module)
        first = LONG_FIRST.index(name) if name in LONG_FIRST else len(LONG_FIRST)
        return first, -len(units[unit])

    return [item for unit in sorted(units, key=rank) for item in units[unit]]


@pytest.fixture
def serve() -> Iterator[object]:
    """serve(runtime_or_sim_name, listen="memory") -> BoardServer, stopped after the test."""
    servers: list[tuple[BoardServer, object]] = []

    def start(rt: BoardRuntime | str = "thesis", listen: str = "memory") -> BoardServer:
        runtime = make_sim(rt, seed=1) if isinstance(rt, str) else rt
        if listen == "memory":
            listen = f"memory://test{next(_names)}"
        server, thread = start_board_thread(runtime, listen)
        servers.append((server, thread))
        return server

    yield start
    for server, thread in servers:
        server.stop()
        thread.join(5)  # type: ignore[attr-defined]


@pytest.fixture(autouse=True)
def no_leftover_threads() -> Iterator[None]:
    """A test leaves no reader thread of its own running (one left by an earlier test, or by
    a module's fixture, is not this test's: said where it was left)."""
    before = set(j2a_threads())
    yield
    left = [t for t in j2a_threads() if t.is_alive() and t.name.startswith("j2a:")]
    left = [t for t in left if t not in before]
    assert not left, f"reader threads left running: {left}"


def _avr_build(shared_tmp: Path) -> Path:
    out = build_avr(shared_tmp, [(UNO, ["all", "sim", "golden"]), (ROVER_MEGA, ["all"])])
    assert "atmega328p: flash" in (out / "build.log").read_text()  # the size line, checked
    return out


@pytest.fixture(scope="session")
def avr_build(shared_tmp: Path) -> Path:
    """The AVR firmware of the thesis rig (Uno) and of the rover (Mega), the golden-vector
    board and rig_sim, built once per run (every pytest-xdist worker's: missing_link.testing's
    build_avr)."""
    return _avr_build(shared_tmp)


@pytest.fixture(scope="session")
def avr_firmware(shared_tmp: Path) -> Callable[[Path], tuple[Path, Path]]:
    """The plugin's (missing_link.testing.pytest_plugin), the thesis rig's from avr_build;
    built when a test first asks (not for the CPython runs of a test on every runtime)."""

    def find(board_file: Path) -> tuple[Path, Path]:
        if Path(board_file).resolve() == UNO.resolve():  # (examples/ is the package's)
            build = _avr_build(shared_tmp)
            return build, build / "uno_rig" / "firmware.elf"
        out = build_avr(shared_tmp, [(board_file, ["all", "sim"])])
        (elf,) = out.glob("*/firmware.elf")
        return out, elf

    return find


@pytest.fixture
def thesis(start_board: Callable[..., RuntimeBoard]) -> RuntimeBoard:
    """The thesis rig on every runtime (board_runtime): the ``thesis`` sim on CPython, on a
    board clock the test turns; examples/boards/thesis-rig.py under MicroPython; its Uno
    (thesis-rig-uno.py) in simavr."""
    return start_board(seed=3)


@pytest.fixture
def avr_rig(avr_build: Path) -> Iterator[AvrRig]:
    """avr_rig(firmware, skew_ppm=..., rover=..., eeprom=...) -> an AvrSim running
    ``BUILD/firmware/firmware.elf`` (``uno_rig``, ``mega_rover``, ``golden``), closed after the
    test."""
    sims: list[AvrSim] = []

    def start(
        firmware: str = "uno_rig",
        *,
        skew_ppm: float = 0.0,
        eeprom: Path | None = None,
        rover: bool = False,
    ) -> AvrSim:
        elf = avr_build / firmware / "firmware.elf"
        sim = AvrSim(avr_build, elf, skew_ppm=skew_ppm, eeprom=eeprom, rover=rover)
        sims.append(sim)
        return sim

    yield start
    for sim in sims:
        sim.close()


@pytest.fixture
def uno_rig(avr_rig: AvrRig) -> AvrSim:
    """The thesis rig's Uno in simavr (uno_rig), closed after the test."""
    return avr_rig("uno_rig")
