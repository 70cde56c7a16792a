"""The whole 3-UAV mission with ``--vehicle mavlink``: every edge flies its own sim autopilot over MAVLink.

In GUIDED (position targets streamed) and in AUTO (the trajectory uploaded as a waypoint mission,
kept in formation by speed corrections). Same bounds as the built-in vehicle's mission
(tests/services/orchestration/test_launcher.py): every UAV at the goal, every capture imaged, formation RMS under 1 m.
"""

import pytest

pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")

from tests.conftest import fly_mission

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)

FORMATION_RMS_BOUND_M = 1.0


@pytest.mark.parametrize("flight", ["guided", "auto"])
def test_mission_with_mavlink_vehicles(request, tmp_path, flight):
    # GUIDED: the run on autopilots still starting when the plan is ready (tests/conftest.py), shared with
    # tests/services/orchestration/test_autopilot_readiness.py
    run = request.getfixturevalue("slow_boot_guided_mission") if flight == "guided" else fly_mission(
        tmp_path / "report", "--vehicle", "mavlink", "--speed", "8", "--flight", flight, "--sim-boot-scale", "0.1",
        timeout=300)
    run.flown(rms_bound_m=FORMATION_RMS_BOUND_M)
    log = (run.out / "services.log").read_text()
    assert all(f"sim-autopilot: uav {i} (system id {i})" in log for i in (1, 2, 3))
    flown = [f"UAV {i}: flying AUTO from mission item" in log for i in (1, 2, 3)]
    assert flown == [flight == "auto"] * 3  # in AUTO the autopilots flew the uploaded missions
    assert "a mode the edge did not command" not in log
