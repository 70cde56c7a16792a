"""The synthetic camera's cost per frame: render the view of the wall, then JPEG-encode it.

At 640x480 and 1280x960, from poses along the inspection pass of the default scenario.
Goal (for three UAVs at a capture a second while the simulation runs): well under 50 ms.

    .venv/bin/python bench/camera.py [--out bench/results/camera.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.camera import CameraPose, SyntheticSource, encode_jpeg  # noqa: E402
from edge.runtime import camera_model, camera_rotation, scenario_doc, synthetic_surface  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "camera.json"))
    args = parser.parse_args()
    sc = scenario_doc(None)
    t0 = time.perf_counter()
    wall = synthetic_surface(sc)
    build_s = time.perf_counter() - t0
    # poses 4.78 m in front of the wall, along its length, looking at it
    n = -wall.normal
    yaw = float(np.arctan2(n[1], n[0]))
    uv = np.column_stack([np.linspace(2, wall.width_m - 2, args.frames), np.full(args.frames, wall.height_m / 2)])
    positions = wall.surface_to_world(uv) + 4.78 * wall.normal
    rows = []
    for size in ((640, 480), (1280, 960)):
        src = SyntheticSource(wall, camera_model(sc, size))
        render, encode = [], []
        for p in positions:
            t1 = time.perf_counter()
            frame = src.grab(CameraPose(p, camera_rotation(yaw)), 0.0)
            t2 = time.perf_counter()
            encode_jpeg(frame.image, 85)
            t3 = time.perf_counter()
            render.append(t2 - t1)
            encode.append(t3 - t2)
        row = {"size": f"{size[0]}x{size[1]}", "render_ms": 1e3 * statistics.median(render),
               "encode_ms": 1e3 * statistics.median(encode),
               "total_p95_ms": 1e3 * float(np.percentile(np.add(render, encode), 95))}
        rows.append(row)
    print(f"wall texture {wall.texture.shape[1]}x{wall.texture.shape[0]} px built in {build_s:.2f} s, "
          f"{len(wall.defects())} ground-truth cracks")
    print("| frame | render (ms, median) | JPEG encode (ms, median) | total p95 (ms) |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['size']} | {r['render_ms']:.2f} | {r['encode_ms']:.2f} | {r['total_p95_ms']:.2f} |")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"surface_build_s": build_s, "rows": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
