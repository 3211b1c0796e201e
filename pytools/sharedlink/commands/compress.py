"""``sharedlink compress``: rewrite a full stream as a compressed one."""

from __future__ import annotations

import argparse

from sharedlink.commands import SECONDS, add_transform_arguments, run_transform


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compress",
        help="rewrite a capture with shared-variable compression",
        description="Rewrite a capture's SharedLink value frames with shared-variable compression: unchanged "
        "values left out (named form: the triplet goes; positional form: an empty D), a full set at least every "
        "--sync-interval seconds per direction. Form, addresses, timestamps and every other frame and packet "
        "are kept; `sharedlink diff IN OUT` agrees.",
        epilog="Exit codes: 0 written, 2 bad usage or a missing/damaged input (the records before the damage are "
        "still written), 130 interrupted.",
    )
    add_transform_arguments(p)
    p.add_argument("--sync-interval", type=SECONDS, default=1.0, metavar="S",
                   help="a full set at least every S seconds (default 1)")
    p.set_defaults(func=lambda args: run_transform(args, "compress"))
