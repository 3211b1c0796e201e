"""The variable table: declarations, positional naming, carry-forward, named compression."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sl_captures import examples

from sharedlink.protocols.codec import (
    Field,
    Frame,
    declaration_fields,
    named_fields,
    positional_fields,
    query_fields,
    reply_fields,
)
from sharedlink.protocols.limits import MAX_CONVERSATIONS, MAX_PENDING
from sharedlink.protocols.state import (
    BEACON_VARIABLES,
    LinkState,
    PendingAsks,
    VariableTable,
    link_response,
    parse_variables,
)


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
    assert [(u.name, u.type_code) for u in ups] == [("a", None), ("#1", None)]
    assert t.names == ["a", "#1"]  # a full set's slots


def test_declaration_is_learnt_per_direction():
    link = LinkState()
    link.apply(frame(declaration_fields([("X", 2), ("Y", 4)])), 1)
    ups = link.apply(frame(positional_fields(["1.5", "hi"])), 2)
    assert [(u.name, u.text) for u in ups] == [("X", "1.5"), ("Y", "hi")]
    assert link.table("B", "A").vars["Y"].value == "hi"
    assert link.table("B", "A").vars["X"].value == 1.5
    # the other direction still has the default (beacon) list, for frames of its length
    ups = link.apply(frame(positional_fields(["7", "8", "9", "10"]), dst="B", src="A"), 3)
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


def test_a_reply_is_shown_never_stored_and_a_query_changes_nothing():
    """Issue 29, disagreement 2: a reply's values are on the reply only."""
    t = VariableTable.with_list([("Lat", 2)])
    assert t.apply(frame(query_fields("Lat")), 1) == []
    t.apply(frame(positional_fields(["38.0"])), 2)
    ups = t.apply(frame(reply_fields("Lat", "40.1")), 3)
    assert [(u.name, u.text, u.type_code, u.changed, u.carried) for u in ups] == [("Lat", "40.1", 2, True, False)]
    assert t.vars["Lat"].text == "38.0" and t.vars["Lat"].set_in == 2
    ups = t.apply(frame(positional_fields([None])), 4)
    assert [(u.text, u.carried, u.carried_from) for u in ups] == [("38.0", True, 2)]
    # a name no list holds: shown untyped, and still not stored
    ups = t.apply(frame(reply_fields("Other", "1")), 5)
    assert [(u.name, u.text, u.type_code) for u in ups] == [("Other", "1", None)] and "Other" not in t.vars


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
    # the declared names replace the default list it started with (issue 29), nothing else
    assert list(link.table("B", "A").values().items()) == [("X", "1.5"), ("Y", "15")]
    assert link.table("B", "A").names == ["X", "Y"]
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


# -- issue 29: the rules for real sessions (docs/fields-sharedlink.md) -------------------------

OCU, OCU2, VEH = ("10.0.0.1", 4104), ("10.0.0.3", 4104), ("10.0.0.2", 4000)


def udp(src: tuple[str, int], dst: tuple[str, int]) -> tuple[str, str, int, str, int]:
    return ("udp", src[0], src[1], dst[0], dst[1])


def test_the_a_priori_list_names_only_frames_of_its_length():
    link = LinkState()  # the beacon's 4 names, typed double
    four = link.apply(frame(positional_fields(["38.3", "-77.0", "85.6", "22.1"])), 1, conv="x")
    assert [(u.name, u.type_code) for u in four] == [(n, 2) for n, _ in BEACON_VARIABLES]
    subset = link.apply(frame(positional_fields(["86", "23"], ordinal=2)), 2, conv="x")  # N2 + 2 = 4 slots
    assert [u.name for u in subset] == ["AutoGpsHead", "AutoGpsVel"]
    long = link.apply(frame(positional_fields([str(i) for i in range(6)])), 3, conv="y")
    assert [(u.name, u.index, u.type_code) for u in long] == [(f"#{i}", i, None) for i in range(6)]
    assert link.table("B", "A", "y").names == [f"#{i}" for i in range(6)]  # a full set of that direction
    short = link.apply(frame(positional_fields(["1", "2"])), 4, conv="z")
    assert [u.name for u in short] == ["#0", "#1"]


def test_a_list_given_for_the_pair_names_every_frame_of_it():
    link = LinkState(default_list=parse_variables("B>A: Head:2,Vel:2; A>B: mux:0; Only"))
    ups = link.apply(frame(positional_fields(["268.87", "0.5", "7"])), 1)
    assert [(u.name, u.type_code) for u in ups] == [("Head", 2), ("Vel", 2), ("#2", None)]
    assert [u.name for u in link.apply(frame(positional_fields(["0", "1"]), dst="B", src="A"), 2)] == ["mux", "#1"]
    # another pair: the every-pair list, by length
    assert [u.name for u in link.apply(frame(positional_fields(["1"]), dst="A", src="C"), 3)] == ["Only"]
    assert [u.name for u in link.apply(frame(positional_fields(["1", "2"]), dst="A", src="D"), 4)] == ["#0", "#1"]
    # only per-pair lists: other pairs have no list at all
    link = LinkState(default_list=parse_variables("B>A: Head:2"))
    assert [u.name for u in link.apply(frame(positional_fields(["1"]), dst="A", src="C"), 1)] == ["#0"]


def test_per_pair_lists_travel_as_one_flat_list():
    flat = parse_variables("Lat:2,Lon; B>A: Head:2,Vel")
    assert flat == [("Lat", 2), ("Lon", None), ("B>A:Head", 2), ("B>A:Vel", None)]
    assert parse_variables("Lat:2, Lon:2") == [("Lat", 2), ("Lon", 2)]  # the old syntax, unchanged
    link = LinkState(default_list=tuple(flat))  # (copied, hashed: the entries survive)
    assert link.apriori is not None and link.apriori.names == (("Lat", 2), ("Lon", None))
    assert link.user_lists[("B", "A")].names == (("Head", 2), ("Vel", None))
    with pytest.raises(ValueError, match="bad type '3'"):
        parse_variables("B>A: Vel:3")


def test_a_declaration_replaces_the_list_of_its_direction():
    link = LinkState()
    conv = udp(("10.0.0.2", 1033), OCU)
    link.apply(frame(declaration_fields([("a", 2), ("b", 2), ("c", 0), ("d", 4)])), 1, conv=conv)
    link.apply(frame(positional_fields(["1", "2", "3", "x"])), 2, conv=conv)
    # a shorter list: the kept names keep their values and marks, the set of 2 is full
    link.apply(frame(declaration_fields([("a", 2), ("b", 2)])), 3, conv=conv)
    t = link.table("B", "A", conv)
    assert t.names == ["a", "b"] and set(t.vars) == {"a", "b"} and t.filled == {0, 1}
    two = frame(positional_fields(["1.5", None]))
    assert t.kind(two) == "delta"
    assert t.kind(frame(positional_fields(["1.5", "2.5"]))) == "full"
    ups = link.apply(two, 4, conv=conv)
    assert [(u.name, u.text, u.carried, u.carried_from) for u in ups] == [("a", "1.5", False, None), ("b", "2", True, 2)]
    # reordered, a dropped name back: carried by name, the dropped one has no value
    link.apply(frame(declaration_fields([("b", 2), ("d", 4), ("a", 2)])), 5, conv=conv)
    ups = link.apply(frame(positional_fields([None, None, None])), 6, conv=conv)
    assert [(u.name, u.index, u.text, u.carried_from, u.type_code) for u in ups] == [
        ("b", 0, "2", 2, 2), ("d", 1, None, None, 4), ("a", 2, "1.5", 4, 2)]
    assert t.filled == {0, 2}


def test_an_inbound_list_names_every_frame_towards_the_declarer_address():
    """The OCU declares from 4104 to the vehicle's 4000; the vehicle sends from 1033. Types
    belong to the list: a second OCU declaring the name untyped gets untyped values."""
    link = LinkState()
    link.apply(frame(declaration_fields([("Head", 2), ("Vel", 2)], inbound=True), dst="B", src="A"), 1,
               conv=udp(OCU, VEH))
    link.apply(frame(declaration_fields([("Head", None), ("Vel", 2)], inbound=True), dst="B", src="A"), 2,
               conv=udp(OCU2, VEH))
    data = frame(positional_fields(["x", "1"]), dst="A", src="B")
    to1 = link.apply(data, 3, conv=udp(("10.0.0.2", 1033), OCU))
    to1_other_port = link.apply(data, 4, conv=udp(("10.0.0.2", 1033), ("10.0.0.1", 5000)))
    to2 = link.apply(data, 5, conv=udp(("10.0.0.2", 1033), OCU2))
    to3 = link.apply(data, 6, conv=udp(("10.0.0.2", 1033), ("10.0.0.4", 4104)))  # declared nothing: the pair's latest
    assert [(u.name, u.type_code, u.bad) for u in to1] == [("Head", 2, True), ("Vel", 2, False)]
    assert [(u.name, u.type_code, u.bad) for u in to1_other_port] == [("Head", 2, True), ("Vel", 2, False)]
    assert [(u.name, u.type_code, u.bad) for u in to2] == [("Head", None, False), ("Vel", 2, False)]
    assert [(u.name, u.type_code) for u in to3] == [("Head", None), ("Vel", 2)]
    # values stay per conversation
    assert link.table("B", "A", udp(("10.0.0.2", 1033), OCU2)).vars["Head"].set_in == 5


def test_replies_link_from_the_queried_address_to_the_querier_port():
    pending = PendingAsks()
    q = frame(query_fields("Vel"), dst="B", src="A")
    r = frame(reply_fields("Vel", "1"), dst="A", src="B")
    assert link_response(pending, udp(OCU2, VEH), q, "query", 1) is None
    assert link_response(pending, udp(OCU, VEH), q, "query", 2) is None
    assert link_response(pending, udp(("10.0.0.9", 1033), OCU), r, "reply", 3) is None  # another address
    assert link_response(pending, udp(("10.0.0.2", 1033), ("10.0.0.1", 4999)), r, "reply", 4) is None  # another port
    assert link_response(pending, udp(("10.0.0.2", 1033), OCU), r, "reply", 5) == 2  # any source port
    assert link_response(pending, udp(("10.0.0.2", 1033), OCU2), r, "reply", 6) == 1  # per receiver
    assert link_response(pending, udp(("10.0.0.2", 1033), OCU2), r, "reply", 7) is None  # answered once


def test_list_requests_are_answered_by_declarations():
    pending = PendingAsks()
    ask_l = frame((Field("L", "?"),), dst="B", src="A")
    ask_n = frame((Field("N", "?"),), dst="B", src="A")
    veh = udp(("10.0.0.2", 1033), OCU)
    assert link_response(pending, udp(OCU, VEH), ask_l, "query", 1) is None
    assert link_response(pending, udp(OCU, VEH), ask_n, "query", 2) is None
    n_decl = frame(declaration_fields([("Head", 2)]), dst="A", src="B")
    l_decl = frame(declaration_fields([("mux", 0)], inbound=True), dst="A", src="B")
    assert link_response(pending, veh, l_decl, "declaration", 3) == 2  # N? -> the L list
    assert link_response(pending, veh, n_decl, "declaration", 4) == 1  # L? -> the N list
    # a declaration is an ask too: the other end's reply names its names
    assert link_response(pending, udp(OCU, ("10.0.0.2", 1033)), frame(reply_fields("Head", "1"), dst="B", src="A"),
                         "reply", 5) == 4


def test_pending_asks_are_bounded_per_conversation():
    """As the dissector (docs/fields-sharedlink.md, "Limits"): one entry per name asked, a repeated
    query replaces the one it repeats, past MAX_PENDING a new name is refused and the frame counted."""
    pending = PendingAsks()
    q = frame(query_fields("Vel"), dst="B", src="A")
    link_response(pending, udp(OCU2, VEH), q, "query", 1)
    for n in range(2, MAX_PENDING + 10):  # one querier polls: one entry, the latest
        link_response(pending, udp(OCU, VEH), q, "query", n)
    assert pending.limits.pending == 0
    for n in range(MAX_PENDING + 10, 2 * MAX_PENDING + 10):  # then floods with new names
        link_response(pending, udp(OCU, VEH), frame(query_fields(f"v{n}"), dst="B", src="A"), "query", n)
    assert pending.limits.pending == 1  # the last new name found MAX_PENDING waiting
    r = frame(reply_fields("Vel", "1"), dst="A", src="B")
    assert link_response(pending, udp(VEH, OCU2), r, "reply", 0) == 1  # the other querier's ask is still there
    assert link_response(pending, udp(VEH, OCU), r, "reply", 0) == MAX_PENDING + 9
    assert link_response(pending, udp(VEH, OCU), r, "reply", 0) is None  # answered once
    last = 2 * MAX_PENDING + 9
    for n, want in ((last - 1, last - 1), (last, None), (MAX_PENDING + 10, MAX_PENDING + 10)):
        assert link_response(pending, udp(VEH, OCU), frame(reply_fields(f"v{n}", "1"), dst="A", src="B"),
                             "reply", 0) == want
    # room again: a new name is remembered
    link_response(pending, udp(OCU, VEH), frame(query_fields("new"), dst="B", src="A"), "query", 7)
    assert link_response(pending, udp(VEH, OCU), frame(reply_fields("new", "1"), dst="A", src="B"), "reply", 0) == 7



def test_pending_asks_past_max_conversations_queriers_are_refused_and_counted():
    """Issue 31: a new querier past MAX_CONVERSATIONS queriers is refused as a new name past
    MAX_PENDING is (nothing remembered, its reply unmatched) and counted in ``limits.pending``
    (it was neither remembered nor counted anywhere); the queriers already there keep asking."""
    pending = PendingAsks()
    q = frame(query_fields("Vel"), dst="B", src="A")
    for port in range(MAX_CONVERSATIONS):
        assert pending.ask(("udp", "10.0.0.1", port, "10.0.0.2", "A", "B"), "R", ["Vel"], port + 1)
    assert pending.limits.pending == 0
    late = ("10.0.0.3", 4104)
    link_response(pending, udp(late, VEH), q, "query", 70000)
    link_response(pending, udp(late, VEH), frame([Field("N", "?")], dst="B", src="A"), "query", 70001)
    assert pending.limits.pending == 2
    assert pending.limits.total == 2
    r = frame(reply_fields("Vel", "1"), dst="A", src="B")
    assert link_response(pending, udp(VEH, late), r, "reply", 0) is None
    assert link_response(pending, udp(VEH, ("10.0.0.1", 7)), r, "reply", 0) == 8
    assert pending.ask(("udp", "10.0.0.1", 7, "10.0.0.2", "A", "B"), "R", ["Vel"], 9)  # a known querier asks again


def test_a_named_value_is_typed_by_its_own_t_only():
    """Issue 31 (agreement with the dissector): a named value's type is the ``T`` of its
    triplet. Without one it is untyped (never a bad value), whatever an earlier triplet of the
    same name or the list said; a positional slot keeps its list's type whatever a named
    triplet of the same name said; a reply with no ``T`` is typed by the list only."""
    link = LinkState(default_list=[])
    link.apply(frame(declaration_fields([("Vel", 2), ("Lat", 0)])), 1)
    ups = link.apply(frame([Field("N", "0"), Field("Q", "Vel"), Field("D", "5")]), 2)
    assert [(u.name, u.type_code, u.bad) for u in ups if not u.carried] == [("Vel", None, False)]
    link.apply(frame(named_fields([("Vel", 4, "x")])), 3)
    ups = link.apply(frame([Field("N", "0"), Field("Q", "Vel"), Field("D", "7"), Field("Q", "Lat"),
                            Field("D", "1.5")]), 4)
    assert [(u.name, u.type_code, u.bad) for u in ups if not u.carried] == [("Vel", None, False), ("Lat", None, False)]
    ups = link.apply(frame(positional_fields(["1", "2"])), 5)
    assert [(u.name, u.type_code) for u in ups] == [("Vel", 2), ("Lat", 0)]
    # a name the list does not have: typed by one triplet, untyped in the next without T
    link.apply(frame(named_fields([("Head", 2, "1.5")])), 6)
    ups = link.apply(frame([Field("N", "0"), Field("Q", "Head"), Field("D", "x"), Field("T", "2"), Field("Q", "Head"),
                            Field("D", "2.5")]), 7)
    assert [(u.type_code, u.bad) for u in ups if u.name == "Head"] == [(None, False), (2, False)]
    reply = link.apply(frame(reply_fields("Head", "9")), 8)
    assert [(u.name, u.type_code) for u in reply] == [("Head", None)]
    assert [(u.name, u.type_code) for u in link.apply(frame(reply_fields("Lat", "9")), 9)] == [("Lat", 0)]


POOL = ["a", "b", "c", "d", "e"]


@st.composite
def list_sessions(draw):
    """Declarations (a list of distinct names in any order) and positional frames as long as the
    list in force, some slots empty."""
    steps = [("decl", draw(st.lists(st.sampled_from(POOL), min_size=1, max_size=5, unique=True)))]
    for _ in range(draw(st.integers(1, 25))):
        if draw(st.integers(0, 4)) == 0:
            steps.append(("decl", draw(st.lists(st.sampled_from(POOL), min_size=1, max_size=5, unique=True))))
        else:
            steps.append(("data", draw(st.lists(st.one_of(st.none(), st.sampled_from(["1", "2", "x"])),
                                                min_size=5, max_size=5))))
    return steps


@settings(max_examples=examples(200), deadline=None)
@given(list_sessions())
def test_a_new_list_keeps_values_by_name_and_drops_the_rest(steps):
    """The rule of issue 29 against a model kept by name: a name the new list keeps keeps its
    value, the frame it came from and its "once filled" mark; a dropped one loses them; a frame
    is full when every once-filled name of the list has a value in it."""
    link = LinkState()
    names: list[str] = []
    values: dict[str, tuple[str, int]] = {}  # name -> (text, frame)
    filled: set[str] = set()
    for number, (what, arg) in enumerate(steps, 1):
        if what == "decl":
            link.apply(frame(declaration_fields([(n, 4) for n in arg])), number)
            names = list(arg)
            values = {n: v for n, v in values.items() if n in names}
            filled &= set(names)
            continue
        texts = arg[: len(names)]
        f = frame(positional_fields(texts))
        want_kind = "full" if all(texts[names.index(n)] is not None for n in filled) else "delta"
        assert link.table("B", "A").kind(f) == want_kind
        ups = link.apply(f, number)
        want = []
        for n, text in zip(names, texts):
            if text is None:
                old = values.get(n)
                want.append((n, old[0] if old else None, True, old[1] if old else None))
            else:
                values[n] = (text, number)
                filled.add(n)
                want.append((n, text, False, None))
        assert [(u.name, u.text, u.carried, u.carried_from) for u in ups] == want


def test_a_slot_past_a_declared_list_is_past_the_list():
    """Python's twin of the dissector's sharedlink.var.unknown (issue 29): a slot past the end of
    a list learnt from a declaration; never past a user's or the a-priori list."""
    link = LinkState()
    link.apply(frame(declaration_fields([("X", 2), ("Y", 4)])), 1)
    ups = link.apply(frame(positional_fields(["1.5", "hi", "7"])), 2)
    t = link.table("B", "A")
    assert [(u.name, t.past_list(u.index)) for u in ups] == [("X", False), ("Y", False), ("#2", True)]
    # a user's list for the pair, and the a-priori list: #i past it, not past a declared list
    user = LinkState(default_list=parse_variables("B>A: Head:2"))
    ups = user.apply(frame(positional_fields(["1", "2"])), 1)
    assert [(u.name, user.table("B", "A").past_list(u.index)) for u in ups] == [("Head", False), ("#1", False)]
    beacon = LinkState()
    ups = beacon.apply(frame(positional_fields(["1"] * 6)), 1)
    assert not any(beacon.table("B", "A").past_list(u.index) for u in ups)
