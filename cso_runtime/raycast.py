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


FREE_CELL, AT_DIAGONAL_GAP, BLOCKED_CELL = 0, 1, 2
"""``ray_codes``' values."""


def ray_codes(blocked: np.ndarray) -> np.ndarray:
    """What ``cast_rays`` reads of each cell (flat, uint8): ``BLOCKED_CELL``, ``AT_DIAGONAL_GAP`` (free, and with a free
    diagonal neighbour across the corner of two blocked cells that touch only there: a wall drawn diagonally) or
    ``FREE_CELL``; one entry more at the end, ``BLOCKED_CELL``: what a sample off the grid reads (a floor plan's border
    is a wall), so every sample is one lookup. A caller that casts on one grid every step makes it once and passes it
    on."""
    b = np.asarray(blocked, dtype=bool)
    low_left, low_right, up_left, up_right = b[:-1, :-1], b[:-1, 1:], b[1:, :-1], b[1:, 1:]  # each 2 x 2 block's cells
    rising = low_left & up_right & ~low_right & ~up_left  # blocked from lower left to upper right, the others free
    falling = low_right & up_left & ~low_left & ~up_right
    gap = np.zeros_like(b)
    gap[:-1, 1:] |= rising
    gap[1:, :-1] |= rising
    gap[:-1, :-1] |= falling
    gap[1:, 1:] |= falling
    codes = gap.astype(np.uint8)
    codes[b] = BLOCKED_CELL
    return np.append(codes.ravel(), np.uint8(BLOCKED_CELL))


def crossed_on_diagonal_steps(
    geometry: GridGeometry, origin_xy_m: np.ndarray, cos: np.ndarray, sin: np.ndarray, before: np.ndarray, step: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For beams whose consecutive samples lie in the cells ``before`` and ``before + step`` (flat indices on the grid,
    diagonal neighbours: ``step`` is +-width +-1), the two cells beside both (flat), the first in ``before``'s row, the
    second in its column; and which of them the beam crossed, where no sample lies: -1 the first (it met the edge
    between columns first), 1 the second, 0 neither (it went exactly through the corner all four share)."""
    width = geometry.shape[1]
    d_row = np.sign(step)  # |step| is width + 1 or width - 1 (at least 2): its sign is the row's
    d_col = step - d_row * width
    row, col = np.divmod(before, width)
    res = geometry.resolution_m
    t_col = (geometry.origin_x_m + (col + (d_col > 0)) * res - origin_xy_m[0]) / cos  # a diagonal step changes both:
    t_row = (geometry.origin_y_m + (row + (d_row > 0)) * res - origin_xy_m[1]) / sin  # cos and sin are not 0
    return before + d_col, before + d_row * width, np.sign(t_col - t_row)


def cast_rays(
    blocked: np.ndarray,
    geometry: GridGeometry,
    origin_xy_m: np.ndarray,
    angles_rad: np.ndarray,
    max_range_m: float,
    codes: np.ndarray | None = None,
) -> np.ndarray:
    """Range to the first blocked cell along each beam, exact where a sample fell in it; ``inf`` when none within range.
    ``codes``: ``ray_codes(blocked)`` where the caller keeps it (made here otherwise).

    Cells outside the grid count as blocked (a floor plan's border is a wall). Beams are sampled a third of a cell
    apart, so a beam may clip a blocked cell's corner between two samples and go on (a wall's corner a fraction of a
    sample smaller); but across the corner two blocked cells share (a wall drawn diagonally) a beam always stops
    (``crossed_on_diagonal_steps``): sampled only, beams saw the room behind such a wall.
    """
    origin = np.asarray(origin_xy_m, dtype=float)
    angles = np.asarray(angles_rad, dtype=float)
    cos, sin = np.cos(angles), np.sin(angles)
    n = samples_to_reach(geometry, max_range_m)
    width = geometry.shape[1]
    any_hit = np.zeros(len(angles), dtype=bool)
    hy = np.zeros(len(angles), dtype=np.int64)
    hx = np.zeros(len(angles), dtype=np.int64)
    py = np.zeros(len(angles), dtype=np.int64)
    px = np.zeros(len(angles), dtype=np.int64)
    near_m = np.zeros(len(angles))
    far_m = np.zeros(len(angles))
    active = np.arange(len(angles))
    codes = ray_codes(blocked) if codes is None else codes
    for first in range(0, n, SAMPLES_PER_CHUNK):
        lead = 1 if first else 0  # the sample before the chunk too: the step into the chunk is tested with it
        cell, inside, dist = sample_cells(geometry, origin, cos[active], sin[active], first - lead, min(first + SAMPLES_PER_CHUNK, n))
        cell[~inside] = len(codes) - 1  # off the grid: ray_codes' last entry, blocked
        code = codes[cell.astype(np.intp)]
        hit = code == BLOCKED_CELL
        # A step from a cell at a diagonal gap to the cell across it (flat step +-width +-1) went between the two
        # blocked cells, which no sample lies in: the hit, at the step's sample, is the one whose edge the beam met first.
        samples = cell.shape[1]
        k = np.flatnonzero(code == AT_DIAGONAL_GAP)
        k = k[k % samples != samples - 1]  # a chunk's last sample has no step after it here
        crossed_at = crossed = k[:0]
        if len(k):
            before, after = cell.ravel()[k].astype(np.int64), cell.ravel()[k + 1].astype(np.int64)
            step = np.where(inside.ravel()[k + 1], after - before, 0)
            diagonal = (np.abs(step) == width + 1) | (np.abs(step) == width - 1)
            k, before, step = k[diagonal], before[diagonal], step[diagonal]
            beams = active[k // samples]
            col_side, row_side, order = crossed_on_diagonal_steps(geometry, origin, cos[beams], sin[beams], before, step)
            stops = (codes[col_side] == BLOCKED_CELL) & (codes[row_side] == BLOCKED_CELL)
            crossed_at, crossed = k[stops] + 1, np.where(order < 0, col_side, row_side)[stops]  # flat samples, ascending
            hit.ravel()[crossed_at] = True
        found = hit.any(axis=1)
        rows = np.flatnonzero(found)
        at = hit[rows].argmax(axis=1)
        beams = active[rows]
        # The hit cell's column and row, recomputed rather than split from the flat index: a sample just outside the left
        # or right edge (column -1 or width) would wrap into another row. The sample before is on the grid (not a hit).
        fx, fy = floor_cells(geometry, origin, cos[beams], sin[beams], dist[at])
        hx[beams], hy[beams] = fx.astype(np.int64), fy.astype(np.int64)
        if len(crossed_at):  # a crossed cell comes before its sample's: the hit where that sample is the beam's first
            i = np.minimum(np.searchsorted(crossed_at, rows * samples + at), len(crossed_at) - 1)
            via = crossed_at[i] == rows * samples + at
            hy[beams[via]], hx[beams[via]] = np.divmod(crossed[i[via]], width)
        before_at = np.maximum(at - 1, 0)
        before_y, before_x = np.divmod(cell[rows, before_at].astype(np.int64), width)
        first_hit = at == 0  # the origin's own sample: no cell before
        if first_hit.any():
            before_y[first_hit], before_x[first_hit] = hy[beams[first_hit]], hx[beams[first_hit]]
        py[beams], px[beams] = before_y, before_x
        near_m[beams] = dist[before_at]
        far_m[beams] = dist[at]
        any_hit[beams] = True
        active = active[~found]
        if not len(active):
            break
    # Exact entry distance into the hit cell: where the beam crossed the edge (or edges) between the cell before and
    # the hit cell, so ranges do not depend on the sampling. It lies between the two samples; the clip keeps it there
    # for a beam along a cell's edge, whose rounding once gave a wall 3.6 m off for one 1.9 m off (and so none).
    res = geometry.resolution_m
    with np.errstate(divide="ignore", invalid="ignore"):
        x0, y0 = geometry.origin_x_m + hx * res, geometry.origin_y_m + hy * res  # the hit cell's low edges
        t_col = np.where(hx != px, (np.where(cos > 0, x0, x0 + res) - origin[0]) / cos, -np.inf)
        t_row = np.where(hy != py, (np.where(sin > 0, y0, y0 + res) - origin[1]) / sin, -np.inf)
        ranges = np.clip(np.maximum(t_col, t_row), near_m, far_m)
        ranges = np.where(any_hit & (ranges <= max_range_m), ranges, np.inf)
    return ranges
