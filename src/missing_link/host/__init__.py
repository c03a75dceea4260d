"""One board from the host side: its link, the loop that reads it, and the faces applications use.

- :mod:`.link` - the link engine: a board's J2A connection, pending calls, SIF handlers
- :mod:`.results` - what a link hands back: call results with their stamps, counters
- :mod:`.sif_handlers` - who hears which SIFs, called inline on the reading thread
- :mod:`.reactor` - one I/O loop for many boards (the daemon's): it reads their descriptors and
  drives their links by public verbs
- :mod:`.board` - :class:`Board` (holds a link): open by URL, handshake, calls by name, blobs,
  clock exchanges
- :mod:`.handshake` - what the host reads of a board first (mapping, properties, descriptors),
  checked, within one deadline and size caps
- :mod:`.clock` - the one clock the host side runs on, passed in (the system's, or a fake one:
  ``missing_link.testing``)
- :mod:`.config` - a board's run-time configuration from the host (keys, values, all-or-none sets)
- :mod:`.aio` - :class:`AsyncBoard`: the same engine, awaited
- :mod:`.samples` - SIFs decoded into samples with the board's descriptors (``listen``)
"""
