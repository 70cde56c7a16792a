"""What trust costs, side by side in one run.

* sign and verify per command (µs): Ed25519 envelope of a ``Land`` and of a 300-waypoint upload,
  codec included (:mod:`protocol.signing`);
* telemetry (200 B, best-effort) and imagery (60 KB, best-effort) round-trip latency and one-way
  throughput through a gateway: plaintext multilink (TCP ``rel=1`` + UDP ``rel=0``) against mutual
  TLS (two TLS links, ``rel=1`` + ``rel=0``). Two real ``skynet gateway`` processes, one per
  transport; the pinging and echoing client sessions alternate *message by message* between the
  two (and throughput in short slices), so the shared machine's noise falls on both alike;
* mutual-TLS connection time against plain TCP (a client session open, median of N);
* the whole mission's CPU (launcher + every service), secure by default against ``--insecure``.

    .venv/bin/python bench/trust.py [--quick] [--no-mission] [--out bench/results/trust.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import codec, keys  # noqa: E402
from protocol.bus import Bus, BusConfig, multilink_endpoints  # noqa: E402
from protocol.keyset import KeySet  # noqa: E402
from protocol.links import IMAGERY, TELEMETRY  # noqa: E402
from protocol.messages import Land, Trajectory, UploadTrajectory, Waypoint  # noqa: E402
from services.keys import init  # noqa: E402
from services.orchestration.process import ProcessGroup, free_port, free_port_pair  # noqa: E402
from services.orchestration.trustmode import tls_endpoints  # noqa: E402

TRANSPORTS = ("plain", "tls")
FLEET = "bench"


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))] if xs else float("nan")


def bench_signing(ks: Path, n: int) -> dict:
    gcs = KeySet(ks, "gcs")
    signer, verifier = gcs.signer(), KeySet(ks, "uav1").verifier(persist=False)
    to = "skynet/demo/uav/1/cmd"
    traj = Trajectory(uav=1, waypoints=[Waypoint(t=float(i), pos=(float(i), 10.0, 5.0), speed=1.0) for i in range(300)])
    out = {}
    for name, msg in (("land", Land(uav=1, cmd_id=1)), ("upload300", UploadTrajectory(uav=1, cmd_id=1, trajectory=traj))):
        t0 = time.perf_counter()
        envs = [codec.encode(signer.sign(msg, to)) for _ in range(n)]
        sign_us = (time.perf_counter() - t0) / n * 1e6
        t0 = time.perf_counter()
        for e in envs:
            verifier.verify(codec.decode(e), to)
        verify_us = (time.perf_counter() - t0) / n * 1e6
        t0 = time.perf_counter()
        for _ in range(n):
            codec.decode(codec.encode(msg))
        plain_us = (time.perf_counter() - t0) / n * 1e6
        out[name] = {"sign_us": sign_us, "verify_us": verify_us, "plain_codec_us": plain_us,
                     "bytes_plain": len(codec.encode(msg)), "bytes_signed": len(envs[0])}
    return out


def client_config(transport: str, endpoints: list[str], ks: Path, role: str) -> BusConfig:
    tls = {}
    if transport == "tls":
        k = KeySet(ks, role)
        tls = {"tls_ca": str(k.ca), "tls_cert": str(k.tls_cert), "tls_key": str(k.tls_key)}
    return BusConfig(mode="client", connect=endpoints, multilink=True, **tls)


class Pair:
    """A pinging and an echoing client session through one gateway."""

    def __init__(self, transport: str, endpoints: list[str], ks: Path):
        self.ping = Bus(client_config(transport, endpoints, ks, "gcs"), "bench", "ping")
        self.echo = Bus(client_config(transport, endpoints, ks, "uav1"), "bench", "echo")
        self.got = threading.Event()
        self.count = 0
        self.bytes = 0
        self.pubs = {}
        # keys the certificate ACL lets through: the ground station pings on the heartbeat key (with the
        # link class's QoS), UAV 1 answers on its state (telemetry) or camera (imagery) key
        hb = keys.heartbeat(FLEET)
        self.echo.subscribe_raw(hb, self._echo)
        self.backs = {TELEMETRY.name: self.echo.publisher(keys.state(FLEET, 1), TELEMETRY),
                      IMAGERY.name: self.echo.publisher(keys.camera(FLEET, 1), IMAGERY)}
        for link in (TELEMETRY, IMAGERY):
            self.pubs[link.name] = self.ping.publisher(hb, link)
        self.ping.subscribe_raw(keys.state(FLEET, 1), self._pong)
        self.ping.subscribe_raw(keys.camera(FLEET, 1), self._pong)
        self.flooding = False

    def _echo(self, sample) -> None:
        data = sample.payload.to_bytes()
        self.backs[TELEMETRY.name if len(data) < 1000 else IMAGERY.name].put_bytes(data)

    def _pong(self, sample) -> None:
        if self.flooding:
            self.count += 1
            self.bytes += len(sample.payload)
        else:
            self.got.set()

    def rtt(self, link: str, payload: bytes, timeout: float = 1.0) -> float | None:
        self.got.clear()
        t0 = time.perf_counter()
        self.pubs[link].put_bytes(payload)
        return (time.perf_counter() - t0) * 1e3 if self.got.wait(timeout) else None

    def close(self) -> None:
        self.ping.close()
        self.echo.close()


def bench_links(ks: Path, group: ProcessGroup, n: int, flood_s: float) -> dict:
    ends = {"plain": multilink_endpoints("127.0.0.1", *free_port_pair()),
            "tls": tls_endpoints("127.0.0.1", free_port(), free_port())}
    for t in TRANSPORTS:
        key_args = ["--keys", str(ks)] if t == "tls" else []
        svc = group.start(f"gw-{t}", ["gateway", "--fleet", "bench", "--multilink", *key_args,
                                      *[x for e in ends[t] for x in ("--listen", e)]])
        assert svc.wait_for("router up", 30), "\n".join(svc.lines)
    # connection time: open + close a client session, alternating transports
    conn = {t: [] for t in TRANSPORTS}
    for _ in range(max(5, n // 50)):
        for t in TRANSPORTS:
            cfg = client_config(t, ends[t][:1], ks, "gcs")
            t0 = time.perf_counter()
            s = zenoh.open(cfg.to_zenoh())
            conn[t].append((time.perf_counter() - t0) * 1e3)
            s.close()
    pairs = {t: Pair(t, ends[t], ks) for t in TRANSPORTS}
    time.sleep(1.0)
    out: dict = {"connect_ms": {t: {"median": statistics.median(v), "p90": pct(v, 0.9)} for t, v in conn.items()}}
    try:
        for link, size in (("telemetry", 200), ("imagery", 60_000)):
            payload = os.urandom(size)
            lat = {t: [] for t in TRANSPORTS}
            lost = {t: 0 for t in TRANSPORTS}
            for i in range(n):
                for t in (TRANSPORTS if i % 2 == 0 else TRANSPORTS[::-1]):
                    r = pairs[t].rtt(link, payload)
                    if r is None:
                        lost[t] += 1
                    else:
                        lat[t].append(r)
            row = {t: {"rtt_median_ms": statistics.median(lat[t] or [float("nan")]), "rtt_p99_ms": pct(lat[t], 0.99), "lost": lost[t]}
                   for t in TRANSPORTS}
            # throughput: one-way best-effort flood, alternating 0.25 s slices
            flood_link = TELEMETRY if link == "telemetry" else IMAGERY
            pubs = {t: pairs[t].backs[flood_link.name] for t in TRANSPORTS}
            sent = {t: 0 for t in TRANSPORTS}
            busy = {t: 0.0 for t in TRANSPORTS}
            for p in pairs.values():
                p.count = p.bytes = 0
                p.flooding = True
            t_end = time.perf_counter() + flood_s
            while time.perf_counter() < t_end:
                for t in TRANSPORTS:
                    s0 = time.perf_counter()
                    while time.perf_counter() - s0 < 0.25:
                        pubs[t].put_bytes(payload)
                        sent[t] += 1
                    busy[t] += time.perf_counter() - s0
            time.sleep(0.5)
            for p in pairs.values():
                p.flooding = False
            for t in TRANSPORTS:
                row[t].update({"flood_sent": sent[t], "flood_received": pairs[t].count,
                               "throughput_MBps": pairs[t].bytes / busy[t] / 1e6,
                               "delivered": pairs[t].count / max(1, sent[t])})
            row["latency_ratio_tls_over_plain"] = row["tls"]["rtt_median_ms"] / row["plain"]["rtt_median_ms"]
            row["throughput_ratio_tls_over_plain"] = row["tls"]["throughput_MBps"] / max(1e-9, row["plain"]["throughput_MBps"])
            out[link] = row
    finally:
        for p in pairs.values():
            p.close()
    return out


def bench_mission(speed: float) -> dict:
    from bench.mission import run  # noqa: E402

    out = {}
    for mode, extra in (("secure", []), ("insecure", ["--insecure"])):
        before = os.times()
        with tempfile.TemporaryDirectory() as tmp:
            r = run(speed, Path(tmp) / "m", extra)
        after = os.times()
        cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
        report = r["report"]
        out[mode] = {"exit": r["exit"], "wall_s": r["wall_s"], "cpu_s": cpu, "success": report.get("success"),
                     "captures": (report.get("captures") or {}).get("imaged") if isinstance(report.get("captures"), dict) else None}
    out["cpu_ratio_secure_over_insecure"] = out["secure"]["cpu_s"] / max(1e-9, out["insecure"]["cpu_s"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-mission", action="store_true")
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--out", default="bench/results/trust.json")
    a = ap.parse_args()
    n = 100 if a.quick else 400
    result: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        ks = init(Path(tmp) / "keys", uavs=1)
        result["signing"] = bench_signing(ks, 200 if a.quick else 2000)
        for name, r in result["signing"].items():
            print(f"sign {name:9}  sign {r['sign_us']:7.1f} µs  verify {r['verify_us']:7.1f} µs  "
                  f"(codec alone {r['plain_codec_us']:6.1f} µs; {r['bytes_plain']} -> {r['bytes_signed']} B)")
        group = ProcessGroup(echo=None)
        try:
            result["links"] = bench_links(ks, group, n, 2.0 if a.quick else 4.0)
        finally:
            group.stop()
    links = result["links"]
    print(f"connect  plain {links['connect_ms']['plain']['median']:.1f} ms   mTLS {links['connect_ms']['tls']['median']:.1f} ms")
    for link in ("telemetry", "imagery"):
        r = links[link]
        print(f"{link:9}  RTT median plain {r['plain']['rtt_median_ms']:.2f} ms  TLS {r['tls']['rtt_median_ms']:.2f} ms "
              f"(x{r['latency_ratio_tls_over_plain']:.2f}); p99 {r['plain']['rtt_p99_ms']:.2f} / {r['tls']['rtt_p99_ms']:.2f} ms; "
              f"throughput {r['plain']['throughput_MBps']:.1f} / {r['tls']['throughput_MBps']:.1f} MB/s "
              f"(x{r['throughput_ratio_tls_over_plain']:.2f}), delivered {r['plain']['delivered']:.0%} / {r['tls']['delivered']:.0%}")
    if not a.no_mission:
        result["mission"] = m = bench_mission(a.speed)
        print(f"mission  CPU secure {m['secure']['cpu_s']:.1f} s  insecure {m['insecure']['cpu_s']:.1f} s "
              f"(x{m['cpu_ratio_secure_over_insecure']:.2f}); exit {m['secure']['exit']} / {m['insecure']['exit']}")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
