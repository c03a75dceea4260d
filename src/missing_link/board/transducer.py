# A transducer on the board side (spec 2.2, the thesis's transds.def fields): its descriptor
# line, the legal range of its type, the values its driver reported and not yet sent, and its
# run-time switch (`enabled`, config.py).  The runtime (runtime.py) turns pending values into SIFs.
#
# MicroPython subset only.

import struct

from .dtypes import DTYPES, SIF_MAX_PAYLOAD, sif_size


class Transducer:
    # One sensor or actuator, as described in spec 2.2 (the thesis's transds.def fields).
    def __init__(self, name, tid, prefix, model, chan_count, dtype, na, **options):
        if dtype not in DTYPES:
            raise ValueError("transducer %s: unknown data type %s" % (name, dtype))
        if not (0 <= tid <= 239):
            raise ValueError("transducer %s: id %d outside 0..239" % (name, tid))
        if not (1 <= chan_count <= 255):
            raise ValueError("transducer %s: chan_count %d outside 1..255" % (name, chan_count))
        if sif_size(dtype, chan_count) > SIF_MAX_PAYLOAD:
            raise ValueError(
                "transducer %s: %d channels of %s need %d bytes, one SIF carries 255"
                % (name, chan_count, dtype, sif_size(dtype, chan_count))
            )
        self.name = name
        self.tid = tid
        self.prefix = prefix
        self.model = model
        self.chan_count = chan_count
        self.dtype = dtype
        self.na = na
        self.options = options
        code, _size, lo, hi = DTYPES[dtype]
        self._lo = lo
        self._hi = hi
        self._float = lo is None
        self._fmt = "<" + ("Q" + code) * chan_count
        self._pending = [None] * chan_count  # (stamp_us, value) per channel, None = no new value
        self._dirty = False
        self.values_dropped = 0  # illegal values replaced by N/A
        self.enabled = True  # run-time configuration (config.py): off = not polled, no SIFs
        self.driver = None
        self._poll = None  # the driver's poll and next_due_us, when it has them
        self._due = None

    def set_enabled(self, on):
        # Off: the driver is not polled and nothing it reports is sent (what is pending is
        # dropped: it was measured while the host asked for nothing).
        self.enabled = bool(on)
        if not on:
            self._pending = [None] * self.chan_count
            self._dirty = False

    def descriptor_line(self):
        fields = [
            self.name,
            str(self.tid),
            self.prefix,
            self.model,
            str(self.chan_count),
            self.dtype,
            _fmt_value(self.na),
        ]
        for key in self.options:
            fields.append("%s=%s" % (key, self.options[key]))
        return ",".join(fields)

    def legal(self, value):
        if self._float:
            return value == value  # NaN is not a measurement
        return self._lo <= value <= self._hi

    def encode_sif(self, now_us):
        # Payload per spec 1.10: [t0 v0 t1 v1 ...]; channels without a new value carry N/A,
        # stamped with the moment the SIF was assembled.
        args = []
        pending = self._pending
        for ch in range(self.chan_count):
            item = pending[ch]
            if item is None:
                args.append(now_us)
                args.append(self.na)
            else:
                args.append(item[0])
                args.append(item[1])
                pending[ch] = None
        self._dirty = False
        return struct.pack(self._fmt, *args)


def _fmt_value(v):
    if isinstance(v, bool):
        return "1" if v else "0"
    return str(v)
