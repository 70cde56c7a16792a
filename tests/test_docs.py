"""The documentation describes the tree as it is: every module a page names exists, and the command-line
reference (docs/cli.md) is what the parsers print."""

from __future__ import annotations

import re
from pathlib import Path

from services import cli_reference
from tests.conftest import ROOT

#: a file path of the tree as the pages write it: ``edge/vehicle/mavlink/driver.py``, ``scripts/run.sh``
FILE = re.compile(r"(?<![\w./-])((?:protocol|edge|services|tests|bench|scripts|compose|docs)/[\w./-]*\w)")
#: a dotted module of the three packages: ``services.recording.load``, ``edge.geometry.formation.ShapeErrorMeter``
MODULE = re.compile(r"(?<![\w./-])((?:protocol|edge|services)(?:\.[A-Za-z_]\w*)+)")

#: paths the pages name that the tree makes at run time, not files of the repository
MADE_AT_RUN_TIME = ("bench/results", "tests/artifacts")
#: file names that look dotted (``services.log``, ``edge.json5``), not modules
FILE_SUFFIXES = {"log", "json", "json5", "yml", "yaml", "toml", "md", "txt", "mcap", "png", "html"}


def pages() -> list[Path]:
    return [ROOT / "README.md", ROOT / "CONTRIBUTING.md", ROOT / "CHANGELOG.md",
            *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name not in {"wire-contract.md", "cli.md"})]


def _file_exists(name: str) -> bool:
    name = name.rstrip(".")
    path = ROOT / name
    if path.exists():
        return True
    # a glob the page writes (``compose/*.yml``) or a folder named without its slash
    return any(ROOT.glob(name)) if "*" in name else False


def _module_exists(dotted: str) -> bool:
    """A dotted name is a module of the tree, or a name its module's source defines or imports
    (``pkg.mod.Class``, ``pkg.mod.f``, ``pkg.mod.Class.method``)."""
    parts = dotted.split(".")
    for n in range(len(parts), 1, -1):  # at least ``package.module``
        base = ROOT.joinpath(*parts[:n])
        source = base.with_suffix(".py") if base.with_suffix(".py").exists() else base / "__init__.py"
        if not source.exists():
            continue
        if n == len(parts):
            return True
        attr = parts[n]
        return re.search(rf"^\s*(?:async\s+)?(?:def|class)\s+{attr}\b|^{attr}\s*[:=]|^(?:from|import)\s.*\b{attr}\b",
                         source.read_text(), re.M) is not None
    return False


def stale_names(text: str) -> list[str]:
    """Every module path or dotted module of ``text`` that the tree does not have.

    >>> stale_names("see `services/recording/load.py` and `services.recording.load.load_record`")
    []
    >>> stale_names("`edge/runtime.py` and `services.gcs.record`")
    ['edge/runtime.py', 'services.gcs.record']
    """
    missing = []
    for name in FILE.findall(text):
        if name.startswith(MADE_AT_RUN_TIME):
            continue
        if not _file_exists(name):
            missing.append(name)
    for dotted in MODULE.findall(text):
        if dotted.rpartition(".")[2] in FILE_SUFFIXES:
            continue
        if not _module_exists(dotted):
            missing.append(dotted)
    return missing


def test_every_module_the_pages_name_exists():
    """README.md, CONTRIBUTING.md, CHANGELOG.md and docs/*.md (not the generated pages): every
    ``path/like/this.py`` and every dotted ``protocol.x`` / ``edge.x`` / ``services.x`` names a module of the tree."""
    stale = [f"{page.relative_to(ROOT)}: {name}" for page in pages() for name in stale_names(page.read_text())]
    assert not stale, "names of modules the tree does not have:\n" + "\n".join(stale)


def test_the_check_finds_a_module_that_is_gone():
    assert stale_names("the driver `edge/vehicle/mavlink.py` (edge.runtime.make_driver)") == [
        "edge/vehicle/mavlink.py", "edge.runtime.make_driver"]
    assert stale_names("`edge/vehicle/mavlink/driver.py`, edge.vehicle.factory.make_driver") == []


def test_the_command_line_reference_is_current():
    assert (ROOT / "docs" / "cli.md").read_text() == cli_reference.document(), \
        "docs/cli.md is stale: regenerate it with `python -m services.cli_reference > docs/cli.md`"


def test_the_reference_has_every_command_and_its_subcommands():
    doc = (ROOT / "docs" / "cli.md").read_text()
    for name in ("gateway", "edge", "up", "mission", "report", "gcs", "keys revoke", "netem udp"):
        assert f"`skynet {name}`" in doc
        assert f"usage: skynet {name} " in doc, name
