"""compress follows its output through the decoding core's fast path (issue 39): the output
decoder reads each rewritten frame from its bytes, so after a direction's first frames it takes
them without the reference path; expand writes full sets, which need no view of the output, and
its input's core takes the steady state on the fast path. Counted, not timed."""

from __future__ import annotations

import pytest

from sharedlink.analysis.transform import Rewriter
from sharedlink.capture.stream import StreamFrame, iter_frames
from sharedlink.generators.beacon import GenOptions, generate_file


@pytest.mark.parametrize("form", ["named", "positional"])
@pytest.mark.parametrize("mode", ["expand", "compress"])
def test_the_output_decoder_takes_the_steady_state_on_the_fast_path(tmp_path, form, mode):
    cap = tmp_path / "in.pcap"
    generate_file(GenOptions(frames=400, compress=mode == "expand", form=form), cap)
    rw = Rewriter(mode)
    n = 0
    for sf in iter_frames(cap):
        if isinstance(sf, StreamFrame) and sf.frame is not None:
            rw.frame(sf.frame, sf.raw, sf.ts_ns, conv=sf.conv)
            n += 1
    assert n >= 400 and rw.stats.rewritten == 400  # (positional: a declaration first)
    # (compress: a full set every second, deltas between; expand: every frame a full set)
    followed = rw.out_decoder if mode == "compress" else rw.src_decoder
    assert followed.fast >= 300, (rw.src_decoder.fast, rw.out_decoder.fast)
    if mode == "expand":
        assert rw.out_decoder.fast == 0  # (what a receiver knows: not needed)
