"""Filtering by variable (issue 29): ``sharedlink.value.<name>``, one field per variable value.

``sharedlink.var.name == "AutoGpsVel" && sharedlink.var.double > 30`` matches a frame where any
double is over 30 (Wireshark does not tie two fields of one subtree together); the value field
asks the question itself.  The frames it must match are computed independently, from the Python
reference decoder (its values, sent or carried), and the dissector is run in a tree nobody sees
(``-Y``, the compact tree) and a shown one (``-T fields``).  Also: the fields registered at load
(the Kairos names typed as their bulletins type them, a name saved in the preferences file), and
a variables preference that cannot be read (the same reason as ``--variables``).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from sl_cli import run_cli

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded
from sharedlink.protocols.varlists import VarListError, parse_varlists

REPO = Path(__file__).resolve().parents[2]
BEACON = REPO / "captures" / "beacon-compressed.pcap"


def _python_frames_over(cap: Path, name: str, limit: float) -> set[int]:
    """Packets with a data frame whose ``name`` (sent or carried) reads as a number over limit."""
    out = set()
    for d in iter_decoded(cap):
        if not isinstance(d, Decoded) or d.kind not in ("full", "delta"):
            continue
        for u in d.shown:
            if u.name == name and u.text is not None:
                try:
                    if float(u.text) > limit:
                        out.add(d.number)
                except ValueError:
                    pass
    return out


def _hidden(cap: Path, flt: str) -> set[int]:
    lines = tu.summary(cap, extra=["-Y", flt, "-o", 'gui.column.format:"No.","%m"'])
    return {int(x.split()[0]) for x in lines if x.strip()}


def _shown(cap: Path, flt: str) -> set[int]:
    return {int(r["frame.number"][0]) for r in tu.fields(cap, ["frame.number"], display_filter=flt, two_pass=False)}


def _generated(tmp_path: Path, *args: str) -> Path:
    cap = tmp_path / "gen.pcap"
    run_cli("gen", "--frames", "200", "--compress", *args, "-o", str(cap), text=False, check=True)
    return cap


@pytest.mark.parametrize("source", ["beacon-compressed", "gen-named", "gen-positional"])
def test_value_field_matches_exactly_the_frames_over_the_limit(source: str, tmp_path: Path) -> None:
    if source == "beacon-compressed":
        cap, limit = BEACON, 30
    else:
        # the generator's vehicle speeds up from 0 by 0.8 a frame (up to 20): over 12 half-way
        cap, limit = _generated(tmp_path, "--seed", "7", "--form", source.split("-")[1], "--drop", "0.1"), 12
    want = _python_frames_over(cap, "AutoGpsVel", limit)
    assert want, f"the capture has speeds over {limit}"
    flt = f"sharedlink.value.AutoGpsVel > {limit}"
    assert _hidden(cap, flt) == want
    assert _shown(cap, flt) == want
    # and a frame is over, at most the limit, or without the value
    at_most = _shown(cap, f"sharedlink.value.AutoGpsVel <= {limit}")
    assert at_most and not (at_most & want)


def test_the_old_filter_matched_the_latitude_too() -> None:
    """The README's old filter: frame 1 (AutoGpsVel 0, latitude 38.3) matches it, not the value field."""
    old = _shown(BEACON, 'sharedlink.var.name == "AutoGpsVel" && sharedlink.var.double > 30')
    new = _shown(BEACON, "sharedlink.value.AutoGpsVel > 30")
    assert 1 in old and 1 not in new
    assert new < old


def _field_types(env: dict[str, str] | None = None) -> dict[str, str]:
    tu.ensure_loaded()
    res = subprocess.run([*tu.TSHARK_CMD, "-G", "fields", "-X", f"lua_script:{tu.DISSECTOR}"], capture_output=True,
                         text=True, env=env or tu._clean_env(), timeout=120)
    tu.check_stderr(res.stderr)
    return {c[2]: c[3] for c in (line.split("\t") for line in res.stdout.splitlines())
            if len(c) > 3 and c[0] == "F" and c[2].startswith("sharedlink.value.")}


def test_kairos_names_registered_with_their_types() -> None:
    types = _field_types()
    for name in ("AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel", "vehicle_bat", "joy_steer"):
        assert types[f"sharedlink.value.{name}"] == "FT_DOUBLE", name
    assert types["sharedlink.value.veh_gear"] == "FT_INT64"
    assert types["sharedlink.value.VehicleName"] == "FT_STRING"
    # BUL-110's declaration gives it no T of its own: the T0 before it (BUL-009, issue 40)
    assert types["sharedlink.value.svp_enb_eng"] == "FT_INT64"


def test_a_name_saved_in_the_preferences_gets_a_field(tmp_path: Path) -> None:
    conf = tmp_path / "conf"
    (conf / "wireshark").mkdir(parents=True)
    (conf / "wireshark" / "preferences").write_text(
        "# saved by Wireshark\nsharedlink.variables: B>A: Odo:0,AutoGpsVel:4; Mileage\n", encoding="utf-8")
    env = dict(os.environ, WIRESHARKCONFIGDIR=str(conf / "wireshark"), XDG_CONFIG_HOME=str(conf), HOME=str(conf),
               LC_ALL="C.UTF-8")
    types = _field_types(env)
    assert types["sharedlink.value.Odo"] == "FT_INT64"
    assert types["sharedlink.value.Mileage"] == "FT_DOUBLE"
    assert types["sharedlink.value.AutoGpsVel"] == "FT_STRING"   # the preference's type wins
    assert "sharedlink.value.Odo" not in _field_types()


@pytest.mark.parametrize("text", ["Lat:7", "B>Q: Lat", "Lat:2,Lo|n", "B>A: ", "Lat:x"])
def test_a_bad_variables_preference_is_reported_as_python_reports_it(text: str) -> None:
    with pytest.raises(VarListError) as ei:
        parse_varlists(text)
    res = tu.tshark(BEACON, ["-c", "2"], prefs={"sharedlink.variables": text})
    assert f"the variables preference is not used: {ei.value}" in res.stderr
    # no list at all: the beacon's 4-slot frames are #i, untyped (named frames keep their names)
    assert "sharedlink" in res.stdout.lower()
