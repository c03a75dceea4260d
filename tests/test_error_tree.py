"""Every error is in one tree (issue 33, item 5; its counting: tests/test_errors.py): what
missing-link raises is a MissingLinkError, input errors stay ValueErrors, the exit codes are as
documented, and the log filter says a record whose arguments do not fit."""

from __future__ import annotations

import importlib
import inspect
import logging
import os
import pkgutil
import time
from pathlib import Path

import pytest

import missing_link
from missing_link.errors import BadURL, ConfigError, MissingLinkError

from .helpers import free_port, ml

# ---- one error tree ----------------------------------------------------------------------------
#: exception classes outside the tree, and why
OUTSIDE = {
    # the board runtime runs on MicroPython (it does not ship errors.py); BreakIn is the REPL's
    # Ctrl-C on the board's own console, control flow rather than an error
    "missing_link.board.firmware.BreakIn",
    # a virtual board's power switched off: unwinds the firmware's own loop like a power cut, a
    # BaseException so that no `except Exception` in the firmware can catch it (control flow)
    "missing_link.virtual.boardfile.PowerOff",
    # (the same runtime: the OSErrors its drivers raise for a part that is not the one they
    # drive, or never gets ready, so its log names the fault: board/log.py)
    "missing_link.board.log.NoReady",
    "missing_link.board.log.WrongPart",
}


def exception_classes() -> dict[str, type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    for mod in pkgutil.walk_packages(missing_link.__path__, "missing_link."):
        if mod.name.endswith("__main__") or mod.name == "missing_link.board.main":
            continue  # (runs the CLI; the board's entry point imports the board's own modules)
        module = importlib.import_module(mod.name)
        for obj in vars(module).values():
            if (
                inspect.isclass(obj)
                and issubclass(obj, BaseException)
                and obj.__module__ == mod.name
            ):
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def test_every_error_missing_link_defines_is_a_missing_link_error() -> None:
    classes = exception_classes()
    assert len(classes) > 20  # (the walk found them)
    outside = {
        name for name, cls in classes.items() if not issubclass(cls, MissingLinkError)
    } - OUTSIDE
    assert not outside, f"not under MissingLinkError: {sorted(outside)}"
    assert set(classes) >= OUTSIDE  # (an exemption that no longer exists goes)


def test_input_errors_stay_value_errors() -> None:
    """``except ValueError`` callers keep working."""
    from missing_link.host.config import ConfigRefused
    from missing_link.j2a import BlobError
    from missing_link.publishers.recover import RecoverError

    for cls in (ConfigError, BadURL, ConfigRefused, BlobError, RecoverError):
        assert issubclass(cls, MissingLinkError) and issubclass(cls, ValueError), cls


@pytest.mark.slow
@pytest.mark.parametrize(
    ("argv", "code"),
    [
        (["run", "--config", "{bad}"], 2),  # a config file that is not there: ConfigError
        (["call", "tcp://127.0.0.1:{port}", "a2jEcho", "--timeout", "0.5"], 1),  # no board
    ],
)
def test_exit_codes_stay_as_documented(argv: list[str], code: int, tmp_path: Path) -> None:
    """ConfigError is a MissingLinkError now: the CLI still says 2 for it (docs/cli.md)."""
    bad = tmp_path / "bad.toml"
    bad.write_text("[daemon]\nbackoff_max = -1\n")
    args = [a.format(bad=bad, port=free_port()) for a in argv]
    env = {**os.environ, "MISSING_LINK_CONTROL": str(tmp_path / "none.sock")}
    out = ml(*args, timeout=60, env=env)
    assert out.returncode == code, out.stderr
    assert out.stderr.startswith("missing-link: error: ") and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr


def test_the_log_filter_says_a_record_whose_arguments_do_not_fit() -> None:
    from missing_link.logs import SafeLog

    rec = logging.LogRecord("x", logging.ERROR, "", 0, "needs two %s %s", ("one",), None)
    assert SafeLog(clock=time.monotonic).filter(rec)
    assert rec.msg.startswith("needs two %s %s (its arguments did not fit: ('one',))")
