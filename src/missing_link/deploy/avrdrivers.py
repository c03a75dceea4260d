"""What each board file entry adds to an AVR board's ``board_gen.c``: its driver's set-up, its
poll, its J2A function, its interrupts, its place in the failsafe (deploy/avrgen.py puts the
parts together).  The C drivers own hardware (timers, interrupts, a UART), so most exist once and
on fixed pins (avrpins.py); what an entry asks that the MCU cannot do is refused here, naming
the entry, and so is a pin two entries (or an entry and the J2A link) would share."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field
from typing import Any

from ..board.drivers import battery, mpu6050
from ..board.runtime import Transducer
from ..errors import ConfigError
from .avrpins import LINK_PINS, PCINT, FixedPins, pin_c, pin_interrupt
from .cgen import c_comment, c_ident, c_text

#: the drivers of the C runtime, and how many of each a board may have
AVR_DRIVERS = {"quadrature": 8, "sharp_gp2y0a02": 1, "srf02": 1, "servo": 1, "trigger": 1,
               "hbridge": 2, "stepper": 1, "hcsr04": 1, "gps_nmea": 1, "battery": 1,
               "mpu6050": 2}  # fmt: skip
#: the C sources (firmware/avr/src/NAME.c) each driver's code is in: an image links those of
#: the drivers its board file names, and no other (avrgen.sources)
DRIVER_SOURCES = {"quadrature": ("quadrature",), "sharp_gp2y0a02": ("sharp",),
                  "srf02": ("srf02", "twi"), "servo": ("servo",), "trigger": ("trigger",),
                  "hbridge": ("hbridge",), "stepper": ("stepper",), "hcsr04": ("hcsr04",),
                  "gps_nmea": ("gps_nmea",), "battery": ("battery",),
                  "mpu6050": ("mpu6050", "twi")}  # fmt: skip


@dataclass
class Part:
    setup: list[str] = field(default_factory=list)
    polls: list[str] = field(default_factory=list)
    decls: list[str] = field(default_factory=list)
    funcs: list[tuple[str, str]] = field(default_factory=list)  #: (J2A name, C function)
    hardware: list[tuple[str, str, str]] = field(default_factory=list)  #: timed by the timer
    make_safe: str | None = None  #: the failsafe's C function for this actuator
    #: (interrupt vector, a statement of its routine): board_gen.c gathers them by vector
    isrs: list[tuple[str, str]] = field(default_factory=list)
    #: (C condition over v[{key}], why) a run-time set must keep (config.c refuses otherwise)
    checks: list[tuple[str, str]] = field(default_factory=list)

    def gather(self, entry: Part) -> None:
        """Append an entry's code to this, every entry's before it (its ``make_safe`` and
        ``checks`` are its own: avrgen keeps them by the entry's index)."""
        self.setup += entry.setup
        self.polls += entry.polls
        self.decls += entry.decls
        self.funcs += entry.funcs
        self.hardware += entry.hardware
        self.isrs += entry.isrs


def gated(k: int, name: str, fn: str) -> str:
    """An actuator's J2A function that refuses while its transducer is disabled (config.c); a
    command it takes arms the failsafe for it (failsafe.c)."""
    why = c_text(f"{name} is disabled")
    return (
        f"static uint8_t call_{k}(const uint8_t *in, uint8_t n, uint8_t *out, "
        f"uint8_t *out_n) {{ /* refused while {c_comment(name)} is disabled (config.c) */\n"
        f"    if (!board_transducers[{k}].enabled) {{\n"
        f"        static const char why[] PROGMEM = {why};\n"
        "        strcpy_P((char *)out, why);\n"
        "        *out_n = sizeof why - 1;\n"
        "        return 0xFF;\n"
        "    }\n"
        f"    uint8_t code = {c_ident(fn, name)}(in, n, out, out_n);\n"
        f"    if (code == 0) failsafe_arm({k});\n"
        "    return code;\n"
        "}"
    )


def _f(x: Any) -> str:
    value = float(x)
    if not math.isfinite(value):
        raise ValueError(f"{x!r} is not a finite number")
    return f"{value!r}f"


@dataclass
class Entry:
    """One board file entry on its way to C: what each driver's maker needs."""

    k: int  #: its index in board_transducers[]
    e: dict[str, Any]
    t: Transducer
    pins: FixedPins
    mcu: str
    inst: int  #: the inst-th of its driver
    at: str  #: names it in errors
    #: digital pin -> who has it, shared by every entry of the board (claim())
    claims: dict[int, str] = field(default_factory=dict)
    p: Part = field(default_factory=Part)

    @property
    def tref(self) -> str:
        return f"&board_transducers[{self.k}]"

    @property
    def enabled(self) -> str:
        return f"board_transducers[{self.k}].enabled"

    @property
    def rate(self) -> float:
        default = {"quadrature": 50, "sharp_gp2y0a02": 25, "battery": 1, "mpu6050": 100}.get(
            self.e["driver"], 10
        )
        return float(self.e.get("rate_hz", default))

    def pin(self, key: str) -> str:
        """The pin_t of the entry's pin ``key``, claimed for it."""
        try:
            c = pin_c(self.pins, int(self.e[key]), f"{self.at}: {key}")
        except ValueError as err:
            raise ConfigError(str(err)) from None
        self.claim(int(self.e[key]), key)
        return c

    def claim(self, pin: int, what: str, shared: str = "") -> None:
        """Pin ``pin`` is this entry's (``what``: which of its pins); ConfigError naming the one
        that has it already.  ``shared``: a bus its other users may claim too (the TWI)."""
        mine = shared or f"{self.t.name} ({what})"
        had = self.claims.setdefault(pin, mine)
        if had != mine:
            raise ConfigError(f"{self.at}: {what} {pin} is {had}'s already")

    def adc(self) -> int:
        """The entry's ADC channel (``pin``: 0..7 = A0..A7), its digital pin claimed."""
        ch = int(self.e["pin"])
        if not 0 <= ch <= 7:
            raise ConfigError(f"{self.at}: pin is the ADC channel on AVR (0..7 = A0..A7)")
        if self.pins.adc0 is not None:
            self.claim(self.pins.adc0 + ch, f"pin (A{ch})")
        return ch

    def twi(self) -> None:
        """The TWI's SDA and SCL, shared by the parts on it."""
        for pin, what in zip(self.pins.twi, ("SDA", "SCL"), strict=True):
            self.claim(pin, f"{what} (the TWI)", shared="the TWI bus")

    def actuator(self, fn: str) -> None:
        self.p.funcs.append((c_ident(self.t.options["call"], f"{self.at}: call"), f"call_{self.k}"))
        self.p.decls.append(gated(self.k, self.t.name, fn))


def part_of(
    k: int,
    e: dict[str, Any],
    t: Transducer,
    pins: FixedPins,
    mcu: str,
    inst: int,
    at: str,
    claims: dict[int, str],
) -> Part:
    """The part of entry ``e`` (transducer index ``k``, the ``inst``-th of its driver); ``claims``:
    the board's pins so far (link_claims() to start), this entry's added."""
    x = Entry(k, e, t, pins, mcu, inst, at, claims)
    MAKERS[e["driver"]](x)
    return x.p


def link_claims() -> dict[int, str]:
    """The pins every AVR board has taken: the J2A link's UART."""
    return {pin: "the J2A link" for pin in LINK_PINS}


def _quadrature(x: Entry) -> None:
    """Each phase's pin interrupts on any change: its own INTn, else its port's pin-change
    interrupt (avrpins.pin_interrupt); their routines (board_gen.c) decode it."""
    e, q = x.e, f"quad_{x.inst}"
    ints = []
    for key in ("pin_a", "pin_b"):
        try:
            ints.append(pin_interrupt(x.pins, x.mcu, int(e[key]), f"{x.at}: {key}"))
        except ValueError as err:
            raise ConfigError(str(err)) from None
    x.p.decls.append(f"static quadrature_t {q};")
    x.p.setup.append(
        f"quadrature_init(&{q}, {x.tref}, (pin_t){x.pin('pin_a')}, (pin_t){x.pin('pin_b')}, "
        f"{int(x.rate)}, {1 if e.get('reverse') else 0});"
    )
    x.p.setup += [i.enable for i in ints]
    x.p.polls.append(f"if ({x.enabled}) quadrature_poll(&{q}, now);")
    x.p.isrs += [(i.vector, f"quadrature_edge(&{q});") for i in ints]


def _sharp(x: Entry) -> None:
    x.p.setup.append(f"sharp_init({x.tref}, {x.adc()}, {int(x.rate)});")
    x.p.polls.append(f"if ({x.enabled}) sharp_poll(now);")


def _srf02(x: Entry) -> None:
    x.twi()
    x.p.setup.append(
        f"srf02_init({x.tref}, 0x{int(x.e.get('address', 0x70)):02x}, {int(x.rate)}, "
        f"{int(x.e.get('min_range', 16))});"
    )
    x.p.polls.append(f"if ({x.enabled}) srf02_poll(now);")


def _trigger(x: Entry) -> None:
    pins = x.pins
    if pins.trigger is None:
        raise ConfigError(f"{x.at}: the {pins.board} has no Timer2 for a timed trigger")
    if int(x.e["pin"]) != pins.trigger:
        raise ConfigError(
            f"{x.at}: on the {pins.board} the trigger is on pin {pins.trigger} "
            "(OC2A: its edges are made by Timer2's compare)"
        )
    x.claim(pins.trigger, "pin (OC2A)")
    x.p.setup.append(f"trigger_init({x.tref}, {int(x.e.get('pulse_us', 10))});")
    x.p.setup.append("timing_hardware = hardware;")
    x.p.polls.append(f"if ({x.enabled}) trigger_poll(now);")
    x.actuator("trigger_command")
    x.p.hardware.append((str(x.t.options["call"]), x.enabled, "trigger_at"))


def _servo(x: Entry) -> None:
    e, pins = x.e, x.pins
    if int(e["pin"]) != pins.servo:
        raise ConfigError(f"{x.at}: on the {pins.board} the servo is on pin {pins.servo} (OC1A)")
    x.claim(pins.servo, "pin (OC1A)")
    x.p.setup.append(
        f"servo_init({x.tref}, {int(e.get('min_us', 900))}, {int(e.get('max_us', 2100))}, "
        f"{int(e.get('centre_us', 1500))}, {int(e.get('span_us', 1200))}, "
        f"{1 if e.get('safe', 'hold') == 'limp' else 0});"
    )
    x.actuator("servo_command")
    x.p.make_safe = "servo_make_safe"


def _stepper(x: Entry) -> None:
    e = x.e
    en = "enable_pin" in e
    x.p.setup.append(
        f"stepper_init({x.tref}, (pin_t){x.pin('step_pin')}, (pin_t){x.pin('dir_pin')}, "
        f"(pin_t){x.pin('enable_pin') if en else '{0, 0}'}, {1 if en else 0}, "
        f"{int(e.get('steps_per_rev', 200)) * int(e.get('microsteps', 1))}, "
        f"{_f(e.get('max_speed', 2.0))}, {_f(e.get('accel', 4.0))}, "
        f"{1 if e.get('mode', 'position') == 'velocity' else 0}, "
        f"{1 if e.get('invert') else 0});"
    )
    x.p.polls.append(f"if ({x.enabled}) stepper_poll(now);")
    x.actuator("stepper_command")
    x.p.make_safe = "stepper_make_safe"


def _hcsr04(x: Entry) -> None:
    e, pins, mcu = x.e, x.pins, x.mcu
    echo = int(e["echo_pin"])
    port = pins.ports.get(echo, ("?", 0))[0]
    if port not in PCINT.get(mcu, {}):
        raise ConfigError(
            f"{x.at}: echo_pin {echo} has no pin-change interrupt on the {pins.board} "
            f"(ports {', '.join(PCINT.get(mcu, {})) or 'none'})"
        )
    pcie, pcmsk, vect = PCINT[mcu][port]
    x.claim(echo, "echo_pin")
    x.p.setup.append(
        f"hcsr04_init({x.tref}, (pin_t){x.pin('trig_pin')}, (pin_t){pin_c(pins, echo, '')}, "
        f"{pcie}, &{pcmsk}, {_f(x.rate)}, {_f(e.get('temperature_c', 20.0))}, "
        f"{int(e.get('max_range_cm', 400))});"
    )
    x.p.polls.append(f"if ({x.enabled}) hcsr04_poll(now);")
    x.p.isrs.append((vect, "hcsr04_edge();"))


def _gps(x: Entry) -> None:
    e, pins = x.e, x.pins
    if pins.gps is None:
        raise ConfigError(
            f"{x.at}: the {pins.board}'s only UART is the J2A link: a GPS needs a Mega "
            "(USART1, RX1 D19)"
        )
    pps = e.get("pps_pin")
    if pps is not None and int(pps) != pins.pps:
        raise ConfigError(f"{x.at}: on the {pins.board} the PPS input is pin {pins.pps} (INT4)")
    if int(e.get("uart", 1)) != 1:
        raise ConfigError(f"{x.at}: the AVR runtime reads a GPS on uart 1 (USART1)")
    x.claim(pins.gps[0], "RX1")
    x.claim(pins.gps[1], "TX1")
    if pps is not None:
        x.claim(int(pps), "pps_pin (INT4)")
    x.p.setup.append(
        f"gps_init({x.tref}, {int(e.get('baud', 9600))}UL, {0 if pps is None else 1});"
    )
    x.p.polls.append(f"if ({x.enabled}) gps_poll(now);")


def _hbridge(x: Entry) -> None:
    e, pins, inst, p = x.e, x.pins, x.inst, x.p
    if pins.pwm is None:
        raise ConfigError(f"{x.at}: the {pins.board} runtime has no PWM timer for a motor")
    a, b = pins.pwm
    if "in1" in e:
        if (int(e["in1"]), int(e["in2"])) != (a, b) or inst:
            raise ConfigError(
                f"{x.at}: on the {pins.board} an IN1/IN2 bridge is on pins {a} and {b} "
                "(Timer0's OC0A/OC0B), and it is the only one"
            )
        x.claim(a, "in1 (OC0A)")
        x.claim(b, "in2 (OC0B)")
        out, dirpin = 2, "{0, 0}"
    else:
        pwm = int(e["pwm_pin"])
        if pwm not in (a, b):
            raise ConfigError(
                f"{x.at}: on the {pins.board} a motor's pwm_pin is {a} or {b} (Timer0's OC0A/OC0B)"
            )
        x.claim(pwm, "pwm_pin")
        out, dirpin = (0 if pwm == a else 1), x.pin("dir_pin")
    stop = e.get("stop", "coast")
    if out < 2:
        why = "stop = brake needs in1 and in2 (a PWM/DIR bridge coasts)"
        if stop == "brake":
            raise ConfigError(f"{x.at}: {why}")
        p.checks.append(("v[{stop}] == 0", why))
    p.setup.append(
        f"hbridge_init({inst}, {x.tref}, {out}, (pin_t){dirpin}, {_f(e.get('ramp', 4.0))}, "
        f"{1 if stop == 'brake' else 0}, {1 if e.get('invert') else 0}, "
        f"{int(e.get('freq', 20000))}UL);"
    )
    p.polls.append(f"if ({x.enabled}) hbridge_poll({inst}, now);")
    p.decls.append(
        f"static uint8_t motor_{inst}(const uint8_t *in, uint8_t n, uint8_t *out, "
        f"uint8_t *out_n) {{ return hbridge_command({inst}, in, n, out, out_n); }}"
    )
    p.decls.append(f"static void motor_safe_{inst}(void) {{ hbridge_make_safe({inst}); }}")
    x.actuator(f"motor_{inst}")
    p.make_safe = f"motor_safe_{inst}"


def _mpu6050(x: Entry) -> None:
    """Two at most (AD0 low and high: 0x68, 0x69), on the TWI; the Python driver's ranges."""
    e, m = x.e, f"mpu_{x.inst}"
    accel, gyro, dlpf = e.get("accel_g", 2), e.get("gyro_dps", 250), e.get("dlpf", 3)
    if accel not in mpu6050.ACCEL_RANGES or gyro not in mpu6050.GYRO_RANGES:
        raise ConfigError(
            f"{x.at}: accel_g in {mpu6050.ACCEL_RANGES}, gyro_dps in {mpu6050.GYRO_RANGES}"
        )
    if not (isinstance(dlpf, int) and 0 <= dlpf <= 6):
        raise ConfigError(f"{x.at}: dlpf 0..6")
    x.twi()
    x.p.decls.append(f"static mpu6050_t {m};")
    x.p.setup.append(
        f"mpu6050_init(&{m}, {x.tref}, 0x{int(e.get('address', 0x68)):02x}, {int(x.rate)}, "
        f"{mpu6050.ACCEL_RANGES.index(accel)}, {mpu6050.GYRO_RANGES.index(gyro)}, {dlpf});"
    )
    x.p.polls.append(f"if ({x.enabled}) mpu6050_poll(&{m}, now);")


def _battery(x: Entry) -> None:
    """The Python driver's checks and curves (board/drivers/battery.py: its single source); the
    ADC's reference is AVcc, 5 V on every AVR board here unless the entry's vref says else."""
    e = x.e
    channel = x.adc()
    params = inspect.signature(battery.Battery.__init__).parameters

    def get(key: str) -> Any:
        return e.get(key, params[key].default)

    top, bottom = float(get("r_top")), float(get("r_bottom"))
    empty, full = float(get("cell_empty")), float(get("cell_full"))
    chemistry, cells, reads = get("chemistry"), int(get("cells")), int(get("reads"))
    vref = e.get("vref", 5.0)  # (not the Python default: that is a 3.3 V MicroPython board's)
    if not (top >= 0 and bottom > 0):
        raise ConfigError(f"{x.at}: r_top >= 0 and r_bottom > 0 (ohms)")
    if chemistry not in battery.CHEMISTRIES:
        raise ConfigError(f"{x.at}: chemistry one of {', '.join(battery.CHEMISTRIES)}")
    if not (1 <= cells <= 24 and full > empty > 0):
        raise ConfigError(f"{x.at}: cells 1..24 and cell_full > cell_empty > 0")
    if not 0 < float(vref) <= 5.5:
        raise ConfigError(f"{x.at}: vref is AVcc's voltage on AVR (0..5.5 V)")
    if not 1 <= reads <= 9:  # (battery.h: BATTERY_MAX_READS)
        raise ConfigError(f"{x.at}: reads 1..9 on AVR")
    curves = [battery.CURVES[c] for c in battery.CHEMISTRIES[:-1]] + [((empty, 0.0), (full, 1.0))]
    starts = [sum(len(c) for c in curves[:i]) for i in range(len(curves) + 1)]
    points = ", ".join(f"{_f(v)}, {_f(f)}" for curve in curves for v, f in curve)
    x.p.decls += [
        "/* the battery's curves, (volts a cell, charge), from board/drivers/battery.py */",
        f"static const float battery_points[] PROGMEM = {{{points}}};",
        f"static const uint8_t battery_starts[] = {{{', '.join(map(str, starts))}}};",
    ]
    x.p.setup.append(
        f"battery_init({x.tref}, {channel}, {_f(min(x.rate, 100.0))}, {_f(vref)}, "
        f"{_f((top + bottom) / bottom)}, {cells}, {battery.CHEMISTRIES.index(chemistry)}, "
        f"{reads}, battery_points, battery_starts);"
    )
    x.p.polls.append(f"if ({x.enabled}) battery_poll(now);")


#: the driver's part maker, by the board file's driver name
MAKERS = {"quadrature": _quadrature, "sharp_gp2y0a02": _sharp, "srf02": _srf02,
          "trigger": _trigger, "servo": _servo, "hbridge": _hbridge, "stepper": _stepper,
          "hcsr04": _hcsr04, "gps_nmea": _gps, "battery": _battery,
          "mpu6050": _mpu6050}  # fmt: skip
