"""Frontiers F_t, frontier clusters, and the frontier-based entropy I(M_t) of Eq. 4."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cso_runtime.geometry import GridGeometry

_EIGHT = np.ones((3, 3), dtype=bool)


def frontier_cells(open_cells: np.ndarray, explored: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Open cells with at least one 4-connected unknown neighbour (cells outside the map are not unknown).
    ``out``: a boolean grid to write them into (returned)."""
    unknown = ~explored
    near_unknown = np.zeros_like(unknown)
    near_unknown[1:, :] |= unknown[:-1, :]
    near_unknown[:-1, :] |= unknown[1:, :]
    near_unknown[:, 1:] |= unknown[:, :-1]
    near_unknown[:, :-1] |= unknown[:, 1:]
    return np.logical_and(open_cells, near_unknown, out=out)


def frontier_entropy(frontier: np.ndarray, window_m: float, resolution_m: float, out: np.ndarray | None = None) -> np.ndarray:
    """I_{x,y}: number of frontier cells in the gamma x gamma window centred on each cell (Eq. 4).

    Computed for the whole map at once with a summed-area table. The window is centred, so its side is
    an odd number of cells: gamma / resolution rounded to whole cells, plus one when that is even (2 m
    at 0.05 m cells: 41 cells). A window wider than twice the map counts every cell of it wherever it is centred, as
    one of that width does: it is computed at that width (a 1 km window at 0.05 m would pad the map by 10,000 cells).
    ``out``: an int32 grid to write I into (returned).
    """
    ny, nx = frontier.shape
    half = min(max(1, int(round(window_m / resolution_m))) // 2, max(ny, nx))
    k = 2 * half + 1
    sat = np.zeros((ny + k, nx + k), dtype=np.int32)
    padded = np.pad(frontier, half).astype(np.int32)
    np.cumsum(np.cumsum(padded, axis=0, out=padded), axis=1, out=sat[1:, 1:])
    out = np.subtract(sat[k:, k:], sat[:-k, k:][:ny], out=out)
    out -= sat[k:, :-k][:, :nx]
    out += sat[:ny, :nx]
    return out


@dataclass(frozen=True)
class FrontierCluster:
    """A connected group of frontier cells: one candidate long-term goal (one action)."""

    cluster_id: int
    cells: np.ndarray
    """(k, 2) array of (iy, ix) cell indices."""
    goal_cell: tuple[int, int]
    """The reachable cell of the cluster nearest to the robot: where the robot is sent."""
    goal_xy_m: tuple[float, float]
    distance_m: float
    """Geodesic distance from the robot to ``goal_cell``."""
    size_m: float
    """Frontier length: number of cells times the resolution (explore_lite's ``size``)."""
    entropy: float
    """Frontier-based entropy I at ``goal_cell``."""
    centroid_xy_m: tuple[float, float]


FrontierComponents = tuple[np.ndarray, np.ndarray, np.ndarray]
"""F_t's 8-connected components as (iy, ix, splits): every frontier cell's indices, grouped by
component (in label order, cells in row-major order within one), and where each next group starts."""


def frontier_components(frontier: np.ndarray) -> FrontierComponents:
    """F_t's 8-connected components (``FrontierComponents``): what clustering needs before D."""
    from scipy import ndimage  # noqa: PLC0415  (0.3 s of imports: every CLI command reads messages, which reads this module)

    labels, count = ndimage.label(frontier, structure=_EIGHT)
    if count == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty, empty
    # The frontier cells in row-major order, as np.nonzero(labels) gives them, but found on the flat
    # boolean grid: numpy's nonzero over a 2D array is about ten times slower than over a flat one.
    cells = np.flatnonzero(frontier)
    lab = labels.ravel()[cells]
    iy, ix = np.divmod(cells, frontier.shape[1])
    order = np.argsort(lab, kind="stable")
    iy, ix, lab = iy[order], ix[order], lab[order]
    return iy, ix, np.flatnonzero(np.diff(lab)) + 1


def cluster_frontiers(
    frontier: np.ndarray,
    distance_m: np.ndarray,
    entropy: np.ndarray,
    geometry: GridGeometry,
    min_cluster_size_m: float,
    components: FrontierComponents | None = None,
) -> list[FrontierCluster]:
    """Group frontier cells into 8-connected clusters and describe the reachable ones.

    Clusters shorter than ``min_cluster_size_m`` and clusters with no reachable cell are dropped.
    The result is sorted by distance, then position, so it is deterministic. ``components``: what
    ``frontier_components`` gives for ``frontier``, when already known.
    """
    iy, ix, splits = components if components is not None else frontier_components(frontier)
    if len(iy) == 0:
        return []
    min_cells = max(1, int(np.ceil(min_cluster_size_m / geometry.resolution_m - 1e-9)))
    res = geometry.resolution_m
    clusters: list[FrontierCluster] = []
    for cy, cx in zip(np.split(iy, splits), np.split(ix, splits)):
        if len(cy) < min_cells:
            continue
        d = distance_m[cy, cx]
        best = int(np.argmin(d))
        if not np.isfinite(d[best]):
            continue
        gy, gx = int(cy[best]), int(cx[best])
        gxm, gym = geometry.cell_to_world(gy, gx)
        mx, my = geometry.cell_to_world(cy.mean(), cx.mean())
        clusters.append(
            FrontierCluster(
                cluster_id=0,
                cells=np.stack([cy, cx], axis=1),
                goal_cell=(gy, gx),
                goal_xy_m=(float(gxm), float(gym)),
                distance_m=float(d[best]),
                size_m=len(cy) * res,
                entropy=float(entropy[gy, gx]),
                centroid_xy_m=(float(mx), float(my)),
            )
        )
    clusters.sort(key=lambda c: (c.distance_m, c.goal_cell))
    return [
        FrontierCluster(i, c.cells, c.goal_cell, c.goal_xy_m, c.distance_m, c.size_m, c.entropy, c.centroid_xy_m)
        for i, c in enumerate(clusters)
    ]
