"""The 2014 firmware's a2jMany, as its code has it: the chunk offset is the request's third
byte alone (``(*datap)[2]``), so an offset past 255 is served from ``offset & 0xFF`` with the
offset the host sent echoed back, and a blob over 504 bytes never sends its last chunk.  The
emulated original board (``original``) and the hostile one (``hostile_offset_bug``) use it."""

from __future__ import annotations

from ..board.runtime import BoardRuntime


class OriginalRuntime(BoardRuntime):  # type: ignore[misc]
    """A Part 1 board whose a2jMany is the 2014 firmware's: it read ``(*datap)[2]`` as the
    whole offset, the low byte only."""

    def _dispatch(self, seq, opcode, payload):  # type: ignore[no-untyped-def]
        if opcode == 1 and len(payload) >= 6:
            # Serve the chunk from offset & 0xFF but echo the offset the host sent, as the
            # original did (it copied the header back unchanged).
            target, flags = payload[0], payload[1]
            offset = int.from_bytes(payload[2:6], "little")
            entry = self.functions[target] if target < len(self.functions) else None
            if entry is not None and entry[1] == 1 and not flags & 2:  # a many-function read
                handler = entry[2]
                ret, last, data = handler(False, False, offset & 0xFF, b"")
                head = bytes((ret & 0xFF, 1 if last else 0)) + payload[2:6]
                self._reply(seq, 0, head + data[:249])
                return
        super()._dispatch(seq, opcode, payload)
