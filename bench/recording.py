"""Mission recording (services.recording): MCAP size per mission minute and the recording overhead.

Runs ``skynet mission`` (3 UAVs, ``--speed``) with the recorder and with ``--no-record``,
alternately, ``--repeat`` times each, and reports the whole run's CPU time (every process of the
network, from ``getrusage(RUSAGE_CHILDREN)``), the wall time, the MCAP file's size per minute of
wall time and per minute of mission (simulated) time, and the recorder thread's own CPU time
(the file's ``skynet.recorder`` metadata).

    .venv/bin/python bench/recording.py [--speed 4] [--repeat 1] [--out bench/results/recording.json]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(record: bool, speed: float, out: Path) -> dict:
    c0, t0 = children_cpu(), time.monotonic()
    args = [sys.executable, "-m", "services.cli", "mission", "--speed", str(speed), "--quiet", "--out", str(out)]
    proc = subprocess.run(args + ([] if record else ["--no-record"]), cwd=ROOT, capture_output=True, text=True)
    wall, cpu = time.monotonic() - t0, children_cpu() - c0
    report = json.loads((out / "report.json").read_text())
    row = {"record": record, "ok": proc.returncode == 0, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
           "mission_wall_s": round(report["wall_time_s"], 1), "sim_s": round(report["sim_time_s"] or 0, 1)}
    mcap = out / "mission.mcap"
    if record and mcap.exists():
        sys.path.insert(0, str(ROOT))
        from mcap.reader import make_reader

        with open(mcap, "rb") as f:
            meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}.get("skynet.recorder", {})
        size = mcap.stat().st_size
        row.update(mcap_MB=round(size / 1e6, 2), MB_per_wall_min=round(size / 1e6 / (report["wall_time_s"] / 60), 2),
                   MB_per_sim_min=round(size / 1e6 / (report["sim_time_s"] / 60), 2),
                   recorder_cpu_s=float(meta.get("cpu_s", "nan")), dropped=int(meta.get("dropped", 0)))
    return row


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "bench/results/recording.json"))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-rec-"))
    rows = []
    for k in range(args.repeat):
        for record in (True, False):
            rows.append(run(record, args.speed, tmp / f"{k}-{record}"))
            print(rows[-1], flush=True)
    on = [r["cpu_s"] for r in rows if r["record"]]
    off = [r["cpu_s"] for r in rows if not r["record"]]
    summary = {"speed": args.speed, "cpu_s_with": statistics.mean(on), "cpu_s_without": statistics.mean(off),
               "overhead_percent": round(100 * (statistics.mean(on) / statistics.mean(off) - 1), 1)}
    print(summary)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"rows": rows, "summary": summary}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
