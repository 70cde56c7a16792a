import pytest

from protocol import keys
from protocol.links import COMMAND, IMAGERY, TELEMETRY, class_of_topic


def test_builders_follow_the_key_space():
    assert keys.state("f", 3) == "skynet/f/uav/3/state"
    assert keys.cmd("f", 1) == "skynet/f/uav/1/cmd"
    assert keys.camera("f", "*") == "skynet/f/uav/*/camera"
    assert keys.planner("f") == "skynet/f/rcu/planner/plan"
    assert keys.defects("f") == "skynet/f/rcu/detector/defects"
    assert keys.gateway_stats("f", "gw1") == "skynet/f/gateway/gw1/stats"
    assert keys.heartbeat("f") == "skynet/f/gcs/heartbeat"


@pytest.mark.parametrize("key", [
    keys.state("a", 1), keys.cmd("a", 255), keys.camera("a", 9), keys.event("a", 2), keys.alive("a", 2),
    keys.planner("a"), keys.defects("a"), keys.gateway_stats("a", 1), keys.heartbeat("a"), keys.gcs_event("a"),
    keys.rcu_alive("a", "detector"), keys.rcu_event("a", "planner"),
])
def test_parse_inverts_builders(key):
    info = keys.parse(key)
    assert info.fleet == "a"
    assert key.endswith(info.topic)


@pytest.mark.parametrize("bad", ["", "skynet", "other/a/uav/1/state", "skynet/a/uav/0/state", "skynet/a/uav/256/state",
                                 "skynet/a/uav/x/state", "skynet/a/uav/1/teleport", "skynet/a b/uav/1/state",
                                 "skynet/a/rcu/planner/defects", "skynet/a/gateway/1/other"])
def test_parse_rejects_foreign_keys(bad):
    with pytest.raises(keys.KeyError_):
        keys.parse(bad)


@pytest.mark.parametrize("fleet,uav", [("a/b", 1), ("", 1), ("a", 0), ("a", 256), ("a", True), ("a*", 1)])
def test_builders_reject_bad_chunks(fleet, uav):
    with pytest.raises(keys.KeyError_):
        keys.state(fleet, uav)


def test_advanced_names_the_recovery_keys_of_a_key():
    assert keys.advanced(keys.camera("f", "*")) == "skynet/f/uav/*/camera/@adv/**"
    assert keys.advanced(keys.camera("f", 2)) == "skynet/f/uav/2/camera/@adv/**"
    for bad in ("other/f/x", keys.fleet_all("f"), "skynet/f/uav/1/camera/@adv/**", 3):
        with pytest.raises(keys.KeyError_):
            keys.advanced(bad)


def test_topics_map_to_link_classes():
    assert class_of_topic("state") is TELEMETRY
    assert class_of_topic("camera") is IMAGERY
    assert class_of_topic("cmd") is COMMAND
    assert COMMAND.reliable and not TELEMETRY.reliable and not IMAGERY.reliable
    assert TELEMETRY.express and COMMAND.congestion == "block" and TELEMETRY.congestion == "drop"


def test_preview_is_a_uav_key_the_camera_wildcard_does_not_match():
    import zenoh

    key = keys.preview("f", 2)
    assert key == "skynet/f/uav/2/preview"
    info = keys.parse(key)
    assert (info.area, info.topic, info.uav) == ("uav", "preview", 2)
    cams = zenoh.KeyExpr(keys.camera("f", "*"))
    assert not cams.intersects(zenoh.KeyExpr(key))  # the detector never sees preview frames
    assert not zenoh.KeyExpr(keys.advanced(keys.camera("f", "*"))).intersects(zenoh.KeyExpr(key))
    assert cams.intersects(zenoh.KeyExpr(keys.camera("f", 2)))
    assert zenoh.KeyExpr(keys.fleet_all("f")).intersects(zenoh.KeyExpr(key))  # the recorder takes it
    assert not any(zenoh.KeyExpr(m).intersects(zenoh.KeyExpr(key)) for m in keys.metered("f"))  # the meter not


@pytest.mark.parametrize("key", [
    keys.state("f", 1), keys.cmd("f", 255), keys.camera("f", 9), keys.event("f", 2), keys.alive("f", 2),
    keys.planner("f"), keys.defects("f"), keys.gateway_stats("f", 1), keys.heartbeat("f"), keys.gcs_event("f"),
    keys.rcu_alive("f", "detector-1"), keys.rcu_event("f", "planner"), keys.rcu_stats("f", "detector"),
])
def test_the_meter_takes_every_key_but_the_previews(key):
    import zenoh

    assert sum(zenoh.KeyExpr(m).intersects(zenoh.KeyExpr(key)) for m in keys.metered("f")) == 1
    assert not any(zenoh.KeyExpr(m).intersects(zenoh.KeyExpr(key)) for m in keys.metered("g"))
