"""The ``packets`` table of a fleet dataset (issue 42): one row per P2OS packet or blackboard
message, from the :class:`~sharedlink.analysis.sessions.SessionMessage` s the decoding core's
robot links give out, typed as :data:`~sharedlink.fleet.dataset.PACKETS_COLUMNS` (the fields
``export`` writes: :mod:`sharedlink.analysis.robot_export`). Rows are held per (UTC day,
protocol), the partition ``day=.../link=<protocol>``."""

from __future__ import annotations

from typing import Any

import pyarrow as pa

from sharedlink.analysis.robot_export import RobotRows
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.fleet.dataset import PACKETS_COLUMNS

_BOOLS = ("stall_left", "stall_right", "motors_enabled", "moving")
_RENAMED = {"number": "frame", "link": "conversation", "bytes": "size"}
_CHECKSUM_OK = {"good": True, "bad": False, "none": None}


class PacketRows:
    """Rows held per (day, protocol) until :meth:`take`."""

    def __init__(self) -> None:
        self.rows = RobotRows()
        self.parts: dict[tuple[str, str], list[dict[str, Any]]] = {}
        self.held = 0
        self.count = 0

    def add(self, m: SessionMessage, day: str) -> None:
        row = self.rows.row(m)
        out = {_RENAMED.get(k, k): v for k, v in row.items() if v is not None and v != ""}
        out["time_ns"] = out.pop("ts_ns")
        out["checksum_ok"] = _CHECKSUM_OK[row["checksum"]]
        arg = out.pop("arg", None)
        if isinstance(arg, int):
            out["arg_int"] = arg
        elif arg is not None:
            out["arg_text"] = arg
        for b in _BOOLS:
            if b in out:
                out[b] = bool(out[b])
        if "data" in out:
            out["data"] = bytes.fromhex(out["data"])
        out["raw"] = m.raw
        self.parts.setdefault((day, m.protocol), []).append(out)
        self.held += 1
        self.count += 1

    def take(self) -> list[tuple[tuple[str, str], list[dict[str, Any]]]]:
        """The rows held, per partition; then none are."""
        parts = sorted(self.parts.items())
        self.parts = {}
        self.held = 0
        return parts


def packet_columns(rows: list[dict[str, Any]], capture: str, vehicle: str) -> dict[str, pa.Array]:
    """The rows as the table's columns (``capture`` and ``vehicle`` as dictionary arrays, one
    value each, as the other tables write them)."""
    n = len(rows)
    zeros = pa.repeat(pa.scalar(0, pa.int32()), n)
    cols: dict[str, pa.Array] = {
        "capture": pa.DictionaryArray.from_arrays(zeros, pa.array([capture], pa.string())),
        "vehicle": pa.DictionaryArray.from_arrays(zeros, pa.array([vehicle], pa.string())),
    }
    for name, kind in PACKETS_COLUMNS[2:]:
        cols[name] = pa.array([r.get(name) for r in rows], getattr(pa, kind)())
    return cols
