"""The state s(w_t) = (M_t, D(M_t, w_t), I(M_t)) of Eq. 2, with the frontier clusters as actions."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cso_runtime.config import FrontierConfig, RobotConfig
from cso_runtime.frontiers import (
    FrontierCluster,
    FrontierComponents,
    cluster_frontiers,
    frontier_cells,
    frontier_components,
    frontier_entropy,
)
from cso_runtime.geodesic import escape_cells, geodesic_distance, traversable_cells
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.occupancy import OccupancyMap


@dataclass
class Observation:
    """What a goal selector sees at one decision. Arrays are indexed [iy, ix] on ``geometry``."""

    geometry: GridGeometry
    pose: Pose2D
    explored: np.ndarray
    occupied: np.ndarray
    traversable: np.ndarray
    distance_m: np.ndarray | None
    """D(M_t, w_t): geodesic distance from the robot, inf where unreachable. None on an Observation
    rebuilt from a decision message, which carries D only where goal selectors read it (the path
    nodes, ``known_distance_m``): ``distance_at`` reads those, ``distance_map`` computes D again."""
    frontier: np.ndarray
    """F_t as a boolean grid."""
    entropy: np.ndarray
    """I(M_t): frontier cells in the gamma x gamma window of each cell."""
    clusters: list[FrontierCluster]
    """Candidate goals (actions), sorted by distance."""
    open_area_m2: float
    """||M_t||, the explored open area."""
    path_nodes_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """Omega_t: the robot's past decision positions (oldest first), for the graph policy."""
    known_distance_m: dict[tuple[int, int], float] = field(default_factory=dict, repr=False)
    """D at single cells (iy, ix), for an Observation without ``distance_m``."""
    _extra_distance: dict = field(default_factory=dict, repr=False)

    @property
    def goal_xy_m(self) -> np.ndarray:
        """(n, 2) goal positions of the clusters."""
        if not self.clusters:
            return np.zeros((0, 2))
        return np.array([c.goal_xy_m for c in self.clusters], dtype=float)

    @property
    def goal_distance_m(self) -> np.ndarray:
        return np.array([c.distance_m for c in self.clusters], dtype=float)

    def distance_map(self) -> np.ndarray:
        """D over the whole map; computed again (one fast-marching pass, the same as ``build``'s, so
        the same values) on an Observation that travelled without it."""
        if self.distance_m is None:
            self.distance_m = geodesic_distance(self.traversable, self.geometry, self.pose.xy)
        return self.distance_m

    def distance_at(self, xy_m: np.ndarray) -> np.ndarray:
        """D at the cells of the points ``xy_m`` (n, 2): inf off the map or where unreachable. Reads
        ``known_distance_m`` when D did not travel and every cell asked for is known there."""
        pts = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        iy, ix = self.geometry.world_to_cell(pts[:, 0], pts[:, 1])
        iy, ix = np.asarray(iy, dtype=int), np.asarray(ix, dtype=int)
        inside = self.geometry.in_bounds(iy, ix)
        out = np.full(len(pts), np.inf)
        if self.distance_m is None:
            cells = list(zip(iy[inside].tolist(), ix[inside].tolist()))
            if all(c in self.known_distance_m for c in cells):
                out[inside] = [self.known_distance_m[c] for c in cells]
                return out
        out[inside] = self.distance_map()[iy[inside], ix[inside]]
        return out

    def distance_map_from(self, source_xy_m: tuple[float, float], within_m: float | None = None) -> np.ndarray:
        """Geodesic distance map from another source on the same map (cached per source and bound);
        ``within_m``: only distances below it are exact, farther cells may read inf (much cheaper)."""
        key = (distance_source_key(source_xy_m), within_m)
        if key not in self._extra_distance:
            self._extra_distance[key] = geodesic_distance(self.traversable, self.geometry, np.asarray(key[0]), within_m)
        return self._extra_distance[key]

    def goal_distances_from(self, source_xy_m: tuple[float, float], within_m: float | None = None) -> np.ndarray:
        """Geodesic distances from ``source_xy_m`` to each cluster's goal cell (exact below ``within_m``)."""
        if not self.clusters:
            return np.zeros(0)
        d = self.distance_map_from(source_xy_m, within_m)
        cells = np.array([c.goal_cell for c in self.clusters])
        return d[cells[:, 0], cells[:, 1]]


def distance_source_key(source_xy_m: tuple[float, float]) -> tuple[float, float]:
    """A source position rounded to 0.1 mm: the cache key of ``Observation.distance_map_from``, and
    the exact point fast marching starts from (so equal keys always give equal maps)."""
    return (round(float(source_xy_m[0]), 4), round(float(source_xy_m[1]), 4))


@dataclass(frozen=True)
class FrontierLayer:
    """The part of an Observation that needs no distance map: F_t (less the frontiers excluded),
    I(M_t) (Eq. 4) and F_t's 8-connected components. Independent of D, so it can be computed beside
    the fast-marching pass (a frontier service's helper process does, on another core)."""

    frontier: np.ndarray
    entropy: np.ndarray
    components: FrontierComponents


def frontier_layer(
    open_cells: np.ndarray,
    explored: np.ndarray,
    exclude_frontier: np.ndarray | None,
    entropy_window_m: float,
    resolution_m: float,
    out: tuple[np.ndarray, np.ndarray] | None = None,
) -> FrontierLayer:
    """F_t, I and F_t's components for one map (``exclude_frontier``: cells that are no actions).
    ``out``: (bool, int32) grids to write F_t and I into."""
    f_out, i_out = out if out is not None else (None, None)
    frontier = frontier_cells(open_cells, explored, f_out)
    if exclude_frontier is not None:
        frontier &= ~exclude_frontier
    entropy = frontier_entropy(frontier, entropy_window_m, resolution_m, i_out)
    return FrontierLayer(frontier, entropy, frontier_components(frontier))


def _on_cell(grid: np.ndarray, geometry: GridGeometry, pose: Pose2D) -> bool:
    """``grid`` is set at the robot's cell (False off the map)."""
    iy, ix = geometry.world_to_cell(pose.x_m, pose.y_m)
    return bool(geometry.in_bounds(iy, ix) and grid[int(iy), int(ix)])


class ObservationBuilder:
    """Turns (M_t, w_t) into an Observation: frontiers, one fast-marching pass, entropy, clusters."""

    def __init__(self, frontier: FrontierConfig | None = None, robot: RobotConfig | None = None) -> None:
        self.frontier_config = frontier or FrontierConfig()
        self.robot_config = robot or RobotConfig()

    def traversable(self, occupancy: OccupancyMap) -> np.ndarray:
        """Cells the robot's centre may occupy: open cells away from obstacles by its radius."""
        return traversable_cells(occupancy.open, occupancy.occupied, self.robot_config.radius_m, occupancy.geometry.resolution_m)

    def frontier_layer(self, occupancy: OccupancyMap, exclude_frontier: np.ndarray | None = None) -> FrontierLayer:
        return frontier_layer(occupancy.open, occupancy.explored, exclude_frontier, self.frontier_config.entropy_window_m, occupancy.geometry.resolution_m)

    def build(
        self,
        occupancy: OccupancyMap,
        pose: Pose2D,
        path_nodes_xy_m: np.ndarray | None = None,
        exclude_frontier: np.ndarray | None = None,
        layer: Callable[[], FrontierLayer] | None = None,
    ) -> Observation:
        """``exclude_frontier`` marks frontier cells known to be unclearable (they are not actions).
        ``layer``: gives ``frontier_layer(occupancy, exclude_frontier)`` computed elsewhere meanwhile
        (called once D is done); by default it is computed here."""
        g = occupancy.geometry
        traversable = self.traversable(occupancy)
        distance = geodesic_distance(traversable, g, pose.xy)
        fl = layer() if layer is not None else self.frontier_layer(occupancy, exclude_frontier)
        frontier, entropy = fl.frontier, fl.entropy
        min_size_m = self.frontier_config.min_cluster_size_m
        clusters = cluster_frontiers(frontier, distance, entropy, g, min_size_m, fl.components)
        if not clusters and frontier.any() and not _on_cell(traversable, g, pose):
            # Inside the inflated obstacles, nothing may be reachable but the robot's own few cells: let it
            # move out through the open cells its body covers. Only then, so that a robot which reaches a
            # frontier anyway decides on the same D as before.
            traversable = traversable | escape_cells(occupancy.open, g, pose.xy, self.robot_config.radius_m)
            distance = geodesic_distance(traversable, g, pose.xy)
            clusters = cluster_frontiers(frontier, distance, entropy, g, min_size_m, fl.components)
        nodes = np.zeros((0, 2)) if path_nodes_xy_m is None else np.asarray(path_nodes_xy_m, dtype=float).reshape(-1, 2)
        return Observation(
            geometry=g,
            pose=pose,
            explored=occupancy.explored.copy(),
            occupied=occupancy.occupied.copy(),
            traversable=traversable,
            distance_m=distance,
            frontier=frontier,
            entropy=entropy,
            clusters=clusters,
            open_area_m2=occupancy.open_area_m2(),
            path_nodes_xy_m=nodes,
        )
