"""The ground station's downsampled view of the fleet's states through the gateway."""

import json
import time

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig, multilink_endpoints
from protocol.links import TELEMETRY
from protocol.messages import VehicleState
from services.gateway.downsample import state_downsampling
from services.orchestration.process import free_port_pair
from tests.conftest import wait_until

FLEET = "thin"


def test_config_fragment_and_bad_rates():
    doc = state_downsampling(FLEET, 4, 2)
    rule = doc["downsampling"][0]
    assert rule["flows"] == ["egress"]
    assert rule["rules"] == [{"key_expr": keys.state(FLEET, u), "freq": 4.0} for u in (1, 2)]  # a rule per UAV
    for bad in (0, -1, float("nan"), float("inf"), "4"):
        with pytest.raises(ValueError):
            state_downsampling(FLEET, bad, 3)
    with pytest.raises(ValueError):
        state_downsampling(FLEET, 4, 0)


def test_gateway_forwards_a_few_states_a_second_to_a_client_while_neighbours_get_all(group, tmp_path):
    cfg = tmp_path / "gateway.json5"
    cfg.write_text(json.dumps(state_downsampling(FLEET, 4.0, 2)))
    gw = multilink_endpoints("127.0.0.1", *free_port_pair())
    svc = group.start("gateway", ["gateway", "--fleet", FLEET, "--multilink", "--config", str(cfg),
                                  *[a for e in gw for a in ("--listen", e)]])
    assert svc.wait_ready(20), "\n".join(svc.lines)
    for uav, home in {1: "10,10,0", 2: "14,10,0"}.items():
        edge = group.start(f"uav{uav}", ["edge", "--uav", str(uav), "--fleet", FLEET, "--multilink", "--camera", "none",
                                         *[a for e in gw for a in ("--connect", e)], "--listen", "tcp/127.0.0.1:0",
                                         "--home", home])
        assert edge.wait_ready(30), "\n".join(edge.lines)
    got: list[VehicleState] = []
    other: list[VehicleState] = []
    with Bus(BusConfig(mode="client", connect=gw, multilink=True), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: (got if m.uav == 1 else other).append(m),
                      expect=VehicleState, link=TELEMETRY)
        assert wait_until(lambda: got and got[-1].neighbours == 1, 30), got[-1:]  # UAV 1 hears UAV 2 (SkyNet)
        first = got[-1].seq
        time.sleep(3.0)
        last = got[-1].seq
        n = sum(1 for m in got if first < m.seq <= last)
        n_other = len(other)
    sent = last - first  # UAV 1 published this many states (20 Hz) meanwhile
    assert sent >= 30, sent
    assert 0 < n <= sent / 3, (n, sent)  # 4 Hz of 20 Hz, with room to spare
    assert n >= 6, n  # about 12 in 3 s: UAV 1 gets its own 4 Hz, not a share of one rate for the fleet
    assert n_other > 0
    assert got[-1].neighbours == 1  # UAV 1 kept hearing UAV 2 at full rate (fresh within 1 s)
