"""Which pytest-xdist worker runs a test (a plugin, loaded by ``tests/conftest.py``).

``make test`` runs ``pytest -n 2 --dist loadgroup``: the controller sends every test whose node
id ends in ``@GROUP`` to one worker, with the rest of its group. Here each test's group is its
``xdist_group`` mark's name, or else its module's path, so that

* a module's fixtures (``scope="module"``: captures, shared tshark runs) are made once, by one
  worker, instead of once by each worker that runs one of its tests;
* the runs shared across files through a helper's memo (``sl_golden``: test_golden.py and
  test_experts.py; ``sl_vectors.tshark_json``: test_vectors.py and test_agreement.py's vector
  streams) are made once: the tests that read them are in one group.

pytest-xdist writes the group into ``item._nodeid``, which pytest 9.2 no longer reads (a node's id
is ``item._id``, a ``NodeId``): with xdist 3.8 the marks had no effect, and every module's
fixtures were made by both workers. This writes it where the running pytest reads it (an id that
names a group already is left alone). Without ``--dist loadgroup`` it does nothing.
"""

from __future__ import annotations

import pytest


def group_of(item: pytest.Item) -> str:
    """The item's xdist group: its ``xdist_group`` marks' names, else its module's path."""
    names = {str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group")}
    return "_".join(sorted(names)) or item.nodeid.split("::")[0]


def _set_nodeid(item: pytest.Item, nodeid: str) -> bool:
    """Give the item ``nodeid``; whether it took (a pytest whose ids live elsewhere again: the
    tests run ungrouped, as before, and test_xdist_groups.py fails, not the collection)."""
    try:
        if hasattr(item, "_id"):   # pytest >= 9.2
            from _pytest.nodeid import NodeId  # noqa: PLC0415

            item._id = NodeId.parse(nodeid)
        else:
            item._nodeid = nodeid  # type: ignore[attr-defined]
    except (ImportError, AttributeError, TypeError, ValueError):
        return False
    return item.nodeid == nodeid


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not getattr(config.option, "loadgroup", False):   # (set by xdist in its workers)
        return
    for item in items:
        if item.nodeid.rfind("@") <= item.nodeid.rfind("]"):   # (no group yet: xdist's own test)
            if not _set_nodeid(item, f"{item.nodeid}@{group_of(item)}"):
                return
