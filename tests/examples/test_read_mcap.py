"""examples/read_mcap.py on a mission's recording: the session's nominal mission (tests/conftest.py), and files that
are not mission logs. A module of its own, so that the network of test_examples.py is not running while the
nominal mission flies."""

from __future__ import annotations

import re

import pytest

from tests.conftest import ROOT
from tests.examples.test_examples import run_example


@pytest.mark.mission
def test_read_mcap_of_the_nominal_mission(nominal_mission):
    """The session's nominal mission (tests/conftest.py): its channels, their counts, and its verdict."""
    proc = run_example("read_mcap.py", str(nominal_mission.out), cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = {topic: int(n) for n, topic in re.findall(r"^\s*(\d+)  (\S+)$", proc.stdout, re.M)}
    for uav in (1, 2, 3):
        assert counts.get(f"skynet/demo/uav/{uav}/state", 0) > 0, proc.stdout
    assert counts.get("skynet/demo/rcu/detector/defects", 0) > 0, proc.stdout
    total = re.search(r"^(\d+) messages on (\d+) channels", proc.stdout, re.M)
    assert total and int(total.group(1)) == sum(counts.values()) and int(total.group(2)) == len(counts), proc.stdout
    verdict = "verdict: success" if nominal_mission.report()["success"] else "verdict: failed: "
    assert verdict in proc.stdout, proc.stdout


def test_read_mcap_refuses_what_is_not_a_mission_log_in_one_line(tmp_path):
    (tmp_path / "mission.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 100)
    for path, words in ((tmp_path, "not a readable MCAP file"), (ROOT / "README.md", "not an MCAP file"),
                        (tmp_path / "none", "No such file")):
        proc = run_example("read_mcap.py", str(path), cwd=tmp_path)
        assert proc.returncode == 1 and proc.stdout == "", proc.stdout
        assert proc.stderr.count("\n") == 1 and words in proc.stderr, proc.stderr
