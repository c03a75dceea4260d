"""A board's topics, declared at each handshake: one per transducer in the thesis format (its
name remapped as the config says, its message type claimed daemon-wide), one per standard type
it maps to (``ros/standard``: by default every driver's, ``/<topic>/<suffix>``), and per
actuator two command topics: ``/<topic>/cmd`` in the thesis type and ``/<topic>/command`` as
``std_msgs/msg/Float64`` in SI units, whose handler is the session's (``actuators.py``).
Either kind can be turned off per transducer (``[boards.<board>.ros.<name>]``) and daemon-wide
(``[daemon] standard_types``, ``thesis_types``); a transducer whose thesis-format topic is off
is still decoded (its standard types come from it) but not published (``quiet``).  The session
hands what this needs; nothing here keeps state but the board's frame ids (``FrameIds``, kept
by the session across reconnects).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Container, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from ...descriptors import Transducer, load_descriptor_file
from ...errors import BoardError
from ...ros.standard import (
    FLOAT64,
    FrameIds,
    StandardMapping,
    command_kind,
    frame_of,
    mappings_for,
    raw_command,
)
from ...topics import Command, Topic
from .context import CommandHandler, SessionContext


@dataclass
class BoardTopics:
    """What one handshake declared (filled as it goes: a failure half-way leaves the command
    topics added so far in ``commands`` for the session to withdraw)."""

    topics: dict[int, Topic] = field(default_factory=dict)  #: transducer id -> topic
    #: transducer id -> its standard-type topics and how each is made
    standard: dict[int, list[tuple[Topic, StandardMapping]]] = field(default_factory=dict)
    #: an actuator's function -> its command topic (the allow-list's name for it)
    calls: dict[str, str] = field(default_factory=dict)
    commands: list[str] = field(default_factory=list)  #: every command topic offered
    quiet: set[int] = field(default_factory=set)  #: thesis-format topic off: not published


def transducers_of(board: str, own: list[Transducer] | None, descriptors: str) -> list[Transducer]:
    """A board's transducers: from its ``[[board]]`` table's ``descriptors`` file when it names
    one, else as the board described them (``own``); an original board needs the file."""
    if descriptors:
        return load_descriptor_file(descriptors)
    if own is None:
        raise BoardError(
            board,
            'original board without descriptors; give them with descriptors = "FILE" in its '
            "[[board]] table",
        )
    return own


def declare_topics(
    ctx: SessionContext,
    board: str,
    functions: Container[str],
    transducers: Sequence[Transducer],
    handler: Callable[[Transducer], CommandHandler],
    warn: Callable[[str], None],
    out: BoardTopics,
    frames: FrameIds | None = None,
    settings: Callable[[], Mapping[str, Any]] = dict,
) -> None:
    """Declare the topics of board ``board`` (its topic name) into ``out``; ``functions``: the
    board's function names (an actuator must name one), ``handler(t)``: actuator ``t``'s
    command handler; ``frames``: the board's frame ids (kept across reconnects);
    ``settings()``: its run-time configuration now (an IMU's covariances follow its range)."""
    cfg = ctx.config
    frames = frames if frames is not None else FrameIds()
    for t in transducers:
        name = cfg.remap.get(f"/{board}/{t.name}", f"/{board}/{t.name}")
        opts = cfg.std_options(board, t.name)
        if opts.counts_per_rev is not None:  # (the host's key wins on every face: ros.md)
            per = {**t.options, "counts_per_rev": f"{opts.counts_per_rev:g}"}
            t = replace(t, options=per)
        type_name = None
        if opts.thesis:
            type_name, clash = ctx.claims.type(board, t)
            if clash:
                warn(clash)
        topic = Topic.for_transducer(name, board, t, cfg.package, type_name)
        out.topics[t.id] = topic
        if opts.thesis:
            ctx.faces.declare(topic)
        else:
            out.quiet.add(t.id)
        frame = frames.holder(t.name, frame_of(t, board, opts))
        try:
            mappings = mappings_for(t, board, ctx.typestore, frame, opts, settings)
        except ValueError as e:
            warn(str(e))
            mappings = []
        for mapping in mappings:
            std = Topic.standard_type(
                f"{name}/{mapping.suffix}", board, t, mapping.type_name, ctx.typestore, frame
            )
            out.standard.setdefault(t.id, []).append((std, mapping))
            ctx.faces.declare(std)
        if t.is_actuator:
            _commands(ctx, board, functions, t, name, handler, out, opts.thesis and topic)
            if opts.standard:
                std_cmd = Topic.standard_type(f"{name}/command", board, t, FLOAT64, ctx.typestore)
                convert = raw_command(t, command_kind(t))
                _offer(ctx, out, std_cmd.name, std_cmd, si_command(t, convert, handler(t)))


def _commands(
    ctx: SessionContext,
    board: str,
    functions: Container[str],
    t: Transducer,
    name: str,
    handler: Callable[[Transducer], CommandHandler],
    out: BoardTopics,
    thesis: Topic | bool,
) -> None:
    if t.call not in functions:
        raise BoardError(board, f"actuator {t.name} names call={t.call}, which the board lacks")
    out.calls[str(t.call)] = f"{name}/cmd"
    if isinstance(thesis, Topic):
        _offer(ctx, out, f"{name}/cmd", thesis, handler(t))


def _offer(ctx: SessionContext, out: BoardTopics, name: str, topic: Topic, h: Any) -> None:
    out.commands.append(name)
    ctx.faces.add_command(name, topic, h)


def si_command(
    t: Transducer, convert: Callable[[float], int | float], act: CommandHandler
) -> CommandHandler:
    """A standard command's handler: an SI value (a number, a ``std_msgs/msg/Float64`` as any
    face decodes it, or a ``Command`` whose first value is one: timed when it says when)
    converted to the raw value ``t`` takes and handed to the actuator's own handler, which
    checks it (out of range: ValueError, as a thesis-format command)."""

    def handle(value: Any) -> None:
        at, done = None, None
        if isinstance(value, Command):
            at, done = value.at_ns, value.done
            value = value.values[0] if value.values else None
        elif hasattr(value, "data"):
            value = value.data
        elif isinstance(value, (list, tuple)):
            value = value[0] if value else None
        if hasattr(value, "item"):  # (a numpy scalar)
            value = value.item()
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{t.name}: {value!r} is not a number in SI units")
        si = float(value) if abs(value) <= sys.float_info.max else math.copysign(math.inf, value)
        try:  # (NaN, an infinity, beyond the type: refused and counted where it meets its type)
            act(Command([convert(si)], at, done))
        except ValueError as e:
            raise ValueError(f"{e} (the command {si!r} in SI units)") from None

    return handle
