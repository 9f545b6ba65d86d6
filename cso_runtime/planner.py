"""Local planner: a path on the inflated map and a pure-pursuit follower that drives it safely.

Split like Nav2: ``plan_path`` is the planner server (path by descending the fast-marching distance
field), ``PathFollower`` the controller (pure pursuit with rotate-in-place and an obstacle slow-down),
``ProgressChecker`` Nav2's progress checker, ``StallRecovery`` its BackUp behaviour, ``ProgressRecovery`` the
recovery its navigator runs before giving a goal up. ``LocalPlanner`` ties them and reports a status the
policy can act on: ``following``, ``reached``, ``blocked`` (no path) or ``no_progress``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from cso_runtime.config import ExplorationConfig, PlannerConfig, RobotConfig
from cso_runtime.geodesic import disk_cells, disk_offsets, geodesic_distance, inflate
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, VelocityCommand, no_return_mask, wrap_angle_rad

FACE_GOAL_MIN_DISTANCE_M = 0.05
"""A goal closer than this to the robot is under it: no heading looks at it, so it is not turned to."""
FACE_GOAL_VIEW_FRACTION = 0.75
"""A goal counts as in view once within this fraction of the half field of view (not at its very edge)."""

STALL_ACHIEVED_FRACTION = 0.25
"""A control period that moved the robot less than this fraction of the translation (along its heading,
``driven_along_heading_m``) and of the rotation its command asked for counts as stalled."""
STALL_MIN_ASKED_M = 0.01
STALL_MIN_ASKED_RAD = 0.05
"""Commands that ask less than these in a period (a stop, a creep) are never called stalled."""

_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


MIN_DRIVE_MPS = 0.05
"""``PathFollower.min_speed_mps`` on a robot whose top speed is at least four times this."""
CREEP_BACK_MPS = 0.2
"""The blocked-ahead back-off's speed (at most the robot's top speed)."""

REVERSE_LOOKAHEAD_M = 0.1
"""The least distance behind the robot checked before a reverse command (a period's travel is 4-5 cm)."""

PURSUIT_MAX_HEADING_ERROR_RAD = 0.5 * math.pi
"""Pure pursuit never drives towards a lookahead point more than this off the heading, whatever
``planner.rotate_in_place_rad`` (its bounds reach pi): the arc to a point behind the robot starts forward, away from
it, and at pi it is a straight line away at full speed. The robot turns in place instead."""

ESCAPE_HEADING_STEP_RAD = math.radians(5.0)
"""The progress recovery's candidate headings are this far apart."""
ESCAPE_UNSEEN_MARGIN_RAD = math.radians(45.0)
"""With a sensor narrower than 360 degrees, the recovery's headings stay this far inside the field of view: a sweep
along the edge of the view would pass returns the sensor never saw."""
ESCAPE_TURNED_RAD = 0.03
"""The recovery drives once its heading is within this of the open heading (and steers to hold it)."""
ESCAPE_MAX_S = 10.0
"""A recovery ends this long after it started whatever happens (a turn the robot cannot make): real time, as the
commands' ``time_s`` says, not control periods (a real LIMO gets a command per scan, not per ``control_period_s``)."""
TIME_EPS_S = 1e-6
"""Times this close count as equal (lockstep times are sums of control periods)."""


class PlannerStatus(str, Enum):
    """What the path follower is doing, as the planner service's feedback carries it: ``decision_reason`` asks for a
    new goal on any status but ``following``."""

    IDLE = "idle"
    FOLLOWING = "following"
    REACHED = "reached"
    BLOCKED = "blocked"
    NO_PROGRESS = "no_progress"


class NoPath(Exception):
    """The goal cannot be reached through known free space (reported as ``blocked``)."""


def descend_path(distance_m: np.ndarray, geometry: GridGeometry, goal_cell: tuple[int, int]) -> np.ndarray:
    """Path (N x 2, metres, robot first) from the robot to ``goal_cell`` by steepest descent of D.

    ``distance_m`` must be a geodesic distance map from the robot (``geodesic_distance``); a goal at
    infinite distance raises NoPath. A diagonal step between two cells of infinite distance (a line of
    untraversable cells one cell thick, unknown cells between two LiDAR rays) is never taken: the fast
    marching that made D is 4-connected and does not pass there either, so such a step would take the path
    through the corner of cells it must not enter, and far shorter than the distance D says. Every cell of
    finite distance beyond the robot's has a 4-connected neighbour of smaller distance, so the descent
    still reaches the robot.
    """
    y, x = int(goal_cell[0]), int(goal_cell[1])
    if not np.isfinite(distance_m[y, x]):
        raise NoPath(f"goal cell {goal_cell} is unreachable")
    ny, nx = distance_m.shape
    cells = [(y, x)]
    for _ in range(ny * nx):
        here = distance_m[y, x]
        if here <= geometry.resolution_m:
            break
        nb = _NEIGHBOURS + (y, x)
        ok = (nb[:, 0] >= 0) & (nb[:, 0] < ny) & (nb[:, 1] >= 0) & (nb[:, 1] < nx)
        nb = nb[ok]
        values = distance_m[nb[:, 0], nb[:, 1]]  # a copy: a squeezed diagonal is struck out of it below
        while True:
            k = int(np.argmin(values))
            if not values[k] < here:  # no step down left (every one struck out, too)
                break
            ky, kx = int(nb[k, 0]), int(nb[k, 1])
            # A diagonal's two sides (same row, same column) lie on the grid whenever the diagonal does. Checked on
            # the step chosen only (a squeezed one struck out, the next best taken): the same step as striking every
            # squeezed diagonal out first, without that check's arrays on each of a path's cells.
            if not (ky != y and kx != x and not math.isfinite(distance_m[ky, x]) and not math.isfinite(distance_m[y, kx])):
                break
            values[k] = np.inf
        if not values[k] < here:
            break
        y, x = ky, kx
        cells.append((y, x))
    arr = np.array(cells[::-1])
    xs, ys = geometry.cell_to_world(arr[:, 0], arr[:, 1])
    return np.stack([xs, ys], axis=1)


def plan_path(
    traversable: np.ndarray,
    geometry: GridGeometry,
    start_xy_m: np.ndarray,
    goal_xy_m: np.ndarray,
    distance_from_start: np.ndarray | None = None,
    goal_distance_m: float | None = None,
) -> np.ndarray:
    """Shortest path from start to goal through ``traversable`` cells, as metric waypoints.

    Pass ``distance_from_start`` when a distance map from the start already exists (one fast-marching
    pass per decision is enough). Otherwise, with ``goal_distance_m`` (the goal's geodesic distance, as
    a decision message gives it), fast marching stops just past the goal: the descent from the goal
    reads only cells closer than it, and below its bound a bounded pass is exactly the full map
    (``geodesic_distance``), so the path is the same; a goal the bounded pass does not reach in time
    (a wrong hint) gets the whole map. Raises NoPath when the goal is off the map, on a cell that is not
    traversable, or unreachable, its message saying which.
    """
    gy, gx = geometry.world_to_cell(goal_xy_m[0], goal_xy_m[1])
    if not geometry.in_bounds(gy, gx):
        raise NoPath("goal is outside the map")
    d = distance_from_start
    if d is None and goal_distance_m is not None and math.isfinite(goal_distance_m):
        within_m = float(goal_distance_m) + geometry.resolution_m
        d = geodesic_distance(traversable, geometry, start_xy_m, within_m)
        if not d[int(gy), int(gx)] < within_m:
            d = None
    if d is None:
        d = geodesic_distance(traversable, geometry, start_xy_m)
    if not np.isfinite(d[int(gy), int(gx)]) and not traversable[int(gy), int(gx)]:
        # Said apart from a goal no path leads to: the goal itself lies where the robot cannot stand.
        raise NoPath(
            f"goal ({float(goal_xy_m[0]):.2f}, {float(goal_xy_m[1]):.2f}) m is on a cell that is not traversable "
            "(an obstacle, within robot.radius_m of one, or unknown)"
        )
    path = descend_path(d, geometry, (int(gy), int(gx)))
    path[-1] = np.asarray(goal_xy_m, dtype=float)
    return path


def path_is_blocked(path_xy_m: np.ndarray, start_index: int, occupied: np.ndarray, geometry: GridGeometry, radius_m: float, horizon: int = 60) -> bool:
    """True when an occupied cell lies within ``radius_m`` of the next ``horizon`` path points."""
    pts = path_xy_m[start_index : start_index + horizon]
    if len(pts) == 0:
        return False
    r = int(math.ceil(radius_m / geometry.resolution_m - 1e-9))
    offsets = disk_offsets(r)
    iy, ix = geometry.world_to_cell(pts[:, 0], pts[:, 1])
    yy = (iy[:, None] + offsets[None, :, 0]).ravel()
    xx = (ix[:, None] + offsets[None, :, 1]).ravel()
    ok = geometry.in_bounds(yy, xx)
    return bool(occupied[yy[ok], xx[ok]].any())


def path_blocked_ahead(path_ahead_xy_m: np.ndarray, pose: Pose2D, occupied: np.ndarray, geometry: GridGeometry, robot_radius_m: float) -> bool:
    """The blocked check of ``LocalPlanner.check_blocked`` on the path still ahead of the robot.

    Path points within two robot radii of the robot are skipped (the robot is already there). A pure
    function of its inputs, so the frontier service can apply the very same check to the path the
    planner reported, without waiting for the planner (one hop less per runtime step).
    """
    ahead = np.asarray(path_ahead_xy_m, dtype=float).reshape(-1, 2)
    if len(ahead) == 0:
        return False
    near = np.hypot(ahead[:, 0] - pose.x_m, ahead[:, 1] - pose.y_m) < 2.0 * robot_radius_m
    skip = int(np.argmin(near)) if not near.all() else len(ahead)
    return path_is_blocked(ahead, skip, occupied, geometry, robot_radius_m * 0.75)


@dataclass(frozen=True)
class FreeSpace:
    """The traversable (inflated) grid a path was planned on, for line-of-sight checks, and the occupied
    (and explored) cells of that map, for the check behind the robot before it reverses."""

    traversable: np.ndarray
    geometry: GridGeometry
    occupied: np.ndarray | None = None
    """None: not known, and reversing is not checked."""
    explored: np.ndarray | None = None
    """The cells that map has seen; None: not known (a plan from an older planner), and only occupied and off-map
    cells stop a reverse."""

    def behind_is_clear(self, pose: Pose2D, length_m: float, width_m: float, distance_m: float, disc_radius_m: float | None = None) -> bool:
        """Whether the body can reverse ``distance_m`` straight back: no cell that shares any area with what it sweeps
        behind it is occupied, unknown (as planning never enters unknown cells, Nav2's ``allow_unknown: false``) or off
        the map. The box (``length_m`` x ``width_m``, centred on ``pose``) sweeps the strip behind its rear edge; a
        disc (``disc_radius_m``, the 2D simulator's body) its rear half's sweep: the strip of its diameter from its
        centre back and the disc where it ends (a cell already touching the disc's rear half is in the way too)."""
        if self.occupied is None or distance_m <= 0:
            return True
        g = self.geometry
        if disc_radius_m is None:
            iy, ix = g.cells_overlapping_rectangle(pose.compose_offset(-0.5 * (length_m + distance_m)), distance_m, width_m)
        else:
            end = pose.compose_offset(-distance_m)
            strip = g.cells_overlapping_rectangle(pose.compose_offset(-0.5 * distance_m), distance_m, 2.0 * disc_radius_m)
            disc = g.cells_overlapping_disc(end.x_m, end.y_m, disc_radius_m)
            iy, ix = np.concatenate([strip[0], disc[0]]), np.concatenate([strip[1], disc[1]])
        on_map = g.in_bounds(iy, ix)
        if not on_map.all():
            return False
        if self.explored is not None and not self.explored[iy, ix].all():
            return False
        return not bool(self.occupied[iy, ix].any())

    def line_is_free(self, a_xy_m: np.ndarray, b_xy_m: np.ndarray) -> bool:
        """Whether the straight segment ``a_xy_m`` -> ``b_xy_m`` stays on traversable cells (sampled every half cell):
        pure pursuit looks ahead only as far as it can drive straight."""
        n = max(2, int(np.ceil(np.hypot(*(b_xy_m - a_xy_m)) / (0.5 * self.geometry.resolution_m))) + 1)
        t = np.linspace(0.0, 1.0, n)[1:]
        pts = a_xy_m[None, :] + t[:, None] * (b_xy_m - a_xy_m)[None, :]
        iy, ix = self.geometry.world_to_cell(pts[:, 0], pts[:, 1])
        ok = self.geometry.in_bounds(iy, ix)
        return bool(ok.all() and self.traversable[iy, ix].all())


@dataclass
class FollowResult:
    """One control period of the path follower: the command to send and the status it leaves the follower in."""

    command: VelocityCommand
    status: PlannerStatus
    recovery: str = ""
    """``"backup"`` when the command is the stall recovery's (``StallRecovery``); ``"escape"`` when it is the progress
    recovery's (``ProgressRecovery``); ``"reverse_blocked"``
    when a reverse command (a back-up, or the blocked-ahead creep back) was replaced by a stop because
    the map shows an obstacle behind the robot; ``"bad_pose"`` when the pose was not finite (a stop); else empty."""


class PathFollower:
    """Pure pursuit along a path: rotate in place on sharp turns, slow down near scanned obstacles."""

    def __init__(self, robot: RobotConfig, config: PlannerConfig, sensor_mount_x_m: float = 0.0) -> None:
        self.robot = robot
        self.config = config
        self.sensor_mount_x_m = sensor_mount_x_m

    def lookahead_index(
        self, pose: Pose2D, path_xy_m: np.ndarray, progress_index: int, free: FreeSpace | None = None
    ) -> tuple[int, int]:
        """(nearest, lookahead) indices on the path, never moving backwards from ``progress_index``.

        With ``free`` (the inflated map the path was planned on), the lookahead point is pulled back
        until the straight line to it stays in free space, so the robot never cuts a corner.
        """
        tail = path_xy_m[progress_index:]
        d = np.hypot(tail[:, 0] - pose.x_m, tail[:, 1] - pose.y_m)
        nearest = progress_index + int(np.argmin(d[: max(1, min(len(d), 40))]))
        ahead = np.hypot(path_xy_m[nearest:, 0] - pose.x_m, path_xy_m[nearest:, 1] - pose.y_m)
        beyond = np.flatnonzero(ahead >= self.config.lookahead_m)
        look = nearest + int(beyond[0]) if beyond.size else len(path_xy_m) - 1
        if free is not None:
            while look > nearest + 1 and not free.line_is_free(pose.xy, path_xy_m[look]):
                look -= 1
        return nearest, look

    @staticmethod
    def valid_returns(scan: LaserScan) -> np.ndarray:
        """Which beams of the scan are returns the controller keeps off. A beam shorter than ``range_min`` is still
        something there (the mapper leaves it out, the controller must not drive into it); a 0 m beam is no reading
        at all (how the ROS bridge passes on NaN and too-close beams), nor is NaN, and inf or ``range_max`` is no
        return (``no_return_mask``)."""
        r = np.asarray(scan.ranges_m, dtype=float)
        return np.isfinite(r) & (r > 0.0) & ~no_return_mask(r, scan.range_max_m)

    def scanned_points(self, scan: LaserScan) -> tuple[np.ndarray, np.ndarray]:
        """(forward_m, lateral_m) of the scan's ``valid_returns`` in the robot's frame."""
        valid = self.valid_returns(scan)
        r, ang = np.asarray(scan.ranges_m, dtype=float)[valid], scan.angles_rad[valid]
        return r * np.cos(ang) + self.sensor_mount_x_m, r * np.sin(ang)

    def clearance_ahead(self, scan: LaserScan | None) -> tuple[float, float]:
        """(travel_m, bearing_rad): how far the robot can drive straight before touching a scanned
        obstacle, and the bearing of that obstacle, for the slow-down. The body is swept forward as a
        circle of half the robot's width plus 1 cm, so walls beside a narrow door do not count;
        ``front_gap_m`` is the hard limit on the body's real front."""
        if scan is None:
            return math.inf, 0.0
        forward, lateral = self.scanned_points(scan)
        radius = self.robot.disc_radius_m
        ahead = (forward > 0.0) & (np.abs(lateral) < radius)
        if not ahead.any():
            return math.inf, 0.0
        travel = forward[ahead] - np.sqrt(radius**2 - lateral[ahead] ** 2)
        k = int(np.argmin(travel))
        return float(travel[k]), float(math.atan2(lateral[ahead][k], forward[ahead][k]))

    def front_gap_m(self, scan: LaserScan | None) -> float:
        """The gap between the body's front and the nearest scanned return in its way (``planner.body``): the disc's
        sweep (``clearance_ahead``), or for the box the nearest return within its width ahead, less ``length_m`` / 2
        (the LIMO's front, 4 cm beyond the disc's). Negative when a return lies inside the box (a wall the robot
        is pressed on)."""
        if scan is None:
            return math.inf
        if self.config.body != "box":
            return self.clearance_ahead(scan)[0]
        forward, lateral = self.scanned_points(scan)
        ahead = (forward > 0.0) & (np.abs(lateral) < 0.5 * self.robot.width_m)
        return float(forward[ahead].min() - 0.5 * self.robot.length_m) if ahead.any() else math.inf

    def open_heading_rad(self, pose: Pose2D, bearing_rad: float, scan: LaserScan | None, distance_m: float, fov_rad: float) -> float | None:
        """The heading (world frame) nearest ``bearing_rad`` along which the body can drive ``distance_m`` and still
        keep ``stop_distance_m`` off every scanned return (the disc's sweep, and for ``body: box`` its front too), or
        None. Headings are checked within the sensor's field of view less ``ESCAPE_UNSEEN_MARGIN_RAD``."""
        if scan is None:
            return None
        forward, lateral = self.scanned_points(scan)
        offsets = np.arange(-math.pi, math.pi, ESCAPE_HEADING_STEP_RAD)
        relative = np.array([wrap_angle_rad(bearing_rad + o - pose.yaw_rad) for o in offsets])
        cos, sin = np.cos(relative)[:, None], np.sin(relative)[:, None]
        along = forward[None, :] * cos + lateral[None, :] * sin
        across = -forward[None, :] * sin + lateral[None, :] * cos
        radius = self.robot.disc_radius_m
        in_sweep = (along > 0.0) & (np.abs(across) < radius)
        travel = np.where(in_sweep, along - np.sqrt(np.maximum(radius**2 - across**2, 0.0)), np.inf).min(axis=1, initial=np.inf)
        if self.config.body == "box":
            in_front = (along > 0.0) & (np.abs(across) < 0.5 * self.robot.width_m)
            travel = np.minimum(travel, np.where(in_front, along - 0.5 * self.robot.length_m, np.inf).min(axis=1, initial=np.inf))
        clear = travel >= distance_m + self.config.stop_distance_m
        clear &= np.roll(clear, 1) & np.roll(clear, -1)  # open a step either side too: a heading the robot can hold
        if fov_rad < 2 * math.pi - 1e-9:
            clear &= np.abs(relative) <= max(0.5 * fov_rad - ESCAPE_UNSEEN_MARGIN_RAD, 0.0)
        open_ = np.flatnonzero(clear)
        if open_.size == 0:
            return None
        nearest = open_[np.argmin(np.abs(offsets[open_]))]
        return wrap_angle_rad(pose.yaw_rad + float(relative[nearest]))

    def obstacle_speed_scale(self, travel_m: float) -> float:
        """1 when the way ahead is clear, falling to 0 at ``stop_distance_m`` before contact."""
        c = self.config
        return float(np.clip((travel_m - c.stop_distance_m) / max(c.slow_down_distance_m - c.stop_distance_m, 1e-6), 0.0, 1.0))

    def _heading_error(self, pose: Pose2D, target_xy_m: np.ndarray) -> float:
        return wrap_angle_rad(math.atan2(target_xy_m[1] - pose.y_m, target_xy_m[0] - pose.x_m) - pose.yaw_rad)

    def command(
        self, pose: Pose2D, path_xy_m: np.ndarray, nearest: int, look: int, distance_to_goal_m: float, scan: LaserScan | None
    ) -> VelocityCommand:
        """Velocity for one control period.

        Pure pursuit towards the lookahead point; when an obstacle in the sweep blocks it (the robot
        cut a corner), it falls back to the path itself: face the path point just ahead, creep
        along it, or back off when even that is blocked.
        """
        v_max, w_max = self.robot.max_linear_mps, self.robot.max_angular_radps
        target = path_xy_m[look]
        heading_error = self._heading_error(pose, target)
        if abs(heading_error) > min(self.config.rotate_in_place_rad, PURSUIT_MAX_HEADING_ERROR_RAD):
            return VelocityCommand(0.0, math.copysign(w_max, heading_error))
        travel, _ = self.clearance_ahead(scan)
        scale = self.obstacle_speed_scale(travel)
        # One period's travel never takes the front closer than stop_distance_m to a scanned return.
        front_limit_mps = (self.front_gap_m(scan) - self.config.stop_distance_m) / self.robot.control_period_s
        min_v = self.min_speed_mps()
        if min(scale * v_max, front_limit_mps) < min_v:
            return self._recover(pose, path_xy_m, nearest, travel)
        dist = max(math.hypot(target[0] - pose.x_m, target[1] - pose.y_m), 1e-6)
        curvature = 2.0 * math.sin(heading_error) / dist
        v = min(v_max * scale, front_limit_mps, distance_to_goal_m / self.robot.control_period_s)  # never overshoot the goal
        if abs(curvature) * v > w_max:
            v = w_max / abs(curvature)
        w = curvature * v
        if v < min_v:  # too slow to steer by moving: turn towards the target instead
            return VelocityCommand(0.0, float(np.clip(2.0 * heading_error, -w_max, w_max)))
        return VelocityCommand(v, w).clamped(v_max, w_max)

    def _recover(self, pose: Pose2D, path_xy_m: np.ndarray, nearest: int, travel_m: float) -> VelocityCommand:
        """Blocked ahead (Nav2's recovery, in two moves): face the path point ~0.2 m ahead (the path
        keeps clear of walls); if already facing it, back up a little."""
        w_max = self.robot.max_angular_radps
        step_m = max(float(np.median(np.hypot(*np.diff(path_xy_m[: nearest + 3], axis=0).T))) if nearest + 2 < len(path_xy_m) else 0.1, 1e-3)
        k = min(len(path_xy_m) - 1, nearest + max(1, int(round(0.2 / step_m))))
        error = self._heading_error(pose, path_xy_m[k])
        if abs(error) > 0.25:
            return VelocityCommand(0.0, math.copysign(0.5 * w_max, error))
        return VelocityCommand(-min(CREEP_BACK_MPS, self.robot.max_linear_mps), 0.0)

    def min_speed_mps(self) -> float:
        """The slowest forward speed driven (below it the robot turns, or recovers when blocked): 0.05 m/s, or a
        quarter of the top speed on a robot limited to less than 0.2 m/s (which would otherwise only ever recover)."""
        return min(MIN_DRIVE_MPS, 0.25 * self.robot.max_linear_mps)

class ProgressChecker:
    """Nav2's simple progress checker: at least ``required_m`` of movement within ``window_s``."""

    def __init__(self, required_m: float, window_s: float) -> None:
        self.required_m = required_m
        self.window_s = window_s
        self.reset()

    def reset(self) -> None:
        self.anchor: tuple[float, float, float] | None = None
        """(x_m, y_m, time_s) where progress was last seen; None before the first check."""

    def check(self, pose: Pose2D, time_s: float) -> bool:
        """False when the robot failed to make progress in time (then the anchor restarts)."""
        if self.anchor is None or math.hypot(pose.x_m - self.anchor[0], pose.y_m - self.anchor[1]) >= self.required_m:
            self.anchor = (pose.x_m, pose.y_m, time_s)
            return True
        if time_s - self.anchor[2] > self.window_s:
            self.anchor = (pose.x_m, pose.y_m, time_s)
            return False
        return True


def driven_along_heading_m(last_pose: Pose2D, pose: Pose2D, linear_mps: float) -> float:
    """How far the robot got from ``last_pose`` to ``pose`` the way a drive at ``linear_mps`` takes it (ahead, or back
    when negative): the distance moved, less what went sideways of every heading the body had on the way. A
    differential drive moves along its heading, so a free arc (any heading between the two poses') counts in full;
    a body pressed on a wall that slides along it (MuJoCo's LIMO, gen_middle_2001) counts only its share along
    the heading, and a push back against the command counts negative."""
    dx_m, dy_m = pose.x_m - last_pose.x_m, pose.y_m - last_pose.y_m
    moved_m = math.hypot(dx_m, dy_m)
    if moved_m == 0.0:
        return 0.0
    if linear_mps < 0:
        dx_m, dy_m = -dx_m, -dy_m
    travel_rad = wrap_angle_rad(math.atan2(dy_m, dx_m) - last_pose.yaw_rad)
    turned_rad = wrap_angle_rad(pose.yaw_rad - last_pose.yaw_rad)
    low_rad, high_rad = min(0.0, turned_rad), max(0.0, turned_rad)
    if low_rad <= travel_rad <= high_rad:
        return moved_m
    sideways_rad = min(abs(wrap_angle_rad(travel_rad - low_rad)), abs(wrap_angle_rad(travel_rad - high_rad)))
    return moved_m * math.cos(sideways_rad)


class StallRecovery:
    """Nav2's BackUp recovery for a robot that its commands no longer move: ``stall_steps`` control periods
    in a row that each achieved less than ``STALL_ACHIEVED_FRACTION`` of what they asked (the robot is
    pinned on a wall's corner) start a straight back-up of ``backup_distance_m``, which ends once odometry says the
    robot got that far back from where it started, or once the time it takes at ``backup_speed_mps`` has passed
    (a robot that cannot move back): real time and distance, not control periods, so that a robot commanded at
    another rate (the real LIMO, once per scan) backs up as far. In lockstep both end it after
    ``ceil(backup_distance_m / (backup_speed_mps * control_period_s))`` periods, as before. The pure-pursuit
    follower alone keeps pushing a pinned robot into the wall: its sweep sees the wall a few centimetres
    ahead but not the corner that holds the body. A period that asked to drive is judged by its drive: pinned
    by its side on a wall outside the depth camera's view, the robot still turns as pure pursuit asks, and
    counting those turns as movement kept the back-up from ever starting. Nor does a drive count what went
    sideways: the MuJoCo LIMO pressed on a wall can slide along it at a third of the asked speed."""

    def __init__(self, config: PlannerConfig) -> None:
        self.config = config
        self.backup_duration_s = config.backup_distance_m / config.backup_speed_mps
        self.backups = 0
        """Back-ups started in this planner's life (the planner service logs each)."""
        self.last_started_now = False
        """The latest back-up was started by ``back_up_now`` (a return the map has not got), not by a stall."""
        self.reset()

    def reset(self) -> None:
        self.last: tuple[Pose2D, float, VelocityCommand] | None = None
        """(pose, time_s, command) of the last control period."""
        self.stalled_periods = 0
        self.backing_up: tuple[Pose2D, float] | None = None
        """(pose, time_s) where and when the running back-up started; None when none runs."""

    def state(self) -> tuple:
        """What a control period changes, for ``LocalPlanner.follow_state``."""
        return self.last, self.stalled_periods, self.backing_up, self.backups, self.last_started_now

    def restore(self, state: tuple) -> None:
        """Put back a ``state()``."""
        self.last, self.stalled_periods, self.backing_up, self.backups, self.last_started_now = state

    def _stalled(self, pose: Pose2D, time_s: float) -> bool:
        """Whether the last period's command barely moved the robot."""
        if self.last is None:
            return False
        last_pose, last_time_s, cmd = self.last
        dt = time_s - last_time_s
        asked_m, asked_rad = abs(cmd.linear_mps) * dt, cmd.angular_radps * dt
        if dt <= 0 or (asked_m < STALL_MIN_ASKED_M and abs(asked_rad) < STALL_MIN_ASKED_RAD):
            return False
        turned_rad = math.copysign(1.0, asked_rad) * wrap_angle_rad(pose.yaw_rad - last_pose.yaw_rad)
        if asked_m >= STALL_MIN_ASKED_M:
            driven_m = driven_along_heading_m(last_pose, pose, cmd.linear_mps)
            return driven_m < STALL_ACHIEVED_FRACTION * asked_m  # a drive that went nowhere is pinned, whatever its turn did
        return turned_rad < STALL_ACHIEVED_FRACTION * abs(asked_rad)  # a turn in place is judged by its turn

    def command(self, pose: Pose2D, time_s: float) -> VelocityCommand | None:
        """The back-up command for this period, or None to follow the path as usual."""
        if self.config.stall_steps <= 0:
            return None
        self.stalled_periods = self.stalled_periods + 1 if self._stalled(pose, time_s) else 0
        running = self._backing_up(pose, time_s)
        if running is not None or self.stalled_periods < self.config.stall_steps:
            return running
        self._start(pose, time_s, now=False)
        return self._backing_up(pose, time_s)

    def back_up_now(self, pose: Pose2D, time_s: float) -> VelocityCommand | None:
        """Start a back-up now, whatever the last periods did (``LocalPlanner`` found the body blocked by a return its
        map has not got); its first period's command, or None when the recovery is off."""
        if self.config.stall_steps <= 0:
            return None
        self._start(pose, time_s, now=True)
        return self._backing_up(pose, time_s)

    def _start(self, pose: Pose2D, time_s: float, now: bool) -> None:
        self.backing_up = (pose, time_s)
        self.backups += 1
        self.stalled_periods = 0
        self.last_started_now = now

    def _backing_up(self, pose: Pose2D, time_s: float) -> VelocityCommand | None:
        if self.backing_up is None:
            return None
        start_pose, start_s = self.backing_up
        backed_m = driven_along_heading_m(start_pose, pose, -1.0)
        if time_s - start_s < self.backup_duration_s - TIME_EPS_S and backed_m < self.config.backup_distance_m - 1e-9:
            return VelocityCommand(-self.config.backup_speed_mps, 0.0)
        self.backing_up = None
        return None

    def record(self, pose: Pose2D, time_s: float, command: VelocityCommand) -> None:
        """What was sent this period, to judge by the next pose whether it moved the robot."""
        self.last = (pose, time_s, command)


class ProgressRecovery:
    """Nav2's recovery on a failed progress check (its navigator runs recoveries before it gives a goal up): turn
    to the open heading nearest the path's bearing and drive ``escape_distance_m`` along it, ``progress_recoveries``
    times per goal. The case it is for: a path that clips a wall's corner by less than the controller keeps off
    scanned returns, where the controller backs off a few centimetres, pure pursuit drives back in, and the robot
    rocks in place until the goal is given up (and every later goal through that corner with it)."""

    def __init__(self, follower: PathFollower) -> None:
        self.follower = follower
        self.config = follower.config
        self.escapes = 0
        """Recoveries started in this planner's life (the planner service logs each)."""
        self.reset()

    def reset(self) -> None:
        """A new goal: its full count of recoveries, none running."""
        self.left = self.config.progress_recoveries
        self.heading_rad: float | None = None
        """The open heading of the recovery running now; None when none runs."""
        self.drive_left_m = 0.0
        """What is left to drive: less, at each command, the speed last commanded times the real time since it."""
        self.periods = 0
        """Commands of the running recovery so far (a count only: ``ESCAPE_MAX_S`` bounds it by time)."""
        self.started_s = 0.0
        """When the running recovery started."""

    def state(self) -> tuple:
        """What a control period changes, for ``LocalPlanner.follow_state``."""
        return self.left, self.heading_rad, self.drive_left_m, self.periods, self.escapes, self.started_s

    def restore(self, state: tuple) -> None:
        """Put back a ``state()``."""
        self.left, self.heading_rad, self.drive_left_m, self.periods, self.escapes, self.started_s = state

    def start(self, pose: Pose2D, bearing_rad: float, scan: LaserScan | None, fov_rad: float, time_s: float) -> bool:
        """Begin a recovery if one is left for this goal and an open heading exists; False gives the goal up."""
        if self.left <= 0:
            return False
        heading = self.follower.open_heading_rad(pose, bearing_rad, scan, self.config.escape_distance_m, fov_rad)
        if heading is None:
            return False
        self.left -= 1
        self.escapes += 1
        self.heading_rad, self.drive_left_m, self.periods, self.started_s = heading, self.config.escape_distance_m, 0, time_s
        return True

    def command(self, pose: Pose2D, scan: LaserScan | None, time_s: float, last: tuple[Pose2D, float, VelocityCommand] | None) -> VelocityCommand | None:
        """This period's command of the running recovery (turn, then drive), or None when none runs (any more).
        ``last`` is the previous period's (pose, time_s, command) as sent (``StallRecovery.last``; None: the robot
        stood still since): a drive it commanded counts against ``drive_left_m`` for the real time it ran."""
        if self.heading_rad is None:
            return None
        robot = self.follower.robot
        if self.periods > 0 and last is not None and last[2].linear_mps > 0.0:
            self.drive_left_m -= last[2].linear_mps * max(time_s - last[1], 0.0)
        self.periods += 1
        in_time = time_s - self.started_s < ESCAPE_MAX_S - TIME_EPS_S
        error = wrap_angle_rad(self.heading_rad - pose.yaw_rad)
        turn_radps = float(np.clip(error / robot.control_period_s, -robot.max_angular_radps, robot.max_angular_radps))
        if in_time and abs(error) > ESCAPE_TURNED_RAD:
            return VelocityCommand(0.0, turn_radps)
        gap_mps = (self.follower.front_gap_m(scan) - self.config.stop_distance_m) / robot.control_period_s
        v = min(self.config.backup_speed_mps, robot.max_linear_mps, gap_mps, self.drive_left_m / robot.control_period_s)
        if not in_time or v < self.follower.min_speed_mps():
            self.heading_rad = None
            return None
        return VelocityCommand(v, turn_radps)


CONTACT_BEYOND_GOAL_CELLS = 3
"""``contacts_beyond_goal``'s margin past the goal's distance: the bounded pass's own (``plan_path`` marches to the
goal's distance plus a cell, ``geodesic_distance`` a band of two cells further)."""


def contacts_beyond_goal(
    traversable: np.ndarray, planned_on: np.ndarray, geometry: GridGeometry, distance_from_robot: np.ndarray, goal_xy_m: np.ndarray
) -> bool:
    """True when every cell the contacts take off ``traversable`` (``planned_on`` is the grid less them) is, on the
    decision's ``distance_from_robot``, at least CONTACT_BEYOND_GOAL_CELLS farther than the goal. The path descends
    only through cells nearer than the goal, and their distances depend only on cells of smaller distance (what
    ``plan_path``'s bounded pass relies on), so the decision's map gives the very path a pass of the planner's own
    on ``planned_on`` would, without that pass. False for a goal off the map (``plan_path`` says so either way)."""
    gy, gx = geometry.world_to_cell(goal_xy_m[0], goal_xy_m[1])
    if not geometry.in_bounds(gy, gx):
        return False
    beyond_m = float(distance_from_robot[int(gy), int(gx)]) + CONTACT_BEYOND_GOAL_CELLS * geometry.resolution_m
    return bool(np.all(distance_from_robot[traversable & ~planned_on] >= beyond_m))


@dataclass(frozen=True)
class FollowCheckpoint:
    """What ``LocalPlanner.update`` carries from one control period to the next, besides the path and the grid it was
    planned on (``LocalPlanner.path``, ``free``) and the contacts: with them, a planner started afresh and given this
    (``LocalPlanner.resume``) commands the next period exactly as the planner it was taken from would have (a planner
    killed mid-episode and restarted, ``services/planner.py``)."""

    status: PlannerStatus
    progress_index: int
    """The path point the robot last progressed to (``PathFollower.lookahead_index`` never goes back from it)."""
    progress_anchor: tuple[float, float, float] | None
    """``ProgressChecker.anchor``: (x_m, y_m, time_s) where progress was last seen; None before the first check."""
    stall_last: tuple[Pose2D, float, VelocityCommand] | None
    """``StallRecovery.last``: (pose, time_s, command) of the last control period."""
    stalled_periods: int
    backing_up: tuple[Pose2D, float] | None
    """``StallRecovery.backing_up``: (pose, time_s) where and when the running back-up started; None when none runs."""
    backups: int
    last_started_now: bool
    recoveries_left: int
    """``ProgressRecovery.left``: recoveries left for this goal."""
    escape_heading_rad: float | None
    """The open heading of the progress recovery running now; None when none runs."""
    escape_drive_left_m: float
    escape_periods: int
    escapes: int
    replan_pending: bool
    blocked_why: str
    escape_started_s: float = 0.0
    """``ProgressRecovery.started_s``: when the progress recovery running now started (``ESCAPE_MAX_S``)."""

    def misfit(self, path_xy_m: np.ndarray | None) -> str:
        """Why this checkpoint cannot be resumed on ``path_xy_m`` (None: no path), "" when it can: a point to follow
        past the path's end (``PathFollower.lookahead_index`` would fail on every command), or a goal followed with no
        path (the follower would report ``following`` and stand still). A planner's own checkpoint and plan always fit;
        a state and plan that are not each other's (two planners at once, a forged one) need not."""
        n = 0 if path_xy_m is None else len(path_xy_m)
        if self.status == PlannerStatus.FOLLOWING and n == 0:
            return "it follows a goal, with no path"
        if n and self.progress_index >= n:  # without a path the index is unused (``clear`` leaves it as it was)
            return f"its path point {self.progress_index} is past the path's {n} points"
        return ""


class LocalPlanner:
    """Follows one goal at a time: path, pure pursuit, goal check, progress check, blocked check."""

    def __init__(
        self,
        robot: RobotConfig | None = None,
        config: PlannerConfig | None = None,
        goal_tolerance_m: float = 0.3,
        sensor_mount_x_m: float = 0.0,
        sensor_fov_rad: float = 2 * math.pi,
    ) -> None:
        self.robot = robot or RobotConfig()
        self.config = config or PlannerConfig()
        self.goal_tolerance_m = goal_tolerance_m
        self.sensor_fov_rad = sensor_fov_rad
        self.follower = PathFollower(self.robot, self.config, sensor_mount_x_m)
        self.progress = ProgressChecker(self.config.progress_required_m, self.config.progress_window_s)
        self.stall = StallRecovery(self.config)
        self.recovery = ProgressRecovery(self.follower)
        self.path: np.ndarray | None = None
        self.free: FreeSpace | None = None
        self.progress_index = 0
        self.status = PlannerStatus.IDLE
        self.blocked_why = ""
        """Why the last goal could not be planned (``NoPath``'s message: off the map, on a cell that is not traversable, unreachable);
        empty otherwise."""
        self.contacts_xy_m = np.zeros((0, 2))
        """Centres (metres) of the cells a pinned robot was pressed against (``mark_contact``): obstacles that no scan
        mapped, kept for the planner's life (an episode) and inflated into every grid it plans on."""
        self.replan_pending = False
        """A back-up from a new contact is running: re-plan round the contact once it ends."""

    @classmethod
    def for_config(cls, config: ExplorationConfig) -> LocalPlanner:
        """The planner of an episode with these settings (the in-process Explorer and the planner service)."""
        return cls(config.robot, config.planner, config.episode.goal_tolerance_m, config.sensor.mount_x_m, math.radians(config.sensor.fov_deg))

    def narrow_sensor(self) -> bool:
        """A sensor narrower than ``face_goal_below_fov_deg`` (the depth camera): it turns to goals, and a wall that pins
        it from the side is one it cannot see."""
        return self.sensor_fov_rad < math.radians(self.config.face_goal_below_fov_deg) - 1e-9

    def without_contacts(self, traversable: np.ndarray, geometry: GridGeometry) -> np.ndarray:
        """``traversable`` less the contacts inflated by the robot's radius (the same grid when there are none)."""
        if len(self.contacts_xy_m) == 0:
            return traversable
        iy, ix = geometry.world_to_cell(self.contacts_xy_m[:, 0], self.contacts_xy_m[:, 1])
        ok = geometry.in_bounds(iy, ix)
        contacts = np.zeros(traversable.shape, dtype=bool)
        contacts[iy[ok], ix[ok]] = True
        return traversable & ~inflate(contacts, self.robot.radius_m, geometry.resolution_m)

    def mark_contact(self, pose: Pose2D, forward: bool) -> None:
        """A drive that went nowhere (``StallRecovery``) has the body pressed against something no scan shows: with a
        narrow sensor, a wall end beside the robot, outside the view and nearer than ``range_min``, which the map left
        unknown. Remember as obstacles the cells of the planned-on grid that are not traversable and touch the body's
        disc (half its width plus 1 cm, and half a cell) on the side it drove to, so that the path after the back-up
        keeps the robot's radius off them, as the bumper layers of ROS costmaps mark a contact. A cell already marked
        (a second back-up at the same place) is not added again."""
        if self.free is None:
            return
        geometry, res = self.free.geometry, self.free.geometry.resolution_m
        radius = self.robot.disc_radius_m
        iy, ix = disk_cells(geometry, pose.xy, int(math.ceil(radius / res)) + 2)
        cx, cy = geometry.cell_to_world(iy, ix)
        gap = geometry.cell_gap_m(iy, ix, pose.x_m, pose.y_m)  # from the robot's centre to the nearest point of each cell
        sign = 1.0 if forward else -1.0
        along = (cx - pose.x_m) * math.cos(pose.yaw_rad) + (cy - pose.y_m) * math.sin(pose.yaw_rad)
        ahead = sign * along > 0.0
        touching = (gap >= 0.5 * self.robot.width_m) & (gap <= radius + 0.5 * res) & ahead & ~self.free.traversable[iy, ix]
        if touching.any():
            self.add_contacts(geometry, iy[touching], ix[touching])  # a second back-up at the same place adds none

    def mark_unmapped_returns(self, pose: Pose2D, scan: LaserScan | None) -> bool:
        """The follower blocked ahead (it is about to creep back) by returns nearer than the sensor's ``range_min``: the
        mapper leaves those out, so the path, planned on the map, runs on through them (with the depth camera, the
        end of a wall it only ever saw from nearer than 0.3 m or from outside its 79 degrees), and pure pursuit
        drives back in after every creep back until the progress check gives the goal up. Add as contacts the cells
        of such returns in the body's sweep ahead that the planned-on grid does not show occupied; True when one
        was new (then the path is planned again round them, as after a pinned back-up)."""
        if scan is None or self.free is None:
            return False
        ranges = np.asarray(scan.ranges_m, dtype=float)
        forward, lateral = self.follower.scanned_points(scan)
        near = ranges[self.follower.valid_returns(scan)] < scan.range_min_m
        blocking = near & (forward > 0.0) & (np.abs(lateral) < self.robot.disc_radius_m)
        if not blocking.any():
            return False
        # A hair beyond each return, as the mapper puts a hit: in the cell behind the surface, not the free one before it.
        sensor_x_m = self.follower.sensor_mount_x_m
        beyond = 1.0 + 1e-6 / np.maximum(np.hypot(forward[blocking] - sensor_x_m, lateral[blocking]), 1e-9)
        ahead_m = sensor_x_m + (forward[blocking] - sensor_x_m) * beyond
        side_m = lateral[blocking] * beyond
        cos, sin = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
        geometry = self.free.geometry
        iy, ix = geometry.world_to_cell(pose.x_m + ahead_m * cos - side_m * sin, pose.y_m + ahead_m * sin + side_m * cos)
        ok = geometry.in_bounds(iy, ix)
        iy, ix = iy[ok], ix[ok]
        if self.free.occupied is not None:
            unmapped = ~self.free.occupied[iy, ix]
            iy, ix = iy[unmapped], ix[unmapped]
        return self.add_contacts(geometry, iy, ix)

    def add_contacts(self, geometry: GridGeometry, iy: np.ndarray, ix: np.ndarray) -> bool:
        """Keep the centres of these cells as contacts; a cell already kept is not added again. True when one was new."""
        cx, cy = geometry.cell_to_world(iy, ix)
        known = {(float(x), float(y)) for x, y in self.contacts_xy_m}
        new = list(dict.fromkeys((float(x), float(y)) for x, y in zip(np.atleast_1d(cx), np.atleast_1d(cy)) if (float(x), float(y)) not in known))
        if new:
            self.contacts_xy_m = np.concatenate([self.contacts_xy_m, np.array(new)])
        return bool(new)

    def set_path(self, path_xy_m: np.ndarray, free: FreeSpace | None = None) -> None:
        """Follow a new path. Progress is tracked across re-plans to the same goal, so re-sending a
        goal cannot hide a robot that makes no progress."""
        path = np.asarray(path_xy_m, dtype=float)
        if self.path is None or np.hypot(*(path[-1] - self.path[-1])) > self.goal_tolerance_m:
            self.progress.reset()
            self.recovery.reset()
        self.path = path
        self.free = free
        self.progress_index = 0
        self.status = PlannerStatus.FOLLOWING

    def set_goal(
        self,
        traversable: np.ndarray,
        geometry: GridGeometry,
        pose: Pose2D,
        goal_xy_m: np.ndarray,
        distance_from_robot: np.ndarray | None = None,
        goal_distance_m: float | None = None,
        occupied: np.ndarray | None = None,
        explored: np.ndarray | None = None,
    ) -> PlannerStatus:
        """Plan to a new goal; the status is ``blocked`` when there is no path. Without
        ``distance_from_robot``, ``goal_distance_m`` bounds the fast-marching pass (``plan_path``).
        ``occupied`` (the same map's obstacles) lets the robot reverse only where the map shows none, and ``explored``
        (its seen cells) only where it has seen (``FreeSpace.behind_is_clear``)."""
        self.blocked_why = ""
        self.replan_pending = False
        if len(self.contacts_xy_m):  # the decision's grid and distances know nothing of the contacts
            planned_on = self.without_contacts(traversable, geometry)
            if distance_from_robot is not None and not contacts_beyond_goal(traversable, planned_on, geometry, distance_from_robot, goal_xy_m):
                distance_from_robot = None  # the contacts may change the distances the path descends: a pass of its own
            traversable = planned_on
        try:
            path = plan_path(traversable, geometry, pose.xy, np.asarray(goal_xy_m, dtype=float), distance_from_robot, goal_distance_m)
            self.set_path(path, FreeSpace(traversable, geometry, occupied, explored))
        except NoPath as exc:
            self.blocked_why = str(exc)
            self.path = None
            self.progress.reset()
            self.status = PlannerStatus.BLOCKED
        return self.status

    def clear(self) -> None:
        self.path = None
        self.status = PlannerStatus.IDLE

    def stood_still(self) -> None:
        """The robot stood still because it was told to (paused, stale inputs, no planner running), not because its goal
        is out of reach or it is pinned: the progress check starts over, and the command before the wait is not judged
        against where the robot is after it (``StallRecovery.last`` dropped: the next period counts no stall)."""
        self.progress.reset()
        self.stall.last = None

    def follow_state(self) -> tuple:
        """What ``update`` changes (status, progress along the path, the progress anchor, the stall
        recovery's state, and the path, its grid and the contacts a stall re-plans with): a caller may compute a
        command ahead of time and keep or undo it with ``restore_follow_state``."""
        recovered = (self.path, self.free, self.contacts_xy_m, self.replan_pending, self.blocked_why)
        return (self.status, self.progress_index, self.progress.anchor, self.stall.state(), self.recovery.state(), *recovered)

    def restore_follow_state(self, state: tuple) -> None:
        """Put back a ``follow_state()``, as if the commands computed since had not been."""
        self.status, self.progress_index, self.progress.anchor, stall, recovery = state[:5]
        self.path, self.free, self.contacts_xy_m, self.replan_pending, self.blocked_why = state[5:]
        self.stall.restore(stall)
        self.recovery.restore(recovery)

    def checkpoint(self) -> FollowCheckpoint:
        """The follower's state after this period (``FollowCheckpoint``), to resume from in another planner."""
        last, stalled, backing_up, backups, started_now = self.stall.state()
        left, heading, drive_left, periods, escapes, escape_started_s = self.recovery.state()
        return FollowCheckpoint(
            self.status, self.progress_index, self.progress.anchor, last, stalled, backing_up, backups, started_now,
            left, heading, drive_left, periods, escapes, self.replan_pending, self.blocked_why, escape_started_s,
        )  # fmt: skip

    def resume(self, path_xy_m: np.ndarray | None, free: FreeSpace | None, checkpoint: FollowCheckpoint) -> None:
        """Carry on from another planner's ``checkpoint`` on its path and grid (the contacts are set apart): the next
        ``update`` is the one that planner would have made."""
        c = checkpoint
        self.path, self.free = path_xy_m, free
        self.status, self.progress_index, self.progress.anchor = c.status, c.progress_index, c.progress_anchor
        self.stall.restore((c.stall_last, c.stalled_periods, c.backing_up, c.backups, c.last_started_now))
        self.recovery.restore((c.recoveries_left, c.escape_heading_rad, c.escape_drive_left_m, c.escape_periods, c.escapes, c.escape_started_s))
        self.replan_pending, self.blocked_why = c.replan_pending, c.blocked_why

    def remaining_path(self) -> np.ndarray:
        """The path still ahead (n x 2, metres) from the point the robot last progressed to; empty without a path."""
        if self.path is None:
            return np.zeros((0, 2))
        return self.path[self.progress_index :]

    def check_blocked(self, occupied: np.ndarray, geometry: GridGeometry, pose: Pose2D) -> bool:
        """Mark the path blocked when newly mapped obstacles cut it ahead (call after a map update).

        Path points within two robot radii of the robot are skipped: the robot is already there.
        """
        if self.path is None or self.status != PlannerStatus.FOLLOWING:
            return False
        if path_blocked_ahead(self.remaining_path(), pose, occupied, geometry, self.robot.radius_m):
            self.status = PlannerStatus.BLOCKED
            return True
        return False

    def _face_goal(self, pose: Pose2D, goal_xy_m: np.ndarray, to_goal_m: float) -> VelocityCommand | None:
        """At the goal, with a sensor narrower than ``face_goal_below_fov_deg``: the turn in place that brings the
        goal within FACE_GOAL_VIEW_FRACTION of the half field of view, or None when it is there already (or
        the goal is under the robot, where no heading looks at it). Bounded like any goal: the caller's
        re-decision timeout ends a turn that never gets there."""
        if not self.narrow_sensor() or to_goal_m < FACE_GOAL_MIN_DISTANCE_M:
            return None
        error = wrap_angle_rad(math.atan2(goal_xy_m[1] - pose.y_m, goal_xy_m[0] - pose.x_m) - pose.yaw_rad)
        if abs(error) <= FACE_GOAL_VIEW_FRACTION * self.sensor_fov_rad / 2:
            return None
        return VelocityCommand(0.0, math.copysign(self.robot.max_angular_radps, error))

    def update(self, pose: Pose2D, time_s: float, scan: LaserScan | None = None) -> FollowResult:
        """One control period: the command to send (within the robot's limits) and the resulting status. A pose
        or time that is not finite gives a stop and changes nothing (no progress judged, no stall counted)."""
        if not all(math.isfinite(v) for v in (pose.x_m, pose.y_m, pose.yaw_rad, time_s)):
            return FollowResult(VelocityCommand(0.0, 0.0), self.status, "bad_pose")
        result = self._guard_reverse(pose, self._update(pose, time_s, scan))
        result = dataclasses.replace(result, command=result.command.clamped(self.robot.max_linear_mps, self.robot.max_angular_radps))
        self.stall.record(pose, time_s, result.command)
        return result

    def _guard_reverse(self, pose: Pose2D, result: FollowResult) -> FollowResult:
        """A reverse command drives the body into space the LIMO's front LiDAR does not see: send it only
        when the map the path was planned on shows no obstacle, unknown cell or map edge in what the body (``planner.body``)
        sweeps behind it this period, and at least ``REVERSE_LOOKAHEAD_M`` (``FreeSpace.behind_is_clear``, as Nav2's
        BackUp checks its costmap); otherwise stop, and the progress checker ends the goal."""
        reverse_m = -result.command.linear_mps * self.robot.control_period_s
        if reverse_m <= 0 or self.free is None:
            return result
        disc_m = None if self.config.body == "box" else self.robot.disc_radius_m
        if self.free.behind_is_clear(pose, self.robot.length_m, self.robot.width_m, max(reverse_m, REVERSE_LOOKAHEAD_M), disc_m):
            return result
        return FollowResult(VelocityCommand(0.0, 0.0), result.status, "reverse_blocked")

    def _replan(self, pose: Pose2D) -> bool:
        """The path to the same goal from here on the planned-on grid less the contacts; False (``blocked``) when the
        contacts cut every way there. A path given without a grid (``set_path(free=None)``) has no contacts and
        nothing to re-plan on: it is kept, and the progress checker ends a goal the robot cannot get to."""
        assert self.path is not None
        if self.free is None:
            return True
        traversable = self.without_contacts(self.free.traversable, self.free.geometry)
        try:
            path = plan_path(traversable, self.free.geometry, pose.xy, self.path[-1])
        except NoPath as exc:
            self.blocked_why = str(exc)
            self.status = PlannerStatus.BLOCKED
            return False
        self.path, self.progress_index = path, 0
        self.free = dataclasses.replace(self.free, traversable=traversable)
        return True

    def _path_bearing_rad(self, pose: Pose2D) -> float:
        """The bearing from the robot to the path's lookahead point (not pulled back to keep a free line of sight)."""
        assert self.path is not None
        _, look = self.follower.lookahead_index(pose, self.path, self.progress_index)
        return math.atan2(self.path[look][1] - pose.y_m, self.path[look][0] - pose.x_m)

    def _update(self, pose: Pose2D, time_s: float, scan: LaserScan | None) -> FollowResult:
        stop = VelocityCommand(0.0, 0.0)
        if self.path is None or self.status != PlannerStatus.FOLLOWING:
            return FollowResult(stop, self.status)  # outcomes stick until the next goal
        goal = self.path[-1]
        to_goal = math.hypot(goal[0] - pose.x_m, goal[1] - pose.y_m)
        if to_goal <= self.goal_tolerance_m:
            turn = self._face_goal(pose, goal, to_goal)
            if turn is not None:
                return FollowResult(turn, self.status)  # still following: the goal is not in view yet
            self.status = PlannerStatus.REACHED
            return FollowResult(stop, self.status)
        if not self.progress.check(pose, time_s) and not self.recovery.start(pose, self._path_bearing_rad(pose), scan, self.sensor_fov_rad, time_s):
            self.status = PlannerStatus.NO_PROGRESS
            return FollowResult(stop, self.status)
        escape = self.recovery.command(pose, scan, time_s, self.stall.last)
        if escape is not None:
            return FollowResult(escape, self.status, "escape")
        backups = self.stall.backups
        backup = self.stall.command(pose, time_s)
        if backup is not None:
            if self.stall.backups > backups and self.narrow_sensor() and self.stall.last is not None:
                self.mark_contact(pose, self.stall.last[2].linear_mps > 0)
                self.replan_pending = True
            return FollowResult(backup, self.status, "backup")
        if self.replan_pending:
            self.replan_pending = False
            if not self._replan(pose):
                return FollowResult(stop, self.status)
        nearest, look = self.follower.lookahead_index(pose, self.path, self.progress_index, self.free)
        self.progress_index = nearest
        cmd = self.follower.command(pose, self.path, nearest, look, to_goal, scan)
        self.status = PlannerStatus.FOLLOWING
        # With the stall recovery off (stall_steps 0) no contact is kept: nothing would back up and re-plan round it.
        if cmd.linear_mps < 0.0 and self.narrow_sensor() and self.config.stall_steps > 0 and self.mark_unmapped_returns(pose, scan):
            backup = self.stall.back_up_now(pose, time_s)  # the follower's creep back would only rock the robot on the same return
            if backup is not None:
                self.replan_pending = True
                return FollowResult(backup, self.status, "backup")
        return FollowResult(cmd, self.status)
