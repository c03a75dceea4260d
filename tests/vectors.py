"""Golden vectors of docs/protocol.md (captured from the original 2014 host and board)."""

ORIGINAL_TABLE = [
    "a2jGetMapping",
    "a2jMany",
    "a2jGetProperties",
    "a2jDebug",
    "a2jEcho",
    "a2jEchoMany",
    "getTime",
    "syncTime",
    "bigBlob",
]
NAMES = b"".join(n.encode() + b"\0" for n in ORIGINAL_TABLE)


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


ECHO16 = h("10 17 1e 25 2c 33 3a 41 48 4f 56 5d 64 6b 72 79")

# (case, request, reply); None where the vector's reply content is not fully given.
VECTORS = [
    ("GetMapping seq 0", h("12 00 00 00 6a"), h("12 00 00 5d") + NAMES + h("b7")),
    ("GetMapping seq 0x12", h("12 7d 11 00 00 78"), h("12 7d 11 00 5d") + NAMES + h("a5")),
    ("Echo len 0 seq 2", h("12 02 04 00 6c"), h("12 02 ba 00 a6")),
    (
        "Echo seq 0x12 16 bytes",
        h("12 7d 11 04 10") + ECHO16 + h("3c"),
        h("12 7d 11 ba 10") + ECHO16 + h("f6"),
    ),
    (
        "EchoMany isWrite+isLast offset 0x10",
        h("12 07 01 09 05 03 10 00 00 00 61 62 63 17"),
        h("12 07 00 09 be 01 10 00 00 00 61 62 63 a9"),
    ),
]
PROPS_REQUEST = h("12 01 01 06 02 00 00 00 00 00 68")
PROPS_REPLY_HEAD = h("12 01 00 33 00 01 00 00 00 00")  # + 45 bytes + checksum
SIF = h("ed 00 0d 0a 16 01 91 a1 c6 60 06 00 00 00 f4")

# What the original 2014 firmware answers to damaged and odd requests: its own arduino2j code
# (java2arduino-uc ceeec46, serial build, the table above) measured on AVR machine code in
# simavr.  Its error frames carry a source line as the diagnostic (0x0125 = line 293, ...).
# (case, request, the original's whole answer; b"" = nothing)
ORIGINAL_ERROR_PATHS = [
    ("lone SOF, then silence", h("12"), h("12 0e f2 02 01 25 b4")),
    ("SOF and seq, then silence", h("12 0e"), h("12 0e f2 02 01 2d bc")),
    ("cut frame, then a good echo", h("12 05 04 03 aa 12 06 04 00 68"), h("12 05 f2 02 01 4c d6")),
    ("a2jMany with a 2-byte payload", h("12 05 01 02 02 00 68"), h("12 05 ff 02 02 00 6e")),
    (
        "a2jGetProperties through a2jMany with isWrite",
        h("12 01 01 06 02 02 00 00 00 00 6a"),
        h("12 01 00 06 ff 00 00 00 00 00 92"),
    ),
    ("escape 7D FF in a payload", h("12 08 04 01 7d ff 65"), h("12 08 f2 02 01 4c db")),
    ("escape 7D 00 in a payload", h("12 08 04 01 7d 00 64"), h("12 08 ba 01 01 ae")),
    ("bad checksum", h("12 0a 04 00 00"), h("12 0a f3 02 01 5c ca")),
    ("no function 200", h("12 0b c8 00 b9"), h("12 0b f0 02 01 34 a6")),
]
# a2jMany read of bigBlob ((i * 7 + 3) & 0xFF, 1000 bytes) at offset 300: the data of offset 44,
# with the offset 300 echoed (the offset bug)
ORIGINAL_OFFSET_300 = (h("12 09 01 06 08 00 2c 01 00 00 47"), h("12 09 00 ff 00 00 2c 01 00 00"))

# The run-time configuration (docs/configuration.md): the board of tests/micropython/
# setup_config.py (one transducer "signal" with rate_hz, an enum, a read-only key and a
# combination its driver refuses), function indices 11..14 after the Part 2 built-ins.
CONFIG_KEYS = (
    b"config/1\nsignal.enabled;bool;1;;\nsignal.rate_hz;float;100;0.1..1000;\n"
    b"signal.mode;enum;fast;fast|slow;\nsignal.gain;int;2;1..8;ro\n"
)
# (case, request, reply), in this order on one board (each changes what the next sees)
CONFIG_VECTORS = [
    ("get from key 0: 4 keys, state 0, [1, 100.0f, 0 (fast), 2]",
     h("12 01 0c 01 00 74"),
     h("12 01 00 13 00 04 00 01 00 00 00 00 00 c8 42 00 00 00 00 02 00 00 00 f3")),
    ("set rate_hz (key 1) = 10.0f", h("12 02 0d 06 00 01 00 00 20 41 1d"), h("12 02 00 00 68")),
    ("set rate_hz = 2000.0f: outside its limits, nothing changes",
     h("12 03 0d 06 00 01 00 00 fa 44 c3"),
     h("12 03 ff 22") + b"signal.rate_hz: expected 0.1..1000" + h("ff")),
    ("set mode (key 2) = slow (1)", h("12 04 0d 06 00 02 01 00 00 00 78"), h("12 04 00 00 6e")),
    ("set rate_hz = 50.0f: the driver refuses the combination",
     h("12 05 0d 06 00 01 00 00 48 42 71"),
     h("12 05 ff 22") + b"signal: slow mode goes up to 10 Hz" + h("bf")),
    ("set gain (key 3): read-only",
     h("12 06 0d 06 00 03 04 00 00 00 7e"),
     h("12 06 ff 16") + b"signal.gain: read-only" + h("7b")),
    ("set enabled (key 0) = 0, and save (flags 1)",
     h("12 07 0d 06 01 00 00 00 00 00 79"), h("12 07 00 00 6d")),
    ("get (empty = from 0): state 1 (saved), [0, 10.0f, 1 (slow), 2]",
     h("12 08 0c 00 7e"),
     h("12 08 00 13 00 04 01 00 00 00 00 00 00 20 41 01 00 00 00 02 00 00 00 10")),
    ("reset, erasing the saved record (flags 1)", h("12 09 0e 01 01 73"), h("12 09 00 00 63")),
    ("get: the defaults, nothing saved",
     h("12 0a 0c 00 7c"),
     h("12 0a 00 13 00 04 00 01 00 00 00 00 00 c8 42 00 00 00 00 02 00 00 00 f8")),
]  # fmt: skip
