"""The inspection deliverable of a mission: built from the captures the detector kept, told first.

Design notes: docs/report.md (services/inspection/mission.py).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from protocol.textsafe import md_text
from services.detector.measure import SEVERITY_LIMITS_M
from services.recording.record import MissionRecord, capture_name

from .deliverable import (
    SEVERITY_ORDER,
    SORT_KEY,
    Deliverable,
    aligned_text,
    frame_name,
    frames_from_log,
    inspect_frames,
    load_folder,
    markdown_table,
    resolution_note,
    unusable_text,
    width_text,
    write_deliverable,
)
from .mosaic import Plane, PosedFrame

__all__ = ["append_deliverable", "FOLDER", "HEADING", "findings_markdown", "class_ranges", "deliverable_line"]

log = logging.getLogger(__name__)

#: sub-folder of the report with the deliverable
FOLDER = "inspection"
#: the section's heading in report.md
HEADING = "## Inspection deliverable: findings"
#: rows of the defect table shown in report.md (all of them are in inspection/defects.md)
TABLE_ROWS = 60
#: worst cracks shown with their crops at the top
WORST = 5


def _origin(record: MissionRecord) -> tuple[float, float, float] | None:
    if record.scenario is None:
        return None
    o = record.scenario.origin
    return o.lat, o.lon, o.alt


def class_ranges() -> dict[str, str]:
    """The width range of each severity class, as text (AASHTO MBEI, reinforced concrete)."""
    out, lo = {}, 0.0
    for name, hi in SEVERITY_LIMITS_M:
        out[name] = f"{lo * 1e3:g}–{hi * 1e3:g} mm" if lo else f"< {hi * 1e3:g} mm"
        lo = hi
    out["wide"] = f"> {lo * 1e3:g} mm"
    return out


def _accuracy(record: MissionRecord, res: Deliverable):
    """The deliverable against the simulated wall's truth, on the part of it the captures saw (None without one)."""
    from services.inspection.ground_truth import truth_surface

    from .accuracy import compare, seen_pixels, truth_cracks, unseen_cracks

    surf = truth_surface(record)
    if surf is None:
        return None
    s = 1.0 / surf.px_per_m
    (h, w), plane = surf.mask.shape, res.mosaic.plane
    if abs(plane.width_m - w * s) > s or abs(plane.height_m - h * s) > s:  # a mosaic on another plane
        truth, labels = truth_cracks(surf.mask, s)
        return compare(res.defects, truth, labels, s, gsd_m=res.mosaic.m_per_px)
    seen = seen_pixels(res.mosaic.owner, res.mosaic.m_per_px, surf.mask.shape, s)
    truth, labels = truth_cracks(surf.mask, s, seen=seen)
    return compare(res.defects, truth, labels, s, gsd_m=res.mosaic.m_per_px, unseen=unseen_cracks(surf.mask, seen))


def absent_text(record: MissionRecord, posed: Sequence[PosedFrame]) -> str:
    """What the mosaic lacks: the planned captures whose frames are not among its input ("" when none is)."""
    planned = {(t.uav, w.capture_id) for t in (record.plan.trajectories if record.plan else ())
               for w in t.waypoints if w.capture_id is not None}
    absent = sorted(planned - {(f.meta.uav, f.meta.capture_id) for f in posed})
    if not absent:
        return ""
    return (f"{len(absent)} of the {len(planned)} planned captures are not among its frames (not taken, or lost "
            "on the way to the ground station's log): " + ", ".join(capture_name(u, c) for u, c in absent[:12])
            + (", ..." if len(absent) > 12 else "") + ".")


def findings_markdown(res: Deliverable, acc: Any = None, prefix: str = FOLDER, frames: str = "frames",
                      absent: str = "", detector: str | None = None) -> list[str]:
    """The findings section's lines (docs/report.md); file links relative to the report."""
    from .accuracy import markdown_accuracy

    m = res.mosaic
    by_class = {c: [d for d in res.defects if d.severity == c] for c in SEVERITY_ORDER}
    ranges = class_ranges()
    note = resolution_note(m.m_per_px)
    lines = [HEADING, "",
             f"**{len(res.defects)} defects (" + ", ".join(f"{len(by_class[c])} {c}" for c in SEVERITY_ORDER)
             + f")** found on the inspected surface. Coverage of the surface: {m.coverage:.0%} (by {m.frames_used} of {res.frames} captures, "
             f"mosaic {m.image.shape[1]} x {m.image.shape[0]} px at {m.m_per_px * 1e3:.2f} mm/px). "
             f"At this ground sampling distance a crack narrower than {note['smallest_width_mm']:.2f} mm (one pixel) "
             "is flagged, not measured; the classes told apart by width: "
             + ", ".join(note["classes_resolved"])
             + (f" (not: {', '.join(note['classes_unresolved'])}, narrower than one pixel)"
                if note["classes_unresolved"] else "") + "." + "".join(f" {md_text(x)}" for x in (absent, unusable_text(res), aligned_text(m)) if x),
             "",
             md_text(orientation_text_of(res)), "",
             "| class (AASHTO, max width) | defects | longest (m) | widest (mm) |", "|---|---|---|---|"]
    for c in SEVERITY_ORDER:
        ds = by_class[c]
        lines.append(f"| {c} ({ranges[c]}) | {len(ds)} | {max((d.length_m for d in ds), default=0):.2f} | "
                     f"{max((d.width_max_mm for d in ds), default=0):.1f} |")
    lines.append("")
    worst = res.defects[:WORST]
    if worst:
        lines += [f"### The worst {len(worst)} cracks", ""]
        for d in worst:
            seen = ", ".join(f"[{n}]({frames}/{n}.jpg)" for n in d.seen_by) or "–"
            lines += [f"**{d.id}.** {md_text(d.severity)}, {d.length_m:.2f} m long, width max / mean "
                      f"{width_text(d)} mm, at u = {d.u_m:.2f} m, v = {d.v_m:.2f} m"
                      + (f" ({d.lla[0]:.7f}, {d.lla[1]:.7f}, {d.lla[2]:.1f} m)" if d.lla else "")
                      + f"; captures: {seen}.", "", f"![defect {d.id}]({prefix}/{d.crop})", ""]
    if acc is not None:
        lines += ["### Measurements against the ground truth", "", markdown_accuracy(acc), ""]
    lines += ["### The wall", "",
              f"![overview of the wall: 1 m grid, scale bar, u/v axes, defects numbered]({prefix}/overview.png)", "",
              f"Full resolution: `{prefix}/mosaic.png`; zoomable in `report.html`.",
              "", f"### Defect table (sorted by {SORT_KEY})", ""]
    rows = [d.model_copy(update={"crop": f"{prefix}/{d.crop}" if d.crop else ""}) for d in res.defects[:TABLE_ROWS]]
    lines.append(markdown_table(rows))
    if len(res.defects) > TABLE_ROWS:
        lines.append(f"\n({len(res.defects) - TABLE_ROWS} more in `{prefix}/defects.md`.)")
    lines += ["", f"Geometry for a GIS: `{prefix}/defects.geojson` (RFC 7946: each crack's centre line and outline, "
              f"lon, lat, altitude), `{prefix}/defects.kml` (Google Earth, absolute altitudes), `{prefix}/defects.json`. "
              + (f"Segmented with `{res.method}`" + (f", each crack confirmed by `{res.confirm}`" if res.confirm else "")
                 + (f" ({md_text(res.unconfirmed)})" if res.unconfirmed else "")
                 + (f" (the mission's detector ran `{detector}`)" if detector and detector != res.method else "") + ": "
                 if res.method else "")
              + f"segmentation {res.seconds.get('segment', 0):.2f} s, mosaic {res.seconds.get('mosaic', 0):.2f} s, "
              f"measurement {res.seconds.get('measure', 0):.2f} s; a crack seen by overlapping frames is one defect "
              "here. The mission's own figures follow.", ""]
    return lines


def orientation_text_of(res: Deliverable) -> str:
    from .views import orientation, orientation_text

    return orientation_text(orientation(res.mosaic.plane, res.origin))


def _insert_first(report_md: Path, lines: list[str]) -> None:
    """Put ``lines`` right after the report's outcome (before its first ``## `` section)."""
    text = report_md.read_text() if report_md.exists() else ""
    block = "\n".join(lines) + "\n"
    at = text.find("\n## ")
    if at < 0:
        report_md.write_text(text + ("\n" if text and not text.endswith("\n") else "") + "\n" + block)
    else:
        report_md.write_text(text[:at + 1] + block + "\n" + text[at + 1:])


def cited_captures(log_path: Path, res: Deliverable, folder: Path) -> list[str]:
    """Write the capture frames the worst cracks cite (as the mission log holds them) into ``folder``, named as
    the findings link them; the files written, relative to the report folder."""
    from services.recording.mcap_log import captures

    cited = {n for d in res.defects[:WORST] for n in d.seen_by}
    written = []
    for meta, image in captures(log_path):
        name = frame_name(meta)
        if name in cited:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / f"{name}.jpg").write_bytes(image)
            written.append(f"{FOLDER}/{folder.name}/{name}.jpg")
    return written


def surface_corners(record: MissionRecord) -> list | None:
    """The inspected surface's corners: the record's (a simulated wall's), else the scenario's (the operator's
    survey, whatever the cameras are); None without either."""
    if len(record.surface_corners) == 4:
        return list(record.surface_corners)
    surface = record.scenario.surface if record.scenario is not None else None
    return list(surface.corners) if surface is not None else None


def append_deliverable(record: MissionRecord, folder: str | Path, files: list[str] | None = None,
                       frames: str | Path | None = None) -> list[str]:
    """Build the deliverable from ``frames`` (a mission log, or a folder of posed photos; default
    ``folder/frames``; if any), put its findings first in ``folder/report.md`` and write
    ``folder/report.html``; the files written (relative to ``folder``) are added to ``files``."""
    out = Path(folder)
    source = Path(frames) if frames is not None else out / "frames"
    if not (source.is_dir() or source.is_file()):
        return []
    try:
        posed = frames_from_log(source) if source.is_file() else load_folder(source)[0]
        if not posed:
            raise ValueError(f"no captures in {source.name}")
        plane = Plane.from_corners(corners) if (corners := surface_corners(record)) else None
        origin = _origin(record)
        res = inspect_frames(posed, plane, origin)
        written = [f"{FOLDER}/{f}" for f in write_deliverable(res, out / FOLDER, origin=origin)]
    except ValueError as exc:
        _insert_first(out / "report.md", [HEADING, "", f"Not built: {md_text(exc)}.", ""])
        return []
    acc = None
    try:
        acc = _accuracy(record, res)
    except ValueError as exc:  # a scenario without a simulated wall
        log.warning("no ground truth to measure against: %s", exc)
    if acc is not None:
        (out / FOLDER / "accuracy.json").write_text(json.dumps(acc.to_dict(), indent=1))
        written.append(f"{FOLDER}/accuracy.json")
    if source.is_file():  # a mission log: the captures the findings cite, as files beside the deliverable
        written += cited_captures(source, res, out / FOLDER / "captures")
        rel_frames = f"{FOLDER}/captures"
    else:
        rel_frames = source.name if source.parent.resolve() == out.resolve() else str(source)
    absent = absent_text(record, posed)
    if absent:
        log.warning("deliverable: %s", absent)
    _insert_first(out / "report.md", findings_markdown(res, acc, FOLDER, rel_frames, absent, record.method))
    from .html import write_html

    figures = [f for f in (files or []) if f.endswith(".png") and "/" not in f]
    write_html(out / "report.html", res, acc, FOLDER, rel_frames, figures, record, absent)
    written.append("report.html")
    if files is not None:
        files.extend(written)
    return written


def deliverable_line(folder: str | Path) -> str | None:
    """The terminal's last line after a mission: the defect count and the deliverable's path (None
    when the report has no deliverable)."""
    out = Path(folder)
    doc_path = out / FOLDER / "defects.json"
    if not doc_path.is_file():
        return None
    try:
        doc = json.loads(doc_path.read_text())
        ds = doc["defects"]
        counts = {c: sum(1 for d in ds if d.get("severity") == c) for c in SEVERITY_ORDER}
    except (ValueError, KeyError, TypeError):
        return None
    page = out / "report.html"
    return (f"{len(ds)} defects (" + ", ".join(f"{n} {c}" for c, n in counts.items()) + "): "
            f"{page if page.is_file() else out / 'report.md'}")
