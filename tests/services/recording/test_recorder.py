"""The recorder under a flood (services.recording.recorder): each source is held to its topic's budget
before anything is queued, so a flood of one key neither fills the log nor evicts another UAV's states;
samples on keys outside the key space are not logged. Real Zenoh sessions through a real gateway."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader

from protocol import keys
from protocol.budget import LIMITS
from protocol.bus import Bus, BusConfig
from protocol.links import COMMAND
from protocol.messages import Event, Mode, VehicleState
from services.recording.mcap_log import read
from services.recording.record import MissionRecord
from services.recording.recorder import MissionLogWriter
from tests.conftest import wait_until

FLEET = "rec"
FLOOD = 3000


def test_a_flood_of_one_key_is_cut_to_its_budget_and_the_other_sources_are_all_logged(gateway, tmp_path: Path):
    path = tmp_path / "mission.mcap"
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "gcs") as gcs, Bus(cfg, FLEET, "uav") as uav:
        rec = MissionLogWriter(gcs, path)
        time.sleep(0.5)
        flood = uav.publisher(keys.event(FLEET, 1), COMMAND)
        state = uav.publisher(keys.state(FLEET, 2), COMMAND)  # reliable here: the test counts every one
        t0 = time.monotonic()
        for k in range(FLOOD):
            flood.put(Event(source="uav1", stamp=time.time(), kind="trust-refused", text="x" * 500))
            if k % 100 == 0:
                state.put(VehicleState(uav=2, seq=k // 100, t=k * 0.01, stamp=time.time(), pos=(0, 0, 10),
                                       vel=(0, 0, 0), att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION))
        uav.session.put(f"skynet/{FLEET}/uav/1/bogus", b"not a key of the key space")
        elapsed = time.monotonic() - t0
        assert wait_until(lambda: rec.counts["over-budget"] + rec.counts["json"] >= FLOOD + FLOOD // 100, 20), \
            rec.counts
        assert wait_until(lambda: rec.counts["unknown-key"] == 1, 5), rec.counts
        rec.finish(MissionRecord(fleet=FLEET, speed=1.0, started=time.time()))
    logged = Counter(item.topic for item in read(path))
    limit = LIMITS["event"]
    assert 0 < logged[keys.event(FLEET, 1)] <= limit.burst + limit.rate_hz * (elapsed + 2.0)
    assert logged[keys.state(FLEET, 2)] == FLOOD // 100  # the other source: every sample
    assert not any(t.endswith("/bogus") for t in logged)
    with open(path, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["skynet.recorder"]
    assert int(meta["over-budget"]) == FLOOD - logged[keys.event(FLEET, 1)] and meta["unknown-key"] == "1"
