"""Sampling of piecewise-constant shapes on a regular grid that also contains every edge."""

from __future__ import annotations

import numpy as np


def sample_piecewise(edges: np.ndarray, values: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample a zero-order-hold shape.

    ``values[j]`` holds on ``[edges[j], edges[j+1])``. Returns sample times: the union of the regular grid
    ``0, dt, 2 dt, ...`` and all edges (so every edge is exactly on a sample), and the value at each sample
    time (right limit; the last sample repeats the last value).
    """
    edges = np.asarray(edges, dtype=float)
    values = np.asarray(values, dtype=float)
    grid = np.arange(0.0, edges[-1] + 0.5 * dt, dt)
    grid = grid[grid < edges[-1] - 1e-9 * max(1.0, edges[-1])]
    t = np.union1d(grid, edges)
    k = np.searchsorted(edges, t, side="right") - 1
    k = np.clip(k, 0, values.size - 1)
    return t, values[k]
