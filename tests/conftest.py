from __future__ import annotations

import itertools
from collections.abc import Iterator

import pytest

from missing_link.board.runtime import BoardRuntime
from missing_link.virtual import BoardServer, make_sim, start_board_thread

from .helpers import j2a_threads

_names = itertools.count()


@pytest.fixture
def serve() -> Iterator[object]:
    """serve(runtime_or_sim_name, listen="memory") -> BoardServer, stopped after the test."""
    servers: list[tuple[BoardServer, object]] = []

    def start(rt: BoardRuntime | str = "thesis", listen: str = "memory") -> BoardServer:
        runtime = make_sim(rt, seed=1) if isinstance(rt, str) else rt
        if listen == "memory":
            listen = f"memory://test{next(_names)}"
        server, thread = start_board_thread(runtime, listen)
        servers.append((server, thread))
        return server

    yield start
    for server, thread in servers:
        server.stop()
        thread.join(5)  # type: ignore[attr-defined]


@pytest.fixture(autouse=True)
def no_leftover_threads() -> Iterator[None]:
    yield
    left = [t for t in j2a_threads() if t.is_alive() and t.name.startswith("j2a:")]
    assert not left, f"reader threads left running: {left}"
