"""Per-pair variable lists (sharedlink.protocols.varlists, issue 29): the syntax of vehicle
profiles, ``B>A: AutoGpsHead:2,...; A>B: ...``, and the plain old syntax as the list of every
pair. The 28-name list is the one the public jaffe-se/shared_link_bridge declares (L0) for a
real vehicle; the 10 names are its OCU's control values (N0)."""

from __future__ import annotations

import pytest
from sl_vectors import REAL_OCU_LIST, REAL_VEHICLE_LIST

from sharedlink.protocols.varlists import (
    ANY_PAIR,
    MAX_SLOTS,
    VarListError,
    format_list,
    format_varlists,
    parse_list,
    parse_pair,
    parse_varlists,
)

VEHICLE, OCU = REAL_VEHICLE_LIST, REAL_OCU_LIST
VEHICLE_TEXT = (
    "AutoGpsHead:2,AutoGpsLat:2,AutoGpsLon:2,AutoGpsVel:2,AutoGpsReferences:0,AutoGpsQuality:0,AutoGpsStamp:2,"
    "pause:0,key_on:0,eng_enb:0,pe7:0,bbrake:0,fbrake:0,steerang:2,throttle:0,svp_enb_eng,serialpck:0,veh_gear:0,"
    "veh_state:0,veh_estop:0,veh_obstacle:0,vehicle_bat:2,run_composite:4,VehicleName:4,Health_total:0,rpm:0,"
    "fuel:0,sys_thd:2"
)
OCU_TEXT = ("video_mux1:0,veh_start:0,veh_enable:0,veh_motion:0,joy_steer:2,veh_steer:0,veh_brake:0,"
            "veh_throttle:0,veh_shift:0,veh_clutch:0")


def test_a_list_per_pair():
    got = parse_varlists(f"B>A: {VEHICLE_TEXT}; A>B: {OCU_TEXT}")
    assert got == {"B>A": VEHICLE, "A>B": OCU}
    assert len(got["B>A"]) == 28 and got["B>A"][15] == ("svp_enb_eng", None)
    assert list(got) == ["B>A", "A>B"]


def test_the_plain_old_syntax_is_the_list_of_every_pair():
    assert parse_varlists("AutoGpsLat,AutoGpsLon,AutoGpsHead,AutoGpsVel") == {
        ANY_PAIR: [("AutoGpsLat", None), ("AutoGpsLon", None), ("AutoGpsHead", None), ("AutoGpsVel", None)]}
    assert parse_varlists("Lat:2,Lon:2,Mode:4,Count:0,Note,") == {
        ANY_PAIR: [("Lat", 2), ("Lon", 2), ("Mode", 4), ("Count", 0), ("Note", None)]}


def test_every_pair_and_per_pair_entries_mix_and_a_later_entry_replaces():
    got = parse_varlists("Lat:2,Lon:2; B>A: X:0; C>A: Y:4; B>A: Z:2,W")
    assert got == {ANY_PAIR: [("Lat", 2), ("Lon", 2)], "B>A": [("Z", 2), ("W", None)], "C>A": [("Y", 4)]}


def test_new_lines_spaces_and_comments():
    text = f"# profile of VEH_NorthEastern1\n  B > A :  {VEHICLE_TEXT.replace(',', ' , ')}\n#\n\n#C>A: x\nA>B: {OCU_TEXT}\n"
    assert parse_varlists(text) == {"B>A": VEHICLE, "A>B": OCU}
    # '#3' is a name (a slot nothing named), not a comment
    assert parse_varlists("B>A: #0,#1,Vel:2") == {"B>A": [("#0", None), ("#1", None), ("Vel", 2)]}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("B>A: Vel:3", "bad type '3' for Vel in B>A (types are 0 long, 2 double, 4 string)"),
        ("Vel:1", "bad type '1' for Vel (types are 0 long, 2 double, 4 string)"),
        ("B>A: Vel:double", "bad type 'double' for Vel in B>A"),
        ("Vel:-2", "bad type '-2' for Vel"),
        ("Q>A: Vel:2", "bad node pair 'Q>A' (SRC>DST, letters A-P)"),
        ("AB>A: Vel:2", "bad node pair 'AB>A'"),
        ("B>: Vel:2", "bad node pair 'B>'"),
        ("B>A:", "empty variable list in B>A"),
        ("B>A: Vel:2; A>B: , ,", "empty variable list in A>B"),
        ("B>A: a|b:2", "bad variable name 'a|b' in B>A"),
        (":2", "bad variable name ''"),
        ("", "empty variable list"),
        ("# only a comment\n;;", "empty variable list"),
    ],
)
def test_bad_lists_are_one_line_errors(text, message):
    with pytest.raises(VarListError) as ei:
        parse_varlists(text)
    assert isinstance(ei.value, ValueError)
    assert str(ei.value).startswith(message) and "\n" not in str(ei.value)


def test_a_list_longer_than_the_slot_limit_is_an_error():
    assert len(parse_list(",".join(f"v{i}" for i in range(MAX_SLOTS)))) == MAX_SLOTS
    with pytest.raises(VarListError, match=f"more than {MAX_SLOTS} variables in B>A"):
        parse_varlists("B>A: " + ",".join(f"v{i}" for i in range(MAX_SLOTS + 1)))


def test_pairs():
    assert parse_pair(" P > A ") == "P>A"
    for bad in ("a>B", "B-A", "B>AA", ">A"):
        with pytest.raises(VarListError):
            parse_pair(bad)


def test_format_round_trips():
    lists = {"B>A": VEHICLE, "A>B": OCU}
    text = format_varlists(lists)
    assert text == f"B>A: {VEHICLE_TEXT}; A>B: {OCU_TEXT}"
    assert parse_varlists(text) == lists
    assert parse_varlists(format_varlists(lists, sep="\n")) == lists
    every = {"C>D": [("x", 4)], ANY_PAIR: [("Lat", 2), ("Note", None)]}
    assert format_varlists(every) == "Lat:2,Note; C>D: x:4"
    assert parse_varlists(format_varlists(every)) == every
    # a type the syntax cannot give (T1, T3 in a frame) is written untyped
    assert format_list([("a", 1), ("b", 3), ("c", 0)]) == "a,b,c:0"
