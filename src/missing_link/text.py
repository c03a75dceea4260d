"""Board strings made safe: every string a board sends is untrusted.

``clean`` strips what could change the meaning of the place a string lands in: terminal escape
sequences whole (CSI such as ``ESC [2J``, OSC such as a window title ``ESC ]0;...BEL``, and their
one-byte C1 forms), then every other control character (C0, DEL, C1: ``\\r`` would add a line
to a generated ``.msg`` file or forge one on a terminal), line and paragraph separators, and
invisible format characters (bidi overrides).  Board text leaves the host through two doors
besides the parsers that read it in: an error's message (``errors.MissingLinkError``) and a
board log line (``host/board_log.LogLine``); both clean here, and so does the log handler
(``logs.py``), for every line of every logger.  ``slug`` turns a name into a ROS topic token
(``board-a`` -> ``board_a``); ``did_you_mean`` names the known name nearest to one that matches
nothing (a typo in a configuration or a board file).  Pure code."""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable

_TOKEN_RE = re.compile(r"[a-z][a-z0-9_]*\Z")
_UNSAFE = frozenset(("Cc", "Cf", "Zl", "Zp", "Cs", "Co", "Cn"))
#: an escape sequence: CSI (ESC [ or 0x9B: parameters, intermediates, a final byte), OSC, DCS,
#: APC, PM, SOS (ESC ] P _ ^ X or their C1 bytes: up to BEL or ST, or the end), or ESC and one byte
_ESCAPE = re.compile(
    r"(?:\x1b\[|\x9b)[0-?]*[ -/]*[@-~]?"
    r"|(?:\x1b[\]P_^X]|[\x9d\x90\x9f\x9e\x98])[^\x07\x1b\x9c]*(?:\x07|\x1b\\|\x9c)?"
    r"|\x1b[ -~]?"
)


def clean(text: str) -> str:
    """``text`` without control, separator and format characters (printable as it stands)."""
    if text.isprintable():  # the common case: nothing to strip (fast)
        return text
    text = _ESCAPE.sub("", text)
    return "".join(c for c in text if c == " " or unicodedata.category(c) not in _UNSAFE)


def safe_text(text: str, limit: int = 200) -> str:
    """``clean(text)``, at most ``limit`` characters (``...`` marks a cut): for text from a
    board or a network client on its way to a log or a terminal."""
    text = clean(text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def is_token(name: str) -> bool:
    """A ROS name token as used for board and transducer names: ``[a-z][a-z0-9_]*``."""
    return bool(_TOKEN_RE.match(name))


def slug(name: str) -> str:
    """A topic token for ``name``: lower case, runs of anything but ``[a-z0-9]`` become one
    ``_``, no ``_`` at the ends, ``b_`` in front of a leading digit.  '' if nothing is left."""
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    out = re.sub(r"[^a-z0-9]+", "_", ascii_name.lower()).strip("_")
    if out and out[0].isdigit():
        out = "b_" + out
    return out


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` with the name of ``known`` nearest to ``word``, or "" when none
    is near (difflib's ratio below 0.6): for a key or a name that matches nothing."""
    import difflib

    near = difflib.get_close_matches(str(word), [str(k) for k in known], n=1, cutoff=0.6)
    return f" (did you mean {near[0]!r}?)" if near else ""
