"""Carried values read back from the first pass's packed record lines (state.lua, records.lua).

A compressed stream's delta keeps its record as a text line; the line of a delta of a known
subset is made once and kept while none of the values it carries changes (records.subset_line),
and a frame with no value at all carries every name the same way.  These tests check the values
and frames each delta shows against a model written here (the direction's last good value of
each name and its frame), with one pass and with two (the second reads the lines back), and that
a packet whose lines straddle two packed chunks is found on the second pass.
"""

from __future__ import annotations

import re
from pathlib import Path

from tshark_util import Pkt, fields, frame, tshark, write_pcap

VAR_LINE = re.compile(r"^    \[?(\w+) = (\S+?)(?: \(carried from frame (\d+)\))?\]?$")


def named(**values: int) -> bytes:
    """A named data frame B -> A, N0, one T/Q/D triplet a value (none: a frame with no value)."""
    return frame("A", "B", "N0", *[x for k, v in values.items() for x in ("T2", "Q" + k, "D" + str(v))])


def model(packets: list[tuple[float, str, dict[str, int]]]) -> dict[int, list[tuple[str, str, int | None]]]:
    """Frame number -> (name, value, frame it came from: None when sent) in the order shown: the
    values sent, then the direction's other names in the order first sent (each source address is
    a direction of its own)."""
    state: dict[str, dict[str, tuple[str, int]]] = {}
    out = {}
    for num, (_, src, values) in enumerate(packets, 1):
        known = state.setdefault(src, {})
        shown: list[tuple[str, str, int | None]] = [(k, str(v), None) for k, v in values.items()]
        shown += [(k, v, fr) for k, (v, fr) in known.items() if k not in values]
        for k, v in values.items():
            known[k] = (str(v), num)   # (a name keeps its place: the order first sent)
        out[num] = shown
    return out


def shown_vars(pcap: Path, two_pass: bool) -> dict[int, list[tuple[str, str, int | None]]]:
    out: dict[int, list[tuple[str, str, int | None]]] = {}
    num = 0
    for line in tshark(pcap, ["-V", "-O", "sharedlink"], two_pass=two_pass).stdout.splitlines():
        if line.startswith("Frame "):
            num = int(line.split()[1].rstrip(":"))
            out[num] = []
            continue
        m = VAR_LINE.match(line)
        if m:
            out[num].append((m.group(1), m.group(2), int(m.group(3)) if m.group(3) else None))
    return out


def test_kept_delta_lines_follow_every_change(tmp_path):
    """Deltas of one layout in a row (its line kept), another layout's delta changing a value the
    first carries, frames with no value, a full frame, a late delta (a table record), and a
    second sender with the same ports and letters in between: every carried value and its frame
    as the model has them, in one pass and read back in a second."""
    seq = [{"a": 1, "b": 1, "c": 1}, {"a": 2}, {"a": 3}, {"b": 4}, {"a": 5}, {"a": 6}, {}, {}, {"c": 8},
           {}, {"a": 10}, {"a": 11, "b": 11, "c": 11}, {"a": 12}, {"a": 13}, {}, {"b": 15}, {"a": 16}]
    packets: list[tuple[float, str, dict[str, int]]] = []
    t = 0.0
    for i, values in enumerate(seq):
        t += 3.0 if i == 13 else 0.1   # frame 27's gap: a late sync
        packets.append((t, "10.0.0.2", values))
        packets.append((t + 0.01, "10.0.0.3", {k: v + 100 for k, v in values.items()}))
    pcap = write_pcap(tmp_path / "kept.pcap", [Pkt(ts, named(**vals), src=src) for ts, src, vals in packets])
    want = model(packets)
    assert "Sync late: True" in tshark(pcap, ["-V", "-O", "sharedlink"]).stdout
    assert shown_vars(pcap, two_pass=False) == want
    assert shown_vars(pcap, two_pass=True) == want


def test_a_packet_whose_lines_straddle_two_chunks(tmp_path):
    """Packets of three frames that carry values: their record lines are packed in chunks, and a
    packet's lines can begin in one chunk and end in the next; the second pass finds them all
    (on 42785e0 frames past the first chunk showed no carried value on the second pass)."""
    pk = []
    for i in range(400):
        if i % 50 == 0:
            pk.append(Pkt(i * 0.02, frame("A", "B", "N0", f"D{i}", f"D{i + 1}", f"D{i + 2}", f"D{i + 3}")))
        else:
            pk.append(Pkt(i * 0.02, frame("A", "B", "N0", f"D{i}", "D", "D", f"D{i + 3}") +
                          frame("B", "A", "N0", "D", f"D{i}") + frame("C", "A", "N0", "D", f"D{i}")))
    pcap = write_pcap(tmp_path / "straddle.pcap", pk)
    names = ["sharedlink.var.value", "sharedlink.var.carried_from"]
    one_pass = fields(pcap, names, two_pass=False)
    assert sum(len(r["sharedlink.var.carried_from"]) for r in one_pass) > 700
    assert one_pass == fields(pcap, names, two_pass=True)
