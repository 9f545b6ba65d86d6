"""Occupancy map M_t (section 3.2): an explored channel and an occupied channel in a metric frame."""

from __future__ import annotations

import math

import numpy as np

from cso_runtime.config import ExplorationConfig
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, no_return_mask
from cso_runtime.raycast import SAMPLES_PER_CHUNK, sample_cells, sample_step_m, samples_to_reach

UNKNOWN, FREE, OCCUPIED = -1, 0, 100
"""nav_msgs/OccupancyGrid cell values."""

LOG_ODDS_HIT = 0.9
LOG_ODDS_MISS = -0.4
LOG_ODDS_MIN, LOG_ODDS_MAX = -2.0, 3.5


class OccupancyMap:
    """Two-channel occupancy map built from range scans.

    ``explored`` only ever grows (a cell once seen is never unknown again). ``occupied`` follows a
    clamped log-odds of hits and pass-throughs, so a noisy return is corrected by later scans.
    """

    def __init__(self, geometry: GridGeometry) -> None:
        self.geometry = geometry
        self.explored = np.zeros(geometry.shape, dtype=bool)
        self._log_odds: np.ndarray | None = np.zeros(geometry.shape, dtype=np.float32)
        self.occupied = np.zeros(geometry.shape, dtype=bool)

    @property
    def log_odds(self) -> np.ndarray:
        """Clamped log-odds of occupancy per cell. A map rebuilt from an OccupancyGrid starts each cell
        at one hit or one miss; that array is only made when a scan is integrated into such a map
        (the runtime's readers of the map never need it)."""
        if self._log_odds is None:
            lo = np.zeros(self.geometry.shape, dtype=np.float32)
            lo[self.explored] = LOG_ODDS_MISS
            lo[self.occupied] = LOG_ODDS_HIT
            self._log_odds = lo
        return self._log_odds

    @log_odds.setter
    def log_odds(self, value: np.ndarray) -> None:
        self._log_odds = value

    @property
    def open(self) -> np.ndarray:
        """Explored and not occupied ("open" cells of the paper)."""
        return self.explored & ~self.occupied

    @property
    def unknown(self) -> np.ndarray:
        return ~self.explored

    def open_area_m2(self) -> float:
        """||M_t||: the area of open space, the quantity rewarded by Eq. 6."""
        return float(np.count_nonzero(self.open)) * self.geometry.cell_area_m2

    def integrate_scan(self, sensor_pose: Pose2D, scan: LaserScan) -> int:
        """Ray-cast one scan taken at ``sensor_pose`` into the map; returns newly explored cells.

        Beams with no return (``inf``, ``range_max_m`` or beyond: ``no_return_mask``) clear free space up to the
        max range and mark no obstacle;
        readings below ``range_min_m`` are ignored, and so is a range of 0 m even when ``range_min_m`` is 0
        (the ROS bridge's mark for NaN and too-close readings: never an obstacle at the sensor). Raises
        ValueError on NaN or malformed scans and on a sensor pose that is not finite (then changes nothing).
        """
        scan.validate()
        if not all(math.isfinite(v) for v in (sensor_pose.x_m, sensor_pose.y_m, sensor_pose.yaw_rad)):
            raise ValueError(f"scan's sensor pose is not finite: {sensor_pose}")
        ranges = np.asarray(scan.ranges_m, dtype=float)
        angles = scan.angles_rad + sensor_pose.yaw_rad
        usable = (ranges >= scan.range_min_m) & (ranges > 0.0)
        is_hit = usable & ~no_return_mask(ranges, scan.range_max_m)
        clear_len = np.where(is_hit, ranges, scan.range_max_m)
        angles, clear_len, is_hit = angles[usable], clear_len[usable], is_hit[usable]
        if len(angles) == 0:
            return 0
        origin = np.array([sensor_pose.x_m, sensor_pose.y_m])
        cos, sin = np.cos(angles), np.sin(angles)
        free_until = clear_len - 1e-9  # samples strictly before a beam's end are pass-throughs
        n = samples_to_reach(self.geometry, float(np.max(clear_len)))
        step_m = sample_step_m(self.geometry)
        free_cells = []
        for first in range(0, n, SAMPLES_PER_CHUNK):
            active = np.flatnonzero(free_until > first * step_m)
            if not len(active):
                break
            cell, inside, dist = sample_cells(self.geometry, origin, cos[active], sin[active], first, min(first + SAMPLES_PER_CHUNK, n))
            inside &= dist[None, :] < free_until[active, None]
            free_cells.append(cell[inside])
        hit_xy = origin[None, :] + (clear_len[is_hit] + 1e-6)[:, None] * np.stack(
            [np.cos(angles[is_hit]), np.sin(angles[is_hit])], axis=1
        )
        hy, hx = self.geometry.world_to_cell(hit_xy[:, 0], hit_xy[:, 1])
        keep = self.geometry.in_bounds(hy, hx)
        width = self.geometry.shape[1]
        free = np.concatenate(free_cells).astype(np.intp) if free_cells else np.zeros(0, np.intp)
        hit = hy[keep] * width + hx[keep]
        if not len(free) and not len(hit):
            return 0
        # Only the rows of the grid the scan touched are read or written (flat, contiguous): a scan
        # reaches a few metres, a large plan is tens of metres tall.
        touched = [a for a in (free, hit) if len(a)]
        first_row = int(min(a.min() for a in touched)) // width
        last_row = int(max(a.max() for a in touched)) // width
        rows = slice(first_row, last_row + 1)
        explored, log_odds, occupied = self.explored[rows], self.log_odds[rows], self.occupied[rows]
        offset = first_row * width
        touched_free: np.ndarray = np.zeros(explored.size, dtype=bool)
        touched_free[free - offset] = True
        touched_hit: np.ndarray = np.zeros(explored.size, dtype=bool)
        touched_hit[hit - offset] = True
        touched_free = touched_free.reshape(explored.shape)
        touched_hit = touched_hit.reshape(explored.shape)
        touched_free &= ~touched_hit
        newly = np.count_nonzero((touched_free | touched_hit) & ~explored)
        log_odds[touched_free] = np.maximum(log_odds[touched_free] + LOG_ODDS_MISS, LOG_ODDS_MIN)
        log_odds[touched_hit] = np.minimum(log_odds[touched_hit] + LOG_ODDS_HIT, LOG_ODDS_MAX)
        changed = touched_free | touched_hit
        occupied[changed] = log_odds[changed] > 0.0
        explored |= changed
        return int(newly)

    def mark_footprint_free(self, robot_pose: Pose2D, length_m: float, width_m: float) -> int:
        """Mark the unknown cells whose centres lie under the robot's rectangular body (centred on
        ``robot_pose``, ``length_m`` along its heading) as free; returns how many. Cells already seen,
        free or occupied, keep what the scans said of them."""
        iy, ix = self.geometry.cells_in_rectangle(robot_pose, length_m, width_m)
        unseen = ~self.explored[iy, ix]
        cy, cx = iy[unseen], ix[unseen]
        self.log_odds[cy, cx] = LOG_ODDS_MISS
        self.occupied[cy, cx] = False
        self.explored[cy, cx] = True
        return len(cy)

    def to_occupancy_grid(self) -> np.ndarray:
        """int8 grid with ROS values: -1 unknown, 0 free, 100 occupied (row 0 at the origin)."""
        grid = np.full(self.geometry.shape, UNKNOWN, dtype=np.int8)
        grid[self.explored] = FREE
        grid[self.explored & self.occupied] = OCCUPIED
        return grid

    @classmethod
    def from_occupancy_grid(cls, grid: np.ndarray, geometry: GridGeometry) -> OccupancyMap:
        """Inverse of ``to_occupancy_grid`` (values above 50 are occupied, ROS convention)."""
        grid = np.asarray(grid)
        if grid.shape != tuple(geometry.shape):
            raise ValueError(f"grid shape {grid.shape} does not match geometry {geometry.shape}")
        return cls.from_masks(grid >= 0, grid > 50, geometry)

    @classmethod
    def from_masks(cls, explored: np.ndarray, occupied: np.ndarray, geometry: GridGeometry) -> OccupancyMap:
        """A map with these two channels (as received: the arrays are kept, not copied)."""
        if explored.shape != tuple(geometry.shape) or occupied.shape != tuple(geometry.shape):
            raise ValueError(f"channel shapes {explored.shape}, {occupied.shape} do not match geometry {geometry.shape}")
        m = cls.__new__(cls)
        m.geometry = geometry
        m.explored = explored
        m.occupied = occupied
        m._log_odds = None
        return m

    def copy(self) -> OccupancyMap:
        m = OccupancyMap(self.geometry)
        m.explored = self.explored.copy()
        m.log_odds = self.log_odds.copy()
        m.occupied = self.occupied.copy()
        return m


def open_on_border(explored: np.ndarray, occupied: np.ndarray) -> bool:
    """Whether an open cell (explored, not occupied) lies on the grid's outermost rows or columns: a beam went on
    past it, so the space beyond, which the grid cannot hold, is open and unexplored. A map bounded by walls (a
    simulated plan, a room inside the arena) has none."""
    edges = [(explored[i], occupied[i]) for i in (0, -1)] + [(explored[:, j], occupied[:, j]) for j in (0, -1)]
    return any(bool(np.any(e & ~o)) for e, o in edges)


def integrate_observation(occupancy: OccupancyMap, sensor_pose: Pose2D, scan: LaserScan, config: ExplorationConfig) -> int:
    """One scan into the map, then (``mapping.footprint_clearing``) the robot's own footprint: what the
    in-process Explorer and the mapper service both do with a scan. The robot's centre is the sensor pose
    less ``sensor.mount_x_m``. Returns newly explored cells; raises ValueError on a malformed scan (and
    then changes nothing)."""
    newly = occupancy.integrate_scan(sensor_pose, scan)
    if config.mapping.footprint_clearing:
        robot = config.robot
        newly += occupancy.mark_footprint_free(sensor_pose.compose_offset(-config.sensor.mount_x_m), robot.length_m, robot.width_m)
    return newly
