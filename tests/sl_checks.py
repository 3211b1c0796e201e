"""Checks shared by several test files: the Lua tap's report parsed (``tshark -z
sharedlink,stats``), an MCAP file read back with the ``mcap`` package, diff's change records
against the reference decoder's, and the odd captures' builders and agreement check (the fast
tiers, the tap, ingest and export on one capture)."""

from __future__ import annotations

import io
import json
import re
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import mcap.reader as mcap_reader
from core_streams import stats_by_reference
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

import sharedlink.analysis.compiled_blocks as compiled_blocks
from sharedlink.analysis.changes import ChangeReader, read_changes
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.export import ExportOptions, export
from sharedlink.analysis.stats import CaptureStats, capture_stats, one_line
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, PcapWriter
from sharedlink.capture.stream import Chunk
from sharedlink.protocols.codec import encode_named
from sharedlink.protocols.state import BEACON_VARIABLES
from tshark_util import REPO, tshark

STATS_LUA = REPO / "dissector" / "sharedlink_stats.lua"


def flat_changes(path: Path, fast: bool, block: int = 1 << 20, variables=BEACON_VARIABLES) -> tuple:
    """Everything the reader gives, chunk boundaries left out (they follow the read blocks)."""
    ts, nums, recs, events, snaps, stats = b"", b"", [], [], [], None
    for c in read_changes(path, variables, fast=fast, block=block):
        if isinstance(c, Chunk):
            ts, nums, recs, events = ts + c.ts, nums + c.numbers, recs + c.records, events + c.events
            snaps.append((c.start + len(c.records), c.snapshot))
        else:
            stats = c.to_dict()
    return ts, nums, recs, events, snaps, stats


def same_changes(path: Path, variables=BEACON_VARIABLES, blocks=(700,)) -> int:
    """The core's changes equal the reference decoder's, chunk by chunk (the snapshot of every
    table at each chunk's end included), and with small read blocks (runs of records cut at a
    block's end); returns how many frames the compiled layouts took."""
    want = [c.as_tuple() if isinstance(c, Chunk) else c.to_dict() for c in read_changes(path, variables, fast=False)]
    r = ChangeReader(variables)
    got = [c.as_tuple() for c in r.chunks(path)] + [r.finish().to_dict()]
    assert got == want
    for block in blocks:  # runs of records cut at a block's end; the same chunks
        assert flat_changes(path, True, block, variables) == flat_changes(path, False, block, variables), block
    return r.dec.fast


def change_records(path: Path) -> list[bytes]:
    return [r for c in read_changes(path) if isinstance(c, Chunk) for r in c.records]


def tap_stats(path: Path, flt: str = "", prefs: dict | None = None) -> dict:
    """Run ``tshark -z sharedlink,stats`` with both scripts and parse its report. The tap writes
    pairs as the packet list does (``B→A``); they are returned as Python writes them (``B>A``)."""
    z = "sharedlink,stats" + ("," + flt if flt else "")
    res = tshark(path, ["-q", "-X", f"lua_script:{STATS_LUA}", "-z", z], prefs=prefs)
    text = res.stdout
    assert "SharedLink statistics" in text, text
    out: dict = {"kinds": {}, "pairs": {}, "vars": {}}
    section = None
    header: list[str] = []
    for line in text.splitlines():
        if m := re.match(r"(Frames|Checksum failures|Sync late|Noise): (\d+)$", line):
            out[m.group(1)] = int(m.group(2))
        elif line in ("Frames per kind", "Frames per node pair", "Variables"):
            section = line
        elif line.startswith("  ") and section:
            cols = re.split(r"\s{2,}", line.strip())
            if cols[0] in ("Kind", "Pair"):
                header = cols
                continue
            if section == "Frames per kind":
                out["kinds"][cols[0]] = int(cols[1])
            elif section == "Frames per node pair":
                kinds = {k: int(n) for k, n in zip(header[4:], cols[4:]) if int(n)}
                out["pairs"][cols[0].replace("→", ">")] = (int(cols[1]), int(cols[2]), int(cols[3]), kinds)
            else:
                parts = line.split(None, 3)
                out["vars"][(parts[0].replace("→", ">"), parts[1])] = (int(parts[2]), parts[3] if len(parts) > 3 else "")
        elif not line.startswith("  "):  # (a section of its own: link health, tests/dissector/test_health_tap.py)
            section = None
    return out


class Mcap:
    """Everything in an MCAP file, read with the `mcap` package's reader."""

    def __init__(self, path: Path) -> None:
        with open(path, "rb") as fh:
            r = mcap_reader.make_reader(fh)
            self.header = r.get_header()
            self.summary = r.get_summary()
            self.msgs: dict[str, list] = defaultdict(list)
            self.schemas: dict[str, tuple[str, str, str]] = {}
            self._decoders: dict[str, object] = {}
            for schema, channel, message in r.iter_messages(log_time_order=False):
                self.schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
                self.msgs[channel.topic].append((message.log_time, self.decode(schema, channel, message.data)))

    def decode(self, schema, channel, data: bytes):
        if channel.message_encoding == "json":
            return json.loads(data)
        assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
        cls = self._decoders.get(schema.name)
        if cls is None:
            pool = descriptor_pool.DescriptorPool()
            for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                pool.Add(fd)
            cls = self._decoders[schema.name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        return cls.FromString(data)  # type: ignore[attr-defined]

    def counts(self) -> dict[str, int]:
        """Message counts per topic as the summary's statistics record states them."""
        by_id = {cid: ch.topic for cid, ch in self.summary.channels.items()}
        return {by_id[cid]: n for cid, n in self.summary.statistics.channel_message_counts.items()}


T0 = 1_700_000_000 * 10**9


MS = 1_000_000


def beacon(src: str, dst: str, n: int, big: frozenset[int] = frozenset()) -> Iterator[tuple[int, bytes]]:
    """(time offset ns, payload): a named beacon at 5 Hz, a full set every 20th frame (late frames
    before each), a delta of Lat between, a bad checksum every 37th, a 3 s silence after frame 25;
    the full sets whose index is in ``big`` carry a 3000-byte string (a datagram over the MTU)."""
    t = 0
    for i in range(n):
        lat = "%.5f" % (38.0 + i / 1000)
        if i % 20 == 0:
            text = ("x" * 3000 + str(i)) if i in big else "run %d" % i
            raw = encode_named(dst, src, [("Lat", 2, lat), ("Lon", 2, "-77.1"), ("Mode", 4, text)])
        else:
            raw = encode_named(dst, src, [("Lat", 2, lat)])
        if i % 37 == 5:
            raw = raw[:-5] + b"00]\r\n"  # a wrong checksum
        yield t, raw
        t += 3000 * MS if i == 25 else 200 * MS


def udp(src_ip: str, payload: bytes, sport: int = 7013, ip_id: int = 1):
    from scapy.all import IP, UDP  # noqa: PLC0415 (slow import)

    return IP(src=src_ip, dst="10.0.0.9", id=ip_id, flags=0) / UDP(sport=sport, dport=7013) / payload


def ether(pkt) -> bytes:
    from scapy.all import Ether  # noqa: PLC0415

    return bytes(Ether(src="02:00:00:00:00:01", dst="02:00:00:00:00:09") / pkt)


def sll2(pkt) -> bytes:
    from scapy.layers.l2 import CookedLinuxV2  # noqa: PLC0415

    return bytes(CookedLinuxV2(proto=0x0800, ifindex=2, lladdrtype=1, pkttype=0, lladdrlen=6,
                               src=b"\x02\0\0\0\0\x01\0\0") / pkt)


def write_records(path: Path, records: list[tuple[int, bytes]], linktype: int = LINKTYPE_ETHERNET) -> Path:
    with open(path, "wb") as fh:
        w = PcapWriter(fh, linktype)
        for ts, data in records:
            w.write(T0 + ts, data)
    return path


def count_tiers(monkeypatch) -> dict[str, int]:
    """Frames the fast tiers take: ``counts`` (Decoder.count_run, stats), ``compiled`` (diff's
    compiled layouts, per record and block), ``block`` (compiled_blocks' block tier)."""
    took = {"counts": 0, "compiled": 0, "block": 0}
    run = Decoder.count_run

    def count_run(self, *args):
        r = run(self, *args)
        if r is not None:
            took["counts"] += r[2]
        return r

    make = compiled_blocks.block_taker

    def block_taker(*args, **kwargs):
        take = make(*args, **kwargs)

        def counted(*a):
            got = take(*a)
            if got is not None:
                took["block"] += got[2]
            return got

        return counted

    monkeypatch.setattr(Decoder, "count_run", count_run)
    monkeypatch.setattr(compiled_blocks, "block_taker", block_taker)
    return took


def agree(path: Path, took: dict[str, int]) -> CaptureStats:
    """stats (counts mode) == stats by reference == the tap; diff's tiers == the reference;
    ingest keeps as many frames, export (jsonl) as many of each kind. Returns the statistics."""
    from sharedlink.fleet.ingest import ingest  # noqa: PLC0415

    st = capture_stats(path)
    ref = stats_by_reference(path)
    skip = ("path", "limits", "error", "other_records")
    assert {k: v for k, v in ref.to_dict().items() if k not in skip} == \
        {k: v for k, v in st.to_dict().items() if k not in skip}
    tap = tap_stats(path)
    assert (tap["Frames"], tap["Checksum failures"], tap["Sync late"], tap["Noise"]) == (
        st.frames, st.checksum_failures, st.sync_late, st.noise_segments)
    assert tap["kinds"] == st.kinds
    assert tap["pairs"] == {p.pair: (p.frames, p.checksum_failures, p.sync_late, p.kinds) for p in st.pairs.values()}
    assert tap["vars"] == {k: (v.count, one_line(v.last or "")) for k, v in st.variables.items()}
    took["compiled"] += same_changes(path)
    assert ingest([path], path.parent / (path.stem + "-ds")).frames == st.frames
    out = io.StringIO()
    assert export(path, out, ExportOptions(fmt="jsonl")).frames == st.frames
    kinds: dict[str, int] = {}
    for line in out.getvalue().splitlines():
        kind = json.loads(line)["kind"]
        kinds[kind] = kinds.get(kind, 0) + 1
    assert kinds == st.kinds
    return st
