"""The whole 3-UAV mission through the launcher with ``--vehicle mavlink --sim-firmware px4``: every edge picks the
PX4 dialect from its sim autopilot's HEARTBEAT and flies it in OFFBOARD (guided) and in AUTO.MISSION (auto), in the
default secure mode. Same bounds as the ArduCopter missions (tests/services/orchestration/test_mavlink_mission.py)."""

import pytest

pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")

from tests.conftest import fly_mission

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)

FORMATION_RMS_BOUND_M = 1.0


@pytest.mark.parametrize("flight", ["guided", "auto"])
def test_mission_with_px4_sim_autopilots(tmp_path, flight):
    run = fly_mission(tmp_path / "report", "--vehicle", "mavlink", "--speed", "8", "--flight", flight,
                      "--sim-firmware", "px4", "--sim-boot-scale", "0.1", timeout=300)
    run.flown(rms_bound_m=FORMATION_RMS_BOUND_M)
    log = (run.out / "services.log").read_text()
    assert all(f"sim-autopilot: uav {i} (system id {i}) as px4" in log for i in (1, 2, 3))
    assert all(f"UAV {i}: autopilot parameters in PX4" in log for i in (1, 2, 3))  # the dialect from the HEARTBEAT
    flown = [f"UAV {i}: flying AUTO.MISSION from mission item" in log for i in (1, 2, 3)]
    assert flown == [flight == "auto"] * 3
    assert "a mode the edge did not command" not in log and "Failsafe: no offboard" not in log
