"""Planner service: ``LocalPlanner`` (path, pure pursuit, progress and blocked checks) -> cmd_vel.

Per step it reports twice on ``planner/feedback``: after the step's map (``check_blocked``) and after
the step's command (``update``), so the frontier service applies the shared re-decision rule to the
same status as the in-process loop. It stops the robot, and says why in its status, when odometry or
scans are older than ``stale_after_s``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from cso_runtime.config import ConfigError, from_dict
from cso_runtime.geometry import VelocityCommand
from cso_runtime.messages import CmdVelMsg, FrontiersMsg, GoalMsg, MapMsg, Message, OdometryMsg, PathMsg, PlannerFeedbackMsg, ScanMsg
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.planner import LocalPlanner, PlannerStatus
from services.common import Service, ServiceContext, service_main

log = logging.getLogger("cso.planner")


@dataclass
class PlannerParams:
    """Parameters of the planner service (``services.planner`` in a profile)."""

    stale_after_s: float = 2.0
    """Odometry or scans older than this (wall clock) stop the robot."""

    def validate(self) -> None:
        if not self.stale_after_s > 0:
            raise ConfigError("stale_after_s must be positive")


class PlannerService(Service):
    name = "planner"
    inputs = {"map": MapMsg, "odom": OdometryMsg, "scan": ScanMsg, "frontiers": FrontiersMsg, "goal": GoalMsg}
    tick_period_s = 0.1

    def __init__(self, ctx: ServiceContext):
        super().__init__(ctx)
        self.params = from_dict(PlannerParams, ctx.params, where="services.planner")
        self.reset_episode()

    def reset_episode(self) -> None:
        """A fresh planner and empty buffers (a new episode, or a fresh start)."""
        cfg = self.ctx.exploration
        self.planner = LocalPlanner(cfg.robot, cfg.planner, cfg.episode.goal_tolerance_m, cfg.sensor.mount_x_m)
        self.maps: dict[int, MapMsg] = {}
        self.odoms: dict[int, tuple[OdometryMsg, float]] = {}
        self.scans: dict[int, tuple[ScanMsg, float]] = {}
        self.frontiers: dict[int, FrontiersMsg] = {}
        self.goals: dict[int, GoalMsg] = {}
        self.map_step = -1
        self.cmd_step = -1
        self.set_goal_blocked = False
        self.last_feedback: dict[str, PlannerFeedbackMsg] = {}
        self.last_cmd: CmdVelMsg | None = None
        self.last_input_s = time.monotonic()
        self.stopped_for_stale = False

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        step = getattr(msg, "step", -1)
        if isinstance(msg, OdometryMsg) and step == 0 and self.cmd_step > 0:
            log.info("odometry restarted at step 0: new episode, clearing the planner")
            self.reset_episode()
        if isinstance(msg, (OdometryMsg, ScanMsg)):
            self.last_input_s = received_s
        if self.ctx.lockstep and self.resend_if_retry(topic, step):
            return
        if isinstance(msg, MapMsg):
            self.maps[step] = msg
        elif isinstance(msg, OdometryMsg):
            self.odoms[step] = (msg, received_s)
        elif isinstance(msg, ScanMsg):
            self.scans[step] = (msg, received_s)
        elif isinstance(msg, FrontiersMsg):
            if msg.decide:
                self.frontiers[step] = msg
        elif isinstance(msg, GoalMsg):
            self.goals[step] = msg
        self.progress()

    def resend_if_retry(self, topic: str, step: int) -> bool:
        """A lockstep retry re-sends inputs of a step already handled: answer again, do not redo it."""
        if topic == "map" and step <= self.map_step:
            if step == self.map_step and "map" in self.last_feedback:
                self.publish("planner_feedback", self.last_feedback["map"])
            return True
        if topic == "goal" and step <= self.cmd_step:
            if step == self.cmd_step and self.last_cmd is not None:
                self.publish("cmd_vel", self.last_cmd)
            return True
        return False

    def progress(self) -> None:
        """Lockstep: map phase of step k, then command phase of step k, strictly in order. Real time:
        the newest step whose inputs are complete (older ones are dropped)."""
        lock = self.ctx.lockstep
        while True:
            if lock:
                # A fresh (or restarted) planner joins at the first step it has both inputs for.
                k = self.map_step + 1 if self.map_step >= 0 else min((s for s in self.maps if s in self.odoms), default=-1)
                map_ready = self.map_step == self.cmd_step and k in self.maps and k in self.odoms
            else:
                k = max((s for s in self.maps if s in self.odoms and s > self.map_step), default=-1)
                map_ready = k >= 0
            if map_ready:
                self.on_map(k)
                continue
            if lock:
                cands = [self.map_step] if self.cmd_step < self.map_step else []
            else:
                cands = sorted(s for s in self.goals if s > self.cmd_step)[-1:]
            ready = [
                s
                for s in cands
                if s in self.goals and s in self.odoms and s in self.scans and not (self.goals[s].decided and self.goals[s].has_goal and s not in self.frontiers)
            ]
            if not ready:
                return
            self.on_goal(ready[0])

    def on_map(self, k: int) -> None:
        m, (odom, _) = self.maps.pop(k), self.odoms[k]
        for s in [s for s in self.maps if s < k]:
            self.maps.pop(s)
        for d in (self.odoms, self.scans, self.goals, self.frontiers):
            for s in [s for s in d if s < k - 20]:
                d.pop(s)
        occupancy = OccupancyMap.from_occupancy_grid(m.grid, m.geometry)
        self.planner.check_blocked(occupancy.occupied, occupancy.geometry, odom.pose)
        fb = PlannerFeedbackMsg(k, self.planner.status.value, "map", self.set_goal_blocked)
        self.set_goal_blocked = False
        self.map_step = self.last_step = k
        self.last_feedback["map"] = fb
        self.publish("planner_feedback", fb)

    def on_goal(self, k: int) -> None:
        g = self.goals.pop(k)
        (odom, odom_s), (scan, scan_s) = self.odoms.pop(k), self.scans.pop(k)
        frontiers = self.frontiers.pop(k, None)
        for d in (self.goals, self.odoms, self.scans, self.frontiers):
            for s in [s for s in d if s < k]:
                d.pop(s)
        self.cmd_step = k
        reason = ""
        if g.decided and not g.has_goal:
            self.planner.clear()
            cmd, reason = VelocityCommand(), "no_frontier"
        else:
            if g.decided and frontiers is not None:
                status = self.planner.set_goal(
                    frontiers.arrays["traversable"], frontiers.geometry, frontiers.pose, np.array([g.x_m, g.y_m]), frontiers.arrays["distance_m"]
                )
                self.set_goal_blocked = status == PlannerStatus.BLOCKED
            age_s = time.monotonic() - min(odom_s, scan_s)
            if age_s > self.params.stale_after_s:
                cmd, reason = VelocityCommand(), f"stale: inputs of step {k} are {age_s:.1f} s old"
                self.set_state("stale", reason)
            else:
                result = self.planner.update(odom.pose, odom.stamp_s, scan.scan)
                cmd = result.command
                if result.status != PlannerStatus.FOLLOWING:
                    reason = result.status.value
                self.set_state("running")
        self.stopped_for_stale = False
        self.publish("path", PathMsg(k, self.planner.remaining_path()))
        self.last_cmd = CmdVelMsg(k, cmd, reason)
        self.publish("cmd_vel", self.last_cmd)
        fb = PlannerFeedbackMsg(k, self.planner.status.value, "command", self.set_goal_blocked, reason)
        self.last_feedback["command"] = fb
        self.publish("planner_feedback", fb)

    def on_tick(self, now_s: float) -> None:
        age_s = now_s - self.last_input_s
        if age_s > self.params.stale_after_s and not self.stopped_for_stale and self.cmd_step >= 0:
            reason = f"stale: no odometry/scan for {age_s:.1f} s"
            self.set_state("stale", reason)
            self.publish("cmd_vel", CmdVelMsg(self.cmd_step, VelocityCommand(), reason))
            self.stopped_for_stale = True


def main(argv: list[str] | None = None) -> int:
    return service_main(PlannerService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
