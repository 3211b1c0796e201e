"""Under ``--dist loadgroup`` (make test) every test's node id names its group, which the xdist
controller schedules by (tests/sl_groups.py): an xdist_group mark's name, else its module's path."""

from __future__ import annotations

import pytest
from sl_groups import group_of


def _loadgroup(request: pytest.FixtureRequest) -> None:
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not a pytest-xdist worker under --dist loadgroup (make test runs one)")


@pytest.mark.xdist_group("xdist_groups_check")
def test_a_marked_test_is_scheduled_with_its_group(request: pytest.FixtureRequest) -> None:
    assert group_of(request.node) == "xdist_groups_check"
    _loadgroup(request)
    assert request.node.nodeid.endswith("@xdist_groups_check"), request.node.nodeid


def test_a_test_without_a_mark_is_scheduled_with_its_module(request: pytest.FixtureRequest) -> None:
    assert group_of(request.node) == "tests/tools/test_xdist_groups.py"
    _loadgroup(request)
    assert request.node.nodeid.endswith("@tests/tools/test_xdist_groups.py"), request.node.nodeid
