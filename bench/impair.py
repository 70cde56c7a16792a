"""Latency/loss injection benchmark: the issue-7 goals, measured with ``skynet experiment``.

A thin wrapper over :mod:`services.experiment`: flies the default mission with every best-effort
link impaired (``--links all/udp``: each node's uplink and the SkyNet links) at 200 ms delay and
0, 20 and 40 % random loss, with imagery recovery on and off, then checks the impairment goals:

- 20 % loss, 200 ms delay, recovery on: the mission completes, 100 % of commands are
  acknowledged, capture coverage is 100 %, telemetry age p95 < 500 ms;
- 40 % loss: every run ends by itself with a report (completes or stops safely), none hangs.

Writes the experiment's ``results.json`` content plus the goal verdicts to
``bench/results/impair.json``; the runs themselves go to a temporary folder (``--keep DIR`` to keep
them, with the table and plots).

    .venv/bin/python bench/impair.py [--speed 6] [--repeat 1] [--loss-pct 0,20,40] [--delay-ms 200]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from services.experiment import cli as experiment


def _cell(doc: dict, loss: float, delay: float, recovery: bool) -> dict | None:
    for c in doc["cells"]:
        cell = c["cell"]
        if (cell["loss_pct"], cell["delay_ms"], cell["recovery"]) == (loss, delay, recovery):
            return c
    return None


def _mean(cell: dict | None, metric: str) -> float | None:
    st = (cell or {}).get("metrics", {}).get(metric)
    return None if not st else st["mean"]


def goals(doc: dict) -> list[dict]:
    """The issue's goals against the measured cells (those that ran)."""
    out = []
    c20 = _cell(doc, 20.0, 200.0, True)
    if c20 is not None:
        n = c20["runs"]
        age = _mean(c20, "telemetry_age_p95_ms")
        out += [
            {"goal": "20% loss, 200 ms: the mission completes", "measured": f"{c20['succeeded']}/{n}",
             "pass": c20["succeeded"] == n},
            {"goal": "20% loss, 200 ms: 100% of commands acknowledged",
             "measured": _mean(c20, "cmd_ack_ratio"), "pass": _mean(c20, "cmd_ack_ratio") == 1.0},
            {"goal": "20% loss, 200 ms, recovery on: capture coverage 100%", "measured": _mean(c20, "coverage"),
             "pass": (c20["metrics"].get("coverage") or {}).get("min") == 1.0},
            {"goal": "20% loss, 200 ms: telemetry age p95 < 500 ms", "measured": age,
             "pass": age is not None and (c20["metrics"]["telemetry_age_p95_ms"]["max"] < 500.0)},
        ]
    c40 = [c for c in doc["cells"] if c["cell"]["loss_pct"] == 40.0]
    if c40:
        hung = sum(c["hung"] + c["failed_to_report"] for c in c40)
        out.append({"goal": "40% loss: every run completes or stops safely with a report (never hangs)",
                    "measured": f"{sum(c['succeeded'] for c in c40)} completed, "
                                f"{sum(c['runs'] for c in c40) - hung - sum(c['succeeded'] for c in c40)} stopped "
                                f"with a report, {hung} hung or without report",
                    "pass": hung == 0})
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--speed", default="6")
    p.add_argument("--repeat", default="1")
    p.add_argument("--loss-pct", dest="loss", default="0,20,40")
    p.add_argument("--delay-ms", dest="delay", default="200")
    p.add_argument("--recovery", default="on,off")
    p.add_argument("--timeout-s", dest="timeout", default="300")
    p.add_argument("--keep", default=None, help="keep the runs, table and plots in this folder")
    p.add_argument("--out", default=str(Path(__file__).parent / "results" / "impair.json"))
    a = p.parse_args()
    argv = ["--loss-pct", a.loss, "--delay-ms", a.delay, "--recovery", a.recovery, "--repeat", a.repeat,
            "--speed", a.speed, "--links", "all/udp", "--timeout-s", a.timeout]
    args = experiment.build_parser().parse_args(argv)
    try:
        cells, runs = experiment.check_options(args)
    except ValueError as e:
        print(f"bench/impair.py: error: {e}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(a.keep or tmp)
        doc, code = experiment.run_experiment(args, cells, runs, folder)
    doc["goals"] = goals(doc)
    for g in doc["goals"]:
        print(f"{'PASS' if g['pass'] else 'FAIL'}  {g['goal']}: {g['measured']}")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for r in doc["runs"]:  # machine-specific paths stay out of the committed results
        r["out"] = Path(r["out"]).name
        cmd = ["skynet", *r["command"][3:]]
        r["command"] = [r["out"] if i and cmd[i - 1] == "--out" else x for i, x in enumerate(cmd)]
    out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {out}")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
