"""The simulated inspected wall: the scenario's surface as a textured, cracked :class:`SyntheticSurface`.

One wall for the whole fleet (one seed, whatever the UAV), so that the ground station rebuilds the
very surface the edges image, and with it the ground truth.
"""

from __future__ import annotations

import numpy as np

from protocol.scenario import Scenario

from .surface import DEFAULT_PX_PER_M, SyntheticSurface, surface_options

#: seed of the synthetic surface: one wall for the whole fleet, whatever the UAV
SURFACE_SEED = 2024


def synthetic_surface(scenario: Scenario, px_per_m: float | None = None, seed: int = SURFACE_SEED) -> SyntheticSurface:
    """The inspected wall of the scenario as a textured, cracked :class:`SyntheticSurface`."""
    if scenario.surface is None:
        raise ValueError(f"scenario {scenario.name!r} has no [surface] to image")
    corners = np.asarray(scenario.surface.corners, dtype=float)
    opts = surface_options(scenario.surface)  # the scenario's texture pixel and real-size cracks, if any
    own = opts.pop("px_per_m", DEFAULT_PX_PER_M)
    return SyntheticSurface.from_corners(corners, px_per_m=px_per_m or own, seed=seed, **opts)
