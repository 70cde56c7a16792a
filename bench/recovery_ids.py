"""What a claimed publisher id costs a recovering subscriber: one UAV's session puts N samples on its own
camera key, each under a new publisher id (Zenoh takes the id the sender names); a plain and a recovering
subscriber (as the detector's and the mission log's) in processes of their own; their resident memory
before, after the flood and after the sender left (docs/security.md).

    .venv/bin/python bench/recovery_ids.py [--n 20000] [--out bench/results/recovery_ids.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.heap import resident_mb  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port  # noqa: E402

FLEET = "bench"


def subscriber(endpoint: str, recover: bool) -> None:
    """The receiving process: prints its sample count and resident MB for each line read from stdin."""
    n = [0]
    with Bus(BusConfig(mode="client", connect=[endpoint]), FLEET, "gcs") as bus:
        bus.subscribe_raw(keys.camera(FLEET, "*"), lambda s: n.__setitem__(0, n[0] + 1), recover=recover)
        print("ready", flush=True)
        for _ in sys.stdin:
            print(n[0], resident_mb(os.getpid()), flush=True)


def flood(endpoint: str, n: int, recover: bool) -> dict:
    sub = subprocess.Popen([sys.executable, __file__, "--subscriber", endpoint, *(["--recover"] if recover else [])],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert sub.stdin is not None and sub.stdout is not None
    sub.stdout.readline()

    def reading() -> tuple[int, float]:
        time.sleep(2.0)
        sub.stdin.write("\n")
        sub.stdin.flush()
        got, mb = sub.stdout.readline().split()
        return int(got), float(mb)

    _, start = reading()
    with Bus(BusConfig(mode="client", connect=[endpoint]), FLEET, "uav2") as bus:
        key = keys.camera(FLEET, 2)
        t0 = time.perf_counter()
        for _ in range(n):
            pub = bus.session.declare_publisher(key)  # a new publisher id each time
            bus.session.put(key, b"x" * 20, source_info=zenoh.SourceInfo(pub.id, 1))
            pub.undeclare()
        put_s = time.perf_counter() - t0
        got, held = reading()
    _, after = reading()
    sub.kill()
    return {"received": got, "put_s": round(put_s, 2), "held_mb": round(held - start, 2),
            "after_sender_left_mb": round(after - start, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20000, help="samples, each under a new publisher id")
    ap.add_argument("--out", default=None)
    ap.add_argument("--subscriber", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--recover", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.subscriber:
        subscriber(a.subscriber, a.recover)
        return 0
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    group = ProcessGroup(echo=None)
    try:
        gw = group.start("gw", ["gateway", "--fleet", FLEET, "--listen", endpoint], ready=True)
        assert gw.wait_ready(30), "\n".join(gw.lines)
        result = {"n": a.n, "plain": flood(endpoint, a.n, False), "recovering": flood(endpoint, a.n, True)}
    finally:
        group.stop()
    print(json.dumps(result, indent=1))
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
