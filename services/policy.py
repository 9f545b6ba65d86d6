"""Policy service: ``make_policy(method)`` and ``select`` on each decision's Observation.

With ``serve_all_robots`` one process serves every robot (it subscribes to ``cso/*/frontiers`` and
keeps one selector per robot); each robot it serves sees it under its own keys, as if it were its own
policy: a liveliness token ``cso/<robot>/alive/policy`` from its first decision input, and
``cso/<robot>/service/policy/status`` with that robot's state, so ``status --robot ID`` shows it. A robot
whose own policy is alive (another process's ``cso/<robot>/alive/policy``: its run has a policy of its own, or
another server serves it) is left to that policy: two policies would send it two goals at each decision. A robot
whose frontier service goes with the rest of its run (its run stopped) is let go: its token is withdrawn, so the robot
no longer looks running to ``status`` and a new run of that id may start a policy of its own. One whose frontier
service goes while other services of its run still run (a crash its launcher restarts) is kept for
``frontier_restart_grace_s``, so that the restarted frontier service finds its selector as it was, as a robot with a
policy of its own keeps its selector through such a restart; it is let go once that has passed. A robot heard from by no input for
``forget_robot_after_s`` while no frontier service of it is alive is let go too; either way the server forgets it
(its selector, last goal, counts, steps, publisher), so that it does not grow with every robot a long deployment sees,
and counts it in its status (``robots_forgotten``): a robot that comes back is served afresh.

It answers the steps that ask for a decision with ``decided: true`` and the new goal (or none: nothing
left to explore); on the other steps the planner keeps following the current goal without waiting for
the policy, and late joiners query the last goal. A decision input older than ``stale_after_s`` is not
acted on (the status says why).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import zenoh

from cso_runtime.config import ConfigError, check_bounds, check_torch_device, from_dict, seconds
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import (
    FrontiersMsg,
    GoalMsg,
    Message,
    ServiceStatusMsg,
    decode,
    encode,
    frontiers_from_observation,
    frontiers_reading,
    observation_from_frontiers,
)
from cso_runtime.policies import LEARNED_METHODS, GoalSelector, check_method, make_policy
from services.common import EpisodeWatch, Service, ServiceContext, service_main, warm_up_observation

log = logging.getLogger("cso.policy")


POLICY_PARAMS_BOUNDS = {**seconds("stale_after_s", "forget_robot_after_s", positive=True), **seconds("frontier_restart_grace_s")}
"""``PolicyParams``' bounds: its times at most a day (``config.MAX_WAIT_S``)."""


@dataclass
class PolicyParams:
    """Parameters of the policy service (``services.policy`` in a profile)."""

    method: str = ""
    """Goal selector by name (greedy-dist, greedy-info, utility, random, cso...) or a method of one's own,
    ``module.path:Attribute`` (importable by this process: on PYTHONPATH or installed); empty = the profile's method."""
    stale_after_s: float = 5.0
    """Decision inputs older than this (wall clock) are not acted on; no input for this long = stale."""
    device: str = "cpu"
    """Torch device of a learned policy."""
    serve_all_robots: bool = False
    """Answer every robot on the network (``cso/*/frontiers``), not only ``--robot``: one policy server
    for several robots (then start one policy per network, not one per robot)."""
    forget_robot_after_s: float = 600.0
    """With ``serve_all_robots``: a robot (not ``--robot``) heard from by no input for this long (wall clock) while no
    frontier service of it is alive is forgotten (a robot whose frontier service goes is left to
    ``frontier_restart_grace_s``, sooner or later than this)."""
    frontier_restart_grace_s: float = 30.0
    """With ``serve_all_robots``: how long (wall clock) a robot whose frontier service went while another service of its
    run is still alive (a crash, a kill: its launcher restarts it after ``supervision.backoff_s``, doubling up to
    ``backoff_max_s``, 8 s, then its start-up) is kept, its selector (memory of past goals, stuck mask) and its token
    with it, for the restarted frontier service; then it is forgotten. A robot whose run stopped (no service of it
    alive) is forgotten at the next tick whatever this is. 0: at the next tick too."""

    def validate(self) -> None:
        check_bounds("", self, POLICY_PARAMS_BOUNDS)  # each time's range: its one check
        if self.method:
            try:
                check_method(self.method)
            except ConfigError as exc:
                raise ConfigError(f"method: {exc} (or empty: the profile's)") from None
        try:
            check_torch_device(self.device)
        except ConfigError as exc:
            raise ConfigError(f"device: {exc}") from None


@dataclass
class RobotState:
    """What the policy service keeps for each robot it serves: its own selector, its last answer, and when its last
    input came (``last_input_s``, the service's clock) to tell when it went stale."""

    selector: GoalSelector
    answered_step: int = -1
    last_answer: GoalMsg | None = None
    last_input_s: float = 0.0
    stale_reason: str = ""
    """Why this robot is not commanded now (its inputs went stale), or empty."""
    episodes: EpisodeWatch = field(default_factory=EpisodeWatch)


class PolicyService(Service):
    """Chooses the goal on each decision's Observation with ``make_policy(method)``, for one robot or, with
    ``serve_all_robots``, for every robot without a policy of its own."""

    name = "policy"
    inputs = {"frontiers": FrontiersMsg}
    outputs = {"goal": GoalMsg}

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(PolicyParams, ctx.params, where="services.policy")
        self.method = self.params.method or str(ctx.profile.get("method", "greedy-dist"))
        if self.params.serve_all_robots:
            self.subscribe_robot = "*"
        self.seed = int(ctx.profile.get("seed", 0))
        self.robots: dict[str, RobotState] = {}
        selector = self.new_selector()  # fail early on an unknown method
        # Decode of each decision message the grids this method reads (GoalSelector.grids), no more.
        grids = getattr(selector, "grids", None)
        self.inputs = {"frontiers": frontiers_reading(None if grids is None else tuple(grids))}  # type: ignore[misc]  # may narrow
        if self.method in LEARNED_METHODS:
            from cso_runtime.learned.weights import weights_path  # noqa: PLC0415

            log.info("%s: weights %s", self.method, weights_path(self.method, ctx.exploration.sensor))
        for said in getattr(selector, "input_warnings", ()):  # settings the weights were trained otherwise with, said once
            log.warning("%s", said)
        self._queryables: list = []
        self._tokens: dict[str, zenoh.LivelinessToken] = {}
        """Robot -> the liveliness token under its keys (the robots served besides ``--robot``)."""
        self._mine: set[str] = {ctx.robot}
        """Robots whose ``alive/policy`` token is this service's own (``--robot``'s, and each robot served)."""
        self._other_policies: set[str] = set()
        """Robots (not ours) whose own policy, another process, is alive: a server leaves them to it."""
        self._left: set[str] = set()
        """Robots left to their own policy, said once in the log until that policy goes."""
        self._frontier_gone_s: dict[str, float | None] = {}
        """Robots (not ``--robot``) whose frontier service (their decision inputs) has gone -> the tick that first saw it
        gone (None until one has): let go when their run is gone too, or ``frontier_restart_grace_s`` after."""
        self._services_alive: dict[str, set[str]] = {}
        """Robot -> its services alive besides a policy (their ``alive/<name>`` tokens): whether its run still runs, and
        its frontier service (a robot with one is not forgotten however long it is silent: a paused run)."""
        self._gone_lock = threading.Lock()
        self.robots_forgotten = 0

    def new_selector(self) -> GoalSelector:
        try:
            return make_policy(
                self.method, self.ctx.exploration.masks, seed=self.seed, device=self.params.device, sensor=self.ctx.exploration.sensor, frontier=self.ctx.exploration.frontier
            )
        except (ValueError, FileNotFoundError) as exc:  # an unknown method, or a learned one without weights
            raise ConfigError(str(exc)) from None

    def warm_up(self) -> None:
        """The selector's own warm-up (the learned policy's traced network), then one decision on a
        practice Observation that went through this service's decoding, with a selector thrown away."""
        selector = self.new_selector()
        warm_up = getattr(selector, "warm_up", None)
        if warm_up is not None:
            warm_up()
        msg = decode(encode(frontiers_from_observation(0, "no_goal", warm_up_observation(self.ctx.exploration), 0.0)), self.inputs["frontiers"])
        assert isinstance(msg, FrontiersMsg)
        selector.select(observation_from_frontiers(msg))

    def start(self) -> None:
        assert self.session is not None
        self._queryables.append(self.session.declare_queryable(f"cso/{self.subscribe_robot}/goal", self.guarded(self._on_query)))
        if self.params.serve_all_robots:  # --robot's own status is the service's (run_service's queryable)
            self._queryables.append(self.session.declare_queryable(RobotKeys("*").service_status(self.name), self.guarded(self._on_status_query)))
            self._queryables.append(self.session.liveliness().declare_subscriber(RobotKeys("*").alive("*"), self.guarded(self._on_alive), history=True))
            # The subscriber's history comes on its own time: a robot's decision input queued meanwhile (the loop
            # handles it after ``start``) was served though its run has a policy of its own. Asked here, before.
            for reply in self.session.liveliness().get(RobotKeys("*").alive(self.name), timeout=1.0):
                if reply.ok is not None:
                    self._on_policy_alive(reply.ok)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        """A service of a robot came or went: its policy (``_on_policy_alive``), or another, which says whether its run
        still runs and whether its frontier service (its decision inputs) is alive."""
        _, robot, _, service = str(sample.key_expr).split("/")
        if service == self.name:
            self._on_policy_alive(sample)
            return
        came = str(sample.kind).endswith("PUT")
        with self._gone_lock:
            alive = self._services_alive.setdefault(robot, set())
            if came:
                alive.add(service)
            else:
                alive.discard(service)
                if not alive:
                    del self._services_alive[robot]
            if service == "frontier":
                if came:
                    self._frontier_gone_s.pop(robot, None)  # back (a restart): keep serving it as it was
                elif robot != self.ctx.robot:
                    self._frontier_gone_s.setdefault(robot, None)

    def release_gone_robots(self, now_s: float) -> None:
        """Stop serving the robots whose frontier service went with their run, or ``frontier_restart_grace_s`` ago
        without coming back, and those heard from by no input for ``forget_robot_after_s`` with no frontier service
        alive nor one within its grace, and forget them."""
        grace_s = self.params.frontier_restart_grace_s
        gone: dict[str, str] = {}
        with self._gone_lock:
            for robot, gone_s in list(self._frontier_gone_s.items()):
                if gone_s is None:
                    gone_s = self._frontier_gone_s[robot] = now_s
                if robot not in self._services_alive:
                    gone[robot] = "its frontier service is gone, and no other service of its run is alive"
                elif now_s - gone_s >= grace_s:
                    gone[robot] = f"its frontier service has been gone for {now_s - gone_s:.0f} s (frontier_restart_grace_s)"
                else:
                    continue  # its launcher may be restarting it
                del self._frontier_gone_s[robot]
            alive = {robot for robot, services in self._services_alive.items() if "frontier" in services}
            in_grace = set(self._frontier_gone_s)  # left to the grace: silent while its frontier service restarts
        for robot, why in gone.items():
            if robot in self.robots or robot in self.heard_from_s:
                self.forget_robot(robot, why)
        for robot, heard_s in list(self.heard_from_s.items()):
            silent_s = now_s - heard_s
            if robot != self.ctx.robot and robot not in alive | in_grace and silent_s > self.params.forget_robot_after_s:
                self.forget_robot(robot, f"nothing heard from it for {silent_s:.0f} s, and no frontier service of it is alive")

    def forget_robot(self, robot: str, why: str = "") -> None:
        """Withdraw the token under ``robot``'s keys and forget all of it: its selector (past goals, stuck mask), last
        goal, counts and steps. A robot that comes back is served afresh from its next decision input."""
        super().forget_robot(robot)
        self.robots.pop(robot, None)
        token = self._tokens.pop(robot, None)
        if token is not None:
            token.undeclare()
        self._mine.discard(robot)
        self._left.discard(robot)
        with self._lock:
            self.robots_forgotten += 1
        log.info("robot %s: %s; forgetting it (%d robots forgotten so far)", robot, why, self.robots_forgotten)

    def extra_status(self) -> dict[str, int]:
        with self._lock:
            return {"robots_forgotten": self.robots_forgotten}

    def _on_policy_alive(self, sample: zenoh.Sample) -> None:
        """Track the robots that have a policy of their own (a token under their keys that is not ours)."""
        robot = str(sample.key_expr).split("/")[1]
        if robot in self._mine:
            return
        if str(sample.kind).endswith("PUT"):
            self._other_policies.add(robot)
        else:
            self._other_policies.discard(robot)
            self._left.discard(robot)

    def _on_status_query(self, query: zenoh.Query) -> None:
        robot = str(query.key_expr).split("/")[1]
        for name, st in list(self.robots.items()):
            if name != self.ctx.robot and robot in (name, "*"):
                query.reply(RobotKeys(name).service_status(self.name), encode(self.robot_status(name, st)))

    def robot_status(self, robot: str, st: RobotState) -> ServiceStatusMsg:
        """This service's status as one robot's own policy would give it: that robot's step, staleness,
        rejected inputs and inputs handled."""
        state = "stale" if st.stale_reason else "running"
        with self._lock:
            rejected = dict(self.rejected_by_robot.get(robot, {}))
        return ServiceStatusMsg(self.name, robot, state, st.answered_step, st.stale_reason, rejected, self.processed_by_robot[robot])

    def _on_query(self, query: zenoh.Query) -> None:
        robot = str(query.key_expr).split("/")[1]
        for name, st in list(self.robots.items()):
            if st.last_answer is not None and robot in (name, "*"):
                query.reply(f"cso/{name}/goal", encode(st.last_answer))

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        st = self.robots.get(robot)
        if st is None:
            if robot != self.ctx.robot and robot in self._other_policies:
                if robot not in self._left:
                    self._left.add(robot)
                    log.warning("robot %s has a policy of its own (%s is alive): not serving it", robot, RobotKeys(robot).alive(self.name))
                return
            st = self.robots[robot] = RobotState(self.new_selector())
            log.info("serving robot %s with %s", robot, self.method)
            if robot != self.ctx.robot and self.session is not None:  # it sees a policy under its own keys
                self._mine.add(robot)
                self._tokens[robot] = self.session.liveliness().declare_token(RobotKeys(robot).alive(self.name))
        assert isinstance(msg, FrontiersMsg)
        st.last_input_s = received_s
        seen = st.episodes.classify(msg.episode, msg.step, st.answered_step > 0)
        if seen == "ended":
            self.reject("frontiers", f"robot {robot}: decision input of episode {msg.episode}, which has ended", robot)
            return
        if seen == "new":
            log.info("robot %s: new episode %d at step %d, new selector", robot, msg.episode, msg.step)
            st = self.robots[robot] = RobotState(self.new_selector(), last_input_s=received_s, episodes=st.episodes)
        if msg.step <= st.answered_step:
            last = st.last_answer
            if msg.step == st.answered_step and msg.decide and last is not None and last.step == msg.step:
                self.publish("goal", last, robot)  # lockstep retry
            return
        age_s = time.monotonic() - received_s
        if age_s > self.params.stale_after_s:
            st.stale_reason = f"robot {robot}: decision input of step {msg.step} is {age_s:.1f} s old; not commanding"
            self.update_state()
            return
        st.stale_reason = ""
        self.update_state()
        st.answered_step = self.last_step = msg.step
        if not msg.decide:
            return  # the planner keeps following the current goal without us
        t0 = time.perf_counter()
        obs = observation_from_frontiers(msg)
        goal = st.selector.select(obs)
        ms = msg.build_ms + (time.perf_counter() - t0) * 1e3
        if goal is None:
            out = GoalMsg(msg.step, True, decision_ms=ms, method=self.method, reason=msg.reason, episode=msg.episode)
        else:
            out = GoalMsg(msg.step, True, goal.x_m, goal.y_m, goal.cluster_index, goal.distance_m, ms, self.method, msg.reason, msg.episode)
        st.last_answer = out
        self.publish("goal", out, robot)

    def on_tick(self, now_s: float) -> None:
        self.release_gone_robots(now_s)
        for robot, st in self.robots.items():
            if now_s - st.last_input_s > self.params.stale_after_s and not st.stale_reason:
                st.stale_reason = f"robot {robot}: no frontiers for {now_s - st.last_input_s:.1f} s; not commanding"
        self.update_state()

    def update_state(self) -> None:
        """One state for every robot served: stale when all of them are (each one's reason), running
        when any is commanded (saying which others are not). The robots counted are those it has a selector for:
        heard from (a decision input) and not forgotten, not every robot whose run is up, which it cannot tell from
        one that is starting (no input yet) or whose episode is over (no more inputs): the reason says so."""
        stale = [st.stale_reason for st in self.robots.values() if st.stale_reason]
        if not stale:
            self.set_state("running")
        elif len(stale) == len(self.robots):
            self.set_state("stale", "; ".join(stale))
        else:
            commanded = len(self.robots) - len(stale)
            self.set_state("running", f"commanding {commanded} of the {len(self.robots)} robots it has heard from; " + "; ".join(stale))


def main(argv: list[str] | None = None) -> int:
    """``python -m services.policy``'s entry point; exit code 2 for a bad config."""
    return service_main(PolicyService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
