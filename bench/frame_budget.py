"""Where a 12 MP capture's time goes between the camera and the defect report.

Each step of the path timed on its own, on this machine (median of ``--repeat`` runs): the edge's
JPEG encode (quality 85) of a 4000x3000 grey frame of cracks; its transfer as one 12 MP sample on
the reliable link (a Zenoh router and two client sessions on loopback, TCP); the detector's
decode, full size and DCT-reduced (1/2, 1/4); detection (IT+) on each; the report (mapping to the
wall). The figures of a mission (queueing, playout, several UAVs at once) are bench/scale.py's.

    .venv/bin/python bench/frame_budget.py [--repeat 3] [--out bench/results/frame_budget.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from edge.world.surface import crack_image  # noqa: E402
from protocol.imagecodec import decode_image, encode_jpeg  # noqa: E402
from protocol.messages import ImageMeta, Intrinsics  # noqa: E402
from services.detector.detect import detect  # noqa: E402
from services.detector.pipeline import MIN_REPORT_AREA_PX, scaled, to_report  # noqa: E402


def timed(fn, repeat: int) -> tuple[object, float]:
    out, ts = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        ts.append(1000 * (time.perf_counter() - t0))
    return out, statistics.median(ts)


def zenoh_transfer_ms(payload: bytes, repeat: int) -> float:
    import zenoh

    from services.orchestration.process import free_port

    port = free_port()

    def cfg(mode: str, key: str) -> zenoh.Config:
        c = zenoh.Config()
        c.insert_json5("mode", json.dumps(mode))
        c.insert_json5(key, json.dumps([f"tcp/127.0.0.1:{port}"]))
        c.insert_json5("scouting/multicast/enabled", "false")
        return c

    router = zenoh.open(cfg("router", "listen/endpoints"))
    rx, tx = zenoh.open(cfg("client", "connect/endpoints")), zenoh.open(cfg("client", "connect/endpoints"))
    got = threading.Event()
    sub = rx.declare_subscriber("bench/frame", lambda s: got.set())
    pub = tx.declare_publisher("bench/frame", reliability=zenoh.Reliability.RELIABLE,
                               congestion_control=zenoh.CongestionControl.BLOCK)
    time.sleep(0.5)
    ts = []
    for _ in range(repeat + 1):
        got.clear()
        t0 = time.perf_counter()
        pub.put(payload)
        got.wait(10)
        ts.append(1000 * (time.perf_counter() - t0))
    sub.undeclare()
    for s in (tx, rx, router):
        s.close()
    return statistics.median(ts[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "frame_budget.json"))
    args = parser.parse_args()
    grey, _ = crack_image((3000, 4000), np.random.default_rng(0), n_cracks=3, width_px=(4.0, 8.0))
    meta = ImageMeta(uav=1, capture_id=0, t=0.0, stamp=time.time(), cam_pos=(55.0, 60.0, 28.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=4000, height=3000, fx=3822, fy=3822, cx=2000, cy=1500), range_m=4.78)
    rows = {}
    jpeg, rows["edge encode (q85)"] = timed(lambda: encode_jpeg(grey, 85), args.repeat)
    rows["transfer, reliable (loopback)"] = zenoh_transfer_ms(jpeg, args.repeat)
    for f in (1, 2, 4):
        img, rows[f"decode 1/{f}"] = timed(lambda f=f: decode_image(jpeg, grey=True, reduce=f), args.repeat)
        det, rows[f"detect it+ 1/{f} ({img.shape[1]}x{img.shape[0]})"] = timed(
            lambda img=img, f=f: detect(img, "it+", min_defect_area=max(1, MIN_REPORT_AREA_PX // (f * f))),
            max(1, args.repeat if f > 1 else 1))
        _, rows[f"report 1/{f} ({len(det.defects)} defects)"] = timed(lambda det=det, f=f: to_report(meta, scaled(det, f)),
                                                                       args.repeat)
    print(f"12 MP JPEG: {len(jpeg) / 1024:.0f} KB\n\n| step | ms (median) |\n|---|---|")
    for k, v in rows.items():
        print(f"| {k} | {v:.1f} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"jpeg_bytes": len(jpeg), "ms": rows}, indent=1))


if __name__ == "__main__":
    main()
