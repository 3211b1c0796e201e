"""``sharedlink completion bash|zsh|fish``: the shell completion script, made from the parsers
(shtab), on standard output."""

from __future__ import annotations

import argparse
import sys

from sharedlink.commands import EXIT_OK

SHELLS = ("bash", "zsh", "fish")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "completion",
        help="print the shell completion script (bash, zsh, fish)",
        description="Print the completion script of every command and option for SHELL, made from the "
        "parsers (shtab). bash: save it as ~/.local/share/bash-completion/completions/sharedlink; zsh: "
        "as _sharedlink in a folder of $fpath; fish: as ~/.config/fish/completions/sharedlink.fish.",
    )
    p.add_argument("shell", choices=SHELLS, help="the shell")
    p.add_argument("--json", action="store_true", help='print {"shell": ..., "script": ...} as JSON instead')
    p.set_defaults(func=run)


def script(parser: argparse.ArgumentParser, shell: str) -> str:
    """The completion script of ``parser`` (the ``sharedlink`` one) for ``shell``."""
    import shtab

    return shtab.complete(parser, shell=shell)


def run(args: argparse.Namespace) -> int:
    text = script(args.root_parser, args.shell)  # (set by cli.build_parser: the whole command)
    if args.json:
        import json

        json.dump({"shell": args.shell, "script": text}, sys.stdout)
        print()
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return EXIT_OK
