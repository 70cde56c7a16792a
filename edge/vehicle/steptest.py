"""The paper's attitude step test (PAPER.md Section 5) as a reusable scenario.

Design notes: docs/edge.md (edge/vehicle/steptest.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edge.vehicle.atsm import ATSM, ATSMGains, TwistingController
from edge.vehicle.quadrotor import DisturbanceParams, QuadParams, Quadrotor, euler_rates_from_body_rates

__all__ = ["STEPS", "StepResult", "run_step_test"]

#: (axis, time of the step s, reference rad) of the paper's test
STEPS: tuple[tuple[int, float, float], ...] = ((0, 0.5, math.radians(-10.0)), (1, 1.0, math.radians(10.0)),
                                               (2, 2.0, math.radians(45.0)))

#: torque disturbance of the test: |d| <= 0.03, 0.03, 0.01 N·m
TEST_DISTURBANCE = DisturbanceParams(torque_amp=(0.03, 0.03, 0.01))


@dataclass(frozen=True)
class StepResult:
    """Outcome of :func:`run_step_test`; per-axis tuples are (roll, pitch, yaw)."""

    controller: str
    t: np.ndarray  # (n,) s
    att: np.ndarray  # (n, 3) rad
    ref: np.ndarray  # (n, 3) rad
    torque: np.ndarray  # (n, 3) N·m, applied (lagged, saturated)
    alpha: np.ndarray  # (n, 3) N·m, twisting gain
    settling_s: tuple[float, float, float]  # inf if never settled
    overshoot_pct: tuple[float, float, float]
    chattering_std: tuple[float, float, float]
    chattering_tv: tuple[float, float, float]

    def as_dict(self) -> dict:
        return {"controller": self.controller, "settling_s": list(self.settling_s),
                "overshoot_pct": list(self.overshoot_pct), "chattering_std_Nm": list(self.chattering_std),
                "chattering_tv_Nm": list(self.chattering_tv), "final_alpha_Nm": self.alpha[-1].tolist()}


def run_step_test(controller: str = "atsm", *, inertia_mismatch: float = 1.2,
                  disturbance: DisturbanceParams = TEST_DISTURBANCE, gains: ATSMGains = ATSMGains(),
                  params: QuadParams = QuadParams(), seed: int = 0, duration: float = 6.0, physics_hz: int = 200,
                  band: float = 0.02, steady_s: float = 2.0) -> StepResult:
    """Run the step test with ``controller`` "atsm" (P13)-(P17) or "twisting" (fixed gain), the controller's
    inertia the plant's times ``inertia_mismatch``, ``disturbance`` (default bounded torques of
    0.03/0.03/0.01 N·m), ``duration`` simulated s (> 2 s + ``steady_s``) and a settling ``band`` (fraction of the step).
    """
    if controller not in ("atsm", "twisting"):
        raise ValueError("controller must be 'atsm' or 'twisting'")
    if not (math.isfinite(duration) and duration > STEPS[-1][1] + steady_s):
        raise ValueError("duration must exceed the last step plus the steady window")
    if not (math.isfinite(inertia_mismatch) and inertia_mismatch > 0):
        raise ValueError("inertia_mismatch must be finite and > 0")
    dt = 1.0 / physics_hz
    quad = Quadrotor(params, dt, disturbance, np.random.default_rng(seed), pos=(0.0, 0.0, 10.0), ground_z=None)
    model = (params.ixx * inertia_mismatch, params.iyy * inertia_mismatch, params.izz * inertia_mismatch)
    ctl = ATSM(model, gains, dt) if controller == "atsm" else TwistingController(model, gains, dt)
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    ref = np.zeros((n, 3))
    for axis, ts, val in STEPS:
        ref[t >= ts - 1e-12, axis] = val
    att = np.empty((n, 3))
    torque = np.empty((n, 3))
    alpha = np.empty((n, 3))
    refs = [tuple(r) for r in ref.tolist()]
    w = params.hover_thrust
    for k in range(n):
        s = quad.s
        a = (s[6], s[7], s[8])
        rates = (s[9], s[10], s[11])
        u = ctl.update(a, euler_rates_from_body_rates(a, rates), rates, refs[k])
        quad.step(w / (math.cos(a[0]) * math.cos(a[1])), *u)
        s = quad.s
        att[k] = s[6:9]
        torque[k] = quad.torque
        alpha[k] = ctl.alpha
    t_after = t + dt  # att[k] is the state at the end of step k
    settling, overshoot = [], []
    for axis, ts, val in STEPS:
        after = t_after >= ts
        err = np.abs(att[:, axis] - val)
        out = np.nonzero(after & (err > band * abs(val)))[0]
        if len(out) == 0:
            settling.append(0.0)
        elif out[-1] == n - 1:
            settling.append(math.inf)
        else:
            settling.append(float(t_after[out[-1] + 1] - ts))
        exc = (att[after, axis] - val) * math.copysign(1.0, val)
        overshoot.append(float(max(0.0, exc.max()) / abs(val) * 100.0))
    steady = t_after > duration - steady_s
    std = torque[steady].std(axis=0)
    tv = np.abs(np.diff(torque[steady], axis=0)).mean(axis=0)
    return StepResult(controller=controller, t=t_after, att=att, ref=ref, torque=torque, alpha=alpha,
                      settling_s=tuple(settling), overshoot_pct=tuple(overshoot),
                      chattering_std=tuple(float(v) for v in std), chattering_tv=tuple(float(v) for v in tv))
