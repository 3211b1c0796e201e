"""watch's live link-quality line (issue 43): a direction's outages, and "LINK DOWN" while the
silence lasts past the link's threshold, from a real generated capture with a planted outage."""

from __future__ import annotations

from rich.console import Console

from sharedlink.analysis.decode import Decoded, iter_decoded
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.watch import LiveView


def _line(view: LiveView, now_ns: int) -> str:
    console = Console(record=True, width=160)
    console.print(view.render(now_ns))
    return next(x for x in console.export_text().splitlines() if "frames/s" in x)


def test_watch_shows_an_outage_while_it_lasts(tmp_path):
    cap = tmp_path / "o.pcap"
    generate_file(GenOptions(duration=30, outages=((10.0, 3.0),)), cap)
    items = [d for d in iter_decoded(cap) if isinstance(d, Decoded)]
    view = LiveView(1.0, "t")
    before = [d for d in items if d.ts_ns < items[0].ts_ns + 10 * 10**9]
    for d in before:
        view.update(d)
    last = before[-1].ts_ns
    assert "LINK DOWN" not in _line(view, last + 5 * 10**8) and "outages 0" in _line(view, last + 5 * 10**8)
    line = _line(view, last + 2 * 10**9)  # past the 1 s threshold (5 Hz: 3 periods are 0.6 s)
    assert "LINK DOWN 2.0 s" in line and "outages 1" in line
    for d in items[len(before):]:
        view.update(d)
    line = _line(view, items[-1].ts_ns)
    assert "LINK DOWN" not in line and "outages 1" in line
