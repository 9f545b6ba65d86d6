"""Geodesic distance map D(M_t, w_t) (Eq. 3) by the fast marching method (scikit-fmm)."""

from __future__ import annotations

import numpy as np
import skfmm
from scipy import ndimage

from cso_runtime.geometry import GridGeometry


def disk(radius_cells: int) -> np.ndarray:
    """Boolean disk structuring element of the given radius in cells."""
    r = max(0, int(radius_cells))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return (xx * xx + yy * yy) <= r * r + 1e-9


def inflate(occupied: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Occupied cells grown by ``radius_m``: the cells where the robot centre would collide."""
    r = int(np.ceil(radius_m / resolution_m - 1e-9))
    if r <= 0 or not occupied.any():
        return occupied.copy()
    return ndimage.binary_dilation(occupied, structure=disk(r))


def traversable_cells(open_cells: np.ndarray, occupied: np.ndarray, robot_radius_m: float, resolution_m: float) -> np.ndarray:
    """Known free cells where the robot fits: open and outside the inflated obstacles.

    Unknown space is not traversable but is not inflated either, so frontier cells stay reachable.
    """
    return open_cells & ~inflate(occupied, robot_radius_m, resolution_m)


def _bounding_box(mask: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, mask.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, mask.shape[1])
    return slice(r0, r1), slice(c0, c1)


def geodesic_distance(traversable: np.ndarray, geometry: GridGeometry, source_xy_m: np.ndarray) -> np.ndarray:
    """Travel distance in metres from ``source_xy_m`` to every cell through ``traversable`` cells.

    Unreachable cells are ``inf`` (never a large finite number). The source cell and its immediate
    neighbourhood are treated as traversable, so a robot standing close to a wall still gets a map.
    Fast marching runs only on the bounding box of the traversable cells.
    """
    res = geometry.resolution_m
    out = np.full(geometry.shape, np.inf)
    sy, sx = geometry.world_to_cell(source_xy_m[0], source_xy_m[1])
    sy, sx = int(sy), int(sx)
    if not geometry.in_bounds(sy, sx):
        return out
    passable = traversable.copy()
    passable[max(sy - 1, 0) : sy + 2, max(sx - 1, 0) : sx + 2] = True
    box = _bounding_box(passable, margin=1)
    assert box is not None
    by, bx = box
    sub = passable[by, bx]
    ys, xs = np.mgrid[by, bx]
    cx, cy = geometry.cell_to_world(ys, xs)
    # Signed field whose zero level is a small circle around the source: FMM measures from it.
    r0 = 0.75 * res
    phi = np.hypot(cx - source_xy_m[0], cy - source_xy_m[1]) - r0
    phi_masked = np.ma.MaskedArray(phi, mask=~sub)
    try:
        dist = skfmm.distance(phi_masked, dx=res)
    except ValueError:  # no zero contour inside the passable region
        return out
    values = np.ma.filled(dist, np.inf).astype(float)
    values = np.where(np.ma.getmaskarray(dist) | ~sub, np.inf, np.abs(values) + r0)
    inside = phi < 0
    values[inside & sub] = np.hypot(cx - source_xy_m[0], cy - source_xy_m[1])[inside & sub]
    out[by, bx] = values
    return out
