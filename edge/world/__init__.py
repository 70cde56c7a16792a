"""The simulated world: the synthetic surface (the wall and its ground-truth cracks) and the
synthetic camera that views it.

Imports :mod:`protocol` and :mod:`edge.geometry` only, never the bus nor the UAV's process, so
that the ground station rebuilds the edges' wall to score a mission (the import contracts in
``pyproject.toml``, checked by ``tests/test_layers.py``).
"""
