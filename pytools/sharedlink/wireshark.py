"""Decode captures with the project's Wireshark Lua dissector, through pyshark.

    from sharedlink.wireshark import decode
    for f in decode("beacon.pcapng"):
        print(f.number, f.src, f.dst, f.kind, {v.name: v.value for v in f.variables})

tshark runs with ``-X lua_script:<dissectors>/sharedlink.lua`` (or the path given)
in JSON mode (pyshark's EK mode cannot type Lua fields).  Each SharedLink frame becomes
one :class:`SharedLinkFrame`; a packet holding several frames yields several, with
the same ``number``.

The dissectors, the coloring rules and the extcap launcher travel with the package (package
data ``sharedlink/dissector`` and ``sharedlink/extcap_launcher``, from the repository's
``dissector/`` and ``extcap/``): :func:`dissector_dir` and :func:`extcap_launcher` find them in
the installed package, else in the source checkout the module runs from.
"""

from __future__ import annotations

import asyncio
import signal
import threading
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedlink.extras import require

_PACKAGE = Path(__file__).resolve().parent
_CHECKOUT = _PACKAGE.parents[1]  # <repo>/pytools/sharedlink -> <repo>


def _data(installed: str, checkout: str, name: str) -> Path:
    """``name`` in the installed package's data folder ``installed``, else in the checkout's
    ``checkout`` folder (an editable install, or run from the source tree); the installed
    path when neither has it (the error then names where it was looked for)."""
    for folder in (_PACKAGE / installed, _CHECKOUT / checkout):
        if (folder / name).exists():
            return folder
    return _PACKAGE / installed


def dissector_dir() -> Path:
    """The folder of the Lua dissectors (``sharedlink.lua``, the other plugins, modules in
    subfolders) and ``sharedlink.colorfilters``."""
    return _data("dissector", "dissector", "sharedlink.lua")


def dissector_files() -> list[Path]:
    """Every Lua file of the dissectors, subfolders included, sorted."""
    return sorted(dissector_dir().rglob("*.lua"))


def colorfilters_file() -> Path:
    """The coloring rules (``sharedlink.colorfilters``)."""
    return dissector_dir() / "sharedlink.colorfilters"


def extcap_launcher() -> Path:
    """The serial extcap's launcher script (``sharedlink-serial``)."""
    return _data("extcap_launcher", "extcap", "sharedlink-serial") / "sharedlink-serial"


DEFAULT_DISSECTOR = dissector_dir() / "sharedlink.lua"

CHECKSUM_STATUS = {"0": "Bad", "1": "Good", "2": "Unverified"}

__all__ = ["DEFAULT_DISSECTOR", "SharedLinkFrame", "Variable", "colorfilters_file", "decode", "dissector_dir",
           "dissector_files", "extcap_launcher", "frame_from_layer"]


@dataclass
class Variable:
    """One variable of a frame (present, carried forward, declared or a reply)."""

    name: str | None
    value: str | None
    index: int | None = None
    type: int | None = None
    double: float | None = None
    long: int | None = None
    string: str | None = None
    carried: bool = False
    carried_from: int | None = None


@dataclass
class SharedLinkFrame:
    """One decoded SharedLink frame."""

    number: int
    time: float
    src: str | None
    dst: str | None
    src_node: int | None
    dst_node: int | None
    kind: str | None
    ordinal: int | None = None
    variables: list[Variable] = field(default_factory=list)
    queries: list[str] = field(default_factory=list)
    checksum: int | None = None
    checksum_calculated: int | None = None
    checksum_status: str | None = None       # "Good", "Bad", "Unverified" or None
    response_in: int | None = None
    response_to: int | None = None
    response_time: float | None = None
    command: str | None = None
    mode: str | None = None
    experts: list[str] = field(default_factory=list)


def _as_list(v: Any) -> list[Any]:
    if v is None:
        return []
    return v if isinstance(v, list) else [v]


def _first(d: Mapping[str, Any], key: str) -> Any:
    vals = _as_list(d.get(key))
    return vals[0] if vals else None


def _int(v: Any) -> int | None:
    if v is None:
        return None
    try:
        return int(str(v), 0)
    except ValueError:
        return None


def _float(v: Any) -> float | None:
    try:
        return float(v) if v is not None else None
    except ValueError:
        return None


def _walk(d: Any, key: str) -> Iterator[Any]:
    """All values of ``key`` anywhere below ``d`` (JSON subtrees nest under labels)."""
    if isinstance(d, dict):
        for k, v in d.items():
            if k == key:
                yield from _as_list(v)
            elif isinstance(v, (dict, list)):
                yield from _walk(v, key)
    elif isinstance(d, list):
        for item in d:
            yield from _walk(item, key)


def _variable(vd: Mapping[str, Any]) -> Variable:
    return Variable(
        name=_first(vd, "sharedlink.var.name"),
        value=_first(vd, "sharedlink.var.value"),
        index=_int(_first(vd, "sharedlink.var.index")),
        type=_int(_first(vd, "sharedlink.type")),
        double=_float(_first(vd, "sharedlink.var.double")),
        long=_int(_first(vd, "sharedlink.var.long")),
        string=_first(vd, "sharedlink.var.string"),
        carried=_first(vd, "sharedlink.var.carried") in ("1", "True", "true"),
        carried_from=_int(_first(vd, "sharedlink.var.carried_from")),
    )


def frame_from_layer(layer: Mapping[str, Any], number: int = 0, time: float = 0.0) -> SharedLinkFrame:
    """Build a :class:`SharedLinkFrame` from one ``sharedlink`` layer of tshark's JSON."""
    variables = [_variable(vd) for vd in _as_list(layer.get("sharedlink.var")) if isinstance(vd, dict)]
    reply = next((vd for vd in _as_list(layer.get("sharedlink.var")) if isinstance(vd, dict)
                  and "sharedlink.response_to" in vd), {})
    status = _first(layer, "sharedlink.checksum.status")
    if status is None:
        status = next(_walk(layer.get("sharedlink.checksum_tree"), "sharedlink.checksum.status"), None)
    calc = next(_walk(layer.get("sharedlink.checksum_tree"), "sharedlink.checksum.calculated"), None)
    queries = [q for q in _as_list(layer.get("sharedlink.query")) if isinstance(q, str)]
    resp_in = next(_walk(layer, "sharedlink.response_in"), None)
    experts = [str(m) for m in _walk(layer, "_ws.expert.message")]
    return SharedLinkFrame(
        number=number,
        time=time,
        src=_first(layer, "sharedlink.src"),
        dst=_first(layer, "sharedlink.dst"),
        src_node=_int(_first(layer, "sharedlink.src.node")),
        dst_node=_int(_first(layer, "sharedlink.dst.node")),
        kind=_first(layer, "sharedlink.kind"),
        ordinal=_int(_first(layer, "sharedlink.ordinal")),
        variables=variables,
        queries=queries,
        checksum=_int(_first(layer, "sharedlink.checksum")),
        checksum_calculated=_int(calc),
        checksum_status=CHECKSUM_STATUS.get(str(status)) if status is not None else None,
        response_in=_int(resp_in),
        response_to=_int(reply.get("sharedlink.response_to")),
        response_time=_float(reply.get("sharedlink.response_time")),
        command=_first(layer, "sharedlink.command"),
        mode=_first(layer, "sharedlink.mode"),
        experts=experts,
    )


def decode(
    capture: str | Path,
    dissector: str | Path | None = None,
    prefs: Mapping[str, Any] | None = None,
    display_filter: str | None = None,
    tshark_path: str | None = None,
    extra_args: Sequence[str] = (),
) -> Iterator[SharedLinkFrame]:
    """Yield every SharedLink frame of ``capture``, decoded by tshark with the Lua dissector.

    ``prefs`` are SharedLink (or other) preferences, e.g. ``{"sharedlink.variables": "A,B"}``.
    """
    require("pyshark", "sharedlink.wireshark.decode")
    import pyshark  # imported here: optional dependency, slow import

    script = Path(dissector) if dissector is not None else DEFAULT_DISSECTOR
    if not script.is_file():
        raise FileNotFoundError(f"SharedLink dissector not found: {script}")
    override = {k: ("TRUE" if v is True else "FALSE" if v is False else str(v)) for k, v in (prefs or {}).items()}
    signals = _SignalState.save()   # before pyshark sets up its loop and child watcher
    try:
        cap = pyshark.FileCapture(
            str(capture),
            use_json=True,
            keep_packets=False,
            display_filter=display_filter,
            override_prefs=override or None,
            custom_parameters=["-X", f"lua_script:{script.resolve()}", *extra_args],
            tshark_path=tshark_path,
        )
    except BaseException:
        signals.restore()
        raise
    try:
        for pkt in cap:
            number = int(pkt.number)
            t = float(pkt.sniff_timestamp)
            for layer in pkt.layers:
                if layer.layer_name != "sharedlink":
                    continue
                dicts = [layer._all_fields] + [d._all_fields for d in getattr(layer, "duplicate_layers", [])]
                for d in dicts:
                    if d.get("sharedlink.noise") is not None and d.get("sharedlink.src") is None:
                        continue      # a noise item, not a frame
                    yield frame_from_layer(d, number, t)
    finally:
        try:
            cap.close()
        finally:
            signals.restore()


@dataclass
class _SignalState:
    """The process's SIGCHLD handler and signal wakeup fd, put back after pyshark.

    pyshark (0.6) attaches a SafeChildWatcher to its event loop for tshark: a SIGCHLD handler
    and the loop's self-pipe as the wakeup fd, left in place after the capture closes.  Nobody
    reads that pipe again, so once it filled every later signal in the caller's process (Ctrl-C
    held by a command, a test's SIGINT) reported BlockingIOError.  Only the main thread owns
    signals; elsewhere there is nothing to save.
    """

    chld: Any = None
    wakeup_fd: int = -1
    main: bool = False

    @classmethod
    def save(cls) -> _SignalState:
        if threading.current_thread() is not threading.main_thread():
            return cls()
        fd = signal.set_wakeup_fd(-1)
        signal.set_wakeup_fd(fd)
        return cls(signal.getsignal(signal.SIGCHLD), fd, True)

    def restore(self) -> None:
        if not self.main:
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)   # child watchers (Python 3.12)
            try:
                asyncio.get_child_watcher().close()   # removes its SIGCHLD handler from the loop
            except (NotImplementedError, RuntimeError):
                pass
        signal.signal(signal.SIGCHLD, self.chld if self.chld is not None else signal.SIG_DFL)
        signal.set_wakeup_fd(self.wakeup_fd)
