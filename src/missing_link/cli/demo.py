"""``missing-link demo``: the thesis test rig (:mod:`.rig`) on two virtual boards, recorded."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import EXIT_USAGE


def cmd_demo(args: argparse.Namespace) -> int:
    from .rig import run_demo

    if args.duration < 1:
        print("missing-link: error: --duration must be at least 1 s", file=sys.stderr)
        return EXIT_USAGE
    return run_demo(duration=args.duration, seed=args.seed, record=args.record)


def add_parsers(sub: Any) -> None:
    sp = sub.add_parser("demo", help="the thesis test rig on two virtual boards, recorded")
    sp.add_argument("--duration", type=float, default=20.0, help="seconds to run (20)")
    sp.add_argument("--record", default="recordings", help="recording directory (recordings)")
    sp.add_argument("--seed", type=int, default=0)
    sp.set_defaults(func=cmd_demo)
