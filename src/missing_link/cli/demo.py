"""``missing-link demo``: the thesis test rig (:mod:`.rig`) on two virtual boards, recorded."""

from __future__ import annotations

import argparse
import sys

from .common import EXIT_USAGE


def cmd_demo(args: argparse.Namespace) -> int:
    from .rig import run_demo

    if args.duration < 1:
        print("missing-link: error: --duration must be at least 1 s", file=sys.stderr)
        return EXIT_USAGE
    return run_demo(duration=args.duration, seed=args.seed, record=args.record, web=args.web)
