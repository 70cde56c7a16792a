"""The nominal mission flown with each detector method, back to back: latency and the wall's object scores.

    .venv/bin/python bench/mission_methods.py [--methods it+r learned] [--rounds 1] [--speed 4]
                                              [--out bench/results/mission_methods.json]

The learned method runs on the runtime ``$SKYNET_DETECTOR_RUNTIME`` chooses (default OpenVINO when the
extra ``fast`` is installed, else OpenCV's cv2.dnn), which the JSON records. Each round runs ``skynet mission --method M`` (the launcher, default secure mode: TLS and the ACL, three
UAVs, the monorail wall at 640 x 480) once per method, interleaved so that the machine's load falls on
both alike, and reads the mission's own report.json: capture-to-report p50 / p95 (goal: p95 < 150 ms
for three UAVs), the detector's queue and worker times, and the object-level recall and precision of the
defect reports against the synthetic wall's cracks (:func:`services.gcs.scoring.score_defects`; goal:
precision >= 0.95 at recall 1.00). Prints a Markdown table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from mission import find, run  # noqa: E402  (bench/mission.py: one `skynet mission` and its report)


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=False).stdout.strip()
    except OSError:
        return "?"


def learned_runtime() -> str:
    """The learned method's runtime the missions' detector workers choose (they inherit this environment)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from services.detector.learned import runtime

    return runtime()


def row(method: str, rnd: int, r: dict) -> dict:
    rep = r["report"]
    lat = find(rep, "links", "imagery", "capture_to_report_ms", default={}) or {}
    d = rep.get("defects") or {}
    return {"method": method, "round": rnd, "exit": r["exit"], "success": rep.get("success"), "wall_s": r["wall_s"],
            "capture_to_report_ms": lat, "recall": d.get("recall"), "precision": d.get("precision"),
            "truth": d.get("n_truth"), "found": d.get("n_found"), "reported": d.get("n_reported"),
            "true": d.get("n_true"), "failures": rep.get("failures"), "tail": r["tail"][-600:] if r["exit"] else ""}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=["it+r", "learned"])
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "mission_methods.json")
    a = ap.parse_args()
    rows = []
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(a.rounds):
            for m in a.methods:
                r = run(a.speed, Path(tmp) / f"{m}-{rnd}", ["--method", m])
                rows.append(row(m, rnd, r))
                print(json.dumps(rows[-1]), flush=True)
                if r["exit"] != 0:
                    print(r["tail"])
    doc = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": commit(),
           "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load0[0]:.1f} at the start "
                      f"and {os.getloadavg()[0]:.1f} at the end",
           "command": " ".join(["bench/mission_methods.py", *sys.argv[1:]]), "learned_runtime": learned_runtime(),
           "rows": rows}
    print(f"\n{doc['date']}, commit {doc['commit']}, {doc['machine']}, learned on {doc['learned_runtime']}\n")
    print("| method | round | success | capture->report p50 / p95 (ms) | recall | precision (reports on a crack / reports) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        c = r["capture_to_report_ms"]
        rec = "–" if r["recall"] is None else f"{r['recall']:.2f}"
        prec = "–" if r["precision"] is None else f"{r['precision']:.2f}"
        print(f"| {r['method']} | {r['round'] + 1} | {r['success']} | {c.get('p50', float('nan')):.0f} / "
              f"{c.get('p95', float('nan')):.0f} | {rec} | {prec} ({r['true']} / {r['reported']}) |")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
