"""Bus-layer overhead against raw zenoh-python, side by side in one run.

Round-trip latency (median, p99) of telemetry-sized (200 B) and image-sized (200 KB) payloads,
peer-to-peer and client -> router -> client, through ``protocol.bus`` and through raw
zenoh-python with the same payload and QoS; and one-way throughput. The echo side runs in its
own process and hosts both a raw session and a bus session; the pinging side alternates
*message by message* between its raw and its bus session (and throughput bursts alternate in
short slices), so that the machine's noise falls on both alike — these machines are shared.

    .venv/bin/python bench/bus.py [--quick] [--out bench/results/bus.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.links import COMMAND, IMAGERY, TELEMETRY, LinkClass  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402

IMPLS = ("raw", "bus")
BULK = LinkClass("bulk", True, "block", "DATA", False)


def key(impl: str, what: str) -> str:
    return f"bench/{impl}/{what}"


class Node:
    """The same operations through raw zenoh-python or through the bus layer."""

    def __init__(self, impl: str, config: BusConfig):
        self.impl = impl
        if impl == "bus":
            self.bus = Bus(config, fleet="bench", name="bench")
            self.session = self.bus.session
        else:
            self.bus = None
            self.session = zenoh.open(config.to_zenoh())

    def publisher(self, k: str, link: LinkClass):
        if self.bus is not None:
            return self.bus.publisher(k, link).put_bytes
        return self.session.declare_publisher(k, **link.publisher_qos()).put

    def subscribe(self, k: str, callback) -> None:
        if self.bus is not None:
            self.bus.subscribe_raw(k, callback)
        else:
            self.session.declare_subscriber(k, callback)

    def close(self) -> None:
        (self.bus or self.session).close()


def echo_main(configs: dict[str, dict], link_name: str) -> None:
    link = {"telemetry": TELEMETRY, "imagery": IMAGERY}[link_name]
    counts = {impl: [0] for impl in IMPLS}
    nodes = []
    for impl in IMPLS:
        node = Node(impl, BusConfig(**configs[impl]))
        put = node.publisher(key(impl, "pong"), link)
        node.subscribe(key(impl, "ping"), lambda s, put=put: put(s.payload.to_bytes()))
        c = counts[impl]

        def on_flood(sample, c=c):
            c[0] += 1

        node.subscribe(key(impl, "flood"), on_flood)
        nodes.append(node)
    print("ready", flush=True)
    for _ in sys.stdin:  # the orchestrator asks for the flood counts, then closes stdin
        print(json.dumps({i: c[0] for i, c in counts.items()}), flush=True)
    for node in nodes:
        node.close()


def percentile(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def measure(topology: str, size: int, n: int, flood_s: float) -> dict:
    host = "127.0.0.1"
    link = TELEMETRY if size < 4096 else IMAGERY
    routers, mine, theirs = [], {}, {}
    for impl in IMPLS:
        port = free_port()
        if topology == "p2p":
            mine[impl] = dict(mode="peer", listen=[f"tcp/{host}:{port}"])
            theirs[impl] = dict(mode="peer", connect=[f"tcp/{host}:{port}"])
        else:
            routers.append(zenoh.open(BusConfig(mode="router", listen=[f"tcp/{host}:{port}"]).to_zenoh()))
            mine[impl] = theirs[impl] = dict(mode="client", connect=[f"tcp/{host}:{port}"])
    echo = subprocess.Popen([sys.executable, __file__, "--echo", json.dumps(theirs), link.name],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert echo.stdout.readline().strip() == "ready"
    nodes = {impl: Node(impl, BusConfig(**mine[impl])) for impl in IMPLS}
    got = {impl: threading.Event() for impl in IMPLS}
    puts = {}
    for impl, node in nodes.items():
        node.subscribe(key(impl, "pong"), lambda s, e=got[impl]: e.set())
        puts[impl] = node.publisher(key(impl, "ping"), link)
    payload = bytes(size)
    for impl in IMPLS:  # warm up until both routes exist
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            got[impl].clear()
            puts[impl](payload)
            if got[impl].wait(0.2):
                break
    rtts: dict[str, list[float]] = {impl: [] for impl in IMPLS}
    for i in range(2 * n):
        impl = IMPLS[i % 2] if (i // 2) % 2 == 0 else IMPLS[1 - i % 2]  # raw,bus,bus,raw,...
        ev = got[impl]
        ev.clear()
        t0 = time.perf_counter()
        puts[impl](payload)
        if ev.wait(1.0):
            rtts[impl].append(time.perf_counter() - t0)
    # one-way throughput, reliable + block so that the sender never drops: alternating slices
    floods = {impl: nodes[impl].publisher(key(impl, "flood"), COMMAND if size < 4096 else BULK) for impl in IMPLS}
    sent = {impl: 0 for impl in IMPLS}
    busy = {impl: 0.0 for impl in IMPLS}
    slice_s, batch = flood_s / 8, (100 if size < 4096 else 5)
    for k in range(8):
        impl = IMPLS[k % 2]
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < slice_s:
            for _ in range(batch):
                floods[impl](payload)
            sent[impl] += batch
        time.sleep(0.2)  # let the slice drain before the other one starts
        busy[impl] += time.perf_counter() - t0 - 0.2
    echo.stdin.write("count\n")
    echo.stdin.flush()
    received = json.loads(echo.stdout.readline())
    echo.stdin.close()
    echo.wait(10)
    for node in nodes.values():
        node.close()
    for r in routers:
        r.close()
    out = {}
    for impl in IMPLS:
        xs = rtts[impl]
        out[impl] = {"samples": len(xs), "lost": n - len(xs), "rtt_median_us": 1e6 * statistics.median(xs),
                     "rtt_p99_us": 1e6 * percentile(xs, 0.99), "sent": sent[impl], "received": received[impl],
                     "msgs_per_s": received[impl] / busy[impl], "mb_per_s": received[impl] * size / busy[impl] / 1e6}
    return out


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--echo":
        echo_main(json.loads(sys.argv[2]), sys.argv[3])
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bus.json"))
    args = parser.parse_args()
    zenoh.init_log_from_env_or("error")
    n_small, n_big, flood_s = (500, 100, 1.0) if args.quick else (4000, 600, 3.0)
    rows = []
    for topology in ("p2p", "client-router-client"):
        for size, n in ((200, n_small), (200_000, n_big)):
            agg = measure(topology, size, n, flood_s)
            row = {"topology": topology, "size": size, **agg,
                   "latency_ratio": agg["bus"]["rtt_median_us"] / agg["raw"]["rtt_median_us"],
                   "p99_ratio": agg["bus"]["rtt_p99_us"] / agg["raw"]["rtt_p99_us"],
                   "throughput_share": agg["bus"]["msgs_per_s"] / agg["raw"]["msgs_per_s"]}
            rows.append(row)
            print(f"{topology:>22} {size:>7} B | raw {row['raw']['rtt_median_us']:7.0f} us p99 {row['raw']['rtt_p99_us']:7.0f}"
                  f" {row['raw']['msgs_per_s']:9.0f}/s | bus {row['bus']['rtt_median_us']:7.0f} us p99 "
                  f"{row['bus']['rtt_p99_us']:7.0f} {row['bus']['msgs_per_s']:9.0f}/s | latency x{row['latency_ratio']:.2f}"
                  f" throughput {100 * row['throughput_share']:.0f} %", flush=True)
    goal = all(r["latency_ratio"] <= 1.3 for r in rows) and all(r["throughput_share"] >= 0.7 for r in rows)
    print("\n| topology | size | raw RTT median / p99 (µs) | bus RTT median / p99 (µs) | latency ratio | raw msg/s | bus msg/s | throughput share |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['topology']} | {r['size']} B | {r['raw']['rtt_median_us']:.0f} / {r['raw']['rtt_p99_us']:.0f} | "
              f"{r['bus']['rtt_median_us']:.0f} / {r['bus']['rtt_p99_us']:.0f} | {r['latency_ratio']:.2f} | "
              f"{r['raw']['msgs_per_s']:.0f} | {r['bus']['msgs_per_s']:.0f} | {100 * r['throughput_share']:.0f} % |")
    print(f"\ngoal (latency <= 1.3x raw, throughput >= 70 % of raw): {'met' if goal else 'NOT met'}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "goal_met": goal, "n": {"small": n_small, "big": n_big},
                               "flood_s": flood_s}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
