"""Errors: each says whose fault it was, the state of the link, and what to do next.

One tree: every exception class missing-link defines derives from :class:`MissingLinkError`
(``tests/test_errors.py`` walks the package), so ``except MissingLinkError`` catches whatever
it raises on purpose.  Errors in the user's input are ``ValueError`` too (``BadURL``,
``ConfigError``), so callers that catch ``ValueError`` keep working.  A bug (ours or a case a
board's data reached unvalidated) is any other exception: where a thread must outlive it, it
is counted by kind and logged once (``logs.ErrorCounts``).  Every message is text: no control
character or escape sequence of what it quotes survives ``str()``.
"""

from __future__ import annotations

from .text import clean


class MissingLinkError(Exception):
    """Base class of every error missing-link raises on purpose.

    Its message is text whatever it quotes (``text.clean``): what a board or a network client
    said (an update refused with a new window title, a cleared screen and a forged line) reaches
    the CLI's one error line, the logs, the control endpoint's and the web console's replies
    only through ``str()`` of the error, so it is cleaned here, once for all of them."""

    def __str__(self) -> str:
        return clean(super().__str__())


class TransportError(MissingLinkError):
    """The byte link to a board failed or was unusable."""


class TransportClosed(TransportError):
    """The link was closed on this side (our doing); open it again to continue."""


class TransportBroken(TransportError):
    """The link failed under us (board unplugged, peer closed, I/O error); reconnect."""


class BadURL(MissingLinkError, ValueError):
    """A board URL cannot be understood (the caller's input)."""


class ConfigError(MissingLinkError, ValueError):
    """A configuration, board file or option is invalid (the user's input): the message says
    where and why."""


class BoardError(MissingLinkError):
    """Something went wrong talking to a board; ``board`` names it."""

    def __init__(self, board: str, message: str) -> None:
        super().__init__(f"{board}: {message}")
        self.board = board


class UnknownFunction(BoardError):
    def __init__(self, board: str, function: str, available: list[str]) -> None:
        super().__init__(
            board,
            f"board has no function {function!r} (it has: {', '.join(available) or 'none'})",
        )
        self.function = function


class CallTimeout(BoardError):
    def __init__(self, board: str, function: str, detail: str) -> None:
        super().__init__(board, f"{function}: {detail} (board busy, link too slow, or gone?)")
        self.function = function


class CallError(BoardError):
    """The board answered with an error frame, or the reply broke the protocol."""

    def __init__(self, board: str, function: str, detail: str, code: int | None = None) -> None:
        super().__init__(board, f"{function}: {detail}")
        self.function = function
        self.code = code


def without_prefix(who: str, text: str) -> str:
    """``text`` without a leading ``who: `` (an error that names its board, shown where the
    board is named already)."""
    while who and text.startswith(who + ": "):
        text = text[len(who) + 2 :]
    return text


def payload_text(payload: bytes) -> str:
    """A reply payload as text when it is text (a board's error message), else ''."""
    try:
        text = payload.decode("utf-8").rstrip("\0")
    except UnicodeDecodeError:
        return ""
    return text if text and text.isprintable() else ""


class FunctionFailed(BoardError):
    """The function ran and returned a nonzero status where 0 (OK) was required."""

    def __init__(self, board: str, function: str, code: int, payload: bytes = b"") -> None:
        said = payload_text(payload)
        super().__init__(board, f"{function} returned {code:#04x}" + (f": {said}" if said else ""))
        self.function = function
        self.code = code
        self.payload = payload


class LinkLost(BoardError):
    """The link to the board closed or broke while a call was waiting."""

    def __init__(self, board: str, function: str, detail: str, broken: bool) -> None:
        super().__init__(board, f"{function}: {detail}")
        self.function = function
        self.broken = broken


class DescriptorError(BoardError):
    """A transducer descriptor is malformed; the message names the line and the field."""
