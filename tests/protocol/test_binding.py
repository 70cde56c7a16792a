from protocol import binding, keys


def test_body_must_name_the_uav_of_its_key():
    assert binding.matches(keys.state("f", 2), 2)
    assert not binding.matches(keys.state("f", 2), 1)
    assert binding.matches(keys.event("f", 3), None, "uav/3")
    assert not binding.matches(keys.event("f", 3), None, "uav/1")
    assert not binding.matches(keys.gcs_event("f"), None, "uav/1")  # no UAV key: may not claim one
    assert binding.matches(keys.gcs_event("f"), None, "gcs")
    assert not binding.matches("not/a/skynet/key", 1)


def test_every_role_speaks_only_for_its_own_key():
    own = {
        keys.event("f", 2): "uav/2",
        keys.gcs_event("f"): "gcs",
        keys.heartbeat("f"): "gcs",
        keys.rcu_event("f", "planner"): "planner",
        keys.rcu_stats("f", "detector-0"): "detector-0",
        keys.rcu_event("f", "detector"): "detector",
        keys.gateway_stats("f", "1"): "gateway/1",
    }
    claims = set(own.values()) | {"uav/1", "uav2", "detector-1", "gateway/2", "", "gcs ", "uav/2/../gcs"}
    for key, source in own.items():
        assert binding.source_of(key) == source
        assert binding.matches(key, None, source) and binding.source_matches(key, source)
        for forged in claims - {source}:
            assert not binding.matches(key, None, forged), (key, forged)  # e.g. uav/2/event claiming "gcs"
            assert not binding.source_matches(key, forged), (key, forged)
    assert binding.source_of("skynet/f/uav/2/bogus") is None and not binding.source_matches("x/y", "gcs")


def test_a_frame_speaks_only_for_the_camera_of_the_uav_whose_key_carried_it():
    from protocol.binding import frame_source
    from protocol.rtp import ssrc_for

    assert frame_source("skynet/demo/uav/2/camera", ssrc_for(2, 1)) == (2, 1)
    assert frame_source("skynet/demo/uav/1/camera", ssrc_for(2)) is None  # another UAV's camera
    assert frame_source("skynet/demo/uav/2/camera", 0x12345678) is None  # not a SkyNet SSRC
    assert frame_source("not/a/key", ssrc_for(2)) is None
