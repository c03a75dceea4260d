"""An attribute read through to a part (missing_link.delegate) and a package's names imported on
first use (missing_link.lazy)."""

from __future__ import annotations

import sys
import types

import pytest

from missing_link.delegate import Delegate
from missing_link.lazy import lazy_names


class _Part:
    def __init__(self) -> None:
        self.level = 1


class _Owner:
    level = Delegate[int]("part", "the part's level")

    def __init__(self) -> None:
        self.part = _Part()


def test_a_delegate_reads_its_part_each_time_and_is_read_only() -> None:
    owner = _Owner()
    assert owner.level == 1
    owner.part.level = 7
    assert owner.level == 7
    with pytest.raises(AttributeError, match="level is part's: read only here"):
        owner.level = 3
    assert owner.part.level == 7
    assert _Owner.level.__doc__ == "the part's level"


def test_lazy_names_import_on_first_use_and_keep_the_name() -> None:
    space: dict[str, object] = {}
    getattr_ = lazy_names("missing_link", {"clean": "text"}, space)
    assert space == {}
    from missing_link.text import clean

    assert getattr_("clean") is clean and space == {"clean": clean}
    with pytest.raises(AttributeError, match="module 'missing_link' has no attribute 'nope'"):
        getattr_("nope")


def test_timesync_finds_each_name_in_its_module() -> None:
    import missing_link.timesync as ts

    assert isinstance(ts, types.ModuleType)
    assert ts.Exchange is sys.modules["missing_link.timesync.exchange"].Exchange
    with pytest.raises(AttributeError):
        ts.Nothing  # noqa: B018
