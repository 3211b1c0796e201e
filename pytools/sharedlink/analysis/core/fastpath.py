"""The core's fast path for :class:`~sharedlink.analysis.core.decoded.Decoded` frames: a frame in
a layout its direction already had, taken without parsing it into fields."""

from __future__ import annotations

import re

from sharedlink.analysis.core.checksum import frame_ok
from sharedlink.analysis.core.decoded import DATA_KINDS, Decoded
from sharedlink.analysis.core.direction import MAX_LAYOUTS, Direction, Layout, full_set, is_late, layout_key
from sharedlink.protocols.limits import MAX_CONVERSATIONS
from sharedlink.protocols.state import Update, _update, conversation_key

#: one named full/delta frame alone in a datagram (decoded as latin-1), with plain names and
#: numeric values, or a bare ``N0`` (nothing changed): groups destination letter, source letter,
#: body ("T2|QName|Dvalue|" ..., empty when bare), checksum
HOT = re.compile(r"\[:([A-P])([A-P])\|N0\|((?:T[024]\|Q[A-Za-z0-9_.]+\|D[-+0-9.eE]+\|)*)C([0-9A-F]{2})\]\r\n")
#: one positional ``N0`` frame alone in a datagram, numeric or empty (carried) values: groups
#: destination letter, source letter, body ("|Dvalue|D|Dvalue" ..., at least one value), checksum
HOT_POS = re.compile(r"\[:([A-P])([A-P])\|N0((?:\|D[-+0-9.eE]*)+)\|C([0-9A-F]{2})\]\r\n")


class FastPath:
    """The fast path of the Decoded mode (a part of :class:`~sharedlink.analysis.core.decoder.Decoder`):
    a datagram that is one ``N0`` frame of a layout its direction had (:data:`HOT`, :data:`HOT_POS`)
    is decoded from one latin-1 string and one split into the direction's table, Updates reused
    while they say the same; :meth:`_learn` makes the layouts from what the reference path decoded.
    Its attributes (``_hot``, ``fast``, ``carried``, ``late_ns``, ``_sync``) are the Decoder's."""

    _hot: dict[tuple, Direction]
    _sync: dict[tuple, list]
    fast: int
    carried: bool
    late_ns: int

    def _try_fast(self, number: int, ts: int, conv: tuple, raw: bytes) -> Decoded | None:
        found = self._match(conv, raw)
        if found is None:
            return self._try_positional(number, ts, conv, raw)
        h, lay, src, dst, values = found
        return self._fast(number, ts, conv, raw, h, lay, src, dst, values)

    def _try_positional(self, number: int, ts: int, conv: tuple, raw: bytes) -> Decoded | None:
        """A positional ``N0`` frame alone in a datagram, in a slot count its direction's last
        reference-path frame had, with a good checksum: decoded without a Frame."""
        m = HOT_POS.fullmatch(raw.decode("latin-1"))
        if m is None:
            return None
        dst, src, body, cs = m.groups()
        h = self._hot.get((conv, src, dst))
        if h is None or not h.pos:
            return None
        values = body[2:].split("|D")
        lay = h.pos.get(len(values))
        if lay is None:
            return None
        if not frame_ok(raw, cs):
            return None
        return self._fast_positional(number, ts, conv, raw, h, lay, src, dst, values)

    def _match(self, conv: tuple, raw: bytes) -> tuple[Direction, Layout, str, str, list[str]] | None:
        """The direction, layout, letters and values (``D`` fields) of a datagram the fast path
        takes, else None."""
        # measured choices: one latin-1 decode of the datagram, then str operations (the values
        # come out as str, no decode each); one split of the body gives the layout and values
        m = HOT.fullmatch(raw.decode("latin-1"))
        if m is None:
            return None
        dst, src, body, cs = m.groups()
        h = self._hot.get((conv, src, dst))
        if h is None or (not body and h.table.named is not True):  # (a bare N0 takes the direction's form)
            return None
        parts = body.split("|")
        lay = h.layouts.get(layout_key(parts))
        if lay is None:
            return None
        if not frame_ok(raw, cs):
            return None
        if lay.checked != h.version:  # the types may have moved since: the layout's must still hold
            vars_ = h.table.vars
            for n, t in zip(lay.names, lay.types):
                if vars_[n].type_code != t:
                    return None
            lay.checked = h.version
        return h, lay, src, dst, parts[2::3]

    def _learn(self, d: Decoded) -> None:
        if d.kind == "declaration":
            self._hot.clear()
            return
        if d.checksum_ok is False:
            return  # changed nothing
        key = (d.conv, d.src, d.dst)
        text = d.raw.decode("latin-1")
        m = HOT.fullmatch(text)
        sync = self._sync.get((conversation_key(d.conv), d.src, d.dst))
        named = d.table.named
        # (a bare N0 is named only in a direction already named, else it is read as positional)
        if m is None or named is not True:
            m = None
            mp = HOT_POS.fullmatch(text) if named is False else None
        if (m is None and mp is None) or d.checksum_ok is not True or d.kind not in DATA_KINDS or sync is None:
            self._hot.pop(key, None)
            return
        h = self._hot.get(key)
        if h is None or h.table is not d.table or h.sync is not sync:
            if h is None and len(self._hot) >= MAX_CONVERSATIONS:
                return
            h = self._hot[key] = Direction(d.table, sync)
        h.version += 1
        h.last.clear()  # the reference path may have moved a type, an index or a value
        h.pos.clear()  # slots are named as this frame's decoding says, not as an earlier one's
        if m is None:
            # a positional layout: the names the reference path gave the slots, in slot order
            ups = d.updates
            n = len(mp.group(3)[2:].split("|D"))
            vars_ = d.table.vars
            if len(ups) == n and all(u.index == i and u.name in vars_ for i, u in enumerate(ups)):
                names = tuple(u.name for u in ups)
                h.pos[n] = Layout(names, (), tuple(vars_[x] for x in names))
            return
        parts = m.group(3).split("|")  # the body ends with its last "|": one more, empty part
        names = tuple(q[1:] for q in parts[1::3])
        if len(h.layouts) < MAX_LAYOUTS and all(n in d.table.vars for n in names):
            h.layouts[layout_key(parts)] = Layout(names, tuple(int(t[1:]) for t in parts[0:-1:3]))

    def _fast(self, number: int, ts: int, conv: tuple, raw: bytes, h: Direction, lay: Layout, src: str, dst: str,
              values: list[str]) -> Decoded:
        table = h.table
        vars_ = table.vars
        sent = table.sent_names
        last = h.last
        updates: list[Update] = []
        add = updates.append
        stamp = (len(vars_), len(sent))
        if h.stamp != stamp or table.named is not True:  # new names or another form: indexes may differ
            last.clear()
            h.stamp = stamp
        full = lay.full if lay.stamp == stamp else lay.settle(sent, stamp)  # (before the frame names anything new)
        for name, dval in zip(lay.names, values):
            text = dval[1:]
            v = vars_[name]
            index = sent.get(name)
            if index is None:
                index = sent[name] = len(sent)
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, ts
            u = last.get(name)
            if changed or u is None or u.changed or u.carried or u.index != index or u.text != text:
                u = last[name] = _update(v, index, False, None, changed)
            add(u)
        if len(sent) != stamp[1]:
            lay.stamp = (-1, -1)
        if self.carried:
            for name in lay.missing:
                v = vars_[name]
                text = v.text
                if text is None:
                    continue
                u = last.get(name)
                if u is None or not u.carried or u.carried_from != v.set_in or u.text != text:
                    u = last[name] = _update(v, sent.get(name, table._index(name)), True, v.set_in, False)
                add(u)
        table.named = True
        return self._fast_decoded(number, ts, conv, raw, h, full, updates, src, dst)

    def _fast_positional(self, number: int, ts: int, conv: tuple, raw: bytes, h: Direction, lay: Layout, src: str,
                         dst: str, values: list[str]) -> Decoded:
        """A positional frame, as :meth:`VariableTable._positional` decodes it (a slot without a
        value: its variable carried; full when every slot that has held a value has one)."""
        table = h.table
        filled = table.filled
        n = len(values)
        last = h.last
        if table.named is not False:  # the named path's Updates index names by when they were sent
            last.clear()
        full = True
        for i in filled:  # the kind before the frame, as VariableTable.kind
            if i >= n or not values[i]:
                full = False
                break
        updates: list[Update] = []
        add = updates.append
        for i, (v, text) in enumerate(zip(lay.vars, values)):
            name = v.name
            u = last.get(name)
            if not text:
                t = v.text
                if u is None or not u.carried or u.index != i or u.carried_from != v.set_in or u.text != t:
                    u = last[name] = _update(v, i, True, v.set_in, False)
                add(u)
                continue
            if i not in filled:
                filled.add(i)
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, ts
            if changed or u is None or u.changed or u.carried or u.index != i or u.text != text:
                u = last[name] = _update(v, i, False, None, changed)
            add(u)
        table.named = False
        return self._fast_decoded(number, ts, conv, raw, h, full, updates, src, dst)

    def _fast_decoded(self, number: int, ts: int, conv: tuple, raw: bytes, h: Direction, full: bool, updates: list[Update],
                      src: str, dst: str) -> Decoded:
        """A fast frame's ending, named or positional: the sync clock (a full set resets it, a
        delta past the interval is late) and the :class:`Decoded`."""
        table = h.table
        gap: int | None = None
        late = False
        if full:
            table.last_full_at, table.last_full_in = ts, number
            gap = full_set(h.sync, ts)
        else:
            late = is_late(h.sync, ts, self.late_ns)
        self.fast += 1
        ups = tuple(updates)
        return Decoded(number, ts, conv, raw, None, "full" if full else "delta", True, ups, table, late, gap, ups, None,
                       src, dst)

