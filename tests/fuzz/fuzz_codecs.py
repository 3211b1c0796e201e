"""Fuzz targets for the Python parsers: each takes arbitrary bytes and checks the parser's contract
(only its own error type escapes; splitters lose nothing). ``make fuzz`` runs every target with
atheris (coverage-guided libFuzzer) for at least 100,000 inputs; without atheris, hypothesis.

    python tests/fuzz/fuzz_codecs.py --list
    python tests/fuzz/fuzz_codecs.py TARGET [libFuzzer options, e.g. -runs=100000] [CORPUS_DIR...]
    python tests/fuzz/fuzz_codecs.py --hypothesis TARGET RUNS

Targets for sharedlink.protocols.p2os and sharedlink.protocols.blackboard are there only when those modules exist.
A failing input is replayed by tests/fuzz/test_fuzz_short.py once it is kept in
tests/fuzz/fuzz-regressions/codec-TARGET-*.bin.
"""

from __future__ import annotations

import importlib
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

Target = Callable[[bytes], None]

_TMP = Path(os.environ.get("SHAREDLINK_FUZZ_TMP") or ("/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()))


def _codec_targets() -> dict[str, Target]:
    from sharedlink.protocols import codec

    def parse_frame(data: bytes) -> None:
        try:
            f = codec.parse_frame(data)
        except codec.SharedLinkError as e:
            assert 0 <= e.offset <= len(data), (e.offset, len(data))
            return
        assert f.checksum is not None

    def iter_segments(data: bytes) -> None:
        pos = 0
        for seg in codec.iter_segments(data):
            assert seg.start == pos and seg.end > seg.start, (seg, pos)
            if seg.frame is not None:
                assert codec.parse_frame(data[seg.start : seg.end]) == seg.frame, seg
            else:
                assert seg.error is not None
            pos = seg.end
        assert pos == len(data), (pos, len(data))

    return {"codec.parse_frame": parse_frame, "codec.iter_segments": iter_segments}


def _pcapio_targets() -> dict[str, Target]:
    from sharedlink.capture import pcapio

    path = _TMP / f"slfuzz-pcapio-{os.getpid()}.bin"

    def read_records(data: bytes) -> None:
        path.write_bytes(data)
        n = 0
        try:
            for rec in pcapio.read_records(path, chunk=4096):
                n += 1
                assert rec.number == n and isinstance(rec.data, bytes)
        except pcapio.CaptureError:
            pass

    return {"pcapio.read_records": read_records}


def _p2os_targets() -> dict[str, Target]:
    p2os = importlib.import_module("sharedlink.protocols.p2os")

    def parse_packet(data: bytes) -> None:
        try:
            p2os.parse_packet(data)
        except p2os.P2osError:
            pass

    def iter_chunks(data: bytes) -> None:
        assert b"".join(c.data for c in p2os.iter_chunks(data)) == data

    def decode_payload(data: bytes) -> None:
        if not data:
            return
        try:
            p2os.decode_payload(data[1:], from_client=bool(data[0] & 1))
        except p2os.P2osError:
            pass

    return {"p2os.parse_packet": parse_packet, "p2os.iter_chunks": iter_chunks, "p2os.decode_payload": decode_payload}


def _blackboard_targets() -> dict[str, Target]:
    bb = importlib.import_module("sharedlink.protocols.blackboard")

    def parse_message(data: bytes) -> None:
        try:
            bb.parse_message(data)
        except bb.BlackboardError:
            pass

    def parse_response(data: bytes) -> None:
        if len(data) < 4:
            return
        req = bb.RequestMessage(data[0] << 8 | data[1], data[2], data[3])
        try:
            bb.parse_response(req, data[4:])
        except bb.BlackboardError:
            pass

    return {"blackboard.parse_message": parse_message, "blackboard.parse_response": parse_response}


def targets() -> dict[str, Target]:
    """Every target whose module exists (p2os and blackboard are skipped when missing)."""
    out: dict[str, Target] = {}
    for make in (_codec_targets, _pcapio_targets, _p2os_targets, _blackboard_targets):
        try:
            out.update(make())
        except ImportError:
            pass
    return out


def seeds() -> dict[str, list[bytes]]:
    """Starting inputs per module: real frames and small real captures, for the fuzzer to mutate."""
    from sharedlink.generators.beacon import GenOptions, beacon_payloads, generate_file
    from sharedlink.protocols import codec

    frames = [p for _, p, _ in beacon_payloads(GenOptions(frames=6, compress=True))]
    frames += [p for _, p, _ in beacon_payloads(GenOptions(frames=2, form="positional"))]
    frames += [codec.build_fields(codec.query_fields("AutoGpsLat")), b"[:AB|N0|T0|QMode|D3]", b"x[:AB|P1|C71]\r\n[:A"]
    caps = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, kw in enumerate(({"frames": 3}, {"frames": 3, "fmt": "pcapng"}, {"frames": 2, "form": "positional"})):
            p = Path(tmp, f"s{i}")
            generate_file(GenOptions(**kw), p)  # type: ignore[arg-type]
            caps.append(p.read_bytes())
    out = {"codec": frames + [b"".join(frames)], "pcapio": caps, "p2os": [], "blackboard": []}
    try:
        p2os = importlib.import_module("sharedlink.protocols.p2os")
        pk = [p2os.encode_message(p2os.command(1)), p2os.encode_message(p2os.Sip(moving=True, sonars=((1, 500),)))]
        out["p2os"] = pk + [b"\x01" + p[3:-2] for p in pk] + [b"noise" + b"".join(pk)]
    except (ImportError, AttributeError, TypeError):
        pass
    try:
        bb = importlib.import_module("sharedlink.protocols.blackboard")
        out["blackboard"] = [
            bb.build_message(bb.SetMessage(0x1F00, 1, b"\x01\x02\x03")),
            bb.build_message(bb.RequestMessage(0xE000, 1, 5)),
            b"\xe0\x00\x01\x05" + bytes(6),
        ]
    except (ImportError, AttributeError, TypeError):
        pass
    return out


def run_hypothesis(name: str, runs: int) -> int:
    """The fallback without atheris: ``runs`` random inputs through hypothesis."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    fn = targets()[name]
    pool = seeds().get(name.split(".")[0], [])
    data = st.binary(max_size=4096)
    if pool:
        data = st.one_of(data, st.sampled_from(pool), st.tuples(st.sampled_from(pool), st.binary(max_size=64), st.integers(0, 4096)).map(
            lambda t: t[0][: t[2]] + t[1] + t[0][t[2] :]
        ))

    @settings(max_examples=runs, database=None, deadline=None, phases=[Phase.generate], suppress_health_check=list(HealthCheck))
    @given(data)
    def check(b: bytes) -> None:
        fn(b)

    check()
    print(f"Done {runs} runs (hypothesis)")
    return 0


def main(argv: list[str]) -> int:
    if len(argv) > 1 and argv[1] == "--list":
        print("\n".join(targets()))
        return 0
    if len(argv) > 3 and argv[1] == "--hypothesis":
        return run_hypothesis(argv[2], int(argv[3]))
    if len(argv) < 2 or argv[1].startswith("-"):
        print(__doc__, file=sys.stderr)
        return 2
    import atheris

    name = argv[1]
    with atheris.instrument_imports(include=["sharedlink"]):
        chosen = targets().get(name)
    if chosen is None:
        print(f"unknown target {name!r}; targets: {', '.join(targets())}", file=sys.stderr)
        return 2
    atheris.Setup([argv[0], *argv[2:]], chosen)
    atheris.Fuzz()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
