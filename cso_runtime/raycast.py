"""Vectorised 2D ray marching on grids, shared by the simulated sensor and the mapper.

Beams are sampled at a fixed spacing (``SAMPLES_PER_CELL`` per cell) in chunks of
``SAMPLES_PER_CHUNK`` samples: a beam leaves the march at its first hit (sensor) or its length
(mapper), so an indoor scan touches a few metres per beam instead of the full range, and the
temporaries stay small (no fresh pages from the allocator on every scan).
"""

from __future__ import annotations

import numpy as np

from cso_runtime.geometry import GridGeometry

SAMPLES_PER_CELL = 3
"""Samples per cell length along each beam: fine enough that no beam skips a wall one cell thick."""
SAMPLES_PER_CHUNK = 96
"""Samples marched at once per beam (a speed setting only: results do not depend on it)."""


def sample_step_m(geometry: GridGeometry) -> float:
    """Spacing of the samples along a beam."""
    return geometry.resolution_m / SAMPLES_PER_CELL


def samples_to_reach(geometry: GridGeometry, length_m: float) -> int:
    """Samples per beam (from the origin, ``i * sample_step_m``) that cover ``length_m``."""
    return max(1, int(np.ceil(length_m / sample_step_m(geometry))) + 1)


def floor_cells(
    geometry: GridGeometry, origin_xy_m: np.ndarray, cos: np.ndarray, sin: np.ndarray, dist_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (floats, floored; outside the grid too) of the points ``origin + dist_m * (cos, sin)``,
    with ``cos``, ``sin`` and ``dist_m`` broadcast together: ``GridGeometry.world_to_cell`` to the last bit,
    worked in place."""
    res = geometry.resolution_m
    fx = cos * dist_m
    fx += origin_xy_m[0]
    fx -= geometry.origin_x_m
    fx /= res
    np.floor(fx, out=fx)
    fy = sin * dist_m
    fy += origin_xy_m[1]
    fy -= geometry.origin_y_m
    fy /= res
    np.floor(fy, out=fy)
    return fx, fy


def sample_cells(
    geometry: GridGeometry, origin_xy_m: np.ndarray, cos: np.ndarray, sin: np.ndarray, first: int, stop: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples ``first .. stop - 1`` along beams of direction ``(cos, sin)``, shape (beams, samples):
    each sample's flat cell index ``iy * width + ix`` as float64 (exact: cell indices are small
    integers; meaningful only where inside), whether it lies inside the grid, and the samples'
    distances from the origin ``dist_m`` (samples,). Worked in place and in floats, since this runs
    for every beam of every scan, in the simulator and in the mapper."""
    dist = np.arange(first, stop, dtype=np.float64) * sample_step_m(geometry)
    height, width = geometry.shape
    fx, fy = floor_cells(geometry, origin_xy_m, cos[:, None], sin[:, None], dist[None, :])
    inside = fx >= 0
    inside &= fx < width
    inside &= fy >= 0
    inside &= fy < height
    fy *= width
    fy += fx
    return fy, inside, dist


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
    cos, sin = np.cos(angles), np.sin(angles)
    n = samples_to_reach(geometry, max_range_m)
    any_hit = np.zeros(len(angles), dtype=bool)
    hy = np.zeros(len(angles), dtype=np.int64)
    hx = np.zeros(len(angles), dtype=np.int64)
    active = np.arange(len(angles))
    blocked_flat = np.ascontiguousarray(blocked).ravel()
    for first in range(0, n, SAMPLES_PER_CHUNK):
        cell, inside, dist = sample_cells(geometry, origin, cos[active], sin[active], first, min(first + SAMPLES_PER_CHUNK, n))
        hit = ~inside
        hit[inside] = blocked_flat[cell[inside].astype(np.intp)]
        found = hit.any(axis=1)
        rows = np.flatnonzero(found)
        at = hit[rows].argmax(axis=1)
        beams = active[rows]
        # The hit cell's column and row, recomputed rather than split from the flat index: a sample
        # just outside the left or right edge (column -1 or width) would wrap into another row.
        fx, fy = floor_cells(geometry, origin, cos[beams], sin[beams], dist[at])
        hx[beams], hy[beams] = fx.astype(np.int64), fy.astype(np.int64)
        any_hit[beams] = True
        active = active[~found]
        if not len(active):
            break
    # Exact entry distance into the hit cell (slab test), so ranges do not depend on the sampling.
    res = geometry.resolution_m
    x0 = geometry.origin_x_m + hx * res
    y0 = geometry.origin_y_m + hy * res
    with np.errstate(divide="ignore", invalid="ignore"):
        tx0, tx1 = (x0 - origin[0]) / cos, (x0 + res - origin[0]) / cos
        ty0, ty1 = (y0 - origin[1]) / sin, (y0 + res - origin[1]) / sin
        tx_enter = np.where(cos == 0, -np.inf, np.minimum(tx0, tx1))
        ty_enter = np.where(sin == 0, -np.inf, np.minimum(ty0, ty1))
        ranges = np.maximum(np.maximum(tx_enter, ty_enter), 0.0)
        ranges = np.where(any_hit & (ranges <= max_range_m), ranges, np.inf)
    return ranges
