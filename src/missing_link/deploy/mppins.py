"""The pins of the MicroPython boards' MCUs (RP2040, ESP32, ESP32-S3), and the check of a board
file's use of them (``check_pins``, run by boardfile.py for ``board --file``, ``flash``,
``gen-firmware`` and ``update``): a pin the MCU has, no pin twice, an ADC pin for what reads a
voltage, an output pin for what drives one, bus pins that the bus can take, PWM outputs that do
not share a channel; each refusal one line naming the transducer, the key and the pin (exit 2).
A strapping pin, or one a module may wire to its PSRAM, is a warning (it works, with care).
The AVR boards' pins are deploy/avrpins.py's (the C runtime's own fixed hardware).

Where the tables come from:

* RP2040 Datasheet (Raspberry Pi Ltd), 1.4.3 "GPIO Functions" and 2.19.2 "Function Select":
  GPIO0..29; function F2 (UART) gives UART n TX on GPIO 4k and RX on 4k+1, n alternating every
  eight pins from UART0 at GPIO0/1, UART1 at GPIO4/5 and GPIO8/9, UART0 at 12/13 and 16/17, ...;
  F3 (I2C) gives I2C (GPIO/2 mod 2) SDA on even and SCL on odd pins; F4 (PWM) slice GPIO/2
  mod 8, channel A on even and B on odd pins (GPIO n and n+16 are one output).  4.9 "ADC":
  inputs 0..3 on GPIO26..29.  No strapping pins (BOOTSEL is the flash's chip select).
* ESP32 Series Datasheet (Espressif), 2.2 "Pin Description" and 3.3 "Strapping Pins"; ESP32
  Technical Reference Manual, 4 "IO MUX and GPIO Matrix"; ESP-IDF "GPIO & RTC GPIO" summary:
  GPIO0..19, 21..23, 25..27, 32..39; 34..39 input only, without pull-up or pull-down; 6..11 the
  module's SPI flash, 16/17 the PSRAM of WROVER modules; strapping GPIO0, 2, 5, 12 (MTDI), 15
  (MTDO); ADC1 on GPIO32..39, ADC2 on GPIO0, 2, 4, 12..15, 25..27, which cannot be read while
  Wi-Fi runs; UART0 (GPIO1 TX, GPIO3 RX) is the USB bridge's; I2C and UART signals go through
  the GPIO matrix to any pin that can take them.
* ESP32-S3 Series Datasheet (Espressif), 2 "Pins" and 3 "Boot Configurations"; ESP-IDF "GPIO &
  RTC GPIO" (esp32s3): GPIO0..21, 26..48; 26..32 the SPI flash and PSRAM, 33..37 an octal
  PSRAM's; strapping GPIO0, 3, 45, 46; ADC1 on GPIO1..10, ADC2 on GPIO11..20; GPIO19/20 the USB
  the REPL runs on.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..board.drivers import driver_class
from ..errors import ConfigError

log = logging.getLogger(__name__)

IN, PULL, OUT, PWM, ADC = "input", "input with a pull-up", "output", "PWM output", "analog input"
#: what each driver does with each pin it takes (the driver's own __init__: board/drivers/)
ROLES: dict[str, dict[str, str]] = {
    "quadrature": {"pin_a": PULL, "pin_b": PULL},
    "digital": {"pin": PULL},
    "sharp_gp2y0a02": {"pin": ADC},
    "analog": {"pin": ADC},
    "battery": {"pin": ADC},
    "servo": {"pin": PWM},
    "trigger": {"pin": OUT},
    "hbridge": {"pwm_pin": PWM, "dir_pin": OUT, "in1": PWM, "in2": PWM},
    "stepper": {"step_pin": OUT, "dir_pin": OUT, "enable_pin": OUT},
    "hcsr04": {"trig_pin": OUT, "echo_pin": IN},
    "gps_nmea": {"tx": OUT, "rx": IN, "pps_pin": IN},
}
#: the drivers whose `pull` option decides whether their input pins need a pull-up
PULLED = ("quadrature", "digital")


@dataclass(frozen=True)
class Mcu:
    name: str
    gpios: frozenset[int]
    flash: frozenset[int] = frozenset()  #: wired to the module's flash: never
    input_only: frozenset[int] = frozenset()  #: no output, no pull-up
    adc: frozenset[int] = frozenset()
    adc_no_wifi: frozenset[int] = frozenset()  #: ADC pins Wi-Fi takes (a tcp link)
    #: pin -> why to take care (strapping, a PSRAM some modules wire): a warning
    care: dict[int, str] = field(default_factory=dict)
    usb: dict[int, str] = field(default_factory=dict)  #: pins a usb link uses
    #: (peripheral, instance, signal, pin) -> why the pin cannot carry it, or None
    routes: Callable[[str, int, str, int], str | None] | None = None
    pwm_slices: bool = False  #: RP2040: PWM outputs pair up in slices (one frequency each)


def _rp2040_route(kind: str, unit: int, signal: str, pin: int) -> str | None:
    """Which GPIOs carry I2C/UART ``unit``'s ``signal`` (2.19.2's function table)."""
    if kind == "i2c":
        ok = [p for p in range(30) if (p // 2) % 2 == unit and p % 2 == (signal == "scl")]
    else:
        offset = 0 if signal == "tx" else 1
        ok = [p for p in range(offset, 30, 4) if ((p - offset + 4) // 8) % 2 == unit]
    if pin in ok:
        return None
    return f"{kind.upper()}{unit} {signal.upper()} is on GPIO {', '.join(map(str, ok))}"


def _esp_route(
    input_only: frozenset[int], units: int
) -> Callable[[str, int, str, int], str | None]:
    def route(kind: str, unit: int, signal: str, pin: int) -> str | None:
        if unit >= (2 if kind == "i2c" else units):
            return f"the MCU has no {kind.upper()}{unit}"
        if pin in input_only and signal != "rx":  # (an I2C line is driven low: an output)
            return f"GPIO {pin} is input only"
        return None

    return route


_ESP32_IN = frozenset(range(34, 40))
_S3_GPIOS = frozenset([*range(0, 22), *range(26, 49)])
MCUS = {
    "rp2040": Mcu("rp2040", frozenset(range(30)), adc=frozenset(range(26, 30)),
                  routes=_rp2040_route, pwm_slices=True),
    "esp32": Mcu(
        "esp32",
        frozenset([*range(0, 20), 21, 22, 23, 25, 26, 27, *range(32, 40)]),
        flash=frozenset(range(6, 12)),
        input_only=_ESP32_IN,
        adc=frozenset([*range(32, 40), 0, 2, 4, 12, 13, 14, 15, 25, 26, 27]),
        adc_no_wifi=frozenset([0, 2, 4, 12, 13, 14, 15, 25, 26, 27]),
        care={0: "a strapping pin (low at reset: the ROM's download mode)",
              2: "a strapping pin (high at reset keeps it from download mode)",
              5: "a strapping pin (the SDIO timing at reset)",
              12: "a strapping pin (MTDI: high at reset selects 1.8 V flash, and most modules "
                  "do not boot)",
              15: "a strapping pin (MTDO: low at reset silences the boot log)",
              16: "the PSRAM's on WROVER modules", 17: "the PSRAM's on WROVER modules"},
        usb={1: "UART0 TX, the USB bridge's", 3: "UART0 RX, the USB bridge's"},
        routes=_esp_route(_ESP32_IN, 3),
    ),
    "esp32s3": Mcu(
        "esp32s3",
        _S3_GPIOS,
        flash=frozenset(range(26, 33)),
        adc=frozenset(range(1, 21)),
        care={0: "a strapping pin (low at reset: download mode)",
              3: "a strapping pin (JTAG source at reset)",
              45: "a strapping pin (VDD_SPI voltage at reset)",
              46: "a strapping pin (low at reset with GPIO0: download mode)",
              **{p: "an octal PSRAM's on R8 modules" for p in range(33, 38)}},
        usb={19: "USB D-, the REPL's", 20: "USB D+, the REPL's"},
        routes=_esp_route(frozenset(), 3),
    ),
}  # fmt: skip


def check_pins(board: dict[str, Any], where: str) -> list[str]:
    """Every pin of a MicroPython board file against its MCU (``board`` already checked by
    form: boardfile.py); ConfigError naming the first wrong one; the warnings, said."""
    mcu = MCUS.get(str(board.get("mcu", "rp2040")))
    if mcu is None:
        return []
    check = _Check(mcu, board, where)
    check.run()
    for line in check.warnings:
        log.warning("%s", line)
    return check.warnings


class _Check:
    def __init__(self, mcu: Mcu, board: dict[str, Any], where: str) -> None:
        self.mcu, self.board, self.where = mcu, board, where
        self.link = board.get("link", {"kind": "usb"})
        self.owner: dict[int, str] = {}  #: pin -> who has it
        self.pwm: dict[tuple[int, int], tuple[int, str]] = {}  #: (slice, ch) -> (pin, who)
        self.freq: dict[int, tuple[float, str]] = {}  #: slice -> (Hz, who)
        self.warnings: list[str] = []

    def fail(self, at: str, pin: int, why: str) -> ConfigError:
        return ConfigError(f"{self.where}: {at} {pin}: {why}")

    def run(self) -> None:
        if self.link.get("kind", "usb") == "usb":
            for pin, what in self.mcu.usb.items():
                self.owner[pin] = f"the usb link's ({what})"
        if self.link.get("kind") == "uart":
            unit = int(self.link.get("id", 0))
            for signal in ("tx", "rx"):
                self._bus("link", "uart", unit, signal, self.link.get(signal))
        for name, bus in self.board.get("buses", {}).items():
            for signal in ("scl", "sda"):
                self._bus(f"bus {name}", "i2c", int(bus.get("id", 0)), signal, bus.get(signal))
        for t in self.board["transducers"]:
            self._entry(t)

    def _bus(self, who: str, kind: str, unit: int, signal: str, pin: Any) -> None:
        if pin is None:
            return
        self._take(f"{who} {signal}", pin, OUT if signal != "rx" else IN)
        why = self.mcu.routes(kind, unit, signal, pin) if self.mcu.routes else None
        if why is not None:
            raise self.fail(f"{who} {signal}", pin, why)

    def _entry(self, t: dict[str, Any]) -> None:
        drv = str(t["driver"])
        defaults = _defaults(drv)
        for key, role in ROLES.get(drv, {}).items():
            pin = t.get(key, defaults.get(key))
            if pin is None:
                continue
            if role == PULL and t.get("pull", defaults.get("pull")) in (None, "none"):
                role = IN
            if drv == "gps_nmea" and key in ("tx", "rx"):
                self._bus(f"{t['name']}: uart", "uart", int(t.get("uart", 0)), key, pin)
                continue
            at = f"{t['name']}: {key}"
            self._take(at, pin, role)
            if role == PWM and self.mcu.pwm_slices:
                self._slice(at, pin, float(t.get("freq", defaults.get("freq", 0))))

    def _take(self, at: str, pin: int, role: str) -> None:
        mcu = self.mcu
        if pin not in mcu.gpios:
            raise self.fail(at, pin, f"the {mcu.name} has no GPIO {pin} ({_spans(mcu.gpios)})")
        if pin in mcu.flash:
            raise self.fail(at, pin, f"GPIO {pin} is wired to the module's flash: not usable")
        if pin in self.owner:
            raise self.fail(at, pin, f"GPIO {pin} is {self.owner[pin]} already")
        self.owner[pin] = at.replace(": ", "'s ", 1) if ": " in at else f"the {at}"
        if pin in mcu.input_only and role not in (IN, ADC):
            why = "no pull-up: pull='none' and a resistor" if role == PULL else "no output"
            raise self.fail(at, pin, f"GPIO {pin} is input only ({why}), not an {role}")
        if role == ADC and pin not in mcu.adc:
            raise self.fail(at, pin, f"GPIO {pin} has no ADC (the {mcu.name}'s: "
                            f"{_spans(mcu.adc)})")  # fmt: skip
        if role == ADC and pin in mcu.adc_no_wifi and self.link.get("kind") == "tcp":
            raise self.fail(at, pin, f"GPIO {pin} is on ADC2, which Wi-Fi takes (a tcp link): "
                            f"an ADC1 pin ({_spans(mcu.adc - mcu.adc_no_wifi)})")  # fmt: skip
        if pin in mcu.care:
            self.warnings.append(f"{self.where}: {at} {pin}: GPIO {pin} is {mcu.care[pin]}")

    def _slice(self, at: str, pin: int, hz: float) -> None:
        """RP2040 PWM: GPIO n and n+16 are one output; a slice's two share one frequency."""
        s, ch = (pin // 2) % 8, pin % 2
        other = self.pwm.get((s, ch))
        if other is not None:
            raise self.fail(at, pin, f"PWM slice {s} {'AB'[ch]} is GPIO {other[0]}'s output "
                            f"already ({other[1]}): one signal")  # fmt: skip
        self.pwm[(s, ch)] = (pin, at)
        if s in self.freq and self.freq[s][0] != hz:
            hz0, who = self.freq[s]
            pair = f"GPIO {2 * s}/{2 * s + 1} and {2 * s + 16}/{2 * s + 17}"
            raise self.fail(at, pin, f"PWM slice {s} ({pair}) runs at {hz0:g} Hz for {who}, "
                            f"not {hz:g} Hz: a slice has one frequency")  # fmt: skip
        self.freq[s] = (hz, at)


def _defaults(drv: str) -> dict[str, Any]:
    params = inspect.signature(driver_class(drv).__init__).parameters
    return {k: p.default for k, p in params.items() if p.default is not inspect.Parameter.empty}


def _spans(pins: frozenset[int]) -> str:
    """GPIO 0..19, 21..23 for a set of pins."""
    out: list[list[int]] = []
    run: list[int] = []
    for p in sorted(pins):
        if run and p != run[-1] + 1:
            out.append(run)
            run = []
        run.append(p)
    out.append(run)
    return "GPIO " + ", ".join(f"{r[0]}..{r[-1]}" if len(r) > 2 else ", ".join(map(str, r))
                               for r in out)  # fmt: skip
