"""What a test of missing-link, or of a program built on it, needs and should not write again
(shipped with the library, as ``trio.testing`` is).

- :class:`FakeClock` (:mod:`.clock`) - the host's clock, standing still until a test advances it
  (``Board``, ``Reactor`` and ``Daemon`` take it as ``clock=``)
"""

from __future__ import annotations

from .clock import FakeClock

__all__ = ["FakeClock"]
