"""Overhead of the user-space impairment proxies (services.netem) on loopback.

For UDP and TCP: round-trip latency of 64 B messages (median, p99) straight to an echo server
and through a proxy with no impairment (the proxy's own added latency), echo throughput through
the proxy and without it, and the accuracy of a configured delay (``delay 20ms`` each way: how
far the measured round trip lands from 40 ms). The echo server and the proxy (``python -m
services.netem.cli``) each run in their own process, as in a deployment, so the client does not
share the interpreter lock with them.

    .venv/bin/python bench/netem.py [--quick] [--out bench/results/netem.json]
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import statistics
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

ECHO = textwrap.dedent("""
    import socket, sys, threading
    kind = sys.argv[1]
    if kind == "udp":
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.bind(("127.0.0.1", 0)); print(s.getsockname()[1], flush=True)
        while True:
            d, a = s.recvfrom(65535); s.sendto(d, a)
    s = socket.socket(); s.bind(("127.0.0.1", 0)); s.listen(); print(s.getsockname()[1], flush=True)
    def echo(c):
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        while d := c.recv(1 << 16):
            c.sendall(d)
        c.close()
    while True:
        threading.Thread(target=echo, args=(s.accept()[0],), daemon=True).start()
""")


def start_echo(kind: str) -> tuple[subprocess.Popen, int]:
    p = subprocess.Popen([sys.executable, "-c", ECHO, kind], stdout=subprocess.PIPE, text=True)
    return p, int(p.stdout.readline())


def start_proxy(kind: str, target_port: int, impair: str = "") -> tuple[subprocess.Popen, int]:
    p = subprocess.Popen([sys.executable, "-m", "services.netem.cli", kind, "--target", f"127.0.0.1:{target_port}",
                          "--impair", impair, "--seed", "0", "--interval-s", "3600"],
                         cwd=ROOT, stdout=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    m = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
    if not m:
        p.kill()
        raise RuntimeError(f"proxy did not start: {line!r}")
    return p, int(m.group(1))


def stop(p: subprocess.Popen) -> None:
    p.terminate()
    try:
        p.wait(5)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))]


# ----------------------------------------------------------------------------- UDP
def udp_rtt(port: int, n: int) -> list[float]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        c.settimeout(2.0)
        out = []
        for i in range(n + 20):
            msg = i.to_bytes(4, "big") + bytes(60)
            t = time.perf_counter()
            c.sendto(msg, ("127.0.0.1", port))
            while c.recv(100)[:4] != msg[:4]:
                pass
            if i >= 20:  # warm-up
                out.append((time.perf_counter() - t) * 1e3)
        return out


def udp_throughput(port: int, size: int, seconds: float, window: int = 32) -> float:
    """Echoed bytes per second (each way) with ``window`` datagrams in flight."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        c.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        c.settimeout(0.5)
        msg, done, t0 = bytes(size), 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            for _ in range(window):
                c.sendto(msg, ("127.0.0.1", port))
            for _ in range(window):
                try:
                    done += len(c.recv(65535))
                except TimeoutError:
                    break
        return done / (time.perf_counter() - t0)


# ----------------------------------------------------------------------------- TCP
def tcp_rtt(port: int, n: int) -> list[float]:
    with socket.create_connection(("127.0.0.1", port)) as c:
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        out, msg = [], bytes(64)
        for i in range(n + 20):
            t = time.perf_counter()
            c.sendall(msg)
            got = 0
            while got < 64:
                got += len(c.recv(64 - got))
            if i >= 20:
                out.append((time.perf_counter() - t) * 1e3)
        return out


def tcp_throughput(port: int, total: int) -> float:
    """Bytes per second streamed through the echo (each way)."""
    block = bytes(1 << 16)
    with socket.create_connection(("127.0.0.1", port)) as c:
        def send() -> None:
            for _ in range(total // len(block)):
                c.sendall(block)
            c.shutdown(socket.SHUT_WR)
        t0 = time.perf_counter()
        th = threading.Thread(target=send)
        th.start()
        got = 0
        while data := c.recv(1 << 17):
            got += len(data)
        th.join()
        return got / (time.perf_counter() - t0)


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    ap.add_argument("--out", default=str(ROOT / "bench/results/netem.json"))
    args = ap.parse_args(argv)
    n = 300 if args.quick else 2000
    secs = 0.5 if args.quick else 2.0
    total = (16 if args.quick else 64) << 20
    rows: list[dict] = []

    for kind in ("udp", "tcp"):
        echo, eport = start_echo(kind)
        procs = [echo]
        try:
            plain, pport = start_proxy(kind, eport)
            procs.append(plain)
            delayed, dport = start_proxy(kind, eport, "delay 20ms")
            procs.append(delayed)
            rtt = udp_rtt if kind == "udp" else tcp_rtt
            for path, port in (("direct", eport), ("proxy", pport)):
                lat = rtt(port, n)
                row = {"proto": kind, "path": path, "rtt_median_ms": statistics.median(lat),
                       "rtt_p99_ms": pct(lat, 0.99)}
                if kind == "udp":
                    for size in (1024, 8192):
                        row[f"echo_MBps_{size}B"] = udp_throughput(port, size, secs) / 1e6
                else:
                    row["echo_MBps_stream"] = tcp_throughput(port, total) / 1e6
                rows.append(row)
            lat = rtt(dport, max(100, n // 10))
            rows.append({"proto": kind, "path": "proxy delay 20ms each way",
                         "rtt_median_ms": statistics.median(lat), "rtt_p99_ms": pct(lat, 0.99),
                         "excess_over_40ms_median_ms": statistics.median(lat) - 40.0})
        finally:
            for p in procs:
                stop(p)

    print(f"{'proto':5} {'path':28} {'RTT med ms':>10} {'RTT p99 ms':>10}  throughput (echo, MB/s each way)")
    for r in rows:
        tput = "  ".join(f"{k[10:]}={v:.1f}" for k, v in r.items() if k.startswith("echo_MBps_"))
        print(f"{r['proto']:5} {r['path']:28} {r['rtt_median_ms']:10.3f} {r['rtt_p99_ms']:10.3f}  {tput}")
    for kind in ("udp", "tcp"):
        d, p = (next(r for r in rows if r["proto"] == kind and r["path"] == x) for x in ("direct", "proxy"))
        print(f"{kind}: proxy adds {p['rtt_median_ms'] - d['rtt_median_ms']:.3f} ms median round trip "
              f"({(p['rtt_median_ms'] - d['rtt_median_ms']) / 2:.3f} ms per pass)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"quick": args.quick, "samples": n, "rows": rows}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
