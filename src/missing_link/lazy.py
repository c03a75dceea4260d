"""A package's names imported on first use (PEP 562's module ``__getattr__``): importing
``missing_link.timesync`` or ``missing_link.daemon`` loads none of their modules until a name is
used.  (The package's face, ``missing_link/__init__.py``, imports nothing at run time, this
neither: it keeps its own copy of these lines.)"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_names(package: str, where: dict[str, str], space: dict[str, Any]) -> Callable[[str], Any]:
    """The package's ``__getattr__``: ``where`` maps each public name to the module below
    ``package`` that defines it; a name is imported when first asked for and kept in ``space``
    (the package's globals), so later look-ups are plain attribute reads."""

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        space[name] = value
        return value

    return __getattr__
