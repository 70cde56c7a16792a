"""The synthetic camera's cost per frame: render the view of the wall, then JPEG-encode it.

At 640x480 and 1280x960, for three kinds of pose on the default scenario's wall (seed of the
edges, 100 px/m): square-on at the (P2) stand-off of the default scenario (4.78 m, the shots of an
inspection pass), oblique (looking 50 degrees off the normal, part of the frame is sky), and far
(40 m away: the whole wall in view, rendered from the coarser texture levels). Goal: three UAVs at
a capture a second while the simulation runs, so well under 50 ms per frame.

    .venv/bin/python bench/camera.py [--frames 60] [--out bench/results/camera.json]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.geometry.camera import camera_model
from edge.geometry.optics import CameraPose
from edge.world.camera import SyntheticSource
from edge.world.wall import synthetic_surface
from protocol.imagecodec import encode_jpeg
from protocol.scenario import load_scenario


def poses(wall, kind: str, n: int) -> list[CameraPose]:
    uv = np.column_stack([np.linspace(3, wall.width_m - 3, n), np.full(n, wall.height_m / 2)])
    pts = wall.surface_to_world(uv)
    if kind == "square-on":
        return [CameraPose.facing(p, wall.normal, 4.78) for p in pts]
    if kind == "oblique":
        n_ = -wall.normal
        yaw = math.atan2(n_[1], n_[0]) + math.radians(50)
        return [CameraPose.looking(p + 4.78 * wall.normal, yaw) for p in pts]
    return [CameraPose.facing(wall.center, wall.normal, 40.0)] * n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--quality", type=int, default=85)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "camera.json"))
    args = parser.parse_args()
    sc = load_scenario()
    t0 = time.perf_counter()
    wall = synthetic_surface(sc)
    build_s = time.perf_counter() - t0
    rows = []
    for size in ((640, 480), (1280, 960)):
        src = SyntheticSource(wall, camera_model(sc, size))
        for kind in ("square-on", "oblique", "far"):
            ps = poses(wall, kind, args.frames)
            src.grab(ps[0], 0.0)  # builds any texture level this pose needs, once
            render, encode, sizes = [], [], []
            for p in ps:
                t1 = time.perf_counter()
                frame = src.grab(p, 0.0)
                t2 = time.perf_counter()
                jpeg = encode_jpeg(frame.image, args.quality)
                t3 = time.perf_counter()
                render.append(t2 - t1)
                encode.append(t3 - t2)
                sizes.append(len(jpeg))
            rows.append({"size": f"{size[0]}x{size[1]}", "pose": kind,
                         "render_ms": 1e3 * statistics.median(render),
                         "encode_ms": 1e3 * statistics.median(encode),
                         "total_p95_ms": 1e3 * float(np.percentile(np.add(render, encode), 95)),
                         "jpeg_kB": statistics.median(sizes) / 1e3})
    print(f"wall texture {wall.texture.shape[1]}x{wall.texture.shape[0]} px built in {build_s:.2f} s, "
          f"{len(wall.defects())} ground-truth cracks; JPEG quality {args.quality}, {args.frames} frames each")
    print("| frame | pose | render (ms, median) | JPEG encode (ms, median) | total p95 (ms) | JPEG (kB) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['size']} | {r['pose']} | {r['render_ms']:.2f} | {r['encode_ms']:.2f} | "
              f"{r['total_p95_ms']:.2f} | {r['jpeg_kB']:.0f} |")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"surface_build_s": build_s, "quality": args.quality, "rows": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
