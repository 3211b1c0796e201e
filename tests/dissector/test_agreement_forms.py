"""A direction that changes form: positional frames, then named ones, then positional again.

A named frame carries only the names the direction sent by name (docs/fields-sharedlink.md,
"Rules for real sessions"); the positional slots' values are not shown on it as carried. Both
decoders (sharedlink.lua in tshark, and the Python core every command uses) must show the same
values on every frame.
"""

from __future__ import annotations

from pathlib import Path

from sl_agreement import lua_frames, python_frames, session, write_session

import tshark_util as tu

SESSION = [
    "AB|N0|D1|D2|D3|D4",                          # positional: four slots
    "AB|N1|D|D5",                                 # a delta: slot 0 carried
    "AB|T2|QAutoGpsLat|D1.5",                     # named: one name, no slot carried
    "AB|N1|D|D6",                                 # positional again
    "AB|T2|QAutoGpsLat|D1.5|T2|QSpeed|D2",        # named: a second name
    "AB|T2|QSpeed|D3",                            # named: AutoGpsLat carried, no slot
]


def test_a_named_frame_after_positional_ones_carries_only_names_sent_by_name(tmp_path: Path) -> None:
    cap = write_session(tmp_path / "forms.pcap", session(SESSION))
    rows = tu.fields(cap, ["frame.number"], two_pass=False)
    assert len(rows) == len(SESSION)
    lua, py = lua_frames(cap), python_frames(cap, len(SESSION))
    assert lua == py
    named_after_positional = [v[0] for v in lua[2][0]["vars"]]
    assert named_after_positional == ["AutoGpsLat"], lua[2]
    last = sorted((v[0], v[2]) for v in lua[5][0]["vars"])
    assert last == [("AutoGpsLat", True), ("Speed", False)], lua[5]
