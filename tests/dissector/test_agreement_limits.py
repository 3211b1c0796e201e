"""Issue 31: the dissector and the Python tools drop and count the same input at each limit
(docs/fields-sharedlink.md, "Limits").

Each capture is what a real sender produces past a limit: a querier that asks and asks without
answer (``max_pending``), a TCP sender that starts a frame and never closes it
(``max_held_bytes``), ordinals and types of ten digits and more (``MAX_NUMBER_DIGITS``). tshark
with sharedlink.lua marks each frame where input was dropped with "Limit exceeded: ..."; Python
counts the same drops in ``stats``'s ``limits`` (:class:`~sharedlink.protocols.limits.LimitCounts`).
Both must name the same frames (or counts) and link the same replies.
"""

from __future__ import annotations

import json
from pathlib import Path

from sl_agreement import (
    OCU,
    VEHICLE,
    limit_frame,
    limit_rows,
    lua_frames,
    python_frames,
    session,
    udp_builder,
    write_session,
)
from sl_cli import run_cli

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import TcpConversation
from sharedlink.capture.serial_format import GIVEN_UP
from sharedlink.capture.stream import iter_frames
from sharedlink.protocols.limits import MAX_HELD_BYTES, MAX_NAMES, MAX_PENDING


def _limited(rows: list[dict[str, list[str]]], what: str = "") -> list[int]:
    """The frames the dissector marks "Limit exceeded: ..." (with ``what`` in the text)."""
    return [int(r["frame.number"][0]) for r in rows
            if any(m.startswith("Limit exceeded:") and what in m for m in r["_ws.expert.message"])]


def _counts(cap: Path) -> dict[str, int]:
    """``sharedlink stats --json``'s limits (the command as users run it)."""
    r = run_cli("stats", "--json", str(cap), timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return json.loads(r.stdout)["limits"]


# -- max_pending ------------------------------------------------------------------------------


def test_a_querier_past_max_pending_is_refused_and_counted_alike(tmp_path: Path) -> None:
    """An OCU polls one name and the list (``N?``) 520 times each with no answer (a repeated
    query replaces the one it repeats: no limit), then asks for 1,100 names no one answers:
    from the one that finds max_pending (1024) already waiting, each new query is refused (not
    remembered) and counted. A reply to an early name still finds its query; one to a refused
    name, and the poll's reply, as each side links them."""
    ask, answer = udp_builder(OCU, VEHICLE), udp_builder(VEHICLE, OCU)
    frames = []
    for i in range(520):
        frames += [ask.frame(limit_frame("BA|Qpoll"), 2 * i + 1), ask.frame(limit_frame("BA|N?"), 2 * i + 2)]
    first_q = len(frames) + 1
    frames += [ask.frame(limit_frame(f"BA|Qq{i}"), 1300 + i) for i in range(1100)]
    late = 1100 - (MAX_PENDING - 2)  # the poll and the N? already wait
    frames += [answer.frame(limit_frame("AB|Rq5|D1"), 1), answer.frame(limit_frame("AB|Rq1099|D1"), 2),
               answer.frame(limit_frame("AB|Rpoll|D7"), 3)]
    cap = write_session(tmp_path / "queries.pcap", frames)

    rows = limit_rows(cap, ("sharedlink.response_to",))
    refused = list(range(first_q + 1100 - late, first_q + 1100))
    assert _limited(rows, "(max_pending)") == refused
    assert _limited(rows) == refused
    lua_links = [r["sharedlink.response_to"] for r in rows[-3:]]
    assert lua_links == [[str(first_q + 5)], [], [str(first_q - 2)]]

    py = [d for d in iter_decoded(cap) if isinstance(d, Decoded)]
    assert [d.response_to for d in py[-3:]] == [first_q + 5, None, first_q - 2]
    assert capture_stats(cap).limits.to_dict() == {"slots": 0, "names": 0, "numbers": 0, "conversations": 0,
                                                   "held": 0, "pending": len(refused)}


# -- max_held_bytes (TCP) ---------------------------------------------------------------------


def test_a_tcp_frame_that_never_closes_is_given_up_and_counted_alike(tmp_path: Path) -> None:
    """A vehicle on TCP sends a frame, then a frame it never closes (a dump of 84 KB with no
    ``]``, in 1,400-byte segments), twice, then good frames again: each time the held bytes go
    past max_held_bytes (65536) on the same segment, both sides give the frame up there (Lua:
    "Limit exceeded" and the frame decoded as it is; Python: noise, counted in ``limits.held``)
    and decode the frames after it."""
    tcp = TcpConversation(*OCU, *VEHICLE)
    frames = tcp.open()
    good = limit_frame("AB|N0|T2|QLat|D1.5")
    frames.append(tcp.send(False, good))
    for _ in range(2):
        frames.append(tcp.send(False, b"[:AB|N0|T4|QDump|D"))
        frames += [tcp.send(False, b"x" * 1400) for _ in range(60)]
        frames.append(tcp.send(False, b"\r\n" + good))
    cap = write_session(tmp_path / "tcp.pcap", frames)

    rows = limit_rows(cap, ("sharedlink.kind",))
    given_up = _limited(rows, "(max_held_bytes)")
    assert len(given_up) == 2 and _limited(rows) == given_up
    goods = [i + 1 for i, r in enumerate(rows) if "full" in r["sharedlink.kind"]]
    assert len(goods) == 3

    ours = [sf.number for sf in iter_frames(cap) if not isinstance(sf, tuple) and sf.error == GIVEN_UP]
    assert ours == given_up
    assert [d.number for d in iter_decoded(cap) if isinstance(d, Decoded) and d.kind == "full"] == goods
    assert capture_stats(cap).limits.held == 2
    # what was given up went past the limit: the first segment past it, no earlier
    assert (given_up[0] - 5) * 1400 + len(b"[:AB|N0|T4|QDump|D") > MAX_HELD_BYTES


# -- digits of a number field -----------------------------------------------------------------


def test_numbers_of_ten_digits_alike(tmp_path: Path) -> None:
    """A sender that writes an unset 32-bit integer (4294967295) or a wrapped counter where an
    ordinal or a type goes: an N or L of more than 9 digits is a limit hit on both sides (Lua
    "Limit exceeded: N has more than 9 digits", Python ``limits.numbers``); a T of more than 9
    digits is a type that is not a number, as a T past 255 (Lua "Type is not a number" on the
    value, its var.badvalue; Python: no type, the value flagged bad), not a limit hit."""
    b = udp_builder(VEHICLE, OCU)
    bodies = ["AB|N0|T4294967295|QVel|D5", "AB|N0|T12345678901234|QVel|D5", "AB|N4294967295|D1",
              "AB|L4294967295|T2|QLat", "AB|N0|T2|QVel|D6", "AB|N0|T300|QVel|D7", "AB|N0|T0|QVel|T99999999999|QW|D3",
              "BA|T4294967295|RVel|D1", "AB|N0|T9999999999|QP0|T2|QP1", "AB|N0|D5|D6"]
    cap = write_session(tmp_path / "digits.pcap", [b.frame(limit_frame(x), i + 1) for i, x in enumerate(bodies)])
    rows = limit_rows(cap, ("sharedlink.var.name",))
    assert _limited(rows) == _limited(rows, "more than 9 digits") == [3, 4]
    not_a_type = [i + 1 for i, r in enumerate(rows) if "Type is not a number" in r["_ws.expert.message"]]
    assert not_a_type == [1, 2, 6, 7, 8, 9]
    # one count a long ordinal (Python counts the values it puts past max_slots in "slots" besides)
    assert _counts(cap)["numbers"] == 2
    # the values with a T that is no type: shown alike (bad, untyped), and the declaration's
    # slot P0 untyped after it; the value after a long ordinal shown as sent, stored nowhere
    lua, py = lua_frames(cap, None), python_frames(cap, len(bodies), None)
    assert lua == py
    assert py[2][0]["vars"] == [(None, "1", False, False, None, False)]
    assert py[0][0]["vars"] == [("Vel", "5", False, True, None, False)]
    assert py[-1][0]["vars"] == [("P0", "5", False, False, None, False), ("P1", "6", False, False, "double", False)]


# -- an ordinal of 2^31 - 1 and more --------------------------------------------------------------

#: a vehicle sends a full set, then a frame whose ordinal is an unset 32-bit integer, then a delta
#: that sends nothing: the slots keep the full set's values (the odd frame is past max_slots)
HUGE_ORDINAL = ["AB|N4294967295|D1", "AB|N0|D5|D6", "AB|N4294967295|D1", "AB|N0|D|D"]


def _huge_ordinal(tmp_path: Path) -> Path:
    b = udp_builder(VEHICLE, OCU)
    return write_session(tmp_path / "ordinal.pcap", [b.frame(limit_frame(x), i + 1) for i, x in enumerate(HUGE_ORDINAL)])


def test_python_drops_the_values_of_a_huge_ordinal(tmp_path: Path) -> None:
    py = python_frames(_huge_ordinal(tmp_path), len(HUGE_ORDINAL), None)
    assert [f[0]["kind"] for f in py] == ["delta", "full", "delta", "delta"]
    assert py[3][0]["vars"] == [(None, "5", True, False, None, False), (None, "6", True, False, None, False)]
    assert capture_stats(tmp_path / "ordinal.pcap").limits.numbers == 2


def test_lua_drops_the_values_of_a_huge_ordinal(tmp_path: Path) -> None:
    lua = lua_frames(_huge_ordinal(tmp_path), None)
    assert [f[0]["kind"] for f in lua] == ["delta", "full", "delta", "delta"]
    assert lua[3][0]["vars"] == [(None, "5", True, False, None, False), (None, "6", True, False, None, False)]


# -- max_slots and max_names: shown as sent, stored nowhere -------------------------------------


def test_values_past_max_slots_are_shown_as_sent_and_stored_nowhere_alike(tmp_path: Path) -> None:
    """A vehicle sends slots 1022 to 1025 (two past max_slots), then a full set, then the same
    slots empty: both sides show the values past the limit as the frame sends them (``#1024``:
    a value, not carried; an empty one: carried with no value, as no slot holds one), flag the
    frame, store nothing for them, and carry only the two slots within the limit."""
    bodies = ["AB|N1022|D1|D2|D3|D4", "AB|N0|D5", "AB|N1022|D|D|D|D", "AB|N0|D6|D7"]
    cap = write_session(tmp_path / "slots.pcap", [udp_builder(VEHICLE, OCU).frame(limit_frame(x), i + 1) for i, x in enumerate(bodies)])
    assert _limited(limit_rows(cap), "(max_slots)") == [1, 3]
    assert capture_stats(cap).limits.slots == 4
    lua, py = lua_frames(cap, None), python_frames(cap, len(bodies), None)
    assert lua == py
    assert py[0][0]["vars"] == [(None, x, False, False, None, False) for x in "1234"]
    assert py[2][0]["vars"] == sorted([(None, None, True, False, None, False)] * 2 + [
        (None, "1", True, False, None, False), (None, "2", True, False, None, False)], key=repr)
    ours = [d for d in iter_decoded(cap) if isinstance(d, Decoded)]
    assert [u.name for u in ours[0].updates] == ["#1022", "#1023"]  # what commands report: the stored slots
    assert [u.name for u in ours[0].shown] == ["#1022", "#1023", "#1024", "#1025"]


def test_a_new_name_past_max_names_is_shown_as_sent_and_stored_nowhere_alike(tmp_path: Path) -> None:
    """A direction that has sent max_names (4096) names sends two more, one with a T and one
    without, and a known one: the new names are shown once, typed by their own T, never
    carried after, and the frame flagged (Lua) / counted (Python, one a value)."""
    big = "AB|N0|" + "|".join(f"T2|Qn{i}|D1" for i in range(MAX_NAMES))
    bodies = [big, "AB|N0|T2|QZ|D5|T2|Qn0|D2", "AB|N0|QY|D6", "AB|N0|T2|Qn1|D3"]
    cap = write_session(tmp_path / "names.pcap", [udp_builder(VEHICLE, OCU).frame(limit_frame(x), i + 1) for i, x in enumerate(bodies)])
    assert _limited(limit_rows(cap)) == _limited(limit_rows(cap), "(max_names)") == [2, 3]
    assert capture_stats(cap).limits.names == 2
    lua, py = lua_frames(cap, None), python_frames(cap, len(bodies), None)
    assert lua == py
    assert [v for v in py[1][0]["vars"] if not v[2]] == [("Z", "5", False, False, "double", False),
                                                         ("n0", "2", False, False, "double", False)]
    assert [v for v in py[2][0]["vars"] if not v[2]] == [("Y", "6", False, False, None, False)]
    assert not any(v[0] in ("Y", "Z") for v in py[3][0]["vars"])
    ours = [d for d in iter_decoded(cap) if isinstance(d, Decoded)]
    assert not any(u.name in ("Y", "Z") for d in ours for u in d.updates)


# -- a named value without T -------------------------------------------------------------------

#: a vehicle declares Vel double and Lat long, then sends named values with and without T: a
#: value is typed by the T of its own triplet (BUL-009: "Ttype|Qname|Ddata"), or the frame's last
#: T before it (issue 40), untyped (never bad) with none in its frame, whatever an earlier frame
#: or the list said; a positional slot by its list
UNTYPED_AFTER_TYPED = ["AB|N0|T2|QVel|T0|QLat", "AB|N0|QVel|D5", "AB|N0|T4|QVel|D6", "AB|N0|QVel|D7",
                       "AB|N0|D1|D2", "AB|N0|QLat|D1.5", "AB|N0|T2|QHead|D1|QHead|D2", "BA|QHead", "AB|RHead|D5",
                       "BA|QLat", "AB|RLat|D1.5"]


def test_a_named_value_without_t_is_untyped_alike(tmp_path: Path) -> None:
    frames = session(UNTYPED_AFTER_TYPED)
    cap = write_session(tmp_path / "untyped.pcap", frames)
    lua, py = lua_frames(cap, None), python_frames(cap, len(frames), None)
    assert lua == py

    def sent(i: int) -> list[tuple]:
        return [v for v in py[i][0]["vars"] if not v[2]]
    assert sent(1) == [("Vel", "5", False, False, None, False)]
    assert sent(3) == [("Vel", "7", False, False, None, False)]
    assert sent(4) == [("Lat", "2", False, False, "long", False), ("Vel", "1", False, False, "double", False)]
    assert sent(5) == [("Lat", "1.5", False, False, None, False)]
    # the second Head has no T of its own: the frame's last T (issue 40)
    assert sent(6) == [("Head", "1", False, False, "double", False), ("Head", "2", False, False, "double", False)]
    assert sent(8) == [("Head", "5", False, False, None, False)]  # a reply: the list's type, Head has none
    assert sent(10) == [("Lat", "1.5", False, True, None, False)]  # ... Lat's is long: a bad value


# -- a name without T after one (issue 40) ----------------------------------------------------

#: BUL-009: a Q name with no T of its own takes the frame's last T ("created with the
#: previously defined type"): in a declaration (BUL-110's svp_enb_eng, veh_clutch), in named
#: data (a bad value when it does not fit), after a T that is no type (untyped, no warning of
#: its own), and in a reply (the T before it wins over the list's type)
LAST_T = ["AB|N0|T0|Qthrottle|Qsvp_enb_eng|T4|Qname|T2|Qvel|Qhead", "AB|N0|D1|D2|Dx|D1.5|D7",
          "AB|N0|D|D1.5|D|D|D", "AB|N0|T0|QA|D1|QB|D2|T2|QC|D3|QD|D4.5", "AB|N0|T0|QA|D1|QB|Dz",
          "AB|N0|Tx|QA|D1|QB|D2", "AB|N0|QE|D1|T2|QF|D2", "BA|QA|QB", "AB|T2|RA|D1|RB|D2",
          "BA|N0|T0|Qveh_shift|Qveh_clutch", "BA|N0|D3|D1"]


def test_a_name_without_t_takes_the_last_t_alike(tmp_path: Path) -> None:
    frames = session(LAST_T)
    cap = write_session(tmp_path / "last_t.pcap", frames)
    lua, py = lua_frames(cap, None), python_frames(cap, len(frames), None)
    assert lua == py

    def types(i: int) -> dict[str, tuple]:   # name -> (bad, type) of the values the frame sends
        return {v[0]: (v[3], v[4]) for v in py[i][0]["vars"] if not v[2]}
    assert types(1) == {"throttle": (False, "long"), "svp_enb_eng": (False, "long"), "name": (False, "string"),
                        "vel": (False, "double"), "head": (False, "double")}
    assert types(2) == {"svp_enb_eng": (True, None)}   # a long slot: 1.5 is a bad value
    assert types(3) == {"A": (False, "long"), "B": (False, "long"), "C": (False, "double"), "D": (False, "double")}
    assert types(4) == {"A": (False, "long"), "B": (True, None)}
    assert types(5) == {"A": (True, None), "B": (False, None)}   # after a T that is no type: untyped, no warning
    assert types(6) == {"E": (False, None), "F": (False, "double")}   # no T before E in its frame
    assert types(8) == {"A": (False, "double"), "B": (False, "double")}   # a reply: the T before it
    assert types(10) == {"veh_shift": (False, "long"), "veh_clutch": (False, "long")}
    rows = tu.fields(cap, ["frame.number", "sharedlink.type"], two_pass=False)
    assert rows[0]["sharedlink.type"] == ["0", "0", "4", "2", "2"]   # the inherited ones generated


# -- max_slots: named values are no slots ------------------------------------------------------


def test_named_values_past_the_1024th_are_no_slot_limit_hit(tmp_path: Path) -> None:
    """A beacon of 1,100 named triplets, and one at ordinal 1023 or 2000: a named value has no
    slot, so neither side calls it past max_slots (the dissector did: its variables' running
    index passed 1024); every value is shown and stored alike. A positional value and a declared
    name at slot 1024 still are (frames 4 and 5)."""
    big = "AB|N0|" + "|".join(f"T2|Qv{i}|D{i}" for i in range(1100))
    bodies = [big, "AB|N1023|T2|Qv0|D1|T2|Qv1|D2", "AB|N2000|T2|Qv2|D3", "AB|N1023|D1|D2", "BA|N1023|Qa|Qb"]
    frames = session(bodies)
    cap = write_session(tmp_path / "named.pcap", frames)
    assert _limited(limit_rows(cap)) == [4, 5]
    assert capture_stats(cap).limits.to_dict()["slots"] == 2
    lua, py = lua_frames(cap, None), python_frames(cap, len(bodies), None)
    assert lua[:3] == py[:3]
    assert len(py[0][0]["vars"]) == 1100


# -- an ordinal that is not decimal digits ---------------------------------------------------------

#: ordinals Lua's tonumber reads and a decimal reading does not (hex, exponent, sign, fraction),
#: and ones that are no number: each is no ordinal (its values from slot 0, never a full set),
#: so 1e9 and 1023.0 are no slot past max_slots, and 0x1 declares from slot 0
ODD_ORDINALS = ["AB|N0|T2|QA|T2|QB", "AB|N?|D1|D2", "AB|N|D1|D2", "AB|Nx|D1|D2", "AB|N+0|D1|D2", "AB|N00|D3|D4",
                "AB|N1023.0|D5|D6", "AB|N?|T2|QA|D1|T2|QB|D2", "AB|N1e9|D7", "AB|N0x1|T2|QY", "AB|N0|D1|D2",
                "BA|L+1|T2|QZ", "BA|N5.5|D1"]


def test_an_ordinal_that_is_not_decimal_digits_is_no_number_alike(tmp_path: Path) -> None:
    frames = session(ODD_ORDINALS)
    cap = write_session(tmp_path / "ordinals.pcap", frames)
    rows = limit_rows(cap)
    assert _limited(rows) == []
    assert capture_stats(cap).limits.total == 0
    lua, py = lua_frames(cap, None), python_frames(cap, len(frames), None)
    assert lua == py
    assert [f[0]["kind"] for f in py[1:9]] == ["delta", "delta", "delta", "delta", "full", "delta", "delta", "delta"]
    assert py[8][0]["vars"][0] == ("A", "7", False, False, "double", False)  # 1e9 is no slot 10^9
    assert [v[0] for v in py[10][0]["vars"]] == ["Y", None]  # 0x1 declared Y at slot 0



# -- a declaration that shortens the list under waiting asks -----------------------------------

#: an OCU declares a, b, c, fills them, shortens its list to a before the vehicle's reply to both
#: declarations comes (the reply links to the latest ask of each name), then declares z at slot 1
#: and x, y at 1023 and 1024 (y past max_slots: not in the list, its ask still waits)
SHORTENED = ["BA|N0|T2|Qa|T2|Qb|T2|Qc", "BA|N0|D1|D2|D3", "BA|N0|T2|Qa", "AB|N0|Ra|D1|Rb|D2|Rc|D3", "BA|N0|D4",
             "BA|N0|D|D|D", "BA|N1|T0|Qz", "BA|N0|D|D|D", "AB|Rz|D5", "BA|L0|T2|Qq", "AB|N0|D9|D8",
             "BA|N1023|T2|Qx|T2|Qy", "BA|N0|D|D", "AB|Rx|D1|Ry|D2"]


def test_a_shortened_list_under_waiting_asks_alike(tmp_path: Path) -> None:
    frames = session(SHORTENED)
    cap = write_session(tmp_path / "shortened.pcap", frames)
    lua, py = lua_frames(cap, None), python_frames(cap, len(frames), None)
    assert lua == py
    rows = limit_rows(cap, ("sharedlink.response_to",))
    ours = [d.response_to for d in iter_decoded(cap) if isinstance(d, Decoded)]
    assert [max(map(int, r["sharedlink.response_to"]), default=None) for r in rows] == ours
    assert _limited(rows) == [12]
    assert ours[3] == 3 and ours[8] == 7 and ours[13] == 12
