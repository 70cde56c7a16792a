"""The command-line reference (``docs/cli.md``) generated from the parsers themselves.

Every ``skynet`` subcommand of :data:`services.cli.COMMANDS` is asked for its ``--help`` (and each of its own
subcommands, the ``{a,b}`` choices of its usage line, for theirs) in this process, at a fixed width, so the page
is what a user sees and a test (``tests/test_docs.py``) keeps the committed page equal to it.

    python -m services.cli_reference > docs/cli.md
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys

from services.cli import COMMANDS
from services.cli import main as skynet

#: the terminal width argparse formats for (it reads COLUMNS), so the page does not depend on the terminal
WIDTH = 100

#: a usage line's subcommands: argparse's ``{a,b} ...`` or a hand-written ``a|b ...``
SUBCOMMANDS = re.compile(r"^usage: skynet [^\n]*? (?:\{([\w,-]+)\}|([\w-]+(?:\|[\w-]+)+)) \.\.\.", re.M)


def help_text(argv: list[str]) -> str:
    """What ``skynet ARGV --help`` prints (stdout and stderr), at :data:`WIDTH` columns."""
    out = io.StringIO()
    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            with contextlib.suppress(SystemExit):
                skynet([*argv, "--help"])
    finally:
        if saved is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = saved
    return out.getvalue().rstrip() + "\n"


def subcommands(text: str) -> list[str]:
    """The subcommands a help text's usage line offers (``{mission}`` -> ``["mission"]``), none when it has none.

    >>> subcommands("usage: skynet netem [-h] {udp,tcp} ...\\n")
    ['udp', 'tcp']
    >>> subcommands("usage: skynet plan [-h] mission|compare ...\\n")
    ['mission', 'compare']
    >>> subcommands("usage: skynet web [-h] [--web ADDR]\\n")
    []
    """
    found = SUBCOMMANDS.match(text)
    if found is None:
        return []
    return found.group(1).split(",") if found.group(1) else found.group(2).split("|")


def _section(level: str, argv: list[str]) -> list[str]:
    text = help_text(argv)
    lines = [f"{level} `skynet {' '.join(argv)}`", "", "```text", text.rstrip("\n"), "```", ""]
    for sub in subcommands(text):
        lines += _section(level + "#", [*argv, sub])
    return lines


def document() -> str:
    """The whole page: the command list, then every subcommand's help in :data:`~services.cli.COMMANDS` order."""
    lines = ["# Command-line reference", "",
             "Generated from the parsers by `python -m services.cli_reference > docs/cli.md` (a test keeps it",
             "current): every `skynet` command's `--help`, with its defaults.", ""]
    lines += [f"- [`skynet {name}`](#skynet-{name}): {help_}" for name, (_, help_) in COMMANDS.items()]
    lines.append("")
    for name in COMMANDS:
        lines += _section("##", [name])
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    """Print the page (``python -m services.cli_reference > docs/cli.md``)."""
    del argv
    sys.stdout.write(document())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
