"""What the plan's authority costs the ground station and the planner, per plan (no bus).

* the scenario digest (SHA-256 of its canonical JSON) of a request;
* the planner's Ed25519 envelope of the plan (codec + sign) and the ground station's opening of it
  (verify + decode + the binding to nonce and digest), :mod:`protocol.planauth`;
* the check of the plan against the scenario (box, obstacles, segments every 0.25 m, captures),
  :func:`services.gcs.preflight.scenario_problem`;

for the paper's three UAVs and a stacked fleet of 24 (median of N runs, ms), and the plan's size on
the wire, plain and signed. The plan request's wait for other answers adds nothing when one planner
answers (the query ends with its answer); a queryable that never answers adds at most the settle
window (``MissionOptions.plan_settle_s``, 10 s).

    .venv/bin/python bench/plan_auth.py [--runs 20] [--out bench/results/plan_auth.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey  # noqa: E402

from protocol import codec, planauth  # noqa: E402
from protocol.messages import PlanRequest  # noqa: E402
from protocol.scenario import load_scenario  # noqa: E402
from protocol.signing import Signer  # noqa: E402
from services.gcs.mission import with_formation_size  # noqa: E402
from services.gcs.preflight import scenario_problem  # noqa: E402
from services.planner.service import answer  # noqa: E402

TO = "skynet/bench/rcu/planner/plan"


def median_ms(fn, runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return round(1e3 * statistics.median(times), 3)


def one(n: int, runs: int) -> dict:
    sc = with_formation_size(load_scenario(), n)
    req = PlanRequest(request_id=1, nonce=planauth.new_nonce(), scenario=sc)
    plan = answer(req)
    key = Ed25519PrivateKey.generate()
    signer = Signer("planner", key)
    verifier = planauth.plan_verifier(key.public_key())
    signed = signer.sign(plan, TO)
    assert scenario_problem(plan, sc, range(1, n + 1)) == ""
    return {
        "uavs": n,
        "waypoints": sum(len(t.waypoints) for t in plan.trajectories),
        "bytes_plain": len(codec.encode(plan)),
        "bytes_signed": len(codec.encode(signed)),
        "digest_ms": median_ms(lambda: planauth.scenario_digest(sc), runs),
        "sign_ms": median_ms(lambda: signer.sign(plan, TO), runs),
        "open_ms": median_ms(lambda: planauth.open_answer(signed, req, TO, verifier), runs),
        "scenario_check_ms": median_ms(lambda: scenario_problem(plan, sc, range(1, n + 1)), runs),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--out", default="bench/results/plan_auth.json")
    args = ap.parse_args()
    rows = [one(n, args.runs) for n in (3, 24)]
    for r in rows:
        print(f"{r['uavs']:>3} UAVs, {r['waypoints']} waypoints, {r['bytes_plain']} B plain / {r['bytes_signed']} B signed: "
              f"digest {r['digest_ms']} ms, sign {r['sign_ms']} ms, open (verify+decode+bind) {r['open_ms']} ms, "
              f"scenario check {r['scenario_check_ms']} ms")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"runs": args.runs, "plans": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
