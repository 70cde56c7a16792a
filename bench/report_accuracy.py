"""The inspection report's measurements against the ground truth: the nominal wall and the real-size one.

    .venv/bin/python bench/report_accuracy.py [--out bench/results/report_accuracy.json]
                                              [--methods it+ learned it+r] [--mission REPORT_FOLDER ...]

For each scenario (``monorail``: cracks 3.5-8 cm wide at 640 x 480, 7.8 mm/px; ``real-cracks``: cracks
0.1-3 mm wide at 4000 x 3000, 0.25 mm/px) the captures are rendered off the bus at the planned shots
(:func:`services.inspection.captures.synthetic_captures`, the frames a mission's edges send), the
deliverable is built from them (:func:`services.inspection.deliverable.inspect_frames`) and compared
with the wall's truth (:mod:`services.inspection.accuracy`): median and worst errors of length and
widths, the share of cracks in their true class, the cracks narrower than one pixel and the defects on
no true crack, and the object-level recall (true cracks found / true cracks) and precision (defects on a true
crack / defects) of each detector method of ``--methods`` (default: the deliverable's own, ``it+``), its components
confirmed by ``--confirm`` (default: the deliverable's, ``learned``; ``none``: all kept). ``--mission`` adds the ``inspection/accuracy.json`` of missions already flown
(``skynet mission --out FOLDER``). Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.world.wall import synthetic_surface  # noqa: E402
from protocol.scenario import load_scenario  # noqa: E402
from services.inspection.accuracy import compare, truth_cracks  # noqa: E402
from services.inspection.captures import decode, synthetic_captures  # noqa: E402
from services.inspection.deliverable import CONFIRM_METHOD, inspect_frames  # noqa: E402
from services.inspection.mosaic import Plane, PosedFrame  # noqa: E402

#: scenario -> capture frame size (the launcher's --frame-size for it)
SCENARIOS = {"monorail": (640, 480), "real-cracks": (4000, 3000)}


def object_scores(summary: dict, defects: int) -> dict[str, float]:
    """Object-level recall (true cracks with a defect on them / true cracks) and precision (defects on a true
    crack / defects; 1 with no defect), the analogues of (P20)'s r and p."""
    truth, found = summary.get("truth", 0), summary.get("matched", 0)
    return {"recall": found / truth if truth else 1.0,
            "precision": (defects - summary.get("unmatched_defects", 0)) / defects if defects else 1.0}


def run(name: str, size: tuple[int, int], method: str = "it+", confirm: str | None = CONFIRM_METHOD) -> dict:
    t0 = time.perf_counter()
    sc = load_scenario(name)
    surf = synthetic_surface(sc)
    caps = synthetic_captures(sc, surf, frame_size=size)
    o = sc.origin
    res = inspect_frames([PosedFrame(c.meta, decode(c)) for c in caps], Plane.from_corners(surf.corners),
                         (o.lat, o.lon, o.alt), method, confirm=confirm)
    s = 1.0 / surf.px_per_m
    truth, labels = truth_cracks(surf.mask, s)
    acc = compare(res.defects, truth, labels, s, gsd_m=res.mosaic.m_per_px)
    return {"scenario": name, "method": method + (f" confirmed by {confirm}" if confirm else ""), "frame": list(size), "captures": len(caps),
            "defects": len(res.defects), "seconds": time.perf_counter() - t0, **acc.summary,
            **object_scores(acc.summary, len(res.defects)), "rows": acc.to_dict()["rows"]}


def line(r: dict) -> str:
    def pct(x: float | None) -> str:
        return "–" if x is None else f"{100 * x:.1f} %"

    def mm(x: float | None) -> str:
        return "–" if x is None else f"{x:.2f}"

    pr = "–" if "precision" not in r else f"{r['recall']:.2f} / {r['precision']:.2f}"
    return (f"| {r['scenario']} | {r.get('method', '–')} | {pr} | {r.get('gsd_mm', 0):.2f} | {r['truth']} / {r['matched']} / {r['unmatched_defects']} | "
            f"{pct(r['length_error_median'])} / {pct(r['length_error_worst'])} | "
            f"{mm(r['width_mean_error_mm_median'])} / {mm(r['width_mean_error_mm_worst'])} | "
            f"{mm(r['width_max_error_mm_median'])} / {mm(r['width_max_error_mm_worst'])} | "
            f"{pct(r['class_agreement'])} | {r.get('below_pixel', 0)} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "report_accuracy.json")
    ap.add_argument("--mission", type=Path, action="append", default=[], help="a mission's report folder")
    ap.add_argument("--only", choices=sorted(SCENARIOS), default=None)
    ap.add_argument("--methods", nargs="+", default=["it+"], metavar="METHOD",
                    help="detector methods that segment the captures (default: the deliverable's it+)")
    ap.add_argument("--confirm", nargs="+", default=[CONFIRM_METHOD], metavar="METHOD",
                    help="the method confirming each component, as the deliverable does ('none': not confirmed); "
                         "several: a row for each")
    a = ap.parse_args()
    results = [run(n, s, m, None if c == "none" else c) for n, s in SCENARIOS.items() if a.only in (None, n)
               for m in a.methods for c in a.confirm]
    for folder in a.mission:
        path = folder / "inspection" / "accuracy.json"
        if not path.is_file():
            print(f"{folder}: no {path.relative_to(folder)} (a mission without a simulated wall or an older report)")
            continue
        doc = json.loads(path.read_text())
        rec = json.loads((folder / "record.json").read_text())
        name = (rec.get("scenario") or {}).get("name", "?")
        results.append({"scenario": f"{name} (mission {folder.name})", **doc["summary"], "rows": doc["rows"]})
    print("| wall | method | recall / precision (objects) | GSD (mm/px) | truth / found / on no crack | length error median / worst | "
          "mean width error (mm) median / worst | max width error (mm) median / worst | in true class | "
          "narrower than 1 px |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        print(line(r))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(results, indent=1))
    print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
