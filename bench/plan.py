"""Planner benchmark: the paper's setting (150 particles, 10 waypoints, 300 iterations).

Prints Table I over 20 seeds and θ-PSO's wall time against pyswarms' GlobalBestPSO on the same
cost and budget; writes bench/results/plan.json. Same as ``skynet plan bench``.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.planner.cli import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main(["bench", *sys.argv[1:]]))
