"""Does an AVR firmware fit its MCU?  Flash (``.text`` + ``.data``'s initial values) within what
the bootloader leaves, and static RAM (``.data`` + ``.bss``) leaving at least STACK bytes for the
stack; when not, one line with the numbers and the biggest consumers (avr-nm), so the user
knows what to drop.  ``make -C firmware/avr`` runs it after linking (``python -m
missing_link.deploy.avrsize ELF MCU STACK``: prints the size line, or the reason on stderr and
exit 1); ``flash`` and ``gen-firmware`` run it in-process before anything is written
(docs/hardware.md, "Memory")."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from .heap import DoesNotFit

#: flash the Arduino bootloader leaves, and RAM, per MCU (bytes)
BUDGETS = {
    "atmega328p": (32_256, 2_048),
    "atmega2560": (253_952, 8_192),
    "atmega32u4": (28_672, 2_560),
}
#: RAM the stack needs at least (the Makefile's STACK): the deepest the firmware's own calls
#: and interrupts go, with room to spare (tests/test_avr_memory.py measures it)
STACK = 384
_RAM_TYPES = set("bBdD")
_FLASH_TYPES = set("tTwW")


@dataclass(frozen=True)
class AvrSize:
    mcu: str
    flash: int
    ram: int

    @property
    def flash_max(self) -> int:
        return BUDGETS[self.mcu][0]

    @property
    def ram_max(self) -> int:
        return BUDGETS[self.mcu][1]

    def line(self) -> str:
        """The size line make prints (tests look for ``<mcu>: flash``)."""
        return (
            f"{self.mcu}: flash {self.flash} of {self.flash_max} bytes, RAM {self.ram} of "
            f"{self.ram_max} bytes (static; {self.ram_max - self.ram} left for the stack)"
        )


def _run(cmd: list[str]) -> str:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, check=True, timeout=60).stdout
    except FileNotFoundError:
        raise DoesNotFit(f"cannot run {cmd[0]}: run scripts/system-deps.sh") from None
    except subprocess.CalledProcessError as e:
        raise DoesNotFit(f"{cmd[0]} failed on {cmd[-1]}: {e.stderr.strip()}") from None


def sizes(elf: Path, mcu: str) -> AvrSize:
    if mcu not in BUDGETS:
        raise DoesNotFit(f"{mcu!r} is not an AVR this firmware knows ({', '.join(BUDGETS)})")
    sections: dict[str, int] = {}
    for line in _run(["avr-size", "-A", str(elf)]).splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[1].isdigit():
            sections[parts[0]] = int(parts[1])
    data = sections.get(".data", 0)
    return AvrSize(mcu, sections.get(".text", 0) + data, data + sections.get(".bss", 0))


def biggest(elf: Path, types: set[str], n: int = 3) -> list[tuple[str, int]]:
    """The ``n`` largest symbols of those ``types`` (avr-nm's letters)."""
    out = []
    for line in _run(["avr-nm", "--size-sort", "-S", "--radix=d", str(elf)]).splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in types:
            out.append((parts[3], int(parts[1])))
    return sorted(out, key=lambda s: -s[1])[:n]


def check(elf: Path, mcu: str, where: str, stack: int = STACK) -> AvrSize:
    """The sizes, or DoesNotFit naming the numbers and the biggest consumers."""
    s = sizes(elf, mcu)
    problems = []
    if s.flash > s.flash_max:
        top = ", ".join(f"{name} {size}" for name, size in biggest(elf, _FLASH_TYPES))
        problems.append(f"flash {s.flash} of {s.flash_max} bytes (biggest code: {top})")
    if s.ram_max - s.ram < stack:
        top = ", ".join(f"{name} {size}" for name, size in biggest(elf, _RAM_TYPES))
        problems.append(
            f"RAM {s.ram} of {s.ram_max} bytes static leaves {s.ram_max - s.ram} for the stack, "
            f"which needs {stack} (biggest in RAM: {top})"
        )
    if problems:
        raise DoesNotFit(
            f"{where}: does not fit the {mcu}: {'; '.join(problems)} (docs/hardware.md, "
            '"Memory": fewer transducers, or a bigger MCU)'
        )
    return s


def main(argv: list[str]) -> int:
    """``python -m missing_link.deploy.avrsize ELF MCU [STACK]`` (the Makefile's check)."""
    elf, mcu = Path(argv[0]), argv[1]
    try:
        print(check(elf, mcu, str(elf), int(argv[2]) if len(argv) > 2 else STACK).line())
    except DoesNotFit as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
