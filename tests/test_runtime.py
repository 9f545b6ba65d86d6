"""The Zenoh runtime: one service in-process over loopback, then real processes started by ``up``.

Every test uses free loopback ports with multicast scouting off, waits on conditions with deadlines,
and stops whatever it started in ``finally`` blocks (``down``, then SIGKILL of any pid left).
"""

from __future__ import annotations

import contextlib
import csv
import errno
import functools
import io
import json
import math
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from PIL import Image

import cso_runtime
from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import run_episode
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D
from cso_runtime.keys import TOPICS, RobotKeys
from cso_runtime.map_files import load_map, save_map
from cso_runtime.messages import (
    EPISODE_OVER,
    ClockMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    LauncherStatusMsg,
    MapMsg,
    OdometryMsg,
    PlannerContactsMsg,
    PlannerStateMsg,
    ScanMsg,
    ServiceStatusMsg,
    decode,
    encode,
)
from cso_runtime.policies import make_policy
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.status import query_status, render_table, save_map_main, status_main, status_of
from cso_runtime.supervision import pid_alive, python_module_argv
from cso_runtime.transport import (
    UNREACHABLE,
    ZENOH_CONFIG_ENV,
    TransportConfig,
    TransportError,
    free_tcp_port,
    loopback_endpoint,
    open_session,
)
from tests.conftest import HANG_DEADLINE_S, TerminalFile, unset_weights_env

REPO = Path(__file__).resolve().parents[1]
PROFILES = REPO / "cso_runtime" / "profiles"
SCENE = "generated:small:1:0"


def wait_for(cond: Callable[[], Any], timeout_s: float, what: str, period_s: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def cli(*args: str, cwd: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """The command as the installed ``cso-runtime`` script runs it: the working folder is not on its module path."""
    return subprocess.run([*python_module_argv("cso_runtime.cli"), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout_s)


def usage_error(*args: str) -> str:
    """The error that ``cso-runtime ARGS`` ends with (exit 2, no traceback), asked of its app in this process: a usage
    error comes before anything starts, where a command of its own costs a second or more of start-up."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    r = CliRunner().invoke(app, list(args))
    assert r.exit_code == 2 and not isinstance(r.exception, Exception) and "Traceback" not in r.stderr, (r.exit_code, r.exception, r.stderr)
    return r.stderr


def write_profile(tmp_path: Path, scene: str = SCENE, method: str = "greedy-dist", leave_out: tuple[str, ...] = (), **sim_params: Any) -> Path:
    """The lockstep profile on ``scene`` with ``method``, without the services in ``leave_out`` (not listed, no
    ``without:``: a profile that leaves them to another process)."""
    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    data["scene"] = scene
    data["method"] = method
    data["services"]["sim"].update(sim_params)
    for name in leave_out:
        del data["services"][name]
    path = tmp_path / "test_profile.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run_pids(runs: Path) -> list[int]:
    pids = []
    for f in runs.glob("*/run.json"):
        info = json.loads(f.read_text())
        pids.append(int(info["launcher_pid"]))
        pids += [int(s["pid"]) for s in info["services"].values() if s.get("pid")]
    return pids


def current_run_with_services(runs: Path, services: int) -> dict | None:
    """The runs folder's current-run file once it lists ``services`` spawned services (and its router's endpoints),
    else None. The launcher writes the run's run.json before this file, so run.json's pids say nothing of it."""
    path = runs / "current.json"
    if not path.exists():
        return None
    info = json.loads(path.read_text())
    spawned = [s for s in info["services"].values() if s.get("pid")]
    return info if info["endpoints"] and len(spawned) == services else None


def detached_launchers(runs: Path) -> list[int]:
    """The detached launchers (``python -m cso_runtime.launcher ... --run-dir RUNS/<run-id>``) of ``runs`` running now,
    found by their command lines (Linux /proc): one whose ``up --detach`` was killed before it wrote its run.json is in
    no run file, and its services with it."""
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = [os.fsdecode(a) for a in (proc / "cmdline").read_bytes().split(b"\0")]
            cwd = Path(os.readlink(proc / "cwd"))
        except OSError:  # gone meanwhile, or not ours to read
            continue
        if "cso_runtime.launcher" in argv and "--run-dir" in argv[:-1]:
            run_dir = cwd / argv[argv.index("--run-dir") + 1]
            if run_dir.parent.resolve() == runs.resolve():
                found.append(int(proc.name))
    return found


def kill_leftovers(runs: Path, extra: list[int] = (), exclude: int | None = None) -> list[int]:
    """SIGKILL what a test's runs left alive (each process's group), but ``exclude`` (a launcher run in the test's own
    process): the processes of its run files, and detached launchers that wrote none (``detached_launchers``)."""
    left = [p for p in dict.fromkeys([*run_pids(runs), *detached_launchers(runs), *extra]) if p != exclude and pid_alive(p)]
    for p in left:
        try:
            os.killpg(p, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
    return left


@functools.cache
def in_process_result(scene: str = SCENE, method: str = "greedy-dist"):
    """The in-process episode that a run of ``scene`` with ``method`` must match: seeded, so computed once per
    module (several tests compare with the same one; none changes it)."""
    plan = resolve_scenes(scene)[0].load()
    config = ExplorationConfig()
    return run_episode(KinematicSimulator(plan, seed=0), make_policy(method, seed=0, sensor=config.sensor), config, seed=0)


THREADS_OF_A_SESSION = """
import os, sys, time
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
a = free_tcp_port()  # s2 only connects: a second picked port could be taken by then
with open_session(TransportConfig(mode="peer", listen=[loopback_endpoint(a)])) as s1, \
        open_session(TransportConfig(mode="peer", connect=[loopback_endpoint(a)])) as s2:
    got = []
    sub = s1.declare_subscriber("t/x", lambda sample: got.append(1))
    deadline = time.monotonic() + 10
    while not got and time.monotonic() < deadline:
        s2.put("t/x", b"x")
        time.sleep(0.02)
    assert got, "no message crossed the link"
    print(" ".join(sorted(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))))
"""


@pytest.mark.parametrize("user_value", [None, "(app: (worker_threads: 2))"])
def test_zenoh_runs_on_one_thread_per_process_unless_the_user_says_otherwise(user_value):
    """Zenoh's runtimes share one worker thread (``ONE_ZENOH_THREAD``); a ``ZENOH_RUNTIME`` set by the
    user wins. Checked on the threads of a process with a live link, where Zenoh has started them all."""
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    if user_value is not None:
        env["ZENOH_RUNTIME"] = user_value
    out = subprocess.run([sys.executable, "-c", THREADS_OF_A_SESSION], env=env, capture_output=True, text=True, timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    zenoh_threads = {name for name in out.stdout.split() if name.split("-")[0] in ("app", "acc", "tx", "rx", "net")}
    if user_value is None:  # one worker (rx-0); tokio names its blocking-call threads rx-1, ... too
        # (Zenoh's own default also starts app-, acc-, net- and tx- threads)
        assert "rx-0" in zenoh_threads and all(name.startswith("rx-") for name in zenoh_threads)
    else:
        assert {"app-0", "app-1", "rx-0", "rx-1"} <= zenoh_threads


A_HANDLER_PUBLISHES_A_LARGE_MESSAGE = """
import sys, threading, time
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
size = int(sys.argv[1])
a = free_tcp_port()  # s2 only connects: a second picked port could be taken by then
with open_session(TransportConfig(mode="peer", listen=[loopback_endpoint(a)])) as s1, \
        open_session(TransportConfig(mode="peer", connect=[loopback_endpoint(a)])) as s2:
    big = s1.declare_publisher("t/big")
    asked = s1.declare_subscriber("t/ask", lambda sample: big.put(bytes(size)))
    got, sizes = threading.Event(), []
    sub = s2.declare_subscriber("t/big", lambda sample: (sizes.append(len(sample.payload.to_bytes())), got.set()))
    deadline = time.monotonic() + 20
    while not got.is_set() and time.monotonic() < deadline:
        s2.put("t/ask", b"?")
        got.wait(0.05)
    print(sizes[0] if sizes else "nothing")
"""


def test_a_handler_on_the_one_zenoh_thread_publishes_a_message_larger_than_the_links_queue():
    """In lockstep the services publish from their handlers, which run on the process's one Zenoh thread,
    the thread that also sends. A message larger than the link's queue (8 batches of 64 KB; a distance map
    of a 1000 x 1000 grid is 8 MB) must still go out rather than wait for that same thread. The receiving
    session shares the thread too (both in one process), the harder case."""
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    size = 8_000_000
    out = subprocess.run([sys.executable, "-c", A_HANDLER_PUBLISHES_A_LARGE_MESSAGE, str(size)], env=env, capture_output=True, text=True, timeout=60, cwd=REPO, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(size)]


# --- tier 2: one service in this process, a second session on explicit loopback endpoints --------


def test_mapper_service_over_loopback_maps_and_counts_rejections():
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(router) as session:
        maps: list[MapMsg] = []
        sub = session.declare_subscriber(keys.map, lambda s: maps.append(decode(s.payload.to_bytes(), MapMsg)))
        svc = MapperService(ServiceContext("mapper", "t1", {}, ExplorationConfig(), client, {"restore_timeout_s": 0.2}))

        def failing_warm_up() -> None:
            raise RuntimeError("warm-up failed")

        svc.warm_up = failing_warm_up  # only a speed-up: the service comes up all the same (logged)
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
        thread.start()
        try:
            wait_for(lambda: any(True for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5) if r.ok), 10, "the mapper's liveliness token")
            geom = GridGeometry(0.1, (40, 40))
            scan = LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.inf, np.float32))
            session.put(keys.clock, encode(ClockMsg(0, 0.0, geom)))
            session.put(keys.scan, b"not msgpack")
            nan_scan = ScanMsg(0, LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.nan, np.float32)), Pose2D(2, 2, 0))
            session.put(keys.scan, encode(nan_scan))  # encoding does not validate; decoding does
            session.put(keys.scan, encode(ScanMsg(0, scan, Pose2D(2.0, 2.0, 0.0))))
            wait_for(lambda: maps, HANG_DEADLINE_S, "a map")
            assert maps[-1].step == 0 and (maps[-1].grid == 0).sum() > 100
            # A get ends with its answers: a long timeout only bounds a hang (a loaded host answers late, not never).
            replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(keys.service_status("mapper"), timeout=HANG_DEADLINE_S) if r.ok]
            assert replies and replies[0].rejected.get("scan") == 2, replies
            late = [decode(r.ok.payload.to_bytes(), MapMsg) for r in session.get(keys.map, timeout=HANG_DEADLINE_S) if r.ok]
            assert late and late[0].step == 0, "a late joiner gets the latest map"
        finally:
            stop.set()
            thread.join(10)
            sub.undeclare()
    assert not thread.is_alive()


def test_a_service_whose_loop_is_stuck_in_a_handler_stops_answering_its_status(monkeypatch, caplog):
    """In real time a service handles its inputs on its loop's thread, while Zenoh's thread answers its status query.
    A handler stuck there (a deadlock: an injected wait stands in for it) left the service answering "running" for
    good: the launcher's hang check never fired, and the episode went on to its step limit with the robot standing
    (the planner's loop stuck at step 10 of a ``sim`` run: 51 % coverage at step 536, every service "alive, running").
    Once one handler has run for ``LOOP_STUCK_S`` the service stops answering (its log says so), so that the
    launcher kills and restarts it as hung; it answers again if the handler returns."""
    from services import common
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    monkeypatch.setattr(common, "LOOP_STUCK_S", 0.5)
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        svc = MapperService(ServiceContext("mapper", "t1", {}, ExplorationConfig(), client, {"restore_timeout_s": 0.2}))
        assert not svc.ctx.lockstep  # real time: inputs are handled on the loop's thread
        entered, release = threading.Event(), threading.Event()
        handle = svc.on_message

        def stuck_on_scans(robot: str, topic: str, msg: Any, received_s: float) -> None:
            if topic == "scan":
                entered.set()
                release.wait(30)
            handle(robot, topic, msg, received_s)

        svc.on_message = stuck_on_scans
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)

        def answers() -> bool:
            return any(r.ok is not None for r in session.get(keys.service_status("mapper"), timeout=0.5))

        thread.start()
        try:
            wait_for(lambda: any(True for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5) if r.ok), 10, "the mapper's liveliness token")
            wait_for(answers, 10, "the mapper's status")
            geom = GridGeometry(0.1, (40, 40))
            session.put(keys.clock, encode(ClockMsg(0, 0.0, geom)))
            scan = LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.inf, np.float32))
            session.put(keys.scan, encode(ScanMsg(0, scan, Pose2D(2.0, 2.0, 0.0))))
            assert entered.wait(10), "the scan's handler never ran"
            with caplog.at_level("ERROR", logger="cso.service"):
                wait_for(lambda: not answers(), 10, "the stuck mapper to stop answering its status")
            assert re.search(r"mapper: its loop has been in one handler \(scan, step 0\) for \d+\.\d s", caplog.text), caplog.text
            release.set()
            wait_for(answers, 10, "the mapper to answer again once its handler returned")
        finally:
            release.set()
            stop.set()
            thread.join(10)
    assert not thread.is_alive()


@contextlib.contextmanager
def shared_policy_server(session, client: TransportConfig, profile: dict | None = None):
    """A ``serve_all_robots`` policy service of robot ``a`` (greedy-dist), run on a thread until the block ends;
    entered once its ``alive/policy`` token answers on ``session``."""
    from services.common import ServiceContext, run_service
    from services.policy import PolicyService

    profile = profile or {"method": "greedy-dist", "seed": 0}
    svc = PolicyService(ServiceContext("policy", "a", profile, ExplorationConfig(), client, {"serve_all_robots": True}))
    stop = threading.Event()
    thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
    thread.start()
    try:
        wait_for(lambda: any(True for r in session.liveliness().get(RobotKeys("a").alive("policy"), timeout=0.5) if r.ok), 10, "the policy")
        yield svc
    finally:
        stop.set()
        thread.join(10)


def test_one_policy_server_answers_several_robots():
    from cso_runtime.messages import GoalMsg, frontiers_from_observation
    from tests.test_messages import _observation

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        goals: dict[str, GoalMsg] = {}
        sub = session.declare_subscriber("cso/*/goal", lambda s: goals.__setitem__(str(s.key_expr).split("/")[1], decode(s.payload.to_bytes(), GoalMsg)))
        profile = {"method": "greedy-dist", "seed": 0}
        with shared_policy_server(session, client, profile):
            try:
                obs = _observation()
                expected = make_policy("greedy-dist").select(obs)
                for robot in ("a", "b"):
                    session.put(RobotKeys(robot).frontiers, encode(frontiers_from_observation(0, "no_goal", obs, 1.0)))
                wait_for(lambda: set(goals) == {"a", "b"}, HANG_DEADLINE_S, "a goal for each robot")
                for g in goals.values():
                    assert g.decided and g.step == 0 and (g.x_m, g.y_m) == (expected.x_m, expected.y_m)
                # Robot b sees the policy under its own keys, as `status --robot b` asks: alive, with b's own status.
                assert any(r.ok for r in session.liveliness().get(RobotKeys("b").alive("policy"), timeout=HANG_DEADLINE_S))
                assert not any(r.ok for r in session.liveliness().get(RobotKeys("c").alive("policy"), timeout=0.5))  # not served
                for robot in ("a", "b"):
                    replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(RobotKeys(robot).service_status("*"), timeout=HANG_DEADLINE_S) if r.ok]
                    assert [(m.service, m.robot, m.state, m.last_step) for m in replies] == [("policy", robot, "running", 0)], replies
                assert not [r for r in session.get(RobotKeys("c").service_status("*"), timeout=0.5) if r.ok]
                status = query_status([loopback_endpoint(port)], "b", timeout_s=1.0)
                assert status is not None and status["services"]["policy"]["alive"] and status["services"]["policy"]["state"] == "running"
            finally:
                sub.undeclare()


def test_a_policy_server_leaves_a_robot_with_a_policy_of_its_own_to_it():
    """A robot whose run has its own policy (its alive/policy token is another process's) gets no goal from a
    ``serve_all_robots`` server: two policies would send it two different goals at each decision."""
    from cso_runtime.messages import GoalMsg, frontiers_from_observation
    from tests.test_messages import _observation

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        goals: list[tuple[str, int]] = []
        sub = session.declare_subscriber("cso/*/goal", lambda s: goals.append((str(s.key_expr).split("/")[1], decode(s.payload.to_bytes(), GoalMsg).step)))
        own_policy = session.liveliness().declare_token(RobotKeys("b").alive("policy"))  # robot b's run has its own
        with shared_policy_server(session, client) as svc:
            try:
                obs = _observation()
                for robot in ("a", "b", "c"):  # handled in this order: c's goal comes after b's input was handled
                    session.put(RobotKeys(robot).frontiers, encode(frontiers_from_observation(0, "no_goal", obs, 1.0)))
                wait_for(lambda: ("c", 0) in goals, 10, "robot c's goal")
                assert sorted(goals) == [("a", 0), ("c", 0)], goals
                own_policy.undeclare()  # b's own policy is gone: the server serves b from its next decision input
                wait_for(lambda: "b" not in svc._other_policies, 10, "the server to see b's policy gone")
                session.put(RobotKeys("b").frontiers, encode(frontiers_from_observation(1, "no_goal", obs, 1.0)))
                wait_for(lambda: ("b", 1) in goals, 10, "robot b's goal once its own policy is gone")
            finally:
                sub.undeclare()


def test_a_policy_server_knows_the_robots_with_a_policy_of_their_own_before_it_handles_any_input():
    """The server learnt of other robots' policies only from its liveliness subscriber's history, which comes on its
    own time: a decision input queued before it came (handled once ``start`` returns) was served, and a robot whose
    run has its own policy got a second goal (CI, once, under load). ``start`` now asks for those tokens itself;
    here the subscriber's history never comes, so only that question can tell."""
    from services.common import ServiceContext
    from services.policy import PolicyService

    class NoHistory:
        """The session's liveliness, with a subscriber that delivers nothing (its history late past ``start``)."""

        def __init__(self, real):
            self.real = real

        def declare_subscriber(self, *args, **kwargs):
            return types.SimpleNamespace(undeclare=lambda: None)

        def get(self, *args, **kwargs):
            return self.real.get(*args, **kwargs)

    port = free_tcp_port()
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        own_policy = session.liveliness().declare_token(RobotKeys("b").alive("policy"))  # robot b's run has its own
        try:
            svc = PolicyService(ServiceContext("policy", "a", {"method": "greedy-dist", "seed": 0}, ExplorationConfig(), TransportConfig(), {"serve_all_robots": True}))
            liveliness = NoHistory(session.liveliness())
            svc.session = types.SimpleNamespace(liveliness=lambda: liveliness, declare_queryable=lambda *a, **k: types.SimpleNamespace(undeclare=lambda: None))
            svc.start()
            assert svc._other_policies == {"b"}
        finally:
            own_policy.undeclare()


def test_a_policy_server_lets_a_robot_go_when_its_run_stops():
    """A ``serve_all_robots`` server kept a stopped robot's ``alive/policy`` token: ``status --robot`` showed that
    robot as starting with a live policy, and a new run of the id was refused. When the robot's frontier service
    (its decision inputs) goes, the server withdraws the token; a robot that comes back is served again."""
    from cso_runtime.messages import GoalMsg, frontiers_from_observation
    from tests.test_messages import _observation

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])

    def policy_alive(robot: str) -> bool:
        return any(True for r in session.liveliness().get(RobotKeys(robot).alive("policy"), timeout=0.5) if r.ok)

    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        goals: list[tuple[str, int]] = []
        sub = session.declare_subscriber("cso/*/goal", lambda s: goals.append((str(s.key_expr).split("/")[1], decode(s.payload.to_bytes(), GoalMsg).step)))
        with shared_policy_server(session, client):
            try:
                obs = _observation()
                frontier_b = session.liveliness().declare_token(RobotKeys("b").alive("frontier"))  # robot b's run
                session.put(RobotKeys("b").frontiers, encode(frontiers_from_observation(0, "no_goal", obs, 1.0)))
                wait_for(lambda: ("b", 0) in goals, 10, "robot b's goal")
                assert policy_alive("b")
                frontier_b.undeclare()  # b's run stops
                wait_for(lambda: not policy_alive("b"), 10, "the server to let robot b go")
                assert not [r for r in session.get(RobotKeys("b").service_status("*"), timeout=0.5) if r.ok]
                assert policy_alive("a")  # its own robot's token stays
                frontier_b = session.liveliness().declare_token(RobotKeys("b").alive("frontier"))  # a new run of b
                session.put(RobotKeys("b").frontiers, encode(frontiers_from_observation(0, "no_goal", obs, 1.0)))
                wait_for(lambda: goals.count(("b", 0)) == 2, 10, "robot b served afresh (its step 0 again)")
                assert policy_alive("b")
                frontier_b.undeclare()
            finally:
                sub.undeclare()


# --- tier 3: real processes ------------------------------------------------------------------------


def test_bad_profiles_fail_before_anything_starts(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # usage errors, asked of the app in this process (``usage_error``)
    assert "unknown profile 'no-such-profile'" in usage_error("up", "--profile", "no-such-profile", "--no-live")
    bad = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    bad["services"]["sim"]["warp_speed"] = 9
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    assert "warp_speed" in usage_error("up", "--profile", str(tmp_path / "bad.yaml"), "--no-live")
    assert "scene" in usage_error("up", "--profile", "lockstep", "--scene", "generated:huge:1:0", "--no-live")
    Image.new("RGB", (40, 30), (127, 127, 127)).save(tmp_path / "walls.png")  # resolves, but no floor and no start
    said = usage_error("up", "--profile", "lockstep", "--scene", "walls.png", "--no-live")
    assert "walls: no start marker" in said
    assert "lockstep.yaml with --scene walls.png: scene:" in said  # the flag that brought the bad scene
    (tmp_path / "weights").mkdir()
    shutil.copy(Path(cso_runtime.__file__).parent / "data" / "weights" / "cso.pt", tmp_path / "weights" / "cso.pt")
    unset_weights_env(monkeypatch)  # --weights sets the weights folder in this process's environment: put back after the test
    said = usage_error("up", "--profile", "lockstep", "--method", "gnn-baseline", "--weights", str(tmp_path / "weights"), "--no-live")
    assert "gnn-baseline.pt" in said  # a learned method without weights in --weights
    assert not (tmp_path / "runs").exists()


def test_a_profile_finds_its_scene_beside_it_and_a_flag_is_read_from_the_working_folder(tmp_path, monkeypatch):
    """A relative ``scene:`` in a profile file that is not in the working folder is looked for beside the file
    (as compose files do), so a profile with its plan next to it runs from anywhere; a ``--scene`` flag stays
    relative to the working folder."""
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import load_profile

    own = tmp_path / "configs" / "profiles"
    own.mkdir(parents=True)
    shutil.copy(REPO / "cso_runtime" / "data" / "scenes" / "img_1.png", own / "office.png")
    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    data["scene"] = "office.png"
    (own / "mine.yaml").write_text(yaml.safe_dump(data))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    profile, written = load_profile(str(own / "mine.yaml"))
    assert profile.scene == written["scene"] == str(own / "office.png")
    with pytest.raises(ConfigError, match="with --scene office.png: scene: office.png: file not found"):
        load_profile(str(own / "mine.yaml"), {"scene": "office.png"})


def test_set_changes_one_parameter_of_the_profile_and_is_validated_like_the_file(tmp_path, monkeypatch):
    """``up --set KEY=VALUE``: a dotted key into the profile (a service's parameter, an exploration setting), set
    in the data the run's services read; an unknown parameter or a key through a value is refused before anything
    starts, naming the flag."""
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import load_profile

    settings = {"services.sim.min_step_period_s": 0.1, "exploration.episode.max_steps": 40, "services.mapper.publish_period_s": None}
    with pytest.raises(ConfigError, match=r"with --set services.sim.min_step_period_s=0.1 .*services.mapper.*publish_period_s"):
        load_profile("lockstep", {}, settings=settings)  # the mapper has no such parameter
    del settings["services.mapper.publish_period_s"]
    profile, written = load_profile("lockstep", {"seed": 3}, settings=settings)
    assert profile.services["sim"]["min_step_period_s"] == 0.1 == written["services"]["sim"]["min_step_period_s"]
    assert profile.exploration_config().episode.max_steps == 40 and profile.seed == 3
    with pytest.raises(ConfigError, match="--set seed.x: seed is 0, not a mapping"):
        load_profile("lockstep", {}, settings={"seed.x": 1})
    with pytest.raises(ConfigError, match=re.escape("progress_log_s must be in [0, 86,400] s (a day: config.MAX_WAIT_S), got -1")):
        load_profile("lockstep", {}, settings={"progress_log_s": -1})
    r = cli("up", "--profile", "lockstep", "--set", "services.sim.min_step_period_s=0.1", "--seed", "3", "--dry-run", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.startswith("# profile lockstep, valid: `up` would start sim, mapper, frontier, policy, planner"), r.stderr
    shown = yaml.safe_load(r.stdout)  # what the services would read, and nothing started
    assert shown["services"]["sim"]["min_step_period_s"] == 0.1 and shown["seed"] == 3 and not (tmp_path / "runs").exists()
    monkeypatch.chdir(tmp_path)  # usage errors, asked of the app in this process (``usage_error``)
    assert "--set expects KEY=VALUE, got 'services.sim'" in usage_error("up", "--profile", "lockstep", "--set", "services.sim", "--no-live")
    assert "warp_speed" in usage_error("up", "--profile", "lockstep", "--set", "services.sim.warp_speed=9", "--no-live") and not (tmp_path / "runs").exists()


def test_a_realtime_priority_out_of_range_or_not_an_integer_is_refused_before_anything_starts(tmp_path):
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import load_profile

    for bad in (-1, 100):
        with pytest.raises(ConfigError, match=re.escape(f"realtime_priority must be in [0, 99] (0: normal scheduling; 1 to 99: SCHED_FIFO's priorities), got {bad}")):
            load_profile("lockstep", {}, settings={"realtime_priority": bad})
    with pytest.raises(ConfigError, match="realtime_priority: expected an integer, got 'high'"):
        load_profile("lockstep", {}, settings={"realtime_priority": "high"})
    assert load_profile("lockstep", {})[0].realtime_priority == 0  # the shipped profiles leave the normal scheduling
    said = usage_error("up", "--profile", "lockstep", "--set", "realtime_priority=100", "--no-live")
    assert "realtime_priority must be in [0, 99]" in said and not (tmp_path / "runs").exists()


def zenoh_threads_and_main(pid: int) -> dict[int, str]:
    """Thread id -> name of a process's main thread and its Zenoh threads (Zenoh's runtime names them ``rx-N``, ``tx-N``
    and the like; ``app-N`` with more than one worker)."""
    threads = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
        except FileNotFoundError:  # a thread that ended meanwhile
            continue
        if int(task.name) == pid or re.fullmatch(r"(rx|tx|app|net|acc)-\d+", name):
            threads[int(task.name)] = name
    return threads


def test_up_with_a_realtime_priority_runs_its_services_under_sched_fifo_or_says_why_not_and_the_episode_is_the_same(tmp_path):
    """``realtime_priority``: every service sets SCHED_FIFO on every thread of its process and of its helper processes once
    it has warmed up, before it says it is up, so its main thread, its Zenoh threads and the frontier service's layer
    helper run under it, and the episode is step for step the in-process one. Where the machine does not permit it (no CAP_SYS_NICE, no rtprio limit), ``up`` says so once before
    anything starts, each service's log says so, and they run with normal scheduling."""
    from cso_runtime.processes import realtime_refusal

    refusal = realtime_refusal(7)
    expected_policy = (os.SCHED_FIFO, 7) if refusal is None else (os.SCHED_OTHER, 0)
    said = "real-time scheduling, SCHED_FIFO priority 7 (realtime_priority)" if refusal is None else f"realtime_priority 7: {refusal}; running with normal scheduling"
    profile = write_profile(tmp_path, SCENE, "greedy-dist", min_step_period_s=0.25)  # 9 s: its processes live long enough to be looked at
    runs = tmp_path / "runs"
    up = subprocess.Popen(
        [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(profile), "--no-live", "--runs-dir", str(runs), "--set", "realtime_priority=7"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        info = wait_for(lambda: current_run_with_services(runs, 5), HANG_DEADLINE_S, "the run's five services")
        logs = next(runs.glob("*/logs"))
        names = ("sim", "mapper", "frontier", "policy", "planner")

        def read(name: str) -> str:
            return (logs / f"{name}.log").read_text() if (logs / f"{name}.log").exists() else ""

        wait_for(lambda: all(said in read(n) for n in names) and "frontier layer helper ready" in read("frontier"), HANG_DEADLINE_S, "each service's word on its scheduling")
        for name in names:
            pid = info["services"][name]["pid"]
            threads = zenoh_threads_and_main(pid)
            assert any(n.startswith("rx-") for n in threads.values()), (name, threads)
            for tid, thread in threads.items():
                assert (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority) == expected_policy, (name, thread)
        def answered() -> dict | None:
            st = query_status(info["endpoints"])
            return st if st is not None and all("counters" in st["services"].get(n, {}) for n in names) else None

        status = wait_for(answered, HANG_DEADLINE_S, "every service's status")
        for name in names:  # `status` shows it under each service's counts
            assert status["services"][name]["counters"].get("realtime_priority", 0) == (7 if refusal is None else 0), (name, status["services"][name])
        frontier = info["services"]["frontier"]["pid"]
        children = [int(c) for c in Path(f"/proc/{frontier}/task/{frontier}/children").read_text().split()]
        (helper,) = [c for c in children if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]  # the layer helper
        for tid in zenoh_threads_and_main(helper):
            assert (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority) == expected_policy
        _, err = up.communicate(timeout=120)
        assert up.returncode == 0, err[-3000:]
        assert err.count("warning: realtime_priority 7") == (0 if refusal is None else 1)
        (summary,) = [json.loads(p.read_text()) for p in runs.glob("*/summary.json")]
        expected = in_process_result(SCENE, "greedy-dist")
        ran = summary["methods"]["greedy-dist"]
        assert ran["steps"] == expected.steps and abs(ran["coverage_pct"] - expected.coverage_pct) < 1e-3
    finally:
        up.kill()
        up.communicate()
        kill_leftovers(runs)


def test_a_malformed_endpoint_is_a_usage_error_not_a_traceback_or_nothing_running(tmp_path, capsys):
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import load_profile
    from cso_runtime.status import save_map_main, status_main

    with pytest.raises(ConfigError, match="router: bad zenoh endpoint '127.0.0.1:7447'"):
        load_profile("lockstep", {}, connect=["127.0.0.1:7447"])
    with pytest.raises(ConfigError, match="bad zenoh endpoint 'tcp/1.2.3.4:99999': the port must be a number from 0 to 65535"):
        load_profile("lockstep", {}, connect=["tcp/1.2.3.4:99999"])
    assert status_main(["127.0.0.1:7447"], None, as_json=True, watch=False, runs_dir=tmp_path) == 2
    assert save_map_main(["127.0.0.1:7447"], None, tmp_path / "m", "pgm", tmp_path) == 2
    err = capsys.readouterr().err
    assert err.count("error: bad zenoh endpoint '127.0.0.1:7447'") == 2
    assert not list(tmp_path.iterdir())
    from services.common import service_main
    from services.mapper import MapperService

    # A service given a malformed endpoint refuses its configuration (exit 2: the launcher does not restart it).
    assert service_main(MapperService, ["--config", str(PROFILES / "lockstep.yaml"), "--connect", "127.0.0.1:7447"], exit_process=False) == 2


def test_a_service_bounds_the_grids_it_decodes_by_its_profiles_max_grid_cells(tmp_path, caplog):
    """Each service sets the run's grid bound (``max_grid_cells``, docs/messages.md) from its profile before it decodes
    anything, and refuses its configuration (exit 2, not restarted) for a bound out of range. A malformed endpoint
    stops each start here before Zenoh opens."""
    from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, max_grid_cells, set_max_grid_cells
    from services.common import service_main
    from services.mapper import MapperService

    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    path = tmp_path / "profile.yaml"
    try:
        for bound in (1_000_000, 0):
            path.write_text(yaml.safe_dump({**data, "max_grid_cells": bound}))
            assert service_main(MapperService, ["--config", str(path), "--connect", "127.0.0.1:7447"], exit_process=False) == 2
        assert max_grid_cells() == 1_000_000  # set by the first start; the second refused its bound
        assert "mapper: bad configuration: max_grid_cells must be an integer in 1 .. 50_000_000, got 0" in caplog.text
    finally:
        set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)


def test_a_service_log_level_is_checked_and_applied_under_the_cli(capsys):
    """``--log-level`` of a service: a level logging does not know is a usage error (exit 2; it was a ValueError
    traceback from logging), and under ``cso-runtime service``, whose command line has set up logging already, the
    level given still applies (it was ignored: ``logging.basicConfig`` does nothing once the root logger has a handler)."""
    import logging

    from services.common import parse_args, service_main
    from services.mapper import MapperService

    with pytest.raises(SystemExit) as exc:
        parse_args("mapper", ["--config", str(PROFILES / "lockstep.yaml"), "--log-level", "loud"])
    assert exc.value.code == 2
    assert "--log-level" in capsys.readouterr().err
    root = logging.getLogger()
    handler, level = logging.NullHandler(), root.level
    root.addHandler(handler)  # as the CLI's own logging set-up leaves it
    root.setLevel(logging.INFO)
    try:
        # A malformed endpoint: refused (exit 2) after logging is set up, without opening Zenoh.
        assert service_main(MapperService, ["--config", str(PROFILES / "lockstep.yaml"), "--connect", "127.0.0.1:7447", "--log-level", "debug"], exit_process=False) == 2
        assert root.level == logging.DEBUG
        assert service_main(MapperService, ["--config", str(PROFILES / "lockstep.yaml"), "--connect", "127.0.0.1:7447"], exit_process=False) == 2
        assert root.level == logging.DEBUG  # no --log-level: the level the command line chose stays (`cso-runtime -v service`)
    finally:
        root.removeHandler(handler)
        root.setLevel(level)


def test_up_refuses_folders_it_cannot_write_before_anything_starts(tmp_path, caplog, monkeypatch):
    """``--runs-dir`` or ``--record-out`` below a file: one error line and exit 2, no run folder, no process
    (the recorder's thread used to die with a traceback after the router had started). ``--runs-dir`` a file: the
    same one line, with no warning before it that its ``current.json`` is "not readable as JSON". These refusals
    come before anything starts: asked of the app in this process (a command's start costs a second each), where
    its log records reach ``caplog`` (``usage_error``); the recorder's failure, after the router has opened, from the command."""
    (tmp_path / "a_file").write_text("")
    monkeypatch.chdir(tmp_path)
    for flags, why in (
        (["--runs-dir", str(tmp_path / "a_file" / "runs")], "--runs-dir"),
        (["--runs-dir", str(tmp_path / "a_file")], "--runs-dir"),
        (["--record-out", str(tmp_path / "a_file" / "r.mcap"), "--runs-dir", str(tmp_path / "runs")], "--record-out"),
    ):
        for detach in ([], ["--detach"]):
            caplog.clear()
            with caplog.at_level("WARNING"):
                said = usage_error("up", "--profile", "lockstep", *flags, *detach)
            assert why in said and "cannot create the folder" in said and "WARNING" not in said, said
            assert not caplog.records, caplog.text
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
    # A recording path whose folder exists passes that check; here the recorder then fails to open it (a link
    # into a folder that is gone) and the run stops before any service starts, saying why.
    (tmp_path / "dangling.mcap").symlink_to(tmp_path / "gone" / "r.mcap")
    r = cli("up", "--profile", "lockstep", "--record-out", str(tmp_path / "dangling.mcap"), "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path, timeout_s=30)
    assert r.returncode == 2 and "cannot record into" in r.stderr and "no service was started" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "runs" / "current.json").exists()


def test_up_without_a_zenoh_session_says_so_and_starts_nothing(tmp_path):
    """The router cannot open (here: its port is taken; on a robot: the router to join is down): one error
    line and exit 3, foreground and detached alike, no traceback, no service started."""
    import socket

    from cso_runtime.runs import list_runs

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
        data["scene"] = SCENE
        data["router"]["listen"] = [loopback_endpoint(taken.getsockname()[1])]
        profile = tmp_path / "taken.yaml"
        profile.write_text(yaml.safe_dump(data))
        for detach in ([], ["--detach"]):
            runs = tmp_path / f"runs{len(detach)}"
            r = cli("up", "--profile", str(profile), "--no-live", *detach, "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            said = r.stdout + r.stderr
            assert r.returncode == 3 and "no service was started" in said and "Traceback" not in said, said
            assert "another process holds a port the embedded router is to listen on" in said and "router to join" not in said, said
            assert not (runs / "current.json").exists()
            assert [run.state for run in list_runs(runs)] == ["failed"]  # listed as it ended, not left unlisted
            assert not any(p.name.endswith(".log") and p.name != "launcher.log" for p in runs.rglob("*.log"))


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder that exists and that this process cannot write in: read-only by its mode, or (root ignores modes)
    /proc, where no file can be made."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o555)
    return folder if not os.access(folder, os.W_OK) else Path("/proc")


def test_up_and_eval_refuse_an_existing_folder_they_cannot_write_in(tmp_path):
    """``--runs-dir`` on a read-only file system, or a folder of another user's: the check that the folder can be
    made passed (it exists) and ``up`` ended in a Python traceback as it made the run's folder (exit 1); ``eval``
    would run its episodes first. Now one error line and exit 2 before anything starts, as for a folder below a file."""
    folder = unwritable_folder(tmp_path)
    try:
        for args in (["up", "--profile", "lockstep", "--runs-dir"], ["up", "--profile", "lockstep", "--detach", "--runs-dir"], ["eval", "--maps", SCENE, "--out"]):
            r = cli(*args, str(folder), cwd=tmp_path, timeout_s=60)
            assert r.returncode == 2 and f"{args[-1]} {folder}: cannot write in the folder" in r.stderr, r.stderr[-3000:]
            assert "Traceback" not in r.stderr and not list(folder.glob("*lockstep*"))
    finally:
        (tmp_path / "read_only").chmod(0o755)


def test_a_scene_file_named_in_bytes_that_are_no_utf8_runs_under_up_and_eval(tmp_path):
    """A plan file named ``img_\\xff.png`` (bytes that are no UTF-8; Python reads the name with a lone surrogate): the
    sim raised on each ``episode_status`` it encoded and was restarted until given up (``up`` exit 1, no results, a
    "Logging error" traceback for the launcher's first line), and ``eval`` ran its episodes and ended in a traceback
    writing episodes.csv. Both now run: the scene is named ``img_\\udcff`` in every file, the path escaped as written."""
    from cso_runtime.scenes import builtin_scene_dir

    maps = tmp_path / "maps"
    maps.mkdir()
    png = maps / os.fsdecode(b"img_\xff.png")
    try:
        shutil.copyfile(builtin_scene_dir() / "img_1.png", png)
    except OSError:  # a file system that takes only UTF-8 names (macOS)
        pytest.skip("this file system refuses a file name of bytes that are no UTF-8")
    runs = tmp_path / "runs"
    r = cli("up", "--profile", "lockstep", "--scene", str(png), "--no-live", "--set", "exploration.episode.max_steps=5", "--runs-dir", str(runs), cwd=tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr and "Logging error" not in r.stderr, r.stderr[-3000:]
    (run_dir,) = runs.glob("*lockstep*")
    with (run_dir / "episodes.csv").open(newline="", encoding="utf-8") as fh:
        assert [row["map"] for row in csv.DictReader(fh)] == ["img_\\udcff"]
    assert "img_\\udcff.png" in (run_dir / "report.html").read_text(encoding="utf-8")
    assert "img_\\udcff.png" in (run_dir / "logs" / "launcher.log").read_text(encoding="utf-8")

    r = cli("eval", "--maps", str(maps), "--max-steps", "5", "--out", str(tmp_path / "eval"), cwd=tmp_path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    with (tmp_path / "eval" / "episodes.csv").open(newline="", encoding="utf-8") as fh:
        assert [row["map"] for row in csv.DictReader(fh)] == ["img_\\udcff"]
    assert json.loads((tmp_path / "eval" / "summary.json").read_text(encoding="utf-8"))["methods"]["greedy-dist"]["episodes"] == 1


def test_up_that_cannot_reach_the_router_to_join_says_so_and_starts_nothing(tmp_path):
    """``up --connect`` to a router that is not there (a robot that is off, another run's router gone): the embedded
    router retried in the background and the run started alone, exit 0, with no word of it. Now the no-session error
    (docs/commands.md: exit 3), foreground and detached alike, once ``router.connect_timeout_s`` has passed; a foreground ``up``
    says the wait as it starts."""
    from cso_runtime.runs import list_runs

    nobody = loopback_endpoint(free_tcp_port())
    for detach in ([], ["--detach"]):
        runs = tmp_path / f"runs{len(detach)}"
        try:
            r = cli(
                "up", "--profile", str(write_profile(tmp_path)), "--no-live", *detach, "--runs-dir", str(runs),
                "--connect", nobody, "--set", "router.connect_timeout_s=0.5", cwd=tmp_path, timeout_s=60,
            )  # fmt: skip
            said = r.stdout + r.stderr
            assert r.returncode == 3 and f"cannot reach {nobody}" in said and "no service was started" in said, said
            # The wait itself is said as it starts (it was silent up to the timeout, 10 s by default, with the robot off).
            assert detach or f"joining {nobody} (up to 0.5 s, router.connect_timeout_s)" in said, said
            assert "Traceback" not in said and not (runs / "current.json").exists()
            assert [run.state for run in list_runs(runs)] == ["failed"]
        finally:
            assert kill_leftovers(runs) == []


def test_a_zenoh_runtime_setting_zenoh_cannot_read_is_said_not_a_traceback(tmp_path):
    """A ``ZENOH_RUNTIME`` that Zenoh cannot parse made it panic as the router opened: a Rust traceback, exit code 1
    and a run folder with no run.json (``runs`` did not list it). Now the no-session error: exit 3, one line that
    names the variable, the run listed as failed, nothing started."""
    from cso_runtime.runs import list_runs

    runs = tmp_path / "runs"
    env = {**os.environ, "ZENOH_RUNTIME": "(bogus"}
    r = subprocess.run(
        [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(write_profile(tmp_path)), "--no-live", "--runs-dir", str(runs)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60,
    )
    said = r.stdout + r.stderr
    assert r.returncode == 3 and "ZENOH_RUNTIME='(bogus'" in said and "no service was started" in said and "Traceback" not in said, said
    assert [run.state for run in list_runs(runs)] == ["failed"] and not (runs / "current.json").exists()


def test_a_second_up_in_the_same_runs_folder_is_refused_whichever_robot(tmp_path):
    """Another robot's run in the same folder would take over runs/current.json and leave the first run
    beyond ``status`` and ``down`` (its five services orphaned): refused, with the way out (which named no
    ``--runs-dir``: `cso-runtime down` as said stopped the run of ./runs, another robot's)."""
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "current.json").write_text(json.dumps({"run_id": "run-a", "robot": "r0", "launcher_pid": os.getpid(), "endpoints": []}))
    r = cli("up", "--profile", "lockstep", "--robot", "r1", "--detach", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
    assert r.returncode == 2 and "run-a (robot r0) is already running" in r.stderr and "--runs-dir" in r.stderr, r.stderr
    # the way out stops the run of this folder, not of ./runs (another robot's, when each has its own folder)
    assert f"`cso-runtime down --runs-dir {runs}` first" in r.stderr, r.stderr
    assert sorted(p.name for p in runs.iterdir()) == ["current.json"]  # nothing started


@pytest.mark.parametrize("taken_by", ["launcher", "service", "claim"])
def test_up_refuses_a_robot_id_that_another_run_on_the_network_has(tmp_path, taken_by):
    """Two runs of one robot id on one network cross-fed every key (each cleared the other's map on each new
    episode, and one cmd_vel would drive both robots): ``up`` joining a router where that id already has a
    launcher, or one of the services it would start, or the claim of a run starting at that moment, refuses before
    starting anything."""
    from cso_runtime.claims import RunClaim
    from cso_runtime.keys import robot_claim_subject, run_claim_token

    port = free_tcp_port()
    keys = RobotKeys("r0")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        if taken_by == "launcher":
            held = session.declare_queryable(keys.launcher_status, lambda query: query.reply(keys.launcher_status, b"x"))
        elif taken_by == "service":
            held = session.liveliness().declare_token(keys.alive("mapper"))
        else:
            held = session.liveliness().declare_token(run_claim_token(robot_claim_subject("r0"), RunClaim.new("other-run").chunk))
        try:
            runs = tmp_path / "runs"
            r = cli("up", "--profile", "lockstep", "--connect", loopback_endpoint(port), "--no-live", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            expected = {
                "launcher": "is already run by another launcher",
                "service": "already has a mapper service",
                "claim": "is being started by another run on this network at the same moment (run other-run goes on)",
            }[taken_by]
            assert r.returncode == 2 and f"robot r0 {expected}" in r.stderr and "another --robot" in r.stderr, r.stderr[-2000:]
            assert not list(runs.glob("*/logs/mapper.log"))  # no service was started
            # Its folder is the record of the refusal (its launcher.log says it): `runs` lists it as failed, and why
            r = cli("runs", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            (row,) = json.loads(r.stdout)
            assert row["state"] == "failed" and row["reason"].startswith(f"refused: robot r0 {expected}"), row
            from typer.testing import CliRunner

            from cso_runtime.cli import app

            table = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "200"}).output
            assert "failed: refused: robot r0" in table, table
        finally:
            held.undeclare()


def test_up_refuses_to_drive_a_robot_that_another_runs_ros2_bridge_drives(tmp_path):
    """Two ``limo-ros2`` runs of different robot ids on one robot's router and namespace both started: each run's
    bridge sent the LIMO a Twist on ``limo1/cmd_vel`` every scan, each toward its own goal. The bridge says which
    robot it drives (a liveliness token, ``keys.robot_driver_token``), and ``up`` refuses a run whose bridge would
    drive the same one, before starting anything; another namespace is another robot and is let through."""
    from cso_runtime.keys import robot_driver_token
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import load_profile

    port = free_tcp_port()
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        held = session.liveliness().declare_token(robot_driver_token("limo1/cmd_vel", "r7"))
        try:
            runs = tmp_path / "runs"
            args = ("up", "--profile", "limo-ros2", "--connect", loopback_endpoint(port), "--robot", "r1", "--no-live")
            r = cli(*args, "--namespace", "limo1", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            assert r.returncode == 2, r.stderr[-2000:]
            assert "limo1/cmd_vel is already driven by robot r7's run" in r.stderr and "--namespace" in r.stderr, r.stderr[-2000:]
            assert "no service was started" in r.stderr and not list(runs.glob("*/logs/ros2_bridge.log")), r.stderr[-2000:]
            other, data = load_profile("limo-ros2", connect=[loopback_endpoint(port)], namespace="limo2")
            assert Launcher(other, data, tmp_path / "other").robot_already_served(session) == ""
        finally:
            held.undeclare()


PRE_START_CHECK_AT_ONCE = """
import sys
from pathlib import Path
from cso_runtime.launcher import Launcher
from cso_runtime.run_profile import load_profile
from cso_runtime.transport import TransportConfig, open_session
profile_name, endpoint, run_dir, robot, namespace = sys.argv[1:6]
profile, data = load_profile(profile_name, {"robot": robot}, connect=[endpoint], namespace=namespace or None)
launcher = Launcher(profile, data, Path(run_dir))
with open_session(TransportConfig(mode="client", connect=[endpoint])) as session:
    print("ready", flush=True)
    sys.stdin.readline()  # the barrier: the test lets every launcher go at once
    verdict = launcher.robot_already_served(session)
    print("verdict " + verdict, flush=True)
    sys.stdin.readline()  # a launcher that goes on holds what it declared while the others decide, as its run would
"""


def pre_start_checks_at_once(tmp_path: Path, endpoint: str, runs: list[tuple[str, str, str]]) -> list[str]:
    """Each run's pre-start check (``Launcher.robot_already_served``; a run: profile, robot id, ROS namespace or "")
    in a process of its own, all let go at one instant (a barrier on their stdin once every session is open); what
    each said, in the order of ``runs`` ("": it goes on)."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", PRE_START_CHECK_AT_ONCE, name, endpoint, str(tmp_path / f"run{i}"), robot, namespace],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        )
        for i, (name, robot, namespace) in enumerate(runs)
    ]
    try:
        for p in procs:
            assert p.stdout.readline() == "ready\n", p.communicate(timeout=30)[1][-2000:]
        for p in procs:  # go: each line is sent at once, before any launcher could have answered
            p.stdin.write("\n")
            p.stdin.flush()
        said = [p.stdout.readline() for p in procs]
        for p in procs:
            p.stdin.write("\n")
            p.stdin.flush()
            assert p.wait(30) == 0, p.stderr.read()[-2000:]
        assert all(s.startswith("verdict ") for s in said), said
        return [s.removeprefix("verdict ").strip() for s in said]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def test_of_two_runs_of_one_robot_started_at_once_exactly_one_goes_on(tmp_path):
    """Two ``up`` of one robot id on one network, started at the same instant, both passed the pre-start check (each
    asked before the other had declared anything) and both ran: two sims fed one robot's keys. Each run now claims
    its robot before it asks (``cso_runtime.claims``); of claims made at once exactly one goes on, and the other is
    refused as ``up`` refuses a robot already run (exit 2, nothing started). Another robot's run goes on beside them."""
    port = free_tcp_port()
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])):
        said = pre_start_checks_at_once(tmp_path, loopback_endpoint(port), [("lockstep", "r0", ""), ("lockstep", "r0", ""), ("lockstep", "r1", "")])
    assert min(said[:2]) == "" and said[2] == "", said
    refused = max(said[:2])
    assert "robot r0 is being started by another run" in refused and "another --robot" in refused, refused


def test_of_two_runs_started_at_once_to_drive_one_ros_robot_exactly_one_goes_on(tmp_path):
    """Two ``limo-ros2`` runs of different robot ids on one robot's namespace, started at the same instant, both
    passed the check of the robot's driver (no bridge drove it yet), and both bridges would send it Twists. Each run
    claims the ``cmd_vel`` it would drive too: exactly one goes on; a run on another namespace goes on beside it."""
    port = free_tcp_port()
    runs = [("limo-ros2", "r1", "limo1"), ("limo-ros2", "r2", "limo1"), ("limo-ros2", "r3", "limo2")]
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])):
        said = pre_start_checks_at_once(tmp_path, loopback_endpoint(port), runs)
    assert min(said[:2]) == "" and said[2] == "", said
    refused = max(said[:2])
    assert "limo1/cmd_vel is being claimed by another run" in refused and "--namespace" in refused, refused



def test_of_two_up_of_one_robot_started_together_one_runs_and_a_later_one_is_refused(tmp_path):
    """Two ``up --detach`` of robot r0 started together, each from its own runs folder, joining one router: one
    runs, the other stops before it starts anything (exit 2), whichever got there first. The run that goes on then
    withdraws its claims (one session on the router: its own router's) once the router answers for it, and a run
    started later is refused by that answer."""
    from tests.test_limo_ros2 import _connections_to_port

    port = free_tcp_port()
    profile = write_profile(tmp_path, min_step_period_s=0.25)
    all_runs = [tmp_path / f"runs{i}" for i in range(3)]

    started: list[subprocess.Popen] = []

    def up(runs: Path) -> subprocess.Popen:
        argv = ["up", "--profile", str(profile), "--connect", loopback_endpoint(port), "--detach", "--runs-dir", str(runs)]
        started.append(subprocess.Popen([*python_module_argv("cso_runtime.cli"), *argv], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        return started[-1]

    try:
        with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])):
            together = [up(runs) for runs in all_runs[:2]]
            said = [p.communicate(timeout=60) for p in together]
            codes = [p.returncode for p in together]
            assert sorted(codes) == [0, 2], said
            refused = said[codes.index(2)][1]
            assert "robot r0 is" in refused and "another --robot" in refused and "no service was started" in refused, refused
            assert _connections_to_port(port) == 1, "the run's own router only: its claims are withdrawn"
            later = up(all_runs[2])
            _, err = later.communicate(timeout=60)
            assert later.returncode == 2 and "robot r0 is already run by another launcher" in err, err
    finally:
        for proc in started:  # an `up` that did not return in time (the launchers it started: kill_leftovers)
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
        for runs in all_runs:
            if (runs / "current.json").exists():
                cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            kill_leftovers(runs)


def test_kill_leftovers_kills_a_detached_launcher_that_wrote_no_run_file(tmp_path):
    """An ``up --detach`` killed by a test (one that did not return in time) after it started its launcher, before that
    launcher wrote its run.json: ``kill_leftovers`` read only run files and left the launcher running. It finds one by
    its command line (here a stand-in with a detached launcher's, relative ``--run-dir`` and all); another runs
    folder's is left alone."""
    runs, other = tmp_path / "runs", tmp_path / "other"
    stand_in = [sys.executable, "-c", "import time; time.sleep(120)", "-m", "cso_runtime.launcher", "--profile-data", "-", "--run-dir"]
    mine = subprocess.Popen([*stand_in, "runs/20261206-000000-lockstep-r0"], cwd=tmp_path, start_new_session=True)
    theirs = subprocess.Popen([*stand_in, str(other / "20261206-000000-lockstep-r0")], cwd=tmp_path, start_new_session=True)
    try:
        assert kill_leftovers(runs) == [mine.pid]
        assert mine.wait(10) == -signal.SIGKILL and theirs.poll() is None
    finally:
        for proc in (mine, theirs):
            proc.kill()
            proc.wait(10)


def test_a_run_that_started_no_service_is_listed_as_it_ended(tmp_path):
    """Ctrl-C while the router opens (the first second of ``up``) left a run folder with no run.json, which
    ``runs`` never listed; a run refused before its services (robot id taken, recording that cannot open)
    was listed as ``launcher died``. Each now says how it ended, and leaves no current run."""
    from cso_runtime.runs import list_runs

    runs = tmp_path / "runs"
    (tmp_path / "a_file").write_text("")
    # Each launcher in a process of its own that has exited when ``runs`` reads its folder, as after ``up``.
    script = textwrap.dedent(
        f"""
        from pathlib import Path
        from cso_runtime.launcher import Launcher
        from cso_runtime.run_profile import find_profile, load_profile
        profile, data = load_profile(str(find_profile("lockstep")), {{"scene": {SCENE!r}}})
        interrupted = Launcher(profile, data, Path({str(runs / "interrupted")!r}))
        interrupted.stop_event.set()  # as the signal handler does, before the services are spawned
        refused = Launcher(profile, data, Path({str(runs / "refused")!r}), record_path=Path({str(tmp_path / "a_file" / "r.mcap")!r}))
        print(interrupted.run(), refused.run())  # the recorder cannot make its folder: refused (2)
        """
    )
    r = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.split() == ["130", "2"], r.stderr[-2000:]
    listed = {run.run_id: run for run in list_runs(runs)}
    assert {k: v.state for k, v in listed.items()} == {"interrupted": "interrupted", "refused": "failed"}
    assert all(v.duration_s is not None and v.restarts == 0 for v in listed.values())
    assert json.loads((runs / "refused" / "run.json").read_text())["exit_code"] == 2
    assert not (runs / "current.json").exists()
    assert not list(runs.glob("*/logs/*.log"))  # no service was started


def test_a_run_stopped_before_its_results_does_not_wait_out_pyplots_import(tmp_path):
    """The launcher joined its background pyplot import with no bound as it stopped: a run stopped before its results
    (no figure to draw) waited for a first run's matplotlib to build its font cache, tens of seconds. Here the import
    never ends: the stop waits ``PYPLOT_IMPORT_STOP_S`` for it, says so, and the run ends (interrupted, 130) without it."""
    runs = tmp_path / "runs"
    script = textwrap.dedent(
        f"""
        import logging, threading
        from pathlib import Path
        import cso_runtime.launcher as L
        from cso_runtime.run_profile import find_profile, load_profile

        logging.basicConfig(level=logging.INFO)
        never = threading.Event()
        importing = threading.Thread(target=never.wait, name="import-pyplot", daemon=True)  # a font cache being built

        def import_pyplot_in_background():
            importing.start()
            return importing

        L.import_pyplot_in_background = import_pyplot_in_background
        L.Launcher.spawn_all = lambda self: self.stop_event.set()  # stopped (Ctrl-C) as its services would start
        profile, data = load_profile(str(find_profile("lockstep")), {{"scene": {SCENE!r}}})
        launcher = L.Launcher(profile, data, Path({str(runs / "r")!r}))
        print(launcher.run(), importing.is_alive())
        """
    )
    r = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=HANG_DEADLINE_S)
    assert r.returncode == 0 and r.stdout.split() == ["130", "True"], r.stderr[-2000:]
    assert "pyplot's import (for the figures; a first run builds matplotlib's font cache) is not done: the stop does not wait for it" in r.stderr


def test_a_run_stopped_as_its_status_watch_asks_closes_its_session_after_the_watch_ends(tmp_path):
    """Ctrl-C as ``up`` was about to start its services (its status watch's first query in flight) closed the run's
    session under that query: "RuntimeError: Already borrowed" out of ``up`` and, at the process's end, "FATAL:
    exception not rethrown" (SIGABRT). The watch now ends before the session closes. Here a query is held in flight
    for 0.5 s, the stop comes as it is, and the session records whether the watch's thread still ran at its close."""
    runs = tmp_path / "runs"
    script = textwrap.dedent(
        f"""
        import threading, time
        from pathlib import Path
        import cso_runtime.launcher as L
        from cso_runtime.run_profile import find_profile, load_profile

        class SlowGet:
            \"\"\"The session, its status queries held in flight 0.5 s.\"\"\"
            def __init__(self, session):
                self.session = session
            def get(self, *args, **kwargs):
                replies = self.session.get(*args, **kwargs)
                time.sleep(0.5)
                return replies
            def __getattr__(self, name):
                return getattr(self.session, name)

        class Recorded:
            \"\"\"The run's session, recording at its close whether the status watch's thread still runs.\"\"\"
            def __init__(self, session):
                self.session = session
            def __enter__(self):
                self.session.__enter__()
                return self
            def __exit__(self, *exc):
                print("watch alive at close:", any(t.name == "status-watch" and t.is_alive() for t in threading.enumerate()))
                return self.session.__exit__(*exc)
            def __getattr__(self, name):
                return getattr(self.session, name)

        real_open_router = L.open_router
        L.open_router = lambda *a, **k: (lambda opened: (Recorded(opened[0]), opened[1]))(real_open_router(*a, **k))
        real_start = L.StatusWatch.start

        def start(self):
            self._session = SlowGet(self._session)
            real_start(self)
            time.sleep(0.1)  # its first query in flight
            launcher.stop_event.set()  # Ctrl-C, as the signal handler sets it

        L.StatusWatch.start = start
        profile, data = load_profile(str(find_profile("lockstep")), {{"scene": {SCENE!r}}})
        launcher = L.Launcher(profile, data, Path({str(runs / "r")!r}))
        print("exit", launcher.run())
        """
    )
    r = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.splitlines() == ["watch alive at close: False", "exit 130"], r.stdout + r.stderr[-2000:]


def test_two_up_started_at_once_cannot_both_run(tmp_path):
    """Two ``up`` started together both pass the current.json check (the first writes it only once it holds the
    runs folder's lock); the runs folder's lock lets one launcher run, and the other stops before it
    starts anything, foreground or detached, saying why."""
    from cso_runtime.current_run import RUNS_LOCK, hold_runs_lock

    runs = tmp_path / "runs"
    fd = hold_runs_lock(runs)  # the first launcher, in its first seconds
    assert fd is not None and hold_runs_lock(runs) is None
    try:
        for detach in ([], ["--detach"]):
            r = cli("up", "--profile", "lockstep", "--scene", SCENE, "--no-live", *detach, "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
            said = r.stdout + r.stderr
            assert r.returncode == 2 and "another `cso-runtime up` is running" in said and RUNS_LOCK in said, said
            assert not (runs / "current.json").exists()
            assert not any(p.name.endswith(".log") and p.name != "launcher.log" for p in runs.rglob("*.log"))  # no service
    finally:
        os.close(fd)
    fd = hold_runs_lock(runs)  # released with its holder
    assert fd is not None
    os.close(fd)



def test_a_deleted_runs_lock_is_taken_again_unless_another_launcher_took_it_first(tmp_path):
    from cso_runtime.current_run import RUNS_LOCK, hold_runs_lock, keep_runs_lock

    runs = tmp_path / "runs"
    fd = hold_runs_lock(runs)
    assert fd is not None and keep_runs_lock(runs, fd) == fd  # its file still there: nothing to do
    (runs / RUNS_LOCK).unlink()
    other = hold_runs_lock(runs)  # a second launcher, in the moment before the first's round
    assert other is not None and keep_runs_lock(runs, fd) is None
    os.close(other)
    kept = keep_runs_lock(runs, fd)  # the other gone: the lock file is free, and taken
    assert kept is not None and hold_runs_lock(runs) is None
    os.close(kept)


def test_a_runs_folder_deleted_mid_run_keeps_its_lock_and_a_second_up_is_refused(tmp_path):
    """The whole runs folder deleted while ``up`` ran took its lock file with it: the launcher's lock stayed on a file
    with no name, and a second ``up`` in that folder (with no current.json to stop it: deleted too, or not yet written
    again) made a new lock file, locked it and started beside the first. The launcher takes the lock again on a new
    file on its next round, and a second ``up`` is refused by it."""
    from cso_runtime.current_run import CURRENT_RUN, RUNS_LOCK, hold_runs_lock

    profile = write_profile(tmp_path, min_step_period_s=0.3)  # an episode of minutes: it runs through the test
    runs = tmp_path / "runs"
    first: list[int] = []
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        current = json.loads((runs / "current.json").read_text())
        # the way to follow it reads this runs folder (a plain `cso-runtime logs -f` said "no runs in runs"), and where its results go
        assert f"(`cso-runtime logs -f --runs-dir {runs}` follows them), results in {runs / current['run_id']}/ once its episode ends" in r.stdout, r.stdout
        # Every service has read its configuration from the run folder: deleted before that, a service that has not is
        # restarted once the folder is made again, which is another case (test_a_run_folder_deleted_before_a_service_...).
        wait_for(lambda: (s := query_status(current["endpoints"], current["robot"], timeout_s=0.5)) and s["state"] == "exploring", 60, "the episode to start")
        first += run_pids(runs)
        for _ in range(20):  # as `rm -rf runs` does; the services write logs meanwhile, so one walk may meet a new file
            try:
                shutil.rmtree(runs)
                break
            except OSError:
                if not runs.exists():
                    break
        else:
            raise AssertionError("runs/ could not be deleted in 20 tries")
        wait_for(lambda: (runs / RUNS_LOCK).exists() and (runs / CURRENT_RUN).exists(), 10, "the launcher to take its lock again")
        fd = hold_runs_lock(runs)
        if fd is not None:
            os.close(fd)
        assert fd is None, "the lock file is there, but nobody holds it"
        (runs / CURRENT_RUN).unlink()  # as a second `up` finds the folder before the launcher's round writes it again
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        said = r.stdout + r.stderr
        assert r.returncode == 2 and "another `cso-runtime up` is running" in said and RUNS_LOCK in said, said
        assert sorted(run_pids(runs)) == sorted(first) and all(pid_alive(p) for p in first)  # the first run goes on, alone
    finally:
        kill_leftovers(runs, extra=first)  # the pids read before the folder went: a run folder deleted half-way lists none


SIGNAL_WHILE = """
import importlib, os, signal, sys
from pathlib import Path
sig, module_name, attr, pid_file = signal.Signals[sys.argv[1]], sys.argv[2], sys.argv[3], Path(sys.argv[4])
owner = importlib.import_module(module_name)
for part in attr.split(".")[:-1]:
    owner = getattr(owner, part)
name = attr.split(".")[-1]
real = getattr(owner, name)

def call(*args, **kwargs):  # the signal comes exactly while `up` does this (once), as a Ctrl-C at that moment would
    setattr(owner, name, real)
    out = real(*args, **kwargs) if name == "Popen" else None
    if out is not None:
        pid_file.write_text(str(out.pid))  # the detached launcher, for the test to clean up
    os.kill(os.getpid(), sig)
    return out if out is not None else real(*args, **kwargs)

setattr(owner, name, call)
from cso_runtime.cli import main
sys.argv = ["cso-runtime", *sys.argv[5:]]
main()
"""


@pytest.mark.parametrize(
    ("sig", "module", "attr"),
    [
        ("SIGINT", "typer.main", "get_command"),  # typer building the command line, before any command runs
        ("SIGINT", "cso_runtime.run_profile", "load_profile"),  # validating the profile
        ("SIGTERM", "cso_runtime.run_profile", "load_profile"),
        ("SIGINT", "cso_runtime.launcher", "hold_runs_lock"),  # its run folder made, the launcher's handlers not yet in
        ("SIGHUP", "cso_runtime.launcher", "hold_runs_lock"),
        ("SIGINT", "cso_runtime.launcher", "open_router"),
        ("SIGTERM", "cso_runtime.supervision", "Child.spawn"),  # starting the first service
    ],
)
def test_up_stopped_in_its_first_moments_exits_cleanly(tmp_path, sig, module, attr):
    """Ctrl-C (or SIGTERM, or the terminal closing) in ``up``'s first moments, before the launcher had installed
    its handlers, ended it with a KeyboardInterrupt traceback, or silently (typer's 130, no line, or killed by
    SIGTERM), with a run folder that had no run.json. Wherever it comes now: one ``interrupted`` line, exit 130,
    no process left, no current run, and a run folder, if one was made, whose run.json says it was interrupted."""
    runs = tmp_path / "runs"
    argv = ["up", "--profile", str(write_profile(tmp_path)), "--no-live", "--runs-dir", str(runs)]
    try:
        r = subprocess.run(
            [sys.executable, "-c", SIGNAL_WHILE, sig, module, attr, str(tmp_path / "pid"), *argv],
            cwd=tmp_path, capture_output=True, text=True, timeout=60,
        )
        said = r.stdout + r.stderr
        assert r.returncode == 130 and "interrupted" in said and "Traceback" not in said, (r.returncode, said[-3000:])
        assert not (runs / "current.json").exists()
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
        run_dirs = [d for d in runs.glob("*") if d.is_dir()] if runs.exists() else []
        for run_dir in run_dirs:
            info = json.loads((run_dir / "run.json").read_text())
            assert (info["state"], info["outcome"], info["exit_code"]) == ("stopped", "interrupted", 130), info
            assert "Traceback" not in (run_dir / "logs" / "launcher.log").read_text()
        assert bool(run_dirs) == (attr not in ("get_command", "load_profile"))  # none made after a stop
    finally:
        kill_leftovers(runs)


def test_up_stopped_while_its_router_waits_for_a_router_to_join_exits_at_once(tmp_path):
    """SIGTERM while the launcher's router waited to reach the router it joins (``--connect``, gone: a robot's bridge
    down, or a test's router closed) did nothing until ``router.connect_timeout_s`` had passed: Zenoh opens in Rust
    code, where no Python signal handler runs. The launcher then said "cannot reach" (exit 3), or, with the router
    back meanwhile, went on to its claims' client session and waited there again. Now the open is given up at the
    signal: one ``interrupted`` line, exit 130, a run.json that says so, nothing left."""
    runs = tmp_path / "runs"
    gone = loopback_endpoint(free_tcp_port())  # no router there
    argv = ["up", "--profile", str(write_profile(tmp_path)), "--no-live", "--runs-dir", str(runs), "--connect", gone, "--set", "router.connect_timeout_s=60"]
    proc = subprocess.Popen([*python_module_argv("cso_runtime.cli"), *argv], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Its router listens as soon as Zenoh opens it, then tries the one it joins: the launcher is inside the open.
        wait_for(lambda: proc.poll() is not None or listening_tcp_ports(proc.pid), 60, "the launcher's router to listen")
        assert proc.poll() is None, proc.communicate()
        signalled_s = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)  # before: some 60 s, the whole connect timeout
        took_s = time.monotonic() - signalled_s
        assert proc.returncode == 130 and "interrupted before any service was started" in err and "Traceback" not in err, (proc.returncode, err[-3000:])
        assert took_s < 5.0, took_s
        (run_dir,) = [d for d in runs.glob("*") if d.is_dir()]
        info = json.loads((run_dir / "run.json").read_text())
        assert (info["state"], info["outcome"], info["exit_code"], info["services"]) == ("stopped", "interrupted", 130, {}), info
        assert not (runs / "current.json").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
        kill_leftovers(runs)


def test_up_stopped_while_python_imports_it_exits_cleanly(tmp_path):
    """Ctrl-C while Python imports the command line (typer, here one that is interrupted as it loads): one line, 130."""
    (tmp_path / "fake").mkdir()
    (tmp_path / "fake" / "typer.py").write_text("import os, signal\nos.kill(os.getpid(), signal.SIGINT)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "fake"), str(REPO), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "up"], cwd=tmp_path, capture_output=True, text=True, timeout=60, env=env)
    assert (r.returncode, r.stdout, r.stderr) == (130, "", "error: interrupted\n")


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_up_detach_stopped_as_its_launcher_starts_leaves_no_run(tmp_path, sig):
    """``up --detach`` stopped just after it started its launcher: Ctrl-C there (outside its wait) raised in ``up``
    and left the launcher to run in the background, as SIGTERM anywhere did; the launcher, stopped in its own first
    moments, wrote a KeyboardInterrupt traceback to its log and no run.json. Now ``up`` stops it (SIGTERM: quiet
    while it still imports, its clean stop once its handlers are in) and the run says it was interrupted."""
    runs = tmp_path / "runs"
    argv = ["up", "--profile", str(write_profile(tmp_path)), "--detach", "--runs-dir", str(runs)]
    pid_file = tmp_path / "pid"
    try:
        r = subprocess.run(
            [sys.executable, "-c", SIGNAL_WHILE, sig, "subprocess", "Popen", str(pid_file), *argv],
            cwd=tmp_path, capture_output=True, text=True, timeout=90,
        )
        said = r.stdout + r.stderr
        assert r.returncode == 130 and "interrupted while the launcher started: stopped it" in said and "Traceback" not in said, said[-3000:]
        launcher_pid = int(pid_file.read_text())
        assert not pid_alive(launcher_pid)
        (run_dir,) = [d for d in runs.glob("*") if d.is_dir()]
        info = json.loads((run_dir / "run.json").read_text())
        assert (info["state"], info["outcome"], info["launcher_pid"]) == ("stopped", "interrupted", launcher_pid), info
        assert "Traceback" not in (run_dir / "logs" / "launcher.log").read_text()
        assert not (runs / "current.json").exists() and [p for p in run_pids(runs) if pid_alive(p)] == []
    finally:
        kill_leftovers(runs, [int(pid_file.read_text())] if pid_file.exists() else [])


def test_a_detached_launcher_stopped_while_it_loads_its_profile_stops_cleanly(tmp_path):
    """The detached launcher (``python -m cso_runtime.launcher``) takes a stop as its clean stop from its first line:
    SIGTERM while it loads its profile (``up --detach`` giving up on it) ended it with no run.json."""
    from cso_runtime.run_profile import load_profile

    _, data = load_profile(str(write_profile(tmp_path)), {})
    run_dir = tmp_path / "runs" / "r"
    (run_dir / "logs").mkdir(parents=True)
    (run_dir / "profile.requested.yaml").write_text(yaml.safe_dump(data))
    script = textwrap.dedent(
        """
        import os, signal, sys
        import cso_runtime.launcher as launcher
        real = launcher.load_yaml
        def load_yaml(path):
            os.kill(os.getpid(), signal.SIGTERM)
            return real(path)
        launcher.load_yaml = load_yaml
        raise SystemExit(launcher.main(sys.argv[1:]))
        """
    )
    try:
        r = subprocess.run(
            [sys.executable, "-c", script, "--profile-data", str(run_dir / "profile.requested.yaml"), "--run-dir", str(run_dir)],
            cwd=tmp_path, capture_output=True, text=True, timeout=60,
        )
        assert r.returncode == 130 and "interrupted before any service was started" in r.stderr and "Traceback" not in r.stderr, r.stderr[-3000:]
        info = json.loads((run_dir / "run.json").read_text())
        assert (info["state"], info["outcome"], info["services"]) == ("stopped", "interrupted", {}), info
        assert not (tmp_path / "runs" / "current.json").exists()
    finally:
        kill_leftovers(tmp_path / "runs")


def holds_pipe(pid: int, pipe: str) -> bool:
    """Whether process ``pid`` has a file descriptor on ``pipe`` (``pipe:[INODE]``, as /proc names it; Linux)."""
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):  # closed meanwhile
            if os.readlink(fd) == pipe:
                return True
    return False


def test_a_detached_launcher_whose_up_was_killed_as_it_started_is_found_and_stopped_by_down(tmp_path):
    """``up --detach`` killed outright (SIGKILL: no handler of its own runs) just after it started its launcher, before
    that launcher wrote its run file: the launcher is a session of its own with the profile on its stdin, so it goes
    on and writes run.json and current.json as it starts; ``status`` and ``runs`` see it, and ``down`` stops it and its
    services. No run is left that nothing knows of (docs/runtime.md)."""
    runs = tmp_path / "runs"
    argv = ["up", "--profile", str(write_profile(tmp_path, min_step_period_s=0.25)), "--detach", "--runs-dir", str(runs)]
    up = subprocess.Popen([*python_module_argv("cso_runtime.cli"), *argv], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        (launcher,) = wait_for(lambda: detached_launchers(runs), 60, "up to start its launcher", period_s=0.005)
        # Killed once it has handed the profile over (closed its end of the launcher's stdin; before that, see
        # test_a_detached_launcher_given_no_profile_by_its_killed_up_says_so_and_starts_nothing), as the launcher imports.
        wait_for(lambda: not holds_pipe(up.pid, os.readlink(f"/proc/{launcher}/fd/0")), 60, "up to hand its launcher the profile", period_s=0.005)
        up.kill()
        up.wait(10)
        current = wait_for(lambda: (runs / "current.json").exists() and json.loads((runs / "current.json").read_text()), 60, "the launcher's current run")
        assert current["launcher_pid"] == launcher
        wait_for(lambda: json.loads((runs / "current.json").read_text())["services"], 60, "its services")
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
        assert r.returncode == 0 and json.loads(r.stdout)["run_id"] == current["run_id"], r.stdout + r.stderr
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0 and "stopped run" in r.stdout, r.stdout + r.stderr
        assert not pid_alive(launcher) and [p for p in run_pids(runs) if pid_alive(p)] == [] and not (runs / "current.json").exists()
    finally:
        if up.poll() is None:
            up.kill()
            up.wait(10)
        kill_leftovers(runs)


def test_a_detached_launcher_given_no_profile_by_its_killed_up_says_so_and_starts_nothing(tmp_path):
    """``up --detach`` killed (SIGKILL) after it started its launcher and before it wrote the profile to the launcher's
    stdin: the launcher read an empty profile and ended with a ConfigError traceback ("a profile must list at least one
    service"), as if ``up`` had handed it a bad one. Now it says what happened in one line: exit 130, nothing started."""
    run_dir = tmp_path / "runs" / "r"
    (run_dir / "logs").mkdir(parents=True)
    r = subprocess.run(
        [*python_module_argv("cso_runtime.launcher"), "--profile-data", "-", "--run-dir", str(run_dir)],
        stdin=subprocess.DEVNULL, cwd=tmp_path, capture_output=True, text=True, timeout=60,
    )
    said = r.stdout + r.stderr
    assert r.returncode == 130 and "no profile came from `up --detach`" in said and "Traceback" not in said, (r.returncode, said[-3000:])
    assert not (tmp_path / "runs" / "current.json").exists() and not (run_dir / "run.json").exists()


def test_a_detached_start_that_is_interrupted_or_too_slow_stops_its_launcher(tmp_path, monkeypatch):
    """``up --detach`` waits for its launcher to start; Ctrl-C then, or a start slower than the deadline,
    stops that launcher instead of leaving a run behind that ``status`` and ``down`` do not know of."""
    from cso_runtime import launcher as launcher_module
    from cso_runtime.config import EXIT_INTERRUPTED
    from cso_runtime.current_run import current_launcher_alive, read_current_run
    from cso_runtime.launcher import start_detached
    from cso_runtime.run_profile import load_profile

    started: list[subprocess.Popen] = []
    real_popen = subprocess.Popen

    def popen(*args, **kwargs):
        proc = real_popen(*args, **kwargs)
        if "cso_runtime.launcher" in args[0]:  # not the provenance's git commands (the same module's Popen)
            started.append(proc)
        return proc

    try:
        monkeypatch.setattr(launcher_module.subprocess, "Popen", popen)
        profile, data = load_profile(str(write_profile(tmp_path)), {})
        code, message = start_detached(profile, data, tmp_path / "runs", ready_timeout_s=0.0)  # no launcher is ready the moment it is spawned
        assert code == 1 and "did not start within 0 s: stopped it" in message, message
        assert started[-1].poll() is not None

        def popen_then_ctrl_c(*args, **kwargs):
            """Ctrl-C at the first look at the launcher, microseconds after it was spawned: long before its services are
            up, whatever the host's speed (a timer of 0.3 s came after a fast launcher's start)."""
            proc = popen(*args, **kwargs)
            if proc not in started:
                return proc
            real_poll = proc.poll

            def poll():
                if not getattr(proc, "ctrl_c_sent", False):
                    proc.ctrl_c_sent = True
                    os.kill(os.getpid(), signal.SIGINT)
                return real_poll()

            proc.poll = poll
            return proc

        monkeypatch.setattr(launcher_module.subprocess, "Popen", popen_then_ctrl_c)
        code, message = start_detached(profile, data, tmp_path / "runs2")
        assert code == EXIT_INTERRUPTED and "interrupted while the launcher started: stopped it" in message, message
        assert started[-1].poll() is not None and len(started) == 2
        for runs in (tmp_path / "runs", tmp_path / "runs2"):  # nothing `status` and `down` would take for a running run
            info = read_current_run(runs)
            assert info is None or not current_launcher_alive(info), info
    finally:  # whatever failed: no launcher, and none of its services, left running
        for runs in (tmp_path / "runs", tmp_path / "runs2"):
            kill_leftovers(runs, [p.pid for p in started])


def _a_detached_run_folder(tmp_path: Path, log_text: str):
    """The lockstep profile and a run folder ``runs/run1`` whose launcher's log holds ``log_text``, for
    ``_wait_for_detached`` to look at: (profile, data, run_dir, log_path)."""
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    run_dir = tmp_path / "runs" / "run1"
    (run_dir / "logs").mkdir(parents=True)
    log_path = run_dir / "logs" / "launcher.log"
    log_path.write_text(log_text)
    return profile, data, run_dir, log_path


def test_up_detach_says_how_a_run_that_stopped_before_it_looked_ended_not_that_it_started(tmp_path):
    """``up --detach`` said "started" (exit 0) once run.json named services and endpoints, before it looked at its
    launcher's exit: a run that stopped between two of its looks (its services given up on at once, a ``down``) left a
    run.json that names them too, state ``stopped``, and ``up --detach`` said "started" of a run that was over. It says
    how the run ended, with its exit code."""
    from cso_runtime.launcher import _wait_for_detached

    profile, data, run_dir, log_path = _a_detached_run_folder(tmp_path, "the sim service is gone for good: stopping\n")
    stopped = {
        "run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [loopback_endpoint(7447)], "state": "stopped",
        "services": {"sim": {"pid": None, "start_ticks": None, "restarts": 3, "gave_up": True}},
        "outcome": "failed", "exit_code": 1, "reason": "gave up on sim: exit code 1",
    }  # fmt: skip

    def answer(run: dict, launcher_exit: int) -> tuple[int, str]:
        """``up --detach``'s answer to ``run`` in run.json, its launcher exiting with ``launcher_exit``."""
        (run_dir / "run.json").write_text(json.dumps(run))
        proc = subprocess.Popen([sys.executable, "-c", f"raise SystemExit({launcher_exit})"])  # the launcher, ending the run
        try:
            return _wait_for_detached(proc, profile, data, run_dir, None, False, log_path, 5.0, threading.Event())
        finally:
            proc.kill()
            proc.wait(timeout=30)

    code, message = answer(stopped, 1)
    assert code == 1 and message.startswith("run run1 stopped as it started: failed (gave up on sim: exit code 1)"), (code, message)
    assert "the sim service is gone for good" in message and "started (launcher pid" not in message, message
    assert json.loads((run_dir / "run.json").read_text()) == stopped  # its launcher's own account, kept
    # an episode short enough to be over, and done, before the first look (a busy host): exit 0, said ended, not failed
    code, message = answer({**stopped, "outcome": "done", "exit_code": 0, "reason": ""}, 0)
    assert code == 0 and message.startswith("run run1 started and has ended already: done (launcher pid"), (code, message)


def test_up_detach_reads_run_json_after_its_launchers_exit_not_before(tmp_path):
    """``up --detach`` read run.json, then looked at its launcher's exit: a launcher that wrote its last run.json
    (``stopped``, done: a ``down`` of a run whose episode was over) and exited between the two looks was said by its exit
    code alone, "the launcher exited with code 0", exit 1. Its exit is looked at first, then the run.json it left."""
    from cso_runtime.launcher import _wait_for_detached

    profile, data, run_dir, log_path = _a_detached_run_folder(tmp_path, "stopping services\n")
    running = {
        "run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [loopback_endpoint(7447)], "state": "starting",
        "services": {"sim": {"pid": None, "start_ticks": None, "restarts": 0, "gave_up": False}},
    }  # fmt: skip
    (run_dir / "run.json").write_text(json.dumps({**running, "endpoints": []}))  # not yet up: `up --detach` waits

    class EndsAsItIsLookedAt:
        """The launcher: at the first look at its exit it is still up, and then ends its run, done, and exits (0)."""

        pid, returncode, looks = 4242, None, 0

        def poll(self) -> int | None:
            self.looks += 1
            if self.looks == 1:
                return None
            if self.returncode is None:
                stopped = {**running, "state": "stopped", "outcome": "done", "exit_code": 0}
                (run_dir / "run.json").write_text(json.dumps(stopped))
                self.returncode = 0
            return self.returncode

        def wait(self, timeout: float | None = None) -> int:
            return 0

    code, message = _wait_for_detached(EndsAsItIsLookedAt(), profile, data, run_dir, None, False, log_path, 5.0, threading.Event())  # type: ignore[arg-type]
    assert code == 0 and message.startswith("run run1 started and has ended already: done (launcher pid 4242)"), (code, message)


def test_up_detach_of_a_launcher_killed_after_it_spawned_its_services_does_not_say_started(tmp_path):
    """``up --detach`` read run.json before it looked at its launcher: a launcher killed (SIGKILL: out of memory, a
    user's ``kill -9``) after it wrote that its services and router are up left run.json saying so, and ``up --detach``
    said "started", exit 0, of a run with no launcher. It looks at its launcher first: killed, it cleans the run up
    (its services, its current-run file) and says so."""
    from cso_runtime.config import EXIT_INTERRUPTED
    from cso_runtime.launcher import _wait_for_detached
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    runs = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])  # the launcher, killed
    proc.kill()
    proc.wait(timeout=30)
    run_dir, starting = starting_run_files(runs, proc.pid)
    running = {**starting, "run_id": run_dir.name, "state": "running", "endpoints": [loopback_endpoint(7447)],
               "services": {"sim": {"pid": None, "start_ticks": None, "restarts": 0, "gave_up": False}}}  # fmt: skip
    for path in (runs / "current.json", run_dir / "run.json"):
        path.write_text(json.dumps(running))
    (run_dir / "logs").mkdir()
    code, message = _wait_for_detached(proc, profile, data, run_dir, None, False, run_dir / "logs" / "launcher.log", 5.0, threading.Event())
    assert code == EXIT_INTERRUPTED and message.startswith(f"the launcher (pid {proc.pid}) was stopped as it started"), (code, message)
    assert not (runs / "current.json").exists()  # nothing `status` or `down` takes for a running run
    assert json.loads((run_dir / "run.json").read_text())["state"] == "stopped"


def test_up_detach_ending_a_launcher_it_gave_up_on_leaves_another_runs_current_file_alone(tmp_path):
    """``up --detach`` that stops a launcher it gave up on (killed as it started, Ctrl-C, too slow) writes that run's end
    for it. It wrote it to the current-run file too, and then removed that file: a run another ``up`` had started in the
    folder once that launcher was gone (its lock free) lost its current-run file, and ``status`` and ``down`` no longer
    found it. Only the stopped run's run.json is written; the current-run file is the running launcher's."""
    from cso_runtime.config import EXIT_INTERRUPTED
    from cso_runtime.launcher import Launcher, _stop_unstarted_launcher
    from cso_runtime.run_profile import find_profile, load_profile

    runs = tmp_path / "runs"
    _, other = starting_run_files(runs, os.getpid())  # the run started since, its launcher alive
    other = {**other, "state": "running", "endpoints": [loopback_endpoint(7447)]}
    (runs / "current.json").write_text(json.dumps(other))
    profile, data = load_profile(str(find_profile("lockstep")), {})
    given_up = Launcher(profile, data, runs / "20261206-115959-lockstep-r0")
    given_up.run_dir.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", "pass"])  # its launcher, killed before it wrote its run file
    proc.wait(timeout=30)
    _stop_unstarted_launcher(proc, given_up, EXIT_INTERRUPTED)
    assert json.loads((runs / "current.json").read_text()) == other
    ended = json.loads((given_up.run_dir / "run.json").read_text())
    assert (ended["state"], ended["outcome"], ended["launcher_pid"]) == ("stopped", "interrupted", proc.pid), ended


def test_down_while_a_detached_launcher_starts_stops_it(tmp_path, monkeypatch):
    """``down`` in the seconds between ``up --detach`` spawning its launcher and the launcher writing ``current.json``
    (its imports: 3 s on a loaded 2-core host; found by a fault-injection soak) answered "nothing running", exit 1, and
    the run came up all the same and stayed up until a second ``down``. ``up --detach`` now names its launcher in the
    run folder at once (``STARTING_LAUNCHER``), and ``down`` stops it; ``up`` says so, and the run file says stopped."""
    from cso_runtime import launcher as launcher_module
    from cso_runtime.current_run import STARTING_LAUNCHER, down
    from cso_runtime.launcher import start_detached
    from cso_runtime.run_profile import load_profile

    real_popen = subprocess.Popen
    started: list[subprocess.Popen] = []

    def slow_launcher(args, **kwargs):
        """The launcher, still importing for a minute (no signal handler yet): ``down`` comes before its run file
        whatever the host's speed."""
        if "cso_runtime.launcher" in args:
            started.append(real_popen([sys.executable, "-c", "import time; time.sleep(60)"], **kwargs))
            pipe = started[-1].stdin
            real_write = pipe.write
            # named before it is given its profile: what a `down` in between goes by
            pipe.write = lambda data: named_at_profile.append(bool(list(runs.glob(f"*/{STARTING_LAUNCHER}")))) or real_write(data)
            return started[-1]
        return real_popen(args, **kwargs)

    named_at_profile: list[bool] = []
    monkeypatch.setattr(launcher_module.subprocess, "Popen", slow_launcher)
    runs = tmp_path / "runs"
    profile, data = load_profile(str(write_profile(tmp_path)), {})
    result: list[tuple[int, str]] = []
    starter = threading.Thread(target=lambda: result.append(start_detached(profile, data, runs, ready_timeout_s=120.0)))
    starter.start()
    try:
        # what `down` goes by: up --detach names its launcher (STARTING_LAUNCHER) as it spawns it, before it gives it its
        # profile (after it, a `down` between the two said "nothing running" on a busy host)
        wait_for(lambda: started and list(runs.glob(f"*/{STARTING_LAUNCHER}")), 30, "up --detach to spawn and name its launcher")
        ok, message = down(runs)
        assert ok and "as it started" in message and f"launcher pid {started[0].pid}" in message, message
        assert named_at_profile == [True]
        starter.join(30)
        assert not starter.is_alive() and started[0].poll() is not None
        ((code, said),) = result
        assert code != 0 and "stopped as it started" in said, said
        (run_json,) = runs.glob("*/run.json")
        assert json.loads(run_json.read_text())["state"] == "stopped"
        assert not (runs / "current.json").exists() and not list(runs.glob(f"*/{STARTING_LAUNCHER}"))
    finally:
        for proc in started:
            proc.kill()
        starter.join(130)


SLOW_CHECK_METHOD = """\
# A goal selector of one's own whose import blocks on a fifo: `up`'s profile check imports it (check_method), and
# is held there until a stop, whatever the host's speed. The test holds the fifo's writing end open, never writing.
import os

with open(os.environ["CSO_TEST_CHECK_FIFO"]) as fifo:
    fifo.read()
"""


def fifo_reader_waits(fifo: Path) -> int | None:
    """A writing end of ``fifo`` once a process has it open for reading (None before: ENXIO). Kept open and never
    written to, it holds that reader in its ``read``."""
    try:
        return os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno != errno.ENXIO:
            raise
        return None


@pytest.mark.parametrize("detach", [False, True], ids=["foreground", "detach"])
def test_down_while_up_checks_its_profile_stops_that_up(tmp_path, detach):
    """``down`` while ``up`` still checks its profile (seconds: a learned method's weights, a scene to load, a method of
    one's own to import), before any launcher or run file exists, answered "nothing running" (exit 1), and the ``up``
    then started its run all the same. ``up`` now names itself in its runs folder first of all
    (``current_run.STARTING_UP_GLOB``); ``down`` stops it and says so, and the ``up`` ends at once, in the middle of its
    check (here held on a fifo by a method of one's own as it is imported), saying that no run was started: no process,
    no run folder and no file of it left."""
    from cso_runtime.config import EXIT_INTERRUPTED
    from cso_runtime.current_run import STARTING_UP_GLOB

    fifo = tmp_path / "check.fifo"
    os.mkfifo(fifo)
    (tmp_path / "slow_check_method.py").write_text(SLOW_CHECK_METHOD)
    runs = tmp_path / "runs"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")])), "CSO_TEST_CHECK_FIFO": str(fifo)}
    argv = [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(write_profile(tmp_path)), "--method", "slow_check_method:Selector"]
    argv += ["--runs-dir", str(runs), "--no-live", *(["--detach"] if detach else [])]
    up = subprocess.Popen(argv, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    writer: list[int] = []
    try:
        writer.append(wait_for(lambda: fifo_reader_waits(fifo), HANG_DEADLINE_S, "up to import the method of its profile"))
        assert list(runs.glob(STARTING_UP_GLOB)) and not [d for d in runs.iterdir() if d.is_dir()]  # named, nothing started
        down = cli("down", "--runs-dir", str(runs), cwd=tmp_path)
        assert down.returncode == 0, down.stderr
        assert f"stopped `up` (pid {up.pid}) before its run had started" in down.stdout and "no run was started" in down.stdout, down.stdout
        out, err = up.communicate(timeout=30)  # gone already: down waits for it
        assert up.returncode == EXIT_INTERRUPTED, (up.returncode, out, err)
        assert "interrupted (`cso-runtime down`, Ctrl-C or a signal) while checking the profile: no run was started" in err, err
        assert "Traceback" not in err, err
        assert not runs.exists()  # made by that up for its file, and removed with it
        assert detached_launchers(runs) == []
    finally:
        for fd in writer:
            os.close(fd)
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
        up.communicate(timeout=30)
        kill_leftovers(runs, [up.pid])


def test_up_names_itself_for_down_before_its_command_line_is_parsed(tmp_path, monkeypatch):
    """``up`` wrote its file for ``down`` (``STARTING_UP_GLOB``) only once typer had parsed its command line and the
    command had imported its first modules: in that first fifth of a second ``down`` answered "nothing running", and
    the ``up`` then started its run all the same. ``main`` now writes it before typer even sees the command line (here
    typer refuses it, as a bad flag: the file and the folders made for it go); ``up`` keeps that very file (never a
    moment without one), and writes its own where the early reading of ``--runs-dir`` was wrong. A command line that
    starts no run (``--dry-run``, ``--resolved``, ``--help``, another command) names nothing."""
    from cso_runtime import cli
    from cso_runtime.current_run import STARTING_UP_GLOB, starting_up_path

    runs = tmp_path / "made" / "runs"
    seen: list[list[Path]] = []

    def typer_refuses(prog_name: str) -> None:  # the moment typer gets the command line
        seen.append(sorted(runs.glob(STARTING_UP_GLOB)))
        raise SystemExit(2)

    monkeypatch.setattr(cli, "app", typer_refuses)
    for argv, named in (
        (["up", "--runs-dir", str(runs), "--no-live", "--bad-flag"], True),
        (["up", f"--runs-dir={runs}", "--profile", "sim"], True),
        (["up", "--runs-dir", str(runs), "--dry-run"], False),
        (["up", "--resolved", "--runs-dir", str(runs)], False),
        (["up", "--runs-dir", str(runs), "--help"], False),
        (["status", "--runs-dir", str(runs)], False),
    ):
        seen.clear()
        monkeypatch.setattr(sys, "argv", ["cso-runtime", *argv])
        with pytest.raises(SystemExit):
            cli.main()
        assert seen == [[starting_up_path(runs, os.getpid())] if named else []], argv
        assert not (tmp_path / "made").exists(), argv  # made for the file, removed with it
    monkeypatch.undo()

    wrote: list[Path] = []
    from cso_runtime import current_run

    record = current_run.record_starting_up
    monkeypatch.setattr(current_run, "record_starting_up", lambda runs_dir: (wrote.append(runs_dir), record(runs_dir))[1])
    monkeypatch.chdir(tmp_path)
    for argv, folders in (
        (["up", "--runs-dir", str(runs), "--profile", str(tmp_path / "no-such.yaml")], [runs]),  # taken over: one file
        (["up", "--scene", "--runs-dir", "--profile", str(tmp_path / "no-such.yaml")], [Path("--profile"), Path("runs")]),  # misread: a scene's value
    ):
        wrote.clear()
        monkeypatch.setattr(sys, "argv", ["cso-runtime", *argv])
        with pytest.raises(SystemExit) as ended:
            cli.main()
        assert ended.value.code not in (0, None) and wrote == folders, (ended.value.code, wrote)
        assert not list(tmp_path.rglob(STARTING_UP_GLOB)) and sorted(tmp_path.iterdir()) == [], sorted(tmp_path.iterdir())
    # Cheap as a first act must be: what writes the file imports no numpy (nor the profile's modules).
    code = "import sys, cso_runtime.current_run; print(sorted(m for m in ('numpy', 'yaml', 'zenoh', 'cso_runtime.config') if m in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True).stdout.strip() == "[]"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_up_killed_before_its_own_signal_handlers_leaves_no_file_for_down(tmp_path, sig):
    """``main`` writes ``up``'s file for ``down`` before typer parses the command line, but ``up`` puts in its signal
    handlers only once typer has called it: a SIGTERM (``kill``, a CI's cancel, ``timeout``) or a SIGHUP (its terminal
    closed) in between killed the process and left ``.up-<pid>.starting.json`` and the runs folder made for it. The
    file and folder go, and the process still dies of the signal; a command line that ends normally leaves the
    signals' handlers as it found them."""
    runs = tmp_path / "made" / "runs"
    script = textwrap.dedent(
        f"""
        import os, signal, sys, time
        from cso_runtime import cli

        def typer_parses(prog_name):  # the moment typer has the command line, before `up` runs
            assert list((cli.Path({str(runs)!r})).glob(".up-*.starting.json")), "no file to remove"
            if sys.argv[-1] == "--kill":
                os.kill(os.getpid(), {int(sig)})
                time.sleep(30)
            raise SystemExit(2)

        cli.app = typer_parses
        sys.argv = ["cso-runtime", "up", "--runs-dir", {str(runs)!r}, sys.argv[1]]
        try:
            cli.main()
        except SystemExit:
            pass
        print(signal.getsignal({int(sig)}) == signal.SIG_DFL)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    killed = subprocess.run([sys.executable, "-c", script, "--kill"], capture_output=True, text=True, timeout=60, env=env, check=False)
    assert killed.returncode == -sig, (killed.returncode, killed.stderr)
    assert not (tmp_path / "made").exists(), sorted(str(p) for p in tmp_path.rglob("*"))
    ended = subprocess.run([sys.executable, "-c", script, "--bad-flag"], capture_output=True, text=True, timeout=60, env=env, check=False)
    assert ended.returncode == 0 and ended.stdout.strip() == "True", (ended.returncode, ended.stdout, ended.stderr)
    assert not (tmp_path / "made").exists()


@pytest.mark.parametrize("when", ["the file just written", "the file being removed"])
def test_a_sigterm_as_main_names_or_unnames_up_still_leaves_no_file(tmp_path, when):
    """``main``'s early handler removes ``up``'s file for ``down`` once ``_starting_up`` names it, but the file was
    written before that: a SIGTERM just after the write (``down`` sends one as soon as it sees the file) ran the handler
    with nothing named, and the process died leaving the file and its runs folder. Likewise as ``main`` ended, between
    taking the file off ``_starting_up`` and removing it. The signal, sent by the process itself at those points (no
    timing), is acted on with the file named: it goes, and the process still dies of SIGTERM."""
    runs = tmp_path / "made" / "runs"
    script = textwrap.dedent(
        f"""
        import os, signal, sys
        from cso_runtime import cli, current_run

        record = current_run.record_starting_up
        sent = []

        def kill_once():
            if not sent:
                sent.append(True)
                os.kill(os.getpid(), signal.SIGTERM)

        def record_then_killed(runs_dir):
            remove = record(runs_dir)
            if {when!r} == "the file just written":
                kill_once()

            def remove_killed():
                if {when!r} == "the file being removed":
                    kill_once()
                remove()

            return remove_killed

        current_run.record_starting_up = record_then_killed

        def typer_refuses(prog_name):
            raise SystemExit(2)

        cli.app = typer_refuses
        sys.argv = ["cso-runtime", "up", "--runs-dir", {str(runs)!r}]
        try:
            cli.main()
        except SystemExit:
            pass
        print("survived")
        """
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    killed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=env, check=False)
    assert killed.returncode == -signal.SIGTERM, (killed.returncode, killed.stdout, killed.stderr)
    assert not (tmp_path / "made").exists(), sorted(str(p) for p in tmp_path.rglob("*"))


def test_down_removes_the_file_of_an_up_that_is_gone_and_never_signals_a_process_that_took_its_pid(tmp_path):
    """An ``up`` killed (SIGKILL) in its check leaves its file (``STARTING_UP_GLOB``); its pid may be another process's
    since. ``down`` tells them apart by the start time the file records, as for a run file: that process is left alone
    (here this very test), and the stale file removed."""
    from cso_runtime.current_run import down, starting_up_path
    from cso_runtime.supervision import process_start_ticks

    runs = tmp_path / "runs"
    runs.mkdir()
    ticks = process_start_ticks(os.getpid())
    assert ticks is not None
    stale = starting_up_path(runs, os.getpid())
    stale.write_text(json.dumps({"up_pid": os.getpid(), "up_start_ticks": ticks + 1}))  # the pid, not the process
    ok, message = down(runs, timeout_s=0.0)
    assert not ok and message.startswith("nothing running"), message
    assert not stale.exists()


def test_down_never_signals_a_process_that_took_a_dead_runs_pid(tmp_path):
    """A run file outlives its launcher (SIGKILL, a reboot); its pids may belong to other processes since.
    The start time the file records tells them apart: ``down`` leaves such a process alone, and ``up`` is
    not refused because of it."""
    from cso_runtime.current_run import current_launcher_alive, down
    from cso_runtime.supervision import process_start_ticks

    bystander = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
    try:
        ticks = process_start_ticks(bystander.pid)
        assert isinstance(ticks, int)
        runs = tmp_path / "runs"
        runs.mkdir()
        stale = {"run_id": "old", "robot": "r0", "launcher_pid": bystander.pid, "launcher_start_ticks": ticks - 1,
                 "services": {"mapper": {"pid": bystander.pid, "start_ticks": ticks - 1}}}
        (runs / "current.json").write_text(json.dumps(stale))
        assert not current_launcher_alive(stale)
        assert current_launcher_alive({**stale, "launcher_start_ticks": ticks})  # the very process: alive
        ok, message = down(runs, timeout_s=1.0)
        assert ok and "stopped run old" in message and not (runs / "current.json").exists()
        # Nothing of it ran: said, not a plain "stopped" as if down had stopped it.
        assert f"its launcher, pid {bystander.pid}, had already exited: {runs / 'current.json'} cleared" in message, message
        assert bystander.poll() is None  # not signalled
        # A service the launcher found dead when it wrote the file has no start time: its pid is not its own.
        dead_service = {**stale, "services": {"mapper": {"pid": bystander.pid, "start_ticks": None}}}
        (runs / "current.json").write_text(json.dumps(dead_service))
        ok, message = down(runs, timeout_s=1.0)
        assert ok and bystander.poll() is None
    finally:
        bystander.kill()
        bystander.wait(timeout=30)


def test_down_beside_a_run_file_its_launcher_outlived_stops_an_up_checking_its_profile(tmp_path):
    """A run file outlives its launcher (SIGKILL, a reboot), and ``up`` starts anyway (it is not refused by a dead
    launcher's file). ``down`` while that ``up`` checks its profile cleared the dead run's file and left the ``up``
    alone, which then started its run: the ``up`` it named in the runs folder (``STARTING_UP_GLOB``) is stopped as with
    no run file at all, and both are said. Here a process of the test's stands for that ``up``."""
    from cso_runtime.current_run import down, starting_up_path
    from cso_runtime.supervision import process_start_ticks

    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
    try:
        ticks = process_start_ticks(up.pid)
        assert isinstance(ticks, int)
        runs = tmp_path / "runs"
        runs.mkdir()
        stale = {"run_id": "old", "robot": "r0", "launcher_pid": up.pid, "launcher_start_ticks": ticks - 1, "services": {}}  # its pid, since taken
        (runs / "current.json").write_text(json.dumps(stale))
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": ticks}))
        ok, message = down(runs, timeout_s=5.0)
        assert ok and "stopped run old" in message and f"stopped `up` (pid {up.pid}) before its run had started" in message, message
        assert up.wait(timeout=30) == -signal.SIGTERM
        assert not (runs / "current.json").exists() and list(runs.iterdir()) == []
        bystander = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
        try:  # an `up` cleaning up after its own dead launcher (launcher._stop_unstarted_launcher) leaves another `up` be
            b_ticks = process_start_ticks(bystander.pid)
            (runs / "current.json").write_text(json.dumps(stale))
            starting_up_path(runs, bystander.pid).write_text(json.dumps({"up_pid": bystander.pid, "up_start_ticks": b_ticks}))
            ok, message = down(runs, timeout_s=0.0, stop_starting=False)
            assert ok and "stopped `up`" not in message and bystander.poll() is None and starting_up_path(runs, bystander.pid).exists(), message
        finally:
            bystander.kill()
            bystander.wait(timeout=30)
    finally:
        if up.poll() is None:
            up.kill()
        up.wait(timeout=30)


DOWN_FROM_AN_UP = """\
# An `up --detach` whose launcher died after writing its run file cleans up with down() (launcher._stop_unstarted_launcher)
# while its own file still names it (STARTING_UP_GLOB): down must not stop the very process that calls it.
import json, os, sys
from pathlib import Path

from cso_runtime.current_run import down, starting_up_path
from cso_runtime.supervision import process_start_ticks

runs = Path(sys.argv[1])
ticks = process_start_ticks(os.getpid())
(runs / "current.json").write_text(json.dumps({"run_id": "died", "robot": "r0", "launcher_pid": os.getpid(), "launcher_start_ticks": ticks - 1, "services": {}}))
starting_up_path(runs, os.getpid()).write_text(json.dumps({"up_pid": os.getpid(), "up_start_ticks": ticks}))
ok, message = down(runs, timeout_s=0.0)
print("alive after down:", ok, message, starting_up_path(runs, os.getpid()).exists())
"""


def test_down_called_by_an_up_never_stops_that_up(tmp_path):
    """``up --detach`` whose launcher was killed after writing its run file cleans the run up with ``down`` (its launcher
    is dead) while its own file still names it for ``down`` (``STARTING_UP_GLOB``): ``down`` leaves the process that
    calls it alone (it would SIGTERM, then SIGKILL, itself) and its file in place."""
    runs = tmp_path / "runs"
    runs.mkdir()
    (tmp_path / "down_from_an_up.py").write_text(DOWN_FROM_AN_UP)
    done = subprocess.run([sys.executable, str(tmp_path / "down_from_an_up.py"), str(runs)], capture_output=True, text=True, timeout=60, start_new_session=True)
    assert done.returncode == 0, (done.returncode, done.stdout, done.stderr)
    assert "alive after down: True stopped run died" in done.stdout and done.stdout.rstrip().endswith("True"), done.stdout
    assert "stopped `up`" not in done.stdout, done.stdout


def test_down_waits_for_the_services_it_kills_to_be_gone(tmp_path):
    """A launcher killed outright leaves its services to ``down``, which kills them; a stopped process takes a
    moment to go after SIGKILL, and ``down`` waits for that rather than report it as still running."""
    from cso_runtime.current_run import down
    from cso_runtime.supervision import process_start_ticks

    service = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True)
    reaper = threading.Thread(target=service.wait, daemon=True)  # its parent reaps it, as init does a dead launcher's
    reaper.start()
    try:
        os.kill(service.pid, signal.SIGSTOP)
        runs = tmp_path / "runs"
        runs.mkdir()
        gone_launcher = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True).stdout.strip()
        info = {"run_id": "killed", "robot": "r0", "launcher_pid": int(gone_launcher), "launcher_start_ticks": 1,
                "services": {"mapper": {"pid": service.pid, "start_ticks": process_start_ticks(service.pid)}}}
        (runs / "current.json").write_text(json.dumps(info))
        ok, message = down(runs)
        assert ok and message == f"stopped run killed (its launcher, pid {gone_launcher}, had already exited: killed the 1 service(s) it left running; {runs / 'current.json'} cleared)", message
        reaper.join(timeout=10)  # poll() answers None while another thread waits on the process
        assert service.returncode == -signal.SIGKILL
    finally:
        if service.poll() is None:
            service.kill()


SLOW_STOPPING_LAUNCHER = """
import pathlib, signal, sys, time
out = pathlib.Path(sys.argv[1])
def finish(signum, frame):
    time.sleep(float(sys.argv[2]))  # stopping its services and writing its results
    (out / "finished").write_text("yes")
    sys.exit(0)
signal.signal(signal.SIGINT, finish)
(out / "ready").write_text("yes")
time.sleep(60)
"""


@pytest.mark.parametrize("timeout_s", [None, 0.3])
def test_down_gives_the_launcher_the_stop_time_of_its_run(tmp_path, timeout_s):
    """``down`` lets a launcher that is stopping its services and writing its results finish (three stop
    stages of the run's ``stop_timeout_s``, plus a margin) before it escalates to SIGTERM; ``--timeout-s``
    shorter than the stop escalates."""
    from cso_runtime.current_run import DOWN_TERM_WAIT_S, down
    from cso_runtime.supervision import process_start_ticks

    stop_s = 1.5 if timeout_s is None else 60.0  # escalated: a stop that cannot end within the 0.3 s however late down looks
    argv = [sys.executable, "-c", SLOW_STOPPING_LAUNCHER, str(tmp_path), str(stop_s)]
    launcher = subprocess.Popen(argv, start_new_session=True)
    reaper = threading.Thread(target=launcher.wait, daemon=True)
    reaper.start()
    try:
        wait_for(lambda: (tmp_path / "ready").exists(), 30, "the launcher's SIGINT handler")
        runs = tmp_path / "runs"
        runs.mkdir()
        info = {"run_id": "slow", "robot": "r0", "launcher_pid": launcher.pid, "launcher_start_ticks": process_start_ticks(launcher.pid), "stop_timeout_s": 0.2}
        (runs / "current.json").write_text(json.dumps(info))
        started_s = time.monotonic()
        ok, message = down(runs, timeout_s)
        took_s = time.monotonic() - started_s
        reaper.join(timeout=10)
        if timeout_s is None:  # 3 * 0.2 s + the margin: it finished on its own
            assert ok and message == "stopped run slow", message
            assert launcher.returncode == 0 and (tmp_path / "finished").exists()
        else:  # escalated, and said: its results may be missing
            # down's SIGTERM ended it: a process's exit status keeps the signal it began to die of, even when SIGKILL followed.
            assert launcher.returncode == -signal.SIGTERM and not (tmp_path / "finished").exists(), (message, launcher.returncode)
            said = "stopped run slow (its launcher did not stop on SIGINT within 0.3 s: {})"
            assert ok and message in (said.format("SIGTERM"), said.format("SIGKILL")), message
            # Dying still takes a CPU: a host that stalls the launcher past the SIGTERM stage (once in a CI run) lets down
            # go on to SIGKILL and say so; never before the stage is over.
            assert message == said.format("SIGTERM") or took_s >= timeout_s + DOWN_TERM_WAIT_S, (message, took_s)
    finally:
        if launcher.poll() is None:
            launcher.kill()


def test_down_names_only_a_signal_it_sent(tmp_path, monkeypatch):
    """``down`` named the signal of its next stage before it sent it: a launcher that ended just then, late but on
    its own (its results written), was reported as stopped by SIGTERM (or SIGKILL) that no one had sent."""
    from cso_runtime import current_run

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "current.json").write_text(json.dumps({"run_id": "late", "robot": "r0", "launcher_pid": 4242}))
    alive, sent = [True], []
    real_kill = os.kill

    def kill(pid: int, sig: int) -> None:
        if pid != 4242:
            return real_kill(pid, sig)
        if sig == signal.SIGTERM:  # it ended between down's look and its SIGTERM
            alive[0] = False
            raise ProcessLookupError
        sent.append(sig)

    monkeypatch.setattr(current_run, "current_launcher_alive", lambda info: True)
    monkeypatch.setattr(current_run, "pid_alive", lambda pid: pid == 4242 and alive[0])
    monkeypatch.setattr(current_run, "process_state", lambda pid: "S")
    monkeypatch.setattr(current_run.os, "kill", kill)
    ok, message = current_run.down(runs, timeout_s=0.1)
    assert ok and message == "stopped run late" and sent == [signal.SIGINT, signal.SIGCONT], (message, sent)


def test_a_scene_file_is_kept_as_an_absolute_path_in_the_run_profile(tmp_path, monkeypatch):
    """``up --scene office.yaml`` from a folder: the run's profile copy (``runs/<id>/profile.yaml``, which
    ``cso-runtime service ... --config`` takes) must name the same file from anywhere."""
    from cso_runtime.run_profile import load_profile

    monkeypatch.chdir(tmp_path)
    shutil.copy(REPO / "cso_runtime" / "data" / "scenes" / "img_1.png", tmp_path / "office.png")
    profile, data = load_profile("lockstep", {"scene": "office.png"})
    assert data["scene"] == profile.scene == str(tmp_path / "office.png")
    assert load_profile("lockstep", {"scene": "generated:small:2:0"})[1]["scene"] == "generated:small:2:0"


def test_a_service_that_refuses_its_configuration_is_not_restarted(tmp_path):
    """Exit code 2 (a configuration the service refuses) would repeat on every restart: the launcher
    gives up on that service at once and says why; any other exit is restarted with back-off."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.run_dir.mkdir()
    refuse = "print('2026-12-01 10:00:00,000 ERROR cso.service: sim: bad configuration: no such scene'); raise SystemExit(2)"
    refused = Child("sim", [sys.executable, "-c", refuse], tmp_path / "sim.log")
    crashed = Child("mapper", [sys.executable, "-c", "raise ValueError('map of another shape')"], tmp_path / "mapper.log")
    launcher.children = [refused, crashed]
    for c in launcher.children:
        c.spawn()
        c.proc.wait(timeout=30)
    launcher.supervise()
    assert refused.gave_up and refused.restarts == 0 and refused.exit_codes == [2]
    assert not crashed.gave_up and crashed.restart_at is not None and crashed.exit_codes == [1]
    # The launcher's own message says why, from each log: a logged error, or a traceback's last line.
    assert refused.last_error() == "cso.service: sim: bad configuration: no such scene"
    assert crashed.last_error() == "ValueError: map of another shape"
    # Dead before its logging began (the interpreter's own line): said, not "no error logged"; a log of routine
    # lines only has no error.
    (tmp_path / "early.log").write_text("/usr/bin/python3: No module named services.sim\n\n")
    assert Child("sim", [], tmp_path / "early.log").last_error() == "/usr/bin/python3: No module named services.sim"
    (tmp_path / "calm.log").write_text("2026-12-01 10:00:00,000 INFO cso.sim: step 3\n")
    assert Child("sim", [], tmp_path / "calm.log").last_error() == ""


def test_a_run_file_that_cannot_be_written_is_said_and_the_supervision_goes_on(tmp_path, caplog):
    """A runs folder whose disk filled up mid-run (a 200 kB tmpfs): the launcher's next write of run.json, as it
    restarted a killed service, raised out of its loop; every service was stopped and the run left as 'launcher
    died', with a traceback in its log. The run file only helps ``status``, ``down`` and ``runs`` find the run: a
    write that fails is said in the launcher's log (once, until one works again) and the supervision goes on."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    launcher.run_dir.mkdir(parents=True)
    (launcher.run_dir / "run.json").mkdir()  # cannot be written over, as on a full disk
    children = [Child(name, [sys.executable, "-c", "raise SystemExit(2)"], tmp_path / f"{name}.log") for name in ("sim", "policy")]
    for c in children:
        c.spawn()
        c.proc.wait(timeout=30)
    with caplog.at_level("ERROR", logger="cso.launcher"):
        for c in children:
            launcher.children.append(c)
            launcher.supervise()  # gives up on it (exit code 2), and writes the run file
        assert [c.gave_up for c in children] == [True, True]
        said = [r.getMessage() for r in caplog.records if "cannot write" in r.getMessage()]
        assert len(said) == 1 and str(launcher.run_dir / "run.json") in said[0] and "status" in said[0], said
        (launcher.run_dir / "run.json").rmdir()
        launcher.write_run_file("stopped")  # written again, and the next failure is said again
    assert json.loads((launcher.run_dir / "run.json").read_text())["state"] == "stopped"


def test_a_given_up_service_that_no_one_serves_stops_the_episode(tmp_path):
    """A policy that refused its configuration (say, a corrupt weights file) leaves nobody choosing goals:
    the episode must stop saying so once the grace for another process to serve it has passed, not run
    on to its step limit. A token from such a process (another host) keeps the episode going."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {"supervision": {"given_up_grace_s": 5.0}})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.run_dir.mkdir()
    policy = Child("policy", [sys.executable, "-c", "raise SystemExit(2)"], tmp_path / "policy.log")
    mapper = Child("mapper", [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "mapper.log")
    launcher.children = [policy, mapper]
    try:
        for c in launcher.children:
            c.spawn()
        policy.proc.wait(timeout=30)
        launcher.supervise()
        assert policy.gave_up and policy.gave_up_at is not None and not mapper.gave_up
        assert launcher.unserved_services(policy.gave_up_at + 4.9) == []  # still within the grace
        assert launcher.unserved_services(policy.gave_up_at + 5.0) == ["policy"]
        launcher.alive_services.add("policy")  # another process declared the policy's token
        assert launcher.unserved_services(policy.gave_up_at + 60.0) == []
    finally:
        mapper.proc.kill()
        mapper.proc.wait(timeout=30)


def test_a_service_that_ignores_the_stop_signals_leaves_its_stacks_in_its_log_before_the_kill(tmp_path):
    """A hung service (it never gets to act on SIGINT or SIGTERM) is killed at the last stage; its log
    must then say where it hung: every thread's stack, written by faulthandler on STACK_DUMP_SIGNAL."""
    from cso_runtime.supervision import Child, stop_children

    hung = textwrap.dedent(
        """
        import signal, sys, time
        from cso_runtime.processes import dump_stacks_on_signal
        dump_stacks_on_signal()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        def stuck_in_a_handler():
            print("ready", flush=True)
            while True:
                time.sleep(0.05)
        stuck_in_a_handler()
        """
    )
    child = Child("frontier", [sys.executable, "-c", hung], tmp_path / "frontier.log")
    child.spawn()
    try:
        deadline = time.monotonic() + 30
        while "ready" not in child.log_path.read_text() and time.monotonic() < deadline:
            assert child.alive, child.log_path.read_text()
            time.sleep(0.02)  # polling the child's own output, with a deadline
        stop_children([child], stage_timeout_s=0.3)
        assert child.proc.wait(timeout=10) == -signal.SIGKILL
        logged = child.log_path.read_text()
        assert "most recent call first" in logged and "stuck_in_a_handler" in logged
    finally:
        if child.alive:
            child.proc.kill()


def test_a_stopped_service_is_continued_to_stop_cleanly_not_killed_after_every_stage(tmp_path):
    """``down`` (or the episode's end) while a service is stopped (SIGSTOP, a debugger, Ctrl-Z of its own): its SIGINT
    and SIGTERM stayed pending, so it waited out both stages (6 s with the profiles' 3 s) and was SIGKILLed, with no
    clean stop (its log without "stopped", its trace and profile unwritten). Each stage's signal now comes with a
    SIGCONT: it handles its SIGINT at once and stops cleanly."""
    from cso_runtime.supervision import Child, process_state, stop_children

    service = textwrap.dedent(
        """
        import signal, sys, threading
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda signum, frame: stop.set())
        print("ready", flush=True)
        stop.wait()
        print("stopped cleanly", flush=True)
        """
    )
    child = Child("planner", [sys.executable, "-c", service], tmp_path / "planner.log")
    child.spawn()
    try:
        assert child.proc is not None
        wait_for(lambda: "ready" in child.log_path.read_text() or not child.alive, 30, "the service to start")
        child.came_up = True
        os.kill(child.proc.pid, signal.SIGSTOP)
        wait_for(lambda: process_state(child.proc.pid) == "T", 10, "the service to be stopped", period_s=0.01)
        t0 = time.monotonic()
        stop_children([child], stage_timeout_s=5.0)
        took_s = time.monotonic() - t0
        assert child.proc.returncode == 0 and "stopped cleanly" in child.log_path.read_text(), (child.proc.returncode, child.log_path.read_text())
        assert took_s < 5.0, took_s  # within the first stage, not after two
    finally:
        if child.alive:
            assert child.proc is not None
            child.proc.kill()
            child.proc.wait(10)


def test_a_service_stopped_before_it_came_up_leaves_no_traceback(tmp_path):
    """``down`` right after ``up`` stops services still importing, before their handlers: SIGINT ended each one
    with a KeyboardInterrupt traceback in its log, read back by ``logs`` as five crashes. One not come up gets
    SIGTERM first and ends quietly; one that is up still gets SIGINT first, its clean stop."""
    from cso_runtime.supervision import Child, stop_children

    importing = "print('ready', flush=True)\nwhile True:\n    sum(range(1000))"  # no handler of its own yet
    up = textwrap.dedent(
        """
        import signal, sys, time
        signal.signal(signal.SIGINT, lambda signum, frame: (print("stopped on", signal.Signals(signum).name, flush=True), sys.exit(0)))
        print("ready", flush=True)
        while True:
            time.sleep(0.05)
        """
    )
    starting = Child("policy", [sys.executable, "-c", importing], tmp_path / "policy.log")
    running = Child("mapper", [sys.executable, "-c", up], tmp_path / "mapper.log")
    try:
        for c in (starting, running):
            c.spawn()
        running.came_up = True
        for c in (starting, running):
            wait_for(lambda c=c: "ready" in c.log_path.read_text() or not c.alive, 30, f"{c.name} to start")
        stop_children([starting, running], stage_timeout_s=10.0)
        assert starting.proc.wait(timeout=10) == -signal.SIGTERM
        assert "Traceback" not in starting.log_path.read_text(), starting.log_path.read_text()
        assert running.proc.wait(timeout=10) == 0 and "stopped on SIGINT" in running.log_path.read_text()
    finally:
        for c in (starting, running):
            if c.alive:
                c.proc.kill()


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            kids += [int(k) for k in (task / "children").read_text().split()]
    return kids


def test_a_frontier_service_stopped_while_it_waits_for_its_helper_logs_a_plain_stop(tmp_path):
    """The launcher stops a service that has not come up with SIGTERM to its process group, which holds the
    frontier service's layer helper: stopped while it waited for that helper (still importing), the service
    logged the helper gone as a warning (and named it again in its last line), as if it had failed. Now: a plain
    stop, exit 0, no warning; the helper is gone with it."""
    from cso_runtime.supervision import Child, signal_group

    argv = [*python_module_argv("services.frontier"), "--config", str(write_profile(tmp_path)), "--robot", "r0", "--mode", "peer", "--listen", "tcp/127.0.0.1:0"]
    frontier = Child("frontier", argv, tmp_path / "frontier.log")
    helper = 0
    try:
        frontier.spawn()

        def the_helper() -> int:
            for kid in _children(frontier.proc.pid):
                with contextlib.suppress(OSError):
                    if b"spawn_main" in Path(f"/proc/{kid}/cmdline").read_bytes():
                        return kid
            return 0

        helper = wait_for(the_helper, 30, "the layer helper to start")
        os.kill(helper, signal.SIGSTOP)  # held while it imports: the service waits for it (helper_start_s)
        signal_group(frontier.proc.pid, signal.SIGTERM)  # the launcher's stop of a service not come up
        os.kill(helper, signal.SIGCONT)  # it dies of the group's SIGTERM, as one still importing does
        assert frontier.proc.wait(timeout=30) == 0
        text = frontier.log_path.read_text()
        assert "frontier: stopped" in text and "frontier layer helper ready" not in text, text
        assert not re.search(r"WARNING|ERROR|Traceback", text), text
        assert "frontier layers: 0 by the helper process, 0 here\n" in text, text
        wait_for(lambda: not pid_alive(helper), 10, "the helper to be gone")
    finally:
        if frontier.alive:
            signal_group(frontier.proc.pid, signal.SIGKILL)
        if helper and pid_alive(helper):
            os.kill(helper, signal.SIGKILL)


def test_launcher_takes_the_published_result_and_says_when_none_comes(tmp_path):
    """The result published on ``episode_result`` is used as is; without one, the launcher keeps asking
    until its deadline and then reports that none came (no summary is written silently)."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import EpisodeResultMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)
    asked: list[str] = []
    nobody = SimpleNamespace(get=lambda key, timeout: asked.append(key) or [])
    assert launcher.wait_for_result(nobody, wait_s=0.3) is None and len(asked) >= 2  # asked again, then gave up
    free = np.ones((3, 4), bool)
    res = EpisodeResultMsg("s", 10, 1.2, 98.0, 1.3, 4.5, "no_frontier", 3, np.ones(3), np.zeros((4, 2)), np.linspace(0, 98, 4), free, free, 0.1, "greedy-dist", 0)
    launcher._on_sample(SimpleNamespace(key_expr=keys.episode_result, payload=SimpleNamespace(to_bytes=lambda: encode(res))))
    asked.clear()
    got = launcher.wait_for_result(nobody, wait_s=5.0)
    assert got is not None and got.steps == 10 and got.terminated_by == "no_frontier" and asked == []


@pytest.mark.parametrize("stay_after_done", [False, True])
def test_a_full_disk_at_the_episodes_end_is_said_and_the_run_stops_cleanly(tmp_path, monkeypatch, caplog, stay_after_done):
    """The episode ended, and its summary.json cannot be written (ENOSPC): the launcher raised out of its loop with a
    traceback. It says which file and why, stops its services, leaves run.json as a failed run and exits 1 (docs/commands.md's
    exit codes: ran but did not succeed), a detached run (``stay_after_done``) too: it has nothing left to stay for."""
    import errno

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    summary = launcher.run_dir / "summary.json"

    def full_disk(*args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(summary))

    monkeypatch.setattr(launcher_module, "write_episode_outputs", full_disk)
    monkeypatch.setattr(Child, "spawn", lambda self: None)  # no service processes: the episode below has ended
    launcher.status = EpisodeStatusMsg(state="done", step=10, scene="s", method="greedy-dist", episode=1)
    launcher.result = _fake_result()
    with caplog.at_level("INFO", logger="cso.launcher"):
        assert launcher.run(stay_after_done=stay_after_done) == 1
    assert f"cannot write the episode's results: {summary}: No space left on device" in caplog.text, caplog.text
    # Its figures were in no file and no line: they are logged (the terminal keeps them when the disk cannot).
    figures = "episode coverage: 98.00% coverage in 10 steps; 1.20 m2 explored, 0.1200 m2/step, path 4.50 m, 3 decisions"
    assert f"{figures}; not written to {launcher.run_dir}" in caplog.text, caplog.text
    info = json.loads((launcher.run_dir / "run.json").read_text())
    assert info["state"] == "stopped" and info["exit_code"] == 1 and info["outcome"] == "failed"
    # Its last line said "results in RUN/: report.html (all of it, for a browser), summary.json, ..." of files never written.
    last = caplog.records[-1].getMessage()
    assert "results in" not in caplog.text.split("cannot write the episode's results", 1)[1], caplog.text
    assert last == f"no results: the episode's results could not be written (see above); the run's profile and logs are in {launcher.run_dir}/ (`cso-runtime logs --run {launcher.run_dir}`)", last


def _sleeping_child(tmp_path: Path, name: str = "planner"):
    """A service stand-in: a real process that runs until killed."""
    from cso_runtime.supervision import Child

    return Child(name, [sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / f"{name}.log")


def test_a_service_that_crashes_while_the_launcher_waits_for_the_result_is_noticed(tmp_path, caplog):
    """The episode said it ended and the launcher asked for its result for up to 15 s without supervising: a service
    that crashed meanwhile was neither logged, nor counted, nor restarted until the wait was over. It supervises
    between its queries."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.run_dir.mkdir(parents=True)
    planner = _sleeping_child(tmp_path)
    launcher.children = [planner]

    def crash_then_no_answer(key: str, timeout: float) -> list[Any]:
        if not planner.exit_codes and planner.proc is not None and planner.proc.poll() is None:  # crashes once, as the query goes out
            planner.proc.kill()
            planner.proc.wait(timeout=30)
        return []

    try:
        planner.spawn()
        with caplog.at_level("WARNING", logger="cso.launcher"):
            assert launcher.wait_for_result(SimpleNamespace(get=crash_then_no_answer), wait_s=2.0) is None
        assert planner.exit_codes == [-signal.SIGKILL], caplog.text
        assert f"planner exited (code -{int(signal.SIGKILL)}); restart 1/{profile.supervision.max_restarts}" in caplog.text, caplog.text
    finally:
        if planner.proc is not None and planner.proc.poll() is None:
            planner.proc.kill()
            planner.proc.wait(timeout=30)


@pytest.mark.parametrize("phase", ["write_outputs", "finish_recording"])
def test_a_service_that_crashes_while_the_episodes_end_is_written_is_restarted(tmp_path, monkeypatch, caplog, phase):
    """The launcher wrote the episode's results (summary, plots, report) and finished its recording and GIF with its
    supervision stopped, for seconds: a service that crashed meanwhile was not restarted, and `up` looked frozen. They
    are written on a thread of their own while the run loop goes on supervising; the run still ends done."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    planner = _sleeping_child(tmp_path)
    restarts_seen: list[int] = []

    def crash_and_wait_for_the_restart() -> None:
        """The phase takes as long as the launcher needs to restart a service that crashes as it starts (``HANG_DEADLINE_S`` at most: a loaded host is slow to spawn it)."""
        if restarts_seen:  # `finish_recording` again, in the run's clean-up
            return
        assert planner.proc is not None
        planner.proc.kill()
        deadline = time.monotonic() + HANG_DEADLINE_S
        while planner.restarts == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        restarts_seen.append(planner.restarts)

    def write_outputs(self: Launcher, result: Any) -> Path:
        crash_and_wait_for_the_restart()
        self.written_result = result
        return self.run_dir

    def spawn_all(self: Launcher) -> None:
        planner.spawn()
        self.children.append(planner)

    monkeypatch.setattr(Launcher, "spawn_all", spawn_all)
    if phase == "write_outputs":
        monkeypatch.setattr(Launcher, "write_outputs", write_outputs)
    else:
        monkeypatch.setattr(Launcher, "write_outputs", lambda self, result: self.run_dir)
        monkeypatch.setattr(Launcher, "finish_recording", lambda self, recorder: crash_and_wait_for_the_restart())
    launcher.status = EpisodeStatusMsg(state="done", step=10, scene="s", method="greedy-dist", episode=1)
    launcher.result = _fake_result()
    try:
        with caplog.at_level("INFO", logger="cso.launcher"):
            assert launcher.run() == 0, caplog.text
        assert restarts_seen == [1], caplog.text
        assert f"planner exited (code -{int(signal.SIGKILL)}); restart 1/{profile.supervision.max_restarts}" in caplog.text, caplog.text
        info = json.loads((launcher.run_dir / "run.json").read_text())
        assert info["outcome"] == "done" and info["services"]["planner"]["restarts"] == 1, info
    finally:
        if planner.proc is not None and planner.proc.poll() is None:
            planner.proc.kill()
            planner.proc.wait(timeout=30)


def test_a_restart_after_the_episode_ended_keeps_its_end_state_in_the_run_file(tmp_path):
    """A service restarted once the episode's results are written (supervision goes on through the episode's end)
    rewrote run.json as "running", which `runs` reads as a run still exploring: it keeps the episode's end state."""
    import threading

    from cso_runtime.launcher import EpisodeEnd, Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    launcher.run_dir.mkdir(parents=True)
    launcher.write_run_file("running")
    end = EpisodeEnd(EpisodeStatusMsg(state="done", step=10, scene="s", method="greedy-dist", episode=1), _fake_result(), threading.Thread(), threading.Event(), True)
    end.outputs_done.set()
    launcher.settle_episode_end(end)
    launcher.write_run_file("running")  # what a restart by `supervise` writes
    assert json.loads((launcher.run_dir / "run.json").read_text())["state"] == "done"


def test_the_current_run_file_is_written_before_run_json_which_up_detach_waits_for(tmp_path, monkeypatch):
    """``up --detach`` says "started" once run.json names the services and the router's endpoints; run.json was written
    first, and a script's ``status`` right after could read the current-run file as it still was ("starting", no
    endpoints: "client mode needs at least one --connect endpoint", twice in one CI run). Whatever run.json says, the
    current-run file said it first."""
    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    launcher.run_dir.mkdir(parents=True)
    seen: list[tuple[str, bool]] = []
    write = launcher_module.write_text_atomic

    def checked(path: Path, text: str) -> None:
        if path.name == "run.json":
            current = launcher.run_dir.parent / "current.json"
            seen.append((path.name, current.exists() and current.read_text() == text))
        write(path, text)

    monkeypatch.setattr(launcher_module, "write_text_atomic", checked)
    launcher.write_run_file("starting")  # run.json first, this once (test_a_run_has_its_run_json_before_...)
    launcher.endpoints = ["tcp/127.0.0.1:7447"]
    launcher.write_run_file("running")
    launcher.write_run_file("stopped")
    assert seen == [("run.json", False), ("run.json", True), ("run.json", True)]
    assert json.loads((launcher.run_dir / "run.json").read_text())["endpoints"] == ["tcp/127.0.0.1:7447"]


def test_a_run_has_its_run_json_before_the_current_run_file_names_it_for_logs_follow(tmp_path, monkeypatch):
    """``logs -f`` goes from the current-run file to the run's run.json (``logs_grow``: is it still going on?). With the
    current-run file written first on the launcher's first write too ("starting"), ``logs -f`` at that moment found the
    run's folder and no run.json in it, took the run for ended, printed the launcher's first lines and "run ... has
    ended", and left. Whenever the current-run file names the run, the run has a run.json."""
    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.runs import logs_grow, resolve_run

    runs = tmp_path / "runs"
    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, runs / "run")
    (launcher.run_dir / "logs").mkdir(parents=True)
    (launcher.run_dir / "logs" / "launcher.log").write_text("")
    write = launcher_module.write_text_atomic
    followed: list[bool] = []

    def checked(path: Path, text: str) -> None:
        write(path, text)
        if path.name == "current.json":  # `logs -f` just now
            followed.append(resolve_run(runs) == launcher.run_dir and logs_grow(launcher.run_dir))

    monkeypatch.setattr(launcher_module, "write_text_atomic", checked)
    launcher.write_run_file("starting")
    launcher.endpoints = ["tcp/127.0.0.1:7447"]
    launcher.write_run_file("running")
    assert followed == [True, True], followed


def test_a_run_folder_made_again_while_the_run_starts_says_starting_not_running(tmp_path, capsys):
    """The run folder deleted as ``up`` started (``tend_run_folder`` makes it again before the router opens) wrote the run
    file as "running", with no endpoints yet: ``status`` said "nothing running (no current run in runs ...)" of a run
    that was starting, and ``status --watch`` ended there. The run file made again says the state it had."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import status_main

    runs = tmp_path / "runs"
    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, runs / "run")
    launcher.run_dir.mkdir(parents=True)
    launcher.write_run_file("starting")
    shutil.rmtree(launcher.run_dir)
    try:
        launcher.tend_run_folder(lost=True)
    finally:
        launcher.run_folder.close()
    for path in (runs / "current.json", launcher.run_dir / "run.json"):
        assert json.loads(path.read_text())["state"] == "starting", path
    capsys.readouterr()
    assert status_main([], None, False, False, runs, 1.0) == 1
    assert capsys.readouterr().out == "run run (robot r0) is starting: its router is not open yet; ask again in a moment\n"


def _fake_result(method: str = "greedy-dist", steps: int = 10):
    from cso_runtime.messages import EpisodeResultMsg

    free = np.ones((3, 4), bool)
    return EpisodeResultMsg("s", steps, 1.2, 98.0, 1.3, 4.5, "coverage", 3, np.ones(3), np.zeros((4, 2)), np.linspace(0, 98, 4), free, free, 0.1, method, 0)


def test_the_launchers_line_of_an_episode_of_no_step_says_it_has_no_m2_per_step():
    """An episode that ended in 0 steps (its first scan saw everything) has no m2/step: episodes.csv leaves the cell
    empty, and the launcher's closing line said "nan m2/step"."""
    from cso_runtime.launcher import episode_figures, episode_record

    _, row = episode_record(_fake_result(steps=0), wall_s=1.0)
    line = episode_figures(row)
    assert "nan" not in line.lower(), line
    assert line == "episode coverage: 98.00% coverage in 0 steps; 1.20 m2 explored, no m2/step (no step), path 4.50 m, 3 decisions"
    _, row = episode_record(_fake_result(steps=10), wall_s=1.0)
    assert "0.1200 m2/step" in episode_figures(row)
    # A real robot's episode has no coverage (its row's 0: no ground truth): "0.00% coverage" read as a failure.
    assert episode_figures(row, simulated=False).startswith("episode coverage: in 10 steps; 1.20 m2 explored, 0.1200 m2/step")


def _recording_launcher(tmp_path: Path):
    """A launcher of the lockstep profile with ``--record --animate`` whose episode has ended (its GIF is due)."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run", record_path=tmp_path / "run" / "recording.mcap", animate=True)
    launcher.written_result = _fake_result()
    return launcher


def test_a_recorder_that_does_not_finish_cannot_hold_up_the_launchers_stop(tmp_path, monkeypatch, caplog):
    """The launcher joined its recorder thread with no timeout as it stopped: a recorder that never finished (its
    session's close hung, a backlog on a busy machine) held the stop for ever, and ``down`` killed the launcher
    with its run unfinished. It waits ``RECORDING_STOP_S``, then goes on, says what the file holds, and draws no
    GIF from an unfinished file. Its stop, stacks, recording and GIF together fit in ``down``'s margin."""
    from cso_runtime import launcher as launcher_module
    from cso_runtime.current_run import DOWN_MARGIN_S
    from cso_runtime.recording import RecordStats

    assert launcher_module.STOP_EXTRAS_S < DOWN_MARGIN_S
    launcher = _recording_launcher(tmp_path)
    drawn: list[Any] = []
    monkeypatch.setattr("cso_runtime.animation.animate_recording", lambda *args, **kwargs: drawn.append(args))
    monkeypatch.setattr(launcher_module, "RECORDING_STOP_S", 0.2)
    release = threading.Event()
    stuck = threading.Thread(target=release.wait, daemon=True)  # a recorder that does not finish
    stuck.start()
    recorder = launcher_module.Recorder(threading.Event(), stuck, RecordStats(launcher.record_path, messages=1234))
    stopping = threading.Thread(target=launcher.finish_recording, args=(recorder,), daemon=True)
    try:
        with caplog.at_level("WARNING", logger="cso.launcher"):
            stopping.start()
            stopping.join(timeout=10)
            assert not stopping.is_alive(), "the launcher's stop waits for its recorder for ever"
    finally:
        release.set()
    assert recorder.stop.is_set() and drawn == []
    said = f"recording not finished within 0.2 s of its stop (a backlog on a busy machine, or its session's close hung?): the launcher goes on without it; {launcher.record_path} holds at most the first 1234 messages"
    gif = launcher.animation_path()
    assert said in caplog.text and caplog.text.rstrip().endswith(f"no animation drawn (`cso-runtime animate {launcher.record_path} --out {gif}` draws one from it)"), caplog.text


def test_a_gif_that_takes_too_long_once_the_run_stops_is_left_to_cso_runtime_animate(tmp_path, monkeypatch, caplog):
    """``up --animate`` drew its GIF for as long as the recording took, also once ``down`` or Ctrl-C had asked the
    run to stop: a long recording outlasted ``down``'s margin, and the launcher was killed mid-drawing, its services
    and its run left to ``down``. Once stopping, the GIF gets ``ANIMATION_STOPPING_S`` more; beyond, the launcher
    gives it up and says how to draw it. Without a stop it is drawn in full."""
    from types import SimpleNamespace

    from cso_runtime import launcher as launcher_module

    launcher = _recording_launcher(tmp_path)
    monkeypatch.setattr(launcher_module, "ANIMATION_STOPPING_S", 0.2)
    gif = tmp_path / "run" / "animations" / "greedy-dist" / "s.gif"

    def slow_gif(recording, out, robot=None, max_frames=200, robot_radius_m=0.1, progress=None):
        """Reports its progress every 50 ms, for 10 s at most (then: drawn in full), a stop at 0.3 s."""
        started_s = time.monotonic()
        while time.monotonic() - started_s < 10.0:
            if time.monotonic() - started_s > 0.3:
                launcher.stop_event.set()
            progress(1, None)
            time.sleep(0.05)
        assert out == gif
        return SimpleNamespace(frames=3)

    monkeypatch.setattr("cso_runtime.animation.animate_recording", slow_gif)
    started_s = time.monotonic()
    with caplog.at_level("INFO", logger="cso.launcher"):
        launcher.write_animation()
    assert time.monotonic() - started_s < 5.0, "drawn in full after the stop"
    said = f"animation skipped: the run is stopping, and the GIF was not drawn within 0.2 s of that; `cso-runtime animate {launcher.record_path} --out {gif}` draws it"
    assert said in caplog.text, caplog.text
    launcher.stop_event.clear()

    def gif_unstopped(recording, out, robot=None, max_frames=200, robot_radius_m=0.1, progress=None):
        for _ in range(20):
            progress(1, None)
            time.sleep(0.05)  # 1 s, longer than ANIMATION_STOPPING_S: a run not stopping waits for its GIF
        return SimpleNamespace(frames=3)

    monkeypatch.setattr("cso_runtime.animation.animate_recording", gif_unstopped)
    caplog.clear()
    with caplog.at_level("INFO", logger="cso.launcher"):
        launcher.write_animation()
    assert f"animation in 3 frames: {gif}" in caplog.text, caplog.text


def test_ups_summary_records_the_software_and_the_command_line_that_ran_it(tmp_path, monkeypatch):
    """``up``'s run folder had the package version and the profile, not the commit, Python, libraries or the command line."""
    from cso_runtime import provenance
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    monkeypatch.setattr(provenance, "_command_line", "cso-runtime up --profile lockstep")  # as the script records it
    profile, data = load_profile(str(find_profile("lockstep")), {})
    Launcher(profile, data, tmp_path / "run").write_outputs(_fake_result())
    meta = json.loads((tmp_path / "run" / "summary.json").read_text())["meta"]
    assert meta["software"] == provenance.software_provenance() and meta["software"]["command_line"] == "cso-runtime up --profile lockstep"
    assert meta["software"]["version"] == meta["version"] == cso_runtime.__version__


def test_ups_record_names_the_commit_that_started_the_run_not_the_one_checked_out_as_it_stops(tmp_path, monkeypatch):
    """The record was taken as the run's results were written, when it stopped: a run of hours while its checkout was
    switched to another branch named the commit checked out then, not the one whose services ran."""
    from cso_runtime import launcher
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    checked_out = {"git_commit": "the commit that starts the services"}
    monkeypatch.setattr(launcher, "software_provenance", lambda: dict(checked_out))
    profile, data = load_profile(str(find_profile("lockstep")), {})
    run = Launcher(profile, data, tmp_path / "run")
    checked_out["git_commit"] = "a commit checked out while it ran"
    run.write_outputs(_fake_result())
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["meta"]["software"] == {"git_commit": "the commit that starts the services"}


@pytest.mark.parametrize(("name", "expected"), [("sim", "mujoco"), ("lockstep", "2d"), ("limo-ros2", None)])
def test_ups_summary_records_every_parameter_of_its_simulator(tmp_path, name, expected):
    """``summary.json`` of ``up`` held the profile as written (``services.sim.mujoco``: only what it changes), not the
    timestep, contacts and limits the MuJoCo LIMO ran with: ``meta.sim_settings`` has all of them, as eval's, and is
    absent on a real robot, which has no simulator."""
    import dataclasses

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    settings = {"services.sim.mujoco.wall_friction": 0.5} if name == "sim" else {}
    profile, data = load_profile(str(find_profile(name)), {}, settings=settings, connect=["tcp/127.0.0.1:7447"] if name == "limo-ros2" else None)
    assert profile.simulator() == expected
    Launcher(profile, data, tmp_path / "run").write_outputs(_fake_result())
    meta = json.loads((tmp_path / "run" / "summary.json").read_text())["meta"]
    if expected == "mujoco":
        from robot_sim.config import MujocoSimConfig

        assert meta["sim_settings"] == {**dataclasses.asdict(MujocoSimConfig(wall_friction=0.5)), "lidar_mount_x_m": 0.103}
    elif expected == "2d":
        assert meta["sim_settings"] == {"collision_radius_m": 0.12, "substeps": 5}
    else:
        assert "sim_settings" not in meta


def test_step_pace_measures_simulated_seconds_per_wall_second_from_the_episodes_statuses():
    from cso_runtime.pace import StepPace, real_time_factor

    assert real_time_factor(10.0, 4.0) == 2.5 and real_time_factor(None, 4.0) is None and real_time_factor(1.0, 0.0) is None
    assert real_time_factor(0.0, 4.0) is None  # no simulated time passed (an episode of no step): no pace, not 0x
    pace = StepPace(control_period_s=0.25)
    pace.observe(episode=1, step=3, at_s=100.0)
    assert pace.real_time_factor is None  # one status: no pace yet
    pace.observe(1, 3, 100.5)
    assert pace.real_time_factor is None  # no step since
    pace.observe(1, 11, 101.0)
    assert pace.real_time_factor == pytest.approx(8 * 0.25 / 1.0)
    pace.observe(2, 0, 200.0)  # a restarted sim's new episode: measured afresh
    pace.observe(2, 40, 202.5)
    assert pace.real_time_factor == pytest.approx(40 * 0.25 / 2.5)


def test_the_pace_read_as_a_new_episodes_status_arrives_is_the_old_episodes_or_none(tmp_path):
    """The real-time factor is read by the run loop (progress lines, the live view, episodes.csv's
    ``real_time_factor``) and the status queryable's thread while a Zenoh thread's ``_on_sample`` measures it, with no
    lock: a new episode's status (a restarted sim) arriving between the reader's look at the measure and its use of
    it (``_latest`` checked, then set to None, then unpacked) raised ``TypeError: cannot unpack non-iterable
    NoneType`` in the reader: the run loop's, which stops the run, or the results' writer's. Here the status arrives at
    each line of the reader in turn: it reads the old episode's factor or none, never raises."""
    from cso_runtime.pace import StepPace

    reader = StepPace.real_time_factor.fget.__code__  # type: ignore[attr-defined]
    lines = sorted({line for _, _, line in reader.co_lines() if line is not None and line > reader.co_firstlineno})
    injected = 0
    for line in lines:
        launcher, hear = _launcher_hearing(tmp_path)
        launcher.simulated = True
        hear(EpisodeStatusMsg("exploring", 10, episode=7))
        hear(EpisodeStatusMsg("exploring", 50, episode=7))
        old = launcher.real_time_factor
        assert old is not None
        arrived: list[int] = []

        def trace(frame: types.FrameType, event: str, _arg: Any, line: int = line, arrived: list[int] = arrived, hear: Callable[[Any], None] = hear) -> Any:
            if frame.f_code is not reader:
                return None

            def at_line(frame: types.FrameType, event: str, _arg: Any) -> Any:
                if event == "line" and frame.f_lineno == line and not arrived:
                    arrived.append(line)
                    sys.settrace(None)
                    hear(EpisodeStatusMsg("exploring", 0, episode=8))  # the restarted sim's, on the Zenoh thread, now
                return at_line

            return at_line

        sys.settrace(trace)
        try:
            got = launcher.real_time_factor
        finally:
            sys.settrace(None)
        assert got in (old, None), (line, got)
        injected += len(arrived)  # a line of its docstring runs no code
    assert injected >= 3, lines


def test_the_progress_line_says_when_the_episode_has_made_no_step_for_a_while(tmp_path, monkeypatch):
    """A sim stopped (SIGSTOP) or a lockstep pipeline stalled on a stopped policy: ``up --no-live``'s progress line
    went on saying "step 105 (26.2 s robot time, 20.47x real time): ..." every 10 s, as if all were well, until the
    hang check killed the culprit 20 s later. It now says how long the episode has made no new step."""
    from types import SimpleNamespace

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    clock = [1000.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    profile, data = load_profile(str(find_profile("sim")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)

    def status(step: int, at_s: float, state: str = "exploring") -> None:
        clock[0] = at_s
        msg = EpisodeStatusMsg(state=state, step=step, scene="s", method="greedy-dist", episode=7)
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))

    status(0, 960.0, "starting")  # the sim waits for the services: step 0 comes 30 s later, and is a new step
    status(0, 990.0)
    assert launcher.progress_log_line(991.0).endswith("goal none"), launcher.progress_log_line(991.0)
    status(14, 1000.0)
    status(15, 1000.25)
    assert launcher.progress_log_line(1002.0).endswith("goal none"), launcher.progress_log_line(1002.0)  # a step 1.75 s ago
    status(15, 1005.0)  # the same step again (a lockstep re-publish): no new step
    line = launcher.progress_log_line(1010.25)
    assert line.startswith("step 15 (3.8 s robot time") and line.endswith("goal none; no new step for 10 s"), line
    status(16, 1011.0)
    assert launcher.progress_log_line(1011.5).endswith("goal none")


def test_the_progress_line_of_a_launcher_that_was_itself_stopped_does_not_say_the_episode_made_no_step(tmp_path, monkeypatch):
    """The launcher stopped (Ctrl-Z, SIGSTOP) for 25 s while its services went on (peers: the episode ran on to step
    144) said on its continue "step 11 ...; no new step for 25 s", a stall of the episode that was its own: the
    steps it did not hear. Its silence is not the episode's, as for the hang check: the stall counts from when its
    status watch asks again, and nothing is said of one while the watch has not."""
    from types import SimpleNamespace

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import WATCH_BEHIND_S, Launcher, StatusWatch
    from cso_runtime.run_profile import find_profile, load_profile

    clock = [1000.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    profile, data = load_profile(str(find_profile("sim")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)
    msg = EpisodeStatusMsg(state="exploring", step=11, scene="s", method="greedy-dist", episode=7)
    launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))
    watch = launcher.status_watch = StatusWatch(None, keys, threading.Event())
    watch.asked_s = 1000.0  # its last round before the launcher was stopped
    line = launcher.progress_log_line(1025.0)  # continued 25 s later, before the watch asked again
    assert watch.behind(1025.0) and line.endswith("goal none"), line
    watch.asked_s = watch.resumed_s = 1025.1  # it asked again, and said that the launcher had not run
    assert launcher.progress_log_line(1026.0).endswith("goal none"), launcher.progress_log_line(1026.0)
    watch.asked_s = 1035.0  # it goes on asking
    line = launcher.progress_log_line(1025.1 + 10.0)
    assert line.endswith("goal none; no new step for 10 s"), line  # a stall since counts
    assert WATCH_BEHIND_S < 25.0


@pytest.mark.parametrize("name", ["lockstep", "limo-ros2"])
def test_up_shows_and_writes_the_simulators_real_time_factor_measured_on_the_episode(tmp_path, monkeypatch, name):
    """MuJoCo users read a sim's speed against real time: the live view, the progress line and episodes.csv give it,
    measured on the statuses of the episode (the sim's wait for the services and every start-up left out, which
    ``wall_s`` holds), and ``sim_time_s`` (steps of 0.25 s); a real robot's run has neither."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView, progress_line
    from cso_runtime.run_profile import find_profile, load_profile

    clock = [1000.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    profile, data = load_profile(str(find_profile(name)), {}, connect=["tcp/127.0.0.1:7447"] if name == "limo-ros2" else None)
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)

    def status(state: str, step: int, at_s: float) -> EpisodeStatusMsg:
        clock[0] = at_s
        msg = EpisodeStatusMsg(state=state, step=step, scene="s", method="greedy-dist", episode=7)
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))
        return msg

    status("starting", 0, 1000.0)  # start-up: the sim waits 30 s for the services, not its pace
    status("exploring", 2, 1030.0)
    last = status("exploring", 42, 1035.0)  # 40 steps of 0.25 s in 5 s: twice as fast as real time
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    text = console.export_text()
    line = progress_line(last, launcher.sim_step_s, launcher.real_time_factor)
    if name == "limo-ros2":
        assert launcher.real_time_factor is None and "x real time" not in text
        # A real robot's steps are its scans (about 10 Hz on the LIMO), not 0.25 s control periods: 42 steps are
        # no "10.5 s robot time" there, so neither the live view nor the log line says so.
        assert "robot time" not in text and re.search(r"│ step +│ 42 \(\d+ s since start\)", text), text
        assert line.startswith("step 42: 0.00 m2 explored") and "robot time" not in line, line
        # No ground truth on a real robot: its coverage (0) is not shown as "0.0 %" beside the map it explores.
        assert "coverage" not in line and re.search(r"│ coverage +│ n/a: a real robot \(no ground truth", text) and "0.0 %" not in text, text
    else:
        assert launcher.real_time_factor == pytest.approx(2.0)
        assert re.search(r"│ step +│ 42 \(10\.5 s robot time, \d+ s since start, 2\.00x real time\)", text), text
        assert "step 42 (10.5 s robot time, 2.00x real time): coverage 0.0 %" in line, line
        assert re.search(r"│ coverage +│ .* 0\.0 %", text), text
    status("done", 50, 1036.0)  # the end: 48 steps in 6 s
    launcher.write_outputs(_fake_result(steps=50))
    with (tmp_path / "run" / "episodes.csv").open() as fh:
        (row,) = list(csv.DictReader(fh))
    methods = json.loads((tmp_path / "run" / "summary.json").read_text())["methods"]["greedy-dist"]
    if name == "limo-ros2":
        assert row["sim_time_s"] == row["real_time_factor"] == "" and methods["sim_time_s"] is methods["real_time_factor"] is None
    else:
        assert float(row["sim_time_s"]) == 12.5 and float(row["real_time_factor"]) == pytest.approx(2.0)
        assert float(row["wall_s"]) == pytest.approx(36.0)  # from the launcher's start: not what the pace is measured on
        assert methods["sim_time_s"] == 12.5 and methods["real_time_factor"] == pytest.approx(2.0)


@pytest.mark.parametrize("name", ["lockstep", "limo-ros2"])
def test_the_live_views_last_table_says_the_step_a_real_robots_episode_ended_at(tmp_path, name):
    """On a LIMO the bridge's steps go on counting the robot's scans after the episode's end, and ``up``'s live view,
    whose last table stays on the terminal under the launcher's "episode no_frontier: in 188 steps; ... 0.1000 m2/step",
    said "step 230" and 0.082 m2/step there: it says the step the episode ended at beside the scans, as ``status``
    does, and its m2/step over the episode's steps. A sim's steps end with its episode: nothing is added."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile(name)), {}, connect=["tcp/127.0.0.1:7447"] if name == "limo-ros2" else None)
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)

    def status(state: str, step: int, episode: int = 7) -> EpisodeStatusMsg:
        msg = EpisodeStatusMsg(state=state, step=step, scene="s", method="greedy-dist", episode=episode, explored_area_m2=18.8)
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))
        return msg

    def table() -> str:
        console = Console(width=200, record=True)
        console.print(LiveView(launcher).render())
        return console.export_text()

    launcher.ended_status = status("done", 188)  # as the run loop takes the end
    launcher.write_outputs(_fake_result(steps=188))
    status("done", 230 if name == "limo-ros2" else 188)  # the robot's scans go on (a sim's steps do not)
    text = table()
    if name == "limo-ros2":
        assert re.search(r"│ step +│ 230 \(\d+ s since start\) \(scans; the episode ended at step 188\)", text), text
        assert re.search(r"│ explored +│ 18\.80 m2, 0\.100 m2/step", text), text
        status("done", 240, episode=9)  # another episode, after the robot's driver restarted: not the one that was written
        assert re.search(r"│ step +│ 240 \(\d+ s since start\) +│", table())
    else:
        assert re.search(r"│ step +│ 188 \(47\.0 s robot time, \d+ s since start\) +│", text) and "m2, 0.100 m2/step" in text, text


@pytest.mark.parametrize("name", ["lockstep", "limo-ros2"])
def test_status_shows_the_simulators_real_time_factor_the_launcher_measures(tmp_path, monkeypatch, name):
    """``up``'s live view gave the sim's real-time factor and ``status`` did not: the launcher's status carries it
    (``real_time_factor``), ``status`` shows it on the step row in the live view's words and ``--json`` has it;
    null before two statuses of the episode, and on a real robot, which has no simulated time."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import render_table, status_of

    clock = [1000.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    profile, data = load_profile(str(find_profile(name)), {}, connect=["tcp/127.0.0.1:7447"] if name == "limo-ros2" else None)
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)

    def heard(step: int, at_s: float) -> dict:
        clock[0] = at_s
        msg = EpisodeStatusMsg(state="exploring", step=step, scene="s", method="greedy-dist", episode=7)
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))
        return msg.to_dict()

    def status_now(episode: dict) -> tuple[dict, str]:
        msg = decode(encode(launcher.launcher_status()), LauncherStatusMsg)  # as `status` gets it
        assert isinstance(msg, LauncherStatusMsg)
        status = status_of(profile.robot, episode, msg.to_dict(), {}, set())
        console = Console(record=True, width=200)
        console.print(render_table(status))
        return json.loads(json.dumps(status)), console.export_text()

    status, text = status_now(heard(2, 1030.0))  # one status: no pace yet
    assert status["real_time_factor"] is None and "x real time" not in text, text
    status, text = status_now(heard(42, 1035.0))  # 40 steps of 0.25 s in 5 s: twice as fast as real time
    if name == "limo-ros2":
        assert status["real_time_factor"] is None and "x real time" not in text, text
        assert re.search(r"│ step +│ 42 +│", text), text
    else:
        assert status["real_time_factor"] == pytest.approx(2.0)
        assert re.search(r"│ step +│ 42 \(2\.00x real time\) +│", text), text


def test_status_of_a_run_just_started_says_its_services_are_starting_not_down():
    """``status`` right after ``up --detach`` (services still importing, no episode yet) listed every service whose
    session was not up as DOWN, the scene and method as " / " and the episode id as 000000000000, as if the run had
    failed. A service whose process the launcher says runs is "starting" (as the live view says it), one given up on
    or whose process is gone is DOWN as before, and the rows with nothing yet say "-"."""
    from rich.console import Console

    from cso_runtime.status import render_table, status_of

    launcher = {
        "run_id": "run1",
        "state": "running",
        "services": {
            "sim": {"pid": 11, "process_alive": True, "liveliness": False, "restarts": 0},
            "mapper": {"pid": 12, "process_alive": True, "liveliness": True, "restarts": 0},
            "planner": {"pid": 13, "process_alive": False, "liveliness": False, "restarts": 1},
            "policy": {"pid": 14, "process_alive": True, "liveliness": False, "restarts": 3, "gave_up": True},
        },
    }
    mapper = {"state": "running", "reason": "", "last_step": 0, "rejected": {}, "processed": 0}
    status = status_of("r0", None, launcher, {"mapper": mapper}, {"mapper"})
    console = Console(record=True, width=200)
    console.print(render_table(status))
    text = console.export_text()
    assert status["state"] == "starting" and status["episode"] == 0 and status["scene"] == "", status  # JSON as before
    assert re.search(r"│ service sim +│ starting +│", text) and re.search(r"│ service mapper +│ alive, running +│", text), text
    assert re.search(r"│ service planner +│ DOWN, restarts 1 +│", text), text
    assert re.search(r"│ service policy +│ DOWN, restarts 3 \(gave up\) +│", text), text
    assert re.search(r"│ scene / method +│ - +│", text) and re.search(r"│ episode id +│ - +│", text), text


def test_a_service_frozen_after_it_came_up_reads_not_answering_not_starting(tmp_path):
    """A service stopped (SIGSTOP) well after its start loses its liveliness token when its lease runs out, while its
    process runs: ``status`` and the live view said "starting" of it until the hang check killed it. "starting" is for
    a process not yet seen alive; one that came up and whose token is gone since is "not answering" (``--json``:
    ``not_answering`` true, the launcher's ``came_up`` beside it)."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    launcher = {
        "run_id": "run1",
        "state": "running",
        "services": {
            "sim": {"pid": 11, "process_alive": True, "liveliness": False, "came_up": True, "restarts": 0},
            "mapper": {"pid": 12, "process_alive": True, "liveliness": False, "came_up": False, "restarts": 0},
        },
    }
    status = status_of("r0", None, launcher, {}, set())
    console = Console(record=True, width=200)
    console.print(render_table(status))
    text = console.export_text()
    assert re.search(r"│ service sim +│ not answering \(its liveliness token is gone: stopped or hung\?\) +│", text) and re.search(r"│ service mapper +│ starting +│", text), text
    assert status["services"]["sim"]["not_answering"] is True and status["services"]["mapper"]["not_answering"] is False, status
    assert status["services"]["sim"]["came_up"] is True

    profile, data = load_profile(str(find_profile("lockstep")), {})
    la = Launcher(profile, data, tmp_path / "run")
    running = SimpleNamespace(pid=4242, poll=lambda: None)  # a process that runs (stopped, as far as its token says)
    frozen = Child("sim", ["true"], tmp_path / "sim.log", proc=running, came_up=True)
    fresh = Child("mapper", ["true"], tmp_path / "mapper.log", proc=running)
    la.children = [frozen, fresh]
    said = decode(encode(la.launcher_status())).to_dict()["services"]
    assert said["sim"]["came_up"] is True and said["mapper"]["came_up"] is False, said  # through the wire's check
    console = Console(width=200, record=True)
    console.print(LiveView(la).render())
    text = console.export_text()
    assert re.search(r"│ sim +│ not answering \(its liveliness token is gone: stopped or hung\?\), pid 4242", text) and re.search(r"│ mapper +│ starting, pid 4242", text), text


def test_a_service_that_came_up_between_the_hang_checks_rounds_reads_not_answering_once_its_token_is_gone(tmp_path):
    """The launcher noted that a service came up only at a round of its hang check (``kill_hung``), which looks at the
    liveliness tokens then, and skips every service while its status watch is behind (the launcher was stopped and
    continued) or the router it joined is lost; the run loop's rounds also wait seconds at a time while an episode's
    result is awaited. A service whose token came and went in such a gap (it came up, then froze) read "starting"
    in ``status`` and the live view until the hang check killed it, as if it had never come up. Its token coming is
    its coming up, whenever the launcher hears it (``_on_alive``); a restart's new process starts anew."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    la = Launcher(profile, data, tmp_path / "run")
    running = SimpleNamespace(pid=4242, poll=lambda: None)
    behind = Child("sim", ["true"], tmp_path / "sim.log", proc=running)  # up while the hang check waits for its watch
    busy = Child("mapper", ["true"], tmp_path / "mapper.log", proc=running)  # up and frozen between two rounds of the loop
    la.children = [behind, busy]
    la.status_watch = SimpleNamespace(behind=lambda now: True, resumed_s=-np.inf, answered_s={})  # type: ignore[assignment]

    def token(name: str, kind: str) -> None:
        la._on_alive(SimpleNamespace(key_expr=la.keys.alive(name), kind=f"SampleKind.{kind}"))

    token("sim", "PUT")
    la.supervise()  # a round: the hang check waits (its watch behind)
    token("sim", "DELETE")  # frozen: its lease ran out
    token("mapper", "PUT")
    token("mapper", "DELETE")  # no round of the loop in between
    la.supervise()
    msg = decode(encode(la.launcher_status()), LauncherStatusMsg)
    assert isinstance(msg, LauncherStatusMsg)
    status = status_of("r0", None, msg.to_dict(), {}, set())
    assert {name: status["services"][name]["not_answering"] for name in ("sim", "mapper")} == {"sim": True, "mapper": True}, status["services"]
    assert behind.came_up_at > 0 and busy.came_up_at > 0  # the hang check counts from when they came up
    busy.argv = [sys.executable, "-c", "pass"]
    busy.spawn()  # its restart: a new process, starting until its own token comes
    busy.proc.wait(10)  # type: ignore[union-attr]
    assert busy.came_up is False


def test_a_restarted_service_whose_token_comes_as_the_hang_check_looks_is_not_killed_as_hung(tmp_path):
    """Its coming up is marked on a Zenoh thread (``_on_alive`` -> ``Child.seen_up``) while the run loop's hang check
    (``kill_hung``) reads ``came_up``, then ``came_up_at``, with no lock. ``seen_up`` wrote ``came_up`` first: a check
    between its two writes took the process for up since its previous process came up (``came_up_at`` still that
    one's) and, with that process's last answer as old (a hung one, killed), killed the new process as hung the
    moment its token came. Simulated here by running the check right when ``came_up`` is written."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    la = Launcher(profile, data, tmp_path / "run")
    now = time.monotonic()
    assert 0 < profile.supervision.hang_timeout_s < 30
    la.status_watch = SimpleNamespace(behind=lambda now: False, resumed_s=-np.inf, answered_s={"mapper": now - 30.0})  # type: ignore[assignment]
    checked: list[int] = []

    class CheckedBetweenWrites(Child):
        def __setattr__(self, name: str, value: Any) -> None:
            super().__setattr__(name, value)
            if name == "came_up" and value is True and not checked:  # the run loop's round, on its own thread, now
                checked.append(self.hung_kills)
                la.kill_hung(time.monotonic())
                checked.append(self.hung_kills)

    c = CheckedBetweenWrites("mapper", [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "mapper.log")
    c.spawn()  # its restart, after a process that came up long ago and last answered 30 s ago (hung, killed)
    try:
        c.came_up_at = now - 60.0  # as its previous process left it
        la.children = [c]
        la._on_alive(SimpleNamespace(key_expr=la.keys.alive_incarnation("mapper", c.incarnation), kind="SampleKind.PUT"))  # its own start's
        assert checked == [0, 0], "the new process was killed as hung as its token came"
        assert c.came_up and c.came_up_at >= now and c.alive
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(c.proc.pid, signal.SIGKILL)  # type: ignore[union-attr]
        c.proc.wait(10)  # type: ignore[union-attr]


def test_a_restarted_service_is_not_marked_up_by_its_predecessors_token(tmp_path):
    """A liveliness token did not say which process declared it: a restarted service was marked up (``came_up``) by its
    predecessor's token, a PUT heard late or a token still there at the hang check's round (its DELETE not read yet),
    while the new process was still starting, so the hang check judged it by ``hang_timeout_s`` from then instead of
    ``start_timeout_s``, and killed a slow start as hung. A service the launcher starts also declares
    ``alive/<name>/<incarnation>``, the nonce its start was given: only its own marks it up. A command node (it declares
    ``$CSO_ALIVE_KEY`` alone) is judged by that token as before."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    la = Launcher(profile, data, tmp_path / "run")
    la.status_watch = SimpleNamespace(behind=lambda now: False, resumed_s=-np.inf, answered_s={})  # type: ignore[assignment]

    def token(key: str, kind: str = "PUT") -> None:
        la._on_alive(SimpleNamespace(key_expr=key, kind=f"SampleKind.{kind}"))

    c = Child("mapper", [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "mapper.log")
    node = Child("policy", [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "node.log", command=["./my_policy"])  # in the policy's place
    la.children = [c, node]
    try:
        c.spawn()  # a restart: its predecessor's token may still be heard
        token(la.keys.alive("mapper"))  # the predecessor's, late
        assert not c.came_up, "marked up by its predecessor's token"
        la.kill_hung(time.monotonic())  # a round with that token still there
        assert not c.came_up and c.alive
        predecessor = la.keys.alive_incarnation("mapper", "0123456789abcdef")
        token(predecessor)
        la.kill_hung(time.monotonic())
        assert not c.came_up and c.alive and c.incarnation and c.incarnation != "0123456789abcdef"
        token(la.keys.alive_incarnation("mapper", c.incarnation))  # its own
        assert c.came_up
        token(predecessor, "DELETE")  # the predecessor's goes: the new one is still up
        la.kill_hung(time.monotonic())
        assert c.came_up and c.alive and c.hung_kills == 0
        first = c.incarnation
        c.spawn()  # its next restart: a new nonce, and the token of the one before is no longer its own
        assert c.incarnation != first and not c.came_up
        la.kill_hung(time.monotonic())
        assert not c.came_up
        # a command node declares $CSO_ALIVE_KEY alone: that token is its coming up, as before
        node.spawn()
        assert node.incarnation == ""
        token(la.keys.alive("policy"))
        assert node.came_up
    finally:
        for child in (c, node):
            if child.proc is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(child.proc.pid, signal.SIGKILL)
                child.proc.wait(10)


def test_a_service_started_by_a_launcher_declares_its_starts_token_beside_the_one_every_reader_reads(tmp_path, monkeypatch):
    """A Python service given an incarnation (``CSO_INCARNATION``, set by ``Child.spawn``) declares
    ``alive/<name>/<incarnation>`` beside ``alive/<name>``, and withdraws both as it stops; ``alive/*``, which
    ``status``, the sim, a shared policy and every reader of the documented key subscribe to, matches the plain one
    alone. Started by hand (no incarnation) it declares the plain one alone, as before."""
    from cso_runtime.processes import INCARNATION_ENV
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t4")

    def tokens(session: Any, key: str) -> list[str]:
        return sorted(str(r.ok.key_expr) for r in session.liveliness().get(key, timeout=0.5) if r.ok)

    with open_session(router) as session:
        for incarnation in ("5eed0123abcd4567", ""):
            monkeypatch.setenv(INCARNATION_ENV, incarnation)
            svc = MapperService(ServiceContext("mapper", "t4", {}, ExplorationConfig(), client, {"restore_timeout_s": 0.1}))
            stop = threading.Event()
            th = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
            th.start()
            try:
                wait_for(lambda: tokens(session, keys.alive("*")), HANG_DEADLINE_S, "the mapper's token")
                own = [keys.alive_incarnation("mapper", incarnation)] if incarnation else []
                wait_for(lambda own=own: tokens(session, keys.alive_incarnation("*", "*")) == own, 10, "its start's token")
                assert tokens(session, keys.alive("*")) == [keys.alive("mapper")]
            finally:
                stop.set()
                th.join(HANG_DEADLINE_S)
            assert not th.is_alive()
            wait_for(lambda: not tokens(session, f"{keys.prefix}/alive/**"), 10, "both tokens withdrawn")


def test_status_of_a_service_that_answers_before_its_token_is_seen_says_one_state():
    """A service answers its status query a moment before its liveliness token is seen: ``status`` read
    "starting, running" (its process runs, its token not yet there, and its own state) and one not started by this run
    "DOWN, not started by this run, running". One that answers is up: "alive, running", as a moment later."""
    from rich.console import Console

    from cso_runtime.status import render_table, status_of

    launcher = {
        "run_id": "run1",
        "state": "running",
        "services": {
            "sim": {"pid": 11, "process_alive": True, "liveliness": False, "restarts": 0},
            "policy": {"liveliness": False, "outside": True},
        },
    }
    answers = {"state": "running", "reason": "", "last_step": 3, "rejected": {}, "processed": 3}
    status = status_of("r0", None, launcher, {"sim": answers, "policy": answers}, set())
    console = Console(record=True, width=200)
    console.print(render_table(status))
    text = console.export_text()
    assert re.search(r"│ service sim +│ alive, running +│", text), text
    assert re.search(r"│ service policy +│ alive, not started by this run, running +│", text), text
    assert status["services"]["sim"]["alive"] is False  # JSON keeps the token's word


def test_status_says_a_real_robots_coverage_is_not_measured_and_json_keeps_its_zero():
    """``status`` on a LIMO said "coverage 0.00 %" for the whole run, beside a map growing by the second (there is no
    ground truth to measure it against): the table says so; ``--json`` keeps ``coverage_pct`` 0, as summary.json."""
    from rich.console import Console

    from cso_runtime.status import render_table, status_of

    episode = {"state": "exploring", "step": 42, "episode": 7, "scene": "ros2:limo1", "method": "cso", "coverage_pct": 0.0, "explored_area_m2": 6.5}
    for referee, said in (("ros2_bridge", r"│ coverage +│ n/a: a real robot \(no ground"), ("sim", r"│ coverage +│ 0\.00 % +│")):
        status = status_of("r0", episode, {"run_id": "run1", "state": "running", "services": {referee: {"pid": 1, "restarts": 0}}}, {}, {referee})
        console = Console(record=True, width=200)
        console.print(render_table(status))
        text = console.export_text()
        assert re.search(said, text) and status["coverage_pct"] == 0.0, text


def test_live_view_shows_how_far_the_planned_path_goes(tmp_path):
    """The launcher's live view reports the length of the planner's latest path (robot to goal), and where the robot is."""
    import dataclasses
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.geometry import VelocityCommand
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.messages import PathMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)
    path = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 5.5]])
    launcher._on_sample(SimpleNamespace(key_expr=keys.topic("path"), payload=SimpleNamespace(to_bytes=lambda: encode(PathMsg(3, path)))))
    assert launcher.path_ahead_m == pytest.approx(6.5)
    launcher._on_sample(SimpleNamespace(key_expr=keys.topic("path"), payload=SimpleNamespace(to_bytes=lambda: b"junk")))
    assert launcher.path_ahead_m == pytest.approx(6.5) and launcher.rejected == {"path": 1}
    launcher.status = EpisodeStatusMsg(state="exploring", step=3, scene="s", method="greedy-dist", coverage_pct=10.0, explored_area_m2=1.0, path_length_m=0.5, goal_xy_m=[3.0, 5.5])
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    text = console.export_text()
    assert "6.50 m ahead on the path" in text
    assert re.search(r"│ pose +│ - +│", text), text  # no odometry in the status yet
    # The robot's pose, in the map frame as the goal above it (a map_server scene's origin applied), and its speed.
    launcher.status = dataclasses.replace(launcher.status, map_origin=Pose2D(1.0, -2.0, 0.0), pose=Pose2D(0.5, 0.25, -0.5), twist=VelocityCommand(0.2, 0.0))
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ pose +│ x 1\.50 m  y -1\.75 m  yaw -0\.50 rad, 0\.20 m/s 0\.00 rad/s +│", console.export_text()), console.export_text()
    assert re.search(r"│ step +│ 3 \(0\.8 s robot time, \d+ s since start\)", text), text
    assert re.search(r"│ coverage +│ ━{2}╺?━* +10\.0 % ", text) and "1.00 m2, 0.333 m2/step" in text, text  # a bar a tenth full
    launcher.status.reason = "the map reached the edge of its arena"  # the referee's note, as `status` shows it
    noted = Console(width=200, record=True)
    noted.print(LiveView(launcher).render())
    assert re.search(r"│ state +│ exploring: the map reached the edge of its arena +│", noted.export_text()), noted.export_text()
    launcher.status.reason = ""
    narrow = Console(width=80, record=True)  # a plain terminal: the title is one line, robot and method a row
    narrow.print(LiveView(launcher).render())
    lines = narrow.export_text().splitlines()
    assert lines[0].strip() == f"cso-runtime {launcher.run_id}" and lines[1].lstrip().startswith("┌")
    assert any("robot / method" in line and "r0 / greedy-dist, lockstep" in line for line in lines)
    launcher.status.goal_xy_m = None  # no goal in the status yet: no path ahead of it either
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ goal +│ - +│", console.export_text()), console.export_text()
    launcher.status.goal_xy_m = [3.0, 5.5]
    launcher.status.scene = "[bold]plan[2]"  # a scene's name is text, not rich markup
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert "[bold]plan[2]" in console.export_text()
    piped = io.StringIO()  # `up > up.log`: the last table ends its line, so the launcher's next log line starts afresh
    view = LiveView(launcher, console=Console(file=piped, width=200))
    view.start()
    view.stop()
    assert piped.getvalue().count("6.50 m ahead on the path") == 1 and piped.getvalue().endswith("┘\n")


def test_the_live_view_shows_no_stale_goal_once_the_episode_has_ended(tmp_path):
    """An ended episode's status keeps its last goal: the view went on showing "(3.00, 5.50) m, 6.50 m ahead on the
    path" under ``done (coverage)``, as if the robot still drove there. The goal row (and the progress line of a
    followed log) says that the episode ended and why instead."""
    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView, progress_line
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.path_ahead_m = 6.5
    launcher.status = EpisodeStatusMsg(state="done", step=80, scene="s", method="greedy-dist", coverage_pct=96.0, goal_xy_m=[3.0, 5.5], terminated_by="coverage")
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    text = console.export_text()
    assert re.search(r"│ goal +│ none: the episode ended \(coverage\) +│", text) and "ahead on the path" not in text, text
    assert progress_line(launcher.status, 0.25).endswith("goal none: the episode ended (coverage)")
    launcher.status.state, launcher.status.terminated_by, launcher.status.reason = "failed", "", "the robot left the map"
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ goal +│ none: the episode failed \(the robot left the map\) +│", console.export_text()), console.export_text()


def test_the_live_views_last_table_after_ctrl_c_says_the_run_was_interrupted(tmp_path):
    """Ctrl-C (or ``down``) on a foreground ``up``: the table left on the terminal said ``exploring`` above "services
    stopped", as if the episode went on; it says the run was interrupted, with no results (the step row says where)."""
    from rich.console import Console

    from cso_runtime.config import EXIT_INTERRUPTED
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.status = EpisodeStatusMsg(state="exploring", step=39, scene="s", method="greedy-dist", coverage_pct=48.0, explored_area_m2=35.0)
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ state +│ exploring +│", console.export_text()), console.export_text()
    launcher.exit_code = EXIT_INTERRUPTED  # what the run loop sets on Ctrl-C, SIGTERM or `down`, before the last table
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ state +│ interrupted: no results +│", console.export_text()), console.export_text()
    launcher.status.state, launcher.status.terminated_by = "done", "coverage"  # an ended episode stays as it ended
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert re.search(r"│ state +│ done \(coverage\) +│", console.export_text()), console.export_text()


def test_live_view_shows_a_service_the_run_leaves_out_and_what_the_episode_waits_for(tmp_path):
    """``up``'s live view listed only the services the run started: a run whose profile has no policy stood at
    step 0 with every row up, and nothing in the view said that the episode waited for a policy nobody served
    (``status`` did). The view lists it as ``status`` does, from the launcher's own status, and its state says
    what the episode waits for; once a policy answers, or the episode is over, nothing is waited for."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    del profile.services["policy"]  # left to another process (a shared policy server)
    launcher = Launcher(profile, data, tmp_path / "run")

    def view() -> str:
        console = Console(width=200, record=True)
        console.print(LiveView(launcher).render())
        return console.export_text()

    text = view()  # no episode status yet: the sim waits for the policy before step 0
    assert re.search(r"│ state +│ starting; waiting for policy, which no process serves +│", text), text
    assert re.search(r"│ policy +│ DOWN, not started by this run, the episode waits for it +│", text), text
    launcher.status = EpisodeStatusMsg(state="exploring", step=0, scene="s", method="greedy-dist")
    text = view()
    assert re.search(r"│ state +│ exploring; waiting for policy, which no process serves +│", text), text
    assert [line.split("│")[1].strip() for line in text.splitlines() if "not started by this run" in line] == ["policy"], text
    launcher._on_alive(SimpleNamespace(key_expr=launcher.keys.alive("policy"), kind="SampleKind.PUT"))  # a server answers
    text = view()
    assert re.search(r"│ state +│ exploring +│", text) and re.search(r"│ policy +│ alive, not started by this run +│", text) and "wait" not in text, text
    launcher._on_alive(SimpleNamespace(key_expr=launcher.keys.alive("policy"), kind="SampleKind.DELETE"))  # and goes
    launcher.status.state = "done"
    text = view()
    assert re.search(r"│ policy +│ idle \(episode done: not needed after it\), not started by this run +│", text) and "wait" not in text, text
    full, full_data = load_profile(str(find_profile("lockstep")), {})  # a run that starts every service: no such row
    launcher = Launcher(full, full_data, tmp_path / "run2")
    assert "not started by this run" not in view() and "wait" not in view()


def test_a_launcher_callback_that_raises_is_logged_and_counted_in_the_status(tmp_path, caplog):
    """An exception inside one of the launcher's Zenoh callbacks (a bug) would reach only Zenoh's stderr
    print: it is logged with its traceback, counted in the launcher's status, shown by ``status``, and the
    callback keeps working for the next sample."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg, PathMsg
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import render_table

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    on_sample = launcher._guarded(launcher._on_sample)
    broken = SimpleNamespace(key_expr=launcher.keys.topic("path"), payload=None)  # .to_bytes() raises
    with caplog.at_level("ERROR", logger="cso.launcher"):
        on_sample(broken)
        on_sample(broken)
    assert [r.message for r in caplog.records] == [f"launcher: on_sample raised ({n} so far); the run goes on" for n in (1, 2)]
    assert all(r.exc_info is not None for r in caplog.records)
    path = np.array([[0.0, 0.0], [3.0, 4.0]])
    on_sample(SimpleNamespace(key_expr=launcher.keys.topic("path"), payload=SimpleNamespace(to_bytes=lambda: encode(PathMsg(3, path)))))
    assert launcher.path_ahead_m == pytest.approx(5.0)
    sent = decode(encode(launcher.launcher_status()), LauncherStatusMsg)
    assert isinstance(sent, LauncherStatusMsg) and sent.handler_errors == {"on_sample": 2}
    older = encode(LauncherStatusMsg("run1", "running"))  # a launcher without the field still decodes
    assert decode(older.replace(b"handler_errors", b"handler_errorz"), LauncherStatusMsg).handler_errors == {}
    status = {
        "robot": "r0", "run_id": "run1", "state": "exploring", "terminated_by": "", "reason": "", "scene": "s", "method": "m", "step": 3,
        "episode": 1, "coverage_pct": 1.0, "explored_area_m2": 1.0, "path_length_m": 0.0, "goal": None, "decisions": 1,
        "last_decision_ms": 1.0, "services": {}, "launcher_rejected": {"path": 1}, "launcher_handler_errors": sent.handler_errors,
    }  # fmt: skip
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert re.search(r"│ launcher +│ rejected 1, 2 callback errors \(see its log\) +│", console.export_text()), console.export_text()


def test_status_says_the_episode_is_stale_not_starting_when_the_sim_stops_answering(tmp_path, monkeypatch):
    """A sim stopped (SIGSTOP) or hung mid-episode answers no episode-status query; ``status`` showed "starting,
    step 0" then. The launcher's status carries the last episode status it heard and its age, and ``status``
    says the episode is stale: the last state and step, and how many seconds ago. Before any: starting."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime import launcher as launcher_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import render_table, status_of

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    now_s = [100.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: now_s[0]))  # the launcher's clock only

    def status_without_the_sim() -> tuple[dict, str]:
        msg = decode(encode(launcher.launcher_status()), LauncherStatusMsg)  # as `status` gets it
        assert isinstance(msg, LauncherStatusMsg)
        status = status_of("r0", None, msg.to_dict(), {}, {"mapper", "frontier", "policy", "planner"})
        console = Console(record=True, width=200)
        console.print(render_table(status))
        return status, console.export_text()

    status, text = status_without_the_sim()  # nothing heard yet: the sim is starting
    assert (status["state"], status["step"], status.get("status_age_s")) == ("starting", 0, None)
    episode = EpisodeStatusMsg("exploring", 41, scene="s", method="cso", episode=7)
    launcher._on_sample(SimpleNamespace(key_expr=launcher.keys.topic("episode_status"), payload=SimpleNamespace(to_bytes=lambda: encode(episode))))
    now_s[0] += 12.5  # then the sim froze
    status, text = status_without_the_sim()
    assert (status["state"], status["step"], status["episode"], status["status_age_s"]) == ("stale", 41, 7, 12.5)
    assert re.search(r"state +│ stale: the sim does not answer; its last episode status, 12\.5 s ago, said exploring at step 41", text), text
    assert re.search(r"step +│ 41 ", text) and "starting" not in text, text
    done = EpisodeStatusMsg(
        "done", 90, terminated_by="coverage", episode=7, scene="s", method="cso", coverage_pct=99.5, explored_area_m2=40.0, path_length_m=12.25, decisions=9
    )
    launcher._on_sample(SimpleNamespace(key_expr=launcher.keys.topic("episode_status"), payload=SimpleNamespace(to_bytes=lambda: encode(done))))
    now_s[0] += 3.0  # an episode over stays over when the sim has gone
    status, text = status_without_the_sim()
    assert (status["state"], status["step"], status["status_age_s"]) == ("done", 90, 3.0)
    # with its figures: `status --watch` on a run whose services stop after its episode showed "0.00 %", no scene
    shown = {k: status[k] for k in ("terminated_by", "scene", "method", "coverage_pct", "explored_area_m2", "path_length_m", "decisions")}
    assert shown == {"terminated_by": "coverage", "scene": "s", "method": "cso", "coverage_pct": 99.5, "explored_area_m2": 40.0, "path_length_m": 12.25, "decisions": 9}
    assert re.search(r"scene / method +│ s / cso ", text) and re.search(r"coverage +│ 99\.50 % ", text), text


def test_log_lines_during_the_live_view_print_above_the_table_not_inside_it(tmp_path):
    """On a terminal the launcher's log lines (a restart, the episode's end) go through the live display, which
    prints them on lines of their own above the table; afterwards the handler writes to stderr again."""
    import logging

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    terminal = TerminalFile()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        view = LiveView(launcher, console=Console(file=terminal, width=120, force_terminal=True, color_system=None))
        before = sys.stderr
        view.start()
        assert handler.stream is sys.stderr and sys.stderr is not before  # rich's proxy of the live display
        logging.getLogger("cso.launcher").warning("mapper exited with code -9; restarting in 0.5 s")
        view.stop()
        assert handler.stream is before and sys.stderr is before
    finally:
        root.removeHandler(handler)
    lines = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", terminal.getvalue()).replace("\r", "\n").splitlines()
    assert "WARNING cso.launcher: mapper exited with code -9; restarting in 0.5 s" in lines
    assert any(line.lstrip().startswith("└") for line in lines)


def test_status_table_shows_the_episode_and_each_service():
    from rich.console import Console

    from cso_runtime.status import render_table

    status = {
        "robot": "r0", "run_id": "run-1", "state": "exploring", "episode": 4242, "step": 17, "coverage_pct": 41.5,
        "explored_area_m2": 12.25, "path_length_m": 3.5, "goal": [1.0, 2.0], "decisions": 6, "last_decision_ms": 9.5,
        "terminated_by": "", "reason": "", "scene": "gen_small_0", "method": "greedy-dist", "lockstep_timeouts": 0,
        "services": {"mapper": {"alive": True, "state": "running", "reason": "", "rejected": {"scan": 2}}, "sim": {"alive": False}},
        "launcher_rejected": {},
    }
    console = Console(record=True, width=120)
    console.print(render_table(status))
    text = console.export_text()
    assert "│ 17 " in text and "000000001092" in text and "41.50 %" in text and "(1.00, 2.00) m" in text
    assert "12.25 m2, 0.721 m2/step" in text  # Table 1's efficiency so far, as the live view's
    assert "mapper" in text and "sim" in text and "counts" not in text
    # A service's own counts: the non-zero ones on a row of their own under it.
    status["services"]["ros2_bridge"] = {"alive": True, "state": "running", "reason": "", "rejected": {}, "counters": {"sent:cmd_vel": 7, "received:scan": 9, "watchdog_stops": 0}}
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert re.search(r"│   ros2_bridge counts +│ received:scan 9, sent:cmd_vel 7 +│", console.export_text()), console.export_text()
    del status["services"]["ros2_bridge"]
    stale = {"alive": True, "state": "stale", "reason": "stale: no odometry for 3.0 s, no scan for 3.0 s", "last_step": 17, "rejected": {}}
    status["services"]["planner"] = stale
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert "stale: no odometry for 3.0 s" in console.export_text()
    # Alive (its token) and no answer to the status query: hung, or stuck in a handler (it said "alive" only).
    status["services"]["policy"] = {"alive": True}
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert re.search(r"│ service policy +│ alive, not answering its status query \(hung\?\) +│", console.export_text()), console.export_text()
    del status["services"]["policy"]
    status["state"] = "done"
    console = Console(record=True, width=160)
    console.print(render_table(status))
    text = console.export_text()
    assert "idle (episode done; last step 17)" in text and "stale" not in text
    # Cells are text, not rich markup: a plan called "[red]plan[1].png" is shown as it is named.
    status["scene"] = "[red]plan[1]"
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert "[red]plan[1] / greedy-dist" in console.export_text()


def test_status_lists_the_services_of_the_runs_profile_not_a_fixed_five():
    """A ``limo-ros2`` run has a ROS 2 bridge and no sim: its status must not show a sim that is DOWN. Without
    a launcher (services started by hand) the five services of the ``sim`` profile are listed."""
    from cso_runtime.status import SERVICES, status_of

    launcher = {"run_id": "run-1", "services": {n: {"pid": 1, "restarts": 0, "gave_up": False} for n in ("ros2_bridge", "mapper", "frontier", "policy", "planner")}}
    launcher["services"]["ros2_bridge"].update(restarts=1, robot_stops=1)  # it died, the launcher stopped the robot
    bridge = {"state": "running", "reason": "", "last_step": 3, "rejected": {}, "processed": 4, "counters": {"received:scan": 4, "watchdog_stops": 1}}
    mapper = {"state": "running", "reason": "", "last_step": 3, "rejected": {}, "processed": 4}  # a service status without counters
    status = status_of("r0", None, launcher, {"mapper": mapper, "ros2_bridge": bridge}, {"mapper", "ros2_bridge"})
    assert sorted(status["services"]) == ["frontier", "mapper", "planner", "policy", "ros2_bridge"]
    # The bridge's own counts reach `status --json`, under the service.
    assert status["services"]["ros2_bridge"]["counters"] == {"received:scan": 4, "watchdog_stops": 1}
    assert status["services"]["mapper"]["counters"] == {} and "counters" not in status["services"]["planner"]
    assert status["services"]["ros2_bridge"]["robot_stops"] == 1 and status["services"]["mapper"]["robot_stops"] == 0
    from rich.console import Console

    from cso_runtime.status import render_table

    console = Console(record=True, width=200)
    console.print(render_table(status))
    assert "restarts 1, the launcher stopped the robot 1 times after it died" in console.export_text(), console.export_text()
    assert status["services"]["ros2_bridge"]["alive"] and not status["services"]["planner"]["alive"]
    alone = status_of("r0", None, None, {}, {"mapper"})
    assert sorted(alone["services"]) == sorted(SERVICES) and alone["state"] == "starting"


class _RunLeavingItsPolicyToAServer:
    """The launcher of robot r1's lockstep run whose policy is another run's server (``serve_all_robots``), its
    liveliness events, and ``status``'s object and table from its launcher's status, as ``status`` gets it."""

    def __init__(self, tmp_path: Path) -> None:
        from cso_runtime.launcher import Launcher
        from cso_runtime.run_profile import find_profile, load_profile

        profile, data = load_profile(str(find_profile("lockstep")), {"robot": "r1"})
        del profile.services["policy"]  # this run's policy is another run's server
        self.launcher = Launcher(profile, data, tmp_path / "run")

    def alive(self, name: str, kind: str) -> None:
        """A token of ``name`` under r1's keys came (``PUT``) or went (``DELETE``)."""
        from types import SimpleNamespace

        self.launcher._on_alive(SimpleNamespace(key_expr=self.launcher.keys.alive(name), kind=f"SampleKind.{kind}"))

    def table(self, alive_names: set[str], episode: dict | None = None) -> tuple[dict, str]:
        from rich.console import Console

        from cso_runtime.messages import LauncherStatusMsg
        from cso_runtime.status import render_table, status_of

        msg = decode(encode(self.launcher.launcher_status()), LauncherStatusMsg)
        assert isinstance(msg, LauncherStatusMsg)
        status = status_of("r1", episode, msg.to_dict(), {}, alive_names)
        console = Console(record=True, width=200)
        console.print(render_table(status))
        return status, console.export_text()


def test_status_shows_a_service_the_run_did_not_start_and_says_when_it_is_gone(tmp_path, caplog):
    """A robot whose run leaves its policy to a shared server (``serve_all_robots`` in another run) had no policy
    row in ``status`` at all: once that server went down the robot waited for goals with every row alive. The
    launcher lists such a service (``outside``), so ``status`` shows it and says DOWN when it goes. A profile that
    simply has no policy (no ``without:``) listed it only once a server answered: before, the robot waited for a
    policy that ``status`` did not name. It is listed from the start, and awaited: the episode waits for it, which
    the state says; a viewer's bridge started by hand and gone is listed DOWN, and nothing waits for it."""
    run = _RunLeavingItsPolicyToAServer(tmp_path)
    launcher, alive, table = run.launcher, run.alive, run.table
    exploring = {"state": "exploring", "step": 3}
    status, text = table({"mapper"}, exploring)  # no server has answered yet
    assert status["services"]["policy"] == {"alive": False, "outside": True, "awaited": True} and status["waiting_for"] == ["policy"]
    assert re.search(r"state +│ exploring; waiting for policy, which no process serves", text), text
    assert re.search(r"service policy +│ DOWN, not started by this run, the episode waits for it", text), text
    alive("mapper", "PUT")  # one of its own: listed as before, never "not started by this run"
    alive("policy", "PUT")
    status, text = table({"mapper", "policy"}, exploring)
    assert status["services"]["policy"] == {"alive": True, "outside": True, "awaited": True} and status["waiting_for"] == []
    assert re.search(r"service policy +│ alive, not started by this run\s", text) and "waiting" not in text, text
    assert launcher.outside_services == {"policy"}
    with caplog.at_level("WARNING", logger="cso.launcher"):
        alive("policy", "DELETE")
    assert "policy, which this run did not start, is gone (cso/r1/alive/policy); the episode waits for it until one comes back" in caplog.text
    status, text = table({"mapper"}, exploring)
    assert status["services"]["policy"] == {"alive": False, "outside": True, "awaited": True} and status["waiting_for"] == ["policy"]
    assert re.search(r"service policy +│ DOWN, not started by this run, the episode waits for it", text), text
    status, text = table({"mapper"}, {"state": "done", "step": 40})  # over: nothing is waited for
    assert status["waiting_for"] == [] and "waits" not in text and "waiting" not in text, text
    alive("foxglove_bridge", "PUT")  # a viewer's bridge started by hand (`service foxglove_bridge --attach`), then gone
    alive("foxglove_bridge", "DELETE")
    status, text = table({"mapper", "policy"}, exploring)
    assert status["services"]["foxglove_bridge"] == {"alive": False, "outside": True} and status["waiting_for"] == []
    assert re.search(r"service foxglove_bridge +│ DOWN, not started by this run\s", text) and "waiting" not in text, text


def test_a_shared_policy_that_no_longer_answers_for_a_finished_robot_is_idle_not_down(tmp_path):
    """A shared policy server restarted after a robot's episode was done announces only the robots it hears from
    again, and a finished robot sends no more decision inputs: its ``status`` (and ``up``'s live view) kept showing
    the policy "DOWN, not started by this run", a fault where there is none. After the episode a service the episode
    waited for and this run did not start reads idle, not needed after it (JSON keeps the raw ``alive: false``); while
    the episode runs it is DOWN as before, and a viewer's bridge (never awaited) gone after the end is DOWN still."""
    from rich.console import Console

    from cso_runtime.live_view import LiveView

    run = _RunLeavingItsPolicyToAServer(tmp_path)
    launcher, alive, table = run.launcher, run.alive, run.table
    alive("policy", "PUT")  # the server serves r1 ...
    alive("foxglove_bridge", "PUT")  # ... and a viewer's bridge is attached by hand
    alive("policy", "DELETE")  # the server restarts after r1's episode is done, and never hears from r1 again
    alive("foxglove_bridge", "DELETE")
    for state in ("done", "failed"):
        status, text = table({"mapper"}, {"state": state, "step": 40})
        assert status["services"]["policy"] == {"alive": False, "outside": True, "awaited": True}, status  # raw in JSON
        assert re.search(rf"service policy +│ idle \(episode {state}: not needed after it\), not started by this run\s", text), text
        assert "DOWN, not started by this run" in text.split("service foxglove_bridge")[1] and text.count("DOWN") == 1, text
    _, text = table({"mapper"}, {"state": "exploring", "step": 40})  # gone while the episode runs: DOWN, awaited
    assert re.search(r"service policy +│ DOWN, not started by this run, the episode waits for it", text), text
    launcher.status = EpisodeStatusMsg(state="done", step=40, scene="s", method="greedy-dist")  # `up`'s live view alike
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    view = console.export_text()
    assert re.search(r"│ policy +│ idle \(episode done: not needed after it\), not started by this run +│", view), view


def test_a_service_started_by_hand_that_leaves_after_the_episode_ended_is_not_said_to_be_awaited(tmp_path, caplog):
    """A viewer's bridge started by hand (``--attach``) that leaves once the episode is over: the launcher said "the
    episode goes on without it until one comes back", of an episode that had ended. It says the episode has ended."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import EpisodeStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {"robot": "r1"})
    launcher = Launcher(profile, data, tmp_path / "run")

    def alive(name: str, kind: str) -> None:
        launcher._on_alive(SimpleNamespace(key_expr=launcher.keys.alive(name), kind=f"SampleKind.{kind}"))

    alive("foxglove_bridge", "PUT")
    launcher.status = EpisodeStatusMsg(state="done", step=40)
    with caplog.at_level("INFO", logger="cso.launcher"):
        alive("foxglove_bridge", "DELETE")
    said = "foxglove_bridge, which this run did not start, is gone (cso/r1/alive/foxglove_bridge); the episode has ended"
    assert said in caplog.text and "goes on" not in caplog.text and "comes back" not in caplog.text, caplog.text


def test_up_without_refuses_a_service_it_cannot_leave_out_before_anything_starts(tmp_path, monkeypatch):
    """``up --without NAME`` leaves a service of the profile out of the run (its robot served by another run's shared
    policy); a name that is no service, one the profile does not have, or a referee (the episode's owner, without
    which the run cannot end) is a usage error naming the flag, exit 2 and nothing started; ``dataflow`` too."""
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import REFEREES, load_profile

    assert REFEREES == ("sim", "ros2_bridge")
    with pytest.raises(ConfigError, match=r"--without polcy \(did you mean policy\?\): no such service; known: sim, "):
        load_profile("lockstep", {}, without=["polcy"])
    with pytest.raises(ConfigError, match="--without foxglove_bridge: profile .*lockstep.yaml has no foxglove_bridge service"):
        load_profile("lockstep", {}, without=["foxglove_bridge"])
    with pytest.raises(ConfigError, match="--without sim: sim owns the episode"):
        load_profile("lockstep", {}, without=["policy", "sim"])
    with pytest.raises(ConfigError, match="--without ros2_bridge: ros2_bridge owns the episode"):
        load_profile("limo-ros2", {}, connect=["tcp/127.0.0.1:7447"], without=["ros2_bridge"])
    with pytest.raises(ConfigError, match="--without foxglove_bridge and --foxglove"):
        load_profile("lockstep", {}, foxglove=True, without=["foxglove_bridge"])
    profile, data = load_profile("lockstep", {}, without=["policy", "mapper", "policy"])  # repeated: once, in the profile's order
    assert list(profile.services) == list(data["services"]) == ["sim", "frontier", "planner"] and profile.without == data["without"] == ["mapper", "policy"]
    data["services"]["policy"] = {}  # a hand-written profile is held to the same: a service either runs or is left out
    with pytest.raises(ConfigError, match="without: policy is also in services"):
        from_dict_profile(data)
    monkeypatch.chdir(tmp_path)
    for args, said in (
        (["--without", "polcy"], "error: --without polcy (did you mean policy?): no such service"),
        (["--without", "sim"], "error: --without sim: sim owns the episode (its status and end); a run cannot go without it"),
        (["--profile", "limo-ros2", "--connect", "tcp/127.0.0.1:7447", "--without", "frontier", "--without", "ros2_bridge"], "error: --without ros2_bridge"),
    ):
        assert said in usage_error("up", "--profile", "lockstep", "--no-live", *args)
    assert not (tmp_path / "runs").exists()
    assert "error: --without planer (did you mean planner?): no such service" in usage_error("dataflow", "--profile", "lockstep", "--without", "planer")
    r = cli("up", "--profile", "lockstep", "--without", "policy", "--dry-run", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.startswith(
        "# profile lockstep, valid: `up` would start sim, mapper, frontier, planner for robot r0 (without policy: not started by this run)"
    ), r.stdout
    assert "policy" not in yaml.safe_load(r.stdout)["services"]
    r = cli("dataflow", "--profile", "lockstep", "--without", "policy", "--format", "mermaid", cwd=tmp_path)
    assert r.returncode == 0 and '  policy["policy (not started by this run)"]\n' in r.stdout and "  class policy outside\n" in r.stdout


def from_dict_profile(data: dict) -> None:
    """Validate a profile mapping as ``load_profile`` does (the run's ``profile.yaml``, a hand-written file)."""
    from cso_runtime.config import from_dict
    from cso_runtime.run_profile import Profile

    from_dict(Profile, data, where="profile")


def test_a_run_without_its_policy_starts_the_rest_records_it_and_lists_the_policy_as_expected_elsewhere(tmp_path, monkeypatch):
    """``up --without policy`` (a robot of another run's ``serve_all_robots`` server): the launcher starts every
    other service of the profile and no policy; the run's ``profile.yaml`` and ``dataflow.md`` say what ran and
    what is left to another process; ``status`` lists the policy, DOWN and not started by this run, before any
    server answers, so the user sees it is expected from elsewhere, not forgotten."""
    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import load_profile
    from cso_runtime.status import render_table, status_of
    from cso_runtime.supervision import Child

    profile, data = load_profile("lockstep", {"robot": "r1"}, without=["policy"])
    stop = threading.Event()
    stop.set()  # run() writes the run's files, then stops before its router: nothing is started here
    launcher = Launcher(profile, data, tmp_path / "run", stop_event=stop)
    launcher.run()
    written = yaml.safe_load(launcher.profile_path.read_text())
    assert list(written["services"]) == ["sim", "mapper", "frontier", "planner"] and written["without"] == ["policy"]
    dataflow = (launcher.run_dir / "dataflow.md").read_text()
    assert "Left out of this run (`up --without`, or not in the profile and needed), served by another process: `policy`." in dataflow
    assert "| policy (not started by this run) | `frontiers` (frontier) |" in dataflow and "  frontier -->|\"frontiers\"| policy\n" in dataflow
    assert '  policy["policy (not started by this run)"]\n' in dataflow and "  class policy outside\n" in dataflow  # drawn dashed, as docs say
    spawned: list[str] = []
    monkeypatch.setattr(Child, "spawn", lambda self: spawned.append(self.name))
    launcher = Launcher(profile, data, tmp_path / "run2")
    launcher.spawn_all()
    assert spawned == ["sim", "mapper", "frontier", "planner"]
    msg = decode(encode(launcher.launcher_status()), LauncherStatusMsg)  # as `status` gets it, no server up yet
    assert isinstance(msg, LauncherStatusMsg)
    status = status_of("r1", None, msg.to_dict(), {}, {"sim", "mapper"})
    assert status["services"]["policy"] == {"alive": False, "outside": True, "awaited": True} and status["waiting_for"] == ["policy"]
    console = Console(record=True, width=200)
    console.print(render_table(status))
    assert re.search(r"service policy +│ DOWN, not started by this run, the episode waits for it", console.export_text()), console.export_text()


def test_up_run_in_process_gives_back_the_signal_handlers_it_found(tmp_path):
    """``up`` sets Ctrl-C, SIGTERM and SIGHUP to stop its run from its first line; run inside another program (a
    test's CliRunner, a notebook) it left them so, and every later Ctrl-C set a finished run's stop event
    instead of interrupting the program (a later test's Ctrl-C never came). However it ends, they go back."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    def handlers() -> list:
        return [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]

    before = handlers()
    r = CliRunner().invoke(app, ["up", "--profile", "no-such-profile", "--runs-dir", str(tmp_path / "runs")])
    assert r.exit_code == 2 and "no-such-profile" in r.output, r.output
    assert handlers() == before
    runs = tmp_path / "runs"
    try:  # a whole run, through the launcher's own handlers
        r = CliRunner().invoke(app, ["up", "--profile", str(write_profile(tmp_path)), "--runs-dir", str(runs), "--no-live"])
        assert r.exit_code == 0 and handlers() == before, r.output
    finally:  # its services, never the launcher: this process
        kill_leftovers(runs, exclude=os.getpid())


def test_status_and_down_with_nothing_running(tmp_path):
    r = cli("status", cwd=tmp_path, timeout_s=10)
    assert r.returncode == 1 and "nothing running" in r.stdout and "`cso-runtime runs` lists past runs" in r.stdout
    # where it looked, and how to look elsewhere: an `up` started in another working folder keeps its run file there
    assert "no current run in runs; give --runs-dir of the folder `up` used, or --connect ENDPOINT" in r.stdout, r.stdout
    r = cli("status", "--json", cwd=tmp_path, timeout_s=10)  # a script reading the JSON gets JSON then too
    assert r.returncode == 1 and json.loads(r.stdout)["state"] == "not running" and "nothing running" in json.loads(r.stdout)["reason"]
    port = free_tcp_port()
    r = cli("status", "--json", "--connect", loopback_endpoint(port), cwd=tmp_path, timeout_s=10)
    assert r.returncode == 1 and json.loads(r.stdout) == {"state": "not running", "reason": f"nothing running (no answer for robot r0 at {loopback_endpoint(port)})"}
    t0 = time.monotonic()
    assert query_status([loopback_endpoint(port)], "r0") is None
    assert time.monotonic() - t0 < 2.0
    r = cli("down", cwd=tmp_path, timeout_s=10)
    assert r.returncode == 1 and "nothing running (no current run in runs;" in r.stderr, r.stderr
    r = cli("save-map", "--connect", loopback_endpoint(port), cwd=tmp_path, timeout_s=10)
    assert r.returncode == 1 and "no map for robot r0" in r.stdout
    assert not (tmp_path / "map.yaml").exists()


def test_status_pause_and_save_map_at_an_endpoint_of_several_robots_ask_which_not_r0(tmp_path):
    """``status --connect EP`` without ``--robot`` asked for robot r0 whatever answered there: with robots r1 and r2
    on the network it said "nothing running", and with r0 among others it showed r0 alone, not saying that others
    were there (``pause`` paused r0 so). It now takes the one robot that answers, and with several names them and
    asks for ``--robot`` (exit code 2, nothing sent)."""
    from cso_runtime.transport import open_router

    router, (endpoint,) = open_router(["tcp/127.0.0.1:0"], [])
    tokens = []
    try:
        tokens = [router.liveliness().declare_token(RobotKeys(robot).alive("sim")) for robot in ("r1", "r2")]
        for command in (("status", "--json"), ("pause",), ("save-map", "-f", str(tmp_path / "m")), ("record", "--out", str(tmp_path / "r.mcap"))):
            r = cli(*command, "--connect", endpoint, cwd=tmp_path, timeout_s=30)
            assert r.returncode == 2 and "robots r1, r2 answer at" in r.stderr and "--robot" in r.stderr, (command, r.stdout, r.stderr)
        assert not (tmp_path / "m.yaml").exists() and not (tmp_path / "r.mcap").exists()
        tokens.pop().undeclare()
        r = cli("status", "--json", "--connect", endpoint, cwd=tmp_path, timeout_s=30)
        assert r.returncode == 0 and json.loads(r.stdout)["robot"] == "r1", (r.stdout, r.stderr)
        record = [*python_module_argv("cso_runtime.cli"), "record", "--out", str(tmp_path / "r.mcap"), "--connect", endpoint]
        with subprocess.Popen(record, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
            try:
                first = proc.stdout.readline()  # said once its session is open
                proc.send_signal(signal.SIGINT)
                proc.communicate(timeout=30)
            finally:
                proc.kill()
        assert first.startswith("recording cso/r1/** from"), first
        r = cli("status", "--json", "--connect", endpoint, "--robot", "r2", cwd=tmp_path, timeout_s=30)  # named: asked as before
        assert r.returncode == 1 and "no answer for robot r2" in r.stdout, (r.stdout, r.stderr)
    finally:
        for token in tokens:
            token.undeclare()
        router.close()


def test_status_says_a_run_is_starting_before_its_router_is_open(tmp_path, monkeypatch, capsys):
    """For its first seconds (its router opening, its services spawning) a foreground ``up`` had written no run file,
    and ``status`` said "no current run". The launcher writes one, state ``starting``, before its router opens, and
    ``status`` (and ``save-map``, and a service's ``--attach``) say the run is starting; a start that fails leaves no
    current run, as before."""
    import cso_runtime.launcher as launcher_module
    from cso_runtime.launcher import Launcher, run_until_stopped
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import save_map_main, status_main
    from cso_runtime.transport import TransportError
    from services.common import parse_args

    runs = tmp_path / "runs"
    profile, data = load_profile(str(find_profile("lockstep")), {"robot": "r1"})
    launcher = Launcher(profile, data, runs / "run1")
    said: dict[str, object] = {}

    def router_opening(*_args: object, **_kwargs: object) -> None:  # what `status` sees while the router opens
        said["file"] = json.loads((runs / "current.json").read_text())
        capsys.readouterr()
        said["status"] = status_main([], None, False, False, runs, 1.0), capsys.readouterr().out
        said["json"] = status_main([], None, True, False, runs, 1.0), json.loads(capsys.readouterr().out)
        said["save-map"] = save_map_main([], None, tmp_path / "map", "pgm", runs), capsys.readouterr().out
        with pytest.raises(SystemExit) as exited:  # `cso-runtime service NAME --attach`: nothing to join yet
            parse_args("foxglove_bridge", ["--attach", "--runs-dir", str(runs)])
        said["attach"] = exited.value.code, capsys.readouterr().err
        raise TransportError("no router for this test")

    monkeypatch.setattr(launcher_module, "open_router", router_opening)
    assert run_until_stopped(launcher, live=False, stay_after_done=False) == launcher_module.EXIT_NO_ZENOH
    info = said["file"]
    assert isinstance(info, dict) and info["state"] == "starting" and info["run_id"] == "run1" and info["robot"] == "r1", info
    assert info["launcher_pid"] == os.getpid() and info["endpoints"] == [] and info["services"] == {}, info
    assert said["status"] == (1, "run run1 (robot r1) is starting: its router is not open yet; ask again in a moment\n"), said["status"]
    code, answer = said["json"]
    assert code == 1 and answer == {"state": "starting", "run_id": "run1", "reason": "run run1 (robot r1) is starting: its router is not open yet; ask again in a moment"}, answer
    assert said["save-map"][0] == 1 and "is starting" in str(said["save-map"][1]) and not (tmp_path / "map.yaml").exists(), said["save-map"]
    assert said["attach"][0] == 2 and "--attach: run run1 (robot r1) is starting" in str(said["attach"][1]), said["attach"]
    assert not (runs / "current.json").exists() and json.loads((runs / "run1" / "run.json").read_text())["state"] == "stopped"


def test_status_save_map_and_pause_of_a_run_whose_launcher_has_ended_it_say_so(tmp_path, monkeypatch, capsys):
    """As it ends a run the launcher writes its run file ``stopped`` and then removes it: ``status`` in between (a
    script polling it, ``status --watch`` started then) said "nothing running (no current run in runs; give --runs-dir
    of the folder `up` used ...)" of a run that failed as it started, and of one that ran, waited out a client's
    timeout on its closing router to say "no answer". They say the run has ended, at once."""
    from cso_runtime import status
    from cso_runtime.status import explore_resume_main, save_map_main, status_main
    from services.common import parse_args

    asked: list[list[str]] = []
    monkeypatch.setattr(status, "_client_session", lambda connect, zenoh_config_file=None: asked.append(connect))  # None: nothing there
    runs = tmp_path / "runs"
    for endpoints in ([], [loopback_endpoint(free_tcp_port())]):
        _, starting = starting_run_files(runs, os.getpid())
        ended = {**starting, "endpoints": endpoints, "state": "stopped", "outcome": "failed", "exit_code": 3}
        (runs / "current.json").write_text(json.dumps(ended))
        line = f"run run1 has ended (failed) and its launcher is exiting; `cso-runtime runs --runs-dir {runs}` lists it"
        capsys.readouterr()
        assert status_main([], None, False, False, runs, 1.0) == 1
        assert capsys.readouterr().out == f"nothing running ({line})\n"
        assert status_main([], None, True, True, runs, 0.1) == 1
        assert json.loads(capsys.readouterr().out) == {"state": "not running", "reason": f"nothing running ({line})"}
        assert save_map_main([], None, tmp_path / "map", "pgm", runs) == 1 and line in capsys.readouterr().out
        assert explore_resume_main([], None, runs, resume=False) == 1 and line in capsys.readouterr().out
        assert asked == [], "asked a router that is closing"
        with pytest.raises(SystemExit) as exited:  # `cso-runtime service NAME --attach`: nothing to join any more
            parse_args("foxglove_bridge", ["--attach", "--runs-dir", str(runs)])
        assert exited.value.code == 2 and f"--attach: {line}" in capsys.readouterr().err
        shutil.rmtree(runs)


def test_a_service_attached_as_up_checks_its_profile_says_that_up_is_starting_not_no_current_run(tmp_path, capsys):
    """``cso-runtime up & python -m services.NAME --attach``: for the ``up``'s first second or more it has written no run
    file, and ``--attach`` said "no current run in runs (start one with `cso-runtime up` ...)" of the run being started.
    It names the ``up`` that is starting, as ``status`` does (still exit 2: nothing to join yet)."""
    from cso_runtime.current_run import starting_up_path
    from cso_runtime.supervision import process_start_ticks
    from services.common import parse_args

    runs = tmp_path / "runs"
    runs.mkdir()
    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # an `up` checking its profile
    try:
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))
        with pytest.raises(SystemExit) as exited:
            parse_args("foxglove_bridge", ["--attach", "--runs-dir", str(runs)])
    finally:
        up.kill()
        up.wait(timeout=30)
    err = capsys.readouterr().err
    assert exited.value.code == 2 and f"--attach: `up` (pid {up.pid}) is starting in {runs}" in err, err


def test_status_names_an_up_still_checking_its_profile_and_watch_waits_for_it(tmp_path):
    """``up ... &`` then ``status --watch`` at once: for its first second or more (Python's imports, its profile
    checked, a scene or weights loaded) ``up`` has written no run file, and ``status`` said "nothing running (no current
    run)", exit 1, and ``--watch`` ended there. ``status`` now names the ``up`` that is starting (still exit 1: nothing
    to ask yet) and ``--watch`` waits for it; an ``up`` that ends without a run (refused) is "nothing running" as before."""
    from cso_runtime.current_run import starting_up_path
    from cso_runtime.supervision import process_start_ticks

    runs = tmp_path / "runs"
    runs.mkdir()
    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # an `up` checking its profile
    watch = None
    try:
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
        assert r.returncode == 1 and f"`up` (pid {up.pid}) is starting in {runs}" in r.stdout, (r.stdout, r.stderr)
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
        assert r.returncode == 1 and json.loads(r.stdout)["state"] == "starting", (r.stdout, r.stderr)
        argv = [*python_module_argv("cso_runtime.cli"), "status", "--watch", "--period", "0.2", "--runs-dir", str(runs)]
        watch = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert watch.stdout is not None
        first = watch.stdout.readline()
        assert f"`up` (pid {up.pid}) is starting" in first and "waiting for it..." in first, first
        up.kill()  # refused: it ends with no run file
        up.wait(timeout=30)
        out, err = watch.communicate(timeout=30)
        assert watch.returncode == 1 and "nothing running (no current run" in out, (out, err)
    finally:
        up.kill()
        up.wait(timeout=30)
        if watch is not None:
            watch.kill()
            watch.wait(timeout=30)


def test_status_watch_and_logs_follow_say_that_a_starting_up_is_stopped(tmp_path):
    """``up`` suspended (Ctrl-Z, SIGSTOP) while it checks its profile: ``status`` kept saying it "is starting", and
    ``status --watch`` and ``logs -f`` waited as long as it stayed stopped, with no word. They say it is stopped and
    how to go on, as ``status`` says it of a stopped launcher (``current_run.stopped_words``), and go on waiting."""
    from cso_runtime.current_run import starting_up_path
    from cso_runtime.supervision import process_start_ticks, process_state

    runs = tmp_path / "runs"
    runs.mkdir()
    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # an `up` checking its profile
    waiting: list[subprocess.Popen] = []
    stopped = f"is starting in {runs}: it has not written its run file yet, and it is stopped (Ctrl-Z or SIGSTOP): `kill -CONT {up.pid}` (or `fg` in its terminal) to go on"
    try:
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))
        os.kill(up.pid, signal.SIGSTOP)
        wait_for(lambda: process_state(up.pid) == "T", 10, "the `up` to be stopped")
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
        assert r.returncode == 1 and f"`up` (pid {up.pid}) {stopped}" in r.stdout and "ask again" not in r.stdout, (r.stdout, r.stderr)
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
        assert r.returncode == 1 and stopped in json.loads(r.stdout)["reason"], (r.stdout, r.stderr)
        os.kill(up.pid, signal.SIGCONT)
        for command, stream in ((["status", "--watch", "--period", "0.2"], "stdout"), (["logs", "-f"], "stderr")):
            proc = subprocess.Popen([*python_module_argv("cso_runtime.cli"), *command, "--runs-dir", str(runs)], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            waiting.append(proc)
            first = getattr(proc, stream).readline()
            assert f"`up` (pid {up.pid}) is starting" in first and "stopped" not in first, (command, first)
            os.kill(up.pid, signal.SIGSTOP)  # Ctrl-Z while they wait: said then
            then = getattr(proc, stream).readline()
            assert stopped in then and then.rstrip().endswith("; waiting for it..."), (command, then)
            assert proc.poll() is None, command  # it waits on, as for an `up` that runs
            os.kill(up.pid, signal.SIGCONT)
    finally:
        up.kill()  # SIGKILL ends a stopped process too
        up.wait(timeout=30)
        for proc in waiting:
            proc.kill()
            proc.communicate(timeout=30)


def test_save_map_below_a_file_names_the_file_in_the_way(tmp_path, monkeypatch, capsys):
    """``save-map -f out/m`` where ``out`` is a file said "cannot write the map to out/m.yaml: File exists": neither
    which path nor why. It names the file that is in the way of the folder; other errors are said as before."""
    import cso_runtime.status as status_module
    from cso_runtime.geometry import MAP_FRAME_ORIGIN
    from cso_runtime.status import RunTarget

    grid = np.zeros((4, 5), dtype=np.int8)
    msg = MapMsg.from_grid(7, GridGeometry(0.05, (4, 5)), grid)
    monkeypatch.setattr(status_module, "target_of_run", lambda *_a, **_k: RunTarget(["tcp/127.0.0.1:1"], "r0", None))
    monkeypatch.setattr(status_module, "query_map", lambda *_a, **_k: (msg, "", MAP_FRAME_ORIGIN))
    (tmp_path / "a_file").write_text("")
    for out in (tmp_path / "a_file" / "m", tmp_path / "a_file" / "deeper" / "m"):
        assert save_map_main([], None, out, "pgm", tmp_path / "runs") == 2
        err = capsys.readouterr().err
        assert err == f"error: cannot write the map to {out}.yaml: {tmp_path / 'a_file'} is a file, not a folder\n", err
    assert save_map_main([], None, tmp_path / "ok" / "m", "pgm", tmp_path / "runs") == 0  # a missing folder is made
    assert (tmp_path / "ok" / "m.yaml").is_file() and "map of step 7" in capsys.readouterr().out


def test_save_map_in_a_runs_first_seconds_says_it_has_no_map_yet_not_only_the_key(tmp_path, monkeypatch, capsys):
    """``save-map`` in the first seconds of a run said "no map for robot r0: nothing answered on cso/r0/cache/map": true,
    but a user's question is what state the run is in. It says that the run has no map yet (its mapper has not
    published one, the episode's state and step when its status answers, else that its services may still be
    starting), to try again in a moment, and keeps the key and what it answered for those who debug."""
    from types import SimpleNamespace

    import cso_runtime.status as status_module
    from cso_runtime.messages import EpisodeStatusMsg
    from cso_runtime.status import RunTarget

    def reply(ok: bytes | None = None, err: str | None = None) -> SimpleNamespace:
        payload = SimpleNamespace(to_bytes=lambda: ok, to_string=lambda: err)
        return SimpleNamespace(ok=None if ok is None else SimpleNamespace(payload=payload), err=None if err is None else SimpleNamespace(payload=payload))

    class Session(contextlib.AbstractContextManager):  # a run's network as save-map asks it: the episode's status and the map's key
        def __init__(self, answers: dict[str, list[SimpleNamespace]]) -> None:
            self.answers = answers

        def __exit__(self, *_exc: object) -> None:
            pass

        def get(self, key: str, **_kw: object) -> list[SimpleNamespace]:
            return self.answers.get(key, [])

    keys = RobotKeys("r0")
    monkeypatch.setattr(status_module, "target_of_run", lambda *_a, **_k: RunTarget(["tcp/127.0.0.1:1"], "r0", None))
    starting = encode(EpisodeStatusMsg(state="starting", step=0))
    for answers, said in (
        ({}, ("no episode status answers either: its services may still be starting", f"nothing answered on {keys.cache('map')}", "`cso-runtime status`")),
        ({keys.episode_status: [reply(starting)]}, ("its mapper has not published one (the episode is starting, at step 0;", f"nothing answered on {keys.cache('map')}")),
        ({keys.episode_status: [reply(starting)], keys.cache("map"): [reply(err="no map yet")]}, (f"{keys.cache('map')} answered: no map yet",)),
    ):
        monkeypatch.setattr(status_module, "_client_session", lambda *_a, answers=answers, **_k: Session(answers))
        assert save_map_main([], None, tmp_path / "m", "pgm", tmp_path / "runs") == 1
        out = capsys.readouterr().out
        assert out.startswith("no map for robot r0: the run has no map yet") and out.rstrip().endswith("; try again in a moment"), out
        assert all(words in out for words in said), out
    # An episode over: no map will come (a mapper restarted after the end), so no "try again".
    over = encode(EpisodeStatusMsg(state="done", step=212))
    monkeypatch.setattr(status_module, "_client_session", lambda *_a, **_k: Session({keys.episode_status: [reply(over)]}))
    assert save_map_main([], None, tmp_path / "m", "pgm", tmp_path / "runs") == 1
    out = capsys.readouterr().out
    assert "none will come: the episode is done, at step 212; " in out and "try again" not in out, out
    assert not (tmp_path / "m.yaml").exists()


def test_save_map_after_the_episode_says_where_its_final_map_is_or_that_none_was_written(tmp_path, monkeypatch, capsys):
    """``save-map`` after the episode's end said "its final map is among the run's results" whatever the run wrote:
    also of a run whose results are not written (yet, or a full disk) and of one whose result carried no map. It says
    only what is true: the final map's file where it is there, else that none was written and why, and what to do; of
    a run given by ``--connect`` (its folder maybe on another host), where to look there."""
    from types import SimpleNamespace

    import cso_runtime.status as status_module
    from cso_runtime.launcher import LAST_MAP
    from cso_runtime.outputs import episode_map_path
    from cso_runtime.status import RunTarget

    over = encode(EpisodeStatusMsg(state="done", step=212, scene="generated:small:1:0", method="cso"))
    payload = SimpleNamespace(to_bytes=lambda: over, to_string=lambda: "")
    keys = RobotKeys("r0")

    class Session(contextlib.AbstractContextManager):  # a finished run's network: its episode's status, no map answers
        def __exit__(self, *_exc: object) -> None:
            pass

        def get(self, key: str, **_kw: object) -> list[SimpleNamespace]:
            return [SimpleNamespace(ok=SimpleNamespace(payload=payload), err=None)] if key == keys.episode_status else []

    monkeypatch.setattr(status_module, "_client_session", lambda *_a, **_k: Session())
    monkeypatch.setattr(status_module, "target_of_run", lambda *_a, **_k: RunTarget(["tcp/127.0.0.1:1"], "r0", None))
    runs, run_dir = tmp_path / "runs", tmp_path / "runs" / "run1"
    run_dir.mkdir(parents=True)
    (runs / "current.json").write_text(json.dumps({"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": ["tcp/127.0.0.1:1"]}))
    final = episode_map_path(run_dir, "cso", "generated:small:1:0")

    def said(connect: list[str] | None = None) -> str:
        assert save_map_main(connect or [], None, tmp_path / "m", "pgm", runs) == 1
        out = capsys.readouterr().out
        assert out.startswith("no map for robot r0: no map answers, and none will come: the episode is done, at step 212; "), out
        assert "among the run's results" not in out and "try again" not in out and not (tmp_path / "m.yaml").exists(), out
        return out

    # No results written (yet, or they could not be): no final map, and where to read why.
    out = said()
    assert f"no final map is written: the run has not written its results in {run_dir}/" in out and f"`cso-runtime logs --run {run_dir}`" in out, out
    # The run's map kept at its stop, its results unwritten: that file.
    save_map(run_dir / LAST_MAP, np.zeros((4, 5), dtype=np.int8), GridGeometry(0.05, (4, 5)), image_format="png")
    assert f"its map at the run's stop is {run_dir / LAST_MAP}" in said()
    # Results written whose episode carried no map: none written, said so.
    (run_dir / "summary.json").write_text("{}")
    out = said()
    assert f"no final map was written: the run's results in {run_dir}/ have none ({final} is not there" in out, out
    # Results with the final map: its file.
    save_map(final, np.zeros((4, 5), dtype=np.int8), GridGeometry(0.05, (4, 5)), image_format="png")
    assert f"its final map is {final}" in said()
    # A run given by --connect: its folder is where it runs, perhaps another host.
    out = said(["tcp/127.0.0.1:1"])
    assert "its final map, where the run wrote one, is in maps/ of the run's folder on the host that runs it" in out and str(final) not in out, out


def test_save_map_of_another_robot_than_the_current_runs_names_no_file_of_the_current_run(tmp_path, monkeypatch, capsys):
    """``save-map --robot r1`` after r1's episode ended, through the current run's router (r0's run, whose network r1's
    run joined): it took the current run's folder for r1's and said "its final map is runs/<r0's run>/maps/cso/...yaml",
    r0's map, where both robots ran one method on one scene. The current run's folder is the asked robot's only where the
    run file names that robot; another robot's run is said as one given by ``--connect``: its folder is elsewhere."""
    from types import SimpleNamespace

    import cso_runtime.status as status_module
    from cso_runtime.outputs import episode_map_path

    over = encode(EpisodeStatusMsg(state="done", step=212, scene="generated:small:1:0", method="cso"))
    payload = SimpleNamespace(to_bytes=lambda: over, to_string=lambda: "")
    keys = RobotKeys("r1")

    class Session(contextlib.AbstractContextManager):  # r1's ended episode answers through r0's router; no map answers
        def __exit__(self, *_exc: object) -> None:
            pass

        def get(self, key: str, **_kw: object) -> list[SimpleNamespace]:
            return [SimpleNamespace(ok=SimpleNamespace(payload=payload), err=None)] if key == keys.episode_status else []

    monkeypatch.setattr(status_module, "_client_session", lambda *_a, **_k: Session())
    runs, run_dir = tmp_path / "runs", tmp_path / "runs" / "run-of-r0"
    run_dir.mkdir(parents=True)
    (runs / "current.json").write_text(json.dumps({"run_id": run_dir.name, "run_dir": str(run_dir), "robot": "r0", "endpoints": ["tcp/127.0.0.1:1"]}))
    r0_map = episode_map_path(run_dir, "cso", "generated:small:1:0")  # r0's own final map, of the same method and scene
    save_map(r0_map, np.zeros((4, 5), dtype=np.int8), GridGeometry(0.05, (4, 5)), image_format="png")
    (run_dir / "summary.json").write_text("{}")
    assert save_map_main([], "r1", tmp_path / "m", "pgm", runs) == 1
    out = capsys.readouterr().out
    assert out.startswith("no map for robot r1: no map answers, and none will come: the episode is done, at step 212; "), out
    assert str(run_dir) not in out and "its final map, where the run wrote one, is in maps/ of the run's folder on the host that runs it" in out, out


def test_save_map_reads_the_run_file_once_and_names_the_folder_of_the_run_it_asked(tmp_path, monkeypatch, capsys):
    """``save-map`` read ``runs/current.json`` twice: once for the run's router (``reachable_target``), once for its
    folder. A run that ended and another that started in between made its "no map" name the next run's folder, of a
    run it had not asked. It reads the run file once: the router asked and the folder named are of one run."""
    from types import SimpleNamespace

    import cso_runtime.current_run as current_run_module
    import cso_runtime.status as status_module

    over = encode(EpisodeStatusMsg(state="done", step=212, scene="generated:small:1:0", method="cso"))
    payload = SimpleNamespace(to_bytes=lambda: over, to_string=lambda: "")
    asked: list[list[str]] = []

    class Session(contextlib.AbstractContextManager):  # an ended episode answers; no map does
        def __exit__(self, *_exc: object) -> None:
            pass

        def get(self, key: str, **_kw: object) -> list[SimpleNamespace]:
            return [SimpleNamespace(ok=SimpleNamespace(payload=payload), err=None)] if key == RobotKeys("r0").episode_status else []

    monkeypatch.setattr(status_module, "_client_session", lambda connect, *_a, **_k: asked.append(list(connect)) or Session())
    runs = tmp_path / "runs"
    first, second = ({"run_id": name, "run_dir": str(runs / name), "robot": "r0", "endpoints": [f"tcp/127.0.0.1:{port}"]} for name, port in (("run-a", 1), ("run-b", 2)))
    readings = iter([first, second, second])  # run-a's file at the first reading, run-b's from then on
    monkeypatch.setattr(current_run_module, "read_current_run", lambda *_a, **_k: next(readings))
    assert save_map_main([], None, tmp_path / "m", "pgm", runs) == 1
    out = capsys.readouterr().out
    assert asked == [["tcp/127.0.0.1:1"]] and f"the run has not written its results in {runs / 'run-a'}/" in out, out
    assert "run-b" not in out and next(readings) is second, out  # read once: run-b's file never read


def test_status_says_at_once_that_a_killed_launchers_run_cannot_answer(tmp_path):
    """A launcher killed by SIGKILL leaves runs/current.json behind: ``status`` says its launcher has exited
    instead of waiting on the router it held. A router that is stopped (its port accepts TCP, no Zenoh
    handshake comes) is still "nothing running" within the 2 s the status command promises."""
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)  # never accepted: the kernel completes each TCP handshake, nothing more comes
    endpoint = loopback_endpoint(silent.getsockname()[1])
    exited = subprocess.Popen([sys.executable, "-c", "pass"])
    exited.wait(timeout=30)
    try:
        runs = tmp_path / "runs"
        runs.mkdir()
        (runs / "current.json").write_text(json.dumps({"run_id": "old", "robot": "r0", "launcher_pid": exited.pid, "endpoints": [endpoint]}))
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=10)
        reason = json.loads(r.stdout)["reason"]
        assert r.returncode == 1 and f"run old's launcher, pid {exited.pid}, has exited" in reason and "cso-runtime down" in reason
        t0 = time.monotonic()
        assert query_status([endpoint], "r0") is None
        assert time.monotonic() - t0 < 2.0
    finally:
        silent.close()


def test_status_says_that_a_stopped_launchers_run_cannot_answer_until_it_is_continued(tmp_path):
    """A launcher stopped with Ctrl-Z or SIGSTOP stops its embedded router with it: ``status`` said "nothing running
    (no answer ...)" of a run whose processes all run, and nothing of why. It now names the stopped launcher and
    how to go on, still exit 1 and the state ``not running`` (nothing answers)."""
    from cso_runtime.supervision import process_start_ticks, process_state

    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)  # the stopped router's port: the kernel completes each TCP handshake, nothing more comes
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        os.kill(launcher.pid, signal.SIGSTOP)
        wait_for(lambda: process_state(launcher.pid) == "T", 10, "the launcher to be stopped")
        runs = tmp_path / "runs"
        runs.mkdir()
        info = {"run_id": "frozen", "robot": "r0", "launcher_pid": launcher.pid, "launcher_start_ticks": process_start_ticks(launcher.pid)}
        (runs / "current.json").write_text(json.dumps({**info, "endpoints": [loopback_endpoint(silent.getsockname()[1])]}))
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=10)
        said = json.loads(r.stdout)
        assert r.returncode == 1 and said["state"] == "not running", r.stdout
        assert f"run frozen's launcher, pid {launcher.pid}, is stopped" in said["reason"] and f"kill -CONT {launcher.pid}" in said["reason"], said
        # the way to stop it names its runs folder: `cso-runtime down` alone stops the run of ./runs, another robot's
        assert said["reason"].endswith(f"`cso-runtime down --runs-dir {runs}` to stop the run)"), said
    finally:
        launcher.kill()
        launcher.wait(timeout=30)
        silent.close()


def test_a_profile_sets_the_mujoco_limos_parameters_checked_before_anything_starts():
    """``services.sim.mujoco``: the MuJoCo LIMO's parameters (``configs/robot_sim.yaml``'s keys) in a profile, each
    checked before any process starts: a bad value, an unknown key, the kinematic backend, a second LiDAR mount."""
    from cso_runtime.config import ConfigError, from_dict
    from cso_runtime.run_profile import load_profile
    from services.sim import SimParams

    profile, written = load_profile("sim", {}, settings={"services.sim.mujoco.odom_trans_noise_frac": 0.02})
    assert written["services"]["sim"]["mujoco"] == {"odom_trans_noise_frac": 0.02}  # what the sim service reads
    assert from_dict(SimParams, profile.services["sim"]).mujoco == {"odom_trans_noise_frac": 0.02}
    for key, value, error in [
        ("services.sim.mujoco.timestep_s", -1, r"timestep_s must be in \[1e-05, 0\.05\] s .*got -1$"),
        ("services.sim.mujoco.odom_noise", 0.1, "unknown key"),
        ("services.sim.mujoco.lidar_mount_x_m", 0.2, "not the sensor's mount"),
    ]:
        with pytest.raises(ConfigError, match=error):
            load_profile("sim", {}, settings={key: value})
    with pytest.raises(ConfigError, match="need backend mujoco, not kinematic"):
        load_profile("lockstep", {}, settings={"services.sim.mujoco.odom_trans_noise_frac": 0.02})


def test_up_checks_the_mujoco_limos_parameters_against_the_mount_its_services_run_with():
    """A profile whose sim is the MuJoCo LIMO runs every service with its LiDAR 0.103 m ahead and its box body
    (``load_profile_for_service``); the launcher's check of ``services.sim.mujoco`` used the bare defaults (a
    sensor at 0 m), so ``--set services.sim.mujoco.lidar_mount_x_m=0.103``, the value ``configs/robot_sim.yaml``
    documents, was refused as "not the sensor's mount (0.0 m)"."""
    from cso_runtime.config import ConfigError
    from cso_runtime.run_profile import find_profile, load_profile
    from services.common import load_profile_for_service

    profile, _ = load_profile("sim", {}, settings={"services.sim.mujoco.lidar_mount_x_m": 0.103})
    ran = load_profile_for_service(find_profile("sim"), "sim")[1]
    assert profile.exploration_config() == ran and ran.sensor.mount_x_m == 0.103 and ran.planner.body == "box"
    with pytest.raises(ConfigError, match=r"0.2 is not the sensor's mount \(0.103 m\).*set exploration.sensor.mount_x_m: 0.2 in the profile "
                       r"or with up --set exploration.sensor.mount_x_m=0.2 instead"):  # a profile's key, not eval's sensor.mount_x_m
        load_profile("sim", {}, settings={"services.sim.mujoco.lidar_mount_x_m": 0.2})
    explicit, _ = load_profile("sim", {}, settings={"exploration.sensor.mount_x_m": 0.05, "services.sim.mujoco.lidar_mount_x_m": 0.05})
    assert explicit.exploration_config().sensor.mount_x_m == 0.05  # a profile's own mount is kept
    assert load_profile("lockstep", {})[0].exploration_config().sensor.mount_x_m == 0.0  # the 2D sim's robot: no LIMO mount


def test_status_watch_prints_each_status_until_nothing_answers_then_exits_1(monkeypatch, capsys):
    """``status --watch --json``: one JSON line per period while the episode answers, then the ``not running``
    line and exit code 1 (a script following a run sees it end)."""
    from cso_runtime import status

    answers = iter([{"state": "exploring", "step": 3}, {"state": "exploring", "step": 5}, {"state": "done", "step": 9}, None])
    query_s = iter([0.2, 1.2, 0.2, 0.2])  # the second query overruns its period (a service that does not answer)
    clock_s = [100.0]
    naps: list[float] = []

    def answer(connect, robot, timeout_s=0.6, zenoh_config_file=None):
        clock_s[0] += next(query_s)
        return next(answers)

    monkeypatch.setattr(status, "query_status", answer)
    monkeypatch.setattr(status.time, "monotonic", lambda: clock_s[0])
    monkeypatch.setattr(status.time, "sleep", lambda s: (naps.append(round(s, 6)), clock_s.__setitem__(0, clock_s[0] + s)))
    code = status.status_main([loopback_endpoint(7447)], "r0", as_json=True, watch=True, runs_dir=Path("."), period_s=0.5)
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    # On the 0.5 s schedule from the first query, not 0.5 s after each; the overrun period is skipped.
    assert code == 1 and naps == [0.3, 0.3, 0.3] and clock_s[0] == pytest.approx(102.7)
    assert [line["state"] for line in lines] == ["exploring", "exploring", "done", "not running"] and lines[2]["step"] == 9


@pytest.mark.parametrize("terminal", [True, False])
def test_status_watch_redraws_one_table_on_a_terminal_and_appends_plain_tables_elsewhere(monkeypatch, capsys, terminal):
    """On a terminal ``status --watch`` printed a new table under the last every period (the screen scrolled,
    each table as wide as its cells); it now redraws one in place, as ``up``'s live view does. In a file or a
    pipe each table still follows the last, with no control codes."""
    import io

    from rich.console import Console

    from cso_runtime import status

    def at(step: int) -> dict:
        return status.status_of("r0", {"state": "exploring", "step": step, "coverage_pct": 2.0 * step, "scene": "s", "method": "cso"},
                                {"run_id": "run1", "services": {"sim": {"pid": 1, "restarts": 0}}}, {}, {"sim"})

    answers = iter([at(3), at(4), at(5), None])
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: next(answers))
    monkeypatch.setattr(status.time, "sleep", lambda s: None)
    out = TerminalFile() if terminal else io.StringIO()
    console = Console(file=out, force_terminal=terminal, width=80, height=40, color_system=None)
    code = status.status_main([loopback_endpoint(7447)], "r0", as_json=False, watch=True, runs_dir=Path("."), period_s=0.1, console=console)
    text = out.getvalue()
    assert code == 1 and capsys.readouterr().out == "nothing running (no answer for robot r0 at tcp/127.0.0.1:7447)\n"
    if terminal:  # (stopping draws the last table once more, in place)
        assert text.count("\x1b[2K") >= 2 * 20  # the second and third tables erase the one before (one line each)
    else:
        assert "\x1b" not in text and text.count("robot r0  run run1") == 3  # each status once, one under the other


def test_status_json_writes_figures_rounded_not_a_float_sums_digits(monkeypatch, capsys):
    """``status --json`` printed a float sum's last digits (``"coverage_pct": 0.30000000000000004``, a pose's
    ``4.7250000000000005``), which a script compares badly and a reader takes for precision: every float of its lines
    (``status.print_json``) is ``geometry.rounded``, ints and text as they are."""
    from cso_runtime import status

    answer = status.status_of("r0", {"state": "exploring", "step": 3, "coverage_pct": 0.1 + 0.2, "explored_area_m2": 4.7250000000000005, "scene": "s", "method": "cso"},
                              {"run_id": "run1", "services": {"sim": {"pid": 1, "restarts": 0}}}, {}, {"sim"})
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: answer)
    assert status.status_main([loopback_endpoint(7447)], "r0", as_json=True, watch=False, runs_dir=Path(".")) == 0
    out = capsys.readouterr().out
    shown = json.loads(out)
    assert (shown["coverage_pct"], shown["explored_area_m2"], shown["step"]) == (0.3, 4.725, 3), out
    assert "0000000" not in out, out


def write_running_run(runs: Path, run_dir: Path) -> dict[str, Any]:
    """``run_dir``'s run.json and the runs folder's current.json, of a run this process launches (robot r0, a router on
    port 7447), as a running launcher writes them; returns that record."""
    run_dir.mkdir(parents=True)
    running = {"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [loopback_endpoint(7447)], "launcher_pid": os.getpid(), "state": "running"}
    for path in (run_dir / "run.json", runs / "current.json"):
        path.write_text(json.dumps(running))
    return running


@pytest.mark.parametrize("pose_heard", [False, True], ids=["older-launcher", "launcher-heard-the-pose"])
@pytest.mark.parametrize(("outcome", "exit_code", "as_json"), [("done", 0, False), ("done", 0, True), ("interrupted", 130, False), ("failed", 1, True)])
def test_status_watch_ends_by_saying_how_the_run_it_watched_ended_and_where_its_results_are(tmp_path, monkeypatch, capsys, outcome, exit_code, as_json, pose_heard):
    """``status --watch`` on a run of ``up`` that ended normally said "nothing running (no answer ...)" and exited 1,
    its last table showing the services DOWN, goal "-" and "last 0.0 ms" as the launcher stopped them. A run it saw
    answering whose run.json then says it stopped: how it ended, where its results are, exit 0 when done (else
    ``up``'s exit code); the frame while the launcher stops the services says "stopping" and keeps the goal and the
    robot's pose: the launcher's last-heard one (of the episode's last step) when it has it, else the watch's last; the
    end line says that pose too (``robot_ended_at``: in the map frame, as the table), and ``--json``'s ``pose``."""
    import io

    from rich.console import Console

    from cso_runtime import status

    runs = tmp_path / "runs"
    run_dir = runs / "20261206-120000-lockstep-r0"
    running = write_running_run(runs, run_dir)
    services = {"sim": {"pid": 1, "restarts": 0}, "planner": {"pid": 2, "restarts": 0}}
    episode = {"state": "exploring", "step": 5, "episode": 7, "scene": "s", "method": "cso", "goal_xy_m": [1.5, 2.5], "last_decision_ms": 12.5, "decisions": 3}
    episode.update(pose=[1.25, 2.0, 0.5], twist=[0.2, 0.0])
    exploring = status.status_of("r0", episode, {"run_id": "run1", "state": "running", "services": services}, {}, {"sim", "planner"})
    heard = {"state": "done", "step": 9, "episode": 7, "age_s": 0.4, "terminated_by": "coverage", "decisions": 4}
    if pose_heard:  # the episode's last step, after the watch's last answer
        heard.update(map_origin=[0.0, 0.0, 0.0], pose=[1.75, 2.25, 0.25], twist=[0.0, 0.0])
    stopping = status.status_of("r0", None, {"run_id": "run1", "state": "stopping", "services": services, "last_episode": heard}, {}, set())

    def launcher_ends() -> None:  # as the launcher does once its services stopped: run.json says how, current.json goes
        (run_dir / "run.json").write_text(json.dumps({**running, "state": "stopped", "outcome": outcome, "exit_code": exit_code}))
        (runs / "current.json").unlink()

    answers = iter([lambda: exploring, lambda: stopping, lambda: launcher_ends()])
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: next(answers)())
    monkeypatch.setattr(status.time, "sleep", lambda s: None)
    out = io.StringIO()
    console = Console(file=out, force_terminal=False, width=100, height=60, color_system=None)
    code = status.status_main([], None, as_json=as_json, watch=True, runs_dir=runs, period_s=0.1, console=console)
    said = capsys.readouterr().out
    assert code == exit_code
    if as_json:
        last = json.loads(said.splitlines()[-1])
        assert (last["state"], last["outcome"], last["exit_code"], last["run_dir"]) == ("not running", outcome, exit_code, str(run_dir))
        assert (last["episode_state"], last["terminated_by"], last["step"]) == ("done", "coverage", 9)
        assert last["pose"] == ([1.75, 2.25, 0.25] if pose_heard else [1.25, 2.0, 0.5])  # where the robot ended, in the map frame
        return
    assert said.startswith(f"run run1 ended: {outcome}, its episode done (coverage) at step 9") and "no answer" not in said, said
    at = "x 1.75 m  y 2.25 m  yaw 0.25 rad" if pose_heard else "x 1.25 m  y 2.00 m  yaw 0.50 rad"  # as the status table says it
    assert f"at step 9, the robot at {at} (map frame)" in said.splitlines()[0], said
    assert (f"results in {run_dir}/: report.html" in said) == (outcome == "done") and (f", exit code {exit_code}" in said) == (exit_code != 0), said
    last_table = out.getvalue().split("robot r0  run run1")[-1]
    assert "DOWN" not in last_table and re.search(r"service sim +│ stopping", last_table), last_table
    assert re.search(r"goal +│ \(1\.50, 2\.50\) m", last_table) and "last 12.5 ms" in last_table, last_table
    where = r"x 1\.75 m  y 2\.25 m  yaw 0\.25 rad, 0\.00 m/s" if pose_heard else r"x 1\.25 m  y 2\.00 m  yaw 0\.50 rad, 0\.20 m/s"
    assert re.search(r"pose +│ " + where, last_table), last_table  # where the robot stopped


@pytest.mark.parametrize("pose_heard", [False, True], ids=["older-launcher", "launcher-heard-the-pose"])
def test_status_watch_json_lines_say_the_pose_the_end_line_says_in_the_map_frame(tmp_path, monkeypatch, capsys, pose_heard):
    """``status --watch --json`` printed each raw status while its table and its end line showed the pose kept from the
    watch's last answer once the sim stopped: with an older launcher (its last-heard status has no pose) the last
    streamed line said ``pose: null`` (and the scene's ``map_origin`` as the identity) and the end line a pose. Every
    pose is ``status_of``'s, in the map frame; the streamed lines are what the table shows, so the last one's ``pose``
    and ``map_origin`` are the end line's and the last answer's."""
    from cso_runtime import status

    runs = tmp_path / "runs"
    run_dir = runs / "20261207-120000-lockstep-r0"
    running = write_running_run(runs, run_dir)
    services = {"sim": {"pid": 1, "restarts": 0}}
    origin = [0.5, -1.0, 0.0]  # a map_server scene's origin: the scene's frame is not the map frame
    episode = {"state": "exploring", "step": 5, "episode": 7, "scene": "s", "method": "cso", "goal_xy_m": [1.5, 2.5], "pose": [1.25, 2.0, 0.5],
               "twist": [0.2, 0.0], "map_origin": origin}
    exploring = status.status_of("r0", episode, {"run_id": "run1", "state": "running", "services": services}, {}, {"sim"})
    heard = {"state": "done", "step": 9, "episode": 7, "age_s": 0.4, "terminated_by": "coverage", "decisions": 4}
    if pose_heard:  # the episode's last step, after the watch's last answer (scene frame, as episode_status carries it)
        heard.update(map_origin=origin, pose=[1.5, 2.25, 0.25], twist=[0.0, 0.0])
    stopping = status.status_of("r0", None, {"run_id": "run1", "state": "stopping", "services": services, "last_episode": heard}, {}, set())

    def launcher_ends() -> None:
        (run_dir / "run.json").write_text(json.dumps({**running, "state": "stopped", "outcome": "done", "exit_code": 0}))
        (runs / "current.json").unlink()

    answers = iter([lambda: exploring, lambda: stopping, lambda: launcher_ends()])
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: next(answers)())
    monkeypatch.setattr(status.time, "sleep", lambda s: None)
    assert status.status_main([], None, as_json=True, watch=True, runs_dir=runs, period_s=0.1) == 0
    *streamed, end = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [line["state"] for line in streamed] == ["exploring", "done"] and end["state"] == "not running"
    ended_at = [2.0, 1.25, 0.25] if pose_heard else [1.75, 1.0, 0.5]  # the scene's pose moved by the map origin
    assert streamed[0]["pose"] == [1.75, 1.0, 0.5] and streamed[-1]["pose"] == end["pose"] == ended_at, (streamed, end)
    assert streamed[-1]["map_origin"] == origin and streamed[-1]["goal"] == streamed[0]["goal"] == [2.0, 1.5]


@pytest.mark.parametrize(("episode_state", "exit_code", "as_json"), [("done", 0, False), ("done", 0, True), ("failed", 1, False)])
def test_status_watch_of_a_detached_run_ends_with_its_episode(tmp_path, monkeypatch, capsys, episode_state, exit_code, as_json):
    """``up --detach`` stays up after its episode, answering ``status``, until ``down``: ``status --watch`` on it
    refreshed the finished episode's table for ever (``logs -f`` ends there). Once run.json says the detached run's
    episode ended, it ends: how the episode ended, where the robot ended (in the map frame), where the results are, that
    the run stays up until ``down``."""
    from rich.console import Console

    from cso_runtime import status
    from cso_runtime.supervision import process_start_ticks

    runs = tmp_path / "runs"
    run_dir = runs / "20261206-120000-lockstep-r0"
    run_dir.mkdir(parents=True)
    running = {"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [loopback_endpoint(7447)], "launcher_pid": os.getpid(),
               "launcher_start_ticks": process_start_ticks(os.getpid()), "state": "running", "detached": True}
    for path in (run_dir / "run.json", runs / "current.json"):
        path.write_text(json.dumps(running))
    services = {"sim": {"pid": 1, "restarts": 0}}
    episode = {"state": "exploring", "step": 5, "episode": 7, "scene": "s", "method": "cso"}
    exploring = status.status_of("r0", episode, {"run_id": "run1", "state": "running", "services": services}, {}, {"sim"})
    ended = {**episode, "state": episode_state, "step": 9, "terminated_by": "coverage", "pose": [1.0, 2.0, 0.5], "map_origin": [0.5, -1.0, 0.0]}
    over = status.status_of("r0", ended, {"run_id": "run1", "state": "running", "services": services}, {}, {"sim"})

    def results_written() -> dict:  # as the detached launcher does once its results are written: it stays up
        for path in (run_dir / "run.json", runs / "current.json"):
            path.write_text(json.dumps({**running, "state": episode_state, "episode_ended_at": 1.0}))
        return over

    answers = iter([lambda: exploring, lambda: over, results_written, lambda: over, lambda: over])
    queries: list[int] = []

    def answer(connect, robot, timeout_s=0.6, zenoh_config_file=None):
        queries.append(1)
        return next(answers)()

    monkeypatch.setattr(status, "query_status", answer)
    monkeypatch.setattr(status.time, "sleep", lambda s: None)
    code = status.status_main([], None, as_json=as_json, watch=True, runs_dir=runs, period_s=0.1, console=Console(file=io.StringIO(), force_terminal=False, width=100))
    said = capsys.readouterr().out
    assert code == exit_code and len(queries) == 3, said
    ended = f"run run1's episode has ended: {episode_state} (coverage) at step 9, the robot at x 1.50 m  y 1.00 m  yaw 0.50 rad (map frame)"  # as status's table
    stays = f"the run stays up (for status) until `cso-runtime down --runs-dir {runs}`"  # its folder's down, not ./runs'
    if as_json:
        last = json.loads(said.splitlines()[-1])
        assert (last["state"], last["exit_code"], last["run_dir"], last["terminated_by"], last["step"]) == (episode_state, exit_code, str(run_dir), "coverage", 9)
        assert last["pose"] == [1.5, 1.0, 0.5]
        assert last["reason"].startswith(ended) and stays in last["reason"], last
        return
    assert said.startswith(ended) and stays in said and (f"results in {run_dir}/: report.html" in said) == (episode_state == "done"), said


def _ended_detached_limo_run(tmp_path: Path, summary: dict) -> tuple[Path, Path]:
    """A detached limo-ros2 run whose episode has ended, its launcher this process: its ``run.json``, the runs folder's
    ``current.json`` and its results' ``summary.json``; (runs folder, run folder)."""
    from cso_runtime.supervision import process_start_ticks

    runs = tmp_path / "runs"
    run_dir = runs / "20261207-103211-limo-ros2-r0"
    run_dir.mkdir(parents=True)
    ended = {"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [loopback_endpoint(7447)], "launcher_pid": os.getpid(),
             "launcher_start_ticks": process_start_ticks(os.getpid()), "state": "done", "detached": True, "episode_ended_at": 1.0}
    for path in (run_dir / "run.json", runs / "current.json"):
        path.write_text(json.dumps(ended))
    (run_dir / "summary.json").write_text(json.dumps(summary))
    return runs, run_dir


@pytest.mark.parametrize("as_json", [False, True])
def test_status_watch_says_the_step_a_real_robots_episode_ended_at(tmp_path, monkeypatch, capsys, as_json):
    """On a real robot (``limo-ros2``) the bridge's steps go on counting the robot's scans after the episode's end, so
    ``status --watch`` ended with "episode has ended: done (no_frontier) at step 202" for an episode whose result, the
    bridge's log and ``episodes.csv`` say ended at step 188. It says the episode's own step, from its results."""
    from rich.console import Console

    from cso_runtime import status

    runs, _ = _ended_detached_limo_run(tmp_path, {"methods": {"cso": {"steps": 188.0, "terminated_by": {"no_frontier": 1}}}})
    episode = {"state": "done", "step": 202, "episode": 7, "scene": "ros2:limo1", "method": "cso", "terminated_by": "no_frontier"}
    over = status.status_of("r0", episode, {"run_id": "run1", "state": "running", "services": {"ros2_bridge": {"pid": 1, "restarts": 0}}}, {}, {"ros2_bridge"})
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: over)
    monkeypatch.setattr(status.time, "sleep", lambda s: None)
    code = status.status_main([], None, as_json=as_json, watch=True, runs_dir=runs, period_s=0.1, console=Console(file=io.StringIO(), force_terminal=False, width=100))
    last = capsys.readouterr().out.splitlines()[-1]
    assert code == 0
    said = json.loads(last)["reason"] if as_json else last
    assert said.startswith("run run1's episode has ended: done (no_frontier) at step 188; "), said
    if as_json:
        assert json.loads(last)["step"] == 188


def test_status_of_a_real_robots_ended_episode_says_the_step_it_ended_at(tmp_path, monkeypatch, capsys):
    """After a LIMO's episode ended, ``status`` said "done (no_frontier)" beside "step 816" (the bridge's steps go on with
    the robot's scans) for an episode of 188 steps: the step row says both, and ``--json`` has ``ended_at_step``."""
    from rich.console import Console

    from cso_runtime import status

    runs, _ = _ended_detached_limo_run(tmp_path, {"methods": {"cso": {"steps": 188.0}}})
    episode = {"state": "done", "step": 816, "episode": 7, "scene": "ros2:limo1", "method": "cso", "terminated_by": "no_frontier", "explored_area_m2": 18.8}
    launcher = {"run_id": "run1", "state": "running", "services": {"ros2_bridge": {"pid": 1, "restarts": 0}}}
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: status.status_of("r0", episode, launcher, {}, {"ros2_bridge"}))
    out = io.StringIO()
    assert status.status_main([], None, as_json=False, watch=False, runs_dir=runs, console=Console(file=out, force_terminal=False, width=120)) == 0
    assert re.search(r"│ step +│ 816 \(scans; the episode ended at step 188\)", out.getvalue()), out.getvalue()
    assert re.search(r"│ explored +│ 18\.80 m2, 0\.100 m2/step", out.getvalue()), out.getvalue()  # the episode's m2/step
    assert status.status_main([], None, as_json=True, watch=False, runs_dir=runs) == 0
    assert json.loads(capsys.readouterr().out)["ended_at_step"] == 188


def test_status_of_a_real_robots_later_episode_does_not_take_the_first_ones_end_step(tmp_path, monkeypatch, capsys):
    """A run writes the results of its first episode only; a LIMO whose driver restarted after that end starts another
    episode, which may end too. ``status`` then said "the episode ended at step 188" (and m2/step over 188) of that
    second episode, from the first one's summary.json, and ``status --watch`` ended with the same step: the results say
    which episode they are of (``meta.episode``), and another episode's end is not read from them."""
    from rich.console import Console

    from cso_runtime import status

    runs, run_dir = _ended_detached_limo_run(tmp_path, {"methods": {"cso": {"steps": 188.0}}, "meta": {"episode": 7}})
    launcher = {"run_id": "run1", "state": "running", "services": {"ros2_bridge": {"pid": 1, "restarts": 0}}}
    for episode_id, said in ((7, 188), (9, None)):
        episode = {"state": "done", "step": 816, "episode": episode_id, "scene": "ros2:limo1", "method": "cso", "terminated_by": "no_frontier", "explored_area_m2": 40.8}
        answer = status.status_of("r0", episode, launcher, {}, {"ros2_bridge"})
        monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None, answer=answer: answer)
        assert status.status_main([], None, as_json=True, watch=False, runs_dir=runs) == 0
        assert json.loads(capsys.readouterr().out)["ended_at_step"] == said, episode_id
        out = io.StringIO()
        assert status.status_main([], None, as_json=False, watch=False, runs_dir=runs, console=Console(file=out, force_terminal=False, width=120)) == 0
        if said is None:
            assert re.search(r"│ step +│ 816 +│", out.getvalue()) and "m2, 0.050 m2/step" in out.getvalue(), out.getvalue()
        else:
            assert "816 (scans; the episode ended at step 188)" in out.getvalue() and "m2, 0.217 m2/step" in out.getvalue(), out.getvalue()
        assert status.episode_end_step(run_dir, answer) == (816 if said is None else 188)


def test_ups_summary_says_which_episode_its_results_are_of(tmp_path):
    """``meta.episode``: the id of the episode whose results the run folder holds (``status --json``'s ``episode``), so
    that a later episode of the same run (a robot's driver restarted after the end) is not read as this one."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import EpisodeStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.ended_status = EpisodeStatusMsg(state="done", step=10, scene="s", method="greedy-dist", episode=0x2A2A2A2A2A2A)
    launcher.write_outputs(_fake_result())
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["meta"]["episode"] == 0x2A2A2A2A2A2A


def test_status_watch_ends_by_saying_that_the_watched_runs_launcher_was_killed(tmp_path, monkeypatch, capsys):
    """``status --watch`` of a run whose launcher was then SIGKILLed ended with "nothing running (no answer for robot r0
    at tcp/...)", where ``status`` says at once that the launcher has exited and how to clear the run: it says so too."""
    from cso_runtime import status

    runs = tmp_path / "runs"
    runs.mkdir()
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (runs / "current.json").write_text(json.dumps({"run_id": "run1", "robot": "r0", "endpoints": [loopback_endpoint(7447)], "launcher_pid": launcher.pid}))
        exploring = status.status_of("r0", {"state": "exploring", "step": 5, "episode": 7}, {"run_id": "run1", "services": {}}, {}, set())

        def killed() -> None:
            launcher.kill()
            launcher.wait(10)

        answers = iter([lambda: exploring, killed])
        monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: next(answers)())
        monkeypatch.setattr(status.time, "sleep", lambda s: None)
        code = status.status_main([], None, as_json=True, watch=True, runs_dir=runs, period_s=0.1)
    finally:
        launcher.kill()
        launcher.wait(10)
    last = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert code == 1 and last["state"] == "not running", last
    assert last["reason"].endswith(f"; run run1's launcher, pid {launcher.pid}, has exited; `cso-runtime down --runs-dir {runs}` clears {runs / 'current.json'})"), last


def test_a_run_folder_deleted_mid_run_is_made_again_with_the_logs_still_written_copied_back(tmp_path, caplog):
    """``rm -rf runs/RUN`` while the run ran: the launcher and its services went on writing their logs into files with
    no name, lost at their close, and nothing said so (run.json, ``status``, ``logs`` all silent). The launcher's next
    round now makes the folder again (run.json, profile.yaml, logs/), copies back every log its processes still write
    (lines from before the deletion too) and keeps the copies up to date; it says so in its log (stderr) and status."""
    import logging
    import shutil

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.status import render_table, status_of
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    run_dir = tmp_path / "runs" / "run1"
    launcher = Launcher(profile, data, run_dir)
    go = tmp_path / "go"  # outside the run folder
    writes = f"import os, time\nprint('before', flush=True)\nwhile not os.path.exists({str(go)!r}):\n    time.sleep(0.01)\nprint('after', flush=True)\ntime.sleep(60)"
    child = Child("mapper", [sys.executable, "-c", writes], run_dir / "logs" / "mapper.log")
    launcher.children = [child]
    (run_dir / "logs").mkdir(parents=True)
    own_log = logging.FileHandler(run_dir / "logs" / "launcher.log")  # as run_foreground's
    launcher_log = logging.getLogger("cso.launcher")
    launcher_log.addHandler(own_log)
    caplog.set_level(logging.INFO, logger="cso.launcher")
    try:
        launcher.write_run_file("running")
        child.spawn()
        wait_for(lambda: "before" in child.log_path.read_text(), 30, "the service's first line")
        launcher_log.info("a line before the deletion")
        launcher.tend_run_folder()  # nothing gone: nothing said
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR] and launcher.run_folder.losses == 0
        shutil.rmtree(run_dir)
        launcher.tend_run_folder()
        assert json.loads((run_dir / "run.json").read_text())["run_dir_lost"] == 1 and (run_dir / "profile.yaml").is_file()
        assert child.log_path.read_text() == "before\n"  # copied back from the nameless file the service writes
        (error,) = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert error.startswith(f"the run folder {run_dir} (or its logs/) was deleted while the run ran: made it again") and "2 files" in error, error
        assert "logs/launcher.log, logs/mapper.log" in error, error
        go.touch()
        launcher_log.info("a line after it")
        wait_for(lambda: (launcher.tend_run_folder(), child.log_path.read_text())[1] == "before\nafter\n", 30, "the service's later line copied")
        launcher.tend_run_folder()
        assert "a line before the deletion\n" in (kept := (run_dir / "logs" / "launcher.log").read_text()) and kept.endswith("a line after it\n"), kept
        status = launcher.launcher_status()
        assert LauncherStatusMsg.from_body(status.body()).run_dir_lost == 1
        shown = status_of("r0", None, status.to_dict(), {}, set())
        assert shown["run_dir_lost"] == 1
        console = Console(width=200, record=True)
        console.print(render_table(shown))
        assert "its run folder was deleted 1 time(s) while it ran: made again (see launcher.log)" in console.export_text()
        assert len([r for r in caplog.records if r.levelno >= logging.ERROR]) == 1  # said once
    finally:
        launcher_log.removeHandler(own_log)
        own_log.close()
        if child.alive:
            child.proc.kill()
            child.proc.wait(10)
        launcher.run_folder.close()


def test_a_run_folder_deleted_before_a_service_read_its_profile_is_made_again_and_the_service_restarted(tmp_path, caplog):
    """``rm -rf runs/RUN`` in a run's first second, before its services had read ``profile.yaml``: each service's start
    made ``logs/`` again (its log file), so the launcher took the folder for there, never wrote ``profile.yaml`` again,
    and every service refused its configuration (``config file not found``, exit code 2, not restarted): the run
    stopped (exit code 1) on a confusing "refused its configuration". The folder is made again once its profile.yaml
    is gone, and a service that refused its configuration after the folder was made again since its start is restarted:
    the run goes on as for a folder deleted later."""
    import logging
    import shutil

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {})
    run_dir = tmp_path / "runs" / "run1"
    launcher = Launcher(profile, data, run_dir)
    (run_dir / "logs").mkdir(parents=True)
    launcher.profile_path.write_text(yaml.safe_dump(data))
    launcher.run_folder.expect(launcher.profile_path)  # as ``run`` does
    reads = f"import pathlib, sys\nif not pathlib.Path({str(launcher.profile_path)!r}).is_file():\n    print('ERROR config file not found', flush=True)\n    sys.exit(2)\nprint('read it', flush=True)\nimport time; time.sleep(60)"
    child = Child("mapper", [sys.executable, "-c", reads], run_dir / "logs" / "mapper.log")
    launcher.children = [child]
    caplog.set_level(logging.INFO, logger="cso.launcher")
    try:
        shutil.rmtree(run_dir)
        child.spawn()  # makes logs/ again, and finds no profile.yaml
        child.proc.wait(timeout=30)
        assert (run_dir / "logs").is_dir() and not launcher.profile_path.exists()
        launcher.supervise()
        assert not child.gave_up and child.restart_at is not None and child.exit_codes == [2], caplog.text
        launcher.tend_run_folder()  # the run loop's next round, before the restart
        assert launcher.profile_path.is_file() and launcher.run_folder.losses == 1
        launcher.supervise(child.restart_at)
        assert child.restarts == 1
        wait_for(lambda: "read it" in child.log_path.read_text() or not child.alive, 30, "the service to read its profile")
        assert child.alive
        launcher.tend_run_folder()  # nothing gone again
        assert launcher.run_folder.losses == 1
        # A refusal of a folder's own profile.yaml (none lost since it started) is still not restarted.
        child.proc.kill()
        child.proc.wait(timeout=30)
        child.argv = [sys.executable, "-c", "raise SystemExit(2)"]
        child.spawn()
        child.proc.wait(timeout=30)
        launcher.supervise()
        assert child.gave_up, caplog.text
    finally:
        if child.alive:
            child.proc.kill()
            child.proc.wait(10)
        launcher.run_folder.close()


DELETE_THE_RUN_FOLDER_AS_THE_LAUNCHER_STARTS = """
import shutil, subprocess, sys
from pathlib import Path
real = subprocess.Popen

def popen(argv, *args, **kwargs):  # `rm -rf runs/RUN` right as `up --detach` has started its launcher
    proc = real(argv, *args, **kwargs)
    if "cso_runtime.launcher" in argv:
        subprocess.Popen = real
        run_dir = Path(argv[argv.index("--run-dir") + 1])
        Path(sys.argv[1]).write_text(str(proc.pid))  # for the test to clean up
        shutil.rmtree(run_dir)
    return proc

subprocess.Popen = popen
from cso_runtime.cli import main
sys.argv = ["cso-runtime", *sys.argv[2:]]
main()
"""


def test_a_run_folder_deleted_as_a_detached_launcher_starts_is_made_again_and_the_run_goes_on(tmp_path):
    """``rm -rf runs/RUN`` in the second ``up --detach`` takes to start its launcher: the launcher read its profile from
    the folder (``profile.requested.yaml``) and refused to start (config file not found), and ``up`` died with a
    FileNotFoundError traceback reading the launcher's log there. The launcher gets its profile on its stdin, finds
    its own log without a name as it starts, makes the folder again with that log copied back, and the run goes on
    as for a folder deleted later."""
    runs = tmp_path / "runs"
    argv = ["up", "--profile", str(write_profile(tmp_path)), "--detach", "--set", "exploration.episode.max_steps=8", "--runs-dir", str(runs)]
    launcher_pid: list[int] = []
    try:
        r = subprocess.run(
            [sys.executable, "-c", DELETE_THE_RUN_FOLDER_AS_THE_LAUNCHER_STARTS, str(tmp_path / "pid"), *argv],
            cwd=tmp_path, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        said = r.stdout + r.stderr
        if (tmp_path / "pid").exists():
            launcher_pid.append(int((tmp_path / "pid").read_text()))
        assert r.returncode == 0 and "started" in said and "Traceback" not in said, said[-3000:]
        current = json.loads((runs / "current.json").read_text())
        run_dir = Path(current["run_dir"])
        final = wait_for(lambda: (s := query_status(current["endpoints"], current["robot"], timeout_s=0.5)) and s["state"] in EPISODE_OVER and s, 60, "the episode's end")
        assert (final["state"], final["step"]) == ("done", 8), final
        assert json.loads((run_dir / "run.json").read_text())["run_dir_lost"] == 1
        log_text = (run_dir / "logs" / "launcher.log").read_text()
        assert "was deleted while the run ran: made it again" in log_text and "logs/launcher.log" in log_text, log_text[-3000:]
        wait_for(lambda: "episode_ended_at" in json.loads((run_dir / "run.json").read_text()), 30, "the episode's results")
        assert (run_dir / "profile.yaml").is_file() and (run_dir / "summary.json").is_file()
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        kill_leftovers(runs, extra=launcher_pid)


def starting_run_files(runs: Path, launcher_pid: int) -> tuple[Path, dict]:
    """A run folder and the run file ``up`` writes first (state ``starting``, no endpoints), as current run of ``runs``."""
    run_dir = runs / "20261206-120000-lockstep-r0"
    run_dir.mkdir(parents=True)
    starting = {"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [], "launcher_pid": launcher_pid, "state": "starting", "services": {}}
    for path in (run_dir / "run.json", runs / "current.json"):
        path.write_text(json.dumps(starting))
    return run_dir, starting


def test_status_watch_waits_for_a_starting_run_to_come_up_and_then_follows_it(tmp_path, monkeypatch, capsys):
    """``up --detach`` then ``status --watch``: the run file said ``starting`` (no endpoints yet) and ``status --watch``
    exited 1 at once ("ask again in a moment"). It waits, saying so once, and follows the run once its router is open."""
    from cso_runtime import status

    runs = tmp_path / "runs"
    run_dir, starting = starting_run_files(runs, os.getpid())
    running = {**starting, "endpoints": [loopback_endpoint(7447)], "state": "running"}
    periods = iter([lambda: None, lambda: (runs / "current.json").write_text(json.dumps(running))])
    monkeypatch.setattr(status.time, "sleep", lambda s: next(periods)() if s == 0.1 else None)
    exploring = status.status_of("r0", {"state": "exploring", "step": 5, "episode": 7}, {"run_id": "run1", "services": {}}, {}, set())

    def launcher_ends() -> None:
        (run_dir / "run.json").write_text(json.dumps({**running, "state": "stopped", "outcome": "interrupted", "exit_code": 130}))
        (runs / "current.json").unlink()

    answers = iter([lambda: exploring, launcher_ends])
    asked: list[list[str]] = []
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: (asked.append(connect), next(answers)())[1])
    monkeypatch.setattr(status, "watched_run_dir", lambda st, runs_dir: run_dir)
    code = status.status_main([], None, as_json=True, watch=True, runs_dir=runs, period_s=0.1)
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert code == 130 and asked == [[loopback_endpoint(7447)]] * 2, (code, asked)
    waiting = "run run1 (robot r0) is starting: its router is not open yet; waiting for it..."
    assert lines[:2] == [{"state": "starting", "run_id": "run1", "reason": waiting}] * 2, lines  # --json: one line a period
    assert [line["state"] for line in lines[2:]] == ["exploring", "not running"] and lines[-1]["outcome"] == "interrupted", lines


@pytest.mark.parametrize("as_json", [False, True])
def test_status_watch_of_a_starting_run_ends_when_its_launcher_dies_or_its_start_fails(tmp_path, monkeypatch, capsys, as_json):
    """``status --watch`` waiting for a starting run never waits silently for ever: a launcher killed while starting
    (its run file left, no endpoints) ends it as ``status`` says it (``status`` itself said "no current run"), and a
    start that failed (the run file gone, run.json stopped) with how the run ended and its exit code."""
    from cso_runtime import status

    runs = tmp_path / "runs"
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        starting_run_files(runs, launcher.pid)

        def killed() -> None:
            launcher.kill()
            launcher.wait(10)

        monkeypatch.setattr(status.time, "sleep", lambda s: killed() if s == 0.1 else None)
        code = status.status_main([], None, as_json=as_json, watch=True, runs_dir=runs, period_s=0.1)
    finally:
        launcher.kill()
        launcher.wait(10)
    said = capsys.readouterr().out.splitlines()
    gone = f"run run1's launcher, pid {launcher.pid}, has exited; `cso-runtime down --runs-dir {runs}` clears {runs / 'current.json'}"
    assert code == 1 and len(said) == 2 and (json.loads(said[-1])["reason"] if as_json else said[-1]) == f"nothing running ({gone})", said
    assert status.status_main([], None, as_json=False, watch=False, runs_dir=runs) == 1 and capsys.readouterr().out == f"nothing running ({gone})\n"

    for pointer_left in (False, True):  # as Launcher.stop_before_start does: both files say it stopped, then current.json goes
        runs = tmp_path / f"runs-{pointer_left}"
        run_dir, starting = starting_run_files(runs, os.getpid())

        def start_failed(runs: Path = runs, run_dir: Path = run_dir, starting: dict = starting, pointer_left: bool = pointer_left) -> None:
            stopped = json.dumps({**starting, "state": "stopped", "outcome": "failed", "exit_code": 3})
            for path in (run_dir / "run.json", runs / "current.json"):
                path.write_text(stopped)
            if not pointer_left:
                (runs / "current.json").unlink()

        monkeypatch.setattr(status.time, "sleep", lambda s, start_failed=start_failed: start_failed() if s == 0.1 else None)
        code = status.status_main([], None, as_json=as_json, watch=True, runs_dir=runs, period_s=0.1)
        said = capsys.readouterr().out.splitlines()
        assert code == 3 and len(said) == 2, said
        if as_json:
            assert (json.loads(said[-1])["outcome"], json.loads(said[-1])["exit_code"]) == ("failed", 3), said
        else:
            assert said[-1] == f"run run1 ended: failed, exit code 3; its folder: {run_dir}/ (the logs in {run_dir / 'logs'}/)", said


def test_down_after_a_dead_launcher_writes_how_its_run_ended_before_it_clears_the_current_run_file(tmp_path, monkeypatch):
    """``down`` of a run whose launcher died removed the current-run file and only then wrote in run.json that the run
    ended: ``status --watch`` waiting on that starting run, finding no current-run file in between, read run.json still
    "starting" and ended with "nothing running (no current run ...)" instead of how the run ended. run.json says it
    first, as the launcher's own end does (``Launcher.stop_before_start``)."""
    from cso_runtime import current_run

    runs = tmp_path / "runs"
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    launcher.kill()
    launcher.wait(timeout=30)
    run_dir, _ = starting_run_files(runs, launcher.pid)
    record = current_run.record_launcher_died
    pointer_there: list[bool] = []
    monkeypatch.setattr(current_run, "record_launcher_died", lambda info: (pointer_there.append((runs / "current.json").exists()), record(info))[1])
    stopped, said = current_run.down(runs, timeout_s=0.0)
    assert stopped and "had already exited" in said and pointer_there == [True], (said, pointer_there)
    assert not (runs / "current.json").exists() and json.loads((run_dir / "run.json").read_text())["state"] == "stopped"


def test_status_watch_of_a_run_stopped_before_its_episode_ended_says_where_its_map_so_far_is(tmp_path, capsys):
    """``status --watch`` of a run stopped by ``down`` (or Ctrl-C) ended with "its folder: RUN/ (the logs in ...)" and
    nothing of the one result such a run keeps, its map so far (``up``'s own last line names it): it names it now,
    where the run kept one."""
    from cso_runtime import status
    from cso_runtime.launcher import LAST_MAP

    run_dir = tmp_path / "runs" / "run1"
    run_dir.mkdir(parents=True)
    run = {"run_id": "run1", "state": "stopped", "outcome": "interrupted", "exit_code": 130}
    assert status.say_run_ended(run, run_dir, {"state": "exploring", "step": 40}, as_json=False) == 130
    assert capsys.readouterr().out == f"run run1 ended: interrupted, exit code 130; its folder: {run_dir}/ (the logs in {run_dir / 'logs'}/)\n"
    (run_dir / LAST_MAP).write_text("image: last_map.png\n")
    assert status.say_run_ended(run, run_dir, {"state": "exploring", "step": 40}, as_json=False) == 130
    said = capsys.readouterr().out
    assert said.endswith(f"(the logs in {run_dir / 'logs'}/); the episode's map so far: {run_dir / LAST_MAP}\n"), said


def test_status_tables_wrap_on_a_narrow_terminal_rather_than_cut_with_an_ellipsis():
    from rich.console import Console

    from cso_runtime import status

    st = status.status_of("r0", {"state": "failed", "reason": "the planner gave up: /very/long/path/to/runs/20261206-062256-sim-r0/logs"},
                          None, {}, set())
    console = Console(width=40, record=True)
    console.print(status.render_table(st))
    text = console.export_text()
    assert "…" not in text and "20261206-062256-sim-r0" in "".join(line.split("│")[2].strip() for line in text.splitlines() if line.count("│") == 3)


def test_status_reads_the_run_file_once_so_its_endpoints_and_launcher_are_of_one_run(tmp_path, monkeypatch):
    """A new run may replace runs/current.json between two reads: status then asked the old run's router
    and judged the new run's launcher. One read gives both from one run (here: a live launcher's)."""
    from cso_runtime import current_run, status

    exited = subprocess.Popen([sys.executable, "-c", "pass"])
    exited.wait(timeout=30)
    files = iter([
        {"run_id": "live", "robot": "r3", "launcher_pid": os.getpid(), "endpoints": ["tcp/127.0.0.1:7001"]},
        {"run_id": "gone", "robot": "r0", "launcher_pid": exited.pid, "endpoints": ["tcp/127.0.0.1:7002"]},
    ])
    reads = []
    monkeypatch.setattr(current_run, "read_current_run", lambda runs_dir: reads.append(runs_dir) or next(files))
    assert status.reachable_target([], None, tmp_path) == (["tcp/127.0.0.1:7001"], "r3", None)
    assert len(reads) == 1


def test_a_status_with_no_episode_heard_places_the_scene_at_the_map_frames_origin():
    """No episode status (the launcher's last-heard one carries no ``map_origin``): the map frame's own origin, as an
    episode status of a Dungeon or generated plan says it."""
    none_heard = status_of("r0", None, None, {}, set())
    assert none_heard["map_origin"] == EpisodeStatusMsg("exploring", 1).to_dict()["map_origin"] == [0.0, 0.0, 0.0]
    assert none_heard["goal"] is None


def test_status_shows_the_robots_pose_in_the_map_frame_as_the_goal_and_none_before_odometry():
    """The episode status's ``pose`` is in the scene's own frame (its odometry's); ``status`` (text and ``--json``,
    a new key ``pose`` beside ``goal``) shows it in the user's map frame, a map_server scene's ``origin`` applied as to
    the goal (REP-103: x, y in metres, yaw in radians within +-pi), with its twist; "-" and null before any odometry,
    and for a status the launcher last heard (it carries none)."""
    from rich.console import Console

    from cso_runtime.geometry import VelocityCommand

    origin = Pose2D(-3.5, 2.0, math.pi / 2)
    msg = EpisodeStatusMsg("exploring", 5, goal_xy_m=[1.0, 0.0], episode=3, map_origin=origin, pose=Pose2D(1.0, 0.0, 3.0), twist=VelocityCommand(0.25, -0.1))
    status = json.loads(json.dumps(status_of("r0", decode(encode(msg), EpisodeStatusMsg).to_dict(), None, {}, set())))
    assert status["goal"] == pytest.approx([-3.5, 3.0])  # the goal's frame
    assert status["pose"] == pytest.approx([-3.5, 3.0, 3.0 + math.pi / 2 - 2 * math.pi]) and status["twist"] == [0.25, -0.1]
    console = Console(record=True, width=160)
    console.print(render_table(status))
    assert re.search(r"│ pose +│ x -3\.50 m  y 3\.00 m  yaw -1\.71 rad, 0\.25 m/s -0\.10 rad/s +│", console.export_text()), console.export_text()
    from cso_runtime.live_view import progress_line  # up's log line every 10 s (no live view): the same pose

    assert ", pose x -3.50 m  y 3.00 m  yaw -1.71 rad, 0.25 m/s -0.10 rad/s, 0 decisions, goal (-3.50, 3.00) m" in progress_line(msg, 0.25)
    assert ", pose -, 0 decisions, goal none" in progress_line(EpisodeStatusMsg("starting", 0), 0.25)
    for unknown in (EpisodeStatusMsg("starting", 0).to_dict(), None):  # no odometry yet; nothing heard from the sim
        status = status_of("r0", unknown, None, {}, set())
        assert status["pose"] is None and status["twist"] is None
        console = Console(record=True, width=160)
        console.print(render_table(status))
        assert re.search(r"│ pose +│ - +│", console.export_text()), console.export_text()


def test_reading_the_run_file_passes_its_zenoh_config_on_and_leaves_the_environment_alone(tmp_path, monkeypatch, capsys):
    """A run of ``up --zenoh-config`` names its config file in runs/current.json; reading that file set
    $CSO_ZENOH_CONFIG in the reading process, for every later session of it. The file now goes, explicitly, to the
    sessions of the run's status and map (a config given to this process still comes first), and the environment
    stays as it was."""
    from cso_runtime import status
    from cso_runtime.current_run import read_current_run

    monkeypatch.setenv(ZENOH_CONFIG_ENV, "")  # recorded, so that the teardown removes what a read may have set
    monkeypatch.delenv(ZENOH_CONFIG_ENV)
    runs = tmp_path / "runs"
    runs.mkdir()
    missing = str(tmp_path / "gone.json5")  # a config Zenoh cannot load: status says so and asks no one
    run = {"run_id": "tls", "robot": "r2", "launcher_pid": os.getpid(), "endpoints": ["tls/127.0.0.1:7001"], "zenoh_config": missing}
    (runs / "current.json").write_text(json.dumps(run))
    assert status.endpoints_of_run(read_current_run(runs)) == (["tls/127.0.0.1:7001"], "r2", missing)
    assert status.reachable_target([], None, runs) == 2 and "gone.json5" in capsys.readouterr().err
    assert ZENOH_CONFIG_ENV not in os.environ
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import EXIT_NO_ZENOH

    # The run's file refused before a session is opened: a bad config (exit 2), as status says it above, not "no Zenoh
    # session" (exit 3, once the session failed to open), nor the recordings folder made first.
    r = CliRunner().invoke(app, ["record", "--out", str(tmp_path / "r.mcap"), "--runs-dir", str(runs)])
    assert r.exit_code == 2 != EXIT_NO_ZENOH and "gone.json5" in r.output and ZENOH_CONFIG_ENV not in os.environ, r.output
    assert not (tmp_path / "r.mcap").exists()
    config = tmp_path / "run.json5"
    config.write_text("{}")
    (runs / "current.json").write_text(json.dumps({**run, "zenoh_config": str(config)}))
    asked = []
    monkeypatch.setattr(status, "query_status", lambda connect, robot, timeout_s=0.6, zenoh_config_file=None: asked.append(zenoh_config_file))
    assert status.status_main([], None, as_json=True, watch=False, runs_dir=runs) == 1  # no answer (from this stand-in)
    assert asked == [str(config)] and ZENOH_CONFIG_ENV not in os.environ
    given = str(tmp_path / "given.json5")
    monkeypatch.setenv(ZENOH_CONFIG_ENV, given)  # --zenoh-config or $CSO_ZENOH_CONFIG: this process's sessions use it
    assert status.endpoints_of_run(read_current_run(runs)).zenoh_config_file is None and os.environ[ZENOH_CONFIG_ENV] == given


@pytest.mark.parametrize("content", ["[]", '{"run_id": "x", "launcher_pid": "abc"}', '{"run_id": "x", "services": {"sim": {"pid": "1"}}}', "{bad"])
def test_a_run_file_that_is_not_one_is_ignored_with_a_warning_not_a_traceback(tmp_path, content):
    """A half-written or hand-edited runs/current.json: status, down and logs say they ignore it and why,
    then answer as with none (exit 1), never a traceback."""
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "current.json").write_text(content)
    for command in ("status", "down", "logs"):
        r = cli(command, "--runs-dir", str(runs), cwd=tmp_path, timeout_s=10)
        said = r.stdout + r.stderr
        assert r.returncode == 1 and "ignoring" in said and "current.json" in said and "Traceback" not in said, (command, said)


@pytest.mark.parametrize("robot", ["a/b", "*", "r0/**"])
def test_status_and_save_map_refuse_a_robot_id_that_is_not_one_robot(robot, tmp_path, capsys):
    """A wildcard or a slash in --robot would ask a key expression of several robots (or none): a usage error
    before any session opens, not "nothing running" or a traceback from the key's check."""
    endpoint = [loopback_endpoint(free_tcp_port())]
    assert status_main(endpoint, robot, as_json=True, watch=False, runs_dir=tmp_path) == 2
    assert save_map_main(endpoint, robot, tmp_path / "m", "pgm", runs_dir=tmp_path) == 2
    err = capsys.readouterr().err
    assert err.count(f"--robot: robot id {robot!r} must be") == 2
    assert not (tmp_path / "m.yaml").exists()


@pytest.mark.parametrize("scene, method", [(SCENE, "greedy-dist"), ("generated:middle:1:0", "greedy-dist"), (SCENE, "cso")])
def test_up_in_lockstep_matches_the_in_process_episode(tmp_path, scene, method):
    """Foreground ``up``: the same steps and coverage as ``run_episode`` on the same scene and seed. The
    middle scene's decision messages carry arrays large enough to be compressed (clusters' cells too).
    With ``cso`` the stuck mask engages on 3 of the 7 decisions of the small scene."""
    profile = write_profile(tmp_path, scene, method)
    runs = tmp_path / "runs"
    # A user's own ``services`` package and ``robot_sim.py`` in the folder ``up`` runs from: the services are
    # still the installed ones (they used to import these and die: "No module named services.sim").
    (tmp_path / "services").mkdir()
    (tmp_path / "services" / "__init__.py").write_text("")
    (tmp_path / "robot_sim.py").write_text("raise ImportError('the user\'s own robot_sim.py')\n")
    try:
        r = cli("up", "--profile", str(profile), "--no-live", "--runs-dir", str(runs), "--animate", cwd=tmp_path, timeout_s=120)
        assert r.returncode == 0, r.stderr[-3000:]
        (run_dir,) = list(runs.glob("*/summary.json"))
        summary = json.loads(run_dir.read_text())
        zenoh_metrics = summary["methods"][method]
        assert summary["meta"]["command"] == "cso-runtime up" and summary["meta"]["version"] == cso_runtime.__version__
        from cso_runtime.config import to_dict
        from cso_runtime.run_profile import load_profile

        ran = load_profile(str(profile), {})[0].exploration_config()
        assert summary["meta"]["config"] == to_dict(ran)  # every exploration parameter, as eval's summary holds them
        # report.html says what made its table, as eval's does: the commit run from a checkout (none from a wheel), the
        # profile, scene, seed, sensor and step limit
        software = summary["meta"]["software"]
        commit = f"commit: {software['git_commit'][:12]}{' (modified)' if software['git_modified'] else ''}, " if "git_commit" in software else ""
        assert summary["meta"]["sim"] == "2d"  # as eval's meta says its simulator (episodes.csv's sim)
        settings = f"command: cso-runtime up, version: {cso_runtime.__version__}, {commit}sim: 2d, profile: lockstep, scene: {scene}, seed: 0, lockstep, "
        settings += f"sensor field of view: {ran.sensor.fov_deg:g} degrees, step limit: {ran.episode.max_steps}"
        assert f"<p>{settings}</p>" in (run_dir.parent / "report.html").read_text()
        expected = in_process_result(scene, method)
        assert zenoh_metrics["steps"] == expected.steps
        assert abs(zenoh_metrics["coverage_pct"] - expected.coverage_pct) < 1e-3
        assert zenoh_metrics["terminated_by"] == {expected.terminated_by: 1}
        out = run_dir.parent
        closing = f"episode {expected.terminated_by}: {expected.coverage_pct:.2f}% coverage in {expected.steps} steps; "
        closing += f"{expected.explored_area_m2:.2f} m2 explored, {expected.efficiency_m2_per_step:.4f} m2/step, "
        closing += f"path {zenoh_metrics['path_length_m']:.2f} m, {expected.decisions} decisions; results in {out}"
        assert closing in r.stderr  # the Table 1 row of the run, said when it ends
        # its last line, under the services' stop: where the results are and what to open first, as eval's
        assert r.stderr.rstrip().splitlines()[-1].endswith(f"results in {out}/: report.html (all of it, for a browser), summary.json, episodes.csv, the figures")
        assert (out / "trajectories" / f"{expected.scene}.png").is_file()
        with Image.open(out / "animations" / method / f"{expected.scene}.gif") as gif:  # --animate, from the run's recording
            assert gif.n_frames >= 2 and (out / "recording.mcap").is_file()
        assert f'<img src="animations/{method}/{expected.scene}.gif"' in (out / "report.html").read_text()  # updated with it
        assert (out / "episodes" / method / f"{expected.scene}.npz").is_file()
        grid, geometry = load_map(out / "maps" / method / f"{expected.scene}.yaml")  # the mapper's final map
        assert geometry == expected.map_geometry and np.array_equal(grid, expected.map_grid)
        for name in ("sim", "mapper", "frontier", "policy", "planner"):
            assert (out / "logs" / f"{name}.log").is_file()
        assert "INFO cso.launcher: started sim (pid" in (out / "logs" / "launcher.log").read_text()  # as a detached run's
        info = json.loads((out / "run.json").read_text())
        assert info["outcome"] == "done" and 0 < info["ended_at"] - info["started_at"] < 120  # `runs`' took column
        assert "  mapper -->|\"map\"| frontier\n" in (out / "dataflow.md").read_text()
        assert not (runs / "current.json").exists()
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
    finally:
        kill_leftovers(runs)


def test_up_foxglove_serves_the_episode_and_the_episode_is_the_same(tmp_path):
    """``up --foxglove`` in lockstep: the bridge, a sixth process, receives over Zenoh and serves every step
    (read back from its MCAP sink), and the episode does not wait for it: the same steps as in one process."""
    from mcap.reader import make_reader

    profile = write_profile(tmp_path)
    runs, mcap = tmp_path / "runs", tmp_path / "served.mcap"
    try:
        r = cli("up", "--profile", str(profile), "--no-live", "--runs-dir", str(runs), "--foxglove",
                "--set", "services.foxglove_bridge.port=0", "--set", f"services.foxglove_bridge.mcap_path={mcap}", cwd=tmp_path, timeout_s=120)
        assert r.returncode == 0, r.stderr[-3000:]
        assert "Foxglove: open ws://127.0.0.1:<a free port, in logs/foxglove_bridge.log>" in r.stderr
        (summary,) = list(runs.glob("*/summary.json"))
        expected = in_process_result()
        assert json.loads(summary.read_text())["methods"]["greedy-dist"]["steps"] == expected.steps
        log_text = (summary.parent / "logs" / "foxglove_bridge.log").read_text()
        assert re.search(r"Foxglove: open ws://127\.0\.0\.1:\d+ ", log_text), log_text[-2000:]
        with mcap.open("rb") as f:
            topics = [channel.topic for _, channel, _ in make_reader(f).iter_messages()]
        assert topics.count("/scan") == expected.steps + 1  # steps 0..N: every scan the sim sent
        assert topics.count("/cmd_vel") >= expected.steps  # (and the last step's, sent before the sim ends the episode)
        assert "/map" in topics and "/goal_pose" in topics and "/explore/frontiers" in topics
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
    finally:
        kill_leftovers(runs)


def test_a_service_attaches_to_the_current_run_and_a_bridge_started_late_serves_it(tmp_path):
    """``service foxglove_bridge --attach``: the run's profile, router and robot from runs/current.json; the bridge,
    started mid-episode, serves the steps from then on; without a current run, a usage error. The run records
    into a folder given with a trailing slash, and its recording is finished when the episode ends, before `down`."""
    from mcap.reader import make_reader

    from cso_runtime.current_run import current_launcher_alive
    from cso_runtime.recording import RecordingError, recording_contents

    def finished_messages(path: Path) -> int | None:
        """How many messages a finished recording holds; None while it has no summary (or not one chunk yet)."""
        try:
            return recording_contents(path)[1]
        except RecordingError:
            return None

    profile = write_profile(tmp_path, min_step_period_s=0.2)
    runs, mcap = tmp_path / "runs", tmp_path / "late.mcap"
    bridge = None
    try:
        r = cli("service", "foxglove_bridge", "--attach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 2 and f"--attach: no current run in {runs}" in r.stderr, r.stderr
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), "--record-out", f"{tmp_path}/recordings/", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        endpoints = json.loads((runs / "current.json").read_text())["endpoints"]
        wait_for(lambda: (s := query_status(endpoints, "r0", timeout_s=0.5)) and s["step"] >= 2, 60, "the episode to start")
        (recording,) = (tmp_path / "recordings").glob("*.mcap")
        assert recording.name == f"{json.loads((runs / 'current.json').read_text())['run_id']}.mcap"
        log_path = tmp_path / "bridge.log"
        with log_path.open("w") as log_file:
            bridge = subprocess.Popen([sys.executable, "-m", "cso_runtime.cli", "service", "foxglove_bridge", "--attach", "--runs-dir", str(runs),
                                       "--port", "0", "--mcap", str(mcap)], cwd=tmp_path, stdout=log_file, stderr=subprocess.STDOUT)
        wait_for(lambda: "foxglove_bridge: up for robot r0" in log_path.read_text(), 60, "the bridge to join")
        final = wait_for(lambda: (s := query_status(endpoints, "r0", timeout_s=0.5)) and s["state"] in ("done", "failed") and s, 90, "the end of the episode")
        assert final["state"] == "done", final
        bridge.send_signal(signal.SIGINT)
        assert bridge.wait(30) == 0, log_path.read_text()[-2000:]
        with mcap.open("rb") as f:
            topics = [channel.topic for _, channel, _ in make_reader(f).iter_messages()]
        assert 0 < topics.count("/scan") <= final["step"] + 1 and "/map" in topics and "/tf_static" in topics
        # the launcher stays for `status` and `down`, but the recording ended with the episode: a finished file
        recorded = wait_for(lambda: finished_messages(recording), 30, "the recording to be finished")
        assert recorded > final["step"] and current_launcher_alive(json.loads((runs / "current.json").read_text()))
        assert cli("down", "--runs-dir", str(runs), cwd=tmp_path).returncode == 0
        assert finished_messages(recording) == recorded  # nothing written after the episode
    finally:
        if bridge is not None and bridge.poll() is None:
            bridge.kill()
        kill_leftovers(runs)


def test_up_with_a_zenoh_config_file_zenoh_refuses_says_so_and_starts_nothing(tmp_path, monkeypatch):
    """A missing file, one not JSON5 and one with a key Zenoh does not know: one error line, exit 2, no run (usage
    errors, asked of the app in this process: ``usage_error``)."""
    (tmp_path / "bad.json5").write_text("{ transport: ")
    (tmp_path / "typo.json5").write_text("{ transport: { auth: { usrpwd: { usr: 'cso' } } } }")
    runs = tmp_path / "runs"
    monkeypatch.chdir(tmp_path)
    for name, said in (("missing.json5", "No such file"), ("bad.json5", "expected"), ("typo.json5", "unknown field `usr`")):
        for flags in (["up", "--profile", "lockstep", "--zenoh-config", name], ["--zenoh-config", name, "up", "--profile", "lockstep"]):
            assert said in usage_error(*flags, "--no-live", "--runs-dir", str(runs))
            assert not runs.exists() and ZENOH_CONFIG_ENV not in os.environ


def log_tails(runs: Path, chars: int = 1500) -> str:
    """The end of each log of the runs in ``runs``: what a failed run test shows (a run's folder goes with its tmp_path)."""
    return "".join(f"\n--- {f.parent.parent.name}/{f.name}\n{f.read_text(errors='replace')[-chars:]}" for f in sorted(runs.glob("*/logs/*.log")))


def test_a_run_behind_a_user_password_router_completes_and_a_session_without_them_cannot_join(tmp_path, monkeypatch):
    """``up --zenoh-config FILE`` with Zenoh's user/password authentication: the embedded router asks every
    session for a user in its dictionary, the services (given the same file) answer and the lockstep episode ends;
    a session without the credentials, or with a wrong password, cannot join to publish a forged command or goal."""
    users = tmp_path / "users.txt"
    users.write_text("cso:s3cret\n")
    auth = tmp_path / "zenoh.json5"
    auth.write_text(f'{{ transport: {{ auth: {{ usrpwd: {{ user: "cso", password: "s3cret", dictionary_file: "{users}" }} }} }} }}')
    wrong = tmp_path / "wrong.json5"
    wrong.write_text('{ transport: { auth: { usrpwd: { user: "cso", password: "guess" } } } }')
    profile = write_profile(tmp_path, min_step_period_s=0.1)
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--zenoh-config", str(auth), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        endpoints = json.loads((runs / "current.json").read_text())["endpoints"]
        for credentials in ("", str(wrong)):
            with pytest.raises(TransportError) as err:
                open_session(TransportConfig(mode="client", connect=endpoints, connect_timeout_s=1.0, zenoh_config_file=credentials))
            assert err.value.cause == UNREACHABLE, err.value
        r = cli("status", "--json", "--connect", endpoints[0], cwd=tmp_path, timeout_s=30)  # another run's router: no credentials
        assert r.returncode == 1 and "no answer for robot r0" in r.stdout, r.stdout + r.stderr
        monkeypatch.setenv(ZENOH_CONFIG_ENV, str(auth))  # this test's own status queries, as `--zenoh-config` does
        final = wait_for(
            lambda: (s := query_status(endpoints, "r0", timeout_s=0.5)) and s["state"] in ("done", "failed") and s, 120, "the end of the episode", period_s=0.2
        )
        assert final["state"] == "done" and all(s["alive"] for s in final["services"].values()), (final, log_tails(runs))
        monkeypatch.delenv(ZENOH_CONFIG_ENV)
        for flags in (["--zenoh-config", str(auth)], []):  # given, or the current run's own (its run file names it)
            r = cli(*flags, "status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=30)
            assert r.returncode == 0 and json.loads(r.stdout)["state"] == "done", r.stdout + r.stderr
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        kill_leftovers(runs)


def listening_tcp_ports(pid: int) -> list[int]:
    """The TCP ports (IPv4) process ``pid`` listens on, from /proc (Linux)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):
            if (target := os.readlink(fd)).startswith("socket:["):
                inodes.add(target[8:-1])
    rows = [line.split() for line in Path("/proc/net/tcp").read_text().splitlines()[1:]]
    return sorted(int(row[1].rsplit(":", 1)[1], 16) for row in rows if row[3] == "0A" and row[9] in inodes)  # 0A: LISTEN


def test_a_run_behind_a_mutual_tls_router_completes_and_a_session_without_a_certificate_cannot_join(tmp_path, monkeypatch, tls_config):
    """``up --zenoh-config FILE`` with mutual TLS, one file for every role: the embedded router listens on
    ``tls/127.0.0.1:PORT`` with a certificate signed by a throwaway CA and asks each session for one too; the services
    (given the same file: the CA's certificate, and the certificate as theirs) join it, and each other, over TLS and
    the lockstep episode ends; ``status`` reaches it with the file. A session without the CA, or with the CA but no
    certificate, or over plain TCP, joins neither the router nor any service."""
    settings = json.loads(tls_config.read_text())
    tls = settings["transport"]["link"]["tls"]
    tls.update(enable_mtls=True, connect_certificate=tls["listen_certificate"], connect_private_key=tls["listen_private_key"])
    mtls = tmp_path / "zenoh-mtls.json5"
    mtls.write_text(json.dumps(settings))
    profile = write_profile(tmp_path, min_step_period_s=0.1)
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--zenoh-config", str(mtls), "--set", "router.listen=[tls/127.0.0.1:0]", "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        endpoints = json.loads((runs / "current.json").read_text())["endpoints"]
        assert len(endpoints) == 1 and re.fullmatch(r"tls/127\.0\.0\.1:\d+", endpoints[0]), endpoints
        monkeypatch.setenv(ZENOH_CONFIG_ENV, str(mtls))  # this test's own status queries, as `--zenoh-config` does
        final = wait_for(
            lambda: (s := query_status(endpoints, "r0", timeout_s=0.5)) and s["state"] in ("done", "failed") and s, 120, "the end of the episode", period_s=0.2
        )
        assert final["state"] == "done" and all(s["alive"] for s in final["services"].values()), (final, log_tails(runs))
        monkeypatch.delenv(ZENOH_CONFIG_ENV)
        # the services (peers) listen too, over TLS as their router: with the file a session joins one
        service_pids = [s["pid"] for s in final["services"].values()]
        ports = [port for pid in service_pids for port in listening_tcp_ports(pid)]
        assert len(ports) == len(service_pids), (service_pids, ports)
        with open_session(TransportConfig(mode="client", connect=[f"tls/127.0.0.1:{ports[0]}"], connect_timeout_s=5.0, zenoh_config_file=str(mtls))):
            pass
        router_port = int(endpoints[0].rsplit(":", 1)[1])
        unsafe = [f"{protocol}/127.0.0.1:{port}" for port in [router_port, *ports] for protocol in ("tcp", "tls")]
        for credentials in ("", str(tls_config)):  # no CA to trust the router's certificate; the CA, but no certificate
            with pytest.raises(TransportError) as err:
                open_session(TransportConfig(mode="client", connect=unsafe, connect_timeout_s=1.0, zenoh_config_file=credentials))
            assert err.value.cause == UNREACHABLE, err.value
        r = cli("--zenoh-config", str(mtls), "status", "--json", "--connect", endpoints[0], cwd=tmp_path, timeout_s=30)
        assert r.returncode == 0 and json.loads(r.stdout)["state"] == "done", r.stdout + r.stderr
        r = cli("status", "--json", "--connect", endpoints[0], cwd=tmp_path, timeout_s=30)  # without the file: no CA
        assert r.returncode == 1 and "no answer for robot r0" in r.stdout, r.stdout + r.stderr
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        kill_leftovers(runs)


def test_detached_episode_survives_a_killed_mapper_and_malformed_payloads(tmp_path):
    """``up --detach``; during the episode: malformed payloads on every key, SIGKILL of the mapper;
    ``status --json`` during and after, with the robot's pose, its odometry's; ``save-map`` from the finished run;
    ``down`` leaves no process."""
    from rich.console import Console

    profile = write_profile(tmp_path, min_step_period_s=0.25, lockstep_timeout_s=0.5)  # 36 steps: at least 9 s to do all this
    runs = tmp_path / "runs"
    listening = contextlib.ExitStack()
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        info = json.loads((runs / "current.json").read_text())
        endpoints = info["endpoints"]

        def status() -> dict | None:
            return query_status(endpoints, "r0", timeout_s=0.5)

        # The robot's odometry of each step, as the sim publishes it: what `status` says of where the robot is.
        odometry: dict[int, OdometryMsg] = {}
        listener = listening.enter_context(open_session(TransportConfig(mode="client", connect=endpoints)))
        heard = listener.declare_subscriber(RobotKeys("r0").topic("odom"), lambda sample: odometry.setdefault((m := decode(sample.payload.to_bytes(), OdometryMsg)).step, m))
        listening.callback(heard.undeclare)
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0, r.stdout + r.stderr
        during = json.loads(r.stdout)
        assert during["state"] == "exploring" and all(s["alive"] for s in during["services"].values())
        assert len(during["pose"]) == 3 and len(during["twist"]) == 2, during  # [x_m, y_m, yaw_rad], [linear_mps, angular_radps]
        # Malformed payloads on every key of the robot.
        keys = RobotKeys("r0")
        nan_scan = encode(ScanMsg(1, LaserScan(0.0, 0.1, 0.1, 5.0, np.array([1.0, np.nan], np.float32)), Pose2D(0, 0, 0)))
        with open_session(TransportConfig(mode="client", connect=endpoints)) as session:
            for topic in TOPICS:
                for payload in (b"\x93garbage", nan_scan, b'{"schema": "x"}'):
                    session.put(keys.topic(topic), payload)

        def rejected_topics() -> set[str]:
            s = status()
            if s is None:
                return set()
            counted = {t for svc in s["services"].values() for t, n in (svc.get("rejected") or {}).items() if n > 0}
            return counted | {t for t, n in s["launcher_rejected"].items() if n > 0}

        wait_for(lambda: rejected_topics() >= set(TOPICS), 20, f"rejections counted on every key ({sorted(TOPICS)}); {sorted(set(TOPICS) - rejected_topics())} missing")

        # Kill the mapper mid-episode: the launcher restarts it and the episode still completes.
        s = status()
        assert s is not None and s["state"] == "exploring", s
        mapper_pid = s["services"]["mapper"]["pid"]
        os.kill(mapper_pid, signal.SIGKILL)
        wait_for(lambda: (s := status()) and s["services"]["mapper"].get("restarts", 0) >= 1, 30, "the mapper to be restarted")
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and final["terminated_by"] == "coverage", final
        assert "restored the map of step" in next(runs.glob("*/logs/mapper.log")).read_text()  # the sim's cache/map
        expected = in_process_result()
        assert abs(final["coverage_pct"] - expected.coverage_pct) <= 5.0

        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        after_end = json.loads(r.stdout)
        assert r.returncode == 0 and after_end["state"] == "done"
        # Where the robot stopped: its odometry of the last step (the builtin scene's frame is the map frame), with its twist.
        last = odometry[after_end["step"]]
        assert after_end["map_origin"] == [0.0, 0.0, 0.0] and after_end["pose"] == pytest.approx(last.pose.as_list(), abs=1e-9), (after_end, last)
        assert after_end["twist"] == pytest.approx([last.twist.linear_mps, last.twist.angular_radps], abs=1e-9)
        first = odometry[min(odometry)]
        assert math.hypot(last.pose.x_m - first.pose.x_m, last.pose.y_m - first.pose.y_m) > 0.1  # it moved: not a pose left at 0
        console = Console(record=True, width=160)
        console.print(render_table(after_end))
        x_m, y_m, yaw_rad = last.pose.as_list()
        assert re.search(rf"│ pose +│ x {x_m:.2f} m  y {y_m:.2f} m  yaw {yaw_rad:.2f} rad, ", console.export_text()), console.export_text()
        listening.close()
        # The map, saved from the detached run that still answers once its episode is done.
        r = cli("save-map", "-f", str(tmp_path / "live"), "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0, r.stdout + r.stderr
        grid, geometry = load_map(tmp_path / "live.yaml")  # map_saver_cli's files, read back
        assert (tmp_path / "live.pgm").is_file() and geometry.shape == grid.shape
        assert (grid == 0).any() and (grid == -1).any() and set(np.unique(grid)) <= {-1, 0, 100}
        (tmp_path / "maps").mkdir()  # a folder: map.yaml inside it, as map_saver_cli's default name
        r = cli("save-map", "-f", str(tmp_path / "maps"), "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and (tmp_path / "maps" / "map.yaml").is_file(), r.stdout + r.stderr
        # Somewhere that cannot be written (below a file): one error line, exit 2, for both writers.
        (tmp_path / "a_file").write_text("")
        r = cli("save-map", "-f", str(tmp_path / "a_file" / "m"), "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 2 and "cannot write the map" in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert f"{tmp_path / 'a_file'} is a file, not a folder" in r.stderr, r.stderr
        r = cli("record", "--out", str(tmp_path / "a_file" / "r.mcap"), "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 2 and "--out" in r.stderr and "cannot create the folder" in r.stderr and "Traceback" not in r.stderr, r.stderr

        wait_for(lambda: list(runs.glob("*/summary.json")), 20, "summary.json")
        pids = run_pids(runs)
        assert mapper_pid not in pids  # the restarted mapper replaced it in the run file
        r = cli("runs", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        (listed,) = json.loads(r.stdout)
        assert listed["state"] == "done" and listed["steps"] == final["step"] and listed["restarts"] >= 1, listed  # waits for `down`
        assert listed["duration_s"] > 0, listed  # running: so far
        # `logs -f` of the run whose episode has ended (it stays up for `status`) prints the logs and exits by itself:
        # `up --detach && logs -f` returns.
        follower = subprocess.Popen(
            [*python_module_argv("cso_runtime.cli"), "logs", "--follow", "--runs-dir", str(runs)], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:
            out, err = follower.communicate(timeout=30)
        finally:
            if follower.poll() is None:
                follower.kill()
        assert follower.returncode == 0 and f"episode has ended; the run stays up (for status) until `cso-runtime down --runs-dir {runs}`" in err, err
        assert re.search(r"^mapper +\| .* restored the map of step", out, re.MULTILINE) and re.search(r"^launcher +\| .* episode ", out, re.MULTILINE), out[-3000:]
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        (run_dir,) = (d for d in runs.iterdir() if d.is_dir())
        assert r.returncode == 0 and r.stdout.strip().endswith(f"; results in {run_dir}/: report.html (all of it, for a browser), summary.json, episodes.csv, the figures"), r.stdout + r.stderr
        (after,) = json.loads(cli("runs", "--json", "--runs-dir", str(runs), cwd=tmp_path).stdout)
        (info,) = (json.loads(f.read_text()) for f in runs.glob("*/run.json"))
        assert after["state"] == "done" and info["started_at"] < info["episode_ended_at"] <= info["ended_at"], info
        assert after["duration_s"] == round(info["episode_ended_at"] - info["started_at"], 1)  # not the wait for `down`
        assert [p for p in [*pids, mapper_pid] if pid_alive(p)] == []
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=10)
        assert r.returncode == 1
    finally:
        listening.close()
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


@contextlib.contextmanager
def detached_run(tmp_path: Path, *up_args: str, leave_out: tuple[str, ...] = (), **sim_params: Any) -> Iterator[tuple[Path, Callable[[], dict | None]]]:
    """``up --detach`` of the test profile (``sim_params`` for its sim, without the services in ``leave_out``); yields
    the runs folder and a function that asks the episode's status. ``down`` and a kill of anything left afterwards,
    whatever happened."""
    profile = write_profile(tmp_path, leave_out=leave_out, **sim_params)
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), *up_args, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        current = json.loads((runs / "current.json").read_text())
        yield runs, lambda: query_status(current["endpoints"], current["robot"], timeout_s=0.5)
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def test_up_under_another_robot_id_namespaces_every_key_and_the_tools_follow_it(tmp_path):
    """``up --robot r7``: the episode runs under cso/r7/ only (nothing answers for r0), and ``status`` and
    ``save-map`` find it through the run file without being told the robot."""
    with detached_run(tmp_path, "--robot", "r7", min_step_period_s=0.05) as (runs, status):
        current = json.loads((runs / "current.json").read_text())
        assert current["robot"] == "r7"
        wait_for(lambda: (s := status()) and s["step"] >= 2, 60, "the episode of r7 to run")
        assert query_status(current["endpoints"], "r0", timeout_s=0.5) is None
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and json.loads(r.stdout)["step"] >= 2, r.stdout + r.stderr
        r = cli("save-map", "-f", str(tmp_path / "r7map"), "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and (tmp_path / "r7map.yaml").is_file(), r.stdout + r.stderr
        r = cli("status", "--json", "--robot", "r0", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 1 and json.loads(r.stdout)["state"] == "not running"


def test_status_names_the_policy_a_profile_leaves_out_and_says_the_episode_waits_until_one_serves_it(tmp_path):
    """A profile with no policy (none listed, no ``without:``; its robot is to be served by a shared server) had no
    policy row in ``status`` until some policy answered, while the episode stood at step 0: nothing said what it waited
    for. ``status`` lists it from the start, DOWN, not started by this run, and says the episode waits for it. Step 0
    waits for it too: the sim started without it, re-published step 0 every second (``lockstep_timeouts`` climbing,
    "no cmd_vel (frontier/planner)") with its give-up clock running. A policy that attaches starts the episode, and
    once it is gone the episode waits again."""
    policy = None
    with detached_run(tmp_path, leave_out=("policy",), min_step_period_s=0.25, wait_for_services_s=120) as (runs, status):
        current = json.loads((runs / "current.json").read_text())
        sim_log = Path(current["run_dir"]) / "logs" / "sim.log"
        waits = "the profile's services are up; step 0 waits for policy, which the profile leaves to another process"
        # Or the episode starts without it, as it did (then the assertion below says so at once).
        wait_for(lambda: (sim_log.is_file() and waits in sim_log.read_text()) or ((s := status()) and s["state"] != "starting"), 60, "the sim to wait")
        s = status()
        assert s["state"] == "starting" and s["step"] == 0 and s["lockstep_timeouts"] == 0, s
        assert s["services"]["policy"] == {"alive": False, "outside": True, "awaited": True} and s["waiting_for"] == ["policy"], s
        assert all(s["services"][name]["alive"] for name in ("sim", "mapper", "frontier", "planner")), s
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and re.search(r"state +│ starting; waiting for policy, which no process serves", r.stdout), r.stdout
        assert re.search(r"service policy +│ DOWN, not started by this run, the episode waits for it", r.stdout), r.stdout
        launcher_log = (Path(current["run_dir"]) / "logs" / "launcher.log").read_text()
        assert "profile lockstep has no policy service, and the episode needs one: it waits until another process serves robot r0" in launcher_log
        log_path = tmp_path / "policy.log"
        try:
            with log_path.open("w") as log_file:
                policy = subprocess.Popen([*python_module_argv("cso_runtime.cli"), "service", "policy", "--attach", "--runs-dir", str(runs)],
                                          cwd=tmp_path, stdout=log_file, stderr=subprocess.STDOUT)
            s = wait_for(lambda: (s := status()) and s["decisions"] >= 1 and s["step"] >= 1 and s, 60, "the robot to explore with the policy")
            assert s["services"]["policy"]["alive"] and s["services"]["policy"]["outside"] and s["waiting_for"] == [], s
            assert "starting the episode without" not in sim_log.read_text()  # step 0 came with the policy, not after the wait
            policy.send_signal(signal.SIGINT)
            assert policy.wait(30) == 0, log_path.read_text()[-2000:]
            s = wait_for(lambda: (s := status()) and not s["services"]["policy"]["alive"] and s, 30, "status to see the policy gone")
            assert s["state"] == "exploring" and s["waiting_for"] == ["policy"], s
        finally:
            if policy is not None and policy.poll() is None:
                policy.kill()


def test_a_goal_forged_for_a_later_step_is_rejected_and_the_lockstep_episode_goes_on(tmp_path):
    """Lockstep, over Zenoh: as soon as a step k asks for a decision, a decided goal for step k + 100 is published (of
    this episode, long before any decision asks for that step). The frontier service took it as its decision, newer
    than any real one: the policy's answer to the next decision it asked for was older, so ignored, and the frontier
    service waited for an answer until the sim gave up after ``lockstep_give_up_s`` ("failed", lockstep_timeout, a few
    steps in; a stall that no test had reproduced, 5e968a7). A goal only answers a decision asked for: this one is
    rejected, counted in the frontier service's status, and the episode ends as it does in one process."""
    from cso_runtime.messages import FrontiersMsg, GoalMsg

    expected = in_process_result()
    with detached_run(tmp_path, min_step_period_s=0.05, lockstep_give_up_s=4.0) as (runs, status):
        current = json.loads((runs / "current.json").read_text())
        keys = RobotKeys(current["robot"])
        decisions: list[FrontiersMsg] = []
        with open_session(TransportConfig(mode="client", connect=current["endpoints"])) as session:
            sub = session.declare_subscriber(keys.frontiers, lambda sample: decisions.append(decode(sample.payload.to_bytes(), FrontiersMsg)))
            asked = wait_for(lambda: next((m for m in decisions if m.decide), None), 60, "a step that asks for a decision")
            session.put(keys.goal, encode(GoalMsg(asked.step + 100, True, 0.0, 0.0, 0, 1.0, 0.0, "greedy-dist", episode=asked.episode)))
            final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
            sub.undeclare()
        assert asked.step < final["step"]  # forged during the episode
        assert (final["state"], final["terminated_by"], final["step"]) == ("done", expected.terminated_by, expected.steps), final
        assert abs(final["coverage_pct"] - expected.coverage_pct) < 1e-3
        assert final["services"]["frontier"]["rejected"] == {"goal": 1}, final["services"]["frontier"]


def test_a_hung_service_is_killed_and_restarted_and_the_episode_completes(tmp_path):
    """A service whose process lives but does nothing (SIGSTOP stands in for a deadlock) would leave the
    episode waiting with every process up: the launcher notices it stopped answering its status query,
    writes why, kills and restarts it, and the episode completes.

    What it waits for is this planner's kill and restart: its process replaced by another in the launcher's status.
    It waited for counts (a hung kill and a restart) that an earlier kill of the planner on a loaded machine had
    already reached, and found the planner it had just stopped alive."""
    from cso_runtime.supervision import process_start_ticks, run_process_alive

    # 0.1 s steps: the robot stands while its planner hangs (no goal, no coverage), so the episode cannot end before the kill.
    with detached_run(tmp_path, "--set", "supervision.hang_timeout_s=2", min_step_period_s=0.1, lockstep_timeout_s=0.5) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        before = status()["services"]["planner"]
        planner_pid, planner_ticks = before["pid"], process_start_ticks(before["pid"])
        os.kill(planner_pid, signal.SIGSTOP)

        def planner() -> dict | None:
            s = status()
            return s and s["services"]["planner"]

        after = wait_for(
            lambda: (p := planner()) and p["pid"] != planner_pid and p.get("hung_kills", 0) > before.get("hung_kills", 0) and p,
            30, f"the hung planner (pid {planner_pid}) to be killed and restarted",
        )
        assert after["restarts"] > before["restarts"] and not run_process_alive(planner_pid, planner_ticks), after
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and final["terminated_by"] == "coverage", final
        launcher_log = next(runs.glob("*/logs/launcher.log")).read_text()
        assert re.search(rf"planner \(pid {planner_pid}\) runs but has not answered for \d+ s \(hung\? stopped\?\): killing it to restart it", launcher_log), launcher_log[-3000:]
        hung = final["services"]["planner"]["hung_kills"]
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert f"{hung} of them hung" in " ".join(re.sub(r"[│┃]", " ", r.stdout).split()), r.stdout  # the table may wrap the row


STAND_IN_LAUNCHER = """
import os, subprocess, sys, time
env = {**os.environ, "CSO_PARENT_PID": str(os.getpid())}  # as the launcher starts a service (supervision.Child)
with open(sys.argv[1], "w") as log:
    proc = subprocess.Popen([sys.executable, "-c", *sys.argv[2:]], env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
print(proc.pid, flush=True)
time.sleep(600)
"""

def end_stand_in_launcher(launcher: subprocess.Popen, service_pid: int | None) -> None:
    """A test's clean-up of ``STAND_IN_LAUNCHER``: the launcher killed and reaped, and its service killed if still alive."""
    launcher.kill()
    launcher.wait(10)
    if launcher.stdout is not None:
        launcher.stdout.close()
    if service_pid is not None and pid_alive(service_pid):
        os.kill(service_pid, signal.SIGKILL)


MAPPER_STUCK_IN_ITS_FIRST_HANDLER = """
import sys, threading
from pathlib import Path
from services import common
from services.mapper import MapperService
common.ORPHAN_STOP_S = 1.0
def stuck(self, robot, topic, msg, received_s):
    Path(sys.argv[1]).touch()
    threading.Event().wait()
MapperService.on_message = stuck
sys.exit(common.service_main(MapperService, sys.argv[2:]))
"""


def test_a_service_stuck_in_a_handler_does_not_outlive_its_killed_launcher(tmp_path):
    """The launcher SIGKILLed while a service's loop is stuck in a handler (a deadlock): the kernel's SIGTERM only sets
    the service's stop event, which its stuck loop never looks at, so the service lived on for good, an orphan holding
    its memory and its place on the network (seen with a planner stuck in a ``sim`` run and ``up`` killed). Once its
    launcher is gone it has ``ORPHAN_STOP_S`` to stop; then it writes its threads' stacks to its log and exits."""
    port = free_tcp_port()
    keys = RobotKeys("t1")
    marker, log_path = tmp_path / "stuck", tmp_path / "mapper.log"
    service = [MAPPER_STUCK_IN_ITS_FIRST_HANDLER, str(marker), "--config", str(PROFILES / "sim.yaml"), "--robot", "t1", "--connect", loopback_endpoint(port)]
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        launcher = subprocess.Popen([sys.executable, "-c", STAND_IN_LAUNCHER, str(log_path), *service], cwd=REPO, stdout=subprocess.PIPE, text=True)
        mapper_pid = None
        try:  # from its first line: a stand-in that dies before it says its mapper's pid is still reaped
            mapper_pid = int(launcher.stdout.readline())
            wait_for(lambda: any(True for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5) if r.ok), 60, "the mapper's liveliness token")
            session.put(keys.clock, encode(ClockMsg(0, 0.0, GridGeometry(0.1, (40, 40)))))
            wait_for(marker.exists, 10, "the mapper to be stuck in its handler")
            launcher.kill()
            launcher.wait(10)
            wait_for(lambda: not pid_alive(mapper_pid), 30, f"the stuck mapper (pid {mapper_pid}) to exit once its launcher is gone")
        finally:
            end_stand_in_launcher(launcher, mapper_pid)
    text = log_path.read_text()
    assert f"mapper: still running 1 s after its launcher (pid {launcher.pid}) went (stuck?)" in text, text[-3000:]
    assert re.search(r'File "<string>", line \d+ in stuck', text), text[-3000:]  # the stuck handler, in the stacks


MAPPER = "import sys; from services.common import service_main; from services.mapper import MapperService; sys.exit(service_main(MapperService, sys.argv[1:]))"


def test_a_service_whose_launcher_dies_before_it_joins_stops_at_once_and_says_why(tmp_path):
    """The launcher SIGKILLed while a service still started (a policy loading its weights; found by a fault-injection
    soak): the kernel's SIGTERM set the stop, but the service then opened its session all the same, waiting for the
    killed launcher's router up to the connect timeout (10 s), and ended either by the orphan guard, with "still running
    10 s after its launcher went (stuck?)" and every thread's stack in its log, or as "cannot reach" the router (exit
    3): a service that was not stuck, reported as hung or as a network fault. The stop now ends the open at once."""
    port = free_tcp_port()  # no router: the killed launcher's went with it
    log_path = tmp_path / "mapper.log"
    service = [MAPPER, "--config", str(PROFILES / "sim.yaml"), "--robot", "t1", "--connect", loopback_endpoint(port)]
    launcher = subprocess.Popen([sys.executable, "-c", STAND_IN_LAUNCHER, str(log_path), *service], cwd=REPO, stdout=subprocess.PIPE, text=True)
    mapper_pid = None
    try:
        mapper_pid = int(launcher.stdout.readline())
        launcher.kill()  # before the mapper has joined (it is still importing, or opening its session)
        launcher.wait(10)
        wait_for(lambda: not pid_alive(mapper_pid), 30, f"the mapper (pid {mapper_pid}) to exit once its launcher is gone")
    finally:
        end_stand_in_launcher(launcher, mapper_pid)
    text = log_path.read_text()
    assert f"mapper: stopping: the launcher (pid {launcher.pid}) is gone (killed? crashed?)" in text and "mapper: stopped" in text, text[-3000:]
    assert "still running" not in text and "cannot reach" not in text and "Thread 0x" not in text, text[-3000:]


def test_a_killed_launchers_services_stop_at_once_and_each_log_says_why(tmp_path):
    """The launcher SIGKILLed mid-episode (its router dies with it): the kernel's SIGTERM (PR_SET_PDEATHSIG) stops
    every service and the frontier's layer helper within a second, no orphan left. Each service's log said only
    "stopped"; now a WARNING names the reason first. ``status`` says the launcher has exited, ``runs`` that it
    died, and ``down`` clears the run and writes in its run.json that it ended (it said "running" for good)."""
    with detached_run(tmp_path, min_step_period_s=0.25) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        current = json.loads((runs / "current.json").read_text())
        launcher, run_dir = current["launcher_pid"], Path(current["run_dir"])
        services = {name: s["pid"] for name, s in current["services"].items()}
        assert sorted(services) == ["frontier", "mapper", "planner", "policy", "sim"]
        helpers = wait_for(lambda: _children(services["frontier"]), 30, "the frontier's layer helper")
        pids = [*services.values(), *helpers]
        t0 = time.monotonic()
        os.kill(launcher, signal.SIGKILL)
        wait_for(lambda: not any(pid_alive(p) for p in pids), 10, "every service and helper to be gone", period_s=0.01)
        took_s = time.monotonic() - t0
        for name in services:
            text = (run_dir / "logs" / f"{name}.log").read_text()
            why = f"WARNING cso.service: {name}: stopping: the launcher (pid {launcher}) is gone"
            assert why in text and f"INFO cso.service: {name}: stopped" in text.split(why, 1)[1], text[-2000:]
        assert took_s < 5.0, took_s  # measured 0.3 to 0.5 s on 2 busy cores
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 1 and f"launcher, pid {launcher}, has exited" in json.loads(r.stdout)["reason"], r.stdout
        r = cli("runs", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and "launcher died" in r.stdout, r.stdout
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and f"stopped run {current['run_id']}" in r.stdout and not (runs / "current.json").exists(), r.stdout + r.stderr
        # run.json said "running" for good; once `down` has cleaned up, it says how the run ended (and `runs` still why)
        run = json.loads((run_dir / "run.json").read_text())
        assert (run["state"], run["outcome"], run["reason"]) == ("stopped", "failed", "launcher died; stopped by down"), run
        assert "ended_at" not in run and run["stopped_by_down_at"] >= run["started_at"], run
        r = cli("runs", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and [x["state"] for x in json.loads(r.stdout)] == ["launcher died"], r.stdout


def test_a_stopped_service_does_not_outlive_its_killed_launcher(tmp_path):
    """A service stopped (SIGSTOP, a debugger, Ctrl-Z of its own) when its launcher is SIGKILLed cannot act on the
    kernel's SIGTERM (PR_SET_PDEATHSIG) nor on its own orphan check: it stayed stopped for good, an orphan holding its
    memory and its place on the network, with no one left to continue or kill it. A service's parent-death signal is
    now SIGCONT (its handler stops it when its launcher is gone), which continues a stopped one: it stops as its
    siblings do."""
    from cso_runtime.supervision import process_state

    with detached_run(tmp_path, min_step_period_s=0.25) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        current = json.loads((runs / "current.json").read_text())
        launcher, run_dir = current["launcher_pid"], Path(current["run_dir"])
        mapper = current["services"]["mapper"]["pid"]
        os.kill(mapper, signal.SIGSTOP)
        try:
            wait_for(lambda: process_state(mapper) == "T", 10, "the mapper to be stopped", period_s=0.01)
            os.kill(launcher, signal.SIGKILL)
            wait_for(lambda: not pid_alive(mapper), 10, "the stopped mapper to be gone", period_s=0.01)
        finally:
            if pid_alive(mapper):
                os.kill(mapper, signal.SIGCONT)  # the clean-up's `down` and kill reach it all the same
        text = (run_dir / "logs" / "mapper.log").read_text()
        why = f"WARNING cso.service: mapper: stopping: the launcher (pid {launcher}) is gone"
        assert why in text and "INFO cso.service: mapper: stopped" in text.split(why, 1)[1], text[-2000:]


def test_a_run_stopped_while_its_sim_is_hung_keeps_its_map_so_far(tmp_path):
    """``down`` of a run whose sim is hung (SIGSTOP stands in for a deadlock): the map so far was not kept, and the
    launcher's log said "the run has no map yet, and no episode status answers either: its services may still be
    starting" at step 10 and more, for the sim serves the map's cache. The mapper, which answers on its map's key,
    gives it where the cache does not."""
    with detached_run(tmp_path, min_step_period_s=0.1) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 5, 60, "the episode to run")
        current = json.loads((runs / "current.json").read_text())
        run_dir, sim = Path(current["run_dir"]), current["services"]["sim"]["pid"]
        os.kill(sim, signal.SIGSTOP)
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stdout + r.stderr
        launcher_log = (run_dir / "logs" / "launcher.log").read_text()
        assert (run_dir / "last_map.yaml").is_file() and re.search(r"the episode's map at step \d+ kept", launcher_log), launcher_log[-3000:]


def test_down_of_a_cso_run_stops_the_policy_service_on_sigint_and_its_log_ends_with_its_stop(tmp_path):
    """The policy service of method cso (torch) took 1.5 to 3.4 s after its "stopped" line to exit on 2 busy cores (the
    interpreter's teardown), past the 3 s stop timeout now and then: the launcher said "policy still running after
    SIGINT" and sent SIGTERM on a clean stop. It now ends its process once stopped (``services.common.exit_now``): it
    stops on the SIGINT alone, with no warning, and its log ends with its stop line."""
    profile = write_profile(tmp_path, method="cso", min_step_period_s=0.25)
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        current = json.loads((runs / "current.json").read_text())
        run_dir = Path(current["run_dir"])
        wait_for(lambda: (s := query_status(current["endpoints"], current["robot"], timeout_s=0.5)) and s["step"] >= 2, 60, "the episode to run")
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        # and where its map so far is (it said "stopped run X" alone: a detached run's own last line is in launcher.log)
        kept = f"no results (its episode had not ended); its map so far: {run_dir / 'last_map.yaml'}"
        assert r.returncode == 0 and r.stdout.strip() == f"stopped run {current['run_id']}; {kept}", r.stdout + r.stderr
        launcher_log = (run_dir / "logs" / "launcher.log").read_text()
        assert "still running after" not in launcher_log, launcher_log
        assert (run_dir / "logs" / "policy.log").read_text().splitlines()[-1].endswith("INFO cso.service: policy: stopped")
        # where it stopped: run.json keeps the step, `runs` shows it (it showed "-" for a run without results)
        assert json.loads((run_dir / "run.json").read_text())["last_step"] >= 2
        r = cli("runs", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        (row,) = json.loads(r.stdout)
        assert row["state"] == "interrupted" and row["steps"] is None and row["stopped_at_step"] >= 2, row
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def test_down_continues_a_stopped_launcher_which_then_ends_its_run_itself(tmp_path):
    """``down`` of a run whose launcher is stopped (Ctrl-Z on ``up``, SIGSTOP): its SIGINT stays pending until the
    launcher runs again, so ``down`` waited out every stage and killed it, and the run was left unfinished
    (run.json "running", no outcome: ``runs`` said "launcher died"). ``down`` now continues it, and the launcher
    stops its services and ends its run as on any ``down``."""
    from cso_runtime.current_run import down
    from cso_runtime.supervision import process_state

    with detached_run(tmp_path, min_step_period_s=0.25) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        current = json.loads((runs / "current.json").read_text())
        os.kill(current["launcher_pid"], signal.SIGSTOP)
        wait_for(lambda: process_state(current["launcher_pid"]) == "T", 10, "the launcher to be stopped")
        ok, message = down(runs, timeout_s=60)
        kept = f"no results (its episode had not ended); its map so far: {Path(current['run_dir']) / 'last_map.yaml'}"
        assert ok and message == f"stopped run {current['run_id']} (its launcher was stopped (Ctrl-Z, SIGSTOP): continued so that it could stop); {kept}", message
        run = json.loads((Path(current["run_dir"]) / "run.json").read_text())
        assert run["state"] == "stopped" and run["outcome"] == "interrupted", run
        assert not any(pid_alive(p) for p in run_pids(runs))


def test_a_launcher_stopped_and_continued_does_not_take_its_services_for_hung(tmp_path):
    """A launcher stopped for longer than ``hang_timeout_s`` (Ctrl-Z on ``up`` and ``fg``, SIGSTOP and SIGCONT)
    found on its return that no service had answered it meanwhile, and killed them as hung, the sim first: its
    episode started over. The silence was the launcher's own: the hang check starts over once it asks again, and
    the episode goes on to its end with no restart."""
    from cso_runtime.launcher import WATCH_BEHIND_S
    from cso_runtime.supervision import process_state

    with detached_run(tmp_path, "--set", "supervision.hang_timeout_s=2", min_step_period_s=0.25, lockstep_timeout_s=0.5) as (runs, status):
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        launcher_pid = json.loads((runs / "current.json").read_text())["launcher_pid"]
        os.kill(launcher_pid, signal.SIGSTOP)
        try:
            wait_for(lambda: process_state(launcher_pid) == "T", 10, "the launcher to be stopped")
            time.sleep(WATCH_BEHIND_S + 1.0)  # the fault: stopped longer than hang_timeout_s and than the watch's round
        finally:
            os.kill(launcher_pid, signal.SIGCONT)
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and final["terminated_by"] == "coverage", final
        assert {name: (svc["restarts"], svc.get("hung_kills", 0)) for name, svc in final["services"].items()} == {name: (0, 0) for name in final["services"]}
        launcher_log = next(runs.glob("*/logs/launcher.log")).read_text()
        assert "their silence meanwhile is not taken for a hang" in launcher_log and "killing it" not in launcher_log, launcher_log[-3000:]


def test_a_stray_episode_end_does_not_end_the_run(tmp_path):
    """One episode status saying "done" that no result follows, while the sim goes on reporting the
    episode exploring (a stray or forged message): ignored, counted, and the run ends with the episode. A status of
    the episode exploring right behind it (the sim's next step's can be, before the launcher's loop, which looks every
    0.1 s, gets to it: on a loaded host it missed the end, never counted it, and the test waited in vain) changes nothing."""
    # 36 steps of at least 0.25 s: the launcher waits up to a few seconds for the stray end's result before it calls
    # the end stray (the sim going on exploring), and the real end must not come within that wait (0.1 s steps did, once).
    with detached_run(tmp_path, min_step_period_s=0.25, lockstep_timeout_s=0.5) as (runs, status):
        s = wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2 and s, 60, "the episode to start")
        endpoints = json.loads((runs / "current.json").read_text())["endpoints"]
        with open_session(TransportConfig(mode="client", connect=endpoints)) as session:
            session.put(RobotKeys("r0").episode_status, encode(EpisodeStatusMsg("done", s["step"], terminated_by="coverage", episode=s["episode"])))
            session.put(RobotKeys("r0").episode_status, encode(EpisodeStatusMsg("exploring", s["step"], episode=s["episode"])))
        wait_for(lambda: (s := status()) and s["launcher_rejected"].get("episode_status", 0) == 1, 30, "the stray end to be ignored")
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and final["step"] > s["step"] + 2, final
        wait_for(lambda: list(runs.glob("*/summary.json")), 20, "summary.json")
        assert "but the episode goes on" in next(runs.glob("*/logs/launcher.log")).read_text()


def test_an_episode_end_heard_is_judged_once_however_the_launchers_threads_interleave(tmp_path):
    """``_on_sample`` set ``status`` to an episode end, then (a statement later, under the lock) ``end_heard``: the run
    loop asking in between (``episode_end_heard``) got the end from ``status``, and once more from ``end_heard`` at its
    next look, after the sim's next status said the episode goes on. A stray end was judged twice: counted twice in
    ``launcher_rejected`` and logged twice, with a second wait for a result that does not come. The switch of threads
    is made here where the callback takes the lock: the end is handed to the loop once."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)
    judged: list[EpisodeStatusMsg | None] = []

    class SwitchOnTake:
        """The launcher's lock, whose first take lets the run loop look (``episode_end_heard``) before it is held."""

        def __init__(self) -> None:
            self.lock, self.armed = threading.RLock(), True

        def __enter__(self) -> None:
            if self.armed:
                self.armed = False
                judged.append(launcher.episode_end_heard())
            self.lock.acquire()

        def __exit__(self, *exc: object) -> None:
            self.lock.release()

    def hear(msg: EpisodeStatusMsg) -> None:
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))

    hear(EpisodeStatusMsg("exploring", 4, episode=7))
    launcher._lock = SwitchOnTake()  # type: ignore[assignment]
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=7))  # the stray end
    hear(EpisodeStatusMsg("exploring", 5, episode=7))  # the sim's next status: the episode goes on
    judged += [launcher.episode_end_heard(), launcher.episode_end_heard()]
    ends = [st for st in judged if st is not None]
    assert [(st.state, st.step) for st in ends] == [("done", 5)], judged


class _ScriptedResultQueries:
    """A launcher's session for ``judge_episode_end``: its queries for the episode's result get no answer, and each
    first runs the next step of ``script`` (what the launcher hears meanwhile); a query past the script fails the test
    (the launcher waited where it should not have)."""

    def __init__(self, script: list[Callable[[], None]]) -> None:
        self.script, self.queries = list(script), 0

    def get(self, key: str, timeout: float) -> list[Any]:
        self.queries += 1
        assert self.script, f"query {self.queries} for the result: the launcher still waits"
        self.script.pop(0)()
        return []


def _launcher_hearing(tmp_path):
    """A launcher of the lockstep profile, and ``hear``, which hands it a message as its subscriber would."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import EpisodeResultMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)

    def hear(msg: Any) -> None:
        key = keys.episode_result if isinstance(msg, EpisodeResultMsg) else keys.episode_status
        launcher._on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))

    return launcher, hear


def _result(steps: int, terminated_by: str, episode: int = 0):
    """A result of ``episode`` (0: no id, a referee from before results carried one)."""
    from cso_runtime.messages import EpisodeResultMsg

    free = np.ones((4, 4), bool)
    return EpisodeResultMsg("s", steps, 1.2, 98.0, 1.3, 4.5, terminated_by, 3, np.ones(3), np.zeros((4, 2)), np.linspace(0, 98, 4), free, free, 0.1, "greedy-dist", 0, episode=episode)


class _AnsweredResultQueries:
    """A launcher's session for ``judge_episode_end`` whose queries for the episode's result are answered by the next
    results of ``answers`` (a list of results per query); a query past them fails the test."""

    def __init__(self, answers: list[list[Any]]) -> None:
        self.answers, self.queries = list(answers), 0

    def get(self, key: str, timeout: float) -> list[Any]:
        from types import SimpleNamespace

        self.queries += 1
        assert self.answers, f"query {self.queries} for the result: the launcher still waits"
        return [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda r=r: encode(r)))) for r in self.answers.pop(0)]


def test_a_late_result_of_an_episode_a_restart_left_behind_is_not_the_next_episodes_result(tmp_path, caplog):
    """Episode 7 ended, its result did not come, the sim restarted (episode 8) and 7's end was left behind; then 7's
    result came after all (late, in flight from the process that ran it). The launcher kept "whatever result arrived":
    at episode 8's end it took episode 7's result, at once, and wrote episode 7's figures as the run's under episode
    8's end. A result names its episode: one of another episode than the end judged is not that end's result, pushed
    or answered to a query; a result without an id (an older referee's) is taken as before."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))
    over = launcher.episode_end_heard()
    assert over is not None
    restart = [lambda: None, lambda: hear(EpisodeStatusMsg("starting", 0, episode=8))]
    assert launcher.judge_episode_end(_ScriptedResultQueries(restart), over, lambda: None) is None  # left behind
    with caplog.at_level("WARNING", logger="cso.launcher"):
        hear(_result(31, "coverage", episode=7))  # late: episode 7's result after all
    said = "the result of episode 7 came after its end was left behind: it is not the run's, which goes on with episode 8"
    assert said in caplog.text, caplog.text
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: None, lambda: hear(_result(40, "max_steps", episode=8))]), over, lambda: None)
    assert judged is not None and judged[1] is not None, judged
    assert (judged[1].episode, judged[1].steps, judged[0].terminated_by) == (8, 40, "max_steps"), judged

    # answered to a query: a reply of another episode (a late one) is skipped, the end's own taken
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None
    answers = _AnsweredResultQueries([[_result(31, "coverage", episode=7)], [_result(31, "coverage", episode=7), _result(40, "max_steps", episode=8)]])
    judged = launcher.judge_episode_end(answers, over, lambda: None)
    assert judged is not None and judged[1] is not None and (judged[1].episode, judged[1].steps) == (8, 40) and answers.queries == 2

    # a result without an id is the end's, as before ids: pushed or answered
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_AnsweredResultQueries([[_result(40, "max_steps")]]), over, lambda: None)
    assert judged is not None and judged[1] is not None and (judged[1].episode, judged[1].steps) == (0, 40)


def test_a_result_of_the_running_episode_is_not_taken_for_a_late_end_of_the_episode_before(tmp_path):
    """Episode 7's end is heard after episode 8 started, and a result is here: the launcher took it for episode 7's,
    whatever its episode, and ended the run with it. Only episode 7's own result (or one without an id, as before)
    ends the run there; episode 8's result waits for episode 8's end."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(_result(3, "lockstep_timeout", episode=8))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # late, of the episode before
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    assert launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None  # left behind, no wait
    assert [e["episode"] for e in launcher.lost_results] == [7]
    hear(EpisodeStatusMsg("failed", 3, terminated_by="lockstep_timeout", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
    assert judged is not None and judged[1] is not None and (judged[1].episode, judged[1].steps) == (8, 3)


def test_a_late_result_of_an_end_left_behind_neither_ends_the_run_nor_displaces_the_running_episodes(tmp_path):
    """Episode 7's end was left behind (the sim restarted into episode 8), then 7's result came late: the launcher said
    "it is not the run's" but kept it as the result heard. Its end heard again (late or replayed, which ``_on_sample``
    hands to the run loop to judge) then ended the run with episode 7's result, an episode ``lost_results`` still named
    lost; and heard after episode 8's own result, it put that one out of reach of a referee that answers no query.
    A result of an end left behind is never kept."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    end7 = EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7)
    hear(end7)
    over = launcher.episode_end_heard()
    assert over is not None
    restart = [lambda: None, lambda: hear(EpisodeStatusMsg("starting", 0, episode=8))]
    assert launcher.judge_episode_end(_ScriptedResultQueries(restart), over, lambda: None) is None  # left behind
    hear(EpisodeStatusMsg("exploring", 2, episode=8))
    hear(_result(31, "coverage", episode=7))  # late: not the run's (logged so)
    hear(end7)  # its end again, late
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    assert launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None, "the run ended with an episode left behind"
    assert [e["episode"] for e in launcher.lost_results] == [7]
    # heard on the Zenoh thread as the run loop left its end behind, before ``lost_results`` named it: kept, but an end
    # once left behind is left behind whatever result comes later
    launcher.result = _result(31, "coverage", episode=7)
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    assert launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None, "the run ended with an episode left behind"
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    hear(_result(40, "max_steps", episode=8))
    hear(_result(31, "coverage", episode=7))  # once more, late
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)  # pushed, no query answered
    assert judged is not None and judged[1] is not None and (judged[1].episode, judged[1].steps) == (8, 40), judged


def test_the_end_a_result_belongs_to_decides_the_run_not_a_stray_end_awaited_before_it(tmp_path):
    """A stray end ("failed" at step 5) is awaited; meanwhile the episode really ends ("done" at step 9) and its result
    comes. The launcher judged the stray's status with the real result: the run said "failed" (exit code 1) while its
    summary said done. The end the result belongs to (its ``terminated_by``, the latest end of the episode) decides."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 4, episode=7))
    hear(EpisodeStatusMsg("failed", 5, terminated_by="lockstep_timeout", episode=7))  # the stray
    over = launcher.episode_end_heard()
    assert over is not None and over.state == "failed"

    def the_real_end() -> None:
        hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=7))
        hear(_result(9, "coverage"))

    judged = launcher.judge_episode_end(_ScriptedResultQueries([the_real_end]), over, lambda: None)
    assert judged is not None
    end, result = judged
    assert result is not None and result.terminated_by == "coverage"
    assert (end.state, end.step, end.terminated_by) == ("done", 9, "coverage"), end
    assert launcher.ended_status is end  # summary.json's meta.episode and `status` go by it


def test_the_end_a_result_belongs_to_is_one_of_its_episode(tmp_path):
    """Episode 8's end is awaited; meanwhile an end of episode 9 is heard (a restarted sim's, which ended before it said
    it ran), then episode 8's result. The end the result belongs to was chosen by ``terminated_by`` alone: episode 9's
    end, of the same ``terminated_by``, became the run's end with episode 8's figures (summary.json's meta.episode 9).
    A result that names its episode belongs to an end of that episode."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None

    def meanwhile() -> None:
        hear(EpisodeStatusMsg("done", 2, terminated_by="max_steps", episode=9))
        hear(_result(40, "max_steps", episode=8))

    judged = launcher.judge_episode_end(_ScriptedResultQueries([meanwhile]), over, lambda: None)
    assert judged is not None and judged[1] is not None
    assert (judged[0].episode, judged[0].step, judged[1].episode) == (8, 40, 8), judged
    assert launcher.ended_status is judged[0]


def test_an_end_of_another_episode_than_the_one_running_is_left_behind_at_once(tmp_path, caplog):
    """A late "done" of episode 7 after episode 8 started (or a forged one naming an episode not running): the
    launcher waited for its result, as the episode going on was looked for in episode 7 only, and after 15 s said
    "result never arrived" and stopped the run. An end of another episode than the running one (its latest
    status's, starting or exploring) is not the run's end, at once, with no wait; so is one heard while episode
    8 is starting. It is no stray either (not counted under ``launcher_rejected``: it may be episode 7's real end,
    whose result went with the sim that ran it), and the log says so. An end of the episode running is awaited as before."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))  # a restarted sim: a new episode
    for episode_8 in (EpisodeStatusMsg("starting", 0, episode=8), EpisodeStatusMsg("exploring", 3, episode=8)):
        hear(episode_8)
        hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # late, of the episode before
        over = launcher.episode_end_heard()
        assert over is not None and over.episode == 7
        with caplog.at_level("WARNING", logger="cso.launcher"):
            assert launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
        assert launcher.ended_status is None
    assert launcher.rejected == {}
    said = (
        "episode 7 ended (done at step 31), but episode 8 has started since (the sim restarted) and no result of episode 7 came: "
        "it is lost with the process that ran it; the run goes on with episode 8, whose results will be the run's"
    )
    assert caplog.text.count(said) == 2, caplog.text
    # the end of the episode running: awaited, and judged with its result
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(9, "coverage"))]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None


def test_an_end_claiming_a_step_ahead_is_a_stray_once_the_episode_steps_on_behind_it(tmp_path):
    """A forged "done" at step 50 while the sim is at step 10: the episode going on was judged by a status at the
    end's step or later, which comes only at step 50, so the launcher waited 15 s and stopped the run without a
    summary. The sim stepping on in the same episode after the end (a later step than its first status heard since)
    shows the end stray. One status of an earlier step after a real end (late, from before it) shows nothing: the
    real end is awaited, and judged with its result."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 10, episode=7))
    hear(EpisodeStatusMsg("done", 50, terminated_by="coverage", episode=7))  # forged, a step ahead
    over = launcher.episode_end_heard()
    assert over is not None
    steps_on = [lambda: hear(EpisodeStatusMsg("exploring", 11, episode=7)), lambda: hear(EpisodeStatusMsg("exploring", 12, episode=7))]
    assert launcher.judge_episode_end(_ScriptedResultQueries(steps_on), over, lambda: None) is None
    assert launcher.rejected == {"episode_status": 1} and launcher.ended_status is None
    # the real end, a late status from before it, then its result
    hear(EpisodeStatusMsg("done", 40, terminated_by="coverage", episode=7))
    over = launcher.episode_end_heard()
    assert over is not None
    late = [lambda: hear(EpisodeStatusMsg("exploring", 39, episode=7)), lambda: None, lambda: hear(_result(40, "coverage"))]
    judged = launcher.judge_episode_end(_ScriptedResultQueries(late), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None
    assert launcher.rejected == {"episode_status": 1}


def test_a_stray_end_of_another_episode_is_judged_once_while_it_stays_the_latest_status(tmp_path):
    """A late "done" of episode 7 heard after episode 8 started stayed ``status`` until the sim's next status (a sim
    waiting for its services says nothing for seconds): the run loop, looking every 0.1 s, judged it again at each
    look, logging it and counting it in ``launcher_rejected`` ten times a second. It is judged once (and, since, it
    is never ``status``: a status of an episode a restart left behind is none of the running one's)."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # late, of the episode before
    over = launcher.episode_end_heard()
    assert over is not None and launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    assert launcher.episode_end_heard() is None and launcher.episode_end_heard() is None  # the loop's next looks
    assert launcher.rejected == {}  # left behind (the sim restarted), no stray: counted nowhere, said once
    # the sim's own end, later, is heard and judged
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None and (over.episode, over.step) == (8, 9)


def test_the_end_of_a_restarted_sims_episode_heard_before_any_status_of_it_running_ends_the_run(tmp_path):
    """The sim restarted (a new episode id) and its episode ended before it said the episode runs (the sim sends
    its status with a map measured: a restarted lockstep sim whose step 0 never gets its map fails "lockstep_timeout"
    with no status before; a first map that already ends it). ``episode_running`` still named the episode before the
    restart: the real end was a stray at once, judged again at every look, and the run never ended. An end of an
    episode never heard running is awaited, and judged with its result; one of an episode heard before the running
    one is still a stray at once."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("failed", 0, terminated_by="lockstep_timeout", episode=8))  # the restarted sim's end
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(0, "lockstep_timeout"))]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None
    assert launcher.rejected == {}


def test_an_end_whose_result_is_lost_to_a_restart_of_the_sim_leaves_the_run_to_the_new_episode(tmp_path, caplog):
    """Episode 7 ends, its result is lost (dropped on the way, and its sim died before the launcher's query: a hang,
    the OOM killer), and the launcher restarts the sim: episode 8. Heard in this order, the end was awaited for its
    15 s while episode 8 ran, then the launcher said "its result never arrived" and stopped the run, killing episode
    8; heard after episode 8's first status, the same end was a stray at once, counted in ``launcher_rejected``, and
    the run went on. One judgement for both orders, as a user reads a restart of the sim: episode 7's result went with
    the process that ran it, the run goes on with episode 8, whose end and results are the run's, and the log says
    so in those words; nothing was rejected. A result of episode 7 that did come is kept: the run ends with it."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # episode 7's real end; its result is lost
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    restart = [lambda: None, lambda: hear(EpisodeStatusMsg("starting", 0, episode=8))]  # the sim died and came back
    with caplog.at_level("WARNING", logger="cso.launcher"):
        assert launcher.judge_episode_end(_ScriptedResultQueries(restart), over, lambda: None) is None  # no wait beyond
    assert launcher.rejected == {} and launcher.ended_status is None
    said = "episode 7 ended (done at step 31), but episode 8 has started since (the sim restarted) and no result of episode 7 came"
    assert said in caplog.text and "the run goes on with episode 8, whose results will be the run's" in caplog.text, caplog.text
    assert launcher.episode_end_heard() is None  # not judged again
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="coverage", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(40, "coverage"))]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None and judged[1].steps == 40

    # episode 7's end heard after episode 8 started, its result there too: the run ends with episode 7's results
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))
    hear(_result(31, "coverage"))
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None and judged[1].steps == 31
    assert launcher.rejected == {}


def test_a_late_status_of_an_episode_a_restart_left_behind_does_not_make_it_the_running_one_again(tmp_path):
    """The sim restarted (episode 7, then 8); a status of episode 7 exploring heard after episode 8 started made 7 the
    running episode again and 8 one "before" it: episode 8's real end was then taken for an end of another episode,
    and the run never ended. An episode a restart left behind runs no more (a new episode draws a new id)."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("exploring", 30, episode=7))  # late, of the episode before
    assert launcher.episode_running == 8
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(9, "coverage"))]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None


def test_an_end_a_ros2_bridges_new_episode_left_behind_is_not_said_lost_with_its_process(tmp_path, caplog):
    """On a robot the ROS 2 bridge starts a new episode in the same process (the robot's odometry or clock started
    again): an end of the episode before it, its result never heard, is left behind as after a restart of the sim,
    but the launcher's log said its result "is lost with the process that ran it", which still runs. It says that
    the referee started a new episode, and ``status`` words it alike."""
    from types import SimpleNamespace

    from rich.console import Console

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("limo-ros2")), {}, connect=["tcp/127.0.0.1:1"])
    launcher = Launcher(profile, data, tmp_path / "run")
    keys = RobotKeys(profile.robot)
    for msg in (EpisodeStatusMsg("exploring", 30, episode=7), EpisodeStatusMsg("starting", 0, episode=8), EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7)):
        launcher._on_sample(SimpleNamespace(key_expr=keys.episode_status, payload=SimpleNamespace(to_bytes=lambda msg=msg: encode(msg))))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    with caplog.at_level("WARNING", logger="cso.launcher"):
        assert launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    said = (
        "episode 7 ended (done at step 31), but episode 8 has started since (the referee started a new one) and no result of "
        "episode 7 came: it is lost; the run goes on with episode 8, whose results will be the run's"
    )
    assert said in caplog.text and "process" not in caplog.text, caplog.text
    msg = decode(encode(launcher.launcher_status()), LauncherStatusMsg)
    assert isinstance(msg, LauncherStatusMsg)
    console = Console(record=True, width=400)
    console.print(render_table(status_of("r0", None, msg.to_dict(), {}, set())))
    text = " ".join(console.export_text().split())
    assert "but its result was lost: the referee started a new episode before it came" in text and "sim restarted" not in text, text


def test_the_live_view_says_that_an_episodes_result_was_lost_to_a_restart_of_the_sim(tmp_path):
    """``status`` says that an episode's result was lost to a restart of the sim (``lost_results``); ``up``'s live
    view showed the new episode starting as if the run had just begun, its one warning line scrolled away above the
    table (and in a file, the table written once at the end said nothing of it). It says it as ``status`` does."""
    from rich.console import Console

    from cso_runtime.live_view import LiveView

    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=0x2A))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=0x2A))
    hear(EpisodeStatusMsg("starting", 0, episode=0x2B))

    def table() -> str:
        console = Console(width=300, record=True)
        console.print(LiveView(launcher).render())
        return " ".join(console.export_text().split())

    said = "episode 00000000002a ended (done at step 31), but its result was lost: the sim restarted before it came; the run went on with episode 00000000002b"
    assert "result was lost" not in table()
    over = launcher.episode_end_heard()
    assert over is not None and launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    hear(EpisodeStatusMsg("exploring", 3, episode=0x2B))
    assert said in table(), table()


def test_run_json_and_summary_json_keep_the_episodes_whose_result_a_restart_lost(tmp_path):
    """An episode's end left behind with no result (``end_left_behind``) was said in launcher.log and, while the run
    ran, by ``status``: once the launcher exited, run.json said nothing of it, and a run whose next episode gave its
    results (or that was stopped before it did) read in ``runs`` and report.html as if nothing had been lost. run.json
    names them (``lost_results``, as ``launcher_status`` does) from the moment it is judged (a launcher killed later
    leaves it there) to the run's end, and the results written after (summary.json's ``meta.lost_results``) too."""
    launcher, hear = _launcher_hearing(tmp_path)
    launcher.run_dir.mkdir(parents=True)
    launcher.write_run_file("running")
    assert "lost_results" not in json.loads((launcher.run_dir / "run.json").read_text())
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # its result never comes
    hear(EpisodeStatusMsg("starting", 0, episode=8))  # the sim restarted
    over = launcher.episode_end_heard()
    assert over is not None and launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    lost = [{"episode": 7, "state": "done", "step": 31, "running": 8}]
    assert json.loads((launcher.run_dir / "run.json").read_text())["lost_results"] == lost  # written as it is judged
    writes: list[str] = []
    write_run_file = launcher.write_run_file
    launcher.write_run_file = lambda state: writes.append(state) or write_run_file(state)  # type: ignore[method-assign]
    for _ in range(3):  # its end replayed: judged again, nothing new to write (a flood of them writes no file a round)
        hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))
        over = launcher.episode_end_heard()
        assert over is not None and launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    assert writes == [] and launcher.lost_results == lost
    launcher.write_run_file = write_run_file  # type: ignore[method-assign]
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="coverage", episode=8))
    over = launcher.episode_end_heard()
    assert over is not None
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(40, "coverage"))]), over, lambda: None)
    assert judged is not None and judged[1] is not None
    launcher.write_outputs(judged[1])
    summary = json.loads((launcher.run_dir / "summary.json").read_text())
    assert summary["meta"]["lost_results"] == lost and summary["meta"]["episode"] == 8
    launcher.write_run_file("stopped")
    assert json.loads((launcher.run_dir / "run.json").read_text())["lost_results"] == lost
    report = (launcher.run_dir / "report.html").read_text()
    said = "episode 000000000007 ended (done at step 31), but its result was lost: the sim restarted before it came; the run went on with episode 000000000008"
    assert said in report, report


def test_status_says_that_an_episodes_result_was_lost_to_a_restart_of_the_sim(tmp_path):
    """An episode's end left behind with no result (the sim restarted before it came, ``end_left_behind``) was said
    in launcher.log only: ``status`` showed the new episode running as if nothing had been lost. The launcher's status
    names it (``lost_results``: once per episode however often its end is heard), ``status --json`` has it, and the
    table says it in words; an older launcher's status, without the field, reads as none lost."""
    from rich.console import Console

    from cso_runtime.messages import LauncherStatusMsg

    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=0x2A))
    hear(EpisodeStatusMsg("starting", 0, episode=0x2B))
    for _ in range(2):  # its late end heard twice: one episode lost
        hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=0x2A))
        over = launcher.episode_end_heard()
        assert over is not None and launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None) is None
    msg = decode(encode(launcher.launcher_status()), LauncherStatusMsg)
    assert isinstance(msg, LauncherStatusMsg)
    assert msg.lost_results == [{"episode": 0x2A, "state": "done", "step": 31, "running": 0x2B}], msg.lost_results
    status = status_of("r0", None, msg.to_dict(), {}, set())
    assert status["lost_results"] == msg.lost_results
    console = Console(record=True, width=400)
    console.print(render_table(status))
    text = " ".join(console.export_text().split())
    said = (
        "episode 00000000002a ended (done at step 31), but its result was lost: the sim restarted before it came; "
        "the run went on with episode 00000000002b"
    )
    assert said in text, text
    older = status_of("r0", None, LauncherStatusMsg("run1", "running").to_dict(), {}, set())
    assert older["lost_results"] == []


def test_a_late_status_of_an_episode_a_restart_left_behind_is_not_the_running_episodes_status(tmp_path):
    """Episode 7's sim restarted into episode 8; a status of episode 7 heard after that (late, or replayed) still
    replaced the launcher's latest status: its ``last_episode`` (``status`` with the sim silent, the live view) said
    episode 7, the real-time factor of episode 8 was measured anew from it (episodes.csv's ``real_time_factor``
    of episode 8 empty when it came between 8's last status and its end), and a late end of 7 heard after 8's end
    hid 8's end: judged left behind, it stayed the latest status, 8's end was never judged and the run never ended.
    A status of an episode a restart left behind is no status of the running episode; its end is judged all the
    same (its result may be here)."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("exploring", 5, episode=8))
    hear(EpisodeStatusMsg("exploring", 9, episode=8))
    assert launcher.real_time_factor is not None
    hear(EpisodeStatusMsg("exploring", 31, episode=7))  # late, of the episode before
    last = launcher.launcher_status().last_episode
    assert last is not None and (last["episode"], last["step"]) == (8, 9), last
    assert launcher.real_time_factor is not None  # 8's pace, not started over on 7's status
    hear(EpisodeStatusMsg("done", 40, terminated_by="coverage", episode=8))
    hear(EpisodeStatusMsg("done", 31, terminated_by="coverage", episode=7))  # late, after 8's end
    over = launcher.episode_end_heard()
    assert over is not None and (over.episode, over.step) == (8, 40), over
    judged = launcher.judge_episode_end(_ScriptedResultQueries([lambda: hear(_result(40, "coverage"))]), over, lambda: None)
    assert judged is not None and judged[0] is over and judged[1] is not None and judged[1].steps == 40
    assert launcher.real_time_factor is not None

    # 8's end heard, then 7's late end and 8's result before the run loop looks: the run's end is 8's, not 7's
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("exploring", 30, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 40, terminated_by="max_steps", episode=8))
    hear(EpisodeStatusMsg("failed", 31, terminated_by="lockstep_timeout", episode=7))
    hear(_result(40, "max_steps"))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8, over
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
    assert judged is not None and (judged[0].episode, judged[0].state) == (8, "done"), judged


def test_an_end_of_an_episode_a_restart_left_behind_heard_beside_another_end_is_left_behind_too(tmp_path):
    """Found by the seeded interleavings below. The run loop looks for an end every 0.1 s and took one end heard since
    (``end_heard``): an end of an episode a restart left behind heard while another end waited there was dropped, and
    one waiting there was replaced by the running episode's end. That end was never judged: the run went on and ended
    well, but neither its log, ``status`` nor summary.json's ``meta.lost_results`` said that episode's result was lost.
    The running episode's end is judged first, as before; the others are left behind, in turn or with the run's end."""

    def judge_until_the_run_ends(launcher):
        ends = []
        while (over := launcher.episode_end_heard()) is not None:
            judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
            if judged is not None:
                return ends, judged
            ends.append(over.episode)
        return ends, None

    # episode 8's end, then 7's late one and 8's result, before the run loop looks
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    hear(EpisodeStatusMsg("failed", 3, terminated_by="lockstep_timeout", episode=7))  # late, of the episode before
    hear(_result(9, "coverage", episode=8))
    ends, judged = judge_until_the_run_ends(launcher)
    assert judged is not None and judged[1] is not None and (judged[0].episode, judged[0].state, judged[1].episode) == (8, "done", 8), judged
    assert launcher.ended_status is judged[0]  # summary.json's meta.episode
    assert [e["episode"] for e in launcher.lost_results] == [7]

    # episode 7's end, then 8 starts and ends, before the run loop looks; and 6's late end heard twice meanwhile
    launcher, hear = _launcher_hearing(tmp_path / "2")
    hear(EpisodeStatusMsg("starting", 0, episode=6))
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 4, terminated_by="coverage", episode=6))  # late
    hear(EpisodeStatusMsg("done", 4, terminated_by="coverage", episode=6))  # and replayed
    hear(EpisodeStatusMsg("exploring", 3, episode=8))
    ends, judged = judge_until_the_run_ends(launcher)  # the run loop looks with no end of episode 8 yet
    assert judged is None and sorted(ends) == [6, 7], ends
    assert sorted(e["episode"] for e in launcher.lost_results) == [6, 7]
    hear(EpisodeStatusMsg("done", 9, terminated_by="max_steps", episode=8))
    hear(_result(9, "max_steps", episode=8))
    ends, judged = judge_until_the_run_ends(launcher)
    assert ends == [] and judged is not None and judged[1] is not None and (judged[0].episode, judged[1].episode) == (8, 8), (ends, judged)
    assert sorted(e["episode"] for e in launcher.lost_results) == [6, 7] and launcher.rejected == {}

    # episode 7's end waits for the run loop when episode 8 starts and ends, with its result
    launcher, hear = _launcher_hearing(tmp_path / "3")
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("failed", 9, terminated_by="lockstep_timeout", episode=8))
    hear(_result(9, "lockstep_timeout", episode=8))
    ends, judged = judge_until_the_run_ends(launcher)
    assert judged is not None and judged[1] is not None and (judged[0].episode, judged[0].state, judged[1].episode) == (8, "failed", 8), judged
    assert [e["episode"] for e in launcher.lost_results] == [7]


def test_a_late_result_of_an_episode_before_a_restart_does_not_displace_the_running_episodes(tmp_path):
    """Found by the seeded interleavings below. Episode 8 (the sim restarted into it) ended and its result came; then
    episode 7's end and result, late, from the sim before: the launcher kept the latest result heard, 7's, so 8's end
    found no result of its own, waited 15 s and the run ended with "its result never arrived" and no summary.json. A
    late result of an episode a restart left behind never takes the place of a result of another episode."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    hear(_result(9, "coverage", episode=8))
    hear(EpisodeStatusMsg("failed", 3, terminated_by="lockstep_timeout", episode=7))  # late, of the episode before
    hear(_result(3, "lockstep_timeout", episode=7))  # late too
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 8
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)  # no query answered: pushed only
    assert judged is not None and judged[1] is not None and (judged[0].episode, judged[1].episode, judged[1].steps) == (8, 8, 9), judged
    assert launcher.ended_status is judged[0] and [e["episode"] for e in launcher.lost_results] == [7]


def test_a_replayed_end_of_the_episode_the_run_ends_with_is_not_named_lost(tmp_path):
    """Review of the ends left behind: the run can end on an episode a restart left behind whose own result came. Its
    end heard again (replayed) after the run loop took it waited in ``end_heard``, and ``leave_ends_behind`` named that
    very episode lost (log: "no result of episode 7 came", ``lost_results``), while the run ended with its result."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=7))  # late, of the episode before
    hear(_result(5, "coverage", episode=7))
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == 7
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=7))  # replayed, before the run loop judges it
    judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
    assert judged is not None and judged[1] is not None and (judged[0].episode, judged[1].episode) == (7, 7), judged
    assert launcher.lost_results == [] and launcher.ended_status is judged[0]


def test_ends_left_behind_wait_in_a_bounded_list(tmp_path):
    """Review of the ends left behind: a misbehaving referee replaying the ends of many episodes a restart left behind,
    while an end waits, grew ``ends_behind`` without bound; it keeps the latest ``LOST_RESULTS_KEPT`` (``lost_results``
    names no more)."""
    from cso_runtime.messages import LOST_RESULTS_KEPT

    launcher, hear = _launcher_hearing(tmp_path)
    ids = range(1, 4 * LOST_RESULTS_KEPT + 2)
    for episode in ids:
        hear(EpisodeStatusMsg("starting", 0, episode=episode))
    for episode in ids[:-1]:
        hear(EpisodeStatusMsg("done", 3, terminated_by="coverage", episode=episode))
    assert len(launcher.ends_behind) <= LOST_RESULTS_KEPT
    assert launcher.ends_behind[-1].episode == ids[-2]  # the latest kept


def test_the_episodes_a_restart_left_behind_are_a_bounded_set_that_keeps_the_latest(tmp_path):
    """Review of the ends left behind: ``episodes_before`` grew by one episode per restart of the sim, for good, in a
    long run (``ends_behind`` and ``lost_results`` keep the latest ``LOST_RESULTS_KEPT``). It keeps the latest
    ``EPISODES_BEFORE_KEPT``; a late status of a recent one is still none of the running episode's."""
    from cso_runtime.launcher import EPISODES_BEFORE_KEPT

    launcher, hear = _launcher_hearing(tmp_path)
    ids = range(1, 3 * EPISODES_BEFORE_KEPT + 2)
    for episode in ids:
        hear(EpisodeStatusMsg("starting", 0, episode=episode))
    assert len(launcher.episodes_before) == EPISODES_BEFORE_KEPT
    assert list(launcher.episodes_before) == list(ids[-EPISODES_BEFORE_KEPT - 1 : -1])  # the latest, in order
    hear(EpisodeStatusMsg("exploring", 4, episode=ids[-EPISODES_BEFORE_KEPT - 1]))  # late, of the oldest kept
    assert launcher.episode_running == ids[-1] and launcher.status is not None and launcher.status.episode == ids[-1]
    hear(EpisodeStatusMsg("done", 5, terminated_by="coverage", episode=ids[-2]))  # late end of the episode just before
    over = launcher.episode_end_heard()
    assert over is not None and over.episode == ids[-2] and launcher.of_another_episode(over)


def test_the_log_of_an_end_left_behind_says_its_late_result_came(tmp_path, caplog):
    """Review of the ends left behind: a late result of an episode a restart left behind, heard after the running
    episode's, is not kept; its end, left behind, was logged "no result of episode 7 came", which was untrue."""
    launcher, hear = _launcher_hearing(tmp_path)
    hear(EpisodeStatusMsg("starting", 0, episode=7))
    hear(EpisodeStatusMsg("starting", 0, episode=8))
    hear(EpisodeStatusMsg("done", 9, terminated_by="coverage", episode=8))
    hear(_result(9, "coverage", episode=8))
    hear(EpisodeStatusMsg("failed", 3, terminated_by="lockstep_timeout", episode=7))  # late
    hear(_result(3, "lockstep_timeout", episode=7))  # late too: not kept
    over = launcher.episode_end_heard()
    assert over is not None
    with caplog.at_level("WARNING", logger="cso.launcher"):
        judged = launcher.judge_episode_end(_ScriptedResultQueries([]), over, lambda: None)
    assert judged is not None and judged[0].episode == 8 and [e["episode"] for e in launcher.lost_results] == [7]
    lines = [r.getMessage() for r in caplog.records if "episode 7 ended" in r.getMessage()]
    assert lines and not any("no result of episode 7 came" in line for line in lines), lines
    assert any("its result came" in line for line in lines), lines


# --- the launcher's judgement of an episode's end, over seeded interleavings ---------------------------------------
#
# A history is 1 to 3 episodes, each run by a sim process of its own (a restart between them, ids drawn anew): each
# process sends its statuses, then (maybe: killed before) its end, then its result (the last one's, unless the case is
# "its result lost"; an earlier one's at times, else it died with its sim), and maybe its end once more, in that order;
# the launcher hears the processes' messages merged in a random order that keeps each process's order (a dead process's
# messages come late), the run loop looking in between (``episode_end_heard``, ``judge_episode_end``), and the referee's
# queries and the run loop's tending while a result is awaited are further points where messages arrive.


class _Interleaving:
    """One seeded history and the order it is heard in (``deliveries``), with what the launcher should make of it."""

    def __init__(self, seed: int) -> None:
        rng = self.rng = random.Random(seed)
        count = rng.randint(1, 3)
        self.ids = rng.sample(range(1, 10_000), count)
        self.result_lost = rng.random() < 0.15  # the last episode's result never comes (its sim died after its end)
        self.answers_queries = rng.random() < 0.5  # the last sim answers the queries for its result once it sent it
        self.processes: list[list[Any]] = []
        self.ends: dict[int, EpisodeStatusMsg] = {}
        self.results: dict[int, EpisodeResultMsg] = {}
        self.completed: set[int] = set()  # earlier episodes whose sim sent their result before it died (late, or in time)
        for i, episode in enumerate(self.ids):
            last = i == count - 1
            steps = rng.randint(1, 4)
            sent: list[Any] = [EpisodeStatusMsg("starting", 0, episode=episode)]
            sent += [EpisodeStatusMsg("exploring", s, episode=episode) for s in range(1, steps + 1)]
            if last or rng.random() < 0.6:  # else killed mid-episode: no end
                state, by = rng.choice([("done", "coverage"), ("done", "max_steps"), ("failed", "lockstep_timeout")])
                end = self.ends[episode] = EpisodeStatusMsg(state, steps + 1, terminated_by=by, episode=episode)
                sent.append(end)
                if last and not self.result_lost or not last and rng.random() < 0.35:  # else it died with its sim
                    result = self.results[episode] = _result(steps + 1, by, episode=episode)
                    sent.append(result)
                    if not last:
                        self.completed.add(episode)
                if not last and rng.random() < 0.3:
                    sent.append(EpisodeStatusMsg(state, steps + 1, terminated_by=by, episode=episode))  # replayed
            self.processes.append(sent)
        # A random merge that keeps each process's order, where a sim's first status comes after the first of the sim
        # before it (the launcher heard an episode run before the next one started: ids say no order).
        queues = [list(p) for p in self.processes]
        started = 0
        self.deliveries: list[Any] = []
        while any(queues):
            ready = [i for i, q in enumerate(queues) if q and (i <= started)]
            i = rng.choice(ready)
            self.deliveries.append(queues[i].pop(0))
            if i == started and started + 1 < count:
                started += 1
        self.heard = 0  # how many of ``deliveries`` the launcher heard so far

    @property
    def last(self) -> int:
        return self.ids[-1]

    def delivered(self, msg: Any) -> bool:
        return any(m is msg for m in self.deliveries[: self.heard])

    def describe(self) -> str:
        def said(m: Any) -> str:
            if isinstance(m, EpisodeStatusMsg):
                return f"{m.state}({m.episode}@{m.step})"
            return f"result({m.episode})"

        return (
            f"episodes {self.ids}, completed={sorted(self.completed)}, result_lost={self.result_lost}, answers_queries={self.answers_queries}: "
            + " ".join(said(m) for m in self.deliveries)
        )


class _InterleavedSession:
    """The launcher's session while it awaits a result (``judge_episode_end``): each query first lets the next message
    be heard, and the last sim answers it with its result once it sent it (heard: sent before); each query is half a
    second of the launcher's clock (``clock``), so the 15 s wait ends once nothing more comes."""

    def __init__(self, case: _Interleaving, hear_next: Callable[[], None], clock: list[float]) -> None:
        self.case, self.hear_next, self.clock = case, hear_next, clock

    def get(self, key: str, timeout: float) -> list[Any]:
        from types import SimpleNamespace

        self.clock[0] += 0.5
        self.hear_next()
        result = self.case.processes[-1][-1]
        if not (self.case.answers_queries and isinstance(result, EpisodeResultMsg) and self.case.delivered(result)):
            return []
        return [SimpleNamespace(ok=SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: encode(result))))]


def _run_interleaving(seed: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str | None:
    """Drive the launcher's judgement (``_on_sample``, the run loop's ``episode_end_heard`` and ``judge_episode_end``)
    with seed's interleaving; what went wrong, or None."""
    from types import SimpleNamespace

    import cso_runtime.launcher as launcher_module

    case = _Interleaving(seed)
    rng = case.rng
    clock = [1000.0]
    monkeypatch.setattr(launcher_module, "time", SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    launcher, hear = _launcher_hearing(tmp_path / str(seed))
    launcher.run_dir.mkdir(parents=True)  # run.json names the lost results as they are judged
    launcher.stop_event = SimpleNamespace(is_set=lambda: False, wait=lambda timeout=None: False)  # type: ignore[assignment]

    def hear_next() -> None:
        if case.heard < len(case.deliveries):
            case.heard += 1
            hear(case.deliveries[case.heard - 1])

    def tend() -> None:  # the run loop's supervision between queries: the callbacks run meanwhile too
        if rng.random() < 0.5:
            hear_next()

    session = _InterleavedSession(case, hear_next, clock)
    judged = None
    ended_at = -1
    looks_after_all = 0
    while judged is None and looks_after_all < 3:
        if case.heard < len(case.deliveries) and rng.random() < 0.6:
            hear_next()
            continue
        looks_after_all += case.heard == len(case.deliveries)
        over = launcher.episode_end_heard()  # the run loop looks
        if over is not None and rng.random() < 0.3:
            hear_next()  # the callbacks run between the run loop's look and its judgement too
        if over is not None:
            judged = launcher.judge_episode_end(session, over, tend)
            ended_at = case.heard
    problems = []
    if judged is None:
        problems.append("the run never ended")
    else:
        end, result = judged
        ran = end.episode  # the episode whose end is the run's: the last, or an earlier one whose result came in time
        if ran != case.last and ran not in case.completed:
            problems.append(f"the run ended with episode {ran}'s end, not the last one's ({case.last}), and no result of {ran} was sent")
        if not case.delivered(case.ends[ran]):
            problems.append(f"the run ended before episode {ran}'s end was heard")
        if ran == case.last and case.result_lost:
            if result is not None:
                problems.append(f"a result of episode {result.episode} though the last one's was lost")
        elif result is None:
            problems.append(f"the run ended with no result though episode {ran}'s came")
        else:
            sent = case.results[ran]
            if result.episode != ran or result.steps != sent.steps:
                problems.append(f"the run's result is episode {result.episode}'s, its end episode {ran}'s")
            if not case.delivered(sent):
                problems.append(f"the run ended before episode {ran}'s result was heard")
            if (end.state, end.terminated_by) != (case.ends[ran].state, case.ends[ran].terminated_by):
                problems.append(f"the run ended {end.state}/{end.terminated_by}, episode {ran} {case.ends[ran].state}/{case.ends[ran].terminated_by}")
        if launcher.ended_status is not end or (result is not None and launcher.ended_status.episode != result.episode):
            problems.append(f"meta.episode would be {launcher.ended_status and launcher.ended_status.episode}, the run's end is of {end.episode}")
    # an earlier episode's end heard before the run's end was judged, whose result never came: it went with its sim, and
    # the run says so; one whose result came late may be so too, never the run's
    heard_before_end = case.deliveries[: ended_at if judged is not None else case.heard]
    ends_heard = {m.episode for m in heard_before_end if isinstance(m, EpisodeStatusMsg) and m.state in EPISODE_OVER and m.episode != case.last}
    lost = [e["episode"] for e in launcher.lost_results]
    ran_set = {judged[0].episode} if judged is not None else set()
    if len(lost) != len(set(lost)) or not ends_heard - case.completed - ran_set <= set(lost) <= ends_heard - ran_set:
        problems.append(f"lost_results {lost}, but the ends of earlier episodes heard before the run ended are of {sorted(ends_heard)}")
    if launcher.rejected.get("episode_status", 0):
        problems.append(f"{launcher.rejected['episode_status']} ends counted as strays")
    return f"seed {seed}: {'; '.join(problems)}\n  {case.describe()}" if problems else None


def test_the_launcher_judges_the_run_s_end_alike_over_seeded_interleavings_of_restarts(tmp_path, monkeypatch):
    """300 seeded histories of 1 to 3 episodes (a sim restart between them), heard in random orders a network makes
    possible, with the run loop looking in between: the run ends (never waits for good) once the last episode's end and
    result are heard (or its end, with no result, when that result was lost), never on an earlier episode's end unless
    that episode's own result came, with that end's result (summary.json's meta.episode is its episode);
    ``lost_results`` names, once, each earlier episode whose end was heard before the run's end and whose result never
    came, maybe one whose result came late, never the run's; no end is counted a stray."""
    failures = [f for seed in range(300) if (f := _run_interleaving(seed, tmp_path, monkeypatch)) is not None]
    assert not failures, f"{len(failures)} of 300 interleavings:\n" + "\n".join(failures[:8])


def _launcher_with_a_silent_planner(tmp_path, endpoint: str, embedded: bool, routers: list[str]):
    """A launcher of the lockstep profile joining ``endpoint`` (its own router or none), whose session's routes are
    ``routers`` (the test changes it), supervising a planner that never answers; the caller kills the planner."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), {}, connect=[endpoint], settings={"router.embedded": embedded})
    launcher = Launcher(profile, data, tmp_path / "runs" / "run")
    launcher.run_dir.mkdir(parents=True)
    launcher.session = SimpleNamespace(info=SimpleNamespace(routers_zid=lambda: list(routers)))
    launcher.routers_joined = launcher.count_joined_routers()
    planner = Child("planner", [sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "planner.log")
    launcher.children = [planner]
    planner.spawn()
    launcher.alive_services, launcher.alive_incarnations = {"planner"}, {("planner", planner.incarnation)}  # its own token
    launcher.status_watch = SimpleNamespace(answered_s={"planner": planner.spawned_at}, resumed_s=-np.inf, behind=lambda now: False)
    return launcher, planner


def test_a_lost_external_router_is_named_and_no_service_is_killed_as_hung_for_it(tmp_path, caplog, capsys):
    """A run that joined a router (``--connect``, ``router.embedded: false``) whose router died: every service went
    silent at once and the launcher killed each one as "hung? stopped?", never naming the cause. Its session has no
    route to the router: it says it lost the router at ENDPOINT (log, run.json, ``status``), kills none, and once the
    router is back counts their silence from then."""
    endpoint = loopback_endpoint(free_tcp_port())  # nothing listens there: `status` gets no answer
    routers: list[str] = []
    launcher, planner = _launcher_with_a_silent_planner(tmp_path, endpoint, False, routers)
    launcher.endpoints = [endpoint]
    hang_s = launcher.profile.supervision.hang_timeout_s
    try:
        with caplog.at_level("WARNING", logger="cso.launcher"):
            launcher.kill_hung(planner.spawned_at + hang_s + 10.0)
            assert planner.alive and planner.hung_kills == 0, caplog.text
            assert f"lost the router at {endpoint}" in caplog.text and "hung?" not in caplog.text, caplog.text
            assert json.loads((launcher.run_dir / "run.json").read_text())["lost_router"] == endpoint
            assert status_main([], None, True, False, tmp_path / "runs") == 1
            said = json.loads(capsys.readouterr().out)
            assert f"launcher lost the router at {endpoint}" in said["reason"], said
            routers.append("zid")  # back: the services' silence counts from now
            back_s = planner.spawned_at + hang_s + 20.0
            launcher.kill_hung(back_s)
            assert f"the router at {endpoint} is back after 10 s" in caplog.text and "lost_router" not in json.loads((launcher.run_dir / "run.json").read_text())
            launcher.kill_hung(back_s + hang_s - 0.5)
            assert planner.alive and planner.hung_kills == 0
            launcher.kill_hung(back_s + hang_s + 0.5)
            assert not planner.alive and planner.hung_kills == 1  # silent with the router there: hung
    finally:
        if planner.proc is not None:
            planner.proc.kill()
            planner.proc.wait(timeout=30)


def test_a_lost_router_joined_by_the_runs_own_router_is_named_and_services_are_still_supervised(tmp_path, caplog):
    """With its own router (``router.embedded: true``, the ``limo-ros2`` default) joining the robot's (``--connect``), a
    lost robot router silenced no service (they talk on loopback) and was named nowhere: the launcher says it lost the
    router at ENDPOINT (log, run.json, its status: ``status``'s table and JSON) and that it is back, and a silent
    service is still a hung one."""
    from rich.console import Console

    endpoint = loopback_endpoint(free_tcp_port())
    routers = ["robot's zid"]
    launcher, planner = _launcher_with_a_silent_planner(tmp_path, endpoint, True, routers)
    hang_s = launcher.profile.supervision.hang_timeout_s
    try:
        with caplog.at_level("WARNING", logger="cso.launcher"):
            launcher.kill_hung(planner.spawned_at + 1.0)
            assert "lost the router" not in caplog.text
            routers.clear()  # the robot's bridge died
            launcher.kill_hung(planner.spawned_at + 2.0)
            assert f"lost the router at {endpoint}" in caplog.text and "scans and odometry stop" in caplog.text, caplog.text
            assert json.loads((launcher.run_dir / "run.json").read_text())["lost_router"] == endpoint
            # `status` gets its answers from the run's own router, so it learns of the loss from the launcher's status.
            said = launcher.launcher_status()
            assert decode(encode(said)).lost_router == endpoint
            shown = status_of("r0", None, said.to_dict(), {}, set())
            assert shown["lost_router"] == endpoint
            table = Console(width=200, record=True)
            table.print(render_table(shown))
            assert f"LOST the router at {endpoint}" in table.export_text()
            routers.append("the restarted robot's zid")
            launcher.kill_hung(planner.spawned_at + 5.0)
            assert f"the router at {endpoint} is back after 3 s" in caplog.text
            assert "lost_router" not in json.loads((launcher.run_dir / "run.json").read_text())
            assert launcher.launcher_status().lost_router is None and "lost_router" not in launcher.launcher_status().to_dict()
            routers.clear()
            launcher.kill_hung(planner.spawned_at + hang_s + 10.0)  # reachable on loopback: silent is hung
            assert not planner.alive and planner.hung_kills == 1, caplog.text
    finally:
        if planner.proc is not None:
            planner.proc.kill()
            planner.proc.wait(timeout=30)


def test_a_service_that_never_comes_up_is_killed_to_be_restarted(tmp_path, caplog):
    """A service process that hangs before it declares its liveliness token (a deadlock in an import or the
    warm-up) would show as starting for ever: after ``supervision.start_timeout_s`` it is killed like a hung
    one (``supervise`` then restarts it); one that is up is left to the status-query watch."""
    from types import SimpleNamespace

    from cso_runtime.config import ConfigError
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    with pytest.raises(ConfigError, match="start_timeout_s"):
        load_profile(str(find_profile("lockstep")), settings={"supervision.start_timeout_s": 1.0})
    profile, data = load_profile(str(find_profile("lockstep")), settings={"supervision.start_timeout_s": 5.0})
    launcher = Launcher(profile, data, tmp_path / "run")
    stuck = Child("mapper", [sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "mapper.log")
    up = Child("planner", [sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "planner.log")
    launcher.children = [stuck, up]
    try:
        stuck.spawn()
        up.spawn()
        launcher.alive_services, launcher.alive_incarnations = {"planner"}, {("planner", up.incarnation)}  # its token came: its hangs are the status watch's (none yet)
        launcher.kill_hung(stuck.spawned_at + 4.9)
        assert stuck.alive and up.alive and stuck.hung_kills == 0
        with caplog.at_level("ERROR", logger="cso.launcher"):
            launcher.kill_hung(max(stuck.spawned_at, up.spawned_at) + 100.0)
        assert not stuck.alive and stuck.hung_kills == 1 and up.alive and up.hung_kills == 0
        assert any(r.message.startswith(f"mapper (pid {stuck.proc.pid}) runs but has not come up in 100 s") for r in caplog.records)
        # The planner came up; stopped (SIGSTOP), it loses its token when its lease runs out: hung, not starting.
        launcher.alive_services, launcher.alive_incarnations = set(), set()
        launcher.status_watch = SimpleNamespace(
            answered_s={"planner": up.spawned_at + 200.0}, resumed_s=-np.inf, behind=lambda now: False,  # asking all along
        )
        hang_s = profile.supervision.hang_timeout_s
        launcher.kill_hung(up.spawned_at + 200.0 + hang_s - 0.5)
        assert up.alive and up.hung_kills == 0
        with caplog.at_level("ERROR", logger="cso.launcher"):
            launcher.kill_hung(up.spawned_at + 200.0 + hang_s + 0.5)
        assert not up.alive and up.hung_kills == 1
        assert any(r.message.startswith(f"planner (pid {up.proc.pid}) runs but has not answered for {hang_s + 0.5:.0f} s") for r in caplog.records)
        launcher.status_watch = None
        profile.supervision.start_timeout_s = 0.0  # off: a slow start is never killed
        stuck.spawn()
        launcher.kill_hung(stuck.spawned_at + 1000.0)
        assert stuck.alive and stuck.hung_kills == 1
    finally:
        for c in (stuck, up):
            if c.proc is not None:
                c.proc.kill()
                c.proc.wait(timeout=30)


def test_a_service_that_comes_up_after_hang_timeout_s_is_not_killed_as_hung(tmp_path):
    """The hang check counted a service's silence from its start: one whose start took longer than
    ``hang_timeout_s`` (a loaded machine, a slow import; ``start_timeout_s`` allows 60 s) was killed the moment its
    liveliness token came, before the launcher's status watch had asked it even once, and counted as hung. The
    silence counts from when it came up; one that then never answers is still killed."""
    from types import SimpleNamespace

    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    profile, data = load_profile(str(find_profile("lockstep")), settings={"supervision.hang_timeout_s": 2.0})
    launcher = Launcher(profile, data, tmp_path / "run")
    slow = Child("planner", [sys.executable, "-c", "import time; time.sleep(120)"], tmp_path / "planner.log")
    launcher.children = [slow]
    launcher.status_watch = SimpleNamespace(answered_s={}, resumed_s=-np.inf, behind=lambda now: False)  # asking, not answered yet
    try:
        slow.spawn()
        launcher.kill_hung(slow.spawned_at + 4.0)  # still starting
        launcher.alive_services, launcher.alive_incarnations = {"planner"}, {("planner", slow.incarnation)}
        came_up_s = slow.spawned_at + 5.0  # its token came 5 s after its start
        launcher.kill_hung(came_up_s)
        launcher.kill_hung(came_up_s + 1.5)
        assert slow.alive and slow.hung_kills == 0
        launcher.kill_hung(came_up_s + 2.5)  # up, and silent for longer than hang_timeout_s since
        assert not slow.alive and slow.hung_kills == 1
    finally:
        slow.proc.kill()
        slow.proc.wait(timeout=30)


def test_a_killed_sim_restarts_the_episode_and_it_ends_as_a_fresh_one(tmp_path):
    """The sim is the world: a restarted sim starts a new episode (a new id, step 0). Every other
    service starts over on it (maps of the old episode still in flight are rejected), so in lockstep
    the new episode ends exactly as a fresh in-process episode does."""
    profile = write_profile(tmp_path, min_step_period_s=0.05, lockstep_timeout_s=0.5)
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        endpoints = json.loads((runs / "current.json").read_text())["endpoints"]

        def status() -> dict | None:
            return query_status(endpoints, "r0", timeout_s=0.5)

        first = wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 5 and s, 60, "the episode to run")
        os.kill(first["services"]["sim"]["pid"], signal.SIGKILL)
        wait_for(lambda: (s := status()) and s["services"]["sim"].get("restarts", 0) >= 1 and s["episode"] != first["episode"], 30, "a new episode")
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2)
        expected = in_process_result()
        assert final["state"] == "done" and final["terminated_by"] == expected.terminated_by, final
        assert final["step"] == expected.steps and abs(final["coverage_pct"] - expected.coverage_pct) < 1e-3, final
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def test_the_readme_main_command_explores_with_the_mujoco_limo_and_the_learned_policy(tmp_path):
    """``cso-runtime up --profile sim`` exactly as README runs it (the shipped profile: the MuJoCo LIMO in real
    time, the shipped ``cso`` weights, the embedded router on a free loopback port): every service comes up,
    the policy makes decisions and the map grows; ``save-map`` gets the map; ``down`` leaves no process."""
    runs = tmp_path / "runs"
    try:  # the start inside: a detached run that timed out or failed after spawning is cleaned up too
        r = cli("up", "--profile", "sim", "--detach", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr[-3000:]
        info = json.loads((runs / "current.json").read_text())

        def exploring() -> dict | None:
            s = query_status(info["endpoints"], info["robot"], timeout_s=0.5)
            return s if s and s["state"] == "exploring" and s["decisions"] >= 2 and s["coverage_pct"] > 5.0 else None

        s = wait_for(exploring, 120, "decisions and a growing map", period_s=0.2)
        assert s["method"] == "cso" and s["scene"] == "gen_middle_0" and s["last_decision_ms"] > 0
        assert all(svc["alive"] for svc in s["services"].values()), s["services"]
        r = cli("save-map", "-f", str(tmp_path / "live"), "--format", "png", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0, r.stdout + r.stderr
        grid, _ = load_map(tmp_path / "live.yaml")
        assert (grid == 0).sum() * 0.05**2 > 1.0  # square metres of free space seen
        pids = run_pids(runs)
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr
        assert [p for p in pids if pid_alive(p)] == []
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        kill_leftovers(runs)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP], ids=["ctrl-c", "terminal-closed"])
def test_ctrl_c_stops_a_foreground_run_without_orphans(tmp_path, sig):
    profile = write_profile(tmp_path, min_step_period_s=0.2)
    runs = tmp_path / "runs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cso_runtime.cli", "up", "--profile", str(profile), "--no-live", "--runs-dir", str(runs), "--set", "progress_log_s=0.2"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        info = wait_for(lambda: current_run_with_services(runs, 5), 30, "the services to start")
        # 0.2 s a step: a second of exploring, in which the launcher checks five times a progress line is due
        wait_for(lambda: (s := query_status(info["endpoints"], "r0", 0.5)) and s["step"] >= 6, 60, "the first steps")
        os.killpg(proc.pid, sig)  # what Ctrl-C in a terminal does: the whole foreground group
        # 130, as for eval: a script's `up && next-step` must not go on without the episode's summary.json
        assert proc.wait(timeout=30) == 130
        out = proc.stdout.read().decode()
        assert "interrupted at step" in out
        (run_dir,) = [d for d in runs.iterdir() if d.is_dir()]
        # its first line says which run this is and where its logs and results go, before any service starts
        first = out.splitlines()[0]
        assert first.endswith(f"INFO cso.launcher: run {run_dir.name}: profile lockstep, scene {SCENE}, method greedy-dist, robot r0; logs, then results, in {run_dir}/"), out
        # its last line says what the interrupted run kept, and where: the episode's map so far too (it kept only its
        # profile and logs: minutes of mapping were lost to a Ctrl-C unless `save-map` had been run just before)
        last = out.rstrip().splitlines()[-1]
        kept = re.search(rf"no results: the episode's map at step (\d+) is in {re.escape(str(run_dir))}/last_map\.yaml; the run's profile and logs are in ", last)
        assert kept and last.endswith(f"{run_dir}/ (`cso-runtime logs --run {run_dir}`)"), out
        grid, _ = load_map(run_dir / "last_map.yaml")
        assert int(kept.group(1)) >= 6 and (grid == 0).sum() > 100 and (run_dir / "last_map.png").exists()
        # without a live view, a followed log is never silent: the episode's progress every progress_log_s
        # (with the sim's real-time factor, at most about 1.25x at 0.2 s a step of 0.25 s, once two statuses have come)
        line = r"INFO cso\.launcher: step \d+ \([\d.]+ s robot time(, [\d.]+x real time)?\): coverage [\d.]+ %, [\d.]+ m2 explored"
        assert re.search(line, out), out
        assert re.search(r"s robot time, [01]\.\d\dx real time\)", out), out
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
        (run_file,) = runs.glob("*/run.json")
        assert json.loads(run_file.read_text())["state"] == "stopped" and not (runs / "current.json").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
        kill_leftovers(runs)


def test_a_closed_terminal_stops_a_foreground_run_with_its_live_view_cleanly(tmp_path):
    """``up`` in a terminal (its live view on) whose terminal then closes (a window closed, an ssh link lost): the
    kernel's SIGHUP stopped the run, and the live view's last redraw then met the gone terminal (EIO) in the launcher's
    clean-up, before it stopped anything: the launcher died with a traceback nobody saw, its services went only by
    their PR_SET_PDEATHSIG, and run.json said "running" for good (``runs``: launcher died). A real pseudo-terminal
    here, closed as a terminal emulator closes it; the run stops as on Ctrl-C."""
    import pty

    profile = write_profile(tmp_path, min_step_period_s=0.2)
    runs = tmp_path / "runs"
    master, slave = pty.openpty()
    # A session of its own whose controlling terminal is the pty, as a terminal emulator starts its shell; then `up`.
    in_a_terminal = "import fcntl, os, sys, termios; os.setsid(); fcntl.ioctl(0, termios.TIOCSCTTY, 0); os.execv(sys.argv[1], sys.argv[1:])"
    up = [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(profile), "--runs-dir", str(runs)]
    proc = subprocess.Popen([sys.executable, "-c", in_a_terminal, *up], cwd=tmp_path, stdin=slave, stdout=slave, stderr=slave)
    os.close(slave)
    shown = bytearray()

    def drain() -> None:  # as a terminal does: the live view's redraws must not fill the pty's buffer
        with contextlib.suppress(OSError):
            while chunk := os.read(master, 65536):
                shown.extend(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        info = wait_for(lambda: current_run_with_services(runs, 5), 30, "the services to start")
        wait_for(lambda: (s := query_status(info["endpoints"], "r0", 0.5)) and s["step"] >= 3, 60, "the first steps")
        assert b"coverage" in shown  # the live view was drawing on the terminal
        os.close(master)  # the terminal closes: SIGHUP to its session's leader, and every later write to it fails
        master = -1
        proc.wait(timeout=30)
        (run_file,) = runs.glob("*/run.json")
        run = json.loads(run_file.read_text())
        assert (run["state"], run.get("outcome")) == ("stopped", "interrupted"), run
        launcher_log = (run_file.parent / "logs" / "launcher.log").read_text()
        assert "services stopped in" in launcher_log and "stopping: the launcher" not in (run_file.parent / "logs" / "sim.log").read_text(), launcher_log
        assert [p for p in run_pids(runs) if pid_alive(p)] == [] and not (runs / "current.json").exists()
    finally:
        if master >= 0:
            os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        kill_leftovers(runs)


def test_a_run_whose_output_pipe_is_closed_ends_cleanly(tmp_path):
    """``cso-runtime up | head -5``: the reader gone, the live view's table at the end met a broken pipe, on which
    rich raises SystemExit(1) (``Console.on_broken_pipe``): it flew through the launcher's clean-up, the services were
    never stopped (their PR_SET_PDEATHSIG did it), run.json kept the episode's end ("done", not stopped) and ``up``
    exited 1 with nothing said. The view stops drawing and the run ends as it would have."""
    profile = write_profile(tmp_path)
    runs = tmp_path / "runs"
    proc = subprocess.Popen(
        [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(profile), "--runs-dir", str(runs)],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    proc.stdout.close()  # the reader is gone before anything is written
    try:
        assert proc.wait(timeout=120) == 0
        (run_file,) = runs.glob("*/run.json")
        run = json.loads(run_file.read_text())
        assert (run["state"], run.get("outcome")) == ("stopped", "done"), run
        launcher_log = (run_file.parent / "logs" / "launcher.log").read_text()
        assert "the live view stops: its terminal is gone (Broken pipe)" in launcher_log and "services stopped in" in launcher_log, launcher_log
        assert (run_file.parent / "summary.json").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        kill_leftovers(runs)


def test_service_command_help_lists_the_services_own_options():
    """``cso-runtime service NAME --help`` is the service's help (its --config, --listen, ... and extra
    options), under the name it was run by; without a name it is the command's help, and exit 2."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    r = CliRunner().invoke(app, ["service", "planner", "--help"])
    assert r.exit_code == 0 and "usage: cso-runtime service planner" in r.output
    assert "--config CONFIG" in r.output and "--listen LISTEN" in r.output
    r = CliRunner().invoke(app, ["service"])
    assert r.exit_code == 2 and "sim, mapper, frontier, policy, planner" in r.output
    r = CliRunner().invoke(app, ["service", "bogus"])
    assert r.exit_code == 2 and "unknown service 'bogus'" in r.output


def test_every_command_renders_its_help_with_its_summary():
    """Each command's ``--help`` works (typer builds it from the signature: a bad annotation fails here, not in a
    user's terminal) and starts with the command's own summary; the top-level help lists every command."""
    from typer.main import get_command
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    top = CliRunner().invoke(app, ["--help"], terminal_width=200)
    assert top.exit_code == 0
    commands = get_command(app).commands
    assert {"eval", "up", "status", "down", "record", "replay", "export-bag", "save-map", "train"} <= set(commands)
    for name, command in commands.items():
        if name == "service":  # its help is the service's own (the test above)
            continue
        r = CliRunner().invoke(app, [name, "--help"], terminal_width=200)
        summary = " ".join((command.help or "").split())[:40]
        assert r.exit_code == 0, (name, r.output)
        assert summary and summary in " ".join(r.output.replace("│", " ").split()), name
        assert name in top.output


def test_shell_completion_offers_profiles_methods_runs_and_service_logs(tmp_path, monkeypatch, capsys):
    """``cso-runtime --install-completion`` (typer/click): the values a user types most come from what exists:
    profile names, methods (the last of a comma list), run ids and the services with a log in the run."""
    from cso_runtime.cli import main
    from tests.test_runs import make_run

    runs = tmp_path / "runs"
    make_run(runs, "20261203-091000-lockstep-r0", outcome="done", logs={"sim": "", "mapper": ""})
    make_run(runs, "20261203-091100-lockstep-r0", outcome="done", logs={"planner": ""})

    def completion_env(line: str) -> dict[str, str]:
        return {"_CSO_RUNTIME_COMPLETE": "complete_bash", "COMP_WORDS": line, "COMP_CWORD": str(len(line.split(" ")) - 1)}

    def complete_in_a_process(line: str) -> list[str]:
        """As the shell asks: the script run with the completion variables."""
        env = {**os.environ, **completion_env(line)}
        r = subprocess.run([sys.executable, "-m", "cso_runtime.cli"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        return r.stdout.split()

    def complete(line: str) -> list[str]:
        """The same entry point (``main``) in this process: a second of interpreter start-up less per line."""
        monkeypatch.chdir(tmp_path)
        with monkeypatch.context() as m:
            for name, value in completion_env(line).items():
                m.setenv(name, value)
            m.setattr(sys, "argv", ["cso-runtime"])
            with pytest.raises(SystemExit) as exited:
                main()
        out, err = capsys.readouterr()
        assert exited.value.code in (0, None), err
        return out.split()

    assert complete_in_a_process("cso-runtime up --profile ") == complete("cso-runtime up --profile ") == ["limo-ros2", "lockstep", "sim"]
    assert complete("cso-runtime eval --method greedy-dist,cso-n") == ["greedy-dist,cso-no-info", "greedy-dist,cso-no-mask"]
    assert complete("cso-runtime eval --method cso,a") == ["cso,all"]  # a group, in eval's list only
    assert complete("cso-runtime up --method a") == []
    assert complete("cso-runtime up --method greedy-") == ["greedy-dist", "greedy-info"]
    assert complete("cso-runtime up --profile lockstep --without ") == ["mapper", "frontier", "policy", "planner"]  # never the sim
    assert complete("cso-runtime up --profile lockstep --without policy --without p") == ["planner"]
    assert complete(f"cso-runtime logs --runs-dir {runs} --run 2026") == ["20261203-091100-lockstep-r0", "20261203-091000-lockstep-r0"]
    assert complete(f"cso-runtime logs --runs-dir {runs} --run 20261203-091000-lockstep-r0 sim ") == ["mapper"]
    assert complete(f"cso-runtime logs --runs-dir {runs} ") == ["planner"]  # the newest run's
    assert "--install-completion" in cli("--help", cwd=tmp_path).stdout


def test_restarts_older_than_the_restart_window_no_longer_count_towards_giving_up(tmp_path):
    """A robot running for hours keeps a service that crashes now and then (systemd's StartLimitIntervalSec): only
    the restarts within ``supervision.restart_window_s`` count towards ``max_restarts`` and the back-off, while
    ``restarts`` (what ``status`` shows) counts them all; with the window at 0 every restart of the run counts."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.supervision import Child

    def crashing_launcher(window_s: float, name: str) -> tuple[Launcher, Child]:
        sup = {"max_restarts": 2, "restart_window_s": window_s, "backoff_s": 1.0, "backoff_max_s": 8.0, "hang_timeout_s": 0, "start_timeout_s": 0}
        profile, data = load_profile(str(find_profile("lockstep")), {"supervision": sup})
        launcher = Launcher(profile, data, tmp_path / name)
        launcher.run_dir.mkdir()
        child = Child("mapper", [sys.executable, "-c", "raise SystemExit(1)"], tmp_path / f"{name}.log")
        launcher.children = [child]
        child.spawn()
        return launcher, child

    def crash_and_restart(launcher: Launcher, child: Child, at_s: float) -> float:
        """The child's crash seen at ``at_s``, then its restart once the back-off has passed; when it is restarted."""
        child.proc.wait(timeout=30)
        launcher.supervise(at_s)
        if child.gave_up:
            return at_s
        restart_s = child.restart_at
        launcher.supervise(restart_s)
        return restart_s

    t0 = time.monotonic()
    windowed, child = crashing_launcher(100.0, "windowed")
    t = crash_and_restart(windowed, child, t0)  # back-off 1 s
    assert child.restarts == 1 and t == t0 + 1.0
    t = crash_and_restart(windowed, child, t + 1.0)  # back-off 2 s: the first restart is recent
    assert child.restarts == 2 and t == t0 + 4.0
    t = crash_and_restart(windowed, child, t + 150.0)  # both restarts are older than the window: back-off 1 s again
    assert child.restarts == 3 and not child.gave_up and t == t0 + 155.0
    t = crash_and_restart(windowed, child, t + 1.0)
    assert child.restarts == 4 and not child.gave_up
    crash_and_restart(windowed, child, t + 1.0)  # two restarts within 100 s: given up
    assert child.gave_up and child.restarts == 4

    whole_run, child = crashing_launcher(0.0, "whole_run")
    t = crash_and_restart(whole_run, child, t0)
    t = crash_and_restart(whole_run, child, t + 1.0)
    crash_and_restart(whole_run, child, t + 1000.0)
    assert child.gave_up and child.restarts == 2


def test_status_and_save_map_show_a_map_scenes_goal_and_map_in_its_map_frame(tmp_path):
    """A map_server scene's ``origin`` was lost on the network: ``status`` showed the goal in the scene's own frame
    and ``save-map`` wrote ``origin: [0, 0, 0]``, off the user's map in RViz. The sim's episode status carries the
    scene's ``map_origin``; both now show the map frame."""
    from rich.console import Console

    from cso_runtime.live_view import progress_line
    from cso_runtime.status import render_table

    port = free_tcp_port()
    keys = RobotKeys("r0")
    origin = Pose2D(-3.5, 2.0, 0.0)
    episode = encode(EpisodeStatusMsg("exploring", 5, scene="office", method="greedy-dist", goal_xy_m=[1.0, 1.5], episode=3, map_origin=origin))
    explored = np.zeros((4, 6), dtype=bool)
    explored[1:3, 1:5] = True
    grid_map = encode(MapMsg(5, GridGeometry(0.5, (4, 6)), explored, np.zeros_like(explored), 3))
    assert progress_line(decode(episode, EpisodeStatusMsg), 0.25).endswith("goal (-2.50, 3.50) m")  # up's log and live view
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        held = [
            session.declare_queryable(keys.episode_status, lambda query: query.reply(keys.episode_status, episode)),
            session.declare_queryable(keys.cache("map"), lambda query: query.reply(keys.cache("map"), grid_map)),
        ]
        try:
            status = query_status([loopback_endpoint(port)], "r0")
            assert status is not None and status["goal"] == pytest.approx([-2.5, 3.5]) and status["map_origin"] == [-3.5, 2.0, 0.0]
            console = Console(width=120, record=True)
            console.print(render_table(status))
            assert "(-2.50, 3.50) m" in console.export_text()
            assert save_map_main([loopback_endpoint(port)], "r0", tmp_path / "m", "pgm", tmp_path) == 0
        finally:
            for h in held:
                h.undeclare()
    assert yaml.safe_load((tmp_path / "m.yaml").read_text())["origin"] == [-3.5, 2.0, 0.0]
    grid, geometry = load_map(tmp_path / "m.yaml")
    assert geometry == GridGeometry(0.5, (4, 6), -3.5, 2.0) and (grid == 0).sum() == explored.sum()


def test_up_writes_a_map_scenes_final_map_at_the_scenes_map_origin(tmp_path):
    """``up``'s ``maps/<method>/<map>.yaml`` of a map_server scene: at the scene's ``origin`` (the episode result's
    ``map_origin``), not [0, 0, 0], so it overlays the user's map; the npz keeps the plan-frame trajectory beside it."""
    from cso_runtime.launcher import write_episode_outputs
    from cso_runtime.messages import EpisodeResultMsg

    free = np.ones((4, 6), bool)
    final = MapMsg(9, GridGeometry(0.5, (4, 6)), free, np.zeros_like(free), 1)
    res = EpisodeResultMsg(
        "office", 9, 6.0, 100.0, 6.0, 2.5, "coverage", 2, np.ones(2), np.array([[1.0, 1.0], [2.0, 1.0]]), np.array([50.0, 100.0]), free, free, 0.5,
        "greedy-dist", 0, final, Pose2D(-3.5, 2.0, 0.0),
    )
    write_episode_outputs(tmp_path, res, wall_s=1.0, meta={})
    assert yaml.safe_load((tmp_path / "maps" / "greedy-dist" / "office.yaml").read_text())["origin"] == [-3.5, 2.0, 0.0]
    npz = np.load(tmp_path / "episodes" / "greedy-dist" / "office.npz")
    np.testing.assert_array_equal(npz["map_origin"], [-3.5, 2.0, 0.0])
    np.testing.assert_array_equal(npz["trajectory"], [[1.0, 1.0], [2.0, 1.0]])


def test_ups_summary_json_and_episodes_csv_say_why_the_episode_ended_no_frontier(tmp_path):
    """``up`` writes eval's summary.json and episodes.csv for its episode: the result's ``ended_why`` (the frontier
    service's reason, which the launcher's line ends with) is in both, as eval writes it; empty for another end."""
    import dataclasses

    from cso_runtime.launcher import write_episode_outputs

    why = "no frontier left: 3 frontier cells, all given up around goals reached"
    for result, said in ((dataclasses.replace(_fake_result(), terminated_by="no_frontier", ended_why=why), why), (_fake_result(), "")):
        out = tmp_path / result.terminated_by
        write_episode_outputs(out, result, wall_s=1.0, meta={})
        with (out / "episodes.csv").open(newline="") as fh:
            (row,) = csv.DictReader(fh)
        assert (row["terminated_by"], row["ended_why"]) == (result.terminated_by, said)
        entry = json.loads((out / "summary.json").read_text())["methods"]["greedy-dist"]
        assert entry["ended_why"] == ([{"map": "s", "seed": 0, "why": why}] if said else [])


def test_pause_holds_a_real_time_robot_still_and_resume_lets_the_episode_finish(tmp_path):
    """``cso-runtime pause`` on a real-time run: the robot holds still (odometry's pose the same, its twist zero, over
    several steps) while the sim's time goes on, ``status`` says who paused it and for how long, a planner restarted
    meanwhile stays paused (the launcher's ``cache/explore/resume``), the frontier service asks the policy for no
    decision over more than ``replan_every_steps`` paused steps, and ``resume`` lets the episode finish, its summary
    saying how long the robot stood (``paused_s``). With nothing running both commands say so (exit 1).

    The pause goes out from the test's own session as soon as odometry shows the robot moving, in Zenoh's order with
    the steps: sent by a ``cso-runtime pause`` started then, it landed seconds later on a loaded host, after this small
    scene's episode had ended (38 steps at twice real time), and the robot never stood "paused". The command then
    finds the robot paused. Every wait is on its condition, bounded only against a hang (``HANG_DEADLINE_S``)."""
    from cso_runtime.messages import ExploreResumeMsg, FrontiersMsg
    from cso_runtime.status import operator_name

    runs = tmp_path / "runs"
    for command in ("pause", "resume"):
        r = cli(command, "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
        assert r.returncode == 1 and "nothing running" in r.stdout, (r.stdout, r.stderr)
    # Real time at twice the wall clock's pace: the test waits on steps (the robot moving, standing, the end).
    settings = ["scene=generated:small:1:0", "method=greedy-dist", "services.sim.backend=kinematic", "services.sim.real_time_factor=2", "services.frontier.layer_helper=false", "progress_log_s=0"]
    try:
        r = cli("up", "--profile", "sim", "--detach", "--runs-dir", str(runs), *[a for s in settings for a in ("--set", s)], cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
        assert r.returncode == 0, r.stderr[-3000:]
        info = json.loads((runs / "current.json").read_text())

        def status() -> dict | None:
            return query_status(info["endpoints"], "r0", timeout_s=0.5)

        odoms: list[tuple[int, Pose2D, tuple[float, float]]] = []  # step, pose, twist
        pause = encode(ExploreResumeMsg(False, operator_name(), "inspecting", time.time()))
        paused_at: list[int] = []  # how many odometry steps had come when the pause went out
        with open_session(TransportConfig(mode="client", connect=info["endpoints"])) as session:

            def on_odom(sample: Any) -> None:
                m = decode(sample.payload.to_bytes(), OdometryMsg)
                odoms.append((m.step, m.pose, (m.twist.linear_mps, m.twist.angular_radps)))
                moved_m = float(np.hypot(*(np.array(m.pose.xy) - np.array(odoms[0][1].xy))))
                if not paused_at and m.step >= 4 and moved_m > 0.1:  # the robot moving: pause it, before its next steps
                    session.put(RobotKeys("r0").explore_resume, pause)
                    paused_at.append(len(odoms))

            sub = session.declare_subscriber(RobotKeys("r0").odom, on_odom)
            decided: list[int] = []  # the steps the frontier service asked the policy to decide
            asks = session.declare_subscriber(RobotKeys("r0").frontiers, lambda sample: (f := decode(sample.payload.to_bytes(), FrontiersMsg)).decide and decided.append(f.step))
            wait_for(lambda: paused_at and (s := status()) and s["pause"]["paused"], HANG_DEADLINE_S, "the robot moving, then paused", period_s=0.1)
            r = cli("pause", "--reason", "inspecting", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
            assert r.returncode == 0 and "robot r0" in r.stdout and "already paused" in r.stdout, (r.stdout, r.stderr)

            def still_for(n: int) -> list | None:
                """The last ``n`` odometry steps since the pause, when the robot stood through all of them."""
                after = odoms[paused_at[0] :]
                stood = [o for o in after if abs(o[2][0]) < 1e-6 and abs(o[2][1]) < 1e-6]
                if len(stood) < n or stood[-n:] != after[-n:]:
                    return None
                last = after[-n:]
                return last if all(np.allclose(o[1].as_list(), last[0][1].as_list(), atol=1e-6) for o in last) else None

            held = wait_for(lambda: still_for(8), HANG_DEADLINE_S, "eight steps standing still", period_s=0.1)
            assert held[-1][0] - held[0][0] == 7  # consecutive steps: the sim's time goes on
            s = wait_for(lambda: (t := status()) and t["services"]["planner"].get("state") and t, HANG_DEADLINE_S, "the planner's status")
            assert s["state"] == "exploring" and s["pause"]["paused"] and s["pause"]["reason"] == "inspecting", s
            assert s["services"]["planner"]["reason"].startswith("paused: by "), s["services"]["planner"]
            assert s["services"]["frontier"]["reason"].startswith("paused: by "), s["services"]["frontier"]
            r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
            assert r.returncode == 0 and re.search(r"exploring; paused \(by \S+@\S+, for \d+ s\): inspecting", r.stdout), r.stdout
            r = cli("pause", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
            assert r.returncode == 0 and "already paused" in r.stdout, r.stdout

            os.kill(s["services"]["planner"]["pid"], signal.SIGKILL)  # a planner restarted while paused stays paused
            wait_for(lambda: (t := status()) and t["services"]["planner"].get("restarts", 0) >= 1 and t["services"]["planner"].get("reason", "").startswith("paused"), HANG_DEADLINE_S, "the planner back, paused")
            restarted_at = len(odoms)
            replan_every_steps = ExplorationConfig().episode.replan_every_steps
            wait_for(lambda: len(odoms) >= restarted_at + 8 and odoms[-1][0] > held[0][0] + replan_every_steps + 4, HANG_DEADLINE_S, "more steps")
            assert all(abs(o[2][0]) < 1e-6 and abs(o[2][1]) < 1e-6 for o in odoms[restarted_at:]), odoms[restarted_at:]
            assert [k for k in decided if k >= held[0][0]] == [], decided  # no goal chosen while paused
            sub.undeclare()
            asks.undeclare()

        r = cli("resume", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
        assert r.returncode == 0 and "resumed robot r0" in r.stdout, (r.stdout, r.stderr)
        final = wait_for(lambda: (s := status()) and s["state"] in ("done", "failed") and s, HANG_DEADLINE_S, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and not final["pause"]["paused"] and final["pause"]["total_s"] > 1.0, final
        summary = wait_for(lambda: next(iter(runs.glob("*/summary.json")), None), HANG_DEADLINE_S, "summary.json")
        assert json.loads(summary.read_text())["meta"]["paused_s"] > 1.0
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=HANG_DEADLINE_S)
        assert kill_leftovers(runs) == []


def test_a_planner_killed_mid_episode_comes_back_with_the_contacts_of_its_episode(tmp_path):
    """SIGKILL of the planner mid-episode: the launcher restarts it, and the new planner starts from the contacts the
    sim keeps (``cache/planner/contacts``) instead of none, so its paths still keep off what the robot bumped into;
    the episode completes. A contact comes from a stall against a wall no scan shows (the depth camera's), which this
    360-degree scene never has: the test sends the planner's message itself, contacts on the scene's walls (they
    change no path), and the first planner, which never heard them, keeps none.

    The contacts are of a step the planner has commanded (the step of its state in the sim's cache), as another
    sender's are: a planner's own contacts of a later step than its cached state were sent by one killed before that
    step's command, which the restarted one commands again, adding them again, so the restore drops them
    (``PlannerService.contacts_of``). Sent as of the step ``status`` showed, in flight and not yet commanded, they were
    dropped whenever the kill came before its command (a loaded host): the planner came back with none."""
    profile = write_profile(tmp_path, min_step_period_s=0.25, lockstep_timeout_s=0.5)  # 36 steps: at least 9 s
    plan = resolve_scenes(SCENE)[0].load()
    walls = np.argwhere(~plan.free)[:2]
    contacts = np.stack(plan.geometry.cell_to_world(walls[:, 0], walls[:, 1]), axis=1)
    runs = tmp_path / "runs"
    keys = RobotKeys("r0")
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        info = wait_for(lambda: current_run_with_services(runs, 5), 30, "the services to start")

        def status() -> dict | None:
            return query_status(info["endpoints"], "r0", timeout_s=0.5)

        s = wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2 and s["services"]["planner"].get("counters") is not None and s, 60, "the episode to start")
        assert s["services"]["planner"]["counters"].get("contacts") == 0, s["services"]["planner"]
        with open_session(TransportConfig(mode="client", connect=info["endpoints"])) as session:

            def commanded() -> int | None:
                """The step of the planner's state in the sim's cache: a step the planner has commanded."""
                kept = [decode(rep.ok.payload.to_bytes(), PlannerStateMsg) for rep in session.get(keys.cache("planner_state"), timeout=1.0) if rep.ok]
                return kept[0].step if kept and kept[0].episode == s["episode"] else None

            step = wait_for(lambda: (k := commanded()) is not None and k >= 1 and k, 20, "the planner's state in the sim's cache")
            sent = encode(PlannerContactsMsg(step, contacts, s["episode"]))

            def cached() -> PlannerContactsMsg | None:
                session.put(keys.topic("planner_contacts"), sent)  # again until kept: the sim keeps the latest, the same
                replies = [decode(rep.ok.payload.to_bytes(), PlannerContactsMsg) for rep in session.get(keys.cache("planner_contacts"), timeout=1.0) if rep.ok]
                return next((m for m in replies if len(m.contacts_xy_m)), None)  # type: ignore[attr-defined]

            kept = wait_for(cached, 20, "the sim to keep the contacts")
            assert (kept.step, kept.episode) == (step, s["episode"]) and np.array_equal(kept.contacts_xy_m, contacts)
        planner_pid = s["services"]["planner"]["pid"]
        os.kill(planner_pid, signal.SIGKILL)
        back = wait_for(
            lambda: (t := status()) and t["services"]["planner"].get("restarts", 0) >= 1 and (t["services"]["planner"].get("counters") or {}).get("contacts") == 2 and t,
            60, "the planner restarted with the two contacts",
        )  # fmt: skip
        assert back["services"]["planner"]["pid"] != planner_pid
        log_text = next(runs.glob("*/logs/planner.log")).read_text()
        assert re.search(rf"restored 2 contacts of step {step} \(episode {s['episode']}\) from the cache", log_text), log_text[-3000:]
        final = wait_for(lambda: (t := status()) and t["state"] in EPISODE_OVER and t, 90, "the end of the episode", period_s=0.2)
        assert final["state"] == "done" and final["terminated_by"] == "coverage", final
        assert final["services"]["planner"]["counters"]["contacts"] == 2  # to the end of the episode
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def test_a_planner_killed_mid_episode_carries_on_with_its_goal_and_the_episode_ends_as_the_uninterrupted_one(tmp_path):
    """SIGKILL of the planner while it follows a goal: the restarted planner resumes from the state and plan the sim keeps
    (``cache/planner/state``, ``cache/planner/plan``), the same goal, path and counters, instead of reporting idle (which
    made the frontier service ask for a new goal, and the episode another one). The sim holds the step in flight until
    the new planner commands it, so the lockstep episode ends exactly as the uninterrupted in-process one: the same
    steps, coverage, decisions, trajectory and final map. The in-process episode decides on every step to step 18 and then
    keeps its goal to step 26: a kill in steps 20 to 23 lands mid-goal (before, the restarted planner's idle report cost a
    decision and a step: 25 decisions, 37 steps, another trajectory)."""
    profile = write_profile(tmp_path, min_step_period_s=0.3, lockstep_timeout_s=0.5)  # 36 steps: at least 11 s
    expected = in_process_result()
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        info = wait_for(lambda: current_run_with_services(runs, 5), 30, "the services to start")

        def status() -> dict | None:
            return query_status(info["endpoints"], "r0", timeout_s=0.5)

        with open_session(TransportConfig(mode="client", connect=info["endpoints"])) as session:

            def commanded_mid_goal() -> int | None:
                """A step of 20 to 23 that the planner has commanded: its state of that step in the sim's cache (it rides on
                the step's ``cmd_vel``: no window leaves the cache behind the sim any more; a planner killed before it
                commands the next step leaves this state, from which the next one commands that step). The state restored
                is of that step or later. The sim need not be between the two steps still: it holds a commanded step only
                for what is left of ``min_step_period_s`` once the step's chain is done, nothing on a host slow enough that
                the chain takes longer, where a wait on the sim's step being the state's saw no such moment in steps 20 to
                23. The states of steps 20 to 23 are in the cache over at least three periods (0.9 s), whatever the host."""
                kept = [decode(rep.ok.payload.to_bytes(), PlannerStateMsg) for rep in session.get(RobotKeys("r0").cache("planner_state"), timeout=0.5) if rep.ok]
                return kept[0].step if kept and kept[0].episode == s["episode"] and 20 <= kept[0].step <= 23 else None

            s = wait_for(lambda: (t := status()) and t["state"] == "exploring" and t["services"]["planner"].get("pid") and t, 60, "the episode to start")
            step = wait_for(commanded_mid_goal, 60, "the planner's state of one of the episode's steps 20 to 23")
            os.kill(s["services"]["planner"]["pid"], signal.SIGKILL)
        final = wait_for(lambda: (t := status()) and t["state"] in EPISODE_OVER and t, 90, "the end of the episode", period_s=0.2)
        assert final["services"]["planner"]["restarts"] >= 1 and final["services"]["planner"]["pid"] != s["services"]["planner"]["pid"]
        log_text = next(runs.glob("*/logs/planner.log")).read_text()
        restored = re.search(r"restored the state of step (\d+) \(episode (\d+)\) from the cache: the goal \(\S+, \S+\) of step (\d+)", log_text)
        assert restored, log_text[-3000:]
        assert int(restored[1]) >= step and int(restored[2]) == s["episode"] and 0 <= int(restored[3]) < int(restored[1])  # mid-goal
        assert "behind the episode" not in log_text  # the state rides on the step's cmd_vel: never behind the sim
        assert (final["state"], final["terminated_by"], final["step"]) == ("done", expected.terminated_by, expected.steps), final
        assert abs(final["coverage_pct"] - expected.coverage_pct) < 1e-3 and final["decisions"] == expected.decisions, final
        out = Path(info["run_dir"])
        npz = wait_for(lambda: next(iter(out.glob("episodes/greedy-dist/*.npz")), None), 30, "the episode's results")
        np.testing.assert_allclose(np.load(npz)["trajectory"], expected.trajectory_xy_m, atol=1e-9)
        grid, geometry = load_map(next(iter(out.glob("maps/greedy-dist/*.yaml"))))
        assert geometry == expected.map_geometry and np.array_equal(grid, expected.map_grid)
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def test_status_after_the_episode_still_says_where_the_robot_ended(tmp_path):
    """``status`` shows the robot's pose and twist in the map frame during the episode (episode_status v4), but once
    the sim no longer answered (the episode over and the run stopping, or the sim hung) it showed the launcher's
    last-heard status (``last_episode``), which had no pose: "-", where a ROS 2 user asks where the robot ended. The
    launcher's record now carries the last status's ``pose``, ``twist`` and ``map_origin`` as episode_status has
    them, so ``status`` says where it ended, in the same map frame; an older launcher's record (none of them) says "-"."""
    import dataclasses

    from rich.console import Console

    from cso_runtime.geometry import VelocityCommand
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    origin, pose, twist = Pose2D(1.0, -2.0, math.pi / 2), Pose2D(0.5, 0.25, 0.1), VelocityCommand(0.2, -0.1)
    ended = EpisodeStatusMsg("done", 90, "s", "cso", 99.5, 40.0, 12.25, None, 9, terminated_by="coverage", episode=7, map_origin=origin, pose=pose, twist=twist)
    launcher.status, launcher.status_heard_at_s = ended, time.monotonic()
    heard = decode(encode(launcher.launcher_status()), LauncherStatusMsg).to_dict()  # as `status` gets it, the sim gone
    shown = status_of("r0", None, heard, {}, set())
    fresh = status_of("r0", ended.to_dict(), heard, {}, set())  # what it showed while the sim answered
    assert shown["state"] == "done" and shown["step"] == 90
    assert shown["pose"] == pytest.approx(fresh["pose"]) and shown["pose"] == pytest.approx(ended.pose_in_map_frame.as_list())
    assert shown["twist"] == fresh["twist"] == [0.2, -0.1] and shown["map_origin"] == fresh["map_origin"]
    console = Console(width=200, record=True)
    console.print(render_table(shown))
    x, y, yaw = ended.pose_in_map_frame.as_list()
    assert f"x {x:.2f} m  y {y:.2f} m  yaw {yaw:.2f} rad, 0.20 m/s -0.10 rad/s" in console.export_text()
    older = {**heard, "last_episode": {k: v for k, v in heard["last_episode"].items() if k not in ("pose", "twist", "map_origin")}}
    assert status_of("r0", None, older, {}, set())["pose"] is None
    launcher.status = dataclasses.replace(ended, pose=None, twist=None)  # a ROS 2 bridge before its first scan
    last = decode(encode(launcher.launcher_status()), LauncherStatusMsg).last_episode
    assert last is not None and (last["pose"], last["twist"]) == (None, None)


def test_up_says_why_an_episode_ended_no_frontier_as_the_in_process_episode_does(tmp_path):
    """A corridor (a map_server scene) whose start faces away from 0.4 m of dead end behind the 180-degree LiDAR
    (tests/test_planner.py's): the episode ends no_frontier at 88 % after 2 steps. ``up`` said only "no_frontier",
    read as a bug; the frontier service now says why, with the in-process episode's words (``ended_no_frontier_why``),
    and the launcher's line and ``status`` (the sim's, and the launcher's last-heard once the sim is gone) show it."""
    free = np.zeros((22, 64), dtype=bool)
    free[2:20, 2:62] = True  # the corridor of tests/test_planner.py: 3.0 x 0.9 m at 0.05 m cells
    scene = save_map(tmp_path / "corridor.yaml", np.where(free, 0, 100).astype(np.int8), GridGeometry(0.05, free.shape))
    scene.write_text(scene.read_text() + "start: [0.5, 0.5, 0.0]\n")
    expected = in_process_result(str(scene))
    assert expected.terminated_by == "no_frontier" and "given up around goals reached" in expected.ended_why
    runs = tmp_path / "runs"
    try:
        r = cli("up", "--profile", str(write_profile(tmp_path, str(scene))), "--detach", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr[-3000:]
        current = json.loads((runs / "current.json").read_text())
        status = lambda: query_status(current["endpoints"], current["robot"], timeout_s=0.5)  # noqa: E731
        final = wait_for(lambda: (s := status()) and s["state"] in EPISODE_OVER and s, 60, "the end of the episode", period_s=0.2)
        assert (final["state"], final["terminated_by"], final["step"], final["reason"]) == ("done", "no_frontier", expected.steps, expected.ended_why)
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert json.loads(r.stdout)["reason"] == expected.ended_why, r.stdout
        from rich.console import Console

        console = Console(width=400, record=True)
        console.print(render_table(final))
        assert f"done (no_frontier): {expected.ended_why}" in console.export_text()
        run_dir = Path(current["run_dir"])
        said = f"episode no_frontier: {expected.coverage_pct:.2f}% coverage in {expected.steps} steps; "
        wait_for(lambda: said in (run_dir / "logs" / "launcher.log").read_text(), 30, "the launcher's line")
        line = next(ln for ln in (run_dir / "logs" / "launcher.log").read_text().splitlines() if said in ln)
        assert line.endswith(f"{expected.decisions} decisions; {expected.ended_why}; results in {run_dir}"), line
        with open_session(TransportConfig(mode="client", connect=current["endpoints"])) as session:
            replies = [decode(rep.ok.payload.to_bytes(), LauncherStatusMsg) for rep in session.get(RobotKeys("r0").launcher_status, timeout=5.0) if rep.ok]
        last = replies[0].last_episode  # type: ignore[attr-defined]
        assert (last["terminated_by"], last["reason"]) == ("no_frontier", expected.ended_why)  # what `status` shows once the sim is gone
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []
