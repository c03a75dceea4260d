"""``create-msgs``: ``.msg`` files and a ROS package from descriptors (and ``--build``)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..host.board import Board
from .common import EXIT_FAIL, EXIT_USAGE, positive


def cmd_create_msgs(args: argparse.Namespace) -> int:
    import os

    from ..descriptors import load_descriptor_file
    from ..ros.msgs import check_package, package_files
    from ..ros.package import write_package

    try:
        check_package(args.package)
    except ValueError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    if args.build and args.ros != 2:
        print("missing-link: error: --build builds ROS 2 packages (--ros 2)", file=sys.stderr)
        return EXIT_USAGE
    if os.path.exists(args.source):
        transducers = load_descriptor_file(args.source)
        origin = args.source
    else:
        with Board.open(args.source, timeout=args.timeout) as board:
            if board.transducers is None:
                print(
                    f"missing-link: error: {board.name} is an original board without descriptors;"
                    " give them in a file (see docs/descriptors.md)",
                    file=sys.stderr,
                )
                return EXIT_USAGE
            transducers = board.transducers
            origin = board.name
    files = package_files(transducers, args.package, args.ros)
    try:
        written = write_package(args.out, args.package, files, force=args.force)
    except (FileExistsError, NotADirectoryError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as e:
        print(
            f"missing-link: error: cannot write into {args.out}: {e.strerror or e}", file=sys.stderr
        )
        return EXIT_FAIL
    for path in written:
        print(path)
    print(
        f"{len(transducers)} message type(s) from {origin} in ROS {args.ros} package "
        f"{args.package}"
        + (
            ""
            if args.build
            else f" ({'colcon build' if args.ros == 2 else 'catkin_make'} to build it)"
        ),
        file=sys.stderr,
    )
    if args.build:
        from ..ros.build import build_package

        root = os.path.join(args.out, args.package)
        log = build_package(
            root, args.build, progress=lambda line: print(f"  {line}", file=sys.stderr, flush=True)
        )
        print(
            f"built and installed into {args.build} (log {log}); the daemon finds it with "
            f'[ros2] prefix = "{os.path.abspath(args.build)}" or '
            f"MISSING_LINK_ROS2_PREFIX={os.path.abspath(args.build)}",
            file=sys.stderr,
        )
    return 0


def add_parsers(sub: Any) -> None:
    sp = sub.add_parser("create-msgs", help="write .msg files and a ROS package from descriptors")
    sp.add_argument("source", help="board URL, or a descriptor file (.toml or transds/1 text)")
    sp.add_argument("--out", required=True, help="directory to write the package into")
    sp.add_argument("--ros", type=int, choices=(1, 2), default=2, help="ROS version (2)")
    sp.add_argument("--package", default="missing_link_msgs", help="package name")
    sp.add_argument("--timeout", type=positive, default=1.0)
    sp.add_argument(
        "--force", action="store_true", help="replace a package directory create-msgs did not write"
    )
    sp.add_argument(
        "--build",
        metavar="PREFIX",
        help="build the ROS 2 package with the ROS 2 in this environment and install it there",
    )
    sp.set_defaults(func=cmd_create_msgs)
