"""ROS 2 bridge service: a real LIMO (through zenoh-bridge-ros2dds) in place of the simulator.

zenoh-bridge-ros2dds publishes a ROS 2 topic ``/NS/scan`` on the Zenoh key ``NS/scan`` (no leading
slash, no ``rt/`` prefix) with the CDR bytes of the DDS sample, and forwards what is put on
``NS/cmd_vel`` to the ROS topic. This service:

* decodes ``scan`` (sensor_msgs/LaserScan) and ``odom`` (nav_msgs/Odometry) with the rosbags
  typestore (``cso_runtime.ros2_cdr``), matches each scan with the odometry at the scan's time
  (interpolated between the two samples around it, or the nearest one within a tolerance), and
  publishes one step of our messages per matched scan: ``clock`` (with the mapping arena),
  ``odom`` and ``scan`` -- exactly what the sim service publishes, so mapper, frontier, policy and
  planner run unchanged. Stale, out-of-order, unmatched and undecodable scans are dropped and counted;
* turns our ``cmd_vel`` into geometry_msgs/Twist CDR on ``NS/cmd_vel`` (TwistStamped with ``cmd_vel_stamped``),
  clamped to the robot's limits, and sends a zero one when no command arrived for ``cmd_timeout_s`` (watchdog),
  at the episode's end and when it stops;
* publishes the map (nav_msgs/OccupancyGrid on ``NS/map``, its last one kept for a late transient-local
  subscriber), the goal (geometry_msgs/PoseStamped on
  ``NS/goal_pose``) and the frontiers (visualization_msgs/MarkerArray on ``NS/explore/frontiers``,
  explore_lite's conventions) for RViz;
* plays the sim's referee part where it can without ground truth: episode status (explored area
  from the map, path length from odometry, decisions) and the end of the episode (no reachable
  frontier left, with the frontier service's reason as the sim has it: ``frontiers/ended_why``; or ``max_steps``).
  Coverage is not known on a real robot and reported as 0.

The time matching (``OdometryBuffer``) is pure and unit-tested; the service is the thin shell.
"""

from __future__ import annotations

import argparse
import functools
import logging
import math
import os
import threading
import time
from bisect import bisect_right
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import zenoh
import zenoh.ext

from cso_runtime import ros2_cdr
from cso_runtime.claims import DECIDE_WITHIN_S, RunClaim, declare_claims, settle_claims
from cso_runtime.config import Bound, ConfigError, check_bounds, from_dict, seconds
from cso_runtime.episode import TERMINATED_MAX_STEPS, TERMINATED_NO_FRONTIER
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, VelocityCommand, wrap_angle_rad
from cso_runtime.keys import PLANNER_KEPT, ROOT, WILDCARD, driver_claim_subject, robot_driver_token
from cso_runtime.messages import (
    EPISODE_OVER,
    MAX_GRID_SIDE_M,
    ROS_RESUME_BY,
    ClockMsg,
    CmdVelMsg,
    EndedWhyMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    MessageError,
    OdometryMsg,
    PlannerContactsMsg,
    ScanMsg,
    check_configured_grid,
    decode,
    encode,
    new_episode_id,
)
from cso_runtime.occupancy import open_on_border
from cso_runtime.processes import starting_launcher_pid
from services.common import NoFrontierEnd, Service, ServiceContext, service_main
from services.dataflow import missing_producers

log = logging.getLogger("cso.ros2_bridge")

SCANS_ELSEWHERE_SAID = 3
"""How many other keys with LaserScans the no-scan note names at most."""

SCANS_ELSEWHERE_NOTE = "LaserScans arrive on "
"""How the no-scan note names the keys that LaserScans arrive on instead (another namespace's)."""

STAMPS_HELD = 200
"""Steps whose scan time the bridge keeps, to stamp the maps, goals and frontiers computed from them."""

LEGACY_PUB_CACHE_PREFIX = "@ros2_pub_cache"
"""Where zenoh-bridge-ros2dds releases from before its advanced subscriber (zenoh-plugin-ros2dds PR #524, August 2025;
1.0.x among them) ask for a transient-local topic's last sample: a query on ``@ros2_pub_cache/*/<key>`` that accepts
replies on any key, which zenoh's PublicationCache answered from ``@ros2_pub_cache/<its id>/<key>``."""

ROS2_BRIDGE_PARAMS_BOUNDS = {
    **seconds(
        "match_tolerance_s", "interpolate_max_gap_s", "max_scan_lag_s", "odom_history_s", "clock_jump_back_s", "odom_jump_confirm_s",
        "pending_timeout_s", "cmd_timeout_s", "log_period_s", "no_scan_warn_s", positive=True,
    ),
    **seconds("map_period_s", "ended_why_wait_s"),
    "odom_jump_m": Bound(0.0, MAX_GRID_SIDE_M, "m", low_open=True, why="the longest side a map may have: messages.MAX_GRID_SIDE_M"),
    "odom_jump_rad": Bound(0.0, 2 * math.pi, "rad", low_open=True, why="a turn: more is never a jump"),
}
"""``Ros2BridgeParams``' bounds: its times at most a day (``config.MAX_WAIT_S``); its arena's, the run's ``max_grid_cells``."""


@dataclass
class Ros2BridgeParams:
    """Parameters of the ROS 2 bridge service (``services.ros2_bridge`` in a profile)."""

    namespace: str = ""
    """ROS namespace of the robot's topics: ``limo1`` -> keys ``limo1/scan``...; empty: bare keys."""
    scan_topic: str = "scan"
    """sensor_msgs/LaserScan in (ROS topic name relative to the namespace)."""
    odom_topic: str = "odom"
    """nav_msgs/Odometry in."""
    cmd_vel_topic: str = "cmd_vel"
    """geometry_msgs/Twist out (TwistStamped with ``cmd_vel_stamped``)."""
    cmd_vel_stamped: bool = False
    """Send geometry_msgs/TwistStamped on ``cmd_vel_topic`` instead of Twist: what ROS 2 Jazzy's diff_drive_controller
    takes (its ``~/cmd_vel``) and Nav2 sends with ``enable_stamped_cmd_vel`` (Kilted's default). Stamped with the
    robot's clock when the command is sent (the newest scan's stamp plus the time since it came; 0, which
    diff_drive_controller reads as its own now, before any scan and in the launcher's stop), in ``base_frame_id``."""
    base_frame_id: str = "base_link"
    """frame_id of the TwistStamped commands (``cmd_vel_stamped``): the robot's base frame, as Nav2 stamps its own."""
    map_topic: str = "map"
    """nav_msgs/OccupancyGrid out."""
    goal_topic: str = "goal_pose"
    """geometry_msgs/PoseStamped out (the current long-term goal)."""
    frontiers_topic: str = "explore/frontiers"
    """visualization_msgs/MarkerArray out (explore_lite's frontier markers)."""
    resume_topic: str = "explore/resume"
    """std_msgs/Bool in (explore_lite's): false pauses exploration, true resumes it (``cso/<robot>/explore/resume``)."""
    map_frame_id: str = "odom"
    """frame_id of the map, goal and frontiers: the map is built in the odometry frame, so this is the frame_id of the
    robot's odometry (warned of when that says another)."""
    match_tolerance_s: float = 0.05
    """A scan that cannot be interpolated takes the nearest odometry sample within this time."""
    interpolate_max_gap_s: float = 0.25
    """Interpolate only between odometry samples at most this far apart."""
    max_scan_lag_s: float = 0.5
    """Stale: a scan older than the newest odometry by more than this (robot clock) is dropped."""
    odom_history_s: float = 2.0
    """Odometry kept for matching."""
    clock_jump_back_s: float = 1.0
    """Odometry stamped this much before the newest sample means the robot's clock started again (its driver
    restarted, a bag played again): the bridge starts a new episode (a new map) on the new clock, as tf2 clears
    its buffer on a jump back in time. Less than this is only out of order (dropped, counted)."""
    odom_jump_m: float = 0.5
    """Odometry that moved more than this beyond twice the robot's top speed (``exploration.robot``) times the
    time since the sample before it is a jump (a glitch, or odometry reset to its origin): dropped and counted
    (``ros_odom:jump``)."""
    odom_jump_rad: float = 1.0
    """The same for the heading, beyond twice the robot's top turn rate."""
    odom_jump_confirm_s: float = 1.0
    """Odometry that goes on from a jump, consistently, for this long (robot clock) has a new origin (limo_base
    restarted): the bridge starts a new episode (a new map) from it, since the old map no longer lines up."""
    pending_timeout_s: float = 0.5
    """A scan newer than every odometry sample waits this long (wall clock) for odometry, then is dropped."""
    cmd_timeout_s: float = 0.5
    """Watchdog: no velocity command for this long (wall clock) sends one zero Twist."""
    resolution_m: float = 0.05
    """Cell size of the mapping arena announced on ``clock``."""
    arena_width_m: float = 20.0
    """Arena width, centred on the first matched odometry pose unless ``arena_origin_xy_m`` is set."""
    arena_height_m: float = 20.0
    """Arena height."""
    arena_origin_xy_m: list[float] | None = None
    """Lower-left corner of the arena in the odometry frame; None: centred on the first pose."""

    def arena_shape(self) -> tuple[int, int]:
        """The arena's ``(ny, nx)`` cells: its size in whole cells, rounded up."""
        return math.ceil(self.arena_height_m / self.resolution_m - 1e-9), math.ceil(self.arena_width_m / self.resolution_m - 1e-9)

    def check_grid(self, bound: int | None = None) -> None:
        """ConfigError for an arena of more cells than ``bound`` (this process's ``max_grid_cells`` when None) or too many
        to count (``messages.check_configured_grid``): ``up`` checks it, and the bridge as it starts."""
        check_configured_grid(
            "services.ros2_bridge.arena_width_m, arena_height_m", self.resolution_m, self.arena_width_m, self.arena_height_m, self.arena_shape, bound
        )
    map_period_s: float = 0.5
    """At most one map on ``map_topic`` per this long (wall clock); the newest map always goes out once nothing newer
    follows. The mapper makes one map per scan, a few hundred kB at 10 Hz: more than RViz needs, sent over the robot's
    WiFi (slam_toolbox publishes its map every few seconds). 0: every map."""
    log_period_s: float = 10.0
    """How often the counters are logged."""
    no_scan_warn_s: float = 5.0
    """No LaserScan on the scan key this long (wall clock; from the bridge's start, or since the last one): said in
    the episode status and the log, with what to check (the robot's zenoh-bridge-ros2dds, its namespace)."""
    ended_why_wait_s: float = 2.0
    """As the sim's: when the policy's goal comes back empty (the episode ends ``no_frontier``), wait (wall clock, at most
    this long) for the frontier service to say why (``frontiers/ended_why``: the result's ``ended_why``, ``status``'s
    reason); the episode ends at that goal either way, and with no frontier service in the profile, without the wait."""

    def validate(self) -> None:
        self.namespace = self.namespace.strip("/")
        if self.namespace and not ros2_cdr.is_ros_name(self.namespace):
            raise ConfigError(f"namespace {self.namespace!r} is not a ROS name (letters, digits, '_', '/')")
        for name in ("scan_topic", "odom_topic", "cmd_vel_topic", "map_topic", "goal_topic", "frontiers_topic", "resume_topic"):
            value = getattr(self, name).strip("/")
            if not ros2_cdr.is_ros_name(value):
                raise ConfigError(f"{name} {value!r} is not a ROS topic name")
            setattr(self, name, value)
        for name in ("resolution_m", "arena_width_m", "arena_height_m"):  # the rest of its numbers: ROS2_BRIDGE_PARAMS_BOUNDS
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive")
        for name in ("map_frame_id", "base_frame_id"):
            frame = getattr(self, name)
            if not ros2_cdr.is_frame_id(frame):
                raise ConfigError(f"{name} {frame!r} is not a tf2 frame id ({ros2_cdr.FRAME_ID_RULE})")
        check_bounds("", self, ROS2_BRIDGE_PARAMS_BOUNDS)
        if self.arena_origin_xy_m is not None and len(self.arena_origin_xy_m) != 2:
            raise ConfigError("arena_origin_xy_m must be [x_m, y_m]")

    def ros_key(self, topic: str) -> str:
        """The Zenoh key zenoh-bridge-ros2dds uses for a ROS topic of this robot."""
        return f"{self.namespace}/{topic}" if self.namespace else topic

    def command_cdr(self, command: VelocityCommand, stamp_ns: int = 0) -> bytes:
        """A velocity command as the robot's ``cmd_vel`` takes it: a Twist, or with ``cmd_vel_stamped`` a TwistStamped
        stamped ``stamp_ns`` (the robot's clock; 0: unknown, the receiver's own now) in ``base_frame_id``."""
        if self.cmd_vel_stamped:
            return ros2_cdr.twist_stamped_to_cdr(command, stamp_ns, self.base_frame_id)
        return ros2_cdr.twist_to_cdr(command)

    def stop_command(self, stamp_ns: int = 0) -> tuple[str, bytes]:
        """The robot's ``cmd_vel`` key and a zero command in CDR (``command_cdr``): what the bridge sends last when it
        stops, and what the launcher sends for it when its process dies (``Launcher.stop_robot``; made before the robot
        has sent any time, so stamped 0)."""
        return self.ros_key(self.cmd_vel_topic), self.command_cdr(VelocityCommand(), stamp_ns)


# --- time matching (pure) -------------------------------------------------------------------------


class OdometryBuffer:
    """Recent odometry samples in time order, and the pose at a scan's time.

    ``match`` interpolates between the samples just before and after the time when they are at most
    ``max_gap_s`` apart (position linearly, yaw along the shorter arc), else takes the nearest sample
    within ``tolerance_s``. Reasons when there is no match: ``no_odometry``, ``stale`` (older than the
    newest sample by more than ``max_lag_s``, or than the history), ``waiting`` (newer than every
    sample: odometry may still come), ``gap`` (odometry around the time is missing).
    """

    def __init__(
        self,
        history_s: float,
        tolerance_s: float,
        max_gap_s: float,
        max_lag_s: float,
        jump_back_s: float = math.inf,
        max_speed_mps: float = math.inf,
        max_turn_radps: float = math.inf,
        jump_m: float = 0.5,
        jump_rad: float = 1.0,
    ) -> None:
        self.history_s, self.tolerance_s, self.max_gap_s, self.max_lag_s = history_s, tolerance_s, max_gap_s, max_lag_s
        self.jump_back_s, self.max_speed_mps, self.max_turn_radps = jump_back_s, max_speed_mps, max_turn_radps
        self.jump_m, self.jump_rad = jump_m, jump_rad
        self.samples: deque[ros2_cdr.OdometrySample] = deque()

    @property
    def newest_s(self) -> float | None:
        return self.samples[-1].stamp_s if self.samples else None

    def add(self, sample: ros2_cdr.OdometrySample) -> bool:
        """Append a sample; False (not added) when it is not newer than the last one."""
        if self.samples and sample.stamp_s <= self.samples[-1].stamp_s:
            return False
        self.samples.append(sample)
        while self.samples and self.samples[0].stamp_s < sample.stamp_s - self.history_s:
            self.samples.popleft()
        return True

    def discontinuity(self, sample: ros2_cdr.OdometrySample, after: ros2_cdr.OdometrySample | None = None) -> str:
        """Why ``sample`` cannot follow ``after`` (default: the newest sample), or "" when it can: ``out_of_order``
        (not newer), ``clock_back`` (older by more than ``jump_back_s``: the robot's clock started again) or
        ``jump`` (moved or turned more than the robot's top speeds, doubled, explain in the time between, plus
        ``jump_m`` / ``jump_rad``)."""
        last = after if after is not None else (self.samples[-1] if self.samples else None)
        if last is None:
            return ""
        dt = sample.stamp_s - last.stamp_s
        if dt < -self.jump_back_s:
            return "clock_back"
        if dt <= 0:
            return "out_of_order"
        moved = math.hypot(sample.pose.x_m - last.pose.x_m, sample.pose.y_m - last.pose.y_m)
        turned = abs(wrap_angle_rad(sample.pose.yaw_rad - last.pose.yaw_rad))
        if moved > self.jump_m + 2 * self.max_speed_mps * dt or turned > self.jump_rad + 2 * self.max_turn_radps * dt:
            return "jump"
        return ""

    def strain(self, sample: ros2_cdr.OdometrySample, after: ros2_cdr.OdometrySample) -> float:
        """How much of what the robot can do since ``after`` ``sample`` takes: the distance moved and the angle turned,
        each over its ``discontinuity`` limit, the larger (above 1: a jump; inf when not newer). Which of two samples
        ``sample`` more plausibly goes on from is the one it strains less."""
        dt = sample.stamp_s - after.stamp_s
        if dt <= 0:
            return math.inf
        moved = math.hypot(sample.pose.x_m - after.pose.x_m, sample.pose.y_m - after.pose.y_m)
        turned = abs(wrap_angle_rad(sample.pose.yaw_rad - after.pose.yaw_rad))
        return max(moved / (self.jump_m + 2 * self.max_speed_mps * dt), turned / (self.jump_rad + 2 * self.max_turn_radps * dt))

    def reset(self, samples: list[ros2_cdr.OdometrySample]) -> None:
        """Forget every sample and start again from ``samples`` (in time order)."""
        self.samples.clear()
        for sample in samples:
            self.add(sample)

    def match(self, stamp_s: float) -> tuple[ros2_cdr.OdometrySample | None, str]:
        if not self.samples:
            return None, "no_odometry"
        newest = self.samples[-1].stamp_s
        if stamp_s < newest - self.max_lag_s:
            return None, "stale"
        stamps = [s.stamp_s for s in self.samples]
        i = bisect_right(stamps, stamp_s)  # samples[:i] are at or before the scan
        before = self.samples[i - 1] if i > 0 else None
        after = self.samples[i] if i < len(self.samples) else None
        if before is not None and before.stamp_s == stamp_s:
            return before, ""
        if before is not None and after is not None and after.stamp_s - before.stamp_s <= self.max_gap_s:
            return _interpolate(before, after, stamp_s), ""
        near = min((s for s in (before, after) if s is not None), key=lambda s: abs(s.stamp_s - stamp_s))
        if abs(near.stamp_s - stamp_s) <= self.tolerance_s:
            return near, ""
        if after is None:
            return None, "waiting"
        return None, "stale" if before is None else "gap"


def _interpolate(a: ros2_cdr.OdometrySample, b: ros2_cdr.OdometrySample, stamp_s: float) -> ros2_cdr.OdometrySample:
    f = (stamp_s - a.stamp_s) / (b.stamp_s - a.stamp_s)
    pa, pb = a.pose, b.pose
    yaw = wrap_angle_rad(pa.yaw_rad + f * wrap_angle_rad(pb.yaw_rad - pa.yaw_rad))
    pose = Pose2D(pa.x_m + f * (pb.x_m - pa.x_m), pa.y_m + f * (pb.y_m - pa.y_m), yaw)
    velocity = a.velocity if f < 0.5 else b.velocity
    return ros2_cdr.OdometrySample(pose, velocity, stamp_s, a.frame_id, a.child_frame_id)


# --- the service ----------------------------------------------------------------------------------


class Ros2BridgeService(Service):
    """A real LIMO behind zenoh-bridge-ros2dds in place of the sim: its ROS 2 scans and odometry in as our steps, our
    cmd_vel out as Twist, and the referee's part that needs no ground truth."""

    name = "ros2_bridge"
    inputs: ClassVar[dict[str, type[Message]]] = {
        "cmd_vel": CmdVelMsg, "map": MapMsg, "goal": GoalMsg, "frontiers": FrontiersMsg, "ended_why": EndedWhyMsg,
        "planner_contacts": PlannerContactsMsg,
    }  # fmt: skip
    optional_inputs: ClassVar[tuple[str, ...]] = ("ended_why", "planner_contacts")  # the reason is words: the episode ends without them; the planner's are kept, not used
    outputs: ClassVar[dict[str, type[Message]]] = {
        "scan": ScanMsg, "odom": OdometryMsg, "clock": ClockMsg, "episode_status": EpisodeStatusMsg, "episode_result": EpisodeResultMsg,
        "explore_resume": ExploreResumeMsg,
    }  # fmt: skip
    tick_period_s = 0.05
    serves_latest = ("map", *PLANNER_KEPT)
    pending: tuple[ros2_cdr.ScanConversion, float] | None
    """A scan waiting for the odometry of its stamp, and when it came (monotonic s); set in ``_start_episode_state``."""

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(Ros2BridgeParams, ctx.params, where="services.ros2_bridge")
        p = self.params
        p.check_grid()  # started by hand, with no `up` to check its profile: before the first odometry makes the arena
        self.robot_cfg = ctx.exploration.robot
        self.odometry = OdometryBuffer(
            p.odom_history_s,
            p.match_tolerance_s,
            p.interpolate_max_gap_s,
            p.max_scan_lag_s,
            p.clock_jump_back_s,
            self.robot_cfg.max_linear_mps,
            self.robot_cfg.max_angular_radps,
            p.odom_jump_m,
            p.odom_jump_rad,
        )
        self.jumped: list[ros2_cdr.OdometrySample] = []
        """Odometry dropped as a jump that goes on consistently from it (a new origin, once it lasts)."""
        self.mount_x_m = ctx.exploration.sensor.mount_x_m
        self.max_steps = ctx.exploration.episode.max_steps
        listed = list(ctx.profile.get("services") or {})
        self.frontier_expected = bool(listed) and "frontier" in listed + missing_producers(listed, ctx.profile.get("services"))
        """Whether a frontier service runs to say why a goal is empty: the profile's, or one it leaves to another process."""
        self.counters: Counter[str] = Counter()
        self.episode = new_episode_id()
        """One episode per bridge start: a restarted bridge counts steps from 0 again."""
        self._start_episode_state()
        self.last_cmd_s: float | None = None
        self.last_ros_map_s: float | None = None
        self.zero_sent = True
        self.sent_any_command = False
        self.last_log_s = time.monotonic()
        self.last_scan_wall_s = time.monotonic()
        """When the last LaserScan arrived (wall clock, monotonic), any scan, even one dropped; the bridge's start before."""
        self.no_scan_note = ""
        """What the episode status says while no scan arrives for ``no_scan_warn_s`` (``scan_silence``)."""
        self.scans_elsewhere: list[str] = []
        """While no scan arrives: the other keys that LaserScans of the same topic name arrive on (another namespace's,
        heard by ``_scan_probe``): the namespace to give, said in the note."""
        self._scan_probe: Any = None
        """A subscriber to ``**/<scan_topic>``, only while no scan arrives (``scan_silence``)."""
        self._bridge_lock = threading.RLock()
        self._ros_subs: list[Any] = []
        self._queryables: list[Any] = []
        self._driver_token: Any = None
        """Says on the network that this run drives the robot's ``cmd_vel`` (``keys.robot_driver_token``)."""
        self._claim_tokens: list[Any] = []
        """A bridge started by hand: its claim on the robot it drives, held while it runs (``claim_robot``)."""
        self._latched: dict[str, Any] = {}
        """ROS topics whose last message a late transient-local subscriber gets (``declare_latched``): the map."""
        self._latched_payloads: dict[str, bytes] = {}
        """The last message sent on each of those topics, for the queries of older zenoh-bridge-ros2dds releases
        (``answer_legacy_cache_query``)."""

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--namespace", default=None, help="ROS namespace of the robot's topics (overrides the profile)")

    @classmethod
    def apply_arguments(cls, args: argparse.Namespace, params: dict[str, Any]) -> dict[str, Any]:
        return params if args.namespace is None else {**params, "namespace": args.namespace}

    def shutdown(self) -> None:
        """Stop taking ROS samples, then stop the robot: one last zero Twist if we ever commanded it."""
        with self._bridge_lock:
            stop_stamp_ns = self.robot_time_ns(time.monotonic())
            entities, self._ros_subs, self._queryables = [*self._ros_subs, *self._queryables], [], []
            if self._scan_probe is not None:
                entities.append(self._scan_probe)
                self._scan_probe = None
            if self._driver_token is not None:
                entities.append(self._driver_token)
                self._driver_token = None
            entities += [*self._claim_tokens, *self._latched.values()]
            self._claim_tokens, self._latched, self._latched_payloads = [], {}, {}
        for entity in entities:  # outside the lock: a callback in flight may be waiting for it
            entity.undeclare()
        if self.session is None or not self.sent_any_command:
            return
        key, zero = self.params.stop_command(stop_stamp_ns)
        try:
            self.session.put(key, zero)
            log.info("stopping: sent a zero %s on %s", self.command_type, key)
        except zenoh.ZError as exc:
            log.error("could not send the final zero Twist: %s", exc)

    # --- wiring ---------------------------------------------------------------------------------
    def start(self) -> None:
        assert self.session is not None
        p, keys = self.params, self.ctx.keys
        cmd_key = p.ros_key(p.cmd_vel_topic)
        by_hand = starting_launcher_pid() is None
        if by_hand and not self.claim_robot(cmd_key):
            return  # stopped while it waited for another bridge's decision: the loop ends, nothing was driven
        for reply in self.session.liveliness().get(robot_driver_token(cmd_key, WILDCARD), timeout=1.0):
            # A token of this robot id is its own run's (up's bridge restarted: its old token still held for a moment),
            # unless this bridge was started by hand: then another run's or bridge's of the same id.
            if reply.ok is not None and ((other := str(reply.ok.key_expr).rsplit("/", 1)[-1]) != self.ctx.robot or by_hand):
                # `up` refuses such a run before it starts; this holds a bridge started by hand, or one of two runs started
                # at once. Exit 2: the launcher does not restart it, and the robot is left to the run that drives it.
                raise ConfigError(f"robot {other}'s run already drives {cmd_key} on this network ({reply.ok.key_expr} is alive): stop it, or give another --namespace")
        self._driver_token = self.session.liveliness().declare_token(robot_driver_token(cmd_key, self.ctx.robot))
        map_key = p.ros_key(p.map_topic)
        self._latched = {p.map_topic: self.declare_latched(map_key)}
        map_cache_key = f"{LEGACY_PUB_CACHE_PREFIX}/{self.session.zid()}/{map_key}"
        # Each callback guarded (``Service.guarded``): an exception in one is logged and counted, the service goes on.
        self._ros_subs = [
            self.session.declare_subscriber(p.ros_key(p.scan_topic), self.guarded(self._on_ros_scan)),
            self.session.declare_subscriber(p.ros_key(p.odom_topic), self.guarded(self._on_ros_odom)),
            self.session.declare_subscriber(p.ros_key(p.resume_topic), self.guarded(self._on_ros_resume)),
        ]
        self._queryables = [
            self.session.declare_queryable(keys.episode_status, self.guarded(self._on_status_query)),
            self.session.declare_queryable(keys.episode_result, self.guarded(self._on_result_query)),
            self.session.declare_queryable(map_cache_key, self.guarded(functools.partial(self.answer_legacy_cache_query, topic=p.map_topic, cache_key=map_cache_key))),
        ]
        log.info(
            "bridging ROS keys %s, %s -> %s; %s -> %s",
            p.ros_key(p.scan_topic),
            p.ros_key(p.odom_topic),
            keys.scan,
            keys.cmd_vel,
            p.ros_key(p.cmd_vel_topic),
        )

    def claim_robot(self, cmd_key: str) -> bool:
        """A bridge started by hand claims the robot behind ``cmd_key`` as ``up`` does for its bridge
        (``cso_runtime.claims``, the same subject): of bridges and runs started at the same moment exactly one drives
        it. The claim is held while the bridge runs, so that a run or bridge started later is refused by it. A
        ConfigError (exit 2) when another has it; False when the service was stopped while it waited."""
        assert self.session is not None
        subject = driver_claim_subject(cmd_key)
        claim = RunClaim.new(f"ros2_bridge-{self.ctx.robot}-pid{os.getpid()}")
        self._claim_tokens = declare_claims(self.session, [subject], claim)
        went_on, lost = settle_claims(self.session, [subject], claim, stop=self.stop_event)
        self._claim_tokens += went_on
        if lost is None:
            return True
        for token in self._claim_tokens:  # withdrawn at once: one that waits for this bridge's decision goes on
            token.undeclare()
        self._claim_tokens = []
        if lost.stopped:
            return False
        other = f"{lost.winner.run_id} has not said within {DECIDE_WITHIN_S:g} s whether it goes on; try again" if lost.undecided else f"{lost.winner.run_id} has it"
        raise ConfigError(
            f"the robot behind {cmd_key} is claimed by another run or bridge on this network ({other}): this bridge would send it "
            f"commands too; stop that one first, or give another --namespace"
        )

    def _on_status_query(self, query: zenoh.Query) -> None:
        query.reply(self.ctx.keys.episode_status, encode(self.episode_status()))

    def _on_result_query(self, query: zenoh.Query) -> None:
        result = self.final_result
        if result is not None:
            query.reply(self.ctx.keys.episode_result, encode(result))
        else:
            query.reply_err(b"episode not finished")

    def declare_latched(self, key: str) -> Any:
        """A publisher that keeps its last sample for subscribers that come later, as a transient-local ROS publisher
        (map_server's ``/map``) does. zenoh-bridge-ros2dds subscribes for a transient-local ROS subscriber (RViz's Map
        display, Nav2's static layer) with zenoh-ext's advanced subscriber, which detects such publishers and asks
        them for their cache. Sample-miss detection numbers the samples, so the cache needs no timestamps (which a
        client session does not have)."""
        assert self.session is not None
        numbered = zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=None)
        return zenoh.ext.declare_advanced_publisher(
            self.session, key, cache=zenoh.ext.CacheConfig(max_samples=1), sample_miss_detection=numbered, publisher_detection=True
        )

    def answer_legacy_cache_query(self, query: zenoh.Query, topic: str, cache_key: str) -> None:
        """The last message sent on a latched topic, for the transient-local subscriber of a zenoh-bridge-ros2dds
        release that asks ``@ros2_pub_cache/*/<key>`` (``LEGACY_PUB_CACHE_PREFIX``) rather than the advanced publisher's
        cache: on the topic's own key, as zenoh's PublicationCache replied (or on the queryable's, ``cache_key``, for a
        query that takes matching replies only); nothing before the first one."""
        with self._bridge_lock:
            payload = self._latched_payloads.get(topic)
        if payload is None:
            return
        any_key = query.accepts_replies() == zenoh.ReplyKeyExpr.ANY
        query.reply(self.params.ros_key(topic) if any_key else cache_key, payload)

    def _put_ros(self, topic: str, payload: bytes) -> None:
        publisher = self._latched.get(topic)
        if publisher is not None:
            self._latched_payloads[topic] = payload
        (publisher if publisher is not None else self.declare_publisher(self.params.ros_key(topic))).put(payload)
        self.counters[f"sent:{topic}"] += 1

    def count_reject(self, what: str, why: str) -> None:
        """A dropped ROS sample: counted per ``<topic>:<reason>`` in the service status, logged."""
        self.counters[f"dropped:{what}"] += 1
        self.reject(what, why)

    # --- ROS -> cso -------------------------------------------------------------------------------
    def _on_ros_resume(self, sample: zenoh.Sample) -> None:
        """explore_lite's ``explore/resume`` (std_msgs/Bool) -> ``cso/<robot>/explore/resume``: false pauses."""
        key = self.params.ros_key(self.params.resume_topic)
        with self._bridge_lock:
            self.counters["received:resume"] += 1
            try:
                resume = ros2_cdr.bool_from_cdr(sample.payload.to_bytes())
            except ros2_cdr.CdrError as exc:
                self.count_reject("ros_resume:bad_cdr", str(exc))
                return
        log.info("%s on %s", "resume" if resume else "pause", key)
        self.publish("explore_resume", ExploreResumeMsg(resume, f"{ROS_RESUME_BY}{key}", stamp_s=time.time()))

    def _on_ros_odom(self, sample: zenoh.Sample) -> None:
        raw = sample.payload.to_bytes()
        with self._bridge_lock:
            self.counters["received:odom"] += 1
            try:
                odom = ros2_cdr.odometry_from_cdr(raw)
            except ros2_cdr.CdrError as exc:
                self.count_reject("ros_odom:bad_cdr", str(exc))
                return
            self._check_odometry_frame(odom)
            if not self._take_odometry(odom):
                return
            if self.pending is not None:
                conv, _ = self.pending
                match, reason = self.odometry.match(conv.scan.stamp_s)
                if reason != "waiting":
                    self.pending = None
                    self._accept_or_drop(conv, match, reason)

    def _check_odometry_frame(self, odom: ros2_cdr.OdometrySample) -> None:
        """The map is built in the odometry's frame and sent out in ``map_frame_id``: odometry in another frame (a
        multi-robot TF tree's ``limo1/odom``) puts the map, goal and frontiers in the wrong frame in RViz and for TF.
        Counted (``odom_in_another_frame``) and warned of once; an empty frame_id says nothing to check. Likewise a
        base frame (the odometry's child_frame_id) other than ``base_frame_id``, with ``cmd_vel_stamped`` on: the
        commands would name a frame that is not the robot's (``base_in_another_frame``)."""
        if self.params.cmd_vel_stamped and odom.child_frame_id and odom.child_frame_id != self.params.base_frame_id:
            self.count_and_warn_once(
                "base_in_another_frame",
                "the robot's odometry is of frame %r, but the TwistStamped commands go out in %r: set "
                "services.ros2_bridge.base_frame_id: %s (a multi-robot TF tree's limo1/base_link)",
                odom.child_frame_id, self.params.base_frame_id, odom.child_frame_id,
            )  # fmt: skip
        if not odom.frame_id or odom.frame_id == self.params.map_frame_id:
            return
        self.count_and_warn_once(
            "odom_in_another_frame",
            "the robot's odometry is in frame %r, but the map, goal and frontiers go out in %r: set "
            "services.ros2_bridge.map_frame_id: %s (the map is built in the odometry's frame)",
            odom.frame_id, self.params.map_frame_id, odom.frame_id,
        )  # fmt: skip

    def count_and_warn_once(self, counter: str, message: str, *args: object) -> None:
        """Count an event the operator should know of (in ``status``), and log it the first time only: most recur on
        every scan or odometry sample."""
        self.counters[counter] += 1
        if self.counters[counter] == 1:
            log.warning(message, *args)

    def _take_odometry(self, odom: ros2_cdr.OdometrySample) -> bool:
        """Add a decoded odometry sample to the buffer (True), or drop it and count why (False). A jump back of the
        robot's clock, or odometry that goes on from a jump for ``odom_jump_confirm_s``, starts a new episode."""
        p = self.params
        why = self.odometry.discontinuity(odom)
        if why == "clock_back":
            self._new_episode(
                f"the robot's clock went back from {self.odometry.newest_s:.3f} s to {odom.stamp_s:.3f} s (its driver restarted?)",
                "clock_jumps_back",
            )
            self.odometry.reset([odom])
            return True
        if why == "out_of_order":
            self.count_reject("ros_odom:out_of_order", f"odometry at {odom.stamp_s:.3f} s is not newer than {self.odometry.newest_s:.3f} s")
            return False
        # Odometry that could go on from both the jump and the samples before it (a glitch just after a good sample,
        # then good samples again; or a reset whose samples the old ones' growing reach takes in) goes on from the one
        # it strains less: taken as the jump's, a good sample kept every later one dropped, and started a new episode.
        continues_jump = (
            bool(self.jumped)
            and not self.odometry.discontinuity(odom, self.jumped[-1])
            and (why == "jump" or self.odometry.strain(odom, self.jumped[-1]) < self.odometry.strain(odom, self.odometry.samples[-1]))
        )
        if why == "jump" or continues_jump:
            if continues_jump:
                self.jumped.append(odom)  # goes on from the jump
            else:
                self.jumped = [odom]
            if self.jumped[-1].stamp_s - self.jumped[0].stamp_s >= p.odom_jump_confirm_s:
                last = self.odometry.samples[-1].pose
                self._new_episode(
                    f"odometry jumped from ({last.x_m:.2f}, {last.y_m:.2f}, {last.yaw_rad:.2f}) and went on from "
                    f"({self.jumped[0].pose.x_m:.2f}, {self.jumped[0].pose.y_m:.2f}, {self.jumped[0].pose.yaw_rad:.2f}) "
                    f"for {p.odom_jump_confirm_s} s (odometry reset?)",
                    "odometry_resets",
                )
                self.odometry.reset(self.jumped)
                self.jumped = []
                return True
            newest = self.odometry.samples[-1]
            self.count_reject(
                "ros_odom:jump",
                f"odometry at {odom.stamp_s:.3f} s is {math.hypot(odom.pose.x_m - newest.pose.x_m, odom.pose.y_m - newest.pose.y_m):.2f} m "
                f"and {abs(wrap_angle_rad(odom.pose.yaw_rad - newest.pose.yaw_rad)):.2f} rad from the sample "
                f"{odom.stamp_s - newest.stamp_s:.3f} s before it: faster than the robot drives",
            )
            return False
        self.jumped = []  # a glitch: odometry goes on where it was
        self.odometry.add(odom)
        return True

    def _start_episode_state(self) -> None:
        """What an episode of the bridge knows, as at its start (the bridge's own start, or a new episode)."""
        self.step = -1
        self.arena: GridGeometry | None = None
        self.last_scan_stamp_s = -math.inf
        self.last_scan_stamp_ns: int | None = None
        self.robot_clock: tuple[int, float] | None = None
        """The newest scan's stamp (ns, the robot's clock) and when it came (``time.monotonic()``): the robot's time now
        for stamped commands (``robot_time_ns``)."""
        self.pending = None
        self.stamps_ns: dict[int, int] = {}
        """Each of the last ``STAMPS_HELD`` steps' scan stamp, exactly as the robot sent it."""
        self.last_pose: Pose2D | None = None
        self.last_twist: VelocityCommand | None = None
        """The twist on ``last_pose``'s odometry: with it, what ``episode_status`` says of the robot."""
        self.path_length_m = 0.0
        self.trajectory: list[tuple[float, float]] = []
        self.held_map: MapMsg | None = None
        """The newest map not sent to ROS yet because of ``map_period_s``."""
        self.last_goal_xy: tuple[float, float] | None = None
        self.episode_state, self.terminated_by = "starting", ""
        self.arena_edge_step: int | None = None
        """The first step whose map has open cells on the arena's edge (``open_on_border``): what lies beyond is
        not mapped, and the episode may end with no frontier left inside the arena."""
        self.decisions = 0
        self.decision_ms: list[float] = []
        self.no_frontier_end = NoFrontierEnd(self.params.ended_why_wait_s)
        self.ended_why = ""
        """Why the episode ended ``no_frontier`` (the frontier service's words), once it has; empty otherwise."""
        self.final_result: EpisodeResultMsg | None = None
        """The result published at the end, answered as it was to a query (the robot's scans go on after the end)."""

    def _new_episode(self, why: str, counter: str) -> None:
        """Start a new episode (a new id: every service starts over, the mapper with an empty map), as a restarted
        sim does: what was mapped in the old odometry frame no longer lines up with the robot's poses."""
        old = self.episode
        self.episode = new_episode_id()
        self._start_episode_state()
        for topic in self.serves_latest:  # the old episode's map and contacts are no restarted service's to resume from
            self.latest.pop(topic, None)
        self.counters[counter] += 1
        log.warning("%s: episode %d ends, a new one (%d) starts with a new map", why, old, self.episode)
        self.publish("episode_status", self.episode_status())

    def _on_ros_scan(self, sample: zenoh.Sample) -> None:
        raw = sample.payload.to_bytes()
        with self._bridge_lock:
            self.counters["received:scan"] += 1
            self.last_scan_wall_s = time.monotonic()
            if self.no_scan_note:
                self.no_scan_note = ""
                log.info("scans arrive on %s", self.params.ros_key(self.params.scan_topic))
                self.end_scan_probe()
            try:
                conv = ros2_cdr.laserscan_from_cdr(raw)
            except ros2_cdr.CdrError as exc:
                self.count_reject("ros_scan:bad_cdr", str(exc))
                return
            self._check_scan_fov(conv.scan)
            if conv.invalid_beams or conv.too_close_beams:
                self.counters["scans_with_invalid_beams"] += 1
                self.counters["invalid_beams"] += conv.invalid_beams + conv.too_close_beams
            stamp = conv.scan.stamp_s
            newest = max(self.last_scan_stamp_s, self.pending[0].scan.stamp_s if self.pending else -math.inf)
            if stamp <= newest:
                self.count_reject("ros_scan:out_of_order", f"scan at {stamp:.3f} s is not newer than {newest:.3f} s")
                return
            self.robot_clock = (conv.stamp_ns, self.last_scan_wall_s)
            match, reason = self.odometry.match(stamp)
            if reason in ("waiting", "no_odometry"):
                if self.pending is not None:
                    self.count_reject("ros_scan:unmatched", "superseded by a newer scan before its odometry arrived")
                self.pending = (conv, time.monotonic())
                return
            self._accept_or_drop(conv, match, reason)

    def _check_scan_fov(self, scan: LaserScan) -> None:
        """The policy (its weights are chosen by the field of view) and the planner take the LiDAR's field of view from
        ``exploration.sensor.fov_deg``, not from the scans: a LaserScan that covers more or less (by more than two
        beams) is counted (``scan_fov_mismatch``) and warned of once."""
        increment_deg = math.degrees(scan.angle_increment_rad)
        covers_deg = len(scan.ranges_m) * increment_deg
        fov_deg = self.ctx.exploration.sensor.fov_deg
        if abs(covers_deg - fov_deg) <= max(2 * increment_deg, 2.0):
            return
        self.count_and_warn_once(
            "scan_fov_mismatch",
            "the robot's LaserScan covers %.0f degrees (%.0f to %.0f), but exploration.sensor.fov_deg is %g: the policy and "
            "the planner go on with %g degrees; set exploration.sensor.fov_deg (and resolution_deg, %.2f here) in the profile",
            covers_deg, math.degrees(scan.angle_min_rad), math.degrees(scan.angle_min_rad) + covers_deg - increment_deg,
            fov_deg, fov_deg, increment_deg,
        )  # fmt: skip

    def _accept_or_drop(self, conv: ros2_cdr.ScanConversion, odom: ros2_cdr.OdometrySample | None, reason: str) -> None:
        stamp = conv.scan.stamp_s
        if odom is None:
            self.count_reject(f"ros_scan:{reason}", f"scan at {stamp:.3f} s, newest odometry at {self.odometry.newest_s}")
            return
        scan_msg = ScanMsg(self.step + 1, conv.scan, odom.pose.compose_offset(self.mount_x_m), self.episode)
        odom_msg = OdometryMsg(self.step + 1, stamp, odom.pose, odom.velocity, self.episode)
        # The checks every subscriber applies, before publishing: a step whose odometry none could read (a finite
        # twist over odom's +-100, a driver's glitch) is dropped with its scan, never kept for episode_status (v4).
        try:
            decode(encode(scan_msg), ScanMsg)
        except MessageError as exc:
            self.count_reject("ros_scan:invalid", str(exc))
            return
        try:
            decode(encode(odom_msg), OdometryMsg)
        except MessageError as exc:
            self.count_reject("ros_odom:invalid", str(exc))
            return
        self.last_scan_stamp_s, self.last_scan_stamp_ns = stamp, conv.stamp_ns
        self.step += 1
        k = self.step
        if self.arena is None:
            self.arena = self._arena_around(odom.pose)
            log.info(
                "arena %.1f x %.1f m at %.3f m, origin (%.2f, %.2f)",
                self.arena.width_m,
                self.arena.height_m,
                self.arena.resolution_m,
                self.arena.origin_x_m,
                self.arena.origin_y_m,
            )
        if self.last_pose is not None:
            self.path_length_m += math.hypot(odom.pose.x_m - self.last_pose.x_m, odom.pose.y_m - self.last_pose.y_m)
        self.last_pose, self.last_twist = odom.pose, odom.velocity
        self.trajectory.append((odom.pose.x_m, odom.pose.y_m))
        self.stamps_ns[k] = conv.stamp_ns
        for s in [s for s in self.stamps_ns if s < k - STAMPS_HELD]:
            self.stamps_ns.pop(s)
        if self.episode_state == "starting":
            self.episode_state = "exploring"
        self.publish("clock", ClockMsg(k, stamp, self.arena, self.episode))
        self.publish("odom", odom_msg)
        self.publish("scan", scan_msg)
        self.processed += 1
        self.last_step = k
        self.counters["steps"] += 1
        if k >= self.max_steps and self.episode_state == "exploring" and self.no_frontier_end.empty_goal is None:
            self.finish(TERMINATED_MAX_STEPS)

    def _arena_around(self, pose: Pose2D) -> GridGeometry:
        p = self.params
        shape = p.arena_shape()
        if p.arena_origin_xy_m is not None:
            ox, oy = p.arena_origin_xy_m
        else:
            ox, oy = pose.x_m - shape[1] * p.resolution_m / 2, pose.y_m - shape[0] * p.resolution_m / 2
        return GridGeometry(p.resolution_m, shape, float(ox), float(oy))

    # --- cso -> ROS -------------------------------------------------------------------------------
    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if not isinstance(msg, CmdVelMsg) and self.of_another_episode(topic, msg, self.episode):  # a map, goal or frontiers from before this bridge started
            return
        with self._bridge_lock:
            if isinstance(msg, EndedWhyMsg):
                self.no_frontier_end.heard = (msg.step, msg.why)
                self.end_if_why_heard(time.monotonic())
            elif isinstance(msg, CmdVelMsg):
                self.forward_command(msg.command, received_s)  # whatever its episode, as before it carried one
                self.keep_carried(msg, self.episode)  # the planner's state and plan, kept as they came for a restarted planner
            elif isinstance(msg, MapMsg):
                self.keep_latest("map", msg)
                if self.arena_edge_step is None and open_on_border(msg.explored, msg.occupied):
                    self.arena_edge_step = msg.step
                    self.counters["arena_edge_reached"] += 1
                    log.warning("%s", self.arena_edge_note())
                if self.last_ros_map_s is None or received_s - self.last_ros_map_s >= self.params.map_period_s:
                    self._send_map(msg, received_s)
                else:
                    self.held_map = msg
                if self.episode_state == "exploring":
                    self.publish("episode_status", self.episode_status())
            elif isinstance(msg, GoalMsg):
                self.take_goal(msg)
            elif isinstance(msg, PlannerContactsMsg):  # kept for a restarted planner
                self.keep_latest(topic, msg)
            elif isinstance(msg, FrontiersMsg) and msg.decide and msg.geometry is not None:
                if self.episode_state in EPISODE_OVER:
                    # The frontier service asks for no decision after the end, unless it did not hear it (restarted
                    # since): it hears it now, and the decision's frontiers do not go over the robot's link.
                    self.counters["decisions_after_episode"] += 1
                    self.publish("episode_status", self.episode_status())
                    return
                points, goals = msg.cluster_points_xy_m()
                stamp_ns = self.stamp_ns_of(msg.step, "frontiers")
                self._put_ros(
                    self.params.frontiers_topic, ros2_cdr.frontier_markers_to_cdr(points, goals, stamp_ns, self.params.map_frame_id)
                )

    def stamp_ns_of(self, step: int, what: str) -> int:
        """The robot's time (ns) of a step's scan, which a map, goal or frontiers sent to ROS is stamped with. A step
        no longer held (only the last ``STAMPS_HELD`` are) takes the newest scan's time, and before any scan the wall
        clock: never 0, which RViz's and Foxglove's TF lookups and plots cannot place. Such an approximation is
        counted (``approximate_stamps``) and logged the first time."""
        stamp_ns = self.stamps_ns.get(step)
        if stamp_ns is not None:
            return stamp_ns
        if self.last_scan_stamp_ns is not None:
            stamp_ns, whence = self.last_scan_stamp_ns, "the newest scan's time"
        else:
            stamp_ns, whence = time.time_ns(), "the wall clock (no scan yet)"
        self.counters["approximate_stamps"] += 1
        if self.counters["approximate_stamps"] == 1:
            log.warning("%s of step %d: its scan time is no longer held (the last %d steps are), stamped with %s; later ones are only counted", what, step, STAMPS_HELD, whence)
        return stamp_ns

    def _send_map(self, msg: MapMsg, now_s: float) -> None:
        """A map -> nav_msgs/OccupancyGrid on ``map_topic``, stamped with its step's scan time."""
        self.held_map, self.last_ros_map_s = None, now_s
        stamp_ns = self.stamp_ns_of(msg.step, "map")
        self._put_ros(self.params.map_topic, ros2_cdr.occupancy_grid_to_cdr(msg.grid, msg.geometry, stamp_ns, self.params.map_frame_id))

    def forward_command(self, command: VelocityCommand, received_s: float) -> None:
        """Our command -> Twist on the robot's cmd_vel, within the robot's limits."""
        r = self.robot_cfg
        safe = command.clamped(r.max_linear_mps, r.max_angular_radps)
        if safe != command:
            self.counters["clamped_commands"] += 1
        if self.episode_state in EPISODE_OVER and safe != VelocityCommand():
            # The scans go on after the end, and a command may still come (the planner's last goal, a frontier service
            # that did not hear the end): the robot would drive again while status says done. Over is over, as for
            # explore_lite.
            self.count_and_warn_once(
                "commands_after_episode",
                "the episode is over (%s): the robot is held still, every command after it is sent as a zero Twist",
                self.terminated_by,
            )
            safe = VelocityCommand()
        self.send_command(safe, received_s)
        self.last_cmd_s = received_s
        self.zero_sent = safe == VelocityCommand()
        self.sent_any_command = True

    @property
    def command_type(self) -> str:
        """What the robot's ``cmd_vel`` carries, for the log: Twist or TwistStamped (``cmd_vel_stamped``)."""
        return "TwistStamped" if self.params.cmd_vel_stamped else "Twist"

    def robot_time_ns(self, now_s: float) -> int:
        """The robot's clock at ``now_s`` (``time.monotonic()``) as the bridge knows it: the newest scan's stamp plus the
        time since that scan came, so behind the robot's clock by the scan's delivery delay, never ahead of it. 0 before
        any scan of this episode: an unknown time, which diff_drive_controller reads as its own now."""
        if self.robot_clock is None:
            return 0
        stamp_ns, came_s = self.robot_clock
        return stamp_ns + max(0, round((now_s - came_s) * ros2_cdr.NS_PER_S))

    def send_command(self, command: VelocityCommand, now_s: float) -> None:
        """A velocity command on the robot's ``cmd_vel``: a Twist, or a TwistStamped (``cmd_vel_stamped``) stamped with
        the robot's time at ``now_s``, as Nav2's controller_server stamps its commands when it sends them: a driver
        that drops commands older than its timeout (diff_drive_controller's ``cmd_vel_timeout``) measures the
        bridge's delay, not the planner's."""
        self._put_ros(self.params.cmd_vel_topic, self.params.command_cdr(command, self.robot_time_ns(now_s)))

    def take_goal(self, g: GoalMsg) -> None:
        if self.episode_state in EPISODE_OVER:
            # The answer to a decision asked after the end (a frontier service that did not hear it): the robot is held
            # still, so its goal is not shown in RViz, nor counted among the ended episode's decisions.
            self.counters["goals_after_episode"] += 1
            return
        if g.decided:
            self.decisions += 1
            self.decision_ms.append(g.decision_ms)
            if not g.has_goal and self.episode_state == "exploring" and self.no_frontier_end.empty_goal is None:
                self.no_frontier_end.empty_goal = (g.step, time.monotonic())
                self.end_if_why_heard(time.monotonic())
        xy = g.goal_xy_m
        if xy is not None and xy != self.last_goal_xy:
            self.last_goal_xy = (float(xy[0]), float(xy[1]))
            stamp_ns = self.stamp_ns_of(g.step, "goal")
            self._put_ros(
                self.params.goal_topic, ros2_cdr.pose_stamped_to_cdr(xy[0], xy[1], 0.0, stamp_ns, self.params.map_frame_id)
            )
        elif xy is None:
            self.last_goal_xy = None

    def end_if_why_heard(self, now_s: float) -> None:
        """While an empty goal's end waits (``NoFrontierEnd``): end with the frontier service's reason once heard, or
        without one after ``ended_why_wait_s``."""
        why = self.no_frontier_end.why_now(now_s, self.frontier_expected)
        if why is not None and self.episode_state == "exploring":
            self.finish(TERMINATED_NO_FRONTIER, why)

    def on_tick(self, now_s: float) -> None:
        with self._bridge_lock:
            self.end_if_why_heard(now_s)
            if self.last_cmd_s is not None and not self.zero_sent and now_s - self.last_cmd_s > self.params.cmd_timeout_s:
                self.send_command(VelocityCommand(), now_s)
                self.zero_sent = True
                self.counters["watchdog_stops"] += 1
                log.warning("no velocity command for %.2f s: sent a zero %s (watchdog)", now_s - self.last_cmd_s, self.command_type)
            if self.held_map is not None and self.last_ros_map_s is not None and now_s - self.last_ros_map_s >= self.params.map_period_s:
                if self.held_map.episode in (0, self.episode):  # not one of an episode that has ended since
                    self._send_map(self.held_map, now_s)
                self.held_map = None
            if self.pending is not None and now_s - self.pending[1] > self.params.pending_timeout_s:
                conv, _ = self.pending
                self.pending = None
                self.count_reject(
                    "ros_scan:no_odometry",
                    f"no odometry at or after the scan at {conv.scan.stamp_s:.3f} s within {self.params.pending_timeout_s} s",
                )
            self.scan_silence(now_s)
            if now_s - self.last_log_s >= self.params.log_period_s:
                self.last_log_s = now_s
                log.info("counters: %s", dict(sorted(self.counters.items())))

    def scan_silence(self, now_s: float) -> None:
        """Once no scan has come for ``no_scan_warn_s``, say so in the episode status (published at once, as the live
        view shows it) and the log: with no scan the episode neither starts nor goes on, and every service looks
        fine. A wrong ``--namespace`` or a robot bridge that is not running look just like this. While the silence
        lasts, the note (what ``status`` asks for) says how long it has lasted; logged and published once."""
        silent_s = now_s - self.last_scan_wall_s
        if silent_s < self.params.no_scan_warn_s:
            return
        key = self.params.ros_key(self.params.scan_topic)
        since = "since the bridge started" if self.counters["received:scan"] == 0 else "since the last one"
        said = self.no_scan_note
        if self.scans_elsewhere:  # the robot's bridge runs, in another namespace: which one is known
            given = [f"--namespace {ns}" if (ns := k.removesuffix(self.params.scan_topic).strip("/")) else "no --namespace" for k in self.scans_elsewhere]
            check = (
                f"{SCANS_ELSEWHERE_NOTE}{', '.join(self.scans_elsewhere)} instead: if that is this robot, give {' or '.join(given)} "
                "(its zenoh-bridge-ros2dds -n)"
            )
        else:
            check = "is the robot's zenoh-bridge-ros2dds running, its LiDAR publishing, and --namespace its -n?"
        self.no_scan_note = f"no LaserScan on {key} for {silent_s:.0f} s ({since}): {check} (docs/hardware.md, Troubleshooting)"
        if not said:
            self.start_scan_probe()
        elif not self.scans_elsewhere or SCANS_ELSEWHERE_NOTE in said:
            return  # said already: the note only keeps its silence up to date (it stayed "for 5 s" however long it lasted)
        log.warning("%s", self.no_scan_note)
        self.publish("episode_status", self.episode_status())

    def start_scan_probe(self) -> None:
        """Listen for LaserScans on any key that ends in the scan topic (``**/scan``), as long as none comes on ours:
        a robot bridge in another namespace (``-n /limo1`` against ``--namespace limo2``, or none) is then named."""
        if self.session is None or self._scan_probe is not None:
            return
        self._scan_probe = self.session.declare_subscriber(f"**/{self.params.scan_topic}", self.guarded(self._on_probe_scan))

    def end_scan_probe(self) -> None:
        """Scans come on our key: the probe and what it heard go (a callback in flight may be waiting for the lock)."""
        probe, self._scan_probe = self._scan_probe, None
        self.scans_elsewhere = []
        if probe is not None:
            threading.Thread(target=probe.undeclare, name="scan-probe-undeclare", daemon=True).start()

    def _on_probe_scan(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key == self.params.ros_key(self.params.scan_topic) or key.split("/", 1)[0] == ROOT:  # ours, or our services' scans
            return
        with self._bridge_lock:
            if self.no_scan_note and key not in self.scans_elsewhere and len(self.scans_elsewhere) < SCANS_ELSEWHERE_SAID:
                self.scans_elsewhere.append(key)

    def extra_status(self) -> dict[str, int]:
        with self._bridge_lock:
            return dict(self.counters)

    # --- episode status (no ground truth on a real robot) ---------------------------------------
    def explored_area_m2(self) -> float:
        m = self.kept("map", MapMsg)
        return 0.0 if m is None else float(np.count_nonzero(m.explored)) * m.geometry.cell_area_m2

    def arena_edge_note(self) -> str:
        """What ``status`` and the log say once the map has reached its arena's edge, or ""."""
        if self.arena_edge_step is None:
            return ""
        a = self.arena
        size = f"{a.width_m:.1f} x {a.height_m:.1f} m " if a is not None else ""
        return (
            f"the map reached the edge of its {size}arena at step {self.arena_edge_step}: nothing beyond it is mapped or "
            "explored (services.ros2_bridge.arena_width_m, arena_height_m)"
        )

    def episode_status(self) -> EpisodeStatusMsg:
        with self._bridge_lock:
            return EpisodeStatusMsg(
                state=self.episode_state,
                step=max(self.step, 0),
                scene=f"ros2:{self.params.namespace or '/'}",
                method=str(self.ctx.profile.get("method", "")),
                coverage_pct=0.0,
                explored_area_m2=self.explored_area_m2(),
                path_length_m=self.path_length_m,
                goal_xy_m=list(self.last_goal_xy) if self.last_goal_xy else None,
                decisions=self.decisions,
                last_decision_ms=self.decision_ms[-1] if self.decision_ms else 0.0,
                terminated_by=self.terminated_by,
                reason="; ".join(note for note in (self.ended_why, self.no_scan_note, self.arena_edge_note()) if note),
                episode=self.episode,
                pose=self.last_pose,
                twist=self.last_twist,
                coverage_measured=False,  # a real robot: no ground truth, its coverage_pct 0 is no measure
            )

    def episode_result(self) -> EpisodeResultMsg:
        m = self.kept("map", MapMsg)
        known_free = m.occupancy().open if m is not None else np.zeros((1, 1), bool)
        return EpisodeResultMsg(
            scene=f"ros2:{self.params.namespace or '/'}",
            steps=max(self.step, 0),
            explored_area_m2=self.explored_area_m2(),
            coverage_pct=0.0,
            traversable_area_m2=float(known_free.sum()) * (m.geometry.cell_area_m2 if m is not None else 0.0),
            path_length_m=self.path_length_m,
            terminated_by=self.terminated_by,
            decisions=self.decisions,
            decision_ms=np.array(self.decision_ms, dtype=float),
            trajectory_xy_m=np.array(self.trajectory, dtype=float).reshape(-1, 2),
            coverage_curve_pct=np.zeros(0),
            explored_free=known_free,
            plan_free=known_free,
            resolution_m=m.geometry.resolution_m if m is not None else self.params.resolution_m,
            method=str(self.ctx.profile.get("method", "")),
            seed=int(self.ctx.profile.get("seed", 0)),
            final_map=m,
            ended_why=self.ended_why,
            episode=self.episode,  # whose result: the bridge starts a new episode in the same process
        )

    def finish(self, terminated_by: str, ended_why: str = "") -> None:
        """End the episode: its status (``reason``: ``ended_why`` first) and its result go out."""
        self.episode_state, self.terminated_by, self.ended_why = "done", terminated_by, ended_why
        self.no_frontier_end.empty_goal = None
        if self.arena_edge_step is not None:
            log.warning("the episode ends (%s), but %s", terminated_by, self.arena_edge_note())
        log.info(
            "episode done at step %d: %s (explored %.1f m2, path %.1f m)",
            self.step,
            terminated_by,
            self.explored_area_m2(),
            self.path_length_m,
        )
        if self.sent_any_command and not self.zero_sent:  # held still from the end on, not only once the watchdog fires
            self.send_command(VelocityCommand(), time.monotonic())
            self.zero_sent = True
        self.publish("episode_status", self.episode_status())
        self.final_result = self.episode_result()
        self.publish("episode_result", self.final_result)


def main(argv: list[str] | None = None) -> int:
    """``python -m services.ros2_bridge --config FILE --robot ID [--namespace NS] --connect EP``."""
    return service_main(Ros2BridgeService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
