"""A fleet dataset on disk: its Parquet tables, their Hive partitions and the manifest.

Layout (``docs/fleet.md``)::

    DATASET/_manifest.json                     which captures are in, and their files
    DATASET/frames/day=2026-01-01/link=B_to_A/<capture id>-<run>.parquet
    DATASET/values/day=2026-01-01/link=B_to_A/<capture id>-<run>.parquet
    DATASET/packets/day=2026-01-01/link=p2os/<capture id>-<run>.parquet   (P2OS, blackboard)
    DATASET/links/day=2026-01-01/link=B_to_A/<capture id>-<run>.parquet   (link health per second)
    DATASET/outages/day=2026-01-01/link=B_to_A/<capture id>-<run>.parquet

* ``day`` is the frame's UTC date, ``link`` its node pair as identifiers spell it, ``SRC_to_DST``
  (``B_to_A``: from B to A; ``>`` is kept out of directory names; docs/cli.md "Words"). Both come
  from the path (Hive partitioning), not from the files, so every engine that reads Hive
  partitions (DuckDB, pyarrow, Dask, Polars, Spark) sees them as columns. Datasets written before
  issue 41 have ``link=B-A`` folders (:func:`old_links`): their manifest lists those files, read
  as they are, and ``sharedlink query``'s ``link`` column says ``B_to_A`` for them too.
* The manifest is the truth: a query reads the files it lists. A capture's files are written
  under hidden names (``.<name>``, which Parquet readers skip) and renamed when complete; the
  manifest is replaced atomically; then the files it no longer lists are deleted. A crash leaves
  at worst files no manifest lists; the next ingest deletes them.
* One ingest at a time per dataset (an exclusive lock on ``DATASET/_lock``).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from urllib.parse import quote

from sharedlink.capture.pcapio import atomic_open
from sharedlink.errors import UsageError

# -- layout --------------------------------------------------------------------------------------
MANIFEST = "_manifest.json"
LOCK = "_lock"
TABLES = ("frames", "values", "packets", "links", "outages")
#: manifest format version
VERSION = 1
#: partition keys, in directory order
PARTITION_KEYS = ("day", "link")

# -- tables --------------------------------------------------------------------------------------
# (Arrow types by name: the schemas are made on first use, so that ``sharedlink query``, which
# reads through DuckDB, does not import pyarrow, a tenth of a second and more)
#: one row per SharedLink frame
FRAMES_COLUMNS = (
    ("capture", "string"),  # the capture's path as ingested
    ("vehicle", "string"),
    ("seq", "int64"),  # the frame's ordinal in its capture, from 1 (several frames may share a record)
    ("frame", "int64"),  # record number (Wireshark's frame.number)
    ("time_ns", "int64"),  # UTC, ns since 1970
    ("transport", "string"),  # udp, tcp or serial
    ("conversation", "string"),  # "udp 10.0.0.2:7013 > 255.255.255.255:7013", "serial outbound if0"
    ("src", "string"),
    ("dst", "string"),
    ("pair", "string"),  # "B>A": from B to A
    ("kind", "string"),  # full, delta, reply, query, declaration, ... (as the dissector)
    ("checksum_ok", "bool_"),  # null: the frame has no checksum field
    ("late", "bool_"),  # sharedlink.sync.late
    ("size", "int32"),  # bytes of the frame, CR LF included
    ("raw", "binary"),  # the frame's bytes
)
#: one row per variable value a frame with a good (or no) checksum leaves
VALUES_COLUMNS = (
    ("capture", "string"),
    ("vehicle", "string"),
    ("seq", "int64"),  # joins frames.seq (with capture)
    ("frame", "int64"),
    ("time_ns", "int64"),
    ("src", "string"),
    ("dst", "string"),
    ("pair", "string"),
    ("name", "string"),
    ("type", "int8"),  # the T code (0 long, 2 double, 4 string); null when none was declared
    ("text", "string"),  # the value as written
    ("value_long", "int64"),  # integers
    ("value_double", "float64"),  # every numeric value (integers too)
    ("value_string", "string"),  # values that are not numbers
    ("carried", "bool_"),  # not in the frame: carried forward from an earlier one (compression)
    ("changed", "bool_"),  # differs from the value before this frame
)
#: one row per P2OS packet or blackboard message (a slave's answer too), issue 42; the partition's
#: ``link`` is the protocol ("p2os", "blackboard"); the columns as ``export`` names them
#: (analysis/robot_export.py), typed
PACKETS_COLUMNS = (
    ("capture", "string"),
    ("vehicle", "string"),
    ("protocol", "string"),  # p2os, blackboard
    ("frame", "int64"),  # record number that completed the packet
    ("time_ns", "int64"),
    ("session", "int32"),  # 1, 2, ... in the capture
    ("conversation", "string"),  # "tcp 127.0.0.1:8101 - 127.0.0.1:45678", "serial interface 0"
    ("side", "string"),  # p2os: client, robot; blackboard: master, slave
    ("type", "string"),  # command name, SIP, ENCODER, SYNC2 echo, ...; set, request, ack, response
    ("checksum_ok", "bool_"),  # null: nothing to check
    ("size", "int32"),
    ("command", "string"),
    ("arg_int", "int64"),
    ("arg_text", "string"),
    ("x_mm", "int32"),  # SIP: robot odometry frame
    ("y_mm", "int32"),
    ("heading_deg", "float64"),
    ("left_velocity_mm_s", "int32"),
    ("right_velocity_mm_s", "int32"),
    ("velocity_mm_s", "float64"),
    ("battery_v", "float64"),
    ("stall_left", "bool_"),
    ("stall_right", "bool_"),
    ("motors_enabled", "bool_"),
    ("moving", "bool_"),
    ("compass_deg", "int32"),
    ("sonars_mm", "string"),  # "number:range ..."
    ("encoder_left", "int64"),
    ("encoder_right", "int64"),
    ("robot_name", "string"),
    ("robot_class", "string"),
    ("robot_subclass", "string"),
    ("address", "int32"),  # blackboard
    ("node", "int32"),
    ("count", "int32"),
    ("data", "binary"),
    ("error", "string"),
    ("raw", "binary"),
)
#: link health (issue 43, analysis/health.py, fleet/health_rows.py): one row per SharedLink link and
#: second (epoch-aligned, from the link's first frame's second to the capture's end)
LINKS_COLUMNS = (
    ("capture", "string"),
    ("vehicle", "string"),
    ("time_ns", "int64"),  # the second's start, UTC ns since 1970
    ("conversation", "string"),  # the link: "10.0.0.2:7013 > 255.255.255.255:7013", "serial inbound"
    ("src", "string"),
    ("dst", "string"),
    ("pair", "string"),
    ("frames", "int32"),  # frames received in the second
    ("state", "string"),  # up, down (an outage in progress at the second's end, no frame in it)
    ("quality", "float64"),  # Shepherd's Link Quality: frames while up, seconds of outage while down
    ("down_s", "float64"),  # null while up: the seconds since the outage began
)
#: one row per outage of a SharedLink link (as stats --json's "outages")
OUTAGES_COLUMNS = (
    ("capture", "string"),
    ("vehicle", "string"),
    ("time_ns", "int64"),  # the start: the link's last frame before the silence
    ("conversation", "string"),
    ("src", "string"),
    ("dst", "string"),
    ("pair", "string"),
    ("end_ns", "int64"),  # the frame after it; null when open at the capture's end
    ("duration_ns", "int64"),  # to end_ns, or to the capture's end
    ("duration_s", "float64"),
    ("open", "bool_"),
)
COLUMNS = {"frames": FRAMES_COLUMNS, "values": VALUES_COLUMNS, "packets": PACKETS_COLUMNS, "links": LINKS_COLUMNS,
           "outages": OUTAGES_COLUMNS}
#: DuckDB's names of the Arrow types above
DUCKDB_TYPES = {"string": "VARCHAR", "int64": "BIGINT", "int32": "INTEGER", "int8": "TINYINT", "float64": "DOUBLE",
                "bool_": "BOOLEAN", "binary": "BLOB"}


def __getattr__(name: str) -> object:
    """``FRAMES_SCHEMA``, ``VALUES_SCHEMA``, ``PACKETS_SCHEMA`` and ``SCHEMAS`` (table -> schema):
    the tables as pyarrow schemas, made when first asked for."""
    if name in ("FRAMES_SCHEMA", "VALUES_SCHEMA", "PACKETS_SCHEMA", "SCHEMAS"):
        import pyarrow as pa

        schemas = {t: pa.schema([(c, getattr(pa, kind)()) for c, kind in cols]) for t, cols in COLUMNS.items()}
        globals().update(FRAMES_SCHEMA=schemas["frames"], VALUES_SCHEMA=schemas["values"],
                         PACKETS_SCHEMA=schemas["packets"], SCHEMAS=schemas)
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def link_name(src: str, dst: str) -> str:
    """A node pair as identifiers spell it: ``B_to_A`` (from B to A), the ``link`` partition of
    the frames and values tables (``pair`` says ``B>A``)."""
    return f"{src}_to_{dst}"


def old_links(manifest: Manifest) -> bool:
    """Whether the frames or values files the manifest lists include some in a partition of the
    spelling before ``link_name``'s, ``link=B-A`` (a dataset written before, or ingested into
    since). New partitions always hold ``_to_`` (``_`` is never percent-encoded)."""
    return any("_to_" not in _link_of(f) for table in ("frames", "values") for f in manifest.files(table))


def _link_of(path: str) -> str:
    """The ``link=`` partition value of a table file's path (as written: percent-encoded)."""
    for part in path.split("/"):
        if part.startswith("link="):
            return part[5:]
    return "_to_"  # (no link partition: nothing old to read)


def partition_dir(day: str, link: str) -> str:
    """``day=2026-01-01/link=B_to_A``: a partition's directory below a table's. The link is
    percent-encoded past letters, digits and ``-_.~`` (a malformed frame's ``?``, any byte a
    header names: no glob, no ``/``), as Hive readers (DuckDB, pyarrow) decode it."""
    return f"day={day}/link={quote(link, safe='-')}"


# -- manifest ------------------------------------------------------------------------------------


@dataclass
class CaptureEntry:
    """One ingested capture, as the manifest records it."""

    path: str
    size: int
    hash: str  # "blake2b:<hex>" of the content
    id: str  # stable per path: the prefix of its files
    vehicle: str
    options: str  # the decode options it was ingested with
    frames: int = 0
    values: int = 0
    records: int = 0
    packets: int = 0  # P2OS packets and blackboard messages (the packets table)
    first_ns: int | None = None
    last_ns: int | None = None
    error: str | None = None  # damaged here: the rows are what came before
    files: list[str] = field(default_factory=list)  # relative to the dataset


@dataclass
class Manifest:
    captures: dict[str, CaptureEntry] = field(default_factory=dict)  # by path

    def files(self, table: str) -> list[str]:
        return sorted(f for e in self.captures.values() for f in e.files if f.startswith(table + "/"))


def load_manifest(root: Path) -> Manifest:
    """The manifest of ``root`` (empty when there is none yet); UsageError if unreadable."""
    p = root / MANIFEST
    if not p.exists():
        return Manifest()
    try:
        doc = json.loads(p.read_text())
        if doc.get("version") != VERSION:
            raise ValueError(f"version {doc.get('version')!r}, expected {VERSION}")
        return Manifest({k: CaptureEntry(**v) for k, v in doc["captures"].items()})
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UsageError(f"{p}: not a fleet dataset manifest ({exc})") from None


def save_manifest(root: Path, manifest: Manifest) -> None:
    doc = {"version": VERSION, "captures": {k: asdict(v) for k, v in sorted(manifest.captures.items())}}
    with atomic_open(root / MANIFEST, "w") as fh:
        json.dump(doc, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())


def require_dataset(root: Path) -> Manifest:
    """The manifest of an existing dataset; UsageError when ``root`` is not one."""
    if not (root / MANIFEST).exists():
        raise UsageError(f"{root}: not a fleet dataset (no {MANIFEST}; make one with sharedlink ingest)")
    return load_manifest(root)


@contextlib.contextmanager
def locked(root: Path) -> Iterator[None]:
    """Hold the dataset's ingest lock (one ingest at a time); UsageError if another holds it,
    or if ``root`` cannot be the dataset's directory (a file, a link to nothing)."""
    if root.is_symlink() and not root.exists():
        raise UsageError(f"{root}: a symbolic link to nothing; give the dataset's directory")
    if root.exists() and not root.is_dir():
        raise UsageError(f"{root}: not a directory; give the dataset's directory")
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{root}: cannot make the dataset's directory: {exc.strerror}") from None
    with open(root / LOCK, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UsageError(f"{root}: another ingest is writing this dataset") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def sweep(root: Path, manifest: Manifest) -> int:
    """Delete the table files (finished or half-written) the manifest does not list, and the
    partition directories left empty; the number of files deleted."""
    keep = {f for e in manifest.captures.values() for f in e.files}
    gone = 0
    for table in TABLES:
        base = root / table
        if not base.is_dir():
            continue
        for p in sorted(base.rglob("*.parquet")):
            if p.relative_to(root).as_posix() not in keep:
                p.unlink()
                gone += 1
        for d in sorted((d for d in base.rglob("*") if d.is_dir()), key=lambda d: -len(d.parts)):
            with contextlib.suppress(OSError):
                d.rmdir()  # only empty ones go
    return gone
