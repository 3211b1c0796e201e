"""Stream state: the shared-variable table that frames update, in order.

One :class:`VariableTable` per direction of a link (sender, receiver). It learns variable lists
from declaration frames, names positional values from them, carries elided values forward
(compression) and remembers which frame last set each variable. gen, diff, compress and expand
all use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from sharedlink.protocols.codec import (
    TYPE_NAMES,
    Frame,
    declared_list,
    frame_kind,
    guess_value,
    named_values,
    positional_values,
    typed_value,
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
        return typed_value(self.type_code, self.text)


@dataclass(frozen=True)
class Update:
    """One variable's value as a frame leaves it."""

    name: str
    index: int | None  # position in the list, None for named values not in the list
    text: str | None
    carried: bool  # value not in this frame, carried forward
    carried_from: int | None  # frame number the value came from, when carried
    changed: bool  # differs from the value before this frame


@dataclass
class VariableTable:
    """The variables of one direction of a link."""

    names: list[str] = field(default_factory=list)  # the positional (outbound) list
    types: dict[str, int | None] = field(default_factory=dict)
    vars: dict[str, Variable] = field(default_factory=dict)
    last_full_at: int | None = None
    last_full_in: int | None = None
    named: bool | None = None  # which form this direction uses, once seen

    @classmethod
    def with_list(cls, names: Sequence[tuple[str, int | None]] | Sequence[str]) -> VariableTable:
        t = cls()
        t.declare(0, [(n, None) if isinstance(n, str) else n for n in names])
        return t

    def declare(self, ordinal: int, names: Sequence[tuple[str, int | None]]) -> None:
        """Install a declared list (or part of one, from ``ordinal``)."""
        if ordinal > len(self.names):
            self.names.extend(f"var{i}" for i in range(len(self.names), ordinal))
        del self.names[ordinal:]
        for name, type_code in names:
            self.names.append(name)
            if type_code is not None:
                self.types[name] = type_code
            self._var(name, type_code)

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
        """The frame's kind with this table's context: a named frame at ordinal 0 is full only
        when it carries every variable known so far."""
        k = frame_kind(frame.fields)
        if k == "full" and any(f.letter == "Q" for f in frame.fields):
            present = {nv.name for nv in named_values(frame.fields)}
            if not all(n in present for n in self.vars if self.vars[n].text is not None):
                return "delta"
        return k

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
            if any(f.letter == "Q" for f in fields):
                self.named = True
                seen: set[str] = set()
                for nv in named_values(fields):
                    seen.add(nv.name)
                    v = self._var(nv.name, nv.type_code)
                    if nv.name not in self.names and nv.type_code is not None:
                        self.types.setdefault(nv.name, nv.type_code)
                    updates.append(self._set(v, nv.text, number, time_ns))
                for name, v in self.vars.items():
                    if name not in seen and v.text is not None:
                        updates.append(Update(name, self._index(name), v.text, True, v.set_in, False))
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
                        updates.append(Update(name, idx, v.text, True, v.set_in, False))
                    else:
                        u = self._set(v, text, number, time_ns)
                        updates.append(Update(u.name, idx, u.text, False, None, u.changed))
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
        return Update(v.name, self._index(v.name), text, False, None, changed)


@dataclass
class LinkState:
    """Variable tables for every direction seen on a link, keyed by (src, dst) letters plus
    an optional conversation key (addresses and ports)."""

    default_list: Sequence[tuple[str, int | None]] = BEACON_VARIABLES
    tables: dict[tuple[object, str, str], VariableTable] = field(default_factory=dict)

    def table(self, src: str, dst: str, conv: object = None) -> VariableTable:
        key = (conv, src, dst)
        t = self.tables.get(key)
        if t is None:
            t = self.tables[key] = VariableTable.with_list(list(self.default_list))
        return t

    def apply(self, frame: Frame, number: int = 0, time_ns: int = 0, conv: object = None) -> list[Update]:
        decl = declared_list(frame.fields)
        if decl is not None and decl[0] == "L":
            # the sender declares its inbound list: the list of the reverse direction
            self.table(frame.dst, frame.src, conv).declare(decl[1], decl[2])
            return []
        return self.table(frame.src, frame.dst, conv).apply(frame, number, time_ns)
