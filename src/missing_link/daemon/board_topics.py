"""A board's topics, declared at each handshake: one per transducer (its name remapped as the
config says, its message type claimed daemon-wide), one more per standard type a transducer
maps to (``ros/standard.py``), and a command topic per actuator, whose handler is the
session's (``actuators.py``).  The session hands what this needs; nothing here keeps state.
"""

from __future__ import annotations

from collections.abc import Callable, Container, Sequence
from dataclasses import dataclass, field

from ..descriptors import Transducer
from ..errors import BoardError
from ..ros.standard import StandardMapping, mapping_for
from ..topics import Topic
from .context import CommandHandler, SessionContext


@dataclass
class BoardTopics:
    """What one handshake declared (filled as it goes: a failure half-way leaves the command
    topics added so far in ``commands`` for the session to withdraw)."""

    topics: dict[int, Topic] = field(default_factory=dict)  #: transducer id -> topic
    standard: dict[int, tuple[Topic, StandardMapping]] = field(default_factory=dict)
    #: an actuator's function -> its command topic (the allow-list's name for it)
    calls: dict[str, str] = field(default_factory=dict)


def declare_topics(
    ctx: SessionContext,
    board: str,
    functions: Container[str],
    transducers: Sequence[Transducer],
    handler: Callable[[Transducer], CommandHandler],
    warn: Callable[[str], None],
    out: BoardTopics,
) -> None:
    """Declare the topics of board ``board`` (its topic name) into ``out``; ``functions``: the
    board's function names (an actuator must name one), ``handler(t)``: actuator ``t``'s
    command handler."""
    cfg = ctx.config
    for t in transducers:
        name = cfg.remap.get(f"/{board}/{t.name}", f"/{board}/{t.name}")
        type_name, clash = ctx.claim_type(board, t)
        if clash:
            warn(clash)
        topic = Topic.for_transducer(name, board, t, cfg.package, type_name)
        out.topics[t.id] = topic
        ctx.declare(topic)
        try:
            mapping = mapping_for(t, board, ctx.typestore)
        except ValueError as e:
            warn(str(e))
            mapping = None
        if mapping is not None:
            std = Topic.standard_type(
                f"{name}/{mapping.suffix}", board, t, mapping.type_name, ctx.typestore
            )
            out.standard[t.id] = (std, mapping)
            ctx.declare(std)
        if t.is_actuator:
            if t.call not in functions:
                raise BoardError(
                    board, f"actuator {t.name} names call={t.call}, which the board lacks"
                )
            out.calls[str(t.call)] = f"{name}/cmd"
            ctx.add_command(f"{name}/cmd", topic, handler(t))
