"""services.recording.witness: the capture frames the ground station holds, and what a report's evidence names."""

import hashlib

from protocol.imagery import pack_image
from protocol.messages import DefectReport, FrameEvidence, ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from services.recording.witness import FrameWitness, Seen

KEY = "skynet/t/uav/{u}/camera"
JPEG = b"\xff\xd8 not really a jpeg, but bytes \xff\xd9"


def _frame(uav: int, capture: int, camera: int = 0, image: bytes = JPEG, seq: int = 5) -> bytes:
    meta = ImageMeta(uav=uav, capture_id=capture, t=0.0, stamp=1.0, cam_pos=(0, 0, 0),
                     cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                     intrinsics=Intrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0))
    return pack_image(RtpSender(ssrc_for(uav, camera), initial_seq=seq), meta, image, 1.0)


def _report(uav: int, capture: int, seq: int = 5, digest: str | None = None, ssrc: int | None = None) -> DefectReport:
    ev = FrameEvidence(ssrc=ssrc_for(uav) if ssrc is None else ssrc, seq=seq,
                       digest=digest or hashlib.sha256(JPEG).hexdigest())
    return DefectReport(uav=uav, capture_id=capture, stamp_capture=1.0, stamp_report=2.0, method="it+", frame=ev)


def test_a_report_counts_only_on_the_frame_received_as_it_names_it():
    w = FrameWitness()
    assert w.add_sample(KEY.format(u=2), _frame(2, capture=7))
    assert w.seen(_report(2, 7)) is Seen.HELD
    assert w.seen(_report(2, 7, seq=6)) is Seen.NOT_RECEIVED  # a sequence number the camera never sent
    assert w.seen(_report(2, 7, digest="00" * 32)) is Seen.DIFFERENT  # other image bytes
    assert w.seen(_report(2, 8)) is Seen.DIFFERENT  # the right frame cited for another capture
    assert w.seen(_report(1, 7)) is Seen.NOT_RECEIVED  # another UAV's camera sent nothing
    assert w.seen(_report(2, 7, ssrc=ssrc_for(2, 1))) is Seen.NO_EVIDENCE  # its preview camera
    assert w.seen(_report(2, 7).model_copy(update={"frame": None})) is Seen.NO_EVIDENCE


def test_frames_a_node_may_not_send_are_not_witnessed():
    w = FrameWitness()
    assert not w.add_sample(KEY.format(u=1), _frame(2, 7))  # uav2's SSRC on uav1's key
    assert not w.add_sample(KEY.format(u=2), _frame(2, 7, camera=1))  # a preview frame
    assert not w.add_sample(KEY.format(u=2), b"\x80\x60" + b"\x00" * 10)  # an announce (no image)
    assert not w.add_sample(KEY.format(u=2), b"garbage")
    assert not w.add_sample("not/a/fleet/key", _frame(2, 7))
    assert len(w) == 0 and w.seen(_report(2, 7)) is Seen.NOT_RECEIVED


def test_the_witness_is_bounded_and_counts_what_it_did_not_keep():
    w = FrameWitness(max_frames=3)
    for seq in range(5):
        w.add(ssrc_for(1), seq, "ab" * 32, seq)
    w.add(ssrc_for(1), 0, "ab" * 32, 0)  # already held: not counted again
    assert len(w) == 3 and w.not_kept == 2
    assert w.seen(_report(1, 4, seq=4, digest="ab" * 32)) is Seen.NOT_RECEIVED
