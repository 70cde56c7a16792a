"""One UAV's planned inspection pass flown three ways, side by side in one run:

- ``sim``       the built-in SimDriver (GUIDED-style reference tracking, no MAVLink);
- ``mavlink``   MavlinkDriver streaming GUIDED position targets to the sim autopilot over loopback UDP;
- ``auto``      the pass exported as a mission (:func:`services.planner.export.mission_items`: speed items,
                CONDITION_YAW, capture triggers), uploaded with the mission protocol and flown in AUTO.

Figures per run: tracking error against the planned trajectory at the planned time (RMS, max; for
AUTO the planned time starts when the first waypoint is reached), captures fired / planned, and the
command round trip (COMMAND_LONG -> COMMAND_ACK, median / p95 over 30 REQUEST_MESSAGE commands;
the SimDriver has no link). Formation RMS needs the three-UAV mission, which this bench does not run.

    .venv/bin/python bench/mavlink.py [--speed 4] [--uav 1] [--out bench/results/mavlink.json]
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.clock import SimClock  # noqa: E402
from edge.vehicle.mavlink import MavlinkDriver, open_connection  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from edge.vehicle.sim import SimDriver  # noqa: E402
from protocol.messages import Mode  # noqa: E402
from services.planner.export import mission_items  # noqa: E402
from services.planner.mission import plan_details  # noqa: E402
from services.planner.scenario import load_scenario  # noqa: E402


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def planned(tr):
    T = np.array([w.t for w in tr.waypoints])
    P = np.array([w.pos for w in tr.waypoints])
    return T, P, lambda tau: np.array([np.interp(tau, T, P[:, k]) for k in range(3)])


def fly_driver(drv, clock, tr, home, limit_s: float) -> dict:
    """takeoff, start, step on the clock until the pass is flown; errors vs the plan at progress x duration."""
    T, P, at = planned(tr)
    drv.upload(tr)
    drv.takeoff(float(P[0, 2] - home[2]))
    end = time.monotonic() + limit_s
    while drv.state().mode != Mode.HOLD and time.monotonic() < end:
        drv.step(clock.now())
        time.sleep(0.02)
    drv.start(clock.now())
    errs, caps = [], 0
    while time.monotonic() < end:
        caps += len(drv.step(clock.now()))
        st = drv.state()
        if st.progress > 0:
            errs.append(float(np.linalg.norm(np.asarray(st.pos) - at(st.progress * T[-1]))))
        if st.progress >= 1.0:
            break
        time.sleep(0.02)
    return {"errors": errs, "captures": caps}


def ack_latency(drv, n: int = 30) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        drv.command(M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_HOME_POSITION,), "request HOME_POSITION")
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def run_sim(tr, home, speed) -> dict:
    clock = SimClock(speed=speed)
    drv = SimDriver(tr.uav, home=home, t0=clock.now(), seed=tr.uav)
    return fly_driver(drv, clock, tr, home, 600 / speed + 60)


def run_mavlink(tr, home, speed, origin) -> dict:
    port = free_port()
    clock = SimClock(speed=speed)
    drv = MavlinkDriver(tr.uav, f"udpin:127.0.0.1:{port}", home=home)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", tr.uav, home=home, speed=speed, epoch=clock.epoch,
                            seed=tr.uav, origin=origin).start()
    try:
        drv.wait_heartbeat(10)
        lat = ack_latency(drv)
        r = fly_driver(drv, clock, tr, home, 600 / speed + 60)
        r["ack_ms"] = lat
        return r
    finally:
        drv.close()
        veh.close()


def run_auto(tr, home, speed, origin) -> dict:
    """Upload the exported mission as a ground station does, fly it in AUTO, compare with the plan."""
    T, P, at = planned(tr)
    items = mission_items(tr, origin)
    port = free_port()
    gcs = open_connection(f"udpin:127.0.0.1:{port}", 255, M.MAV_COMP_ID_MISSIONPLANNER)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", tr.uav, home=home, speed=speed, seed=tr.uav,
                            origin=origin).start()
    try:
        gcs.wait_heartbeat(timeout=10)

        def ack(cmd):
            while True:
                a = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
                if a is None:
                    raise TimeoutError(f"no ack to {cmd}")
                if a.command == cmd:
                    return a.result

        lat = []
        for _ in range(30):
            t0 = time.perf_counter()
            gcs.mav.command_long_send(tr.uav, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_HOME_POSITION,
                                      0, 0, 0, 0, 0, 0)
            ack(M.MAV_CMD_REQUEST_MESSAGE)
            lat.append((time.perf_counter() - t0) * 1e3)
        gcs.mav.mission_count_send(tr.uav, 1, len(items))
        while True:
            m = gcs.recv_match(type=["MISSION_REQUEST_INT", "MISSION_ACK"], blocking=True, timeout=5)
            if m is None:
                raise TimeoutError("mission upload stalled")
            if m.get_type() == "MISSION_ACK":
                assert m.type == 0, m
                break
            it = items[m.seq]
            p = it.params
            glob = it.frame in (0, 3)
            gcs.mav.mission_item_int_send(tr.uav, 1, it.index, it.frame, it.command, it.current, 1, *p[:4],
                                          round(p[4] * 1e7) if glob else int(p[4]),
                                          round(p[5] * 1e7) if glob else int(p[5]), p[6])
        for mode in (M.COPTER_MODE_GUIDED,):
            gcs.mav.command_long_send(tr.uav, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, mode, 0, 0, 0, 0, 0)
            ack(M.MAV_CMD_DO_SET_MODE)
        gcs.mav.command_long_send(tr.uav, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        assert ack(M.MAV_CMD_COMPONENT_ARM_DISARM) == 0
        gcs.mav.command_long_send(tr.uav, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, M.COPTER_MODE_AUTO, 0, 0, 0, 0, 0)
        assert ack(M.MAV_CMD_DO_SET_MODE) == 0
        first_wp = next(it.index for it in items[2:] if it.command == 16)
        last_wp = max(it.index for it in items if it.command == 16)
        end = time.monotonic() + 600 / speed + 60
        t_first, errs = None, []
        while time.monotonic() < end:
            gcs.recv_match(blocking=True, timeout=0.02)  # drain, keep the link alive
            if t_first is None and first_wp in veh.reached:
                t_first = veh.sim.t
            if t_first is not None:
                tau = veh.sim.t - t_first
                if tau > T[-1] or last_wp in veh.reached:
                    break
                errs.append(float(np.linalg.norm(np.asarray(veh.sim.state().pos) - at(tau))))
        return {"errors": errs, "captures": len(veh.shots), "ack_ms": lat, "auto_duration_s": (
            veh.sim.t - t_first) if t_first is not None else None}
    finally:
        gcs.close()
        veh.close()


def summary(name: str, r: dict, planned_caps: int) -> dict:
    e = np.asarray(r["errors"]) if r["errors"] else np.array([math.nan])
    s = {"run": name, "tracking_rms_m": float(np.sqrt(np.mean(e ** 2))), "tracking_max_m": float(np.max(e)),
         "captures": r["captures"], "captures_planned": planned_caps}
    if "ack_ms" in r:
        a = sorted(r["ack_ms"])
        s["ack_median_ms"] = statistics.median(a)
        s["ack_p95_ms"] = a[int(0.95 * (len(a) - 1))]
    if "auto_duration_s" in r:
        s["auto_duration_s"] = r["auto_duration_s"]
    return s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--uav", type=int, default=1)
    ap.add_argument("--out", default="bench/results/mavlink.json")
    a = ap.parse_args(argv)
    sc = load_scenario()
    plan, _, _ = plan_details(sc, seed=0, particles=60, iterations=100)
    tr = next(t for t in plan.trajectories if t.uav == a.uav)
    home = (tr.waypoints[0].pos[0], tr.waypoints[0].pos[1], 0.0)
    n_caps = sum(w.capture_id is not None for w in tr.waypoints)
    rows = [summary("sim", run_sim(tr, home, a.speed), n_caps),
            summary("mavlink (GUIDED)", run_mavlink(tr, home, a.speed, plan.origin), n_caps),
            summary("mavlink (AUTO)", run_auto(tr, home, a.speed, plan.origin), n_caps)]
    print(f"uav {a.uav}, {len(tr.waypoints)} waypoints, {tr.waypoints[-1].t:.1f} s planned, speed x{a.speed:g}")
    print(f"{'run':<18} {'RMS m':>7} {'max m':>7} {'captures':>9} {'ack p50/p95 ms':>15}")
    for r in rows:
        ack = f"{r['ack_median_ms']:.2f}/{r['ack_p95_ms']:.2f}" if "ack_median_ms" in r else "-"
        print(f"{r['run']:<18} {r['tracking_rms_m']:>7.3f} {r['tracking_max_m']:>7.3f} "
              f"{r['captures']:>4}/{r['captures_planned']:<4} {ack:>15}")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"speed": a.speed, "uav": a.uav, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
