"""Bus-layer overhead against raw zenoh-python, side by side in one run.

Round-trip latency (median, p99) of telemetry-sized (200 B) and image-sized (200 KB) payloads,
peer-to-peer and client -> router -> client, through ``protocol.bus`` and through raw
zenoh-python with the same payload and QoS; and one-way throughput. The echo side runs in its
own process. Raw and bus runs alternate so that machine noise hits both alike.

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
from services.process import free_port  # noqa: E402

PING, PONG, FLOOD, DONE = "bench/ping", "bench/pong", "bench/flood", "bench/done"


def make_config(mode: str, listen: list[str], connect: list[str]) -> BusConfig:
    return BusConfig(mode=mode, listen=listen, connect=connect)


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

    def publisher(self, key: str, link: LinkClass):
        if self.bus is not None:
            return self.bus.publisher(key, link).put_bytes
        return self.session.declare_publisher(key, **link.publisher_qos()).put

    def subscribe(self, key: str, callback) -> None:
        if self.bus is not None:
            self.bus.subscribe_raw(key, callback)
        else:
            self.session.declare_subscriber(key, callback)

    def close(self) -> None:
        (self.bus or self.session).close()


def echo_main(impl: str, mode: str, listen: list[str], connect: list[str], link_name: str) -> None:
    link = {"telemetry": TELEMETRY, "imagery": IMAGERY, "command": COMMAND}[link_name]
    node = Node(impl, make_config(mode, listen, connect))
    put = node.publisher(PONG, link)
    count = [0]
    done = threading.Event()

    def on_flood(sample):
        count[0] += 1

    node.subscribe(PING, lambda s: put(s.payload.to_bytes()))
    node.subscribe(FLOOD, on_flood)
    node.subscribe(DONE, lambda s: done.set())
    print("ready", flush=True)
    for line in sys.stdin:  # the orchestrator asks for the flood count, then closes stdin
        print(count[0], flush=True)
    node.close()


def percentile(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def measure(impl: str, topology: str, size: int, n: int, flood_s: float) -> dict:
    host = "127.0.0.1"
    link = TELEMETRY if size < 4096 else IMAGERY
    router = None
    if topology == "p2p":
        port = free_port()
        me = make_config("peer", [f"tcp/{host}:{port}"], [])
        other = ("peer", [], [f"tcp/{host}:{port}"])
    else:
        port = free_port()
        router = zenoh.open(make_config("router", [f"tcp/{host}:{port}"], []).to_zenoh())
        me = make_config("client", [], [f"tcp/{host}:{port}"])
        other = ("client", [], [f"tcp/{host}:{port}"])
    echo = subprocess.Popen(
        [sys.executable, __file__, "--echo", impl, other[0], json.dumps(other[1]), json.dumps(other[2]), link.name],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert echo.stdout.readline().strip() == "ready"
    node = Node(impl, me)
    got = threading.Event()
    node.subscribe(PONG, lambda s: got.set())
    put = node.publisher(PING, link)
    payload = bytes(size)
    # warm up until the route exists
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        got.clear()
        put(payload)
        if got.wait(0.2):
            break
    rtts = []
    for _ in range(n):
        got.clear()
        t0 = time.perf_counter()
        put(payload)
        if got.wait(1.0):
            rtts.append(time.perf_counter() - t0)
    # one-way throughput: reliable + block so that nothing is dropped on the sender
    flood = node.publisher(FLOOD, COMMAND if size < 4096 else LinkClass("bulk", True, "block", "DATA", False))
    sent = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < flood_s:
        for _ in range(100 if size < 4096 else 5):
            flood(payload)
        sent += 100 if size < 4096 else 5
    time.sleep(0.3)
    echo.stdin.write("count\n")
    echo.stdin.flush()
    received = int(echo.stdout.readline())
    elapsed = time.perf_counter() - t0 - 0.3
    echo.stdin.close()
    echo.wait(10)
    node.close()
    if router is not None:
        router.close()
    return {
        "impl": impl, "topology": topology, "size": size, "samples": len(rtts), "lost": n - len(rtts),
        "rtt_median_us": 1e6 * statistics.median(rtts), "rtt_p99_us": 1e6 * percentile(rtts, 0.99),
        "sent": sent, "received": received, "msgs_per_s": received / elapsed, "mb_per_s": received * size / elapsed / 1e6,
    }


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--echo":
        _, _, impl, mode, listen, connect, link = sys.argv
        echo_main(impl, mode, json.loads(listen), json.loads(connect), link)
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bus.json"))
    args = parser.parse_args()
    zenoh.init_log_from_env_or("error")
    n_small, n_big, flood_s = (500, 100, 1.0) if args.quick else (3000, 500, 2.0)
    rows = []
    for topology in ("p2p", "client-router-client"):
        for size, n in ((200, n_small), (200_000, n_big)):
            runs: dict[str, list[dict]] = {"raw": [], "bus": []}
            for _ in range(args.reps):
                for impl in ("raw", "bus"):
                    runs[impl].append(measure(impl, topology, size, n, flood_s))
            agg = {}
            for impl, rs in runs.items():
                agg[impl] = {k: statistics.median(r[k] for r in rs) for k in
                             ("rtt_median_us", "rtt_p99_us", "msgs_per_s", "mb_per_s", "lost")}
            row = {"topology": topology, "size": size, "raw": agg["raw"], "bus": agg["bus"],
                   "latency_ratio": agg["bus"]["rtt_median_us"] / agg["raw"]["rtt_median_us"],
                   "p99_ratio": agg["bus"]["rtt_p99_us"] / agg["raw"]["rtt_p99_us"],
                   "throughput_share": agg["bus"]["msgs_per_s"] / agg["raw"]["msgs_per_s"]}
            rows.append(row)
            print(f"{topology:>22} {size:>7} B | raw {row['raw']['rtt_median_us']:8.0f} us p99 {row['raw']['rtt_p99_us']:8.0f}"
                  f" {row['raw']['msgs_per_s']:9.0f}/s | bus {row['bus']['rtt_median_us']:8.0f} us p99 "
                  f"{row['bus']['rtt_p99_us']:8.0f} {row['bus']['msgs_per_s']:9.0f}/s | latency x{row['latency_ratio']:.2f}"
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
    out.write_text(json.dumps({"rows": rows, "goal_met": goal, "reps": args.reps,
                               "n": {"small": n_small, "big": n_big}, "flood_s": flood_s}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
