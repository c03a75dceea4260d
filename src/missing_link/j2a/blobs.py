"""Parsing of the blobs boards send: the function mapping (spec 1.6) and properties (spec 1.8)."""

from __future__ import annotations

import struct

from ..errors import MissingLinkError
from ..text import clean

MANY_HEADER = struct.Struct("<BBI")  # target/return, flags, offset
MANY_CHUNK = 249
#: function indices 0xF0..0xFF are error codes: a table can hold at most 240 functions
MAX_FUNCTIONS = 0xF0
FLAG_LAST = 0x01
FLAG_WRITE = 0x02


class BlobError(MissingLinkError, ValueError):
    """A mapping or property blob from a board is malformed (the board's fault)."""


def parse_mapping(blob: bytes) -> list[str]:
    """NUL-terminated names in table order; index k is function k."""
    if not blob:
        raise BlobError("function mapping is empty (a board always has a2jGetMapping at 0)")
    if blob[-1] != 0:
        raise BlobError(
            f"function mapping does not end in NUL after {len(blob)} bytes "
            "(truncated at 255 bytes by an original board?)"
        )
    names = blob[:-1].split(b"\0")
    out: list[str] = []
    for i, raw in enumerate(names):
        try:
            name = raw.decode("ascii")
        except UnicodeDecodeError as e:
            raise BlobError(f"function {i} has a non-ASCII name {raw!r}") from e
        if not name:
            raise BlobError(f"function {i} has an empty name")
        if clean(name) != name or " " in name:
            raise BlobError(f"function {i} has control characters or spaces in its name {raw!r}")
        out.append(name)
    if len(out) > MAX_FUNCTIONS:
        raise BlobError(
            f"function table has {len(out)} entries; indices from {MAX_FUNCTIONS} (0xF0) are "
            f"error codes, so {out[MAX_FUNCTIONS]!r} and later could never be called"
        )
    return out


def mapping_index(names: list[str]) -> dict[str, int]:
    index: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in index:
            raise BlobError(f"function {name!r} appears twice (indices {index[name]} and {i})")
        index[name] = i
    return index


def parse_properties(blob: bytes) -> dict[str, str]:
    """``key\\0value\\0...``; empty values are legal, duplicate keys are an error."""
    if not blob:
        return {}
    if blob[-1] != 0:
        raise BlobError(f"property blob does not end in NUL ({len(blob)} bytes)")
    parts = blob[:-1].split(b"\0")
    if len(parts) % 2:
        raise BlobError(
            f"property blob has {len(parts)} strings; keys and values must pair up "
            f"(last key {parts[-1]!r} has no value)"
        )
    props: dict[str, str] = {}
    for i in range(0, len(parts), 2):
        try:
            key = parts[i].decode()
            value = parts[i + 1].decode()
        except UnicodeDecodeError as e:
            raise BlobError(f"property {i // 2} is not UTF-8: {parts[i]!r}") from e
        if not key:
            raise BlobError(f"property {i // 2} has an empty key")
        key, value = clean(key), clean(value)  # untrusted: may reach a terminal or a file
        if key in props:
            raise BlobError(f"property {key!r} appears twice")
        props[key] = value
    return props


def many_request(target: int, flags: int, offset: int, data: bytes = b"") -> bytes:
    return MANY_HEADER.pack(target, flags, offset) + data
