from protocol import binding, keys


def test_body_must_name_the_uav_of_its_key():
    assert binding.matches(keys.state("f", 2), 2)
    assert not binding.matches(keys.state("f", 2), 1)
    assert binding.matches(keys.event("f", 3), None, "uav/3")
    assert not binding.matches(keys.event("f", 3), None, "uav/1")
    assert not binding.matches(keys.gcs_event("f"), None, "uav/1")  # no UAV key: may not claim one
    assert binding.matches(keys.gcs_event("f"), None, "gcs")
    assert not binding.matches("not/a/skynet/key", 1)
