"""The pins of the AVR boards the C runtime runs on, by Arduino pin number: the fixed hardware
each driver owns (Timer1's OC1A for the servo, Timer2's OC2A for the trigger, Timer0's OC0A/OC0B
for the H-bridges, USART1 and INT4 for a GPS, the TWI's SDA/SCL), the interrupts a pin has (an
external one, INTn, or its port's pin-change one: an encoder's phases, an echo), and the port
and bit of every digital pin, for the drivers that take any pin (a direction, a step, an echo).

From the ATmega328P and ATmega2560 datasheets' pin descriptions and the Arduino Uno/Nano and
Mega 2560 schematics (Leonardo: the fixed pins only)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class FixedPins:
    twi: tuple[int, int]  #: SDA, SCL
    servo: int  #: OC1A
    board: str
    trigger: int | None = None  #: OC2A: PB3 (Uno D11) / PB4 (Mega D10); none without Timer2
    pwm: tuple[int, int] | None = None  #: Timer0's OC0A, OC0B (the H-bridges)
    gps: tuple[int, int] | None = None  #: USART1 RX, TX (the Uno's only UART is the J2A link)
    pps: int | None = None  #: INT4 (Mega D2)
    #: Arduino pin -> (port letter, bit)
    ports: dict[int, tuple[str, int]] = field(default_factory=dict)
    #: Arduino pin -> n of its external interrupt INTn (any edge: ISCn0)
    ext_int: dict[int, int] = field(default_factory=dict)
    adc0: int | None = None  #: the digital pin of ADC channel 0 (A0)


def _uno() -> dict[int, tuple[str, int]]:
    ports = {d: ("D", d) for d in range(8)}
    ports.update({8 + b: ("B", b) for b in range(6)})
    ports.update({14 + b: ("C", b) for b in range(6)})  # A0..A5
    return ports


def _mega() -> dict[int, tuple[str, int]]:
    ports = {0: ("E", 0), 1: ("E", 1), 2: ("E", 4), 3: ("E", 5), 4: ("G", 5), 5: ("E", 3),
             6: ("H", 3), 7: ("H", 4), 8: ("H", 5), 9: ("H", 6), 10: ("B", 4), 11: ("B", 5),
             12: ("B", 6), 13: ("B", 7), 14: ("J", 1), 15: ("J", 0), 16: ("H", 1), 17: ("H", 0),
             18: ("D", 3), 19: ("D", 2), 20: ("D", 1), 21: ("D", 0), 38: ("D", 7), 39: ("G", 2),
             40: ("G", 1), 41: ("G", 0), 50: ("B", 3), 51: ("B", 2), 52: ("B", 1),
             53: ("B", 0)}  # fmt: skip
    ports.update({22 + b: ("A", b) for b in range(8)})
    ports.update({37 - b: ("C", b) for b in range(8)})  # D30..D37 = PC7..PC0
    ports.update({49 - b: ("L", b) for b in range(8)})  # D42..D49 = PL7..PL0
    ports.update({54 + b: ("F", b) for b in range(8)})  # A0..A7
    ports.update({62 + b: ("K", b) for b in range(8)})  # A8..A15
    return ports


PINS = {
    "atmega328p": FixedPins((18, 19), 9, "Uno/Nano", 11, (6, 5), None, None, _uno(),
                            {2: 0, 3: 1}, 14),
    "atmega2560": FixedPins((20, 21), 11, "Mega 2560", 10, (13, 4), (19, 18), 2, _mega(),
                            {21: 0, 20: 1, 19: 2, 18: 3, 2: 4, 3: 5}, 54),
    # (the Leonardo: its encoder's INT0/INT1 pins only, D3 = PD0 and D2 = PD1)
    "atmega32u4": FixedPins((2, 3), 9, "Leonardo", ports={3: ("D", 0), 2: ("D", 1)},
                            ext_int={3: 0, 2: 1}, adc0=18),
}  # fmt: skip
#: the J2A link's UART: D0/D1 on all three (the Leonardo's Serial1; its USB CDC is not used)
LINK_PINS = (0, 1)

#: pin-change interrupts: port letter -> (PCICR bit, PCMSK register, vector); a pin's PCINT
#: bit is its port bit on these ports
PCINT = {
    "atmega328p": {"B": (0, "PCMSK0", "PCINT0_vect"), "C": (1, "PCMSK1", "PCINT1_vect"),
                   "D": (2, "PCMSK2", "PCINT2_vect")},
    "atmega2560": {"B": (0, "PCMSK0", "PCINT0_vect"), "K": (2, "PCMSK2", "PCINT2_vect")},
}  # fmt: skip


@dataclass(frozen=True)
class PinInterrupt:
    """How a pin interrupts on any change: its vector and the C that enables it."""

    vector: str
    enable: str


def pin_interrupt(pins: FixedPins, mcu: str, pin: int, what: str) -> PinInterrupt:
    """The pin's own external interrupt (INTn), else its port's pin-change interrupt; ValueError
    naming it and the pins that have one if it has neither."""
    if pin in pins.ext_int:
        n = pins.ext_int[pin]
        reg, bit = ("EICRA", 2 * n) if n < 4 else ("EICRB", 2 * (n - 4))
        return PinInterrupt(f"INT{n}_vect", f"{reg} |= 1 << {bit}; EIMSK |= 1 << {n};")
    port, bit = pins.ports.get(pin, ("?", 0))
    if pin in LINK_PINS or port not in PCINT.get(mcu, {}):
        ext = ", ".join(str(p) for p in sorted(pins.ext_int))
        change = [p for p, (port, _b) in pins.ports.items() if port in PCINT.get(mcu, {})]
        beyond = f"; pin-change: {_ranges(sorted(set(change) - set(LINK_PINS)))}" if change else ""
        raise ValueError(
            f"{what}: pin {pin} has no interrupt on the {pins.board} (external: {ext}{beyond})"
        )
    pcie, pcmsk, vect = PCINT[mcu][port]
    return PinInterrupt(vect, f"{pcmsk} |= 1 << {bit}; PCICR |= 1 << {pcie};")


def _ranges(pins: list[int]) -> str:
    """2, 3, 4, 8 -> "2-4, 8" """
    out: list[str] = []
    for p in pins:
        if out and p == int(out[-1].split("-")[-1]) + 1:
            out[-1] = f"{out[-1].split('-')[0]}-{p}"
        else:
            out.append(str(p))
    return ", ".join(out)


def pin_c(pins: FixedPins, pin: int, what: str) -> str:
    """A pin_t initialiser (pins.h) for an Arduino pin; ValueError naming it if there is none."""
    if pin not in pins.ports:
        raise ValueError(f"{what}: the {pins.board} has no digital pin {pin} the runtime knows")
    port, bit = pins.ports[pin]
    return f"{{&PORT{port}, 1 << {bit}}}"
