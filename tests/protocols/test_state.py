"""The variable table: declarations, positional naming, carry-forward, named compression."""

from __future__ import annotations

import pytest

from sharedlink.protocols.codec import (
    Field,
    Frame,
    declaration_fields,
    named_fields,
    positional_fields,
    query_fields,
    reply_fields,
)
from sharedlink.protocols.state import BEACON_VARIABLES, LinkState, VariableTable, parse_variables


def frame(fields, dst="A", src="B"):
    return Frame(dst, src, tuple(fields))


def test_positional_with_given_list_and_carry_forward():
    t = VariableTable.with_list(["Lat", "Lon", "Head", "Vel"])
    ups = t.apply(frame(positional_fields(["1.0", "2.0", "3.0", "4.0"])), number=1)
    assert [(u.name, u.index, u.text, u.carried) for u in ups] == [
        ("Lat", 0, "1.0", False),
        ("Lon", 1, "2.0", False),
        ("Head", 2, "3.0", False),
        ("Vel", 3, "4.0", False),
    ]
    assert t.last_full_in == 1
    ups = t.apply(frame(positional_fields([None, "2.5", None, None])), number=2)
    assert [(u.name, u.text, u.carried, u.carried_from, u.changed) for u in ups] == [
        ("Lat", "1.0", True, 1, False),
        ("Lon", "2.5", False, None, True),
        ("Head", "3.0", True, 1, False),
        ("Vel", "4.0", True, 1, False),
    ]
    assert t.last_full_in == 1  # a delta is no sync


def test_subset_frame_starts_at_ordinal():
    t = VariableTable.with_list(["a", "b", "c"])
    ups = t.apply(frame(positional_fields(["9"], ordinal=2)), number=5)
    assert [(u.name, u.index, u.text) for u in ups] == [("c", 2, "9")]
    assert t.vars["c"].set_in == 5


def test_positional_past_the_list_gets_placeholder_names():
    t = VariableTable.with_list(["a"])
    ups = t.apply(frame(positional_fields(["1", "2"])), 1)
    assert [u.name for u in ups] == ["a", "var1"]


def test_declaration_is_learnt_per_direction():
    link = LinkState()
    link.apply(frame(declaration_fields([("X", 2), ("Y", 4)])), 1)
    ups = link.apply(frame(positional_fields(["1.5", "hi"])), 2)
    assert [(u.name, u.text) for u in ups] == [("X", "1.5"), ("Y", "hi")]
    assert link.table("B", "A").vars["Y"].value == "hi"
    assert link.table("B", "A").vars["X"].value == 1.5
    # the other direction still has the default (beacon) list
    ups = link.apply(frame(positional_fields(["7"]), dst="B", src="A"), 3)
    assert ups[0].name == "AutoGpsLat"


def test_inbound_declaration_names_the_reverse_direction():
    link = LinkState()
    link.apply(frame(declaration_fields([("Cmd", 0)], inbound=True)), 1)  # B says: I receive Cmd
    ups = link.apply(frame(positional_fields(["3"]), dst="B", src="A"), 2)
    assert ups[0].name == "Cmd" and link.table("A", "B").vars["Cmd"].value == 3


def test_named_compression_carries_missing_triplets():
    t = VariableTable()
    full = named_fields([("Lat", 2, "1.0"), ("Lon", 2, "2.0")])
    assert t.kind(frame(full)) == "full"
    t.apply(frame(full), 1, 100)
    delta = named_fields([("Lon", 2, "2.5")])
    assert t.kind(frame(delta)) == "delta"
    ups = t.apply(frame(delta), 2, 200)
    assert {(u.name, u.text, u.carried, u.carried_from) for u in ups} == {
        ("Lon", "2.5", False, None),
        ("Lat", "1.0", True, 1),
    }
    assert t.last_full_in == 1 and t.last_full_at == 100


def test_reply_sets_the_variable_and_query_changes_nothing():
    t = VariableTable()
    assert t.apply(frame(query_fields("Lat")), 1) == []
    ups = t.apply(frame(reply_fields("Lat", "40.1")), 2)
    assert ups[0].name == "Lat" and t.vars["Lat"].text == "40.1"


def test_unknown_and_command_frames_do_not_disturb_state():
    t = VariableTable.with_list(["a"])
    t.apply(frame(positional_fields(["1"])), 1)
    for fields in ((Field("E", "Link"), Field("D", "0, outbound, on")), (Field("P", ""),), (Field("Z", "?"),)):
        t.apply(frame(fields), 2)
    assert t.vars["a"].text == "1" and t.vars["a"].set_in == 1


def test_types_names_and_conversations_are_kept_apart():
    """Details a mutation run showed no test looked at (scripts/mutate.py)."""
    link = LinkState()
    link.apply(frame(declaration_fields([("X", 2), ("Y", 4)])), 1)
    link.apply(frame(positional_fields(["1.5", "15"])), 2)
    # the declared names join the table (after the default list it started with), nothing else
    assert list(link.table("B", "A").values().items())[-3:] == [("AutoGpsVel", None), ("X", "1.5"), ("Y", "15")]
    assert len(link.table("B", "A").vars) == len(BEACON_VARIABLES) + 2
    assert link.table("B", "A").vars["Y"].value == "15"  # declared a string: not guessed as a number
    # a named frame's T field types its value
    link.apply(frame(named_fields([("S", 4, "7"), ("L", 0, "7")]), dst="C", src="D"), 3)
    t = link.table("D", "C")
    assert (t.vars["S"].type_code, t.vars["S"].value, t.vars["L"].value) == (4, "7", 7)
    # an inbound list declared in one conversation stays in it
    link.apply(frame(declaration_fields([("Cmd", 0)], inbound=True)), 4, conv="port 1")
    assert link.table("A", "B", "port 1").names == ["Cmd"]
    ups = link.apply(frame(positional_fields(["3"]), dst="B", src="A"), 5, conv="port 1")
    assert ups[0].name == "Cmd"


def test_variable_lists_as_given_on_the_command_line():
    assert parse_variables("Lat:2, Lon:2,Name:4,Count") == [("Lat", 2), ("Lon", 2), ("Name", 4), ("Count", None)]
    assert parse_variables("A:2,B,") == [("A", 2), ("B", None)]
    assert parse_variables("A:") == [("A", None)]
    for bad in ("", ",", "A:x", "A|B", ":2"):
        with pytest.raises(ValueError):
            parse_variables(bad)
