"""Parameters of the MuJoCo LIMO simulator (defaults documented; YAML in ``configs/robot_sim.yaml``).

The robot's footprint and velocity limits come from ``cso_runtime.config.RobotConfig`` and the range
sensor from ``SensorConfig``, exactly as for the 2D simulator; this dataclass holds only what the
physics adds: time step, acceleration limits, watchdog, odometry drift, the LIMO's body and the walls.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from cso_runtime.config import (
    MAX_ROBOT_RADIUS_M,
    Bound,
    ConfigError,
    ExplorationConfig,
    RobotConfig,
    SensorConfig,
    check_bounds,
    seconds,
    with_mujoco_limo_defaults,
)

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


def through_wall_problem(sim: MujocoSimConfig, robot: RobotConfig, robot_key: str | None = "robot", exploration: ExplorationConfig | None = None) -> str | None:
    """Why walls may not stop ``robot`` at its top speed under ``sim`` (``MAX_SINK_OF_SIDE``: it travels too far within
    the contact's time constant, and so within a physics step), with values that work, or None. Checked where the
    MuJoCo LIMO's parameters meet the robot's (``simulator.mujoco_config``, ``MujocoSimulator``), before anything starts.
    The robot's keys are named under ``robot_key``, where the caller's user sets them (``simulator.MountSetting``: a
    profile's ``exploration.robot``); a top speed is suggested only where the whole exploration config ``robot`` is of
    takes it (``exploration``; None: ``ExplorationConfig``'s other sections), not one below the planner's
    ``backup_speed_mps``, which it refuses; none where ``robot_key`` is None (the caller fixes the robot: ``scenes
    --mjcf``'s LIMO, its keys named ``robot``)."""
    fixed = robot_key is None
    robot_key = robot_key or "robot"
    side_m = min(robot.length_m, robot.width_m)
    most_m = MAX_SINK_OF_SIDE * side_m
    v = robot.max_linear_mps
    if sim.contact_time_constant_s * v <= most_m * (1 + _WHOLE_STEPS_REL_TOL):
        return None
    side = f"{robot_key}.width_m" if robot.width_m <= robot.length_m else f"{robot_key}.length_m"
    softest_s = float(f"{most_m / v:.6g}")  # as said, so that the value said is the value taken (within the tolerance)
    finer = ""
    if 2 * sim.timestep_s > softest_s + 1e-12:  # the contact must stay two physics steps or more (``validate``'s rule)
        step = _coarsest_whole_timestep(sim, robot, softest_s)
        whole = f"the contact at least two physics steps; whole steps of {robot_key}.control_period_s and of odometry_rate_hz's period"
        finer = f" with timestep_s {step:.6g} s or finer ({whole})" if step else " with a finer timestep_s"
    slowest = float(f"{most_m / sim.contact_time_constant_s:.6g}")  # as said, as softest_s
    contact = f"contact_time_constant_s {softest_s:.6g} s or less{finer}"
    if fixed:  # no setting of the robot's to change: the contact (or the step) is the way out
        use = f"Use {contact}"
    elif _top_speed_taken(robot, slowest, exploration):
        use = f"Use {robot_key}.max_linear_mps {slowest:.6g} m/s or less, or {contact}"
    else:  # a top speed slow enough for these walls is one the rest of the config refuses (the planner's back-up speed)
        use = f"Use {contact} ({robot_key}.max_linear_mps {slowest:.6g} m/s, slow enough for walls this soft, is too slow for the exploration config)"
    return (
        f"contact_time_constant_s ({sim.contact_time_constant_s:g} s) x {robot_key}.max_linear_mps ({v:g} m/s) is "
        f"{sim.contact_time_constant_s * v:.3g} m, more than half the robot's smaller side ({side} {side_m:g} m: {most_m:.3g} m; "
        f"timestep_s ({sim.timestep_s:g} s) x it: {sim.timestep_s * v:.3g} m a physics step): at top speed the body sinks into "
        f"walls that soft and can pass through them. {use}"
    )


def _top_speed_taken(robot: RobotConfig, speed_mps: float, exploration: ExplorationConfig | None) -> bool:
    """Whether ``robot`` with top speed ``speed_mps`` passes the checks of the robot and of the whole exploration config
    (``exploration``, None: ``ExplorationConfig``'s other sections): the planner's back-up speed and progress need a
    speed at least theirs."""
    slower = dataclasses.replace(robot, max_linear_mps=speed_mps)
    try:
        slower.validate()
        dataclasses.replace(exploration or ExplorationConfig(), robot=slower).validate()
    except ConfigError:
        return False
    return True


def _coarsest_whole_timestep(sim: MujocoSimConfig, robot: RobotConfig, contact_s: float) -> float | None:
    """The coarsest physics step, as said (6 significant digits), that a contact of ``contact_s`` spans twice (as
    ``MujocoSimConfig.validate`` checks it) and that keeps the control period and the odometry period whole steps
    (``whole_steps``); None where none is at least ``MIN_TIMESTEP_S``. The value said, not the quotient it rounds: a step
    a hair above half the contact, or one that rounds up, is refused by the very check the message names."""
    first = max(1, math.floor(2 * robot.control_period_s / contact_s))
    for n in range(first, int(robot.control_period_s / MIN_TIMESTEP_S) + 1):
        timestep_s = float(f"{robot.control_period_s / n:.6g}")
        if 2 * timestep_s > contact_s + 1e-12:
            continue
        if _steps_if_whole(robot.control_period_s / timestep_s) is not None and _steps_if_whole(1.0 / (sim.odometry_rate_hz * timestep_s)) is not None:
            return timestep_s
    return None


def check_walls_hold(sim: MujocoSimConfig, robot: RobotConfig, robot_key: str | None = "robot", exploration: ExplorationConfig | None = None) -> None:
    """``through_wall_problem`` as a ConfigError."""
    if (problem := through_wall_problem(sim, robot, robot_key, exploration)) is not None:
        raise ConfigError(problem)


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


MIN_TIMESTEP_S = 1e-5
"""The finest physics step taken: 10 microseconds, already 25,000 steps for each 0.25 s control step (a finer one, typed
in other units, would not finish an episode)."""
MAX_TIMESTEP_S = 0.05
"""The coarsest physics step taken: in 50 ms the robot at ``robot.max_linear_mps``' largest, 5 m/s, moves 25 cm, through
a wall between two steps, so the step is bounded by the robot's top speed too (``MAX_SINK_OF_SIDE``); the control
period is the command's step, not this."""
MAX_SINK_OF_SIDE = 0.5
"""How far the robot may travel at its top speed within the walls' contact time constant (``contact_time_constant_s`` x
``robot.max_linear_mps``), as a fraction of its smaller side (``robot.length_m``, ``robot.width_m``): the walls hold
it (``through_wall_problem``). A contact is soft: a body driven into a wall sinks into it about 0.4 x that distance
before the wall stops it, and MuJoCo pushes a body that got past a wall's middle out on the far side. How thin the
wall is barely matters (a wall is one plan cell at the thinnest, 1 cm or less: the body's own size is what holds it
back). The LIMO (0.322 x 0.22 m) driven at 100 m/s2 and 10 kN into a 1 cm wall sank 0.16 m at 4 m/s with a 0.1 s
contact and went through at 5 m/s (at 3.3 m/s and more with the 0.05 s physics step that such a contact allows);
at half its width, 0.11 m (1.1 m/s with 0.1 s, 5 m/s with 0.02 s), it sank at most 5 cm, head-on or at an angle.
As the contact time constant is at least two physics steps, this bounds the distance travelled in one physics step
at top speed (``timestep_s`` x ``robot.max_linear_mps``) to a quarter of the smaller side too. The defaults (1 m/s,
10 ms) travel 1 cm."""
MAX_TIME_CONSTANT_S = 10.0
"""The slowest servo or contact time constant taken: a servo that takes longer than 10 s to follow a command, or a wall
as soft, is a value in other units (the defaults are 20 ms and 10 ms)."""
MAX_ACCEL_MPS2 = 100.0
"""The largest linear acceleration limit taken (about 10 g; the default is 2 m/s^2)."""
MAX_ANGULAR_ACCEL_RADPS2 = 1000.0
"""The largest angular acceleration limit taken (the default is 3 rad/s^2)."""
MAX_MASS_KG = 1000.0
"""The heaviest robot taken: a tonne, a ground robot for indoor scenes (the LIMO's is 4.8 kg)."""
MAX_FORCE_N = 10_000.0
"""The largest servo force taken: the grip of the heaviest robot, about ``MAX_MASS_KG`` x g."""
MAX_TORQUE_NM = 2 * MAX_MASS_KG * 9.81 * MAX_ROBOT_RADIUS_M
"""The largest yaw torque taken: twice the heaviest robot's grip at the largest robot radius."""
MAX_WALL_HEIGHT_M = 100.0
"""The tallest wall taken (the walls of an indoor scene; the default is 1 m)."""
MAX_FRICTION = 10.0
"""The largest sliding friction coefficient taken (the default is 0.3; rubber on concrete is about 1)."""
MAX_ODOMETRY_RATE_HZ = 1000.0
"""The fastest odometry rate taken (the default is 40 Hz); its period is whole physics steps besides."""
MAX_ODOMETRY_NOISE_FRAC = 1.0
"""The largest odometry drift taken as a fraction of each increment: an error as large as the increment itself."""

MUJOCO_SIM_BOUNDS: dict[str, Bound] = {
    "timestep_s": Bound(MIN_TIMESTEP_S, MAX_TIMESTEP_S, "s", why="MAX_TIMESTEP_S"),
    **seconds("watchdog_s", positive=True),
    "max_linear_accel_mps2": Bound(0.0, MAX_ACCEL_MPS2, "m/s2", low_open=True, why="MAX_ACCEL_MPS2"),
    "max_angular_accel_radps2": Bound(0.0, MAX_ANGULAR_ACCEL_RADPS2, "rad/s2", low_open=True, why="MAX_ANGULAR_ACCEL_RADPS2"),
    "actuator_time_constant_s": Bound(0.0, MAX_TIME_CONSTANT_S, "s", low_open=True, why="MAX_TIME_CONSTANT_S"),
    "contact_time_constant_s": Bound(0.0, MAX_TIME_CONSTANT_S, "s", low_open=True, why="MAX_TIME_CONSTANT_S"),
    "traction_force_n": Bound(0.0, MAX_FORCE_N, "N", low_open=True, why="the heaviest robot's grip: MAX_FORCE_N"),
    "yaw_torque_nm": Bound(0.0, MAX_TORQUE_NM, "N m", low_open=True, why="MAX_TORQUE_NM"),
    "wall_friction": Bound(0.0, MAX_FRICTION, why="MAX_FRICTION"),
    "wall_height_m": Bound(0.0, MAX_WALL_HEIGHT_M, "m", low_open=True, why="MAX_WALL_HEIGHT_M"),
    "mass_kg": Bound(0.0, MAX_MASS_KG, "kg", low_open=True, why="MAX_MASS_KG"),
    "body_height_m": Bound(0.0, 2 * MAX_ROBOT_RADIUS_M, "m", low_open=True, why="as robot.length_m: config.MAX_ROBOT_RADIUS_M x 2"),
    "wheelbase_m": Bound(0.0, 2 * MAX_ROBOT_RADIUS_M, "m", low_open=True, why="as robot.length_m: config.MAX_ROBOT_RADIUS_M x 2"),
    "track_m": Bound(0.0, 2 * MAX_ROBOT_RADIUS_M, "m", low_open=True, why="as robot.width_m: config.MAX_ROBOT_RADIUS_M x 2"),
    "wheel_radius_m": Bound(0.0, MAX_ROBOT_RADIUS_M, "m", low_open=True, why="config.MAX_ROBOT_RADIUS_M"),
    "lidar_height_m": Bound(0.0, 2 * MAX_ROBOT_RADIUS_M, "m", low_open=True, why="on the robot, as body_height_m"),
    "odometry_rate_hz": Bound(0.0, MAX_ODOMETRY_RATE_HZ, "Hz", low_open=True, why="MAX_ODOMETRY_RATE_HZ"),
    "odom_trans_noise_frac": Bound(0.0, MAX_ODOMETRY_NOISE_FRAC, why="MAX_ODOMETRY_NOISE_FRAC"),
    "odom_rot_noise_frac": Bound(0.0, MAX_ODOMETRY_NOISE_FRAC, why="MAX_ODOMETRY_NOISE_FRAC"),
    "odom_rot_per_trans_noise_radpm": Bound(0.0, 2 * math.pi, "rad/m", why="a turn per metre"),
}
"""``MujocoSimConfig``'s bounds, each checked by its ``validate`` before anything starts (``config.check_bounds``), as
``configs/robot_sim.yaml`` documents them; beside them the time constants are at least two physics steps,
``wheel_radius_m`` is below ``body_height_m`` and ``wall_height_m``, ``lidar_height_m`` below ``wall_height_m`` and the
odometry period whole physics steps; with the robot's parameters, walls stop it at top speed (``through_wall_problem``).
``lidar_mount_x_m`` must be the sensor's mount, which ``SensorConfig`` bounds."""


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
        check_bounds("", self, MUJOCO_SIM_BOUNDS)
        for name in ("actuator_time_constant_s", "contact_time_constant_s"):
            if getattr(self, name) < 2 * self.timestep_s - 1e-12:
                raise ConfigError(f"{name} must be at least two physics steps (timestep_s {self.timestep_s:g} s), got {getattr(self, name):g}")
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
        if not self.wheel_radius_m < self.wall_height_m:  # the body's box spans wheel_radius_m to body_height_m
            raise ConfigError(
                f"wall_height_m ({self.wall_height_m:g} m) must be above wheel_radius_m ({self.wheel_radius_m:g} m, where the "
                "body starts above the floor) or the robot drives over the walls its LiDAR sees"
            )
        if not self.lidar_height_m < self.wall_height_m:
            raise ConfigError(f"lidar_height_m ({self.lidar_height_m:g} m) must be below wall_height_m ({self.wall_height_m:g} m) or beams pass over the walls")
