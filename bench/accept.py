"""How long a legitimate node waits to be admitted while bogus connections hammer the gateway's TLS port.

A real ``skynet gateway`` process (mutual TLS, a key set of its own) per variant; an attacker in this process
opens about ``--rate`` TCP connections a second on the gateway's TLS port, either closing each at once
(``close``: no TLS byte, no credential) or keeping it open and silent (``idle``, at most ``--idle-max`` at a
time, the oldest closed first); meanwhile a legitimate client (the ground station's certificate) opens a
session, closes it and opens the next, for ``--seconds``. Printed and written as JSON: per variant and attack,
the admission time of each session (median, p90, max) and how many did not open within ``--open-timeout``.

Variants: zenoh alone (its defaults); zenoh with ``transport/unicast/accept_timeout`` 500 ms and
``accept_pending`` 10000 (how long an incoming link may take to finish its handshake, how many may be
unfinished at once); and the gateway's accept guard (on by default, ``--no-accept-guard`` turns it off; :mod:`services.gateway.guard`).

    .venv/bin/python bench/accept.py [--seconds 10] [--rate 1000] [--out bench/results/accept.json]
"""

from __future__ import annotations

import argparse
import collections
import json
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.keyset import KeySet  # noqa: E402
from services.keys import init  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port  # noqa: E402

FLEET = "bench"
ATTACKS = ("none", "close", "idle")
#: the zenoh settings tried as a remedy
ACCEPT_LIMITS = {"transport/unicast/accept_timeout": 500, "transport/unicast/accept_pending": 10000}


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))] if xs else float("nan")


class Attacker:
    """About ``rate`` TCP connections a second to ``port``: closed at once, or held silent (``idle_max`` at most)."""

    def __init__(self, port: int, kind: str, rate: float, idle_max: int):
        self.port, self.kind, self.rate, self.idle_max = port, kind, rate, idle_max
        self.stop = threading.Event()
        self.made = 0
        self.failed = 0
        self.held: collections.deque[socket.socket] = collections.deque()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        period = 1.0 / self.rate
        next_t = time.perf_counter()
        while not self.stop.is_set():
            try:
                s = socket.create_connection(("127.0.0.1", self.port), timeout=1.0)
                self.made += 1
                if self.kind == "close":
                    s.close()
                else:
                    self.held.append(s)
                    while len(self.held) > self.idle_max:
                        self.held.popleft().close()
            except OSError:
                self.failed += 1
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -1.0:  # fell behind by a second: do not burst to catch up
                next_t = time.perf_counter()

    def __enter__(self) -> Attacker:
        if self.kind != "none":
            self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        if self.thread.is_alive():
            self.thread.join(5)
        while self.held:
            self.held.popleft().close()


def admissions(config: BusConfig, seconds: float) -> tuple[list[float], int]:
    """Open, close, repeat for ``seconds``: the open times (s) of the sessions that opened, and how many did not."""
    times, failed = [], 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.perf_counter()
        try:
            bus = Bus(config, FLEET, "legit")
            ok = bool(bus.routers())
            bus.close()
        except zenoh.ZError:
            ok = False
        if ok:
            times.append(time.perf_counter() - t0)
        else:
            failed += 1
        time.sleep(0.2)
    return times, failed


def run_variant(keys: Path, name: str, cfg: dict, attack: str, args: argparse.Namespace) -> dict:
    group = ProcessGroup(echo=None)
    port = free_port(socket.SOCK_STREAM)
    where = f"tls/127.0.0.1:{port}"
    extra = [a for k, v in cfg.items() for a in ("--cfg", f"{k}:{json.dumps(v)}")]
    try:
        gw = group.start(f"gateway-{name}-{attack}", ["gateway", "--fleet", FLEET, "--keys", str(keys), "--listen",
                                                      where, *extra, *([] if name == "accept guard" else ["--no-accept-guard"])])
        if not gw.wait_for("router up", 30):
            raise RuntimeError("gateway did not start:\n" + "\n".join(gw.lines[-10:]))
        ks = KeySet(keys, "gcs")
        config = BusConfig(mode="client", connect=[where], tls_ca=str(ks.tls_ca), tls_cert=str(ks.tls_cert),
                           tls_key=str(ks.tls_key), connect_timeout_s=args.open_timeout)
        with Attacker(port, attack, args.rate, args.idle_max) as atk:
            time.sleep(1.0 if attack != "none" else 0.0)  # the flood is on before the first admission
            t0 = time.monotonic()
            times, failed = admissions(config, args.seconds)
            elapsed = time.monotonic() - t0
        made = atk.made
        # after the flood: how long until a session opens again
        t0 = time.perf_counter()
        times_after, failed_after = admissions(config, 0.1)
        return {"variant": name, "attack": attack, "bogus_per_s": round(made / (elapsed + 1.0), 1) if attack != "none" else 0,
                "sessions": len(times), "not_admitted": failed,
                "median_s": round(statistics.median(times), 3) if times else None,
                "p90_s": round(pct(times, 0.9), 3) if times else None, "max_s": round(max(times), 3) if times else None,
                "after_flood_s": round(times_after[0], 3) if times_after else None,
                "open_timeout_s": args.open_timeout}
    finally:
        group.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="admissions measured per variant and attack")
    ap.add_argument("--rate", type=float, default=1000.0, help="bogus connections per second")
    ap.add_argument("--idle-max", type=int, default=800, help="silent connections held at once (idle attack)")
    ap.add_argument("--open-timeout", type=float, default=10.0, help="a session not open by then is not admitted")
    ap.add_argument("--attacks", default=",".join(ATTACKS))
    ap.add_argument("--out", default="bench/results/accept.json")
    args = ap.parse_args()
    variants = {"zenoh defaults": {}, "accept limits": ACCEPT_LIMITS, "accept guard": {}}
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        keys = init(Path(tmp) / "keys", uavs=1)
        for attack in args.attacks.split(","):
            for name, cfg in variants.items():
                r = run_variant(keys, name, cfg, attack, args)
                results.append(r)
                print(f"{r['variant']:14} {attack:5} bogus {r['bogus_per_s']:7.1f}/s  admitted {r['sessions']:3} "
                      f"(not {r['not_admitted']}) in median {r['median_s']} s, p90 {r['p90_s']} s, "
                      f"max {r['max_s']} s; after the flood {r['after_flood_s']} s", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"accept_limits": ACCEPT_LIMITS, "rate": args.rate, "seconds": args.seconds,
                               "idle_max": args.idle_max, "results": results}, indent=2))
    print(f"written {out}")


if __name__ == "__main__":
    main()
