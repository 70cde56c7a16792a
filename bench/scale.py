"""Scale benchmark: the mission for fleets of N UAVs at real time, and 12 MP frames.

For each N, runs ``skynet mission --uavs N --speed S`` (all services as processes on loopback)
and reports: success; CPU per UAV per simulated second (every process of the run, from
``wait4``'s rusage, and the edges alone, sampled from ``/proc`` while all N edges run); the edge
processes' resident memory (max over the run, median over the edges); telemetry age p95 at the
ground station; capture-to-report p95; plan time. The edges' steady CPU (cores) is fitted
against N, ``a + b N`` and ``a + b N + c N^2``: the goal is linear, ``b <= 0.03`` cores per UAV
at 1x. With ``--frames`` it also flies the paper's 12 MP frames (``--frame-size 4000x3000``) with
capture frames on each link class side by side: capture-to-report p95 and the frames that
reached the detector only through recovery (lost on a clean link) or not at all.

    .venv/bin/python bench/scale.py [--uavs 3 12 24 48] [--speed 1] [--frames] [--sites 1 2]
                                    [--idle 3 12 24 48 99] [--out bench/results/scale.json]

Fleets above 10 UAVs fly stacked in rows (:func:`edge.geometry.formation.offsets_for`), which the monorail
box holds up to 50 UAVs; ``--idle`` measures any fleet as ``skynet up``: every edge on the
ground, sharing state with its formation at 20 Hz.

``--sites 1 2`` flies each N with each number of gateways (``skynet mission --sites S``, one per site,
a router mesh on loopback; S up to the number of formations) one after the other, side by side.

Heavy: N = 100 on 2 cores is most of the machine for several minutes. Never run in tests.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mission import find, write_rows  # noqa: E402  (bench/mission.py: the same run and report reading)

TICK = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                stat = Path(f"/proc/{d}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            kids.setdefault(ppid, []).append(int(d))
    return kids


def _edges(root: int) -> list[int]:
    """The ``skynet edge`` processes under ``root``."""
    kids, out, todo = _children(), [], [root]
    while todo:
        p = todo.pop()
        for c in kids.get(p, []):
            todo.append(c)
            try:
                cmd = Path(f"/proc/{c}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"edge" in cmd and b"--uav" in cmd:
                out.append(c)
    return out


def _cpu_rss(pid: int) -> tuple[float, int] | None:
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(f[11]) + int(f[12])) / TICK, int(f[21]) * PAGE  # utime + stime (s), rss (bytes)


def _pss(pid: int) -> int | None:
    """The proportional set size (bytes): RSS with each shared page divided among the processes mapping it.
    RSS counts the shared libraries (zenoh, cv2, numpy: ~60 MB) in full in every edge; PSS is what one more
    edge costs the machine."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


class EdgeSampler(threading.Thread):
    """Every ``period`` s: the CPU seconds and RSS of each edge under ``root``."""

    def __init__(self, root: int, n: int, period: float = 2.0):
        super().__init__(daemon=True)
        self.root, self.n, self.period = root, n, period
        self.samples: list[tuple[float, dict[int, tuple[float, int]]]] = []
        self.pss: dict[int, int] = {}  # max over the run, every 5th sample
        self.stop = threading.Event()

    def run(self) -> None:
        k = 0
        while not self.stop.wait(self.period):
            now = time.monotonic()
            got = {p: v for p in _edges(self.root) if (v := _cpu_rss(p)) is not None}
            self.samples.append((now, got))
            k += 1
            if k % 5 == 1:
                for p in got:
                    if (m := _pss(p)) is not None:
                        self.pss[p] = max(self.pss.get(p, 0), m)

    def figures(self) -> dict:
        full = [(t, s) for t, s in self.samples if len(s) >= self.n]
        rss = {}
        for _, s in self.samples:
            for p, (_, r) in s.items():
                rss[p] = max(rss.get(p, 0), r)
        out = {"edge_rss_mb_median": statistics.median(rss.values()) / 2**20 if rss else None,
               "edge_rss_mb_max": max(rss.values()) / 2**20 if rss else None,
               "edge_pss_mb_median": statistics.median(self.pss.values()) / 2**20 if self.pss else None,
               "edge_pss_mb_sum": sum(self.pss.values()) / 2**20 if self.pss else None}
        if len(full) >= 3:
            # the edges alive in both the first and the last full sample: their CPU over that window
            (t0, a), (t1, b) = full[0], full[-1]
            common = set(a) & set(b)
            cores = sum(b[p][0] - a[p][0] for p in common) / (t1 - t0)
            out.update(edge_cores=cores, edge_cores_per_uav=cores / max(1, len(common)), window_s=t1 - t0)
        return out


def run_one(n: int, speed: float, out: Path, extra: list[str]) -> dict:
    before = os.times()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "mission", "--uavs", str(n), "--speed", str(speed),
                             "--quiet", "--out", str(out), *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    sampler = EdgeSampler(proc.pid, n)
    sampler.start()
    output, _ = proc.communicate()
    sampler.stop.set()
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    rep = json.loads((out / "report.json").read_text()) if (out / "report.json").exists() else {}
    sim_s = wall * speed
    imagery = rep.get("imagery") or {}
    cams = [v for k, v in imagery.items() if isinstance(v, dict) and k.endswith(".cam0")]
    row = {
        "uavs": n, "speed": speed, "args": extra, "exit": proc.returncode, "success": rep.get("success"),
        "failures": rep.get("failures"), "wall_s": wall, "cpu_s": cpu,
        "cpu_per_uav_per_sim_s": cpu / (n * sim_s),
        "plan_s": find(rep, "planner", "plan_request_s"),
        "telemetry_age_p95_ms": find(rep, "links", "telemetry", "latency_ms", "p95"),
        "capture_to_report_p95_ms": find(rep, "links", "imagery", "latency_ms", "p95"),
        "captures": rep.get("captures"),
        "frames_recovered": sum(c.get("recovered", 0) for c in cams),
        "frames_lost": sum(c.get("lost", 0) for c in cams),
        **sampler.figures(),
    }
    if proc.returncode != 0:
        row["tail"] = output[-1500:]
    return row


def run_idle(n: int, speed: float, seconds: float, checkout: Path | None = None, extra: list[str] | None = None) -> dict:
    """``skynet up --uavs N`` (gateway, N edges on the ground sharing state at 20 Hz, planner,
    detector) for ``seconds`` after every edge is up: the edges' steady CPU and memory without a
    mission, for fleets too long for the scenario's box as one line."""
    t0 = time.perf_counter()
    python = sys.executable if checkout is None else str(checkout / ".venv" / "bin" / "python")
    proc = subprocess.Popen([python, "-m", "services.cli", "up", "--uavs", str(n), "--speed", str(speed), *(extra or [])],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=checkout)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and len(_edges(proc.pid)) < n and proc.poll() is None:
        time.sleep(1.0)
    while time.monotonic() < deadline and sum("board up" in x for x in list(lines)) < n and proc.poll() is None:
        time.sleep(1.0)
    up_s = time.perf_counter() - t0
    sampler = EdgeSampler(proc.pid, n)
    sampler.start()
    time.sleep(seconds)
    sampler.stop.set()
    proc.send_signal(2)
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    kind = (["up"] if checkout is None else ["up", f"baseline {checkout}"]) + list(extra or [])
    row = {"uavs": n, "speed": speed, "args": kind, "exit": proc.returncode, "up_s": up_s, **sampler.figures()}
    if row.get("edge_cores") is None:
        row["tail"] = "".join(lines[-30:])
    return row


def fit(rows: list[dict], kind: list[str] | None = None) -> dict:
    kind = kind or []
    pts = [(r["uavs"], r["edge_cores"]) for r in rows if r.get("edge_cores") is not None and r["args"] == kind]
    if len(pts) < 2:
        return {}
    n, c = np.array(pts, float).T
    lin = np.polyfit(n, c, 1)
    out = {"linear": {"cores_per_uav": lin[0], "intercept": lin[1]}}
    if len(pts) >= 3:
        q = np.polyfit(n, c, 2)
        out["quadratic"] = {"n2": q[0], "n": q[1], "intercept": q[2]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--uavs", type=int, nargs="*", default=[3, 12, 24, 48])
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--frames", action="store_true", help="also 12 MP frames, reliable vs best-effort capture link")
    parser.add_argument("--idle", type=int, nargs="*", default=[],
                        help="fleet sizes run as `skynet up` (no mission): the edges' steady cost alone")
    parser.add_argument("--idle-s", type=float, default=40.0, help="seconds sampled per --idle run")
    parser.add_argument("--idle-args", nargs="*", default=[], help="more options of the --idle runs' skynet up "
                        "(not given to --baseline), e.g. --preview-hz 0")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="another checkout of the project (with its .venv) whose `skynet up` runs the same "
                             "--idle sizes side by side, e.g. an older tree")
    parser.add_argument("--sites", type=int, nargs="*", default=[1],
                        help="numbers of gateways each N flies with (skynet mission --sites S), side by side")
    parser.add_argument("--mission-args", nargs="*", default=[],
                        help="more options of every mission run's skynet mission, e.g. --gcs-state-hz 5")
    parser.add_argument("--reports", type=Path, default=None,
                        help="keep each mission's report folder under DIR/run-K (default: a temporary folder)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "scale.json"))
    args = parser.parse_args()
    runs = [(n, ([] if s == 1 else ["--sites", str(s)]) + args.mission_args) for n in args.uavs for s in args.sites
            if s <= -(-n // 3)]  # at most one site per formation of 3
    if args.frames:
        runs += [(3, ["--frame-size", "4000x3000", "--capture-link", link]) for link in ("reliable", "best-effort")]
        # the detector's reduced decode (default 1 MP: a 12 MP frame detected on its 1/4 decode) against full size
        runs += [(3, ["--frame-size", "4000x3000", "--capture-link", "reliable", "--detect-max-mp", "0"])]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (n, extra) in enumerate(runs):
            row = run_one(n, args.speed, (args.reports or Path(tmp)) / f"run-{i}", extra)
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "captures"}), flush=True)
        for n in args.idle:
            for checkout in ([None, args.baseline] if args.baseline else [None]):
                row = run_idle(n, args.speed, args.idle_s, checkout, None if checkout else args.idle_args)
                rows.append(row)
                print(json.dumps(row), flush=True)
    f = {"mission": fit(rows), "up": fit(rows, ["up"])}
    if args.idle_args:
        f["up " + " ".join(args.idle_args)] = fit(rows, ["up", *args.idle_args])
    if args.baseline:
        f["up baseline"] = fit(rows, ["up", f"baseline {args.baseline}"])
    print("\n| N | args | success | CPU s | CPU / UAV / sim s | edge cores / UAV | edge RSS MB (median) "
          "| edge PSS MB (median) | telemetry age p95 ms | capture->report p95 ms | recovered / lost | plan s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    nan = float("nan")
    for r in rows:
        if r["args"][:1] == ["up"]:
            print(f"| {r['uavs']} | {' '.join(r['args'])} (no mission) | exit {r['exit']} | - | - | {r.get('edge_cores_per_uav') or nan:.4f} | "
                  f"{r.get('edge_rss_mb_median') or nan:.0f} | {r.get('edge_pss_mb_median') or nan:.0f} | - | - | - | - |")
            continue
        print(f"| {r['uavs']} | {' '.join(r['args'])} | {r['success']} | {r['cpu_s']:.0f} | "
              f"{r['cpu_per_uav_per_sim_s']:.4f} | {r.get('edge_cores_per_uav') or nan:.4f} | "
              f"{r.get('edge_rss_mb_median') or nan:.0f} | {r.get('edge_pss_mb_median') or nan:.0f} | "
              f"{r['telemetry_age_p95_ms'] or nan:.1f} | "
              f"{r['capture_to_report_p95_ms'] or nan:.0f} | {r['frames_recovered']:.0f} / {r['frames_lost']:.0f} | "
              f"{r['plan_s'] or nan:.2f} |")
    print("\nedge cores vs N:", json.dumps(f))
    write_rows([*rows, {"fit": f}], args.out)


if __name__ == "__main__":
    main()
