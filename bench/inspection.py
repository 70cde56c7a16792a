"""Inspection deliverable benchmark: mosaic / segmentation / measurement time for one mission's
captures, and the size errors against a synthetic wall whose cracks have known lengths and widths.

    .venv/bin/python bench/inspection.py [--out bench/results/inspection.json]

The captures are rendered off the bus at the scenario's planned shots
(:func:`services.inspection.captures.synthetic_captures`, 26 frames of 640 x 480 for the default
scenario), on a wall of straight cracks 2..6 texture pixels (2..6 cm) wide and 1..2.5 m long.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.scenario import load_scenario  # noqa: E402
from services.inspection.captures import decode, known_crack_wall, synthetic_captures  # noqa: E402
from services.inspection.deliverable import inspect_frames  # noqa: E402
from services.inspection.mosaic import Plane, PosedFrame  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "inspection.json")
    ap.add_argument("--method", default="it+")
    a = ap.parse_args()
    sc = load_scenario()
    surf, truth = known_crack_wall(sc)
    caps = synthetic_captures(sc, surf)
    frames = [PosedFrame(c.meta, decode(c)) for c in caps]
    runs = [inspect_frames(frames, Plane.from_corners(surf.corners), method=a.method) for _ in range(3)]
    res = runs[-1]
    px = res.mosaic.m_per_px
    rows = []
    for u, v, length, width in truth:
        d = min(res.defects, key=lambda d: (d.u_m - u) ** 2 + (d.v_m - v) ** 2)
        rows.append({"u": u, "v": v, "length_m": length, "width_mm": 1e3 * width, "meas_length_m": d.length_m,
                     "meas_width_mean_mm": d.width_mean_mm, "meas_width_max_mm": d.width_max_mm,
                     "length_err_pct": 100 * (d.length_m / length - 1),
                     "width_err_px": (d.width_mean_mm / 1e3 - width) / px})
    le = np.array([r["length_err_pct"] for r in rows])
    we = np.array([r["width_err_px"] for r in rows])
    secs = {k: float(np.median([r.seconds[k] for r in runs])) for k in runs[0].seconds}
    print(f"{len(frames)} frames -> mosaic {res.mosaic.image.shape[1]}x{res.mosaic.image.shape[0]} px at "
          f"{px * 1e3:.1f} mm/px; median of 3 runs: " + ", ".join(f"{k} {v:.2f} s" for k, v in secs.items()))
    print("\n| length m | width mm | measured length m | err % | mean width mm | err px |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['length_m']:.2f} | {r['width_mm']:.0f} | {r['meas_length_m']:.3f} | {r['length_err_pct']:+.1f} | "
              f"{r['meas_width_mean_mm']:.1f} | {r['width_err_px']:+.2f} |")
    ok = (np.abs(le) <= 5) & (np.abs(we) <= 1)
    print(f"\nwithin 5 % length and 1 px width: {int(ok.sum())} of {len(rows)}; median |length err| "
          f"{np.median(np.abs(le)):.1f} %, median |width err| {np.median(np.abs(we)):.2f} px")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"seconds": secs, "m_per_px": px, "frames": len(frames), "rows": rows,
                                 "within": int(ok.sum())}, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
