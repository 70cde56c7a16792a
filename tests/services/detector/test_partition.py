"""services.detector.partition: N instances cover every UAV exactly once, on concrete keys."""

import pytest
import zenoh

from protocol import keys
from services.detector.partition import MAX_UAV, Partition


def test_n_partitions_cover_every_uav_exactly_once():
    for n in (1, 2, 3, 7):
        owned = [u for k in range(n) for u in Partition(k, n).uavs()]
        assert sorted(owned) == list(range(1, MAX_UAV + 1))


def test_keys_match_only_the_owned_cameras():
    p = Partition.parse("1/2")
    exprs = [zenoh.KeyExpr(k) for k in p.camera_keys("f", max_uav=8)]
    for uav in range(1, 9):
        hit = any(e.intersects(zenoh.KeyExpr(keys.camera("f", uav))) for e in exprs)
        assert hit == (uav % 2 == 1), uav
        assert not any(e.intersects(zenoh.KeyExpr(keys.preview("f", uav))) for e in exprs)
    assert p.name == "detector-1" and str(p) == "1/2"
    assert Partition().camera_keys("f") == [keys.camera("f", "*")] and Partition().name == "detector"


def test_instance_names_are_heard_on_one_key_expression():
    every = zenoh.KeyExpr(keys.rcu_instances("f", "detector", "stats"))
    for name in ("detector", "detector-0", "detector-12"):
        assert every.includes(zenoh.KeyExpr(keys.rcu_stats("f", name)))
    assert not every.intersects(zenoh.KeyExpr(keys.rcu_stats("f", "planner")))
    assert keys.parse(keys.rcu_stats("f", "detector-3")).name == "detector-3"


@pytest.mark.parametrize("text", ["2/2", "-1/2", "1", "a/b", "0/0", "0/256", "1/2/3"])
def test_bad_partitions_are_refused_with_a_reason(text):
    with pytest.raises(ValueError, match="partition"):
        Partition.parse(text)
