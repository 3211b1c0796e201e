"""One direction of a conversation as the core's fast tiers follow it.

:class:`Direction` holds what the fast tiers keep of a direction beside its
:class:`~sharedlink.protocols.state.VariableTable` (the state the reference path writes, and every
tier writes back to): its sync clock, the layouts its good full and delta frames have had
(:class:`Layout`), the Updates kept for reuse and, in the changes-only mode, its compiled layouts.
The sync clock is a list ``[time of the first data frame, time of the last full set or None]``
shared with :class:`~sharedlink.analysis.core.reference.ReferenceDecoder`; :func:`is_late` is its
one verdict on a frame that is not a full set.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from sharedlink.protocols.state import Update, VariableTable

if TYPE_CHECKING:
    from sharedlink.analysis.core.compiled import Compiled

#: layouts kept per direction (a compressed beacon has a handful)
MAX_LAYOUTS = 32


def layout_key(parts: list[str]) -> tuple[str, ...]:
    """A hot body's layout (its ``T`` and ``Q`` fields, no values) from ``body.split("|")``."""
    return (*parts[0::3], *parts[1::3])


class Layout:
    """One frame layout of a direction: its names, their types, and what follows from them
    while the direction's names stay the same (``stamp``): the names the frame leaves out
    (carried) and whether it is full."""

    __slots__ = ("names", "types", "present", "stamp", "missing", "full", "checked", "full_at", "vars", "cols")

    def __init__(self, names: tuple[str, ...], types: tuple[int, ...], vars_: tuple = ()) -> None:
        self.names, self.types, self.present = names, types, frozenset(names)
        self.vars = vars_  # positional: the slots' Variables, as the reference path named them
        self.checked = -1  # the direction's version its types were last checked at
        self.full_at = -1  # ... and ``full`` worked out at (counts only)
        self.stamp: tuple[int, int] = (-1, -1)  # (len(table.vars), len(table.sent_names)) the two below hold for
        self.missing: tuple[str, ...] = ()
        self.full = False
        #: columns only (:meth:`Decoder.column`): what its frames' rows share while the direction's
        #: version and names stay: (version, stamp), whether a name is not yet in ``sent_names``,
        #: the carried names' type codes, True and False as many times as names carried and present
        self.cols: tuple = ()

    def settle(self, sent: dict[str, int], stamp: tuple[int, int]) -> bool:
        """Whether a frame of this layout is a full set, as :meth:`VariableTable.kind` says
        before the frame (a bare ``N0`` is a delta), with ``missing`` (the direction's sent
        names the layout leaves out), worked out again when the direction's names changed
        (``stamp``: its variable and sent-name counts)."""
        if self.stamp != stamp:
            present = self.present
            self.missing = tuple(n for n in sent if n not in present)
            self.full = bool(present) and sum(1 for n in present if n in sent) == len(sent)
            self.stamp = stamp
        return self.full


class Direction:
    """A direction's steady state: its table, sync state and the layouts its good full and
    delta frames have had (named: by types and names; positional: by slot count, named as the
    reference path named the slots of the last such frame it decoded); ``last``: the last
    Update the fast path made for each variable, reused while it still says the same (Updates
    are immutable; forgotten whenever the reference path decodes a frame of the direction)."""

    __slots__ = ("table", "sync", "layouts", "last", "stamp", "version", "pos", "compiled")

    def __init__(self, table: VariableTable, sync: list) -> None:
        self.table, self.sync = table, sync
        self.compiled: Compiled | None = None  # changes only: its layouts as compiled patterns
        self.version = 0  # counts the direction's frames through the reference path (types may move)
        self.layouts: dict[tuple[str, ...], Layout] = {}
        self.pos: dict[int, Layout] = {}  # positional layouts by slot count
        self.last: dict[str, Update] = {}
        self.stamp: tuple[int, int] = (-1, -1)  # (len(table.vars), len(table.sent_names)) ``last`` was made for


def write_back(table: VariableTable, layouts: Iterable[tuple[Layout, int, int]], last_full: tuple[int, int] | None
               ) -> None:
    """The end of a batch of named frames a sink took (counts, columns): for each layout, given
    with the number and time of its last frame, the frames that last set its variables (a run
    taker may have set one later already); the direction's last full set ``(number, time)``; its
    named form."""
    vars_ = table.vars
    for lay, number, ts in sorted(layouts, key=lambda x: x[1]):
        for name in lay.names:
            v = vars_[name]
            if v.set_in is None or number > v.set_in:
                v.set_in, v.set_at = number, ts
    if last_full is not None:
        table.last_full_at, table.last_full_in = last_full[1], last_full[0]
    table.named = True


def named_size(name: str, type_code: int | None, text: str | None) -> int:
    """Bytes of one value in a named full set, ``|T t|Q name|D text`` (0 without a value)."""
    if text is None:
        return 0
    return 4 + len(name) + len(text) + (2 + len(str(type_code)) if type_code is not None else 0)



def is_late(sync: list, ts: int, late_ns: int) -> bool:
    """The sync clock's verdict on a data frame at ``ts`` that is not a full set: later than
    ``late_ns`` after the direction's last full set (or, before any, its first data frame)."""
    since = sync[1] if sync[1] is not None else sync[0]
    return ts - since > late_ns


def full_set(sync: list, ts: int) -> int | None:
    """A good (or unchecked) full set at ``ts`` resets the sync clock: the gap since the
    direction's previous full set (ns; None for its first)."""
    last = sync[1]
    sync[1] = ts
    return ts - last if last is not None else None
