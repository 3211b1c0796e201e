"""Constants the command-line parsers need (choices, bounds, defaults), kept apart from the
modules that use them: building every command's parser at start-up imports only this, not
the decoders, replay or watch (each command loads those when it runs)."""

from __future__ import annotations

#: ``sharedlink export --format``
EXPORT_FORMATS = ("csv", "jsonl", "geojson", "kml", "mcap")
#: formats written as bytes to a file by their own module (not through ``analysis.export.export``)
EXPORT_BINARY_FORMATS = ("mcap",)

#: the steady rates ``replay --pps`` takes: a period of at most 1e7 s (about 115 days; a rate like
#: 1e-300 made the period infinite and the schedule NaN) and, on the command line, at least 1 ns
MIN_PPS, MAX_PPS = 1e-7, 1e9

#: the UDP port ``watch`` listens on by default
WATCH_DEFAULT_PORT = 7013

# ``sharedlink serial``: copies of the serial modules' own constants (tests/tools/test_cli_startup.py
# holds them equal), so that the parser does not load those modules and the protocols they import
#: ``serial import --protocol`` (capture.serial_format.PROTOCOLS)
SERIAL_PROTOCOLS = ("sharedlink", "p2os", "blackboard")
#: ``serial import --log-format`` (capture.serial_import.FORMATS)
SERIAL_LOG_FORMATS = ("auto", "raw", "hex", "log")
#: the latest ``serial import --start`` (capture.serial_import.MAX_LOG_NS)
SERIAL_MAX_LOG_NS = (1 << 64) - 1
#: ``serial import --direction`` names (capture.serial_format's DIR_* codes: 0 unknown, 1 in, 2 out)
SERIAL_DIRECTIONS = {"in": 1, "inbound": 1, "out": 2, "outbound": 2, "unknown": 0}
