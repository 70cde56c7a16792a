"""The import layers of pyproject.toml's ``[tool.importlinter]`` contracts: kept by the tree, and broken by a
new import across them (so the suite fails on one).

The layers: protocol (the wire contract) < edge.geometry (shared geometry) < edge.world (the simulated world) <
the UAV's process (edge) < the ground (services); the ground imports of edge only its geometry and world (the
exceptions are listed with their reason in the contract); the service packages form no cycle.
"""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = ROOT / "pyproject.toml"

pytest.importorskip("importlinter", reason="import-linter is in the test extra (pip install -e '.[test]')")
grimp = pytest.importorskip("grimp", reason="grimp comes with import-linter")

from importlinter import api  # noqa: E402
from importlinter.contracts.forbidden import ForbiddenContract  # noqa: E402
from importlinter.contracts.layers import LayersContract  # noqa: E402

CONTRACT_TYPES = {"layers": LayersContract, "forbidden": ForbiddenContract}


@pytest.fixture(scope="module")
def config() -> dict:
    return api.read_configuration(str(PYPROJECT))


@pytest.fixture(scope="module")
def graph(config: dict):
    opts = config["session_options"]
    return grimp.build_graph(*opts["root_packages"], include_external_packages=True, cache_dir=None)


def check(config: dict, graph, name_part: str) -> bool:
    """Whether the one contract whose name contains ``name_part`` is kept on ``graph``."""
    found = [c for c in config["contracts_options"] if name_part in c["name"]]
    assert len(found) == 1, f"{len(found)} contracts named like {name_part!r}"
    opts = found[0]
    contract = CONTRACT_TYPES[opts["type"]](name=opts["name"], session_options=config["session_options"],
                                            contract_options=opts)
    return contract.check(copy.deepcopy(graph), verbose=False).kept


def test_lint_imports_keeps_every_contract() -> None:
    """The command CI runs, on the working tree."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    assert exe, "lint-imports not installed (the test extra)"
    run = subprocess.run([exe, "--no-cache", "--config", str(PYPROJECT)], cwd=ROOT, capture_output=True,
                         text=True, timeout=240)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "0 broken" in run.stdout


@pytest.mark.parametrize("importer, imported, contract", [
    ("edge.board", "services.gcs.cli", "the ground (services) over the UAV"),
    ("protocol.messages", "edge.geometry.formation", "the ground (services) over the UAV"),
    ("edge.geometry.formation", "edge.board", "edge: the UAV's process"),
    ("edge.geometry.optics", "edge.world.surface", "edge: the UAV's process"),
    ("edge.world.surface", "edge.camera_service", "edge: the UAV's process"),
    ("services.planner.task", "edge.config", "the ground imports of edge"),
    ("services.web.view", "edge.vehicle.mavlink", "the ground imports of edge"),
    ("edge.geometry.formation", "protocol.bus", "the shared geometry loads"),
    ("edge.geometry.optics", "cv2", "the shared geometry loads"),
    ("edge.world.camera", "zenoh", "the simulated world does not"),
    ("protocol.messages", "zenoh", "the wire contract loads Zenoh"),
    ("protocol.imagery", "cv2", "the wire contract loads OpenCV"),
    ("services.gcs.scoring", "cv2", "the report's record"),
    ("services.recording.record", "zenoh", "the report's record"),
    ("services.recording.record", "services.gcs.report", "service packages"),
    ("services.detector.pipeline", "services.inspection.deliverable", "service packages"),
    ("services.planner.task", "services.detector.detect", "service packages"),
    ("services.attach", "services.orchestration.launcher", "service packages"),
])
def test_a_new_import_across_a_layer_breaks_its_contract(config, graph, importer, imported, contract) -> None:
    assert check(config, graph, contract), "kept on the tree as it is"
    bad = copy.deepcopy(graph)
    bad.add_import(importer=importer, imported=imported)
    assert not check(config, bad, contract)


@pytest.mark.parametrize("module, contract", [("edge.newthing", "edge: the UAV's process"),
                                              ("services.newthing", "service packages")])
def test_a_new_module_must_take_its_place_in_the_layers(config, graph, module, contract) -> None:
    bad = copy.deepcopy(graph)
    bad.add_module(module)
    assert not check(config, bad, contract)


def _loaded(*modules: str) -> set[str]:
    """The heavy dependencies (zenoh, cv2) loaded by importing ``modules`` in a fresh interpreter."""
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "print(' '.join(sorted(m for m in ('zenoh', 'cv2') if m in sys.modules)))")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    return set(run.stdout.split())


def test_the_reports_scoring_loads_neither_the_bus_nor_opencv() -> None:
    assert _loaded("services.gcs.scoring", "services.gcs.figures", "services.gcs.verdict",
                   "services.recording.record") == set()


def test_the_shared_geometry_loads_neither_the_bus_nor_opencv() -> None:
    assert _loaded("edge.geometry.formation", "edge.geometry.optics", "edge.geometry.neighbourhood",
                   "edge.geometry.waypoint_mission", "edge.geometry.ardupilot_items", "edge.geometry.validate") == set()


def test_the_simulated_world_does_not_load_the_bus() -> None:
    # OpenCV draws the wall's cracks and renders the synthetic camera's view
    assert _loaded("edge.world.surface", "edge.world.camera") == {"cv2"}


def test_the_ground_truth_does_not_load_the_bus() -> None:
    """The ground truth is the wall's crack mask, drawn by OpenCV: loading cv2 is its nature, not the bus."""
    assert "zenoh" not in _loaded("services.inspection.ground_truth")
