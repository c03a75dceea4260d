"""A board's own memory figures, seen from the host (board/memory.py, firmware/avr/src/memory.c;
docs/hardware.md, "Memory").

``a2jMemory`` answers a kind byte and its figures: 1, a MicroPython board's heap (bytes free now
and at the lowest since boot, allocated, and its garbage collections: how many, the longest and
the last in µs, how many reached an instant the board had to be on time for, how many it put
off for one); 2, an AVR board's stack (bytes of it never touched since boot, of how many) and
static RAM (``.data`` + ``.bss``, of the RAM's size).  :func:`parse_memory` reads either into a
:class:`~missing_link.daemon.session.status.MemoryStatus`.  The session reads it once per
diagnostics period on a board that has the function, in the background like the failsafe's count
(a :class:`~missing_link.daemon.session.inflight.BoardRead`: one read in flight, never waited
for: the supervisor must not be held up); ``info --json`` reads it once.
"""

from __future__ import annotations

import struct

from .status import MemoryStatus

FUNCTION = "a2jMemory"
KIND_HEAP = 1
KIND_STACK = 2
_HEAP = struct.Struct("<BIIIIIIII")
_STACK = struct.Struct("<BHHHH")


def parse_memory(payload: bytes) -> MemoryStatus:
    """The figures of an ``a2jMemory`` reply; ``problem`` says what is wrong with one that
    makes no sense (a board is untrusted: nothing here raises)."""
    kind = payload[0] if payload else None
    if kind == KIND_HEAP and len(payload) == _HEAP.size:
        _, free, low, alloc, n, longest, last, overlaps, deferred = _HEAP.unpack(payload)
        return MemoryStatus(
            heap_free=free,
            heap_free_low=low,
            heap_alloc=alloc,
            gc_collections=n,
            gc_longest_us=longest,
            gc_last_us=last,
            gc_overlaps=overlaps,
            gc_deferred=deferred,
        )
    if kind == KIND_STACK and len(payload) == _STACK.size:
        _, untouched, stack, static, ram = _STACK.unpack(payload)
        return MemoryStatus(
            stack_free_low=untouched, stack_size=stack, ram_static=static, ram_size=ram
        )
    size = {KIND_HEAP: _HEAP.size, KIND_STACK: _STACK.size}.get(kind or 0)
    if size is None:
        return MemoryStatus(problem=f"a reply of kind {kind}, not 1 (heap) or 2 (stack)")
    return MemoryStatus(problem=f"a kind {kind} reply of {len(payload)} bytes, not {size}")
