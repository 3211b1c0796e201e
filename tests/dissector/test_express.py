"""The express lane of sharedlink.lua stands in for the phases of dissect_frame.

In any pass (no tree: tshark's summary pass; a tree nobody sees: -Y, coloring rules; a shown
tree: -V, -T pdml, the GUI's details), a packet that is one plain named frame of a layout seen
before is decoded by one function (`express`).  It must
leave exactly what the phases would: the same Info, tree, state and records, which the
frames after it and a second pass (-2, -2 -V) read.  SHAREDLINK_NO_EXPRESS=1 turns the lane off;
SHAREDLINK_EXPRESS_MARK=1 marks the Info of the packets it took, to show that it ran at all.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from sl_captures import write_capture
from sl_vectors import load_streams, stream_ids, write_stream

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
OTHERS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
          for a in ("-X", f"lua_script:{s}")]
MARK = "[express] "

# beacon streams the lane is for, and the ways out of it: bad checksums, dropped frames, late
# sync (full frames every 3 s), positional values, serial records, TCP segments
GEN = {
    "full": ["--frames", "120"],
    "compressed": ["--frames", "200", "--compress"],
    "compressed-faults": ["--frames", "300", "--compress", "--bad-checksum", "0.1", "--drop", "0.1"],
    "late-sync": ["--frames", "150", "--compress", "--sync-interval", "3"],
    "positional": ["--frames", "100", "--compress", "--form", "positional"],
    "serial": ["--frames", "80", "--compress", "--transport", "serial", "--noise", "0.05"],
    "other-pair": ["--frames", "60", "--compress", "--src", "C", "--dst", "D"],
}
STREAMS = load_streams()
# filters on fields of the frame, of its variables and of its carried variables
FILTERS = ['sharedlink.kind == "delta" && sharedlink.checksum.status == 1',
           "sharedlink.crlf.missing || sharedlink.sync.is_late",
           "sharedlink.var.double > 40 && sharedlink.var.index == 1",
           'sharedlink.var.carried_from > 1 && sharedlink.var.name == "AutoGpsHead"',
           "count(sharedlink.var) == 4 && sharedlink.checksum.calculated > 0"]


def _outputs(cap: Path, monkeypatch: pytest.MonkeyPatch, *, express: bool, mark: bool = False) -> dict[str, str]:
    with monkeypatch.context() as m:
        if not express:
            m.setenv("SHAREDLINK_NO_EXPRESS", "1")
        if mark:
            m.setenv("SHAREDLINK_EXPRESS_MARK", "1")
        return {
            "one pass": tu.tshark(cap, [*OTHERS], two_pass=False).stdout,
            "two passes": tu.tshark(cap, [*OTHERS], two_pass=True).stdout,
            "two passes, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout,
            # a shown tree, every item's place and size (hidden ones too)
            "one pass, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=False).stdout,
            "pdml": "\n".join(x for x in tu.tshark(cap, ["-T", "pdml", *OTHERS], two_pass=False).stdout.splitlines()
                              if not x.startswith("<pdml ")),   # its line holds the time it ran
            # a tree nobody sees: the lane makes its compact form
            **{f"filter {f}": tu.tshark(cap, ["-Y", f, *OTHERS], two_pass=False).stdout for f in FILTERS},
            "two passes, filter": tu.tshark(cap, ["-Y", FILTERS[0], *OTHERS], two_pass=True).stdout,
        }


def _same_both_ways(cap: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    on, off = _outputs(cap, monkeypatch, express=True), _outputs(cap, monkeypatch, express=False)
    for how in on:
        assert on[how] == off[how], how
    assert on["one pass"] and on["two passes, tree"]


@pytest.mark.parametrize("name", sorted(GEN))
def test_express_leaves_what_the_phases_leave(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cap = tmp_path / f"{name}.pcap"
    subprocess.run([sys.executable, "-m", "sharedlink", "gen", "--seed", "7", *GEN[name], str(cap)],
                   check=True, capture_output=True)
    _same_both_ways(cap, monkeypatch)


@pytest.mark.parametrize("stream", STREAMS, ids=stream_ids(STREAMS))
def test_express_on_the_vector_streams(stream: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _same_both_ways(write_stream(stream, tmp_path / "s.pcap"), monkeypatch)


def test_express_on_every_line_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The lane's pattern lets CR LF, CR, LF or nothing follow the frame (the CR LF expert and the
    frame's length in the hidden tree must come out as the phases make them)."""

    def frame(body: str, end: str) -> bytes:
        return f"[{body}{sum(body.encode()) % 256:02X}]{end}".encode()

    ends = ["\n", "\r", "\r\n", "", "\n", "\r"] * 4
    bodies = [":AB|N0|T2|QLat|D1.5|T2|QLon|D2.5|C" if i % 3 == 0 else ":AB|N0|T2|QLat|D1.6|C" for i in range(len(ends))]
    t0 = 1_767_268_800_000_000_000
    cap = write_capture(tmp_path / "ends.pcap", [(t0 + i * 200_000_000, frame(b, e))
                                                  for i, (b, e) in enumerate(zip(bodies, ends))])
    _same_both_ways(cap, monkeypatch)
    monkeypatch.setenv("SHAREDLINK_EXPRESS_MARK", "1")
    marked = tu.tshark(cap, ["-Y", "sharedlink.crlf.missing", *OTHERS]).stdout.count(MARK)
    assert marked > 10


def test_express_takes_the_bulk_of_a_beacon_stream(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Full frames and compressed deltas (bare ones too) take the lane in both passes; the
    frames it leaves (the first of each layout, bad checksums, late sync) go the long way."""
    cap = tmp_path / "c.pcap"
    subprocess.run([sys.executable, "-m", "sharedlink", "gen", "--frames", "300", "--compress",
                    "--bad-checksum", "0.05", str(cap)], check=True, capture_output=True)
    out = _outputs(cap, monkeypatch, express=True, mark=True)
    for how in ("one pass", "two passes"):
        lines = out[how].splitlines()
        marked = [x for x in lines if MARK in x]
        assert len(lines) == 300 and len(marked) > 240, (how, len(marked))
        assert any(" full " in x for x in marked) and any("delta (+4 carried)" in x for x in marked)
        assert any("delta AutoGpsLat" in x for x in marked)
    assert all(MARK not in x for x in out["one pass"].splitlines() if "[sync late]" in x)


def test_records_of_a_long_compressed_stream(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second pass reads the carried values the first pass kept for each delta, packed 256
    records to a chunk in one ByteArray: a stream long enough for several chunks, read by the
    second pass in order, shows the same carried values with the lane as without it."""
    cap = tmp_path / "long.pcap"
    subprocess.run([sys.executable, "-m", "sharedlink", "gen", "--seed", "11", "--frames", "1400", "--compress",
                    str(cap)], check=True, capture_output=True)
    outs = []
    for express in (True, False):
        with monkeypatch.context() as m:
            if not express:
                m.setenv("SHAREDLINK_NO_EXPRESS", "1")
            outs.append(tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout)
    assert outs[0] == outs[1]
    # most of the 1400 frames are deltas: well over 256 records, each showing its carried values
    carried = [x for x in outs[0].splitlines() if "(carried from frame " in x]
    assert len(carried) > 1000, len(carried)
    last_frame = max(int(x.rsplit("(carried from frame ", 1)[1].split(")")[0]) for x in carried)
    assert last_frame > 1200


def test_express_on_every_kind_of_value(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The lane's value pattern is a set of byte ranges (any byte but '|', '[', ']', the control
    characters and DEL) and its checksum sums the values as one string: values long and short,
    UTF-8, punctuation, and the bytes it must leave to the phases ('[', ']', control characters,
    DEL) come out as the phases make them; the long and the UTF-8 ones take the lane."""
    long_text = "x" * 50
    values = ["1.5", long_text, "Ωμέγα", "%^{}~\\`'\"", "a[b", "a]b", "tab\there", "del\x7f", "", "-0.25",
              "y" * 30]
    bodies = []
    for i in range(60):
        v = values[i % len(values)]
        w = values[(i * 7 + 3) % len(values)]
        bodies.append(f":AB|N0|T4|QName|D{v}|T4|QNote|D{w}|T2|QLat|D{i}.5|C")
    t0 = 1_767_268_800_000_000_000
    frames = []
    for i, body in enumerate(bodies):
        raw = body.encode()
        frames.append((t0 + i * 200_000_000, b"[" + raw + f"{sum(raw) % 256:02X}]\r\n".encode()))
    cap = write_capture(tmp_path / "values.pcap", frames)
    _same_both_ways(cap, monkeypatch)
    monkeypatch.setenv("SHAREDLINK_EXPRESS_MARK", "1")
    lines = tu.tshark(cap, [*OTHERS]).stdout.splitlines()
    marked = [x for x in lines if MARK in x]
    assert any(long_text in x for x in marked) and any("Ωμέγα" in x for x in marked)
    assert not any("a[b" in x or "tab" in x for x in marked)


# The phases' own fast paths (parse_frame: a frame of a layout its node pair sent before, parsed by
# one pattern) serve a shown tree too, where the fields' places follow from the layout and the
# values' lengths (fast_positions, which the express lane uses as well).  With the express lane
# off (it takes most of these frames first), SHAREDLINK_NO_FAST=1 parses every frame field by
# field: the trees, ranges and all, must come out the same.
def _shown_trees(cap: Path, monkeypatch: pytest.MonkeyPatch, *, fast: bool) -> dict[str, str]:
    with monkeypatch.context() as m:
        m.setenv("SHAREDLINK_NO_EXPRESS", "1")
        if not fast:
            m.setenv("SHAREDLINK_NO_FAST", "1")
        return {
            "one pass, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=False).stdout,
            "two passes, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout,
            # byte ranges of every item, hidden ones too
            "pdml": "\n".join(x for x in tu.tshark(cap, ["-T", "pdml", *OTHERS], two_pass=False).stdout.splitlines()
                              if not x.startswith("<pdml ")),   # its line holds the time it ran
            "filter, tree": tu.tshark(cap, ["-V", "-Y", FILTERS[2], *OTHERS], two_pass=False).stdout,
        }


@pytest.mark.parametrize("name", ["full", "compressed-faults", "positional", "serial", "other-pair"])
def test_fast_paths_in_a_shown_tree(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cap = tmp_path / f"{name}.pcap"
    subprocess.run([sys.executable, "-m", "sharedlink", "gen", "--seed", "5", *GEN[name], str(cap)],
                   check=True, capture_output=True)
    on, off = _shown_trees(cap, monkeypatch, fast=True), _shown_trees(cap, monkeypatch, fast=False)
    for how in on:
        assert on[how] == off[how], how
    # and they ran: dozens of the packets of a shown tree took them
    monkeypatch.setenv("SHAREDLINK_NO_EXPRESS", "1")
    monkeypatch.setenv("SHAREDLINK_FAST_MARK", "1")
    lines = tu.tshark(cap, ["-V", "-P", *OTHERS]).stdout.splitlines()
    assert sum(" SharedLink " in x and "[fast] " in x for x in lines) >= 20, name


def test_fast_paths_on_every_kind_of_value(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Values of every length and byte class, in named and positional layouts: the places the
    fast paths give each field are those parsing field by field finds."""
    values = ["1.5", "x" * 50, "Ωμέγα", "%^{}~\\`'\"", "", "-0.25", "7", "a[b"]
    bodies = []
    for i in range(40):
        v, w = values[i % len(values)], values[(i * 3 + 1) % len(values)]
        bodies.append(f":AB|N0|T4|QName|D{v}|T4|QNote|D{w}|T2|QLat|D{i}.5|C" if i % 2 else f":CD|N0|D{v}|D{w}|D{i}|C")
    t0 = 1_767_268_800_000_000_000
    frames = [(t0 + i * 200_000_000, b"[" + b.encode() + f"{sum(b.encode()) % 256:02X}]\r\n".encode())
              for i, b in enumerate(bodies)]
    cap = write_capture(tmp_path / "values.pcap", frames)
    on, off = _shown_trees(cap, monkeypatch, fast=True), _shown_trees(cap, monkeypatch, fast=False)
    for how in on:
        assert on[how] == off[how], how
    monkeypatch.setenv("SHAREDLINK_NO_EXPRESS", "1")
    monkeypatch.setenv("SHAREDLINK_FAST_MARK", "1")
    out = tu.tshark(cap, ["-V", "-P", *OTHERS]).stdout
    assert out.count("[fast] ") > 20


def test_express_takes_a_shown_tree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """-V (one pass and the second of -2) and the GUI's details go the express lane too: most
    packets of a beacon stream, full frames and deltas, carried values shown in the tree."""
    cap = tmp_path / "c.pcap"
    subprocess.run([sys.executable, "-m", "sharedlink", "gen", "--frames", "300", "--compress", str(cap)],
                   check=True, capture_output=True)
    monkeypatch.setenv("SHAREDLINK_EXPRESS_MARK", "1")
    for two_pass in (False, True):
        out = tu.tshark(cap, ["-V", "-P", *OTHERS], two_pass=two_pass).stdout
        marked = [x for x in out.splitlines() if MARK in x]
        assert len(marked) > 240, (two_pass, len(marked))
        assert any(" full " in x for x in marked) and any("delta (+4 carried)" in x for x in marked)
        assert "(carried from frame " in out
