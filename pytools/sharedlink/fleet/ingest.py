"""``sharedlink ingest``: captures into a fleet dataset, one capture per task, on local processes
or a Dask distributed cluster.

A task (:func:`ingest_capture`) hashes its capture, and unless the manifest already holds that
content with the same decode options, decodes it with :class:`sharedlink.analysis.decode.Decoder`
(the one decoder of the package, in its columns mode: no per-value object) and writes its rows to the dataset as it goes: rows are buffered
up to ``batch_rows`` in all (whatever the capture's size) and each flush is one Parquet row group
of frames and, sorted by name, row groups of whole names of values (:func:`name_groups`: a query
for one name skips the others'), so a worker's memory does not grow with the capture. The driver (:func:`ingest`) holds the
dataset's lock, hands out the tasks, and records the results in the manifest in batches (an
eighth of the captures it lists, and at the end: :class:`_ManifestBatch`), then deletes the
files a re-ingested capture replaced (see :mod:`.dataset` for why that is safe).

A damaged capture keeps the rows decoded before the damage; its manifest entry carries the
error and the report lists it. Workers write straight into the dataset directory: with
``scheduler`` it must be on a filesystem the workers share with the driver.
"""

from __future__ import annotations

import functools
import hashlib
import uuid
from array import array
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from itertools import accumulate
from operator import itemgetter
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sharedlink.analysis.decode import Columns, Decoded, Decoder
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.errors import InputError, UsageError
from sharedlink.fleet import BATCH_ROWS as BATCH_ROWS  # its home is the package (a light import for the CLI)
from sharedlink.fleet import SCHEDULER_TIMEOUT_S as SCHEDULER_TIMEOUT_S
from sharedlink.fleet.dataset import (
    MANIFEST,
    SCHEMAS,
    CaptureEntry,
    Manifest,
    link_name,
    load_manifest,
    locked,
    partition_dir,
    save_manifest,
    sweep,
)
from sharedlink.fleet.health_rows import HealthRows
from sharedlink.fleet.heap import glibc as _glibc  # noqa: F401 - tests/fleet/test_ingest.py imports it here
from sharedlink.fleet.heap import heap_kept
from sharedlink.fleet.parts import DAY_NS, Batches, Part, day_of
from sharedlink.fleet.robot_rows import PacketRows, packet_columns
from sharedlink.protocols.codec import TYPE_DOUBLE, TYPE_LONG
from sharedlink.protocols.state import BEACON_VARIABLES

#: file name endings taken as captures when a directory is given
CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap")
_HASH_CHUNK = 1 << 20


# -- one capture (runs on a worker) ----------------------------------------------------------------


@dataclass(frozen=True)
class Task:
    """What a worker needs to ingest one capture (picklable: it travels to processes and Dask)."""

    path: str  # resolved
    root: str
    id: str
    vehicle: str
    options: str
    variables: tuple[tuple[str, int | None], ...]
    sync_interval: float
    known_hash: str | None  # the manifest already holds this content with these options
    batch_rows: int = BATCH_ROWS


@dataclass
class Outcome:
    path: str
    status: str  # "ingested", "damaged", "unchanged" or "failed"
    entry: CaptureEntry | None = None  # None when unchanged or failed
    error: str | None = None


def content_hash(path: str | Path) -> tuple[int, str]:
    """(size, ``"blake2b:<hex>"``) of a file, read in chunks."""
    h = hashlib.blake2b(digest_size=20)
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return size, "blake2b:" + h.hexdigest()


def ingest_capture(task: Task, progress: Callable[[int, int], None] | None = None) -> Outcome:
    """Ingest one capture (see the module doc). Never raises for a bad capture: the outcome says.
    ``progress(bytes read, records)`` is called now and then while it decodes."""
    try:
        size, digest = content_hash(task.path)
    except OSError as exc:
        return Outcome(task.path, "failed", error=f"{task.path}: {exc.strerror or exc}")
    if digest == task.known_hash:
        return Outcome(task.path, "unchanged")
    entry = CaptureEntry(task.path, size, digest, task.id, task.vehicle, task.options)
    run = uuid.uuid4().hex[:8]
    rows = _Rows(Path(task.root), task.path, task.vehicle, f"{task.id}-{run}", task.batch_rows)
    try:
        with heap_kept():
            _decode_into(task, entry, rows, progress)
            entry.files += rows.close()
    except BaseException:
        rows.abort()
        raise
    return Outcome(task.path, "damaged" if entry.error else "ingested", entry, entry.error)


def _decode_into(task: Task, entry: CaptureEntry, rows: _Rows, progress: Callable[[int, int], None] | None = None
                 ) -> None:
    """The capture's frames into ``rows``. The decoder's columns mode: the frames its fast path
    takes come as per-column lists (:class:`~sharedlink.analysis.decode.Columns`), appended to
    their partition's lists a direction at a time (:class:`~sharedlink.fleet.parts.Batches`);
    the other frames one by one."""
    parts = rows.parts
    batches = Batches(parts)  # the fast path's frames (Columns), a direction at a time
    day_start = day_end = 0  # the UTC day of the last frame decoded the general way: [start, end) ns
    day = ""
    seq = records = frames = 0
    first_ns = last_ns = None
    held = batch = rows.batch_rows
    dec = Decoder(task.variables, task.sync_interval)
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]  # P2OS, blackboard: the packets table
    try:
        for item in rows.health.fed(dec.capture(task.path, progress, columns=True)):
            t = type(item)
            if t is Columns:
                first_ns, last_ns, added = batches.add(item, seq, first_ns, last_ns)  # type: ignore[arg-type]
                seq += item.frames  # type: ignore[union-attr]
                frames += item.frames  # type: ignore[union-attr]
                held -= added
                if held <= 0:
                    rows.flush_largest()
                    held = batch - rows.held()
                continue
            if t is SessionMessage:
                rows.add_packet(item)  # type: ignore[arg-type]
            if t is not Decoded:
                n = item[0] if isinstance(item, tuple) else item.number  # type: ignore[union-attr]
                if n > records:
                    records = n
                continue
            d: Decoded = item  # type: ignore[assignment]
            seq += 1
            ts = d.ts_ns
            if d.number > records:
                records = d.number
            if first_ns is None:
                first_ns = ts
            last_ns = ts
            if not day_start <= ts < day_end:
                day_start = ts - ts % DAY_NS
                day_end = day_start + DAY_NS
                day = day_of(ts)
            key = (day, d.src, d.dst)
            part = parts.get(key)
            if part is None:
                part = parts[key] = Part(day, d.src, d.dst)
            held -= 1 + part.add_decoded(d, seq)
            if held <= 0:
                rows.flush_largest()
                held = batch - rows.held()
            frames += 1
    except InputError as exc:  # damage: the rows before it are kept
        entry.error = str(exc)
    finally:
        entry.records = max(entry.records, records, batches.records)
        entry.frames += frames
        entry.packets += rows.packets.count
        entry.first_ns = entry.first_ns if entry.first_ns is not None else first_ns
        entry.last_ns = last_ns if last_ns is not None else entry.last_ns
    entry.values += rows.close_counts()


def _typed(type_code: int | None, text: str) -> tuple[int | None, float | None, str | None]:
    """(value_long, value_double, value_string) of a value: doubles hold every number. The
    typing of :func:`~sharedlink.protocols.codec.parse_typed` (and ``guess_value`` untyped),
    without its patterns: ``int()``/``float()`` straight, once the forms they take beyond the
    protocol's (``_``, spaces, other digits, ``nan``/``inf``) are ruled out."""
    if (type_code == TYPE_DOUBLE or type_code == TYPE_LONG or type_code is None) and "_" not in text \
            and text.isascii() and text.strip() == text:
        if type_code != TYPE_DOUBLE:
            try:
                x = int(text)
            except ValueError:
                if type_code == TYPE_LONG or text.lstrip("+-").isdigit():  # (too many digits: text)
                    return None, None, text
            else:
                return (x, float(x), None) if -(1 << 63) <= x < (1 << 63) else (None, float(x), None)
        try:
            f = float(text)
        except ValueError:
            return None, None, text
        if f - f == 0.0 or text.lstrip("+-")[:1] in _DIGITS:  # finite, or an exponent past the double's range
            return None, f, None
    return None, None, text


_DIGITS = frozenset("0123456789.")


def _conversation(conv: tuple) -> tuple[str, str]:
    """(transport, conversation text) of a frame's ``conv`` tuple (see StreamFrame)."""
    proto = str(conv[0])
    if proto == "serial":
        return proto, f"serial {conv[1]} if{conv[4]}"
    return proto, f"{proto} {conv[1]}:{conv[2]} > {conv[3]}:{conv[4]}"


#: columns Parquet dictionary-encodes (few distinct values; the others are written plain, which
#: is both faster and, under zstd, smaller for them: measured on 200k compressed beacon frames)
_DICTIONARY = ["capture", "vehicle", "transport", "conversation", "src", "dst", "pair", "kind", "name", "type"]
#: columns written DELTA_BINARY_PACKED: rising integers (in a values row group sorted by name,
#: the times of one name rise by about a frame's interval: plain, zstd kept them 5 times bigger)
_DELTA = ["seq", "frame", "time_ns"]
#: a values row group holds at least this many rows (unless the flush has fewer), whole names
#: (see :func:`name_groups`)
NAME_GROUP_ROWS = 8192
_FIRST, _SECOND, _THIRD = itemgetter(0), itemgetter(1), itemgetter(2)
#: a double's text as :func:`~sharedlink.protocols.codec.parse_typed` takes it (its
#: ``_DOUBLE_TEXT``, whole text: RE2's ``$`` is the end of the text): the rest is a bad value
_DOUBLE_RE2 = r"^[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?$"


#: columns handed to Parquet as dictionary arrays (those one value throughout a flush, and the
#: sorted names): their dictionary pages come straight from the arrays instead of each row's
#: string hashed (4 ms less CPU per 80,000 values rows). The Arrow schema is not stored in the
#: files: readers take the Parquet types, which are :data:`~.dataset.SCHEMAS`' (strings)
_AS_DICTIONARY = ("capture", "vehicle", "src", "dst", "pair", "name")


@functools.cache
def _written_schema(table: str) -> pa.Schema:
    return pa.schema([pa.field(f.name, pa.dictionary(pa.int32(), f.type)) if f.name in _AS_DICTIONARY else f
                      for f in SCHEMAS[table]])


def by_name(names: pa.Array) -> tuple[pa.Array, pa.DictionaryArray]:
    """(the indices that sort ``names``, rows of one name in the order they came: a stable sort;
    the names so sorted, as a dictionary array). The sort is on each row's rank among the
    distinct names, 3 times faster than on the strings."""
    d = pc.dictionary_encode(names)
    order = pc.sort_indices(pc.rank(d.dictionary, tiebreaker="first").take(d.indices))
    return order, pa.DictionaryArray.from_arrays(d.indices.take(order), d.dictionary)


def name_groups(names: pa.Array, least: int = NAME_GROUP_ROWS) -> list[int]:
    """The row group sizes of values rows sorted by name: each a run of whole names of at least
    ``least`` rows (unless there are fewer in all). A row group's name statistics then span only
    its own names, and a reader asking for one name (``WHERE name = ...``) skips the other row
    groups."""
    if pa.types.is_dictionary(names.type):  # (a unique dictionary: one index per name)
        names = names.indices
    groups: list[int] = []
    held = at = 0
    for end in pc.run_end_encode(names).run_ends.to_pylist():
        held += end - at
        at = end
        if held >= least:
            groups.append(held)
            held = 0
    if held:
        if groups:
            groups[-1] += held  # (a short tail joins the group before it)
        else:
            groups.append(held)
    return groups


class _Rows:
    """One capture's rows: held per partition as the frames themselves, written a partition at
    a time, column by column (the values rows' frame columns taken from the frames'), one row
    group per table per flush into one Parquet file per table and partition. At most about
    ``batch_rows`` rows (frames and values together) are held."""

    def __init__(self, root: Path, capture: str, vehicle: str, stem: str, batch_rows: int) -> None:
        self.root, self.capture, self.vehicle, self.stem = root, capture, vehicle, stem
        self.batch_rows = max(1, batch_rows)
        self.parts: dict[tuple[str, str, str], Part] = {}
        self.writers: dict[tuple[str, str, str, str], tuple[pq.ParquetWriter, Path, Path]] = {}
        self.convs: dict[tuple, tuple[str, str]] = {}
        self.typed: dict[tuple[int | None, str], tuple[int | None, float | None, str | None]] = {}
        self.repeated: set[str] = set()  # value texts met once (typed values are kept from the second time)
        self.values = 0  # values rows written
        self.packets = PacketRows()  # the packets table's rows held
        self.health = HealthRows()  # the links and outages tables, written at the end

    def held(self) -> int:
        return sum(p.held() for p in self.parts.values())

    def flush_largest(self) -> None:
        self._flush(max(self.parts, key=lambda k: self.parts[k].held()))

    def _flush(self, key: tuple[str, str, str]) -> None:
        part = self.parts.pop(key, None)
        if part is None or not part.seq:
            return
        n = len(part.seq)
        link = link_name(part.src, part.dst)
        convs = self.convs
        for c in set(part.conv):
            if c not in convs:
                convs[c] = _conversation(c)
        conv = [convs[c] for c in part.conv]
        seq = pa.array(part.seq, pa.int64())
        number = pa.array(part.number, pa.int64())
        time_ns = pa.array(part.ts_ns, pa.int64())
        raws = part.raw
        offsets = array("i", accumulate(map(len, raws), initial=0))
        raw = pa.BinaryArray.from_buffers(pa.binary(), n, [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(raws))])
        frames = {
            **self._fixed(part, n), "seq": seq, "frame": number, "time_ns": time_ns,
            "transport": pa.array(list(map(_FIRST, conv)), pa.string()),
            "conversation": pa.array(list(map(_SECOND, conv)), pa.string()),
            "kind": pa.array(part.kind, pa.string()),
            "checksum_ok": pa.array(part.ok, pa.bool_()),
            "late": pa.array(part.late, pa.bool_()),
            "size": pc.subtract(pa.Array.from_buffers(pa.int32(), n, [None, pa.py_buffer(offsets)], offset=1),
                                pa.Array.from_buffers(pa.int32(), n, [None, pa.py_buffer(offsets)])),
            "raw": raw,
        }
        self._write("frames", (part.day, link), frames, n)
        # values: every value row, its frame's columns taken by the frame's index
        m = len(part.name)
        if not m:
            return
        # (each row's frame index: the parents of a list array whose lists are the frames' rows)
        take = pc.list_parent_indices(pa.ListArray.from_arrays(
            pa.array(accumulate(part.nvalues, initial=0), pa.int32()), pa.nulls(m)))
        tc = pa.array(part.type_code, pa.int8())
        text_a = pa.array(part.text, pa.string())
        vlong, vdouble, vstring = self._typed_columns(part.type_code, part.text, tc, text_a)
        order, name = by_name(pa.array(part.name, pa.string()))
        take = take.take(order)
        values = {
            **self._fixed(part, m),
            "seq": seq.take(take), "frame": number.take(take), "time_ns": time_ns.take(take),
            "name": name, "type": tc.take(order),
            "text": text_a.take(order), "value_long": vlong.take(order), "value_double": vdouble.take(order),
            "value_string": vstring.take(order),
            "carried": pa.array(part.carried, pa.bool_()).take(order),
            "changed": pa.array(part.changed, pa.bool_()).take(order),
        }
        self._write("values", (part.day, link), values, m, name_groups(name, NAME_GROUP_ROWS))
        self.values += m

    def _typed_columns(self, tc: list, text: list, tc_a: pa.Array, text_a: pa.Array
                       ) -> tuple[pa.Array, pa.Array, pa.Array]:
        """value_long, value_double and value_string of values rows. A double whose text fits
        its type (:func:`~sharedlink.protocols.codec.parse_typed`'s pattern, matched by Arrow)
        is converted by Arrow, all such in one cast (Arrow parses the protocol's number forms to
        the same doubles as ``float``: checked by the tests); every other row by
        :func:`_typed`, a value met twice kept."""
        m = len(text)
        is_d = pc.fill_null(pc.and_(pc.equal(tc_a, TYPE_DOUBLE), pc.match_substring_regex(text_a, _DOUBLE_RE2)), False)
        doubles = pc.cast(pc.filter(text_a, is_d), pa.float64())
        if len(doubles) == m:
            return pa.nulls(m, pa.int64()), doubles, pa.nulls(m, pa.string())
        typed, repeated = self.typed, self.repeated
        if len(typed) > 4096 or len(repeated) > 65536:
            typed.clear()
            repeated.clear()
        rows = []
        for k, d in zip(zip(tc, text), is_d.to_pylist()):
            if d:
                continue
            t = typed.get(k)
            if t is None:
                t = _typed(k[0], k[1])
                if k[1] in repeated:  # (a value met twice is likely to come again: carried)
                    typed[k] = t
                else:
                    repeated.add(k[1])
            rows.append(t)
        not_d = pc.invert(is_d)
        vlong = pc.replace_with_mask(pa.nulls(m, pa.int64()), not_d, pa.array(list(map(_FIRST, rows)), pa.int64()))
        vdouble = pc.replace_with_mask(pc.replace_with_mask(pa.nulls(m, pa.float64()), is_d, doubles), not_d,
                                       pa.array(list(map(_SECOND, rows)), pa.float64()))
        vstring = pc.replace_with_mask(pa.nulls(m, pa.string()), not_d, pa.array(list(map(_THIRD, rows)), pa.string()))
        return vlong, vdouble, vstring

    def _fixed(self, part: Part, n: int) -> dict[str, pa.Array]:
        """The columns that are one value throughout a partition's rows of this capture (as
        dictionary arrays: see :data:`_AS_DICTIONARY`)."""
        zeros = pa.repeat(pa.scalar(0, pa.int32()), n)
        return {c: pa.DictionaryArray.from_arrays(zeros, pa.array([x], pa.string())) for c, x in (
            ("capture", self.capture), ("vehicle", self.vehicle), ("src", part.src), ("dst", part.dst),
            ("pair", f"{part.src}>{part.dst}"))}

    def _write(self, table: str, part: tuple[str, str], cols: dict[str, pa.Array], n: int,
               groups: Sequence[int] = ()) -> None:
        """The rows as one row group, or as row groups of ``groups`` rows each."""
        schema = _written_schema(table)
        key = (table, *part)
        w = self.writers.get(key)
        if w is None:
            d = self.root / table / partition_dir(*part)
            d.mkdir(parents=True, exist_ok=True)
            final = d / f"{self.stem}.parquet"
            tmp = d / f".{self.stem}.parquet"
            writer = pq.ParquetWriter(tmp, schema, compression="zstd",
                                      use_dictionary=[c for c in _DICTIONARY if c in schema.names],
                                      column_encoding={c: "DELTA_BINARY_PACKED" for c in _DELTA if c in schema.names},
                                      store_schema=False)
            w = self.writers[key] = (writer, tmp, final)
        batch = pa.RecordBatch.from_arrays([cols[f.name] for f in schema], schema=schema)
        at = 0
        for rows in groups or (n,):
            w[0].write_batch(batch.slice(at, rows), row_group_size=rows)
            at += rows

    def add_packet(self, m: SessionMessage) -> None:
        """A P2OS or blackboard message's row, in its UTC day's partition; the rows held are
        written once there are ``batch_rows``."""
        self.packets.add(m, day_of(m.ts_ns))
        if self.packets.held >= self.batch_rows:
            self.flush_packets()

    def flush_packets(self) -> None:
        for part, rs in self.packets.take():
            self._write("packets", part, packet_columns(rs, self.capture, self.vehicle), len(rs))

    def close_counts(self) -> int:
        """Write what is held; the values rows written in all."""
        for key in list(self.parts):
            self._flush(key)
        self.flush_packets()
        for table, part, cols, n in self.health.tables(self.capture, self.vehicle):
            self._write(table, part, cols, n)
        return self.values

    def close(self) -> list[str]:
        """Flush, close and rename the files into place; their paths relative to the dataset."""
        self.close_counts()
        out = []
        for writer, tmp, final in self.writers.values():
            writer.close()
            tmp.replace(final)
            out.append(final.relative_to(self.root).as_posix())
        self.writers.clear()
        return sorted(out)

    def abort(self) -> None:
        for writer, tmp, _final in self.writers.values():
            try:
                writer.close()
            finally:
                tmp.unlink(missing_ok=True)
        self.writers.clear()
        self.parts.clear()


# -- the driver ---------------------------------------------------------------------------------------


@dataclass
class IngestReport:
    outcomes: list[Outcome] = field(default_factory=list)
    swept: int = 0  # stray files of an interrupted earlier ingest, deleted

    @property
    def ok(self) -> bool:
        return all(o.status in ("ingested", "unchanged") for o in self.outcomes)

    def count(self, status: str) -> int:
        return sum(o.status == status for o in self.outcomes)

    @property
    def frames(self) -> int:
        return sum(o.entry.frames for o in self.outcomes if o.entry is not None)

    @property
    def values(self) -> int:
        return sum(o.entry.values for o in self.outcomes if o.entry is not None)


def find_captures(inputs: Iterable[str | Path]) -> list[Path]:
    """The capture files named, directories searched (recursively) for ``*.pcap``, ``*.pcapng``
    and ``*.cap``; UsageError for a name that does not exist."""
    out: list[Path] = []
    for name in inputs:
        p = Path(name)
        if p.is_dir():
            out += sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in CAPTURE_SUFFIXES)
        elif p.exists():
            out.append(p)
        else:
            raise UsageError(f"{p}: no such file or directory")
    return list(dict.fromkeys(p.resolve() for p in out))  # each once, in order


def options_key(variables: Sequence[tuple[str, int | None]], sync_interval: float) -> str:
    """The decode options as the manifest records them (a change re-ingests)."""
    names = ",".join(n if t is None else f"{n}:{t}" for n, t in variables)
    return f"variables={names};sync-interval={sync_interval:g}"


def ingest(
    inputs: Iterable[str | Path],
    root: str | Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    scheduler_timeout: float = SCHEDULER_TIMEOUT_S,
    vehicle: str | None = None,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    force: bool = False,
    batch_rows: int = BATCH_ROWS,
    on_outcome: Callable[[Outcome], None] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> IngestReport:
    """Ingest captures (files or directories) into the dataset at ``root`` (made if need be).

    ``vehicle`` names the vehicle of every capture; by default a capture's vehicle is the name
    of the directory it is in. Unchanged captures (same content and options) are skipped unless
    ``force``. ``workers`` local processes, or the Dask scheduler at ``scheduler`` (given up after
    ``scheduler_timeout`` seconds: a usage error).
    ``progress(bytes, records)``: the bytes and records of the captures read so far (all
    together), with one local worker now and then while a capture is decoded, with more or a
    scheduler as each capture is done.
    """
    root = Path(root)
    if workers < 1:
        raise UsageError("--workers must be at least 1")
    paths = find_captures(inputs)
    if root.exists() and not root.is_dir():
        raise UsageError(f"{root}: not a directory")
    report = IngestReport()
    opts = options_key(variables, sync_interval)
    with locked(root):
        manifest = load_manifest(root)
        if not (root / MANIFEST).exists():
            save_manifest(root, manifest)  # a dataset from now on, even with no capture yet
        report.swept = sweep(root, manifest)
        tasks = [_task(p, root, manifest, vehicle, opts, variables, sync_interval, force, batch_rows) for p in paths]
        tasks.sort(key=lambda t: -_size(t.path))  # big ones first: better balance
        run = _run_dask(tasks, scheduler, scheduler_timeout) if scheduler else _run_local(tasks, workers, progress)
        done = records = 0
        batch = _ManifestBatch(root, manifest)
        try:
            for outcome in run:
                done += _size(outcome.path)
                records += outcome.entry.records if outcome.entry is not None else 0
                if progress is not None:
                    progress(done, records)
                batch.record(outcome)
                report.outcomes.append(outcome)
                if on_outcome is not None:
                    on_outcome(outcome)
        finally:
            batch.save()
    return report


def _task(path: Path, root: Path, manifest: Manifest, vehicle: str | None, opts: str,
          variables: Sequence[tuple[str, int | None]], sync_interval: float, force: bool, batch_rows: int) -> Task:
    key = str(path)
    vehicle = vehicle or path.parent.name
    opts = f"{opts};vehicle={vehicle}"
    old = manifest.captures.get(key)
    known = old.hash if old is not None and old.options == opts and not force else None
    return Task(
        path=key,
        root=str(root.resolve()),
        id=hashlib.blake2b(key.encode(), digest_size=8).hexdigest(),
        vehicle=vehicle,
        options=opts,
        variables=tuple(variables),
        sync_interval=sync_interval,
        known_hash=known,
        batch_rows=batch_rows,
    )


def _size(path: str) -> int:
    try:
        return Path(path).stat().st_size
    except OSError:
        return 0


class _ManifestBatch:
    """The results of an ingest put in the manifest in batches (issue 44: the whole manifest
    rewritten after each capture made 1,600 small captures cost 10.6 times the CPU of 400).

    The manifest is saved (atomically: :func:`save_manifest`) once the results waiting number
    an eighth of the captures it lists (at least one), and at the end of the ingest, so its
    rewrites cost linear time in all. Still crash-consistent: a capture's new files are written
    before the manifest lists them (a crash leaves them unlisted: the next ingest sweeps them and
    ingests the capture again), and the files a result replaces are deleted only after the save
    that stops listing them."""

    def __init__(self, root: Path, manifest: Manifest) -> None:
        self.root, self.manifest = root, manifest
        self.waiting = 0  # results in ``manifest`` not yet saved
        self.replaced: list[str] = []  # files of replaced entries, deleted after the next save

    def record(self, outcome: Outcome) -> None:
        """Put a result in the manifest (saved when the batch is full)."""
        manifest = self.manifest
        if outcome.status == "unchanged":
            old = manifest.captures.get(outcome.path)
            if old is not None and old.error:  # still damaged: say so again
                outcome.status, outcome.error = "damaged", old.error
            return
        if outcome.entry is None:
            return
        old = manifest.captures.get(outcome.path)
        manifest.captures[outcome.path] = outcome.entry
        if old is not None:
            self.replaced += sorted(set(old.files) - set(outcome.entry.files))
        self.waiting += 1
        if self.waiting >= max(1, len(manifest.captures) // 8):
            self.save()

    def save(self) -> None:
        """Save the waiting results, then delete the files they replace."""
        if not self.waiting:
            return
        save_manifest(self.root, self.manifest)
        self.waiting = 0
        if self.replaced:
            for f in self.replaced:
                (self.root / f).unlink(missing_ok=True)
            self.replaced = []
            sweep(self.root, self.manifest)


def _run_local(tasks: list[Task], workers: int, progress: Callable[[int, int], None] | None = None
               ) -> Iterator[Outcome]:
    if workers == 1 or len(tasks) <= 1:
        before = records = 0
        for t in tasks:
            inner = None if progress is None else (lambda b, r, at=(before, records): progress(at[0] + b, at[1] + r))
            outcome = _guarded(t, inner)
            before += _size(t.path)
            records += outcome.entry.records if outcome.entry is not None else 0
            yield outcome
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=min(workers, len(tasks))) as pool:
        futures = [pool.submit(_guarded, t) for t in tasks]
        try:
            for fut in as_completed(futures):
                yield fut.result()
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _run_dask(tasks: list[Task], address: str, timeout: float = SCHEDULER_TIMEOUT_S) -> Iterator[Outcome]:
    try:
        from distributed import Client, as_completed
    except ImportError:  # pragma: no cover - dask is a dependency
        raise UsageError("--scheduler needs dask[distributed] installed") from None
    try:
        client = Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--scheduler {address}: cannot reach the Dask scheduler ({exc})") from None
    with client:
        futures = client.map(_guarded, tasks, pure=False)
        for fut in as_completed(futures):
            yield fut.result()


def _guarded(task: Task, progress: Callable[[int, int], None] | None = None) -> Outcome:
    """:func:`ingest_capture`, with an unexpected failure reported as the capture's outcome."""
    try:
        return ingest_capture(task, progress)
    except (OSError, ValueError, pa.ArrowException) as exc:
        return Outcome(task.path, "failed", error=f"{task.path}: {exc}")
