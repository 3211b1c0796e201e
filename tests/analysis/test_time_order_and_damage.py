"""Records are frames in file order, as in Wireshark, whatever their time stamps say: durations
and rates come from the real time span, a capture always agrees with itself, compress keeps its
full-set promise. A damaged capture: everything before the damage is used and reported, then
exit 2."""

from __future__ import annotations

import io
import json
import random
import struct
from pathlib import Path

import pytest

from sharedlink.capture.pcapio import PcapWriter, read_records
from sharedlink.cli import main
from sharedlink.generators.beacon import GenOptions, generate_file
from tshark_util import fields

NS = 1_000_000_000


def run(capsys, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _retimed(src: Path, dst: Path, shift) -> Path:
    """``src`` with each record's time changed by ``shift(index, ts_ns)``."""
    with open(dst, "wb") as fh:
        w = PcapWriter(fh)
        for i, r in enumerate(read_records(src)):
            w.write(shift(i, r.ts_ns), r.data)
    return dst


@pytest.fixture(scope="module")
def beacon(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("time") / "b.pcap"
    generate_file(GenOptions(frames=60), p)
    return p


@pytest.fixture(scope="module", params=["first-late", "shuffled"])
def disordered(request, beacon, tmp_path_factory) -> Path:
    rnd = random.Random(4)
    dst = tmp_path_factory.mktemp("time") / f"{request.param}.pcap"
    if request.param == "first-late":  # the first record is stamped 100 s after the others
        return _retimed(beacon, dst, lambda i, ts: ts + 100 * NS if i == 0 else ts)
    return _retimed(beacon, dst, lambda i, ts: ts + rnd.randrange(-3 * NS, 3 * NS))


def test_stats_duration_is_the_real_time_span(capsys, disordered):
    times = [float(r["frame.time_epoch"][0]) for r in fields(disordered, ["frame.time_epoch"], display_filter="sharedlink")]
    assert len(times) == 60
    code, out, err = run(capsys, "stats", "--json", disordered)
    assert code == 0, err
    st = json.loads(out)
    assert st["frames"] == 60
    assert st["duration_s"] == pytest.approx(max(times) - min(times), abs=1e-6)
    assert st["rate_hz"] == pytest.approx(59 / (max(times) - min(times)))


def test_a_capture_agrees_with_itself(capsys, disordered):
    code, out, err = run(capsys, "diff", "--json", disordered, disordered)
    assert code == 0, out
    d = json.loads(out)
    assert d["agree"] and d["pairs"] == 60 and d["unmatched_a"] == d["unmatched_b"] == 0


def test_compress_keeps_a_full_set_every_interval(capsys, disordered, tmp_path):
    out = tmp_path / "c.pcap"
    code, _, err = run(capsys, "compress", disordered, out)
    assert code == 0, err
    code, text, err = run(capsys, "export", out, "--format", "jsonl")
    assert code == 0, err
    rows = [json.loads(line) for line in io.StringIO(text)]
    assert len(rows) == 60
    fulls: list[int] = []
    for r in rows:  # every frame has a full set before it in the file, at most 1 s earlier
        if r["kind"] == "full":
            fulls.append(r["ts_ns"])
        else:
            assert any(0 <= r["ts_ns"] - f <= NS for f in fulls), r["number"]
    code, out_text, _ = run(capsys, "diff", disordered, out)
    assert code == 0, out_text


# -- damage ---------------------------------------------------------------------------------------


def _damage_at(src: Path, dst: Path, number: int) -> Path:
    """``src`` with record ``number``'s length field made implausible."""
    data = bytearray(src.read_bytes())
    off = 24
    for _ in range(number - 1):
        off += 16 + struct.unpack_from("<I", data, off + 8)[0]
    struct.pack_into("<I", data, off + 8, 0x7FFFFFFF)
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("frames, at", [(60, 26), (20_100, 20_000)])
def test_diff_uses_everything_before_the_damage(capsys, tmp_path, frames, at):
    good = tmp_path / "good.pcap"
    generate_file(GenOptions(frames=frames), good)
    bad = _damage_at(good, tmp_path / "bad.pcap", at)
    before = bad.read_bytes()
    code, out, err = run(capsys, "diff", "--json", bad, good)
    assert code == 2, err
    d = json.loads(out)
    assert d["a"]["value_frames"] == at - 1 and d["pairs"] == at - 1
    assert f"record {at}" in err and "Traceback" not in err
    code, out, err = run(capsys, "diff", bad, bad)  # the report is printed, then the error
    assert code == 2 and "matched value-frame pairs" in out and f"record {at}" in err
    code, out, err = run(capsys, "stats", "--json", bad)
    assert code == 2 and json.loads(out)["frames"] == at - 1
    assert bad.read_bytes() == before
