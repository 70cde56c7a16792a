"""Detector scaling benchmark: capture->report latency for bursts of simultaneous frames.

A real gateway and real ``skynet detector`` processes on loopback; a sender node plays N UAVs whose
cameras each send one capture at the same instant (a formation reaching its capture points together).
Every configuration runs at once, each on a fleet of its own, and their bursts take turns, ``--gap``
seconds apart, ``--bursts`` rounds (so a change in the machine's load falls on all of them):

* ``1 process``: one instance, ``--workers 1`` (one detection process);
* ``2 processes``: one instance, ``--workers 2``;
* ``2 instances x 1``: ``--partition 0/2`` and ``1/2``, one worker process each.

Reports per configuration: frames sent, reports received (each exactly once?), capture->report p50/p95/max
(report stamp minus the capture stamp the sender put in the frame's metadata; one machine, one clock) and
the wall time of a burst's last report. Frames go on the reliable imagery class so that loss does not
mix into the figures. Prints a Markdown table and writes JSON (bench/results/ is git-ignored).

    .venv/bin/python bench/detect_scale.py [--uavs 16] [--bursts 8] [--gap 2.0] [--size 640x480]
                                           [--configs 1 2 2x1] [--out bench/results/detect_scale.json]

On 2 cores shared with other work the figures move from run to run: compare the rows of one run.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edge.world.surface import crack_image  # noqa: E402
from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig, multilink_endpoints  # noqa: E402
from protocol.imagery import pack_image  # noqa: E402
from protocol.links import IMAGERY_RELIABLE  # noqa: E402
from protocol.messages import DefectReport, ImageMeta, Intrinsics  # noqa: E402
from protocol.rtp import RtpSender, ssrc_for  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port_pair  # noqa: E402

FLEET = "bench"
CONFIGS = {"1": [(None, 1)], "2": [(None, 2)], "2x1": [("0/2", 1), ("1/2", 1)]}
LABEL = {"1": "1 process", "2": "2 processes", "2x1": "2 instances x 1 process"}


def _meta(uav: int, cid: int, w: int, h: int, stamp: float) -> ImageMeta:
    return ImageMeta(uav=uav, capture_id=cid, t=float(cid), stamp=stamp, cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=w, height=h, fx=500, fy=500, cx=w / 2, cy=h / 2), range_m=5.0)


class Config:
    """One configuration's detector processes (on a fleet of its own) and what its reports said."""

    def __init__(self, name: str, args, endpoints: list[str], group: ProcessGroup):
        self.name, self.args, self.fleet = name, args, f"bench{name.replace('x', 'i')}"
        self.instances = CONFIGS[name]
        self.procs = []
        for i, (part, workers) in enumerate(self.instances):
            extra = [] if part is None else ["--partition", part, "--uavs", str(args.uavs)]
            self.procs.append(group.start(f"det-{name}-{i}", [
                "detector", "--fleet", self.fleet, "--multilink", "--workers", str(workers), *extra,
                *[a for e in endpoints for a in ("--connect", e)]]))
        self.reports: list[DefectReport] = []
        self.lock = threading.Lock()
        self.bursts: list[float] = []
        self.sent = 0

    def attach(self, bus: Bus) -> None:
        for svc in self.procs:
            if not svc.wait_for("detector up", 90):
                raise RuntimeError("\n".join(svc.lines[-20:]))
        bus.subscribe(keys.defects(self.fleet), self._on_report, expect=DefectReport)
        names = ["detector"] if len(self.instances) == 1 else [f"detector-{k}" for k in range(len(self.instances))]
        deadline = time.monotonic() + 20
        while not all(bus.alive(keys.rcu_alive(self.fleet, n)) for n in names) and time.monotonic() < deadline:
            time.sleep(0.1)
        self.pubs = {u: bus.publisher(keys.camera(self.fleet, u), IMAGERY_RELIABLE)
                     for u in range(1, self.args.uavs + 1)}
        self.senders = {u: RtpSender(ssrc_for(u)) for u in self.pubs}

    def _on_report(self, m: DefectReport, s) -> None:
        with self.lock:
            self.reports.append(m)

    def burst(self, b: int, jpegs: list[bytes]) -> None:
        w, h = self.args.size
        self.bursts.append(time.time())
        for u, pub in self.pubs.items():  # every UAV at its capture point together
            now = time.time()
            jpeg = jpegs[(b * self.args.uavs + u) % len(jpegs)]
            pub.put_bytes(pack_image(self.senders[u], _meta(u, b, w, h, now), jpeg, now))
            self.sent += 1

    def done(self) -> bool:
        with self.lock:
            return len(self.reports) >= self.sent

    def row(self) -> dict:
        with self.lock:
            got = list(self.reports)
        lat = np.array([1000 * (m.stamp_report - m.stamp_capture) for m in got if m.ok])
        seen = Counter((m.uav, m.capture_id) for m in got)
        last = []
        for b, t0 in enumerate(self.bursts):
            ts = [m.stamp_report for m in got if m.capture_id == b]
            if ts:
                last.append(1000 * (max(ts) - t0))
        return {"config": self.name, "label": LABEL[self.name], "instances": len(self.instances),
                "processes": sum(wk for _, wk in self.instances), "sent": self.sent, "reports": len(got),
                "distinct": len(seen), "duplicates": sum(c - 1 for c in seen.values()),
                "p50_ms": float(np.percentile(lat, 50)) if len(lat) else None,
                "p95_ms": float(np.percentile(lat, 95)) if len(lat) else None,
                "max_ms": float(lat.max()) if len(lat) else None,
                "burst_last_report_ms_median": float(np.median(last)) if last else None}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--uavs", type=int, default=16)
    ap.add_argument("--bursts", type=int, default=8)
    ap.add_argument("--gap", type=float, default=2.0, help="seconds between bursts")
    ap.add_argument("--size", type=lambda s: tuple(int(v) for v in s.lower().split("x")), default=(640, 480))
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--out", default="bench/results/detect_scale.json")
    args = ap.parse_args()
    rng = np.random.default_rng(18)
    w, h = args.size
    jpegs = [cv2.imencode(".jpg", crack_image((h, w), rng, n_cracks=3)[0], [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
             for _ in range(8)]
    group = ProcessGroup(echo=None)
    rows = []
    try:
        tcp, udp = free_port_pair()
        endpoints = multilink_endpoints("127.0.0.1", tcp, udp)
        gw = group.start("gateway", ["gateway", "--fleet", FLEET, "--multilink",
                                     *[a for e in endpoints for a in ("--listen", e)]])
        if not gw.wait_for("router up", 30):
            raise RuntimeError("\n".join(gw.lines[-20:]))
        configs = [Config(name, args, endpoints, group) for name in args.configs]  # all started up front
        with Bus(BusConfig(mode="client", connect=endpoints, multilink=True), "bench", "bench-uavs") as bus:
            for c in configs:
                c.attach(bus)
            time.sleep(1.0)
            for b in range(args.bursts):  # the configurations' bursts take turns: the same load on each
                for c in configs:
                    c.burst(b, jpegs)
                    time.sleep(args.gap)
            deadline = time.monotonic() + 30
            while not all(c.done() for c in configs) and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.5)
        rows = [c.row() for c in configs]
    finally:
        group.stop()
    print(f"\nBursts of {args.uavs} simultaneous {w}x{h} captures, {args.bursts} bursts {args.gap} s apart "
          f"({platform.node()}, {len(__import__('os').sched_getaffinity(0))} cores)\n")
    print("| configuration | sent | reports | duplicates | p50 ms | p95 ms | max ms | burst done, median ms |")
    print("|---|---|---|---|---|---|---|---|")
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    for r in rows:
        print(f"| {r['label']} | {r['sent']} | {r['reports']} | {r['duplicates']} | {fmt(r['p50_ms'])} | "
              f"{fmt(r['p95_ms'])} | {fmt(r['max_ms'])} | {fmt(r['burst_last_report_ms_median'])} |")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"uavs": args.uavs, "bursts": args.bursts, "gap_s": args.gap, "size": [w, h],
                               "rows": rows}, indent=2))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
