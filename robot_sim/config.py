"""Parameters of the MuJoCo LIMO simulator (defaults documented; YAML in ``configs/robot_sim.yaml``).

The robot's footprint and velocity limits come from ``cso_runtime.config.RobotConfig`` and the range
sensor from ``SensorConfig``, exactly as for the 2D simulator; this dataclass holds only what the
physics adds: time step, acceleration limits, watchdog, odometry drift, the LIMO's body and the walls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cso_runtime.config import ConfigError, ExplorationConfig, SensorConfig, with_mujoco_limo_defaults

_WHOLE_STEPS_REL_TOL = 1e-5
"""A duration is a whole number of physics steps to this relative precision: a rate or step written to 6
significant digits (41.6667 Hz, 0.00333333 s, as the errors print them) counts as the whole number it rounds to."""


def _steps_if_whole(steps: float) -> int | None:
    """``steps`` as a whole number of physics steps (at least one), or None."""
    n = round(steps)
    return int(n) if n >= 1 and abs(steps - n) <= _WHOLE_STEPS_REL_TOL * n else None


def whole_steps(duration_s: float, timestep_s: float, what: str) -> int:
    """How many physics steps make ``duration_s``; a ConfigError when it is not a whole number of them (the
    control period against ``timestep_s``), said where the parameters are read, not when a world is built."""
    n = _steps_if_whole(duration_s / timestep_s)
    if n is None:
        raise ConfigError(f"{what} ({duration_s} s) must be a whole number of physics steps (timestep_s {timestep_s} s)")
    return n


def limo_sensor() -> SensorConfig:
    """The sensor of a ``MujocoSimulator`` given none, ``doctor``'s, ``scenes --mjcf``'s and the fake LIMO's: the default
    LiDAR where the LIMO carries it (0.103 m ahead), by the rule ``eval --sim mujoco`` and a MuJoCo profile follow."""
    return with_mujoco_limo_defaults(ExplorationConfig()).sensor


def lidar_mount_problem(given: object, sensor: SensorConfig) -> str | None:
    """Why ``lidar_mount_x_m: given`` cannot stand beside ``sensor``, or None (left out, or the sensor's own mount, as
    old configs repeat it): the rays are cast from ``sensor.mount_x_m``, which the mapper and the planner use too, so
    a second mount that disagrees would shift the map silently."""
    if given is None or (
        isinstance(given, (int, float)) and not isinstance(given, bool) and math.isclose(float(given), sensor.mount_x_m, abs_tol=1e-9)
    ):
        return None
    return f"lidar_mount_x_m: {given!r} is not the sensor's mount ({sensor.mount_x_m} m), which the mapper and the planner use"


@dataclass
class MujocoSimConfig:
    """Physics, control and odometry parameters of the MuJoCo LIMO."""

    timestep_s: float = 0.005
    """Physics step. The control period (RobotConfig.control_period_s, 0.25 s) must be a whole number of steps."""
    watchdog_s: float = 0.5
    """The base brakes to a stop when no command arrived for this long (simulated seconds), as the real LIMO's base
    does: the watchdog of a LIMO driven by commands as they come (``set_command`` with ``advance`` or ``RealTimePacer``,
    as ``python -m robot_sim.fake_limo`` drives it from ``cmd_vel``). Under ``up``'s sim service each control step sets
    the command anew, so it never fires there while it is at least ``robot.control_period_s`` (0.25 s; shorter, it
    brakes within every step); a stale command there is the service's ``cmd_timeout_s`` (wall clock) to stop
    (docs/runtime.md, Command watchdogs)."""
    max_linear_accel_mps2: float = 2.0
    """Linear acceleration limit of the command path (assumed; Nav2's DWB default is 2.5 m/s^2)."""
    max_angular_accel_radps2: float = 3.0
    """Angular acceleration limit of the command path (assumed; Nav2's DWB default is 3.2 rad/s^2)."""
    actuator_time_constant_s: float = 0.02
    """Time constant with which the base's velocity servos track the rate-limited command (assumed: a fast servo)."""
    traction_force_n: float = 38.0
    """Force limit of the planar servos: tyre grip, about 0.8 x 4.8 kg x g. A wall pushes back harder."""
    yaw_torque_nm: float = 6.0
    """Torque limit of the yaw servo (skid-steer turning grip; assumed, the manual gives none: with the body's 0.061 kg m^2
    yaw inertia it allows ~100 rad/s^2, far above the 3 rad/s^2 ramp, so only a wall's push-back makes it bind)."""
    wall_friction: float = 0.3
    """Sliding friction coefficient between the body and walls (a bumper scraping along a wall; assumed)."""
    contact_time_constant_s: float = 0.01
    """Stiffness of robot-wall contacts (MuJoCo solref time constant, at least two physics steps): a
    stiffer contact lets the body sink less into a wall it hits at full speed."""
    wall_height_m: float = 1.0
    """Height of the wall boxes built from occupied cells."""
    walls_boundary_only: bool = False
    """Build walls only from occupied cells 8-adjacent to free space (thick walls become hollow shells,
    which rays and the robot cannot tell apart from solid ones). Off by default: solid rectilinear walls
    merge into fewer boxes (Dungeon img_1: 22 solid vs 42 shell boxes); it helps for blobby walls."""
    mass_kg: float = 4.8
    """LIMO mass: the "dead load" of the AgileX LIMO user manual, section 1.3 Tech specifications
    (github.com/agilexrobotics/limo-doc), which also gives the 322 x 220 x 251 mm overall size (RobotConfig's
    length and width, ``body_height_m``), the 200 mm wheelbase, the 175 mm tread and the 1 m/s no-load top speed
    (RobotConfig.max_linear_mps). Only the mass and the yaw inertia of a solid box of that size act on the planar
    base (x, y, yaw joints)."""
    body_height_m: float = 0.251
    """LIMO overall height (body length and width come from RobotConfig)."""
    wheelbase_m: float = 0.200
    """Distance between front and rear axles (wheels are visual only)."""
    track_m: float = 0.175
    """Distance between left and right wheels (visual only)."""
    wheel_radius_m: float = 0.045
    """Wheel radius (visual only, assumed: the manual gives none); also where the body box starts above the floor
    (the manual's minimum ground clearance is 24 mm; neither acts on the planar base, whose floor does not collide)."""
    lidar_mount_x_m: float | None = None
    """Deprecated, kept so old configs load: the LiDAR sits at ``SensorConfig.mount_x_m`` (the LIMO's EAI X2L at
    0.103 m ahead of the centre: ``limo_sensor()``), one mount for the rays, the mapper and the planner. A value here
    must be that same mount; another is a ConfigError, never a second mount that disagrees."""
    lidar_height_m: float = 0.2
    """Height of the scan plane above the floor (below wall_height_m)."""
    odometry_rate_hz: float = 40.0
    """Rate at which odometry increments are measured (and drift noise is added): its period must be a whole
    number of physics steps (40 Hz = 5 steps of 5 ms), since the drift per increment makes the noise depend on it."""
    odom_trans_noise_frac: float = 0.0
    """Odometry drift: std of the position error of each increment, as a fraction of its length."""
    odom_rot_noise_frac: float = 0.0
    """Odometry drift: std of the heading error of each increment, as a fraction of its rotation."""
    odom_rot_per_trans_noise_radpm: float = 0.0
    """Odometry drift: std of the heading error of each increment per metre travelled."""

    def lidar_mount_for(self, sensor: SensorConfig) -> float:
        """Where the rays are cast from, ahead of the robot centre: the sensor's mount. A ConfigError where
        ``lidar_mount_x_m`` says another (``lidar_mount_problem``)."""
        if (problem := lidar_mount_problem(self.lidar_mount_x_m, sensor)) is not None:
            raise ConfigError(f"{problem}; set SensorConfig.mount_x_m instead, or leave lidar_mount_x_m out")
        return sensor.mount_x_m

    def validate(self) -> None:
        """Each message names the key as the config's own (``timestep_s``): ``from_dict`` puts where it sits in front
        (``services.sim.mujoco: ``, ``configs/robot_sim.yaml: ``)."""
        positive = (
            "timestep_s", "watchdog_s", "max_linear_accel_mps2", "max_angular_accel_radps2", "actuator_time_constant_s",
            "contact_time_constant_s", "traction_force_n", "yaw_torque_nm", "wall_height_m", "mass_kg", "body_height_m", "wheel_radius_m",
            "lidar_height_m", "odometry_rate_hz",
        )  # fmt: skip
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive")
        for name in ("wall_friction", "odom_trans_noise_frac", "odom_rot_noise_frac", "odom_rot_per_trans_noise_radpm"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must not be negative")
        for name in ("actuator_time_constant_s", "contact_time_constant_s"):
            if getattr(self, name) < 2 * self.timestep_s - 1e-12:
                raise ConfigError(f"{name} must be at least two physics steps")
        for name in ("wheelbase_m", "track_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive")
        if not self.wheel_radius_m < self.body_height_m:
            raise ConfigError(
                f"wheel_radius_m ({self.wheel_radius_m} m, the body's ground clearance) must be below "
                f"body_height_m ({self.body_height_m} m)"
            )
        steps = 1.0 / (self.odometry_rate_hz * self.timestep_s)
        if _steps_if_whole(steps) is None:
            near = 1.0 / (max(1, round(steps)) * self.timestep_s)
            raise ConfigError(
                f"odometry_rate_hz ({self.odometry_rate_hz:g} Hz) must be a whole number of physics steps per "
                f"tick (timestep_s {self.timestep_s:g} s gives {steps:.3g}); nearest such rate: {near:g} Hz"
            )
        if not self.lidar_height_m < self.wall_height_m:
            raise ConfigError("lidar_height_m must be below wall_height_m or beams pass over the walls")
