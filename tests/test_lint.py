"""The developer's checks run by the suite (so README's test command and CI run them): ruff and mypy clean
with the configuration of pyproject.toml, the modules' ``>>>`` examples collected as tests, every relative link
of README.md and docs/ resolving, and a missing optional extra named in one line instead of a traceback."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT, MissionRun, env_without

BIN = Path(sys.executable).parent


def _tool(name: str) -> str:
    path = BIN / name
    if path.exists():
        return str(path)
    found = shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (the lint extra: pip install -e '.[lint]')")
    return found


def test_ruff_finds_nothing():
    """The rule set of pyproject.toml ([tool.ruff.lint], the reasons beside it) over the whole tree."""
    proc = subprocess.run([_tool("ruff"), "check", "--no-cache", "--output-format", "concise", "."], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]


def test_mypy_finds_nothing():
    """protocol/ strict, edge/ and services/ at the baseline of pyproject.toml ([tool.mypy])."""
    proc = subprocess.run([_tool("mypy")], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Success" in proc.stdout, proc.stdout[-4000:] + proc.stderr[-2000:]


def test_the_modules_examples_are_collected_as_doctests():
    """``--doctest-modules`` over the packages (pyproject.toml's testpaths): a module's ``>>>`` examples are
    tests of the suite, and an example that fails fails it."""
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                           "protocol/rtp.py", "services/cli.py"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert "protocol/rtp.py::protocol.rtp" in proc.stdout, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "services/cli.py::services.cli.missing_extra" in proc.stdout, proc.stdout[-3000:]


def test_a_failing_example_fails_the_run(tmp_path):
    (tmp_path / "wrong.py").write_text('def f():\n    """\n    >>> 1 + 1\n    3\n    """\n')
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--doctest-modules",
                           "-o", "addopts=", str(tmp_path / "wrong.py")], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1 and "1 failed" in proc.stdout, proc.stdout[-3000:]


#: a Markdown link or image: [text](target) / ![alt](target); the target up to a space or ')'
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _pages() -> list[Path]:
    return [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors of a page: lower case, punctuation dropped, spaces to hyphens."""
    text = FENCE.sub("", page.read_text())
    heads = re.findall(r"^#{1,6}\s+(.+?)\s*$", text, re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


def test_every_relative_link_of_the_docs_resolves():
    """README.md, CONTRIBUTING.md and docs/**/*.md: every relative link names a file or folder of the
    repository, and a ``#fragment`` a heading of its page (outside code blocks)."""
    broken = []
    for page in _pages():
        if not page.exists():
            broken.append(f"{page.relative_to(ROOT)}: missing")
            continue
        for target in LINK.findall(FENCE.sub("", page.read_text())):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...: not checked here
                continue
            path, _, fragment = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif fragment and dest.suffix == ".md" and fragment not in _anchors(dest):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
            elif ROOT not in dest.parents and dest != ROOT:
                broken.append(f"{page.relative_to(ROOT)}: {target} (outside the repository)")
    assert not broken, "\n".join(broken)


def test_the_link_check_finds_a_broken_link(tmp_path):
    page = tmp_path / "README.md"
    page.write_text("[ok](README.md) [gone](docs/nothing.md)\n```\n[in code](nowhere.md)\n```\n")
    found = [t for t in LINK.findall(FENCE.sub("", page.read_text())) if not (tmp_path / t).exists()]
    assert found == ["docs/nothing.md"]


def _without(tmp_path: Path, blocked: set[str], *argv: str) -> subprocess.CompletedProcess:
    """``skynet ARGV`` in a Python where the ``blocked`` packages cannot be imported."""
    return subprocess.run([sys.executable, "-m", "services.cli", *argv], cwd=ROOT, env=env_without(tmp_path, blocked),
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("argv", [("sim-autopilot", "--help"), ("sim-autopilot", "--uav", "1")])
def test_a_command_whose_extra_is_missing_names_it_in_one_line(tmp_path, argv):
    proc = _without(tmp_path, {"pymavlink"}, *argv)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "'mavlink' extra" in proc.stderr and "pip install -e '.[mavlink]'" in proc.stderr, proc.stderr


def test_the_main_commands_need_no_extra(tmp_path):
    """The main job installs no extra (scripts/run.sh): ``skynet mission --help`` works without them."""
    proc = _without(tmp_path, {"pymavlink", "mavsdk", "selenium"}, "mission", "--help")
    assert proc.returncode == 0 and "--uavs" in proc.stdout, proc.stdout[-2000:] + proc.stderr[-2000:]


@pytest.mark.mission
def test_the_main_job_flies_without_any_extra(nominal_mission: MissionRun):
    """The nominal mission (tests/conftest.py) is flown with none of the extras importable, as scripts/run.sh
    installs it: it succeeds, and no process of it missed a module."""
    assert nominal_mission.proc.returncode == 0, nominal_mission.failure()
    services = (nominal_mission.out / "services.log").read_text()
    assert "ModuleNotFoundError" not in services and "needs the optional" not in services, services[-3000:]
