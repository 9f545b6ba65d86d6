"""Simulators behind one interface, and the fast 2D kinematic simulator used for eval and training.

The 2D simulator ray-casts the LiDAR on the ground-truth plan and integrates a unicycle for one
control period per ``step``; the MuJoCo LIMO (``robot_sim``) implements the same ``Simulator``
protocol with physics. Mapping, frontiers, policies and the planner never know which one runs.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from cso_runtime.config import ConfigError, ExplorationConfig, RobotConfig, SensorConfig, from_dict
from cso_runtime.geometry import LaserScan, Pose2D, VelocityCommand, returns_as_float32, wrap_angle_rad
from cso_runtime.raycast import cast_rays, ray_codes
from cso_runtime.scenes import FloorPlan, overlap_at_start_said

if TYPE_CHECKING:
    from robot_sim import MujocoSimConfig

log = logging.getLogger(__name__)


@runtime_checkable
class Simulator(Protocol):
    """A robot in a floor plan that takes velocity commands and returns scans."""

    plan: FloorPlan
    time_s: float

    def reset(self, seed: int | None = None) -> None:
        """Put the robot at the plan's start pose; re-seed noise."""

    def scan(self) -> LaserScan:
        """The latest range scan, in the sensor frame."""

    def odometry(self) -> Pose2D:
        """The robot's own pose estimate in the map frame (odometry starts at the start pose)."""

    def sensor_pose(self) -> Pose2D:
        """Pose of the range sensor according to odometry (where the mapper puts the scan)."""

    def true_pose(self) -> Pose2D:
        """Ground-truth pose: for evaluation only, never for the robot's decisions."""

    def step(self, command: VelocityCommand) -> None:
        """Apply ``command`` for one control period (0.25 s by default) and advance time."""


@runtime_checkable
class StateSaving(Protocol):
    """A simulator that can step ahead and undo it (``KinematicSimulator``; MuJoCo's cannot)."""

    def save_state(self) -> tuple:
        """Everything ``step`` and ``scan`` change."""

    def restore_state(self, state: tuple) -> None:
        """Back to what ``save_state`` returned."""


class WallClearance:
    """The 2D simulator's collision test: the exact distance from a point to a plan's nearest wall cell (cells are squares,
    cells outside the plan walls), up to 2 radii of its collision disc, and whether the disc round the point overlaps a
    wall (its clearance below its radius). One for the simulator's every substep (``KinematicSimulator.clearance_m``)
    and for the check of a start from the plan alone (``disc_start_overlap_said``)."""

    def __init__(self, plan: FloorPlan, radius_m: float) -> None:
        self.plan = plan
        self.radius_m = radius_m
        self._padded_walls: np.ndarray | None = None
        """The plan's walls padded by the window's half-width (made at the first call)."""

    def __call__(self, x_m: float, y_m: float) -> float:
        """Exact distance from (x, y) to the nearest wall cell, up to 2 radii (inf beyond). The window of cells around
        (x, y) is a slice of the plan's walls padded by its half-width."""
        g = self.plan.geometry
        r = int(np.ceil(2 * self.radius_m / g.resolution_m)) + 1
        # GridGeometry.world_to_cell of one point, in plain floats (the same division and floor).
        cy, cx = math.floor((y_m - g.origin_y_m) / g.resolution_m), math.floor((x_m - g.origin_x_m) / g.resolution_m)
        if self._padded_walls is None:
            self._padded_walls = np.pad(~self.plan.free, r, constant_values=True)
        if 0 <= cy < g.shape[0] and 0 <= cx < g.shape[1]:
            window = self._padded_walls[cy : cy + 2 * r + 1, cx : cx + 2 * r + 1]  # cells cy - r .. cy + r
        else:  # the robot's centre off the plan: every cell of the window outside it is a wall
            iy, ix = np.mgrid[cy - r : cy + r + 1, cx - r : cx + r + 1]
            window = ~g.in_bounds(iy, ix)
            window[~window] = ~self.plan.free[iy[~window], ix[~window]]
        wy, wx = np.divmod(np.flatnonzero(window), 2 * r + 1)
        if not len(wy):
            return math.inf
        return float(np.min(g.cell_gap_m(wy + (cy - r), wx + (cx - r), x_m, y_m)))

    def overlaps(self, x_m: float, y_m: float) -> bool:
        """Whether the disc round (x, y) shares some area with a wall cell: its clearance below its radius (a disc that
        only touches a wall's face overlaps none)."""
        return self(x_m, y_m) < self.radius_m


def disc_start_overlap_said(clearance: WallClearance) -> str | None:
    """The 2D simulator's warning of its collision disc (``robot.disc_radius_m``, ``clearance.radius_m``) overlapping a
    wall at the plan's start pose (``WallClearance.overlaps``, its own collision test), or None: what it logs at each
    reset (the run goes on, the robot moving only where that takes it no deeper into the wall) and ``up`` says before
    anything starts, from the plan alone (``Profile.start_overlap_said``; ``scenes.start_overlap_said`` is the MuJoCo
    LIMO's box)."""
    start = clearance.plan.start
    if not clearance.overlaps(start.x_m, start.y_m):
        return None
    body = f"the 2D simulator's collision disc (radius {clearance.radius_m:g} m)"
    return overlap_at_start_said(clearance.plan, body, "it can only move where that takes it no deeper into the wall")


class KinematicSimulator:
    """Fast 2D simulator: unicycle motion that stops at walls, LiDAR by ray casting the plan. The robot collides as a
    disc, ``robot.disc_radius_m`` (the LIMO's 0.12 m), the planner's ``body: disc``; planning inflates by more."""

    MIN_SUBSTEPS = 5
    """Substeps of a control step (the LIMO's: 5 cm each at its 1 m/s), or more where a substep at ``max_linear_mps``
    would be longer than the collision disc's radius (``substeps_for``)."""

    @staticmethod
    def substeps_for(robot: RobotConfig) -> int:
        """Substeps of ``robot``'s control step: enough that none at full speed is longer than ``robot.disc_radius_m``.
        A move is checked at its end only, so a longer one (a 1 s step at 5 m/s: 1 m in 5 substeps) jumped the disc
        over a wall thinner than the substep less its diameter, onto the floor behind it."""
        travel_m = robot.max_linear_mps * robot.control_period_s
        return max(KinematicSimulator.MIN_SUBSTEPS, math.ceil(travel_m / robot.disc_radius_m))

    def __init__(self, plan: FloorPlan, sensor: SensorConfig | None = None, robot: RobotConfig | None = None, seed: int | None = None) -> None:
        self.plan = plan
        self._ray_codes: np.ndarray | None = None
        """``raycast.ray_codes`` of the plan's walls (made at the first scan)."""
        self.sensor = sensor or SensorConfig()
        self.robot = robot or RobotConfig()
        self.collision_radius_m = self.robot.disc_radius_m
        self._clearance = WallClearance(plan, self.collision_radius_m)
        self.substeps = self.substeps_for(self.robot)
        n = max(1, int(round(self.sensor.fov_deg / self.sensor.resolution_deg)))
        fov = math.radians(self.sensor.fov_deg)
        inc = fov / n
        full_ring = self.sensor.fov_deg >= 360.0
        self._angle_min = -math.pi if full_ring else -fov / 2.0
        self._increment = inc
        self._n_beams = n if full_ring else n + 1
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)
        # The start's yaw in [-pi, pi), as every later one (a plan made in code may say 4 rad); one already there is kept
        # to the bit (wrapping moves its last bits).
        start = self.plan.start
        yaw_rad = start.yaw_rad if -math.pi <= start.yaw_rad < math.pi else wrap_angle_rad(start.yaw_rad)
        self._pose = Pose2D(start.x_m, start.y_m, yaw_rad)
        # As the MuJoCo LIMO logs its box's: in the words `up` says before anything starts (Profile.start_overlap_said).
        if (overlap := disc_start_overlap_said(self._clearance)) is not None:
            log.warning("%s", overlap)
        self.time_s = 0.0
        self.collisions = 0
        self._scan: tuple[Pose2D, LaserScan] | None = None
        """The scan of this step and the pose it was cast at, cast at the step's first ``scan()`` (None until then): a scan
        asked for again (the sim service re-publishing a step whose answer was lost) is the same one, not new noise that
        also shifts every later scan's. Another pose (a step, a restored state) casts anew."""

    def true_pose(self) -> Pose2D:
        return self._pose

    def save_state(self) -> tuple:
        """Everything ``step`` and ``scan`` change (pose, time, collision count, noise generator): a
        lockstep sim steps ahead on a provisional command and keeps or undoes it (``restore_state``)."""
        return self._pose, self.time_s, self.collisions, self.rng.bit_generator.state, self._scan

    def restore_state(self, state: tuple) -> None:
        self._pose, self.time_s, self.collisions, rng_state, self._scan = state
        self.rng.bit_generator.state = rng_state

    def odometry(self) -> Pose2D:
        return self._pose

    def sensor_pose(self) -> Pose2D:
        return self._pose.compose_offset(self.sensor.mount_x_m)

    def scan(self) -> LaserScan:
        """The scan at the pose of this step: cast (and its noise drawn) once per step, as the MuJoCo LIMO's."""
        if self._scan is None or self._scan[0] is not self._pose:
            self._scan = (self._pose, self._cast_scan())
        return self._scan[1]

    def _cast_scan(self) -> LaserScan:
        sp = self._pose.compose_offset(self.sensor.mount_x_m)
        rel = self._angle_min + self._increment * np.arange(self._n_beams)
        if self._ray_codes is None:
            self._ray_codes = ray_codes(self.plan.occupied)
        ranges = cast_rays(self.plan.occupied, self.plan.geometry, sp.xy, rel + sp.yaw_rad, self.sensor.range_max_m, self._ray_codes)
        if self.sensor.range_noise_std_m > 0:
            finite = np.isfinite(ranges)
            ranges[finite] += self.rng.normal(0.0, self.sensor.range_noise_std_m, int(finite.sum()))
            ranges[finite] = np.maximum(ranges[finite], 0.0)
        ranges32 = returns_as_float32(ranges, self.sensor.range_max_m)
        return LaserScan(self._angle_min, self._increment, self.sensor.range_min_m, self.sensor.range_max_m, ranges32, self.time_s)

    def clearance_m(self, x_m: float, y_m: float) -> float:
        """Exact distance from (x, y) to the nearest wall cell (``WallClearance``), up to 2 radii. Called on every substep."""
        return self._clearance(x_m, y_m)

    def overlaps_walls(self, x_m: float, y_m: float) -> bool:
        """Whether the collision disc round (x, y) is in contact (``WallClearance.overlaps``): what ``_can_move`` lets no
        move deepen."""
        return self._clearance.overlaps(x_m, y_m)

    def _can_move(self, clearance_now_m: float, x_m: float, y_m: float, nx_m: float, ny_m: float) -> tuple[bool, float]:
        """A move from (x, y) to (nx, ny) is allowed when the footprint stays clear of walls, or, for a robot already in
        contact, when it does not push further into them (so it can always back away); and never when its centre passes
        through a wall. Clearances at both ends that add up to more than the move prove the way clear (the clearance
        changes no faster than the centre moves); a robot in contact (a start next to a wall), whose end clearance need
        only match its small one, is checked cell by cell: it crossed a wall thinner than a substep less twice its
        clearance (a 2 cm cell's wall from 1 cm, with the LIMO's 5 cm substeps) onto the floor behind it."""
        c = self.clearance_m(nx_m, ny_m)
        if c < min(self.collision_radius_m, clearance_now_m):
            return False, c
        return clearance_now_m + c > math.hypot(nx_m - x_m, ny_m - y_m) or not self._crosses_wall(x_m, y_m, nx_m, ny_m), c

    def _crosses_wall(self, x_m: float, y_m: float, nx_m: float, ny_m: float) -> bool:
        """Whether the segment from (x, y) to (nx, ny) runs through a wall cell for some length (cells outside the plan
        are walls; along the edge between two wall cells is through the wall); touching one at a point is not (a robot
        at a wall's edge backs away from it)."""
        g = self.plan.geometry
        res = g.resolution_m
        y_lo, y_hi = sorted((y_m, ny_m))
        x_lo, x_hi = sorted((x_m, nx_m))
        iy, ix = np.mgrid[
            math.floor((y_lo - g.origin_y_m) / res) : math.floor((y_hi - g.origin_y_m) / res) + 1,
            math.floor((x_lo - g.origin_x_m) / res) : math.floor((x_hi - g.origin_x_m) / res) + 1,
        ]
        wall = ~g.in_bounds(iy, ix)
        wall[~wall] = ~self.plan.free[iy[~wall], ix[~wall]]
        if not wall.any():
            return False
        t_enter, t_exit = np.zeros(int(wall.sum())), np.ones(int(wall.sum()))
        for start, delta, low in ((x_m, nx_m - x_m, g.origin_x_m + ix[wall] * res), (y_m, ny_m - y_m, g.origin_y_m + iy[wall] * res)):
            if delta == 0.0:  # the segment within the cells' span on this axis throughout, or never
                inside = (low <= start) & (start <= low + res)
                t_exit = np.where(inside, t_exit, -1.0)
                continue
            t_a, t_b = (low - start) / delta, (low + res - start) / delta
            t_enter, t_exit = np.maximum(t_enter, np.minimum(t_a, t_b)), np.minimum(t_exit, np.maximum(t_a, t_b))
        return bool(np.any(t_enter < t_exit))

    def step(self, command: VelocityCommand) -> None:
        cmd = command.clamped(self.robot.max_linear_mps, self.robot.max_angular_radps)
        dt = self.robot.control_period_s / self.substeps
        x, y, yaw = self._pose.x_m, self._pose.y_m, self._pose.yaw_rad
        clearance = self.clearance_m(x, y)
        for _ in range(self.substeps):
            yaw_mid = yaw + 0.5 * cmd.angular_radps * dt
            nx, ny = x + cmd.linear_mps * dt * math.cos(yaw_mid), y + cmd.linear_mps * dt * math.sin(yaw_mid)
            if cmd.linear_mps != 0.0:
                ok, c = self._can_move(clearance, x, y, nx, ny)
                if ok:
                    x, y, clearance = nx, ny, c
                else:
                    self.collisions += 1
            yaw = wrap_angle_rad(yaw + cmd.angular_radps * dt)
        self._pose = Pose2D(x, y, yaw)
        self.time_s += self.robot.control_period_s


SIMULATORS = ("2d", "mujoco")


@dataclass(frozen=True)
class MountSetting:
    """Where the user of a command sets the sensor's mount, for the error that asks for it: a profile's key is
    ``exploration.sensor.mount_x_m``, eval's config's ``sensor.mount_x_m``; and the robot's keys, which the checks of
    the physics against the robot name (a profile's ``exploration.robot.max_linear_mps``, eval's ``robot.max_linear_mps``)."""

    key: str = "sensor.mount_x_m"
    """The dotted key of the sensor's mount in ``file``."""
    file: str = "the exploration config"
    command: str = ""
    """The command whose ``--set`` sets ``key`` too (``up``, ``eval``); empty: none."""
    robot_key: str = "robot"
    """The dotted key of the robot's section (``RobotConfig``) in ``file``."""

    def advice(self, value: object) -> str:
        flag = f" or with {self.command} --set {self.key}={value}" if self.command else ""
        return f"set {self.key}: {value} in {self.file}{flag} instead"


def mujoco_config(
    overrides: Mapping[str, Any] | None,
    sensor: SensorConfig,
    where: str = "mujoco",
    robot: RobotConfig | None = None,
    mount: MountSetting | None = MountSetting(),
    exploration: ExplorationConfig | None = None,
) -> MujocoSimConfig:
    """The MuJoCo LIMO's parameters: ``robot_sim``'s defaults with ``overrides`` on top (the keys of
    ``configs/robot_sim.yaml``: physics, odometry drift), its rays cast from the sensor's own mount, which the
    mapper and the planner use too (eval, the services and doctor give it the LIMO's 0.103 m unless a config
    sets it): one mount, not two that disagree. With ``robot``, its control period must be a whole number of
    physics steps, and walls must stop it at its top speed (``check_walls_hold``: a slower top speed is suggested only
    where ``exploration``, the whole config ``robot`` is of, takes it). Raises ConfigError naming ``where``, the robot's
    keys where the caller's user sets them (``mount.robot_key``) and, for another mount, how the caller's user sets the
    sensor's (``mount``; None: the caller fixes it, the key can only be left out, and the robot, whose top speed is then
    suggested nowhere)."""
    from robot_sim.config import MujocoSimConfig, check_walls_hold, lidar_mount_problem, whole_steps  # noqa: PLC0415 - MuJoCo only when asked for

    data = dict(overrides or {})
    given = data.pop("lidar_mount_x_m", None)
    if (problem := lidar_mount_problem(given, sensor)) is not None:
        instead = f"{mount.advice(given)} (or leave this key out)" if mount is not None else "the sensor's mount is fixed here: leave this key out"
        raise ConfigError(f"{where}.{problem}; {instead}")
    config = from_dict(MujocoSimConfig, data, where=where)
    if robot is not None:
        try:
            robot_key = mount.robot_key if mount is not None else None  # None: the caller fixes the robot too (scenes --mjcf: the LIMO's own)
            whole_steps(robot.control_period_s, config.timestep_s, f"{robot_key or MountSetting.robot_key}.control_period_s")
            check_walls_hold(config, robot, robot_key, exploration)  # not the body through walls too soft for its top speed, or between two physics steps
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    return config


def simulator_settings(name: str, sensor: SensorConfig, robot: RobotConfig, mujoco: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Every parameter of the simulator that ``make_simulator(name, ..., mujoco=mujoco)`` builds, as it runs them, units
    in the names: ``summary.json``'s ``meta.sim_settings`` (eval and ``up``), so that a results file says what produced
    it, defaults included. The MuJoCo LIMO's are every field of ``robot_sim.MujocoSimConfig``, ``lidar_mount_x_m``
    where its rays are cast from; the 2D simulator's, its collision disc (``robot.disc_radius_m``) and substeps. The robot and the sensor are
    the exploration config's (``meta.config``)."""
    if name == "mujoco":
        config = mujoco_config(mujoco, sensor, robot=robot)
        return {**dataclasses.asdict(config), "lidar_mount_x_m": config.lidar_mount_for(sensor)}
    if name == "2d":
        return {"collision_radius_m": robot.disc_radius_m, "substeps": KinematicSimulator.substeps_for(robot)}
    raise ValueError(f"unknown simulator {name!r}; choose one of {', '.join(SIMULATORS)}")


UP_WATCHDOG_ADVICE = "to stop a robot whose commands stop coming sooner, lower services.sim.cmd_timeout_s instead"
"""What ``up`` can tune in place of a short ``watchdog_s``: its sim service's stale-command timeout."""


def watchdog_within_a_step_said(
    settings: Mapping[str, Any],
    robot: RobotConfig,
    watchdog_key: str = "watchdog_s",
    period_key: str = "robot.control_period_s",
    advice: str = UP_WATCHDOG_ADVICE,
) -> str | None:
    """A warning where the MuJoCo LIMO's ``watchdog_s`` in ``settings`` (``simulator_settings``) is shorter than a control
    step: each step hands the simulator its command afresh, so the base would brake to a stop within every step,
    commands or not (docs/runtime.md, Command watchdogs); None where it is not (or the simulator has no watchdog).
    ``advice``: what the caller's user can change instead (eval has no sim service, so no ``cmd_timeout_s``)."""
    watchdog_s = settings.get("watchdog_s")
    if watchdog_s is None or watchdog_s >= robot.control_period_s:
        return None
    return (
        f"{watchdog_key} {watchdog_s:g} s is shorter than a control step ({period_key}, {robot.control_period_s:g} s): the MuJoCo "
        f"LIMO brakes to a stop within every step, commands or not, and the robot barely moves; {advice} (docs/runtime.md, Command watchdogs)"
    )


def make_simulator(
    name: str, plan: FloorPlan, sensor: SensorConfig, robot: RobotConfig, seed: int | None = None, mujoco: Mapping[str, Any] | None = None
) -> Simulator:
    """Simulator by name: ``2d`` (kinematic, fast) or ``mujoco`` (the physics LIMO in ``robot_sim``, with the
    ``mujoco_config`` of ``mujoco``: parameters over its defaults)."""
    if name == "2d":
        if mujoco:
            raise ConfigError(f"MuJoCo parameters ({', '.join(mujoco)}) need the mujoco simulator, not the 2d one")
        return KinematicSimulator(plan, sensor, robot, seed=seed)
    if name == "mujoco":
        from robot_sim import MujocoSimulator  # noqa: PLC0415 - MuJoCo only when asked for

        return MujocoSimulator(plan, sensor, robot, seed=seed, config=mujoco_config(mujoco, sensor, robot=robot))
    raise ValueError(f"unknown simulator {name!r}; choose one of {', '.join(SIMULATORS)}")
