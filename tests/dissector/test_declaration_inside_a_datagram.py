"""Data, a declaration and data again in one datagram: the frames before the declaration use the
list in force, the ones after it the declared names, and a second pass (-2, which reads what the
first pass kept for each frame) shows exactly what one pass shows. The Python decoder names them
alike.

Packets (one conversation B>A): a declaration of X, Y; then one datagram holding ``D1|D2``, a
declaration of U, V and ``D3|D4``; then ``D5|D`` (V carried from the second packet).
"""

from __future__ import annotations

from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded

PACKETS = [
    tu.frame("A", "B", "N0", "T2", "QX", "T2", "QY"),
    tu.frame("A", "B", "N0", "D1", "D2") + tu.frame("A", "B", "N0", "T2", "QU", "T2", "QV")
    + tu.frame("A", "B", "N0", "D3", "D4"),
    tu.frame("A", "B", "N0", "D5", "D"),
]
FIELDS = ["sharedlink.kind", "sharedlink.var.name", "sharedlink.var.value", "sharedlink.var.carried",
          "sharedlink.var.carried_from", "sharedlink.sync.is_late", tu.INFO_FIELD]


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    t0 = 1_767_268_800.0
    return tu.write_pcap(tmp_path_factory.mktemp("decl") / "decl.pcap",
                         [tu.Pkt(t0 + 0.2 * i, p, src="10.0.0.2", dst="10.0.0.1") for i, p in enumerate(PACKETS)])


def test_one_pass_and_two_passes_show_the_same(capture: Path) -> None:
    one = tu.fields(capture, FIELDS, two_pass=False)
    two = tu.fields(capture, FIELDS, two_pass=True)
    assert one == two
    assert one[1]["sharedlink.kind"] == ["full", "declaration", "full"]
    assert one[1]["sharedlink.var.name"] == ["X", "Y", "U", "V", "U", "V"]
    assert one[2]["sharedlink.var.name"] == ["U", "V"]
    assert one[2]["sharedlink.var.value"] == ["5", "4"]
    assert one[2]["sharedlink.kind"] == ["delta"]
    assert one[2]["sharedlink.var.carried"] == ["1"] and one[2]["sharedlink.var.carried_from"] == ["2"]


def test_the_python_decoder_names_them_alike(capture: Path) -> None:
    decoded = [d for d in iter_decoded(capture) if isinstance(d, Decoded)]
    assert [(d.number, d.kind) for d in decoded] == [(1, "declaration"), (2, "full"), (2, "declaration"), (2, "full"),
                                                     (3, "delta")]
    shown = [[(u.name, u.text, u.carried) for u in d.updates] for d in decoded if d.kind != "declaration"]
    assert shown == [[("X", "1", False), ("Y", "2", False)], [("U", "3", False), ("V", "4", False)],
                     [("U", "5", False), ("V", "4", True)]]
