"""Benchmark of the simulated vehicle (edge.vehicle) and the paper's attitude step test.

1. Real-time factor of one simulated vehicle (physics + PID + ATSM at 200 Hz) flying a mission in
   moderate wind.
2. How many vehicles one core keeps at real time when each also builds and encodes a
   VehicleState at 20 Hz (the edge's telemetry load): the per-vehicle cost of one simulated
   second is measured on a small fleet, its inverse is the capacity, and a fleet of that size is
   then run to check that it indeed keeps up.
3. ATSM vs fixed-gain twisting in the paper's step test (φ −10° at 0.5 s, θ 10° at 1 s, ψ 45° at
   2 s; bounded torque disturbance; 20 % inertia mismatch): settling time to 2 %, overshoot, and
   torque chattering in the steady hold, for several disturbance seeds.

Usage: ``python bench/sim.py [--quick]``. Prints tables and writes bench/results/sim.json.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from edge.vehicle.quadrotor import DisturbanceParams  # noqa: E402
from edge.vehicle.sim import SimDriver, SimParams  # noqa: E402
from edge.vehicle.steptest import run_step_test  # noqa: E402
from protocol.messages import Mode, Trajectory, Waypoint  # noqa: E402

try:
    from protocol.codec import encode  # noqa: E402
except ImportError:  # the codec may not exist yet in a partial tree
    import msgpack

    def encode(msg):  # type: ignore[no-redef]
        return msgpack.packb(msg.model_dump(mode="json"))


PARAMS = SimParams(disturbance=DisturbanceParams.moderate())


def _mission(uav: int, seconds: float, offset: float = 0.0) -> Trajectory:
    """A lawn-mower pass pattern at 3 m/s long enough for ``seconds`` of flight."""
    wps, t, x, y = [], 0.0, offset, 0.0
    leg = 30.0
    i = 0
    while t <= seconds + 30:
        wps.append(Waypoint(t=t, pos=(x, y, 10.0), capture_id=i))
        if i % 2 == 0:
            x += leg if (i // 2) % 2 == 0 else -leg
            t += leg / 3.0
        else:
            y += 5.0
            t += 5.0 / 3.0
        i += 1
    return Trajectory(uav=uav, waypoints=wps)


def _flying(uav: int, seconds: float, seed: int) -> SimDriver:
    d = SimDriver(uav, PARAMS, seed=seed, home=(3.0 * uav, 0.0, 0.0))
    d.takeoff(10.0)
    while d.mode != Mode.HOLD:
        d.step(d.t + 0.5)
    d.upload(_mission(uav, seconds, offset=3.0 * uav))
    d.start()
    d.step(d.t + 5.0)  # through the transit, onto the pattern
    return d


def bench_single(seconds: float) -> dict:
    d = _flying(1, seconds, seed=1)
    steps0 = d._k
    w = time.perf_counter()
    d.step(d.t + seconds)
    wall = time.perf_counter() - w
    steps = d._k - steps0
    if d.mode != Mode.MISSION:
        raise RuntimeError(f"mission ended early ({d.mode})")
    return {
        "sim_s": seconds,
        "wall_s": wall,
        "steps": steps,
        "us_per_step": wall / steps * 1e6,
        "real_time_factor": seconds / wall,
    }


def _run_fleet(drivers: list[SimDriver], seconds: float) -> tuple[float, int]:
    """Step every driver in 50 ms chunks, building and encoding a VehicleState after each."""
    chunks = int(round(seconds * 20))
    nbytes = 0
    seq = 0
    w = time.perf_counter()
    for _ in range(chunks):
        for d in drivers:
            d.step(d.t + 0.05)
            msg = d.state().to_message(uav=d.uav, seq=seq, stamp=time.time())
            nbytes += len(encode(msg))
        seq += 1
    return time.perf_counter() - w, nbytes


def bench_fleet(seconds: float) -> dict:
    probe = [_flying(u, seconds * 3, seed=u) for u in range(1, 6)]
    wall, nbytes = _run_fleet(probe, seconds)
    per_vehicle = wall / (len(probe) * seconds)  # wall seconds per simulated vehicle-second
    capacity = int(1.0 / per_vehicle)
    # the check fleet: copies of the probe vehicles (same flight state, same cost per step)
    fleet = [copy.deepcopy(probe[i % len(probe)]) for i in range(capacity)]
    check_wall, _ = _run_fleet(fleet, seconds)
    return {
        "probe_vehicles": len(probe),
        "sim_s": seconds,
        "wall_s_per_vehicle_second": per_vehicle,
        "state_bytes": nbytes / (len(probe) * seconds * 20),
        "vehicles_per_core_real_time": capacity,
        "check_fleet": capacity,
        "check_wall_s": check_wall,
        "check_keeps_real_time": check_wall <= seconds,
    }


def bench_step_test(seeds: list[int]) -> dict:
    out: dict = {}
    for c in ("atsm", "twisting"):
        runs = [run_step_test(c, inertia_mismatch=1.2, seed=s).as_dict() for s in seeds]
        agg = {}
        for key in ("settling_s", "overshoot_pct", "chattering_std_Nm", "chattering_tv_Nm", "final_alpha_Nm"):
            agg[key] = [statistics.fmean(r[key][i] for r in runs) for i in range(3)]
            agg[key + "_max"] = [max(r[key][i] for r in runs) for i in range(3)]
        agg["within_2s_all_seeds"] = all(max(r["settling_s"]) <= 2.0 for r in runs)
        out[c] = {"seeds": seeds, "mean": agg, "runs": runs}
    return out


def _finite(o):
    """JSON-safe copy: non-finite floats (a never-settled axis) become null."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    return o


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "sim.json"))
    args = ap.parse_args()
    single_s, fleet_s = (20.0, 5.0) if args.quick else (60.0, 10.0)
    seeds = [0, 1, 2] if args.quick else [0, 1, 2, 3, 4]

    single = bench_single(single_s)
    print("\n== one simulated vehicle (physics + PID + ATSM at 200 Hz, mission in wind) ==")
    print(f"{'sim s':>8} {'wall s':>8} {'us/step':>9} {'x real time':>12}")
    print(f"{single['sim_s']:8.1f} {single['wall_s']:8.3f} {single['us_per_step']:9.1f} {single['real_time_factor']:12.1f}")

    fleet = bench_fleet(fleet_s)
    print("\n== vehicles per core at real time, VehicleState built + encoded at 20 Hz each ==")
    print(f"wall per vehicle-second: {fleet['wall_s_per_vehicle_second'] * 1e3:.2f} ms "
          f"({fleet['state_bytes']:.0f} B per state)")
    print(f"capacity: {fleet['vehicles_per_core_real_time']} vehicles; check run of that fleet: "
          f"{fleet['check_wall_s']:.2f} s wall for {fleet['sim_s']:.0f} s simulated "
          f"({'keeps' if fleet['check_keeps_real_time'] else 'does NOT keep'} real time)")

    st = bench_step_test(seeds)
    print(f"\n== attitude step test (paper Sec. 5), 20 % inertia mismatch, disturbance, seeds {seeds} ==")
    print(f"{'controller':<10} {'axis':<5} {'settle s':>9} {'(max)':>7} {'overshoot %':>12} "
          f"{'chat std N·m':>13} {'chat TV N·m':>12} {'final α':>8}")
    for c in ("atsm", "twisting"):
        m = st[c]["mean"]
        for i, ax in enumerate(("roll", "pitch", "yaw")):
            print(f"{c:<10} {ax:<5} {m['settling_s'][i]:9.3f} {m['settling_s_max'][i]:7.3f} "
                  f"{m['overshoot_pct'][i]:12.2f} {m['chattering_std_Nm'][i]:13.4f} "
                  f"{m['chattering_tv_Nm'][i]:12.4f} {m['final_alpha_Nm'][i]:8.3f}")
        print(f"{c:<10} all axes within 2 s on every seed: {m['within_2s_all_seeds']}")

    result = {
        "host": {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()},
        "single_vehicle": single,
        "fleet": fleet,
        "step_test": st,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(_finite(result), indent=2))
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
