"""``examples DIR``: the example board files and configuration installed with the package
(``missing_link/examples``, package data), written out where a user can read and edit them; and
the hint a command adds when a file it was given is not there but an installed example of that
name is (a user of an installed package has no checkout's ``examples/``)."""

from __future__ import annotations

import argparse
import os
import sys
from importlib import resources
from pathlib import Path

from .common import EXIT_FAIL, EXIT_USAGE, error


def installed() -> Path:
    """Where the examples are installed (beside the package's modules)."""
    return Path(str(resources.files("missing_link") / "examples"))


def example_files() -> list[Path]:
    """Every installed example, relative to :func:`installed`, sorted (the board files, the
    daemon's configuration, a descriptor file, the certificate script)."""
    top = installed()
    return sorted(
        p.relative_to(top) for p in top.rglob("*") if p.is_file() and "__pycache__" not in p.parts
    )


def cmd_examples(args: argparse.Namespace) -> int:
    out = Path(args.dir)
    files = example_files()
    if not files:
        return error(f"no examples installed at {installed()}", EXIT_FAIL)
    there = [f for f in files if (out / f).exists()]
    if there and not args.force:
        print(
            f"missing-link: error: {out / there[0]} exists ({len(there)} of the "
            f"{len(files)} files are there already; --force replaces them)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    top = installed()
    for f in files:
        dst = out / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes((top / f).read_bytes())
        if f.suffix == ".sh":
            os.chmod(dst, 0o755)
        print(f"wrote {dst}")
    print(
        f"try:  missing-link board --file {out / 'boards' / 'thesis-rig.py'} --listen pty\n"
        f"      missing-link run --config {out / 'missing-link.toml'}   (every key explained)\n"
        f"      missing-link flash {out / 'boards' / 'thesis-rig.py'} --port /dev/ttyACM0 "
        "--dry-run"
    )
    return 0


def hint(paths: list[str]) -> str:
    """What to add to "cannot read" when one of ``paths`` (the files a command was given) is
    missing and is, by name, an installed example (or lies under an ``examples`` directory):
    where the installed one is and how to write them all out; "" when none is."""
    names = {f.name: f for f in example_files()}
    for text in paths:
        p = Path(text)
        if p.exists():
            continue
        if p.name in names:
            return (
                f" ({p.name} is an example installed with missing-link: "
                f"{installed() / names[p.name]}; `missing-link examples DIR` writes them all)"
            )
        if "examples" in p.parts:
            return (
                f" (the examples installed with missing-link: {', '.join(sorted(names))}; "
                "`missing-link examples DIR` writes them out)"
            )
    return ""
