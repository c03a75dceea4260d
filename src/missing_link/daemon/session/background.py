"""Work a session's supervisor asks for but must not wait for, run on a thread of its own: the
configuration file's keys again after a board reset seen under the same link (run_config.py).
They are calls to the board, waited for one by one; the supervisor only notices the reset.

``request()`` starts the thread unless one is running; a request that comes while it runs makes
it go once more, so a second reset during the first re-apply is not lost, and there is never
more than one such thread per session.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from ...logs import ErrorCounts


class Background:
    def __init__(self, name: str, work: Callable[[], None], faults: ErrorCounts) -> None:
        """``name``: the thread's; ``work()``: what to run; ``faults``: where its exceptions
        are counted (by kind, the first of each logged)."""
        self.name = name
        self._work = work
        self._faults = faults
        self._lock = threading.Lock()
        self._owed = 0  # requests not yet run
        self._running = False
        self.runs = 0

    def request(self) -> None:
        with self._lock:
            self._owed += 1
            if self._running:
                return
            self._running = True
        threading.Thread(target=self._run, name=self.name, daemon=True).start()

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._owed:
                    self._running = False
                    return
                self._owed = 0
            try:
                self._work()
            except Exception as e:  # noqa: BLE001 - a bug must not stop the next request's run
                self._faults.caught("background work", e, self.name)
            self.runs += 1
