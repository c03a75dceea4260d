"""The suite's own arrangement (tests/conftest.py): a module whose tests share a module fixture is
one group, and under make unit (pytest-xdist, --dist loadgroup) the group is applied, so those
tests run in one worker and the fixture is set up once.  With pytest 9.2, pytest-xdist 3.8
applied no group at all and nothing said so (pyproject.toml pins pytest below it)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def shared() -> str:
    return "set up once"


@pytest.mark.parametrize("n", [1, 2])
def test_a_module_fixtures_tests_are_one_group(
    shared: str, n: int, request: pytest.FixtureRequest
) -> None:
    (mark,) = request.node.iter_markers("xdist_group")
    assert mark.args == ("test_suite_groups.py",)
    if getattr(request.config.option, "loadgroup", False):  # (a worker of make unit)
        assert request.node.nodeid.endswith("@test_suite_groups.py"), request.node.nodeid
