"""Ring 1 stays pure: the J2A core, the board runtime and the world of virtual boards import no
I/O, threads or clocks."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parent.parent / "src" / "missing_link"
FORBIDDEN = {
    "socket",
    "select",
    "selectors",
    "threading",
    "asyncio",
    "subprocess",
    "os",
    "io",
    "serial",
    "usb",
    "time",
    "signal",
    "multiprocessing",
    "logging",
}
# The board runtime may read its clock (board/clock.py, injected everywhere else) and nothing more.
BOARD_ALLOWED = {
    "board/clock.py": {"time", "os"},
    # the firmware's shell on a microcontroller: the link is I/O by definition
    "board/link.py": {"time", "select", "sys", "socket", "os"},
    # ... and the file a saved configuration lives in
    "board/store.py": {"os"},
    # ... and the firmware's own files, hashed for fw.hash
    "board/identity.py": {"os"},
    # ... and the firmware's slots and their boot record: updates over the link
    "board/boot.py": {"os"},
    "board/update.py": {"os"},
}


def imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_core_modules_import_no_io() -> None:
    checked = 0
    for folder in ("j2a", "board", "world"):
        for path in sorted((SRC / folder).glob("*.py")):
            rel = f"{folder}/{path.name}"
            bad = (imports(path) & FORBIDDEN) - BOARD_ALLOWED.get(rel, set())
            assert not bad, f"{rel} imports {bad}: ring 1 must stay free of I/O"
            checked += 1
    assert checked >= 8


def test_board_runtime_stays_in_micropython_subset() -> None:
    for path in sorted((SRC / "board").glob("*.py")):
        names = imports(path)
        assert not names & {"typing", "dataclasses", "enum", "abc", "__future__"}, path.name
        tree = ast.parse(path.read_text())
        # %-formatting only: MicroPython's f-strings lack '=' and nested format specs.
        assert not any(isinstance(n, ast.JoinedStr) for n in ast.walk(tree)), path.name
        assert not any(isinstance(n, (ast.AnnAssign, ast.Match)) for n in ast.walk(tree)), path.name
