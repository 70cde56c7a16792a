"""Planner benchmark: the paper's setting (150 particles, 10 waypoints, 300 iterations).

Prints Table I over 20 seeds (0-19; θ-PSO's settings were chosen on seeds 100-139) and θ-PSO's
time per plan against pyswarms' GlobalBestPSO on the same cost and budget, measured side by side
in this run; writes bench/results/plan.json. Same as ``skynet plan bench``, plus the CPU times.
Runs on one thread: BLAS threading is switched off before numpy is imported.
"""

import json
import os
import sys
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.planner.cli import main  # noqa: E402

if __name__ == "__main__":
    argv = sys.argv[1:]
    rc = main(["bench", *argv])
    out = Path(argv[argv.index("--out") + 1] if "--out" in argv else "bench/results/plan.json")
    if rc == 0 and out.exists():
        r = json.loads(out.read_text())
        line = f"medians of {r['repeats']} alternating runs: theta-pso CPU {r['theta_pso_cpu_s']:.3f} s"
        if r.get("pyswarms_s") is not None:
            line += (f", pyswarms CPU {r['pyswarms_cpu_s']:.3f} s (CPU ratio "
                     f"{r['pyswarms_over_theta_pso_cpu']:.2f}x); evaluations {r['theta_pso_evaluations']} "
                     f"vs {r['pyswarms_evaluations']}")
        print(line)
        print("cost (P5) per call of " + str(r["compare"]["particles"]) + " paths, ms: "
              + ", ".join(f"{k} {v:.3f}" for k, v in r["cost_call_ms"].items()))
    raise SystemExit(rc)
