"""The wheel as a user installs it (issue 45.1): built from this checkout, installed into a fresh
venv outside it (with the extras the demo needs, as pyproject declares them), and run from
another directory: the demo, the examples written out, ``board --file`` on one of them, an AVR
``gen-firmware`` that builds the firmware from the package's own C sources, and the hint a
checkout's path gets there.  Before, the examples and the AVR sources were not in the wheel."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from .helpers import board_process

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parent.parent
#: the extras `missing-link demo` uses (its live faces), where pyproject declares them
DEMO_EXTRAS = ("web",)
#: what a checkout's src/ holds that is no part of a build
NOT_BUILT = ("__pycache__", "*.egg-info", "build")


def _run(cmd: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    return r


@pytest.fixture(scope="module")
def core(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path, Path]]:
    """The wheel installed without extras: (the fresh venv's bin directory, a working directory
    outside the checkout, the wheel)."""
    top = tmp_path_factory.mktemp("install")
    tree, wheels = top / "tree", top / "wheels"  # (built from a copy: a build leaves build/)
    shutil.copytree(ROOT / "src", tree / "src", ignore=shutil.ignore_patterns(*NOT_BUILT))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).exists():
            shutil.copy(ROOT / name, tree / name)
    r = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels),
              str(tree)], top)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    (wheel,) = wheels.glob("missing_link-*.whl")
    r = _run([sys.executable, "-m", "venv", str(top / "venv")], top)
    assert r.returncode == 0, r.stderr
    bin_ = top / "venv" / "bin"
    r = _run([str(bin_ / "python"), "-m", "pip", "install", "-q", str(wheel)], top)
    assert r.returncode == 0, r.stderr[-3000:]
    work = top / "elsewhere"
    work.mkdir()
    yield bin_, work, wheel


@pytest.fixture(scope="module")
def venv(core: tuple[Path, Path, Path]) -> tuple[Path, Path]:
    """The same venv with the extras the demo needs (pyproject's, where it declares them)."""
    bin_, work, wheel = core
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"].get(
        "optional-dependencies", {}
    )
    extras = [e for e in DEMO_EXTRAS if e in declared]
    if extras:
        spec = f"{wheel}[{','.join(extras)}]"
        r = _run([str(bin_ / "python"), "-m", "pip", "install", "-q", spec], work)
        assert r.returncode == 0, r.stderr[-3000:]
    return bin_, work


@pytest.mark.parametrize(
    ("argv", "extra"),
    [
        (["demo", "--duration", "1"], "web"),
        (["router"], "zenoh"),
        (["run", "serial:///dev/null", "-p", "zenoh"], "zenoh"),
        (["flash", "BOARDS/thesis-rig.py", "--dry-run"], "flash"),
    ],
)
def test_a_missing_extra_is_one_line_naming_it(
    core: tuple[Path, Path, Path], argv: list[str], extra: str
) -> None:
    """Before the extras are installed (this test runs first): the core alone."""
    bin_, work, _ = core
    boards = str(bin_.parent / "lib")  # (the installed examples, wherever site-packages is)
    found = next(Path(boards).glob("python3*/site-packages/missing_link/examples/boards"))
    argv = [a.replace("BOARDS", str(found)) for a in argv]
    r = _run([str(bin_ / "missing-link"), *argv], work, timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    err = r.stderr.strip()
    assert "\n" not in err and f"pip install 'missing-link[{extra}]'" in err, err


def test_it_is_not_the_checkout(venv: tuple[Path, Path]) -> None:
    bin_, work = venv
    r = _run(
        [str(bin_ / "python"), "-c", "import missing_link; print(missing_link.__file__)"], work
    )
    assert r.returncode == 0, r.stderr
    where = Path(r.stdout.strip())
    assert ROOT not in where.parents and bin_.parent in where.parents, where


def test_the_demo_runs(venv: tuple[Path, Path]) -> None:
    bin_, work = venv
    r = _run([str(bin_ / "missing-link"), "demo", "--duration", "3", "--web", "off", "--record",
              str(work / "rec")], work, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "demo finished OK" in r.stdout
    assert list((work / "rec").glob("demo_*"))


def test_a_written_example_runs_as_a_board(venv: tuple[Path, Path]) -> None:
    bin_, work = venv
    ml = str(bin_ / "missing-link")
    r = _run([ml, "examples", "ex"], work)
    assert r.returncode == 0, r.stderr
    assert (work / "ex" / "missing-link.toml").is_file()
    with board_process("--file", "ex/boards/thesis-rig.py", cmd=[ml], cwd=work) as url:
        r = _run([ml, "info", url, "--json"], work, timeout=60)
        assert r.returncode == 0, r.stderr
        assert '"imu"' in r.stdout and '"servo"' in r.stdout


def test_an_avr_firmware_builds_from_the_installed_sources(venv: tuple[Path, Path]) -> None:
    if shutil.which("avr-gcc") is None:
        pytest.fail("avr-gcc is required: run scripts/system-deps.sh")
    bin_, work = venv
    ml = str(bin_ / "missing-link")
    r = _run([ml, "examples", "avr-ex", "--force"], work)
    assert r.returncode == 0, r.stderr
    r = _run([ml, "gen-firmware", "avr-ex/boards/thesis-rig-uno.py", "--out", "fw"], work)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("atmega328p: flash "), r.stdout  # (built: the fit check's line)
    assert (work / "fw" / "board_gen.c").is_file()


def test_a_checkouts_path_gets_the_installed_one(venv: tuple[Path, Path]) -> None:
    bin_, work = venv
    r = _run([str(bin_ / "missing-link"), "board", "--file", "examples/boards/rover.py",
              "--listen", "pty"], work)  # fmt: skip
    assert r.returncode == 2
    err = r.stderr.strip()
    assert "\n" not in err and "missing-link examples DIR" in err, err
    assert str(bin_.parent) in err and err.count("examples/boards/rover.py") == 2, err
