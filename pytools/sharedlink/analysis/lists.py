"""Vehicle profiles: every list declaration of a capture (``sharedlink lists``, issue 29).

A declaration (``N``k or ``L``k, then ``T``/``Q`` pairs, no ``D``) names the positional values
of one direction: ``N`` the sender's own (``A>B`` for a frame from A to B), ``L`` the sender's
inbound list, the reverse direction's (``B>A``). This module finds them all, per node pair in
capture order, and the list each pair has at the end, in the per-pair syntax of
:mod:`sharedlink.protocols.varlists` (the variables preference and ``--variables``), so a list
learnt from one capture names another. As in the decoding rules (docs/fields-sharedlink.md),
a declaration with a bad checksum is reported but changes no list, one at ordinal k > 0 keeps
the slots before k (``#i`` where nothing named them) and replaces the rest, and a type other
than 0, 2, 4 leaves its name untyped.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedlink.capture.pcapio import CaptureError
from sharedlink.capture.stream import StreamFrame, iter_frames
from sharedlink.protocols.codec import Frame, declared_list
from sharedlink.protocols.varlists import MAX_SLOTS, TYPES, format_list, format_varlists

#: declarations kept for the report per capture; past it they still change the lists, and are
#: counted (``omitted``), not kept (a capture of nothing but declarations stays bounded)
MAX_LISTED = 65536
#: characters the list syntax cannot carry in a name (its separators, line ends)
_UNWRITABLE = set(",;:>\r\n")

Names = tuple[tuple[str, int | None], ...]


@dataclass(frozen=True)
class Declaration:
    """One declaration frame of a capture."""

    number: int  # record number (1-based, as Wireshark counts frames)
    ts_ns: int
    pair: str  # the direction whose list it declares, "B>A" (from B to A)
    letter: str  # "N" (the sender's outbound list) or "L" (its inbound list)
    ordinal: int
    names: Names  # as declared: (name, T code or None)
    src: str  # "10.0.0.1:4104", or "serial inbound"
    dst: str
    checksum: str  # "good", "bad" or "missing"
    applied: bool  # False: bad checksum, or an ordinal past the limit; the pair's list unchanged
    result: Names  # the pair's list after it
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.number,
            "ts_ns": self.ts_ns,
            "pair": self.pair,
            "field": self.letter,
            "ordinal": self.ordinal,
            "src": self.src,
            "dst": self.dst,
            "checksum": self.checksum,
            "applied": self.applied,
            "names": [{"name": n, "type": t} for n, t in self.names],
            "list": [{"name": n, "type": t} for n, t in self.result],
            "notes": list(self.notes),
        }


@dataclass
class CaptureLists:
    """The declarations of one capture and the list of each pair at its end."""

    path: str
    declarations: list[Declaration] = field(default_factory=list)
    lists: dict[str, Names] = field(default_factory=dict)
    error: str | None = None  # the capture is damaged: what was found before it is above
    omitted: int = 0  # declarations past MAX_LISTED: applied, not kept

    def by_pair(self) -> dict[str, list[Declaration]]:
        out: dict[str, list[Declaration]] = {}
        for d in self.declarations:
            out.setdefault(d.pair, []).append(d)
        return out

    def variables(self) -> str:
        """The lists at the end in the per-pair syntax (``""`` when there is none)."""
        return format_varlists(self.lists)

    def to_dict(self) -> dict[str, Any]:
        return {
            "capture": self.path,
            "declarations": [d.to_dict() for d in self.declarations],
            "lists": {p: [{"name": n, "type": t} for n, t in names] for p, names in self.lists.items()},
            "variables": self.variables(),
            "omitted": self.omitted,
            "error": self.error,
        }


def _endpoint(sf: StreamFrame, which: str) -> str:
    proto, src, sport, dst, dport = sf.conv
    if proto == "serial":
        return f"serial {src}" if which == "src" else "serial"
    host, port = (src, sport) if which == "src" else (dst, dport)
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _checksum_word(frame: Frame) -> str:
    ok = frame.checksum.ok if frame.checksum is not None else None
    return {True: "good", False: "bad", None: "missing"}[ok]


def _writable(name: str) -> bool:
    return bool(name) and name == name.strip() and not _UNWRITABLE.intersection(name)


def _apply(before: Names, ordinal: int, names: Sequence[tuple[str, int | None]]) -> Names:
    keep = list(before[:ordinal]) + [(f"#{i}", None) for i in range(len(before), ordinal)]
    new = [(n if _writable(n) else f"#{ordinal + i}", t if t in TYPES else None) for i, (n, t) in enumerate(names)]
    return tuple(keep + new)


def capture_lists(path: str | Path) -> CaptureLists:
    """Every declaration of the capture, in order, and each pair's list at the end. A damaged
    capture gives what was found before the damage, with ``error`` set."""
    out = CaptureLists(str(path))
    try:
        for item in iter_frames(path):
            if isinstance(item, StreamFrame) and item.frame is not None:
                _take(out, item, item.frame)
    except CaptureError as exc:
        out.error = str(exc)
    return out


def _take(out: CaptureLists, sf: StreamFrame, frame: Frame) -> None:
    decl = declared_list(frame.fields)  # (the codec's parser: the decoder's rule)
    if decl is None:
        return
    letter, ordinal, names = decl
    pair = f"{frame.src}>{frame.dst}" if letter == "N" else f"{frame.dst}>{frame.src}"
    checksum = _checksum_word(frame)
    notes = [f"type T{t} of {n} is not 0, 2 or 4: untyped" for n, t in names if t is not None and t not in TYPES]
    notes += [f"name {n!r} cannot be written in a list: shown as #{ordinal + i}"
              for i, (n, _) in enumerate(names) if not _writable(n)]
    applied = checksum != "bad"
    if not applied:
        notes.append("bad checksum: not applied")
    if ordinal >= MAX_SLOTS:
        notes.append(f"Limit exceeded: ordinal {ordinal} (max {MAX_SLOTS - 1}): not applied")
        applied = False
    elif ordinal + len(names) > MAX_SLOTS:
        notes.append(f"Limit exceeded: {ordinal + len(names)} slots (max {MAX_SLOTS}): the names past it dropped")
        names = names[: MAX_SLOTS - ordinal]
    before = out.lists.get(pair, ())
    result = _apply(before, ordinal, names) if applied else before
    if applied:
        out.lists[pair] = result
    if len(out.declarations) >= MAX_LISTED:
        out.omitted += 1
        return
    out.declarations.append(Declaration(
        sf.number, sf.ts_ns, pair, letter, ordinal, tuple(names), _endpoint(sf, "src"), _endpoint(sf, "dst"),
        checksum, applied, result, tuple(notes),
    ))


def render_text(results: Iterable[CaptureLists]) -> str:
    """Per capture: each pair's declarations in order (a comment line, then the pair's list
    after it), then the lists at the end on one line. The whole text is valid input for
    :func:`sharedlink.protocols.varlists.parse_varlists` (declarations not applied are
    comments) and reads as the lists at the end of the last capture."""
    lines: list[str] = []
    for res in results:
        n = len(res.declarations) + res.omitted
        pairs = res.by_pair()
        if not n:
            lines.append(f"# {res.path}: no declarations")
            continue
        lines.append(f"# {res.path}: {n} declaration{'s' if n != 1 else ''}, {len(pairs)} node pair{'s' if len(pairs) != 1 else ''}")
        if res.omitted:
            lines.append(f"# Limit exceeded: only the first {len(res.declarations)} are listed; the "
                         f"{res.omitted} after them are in the lists at the end")
        for pair, decls in pairs.items():
            for d in decls:
                lines.append(
                    f"# frame {d.number}: {d.letter}{d.ordinal} from {d.src} to {d.dst}, {len(d.names)} "
                    f"name{'s' if len(d.names) != 1 else ''}, checksum {d.checksum}"
                )
                lines += [f"#   {note}" for note in d.notes]
                text = f"{pair}: {format_list(d.result)}" if d.result else ""
                if d.applied:
                    lines.append(text)
                elif text:
                    lines.append(f"#   (the list stays) {text}")
        if res.lists:
            lines.append("# the lists at the end (for the sharedlink.variables preference or --variables):")
            lines.append(res.variables())
    return "\n".join(lines) + "\n"
