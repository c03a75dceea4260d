"""Golden vectors from ../shared/spec/j2a-vectors.md (the original 2014 host and board)."""

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
