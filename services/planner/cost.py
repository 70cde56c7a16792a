"""Path cost of the formation (P5), vectorised over a whole swarm, and a dense collision check.

Design notes: docs/planner.md (services/planner/cost.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .scenario import Scenario
from .task import InspectionPass, formation_pass

__all__ = ["point_segment_distance", "PathProblem", "Cost", "cost_offsets", "clearance", "formation_points",
           "path_collision_free", "crosses_wall_free"]


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


def cost_offsets(offsets: ArrayLike, wall_height: float | None = None) -> NDArray[np.float64]:
    """The UAVs the cost needs to look at: for a fleet stacked in columns
    (:func:`edge.geometry.formation.offsets_for`) the top and bottom UAV of each column and, between them,
    as few as keep consecutive ones at most ``wall_height`` apart; every UAV of a fleet without
    stacked UAVs (the paper's three: unchanged). Why the zero set of the cost is unchanged: docs/planner.md.
    """
    off = np.asarray(offsets, float).reshape(-1, 3)
    gap = np.inf if wall_height is None or not wall_height > 0 else float(wall_height)
    keep = np.zeros(off.shape[0], bool)
    cols: dict[tuple[float, float], list[int]] = {}
    for k, (x, y, _) in enumerate(off):
        cols.setdefault((round(float(x), 6), round(float(y), 6)), []).append(k)
    for members in cols.values():
        order = sorted(members, key=lambda k: -off[k, 2])  # top first
        keep[order[0]] = keep[order[-1]] = True
        last = off[order[0], 2]
        for a, b in zip(order[1:], order[2:]):  # keep a when skipping it would leave a gap over `gap`
            if last - off[b, 2] > gap + 1e-9:
                keep[a] = True
                last = off[a, 2]
    return off[keep]


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
    def from_scenario(cls, scenario: Scenario, waypoints: int) -> PathProblem:
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

    def initial_population(self, particles: int, rng: np.random.Generator, mode: str = "corridor",
                           width: float = 15.0) -> NDArray[np.float64]:
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

    ``evaluations`` counts the candidate paths evaluated so far (the algorithms' budget). The array layout and
    the segment frame: docs/planner.md (services/planner/cost.py).
    """

    SAMPLES = 8  # per UAV segment, for the wall stand-off term

    def __init__(self, problem: PathProblem):
        self.problem = problem
        sc = problem.scenario
        self.cyl = sc.cylinders()
        full = sc.offsets
        self.off = cost_offsets(full, None if sc.surface is None else float(np.ptp(sc.surface.z_range)))
        self.beta = np.asarray(sc.cost.beta, float)
        self.r_uav = sc.cost.uav_radius
        self.band = sc.cost.danger_band
        self.pen = sc.cost.collision_penalty
        self.alt = sc.cost.altitude
        self.max_turn = np.deg2rad(sc.cost.max_turn_deg)
        self.evaluations = 0
        self._ws: dict[str, NDArray] = {}
        i, j = np.triu_indices(full.shape[0], 1)
        dsep = np.linalg.norm(full[i] - full[j], axis=1)
        dmin = sc.formation.min_separation
        self.sep_shortfall = float(np.sum(np.clip((dmin - dsep) / dmin, 0, None))) if dmin > 0 else 0.0
        M = self.off.shape[0]
        # per-UAV offsets, broadcasting against (M, ...) arrays with three trailing axes
        self._ox, self._oy, self._oz = (self.off[:, k].reshape(M, 1, 1, 1).copy() for k in range(3))
        C = self.cyl.shape[0]
        # per-obstacle arrays: centre against (C, S, P); radius and height against (M, C, S, P)
        self._cx = self.cyl[:, 0].reshape(C, 1, 1).copy()
        self._cy = self.cyl[:, 1].reshape(C, 1, 1).copy()
        self._r = self.cyl[:, 2].reshape(1, C, 1, 1).copy()
        self._h_oz = (self.cyl[:, 3].reshape(1, C, 1, 1) - self._oz).copy()  # top minus UAV's z offset
        if sc.surface is not None and problem.inspection is not None:
            p0, u, n = sc.surface.frame
            self.wall: tuple[Any, ...] | None = (p0, u, n, sc.surface.length, *sc.surface.z_range)
            self.keep = 0.9 * problem.inspection.standoff
            # sample parameters along a UAV segment, centred on its midpoint: (k + 1/2) / K - 1/2
            K = self.SAMPLES
            self._k = ((np.arange(K) + 0.5) / K - 0.5).reshape(K, 1, 1, 1)
            # offsets along u and n: (ox e + oy e⊥ + oz z)·u = ex (ox u_x + oy u_y)
            # + ey (ox u_y - oy u_x) + oz u_z, with e = (ex, ey), e⊥ = (-ey, ex); n_z = 0
            ox, oy, oz = self._ox[:, :, 0], self._oy[:, :, 0], self._oz[:, :, 0]  # (M, 1, 1)
            self._wall_coef = (ox * u[0] + oy * u[1], ox * u[1] - oy * u[0], oz * u[2],
                               ox * n[0] + oy * n[1], ox * n[1] - oy * n[0])
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
        """J1, J2, J3 of centroid polylines ``V (P, nv, 3)``, shape ``(P, 3)``."""
        V = np.asarray(V, float)
        P, nv = V.shape[:2]
        T = np.ascontiguousarray(V.transpose(2, 1, 0))  # (3, nv, P)
        a = T[:, :-1]  # segment starts (3, S, P)
        d = T[:, 1:] - a
        dx, dy, dz = d
        S = nv - 1
        L2 = dx * dx + dy * dy
        L = np.sqrt(L2)  # horizontal length
        J1 = np.sqrt(L2 + dz * dz).sum(axis=0)
        flat = L > 0
        inv = 1.0 / np.where(flat, L, 1.0)
        # horizontal heading (P7): (1, 0) for a vertical segment, as atan2(0, 0) = 0 gives
        ex = np.where(flat, dx * inv, 1.0)
        ey = dy * inv
        J2 = np.full(P, self.pen * self.sep_shortfall * S)
        # manoeuvrability: horizontal turn at each inner vertex beyond max_turn
        ok = (L[:-1] > 1e-9) & (L[1:] > 1e-9)
        cosang = (dx[:-1] * dx[1:] + dy[:-1] * dy[1:]) / np.where(ok, L[:-1] * L[1:], 1.0)
        turn = np.where(ok, np.arccos(np.clip(cosang, -1.0, 1.0)), 0.0)
        J2 += 0.1 * self.pen * np.clip(turn - self.max_turn, 0.0, None).sum(axis=0)
        if self.cyl.shape[0]:
            J2 += self._cyl_penalty(a, ex, ey, L, np.where(flat, dz * inv, 0.0))
        # J3 altitude band at every vertex of every UAV's polyline
        z = T[2] + self._oz[:, :, 0]  # (M, nv, P)
        lo, hi = self.alt
        below = np.clip(lo - z, 0.0, np.inf).reshape(-1, P).sum(axis=0)
        above = np.clip(z - hi, 0.0, np.inf).reshape(-1, P).sum(axis=0)
        J3 = 0.1 * self.pen * (below + above)
        if self.wall is not None:
            w2, w3 = self._wall_penalty(a, d, ex, ey)
            J2 += w2
            J3 += w3
        return np.stack([J1, J2, J3], axis=1)

    def _buf(self, name: str, shape: tuple[int, ...], dtype: type = np.float64) -> NDArray:
        """A reusable work array (allocating large arrays on every call costs page faults)."""
        b = self._ws.get(name)
        if b is None or b.shape != shape or b.dtype != dtype:
            b = self._ws[name] = np.empty(shape, dtype)
        return b

    def _cyl_penalty(self, a, ex, ey, L, slope) -> NDArray[np.float64]:
        """Σ over UAVs, segments and cylinders of the J2 obstacle term, ``(P,)``."""
        ax, ay, az = a
        S, P = ax.shape
        M, C = self._ox.shape[0], self._cx.shape[0]
        hL = 0.5 * L  # (S, P)
        c1, c2, c3, c4 = (self._buf(f"c{i}", (C, S, P)) for i in range(4))
        B1, B2, B3, B4 = (self._buf(f"B{i}", (M, C, S, P)) for i in range(4))
        under = self._buf("under", (M, C, S, P), np.bool_)
        wx = np.subtract(self._cx, ax, out=c1)  # (C, S, P)
        wy = np.subtract(self._cy, ay, out=c2)
        uc = np.multiply(wx, ex, out=c3)
        uc += np.multiply(wy, ey, out=c4)
        uc -= hL  # along-track coordinate of the axis from the segment's midpoint
        v = np.multiply(wy, ex, out=c4)
        v -= np.multiply(wx, ey, out=c1)  # left of track
        uu = np.subtract(uc, self._ox, out=B1)  # (M, C, S, P), from UAV n's segment midpoint
        sc = np.maximum(uu, -hL, out=B2)
        np.minimum(sc, hL, out=sc)  # closest point, from the midpoint
        uu -= sc  # along-track distance beyond the segment's ends
        uu *= uu
        dv = np.subtract(v, self._oy, out=B3)
        dv *= dv
        uu += dv
        rho = np.sqrt(uu, out=uu)
        gap = np.subtract(rho, self._r, out=rho)  # horizontal clearance from the cylinder's side
        # height above the top at the closest point: a_z + dz/2 + sc dz/L + oz - h
        zt = np.multiply(sc, slope, out=sc)
        zt += az + hL * slope
        zt -= self._h_oz
        # clearance: gap below the top, hypot(max(gap, 0), zt) above it
        g0 = np.clip(gap, 0.0, np.inf, out=B3)
        zp = np.clip(zt, 0.0, np.inf, out=B4)
        np.less_equal(zt, 0.0, out=under)
        gap -= g0  # min(gap, 0), kept only below the top
        gap *= under
        g0 *= g0
        zp *= zp
        g0 += zp
        cl = np.sqrt(g0, out=g0)
        cl += gap  # clearance of the UAV's centre; minus r_uav gives the body's clearance c
        # ((D - c) / D)^2 clipped to [0, 1], plus K (1 - c) inside (c < 0)
        D, r, K = self.band, self.r_uav, self.pen
        inside = np.less(cl, r, out=under)
        q = np.multiply(cl, -1.0 / D, out=B4)
        q += 1.0 + r / D
        np.clip(q, 0.0, 1.0, out=q)
        q *= q
        depth = np.multiply(cl, -K, out=cl)
        depth += K * (1.0 + r)
        depth *= inside
        q += depth
        return q.reshape(-1, P).sum(axis=0)

    def _wall_penalty(self, a, d, ex, ey):
        """Wall crossing (J2) and stand-off (J3) terms, each ``(P,)``."""
        p0, u, n, L, z0, z1 = self.wall
        S, P = a.shape[1:]
        # wall coordinates of UAV n's segment start, s along the bottom edge and q off the plane:
        # the centroid's plus its offset ox e + oy e⊥ + oz z (e⊥ = (-ey, ex)) projected on u, n
        su_x, su_y, su_1, sn_x, sn_y = self._wall_coef  # (M, 1, 1) each
        ax, ay, az = a
        sA = (ax * u[0] + ay * u[1] + az * u[2] - p0 @ u) + (su_x * ex + su_y * ey + su_1)  # (M, S, P)
        qA = (ax * n[0] + ay * n[1] + az * n[2] - p0 @ n) + (sn_x * ex + sn_y * ey)
        ds = d[0] * u[0] + d[1] * u[1] + d[2] * u[2]  # (S, P): the same for every UAV
        dq = d[0] * n[0] + d[1] * n[1] + d[2] * n[2]
        zA = az + self._oz[:, :, 0]
        qB = qA + dq
        cross = qA * qB < 0
        t = qA / np.where(cross, qA - qB, 1.0)
        su, zz = sA + t * ds, zA + t * d[2]
        depth = np.minimum(np.minimum(su, L - su), np.minimum(zz - z0, z1 - zz))
        hit = cross & (depth > -self.r_uav)
        J2 = (hit * (self.pen * (1.0 + np.clip(depth, 0.0, np.inf)))).reshape(-1, P).sum(axis=0)
        # stand-off: distance to the rectangle at K samples per UAV segment, K along the axis 0,
        # with every coordinate measured from the middle of the segment and of the wall
        k = self._k  # (K, 1, 1, 1)
        shape = (k.shape[0], sA.shape[0], S, P)
        W1, W2, W3 = (self._buf(f"W{i}", shape) for i in range(3))
        es = np.add(k * ds, sA + (0.5 * ds - 0.5 * L), out=W1)  # along the edge
        np.abs(es, out=es)
        es -= 0.5 * L
        np.clip(es, 0.0, np.inf, out=es)  # beyond the wall's ends
        es *= es
        ez = np.add(k * d[2], zA + (0.5 * d[2] - 0.5 * (z0 + z1)), out=W2)  # height
        np.abs(ez, out=ez)
        ez -= 0.5 * (z1 - z0)
        np.clip(ez, 0.0, np.inf, out=ez)  # above or below the wall
        ez *= ez
        q = np.add(k * dq, qA + 0.5 * dq, out=W3)  # off the plane
        q *= q
        es += ez
        es += q
        kp = self.keep
        np.clip(es, 0.0, kp * kp, out=es)
        dist = np.sqrt(es, out=es)
        # Σ max((k - dist) / k, 0) = count - Σ min(dist, k) / k
        J3 = es[0].size // P * self.SAMPLES - dist.reshape(-1, P).sum(axis=0) / kp
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
