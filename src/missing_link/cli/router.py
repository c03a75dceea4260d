"""``router``: a Zenoh router for daemons and consumers on several machines."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from .common import EXIT_FAIL, EXIT_USAGE, error


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router (like rmw_zenohd, without ROS 2): daemons and consumers on several
    machines meet here.  Multicast scouting off; prints one READY line, stops on SIGINT/SIGTERM."""
    import zenoh

    from ..errors import ConfigError
    from ..publishers.zenoh_config import check_endpoints, session_config

    if not args.listen:
        print("missing-link: error: --listen ENDPOINT is required", file=sys.stderr)
        return EXIT_USAGE
    try:
        check_endpoints("--listen/--connect", (args.listen or []) + (args.connect or []))
        cfg = session_config("router", args.connect or [], args.listen, args.config)
    except ConfigError as e:
        return error(e, EXIT_USAGE)
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
