"""The changes-only mode's compiled layouts (``diff``): a direction's layouts as one pattern a form
on the frame's bytes, and the run taker that decodes a classic pcap block's records with them."""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

from sharedlink.analysis.core.checksum import frame_ok
from sharedlink.analysis.core.direction import Direction
from sharedlink.analysis.core.patterns import CV, MAX_COMPILED_VARS, PCAP_UDP, fullmatch, plain_udp
from sharedlink.capture.pcapio import NS
from sharedlink.protocols.state import Variable, VariableTable

#: a frame's head and tail around its values, as the compiled patterns match them
_TAIL = rb"\|C([0-9A-F]{2})\]\r\n"


class Compiled:
    """Changes only: a direction's layouts as compiled patterns on the frame's bytes, one a
    form, and :attr:`take`, the function that decodes a frame with them.

    Named: every typed variable of the table, in table order, as an optional ``|T t|Q name|D
    value`` (so every subset a compressed stream sends, in that order, is one match);
    positional: one ``|D value`` a slot of the table's full set. Each group is a value as bytes,
    compared with ``cur`` (the table's texts, latin-1, kept in step: a changed value is written
    to the table at the end of the run that changed it). Made from the table as the reference
    path leaves it; valid while the direction's :class:`Direction` version is ``version`` (every
    reference-path frame of the direction moves it) and made again when a frame gives a
    variable its first value.

    ``take(buf, off, number, mult, lane, out)`` decodes a run of records of a classic pcap block
    (``buf`` from ``off``; ``number``: the last record's number; ``mult``: 1 for nanosecond
    times, 1000 for microseconds): while a record is a plain Ethernet/IPv4/UDP datagram of
    ``lane`` (the packet's addresses and ports, as it holds them), its payload one
    frame of this direction a compiled layout matches, with a right checksum, the table is
    updated and ``out`` (four appends) gets its packed time, number and change record (the
    record as :mod:`sharedlink.capture.change_records` makes it: the letters, then each value
    the frame changed) and, for a full frame, its time. It stops at the first record it does
    not take (the caller decodes that one with :meth:`Decoder.reference`) or after a frame that
    gave a variable its first value (then the layouts are made again, with a new ``take``) and
    returns ``(offset, number, frames taken, their captured bytes, first)``, ``first`` the
    variables that frame gave a first value, else None. The caller counts what it took in
    :attr:`Decoder.fast`. No Decoded, no Updates: a frame costs one struct call, one match
    and a comparison per value it holds; ``set_in``/``set_at`` are not kept. A run of one
    direction (a capture of one sender) is one call; everything the loop uses is bound in the
    closure (no attribute look-ups per frame)."""

    __slots__ = ("hot", "version", "key", "vars", "cur", "named", "pos", "take")

    def __init__(self, h: Direction, key: bytes) -> None:
        self.hot = h
        self.key = key  # destination and source letters: a change record's first two bytes
        self.build(h)

    def build(self, h: Direction) -> None:
        """Make the patterns and :attr:`take` from the direction's table as it is now."""
        from sharedlink.analysis.compiled_blocks import block_taker
        from sharedlink.capture.change_records import SEP_CHANGE, SEP_VALUE, escape

        t = h.table
        self.version = h.version
        if len(t.vars) > MAX_COMPILED_VARS:
            # too wide to compile: nothing made, so a table that grows by new names every frame
            # costs nothing a frame here (a build walks every variable: quadratic, issue 31)
            self.vars, self.cur, self.named, self.pos = [], [], None, None
            return
        vs = list(t.vars.values())
        self.vars = vs
        self.cur = [None if v.text is None else v.text.encode("latin-1", "replace") for v in vs]
        head = rb"\[:" + re.escape(self.key) + rb"\|N0"
        named_rx, nslots = _named_pattern(t, vs, head)
        pos_rx, pslots, preq = _positional_pattern(t, vs, head)
        self.named = fullmatch(named_rx) if named_rx is not None else None
        self.pos = fullmatch(pos_rx) if pos_rx is not None else None
        rec = [SEP_CHANGE + escape(v.name) + SEP_VALUE for v in vs]
        block = block_taker(self.key, named_rx, pos_rx, CV, nslots, pslots, self.cur, rec, h.sync)
        self.take = _run_taker(self, (nslots, pslots, preq), rec, block)


def _named_pattern(t: VariableTable, vs: list[Variable], head: bytes) -> tuple[bytes | None, list[int]]:
    """The named form's pattern and the variable each value group is: only when every variable
    with a value has a type and was sent named (then "full", every sent name present, is "every
    variable with a value present")."""
    valued = {v.name for v in vs if v.text is not None}
    if not all(v.type_code is not None or v.text is None for v in vs) or valued != set(t.sent_names):
        return None, []
    nslots = [i for i, v in enumerate(vs) if v.type_code is not None]
    return head + b"".join(
        rb"(?:\|T%d\|Q%s\|D(%s+))?" % (vs[i].type_code, re.escape(vs[i].name.encode("latin-1", "replace")), CV)
        for i in nslots) + _TAIL, nslots


def _positional_pattern(t: VariableTable, vs: list[Variable], head: bytes
                        ) -> tuple[bytes | None, list[int], list[int]]:
    """The positional form's pattern: the table's full set, each slot named as the reference
    path names it in a frame of that many slots, every value held in a slot that has held one;
    the variable each slot is, and the slots that have held a value."""
    names = t.names
    n = len(names)
    valued = {v.name for v in vs if v.text is not None}
    index = {v.name: i for i, v in enumerate(vs)}
    if not (names and len(set(names)) == n and all(x in index for x in names)
            and all(t.slot_name(i, n) == names[i] for i in range(n))
            and t.filled == {i for i, x in enumerate(names) if x in valued} and valued <= set(names)):
        return None, [], []
    return head + (rb"\|D(%s*)" % CV) * n + _TAIL, [index[x] for x in names], sorted(t.filled)


def _named_full(g: tuple, slots: list[int], cur: list) -> bool:
    """Whether a named frame (its value groups ``g``) is a full set: every variable with a value
    present (all were sent named), and one present."""
    if None not in g:
        return len(g) > 1
    if g.count(None) >= len(g) - 1:
        return False
    return all(v is not None or cur[k] is None for v, k in zip(g, slots))


def _run_taker(compiled: Compiled, slots: tuple[list[int], list[int], list[int]], rec: list[bytes],
               block: Callable) -> Callable:
    """The ``take`` of :class:`Compiled` (see there), everything it uses bound in its closure."""
    from sharedlink.analysis.compiled_blocks import BLOCK_AFTER

    h = compiled.hot
    t = h.table
    vs, cur, key = compiled.vars, compiled.cur, compiled.key
    nslots, pslots, preq = slots
    sync = h.sync
    unpack_x = PCAP_UDP.unpack_from
    struct_error = struct.error
    match = _matcher(compiled, pslots, nslots, preq)

    def take(buf: bytes, off: int, number: int, mult: int, lane: bytes, out: tuple, bulk: tuple | None = None
             ) -> tuple[int, int, int, int, list[Variable] | None]:
        # a run of records, while each is one frame of this direction a layout matches
        end = len(buf)
        ts_app, num_app, rec_app, full_app = out
        first: list[Variable] | None = None
        n = wire = 0
        form = last_full = g = None
        slots = nslots
        dirty: list[int] = []  # the variables whose value changed (written to the table at the end)
        changed = dirty.append
        # the block tier: once BLOCK_AFTER records in a row were taken here
        run = 0 if bulk is not None else -(1 << 62)
        while first is None:
            if run >= BLOCK_AFTER and off + 67 <= end:
                bpos = buf[off + 66] == 68  # positional: "[:AB|N0|D" (after 16 + 42 bytes of headers)
                got = block(buf, off, number, mult, lane, bulk, bpos, t.named is True, changed)
                run = 0 if got is None or not got[5] else run
                if got is not None:
                    off, number, k, w, lf, _whole = got
                    n, wire, form = n + k, wire + w, bpos
                    last_full = lf if lf is not None else last_full
                    continue
            try:
                sec, frac, incl, _orig, eth, tl, frag, proto, here, ul = unpack_x(buf, off)
            except struct_error:
                break
            start = off + 58
            e = off + 16 + incl
            if here != lane or e > end or not plain_udp(eth, tl, frag, proto, incl, ul):
                break
            got = match(buf, start, e)
            if got is None:
                break
            g, slots, full = got
            if not frame_ok(buf[start:e], g[-1]):
                break
            off = e
            number += 1
            n += 1
            wire += incl
            parts = [key]
            for v, k in zip(g, slots):
                if v and v != cur[k]:
                    if cur[k] is None:
                        first = [vs[k]] if first is None else [*first, vs[k]]
                    cur[k] = v
                    changed(k)
                    parts += (rec[k], v)
            ts_app(sec | (frac * mult) << 32)  # (the packed time of a change chunk)
            num_app(number)
            rec_app(b"".join(parts))
            form = slots is pslots
            run += 1
            if full:
                ts = sec * NS + frac * mult
                full_app(ts)
                last_full = number
                sync[1] = ts
        _write_back(compiled, dirty, form, last_full)
        if first is not None:  # what the reference path notes of a first value, then build again
            _note_first(t, vs, g, slots, slots is pslots)
            compiled.build(h)  # (a new take: the caller looks it up again)
        return off, number, n, wire, first

    return take


def _matcher(compiled: Compiled, pslots: list[int], nslots: list[int], preq: list[int]) -> Callable:
    """The per-record match of a :class:`Compiled`'s ``take``: ``match(buf, start, end)`` -> None
    when the frame is not one of this direction in a compiled layout, else its groups, the
    variable each is, and whether it is a full set (as :meth:`VariableTable.kind` before it)."""
    t = compiled.hot.table
    cur, named, pos = compiled.cur, compiled.named, compiled.pos

    def match(buf: bytes, start: int, e: int) -> tuple[tuple, list[int], bool] | None:
        # one frame of this direction in a compiled layout: its groups, their variables, full
        if buf[start + 8] == 68:  # "[:AB|N0|D": positional
            m = pos(buf, start, e) if pos is not None else None
            if m is None:
                return None
            g = m.groups()
            # full (as VariableTable.kind, before the frame): every slot that has held a value has one
            return g, pslots, b"" not in g or all(g[i] for i in preq)
        if named is None or (buf[start + 8] == 67 and t.named is not True):
            return None  # (a bare N0 takes the direction's form: named only in a named direction)
        m = named(buf, start, e)
        if m is None:
            return None
        g = m.groups()
        return g, nslots, _named_full(g, nslots, cur)

    return match


def _write_back(compiled: Compiled, dirty: list[int], form: bool | None, last_full: int | None) -> None:
    """The end of a run: the table's texts that changed, its form and its last full set."""
    t = compiled.hot.table
    vs, cur = compiled.vars, compiled.cur
    for k in set(dirty):  # the table's texts, once a run
        vs[k].text = cur[k].decode("latin-1")
    if form is not None:
        t.named = not form
        if last_full is not None:
            t.last_full_at, t.last_full_in = compiled.hot.sync[1], last_full


def _note_first(t: VariableTable, vs: list[Variable], g: tuple | None, slots: list[int], positional: bool) -> None:
    """What the reference path notes of a frame that gave a variable its first value: the slots
    that have held one (positional), the names sent (named)."""
    assert g is not None
    if positional:
        t.filled.update(i for i, v in enumerate(g[:-1]) if v)
        return
    sent = t.sent_names
    for v, k in zip(g, slots):
        if v is not None and vs[k].name not in sent:
            sent[vs[k].name] = len(sent)
