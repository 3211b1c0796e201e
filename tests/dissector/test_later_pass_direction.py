"""A later pass finds a frame's direction for its tree alone (issue 40, the GUI's rows).

On a later pass (``-2``'s second, sharkd, the GUI's packet list) the state leaves a frame's
direction and list, which only its tree reads, to be found when the tree is built in full
(``state.lua`` ``later_tree_dir``); a hidden tree nobody references a variable's field of never
needs them.  The variables' indexes (their place among the direction's names, the direction's
facts) of the second pass must be the first pass's, in a shown tree and in a hidden one.
"""

from __future__ import annotations

from pathlib import Path

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
# deltas of the four beacon names: each carries the values it left out, with their indexes
BEACON = REPO / "captures" / "beacon-compressed.pcap"
NAMES = ["frame.number", "sharedlink.kind", "sharedlink.var.name", "sharedlink.var.index"]


def _indexes(two_pass: bool) -> list[tuple[str, ...]]:
    rows = tu.fields(BEACON, NAMES, two_pass=two_pass)
    return [tuple(",".join(r[n]) for n in NAMES) for r in rows]


def _matches(flt: str, two_pass: bool) -> list[int]:
    out = tu.summary(BEACON, two_pass=two_pass, extra=["-Y", flt, "-o", 'gui.column.format:"No.","%m"'])
    return [int(x) for x in out if x.strip()]


def test_a_shown_tree_of_the_second_pass_has_the_first_pass_indexes() -> None:
    one, two = _indexes(False), _indexes(True)
    assert any(r[1] == "delta" and r[3] == "0,1,2,3" for r in one), "no delta carrying indexed values"
    assert two == one


def test_a_hidden_tree_of_the_second_pass_matches_what_one_pass_matches() -> None:
    flt = 'sharedlink.kind == "delta" && sharedlink.var.index == 3'
    one = _matches(flt, False)
    assert len(one) > 10, "the filter matches too few frames to tell"
    assert _matches(flt, True) == one
