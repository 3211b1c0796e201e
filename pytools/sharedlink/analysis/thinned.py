"""A bounded even sample of a stream of points (``plot``'s tracks and series, the robot panels'
series): :class:`Thinned`."""

from __future__ import annotations


class Thinned:
    """Points ``(t, values...)`` kept at most about ``2 * limit`` : when full, every other point
    is dropped and only every ``stride``-th new one is kept."""

    def __init__(self, limit: int) -> None:
        self.limit = max(2, limit)
        self.stride = 1
        self.seen = 0
        self.rows: list[tuple] = []

    def add(self, *row: object) -> None:
        self.seen += 1
        if (self.seen - 1) % self.stride:
            return
        self.rows.append(row)
        if len(self.rows) >= 2 * self.limit:
            self.rows = self.rows[::2]
            self.stride *= 2

    def columns(self) -> list[list]:
        if not self.rows:
            return []
        return [list(c) for c in zip(*self.rows)]
