"""A full frame with no checksum field resets the sync clock (docs/fields-sharedlink.md: "Only full
frames with a good (or missing) checksum reset the clock"), in the dissector (checksum validation
on and off) and in the Python decoder alike.

The conversation: a full frame at 0 s, a full frame without a checksum field at 1 s, deltas at
2.2 s and 3 s, the sync interval 1 s (late past 1.5 s). Reset by the second full frame, the first
delta (1.2 s after it) is on time and the second (2 s after it) late; not reset, both are late.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded

NO_CHECKSUM = b"[:AB|N0|D5|D6|D7|D8]\r\n"
FRAMES = [(0.0, tu.frame("A", "B", "N0", "D1", "D2", "D3", "D4")), (1.0, NO_CHECKSUM),
          (2.2, tu.frame("A", "B", "N0", "D9", "D", "D", "D")), (3.0, tu.frame("A", "B", "N0", "D10", "D", "D", "D"))]
KINDS = ["full", "full", "delta", "delta"]
LATE = [False, False, False, True]


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    t0 = 1_767_268_800.0
    return tu.write_pcap(tmp_path_factory.mktemp("nock") / "nock.pcap",
                         [tu.Pkt(t0 + t, raw, src="10.0.0.2", dst="10.0.0.1") for t, raw in FRAMES])


@pytest.mark.parametrize("validate", [True, False], ids=["validation-on", "validation-off"])
@pytest.mark.parametrize("two_pass", [False, True], ids=["one-pass", "two-passes"])
def test_the_dissector_resets_the_clock_on_a_full_frame_without_checksum(capture: Path, validate: bool,
                                                                          two_pass: bool) -> None:
    rows = tu.fields(capture, ["sharedlink.kind", "sharedlink.sync.is_late", "sharedlink.checksum.missing"],
                     prefs={"sharedlink.validate_checksum": validate, "sharedlink.sync_interval": 1000},
                     two_pass=two_pass)
    assert [r["sharedlink.kind"] for r in rows] == [[k] for k in KINDS]
    assert [r["sharedlink.sync.is_late"] == ["1"] for r in rows] == LATE
    assert [bool(r["sharedlink.checksum.missing"]) for r in rows] == [False, True, False, False]


def test_the_python_decoder_resets_the_clock_on_a_full_frame_without_checksum(capture: Path) -> None:
    decoded = [d for d in iter_decoded(capture) if isinstance(d, Decoded)]
    assert [d.kind for d in decoded] == KINDS
    assert [d.checksum_ok for d in decoded] == [True, None, True, True]
    assert [d.late for d in decoded] == LATE
