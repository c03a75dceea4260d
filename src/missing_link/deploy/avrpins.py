"""The pins of the AVR boards the C runtime runs on, by Arduino pin number: the fixed hardware
each driver owns (INT0/INT1 for the encoder, Timer1's OC1A for the servo, Timer2's OC2A for the
trigger, Timer0's OC0A/OC0B for the H-bridges, USART1 and INT4 for a GPS), and the port and bit
of every digital pin, for the drivers that take any pin (a direction, a step, an echo).

From the ATmega328P and ATmega2560 datasheets' pin descriptions and the Arduino Uno/Nano and
Mega 2560 schematics (Leonardo: the fixed pins only)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class FixedPins:
    quad: tuple[int, int]  #: INT0, INT1
    servo: int  #: OC1A
    board: str
    trigger: int | None = None  #: OC2A: PB3 (Uno D11) / PB4 (Mega D10); none without Timer2
    pwm: tuple[int, int] | None = None  #: Timer0's OC0A, OC0B (the H-bridges)
    gps: tuple[int, int] | None = None  #: USART1 RX, TX (the Uno's only UART is the J2A link)
    pps: int | None = None  #: INT4 (Mega D2)
    #: Arduino pin -> (port letter, bit)
    ports: dict[int, tuple[str, int]] = field(default_factory=dict)


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
    "atmega328p": FixedPins((2, 3), 9, "Uno/Nano", 11, (6, 5), None, None, _uno()),
    "atmega2560": FixedPins((21, 20), 11, "Mega 2560", 10, (13, 4), (19, 18), 2, _mega()),
    "atmega32u4": FixedPins((3, 2), 9, "Leonardo"),
}

#: pin-change interrupts: port letter -> (PCICR bit, PCMSK register, vector); a pin's PCINT
#: bit is its port bit on these ports
PCINT = {
    "atmega328p": {"B": (0, "PCMSK0", "PCINT0_vect"), "C": (1, "PCMSK1", "PCINT1_vect"),
                   "D": (2, "PCMSK2", "PCINT2_vect")},
    "atmega2560": {"B": (0, "PCMSK0", "PCINT0_vect"), "K": (2, "PCMSK2", "PCINT2_vect")},
}  # fmt: skip


def pin_c(pins: FixedPins, pin: int, what: str) -> str:
    """A pin_t initialiser (pins.h) for an Arduino pin; ValueError naming it if there is none."""
    if pin not in pins.ports:
        raise ValueError(f"{what}: the {pins.board} has no digital pin {pin} the runtime knows")
    port, bit = pins.ports[pin]
    return f"{{&PORT{port}, 1 << {bit}}}"
