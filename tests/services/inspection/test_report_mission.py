"""The inspector's report as ``skynet mission`` writes it (secure default, recorded, three UAVs): findings
first, report.html, crack geometry, the measurements against the wall's truth within the stated
tolerances, and the terminal's last line naming the defect count and the deliverable; on the nominal
mission and on the real-size scenario one flag away."""

from __future__ import annotations

import json
import re

import pytest

from services.inspection.mission import HEADING
from tests.conftest import fly_mission
from tests.services.inspection.test_real_cracks import REAL_TOLERANCE
from tests.services.inspection.test_report_views import NOMINAL_TOLERANCE

pytestmark = pytest.mark.mission

#: a flown mission's tolerance: the planned shots' (test_report_views.py) but for the worst length. A crack's tip
#: narrower than the blur reads shallower than half the crack's depth and is not measured (docs/report.md): the
#: nominal wall's 1 m crack reads 6 % short at the planned shots, and a flight on a loaded machine (captures fired
#: elsewhere along the path: other views, other seams) has made that 11.6 % once in a CI run
FLOWN_TOLERANCE = {**NOMINAL_TOLERANCE, "length_error_worst": 0.15}


def last_line(run) -> str:
    lines = [x for x in (run.proc.stderr + run.proc.stdout).splitlines() if x.strip()]
    ours = [x for x in lines if "inspection: " in x]
    assert ours, run.failure()
    return ours[-1]


def acc_rows(out) -> list[tuple[float, int, float]]:
    doc = json.loads((out / "inspection" / "accuracy.json").read_text())
    return [(round(r["length_error"], 3), r["truth"]["id"], round(r["truth"]["length_m"], 2))
            for r in doc["rows"] if r["length_error"] is not None]


def check_report(run, tolerance: dict[str, float]) -> dict:
    assert run.proc.returncode == 0, run.failure()
    out = run.out
    doc = json.loads((out / "inspection" / "defects.json").read_text())
    n = len(doc["defects"])
    line = last_line(run)
    # the terminal's last line: the count by class and the page to send on
    assert re.search(rf"inspection: {n} defects \(\d+ wide, \d+ moderate, \d+ insignificant\): \S+report\.html$", line), line
    assert run.proc.stderr.rstrip().endswith(line.rstrip())  # the mission's log (Zenoh's own log lines go to stdout)
    md = (out / "report.md").read_text()
    assert md.index("Outcome") < md.index(HEADING) < md.index("## Experimental setup")
    assert (out / "report.html").is_file() and (out / "inspection" / "tiles" / "0" / "0_0.jpg").is_file()
    gj = json.loads((out / "inspection" / "defects.geojson").read_text())
    assert {f["geometry"]["type"] for f in gj["features"]} == {"LineString", "Polygon"}
    # the default secure mode's links are TLS streams, and the link table says so (it said UDP)
    assert "best-effort class on TLS" in md and "| command | TLS: reliable, block |" in md
    # every capture the findings cite opens, in report.md and in report.html
    links = re.findall(r"\]\(([^)]+\.jpg)\)", md) + re.findall(r"href='([^']+\.jpg)'", (out / "report.html").read_text())
    assert links and all((out / link).is_file() for link in links), [x for x in links if not (out / x).is_file()]
    # the captures counted are those on a frame the ground station logged itself, every one of them
    report = json.loads((out / "report.json").read_text())
    record = json.loads((out / "record.json").read_text())
    assert report["captures"]["checked"] and len(record["held_captures"]) >= report["captures"]["imaged"] > 0
    assert "on a frame the ground station received itself" in md
    assert all(row["not_received"] == 0 and row["different"] == 0 for row in record["imagery"].values())
    # the deliverable's cracks are IT+'s, each confirmed by the learned model, and none stands on no crack
    assert "Segmented with `it+`, each crack confirmed by `learned`" in md
    acc = json.loads((out / "inspection" / "accuracy.json").read_text())["summary"]
    worst = sorted(acc_rows(out), key=lambda r: -abs(r[0]))[:3]
    for k, tol in tolerance.items():
        assert acc[k] is not None and acc[k] <= tol, (k, acc[k], tol, "worst (error, truth id, length m):", worst)
    return acc


def unmatched_rows(out) -> list[dict]:
    """The deliverable's defects on no true crack, each with where and from which capture (a failure's evidence)."""
    ids = set(json.loads((out / "inspection" / "accuracy.json").read_text())["unmatched"])
    keys = ("id", "u_m", "v_m", "length_m", "width_max_mm", "uav", "capture_id", "seen_by")
    doc = json.loads((out / "inspection" / "defects.json").read_text())
    return [{k: d.get(k) for k in keys} for d in doc["defects"] if d["id"] in ids]


def test_nominal_mission_report_for_the_inspector(nominal_mission):
    acc = check_report(nominal_mission, FLOWN_TOLERANCE)
    assert acc["matched"] == acc["truth"] and acc["class_agreement"] == 1.0
    # the learned detector's bar for the mission's wall: precision >= .95 at recall 1.00 (the planned shots have
    # none on no crack, test_report_views.py; flown on a loaded machine, one of 20 has stood on no crack once)
    defects = len(json.loads((nominal_mission.out / "inspection" / "defects.json").read_text())["defects"])
    precision = (defects - acc["unmatched_defects"]) / defects
    assert precision >= 0.95, (acc["unmatched_defects"], defects, unmatched_rows(nominal_mission.out))


def test_real_size_cracks_through_the_launcher(tmp_path):
    # at the default speed: the 0.8 m panel sits in one footprint with 10 cm to spare, the tracking error at
    # under a metre's stand-off decides how much of it the one capture covers
    run = fly_mission(tmp_path / "report", "--scenario", "real-cracks", timeout=500)  # one flag: full frames
    acc = check_report(run, REAL_TOLERANCE)
    # IT+ alone put ~48 defects on the wall's texture; confirmed, a flown mission left 1 (the flight's own views)
    assert acc["unmatched_defects"] <= 3, (acc, unmatched_rows(run.out))
    doc = json.loads((run.out / "inspection" / "defects.json").read_text())
    sizeable = acc["truth"] - acc["below_pixel"]
    # the cracks wider than one pixel on the covered part are found and sized within tolerance
    assert acc["sized"] >= 1 and acc["sized"] >= round(sizeable * doc["coverage"]) - 1, (acc, doc["coverage"])
    assert acc["below_pixel"] >= 1 and acc["gsd_mm"] < 0.3
    md = (run.out / "report.md").read_text()
    assert "narrower than one pixel at the flown" in md
