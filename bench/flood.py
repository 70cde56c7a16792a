"""The flood benchmark: the mission while one writable key is flooded for 10 s, against no flood, in one run.

For each case (``none`` and one flood per key a UAV or a forged RCU may write: ``uav/1/state`` with
malformed bytes, ``uav/1/event`` with 4 KB events, ``uav/1/camera`` with 50 KB RTP-looking junk,
``rcu/detector/defects`` with forged reports) it runs ``skynet mission --speed 4`` (a real network
of processes on loopback), starts the flood 2 s into the mission phase from a client of the gateway
in this process (as fast as it can, bounded to 10 s), and prints: mission success, telemetry age
p50/p95/max of the states received *during* the flood window, samples sent by the flooder, what the
ground station refused (budgets, decoding), the record's size, and the RSS of every service (and the
ground station's process) before and after the flood, and each telemetry age p95 against the stated bound
(:data:`BOUND_P95_MS`, README "Hostile input"). JSON goes to ``bench/results/flood.json`` with a ``pass``
flag (every flood within the bound).

    .venv/bin/python bench/flood.py [--cases none,event,...] [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import keys  # noqa: E402
from protocol.bus import Bus, BusConfig  # noqa: E402
from protocol.links import COMMAND, IMAGERY, TELEMETRY  # noqa: E402
from protocol.messages import DefectReport, Event, FrameEvidence  # noqa: E402
from protocol.rtp import ssrc_for  # noqa: E402

FLEET = "flood"
CASES = ("none", "state", "event", "camera", "defects")
#: the stated bound (README, "Hostile input"): the good telemetry's age p95 at the ground station while any
#: one writable key is flooded, 3 UAVs, the flooder on a core of its own
BOUND_P95_MS = 100.0


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def service_pids(root: int) -> dict[str, int]:
    """The mission process (the ground station) and each child service, by name."""
    out = {"gcs (mission process)": root}
    kids = subprocess.run(["pgrep", "-P", str(root)], capture_output=True, text=True).stdout.split()
    for pid in kids:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        words = [w.decode() for w in cmd]
        if "services.cli" in words:
            name = words[words.index("services.cli") + 1]
            if name == "edge" and "--uav" in words:
                name = f"uav{words[words.index('--uav') + 1]}"
            out[name] = int(pid)
    return out


def services_rss(root: int) -> dict[str, float | None]:
    """RSS of the mission process (the ground station) and of each child service, by name."""
    return {name: rss_mb(pid) for name, pid in service_pids(root).items()}


TICK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float | None:
    """User + system CPU time of a process so far, s (/proc/PID/stat fields 14 and 15)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def machine_busy_s() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine so far, all cores (/proc/stat)."""
    vals = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = vals[3] + vals[4]  # idle + iowait
    return (sum(vals) - idle) / TICK, sum(vals) / TICK


def cpu_usage(before: dict[str, float | None], after: dict[str, float | None], seconds: float) -> dict[str, float]:
    """Share of one core each process used between two :func:`cpu_s` snapshots, %."""
    return {n: round(100 * (after[n] - b) / seconds, 1) for n, b in before.items()
            if b is not None and after.get(n) is not None}


def seq_losses(states: list[dict], window: tuple[float, float] | None = None) -> dict[int, int]:
    """Per UAV, states missing from its received sequence numbers (between its first and last received)."""
    seqs: dict[int, set[int]] = {}
    for s in states:
        if window is None or window[0] <= s["rx"] <= window[1]:
            seqs.setdefault(s["msg"]["uav"], set()).add(s["msg"]["seq"])
    return {u: max(v) - min(v) + 1 - len(v) for u, v in sorted(seqs.items())}


#: who floods each case: a node that may write the key (the gateway's ACL by certificate: a compromised
#: UAV 1, a forged detector), so the flood reaches every subscriber as it would in the field
ROLE = {"state": "uav1", "event": "uav1", "camera": "uav1", "defects": "detector"}
KEYS = Path(__file__).resolve().parents[1] / ".keys" / "dev"


def flood(case: str, endpoints: list[str], seconds: float, stop: threading.Event) -> int:
    """Publish the case's flood for ``seconds``; the samples sent."""
    rng = np.random.default_rng(12)
    tls = {}
    if endpoints[0].startswith("tls/"):  # the mission runs secure (the default): the flooder holds its role's keys
        from protocol.keyset import KeySet

        ks = KeySet(KEYS, ROLE[case])
        tls = {"tls_ca": str(ks.ca), "tls_cert": str(ks.tls_cert), "tls_key": str(ks.tls_key)}
    with Bus(BusConfig(mode="client", connect=endpoints, multilink=True, **tls), FLEET, "flooder") as bus:
        if case == "state":
            pub = bus.publisher(keys.state(FLEET, 1), TELEMETRY)
            make = lambda i: b"\x01" + rng.integers(0, 256, 300, dtype=np.uint8).tobytes()  # noqa: E731
        elif case == "event":
            pub = bus.publisher(keys.event(FLEET, 1), COMMAND)
            make = lambda i: Event(source="uav/1", stamp=time.time(), kind="trust-refused", text="x" * 4000)  # noqa: E731
        elif case == "camera":
            pub = bus.publisher(keys.camera(FLEET, 1), IMAGERY)
            junk = rng.integers(0, 256, 50_000, dtype=np.uint8).tobytes()
            make = lambda i: bytes([0x80, 26]) + i.to_bytes(2, "big") + b"\0\0\0\0" + b"\x12\x34\x56\x78" + junk  # noqa
        else:
            pub = bus.publisher(keys.defects(FLEET), COMMAND)
            make = lambda i: DefectReport(uav=1, capture_id=i % 40, stamp_capture=time.time(),  # noqa: E731
                                          stamp_report=time.time(), method="it+",
                                          frame=FrameEvidence(ssrc=ssrc_for(1), seq=i % 65536, digest="00" * 32))
        n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < seconds and not stop.is_set():
            item = make(n)
            pub.put_bytes(item) if isinstance(item, bytes) else pub.put(item)
            n += 1
            if case == "camera":
                time.sleep(0.001)  # 50 KB frames: ~1000/s, more than any camera sends
        return n


def run_case(case: str, seconds: float, speed: float, onset: float, extra: list[str] | None = None) -> dict:
    out = Path(tempfile.mkdtemp(prefix=f"skynet-flood-{case}-"))
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "mission", "--quiet", "--speed", str(speed),
                             "--fleet", FLEET, "--out", str(out / "report"), *(extra or [])], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    mission = threading.Event()

    def reader() -> None:
        for line in proc.stdout:
            lines.append(line)
            if "phase: mission" in line:
                mission.set()

    threading.Thread(target=reader, daemon=True).start()
    res: dict = {"case": case}
    try:
        if not mission.wait(180):
            raise RuntimeError("no mission phase:\n" + "".join(lines[-30:]))
        log = (out / "report" / "services.log").read_text()
        m = re.search(r"listening on ((?:tcp|tls)/[\d.:]+\?rel=1), ((?:udp|tls)/[\d.:]+\?rel=0)", log)
        endpoints = [m.group(1), m.group(2)]
        time.sleep(onset)
        res["rss_before_mb"] = services_rss(proc.pid)
        pids = {**service_pids(proc.pid), "flooder (bench process)": os.getpid()}
        cpu0, busy0 = {n: cpu_s(p) for n, p in pids.items()}, machine_busy_s()
        t0 = time.time()
        res["sent"] = 0 if case == "none" else flood(case, endpoints, seconds, threading.Event())
        if case == "none":
            time.sleep(seconds)
        t1 = time.time()
        cpu1, busy1 = {n: cpu_s(p) for n, p in pids.items()}, machine_busy_s()
        res["window"] = (t0, t1)
        # share of one core per process during the flood window, and the machine's (2 cores = 200 %), the rest
        # being other work on the machine
        res["cpu_pct"] = cpu_usage(cpu0, cpu1, t1 - t0)
        res["machine_busy_pct"] = round(100 * (busy1[0] - busy0[0]) / (t1 - t0), 1)
        res["loadavg"] = os.getloadavg()[0]
        res["rss_after_mb"] = services_rss(proc.pid)
        proc.wait(600)
    finally:
        if proc.poll() is None:  # Ctrl-C: the launcher stops every service it started (no orphans)
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    rep = json.loads((out / "report" / "report.json").read_text())
    rec_path = out / "report" / "record.json"
    rec = json.loads(rec_path.read_text())
    ages = [1000 * (s["rx"] - s["msg"]["stamp"]) for s in rec["states"] if t0 <= s["rx"] <= t1]
    res.update(success=rep["success"], failures=rep["failures"][:3], states_in_window=len(ages),
               states_lost=seq_losses(rec["states"]), states_lost_in_window=seq_losses(rec["states"], (t0, t1)),
               age_ms={"p50": float(np.percentile(ages, 50)) if ages else None,
                       "p95": float(np.percentile(ages, 95)) if ages else None,
                       "max": float(max(ages)) if ages else None},
               refused=sum(rec.get("rejected", {}).values()), record_mb=rec_path.stat().st_size / 1e6,
               log_mb=(out / "report" / "mission.mcap").stat().st_size / 1e6
               if (out / "report" / "mission.mcap").exists() else None,
               report_md_kb=(out / "report" / "report.md").stat().st_size / 1e3, folder=str(out))
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--speed", type=float, default=4.0)
    p.add_argument("--onset", type=float, default=2.0, help="flood starts this long into the mission phase, s")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "flood.json"))
    p.add_argument("--bound-ms", type=float, default=BOUND_P95_MS, help="the telemetry age p95 bound, ms")
    p.add_argument("--mission-arg", action="append", default=[], help="passed to skynet mission (repeatable), "
                   "e.g. --mission-arg=--insecure")
    args = p.parse_args(argv)
    rows = []
    for case in args.cases.split(","):
        r = run_case(case, args.seconds, args.speed, args.onset, args.mission_arg)
        rows.append(r)
        a = r["age_ms"]
        r["bound_p95_ms"] = args.bound_ms
        r["within_bound"] = a["p95"] is not None and a["p95"] <= args.bound_ms
        print(f"{case:>8}: success {r['success']}, flood sent {r['sent']}, refused {r['refused']}, telemetry age "
              f"p50 {a['p50']:.1f} / p95 {a['p95']:.1f} ({'<=' if r['within_bound'] else '>'} {args.bound_ms:.0f}: "
              f"{'pass' if r['within_bound'] else 'FAIL'}) / max {a['max']:.1f} ms over {r['states_in_window']} states, "
              f"record.json {r['record_mb']:.2f} MB, mission log {r['log_mb'] or 0:.2f} MB, report.md "
              f"{r['report_md_kb']:.0f} kB", flush=True)
        print(f"{'':>10}states lost (seq gaps) whole mission {r['states_lost']}, in the window "
              f"{r['states_lost_in_window']}; CPU in the window (% of a core): "
              + ", ".join(f"{n} {v:.0f}" for n, v in r["cpu_pct"].items())
              + f"; machine {r['machine_busy_pct']:.0f} of 200, load {r['loadavg']:.1f}")
        for name in r["rss_before_mb"]:
            b, e = r["rss_before_mb"][name], r["rss_after_mb"].get(name)
            print(f"{'':>10}{name:<24} RSS {b or 0:7.1f} -> {e or 0:7.1f} MB")
        if r["failures"]:
            print(f"{'':>10}failures: {r['failures']}")
    floods = [r for r in rows if r["case"] != "none"]
    passed = all(r["within_bound"] for r in floods)
    print(f"bound: telemetry age p95 <= {args.bound_ms:.0f} ms under every flood: {'pass' if passed else 'FAIL'} "
          f"({sum(r['within_bound'] for r in floods)}/{len(floods)} floods within it)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"bound_p95_ms": args.bound_ms, "pass": passed, "cases": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
