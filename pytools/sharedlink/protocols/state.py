"""Stream state: the shared-variable table that frames update, in order.

One :class:`VariableTable` per direction of a conversation (see :class:`LinkState`). It learns
variable lists from declaration frames, names and types positional values from them, carries
elided values forward (compression) and remembers which frame last set each variable. gen,
diff, compress, expand and the decoder all use it. The rules are the dissector's
(``docs/fields-sharedlink.md``, "Decoding rules", and "Rules for real sessions", issue 29,
which wins where they differ):

* a positional frame is full when its ordinal is 0 and every *required* slot has a non-empty
  ``D``; a slot is required once a frame of this direction gave it a value, so a sender that
  leaves never-filled slots empty still sends full sets;
* a named frame is full when its ordinal is 0 (or absent) and it carries every name the
  direction has sent before in a named frame; an empty ``D`` in a triplet is an empty value;
* a positional slot is named and typed by the list its direction uses (:class:`LinkState`):
  a declared one, one the user gave for the node pair, or the a-priori list of every pair, which
  names only frames with as many slots as it has; a slot no list names is ``#i``, untyped;
  text that does not fit its type stays text, flagged ``bad``;
* a new list replaces the old one: kept names keep their values (by name), dropped ones lose them;
* a bare ``N`` (no ``D``) is a delta in its direction's form (``VariableTable.named``, the last
  good data frame's): named, every name sent by name carried; positional (or none yet), nothing;
* a reply's values are shown, never stored;
* ``L?`` / ``N?`` are queries and leave the learnt list alone.

Replies and the list requests declarations answer are linked by :func:`link_response`
(per querier, whatever the answer's source port).

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
    Frame,
    declared_list,
    frame_kind,
    frame_ordinal,
    guess_value,
    named_values,
    parse_typed,
    positional_values,
    stray_values,
)
from sharedlink.protocols.limits import (
    MAX_CONVERSATIONS,
    MAX_NAMES,
    MAX_PENDING,
    MAX_PENDING_TOTAL,
    MAX_SLOTS,
    LimitCounts,
)
from sharedlink.protocols.varlists import flatten, parse_varlists, split

VarList = list[tuple[str, int | None]]

#: The beacon's variables (BUL-009), used when no list is given or learnt.
BEACON_VARIABLES: tuple[tuple[str, int], ...] = (
    ("AutoGpsLat", 2),
    ("AutoGpsLon", 2),
    ("AutoGpsHead", 2),
    ("AutoGpsVel", 2),
)

def parse_variables(text: str) -> list[tuple[str, int | None]]:
    """A variable list as ``--variables`` gives it, ``"Lat:2,Lon:2,Name:4,Count"`` ->
    ``[("Lat", 2), ("Lon", 2), ("Name", 4), ("Count", None)]``: the a-priori list positional
    frames of every pair are named by, when a frame has as many slots as it (type codes as in
    ``T`` fields: 0 long, 2 double, 4 string; none given, or an empty one, = untyped). Per-pair
    lists (``B>A: AutoGpsHead:2,...; A>B: ...``, :func:`sharedlink.protocols.varlists.parse_varlists`)
    come in the same flat list, their names as ``"B>A:AutoGpsHead"``
    (:func:`~sharedlink.protocols.varlists.flatten`); :class:`LinkState` takes them apart. Empty
    items are skipped (``"A:2,B,"`` is ``A`` and ``B``). Raises ValueError on a bad name or type,
    or no name at all. The one parser of such lists: every command and library function uses it."""
    return flatten(parse_varlists(text))


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


def placeholder(index: int) -> str:
    """The name of a slot no list names: ``#3`` (as the dissector shows it)."""
    return f"#{index}"


@dataclass(eq=False)
class VarSource:
    """A list positional frames are named by, as one object (a table notices a new list by
    identity): from a declaration, a list the user gave for the node pair, or the a-priori list
    of every pair (``by_length``: it names only a frame with as many slots as it has).
    docs/fields-sharedlink.md, "Rules for real sessions"."""

    names: tuple[tuple[str, int | None], ...]
    by_length: bool = False
    declared: bool = False  # learnt from a declaration: a slot past its end is ``Update.unknown``


@dataclass
class VariableTable:
    """The variables of one direction of a conversation."""

    names: list[str] = field(default_factory=list)  # a full set's slots: the list in use, then #i past it
    types: dict[str, int | None] = field(default_factory=dict)
    vars: dict[str, Variable] = field(default_factory=dict)
    last_full_at: int | None = None
    last_full_in: int | None = None
    named: bool | None = None  # which form this direction uses, once seen
    filled: set[int] = field(default_factory=set)  # positional slots that have held a value
    sent_names: dict[str, int] = field(default_factory=dict)  # names sent in named data frames -> position
    list_from: object = None  # the VarSource in use (LinkState's), None: a list given to the table itself
    limits: LimitCounts = field(default_factory=LimitCounts)  # input dropped at a bound (shared by a LinkState)
    slot_of: dict[str, int] = field(default_factory=dict)  # name -> its first slot in ``names``
    in_use: VarList = field(default_factory=list)  # the list in use, with its types
    by_length: bool = False  # the list names only frames with exactly len(list) slots (the a-priori list)
    unlisted: bool = False  # (by_length) the last positional frame had another length: ``names`` are #i
    own: VarSource | None = None  # the list this conversation declared itself (LinkState)
    declared: bool = False  # the list in use was learnt from a declaration (slots past it: past_list)
    #: the values the last apply or preview dropped at a limit (a slot past MAX_SLOTS, a new name
    #: past MAX_NAMES), as the frame shows them (never stored, never in the returned updates)
    dropped: list[Update] = field(default_factory=list, repr=False, compare=False)
    _shown: dict[str, Variable] | None = field(default=None, repr=False, compare=False)  # preview's values

    @classmethod
    def with_list(cls, names: Sequence[tuple[str, int | None]] | Sequence[str], by_length: bool = False
                  ) -> VariableTable:
        t = cls()
        t.use_list([(n, None) if isinstance(n, str) else n for n in names], by_length)
        return t

    def declare(self, ordinal: int, names: Sequence[tuple[str, int | None]]) -> None:
        """Install a declared list (or part of one, from ``ordinal``: the slots before it are
        kept): it replaces the list in use (:meth:`use_list`)."""
        self.use_list(extend_list(self.in_use, ordinal, names, self.limits), declared=True)

    def use_list(self, names: Sequence[tuple[str, int | None]], by_length: bool = False,
                 declared: bool = False) -> None:
        """Replace the list in use (docs/fields-sharedlink.md, "A declaration replaces its
        direction's list"). A name the new list keeps keeps its value, the frame it came from
        and its "once filled" mark, at its new slot (carrying is by name); a name it drops loses
        them (unless named frames send it); slots past its end no longer exist. Types belong to
        the list: each listed name takes the type given with it, untyped when none, whatever an
        earlier list said. Past ``MAX_SLOTS`` names are dropped (counted in ``limits.slots``)."""
        if len(names) > MAX_SLOTS:
            self.limits.slots += len(names) - MAX_SLOTS
            names = names[:MAX_SLOTS]
        old = self.names
        marked = {old[i] for i in self.filled if i < len(old)}
        self.in_use = list(names)
        self.by_length = by_length and bool(names)
        self.declared = declared
        self.unlisted = False
        keep = {n for n, _ in names}
        for n in [n for n in self.vars if n not in keep and n not in self.sent_names]:
            del self.vars[n]
            self.types.pop(n, None)
        for name, type_code in names:
            v = self._var(name, type_code)
            if type_code is not None:
                self.types[name] = type_code
            else:
                self.types.pop(name, None)
            if v is not None:
                v.type_code = type_code
        self._set_names([n for n, _ in names])
        self.filled = {i for i, n in enumerate(self.names) if n in marked}

    def _set_names(self, names: list[str]) -> None:
        self.names = names
        slot_of: dict[str, int] = {}
        for i, n in enumerate(names):
            slot_of.setdefault(n, i)
        self.slot_of = slot_of

    def slot_name(self, index: int, frame_slots: int) -> str:
        """The name of slot ``index`` in a positional frame of ``frame_slots`` slots (its ordinal
        plus its ``D`` fields): the list's, unless the list is the a-priori one and the frame
        has another length, or the slot is past the list: then :func:`placeholder`."""
        lst = self.in_use
        if index < len(lst) and not (self.by_length and frame_slots != len(lst)):
            return lst[index][0]
        return placeholder(index)

    def past_list(self, index: int) -> bool:
        """Whether positional slot ``index`` is past the end of a list learnt from a declaration
        (the sender sends more than it declared): the twin of the dissector's
        ``sharedlink.var.unknown``. Never past a user's or the a-priori list (those slots are
        ``#i`` with no warning: docs/fields-sharedlink.md, "Names from an a-priori list")."""
        return self.declared and index >= len(self.in_use)

    def _widen(self, frame_slots: int) -> None:
        """A positional frame of ``frame_slots`` slots was stored: ``names`` (a full set's slots)
        becomes the slots such a frame has, named as it names them: the a-priori list's names
        after a frame of its length, else ``#i`` over the widest such frame; a list that names
        every frame grows ``#i`` past its end."""
        names = self.names
        if self.by_length:
            if frame_slots == len(self.in_use):
                if self.unlisted:
                    self.unlisted = False
                    self._set_names([n for n, _ in self.in_use])
                return
            width = min(max(frame_slots, len(names) if self.unlisted else 0), MAX_SLOTS)
            if not self.unlisted or width != len(names):
                self.unlisted = True
                self._set_names([placeholder(i) for i in range(width)])
        elif frame_slots > len(names):
            width = min(frame_slots, MAX_SLOTS)
            self._set_names(names + [self.slot_name(i, width) for i in range(len(names), width)])

    def _var(self, name: str, type_code: int | None = None) -> Variable | None:
        """The variable ``name`` (made when new); None for a new name past ``MAX_NAMES``."""
        v = self.vars.get(name)
        if v is None:
            if len(self.vars) >= MAX_NAMES + MAX_SLOTS:  # (named names are bounded in _named, list names by MAX_SLOTS)
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
            _, strays = stray_values(fields)
            if strays:  # named values and positional slots: judged by its slots, as a positional frame
                top = max(i for i, _ in strays)
                empty = {i for i, t in strays if t is None}
                return "full" if all(i <= top and i not in empty for i in self.filled) else "delta"
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
        if self.dropped:
            self.dropped = []
        kind = self.kind(frame)
        fields = frame.fields
        if kind == "declaration":
            decl = declared_list(fields)
            if store and decl is not None and decl[0] == "N":
                self.declare(decl[1], decl[2])
            return []
        if kind == "reply":
            return self._reply(fields, number, time_ns)
        if kind not in ("full", "delta"):
            return []
        bare = not any(f.letter == "D" for f in fields)  # a bare N0: the direction's form, no change
        if any(f.letter == "Q" for f in fields) or (bare and self.named):
            # a D after a named value with no name of its own is the positional slot it stands at
            # (N0|QZ|D1|D2|D3: Z, then slots 1 and 2); such a frame shows what it holds, nothing
            # carried by name (docs/fields-sharedlink.md, "Values")
            frame_slots, strays = stray_values(fields) if not bare else (0, [])
            updates = self._named(fields, number, time_ns, carried and not strays, store)
            if strays:
                updates += self._slots(strays, frame_slots, number, time_ns, store)
        else:
            updates = self._positional(fields, number, time_ns, store)
        if kind == "full" and store:
            self.last_full_at, self.last_full_in = time_ns, number
        return updates

    def _reply(self, fields: Sequence, number: int, time_ns: int) -> list[Update]:
        """A reply's values, shown and never stored (docs/fields-sharedlink.md, disagreement 2:
        they change no carried value, no "once filled" mark, no list): typed by the ``T``
        before them, else by the list this direction uses."""
        out: list[Update] = []
        for nv in named_values(fields):
            old = self.vars.get(nv.name)
            tc = nv.type_code if nv.type_code is not None else self.types.get(nv.name)
            v = Variable(nv.name, tc, nv.text, number, time_ns)
            changed = (old.text if old is not None else None) != nv.text
            u = _update(v, self._index(nv.name), False, None, changed)
            out.append(u._replace(bad=True) if nv.bad_type else u)
        return out

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
                if store and len(sent) >= MAX_NAMES:
                    self.limits.names += 1
                    self._drop(nv.name, None, nv.text, nv.type_code, nv.bad_type)
                    continue
                pos = sent[nv.name] = len(sent)
            u = self._value(nv.name, nv.type_code, nv.text, number, time_ns, pos, store)
            if u is not None:
                updates.append(u._replace(bad=True) if nv.bad_type else u)  # "Type is not a number"
        if carried:  # the names this direction sent by name, in the order it sent them first
            for name, pos in sent.items():
                v = self.vars.get(name)
                if name not in seen and v is not None and v.text is not None:
                    updates.append(_update(v, pos, True, v.set_in, False))
        return updates

    def _positional(self, fields: Sequence, number: int, time_ns: int, store: bool) -> list[Update]:
        if store:
            self.named = False
        ordinal, vals = positional_values(fields)
        return self._slots([(ordinal + i, text) for i, text in enumerate(vals)], ordinal + len(vals), number, time_ns,
                           store)

    def _slots(self, slots: list[tuple[int, str | None]], frame_slots: int, number: int, time_ns: int,
               store: bool) -> list[Update]:
        """Positional values (slot, text; None: empty, carried) of a frame of ``frame_slots`` slots."""
        updates: list[Update] = []
        for i, (idx, text) in enumerate(slots):
            if idx >= MAX_SLOTS:
                if store:
                    self.limits.slots += len(slots) - i
                for j, past in slots[i:]:
                    self._drop(placeholder(j), j, past, None, False)
                break
            name = self.slot_name(idx, frame_slots)
            if text is None:
                v = ((self._shown or {}).get(name) or self.vars.get(name)
                     or (self._var(name) if store else Variable(name, self.types.get(name))))
                if v is not None:
                    updates.append(_update(v, idx, True, v.set_in, False))
                continue
            if store:
                self.filled.add(idx)
            u = self._value(name, self.types.get(name), text, number, time_ns, idx, store)
            if u is not None:
                updates.append(u)
        if store and slots:
            self._widen(frame_slots)
        return updates

    def _value(self, name: str, type_code: int | None, text: str, number: int, time_ns: int, index: int | None,
               store: bool) -> Update | None:
        """Set (or, not ``store``, show) one value of type ``type_code``; None when the name is
        past ``MAX_NAMES``. A value's type is what its frame gives it: a named value's the ``T``
        of its triplet (untyped without one, whatever an earlier triplet of the name said), a
        positional value's its list's (docs/fields-sharedlink.md, "Values")."""
        if store:
            v = self._var(name, type_code)
            if v is None:
                return None
            # a listed name's Variable keeps its list's type (what its positional values and the
            # fast paths read); a named value of it gets its triplet's type on its Update only
            v.type_code = self.types.get(name) if name in self.slot_of else type_code
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, time_ns
            if v.type_code != type_code:
                u = _update(v, self._index(name) if index is None else index, False, None, changed)
                return u._replace(type_code=type_code, bad=not parse_typed(type_code, text)[1])
        else:
            shown = self._shown
            assert shown is not None
            old = shown.get(name) or self.vars.get(name)
            tc = type_code
            changed = (old.text if old is not None else None) != text
            v = shown[name] = Variable(name, tc, text, number, time_ns)
        return _update(v, self._index(name) if index is None else index, False, None, changed)

    def _drop(self, name: str, index: int | None, text: str | None, type_code: int | None, bad_type: bool) -> None:
        """A value dropped at a limit, as its frame shows it (:attr:`dropped`): sent (an empty
        positional ``D``: carried with no value), never stored."""
        if text is None:
            self.dropped.append(Update(name, index, None, True, None, False))
            return
        bad = bad_type or not parse_typed(type_code, text)[1]
        self.dropped.append(Update(name, index, text, False, None, True, type_code, bad))

    def _index(self, name: str) -> int | None:
        return self.slot_of.get(name)


def extend_list(base: Sequence[tuple[str, int | None]], ordinal: int, names: Sequence[tuple[str, int | None]],
                limits: LimitCounts) -> VarList:
    """The list a declaration at ``ordinal`` makes of ``base``: its slots before ``ordinal``
    (``#i`` where it has none), then the declared names; past ``MAX_SLOTS`` dropped and
    counted in ``limits.slots``."""
    room = MAX_SLOTS - ordinal
    if room < len(names):
        limits.slots += len(names) - max(room, 0)
        names = names[:max(room, 0)]
        if room <= 0:
            return list(base[:MAX_SLOTS])
    head = list(base[:ordinal]) + [(placeholder(i), None) for i in range(len(base), ordinal)]
    return head + list(names)


def receiver_key(conv: Hashable, src: str, dst: str) -> Hashable:
    """The key of a direction's receiver: UDP/TCP by the two addresses and the letters, ports
    left out (a vehicle listens on 4000 and sends from 1033); serial and anything else by the
    whole conversation key and the letters."""
    if isinstance(conv, tuple) and len(conv) == 5 and conv[0] != "serial":
        return (conv[0], conv[1], conv[3], src, dst)
    return (conv, src, dst)


def ask_key(conv: Hashable, src: str, dst: str) -> Hashable:
    """Where the answer to a query or declaration sent on ``conv`` from ``src`` to ``dst``
    must go: the querier's address and port, the queried address, the letters. UDP/TCP only
    by those; serial (and anything else) by the conversation."""
    if isinstance(conv, tuple) and len(conv) == 5 and conv[0] != "serial":
        proto, saddr, sport, daddr, _dport = conv
        return (proto, saddr, sport, daddr, src, dst)
    return (conv, src, dst)


def answer_key(conv: Hashable, src: str, dst: str) -> Hashable:
    """The :func:`ask_key` a reply (or a declaration answering a list request) sent on
    ``conv`` from ``src`` to ``dst`` answers: it comes from the queried address and goes to the
    querier's address and port, whatever its source port."""
    if isinstance(conv, tuple) and len(conv) == 5 and conv[0] != "serial":
        proto, saddr, _sport, daddr, dport = conv
        return (proto, daddr, dport, saddr, dst, src)
    return (reverse_conversation(conv), dst, src)


class PendingAsks:
    """Unanswered queries, list requests and declarations, per querier (:func:`ask_key`), kept
    as the dissector keeps them (``state.lua``, ``ask``/``answered``): one entry per name asked
    (what it waits for and the name: ``("R", name)`` for a reply naming it, from a ``Q``
    query or a declaration; ``("N", "")`` for an ``N``k declaration, the answer to ``L?``;
    ``("L", "")`` for ``N?``), holding the frame that asked last. Asking again for a name
    that waits replaces it (a querier that polls one name holds one entry). At most
    ``MAX_PENDING`` entries a querier and ``MAX_PENDING_TOTAL`` in all (issue 44): a new one past
    either is refused (not remembered: its answer is unmatched) and the frame counted once in ``limits.pending`` (docs/fields-sharedlink.md,
    "Limits"). At most ``MAX_CONVERSATIONS`` queriers: a new one past it is refused the same way
    (nothing of it remembered, the frame counted in ``limits.pending``; its direction may be
    counted besides in ``limits.conversations`` by :meth:`LinkState.table`, a bound of its own)."""

    def __init__(self, limits: LimitCounts | None = None) -> None:
        self._by: dict[Hashable, dict[tuple[str, str], int]] = {}
        self._total = 0  # entries waiting, every querier's (at most MAX_PENDING_TOTAL)
        self.limits = limits if limits is not None else LimitCounts()

    def ask(self, key: Hashable, wants: str, names: frozenset[str] | Sequence[str], number: int) -> bool:
        """Frame ``number`` asks ``key``'s peer for ``names`` (``wants`` ``"R"``) or for a list
        (``"N"``, ``"L"``: no names). False when an entry was refused at ``MAX_PENDING``, or
        the querier is new past ``MAX_CONVERSATIONS`` queriers (both counted in ``limits.pending``)."""
        asks = self._by.get(key)
        if asks is None:
            if len(self._by) >= MAX_CONVERSATIONS:
                self.limits.pending += 1
                return False
            asks = self._by[key] = {}
        refused = False
        for name in (names if wants == "R" else ("",)):
            k = (wants, name)
            if k in asks:
                asks[k] = number
            elif len(asks) < MAX_PENDING and self._total < MAX_PENDING_TOTAL:
                asks[k] = number
                self._total += 1
            else:
                refused = True
        if refused:
            self.limits.pending += 1
        return not refused

    def answer(self, key: Hashable, kind: str, names: frozenset[str] | Sequence[str] = ()) -> int | None:
        """What ``kind`` (``"R"`` with the reply's ``names``, ``"N"``, ``"L"``) answers of
        ``key``'s asks, taken off: the latest frame among them; None when none waits."""
        asks = self._by.get(key)
        if not asks:
            return None
        found = [asks.pop((kind, name), None) for name in (names if kind == "R" else ("",))]
        self._total -= sum(n is not None for n in found)
        return max((n for n in found if n is not None), default=None)


def link_response(pending: PendingAsks, conv: Hashable, frame: Frame, kind: str, number: int) -> int | None:
    """Issue 29's reply rule for a query, declaration or reply (docs/fields-sharedlink.md,
    "Replies"): a reply (and a declaration answering a list request) is linked to the latest
    unanswered ask of each name it answers, from the queried address to the querier's address
    and port, the letters reversed, whatever its source port; returns the latest of those asks'
    frame numbers. A query or declaration (frame ``number``) is remembered as an ask of each
    name (:class:`PendingAsks`)."""
    fields = frame.fields
    if kind == "reply":
        return pending.answer(answer_key(conv, frame.src, frame.dst), "R",
                              frozenset(f.text for f in fields if f.letter == "R"))
    names = [f.text for f in fields if f.letter == "Q"]
    response_to = None
    if kind == "declaration":
        decl = declared_list(fields)
        if decl is not None:
            response_to = pending.answer(answer_key(conv, frame.src, frame.dst), decl[0])
    if names:
        pending.ask(ask_key(conv, frame.src, frame.dst), "R", names, number)
    elif kind == "query":
        req = next((f.letter for f in fields if f.letter in ("N", "L")), None)
        if req is not None:  # L? is answered by the N list, N? by the L list
            pending.ask(ask_key(conv, frame.src, frame.dst), "N" if req == "L" else "L", (), number)
    return response_to


@dataclass
class LinkState:
    """Variable tables for every direction seen on a link, keyed by a conversation key
    (addresses and ports, or a serial direction: see :func:`conversation_key`) plus the
    (src, dst) letters, and the lists that name their positional frames
    (docs/fields-sharedlink.md, "Rules for real sessions"). A direction uses, first found:

    1. the list it declared itself (an ``N``k declaration on its conversation);
    2. its receiver's inbound list (an ``L``k declaration from the receiver's address to the
       sender's address, whatever the ports: :func:`receiver_key`);
    3. the latest good declaration for its letter pair, from any conversation;
    4. the list the user gave for its letter pair (``default_list`` entries ``"B>A:name"``);
    5. the a-priori list of every pair (``default_list``'s plain entries, the beacon's by
       default), which names only frames with as many slots as it has.

    Values, carried values and "once filled" marks stay per conversation: two receivers never
    share them. A direction that takes a new list keeps the values of the names it keeps."""

    default_list: Sequence[tuple[str, int | None]] = BEACON_VARIABLES
    tables: dict[tuple[object, str, str], VariableTable] = field(default_factory=dict)
    pair_lists: dict[tuple[str, str], VarSource] = field(default_factory=dict)  # the letter pair's latest declaration
    inbound: dict[Hashable, VarSource] = field(default_factory=dict)  # receiver_key -> its inbound (L) list
    limits: LimitCounts = field(default_factory=LimitCounts)  # input dropped at a bound, every table's
    #: the values the last :meth:`apply` dropped at a limit, as the frame shows them (VariableTable.dropped)
    dropped: list[Update] = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        every, pairs = split(self.default_list)
        self.apriori = VarSource(tuple(every), by_length=True) if every else None
        self.user_lists = {k: VarSource(tuple(v)) for k, v in pairs.items()}

    def source(self, src: str, dst: str, conv: Hashable = None) -> VarSource | None:
        """The list a direction with no list of its own uses (2 to 5 above)."""
        s = self.inbound.get(receiver_key(conv, src, dst)) if self.inbound else None
        if s is None:
            s = self.pair_lists.get((src, dst)) or self.user_lists.get((src, dst)) or self.apriori
        return s

    def table(self, src: str, dst: str, conv: Hashable = None) -> VariableTable:
        """The table of a direction (made when new), its list brought up to date. Past
        ``MAX_CONVERSATIONS`` directions a new one gets a fresh table that is not kept (counted
        in ``limits.conversations``): its frames are decoded on their own, with no state before them."""
        key = (conv, src, dst)
        t = self.tables.get(key)
        if t is None:
            t = VariableTable()
            t.limits = self.limits
            if len(self.tables) >= MAX_CONVERSATIONS:
                self.limits.conversations += 1
            else:
                self.tables[key] = t
        s = t.own or self.source(src, dst, conv)
        if s is not t.list_from and s is not None:
            t.use_list(s.names, s.by_length, s.declared)
            t.list_from = s
        return t

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0, conv: Hashable = None,
              carried: bool = True) -> list[Update]:
        decl = declared_list(frame.fields)
        if decl is None:
            t = self.table(frame.src, frame.dst, conv)
            ups = t.apply(frame, number, time_ns, carried)
            self.dropped = t.dropped
            return ups
        self.dropped = []
        which, ordinal, names = decl
        if which == "N":  # the sender's outbound list: its own conversation's
            t = self.table(frame.src, frame.dst, conv)
            new = VarSource(tuple(extend_list(t.in_use, ordinal, names, self.limits)), declared=True)
            t.own = new
            self.table(frame.src, frame.dst, conv)
            self.pair_lists[(frame.src, frame.dst)] = new
            return []
        # L: the sender's inbound list, the list of every direction from the declaration's
        # destination address to the declarer's address
        src, dst, rconv = frame.dst, frame.src, reverse_conversation(conv)
        rkey = receiver_key(rconv, src, dst)
        base = self.source(src, dst, rconv)
        new = VarSource(tuple(extend_list(base.names if base is not None else (), ordinal, names, self.limits)),
                        declared=True)
        if rkey in self.inbound or len(self.inbound) < MAX_CONVERSATIONS:
            self.inbound[rkey] = new
        else:
            self.limits.conversations += 1
        self.pair_lists[(src, dst)] = new
        return []


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
