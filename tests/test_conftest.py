"""The suite's own scheduling (tests/conftest.py, scripts/test.sh): whole missions stay on one xdist worker."""

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
