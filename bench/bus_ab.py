"""``bench/bus.py`` from two trees side by side: each tree's script with its own .venv, alternating
(A, B, A, B ...), so that the machine's noise falls on both alike; the figures of every run and their
medians go to one JSON.

    .venv/bin/python bench/bus_ab.py --before ../before [--runs 2] [--quick] [--out bench/results/bus-ab.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
FIGURES = ("rtt_median_us", "rtt_p99_us", "msgs_per_s")


def run(tree: Path, quick: bool, out: Path) -> dict:
    """One run of ``bench/bus.py`` in ``tree`` with that tree's interpreter, niced."""
    python = tree / ".venv" / "bin" / "python"
    argv = ["nice", "-n", "10", str(python), str(tree / "bench" / "bus.py"), "--out", str(out)]
    if quick:
        argv.append("--quick")
    subprocess.run(argv, cwd=tree, check=True, env={**os.environ, "PYTHONPATH": str(tree)})
    return json.loads(out.read_text())


def summary(runs: list[dict]) -> list[dict]:
    """Per (topology, size): the median over runs of each figure of the bus and raw sides and their ratios."""
    rows = []
    for i, first in enumerate(runs[0]["rows"]):
        row = {"topology": first["topology"], "size": first["size"]}
        for impl in ("raw", "bus"):
            for fig in FIGURES:
                row[f"{impl}_{fig}"] = statistics.median(r["rows"][i][impl][fig] for r in runs)
        for fig in ("latency_ratio", "p99_ratio", "throughput_share"):
            row[fig] = statistics.median(r["rows"][i][fig] for r in runs)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, type=Path, help="the other tree (bootstrapped: its .venv)")
    parser.add_argument("--runs", type=int, default=2, help="runs per tree, alternating")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=Path, default=HERE / "bench" / "results" / "bus-ab.json")
    args = parser.parse_args()
    trees = {"before": args.before.resolve(), "after": HERE}
    commits = {name: subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tree, capture_output=True,
                                    text=True).stdout.strip() for name, tree in trees.items()}
    runs: dict[str, list[dict]] = {name: [] for name in trees}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for k in range(args.runs):
        for name, tree in trees.items():
            print(f"== {name} ({commits[name]}) run {k + 1}", flush=True)
            runs[name].append(run(tree, args.quick, args.out.with_suffix(f".{name}.{k}.json")))
    result = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "commits": commits,
              "load": os.getloadavg(), "cores": os.cpu_count(), "runs": runs,
              "summary": {name: summary(r) for name, r in runs.items()}}
    args.out.write_text(json.dumps(result, indent=2))
    print("\n| topology | size | tree | bus RTT median / p99 (µs) | latency ratio | bus msg/s | throughput share |")
    print("|---|---|---|---|---|---|---|")
    for i in range(len(result["summary"]["after"])):
        for name in trees:
            r = result["summary"][name][i]
            print(f"| {r['topology']} | {r['size']} B | {name} | {r['bus_rtt_median_us']:.0f} / "
                  f"{r['bus_rtt_p99_us']:.0f} | {r['latency_ratio']:.2f} | {r['bus_msgs_per_s']:.0f} | "
                  f"{100 * r['throughput_share']:.0f} % |")
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
