"""Cost of the mission report on a mission of realistic size.

Plans the default (monorail) scenario with a small θ-PSO budget, then synthesises a flight
record: every UAV follows its planned trajectory (linear between waypoints) with a lag, a
seeded random-walk position error and 20 Hz telemetry, plus one defect report per planned
capture. Times, for flights of increasing length (telemetry states in total):

- ``record``     : building the MissionRecord (pydantic validation of every message; what the
                   ground station pays while recording, for scale)
- ``summarise``  : every figure (path errors against the planned polyline, formation error,
                   link statistics, defect scoring)
- ``write``      : the whole report folder (figures + 7 PNG plots + JSON + Markdown)

and prints a table (seconds, median of repeats), then writes JSON.

    .venv/bin/python bench/report.py [--quick] [--out bench/results/report.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.messages import Defect, DefectReport, LinkStats, Mode, VehicleState  # noqa: E402
from protocol.scenario import Scenario, default_scenario_path, load_scenario  # noqa: E402
from services.gcs.figures import planned_positions, summarise  # noqa: E402
from services.gcs.report import write_report  # noqa: E402
from services.planner.mission import plan_mission  # noqa: E402
from services.recording.record import CommandRecord, DefectRx, MissionRecord, StateRx, StatsRx  # noqa: E402


def synth_record(plan, scenario: Scenario, rate_hz: float, repeat: int, rng: np.random.Generator) -> MissionRecord:
    """A flight that follows ``plan`` ``repeat`` times over (to make long records)."""
    states, defects = [], []
    corners = list(scenario.surface.corners) if scenario.surface else []
    for tr in plan.trajectories:
        t0, t1 = tr.waypoints[0].t, tr.waypoints[-1].t
        taus = np.arange(0.0, (t1 - t0) * repeat, 1.0 / rate_hz)
        ref = planned_positions(tr, t0 + np.maximum(np.mod(taus, t1 - t0) - 0.4, 0.0))
        walk = np.cumsum(rng.normal(0.0, 0.01, ref.shape), axis=0)
        walk -= np.linspace(0, 1, len(walk))[:, None] * walk[-1]
        pos = ref + walk
        for i, (tau, p) in enumerate(zip(taus, pos)):
            stamp = 1000.0 + tau
            msg = VehicleState(uav=tr.uav, seq=i, t=100.0 + tau, stamp=stamp, pos=tuple(p), vel=(0, 0, 0),
                               att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION, armed=True, wp_index=0,
                               progress=min(tau / (t1 - t0), 1.0))
            states.append(StateRx(rx=stamp + rng.exponential(0.01), msg=msg))
        for w in tr.waypoints:
            if w.capture_id is None:
                continue
            s = 1000.0 + w.t - t0
            d = [Defect(area_px=20, bbox=(0, 0, 2, 10), centroid_px=(1, 5), contrast=0.4,
                        pos=tuple(np.asarray(corners[0]) + rng.uniform(0, 1, 3) * (np.asarray(corners[2]) -
                                                                                  np.asarray(corners[0]))))]
            defects.append(DefectRx(rx=s + 0.2, msg=DefectReport(uav=tr.uav, capture_id=w.capture_id, stamp_capture=s,
                                                                stamp_report=s + 0.15, method="it", defects=d)))
    det = [StatsRx(rx=1100.0, msg=LinkStats(source="detector", stamp=1100.0,
                                            metrics={"uav1.cam0.received": 10.0, "uav1.cam0.lost": 1.0}))]
    cmds = [CommandRecord(uav=tr.uav, kind="upload", cmd_id=tr.uav, ok=True, accepted=True, elapsed_s=0.02,
                          ack_s=[0.02]) for tr in plan.trajectories]
    return MissionRecord(fleet="bench", scenario=scenario, speed=1.0, started=999.0, ended=2000.0, plan=plan,
                         states=states, defects=defects, detector_stats=det, commands=cmds,
                         surface_corners=[tuple(c) for c in corners])


def median_time(fn, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return statistics.median(samples)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one short flight, one repeat")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "report.json"))
    args = ap.parse_args(argv)

    scenario = load_scenario(default_scenario_path())
    plan = plan_mission(scenario, seed=1, particles=20, iterations=20)
    rng = np.random.default_rng(0)
    repeats = 1 if args.quick else 3
    lengths = [1] if args.quick else [1, 4]
    rows = []
    for rep in lengths:
        t = time.perf_counter()
        rec = synth_record(plan, scenario, 20.0, rep, rng)
        t_record = time.perf_counter() - t
        t_sum = median_time(lambda: summarise(rec), repeats)
        with tempfile.TemporaryDirectory() as tmp:
            t_write = median_time(lambda: write_report(rec, tmp), repeats)
        s = summarise(rec)
        rows.append({"states": len(rec.states), "waypoints": sum(len(tr.waypoints) for tr in plan.trajectories),
                     "flight_s": max(st.msg.t for st in rec.states) - 100.0, "record_s": t_record,
                     "summarise_s": t_sum, "write_s": t_write,
                     "path_error_rms_m": {u: f.path_error_rms_m for u, f in s.uavs.items()}})
    print(f"{'states':>8} {'waypoints':>9} {'flight s':>9} {'record s':>9} {'summarise s':>12} {'write s':>8}")
    for r in rows:
        print(f"{r['states']:>8} {r['waypoints']:>9} {r['flight_s']:>9.0f} {r['record_s']:>9.2f} "
              f"{r['summarise_s']:>12.3f} {r['write_s']:>8.2f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
