"""Path cost of the formation (P5), vectorised over a whole swarm, and a dense collision check.

A candidate is ``n`` free waypoints of the formation centroid; the path is the polyline
``start -> free[:split] -> via points -> free[split:] -> goal`` where the via points are the fixed
entry and exit of the inspection pass (:func:`services.planner.task.formation_pass`), or none.
The formation keeps its offsets ΔT_n (P9) rotated to each segment's heading (P7, yaw only), so
UAV n flies the segment ``(a + R ΔT_n, b + R ΔT_n)``.

``J_F = β1 J1 + β2 J2 + β3 J3`` (P5), our reading of the paper's three terms:

- J1, path length: the length of the centroid polyline, metres.
- J2, collision violation: for every UAV, segment and cylinder, the clearance ``c`` between
  the UAV segment and the cylinder minus the UAV radius; ``((D - c) / D)^2`` inside the danger
  band ``0 <= c < D`` (0 at its edge, 1 at contact), and ``1 + K (1 + depth)`` inside an
  obstacle (``K`` the collision penalty, ``depth = -c`` metres), so that deeper violations cost
  more and swarms are pushed out of obstacles rather than trapped in them by a flat penalty.
  Crossing the inspected wall costs ``K (1 + depth)`` too (depth: distance of the crossing point
  from the wall's nearest edge). Inter-UAV term: ``K`` per segment times the relative shortfall
  of every pair closer than the minimum separation (rigid formation: constant per segment).
  Manoeuvrability (the paper lists it among the constraints folded into (P5)): ``K/10`` per
  radian by which the horizontal turn at a waypoint exceeds ``max_turn_deg`` (a formation
  reversing on itself swings its outer UAVs through the obstacles the centroid path avoids).
- J3, flying altitude / stand-off: ``K/10`` per metre that a UAV's waypoint altitude leaves the
  allowed band, plus, at 8 samples per UAV segment, the relative shortfall ``(k - dist) / k`` of
  the distance to the wall below ``k = 0.9 d_f`` (keep the (P2) distance from the surface).

Segment-cylinder clearance: the horizontal point-to-segment distance ρ from the axis to the
segment (exact, :func:`point_segment_distance`) at the closest parameter ``t*``; if the segment
is below the cylinder top there, ``c = ρ - r``, otherwise ``c = hypot(max(ρ - r, 0), z* - h)``.
This is exact for cylinders taller than the segment and an approximation for segments passing
over a cylinder's top; :func:`clearance` on densely sampled points gives the exact answer and is
what decides ``collision_free``.

Every result is finite for finite input.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .scenario import Scenario
from .task import InspectionPass, formation_pass

__all__ = [
    "point_segment_distance",
    "PathProblem",
    "Cost",
    "clearance",
    "formation_points",
    "path_collision_free",
    "crosses_wall_free",
]


def point_segment_distance(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Euclidean distance from points ``p`` to segments ``a-b`` (any dimension, broadcast).

    ``t* = clip(((p - a)·(b - a)) / |b - a|^2, 0, 1)``, distance ``|p - (a + t* (b - a))|``;
    a degenerate segment (``a == b``) gives ``|p - a|``.
    """
    p, a, b = (np.asarray(x, float) for x in (p, a, b))
    d = b - a
    dd = np.sum(d * d, axis=-1)
    t = np.sum((p - a) * d, axis=-1) / np.where(dd > 0, dd, 1.0)
    t = np.clip(np.where(dd > 0, t, 0.0), 0.0, 1.0)
    q = a + t[..., None] * d
    return np.linalg.norm(p - q, axis=-1)


@dataclass(frozen=True)
class PathProblem:
    """The optimisation problem shared by every algorithm: bounds, fixed points and cost data."""

    scenario: Scenario
    n_free: int
    split: int
    inspection: InspectionPass | None
    lo: NDArray[np.float64] = field(repr=False)
    hi: NDArray[np.float64] = field(repr=False)

    @classmethod
    def from_scenario(cls, scenario: Scenario, waypoints: int) -> "PathProblem":
        """Problem with ``waypoints`` free centroid waypoints, half before the pass, half after."""
        if int(waypoints) != waypoints or waypoints < 1:
            raise ValueError(f"waypoints must be a positive integer, got {waypoints!r}")
        insp = formation_pass(scenario)
        n = int(waypoints)
        split = (n + 1) // 2 if insp is not None else n
        return cls(scenario, n, split, insp, scenario.lo.copy(), scenario.hi.copy())

    @property
    def dim(self) -> int:
        return 3 * self.n_free

    @property
    def via(self) -> NDArray[np.float64]:
        if self.inspection is None:
            return np.zeros((0, 3))
        return np.stack([self.inspection.entry, self.inspection.exit])

    def assemble(self, x: ArrayLike) -> NDArray[np.float64]:
        """Full centroid polylines ``(P, n + 2 + via, 3)`` from decision vectors ``(P, 3n)``."""
        X = np.asarray(x, float).reshape(-1, self.n_free, 3)
        P = X.shape[0]
        s = np.broadcast_to(np.asarray(self.scenario.start, float), (P, 1, 3))
        g = np.broadcast_to(np.asarray(self.scenario.goal, float), (P, 1, 3))
        v = np.broadcast_to(self.via, (P, self.via.shape[0], 3))
        return np.concatenate([s, X[:, : self.split], v, X[:, self.split :], g], axis=1)

    def reference(self) -> NDArray[np.float64]:
        """Nominal free waypoints ``(n, 3)`` evenly spaced on the straight legs to/from the pass."""
        s, g = np.asarray(self.scenario.start, float), np.asarray(self.scenario.goal, float)
        if self.inspection is None:
            legs = [(s, g, self.n_free)]
        else:
            legs = [(s, self.inspection.entry, self.split), (self.inspection.exit, g, self.n_free - self.split)]
        pts = [a + (b - a) * (k / (m + 1)) for a, b, m in legs for k in range(1, m + 1)]
        return np.asarray(pts, float).reshape(self.n_free, 3)

    def initial_population(
        self, particles: int, rng: np.random.Generator, mode: str = "corridor", width: float = 15.0
    ) -> NDArray[np.float64]:
        """Initial decision vectors ``(P, 3n)`` shared by every algorithm.

        ``"corridor"``: the nominal waypoints (:meth:`reference`) plus uniform noise of
        ``±width`` m horizontally and ``±width/3`` m vertically, clipped to the box; ``"box"``:
        uniform over the whole box.
        """
        if int(particles) != particles or particles < 2:
            raise ValueError(f"particles must be an integer >= 2, got {particles!r}")
        P = int(particles)
        if mode == "box":
            X = rng.uniform(self.lo, self.hi, size=(P, self.n_free, 3))
        elif mode == "corridor":
            if not (np.isfinite(width) and width > 0):
                raise ValueError(f"corridor width must be positive, got {width!r}")
            half = np.array([width, width, width / 3.0])
            X = self.reference()[None] + rng.uniform(-1.0, 1.0, size=(P, self.n_free, 3)) * half
            X = np.clip(X, self.lo, self.hi)
        else:
            raise ValueError(f"init must be 'corridor' or 'box', got {mode!r}")
        return X.reshape(P, self.dim)


class Cost:
    """The cost (P5) of decision vectors, vectorised: ``cost(X) -> (P,)`` for ``X (P, 3n)``.

    ``evaluations`` counts the candidate paths evaluated so far (the algorithms' budget).
    """

    SAMPLES = 8  # per UAV segment, for the wall stand-off term

    def __init__(self, problem: PathProblem):
        self.problem = problem
        sc = problem.scenario
        self.cyl = sc.cylinders()
        self.off = sc.offsets
        self.beta = np.asarray(sc.cost.beta, float)
        self.r_uav = sc.cost.uav_radius
        self.band = sc.cost.danger_band
        self.pen = sc.cost.collision_penalty
        self.alt = sc.cost.altitude
        self.max_turn = np.deg2rad(sc.cost.max_turn_deg)
        self.evaluations = 0
        M = self.off.shape[0]
        i, j = np.triu_indices(M, 1)
        dsep = np.linalg.norm(self.off[i] - self.off[j], axis=1)
        dmin = sc.formation.min_separation
        self.sep_shortfall = float(np.sum(np.clip((dmin - dsep) / dmin, 0, None))) if dmin > 0 else 0.0
        if sc.surface is not None and problem.inspection is not None:
            p0, u, n = sc.surface.frame
            self.wall = (p0, u, n, sc.surface.length, *sc.surface.z_range)
            self.keep = 0.9 * problem.inspection.standoff
        else:
            self.wall = None

    def __call__(self, x: ArrayLike) -> NDArray[np.float64]:
        return self.terms(x) @ self.beta

    def terms(self, x: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3)`` array of J1, J2, J3 for decision vectors ``x (P, 3n)`` (P5)."""
        X = np.asarray(x, float)
        if X.ndim == 1:
            X = X[None]
        if X.ndim != 2 or X.shape[1] != self.problem.dim:
            raise ValueError(f"decision vectors must have shape (P, {self.problem.dim}), got {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError("decision vectors must be finite")
        self.evaluations += X.shape[0]
        return self.path_terms(self.problem.assemble(X))

    def path_terms(self, V: NDArray[np.float64]) -> NDArray[np.float64]:
        """J1, J2, J3 of centroid polylines ``V (P, nv, 3)``."""
        a, b = V[:, :-1], V[:, 1:]
        d = b - a
        J1 = np.sum(np.linalg.norm(d, axis=-1), axis=1)
        yaw = np.arctan2(d[..., 1], d[..., 0])  # (P, S)
        c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
        ox, oy, oz = self.off[:, 0], self.off[:, 1], self.off[:, 2]
        rot = np.stack([ox * c - oy * s, ox * s + oy * c, np.broadcast_to(oz, c.shape[:-1] + oz.shape)], -1)
        A = a[:, :, None, :] + rot  # (P, S, M, 3)
        B = b[:, :, None, :] + rot
        P, S, M = A.shape[:3]
        J2 = np.full(P, self.pen * self.sep_shortfall * S)
        hx, hy = d[..., 0], d[..., 1]
        hn = np.hypot(hx, hy)
        ok = (hn[:, :-1] > 1e-9) & (hn[:, 1:] > 1e-9)
        cosang = (hx[:, :-1] * hx[:, 1:] + hy[:, :-1] * hy[:, 1:]) / np.where(ok, hn[:, :-1] * hn[:, 1:], 1.0)
        turn = np.where(ok, np.arccos(np.clip(cosang, -1.0, 1.0)), 0.0)
        J2 += 0.1 * self.pen * np.sum(np.clip(turn - self.max_turn, 0.0, None), axis=1)
        if self.cyl.shape[0]:
            J2 += np.sum(self._cyl_penalty(A, B), axis=(1, 2, 3))
        J3 = np.zeros(P)
        z = np.concatenate([A[..., 2], B[:, -1:, :, 2]], axis=1)
        lo, hi = self.alt
        J3 += 0.1 * self.pen * np.sum(np.clip(lo - z, 0, None) + np.clip(z - hi, 0, None), axis=(1, 2))
        if self.wall is not None:
            w2, w3 = self._wall_penalty(A, B)
            J2 += w2
            J3 += w3
        return np.stack([J1, J2, J3], axis=1)

    def _cyl_penalty(self, A: NDArray[np.float64], B: NDArray[np.float64]) -> NDArray[np.float64]:
        # float32 halves the memory traffic of this, the hottest part; clearances are needed
        # to millimetres only, far above float32's resolution at these scales.
        cx, cy, r, h = self.cyl.T.astype(np.float32)
        A32, B32 = A.astype(np.float32), B.astype(np.float32)
        ax, ay, az = A32[..., 0, None], A32[..., 1, None], A32[..., 2, None]
        dx, dy, dz = B32[..., 0, None] - ax, B32[..., 1, None] - ay, B32[..., 2, None] - az
        wx, wy = cx - ax, cy - ay  # (P, S, M, C)
        dd = dx * dx + dy * dy
        dd[dd <= 0] = 1.0  # degenerate: w·d = 0 there, so t = 0
        t = wx * dx
        t += wy * dy
        t /= dd
        np.clip(t, 0.0, 1.0, out=t)
        wx -= t * dx
        wy -= t * dy
        gap = np.hypot(wx, wy)
        gap -= r
        zt = t * dz
        zt += az
        zt -= h  # height above the top
        above = zt > 0
        if np.any(above):
            gap = np.where(above, np.hypot(np.clip(gap, 0, None), zt), gap)
        gap -= np.float32(self.r_uav)
        return self._shape(gap).astype(np.float64)

    def _shape(self, cl: NDArray[np.float64]) -> NDArray[np.float64]:
        D = cl.dtype.type(self.band)
        out = np.clip((D - cl) / D, 0.0, 1.0)
        out *= out
        inside = cl < 0
        if np.any(inside):
            out[inside] = 1.0 + self.pen * (1.0 - cl[inside])
        return out

    def _wall_penalty(self, A, B):
        p0, u, n, L, z0, z1 = self.wall
        # wall coordinates: s along the bottom edge, q = signed distance from the plane, z
        uA, uB = (A - p0) @ u, (B - p0) @ u
        qA, qB = (A - p0) @ n, (B - p0) @ n
        zA, zB = A[..., 2], B[..., 2]
        cross = qA * qB < 0
        J2 = np.zeros(A.shape[0])
        if np.any(cross):
            t = qA / np.where(cross, qA - qB, 1.0)
            su, zz = uA + t * (uB - uA), zA + t * (zB - zA)
            depth = np.minimum(np.minimum(su, L - su), np.minimum(zz - z0, z1 - zz))
            hit = cross & (depth > -self.r_uav)
            J2 = np.sum(np.where(hit, self.pen * (1.0 + np.clip(depth, 0, None)), 0.0), axis=(1, 2))
        f32 = np.float32
        k = ((np.arange(self.SAMPLES) + 0.5) / self.SAMPLES).astype(f32)

        def lerp(a, b):
            a = a.astype(f32)[..., None]
            return a + k * (b.astype(f32)[..., None] - a)  # (P, S, M, K)

        s, q, z = lerp(uA, uB), lerp(qA, qB), lerp(zA, zB)
        es = s - np.clip(s, f32(0.0), f32(L))
        ez = z - np.clip(z, f32(z0), f32(z1))
        es *= es
        ez *= ez
        q *= q
        es += ez
        es += q
        dist = np.sqrt(es)
        keep = f32(self.keep)
        J3 = np.sum(np.clip((keep - dist) / keep, f32(0.0), None), axis=(1, 2, 3), dtype=np.float64)
        return J2, J3


def _wall_distance(Q, p0, u, L, z0, z1):
    rel = Q - p0
    s = np.clip(rel @ u, 0.0, L)
    z = np.clip(Q[..., 2], z0, z1)
    nearest = p0 + s[..., None] * u
    nearest = np.concatenate([nearest[..., :2], z[..., None]], axis=-1)
    return np.linalg.norm(Q - nearest, axis=-1)


def clearance(points: ArrayLike, scenario: Scenario) -> NDArray[np.float64]:
    """Exact clearance (m) of points ``(..., 3)`` from every obstacle and the wall, minus the UAV radius.

    Negative means a collision. Point-cylinder distance: ``ρ - r`` below the top, else
    ``hypot(max(ρ - r, 0), z - h)``; point-wall: distance to the rectangle.
    """
    Q = np.asarray(points, float)
    if Q.shape[-1:] != (3,) or not np.all(np.isfinite(Q)):
        raise ValueError("points must be finite with a last axis of 3")
    out = np.full(Q.shape[:-1], np.inf)
    cyl = scenario.cylinders()
    if cyl.shape[0]:
        rho = np.hypot(Q[..., 0, None] - cyl[:, 0], Q[..., 1, None] - cyl[:, 1])
        gap = rho - cyl[:, 2]
        dz = Q[..., 2, None] - cyl[:, 3]
        signed = np.where(dz <= 0, gap, np.hypot(np.clip(gap, 0, None), dz))
        out = np.min(signed, axis=-1)
    if scenario.surface is not None:
        p0, u, _ = scenario.surface.frame
        out = np.minimum(out, _wall_distance(Q, p0, u, scenario.surface.length, *scenario.surface.z_range))
    out = out - scenario.cost.uav_radius
    return np.where(np.isfinite(out), out, 1.0e6)


def formation_points(V: ArrayLike, offsets: ArrayLike, step: float = 0.25) -> NDArray[np.float64]:
    """UAV positions ``(N, M, 3)`` along a centroid polyline ``V (nv, 3)`` sampled every ``step`` m.

    The formation keeps each segment's heading (as in :class:`Cost`).
    """
    V = np.asarray(V, float)
    off = np.asarray(offsets, float)
    pts = []
    for a, b in zip(V[:-1], V[1:]):
        L = float(np.linalg.norm(b - a))
        k = max(int(np.ceil(L / step)), 1)
        t = np.linspace(0.0, 1.0, k + 1)
        yaw = np.arctan2(b[1] - a[1], b[0] - a[0])
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.stack([off[:, 0] * c - off[:, 1] * s, off[:, 0] * s + off[:, 1] * c, off[:, 2]], -1)
        pts.append((a + t[:, None] * (b - a))[:, None, :] + rot[None])
    return np.concatenate(pts, axis=0)


def crosses_wall_free(Q: ArrayLike, scenario: Scenario) -> bool:
    """True if no UAV track ``Q (N, M, 3)`` (consecutive samples joined) passes through the wall."""
    if scenario.surface is None:
        return True
    Q = np.asarray(Q, float)
    p0, u, n = scenario.surface.frame
    s = (Q - p0) @ n
    cross = s[:-1] * s[1:] < 0
    if not np.any(cross):
        return True
    t = s[:-1] / np.where(cross, s[:-1] - s[1:], 1.0)
    X = Q[:-1] + t[..., None] * (Q[1:] - Q[:-1])
    su, z = (X - p0) @ u, X[..., 2]
    z0, z1 = scenario.surface.z_range
    inwall = (su >= 0) & (su <= scenario.surface.length) & (z >= z0) & (z <= z1)
    return not bool(np.any(cross & inwall))


def path_collision_free(V: ArrayLike, scenario: Scenario, step: float = 0.25) -> bool:
    """True if no UAV of the formation along centroid polyline ``V`` comes into an obstacle or the wall.

    Exact point clearances (:func:`clearance`) every ``step`` metres, plus wall crossings between
    samples; the formation keeps each segment's heading.
    """
    Q = formation_points(V, scenario.offsets, step)
    return bool(np.all(clearance(Q, scenario) >= 0)) and crosses_wall_free(Q, scenario)
