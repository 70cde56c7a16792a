"""Sites of a router mesh: who attaches to which gateway, the router links, their addresses."""

import pytest

from edge.geometry.neighbourhood import formation_index
from services.orchestration.sites import (
    check_sites,
    gateway_process,
    mesh,
    parse_rcu_sites,
    router_endpoint,
    site_of_uav,
    veth_addresses,
)


def test_formations_are_never_split_across_sites_and_every_uav_has_one():
    m = mesh(24, 3, {"planner": 2, "detector": 1})
    seen = [u for s in m.sites for u in s.uavs]
    assert sorted(seen) == list(range(1, 25))
    for s in m.sites:
        assert {formation_index(u) % 3 for u in s.uavs} == {s.index}
    assert m.site_of("planner") == 2 and m.site_of("detector") == 1 and m.site_of(7) == site_of_uav(7, 3) == 2
    assert m.links == ((0, 1), (0, 2), (1, 2)) and m.peers_of(2) == (0, 1) and m.peers_of(0) == ()
    with pytest.raises(KeyError):
        m.site_of("gcs")


def test_bad_sites_are_refused():
    for bad in ((3, 0, None), (3, 17, None), (3, 2, {"planner": 2}), (256, 2, None)):
        with pytest.raises(ValueError):
            mesh(*bad)


def test_veth_addresses_are_distinct_private_30s():
    links = mesh(0, 4).links
    addr = veth_addresses(links)
    ips = [a for pair in addr.values() for a in pair]
    assert len(ips) == len(set(ips)) == 2 * len(links) == 12
    assert all(a.startswith("10.18.") and a.endswith("/30") for a in ips)
    assert router_endpoint("10.18.0.5/30") == "tcp/10.18.0.5:7447"


def test_sites_option_is_one_to_the_number_of_formations():
    assert check_sites(1, 1) == 1 and check_sites(2, 4) == 2 and check_sites(4, 12) == 4
    for sites, uavs, why in ((0, 6, "at least one site"), (-1, 6, "at least one site"),
                             (3, 6, "6 UAVs fly as 2 formations"), (2, 3, "1 formation of up to 3")):
        with pytest.raises(ValueError, match=why):
            check_sites(sites, uavs)
    with pytest.raises(ValueError):
        check_sites(True, 6)  # a bool is not a number of sites
    assert [gateway_process(k) for k in range(3)] == ["gateway", "gateway-1", "gateway-2"]


def test_rcu_sites_default_to_site_0_and_detector_names_every_instance():
    names = ["planner", "detector-0", "detector-1"]
    assert parse_rcu_sites([], 2, names) == {"planner": 0, "detector-0": 0, "detector-1": 0}
    assert parse_rcu_sites(["detector=1"], 2, names) == {"planner": 0, "detector-0": 1, "detector-1": 1}
    assert parse_rcu_sites([" planner = 1 "], 2, ["planner", "detector"]) == {"planner": 1, "detector": 0}
    assert parse_rcu_sites(["planner=1", "planner=0"], 2, names)["planner"] == 0  # later wins
    for item, why in (("planner", "NAME=SITE"), ("planner=", "NAME=SITE"), ("planner=2", "not one of 0..1"),
                      ("planner=x", "not one of 0..1"), ("gcs=1", "no RCU 'gcs'"), ("detector-2=1", "no RCU")):
        with pytest.raises(ValueError, match=why):
            parse_rcu_sites([item], 2, names)
