"""Does an AVR firmware fit its MCU?  Flash (``.text`` + ``.data``'s initial values) within what
the bootloader leaves, and static RAM (``.data`` + ``.bss``) leaving at least STACK bytes for the
stack; when not, one line with the numbers and the biggest consumers (avr-nm), so the user
knows what to drop.  ``make -C firmware/avr`` runs it after linking (``python -m
missing_link.deploy.avrsize ELF MCU STACK``: prints the size line, or the reason on stderr and
exit 1); ``flash`` and ``gen-firmware`` run it in-process before anything is written
(docs/hardware.md, "Memory")."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Mapping, Sequence
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


#: an input section's line in the linker's map: name (or on the line before), address, size, file
_MAP_INPUT = re.compile(r"^ (\S+)?\s+0x[0-9a-f]+\s+0x([0-9a-f]+)\s+(\S+)$")
_MAP_OUTPUT = re.compile(r"^(\.\S+)\s+0x[0-9a-f]+\s+0x[0-9a-f]+")
#: what the image holds besides the board's own sources: avr-libc's start-up and the C
#: library's routines (float and 64-bit arithmetic, memcpy, the EEPROM's)
LIBRARY = "C library"


def by_source(map_text: str) -> dict[str, int]:
    """Flash bytes of a linked image by the source they came from, from the linker's map
    (``-Wl,-Map``): every input section placed in ``.text`` or ``.data`` (whose initial values
    are in flash), by its object: ``NAME`` for NAME.o (a C file of the runtime, board_gen),
    LIBRARY for a library member or the start-up code.  board_gen's configuration tables count
    as ``config``'s, its dispatch of timed calls to the hardware as ``timing``'s."""
    out: dict[str, int] = {}
    section = name = ""
    lines = map_text.split("\n")
    start = next((i for i, ln in enumerate(lines) if ln.startswith("Linker script and memory")), 0)
    for line in lines[start:]:
        m = _MAP_OUTPUT.match(line)
        if m:
            section = m.group(1)
            continue
        m = _MAP_INPUT.match(line)
        if m is None:
            name = line.strip() if line.startswith(" .") and " " not in line.strip() else ""
            continue
        name, input_name = "", m.group(1) or name
        if section not in (".text", ".data"):
            continue
        size, obj = int(m.group(2), 16), m.group(3)
        base = Path(obj).name
        key = base[:-2] if base.endswith(".o") and "(" not in base and "/obj/" in obj else LIBRARY
        if key == "board_gen":
            key = _generated_feature(input_name)
        out[key] = out.get(key, 0) + size
    return out


def _generated_feature(section: str) -> str:
    if "config" in section:
        return "config"
    return "timing" if section.endswith(".hardware") else "board_gen"


def budget(
    sources: Mapping[str, int], parts: Sequence[tuple[str, Sequence[str]]], total: int
) -> list[tuple[str, int]]:
    """The image's flash by part: each (label, its sources) of ``parts`` in order, then the
    runtime (every other source), the C library, and what the linker added between them
    (alignment: the image's total less the sources')."""
    left = dict(sources)
    out = []
    for label, names in parts:
        out.append((label, sum(left.pop(n, 0) for n in names)))
    lib = left.pop(LIBRARY, 0)
    out.append(("runtime", sum(left.values())))
    out.append((LIBRARY + " (float, 64-bit arithmetic, start-up)", lib))
    rest = total - sum(sources.values())
    if rest:
        out.append(("linker (alignment)", rest))
    return out


def budget_table(rows: list[tuple[str, int]], size: AvrSize) -> str:
    """The budget as text: a line a part, bytes and share of the MCU's flash."""
    width = max(len(label) for label, _n in rows)
    lines = [f"  {label:<{width}} {n:>6} B {100 * n / size.flash_max:5.1f} %" for label, n in rows]
    share = 100 * size.flash / size.flash_max
    lines.append(f"  {'image':<{width}} {size.flash:>6} B {share:5.1f} % of {size.flash_max}")
    return "\n".join(lines)


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
