from __future__ import annotations

import itertools
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.board.runtime import BoardRuntime
from missing_link.deploy.avr import AVR_DIR as AVR
from missing_link.virtual import BoardServer, make_sim, start_board_thread

from .helpers import AvrRig, AvrSim, j2a_threads

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
ROVER_MEGA = ROOT / "examples" / "boards" / "rover-mega.py"

_names = itertools.count()


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
    yield
    left = [t for t in j2a_threads() if t.is_alive() and t.name.startswith("j2a:")]
    assert not left, f"reader threads left running: {left}"


@pytest.fixture(scope="session")
def avr_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The AVR firmware of the thesis rig (Uno) and of the rover (Mega), the golden-vector
    board and rig_sim, built once per session (tests/test_avr*.py)."""
    for tool in ("avr-gcc", "cc"):
        if shutil.which(tool) is None:
            pytest.fail(f"{tool} is required: run scripts/system-deps.sh")
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        pytest.fail("libsimavr-dev is required: run scripts/system-deps.sh")
    out = tmp_path_factory.mktemp("avr")
    r = subprocess.run(
        [
            "make",
            "-C",
            str(AVR),
            f"BOARD={UNO}",
            f"BUILD={out}",
            f"PYTHON={sys.executable}",
            "all",
            "sim",
            "golden",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "atmega328p: flash" in r.stdout  # the size line, budgets checked by make
    r = subprocess.run(  # the rover's parts on a Mega (tests/test_avr_rover.py)
        ["make", "-C", str(AVR), f"BOARD={ROVER_MEGA}", f"BUILD={out}", f"PYTHON={sys.executable}"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return out


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
    """The thesis rig's Uno (examples/boards/thesis-rig-uno.py) in simavr, closed after the
    test."""
    return avr_rig("uno_rig")
