"""The command line is consistent across commands: one flag per concept, the unit of a quantity at the end of its
flag, every default in the help, and a missing optional extra named in one line. Each rule walks every ``skynet``
command (and subcommand) as ``--help`` builds it, so a new option that breaks a rule fails here."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from unittest import mock

import pytest

from protocol.cliconfig import has_default
from services import cli_reference
from services.cli import COMMANDS, EXTRAS

#: one concept, one flag: the flag every command uses, and the names it must not go by on any command
SYNONYMS: dict[str, tuple[str, ...]] = {
    "--web": ("--listen-web", "--web-listen", "--web-addr"),
    "--sdp-dir": ("--video-sdp", "--sdp", "--sdp-folder"),
    "--preview-port": ("--video-port", "--port-preview"),
    "--uavs": ("--mesh-uavs", "--max-uav", "--max-uavs", "--fleet-size", "--num-uavs", "--n-uavs"),
    "--seed": ("--random-seed", "--rng-seed"),
    "--keys": ("--key-dir", "--keys-dir", "--keyset", "--key-set"),
    "--scenario": ("--scenario-file", "--scene"),
    "--fleet": ("--fleet-name",),
    "--impair": ("--impairment", "--netem"),
}

#: a unit a help text names after a comma or as a word (", s", "seconds", ", Hz", "per second", ", ms", ", %")
#: -> the suffix the flag ends in
UNITS: list[tuple[re.Pattern[str], str]] = [
    (re.compile(r"(?:[,;] ?s\b(?!')|(?<!per )\bseconds?\b)"), "-s"),
    (re.compile(r"(?:\bHz\b|per second)"), "-hz"),
    (re.compile(r"[,;] ?ms\b"), "-ms"),
    (re.compile(r"[,;] ?%"), "-pct"),
]
#: options whose help names a unit of something else than their own value
UNIT_EXEMPT: set[str] = set()


def _walk() -> list[tuple[str, argparse.ArgumentParser]]:
    """Every (command line, parser) of every ``skynet`` command and subcommand, as its ``--help`` builds it."""
    found: list[tuple[str, argparse.ArgumentParser]] = []
    original = argparse.ArgumentParser.print_help

    def record(self: argparse.ArgumentParser, file=None) -> None:
        found.append((self.prog, self))
        original(self, file)

    def visit(argv: list[str]) -> None:
        with mock.patch.object(argparse.ArgumentParser, "print_help", record):
            text = cli_reference.help_text(argv)
        for sub in cli_reference.subcommands(text):
            visit([*argv, sub])

    for name in COMMANDS:
        visit([name])
    return found


@pytest.fixture(scope="module")
def parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    return _walk()


def _options(parsers):
    for prog, parser in parsers:
        for action in parser._actions:
            if action.option_strings and not isinstance(action, argparse._HelpAction):
                yield prog, parser, action


def test_the_walk_sees_every_command_and_subcommand(parsers):
    progs = {prog for prog, _ in parsers}
    assert {f"skynet {name}" for name in COMMANDS} <= progs
    assert {"skynet netem udp", "skynet keys init", "skynet plan compare", "skynet detect eval"} <= progs


def test_one_flag_per_concept(parsers):
    banned = {old: new for new, olds in SYNONYMS.items() for old in olds}
    found = [f"{prog}: {flag} (use {banned[flag]})" for prog, _, action in _options(parsers)
             for flag in action.option_strings if flag in banned]
    assert not found, found
    # and the concept's one flag is there where the concept is
    flags = {prog: {f for a in p._actions for f in a.option_strings} for prog, p in parsers}
    assert all("--web" in flags[f"skynet {c}"] for c in ("up", "mission", "gcs", "web"))
    assert all("--sdp-dir" in flags[f"skynet {c}"] and "--preview-port" in flags[f"skynet {c}"]
               for c in ("up", "mission", "video"))
    assert all("--uavs" in flags[f"skynet {c}"] for c in ("edge", "detector", "up", "mission", "gcs", "video",
                                                          "experiment", "keys init"))
    # written the same way too
    metavars = {a.metavar for _, _, a in _options(parsers) if "--uavs" in a.option_strings}
    assert metavars == {"N"}, metavars


def test_a_quantity_has_its_unit_at_the_end_of_its_flag(parsers):
    wrong = []
    for prog, parser, action in _options(parsers):
        flag = action.option_strings[0]
        if flag in UNIT_EXEMPT or not action.help:
            continue
        text = parser._get_formatter()._expand_help(action)
        for pattern, suffix in UNITS:
            if pattern.search(text) and not flag.endswith(suffix):
                wrong.append(f"{prog} {flag}: {suffix} ({text!r})")
    assert not wrong, wrong


def test_the_unit_rule_catches_a_flag_without_its_unit():
    text = "neighbour state considered stale after, s"
    assert UNITS[0][0].search(text) and not "--stale".endswith(UNITS[0][1])
    assert not UNITS[0][0].search("UAV n's port") and not UNITS[0][0].search("the edges' speed")


def test_every_option_with_a_default_shows_it_in_the_help(parsers):
    missing = []
    for prog, parser, action in _options(parsers):
        if not has_default(action):
            continue
        text = parser._get_formatter()._expand_help(action) if action.help else ""
        if "default" not in text:
            missing.append(f"{prog} {action.option_strings[0]} (default {action.default!r})")
    assert not missing, missing


#: a program that runs ``skynet ARGV`` with every optional extra unimportable (``None`` in sys.modules)
BLOCKED = ("import sys\n"
           f"for name in {sorted(EXTRAS)!r}: sys.modules[name] = None\n"
           "from services.cli import main\n"
           "raise SystemExit(main(sys.argv[1:]))\n")


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_without_the_optional_extras_is_help_or_one_line(command):
    p = subprocess.run([sys.executable, "-c", BLOCKED, command, "--help"], capture_output=True, text=True,
                       timeout=120)
    assert "Traceback" not in p.stderr, p.stderr
    if p.returncode == 0:
        assert p.stdout.startswith(f"usage: skynet {command}"), p.stdout
    else:
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(lines) == 1 and "needs the optional" in lines[0], p.stderr


def test_a_command_that_needs_an_extra_names_it_in_one_line():
    """``skynet sim-autopilot`` runs on pymavlink: without it, a run is one line naming the extra."""
    p = subprocess.run([sys.executable, "-c", BLOCKED, "sim-autopilot", "--uav", "1"], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and p.stderr.strip() == ("skynet sim-autopilot: error: needs the optional 'mavlink' "
                                                      "extra (pymavlink is not installed): pip install -e '.[mavlink]'"), \
        p.stderr
