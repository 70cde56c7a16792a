"""The launcher vs docker compose, side by side: the same mission (3 UAVs, 4x, seed 0) both ways.

Runs ``skynet mission`` (every service a process on loopback), then ``scripts/compose-e2e.sh`` with
the unimpaired compose run (an engine, the image, ``up --exit-code-from gcs``; see README "docker
compose"), and prints from each mission's own report.json: verdict, captures, formation RMS,
telemetry age, capture-to-report latency, the mission's wall time, and the time from the command to
the verdict; for compose also the image size, build times and per-container CPU and memory.

    .venv/bin/python bench/compose.py [--out bench/results/compose.json]
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

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"


def figures(report: dict) -> dict:
    links = report.get("links") or {}
    tel = (links.get("telemetry") or {}).get("latency_ms") or {}
    img = (links.get("imagery") or {}).get("latency_ms") or {}
    cap = report.get("captures") or {}
    return {"success": report.get("success"), "captures": f"{cap.get('imaged')}/{cap.get('planned')}",
            "formation_rms_m": (report.get("formation") or {}).get("rms_m"),
            "telemetry_age_p50_ms": tel.get("p50"), "telemetry_age_p95_ms": tel.get("p95"),
            "capture_to_report_p95_ms": img.get("p95"),
            "mission_wall_s": (report.get("mission") or {}).get("wall_time_s")}


def run_launcher() -> dict:
    with tempfile.TemporaryDirectory() as d:
        t = time.monotonic()
        p = subprocess.run([str(ROOT / ".venv/bin/skynet"), "mission", "--quiet", "--out", d], cwd=ROOT,
                           capture_output=True, text=True)
        wall = time.monotonic() - t
        f = figures(json.loads((Path(d) / "report.json").read_text())) if (Path(d) / "report.json").exists() else {}
    return {**f, "exit": p.returncode, "command_to_verdict_s": wall}


def run_compose() -> dict:
    env = os.environ | {"COMPOSE_E2E_RUNS": "plain"}
    p = subprocess.run(["bash", str(ROOT / "scripts/compose-e2e.sh")], cwd=ROOT, env=env, capture_output=True,
                       text=True)
    print(p.stdout, end="")
    summary = json.loads((RESULTS / "compose-e2e.json").read_text())
    rep = RESULTS / "compose-e2e-plain-report" / "report.json"
    f = figures(json.loads(rep.read_text())) if rep.exists() else {}
    return {**f, "exit": p.returncode, "command_to_verdict_s": (summary.get("up_to_verdict_s") or {}).get("plain"),
            "image_mb": summary.get("image_mb"), "build_s": summary.get("build_s"),
            "build_steps_cached": f"{summary.get('build_steps_cached')}/{summary.get('build_steps')}"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=RESULTS / "compose.json")
    a = ap.parse_args()
    rows = {"launcher": run_launcher(), "compose": run_compose()}
    keys = ["exit", "success", "captures", "formation_rms_m", "telemetry_age_p50_ms", "telemetry_age_p95_ms",
            "capture_to_report_p95_ms", "mission_wall_s", "command_to_verdict_s"]
    fmt = lambda v: f"{v:.2f}" if isinstance(v, float) else str(v)  # noqa: E731
    print(f"{'':28s} {'launcher':>12s} {'compose':>12s}")
    for k in keys:
        print(f"{k:28s} {fmt(rows['launcher'].get(k)):>12s} {fmt(rows['compose'].get(k)):>12s}")
    for k in ("image_mb", "build_s", "build_steps_cached"):
        print(f"{k:28s} {'':>12s} {fmt(rows['compose'].get(k)):>12s}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"load_avg": os.getloadavg(), **rows}, indent=1))
    return 0 if all(r.get("exit") == 0 for r in rows.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
