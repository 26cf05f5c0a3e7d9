"""Where a mechanism's train fit is best on its search grid, between grid points.

A mechanism's parameter is searched on a grid (:meth:`sindy_ekf.diagnose.families.Family.grid`) and
refined between its points by the parabola through the best point and its neighbours, so that
mechanisms on grids of different spacing are compared near their optima (the scoring, the choice of
form and the per-input values share these).
"""

from __future__ import annotations

import numpy as np


def parabolic_argmin(grid: np.ndarray, sse: np.ndarray) -> np.ndarray:
    """Return the vertex of the parabola through the best grid point and its neighbours (1-D)."""
    i = int(np.argmin(sse))
    if grid.shape[1] != 1 or i == 0 or i == len(grid) - 1 or not np.all(np.isfinite(sse[i - 1:i + 2])):
        return grid[i]
    x, y = grid[i - 1:i + 2, 0], sse[i - 1:i + 2]
    den = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / den
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / den
    return np.array([-b / (2 * a)]) if a > 0 else grid[i]


def parabolic_min(grid: np.ndarray, sse: np.ndarray) -> float:
    """Return the minimum of the parabola through the best of ``sse`` on ``grid`` and its neighbours
    (the best value itself at an edge or without curvature): mechanisms on grids of different
    spacing compared near their optima, not at wherever their grid points happen to fall."""
    i = int(np.nanargmin(np.where(np.isfinite(sse), sse, np.inf)))
    if i == 0 or i == len(sse) - 1 or not np.all(np.isfinite(sse[i - 1:i + 2])):
        return float(sse[i])
    (x0, x1, x2), (y0, y1, y2) = grid[i - 1:i + 2], sse[i - 1:i + 2]
    c2 = ((y2 - y1) / (x2 - x1) - (y1 - y0) / (x1 - x0)) / (x2 - x0)  # second divided difference
    if c2 <= 0:
        return float(y1)
    c1 = (y1 - y0) / (x1 - x0) - c2 * (x0 + x1)  # y = c2 x^2 + c1 x + c0 through the three points
    x_min = -c1 / (2 * c2)
    return float(min(y1, y1 + c1 * (x_min - x1) + c2 * (x_min ** 2 - x1 ** 2)))
