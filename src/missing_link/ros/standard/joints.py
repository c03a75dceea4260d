"""``sensor_msgs/msg/JointState`` for what turns, one message per sample with one joint per
channel (named ``<board>/<transducer>``, ``/<channel>`` added when it has several), and the
standard command (``std_msgs/msg/Float64`` in SI units) back to the raw value an actuator takes.

Theory of operation
-------------------
* quadrature encoder: ``position`` (rad) = the board's count x 2 pi / ``counts_per_rev`` (the
  board counts from its power-up, so a daemon that restarts, or a second one, says the same
  angle); the count wraps like the board's counter (its data type) and the host unwraps it from
  the first count it sees, so the position keeps growing over a wrap; ``velocity`` (rad/s) is
  the change since the previous sample
  over the time between their host stamps (NaN for the first sample and after an N/A one:
  the board says a count with a missed edge is not to be trusted);
* servo (any actuator or ``ros=`` JointState in an angle unit): ``position`` = the commanded
  angle in rad (a servo cannot say where it is: what it was told, stamped when it took effect);
* stepper: ``position`` (channel 0, rev -> rad) and ``velocity`` (channel 1, rev/s -> rad/s);
* H-bridge: ``effort`` = the applied duty, -1..1 (a motor through a bridge knows no torque);
  position and velocity are empty.  Paired with an encoder in the daemon's ``[joints]``, the
  robot-level JointState takes position and velocity from the encoder.
A field no joint of the message measures is empty; one that a joint lacks this time is NaN.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

from ...board.dtypes import DTYPES
from ...descriptors import Transducer
from .common import UNIT_TO_SI, Ctx, StandardMapping, descriptor_key, no_channel, si_value

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
TWO_PI = 2 * math.pi
ENCODER, STEPPER, HBRIDGE, POSITION = "encoder", "stepper", "hbridge", "position"
Fields = tuple[list[float] | None, list[float] | None, list[float] | None]


def joint_state(c: Ctx, ns: int, names: list[str], fields: Fields) -> bytes:
    return joint_state_cdr(ns, c.frame.value, names, fields)


def joint_state_cdr(ns: int, frame_id: str, names: list[str], fields: Fields) -> bytes:
    """A JointState in CDR, packed directly (an encoder's sample path runs at up to a kHz:
    message objects cost ten times more); byte for byte what rosbags makes (the tests say so).
    Offsets align relative to the data after the 4-byte encapsulation header."""
    out = bytearray(b"\x00\x01\x00\x00")  # CDR, little endian
    sec, nsec = divmod(ns, 1_000_000_000)
    out += _TIME.pack(sec, nsec)
    _string(out, frame_id)
    _align(out, 4)
    out += _U32.pack(len(names))
    for name in names:
        _string(out, name)
    for values in fields:
        vals = values or []
        _align(out, 4)
        out += _U32.pack(len(vals))
        if vals:
            _align(out, 8)
            out += struct.pack(f"<{len(vals)}d", *vals)
    return bytes(out)


_TIME, _U32 = struct.Struct("<iI"), struct.Struct("<I")


def _align(out: bytearray, n: int) -> None:
    out += bytes((4 - len(out)) % n)


def _string(out: bytearray, text: str) -> None:
    data = text.encode()
    _align(out, 4)
    out += _U32.pack(len(data) + 1)
    out += data
    out += b"\0"


def counts_per_rev(c: Ctx) -> float:
    """An encoder's counts per revolution: the host's key (``[boards.<board>.ros.<name>]``),
    else the descriptor's (the board file's ``options``: it is the hardware)."""
    given = c.options.counts_per_rev
    if given is None:
        text = descriptor_key(c.t, "counts_per_rev")
        try:
            given = float(text) if text is not None else None
        except ValueError:
            raise ValueError(
                f"{c.board}/{c.t.name}: counts_per_rev={text!r} is no number"
            ) from None
    if given is None or not given > 0 or not math.isfinite(given):
        raise ValueError(
            f"{c.board}/{c.t.name}: an encoder's JointState needs its counts per revolution: "
            f'"options": {{"counts_per_rev": N}} on its board file entry (edges x4 per '
            f"turn), or [boards.{c.board}.ros.{c.t.name}] counts_per_rev = N in the daemon's "
            "configuration; it goes out as counts only until then"
        )
    return given


def build(c: Ctx, kind: str) -> list[StandardMapping]:
    maker = {ENCODER: _encoder, STEPPER: _stepper, HBRIDGE: _hbridge, POSITION: _position}[kind]
    sample = maker(c)
    return [StandardMapping(JOINT_STATE, "joint_states", no_channel, sample, frame=c.frame)]


Sample = Callable[[list[int], list[Any]], bytes | None]


def _encoder(c: Ctx) -> Sample:
    t = c.t
    rad_per_count = TWO_PI / counts_per_rev(c)
    bits = 8 * int(DTYPES[t.dtype][1])
    span, half = 1 << bits, 1 << (bits - 1)
    n = t.chan_count
    names = [c.joint(ch) for ch in range(n)]
    raw: list[int | None] = [None] * n  # the previous count (for the wrap)
    acc = [0] * n  # the board's count, unwrapped from the first one seen
    last: list[tuple[int, int] | None] = [None] * n  # (host ns, acc) of the previous good one

    def sample(host_ns: list[int], values: list[Any]) -> bytes:
        pos, vel = [math.nan] * n, [math.nan] * n
        for ch, v in enumerate(values):
            if v is None:
                last[ch] = None  # (a missed edge: no speed across it)
                continue
            prev = raw[ch]
            if prev is None:
                acc[ch] = int(v)  # (the board's own count: its angle since power-up)
            else:
                acc[ch] += (int(v) - prev + half) % span - half
            raw[ch] = int(v)
            pos[ch] = acc[ch] * rad_per_count
            before = last[ch]
            if before is not None and host_ns[ch] > before[0]:
                vel[ch] = (acc[ch] - before[1]) * rad_per_count * 1e9 / (host_ns[ch] - before[0])
            last[ch] = (host_ns[ch], acc[ch])
        return joint_state(c, max(host_ns), names, (pos, vel, None))

    return sample


def _stepper(c: Ctx) -> Sample:
    names = [f"{c.board}/{c.t.name}"]  # (one joint: position and speed on two channels)

    def sample(host_ns: list[int], values: list[Any]) -> bytes:
        p, v = (math.nan if x is None else x * TWO_PI for x in values[:2])
        return joint_state(c, max(host_ns), names, ([p], [v], None))

    return sample


def _hbridge(c: Ctx) -> Sample:
    n = c.t.chan_count
    names = [c.joint(ch) for ch in range(n)]

    def sample(host_ns: list[int], values: list[Any]) -> bytes:
        duty = [math.nan if v is None else float(v) for v in values]
        return joint_state(c, max(host_ns), names, (None, None, duty))

    return sample


def _position(c: Ctx) -> Sample:
    t = c.t
    n = t.chan_count
    names = [c.joint(ch) for ch in range(n)]

    def sample(host_ns: list[int], values: list[Any]) -> bytes:
        pos = [math.nan if v is None else si_value(t, v) for v in values]
        return joint_state(c, max(host_ns), names, (pos, None, None))

    return sample


# ---- standard commands -----------------------------------------------------------------------
def raw_command(t: Transducer, kind: str | None) -> Callable[[float], int | float]:
    """SI value (a Float64's ``data``) -> the raw value actuator ``t`` takes: a servo's angle
    in rad, a stepper's position in rad (or speed in rad/s in its velocity mode: the same
    factor), an H-bridge's duty -1..1; another actuator's value in SI units of its ``unit``.
    The result is checked as any command is (``Actuators``): out of the type's range or the
    N/A value is refused, never clamped."""
    if kind == STEPPER:
        return lambda si: si / TWO_PI
    if kind == HBRIDGE:
        return float
    scale = float(t.options.get("scale", 1.0))
    offset = float(t.options.get("offset", 0.0))
    factor = UNIT_TO_SI.get(t.unit or "", 1.0)
    integer = t.dtype not in ("float", "double")

    def convert(si: float) -> int | float:
        value = (si / factor - offset) / scale
        if not integer:
            return value
        return round(value) if math.isfinite(value) else value  # (refused by its type)

    return convert
