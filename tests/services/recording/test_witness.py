"""services.recording.witness: the capture frames the ground station holds, and what a report's evidence names."""

import hashlib

from protocol.imagery import pack_image
from protocol.messages import FrameEvidence, ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from services.recording.witness import FrameWitness, Seen

KEY = "skynet/t/uav/{u}/camera"
JPEG = b"\xff\xd8 not really a jpeg, but bytes \xff\xd9"
DIGEST = hashlib.sha256(JPEG).hexdigest()


def _frame(uav: int, capture: int, camera: int = 0, image: bytes = JPEG, seq: int = 5, meta_uav: int | None = None
           ) -> bytes:
    meta = ImageMeta(uav=meta_uav or uav, capture_id=capture, t=0.0, stamp=1.0, cam_pos=(0, 0, 0),
                     cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                     intrinsics=Intrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0))
    return pack_image(RtpSender(ssrc_for(uav, camera), initial_seq=seq), meta, image, 1.0)


def _ev(uav: int, seq: int = 5, digest: str = DIGEST) -> FrameEvidence:
    return FrameEvidence(ssrc=ssrc_for(uav), seq=seq, digest=digest)


def test_a_report_counts_only_on_the_frame_received_as_it_names_it():
    w = FrameWitness()
    assert w.add_sample(KEY.format(u=2), _frame(2, capture=7))
    assert w.seen(_ev(2), 7) is Seen.HELD
    assert w.seen(_ev(2, seq=6), 7) is Seen.NOT_RECEIVED  # a sequence number the camera never sent
    assert w.seen(_ev(2, digest="00" * 32), 7) is Seen.DIFFERENT  # other image bytes
    assert w.seen(_ev(2), 8) is Seen.DIFFERENT  # the right frame cited for another capture
    assert w.seen(_ev(1), 7) is Seen.NOT_RECEIVED  # another UAV's camera sent nothing


def test_frames_a_node_may_not_send_are_not_witnessed():
    w = FrameWitness()
    assert not w.add_sample(KEY.format(u=1), _frame(2, 7))  # uav2's SSRC on uav1's key
    assert not w.add_sample(KEY.format(u=2), _frame(2, 7, meta_uav=1))  # metadata naming another UAV
    assert not w.add_sample(KEY.format(u=2), _frame(2, 7, camera=1))  # a preview frame
    assert not w.add_sample(KEY.format(u=2), _frame(2, 7, image=b""))  # an announce (no image)
    assert not w.add_sample(KEY.format(u=2), b"garbage")
    assert not w.add_sample("not/a/fleet/key", _frame(2, 7))
    assert len(w) == 0 and w.seen(_ev(2), 7) is Seen.NOT_RECEIVED


def test_one_cameras_flood_cannot_crowd_out_another_cameras_frames():
    """A UAV may send what it likes on its own camera key: beyond its camera's bound its frames are counted, not
    kept, and another camera's frames are still witnessed."""
    w = FrameWitness(max_per_camera=3)
    for seq in range(5):
        w.add(ssrc_for(2), seq, "ab" * 32, seq)
    assert not w.add(ssrc_for(2), 0, "ab" * 32, 0)  # held already: neither kept again nor counted
    assert len(w) == 3 and w.not_kept == {ssrc_for(2): 2}
    assert w.seen(FrameEvidence(ssrc=ssrc_for(2), seq=4, digest="ab" * 32), 4) is Seen.NOT_RECEIVED
    assert w.add_sample(KEY.format(u=1), _frame(1, capture=3))
    assert w.seen(_ev(1), 3) is Seen.HELD
