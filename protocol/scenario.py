"""The scenario: one typed model of the whole inspection problem, and its TOML file.

Design notes: docs/scenario.md (protocol/scenario.py).
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = ["ScenarioError", "Origin", "Bounds", "Cylinder", "Surface", "surface_frame", "Camera", "Inspection",
           "FormationSpec", "CostSpec", "Speeds", "PlannerSpec", "Scenario", "validate_scenario", "load_scenario",
           "default_scenario_path"]

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Coord = Annotated[float, Field(ge=-1.0e5, le=1.0e5, allow_inf_nan=False)]
Vec3 = tuple[Coord, Coord, Coord]
Vec2 = tuple[Coord, Coord]


class ScenarioError(ValueError):
    """A scenario file or document that does not describe a valid planning problem."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Origin(_Model):
    """Geodetic origin of the local ENU frame: latitude, longitude (degrees), altitude (m)."""

    lat: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
    alt: Annotated[float, Field(ge=-1000.0, le=10000.0, allow_inf_nan=False)] = 0.0


class Bounds(_Model):
    """Operation box (geofence), ENU metres."""

    lo: Vec3
    hi: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Bounds:
        if any(h <= l for l, h in zip(self.lo, self.hi)):
            raise ValueError("box.hi must exceed box.lo on every axis")
        return self

    def contains(self, p: Any, margin: float = 0.0) -> bool:
        q = np.asarray(p, float)
        return bool(np.all(q >= np.add(self.lo, -margin)) and np.all(q <= np.add(self.hi, margin)))


class Cylinder(_Model):
    """A vertical cylinder standing on z = 0: horizontal centre (m), radius (m), height (top z, m)."""

    centre: Vec2
    radius: Positive
    height: Positive


def surface_frame(corners: Any) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Origin and unit axes ``(p0, u, v)`` of the surface frame of corners ``(4, 3)`` (p0-p1 the bottom edge,
    p3 above p0): ``u`` along ``p1 - p0``, ``v`` the unit part of ``p3 - p0`` orthogonal to ``u``.
    ValueError for a wrong shape, non-finite values or degenerate edges."""
    c = np.asarray(corners, dtype=float)
    if c.shape != (4, 3):
        raise ValueError(f"corners must have shape (4, 3), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("corners must be finite (got NaN or inf)")
    p0 = c[0]
    a, b = c[1] - p0, c[3] - p0
    la = float(np.linalg.norm(a))
    if la < 1e-9:
        raise ValueError("corners: the bottom edge corners[1] - corners[0] has zero length")
    u = a / la
    b = b - (b @ u) * u
    lb = float(np.linalg.norm(b))
    if lb < 1e-9:
        raise ValueError("corners: corners[3] - corners[0] is zero or parallel to the bottom edge")
    return p0, u, b / lb


class Surface(_Model):
    """A vertical planar rectangle to inspect.

    ``corners`` p0, p1, p2, p3 in order: p0-p1 is the horizontal bottom edge, p3 lies above p0,
    and the normal ``(p1 - p0) x (p3 - p0)`` points to the side the formation flies on.
    """

    corners: tuple[Vec3, Vec3, Vec3, Vec3]
    # the simulated wall (edge.world.surface.SyntheticSurface): texture pixel (mm) and real-size cracks, each
    # main crack's width range (mm) taken in turn from ``crack_widths_mm``; None keeps the defaults
    texture_mm: Annotated[float, Field(ge=0.05, le=100.0, allow_inf_nan=False)] | None = None
    crack_widths_mm: list[tuple[Positive, Positive]] | None = Field(default=None, min_length=1, max_length=64)
    crack_length_m: tuple[Positive, Positive] | None = None
    cracks: Annotated[int, Field(ge=1, le=1000)] | None = None

    @model_validator(mode="after")
    def _rectangle(self) -> Surface:
        p = np.asarray(self.corners, float)
        u, v = p[1] - p[0], p[3] - p[0]
        lu, lv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        if lu < 0.1 or lv < 0.1:
            raise ValueError("surface.corners: edges must be at least 0.1 m long")
        if not np.allclose(p[2], p[1] + v, atol=0.01):
            raise ValueError("surface.corners: p2 must equal p1 + (p3 - p0) (a rectangle, in order)")
        if abs(float(u @ v)) > 1e-3 * lu * lv:
            raise ValueError("surface.corners: edges p0-p1 and p0-p3 must be perpendicular")
        if abs(u[2]) > 0.01 or np.hypot(v[0], v[1]) > 0.01 or v[2] <= 0:
            raise ValueError("surface.corners: only vertical walls are supported (p0-p1 horizontal, p3 above p0)")
        for lo, hi in self.crack_widths_mm or ():
            if lo > hi:
                raise ValueError(f"surface.crack_widths_mm: ({lo}, {hi}) is not a (min, max) pair")
        if self.crack_length_m is not None and self.crack_length_m[0] > self.crack_length_m[1]:
            raise ValueError("surface.crack_length_m must be a (min, max) pair")
        if self.texture_mm is not None and lu * lv * (1e3 / self.texture_mm) ** 2 > 100e6:
            raise ValueError(f"surface.texture_mm: {lu:.2f} m x {lv:.2f} m at {self.texture_mm} mm per pixel "
                             "exceeds 100 MP")
        return self

    @property
    def frame(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(p0, u, n)``: bottom-left corner, unit vector along the bottom edge, unit normal ``u x v``
        (:func:`surface_frame`; the wall is vertical, so ``v`` is straight up)."""
        p0, u, v = surface_frame(self.corners)
        return p0, u, np.cross(u, v)

    @property
    def length(self) -> float:
        p = np.asarray(self.corners, float)
        return float(np.linalg.norm(p[1] - p[0]))

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.corners[0][2]), float(self.corners[3][2])


class Camera(_Model):
    """Pinhole camera: resolution (px), sensor size and focal length in the same unit (mm)."""

    resolution: tuple[Annotated[int, Field(ge=1, le=100000)], Annotated[int, Field(ge=1, le=100000)]]
    sensor_mm: tuple[Positive, Positive]
    focal_mm: Positive
    #: the edges deliver frames at ``resolution`` (cracks of real size need every pixel) unless the launcher is
    #: given a frame size; False: the launcher's default capture size (the same field of view, fewer pixels)
    full_frames: bool = False


class Inspection(_Model):
    """Task-assessment parameters: smallest feature ``s_f`` (m), overlap ``o_p`` (P1)-(P3)."""

    smallest_feature: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 0.0025
    overlap: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)] = 0.2
    lead_in: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)] = 2.0


class FormationSpec(_Model):
    """Formation offsets ΔT_n (formation frame: x along travel, y left, z up) (P9)."""

    offsets: list[Vec3] = Field(default=[(0.0, 0.0, 2.0), (3.0, 0.0, -1.0), (-3.0, 0.0, -1.0)], min_length=1,
                                max_length=255)
    min_separation: NonNeg = 2.0


class CostSpec(_Model):
    """Weights and shape parameters of the cost (P5); see :mod:`services.planner.cost`."""

    beta: tuple[NonNeg, NonNeg, NonNeg] = (1.0, 1.0, 1.0)
    uav_radius: NonNeg = 0.5
    danger_band: Positive = 2.0
    collision_penalty: NonNeg = 100.0
    altitude: tuple[Finite, Finite] = (5.0, 38.0)
    max_turn_deg: Annotated[float, Field(gt=0.0, le=180.0, allow_inf_nan=False)] = 60.0

    @model_validator(mode="after")
    def _band(self) -> CostSpec:
        if self.altitude[1] <= self.altitude[0]:
            raise ValueError("cost.altitude: upper bound must exceed the lower bound")
        return self


class Speeds(_Model):
    """Speed (m/s) and acceleration (m/s^2) limits of the formation."""

    cruise: Annotated[float, Field(gt=0.0, le=30.0, allow_inf_nan=False)] = 2.5
    inspect: Annotated[float, Field(gt=0.0, le=30.0, allow_inf_nan=False)] = 2.0
    max: Annotated[float, Field(gt=0.0, le=30.0, allow_inf_nan=False)] = 5.0
    accel: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)] = 1.0
    lateral_accel: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)] = 1.0

    @model_validator(mode="after")
    def _max(self) -> Speeds:
        if self.cruise > self.max or self.inspect > self.max:
            raise ValueError("speeds.max must be at least speeds.cruise and speeds.inspect")
        return self


class PlannerSpec(_Model):
    """Default optimiser budget and initialisation."""

    particles: Annotated[int, Field(ge=2, le=10000)] = 60
    waypoints: Annotated[int, Field(ge=1, le=200)] = 10
    iterations: Annotated[int, Field(ge=1, le=100000)] = 150
    init: Literal["corridor", "box"] = "corridor"
    corridor_width: Positive = 15.0


class Scenario(_Model):
    """The whole planning problem (the file format: docs/scenario.md)."""

    name: Annotated[str, Field(max_length=256)] = "scenario"
    origin: Origin
    box: Bounds
    start: Vec3
    goal: Vec3
    geodetic_far_corner: tuple[Finite, Finite, Finite] | None = None
    obstacles: list[Cylinder] = Field(default=[], max_length=1000)
    surface: Surface | None = None
    camera: Camera = Camera(resolution=(4000, 3000), sensor_mm=(36.0, 27.0), focal_mm=34.4)
    inspection: Inspection = Inspection()
    formation: FormationSpec = FormationSpec()
    cost: CostSpec = CostSpec()
    speeds: Speeds = Speeds()
    planner: PlannerSpec = PlannerSpec()

    @model_validator(mode="after")
    def _consistent(self) -> Scenario:
        for name in ("start", "goal"):
            p = getattr(self, name)
            if not self.box.contains(p):
                raise ValueError(f"{name}: {tuple(p)} lies outside the box {self.box.lo}..{self.box.hi}")
            for i, c in enumerate(self.obstacles):
                if math.hypot(p[0] - c.centre[0], p[1] - c.centre[1]) < c.radius and p[2] < c.height:
                    raise ValueError(f"{name}: {tuple(p)} lies inside obstacles[{i}]")
        if self.surface is not None:
            for i, q in enumerate(self.surface.corners):
                if not self.box.contains(q):
                    raise ValueError(f"surface.corners[{i}]: {tuple(q)} lies outside the box")
        lo, hi = self.cost.altitude
        if lo < self.box.lo[2] or hi > self.box.hi[2]:
            raise ValueError("cost.altitude: the altitude band must lie within the box's z range")
        return self

    # ------------------------------------------------------------------ array views
    @property
    def lo(self) -> NDArray[np.float64]:
        return np.asarray(self.box.lo, float)

    @property
    def hi(self) -> NDArray[np.float64]:
        return np.asarray(self.box.hi, float)

    @property
    def offsets(self) -> NDArray[np.float64]:
        return np.asarray(self.formation.offsets, float)

    def cylinders(self) -> NDArray[np.float64]:
        """Obstacles as an array ``(C, 4)``: centre x, centre y, radius, height."""
        if not self.obstacles:
            return np.zeros((0, 4))
        return np.array([[*c.centre, c.radius, c.height] for c in self.obstacles], float)


def _field_name(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "<root>"


def _format(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        msg = e["msg"].removeprefix("Value error, ")
        name = _field_name(tuple(e["loc"]))
        lines.append(f"scenario field {name!r}: {msg}" if name != "<root>" else f"scenario: {msg}")
    return "; ".join(lines)


def validate_scenario(doc: Any) -> Scenario:
    """Validate a scenario document (a dict as read from TOML or carried by a plan request); ScenarioError
    naming the field (``obstacles[2].radius``, ``start``, ...) otherwise."""
    if isinstance(doc, Scenario):
        return doc
    if not isinstance(doc, dict):
        raise ScenarioError(f"scenario must be a mapping, got {type(doc).__name__}")
    try:
        return Scenario.model_validate(doc)
    except ValidationError as err:
        raise ScenarioError(_format(err)) from None


def default_scenario_path() -> Path:
    """Path of the packaged default scenario (the paper's monorail bridge)."""
    return Path(str(resources.files("protocol") / "scenarios" / "monorail.toml"))


def load_scenario(path: str | Path | None = None) -> Scenario:
    """Read and validate a scenario TOML file: ``None`` the default monorail scenario, a packaged scenario's
    name (``protocol/scenarios/<name>.toml``, e.g. ``real-cracks``) that one; ScenarioError naming the file
    and the field otherwise."""
    p = default_scenario_path() if path is None else Path(path)
    packaged = default_scenario_path().parent / f"{p.name}.toml"
    if path is not None and not p.exists() and p.name == str(path) and packaged.is_file():
        p = packaged  # a packaged scenario by name: ``--scenario real-cracks``
    try:
        with open(p, "rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario file {p}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"scenario file {p} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:  # TOML is UTF-8 (TOML v1.0.0, "Spec"); tomllib lets this one through
        raise ScenarioError(f"scenario file {p} is not UTF-8 text: {exc.reason} at byte {exc.start}") from None
    except RecursionError:  # tomllib recurses once per nested array or inline table
        raise ScenarioError(f"scenario file {p} is nested too deeply to read (arrays or inline tables "
                            "within each other, deeper than Python's recursion limit)") from None
    try:
        return validate_scenario(doc)
    except ScenarioError as exc:
        raise ScenarioError(f"{p}: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{p}: nested too deeply to validate") from None

