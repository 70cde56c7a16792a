"""The live mission display's pure part: one line per UAV, and what it says about a UAV in trouble."""

from protocol.messages import Mode, VehicleState
from services.gcs.progress import bar, render


def _state(uav: int, progress: float) -> VehicleState:
    return VehicleState(uav=uav, seq=1, t=10.0, stamp=1.0, pos=(uav * 3.0, 0.0, 20.0), vel=(2.0, 0.0, 0.0),
                        att=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), mode=Mode.MISSION, armed=True, progress=progress)


def test_bar_is_clamped_and_proportional():
    assert bar(0.5, 10) == "█" * 5 + "·" * 5
    assert bar(-1.0, 4) == "····" and bar(2.0, 4) == "████"


def test_render_marks_lost_and_silent_uavs_only():
    offsets = {1: (0.0, 0.0, 2.0), 2: (3.0, 0.0, -1.0), 3: (-3.0, 0.0, -1.0)}
    states = {1: _state(1, 0.25), 2: _state(2, 0.5)}
    lines = render("mission", states, (1, 2, 3), [2.0, 3.0], 4, 26, offsets, 12.0,
                   notes={2: "silent 3.2 s", 3: "LOST"})
    assert lines[0].startswith("mission") and "phase: mission" in lines[0]
    assert "25.0 %" in lines[1] and "[" not in lines[1]
    assert "50.0 %" in lines[2] and lines[2].endswith("[silent 3.2 s]")
    assert "no telemetry yet" in lines[3] and lines[3].endswith("[LOST]")
    assert "defect reports 4/26" in lines[4]
    assert render("mission", states, (1, 2), [], 0, 0, offsets, 1.0)[1:3] == lines[1:2] + [lines[2].split("  [")[0]]
