"""``sharedlink ingest``: captures into a fleet dataset, one capture per task, on local processes
or a Dask distributed cluster.

A task (:func:`ingest_capture`) hashes its capture, and unless the manifest already holds that
content with the same decode options, decodes it with :func:`sharedlink.analysis.decode.iter_decoded`
(the one decoder of the package) and writes its rows to the dataset as it goes: rows are buffered
up to ``batch_rows`` in all (whatever the capture's size) and each flush is one Parquet row group,
so a worker's memory does not grow with the capture. The driver (:func:`ingest`) holds the
dataset's lock, hands out the tasks, and records each result in the manifest as it arrives,
deleting the files a re-ingested capture replaces (see :mod:`.dataset` for why that is safe).

A damaged capture keeps the rows decoded before the damage; its manifest entry carries the
error and the report lists it. Workers write straight into the dataset directory: with
``scheduler`` it must be on a filesystem the workers share with the driver.
"""

from __future__ import annotations

import hashlib
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from sharedlink.analysis.decode import NS, Decoded, iter_decoded
from sharedlink.errors import InputError, UsageError
from sharedlink.fleet import BATCH_ROWS as BATCH_ROWS  # its home is the package (a light import for the CLI)
from sharedlink.fleet.dataset import (
    MANIFEST,
    SCHEMAS,
    CaptureEntry,
    Manifest,
    load_manifest,
    locked,
    partition_dir,
    save_manifest,
    sweep,
)
from sharedlink.protocols.codec import guess_value, typed_value
from sharedlink.protocols.state import BEACON_VARIABLES

#: file name endings taken as captures when a directory is given
CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap")
DAY_NS = 86_400 * NS
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


def ingest_capture(task: Task) -> Outcome:
    """Ingest one capture (see the module doc). Never raises for a bad capture: the outcome says."""
    try:
        size, digest = content_hash(task.path)
    except OSError as exc:
        return Outcome(task.path, "failed", error=f"{task.path}: {exc.strerror or exc}")
    if digest == task.known_hash:
        return Outcome(task.path, "unchanged")
    entry = CaptureEntry(task.path, size, digest, task.id, task.vehicle, task.options)
    run = uuid.uuid4().hex[:8]
    writers = {t: _TableWriter(Path(task.root), t, f"{task.id}-{run}", task.batch_rows) for t in SCHEMAS}
    try:
        _decode_into(task, entry, writers["frames"], writers["values"])
        for w in writers.values():
            entry.files += w.close()
    except BaseException:
        for w in writers.values():
            w.abort()
        raise
    return Outcome(task.path, "damaged" if entry.error else "ingested", entry, entry.error)


def _decode_into(task: Task, entry: CaptureEntry, frames: _TableWriter, values: _TableWriter) -> None:
    cap, vehicle = task.path, task.vehicle
    days: dict[int, str] = {}
    convs: dict[tuple, tuple[str, str]] = {}
    seen: dict[tuple[int | None, str], tuple[int | None, float | None, str | None]] = {}
    seq = 0
    try:
        for item in iter_decoded(cap, task.variables, task.sync_interval):
            if not isinstance(item, Decoded):
                entry.records = max(entry.records, item[0] if isinstance(item, tuple) else item.number)
                continue
            seq += 1
            ts = item.ts_ns
            entry.records = max(entry.records, item.number)
            if entry.first_ns is None:
                entry.first_ns = ts
            entry.last_ns = ts
            day = days.get(ts // DAY_NS)
            if day is None:
                day = days[ts // DAY_NS] = _day(ts)
            conv = convs.get(item.conv)
            if conv is None:
                conv = convs[item.conv] = _conversation(item.conv)
            src, dst = item.src, item.dst  # (not item.frame: the core's fast frames are not parsed)
            pair = f"{src}>{dst}"
            key = (day, f"{src}-{dst}")
            frames.add(key, (cap, vehicle, seq, item.number, ts, conv[0], conv[1], src, dst, pair, item.kind,
                             item.checksum_ok, item.late, len(item.raw), item.raw))
            entry.frames += 1
            head = (cap, vehicle, seq, item.number, ts, src, dst, pair)
            tvars = item.table.vars
            for u in item.updates:
                if u.text is None:
                    continue
                tv = tvars.get(u.name)
                tc = tv.type_code if tv is not None else None
                typed = seen.get((tc, u.text))
                if typed is None:  # carried values repeat row after row: typed once
                    if len(seen) >= 1024:
                        seen.clear()
                    typed = seen[(tc, u.text)] = _typed(tc, u.text)
                values.add(key, head + (u.name, tc, u.text, *typed, u.carried, u.changed))
                entry.values += 1
    except InputError as exc:  # damage: the rows before it are kept
        entry.error = str(exc)


def _typed(type_code: int | None, text: str) -> tuple[int | None, float | None, str | None]:
    """(value_long, value_double, value_string) of a value: doubles hold every number."""
    x = guess_value(text) if type_code is None else typed_value(type_code, text)
    if isinstance(x, str):
        return None, None, x
    if isinstance(x, int):
        return (x, float(x), None) if -(1 << 63) <= x < (1 << 63) else (None, float(x), None)
    return None, x, None


def _day(ts_ns: int) -> str:
    import datetime as _dt

    return _dt.datetime.fromtimestamp(ts_ns // NS, _dt.timezone.utc).strftime("%Y-%m-%d")


def _conversation(conv: tuple) -> tuple[str, str]:
    """(transport, conversation text) of a frame's ``conv`` tuple (see StreamFrame)."""
    proto = str(conv[0])
    if proto == "serial":
        return proto, f"serial {conv[1]} if{conv[4]}"
    return proto, f"{proto} {conv[1]}:{conv[2]} > {conv[3]}:{conv[4]}"


class _TableWriter:
    """Rows of one table of one capture into one Parquet file per partition, a row group per
    flush; at most ``batch_rows`` rows are held at once, over all partitions."""

    def __init__(self, root: Path, table: str, stem: str, batch_rows: int) -> None:
        self.root, self.table, self.stem, self.batch_rows = root, table, stem, batch_rows
        self.schema = SCHEMAS[table]
        self.rows: dict[tuple[str, str], list[tuple]] = {}
        self.held = 0
        self.writers: dict[tuple[str, str], tuple[pq.ParquetWriter, Path, Path]] = {}

    def add(self, key: tuple[str, str], row: tuple) -> None:
        rows = self.rows.get(key)
        if rows is None:
            rows = self.rows[key] = []
        rows.append(row)
        self.held += 1
        if self.held >= self.batch_rows:
            self._flush(max(self.rows, key=lambda k: len(self.rows[k])))

    def _flush(self, key: tuple[str, str]) -> None:
        rows = self.rows.pop(key, None)
        if not rows:
            return
        self.held -= len(rows)
        w = self.writers.get(key)
        if w is None:
            d = self.root / self.table / partition_dir(*key)
            d.mkdir(parents=True, exist_ok=True)
            final = d / f"{self.stem}.parquet"
            tmp = d / f".{self.stem}.parquet"
            w = self.writers[key] = (pq.ParquetWriter(tmp, self.schema, compression="zstd"), tmp, final)
        cols = [pa.array(c, type=f.type) for c, f in zip(zip(*rows), self.schema)]
        w[0].write_batch(pa.RecordBatch.from_arrays(cols, schema=self.schema))

    def close(self) -> list[str]:
        """Flush, close and rename the files into place; their paths relative to the dataset."""
        for key in list(self.rows):
            self._flush(key)
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
        self.rows.clear()


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
    vehicle: str | None = None,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    force: bool = False,
    batch_rows: int = BATCH_ROWS,
    on_outcome: Callable[[Outcome], None] | None = None,
) -> IngestReport:
    """Ingest captures (files or directories) into the dataset at ``root`` (made if need be).

    ``vehicle`` names the vehicle of every capture; by default a capture's vehicle is the name
    of the directory it is in. Unchanged captures (same content and options) are skipped unless
    ``force``. ``workers`` local processes, or the Dask scheduler at ``scheduler``.
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
        run = _run_dask(tasks, scheduler) if scheduler else _run_local(tasks, workers)
        for outcome in run:
            _record(root, manifest, outcome)
            report.outcomes.append(outcome)
            if on_outcome is not None:
                on_outcome(outcome)
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


def _record(root: Path, manifest: Manifest, outcome: Outcome) -> None:
    """Put a result in the manifest, then delete the files it replaces."""
    if outcome.status == "unchanged":
        old = manifest.captures.get(outcome.path)
        if old is not None and old.error:  # still damaged: say so again
            outcome.status, outcome.error = "damaged", old.error
        return
    if outcome.entry is None:
        return
    old = manifest.captures.get(outcome.path)
    manifest.captures[outcome.path] = outcome.entry
    save_manifest(root, manifest)
    if old is not None:
        for f in set(old.files) - set(outcome.entry.files):
            (root / f).unlink(missing_ok=True)
        sweep(root, manifest)


def _run_local(tasks: list[Task], workers: int) -> Iterator[Outcome]:
    if workers == 1 or len(tasks) <= 1:
        for t in tasks:
            yield _guarded(t)
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


def _run_dask(tasks: list[Task], address: str) -> Iterator[Outcome]:
    try:
        from distributed import Client, as_completed
    except ImportError:  # pragma: no cover - dask is a dependency
        raise UsageError("--scheduler needs dask[distributed] installed") from None
    try:
        client = Client(address, timeout=30)
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--scheduler {address}: cannot reach the Dask scheduler ({exc})") from None
    with client:
        futures = client.map(_guarded, tasks, pure=False)
        for fut in as_completed(futures):
            yield fut.result()


def _guarded(task: Task) -> Outcome:
    """:func:`ingest_capture`, with an unexpected failure reported as the capture's outcome."""
    try:
        return ingest_capture(task)
    except (OSError, ValueError, pa.ArrowException) as exc:
        return Outcome(task.path, "failed", error=f"{task.path}: {exc}")
