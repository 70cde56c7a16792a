"""Whole-system benchmark: the default mission at real time and at the default speed factor.

For each speed factor, runs ``skynet mission`` (all services as processes on loopback) and
reports the mission's wall time and CPU time (the launcher and every service, from
``wait4``'s rusage), the capture-to-defect-report latency (median, p95) with three UAVs
streaming, and the telemetry age at the ground station (median, p95), read from the mission's
own report.json. Goals: capture-to-report p95 < 150 ms; telemetry age p95 < 50 ms.

    .venv/bin/python bench/mission.py [--speeds 1 4] [--out bench/results/mission.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def find(d: dict, *path: str, default=None):
    for p in path:
        if not isinstance(d, dict) or p not in d:
            return default
        d = d[p]
    return d


def run(speed: float, out: Path, extra: list[str] | None = None) -> dict:
    """One ``skynet mission`` into ``out``: exit status, wall time, its report.json and the output's tail."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "mission", "--speed", str(speed), "--quiet",
                             "--out", str(out), *(extra or [])], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    output, _ = proc.communicate()  # reaps the launcher: its and its services' CPU go to os.times().children_*
    wall = time.perf_counter() - t0
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").exists() else {}
    return {"speed": speed, "exit": proc.returncode, "wall_s": wall, "report": report, "tail": output[-2000:]}


def write_rows(rows: list[dict], path: str) -> None:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2))
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 4.0])
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "mission.json"))
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for speed in args.speeds:
            before = os.times()
            r = run(speed, Path(tmp) / f"speed-{speed:g}")
            after = os.times()
            cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
            rep = r["report"]
            lat = find(rep, "links", "imagery", "capture_to_report_ms", default={}) or {}
            age = find(rep, "links", "telemetry", "age_ms", default={}) or {}
            row = {
                "speed": speed, "exit": r["exit"], "success": rep.get("success"), "wall_s": r["wall_s"],
                "cpu_s": cpu, "cpu_share_of_2_cores": cpu / (2 * r["wall_s"]),
                "mission_sim_s": find(rep, "mission", "sim_duration_s"),
                "capture_to_report_ms": lat, "telemetry_age_ms": age,
            }
            rows.append(row)
            print(json.dumps(row, indent=1), flush=True)
            if r["exit"] != 0:
                print(r["tail"])
    print("\n| speed | success | wall (s) | CPU (s) | capture->report p50 / p95 (ms) | telemetry age p50 / p95 (ms) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        c, a = r["capture_to_report_ms"], r["telemetry_age_ms"]
        print(f"| x{r['speed']:g} | {r['success']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
              f"{c.get('p50', float('nan')):.1f} / {c.get('p95', float('nan')):.1f} | "
              f"{a.get('p50', float('nan')):.1f} / {a.get('p95', float('nan')):.1f} |")
    write_rows(rows, args.out)


if __name__ == "__main__":
    main()
