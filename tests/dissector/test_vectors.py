"""The shared vector table (tests/vectors/sharedlink.json, issue 12) through the real tshark.

Each stream is written as a capture (tests/sl_vectors.py), decoded with every dissector/*.lua
loaded (as `make install` leaves them) in two passes, and every SharedLink frame of every
packet is compared with the table: kind, checksum verdict, variables (name, index, value,
typed value, carried, carried-from, bad value), expert infos, request/response links.
The one-pass decode must agree with the two-pass one on everything but the links a second
pass adds (a query's "Response in").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from sl_cli import run_cli
from sl_robots import OTHERS
from sl_vectors import expected_frames, load_streams, stream_ids, stream_params, tshark_json

import tshark_util as tu

# (one worker for the file: each stream's two-pass run is shared by two tests here and by
# test_agreement.py's test_vector_stream_agrees, in sl_vectors.tshark_json)
pytestmark = pytest.mark.xdist_group("vectors")

REPO = Path(__file__).resolve().parents[2]
STREAMS = load_streams()
CHECKSUM_WORD = {"1": "good", "0": "bad"}
TYPED_FIELDS = {"long": "sharedlink.var.long", "double": "sharedlink.var.double", "string": "sharedlink.var.string"}
TRUE = ("1", "True", "true")


_as_list, _walk = tu.as_list, tu.walk


def _experts(node: Any) -> set[str]:
    return {k for e in _walk(node, "_ws.expert") if isinstance(e, dict) for k in e if not k.startswith("_ws.expert")}


def _one(node: dict, key: str) -> str | None:
    vals = _as_list(node.get(key))
    assert len(vals) <= 1, (key, vals)
    return vals[0] if vals else None


def _frame_trees(layers: dict[str, Any]) -> list[dict[str, Any]]:
    """The packet's SharedLink frame subtrees in order (noise subtrees left out)."""
    return [t for t in _as_list(layers.get("sharedlink")) if isinstance(t, dict) and "sharedlink.noise" not in t]


def _checksum(tree: dict[str, Any]) -> str:
    if "sharedlink.checksum" not in tree and "sharedlink.checksum.text" not in tree:
        return "missing"
    status = [s for s in _walk(tree, "sharedlink.checksum.status")]
    assert len(status) == 1, status
    return CHECKSUM_WORD.get(status[0], "unverified")


def _var(node: dict[str, Any]) -> dict[str, Any]:
    typed = {t: _one(node, f) for t, f in TYPED_FIELDS.items() if f in node}
    index = _one(node, "sharedlink.var.index")
    carried_from = _one(node, "sharedlink.var.carried_from")
    return {
        "name": _one(node, "sharedlink.var.name"),
        "index": int(index) if index is not None else None,
        "value": _one(node, "sharedlink.var.value"),
        "typed": typed,
        "carried": _one(node, "sharedlink.var.carried") in TRUE,
        "carried_from": int(carried_from) if carried_from is not None else None,
        "bad": "sharedlink.var.badvalue" in _experts(node),
    }


def _actual(tree: dict[str, Any]) -> dict[str, Any]:
    resp_to = [int(x) for x in _walk(tree, "sharedlink.response_to")]
    resp_in = [int(x) for x in _walk(tree, "sharedlink.response_in")]
    return {
        "kind": _one(tree, "sharedlink.kind"),
        "checksum": _checksum(tree),
        "vars": [_var(v) for v in _as_list(tree.get("sharedlink.var")) if isinstance(v, dict)],
        "experts": _experts(tree),
        "response_to": sorted(set(resp_to)),
        "response_in": sorted(set(resp_in)),
    }


def _check_var(where: str, exp: dict[str, Any], act: dict[str, Any]) -> None:
    for key in ("name", "index", "value", "carried", "carried_from", "bad"):
        if key in exp:
            assert act[key] == exp[key], f"{where}: {key} {act[key]!r} != expected {exp[key]!r} ({act})"
    if "typed" in exp:
        if exp["typed"] is None:
            assert not act["typed"], f"{where}: no typed value expected, got {act['typed']}"
        else:
            vtype = exp["type"]
            assert list(act["typed"]) == [vtype], f"{where}: typed fields {act['typed']} != {vtype}"
            got = act["typed"][vtype]
            if vtype == "double":
                assert float(got) == exp["typed"], f"{where}: double {got} != {exp['typed']}"
            elif vtype == "long":
                assert int(got) == exp["typed"], f"{where}: long {got} != {exp['typed']}"
            else:
                assert got == exp["typed"], f"{where}: string {got!r} != {exp['typed']!r}"
    elif "type" in exp and not act["carried"]:
        allowed = {exp["type"]} if exp["type"] else set()
        assert set(act["typed"]) <= allowed, f"{where}: typed fields {act['typed']} for type {exp['type']}"


def _check_frame(where: str, exp: dict[str, Any], act: dict[str, Any]) -> None:
    for key in ("kind", "checksum"):
        if key in exp:
            assert act[key] == exp[key], f"{where}: {key} {act[key]!r} != expected {exp[key]!r}"
    if "vars" in exp:
        got = sorted(act["vars"], key=lambda v: 1 << 30 if v["index"] is None else v["index"])
        names = [v["name"] for v in got]
        assert names == [v["name"] for v in exp["vars"]], f"{where}: variables {names}"
        for e, a in zip(exp["vars"], got):
            _check_var(f"{where} {e['name']}", e, a)
    for name in exp.get("experts", []):
        assert name in act["experts"], f"{where}: expert {name} missing ({sorted(act['experts'])})"
    for name in exp.get("no_experts", []):
        assert name not in act["experts"], f"{where}: unexpected expert {name}"
    for key in ("response_to", "response_in"):
        if key in exp:
            want = [] if exp[key] is None else [exp[key]]
            assert act[key] == want, f"{where}: {key} {act[key]} != expected {want}"


def _decode(stream: dict[str, Any], two_pass: bool) -> list[list[dict[str, Any]]]:
    packets = tshark_json(stream, two_pass)   # (the two-pass run is test_agreement.py's too)
    assert len(packets) == len(stream["packets"]), "one capture record per packet"
    return [[_actual(t) for t in _frame_trees(p["_source"]["layers"])] for p in packets]


@pytest.mark.parametrize("stream", stream_params(STREAMS, "tshark"))
def test_vector_stream(stream: dict[str, Any]) -> None:
    decoded = _decode(stream, True)
    for num, pkt in enumerate(stream["packets"], 1):
        assert len(decoded[num - 1]) == len(pkt["frames"]), f"packet {num}: frames {decoded[num - 1]}"
    for num, k, exp in expected_frames(stream):
        _check_frame(f"{stream['name']} packet {num} frame {k + 1}", exp, decoded[num - 1][k])


@pytest.mark.parametrize("stream", STREAMS, ids=stream_ids(STREAMS))
def test_vector_stream_one_pass_equals_two_pass(stream: dict[str, Any]) -> None:
    one = _decode(stream, False)
    two = _decode(stream, True)
    for frames in (one, two):
        for f in (f for p in frames for f in p):
            f.pop("response_in")
    assert one == two


# A tree nobody sees (-Y with a summary, coloring rules, taps) is built by a fast path without
# ranges or labels; a shown tree (-V) by the full one.  Both must match the same frames.
FILTERS = [
    "sharedlink.var.double > 50 && sharedlink.var.index == 2", "sharedlink.var.carried_from == 1",
    'sharedlink.kind == "delta" && sharedlink.checksum.status == 0', "sharedlink.sync.is_late",
    'sharedlink.var.name == "AutoGpsVel" && sharedlink.src.node == 2', "sharedlink.var.badvalue || sharedlink.crlf.missing",
    # per-variable fields are probed once a frame in the hidden tree (referenced or not): every
    # variable's item must be there when a filter counts or picks a later one
    "count(sharedlink.var.name) == 4", 'count(sharedlink.var) == 4 && sharedlink.kind == "delta"',
    "sharedlink.var.carried && sharedlink.var.index == 3", "count(sharedlink.var.double) == 2",
]


def _matched_hidden(cap: Path, flt: str, prefs: dict | None) -> set[int]:
    lines = tu.summary(cap, prefs=prefs, extra=["-Y", flt, "-o", 'gui.column.format:"No.","%m"', *OTHERS])
    return {int(x.split()[0]) for x in lines if x.strip()}


def _matched_shown(cap: Path, prefs: dict | None) -> dict[str, set[int]]:
    """Each filter's frames in a shown tree, from one run (a Lua tap a filter under -V)."""
    return {flt: set(found) for flt, found in tu.shown_matches(cap, FILTERS, prefs=prefs, extra=OTHERS).items()}


# Which fields are referenced is kept over tshark's first pass; with SHAREDLINK_PROBE_EACH_FRAME
# it is asked again in every frame: both must match.
@pytest.mark.parametrize("each_frame", [False, True], ids=["pass-cache", "each-frame"])
@pytest.mark.parametrize("form", ["named", "positional"])
def test_hidden_tree_matches_shown_tree(form: str, each_frame: bool, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:

    if each_frame:
        monkeypatch.setenv("SHAREDLINK_PROBE_EACH_FRAME", "1")

    cap = tmp_path / f"{form}.pcap"
    run_cli("gen", "--frames", "60", "--compress", "--form", form, "--bad-checksum", "0.1", "--drop", "0.1", str(cap), text=False, check=True)
    prefs = {"sharedlink.variables": "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2"}
    shown = _matched_shown(cap, prefs)
    for flt in FILTERS:
        assert _matched_hidden(cap, flt, prefs) == shown[flt], flt


def test_hidden_tree_learns_again_in_the_second_pass(tmp_path: Path) -> None:
    """tshark -2: the first pass primes the read filter's fields only, the second the display
    filter's. What the first pass learnt must not hide a field the second pass asks for."""

    cap = tmp_path / "two.pcap"
    run_cli("gen", "--frames", "40", "--compress", str(cap), text=False, check=True)
    read_filter, display = 'sharedlink.kind == "delta"', "count(sharedlink.var.name) == 4 && sharedlink.var.carried"
    # -R drops frames and numbers the rest again: frames are compared by their time
    lines = tu.summary(cap, two_pass=True, extra=["-R", read_filter, "-Y", display, "-t", "e",
                                                  "-o", 'gui.column.format:"Time","%t"', *OTHERS])
    hidden = {round(float(x.split()[0]), 6) for x in lines if x.strip()}
    rows = tu.fields(cap, ["frame.time_epoch"], display_filter=f"({read_filter}) && ({display})", two_pass=False,
                     extra=OTHERS)
    shown = {round(float(r["frame.time_epoch"][0]), 6) for r in rows}
    assert shown and hidden == shown
