"""docs/sharedlink.1, the man page, made from the ``sharedlink`` parsers (argparse-manpage, a
test tool): ``make man`` runs it; tests/tools/test_cli_docs.py checks the file is fresh.

    python scripts/manpage.py [OUT]     (OUT default docs/sharedlink.1; -: standard output)
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def manpage() -> str:
    """The man page's text (roff), the same on every machine: 80 columns, no date."""
    os.environ["COLUMNS"] = "80"  # argparse wraps the help to the terminal's width
    from argparse_manpage.manpage import Manpage

    import sharedlink
    from sharedlink.cli import build_parser

    parser = build_parser()
    page = Manpage(parser, format="pretty")
    page.source = f"sharedlink {sharedlink.__version__}"
    page.manual = "SharedLink analyzer"
    page.date = sharedlink.__version__  # a fixed string: the page changes with the parsers only
    page.description = "generate, replay, compare and decode SharedLink beacon captures"
    return str(page).rstrip("\n") + "\n" + _examples()


def _examples() -> str:
    """An EXAMPLES section: every command's examples, as its --help ends with them."""
    from sharedlink.commands.examples import EXAMPLES

    lines = [".SH EXAMPLES"]
    for command, examples in EXAMPLES.items():
        for line, what in examples:
            lines += [".TP", f"\\fB{_roff(line)}\\fR", _roff(f"{what} ({command})")]
    return "\n".join(lines) + "\n"


def _roff(text: str) -> str:
    return text.replace("\\", "\\\\").replace("-", "\\-").replace("'", "\\(aq")


def main(argv: list[str]) -> int:
    out = argv[0] if argv else str(ROOT / "docs" / "sharedlink.1")
    text = manpage()
    if out == "-":
        sys.stdout.write(text)
    else:
        Path(out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
