"""The suite's own scheduling (tests/conftest.py, scripts/test.sh): whole missions stay on one xdist worker, but
for the late ones, which go out after the rest of the suite."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from tests.conftest import ROOT

pytest.importorskip("xdist", reason="scripts/test.sh runs the suite on two pytest-xdist workers")


def test_missions_share_one_worker_and_the_rest_is_spread(tmp_path):
    """The ``mission`` marker becomes one xdist group, so ``--dist loadgroup`` runs every mission on the same
    worker (pytest 9.2 silently broke xdist's groups, pytest-dev/pytest-xdist#1386: this test fails there)."""
    (tmp_path / "conftest.py").write_text("from tests.conftest import pytest_collection_modifyitems  # noqa: F401\n")
    (tmp_path / "test_sample.py").write_text(textwrap.dedent("""
        import time
        import pytest

        @pytest.mark.mission
        @pytest.mark.parametrize("i", range(4))
        def test_mission(i):
            time.sleep(0.2)

        @pytest.mark.parametrize("i", range(8))
        def test_other(i):
            time.sleep(0.2)
    """))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v", "-p", "no:cacheprovider",
                           "-o", "addopts=", "-W", "ignore::pytest.PytestUnknownMarkWarning", str(tmp_path)],
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ran = [line.split() for line in proc.stdout.splitlines() if line.startswith("[gw") and "PASSED" in line]
    missions = [(words[0], words[-1]) for words in ran if "test_mission[" in words[-1]]
    assert len(missions) == 4 and len({w for w, _ in missions}) == 1, missions
    assert all(nodeid.endswith("@mission") for _, nodeid in missions), missions
    assert len({words[0] for words in ran}) == 2, ran  # the others are shared by both workers


def test_late_missions_go_out_after_the_rest_to_the_worker_that_is_free(tmp_path):
    """The missions of ``LATE_MISSION_MODULES`` are a group per module, sent after every other test (xdist's own
    largest-group-first order off): the worker done with the rest takes them while the other one still flies
    the main group's missions, which come first."""
    (tmp_path / "conftest.py").write_text(textwrap.dedent("""
        import tests.conftest as suite
        from tests.conftest import pytest_collection_modifyitems, pytest_configure  # noqa: F401

        suite.LATE_MISSION_MODULES = ("test_late.py",)
    """))
    (tmp_path / "test_late.py").write_text(textwrap.dedent("""
        import time
        import pytest

        @pytest.mark.mission
        @pytest.mark.parametrize("i", range(2))
        def test_late(i):
            time.sleep(0.2)
    """))
    (tmp_path / "test_sample.py").write_text(textwrap.dedent("""
        import time
        import pytest

        @pytest.mark.mission
        @pytest.mark.parametrize("i", range(6))
        def test_mission(i):
            time.sleep(0.5)

        @pytest.mark.parametrize("i", range(6))
        def test_other(i):
            time.sleep(0.1)
    """))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v", "-p", "no:cacheprovider",
                           "-o", "addopts=", "-W", "ignore::pytest.PytestUnknownMarkWarning", str(tmp_path)],
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ran = [line.split() for line in proc.stdout.splitlines() if line.startswith("[gw") and "PASSED" in line]
    names = [words[-1] for words in ran]
    missions = {words[0] for words in ran if "test_mission[" in words[-1]}
    late = [k for k, n in enumerate(names) if "test_late[" in n]
    others = [k for k, n in enumerate(names) if "test_other[" in n]
    assert len(missions) == 1 and len(late) == 2 and len(others) == 6, ran
    assert all(names[k].endswith("@mission-late:test_late.py") for k in late), ran
    assert min(late) > max(others), ran  # after the rest of the suite
    # the worker without the main group's missions took them (it was free; the other one still flew)
    assert {ran[k][0] for k in late} != missions, ran
