"""``sharedlink expand``: every value frame carries every value."""

from __future__ import annotations

import argparse

from sharedlink.commands import add_transform_arguments, run_transform


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "expand",
        help="rewrite a compressed capture so every frame carries every value",
        description="Rewrite a capture's SharedLink value frames so each carries the full set of values (the "
        "reverse of compress). Form, addresses, timestamps and every other frame and packet are kept; "
        "`sharedlink diff IN OUT` agrees.",
        epilog="Exit codes: 0 written, 2 bad usage or a missing/damaged input (the records before the damage are "
        "still written), 130 interrupted.",
    )
    add_transform_arguments(p)
    p.set_defaults(func=lambda args: run_transform(args, "expand"), sync_interval=1.0)
