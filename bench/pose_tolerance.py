"""How much pose error the inspection deliverable takes: the nominal wall's captures at the planned shots, each
frame's camera position moved along the wall by a random offset, the deliverable rebuilt and scored.

    .venv/bin/python bench/pose_tolerance.py [--sigmas-m 0 0.01 0.02 0.03 0.05 0.1 0.2] [--seeds 3] [--placement-seeds 20]
                                             [--align-m 0 0.6]
                                             [--scenario monorail] [--out bench/results/pose_tolerance.json]

The mosaic places frames by their poses alone (docs/report.md, services/inspection/mosaic.py). The frames are
segmented once (IT+, each component confirmed by the learned model: the deliverable's own), then for each
standard deviation (metres, per axis of the wall plane) and seed every frame's ``cam_pos`` gets its own offset,
and the deliverable is built (``--align-m``: how far a frame may move to fit the others, 0 for none) and
compared with the wall's truth (services/inspection/accuracy.py): defects, true
cracks found, defects on no true crack, worst length error. Then the alignment alone over more seeds: how far each
frame ends up from where it belongs (less the mean pose error, which no alignment can see). Prints tables and
writes JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.world.wall import synthetic_surface  # noqa: E402
from protocol.scenario import load_scenario  # noqa: E402
from services.inspection.accuracy import compare, truth_cracks  # noqa: E402
from services.inspection.captures import decode, synthetic_captures  # noqa: E402
from services.inspection.deliverable import ALIGN_M, inspect_frames, segment  # noqa: E402
from services.inspection.mosaic import Plane, PosedFrame, build_mosaic, moved_camera  # noqa: E402


def offsets(n: int, sigma_m: float, seed: int) -> np.ndarray:
    """``n`` random (du, dv) camera offsets along the wall, N(0, sigma_m) per axis."""
    return np.random.default_rng(seed).normal(0.0, sigma_m, (n, 2))


def jittered(frames: list[PosedFrame], plane: Plane, sigma_m: float, seed: int) -> list[PosedFrame]:
    """``frames`` with each camera moved by its :func:`offsets` along ``plane``."""
    return [PosedFrame(moved_camera(f.meta, plane, float(du), float(dv)), f.grey, f.mask)
            for f, (du, dv) in zip(frames, offsets(len(frames), sigma_m, seed))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="monorail")
    ap.add_argument("--sigmas-m", type=float, nargs="+", default=[0.0, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per pose error for the whole deliverable")
    ap.add_argument("--placement-seeds", type=int, default=20, help="seeds per pose error for the alignment alone")
    ap.add_argument("--align-m", type=float, nargs="+", default=[0.0, ALIGN_M],
                    help="the deliverable's alignment limits to compare (0: frames placed by their poses alone)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "pose_tolerance.json")
    a = ap.parse_args()
    sc = load_scenario(a.scenario)
    surf = synthetic_surface(sc)
    plane = Plane.from_corners(surf.corners)
    t0 = time.perf_counter()
    seg = segment([PosedFrame(c.meta, decode(c)) for c in synthetic_captures(sc, surf)])
    s = 1.0 / surf.px_per_m
    truth, labels = truth_cracks(surf.mask, s)
    rows = []
    print("| alignment (m) | sigma (cm) | seed | defects | true cracks found | defects on no crack | worst length error |")
    print("|---|---|---|---|---|---|---|")
    for align in a.align_m:
        for sigma in a.sigmas_m:
            for seed in range(a.seeds if sigma > 0 else 1):
                res = inspect_frames(jittered(seg, plane, sigma, seed), plane, align_m=align)
                acc = compare(res.defects, truth, labels, s, gsd_m=res.mosaic.m_per_px).summary
                row = {"align_m": align, "sigma_m": sigma, "seed": seed, "defects": len(res.defects),
                       "truth": acc["truth"], "matched": acc["matched"], "unmatched_defects": acc["unmatched_defects"],
                       "length_error_worst": acc["length_error_worst"],
                       "moved_m_max": max(res.mosaic.moved_m, default=0.0)}
                rows.append(row)
                worst = "–" if row["length_error_worst"] is None else f"{100 * row['length_error_worst']:.1f} %"
                print(f"| {align:g} | {100 * sigma:g} | {seed} | {row['defects']} | {row['matched']} of {row['truth']} | "
                      f"{row['unmatched_defects']} | {worst} |", flush=True)
    # the alignment alone, over more seeds: how far each frame ends up from where it belongs (relative to the mean
    # pose error, which no alignment can see)
    placement = []
    m_per_px = res.mosaic.m_per_px
    print("\n| alignment (m) | sigma (cm) | seeds | seeds with a frame > 2 cm off | worst frame (cm) | median worst (cm) |")
    print("|---|---|---|---|---|---|")
    for align in (x for x in a.align_m if x > 0):
        for sigma in (x for x in a.sigmas_m if x > 0):
            worsts: list[float] = []
            for seed in range(a.placement_seeds):
                offs = offsets(len(seg), sigma, seed)
                shifts = build_mosaic(jittered(seg, plane, sigma, seed), plane, m_per_px, align).shifts_m
                got = np.array([(np.nan, np.nan) if d is None else d for d in shifts])
                want = -offs + offs.mean(0)
                worsts.append(float(np.nanmax(np.hypot(*(got - want).T))))
            row = {"align_m": align, "sigma_m": sigma, "seeds": a.placement_seeds,
                   "seeds_off_2cm": sum(w > 0.02 for w in worsts), "worst_m": max(worsts),
                   "median_worst_m": float(np.median(worsts))}
            placement.append(row)
            print(f"| {align:g} | {100 * sigma:g} | {row['seeds']} | {row['seeds_off_2cm']} | {100 * row['worst_m']:.1f} | "
                  f"{100 * row['median_worst_m']:.2f} |", flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"scenario": a.scenario, "frames": len(seg), "rows": rows, "placement": placement,
                                 "seconds": time.perf_counter() - t0}, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
