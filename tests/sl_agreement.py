"""The two decoders' frames side by side, for the tests that compare them (test_agreement*.py):
the dissector's (tshark -T json, two passes) and Python's (iter_decoded), each reduced to the
same comparable shape, and the limit sessions' capture builders (an OCU and a vehicle on UDP)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded, parse_variables
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import NS, PcapWriter, read_records
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
    packets = tu.json_packets(cap, prefs=prefs, two_pass=True, extra=extra)
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


# -- link health (issue 43): the outages of stats and of the -z sharedlink,stats tap ------------

CLI = [sys.executable, "-m", "sharedlink"]
REPO = Path(__file__).resolve().parents[1]
STATS = REPO / "dissector" / "sharedlink_stats.lua"
SERIAL = REPO / "dissector" / "serial.lua"
ARROW = "\u2192"


def python_outages(path: Path, *extra: object) -> tuple[list[tuple], list[dict]]:
    """stats --json's links, and its outages (from the same run's integer-ns figures): link, pair,
    start in seconds from the first record, duration, open."""
    r = subprocess.run([*CLI, "stats", "--json", str(path), *map(str, extra)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    st = capture_stats(path, outage_after=float(extra[1]) if extra else None)
    first = next(iter(read_records(path))).ts_ns
    outs = sorted((o.link, o.pair, (o.start_ns - first) / NS, o.duration_ns / NS, o.end_ns is None)
                  for o in st.health.outages())
    assert [(o["link"], o["pair"], o["duration_s"]) for o in d["outages"]] == [
        (o.link, o.pair, o.duration_ns / NS) for o in st.health.outages()]
    return outs, d["links"]


def same_outages(got: list[tuple], want: list[tuple]) -> None:
    """The same outages: count, links, open or not, start and duration to the microsecond."""
    assert len(got) == len(want), (got, want)
    for g, w in zip(got, want):
        assert (g[0], g[1], g[4]) == (w[0], w[1], w[4])
        assert abs(g[2] - w[2]) <= 0.6e-6 and abs(g[3] - w[3]) <= 0.6e-6, (g, w)


def health_tap(path: Path, prefs: dict | None = None) -> tuple[list[tuple], dict[tuple, list[str]], str]:
    res = tu.tshark(path, ["-q", "-X", f"lua_script:{SERIAL}", "-X", f"lua_script:{STATS}", "-z", "sharedlink,stats",
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
