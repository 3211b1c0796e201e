"""The examples every ``--help`` ends with (its epilog), by command; ``cli.build_parser`` hangs
them on the parsers, the man page and docs/cli.md show the same. Each line is a whole command
that runs as written in a folder with ``drive.pcap`` (tests/tools/test_help.py runs them)."""

from __future__ import annotations

#: command (as ``sharedlink`` names it, subcommands with a space) -> (command line, what it does)
EXAMPLES: dict[str, list[tuple[str, str]]] = {
    "gen": [("sharedlink gen -o drive.pcap", "a 60 s drive, named beacon frames at 5 Hz"),
            ("sharedlink gen -o drive.pcap --compress --drop 0.01 --bad-checksum 0.01", "compressed, with faults"),
            ("sharedlink gen -o robot.pcap --protocol p2os", "a P2OS robot session over TCP")],
    "replay": [("sharedlink replay drive.pcap --to 127.0.0.1:7013", "send the frames with the capture's timing"),
               ("sharedlink replay drive.pcap --to 127.0.0.1 --speed 10 --quiet", "ten times as fast, no progress")],
    "compress": [("sharedlink compress drive.pcap -o small.pcap", "leave out unchanged values")],
    "expand": [("sharedlink expand small.pcap -o full.pcap", "every value in every frame again")],
    "diff": [("sharedlink diff drive.pcap small.pcap", "exit 1 when the data diverge"),
             ("sharedlink diff drive.pcap small.pcap --json", "the report as JSON")],
    "stats": [("sharedlink stats drive.pcap", "frames, rates, checksums, variables"),
              ("sharedlink stats drive.pcap --fail-on checksum,late", "exit 1 on bad checksums or late full sets (CI)")],
    "health": [("sharedlink health drive.pcap", "link quality per second, outages and learnt rates"),
               ("sharedlink health drive.pcap -o quality.csv --plot quality.png", "the same as CSV and a PNG strip")],
    "export": [("sharedlink export drive.pcap -o drive.csv", "one row per frame"),
               ("sharedlink export drive.pcap --changes --select AutoGpsVel -o speed.jsonl", "one row per change"),
               ("sharedlink export drive.pcap -o track.geojson", "the GPS track for a map")],
    "plot": [("sharedlink plot drive.pcap -o drive.png", "track and variables (needs the 'plot' extra)")],
    "lists": [("sharedlink lists drive.pcap", "the variable lists the capture declares")],
    "watch": [("sharedlink watch", "UDP port 7013 live; Ctrl-C ends it (exit 0)"),
              ("sharedlink watch drive.pcap --speed 100 --json", "a capture played as JSON lines")],
    "ingest": [("sharedlink ingest drive.pcap -o fleet.parquet", "into a Parquet dataset (the 'fleet' extra)")],
    "query": [('sharedlink query fleet.parquet "SELECT pair, count(*) FROM frames GROUP BY pair"', "SQL (DuckDB)")],
    "plugins": [("sharedlink plugins install", "the dissectors into your Wireshark folders")],
    "completion": [("sharedlink completion bash > ~/.local/share/bash-completion/completions/sharedlink", "bash"),
                   ("sharedlink completion fish > ~/.config/fish/completions/sharedlink.fish", "fish")],
    "serial capture": [("sharedlink serial capture /dev/ttyUSB0 -o line.pcapng", "record at 9600 baud until Ctrl-C")],
    "serial import": [("sharedlink serial import log.txt -o line.pcapng", "a hex dump or raw log into a capture")],
    "serial ports": [("sharedlink serial ports", "the machine's serial ports")],
}


def epilog(command: str) -> str | None:
    """The ``examples:`` block of ``command``'s help, None when it has none."""
    lines = EXAMPLES.get(command)
    if not lines:
        return None
    width = max(len(c) for c, _ in lines)
    body = "\n".join(f"  {c:<{width}}  # {what}" if width <= 60 else f"  {c}\n      # {what}" for c, what in lines)
    return f"examples:\n{body}"
