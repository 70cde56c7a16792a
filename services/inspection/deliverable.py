"""The inspection deliverable: mosaic of the wall, defect table with sizes and crops, GeoJSON and KML.

Pure (no bus code). Input: posed frames (:class:`services.inspection.mosaic.PosedFrame`) from a
mission (the detector's saved captures) or from a folder of photos with poses
(:func:`load_folder`). Steps:

1. every frame is segmented by the detector's method (:func:`services.detector.detect.detect`, IT+
   by default: what the mission's detector reported);
2. frames and masks are warped onto the surface plane (:func:`services.inspection.mosaic.build_mosaic`);
3. each 8-connected component of the mosaic's defect mask is one defect (a crack seen by two
   overlapping frames is one defect): its position (centroid) on the surface, in ENU and, with the
   geodetic origin, in WGS-84 (:func:`edge.geometry.waypoint_mission.enu_to_geodetic`); its length, maximum
   and mean width and severity class (:mod:`services.detector.measure`, at the mosaic's scale);
   and a crop of the mosaic around it;
4. files: ``mosaic.png`` (defects outlined and numbered), ``defects.json``, ``defects.md``,
   ``defects.geojson`` (RFC 7946: a Point per defect, the skeleton-free centroid, with its sizes as
   properties), ``defects.kml`` (OGC KML 2.2 placemarks) and ``crops/defect-<id>.png``.

Folder of photos with poses: ``<name>.jpg|png`` each with ``<name>.json`` holding the fields of
:class:`protocol.messages.ImageMeta` (``cam_pos`` ENU m, ``cam_rot`` world-from-camera row-major
with OpenCV camera axes, ``intrinsics``, ``range_m``; ``uav``, ``capture_id``, ``t`` and ``stamp``
may be left out), and optionally ``surface.json`` with ``corners`` (4 ENU points, p0-p1 the bottom
edge) and ``origin`` (lat, lon, alt). Without corners the plane is fitted to the frames
(:func:`services.inspection.mosaic.plane_from_frames`).

    python -m services.inspection.deliverable FOLDER --out OUT [--method it+]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict

from edge.geometry.waypoint_mission import enu_to_geodetic
from protocol import codec
from protocol.messages import ImageMeta
from protocol.textsafe import md_text, xml_text
from services.detector.detect import detect
from services.detector.pipeline import MIN_REPORT_AREA_PX

from services.detector.measure import measure_mask
from .mosaic import Mosaic, Plane, PosedFrame, build_mosaic, plane_from_frames

__all__ = ["InspectionDefect", "Deliverable", "inspect_frames", "load_folder", "write_deliverable",
           "markdown_table", "geojson", "kml", "FRAME_SUFFIXES", "frames_from_log"]

FRAME_SUFFIXES = (".jpg", ".jpeg", ".png")
CROP_MARGIN_PX = 12


class InspectionDefect(BaseModel):
    """One row of the defect table."""

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


@dataclass
class Deliverable:
    mosaic: Mosaic
    defects: list[InspectionDefect]
    frames: int
    seconds: dict[str, float] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)


def segment(frames: Sequence[PosedFrame], method: str = "it+") -> list[PosedFrame]:
    """The frames with their defect masks from the detector's ``method``."""
    return [PosedFrame(f.meta, f.grey, detect(f.grey, method, with_defects=False).mask) for f in frames]


def inspect_frames(frames: Sequence[PosedFrame], plane: Plane | None = None, origin: Sequence[float] | None = None,
                   method: str = "it+", m_per_px: float | None = None, min_area_px: int = MIN_REPORT_AREA_PX
                   ) -> Deliverable:
    """Segment, mosaic and measure (steps 1-3 of the module docstring)."""
    if not frames:
        raise ValueError("no frames")
    t0 = time.perf_counter()
    seg = segment(frames, method) if any(f.mask is None for f in frames) else list(frames)
    t1 = time.perf_counter()
    pl = plane if plane is not None else plane_from_frames([f.meta for f in frames])
    mos = build_mosaic(seg, pl, m_per_px)
    t2 = time.perf_counter()
    rows = []
    for k, (bbox, ctr, m) in enumerate(measure_mask(mos.mask, mos.m_per_px, min_area_px, mos.image), start=1):
        uv = mos.pixel_to_uv(np.array(ctr))
        enu = pl.to_world(uv)
        lla = None
        if origin is not None:
            lla = tuple(float(x) for x in enu_to_geodetic(enu, origin))
        d = m.as_dict()
        rows.append(InspectionDefect(
            id=k, u_m=float(uv[0]), v_m=float(uv[1]), enu=tuple(float(x) for x in enu), lla=lla,
            length_m=float(d["length_m"]), width_max_mm=float(d["width_max_mm"]),
            width_mean_mm=float(d["width_mean_mm"]), area_m2=float(d["area_m2"]), severity=str(d["severity"]),
            resolved=bool(d["resolved"]), bbox_px=bbox,
        ))
    t3 = time.perf_counter()
    return Deliverable(mosaic=mos, defects=rows, frames=len(frames),
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
        cv2.putText(bgr, str(d.id), (x, max(10, y - 5)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 255, 255), 1,
                    cv2.LINE_AA)
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


def markdown_table(defects: Sequence[InspectionDefect], crops: bool = True, limit: int | None = None) -> str:
    head = "| id | u, v (m) | lat, lon | length (m) | width max / mean (mm) | class | crop |\n|---|---|---|---|---|---|---|"
    lines = [head]
    for d in defects[:limit]:
        ll = f"{d.lla[0]:.7f}, {d.lla[1]:.7f}" if d.lla else "-"
        c = f"![{d.id}]({d.crop})" if crops and d.crop else "-"
        cls = md_text(d.severity if d.resolved else f"{d.severity} (below 1 px)")
        lines.append(f"| {d.id} | {d.u_m:.2f}, {d.v_m:.2f} | {ll} | {d.length_m:.2f} | "
                     f"{d.width_max_mm:.0f} / {d.width_mean_mm:.0f} | {cls} | {c} |")
    return "\n".join(lines)


def geojson(defects: Sequence[InspectionDefect]) -> dict:
    """RFC 7946 FeatureCollection: one Point (lon, lat, alt) per defect with a position."""
    feats = []
    for d in defects:
        if d.lla is None:
            continue
        props = d.model_dump(exclude={"lla", "bbox_px"})
        feats.append({"type": "Feature", "id": d.id,
                      "geometry": {"type": "Point", "coordinates": [d.lla[1], d.lla[0], d.lla[2]]},
                      "properties": props})
    return {"type": "FeatureCollection", "features": feats}


def kml(defects: Sequence[InspectionDefect], name: str = "SkyNet Inspect defects") -> str:
    """OGC KML 2.2 document: one Placemark per defect with a position (absolute altitude)."""
    marks = []
    for d in defects:
        if d.lla is None:
            continue
        desc = (f"length {d.length_m:.2f} m, width max {d.width_max_mm:.0f} mm, mean {d.width_mean_mm:.0f} mm, "
                f"class {d.severity}")
        marks.append(f"<Placemark><name>defect {d.id}</name><description>{xml_text(desc)}</description>"
                     f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{d.lla[1]:.9f},{d.lla[0]:.9f},"
                     f"{d.lla[2]:.3f}</coordinates></Point></Placemark>")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{xml_text(name)}</name>" + "".join(marks) + "</Document></kml>\n")


def write_deliverable(res: Deliverable, out: str | Path) -> list[str]:
    """Write the files of step 4 into ``out``; returns their names (relative to ``out``)."""
    o = Path(out)
    (o / "crops").mkdir(parents=True, exist_ok=True)
    files = ["mosaic.png", "defects.json", "defects.md", "defects.geojson", "defects.kml"]
    for d in res.defects:
        d.crop = f"crops/defect-{d.id}.png"
        cv2.imwrite(str(o / d.crop), crop(res.mosaic, d))
    cv2.imwrite(str(o / "mosaic.png"), annotated(res.mosaic, res.defects))
    summary = {"frames": res.frames, "frames_used": res.mosaic.frames_used, "m_per_px": res.mosaic.m_per_px,
               "mosaic_px": list(res.mosaic.image.shape[::-1]), "coverage": res.mosaic.coverage,
               "seconds": res.seconds, "skipped": res.mosaic.skipped,
               "defects": [d.model_dump() for d in res.defects]}
    (o / "defects.json").write_text(json.dumps(summary, indent=1))
    (o / "defects.md").write_text(markdown_table(res.defects) + "\n")
    (o / "defects.geojson").write_text(json.dumps(geojson(res.defects), indent=1))
    (o / "defects.kml").write_text(kml(res.defects))
    res.files = files
    return files


# ------------------------------------------------------------------------------------ folders
def _meta_from(doc: dict, index: int) -> ImageMeta:
    base = {"uav": 1, "capture_id": index, "t": 0.0, "stamp": 0.0}
    return ImageMeta.model_validate({**base, **{k: v for k, v in doc.items() if k != "type"}})


def load_folder(folder: str | Path) -> tuple[list[PosedFrame], Plane | None, tuple[float, float, float] | None]:
    """Frames with poses from ``folder`` (see the module docstring), its plane and geodetic origin.

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
            meta = _meta_from(codec.loads_json(side.read_text()), i)
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
    for meta, image in captures(path):
        g = cv2.imdecode(np.frombuffer(image, np.uint8), cv2.IMREAD_GRAYSCALE)
        k = meta.intrinsics
        if g is not None and (k.width, k.height) == (g.shape[1], g.shape[0]):
            frames.append(PosedFrame(meta, g))
    return sorted(frames, key=lambda f: f"uav{f.meta.uav}-{f.meta.capture_id:05d}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m services.inspection.deliverable", description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="photos with pose files (see the module docstring)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--method", default="it+")
    ap.add_argument("--resolution-mm", type=float, default=None, help="mosaic resolution (default: the frames')")
    a = ap.parse_args(argv)
    try:
        frames, plane, origin = load_folder(a.folder)
        if not frames:
            raise ValueError(f"no photos in {a.folder}")
        res = inspect_frames(frames, plane, origin, a.method, None if a.resolution_mm is None else a.resolution_mm / 1e3)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    write_deliverable(res, a.out)
    print(f"{len(res.defects)} defects on a {res.mosaic.image.shape[1]}x{res.mosaic.image.shape[0]} px mosaic "
          f"({res.mosaic.m_per_px * 1e3:.1f} mm/px, coverage {res.mosaic.coverage:.0%}) in {res.seconds['total']:.2f} s: {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
