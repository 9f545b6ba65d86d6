"""Frontier service: decides *when* a new goal is needed and builds the decision's Observation.

The re-decision rule is ``cso_runtime.episode.decision_reason`` (reached, blocked, no_progress, goal
no longer a frontier, every ``replan_every_steps``), the same function the in-process ``Explorer``
uses, on the planner's status after the previous step's command and the planner's own blocked check
(``path_blocked_ahead``) applied here to this step's map. The Observation is
``ObservationBuilder.build`` (frontiers, one fast-marching pass, entropy, clusters). Per step it
publishes either ``decide: false`` (the planner keeps its goal) or the arrays the policy needs. Once the episode is
over (the goal of its decision came back empty, or in real time the referee's ``episode_status`` says done or failed) every step
is ``decide: false`` until a new episode: a real robot's scans go on after the end, as explore_lite stops.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cso_runtime.config import MAX_RESTARTS, Bound, check_bounds, from_dict, seconds
from cso_runtime.episode import decision_reason, ended_no_frontier_why, goal_failed_in_place, mark_dead_frontier
from cso_runtime.geometry import GridGeometry
from cso_runtime.messages import (
    EPISODE_OVER,
    DistanceMapMsg,
    EndedWhyMsg,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    OdometryMsg,
    PlannerFeedbackMsg,
    encode,
    frontiers_from_observation,
)
from cso_runtime.observation import FrontierLayer, Observation, ObservationBuilder
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.planner import PlannerStatus, path_blocked_ahead
from cso_runtime.policies import Goal
from services.common import (
    PENDING_SMALL_STEPS_KEPT,
    PENDING_STEPS_KEPT,
    EpisodeWatch,
    Service,
    ServiceContext,
    service_main,
    warm_up_map,
)
from services.frontier_layer import FrontierLayerWorker

log = logging.getLogger("cso.frontier")


DEFER_MAX_INPUTS = 100
"""Real time: the most inputs in a row that may each find a map and odometry of one step to decide on and leave them
to a newer one (``backlog() > 0``) before the service decides anyway, on the newest pair it holds; and
``DEFER_MAX_S`` the most seconds. Without a bound a sustained flood above the service's handling rate (maps of a large
grid, each slower to decode than the next comes) kept the inbox from ever emptying, and no decision was ever made."""

DEFER_MAX_S = 1.0
"""The most seconds real time leaves a ready step undecided for newer inputs (``DEFER_MAX_INPUTS``)."""


FRONTIER_PARAMS_BOUNDS = {
    **seconds("goal_wait_s", "helper_reply_s", "helper_start_limit_s", positive=True),
    **seconds("helper_start_s"),
    "helper_max_restarts": Bound(0, MAX_RESTARTS, why="config.MAX_RESTARTS"),
}
"""``FrontierParams``' bounds: its times at most a day (``config.MAX_WAIT_S``), its restarts at most ``config.MAX_RESTARTS``."""


@dataclass
class FrontierParams:
    """Parameters of the frontier service (``services.frontier`` in a profile)."""

    goal_wait_s: float = 2.0
    """Real time: after asking for a decision, keep the current goal (``decide: false``) for at most this
    long while the policy answers, instead of asking again on every map. Lockstep always waits."""
    layer_helper: bool = True
    """Compute a decision's frontier layer (F_t, I, the frontier components) in a helper process while this
    one computes D (``services/frontier_layer.py``): the Observation is the same, sooner on two or more
    cores. False: one process."""
    helper_start_s: float = 10.0
    """Wall clock: how long the warm-up waits for the layer helper to start (imports) before the
    service says it is up, and for its practice layer (the helper's first calls: on a loaded host more than
    ``helper_reply_s``); a helper still starting after that is used from the first map it is ready for."""
    helper_reply_s: float = 2.0
    """Wall clock: how long a decision waits for the layer helper's answer (its layer, or its mapping of a new map
    shape) before it computes the layer here and counts the helper as lost (hung: a new one is started, as for a
    killed one). The layer takes milliseconds; a host loaded far beyond its cores may need more than the default."""
    helper_start_limit_s: float = 30.0
    """Wall clock: a layer helper that has still not started this long after it was spawned (never less than
    ``helper_start_s``) is given up as hung, as a lost one is: logged, counted (``layer_helper_deaths``) and replaced
    (at most ``helper_max_restarts`` times). Meanwhile, from ``helper_start_s`` on, the log and the service's status
    say that it has not started and that the layers are computed here."""
    helper_max_restarts: int = 3
    """How many times a layer helper lost while the service runs (killed, crashed, hung) is replaced by a new one;
    after that the service computes every layer itself (the same Observation, slower). Bounded: a helper that dies
    as soon as it starts does not loop."""

    def validate(self) -> None:
        check_bounds("", self, FRONTIER_PARAMS_BOUNDS)  # each key's range: its one check


class FrontierService(Service):
    """Decides when a new goal is needed (``decision_reason``, as the in-process loop) and publishes the Observation
    the policy decides on."""

    name = "frontier"
    inputs = {
        "map": MapMsg, "odom": OdometryMsg, "planner_feedback": PlannerFeedbackMsg, "goal": GoalMsg, "explore_resume": ExploreResumeMsg,
        "episode_status": EpisodeStatusMsg,
    }  # fmt: skip
    optional_inputs = ("explore_resume", "episode_status")  # a pause is an operator's; the referee's end only saves work
    outputs = {"frontiers": FrontiersMsg, "distance_map": DistanceMapMsg, "ended_why": EndedWhyMsg}

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(FrontierParams, ctx.params, where="services.frontier")
        cfg = ctx.exploration
        self.builder = ObservationBuilder(cfg.frontier, cfg.robot)
        self.replan_every_steps = cfg.episode.replan_every_steps
        self.goal_tolerance_m = cfg.episode.goal_tolerance_m
        self.robot_radius_m = cfg.robot.radius_m
        self.layer_worker: FrontierLayerWorker | None = None
        self.decisions_built = 0
        """Observations built (the helpers computed ``layers_by_helpers()`` of their layers)."""
        self.layers_by_lost_helpers = 0
        """Layers computed by helpers lost since (``tend_layer_helper``)."""
        self.helper_deaths = 0
        """Layer helpers lost while the service ran (the status's ``layer_helper_deaths``)."""
        self.helper_restarts = 0
        """New helpers started in their place (the status's ``layer_helper_restarts``; at most ``helper_max_restarts``)."""
        self.helper_given_up = False
        """No new helper is started any more: the layers are computed here."""
        self.steps_after_episode = 0
        """Steps decided on with ``decide: false`` because the episode was over (the status's ``steps_after_episode``)."""
        self.episodes = EpisodeWatch()
        self.paused = False
        """The operator's pause (real time): no decision is asked and the paused steps do not count towards the
        periodic re-decision. It outlives an episode, as the planner's."""
        self.pause_note = ""
        """The status's reason for the pause ("paused: by ..."; "" when exploring)."""
        self.helper_note = ""
        """The status's reason for a layer helper late to start ("" when none is: ``say_helper_late``)."""
        self.late_helpers_said: set[int] = set()
        """The pids of the helpers the log has said are late to start (once each)."""
        self.reset_episode()

    def start(self) -> None:
        """A frontier service (re)started while the robot is paused learns it from the launcher (``pause_in_force``)."""
        if (pause := self.pause_in_force()) is not None:
            self.on_pause(pause)

    def on_pause(self, msg: ExploreResumeMsg) -> None:
        """Pause or resume asking for decisions; lockstep ignores it (the planner says so)."""
        paused = not msg.resume
        if self.ctx.lockstep or paused == self.paused:  # a second pause is no new one
            return
        self.paused = paused
        by = f": by {msg.by}" if msg.by else ""
        self.pause_note = f"paused{by}" if self.paused else ""
        self.show_state()

    def show_state(self) -> None:
        """The status's state and reason: running, with the pause and a helper late to start, when there are."""
        self.set_state("running", "; ".join(note for note in (self.pause_note, self.helper_note) if note))

    def warm_up(self) -> None:
        """Start the layer helper and wait for it (at most ``helper_start_s``), then build one
        Observation through it and encode its decision message: the first step's decision then pays
        neither the helper's start nor first calls."""
        if self.params.layer_helper:
            try:
                self.layer_worker = FrontierLayerWorker(self.ctx.exploration.frontier.entropy_window_m, self.params.helper_reply_s, stopping=self.stopping)
            except OSError as exc:  # no process to spare: the layers are computed here, as with layer_helper false
                log.warning("no frontier layer helper (%s): computing the layers in this process", exc)
            else:
                if not self.layer_worker.wait_ready(self.params.helper_start_s) and not self.stopping():
                    self.say_helper_late(self.layer_worker, time.monotonic())  # the service goes on: said, not silent
        if self.stopping():  # stopped while it waited for its helper: no practice for a service that stops
            return
        occupancy, pose = warm_up_map()
        w = self.layer_worker
        if w is not None:  # the practice layer pays the helper's first calls: it may take as long as the helper's start
            w.timeout_s = max(self.params.helper_reply_s, self.params.helper_start_s)
        try:
            obs = self.builder.build(occupancy, pose, np.array([pose.xy]), layer=self.layer_beside_d(occupancy, None))
        finally:
            if w is not None:
                w.timeout_s = self.params.helper_reply_s
        encode(frontiers_from_observation(0, "no_goal", obs, 0.0))
        encode(DistanceMapMsg(0, obs.geometry, obs.pose, obs.distance_map()))
        if w is not None:
            w.layers_computed = 0  # the practice layer is not a decision's

    def on_tick(self, now_s: float) -> None:
        self.tend_layer_helper(now_s)

    def say_helper_late(self, w: FrontierLayerWorker, now_s: float) -> None:
        """Say (once in the log, and in the status's reason while it lasts) that the layer helper has not started
        ``helper_start_s`` after it was spawned, so the layers are computed here; nothing once it has (or was given up)."""
        starting_s, pid = w.starting_for_s(now_s), w.proc.pid or 0
        late = self.params.helper_start_s > 0 and starting_s >= self.params.helper_start_s
        limit_s = max(self.params.helper_start_limit_s, self.params.helper_start_s)
        start_s = self.params.helper_start_s
        note = f"layer helper (pid {pid}) not started after {start_s:g} s: layers computed here; given up at {limit_s:g} s" if late else ""
        if late and pid not in self.late_helpers_said:
            self.late_helpers_said.add(pid)
            log.warning(
                "frontier layer helper (pid %d) has not started %.1f s after it was spawned (a loaded host, or hung): the layers are computed in "
                "this process until it does; given up as hung %.0f s after its spawn (services.frontier.helper_start_limit_s)",
                pid, starting_s, limit_s,
            )  # fmt: skip
        if note != self.helper_note:
            self.helper_note = note
            self.show_state()

    def tend_layer_helper(self, now_s: float | None = None) -> None:
        """Notice a layer helper lost while the service runs (its process killed or crashed, or hung: no answer in time,
        or not started ``helper_start_limit_s`` after its spawn), say so, count it and start a new one, at most
        ``helper_max_restarts`` times; meanwhile (and after) the layers are computed here, with the same results. A helper
        late to start is said (``say_helper_late``). A helper lost to the service's own stop is no loss."""
        w = self.layer_worker
        if w is None or self.helper_given_up or self.stopping():
            return
        now_s = time.monotonic() if now_s is None else now_s
        if w.usable() and not w.not_started_within(now_s, max(self.params.helper_start_limit_s, self.params.helper_start_s)):
            self.say_helper_late(w, now_s)
            return
        if self.helper_note:  # given up: the lines below say what follows
            self.helper_note = ""
            self.show_state()
        if w.lost_to_stop:
            return
        with self._lock:
            self.helper_deaths += 1
        if self.helper_restarts >= self.params.helper_max_restarts:
            self.helper_given_up = True
            log.error(
                "frontier layer helper lost (%s) after %d restarts: no new one, the layers are computed in this process from now on",
                w.broken, self.helper_restarts,
            )  # fmt: skip
            return
        self.layers_by_lost_helpers += w.layers_computed
        w.close()
        try:
            new = FrontierLayerWorker(self.ctx.exploration.frontier.entropy_window_m, self.params.helper_reply_s, stopping=self.stopping)
        except OSError as exc:  # no process to spare
            self.helper_given_up = True
            log.error("frontier layer helper lost (%s), and no new one starts (%s): the layers are computed in this process from now on", w.broken, exc)
            return
        with self._lock:
            self.helper_restarts += 1
        self.layer_worker = new
        log.warning(
            "frontier layer helper lost (%s): started a new one (pid %d, restart %d of at most %d); the layers are computed here until it is ready",
            w.broken, new.proc.pid, self.helper_restarts, self.params.helper_max_restarts,
        )  # fmt: skip

    def extra_status(self) -> dict[str, int]:
        with self._lock:
            after = {"steps_after_episode": self.steps_after_episode} if self.steps_after_episode else {}
            return {"layer_helper_deaths": self.helper_deaths, "layer_helper_restarts": self.helper_restarts, **after}

    def layers_by_helpers(self) -> int:
        """The decisions' layers computed by helper processes, lost ones included (the rest were computed here)."""
        return self.layers_by_lost_helpers + (self.layer_worker.layers_computed if self.layer_worker is not None else 0)

    def shutdown(self) -> None:
        if self.layer_worker is not None:
            w = self.layer_worker
            why = f" ({w.broken})" if w.broken and not w.lost_to_stop else ""
            by_helpers = self.layers_by_helpers()
            lost = f", {self.helper_deaths} helpers lost, {self.helper_restarts} restarted" if self.helper_deaths else ""
            log.info("frontier layers: %d by the helper process, %d here%s%s", by_helpers, self.decisions_built - by_helpers, lost, why)
            w.close()

    def helper_pids(self) -> list[int]:
        """The layer helper's process, while it runs (a helper started later by this service inherits its scheduling)."""
        w = self.layer_worker
        return [w.proc.pid] if w is not None and w.proc.pid is not None and w.proc.is_alive() else []

    def layer_beside_d(self, occupancy: OccupancyMap, dead: np.ndarray | None) -> Callable[[], FrontierLayer] | None:
        """The decision's frontier layer, started in the helper process (``build`` waits for it once D
        is done); None when there is no helper to use (``build`` computes it)."""
        w = self.layer_worker
        if w is None or not w.submit(occupancy, dead):
            return None
        return lambda: w.result() or self.builder.frontier_layer(occupancy, dead)

    def reset_episode(self) -> None:
        """Forget the decision state (a new episode, or a fresh start)."""
        self.maps: dict[int, MapMsg] = {}
        self.odoms: dict[int, OdometryMsg] = {}
        self.feedback: dict[int, PlannerFeedbackMsg] = {}
        self.deferred_since_s: float | None = None
        """Real time: when a ready step was first left to newer inputs since the last step decided on (None: none)."""
        self.deferred_inputs = 0
        """Real time: how many inputs in a row have left a ready step to newer ones (``DEFER_MAX_INPUTS``)."""
        self.goal: Goal | None = None
        self.awaiting_goal_step: int | None = None
        """The step of a decision whose goal has not arrived yet (lockstep: the next step waits for it)."""
        self.awaiting_since_s = 0.0
        self.decision_step = 0
        self.asked_step = -1
        """The newest step this service asked the policy to decide (``decide: true``): a goal is only ever its answer."""
        self.dead: np.ndarray | None = None
        self.asked: tuple[Observation, np.ndarray] | None = None
        """The Observation of the decision asked at ``asked_step`` and the frontiers given up then: why it found no
        goal, should its goal come back empty (``say_why_no_goal``)."""
        self.path_nodes: list[tuple[float, float]] = []
        self.done_step = -1
        self.last_out: FrontiersMsg | None = None
        self.episode_grid: GridGeometry | None = None
        """The grid of the episode's maps (its first map's): the mapper keeps one grid for an episode."""
        self.paused_spans: list[tuple[int, int]] = []
        """Steps decided on while paused, as spans (after, last]: left out of the count towards ``replan_every_steps``."""
        self.why_no_goal_said = ""
        """The reason for no goal the log said last (``say_why_no_goal``): said again only when it changes, or after a
        goal."""
        self.episode_over = ""
        """How the episode ended ("": it goes on): no decision is asked any more (``end_episode``)."""
        self.no_goal_left = False
        """The goal of its decision came back empty: the referees end the episode on it, whatever a status says after."""

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, ExploreResumeMsg):  # a control, of no episode or step
            self.on_pause(msg)
            return
        step = getattr(msg, "step", -1)
        # Every input carries its episode id, and the episode shows itself on whichever comes first: maps (and the
        # planner's reports) of the episode before a sim restart may still be in flight among the new one's first
        # messages. Without ids, only odometry of step 0 starts one, as before ids: in real time the goal of step 0
        # comes after later steps.
        odometry = isinstance(msg, OdometryMsg)
        episode = getattr(msg, "episode", 0)
        seen = self.episodes.classify(episode, step, self.done_step > 0 and odometry, from_referee=odometry)
        if seen == "ended":
            self.reject(topic, f"{topic} of episode {episode} at step {step}: that episode has ended", robot)
            return
        if seen == "new":
            log.info("new episode %d (%s of step %d): forgetting the decision state", self.episodes.current, topic, step)
            self.reset_episode()
        if isinstance(msg, GoalMsg):
            if msg.decided and step > self.asked_step:  # a goal for a step no decision asked for: forged or malformed
                why = f"a goal decided for step {step}, but no decision was asked for it (the last was asked at step {self.asked_step})"
                self.reject(topic, why, robot)
                return
            if msg.decided and step >= self.decision_step:
                self.goal = None if (xy := msg.goal_xy_m) is None else Goal(xy[0], xy[1], msg.cluster_index, msg.distance_m)
                if self.goal is not None:
                    self.why_no_goal_said = ""
                if self.goal is None and step == self.asked_step:
                    self.say_why_no_goal(step)
                    self.no_goal_left = True
                    self.end_episode(f"no goal at step {step}")
                self.decision_step = step
                if self.awaiting_goal_step is not None and step >= self.awaiting_goal_step:
                    self.awaiting_goal_step = None
            self.try_decide()
            return
        if isinstance(msg, EpisodeStatusMsg):
            if not self.ctx.lockstep:  # a lockstep sim steps no more after the end: nothing to save there
                self.on_referee_status(msg)
                self.try_decide()  # a ros2_bridge's status comes with every map: a map it held back is decided now
            return
        if isinstance(msg, PlannerFeedbackMsg):
            if msg.phase == "command" and step >= self.done_step - 1:
                self.feedback[step] = msg
                if not self.ctx.lockstep:  # no map (a mapper gone): no decision prunes them; a map far behind needs them
                    self.keep_newest_within("planner_feedback", self.feedback, PENDING_SMALL_STEPS_KEPT, None, "a map after its step", robot)
                self.try_decide()
            return
        if isinstance(msg, MapMsg) and self.of_another_grid(msg, robot):
            return
        if step <= self.done_step:
            if isinstance(msg, MapMsg) and self.last_out is not None and step == self.done_step:
                self.publish("frontiers", self.last_out)  # a lockstep retry: answer again
            return
        if isinstance(msg, MapMsg):
            self.maps[step] = msg
            if not self.ctx.lockstep:  # odometry silent: no map finds its partner (large: only the newest matters)
                # Every map waiting is on the episode's grid (``of_another_grid``): each holds what this one does.
                map_bytes = msg.explored.nbytes + msg.occupied.nbytes
                self.keep_newest_within("map", self.maps, PENDING_STEPS_KEPT, map_bytes, "the odometry of its step", robot)
        elif isinstance(msg, OdometryMsg):
            self.odoms[step] = msg
            if not self.ctx.lockstep:  # bounded for a mapper gone; 100,000 steps for one far behind (replay --speed max)
                self.keep_newest_within("odom", self.odoms, PENDING_SMALL_STEPS_KEPT, None, "the map of its step", robot)
        self.try_decide()

    def end_episode(self, how: str) -> None:
        """The episode is over: the referees (the sim, the ROS 2 bridge) end it on an empty goal, on coverage, at
        ``max_steps`` or on a failure. No decision is asked from now on (nor its Observation built) until a new
        episode: a real robot's scans go on after the end, and each decision's frontiers went to RViz over its WiFi.
        The maps go on (the mapper's), and so does ``ended_why``, which the referee waits for."""
        if self.episode_over:
            return
        self.episode_over = how
        log.info("episode %d over (%s): no more decisions until a new episode", self.episodes.current or 0, how)

    def on_referee_status(self, msg: EpisodeStatusMsg) -> None:
        """The referee's status (real time): done or failed ends the episode here. One that says it goes on after that
        shows the end stray or forged (the launcher, too, ignores an end that no result follows): decide again."""
        if msg.state in EPISODE_OVER:
            self.end_episode(f"{msg.state} ({msg.terminated_by})" if msg.terminated_by else msg.state)
        elif self.episode_over and not self.no_goal_left:
            log.warning("episode %d goes on (its status says %s after %s): deciding again", self.episodes.current or 0, msg.state, self.episode_over)
            self.episode_over = ""

    def say_why_no_goal(self, step: int) -> None:
        """The decision of ``step`` found no goal, and the episode ends ``no_frontier``: publish why (the frontier cells
        left and what kept each from being a goal, as the in-process ``Explorer`` says it) for the referee's result."""
        if self.asked is None:
            return
        obs, dead = self.asked
        why = ended_no_frontier_why(obs, dead, self.ctx.exploration)
        # The same reason again (a lockstep retry of the step brings its empty goal again): the log says it once.
        log.log(logging.DEBUG if why == self.why_no_goal_said else logging.INFO, "no goal at step %d: %s", step, why)
        self.why_no_goal_said = why
        self.publish("ended_why", EndedWhyMsg(step, why, self.episodes.current or 0))

    def of_another_grid(self, msg: MapMsg, robot: str) -> bool:
        """Whether ``msg`` is on another grid than the episode's maps before it, and rejected (counted, logged): another
        robot's map, a mapper with a grid of its own or a forged map would be decided on as this episode's (all of it
        explored, no frontier: the episode ended as 'no frontier left'). The sim rejects such a map too."""
        if self.episode_grid is None:
            self.episode_grid = msg.geometry
        if msg.geometry == self.episode_grid:
            return False
        why = f"map of step {msg.step} on a {msg.geometry.describe()}, not the episode's {self.episode_grid.describe()}: another robot's or mapper's"
        self.reject("map", why, robot)
        return True

    def planner_state(self, k: int) -> PlannerFeedbackMsg | None:
        """The planner's report after the command of step k - 1 (lockstep: exactly that one; real time:
        the newest before k about the goal decided last, since the planner may report on newer steps
        before that goal reaches it). None: no such report yet."""
        if self.ctx.lockstep:
            return self.feedback.get(k - 1)
        recent = [s for s, fb in self.feedback.items() if s < k and fb.goal_step == self.decision_step]
        return self.feedback[max(recent)] if recent else None

    def steps_explored_since_decision(self, k: int) -> int:
        """Steps from the goal's decision to ``k``, less those paused: the robot stood still, told to."""
        d = self.decision_step
        return k - d - sum(max(0, last - max(after, d)) for after, last in self.paused_spans)

    def note_paused_step(self, k: int) -> None:
        """Steps after the last one decided on, up to ``k``, were paused: extend the last span or start one (spans
        before the goal's decision count no more)."""
        spans = [span for span in self.paused_spans if span[1] > self.decision_step]
        after = spans.pop()[0] if spans and spans[-1][1] == self.done_step else self.done_step
        self.paused_spans = [*spans, (after, k)]

    def deferred_too_long(self) -> bool:
        """Real time, newer inputs waiting: count one more input that leaves a ready step to them, and whether it has
        been done for ``DEFER_MAX_INPUTS`` inputs or ``DEFER_MAX_S`` seconds, so that the service decides anyway."""
        now_s = time.monotonic()
        if self.deferred_since_s is None:
            self.deferred_since_s = now_s
        self.deferred_inputs += 1
        return self.deferred_inputs > DEFER_MAX_INPUTS or now_s - self.deferred_since_s >= DEFER_MAX_S

    def try_decide(self) -> None:
        # The maps' steps, not the odometry's: far fewer wait (``PENDING_STEPS_KEPT``) than odometry may, ahead of a
        # mapper far behind (``PENDING_SMALL_STEPS_KEPT``), and this runs on every input.
        ready = sorted(s for s in self.maps if s in self.odoms)
        if not ready:
            return
        k = ready[0] if self.ctx.lockstep else ready[-1]
        if self.ctx.lockstep:
            fb = self.planner_state(k)
            if self.awaiting_goal_step is not None or (k > 0 and fb is None):
                return  # the last decision's goal, or the planner's report on step k - 1, is on its way
        elif self.backlog() > 0 and not self.deferred_too_long():
            return  # real time: newer inputs are waiting; decide on the newest
        else:
            fb = self.planner_state(k)  # after the check: it reads every report waiting
        self.deferred_since_s, self.deferred_inputs = None, 0
        waiting = self.awaiting_goal_step is not None and time.monotonic() - self.awaiting_since_s < self.params.goal_wait_s
        m, odom = self.maps.pop(k), self.odoms.pop(k)
        for d in (self.maps, self.odoms):
            for s in [s for s in d if s <= k]:
                d.pop(s)
        for s in [s for s in self.feedback if s < k - 1]:
            self.feedback.pop(s)
        episode = self.episodes.current or 0
        if self.episode_over:  # nothing to decide: no map to read, no Observation to build
            with self._lock:
                self.steps_after_episode += 1
            self.done_step = self.last_step = k
            self.last_out = FrontiersMsg(k, False, episode=episode)
            self.publish("frontiers", self.last_out)
            return
        if self.paused:
            self.note_paused_step(k)
        self.done_step = self.last_step = k
        occupancy = m.occupancy()
        if self.dead is None or self.dead.shape != occupancy.geometry.shape:
            self.dead = np.zeros(occupancy.geometry.shape, dtype=bool)
        # No report yet: idle, or (real time) already on its way to the goal just decided.
        status = PlannerStatus.FOLLOWING if fb is None and self.goal is not None and not self.ctx.lockstep else PlannerStatus.IDLE
        if fb is not None:
            if fb.set_goal_blocked and self.goal is not None:
                mark_dead_frontier(self.dead, occupancy.geometry, (self.goal.x_m, self.goal.y_m), self.goal_tolerance_m)
            status = PlannerStatus(fb.status) if fb.status != "stale" else PlannerStatus.BLOCKED
            # The planner's check_blocked on this step's map, run here on the path it reported.
            if status == PlannerStatus.FOLLOWING and path_blocked_ahead(fb.path_ahead_xy_m, odom.pose, occupancy.occupied, occupancy.geometry, self.robot_radius_m):
                status = PlannerStatus.BLOCKED
        reason = None if self.paused else decision_reason(self.goal, status, occupancy, self.steps_explored_since_decision(k), self.replan_every_steps)
        if reason is None or waiting:
            out = FrontiersMsg(k, False, episode=episode)
        else:
            t0 = time.perf_counter()
            if self.goal is not None and goal_failed_in_place(reason, self.goal, occupancy, odom.pose):
                mark_dead_frontier(self.dead, occupancy.geometry, (self.goal.x_m, self.goal.y_m), self.goal_tolerance_m)
            self.path_nodes.append((odom.pose.x_m, odom.pose.y_m))
            obs = self.builder.build(occupancy, odom.pose, np.array(self.path_nodes), exclude_frontier=self.dead, layer=self.layer_beside_d(occupancy, self.dead))
            self.decisions_built += 1
            out = frontiers_from_observation(k, reason, obs, (time.perf_counter() - t0) * 1e3, episode)
            self.awaiting_goal_step, self.awaiting_since_s, self.asked_step = k, time.monotonic(), k
            self.asked = (obs, self.dead.copy())
        self.last_out = out
        self.publish("frontiers", out)
        if out.decide:
            # After the decision message: the policy starts on it while D is encoded and travels to the
            # planner, which decodes it while the policy decides (a goal selector reads D only at the
            # path nodes, which the decision message carries).
            self.publish("distance_map", DistanceMapMsg(k, obs.geometry, obs.pose, obs.distance_map(), episode))


def main(argv: list[str] | None = None) -> int:
    """``python -m services.frontier``'s entry point; exit code 2 for a bad config."""
    return service_main(FrontierService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
