"""Frontier service: decides *when* a new goal is needed and builds the decision's Observation.

The re-decision rule is ``cso_runtime.episode.decision_reason`` (reached, blocked, no_progress, goal
no longer a frontier, every ``replan_every_steps``), the same function the in-process ``Explorer``
uses; the Observation is ``ObservationBuilder.build`` (frontiers, one fast-marching pass, entropy,
clusters). Per step it publishes either ``decide: false`` or the arrays the policy needs.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from cso_runtime.episode import decision_reason, goal_failed_in_place, mark_dead_frontier
from cso_runtime.messages import FrontiersMsg, GoalMsg, MapMsg, Message, OdometryMsg, PlannerFeedbackMsg, frontiers_from_observation
from cso_runtime.observation import ObservationBuilder
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.planner import PlannerStatus
from cso_runtime.policies import Goal
from services.common import Service, ServiceContext, service_main

log = logging.getLogger("cso.frontier")


class FrontierService(Service):
    name = "frontier"
    inputs = {"map": MapMsg, "odom": OdometryMsg, "planner_feedback": PlannerFeedbackMsg, "goal": GoalMsg}

    def __init__(self, ctx: ServiceContext):
        super().__init__(ctx)
        cfg = ctx.exploration
        self.builder = ObservationBuilder(cfg.frontier, cfg.robot)
        self.replan_every_steps = cfg.episode.replan_every_steps
        self.goal_tolerance_m = cfg.episode.goal_tolerance_m
        self.reset_episode()

    def reset_episode(self) -> None:
        """Forget the decision state (a new episode, or a fresh start)."""
        self.maps: dict[int, MapMsg] = {}
        self.odoms: dict[int, OdometryMsg] = {}
        self.feedback: dict[int, PlannerFeedbackMsg] = {}
        self.goal: Goal | None = None
        self.goal_seen_step = -1
        self.decision_step = 0
        self.dead: np.ndarray | None = None
        self.path_nodes: list[tuple[float, float]] = []
        self.done_step = -1
        self.last_out: FrontiersMsg | None = None

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        step = getattr(msg, "step", -1)
        if isinstance(msg, OdometryMsg) and step == 0 and self.done_step > 0:
            log.info("odometry restarted at step 0: new episode, forgetting the decision state")
            self.reset_episode()
        if isinstance(msg, GoalMsg):
            self.goal_seen_step = max(self.goal_seen_step, step)
            if msg.decided:
                self.goal = Goal(msg.x_m, msg.y_m, msg.cluster_index, msg.distance_m) if msg.has_goal else None
                self.decision_step = step
            self.try_decide()
            return
        if step <= self.done_step:
            if self.last_out is not None and step == self.done_step:
                self.publish("frontiers", self.last_out)  # a lockstep retry: answer again
            return
        if isinstance(msg, MapMsg):
            self.maps[step] = msg
        elif isinstance(msg, OdometryMsg):
            self.odoms[step] = msg
        elif isinstance(msg, PlannerFeedbackMsg) and msg.phase == "map":
            self.feedback[step] = msg
        self.try_decide()

    def try_decide(self) -> None:
        ready = sorted(set(self.maps) & set(self.odoms) & set(self.feedback))
        if not ready:
            return
        k = ready[0] if self.ctx.lockstep else ready[-1]
        if self.ctx.lockstep and self.goal_seen_step >= 0 and self.goal_seen_step < k - 1:
            return  # the goal of the previous step is still on its way (a fresh start does not wait)
        m, odom, fb = self.maps.pop(k), self.odoms.pop(k), self.feedback.pop(k)
        for d in (self.maps, self.odoms, self.feedback):
            for s in [s for s in d if s <= k]:
                d.pop(s)
        self.done_step = self.last_step = k
        occupancy = OccupancyMap.from_occupancy_grid(m.grid, m.geometry)
        if self.dead is None or self.dead.shape != occupancy.geometry.shape:
            self.dead = np.zeros(occupancy.geometry.shape, dtype=bool)
        if fb.set_goal_blocked and self.goal is not None:
            mark_dead_frontier(self.dead, occupancy.geometry, (self.goal.x_m, self.goal.y_m), self.goal_tolerance_m)
        status = PlannerStatus(fb.status) if fb.status != "stale" else PlannerStatus.BLOCKED
        reason = decision_reason(self.goal, status, occupancy, k - self.decision_step, self.replan_every_steps)
        if reason is None:
            out = FrontiersMsg(k, False)
        else:
            t0 = time.perf_counter()
            if self.goal is not None and goal_failed_in_place(reason, self.goal, occupancy, odom.pose):
                mark_dead_frontier(self.dead, occupancy.geometry, (self.goal.x_m, self.goal.y_m), self.goal_tolerance_m)
            self.path_nodes.append((odom.pose.x_m, odom.pose.y_m))
            obs = self.builder.build(occupancy, odom.pose, np.array(self.path_nodes), exclude_frontier=self.dead)
            out = frontiers_from_observation(k, reason, obs, (time.perf_counter() - t0) * 1e3)
        self.last_out = out
        self.publish("frontiers", out)


def main(argv: list[str] | None = None) -> int:
    return service_main(FrontierService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
