"""Latency/loss injection experiment: the default mission under impaired links.

Runs ``skynet mission`` once per impairment (user-space netem proxies between a node and the
gateway, :mod:`services.netem`) and tabulates, from each mission's report: success, imagery
delivered, capture-to-report latency, telemetry age, command acknowledgement time and the
formation error. The impairments hit UAV 2's link (its telemetry, imagery and commands) and the
detector's link (all imagery), the two places where the paper's 4G relay would hurt.

    .venv/bin/python bench/impair.py [--speed 6] [--out bench/results/impair.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from mission import find, run, write_rows  # bench/mission.py: one mission run and its report

CASES = [
    ("clean", []),
    ("uav2 4G-like: delay 50ms jitter 10ms", ["uav2=delay 50ms jitter 10ms"]),
    ("detector: loss 5% (after 2s)", ["detector=after 2s loss 5%"]),
    ("uav2 delay 100ms + detector loss 10%", ["uav2=delay 100ms jitter 20ms", "detector=after 2s loss 10%"]),
    ("uav2 rate 2mbit + loss 2%", ["uav2=after 2s rate 2mbit loss 2%"]),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speed", type=float, default=6.0)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "impair.json"))
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, impair in CASES:
            r = run(args.speed, Path(tmp) / f"case{len(rows)}", [a for spec in impair for a in ("--impair", spec)])
            rep = r["report"]
            links = rep.get("links", {})
            nan = float("nan")

            def g(d: dict, *path):
                return find(d, *path, default=nan)

            row = {
                "case": name, "impair": impair, "exit": r["exit"], "success": rep.get("success"),
                "wall_s": r["wall_s"], "failures": rep.get("failures", []),
                "imagery_delivered": g(links, "imagery", "delivered"), "imagery_sent": g(links, "imagery", "sent"),
                "capture_to_report_p50_ms": g(links, "imagery", "capture_to_report_ms", "p50"),
                "capture_to_report_p95_ms": g(links, "imagery", "capture_to_report_ms", "p95"),
                "telemetry_age_p95_ms": g(links, "telemetry", "age_ms", "p95"),
                "ack_p95_ms": g(links, "command", "latency_ms", "p95"),
                "formation_rms_m": g(rep, "formation", "rms_m"),
                "captures": f"{g(rep, 'captures', 'imaged')}/{g(rep, 'captures', 'planned')}",
                "recall": g(rep, "defects", "recall"),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("\n| case | success | captures imaged | capture->report p50 / p95 (ms) | telemetry age p95 (ms) |"
          " command ack p95 (ms) | formation RMS (m) | defect recall |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['success']} | {r['captures']} | {r['capture_to_report_p50_ms']:.1f} / "
              f"{r['capture_to_report_p95_ms']:.1f} | {r['telemetry_age_p95_ms']:.1f} | {r['ack_p95_ms']:.1f} | "
              f"{r['formation_rms_m']:.2f} | {r['recall']:.2f} |")
    write_rows(rows, args.out)


if __name__ == "__main__":
    main()
