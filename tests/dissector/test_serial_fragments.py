"""serial.lua's fragment subtree when a record's first bytes complete one frame and its last
bytes start the next: that record's share of the next frame is its last bytes, from the
reassembled frame's start (it was shown with its whole length at a negative offset,
"#1(23)" and "payload: -17-5"). Besides: the shares are kept as the subtree's text (issue 44:
about 8 bytes a record where a table of numbers took about 110)."""

from __future__ import annotations

import re
from pathlib import Path

from sl_robots import write_serial

import tshark_util as tu
from sharedlink.capture.serial_format import DIR_IN

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = [a for s in ("serial.lua", "sharedlink.lua") for a in ("-X", f"lua_script:{REPO / 'dissector' / s}")]


def test_a_record_that_ends_one_frame_and_starts_the_next(tmp_path: Path) -> None:
    f1, f2 = tu.frame("A", "B", "N0", "D1"), tu.frame("A", "B", "N0", "D2")
    cap = write_serial(tmp_path / "frag.pcapng", [(f1 + f2[:6], DIR_IN), (f2[6:10], DIR_IN), (f2[10:], DIR_IN)],
                       times=[10**18, 10**18 + 1000, 10**18 + 2000])
    out = tu.verbose(cap, extra=SCRIPTS)
    assert "Protocols in frame: slserial:sharedlink" in out  # both dissectors loaded and ran
    n = len(f2)
    assert f"[3 Reassembled fragments ({n} bytes): #1(6), #2(4), #3({n - 10})]" in out, out
    rows = re.findall(r"\[Frame: (\d+), payload: (-?\d+)-(\d+) \((\d+) bytes?\)\]", out)
    assert rows == [("1", "0", "5", "6"), ("2", "6", "9", "4"), ("3", "10", str(n - 1), str(n - 10))]
