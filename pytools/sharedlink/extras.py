"""The optional parts of the package and the one way to ask for them.

``pip install sharedlink`` (or ``pipx install``) brings the core: decode, stats, export to CSV
and JSON lines (and GeoJSON, KML), gen, replay, diff, compress, expand, lists, serial, watch in
the terminal and plugins, on scapy, rich and pyserial. The rest is in extras (pyproject.toml's
``[project.optional-dependencies]``, the same names as here), and a command that needs one
calls :func:`require` before it imports anything of it: a missing extra is a
:class:`MissingExtra` (a UsageError: ``sharedlink: error: ...``, exit 2) that names the extra
and the command that installs it, never an ImportError traceback.
"""

from __future__ import annotations

import importlib.util

from sharedlink.errors import UsageError

__all__ = ["EXTRAS", "MissingExtra", "install_hint", "require"]

#: extra -> the top-level modules it brings (the import names, not the distribution names);
#: ``all`` is every extra. pyproject.toml lists the same extras (a test holds the two together).
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib",),  # sharedlink plot
    "fleet": ("pyarrow", "duckdb"),  # sharedlink ingest, query
    "dask": ("distributed",),  # ingest --scheduler (a Dask cluster); in [fleet]
    "foxglove": ("foxglove",),  # export --format mcap, watch --foxglove
    "pyshark": ("pyshark",),  # sharedlink.wireshark.decode (tshark through pyshark)
}

#: modules that stand for an extra whose name differs (dask comes with [fleet])
_EXTRA_NAME = {"dask": "fleet"}


def install_hint(extra: str) -> str:
    """How to add ``extra`` to an installed sharedlink (pipx, pip, or a checkout)."""
    return (f"pipx install --force 'sharedlink[{extra}]' (from a checkout: pipx install --force '.[{extra}]'; "
            f"in a virtualenv: pip install 'sharedlink[{extra}]')")


class MissingExtra(UsageError):
    """A command that needs an extra that is not installed: names both and how to install it."""

    def __init__(self, what: str, extra: str, module: str) -> None:
        extra = _EXTRA_NAME.get(extra, extra)
        super().__init__(f"{what} needs the '{extra}' extra (no module {module}): {install_hint(extra)}")
        self.what, self.extra, self.module = what, extra, module


def require(extra: str, what: str) -> None:
    """Raise :class:`MissingExtra` naming ``what`` (e.g. ``"sharedlink plot"``) unless the
    modules of ``extra`` (``"plot"``, ``"fleet"``, ...) are installed. Call it where the command
    starts, before the work. It finds them without importing them (a command imports only
    what it uses: ``query`` loads DuckDB, never pyarrow)."""
    for module in EXTRAS[extra]:
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            raise MissingExtra(what, extra, module)
