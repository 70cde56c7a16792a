"""The inspection deliverable: mosaic of the wall, defect table with sizes and crops, GeoJSON and KML.

Design notes: docs/report.md (services/inspection/deliverable.py).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict

from edge.geometry.waypoint_mission import enu_to_geodetic
from protocol import codec
from protocol.imagecodec import decode_image
from protocol.messages import ImageMeta
from protocol.textsafe import md_text, xml_text
from services.detector.detect import detect
from services.detector.learned import ModelError
from services.detector.measure import SEVERITY_LIMITS_M, centre_line, measure_mask, outline
from services.detector.pipeline import MIN_REPORT_AREA_PX
from services.recording.record import capture_name

from .mosaic import Mosaic, Plane, PosedFrame, build_mosaic, moved_camera, plane_from_frames, unusable_frames

log = logging.getLogger("skynet.inspection.deliverable")

__all__ = ["InspectionDefect", "Deliverable", "inspect_frames", "load_folder", "write_deliverable",
           "markdown_table", "geojson", "kml", "FRAME_SUFFIXES", "frames_from_log"]

FRAME_SUFFIXES = (".jpg", ".jpeg", ".png")
CROP_MARGIN_PX = 12
#: the frame size the detector's smallest reported component is set for (640 x 480)
REFERENCE_FRAME_PX = 640 * 480


#: order of the severity classes in the table, worst first (:mod:`services.detector.measure`)
SEVERITY_ORDER = ("wide", "moderate", "insignificant")
#: the table's sort key, as the report states it
SORT_KEY = "severity class (worst first), then length (longest first)"


class InspectionDefect(BaseModel):
    """One row of the defect table: where, how big, which class, and the capture behind it (``uav`` to ``stamp``:
    the frame that shows the defect's largest part on the mosaic; ``t`` mission time, ``stamp`` UTC seconds).
    ``seen_by`` names the frames behind it (``uav<N>-<capture>``, the files kept in ``frames/``): those that give its
    pixels on the mosaic (largest share first), then any other whose view holds its centroid. ``centre_line_uv``
    and ``outline_uv`` are its skeleton's longest path and its outline on the surface (u, v metres), the ``_lla``
    ones the same in WGS-84 (lat, lon deg, alt m) with an origin."""

    model_config = ConfigDict(extra="forbid")
    id: int
    u_m: float
    v_m: float
    enu: tuple[float, float, float]
    lla: tuple[float, float, float] | None = None
    length_m: float
    width_max_mm: float
    width_mean_mm: float
    area_m2: float
    severity: str
    resolved: bool
    bbox_px: tuple[int, int, int, int]
    crop: str = ""
    uav: int | None = None
    capture_id: int | None = None
    t: float | None = None
    stamp: float | None = None
    seen_by: list[str] = []
    centre_line_uv: list[tuple[float, float]] = []
    outline_uv: list[tuple[float, float]] = []
    centre_line_lla: list[tuple[float, float, float]] = []
    outline_lla: list[tuple[float, float, float]] = []


@dataclass
class Deliverable:
    mosaic: Mosaic
    defects: list[InspectionDefect]
    frames: int
    seconds: dict[str, float] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)
    origin: tuple[float, float, float] | None = None  # the geodetic origin of the ENU frame
    method: str = ""  # the detection method the frames were segmented with ("": masks given with the frames)
    confirm: str = ""  # the method whose mask confirmed each component of ``method``'s ("": none)
    unconfirmed: str = ""  # why the components were not confirmed as asked (the confirming model cannot run)
    #: the captures that show no surface (:func:`~services.detector.exposure.exposure_problem`), by name
    unusable: dict[str, str] = field(default_factory=dict)


#: the method whose mask must confirm each component of the deliverable's own (docs/report.md): IT+ measures a
#: crack's length and width closely but also answers to the texture of a wall seen at 0.25 mm/px; the learned
#: model does not, and cuts some cracks short
CONFIRM_METHOD = "learned"
#: how near (px) a confirming pixel must come to a component
CONFIRM_REACH_PX = 2
#: how far (m, along the surface) two frames may be moved against each other to fit (docs/report.md: poses off by
#: up to about 10 cm per axis give the report of exact ones, bench/pose_tolerance.py)
ALIGN_M = 0.6


def confirmed(mask: np.ndarray, by: np.ndarray, reach_px: int = CONFIRM_REACH_PX) -> np.ndarray:
    """The 8-connected components of ``mask`` that come within ``reach_px`` of a pixel of ``by``, whole (uint8
    0 / 255): the confirming mask decides which components stay, never their shape."""
    n, labels = cv2.connectedComponents((mask > 0).astype(np.uint8), connectivity=8)
    side = 2 * reach_px + 1
    near = cv2.dilate((by > 0).astype(np.uint8), np.ones((side, side), np.uint8)) > 0
    keep = np.zeros(n, bool)
    keep[np.unique(labels[near])] = True
    keep[0] = False
    return np.where(keep[labels], 255, 0).astype(np.uint8)


def segment(frames: Sequence[PosedFrame], method: str = "it+", confirm: str | None = CONFIRM_METHOD,
            unusable: Collection[int] | None = None) -> list[PosedFrame]:
    """The frames with their defect masks from the detector's ``method``, each component kept only where
    ``confirm``'s mask of the same frame touches it (None: all kept); a frame that shows no surface (``unusable``,
    by default :func:`~.mosaic.unusable_frames`) is not segmented (an empty mask): the mosaic leaves it out."""
    skip = unusable_frames(frames) if unusable is None else unusable
    out = []
    for i, f in enumerate(frames):
        if i in skip:
            out.append(PosedFrame(f.meta, f.grey, np.zeros(f.grey.shape, np.uint8)))
            continue
        mask = detect(f.grey, method, with_defects=False).mask
        if confirm:
            mask = confirmed(mask, detect(f.grey, confirm, with_defects=False).mask)
        out.append(PosedFrame(f.meta, f.grey, mask))
    return out


def frame_name(meta: ImageMeta) -> str:
    """A capture's name in ``frames/`` (:func:`save_frame`): ``uav<N>-<capture>``."""
    return capture_name(meta.uav, meta.capture_id)


def sees(meta: ImageMeta, point: Sequence[float]) -> bool:
    """Whether the frame of ``meta`` images the world ``point`` (pinhole ``K R^T (X - C)``, in front
    of the camera and inside the image)."""
    k = meta.intrinsics
    R = np.asarray(meta.cam_rot, float).reshape(3, 3)
    x = R.T @ (np.asarray(point, float) - np.asarray(meta.cam_pos, float))
    if x[2] <= 1e-9:
        return False
    c, r = k.fx * x[0] / x[2] + k.cx, k.fy * x[1] / x[2] + k.cy
    return bool(-0.5 <= c <= k.width - 0.5 and -0.5 <= r <= k.height - 0.5)


def severity_rank(severity: str) -> int:
    """Position of a class in :data:`SEVERITY_ORDER` (unknown classes last)."""
    return SEVERITY_ORDER.index(severity) if severity in SEVERITY_ORDER else len(SEVERITY_ORDER)


def inspect_frames(frames: Sequence[PosedFrame], plane: Plane | None = None, origin: Sequence[float] | None = None,
                   method: str = "it+", m_per_px: float | None = None, min_area_px: int | None = None,
                   confirm: str | None = CONFIRM_METHOD, align_m: float = ALIGN_M) -> Deliverable:
    """Segment, mosaic and measure (steps 1-3 of docs/report.md); the defects come sorted by
    :data:`SORT_KEY` and numbered in that order (defect 1 is the worst).

    ``min_area_px`` defaults to the detector's smallest reported component
    (:data:`services.detector.pipeline.MIN_REPORT_AREA_PX`, set for 640 x 480 frames) scaled by the
    frames' pixel count over that reference (docs/report.md). The frames are aligned to each other along the surface,
    two by up to ``align_m`` against each other (0: each placed by its pose alone; :func:`~.mosaic.build_mosaic`).
    """
    if not frames:
        raise ValueError("no frames")
    if min_area_px is None:
        px = float(np.median([f.grey.shape[0] * f.grey.shape[1] for f in frames]))
        min_area_px = int(round(MIN_REPORT_AREA_PX * max(1.0, px / REFERENCE_FRAME_PX)))
    t0 = time.perf_counter()
    segmented = any(f.mask is None for f in frames)
    unconfirmed = ""
    unusable = unusable_frames(frames)  # judged once, for the segmentation and the mosaic
    try:
        seg = segment(frames, method, confirm, unusable) if segmented else list(frames)
    except ModelError as exc:  # the confirming model cannot run: every component kept, and the findings say why
        log.warning("deliverable: components not confirmed by %s: %s", confirm, exc)
        unconfirmed, confirm = f"not confirmed by `{confirm}`: {exc}", None
        seg = segment(frames, method, None, unusable)
    t1 = time.perf_counter()
    pl = plane if plane is not None else plane_from_frames([f.meta for f in frames])
    mos = build_mosaic(seg, pl, m_per_px, align_m, unusable)
    t2 = time.perf_counter()
    _, labels, stats, _ = cv2.connectedComponentsWithStats((mos.mask > 0).astype(np.uint8), connectivity=8,
                                                          ltype=cv2.CV_32S)
    label_of = {tuple(int(v) for v in st[:4]): i for i, st in enumerate(stats) if i > 0}
    metas = [f.meta if d is None else moved_camera(f.meta, pl, *d)  # the cameras where the alignment put them
             for f, d in zip(frames, mos.shifts_m or [None] * len(frames))]
    rows = []
    for bbox, ctr, m in measure_mask(mos.mask, mos.m_per_px, min_area_px, mos.image):
        uv = mos.pixel_to_uv(np.array(ctr))
        enu = pl.to_world(uv)
        lla = None if origin is None else tuple(float(x) for x in enu_to_geodetic(enu, origin))
        d = m.as_dict()
        x, y, w, h = bbox
        sub = labels[y:y + h, x:x + w] == label_of.get(bbox, -1)
        geo: dict = {}
        behind: list[int] = []
        if sub.any():
            line = mos.pixel_to_uv(centre_line(sub) + (x, y))
            ring = mos.pixel_to_uv(outline(sub) + (x, y))
            geo["centre_line_uv"] = [(round(float(a), 4), round(float(b), 4)) for a, b in line]
            geo["outline_uv"] = [(round(float(a), 4), round(float(b), 4)) for a, b in ring]
            if origin is not None:
                for key, pts in (("centre_line_lla", line), ("outline_lla", ring)):
                    geo[key] = [(round(float(a), 9), round(float(b), 9), round(float(c), 3))
                                for a, b, c in enu_to_geodetic(pl.to_world(pts), origin)]
            own = mos.owner[y:y + h, x:x + w][sub]
            own = own[own >= 0]
            if own.size:
                share = np.bincount(own)
                meta = frames[int(share.argmax())].meta
                geo.update(uav=meta.uav, capture_id=meta.capture_id, t=meta.t, stamp=meta.stamp)
                behind = [int(i) for i in np.argsort(-share, kind="stable") if share[i] > 0]
        seers = [i for i, meta in enumerate(metas) if i not in mos.unusable and sees(meta, enu)]
        geo["seen_by"] = [frame_name(frames[i].meta) for i in dict.fromkeys([*behind, *seers])]
        rows.append(InspectionDefect(id=0, u_m=float(uv[0]), v_m=float(uv[1]), enu=tuple(float(x) for x in enu),
                                     lla=lla, length_m=float(d["length_m"]), width_max_mm=float(d["width_max_mm"]),
                                     width_mean_mm=float(d["width_mean_mm"]), area_m2=float(d["area_m2"]),
                                     severity=str(d["severity"]), resolved=bool(d["resolved"]), bbox_px=bbox, **geo))
    rows.sort(key=lambda r: (severity_rank(r.severity), -r.length_m))
    for k, r in enumerate(rows, start=1):
        r.id = k
    t3 = time.perf_counter()
    return Deliverable(mosaic=mos, defects=rows, frames=len(frames), method=method if segmented else "",
                       unusable={frame_name(frames[i].meta): p for i, p in mos.unusable.items()},
                       confirm=(confirm or "") if segmented else "", unconfirmed=unconfirmed,
                       origin=None if origin is None else (float(origin[0]), float(origin[1]), float(origin[2])),
                       seconds={"segment": t1 - t0, "mosaic": t2 - t1, "measure": t3 - t2, "total": t3 - t0})


# ------------------------------------------------------------------------------------ outputs
def annotated(mos: Mosaic, defects: Sequence[InspectionDefect]) -> np.ndarray:
    """The mosaic in colour with every defect outlined in red and numbered."""
    bgr = cv2.cvtColor(mos.image, cv2.COLOR_GRAY2BGR)
    bgr[mos.owner < 0] = (60, 60, 60)
    contours, _ = cv2.findContours(mos.mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(bgr, contours, -1, (0, 0, 255), 1)
    for d in defects:
        x, y, w, h = d.bbox_px
        cv2.rectangle(bgr, (x - 3, y - 3), (x + w + 2, y + h + 2), (0, 200, 255), 1)
        cv2.putText(bgr, str(d.id), (x, max(10, y - 5)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 255, 255), 1, cv2.LINE_AA)
    return bgr


def crop(mos: Mosaic, d: InspectionDefect, margin: int = CROP_MARGIN_PX) -> np.ndarray:
    """The mosaic around a defect, its pixels tinted red."""
    x, y, w, h = d.bbox_px
    H, W = mos.image.shape
    x0, y0, x1, y1 = max(0, x - margin), max(0, y - margin), min(W, x + w + margin), min(H, y + h + margin)
    g = mos.image[y0:y1, x0:x1]
    bgr = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    m = mos.mask[y0:y1, x0:x1] > 0
    tint = bgr[m].astype(np.float32)
    tint[:, 2] = 0.5 * tint[:, 2] + 127
    bgr[m] = tint.astype(np.uint8)
    return np.hstack([cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), bgr])


def _when(d: InspectionDefect) -> str:
    if d.uav is None:
        return "-"
    t = f", t {d.t:.1f} s" if d.t is not None else ""
    utc = (", " + time.strftime("%H:%M:%S", time.gmtime(d.stamp)) + " UTC") if d.stamp else ""
    return f"UAV {d.uav}, capture {d.capture_id}{t}{utc}"


def width_text(d: InspectionDefect) -> str:
    """The widths as the table shows them: a crack narrower than one pixel is flagged, not measured."""
    if not d.resolved:
        return f"below 1 px (< {d.width_max_mm:.1f})"
    nd = 0 if d.width_max_mm >= 10 else 1 if d.width_max_mm >= 1 else 2
    return f"{d.width_max_mm:.{nd}f} / {d.width_mean_mm:.{nd}f}"


def markdown_table(defects: Sequence[InspectionDefect], crops: bool = True, limit: int | None = None) -> str:
    """The defect table, in the order given (:data:`SORT_KEY` from :func:`inspect_frames`)."""
    head = ("| id | class | length (m) | width max / mean (mm) | u, v (m) | lat, lon (deg), alt (m) | seen in | crop |\n"
            "|---|---|---|---|---|---|---|---|")
    lines = [head]
    for d in defects[:limit]:
        ll = f"{d.lla[0]:.7f}, {d.lla[1]:.7f}, {d.lla[2]:.2f}" if d.lla else "-"
        c = f"![{d.id}]({d.crop})" if crops and d.crop else "-"
        cls = md_text(d.severity if d.resolved else f"{d.severity} (below 1 px)")
        lines.append(f"| {d.id} | {cls} | {d.length_m:.2f} | {width_text(d)} | {d.u_m:.2f}, {d.v_m:.2f} | {ll} | "
                     f"{md_text(_when(d))} | {c} |")
    return "\n".join(lines)


_GEO_EXCLUDE = {"lla", "bbox_px", "centre_line_uv", "outline_uv", "centre_line_lla", "outline_lla"}


def _lonlatalt(pts: Sequence[Sequence[float]]) -> list[list[float]]:
    return [[p[1], p[0], p[2]] for p in pts]


def geojson(defects: Sequence[InspectionDefect]) -> dict:
    """RFC 7946 FeatureCollection: per defect with a position, its centre line (LineString) and its
    outline (Polygon, exterior ring counter-clockwise seen from the front of the surface) as two
    Features with the same properties (``geometry`` says which), coordinates (lon, lat, alt) with the
    altitude above the WGS-84 ellipsoid as the scenario's origin gives it. A defect without a traced
    shape is a Point at its centroid."""
    feats = []
    for d in defects:
        if d.lla is None:
            continue
        props = d.model_dump(exclude=_GEO_EXCLUDE)
        geoms: list[tuple[str, dict[str, Any]]] = []
        if len(d.centre_line_lla) >= 2:
            geoms.append(("centre line", {"type": "LineString", "coordinates": _lonlatalt(d.centre_line_lla)}))
        if len(d.outline_lla) >= 4:
            geoms.append(("outline", {"type": "Polygon", "coordinates": [_lonlatalt(d.outline_lla)]}))
        if not geoms:
            geoms.append(("centroid", {"type": "Point", "coordinates": [d.lla[1], d.lla[0], d.lla[2]]}))
        for role, g in geoms:
            feats.append({"type": "Feature", "id": f"{d.id}-{role.replace(' ', '-')}", "geometry": g,
                          "properties": {**props, "geometry": role}})
    return {"type": "FeatureCollection", "features": feats}


def _kml_coords(pts: Sequence[Sequence[float]]) -> str:
    return " ".join(f"{p[1]:.9f},{p[0]:.9f},{p[2]:.3f}" for p in pts)


def kml(defects: Sequence[InspectionDefect], name: str = "SkyNet Inspect defects") -> str:
    """OGC KML 2.2 document: one Placemark per defect with a position, a MultiGeometry of its centroid
    (Point), centre line (LineString) and outline (Polygon), absolute altitudes; its sizes, class and
    capture in the description and as ExtendedData."""
    marks = []
    for d in defects:
        if d.lla is None:
            continue
        desc = (f"length {d.length_m:.2f} m, width max {d.width_max_mm:.1f} mm, mean {d.width_mean_mm:.1f} mm, "
                f"class {d.severity}" + ("" if d.resolved else " (below 1 px)")
                + (f"; {_when(d)}" if d.uav is not None else ""))
        geo = [f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{_kml_coords([d.lla])}</coordinates></Point>"]
        if len(d.centre_line_lla) >= 2:
            geo.append(f"<LineString><altitudeMode>absolute</altitudeMode><coordinates>"
                       f"{_kml_coords(d.centre_line_lla)}</coordinates></LineString>")
        if len(d.outline_lla) >= 4:
            geo.append("<Polygon><altitudeMode>absolute</altitudeMode><outerBoundaryIs><LinearRing><coordinates>"
                       f"{_kml_coords(d.outline_lla)}</coordinates></LinearRing></outerBoundaryIs></Polygon>")
        data = {"length_m": f"{d.length_m:.3f}", "width_max_mm": f"{d.width_max_mm:.2f}",
                "width_mean_mm": f"{d.width_mean_mm:.2f}", "severity": d.severity, "resolved": str(d.resolved).lower(),
                "uav": "" if d.uav is None else str(d.uav), "capture_id": "" if d.capture_id is None else str(d.capture_id),
                "t": "" if d.t is None else f"{d.t:.2f}", "crop": d.crop}
        ext = "".join(f'<Data name="{k}"><value>{xml_text(v)}</value></Data>' for k, v in data.items())
        marks.append(f"<Placemark><name>defect {d.id}</name><description>{xml_text(desc)}</description>"
                     f"<ExtendedData>{ext}</ExtendedData><MultiGeometry>{''.join(geo)}</MultiGeometry></Placemark>")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{xml_text(name)}</name>" + "".join(marks) + "</Document></kml>\n")


def aligned_text(mos: Mosaic, at_least_m: float = 0.01) -> str:
    """What the alignment did to the poses, for the findings ("" when no capture moved ``at_least_m``)."""
    moved = [m for m in mos.moved_m if m >= at_least_m]
    if not moved:
        return ""
    return (f"The alignment moved {len(moved)} of {len(mos.moved_m)} captures along the surface, by up to "
            f"{100 * max(moved):.0f} cm, to fit the others.")


def unusable_text(res: Deliverable, most: int = 12) -> str:
    """Which captures show no surface and are left out, for the findings ("" when none is)."""
    if not res.unusable:
        return ""
    names = [f"{n} ({p})" for n, p in sorted(res.unusable.items())]
    verb = "shows no surface and is" if len(names) == 1 else "show no surface and are"
    return (f"{len(names)} of the {res.frames} captures {verb} not counted: "
            + "; ".join(names[:most]) + ("; ..." if len(names) > most else "") + ".")


def resolution_note(m_per_px: float) -> dict[str, Any]:
    """What the mosaic's scale can size: a width below one pixel's footprint is flagged, not measured;
    the AASHTO classes (:data:`services.detector.measure.SEVERITY_LIMITS_M`) it can tell apart."""
    px_mm = 1e3 * m_per_px
    limits = [(name, hi * 1e3) for name, hi in SEVERITY_LIMITS_M]
    told = [name for name, hi in limits if hi > px_mm] + ["wide"]
    return {"pixel_mm": px_mm, "smallest_width_mm": px_mm, "classes_resolved": told,
            "classes_unresolved": [name for name, hi in limits if hi <= px_mm]}


def write_deliverable(res: Deliverable, out: str | Path, title: str = "", origin: Sequence[float] | None = None
                      ) -> list[str]:
    """Write the files of step 4 into ``out``; returns their names (relative to ``out``).

    Besides the table, GeoJSON and KML: ``mosaic.png`` (full resolution, defects outlined and
    numbered), ``overview.png`` (gridded panels, scale bar, axes: :func:`views.overview_figure`) and
    ``tiles/`` (the zoomable pyramid, :func:`views.write_tiles`).
    """
    from .views import orientation, orientation_text, overview_figure, write_tiles

    o = Path(out)
    (o / "crops").mkdir(parents=True, exist_ok=True)
    files = ["mosaic.png", "overview.png", "defects.json", "defects.md", "defects.geojson", "defects.kml"]
    for d in res.defects:
        d.crop = f"crops/defect-{d.id}.png"
        cv2.imwrite(str(o / d.crop), crop(res.mosaic, d))
        files.append(d.crop)
    ann = annotated(res.mosaic, res.defects)
    cv2.imwrite(str(o / "mosaic.png"), ann)
    orient = orientation(res.mosaic.plane, origin if origin is not None else res.origin)
    overview_figure(ann, res.mosaic, [(d.id, d.u_m, d.v_m) for d in res.defects], o / "overview.png",
                    title=title or orientation_text(orient))
    tiles = write_tiles(ann, o / "tiles")
    summary = {"frames": res.frames, "frames_used": res.mosaic.frames_used, "m_per_px": res.mosaic.m_per_px,
               "mosaic_px": list(res.mosaic.image.shape[::-1]), "coverage": res.mosaic.coverage,
               "seconds": res.seconds, "skipped": res.mosaic.skipped, "unusable": res.unusable, "sort_key": SORT_KEY,
               "aligned_m": {"max": max(res.mosaic.moved_m, default=0.0),
                             "median": float(np.median(res.mosaic.moved_m)) if res.mosaic.moved_m else 0.0},
               "orientation": orient, "resolution": resolution_note(res.mosaic.m_per_px), "tiles": tiles,
               "defects": [d.model_dump() for d in res.defects]}
    (o / "defects.json").write_text(json.dumps(summary, indent=1))
    (o / "defects.md").write_text(f"Sorted by {SORT_KEY}.\n\n" + markdown_table(res.defects) + "\n")
    (o / "defects.geojson").write_text(json.dumps(geojson(res.defects), indent=1))
    (o / "defects.kml").write_text(kml(res.defects))
    res.files = files
    return files


# ------------------------------------------------------------------------------------ folders
def load_folder(folder: str | Path) -> tuple[list[PosedFrame], Plane | None, tuple[float, float, float] | None]:
    """Frames with poses from ``folder`` (docs/report.md), its plane and geodetic origin.

    Raises ``ValueError`` naming the file when an image does not decode or a pose file is invalid;
    an image without a pose file is an error too (its pose cannot be guessed).
    """
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"{root} is not a folder")
    frames = []
    files = sorted(p for p in root.iterdir() if p.suffix.lower() in FRAME_SUFFIXES)
    for i, p in enumerate(files, start=1):
        side = p.with_suffix(".json")
        if not side.exists():
            raise ValueError(f"{p.name}: no pose file {side.name}")
        try:
            doc = {k: v for k, v in codec.loads_json(side.read_text()).items() if k != "type"}
            meta = ImageMeta.model_validate({"uav": 1, "capture_id": i, "t": 0.0, "stamp": 0.0, **doc})
        except (json.JSONDecodeError, ValueError) as exc:
            raise ValueError(f"{side.name}: {exc}") from None
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if g is None:
            raise ValueError(f"{p.name}: does not decode")
        k = meta.intrinsics
        if (k.width, k.height) != (g.shape[1], g.shape[0]):
            raise ValueError(f"{p.name}: {g.shape[1]}x{g.shape[0]} px but its intrinsics say {k.width}x{k.height}")
        frames.append(PosedFrame(meta, g))
    plane, origin = None, None
    sj = root / "surface.json"
    if sj.exists():
        try:
            doc = codec.loads_json(sj.read_text())
            if doc.get("corners") is not None:
                plane = Plane.from_corners(doc["corners"])
            if doc.get("origin") is not None:
                o = [float(x) for x in doc["origin"]]
                if len(o) != 3 or not all(math.isfinite(x) for x in o):
                    raise ValueError("origin must be (lat, lon, alt)")
                origin = (o[0], o[1], o[2])
        except (json.JSONDecodeError, ValueError, TypeError) as exc:
            raise ValueError(f"surface.json: {exc}") from None
    return frames, plane, origin


def frames_from_log(path: str | Path) -> list[PosedFrame]:
    """The capture frames a mission log holds (:func:`services.recording.mcap_log.captures`: what reached the
    ground station over the bus), decoded to grey, in the order of :func:`services.detector.frames.save_frame`'s file names (as
    :func:`load_folder` reads them: the mosaic does not depend on the order frames arrived in); a frame that does
    not decode or whose size is not its intrinsics' is skipped."""
    from services.recording.mcap_log import captures

    frames = []
    left_out: list[str] = []
    for meta, image in captures(path):
        try:
            frames.append(PosedFrame(meta, decode_image(image, grey=True,
                                                        size=(meta.intrinsics.width, meta.intrinsics.height))))
        except ValueError as exc:
            left_out.append(f"{frame_name(meta)}: {exc}")
    if left_out:  # one line however many (the log's frames came from the bus)
        log.warning("deliverable: %d capture(s) in the log do not decode, left out (the first: %s)", len(left_out),
                    left_out[0])
    return sorted(frames, key=lambda f: frame_name(f.meta))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m services.inspection.deliverable", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="photos with pose files (docs/report.md)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--method", default="it+")
    ap.add_argument("--confirm", default=CONFIRM_METHOD,
                    help="the method whose mask must touch each defect ('none': every defect of --method kept)")
    ap.add_argument("--resolution-mm", type=float, default=None, help="mosaic resolution (default: the frames')")
    ap.add_argument("--align-m", type=float, default=ALIGN_M,
                    help="how far two photos may be moved along the surface to fit each other (0: placed by their "
                         "poses alone; default: %(default)s)")
    a = ap.parse_args(argv)
    if not (math.isfinite(a.align_m) and 0.0 <= a.align_m <= 10.0):
        ap.error(f"--align-m must be in [0, 10] m, got {a.align_m}")
    try:
        frames, plane, origin = load_folder(a.folder)
        if not frames:
            raise ValueError(f"no photos in {a.folder}")
        res = inspect_frames(frames, plane, origin, a.method, None if a.resolution_mm is None else a.resolution_mm / 1e3,
                             confirm=None if a.confirm == "none" else a.confirm, align_m=a.align_m)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    write_deliverable(res, a.out, origin=origin)
    print(f"{len(res.defects)} defects on a {res.mosaic.image.shape[1]}x{res.mosaic.image.shape[0]} px mosaic "
          f"({res.mosaic.m_per_px * 1e3:.1f} mm/px, coverage {res.mosaic.coverage:.0%}) in {res.seconds['total']:.2f} s: {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
