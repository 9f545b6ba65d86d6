"""Geodesic distance map D(M_t, w_t) (Eq. 3) by the fast marching method (scikit-fmm)."""

from __future__ import annotations

import functools
import math

import numpy as np
import skfmm

from cso_runtime.geometry import GridGeometry


def disk(radius_cells: int) -> np.ndarray:
    """Boolean disk structuring element of the given radius in cells."""
    r = max(0, int(radius_cells))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return (xx * xx + yy * yy) <= r * r + 1e-9


@functools.lru_cache(maxsize=32)
def disk_offsets(radius_cells: int) -> np.ndarray:
    """(n, 2) cell offsets (dy, dx) of ``disk(radius_cells)`` around its centre; cached (read-only),
    since every scan, decision and blocked check asks for the same few radii."""
    r = max(0, int(radius_cells))
    offsets = np.argwhere(disk(r)) - r
    offsets.setflags(write=False)
    return offsets


def disk_cells(geometry: GridGeometry, xy_m: tuple[float, float] | np.ndarray, radius_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the cells of ``disk(radius_cells)`` around the cell of ``xy_m`` that lie on the map. A disk
    that reaches past the map's farthest corner holds every cell of it, as one that reaches just that corner does: it is
    made that large (``episode.goal_tolerance_m: 1e300`` asked numpy for a disk of 1e301 cells)."""
    iy, ix = geometry.world_to_cell(xy_m[0], xy_m[1])
    ny, nx = geometry.shape
    farthest = math.ceil(max(math.hypot(y - int(iy), x - int(ix)) for y in (0, ny - 1) for x in (0, nx - 1)))
    offs = disk_offsets(min(radius_cells, farthest))
    yy, xx = offs[:, 0] + int(iy), offs[:, 1] + int(ix)
    ok = geometry.in_bounds(yy, xx)
    return yy[ok], xx[ok]


def inflate(occupied: np.ndarray, radius_m: float, resolution_m: float) -> np.ndarray:
    """Occupied cells grown by ``radius_m``: the cells where the robot centre would collide.

    A dilation by a disk, done as one shifted OR per disk offset: for robot-sized radii (a few
    cells) this is an order of magnitude faster than a generic morphological dilation.
    """
    r = int(np.ceil(radius_m / resolution_m - 1e-9))
    out = occupied.copy()
    if r <= 0 or not occupied.any():
        return out
    ny, nx = occupied.shape
    for dy, dx in disk_offsets(r):
        if (dy == 0 and dx == 0) or abs(dy) >= ny or abs(dx) >= nx:
            continue  # itself, or a shift off the grid (a grid narrower than the disk): a slice end would go negative
        out[max(dy, 0) : ny + min(dy, 0), max(dx, 0) : nx + min(dx, 0)] |= occupied[
            max(-dy, 0) : ny + min(-dy, 0), max(-dx, 0) : nx + min(-dx, 0)
        ]
    return out


def traversable_cells(open_cells: np.ndarray, occupied: np.ndarray, robot_radius_m: float, resolution_m: float) -> np.ndarray:
    """Known free cells where the robot fits: open and outside the inflated obstacles.

    Unknown space is not traversable but is not inflated either, so frontier cells stay reachable.
    """
    return open_cells & ~inflate(occupied, robot_radius_m, resolution_m)


def escape_cells(open_cells: np.ndarray, geometry: GridGeometry, source_xy_m: np.ndarray, robot_radius_m: float) -> np.ndarray:
    """Open cells within the robot's radius (and one cell) of ``source_xy_m``: the way out for a robot
    that stands inside the inflated obstacles (a start placed 0.1 m from a wall, a corner cut too close).
    The robot's body is already there, so it may move through them to the traversable cells around it,
    as Nav2's planners let a robot leave the inscribed zone it starts in."""
    out = np.zeros(geometry.shape, dtype=bool)
    out[disk_cells(geometry, source_xy_m, int(np.ceil(robot_radius_m / geometry.resolution_m - 1e-9)) + 1)] = True
    return out & open_cells


_WINDOW_MARGIN_CELLS = 3
"""How much wider than ``within_m`` the window of a bounded fast-marching pass is, in cells."""


def _bounding_box(mask: np.ndarray, margin: int, window: tuple[int, int, int] | None = None) -> tuple[slice, slice] | None:
    """The bounding box of ``mask``'s set cells grown by ``margin``; with ``window`` (cy, cx, half-width
    in cells) only the part of ``mask`` inside that square counts."""
    oy = ox = 0
    if window is not None:
        cy, cx, half = window
        oy, ox = max(cy - half, 0), max(cx - half, 0)
        mask = mask[oy : cy + half + 1, ox : cx + half + 1]
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, mask.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, mask.shape[1])
    return slice(r0 + oy, r1 + oy), slice(c0 + ox, c1 + ox)


def geodesic_distance(traversable: np.ndarray, geometry: GridGeometry, source_xy_m: np.ndarray, within_m: float | None = None) -> np.ndarray:
    """Travel distance in metres from ``source_xy_m`` to every cell through ``traversable`` cells.

    Unreachable cells are ``inf`` (never a large finite number). The source cell and its immediate
    neighbourhood are treated as traversable, so a robot standing close to a wall still gets a map.
    Fast marching runs only on the bounding box of the traversable cells.

    ``within_m``: only distances below it are wanted (the stuck mask's alpha_3). Fast marching then
    runs on a window a few cells wider than ``within_m`` around the source and stops soon after
    ``within_m``: every value below ``within_m`` is exactly the full map's (a cell's value depends
    only on cells of smaller value, all inside the window), farther cells may read ``inf``. On a
    640 x 480 map with alpha_3 = 1 m that is about 15 times faster than the full map (docs/experiments/runtime-overhead.md).
    """
    res = geometry.resolution_m
    out = np.full(geometry.shape, np.inf)
    sy, sx = map(int, geometry.world_to_cell(source_xy_m[0], source_xy_m[1]))
    if not geometry.in_bounds(sy, sx):
        return out
    window = None if within_m is None else int(math.ceil(within_m / res)) + _WINDOW_MARGIN_CELLS
    box = _bounding_box(traversable, margin=2, window=None if window is None else (sy, sx, window))
    if box is None:
        box = (slice(max(sy - 2, 0), sy + 3), slice(max(sx - 2, 0), sx + 3))
    by = slice(min(box[0].start, max(sy - 2, 0)), max(box[0].stop, sy + 3))
    bx = slice(min(box[1].start, max(sx - 2, 0)), max(box[1].stop, sx + 3))
    sub = traversable[by, bx].copy()
    ly, lx = sy - by.start, sx - bx.start
    sub[max(ly - 1, 0) : ly + 2, max(lx - 1, 0) : lx + 2] = True  # the robot's own cell is passable
    # Signed field whose zero level is a small circle around the source (only a 5x5 patch around
    # it needs true values; everywhere else any positive number will do): FMM measures from it.
    r0 = 0.75 * res
    phi = np.ones(sub.shape)
    # cut to the map on every side (the box may reach past its top or right edge: a robot 2 cells from it)
    py, px = slice(max(ly - 2, 0), min(ly + 3, sub.shape[0])), slice(max(lx - 2, 0), min(lx + 3, sub.shape[1]))
    pys, pxs = np.mgrid[py, px]
    cx, cy = geometry.cell_to_world(pys + by.start, pxs + bx.start)
    near = np.hypot(cx - source_xy_m[0], cy - source_xy_m[1])
    phi[py, px] = near - r0
    try:
        # narrow: the march stops past within_m (skfmm's band is measured from the zero level, r0 in)
        narrow = 0.0 if within_m is None else within_m + 2 * res
        dist = skfmm.distance(np.ma.MaskedArray(phi, mask=~sub), dx=res, narrow=narrow)
    except ValueError:  # no zero contour inside the passable region
        return out
    values = np.ma.filled(dist, np.inf)
    values = np.where(np.ma.getmaskarray(dist) | ~sub, np.inf, np.abs(values) + r0)
    patch = values[py, px]
    inside = (near < r0) & sub[py, px]
    patch[inside] = near[inside]
    out[by, bx] = values
    return out
