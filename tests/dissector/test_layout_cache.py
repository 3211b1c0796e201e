"""The layout cache in front of sharedlink's parser (dissector/sharedlink/parse.lua) stands in
for it: whatever frames it takes, everything after it comes out as if the parser had taken them.

Every frame goes one route (parse, checksum, state, Info, tree), in any pass: no tree (tshark's
summary pass), a tree nobody sees (-Y, coloring rules) or a shown tree (-V, -T pdml, the GUI's
details).  In front of the parser, a frame with the layout of one its node pair sent before
(named, positional or bare) is matched by that layout's pattern, which fills the same arrays and
facts, the fields' places included for a shown tree.  SHAREDLINK_NO_FAST=1 turns the cache off
(every frame parsed field by field); SHAREDLINK_FAST_MARK=1 marks the Info of the packets it
took, to show that it ran at all.  The state, records, Info and trees, which the frames after it
and a second pass (-2, -2 -V) read, must be the same both ways.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_captures import pcap_payloads
from sl_cli import run_cli
from sl_vectors import load_streams, stream_ids, write_stream, write_streams_apart

import tshark_util as tu
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter, read_records

REPO = Path(__file__).resolve().parents[2]
OTHERS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
          for a in ("-X", f"lua_script:{s}")]
MARK = "[fast] "

# beacon streams the cache is for, and the ways out of it: bad checksums, dropped frames, late
# sync (full frames every 3 s), positional values, serial records, TCP segments
GEN = {
    # (a clean compressed stream, 200 frames of seed 7, was a case of its own: its 4 layouts are
    # among the 10 of compressed-faults, the same stream with bad checksums and drops, and the
    # cache's bulk on it is test_cache_takes_the_bulk_of_a_beacon_stream's)
    "full": ["--frames", "120"],
    "compressed-faults": ["--frames", "300", "--compress", "--bad-checksum", "0.1", "--drop", "0.1"],
    "late-sync": ["--frames", "150", "--compress", "--sync-interval", "3"],
    "positional": ["--frames", "100", "--compress", "--form", "positional"],
    "serial": ["--frames", "80", "--compress", "--transport", "serial", "--noise", "0.05"],
    "other-pair": ["--frames", "60", "--compress", "--src", "C", "--dst", "D"],
}
STREAMS = load_streams()
SERIAL_STREAMS = [s for s in STREAMS if s.get("transport") == "serial"]
# filters on fields of the frame, of its variables and of its carried variables
FILTERS = ['sharedlink.kind == "delta" && sharedlink.checksum.status == 1',
           "sharedlink.crlf.missing || sharedlink.sync.is_late",
           "sharedlink.var.double > 40 && sharedlink.var.index == 1",
           'sharedlink.var.carried_from > 1 && sharedlink.var.name == "AutoGpsHead"',
           "count(sharedlink.var) == 4 && sharedlink.checksum.calculated > 0"]


def _outputs(cap: Path, monkeypatch: pytest.MonkeyPatch, *, cache: bool, short: bool = False) -> dict[str, str]:
    with monkeypatch.context() as m:
        if not cache:
            m.setenv("SHAREDLINK_NO_FAST", "1")
        if short:   # the passes that differ most: no tree, a shown one (two passes), a hidden one
            return {
                "one pass": tu.tshark(cap, [*OTHERS], two_pass=False).stdout,
                "two passes, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout,
                f"filter {FILTERS[0]}": tu.tshark(cap, ["-Y", FILTERS[0], *OTHERS], two_pass=False).stdout,
            }
        return {
            "one pass": tu.tshark(cap, [*OTHERS], two_pass=False).stdout,
            "two passes": tu.tshark(cap, [*OTHERS], two_pass=True).stdout,
            "two passes, tree": tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout,
            # a shown tree in one pass, every item's label (showname), place and size (hidden
            # ones too): what -V would print of it, and more
            "pdml": "\n".join(x for x in tu.tshark(cap, ["-T", "pdml", *OTHERS], two_pass=False).stdout.splitlines()
                              if not x.startswith("<pdml ")),   # its line holds the time it ran
            # a tree nobody sees: the compact form
            **{f"filter {f}": tu.tshark(cap, ["-Y", f, *OTHERS], two_pass=False).stdout for f in FILTERS},
            "two passes, filter": tu.tshark(cap, ["-Y", FILTERS[0], *OTHERS], two_pass=True).stdout,
            "filter, tree": tu.tshark(cap, ["-V", "-Y", FILTERS[2], *OTHERS], two_pass=False).stdout,
        }


def _same_both_ways(cap: Path, monkeypatch: pytest.MonkeyPatch, short: bool = False) -> None:
    on, off = _outputs(cap, monkeypatch, cache=True, short=short), _outputs(cap, monkeypatch, cache=False, short=short)
    for how in on:
        assert on[how] == off[how], how
    assert on["one pass"] and on["two passes, tree"]


def _marked(cap: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], two_pass: bool = False) -> list[str]:
    with monkeypatch.context() as m:
        m.setenv("SHAREDLINK_FAST_MARK", "1")
        out = tu.tshark(cap, [*args, *OTHERS], two_pass=two_pass).stdout
    return [x for x in out.splitlines() if MARK in x]


T0 = 1_767_268_800_000_000_000
LONG_TEXT = "x" * 50


def _line_end_payloads() -> list[bytes]:
    """CR LF, CR, LF or nothing after the frame, in turns (test_cache_on_every_line_end)."""

    def frame(body: str, end: str) -> bytes:
        return f"[{body}{sum(body.encode()) % 256:02X}]{end}".encode()

    ends = ["\n", "\r", "\r\n", "", "\n", "\r"] * 4
    bodies = [":AB|N0|T2|QLat|D1.5|T2|QLon|D2.5|C" if i % 3 == 0 else ":AB|N0|T2|QLat|D1.6|C" for i in range(len(ends))]
    return [frame(b, e) for b, e in zip(bodies, ends)]


def _value_payloads() -> list[bytes]:
    """Values of every kind in named and positional layouts, every 7th checksum bad
    (test_cache_on_every_kind_of_value)."""
    values = ["1.5", LONG_TEXT, "Ωμέγα", "%^{}~\\`'\"", "a[b", "a]b", "tab\there", "del\x7f", "", "-0.25",
              "y" * 30, "7"]
    # the first frames of each layout with short values (its hit code pads the joined values most)
    bodies = [":AB|N0|T4|QName|Da|T4|QNote|Db|T2|QLat|D1.5|C", ":CD|N0|D1|D2|D3|C"] * 2
    for i in range(72):
        v = values[i % len(values)]
        w = values[(i * 5 + 1) % len(values)]
        lat = f"+{i}.5" if i % 11 == 1 else f"{i}.5"   # (a sign the double pattern leaves to the parser)
        bodies.append(f":AB|N0|T4|QName|D{v}|T4|QNote|D{w}|T2|QLat|D{lat}|C" if i % 3 else f":CD|N0|D{v}|D{w}|D{i}|C")
    out = []
    for i, body in enumerate(bodies):
        raw = body.encode()
        checksum = (sum(raw) + (i % 7 == 3)) % 256   # every 7th frame a bad one
        out.append(b"[" + raw + f"{checksum:02X}]\r\n".encode())
    return out


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    """The UDP cases of GEN, the line ends over UDP and TCP and the values of every kind in one
    capture, interleaved by time, each from a source address of its own (the dissector keeps each
    conversation's state apart): one tshark run a mode answers for them all. (The capture, and
    each case's source address.)"""
    tmp = tmp_path_factory.mktemp("cache")
    parts: list[Path] = []
    sources: dict[str, str] = {}

    def udp(name: str, datagrams: list[tuple[int, bytes]]) -> None:
        sources[name] = f"10.0.1.{len(sources) + 1}"
        b = UdpBuilder(sources[name], "10.0.0.9", 7000 + len(sources), 7013)
        parts.append(tmp / f"{name}.pcap")
        with open(parts[-1], "wb") as fh:
            w = PcapWriter(fh)
            for i, (ts, payload) in enumerate(datagrams):
                w.write(ts, b.frame(payload, i + 1))

    for name in sorted(n for n in GEN if n != "serial"):
        one = tmp / f"gen-{name}.pcap"
        run_cli("gen", "--seed", "7", *GEN[name], str(one), text=False, check=True)
        udp(name, [(ts, payload) for _n, ts, payload in pcap_payloads(one)])
    udp("line ends udp", [(T0 + i * 200_000_000, p) for i, p in enumerate(_line_end_payloads())])
    udp("values", [(T0 + i * 200_000_000, p) for i, p in enumerate(_value_payloads())])
    sources["line ends tcp"] = "10.0.0.2"
    parts.append(tu.write_pcap(tmp / "ends-tcp.pcap", [tu.Pkt(T0 / 1e9 + i * 0.2, p, 40000, 7013, "tcp", "10.0.0.2",
                                                                "10.0.0.1") for i, p in enumerate(_line_end_payloads())]))
    records = sorted(((r.ts_ns, k, r.data) for k, part in enumerate(parts) for r in read_records(part)))
    cap = tmp / "mixed.pcap"
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        for ts, _k, data in records:
            w.write(ts, data)
    return cap, sources


@pytest.fixture(scope="module")
def marked_shown(mixed: tuple[Path, dict[str, str]]) -> list[str]:
    with pytest.MonkeyPatch.context() as m:
        return _marked(mixed[0], m, ["-V", "-P"])


def test_cache_leaves_what_the_parser_leaves(mixed: tuple[Path, dict[str, str]]) -> None:
    with pytest.MonkeyPatch.context() as m:
        _same_both_ways(mixed[0], m)


@pytest.mark.parametrize("name", sorted(n for n in GEN if n != "serial"))
def test_cache_takes_dozens_of_each_beacon_case(name: str, mixed: tuple[Path, dict[str, str]],
                                                marked_shown: list[str]) -> None:
    """It ran: dozens of the packets of a shown tree took it, in every case."""
    assert sum(f" {mixed[1][name]} " in x for x in marked_shown) >= 20


def test_cache_leaves_what_the_parser_leaves_on_serial(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cap = tmp_path / "serial.pcap"
    run_cli("gen", "--seed", "7", *GEN["serial"], str(cap), text=False, check=True)
    _same_both_ways(cap, monkeypatch)
    assert len(_marked(cap, monkeypatch, ["-V", "-P"])) >= 20


def test_cache_on_the_vector_streams(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every UDP and TCP vector stream in one capture (addresses of its own each), so three
    tshark runs a way answer for them all."""
    cap = write_streams_apart([s for s in STREAMS if s.get("transport", "udp") != "serial"], tmp_path / "s.pcap")
    _same_both_ways(cap, monkeypatch, short=True)


@pytest.mark.parametrize("stream", SERIAL_STREAMS, ids=stream_ids(SERIAL_STREAMS))
def test_cache_on_the_serial_vector_streams(stream: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _same_both_ways(write_stream(stream, tmp_path / "s.pcapng"), monkeypatch, short=True)


@pytest.mark.parametrize("proto", ["udp", "tcp"])
def test_cache_on_every_line_end(proto: str, mixed: tuple[Path, dict[str, str]], marked_shown: list[str]) -> None:
    """CR LF, CR, LF or nothing may follow the frame (the CR LF expert and the frame's length in
    the hidden tree must come out as the parser's: test_cache_leaves_what_the_parser_leaves). The
    CR LF expert is for TCP (and serial), where CR LF frames the bytes, never for a UDP datagram
    (issue 29)."""
    cap, sources = mixed
    src = sources[f"line ends {proto}"]
    assert any(f" {src} " in x for x in marked_shown)  # (its lines are told apart by their source)
    with pytest.MonkeyPatch.context() as m:
        marked = [x for x in _marked(cap, m, ["-Y", "sharedlink.crlf.missing"]) if f" {src} " in x]
    assert len(marked) > 10 if proto == "tcp" else not marked
    if proto == "udp":
        assert not tu.fields(cap, ["sharedlink.crlf.missing"], two_pass=False,
                             display_filter=f"sharedlink.crlf.missing && ip.src == {src}")


def test_cache_takes_the_bulk_of_a_beacon_stream(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Full frames and compressed deltas (bare ones too) take the cache in both passes and with a
    shown tree; the frames it leaves (the first of each layout, bad checksums) go to the parser."""
    cap = tmp_path / "c.pcap"
    run_cli("gen", "--frames", "300", "--compress", "--bad-checksum", "0.05", str(cap), text=False, check=True)
    for args, two_pass in (([], False), ([], True), (["-V", "-P"], False), (["-V", "-P"], True)):
        marked = _marked(cap, monkeypatch, args, two_pass)
        assert len(marked) > 240, (args, two_pass, len(marked))
        assert any(" full " in x for x in marked) and any("delta (+4 carried)" in x for x in marked)
        assert any("delta AutoGpsLat" in x for x in marked)


def test_records_of_a_long_compressed_stream(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second pass reads the carried values the first pass kept for each delta, packed 256
    records to a chunk in one ByteArray: a stream long enough for several chunks, read by the
    second pass in order, shows the same carried values with the cache as without it."""
    cap = tmp_path / "long.pcap"
    run_cli("gen", "--seed", "11", "--frames", "1400", "--compress", str(cap), text=False, check=True)
    outs = []
    for cache in (True, False):
        with monkeypatch.context() as m:
            if not cache:
                m.setenv("SHAREDLINK_NO_FAST", "1")
            outs.append(tu.tshark(cap, ["-V", *OTHERS], two_pass=True).stdout)
    assert outs[0] == outs[1]
    # most of the 1400 frames are deltas: well over 256 records, each showing its carried values
    carried = [x for x in outs[0].splitlines() if "(carried from frame " in x]
    assert len(carried) > 1000, len(carried)
    last_frame = max(int(x.rsplit("(carried from frame ", 1)[1].split(")")[0]) for x in carried)
    assert last_frame > 1200


def test_cache_on_every_kind_of_value(mixed: tuple[Path, dict[str, str]]) -> None:
    """A layout's value pattern is a set of byte ranges (any byte but '|', ']', the control
    characters and DEL; a double-typed value a plain decimal) and its checksum sums the values as
    one string: values long and short, UTF-8, punctuation, and the bytes it must leave to the
    parser come out as the parser makes them (test_cache_leaves_what_the_parser_leaves), in named
    and positional layouts, with good checksums and bad ones (the sum of values joined short and
    long: the hit code pads them past Lua's 40 bytes for interned strings, by what the layout's
    first frame needs); the long and the UTF-8 ones take the cache."""
    cap, sources = mixed
    with pytest.MonkeyPatch.context() as m:
        marked = [x for x in _marked(cap, m, []) if f" {sources['values']} " in x]
    assert any(LONG_TEXT in x for x in marked) and any("Ωμέγα" in x for x in marked)
    assert not any("tab" in x or "a]b" in x for x in marked)
