"""``skynet video``: end-to-end latency capture -> decoded picture, and CPU per stream.

A gateway and a ``skynet video`` process run as in a deployment; this script publishes N UAVs'
preview streams (320x240 colour, numbered with a bar code, ``--hz`` pictures a second each) on
the bus, and decodes UAV 1's stream from its SDP file with FFmpeg (PyAV), as a player would.
Latency = the wall time a picture comes out of the decoder minus its capture stamp (the same
clock: one machine). Two H.264 receivers: FFmpeg's SDP demuxer (its H.264 parser releases a
picture only when the next one begins: one picture period more), and GStreamer's rtph264depay
(releases each access unit on the RTP marker bit) into FFmpeg's decoder. CPU = the video process's user+system time over the run, per stream.

    .venv/bin/python bench/video.py [--seconds 20] [--out bench/results/video.json]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig, multilink_endpoints  # noqa: E402
from protocol.imagery import pack_image  # noqa: E402
from protocol.links import IMAGERY  # noqa: E402
from protocol.messages import ImageMeta, Intrinsics  # noqa: E402
from protocol.rtp import RtpSender, ssrc_for  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port, free_port_pair  # noqa: E402
from tests.services.video.test_service import picture, read_number  # noqa: E402


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    import os

    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def gst_receiver(port: int, stamps: dict, lat: list, stop: threading.Event) -> subprocess.Popen:
    """GStreamer's rtph264depay (one access unit per buffer, on the marker bit) into FFmpeg's decoder
    without its parser: what a marker-driven player (GStreamer, as QGroundControl uses) waits for."""
    import av

    proc = subprocess.Popen([shutil.which("gst-launch-1.0"), "-q", "udpsrc", f"port={port}",
                             "caps=application/x-rtp,media=video,clock-rate=90000,encoding-name=H264,payload=96", "!",
                             "rtph264depay", "!", "video/x-h264,stream-format=byte-stream,alignment=au", "!",
                             "fdsink", "fd=1", "sync=false"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    dec = av.CodecContext.create("h264", "r")
    dec.flags |= av.codec.context.Flags.low_delay

    def read() -> None:
        while not stop.is_set():
            au = proc.stdout.read1(1 << 20)  # fdsink writes one buffer (one access unit) per write
            if not au:
                return
            try:
                frames = dec.decode(av.Packet(au))
            except av.error.FFmpegError:
                continue  # before the first keyframe
            for frame in frames:
                now = time.time()
                n = read_number(frame.to_ndarray(format="bgr24"))
                if n in stamps:
                    lat.append(now - stamps[n])

    threading.Thread(target=read, daemon=True).start()
    return proc


def run(codec: str, uavs: int, seconds: float, hz: float, tmp: Path, receiver: str = "ffmpeg") -> dict:
    import av

    group = ProcessGroup(echo=None)
    try:
        tcp, udp = free_port_pair()
        ends = multilink_endpoints("127.0.0.1", tcp, udp)
        gw = group.start("gateway", ["gateway", "--fleet", "bench", "--multilink", *[a for e in ends for a in ("--listen", e)]])
        assert gw.wait_for("router up", 30)
        base = free_port() & ~1
        sdp_dir = tmp / f"sdp-{codec}-{uavs}"
        svc = group.start("video", ["video", "--fleet", "bench", "--multilink", "--codec", codec, "--preview-port", str(base),
                                    "--uavs", str(uavs), "--sdp-dir", str(sdp_dir), *[a for e in ends for a in ("--connect", e)]])
        assert svc.wait_for("video up", 30), svc.lines
        stamps: dict[int, float] = {}
        lat: list[float] = []
        stop = threading.Event()

        def receive() -> None:
            try:
                _receive()
            except av.error.FFmpegError:
                pass  # the stream ended (timeout after the last picture)

        def _receive() -> None:
            with av.open(str(sdp_dir / "uav1-preview.sdp"), format="sdp", timeout=20,
                         options={"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "0",
                                  "fflags": "nobuffer"}) as c:
                for frame in c.decode(video=0):
                    now = time.time()
                    n = read_number(frame.to_ndarray(format="bgr24"))
                    if n in stamps:
                        lat.append(now - stamps[n])
                    if stop.is_set():
                        return

        gst = None
        if receiver == "gstreamer":
            gst = gst_receiver(base, stamps, lat, stop)
            rx = threading.Thread(target=lambda: None)
        else:
            rx = threading.Thread(target=receive, daemon=True)
        rx.start()
        jpegs = [cv2.imencode(".jpg", picture(i), [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes() for i in range(256)]
        with Bus(BusConfig(mode="client", connect=ends, multilink=True), "bench", "uavs") as bus:
            pubs = {u: bus.publisher(keys.preview("bench", u), IMAGERY) for u in range(1, uavs + 1)}
            senders = {u: RtpSender(ssrc_for(u, 1)) for u in pubs}
            time.sleep(1.0)
            pid = svc.proc.pid
            c0, t0 = cpu_s(pid), time.monotonic()
            i = 0
            while time.monotonic() - t0 < seconds:
                stamp = time.time()
                for u, pub in pubs.items():
                    meta = ImageMeta(uav=u, capture_id=0, t=float(i), stamp=stamp, cam_pos=(0, 0, 0),
                                     cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                                     intrinsics=Intrinsics(width=320, height=240, fx=300.0, fy=300.0, cx=160.0, cy=120.0))
                    if u == 1:
                        stamps[i % 256] = stamp
                    pub.put_bytes(pack_image(senders[u], meta, jpegs[i % 256], stamp))
                i += 1
                time.sleep(max(0.0, t0 + i / hz - time.monotonic()))
            cpu = cpu_s(pid) - c0
            wall = time.monotonic() - t0
            stop.set()
        rx.join(3)
        if gst is not None:
            gst.kill()
            gst.wait()
        lat_ms = sorted(1000 * x for x in lat)
        return {"codec": codec, "receiver": receiver, "uavs": uavs, "hz": hz, "pictures": i, "decoded": len(lat),
                "latency_ms_p50": round(statistics.median(lat_ms), 1) if lat_ms else None,
                "latency_ms_p95": round(lat_ms[int(0.95 * (len(lat_ms) - 1))], 1) if lat_ms else None,
                "cpu_percent_total": round(100 * cpu / wall, 1), "cpu_percent_per_stream": round(100 * cpu / wall / uavs, 1)}
    finally:
        group.stop()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--hz", type=float, default=5.0, help="pictures per second per stream (the edges' preview: 2)")
    ap.add_argument("--out", default=str(ROOT / "bench/results/video.json"))
    args = ap.parse_args()
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="bench-video-"))
    rows = [run(codec, uavs, args.seconds, args.hz, tmp) for codec in ("h264", "mjpeg") for uavs in (1, 3)]
    if shutil.which("gst-launch-1.0"):
        rows += [run("h264", uavs, args.seconds, args.hz, tmp, receiver="gstreamer") for uavs in (1, 3)]
    print(f"{'codec':6} {'receiver':9} {'uavs':>4} {'pics':>5} {'decoded':>7} {'lat p50 ms':>10} {'lat p95 ms':>10} {'CPU %/stream':>12}")
    for r in rows:
        print(f"{r['codec']:6} {r['receiver']:9} {r['uavs']:>4} {r['pictures']:>5} {r['decoded']:>7} {r['latency_ms_p50']!s:>10} "
              f"{r['latency_ms_p95']!s:>10} {r['cpu_percent_per_stream']:>12}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"seconds": args.seconds, "hz": args.hz, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
