"""The referenced-field cache across dissections whose filters change (issues 27 and 40,
docs/architecture.md, "The referenced-field cache"), seen through sharkd, which dissects frames on
request with the custom columns each request names, as the GUI's packet list does with its columns
and coloring rules.

In a tree nobody sees, Wireshark adds only the fields somebody references; the dissector asks which
(wsapi.referenced: TreeItem:referenced) and keeps the answers for the dissection, and over a first
pass outside the GUI only (tshark's, where every dissection is primed alike).  sharkd's requests
dissect visited frames, so each asks again: a field referenced before or never, from the very next
frame on or after a shown tree, is seen.  The second and third tests fail when the answers are kept
from one request's dissections to the next, the first when a field found referenced is not asked
again: the custom column of ``sharedlink.value.AutoGpsLat`` comes back empty.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu

SHARKD = shutil.which("sharkd")
pytestmark = pytest.mark.skipif(SHARKD is None or tu.TSHARK_CMD != [tu.TSHARK],
                                reason="sharkd of this machine's Wireshark needed")

VALUE = "sharedlink.value.AutoGpsLat:0"   # a custom column: field:occurrence
NUMBER = "frame.number:0"


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """A HOME with the dissector installed in its personal plugin folder (as make install)."""
    root = tmp_path_factory.mktemp("sharkd-home")
    env = dict(os.environ, HOME=str(root), XDG_CONFIG_HOME=str(root / ".config"), LC_ALL="C.UTF-8")
    for name in ("WIRESHARKCONFIGDIR", "WIRESHARK_CONFIG_DIR"):
        env.pop(name, None)
    folders = subprocess.run([tu.TSHARK, "-G", "folders"], capture_output=True, text=True, env=env,
                             check=True).stdout
    m = re.search(r"^Personal Lua Plugins:\s*(.+)$", folders, re.M) or re.search(
        r"^Personal Plugins:\s*(.+)$", folders, re.M)
    assert m, folders
    plugins = Path(m.group(1).strip())
    plugins.mkdir(parents=True)
    shutil.copy(tu.DISSECTOR, plugins / "sharedlink.lua")
    shutil.copytree(tu.DISSECTOR.parent / "sharedlink", plugins / "sharedlink")
    conf = re.search(r"^Personal configuration:\s*(.+)$", folders, re.M)
    assert conf, folders
    Path(conf.group(1).strip()).mkdir(parents=True, exist_ok=True)
    shutil.copy(tu.DISSECTOR.parent / "sharedlink.colorfilters", Path(conf.group(1).strip()) / "colorfilters")
    return env


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sharedlink.generators.beacon import GenOptions, generate_file

    path = tmp_path_factory.mktemp("sharkd-cap") / "beacon.pcap"
    generate_file(GenOptions(frames=40), path)
    return path


@pytest.fixture(scope="module")
def faults(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from sharedlink.generators.beacon import GenOptions, generate_file

    path = tmp_path_factory.mktemp("sharkd-faults") / "faults.pcap"
    generate_file(GenOptions(frames=300, compress=True, bad_checksum=0.05, drop=0.2, seed=2), path)
    return path


def sharkd_session(env: dict[str, str], capture: Path, requests: list[tuple[str, dict]]) -> list:
    """Run sharkd on capture, send the requests (method, params) in order; their results."""
    lines = [{"jsonrpc": "2.0", "id": 1, "method": "load", "params": {"file": str(capture)}}]
    lines += [{"jsonrpc": "2.0", "id": i + 2, "method": m, "params": p} for i, (m, p) in enumerate(requests)]
    proc = subprocess.run([SHARKD, "-"], input="".join(json.dumps(x) + "\n" for x in lines), env=env,
                          capture_output=True, text=True, timeout=120)
    tu.check_stderr(proc.stderr)
    replies = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert [r.get("id") for r in replies] == list(range(1, len(lines) + 1)), proc.stdout[:2000]
    assert replies[0]["result"]["status"] == "OK", replies[0]
    for r in replies:
        assert "error" not in r, r
        assert "_ws.lua.error" not in json.dumps(r) and "Lua Error" not in json.dumps(r), r
    return [r["result"] for r in replies[1:]]


def frames(skip: int, *columns: str) -> tuple[str, dict]:
    params: dict = {"limit": 3, **{f"column{i}": c for i, c in enumerate(columns)}}
    if skip:
        params["skip"] = skip
    return "frames", params


def column(result: list, k: int) -> list[str]:
    return [row["c"][k] for row in result]


def test_a_field_found_referenced_before_is_learnt_again(home: dict[str, str], capture: Path) -> None:
    # frames 1-3 reference the value (found referenced); 11-13 do not (learnt unreferenced: a new
    # run, not the next frame); 14-16, the next frames, reference it again
    out = sharkd_session(home, capture, [frames(0, VALUE, NUMBER), frames(10, NUMBER), frames(13, VALUE, NUMBER)])
    assert column(out[0], 1) == ["1", "2", "3"] and column(out[2], 1) == ["14", "15", "16"]
    assert all(re.fullmatch(r"-?\d+\.\d+", v) for v in column(out[0], 0)), out[0]
    assert all(re.fullmatch(r"-?\d+\.\d+", v) for v in column(out[2], 0)), out[2]


def test_a_shown_tree_ends_the_run(home: dict[str, str], capture: Path) -> None:
    # frames 1-3 with nobody referencing the value; frame 3's details (a shown tree, as selecting a
    # packet before Find Packet); then 4-6, the next frames, with the value as a column
    out = sharkd_session(home, capture, [frames(0, NUMBER), ("frame", {"frame": 3, "proto": True}),
                                         frames(3, VALUE, NUMBER)])
    assert "sharedlink" in json.dumps(out[1])
    assert column(out[2], 1) == ["4", "5", "6"]
    assert all(re.fullmatch(r"-?\d+\.\d+", v) for v in column(out[2], 0)), out[2]


def test_a_field_never_referenced_before_from_the_next_frame_on(home: dict[str, str], capture: Path) -> None:
    out = sharkd_session(home, capture, [frames(0, NUMBER), frames(3, VALUE, NUMBER)])
    assert all(re.fullmatch(r"-?\d+\.\d+", v) for v in column(out[1], 0)), out[1]


def test_the_coloring_rules_colour_every_bad_checksum_over_a_run(home: dict[str, str], faults: Path) -> None:
    # the packet list's way: every row in frame order, primed with the coloring rules (the run keeps
    # what the probe learnt); the rows sharkd colours as "SharedLink bad checksum" (background
    # 4718,10030,11796 = #12272e) are the frames tshark's -Y on the same field matches
    bad = {int(r["frame.number"][0]) for r in tu.fields(faults, ["frame.number"], two_pass=False,
                                                       display_filter="sharedlink.checksum.status == 0")}
    assert bad, "no bad checksum in the capture: the test tests nothing"
    out = sharkd_session(home, faults, [("frames", {"column0": NUMBER})])
    coloured = {int(row["c"][0]) for row in out[0] if row.get("bg") == "12272e"}
    assert coloured == bad
