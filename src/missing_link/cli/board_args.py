"""The arguments of the commands that make, run and deploy boards (``flash``, ``update``, ``key``,
``gen-firmware``, ``board``, ``world``, ``relay``, ``examples``): commands.py's table names
them.  Every help text names what an installed package has (``missing-link examples DIR``), not
a checkout's paths."""

from __future__ import annotations

import argparse

from .common import (
    MAX_DURATION_S,
    MAX_RATE_HZ,
    add_timeout,
    count_arg,
    finite,
    number,
    seconds_arg,
)

Parser = argparse.ArgumentParser


def flash(sp: Parser) -> None:
    sp.add_argument(
        "boardfile", help="board file (BOARD = {...}; `missing-link examples DIR` writes examples)"
    )
    sp.add_argument("--port", default="/dev/ttyACM0", help="serial port (/dev/ttyACM0)")
    sp.add_argument("--dry-run", action="store_true", help="list files and commands, touch nothing")
    sp.add_argument(
        "--no-check", action="store_true", help="do not check the board answers J2A afterwards"
    )
    sp.add_argument(
        "--key",
        help="a signing key (missing-link key new) for a board on a network link: copied over "
        "USB as the board file's link key_file, never over the network (docs/signing.md)",
    )
    sp.add_argument(
        "--id",
        help="AVR: the board.id the board takes (into its EEPROM; default: it keeps the one it "
        "has, a new board gets a random one); a MicroPython board's is its chip's",
    )


def update(sp: Parser) -> None:
    sp.add_argument("target", metavar="TARGET", help="board URL or (through a daemon) board name")
    sp.add_argument(
        "boardfile",
        help="the board file of the new firmware (`missing-link examples DIR` writes examples)",
    )
    sp.add_argument(
        "--trial",
        type=lambda s: int(number(5, 3600, unit=" s")(s)),
        default=30,
        metavar="S",
        help="MicroPython: the new firmware's time to complete a handshake with this host, or "
        "the board goes back to the old one (30; 5..3600)",
    )
    sp.add_argument("--id", help="the board.id the board must state (refused if another)")
    sp.add_argument("--json", action="store_true", help="the outcome as JSON (docs/cli.md)")
    add_timeout(sp)


def key(sp: Parser) -> None:
    ksub = sp.add_subparsers(dest="key_command", required=True, metavar="ACTION")
    kp = ksub.add_parser("new", help="write a new random key (mode 0600)")
    kp.add_argument("file")
    kp.add_argument("--force", action="store_true", help="replace an existing file")


def gen_firmware(sp: Parser) -> None:
    sp.add_argument("boardfile", help="board file with mcu = atmega328p, atmega2560 or atmega32u4")
    sp.add_argument("--target", choices=["avr"], default="avr", help="firmware target (avr)")
    sp.add_argument("--out", required=True, help="directory for board_gen.c and board.mk")
    sp.add_argument(
        "--no-fit-check", action="store_true", help="do not build it to check that it fits the MCU"
    )


def board(sp: Parser) -> None:
    what = sp.add_mutually_exclusive_group(required=True)
    what.add_argument("--sim", help="thesis, encoder_servo, rangers, original or rate")
    what.add_argument(
        "--file",
        metavar="BOARDFILE",
        help="run this board file, every part simulated from its datasheet (`missing-link "
        "examples DIR` writes examples)",
    )
    where = sp.add_mutually_exclusive_group(required=True)
    where.add_argument("--listen", help="tcp://127.0.0.1:PORT (0 = any), unix:///PATH or pty")
    where.add_argument(
        "--dial",
        metavar="URL",
        help="connect to a daemon that runs `run --listen` (tcp://HOST:PORT), again with "
        "backoff whenever the connection ends (board/dial.py)",
    )
    sp.add_argument(
        "--runtime",
        choices=["cpython", "micropython", "avr"],
        help="--file: our runtime on CPython (default), our firmware under MicroPython (node), "
        "or an AVR board file's C firmware in simavr (built for its MCU, cached)",
    )
    sp.add_argument(
        "--absent",
        metavar="PART,...",
        help="--file: leave these parts (transducer names) unplugged",
    )
    sp.add_argument(
        "--flash",
        metavar="DIR",
        help="--file: the board's flash (saved configuration, keys), kept between runs",
    )
    sp.add_argument(
        "--seed",
        type=int,
        help="random seed of the simulated signals (and of its board.id: sim-NAME-SEED); "
        "--file: of its chip id (board.id) when it has no --flash (default 0), and of the world's "
        "noise",
    )
    sp.add_argument(
        "--world",
        metavar="FILE",
        help="--file: the world the robot lives in (TOML, docs/world.md; default: a 10 m room, "
        "the robot at its centre facing +x); `none`: no world, the parts read their defaults",
    )
    sp.add_argument(
        "--world-control",
        metavar="URL",
        help="--file: push, turn, place, tilt the robot by hand here (tcp://127.0.0.1:PORT or "
        "unix:///PATH; `missing-link world URL ...`); prints WORLD URL",
    )
    sim_options(sp)


def sim_options(sp: Parser) -> None:
    """``board --sim``'s own options (a hand-written sim: its name, count, rate, clock)."""
    sp.add_argument("--name", help="board.name property (default: the sim's)")
    sp.add_argument(
        "--count",
        type=count_arg,
        default=1,
        help="serve N boards from this process (NAME_0 .. NAME_N-1, tcp only; benchmarks)",
    )
    sp.add_argument(
        "--config-file",
        help="where the board keeps a saved configuration (its flash; default: none, a save "
        "is refused) and reads it back at every boot",
    )
    sp.add_argument(
        "--rate",
        type=number(0, MAX_RATE_HZ, above=True, unit=" Hz"),
        help="updates per second (sim rate only)",
    )
    sp.add_argument("--channels", type=count_arg, help="channels per update (sim rate only)")
    sp.add_argument(
        "--clock-offset-us",
        type=finite,
        help="board clock = OFFSET + (1 + SKEW) * host CLOCK_MONOTONIC (default: the host's clock)",
    )
    sp.add_argument("--clock-skew-ppm", type=finite, help="the board clock's rate error (ppm)")
    sp.add_argument(
        "--clock-drift-ppm-per-s", type=finite, help="the rate error changes this much per second"
    )
    sp.add_argument(
        "--clock-ref-ns",
        type=int,
        help="host CLOCK_MONOTONIC ns the drift and --reset-at count from (default: now)",
    )
    sp.add_argument(
        "--reset-at",
        type=seconds_arg,
        action="append",
        metavar="S",
        help="the board resets S seconds after --clock-ref-ns (repeatable); the link stays",
    )
    sp.add_argument(
        "--boot-gap-ms",
        type=number(0, 3_600_000, unit=" ms"),
        default=100.0,
        help="silence after a reset (100)",
    )


def relay(sp: Parser) -> None:
    sp.add_argument("url", help="the board's URL (tcp, unix, serial, ...)")
    sp.add_argument(
        "--listen", default="tcp://127.0.0.1:0", help="tcp://127.0.0.1:PORT or unix:///PATH"
    )
    # (finite here; the relay's own check says what a probability may be)
    sp.add_argument("--corrupt", type=finite, default=0.0, help="per-byte bit-flip probability")
    sp.add_argument("--drop", type=finite, default=0.0, help="per-chunk loss probability")
    sp.add_argument(
        "--delay-ms",
        type=number(0, 86_400_000, unit=" ms"),
        default=0.0,
        help="hold every chunk this long",
    )
    sp.add_argument(
        "--blackhole-after", type=seconds_arg, help="forward nothing after S s of a connection"
    )
    sp.add_argument("--blackhole-for", type=seconds_arg, help="... for S s (default: for ever)")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument(
        "--duration", type=seconds_arg, default=0, help="stop after S seconds (0 = run)"
    )


def examples(sp: Parser) -> None:
    sp.add_argument("dir", metavar="DIR", help="where to write them (made if missing)")
    sp.add_argument("--force", action="store_true", help="replace files that are there")


def world(sp: Parser) -> None:
    """``world URL VERB ...``: a hand on a running virtual board's world (docs/world.md)."""
    sp.add_argument("url", help="the world's control: tcp://127.0.0.1:PORT or unix:///PATH "
                    "(what `board --world-control` printed after WORLD)")  # fmt: skip
    sp.add_argument("--json", action="store_true", help="the world's state as JSON")
    verbs = sp.add_subparsers(dest="verb", required=True, metavar="VERB")
    verbs.add_parser("state", help="where the robot is and what it does")
    metres, degrees = number(-1000, 1000, unit=" m"), number(-3600, 3600, unit=" deg")
    over = number(0, 60, unit=" s")
    v = verbs.add_parser("push", help="move the body DX m forward and DY m left (its axes)")
    v.add_argument("dx_m", type=metres)
    v.add_argument("dy_m", type=metres, nargs="?", default=0.0)
    v.add_argument("--over", dest="over_s", type=over, default=0.5, help="over S s (0.5)")
    v = verbs.add_parser("turn", help="turn the body DEG degrees (counter-clockwise positive)")
    v.add_argument("deg", type=degrees)
    v.add_argument("--over", dest="over_s", type=over, default=0.5, help="over S s (0.5)")
    v = verbs.add_parser("bump", help="a knock: a short sharp push (default 1 cm back)")
    v.add_argument("dx_m", type=metres, nargs="?", default=-0.01)
    v.add_argument("dy_m", type=metres, nargs="?", default=0.0)
    v = verbs.add_parser("place", help="lift the robot and set it down at X Y (m), YAW (deg)")
    v.add_argument("x_m", type=number(-1e6, 1e6, unit=" m"))
    v.add_argument("y_m", type=number(-1e6, 1e6, unit=" m"))
    v.add_argument("yaw_deg", type=degrees, nargs="?", default=0.0)
    v = verbs.add_parser("tilt", help="lean the body to ROLL and PITCH degrees")
    v.add_argument("roll_deg", type=number(-90, 90, unit=" deg"))
    v.add_argument("pitch_deg", type=number(-90, 90, unit=" deg"))
    v.add_argument("--over", dest="over_s", type=over, default=0.5, help="over S s (0.5)")
    until = number(0, MAX_DURATION_S, unit=" s")
    v = verbs.add_parser("block", help="something DISTANCE m in front of a ranger")
    v.add_argument("part")
    v.add_argument("distance_m", type=number(0, 100, unit=" m"), nargs="?", default=0.05)
    v.add_argument("--for", dest="for_s", type=until, default=0.0, help="S s (0: for good)")
    v = verbs.add_parser("fail", help="a sensor fails: silent (no answer) or stuck")
    v.add_argument("part")
    v.add_argument("--mode", choices=["silent", "stuck"], default="silent")
    v.add_argument("--for", dest="for_s", type=until, default=0.0, help="S s (0: for good)")
    v = verbs.add_parser("slip", help="a wheel (its motor or encoder) slips: FRACTION of 0..1")
    v.add_argument("part")
    v.add_argument("fraction", type=number(0, 1), nargs="?", default=1.0)
    v.add_argument("--for", dest="for_s", type=until, default=0.0, help="S s (0: for good)")
