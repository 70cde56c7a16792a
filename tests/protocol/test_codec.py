import math

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import codec
from protocol import messages as m


def _state(**kw):
    base = dict(uav=2, seq=7, t=1.5, stamp=1.7e9, pos=(1.0, 2.0, 30.0), vel=(0.1, 0.0, -0.2),
                att=(0.01, -0.02, 1.2), rates=(0.0, 0.1, 0.0), mode=m.Mode.MISSION, armed=True, battery=0.8)
    base.update(kw)
    return m.VehicleState(**base)


TRAJ = m.Trajectory(uav=1, waypoints=[m.Waypoint(t=0, pos=(0, 0, 10)), m.Waypoint(t=2, pos=(1, 0, 10), capture_id=3)])
BOX = m.Box(lo=(0, 0, 0), hi=(141, 101, 40))
META = m.ImageMeta(uav=1, capture_id=4, t=3.0, stamp=1.7e9, cam_pos=(1, 2, 3), cam_rot=(1, 0, 0, 0, 1, 0, 0, 0, 1),
                   intrinsics=m.Intrinsics(width=640, height=480, fx=500, fy=500, cx=320, cy=240))
SAMPLES = [
    _state(),
    m.Waypoint(t=1, pos=(0, 0, 1)),
    TRAJ,
    BOX,
    m.UploadTrajectory(uav=1, cmd_id=1, trajectory=TRAJ, geofence=BOX),
    m.Takeoff(uav=1, cmd_id=2, altitude=10),
    m.Start(uav=1, cmd_id=3, t0_stamp=1.7e9),
    m.Land(uav=1, cmd_id=4), m.Hold(uav=1, cmd_id=5), m.Resume(uav=1, cmd_id=6), m.ReturnToLaunch(uav=1, cmd_id=7),
    m.SetFormation(uav=1, cmd_id=8, offsets={1: (0, 0, 2), 2: (3, 0, -1), 3: (-3, 0, -1)}),
    m.CommandAck(uav=1, cmd_id=8, accepted=False, reason="outside geofence"),
    m.Heartbeat(seq=3, stamp=1.7e9),
    m.Signed(signer="gcs", kid="0123456789abcdef", seq=1, stamp=1.7e9, to="skynet/demo/uav/1/cmd", type="cmd.land",
             body="AAAA", sig="AAAA"),
    m.PlanRequest(scenario={"name": "x", "origin": {"lat": 1, "lon": 2}, "box": {"lo": [0, 0, 0], "hi": [10, 10, 40]},
                            "start": [1, 1, 10], "goal": [9, 9, 10]}, seed=3),
    m.CapturePoint(capture_id=0, uav=1, pos=(1, 2, 3), look=(1, 0, 0), t=4.0),
    m.MissionPlan(algorithm="theta-pso", seed=1, cost=111.0, collision_free=True, centroid_path=[(0, 0, 0), (1, 1, 1)],
                  trajectories=[TRAJ], geofence=BOX, origin=(-33.87601, 151.191182, 0.0), convergence=[3.0, 2.0]),
    m.ErrorReply(code="invalid", reason="bad"),
    META.intrinsics, META,
    m.Defect(area_px=10, bbox=(1, 2, 3, 4), centroid_px=(2.0, 3.0), contrast=0.4, pos=(1, 2, 3)),
    m.DefectReport(uav=1, capture_id=4, stamp_capture=1.7e9, stamp_report=1.7e9 + 0.05, method="it",
                   defects=[m.Defect(area_px=10, bbox=(1, 2, 3, 4), centroid_px=(2.0, 3.0), contrast=0.4)]),
    m.FrameEvidence(ssrc=0x534B0100, seq=65535, digest="0f" * 32),
    m.DefectReport(uav=1, capture_id=5, stamp_capture=1.7e9, stamp_report=1.7e9 + 0.05, method="it+",
                   frame=m.FrameEvidence(ssrc=0x534B0100, seq=7, digest="a1" * 32)),
    m.ClassCounters(samples=3, bytes=100),
    m.LinkStats(source="gateway/1", stamp=1.7e9, sessions={"peer": 3}, classes={"telemetry": m.ClassCounters(samples=1)}),
    m.Event(source="uav/1", stamp=1.7e9, kind="failsafe", level=m.Level.WARNING, data={"timeout_s": 5.0, "x": "y"}),
]


def test_every_message_type_is_covered():
    assert {type(s) for s in SAMPLES} == set(m.MESSAGE_TYPES.values())


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda s: s.TYPE)
def test_round_trip(msg):
    data = codec.encode(msg)
    back = codec.decode(data)
    assert back == msg
    assert codec.peek_type(data) == msg.TYPE


def test_envelope_is_version_type_body():
    version, tag, body = msgpack.unpackb(codec.encode(_state()))
    assert (version, tag) == (codec.SCHEMA_VERSION, "state")
    assert body["pos"] == [1.0, 2.0, 30.0]


def _raw(version=codec.SCHEMA_VERSION, tag="state", body=None):
    if body is None:
        body = msgpack.unpackb(codec.encode(_state()))[2]
    return msgpack.packb([version, tag, body])


def _kind(data, expect=None):
    with pytest.raises(codec.CodecError) as info:
        codec.decode(data, expect)
    return info.value.kind


def test_error_kinds():
    good = msgpack.unpackb(codec.encode(_state()))[2]
    assert _kind(b"\xc1garbage") == "bad-bytes"
    assert _kind(b"") == "bad-bytes"
    assert _kind(msgpack.packb({"a": 1})) == "bad-bytes"
    assert _kind(_raw(version=99)) == "unsupported-version"
    assert _kind(_raw(tag="teleport")) == "unknown-type"
    assert _kind(_raw(body=[1, 2])) == "invalid"
    assert _kind(_raw(body={**good, "pos": [float("nan"), 0, 0]})) == "invalid"
    assert _kind(_raw(body={**good, "pos": [math.inf, 0, 0]})) == "invalid"
    assert _kind(_raw(body={**good, "uav": 0})) == "invalid"
    assert _kind(_raw(body={**good, "battery": 1.5})) == "invalid"
    assert _kind(_raw(body={**good, "pos": [1e9, 0, 0]})) == "invalid"
    assert _kind(_raw(body={**good, "surprise": 1})) == "invalid"
    assert _kind(_raw(body={k: v for k, v in good.items() if k != "seq"})) == "invalid"
    assert _kind(b"\x00" * (codec.MAX_MESSAGE_BYTES + 1)) == "oversize"
    assert _kind(codec.encode(_state()), m.CommandAck) == "wrong-type"
    assert _kind("not bytes") == "bad-bytes"  # type: ignore[arg-type]


def test_trajectory_time_must_increase():
    wps = [m.Waypoint(t=1, pos=(0, 0, 1)), m.Waypoint(t=1, pos=(0, 0, 2))]
    body = {"uav": 1, "waypoints": [w.model_dump(mode="json") for w in wps]}
    assert _kind(_raw(tag="trajectory", body=body)) == "invalid"


def test_encode_refuses_non_messages():
    with pytest.raises(TypeError):
        codec.encode({"uav": 1})  # type: ignore[arg-type]


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=512))
def test_random_bytes_give_codec_error_or_message(data):
    try:
        msg = codec.decode(data)
    except codec.CodecError as exc:
        assert exc.kind in codec.CodecError.KINDS
    else:
        assert isinstance(msg, m.Message)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1) | st.floats(allow_nan=True) | st.text(max_size=20)
    | st.binary(max_size=10),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=5),
    max_leaves=30,
)


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(st.sampled_from(sorted(m.MESSAGE_TYPES)), st.dictionaries(st.text(max_size=10), json_values, max_size=8))
def test_random_bodies_give_codec_error_or_message(tag, body):
    try:
        msg = codec.decode(msgpack.packb([codec.SCHEMA_VERSION, tag, body], use_bin_type=True))
    except codec.CodecError as exc:
        assert exc.kind in codec.CodecError.KINDS
    else:
        assert msg.TYPE == tag


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.sampled_from(SAMPLES), st.data())
def test_mutated_valid_messages_never_raise_anything_else(msg, data):
    raw = bytearray(codec.encode(msg))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    try:
        codec.decode(bytes(raw))
    except codec.CodecError:
        pass
