"""What the AVR generator writes into C from a board file, made safe to paste: names only as
identifiers, text only as escaped string literals or comments that cannot end early.  The board
file's loader refuses malformed names first (boardfile.py); these are the generator's own
checks, for any dict it is handed (defence in depth)."""

from __future__ import annotations

import re

from ..errors import ConfigError

C_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}\Z")


def c_ident(name: object, at: str) -> str:
    """``name`` if it is a C identifier; ConfigError otherwise (nothing else reaches the C)."""
    if not isinstance(name, str) or not C_IDENT.match(name):
        raise ConfigError(f"{at}: {name!r} is not a name the firmware can take (an identifier)")
    return name


def c_string(data: bytes) -> str:
    """A C string literal for arbitrary bytes (NULs included), split into lines."""
    parts, line = [], ""
    for b in data:
        ch = chr(b)
        if ch == "\\" or ch == '"':
            line += "\\" + ch
        elif 32 <= b < 127 and ch != "?":  # (no ??x trigraphs either)
            line += ch
        else:
            line += f"\\{b:03o}"  # always 3 octal digits: a digit after it stays a digit
        if b in (0, 10) and len(line) > 60:
            parts.append(f'"{line}"')
            line = ""
    parts.append(f'"{line}"')
    return "\n    ".join(parts)


def c_text(text: str) -> str:
    """``text`` (UTF-8) as a C string literal."""
    return c_string(text.encode())


def c_comment(text: str) -> str:
    """``text`` inside a C comment: printable ASCII, never the comment's end."""
    return "".join(c if " " <= c <= "~" else "?" for c in text).replace("*/", "*?")
