"""Bounds on what hostile or odd input may make the decoders hold (issue 31).

One home for the limits the Python side applies; the Lua dissector has the same defaults as
preferences (``sharedlink.max_slots`` and so on, ``docs/fields-sharedlink.md``, "Limits").
Input past a limit is counted (:class:`LimitCounts`) and dropped, never allocated.
"""

from __future__ import annotations

from dataclasses import dataclass

#: slot number, ordinal or list length (``N``/``L`` ordinals, declaration sizes)
MAX_SLOTS = 1024
#: distinct variable names one direction holds
MAX_NAMES = 4096
#: digits of an ``N``/``T``/ordinal number field; a longer one is malformed
MAX_NUMBER_DIGITS = 9
#: conversations (directions) with state
MAX_CONVERSATIONS = 65536
#: pending (unanswered) queries or messages per conversation
MAX_PENDING = 1024
#: pending (unanswered) query entries in all, every querier's together (issue 44: 1,024 a querier
#: times 65,536 queriers was no practical bound)
MAX_PENDING_TOTAL = 65536
#: bytes held for one unterminated serial or TCP record
MAX_HELD_BYTES = 65536


@dataclass
class LimitCounts:
    """How often input went past each limit (and was dropped)."""

    slots: int = 0  # values or declared names at a slot >= MAX_SLOTS
    names: int = 0  # new names past MAX_NAMES in one direction
    numbers: int = 0  # N/L (ordinal) fields with more than MAX_NUMBER_DIGITS digits (a longer T is no type)
    conversations: int = 0  # frames of a new direction past MAX_CONVERSATIONS
    #: unfinished serial or TCP frames given up at MAX_HELD_BYTES (their bytes counted as noise)
    held: int = 0
    #: queries (frames) refused because MAX_PENDING asks already wait for an answer, or
    #: MAX_PENDING_TOTAL in all, or from a new querier past MAX_CONVERSATIONS queriers
    pending: int = 0

    @property
    def total(self) -> int:
        return self.slots + self.names + self.numbers + self.conversations + self.held + self.pending

    def to_dict(self) -> dict[str, int]:
        return {"slots": self.slots, "names": self.names, "numbers": self.numbers, "conversations": self.conversations,
                "held": self.held, "pending": self.pending}
