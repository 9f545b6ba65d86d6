"""The services' step logic without Zenoh: messages go straight into ``on_message``, publications are
captured. The wiring over Zenoh is covered by tests/test_runtime.py; these pin down the rules of the
real-time and lockstep paths that an end-to-end run would only show by chance."""

from __future__ import annotations

import dataclasses
import math
import queue
import re
import subprocess
import sys
import threading
import time
import types
import weakref
from pathlib import Path

import numpy as np
import pytest

from cso_runtime.config import ExplorationConfig, MaskConfig, SensorConfig
from cso_runtime.episode import Explorer
from cso_runtime.geometry import Pose2D, VelocityCommand
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import (
    ClockMsg,
    CmdVelMsg,
    DistanceMapMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    OdometryMsg,
    PlannerContactsMsg,
    PlannerFeedbackMsg,
    PlannerPlanMsg,
    PlannerStateMsg,
    ScanMsg,
    decode,
    encode,
    frontiers_from_observation,
    observation_from_frontiers,
)
from cso_runtime.planner import LocalPlanner, PlannerStatus, path_blocked_ahead
from cso_runtime.policies import make_policy
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.transport import TransportConfig
from services.common import Service, ServiceContext, ServiceInputs
from services.frontier import FrontierService
from services.planner import PlannerService
from services.policy import PolicyService
from tests.conftest import HANG_DEADLINE_S, two_rooms


def _service(
    cls: type[Service], lockstep: bool, params: dict | None = None, exploration: ExplorationConfig | None = None
) -> tuple[Service, list[tuple[str, Message]]]:
    ctx = ServiceContext(cls.name, "r0", {"lockstep": lockstep}, exploration or ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), params or {})
    svc = cls(ctx)
    out: list[tuple[str, Message]] = []
    # As ``publish`` does, minus Zenoh: only declared outputs go out, and they go out through the codec.
    svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(svc.check_output(topic, msg)), type(msg))))  # type: ignore[method-assign]
    svc._inbox = queue.SimpleQueue()
    return svc, out


def _feed(svc: Service, msg: Message) -> None:
    """As the service loop does: decoded from the wire, then handled."""
    topics = {
        MapMsg: "map", OdometryMsg: "odom", ScanMsg: "scan", FrontiersMsg: "frontiers", DistanceMapMsg: "distance_map", GoalMsg: "goal",
        PlannerFeedbackMsg: "planner_feedback", ExploreResumeMsg: "explore_resume", EpisodeStatusMsg: "episode_status",
        PlannerContactsMsg: "planner_contacts", CmdVelMsg: "cmd_vel",
    }  # fmt: skip
    topic = topics[type(msg)]
    svc.on_message("r0", topic, decode(encode(msg), type(msg)), time.monotonic())


def _explorer_at(steps: int) -> Explorer:
    ex = Explorer(KinematicSimulator(two_rooms(), seed=0))
    ex.reset(0)
    for _ in range(steps):
        ex.advance()
    return ex


def _inputs(ex: Explorer, step: int) -> tuple[MapMsg, OdometryMsg, ScanMsg]:
    m = MapMsg.of(step, ex.map)
    odom = OdometryMsg(step, ex.sim.time_s, ex.sim.odometry())
    return m, odom, ScanMsg(step, ex.last_scan, ex.sim.sensor_pose())


def _far_goal(obs, step: int) -> GoalMsg:
    """A decided goal at the farthest reachable frontier: a path of many points."""
    far = max((c for c in obs.clusters if np.isfinite(c.distance_m)), key=lambda c: c.distance_m)
    return GoalMsg(step, True, far.goal_xy_m[0], far.goal_xy_m[1], far.cluster_id, far.distance_m, 1.0, "greedy-dist")


def _odometry_and_scan(svc: Service, odom: OdometryMsg, scan: ScanMsg, step: int) -> None:
    """A robot's odometry and scan of ``step``, a quarter second a step after ``odom``'s (a real-time planner commands each pair)."""
    _feed(svc, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose))
    _feed(svc, ScanMsg(step, scan.scan, scan.sensor_pose))

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
    assert [(t, m.step) for t, m in out] == [("frontiers", 1), ("distance_map", 1)]  # D right after the decision
    assert out[0][1].decide and out[0][1].pose == odom1.pose == out[1][1].pose
    np.testing.assert_array_equal(out[1][1].distance_m, ex.builder.build(m1.occupancy(), odom1.pose).distance_m)
    del out[1]
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
    assert [(t, m.step, getattr(m, "decide", None), getattr(m, "reason", None)) for t, m in out[3:]] == [("frontiers", 4, True, "reached"), ("distance_map", 4, None, None)]


def test_policy_service_loads_the_weights_trained_with_its_sensor(tmp_path, monkeypatch):
    """The policy service of a profile with the LIMO's 180-degree LiDAR serves ``cso@fov180.pt``; with a
    360-degree LiDAR, ``cso.pt`` (the same rule as eval, ``weights.weights_path``)."""
    import torch

    from cso_runtime.learned.graph import GraphConfig
    from cso_runtime.learned.network import GraphActorCritic
    from cso_runtime.learned.registry import WEIGHTS_DIR_ENV, save_checkpoint
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)  # a CSO_WEIGHTS_FILE of the developer's would take cso's place
    torch.manual_seed(5)
    wide, narrow = GraphActorCritic().eval(), GraphActorCritic().eval()
    save_checkpoint(tmp_path / "cso.pt", wide, GraphConfig(), "cso")
    save_checkpoint(tmp_path / "cso@fov180.pt", narrow, GraphConfig(), "cso")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path))
    for sensor, expected in ((SensorConfig(), narrow), (SensorConfig.preset("lidar", 360), wide)):
        policy, _ = _service(PolicyService, lockstep=True, params={"method": "cso"}, exploration=ExplorationConfig(sensor=sensor))
        served = policy.new_selector().model.state_dict()
        for name, value in expected.state_dict().items():
            torch.testing.assert_close(served[name], value)


def test_policy_service_refuses_a_weights_file_it_would_not_run_naming_the_path_given(tmp_path, monkeypatch):
    """``CSO_WEIGHTS_FILE`` naming a file that is not there, or another method's file, made the policy service run the
    shipped weights without a word (or say "no weights for 'cso'" with a hint to train). It now refuses at its start,
    before it joins the network (exit 2), naming the path exactly as given, as eval and up do."""
    import shutil

    from cso_runtime.config import ConfigError
    from cso_runtime.learned.weights import WEIGHTS_FILE_ENV, weights_path
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    other = tmp_path / "cso-sm.pt"
    shutil.copy(weights_path("cso-sm"), other)
    for given, said in (
        (tmp_path / "nope" / "cso.pt", f"{WEIGHTS_FILE_ENV}={tmp_path / 'nope' / 'cso.pt'}: no such file"),
        (tmp_path / "nope" / "model.pt", f"{WEIGHTS_FILE_ENV}={tmp_path / 'nope' / 'model.pt'}: no such file"),
        (other, f"--weights {other}: the weights of cso-sm alone, not of cso"),
    ):
        monkeypatch.setenv(WEIGHTS_FILE_ENV, str(given))
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}"):
            _service(PolicyService, lockstep=True, params={"method": "cso"})
    monkeypatch.setenv(WEIGHTS_FILE_ENV, str(tmp_path / "nope" / "cso.pt"))
    policy, _ = _service(PolicyService, lockstep=True, params={"method": "greedy-dist"})  # no learned method: no weights read
    assert policy.method == "greedy-dist"


def test_policy_service_stuck_mask_uses_bounded_distance_maps_and_decides_like_in_process(monkeypatch):
    """Three decisions 0.1 m apart on one map: Algorithm 1 finds the robot stuck at the third and
    measures from the three decision positions, each with a fast-marching pass bounded by alpha_3.
    The service's goals are those of the same selector run in one process on the same Observations."""
    from cso_runtime import observation

    ex = _explorer_at(0)
    start = ex.sim.odometry()
    decisions, observations, nodes = [], [], []
    for step, dx in ((0, 0.0), (1, 0.1), (2, 0.2)):
        pose = Pose2D(start.x_m + dx, start.y_m, start.yaw_rad)
        nodes.append((pose.x_m, pose.y_m))
        observations.append(ex.builder.build(ex.map, pose, np.array(nodes)))
        decisions.append(frontiers_from_observation(step, "reached", observations[-1], 1.0))
    from cso_runtime.learned import registry

    monkeypatch.setattr(registry, "_DECISION_TRACES", weakref.WeakKeyDictionary())
    policy, out = _service(PolicyService, lockstep=True, params={"method": "cso"})
    policy.warm_up()  # as run_service does before the liveliness token
    assert any(registry._DECISION_TRACES.values()) and not out  # traced before any input; nothing published
    bounds = []
    real = observation.geodesic_distance
    monkeypatch.setattr(observation, "geodesic_distance", lambda *a: bounds.append(a[3]) or real(*a))
    for f in decisions:
        _feed(policy, f)
    assert policy.robots["r0"].selector.masker.stuck.is_stuck()
    assert bounds == [MaskConfig().alpha3_m] * 3  # and no unbounded pass: D at the path nodes travelled
    in_process = make_policy("cso", MaskConfig(), seed=0, sensor=SensorConfig())  # the service's sensor: the default
    expected = [in_process.select(obs) for obs in observations]
    assert [(m.step, m.x_m, m.y_m, m.cluster_index) for _, m in out] == [(f.step, g.x_m, g.y_m, g.cluster_index) for f, g in zip(decisions, expected)]


def test_a_policy_serving_two_robots_says_which_one_is_stale_without_flapping():
    """One policy server, two robots; robot a's episode ended (no more frontiers), robot b's goes on. The
    service stays "running" and says robot a is not commanded, however b's decisions and the ticks
    interleave; "stale" once neither robot sends anything. The count is of the robots it has heard from, and says
    so: "serving 1 of 2 robots" with a third robot's run up (started, no input yet) read as an off-by-one."""
    from types import SimpleNamespace

    policy, out = _service(PolicyService, lockstep=False, params={"method": "greedy-dist", "stale_after_s": 2.0, "serve_all_robots": True})
    policy._on_alive(SimpleNamespace(key_expr="cso/c/alive/frontier", kind="SampleKind.PUT"))  # robot c's run is up, silent so far
    obs = _explorer_at(0).observe()
    now = time.monotonic()
    policy.on_message("a", "frontiers", frontiers_from_observation(0, "no_goal", obs, 1.0), now)
    states = []
    for step in range(1, 6):
        at_s = now + 3.0 + step * 0.1  # robot a: silent for more than stale_after_s by then
        policy.on_message("b", "frontiers", frontiers_from_observation(step, "timeout", obs, 1.0), at_s)
        policy.on_tick(at_s)
        states.append((policy.state, policy.reason.split(";")[0]))
    assert states[1:] == [("running", "commanding 1 of the 2 robots it has heard from")] * 4, states
    assert "robot a: no frontiers for" in policy.reason and [m.step for t, m in out if t == "goal"][-1] == 5
    policy.on_tick(now + 60.0)
    assert policy.state == "stale" and "robot a" in policy.reason and "robot b" in policy.reason


def test_a_step_that_leaps_far_ahead_is_held_back_until_the_next_one_confirms_it():
    """A stray message many steps ahead would become a service's newest step, after which every real one
    looks old (the policy stopped answering, the mapper dropped every scan): rejected, counted, and the
    episode goes on; a real leap (a service cut off for a while) is taken at the message after it."""
    from services.common import STEP_JUMP_LIMIT, StepGuard, _dispatch

    guard = StepGuard(limit=100)
    assert [guard.check(("r0", "scan"), s) == "" for s in (0, 1, 2, 1000, 3, 4, 0)] == [True, True, True, False, True, True, True]
    assert guard.check(("r0", "scan"), 500) and guard.check(("r0", "scan"), 503) == ""  # the leap, confirmed by the next step
    assert guard.check(("r0", "odom"), 10**6) != ""  # a first message on a key leaps from the robot's last step too
    assert guard.check(("r1", "odom"), 10**6) == ""  # another robot's first message is never a leap
    # A key only decisions use may be quiet for longer than the limit while the robot's other keys go on.
    assert guard.check(("r0", "goal"), 503) == ""
    assert all(guard.check(("r0", "scan"), s) == "" for s in range(504, 800, 50))
    assert guard.check(("r0", "goal"), 790) == "" and guard.check(("r0", "goal"), 790 + 101) != ""

    policy, out = _service(PolicyService, lockstep=True, params={"method": "greedy-dist"})
    obs = _explorer_at(0).observe()
    keys = RobotKeys("r0")
    for step in (1, 2, 2 + STEP_JUMP_LIMIT + 1, 3):
        _dispatch(policy, keys.frontiers, encode(frontiers_from_observation(step, "timeout", obs, 1.0)), time.monotonic())
    assert [m.step for t, m in out if t == "goal"] == [1, 2, 3]
    assert policy.rejected == {"frontiers": 1}


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


def test_a_paused_planner_commands_a_stop_plans_no_new_goal_and_resumes_on_its_goal():
    """``explore/resume`` false (an operator's pause): every command is a stop at once and on each new scan, a goal
    decided meanwhile is not planned; true: the robot moves on toward the goal it had (the same path). Lockstep
    refuses a pause (its sim waits for each command)."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)

    def command(step: int) -> CmdVelMsg:
        _odometry_and_scan(planner, odom, scan, step)
        cmd = [m for t, m in out if t == "cmd_vel"][-1]
        assert isinstance(cmd, CmdVelMsg) and cmd.step == step
        return cmd

    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    goal = _far_goal(obs, 0)
    _feed(planner, goal)
    moving = command(0)
    assert moving.command != VelocityCommand()
    path = planner.planner.path  # to the goal, its last point
    _feed(planner, ExploreResumeMsg(False, "alice@lab", "inspecting"))
    assert out[-1] == ("cmd_vel", CmdVelMsg(0, VelocityCommand(), "paused: by alice@lab"))  # at once, not at the next scan
    assert planner.state == "running" and planner.reason == "paused: by alice@lab"
    _feed(planner, frontiers_from_observation(1, "timeout", obs, 1.0))  # a decision made while paused
    other = sorted((c for c in obs.clusters if np.isfinite(c.distance_m)), key=lambda c: c.distance_m)[-2]
    _feed(planner, GoalMsg(1, True, other.goal_xy_m[0], other.goal_xy_m[1], other.cluster_id, other.distance_m, 1.0, "greedy-dist"))
    for step in (1, 2, 3):
        cmd = command(step)
        assert cmd.command == VelocityCommand() and cmd.reason == "paused: by alice@lab"
    assert planner.planner.path is path and planner.goal_step == 0
    fb = [m for t, m in out if t == "planner_feedback"][-1]
    assert fb.status == "following" and fb.goal_step == 0  # the frontier service keeps the goal
    _feed(planner, ExploreResumeMsg(False, "alice@lab"))  # a second pause changes nothing
    _feed(planner, ExploreResumeMsg(True, "alice@lab"))
    assert planner.state == "running" and planner.reason == "" and planner.goal_step == 1  # the decision made while paused is the newest
    resumed = command(4)
    assert resumed.command != VelocityCommand() and resumed.reason == "" and resumed.new_goal

    lockstep, lockstep_out = _service(PlannerService, lockstep=True)
    _feed(lockstep, ExploreResumeMsg(False, "bob"))
    assert lockstep.paused is None and lockstep_out == []



def test_after_the_episode_ends_no_frontier_the_real_time_planner_sends_one_stop_not_one_per_scan():
    """On a real robot (``limo-ros2``) the scans go on after the episode ended ``no_frontier``, and the planner sent a stop
    on every one of them (about 10 a second until ``down``), each forwarded by the bridge to the robot's ``cmd_vel``
    over its WiFi. One stop is enough: it is the robot's last command (the bridge also sends its zero Twist at the
    end, and any later command as a zero one). The feedback still goes out each step; a goal again (a stray end) is followed
    again. Lockstep is as before: its sim waits for every step's command."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)

    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    _feed(planner, GoalMsg(0, True, method="greedy-dist"))  # no frontier left: the episode ends
    for step in range(5):
        _odometry_and_scan(planner, odom, scan, step)
    assert [(m.step, m.command, m.reason) for t, m in out if t == "cmd_vel"] == [(0, VelocityCommand(), "no_frontier")]
    assert [m.step for t, m in out if t == "planner_feedback"] == [0, 1, 2, 3, 4]
    _feed(planner, frontiers_from_observation(5, "timeout", obs, 1.0))
    _feed(planner, _far_goal(obs, 5))
    out.clear()
    _odometry_and_scan(planner, odom, scan, 5)
    (moving,) = [m for t, m in out if t == "cmd_vel"]
    assert moving.step == 5 and moving.command != VelocityCommand() and moving.new_goal

def test_a_paused_planner_without_a_newer_decision_resumes_on_the_goal_it_had():
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    _feed(planner, _far_goal(obs, 0))
    _feed(planner, ExploreResumeMsg(False))
    _feed(planner, odom)
    _feed(planner, scan)
    assert [m for t, m in out if t == "cmd_vel"][-1].reason == "paused"
    path = planner.planner.path  # to the goal, its last point
    _feed(planner, ExploreResumeMsg(True))
    _feed(planner, OdometryMsg(1, odom.stamp_s + 0.25, odom.pose))
    _feed(planner, ScanMsg(1, scan.scan, scan.sensor_pose))
    cmd = [m for t, m in out if t == "cmd_vel"][-1]
    assert cmd.step == 1 and cmd.command != VelocityCommand() and not cmd.new_goal
    assert planner.planner.path is path and planner.goal_step == 0


def test_the_same_reason_for_no_goal_is_logged_once_not_at_every_scan(caplog):
    """On a real robot the steps go on after the episode ended ``no_frontier`` (the LiDAR keeps scanning, and a detached
    run stays up for ``save-map``): the frontier service decides on every scan and logged its long "no goal at step N:
    ..." line each time, 8 a second (seen on the fake LIMO: one per scan until ``down``). The reason goes to the referee
    every time still (``ended_why``), but the log says it once, and again when it changes or after a goal."""
    frontier, out = _service(FrontierService, lockstep=False)
    ex = _explorer_at(0)
    frontier.asked = (ex.observe(), np.zeros(ex.map.geometry.shape, dtype=bool))
    with caplog.at_level("INFO", logger="cso.frontier"):
        for step in range(5, 9):
            frontier.say_why_no_goal(step)
    assert [m.step for t, m in out if t == "ended_why"] == [5, 6, 7, 8]
    assert caplog.text.count("no goal at step") == 1 and "no goal at step 5" in caplog.text, caplog.text
    frontier.asked_step = 9
    _feed(frontier, _far_goal(ex.observe(), 9))  # a goal again: a later "no goal" is news
    with caplog.at_level("INFO", logger="cso.frontier"):
        frontier.say_why_no_goal(12)
    assert caplog.text.count("no goal at step") == 2 and "no goal at step 12" in caplog.text, caplog.text


def test_once_the_episode_is_over_the_frontier_service_asks_for_no_decision_until_a_new_one(caplog):
    """A real robot's scans go on after its episode ended (a detached run stays up until ``down``): the frontier service
    asked the policy for a decision on every scan (the goal stayed empty: ``no_goal``), and the bridge sent each one's
    frontiers to RViz over the robot's WiFi (295 MarkerArrays against 81 maps in one run). Once the answer to its
    decision is empty (the end ``no_frontier``), or the referee's status says done or failed, it asks for none (no
    Observation, no distance map: ``decide: false``, counted as ``steps_after_episode``, logged once) until a new
    episode; the reason why the goal is empty still goes out (``ended_why``)."""
    ex = _explorer_at(0)
    _, odom, _ = _inputs(ex, 0)
    a, b = 11, 22

    def scan(svc: FrontierService, out: list, step: int, episode: int) -> FrontiersMsg:
        _feed(svc, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose, episode=episode))
        _feed(svc, MapMsg.of(step, ex.map, episode))
        f = [msg for t, msg in out if t == "frontiers"][-1]
        assert isinstance(f, FrontiersMsg) and f.step == step
        return f

    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    assert scan(frontier, out, 0, a).decide
    with caplog.at_level("INFO", logger="cso.frontier"):
        _feed(frontier, GoalMsg(0, True, method="greedy-dist", episode=a))  # no frontier left: the episode ends
        assert [(m.step, m.episode) for t, m in out if t == "ended_why"] == [(0, a)]  # the referee's reason
        _feed(frontier, EpisodeStatusMsg("exploring", 0, episode=a))  # the bridge's, sent before it heard the end
        out.clear()
        assert not any(scan(frontier, out, step, a).decide for step in range(1, 6))
    assert [t for t, _ in out] == ["frontiers"] * 5 and frontier.decisions_built == 1  # no Observation, no D
    assert frontier.status_msg().counters["steps_after_episode"] == 5
    assert caplog.text.count("no more decisions until a new episode") == 1, caplog.text
    assert scan(frontier, out, 0, b).decide  # a new episode (the robot's odometry or clock started again)

    # A ros2_bridge's status comes with each map: one that waited behind a map (real time decides on the newest input)
    # does not leave that map undecided until the next.
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    frontier._inbox.put("the status")
    _feed(frontier, OdometryMsg(0, odom.stamp_s, odom.pose, episode=a))
    _feed(frontier, MapMsg.of(0, ex.map, a))
    assert out == []
    frontier._inbox.get()
    _feed(frontier, EpisodeStatusMsg("exploring", 0, episode=a))
    assert [(t, m.step) for t, m in out] == [("frontiers", 0), ("distance_map", 0)]

    # The referee's end (max_steps here; coverage, a failure), by its status: the periodic re-decision is not asked.
    every = 3
    base = ExplorationConfig()
    cfg = dataclasses.replace(base, episode=dataclasses.replace(base.episode, replan_every_steps=every))
    ended, ended_out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0}, exploration=cfg)
    going, going_out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0}, exploration=cfg)
    for svc, svc_out in ((ended, ended_out), (going, going_out)):
        assert scan(svc, svc_out, 0, a).decide
        _feed(svc, dataclasses.replace(_far_goal(ex.observe(), 0), episode=a))
        _feed(svc, EpisodeStatusMsg("exploring", 1, episode=a))  # not over
    _feed(ended, EpisodeStatusMsg("done", 1, terminated_by="max_steps", episode=a))
    assert [scan(going, going_out, step, a).decide for step in range(1, every + 2)] == [False, False, True, False]
    assert not any(scan(ended, ended_out, step, a).decide for step in range(1, every + 2))
    assert ended.status_msg().counters["steps_after_episode"] == every + 1
    # A status saying the episode goes on after its end shows that end stray or forged (the launcher ignores it too).
    _feed(ended, EpisodeStatusMsg("exploring", every + 2, episode=a))
    assert scan(ended, ended_out, every + 2, a).decide
    # Lockstep: the sim steps no more after the end, and the frontier service goes on as it always did.
    lockstep, lockstep_out = _service(FrontierService, lockstep=True)
    _feed(lockstep, EpisodeStatusMsg("done", 0, terminated_by="coverage", episode=a))
    assert scan(lockstep, lockstep_out, 0, a).decide and not lockstep.episode_over

    assert scan(ended, ended_out, 0, b).decide
    _feed(ended, EpisodeStatusMsg("done", 9, terminated_by="max_steps", episode=a))  # late, of the episode before
    assert ended.rejected == {"episode_status": 1}
    scan(ended, ended_out, 1, b)  # waits for the goal of step 0, and is no step after the end
    assert ended.status_msg().counters["steps_after_episode"] == every + 1


def test_a_paused_frontier_service_asks_for_no_decision_and_counts_no_paused_step():
    """Paused (``explore/resume`` false), the frontier service asks the policy for no decision however many scans come,
    and the paused steps do not count towards the periodic re-decision (``replan_every_steps``): resumed, it asks once
    the steps explored since the goal's decision reach it. A service started while paused learns it from the launcher
    (``pause_in_force``); lockstep ignores a pause (as the planner does)."""
    every = 4
    base = ExplorationConfig()
    cfg = dataclasses.replace(base, episode=dataclasses.replace(base.episode, replan_every_steps=every))
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0}, exploration=cfg)
    ex = _explorer_at(0)
    _, odom, _ = _inputs(ex, 0)

    def scan(step: int) -> FrontiersMsg:
        _feed(frontier, dataclasses.replace(odom, step=step))
        _feed(frontier, MapMsg.of(step, ex.map))  # the same map: the goal stays a frontier, only the count can end it
        f = [msg for t, msg in out if t == "frontiers"][-1]
        assert isinstance(f, FrontiersMsg) and f.step == step
        return f

    assert scan(0).decide
    _feed(frontier, _far_goal(ex.observe(), 0))
    assert not scan(1).decide
    _feed(frontier, ExploreResumeMsg(False, "alice@lab", "inspecting"))
    assert frontier.reason == "paused: by alice@lab"
    assert not any(scan(step).decide for step in range(2, 3 + 2 * every))  # more than replan_every_steps scans
    _feed(frontier, ExploreResumeMsg(True, "alice@lab"))
    assert frontier.reason == ""
    resumed = [scan(step) for step in range(3 + 2 * every, 3 + 2 * every + every - 1)]
    assert [f.decide for f in resumed] == [False, False, True]  # steps 1 and these three: the fourth explored since
    assert resumed[-1].reason == "timeout"

    started, _ = _service(FrontierService, lockstep=False)
    asked: list[str] = []
    started.query_latest = lambda key, expected: asked.append(key) or ExploreResumeMsg(False, "bob")  # type: ignore[method-assign]
    started.start()
    assert started.paused and asked == [RobotKeys("r0").cache("explore_resume")]
    lockstep, lockstep_out = _service(FrontierService, lockstep=True)
    lockstep.query_latest = lambda key, expected: ExploreResumeMsg(False, "bob")  # type: ignore[method-assign]
    lockstep.start()
    _feed(lockstep, ExploreResumeMsg(False, "bob"))
    assert not lockstep.paused and lockstep_out == []


def test_the_planner_says_why_a_goal_has_no_path():
    """``blocked`` covered a goal off the map, one with no path, and a path cut later: the command's reason now
    names the first two (NoPath's message), which the status and the logs show."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    _feed(planner, GoalMsg(0, True, 1000.0, 1000.0, 0, 1.0))
    _feed(planner, odom)
    _feed(planner, scan)
    (cmd,) = [m for t, m in out if t == "cmd_vel"]
    assert cmd.reason == "blocked: goal is outside the map" and cmd.command == VelocityCommand()
    fb = [m for t, m in out if t == "planner_feedback"][-1]
    assert fb.status == "blocked" and fb.set_goal_blocked and fb.reason == cmd.reason


def test_real_time_planner_keeps_a_bounded_number_of_decisions_waiting_for_their_goal():
    """A policy that is down (or far behind) sends no goal: the decisions waiting for one are kept up to
    ``PENDING_DECISIONS_KEPT`` (the newest), not one per decision for as long as the episode runs."""
    from services.planner import PENDING_DECISIONS_KEPT

    planner, _ = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    for step in range(3 * PENDING_DECISIONS_KEPT):
        _feed(planner, frontiers_from_observation(step, "timeout", obs, 1.0))
    kept = sorted(planner.frontiers)  # the newest n, and at most n + n // 8 (``keep_newest``)
    assert kept[-PENDING_DECISIONS_KEPT:] == list(range(2 * PENDING_DECISIONS_KEPT, 3 * PENDING_DECISIONS_KEPT))
    assert PENDING_DECISIONS_KEPT <= len(kept) <= PENDING_DECISIONS_KEPT + PENDING_DECISIONS_KEPT // 8
    assert kept == list(range(kept[0], 3 * PENDING_DECISIONS_KEPT))
    _feed(planner, _far_goal(obs, 3 * PENDING_DECISIONS_KEPT - 1))  # the newest decision's goal is still planned
    assert planner.planner.status.value == "following"


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
    goal = _far_goal(obs, 0)
    in_process = LocalPlanner()
    in_process.set_goal(obs.traversable, obs.geometry, obs.pose, np.array([goal.x_m, goal.y_m]), obs.distance_m)
    np.testing.assert_array_equal(planner.planner.path, in_process.path)  # D never arrived: its own pass, the same path
    _feed(planner, OdometryMsg(1, odom.stamp_s + 0.25, odom.pose))
    _feed(planner, ScanMsg(1, scan.scan, scan.sensor_pose))
    _feed(planner, FrontiersMsg(1, False))  # keep the goal: commanded with no goal message at all
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [(c.step, c.new_goal) for c in cmds] == [(0, True), (1, False)]
    _feed(planner, FrontiersMsg(1, False))  # a lockstep retry: the same command again, not a new step
    assert [m.step for t, m in out if t == "cmd_vel"] == [0, 1, 1] and planner.cmd_step == 1


def test_lockstep_planner_commands_a_step_whose_decision_took_longer_than_stale_after_s():
    """Lockstep: a decision slower than ``stale_after_s`` used to get a stale stop, which the sim drops; each of
    its retries got the same stop and the episode failed. The sim holds the robot, so the step is commanded."""
    planner, out = _service(PlannerService, lockstep=True, params={"stale_after_s": 2.0})
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    long_ago_s = time.monotonic() - 3.0
    planner.on_message("r0", "odom", odom, long_ago_s)
    planner.on_message("r0", "scan", scan, long_ago_s)
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    _feed(planner, _far_goal(obs, 0))
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [c.step for c in cmds] == [0] and not cmds[0].reason.startswith("stale")
    assert cmds[0].command != VelocityCommand() and planner.state != "stale"
    real_time, out_rt = _service(PlannerService, lockstep=False, params={"stale_after_s": 2.0})  # a real robot moves on
    real_time.on_message("r0", "odom", odom, long_ago_s)
    real_time.on_message("r0", "scan", scan, long_ago_s)
    assert [m.reason[:5] for t, m in out_rt if t == "cmd_vel"] == ["stale"]


def _real_time_planner_with_a_goal(stale_after_s: float) -> tuple[PlannerService, list, OdometryMsg, ScanMsg, float]:
    """A real-time planner given step 0's odometry and scan at ``t0`` (now), then a far goal: (planner, its output,
    that odometry, that scan, t0)."""
    planner, out = _service(PlannerService, lockstep=False, params={"stale_after_s": stale_after_s})
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    t0 = time.monotonic()
    planner.on_message("r0", "odom", odom, t0)
    planner.on_message("r0", "scan", scan, t0)
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0))
    _feed(planner, _far_goal(obs, 0))
    return planner, out, odom, scan, t0


def test_real_time_planner_says_which_input_went_silent_and_does_not_blame_the_goal_for_the_wait():
    """Odometry alone kept the planner "running" with no scan for as long as it liked (each input refreshed one
    clock); and a stop for stale inputs longer than the progress window then ended the goal no_progress."""
    planner, out, odom, scan, t0 = _real_time_planner_with_a_goal(stale_after_s=2.0)
    planner.on_message("r0", "odom", OdometryMsg(1, odom.stamp_s + 0.25, odom.pose), t0)
    planner.on_message("r0", "scan", ScanMsg(1, scan.scan, scan.sensor_pose), t0)
    assert planner.planner.status.value == "following"
    for step in range(2, 14):  # odometry goes on for 3 s, the scans have stopped
        planner.on_message("r0", "odom", OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose), t0 + 0.25 * step)
    planner.on_tick(t0 + 3.0)
    assert planner.state == "stale" and planner.reason == "stale: no scan for 3.0 s"
    assert [m.reason for t, m in out if t == "cmd_vel"][-1] == "stale: no scan for 3.0 s"
    stalled_s = odom.stamp_s + 20.0  # the scans come back after longer than progress_window_s (10 s), the robot where it was
    planner.on_message("r0", "odom", OdometryMsg(90, stalled_s, odom.pose), t0 + 20.0)
    planner.on_message("r0", "scan", ScanMsg(90, scan.scan, scan.sensor_pose), t0 + 20.0)
    last = [m for t, m in out if t == "cmd_vel"][-1]
    assert last.step == 90 and last.reason == "" and planner.planner.status.value == "following"


def test_real_time_planner_stopped_for_inputs_that_arrive_stale_does_not_blame_the_goal_for_the_wait():
    """A lagging link: odometry and scans go on coming, each older than ``stale_after_s`` as it arrives, and the
    planner stops the robot on every pair. Unlike a silence (``on_tick``), that stop did not start the progress and
    stall checks over: once fresh inputs came back after longer than the progress window, the robot standing where it
    was stopped, the first command was the progress recovery's (``escape``), and the next such wait ended the goal
    ``no_progress``."""
    planner, out, odom, scan, _ = _real_time_planner_with_a_goal(stale_after_s=2.0)
    planner.on_message("r0", "odom", OdometryMsg(1, odom.stamp_s + 0.25, odom.pose), time.monotonic())
    planner.on_message("r0", "scan", ScanMsg(1, scan.scan, scan.sensor_pose), time.monotonic())
    driving = [m for t, m in out if t == "cmd_vel"][-1]
    assert driving.step == 1 and driving.reason == "" and driving.command.linear_mps > 0
    for step in range(2, 50):  # 12 s of the robot's time (progress_window_s is 10 s), each pair 3 s late
        late_s = time.monotonic() - 3.0
        planner.on_message("r0", "odom", OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose), late_s)
        planner.on_message("r0", "scan", ScanMsg(step, scan.scan, scan.sensor_pose), late_s)
    stops = [m for t, m in out if t == "cmd_vel" and m.step >= 2]
    assert len(stops) == 48 and all(m.reason.startswith("stale: inputs of step") and m.command == VelocityCommand() for m in stops)
    planner.on_message("r0", "odom", OdometryMsg(50, odom.stamp_s + 12.5, odom.pose), time.monotonic())
    planner.on_message("r0", "scan", ScanMsg(50, scan.scan, scan.sensor_pose), time.monotonic())
    last = [m for t, m in out if t == "cmd_vel"][-1]
    assert last.step == 50 and last.reason == "" and last.command == driving.command, last  # following, as before the wait
    assert planner.planner.status.value == "following" and planner.planner.recovery.escapes == 0 and planner.planner.stall.stalled_periods == 0


def test_real_time_planner_says_how_long_its_inputs_have_been_silent_while_they_are(caplog):
    """The fake LIMO killed mid-run: ``status`` said "stale: no odometry for 1.1 s, no scan for 1.1 s" for as long
    as the robot was gone (the reason was written once, at the stop). It now says how long the silence has lasted,
    without a log line or another stop per tick; inputs that come back clear it as before."""
    planner, out, odom, scan, t0 = _real_time_planner_with_a_goal(stale_after_s=1.0)
    with caplog.at_level("INFO", logger="cso.service"):
        planner.on_tick(t0 + 1.1)
        assert planner.state == "stale" and planner.reason == "stale: no odometry for 1.1 s, no scan for 1.1 s"
        planner.on_tick(t0 + 12.4)
    assert planner.state == "stale" and planner.reason == "stale: no odometry for 12 s, no scan for 12 s"
    assert [m.reason for t, m in out if t == "cmd_vel" and m.reason.startswith("stale")] == ["stale: no odometry for 1.1 s, no scan for 1.1 s"]
    assert caplog.text.count("planner: stale") == 1, caplog.text
    planner.on_message("r0", "odom", OdometryMsg(1, odom.stamp_s + 13.0, odom.pose), t0 + 13.0)
    planner.on_message("r0", "scan", ScanMsg(1, scan.scan, scan.sensor_pose), t0 + 13.0)
    assert planner.state != "stale"


def test_planner_plans_on_the_distance_map_of_the_decision_when_it_arrives(monkeypatch):
    """D travels on its own key after the decision message: with it the planner only descends it (no
    fast-marching pass of its own), and the path is the in-process one; a D of another pose is not used."""
    import cso_runtime.planner as planner_module

    passes = []
    real = planner_module.geodesic_distance
    monkeypatch.setattr(planner_module, "geodesic_distance", lambda *a: passes.append(a) or real(*a))
    ex = _explorer_at(0)
    obs = ex.observe()
    goal = _far_goal(obs, 0)
    in_process = LocalPlanner()
    in_process.set_goal(obs.traversable, obs.geometry, obs.pose, np.array([goal.x_m, goal.y_m]), obs.distance_m)
    for distance, expected_passes in ((DistanceMapMsg(0, obs.geometry, obs.pose, obs.distance_m), 0), (DistanceMapMsg(0, obs.geometry, Pose2D(0.0, 0.0, 0.0), obs.distance_m), 1)):
        planner, out = _service(PlannerService, lockstep=True)
        _, odom, scan = _inputs(ex, 0)
        for msg in (odom, scan, frontiers_from_observation(0, "no_goal", obs, 1.0), distance, goal):
            _feed(planner, msg)
        assert [(m.step, m.new_goal) for t, m in out if t == "cmd_vel"] == [(0, True)]
        np.testing.assert_array_equal(planner.planner.path, in_process.path)
        assert len(passes) == expected_passes and not planner.distance_maps  # used up with its step
        passes.clear()


def test_lockstep_planner_command_computed_ahead_is_the_one_computed_on_the_verdict():
    """The planner computes a step's command as soon as its odometry and scan are in (while the map and
    the verdict travel). Fed the verdict last (computed ahead) or first (computed on the verdict), it
    sends the same commands and reports, also across a new goal that voids the command computed ahead."""
    ex = _explorer_at(0)
    ahead, out_ahead = _service(PlannerService, lockstep=True)
    on_verdict, out_verdict = _service(PlannerService, lockstep=True)
    decided_at = {0, 6}
    computed_ahead = 0
    for k in range(12):
        _, odom, scan = _inputs(ex, k)
        if k in decided_at:
            obs = ex.observe()
            verdict, goal = frontiers_from_observation(k, "no_goal", obs, 1.0), _far_goal(obs, k)
        else:
            verdict, goal = FrontiersMsg(k, False), None
        for msg in (odom, scan, verdict, goal):  # verdict last: the command of a keep step is ready before it
            if msg is not None:
                _feed(ahead, msg)
            if msg is scan and ahead.ahead is not None and ahead.ahead[0] == k:
                computed_ahead += 1
        for msg in (verdict, goal, odom, scan):
            if msg is not None:
                _feed(on_verdict, msg)
        cmd = [m for t, m in out_ahead if t == "cmd_vel"][-1]
        assert cmd.step == k
        ex.sim.step(cmd.command)
        ex._integrate()
    assert computed_ahead == 11  # every step but the first (no path yet), the decision at step 6 included (then voided)
    assert on_verdict.ahead is None
    for topic in ("cmd_vel", "planner_feedback"):
        a = [encode(m) for t, m in out_ahead if t == topic]
        b = [encode(m) for t, m in out_verdict if t == topic]
        assert len(a) == 12 and a == b, topic


def _lockstep_step(planner: PlannerService, ex: Explorer, k: int, episode: int, goal_at: int | None = None) -> None:
    """Step ``k`` of a lockstep episode with id ``episode``, in the order the sim and the frontier service send it; a
    decision on the far goal when ``k == goal_at``, else the verdict that keeps the goal."""
    _, odom, scan = _inputs(ex, k)
    _feed(planner, dataclasses.replace(odom, stamp_s=odom.stamp_s + 0.25 * k, episode=episode))
    _feed(planner, dataclasses.replace(scan, episode=episode))
    if k == goal_at:
        obs = ex.observe()
        _feed(planner, frontiers_from_observation(k, "no_goal", obs, 1.0, episode))
        _feed(planner, dataclasses.replace(_far_goal(obs, k), episode=episode))
    else:
        _feed(planner, FrontiersMsg(k, False, episode=episode))


def test_the_planner_sends_its_contacts_only_when_one_is_added_and_a_restarted_one_plans_round_them():
    """Contacts (``LocalPlanner.contacts_xy_m``) are the planner's one memory of an episode that no other service
    has: a planner killed and restarted forgot them and could drive into the same wall again. It sends all of them
    (``planner_contacts``) once a step's command adds one, just before that command (whose carried state counts them;
    the lockstep chain never waits for them) and never on a step that adds none; a planner started with them from the referee's cache
    keeps them (``status`` counts them), plans its next goal round them, and drops them at another episode's input."""
    ex = _explorer_at(0)
    planner, out = _service(PlannerService, lockstep=True)
    obs = ex.observe()
    plain = LocalPlanner()
    goal = _far_goal(obs, 0)
    plain.set_goal(obs.traversable, obs.geometry, obs.pose, np.array([goal.x_m, goal.y_m]), obs.distance_m)
    contact_xy = plain.path[len(plain.path) // 2]  # on the path the planner would take without it
    iy, ix = obs.geometry.world_to_cell(contact_xy[0], contact_xy[1])
    real_update = LocalPlanner.update

    def update(self: LocalPlanner, pose: Pose2D, time_s: float, scan: object = None) -> object:
        result = real_update(self, pose, time_s, scan)  # type: ignore[arg-type]
        if time_s >= 0.5:  # from step 2 on the robot is pinned there (marked once: a cell kept already adds none)
            self.add_contacts(obs.geometry, np.array([iy]), np.array([ix]))
        return result

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(LocalPlanner, "update", update)
        for k in range(5):
            _lockstep_step(planner, ex, k, episode=7, goal_at=0)
    sent = [(t, m.step) for t, m in out if t in ("cmd_vel", "planner_feedback", "planner_contacts")]
    assert [t for t, _ in sent].count("planner_contacts") == 1
    at = sent.index(("planner_contacts", 2))
    assert sent[at : at + 3] == [("planner_contacts", 2), ("cmd_vel", 2), ("planner_feedback", 2)]  # just before the command whose state counts them
    (contacts,) = [m for t, m in out if t == "planner_contacts"]
    assert contacts.episode == 7 and np.array_equal(contacts.contacts_xy_m, planner.planner.contacts_xy_m) and len(contacts.contacts_xy_m) == 1
    assert planner.extra_status() == {"contacts": 1}

    restarted, restarted_out = _service(PlannerService, lockstep=True)
    asked: list[str] = []
    restarted.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: (asked.append(key) or (contacts if key.endswith("/contacts") else None), True)  # type: ignore[method-assign]
    restarted.start()
    assert asked == ["cso/r0/cache/planner/contacts", "cso/r0/cache/planner/state"] and restarted.extra_status() == {"contacts": 1}  # no state kept: no plan asked
    for k in range(5, 8):
        _lockstep_step(restarted, ex, k, episode=7, goal_at=5)
    assert np.array_equal(restarted.planner.contacts_xy_m, contacts.contacts_xy_m)
    assert restarted.planner.free is not None and not restarted.planner.free.traversable[int(iy), int(ix)]  # planned round it
    assert not [t for t, _ in restarted_out if t == "planner_contacts"]  # the referee holds them already
    _lockstep_step(restarted, ex, 0, episode=8, goal_at=0)  # a new episode: none of its contacts
    assert restarted.extra_status() == {"contacts": 0} and len(restarted.planner.contacts_xy_m) == 0

    fresh, _ = _service(PlannerService, lockstep=True)
    fresh.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: (None, True)  # type: ignore[method-assign]
    fresh.start()  # nothing cached (a first start, or an episode with no contact yet)
    assert fresh.extra_status() == {"contacts": 0} and fresh.episodes.current is None


def test_a_restarted_planner_says_whether_the_cache_restored_it_had_nothing_or_did_not_answer(caplog):
    """A restarted planner waits at most ``restore_timeout_s`` for the referee's cache. When it got no answer in that
    time (a loaded host, links not yet up) it started afresh and said nothing, as when the cache had nothing kept: the
    log (and the status's ``cache_unanswered``) now tell the two apart."""
    params = {"restore_timeout_s": 0.05}
    asked: list[str] = []

    def session(*replies: object) -> types.SimpleNamespace:  # a Zenoh session whose every query gets ``replies``
        return types.SimpleNamespace(get=lambda key, target, timeout: asked.append(key) or iter(replies))

    unanswered, _ = _service(PlannerService, lockstep=True, params=params)
    unanswered.session = session()  # no queryable answers (not even "nothing yet")
    with caplog.at_level("INFO"):
        unanswered.start()
    said = [r.getMessage() for r in caplog.records]
    for key in ("cso/r0/cache/planner/contacts", "cso/r0/cache/planner/state"):
        assert f"planner: no answer from the cache on {key} within 0.05 s: starting afresh (nothing of it restored)" in said, said
    assert unanswered.status_msg().counters == {"contacts": 0, "cache_unanswered": 2} and unanswered.cmd_step == -1

    caplog.clear()
    asked.clear()
    empty, _ = _service(PlannerService, lockstep=True, params=params)
    empty.session = session(types.SimpleNamespace(ok=None))  # the cache's answer: "nothing yet" (an error reply)
    with caplog.at_level("INFO"):
        empty.start()
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"planner: the cache had no {name} for this episode: starting afresh" for name in ("planner_contacts", "planner_state")], said
    assert empty.status_msg().counters == {"contacts": 0} and asked == ["cso/r0/cache/planner/contacts", "cso/r0/cache/planner/state"]  # asked once each


def _drive(planner: PlannerService, out: list, ex: Explorer, steps: range, episode: int, decision_obs=None, goal: GoalMsg | None = None) -> None:
    """Lockstep steps on ``ex``'s simulator, each moved by the command the planner sends for it (as the sim steps);
    step 0 decides the far goal of ``decision_obs`` (or ``goal``), every other step keeps the goal."""
    for k in steps:
        _feed(planner, OdometryMsg(k, ex.sim.time_s, ex.sim.odometry(), episode=episode))
        _feed(planner, ScanMsg(k, ex.sim.scan(), ex.sim.sensor_pose(), episode))
        if k == 0:
            _feed(planner, frontiers_from_observation(0, "no_goal", decision_obs, 1.0, episode))
            _feed(planner, dataclasses.replace(goal or _far_goal(decision_obs, 0), episode=episode))
        else:
            _feed(planner, FrontiersMsg(k, False, episode=episode))
        ex.sim.step([m for t, m in out if t == "cmd_vel" and m.step == k][-1].command)


def _with_carried(out: list) -> list:
    """``out`` with the planner's state and plan that each ``cmd_vel`` carries after it, decoded, as (``planner_state``,
    state) and (``planner_plan``, plan): what the referee keeps of them for ``cache/planner/state`` and ``.../plan``."""
    carried = []
    for t, m in out:
        carried.append((t, m))
        if t == "cmd_vel":
            carried += [(name, decode(payload, cls)) for name, payload, cls in (("planner_plan", m.planner_plan, PlannerPlanMsg), ("planner_state", m.planner_state, PlannerStateMsg)) if payload is not None]
    return carried


def _restarted_from(out: list, upto_step: int) -> tuple[PlannerService, list]:
    """A planner started afresh with what the referee kept of ``out`` up to ``upto_step`` (its cache keys)."""
    kept = {t: m for t, m in _with_carried(out) if t in ("planner_contacts", "planner_plan", "planner_state") and m.step <= upto_step}
    restarted, restarted_out = _service(PlannerService, lockstep=True)
    restarted.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: (kept.get(key.removeprefix("cso/r0/cache/").replace("/", "_")), True)  # type: ignore[method-assign]
    restarted.start()
    return restarted, restarted_out


def test_a_planner_state_too_large_for_cmd_vel_is_left_off_and_the_command_still_goes_out(caplog):
    """``with_checkpoint`` put the encoded state on the command whatever its size: one over
    ``MAX_PLANNER_STATE_BYTES`` (a text of the state grown past what it carries) made the referee refuse the whole
    ``cmd_vel``, and the robot stopped. The command now goes out without it, logged and counted (``states_too_large``);
    the next state that fits rides again."""
    episode = 5
    ex = _explorer_at(0)
    obs = ex.observe()
    planner, out = _service(PlannerService, lockstep=True)  # publishes through the codec, as the referee decodes
    _drive(planner, out, ex, range(2), episode, obs)
    checkpoint = planner.planner.checkpoint
    planner.planner.checkpoint = lambda: dataclasses.replace(checkpoint(), blocked_why="x" * 70_000)  # type: ignore[method-assign]
    with caplog.at_level("WARNING", logger="cso.planner"):
        _drive(planner, out, ex, range(2, 3), episode)
    planner.planner.checkpoint = checkpoint  # type: ignore[method-assign]
    _drive(planner, out, ex, range(3, 4), episode)
    cmds = {m.step: m for t, m in out if t == "cmd_vel"}
    assert sorted(cmds) == [0, 1, 2, 3] and cmds[2].planner_state is None and cmds[2].reason == ""  # following
    assert all(cmds[k].planner_state is not None for k in (0, 1, 3))
    assert planner.extra_status() == {"contacts": 0, "states_too_large": 1}
    assert "step 2: the planner's state (7" in caplog.text and "the command goes without it" in caplog.text


def test_a_planner_restarted_from_the_referees_cache_commands_the_next_steps_as_the_one_killed():
    """The planner's ``cmd_vel`` carries its plan when it changes (``planner_plan``) and its state after every command
    (``planner_state``), on no message of their own; one started afresh on what the referee keeps of them carries on: the same goal, path
    and counters, so from the step after the kill every command (and report) is the uninterrupted planner's, in a
    closed loop where each command moves the robot. A cache one step behind (a step's cmd_vel lost with its
    state) is seen at the next step's odometry: the planner keeps the goal and joins there instead of waiting forever
    for a step the sim has passed."""
    episode, kill_after, end = 5, 4, 14  # the goal is reached at step 10
    ex_a, ex_b = _explorer_at(0), _explorer_at(0)
    obs = ex_a.observe()
    uninterrupted, out_a = _service(PlannerService, lockstep=True)
    _drive(uninterrupted, out_a, ex_a, range(end), episode, obs)
    killed, out_b = _service(PlannerService, lockstep=True)
    _drive(killed, out_b, ex_b, range(kill_after + 1), episode, obs)
    assert not {t for t, _ in out_b} & {"planner_plan", "planner_state"}  # no message of their own: they ride on the step's command
    (cmd_2,) = [m for t, m in out_b if t == "cmd_vel" and m.step == 2]
    assert cmd_2.planner_state is not None and decode(cmd_2.planner_state, PlannerStateMsg).cmd == dataclasses.replace(cmd_2, episode=0, planner_state=None, planner_plan=None)
    assert not [m for t, m in out_b if t == "cmd_vel_ahead" and (m.planner_state or m.planner_plan)]  # only the step's command carries them
    assert [m.step for t, m in _with_carried(out_b) if t == "planner_plan"] == [0]  # the plan goes out when it changes, the state every step
    assert [m.step for t, m in _with_carried(out_b) if t == "planner_state"] == list(range(kill_after + 1))

    restarted, out_r = _restarted_from(out_b, kill_after)
    assert (restarted.cmd_step, restarted.goal_step, restarted.planner.status) == (kill_after, 0, PlannerStatus.FOLLOWING)
    assert restarted.planner.path is not None and np.array_equal(restarted.planner.path, killed.planner.path)
    assert restarted.planner.checkpoint() == killed.planner.checkpoint()
    _drive(restarted, out_r, ex_b, range(kill_after + 1, end), episode, obs)
    after = lambda out, topic: [encode(m) for t, m in _with_carried(out) if t == topic and m.step > kill_after]  # noqa: E731
    assert len(after(out_a, "cmd_vel")) == end - kill_after - 1
    for topic in ("cmd_vel", "planner_feedback", "planner_state"):
        assert after(out_r, topic) == after(out_a, topic), topic
    assert restarted.planner.checkpoint() == uninterrupted.planner.checkpoint()

    behind, out_behind = _restarted_from(out_b, kill_after - 1)  # its state of kill_after never went out
    ex_c = _explorer_at(0)
    for k in range(kill_after + 1):  # the world as the killed planner left it
        ex_c.sim.step([m for t, m in out_b if t == "cmd_vel" and m.step == k][-1].command)
    _drive(behind, out_behind, ex_c, range(kill_after + 1, kill_after + 4), episode, obs)
    (report,) = [m for t, m in out_behind if t == "planner_feedback" and m.step == kill_after]  # the report the frontier service waits for
    assert (report.status, report.goal_step) == ("following", 0) and len(report.path_ahead_xy_m) > 0
    assert [m.step for t, m in out_behind if t == "cmd_vel"] == [kill_after + 1, kill_after + 2, kill_after + 3]
    assert behind.goal_step == 0 and behind.planner.status == PlannerStatus.FOLLOWING

    real_time, out_rt = _service(PlannerService, lockstep=False)  # a robot's planner: it resumes the goal too
    kept = {t: m for t, m in _with_carried(out_b) if t in ("planner_plan", "planner_state")}
    real_time.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: (kept.get(key.removeprefix("cso/r0/cache/").replace("/", "_")), True)  # type: ignore[method-assign]
    real_time.start()
    anchor = kept["planner_state"].follow.progress_anchor
    assert anchor is not None
    later = anchor[2] + 60.0  # the robot stood still, where progress was last seen, while no planner ran: no failed progress check for that
    _feed(real_time, OdometryMsg(kill_after + 9, later, Pose2D(anchor[0], anchor[1], ex_c.sim.odometry().yaw_rad), episode=episode))
    _feed(real_time, ScanMsg(kill_after + 9, ex_c.sim.scan(), ex_c.sim.sensor_pose(), episode))
    (cmd,) = [m for t, m in out_rt if t == "cmd_vel"]
    assert cmd.reason == "" and cmd.command.linear_mps > 0 and real_time.goal_step == 0 and real_time.planner.progress.anchor[2] == later  # type: ignore[index]

    state = [m for t, m in _with_carried(out_b) if t == "planner_state"][-1]
    other_plan = dataclasses.replace([m for t, m in _with_carried(out_b) if t == "planner_plan"][-1], step=kill_after)  # a newer plan than the state's
    for plan in (None, other_plan):
        fresh, _ = _service(PlannerService, lockstep=True)
        assert not fresh.restore_state(state, plan) and (fresh.cmd_step, fresh.planner.path, fresh.episodes.current) == (-1, None, None)


def test_a_planner_killed_anywhere_in_a_step_that_adds_a_contact_restarts_with_the_contacts_of_its_state(caplog):
    """The contacts (``planner_contacts``) ride on no command: they went out after the step's ``cmd_vel``, which carries
    the state. A planner killed between the two left the cache a state of step k and the contacts of before k, and the
    one restarted from them went on without the contact step k had added: it added it again a step later (another
    ``planner_contacts``, other paths round it), not the uninterrupted planner's commands. Wherever in the step the
    planner is killed, the restarted one now commands, reports and sends contacts from the step after its state as the
    uninterrupted planner did: the contacts go out before the command whose state counts them (``contacts``), and
    contacts of a later step than the state are dropped at the restore (its step is commanded again, adding them
    again), and the planner's log says so (it said only "restored 1 contacts" and went on with none). Uncounted contacts
    of no later step (another sender's), and any in real time (no step is redone), are kept."""
    episode, end, contact_step = 5, 7, 2
    period_s = ExplorationConfig().robot.control_period_s
    ex = _explorer_at(0)
    obs = ex.observe()
    plain = LocalPlanner()
    goal = _far_goal(obs, 0)
    plain.set_goal(obs.traversable, obs.geometry, obs.pose, np.array([goal.x_m, goal.y_m]), obs.distance_m)
    iy, ix = obs.geometry.world_to_cell(*plain.path[len(plain.path) // 2])
    real_update = LocalPlanner.update

    def update(self: LocalPlanner, pose: Pose2D, time_s: float, scan: object = None) -> object:
        result = real_update(self, pose, time_s, scan)  # type: ignore[arg-type]
        if time_s >= contact_step * period_s - 1e-9:  # pinned there from this step on (a cell kept already adds none)
            self.add_contacts(obs.geometry, np.array([iy]), np.array([ix]))
        return result

    def carried_after(out: list, step: int) -> dict[str, list[bytes]]:
        return {t: [encode(m) for u, m in _with_carried(out) if u == t and m.step > step] for t in ("cmd_vel", "planner_feedback", "planner_contacts", "planner_state")}

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(LocalPlanner, "update", update)
        uninterrupted, out_a = _service(PlannerService, lockstep=True)
        _drive(uninterrupted, out_a, _explorer_at(0), range(end), episode, obs)
        killed, out_b = _service(PlannerService, lockstep=True)
        _drive(killed, out_b, _explorer_at(0), range(contact_step + 1), episode, obs)
        sent = _with_carried(out_b)
        of_step = [i for i, (t, m) in enumerate(sent) if m.step == contact_step and t in ("cmd_vel", "planner_contacts")]
        assert len(of_step) == 2  # the step adds a contact: both go out
        restored_steps = set()
        for cut in range(of_step[0], len(sent) + 1):  # killed before the first of the two, and after each message from there
            kept = {t: m for t, m in sent[:cut] if t in ("planner_contacts", "planner_plan", "planner_state")}
            restarted, out_r = _service(PlannerService, lockstep=True)
            restarted.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: (kept.get(key.removeprefix("cso/r0/cache/").replace("/", "_")), True)  # type: ignore[method-assign]  # noqa: B023
            restarted.start()
            s = restarted.cmd_step
            restored_steps.add(s)
            world = _explorer_at(0)
            for k in range(s + 1):  # the world as the killed planner left it: moved by the commands the sim has
                world.sim.step([m for t, m in out_b if t == "cmd_vel" and m.step == k][-1].command)
            _drive(restarted, out_r, world, range(s + 1, end), episode, obs)
            assert carried_after(out_r, s) == carried_after(out_a, s), (cut, s)
            assert np.array_equal(restarted.planner.contacts_xy_m, uninterrupted.planner.contacts_xy_m), cut
        assert restored_steps == {contact_step - 1, contact_step}  # killed before the step's state went out, and after
    state = [m for t, m in sent if t == "planner_state" and m.step == contact_step - 1][-1]
    plan = [m for t, m in sent if t == "planner_plan"][-1]
    (contacts,) = [m for t, m in sent if t == "planner_contacts"]
    assert state.contacts == 0 and contacts.step == contact_step and len(contacts.contacts_xy_m) == 1
    for lockstep, contacts_step in ((True, contact_step - 1), (False, contact_step)):  # another sender's; real time, where no step is redone
        kept_all, _ = _service(PlannerService, lockstep=lockstep)
        kept_all.restore_contacts(dataclasses.replace(contacts, step=contacts_step))
        assert kept_all.restore_state(state, plan) and len(kept_all.planner.contacts_xy_m) == 1, (lockstep, contacts_step)
    dropped, _ = _service(PlannerService, lockstep=True)
    with caplog.at_level("INFO", logger="cso.planner"):
        dropped.restore_contacts(contacts)
        assert dropped.restore_state(state, plan) and len(dropped.planner.contacts_xy_m) == 0
    said = f"the contacts restored are of step {contact_step}, after the state's (step {contact_step - 1}): keeping the 0 it counted, not the 1 after them"
    assert said in caplog.text, caplog.text


@pytest.mark.parametrize("decision", ["no_goal", "no_path"])
def test_a_planner_killed_before_its_first_plan_restarts_from_its_state_alone(decision):
    """The state every command carries names the plan it follows (``plan_step``), -1 before the planner's first plan: a
    first decision with no goal (no frontier left) or a goal with no path. A planner restarted on such a state was
    refused it ("no plan of step -1 in the cache": there is none to find) and started afresh: no longer stopped for
    no frontier nor reporting its goal blocked, it commanded "idle" where the one killed would have said why it stood,
    and asked the cache for a plan that cannot be there. It now resumes from the state alone, on no path, and commands
    the next steps as the one killed."""
    episode, kill_after, end = 5, 3, 8
    ex_a, ex_b = _explorer_at(0), _explorer_at(0)
    obs = ex_a.observe()
    goal = GoalMsg(0, True, method="greedy-dist") if decision == "no_goal" else GoalMsg(0, True, 1e3, 1e3, 0, 5.0, 1.0, "greedy-dist")
    uninterrupted, out_a = _service(PlannerService, lockstep=True)
    _drive(uninterrupted, out_a, ex_a, range(end), episode, obs, goal)
    killed, out_b = _service(PlannerService, lockstep=True)
    _drive(killed, out_b, ex_b, range(kill_after + 1), episode, obs, goal)
    assert [m.step for t, m in _with_carried(out_b) if t == "planner_plan"] == []  # never a plan
    state = [m for t, m in _with_carried(out_b) if t == "planner_state"][-1]
    assert (state.step, state.plan_step) == (kill_after, -1)
    asked: list[str] = []
    restarted, out_r = _service(PlannerService, lockstep=True)
    kept = {"planner_state": state}
    restarted.query_answered = lambda key, expected, timeout_s=1.0, retry_period_s=0.05: ((asked.append(key), kept.get(key.removeprefix("cso/r0/cache/").replace("/", "_")))[1], True)  # type: ignore[method-assign]
    restarted.start()
    assert not [key for key in asked if key.endswith("planner/plan")]  # the state names no plan: none asked for
    assert (restarted.cmd_step, restarted.goal_step, restarted.no_frontier, restarted.planner.path) == (kill_after, 0, decision == "no_goal", None)
    assert restarted.planner.checkpoint() == killed.planner.checkpoint()
    _drive(restarted, out_r, ex_b, range(kill_after + 1, end), episode, obs, goal)
    after = lambda out, topic: [encode(m) for t, m in _with_carried(out) if t == topic and m.step > kill_after]  # noqa: E731
    assert len(after(out_a, "cmd_vel")) == end - kill_after - 1
    for topic in ("cmd_vel", "planner_feedback", "planner_state"):
        assert after(out_r, topic) == after(out_a, topic), topic
    reasons = {m.reason for t, m in out_r if t == "cmd_vel"}
    assert reasons == ({"no_frontier"} if decision == "no_goal" else {f"blocked: {uninterrupted.planner.blocked_why}"}), reasons


def test_a_restarted_planner_refuses_a_cached_state_that_does_not_fit_its_plan():
    """The cache pairs a state with a plan by step and episode only: a plan of the same step from another planner (two at
    once), or a forged one, may be shorter than the point the state follows, which failed the restarted planner's first
    command (a ValueError in ``lookahead_index``: the argmin of an empty sequence), restart after restart; or
    the state may follow a goal with no path, which stood the robot still reporting ``following``. Such a state is
    not restored: the planner starts afresh. A planner's own state and plan, and its state after its goal was
    cleared (no path, the path point left as it was), are restored."""
    episode, kill_after = 5, 6
    ex = _explorer_at(0)
    obs = ex.observe()
    killed, out = _service(PlannerService, lockstep=True)
    _drive(killed, out, ex, range(kill_after + 1), episode, obs)
    state = [m for t, m in _with_carried(out) if t == "planner_state"][-1]
    plan = [m for t, m in _with_carried(out) if t == "planner_plan"][-1]
    assert state.follow.progress_index >= 2 and state.follow.status == PlannerStatus.FOLLOWING
    fresh, _ = _service(PlannerService, lockstep=True)
    assert fresh.restore_state(state, plan)  # its own: restored
    short = dataclasses.replace(plan, path_xy_m=plan.path_xy_m[:2])
    no_path = dataclasses.replace(plan, path_xy_m=np.zeros((0, 2)), free=None)
    late_cmd = dataclasses.replace(state, cmd=dataclasses.replace(state.cmd, step=state.step + 1))
    for s, p in ((state, short), (state, no_path), (late_cmd, plan)):
        fresh, fresh_out = _service(PlannerService, lockstep=True)
        assert not fresh.restore_state(decode(encode(s), PlannerStateMsg), decode(encode(p), PlannerPlanMsg))
        assert (fresh.cmd_step, fresh.planner.path, fresh.episodes.current) == (-1, None, None)
        _drive(fresh, fresh_out, _explorer_at(0), range(2), episode, obs)  # a fresh planner: it joins and commands
    cleared = dataclasses.replace(state, follow=dataclasses.replace(state.follow, status=PlannerStatus.IDLE), no_frontier=True)
    fresh, _ = _service(PlannerService, lockstep=True)
    assert fresh.restore_state(cleared, no_path)  # no goal left: the path point is unused


def test_a_cached_state_a_restarted_planner_refuses_is_counted_as_rejected():
    """A cached state that does not fit its plan (a plan of another planner, a forged one, one of another step) was
    only logged at info level: ``status`` showed a restarted planner that had started afresh as if it had resumed. It
    is rejected and counted (``planner_state``), as any input refused is; a state of a planner that had not planned yet
    (``plan_step`` -1) needs no plan: it is resumed on no path, and nothing is counted."""
    episode = 5
    ex = _explorer_at(0)
    obs = ex.observe()
    killed, out = _service(PlannerService, lockstep=True)
    _drive(killed, out, ex, range(4), episode, obs)
    state = [m for t, m in _with_carried(out) if t == "planner_state"][-1]
    plan = [m for t, m in _with_carried(out) if t == "planner_plan"][-1]
    for p in (dataclasses.replace(plan, path_xy_m=plan.path_xy_m[:1]), dataclasses.replace(plan, step=plan.step + 1), None):
        fresh, _ = _service(PlannerService, lockstep=True)
        assert not fresh.restore_state(state, p)
        assert fresh.rejected == {"planner_state": 1}
    before_any_plan = dataclasses.replace(state, plan_step=-1, follow=dataclasses.replace(state.follow, status=PlannerStatus.IDLE))
    fresh, _ = _service(PlannerService, lockstep=True)
    assert fresh.restore_state(before_any_plan, None) and fresh.rejected == {} and fresh.planner.path is None


def test_a_robot_stood_still_by_order_is_not_judged_stalled_on_its_last_command():
    """Real time: the robot stands still while no planner runs (a restart), while paused or while its inputs are stale,
    because it was told to, not because it is pinned. The progress check started over after each, but the stall check
    judged the last command before (remembered with its pose and time, ``StallRecovery.last``, and restored from the
    cache after a restart) against where the robot was after the whole wait: one more stalled period, and a robot that
    had stalled ``stall_steps - 1`` periods backed up (with a narrow sensor, marking contacts where nothing was). The
    first command after such a wait is the follower's own."""
    ex = _explorer_at(0)
    obs = ex.observe()
    killed, out = _service(PlannerService, lockstep=True)
    _drive(killed, out, ex, range(5), 5, obs)
    state = [m for t, m in _with_carried(out) if t == "planner_state"][-1]
    plan = [m for t, m in _with_carried(out) if t == "planner_plan"][-1]
    pose, t_s = ex.sim.odometry(), ex.sim.time_s
    stall_steps = ExplorationConfig().planner.stall_steps
    pinned_so_far = dataclasses.replace(  # stalled one period short of a back-up, driving, where progress was last seen
        state.follow, stalled_periods=stall_steps - 1, stall_last=(pose, t_s, VelocityCommand(0.2, 0.0)), progress_anchor=(pose.x_m, pose.y_m, t_s)
    )
    restarted, restarted_out = _service(PlannerService, lockstep=False)
    assert restarted.restore_state(dataclasses.replace(state, follow=pinned_so_far), plan)
    _feed(restarted, OdometryMsg(9, t_s + 60.0, pose, episode=5))
    _feed(restarted, ScanMsg(9, ex.sim.scan(), ex.sim.sensor_pose(), 5))
    (cmd,) = [m for t, m in restarted_out if t == "cmd_vel"]
    assert cmd.reason == "" and cmd.command.linear_mps >= 0, cmd  # following, not backing up
    assert restarted.planner.stall.stalled_periods == 0

    paused, paused_out = _service(PlannerService, lockstep=False)
    assert paused.restore_state(dataclasses.replace(state, follow=pinned_so_far), plan)
    _feed(paused, OdometryMsg(9, t_s + 0.1, pose, episode=5))
    _feed(paused, ScanMsg(9, ex.sim.scan(), ex.sim.sensor_pose(), 5))  # the restart's first command: judged over 0.1 s
    paused.planner.stall.restore((pinned_so_far.stall_last, stall_steps - 1, None, 0, False))
    _feed(paused, ExploreResumeMsg(False, "alice@lab"))
    _feed(paused, OdometryMsg(10, t_s + 60.0, pose, episode=5))
    _feed(paused, ScanMsg(10, ex.sim.scan(), ex.sim.sensor_pose(), 5))
    _feed(paused, ExploreResumeMsg(True, "alice@lab"))
    _feed(paused, OdometryMsg(11, t_s + 60.1, pose, episode=5))
    _feed(paused, ScanMsg(11, ex.sim.scan(), ex.sim.sensor_pose(), 5))
    cmd = [m for t, m in paused_out if t == "cmd_vel"][-1]
    assert cmd.step == 11 and cmd.reason == "" and cmd.command.linear_mps >= 0, cmd


def test_the_sim_keeps_the_planners_latest_contacts_plan_and_state_of_its_episode_for_a_restarted_planner():
    """``cache/planner/contacts`` (and ``cache/planner/plan``, ``cache/planner/state``) answers the newest message of
    the sim's episode (an error reply before any), and one of another episode, still in flight from before a restart,
    is rejected and counted."""
    from types import SimpleNamespace

    from services.sim import SimService

    ctx = ServiceContext("sim", "r0", {"scene": "generated:small:1:0", "lockstep": True}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    sim = SimService(ctx)
    sim.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
    assert "planner_contacts" in sim.serves_latest and "planner_contacts" in sim.optional_inputs

    def cached() -> PlannerContactsMsg | str:
        replies: list[tuple[str, bytes]] = []
        query = SimpleNamespace(reply=lambda key, payload: replies.append((key, payload)), reply_err=lambda payload: replies.append(("error", payload)))
        sim.answer_cache_query("planner_contacts", query)
        ((key, payload),) = replies
        assert key in ("error", "cso/r0/cache/planner/contacts")
        return payload.decode() if key == "error" else decode(payload, PlannerContactsMsg)

    assert cached() == "no planner_contacts yet"
    one, two = np.array([[1.0, 2.0]]), np.array([[1.0, 2.0], [1.5, 2.0]])
    for step, xy in ((3, one), (9, two)):
        _feed(sim, PlannerContactsMsg(step, xy, sim.episode))
    latest = cached()
    assert isinstance(latest, PlannerContactsMsg) and latest.step == 9 and np.array_equal(latest.contacts_xy_m, two)
    _feed(sim, PlannerContactsMsg(12, one, sim.episode + 1))
    assert cached().step == 9 and sim.rejected == {"planner_contacts": 1}  # type: ignore[union-attr]

    def kept(topic: str, cls: type) -> Message | str:
        replies: list[tuple[str, bytes]] = []
        query = SimpleNamespace(reply=lambda key, payload: replies.append((key, payload)), reply_err=lambda payload: replies.append(("error", payload)))
        sim.answer_cache_query(topic, query)
        ((key, payload),) = replies
        return payload.decode() if key == "error" else decode(payload, cls)

    assert kept("planner_state", PlannerStateMsg) == "no planner_state yet" and kept("planner_plan", PlannerPlanMsg) == "no planner_plan yet"
    def carrying(state: PlannerStateMsg | None, plan: PlannerPlanMsg | None = None) -> CmdVelMsg:  # the planner's state and plan ride on its cmd_vel
        step, episode = (state or plan).step, (state or plan).episode  # type: ignore[union-attr]
        return CmdVelMsg(step, VelocityCommand(), episode=episode, planner_state=state and encode(state), planner_plan=plan and encode(plan))

    states = [PlannerStateMsg(step, 0, 0, False, CmdVelMsg(step, VelocityCommand(0.2, 0.0)), False, LocalPlanner().checkpoint(), sim.episode) for step in (4, 5)]
    for state in states:
        _feed(sim, carrying(state))
    _feed(sim, carrying(None, PlannerPlanMsg(0, two, None, sim.episode)))
    _feed(sim, carrying(PlannerStateMsg(6, 0, 0, False, CmdVelMsg(6, VelocityCommand()), False, LocalPlanner().checkpoint(), sim.episode + 1)))
    state, plan = kept("planner_state", PlannerStateMsg), kept("planner_plan", PlannerPlanMsg)
    assert isinstance(state, PlannerStateMsg) and state.step == 5 and state.cmd.command == VelocityCommand(0.2, 0.0)
    assert isinstance(plan, PlannerPlanMsg) and np.array_equal(plan.path_xy_m, two) and sim.rejected["planner_state"] == 1
    raw: list[bytes] = []
    sim.answer_cache_query("planner_state", SimpleNamespace(reply=lambda key, payload: raw.append(payload), reply_err=raw.append))
    assert raw == [encode(states[-1])]  # served as it came on the cmd_vel, never decoded by the sim


def test_sim_starts_the_episode_when_every_service_of_the_profile_is_alive():
    """Step 0 waits for the liveliness tokens of the profile's other services (a policy loading torch comes
    up last; before, its first decision waited a second for a lockstep re-publish), then start_delay_s;
    after wait_for_services_s it starts without the missing ones."""
    from types import SimpleNamespace

    from services.sim import SimService

    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 3, "services": {n: {} for n in ("sim", "mapper", "frontier", "policy", "planner")}}

    def sim(params: dict) -> tuple[SimService, list]:
        svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), params))
        out: list = []
        svc.publish = lambda topic, msg, robot=None: out.append(topic)  # type: ignore[method-assign]
        return svc, out

    def token(name: str, kind: str = "SampleKind.PUT") -> SimpleNamespace:
        return SimpleNamespace(key_expr=f"cso/r0/alive/{name}", kind=kind)

    svc, out = sim({"start_delay_s": 0.2})
    assert svc.expected_services == {"mapper", "frontier", "policy", "planner"}
    t0 = svc.started_s
    for name in ("mapper", "frontier", "planner"):
        svc.on_alive(token(name))
    svc.on_tick(t0 + 5.0)
    assert svc.episode_state == "starting" and "scan" not in out  # the policy is not up yet
    svc.on_alive(token("policy"))
    svc.on_alive(token("mapper", "SampleKind.DELETE"))
    svc.on_tick(t0 + 5.1)
    assert svc.episode_state == "starting"  # the mapper went away again
    svc.on_alive(token("mapper"))
    svc.on_tick(t0 + 5.2)
    assert svc.episode_state == "starting"  # all up: start_delay_s from now
    svc.on_tick(t0 + 5.3)
    assert svc.episode_state == "starting"
    svc.on_tick(t0 + 5.45)
    assert svc.episode_state == "exploring" and "scan" in out

    late, out = sim({"start_delay_s": 0.0, "wait_for_services_s": 2.0})
    for name in ("mapper", "frontier", "planner"):
        late.on_alive(token(name))
    late.on_tick(late.started_s + 1.9)
    assert late.episode_state == "starting"
    late.on_tick(late.started_s + 2.0)  # the policy never came: start anyway (logged), the re-publishing covers it
    assert late.episode_state == "exploring" and "scan" in out


def test_sim_waits_before_step_0_for_a_service_the_profile_leaves_out_and_the_episode_needs(caplog):
    """A profile with no policy (its robot served by a shared policy server, or ``up --without policy``): step 0
    waited only for the services it lists, and started without the policy, to re-publish step 0 in lockstep (its
    give-up clock running) or to spend its steps standing still in real time. It waits for the policy too (any
    robot's: a shared server's), at most ``wait_for_services_s``, and says what for; a listener (the foxglove bridge)
    is never waited for."""
    from types import SimpleNamespace

    from services.sim import SimService

    listed = {"sim": {}, "mapper": {}, "frontier": {}, "planner": {}}
    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 3, "services": listed, "without": ["foxglove_bridge"]}
    svc = SimService(ServiceContext("sim", "r1", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0}))
    svc.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
    for name in ("mapper", "frontier", "planner"):
        svc.on_alive(SimpleNamespace(key_expr=f"cso/r1/alive/{name}", kind="SampleKind.PUT"))
    with caplog.at_level("INFO", logger="cso.sim"):
        svc.on_tick(svc.started_s + 1.0)
        svc.on_tick(svc.started_s + 2.0)
    assert svc.episode_state == "starting"
    said = [r.message for r in caplog.records if "step 0 waits for" in r.message]
    assert said == ["the profile's services are up; step 0 waits for policy, which the profile leaves to another process (at most 29 s more)"]
    svc.on_alive(SimpleNamespace(key_expr="cso/r0/alive/policy", kind="SampleKind.PUT"))  # r0's server serves r1 too
    svc.on_tick(svc.started_s + 3.0)
    assert svc.episode_state == "exploring" and svc.step == 0
    assert svc.left_out_needed == {"policy"} and svc.expected_services == {"mapper", "frontier", "planner", "policy"}


def test_the_sims_result_names_the_episode_it_is_the_result_of():
    """The sim's result carried no episode id: a launcher that heard it late, after a restart of the sim had started
    a new episode, could not tell it from the new episode's and took it for that one's. It carries the id its status
    and every message of the episode carry; the result query answers the same."""
    from types import SimpleNamespace

    from services.sim import SimService

    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 3, "services": {"sim": {}}}
    svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0}))
    out: list = []
    svc.publish = lambda topic, msg, robot=None: out.append((topic, msg))  # type: ignore[method-assign]
    svc.on_tick(svc.started_s + 1.0)
    svc.finish("done", "max_steps")
    (result,) = [m for topic, m in out if topic == "episode_result"]
    status = [m for topic, m in out if topic == "episode_status"][-1]
    assert svc.episode != 0 and result.episode == status.episode == svc.episode
    replies: list = []
    svc._on_result_query(SimpleNamespace(reply=lambda key, payload: replies.append(payload)))  # type: ignore[arg-type]
    assert [decode(p, EpisodeResultMsg).episode for p in replies] == [svc.episode]


@pytest.mark.parametrize("real_time_factor", [1.0, 4.0, 20.0])
def test_real_time_sim_keeps_its_real_time_factor_whatever_its_tick(real_time_factor):
    """One 0.25 s step per 0.25 s / real_time_factor of wall clock, on a fixed schedule: its ticks come every
    20 ms (each a little late), and a step timed from the end of the last one would also wait for the next tick
    (0.96x at real_time_factor 1, never above 12.5x). A stall is not made up in a rush afterwards."""
    from services.sim import SimService

    profile = {"lockstep": False, "scene": "generated:small:1:0", "seed": 3}
    svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0, "real_time_factor": real_time_factor}))
    svc.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
    t0 = svc.started_s
    now = t0
    svc.on_tick(now)
    assert svc.episode_state == "exploring" and svc.step == 0
    wall_s = 100.0 / real_time_factor * 0.25  # 100 steps' worth
    while now < t0 + wall_s:
        now += svc.tick_period_s + 0.001  # a tick comes a little after its period, as the service loop's do
        svc.on_tick(now)
    assert abs(svc.step - (now - t0) * real_time_factor / 0.25) <= 1.0
    before = svc.step
    now += 10.0  # the host stalls for 10 s
    svc.on_tick(now)
    svc.on_tick(now + 0.021)
    assert svc.step - before <= 4 + 1  # at most one tick's worth, then on from now


@pytest.mark.parametrize("backend", ["kinematic", "mujoco"])
def test_the_sims_odometry_carries_the_twist_the_robot_moved_with(backend):
    """``odom``'s ``twist`` (docs/messages.md; the ros2_bridge sends the robot's own, and ``export-bag`` and Foxglove
    show it) was always [0, 0] from the sim, the MuJoCo LIMO's included, while the robot drove. It is the mean
    body-frame twist of the step just run, from odometry, as an odometry node differentiating poses reports it."""
    from services.sim import SimService

    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 0}
    params = {"start_delay_s": 0.0, "backend": backend}
    svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), params))
    out: list[tuple[str, Message]] = []
    svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(svc.check_output(topic, msg)), type(msg))))  # type: ignore[method-assign]
    svc.on_tick(time.monotonic())  # step 0 goes out: at rest
    for _ in range(4):
        svc.advance(VelocityCommand(0.3, 0.5))
    odoms = [m for topic, m in out if topic == "odom"]
    assert [m.step for m in odoms] == [0, 1, 2, 3, 4] and odoms[0].twist == VelocityCommand()
    before, last = odoms[-2].pose, odoms[-1].pose
    c, s = math.cos(before.yaw_rad), math.sin(before.yaw_rad)
    forward_m = c * (last.x_m - before.x_m) + s * (last.y_m - before.y_m)
    assert last.x_m != before.x_m
    assert odoms[-1].twist.linear_mps == pytest.approx(forward_m / 0.25) == pytest.approx(0.3, abs=0.01)
    assert odoms[-1].twist.angular_radps == pytest.approx((last.yaw_rad - before.yaw_rad) / 0.25) == pytest.approx(0.5, abs=0.01)
    svc.publish_step()  # a lockstep re-publish of the same step carries the same twist
    assert [m for topic, m in out if topic == "odom"][-1] == odoms[-1]


def test_the_sims_status_says_one_published_step_whenever_it_is_asked():
    """A status query is answered on Zenoh's thread while the step runs: ``advance`` counted the step (and its path)
    before it published the step's odometry, so a status asked in between said step k+1 with the pose and twist of
    step k. Asked at any moment of a step (here: whenever the simulator's odometry is read), it says a step as
    published, its odometry's pose and twist, and the path driven to it."""
    from services.sim import SimService

    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 0}
    svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0}))
    odoms: dict[int, OdometryMsg] = {}
    paths: dict[int, float] = {}

    def publish(topic: str, msg: Message, robot: str | None = None) -> None:
        if topic == "odom":
            odoms[msg.step] = msg  # type: ignore[attr-defined]
            paths[msg.step] = svc.path_length_m  # type: ignore[attr-defined]

    svc.publish = publish  # type: ignore[method-assign]
    statuses: list[EpisodeStatusMsg] = []
    odometry = svc.sim.odometry

    def odometry_asked_meanwhile() -> Pose2D:
        statuses.append(svc.episode_status())  # a status query, answered on another thread mid-step
        return odometry()

    svc.sim.odometry = odometry_asked_meanwhile  # type: ignore[method-assign]
    svc.on_tick(time.monotonic())  # step 0 goes out
    for _ in range(4):
        svc.advance(VelocityCommand(0.3, 0.5))
    statuses.append(svc.episode_status())
    assert sorted(odoms) == [0, 1, 2, 3, 4] and len(statuses) > 10
    for status in statuses:
        published = odoms[status.step]
        assert (status.pose, status.twist, status.path_length_m) == (published.pose, published.twist, paths[status.step])


def test_lockstep_sim_stepped_ahead_publishes_what_it_would_have_computed():
    """The sim steps ahead on the planner's provisional command while the map travels; with the same
    final command it publishes the stored result, with another it steps afresh. Either way every scan
    and odometry is the one of a sim that never stepped ahead (LiDAR noise on: the noise generator too)."""
    from cso_runtime.geometry import VelocityCommand
    from cso_runtime.occupancy import OccupancyMap
    from services.sim import SimService

    def sim_service():
        ctx = ServiceContext("sim", "r0", {"lockstep": True, "scene": "generated:small:1:0", "seed": 3}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
        ctx.exploration.sensor.range_noise_std_m = 0.02
        svc = SimService(ctx)
        out: list[tuple[str, Message]] = []
        svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(svc.check_output(topic, msg)), type(msg))))  # type: ignore[method-assign]
        svc.episode = 7  # both runs one episode id
        svc.on_tick(time.monotonic())  # starting -> exploring: step 0 goes out
        return svc, out

    ahead, out_ahead = sim_service()
    plain, out_plain = sim_service()
    empty_map = OccupancyMap(ahead.sim.plan.geometry)
    commands = [VelocityCommand(0.3, 0.1), VelocityCommand(0.0, 0.78), VelocityCommand(0.5, -0.2), VelocityCommand(0.2, 0.0)]
    provisional_differs = {2}  # at step 2 the verdict brings a new goal: another command than the provisional one
    reused = 0
    for k, cmd in enumerate(commands):
        m = MapMsg.of(k, empty_map, 7)
        provisional = VelocityCommand(-0.1, 0.3) if k in provisional_differs else cmd
        for svc, msgs in ((ahead, (CmdVelMsg(k, provisional, "ahead"), m, CmdVelMsg(k, cmd))), (plain, (m, CmdVelMsg(k, cmd)))):
            for msg in msgs:
                topic = "map" if isinstance(msg, MapMsg) else ("cmd_vel_ahead" if msg.reason == "ahead" else "cmd_vel")
                if topic == "cmd_vel" and svc is ahead and ahead.ahead is not None and ahead.ahead[1] == cmd:
                    reused += 1
                svc.on_message("r0", topic, decode(encode(msg), type(msg)), time.monotonic())
        assert ahead.step == plain.step == k + 1
    assert reused == len(commands) - len(provisional_differs)
    for topic in ("scan", "odom"):
        a = [encode(m) for t, m in out_ahead if t == topic]
        b = [encode(m) for t, m in out_plain if t == topic]
        assert len(a) == len(commands) + 1 and a == b, topic


def test_a_lockstep_step_re_published_carries_the_same_scan_and_changes_no_later_one():
    """A step whose answer is lost is re-published after ``lockstep_timeout_s``. With LiDAR noise on, the 2D simulator
    drew new noise for the re-published scan (a second scan of the same step, which a mapper that lost the first
    integrated instead), and the draw shifted the noise of every later scan: one lost message changed the episode."""
    from cso_runtime.geometry import VelocityCommand
    from cso_runtime.occupancy import OccupancyMap
    from services.sim import SimService

    def sim_service():
        ctx = ServiceContext("sim", "r0", {"lockstep": True, "scene": "generated:small:1:0", "seed": 3}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
        ctx.exploration.sensor.range_noise_std_m = 0.02
        svc = SimService(ctx)
        out: list[tuple[str, Message]] = []
        svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(svc.check_output(topic, msg)), type(msg))))  # type: ignore[method-assign]
        svc.episode = 7
        svc.on_tick(time.monotonic())  # step 0 goes out
        return svc, out

    retried, out_retried = sim_service()
    plain, out_plain = sim_service()
    empty_map = OccupancyMap(plain.sim.plan.geometry)
    for k, cmd in enumerate([VelocityCommand(0.3, 0.1), VelocityCommand(0.0, 0.78), VelocityCommand(0.5, -0.2)]):
        if k == 1:  # step 1's map never came: the step is published again
            retried.on_tick(time.monotonic() + 2 * retried.params.lockstep_timeout_s)
            assert retried.timeouts == 1
        for svc in (retried, plain):
            svc.on_message("r0", "map", decode(encode(MapMsg.of(k, empty_map, 7)), MapMsg), time.monotonic())
            svc.on_message("r0", "cmd_vel", decode(encode(CmdVelMsg(k, cmd)), CmdVelMsg), time.monotonic())
    scans_retried = [m for t, m in out_retried if t == "scan"]
    scans_plain = [m for t, m in out_plain if t == "scan"]
    assert [m.step for m in scans_retried] == [0, 1, 1, 2, 3]
    assert encode(scans_retried[1]) == encode(scans_retried[2])  # the same scan of step 1, twice
    assert [encode(m) for m in scans_retried[:2] + scans_retried[3:]] == [encode(m) for m in scans_plain]


def test_the_sim_rejects_and_counts_a_map_of_another_grid_instead_of_crashing():
    """A mapper with its own grid (or another robot's map on a shared network) used to raise in the coverage
    measure: the sim exited, was restarted three times and the run stopped. Such a map is a counted rejection,
    and the episode goes on with the maps of the scene's grid; ``up`` refuses a mapper grid next to a sim."""
    from cso_runtime.config import ConfigError
    from cso_runtime.geometry import GridGeometry
    from cso_runtime.occupancy import OccupancyMap
    from cso_runtime.run_profile import load_profile
    from services.sim import SimService

    for lockstep in (True, False):
        ctx = ServiceContext("sim", "r0", {"lockstep": lockstep, "scene": "generated:small:1:0"}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
        svc = SimService(ctx)
        svc.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
        svc.on_tick(time.monotonic())
        other = OccupancyMap(GridGeometry(0.05, (400, 400), origin_x_m=-10.0, origin_y_m=-10.0))
        svc.on_message("r0", "map", decode(encode(MapMsg.of(0, other, svc.episode)), MapMsg), time.monotonic())
        assert svc.rejected == {"map": 1} and svc.running
        own = OccupancyMap(svc.sim.plan.geometry)
        svc.on_message("r0", "map", decode(encode(MapMsg.of(0, own, svc.episode)), MapMsg), time.monotonic())
        assert svc.rejected == {"map": 1}
    with pytest.raises(ConfigError, match="services.mapper.resolution_m: an explicit grid is for a real robot's arena"):
        load_profile("lockstep", {}, settings={"services.mapper.resolution_m": 0.05, "services.mapper.width_m": 20, "services.mapper.height_m": 20})


def test_the_sims_start_waits_for_its_own_robots_services_not_anothers():
    """On a network of several robots the sim of r1 took r0's mapper, frontier and planner tokens for its own
    and started step 0 with none of its services up. Its own tokens count, and a policy of any robot (one policy
    server may serve several)."""
    from types import SimpleNamespace

    from services.sim import SimService

    profile = {"lockstep": True, "scene": "generated:small:1:0", "services": {n: {} for n in ("sim", "mapper", "frontier", "policy", "planner")}}
    svc = SimService(ServiceContext("sim", "r1", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0}))

    def token(robot: str, name: str, kind: str = "PUT") -> None:
        svc.on_alive(SimpleNamespace(key_expr=f"cso/{robot}/alive/{name}", kind=f"SampleKind.{kind}"))

    for name in ("mapper", "frontier", "policy", "planner"):
        token("r0", name)
    assert svc.missing_services() == {"mapper", "frontier", "planner"}  # r0's policy may serve r1 too
    for name in ("mapper", "frontier", "planner"):
        token("r1", name)
    assert svc.missing_services() == set()
    token("r0", "mapper", "DELETE")  # r0's mapper going away is not r1's
    token("r0", "policy", "DELETE")
    assert svc.missing_services() == {"policy"}


def test_the_episode_is_reported_under_the_method_that_decided_its_goals():
    """A policy server shared by several robots may run another method than a robot's profile names: the sim
    labelled the episode's status and result with its profile's method, whoever decided."""
    from services.sim import SimService

    ctx = ServiceContext("sim", "r0", {"lockstep": False, "scene": "generated:small:1:0", "method": "cso"}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
    svc = SimService(ctx)
    assert svc.episode_status().method == "cso"
    svc.take_goal(GoalMsg(0, True, 1.0, 1.0, 0, 1.0, 2.0, "greedy-dist"))
    assert svc.episode_status().method == "greedy-dist" and svc.decisions == 1


def _without_timing(msgs: list[Message]) -> list[bytes]:
    """Encodings with the build time (wall clock) zeroed: what two runs of the same inputs share."""
    out = []
    for m in msgs:
        if isinstance(m, FrontiersMsg):
            m.build_ms = 0.0
        out.append(encode(m))
    return out


def test_lockstep_frontier_never_decides_on_a_map_of_the_episode_before():
    """After a sim restart (a new episode id) maps of the old episode may still be in flight. The
    frontier service rejects them (counted) and decides the new episode exactly as a fresh service
    does, whether the new episode shows itself first by its map of step 0 or by its odometry (both
    carry the episode id)."""
    ex_a, ex_b = _explorer_at(6), _explorer_at(0)  # episode A is well explored, B has just started
    a, b = 11, 22

    def map_of(ex: Explorer, step: int, episode: int) -> MapMsg:
        return MapMsg.of(step, ex.map, episode)

    _, odom_b0, _ = _inputs(ex_b, 0)
    odom_b0 = dataclasses.replace(odom_b0, episode=b)
    odom_b1 = OdometryMsg(1, odom_b0.stamp_s + 0.25, odom_b0.pose, episode=b)
    goal_b0 = _far_goal(ex_b.observe(), 0)
    fb_b0 = PlannerFeedbackMsg(0, "following", "command", goal_step=0)
    episode_b = [map_of(ex_b, 0, b), odom_b0, goal_b0, fb_b0, odom_b1, map_of(ex_b, 1, b)]
    stale = {1: map_of(ex_a, 7, a), 4: map_of(ex_a, 1, a)}  # in flight from A, among B's first messages
    for map_first in (True, False):
        svc, out = _service(FrontierService, lockstep=True)
        _, odom_a0, _ = _inputs(ex_a, 0)
        odom_a0 = dataclasses.replace(odom_a0, episode=a)
        _feed(svc, map_of(ex_a, 0, a))
        _feed(svc, odom_a0)
        _feed(svc, _far_goal(ex_a.observe(), 0))
        for k in (1, 2):
            _feed(svc, PlannerFeedbackMsg(k - 1, "following", "command", goal_step=0))
            _feed(svc, OdometryMsg(k, odom_a0.stamp_s + 0.25 * k, odom_a0.pose, episode=a))
            _feed(svc, map_of(ex_a, k, a))
        assert [m.step for t, m in out if t == "frontiers"] == [0, 1, 2] and svc.done_step == 2
        out.clear()
        order = episode_b if map_first else [episode_b[1], episode_b[0], *episode_b[2:]]
        for i, msg in enumerate(order):
            if i in stale:
                _feed(svc, stale[i])
            _feed(svc, msg)
        fresh, fresh_out = _service(FrontierService, lockstep=True)
        for msg in order:
            _feed(fresh, msg)
        got = [m for t, m in out if t == "frontiers"]
        assert [(m.step, m.decide) for m in got] == [(0, True), (1, False)]
        assert _without_timing(got) == _without_timing([m for t, m in fresh_out if t == "frontiers"])
        assert svc.rejected.get("map") == 2


def test_planner_publishes_the_path_with_each_new_plan_and_otherwise_at_its_period():
    """``path`` is a view: with a period longer than the run it goes out only with the two new plans
    (steps 0 and 6), each the full plan; with period 0 after every command, the path still ahead."""
    ex = _explorer_at(0)
    rare, out_rare = _service(PlannerService, lockstep=True, params={"path_period_s": 3600.0})
    every, out_every = _service(PlannerService, lockstep=True, params={"path_period_s": 0.0})
    for k in range(12):
        _, odom, scan = _inputs(ex, k)
        if k in (0, 6):
            obs = ex.observe()
            verdict, goal = frontiers_from_observation(k, "no_goal", obs, 1.0), _far_goal(obs, k)
        else:
            verdict, goal = FrontiersMsg(k, False), None
        for svc in (rare, every):
            for msg in (odom, scan, verdict, goal):
                if msg is not None:
                    _feed(svc, msg)
        ex.sim.step([m for t, m in out_every if t == "cmd_vel"][-1].command)
        ex._integrate()
    rare_paths = [m for t, m in out_rare if t == "path"]
    every_paths = [m for t, m in out_every if t == "path"]
    assert [m.step for m in rare_paths] == [0, 6]
    assert [m.step for m in every_paths] == list(range(12))
    for p in rare_paths:
        assert np.array_equal(p.path_xy_m, every_paths[p.step].path_xy_m)
    assert len(every_paths[5].path_xy_m) < len(every_paths[0].path_xy_m)  # what is still ahead shrinks


def test_sim_rejects_a_map_of_another_episode():
    """The sim's referee measures only maps of its own episode: a map in flight from an earlier
    episode (fully explored, say) neither ends this one nor enters its coverage curve."""
    from cso_runtime.occupancy import OccupancyMap
    from services.sim import SimService

    ctx = ServiceContext("sim", "r0", {"lockstep": True, "scene": "generated:small:1:0", "seed": 3}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
    svc = SimService(ctx)
    out: list[tuple[str, Message]] = []
    svc.publish = lambda topic, msg, robot=None: out.append((topic, svc.check_output(topic, msg)))  # type: ignore[method-assign]
    svc.on_tick(time.monotonic())  # step 0 goes out
    g = svc.sim.plan.geometry
    everything = np.zeros(g.shape, dtype=np.int8)  # every cell explored and free: coverage 100 %
    nothing = OccupancyMap(g).to_occupancy_grid()
    svc.on_message("r0", "map", MapMsg.from_grid(0, g, everything, svc.episode + 1), time.monotonic())
    assert svc.running and svc.coverage_curve == [] and svc.rejected == {"map": 1}
    svc.on_message("r0", "map", MapMsg.from_grid(0, g, nothing, svc.episode), time.monotonic())
    assert svc.running and svc.coverage_curve == [0.0]
    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand()), time.monotonic())
    assert svc.step == 1 and svc.status_msg().last_step == 1  # `status` shows the step the sim is at
    svc.on_message("r0", "map", MapMsg.from_grid(1, g, everything, svc.episode + 1), time.monotonic())
    assert svc.running and svc.rejected == {"map": 2}
    svc.on_message("r0", "map", MapMsg.from_grid(1, g, everything, svc.episode), time.monotonic())
    assert not svc.running and svc.coverage_curve[-1] > 99.0  # its own full map does end it


def test_restarted_mapper_keeps_the_cached_map_of_its_episode_only():
    """A restarted mapper continues from the referee's cached map; the map it publishes carries the
    episode id; the first scan of another episode starts a new map instead of adding to the old one."""
    from cso_runtime.occupancy import OccupancyMap, integrate_observation
    from services.mapper import MapperService

    ex = _explorer_at(4)
    grid = ex.map.to_occupancy_grid()
    grid[grid < 0] = 0  # the cached map knows every cell (more than one scan can see)
    cached = MapMsg.from_grid(4, ex.map.geometry, grid, 5)
    ex.advance()
    _, _, scan = _inputs(ex, 5)
    for episode in (5, 6):
        mapper, out = _service(MapperService, lockstep=True)
        mapper.restore(cached)
        _feed(mapper, ScanMsg(5, scan.scan, scan.sensor_pose, episode))
        published = [m for t, m in out if t == "map"]
        assert [(m.step, m.episode) for m in published] == [(5, episode)]
        expected = OccupancyMap.from_occupancy_grid(cached.grid, cached.geometry) if episode == 5 else OccupancyMap(cached.geometry)
        integrate_observation(expected, scan.sensor_pose, scan.scan, ExplorationConfig())
        assert np.array_equal(published[0].grid, expected.to_occupancy_grid())
        assert (published[0].grid < 0).any() == (episode == 6)  # episode 6: the old cells are gone


def test_the_mapper_service_counts_a_scan_it_cannot_integrate_and_publishes_no_map():
    """A scan that reaches the mapper with a pose that is not finite, or beams that do not fan out (a message from
    another tool, a service fed in-process): a counted rejection, no map, no exception out of the handler."""
    from cso_runtime.geometry import GridGeometry, LaserScan
    from services.mapper import MapperService

    mapper, out = _service(MapperService, lockstep=False, params={"resolution_m": 0.1, "width_m": 5.0, "height_m": 5.0})
    ranges = np.full(11, 1.0, dtype=np.float32)
    mapper.on_message("r0", "scan", ScanMsg(1, LaserScan(-0.5, 0.1, 0.1, 3.0, ranges), Pose2D(float("nan"), 2.0, 0.0), 1), time.monotonic())
    mapper.on_message("r0", "scan", ScanMsg(2, LaserScan(-0.5, 0.0, 0.1, 3.0, ranges), Pose2D(2.0, 2.0, 0.0), 1), time.monotonic())
    assert mapper.rejected == {"scan": 2} and out == [] and not mapper.map.explored.any()
    mapper.on_message("r0", "scan", ScanMsg(3, LaserScan(-0.5, 0.1, 0.1, 3.0, ranges), Pose2D(2.0, 2.0, 0.0), 1), time.monotonic())
    assert [(t, m.step) for t, m in out] == [("map", 3)] and mapper.map.geometry == GridGeometry(0.1, (50, 50))


def test_a_new_episode_maps_the_arena_its_clock_announces():
    """A restarted ROS bridge announces an arena around where the robot is now: the mapper kept the first
    episode's grid, and a robot 15 m from its old start mapped nothing. A profile's own grid stays."""
    from cso_runtime.geometry import GridGeometry
    from services.mapper import MapperService

    first, second = GridGeometry(0.05, (200, 200), -5.0, -5.0), GridGeometry(0.05, (200, 200), 10.0, -5.0)
    mapper, _ = _service(MapperService, lockstep=False)

    def _feed_clock(step: int, arena: GridGeometry, episode: int) -> None:
        mapper.on_message("r0", "clock", decode(encode(ClockMsg(step, 0.25 * step, arena, episode)), ClockMsg), time.monotonic())

    _feed_clock(0, first, 1)
    assert mapper.map.geometry == first
    _feed_clock(1, first, 1)
    _feed_clock(0, second, 2)
    assert mapper.map.geometry == second and mapper.episode == 2
    fixed, _ = _service(MapperService, lockstep=False, params={"resolution_m": 0.1, "width_m": 10.0, "height_m": 10.0})
    fixed.on_message("r0", "clock", decode(encode(ClockMsg(0, 0.0, second, 2)), ClockMsg), time.monotonic())
    assert fixed.map.geometry == GridGeometry(0.1, (100, 100))


def test_the_mapper_service_builds_the_explorers_map_with_a_forward_narrow_sensor():
    """The depth camera 0.103 m ahead of the centre: the mapper service clears the robot's footprint (the
    robot's centre being the scan's sensor pose less the profile's mount) exactly as the in-process
    Explorer does, so lockstep through Zenoh stays step for step the in-process episode."""
    from cso_runtime.config import SensorConfig
    from services.mapper import MapperService

    sensor = dataclasses.replace(SensorConfig.preset("depth"), mount_x_m=0.103)
    cfg = ExplorationConfig(sensor=sensor)
    ex = Explorer(KinematicSimulator(two_rooms(), sensor, seed=0), cfg)
    ex.reset(0)
    obs = ex.observe()
    ex.apply_goal(obs, make_policy("greedy-dist").select(obs))
    mapper, out = _service(MapperService, lockstep=True, exploration=cfg)
    mapper.on_message("r0", "clock", ClockMsg(0, 0.0, ex.map.geometry, 1), time.monotonic())
    _feed(mapper, ScanMsg(0, ex.last_scan, ex.sim.sensor_pose(), 1))
    start = ex.sim.odometry()
    for step in range(1, 9):
        ex.advance()
        _feed(mapper, ScanMsg(step, ex.last_scan, ex.sim.sensor_pose(), 1))
    assert ex.sim.odometry() != start
    centre = ex.map.geometry.world_to_cell(*ex.sim.odometry().xy)
    assert ex.map.explored[centre]  # the footprint, which the camera never sees
    assert np.array_equal(out[-1][1].grid, ex.map.to_occupancy_grid())


def test_message_trace_records_each_handled_input_and_feeds_the_hop_breakdown(tmp_path):
    """``CSO_TRACE_DIR`` tracing: the service loop's dispatch records (callback, handler start, handler
    end) per input, rejected payloads are not traced, and ``bench_runtime.hop_breakdown`` turns the
    services' traces into per-hop transit / queue+decode / work."""
    import importlib.util
    import json
    from pathlib import Path

    from services.common import MessageTrace, _dispatch

    svc, _ = _service(PlannerService, lockstep=True)
    svc.trace = MessageTrace(tmp_path / "planner.trace.json")
    ex = _explorer_at(0)
    _, odom, _ = _inputs(ex, 0)
    received_s = time.monotonic()
    _dispatch(svc, "cso/r0/odom", encode(odom), received_s)
    _dispatch(svc, "cso/r0/odom", b"junk", received_s)
    svc.trace.write()
    events = json.loads((tmp_path / "planner.trace.json").read_text())
    assert len(events) == 1 and svc.rejected == {"odom": 1}
    kind, topic, step, got_s, start_s, done_s = events[0]
    assert (kind, topic, step) == ("handle", "odom", 0) and got_s == received_s <= start_s <= done_s

    spec = importlib.util.spec_from_file_location("bench_runtime", Path(__file__).parents[1] / "benchmarks" / "bench_runtime.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    ms = 1e-3
    traces = {  # one keep-goal step 0: every hop 1 ms transit, 0.5 ms queue+decode, then 2 ms of work
        "sim": [["put", "scan", 0, 0.0, 0.0, 10], ["handle", "cmd_vel", 0, 11.5 * ms, 12 * ms, 12 * ms], ["put", "scan", 1, 14 * ms, 14 * ms, 10]],
        "mapper": [["handle", "scan", 0, 1 * ms, 1.5 * ms, 3 * ms], ["put", "map", 0, 3.5 * ms, 3.5 * ms, 10]],
        "frontier": [["handle", "map", 0, 4.5 * ms, 5 * ms, 6 * ms], ["put", "frontiers", 0, 7 * ms, 7 * ms, 10]],
        "planner": [["handle", "frontiers", 0, 8 * ms, 8.5 * ms, 9 * ms], ["put", "cmd_vel", 0, 10.5 * ms, 10.5 * ms, 10]],
    }
    for name, ev in traces.items():
        (tmp_path / f"{name}.trace.json").write_text(json.dumps(ev))
    hops = bench.hop_breakdown(tmp_path)
    keep = hops["keep_goal_steps"]
    assert keep["steps"] == 1 and hops["decision_steps"]["steps"] == 0
    assert keep["sim->mapper transit"] == keep["mapper->frontier transit"] == keep["planner->sim transit"] == 1.0
    assert keep["frontier->planner queue+decode"] == 0.5 and keep["mapper work"] == keep["planner work"] == 2.0
    assert keep["sim work"] == 2.0 and keep["step"] == 14.0
    assert hops["first_steps"]["step 0 ms"] == 14.0 and "step 1 ms" not in hops["first_steps"]


def test_service_profile_is_written_into_a_new_folder_and_a_failure_is_only_logged(tmp_path, caplog):
    """``CSO_PROFILE_DIR`` may name a folder that does not exist yet; a profile that cannot be written
    is logged, never raised (it is written while the service stops)."""
    import cProfile
    import pstats

    from services.common import write_profile

    prof = cProfile.Profile()
    prof.enable()
    sorted(range(100))
    prof.disable()
    path = tmp_path / "new" / "folder" / "mapper.prof"
    write_profile([prof, cProfile.Profile()], path)  # a network thread's profiler that never ran adds nothing
    assert pstats.Stats(str(path)).total_calls > 0
    (tmp_path / "taken").write_text("a file where the folder should be")
    with caplog.at_level("ERROR"):
        write_profile([prof], tmp_path / "taken" / "mapper.prof")
    assert "cannot write the profile" in caplog.text


def test_service_profile_covers_handlers_run_on_the_network_thread(tmp_path):
    """In lockstep the handlers run on Zenoh's thread, which the main thread's profiler does not follow:
    ``CSO_PROFILE_DIR`` profiles them with a profiler of their own, merged into the service's file."""
    import cProfile
    import pstats

    from services.common import write_profile

    svc, inputs, _ = _service_inputs()
    svc.network_profile = cProfile.Profile()
    inputs.go_direct()
    main = cProfile.Profile()
    main.enable()
    network = threading.Thread(target=lambda: [inputs.on_sample(_Sample(k)) for k in range(3)])
    network.start()
    network.join()
    main.disable()
    assert svc.steps == [0, 1, 2]
    path = tmp_path / "recorder.prof"
    write_profile([main, svc.network_profile], path)
    handled = {(func[2], stat[0]) for func, stat in pstats.Stats(str(path)).stats.items() if func[2] == "on_message"}
    assert handled == {("on_message", 3)}  # every handler call, each counted once
    write_profile([main], tmp_path / "main_only.prof")  # what the main thread's profiler alone saw
    assert "on_message" not in {func[2] for func in pstats.Stats(str(tmp_path / "main_only.prof")).stats}


class _Recorder(Service):
    """Records the steps of the odometry it handles; raises on ``fail_at``."""

    name = "recorder"
    inputs = {"odom": OdometryMsg}

    def __init__(self, ctx: ServiceContext, fail_at: int = -1):
        super().__init__(ctx)
        self.steps: list[int] = []
        self.fail_at = fail_at

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        assert isinstance(msg, OdometryMsg)
        if msg.step == self.fail_at:
            raise RuntimeError(f"bug at step {msg.step}")
        self.steps.append(msg.step)


class _Sample:
    """What Zenoh hands the subscriber callback: a key expression and a payload."""

    def __init__(self, step: int):
        self.key_expr = "cso/r0/odom"
        self.payload = self
        self._bytes = encode(OdometryMsg(step, 0.25 * step, Pose2D(0.0, 0.0, 0.0)))

    def to_bytes(self) -> bytes:
        return self._bytes


def _service_inputs(fail_at: int = -1) -> tuple[_Recorder, ServiceInputs, threading.Event]:
    ctx = ServiceContext("recorder", "r0", {"lockstep": True}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    svc, stop = _Recorder(ctx, fail_at), threading.Event()
    return svc, ServiceInputs(svc, stop), stop


def test_inputs_are_queued_until_start_then_handled_on_arrival_in_order():
    svc, inputs, _ = _service_inputs()
    inputs.on_sample(_Sample(0))
    inputs.on_sample(_Sample(1))
    assert svc.steps == [] and inputs.queue.qsize() == 2  # before start: queued for the loop's thread
    inputs.go_direct()
    assert svc.steps == [0, 1] and inputs.queue.qsize() == 0  # what was queued, first and in order
    inputs.on_sample(_Sample(2))
    assert svc.steps == [0, 1, 2]  # then each input at once, on the thread that received it


def test_a_handler_that_raises_on_the_network_thread_stops_the_service():
    svc, inputs, stop = _service_inputs(fail_at=1)
    inputs.go_direct()
    inputs.on_sample(_Sample(0))
    inputs.on_sample(_Sample(1))
    assert stop.is_set() and isinstance(inputs.failure, RuntimeError)  # run_service re-raises it
    inputs.on_sample(_Sample(2))
    assert svc.steps == [0]  # nothing is handled once the service is stopping


def test_the_sim_serves_the_newest_map_of_its_episode_for_a_restarted_mapper():
    """The map cache (what a restarted mapper restores, ``cache/map``) is the referee's: it follows the
    steps of the episode, a late map does not replace a newer one, and a map of another episode (still in
    flight from before a restart) is rejected, counted and never cached. The launcher receives no maps."""
    from types import SimpleNamespace

    from cso_runtime.launcher import LAUNCHER_INPUTS
    from services.sim import SimService

    assert "map" not in LAUNCHER_INPUTS and SimService.serves_latest == ("map", "planner_contacts", "planner_plan", "planner_state")
    ctx = ServiceContext("sim", "r0", {"scene": "generated:small:1:0"}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    sim = SimService(ctx)
    sim.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
    sim.episode_state, sim.episode = "exploring", 1
    geom = sim.sim.plan.geometry

    def cached() -> MapMsg | str:
        replies: list[tuple[str, bytes]] = []
        query = SimpleNamespace(reply=lambda key, payload: replies.append((key, payload)), reply_err=lambda payload: replies.append(("error", payload)))
        sim.answer_cache_query("map", query)
        assert len(replies) == 1
        key, payload = replies[0]
        assert key in ("error", "cso/r0/cache/map")
        return payload.decode() if key == "error" else decode(payload, MapMsg)

    assert cached() == "no map yet"  # an answer all the same: a restarted mapper need not wait for one
    empty = np.full(geom.shape, -1, np.int8)
    for step in (5, 7, 6):
        _feed(sim, MapMsg.from_grid(step, geom, empty, 1))
    assert (cached().step, cached().episode) == (7, 1)  # a late step 6 does not replace step 7
    _feed(sim, MapMsg.from_grid(9, geom, empty, 3))
    assert (cached().step, cached().episode) == (7, 1) and sim.rejected == {"map": 1}
    sim.episode = 2  # the next episode: its first map replaces the newer step of the old one
    _feed(sim, MapMsg.from_grid(0, geom, empty, 2))
    assert (cached().step, cached().episode) == (0, 2)


@pytest.mark.parametrize("period_s, expected_steps", [(3600.0, [0, 3]), (0.0, [0, 1, 2, 3])])
def test_sim_status_goes_out_at_its_period_and_always_at_the_end(period_s, expected_steps):
    """``episode/status`` is a view: with a period longer than the run it goes out once, then with the
    end of the episode (the launcher's cue to write the results); with period 0 after every map."""
    from services.sim import SimService

    ctx = ServiceContext("sim", "r0", {"scene": "generated:small:1:0"}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"status_period_s": period_s})
    sim = SimService(ctx)
    out: list[tuple[str, Message]] = []
    sim.publish = lambda topic, msg, robot=None: out.append((topic, msg))  # type: ignore[method-assign]
    sim.episode_state = "exploring"
    g = sim.sim.plan.geometry
    unknown, everything = np.full(g.shape, -1, np.int8), np.zeros(g.shape, np.int8)
    for step, grid in ((0, unknown), (1, unknown), (2, unknown), (3, everything)):
        sim.step = step
        sim.publish_step()  # as ``advance`` does: the status says the step published
        _feed(sim, MapMsg.from_grid(step, g, grid, sim.episode))
    statuses = [m for t, m in out if t == "episode_status"]
    assert [m.step for m in statuses] == expected_steps
    assert statuses[-1].state == "done" and [m.state for m in statuses[:-1]] == ["exploring"] * (len(statuses) - 1)


def test_frontier_layer_helper_computes_what_the_service_would_and_is_dropped_when_it_dies():
    """The helper process gives exactly ``frontier_layer`` (with and without excluded cells), so a
    service's Observation is the one-process Observation; a dead helper is noticed, and the service
    computes the layer itself from then on."""
    from cso_runtime.observation import ObservationBuilder
    from services.frontier_layer import FrontierLayerWorker

    ex = _explorer_at(6)
    builder = ObservationBuilder()
    worker = FrontierLayerWorker(builder.frontier_config.entropy_window_m, timeout_s=20.0)
    try:
        deadline = time.monotonic() + 60.0
        while not worker.submit(ex.map, None):  # False until the helper has started
            assert not worker.broken and time.monotonic() < deadline
            time.sleep(0.05)
        assert worker.result() is not None and worker.layers_computed == 1
        exclude = np.zeros(ex.map.geometry.shape, dtype=bool)
        exclude[: exclude.shape[0] // 2] = True
        for dead in (None, exclude):
            expected = builder.frontier_layer(ex.map, dead)
            assert worker.submit(ex.map, dead)
            got = worker.result()
            assert got is not None
            for a, b in [(got.frontier, expected.frontier), (got.entropy, expected.entropy), *zip(got.components, expected.components)]:
                assert a.dtype == b.dtype
                np.testing.assert_array_equal(a, b)
            obs = builder.build(ex.map, ex.sim.odometry(), exclude_frontier=dead, layer=lambda got=got: got)
            alone = builder.build(ex.map, ex.sim.odometry(), exclude_frontier=dead)
            assert [(c.goal_cell, c.distance_m, c.size_m, c.entropy) for c in obs.clusters] == [(c.goal_cell, c.distance_m, c.size_m, c.entropy) for c in alone.clusters]
        assert worker.layers_computed == 3
        worker.proc.kill()
        worker.proc.join(timeout=10.0)
        assert not worker.submit(ex.map, None) and "exited" in worker.broken
    finally:
        worker.close()
    assert not worker.proc.is_alive()


def test_a_frontier_layer_helper_that_dies_just_before_a_new_map_shape_is_a_lost_helper_not_a_failed_decision():
    """``submit`` sent a new map shape's shared arrays to the helper unguarded (``_map_shape``): a helper that died
    after ``usable`` looked (the first map, a new grid) raised BrokenPipeError out of the decision's handler. It is now
    given up as a lost helper (the service computes the layer itself and starts a new helper), as a failed layer send is."""
    from cso_runtime.observation import ObservationBuilder
    from services.frontier_layer import FrontierLayerWorker

    ex = _explorer_at(6)
    worker = FrontierLayerWorker(ObservationBuilder().frontier_config.entropy_window_m, timeout_s=HANG_DEADLINE_S)
    try:
        assert worker.wait_ready(HANG_DEADLINE_S), worker.broken
        worker.proc.kill()
        worker.proc.join(timeout=HANG_DEADLINE_S)
        worker.proc.is_alive = lambda: True  # type: ignore[method-assign]  # its end not noticed yet: the moment between
        assert not worker.submit(ex.map, None) and "cannot reach the helper" in worker.broken
    finally:
        del worker.proc.is_alive
        worker.close()
    assert not worker.proc.is_alive()


def test_warm_up_starts_the_helper_and_leaves_no_trace_in_the_episode():
    """``warm_up`` (run before the liveliness token) waits for the frontier service's helper and builds
    a practice Observation through it, and the planner plans once: nothing is published, no decision
    state is kept, and the episode's first decision is built by the ready helper, as in one process."""
    # Not about the deadlines: the helper's start and answers wait for as long as a loaded host needs.
    frontier, out = _service(FrontierService, lockstep=True, params={"helper_start_s": HANG_DEADLINE_S, "helper_reply_s": HANG_DEADLINE_S})
    planner, planner_out = _service(PlannerService, lockstep=True)
    try:
        frontier.warm_up()
        planner.warm_up()
        w = frontier.layer_worker
        assert w is not None and w.ready and not w.broken and w.layers_computed == 0 and frontier.decisions_built == 0
        assert not out and not planner_out and frontier.goal is None and frontier.path_nodes == [] and frontier.dead is None
        assert planner.planner.status == PlannerStatus.IDLE and planner.cmd_step == -1
        ex = _explorer_at(0)
        m, odom, _ = _inputs(ex, 0)
        _feed(frontier, odom)
        _feed(frontier, m)
        assert [(t, msg.step) for t, msg in out] == [("frontiers", 0), ("distance_map", 0)] and out[0][1].decide
        assert w.layers_computed == 1 and frontier.decisions_built == 1  # the first decision's layer: the helper's
        got, expected = observation_from_frontiers(out[0][1]), ex.observe()
        key = [(tuple(int(i) for i in c.goal_cell), c.distance_m, c.size_m) for c in got.clusters]
        assert key and key == [(tuple(int(i) for i in c.goal_cell), c.distance_m, c.size_m) for c in expected.clusters]
    finally:
        frontier.shutdown()
    assert not w.proc.is_alive()


def test_a_frontier_layer_helper_whose_service_is_gone_as_it_starts_exits_quietly():
    """The frontier service stopped (its launcher killed) while its layer helper still imported: the helper's "ready"
    met a closed pipe and its BrokenPipeError traceback landed in the frontier's log (found by a fault-injection soak).
    It now exits quietly, as it does when the pipe closes while it waits for a request. Run in a process of its own:
    the helper ignores SIGINT and watches its parent (``worker_init``)."""
    code = "from multiprocessing import Pipe\nfrom services.frontier_layer import worker_main\nservice_end, helper_end = Pipe()\nservice_end.close()\nworker_main(helper_end)\n"
    r = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr


def test_the_warm_ups_practice_layer_may_take_as_long_as_the_helpers_start_not_a_decisions_reply_deadline():
    """The practice layer pays the helper's first calls, which a loaded host stretched past the 2 s a decision waits
    for a layer (``helper_reply_s``): the warm-up gave its just-started helper up ("no layer for request 1 within 2.0
    s") and the service's first tick counted a helper death. The practice layer now waits as long as the helper's
    start (``helper_start_s``); the decisions' deadline is unchanged. A reply deadline no helper can meet shows it."""
    frontier, _ = _service(FrontierService, lockstep=True, params={"helper_start_s": HANG_DEADLINE_S, "helper_reply_s": 1e-9})
    try:
        frontier.warm_up()
        w = frontier.layer_worker
        assert w is not None and w.ready and not w.broken, w and w.broken
        assert w.timeout_s == 1e-9  # a decision's deadline again
        frontier.on_tick(time.monotonic())
        assert frontier.layer_worker is w and frontier.status_msg().counters == {"layer_helper_deaths": 0, "layer_helper_restarts": 0}
    finally:
        frontier.shutdown()
    assert not w.proc.is_alive()


def test_a_frontier_layer_helper_that_dies_is_replaced_a_bounded_number_of_times_and_the_decisions_stay_the_same(caplog):
    """A killed layer helper was not replaced: the frontier service computed every layer itself from then on (slower),
    with one warning and nothing in its status. Its next tick now notices, says so, counts it in its status
    (``layer_helper_deaths``, ``layer_helper_restarts``) and starts a new helper, whose decisions are the one-process
    ones; a helper that dies as soon as it starts is replaced at most ``helper_max_restarts`` times."""
    import logging

    caplog.set_level(logging.INFO, logger="cso.frontier")
    # A lost helper is a killed one here, never a late one: its start and answers wait for as long as a loaded host needs.
    params = {"helper_start_s": HANG_DEADLINE_S, "helper_reply_s": HANG_DEADLINE_S, "helper_max_restarts": 2}
    frontier, out = _service(FrontierService, lockstep=True, params=params)
    alone, alone_out = _service(FrontierService, lockstep=True, params={"layer_helper": False})
    first = second = None
    try:
        frontier.warm_up()
        first = frontier.layer_worker
        assert first is not None and first.ready
        first.proc.kill()
        first.proc.join(timeout=10.0)
        frontier.on_tick(time.monotonic())
        second = frontier.layer_worker
        assert second is not None and second is not first and not first.proc.is_alive()
        assert frontier.status_msg().counters == {"layer_helper_deaths": 1, "layer_helper_restarts": 1}
        assert any(r.levelno == logging.WARNING and r.getMessage().startswith("frontier layer helper lost (the helper process exited (code -9)): started a new one") for r in caplog.records)
        # The lost helper's own line said "not used from now on" just before the new one was started: it says it was lost.
        said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert f"frontier layer helper (pid {first.proc.pid}) lost: the helper process exited (code -9)" in said, said
        assert not any("from now on" in line for line in said), said
        assert second.wait_ready(HANG_DEADLINE_S)
        ex = _explorer_at(0)
        m, odom, _ = _inputs(ex, 0)
        for svc in (frontier, alone):
            _feed(svc, odom)
            _feed(svc, m)
        assert second.layers_computed == 1 and frontier.layers_by_helpers() == 1  # the new helper's layer
        (got, _), (expected, _) = out, alone_out
        assert got[1].decide and expected[1].decide
        for name, array in expected[1].arrays.items():
            np.testing.assert_array_equal(got[1].arrays[name], array)
        assert len(got[1].clusters) == len(expected[1].clusters) > 0
        for a, b in zip(got[1].clusters, expected[1].clusters):
            assert a.keys() == b.keys()
            for key in a:
                np.testing.assert_array_equal(a[key], b[key])
        for _ in range(3):  # a helper that dies at once, again and again: two restarts, then the layers are computed here
            w = frontier.layer_worker
            w.proc.kill()
            w.proc.join(timeout=10.0)
            frontier.on_tick(time.monotonic())
        assert frontier.helper_given_up and frontier.status_msg().counters == {"layer_helper_deaths": 3, "layer_helper_restarts": 2}
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "after 2 restarts: no new one" in errors[0], errors
        frontier.on_tick(time.monotonic())
        assert frontier.status_msg().counters["layer_helper_deaths"] == 3  # counted once
    finally:
        frontier.shutdown()
        alone.shutdown()
    assert not first.proc.is_alive() and not second.proc.is_alive() and not frontier.layer_worker.proc.is_alive()


def test_a_frontier_layer_helper_that_never_starts_is_said_and_given_up_not_waited_for_silently(caplog, monkeypatch):
    """A layer helper hung in its start (here stopped, SIGSTOP, before it could say it had started) was waited for by the
    warm-up (``helper_start_s``) and then never mentioned again: no warning, nothing in the status, never counted lost
    nor replaced (only a helper that exited or missed a reply was), while the service computed every layer itself for
    good. The warm-up now says it (a warning, and the status's reason while it lasts) and goes on; the decisions go on
    meanwhile, computed here; ``helper_start_limit_s`` after its spawn the helper is given up as hung, as a lost one:
    said, counted and replaced, and the reason clears."""
    import logging
    import os
    import signal

    import services.frontier as frontier_module
    from services.frontier_layer import FrontierLayerWorker

    hung: list[FrontierLayerWorker] = []

    class HungAtStart(FrontierLayerWorker):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            os.kill(self.proc.pid, signal.SIGSTOP)  # long before its imports are done: it never says it has started
            hung.append(self)

    monkeypatch.setattr(frontier_module, "FrontierLayerWorker", HungAtStart)
    caplog.set_level(logging.INFO, logger="cso.frontier")
    params = {"helper_start_s": 0.2, "helper_start_limit_s": 60.0, "helper_reply_s": HANG_DEADLINE_S, "helper_max_restarts": 1}
    frontier, out = _service(FrontierService, lockstep=True, params=params)
    warnings = lambda: [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]  # noqa: E731
    try:
        t0 = time.monotonic()
        frontier.warm_up()
        assert time.monotonic() - t0 < HANG_DEADLINE_S
        (w,) = hung
        assert not w.ready and not w.broken and not w.conn.poll(0), w.broken  # never started, still waited for
        (said,) = warnings()
        assert said.startswith(f"frontier layer helper (pid {w.proc.pid}) has not started ") and "the layers are computed in this process until it does" in said, said
        status = frontier.status_msg()
        assert status.state == "running" and status.reason == f"layer helper (pid {w.proc.pid}) not started after 0.2 s: layers computed here; given up at 60 s", status.reason
        frontier.on_tick(time.monotonic())  # within its limit: still waited for, said once
        assert frontier.layer_worker is w and len(warnings()) == 1 and frontier.status_msg().counters == {"layer_helper_deaths": 0, "layer_helper_restarts": 0}
        ex = _explorer_at(0)
        m, odom, _ = _inputs(ex, 0)
        _feed(frontier, odom)
        _feed(frontier, m)
        assert [msg.decide for topic, msg in out if topic == "frontiers"] == [True] and frontier.layers_by_helpers() == 0  # computed here
        monkeypatch.undo()  # the next helper starts
        frontier.on_tick(w.started_s + 60.0)  # its limit is up: given up as hung, counted and replaced
        assert w.broken.startswith("not started 60.0 s after it was spawned") and not w.proc.is_alive(), w.broken
        second = frontier.layer_worker
        assert second is not None and second is not w and frontier.status_msg().counters == {"layer_helper_deaths": 1, "layer_helper_restarts": 1}
        assert f"frontier layer helper (pid {w.proc.pid}) lost: not started 60.0 s after it was spawned (hung?)" in warnings(), warnings()
        assert any(line.startswith("frontier layer helper lost (not started 60.0 s") and "started a new one" in line for line in warnings()), warnings()
        assert frontier.status_msg().reason == ""
        assert second.wait_ready(HANG_DEADLINE_S)
        frontier.on_tick(time.monotonic())
        assert frontier.layer_worker is second and frontier.status_msg().reason == "" and len(warnings()) == 3
    finally:
        frontier.shutdown()
    assert not w.proc.is_alive() and not frontier.layer_worker.proc.is_alive()


def test_a_frontier_layer_helper_that_hangs_in_the_warm_ups_practice_layer_is_said_and_the_service_goes_on(caplog, monkeypatch):
    """A helper that started and then hung (stopped, SIGSTOP) before the warm-up's practice layer: the warm-up waits
    ``helper_start_s`` for its answer, no more, says the helper lost, computes the practice here and goes on; the next
    tick counts it and replaces it, as any helper lost."""
    import logging
    import os
    import signal

    import services.frontier as frontier_module
    from services.frontier_layer import FrontierLayerWorker

    class HangsOnceStarted(FrontierLayerWorker):
        def wait_ready(self, timeout_s: float) -> bool:
            started = super().wait_ready(HANG_DEADLINE_S)  # started, however loaded the host
            if started:
                os.kill(self.proc.pid, signal.SIGSTOP)
            return started

    monkeypatch.setattr(frontier_module, "FrontierLayerWorker", HangsOnceStarted)
    caplog.set_level(logging.INFO, logger="cso.frontier")
    frontier, _ = _service(FrontierService, lockstep=True, params={"helper_start_s": 0.5, "helper_reply_s": 0.5, "helper_max_restarts": 1})
    try:
        frontier.warm_up()
        w = frontier.layer_worker
        assert w is not None and w.ready and w.broken.startswith("no answer to mapping the shared arrays"), w and w.broken
        said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert said == [f"frontier layer helper (pid {w.proc.pid}) lost: {w.broken}"], said
        monkeypatch.undo()
        frontier.on_tick(time.monotonic())
        assert frontier.layer_worker is not w and frontier.status_msg().counters == {"layer_helper_deaths": 1, "layer_helper_restarts": 1}
    finally:
        frontier.shutdown()
    assert not w.proc.is_alive()


@pytest.mark.parametrize("stopping", [True, False], ids=["service-stopping", "helper-died"])
def test_a_frontier_helper_lost_to_the_services_stop_is_no_warning(caplog, stopping):
    """The launcher's SIGTERM reaches a frontier service and its layer helper together (one process group): a
    service stopped while it waited for its helper logged "frontier layer helper not used from now on" and named
    the lost helper again in its last line, a failure in a log that only saw a stop. Lost while the service is
    stopping, the helper is now a plain stop (and the warm-up ends at once); a helper that dies while the service
    runs is still a warning, named in the last line."""
    import logging
    import os
    import signal

    frontier, out = _service(FrontierService, lockstep=True, params={"helper_start_s": 60.0})
    frontier.stop_event = threading.Event()

    def stop_while_warming_up() -> None:  # as the signal that stops the group: the service records it, the helper dies
        deadline = time.monotonic() + 30.0
        while frontier.layer_worker is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert frontier.layer_worker is not None
        if stopping:
            frontier.stop_signal = signal.SIGTERM
        os.kill(frontier.layer_worker.proc.pid, signal.SIGTERM)

    thread = threading.Thread(target=stop_while_warming_up)
    caplog.set_level(logging.DEBUG, logger="cso.frontier")
    t0 = time.monotonic()
    thread.start()
    try:
        frontier.warm_up()
        thread.join()
        assert time.monotonic() - t0 < 30.0  # not the 60 s of helper_start_s
        w = frontier.layer_worker
        assert w is not None and w.broken and not w.ready and not out
    finally:
        thread.join()
        frontier.shutdown()
    assert not w.proc.is_alive()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    (last,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("frontier layers:")]
    if stopping:
        assert warnings == [] and w.lost_to_stop and last == "frontier layers: 0 by the helper process, 0 here", (warnings, last)
    else:
        assert len(warnings) == 1 and warnings[0].startswith(f"frontier layer helper (pid {w.proc.pid}) lost: "), warnings
        assert not w.lost_to_stop and last.endswith(f"({w.broken})"), last


@pytest.mark.parametrize("method, grids", [("greedy-dist", ()), ("utility", ()), ("cso", ("traversable",))])
def test_the_policy_service_decodes_the_grids_its_method_reads(method, grids):
    """A decision message is decoded for what the goal selector reads (``GoalSelector.grids``): no grid
    for the baselines, the traversable grid (stuck mask) for the learned policy."""
    ctx = ServiceContext("policy", "r0", {"lockstep": True, "method": method}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    policy = PolicyService(ctx)
    view = policy.inputs["frontiers"]
    assert view.READS_GRIDS == grids and view.READS_CLUSTERS and PolicyService.inputs["frontiers"] is FrontiersMsg
    obs = _explorer_at(3).observe()
    msg = decode(encode(frontiers_from_observation(0, "no_goal", obs, 1.0)), view)
    assert set(msg.arrays) == set(grids)


def test_episode_watch_tells_a_new_episode_from_a_late_message_of_an_ended_one():
    from services.common import EpisodeWatch

    watch = EpisodeWatch()
    assert watch.classify(11, 0, progressed=False) == "same"  # the first episode seen
    assert watch.classify(11, 40, progressed=True) == "same"
    assert watch.classify(22, 3, progressed=True) == "new"  # its step 0 never came: the id says it all
    assert watch.classify(11, 41, progressed=True) == "ended"  # still in flight from before the restart
    assert watch.classify(0, 0, progressed=True) == "same"  # no id, while ids are in use: never a new episode
    assert watch.current == 22
    legacy = EpisodeWatch()  # publishers without ids: step 0 after later steps is a new episode, as before ids
    assert [legacy.classify(0, s, progressed=p) for s, p in ((0, False), (5, True), (0, True))] == ["same", "same", "new"]


def test_real_time_policy_serves_a_new_episode_whose_step_0_it_never_saw():
    """A real-time frontier service decides on the newest map, so a new episode's first decision input is rarely
    that of step 0. The policy used to take a new episode only from step 0: every decision of the new one
    (steps below the last one it answered) was dropped without a count, and the robot got no goal. It now sees
    the new episode by its id, and a decision input still in flight from the ended episode is rejected, counted."""
    policy, out = _service(PolicyService, lockstep=False, params={"method": "greedy-dist"})
    obs = _explorer_at(0).observe()
    a, b = 11, 22
    for step in range(0, 41, 10):
        _feed(policy, frontiers_from_observation(step, "timeout", obs, 1.0, episode=a))
    assert [(m.step, m.episode) for t, m in out if t == "goal"] == [(s, a) for s in range(0, 41, 10)]
    out.clear()
    _feed(policy, frontiers_from_observation(3, "no_goal", obs, 1.0, episode=b))  # B's step 0 went by unseen
    _feed(policy, frontiers_from_observation(41, "timeout", obs, 1.0, episode=a))  # late, from A
    _feed(policy, frontiers_from_observation(9, "timeout", obs, 1.0, episode=b))
    assert [(m.step, m.episode) for t, m in out if t == "goal"] == [(3, b), (9, b)]
    assert policy.rejected == {"frontiers": 1}


def test_real_time_planner_commands_a_new_episode_whose_first_odometry_was_lost():
    """The planner took a new episode only from odometry of step 0; with that message lost, every command of the
    new episode waited for its steps to pass the old episode's last (no command, no word). It now starts afresh
    at the new episode's first message, and a goal still in flight from the ended episode is not planned."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    a, b = 11, 22
    _feed(planner, frontiers_from_observation(0, "no_goal", obs, 1.0, episode=a))
    _feed(planner, dataclasses.replace(_far_goal(obs, 0), episode=a))
    for step in range(6):
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose, episode=a))
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose, episode=a))
    assert planner.planner.status.value == "following" and planner.cmd_step == 5
    out.clear()
    for step in (1, 2):  # episode B; its step 0 was lost
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose, episode=b))
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose, episode=b))
    _feed(planner, frontiers_from_observation(6, "no_goal", obs, 1.0, episode=a))  # late, from A
    _feed(planner, dataclasses.replace(_far_goal(obs, 6), episode=a))
    cmds = [m for t, m in out if t == "cmd_vel"]
    assert [(c.step, c.reason) for c in cmds] == [(1, "idle"), (2, "idle")]  # a fresh planner: no goal in B yet
    assert planner.planner.status.value == "idle" and planner.rejected == {"frontiers": 1, "goal": 1}


def test_real_time_frontier_service_takes_a_new_episode_from_a_map_past_step_0():
    """A new episode's first map may come at any step in real time (the mapper publishes at its period): it starts
    the episode (it was rejected as a map of another episode until odometry of step 0 came), and the frontier
    service stamps the episode's id on what it decides, for the policy and the planner."""
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    ex = _explorer_at(0)
    _, odom0, _ = _inputs(ex, 0)
    a, b = 11, 22
    _feed(frontier, dataclasses.replace(odom0, episode=a))
    _feed(frontier, MapMsg.of(0, ex.map, a))
    _feed(frontier, dataclasses.replace(_far_goal(ex.observe(), 0), episode=a))
    for step in range(1, 5):
        _feed(frontier, PlannerFeedbackMsg(step - 1, "following", "command", goal_step=0))
        _feed(frontier, OdometryMsg(step, odom0.stamp_s + 0.25 * step, odom0.pose, episode=a))
        _feed(frontier, MapMsg.of(step, ex.map, a))
    assert frontier.done_step == 4 and {m.episode for t, m in out} == {a}
    out.clear()
    _feed(frontier, MapMsg.of(3, ex.map, b))
    _feed(frontier, OdometryMsg(3, odom0.stamp_s, odom0.pose, episode=b))
    got = [(t, m.step, m.episode) for t, m in out]
    assert got == [("frontiers", 3, b), ("distance_map", 3, b)] and out[0][1].decide and out[0][1].reason == "no_goal"
    assert frontier.rejected == {}


def test_sim_rejects_a_goal_of_another_episode():
    """A goal still in flight from before a restart is not this episode's decision (it would be counted, or end
    the episode as 'no frontier left')."""
    from services.sim import SimService

    ctx = ServiceContext("sim", "r0", {"lockstep": False, "scene": "generated:small:1:0", "seed": 3}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})
    svc = SimService(ctx)
    svc.publish = lambda topic, msg, robot=None: svc.check_output(topic, msg)  # type: ignore[method-assign]
    svc.on_tick(time.monotonic())  # the episode starts
    assert svc.running
    svc.on_message("r0", "goal", GoalMsg(4, True, episode=svc.episode + 1), time.monotonic())
    assert svc.decisions == 0 and svc.episode_state != "done" and svc.rejected == {"goal": 1}
    svc.on_message("r0", "goal", GoalMsg(4, True, 1.0, 1.0, 0, 1.0, episode=svc.episode), time.monotonic())
    assert svc.decisions == 1 and svc.goal_xy == [1.0, 1.0]


def test_a_shared_policy_server_answers_each_robots_status_with_that_robots_own_counts():
    """One policy server for several robots: each robot's status (``status --robot ID``) counts the inputs of that
    robot alone, rejected and handled (it counted every robot's together, so one robot's bad link showed on all)."""
    from services.common import _dispatch

    policy, _ = _service(PolicyService, lockstep=False, params={"method": "greedy-dist", "serve_all_robots": True})
    obs = _explorer_at(0).observe()
    for step in range(3):
        for robot in ("a", "b"):
            _dispatch(policy, RobotKeys(robot).frontiers, encode(frontiers_from_observation(step, "timeout", obs, 1.0)), time.monotonic())
    _dispatch(policy, RobotKeys("a").frontiers, b"\x00not msgpack", time.monotonic())
    _dispatch(policy, RobotKeys("a").frontiers, encode(frontiers_from_observation(3, "timeout", obs, 1.0, episode=5)), time.monotonic())
    _dispatch(policy, RobotKeys("a").frontiers, encode(frontiers_from_observation(4, "timeout", obs, 1.0, episode=6)), time.monotonic())
    _dispatch(policy, RobotKeys("a").frontiers, encode(frontiers_from_observation(5, "timeout", obs, 1.0, episode=5)), time.monotonic())  # ended
    a, b = (policy.robot_status(r, policy.robots[r]) for r in ("a", "b"))
    assert (a.rejected, a.processed, a.last_step) == ({"frontiers": 2}, 6, 4)
    assert (b.rejected, b.processed, b.last_step) == ({}, 3, 2)
    assert policy.status_msg().rejected == {"frontiers": 2} and policy.status_msg().processed == 9  # the process: every robot


class _Publisher:
    """A declared Zenoh publisher, minus Zenoh: says whether it was undeclared."""

    undeclared = False

    def undeclare(self) -> None:
        self.undeclared = True


def _liveliness(key: str, kind: str) -> object:
    """What Zenoh hands a liveliness subscriber's callback: a key and its kind (PUT: a token came, DELETE: it went)."""
    return types.SimpleNamespace(key_expr=key, kind=f"SampleKind.{kind}")


def _shared_policy_server(params: dict):
    """A ``serve_all_robots`` policy (greedy-dist) with ``params``, what it publishes, and ``send(robot, step, at_s)``:
    a decision input of episode 1 from ``robot``, received at ``at_s``."""
    from services.common import _dispatch

    policy, out = _service(PolicyService, lockstep=False, params={"method": "greedy-dist", "serve_all_robots": True, **params})
    obs = _explorer_at(0).observe()

    def send(robot: str, step: int, at_s: float) -> None:
        _dispatch(policy, RobotKeys(robot).frontiers, encode(frontiers_from_observation(step, "timeout", obs, 1.0, episode=1)), at_s)

    return policy, out, send


def test_a_shared_policy_server_forgets_a_robot_gone_for_forget_robot_after_s_and_serves_it_afresh(caplog):
    """A ``serve_all_robots`` server kept what it knew of every robot it ever heard (its counts, its step guard's steps,
    the publisher of its goal key; its selector too while its frontier service's going went unseen), so a long
    deployment with robots coming and going grew without bound. A robot silent for ``forget_robot_after_s`` with no
    frontier service alive is forgotten, logged and counted in the status; one silent as long whose frontier service
    is alive (a paused run) is kept; a robot whose frontier service goes is forgotten at once; one that comes back is
    served afresh: its own counts only, and its steps taken from where it is now (one 700 steps on was held back as a
    leap)."""
    from services.common import _dispatch

    policy, out, send = _shared_policy_server({"forget_robot_after_s": 60.0})
    t0_s = time.monotonic()
    policy._other_policies.add("d")  # robot d's run has a policy of its own: heard, never served
    policy._on_alive(_liveliness(RobotKeys("c").alive("frontier"), "PUT"))  # robot c's run is alive
    for step in range(3):
        for robot in ("a", "b", "c", "d"):
            send(robot, step, t0_s + step)
    _dispatch(policy, RobotKeys("b").frontiers, b"\x00not msgpack", t0_s + 3.0)
    own_goal = policy._publishers["cso/r0/goal"] = _Publisher()  # as run_service declares it
    b_goal = policy._publishers[RobotKeys("b").goal] = _Publisher()  # as publish declared it for b's first goal
    assert set(policy.robots) == {"a", "b", "c"} and policy.processed_by_robot["d"] == 3

    # a and d were last heard at t0_s + 2, b at t0_s + 3: 59.5 s and 58.5 s of silence, clear of forget_robot_after_s.
    # (A tick at t0_s + 62, a's silence computed as exactly 60 s, came out above 60 for about one t0_s in five where
    # time.monotonic() is small, as on a CI host just booted: a was forgotten there and the test failed by chance.)
    policy.on_tick(t0_s + 2.0 + 59.5)
    assert set(policy.robots) == {"a", "b", "c"} and policy.status_msg().counters == {"robots_forgotten": 0}
    with caplog.at_level("INFO", logger="cso.policy"):
        policy.on_tick(t0_s + 3.0 + 61.0)
    assert set(policy.robots) == {"c"}, "a, b and d have been silent for forget_robot_after_s, c's run is alive"
    for robot in ("a", "b", "d"):
        assert robot not in policy.processed_by_robot and robot not in policy.rejected_by_robot and robot not in policy.step_guard.recent
        assert f"robot {robot}: nothing heard from it for 6" in caplog.text
    assert b_goal.undeclared and RobotKeys("b").goal not in policy._publishers and not own_goal.undeclared
    assert policy.status_msg().counters == {"robots_forgotten": 3} and "robot b" not in policy.reason

    policy._on_alive(_liveliness(RobotKeys("c").alive("frontier"), "DELETE"))  # c's run stops
    policy.on_tick(t0_s + 3.0 + 62.0)
    assert not policy.robots and "c" not in policy.processed_by_robot and policy.status_msg().counters == {"robots_forgotten": 4}

    # Robot b comes back (a network cut off for long), its run 700 steps on: served at once, with its own counts only.
    now_s = time.monotonic() + 100.0
    send("b", 700, now_s)
    assert [m.step for t, m in out if t == "goal"][-1] == 700
    b = policy.robot_status("b", policy.robots["b"])
    assert (b.rejected, b.processed, b.last_step) == ({}, 1, 700)


def test_a_shared_policy_server_keeps_a_robots_selector_through_a_restart_of_its_frontier_service(caplog):
    """A ``serve_all_robots`` server let a robot go at the first tick (0.2 s) after its frontier service's token went:
    when the launcher restarted a crashed frontier service (its back-off, then its start-up: seconds), the robot's
    selector, with its memory of past goals and its stuck mask, was lost mid-episode, where a robot with a policy of
    its own keeps it. A frontier service that goes while the rest of its run runs now has ``frontier_restart_grace_s``
    to come back and find the same selector; one gone longer is let go as before, and so is a robot whose whole run
    stops, at once."""
    policy, out, send = _shared_policy_server({"frontier_restart_grace_s": 30.0})
    t0_s = time.monotonic()
    for robot in ("a", "b"):  # two runs, each with its sim and its frontier service
        for service in ("sim", "frontier"):
            policy._on_alive(_liveliness(RobotKeys(robot).alive(service), "PUT"))
        for step in range(3):
            send(robot, step, t0_s + step)
    selectors = {robot: policy.robots[robot].selector for robot in ("a", "b")}

    for robot in ("a", "b"):  # both frontier services crash; their launchers restart them
        policy._on_alive(_liveliness(RobotKeys(robot).alive("frontier"), "DELETE"))
    policy.on_tick(t0_s + 3.0)
    policy.on_tick(t0_s + 3.0 + 29.0)
    assert set(policy.robots) == {"a", "b"} and policy.status_msg().counters == {"robots_forgotten": 0}
    policy._on_alive(_liveliness(RobotKeys("a").alive("frontier"), "PUT"))  # a's is back within the grace
    send("a", 3, t0_s + 3.0 + 29.5)
    assert policy.robots["a"].selector is selectors["a"] and [m.step for t, m in out if t == "goal"][-1] == 3
    with caplog.at_level("INFO", logger="cso.policy"):
        policy.on_tick(t0_s + 3.0 + 31.0)
    assert set(policy.robots) == {"a"} and policy.robots["a"].selector is selectors["a"]
    assert "robot b: its frontier service has been gone for 31 s" in caplog.text
    assert policy.status_msg().counters == {"robots_forgotten": 1}

    for service in ("frontier", "sim"):  # a's run stops: let go at the next tick, no grace
        policy._on_alive(_liveliness(RobotKeys("a").alive(service), "DELETE"))
    policy.on_tick(t0_s + 3.0 + 31.2)
    assert not policy.robots and policy.status_msg().counters == {"robots_forgotten": 2}
    assert not policy._frontier_gone_s and set(policy._services_alive) == {"b"}  # its sim runs on


def test_a_first_episode_with_ids_after_steps_without_ids_is_a_new_episode():
    """Publishers without ids (id 0: an external tool), then a sim with ids from step 0: before ids, step 0 started the
    new episode; the watch took the first id for the same episode, and the policy dropped every decision of the new
    one below the last step it had answered (no goal, no count) while the frontier service waited for its old step."""
    from services.common import EpisodeWatch

    watch = EpisodeWatch()
    assert [watch.classify(0, s, progressed=s > 0) for s in (0, 5)] == ["same", "same"]
    assert watch.classify(7, 0, progressed=True) == "new"
    fresh = EpisodeWatch()  # a fresh service whose first message has an id
    assert fresh.classify(7, 3, progressed=False) == "same"
    policy, out = _service(PolicyService, lockstep=False, params={"method": "greedy-dist"})
    obs = _explorer_at(0).observe()
    for step in range(0, 41, 10):
        _feed(policy, frontiers_from_observation(step, "timeout", obs, 1.0))
    out.clear()
    _feed(policy, frontiers_from_observation(0, "no_goal", obs, 1.0, episode=7))
    assert [(m.step, m.episode) for t, m in out if t == "goal"] == [(0, 7)]
    frontier, fout = _service(FrontierService, lockstep=True)
    ex = _explorer_at(0)
    m0, odom0, _ = _inputs(ex, 0)
    _feed(frontier, m0)
    _feed(frontier, odom0)
    _feed(frontier, _far_goal(ex.observe(), 0))
    for k in (1, 2):
        _feed(frontier, PlannerFeedbackMsg(k - 1, "following", "command", goal_step=0))
        _feed(frontier, OdometryMsg(k, odom0.stamp_s + 0.25 * k, odom0.pose))
        _feed(frontier, MapMsg.of(k, ex.map))
    fout.clear()
    _feed(frontier, dataclasses.replace(odom0, episode=7))
    _feed(frontier, MapMsg.of(0, ex.map, 7))
    assert [(m.step, m.decide, m.episode) for t, m in fout if t == "frontiers"] == [(0, True, 7)]


def test_real_time_frontier_service_keeps_its_decision_state_when_the_goal_of_step_0_comes_late():
    """Without ids (id 0) step 0 after later steps starts a new episode, as it did before ids, but only on odometry:
    in real time the policy's goal for the decision of step 0 comes after maps of later steps, and the frontier
    service took it for a new episode (its path nodes, dead frontiers and pending inputs forgotten)."""
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    ex = _explorer_at(0)
    m0, odom0, _ = _inputs(ex, 0)
    _feed(frontier, odom0)
    _feed(frontier, m0)
    for step in range(1, 4):
        _feed(frontier, OdometryMsg(step, odom0.stamp_s + 0.25 * step, odom0.pose))
        _feed(frontier, MapMsg.of(step, ex.map))
    assert [(m.step, m.decide) for t, m in out if t == "frontiers"] == [(0, True), (1, False), (2, False), (3, False)]
    _feed(frontier, _far_goal(ex.observe(), 0))  # the decision of step 0, answered late
    assert frontier.done_step == 3 and len(frontier.path_nodes) == 1 and frontier.goal is not None
    assert frontier.awaiting_goal_step is None


def test_a_restarted_service_whose_first_episode_is_the_new_one_survives_a_late_message_of_the_old():
    """A service restarted about when the sim was (a fresh EpisodeWatch) may hear the new episode B first and then a
    message of the episode before, A, that it never saw (a map, a goal computed late): A's id was taken for a new
    episode and B for an ended one, so every message of B was rejected until the next episode (no command, no
    decision). What comes straight from the referee (odometry, scans) names the episode being run."""
    ex = _explorer_at(0)
    obs = ex.observe()
    _, odom, scan = _inputs(ex, 0)
    a, b = 11, 22
    planner, out = _service(PlannerService, lockstep=False)
    for step in range(3):
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.25 * step, odom.pose, episode=b))
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose, episode=b))
    _feed(planner, frontiers_from_observation(40, "timeout", obs, 1.0, episode=a))  # late, from A
    _feed(planner, dataclasses.replace(_far_goal(obs, 40), episode=a))
    out.clear()
    _feed(planner, OdometryMsg(3, odom.stamp_s + 0.75, odom.pose, episode=b))
    _feed(planner, ScanMsg(3, scan.scan, scan.sensor_pose, episode=b))
    assert [(m.step, m.reason) for t, m in out if t == "cmd_vel"] == [(3, "idle")]
    _feed(planner, dataclasses.replace(_far_goal(obs, 41), episode=a))  # A has ended now
    assert planner.episodes.current == b and planner.rejected == {"goal": 1}
    frontier, fout = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    _, odom0, _ = _inputs(ex, 0)
    _feed(frontier, dataclasses.replace(odom0, episode=b))
    _feed(frontier, MapMsg.of(0, ex.map, b))
    _feed(frontier, MapMsg.of(7, _explorer_at(6).map, a))  # late, from A
    _feed(frontier, OdometryMsg(1, odom0.stamp_s + 0.25, odom0.pose, episode=b))
    _feed(frontier, MapMsg.of(1, ex.map, b))
    assert [(m.step, m.episode) for t, m in fout if t == "frontiers"] == [(0, b), (1, b)]


def test_lockstep_frontier_never_reads_a_planner_report_of_the_episode_before():
    """The frontier service decides step k on the planner's report after command k - 1. After a sim restart a report
    of the old episode for the same step may still be in flight (a blocked goal, say): it is rejected (counted), and
    the new episode is decided on its own planner's report, as a fresh service decides it."""
    ex_a, ex_b = _explorer_at(6), _explorer_at(0)
    a, b = 11, 22
    _, odom_a0, _ = _inputs(ex_a, 0)
    _, odom_b0, _ = _inputs(ex_b, 0)
    goal_b0 = dataclasses.replace(_far_goal(ex_b.observe(), 0), episode=b)
    episode_b = [
        MapMsg.of(0, ex_b.map, b),
        dataclasses.replace(odom_b0, episode=b),
        goal_b0,
        PlannerFeedbackMsg(0, "following", "command", goal_step=0, episode=b),
        OdometryMsg(1, odom_b0.stamp_s + 0.25, odom_b0.pose, episode=b),
        MapMsg.of(1, ex_b.map, b),
    ]
    svc, out = _service(FrontierService, lockstep=True)
    for msg in (MapMsg.of(0, ex_a.map, a), dataclasses.replace(odom_a0, episode=a), dataclasses.replace(_far_goal(ex_a.observe(), 0), episode=a)):
        _feed(svc, msg)
    out.clear()
    for i, msg in enumerate(episode_b):
        if i == 4:  # the old episode's report for step 0 (its goal had no path), just after the new one's
            _feed(svc, PlannerFeedbackMsg(0, "blocked", "command", set_goal_blocked=True, goal_step=0, episode=a))
        _feed(svc, msg)
    fresh, fresh_out = _service(FrontierService, lockstep=True)
    for msg in episode_b:
        _feed(fresh, msg)
    got = [m for t, m in out if t == "frontiers"]
    assert [(m.step, m.decide) for m in got] == [(0, True), (1, False)]  # the goal kept: the blocked report was A's
    assert _without_timing(got) == _without_timing([m for t, m in fresh_out if t == "frontiers"])
    assert svc.rejected == {"planner_feedback": 1}


def test_frontier_service_rejects_a_map_of_another_grid_within_an_episode():
    """A map of the episode on another grid (another robot's map, a mapper with a grid of its own, a forged one)
    ended a lockstep episode as 'no frontier left' at 28 % coverage: the frontier service decided on it (every
    cell explored, no frontier) while the sim rejected it. Now it is rejected too, counted and logged, and the
    episode's own map of that step is decided on as by a service that never saw it, in lockstep and real time."""
    from cso_runtime.geometry import GridGeometry

    ex = _explorer_at(0)
    _, odom0, _ = _inputs(ex, 0)
    e = 7
    other = GridGeometry(ex.map.geometry.resolution_m, (40, 30))
    foreign = MapMsg(1, other, np.ones(other.shape, bool), np.zeros(other.shape, bool), e)
    for lockstep in (True, False):
        services = [_service(FrontierService, lockstep=lockstep, params={"goal_wait_s": 30.0}) for _ in range(2)]
        for svc, out in services:
            _feed(svc, MapMsg.of(0, ex.map, e))
            _feed(svc, dataclasses.replace(odom0, episode=e))
            _feed(svc, dataclasses.replace(_far_goal(ex.observe(), 0), episode=e))
            _feed(svc, PlannerFeedbackMsg(0, "following", "command", goal_step=0, episode=e))
            _feed(svc, OdometryMsg(1, odom0.stamp_s + 0.25, odom0.pose, episode=e))
        (svc, out), (_, fresh_out) = services
        _feed(svc, foreign)
        assert svc.rejected == {"map": 1} and [m.step for t, m in out if t == "frontiers"] == [0], (lockstep, out)
        for s, _ in services:
            _feed(s, MapMsg.of(1, ex.map, e))
        got = [m for t, m in out if t == "frontiers"]
        assert [m.step for m in got] == [0, 1] and got[1].reason != "no_goal", got
        assert _without_timing(got) == _without_timing([m for t, m in fresh_out if t == "frontiers"])


def test_a_goal_for_a_step_no_decision_asked_for_is_rejected_not_followed():
    """Lockstep: a forged decided goal for a future step became the frontier service's decision; the planner's
    reports (about the real goal) then never matched it, and the episode stalled until ``lockstep_give_up_s`` with
    nothing naming the goal. A goal only ever answers a decision this service asked for: any other is rejected,
    counted, and the episode goes on."""
    ex = _explorer_at(0)
    svc, out = _service(FrontierService, lockstep=True)
    map0, odom0, _ = _inputs(ex, 0)
    _feed(svc, map0)
    _feed(svc, odom0)
    assert [(m.step, m.decide) for t, m in out if t == "frontiers"] == [(0, True)]
    _feed(svc, _far_goal(ex.observe(), 0))  # the policy's answer
    _feed(svc, _far_goal(ex.observe(), 2))  # forged: step 2, which no decision asked for
    ex.advance()
    map1, odom1, _ = _inputs(ex, 1)
    _feed(svc, PlannerFeedbackMsg(0, "following", "command", goal_step=0))
    _feed(svc, odom1)
    _feed(svc, map1)
    assert [m.step for t, m in out if t == "frontiers"] == [0, 1] and svc.done_step == 1
    assert svc.rejected == {"goal": 1}


def test_sim_ends_on_an_empty_goal_with_the_frontier_services_reason_or_without_it_after_its_wait():
    """An empty goal ends the episode no_frontier at its step; the result and status carry the frontier service's reason
    (``frontiers/ended_why``), heard before or after the goal. None heard: the episode ends without one once
    ``ended_why_wait_s`` has passed, and at once where no frontier service runs; nothing is measured meanwhile."""
    from cso_runtime.messages import EndedWhyMsg, GoalMsg
    from services.sim import SimService

    def sim(services: dict) -> tuple[SimService, list[tuple[str, Message]]]:
        profile = {"lockstep": False, "scene": "generated:small:1:0", "seed": 3, "services": services}
        svc = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0}))
        out: list[tuple[str, Message]] = []
        svc.publish = lambda topic, msg, robot=None: out.append((topic, svc.check_output(topic, msg)))  # type: ignore[method-assign]
        svc.services_ready_s = svc.started_s
        svc.on_tick(svc.started_s)  # step 0 goes out
        return svc, out

    pipeline = {"sim": {}, "mapper": {}, "frontier": {}, "policy": {}, "planner": {}}
    why = "no frontier left: the map has no open cell next to unknown space"
    for why_first in (True, False):
        svc, out = sim(pipeline)
        if why_first:
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode), time.monotonic())
            assert svc.running
        svc.on_message("r0", "goal", GoalMsg(0, True, episode=svc.episode), time.monotonic())
        if not why_first:
            assert svc.episode_state == "exploring" and not svc.running and svc.result is None  # waits for the reason
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode + 1), time.monotonic())  # another episode's
            assert svc.result is None
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode), time.monotonic())
        assert svc.result is not None and (svc.result.terminated_by, svc.result.ended_why, svc.result.steps) == ("no_frontier", why, 0)
        status = [m for t, m in out if t == "episode_status"][-1]
        assert (status.state, status.terminated_by, status.reason) == ("done", "no_frontier", why)  # type: ignore[attr-defined]

    svc, _ = sim(pipeline)
    svc.on_message("r0", "goal", GoalMsg(0, True, episode=svc.episode), time.monotonic())
    g = svc.sim.plan.geometry
    svc.on_message("r0", "map", MapMsg.from_grid(0, g, np.zeros(g.shape, dtype=np.int8), svc.episode), time.monotonic())
    svc.on_tick(time.monotonic() + svc.params.ended_why_wait_s / 2)
    assert svc.result is None and svc.coverage_curve == []  # the episode ended at the goal: its map is not measured
    svc.on_tick(time.monotonic() + svc.params.ended_why_wait_s)
    assert svc.result is not None and (svc.result.terminated_by, svc.result.ended_why, svc.fail_reason) == ("no_frontier", "", "")
    svc, _ = sim({})  # a sim started on its own (`service sim`), and no frontier service alive: nobody to wait for
    svc.on_message("r0", "goal", GoalMsg(0, True, episode=svc.episode), time.monotonic())
    assert svc.result is not None and svc.result.ended_why == ""


def test_a_shared_policy_server_keeps_a_robot_long_silent_through_the_grace_of_its_frontier_restart():
    """The grace of a restarted frontier service (``frontier_restart_grace_s``) did not hold for a robot that had been
    silent for ``forget_robot_after_s`` before (a robot standing without scans) or that is silent through the grace
    (its frontier service, its only input, is down) where ``forget_robot_after_s`` is the shorter: the silence check
    forgot it at the first tick after its frontier service went, its selector with it. A robot within its grace is left
    to the grace; once the grace is over without its frontier service, it is let go as before."""
    policy, _, send = _shared_policy_server({"forget_robot_after_s": 10.0, "frontier_restart_grace_s": 30.0})
    t0_s = time.monotonic()
    for service in ("sim", "frontier"):
        policy._on_alive(_liveliness(RobotKeys("a").alive(service), "PUT"))
    send("a", 0, t0_s)
    selector = policy.robots["a"].selector
    policy.on_tick(t0_s + 20.0)  # silent for 20 s, but its frontier service is alive: kept
    assert "a" in policy.robots
    policy._on_alive(_liveliness(RobotKeys("a").alive("frontier"), "DELETE"))  # it crashes; its launcher restarts it
    policy.on_tick(t0_s + 20.2)
    policy.on_tick(t0_s + 40.0)
    assert policy.robots["a"].selector is selector and policy.status_msg().counters == {"robots_forgotten": 0}
    policy._on_alive(_liveliness(RobotKeys("a").alive("frontier"), "PUT"))  # back within the grace
    send("a", 1, t0_s + 41.0)
    assert policy.robots["a"].selector is selector
    policy._on_alive(_liveliness(RobotKeys("a").alive("frontier"), "DELETE"))  # gone again, for good this time
    policy.on_tick(t0_s + 42.0)
    policy.on_tick(t0_s + 42.0 + 31.0)
    assert "a" not in policy.robots and policy.status_msg().counters == {"robots_forgotten": 1}


def test_a_status_read_while_the_state_is_set_never_shows_a_new_state_with_the_old_reason():
    """The status queryable answers on Zenoh's thread while the loop calls ``set_state``: a status read between any
    two instructions of ``set_state`` (traced one by one) shows the old pair or the new one, never half of each."""
    import sys

    svc, _ = _service(PlannerService, lockstep=False)
    svc.set_state("stale", "no odometry for 2 s")
    seen: set[tuple[str, str]] = set()

    def between_instructions(frame: types.FrameType, event: str, arg: object) -> object:
        if event == "opcode":
            status = svc.status_msg()
            seen.add((status.state, status.reason))
        return between_instructions

    def trace(frame: types.FrameType, event: str, arg: object) -> object:
        if frame.f_code is not Service.set_state.__code__:
            return None
        frame.f_trace_opcodes = True
        return between_instructions

    previous = sys.gettrace()
    sys.settrace(trace)
    try:
        svc.set_state("running", "paused by operator")
    finally:
        sys.settrace(previous)
    assert ("stale", "no odometry for 2 s") in seen and ("running", "paused by operator") in seen  # the trace saw both sides
    assert seen <= {("stale", "no odometry for 2 s"), ("running", "paused by operator")}, seen
    assert svc.status_msg().state == svc.state == "running" and svc.status_msg().reason == svc.reason == "paused by operator"


SLOW_TEARDOWN_SERVICE = '''
import atexit, os, sys, time
from pathlib import Path
from services.common import Service, service_main

class SlowToFree:
    """Freed as the interpreter tears down, slowly: as torch's modules were on 2 busy cores (1.5 to 3.4 s)."""
    def __del__(self):
        time.sleep(60)

KEPT = SlowToFree()
atexit.register(lambda: Path(os.environ["ATEXIT_MARK"]).write_text("ran"))

class Idle(Service):
    name = "idle"

if __name__ == "__main__":
    raise SystemExit(service_main(Idle))
'''


def test_a_service_ends_its_process_once_stopped_without_the_interpreters_teardown(tmp_path):
    """A service that has stopped cleanly ends its process at once (``exit_now``): the interpreter's teardown, which
    for the policy service (torch) took 1.5 to 3.4 s on a busy host and outlasted the launcher's stop timeout, is
    skipped (here an object that takes 60 s to free). Its exit code is 0, its log ends with its stop line, and what
    an exit does is still done: the atexit functions run, the trace and the profile are written."""
    import os
    import signal

    from cso_runtime.transport import free_tcp_port, loopback_endpoint

    script = tmp_path / "idle_service.py"
    script.write_text(SLOW_TEARDOWN_SERVICE)
    profile = tmp_path / "profile.yaml"
    profile.write_text("services: {}\n")
    log_path = tmp_path / "idle.log"
    env = {
        **os.environ, "PYTHONPATH": str(Path(__file__).parents[1]), "ATEXIT_MARK": str(tmp_path / "atexit"),
        "CSO_TRACE_DIR": str(tmp_path / "trace"), "CSO_PROFILE_DIR": str(tmp_path / "prof"),
    }  # fmt: skip
    argv = [sys.executable, str(script), "--config", str(profile), "--mode", "peer", "--listen", loopback_endpoint(free_tcp_port())]
    with log_path.open("w") as log_file:
        proc = subprocess.Popen(argv, env=env, stdout=log_file, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 60
            while "idle: up for robot" not in log_path.read_text():
                assert proc.poll() is None and time.monotonic() < deadline, log_path.read_text()
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            code = proc.wait(timeout=20)  # with the teardown: 60 s and more
        finally:
            proc.kill()
            proc.wait()
    lines = log_path.read_text().splitlines()
    assert code == 0 and lines[-1].endswith("INFO cso.service: idle: stopped"), lines[-5:]
    assert (tmp_path / "atexit").read_text() == "ran"
    assert (tmp_path / "trace" / "idle.trace.json").exists() and (tmp_path / "prof" / "idle.prof").exists()


def test_policy_service_refuses_an_entropy_window_its_weights_were_not_trained_with(monkeypatch, caplog):
    """A profile's ``exploration.frontier.entropy_window_m`` of 4 m served the weights trained with 2 m their entropy
    input doubled. The policy service now refuses at its start (exit 2), naming the parameter, both values and the
    ``--set`` that matches, as eval does (the same check: ``registry.input_mismatches``); the trained window loads, and
    another ``min_cluster_size_m`` loads with one warning in the service's log."""
    from cso_runtime.config import ConfigError, FrontierConfig
    from cso_runtime.learned.weights import weights_path
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    path = weights_path("cso", SensorConfig())
    wider = ExplorationConfig(frontier=FrontierConfig(entropy_window_m=4.0))
    with pytest.raises(ConfigError, match="^" + re.escape(f"the weights of cso ({path}) were trained with frontier.entropy_window_m 2 m, this run's is 4 m")):
        _service(PolicyService, lockstep=True, params={"method": "cso"}, exploration=wider)
    policy, _ = _service(PolicyService, lockstep=True, params={"method": "cso"}, exploration=ExplorationConfig(frontier=FrontierConfig(entropy_window_m=2.0)))
    assert policy.method == "cso"
    with caplog.at_level("WARNING"):
        _service(PolicyService, lockstep=True, params={"method": "cso"}, exploration=ExplorationConfig(frontier=FrontierConfig(min_cluster_size_m=0.5)))
    assert f"the weights of cso ({path}) were trained with frontier.min_cluster_size_m 0.3 m, this run's is 0.5 m" in caplog.text
