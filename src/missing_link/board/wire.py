# J2A framing for the board side (spec Part 1), in the MicroPython subset.
#
# Theory of operation
# -------------------
# A board gets its input a few bytes at a time (UART, USB CDC) and has little RAM, so this parser
# is a byte-at-a-time state machine with a fixed payload buffer:
#
#   HUNT --0x12--> SEQ -> OP -> LEN -> DATA (len bytes) -> CSUM --> request (or error)
#   HUNT --0xED--> IGNORE: a board never acts on SIF frames (spec 1.1); it only counts the
#                  frame's bytes (seq, op, len, len data, csum; escapes undone) and hunts again,
#                  or, cut short by silence (a stray 0xED of line noise), is dropped as any frame.
#
# ESC (0x7D) sets a flag and the next byte is taken +1; a result that is not one of the three
# specials is a bad escape.  A raw 0x12/0xED inside a frame means the frame was cut: the parser
# reports it (with the seq if it had arrived) and starts again at that marker.  feed() returns a
# list of events; the runtime answers errors with error frames (0xF2/0xF3/0xF4), as the original.
#
# Between frames (hunting) bytes are junk, except the break: BREAK
# then CR or LF, all between frames, is EV_BREAK (the MicroPython firmware's way back to the
# REPL, firmware.py).  J2A never sends bytes between frames, and line noise does not spell seven
# given bytes (2^-56 a try); no marker may come between them.  The rest of a frame that was
# dropped (abort: 10 ms of silence; a bad escape) is not between frames, whatever its payload
# spells: SKIP discards it until the next marker or until the line has been quiet again (the
# runtime's poll calls abort() once more), so a host's payload can never be a break; nor can a
# SIF frame's (an echoing link), which IGNORE walks to its end.
#
# The host side has its own, throughput-oriented decoder (missing_link.j2a.codec); the test suite
# cross-checks the two with random frames in both directions.

SOF = 0x12
SOS = 0xED
ESC = 0x7D

# Event tags returned by FrameParser.feed: (tag, seq, opcode, payload_bytes_or_None)
EV_REQUEST = 0
EV_CUT = 1
EV_CHECKSUM = 2
EV_ESCAPE = 3
EV_BREAK = 4

BREAK = b"\x03\x03repl"  # then CR or LF: Ctrl-C twice, "repl", Enter (docs/hardware.md)

_HUNT = 0
_SEQ = 1
_OP = 2
_LEN = 3
_DATA = 4
_CSUM = 5
_IGNORE = 6
_SKIP = 7  # the rest of a dropped frame


def escape_into(out, data):
    # Append data to bytearray out with J2A escaping.
    for b in data:
        if b == SOF or b == SOS or b == ESC:
            out.append(ESC)
            out.append(b - 1)
        else:
            out.append(b)


def encode_frame(start, seq, opcode, payload):
    n = len(payload)
    if n > 255:
        raise ValueError("J2A payload longer than 255 bytes")
    out, c = encode_frame_head(start, seq, opcode, n, payload)
    escape_into(out, bytes((c,)))
    return bytes(out)


def encode_frame_head(start, seq, opcode, n, head):
    # A frame with an n-byte payload, up to its first len(head) payload bytes: (the encoded
    # bytes so far, the checksum so far).  encode_frame_tail adds the rest.  For a2jClock's
    # reply: t3 is stamped as late as possible and only its 8 bytes are encoded after it.
    c = seq ^ ((opcode + 11) & 0xFF) ^ ((n + 97) & 0xFF)
    for b in head:
        c ^= b
    out = bytearray()
    out.append(start)
    escape_into(out, bytes((seq, opcode, n)))
    escape_into(out, head)
    return out, c


def encode_frame_tail(out, c, tail):
    # The frame begun by encode_frame_head, finished with its last payload bytes (a bytearray).
    for b in tail:
        c ^= b
    escape_into(out, tail)
    escape_into(out, bytes((c,)))
    return out


class FrameParser:
    def __init__(self):
        self.buf = bytearray(255)
        self.state = _HUNT
        self.esc = False
        self.seq = 0
        self.op = 0
        self.n = 0
        self.i = 0
        self.csum = 0
        self.junk = 0
        self.errors = 0
        self.frames = 0
        self._between = bytearray()  # the last bytes between frames (the break's)
        self._sif = 0  # IGNORE: unescaped bytes of the SIF frame seen so far
        self._sif_len = 0  # IGNORE: its total length (seq, op, len, data, csum), once known

    def in_frame(self):
        # (in a frame, an ignored one too, or in the rest of a dropped one: each ends after
        # silence, abort())
        return self.state != _HUNT

    def abort(self):
        # Inter-byte silence: drop the frame (what still comes of it is skipped, until the
        # next silence).  Returns the cut event if a seq had arrived.
        st = self.state
        self.state = _HUNT
        self.esc = False
        if st == _HUNT or st == _SKIP:
            return None
        self.state = _SKIP
        if st == _IGNORE:  # a SIF cut short (or a stray 0xED): nothing to answer
            return None
        self.errors += 1
        if st == _SEQ:
            return (EV_CUT, None, 0, None)
        return (EV_CUT, self.seq, 0, None)

    def _walk_sif(self, b):
        # One byte of an ignored SIF frame: hunt again after its checksum.
        if self.esc:
            self.esc = False
            b = (b + 1) & 0xFF
        elif b == ESC:
            self.esc = True
            return
        if self._sif == 2:
            self._sif_len = b + 4
        self._sif += 1
        if self._sif_len and self._sif >= self._sif_len:
            self.state = _HUNT

    def feed(self, data):
        events = []
        for b in data:
            if b == SOF or b == SOS:
                if self.state != _HUNT and self.state != _IGNORE and self.state != _SKIP:
                    self.errors += 1
                    events.append((EV_CUT, self.seq if self.state > _SEQ else None, 0, None))
                self.esc = False
                self.state = _SEQ if b == SOF else _IGNORE
                self._between = bytearray()
                self._sif = 0
                self._sif_len = 0
                continue
            st = self.state
            if st == _SKIP:
                self.junk += 1
                continue
            if st == _IGNORE:
                self._walk_sif(b)
                continue
            if st == _HUNT:
                self.junk += 1
                if (b == 13 or b == 10) and bytes(self._between) == BREAK:
                    events.append((EV_BREAK, None, 0, None))
                self._between.append(b)
                if len(self._between) > len(BREAK):
                    self._between = self._between[1:]
                continue
            if self.esc:
                self.esc = False
                b += 1
                if b != SOF and b != SOS and b != ESC:
                    self.errors += 1
                    events.append((EV_ESCAPE, self.seq if st > _SEQ else None, 0, None))
                    self.state = _SKIP
                    continue
            elif b == ESC:
                self.esc = True
                continue
            if st == _SEQ:
                self.seq = b
                self.csum = b
                self.state = _OP
            elif st == _OP:
                self.op = b
                self.csum ^= (b + 11) & 0xFF
                self.state = _LEN
            elif st == _LEN:
                self.n = b
                self.i = 0
                self.csum ^= (b + 97) & 0xFF
                self.state = _DATA if b else _CSUM
            elif st == _DATA:
                self.buf[self.i] = b
                self.i += 1
                self.csum ^= b
                if self.i == self.n:
                    self.state = _CSUM
            else:  # _CSUM
                self.state = _HUNT
                if b != self.csum:
                    self.errors += 1
                    events.append((EV_CHECKSUM, self.seq, self.op, None))
                else:
                    self.frames += 1
                    events.append((EV_REQUEST, self.seq, self.op, bytes(self.buf[: self.n])))
        return events
