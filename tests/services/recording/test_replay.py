"""MCAP log and replay (services.recording): streamed to disk, read back in order, replayed onto a real bus.

A recorder (a real Zenoh session) logs a fleet's traffic, including a malformed sample and the
imagery frames byte for byte; ``skynet replay --speed 10`` in its own process plays the file
back under another fleet name, and a subscriber checks that every key's messages come in the
recorded order, as the same messages.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from protocol import codec, keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import COMMAND, IMAGERY, TELEMETRY
from protocol.messages import Event, ImageMeta, Intrinsics, Mode, VehicleState
from protocol.rtp import RtpSender, ssrc_for
from services.recording.mcap_log import FRAME_ENCODING, RAW_ENCODING, McapLog, bus_bytes, read
from services.recording.record import MissionRecord
from services.recording.recorder import MissionLogWriter
from tests.conftest import wait_until

FLEET = "rec"


def _state(u: int, k: int) -> VehicleState:
    return VehicleState(uav=u, seq=k, t=k * 0.05, stamp=time.time(), pos=(u, k * 0.1, 10.0), vel=(0, 2, 0),
                        att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION)


def _frame(sender: RtpSender, u: int) -> bytes:
    jpeg = cv2.imencode(".jpg", np.full((48, 64, 3), 90, np.uint8))[1].tobytes()
    meta = ImageMeta(uav=u, capture_id=0, t=0.0, stamp=time.time(), cam_pos=(0, 0, 0),
                     cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                     intrinsics=Intrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0))
    return pack_image(sender, meta, jpeg, meta.stamp)


def test_log_reads_back_in_order_with_schemas(tmp_path: Path) -> None:
    log = McapLog(tmp_path / "a.mcap", chunk_size=4096)  # small chunks: many of them on disk, one in memory
    sender = RtpSender(ssrc_for(1, 1), initial_seq=0)
    frame = _frame(sender, 1)
    for k in range(300):
        log.write_sample(keys.state(FLEET, 1 + k % 3), codec.encode(_state(1 + k % 3, k)), 100.0 + k * 0.01)
    assert log.write_sample(keys.preview(FLEET, 1), frame, 104.0) == "frame"
    assert log.write_sample(keys.gcs_event(FLEET), b"\x93garbage", 104.5) == "raw"
    log.close()
    items = list(read(tmp_path / "a.mcap"))
    states = [i for i in items if i.topic.endswith("/state")]
    assert [i.message().seq for i in states] == list(range(300))
    assert {i.schema for i in states} == {"skynet.VehicleState"} and {i.encoding for i in states} == {"json"}
    frames = [i for i in items if i.encoding == FRAME_ENCODING]
    assert len(frames) == 1 and bus_bytes(frames[0]) == frame  # imagery goes back byte for byte
    viewer = [i for i in items if i.topic.endswith("/preview/jpeg")]
    assert viewer and viewer[0].schema == "foxglove.CompressedImage" and bus_bytes(viewer[0]) is None
    raw = [i for i in items if i.encoding == RAW_ENCODING]
    assert len(raw) == 1 and bus_bytes(raw[0]) == b"\x93garbage"
    assert codec.decode(bus_bytes(states[5])) == states[5].message()


def test_record_then_replay_at_10x_keeps_order_per_key(group, gateway, tmp_path: Path) -> None:
    path = tmp_path / "mission.mcap"
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "gcs") as gcs, Bus(cfg, FLEET, "uav") as uav:
        rec = MissionLogWriter(gcs, path)
        time.sleep(0.5)
        pubs = {u: uav.publisher(keys.state(FLEET, u), TELEMETRY) for u in (1, 2, 3)}
        ev = uav.publisher(keys.event(FLEET, 2), COMMAND)
        img = uav.publisher(keys.preview(FLEET, 1), IMAGERY)
        sender = RtpSender(ssrc_for(1, 1))
        for k in range(100):
            for u in (1, 2, 3):
                pubs[u].put(_state(u, k))
            if k % 10 == 0:
                ev.put(Event(source="uav2", stamp=time.time(), kind="neighbour-up", data={"k": k}))
                img.put_bytes(_frame(sender, 1))
            time.sleep(0.015)  # 67 Hz per UAV: inside the state budget the recorder holds each source to
        # telemetry is best-effort (a busy machine may drop a few); events are reliable
        assert wait_until(lambda: rec.counts["json"] >= 270 + 10 and rec.counts["frame"] >= 8, 10), rec.counts
        time.sleep(0.5)
        rec.finish(MissionRecord(fleet=FLEET, speed=1.0, started=time.time()))
    logged = defaultdict(list)
    for item in read(path):
        if bus_bytes(item) is not None:
            logged[item.topic].append(bus_bytes(item))
    assert len(logged[keys.state(FLEET, 2)]) >= 85 and len(logged[keys.preview(FLEET, 1)]) >= 8
    assert [codec.decode(b).data["k"] for b in logged[keys.event(FLEET, 2)]] == list(range(0, 100, 10))

    got = defaultdict(list)
    with Bus(cfg, "replayed", "watch") as watch:
        watch.subscribe(keys.state("replayed", "*"), lambda m, s: got[str(s.key_expr)].append(m.seq),
                        expect=VehicleState)
        watch.subscribe(keys.all_events("replayed"), lambda m, s: got[str(s.key_expr)].append(m.data["k"]),
                        expect=Event)
        watch.subscribe_raw(keys.preview("replayed", "*"),
                            lambda s: got[str(s.key_expr)].append(s.payload.to_bytes()))
        time.sleep(0.5)
        svc = group.start("replay", ["replay", str(path), "--speed", "10", "--as-fleet", "replayed", "--multilink",
                                     *[a for e in gateway for a in ("--connect", e)]])
        assert svc.wait_for("replayed:", 60), "\n".join(svc.lines)
        wait_until(lambda: sum(map(len, got.values())) >= sum(map(len, logged.values())), 5)
    for u in (1, 2, 3):
        seqs = got[keys.state("replayed", u)]
        # best-effort at 10x (about 2,000 states a second): most, not all, on a loaded machine (71 of 100 seen
        # in one CI run beside other work); what this test holds the replay to is the order
        assert len(seqs) >= 0.5 * len(logged[keys.state(FLEET, u)]), (u, len(seqs))
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), seqs  # in order, no duplicates
    assert got[keys.event("replayed", 2)] == list(range(0, 100, 10))  # reliable: all, in order
    frames = got[keys.preview("replayed", 1)]
    # best-effort like the states: nearly all, byte for byte, in the recorded order
    recorded = logged[keys.preview(FLEET, 1)]
    at = [recorded.index(f) for f in frames]  # ValueError: a frame the log does not hold
    assert at == sorted(set(at)) and len(frames) >= 8, (at, len(recorded))
