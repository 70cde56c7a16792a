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


def test_the_formation_heading_is_held_when_the_fleet_hovers_and_the_ground_has_no_formation():
    """A formation flying along +y in its exact shape, then hovering in that shape (speed 0): with the heading
    held the error stays 0, as in the report; at heading 0 it would read the rotated slots' distance. Landed
    (or any mode but MISSION and HOLD) there is no formation error to show."""
    import math

    import numpy as np

    from edge.geometry.formation import formation_error
    from services.gcs.progress import HeadingHold, formation_rms

    offsets = {1: (0.0, 0.0, 2.0), 2: (3.0, 0.0, -1.0), 3: (-3.0, 0.0, -1.0)}
    c = math.cos(math.pi / 2), math.sin(math.pi / 2)

    def at(vel):  # each UAV in its slot for heading +y (R_z(90°) of its offset)
        return {u: VehicleState(uav=u, seq=1, t=1.0, stamp=1.0, pos=(c[0] * o[0] - c[1] * o[1],
                                                                      c[1] * o[0] + c[0] * o[1], 20 + o[2]),
                                vel=vel, att=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), mode=Mode.MISSION, armed=True)
                for u, o in offsets.items()}

    heading = HeadingHold()
    assert formation_rms(at((0.0, 2.0, 0.0)), offsets, heading) < 1e-9 and heading.yaw == math.pi / 2
    assert formation_rms(at((0.0, 0.0, 0.0)), offsets, heading) < 1e-9  # landed: the heading is held
    unheld = formation_rms(at((0.0, 0.0, 0.0)), offsets)  # a fresh hold: heading 0
    assert unheld > 1.0
    assert unheld == formation_error({u: s.pos for u, s in at((0, 0, 0)).items()}, None, 0.0, offsets)
    assert np.isfinite(unheld)
    landed = {u: s.model_copy(update={"mode": Mode.LANDED, "vel": (0.0, 0.0, 0.0)}) for u, s in at((0, 2, 0)).items()}
    assert formation_rms(landed, offsets, heading) is None
    assert "formation RMS error -" in render("landing", landed, (1, 2, 3), [], 26, 26, offsets, 99.0)[-1]


def test_a_message_above_the_live_block_cannot_move_the_terminal_cursor():
    import io

    from services.gcs.progress import LiveDisplay

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Tty()
    d = LiveDisplay(out)
    d.update(["mission   1.0 s  phase: mission"], force=True)
    d.message("event from uav/2: \x1b[2J\x1b]0;pwned\x07 text\nsecond line")
    text = out.getvalue()
    assert "\\x1b[2J\\x1b]0;pwned\\x07 text\nsecond line" in text  # escaped; a traceback's line breaks kept
    assert "\x1b[2J" not in text and "\x07" not in text
