"""The inspector's report: crack geometry for a GIS (GeoJSON against its schema and read back by shapely,
KML read back by lxml), the table's order and provenance, the measurements against the wall's truth,
the findings first in report.md, and report.html looked at in headless Chromium.

Built once (module fixture) from the captures of the nominal monorail wall rendered at the planned
shots (the frames a mission's edges send), with a geodetic origin 120 m above the ellipsoid."""

from __future__ import annotations

import json
import math
import shutil
import time

import numpy as np
import pytest

from edge.geometry.waypoint_mission import geodetic_to_enu
from edge.world.wall import synthetic_surface
from protocol.scenario import load_scenario
from services.detector.frames import save_frame
from services.detector.measure import centre_line, outline
from services.inspection.accuracy import compare, truth_cracks
from services.inspection.captures import decode, synthetic_captures
from services.inspection.deliverable import ALIGN_M, SEVERITY_ORDER, inspect_frames, segment, write_deliverable
from services.inspection.mission import HEADING, append_deliverable, deliverable_line
from services.inspection.mosaic import Plane, PosedFrame, moved_camera
from services.recording.record import GroundTruthDefect, MissionRecord

ORIGIN = (-33.87601, 151.191182, 120.0)

#: a JSON Schema of the RFC 7946 objects the deliverable writes (FeatureCollection of Features whose
#: geometry is a Point, LineString or Polygon of 2- or 3-number positions; linear rings closed, >= 4)
POSITION = {"type": "array", "minItems": 2, "maxItems": 3, "items": {"type": "number"}}
GEOJSON_SCHEMA = {
    "type": "object", "required": ["type", "features"],
    "properties": {
        "type": {"const": "FeatureCollection"},
        "features": {"type": "array", "items": {
            "type": "object", "required": ["type", "geometry", "properties"],
            "properties": {
                "type": {"const": "Feature"}, "id": {"type": ["string", "number"]},
                "properties": {"type": ["object", "null"]},
                "geometry": {"oneOf": [
                    {"type": "object", "required": ["type", "coordinates"],
                     "properties": {"type": {"const": "Point"}, "coordinates": POSITION}},
                    {"type": "object", "required": ["type", "coordinates"],
                     "properties": {"type": {"const": "LineString"},
                                    "coordinates": {"type": "array", "minItems": 2, "items": POSITION}}},
                    {"type": "object", "required": ["type", "coordinates"],
                     "properties": {"type": {"const": "Polygon"}, "coordinates": {
                         "type": "array", "minItems": 1,
                         "items": {"type": "array", "minItems": 4, "items": POSITION}}}},
                ]},
            }}},
    },
}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    sc = load_scenario()
    surf = synthetic_surface(sc)
    caps = synthetic_captures(sc, surf)
    frames = [PosedFrame(c.meta.model_copy(update={"t": 10.0 + c.meta.capture_id, "stamp": 1.7e9}), decode(c))
              for c in caps]
    res = inspect_frames(frames, Plane.from_corners(surf.corners), ORIGIN)
    out = tmp_path_factory.mktemp("deliverable")
    write_deliverable(res, out)
    return sc, surf, caps, res, out


def test_centre_line_and_outline_of_a_straight_crack():
    shapely = pytest.importorskip("shapely.geometry")
    m = np.zeros((40, 120), np.uint8)
    m[18:21, 10:110] = 255  # 100 px long, 3 px wide
    line = centre_line(m)
    length = float(np.sum(np.hypot(*np.diff(line, axis=0).T)))
    assert 95 <= length <= 100 and np.allclose(line[:, 1], 19, atol=1.0)  # thinning may hook the last pixel
    ring = outline(m)
    poly = shapely.Polygon(ring)
    assert poly.is_valid and np.allclose(ring[0], ring[-1])
    assert 0.8 * 300 <= poly.area <= 1.2 * 300  # the pixels' area
    # pixels joined only by a corner (an 8-connected diagonal crack) still make one simple ring
    d = np.zeros((30, 30), np.uint8)
    for i in range(25):
        d[2 + i, 2 + i] = 255
    assert shapely.Polygon(outline(d)).is_valid


def test_table_sorted_by_severity_then_length_with_the_capture_behind_each(built):
    sc, surf, caps, res, out = built
    keys = [(SEVERITY_ORDER.index(d.severity), -d.length_m) for d in res.defects]
    assert keys == sorted(keys) and [d.id for d in res.defects] == list(range(1, len(res.defects) + 1))
    names = {f"uav{c.meta.uav}-{c.meta.capture_id:05d}": c.meta for c in caps}
    for d in res.defects:
        assert d.uav is not None and d.seen_by and set(d.seen_by) <= set(names)
        best = names[d.seen_by[0]]  # the frame giving most of its pixels is the one the row names
        assert (best.uav, best.capture_id, d.t) == (d.uav, d.capture_id, 10.0 + best.capture_id)
    md = (out / "defects.md").read_text()
    assert md.startswith("Sorted by severity class (worst first), then length (longest first).")
    # the wall runs north-south: the latitude column changes from row to row, the longitude does not
    lats = {round(d.lla[0], 7) for d in res.defects}
    assert len(lats) > len(res.defects) // 2


def test_geojson_against_its_schema_and_read_back_by_shapely(built):
    jsonschema = pytest.importorskip("jsonschema")
    shapely = pytest.importorskip("shapely.geometry")
    sc, surf, caps, res, out = built
    doc = json.loads((out / "defects.geojson").read_text())
    jsonschema.validate(doc, GEOJSON_SCHEMA)
    plane = res.mosaic.plane
    by_id: dict[int, dict[str, object]] = {}
    unbranched = 0
    for f in doc["features"]:
        g = shapely.shape(f["geometry"])
        assert g.has_z and g.is_valid or g.geom_type == "Polygon"  # a vertical wall's polygon is flat in 2-D
        by_id.setdefault(f["properties"]["id"], {})[f["properties"]["geometry"]] = f
        for k in ("length_m", "width_max_mm", "width_mean_mm", "severity", "uav", "capture_id", "t", "crop"):
            assert k in f["properties"]
    assert set(by_id) == {d.id for d in res.defects}
    for d in res.defects:
        line = by_id[d.id]["centre line"]["geometry"]["coordinates"]
        ring = by_id[d.id]["outline"]["geometry"]["coordinates"][0]
        # back to the wall's (u, v): the outline is a valid polygon there, around the centre line
        lla = np.array([[p[1], p[0], p[2]] for p in ring])
        enu = geodetic_to_enu(lla, ORIGIN)
        assert np.abs((enu - plane.origin) @ plane.normal).max() < 0.01  # on the wall
        poly = shapely.Polygon(plane.to_uv(enu))
        assert poly.is_valid and poly.exterior.is_ccw
        cl = shapely.LineString(plane.to_uv(geodetic_to_enu(np.array([[p[1], p[0], p[2]] for p in line]), ORIGIN)))
        assert poly.buffer(2 * res.mosaic.m_per_px).contains(cl)
        # the line is the skeleton's longest path; the length counts the branches too
        assert 0.3 * d.length_m <= cl.length <= 1.05 * d.length_m + 0.05
        unbranched += abs(cl.length - d.length_m) <= 0.1 * d.length_m + 0.05
        # the altitude is the origin's plus the height on the wall
        assert all(abs(p[2] - (ORIGIN[2] + e[2])) < 0.05 for p, e in zip(ring, enu))
    assert unbranched >= len(res.defects) // 2


def test_kml_read_back_by_lxml(built):
    etree = pytest.importorskip("lxml.etree")
    sc, surf, caps, res, out = built
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = etree.parse(str(out / "defects.kml")).getroot()
    marks = root.findall(".//k:Placemark", ns)
    assert len(marks) == len(res.defects)
    for pm, d in zip(marks, res.defects):
        assert pm.findtext("k:name", namespaces=ns) == f"defect {d.id}"
        line = pm.findtext(".//k:LineString/k:coordinates", namespaces=ns).split()
        ring = pm.findtext(".//k:Polygon//k:coordinates", namespaces=ns).split()
        assert len(line) == len(d.centre_line_lla) and ring[0] == ring[-1]
        lon, lat, alt = map(float, ring[0].split(","))
        assert (lat, lon) == pytest.approx(d.outline_lla[0][:2], abs=1e-8) and alt > ORIGIN[2]
        assert pm.findtext(".//k:Polygon/k:altitudeMode", namespaces=ns) == "absolute"
        data = {e.get("name"): e.findtext("k:value", namespaces=ns) for e in pm.findall(".//k:Data", ns)}
        assert data["severity"] == d.severity and float(data["length_m"]) == pytest.approx(d.length_m, abs=1e-3)


def test_kml_read_back_by_a_kml_reader(built):
    """fastkml (a KML 2.2 reader) finds one placemark per defect holding its point, centre line and outline,
    at absolute altitudes above the scenario origin's."""
    kml = pytest.importorskip("fastkml.kml")
    sc, surf, caps, res, out = built
    doc = kml.KML.from_string((out / "defects.kml").read_bytes())
    marks = [f for d in doc.features for f in d.features]
    assert [m.name for m in marks] == [f"defect {d.id}" for d in res.defects]
    for m, d in zip(marks, res.defects):
        kinds = {type(g).__name__: g for g in m.geometry.geoms}
        assert set(kinds) == {"Point", "LineString", "Polygon"}, kinds
        line, ring = list(kinds["LineString"].coords), list(kinds["Polygon"].exterior.coords)
        assert len(line) == len(d.centre_line_lla) and ring[0] == ring[-1]
        assert all(alt > ORIGIN[2] for _, _, alt in line + ring)


# the nominal wall's cracks are 3.5-8 cm wide at 1 cm texture pixels, imaged at 7.8 mm/px: the
# stated tolerances of the measurement against truth
# (widths: within 3 mosaic pixels at worst)
NOMINAL_TOLERANCE = {"length_error_median": 0.03, "length_error_worst": 0.10, "width_mean_error_mm_median": 2.5,
                     "width_mean_error_mm_worst": 6.0, "width_max_error_mm_median": 6.0,
                     "width_max_error_mm_worst": 24.0}


@pytest.mark.slow
def test_frames_whose_poses_are_off_by_centimetres_give_the_report_of_exact_ones(built):
    # each frame's camera 5 cm off (per axis along the wall, seeded): placed by the poses alone, cracks split at the
    # seams and some defects stand on no crack (bench/pose_tolerance.py); aligned to each other, as exact poses
    sc, surf, caps, res, out = built
    plane = Plane.from_corners(surf.corners)
    rng = np.random.default_rng(2)
    off = [PosedFrame(moved_camera(f.meta, plane, rng.normal(0, 0.05), rng.normal(0, 0.05)), f.grey, f.mask)
           for f in segment([PosedFrame(c.meta, decode(c)) for c in caps])]
    truth, labels = truth_cracks(surf.mask, 1 / surf.px_per_m)

    def scored(align_m: float) -> tuple[dict, int]:
        r = inspect_frames(off, plane, align_m=align_m)
        return compare(r.defects, truth, labels, 1 / surf.px_per_m).summary, len(r.defects)

    (aligned, n_aligned), (placed, n_placed) = scored(ALIGN_M), scored(0.0)
    assert aligned["matched"] == len(truth) and aligned["unmatched_defects"] == 0 and n_aligned == len(truth)
    assert n_placed > len(truth) or placed["unmatched_defects"] > 0, (placed, n_placed)


def test_measurements_against_the_truth_of_the_nominal_wall(built):
    sc, surf, caps, res, out = built
    truth, labels = truth_cracks(surf.mask, 1 / surf.px_per_m)
    assert len(truth) == len(surf.defects())
    acc = compare(res.defects, truth, labels, 1 / surf.px_per_m)
    s = acc.summary
    assert s["matched"] == s["truth"] and s["unmatched_defects"] == 0
    for k, tol in NOMINAL_TOLERANCE.items():
        assert s[k] <= tol, (k, s[k], tol)
    assert s["class_agreement"] == 1.0


def test_findings_first_in_report_md_and_html_in_chromium(built, tmp_path):
    sc, surf, caps, res, _ = built
    report = tmp_path / "report"
    for c in caps:
        save_frame(report / "frames", c.meta, c.jpeg)
    (report / "report.md").write_text("# Mission report\n\nOutcome: **success**.\n\n## Experimental setup\n\nx\n")
    gt = [GroundTruthDefect(id=d.id, pos=d.centroid_world, uv=d.centroid_uv, bbox_uv=d.bbox_uv, area_m2=d.area_m2)
          for d in surf.defects()]
    record = MissionRecord(fleet="f", scenario=sc, speed=1.0, started=time.time(), ground_truth=gt,
                           surface_corners=[tuple(map(float, p)) for p in surf.corners])
    files: list[str] = []
    written = append_deliverable(record, report, files)
    assert "report.html" in written and "inspection/accuracy.json" in written
    md = (report / "report.md").read_text()
    # findings first: right after the outcome, before the mission's own sections
    assert md.index(HEADING) < md.index("## Experimental setup") and md.index("Outcome") < md.index(HEADING)
    assert "### Measurements against the ground truth" in md and "![overview" in md
    assert "### The worst 5 cracks" in md and "](frames/uav" in md
    line = deliverable_line(report)
    assert line is not None and line.startswith(f"{len(res.defects)} defects (") and line.endswith("report.html")

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium drives the browser")
    if not (chromium and driver_path):
        pytest.skip("needs Debian's chromium and chromium-driver (.ci/run installs them)")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    opts = Options()
    opts.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1280,1600",
              "--allow-file-access-from-files"):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=opts)
    try:
        driver.get((report / "report.html").as_uri())
        body = driver.find_element("tag name", "body").text
        assert f"{len(res.defects)} defects" in body and "Measurements against the ground truth" in body
        assert body.index("Findings") < body.index("The wall") < body.index("Defects (sorted by")
        top = tmp_path / "report-html-top.png"
        driver.save_screenshot(str(top))  # the findings, as the page opens
        print(f"screenshot of report.html (top): {top}")
        # every image of the page loads from the folder (offline, no network)
        WebDriverWait(driver, 30).until(lambda d: d.execute_script(
            "return [...document.images].every(i => i.complete)"))
        broken = driver.execute_script("return [...document.images].filter(i => !i.naturalWidth).map(i => i.src)")
        assert broken == [], broken
        # the zoomable wall: zooming in on defect 1 loads full-resolution tiles
        d1 = res.defects[0]
        level = driver.execute_script(f"return window.skynetZoom(64, {d1.u_m}, {d1.v_m})")
        zmax = json.loads((report / "inspection" / "defects.json").read_text())["tiles"]["zmax"]
        assert level == zmax
        WebDriverWait(driver, 30).until(lambda d: d.execute_script(
            f"return [...document.querySelectorAll('#zoom img.tile')].filter(i => i.style.display !== 'none'"
            f" && i.src.indexOf('/tiles/{zmax}/') >= 0 && i.complete && i.naturalWidth > 0).length > 0"))
        driver.execute_script("document.getElementById('zoom').scrollIntoView()")
        shot = tmp_path / "report-html.png"
        driver.save_screenshot(str(shot))
        print(f"screenshot of report.html: {shot}")
        assert shot.stat().st_size > 10_000
    finally:
        driver.quit()
    assert math.isfinite(res.mosaic.m_per_px)
