"""Start-up: building the parsers of every command loads no command's heavy modules (the
decoders, replay, watch, the serial protocols, rich): each command loads its own when it runs."""

from __future__ import annotations

import json
import subprocess
import sys

#: modules only a running command may load (prefixes)
HEAVY = (
    "sharedlink.analysis", "sharedlink.replay", "sharedlink.watch", "sharedlink.capture.stream",
    "sharedlink.capture.packets", "sharedlink.capture.serial_format", "sharedlink.capture.serial_import",
    "sharedlink.capture.serial_port", "sharedlink.generators", "sharedlink.fleet.ingest", "sharedlink.fleet.query",
    "sharedlink.foxglove_server", "sharedlink.protocols.p2os", "sharedlink.protocols.blackboard", "rich", "pyarrow",
)


def _loaded(code: str) -> list[str]:
    r = subprocess.run([sys.executable, "-c", code + "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.splitlines()[-1])


def test_building_the_parsers_loads_no_heavy_module():
    loaded = _loaded("import sharedlink.cli as c\nc.build_parser()")
    assert "sharedlink.commands.stats" in loaded  # every command's parser was built
    assert [m for m in loaded if m.startswith(HEAVY)] == []


def test_help_of_a_command_loads_no_heavy_module():
    code = "import contextlib, io\nfrom sharedlink.cli import main\nwith contextlib.redirect_stdout(io.StringIO()):\n"
    for cmd in ("stats", "export", "replay", "watch", "serial"):
        loaded = _loaded(code + f"    try:\n        main([{cmd!r}, '--help'])\n    except SystemExit:\n        pass")
        assert [m for m in loaded if m.startswith(HEAVY)] == [], cmd


def test_the_parsers_constants_are_the_librarys():
    """sharedlink.defaults holds what the parsers need; the library modules agree with it."""
    from sharedlink import defaults
    from sharedlink.analysis import export
    from sharedlink.capture import serial_format, serial_import
    from sharedlink.replay import MAX_PPS, MIN_PPS
    from sharedlink.watch import DEFAULT_PORT

    assert (defaults.EXPORT_FORMATS, defaults.EXPORT_BINARY_FORMATS) == (export.FORMATS, export.BINARY_FORMATS)
    assert (defaults.MIN_PPS, defaults.MAX_PPS, defaults.WATCH_DEFAULT_PORT) == (MIN_PPS, MAX_PPS, DEFAULT_PORT)
    assert defaults.SERIAL_PROTOCOLS == serial_format.PROTOCOLS
    assert (defaults.SERIAL_LOG_FORMATS, defaults.SERIAL_MAX_LOG_NS) == (serial_import.FORMATS, serial_import.MAX_LOG_NS)
    f = serial_format
    assert defaults.SERIAL_DIRECTIONS == {"in": f.DIR_IN, "inbound": f.DIR_IN, "out": f.DIR_OUT,
                                          "outbound": f.DIR_OUT, "unknown": f.DIR_UNKNOWN}
