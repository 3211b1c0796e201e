"""``sharedlink plugins install|uninstall|path``: the dissectors, the serial extcap and the
coloring rules into (and out of) your personal Wireshark folders, from the installed package."""

from __future__ import annotations

import argparse
import json
import sys

from sharedlink.commands import EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plugins",
        help="install the Wireshark dissectors, extcap and coloring rules for your user",
        description="install: copy the Lua dissectors into the personal plugin folder that `tshark -G folders` "
        "names, the sharedlink-serial extcap into the personal extcap folder (run by this Python), and the "
        "coloring rules to the top of your personal colorfilters. uninstall: remove them again (coloring "
        "rules too, also those you disabled or edited in the GUI). path: where the files come from and go. "
        "What `make install` / `make uninstall` do, without a checkout.",
        epilog="Exit codes: 0 done, 2 tshark missing or a folder that cannot be written.",
    )
    p.add_argument("action", choices=["install", "uninstall", "path"], help="what to do")
    p.add_argument("--tshark", default="tshark", metavar="PATH",
                   help="the tshark whose folders are used (default: tshark on PATH)")
    p.add_argument("--profile", action="store_true",
                   help="install: also the SharedLink configuration profile (columns, filter buttons for bad checksum, "
                   "late full set and outage, coloring rules, I/O graphs of frames a second and outages in the columns of "
                   "the tshark's Wireshark release); uninstall removes it whether given or not")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sharedlink import plugins

    f = plugins.folders(args.tshark)
    if args.action == "path":
        where = plugins.paths(f)
        if args.json:
            print(json.dumps(where))
        else:
            for k, v in where.items():
                print(f"{k}: {v}")
        return EXIT_OK
    report = plugins.install(f) if args.action == "install" else plugins.uninstall(f)
    if args.action == "install" and args.profile:
        report.lines += plugins.install_profile(f, plugins.tshark_version(args.tshark)).lines
    elif args.action == "uninstall":
        report.lines += plugins.uninstall_profile(f).lines
    if args.json:
        print(json.dumps({"action": args.action, "done": report.lines, **plugins.paths(f)}))
    else:
        for line in report.lines:
            print(line)
    sys.stdout.flush()
    return EXIT_OK
