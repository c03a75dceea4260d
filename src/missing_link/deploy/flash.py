"""``missing-link flash BOARDFILE``: put the firmware for a board file on the board and check
that it answers.

MicroPython boards (RP2040, ESP32): the board runtime, the drivers the board file uses, the
board file (as ``/board.py``) and ``main.py`` are staged in a temporary directory and copied with
mpremote (``fs cp -r``), then the board is reset; mpremote's own "\\r\\x03\\x03" stops a running
firmware first (see board/firmware.py).  AVR boards (``mcu = atmega...``): the firmware is
generated and built (``gen-firmware``, ``make -C firmware/avr``) and written with avrdude.
Then the port is opened as a J2A link and the board's name and transducers are compared with the
board file.  ``--dry-run`` prints every file and command without touching the board."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..board import drivers as drivers_pkg
from .avr import flash_avr
from .boardfile import BoardFile
from .check import FlashError, verify

BOARD_PKG = Path(drivers_pkg.__file__).resolve().parent.parent
#: runtime modules every MicroPython board needs (host-only helpers stay on the host)
RUNTIME = (
    "__init__.py", "clock.py", "dtypes.py", "transducer.py", "runtime.py", "config.py", "store.py",
    "timing.py", "failsafe.py", "wire.py", "firmware.py", "link.py",
)  # fmt: skip


@dataclass(frozen=True)
class Copy:
    local: Path
    remote: str  #: path on the board


def micropython_files(bf: BoardFile) -> list[Copy]:
    """Everything that goes on a MicroPython board for this board file, in copy order."""
    out = [Copy(BOARD_PKG / name, f"lib/mlboard/{name}") for name in RUNTIME]
    out.append(Copy(BOARD_PKG / "drivers" / "__init__.py", "lib/mlboard/drivers/__init__.py"))
    for drv in bf.drivers():
        module = drivers_pkg.DRIVERS[drv][0]
        out.append(Copy(BOARD_PKG / "drivers" / f"{module}.py", f"lib/mlboard/drivers/{module}.py"))
    out.append(Copy(bf.path.resolve(), "board.py"))
    out.append(Copy(BOARD_PKG / "main.py", "main.py"))
    return out


def mpremote_command(port: str, stage: Path, mpremote: list[str]) -> list[str]:
    cmd = [*mpremote, "connect", port]
    cmd += ["fs", "cp", "-r", str(stage / "lib"), ":", "+"]
    cmd += ["fs", "cp", str(stage / "board.py"), ":board.py", "+"]
    cmd += ["fs", "cp", str(stage / "main.py"), ":main.py", "+", "reset"]
    return cmd


def stage_files(files: list[Copy], stage: Path) -> None:
    for c in files:
        dst = stage / c.remote
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(c.local, dst)


def flash(
    bf: BoardFile,
    port: str,
    *,
    dry_run: bool = False,
    mpremote: list[str] | None = None,
    say: Callable[[str], None] = print,
    check: bool = True,
    key: str | None = None,
) -> int:
    if bf.is_avr:
        if key:
            raise FlashError("--key: the AVR runtime has no network link to sign")
        return flash_avr(bf, port, dry_run=dry_run, say=say, check=check)
    files = micropython_files(bf)
    link = bf.board.get("link", {})
    if key:  # over USB only: never over a network (docs/signing.md)
        if "://" in port and not port.startswith("serial://"):
            raise FlashError(f"--key goes over USB only, not {port}")
        from ..transport.signed import load_key

        load_key(key)  # (a key that does not load fails here, not on the board)
        files.append(Copy(Path(key).resolve(), str(link.get("key_file", "mlkey.bin"))))
    elif link.get("key_file"):
        raise FlashError(f"{bf.path}: the link has a key_file: give the key with --key")
    mp = mpremote or [sys.executable, "-m", "mpremote"]
    url = port if "://" in port else f"serial://{port}"
    with tempfile.TemporaryDirectory(prefix="missing-link-flash-") as tmp:
        stage = Path(tmp)
        cmd = mpremote_command(port, stage, mp)
        if dry_run:
            say(f"would copy to {port} ({bf.mcu}, MicroPython):")
            for c in files:
                say(f"  {c.local} -> :{c.remote}")
            say("would run: " + shlex.join(cmd))
            say(f"then check that {url} answers J2A as {bf.name!r}")
            return 0
        stage_files(files, stage)
        say(f"copying {len(files)} files to {port} with mpremote ...")
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        except FileNotFoundError:
            raise FlashError(f"cannot run {mp[0]}: pip install mpremote") from None
        except subprocess.TimeoutExpired:
            raise FlashError(f"mpremote on {port} took over 300 s") from None
        if r.returncode != 0:
            tail = (r.stderr or r.stdout).strip().splitlines()
            raise FlashError(f"mpremote failed on {port}: {tail[-1] if tail else r.returncode}")
    if check and link.get("kind") == "tcp":
        say(
            "a network board: check it once it joined its network: missing-link info "
            f"signed+tcp://HOST:{link.get('port', 5000)}?key=KEYFILE"
        )
    elif check:
        say(verify(url, bf))
    return 0
