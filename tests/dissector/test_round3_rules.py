"""Issue 40, item 3: the open items, each decided and made the same in Lua and Python.

* An ordinal is decimal digits only: the state read ``N1e3`` as no number (0, no full set) while
  the tree showed ordinal 1000; now the tree says "Ordinal is not a number" too.
* One bound on queriers, one expert, both sides: Python's ``PendingAsks`` holds at most
  ``MAX_CONVERSATIONS`` queriers; the dissector bounded only each querier's entries. A new querier
  past ``max_conversations`` is now refused on both sides ("Limit exceeded: ... queriers ..."), its
  reply unmatched.
* Expert messages quote no raw control byte: a summary is one text per problem (issue 41), and a
  value is in a field of its own, so an unknown letter or a value with control bytes never goes
  into an expert message.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_agreement import limit_frame as _frame
from sl_agreement import limit_rows as _lua
from sl_agreement import udp_builder as _udp
from sl_agreement import write_session as _write

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded

OCUS = [("10.0.0.1", 4104), ("10.0.0.3", 4104), ("10.0.0.4", 4104)]
VEHICLE = ("10.0.0.2", 4000)


def test_an_ordinal_that_is_not_decimal_digits_is_no_ordinal_in_the_tree(tmp_path: Path) -> None:
    cap = _write(tmp_path / "ord.pcap", [_udp(VEHICLE, OCUS[0]).frame(_frame(b), i + 1) for i, b in
                                         enumerate(["AB|N1e3|D1|D2", "AB|N+5|D1", "AB|N12|D1", "AB|L0x1|T2|QA"])])
    rows = tu.fields(cap, ["frame.number", "sharedlink.ordinal", "sharedlink.inbound_ordinal"], two_pass=False)
    assert [r["sharedlink.ordinal"] for r in rows] == [[], [], ["12"], []]
    assert rows[3]["sharedlink.inbound_ordinal"] == []
    for r in (rows[0], rows[1], rows[3]):
        assert "Ordinal is not a number" in r["_ws.expert.message"], r
    shown = tu.verbose(cap, two_pass=False)
    assert "Ordinal (N): 1e3" in shown and "Start ordinal (N): 1000" not in shown


def test_one_bound_on_queriers_both_sides(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Three OCUs ask the vehicle (each its own querier) with max_conversations 2 on both sides:
    the third querier is refused (the dissector's limit expert on its query), and the vehicle's
    answer to it stays unmatched on both sides."""
    frames = [_udp(o, VEHICLE).frame(_frame(f"BA|Qv{i}"), i + 1) for i, o in enumerate(OCUS)]
    frames += [_udp(VEHICLE, o).frame(_frame(f"AB|Rv{i}|D{i}"), 10 + i) for i, o in enumerate(OCUS)]
    cap = _write(tmp_path / "queriers.pcap", frames)
    rows = tu.fields(cap, ["frame.number", "sharedlink.response_to"], prefs={"sharedlink.max_conversations": 2},
                     two_pass=True)
    lua_links = [r["sharedlink.response_to"] for r in rows[3:]]
    assert lua_links == [["1"], ["2"], []]
    limited = [int(r["frame.number"][0]) for r in rows
               if any("queriers" in m for m in r["_ws.expert.message"])]
    assert limited == [3]

    import sharedlink.protocols.state as state
    monkeypatch.setattr(state, "MAX_CONVERSATIONS", 2)
    py = [d for d in iter_decoded(cap) if isinstance(d, Decoded)]
    assert [d.response_to for d in py[3:]] == [1, 2, None]


def test_no_expert_message_quotes_a_control_byte(tmp_path: Path) -> None:
    bodies = ["AB|N0|\x01x|D1", "AB|N0|T2|QA|D\x07\x1b[0m", "AB|N0|T0|QB|D1\x02", "AB|N0|\x7fy|D2"]
    beacon = ("10.0.0.2", 7013)   # (the SharedLink port: the heuristic refuses control bytes)
    cap = _write(tmp_path / "ctl.pcap", [_udp(beacon, OCUS[0]).frame(_frame(b), i + 1) for i, b in enumerate(bodies)])
    rows = _lua(cap, ("sharedlink.field.letter", "sharedlink.var.value"))
    messages = [m for r in rows for m in r["_ws.expert.message"]]
    assert messages, "the frames draw expert infos"
    assert all(m.isprintable() for m in messages), messages
    assert "Unknown field letter" in messages and "Not a double" in messages and "Not a long (int64)" in messages
