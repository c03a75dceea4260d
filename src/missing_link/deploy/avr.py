"""AVR boards (ATmega328P/2560/32U4): build the C firmware for a board file (``make`` in the
package's ``firmware/avr``, which runs ``gen-firmware`` and stamps the image with a board.id and
its fw.hash: avrstamp.py), check that it fits the MCU's flash and RAM (avrsize.py: refused with
the numbers before anything is written), and write it with avrdude through the Arduino
bootloader; then ``flash`` checks the board answers J2A as the board file says, with the fw.hash
it was stamped with (and the id, when ``--id`` forced one). The id reaches the EEPROM through
the image: the bootloaders write flash only (identity.c). ``gen-firmware`` builds it too, to
refuse a board file that cannot fit (fit())."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable
from importlib import resources
from pathlib import Path

from .avrdrivers import DRIVER_SOURCES
from .avrsize import AvrSize, budget, budget_table, by_source, check
from .avrstamp import check_id
from .boardfile import FEATURES, BoardFile
from .check import FlashError, verify

#: the C runtime, its Makefile and the simavr rig: package data (missing_link/firmware/avr),
#: installed with the package, so a wheel builds firmware as a checkout does
AVR_DIR = Path(str(resources.files("missing_link") / "firmware" / "avr"))
#: avrdude part, programmer and baud of the usual Arduino bootloader per MCU
AVRDUDE = {
    "atmega328p": ("m328p", "arduino", 115200),  # Uno, Nano (new bootloader)
    "atmega2560": ("m2560", "wiring", 115200),  # Mega 2560
    "atmega32u4": ("m32u4", "avr109", 57600),  # Leonardo, Micro (Caterina)
}


def avrdude_command(mcu: str, port: str, hex_path: str | Path) -> list[str]:
    part, programmer, baud = AVRDUDE[mcu]
    return [
        "avrdude", "-p", part, "-c", programmer, "-P", port, "-b", str(baud), "-D",
        "-U", f"flash:w:{hex_path}:i",
    ]  # fmt: skip


def make_command(bf: BoardFile, build: Path, board_id: str | None = None) -> list[str]:
    """``board_id``: stamped forced (the board takes it over the id it has); without it, a
    fresh random id, taken only by a board that has none (a re-flash keeps its id).  make's own
    fit check is off: the caller makes it (check()), to say it in one line."""
    ident = [f"ID={check_id(board_id)}", "FORCE_ID=1"] if board_id else []
    return [
        "make", "-C", str(AVR_DIR), f"BOARD={bf.path.resolve()}", f"BUILD={build}",
        f"PYTHON={sys.executable}", "CHECK=0", *ident,
    ]  # fmt: skip


#: the stamp's line in make's output (avrstamp.py)
STAMPED = re.compile(r"stamped: fw\.hash ([0-9a-f]{16}), board\.id (\S+)")


def build_checked(bf: BoardFile, build: Path, board_id: str | None = None) -> tuple[AvrSize, str]:
    """Build the firmware into ``build`` and check it fits (DoesNotFit, with the numbers):
    its sizes and make's output."""
    if not AVR_DIR.is_dir():
        raise FlashError(f"the AVR firmware sources are missing from this install ({AVR_DIR})")
    out = _run(make_command(bf, build, board_id), "building the AVR firmware", 300)
    return check(build / bf.name / "firmware.elf", bf.mcu, str(bf.path)), out


def fit(bf: BoardFile) -> tuple[AvrSize, str]:
    """Whether ``bf``'s firmware fits its MCU, built in a scratch directory (gen-firmware): its
    sizes, and its flash budget by part as a table (parts())."""
    with tempfile.TemporaryDirectory(prefix="missing-link-avr-fit-") as tmp:
        size = build_checked(bf, Path(tmp))[0]
        map_text = (Path(tmp) / bf.name / "firmware.map").read_text()
    rows = budget(by_source(map_text), parts(bf), size.flash)
    return size, budget_table(rows, size)


#: what each feature is, in the budget
FEATURE_LABELS = {"timing": "aligned sampling, timed calls", "config": "run-time configuration",
                  "log": "board log"}  # fmt: skip


def parts(bf: BoardFile) -> list[tuple[str, tuple[str, ...]]]:
    """The budget's parts of ``bf``'s image: (label, C sources) for each driver, each feature it
    holds, and the generated tables (the runtime and the C library come after: budget())."""
    out: list[tuple[str, tuple[str, ...]]] = []
    for drv in bf.drivers():
        n = sum(1 for e in bf.transducers if e["driver"] == drv)
        out.append((f"driver {drv}" + (f" x{n}" if n > 1 else ""), DRIVER_SOURCES.get(drv, ())))
    for f in FEATURES:
        if f in bf.features:
            out.append((f"feature {f} ({FEATURE_LABELS[f]})", (f,)))
    out.append(("board tables (board_gen.c)", ("board_gen",)))
    return out


def _run(cmd: list[str], what: str, timeout: float) -> str:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except FileNotFoundError:
        raise FlashError(
            f"cannot run {cmd[0]}: run scripts/system-deps.sh (Debian packages)"
        ) from None
    except subprocess.TimeoutExpired:
        raise FlashError(f"{what} took over {timeout:g} s") from None
    if r.returncode != 0:
        lines = [ln.strip() for ln in (r.stderr + r.stdout).splitlines() if ln.strip()]
        # the first line that says what went wrong (avrdude ends with "avrdude done. Thank you.")
        errors = [ln for ln in lines if "error" in ln.lower()] or lines[-1:]
        raise FlashError(f"{what} failed: {errors[0] if errors else r.returncode}")
    return r.stdout


def flash_avr(
    bf: BoardFile,
    port: str,
    *,
    dry_run: bool,
    say: Callable[[str], None],
    check: bool,
    board_id: str | None = None,
) -> int:
    with tempfile.TemporaryDirectory(prefix="missing-link-avr-") as tmp:
        build = Path(tmp)
        hex_path = build / bf.name / "firmware.hex"
        make = make_command(bf, build, board_id)
        dude = avrdude_command(bf.mcu, port, hex_path)
        if dry_run:
            say(f"would build the C firmware for {bf.mcu}: " + shlex.join(make))
            say("would run: " + shlex.join(dude))
            say(f"then check that serial://{port} answers J2A as {bf.name!r}, with the fw.hash "
                "of the image" + (f" and board.id {board_id}" if board_id else ""))  # fmt: skip
            return 0
        size, out = build_checked(bf, build, board_id)  # (one that cannot fit stops here)
        say(size.line())
        for line in out.splitlines():
            if line.startswith("stamped: "):
                say(line)
        stamped = STAMPED.search(out)
        if stamped is None:
            raise FlashError("building the AVR firmware: no stamp line (fw.hash, board.id)")
        say(f"writing {hex_path.name} to {port} with avrdude ...")
        _run(dude, f"avrdude on {port}", 300)
    if check:
        baud = int(bf.board.get("link", {}).get("baudrate", 115200))
        expect = {"fw.hash": stamped.group(1)}
        if board_id:  # (else the board keeps the id it had, if any)
            expect["board.id"] = board_id
        say(verify(f"serial://{port}?baud={baud}", bf, expect=expect))
    return 0


def build_stamped(bf: BoardFile, build: Path, say: Callable[[str], None]) -> tuple[Path, str]:
    """Build the firmware into ``build`` (``missing-link update``): the image's path and the
    fw.hash it was stamped with (a fresh id, taken only by a board that has none); one that
    cannot fit the MCU is refused before anything is written (DoesNotFit, with the numbers)."""
    size, out = build_checked(bf, build)
    say(size.line())  # the size line
    stamped = STAMPED.search(out)
    if stamped is None:
        raise FlashError("building the AVR firmware: no stamp line (fw.hash, board.id)")
    return build / bf.name / "firmware.hex", stamped.group(1)


def run_avrdude(bf: BoardFile, port: str, hex_path: Path) -> None:
    """Write ``hex_path`` through the board's bootloader (FlashError with avrdude's line)."""
    _run(avrdude_command(bf.mcu, port, hex_path), f"avrdude on {port}", 300)
