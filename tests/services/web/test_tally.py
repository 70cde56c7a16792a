"""The page's defect count is the report's (services.web.tally): the same captures folder counted by the
report's inspection section and by the page's tally (in its worker process) give one number, smaller
than the detections of the frames when overlapping frames see the same crack."""

from __future__ import annotations

import json
import time

from edge.world.wall import synthetic_surface
from protocol.scenario import load_scenario
from services.detector.detect import detect
from services.detector.frames import save_frame
from services.detector.pipeline import MIN_REPORT_AREA_PX
from services.inspection.captures import decode, synthetic_captures
from services.inspection.mission import append_deliverable
from services.recording.record import MissionRecord
from services.web.tally import DefectTally, captures_in, count_defects
from services.web.view import FleetView
from tests.conftest import wait_until


def test_the_page_counts_the_defects_of_a_captures_folder_as_the_report_does(tmp_path) -> None:
    sc = load_scenario()
    surf = synthetic_surface(sc, seed=7)
    caps = synthetic_captures(sc, surf)[:10]
    report = tmp_path / "report"
    frames = report / "frames"
    for c in caps[:6]:
        save_frame(frames, c.meta, c.jpeg)
    corners = [tuple(map(float, p)) for p in surf.corners]

    view = FleetView(sc, fleet="f")
    tally = DefectTally(view, frames, corners, interval_s=0.2).start()
    try:
        assert wait_until(lambda: view.snapshot()["inspection"] is not None, 120)
        assert view.snapshot()["inspection"]["frames"] == 6
        for c in caps[6:]:  # more captures arrive: counted again
            save_frame(frames, c.meta, c.jpeg)
        tally.poke()
        assert wait_until(lambda: view.snapshot()["inspection"]["frames"] == len(caps), 120), view.snapshot()["inspection"]
        page = view.snapshot()["defect_count"]
    finally:
        tally.stop()

    (report / "report.md").write_text("# report\n")
    append_deliverable(MissionRecord(fleet="f", scenario=sc, speed=1.0, started=time.time(), surface_corners=corners),
                       report)
    doc = json.loads((report / "inspection" / "defects.json").read_text())
    assert page == len(doc["defects"]) == count_defects(str(frames), corners)[0]
    assert f"{page} defects (" in (report / "report.md").read_text()
    # the per-frame detections count a crack once per frame that saw it: more than the defects
    detections = sum(len(detect(decode(c), "it+", min_defect_area=MIN_REPORT_AREA_PX).defects) for c in caps)
    assert page > 0 and detections > page
    assert captures_in(frames) == len(caps) and captures_in(tmp_path / "none") == 0


def test_the_counting_process_ends_with_its_parent(tmp_path) -> None:
    """A page killed with SIGKILL leaves no counting process behind."""
    import os
    import signal
    import subprocess
    import sys

    code = f"""
import sys, time
from protocol.scenario import load_scenario
from services.web.tally import DefectTally
from services.web.view import FleetView
t = DefectTally(FleetView(load_scenario()), {str(tmp_path)!r}, None).start()
t._pool.submit(int, 1).result()  # the worker is up
print(next(iter(t._pool._processes)), flush=True)
time.sleep(60)
"""
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              cwd=str(__import__("pathlib").Path(__file__).resolve().parents[3]))
    worker = int(parent.stdout.readline())
    os.kill(worker, 0)  # alive
    parent.send_signal(signal.SIGKILL)
    parent.wait(10)

    def gone() -> bool:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            return True
        try:  # a zombie not yet reaped by init counts as gone
            return open(f"/proc/{worker}/stat").read().split(") ")[1].startswith("Z")
        except OSError:
            return True
        return False

    assert wait_until(gone, 15)
