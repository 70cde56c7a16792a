"""Where a 12 MP capture's time goes from the shutter to the ground station, before vs after.

Two parts, one run:

1. **Steps** (in this process, median of ``--repeat``): the mission's own 12 MP frame of the wall
   (the default scenario's camera at its 4.78 m stand-off, :func:`edge.world.wall.synthetic_surface`)
   rendered as before (one warp at the frame size, with the ground-truth mask) and as the edge does
   now (``SyntheticSource(mask=False, upsample=True)``); its JPEG encode (q85, as the edge);
   the detector's decode and the whole analysis (decode, IT+r, report) at 1/2 (the old budget,
   3 MP) and 1/4 (the default, 1 MP) and 1/8; the ground station's own look at the frame (and at a 640x480
   one), and a 333-byte JPEG declaring 30000 x 30000 px refused from its header against OpenCV's decode of it.
2. **Missions** (``skynet mission --uavs 3 --frame-size 4000x3000``, capture frames on the reliable
   link) at each ``--speeds``, with ``--baseline`` (a checkout of the tree before these changes,
   e.g. ``git archive <commit> | tar -x -C DIR``; run with this venv, its modules first on the path)
   and this tree side by side: capture->report p50/p95 (``stamp_report - stamp_capture``, the
   report's figure), frames lost and recovered, report->ground station p95, and -- from the
   ``frame path`` lines the edges and the detector log (:mod:`protocol.stages`) -- p50/p95 of each
   stage: render (shutter to rendered), encode (encoder queue + encode), publish, shutter->sent,
   shutter->arrival at the detector, queue (playout hold + detector queue), worker (decode,
   detect, map in a worker process, with the trip there and back), shutter->published.

The capture stamp is the edge's wall clock when its control loop sees the capture point: the span
includes the synthetic camera's render (a real camera's exposure and read-out) and its JPEG encode
(a real camera also delivers JPEG; it encodes in hardware).

    .venv/bin/python bench/frame_path.py [--speeds 4 1] [--baseline DIR] [--extra='--detectors 3'] [--repeat 3]
                                         [--no-missions] [--out bench/results/frame_path.json]

Heavy: each mission is ~1-2 minutes of the whole machine. Never run in tests.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
from frame_budget import timed  # noqa: E402  (bench/frame_budget.py)
from mission import find, write_rows  # noqa: E402  (bench/mission.py)

FRAME = "4000x3000"


def steps(repeat: int) -> dict[str, float]:
    from edge.geometry.camera import camera_model, camera_rotation
    from edge.geometry.optics import CameraPose
    from edge.world.camera import SyntheticSource
    from edge.world.wall import synthetic_surface
    from protocol.imagecodec import decode_image, encode_jpeg
    from protocol.messages import ImageMeta, Intrinsics
    from protocol.scenario import load_scenario
    from services.detector.pipeline import analyse

    sc = load_scenario(None)
    wall, cam = synthetic_surface(sc), camera_model(sc, (4000, 3000))
    th, tw = wall.shape_px
    pos = wall.pixel_to_world_matrix() @ np.array([tw / 2, th / 2, 1.0]) + 4.78 * wall.normal
    R = camera_rotation(math.atan2(-wall.normal[1], -wall.normal[0]))
    pose = CameraPose(position=pos, rotation=R)
    rows: dict[str, float] = {}
    before, after = SyntheticSource(wall, cam), SyntheticSource(wall, cam, mask=False, upsample=True)
    before.grab(pose, 0.0), after.grab(pose, 0.0)
    _, rows["render, before (warp 12 MP + mask)"] = timed(lambda: before.grab(pose, 0.0), repeat)
    frame, rows["render, after (warp 0.75 MP, resize, no mask)"] = timed(lambda: after.grab(pose, 0.0), repeat)
    jpeg, rows["encode q85"] = timed(lambda: encode_jpeg(frame.image, 85), repeat)
    rows["jpeg KB"] = len(jpeg) / 1024
    fx, fy, cx, cy = cam.intrinsics()
    meta = ImageMeta(uav=1, capture_id=1, t=0.0, stamp=time.time(), cam_pos=tuple(pos), cam_rot=tuple(R.ravel()),
                     intrinsics=Intrinsics(width=4000, height=3000, fx=fx, fy=fy, cx=cx, cy=cy), range_m=4.78)
    for f, mp in ((2, 3.0), (4, 1.0), (8, 0.3)):
        _, rows[f"decode 1/{f}"] = timed(lambda f=f: decode_image(jpeg, grey=True, reduce=f), repeat)
        rep, rows[f"analyse it+r 1/{f} (--detect-max-mp {mp})"] = timed(
            lambda mp=mp: analyse(meta, jpeg, "it+r", max_pixels=int(mp * 1e6)), repeat)
        rows[f"  longest crack 1/{f}, m"] = max((d.length_m or 0.0 for d in rep.defects), default=0.0)
    rows.update(surface_look(meta, jpeg, repeat))
    return rows


def surface_look(meta, jpeg: bytes, repeat: int) -> dict[str, float]:  # noqa: ANN001
    """The ground station's look at each capture it receives (services.gcs.surface, on its receiving thread) for
    this frame and a 640x480 one, and a 333-byte JPEG declaring 30000 x 30000 px: refused from its header now,
    what OpenCV made of it before (once: seconds and ~1 GB)."""
    import cv2

    from protocol.imagecodec import decode_image, encode_jpeg
    from services.gcs.surface import surface_problem

    rows: dict[str, float] = {}
    _, rows["ground station's look, 12 MP (surface_problem)"] = timed(lambda: surface_problem(meta, jpeg), repeat)
    vga = encode_jpeg(cv2.resize(decode_image(jpeg, grey=True, reduce=4), (640, 480), interpolation=cv2.INTER_AREA))
    k = meta.intrinsics
    small = meta.model_copy(update={"intrinsics": k.model_copy(update={"width": 640, "height": 480})})
    _, rows["ground station's look, 640x480"] = timed(lambda: surface_problem(small, vga), repeat)
    bomb = bytearray(encode_jpeg(np.zeros((8, 8), np.uint8)))
    i = bomb.find(b"\xff\xc0")
    bomb[i + 5:i + 9] = (30000).to_bytes(2, "big") + (30000).to_bytes(2, "big")
    rows["30000x30000 bomb, bytes"] = float(len(bomb))

    def refused() -> str:
        try:
            decode_image(bytes(bomb), grey=True, size=(640, 480))
        except ValueError as exc:
            return str(exc)
        raise AssertionError("the bomb was decoded")

    _, rows["30000x30000 bomb, refused from its header"] = timed(refused, repeat)
    _, rows["30000x30000 bomb, cv2.imdecode as before (once)"] = timed(
        lambda: cv2.imdecode(np.frombuffer(bytes(bomb), np.uint8), cv2.IMREAD_GRAYSCALE), 1)
    return rows


def stage_lines(log: str) -> dict[str, dict]:
    """The ``frame path <owner> {json}`` lines of a mission's services.log, by owner."""
    out = {}
    for m in re.finditer(r"frame path (\S+) (\{.*\})\s*$", log, re.M):
        try:
            out[m.group(1)] = json.loads(m.group(2))
        except json.JSONDecodeError:
            continue
    return out


def mission(speed: float, out: Path, checkout: Path | None, extra: list[str]) -> dict:
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "services.cli", "mission", "--uavs", "3", "--speed", str(speed), "--quiet",
           "--frame-size", FRAME, "--capture-link", "reliable", "--out", str(out), *extra]
    env = dict(os.environ, PYTHONPATH=str(checkout)) if checkout else None
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=checkout, env=env)
    rep = json.loads((out / "report.json").read_text()) if (out / "report.json").exists() else {}
    cams = [v for k, v in (rep.get("imagery") or {}).items() if isinstance(v, dict) and k.endswith(".cam0")]
    log = (out / "services.log").read_text(errors="replace") if (out / "services.log").exists() else ""
    lines = stage_lines(log)
    edges = [v for k, v in lines.items() if k.startswith("uav")]
    stages = {}
    for name in ("render", "encode", "publish", "shutter-to-sent"):  # worst edge
        got = [e[name] for e in edges if name in e]
        if got:
            stages[f"edge {name}"] = {"p50": max(g["p50"] for g in got), "p95": max(g["p95"] for g in got)}
    for owner, v in lines.items():
        if not owner.startswith("uav"):
            stages.update({f"{owner} {k}": {"p50": s["p50"], "p95": s["p95"]} for k, s in v.items()})
    return {"speed": speed, "tree": str(checkout) if checkout else "this", "args": extra, "exit": proc.returncode,
            "success": rep.get("success"), "wall_s": time.perf_counter() - t0, "captures": rep.get("captures") if isinstance(rep.get("captures"), int) else len(rep.get("captures") or []),
            "capture_to_report_p50_ms": find(rep, "links", "imagery", "latency_ms", "p50"),
            "capture_to_report_p95_ms": find(rep, "links", "imagery", "latency_ms", "p95"),
            "reports": find(rep, "links", "imagery", "latency_ms", "n"),
            "report_to_gs_p95_ms": find(rep, "links", "defect_reports", "latency_ms", "p95"),
            "frames_recovered": sum(c.get("recovered", 0) for c in cams),
            "frames_lost": sum(c.get("lost", 0) for c in cams), "stages": stages,
            **({"tail": proc.stdout[-1500:]} if proc.returncode else {})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", type=float, nargs="*", default=[4.0, 1.0])
    parser.add_argument("--baseline", type=Path, default=None, help="checkout of the tree before (its modules)")
    parser.add_argument("--extra", type=shlex.split, default=[],
                        help="more mission options for this tree's runs, one string; without --baseline, this tree "
                             "also runs without them, side by side (e.g. --extra='--detectors 3')")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-missions", action="store_true")
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "frame_path.json"))
    args = parser.parse_args()
    rows = steps(args.repeat)
    print("| step (one 12 MP frame, this process) | ms (median) |\n|---|---|")
    for k, v in rows.items():
        print(f"| {k} | {v:.2f} |" if k.endswith(", m") else f"| {k} | {v:.1f} |")
    runs = []
    if not args.no_missions:
        with tempfile.TemporaryDirectory() as tmp:
            for i, speed in enumerate(args.speeds):
                # the baseline tree, or (without one) this tree without --extra, then this tree with --extra
                pairs = [(args.baseline, [])] if args.baseline else ([(None, [])] if args.extra else [])
                for j, (checkout, extra) in enumerate([*pairs, (None, args.extra)]):
                    row = mission(speed, Path(tmp) / f"run-{i}-{j}", checkout, extra)
                    runs.append(row)
                    print(json.dumps(row), flush=True)
        print("\n| tree | speed | success | reports | capture->report p50 / p95 ms | lost / recovered "
              "| report->GS p95 ms |\n|---|---|---|---|---|---|---|")
        for r in runs:
            print(f"| {'before' if r['tree'] != 'this' else 'after'} {' '.join(r['args'])} | {r['speed']:g}x | "
                  f"{r['success']} | {r['reports']} | {r['capture_to_report_p50_ms'] or math.nan:.0f} / "
                  f"{r['capture_to_report_p95_ms'] or math.nan:.0f} | {r['frames_lost']:.0f} / "
                  f"{r['frames_recovered']:.0f} | {r['report_to_gs_p95_ms'] or math.nan:.1f} |")
        for r in runs:
            if r["stages"]:
                print(f"\nstages, {r['tree']} {r['speed']:g}x {' '.join(r['args'])} (ms p50 / p95):")
                for k, s in r["stages"].items():
                    print(f"  {k}: {s['p50']:.0f} / {s['p95']:.0f}")
    write_rows([{"steps_ms": rows}, *runs], args.out)


if __name__ == "__main__":
    main()
