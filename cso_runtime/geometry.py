"""Metric types shared by every module: poses, grid geometry, scans and velocity commands.

Conventions follow ROS (REP-103): x forward/east, y left/north, yaw counter-clockwise in radians,
metres everywhere. Grids are indexed ``[iy, ix]`` with row 0 at the map origin (the bottom edge),
exactly like ``nav_msgs/OccupancyGrid`` data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt


def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi) (NaN stays NaN)."""
    wrapped = (angle_rad + math.pi) % (2.0 * math.pi) - math.pi
    # The float just below -pi gives (-ulp) % 2 pi, which rounds to 2 pi itself, and so +pi: outside the range.
    return -math.pi if wrapped >= math.pi else wrapped


@dataclass(frozen=True)
class Pose2D:
    """Planar pose in the map frame: position in metres, heading in radians."""

    x_m: float
    y_m: float
    yaw_rad: float

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m], dtype=float)

    def as_list(self) -> list[float]:
        """``[x_m, y_m, yaw_rad]``: how messages and JSON files carry a pose."""
        return [float(self.x_m), float(self.y_m), float(self.yaw_rad)]

    def compose_offset(self, forward_m: float, left_m: float = 0.0) -> Pose2D:
        """Pose of a frame mounted at (forward_m, left_m) in this pose's body frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return Pose2D(self.x_m + c * forward_m - s * left_m, self.y_m + s * forward_m + c * left_m, self.yaw_rad)


@dataclass(frozen=True)
class VelocityCommand:
    """Body-frame twist: linear speed in m/s, angular speed in rad/s (like geometry_msgs/Twist)."""

    linear_mps: float = 0.0
    angular_radps: float = 0.0

    def clamped(self, max_linear_mps: float, max_angular_radps: float) -> VelocityCommand:
        """Within the limits; a NaN component (a command computed from a bad input) becomes 0, a stop."""
        v = 0.0 if math.isnan(self.linear_mps) else float(np.clip(self.linear_mps, -max_linear_mps, max_linear_mps))
        w = 0.0 if math.isnan(self.angular_radps) else float(np.clip(self.angular_radps, -max_angular_radps, max_angular_radps))
        return VelocityCommand(v, w)


MAP_FRAME_ORIGIN = Pose2D(0.0, 0.0, 0.0)
"""The map-frame pose of a plan's frame that is the map frame itself: Dungeon, generated and builtin plans, and a
real robot's map (``FloorPlan.map_origin``; a map_server scene's is its YAML's ``origin``)."""

WRITTEN_DECIMALS = 9
"""A pose or time computed by float arithmetic (a grid's corner placed by a map origin, a LiDAR mount read off two
poses, a period read off two stamps) is rounded to the nanometre, nanoradian or nanosecond where it is written out
for people and other tools (``rounded``): ``-5.275``, as map_saver_cli writes it, not the float sum's
``-5.2749999999999995``; so is every float of the commands' JSON (``scenes --json``, ``status --json``:
``rounded_floats``)."""


UNTURNED_YAW_TOLERANCE_RAD = 10.0**-WRITTEN_DECIMALS
"""A map origin's yaw within +- this (1e-9 rad: the nanoradian to which origins are written, ``rounded``) is no turn,
read as 0; a larger one turns the grid (map_server's counterclockwise turn of a map by its YAML ``origin``'s yaw, sent
in an OccupancyGrid's ``info.origin.orientation``), which a ``GridGeometry``, axis-aligned, cannot hold: readers that
give one refuse such a map (``map_files.load_map``, ``ros2_cdr.occupancy_grid_from_cdr``) and name the reader that
gives the grid in its own frame with the turn beside it. A 1 km grid turned by it moves no cell by more than 1 um."""


def rounded(value: float) -> float:
    """``value`` rounded to ``WRITTEN_DECIMALS`` (a value that has no more decimals stays itself, to the bit); never
    ``-0.0``."""
    return round(float(value), WRITTEN_DECIMALS) + 0.0  # + 0.0: no -0.0


def rounded_floats(data: Any) -> Any:
    """``data`` (JSON's mappings, lists, numbers, text) with each float ``rounded``: what ``scenes --json`` and
    ``status --json`` print, ``4.725`` m, not the float sum's ``4.7250000000000005`` (every unit alike: nothing a
    script compares or a reader reads is lost at ``WRITTEN_DECIMALS``). Ints, bools, text and None are left as they
    are; a float with no value (NaN, inf) too."""
    if isinstance(data, dict):
        return {key: rounded_floats(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [rounded_floats(value) for value in data]
    if isinstance(data, float) and math.isfinite(data):
        return rounded(data)
    return data


def rounded_pose(pose: Pose2D) -> Pose2D:
    """``pose`` with each of x, y and yaw ``rounded``: the one rounding of a map's origin in a map_server YAML
    (``map_files.save_map``) and in an OccupancyGrid's ``info.origin`` (``ros2_cdr.occupancy_grid_to_cdr``)."""
    return Pose2D(rounded(pose.x_m), rounded(pose.y_m), rounded(pose.yaw_rad))


def relative_pose(a: Pose2D, b: Pose2D) -> tuple[float, float, float]:
    """Pose of b in a's frame: (dx_m forward, dy_m left, dyaw_rad)."""
    c, s = math.cos(a.yaw_rad), math.sin(a.yaw_rad)
    dx, dy = b.x_m - a.x_m, b.y_m - a.y_m
    return c * dx + s * dy, -s * dx + c * dy, wrap_angle_rad(b.yaw_rad - a.yaw_rad)


def compose_pose(frame: Pose2D, pose: Pose2D) -> Pose2D:
    """``pose``, given in ``frame``'s own axes, in the frame ``frame`` is given in (the inverse of
    ``relative_pose``): a pose in a map's grid frame placed in its map frame by the grid's origin."""
    c, s = math.cos(frame.yaw_rad), math.sin(frame.yaw_rad)
    return Pose2D(frame.x_m + c * pose.x_m - s * pose.y_m, frame.y_m + s * pose.x_m + c * pose.y_m, wrap_angle_rad(frame.yaw_rad + pose.yaw_rad))


def compose_xy(frame: Pose2D, xy_m: npt.ArrayLike) -> np.ndarray:
    """Points (n x 2 metres) given in ``frame``'s own axes, in the frame ``frame`` is given in: ``compose_pose`` of
    each point (a path or frontier cells of a scene's own frame in the user's map frame)."""
    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    c, s = math.cos(frame.yaw_rad), math.sin(frame.yaw_rad)
    return np.column_stack([frame.x_m + c * xy[:, 0] - s * xy[:, 1], frame.y_m + s * xy[:, 0] + c * xy[:, 1]])


def map_frame_pose(map_origin: Pose2D, pose: Pose2D | None) -> Pose2D | None:
    """The robot's ``pose`` of a scene's own frame (its odometry) in the user's map frame (``map_origin``, as
    ``map_frame_xy``): what ``status`` and ``up``'s live view show of it; None for none (before the first odometry)."""
    return None if pose is None else compose_pose(map_origin, pose)


def map_frame_xy(map_origin: Pose2D, xy_m: Sequence[float]) -> list[float]:
    """A point ``[x_m, y_m]`` of a scene's own frame in the user's map frame (``map_origin``: the scene's pose there,
    ``FloorPlan.map_origin``): what ``status`` and ``up``'s live view show of a goal."""
    p = compose_pose(map_origin, Pose2D(float(xy_m[0]), float(xy_m[1]), 0.0))
    return [p.x_m, p.y_m]


def mean_twist(before: Pose2D, after: Pose2D, dt_s: float) -> VelocityCommand:
    """The body-frame twist (forward speed, yaw rate) that takes ``before`` to ``after`` in ``dt_s`` on average,
    as an odometry node that differentiates its poses reports it."""
    dx_m, _, dyaw_rad = relative_pose(before, after)
    return VelocityCommand(dx_m / dt_s, dyaw_rad / dt_s)


@dataclass(frozen=True)
class GridGeometry:
    """Where a grid lies in the map frame: cell size and the metric position of cell (0, 0)'s corner."""

    resolution_m: float
    shape: tuple[int, int]  # (ny, nx)
    origin_x_m: float = 0.0
    origin_y_m: float = 0.0

    @property
    def cell_area_m2(self) -> float:
        return self.resolution_m * self.resolution_m

    @property
    def width_m(self) -> float:
        return self.shape[1] * self.resolution_m

    @property
    def height_m(self) -> float:
        return self.shape[0] * self.resolution_m

    def describe(self) -> str:
        """``nx x ny grid of R m at (x, y)``: what a rejection of a map on another grid says of each grid."""
        return f"{self.shape[1]} x {self.shape[0]} grid of {self.resolution_m} m at ({self.origin_x_m}, {self.origin_y_m})"

    def corner_pose(self, frame: Pose2D | None = None) -> Pose2D:
        """The pose of cell (0, 0)'s corner, rows along x, in the frame that ``frame`` is given in, this grid lying in
        ``frame`` (a scene's own frame, placed in the user's map frame by its ``map_origin``; None: the grid's own
        frame): a map_server YAML's ``origin`` and an OccupancyGrid's ``info.origin``, a yaw turning the grid."""
        corner = Pose2D(float(self.origin_x_m), float(self.origin_y_m), 0.0)
        return corner if frame is None else compose_pose(frame, corner)

    def world_to_cell(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices (iy, ix) of metric points (arrays, or numpy scalars for scalars); may lie outside the grid
        (see ``in_bounds``)."""
        ix = np.floor((np.asarray(x_m) - self.origin_x_m) / self.resolution_m).astype(np.int64)
        iy = np.floor((np.asarray(y_m) - self.origin_y_m) / self.resolution_m).astype(np.int64)
        return iy, ix

    def cell_to_world(self, iy: npt.ArrayLike, ix: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Metric centres (x_m, y_m) of cells (arrays, or numpy scalars for scalars)."""
        x = self.origin_x_m + (np.asarray(ix) + 0.5) * self.resolution_m
        y = self.origin_y_m + (np.asarray(iy) + 0.5) * self.resolution_m
        return x, y

    def in_bounds(self, iy: npt.ArrayLike, ix: npt.ArrayLike) -> np.ndarray:
        """Which cell indices lie on the grid (``world_to_cell`` gives indices off it for points outside)."""
        return (np.asarray(iy) >= 0) & (np.asarray(iy) < self.shape[0]) & (np.asarray(ix) >= 0) & (np.asarray(ix) < self.shape[1])

    def cells_in_rectangle(self, centre: Pose2D, length_m: float, width_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Cells (iy, ix) of the grid whose centres lie in the rectangle ``length_m`` along ``centre``'s
        heading by ``width_m`` across it, centred on ``centre`` (the robot's body, or a strip of it)."""
        reach_m = 0.5 * math.hypot(length_m, width_m)
        low_iy, low_ix = map(int, self.world_to_cell(centre.x_m - reach_m, centre.y_m - reach_m))
        high_iy, high_ix = map(int, self.world_to_cell(centre.x_m + reach_m, centre.y_m + reach_m))
        iy0, ix0 = max(low_iy, 0), max(low_ix, 0)
        iy1, ix1 = min(high_iy, self.shape[0] - 1), min(high_ix, self.shape[1] - 1)
        if iy1 < iy0 or ix1 < ix0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        iy, ix = np.mgrid[iy0 : iy1 + 1, ix0 : ix1 + 1]
        x_m, y_m = self.cell_to_world(iy, ix)
        c, s = math.cos(centre.yaw_rad), math.sin(centre.yaw_rad)
        dx, dy = x_m - centre.x_m, y_m - centre.y_m
        inside = (np.abs(c * dx + s * dy) <= 0.5 * length_m) & (np.abs(-s * dx + c * dy) <= 0.5 * width_m)
        return iy[inside], ix[inside]

    def _cells_around(self, x_m: float, y_m: float, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Every cell (iy, ix) of the square of cells reaching ``reach_m`` round (x, y), on the grid or off it."""
        low_iy, low_ix = map(int, self.world_to_cell(x_m - reach_m, y_m - reach_m))
        high_iy, high_ix = map(int, self.world_to_cell(x_m + reach_m, y_m + reach_m))
        iy, ix = np.mgrid[low_iy : high_iy + 1, low_ix : high_ix + 1]
        return iy.ravel(), ix.ravel()

    def cell_gap_m(self, iy: npt.ArrayLike, ix: npt.ArrayLike, x_m: float, y_m: float) -> np.ndarray:
        """The distance from (x, y) to the nearest point of each cell (0 inside it)."""
        x0 = self.origin_x_m + np.asarray(ix) * self.resolution_m
        y0 = self.origin_y_m + np.asarray(iy) * self.resolution_m
        dx = np.maximum(np.maximum(x0 - x_m, 0.0), x_m - (x0 + self.resolution_m))
        dy = np.maximum(np.maximum(y0 - y_m, 0.0), y_m - (y0 + self.resolution_m))
        return np.hypot(dx, dy)

    def cells_overlapping_rectangle(self, centre: Pose2D, length_m: float, width_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Cells (iy, ix) whose squares share some area with the rectangle of ``cells_in_rectangle`` (a cell that
        straddles its edge too, not only one whose centre lies inside), on the grid or off it (``in_bounds``): the
        conservative rasterisation, for a check that must miss no obstacle. Exact (separating axes: the cells' and
        the rectangle's); a cell that only touches the rectangle's edge does not count."""
        half = 0.5 * self.resolution_m
        iy, ix = self._cells_around(centre.x_m, centre.y_m, 0.5 * math.hypot(length_m, width_m) + half)
        x_m, y_m = self.cell_to_world(iy, ix)
        c, s = math.cos(centre.yaw_rad), math.sin(centre.yaw_rad)
        dx, dy = x_m - centre.x_m, y_m - centre.y_m
        cell_along = half * (abs(c) + abs(s))  # a cell's half extent along either of the rectangle's axes
        apart = (np.abs(c * dx + s * dy) >= 0.5 * length_m + cell_along) | (np.abs(-s * dx + c * dy) >= 0.5 * width_m + cell_along)
        box_x = 0.5 * (length_m * abs(c) + width_m * abs(s))  # the rectangle's half extents along the grid's axes
        box_y = 0.5 * (length_m * abs(s) + width_m * abs(c))
        apart |= (np.abs(dx) >= box_x + half) | (np.abs(dy) >= box_y + half)
        return iy[~apart], ix[~apart]

    def cells_overlapping_disc(self, x_m: float, y_m: float, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Cells (iy, ix) whose squares share some area with the disc of ``radius_m`` round (x, y), on the grid or off
        it (``in_bounds``); a cell that only touches its edge does not count."""
        iy, ix = self._cells_around(x_m, y_m, radius_m)
        inside = self.cell_gap_m(iy, ix, x_m, y_m) < radius_m
        return iy[inside], ix[inside]


MAX_RANGE_M = 1000.0
"""The longest ``range_max_m`` a scan may have: the mapper marches every no-return beam out to it, so a range_max of
1e12 m (finite, so not refused as inf) held the mapper for hours. A planar LiDAR reaches tens of metres."""


def no_return_mask(ranges_m: npt.ArrayLike, range_max_m: float) -> np.ndarray:
    """Beams that saw nothing (REP-117): ``inf``, or a reading of ``range_max_m`` or more, since drivers such as the
    LIMO's report "nothing" as ``range_max`` itself. Not an obstacle: free space up to ``range_max_m``. NaN is not
    one (it is no reading at all). Compared in float64, as the mapper compares."""
    return np.asarray(ranges_m, dtype=np.float64) >= range_max_m


def returns_as_float32(ranges_m: np.ndarray, range_max_m: float) -> np.ndarray:
    """A simulated scan's ranges as a ``LaserScan`` carries them (float32), every return still a return: a range
    within ``range_max_m`` that float32 rounds up to ``range_max_m`` itself would read as no return
    (``no_return_mask``), so it becomes the float32 just below. ``inf`` stays ``inf``. Up to a 16 m ``range_max_m`` the
    float32 below lies within the mapper's 1e-6 m step into the hit cell, so the map marks the same wall cell."""
    ranges32 = np.asarray(ranges_m).astype(np.float32)
    rounded_to_max = np.isfinite(ranges_m) & (ranges32.astype(np.float64) == range_max_m)
    ranges32[rounded_to_max] = np.nextafter(np.float32(range_max_m), np.float32(0.0))
    return ranges32


@dataclass(frozen=True)
class LaserScan:
    """One planar range scan, as in sensor_msgs/LaserScan.

    ``ranges_m[i]`` is the range of the beam at ``angle_min_rad + i * angle_increment_rad`` in the
    sensor frame; ``inf``, ``range_max_m`` or more mean no return (``no_return_mask``). Readings below
    ``range_min_m``, and 0 m readings (how the ROS bridge marks NaN and too-close beams), are invalid and
    ignored by the mapper.
    """

    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    ranges_m: np.ndarray
    stamp_s: float = 0.0

    @property
    def angles_rad(self) -> np.ndarray:
        return self.angle_min_rad + self.angle_increment_rad * np.arange(len(self.ranges_m))

    def validate(self) -> None:
        """Raise ValueError for a scan that cannot be integrated (NaN, bad limits, beams whose angles do not
        increase), never another exception: the mapper service counts a ValueError as a rejected scan."""
        r = np.asarray(self.ranges_m)
        if r.ndim != 1 or r.size == 0:
            raise ValueError("scan ranges must be a non-empty 1-D array")
        if r.dtype.kind not in "fiu":
            raise ValueError(f"scan ranges must be numbers, not {r.dtype}")
        if np.isnan(r).any():
            raise ValueError(f"scan has {int(np.isnan(r).sum())} NaN ranges")
        if (r < 0).any():
            raise ValueError("scan has negative ranges")
        for name in ("angle_min_rad", "angle_increment_rad", "range_min_m", "range_max_m"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
                raise ValueError(f"scan {name} is not finite: {value!r}")
        if r.size > 1 and not self.angle_increment_rad > 0.0:
            # All beams along one line (0), or listed clockwise (< 0: the ROS bridge reverses such a scan).
            raise ValueError(f"scan angle_increment_rad must be positive for {r.size} beams, got {self.angle_increment_rad}")
        if not 0.0 <= self.range_min_m < self.range_max_m:
            raise ValueError("scan needs 0 <= range_min_m < range_max_m")
        if self.range_max_m > MAX_RANGE_M:
            raise ValueError(f"scan range_max_m {self.range_max_m} is above {MAX_RANGE_M:g} m")
