# The built-in functions every board has, as the AVR's table (firmware/avr/src/builtins.h)
# lists them: a2jGetMapping and a2jMany, then (builtins) a2jGetProperties, a2jDebug, a2jEcho and
# a2jEchoMany, then (Part 2) a2jGetMappingMany, a2jGetTransds, a2jClock, a2jHostMap and
# a2jSifCount.  install() puts them at the head of a runtime's function table (runtime.py);
# their handlers read the runtime through what it offers every function (its table, blobs,
# debug text, SIF count, log) and keep the host's clock map in rt.host_map.
#
# MicroPython subset only: no dataclasses, no typing, no f-strings with '='.

import struct

from .log import RAISED_CALL

MANY_CHUNK = 249
# what a host map (a2jHostMap) may say: a rate within 10 % of 1 (crystals: 0.01 %, an RC
# oscillator: a few %), references within the 64-bit sums of the AVR firmware
MAX_PPB = 100000000
MAX_BOARD_US = (1 << 63) - 1
MAX_HOST_NS = 1 << 62
# a function's kind in the table: plain (a request, a reply) or a many-function (a2jMany)
PLAIN_KIND = 0
MANY_KIND = 1
ERR_INDEX = 0xF0  # (the first of the error codes: runtime.py has the others)


def install(rt, builtins, part2):
    b = Builtins(rt)
    rt.add_function("a2jGetMapping", b.get_mapping)
    rt.add_function("a2jMany", b.many)
    if builtins:
        rt.add_blob_function("a2jGetProperties", rt.properties_blob)
        rt.add_function("a2jDebug", b.get_debug)
        rt.add_function("a2jEcho", _echo)
        rt.add_many_function("a2jEchoMany", _echo_many)
    if part2:
        rt.add_blob_function("a2jGetMappingMany", rt.mapping_blob)
        rt.add_blob_function("a2jGetTransds", rt.transds_blob)
        rt.add_function("a2jClock", _clock)
        rt.add_function("a2jHostMap", b.host_map)
        rt.add_function("a2jSifCount", b.sif_count)
    return b


class Builtins:
    def __init__(self, rt):
        self.rt = rt

    def get_mapping(self, payload):
        # As much as fits, cut at a name boundary; the full table is in a2jGetMappingMany.
        if payload:  # (spec 1.6: len 0) a reply of 0 heard back: no 0 again, to echo for ever
            return 0xFF, b""
        blob = self.rt.mapping_blob()
        if len(blob) > 255:
            blob = blob[: blob.rfind(b"\0", 0, 255) + 1]
        return 0, blob

    def get_debug(self, payload):
        return 0, self.rt.take_debug()

    def sif_count(self, payload):
        # u64: SIFs queued since boot (the next SIF's seq, unwrapped), so a host that lost the
        # link can count what it missed meanwhile exactly, not modulo 256.
        return 0, struct.pack("<Q", self.rt.sifs_queued())

    def host_map(self, payload):
        # The host's current map (board µs -> host ns), so the board can act at a host time:
        # <Q board µs><q host ns><i rate - 1 in ppb>.  Empty payload: read it back.  Every field
        # is checked (the same on AVR, timing.c): a map the host got wrong is refused, saying
        # why, and the one before is kept; a rate of -1e9 ppb once divided by zero.
        if len(payload) == 16 + 4:
            b0, h0, ppb = struct.unpack("<Qqi", payload)
            if not -MAX_PPB <= ppb <= MAX_PPB:
                return 0xFF, b"rate off by more than 10 % (ppb)"
            if b0 > MAX_BOARD_US or not -MAX_HOST_NS <= h0 <= MAX_HOST_NS:
                return 0xFF, b"board us beyond 2^63 or host ns beyond +-2^62"
            self.rt.host_map = (b0, h0, ppb)
            return 0, b""
        if not payload and self.rt.host_map is not None:
            return 0, struct.pack("<Qqi", *self.rt.host_map)
        if payload:
            return 0xFF, b"expects <Q board us><q host ns><i ppb> or nothing"
        return 0xFF, b""

    def many(self, payload):
        if len(payload) < 6:
            return 0xFF, payload  # as the original: 0xFF, the request payload echoed (spec 1.11)
        target = payload[0]
        flags = payload[1]
        offset = payload[2] | (payload[3] << 8) | (payload[4] << 16) | (payload[5] << 24)
        rt = self.rt
        if target >= len(rt.functions):
            return ERR_INDEX, None  # _dispatch turns this into an 0xF0 error frame
        name, kind, handler = rt.functions[target]
        if kind != MANY_KIND:
            ret, last, data = 0xFF, True, b""
        else:
            try:
                ret, last, data = handler(bool(flags & 2), bool(flags & 1), offset, payload[6:])
            except Exception as e:  # noqa: BLE001
                rt.debug("%s: %s;" % (name, e))
                rt.fault_raised(RAISED_CALL, name, e)
                ret, last, data = 0xFF, True, b""
        data = data[:MANY_CHUNK]
        head = bytes((ret & 0xFF, 1 if last else 0)) + payload[2:6]
        return 0, head + data


def _clock(payload):
    # Normally answered from _dispatch/take_output (t3 as late as possible); this path
    # only runs for a request with a payload, which the spec does not define.
    return 0xFF, b""


def _echo(payload):
    return 0xBA, payload


def _echo_many(is_write, is_last, offset, data):
    return 0xBE, is_last, data
