"""Vectorised 2D ray marching on grids, shared by the simulated sensor and the mapper."""

from __future__ import annotations

import numpy as np

from cso_runtime.geometry import GridGeometry

SAMPLES_PER_CELL = 3
"""Samples per cell length along each beam: fine enough that no beam skips a wall one cell thick."""


def beam_samples(
    geometry: GridGeometry, origin_xy_m: np.ndarray, angles_rad: np.ndarray, lengths_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells visited along each beam from ``origin_xy_m`` up to ``lengths_m`` (per beam).

    Returns ``(iy, ix, dist_m)`` of shape (beams, samples); samples past a beam's length have
    ``dist_m`` > length and must be ignored by the caller.
    """
    step_m = geometry.resolution_m / SAMPLES_PER_CELL
    longest = float(np.max(lengths_m)) if len(lengths_m) else 0.0
    n = max(1, int(np.ceil(longest / step_m)) + 1)
    dist = np.arange(n, dtype=np.float64) * step_m
    cos, sin = np.cos(angles_rad)[:, None], np.sin(angles_rad)[:, None]
    xs = origin_xy_m[0] + cos * dist[None, :]
    ys = origin_xy_m[1] + sin * dist[None, :]
    iy, ix = geometry.world_to_cell(xs, ys)
    return iy, ix, np.broadcast_to(dist, iy.shape)


def cast_rays(
    blocked: np.ndarray,
    geometry: GridGeometry,
    origin_xy_m: np.ndarray,
    angles_rad: np.ndarray,
    max_range_m: float,
) -> np.ndarray:
    """Exact range to the first blocked cell along each beam; ``inf`` when none within range.

    Cells outside the grid count as blocked (a floor plan's border is a wall).
    """
    origin = np.asarray(origin_xy_m, dtype=float)
    angles = np.asarray(angles_rad, dtype=float)
    iy, ix, _ = beam_samples(geometry, origin, angles, np.full(len(angles), max_range_m))
    inside = geometry.in_bounds(iy, ix)
    hit = ~inside
    hit[inside] = blocked[iy[inside], ix[inside]]
    any_hit = hit.any(axis=1)
    first = hit.argmax(axis=1)
    rows = np.arange(len(angles))
    hy, hx = iy[rows, first], ix[rows, first]
    # Exact entry distance into the hit cell (slab test), so ranges do not depend on the sampling.
    res = geometry.resolution_m
    x0 = geometry.origin_x_m + hx * res
    y0 = geometry.origin_y_m + hy * res
    dx, dy = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx0, tx1 = (x0 - origin[0]) / dx, (x0 + res - origin[0]) / dx
        ty0, ty1 = (y0 - origin[1]) / dy, (y0 + res - origin[1]) / dy
    tx_enter = np.where(dx == 0, -np.inf, np.minimum(tx0, tx1))
    ty_enter = np.where(dy == 0, -np.inf, np.minimum(ty0, ty1))
    ranges = np.maximum(np.maximum(tx_enter, ty_enter), 0.0)
    ranges = np.where(any_hit & (ranges <= max_range_m), ranges, np.inf)
    return ranges
