"""Variable lists per node pair: the syntax of vehicle profiles (issue 29).

``B>A: AutoGpsHead:2,AutoGpsLat:2,...; A>B: video_mux1:0,...`` gives a list of variables for
each direction (``SRC>DST``, letters A-P, from SRC to DST as the ``pair`` column reads). Entries
are separated by ``;`` or new lines; a line starting with ``#`` is a comment (``#3`` as a
name, a slot nothing named, only after a pair or a comma). An entry with no
pair is the list for every pair (:data:`ANY_PAIR`): the plain old syntax ``Lat:2,Lon:2,Note`` is
that one entry. A later entry for a pair replaces the earlier one. Each item is ``NAME`` or
``NAME:TYPE`` with TYPE 0 (long), 2 (double) or 4 (string); anything else is an error.
``sharedlink lists`` prints the declarations of a capture in this syntax
(:func:`format_varlists`), and :func:`parse_varlists` reads it back: the rules are in
docs/fields-sharedlink.md, "Rules for real sessions".
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

#: the key of the list that applies to every node pair (the old syntax)
ANY_PAIR = "*"
#: the type codes a list may give: those of the T field (BUL-009)
TYPES = {0: "long", 2: "double", 4: "string"}
#: node letters (A..P = nodes 1..16)
LETTERS = "ABCDEFGHIJKLMNOP"
#: characters a name cannot hold: the frame's own syntax and this one's separators
_NOT_IN_NAME = "|[],;:>"
_TYPE_HELP = "types are 0 long, 2 double, 4 string"

try:  # issue 31's shared limit (the py-core branch adds the module); the same number until then
    from sharedlink.protocols.limits import MAX_SLOTS
except ImportError:  # pragma: no cover - before the merge
    MAX_SLOTS = 1024

VarList = list[tuple[str, int | None]]


class VarListError(ValueError):
    """A variable list that cannot be read; the message says where and why, on one line."""


def parse_pair(text: str) -> str:
    """``"B>A"`` (spaces allowed around the letters; ``"B→A"``, as Wireshark draws it, too) ->
    ``"B>A"``; anything else an error."""
    src, sep, dst = text.replace("\u2192", ">").partition(">")
    src, dst = src.strip(), dst.strip()
    if not sep or len(src) != 1 or len(dst) != 1 or src not in LETTERS or dst not in LETTERS:
        raise VarListError(f"bad node pair {text.strip()!r} (SRC>DST, letters A-P)")
    return f"{src}>{dst}"


def parse_list(text: str, where: str = "") -> VarList:
    """``"Lat:2,Lon:2,Note"`` -> ``[("Lat", 2), ("Lon", 2), ("Note", None)]``. Empty items
    are skipped; no name at all, a bad name or a type other than 0, 2, 4 is an error."""
    at = f" in {where}" if where else ""
    out: VarList = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        name, _, type_text = item.partition(":")
        name, type_text = name.strip(), type_text.strip()
        if not name or any(c in name for c in _NOT_IN_NAME):
            raise VarListError(f"bad variable name {name!r}{at}")
        type_code: int | None = None
        if type_text:
            try:
                type_code = int(type_text)
            except ValueError:
                type_code = -1
            if type_code not in TYPES:
                raise VarListError(f"bad type {type_text!r} for {name}{at} ({_TYPE_HELP})")
        out.append((name, type_code))
        if len(out) > MAX_SLOTS:
            raise VarListError(f"more than {MAX_SLOTS} variables{at}")
    if not out:
        raise VarListError(f"empty variable list{at}")
    return out


def _entries(text: str) -> Iterable[str]:
    for line in text.splitlines():
        if line.lstrip().startswith("#"):
            continue
        yield from line.split(";")


def parse_varlists(text: str) -> dict[str, VarList]:
    """Per-pair lists: ``{"B>A": [(name, type), ...], ...}``; an entry with no pair is kept
    under :data:`ANY_PAIR`. Raises :class:`VarListError` (a ValueError) with a one-line reason."""
    out: dict[str, VarList] = {}
    for entry in _entries(text):
        if not entry.strip():
            continue
        head, colon, rest = entry.partition(":")
        if colon and (">" in head or "\u2192" in head):
            pair = parse_pair(head)
            out[pair] = parse_list(rest, pair)
        else:
            out[ANY_PAIR] = parse_list(entry)
    if not out:
        raise VarListError("empty variable list")
    return out


def format_list(names: Iterable[tuple[str, int | None]]) -> str:
    """``[("Lat", 2), ("Note", None)]`` -> ``"Lat:2,Note"`` (types other than 0, 2, 4 are
    left out: the name is untyped)."""
    return ",".join(f"{n}:{t}" if t in TYPES else n for n, t in names)


def format_varlists(lists: Mapping[str, Iterable[tuple[str, int | None]]], sep: str = "; ") -> str:
    """The lists in the syntax :func:`parse_varlists` reads: ``"B>A: a:2,b; A>B: c:0"`` (the
    every-pair list first, with no pair)."""
    parts = [format_list(lists[ANY_PAIR])] if ANY_PAIR in lists else []
    parts += [f"{pair}: {format_list(names)}" for pair, names in lists.items() if pair != ANY_PAIR]
    return sep.join(parts)


#: what a pair-qualified name looks like in a flat list (``"B>A:AutoGpsHead"``)
PAIR_SEP = ":"


def flatten(lists: Mapping[str, Iterable[tuple[str, int | None]]]) -> VarList:
    """Per-pair lists as one flat list of ``(name, type)``, the shape every API that takes
    ``--variables`` takes: the every-pair list's names as they are, a pair's as ``"B>A:name"``
    (a name never holds ``>`` or ``:``). So the lists travel through callers that copy, pickle,
    hash or print the list unchanged; :func:`split` takes them apart again."""
    out: VarList = list(lists.get(ANY_PAIR, ()))
    for pair, names in lists.items():
        if pair != ANY_PAIR:
            out += [(f"{pair}{PAIR_SEP}{n}", t) for n, t in names]
    return out


def split(variables: Iterable[tuple[str, int | None]]) -> tuple[VarList | None, dict[tuple[str, str], VarList]]:
    """A flat list (:func:`flatten`) -> (the every-pair list, None when it has none;
    ``{(src, dst): list}`` for the pairs given their own list)."""
    every: VarList = []
    pairs: dict[tuple[str, str], VarList] = {}
    for name, type_code in variables:
        head, sep, rest = name.partition(PAIR_SEP)
        if sep and len(head) == 3 and head[1] == ">" and head[0] in LETTERS and head[2] in LETTERS:
            pairs.setdefault((head[0], head[2]), []).append((rest, type_code))
        else:
            every.append((name, type_code))
    return (every or None), pairs
