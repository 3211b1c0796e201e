"""The shared vector table (tests/vectors/sharedlink.json, issue 12) through the Python decoder.

Each stream is written as a real capture (tests/sl_vectors.py) and read back with
:func:`sharedlink.analysis.decode.iter_decoded`, the reader stats, export and plot use; every
SharedLink frame of every packet is compared with the table: kind, checksum verdict, the
variables it shows (name, index, value, type, typed value, carried, carried-from, bad value),
the experts Python models (sync.late, reply.unmatched, var.badvalue, malformed, unknown and
empty fields) and request/response links. The tshark side reads the same table in
tests/dissector/test_vectors.py.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from sl_vectors import load_streams, stream_params, write_stream

from sharedlink.analysis.decode import Decoded, iter_decoded, parse_variables
from sharedlink.capture.stream import StreamFrame
from sharedlink.protocols.codec import TYPE_NAMES
from sharedlink.protocols.state import BEACON_VARIABLES, Update

STREAMS = load_streams()
CHECKSUM_WORD = {True: "good", False: "bad", None: "missing"}


def decoded_frames(path: Path, variables: str | None) -> dict[int, list[Decoded | StreamFrame]]:
    """Packet number -> its SharedLink frames in order: :class:`Decoded`, or the noise
    :class:`StreamFrame` of a malformed frame (a ``[:`` that is no frame; the core gives a
    :class:`Decoded` of kind ``malformed`` for it)."""
    # no list in the stream: Python's default (BEACON_VARIABLES, the four beacon names typed
    # double), the same as the dissector's preference's default (issue 29)
    vs = parse_variables(variables) if variables else list(BEACON_VARIABLES)
    out: dict[int, list[Decoded | StreamFrame]] = {}
    for item in iter_decoded(path, vs):
        if isinstance(item, Decoded):
            out.setdefault(item.number, []).append(item)
        elif isinstance(item, StreamFrame) and item.raw.startswith(b"[:"):
            out.setdefault(item.number, []).append(item)
    return out


def shown_var(d: Decoded, u: Update, named: bool) -> dict[str, Any]:
    """One shown variable in the table's terms. A carried named variable has no type (the
    frame has no T for it), as the dissector shows it."""
    type_code = None if (named and u.carried) else u.type_code
    tname = TYPE_NAMES.get(type_code) if type_code is not None else None
    typed = None if tname is None or u.bad or u.text is None else u.value
    out = {
        "name": u.name,
        "index": u.index,
        "type": tname,
        "typed": typed,
        "carried": u.carried,
        "carried_from": u.carried_from,
        "bad": u.bad,
    }
    if u.text is not None:
        out["value"] = u.text
    return out


def experts(d: Decoded | StreamFrame) -> set[str]:
    if isinstance(d, StreamFrame) or d.kind == "malformed":
        return {"sharedlink.malformed"}
    out = set()
    if d.late:
        out.add("sharedlink.sync.late")
    if d.kind == "reply" and d.response_to is None:
        out.add("sharedlink.reply.unmatched")
    if any(u.bad and not u.carried for u in d.shown):
        out.add("sharedlink.var.badvalue")
    for dev in d.frame.deviations:
        if dev.startswith("unknown field letter"):
            out.add("sharedlink.field.unknown")
        elif dev.startswith("empty field"):
            out.add("sharedlink.field.empty")
    return out


MODELLED = {
    "sharedlink.sync.late",
    "sharedlink.reply.unmatched",
    "sharedlink.var.badvalue",
    "sharedlink.malformed",
    "sharedlink.field.unknown",
    "sharedlink.field.empty",
}


@pytest.mark.parametrize("stream", stream_params(STREAMS, "python"))
def test_python_decoder_follows_the_vectors(stream, tmp_path):
    ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
    path = write_stream(stream, tmp_path / f"s.{ext}")
    got = decoded_frames(path, stream.get("variables"))
    response_in: dict[int, int] = {}
    for frames in got.values():
        for d in frames:
            if isinstance(d, Decoded) and d.response_to is not None:
                response_in[d.response_to] = d.number
    for n, packet in enumerate(stream["packets"], 1):
        frames = got.get(n, [])
        where = f"{stream['name']} packet {n}"
        assert len(frames) == len(packet["frames"]), (where, [getattr(f, "kind", "malformed") for f in frames])
        for k, (d, want) in enumerate(zip(frames, packet["frames"])):
            at = f"{where} frame {k}"
            kind = "malformed" if isinstance(d, StreamFrame) else d.kind
            assert kind == want["kind"], at
            ex = experts(d)
            for e in want.get("experts", []):
                if e in MODELLED:
                    assert e in ex, (at, e)
            for e in want.get("no_experts", []):
                assert e not in ex, (at, e)
            if isinstance(d, StreamFrame) or d.kind == "malformed":
                continue
            if "checksum" in want:
                assert CHECKSUM_WORD[d.checksum_ok] == want["checksum"], at
            if "response_to" in want:
                assert d.response_to == want["response_to"], at
            if "response_in" in want:
                assert response_in.get(d.number) == want["response_in"], at
            if "vars" in want:
                # (a bare N shows named values only: the named form's, when its direction's is named)
                named = any(f.letter == "Q" for f in d.frame.fields) or not any(f.letter == "D" for f in d.frame.fields)
                shown = sorted(d.shown, key=lambda u: (u.index is None, u.index or 0))
                assert [u.name for u in shown] == [v["name"] for v in want["vars"]], at
                for u, wv in zip(shown, want["vars"]):
                    sv = shown_var(d, u, named)
                    for key, value in wv.items():
                        assert sv.get(key) == value, (at, u.name, key, sv.get(key), value)
