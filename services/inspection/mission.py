"""The inspection deliverable of a mission: built from the captures the detector kept.

With ``skynet mission`` the detector keeps every capture it analysed, with its pose, in
``<report>/frames`` (``--save-frames``; the folder format of :mod:`services.inspection.deliverable`).
:func:`append_deliverable` turns them into ``<report>/inspection/`` (mosaic, defect table, crops,
GeoJSON, KML) on the scenario's surface and geodetic origin, and adds a section to ``report.md``.
A mission without saved captures gets no section; a deliverable that cannot be built says why in it.
"""

from __future__ import annotations

from pathlib import Path

from protocol.textsafe import md_text
from services.recording.record import MissionRecord

from .deliverable import inspect_frames, load_folder, markdown_table, write_deliverable
from .mosaic import Plane

__all__ = ["append_deliverable", "FOLDER"]

#: sub-folder of the report with the deliverable
FOLDER = "inspection"
#: rows of the defect table shown in report.md (all of them are in inspection/defects.md)
TABLE_ROWS = 60


def _origin(record: MissionRecord) -> tuple[float, float, float] | None:
    if record.scenario is None:
        return None
    o = record.scenario.origin
    return o.lat, o.lon, o.alt


def append_deliverable(record: MissionRecord, folder: str | Path, files: list[str] | None = None,
                       frames: str | Path | None = None) -> list[str]:
    """Build the deliverable from ``frames`` (default ``folder/frames``; if any) and append its section to
    ``folder/report.md``; the files written (relative to ``folder``) are added to ``files``."""
    out = Path(folder)
    frames_dir = Path(frames) if frames is not None else out / "frames"
    if not frames_dir.is_dir():
        return []
    lines = ["", "## Inspection deliverable", ""]
    try:
        frames, _, _ = load_folder(frames_dir)
        if not frames:
            raise ValueError("the detector kept no captures")
        plane = Plane.from_corners(record.surface_corners) if len(record.surface_corners) == 4 else None
        res = inspect_frames(frames, plane, _origin(record))
        written = [f"{FOLDER}/{f}" for f in write_deliverable(res, out / FOLDER)]
    except ValueError as exc:
        lines.append(f"Not built: {md_text(exc)}.")
        with open(out / "report.md", "a") as fh:
            fh.write("\n".join(lines) + "\n")
        return []
    m = res.mosaic
    by_class: dict[str, int] = {}
    for d in res.defects:
        by_class[d.severity] = by_class.get(d.severity, 0) + 1
    lines += [
        f"{res.frames} captures mosaicked on the surface plane from their poses ({m.frames_used} used, "
        f"{m.image.shape[1]} x {m.image.shape[0]} px at {m.m_per_px * 1e3:.1f} mm/px, coverage {m.coverage:.0%}) "
        f"in {res.seconds['mosaic']:.2f} s; segmentation {res.seconds['segment']:.2f} s, measurement "
        f"{res.seconds['measure']:.2f} s. {len(res.defects)} defects ("
        + ", ".join(f"{n} {c}" for c, n in sorted(by_class.items())) + "); a crack seen by overlapping "
        "frames is one defect here. Widths below one pixel's footprint cannot be told apart. Files: "
        f"`{FOLDER}/defects.geojson`, `{FOLDER}/defects.kml`, `{FOLDER}/defects.json`.",
        "",
        f"![mosaic]({FOLDER}/mosaic.png)",
        "",
    ]
    rows = res.defects[:TABLE_ROWS]
    for d in rows:
        d.crop = f"{FOLDER}/{d.crop}" if d.crop else ""
    lines.append(markdown_table(rows))
    if len(res.defects) > TABLE_ROWS:
        lines.append(f"\n({len(res.defects) - TABLE_ROWS} more in `{FOLDER}/defects.md`.)")
    with open(out / "report.md", "a") as fh:
        fh.write("\n".join(lines) + "\n")
    if files is not None:
        files.extend(written)
    return written
