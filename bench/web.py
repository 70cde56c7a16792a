"""The live web page: WebSocket update rate, snapshot size and server CPU with 3 and 12 UAVs.

A gateway and a ``skynet web`` process run as in a deployment; this script publishes N UAVs'
states at 20 Hz and previews at 2 Hz (and a defect report a second) on the bus, while a
WebSocket client (aiohttp) reads the page's feed as a browser would (with the page's access token,
handed to the process in its environment). Figures: snapshots per
second received, mean snapshot size, the web process's CPU (user+system over wall time).

    .venv/bin/python bench/web.py [--seconds 20] [--out bench/results/web.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig, multilink_endpoints  # noqa: E402
from protocol.imagery import pack_image  # noqa: E402
from protocol.links import COMMAND, IMAGERY, TELEMETRY  # noqa: E402
from protocol.messages import Defect, DefectReport, ImageMeta, Intrinsics, Mode, VehicleState  # noqa: E402
from protocol.rtp import RtpSender, ssrc_for  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port, free_port_pair  # noqa: E402
from services.web.server import TOKEN_ENV, new_token  # noqa: E402


def cpu_s(pid: int) -> float:
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def feed(bus: Bus, n: int, stop: threading.Event) -> None:
    st = {u: bus.publisher(keys.state("bench", u), TELEMETRY) for u in range(1, n + 1)}
    pv = {u: bus.publisher(keys.preview("bench", u), IMAGERY) for u in st}
    snd = {u: RtpSender(ssrc_for(u, 1)) for u in st}
    dp = bus.publisher(keys.defects("bench"), COMMAND)
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 120, np.uint8))[1].tobytes()
    k, t0 = 0, time.monotonic()
    while not stop.is_set():
        now = time.time()
        for u, pub in st.items():
            pos = (20.0 + u, 10.0 + 0.1 * k, 25.0)
            pub.put(VehicleState(uav=u, seq=k, t=k * 0.05, stamp=now, pos=pos, vel=(0, 2, 0), att=(0, 0, 0),
                                 rates=(0, 0, 0), mode=Mode.MISSION, ref=pos, tau=k * 0.05))
            if k % 10 == u % 10:
                meta = ImageMeta(uav=u, capture_id=0, t=0.0, stamp=now, cam_pos=pos, cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                                 intrinsics=Intrinsics(width=320, height=240, fx=300.0, fy=300.0, cx=160.0, cy=120.0))
                pv[u].put_bytes(pack_image(snd[u], meta, jpeg, now))
        if k % 20 == 0:
            d = Defect(area_px=9, bbox=(0, 0, 3, 3), centroid_px=(1.0, 1.0), contrast=3.0, pos=(60.0, 40.0 + k % 40, 28.0))
            dp.put(DefectReport(uav=1, capture_id=k, stamp_capture=now, stamp_report=now, method="it+", defects=[d] * 3))
        k += 1
        time.sleep(max(0.0, t0 + k * 0.05 - time.monotonic()))


async def read_ws(url: str, seconds: float) -> tuple[int, int, int]:
    import aiohttp

    n = size = static = 0
    async with aiohttp.ClientSession() as s, s.ws_connect(url) as ws:
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            msg = await ws.receive(timeout=5)
            doc = json.loads(msg.data)
            if doc["type"] == "snapshot":
                n += 1
                size += len(msg.data)
            else:
                static += 1
    return n, size, static


def run(n: int, seconds: float) -> dict:
    group = ProcessGroup(echo=None)
    stop = threading.Event()
    try:
        tcp, udp = free_port_pair()
        ends = multilink_endpoints("127.0.0.1", tcp, udp)
        gw = group.start("gateway", ["gateway", "--fleet", "bench", "--multilink", *[a for e in ends for a in ("--listen", e)]])
        assert gw.wait_for("router up", 30)
        port = free_port()
        token = new_token()
        group.env[TOKEN_ENV] = token
        web = group.start("web", ["web", "--fleet", "bench", "--multilink", "--web", f"127.0.0.1:{port}",
                                  *[a for e in ends for a in ("--connect", e)]])
        assert web.wait_for("web up", 30), web.lines
        with Bus(BusConfig(mode="client", connect=ends, multilink=True), "bench", "uavs") as bus:
            th = threading.Thread(target=feed, args=(bus, n, stop), daemon=True)
            th.start()
            time.sleep(2.0)
            c0, t0 = cpu_s(web.proc.pid), time.monotonic()
            snaps, size, _ = asyncio.run(read_ws(f"http://127.0.0.1:{port}/ws?token={token}", seconds))
            wall = time.monotonic() - t0
            cpu = cpu_s(web.proc.pid) - c0
            stop.set()
            th.join(3)
        return {"uavs": n, "seconds": round(wall, 1), "updates_per_s": round(snaps / wall, 2),
                "snapshot_kB": round(size / max(1, snaps) / 1000, 1), "server_cpu_percent": round(100 * cpu / wall, 1)}
    finally:
        stop.set()
        group.stop()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--out", default=str(ROOT / "bench/results/web.json"))
    args = ap.parse_args()
    rows = [run(n, args.seconds) for n in (3, 12)]
    print(f"{'uavs':>4} {'updates/s':>9} {'snapshot kB':>11} {'server CPU %':>12}")
    for r in rows:
        print(f"{r['uavs']:>4} {r['updates_per_s']:>9} {r['snapshot_kB']:>11} {r['server_cpu_percent']:>12}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
