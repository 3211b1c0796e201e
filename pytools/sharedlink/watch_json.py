"""``sharedlink watch --json``: one JSON line per frame (:func:`json_line`; :class:`JsonLines`, the
same text made faster), the keys of ``export --format jsonl`` rows. Importable from
:mod:`sharedlink.watch` too."""

from __future__ import annotations

import json
import math
from typing import Any

from sharedlink.analysis.decode import Decoded, format_time
from sharedlink.protocols.limits import MAX_CONVERSATIONS


def _typed(v: Any) -> Any:
    x = v.value
    return v.text if isinstance(x, float) and not math.isfinite(x) else x


def json_line(d: Decoded, dropped: int = 0) -> str:
    """One frame as a JSON object (the keys of ``export --format jsonl`` rows, without ``t``,
    plus ``late`` and ``dropped``: the datagrams the watch has dropped so far, falling behind)."""
    ok = d.checksum_ok
    return json.dumps({
        "number": d.number, "time": format_time(d.ts_ns), "ts_ns": d.ts_ns, "src": d.src, "dst": d.dst,
        "kind": d.kind, "checksum": "none" if ok is None else ("good" if ok else "bad"), "late": d.late,
        "values": {n: _typed(v) for n, v in d.table.vars.items() if v.text is not None},
        "changed": [u.name for u in d.changes()], "dropped": dropped,
    })


class JsonLines:
    """:func:`json_line`, the same text, faster for a direction holding many names: each
    variable's ``"name": value`` is kept, made again only when its text or type changed (the
    values object of a 4,096-name table took 11 ms a line, every value typed and encoded again;
    a line then cost what its table holds, here a lookup a name). Per table at most twice the
    names it holds (then built anew), so names a table dropped are not kept."""

    def __init__(self) -> None:
        self._tables: dict[int, tuple[Any, dict[str, tuple[Any, Any, Any, str]]]] = {}

    def __call__(self, d: Decoded, dropped: int = 0) -> str:
        vars_ = d.table.vars
        held = self._tables.get(id(d.table))
        if held is None or held[0] is not d.table or len(held[1]) > 2 * len(vars_) + 64:
            if len(self._tables) >= MAX_CONVERSATIONS:
                self._tables.clear()
            held = self._tables[id(d.table)] = (d.table, {})
        cache = held[1]
        dumps = json.dumps
        parts = []
        for n, v in vars_.items():
            text = v.text
            if text is None:
                continue
            c = cache.get(n)
            if c is None or c[0] is not v or c[1] is not text or c[2] != v.type_code:
                c = cache[n] = (v, text, v.type_code, dumps(n) + ": " + dumps(_typed(v)))
            parts.append(c[3])
        ok = d.checksum_ok
        head = dumps({
            "number": d.number, "time": format_time(d.ts_ns), "ts_ns": d.ts_ns, "src": d.src, "dst": d.dst,
            "kind": d.kind, "checksum": "none" if ok is None else ("good" if ok else "bad"), "late": d.late,
        })
        return (head[:-1] + ', "values": {' + ", ".join(parts) + '}, "changed": '
                + dumps([u.name for u in d.changes()]) + ', "dropped": ' + str(int(dropped)) + "}")
