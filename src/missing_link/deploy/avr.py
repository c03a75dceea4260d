"""AVR boards (ATmega328P/2560/32U4): build the C firmware for a board file
(``make -C firmware/avr``, which runs ``gen-firmware``), check that it fits the MCU's flash and
RAM (avrsize.py: refused with the numbers before anything is written), and write it with avrdude
through the Arduino bootloader; then ``flash`` checks the board answers J2A as the board file
says.  ``gen-firmware`` builds it too, to refuse a board file that cannot fit (fit())."""

from __future__ import annotations

import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from .avrsize import AvrSize, check
from .boardfile import BoardFile
from .check import FlashError, verify

#: firmware/avr of the source checkout this package runs from (an editable install)
AVR_DIR = Path(__file__).resolve().parents[3] / "firmware" / "avr"
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


def make_command(bf: BoardFile, build: Path) -> list[str]:
    """make, its own fit check off: the caller makes it (check()), to say it in one line."""
    return [
        "make", "-C", str(AVR_DIR), f"BOARD={bf.path.resolve()}", f"BUILD={build}",
        f"PYTHON={sys.executable}", "CHECK=0",
    ]  # fmt: skip


def build_checked(bf: BoardFile, build: Path) -> AvrSize:
    """Build the firmware into ``build`` and check it fits (DoesNotFit, with the numbers)."""
    if not AVR_DIR.is_dir():
        raise FlashError(f"AVR builds need the missing-link source checkout ({AVR_DIR})")
    _run(make_command(bf, build), "building the AVR firmware", 300)
    return check(build / bf.name / "firmware.elf", bf.mcu, str(bf.path))


def fit(bf: BoardFile) -> AvrSize:
    """Whether ``bf``'s firmware fits its MCU, built in a scratch directory (gen-firmware)."""
    with tempfile.TemporaryDirectory(prefix="missing-link-avr-fit-") as tmp:
        return build_checked(bf, Path(tmp))


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
    bf: BoardFile, port: str, *, dry_run: bool, say: Callable[[str], None], check: bool
) -> int:
    with tempfile.TemporaryDirectory(prefix="missing-link-avr-") as tmp:
        build = Path(tmp)
        hex_path = build / bf.name / "firmware.hex"
        make = make_command(bf, build)
        dude = avrdude_command(bf.mcu, port, hex_path)
        if dry_run:
            say(f"would build the C firmware for {bf.mcu}: " + shlex.join(make))
            say("would run: " + shlex.join(dude))
            say(f"then check that serial://{port} answers J2A as {bf.name!r}")
            return 0
        say(build_checked(bf, build).line())  # (one that cannot fit stops here: DoesNotFit)
        say(f"writing {hex_path.name} to {port} with avrdude ...")
        _run(dude, f"avrdude on {port}", 300)
    if check:
        baud = int(bf.board.get("link", {}).get("baudrate", 115200))
        say(verify(f"serial://{port}?baud={baud}", bf))
    return 0
