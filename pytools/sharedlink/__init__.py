"""SharedLink tools: protocol codecs, capture files, generators and analyses, by role.

Layout (``docs/architecture.md`` is the map):

- ``sharedlink.protocols``: one codec per protocol (``codec`` for SharedLink, ``p2os``,
  ``blackboard``) and the SharedLink variable state (``state``);
- ``sharedlink.capture``: pcap/pcapng I/O, packet headers, the serial capture format and
  live port capture, serial log import, and ``stream`` (records -> datagrams -> frames);
- ``sharedlink.generators``: beacon, P2OS, blackboard and serial session generators;
- ``sharedlink.analysis``: decode, stats, diff, transform (compress/expand), export, plot;
- on top: ``replay``, ``extcap``, ``wireshark``, ``scapy_layer``, ``cli`` and ``commands``.

The flat module names of earlier releases (``sharedlink.decode``, ``sharedlink.codec``,
``sharedlink.serialcap``...) still import: they are aliases of the modules above.
"""

from __future__ import annotations

from ._interrupt import quiet_interrupt

with quiet_interrupt():  # Ctrl-C while the command loads: exit 130, no traceback
    import importlib
    import importlib.abc
    import importlib.machinery
    import sys
    import types

    from .protocols.codec import (
        Checksum,
        Field,
        Frame,
        SharedLinkError,
        build_frame,
        checksum,
        frame_kind,
        iter_segments,
        parse_frame,
        split_frames,
    )

__all__ = [
    "Checksum",
    "Field",
    "Frame",
    "SharedLinkError",
    "build_frame",
    "checksum",
    "frame_kind",
    "iter_segments",
    "parse_frame",
    "split_frames",
]
__version__ = "1.3.0"

# -- old flat module names ------------------------------------------------------------------

#: old name -> the module it now is (``serialcap`` was split: its live capture is ``serial_port``)
MOVED = {
    "codec": "protocols.codec",
    "p2os": "protocols.p2os",
    "blackboard": "protocols.blackboard",
    "state": "protocols.state",
    "pcapio": "capture.pcapio",
    "packets": "capture.packets",
    "serial_import": "capture.serial_import",
    "stream": "capture.stream",
    "serialcap": "capture.serial_format",
    "gen": "generators.beacon",
    "gen_p2os": "generators.p2os",
    "gen_blackboard": "generators.blackboard",
    "gen_serial": "generators.serial",
    "scenario": "generators.scenario",
    "decode": "analysis.decode",
    "stats": "analysis.stats",
    "diff": "analysis.diff",
    "transform": "analysis.transform",
    "export": "analysis.export",
    "plot": "analysis.plot",
}


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``sharedlink.<old>`` as the module it moved to (the same module object, so
    ``sharedlink.decode.iter_decoded is sharedlink.analysis.decode.iter_decoded``)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None):  # type: ignore[override]
        prefix, _, old = fullname.partition(".")
        if prefix != __name__ or old not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        return importlib.import_module(f"{__name__}.{MOVED[spec.name.partition('.')[2]]}")

    def exec_module(self, module: types.ModuleType) -> None:
        # the import machinery set the alias's spec on the module; its own spec is the one
        # its package's path finds (the module keeps its real __name__)
        package = module.__name__.rpartition(".")[0]
        module.__spec__ = importlib.machinery.PathFinder.find_spec(module.__name__, sys.modules[package].__path__)


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    sys.meta_path.append(_MovedFinder())


def __getattr__(name: str) -> types.ModuleType:
    if name in MOVED:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
