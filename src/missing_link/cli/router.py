"""``router``: a Zenoh router for daemons and consumers on several machines."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Any

from .common import EXIT_FAIL, EXIT_USAGE


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router (like rmw_zenohd, without ROS 2): daemons and consumers on several
    machines meet here.  Multicast scouting off; prints one READY line, stops on SIGINT/SIGTERM."""
    import zenoh

    for endpoint in (args.listen or []) + (args.connect or []):
        if "/" not in endpoint or "://" in endpoint:
            print(
                f"missing-link: error: {endpoint!r} is not a Zenoh endpoint "
                "(e.g. tcp/127.0.0.1:7447)",
                file=sys.stderr,
            )
            return EXIT_USAGE
    if not args.listen:
        print("missing-link: error: --listen ENDPOINT is required", file=sys.stderr)
        return EXIT_USAGE
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("listen/endpoints", json.dumps(args.listen))
    cfg.insert_json5("connect/endpoints", json.dumps(args.connect or []))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as e:
        print(
            f"missing-link: error: zenoh router on {', '.join(args.listen)}: {e}", file=sys.stderr
        )
        return EXIT_FAIL
    with session:
        print(f"READY zenoh router {session.info.zid()} on {', '.join(args.listen)}", flush=True)
        stop.wait()
    return 0


def add_parsers(sub: Any) -> None:
    sp = sub.add_parser("router", help="a Zenoh router for daemons and consumers on several hosts")
    sp.add_argument(
        "--listen", action="append", help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    sp.add_argument("--connect", action="append", help="another router to join (repeatable)")
    sp.set_defaults(func=cmd_router)
