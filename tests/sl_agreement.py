"""The two decoders' frames side by side, for the tests that compare them (test_agreement*.py):
the dissector's (tshark -T json, two passes) and Python's (iter_decoded), each reduced to the
same comparable shape, and the limit sessions' capture builders (an OCU and a vehicle on UDP)."""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sl_cli import run_cli

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded, parse_variables
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import NS, PcapWriter, read_records
from sharedlink.fleet.query import run_query
from sharedlink.protocols.codec import TYPE_NAMES
from sharedlink.protocols.state import BEACON_VARIABLES

_as_list, _walk = tu.as_list, tu.walk


VARIABLES = "P0:2,P1:0,P2:4,P3"


CHECKSUM_WORD = {"1": "good", "0": "bad"}


TRUE = ("1", "True", "true")


#: the typed field a value shows (issue 29: types agree too, the default list's included)
TYPED = {"long": "sharedlink.var.long", "double": "sharedlink.var.double", "string": "sharedlink.var.string"}


def _one(node: dict, key: str) -> Any:
    vals = _as_list(node.get(key))
    return vals[0] if vals else None


def _placeholder(name: str | None) -> str | None:
    """A slot past the known list has no name of its own: Python calls it ``var<i>``, the
    dissector ``#<i>`` (or shows none); both compare as None."""
    if name is None or re.fullmatch(r"(var|#)[0-9]+", name):
        return None
    return name


def lua_frames(cap: Path, variables: str | None = VARIABLES, extra: tuple[str, ...] = ()) -> list[list[dict[str, Any]]]:
    """The dissector's frames (``variables`` None: the preference's default)."""
    prefs = None if variables is None else {"sharedlink.variables": variables}
    return frames_of(tu.json_packets(cap, prefs=prefs, two_pass=True, extra=extra))


def frames_of(packets: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """The dissector's frames of a ``tshark -T json`` run's packets."""
    out = []
    for p in packets:
        trees = [t for t in _as_list(p["_source"]["layers"].get("sharedlink")) if isinstance(t, dict)]
        frames = []
        for t in trees:
            if "sharedlink.noise" in t:
                continue
            status = _walk(t, "sharedlink.checksum.status")
            has_ck = "sharedlink.checksum" in t or "sharedlink.checksum.text" in t
            kind = _one(t, "sharedlink.kind")
            variables = []
            for v in _as_list(t.get("sharedlink.var")):
                if not isinstance(v, dict):
                    continue
                experts = {k for e in _walk(v, "_ws.expert") if isinstance(e, dict) for k in e}
                carried = _one(v, "sharedlink.var.carried") in TRUE
                value = _one(v, "sharedlink.var.value")
                typed = None if carried else next((t for t, f in TYPED.items() if f in v), None)
                variables.append(
                    (_placeholder(_one(v, "sharedlink.var.name")), value, carried,
                     "sharedlink.var.badvalue" in experts and not carried, typed,
                     "sharedlink.var.unknown" in experts)
                )
            frames.append({
                "kind": kind,
                "checksum": CHECKSUM_WORD.get(status[0], "?") if has_ck and status else "missing",
                "vars": sorted(variables, key=repr) if kind in ("full", "delta", "reply") else None,
            })
        out.append(frames)
    return out


def python_frames(cap: Path, n: int, variables: str | None = VARIABLES) -> list[list[dict[str, Any]]]:
    """Python's frames (``variables`` None: its default, BEACON_VARIABLES)."""
    out: list[list[dict[str, Any]]] = [[] for _ in range(n)]
    vs = list(BEACON_VARIABLES) if variables is None else parse_variables(variables)
    for d in iter_decoded(cap, vs):
        if not isinstance(d, Decoded) or d.kind == "malformed":  # (left out of both, see test_vector_stream_agrees)
            continue
        # (var.unknown is a positional slot's: a bare N shows named values only, issue 40)
        positional = d.frame is not None and not any(f.letter in "QR" for f in d.frame.fields) and any(
            f.letter == "D" for f in d.frame.fields)
        variables = [(_placeholder(u.name), u.text, u.carried, u.bad and not u.carried,
                      None if u.carried or u.bad else TYPE_NAMES.get(u.type_code),
                      positional and u.index is not None and d.table.past_list(u.index)) for u in d.shown]
        out[d.number - 1].append({
            "kind": d.kind,
            "checksum": {True: "good", False: "bad", None: "missing"}[d.checksum_ok],
            "vars": sorted(variables, key=repr) if d.kind in ("full", "delta", "reply") else None,
        })
    return out


T0_NS = 1_767_268_800 * 1_000_000_000


OCU, VEHICLE = ("10.0.0.1", 4000), ("10.0.0.2", 7013)


def limit_frame(body: str) -> bytes:
    """``[:<body>|C<xx>]`` CR LF with the right checksum."""
    head = f"[:{body}|C".encode("latin-1")
    return head + b"%02X]\r\n" % (sum(head[1:]) % 256)


def udp_builder(src: tuple[str, int], dst: tuple[str, int]) -> UdpBuilder:
    return UdpBuilder(src[0], dst[0], src[1], dst[1])


def session(bodies: list[str]) -> list[bytes]:
    """Each body a frame between the OCU and the vehicle: ``BA|...`` from the OCU, any other
    from the vehicle (as ``limit_frame`` writes it, numbered from 1)."""
    return [(udp_builder(OCU, VEHICLE) if x.startswith("BA") else udp_builder(VEHICLE, OCU)).frame(limit_frame(x), i + 1)
            for i, x in enumerate(bodies)]


def write_session(path: Path, frames: list[bytes]) -> Path:
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, f in enumerate(frames):
            w.write(T0_NS + i * 1_000_000, f)
    return path


def limit_rows(cap: Path, names: tuple[str, ...] = ()) -> list[dict[str, list[str]]]:
    """tshark's frame numbers and ``names`` a frame (one pass), for the limit sessions."""
    return tu.fields(cap, ["frame.number", *names], two_pass=False)


# -- link health (issues 42, 43): the outages of stats, the -z sharedlink,stats tap, and the other outputs --

REPO = Path(__file__).resolve().parents[1]
STATS = REPO / "dissector" / "sharedlink_stats.lua"
SERIAL = REPO / "dissector" / "serial.lua"
#: the robot dissectors (their links feed the tap too)
ROBOTS = [REPO / "dissector" / n for n in ("p2os.lua", "blackboard.lua")]
ARROW = "\u2192"

#: How far two reports of one outage (start from the first record, duration; seconds) may differ,
#: each against the exact reference (:func:`reference_outages`, from integer ns): the tap prints
#: 6 decimals of Wireshark's relative times (0.5 us at most), JSON's epoch seconds are doubles
#: (0.12 us at most each near 1.8e9 s: 0.24 us for a start less the first record's time). Less
#: than a microsecond, so that no output a microsecond off passes.
OUTAGE_TOLERANCE_S = 0.6e-6


def gen_captures(directory: Path, captures: dict[str, list[str]], suffix: str | None = None) -> dict[str, Path]:
    """``sharedlink gen`` of each name's arguments into ``directory`` (``NAME.pcapng`` for a serial
    one, ``NAME.pcap`` otherwise, unless ``suffix`` says)."""
    out = {}
    for name, args in captures.items():
        path = directory / (name + (suffix or (".pcapng" if "serial" in args else ".pcap")))
        run_cli("gen", "-o", path, *args, check=True)
        out[name] = path
    return out


def ingest(directory: Path, captures: Iterable[Path]) -> Path:
    """A fleet dataset of ``captures`` (``sharedlink ingest``), in ``directory``."""
    ds = directory / "ds"
    run_cli("ingest", "-o", ds, *captures, check=True, timeout=300)
    return ds


def _relative(path: Path, outages: Iterable[Any]) -> list[tuple]:
    first = next(iter(read_records(path))).ts_ns
    return sorted((o.link, o.pair, (o.start_ns - first) / NS, o.duration_ns / NS, o.end_ns is None) for o in outages)


def reference_outages(path: Path, outage_after: float | None = None) -> list[tuple]:
    """The outages of ``capture_stats`` (the reference, exact: integer ns): link, pair, start in
    seconds from the first record, duration, open; sorted."""
    return _relative(path, capture_stats(path, outage_after=outage_after).health.outages())


def json_outages(path: Path, rows: Iterable[dict]) -> list[tuple]:
    """Outage rows of a JSON output (``start`` and ``end`` epoch seconds, ``duration_s``) as
    :func:`reference_outages` has them."""
    first = next(iter(read_records(path))).ts_ns / NS
    return sorted((o["link"], o["pair"], o["start"] - first, o["duration_s"], o["end"] is None) for o in rows)


def python_outages(path: Path, *extra: object) -> tuple[list[tuple], list[dict]]:
    """stats --json's links, and its outages (from the same run's integer-ns figures): link, pair,
    start in seconds from the first record, duration, open."""
    d = json.loads(run_cli("stats", "--json", path, *extra, check=True).stdout)
    st = capture_stats(path, outage_after=float(extra[1]) if extra else None)
    outs = _relative(path, st.health.outages())
    assert [(o["link"], o["pair"], o["duration_s"]) for o in d["outages"]] == [
        (o.link, o.pair, o.duration_ns / NS) for o in st.health.outages()]
    return outs, d["links"]


def same_outages(got: list[tuple], want: list[tuple]) -> None:
    """The same outages: count, links, open or not, start and duration within OUTAGE_TOLERANCE_S
    (``want`` the exact reference)."""
    assert len(got) == len(want), (got, want)
    for g, w in zip(got, want):
        assert (g[0], g[1], g[4]) == (w[0], w[1], w[4]), (g, w)
        assert abs(g[2] - w[2]) <= OUTAGE_TOLERANCE_S and abs(g[3] - w[3]) <= OUTAGE_TOLERANCE_S, (g, w)


def exported_outages(text: str) -> list[dict]:
    """The outage rows of `export --format jsonl --outages` (or `watch --json --outages`) as stats
    --json has them (no kind, src, dst), in its order."""
    rows = [x for x in map(json.loads, text.splitlines()) if x["kind"] == "outage"]
    return sorted(({k: v for k, v in x.items() if k not in ("kind", "src", "dst")} for x in rows),
                  key=lambda o: (o["start"], o["link"]))


def ingested_outages(dataset: Path, path: Path) -> list[tuple]:
    """The outages ingest wrote of the capture ``path``, as :func:`reference_outages` has them."""
    first = next(iter(read_records(path))).ts_ns
    rows = run_query(dataset, "SELECT conversation, pair, time_ns, duration_ns, open FROM outages "
                              f"WHERE capture = {_quoted(path)}").rows()
    return sorted((c, p, (t - first) / NS, n / NS, o) for c, p, t, n, o in rows)


def links_table_is_health(dataset: Path, path: Path) -> list[dict]:
    """ingest's links table of the capture ``path`` holds the per-second rows of `sharedlink
    health -o -` (asserted); those rows."""
    per_second = [json.loads(x) for x in run_cli("health", "-o", "-", path, check=True).stdout.splitlines()]
    rows = run_query(dataset, "SELECT conversation, pair, time_ns // 1000000000, frames, state, quality, down_s "
                              f"FROM links WHERE capture = {_quoted(path)} ORDER BY conversation, pair, time_ns").rows()
    assert [tuple(r) for r in rows] == [(s["link"], s["pair"], s["second"], s["frames"], s["state"], s["quality"],
                                         s["down_s"]) for s in sorted(per_second, key=lambda s: (s["link"], s["pair"]))]
    return per_second


def _quoted(path: Path) -> str:
    return "'%s'" % str(path).replace("'", "''")


def health_tap(path: Path, prefs: dict | None = None, robots: bool = False) -> tuple[list[tuple], dict[tuple, list[str]], str]:
    """The -z sharedlink,stats tap (with serial.lua, and the robot dissectors if ``robots``): its
    outages (as :func:`reference_outages`), link rows, and text (Expert Information's too)."""
    scripts = [*(ROBOTS if robots else []), SERIAL, STATS]
    res = tu.tshark(path, ["-q", *(a for s in scripts for a in ("-X", f"lua_script:{s}")), "-z", "sharedlink,stats",
                           "-z", "expert"], prefs=prefs)
    text = res.stdout
    outs, links = tap_tables(text)
    return outs, links, text


def tap_tables(text: str) -> tuple[list[tuple], dict[tuple, list[str]]]:
    """The outages (link, pair, start, duration, open) and the link rows of the -z sharedlink,stats
    tap's text."""
    links: dict[tuple, list[str]] = {}
    outs = []
    section = None
    for line in text.splitlines():
        if line in ("Link health",) or line.startswith("Outages ("):
            section = line[:7]
            continue
        if not line.startswith("  ") or section is None:
            section = None if not line.startswith("  ") else section
            continue
        cols = re.split(r"\s{2,}", line.strip())
        if cols[0] == "Link" or cols[0].startswith("Note:"):
            continue
        if section == "Link he":
            links[(cols[0], cols[1].replace(ARROW, ">"))] = cols[2:]
        else:
            outs.append((cols[0], cols[1].replace(ARROW, ">"), float(cols[2]), float(cols[3]), cols[-1] == "(open)"))
    return sorted(outs), links
