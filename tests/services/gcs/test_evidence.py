"""services.gcs.evidence: captures count only on evidenced, corroborated reports."""

import time

from protocol.messages import DefectReport, FrameEvidence, LinkStats, Mode, VehicleState
from protocol.rtp import ssrc_for
from services.gcs.evidence import (
    corroboration_failures,
    detector_totals,
    has_evidence,
    held_captures,
    ledger,
    no_surface_reasons,
)
from services.recording.witness import FrameWitness

D = "ab" * 32


def _report(uav, cid, ssrc=None, ok=True):
    frame = None if ssrc is False else FrameEvidence(ssrc=ssrc_for(uav) if ssrc is None else ssrc, seq=cid, digest=D)
    return DefectReport(uav=uav, capture_id=cid, stamp_capture=1.0, stamp_report=2.0, method="it+", ok=ok, frame=frame)


def _stats(uptime, source="detector", **metrics):
    return LinkStats(source=source, stamp=time.time(), uptime_s=uptime,
                     metrics={k.replace("_", "."): v for k, v in metrics.items()})


def _state(uav, captures):
    return VehicleState(uav=uav, seq=0, t=0, stamp=time.time(), pos=(0, 0, 0), vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=Mode.MISSION, captures=captures)


def test_only_reports_naming_a_frame_of_the_uavs_capture_camera_count():
    assert has_evidence(_report(1, 3))
    assert not has_evidence(_report(1, 3, ssrc=False))  # no evidence
    assert not has_evidence(_report(1, 3, ssrc=ssrc_for(2)))  # another UAV's camera
    assert not has_evidence(_report(1, 3, ssrc=ssrc_for(1, 1)))  # its preview camera
    assert not has_evidence(_report(1, 3, ok=False))


def test_forged_reports_without_a_detector_are_not_corroborated():
    """The issue's attack: the detector is dead, forged ok reports for every capture (with made-up evidence)."""
    book = ledger([1, 2], [_state(1, 13), _state(2, 13)], [_report(1, c) for c in range(13)], stats=[])
    assert book[1] == {"sent": 13, "received": None, "analysed": None, "reported": 13, "unevidenced": 0,
                       "not_received": None, "different": None, "no_surface": None}
    fails = corroboration_failures(book)
    assert len(fails) == 1 and "UAV 1" in fails[0] and "no statistics were heard from the detector" in fails[0]


def test_more_reports_than_frames_analysed_fail_and_honest_ones_pass():
    stats = [_stats(1, uav1_cam0_received=5, uav1_cam0_analysed=5)]
    book = ledger([1], [_state(1, 13)], [_report(1, c) for c in range(13)], stats)
    assert "analysed only 5" in corroboration_failures(book)[0]
    book = ledger([1], [_state(1, 13)], [_report(1, c) for c in range(5)] + [_report(1, 9, ssrc=False)], stats)
    fails = corroboration_failures(book)
    assert len(fails) == 1 and "name no frame" in fails[0]
    assert book[1]["reported"] == 5 and book[1]["unevidenced"] == 1


def test_detector_restart_adds_up_its_runs():
    stats = [_stats(1, uav1_cam0_received=3, uav1_cam0_analysed=3), _stats(9, uav1_cam0_received=8,
             uav1_cam0_analysed=8), _stats(1, uav1_cam0_received=2, uav1_cam0_analysed=2),
             _stats(2, uav1_cam0_received=4, uav1_cam0_analysed=4)]
    assert detector_totals(stats, [1, 2]) == {1: {"received": 12, "analysed": 12}, 2: {"received": 0, "analysed": 0}}
    assert detector_totals([], [1]) is None


def test_partitioned_detectors_sum_over_instances_each_with_its_own_runs():
    """two instances (detector-0 and detector-1, --partition K/2) interleave their statistics; a
    restart of one does not start a new run of the other, and the totals add both."""
    stats = [_stats(1, "detector-0", uav2_cam0_received=2, uav2_cam0_analysed=2),
             _stats(1, "detector-1", uav1_cam0_received=3, uav1_cam0_analysed=3),
             _stats(5, "detector-0", uav2_cam0_received=4, uav2_cam0_analysed=4),
             _stats(6, "detector-1", uav1_cam0_received=5, uav1_cam0_analysed=5),
             _stats(2, "detector-0", uav2_cam0_received=1, uav2_cam0_analysed=1),  # detector-0 restarted
             _stats(7, "detector-1", uav1_cam0_received=6, uav1_cam0_analysed=6)]
    assert detector_totals(stats, [1, 2]) == {1: {"received": 6, "analysed": 6}, 2: {"received": 5, "analysed": 5}}
    book = ledger([1, 2], [_state(1, 6), _state(2, 5)], [_report(1, c) for c in range(6)]
                  + [_report(2, c) for c in range(5)], stats)
    assert corroboration_failures(book) == []
    assert book[2]["analysed"] == 5 and book[1]["analysed"] == 6


def test_captures_count_only_on_frames_the_ground_station_received_as_named():
    """A detector's statistics corroborate its reports, but the reports name frames the ground station never
    received (made-up sequence numbers) or other bytes than it received: not counted, and said why."""
    w = FrameWitness()
    for cid in range(3):
        w.add(ssrc_for(1), cid, D, cid)  # frames 0..2 received; the report cites them by sequence = capture id
    reports = [_report(1, c) for c in range(6)] + [_report(1, 2).model_copy(
        update={"frame": FrameEvidence(ssrc=ssrc_for(1), seq=2, digest="cd" * 32)})]
    stats = [_stats(1, uav1_cam0_received=6, uav1_cam0_analysed=6)]
    book = ledger([1], [_state(1, 6)], reports, stats, witness=w)
    assert book[1]["reported"] == 3 and book[1]["not_received"] == 3 and book[1]["different"] == 0
    assert held_captures(reports, w) == {(1, 0), (1, 1), (1, 2)}
    fails = corroboration_failures(book)
    assert len(fails) == 1 and "3 capture(s) reported on a frame the ground station never received" in fails[0]
    forged = [_report(1, 0).model_copy(update={"frame": FrameEvidence(ssrc=ssrc_for(1), seq=0, digest="cd" * 32)})]
    book = ledger([1], [_state(1, 1)], forged, stats, witness=w)
    assert book[1]["reported"] == 0 and book[1]["different"] == 1
    assert "other than the one the ground station received" in corroboration_failures(book)[0]


def _capture(uav: int, cid: int, grey):
    """A capture frame as it travels (its camera key and payload) and the evidence a report names it by."""
    import hashlib

    import numpy as np

    from protocol import keys
    from protocol.imagecodec import encode_jpeg
    from protocol.imagery import pack_image
    from protocol.rtp import RtpSender
    from services.inspection.captures import capture_meta

    h, w = grey.shape
    meta = capture_meta(uav, cid, np.zeros(3), np.eye(3), (w, h), 500.0, 500.0, w / 2, h / 2, 5.0)
    jpeg = encode_jpeg(grey, 90)
    sender = RtpSender(ssrc_for(uav), initial_seq=cid)
    data = pack_image(sender, meta, jpeg, time.time())
    return keys.camera("test", uav), data, FrameEvidence(ssrc=ssrc_for(uav), seq=cid, digest=hashlib.sha256(jpeg).hexdigest())


def test_a_detectors_ok_on_a_frame_that_shows_no_surface_does_not_count():
    """The ground station looks at every capture it receives itself: a detector (buggy, or holding a stolen
    identity) that calls a black frame fine does not make its capture point imaged, and the verdict says why."""
    import numpy as np

    from edge.world.surface import textured_background
    from services.gcs.surface import surface_problem
    from services.recording.witness import Seen

    w = FrameWitness(surface_check=surface_problem)
    wall = textured_background((480, 640), np.random.default_rng(1), roughness=6.0)
    frames = [_capture(1, 0, wall), _capture(1, 1, np.zeros((480, 640), np.uint8))]
    for key, data, _ in frames:
        assert w.add_sample(key, data)
    reports = [_report(1, c).model_copy(update={"frame": ev}) for c, (_, _, ev) in enumerate(frames)]
    assert [w.seen(r.frame, r.capture_id) for r in reports] == [Seen.HELD, Seen.NO_SURFACE]
    assert w.no_surface_reason(reports[1].frame, 1) == "under-exposed, 100% of the frame black"
    assert held_captures(reports, w) == {(1, 0)}
    assert no_surface_reasons(reports, w) == {(1, 1): "reported ok, but its frame shows no surface: under-exposed, "
                                                      "100% of the frame black"}
    assert no_surface_reasons([r.model_copy(update={"uav": 2}) for r in reports], w) == {}  # not its camera
    book = ledger([1], [_state(1, 2)], reports, [_stats(1, uav1_cam0_received=2, uav1_cam0_analysed=2)], witness=w)
    assert book[1]["reported"] == 1 and book[1]["no_surface"] == 1
    assert any("1 capture(s) reported ok on a frame that shows no surface" in f for f in corroboration_failures(book))
    assert not w.add_sample(*frames[1][:2])  # the same frame again: kept already, not looked at again


def test_a_camera_past_its_bound_costs_no_look():
    """A UAV flooding its own camera key beyond the witness's bound is counted, not decoded frame by frame."""
    import numpy as np

    looked = []

    def check(meta, image):
        looked.append(meta.capture_id)
        return None

    w = FrameWitness(max_per_camera=2, surface_check=check)
    for cid in range(5):
        key, data, _ = _capture(1, cid, np.full((48, 64), 100 + cid, np.uint8))
        w.add_sample(key, data)
    assert looked == [0, 1] and len(w) == 2 and w.not_kept[ssrc_for(1)] == 3
