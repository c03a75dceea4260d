"""A power cut at any write of an update leaves a board that starts the old or the new
firmware: the firmware under the real MicroPython (node), its flash a directory written through
as the firmware writes (host.mjs --flash), cut short at every change an update makes to it.

The update runs once with every change journaled (host.mjs --journal: each file as it was
closed, each rename, removal and directory); the flash of a cut before each change, and in the
middle of each file's write (torn), is that journal replayed so far, and a board is powered on
from each: it must start the firmware the boot record's rules say (board/boot.py).  The cut
control itself (--cut-after N: the process ends as a board without power) is checked against
the replay at a few points of a real update."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.flashdir import install
from missing_link.deploy.update import micropython_image, target_of
from missing_link.errors import BoardError, MissingLinkError
from missing_link.host.board import Board
from missing_link.host.update import NOT_BACK, UPDATED, Updater

from .helpers import FirmwareSim

pytestmark = [pytest.mark.slow, pytest.mark.micropython]

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
HOST = FirmwareSim.HOST


@contextmanager
def powered(flash: Path, *extra: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """The board started from ``flash``: (its process, its URL)."""
    p = subprocess.Popen(["node", str(HOST), "-", "--port", "0", "--flash", str(flash), *extra],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)  # fmt: skip
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert line.startswith("LISTEN "), (line, p.stderr.read() if p.stderr else "")
        yield p, f"tcp://127.0.0.1:{line.split()[1]}"
    finally:
        if p.poll() is None:
            p.kill()
        p.wait(10)
        for f in (p.stdin, p.stdout, p.stderr):
            if f is not None:
                f.close()


def started_hash(flash: Path) -> str:
    with powered(flash) as (_p, url), Board.open(url, timeout=5.0, describe=False) as b:
        return b.properties["fw.hash"]


def units(op: dict[str, Any]) -> int:
    return len(base64.b64decode(op.get("data", ""))) + 1 if op["op"] == "write" else 1


def replay(base: Path, ops: list[dict[str, Any]], out: Path, cut: int) -> None:
    """``base`` with the changes of ``ops`` as far as ``cut`` units (flashcut.mjs's count)."""
    shutil.copytree(base, out)
    left = cut
    for op in ops:
        if left <= 0:
            return
        n = min(units(op), left)
        left -= n
        path = out / op["path"]
        if op["op"] == "write":
            path.write_bytes(base64.b64decode(op["data"])[: n - 1])
        elif op["op"] == "mkdir":
            path.mkdir()
        elif op["op"] == "remove":
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
        elif op["op"] == "rename":
            path.rename(out / op["to"])


def tree(d: Path) -> dict[str, bytes | None]:
    return {p.relative_to(d).as_posix(): p.read_bytes() if p.is_file() else None
            for p in sorted(d.rglob("*"))}  # fmt: skip


def update(url: str, slow: Path) -> str:
    """The update to ``slow`` on the board at ``url``: its outcome's state (a board that does
    not come back is not waited for)."""

    def gone(_deadline: float) -> Board:
        raise BoardError(url, "not waited for")

    bf = load_board_file(slow)
    b = Board.open(url, timeout=3.0)
    try:
        u = Updater(micropython_image(bf), target_of(bf, None), trial_s=30)  # (as journaled)
        return u.run(b, gone).state
    except MissingLinkError:  # (the board went in the middle)
        return "cut"
    finally:
        b.close()


# (a board powered on at each of 75 cuts: 128 to 149 s beside other work on a 2-core machine,
# past the default bound of 120 s; the bound is for a hang)
@pytest.mark.timeout(600)
def test_a_power_cut_at_any_write_starts_the_old_or_the_new(tmp_path: Path) -> None:
    base = tmp_path / "base"
    install(load_board_file(ROVER), base)
    slow = tmp_path / "rover-slow.py"
    slow.write_text(ROVER.read_text().replace('"i2c0", "rate_hz": 50', '"i2c0", "rate_hz": 20'))
    old, new = started_hash(base), micropython_image(load_board_file(slow)).fw_hash
    # the update once, journaled, through its restart and confirmation
    run, journal = tmp_path / "run", tmp_path / "journal"
    shutil.copytree(base, run)
    with powered(run, "--journal", str(journal)) as (_p, url):
        from missing_link.deploy.update import update_direct

        bf = load_board_file(slow)
        out = update_direct(url, micropython_image(bf), target_of(bf, None), 30,
                            lambda *a: None, 3.0)  # fmt: skip
        assert out.state == UPDATED, out
    ops = [json.loads(line) for line in journal.read_text().splitlines()]
    records = [i for i, op in enumerate(ops) if op["path"].startswith("fw/boot.")]
    assert len(records) == 3  # the switch, the trial's start, the confirmation
    switch, started, confirmed = records
    before = [sum(units(op) for op in ops[:i]) for i in range(len(ops) + 1)]
    cuts = [(i, before[i]) for i in range(len(ops) + 1)]  # before each change, and after all
    cuts += [(i, before[i] + units(op) // 2) for i, op in enumerate(ops) if op["op"] == "write"]
    cuts += [(i, before[i] + 1) for i in records]  # (a record truncated, nothing of it written)
    print(f"{len(ops)} changes, {before[-1]} units; {len(cuts)} cuts")

    def check(n: int, i: int, cut: int) -> None:
        whole = cut == before[i + 1] if i < len(ops) else True  # (change i is in, whole)
        done = i + 1 if whole and i < len(ops) else i  # changes that are in, whole
        # the boot record's rules: the switch in -> the new one, on trial; its start counted
        # and not confirmed -> back to the old one; confirmed -> the new one
        want = new if switch < done <= started or done > confirmed else old
        flash = tmp_path / f"cut-{n}"  # (n: two cuts may be at one point)
        replay(base, ops, flash, cut)
        got = started_hash(flash)
        assert got == want, (i, cut, ops[i]["op"] if i < len(ops) else "end", got, want)
        shutil.rmtree(flash)

    with ThreadPoolExecutor(2) as pool:  # (each board a process of its own: two at a time)
        for fut in [pool.submit(check, n, i, cut) for n, (i, cut) in enumerate(cuts)]:
            fut.result()
    # the cut control: a real update, the power cut at a few of those points
    for i, cut in ((4, before[4] + units(ops[4]) // 2), (switch, before[switch] + 30),
                   (switch, before[switch + 1])):  # fmt: skip
        flash = tmp_path / f"real-{cut}"
        shutil.copytree(base, flash)
        with powered(flash, "--cut-after", str(cut)) as (p, url):
            state = update(url, slow)
            assert p.wait(20) == 0 and p.stdout is not None
            assert "POWER CUT" in p.stdout.read()
        assert state in ("cut", NOT_BACK), state
        replay(base, ops, tmp_path / "replayed", cut)
        assert tree(flash) == tree(tmp_path / "replayed"), i
        shutil.rmtree(tmp_path / "replayed")
        assert started_hash(flash) == (new if i == switch and cut == before[switch + 1] else old)
