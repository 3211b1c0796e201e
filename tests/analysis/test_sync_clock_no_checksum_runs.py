"""A full frame with no checksum field resets the sync clock in runs the fast tiers take too
(test_sync_clock_no_checksum.py has the rule on four frames, which only the plain paths see):
four 5 Hz links of twenty seconds, one after the other, in the Python decoder, the counts tier `stats` reads and the
dissector (checksum validation on and off, one pass and two).

Each link a full frame every second for ten seconds, then every two seconds, deltas between:
B>A (positional) and D>A (named) carry checksums but on the full frames of the odd seconds (a
delta 1.6 s after the last full frame *with* a checksum is on time only if the one without
reset the clock); C>A (positional) and E>A (named) carry none at all. With the sync interval at 1 s a frame is late when the last full frame is more
than 1.5 s old: the deltas 1.6 and 1.8 s after a full frame in the last ten seconds.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter

NS = 10**9
T0 = 1_767_268_800 * NS
STEP = NS // 5
TICKS = 100  # 20 s at 5 Hz


def is_full(k: int) -> bool:
    """A full frame at tick k: every second for ten seconds, then every two."""
    return k % 5 == 0 and (k < 50 or k % 10 == 0)


#: the links: source letter -> (positional, checksums on every frame but the odd seconds' full frames)
LINKS = {"B": (True, True), "C": (True, False), "D": (False, True), "E": (False, False)}
NAMES = ("AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel")


def payload(src: str, k: int) -> bytes:
    positional, checksums = LINKS[src]
    full = is_full(k)
    if positional:
        fields = [f"D{k}", *(["D2", "D3", "D4"] if full else ["D", "D", "D"])]
    else:
        fields = [f for n, v in zip(NAMES if full else NAMES[:1], (k, 2, 3, 4)) for f in ("T2", "Q" + n, f"D{v}")]
    raw = tu.frame("A", src, "N0", *fields)
    if checksums and not (full and (k // 5) % 2):
        return raw
    return raw[:raw.rindex(b"|C")] + b"]\r\n"  # (no checksum field)


def expected_late(k: int) -> bool:
    """The rule: the last full frame (any, checksum or none) more than 1.5 s before."""
    last = max(j for j in range(k + 1) if is_full(j))
    return (k - last) * STEP > 3 * NS // 2


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("nock_runs") / "runs.pcap"
    links = {src: UdpBuilder(f"10.0.0.{n + 2}", "10.0.0.1", 7013, 7013) for n, src in enumerate(LINKS)}
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for n, (src, b) in enumerate(links.items()):  # (one link after another: runs for the fast tier)
            for k in range(TICKS):
                w.write(T0 + (n * TICKS + k) * STEP, b.frame(payload(src, k), k + 1))
    return path


#: (src, kind, late) of every frame, in the capture's order
WANT = [(src, "full" if is_full(k) else "delta", expected_late(k)) for src in LINKS for k in range(TICKS)]


def test_the_schedule_has_late_frames_and_resets_by_frames_without_checksum() -> None:
    assert 10 <= sum(late for _s, _k, late in WANT) < len(WANT) // 4
    # (were a full frame without a checksum no reset, B's deltas 1.6 s after an even second would be late)
    assert not any(expected_late(k) for k in range(50))


def test_the_python_decoder(capture: Path) -> None:
    decoded = [d for d in iter_decoded(capture) if isinstance(d, Decoded)]
    assert [(d.src, d.kind, d.late) for d in decoded] == WANT


def test_stats_fast_tier(capture: Path, tiers: dict[str, int]) -> None:
    st = capture_stats(capture)
    assert tiers["counts"] > 20, tiers  # (runs of the named links went through the fast tier)
    assert st.sync_late == sum(late for _s, _k, late in WANT)


@pytest.mark.parametrize("validate", [True, False], ids=["validation-on", "validation-off"])
@pytest.mark.parametrize("two_pass", [False, True], ids=["one-pass", "two-passes"])
def test_the_dissector(capture: Path, validate: bool, two_pass: bool) -> None:
    rows = tu.fields(capture, ["sharedlink.src", "sharedlink.kind", "sharedlink.sync.is_late"],
                     prefs={"sharedlink.validate_checksum": validate, "sharedlink.sync_interval": 1000},
                     two_pass=two_pass)
    assert [(r["sharedlink.src"][0], r["sharedlink.kind"][0], r["sharedlink.sync.is_late"] == ["1"]) for r in rows] == WANT
