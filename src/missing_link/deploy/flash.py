"""``missing-link flash BOARDFILE``: put the firmware for a board file on the board and check
that it answers.

MicroPython boards (RP2040, ESP32): a board file whose firmware cannot fit the board's heap is
refused first, with the numbers (heap.py).  Then the board runtime, the drivers the board file
uses, the board file (as ``/board.py``), the signing key (``--key``, as the link's ``key_file``) and
``main.py`` are staged in a temporary directory and every one of them is copied with mpremote
(``fs cp``; a new key replaces the old one), then the board is reset.  A running firmware turns
Ctrl-C off and stops only on the break between frames (board/wire.py: "\\x03\\x03repl" then CR
or LF); mpremote (1.29) sends only "\\r\\x03", so ``send_break`` stops it first: the port
opened, 50 ms (a frame cut short ends at the firmware's 10 ms receive timeout, and its rest is
skipped until the line has been quiet 10 ms more: board/wire.py), the break
written, the firmware's "missing-link firmware stopped: REPL" awaited (up to 2 s; a board at its
REPL already answers with its prompt and a harmless NameError), the port closed, then mpremote;
neither within 2 s is an error (mpremote would wait for ever on a firmware that streams).
AVR boards (``mcu = atmega...``): the firmware is generated and built (``gen-firmware``, ``make -C
firmware/avr``) and written with avrdude.
Then the port is opened as a J2A link and the board's name and transducers are compared with the
board file, and its ``fw.hash`` with the hash of the runtime files as they were copied
(board/identity.py: the board hashes the files it has at boot).  ``--dry-run`` prints every file
and command without touching the board."""

from __future__ import annotations

import importlib.util
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..board import drivers as drivers_pkg
from ..board.identity import BOARD_FILE, FirmwareHash
from .avr import AVR_DIR, flash_avr
from .boardfile import BoardFile
from .check import FlashError, verify
from .heap import check_fit

BOARD_PKG = Path(drivers_pkg.__file__).resolve().parent.parent
#: runtime modules every MicroPython board needs (host-only helpers stay on the host)
RUNTIME = (
    "__init__.py", "clock.py", "dtypes.py", "transducer.py", "runtime.py", "config.py", "store.py",
    "timing.py", "failsafe.py", "memory.py", "wire.py", "firmware.py", "link.py", "identity.py",
    "dial.py", "log.py", "signing.py", "boot.py", "update.py", "builtins.py", "pacing.py",
)  # fmt: skip
#: where the runtime goes on the board: fw.hash is over the files under it (board/identity.py)
LIB = "lib/mlboard/"


@dataclass(frozen=True)
class Copy:
    local: Path
    remote: str  #: path on the board


def micropython_files(bf: BoardFile, key: str | None = None) -> list[Copy]:
    """Everything that goes on a MicroPython board for this board file, in copy order: the
    runtime and drivers in ``lib``, the board file as ``board.py``, the signing key (``key``) as
    the link's ``key_file``, and ``main.py`` last (the board boots only complete)."""
    out = [Copy(BOARD_PKG / name, f"lib/mlboard/{name}") for name in RUNTIME]
    out.append(Copy(BOARD_PKG / "drivers" / "__init__.py", "lib/mlboard/drivers/__init__.py"))
    for drv in bf.drivers():
        module = drivers_pkg.DRIVERS[drv][0]
        out.append(Copy(BOARD_PKG / "drivers" / f"{module}.py", f"lib/mlboard/drivers/{module}.py"))
    out.append(Copy(bf.path.resolve(), "board.py"))
    if key is not None:  # (a plain name in the board's root: boardfile.py checks it)
        key_file = str(bf.board.get("link", {}).get("key_file", ""))
        out.append(Copy(Path(key).expanduser().resolve(), key_file))
    out.append(Copy(BOARD_PKG / "main.py", "main.py"))
    return out


def firmware_hash(files: list[Copy]) -> str:
    """The ``fw.hash`` a board reports once ``files`` are on it: the runtime's files, as the
    board hashes its ``lib/mlboard``, and the board file (board/identity.py)."""
    out = FirmwareHash()
    for c in files:
        if c.remote.startswith(LIB) or c.remote == BOARD_FILE:
            data = c.local.read_bytes()
            out.add(c.remote.removeprefix(LIB), len(data), [data])
    digest: str = out.digest()
    return digest


def mpremote_command(port: str, stage: Path, files: list[Copy], mpremote: list[str]) -> list[str]:
    """One mpremote run that copies every staged file (``lib`` as a tree, every other file by
    name, in ``files``' order: main.py last), then resets the board."""
    cmd = [*mpremote, "connect", port]
    tops: list[str] = []
    for c in files:
        top = c.remote.split("/", 1)[0]
        if top not in tops:
            tops.append(top)
    for top in tops:
        if any(c.remote.startswith(top + "/") for c in files):
            cmd += ["fs", "cp", "-r", str(stage / top), ":", "+"]
        else:
            cmd += ["fs", "cp", str(stage / top), f":{top}", "+"]
        if top == LIB.split("/", 1)[0]:
            cmd += ["exec", prune_code(files), "+"]
    return [*cmd, "reset"]


def prune_code(files: list[Copy]) -> str:
    """MicroPython that removes the files under ``lib/mlboard`` that this flash did not put
    there (a driver an earlier board file used): the runtime is then exactly the files
    ``firmware_hash`` hashed, and the board's fw.hash says so.  It also removes ``fw/``, the
    update slots and their boot record (board/boot.py): the firmware flashed here runs.
    Nothing else is touched."""
    keep = sorted(c.remote[len(LIB) :] for c in files if c.remote.startswith(LIB))
    return (
        f"import os\nkeep = {tuple(keep)!r}\ndef prune(rel):\n"
        f"    for name in os.listdir({LIB.rstrip('/')!r} + rel):\n"
        "        path = rel + '/' + name\n"
        f"        full = {LIB.rstrip('/')!r} + path\n"
        "        if os.stat(full)[0] & 0x4000:\n            prune(path)\n"
        "        elif path[1:] not in keep:\n            os.remove(full)\n"
        "prune('')\n"
        "def wipe(path):\n"
        "    try:\n        st = os.stat(path)\n    except OSError:\n        return\n"
        "    if st[0] & 0x4000:\n"
        "        for name in os.listdir(path):\n            wipe(path + '/' + name)\n"
        "        os.rmdir(path)\n"
        "    else:\n        os.remove(path)\n"
        "wipe('fw')\n"
    )


def stage_files(files: list[Copy], stage: Path) -> None:
    for c in files:
        dst = stage / c.remote
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(c.local, dst)


#: what flash sends a running firmware first, and what the firmware answers when it stops
BREAK = b"\r\x03\x03repl\r"
STOPPED = b"missing-link firmware stopped: REPL"
REPL_PROMPT = b">>> "  # (a board at its REPL already: the break is a harmless NameError there)


def send_break(port: str, wait_s: float = 2.0) -> str:
    """Stop a running firmware (see the module's docstring): "stopped" when it said so, "repl"
    when a MicroPython prompt answered instead (no firmware ran).  FlashError when the port
    cannot be opened, or when neither came within ``wait_s``: mpremote would wait on a
    board that does not listen."""
    import time

    import serial

    try:
        port_ = serial.serial_for_url(port, 115200, timeout=0.05)
    except (serial.SerialException, ValueError) as e:
        raise FlashError(f"cannot open {port}: {e}") from None
    got = b""
    with port_:
        time.sleep(0.05)  # (the quiet a cut frame's rest needs: the module's docstring)
        try:
            port_.write(BREAK)
            port_.flush()
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                got = (got + port_.read(512))[-4096:]
                if STOPPED in got:
                    return "stopped"
                if REPL_PROMPT in got:
                    return "repl"
        except (serial.SerialException, OSError) as e:
            raise FlashError(f"{port}: lost while stopping the firmware: {e}") from None
    heard = "nothing" if not got else f"{len(got)} bytes, none of them the line"
    raise FlashError(
        f"{port}: the firmware did not stop: no {STOPPED.decode()!r} nor a REPL prompt within "
        f"{wait_s:g} s after the break ({heard}); reset the board and try again"
    )


def _warn(text: str) -> None:
    print(f"missing-link: warning: {text}", file=sys.stderr)


def check_key(bf: BoardFile, port: str, key: str | None, warn: Callable[[str], None]) -> None:
    """The key goes where the board reads it, over USB only; a network link without one is
    unauthenticated J2A, said so."""
    link = bf.board.get("link", {})
    key_file = link.get("key_file")
    if key:  # over USB only: never over a network (docs/signing.md)
        if "://" in port and not port.startswith("serial://"):
            raise FlashError(f"--key goes over USB only, not {port}")
        if not key_file:
            raise FlashError(
                f"--key: {bf.path}: the link has no key_file, so the board would not use the "
                "key (a network link: {'kind': 'tcp', 'port': 5000, 'key_file': 'mlkey.bin'})"
            )
        from ..transport.signed import load_key

        load_key(key)  # (a key that does not load fails here, not on the board)
    elif key_file:
        raise FlashError(f"{bf.path}: the link has a key_file: give the key with --key")
    elif link.get("dial"):
        warn(
            f"{bf.path}: a board that dials without a key_file speaks unsigned J2A: only a "
            "daemon listening on loopback takes it (make a key with `missing-link key new`, "
            "add 'key_file' to the link: docs/signing.md)"
        )
    elif link.get("kind") == "tcp":
        warn(
            f"{bf.path}: a tcp link without a key_file: J2A unauthenticated on the network, "
            f"anyone who reaches port {link.get('port', 5000)} commands the board (make a key "
            "with `missing-link key new`, add 'key_file' to the link: docs/signing.md)"
        )


def flash(
    bf: BoardFile,
    port: str,
    *,
    dry_run: bool = False,
    mpremote: list[str] | None = None,
    say: Callable[[str], None] = print,
    warn: Callable[[str], None] = _warn,
    check: bool = True,
    key: str | None = None,
    board_id: str | None = None,
) -> int:
    """``board_id`` (AVR only): the board.id the board takes (flash --id); a MicroPython board's
    is its chip's (machine.unique_id)."""
    if bf.is_avr:
        if key:
            raise FlashError("--key: the AVR runtime has no network link to sign")
        if dry_run:
            can_build_avr(bf)  # (a dry run that could not build says so, as the run would)
        return flash_avr(bf, port, dry_run=dry_run, say=say, check=check, board_id=board_id)
    if board_id:
        raise FlashError(
            "--id: a MicroPython board's board.id is its chip's own (machine.unique_id); "
            "--id is for AVR boards"
        )
    check_key(bf, port, key, warn)
    fit = check_fit(bf)  # (a board file that cannot fit is refused here: DoesNotFit)
    files = micropython_files(bf, key or None)
    fw_hash = firmware_hash(files)
    if mpremote is None and importlib.util.find_spec("mpremote") is None:  # (an extra: flash)
        raise ModuleNotFoundError("No module named 'mpremote'", name="mpremote")
    mp = mpremote or [sys.executable, "-m", "mpremote"]
    url = port if "://" in port else f"serial://{port}"
    with tempfile.TemporaryDirectory(prefix="missing-link-flash-") as tmp:
        stage = Path(tmp)
        cmd = mpremote_command(port, stage, files, mp)
        if dry_run:
            if fit is not None:
                say(f"its firmware needs about {fit.need // 1024} KiB of the {bf.mcu}'s heap")
            say(f"would stop a running firmware on {port}: {BREAK!r}, then copy ({bf.mcu}, "
                "MicroPython):")  # fmt: skip
            for c in files:
                say(f"  {c.local} -> :{c.remote}")
            say("would run: " + shlex.join(cmd))
            say(f"then check that {url} answers J2A as {bf.name!r} with fw.hash {fw_hash}")
            return 0
        stage_files(files, stage)
        if send_break(port) == "stopped":
            say(f"{port}: the running firmware stopped for the REPL")
        say(f"copying {len(files)} files to {port} with mpremote ...")
        _run_mpremote(cmd, port)
    link = bf.board.get("link", {})
    if check and link.get("kind") == "tcp":
        key_arg = "?key=KEYFILE" if link.get("key_file") else ""
        say(
            "a network board: check it once it joined its network (fw.hash "
            f"{fw_hash}): " + _network_check(link, key_arg)
        )
    elif check:
        say(verify(url, bf, expect={"fw.hash": fw_hash}))
    return 0


#: what building an AVR image runs (avr.py: make in the package's firmware/avr), and writing it
AVR_TOOLS = ("make", "avr-gcc", "avr-objcopy", "avrdude")


def can_build_avr(bf: BoardFile) -> None:
    """Everything an AVR flash needs but the board: the C sources installed with the package,
    the tools on PATH, and board tables that generate (avrgen: the board file's own errors);
    FlashError (or ConfigError) naming the first thing missing."""
    if not (AVR_DIR / "Makefile").is_file():
        raise FlashError(f"the AVR firmware sources are missing from this install ({AVR_DIR})")
    missing = [tool for tool in AVR_TOOLS if shutil.which(tool) is None]
    if missing:
        raise FlashError(
            f"cannot build or write AVR firmware: no {', '.join(missing)} on PATH (Debian: apt "
            "install make gcc-avr avr-libc binutils-avr avrdude)"
        )
    from .avrgen import write_avr

    with tempfile.TemporaryDirectory(prefix="missing-link-avr-check-") as tmp:
        write_avr(bf, Path(tmp))


def _network_check(link: dict[str, object], key_arg: str) -> str:
    signed = "signed+" if key_arg else ""
    if link.get("dial"):  # (it dials the daemon: the daemon shows it by its id)
        return f"missing-link run --listen {signed}tcp://ADDR:PORT{key_arg} (the board dials it)"
    return f"missing-link info {signed}tcp://HOST:{link.get('port', 5000)}{key_arg}"


MPREMOTE_TIMEOUT_S = 300.0


def _run_mpremote(cmd: list[str], port: str) -> None:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=MPREMOTE_TIMEOUT_S)
    except FileNotFoundError:
        raise FlashError(f"cannot run {cmd[0]}: pip install mpremote") from None
    except subprocess.TimeoutExpired:
        raise FlashError(f"mpremote on {port} took over {MPREMOTE_TIMEOUT_S:g} s") from None
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()
        raise FlashError(f"mpremote failed on {port}: {tail[-1] if tail else r.returncode}")
