"""SkyNet neighbourhoods: formations of three, neighbours only within one."""

import pytest

from edge.geometry.neighbourhood import FORMATION_SIZE, formation_index, formations, members, neighbours


def test_the_papers_three_uavs_are_one_formation():
    assert FORMATION_SIZE == 3
    assert formations(3) == [(1, 2, 3)]
    assert neighbours(2) == (1, 3)


def test_a_fleet_splits_into_formations_of_three_the_last_one_shorter():
    assert formations(7) == [(1, 2, 3), (4, 5, 6), (7,)]
    assert formation_index(4) == formation_index(6) == 1
    assert neighbours(5, fleet=7) == (4, 6)
    assert neighbours(7, fleet=7) == ()
    assert members(7) == (7, 8, 9)  # fleet size unknown: the full slot range
    assert all(len(neighbours(u, fleet=100)) <= FORMATION_SIZE - 1 for u in range(1, 101))


def test_neighbourhood_is_symmetric_and_never_holds_itself():
    for u in range(1, 101):
        ns = neighbours(u, fleet=100)
        assert u not in ns
        assert all(u in neighbours(j, fleet=100) for j in ns)


def test_other_formation_sizes():
    assert formations(6, size=2) == [(1, 2), (3, 4), (5, 6)]
    assert neighbours(3, size=1) == ()


@pytest.mark.parametrize("bad", [0, 256, -1, 2.0, "3"])
def test_bad_ids_are_refused(bad):
    with pytest.raises(ValueError):
        neighbours(bad)


@pytest.mark.parametrize("bad", [0, -3, 1.5])
def test_bad_sizes_are_refused(bad):
    with pytest.raises(ValueError):
        members(1, size=bad)
    with pytest.raises(ValueError):
        formations(6, size=bad)
