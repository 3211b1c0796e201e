"""The SharedLink profile's I/O graphs (``io_graphs``, issue 43), written by
``sharedlink plugins install --profile`` in the columns of the tshark's Wireshark release.

Wireshark reads that file only in its GUI's I/O Graphs window (tshark ignores it: the first test
shows it with a broken one), and a record with more columns than the release knows is an error
there. So the file is checked three ways, each for the release under test (``make test-matrix``
runs this file on 4.0, 4.4 and 4.6):

* against the release's column list and accepted values (``io_graphs_columns.json``, read from
  Wireshark's source and binaries) by a reader that keeps the rules of its UAT loader
  (``epan/uat_load.l``): quoted fields with ``\\xNN`` escapes, commas, more fields than columns
  an error, fewer taking the release's defaults;
* by that release's tshark: each graph's display filter and Y field as ``-z io,stat`` graphs
  over a capture with an outage in each direction (frames a second per direction equal to
  ``sharedlink health``'s, each outage's duration at the second of the frame that ends it);
* ``tshark -C SharedLink`` starts with the profile (its other files) without an error.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink import plugins
from tshark_util import TSHARK_CMD, TSHARK_VERSION, check_stderr, env_for, tshark

COLUMNS = json.loads((Path(__file__).parent / "io_graphs_columns.json").read_text())
RELEASES = {tuple(map(int, k.split("."))): v for k, v in COLUMNS["releases"].items()}

#: a field of a UAT record, as uat_load.l's lexer takes it (quoted, hex bytes, or empty)
_FIELD = re.compile(r'[ \t]*(?:"((?:[^"\\]|\\.)*)"|([0-9a-zA-Z][0-9a-zA-Z])*)[ \t]*')


class UatError(ValueError):
    pass


def _unquote(s: str) -> str:
    """uat_undquote: \\xNN and \\C escapes."""
    return re.sub(r"\\x([0-9a-fA-F]{2})|\\(.)", lambda m: chr(int(m.group(1), 16)) if m.group(1) else m.group(2), s)


def _fields(line: str) -> list[str]:
    out, pos = [], 0
    while True:
        m = _FIELD.match(line, pos)
        if m is None:
            raise UatError(f"unexpected input at {line[pos:]!r}")
        out.append(_unquote(m.group(1)) if m.group(1) is not None else bytes.fromhex(m.group(0).strip()).decode())
        pos = m.end()
        if pos == len(line):
            return out
        if line[pos] != ",":
            raise UatError(f"unexpected char {line[pos]!r} after field {len(out)}")
        pos += 1


def _check(rel: dict, kind: str, value: str) -> None:
    if kind == "bool_enable":
        ok = value in rel["bool_enable"]["exact"] or value.lower() in rel["bool_enable"]["any_case"]
    elif kind == "color":
        ok = re.fullmatch(r"#[0-9a-fA-F]{6}", value) is not None
    elif kind.startswith("vs:"):
        ok = value in rel["vs"][kind[3:]]
    elif kind == "sma_period":
        ok = value in COLUMNS["sma_period"] or f"{value} interval SMA" in COLUMNS["sma_period"] or value == "0"
    elif kind == "dec":
        ok = re.fullmatch(r"-?[0-9]+", value) is not None
    elif kind == "dbl":
        ok = re.fullmatch(r"-?[0-9]+(\.[0-9]*)?([eE][-+]?[0-9]+)?", value) is not None
    else:  # cstring, display_filter, proto_field: any text here (the filters go to tshark below)
        ok = True
    if not ok:
        raise UatError(f"invalid value {value!r} for a {kind} column")


def load_uat(text: str, release: tuple[int, int]) -> list[dict[str, str]]:
    """The records of an ``io_graphs`` text as ``release`` loads them, or UatError."""
    rel = RELEASES[release]
    cols = rel["columns"]
    records = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        values = _fields(line)
        if len(values) > len(cols):
            raise UatError(f"line {n}: more fields than required")
        for (name, _), default in list(zip(cols, rel["defaults"]))[len(values):]:
            if default is None:
                raise UatError(f"line {n}: expecting field {name}")
            values.append(default)
        for (_, kind), value in zip(cols, values):
            _check(rel, kind, value)
        records.append({name: v for (name, _), v in zip(cols, values)})
    return records


def release_of(version: tuple[int, int]) -> tuple[int, int]:
    """The fixture's release whose columns ``version`` has (the latest at or before it)."""
    return max(r for r in RELEASES if r <= version)


def test_tshark_ignores_io_graphs(tmp_path, tiny_capture):
    """A broken io_graphs in the profile: tshark starts, reads and says nothing (it does not read
    the file): only the columns above can tell a wrong one."""
    home = tmp_path / "home"
    prof = home / ".config" / "wireshark" / "profiles" / "SharedLink"
    prof.mkdir(parents=True)
    (prof / "io_graphs").write_text('"Enabled","x","","#000000","Line","Packets","","None","1","Disabled","more"\n'
                                    "not a record\n")
    r = subprocess.run([*TSHARK_CMD, "-n", "-C", "SharedLink", "-r", str(tiny_capture), "-c", "1"],
                       capture_output=True, text=True, env=env_for(home), timeout=120)
    assert r.returncode == 0 and r.stdout.strip(), r.stderr
    check_stderr(r.stderr)
    assert "io_graphs" not in r.stderr and "more fields" not in r.stderr


@pytest.mark.parametrize("release", sorted(RELEASES))
def test_io_graphs_each_release(release):
    """The file for each release loads there, with the four graphs; the 4.6 file would be an
    error on 4.0/4.4 (the reason the version is read at install); 4.6 reads the older one."""
    text = plugins.io_graphs_text(release)
    recs = load_uat(text, release)
    assert [r["name"] for r in recs] == ["SharedLink frames", "B>A frames", "A>B frames", "Outage (s)"]
    assert all(r["enabled"] == "Enabled" for r in recs)
    assert recs[3]["yaxis"] == "MAX(Y Field)" and recs[3]["yfield"] == "sharedlink.outage.duration"
    assert recs[1]["dfilter"] == 'sharedlink.src == "B" && sharedlink.dst == "A"'
    if release >= plugins.IO_GRAPHS_AOT:
        assert all(r["asAOT"] == "Disabled" for r in recs)
        for older in (r for r in RELEASES if r < plugins.IO_GRAPHS_AOT):
            with pytest.raises(UatError, match="more fields than required"):
                load_uat(text, older)
        assert load_uat(plugins.io_graphs_text((4, 4)), release)[0]["asAOT"] == "false"  # the default
    assert plugins.io_graphs_text(None) == plugins.io_graphs_text((4, 0))  # unknown: the nine columns


@pytest.fixture
def tiny_capture(tmp_path):
    cap = tmp_path / "tiny.pcap"
    run_cli("gen", "-o", cap, "--frames", "3", "-q", text=False, check=True, timeout=120)
    return cap


def _two_way_capture(tmp_path: Path) -> Path:
    """B>A at 5 Hz with a 3 s outage and A>B at 7 Hz with a 2.5 s one, in one capture."""
    ba, ab, both = tmp_path / "ba.pcap", tmp_path / "ab.pcap", tmp_path / "both.pcap"
    gen = [sys.executable, "-m", "sharedlink", "gen", "--duration", "12", "-q"]
    subprocess.run([*gen, "-o", ba, "--outage", "5:3"], check=True, timeout=120)
    subprocess.run([*gen, "-o", ab, "--src", "A", "--dst", "B", "--rate", "7", "--outage", "2:2.5", "--seed", "3"],
                   check=True, timeout=120)
    subprocess.run(["mergecap", "-F", "pcap", "-w", both, ba, ab], check=True, timeout=120)
    return both


def _io_stat(capture: Path, recs: list[dict[str, str]]) -> dict[int, list[float]]:
    """The release's ``-z io,stat,1`` of the graphs (a Packets graph: its frames; MAX(Y Field):
    the maximum, 0 in an interval where the graph's filter matched no frame), per interval start
    second. The MAX graph comes last, then its filter again as a Packets graph: tshark 4.0 prints a
    MAX of an interval without a matching frame from memory it never set (garbage on the first
    interval, the last interval's maximum on later ones), so it is read only where frames matched."""
    assert [r["yaxis"] for r in recs][-1] != "Packets" and all(r["yaxis"] == "Packets" for r in recs[:-1])
    specs = [r["dfilter"] if r["yaxis"] == "Packets" else f"MAX({r['yfield']}){r['dfilter']}" for r in recs]
    specs.append(recs[-1]["dfilter"])
    assert not any("," in s for s in specs)
    out = tshark(capture, ["-q", "-z", "io,stat,1," + ",".join(specs)]).stdout
    rows: dict[int, list[float]] = {}
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if "<>" not in cells[0]:
            continue
        nums = [float(c) for c in cells[1:] if c]
        packets = [nums[2 * i] for i in range(len(recs) - 1)]
        bar, matched = nums[-3], nums[-2]
        rows[int(cells[0].split("<>")[0])] = [*packets, bar if matched else 0.0]
    return rows


def test_io_graphs_on_this_tshark(tmp_path):
    """The file ``install --profile`` writes for this tshark's release, loaded by the columns of
    that release; its graphs computed by that tshark agree with ``sharedlink health`` and
    ``stats``; and tshark starts with the installed profile."""
    home = tmp_path / "home"
    f = plugins.Folders(home / "plugins", home / "extcap", home / ".config" / "wireshark")
    plugins.install_profile(f, TSHARK_VERSION)
    text = (plugins.profile_dir(f) / "io_graphs").read_text()
    assert text == plugins.io_graphs_text(TSHARK_VERSION)
    recs = load_uat(text, release_of(TSHARK_VERSION))
    assert len(recs) == 4

    cap = _two_way_capture(tmp_path)
    rows = _io_stat(cap, recs)
    csv = tmp_path / "q.csv"
    run_cli("health", cap, "-o", csv, "-q", text=False, check=True, timeout=120)
    lines = [ln.split(",") for ln in csv.read_text().splitlines()[1:]]
    t0 = min(int(c[2]) for c in lines)
    want: dict[str, dict[int, int]] = {"B>A": {}, "A>B": {}}
    for c in lines:
        want[c[1]][int(c[2]) - t0] = int(c[4])
    for sec, (all_, ba, ab, _) in rows.items():
        assert ba == want["B>A"].get(sec, 0) and ab == want["A>B"].get(sec, 0), (sec, rows[sec], want)
        assert all_ == ba + ab
    stats = json.loads(run_cli("stats", "--json", cap, check=True, timeout=120).stdout)
    assert len(stats["outages"]) == 2
    for o in stats["outages"]:
        sec = int(o["end"]) - t0
        assert rows[sec][3] == pytest.approx(o["duration_s"], abs=1e-6), (o, rows[sec])
    first = min(int(o["end"]) - t0 for o in stats["outages"])
    assert all(rows[s][3] == 0 for s in rows if s < first)  # no bar before the first outage ends

    r = subprocess.run([*TSHARK_CMD, "-n", "-C", "SharedLink", "-X", f"lua_script:{plugins.dissector_dir() / 'sharedlink.lua'}",
                        "-r", str(cap), "-Y", "sharedlink.outage"], capture_output=True, text=True, env=env_for(home),
                       timeout=120)
    assert r.returncode == 0, r.stderr
    check_stderr(r.stderr)
    assert len(r.stdout.splitlines()) == 2
