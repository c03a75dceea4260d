"""AVR boards (ATmega328P/2560/32U4): build the C firmware for a board file and write it with
avrdude.  The C runtime and its generator live in firmware/avr (see docs/hardware.md)."""

from __future__ import annotations

import shlex
from collections.abc import Callable

from .boardfile import BoardFile

#: avrdude part names and the programmer/baud of the usual Arduino bootloader per MCU
AVRDUDE = {
    "atmega328p": ("m328p", "arduino", 115200),  # Uno, Nano (new bootloader)
    "atmega2560": ("m2560", "wiring", 115200),  # Mega 2560
    "atmega32u4": ("m32u4", "avr109", 57600),  # Leonardo, Micro (Caterina)
}


def avrdude_command(mcu: str, port: str, hex_path: str) -> list[str]:
    part, programmer, baud = AVRDUDE[mcu]
    return [
        "avrdude", "-p", part, "-c", programmer, "-P", port, "-b", str(baud), "-D",
        "-U", f"flash:w:{hex_path}:i",
    ]  # fmt: skip


def flash_avr(
    bf: BoardFile, port: str, *, dry_run: bool, say: Callable[[str], None], check: bool
) -> int:
    hex_path = f"build/avr/{bf.name}/firmware.hex"
    cmd = avrdude_command(bf.mcu, port, hex_path)
    if dry_run:
        say(f"would build {hex_path} for {bf.mcu}: make -C firmware/avr BOARD={bf.path}")
        say("would run: " + shlex.join(cmd))
        return 0
    from .flash import FlashError

    raise FlashError("AVR flashing needs the C firmware build (firmware/avr)")
