"""``skynet report`` of a mission's folder and of its log makes the mission's own report: the same
sections (the inspection deliverable included) and the same defect counts."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest


def _headings(md: str) -> list[str]:
    return [line for line in md.splitlines() if re.match(r"^#{1,3} ", line)]


def _defects_line(md: str) -> str | None:
    """The inspection section's sentence counting the deliverable's defects."""
    m = re.search(r"(\d+) defects \(", md)
    return m.group(1) if m else None


@pytest.mark.mission
@pytest.mark.parametrize("source", [".", "mission.mcap"])
def test_skynet_report_of_the_folder_and_the_log_is_the_missions_own(nominal_mission, request, tmp_path: Path,
                                                                      source: str) -> None:
    out = nominal_mission.out
    assert nominal_mission.proc.returncode == 0, nominal_mission.failure()
    own_md = (out / "report.md").read_text()
    own = json.loads((out / "report.json").read_text())
    assert "## Inspection deliverable" in own_md  # the mission's log holds its captures

    if source == ".":  # the folder's: the run the launcher's test checks too (tests/conftest.py)
        proc, again = request.getfixturevalue("nominal_report_again")
    else:
        again = tmp_path / "again"
        proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(out / source), "--out", str(again)],
                              capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    md = (again / "report.md").read_text()
    assert _headings(md) == _headings(own_md)
    rebuilt = json.loads((again / "report.json").read_text())
    assert rebuilt["defects"] == own["defects"]  # the reports' defect score: counts, recall, precision
    assert _defects_line(md) == _defects_line(own_md) is not None  # the deliverable's defects
    own_table = json.loads((out / "inspection" / "defects.json").read_text())
    table = json.loads((again / "inspection" / "defects.json").read_text())
    assert table["defects"] == own_table["defects"]  # the same defects, the same sizes
    assert sorted(f for f in rebuilt["files"]) == sorted(f for f in own["files"])


def test_skynet_report_of_a_file_that_is_no_mission_log_says_so_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "mission.mcap"
    bad.write_bytes(b"not an mcap file at all")
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(bad), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
