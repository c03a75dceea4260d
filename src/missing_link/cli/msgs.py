"""``create-msgs``: ``.msg`` files and a ROS package from descriptors (and ``--build``).

One package serves a daemon with several boards: give every board (URLs, descriptor files, or
the daemon's config with ``--config``) and the package holds every board's types, named as the
daemon names them (board names and type collisions through the daemon's own claims, boards in
the order given).  A package written earlier keeps the types of boards not given this time
(its manifest says which board each type came from); ``--fresh`` starts it over."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..descriptors import Transducer
from ..errors import BadURL, ConfigError
from ..host.board import Board
from .common import EXIT_FAIL, EXIT_USAGE, error

if TYPE_CHECKING:
    from ..daemon.claims import Claims
    from ..ros.package import Generated


@dataclass(frozen=True)
class Source:
    """One board's descriptors: where they came from and the name it wants."""

    origin: str  #: URL or file
    name: str | None  #: the configured name, or the board's own (None: a file without one)
    transducers: list[Transducer]


def _from_url(url: str, name: str | None, timeout: float) -> Source:
    from ..daemon.claims import board_token

    with Board.open(url, timeout=timeout) as board:
        if board.transducers is None:
            raise ConfigError(
                f"{board.name} is an original board without descriptors; give them in a file "
                "(see docs/descriptors.md), or descriptors = FILE in its [[board]] table"
            )
        token, warning = board_token(name, board.properties, url)
        if warning:
            print(f"missing-link: {url}: {warning}", file=sys.stderr)
        return Source(url, token, board.transducers)


def _from_file(path: str, name: str | None) -> Source:
    from ..descriptors import load_descriptor_file
    from ..text import slug

    stem = slug(os.path.splitext(os.path.basename(path))[0]) or "board"
    return Source(path, name or stem, load_descriptor_file(path))


def sources(args: argparse.Namespace) -> list[Source]:
    """Every board asked for, in order: the config's [[board]] tables, then the arguments."""
    out: list[Source] = []
    if args.config:
        from ..daemon.config import load_config

        for spec in load_config(args.config).boards:
            if spec.descriptors:
                out.append(_from_file(spec.descriptors, spec.name))
            else:
                out.append(_from_url(spec.url, spec.name, args.timeout))
    for src in args.source:
        if os.path.exists(src):
            out.append(_from_file(src, None))
        elif "://" in src:
            out.append(_from_url(src, None, args.timeout))
        else:
            raise BadURL(f"{src!r} is neither a file nor a board URL")
    if not out:
        raise BadURL("no boards: give board URLs or descriptor files, or --config FILE")
    return out


def cmd_create_msgs(args: argparse.Namespace) -> int:
    from ..daemon.claims import Claims
    from ..ros.msgs import check_package, package_of
    from ..ros.package import manifest_text, read_manifest, write_package

    try:
        check_package(args.package)
    except ValueError as e:
        return error(e, EXIT_USAGE)
    if args.build and args.ros != 2:
        print("missing-link: error: --build builds ROS 2 packages (--ros 2)", file=sys.stderr)
        return EXIT_USAGE
    boards = sources(args)
    root = os.path.join(args.out, args.package)
    earlier = None if args.fresh else read_manifest(root)
    if earlier is not None and earlier[0] != args.ros:
        raise ConfigError(
            f"{root} is a ROS {earlier[0]} package; --ros {args.ros} cannot add to it "
            "(--fresh starts it over)"
        )
    claims = Claims(args.package)
    names = []
    for src in boards:  # (each board its own claimant, as each session is in the daemon)
        name, warning = claims.name(src, src.name or "board", src.origin)
        if warning:
            print(f"missing-link: {src.origin}: {warning}", file=sys.stderr)
        names.append(name)
    kept, types, made = _types(claims, names, boards, earlier, args)
    files = package_of({k: g.text for k, g in types.items()}, args.package, args.ros)
    try:
        written = write_package(
            args.out,
            args.package,
            files,
            force=args.force,
            manifest=manifest_text(args.ros, types),
        )
    except (FileExistsError, NotADirectoryError) as e:
        return error(e, EXIT_USAGE)
    except OSError as e:
        print(
            f"missing-link: error: cannot write into {args.out}: {e.strerror or e}", file=sys.stderr
        )
        return EXIT_FAIL
    for path in written:
        print(path)
    _say_what_was_made(args, names, boards, kept, made)
    if args.build:
        _build(root, args.build)
    return 0


def _types(
    claims: Claims,
    names: list[str],
    boards: list[Source],
    earlier: tuple[int, dict[str, Generated]] | None,
    args: argparse.Namespace,
) -> tuple[dict[str, Generated], dict[str, Generated], set[str]]:
    """The package's types: those of boards not given now, kept (with those boards as their
    owners), and every given board's, claimed as the daemon claims them; (kept, all, made)."""
    from ..ros.msgs import msg_text, msgdef
    from ..ros.package import Generated

    kept: dict[str, Generated] = {}
    for type_short, g in (earlier[1] if earlier is not None else {}).items():
        others = tuple(b for b in g.boards if b not in names)
        if others or not g.boards:
            kept[type_short] = Generated(others, g.definition, g.text)
            claims.hold(f"{args.package}/msg/{type_short}", g.definition)
    types: dict[str, Generated] = dict(kept)
    made: set[str] = set()
    for name, src in zip(names, boards, strict=True):
        for t in src.transducers:
            full, warning = claims.type(name, t)
            if warning:
                print(f"missing-link: {src.origin}: {warning}", file=sys.stderr)
            short = full.rsplit("/", 1)[1]
            owners = types[short].boards if short in types else ()
            types[short] = Generated((*owners, name), msgdef(t, 2), msg_text(t, args.ros))
            made.add(short)
    return kept, types, made


def _say_what_was_made(
    args: argparse.Namespace,
    names: list[str],
    boards: list[Source],
    kept: dict[str, Generated],
    made: set[str],
) -> None:
    boards_text = ", ".join(f"{n} ({s.origin})" for n, s in zip(names, boards, strict=True))
    print(
        f"{len(made)} message type(s) from {boards_text} in ROS {args.ros} package {args.package}"
        + (
            ""
            if args.build
            else f" ({'colcon build' if args.ros == 2 else 'catkin_make'} to build it)"
        ),
        file=sys.stderr,
    )
    only_kept = sorted(set(kept) - made)
    if only_kept:
        holders = sorted({b for k in only_kept for b in kept[k].boards} or {"an earlier run"})
        print(
            f"kept {len(only_kept)} type(s) of {', '.join(holders)} from the earlier run "
            f"({', '.join(only_kept)}; --fresh starts the package over)",
            file=sys.stderr,
        )


def _build(root: str, prefix: str) -> None:
    """``--build``: build the package and install it into ``prefix`` (ros/build.py)."""
    from ..ros.build import build_package

    log = build_package(
        root, prefix, progress=lambda line: print(f"  {line}", file=sys.stderr, flush=True)
    )
    print(
        f"built and installed into {prefix} (log {log}); the daemon finds it with "
        f'[ros2] prefix = "{os.path.abspath(prefix)}" or '
        f"MISSING_LINK_ROS2_PREFIX={os.path.abspath(prefix)}",
        file=sys.stderr,
    )
