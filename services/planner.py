"""Planner service: ``LocalPlanner`` (path, pure pursuit, progress and blocked checks) -> cmd_vel.

Per step it reports on ``planner/feedback`` after the step's command (``update``): the status, the
path still ahead and the goal they are about. With them the frontier service runs the same blocked
check on the next map (``path_blocked_ahead``) and applies the shared re-decision rule to the same
status as the in-process loop. In lockstep each step's command acts on the frontier service's
``decide: false`` directly, so on most steps the policy is not in the loop; in real time it commands
every new odometry + scan pair on the current path and plans to each new goal when it arrives. It
stops the robot, and says why in its status, when odometry or scans are older than
``stale_after_s`` (in real time: in lockstep the sim holds the robot until each step's command, so a step
whose decision was slow is still commanded).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass

import numpy as np

from cso_runtime.config import check_bounds, from_dict, seconds
from cso_runtime.geometry import VelocityCommand
from cso_runtime.messages import (
    MAX_PLANNER_STATE_BYTES,
    CmdVelMsg,
    DistanceMapMsg,
    ExploreResumeMsg,
    FrontiersMsg,
    GoalMsg,
    Message,
    OdometryMsg,
    PathMsg,
    PlannerContactsMsg,
    PlannerFeedbackMsg,
    PlannerFrontiersMsg,
    PlannerPlanMsg,
    PlannerStateMsg,
    ScanMsg,
    encode,
    max_planner_plan_bytes,
)
from cso_runtime.pause import LOCKSTEP_REFUSAL
from cso_runtime.planner import FollowResult, FreeSpace, LocalPlanner, PlannerStatus
from services.common import (
    PENDING_SMALL_STEPS_KEPT,
    PENDING_STEPS_KEPT,
    EpisodeWatch,
    Service,
    ServiceContext,
    service_main,
    warm_up_observation,
)

log = logging.getLogger("cso.planner")


NO_FRONTIER_REASON = "no_frontier"
"""A command's ``reason`` once the last decision found no reachable frontier (the episode's end): a stop."""

SILENCE_PREFIX = "stale: no "
"""How the planner's stale reason starts when inputs stopped coming (``silence_reason``)."""


def silence_reason(silent: dict[str, float], seconds_format: str) -> str:
    """The planner's stale reason while inputs (name: seconds since the last) stopped coming."""
    return "stale: " + ", ".join(f"no {name} for {age_s:{seconds_format}} s" for name, age_s in sorted(silent.items()))


PENDING_DECISIONS_KEPT = 16
"""Real time: decisions (frontiers with their grids, distance maps) kept while their goal has not come. A
policy that is down or far behind must not grow the planner without bound; a goal for an older decision
than these finds nothing to plan on and waits for the next one. Of each, ``common.PENDING_MAX_BYTES`` at most
(``Service.keep_newest_within``): 18 decisions (16, an eighth more before a trim) of the largest grid the default
``max_grid_cells`` allows (4,000,000 cells: three bool grids and a float64 D, 11 bytes a cell) were 792 MB, and 9.9 GB
at ``messages.MAX_GRID_CELLS``; now 16 to 18 frontiers (216 MB) and 7 to 8 distance maps (256 MB) there, 1 and 1
(550 MB) at the ceiling."""


PLANNER_PARAMS_BOUNDS = {**seconds("stale_after_s", positive=True), **seconds("path_period_s", "restore_timeout_s")}
"""``PlannerParams``' bounds: its times at most a day (``config.MAX_WAIT_S``)."""


@dataclass
class PlannerParams:
    """Parameters of the planner service (``services.planner`` in a profile)."""

    stale_after_s: float = 2.0
    """Odometry or scans older than this (wall clock) stop the robot (real time; in lockstep the sim waits for
    each step's command, so a slow decision does not make its inputs stale)."""
    path_period_s: float = 0.25
    """``path`` is a view (the live view's distance ahead, a user's plot), not an input of any service: it
    goes out with every new plan and otherwise at most this often (wall clock), so that the process showing
    it is not woken on every step; 0 = with every command."""
    restore_timeout_s: float = 1.0
    """How long (wall clock) to wait at start for each of what the referee (sim or ros2_bridge) keeps of the planner: the
    contacts (``cache/planner/contacts``), so that a restarted planner still keeps off what the robot bumped into, and
    the plan and state (``cache/planner/plan``, ``cache/planner/state``), so that it carries on with the same goal and
    path as if it had never stopped."""

    def validate(self) -> None:
        check_bounds("", self, PLANNER_PARAMS_BOUNDS)  # each time's range: its one check


class PlannerService(Service):
    """Follows the path to the current goal: one cmd_vel per step, and feedback the frontier service's re-decision
    rule reads."""

    name = "planner"
    inputs = {
        "odom": OdometryMsg, "scan": ScanMsg, "frontiers": PlannerFrontiersMsg, "distance_map": DistanceMapMsg, "goal": GoalMsg,
        "explore_resume": ExploreResumeMsg,
    }  # fmt: skip
    outputs = {
        "cmd_vel": CmdVelMsg, "cmd_vel_ahead": CmdVelMsg, "planner_feedback": PlannerFeedbackMsg, "path": PathMsg, "planner_contacts": PlannerContactsMsg,
    }  # fmt: skip
    optional_inputs = ("distance_map", "explore_resume")  # without D the planner runs its own fast-marching pass (the same path); a pause is an operator's
    tick_period_s = 0.1

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(PlannerParams, ctx.params, where="services.planner")
        self.episodes = EpisodeWatch()
        self.paused: ExploreResumeMsg | None = None
        """The operator's pause being obeyed (real time; None: exploring). It outlives an episode: a robot paused
        stays still until it is resumed."""
        self.contacts_restored_step: int | None = None
        """The step of the contacts restored from the referee's cache at start (``restore_contacts``); None: none."""
        self.reset_episode()

    def start(self) -> None:
        """A planner (re)started while the robot is paused learns it from the launcher (``pause_in_force``), and one
        restarted mid-episode gets its contacts, its plan and its state back from the referee (``cache/planner/...``)."""
        if (pause := self.pause_in_force()) is not None:
            self.on_pause(pause)
        # Each outcome is said in the log (``restore_from_cache``: nothing kept, or no answer in time; restored: here).
        cached = self.restore_from_cache("planner_contacts", PlannerContactsMsg, self.params.restore_timeout_s)
        if cached is not None:
            self.restore_contacts(cached)
        state = self.restore_from_cache("planner_state", PlannerStateMsg, self.params.restore_timeout_s)
        if state is not None:
            # A state from before the planner's first plan (plan_step -1) names none: none to ask for (nor to wait on).
            plan = None if state.plan_step < 0 else self.restore_from_cache("planner_plan", PlannerPlanMsg, self.params.restore_timeout_s)
            self.restore_state(state, plan)

    def restore_contacts(self, cached: PlannerContactsMsg) -> None:
        """Keep the contacts of a planner that ran before this one in the same episode (it was killed, or crashed): the
        paths planned from here keep off them as its did. They belong to their episode: the first input of another
        episode starts afresh (``reset_episode``), as it does for the mapper's restored map."""
        if len(cached.contacts_xy_m) == 0:
            log.info("the cache's contacts of step %d (episode %d) are none: none restored", cached.step, cached.episode)
            return
        self.episodes.current = cached.episode or None  # id 0 (no ids): the episode running, whichever it is
        self.planner.contacts_xy_m = np.array(cached.contacts_xy_m, dtype=float).reshape(-1, 2)
        self.contacts_published = len(self.planner.contacts_xy_m)  # the referee holds them already
        self.contacts_restored_step = cached.step
        log.info("restored %d contacts of step %d (episode %d) from the cache", self.contacts_published, cached.step, cached.episode)

    def warm_up(self) -> None:
        """Plan once on a practice Observation (a planner thrown away), so the first goal's plan pays
        no first calls."""
        obs = warm_up_observation(self.ctx.exploration)
        if obs.clusters:
            goal = obs.clusters[0]
            self.new_planner().set_goal(obs.traversable, obs.geometry, obs.pose, np.asarray(goal.goal_xy_m), obs.distance_m, goal.distance_m, obs.occupied, obs.explored)

    def new_planner(self) -> LocalPlanner:
        return LocalPlanner.for_config(self.ctx.exploration)

    def reset_episode(self) -> None:
        """A fresh planner and empty buffers (a new episode, or a fresh start)."""
        self.planner = self.new_planner()
        self.backups_logged = 0
        """The planner's stall back-ups logged so far (each is logged once, as it starts)."""
        self.escapes_logged = 0
        """The planner's progress recoveries logged so far (each once, as it starts)."""
        self.reverse_blocked_logged = -2
        """Last step whose reverse command was held (logged once per run of such steps)."""
        self.odoms: dict[int, tuple[OdometryMsg, float]] = {}
        self.scans: dict[int, tuple[ScanMsg, float]] = {}
        self.frontiers: dict[int, FrontiersMsg] = {}
        self.distance_maps: dict[int, DistanceMapMsg] = {}
        """D of each decision, decoded while the policy decides (a path to the goal is then a descent)."""
        self.goals: dict[int, GoalMsg] = {}
        self.cmd_step = -1
        self.goal_step = -1
        """The decision step of the goal being followed (reported with every command)."""
        self.pending_new_goal = False
        """A goal was applied since the last command (the command says so: ``new_goal``)."""
        self.no_frontier = False
        """The last decision found no reachable frontier: the robot stays stopped."""
        self.set_goal_blocked = False
        self.last_feedback: PlannerFeedbackMsg | None = None
        self.last_cmd: CmdVelMsg | None = None
        self.last_input_s = {"odometry": time.monotonic(), "scan": time.monotonic()}
        """When each input last arrived (wall clock): either one going silent stops the robot."""
        self.stopped_for_stale = False
        self.published_plan: np.ndarray | None = None
        """The plan whose ``path`` went out last (a new plan is published at once)."""
        self.path_published_s = -np.inf
        self.ahead: tuple[int, FollowResult, tuple] | None = None
        """Lockstep: the command of the next step computed while the map and the frontier service's
        verdict are still on their way (step, result, planner state after it); used when the verdict
        keeps the goal, dropped when it brings a new one."""
        self.contacts_published = 0
        """How many of the planner's contacts ``planner_contacts`` has sent (they only grow in an episode)."""
        self.contacts_restored_step = None
        self.published_state: tuple[int, np.ndarray | None, FreeSpace | None] = (-1, None, None)
        """The step of the last plan sent (on ``cmd_vel``, ``with_checkpoint``), and its path and grid (a new one goes out
        when they change)."""
        self.states_too_large = 0
        """States over ``MAX_PLANNER_STATE_BYTES`` that ``with_checkpoint`` left off their command (status counter
        ``states_too_large`` once there is one)."""
        self.resumed_step: int | None = None
        """Lockstep: the step of the state restored at start (``restore_state``) until the first odometry: when that is
        of a later step than the next, the state is behind the episode and this planner joins where it is."""

    def restore_state(self, state: PlannerStateMsg, plan: PlannerPlanMsg | None) -> bool:
        """Carry on from the state of the planner that ran before this one in the same episode (it was killed, or
        crashed), on the plan that state names: the same goal, path, progress, stall and recovery counters, so the next
        step's command is the one it would have sent. False (nothing restored: a fresh planner, whose report asks for
        a new goal) when the plan is not the state's (killed between the two) or of another episode than the contacts.
        A state from before the planner's first plan (``plan_step`` -1: its first decision had no goal, or a goal with
        no path) needs none: it resumes on no path, whatever ``plan`` is. The state and plan belong to their episode, as
        the contacts do."""
        why = ""
        if state.plan_step < 0:
            plan = PlannerPlanMsg(state.plan_step, np.zeros((0, 2)), None, state.episode)  # the "no plan yet" it follows
        if plan is None or plan.step != state.plan_step or plan.episode != state.episode:
            why = f"no plan of step {state.plan_step} (episode {state.episode}) in the cache"
        elif self.episodes.current is not None and state.episode != self.episodes.current:
            why = f"the contacts restored are of episode {self.episodes.current}"
        elif state.cmd.step != state.step or not state.plan_step <= state.step or not state.goal_step <= state.step:
            why = f"its command (step {state.cmd.step}), plan (step {state.plan_step}) or goal (step {state.goal_step}) is not of its step or before"
        elif misfit := state.follow.misfit(plan.path_xy_m if len(plan.path_xy_m) else None):
            why = f"it does not fit its plan: {misfit}"
        if plan is None or why:  # refused input, counted: `status` shows that this planner started afresh
            self.reject("planner_state", f"the cached state of step {state.step} (episode {state.episode}) is not restored: {why}")
            return False
        self.episodes.current = state.episode or None
        self.contacts_of(state)
        path = plan.path_xy_m if len(plan.path_xy_m) else None
        self.planner.resume(path, plan.free, state.follow)
        self.published_state = (plan.step, path, plan.free)
        self.cmd_step = self.last_step = state.step
        self.goal_step, self.no_frontier = state.goal_step, state.no_frontier
        self.last_cmd = state.cmd
        self.set_goal_blocked = state.set_goal_blocked
        self.last_feedback = self.feedback_msg(state.step, state.cmd.reason)
        self.set_goal_blocked = False
        self.backups_logged, self.escapes_logged = state.follow.backups, state.follow.escapes
        self.resumed_step = state.step if self.ctx.lockstep else None
        # Real time: the robot stood still while no planner ran (the referee stops it without commands), not because
        # the goal is out of reach: the progress and stall checks start over at the first command, as after stale inputs.
        self.stopped_for_stale = not self.ctx.lockstep
        goal = "no goal" if path is None else f"the goal ({path[-1][0]:.2f}, {path[-1][1]:.2f})"
        log.info(
            "restored the state of step %d (episode %d) from the cache: %s of step %d, %s, path point %d of %d",
            state.step, state.episode, goal, state.goal_step, state.follow.status.value, state.follow.progress_index, 0 if path is None else len(path),
        )  # fmt: skip
        return True

    def contacts_of(self, state: PlannerStateMsg) -> None:
        """Lockstep: keep the contacts ``state`` had (its ``contacts``, the first of those restored: they only grow, in
        order) when the cache's are of a later step, the planner killed after it sent a step's contacts but before that
        step's ``cmd_vel`` and state: that step is commanded again and adds them again, as it did. Contacts the state did
        not count that are not of a later step (another sender's), or in real time (no step is commanded again), are all
        kept: they keep the paths off more, never less. Fewer than the state had (a lost ``planner_contacts``) are kept,
        and said."""
        have = len(self.planner.contacts_xy_m)
        if state.contacts is None or have == state.contacts:
            return
        if have > state.contacts:
            if self.ctx.lockstep and self.contacts_restored_step is not None and self.contacts_restored_step > state.step:
                log.info(
                    "the contacts restored are of step %d, after the state's (step %d): keeping the %d it counted, not the %d "
                    "after them (that step is commanded again, adding them again)",
                    self.contacts_restored_step, state.step, state.contacts, have - state.contacts,
                )  # fmt: skip
                self.planner.contacts_xy_m = self.planner.contacts_xy_m[: state.contacts]
                self.contacts_published = state.contacts  # the step redone sends them again, as it did
            return
        log.warning("the state of step %d had %d contacts, the cache %d: going on without the %d missing", state.step, state.contacts, have, state.contacts - have)

    def on_pause(self, msg: ExploreResumeMsg) -> None:
        """Pause (``resume`` false) or resume exploration. Paused, every command is a stop and no goal is planned
        (the frontier service asks for none meanwhile; a goal asked for just before and answered meanwhile waits and is
        planned on resume, else the goal is kept). Lockstep refuses."""
        if self.ctx.lockstep:
            log.warning("%s%s ignored: %s", "resume" if msg.resume else "pause", f" by {msg.by}" if msg.by else "", LOCKSTEP_REFUSAL)
            return
        if not msg.resume:
            if self.paused is None:
                log.info("paused%s%s: commanding a stop until resumed", f" by {msg.by}" if msg.by else "", f" ({msg.reason})" if msg.reason else "")
            self.paused = msg
            self.set_state("running", self.pause_reason())  # a state of its own would be a new service_status version
            if self.cmd_step >= 0:  # at once, not at the next scan
                self.publish("cmd_vel", CmdVelMsg(self.cmd_step, VelocityCommand(), self.pause_reason()))
            return
        if self.paused is not None:
            log.info("resumed%s", f" by {msg.by}" if msg.by else "")
            self.paused = None
            self.planner.stood_still()  # the robot stood because it was told to, not because its goal is out of reach
            self.set_state("running")
            self.progress()

    def pause_reason(self) -> str:
        """A paused command's ``reason``."""
        by = self.paused.by if self.paused is not None else ""
        return f"paused: by {by}" if by else "paused"

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, ExploreResumeMsg):  # a control, of no episode or step
            self.on_pause(msg)
            return
        step = getattr(msg, "step", -1)
        seen = self.episodes.classify(getattr(msg, "episode", 0), step, self.cmd_step > 0 and isinstance(msg, OdometryMsg), from_referee=isinstance(msg, (OdometryMsg, ScanMsg)))
        if seen == "ended":
            self.reject(topic, f"{topic} of episode {msg.episode} at step {step}: that episode has ended", robot)  # type: ignore[attr-defined]
            return
        if seen == "new":
            log.info("new episode %d (%s of step %d): clearing the planner", self.episodes.current, topic, step)
            self.reset_episode()
        if isinstance(msg, (OdometryMsg, ScanMsg)):
            self.last_input_s["odometry" if isinstance(msg, OdometryMsg) else "scan"] = received_s
        if self.ctx.lockstep and isinstance(msg, OdometryMsg) and self.resumed_step is not None:
            self.join_behind(step)
        if self.ctx.lockstep and self.answer_again(msg, step):
            return
        if isinstance(msg, OdometryMsg):
            self.odoms[step] = (msg, received_s)
            if not self.ctx.lockstep:  # a LiDAR gone silent must not grow the odometry kept for its scans without bound
                self.keep_newest_within("odom", self.odoms, PENDING_SMALL_STEPS_KEPT, None, "the scan of its step", robot)
        elif isinstance(msg, ScanMsg):
            self.scans[step] = (msg, received_s)
            if not self.ctx.lockstep:  # nor odometry gone silent the scans (large: only the newest pair is commanded)
                self.keep_newest_within("scan", self.scans, PENDING_STEPS_KEPT, None, "the odometry of its step", robot)
        elif isinstance(msg, FrontiersMsg) and (msg.decide or self.ctx.lockstep):
            self.frontiers[step] = msg  # real time needs only those that carry a decision's grids
            if not self.ctx.lockstep:  # the grids it decoded (``PlannerFrontiersMsg``): a decision's frontiers are on one grid
                grid_bytes = sum(a.nbytes for a in msg.arrays.values())
                self.keep_newest_within("frontiers", self.frontiers, PENDING_DECISIONS_KEPT, grid_bytes, "the goal of its decision", robot)
        elif isinstance(msg, DistanceMapMsg):
            self.distance_maps[step] = msg
            if not self.ctx.lockstep:  # one float64 a cell: without its D a goal is planned all the same (``apply_goal``)
                self.keep_newest_within("distance_map", self.distance_maps, PENDING_DECISIONS_KEPT, msg.distance_m.nbytes, "the goal of its decision", robot)
            return  # never needed to command a step (a plan goes without it)
        elif isinstance(msg, GoalMsg) and msg.decided:
            self.goals[step] = msg
            if not self.ctx.lockstep:  # a long pause must not grow them either
                self.keep_newest_within("goal", self.goals, PENDING_DECISIONS_KEPT, None, "its decision's frontiers (or the end of a pause)", robot)
        self.progress()

    def join_behind(self, step: int) -> None:
        """Lockstep, the first odometry after a restored state (``resumed_step``): of the step after it or a retry of
        it, the state is the episode's and the steps go on from it. Of a later step, the planner was killed after a
        command but before its state went out, so the cache holds an older one: the planner keeps that state's goal and
        path and joins at the first step it has frontiers for, as a fresh planner does (its commands may then differ
        from the killed planner's by the steps the state missed)."""
        restored, self.resumed_step = self.resumed_step, None
        if restored is not None and step > restored + 1:
            log.warning("step %d: the restored state is of step %d, behind the episode: joining here with its goal", step, restored)
            self.cmd_step, self.last_cmd, self.last_feedback = -1, None, None

    def answer_again(self, msg: Message, step: int) -> bool:
        """Lockstep: the frontier service decides step k on this planner's report after command k - 1.
        Send that report again when the sim re-publishes a step (a retry: odometry seen twice), and
        once when this planner joins mid-episode (it follows nothing). Inputs of a step already
        commanded are a retry too: the command goes again, the step is not redone."""
        if isinstance(msg, OdometryMsg) and step > 0 and (step in self.odoms or self.cmd_step < 0):
            if self.cmd_step == step - 1 and self.last_feedback is not None:
                self.publish("planner_feedback", self.last_feedback)
            elif self.cmd_step < 0:  # a fresh planner reports idle; one whose restored state was behind, its goal
                self.publish("planner_feedback", self.feedback_msg(step - 1, ""))
        if isinstance(msg, (FrontiersMsg, GoalMsg)) and step <= self.cmd_step:
            resend = isinstance(msg, FrontiersMsg) or msg.decided
            if step == self.cmd_step and self.last_cmd is not None and resend:
                self.publish("cmd_vel", self.last_cmd)
            return True
        return False

    def command_ready(self, k: int) -> bool:
        """Lockstep step ``k`` can be commanded: its frontiers (and, when they asked for a decision, the
        new goal), odometry and scan are in."""
        f = self.frontiers.get(k)
        return f is not None and k in self.odoms and k in self.scans and (not f.decide or k in self.goals)

    def progress(self) -> None:
        """Lockstep: command the steps strictly in order (a fresh planner joins at the first step it
        has frontiers for), each on the frontier service's verdict: ``decide: false`` (most steps) keeps
        the current goal without waiting for the policy. The blocked check on the new map is part of
        that verdict (``path_blocked_ahead``), so this service needs no map.

        Real time (a controller loop, as Nav2's): every new odometry + scan pair is commanded at once on
        the current path; a new goal is planned as soon as it arrives with its frontiers."""
        if not self.ctx.lockstep:
            decided = [s for s in self.goals if s > self.goal_step and s in self.frontiers]
            if decided and self.paused is None:
                s = max(decided)
                self.apply_goal(self.frontiers[s], self.goals[s])
            k = max((s for s in self.scans if s > self.cmd_step and s in self.odoms), default=-1)  # the fewer: scans
            if k >= 0:
                self.on_command(k, None, None)
            return
        while True:
            k = self.cmd_step + 1 if self.cmd_step >= 0 else min(self.frontiers, default=-1)
            if k < 0 or not self.command_ready(k):
                self.compute_ahead()
                return
            f = self.frontiers[k]
            self.on_command(k, f, self.goals.get(k) if f.decide else None)

    def compute_ahead(self) -> None:
        """Lockstep: with the next step's odometry and scan in but not its verdict, compute its command
        on the current path now (in parallel with the mapper and the frontier service) and undo the
        planner's state; ``on_command`` keeps it when the verdict keeps the goal. The same ``update``
        on the same inputs and state: the command is the one computed later would be."""
        k = self.cmd_step + 1
        if self.cmd_step < 0 or k in self.frontiers or k not in self.odoms or k not in self.scans or self.no_frontier:
            return
        if self.ahead is not None and self.ahead[0] == k:
            return
        (odom, _), (scan, _) = self.odoms[k], self.scans[k]
        before = self.planner.follow_state()
        result = self.planner.update(odom.pose, odom.stamp_s, scan.scan)
        self.ahead = (k, result, self.planner.follow_state())
        self.planner.restore_follow_state(before)
        # Provisional: the sim may step ahead on it, but moves only on the step's cmd_vel.
        self.publish("cmd_vel_ahead", CmdVelMsg(k, result.command, "ahead"))

    def feedback_msg(self, k: int, reason: str) -> PlannerFeedbackMsg:
        """The report after step ``k``'s command: the planner's status, the path still ahead and the goal they are about."""
        p = self.planner
        ahead = p.remaining_path() if p.status == PlannerStatus.FOLLOWING else np.zeros((0, 2))
        return PlannerFeedbackMsg(k, p.status.value, "command", self.set_goal_blocked, reason, ahead, self.goal_step, self.episodes.current or 0)

    def publish_feedback(self, k: int, reason: str) -> None:
        self.last_feedback = self.feedback_msg(k, reason)
        self.set_goal_blocked = False
        self.publish("planner_feedback", self.last_feedback)

    def apply_goal(self, f: FrontiersMsg, g: GoalMsg) -> None:
        """Plan to a newly decided goal on the traversable grid and D it was chosen on. Without that D
        (lost or late), the planner's own fast-marching pass stops just past the goal's distance: the
        same path."""
        self.pending_new_goal, self.goal_step = True, g.step
        if not g.has_goal:
            self.planner.clear()
            self.no_frontier = True
            return
        self.no_frontier = False
        d = self.distance_maps.get(f.step)
        distance = d.distance_m if d is not None and d.geometry == f.geometry and d.pose == f.pose else None
        assert f.geometry is not None and f.pose is not None  # frontiers that asked for this decision carry them
        status = self.planner.set_goal(f.arrays["traversable"], f.geometry, f.pose, np.array([g.x_m, g.y_m]), distance, g.distance_m, f.arrays["occupied"], f.arrays["explored"])
        self.set_goal_blocked = status == PlannerStatus.BLOCKED
        if self.set_goal_blocked:
            log.info("step %d: no path to the goal (%.2f, %.2f): %s", g.step, g.x_m, g.y_m, self.planner.blocked_why)

    def on_command(self, k: int, f: FrontiersMsg | None, g: GoalMsg | None) -> None:
        """Command step ``k``: lockstep applies the step's new goal ``g`` first (if any)."""
        if g is not None and f is not None:
            self.apply_goal(f, g)
        (odom, odom_s), (scan, scan_s) = self.odoms.pop(k), self.scans.pop(k)
        # Lockstep: this step's frontiers and goal are used up. Real time: those of a decision not
        # planned yet are kept (a goal may arrive after newer odometry).
        done = k if self.ctx.lockstep else self.goal_step
        for d, last in ((self.odoms, k), (self.scans, k), (self.goals, done), (self.frontiers, done), (self.distance_maps, done)):
            for s in [s for s in d if s <= last]:
                d.pop(s)
        self.cmd_step = self.last_step = k
        reason = ""
        if self.paused is not None:
            cmd, reason = VelocityCommand(), self.pause_reason()
            self.set_state("running", reason)  # after a stale spell too
        elif self.no_frontier:
            cmd, reason = VelocityCommand(), NO_FRONTIER_REASON
        else:
            # Lockstep: the sim holds the robot until this very command, so inputs that waited on a slow
            # decision are not stale; a stale stop would only be dropped by the sim, re-sent on each of its
            # retries, and fail the episode.
            age_s = time.monotonic() - min(odom_s, scan_s)
            if age_s > self.params.stale_after_s and not self.ctx.lockstep:
                cmd, reason = VelocityCommand(), f"stale: inputs of step {k} are {age_s:.1f} s old"
                self.set_state("stale", reason)
                # The robot stops because its inputs are stale, as on a silence (``on_tick``): the progress and stall
                # checks start over, or a lagging link longer than the progress window ended the goal (or drove out).
                self.planner.stood_still()
            else:
                if self.stopped_for_stale:
                    # The robot stood still because its inputs were stale (or no planner ran), not because the goal is
                    # out of reach: the progress checker starts over instead of ending the goal no_progress, and the stall
                    # check does not count the wait as a stalled period.
                    self.planner.stood_still()
                ahead, self.ahead = self.ahead, None
                if ahead is not None and ahead[0] == k and g is None and self.ctx.lockstep:
                    result = ahead[1]
                    self.planner.restore_follow_state(ahead[2])
                else:
                    result = self.planner.update(odom.pose, odom.stamp_s, scan.scan)
                cmd = result.command
                if result.status == PlannerStatus.BLOCKED and self.planner.blocked_why:
                    reason = f"blocked: {self.planner.blocked_why}"  # no path at all (off the map, on a cell not traversable, unreachable), not a path cut later
                elif result.status != PlannerStatus.FOLLOWING:
                    reason = result.status.value
                elif result.recovery:
                    reason = result.recovery  # following, but backing up (pinned), driving out (no progress) or held: an obstacle behind
                    if result.recovery == "reverse_blocked":
                        if self.reverse_blocked_logged != k - 1:  # once per run of held steps
                            log.info("step %d: an obstacle on the map behind the robot: not reversing", k)
                        self.reverse_blocked_logged = k
                    if self.planner.recovery.escapes != self.escapes_logged:
                        self.escapes_logged = self.planner.recovery.escapes
                        log.info("step %d: no progress on the goal: driving out on the open heading (recovery %d)", k, self.escapes_logged)
                    if self.planner.stall.backups != self.backups_logged:
                        self.backups_logged = self.planner.stall.backups
                        if self.planner.stall.last_started_now:
                            log.info("step %d: blocked ahead by a return nearer than the sensor's range_min: backing up (back-up %d)", k, self.backups_logged)
                        else:
                            log.info("step %d: the robot has not moved for %d commands: backing up (back-up %d)", k, self.ctx.exploration.planner.stall_steps, self.backups_logged)
                self.set_state("running")
        self.stopped_for_stale = False
        stop_already_sent = self.ends_stopped(self.last_cmd) and reason == NO_FRONTIER_REASON
        self.last_cmd = CmdVelMsg(k, cmd, reason, new_goal=self.pending_new_goal, episode=self.episodes.current or 0)
        self.pending_new_goal = False
        self.publish_contacts(k)  # before the command whose state counts them: the cache never has a state without its contacts
        if not stop_already_sent:
            self.last_cmd = self.with_checkpoint(k, self.last_cmd)
            self.publish("cmd_vel", self.last_cmd)
        self.publish_feedback(k, reason)
        self.publish_path(k)

    def publish_contacts(self, k: int) -> None:
        """All the contacts, once step ``k``'s command has added one (a step that adds none sends nothing), just before
        that command's ``cmd_vel``: the referee keeps them for a restarted planner, and a state it keeps (riding on the
        ``cmd_vel``) then always has its contacts in the cache too (``PlannerStateMsg.contacts``). The lockstep chain does
        not wait for them; a step that adds a contact sends this small message before its command."""
        contacts = self.planner.contacts_xy_m
        if len(contacts) == self.contacts_published:
            return
        self.contacts_published = len(contacts)
        self.publish("planner_contacts", PlannerContactsMsg(k, contacts, self.episodes.current or 0))

    def with_checkpoint(self, k: int, cmd: CmdVelMsg) -> CmdVelMsg:
        """Step ``k``'s command carrying the planner's state after it and, when the command made a new plan (a new goal's,
        a re-plan round a contact, or none), that plan, each encoded (``CmdVelMsg.planner_state``, ``.planner_plan``).
        The referee keeps them for a restarted planner without decoding them: on the message the sim steps on anyway,
        the lockstep chain pays no delivery of its own for them. Sent again as it is on a retry of the step."""
        p, (plan_step, path, free) = self.planner, self.published_state
        plan = None
        if p.path is not path or p.free is not free:
            plan = encode(PlannerPlanMsg(k, np.zeros((0, 2)) if p.path is None else p.path, p.free if p.path is not None else None, self.episodes.current or 0))
            if len(plan) > max_planner_plan_bytes():  # never on a real grid; the state then names a plan the cache lacks
                log.warning("step %d: the plan (%d bytes) is over the %d bytes cmd_vel carries: a restart would start afresh", k, len(plan), max_planner_plan_bytes())
                plan = None
            plan_step = k
            self.published_state = (k, p.path, p.free)
        state = PlannerStateMsg(
            k, plan_step, self.goal_step, self.no_frontier, cmd, self.set_goal_blocked, p.checkpoint(), self.episodes.current or 0, len(p.contacts_xy_m),
        )  # fmt: skip
        encoded = encode(state)
        if len(encoded) > MAX_PLANNER_STATE_BYTES:  # the referee would refuse the whole command (the robot stops): it goes without
            self.states_too_large += 1
            log.warning(
                "step %d: the planner's state (%d bytes) is over the %d bytes cmd_vel carries: the command goes without it "
                "(a restart would resume from an earlier state, or start afresh; %d so far)",
                k, len(encoded), MAX_PLANNER_STATE_BYTES, self.states_too_large,
            )  # fmt: skip
            return dataclasses.replace(cmd, planner_state=None, planner_plan=plan)
        return dataclasses.replace(cmd, planner_state=encoded, planner_plan=plan)

    def extra_status(self) -> dict[str, int]:
        """``contacts``: how many the planner keeps in this episode (restored ones included); ``states_too_large``, once
        there is one: the states left off their command (``with_checkpoint``)."""
        return {"contacts": len(self.planner.contacts_xy_m), **({"states_too_large": self.states_too_large} if self.states_too_large else {})}

    def ends_stopped(self, cmd: CmdVelMsg | None) -> bool:
        """Real time: ``cmd``, the last command sent, was the stop at the episode's end (``no_frontier``), so the
        scans that go on after it (a real robot's) get no command: one stop is enough, the robot's last command (the
        bridge sends its own zero Twist at the end too, and forwards any later command as a zero one: docs/hardware.md);
        a stop on every scan was noise on the robot's ``cmd_vel``. Lockstep commands every step: its sim waits for each."""
        return not self.ctx.lockstep and cmd is not None and cmd.reason == NO_FRONTIER_REASON

    def publish_path(self, k: int) -> None:
        """The path still ahead, with each new plan and otherwise every ``path_period_s``."""
        now_s = time.monotonic()
        if self.planner.path is self.published_plan and now_s - self.path_published_s < self.params.path_period_s:
            return
        self.published_plan, self.path_published_s = self.planner.path, now_s
        self.publish("path", PathMsg(k, self.planner.remaining_path()))

    def on_tick(self, now_s: float) -> None:
        silent = {name: now_s - at_s for name, at_s in self.last_input_s.items() if now_s - at_s > self.params.stale_after_s}
        if not silent or self.cmd_step < 0:
            return
        if not self.stopped_for_stale:
            reason = silence_reason(silent, ".1f")
            self.set_state("stale", reason)
            self.publish("cmd_vel", CmdVelMsg(self.cmd_step, VelocityCommand(), reason))
            self.stopped_for_stale = True
        elif self._state_and_reason[0] == "stale" and self._state_and_reason[1].startswith(SILENCE_PREFIX):
            # Still silent (the robot's bridge gone): the status says for how long now, in whole seconds, where it
            # stayed "no odometry for 1.1 s" however long the silence lasted. Neither logged nor sent again.
            self.set_state("stale", silence_reason(silent, ".0f"), quiet=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m services.planner``'s entry point; exit code 2 for a bad config."""
    return service_main(PlannerService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
