# Run-time configuration of a board (spec Part 2.4, docs/configuration.md): per transducer
# `enabled`, and the keys its driver offers (`rate_hz`, ranges, limits, filters), read and written
# by the host through four J2A functions, kept in non-volatile storage on request.
#
# Theory of operation
# -------------------
# The keys are `<transducer>.<key>`, in a fixed order (the key index on the wire): for each
# transducer `enabled`, then `aligned` and `phase` where it samples on the host-time grid
# (timing.py), `failsafe_ms` for an actuator the failsafe guards (failsafe.py), then its
# driver's CONFIG entries.  A CONFIG entry is (key, kind, limits,
# read_only): kind `bool`, `int`, `float` or `enum`; limits (lo, hi) for numbers, the choices for
# an enum (its wire value is the choice's index).  The driver answers get_config(key) and
# set_config(key, value) (raising ValueError with the reason when it cannot take a value that is
# within the limits, e.g. a servo's min_us above its centre).  The defaults are the values at
# boot, before a saved configuration is applied: the board file's, else the driver's own.
#
#   a2jConfigKeys   many, read-only: "config/1" then one line per key:
#                   name;kind;default;limits;flags   (limits lo..hi or a|b|c; flags "ro" or "")
#   a2jConfigGet    [u8 first] -> [u8 first][u8 count of all keys][u8 state] + 4-byte values
#                   from `first`, as many as fit (int32 for bool/int/enum, float32 for float)
#   a2jConfigSet    [u8 flags] + ([u8 index][4-byte value])*: every pair is checked first, then
#                   all are applied or none (a driver's refusal rolls back what was applied);
#                   flags bit0: save the result.  0 = done; 0xFF + "name: reason" = nothing
#                   changed; 1 + reason = applied but not saved
#   a2jConfigReset  [u8 flags]: the defaults again; bit0: erase the saved configuration too
#
# state bits: 1 = a saved configuration exists, 2 = it was applied at boot, 4 = the running
# configuration differs from the saved one (or from the defaults when none is saved).
#
# Saving: a record [b"MLC" version][u16 schema crc][u8 count][values][u16 crc] written by the
# store (a file written to a temporary name and renamed over the old one: a power cut leaves the
# old or the new file, never half of one; the C runtime keeps two EEPROM slots).  A record whose
# schema crc differs (another board file since) is not applied.  A store that fails (read, write
# or erase) is the answer's reason and a fault in the board's log (log.py): said once (WARN),
# every failure counted.

import struct

from .log import SOURCE_BOARD, STORAGE, WARN

VERSION = 1
MAGIC = b"MLC"
ST_SAVED = 1
ST_LOADED = 2
ST_DIRTY = 4
KINDS = ("bool", "int", "float", "enum")
DEFAULT_FAILSAFE_MS = 500  # (failsafe.py's)


def crc16(data, crc=0xFFFF):
    # CRC-16/CCITT-FALSE, the same on the C runtime (config.c).
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def _fmt(v):
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        r = repr(v)
        return r[:-2] if r.endswith(".0") else r
    return str(v)


class Key:
    def __init__(self, t, key, kind, limits, read_only, get, put):
        self.t = t  # the transducer
        self.name = t.name + "." + key
        self.key = key
        self.kind = kind
        self.limits = limits
        self.read_only = read_only
        self.get = get
        self.put = put
        self.default = get()

    def line(self):
        if self.kind == "enum":
            limits = "|".join(_fmt(c) for c in self.limits)
        elif self.limits is None:
            limits = ""
        else:
            limits = _fmt(self.limits[0]) + ".." + _fmt(self.limits[1])
        flags = "ro" if self.read_only else ""
        return "%s;%s;%s;%s;%s" % (self.name, self.kind, _fmt(self.default), limits, flags)

    def to_wire(self, value):
        if self.kind == "float":
            return struct.pack("<f", value)
        if self.kind == "enum":
            return struct.pack("<i", self.limits.index(value))
        return struct.pack("<i", int(value))

    def from_wire(self, raw):
        # (value, None) or (None, reason)
        if self.kind == "float":
            v = struct.unpack("<f", raw)[0]
            if v != v:
                return None, "not a number"
        else:
            v = struct.unpack("<i", raw)[0]
        if self.kind == "bool":
            if v not in (0, 1):
                return None, "expected 0 or 1"
            return v == 1, None
        if self.kind == "enum":
            if not 0 <= v < len(self.limits):
                return None, "expected one of " + "|".join(_fmt(c) for c in self.limits)
            return self.limits[v], None
        lo, hi = self.limits
        if not lo <= v <= hi:
            return None, "expected %s..%s" % (_fmt(lo), _fmt(hi))
        return v, None


class RuntimeConfig:
    def __init__(self, runtime, store=None):
        self.rt = runtime
        self.store = store
        self.keys = []
        self.changes = 0  # applied sets and resets since boot
        self.state = 0
        timing = runtime.timing
        for t in runtime.transducers:
            self._add(t, "enabled", "bool", None, False, _getter(t), _enabler(t))
            drv = t.driver
            if timing is not None and hasattr(drv, "timing"):
                drv.timing = timing  # (timed calls, the grid: timing.py)
            if timing is not None and getattr(drv, "ALIGNABLE", False):
                # sampling on the host-time grid (timing.py): every board at the same instants
                self._add(t, "aligned", "bool", None, False, _attr(drv, "aligned"), _align(drv))
                self._add(t, "phase", "float", (0.0, 0.999), False, _attr(drv, "phase"),
                          _phase(drv))  # fmt: skip
            if runtime.failsafe is not None and hasattr(drv, "make_safe"):
                # how long without the host before it is made safe (failsafe.py; 0: never)
                if not hasattr(drv, "failsafe_ms"):
                    drv.failsafe_ms = DEFAULT_FAILSAFE_MS
                self._add(t, "failsafe_ms", "int", (0, 60000), False, _attr(drv, "failsafe_ms"),
                          _setattr(drv, "failsafe_ms"))  # fmt: skip
            for entry in getattr(drv, "CONFIG", ()):
                key, kind, limits, ro = entry
                if kind not in KINDS:
                    raise ValueError("%s.%s: kind %s" % (t.name, key, kind))
                self._add(t, key, kind, limits, ro, _drv_get(drv, key), _drv_put(drv, key))
        self.schema_crc = crc16(self.keys_blob())
        rt = runtime
        rt.add_blob_function("a2jConfigKeys", self.keys_blob)
        rt.add_function("a2jConfigGet", self._get)
        rt.add_function("a2jConfigSet", self._set)
        rt.add_function("a2jConfigReset", self._reset)
        self._load()

    def _add(self, t, key, kind, limits, ro, get, put):
        self.keys.append(Key(t, key, kind, limits, ro, get, put))

    def keys_blob(self):
        return ("config/1\n" + "".join(k.line() + "\n" for k in self.keys)).encode()

    def values(self):
        return [k.get() for k in self.keys]

    def _dirty(self):
        if self.state & ST_SAVED:
            saved = self._read()
            now = b"".join(k.to_wire(k.get()) for k in self.keys)
            return saved is None or saved != now
        for k in self.keys:
            if k.get() != k.default:
                return True
        return False

    # ---- J2A functions --------------------------------------------------------------------
    def _get(self, payload):
        first = payload[0] if payload else 0
        keys = self.keys
        if first > len(keys):
            return 0xFF, ("no key index %d" % first).encode()
        state = self.state | (ST_DIRTY if self._dirty() else 0)
        out = bytearray((first, len(keys), state))
        for k in keys[first : first + 63]:
            out.extend(k.to_wire(k.get()))
        return 0, bytes(out)

    def _set(self, payload):
        if not payload or (len(payload) - 1) % 5:
            return 0xFF, b"expects [flags] + ([index][4-byte value])*"
        flags = payload[0]
        wanted = []
        for i in range(1, len(payload), 5):
            idx = payload[i]
            if idx >= len(self.keys):
                return 0xFF, ("no key index %d" % idx).encode()
            k = self.keys[idx]
            if k.read_only:
                return 0xFF, (k.name + ": read-only").encode()
            value, why = k.from_wire(payload[i + 1 : i + 5])
            if why is not None:
                return 0xFF, (k.name + ": " + why).encode()
            wanted.append((k, value))
        why = self.apply(wanted)
        if why is not None:
            return 0xFF, why.encode()
        if wanted:
            self.changes += 1
        if flags & 1:
            why = self.save()
            if why is not None:
                return 1, ("applied, not saved: " + why).encode()
        return 0, b""

    def _reset(self, payload):
        flags = payload[0] if payload else 0
        why = self.apply([(k, k.default) for k in self.keys if not k.read_only])
        if why is not None:
            return 0xFF, why.encode()
        self.changes += 1
        if flags & 1 and self.store is not None:
            try:
                self.store.erase()
            except Exception as e:  # noqa: BLE001 - a failing store is the answer, not a crash
                self._storage_failed("erasing", e)
                return 1, ("defaults applied, saved configuration not erased: %s" % e).encode()
            self.state &= ~ST_SAVED
        return 0, b""

    # ---- applying and saving ---------------------------------------------------------------
    def apply(self, wanted):
        # All or nothing: on a driver's refusal (of a value, or of the combination, checked
        # once every value is in: check_config), what was applied is put back.  None or reason.
        done = []
        why = None
        for k, value in wanted:
            old = k.get()
            try:
                k.put(value)
            except ValueError as e:
                why = "%s: %s" % (k.name, e)
                break
            done.append((k, old))
        if why is None:
            for k, _old in done:
                check = getattr(k.t.driver, "check_config", None)
                why = check() if check is not None else None
                if why is not None:
                    why = "%s: %s" % (k.t.name, why)
                    break
        if why is None:
            return None
        for dk, dv in reversed(done):
            try:
                dk.put(dv)
            except ValueError:
                pass
        return why

    def record(self):
        body = struct.pack("<3sBHB", MAGIC, VERSION, self.schema_crc, len(self.keys))
        body += b"".join(k.to_wire(k.get()) for k in self.keys)
        return body + struct.pack("<H", crc16(body))

    def save(self):
        if self.store is None:
            return "this board has no storage for a configuration"
        try:
            self.store.write(self.record())
        except Exception as e:  # noqa: BLE001 - the answer says it, and the log (counted)
            self._storage_failed("saving", e)
            return "storage failed: %s" % e
        self.state |= ST_SAVED
        return None

    def _storage_failed(self, doing, e):
        # said once (WARN), every failure counted (log.py): the host's status shows it
        text = "configuration storage failed %s: %s" % (doing, e)
        self.rt.log.fault(SOURCE_BOARD, STORAGE, text, WARN)

    def _read(self):
        # The saved values' bytes, or None when there is no valid record for this schema.
        if self.store is None:
            return None
        try:
            rec = self.store.read()
        except Exception as e:  # noqa: BLE001 - unreadable is the same as absent (and said)
            self._storage_failed("reading", e)
            return None
        n = len(self.keys)
        if rec is None or len(rec) != 9 + 4 * n:
            return None
        if crc16(rec[:-2]) != struct.unpack("<H", rec[-2:])[0]:
            return None
        magic, version, schema, count = struct.unpack("<3sBHB", rec[:7])
        if magic != MAGIC or version != VERSION or schema != self.schema_crc or count != n:
            return None
        return rec[7:-2]

    def _load(self):
        values = self._read()
        if values is None:
            return
        self.state |= ST_SAVED
        wanted = []
        for i in range(len(self.keys)):
            k = self.keys[i]
            value, why = k.from_wire(values[4 * i : 4 * i + 4])
            if why is None and not k.read_only:
                wanted.append((k, value))
        if self.apply(wanted) is None:
            self.state |= ST_LOADED
        else:
            self.rt.debug("saved configuration refused;")
            self.rt.log.line(WARN, "the saved configuration was refused: the defaults run")


def _getter(t):
    return lambda: t.enabled


def _enabler(t):
    return t.set_enabled


def _attr(drv, name):
    return lambda: getattr(drv, name)


def _setattr(drv, name):
    def put(value):
        setattr(drv, name, value)

    return put


def _align(drv):
    def put(value):
        drv.aligned = bool(value)
        drv.realign()

    return put


def _phase(drv):
    def put(value):
        drv.phase = value
        drv.realign()

    return put


def _drv_get(drv, key):
    return lambda: drv.get_config(key)


def _drv_put(drv, key):
    return lambda value: drv.set_config(key, value)
