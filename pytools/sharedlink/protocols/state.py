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

Bounds (:mod:`sharedlink.protocols.limits`): a slot at or past ``MAX_SLOTS`` (a value or a
declared name) and a new name past ``MAX_NAMES`` in one direction are dropped and counted in
the table's :class:`~sharedlink.protocols.limits.LimitCounts` (shared by a :class:`LinkState`),
never allocated; so no frame costs more than its own size plus the bounded table.
"""

from __future__ import annotations

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
from sharedlink.protocols.limits import MAX_CONVERSATIONS, MAX_NAMES, MAX_SLOTS, LimitCounts

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
    #: (text, type code, value) of the last :attr:`value` asked: rows of a carried value ask again
    _typed: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def value(self) -> int | float | str | None:
        text, tc = self.text, self.type_code
        c = self._typed
        if c is not None and c[0] is text and c[1] == tc:
            return c[2]
        if text is None:
            x: int | float | str | None = None
        elif tc is None:
            x = guess_value(text)
        else:
            x = parse_typed(tc, text)[0]
        self._typed = (text, tc, x)
        return x


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
    limits: LimitCounts = field(default_factory=LimitCounts)  # input dropped at a bound (shared by a LinkState)
    slot_of: dict[str, int] = field(default_factory=dict)  # name -> its first slot in ``names``
    _shown: dict[str, Variable] | None = field(default=None, repr=False, compare=False)  # preview's values

    @classmethod
    def with_list(cls, names: Sequence[tuple[str, int | None]] | Sequence[str]) -> VariableTable:
        t = cls()
        t.declare(0, [(n, None) if isinstance(n, str) else n for n in names])
        return t

    def declare(self, ordinal: int, names: Sequence[tuple[str, int | None]]) -> None:
        """Install a declared list (or part of one, from ``ordinal``). Each declared name
        takes the type declared with it: a name declared without ``T`` is untyped, whatever
        an earlier list (this conversation's, the letter pair's or the a-priori one) said.
        Slots at or past ``MAX_SLOTS`` are dropped (counted in ``limits.slots``)."""
        room = MAX_SLOTS - ordinal
        if room < len(names):
            self.limits.slots += len(names) - max(room, 0)
            if room <= 0:
                return
            names = names[:room]
        if ordinal > len(self.names):
            self.names.extend(f"var{i}" for i in range(len(self.names), ordinal))
        del self.names[ordinal:]
        for name, type_code in names:
            self.names.append(name)
            v = self._var(name, type_code)
            if v is None:
                continue  # past MAX_NAMES: the slot keeps its name, no variable is made
            if type_code is not None:
                self.types[name] = type_code
            else:
                self.types.pop(name, None)
            v.type_code = type_code
        slot_of: dict[str, int] = {}
        for i, n in enumerate(self.names):
            slot_of.setdefault(n, i)
        self.slot_of = slot_of

    def _var(self, name: str, type_code: int | None = None) -> Variable | None:
        """The variable ``name`` (made when new); None for a new name past ``MAX_NAMES``."""
        v = self.vars.get(name)
        if v is None:
            if len(self.vars) >= MAX_NAMES:
                self.limits.names += 1
                return None
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
            sent = self.sent_names
            # every name sent before is present: count the frame's names that were (linear in the frame)
            present = {nv.name for nv in named_values(fields)}
            return "full" if sum(1 for n in present if n in sent) == len(sent) else "delta"
        ordinal, vals = positional_values(fields)
        if frame_ordinal(fields) != 0 or not vals:
            return "delta"  # a bare N0 stays a delta with no change
        n = len(vals)
        return "full" if all(i < n and vals[i] is not None for i in self.filled) else "delta"

    def preview(self, frame: Frame, number: int = 0, time_ns: int = 0, carried: bool = True) -> list[Update]:
        """What :meth:`apply` would return, leaving the table as it is (for frames whose
        checksum failed: their values are shown as sent, nothing is stored). Costs what the
        frame holds plus the carried values, never a copy of the table."""
        return self._apply(frame, number, time_ns, carried, False)

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0, carried: bool = True) -> list[Update]:
        """Apply a frame; return the value of every variable it concerns (for value frames:
        every known variable, carried ones marked; with ``carried`` False a named frame's
        carried values are left out: the caller pays only for what the frame holds)."""
        return self._apply(frame, number, time_ns, carried, True)

    def _apply(self, frame: Frame, number: int, time_ns: int, carried: bool, store: bool) -> list[Update]:
        self._shown = None if store else {}  # a preview: the values shown so far, over the table
        kind = self.kind(frame)
        fields = frame.fields
        if kind == "declaration":
            decl = declared_list(fields)
            if store and decl is not None and decl[0] == "N":
                self.declare(decl[1], decl[2])
            return []
        if kind == "reply":
            return [u for nv in named_values(fields) if (u := self._value(nv.name, nv.type_code, nv.text, number, time_ns,
                                                                           None, store)) is not None]
        if kind not in ("full", "delta"):
            return []
        bare = not any(f.letter == "D" for f in fields)  # a bare N0: the direction's form, no change
        if any(f.letter == "Q" for f in fields) or (bare and self.named):
            updates = self._named(fields, number, time_ns, carried, store)
        else:
            updates = self._positional(fields, number, time_ns, store)
        if kind == "full" and store:
            self.last_full_at, self.last_full_in = time_ns, number
        return updates

    def _named(self, fields: Sequence, number: int, time_ns: int, carried: bool, store: bool) -> list[Update]:
        if store:
            self.named = True
        updates: list[Update] = []
        seen: set[str] = set()
        sent = self.sent_names if store else dict(self.sent_names)  # (a preview: positions new names would take)
        for nv in named_values(fields):
            seen.add(nv.name)
            pos = sent.get(nv.name)
            if pos is None:
                if store and nv.name not in self.vars and len(self.vars) >= MAX_NAMES:
                    self.limits.names += 1
                    continue
                pos = sent[nv.name] = len(sent)
            if store and nv.name not in self.names and nv.type_code is not None:
                self.types.setdefault(nv.name, nv.type_code)
            u = self._value(nv.name, nv.type_code, nv.text, number, time_ns, pos, store)
            if u is not None:
                updates.append(u)
        if carried:
            for name, v in self.vars.items():
                if name not in seen and v.text is not None:
                    updates.append(_update(v, sent.get(name, self._index(name)), True, v.set_in, False))
        return updates

    def _positional(self, fields: Sequence, number: int, time_ns: int, store: bool) -> list[Update]:
        if store:
            self.named = False
        updates: list[Update] = []
        ordinal, vals = positional_values(fields)
        for i, text in enumerate(vals):
            idx = ordinal + i
            if idx >= MAX_SLOTS:
                if store:
                    self.limits.slots += len(vals) - i
                break
            name = self.name_at(idx)
            if name is None:
                name = f"var{idx}"
                if store:
                    self.declare(len(self.names), [(f"var{j}", None) for j in range(len(self.names), idx + 1)])
            if text is None:
                v = ((self._shown or {}).get(name) or self.vars.get(name)
                     or (self._var(name) if store else Variable(name, self.types.get(name))))
                if v is not None:
                    updates.append(_update(v, idx, True, v.set_in, False))
                continue
            if store:
                self.filled.add(idx)
            u = self._value(name, None, text, number, time_ns, idx, store)
            if u is not None:
                updates.append(u)
        return updates

    def _value(self, name: str, type_code: int | None, text: str, number: int, time_ns: int, index: int | None,
               store: bool) -> Update | None:
        """Set (or, not ``store``, show) one value; None when the name is past ``MAX_NAMES``."""
        if store:
            v = self._var(name, type_code)
            if v is None:
                return None
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, time_ns
        else:
            shown = self._shown
            assert shown is not None
            old = shown.get(name) or self.vars.get(name)
            tc = type_code if type_code is not None else (old.type_code if old is not None else self.types.get(name))
            changed = (old.text if old is not None else None) != text
            v = shown[name] = Variable(name, tc, text, number, time_ns)
        return _update(v, self._index(name) if index is None else index, False, None, changed)

    def _index(self, name: str) -> int | None:
        return self.slot_of.get(name)


@dataclass
class LinkState:
    """Variable tables for every direction seen on a link, keyed by a conversation key
    (addresses and ports, or a serial direction: see :func:`conversation_key`) plus the
    (src, dst) letters. A list learnt from a declaration is also remembered for the letter
    pair alone and used by a new conversation of those letters (as the dissector does)."""

    default_list: Sequence[tuple[str, int | None]] = BEACON_VARIABLES
    tables: dict[tuple[object, str, str], VariableTable] = field(default_factory=dict)
    pair_lists: dict[tuple[str, str], list[tuple[str, int | None]]] = field(default_factory=dict)
    limits: LimitCounts = field(default_factory=LimitCounts)  # input dropped at a bound, every table's

    def table(self, src: str, dst: str, conv: Hashable = None) -> VariableTable:
        """The table of a direction (made when new). Past ``MAX_CONVERSATIONS`` directions a
        new one gets a fresh table that is not kept (counted in ``limits.conversations``):
        its frames are decoded on their own, with no state before them."""
        key = (conv, src, dst)
        t = self.tables.get(key)
        if t is None:
            t = VariableTable.with_list(list(self.default_list))
            t.limits = self.limits
            t.list_from = self.default_list
            if len(self.tables) >= MAX_CONVERSATIONS:
                self.limits.conversations += 1
            else:
                self.tables[key] = t
        if t.list_from is not None and self.pair_lists:
            shared = self.pair_lists.get((src, dst))
            if shared is not None and t.list_from is not shared:
                t.declare(0, shared)  # a list declared on another conversation of these letters
                t.list_from = shared
        return t

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0, conv: Hashable = None,
              carried: bool = True) -> list[Update]:
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
        return self.table(frame.src, frame.dst, conv).apply(frame, number, time_ns, carried)


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
