"""``run`` (the daemon) and ``recover`` (a recording whose process died)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

from ..errors import BadURL, ConfigError, without_prefix
from .common import EXIT_FAIL, EXIT_INTERRUPTED, EXIT_USAGE, error

if TYPE_CHECKING:
    from ..daemon import Daemon


def build_config(args: argparse.Namespace) -> Any:
    from ..daemon.config import BoardSpec, Config, load_config
    from ..daemon.discover_spec import DiscoverSpec, parse_usb_id
    from ..publishers.registry import unavailable

    # the console's sample lines would scroll through the live view: --view shows them itself
    default = ["bus"] if args.view else ["bus", "console"]
    cfg = load_config(args.config) if args.config else Config(publishers=default)
    cfg.boards.extend(BoardSpec(url=u) for u in args.url)
    for name in args.publisher or []:
        why = unavailable(name)
        if why is not None:
            raise ConfigError(f"--publisher {name!r}: {why}")
        if name not in cfg.publishers:
            cfg.publishers.append(name)
    if args.foxglove is not None:
        if "foxglove" not in cfg.publishers:
            cfg.publishers.append("foxglove")
        cfg.publisher_options.setdefault("foxglove", {})["port"] = args.foxglove
    if args.web is not None:
        from ..publishers.web import parse_addr

        if "web" not in cfg.publishers:
            cfg.publishers.append("web")
        web = cfg.publisher_options.setdefault("web", {})
        web["host"], web["port"] = parse_addr(args.web)
    if args.record:
        if "mcap" not in cfg.publishers:
            cfg.publishers.append("mcap")
        cfg.publisher_options.setdefault("mcap", {})["path"] = args.record
    if args.auto or args.port or args.usb_id or args.serial or args.any_usb:
        spec = cfg.discover or DiscoverSpec()
        if args.port:
            spec.ports = list(args.port)
        if args.usb_id:
            try:
                spec.ids = [parse_usb_id(i) for i in args.usb_id]
            except ValueError as e:
                raise ConfigError(f"--usb-id {e}") from None
            spec.vid = spec.pid = None
        if args.serial:
            spec.serial = args.serial
        if args.any_usb:
            spec.any_usb, spec.vid, spec.pid = True, None, None
        cfg.discover = spec
    if args.listen:
        from ..daemon.listen_spec import parse_listen

        parse_listen(args.listen)  # (BadURL: exit 2, at once)
        cfg.listen = args.listen
    if args.accept:
        cfg.accept = args.accept
    if cfg.control is None:  # (config/call/info reach the boards through it: docs/cli.md)
        from ..daemon.control.endpoint import default_control_path

        cfg.control = default_control_path()
    if not cfg.boards and cfg.discover is None and cfg.listen is None:
        raise BadURL(
            "no boards: give URLs on the command line, [[board]] tables or [discover] in "
            "--config, --auto, or --listen for boards that dial in"
        )
    return cfg


def _announce(daemon: Daemon) -> None:
    """What runs, and where each face is (stderr)."""
    if daemon.discovery is not None:
        what = daemon.discovery.spec.describe()
        print(f"missing-link: discovering boards on {what}", file=sys.stderr)
    print(
        f"missing-link: running {len(daemon.sessions)} board(s), publishers: "
        f"{', '.join(p.name for p in daemon.publishers)} (Ctrl-C stops)",
        file=sys.stderr,
    )
    for p in daemon.publishers:
        url = getattr(p, "url", None)
        if url:
            print(f"missing-link: {p.name} at {url}", file=sys.stderr)
    if daemon.control is not None:
        print(f"missing-link: control endpoint {daemon.control.path}", file=sys.stderr)
    if daemon.dialins is not None:
        accept = daemon.config.accept
        print(f"missing-link: boards dial in at {daemon.dialins.listener.url} "
              f"(accept {accept})", file=sys.stderr)  # fmt: skip


def cmd_run(args: argparse.Namespace) -> int:
    from ..daemon import Daemon

    daemon = Daemon(build_config(args))  # config, URL and descriptor errors: exit 2, at once
    given = list(daemon.sessions)  # (boards found by --auto come and go; these were asked for)
    stop = threading.Event()
    interrupted = []

    def on_signal(signum: int, frame: object) -> None:
        if signum == signal.SIGINT:
            interrupted.append(signum)
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    code = 0
    with daemon:
        _announce(daemon)
        if args.wait_up and not daemon.wait_until_up(args.wait_up):
            for s in daemon.sessions:
                if s.state != "up":
                    print(
                        f"missing-link: error: {s.spec.url}: not up within {args.wait_up:g} s: "
                        f"{without_prefix(s.spec.url, s.error or s.state)}",
                        file=sys.stderr,
                    )
            code = EXIT_FAIL
        elif args.view:
            from .view import LiveView

            LiveView(daemon).run(stop, args.duration or None)
        else:
            _wait_watching(daemon, stop, args.duration or None)
    print_summary(daemon, sys.stderr)
    failures = daemon.failures()
    for line in failures:
        print(f"missing-link: error: {line}", file=sys.stderr)
    if code == 0:
        # A board it was given that never came up (nothing listening, the port taken by
        # another daemon, descriptors refused) fails the run: the user asked for that board.
        for s in given:
            if s.connects == 0:
                why = without_prefix(s.spec.url, s.error or s.state)
                print(f"missing-link: error: {s.spec.url}: never up: {why}", file=sys.stderr)
                code = EXIT_FAIL
    if interrupted:
        return EXIT_INTERRUPTED
    return EXIT_FAIL if failures else code


def _wait_watching(daemon: Any, stop: threading.Event, duration: float | None) -> None:
    """Wait for the end; a publisher that fails for good (a recording that cannot write) ends
    the run at once, loudly, rather than running on without it."""
    deadline = None if duration is None else time.monotonic() + duration
    while not stop.wait(0.2):
        if daemon.failures():
            return
        if deadline is not None and time.monotonic() >= deadline:
            return


def print_summary(daemon: Any, out: Any) -> None:
    """What happened, with a number next to every loss: per board, then per publisher."""
    for s in daemon.status():
        extra = [
            f"{s[k]} {label}"
            for k, label in (
                ("lost_sifs", "lost SIFs"),
                ("bad_sifs", "bad SIFs"),
                ("unknown_sifs", "unknown SIFs"),
                ("clock_outliers", "clock outliers"),
                ("bad_checksums", "bad checksums"),
                ("stale_links", "stale links"),
                ("errors", "errors caught"),
            )
            if s.get(k)
        ]
        print(
            f"missing-link: {s['board']}: {s['samples']} samples"
            + "".join(f", {e}" for e in extra)
            + f", {s['connects']} connect(s), state {s['state']}"
            + (  # (one that never came up: the error line after this says why)
                f" ({without_prefix(s['url'], s['error'])})"
                if s["error"] and s["state"] != "up" and s["connects"]
                else ""
            ),
            file=out,
        )
    for p in daemon.publishers:
        st = p.status()
        bits = []
        if "recorded" in st:  # a recording: what is in its files (recover restores as many)
            bits.append(f"{st['recorded']} messages")
        elif "messages" in st:
            bits.append(f"{st['messages']} messages")
        bits.append(f"{st.get('dropped', 0)} dropped")
        if st.get("errors"):  # (bugs caught, by kind: the log has each kind's traceback)
            bits.append(f"{st['errors']} errors caught: {st['error_kinds']}")
        bags = getattr(p, "bags", None)
        if bags:
            bits.append("recorded " + ", ".join(str(b) for b in bags))
        if p.name != "bus" or st.get("dropped") or st.get("errors"):
            print(f"missing-link: publisher {p.name}: {', '.join(bits)}", file=out)


def cmd_recover(args: argparse.Namespace) -> int:
    from ..publishers.recover import recover_bag

    try:
        dest, count = recover_bag(args.path, args.out)
    except (FileNotFoundError, FileExistsError, ValueError) as e:
        return error(e, EXIT_USAGE)
    except OSError as e:
        return error(f"cannot recover {args.path}: {e}", EXIT_FAIL)
    print(f"recovered {count} messages into {dest}")
    return 0
