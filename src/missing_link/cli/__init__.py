"""The ``missing-link`` command line, one module per command group.

- :mod:`.main` - the parser, the command's module imported when it runs; errors -> one line
  and an exit code
- :mod:`.commands` - the light table: every command's arguments and its handler, by name
- :mod:`.common` - exit codes, argument types (finite, in range), opening a board, JSON output
- :mod:`.talk` - ``info``, ``call``, ``listen``, ``sync`` (one board, directly)
- :mod:`.run` - ``run`` (the daemon; its summary) and ``recover``
- :mod:`.msgs` - ``create-msgs``
- :mod:`.deploy` - ``flash``, ``key new``, ``gen-firmware``
- :mod:`.virtual` - ``board``, ``relay``
- :mod:`.router` - ``router`` (Zenoh)
- :mod:`.demo` - ``demo`` (the thesis test rig, :mod:`.rig`); :mod:`.view` - the live view
"""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
