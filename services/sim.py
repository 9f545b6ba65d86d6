"""Simulator service: a ``cso_runtime.simulator.Simulator`` on Zenoh, and the episode's referee.

Publishes clock, odometry and scan each step, applies ``cmd_vel``, and, being the only process that
knows the ground truth, measures coverage on the mapper's map (``GroundTruthMetrics``, the same code
as ``eval``), decides when the episode ends (section 4.1), and answers status/result queries.

Lockstep (deterministic): step k+1 happens only when the map, the goal and the command of step k
have arrived; a missing answer is re-requested by re-publishing the step after ``lockstep_timeout_s``
(logged, counted) and the episode fails after ``lockstep_give_up_s``. Real time: one step every
``control_period_s / real_time_factor`` with the latest command (a stop when it is older than
``cmd_timeout_s``).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import zenoh

from cso_runtime.config import Bound, ConfigError, SensorConfig, check_bounds, from_dict, seconds
from cso_runtime.episode import TERMINATED_COVERAGE, TERMINATED_MAX_STEPS, TERMINATED_NO_FRONTIER, GroundTruthMetrics
from cso_runtime.geometry import LaserScan, Pose2D, VelocityCommand, mean_twist
from cso_runtime.keys import PLANNER_KEPT, RobotKeys
from cso_runtime.messages import (
    ClockMsg,
    CmdVelMsg,
    EndedWhyMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    GoalMsg,
    MapMsg,
    Message,
    OdometryMsg,
    PlannerContactsMsg,
    ScanMsg,
    encode,
    new_episode_id,
)
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import Simulator, StateSaving, make_simulator, mujoco_config
from cso_runtime.transport import track_robots_liveliness
from services import waited_for_at_start
from services.common import NoFrontierEnd, Service, ServiceContext, service_main
from services.dataflow import missing_producers

if TYPE_CHECKING:
    from robot_sim.viewer import SimViewer

log = logging.getLogger("cso.sim")

MAX_STEPS_PER_TICK = 4
"""Real time: steps one tick may run when more than one is due (a real_time_factor above one step per tick, or a
late tick); up to 4 x 0.25 s / 0.02 s = 50x real time."""

BACKENDS = {"kinematic": "2d", "2d": "2d", "mujoco": "mujoco"}


class PublishedStep(NamedTuple):
    """What the episode status says of the robot: the step last published, its odometry's pose and twist, and the path
    driven up to it. Replaced as one by ``publish_step`` and read once by ``episode_status``, which a status query runs
    on Zenoh's thread while the step runs: never a pose of one step with the twist or the step number of another."""

    step: int
    pose: Pose2D
    twist: VelocityCommand
    path_length_m: float


MAX_REAL_TIME_FACTOR = 10_000.0
"""The fastest ``real_time_factor`` taken: a 0.25 s control step every 25 microseconds, faster than any simulator here
steps (the 2D one about 100 times real time); lockstep runs as fast as the pipeline does."""

SIM_PARAMS_BOUNDS = {
    "real_time_factor": Bound(0.0, MAX_REAL_TIME_FACTOR, low_open=True, why="MAX_REAL_TIME_FACTOR"),
    **seconds("cmd_timeout_s", "lockstep_timeout_s", "lockstep_give_up_s", positive=True),
    **seconds("min_step_period_s", "wait_for_services_s", "start_delay_s", "status_period_s", "ended_why_wait_s"),
}
"""``SimParams``' bounds: its times at most a day (``config.MAX_WAIT_S``)."""


@dataclass
class SimParams:
    """Parameters of the sim service (``services.sim`` in a profile)."""

    backend: str = "kinematic"
    """Simulator by name: ``kinematic`` (fast 2D) or ``mujoco`` (physics LIMO, ``robot_sim``)."""
    real_time_factor: float = 1.0
    """Real-time mode: simulated seconds per wall-clock second."""
    cmd_timeout_s: float = 1.0
    """Real-time mode: a command older than this (wall clock) is replaced by a stop. This is the command watchdog of a
    simulation under ``up``, whatever the backend: each control step hands the simulator its command afresh, so the
    MuJoCo LIMO's own ``mujoco.watchdog_s`` (simulated time) never fires here while it is at least
    ``robot.control_period_s`` (docs/runtime.md, Command watchdogs). Wall clock: at ``real_time_factor`` k the robot
    drives on for up to k times this in simulated time. Lockstep needs none: a step waits for its command."""
    lockstep_timeout_s: float = 2.0
    """Lockstep: re-publish the current step when no progress for this long (wall clock)."""
    lockstep_give_up_s: float = 60.0
    """Lockstep: the episode fails when one step waits longer than this."""
    min_step_period_s: float = 0.0
    """Lockstep: wall-clock floor per step (0 = as fast as the pipeline; demos and tests slow it)."""
    wait_for_services_s: float = 30.0
    """Before step 0, wait (wall clock, at most this long) until every other service of the profile, and every
    service it leaves out that the episode needs (a shared server's policy), has declared its liveliness token, so
    that none misses step 0: a policy that loads torch and its weights comes up a second after the others, and its
    first decision used to wait for a lockstep re-publish. After this long the episode starts anyway, with a
    warning that names the missing services."""
    start_delay_s: float = 0.5
    """Then wait this long before step 0, so the services' subscriptions have reached every peer
    (re-publishing the step covers a miss)."""
    status_period_s: float = 0.1
    """``episode/status`` goes out at the end of the episode and otherwise at most this often (wall
    clock), so that its listeners (the launcher's live view) are not woken on every step; ``cso-runtime
    status`` queries the current one at any time. 0 = after every step."""
    mujoco: dict[str, Any] = field(default_factory=dict)
    """``backend: mujoco`` only: the MuJoCo LIMO's parameters over its defaults, keys as in ``configs/robot_sim.yaml``
    (``{odom_trans_noise_frac: 0.01}`` for odometry drift, ``timestep_s``, the acceleration limits). The LiDAR's
    mount is ``exploration.sensor.mount_x_m``, which the mapper and the planner use too."""
    ended_why_wait_s: float = 2.0
    """When the policy's goal comes back empty (the episode ends ``no_frontier``), wait (wall clock, at most this long)
    for the frontier service to say why (``frontiers/ended_why``: the result's ``ended_why``, ``status``'s reason); the
    episode ends at the step of that goal either way, and with no frontier service, without the wait."""
    viewer: bool = False
    """Open a MuJoCo viewer window on the LIMO (``backend: mujoco`` only; needs a display, and mjpython on
    macOS): refreshed after each control step, the current goal as a red ball. ``service sim --viewer``,
    or ``up --set services.sim.viewer=true``. Closing the window does not stop the episode."""

    def validate(self) -> None:
        if self.backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        check_bounds("", self, SIM_PARAMS_BOUNDS)  # each key's range (its times above 0 or at least 0): its one check
        if not self.lockstep_give_up_s > self.lockstep_timeout_s:  # else a lost message fails the episode, never re-published
            raise ConfigError(f"lockstep_give_up_s ({self.lockstep_give_up_s} s) must exceed lockstep_timeout_s ({self.lockstep_timeout_s} s)")
        if self.viewer and BACKENDS[self.backend] != "mujoco":
            raise ConfigError(f"viewer needs backend mujoco (the {self.backend} simulator has no 3D world to show)")
        if self.mujoco:
            if BACKENDS[self.backend] != "mujoco":
                raise ConfigError(f"mujoco parameters ({', '.join(self.mujoco)}) need backend mujoco, not {self.backend}")
            mujoco_config({k: v for k, v in self.mujoco.items() if k != "lidar_mount_x_m"}, SensorConfig(), where="mujoco")


def build_simulator(profile: dict[str, Any], params: SimParams, ctx: ServiceContext) -> Simulator:
    """The scene of the profile in the simulator named by ``params.backend``."""
    spec = str(profile.get("scene", "generated:small:1:0"))
    refs = resolve_scenes(spec, limit=1, resolution_m=float(profile.get("m_per_px", 0.1)))
    if not refs:
        raise ConfigError(f"scene {spec!r} resolves to no scene")
    plan = refs[0].load()
    seed = int(profile.get("seed", 0))
    return make_simulator(BACKENDS[params.backend], plan, ctx.exploration.sensor, ctx.exploration.robot, seed=seed, mujoco=params.mujoco)


def open_viewer(sim: Simulator) -> SimViewer:
    """The window of ``viewer: true``; a ConfigError (the service exits 2 and is not restarted) where none can open."""
    from robot_sim.viewer import SimViewer, ViewerUnavailable  # noqa: PLC0415  (GUI code only when asked for)

    try:
        return SimViewer(sim)  # type: ignore[arg-type]  # validate() allows it only with backend mujoco
    except ViewerUnavailable as exc:
        raise ConfigError(f"services.sim.viewer: {exc}") from None


class SimService(Service):
    """The simulator on Zenoh and the episode's referee: steps the robot, measures coverage against the ground truth and
    ends the episode."""

    name = "sim"
    inputs = {
        "cmd_vel": CmdVelMsg, "cmd_vel_ahead": CmdVelMsg, "map": MapMsg, "goal": GoalMsg, "ended_why": EndedWhyMsg,
        "planner_contacts": PlannerContactsMsg,
    }  # fmt: skip
    optional_inputs = ("cmd_vel_ahead", "ended_why", "planner_contacts")  # a step ahead is a speed-up: without it the sim steps on cmd_vel; the reason is words; the planner's are kept, not used
    outputs = {"scan": ScanMsg, "odom": OdometryMsg, "clock": ClockMsg, "episode_status": EpisodeStatusMsg, "episode_result": EpisodeResultMsg}
    serves_latest = ("map", *PLANNER_KEPT)
    tick_period_s = 0.02
    """How often ``on_tick`` runs: real-time steps run on the first tick at or after they are due."""

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(SimParams, ctx.params, where="services.sim")
        self.sim = build_simulator(ctx.profile, self.params, ctx)
        self.seed = int(ctx.profile.get("seed", 0))
        self.sim.reset(self.seed)
        self.episode = new_episode_id()
        self.metrics = GroundTruthMetrics(self.sim.plan, ctx.exploration.episode)
        self.max_steps = ctx.exploration.episode.max_steps
        self.period_s = ctx.exploration.robot.control_period_s
        self.method = str(ctx.profile.get("method", ""))
        self.step = 0
        self.episode_state = "starting"
        self.terminated_by = ""
        self.fail_reason = ""
        self.maps: dict[int, MapMsg] = {}
        self.goals: dict[int, GoalMsg] = {}
        self.cmds: dict[int, CmdVelMsg] = {}
        self.ahead: tuple[int, VelocityCommand, tuple, LaserScan] | None = None
        """Lockstep: the next state and scan stepped ahead on the planner's provisional command (step,
        command, simulator state, scan); used when the step's cmd_vel is that command."""
        self.steps_on_stored_scan = 0
        """Lockstep steps whose next scan was the one stepped ahead to (not computed on the command)."""
        self.measured_step = -1
        self.goal_step = -1
        self.last_map: OccupancyMap | None = None
        self.explored_m2 = 0.0
        """Ground-truth explored area of ``last_map`` (counted once per map)."""
        self.coverage_curve: list[float] = []
        self.trajectory: list[tuple[float, float]] = [tuple(self.sim.true_pose().xy)]
        self.odom_twist = VelocityCommand()
        """``odom``'s twist: the mean over the step just run, from odometry (at rest before the first step)."""
        self.path_length_m = 0.0
        self.published = PublishedStep(self.step, self.sim.odometry(), self.odom_twist, self.path_length_m)
        """The step, pose, twist and path length of the last ``odom`` published: what the episode status says of the
        robot, taken as one (a status query answered on another thread while the step runs sees a published step,
        never half of one: ``advance`` counts the step and its path before it publishes it)."""
        self.decisions = 0
        self.decision_ms: list[float] = []
        self.goal_xy: list[float] | None = None
        self.last_cmd: tuple[CmdVelMsg, float] | None = None
        self.started_s = time.monotonic()
        listed = list(ctx.profile.get("services") or {})
        self.left_out_needed = set(missing_producers(listed, ctx.profile.get("services"))) if listed else set()
        """The services the episode needs that the profile leaves to other processes (``up --without policy``, or not
        listed: a shared policy server's; ``services.dataflow.missing_producers``, as the launcher's ``awaited``).
        Step 0 waits for them too: started without its policy, a lockstep episode re-published step 0 every
        ``lockstep_timeout_s`` with its give-up clock running, and a real-time one spent its steps standing still."""
        sections = ctx.profile.get("services") or {}
        self.expected_services = {name for name in listed if name != ctx.name and waited_for_at_start(sections[name])} | self.left_out_needed
        """The profile's other services and those it leaves out: step 0 waits for their liveliness tokens
        (``wait_for_services_s``); not for a command node that declares none (``services.waited_for_at_start``)."""
        self.said_waiting_for_left_out = False
        self.alive_services: set[tuple[str, str]] = set()
        """(robot, service) of every liveliness token seen (``missing_services``)."""
        self.services_ready_s: float | None = None if self.expected_services else self.started_s
        self.step_started_s = math.inf
        self.next_step_s = math.inf
        """Real time: when the next step is due, on a fixed schedule from the episode's start (``real_time_factor``)."""
        self.last_publish_s = 0.0
        self.status_published_s = -math.inf
        self.timeouts = 0
        self.result: EpisodeResultMsg | None = None
        self.no_frontier_end = NoFrontierEnd(self.params.ended_why_wait_s)
        """An empty goal's end, while it waits for the frontier service's reason: the episode has ended at that goal's
        step, nothing more is measured or stepped."""
        self._declarations: list[Any] = []
        self.viewer = open_viewer(self.sim) if self.params.viewer else None

    # --- wiring ---------------------------------------------------------------------------------
    def start(self) -> None:
        assert self.session is not None
        keys = self.ctx.keys
        self._declarations.append(self.session.declare_queryable(keys.episode_status, self.guarded(self._on_status_query)))
        self._declarations.append(self.session.declare_queryable(keys.episode_result, self.guarded(self._on_result_query)))
        if self.expected_services:  # every robot's: one policy server may serve several robots under its own id
            self._declarations.append(self.session.liveliness().declare_subscriber(RobotKeys("*").alive("*"), self.guarded(self.on_alive), history=True))

    def on_alive(self, sample: Any) -> None:
        track_robots_liveliness(self.alive_services, sample)

    def missing_services(self) -> set[str]:
        """The profile's services with no liveliness token of this robot; a policy under another robot's id
        counts (one policy server may serve several robots, ``serve_all_robots``), another robot's mapper
        or planner does not."""
        own = {name for robot, name in self.alive_services if robot == self.ctx.robot}
        policy_elsewhere = any(name == "policy" for _, name in self.alive_services)
        return {name for name in self.expected_services if name not in own and not (name == "policy" and policy_elsewhere)}

    def _on_status_query(self, query: zenoh.Query) -> None:
        query.reply(self.ctx.keys.episode_status, encode(self.episode_status()))

    def _on_result_query(self, query: zenoh.Query) -> None:
        if self.result is not None:
            query.reply(self.ctx.keys.episode_result, encode(self.result))
        else:
            query.reply_err(b"episode not finished")

    # --- the step ---------------------------------------------------------------------------------
    def publish_step(self, scan: LaserScan | None = None) -> None:
        """Clock, odometry and scan of the current step (also used to re-request a lost step)."""
        self.published = out = PublishedStep(self.step, self.sim.odometry(), self.odom_twist, self.path_length_m)
        scan = scan if scan is not None else self.sim.scan()
        # The scan first: the mapper, at the head of the step's chain, starts at once (it carries the
        # episode id, so the mapper need not wait for the clock).
        self.publish("scan", ScanMsg(self.step, scan, self.sim.sensor_pose(), self.episode))
        self.last_step = self.step  # what `status` shows for the sim
        self.publish("odom", OdometryMsg(out.step, self.sim.time_s, out.pose, out.twist, self.episode))
        self.publish("clock", ClockMsg(self.step, self.sim.time_s, self.sim.plan.geometry, self.episode))
        self.last_publish_s = time.monotonic()
        if self.viewer is not None:  # after the step is out: the window never delays the pipeline
            self.viewer.show(self.goal_xy)

    def episode_status(self) -> EpisodeStatusMsg:
        cov = self.coverage_curve[-1] if self.coverage_curve else 0.0
        out = self.published  # read once: a step published meanwhile replaces it whole
        return EpisodeStatusMsg(
            state=self.episode_state,
            step=out.step,
            scene=self.sim.plan.name,
            method=self.method,
            coverage_pct=float(min(cov, 100.0)),
            explored_area_m2=self.explored_m2,
            path_length_m=out.path_length_m,
            goal_xy_m=self.goal_xy,
            decisions=self.decisions,
            last_decision_ms=self.decision_ms[-1] if self.decision_ms else 0.0,
            terminated_by=self.terminated_by,
            reason=self.fail_reason,
            lockstep_timeouts=self.timeouts,
            episode=self.episode,
            map_origin=self.sim.plan.map_origin,
            pose=out.pose,  # the step's odom, as published
            twist=out.twist,
            coverage_measured=True,  # the sim knows the scene: its coverage is measured against its plan
        )

    def finish(self, state: str, terminated_by: str, reason: str = "", ended_why: str = "") -> None:
        """End the episode: its status (``reason``: why it failed, or ``ended_why``) and its result go out."""
        self.no_frontier_end.empty_goal = None
        self.episode_state, self.terminated_by, self.fail_reason = state, terminated_by, reason or ended_why
        explored_free = self.metrics.explored_free(self.last_map) if self.last_map is not None else np.zeros(self.sim.plan.free.shape, bool)
        self.result = EpisodeResultMsg(
            scene=self.sim.plan.name,
            steps=self.step,
            explored_area_m2=self.explored_m2,
            coverage_pct=self.coverage_curve[-1] if self.coverage_curve else 0.0,
            traversable_area_m2=self.metrics.region_area_m2,
            path_length_m=self.path_length_m,
            terminated_by=terminated_by,
            decisions=self.decisions,
            decision_ms=np.array(self.decision_ms, dtype=float),
            trajectory_xy_m=np.array(self.trajectory, dtype=float),
            coverage_curve_pct=np.array(self.coverage_curve, dtype=float),
            explored_free=explored_free,
            plan_free=self.sim.plan.free,
            resolution_m=self.sim.plan.resolution_m,
            method=self.method,
            seed=self.seed,
            final_map=self.kept("map", MapMsg),
            map_origin=self.sim.plan.map_origin,
            ended_why=ended_why,
            episode=self.episode,  # whose result: a launcher never takes it for a later episode's (after a restart)
        )
        why = f" ({self.fail_reason})" if self.fail_reason else ""
        log.info("episode %s at step %d: %s%s, coverage %.2f%%, %.2f m2 explored", state, self.step, terminated_by, why, self.result.coverage_pct, self.explored_m2)
        self.publish("episode_status", self.episode_status())
        self.publish("episode_result", self.result)

    @property
    def running(self) -> bool:
        """Whether the episode goes on: not ended, nor ending on an empty goal (``no_frontier_end``)."""
        return self.episode_state in ("starting", "exploring") and self.no_frontier_end.empty_goal is None

    def end_on_empty_goal(self, step: int) -> None:
        """The goal decided at ``step`` is empty: the episode ends ``no_frontier`` there, with the frontier service's
        reason once it is heard (at once if it already was; without it after ``ended_why_wait_s``, or at once where
        no frontier service runs)."""
        self.no_frontier_end.empty_goal = (step, time.monotonic())
        self.end_if_why_heard(time.monotonic())

    def end_if_why_heard(self, now_s: float) -> None:
        """While an empty goal's end waits: end with the reason of its step once heard, or without after the wait."""
        why = self.no_frontier_end.why_now(now_s, self.frontier_service_runs())
        if why is not None:
            self.finish("done", TERMINATED_NO_FRONTIER, ended_why=why)

    def frontier_service_runs(self) -> bool:
        """Whether this robot's frontier service may say why a goal is empty: the profile has one, or leaves it to
        another process (``expected_services``), or one is alive."""
        return "frontier" in self.expected_services or (self.ctx.robot, "frontier") in self.alive_services

    def measure(self, m: MapMsg) -> None:
        """Ground-truth metrics of a map; the termination criteria of section 4.1."""
        self.last_map = m.occupancy()
        self.explored_m2 = self.metrics.explored_area_m2(self.last_map)
        self.coverage_curve.append(self.metrics.coverage_pct_of(self.explored_m2))
        if self.metrics.done_at(self.explored_m2):
            self.finish("done", TERMINATED_COVERAGE)
        elif self.step >= self.max_steps:
            self.finish("done", TERMINATED_MAX_STEPS)
        elif time.monotonic() - self.status_published_s >= self.params.status_period_s:
            self.status_published_s = time.monotonic()
            self.publish("episode_status", self.episode_status())

    def take_goal(self, g: GoalMsg) -> None:
        if g.decided and g.method and g.method != self.method:
            # The policy that decides names its method: a policy server shared by several robots may run another
            # than this profile's, and the episode's status and result must say which one explored.
            log.warning("goals are decided by %s, not this profile's method %s: the episode is reported as %s", g.method, self.method or "(none)", g.method)
            self.method = g.method
        if g.decided:
            self.decisions += 1
            self.decision_ms.append(g.decision_ms)
            if not g.has_goal:
                self.goal_xy = None
                self.end_on_empty_goal(g.step)
                return
        self.goal_xy = None if (xy := g.goal_xy_m) is None else [float(xy[0]), float(xy[1])]

    def step_ahead(self, msg: CmdVelMsg) -> None:
        """Lockstep: step and scan on the planner's provisional command of this step while the map and
        the frontier service's verdict are still on their way, then undo; ``advance`` keeps the result
        when the step's cmd_vel is the same command (the goal was kept), so the next scan goes out at
        once. Simulators without ``save_state`` (MuJoCo) just wait for the command."""
        sim = self.sim
        if not isinstance(sim, StateSaving) or msg.step != self.step or (self.ahead is not None and self.ahead[0] == msg.step):
            return
        before = sim.save_state()
        self.sim.step(msg.command)
        scan = self.sim.scan()
        self.ahead = (msg.step, msg.command, sim.save_state(), scan)
        sim.restore_state(before)

    def advance(self, command: VelocityCommand) -> None:
        before = self.sim.true_pose()
        odom_before = self.sim.odometry()
        ahead, self.ahead = self.ahead, None
        scan = None
        if ahead is not None and ahead[0] == self.step and ahead[1] == command and isinstance(self.sim, StateSaving):
            self.sim.restore_state(ahead[2])
            scan = ahead[3]
            self.steps_on_stored_scan += 1
        else:
            self.sim.step(command)
        after = self.sim.true_pose()
        self.odom_twist = mean_twist(odom_before, self.sim.odometry(), self.period_s)
        self.path_length_m += math.hypot(after.x_m - before.x_m, after.y_m - before.y_m)
        self.trajectory.append((after.x_m, after.y_m))
        self.step += 1
        self.step_started_s = time.monotonic()
        self.publish_step(scan)

    # --- inputs ---------------------------------------------------------------------------------
    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, EndedWhyMsg):
            if msg.episode == self.episode and self.result is None:
                self.no_frontier_end.heard = (msg.step, msg.why)
                self.end_if_why_heard(time.monotonic())
            return
        if isinstance(msg, PlannerContactsMsg):  # kept for a restarted planner, never waited for
            if not self.of_another_episode(topic, msg, self.episode):
                self.keep_latest(topic, msg)
            return
        if topic == "cmd_vel":  # the planner's state and plan ride on it: kept as they came for a restarted planner
            self.keep_carried(msg, self.episode)  # type: ignore[arg-type]
        if not self.running:
            return
        if isinstance(msg, MapMsg) and msg.episode != self.episode:
            self.reject("map", f"map of episode {msg.episode}, not of this one ({self.episode}): still in flight from before a restart")
            return
        if isinstance(msg, GoalMsg) and self.of_another_episode(topic, msg, self.episode):
            return
        if isinstance(msg, MapMsg) and msg.geometry != self.sim.plan.geometry:
            self.reject(
                "map",
                f"a {msg.geometry.describe()}, not the scene's {self.sim.plan.geometry.describe()} that the clock announced: "
                "coverage is measured cell by cell on the scene's grid (a mapper with its own grid, or another robot's map)",
            )
            return
        if isinstance(msg, MapMsg):
            self.keep_latest("map", msg)
        if self.ctx.lockstep:
            step = getattr(msg, "step", -1)
            if step < self.step:
                return
            if topic == "cmd_vel_ahead":
                self.step_ahead(msg)  # type: ignore[arg-type]
                return
            if topic == "map":
                self.maps[step] = msg  # type: ignore[assignment]
            elif topic == "goal":
                self.goals[step] = msg  # type: ignore[assignment]
            elif topic == "cmd_vel" and not msg.reason.startswith("stale"):  # type: ignore[attr-defined]
                self.cmds[step] = msg  # type: ignore[assignment]
            self.lockstep_progress()
        else:
            if topic == "map":
                self.measure(msg)  # type: ignore[arg-type]
            elif topic == "goal":
                self.take_goal(msg)  # type: ignore[arg-type]
            elif topic == "cmd_vel":
                self.last_cmd = (msg, received_s)  # type: ignore[assignment]

    def lockstep_progress(self) -> None:
        """Consume this step's map, then its command (and, when the command follows a goal decided at
        this step, that goal: the decision is counted); step when all are in."""
        k = self.step
        if self.measured_step < k:
            m = self.maps.pop(k, None)
            if m is None:
                return
            self.measured_step = k
            self.measure(m)
            if not self.running:
                return
        cmd = self.cmds.get(k)
        if cmd is None:
            return
        if cmd.new_goal and self.goal_step < k:
            g = self.goals.pop(k, None)
            if g is None:
                return
            self.goal_step = k
            self.take_goal(g)
            if not self.running:
                return
        if time.monotonic() - self.step_started_s < self.params.min_step_period_s:
            return  # on_tick comes back
        self.cmds.pop(k)
        for d in (self.maps, self.goals, self.cmds):
            for s in [s for s in d if s <= k]:
                d.pop(s)
        self.advance(cmd.command)

    def on_tick(self, now_s: float) -> None:
        self.end_if_why_heard(now_s)
        if self.episode_state == "starting":
            if self.services_ready_s is None:
                missing = self.missing_services()
                if missing and now_s - self.started_s < self.params.wait_for_services_s:
                    if missing <= self.left_out_needed and not self.said_waiting_for_left_out:
                        self.said_waiting_for_left_out = True
                        log.info(
                            "the profile's services are up; step 0 waits for %s, which the profile leaves to another process (at most %.0f s more)",
                            ", ".join(sorted(missing)), self.params.wait_for_services_s - (now_s - self.started_s),
                        )
                    return
                if missing:
                    log.warning("starting the episode without %s: no liveliness token after %.0f s", ", ".join(sorted(missing)), now_s - self.started_s)
                self.services_ready_s = now_s
            if now_s - self.services_ready_s >= self.params.start_delay_s:
                self.episode_state = "exploring"
                self.step_started_s = now_s
                self.next_step_s = now_s + self.period_s / self.params.real_time_factor
                self.publish_step()
            return
        if not self.running:
            return
        if self.ctx.lockstep:
            self.lockstep_progress()
            if not self.running:
                return
            waited = now_s - self.step_started_s
            if waited > self.params.lockstep_give_up_s:
                self.finish("failed", "lockstep_timeout", f"step {self.step}: waited {waited:.1f} s for {self.missing()}")
            elif now_s - self.last_publish_s > self.params.lockstep_timeout_s:
                self.timeouts += 1
                log.warning("step %d: no %s after %.1f s; re-publishing the step", self.step, self.missing(), now_s - self.last_publish_s)
                self.publish_step()
            return
        # A fixed schedule, one step every period / real_time_factor from the episode's start: timed from the
        # end of the last step, each step would also wait for the next tick (every tick_period_s) and the clock
        # would run slow (0.96x at real_time_factor 1, at most 12.5x however fast it is asked to run).
        due_s = self.period_s / self.params.real_time_factor
        for _ in range(MAX_STEPS_PER_TICK):
            if now_s < self.next_step_s or not self.running:
                break
            cmd = VelocityCommand()
            if self.last_cmd is not None and now_s - self.last_cmd[1] <= self.params.cmd_timeout_s:
                cmd = self.last_cmd[0].command
            if self.step >= self.max_steps:
                self.finish("done", TERMINATED_MAX_STEPS)
                return
            self.advance(cmd)
            self.next_step_s += due_s
        if now_s - self.next_step_s > self.period_s:  # behind by more than a step (a slow host, a stall): go on from now, not in a rush
            self.next_step_s = now_s + due_s

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--viewer", action="store_true", help="Open a MuJoCo viewer window on the LIMO (backend mujoco; needs a display)")

    @classmethod
    def apply_arguments(cls, args: argparse.Namespace, params: dict[str, Any]) -> dict[str, Any]:
        return {**params, "viewer": True} if args.viewer else params

    def shutdown(self) -> None:
        if self.viewer is not None:
            self.viewer.close()

    def missing(self) -> str:
        k = self.step
        if self.measured_step < k:
            return "map (mapper)"
        cmd = self.cmds.get(k)
        if cmd is None:
            return "cmd_vel (frontier/planner)"
        return "goal (policy)"


def main(argv: list[str] | None = None) -> int:
    """``python -m services.sim``'s entry point; exit code 2 for a bad config."""
    return service_main(SimService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
