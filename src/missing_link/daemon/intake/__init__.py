"""Boards coming in (a room of the daemon, above the session: it hands each board to one).

- :mod:`.discovery` - boards found as their serial ports appear (``run --auto``)
- :mod:`.listener` - boards that dial in (``run --listen``): accepted, greeted and described
- :mod:`.dialin` - each board that dialed in to its session, by its ``board.id``
"""
