"""The services' step logic without Zenoh: messages go straight into ``on_message``, publications are
captured. The wiring over Zenoh is covered by tests/test_runtime.py; these pin down the rules of the
real-time and lockstep paths that an end-to-end run would only show by chance."""

from __future__ import annotations

import queue
import time

import numpy as np

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import Explorer
from cso_runtime.messages import (
    CmdVelMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    OdometryMsg,
    PlannerFeedbackMsg,
    ScanMsg,
    decode,
    encode,
    frontiers_from_observation,
)
from cso_runtime.planner import LocalPlanner, path_blocked_ahead
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.transport import TransportConfig
from services.common import Service, ServiceContext
from services.frontier import FrontierService
from services.planner import PlannerService
from tests.conftest import two_rooms


def _service(cls: type[Service], lockstep: bool, params: dict | None = None) -> tuple[Service, list[tuple[str, Message]]]:
    ctx = ServiceContext(cls.name, "r0", {"lockstep": lockstep}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), params or {})
    svc = cls(ctx)
    out: list[tuple[str, Message]] = []
    svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(msg), type(msg))))  # type: ignore[method-assign]
    svc._inbox = queue.Queue()
    return svc, out


def _feed(svc: Service, msg: Message) -> None:
    """As the service loop does: decoded from the wire, then handled."""
    topic = {MapMsg: "map", OdometryMsg: "odom", ScanMsg: "scan", FrontiersMsg: "frontiers", GoalMsg: "goal", PlannerFeedbackMsg: "planner_feedback"}[type(msg)]
    svc.on_message("r0", topic, decode(encode(msg), type(msg)), time.monotonic())


def _explorer_at(steps: int) -> Explorer:
    ex = Explorer(KinematicSimulator(two_rooms(), seed=0))
    ex.reset(0)
    for _ in range(steps):
        ex.advance()
    return ex


def _inputs(ex: Explorer, step: int) -> tuple[MapMsg, OdometryMsg, ScanMsg]:
    m = MapMsg(step, ex.map.geometry, ex.map.to_occupancy_grid())
    odom = OdometryMsg(step, ex.sim.time_s, ex.sim.odometry())
    return m, odom, ScanMsg(step, ex.last_scan, ex.sim.sensor_pose())


def _far_goal(obs, step: int) -> GoalMsg:
    """A decided goal at the farthest reachable frontier: a path of many points."""
    far = max((c for c in obs.clusters if np.isfinite(c.distance_m)), key=lambda c: c.distance_m)
    return GoalMsg(step, True, far.goal_xy_m[0], far.goal_xy_m[1], far.cluster_id, far.distance_m, 1.0, "greedy-dist")


def test_blocked_check_on_the_reported_path_is_the_planners_own():
    """The frontier service runs ``path_blocked_ahead`` on the path the planner reports: same verdict as
    ``LocalPlanner.check_blocked`` when an obstacle appears on the path, and when it does not."""
    ex = _explorer_at(0)
    obs = ex.observe()
    far = max((c for c in obs.clusters if np.isfinite(c.distance_m)), key=lambda c: c.distance_m)
    planner = LocalPlanner()
    planner.set_goal(obs.traversable, obs.geometry, obs.pose, np.array(far.goal_xy_m), obs.distance_m)
    path = planner.remaining_path()
    assert len(path) > 10
    occupied = ex.map.occupied.copy()
    pose = ex.sim.odometry()
    assert not path_blocked_ahead(path, pose, occupied, ex.map.geometry, planner.robot.radius_m)
    assert not planner.check_blocked(occupied, ex.map.geometry, pose)
    iy, ix = ex.map.geometry.world_to_cell(path[len(path) // 2, 0], path[len(path) // 2, 1])
    occupied[int(iy), int(ix)] = True  # a wall mapped across the path, well ahead of the robot
    assert path_blocked_ahead(path, pose, occupied, ex.map.geometry, planner.robot.radius_m)
    assert planner.check_blocked(occupied, ex.map.geometry, pose)


def test_real_time_frontier_decides_on_the_newest_map_and_waits_for_the_goal():
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    ex = _explorer_at(0)
    m0, odom0, _ = _inputs(ex, 0)
    m1, odom1, _ = _inputs(ex, 1)
    frontier._inbox.put("newer input")  # a backlog: nothing is decided while newer inputs wait
    for msg in (odom0, m0, odom1, m1):
        _feed(frontier, msg)
    assert out == []
    frontier._inbox.get()
    _feed(frontier, m1)  # the last queued input: decide now, on the newest map
    assert [(t, m.step, m.decide) for t, m in out] == [("frontiers", 1, True)]
    m2, odom2, _ = _inputs(ex, 2)
    _feed(frontier, odom2)
    _feed(frontier, m2)  # the goal of step 1 is not in yet: keep the current goal, do not ask again
    assert [(m.step, m.decide) for _, m in out[1:]] == [(2, False)]
    obs = ex.observe()
    _feed(frontier, _far_goal(obs, 1))
    # Reports about the previous goal (none yet): one late, one on a step after the decision, sent
    # before the new goal reached the planner. Neither is the new goal's outcome.
    _feed(frontier, PlannerFeedbackMsg(0, "reached", "command", goal_step=-1))
    _feed(frontier, PlannerFeedbackMsg(2, "reached", "command", goal_step=-1))
    m3, odom3, _ = _inputs(ex, 3)
    _feed(frontier, odom3)
    _feed(frontier, m3)  # the planner is on its way to the new goal: nothing to decide
    assert [(m.step, m.decide) for _, m in out[2:]] == [(3, False)]
    _feed(frontier, PlannerFeedbackMsg(3, "reached", "command", goal_step=1))  # the new goal reached: decide again
    m4, odom4, _ = _inputs(ex, 4)
    _feed(frontier, odom4)
    _feed(frontier, m4)
    assert [(m.step, m.decide, m.reason) for _, m in out[3:]] == [(4, True, "reached")]


def test_real_time_planner_plans_a_goal_that_arrives_after_newer_odometry():
    """In real time the planner is a controller loop: it commands each new odometry + scan pair at once
    and plans to a decided goal whenever it arrives, even when newer steps were commanded meanwhile."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    frontiers = frontiers_from_observation(0, "no_goal", obs, 1.0)
    for step in range(3):
        _, odom, scan = _inputs(ex, 0)
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose))
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose))
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [c.step for c in cmds] == [0, 1, 2] and all(c.reason == "idle" for c in cmds)  # no goal yet: stopped
    _feed(planner, frontiers)
    _feed(planner, _far_goal(obs, 0))
    assert planner.planner.status.value == "following" and len(planner.planner.remaining_path()) > 1
    _, odom, scan = _inputs(ex, 0)
    _feed(planner, OdometryMsg(3, odom.stamp_s + 0.75, odom.pose))
    _feed(planner, ScanMsg(3, scan.scan, scan.sensor_pose))
    last = [m for t, m in out if t == "cmd_vel"][-1]
    assert isinstance(last, CmdVelMsg) and last.step == 3 and last.new_goal and last.reason == ""
    assert last.command.linear_mps != 0.0 or last.command.angular_radps != 0.0
    fb = [m for t, m in out if t == "planner_feedback"][-1]
    assert fb.status == "following" and len(fb.path_ahead_xy_m) > 1 and fb.goal_step == 0


def test_lockstep_planner_keeps_the_goal_without_the_policy_and_waits_for_a_decision():
    planner, out = _service(PlannerService, lockstep=True)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    _feed(planner, odom)
    _feed(planner, scan)
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    assert not [m for t, m in out if t == "cmd_vel"]  # a decision is due: wait for the policy's goal
    _feed(planner, _far_goal(obs, 0))
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [(c.step, c.new_goal) for c in cmds] == [(0, True)]
    _feed(planner, OdometryMsg(1, odom.stamp_s + 0.25, odom.pose))
    _feed(planner, ScanMsg(1, scan.scan, scan.sensor_pose))
    _feed(planner, FrontiersMsg(1, False))  # keep the goal: commanded with no goal message at all
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [(c.step, c.new_goal) for c in cmds] == [(0, True), (1, False)]
    _feed(planner, FrontiersMsg(1, False))  # a lockstep retry: the same command again, not a new step
    assert [m.step for t, m in out if t == "cmd_vel"] == [0, 1, 1] and planner.cmd_step == 1
