"""One board from the host side: its link, the loop that reads it, and the faces applications use.

- :mod:`.link` - the link engine: a board's J2A connection, pending calls, SIF handlers
- :mod:`.reactor` - one I/O loop for many boards (the daemon's), driving links by public verbs
- :mod:`.board` - :class:`Board`: open by URL, handshake, calls by name, blobs, clock exchanges
- :mod:`.aio` - :class:`AsyncBoard`: the same engine, awaited
- :mod:`.samples` - SIFs decoded into samples with the board's descriptors (``listen``)
"""
