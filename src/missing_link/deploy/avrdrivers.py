"""What each board file entry adds to an AVR board's ``board_gen.c``: its driver's set-up, its
poll, its J2A function, its interrupt, its place in the failsafe (deploy/avrgen.py puts the
parts together).  The C drivers own hardware (timers, interrupts, a UART), so most exist once and
on fixed pins (avrpins.py); what an entry asks that the MCU cannot do is refused here, naming
the entry."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..board.runtime import Transducer
from ..errors import ConfigError
from .avrpins import PCINT, FixedPins, pin_c

#: the drivers of the C runtime, and how many of each a board may have
AVR_DRIVERS = {"quadrature": 1, "sharp_gp2y0a02": 1, "srf02": 1, "servo": 1, "trigger": 1,
               "hbridge": 2, "stepper": 1, "hcsr04": 1, "gps_nmea": 1}  # fmt: skip


@dataclass
class Part:
    setup: list[str] = field(default_factory=list)
    polls: list[str] = field(default_factory=list)
    decls: list[str] = field(default_factory=list)
    funcs: list[tuple[str, str]] = field(default_factory=list)  #: (J2A name, C function)
    hardware: list[tuple[str, str, str]] = field(default_factory=list)  #: timed by the timer
    make_safe: str | None = None  #: the failsafe's C function for this actuator
    isrs: list[str] = field(default_factory=list)
    #: (C condition over v[{key}], why) a run-time set must keep (config.c refuses otherwise)
    checks: list[tuple[str, str]] = field(default_factory=list)


def gated(k: int, name: str, fn: str) -> str:
    """An actuator's J2A function that refuses while its transducer is disabled (config.c); a
    command it takes arms the failsafe for it (failsafe.c)."""
    return (
        f"static uint8_t call_{k}(const uint8_t *in, uint8_t n, uint8_t *out, "
        f"uint8_t *out_n) {{ /* refused while {name} is disabled (config.c) */\n"
        f"    if (!board_transducers[{k}].enabled) {{\n"
        f'        static const char why[] PROGMEM = "{name} is disabled";\n'
        "        strcpy_P((char *)out, why);\n"
        "        *out_n = sizeof why - 1;\n"
        "        return 0xFF;\n"
        "    }\n"
        f"    uint8_t code = {fn}(in, n, out, out_n);\n"
        f"    if (code == 0) failsafe_arm({k});\n"
        "    return code;\n"
        "}"
    )


def _f(x: Any) -> str:
    return f"{float(x)!r}f"


def part_of(
    k: int, e: dict[str, Any], t: Transducer, pins: FixedPins, mcu: str, inst: int, at: str
) -> Part:
    """The part of entry ``e`` (transducer index ``k``, the ``inst``-th of its driver)."""
    drv = e["driver"]
    p = Part()
    tref = f"&board_transducers[{k}]"
    enabled = f"board_transducers[{k}].enabled"
    rate = float(e.get("rate_hz", {"quadrature": 50, "sharp_gp2y0a02": 25}.get(drv, 10)))

    def pin(key: str) -> str:
        try:
            return pin_c(pins, int(e[key]), f"{at}: {key}")
        except ValueError as err:
            raise ConfigError(str(err)) from None

    def actuator(fn: str) -> None:
        p.funcs.append((str(t.options["call"]), f"call_{k}"))
        p.decls.append(gated(k, t.name, fn))

    if drv == "quadrature":
        if (e["pin_a"], e["pin_b"]) != pins.quad:
            raise ConfigError(
                f"{at}: on the {pins.board} the encoder is on pins {pins.quad[0]} and "
                f"{pins.quad[1]} (INT0/INT1), not {e['pin_a']} and {e['pin_b']}"
            )
        p.setup.append(f"quadrature_init({tref}, {int(rate)}, {1 if e.get('reverse') else 0});")
        p.polls.append(f"if ({enabled}) quadrature_poll(now);")
    elif drv == "sharp_gp2y0a02":
        if not 0 <= int(e["pin"]) <= 7:
            raise ConfigError(f"{at}: pin is the ADC channel on AVR (0..7 = A0..A7)")
        p.setup.append(f"sharp_init({tref}, {int(e['pin'])}, {int(rate)});")
        p.polls.append(f"if ({enabled}) sharp_poll(now);")
    elif drv == "srf02":
        p.setup.append(
            f"srf02_init({tref}, 0x{int(e.get('address', 0x70)):02x}, {int(rate)}, "
            f"{int(e.get('min_range', 16))});"
        )
        p.polls.append(f"if ({enabled}) srf02_poll(now);")
    elif drv == "trigger":
        if pins.trigger is None:
            raise ConfigError(f"{at}: the {pins.board} has no Timer2 for a timed trigger")
        if int(e["pin"]) != pins.trigger:
            raise ConfigError(
                f"{at}: on the {pins.board} the trigger is on pin {pins.trigger} "
                "(OC2A: its edges are made by Timer2's compare)"
            )
        p.setup.append(f"trigger_init({tref}, {int(e.get('pulse_us', 10))});")
        p.setup.append("timing_hardware = hardware;")
        p.polls.append(f"if ({enabled}) trigger_poll(now);")
        actuator("trigger_command")
        p.hardware.append((str(t.options["call"]), enabled, "trigger_at"))
    elif drv == "servo":
        if int(e["pin"]) != pins.servo:
            raise ConfigError(f"{at}: on the {pins.board} the servo is on pin {pins.servo} (OC1A)")
        p.setup.append(
            f"servo_init({tref}, {int(e.get('min_us', 900))}, {int(e.get('max_us', 2100))}, "
            f"{int(e.get('centre_us', 1500))}, {int(e.get('span_us', 1200))}, "
            f"{1 if e.get('safe', 'hold') == 'limp' else 0});"
        )
        actuator("servo_command")
        p.make_safe = "servo_make_safe"
    elif drv == "hbridge":
        _hbridge(p, k, e, t, pins, inst, at, tref, enabled, pin)
    elif drv == "stepper":
        en = "enable_pin" in e
        p.setup.append(
            f"stepper_init({tref}, (pin_t){pin('step_pin')}, (pin_t){pin('dir_pin')}, "
            f"(pin_t){pin('enable_pin') if en else '{0, 0}'}, {1 if en else 0}, "
            f"{int(e.get('steps_per_rev', 200)) * int(e.get('microsteps', 1))}, "
            f"{_f(e.get('max_speed', 2.0))}, {_f(e.get('accel', 4.0))}, "
            f"{1 if e.get('mode', 'position') == 'velocity' else 0}, "
            f"{1 if e.get('invert') else 0});"
        )
        p.polls.append(f"if ({enabled}) stepper_poll(now);")
        actuator("stepper_command")
        p.make_safe = "stepper_make_safe"
    elif drv == "hcsr04":
        echo = int(e["echo_pin"])
        port = pins.ports.get(echo, ("?", 0))[0]
        if port not in PCINT.get(mcu, {}):
            raise ConfigError(
                f"{at}: echo_pin {echo} has no pin-change interrupt on the {pins.board} "
                f"(ports {', '.join(PCINT.get(mcu, {})) or 'none'})"
            )
        pcie, pcmsk, vect = PCINT[mcu][port]
        p.setup.append(
            f"hcsr04_init({tref}, (pin_t){pin('trig_pin')}, (pin_t){pin('echo_pin')}, {pcie}, "
            f"&{pcmsk}, {_f(rate)}, {_f(e.get('temperature_c', 20.0))}, "
            f"{int(e.get('max_range_cm', 400))});"
        )
        p.polls.append(f"if ({enabled}) hcsr04_poll(now);")
        p.isrs.append(f"ISR({vect}) {{ hcsr04_edge(); }}")
    elif drv == "gps_nmea":
        if pins.gps is None:
            raise ConfigError(
                f"{at}: the {pins.board}'s only UART is the J2A link: a GPS needs a Mega "
                "(USART1, RX1 D19)"
            )
        pps = e.get("pps_pin")
        if pps is not None and int(pps) != pins.pps:
            raise ConfigError(f"{at}: on the {pins.board} the PPS input is pin {pins.pps} (INT4)")
        if int(e.get("uart", 1)) != 1:
            raise ConfigError(f"{at}: the AVR runtime reads a GPS on uart 1 (USART1)")
        p.setup.append(
            f"gps_init({tref}, {int(e.get('baud', 9600))}UL, {0 if pps is None else 1});"
        )
        p.polls.append(f"if ({enabled}) gps_poll(now);")
    return p


def _hbridge(
    p: Part,
    k: int,
    e: dict[str, Any],
    t: Transducer,
    pins: FixedPins,
    inst: int,
    at: str,
    tref: str,
    enabled: str,
    pin: Any,
) -> None:
    if pins.pwm is None:
        raise ConfigError(f"{at}: the {pins.board} runtime has no PWM timer for a motor")
    a, b = pins.pwm
    if "in1" in e:
        if (int(e["in1"]), int(e["in2"])) != (a, b) or inst:
            raise ConfigError(
                f"{at}: on the {pins.board} an IN1/IN2 bridge is on pins {a} and {b} (Timer0's "
                "OC0A/OC0B), and it is the only one"
            )
        out, dirpin = 2, "{0, 0}"
    else:
        pwm = int(e["pwm_pin"])
        if pwm not in (a, b):
            raise ConfigError(
                f"{at}: on the {pins.board} a motor's pwm_pin is {a} or {b} (Timer0's OC0A/OC0B)"
            )
        out, dirpin = (0 if pwm == a else 1), pin("dir_pin")
    stop = e.get("stop", "coast")
    if out < 2:
        why = "stop = brake needs in1 and in2 (a PWM/DIR bridge coasts)"
        if stop == "brake":
            raise ConfigError(f"{at}: {why}")
        p.checks.append(("v[{stop}] == 0", why))
    p.setup.append(
        f"hbridge_init({inst}, {tref}, {out}, (pin_t){dirpin}, {_f(e.get('ramp', 4.0))}, "
        f"{1 if stop == 'brake' else 0}, {1 if e.get('invert') else 0}, "
        f"{int(e.get('freq', 20000))}UL);"
    )
    p.polls.append(f"if ({enabled}) hbridge_poll({inst}, now);")
    p.decls.append(
        f"static uint8_t motor_{inst}(const uint8_t *in, uint8_t n, uint8_t *out, "
        f"uint8_t *out_n) {{ return hbridge_command({inst}, in, n, out, out_n); }}"
    )
    p.decls.append(f"static void motor_safe_{inst}(void) {{ hbridge_make_safe({inst}); }}")
    p.funcs.append((str(t.options["call"]), f"call_{k}"))
    p.decls.append(gated(k, t.name, f"motor_{inst}"))
    p.make_safe = f"motor_safe_{inst}"
