"""Stream state: the shared-variable table that frames update, in order.

One :class:`VariableTable` per direction of a conversation (see :class:`LinkState`). It learns
variable lists from declaration frames, names and types positional values from them, carries
elided values forward (compression) and remembers which frame last set each variable. gen,
diff, compress, expand and the decoder all use it. The rules are the dissector's
(``docs/fields-sharedlink.md``, "Decoding rules"):

* a positional frame is full when its ordinal is 0 and every *required* slot has a non-empty
  ``D``; a slot is required once a frame of this direction gave it a value, so a sender that
  leaves never-filled slots empty still sends full sets;
* a named frame is full when its ordinal is 0 (or absent) and it carries every name the
  direction has sent before in a named frame; an empty ``D`` in a triplet is an empty value;
* a positional value is typed by the declared list (``T`` before ``Q``) or the a-priori list;
  text that does not fit its type stays text, flagged ``bad``;
* ``L?`` / ``N?`` are queries and leave the learnt list alone.

The caller keeps frames with a bad checksum away from :meth:`VariableTable.apply` (they may
be shown with :meth:`VariableTable.preview`, which changes nothing).
"""

from __future__ import annotations

import copy
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from sharedlink.protocols.codec import (
    TYPE_NAMES,
    Frame,
    declared_list,
    frame_kind,
    frame_ordinal,
    guess_value,
    named_values,
    parse_typed,
    positional_values,
)

#: The beacon's variables (BUL-009), used when no list is given or learnt.
BEACON_VARIABLES: tuple[tuple[str, int], ...] = (
    ("AutoGpsLat", 2),
    ("AutoGpsLon", 2),
    ("AutoGpsHead", 2),
    ("AutoGpsVel", 2),
)

_TYPE_HELP = ", ".join(f"{code} {name}" for code, name in TYPE_NAMES.items())


def parse_variables(text: str) -> list[tuple[str, int | None]]:
    """A variable list as ``--variables`` gives it, ``"Lat:2,Lon:2,Name:4,Count"`` ->
    ``[("Lat", 2), ("Lon", 2), ("Name", 4), ("Count", None)]``: the a-priori outbound list
    positional frames are named by (type codes as in ``T`` fields: 0 long, 2 double, 4 string;
    none given, or an empty one, = guessed from the text). Empty items are skipped
    (``"A:2,B,"`` is ``A`` and ``B``). Raises ValueError on a bad name or type, or no name at all.
    The one parser of such lists: every command and library function uses it."""
    out: list[tuple[str, int | None]] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        name, _, type_text = part.partition(":")
        if not name or any(c in name for c in "|[]"):
            raise ValueError(f"bad variable name {name!r}")
        try:
            out.append((name, int(type_text) if type_text else None))
        except ValueError:
            raise ValueError(f"bad type {type_text!r} for {name} ({_TYPE_HELP})") from None
    if not out:
        raise ValueError("empty variable list")
    return out


@dataclass
class Variable:
    name: str
    type_code: int | None = None
    text: str | None = None
    set_in: int | None = None  # frame number that last carried the value
    set_at: int | None = None  # its timestamp (ns)

    @property
    def value(self) -> int | float | str | None:
        if self.text is None:
            return None
        if self.type_code is None:
            return guess_value(self.text)
        return parse_typed(self.type_code, self.text)[0]


class Update(NamedTuple):
    """One variable's value as a frame leaves it (immutable; a NamedTuple, not a frozen
    dataclass: made several times per frame, and a frozen dataclass takes 2.4 µs to build
    against 0.4 µs, measured in the watch's hot path)."""

    name: str
    index: int | None  # positional: the slot; named: the name's position in the direction's names (first appearance)
    text: str | None
    carried: bool  # value not in this frame, carried forward
    carried_from: int | None  # frame number the value came from, when carried
    changed: bool  # differs from the value before this frame
    type_code: int | None = None  # declared (or a-priori) type, None: untyped
    bad: bool = False  # the text does not fit its type (``sharedlink.var.badvalue``)

    @property
    def value(self) -> int | float | str | None:
        """The value by its type (text when untyped or bad)."""
        return None if self.text is None else parse_typed(self.type_code, self.text)[0]


def _update(
    v: Variable, index: int | None, carried: bool, carried_from: int | None, changed: bool
) -> Update:
    text, tc = v.text, v.type_code
    bad = text is not None and not parse_typed(tc, text)[1]
    return Update(v.name, index, text, carried, carried_from, changed, tc, bad)


@dataclass
class VariableTable:
    """The variables of one direction of a conversation."""

    names: list[str] = field(default_factory=list)  # the positional (outbound) list
    types: dict[str, int | None] = field(default_factory=dict)
    vars: dict[str, Variable] = field(default_factory=dict)
    last_full_at: int | None = None
    last_full_in: int | None = None
    named: bool | None = None  # which form this direction uses, once seen
    filled: set[int] = field(default_factory=set)  # positional slots that have held a value
    sent_names: dict[str, int] = field(default_factory=dict)  # names sent in named data frames -> position
    list_from: object = None  # the letter pair's shared list in use, None once a list is declared here

    @classmethod
    def with_list(cls, names: Sequence[tuple[str, int | None]] | Sequence[str]) -> VariableTable:
        t = cls()
        t.declare(0, [(n, None) if isinstance(n, str) else n for n in names])
        return t

    def declare(self, ordinal: int, names: Sequence[tuple[str, int | None]]) -> None:
        """Install a declared list (or part of one, from ``ordinal``). Each declared name
        takes the type declared with it: a name declared without ``T`` is untyped, whatever
        an earlier list (this conversation's, the letter pair's or the a-priori one) said."""
        if ordinal > len(self.names):
            self.names.extend(f"var{i}" for i in range(len(self.names), ordinal))
        del self.names[ordinal:]
        for name, type_code in names:
            self.names.append(name)
            if type_code is not None:
                self.types[name] = type_code
            else:
                self.types.pop(name, None)
            self._var(name, type_code).type_code = type_code

    def _var(self, name: str, type_code: int | None = None) -> Variable:
        v = self.vars.get(name)
        if v is None:
            v = self.vars[name] = Variable(name, type_code if type_code is not None else self.types.get(name))
        elif type_code is not None:
            v.type_code = type_code
        return v

    def name_at(self, index: int) -> str | None:
        return self.names[index] if 0 <= index < len(self.names) else None

    def values(self) -> dict[str, str | None]:
        return {n: v.text for n, v in self.vars.items()}

    def kind(self, frame: Frame) -> str:
        """The frame's kind in this direction's context (the state before the frame)."""
        k = frame_kind(frame.fields)
        if k not in ("full", "delta"):
            return k
        fields = frame.fields
        if any(f.letter == "Q" for f in fields):
            if frame_ordinal(fields) != 0:
                return "delta"
            present = {nv.name for nv in named_values(fields)}
            return "full" if all(n in present for n in self.sent_names) else "delta"
        ordinal, vals = positional_values(fields)
        if frame_ordinal(fields) != 0 or not vals:
            return "delta"  # a bare N0 stays a delta with no change
        n = len(vals)
        return "full" if all(i < n and vals[i] is not None for i in self.filled) else "delta"

    def preview(self, frame: Frame, number: int = 0, time_ns: int = 0) -> list[Update]:
        """What :meth:`apply` would return, leaving the table as it is (for frames whose
        checksum failed: their values are shown as sent, nothing is stored)."""
        return copy.deepcopy(self).apply(frame, number, time_ns)

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0) -> list[Update]:
        """Apply a frame; return the value of every variable it concerns (for value frames:
        every known variable, carried ones marked)."""
        kind = self.kind(frame)
        fields = frame.fields
        updates: list[Update] = []
        if kind == "declaration":
            decl = declared_list(fields)
            if decl is not None and decl[0] == "N":
                self.declare(decl[1], decl[2])
            return updates
        if kind in ("full", "delta"):
            bare = not any(f.letter == "D" for f in fields)  # a bare N0: the direction's form, no change
            if any(f.letter == "Q" for f in fields) or (bare and self.named):
                self.named = True
                seen: set[str] = set()
                sent = self.sent_names
                for nv in named_values(fields):
                    seen.add(nv.name)
                    pos = sent.setdefault(nv.name, len(sent))
                    v = self._var(nv.name, nv.type_code)
                    if nv.name not in self.names and nv.type_code is not None:
                        self.types.setdefault(nv.name, nv.type_code)
                    u = self._set(v, nv.text, number, time_ns)
                    updates.append(_update(v, pos, False, None, u.changed))
                for name, v in self.vars.items():
                    if name not in seen and v.text is not None:
                        updates.append(_update(v, sent.get(name, self._index(name)), True, v.set_in, False))
            else:
                self.named = False
                ordinal, vals = positional_values(fields)
                for i, text in enumerate(vals):
                    idx = ordinal + i
                    name = self.name_at(idx)
                    if name is None:
                        name = f"var{idx}"
                        self.declare(len(self.names), [(f"var{j}", None) for j in range(len(self.names), idx + 1)])
                    v = self._var(name)
                    if text is None:
                        updates.append(_update(v, idx, True, v.set_in, False))
                    else:
                        self.filled.add(idx)
                        u = self._set(v, text, number, time_ns)
                        updates.append(_update(v, idx, False, None, u.changed))
            if kind == "full":
                self.last_full_at, self.last_full_in = time_ns, number
            return updates
        if kind == "reply":
            for nv in named_values(fields):
                v = self._var(nv.name, nv.type_code)
                updates.append(self._set(v, nv.text, number, time_ns))
        return updates

    def _index(self, name: str) -> int | None:
        try:
            return self.names.index(name)
        except ValueError:
            return None

    def _set(self, v: Variable, text: str, number: int, time_ns: int) -> Update:
        changed = v.text != text
        v.text, v.set_in, v.set_at = text, number, time_ns
        return _update(v, self._index(v.name), False, None, changed)


@dataclass
class LinkState:
    """Variable tables for every direction seen on a link, keyed by a conversation key
    (addresses and ports, or a serial direction: see :func:`conversation_key`) plus the
    (src, dst) letters. A list learnt from a declaration is also remembered for the letter
    pair alone and used by a new conversation of those letters (as the dissector does)."""

    default_list: Sequence[tuple[str, int | None]] = BEACON_VARIABLES
    tables: dict[tuple[object, str, str], VariableTable] = field(default_factory=dict)
    pair_lists: dict[tuple[str, str], list[tuple[str, int | None]]] = field(default_factory=dict)

    def table(self, src: str, dst: str, conv: Hashable = None) -> VariableTable:
        key = (conv, src, dst)
        t = self.tables.get(key)
        if t is None:
            t = self.tables[key] = VariableTable.with_list(list(self.default_list))
            t.list_from = self.default_list
        if t.list_from is not None and self.pair_lists:
            shared = self.pair_lists.get((src, dst))
            if shared is not None and t.list_from is not shared:
                t.declare(0, shared)  # a list declared on another conversation of these letters
                t.list_from = shared
        return t

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0, conv: Hashable = None) -> list[Update]:
        decl = declared_list(frame.fields)
        if decl is not None:
            # N: the sender's outbound list; L: its inbound list, the reverse direction's
            src, dst = (frame.src, frame.dst) if decl[0] == "N" else (frame.dst, frame.src)
            rconv = conv if decl[0] == "N" else reverse_conversation(conv)
            t = self.table(src, dst, rconv)
            t.declare(decl[1], decl[2])
            t.list_from = None
            self.pair_lists[(src, dst)] = [(n, t.types.get(n)) for n in t.names]
            return []
        return self.table(frame.src, frame.dst, conv).apply(frame, number, time_ns)


def conversation_key(conv: tuple[str, str, int, str, int]) -> Hashable:
    """The state key of a :class:`~sharedlink.capture.stream.StreamFrame` 's ``conv``: UDP
    and TCP by addresses and ports (both directions of one conversation get mirrored keys),
    serial by capture direction and interface."""
    return conv


def reverse_conversation(conv: Hashable) -> Hashable:
    """The key of the opposite direction: source and destination swapped (serial: the other
    capture direction)."""
    if isinstance(conv, tuple) and len(conv) == 5:
        proto, src, sport, dst, dport = conv
        if proto == "serial":
            other = {"inbound": "outbound", "outbound": "inbound"}.get(str(src), src)
            return (proto, other, sport, dst, dport)
        return (proto, dst, dport, src, sport)
    return conv
