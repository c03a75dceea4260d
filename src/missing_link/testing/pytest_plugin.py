"""missing-link's pytest plugin: a board under test on every runtime.

Enable it in a ``conftest.py``::

    pytest_plugins = ["missing_link.testing.pytest_plugin"]

Fixtures
--------
``board_runtime``
    Parametrised over :data:`~missing_link.testing.RUNTIMES`: ``"cpython"``, ``"micropython"``
    (needs node and the npm MicroPython: ``make node``), ``"avr"`` (needs avr-gcc and simavr);
    the last two marked ``slow`` and ``micropython`` / ``avr``, so ``-m "not slow"`` runs the
    CPython one only.  ``@pytest.mark.parametrize("board_runtime", runtime_params("avr"))``
    chooses (:func:`runtime_params`: the runtimes with their marks).
``start_board``
    ``start_board(board_file=None, *, sim=None, avr=None, seed=0)`` starts a board on that
    runtime and stops it after the test (a :class:`~missing_link.testing.RuntimeBoard`):
    ``board_file`` under MicroPython, on CPython (a process of its own), and ``avr`` (default:
    the same file) in simavr.  ``sim``: on CPython, this virtual board (``make_sim``'s name)
    in the test's process on a :class:`FakeBoardClock` instead.  No board file: the thesis rig
    (the example board files, and the ``thesis`` sim).
``avr_firmware``
    Session-wide: ``avr_firmware(board_file) -> (build directory, firmware.elf)``, built once
    per run, pytest-xdist's workers included (:func:`~missing_link.testing.build_avr`).
``shared_tmp``
    Session-wide: a directory every pytest-xdist worker of this run shares (its own basetemp
    without xdist).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

from ..virtual import make_sim
from .board_clock import FakeBoardClock
from .runtimes import RUNTIMES, ProcessBoard, RuntimeBoard, SteppedBoard
from .sims import AvrSim, MicroPythonSim, build_avr

EXAMPLES = Path(str(resources.files("missing_link") / "examples" / "boards"))
THESIS_RIG, THESIS_RIG_UNO = EXAMPLES / "thesis-rig.py", EXAMPLES / "thesis-rig-uno.py"

#: an AVR build: (its directory, with rig_sim; the image)
AvrFirmware = tuple[Path, Path]

_MARKS = {
    "slow": "other processes or real components (MicroPython, simavr, ...)",
    "micropython": "runs the firmware under MicroPython (needs node)",
    "avr": "the C firmware on AVR machine code in simavr (needs avr-gcc, simavr)",
}


def pytest_configure(config: pytest.Config) -> None:
    for name, what in _MARKS.items():
        config.addinivalue_line("markers", f"{name}: {what}")


def runtime_params(*names: str) -> list[Any]:
    """The runtimes ``names`` (default: all) as pytest params with their marks, for a test that
    concerns some: ``@pytest.mark.parametrize("board_runtime", runtime_params("micropython"))``."""
    marks = {
        "cpython": [],
        "micropython": [pytest.mark.slow, pytest.mark.micropython],
        "avr": [pytest.mark.slow, pytest.mark.avr],
    }
    return [pytest.param(name, marks=marks[name], id=name) for name in names or RUNTIMES]


@pytest.fixture(params=runtime_params())
def board_runtime(request: pytest.FixtureRequest) -> str:
    """The runtime a test runs on (see the module's docstring)."""
    assert request.param in RUNTIMES
    return str(request.param)


@pytest.fixture(scope="session")
def shared_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def avr_firmware(shared_tmp: Path) -> Callable[[Path], AvrFirmware]:
    def build(board_file: Path) -> AvrFirmware:
        out = build_avr(shared_tmp, [(board_file, ["all", "sim"])])
        (elf,) = out.glob("*/firmware.elf")
        return out, elf

    return build


@pytest.fixture
def start_board(
    board_runtime: str, avr_firmware: Callable[[Path], AvrFirmware]
) -> Iterator[Callable[..., RuntimeBoard]]:
    started: list[RuntimeBoard] = []

    def start(
        board_file: Path | str | None = None,
        *,
        sim: str | None = None,
        avr: Path | str | None = None,
        seed: int = 0,
    ) -> RuntimeBoard:
        if board_file is None:
            board_file, sim, avr = THESIS_RIG, sim or "thesis", avr or THESIS_RIG_UNO
        board: RuntimeBoard
        if board_runtime == "cpython" and sim is not None:
            clock = FakeBoardClock()
            board = SteppedBoard(make_sim(sim, seed, clock=clock), clock, sim)
        elif board_runtime == "cpython":
            board = ProcessBoard(board_file, ["--seed", str(seed)])
        elif board_runtime == "micropython":
            board = MicroPythonSim(board_file, args=["--seed", str(1000 + seed)])
        else:
            build, elf = avr_firmware(Path(avr or board_file))
            board = AvrSim(build, elf)
        started.append(board)
        return board

    yield start
    for board in started:
        board.close()
