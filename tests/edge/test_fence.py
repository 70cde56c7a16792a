"""The board's geofence only narrows: configured or signed, a later upload cannot widen it (edge.validate)."""

from __future__ import annotations

import pytest

from edge.validate import narrowed_fence, validate_command
from protocol.messages import Box, Trajectory, UploadTrajectory, Waypoint

BOX = Box(lo=(0, 0, 0), hi=(101, 141, 40))
WIDE = Box(lo=(-3000, -3000, 0), hi=(3000, 3000, 150))


def upload(pos, fence):
    traj = Trajectory(uav=1, waypoints=[Waypoint(t=0, pos=(10, 10, 5)), Waypoint(t=100, pos=pos)])
    return UploadTrajectory(uav=1, cmd_id=1, trajectory=traj, geofence=fence)


def test_a_wider_fence_never_replaces_the_boards():
    assert narrowed_fence(None, BOX) == BOX  # the first signed fence
    assert narrowed_fence(BOX, WIDE) == BOX  # a wider one: the board keeps its own
    inner = Box(lo=(10, 10, 0), hi=(50, 50, 30))
    assert narrowed_fence(BOX, inner) == inner
    assert narrowed_fence(BOX, Box(lo=(50, -10, 0), hi=(200, 60, 120))) == Box(lo=(50, 0, 0), hi=(101, 60, 40))
    with pytest.raises(ValueError, match="does not overlap"):
        narrowed_fence(BOX, Box(lo=(400, 0, 0), hi=(500, 100, 40)))


def test_an_upload_must_stay_inside_the_boards_fence_and_its_own():
    assert validate_command(upload((90, 130, 30), WIDE), 1, BOX, 12.0) == ""
    assert "outside the geofence" in validate_command(upload((520, 130, 120), WIDE), 1, BOX, 12.0)
    # a trajectory outside the fence it comes with is refused even by a board with a wider fence
    assert "outside the geofence" in validate_command(upload((90, 130, 30), Box(lo=(0, 0, 0), hi=(50, 50, 40))),
                                                      1, WIDE, 12.0)
    # no fence of its own (unconfigured, --insecure): the upload's
    assert "outside the geofence" in validate_command(upload((520, 130, 30), BOX), 1, None, 12.0)
