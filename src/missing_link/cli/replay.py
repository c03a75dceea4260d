"""``replay``: a recording played back as the boards that made it (virtual/replay.py)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import Any

from ..text import safe_text
from .common import EXIT_FAIL, EXIT_USAGE

PROGRESS_S = 5.0


def cmd_replay(args: argparse.Namespace) -> int:
    from ..errors import BadURL
    from ..virtual.recording import RecordingError
    from ..virtual.replay_serve import Replay

    try:
        replay = Replay(args.recording, rate=args.rate, loop=args.loop, listen=args.listen,
                        boards=args.board, lead_s=args.lead)  # fmt: skip
    except (FileNotFoundError, RecordingError, BadURL, ValueError) as e:
        _say(f"missing-link: error: {e}")
        return EXIT_USAGE
    except OSError as e:
        print(f"missing-link: error: cannot listen on {args.listen}: {e.strerror or e}",
              file=sys.stderr)  # fmt: skip
        return EXIT_FAIL
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: done.set())
    signal.signal(signal.SIGINT, lambda *a: done.set())
    replay.start()
    for b in replay.boards:
        print(f"LISTENING {b.server.url}", flush=True)
    rec = replay.recording
    if rec.damaged or rec.skipped_chunks:
        _say(f"replay: {rec.damaged} damaged record(s) and {rec.skipped_chunks} damaged chunk(s) "
             "of the recording skipped")  # fmt: skip
    for b in replay.boards:
        _say(f"replay: {b.name} at {b.server.url}: {b.recorded.samples} samples")
        if b.recorded.changed:
            _say(f"replay: {b.name} came up again with other descriptors in the recording; "
                 "the first are served")  # fmt: skip
    how = f" at {args.rate:g}x" if args.rate != 1 else ""
    print(f"replay: {replay.span_s:.1f} s of recording{how}{', looped' if args.loop else ''};"
          f" it starts {args.lead:g} s after a host's first request", file=sys.stderr)  # fmt: skip
    return _serve(replay, done)


def _serve(replay: Any, done: threading.Event) -> int:
    said_done, said_errors = False, 0
    next_progress = time.monotonic() + PROGRESS_S
    while not done.wait(0.1):
        stopped = replay.stopped_serving()  # (a board's server ended: the replay cannot go on)
        errors = replay.errors()
        for line in errors[said_errors:]:
            _say(f"missing-link: error: {line}")
        said_errors = len(errors)
        if stopped:
            break
        sent = ", ".join(f"{b.name} {b.runtime.sent}" for b in replay.boards)
        if replay.finished and not said_done:
            said_done = True
            _say(f"replay: finished, SIFs sent: {sent}; the boards stay up until Ctrl-C")
        elif time.monotonic() >= next_progress and not said_done:
            next_progress += PROGRESS_S
            _say(f"replay: {replay.position_s():.1f} of {replay.span_s:.1f} s, SIFs sent: {sent}")
    replay.stop()
    for b in replay.boards:
        _say(f"replay: {b.summary()}")
    failed = replay.stopped_serving() or any(b.feeder.error for b in replay.boards)
    return EXIT_FAIL if failed else 0


def _say(line: str) -> None:
    """A line to the terminal: board names and errors come from the recording (anyone's file:
    an escape sequence in a name would retitle or repaint the user's terminal)."""
    print(safe_text(line, 1000), file=sys.stderr, flush=True)
