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


def test_a_uav_claiming_anothers_publisher_id_cannot_erase_its_frames_from_the_log(gateway, tmp_path: Path):
    """Recovery tracks sequence numbers per source id, which any sender may claim: uav2 puts one sample on its
    own camera key under uav1's camera's id, far ahead in sequence. The recovering subscription then drops
    uav1's next frames as already seen; the log still holds every one, from the live subscription."""
    from protocol.links import IMAGERY
    from protocol.rtp import RtpSender, ssrc_for
    from services.recording.mcap_log import FRAME_ENCODING

    path = tmp_path / "mission.mcap"
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "gcs") as gcs, Bus(cfg, FLEET, "uav1") as uav1, Bus(cfg, FLEET, "uav2") as uav2:
        rec = MissionLogWriter(gcs, path)
        time.sleep(0.5)
        cam = uav1.publisher(keys.camera(FLEET, 1), IMAGERY, cache=16)
        rtp = RtpSender(ssrc_for(1, 0))
        sent = [rtp.frame(f"frame {i}".encode(), time.time()) for i in range(12)]
        for f in sent[:3]:
            cam.put_bytes(f)
            time.sleep(0.1)
        time.sleep(0.5)
        import zenoh

        uav2.session.put(keys.camera(FLEET, 2), b"forged", source_info=zenoh.SourceInfo(cam._pub.id, 1_000_000))
        time.sleep(1.0)
        for f in sent[3:]:
            cam.put_bytes(f)
            time.sleep(0.1)
        time.sleep(1.5)
        rec.close()
    logged = [i.data for i in read(path) if i.encoding == FRAME_ENCODING and i.topic == keys.camera(FLEET, 1)]
    assert sorted(logged) == sorted(sent), (len(logged), len(sent))
