"""Typed configuration: one dataclass per concern, each field with a default and a docstring.

YAML files in ``configs/`` and CLI flags fill the same dataclasses (``from_dict``); unknown keys are
an error, never silently ignored.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import math
import re
import tempfile
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml

from cso_runtime.geometry import MAX_RANGE_M

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")
"""A dataclass: what ``from_dict`` builds."""


class ConfigError(ValueError):
    """A configuration file or value is invalid."""


EXIT_BAD_CONFIG = 2
"""Exit code of a command or service that refuses its configuration. A launcher does not restart a
service that exits with it: the same configuration would fail the same way."""
EXIT_NO_ZENOH = 3
"""Exit code of a service or launcher that cannot open its Zenoh session (a router to join is unreachable):
a launcher restarts a service that exits with it, since the router may come up."""
EXIT_INTERRUPTED = 130
"""Exit code of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it)."""
EXIT_READER_GONE = 141
"""Exit code of a command whose output's reader left before its end (``runs | head -3``): 128 + SIGPIPE, as a
shell tool killed by SIGPIPE reports it."""
LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
"""Every process's log line (services, launcher, commands): ``cso-runtime logs`` merges the services' logs
by the time stamp in front."""


def number_said(value: float) -> str:
    """A bound or a value as an error says it: ``0.5``, ``3.14159``, ``1,000,000`` (a whole number with its commas)."""
    if isinstance(value, int) or (float(value).is_integer() and abs(value) < 1e15):
        return f"{int(value):,}"
    return f"{value:g}"


@dataclass(frozen=True)
class Bound:
    """The range a numeric configuration key takes, checked by its section's ``validate`` (``check_bounds``) before
    anything starts, so that 0, a negative value or an absurd one (a lookahead of 1e9 m, a length typed in
    millimetres) is refused naming the key, the value and the range, not run, nor failed deep inside a service."""

    low: float
    """The smallest value taken (``low_open``: the values above it)."""
    high: float
    """The largest value taken."""
    unit: str = ""
    """The key's unit as the error says it (``m``, ``s``), or none for a count."""
    low_open: bool = False
    """``low`` itself is refused: the key must be above it (a positive length)."""
    why: str = ""
    """Why ``high`` is the largest, said after the range (``a back-up is a short manoeuvre``)."""
    high_open: bool = False
    """``high`` itself is refused: the key must be below it (PPO's clip coefficient, below 1)."""

    def said(self) -> str:
        """The range in interval notation, with its unit: ``(0, 100] m``, ``[1, 1,000,000]``, ``(0, 1)``; one of no
        largest value (``high`` infinite) as its least: ``>= 0 s``, ``> 0 s``."""
        unit = f" {self.unit}" if self.unit else ""
        if math.isinf(self.high):
            return f"{'>' if self.low_open else '>='} {number_said(self.low)}{unit}"
        return f"{'(' if self.low_open else '['}{number_said(self.low)}, {number_said(self.high)}{')' if self.high_open else ']'}{unit}"

    def within(self) -> str:
        """``said`` after "must be": ``in (0, 100] m``, ``>= 0 s``."""
        return self.said() if math.isinf(self.high) else f"in {self.said()}"

    def problem(self, value: float) -> str | None:
        """Why ``value`` is outside the range, naming it and the range (``must be in (0, 100] m, got 1,000``), or None
        where it is inside. NaN is outside every range."""
        inside = (value > self.low if self.low_open else value >= self.low) and (value < self.high if self.high_open else value <= self.high)
        if inside:
            return None
        why = f" ({self.why})" if self.why else ""
        return f"must be {self.within()}{why}, got {number_said(value)}"

    def check(self, key: str, value: float) -> None:
        """ConfigError naming ``key``, ``value`` and the range when ``value`` is outside it."""
        if (problem := self.problem(value)) is not None:  # NaN included: from_dict refuses it already, a dataclass built in code may not
            raise ConfigError(f"{key} {problem}")


def check_bounds(section: str, obj: object, bounds: typing.Mapping[str, Bound]) -> None:
    """``bounds``' check of each of ``obj``'s keys it names (``section.key`` in the error): the one way a config
    section bounds its numbers (each section's table, e.g. ``PLANNER_BOUNDS``, documents them)."""
    for name, bound in bounds.items():
        bound.check(f"{section}.{name}" if section else name, getattr(obj, name))


MAX_WAIT_S = 86_400.0
"""The longest wait, period or timeout a service or the launcher takes, in seconds (a day): no timeout anyone means is
longer, and one much longer (1e300 s) overflowed Python's own waits (``threading.TIMEOUT_MAX``) deep inside a running
service, where it is refused before anything starts."""
MAX_PROCESSES = 1024
"""The most worker processes a command may start (``eval --workers``, ``collect-teacher --workers``, train's
``num_envs`` with ``async_envs``) and torch threads it may take: no machine has more cores."""
MAX_RESTARTS = 1000
"""The most restarts (a service's by the launcher, a helper process's by its service) a configuration may allow."""


def seconds(*names: str, positive: bool = False) -> dict[str, Bound]:
    """The bounds of time keys ``names`` (a service's waits, periods and timeouts): in [0, ``MAX_WAIT_S``] s, or above 0
    (``positive``)."""
    return {name: Bound(0.0, MAX_WAIT_S, "s", low_open=positive, why="a day: config.MAX_WAIT_S") for name in names}


LIDAR_FOVS_DEG = (180.0, 360.0)
"""The LiDAR fields of view ``eval --lidar-fov`` runs, in degrees: the LIMO's EAI X2L and a full ring (the tables'),
the sensors weights ship for; ``train``'s ``lidar_fov_deg`` takes these alone, so that its weights can be evaluated."""
LIDAR_FOVS_SAID = " or ".join(f"{fov:g}" for fov in LIDAR_FOVS_DEG)
"""``LIDAR_FOVS_DEG`` as the errors say them: ``180 or 360``."""


MAX_SENSOR_RATE_HZ = 1000.0
"""The fastest scan rate taken: no planar LiDAR or depth camera scans faster (the LIMO's EAI X2L scans at 8 Hz)."""

SENSOR_BOUNDS: dict[str, Bound] = {
    "fov_deg": Bound(0.0, 360.0, "degrees", low_open=True),
    "range_max_m": Bound(0.0, MAX_RANGE_M, "m", low_open=True, why="a scan's longest: geometry.MAX_RANGE_M"),
    "range_noise_std_m": Bound(0.0, MAX_RANGE_M, "m", why="a scan's longest: geometry.MAX_RANGE_M"),
    "rate_hz": Bound(0.0, MAX_SENSOR_RATE_HZ, "Hz", low_open=True, why="no planar range sensor scans faster"),
}
"""``SensorConfig``'s bounds; beside them ``resolution_deg`` is in (0, ``fov_deg``], ``range_min_m`` in [0,
``range_max_m``), and a scan's beams (``fov_deg / resolution_deg``) are at most ``messages.MAX_BEAMS``."""


@dataclass
class SensorConfig:
    """Planar range sensor. Defaults are the LIMO's EAI X2L LiDAR (front 180 degrees, 0.1-8 m)."""

    fov_deg: float = 180.0
    """Field of view centred on the robot's heading, degrees (360 for a full ring)."""
    resolution_deg: float = 1.0
    """Angle between beams, degrees."""
    range_min_m: float = 0.1
    """Closer returns are invalid."""
    range_max_m: float = 8.0
    """Beams with no return within this range report inf and clear free space up to it (at most ``MAX_RANGE_M``, 1 km)."""
    range_noise_std_m: float = 0.0
    """Gaussian range noise of the simulated sensor."""
    rate_hz: float = 8.0
    """Scan rate of the real sensor: the MuJoCo LIMO fires its LiDAR at it; the 2D simulator scans once per control step."""
    mount_x_m: float = 0.0
    """Sensor position ahead of the robot centre (the LIMO's LiDAR sits at 0.103 m); on the robot: at most half of
    ``robot.length_m`` (or ``robot.radius_m``) either way."""

    @staticmethod
    def preset(name: str, fov_deg: float | None = None) -> SensorConfig:
        """Named presets: ``lidar`` (EAI X2L) and ``depth`` (LIMO depth camera seen as a 2D scan)."""
        if name == "lidar":
            cfg = SensorConfig()
        elif name == "depth":
            cfg = SensorConfig(fov_deg=79.0, resolution_deg=0.5, range_min_m=0.3, range_max_m=3.0, rate_hz=15.0)
        else:
            raise ConfigError(f"unknown sensor preset {name!r}; choose lidar or depth")
        if fov_deg is not None:
            cfg.fov_deg = float(fov_deg)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        check_bounds("sensor", self, SENSOR_BOUNDS)
        if not 0 < self.resolution_deg <= self.fov_deg:
            raise ConfigError(f"sensor.resolution_deg must be in (0, fov_deg {self.fov_deg:g}] degrees, got {self.resolution_deg:g}")
        if not 0 <= self.range_min_m < self.range_max_m:
            raise ConfigError(f"sensor.range_min_m must be in [0, range_max_m {self.range_max_m:g}) m, got {self.range_min_m:g}")
        from cso_runtime.messages import MAX_BEAMS  # noqa: PLC0415  (messages imports this module)

        beams = self.fov_deg / self.resolution_deg  # infinite for a resolution of 5e-324: no round() of it
        if not (math.isfinite(beams) and round(beams) <= MAX_BEAMS):  # each scan would allocate them all
            said = f"{round(beams):,}" if math.isfinite(beams) else "infinitely many"
            raise ConfigError(
                f"sensor.resolution_deg must be at least {self.fov_deg / MAX_BEAMS:g} degrees for a {self.fov_deg:g}-degree field of view "
                f"(at most {MAX_BEAMS:,} beams a scan: messages.MAX_BEAMS), got {self.resolution_deg:g}: {said} beams"
            )


MAX_ROBOT_RADIUS_M = 2.0
"""The largest inflation radius taken: a ground robot for indoor scenes, not a car."""


ROBOT_LIMITS: dict[str, tuple[float, str, str]] = {
    "length_m": (2 * MAX_ROBOT_RADIUS_M, "m", "millimetres"),
    "width_m": (2 * MAX_ROBOT_RADIUS_M, "m", "millimetres"),
    "max_linear_mps": (5.0, "m/s", "mm/s or km/h"),
    "max_angular_radps": (2 * math.pi, "rad/s", "degrees per second"),
    "control_period_s": (5.0, "s", "milliseconds"),
}
"""``RobotConfig``'s largest values taken (an indoor ground robot, as ``MAX_ROBOT_RADIUS_M``), each with its unit and the
unit a value above it was most likely typed in: the LIMO's width as 220 (mm), its turn rate as 45 (degrees per
second) or its step as 250 (ms) ran an episode of a 220 m robot, a 45 rad/s turn or 250 s steps."""


@dataclass
class RobotConfig:
    """The AgileX LIMO in differential (skid-steer) mode."""

    radius_m: float = 0.2
    """Obstacles are inflated by this radius before planning (circumscribes the LIMO's footprint)."""
    length_m: float = 0.322
    """Body length (LIMO), used for the clearance ahead."""
    width_m: float = 0.220
    """Body width (LIMO), used for the clearance ahead and, as ``disc_radius_m``, the 2D simulator's collisions."""
    max_linear_mps: float = 1.0
    """Top linear speed."""
    max_angular_radps: float = 0.78
    """Top turn rate."""
    control_period_s: float = 0.25
    """One step: the period of one velocity command."""

    @property
    def disc_radius_m(self) -> float:
        """The body as a disc, half ``width_m`` plus 1 cm (0.12 m for the LIMO): the 2D simulator's robot collides
        as this disc, and the planner's ``body: disc`` keeps it off scanned returns; one radius for both."""
        return 0.5 * self.width_m + 0.01

    def validate(self) -> None:
        if not 0 <= self.radius_m <= MAX_ROBOT_RADIUS_M:
            raise ConfigError(f"robot.radius_m must be from 0 to {MAX_ROBOT_RADIUS_M:g} m (the LIMO's is 0.2), got {self.radius_m}")
        for name in ("length_m", "width_m", "max_linear_mps", "max_angular_radps", "control_period_s"):
            if not 0 < getattr(self, name) < math.inf:
                raise ConfigError(f"robot.{name} must be positive and finite, got {getattr(self, name):g}")
        limo = RobotConfig()
        for name, (most, unit, other_unit) in ROBOT_LIMITS.items():
            if (value := getattr(self, name)) > most:
                what = f"{most:.3g} {unit}" + (" (one turn a second; the LIMO's is" if name == "max_angular_radps" else " (the LIMO's is")
                raise ConfigError(f"robot.{name} must be at most {what} {getattr(limo, name):g}), got {value:g}: a value in {other_unit}?")


@dataclass
class MappingConfig:
    """How the occupancy map M_t is built from scans (the same in ``eval``, training and the mapper service)."""

    footprint_clearing: bool = True
    """Cells under the robot's body (``robot.length_m`` x ``robot.width_m`` around its centre) that no scan has
    seen are marked free after each scan: the robot stands there, so they are open (Nav2's obstacle layer
    clears its footprint the same way). Without it a sensor mounted ahead of the centre with a narrow field
    of view (the depth camera) never sees the cells under and behind the centre, and they stay frontiers at
    the robot's own position that no turn can observe. Cells already seen are left as they are."""


def map_length(unit: str = "m", low_open: bool = False) -> Bound:
    """A length, or an area, on the map: at least 0 (above it: ``low_open``), at most ``messages.MAX_GRID_SIDE_M`` (its
    square for an area). A function, not a table: ``messages`` imports this module."""
    from cso_runtime.messages import MAX_GRID_SIDE_M  # noqa: PLC0415  (messages imports this module)

    if unit == "m2":
        return Bound(0.0, MAX_GRID_SIDE_M**2, "m2", low_open, why="the largest area a map may have: messages.MAX_GRID_SIDE_M squared")
    return Bound(0.0, MAX_GRID_SIDE_M, "m", low_open, why="the longest side a map may have: messages.MAX_GRID_SIDE_M")


def frontier_bounds() -> dict[str, Bound]:
    """``FrontierConfig``'s bounds: lengths on the map (a longer one is longer than any map: no cluster is that long,
    every window the whole map)."""
    return {"min_cluster_size_m": map_length(), "entropy_window_m": map_length(low_open=True)}


@dataclass
class FrontierConfig:
    """Frontier extraction and the frontier-based entropy of Eq. 4."""

    min_cluster_size_m: float = 0.3
    """Frontier clusters shorter than this (cells x resolution) are ignored as noise."""
    entropy_window_m: float = 2.0
    """gamma of Eq. 4: side of the square window in which frontier cells are counted. The paper does
    not publish its value; 2 m is roughly a room's half width for the LIMO. At most ``messages.MAX_GRID_SIDE_M`` (as
    ``min_cluster_size_m``): a longer one is longer than any map."""

    def validate(self) -> None:
        check_bounds("frontier", self, frontier_bounds())


STUCK_AVOID = ("positions", "goals")
MASK_CONFLICT = ("distance", "stuck")
"""``MaskConfig.stuck_avoid``'s values."""


def mask_bounds() -> dict[str, Bound]:
    """``MaskConfig``'s bounds: distances and areas on the map, each at least 0 and at most the largest a map may have
    (``beta_near_m < beta_far_m`` is checked beside them)."""
    return {"beta_near_m": map_length(), "beta_far_m": map_length(), "alpha1_m": map_length(), "alpha2_m2": map_length("m2"), "alpha3_m": map_length()}


@dataclass
class MaskConfig:
    """Action masks of section 3.3. Defaults are the paper's values, read as metres and square metres,
    except ``beta_far_m`` (chosen on a development set of training plans; docs/experiments/learned-policy.md,
    "The valid distance mask's far bound")."""

    use_valid_distance: bool = True
    """Apply the valid distance mask (Eq. 5)."""
    beta_near_m: float = 0.2
    """Frontiers geodesically closer than this are masked (first fallback drops this bound)."""
    beta_far_m: float = 1.5
    """Frontiers geodesically farther than this are masked (second fallback drops this bound). The paper's
    value read as metres is 2.0; 1.5 was chosen on 100 held-out training plans: with the shipped weights
    (trained under 2.0, ``train``'s own ``beta_far_m``) it explores about 5 % more area per step on large
    validation plans, as much as 2.0 on super-large ones, about 3.5 % less on generated middle scenes seen
    with a 360-degree LiDAR (docs/experiments/learned-policy.md, "The valid distance mask's far bound")."""
    use_stuck: bool = True
    """Apply the stuck mask (Algorithm 1)."""
    alpha1_m: float = 1.0
    """Stuck when the longest move between the last 3 decisions is below this ..."""
    alpha2_m2: float = 1.0
    """... and the largest explored-area gain between them is below this."""
    alpha3_m: float = 1.0
    """When stuck, goals closer than this to any of the last 3 reference points (``stuck_avoid``) are masked."""
    stuck_avoid: str = "positions"
    """What Algorithm 1 keeps the new goal away from when stuck: ``positions``, where the robot stood at the
    last 3 decisions (every table of BENCHMARKS.md and every shipped weights file), or ``goals``, the last 3
    goals chosen, the paper's literal reading ("the distance from the candidate actions to the past 3
    long-term goals"). The two agree when each goal was reached; a stuck robot has not reached them."""
    conflict: str = "distance"
    """When the stuck mask leaves none of the valid distance mask's goals (the paper does not say):
    ``distance`` drops the stuck mask and keeps Eq. 5's choice (every table of BENCHMARKS.md and every shipped
    weights file); ``stuck`` keeps the stuck mask and lets Eq. 5's fallbacks widen the range over the goals
    it leaves (nearer than beta_near, then farther than beta_far), dropping it only when it leaves none at all."""

    def validate(self) -> None:
        check_bounds("masks", self, mask_bounds())
        if not 0 <= self.beta_near_m < self.beta_far_m:
            raise ConfigError(f"masks need 0 <= beta_near_m < beta_far_m, got beta_near_m {self.beta_near_m:g} and beta_far_m {self.beta_far_m:g}")
        if self.stuck_avoid not in STUCK_AVOID:
            raise ConfigError(f"masks.stuck_avoid must be one of {', '.join(STUCK_AVOID)}, not {self.stuck_avoid!r}")
        if self.conflict not in MASK_CONFLICT:
            raise ConfigError(f"masks.conflict must be one of {', '.join(MASK_CONFLICT)}, not {self.conflict!r}")


MAX_EPISODE_STEPS = 1_000_000
"""The most ``episode.max_steps`` may be (69 hours of 0.25 s steps, 28 of a 10 Hz LiDAR's): it bounds the arrays of one
entry per step or decision on the wire (``messages.MAX_STEP_POINTS``), so a receiver can refuse a record that declares
more before inflating it."""


MAX_DONE_UNEXPLORED_M2 = 1_000_000.0
"""The most ``episode.done_unexplored_m2`` may be: a square kilometre, 300 times the largest shipped scene (64 x 48 m);
more leaves the coverage alone to end an episode."""

EPISODE_BOUNDS: dict[str, Bound] = {
    "max_steps": Bound(1, MAX_EPISODE_STEPS, why="an episode's result must fit its message: MAX_EPISODE_STEPS"),
    "replan_every_steps": Bound(1, MAX_EPISODE_STEPS, why="at most the longest episode: MAX_EPISODE_STEPS"),
    "done_coverage_pct": Bound(0.0, 100.0, "%", low_open=True),
    "done_unexplored_m2": Bound(0.0, MAX_DONE_UNEXPLORED_M2, "m2", why="a square kilometre: MAX_DONE_UNEXPLORED_M2"),
}
"""``EpisodeConfig``'s bounds (``goal_tolerance_m`` is a length on the map: in (0, ``messages.MAX_GRID_SIDE_M``])."""


def check_max_steps(steps: int, name: str = "episode.max_steps") -> None:
    """``episode.max_steps``' bound checked on a step limit given elsewhere (``name``: the gymnasium env's keyword)."""
    EPISODE_BOUNDS["max_steps"].check(name, steps)


@dataclass
class EpisodeConfig:
    """How an exploration episode runs and ends (section 4.1)."""

    max_steps: int = 3000
    """Hard step limit."""
    replan_every_steps: int = 25
    """A new long-term goal is chosen at least this often."""
    goal_tolerance_m: float = 0.3
    """The goal counts as reached within this distance (at most ``messages.MAX_GRID_SIDE_M``, the longest side a map may have)."""
    done_coverage_pct: float = 99.0
    """Done when coverage is above this ..."""
    done_unexplored_m2: float = 1.0
    """... and less than this much traversable area is unexplored."""

    def validate(self) -> None:
        check_bounds("episode", self, EPISODE_BOUNDS)
        # Farther than any map: every goal reached where it is chosen.
        map_length(low_open=True).check("episode.goal_tolerance_m", self.goal_tolerance_m)


BODIES = ("disc", "box")
"""``PlannerConfig.body``: the shapes the controller can keep off obstacles."""

LIMO_BODY = "box"
"""The MuJoCo LIMO's and the real LIMO's body for ``PlannerConfig.body``."""

LIMO_LIDAR_MOUNT_X_M = 0.103
"""Where the LIMO's EAI X2L sits ahead of the robot centre (the MuJoCo model mounts it there)."""


MAX_PLANNER_DISTANCE_M = 100.0
"""The longest of the local planner's own distances (lookahead, slow-down and stop clearance, progress): it follows a
path within sight of the robot, and 100 m is longer than any shipped scene (the largest, 64 x 48 m); a length typed in
millimetres or centimetres (500 for 0.5 m) is above it."""
MAX_RECOVERY_DISTANCE_M = 5.0
"""The longest back-up or escape drive of a recovery (Nav2's BackUp default is 0.15 m): a short manoeuvre, partly blind
(the back-up drives only where the map the path was planned on is free)."""
MAX_PROGRESS_WINDOW_S = 3600.0
"""The longest progress-check window (Nav2's default is 10 s): an hour, beyond it the check never fires; a value in
milliseconds (10000 for 10 s) is above it."""
MAX_RECOVERY_COUNT = 1000
"""The most control periods of a stall (``stall_steps``), or recoveries per goal (``progress_recoveries``), taken: 1000
periods are 250 s of the LIMO pinned; 0 turns either off."""

PLANNER_BOUNDS: dict[str, Bound] = {
    "lookahead_m": Bound(0.0, MAX_PLANNER_DISTANCE_M, "m", low_open=True, why="the local planner's longest distance: MAX_PLANNER_DISTANCE_M"),
    "rotate_in_place_rad": Bound(0.0, math.pi, "rad", low_open=True),
    "slow_down_distance_m": Bound(0.0, MAX_PLANNER_DISTANCE_M, "m", why="the local planner's longest distance: MAX_PLANNER_DISTANCE_M"),
    "stop_distance_m": Bound(0.0, MAX_PLANNER_DISTANCE_M, "m", why="the local planner's longest distance: MAX_PLANNER_DISTANCE_M"),
    "progress_required_m": Bound(0.0, MAX_PLANNER_DISTANCE_M, "m", why="the local planner's longest distance: MAX_PLANNER_DISTANCE_M"),
    "progress_window_s": Bound(0.0, MAX_PROGRESS_WINDOW_S, "s", low_open=True, why="an hour: MAX_PROGRESS_WINDOW_S"),
    "face_goal_below_fov_deg": Bound(0.0, 360.0, "degrees"),
    "stall_steps": Bound(0, MAX_RECOVERY_COUNT, why="0 turns it off: MAX_RECOVERY_COUNT"),
    "backup_distance_m": Bound(0.0, MAX_RECOVERY_DISTANCE_M, "m", low_open=True, why="a short manoeuvre: MAX_RECOVERY_DISTANCE_M"),
    "backup_speed_mps": Bound(0.0, ROBOT_LIMITS["max_linear_mps"][0], "m/s", low_open=True, why="and at most robot.max_linear_mps"),
    "progress_recoveries": Bound(0, MAX_RECOVERY_COUNT, why="0 turns it off: MAX_RECOVERY_COUNT"),
    "escape_distance_m": Bound(0.0, MAX_RECOVERY_DISTANCE_M, "m", low_open=True, why="a short manoeuvre: MAX_RECOVERY_DISTANCE_M"),
}
"""``PlannerConfig``'s bounds, each key's own (``stop_distance_m <= slow_down_distance_m`` and, with the robot, the
back-up speed and the progress the robot can make are checked beside them)."""


@dataclass
class PlannerConfig:
    """Local planner: path following with pure pursuit and a Nav2-style progress checker."""

    lookahead_m: float = 0.5
    """Pure-pursuit lookahead distance along the path."""
    rotate_in_place_rad: float = 0.9
    """Rotate in place when the heading error to the lookahead point exceeds this (or pi / 2, whichever is less:
    pure pursuit towards a point behind the robot drives away from it, ``planner.PURSUIT_MAX_HEADING_ERROR_RAD``)."""
    slow_down_distance_m: float = 0.5
    """Scale speed down when the nearest obstacle in the robot's path is closer than this to its front."""
    stop_distance_m: float = 0.03
    """Stop forward motion when an obstacle in the robot's path is closer than this to its front."""
    progress_required_m: float = 0.5
    """no_progress is reported when the robot moved less than this ..."""
    progress_window_s: float = 10.0
    """... within this much time."""
    face_goal_below_fov_deg: float = 180.0
    """With a sensor narrower than this (the 79-degree depth camera), turn in place at the goal until the goal
    is well inside the field of view before reporting ``reached``, so that a frontier goal beside or behind the
    robot is looked at before it is judged unobservable (without it the depth camera could mark every frontier
    near the start dead and end an episode at 12 % coverage). 0 turns it off; 360 turns it on for the LIMO's
    180-degree LiDAR too, where it changed most episodes (BENCHMARKS.md) and is off by default."""
    stall_steps: int = 4
    """Nav2's BackUp recovery: when this many control periods in a row each moved the robot less than a
    quarter of what their commands asked (pinned on a wall's corner, which the MuJoCo LIMO can be after
    sliding on from full speed), it backs straight up ``backup_distance_m`` before following on (as odometry and the
    real time since it started count it, not control periods), and only while the map the path was planned on shows
    no obstacle, unknown cell or map edge in what the body sweeps behind it (``LocalPlanner`` stops a reverse command
    otherwise). A period that asked to drive is judged by its drive
    alone, whatever its turn did (how far it got along the headings the body had: a body pressed on a wall that
    slides along it counts only its share ahead); a turn in place by its turn. With a sensor narrower than
    ``face_goal_below_fov_deg`` (the depth camera) the cells the pinned body touches become obstacles of the
    planner's grid for the rest of the episode, and the path is planned again round them after the back-up; so do
    returns nearer than the sensor's ``range_min`` (which the mapper leaves out) that block the way ahead, and the
    robot backs up from them at once instead of creeping back and driving in again.
    0 turns it off."""
    backup_distance_m: float = 0.15
    """How far the stall recovery backs up (Nav2's default ``backup_dist``)."""
    backup_speed_mps: float = 0.15
    """How fast it backs up, and how fast the progress recovery drives."""
    progress_recoveries: int = 1
    """Nav2's recovery before a goal is given up: this many times per goal, a failed progress check (the robot
    rocking back and forth where its path clips a wall's corner, the controller's back-off and pure pursuit undoing
    each other) first turns the robot to the open heading nearest the path's bearing and drives it
    ``escape_distance_m`` along it, then follows the path again; the next failure reports ``no_progress``. Open means
    clear of every scanned return for the body's sweep, within the sensor's field of view less 45 degrees each side, so a
    sensor of 90 degrees or less (the depth camera) never has one and its goals end as before. 0 turns it off."""
    escape_distance_m: float = 0.25
    """How far the progress recovery drives along the open heading."""
    body: str = "disc"
    """The body the controller keeps ``stop_distance_m`` off scanned obstacles: ``disc`` (half the robot's width plus
    1 cm, the 2D simulator's robot, whose collisions are those of that disc) or ``box`` (``length_m`` x ``width_m``,
    the LIMO itself: 4 cm longer at the front than the disc). The slow-down is the disc's sweep either way.
    ``eval --sim mujoco``, a profile whose sim is the MuJoCo LIMO, and the ``limo-ros2`` profile use ``box``."""

    def validate(self) -> None:
        check_bounds("planner", self, PLANNER_BOUNDS)
        if not self.stop_distance_m <= self.slow_down_distance_m:
            raise ConfigError(
                f"planner needs 0 <= stop_distance_m <= slow_down_distance_m, got stop_distance_m {self.stop_distance_m:g} and slow_down_distance_m {self.slow_down_distance_m:g}"
            )
        if self.body not in BODIES:
            raise ConfigError(f"planner.body must be one of {', '.join(BODIES)}, got {self.body!r}")


@dataclass
class ExplorationConfig:
    """Everything an exploration episode needs, in one place."""

    sensor: SensorConfig = field(default_factory=SensorConfig)
    """The planar range sensor (``SensorConfig``)."""
    robot: RobotConfig = field(default_factory=RobotConfig)
    """The robot's footprint, velocity limits and control period (``RobotConfig``)."""
    mapping: MappingConfig = field(default_factory=MappingConfig)
    """How scans build the occupancy map (``MappingConfig``)."""
    frontier: FrontierConfig = field(default_factory=FrontierConfig)
    """Frontier clusters and the entropy window of Eq. 4 (``FrontierConfig``)."""
    masks: MaskConfig = field(default_factory=MaskConfig)
    """The action masks of section 3.3 (``MaskConfig``)."""
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    """Step limit, replanning and the end of an episode (``EpisodeConfig``)."""
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    """The local planner: pure pursuit, clearance, progress and recoveries (``PlannerConfig``)."""

    def validate(self) -> None:
        """What no section can check alone: the sensor on the robot, the planner's moves against the robot's limits."""
        on_robot_m = max(self.robot.length_m / 2, self.robot.radius_m)
        if abs(self.sensor.mount_x_m) > on_robot_m:
            raise ConfigError(
                f"sensor.mount_x_m ({self.sensor.mount_x_m} m) puts the sensor off the robot, more than {on_robot_m:g} m from its centre "
                f"(half of robot.length_m, or robot.radius_m): the LIMO's LiDAR sits at {LIMO_LIDAR_MOUNT_X_M:g} m"
            )
        v_max = self.robot.max_linear_mps
        if self.planner.backup_speed_mps > v_max:
            raise ConfigError(
                f"planner.backup_speed_mps ({self.planner.backup_speed_mps} m/s) must not exceed robot.max_linear_mps ({v_max} m/s): "
                "the driver would clamp the back-up and it would back up short of backup_distance_m"
            )
        if self.planner.progress_required_m > v_max * self.planner.progress_window_s:
            raise ConfigError(
                f"planner.progress_required_m ({self.planner.progress_required_m} m) is more than the robot can drive in "
                f"progress_window_s ({self.planner.progress_window_s} s) at robot.max_linear_mps ({v_max} m/s): every goal would end no_progress"
            )


MUJOCO_LIMO_DEFAULTS: dict[str, dict[str, Any]] = {"sensor": {"mount_x_m": LIMO_LIDAR_MOUNT_X_M}, "planner": {"body": LIMO_BODY}}
"""The keys of an exploration config that the MuJoCo LIMO sets where the config leaves them out: where it carries its
LiDAR (the mapper and the planner must know it) and its box body (not the 2D simulator's disc)."""


def with_mujoco_limo_defaults(config: ExplorationConfig, given: Any = None) -> ExplorationConfig:
    """``config`` (changed in place, and returned) as the MuJoCo LIMO runs it: each key of ``MUJOCO_LIMO_DEFAULTS``
    that ``given``, the config's data (eval's file with ``--set``, a profile's ``exploration``), does not set. The one
    rule for ``eval --sim mujoco``, a profile whose sim is MuJoCo and, given nothing, ``robot_sim.config.limo_sensor()``
    (``doctor``, ``scenes --mjcf``, the fake LIMO's default), so that none of them can drift from the others."""
    stated = given if isinstance(given, dict) else {}
    for section, defaults in MUJOCO_LIMO_DEFAULTS.items():
        keys = stated.get(section) or {}
        changes = {key: value for key, value in defaults.items() if key not in keys}
        setattr(config, section, dataclasses.replace(getattr(config, section), **changes))
    return config


def yaml12_number(value: Any) -> Any:
    """``value`` as YAML 1.2 (and map_server's yaml-cpp) reads it: a text that ``yaml_load`` reads as a number and
    PyYAML's YAML 1.1 leaves as text (``1e-8``, ``5e-2``, ``-.5``, ``0o10``), as that number; any other value as it is.
    A file or ``--set`` read by ``yaml_load`` has these as numbers already; this takes them where a text comes by
    another way (a dict of the Python API, a scene's meta). ``YamlLoader`` itself says which texts are numbers: no
    second pattern of them here."""
    if not isinstance(value, str):
        return value
    try:
        number, yaml11 = yaml_load(value), yaml.safe_load(value)
    except yaml.YAMLError:
        return value
    return number if isinstance(number, (int, float)) and not isinstance(number, bool) and isinstance(yaml11, str) else value


_UNDERSCORED_NUMBER = re.compile(r"[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?")
"""A number with ``_`` between its digits (``6_000_000``), as cso-runtime's messages write large ones: YAML 1.1 read
it as the number, YAML 1.2 (``yaml_load``) reads it as text."""


def _how_to_write(value: Any) -> str:
    """For a number field's refusal of ``value``: how to write it where it is a number written with ``_``
    (``_UNDERSCORED_NUMBER``), which YAML 1.2 reads as text; "" for any other value."""
    text = value.strip() if isinstance(value, str) else ""
    if "_" in text and _UNDERSCORED_NUMBER.fullmatch(text):
        return f" (YAML 1.2 reads a number with _ as text: write {text.replace('_', '')})"
    return ""


def finite_number(value: Any) -> float | None:
    """``value`` as a finite float where YAML 1.2 reads it as a number (an int or a float, not a bool; a text
    ``yaml12_number`` reads); None for anything else: a word, ``1_000``, ``1:30``, true, nan, inf, and an integer no
    float holds (``10**400``, which YAML reads whole: ``float`` would raise OverflowError). The one reading of a number
    field: ``from_dict``'s (which says why where it is None) and a map YAML's (``map_files``, a scene's ``start``)."""
    value = yaml12_number(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def _convert(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return from_dict(annotation, value, where)
    if annotation is float:
        if (number := finite_number(value)) is not None:  # PyYAML (YAML 1.1) reads 1e-8, with no dot, as a string
            return number
        value = yaml12_number(value)
        if isinstance(value, str) and value.strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise ConfigError(f"{where}: must be finite, got {value.strip()}")  # YAML's .nan is a float, its nan text: one answer
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}{_how_to_write(value)}")
        # YAML's .nan and -.inf said as the text nan is (an integer no float holds has no shorter words than these)
        raise ConfigError(f"{where}: must be finite" + (f", got {value:g}" if isinstance(value, float) else ""))
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}{_how_to_write(value)}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in typing.get_args(annotation):
            return None
        for arg in typing.get_args(annotation):
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: {value!r} does not fit {annotation}")
    if origin in (list, tuple):
        (inner, *_) = typing.get_args(annotation) or (Any,)
        if not isinstance(value, (list, tuple)):
            value = _one_or_separated(value, inner, where)
        items = [_convert(v, inner, f"{where}[{i}]") if inner is not Any else v for i, v in enumerate(value)]
        return items if origin is list else tuple(items)
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping")
        return dict(value)
    return value


def field_value(value: Any, annotation: Any, where: str) -> Any:
    """``value`` as ``from_dict`` reads it into a field of type ``annotation`` (a YAML value, ``--set``'s): a list
    field's one value or values separated by commas as its list, ``1e-4`` as a number; a ConfigError naming
    ``where`` when it does not fit."""
    return _convert(value, annotation, where)


def text_field(annotation: Any) -> bool:
    """Whether a field of type ``annotation`` holds text: ``str``, ``str | None``, ``list[str]``."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return [a for a in args if a is not type(None)] == [str]
    return annotation is str or (typing.get_origin(annotation) in (list, tuple) and args[:1] == (str,))


def flag_value(text: str, annotation: Any) -> Any:
    """What a command-line flag's ``text`` gives a field of type ``annotation`` (``train``'s field flags, CleanRL's
    ``--out-dir runs/a``): a ``text_field`` takes the text as it is (``2024``, ``on``, a list's ``null`` item stay
    text; a list's values separated by commas, as ``_one_or_separated`` reads them), save a nullable one's ``null``
    (None) and a list given as one (``[a, b]``); any other field reads it as YAML (``0.9``, ``true``), as ``--set``
    does. The value, for ``field_value`` to check."""
    try:
        parsed = yaml_load(text)
    except yaml.YAMLError:
        parsed = text  # said by the field's own check
    if not text_field(annotation):
        return parsed
    if typing.get_origin(annotation) in (list, tuple):
        return parsed if isinstance(parsed, list) else text
    return None if parsed is None and type(None) in typing.get_args(annotation) else text


LIST_SEPARATOR = ","
"""What separates the values of a list field given as one text (``--set generated=A,B``): most CLIs' way."""


def _one_or_separated(value: Any, inner: Any, where: str) -> list[Any]:
    """A list field's value given as one value rather than a list (``--generated generated:small:2:0``, ``--set
    dungeon_m_per_px=0.05``): the list of it, as most command lines take one; a text with commas, the list of the
    values between them, each read as YAML unless the list's items are text (a scene spec keeps its colons, ``null``
    stays the text). An item with a comma in it is written as a list: ``["a,b"]``. A mapping or null is no list."""
    if value is None or isinstance(value, dict):
        raise ConfigError(f"{where}: expected a list")
    if not isinstance(value, str):
        return [value]
    items = [item.strip() for item in value.split(LIST_SEPARATOR)]
    if not all(items):
        raise ConfigError(f"{where}: empty item in {value!r} (values separated by commas, or a list: [a, b])")
    if inner is str:
        return items
    try:
        return [yaml_load(item) for item in items]
    except yaml.YAMLError:
        return items  # said by the item's own check (expected a number, ...)


def _key_where(where: str, key: str) -> str:
    """Where a key sits, for messages: ``configs/eval.yaml: masks`` for a file's own keys (a file path, or a
    profile named with the flags that changed it), ``masks.beta_far_m`` below them."""
    is_file = where.endswith((".yaml", ".yml")) or " with --" in where
    return f"{where}: {key}" if is_file and ": " not in where else f"{where}.{key}"


def import_attribute(spec: str, what: str, example: str) -> object:
    """The object ``module.path:Attribute`` names, imported as uvicorn or an entry point would (a goal selector of
    one's own, a service of one's own); ConfigError naming ``what`` (``method 'x:Y'``) and which part is wrong, with
    ``example`` as the spelling to follow."""
    module_name, _, attribute = spec.partition(":")
    if not module_name or not attribute:
        raise ConfigError(f"{what}: {example}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(
            f"{what}: cannot import module {module_name!r} ({type(exc).__name__}: {exc}); the module must be importable "
            "by the Python that runs cso-runtime: on PYTHONPATH (e.g. PYTHONPATH=/path/to/the/folder/above/it) or installed"
        ) from None
    except Exception as exc:  # the user's module fails as it runs: say where, not only a traceback
        raise ConfigError(f"{what}: importing module {module_name!r} failed: {type(exc).__name__}: {exc}") from exc
    found: object = module
    where = module_name
    for part in attribute.split("."):
        if not hasattr(found, part):
            names = [n for n in dir(found) if not n.startswith("_")]
            raise ConfigError(f"{what}: {where} has no attribute {with_nearest(part, names, shown=repr(part))}")
        found = getattr(found, part)
        where = f"{where}.{part}"
    return found


def utf8_text(text: str) -> str:
    """``text`` with each character UTF-8 cannot carry escaped (``\\udcff``): a lone surrogate, what ``os.fsdecode`` makes of
    a file name's bytes that are no UTF-8 (``b"\\xff"``), which msgpack, a UTF-8 CSV, log or JSON file and MuJoCo's XML
    all refuse. Any other text is returned as it is (an ASCII one without a copy)."""
    return text if text.isascii() else text.encode("utf-8", "backslashreplace").decode("utf-8")


def with_nearest(key: str, known: typing.Iterable[str], shown: str | None = None) -> str:
    """``key`` (or ``shown``, how the message writes it), followed by the known key it most likely misspells
    (``gama (did you mean gamma?)``), if any is close. A dotted key is also matched by its last part, so that
    ``sensor.fov_deg`` among flat keys suggests ``lidar_fov_deg`` rather than the ``sensor`` it merely starts with."""
    known = sorted(known)
    tries = [str(key)] + ([str(key).rsplit(".", 1)[1]] if "." in str(key) else [])
    scored = [
        (difflib.SequenceMatcher(None, tried, match).ratio(), match)
        for tried in tries
        for match in difflib.get_close_matches(tried, known, n=1)
    ]
    shown = str(key) if shown is None else shown
    return f"{shown} (did you mean {max(scored)[1]}?)" if scored else shown


def unknown_keys_said(keys: typing.Iterable[str], known: typing.Iterable[str], named: bool = False) -> str:
    """The one wording of keys a section does not take: ``unknown key(s) mehtod (did you mean method?), x; known: a, b``
    (``keys`` in the order given, each with ``with_nearest``'s suggestion; ``named``: each already said as the message
    names it, a misplaced key's home by ``wrong_section``), the section's ``known`` keys sorted. ``from_dict``,
    ``wrong_section`` and ``run_profile.unknown_top_level_keys`` say it."""
    known = sorted(known)
    said = ", ".join(key if named else with_nearest(key, known) for key in keys)
    return f"unknown key(s) {said}; known: {', '.join(known)}"


def key_sections(cls: type, path: str = "") -> dict[str, set[str]]:
    """Each mapping config dataclass ``cls`` reads, by dotted path (``path``: its own, ``""`` at the top) -> the keys it
    takes: ``cls``'s fields and, for each field that is a dataclass, that one's, and so on down (``planner``...)."""
    hints = typing.get_type_hints(cls)
    sections = {path: {f.name for f in dataclasses.fields(cls)}}
    for f in dataclasses.fields(cls):
        if isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name]):
            sections.update(key_sections(hints[f.name], f"{path}.{f.name}" if path else f.name))
    return sections


def mapping_at(data: dict[str, Any], path: str) -> dict[str, Any]:
    """The mapping ``data`` holds at dotted ``path`` (``""``: ``data``), or an empty one."""
    node: Any = data
    for part in path.split(".") if path else []:
        node = node.get(part) if isinstance(node, dict) else None
    return node if isinstance(node, dict) else {}


def unknown_keys(data: dict[str, Any], sections: dict[str, set[str]]) -> list[tuple[str, str]]:
    """``(path, key)`` for each key of ``data``'s mapping at a section's path that the section does not take."""
    return [(path, key) for path, keys in sections.items() for key in mapping_at(data, path) if key not in keys]


MISSPELT_SECTION_RATIO = 0.8
"""``wrong_section``: an unknown mapping this close (``difflib`` ratio) to a key of its section is that key misspelt
(``exploraton``, ``mask``), which ``from_dict`` names, not the homes of the keys it holds (``exploration.planner or
services.planner``); looser, ``frontier`` would be ``router`` misspelt."""


def wrong_section(unknown: list[tuple[str, str]], sections: dict[str, set[str]], data: dict[str, Any]) -> str | None:
    """What is wrong with every one of ``data``'s ``unknown`` keys that is no key of its section but one of another
    (``lookahead_m`` at eval's top level is ``planner.lookahead_m``; a profile's ``services.planner.lookahead_m``,
    Nav2's place for it, ``exploration.planner.lookahead_m``), or a mapping of keys that belong elsewhere (eval's
    ``masks: {beta_far_m: 2.0}`` in train's flat config is ``beta_far_m``; not a misspelt one, ``MISSPELT_SECTION_RATIO``), in ``from_dict``'s words but saying where
    it belongs rather than the nearest spelling in the wrong section, a section's keys together and the sections one
    after the other (three misplaced keys are three fixes, learnt in one go, not one error each); None when none is (a
    typo: ``from_dict`` says it). A typo beside a misplaced key is named too, with its nearest spelling, so that no fix
    is left for the next run."""
    homes: dict[str, list[str]] = {}
    for path, keys in sections.items():
        for key in keys:
            homes.setdefault(key, []).append(f"{path}.{key}" if path else key)
    named: dict[str, list[str]] = {}  # each section's unknown keys as the error names them, in the order given
    any_misplaced = False
    for path, key in unknown:
        elsewhere = [home for home in homes.get(key, []) if home != (f"{path}.{key}" if path else key)]
        if not elsewhere and not difflib.get_close_matches(key, sections[path], n=1, cutoff=MISSPELT_SECTION_RATIO):
            elsewhere = [home for inner in mapping_at(data, f"{path}.{key}" if path else key) for home in homes.get(inner, [])]
        any_misplaced = any_misplaced or bool(elsewhere)
        named.setdefault(path, []).append(f"{key} (did you mean {' or '.join(elsewhere)}?)" if elsewhere else with_nearest(key, sections[path]))
    if not any_misplaced:
        return None
    return "; ".join(f"{path + ': ' if path else ''}{unknown_keys_said(keys, sections[path], named=True)}" for path, keys in named.items())


def check_field_types(cls: type, data: dict[str, Any], where: str = "config") -> None:
    """ConfigError for a value of ``data`` that its field of dataclass ``cls`` does not take (``from_dict``'s conversion,
    in its words: ``m_per_px: expected a number, got [1]``), without building ``cls`` or checking the whole (its
    ``validate``) and leaving other keys alone: what a service started by hand checks of the profile's top level, which
    it reads key by key (``up`` reads it whole with ``from_dict``). A section that is a dataclass (``router``) is checked
    the same way, its types only: its ``validate`` may need what ``up``'s flags add (``router.embedded: false`` takes
    ``up --connect``'s endpoint; a service started by hand has its own ``--connect``)."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key, value in data.items():
        if key not in names:
            continue
        annotation, key_where = hints[key], _key_where(where, key)
        if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
            if not isinstance(value, dict):
                raise ConfigError(f"{key_where}: expected a mapping, got {type(value).__name__}")
            check_field_types(annotation, value, key_where)
        else:
            _convert(value, annotation, key_where)


def from_dict_with_hints(cls: type[T], data: dict[str, Any], where: str) -> T:
    """``from_dict`` of a whole config (a file and its ``--set`` keys), a key in the wrong section named as such first."""
    sections = key_sections(cls)
    if (problem := wrong_section(unknown_keys(data, sections), sections, data)) is not None:
        raise ConfigError(f"{where}: {problem}")
    return from_dict(cls, data, where)


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from a (possibly partial) mapping; unknown keys raise ConfigError."""
    data = data or {}
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"{where}: {unknown_keys_said(unknown, names)}")
    kwargs = {k: _convert(v, hints[k], _key_where(where, k)) for k, v in data.items()}
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except ValueError as exc:  # ConfigError, or the ValueError of a validate() outside this module (train's Args)
            raise ConfigError(_checked_where(where, str(exc), names)) from None
    return obj


def _checked_where(where: str, message: str, names: set[str]) -> str:
    """A section's ``validate()`` message under ``where``, its key on the path as a type error's is: a nested section's
    own error (``mujoco: timestep_s must be positive``, SimParams' ``mujoco`` checked as ``services.sim``) reads
    ``services.sim.mujoco: timestep_s ...``, and a section that names itself (SensorConfig's ``sensor.fov_deg ...`` as
    ``exploration.sensor``) ``exploration.sensor.fov_deg ...``; a file's own keys follow its name (``_key_where``)."""
    head = re.match(r"(\w+)([.:])", message)
    if head is not None and head[1] in names:
        return _key_where(where, message)
    if head is not None and head[2] == "." and re.split(r"[.: ]", where)[-1] == head[1]:
        return where + message[len(head[1]) :]
    return f"{where}: {message}"


def to_dict(obj: Any) -> dict[str, Any]:
    """Plain-data view of a config dataclass (for logs and result files)."""
    return dataclasses.asdict(obj)


TORCH_DEVICE = re.compile(r"cpu|cuda(:\d+)?")
"""A torch device a policy or a training run can be given by name (``auto`` is the trainer's own choice)."""


def check_torch_device(name: str, allow_auto: bool = False) -> None:
    """The device's spelling, checked without torch (the launcher checks before anything starts): a name torch
    does not know would otherwise surface as a weights file that does not load, after the run started."""
    if not (TORCH_DEVICE.fullmatch(name) or (allow_auto and name == "auto")):
        choices = "auto, cpu, cuda or cuda:N" if allow_auto else "cpu, cuda or cuda:N"
        raise ConfigError(f"unknown device {name!r}; choose {choices}")


MAX_SEED = 2**32 - 1
"""The largest seed (numpy's legacy and torch's generators, and every message's integer fields, take it)."""


def check_seed(seed: int, name: str = "seed") -> int:
    """A seed every generator and message takes (an integer in [0, ``MAX_SEED``]), checked where it is
    configured rather than deep inside a simulator or a worker process, or, worse, once the episode is
    over and its result cannot be sent."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{name} must be an integer from 0 to {MAX_SEED}, got {seed!r}")
    return seed


def make_output_dir(path: str | Path, flag: str = "--out") -> Path:
    """Create an output folder before the work that fills it starts (an evaluation, a training run, hours
    of teacher rollouts), so that a folder that cannot be made, or written in (a read-only file system), is a
    ConfigError now, not a traceback at the end."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{flag} {p}: cannot create the folder ({exc.strerror or exc})") from None
    try:  # a folder that exists is not one that can be written: a read-only file system, another user's folder
        with tempfile.TemporaryFile(dir=p):
            pass
    except OSError as exc:
        raise ConfigError(f"{flag} {p}: cannot write in the folder ({exc.strerror or exc})") from None
    return p


@dataclass(frozen=True)
class FolderProblem:
    """Why a folder could not be made, or written in: ``folder_problem``'s answer."""

    existing: Path
    """The nearest path at or above the folder that exists (absolute): the folder itself where it exists."""
    errno: int
    """``ENOTDIR``: a file above the folder; ``EEXIST``: a file where the folder would be; otherwise ``existing`` is a
    folder this process cannot make the folder, or a file, in: ``EACCES`` where its modes say so (or a read-only file
    system's), else the error the probe got (``ENOENT`` in /proc, where root passes every mode)."""

    @property
    def in_the_way(self) -> bool:
        """A file stands at or above the folder (``ENOTDIR``, ``EEXIST``), not a folder that refuses what is made in it."""
        import errno  # noqa: PLC0415

        return self.errno in (errno.ENOTDIR, errno.EEXIST)

    @property
    def reason(self) -> str:
        """The OS's words for ``errno`` (``Not a directory``, ``File exists``, ``Permission denied``)."""
        import os  # noqa: PLC0415

        return os.strerror(self.errno)


def folder_problem(folder: str | Path) -> FolderProblem | None:
    """Why this process could not make ``folder`` (with the folders above it) or write in it, or None; leaves nothing
    behind. One walk up to the nearest existing path for every check made before a run starts (``eval --dry-run``'s
    ``--out``, the Foxglove bridge's ``mcap_path``), each of which words the answer for its own key or flag."""
    import errno  # noqa: PLC0415
    import os  # noqa: PLC0415

    target = Path(folder).absolute()
    existing = target
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        return FolderProblem(existing, errno.EEXIST if existing == target else errno.ENOTDIR)
    if not os.access(existing, os.W_OK | os.X_OK):  # also False on a read-only file system
        return FolderProblem(existing, errno.EACCES)
    try:  # modes are not all (root passes them in /proc): what the run does first, made there and removed at once
        if existing == target:
            with tempfile.TemporaryFile(dir=existing):  # make_output_dir's write check
                pass
        else:
            os.rmdir(tempfile.mkdtemp(dir=existing, prefix=".probe-"))  # the run's mkdir
    except OSError as exc:
        return FolderProblem(existing, exc.errno or errno.EACCES)
    return None


def check_output_dir(path: str | Path, flag: str = "--out") -> None:
    """``make_output_dir``'s checks, leaving nothing behind (``eval --dry-run``): the folder, or the nearest folder
    above it that exists, must be one this process can write in (ConfigError otherwise, in the same words)."""
    p = Path(path)
    problem = folder_problem(p)
    if problem is not None:
        verb = "write in" if not problem.in_the_way and problem.existing == p.absolute() else "create"
        raise ConfigError(f"{flag} {p}: cannot {verb} the folder ({problem.reason})")


def commented_yaml(comments: list[str], data: Any) -> str:
    """``comments`` as ``# `` lines, then ``data`` as YAML in its own key order: what ``up --dry-run``, ``up --resolved``
    and ``eval --resolved`` print, a file that loads back as the profile or config it shows: every line of a comment
    (a profile's name or a path may hold a line break) is a comment line, and a character YAML allows nowhere in a
    file (a control character, ``\\x07``) is written as its escape, as the YAML below writes it in a value."""
    lines = (line for comment in comments for line in comment.splitlines() or [""])
    return "".join(f"# {_YAML_REFUSES.sub(_escaped, line)}\n" for line in lines) + yaml_dump(data, sort_keys=False)


_YAML_REFUSES = yaml.reader.Reader.NON_PRINTABLE
"""The characters PyYAML's reader refuses anywhere in a stream, a comment too ("unacceptable character #x0007")."""


def _escaped(found: re.Match[str]) -> str:
    """A character ``_YAML_REFUSES`` found, as its Python escape: ``\\x07``, ``\\x1b``, ``\\udcff``."""
    return found.group().encode("unicode_escape").decode("ascii")


def set_flag_text(key: str, value: Any) -> str:
    """``--set KEY=VALUE`` as the user typed it, for an error that names the flags: the value in YAML (``true``,
    ``[a, 2]``, ``café`` not ``"caf\\xE9"``), as ``--set`` reads it, not Python's repr (``True``, ``['a', 2]``)."""
    return f"--set {key}={yaml_text(value)}"


class Settings(dict[str, Any]):
    """``--set``'s ``KEY=VALUE`` pairs (``cli.parse_settings``): each VALUE as YAML reads it, and in ``typed`` its text as
    typed (``on``, ``010``, ``1e3``), which a message naming the ``--set`` says (``set_said``): written again from
    what YAML read, it would be another value (``true``, ``10``, ``1000.0``), and a hint to quote it another text."""

    def __init__(self, *pairs: Any, typed: dict[str, str] | None = None, **values: Any) -> None:
        super().__init__(*pairs, **values)
        self.typed: dict[str, str] = dict(typed or {})


def set_said(settings: typing.Mapping[str, Any], key: str) -> str:
    """The ``--set`` of ``key`` among ``settings`` as the user typed it (``--set robot=on``), where ``settings`` are
    ``Settings`` that hold its text; else its value in YAML (``set_flag_text``)."""
    typed = _typed_text(settings, key)
    return f"--set {key}={typed}" if typed is not None else set_flag_text(key, settings[key])


def _typed_text(settings: typing.Mapping[str, Any], key: str) -> str | None:
    """The text of ``key``'s ``--set`` as typed, where ``settings`` hold it (``Settings``); else None."""
    return settings.typed.get(key) if isinstance(settings, Settings) else None


def refuse_two_values(given: typing.Mapping[str, typing.Sequence[tuple[str, Any]]], read: typing.Callable[[str, Any], Any] | None = None) -> None:
    """The one check of a command whose flags set one field twice: a dedicated flag and ``--set`` (``eval --max-steps 5
    --set episode.max_steps=9``, ``up --seed 3 --set seed=4``, ``train --seed 3 --set seed=4``), or two flags of one
    field. ``given`` holds, by field, each ``(flag as typed, value)`` that set it, in order; two of them with different
    values (as ``read`` reads them: the field's type, ``1e3`` and ``1000.0`` alike, a path as ``place_of`` resolves
    it) are a ConfigError naming both, since one of them would take over the other in silence. The same value twice
    is fine, and so is one number written two ways where the field's type refuses one of them (``--max-steps 40`` and
    ``--set episode.max_steps=40.0``): not "different values", but the field's own type error, said where the
    configuration is read ("expected an integer, got 40.0"). A value ``read`` refuses (a ConfigError: not of the field's type) that is the other's text as ``--set``
    reads it (``up --robot 1 --set robot=1``: the number 1, where a robot id is text) is said as such, with the way
    to write it (``--set robot='1'``), not as another value."""
    for name, said in given.items():
        if not said:
            continue
        (first, value), *others = said
        reading = _reading(read, name, value)
        for other, other_value in others:
            other_reading = _reading(read, name, other_value)
            if other_reading == reading:
                continue
            for (bad, bad_value, bad_reading), (good, good_value, good_reading) in (
                ((other, other_value, other_reading), (first, value, reading)),
                ((first, value, reading), (other, other_value, other_reading)),
            ):
                if isinstance(bad_reading, _Unread) and not isinstance(good_reading, _Unread) and _same_yaml(bad_value, good_value):
                    raise ConfigError(read_as_another_type(bad, bad_value, name, good_value, good))
            if isinstance(reading, _Unread) != isinstance(other_reading, _Unread) and _one_yaml_value(value, other_value):
                continue  # --max-steps 40 and --set episode.max_steps=40.0: one value, which the field's own check refuses
            raise ConfigError(f"{first} and {other} both set {name}, to different values: give one")


def read_as_another_type(flag: str, value: Any, name: str, meant: Any, given_by: str = "") -> str:
    """The one way a flag whose value was read as another type than its field's is said, with the way to write it:
    ``flag`` as typed (``--set robot=1``), ``value`` as read (the number 1), ``meant`` the value the field takes (the
    text "1"), and ``given_by`` the other flag that gave it (``--robot 1``; "" when the ``--set`` came alone)."""
    by, alone = (f" (as {given_by} gives it)", f", or give {given_by} alone") if given_by else ("", "")
    return f"{flag} is read as {_kind(value)}, and {name} is {_kind(meant)}{by}: write {set_flag_text(name, meant)}{alone}"


def refuse_a_setting_read_as_another_type(
    settings: typing.Mapping[str, Any], types: typing.Mapping[str, Any], takes: typing.Callable[[dict[str, Any]], object] | None = None
) -> None:
    """A ConfigError for a ``--set`` of a text field (``types``, by dotted key: ``field_types``) whose value YAML reads as
    another type and whose text the field takes: ``up --set robot=1`` (the number 1, where a robot id is text) says how
    to write it (``--set robot='1'``, ``read_as_another_type``), as with ``--robot 1`` beside it, not only the field's
    type error; so does a key of a section (``--set router.zenoh_config=2024``, ``services.NAME.KEY``). ``takes``: the
    whole configuration built with the given ``--set`` pairs, raising a ConfigError where it is refused; given, the
    hint is said only where the configuration with those values as text is taken (``--set method=1``: ``'1'`` is no
    method either, so the value's own error is said, not a hint that would fail in turn)."""
    texts: dict[str, str] = {}
    for key, value in settings.items():
        annotation = types.get(key)
        if annotation is None or not text_field(annotation) or isinstance(value, (str, dict, list)):
            continue
        try:
            field_value(value, annotation, key)
            continue  # taken as it is (null, where the field may be)
        except ConfigError:
            pass
        typed = _typed_text(settings, key)
        text = typed if typed is not None else yaml_text(value)  # as typed: `on`, not `true` written again
        try:
            field_value(text, annotation, key)
        except ConfigError:
            continue  # its own type error says what is wrong
        texts[key] = text
    if not texts:
        return
    if takes is not None:
        try:
            takes({key: texts.get(key, value) for key, value in settings.items()})
        except ConfigError:
            return  # the text is refused too: the value's own error says what is wrong
    raise ConfigError("; ".join(read_as_another_type(set_said(settings, key), settings[key], key, text) for key, text in texts.items()))


def field_types(cls: type, path: str = "") -> dict[str, Any]:
    """The type of each field of config dataclass ``cls`` by dotted key (``path``: its own, ``""`` at the top), those of
    each field that is a dataclass too, and so on down (``router.zenoh_config``, ``planner.body``): what
    ``refuse_a_setting_read_as_another_type`` reads a ``--set`` key's type from."""
    hints = typing.get_type_hints(cls)
    found: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        key = f"{path}.{f.name}" if path else f.name
        found[key] = hints[f.name]
        if isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name]):
            found.update(field_types(hints[f.name], key))
    return found


@dataclass(frozen=True)
class _Unread:
    """``refuse_two_values``' reading of a value its field's type refuses: the value as given (``from_dict`` says
    what is wrong with it), equal to another only when given the same."""

    value: Any


def _reading(read: typing.Callable[[str, Any], Any] | None, name: str, value: Any) -> Any:
    if read is None:
        return value
    try:
        return read(name, value)
    except ConfigError:
        return _Unread(value)


def _as_yaml(value: Any) -> Any:
    """``value``, a text read as YAML as ``--set`` reads it (a text YAML cannot read, and any other value, as it is)."""
    try:
        return yaml_load(value) if isinstance(value, str) else value
    except yaml.YAMLError:
        return value


def _same_yaml(a: Any, b: Any) -> bool:
    """Whether ``a`` and ``b`` are one value once each text among them is read as YAML, as ``--set`` reads it: the
    text ``1`` and the number 1, ``on`` and true; not the text ``1`` and true, though ``1 == True``."""
    a, b = _as_yaml(a), _as_yaml(b)
    return type(a) is type(b) and a == b


def _one_yaml_value(a: Any, b: Any) -> bool:
    """Whether ``a`` and ``b`` are one value once read as YAML and compared as two ``--set`` values of one key are
    (``yaml_value_compared``): 40 and 40.0 alike, 1 and true not."""
    return bool(yaml_value_compared(_as_yaml(a)) == yaml_value_compared(_as_yaml(b)))


def yaml_value_compared(value: Any) -> Any:
    """``value`` (as ``yaml_load`` reads a text) as two values of one ``--set`` key are compared (``cli.parse_settings``):
    a number as a number, however written (``1``, ``1.0``, ``1e0``; a NaN as NaN), true and false never a number nor a
    text (Python's ``1 == True``, ``[1] == [True]``), a list item by item, a mapping key by key in any order."""
    if isinstance(value, bool):
        return ("bool", value)
    if isinstance(value, (int, float)):
        return ("number", "nan" if isinstance(value, float) and math.isnan(value) else value)
    if isinstance(value, (list, tuple)):
        return ("list", tuple(yaml_value_compared(item) for item in value))
    if isinstance(value, dict):
        return ("mapping", {yaml_value_compared(key): yaml_value_compared(item) for key, item in value.items()})
    return (type(value), value)


def _kind(value: Any) -> str:
    """What ``value`` is, in a sentence: ``refuse_two_values``' "is read as a number, and robot is text"."""
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "text"
    return "null" if value is None else "a mapping" if isinstance(value, dict) else "a list" if isinstance(value, (list, tuple)) else type(value).__name__


def place_of(value: Any, names_a_path: typing.Callable[[str], bool] = bool) -> Any:
    """A path-valued field's value as two spellings of one path compare (``--scene ./plans`` and ``--set scene=plans``,
    ``--out runs/a/`` and ``--set out_dir=$PWD/runs/a``): the path resolved against the current folder, as the command
    resolves it; a text that ``names_a_path`` says is no path (a scene spec's ``builtin``, ``init_from``'s ``shipped``;
    by default the empty text) and any other value as it is."""
    return Path(value).resolve() if isinstance(value, str) and names_a_path(value) else value


def setting_of(key: str, settings: typing.Mapping[str, Any]) -> tuple[str, Any] | None:
    """The value that ``--set`` pairs (in the order given) leave dotted ``key`` at, with the pair that set it as typed:
    ``episode.max_steps=5`` or a whole section, ``episode={max_steps: 5}``; None when none sets it (a later pair that
    replaces its section without it drops it, as ``set_dotted`` does)."""
    found: tuple[str, Any] | None = None
    for pair, value in settings.items():
        if pair == key:
            found = (set_said(settings, pair), value)
        elif key.startswith(pair + "."):
            node = _inside(value, key[len(pair) + 1 :])
            found = None if node is _UNSET else (set_said(settings, pair), node)
    return found


_UNSET = object()
"""``setting_of``'s mark of a key a section set by ``--set`` leaves out."""


def _inside(section: Any, key: str) -> Any:
    """The value at dotted ``key`` within a section's value (``{max_steps: 5}``, ``max_steps``), or ``_UNSET``."""
    node = section
    for part in key.split("."):
        node = node.get(part, _UNSET) if isinstance(node, dict) else _UNSET
    return node


def settings_by_key(pairs: typing.Sequence[tuple[str, str, Any]]) -> dict[str, list[tuple[str, Any]]]:
    """``--set`` pairs (``(key, --set as typed, value)``, in the order given) as ``refuse_two_values`` takes them: by
    key, each pair that sets it, itself or a section of it (``episode={max_steps: 5}`` sets ``episode.max_steps``),
    with the value it gives it. A section given after a key of it without that key is a ConfigError: it replaces the
    section whole (``set_dotted``), and the key's value would be dropped in silence."""
    given: dict[str, list[tuple[str, Any]]] = {}
    for key in dict.fromkeys(key for key, _, _ in pairs):
        said = given[key] = []
        for pair, flag, value in pairs:
            if pair == key:
                said.append((flag, value))
            elif key.startswith(pair + "."):
                if (node := _inside(value, key[len(pair) + 1 :])) is not _UNSET:
                    said.append((flag, node))
                elif said:
                    raise ConfigError(
                        f"{flag} replaces all of {pair}, without {key}: {said[-1][0]} would be dropped; give it in {pair}'s value, or after it"
                    )
    return given


def refuse_a_flag_and_a_setting_that_disagree(
    flags: typing.Mapping[str, tuple[str, Any]],
    settings: typing.Mapping[str, Any],
    types: typing.Mapping[str, Any],
    paths: typing.Mapping[str, typing.Callable[[str], bool]] | None = None,
) -> None:
    """``refuse_two_values`` of a command's dedicated flags (``flags``: dotted key -> ``(flag as typed, value)``, for
    each flag given) against its ``--set`` pairs (``settings``) for the same key, each read as its field's type
    (``types``, by key) as ``from_dict`` reads it: ``eval --max-steps`` and ``--set episode.max_steps``, ``up --seed``
    and ``--set seed``. A key of ``paths`` holds a path: its values compare as ``place_of`` resolves them, with the
    key's own test of which texts name a path (``up --scene``: not ``builtin``)."""
    given = {key: [flag, *([by_set] if (by_set := setting_of(key, settings)) is not None else [])] for key, flag in flags.items()}

    def read(key: str, value: Any) -> Any:
        value = field_value(value, types[key], key)
        return place_of(value, paths[key]) if paths and key in paths else value

    refuse_two_values(given, read)


def yaml_text(value: Any) -> str:
    """``value`` in YAML on one line, as a flag's value reads back (``true``, ``[a, 2]``, ``café``): what
    ``set_flag_text`` and ``train``'s field flags write of it."""
    text = yaml_dump(value, default_flow_style=True, width=10**9, allow_unicode=True).strip()
    return text.removesuffix("...").strip()


def setting_text(value: float) -> str:
    """A number as a message and a ``--set`` write it: ``:g``'s short form (``2``, ``0.3``) where it reads back as
    ``value``, else the shortest text that does (``2.1234567``, ``2.0000001``), so that the ``--set`` a refusal or
    ``train``'s closing ``eval`` command names (``learned.weights.InputMismatch``, ``learned.ppo.matching_eval_command``)
    gives the very value compared, not one that is refused in turn, and two values that differ never read alike."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    """Set ``a.b.c`` in nested mappings (``--set services.sim.real_time_factor=4``), making the mappings on the
    way (a key written as ``mapper:`` with no value is an empty one); a value in the way is an error."""
    parts = key.split(".")
    if not all(p.strip() for p in parts):
        raise ConfigError(f"--set {key}: empty part in the key")
    node = data
    for depth, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"--set {key}: {'.'.join(parts[: depth + 1])} is {child!r}, not a mapping")
        node = child
    node[parts[-1]] = value


_YAML_INT_TAG, _YAML_FLOAT_TAG, _YAML_TIMESTAMP_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float", "tag:yaml.org,2002:timestamp"
_YAML12_INT = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
"""YAML 1.2 core schema's integers: decimal (``010`` is 10), ``0o`` octal, ``0x`` hexadecimal; no ``_`` in them,
no base 60 (``1:30``), no C octal (``010`` as 8), which YAML 1.1 has."""
_YAML12_FLOAT = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.nan|\.NaN|\.NAN)$")
"""YAML 1.2 core schema's floats: ``5e-2``, ``-.5``, ``2.``, ``.inf``, ``.nan`` (an integer matches too: ints are
tried first). Anchored, as PyYAML's resolvers match from the start only."""
_DIGITS = "-+0123456789"


def _yaml12_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int:
    """An integer of YAML 1.2's core schema: ``010`` is ten, ``0o10`` eight, ``0x10`` sixteen."""
    text = str(loader.construct_scalar(node))
    try:
        if text.startswith(("0o", "0x")):
            return int(text[2:], 8 if text[1] == "o" else 16)
        return int(text, 10)
    except ValueError:  # an explicit !!int of no integer
        raise yaml.constructor.ConstructorError(None, None, f"{text!r} is no integer of YAML 1.2", node.start_mark) from None


class YamlLoader(yaml.SafeLoader):
    """The one reader of every YAML file and value cso-runtime takes (configs, profiles, ``--set`` and field flags, a
    run's ``profile.yaml``, map_server map YAMLs, ``yaml_load``): ``yaml.SafeLoader`` with YAML 1.2 core schema's
    numbers, as map_server's yaml-cpp and any YAML 1.2 reader reads them. PyYAML's YAML 1.1 read ``010`` as 8,
    ``1_000`` as 1000, ``1:30`` as 90 and ``2024-01-01`` as a date, and left ``5e-2`` and ``-.5`` as text: here they
    are 10, the texts ``1_000``, ``1:30`` and ``2024-01-01``, 0.05 and -0.5 (``0x10`` 16, ``0o10`` 8). Booleans are YAML
    1.1's, ``yes``/``no``/``on``/``off`` (any case as PyYAML) true or false beside ``true``/``false``, as yaml-cpp's
    ``as<bool>`` (a map's ``negate``) and ROS 2's parameter files (rcl_yaml_param_parser) read them, and as this
    project's ``--set`` has read them: a text ``on`` is written quoted (``'on'``). A key given twice in one mapping
    (``010`` and ``10`` are one key) is refused, in a file or a ``--set`` value alike: PyYAML keeps the last one in
    silence and yaml-cpp (map_server) reads the first, so an edited profile's first value would be dropped without a
    word, and a map YAML read otherwise than map_server reads it."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.setdefault(key, key_node.start_mark)
            except TypeError:  # an unhashable key: SafeLoader's own error says so
                break
            if first is not key_node.start_mark:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping", node.start_mark, f"found key {key!r} twice (first at line {first.line + 1})", key_node.start_mark
                )
        return super().construct_mapping(node, deep=deep)


YamlLoader.yaml_implicit_resolvers = {  # SafeLoader's, less YAML 1.1's numbers and dates
    first: [(tag, regexp) for tag, regexp in resolvers if tag not in (_YAML_INT_TAG, _YAML_FLOAT_TAG, _YAML_TIMESTAMP_TAG)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
YamlLoader.add_implicit_resolver(_YAML_INT_TAG, _YAML12_INT, list(_DIGITS))  # before the float's, which matches 10 too
YamlLoader.add_implicit_resolver(_YAML_FLOAT_TAG, _YAML12_FLOAT, [*_DIGITS, "."])
YamlLoader.add_constructor(_YAML_INT_TAG, _yaml12_int)


class YamlDumper(yaml.SafeDumper):
    """The one writer of YAML that cso-runtime reads back or hands on (``up --resolved``, a run's ``profile.yaml``,
    the launcher's profile, a map's YAML, ``yaml_text``): ``yaml.SafeDumper``, quoting a text that YAML 1.1 or YAML
    1.2 would read as anything but that text (``'1e3'``, ``'-.5'`` as ``'010'`` and ``'on'``), so that ``YamlLoader``,
    PyYAML's own loader and yaml-cpp all read it back as the text."""


for _first, _resolvers in YamlLoader.yaml_implicit_resolvers.items():
    for _tag, _regexp in _resolvers:
        if _tag in (_YAML_INT_TAG, _YAML_FLOAT_TAG):
            YamlDumper.add_implicit_resolver(_tag, _regexp, [_first])


def yaml_load(stream: Any) -> Any:
    """A YAML text or stream as ``YamlLoader`` reads it (YAML 1.2's numbers); a ``yaml.YAMLError`` where it is no YAML."""
    return yaml.load(stream, Loader=YamlLoader)


def yaml_dump(data: Any, **options: Any) -> str:
    """``data`` in YAML as ``YamlDumper`` writes it (``yaml.safe_dump``'s ``options``): what ``yaml_load`` reads back.
    Non-ASCII text as it is (``café``, not ``"caf\\xE9"``, a file users read and edit): the text is UTF-8's to write
    and to read back (``outputs.write_text_atomic``, ``load_yaml``, the launcher's stdin as bytes)."""
    return str(yaml.dump(data, Dumper=YamlDumper, **{"allow_unicode": True, **options}))


def one_line(text: str) -> str:
    """``text`` on one line, its runs of spaces and line breaks one space: a YAML error (three lines or more, a caret
    drawing among them) as every error of the CLI is said, in one line."""
    return " ".join(text.split())


def not_yaml_said(where: object, exc: Exception) -> str:
    """What a text that ``yaml_load`` refuses is said as, wherever it came from (a config or profile file, a map YAML, a
    ``--set``; a key given twice included): ``WHERE: not valid YAML: YAML's own words``, on one line."""
    return f"{where}: not valid YAML: {one_line(str(exc))}"


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping, with a clear error for a missing or malformed file or a key given twice."""
    p = Path(path)
    if p.is_dir():  # not "not found": it is there, as a folder
        raise ConfigError(f"{p} is a folder; give the YAML file (a config file is one .yaml file)")
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    try:
        with p.open(encoding="utf-8") as stream:  # a file stream, so YAML's message names the file, not "<unicode string>"
            data = yaml_load(stream)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(not_yaml_said(p, exc)) from None
    except OSError as exc:  # another user's file (no read permission), an I/O error: one line, as a map YAML's, not a traceback
        raise ConfigError(f"{p}: cannot read the config file ({exc.strerror or exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: top level must be a mapping")
    return data
