"""Where the daemon keeps its files: the per-user runtime directory of the control endpoint
(control/endpoint.py), which the configuration checks an endpoint's directory against (config.py).
os only: a one-off ``missing-link call`` imports it."""

from __future__ import annotations

import os


def runtime_dir() -> str:
    """The per-user directory of the default endpoint, ``$XDG_RUNTIME_DIR/missing-link``, else
    ``/tmp/missing-link-<uid>``: the one directory the daemon creates for it (mode 0700)."""
    run = os.environ.get("XDG_RUNTIME_DIR")
    return os.path.join(run, "missing-link") if run else f"/tmp/missing-link-{os.getuid()}"
