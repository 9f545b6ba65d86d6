"""Issue 6 through the launcher: ``cso-runtime up --profile limo-ros2 --connect ... --namespace ... --record``
against a fake LIMO process (``python -m robot_sim.fake_limo``: the MuJoCo LIMO speaking only ROS 2 CDR
made by rosbags, on its own Zenoh router), then the recording replayed into a fresh mapper.

Also the launcher's profile options and the mapper's episode handling. Real processes, loopback, free
ports, multicast scouting off, waits with deadlines, every process stopped in ``finally``.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from cso_runtime.config import ConfigError, ExplorationConfig, from_dict
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import ClockMsg, FrontiersMsg, GoalMsg, MapMsg, ScanMsg, decode
from cso_runtime.recording import read_recording, replay
from cso_runtime.run_profile import PACKAGED_PROFILES, find_profile, load_profile
from cso_runtime.scenes import resolve_scenes
from cso_runtime.supervision import pid_alive
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from tests.conftest import wait_for

SCENE = "generated:small:1:0"



def _kill_group(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(5)


def _connections_to_port(port: int) -> int:
    """Established TCP connections (IPv4, this host) to ``port``: the sessions that a router on it serves."""
    lines = Path("/proc/net/tcp").read_text().splitlines()[1:]
    return sum(1 for line in lines if (f := line.split())[2].endswith(f":{port:04X}") and f[3] == "01")


def _run_pids(runs: Path) -> list[int]:
    pids = []
    for f in runs.glob("*/run.json"):
        info = json.loads(f.read_text())
        pids += [int(info["launcher_pid"])] + [int(s["pid"]) for s in info["services"].values() if s.get("pid")]
    return pids


# --- launcher options and packaged profiles ----------------------------------------------------------


def test_packaged_profiles_are_found_from_anywhere_and_take_connect_and_namespace(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./configs/profiles here: the packaged ones are used
    assert find_profile("limo-ros2") == PACKAGED_PROFILES / "limo-ros2.yaml"
    profile, data = load_profile("limo-ros2", connect=["tcp/10.0.0.7:7447", "tcp/10.0.0.8:7447"], namespace="limo1")
    profile.validate()
    assert profile.router.connect == ["tcp/10.0.0.7:7447", "tcp/10.0.0.8:7447"]
    assert data["services"]["ros2_bridge"]["namespace"] == "limo1"
    with pytest.raises(ConfigError, match="ros2_bridge"):
        load_profile("sim", namespace="limo1")
    robot = ["tcp/10.0.0.7:7447"]
    with pytest.raises(ConfigError, match="namespace"):
        load_profile("limo-ros2", connect=robot, namespace="1-not-a-ros-name")
    # The runtime's own router (the services' traffic stays on this host) joins the robot's: it needs to be told where.
    assert profile.router.embedded is True
    with pytest.raises(ConfigError, match="--connect"):
        load_profile("limo-ros2")
    with pytest.raises(ConfigError, match="--connect"):
        load_profile("limo-ros2", settings={"router.embedded": False})
    # One referee, in real time: `--set services.sim.real_time_factor=2` on this profile added a MuJoCo sim beside the
    # bridge (both published scan, odometry and clock: the mapper cleared its map at every step while the real robot
    # was driven), and `--lockstep` was taken for a robot that does not wait for the pipeline.
    with pytest.raises(ConfigError, match="services: sim and ros2_bridge each run the episode"):
        load_profile("limo-ros2", connect=robot, settings={"services.sim.real_time_factor": 2})
    with pytest.raises(ConfigError, match="lockstep: a real robot"):
        load_profile("limo-ros2", {"lockstep": True}, connect=robot)
    # No simulator, no scene: `--scene` was taken and silently ignored (the robot explores the room it is in).
    with pytest.raises(ConfigError, match="--scene generated:small:1:0: .* no simulator"):
        load_profile("limo-ros2", {"scene": SCENE}, connect=robot)
    own = tmp_path / "configs" / "profiles"
    own.mkdir(parents=True)
    (own / "limo-ros2.yaml").write_text((PACKAGED_PROFILES / "limo-ros2.yaml").read_text().replace("seed: 0", "seed: 5"))
    assert load_profile("limo-ros2", connect=robot)[0].seed == 5, "a user's ./configs/profiles/ comes first"


# --- the mapper: a new episode is an episode id, not a step going back --------------------------------


def test_mapper_keeps_its_map_when_a_clock_arrives_late_and_clears_it_on_a_new_episode():
    from services.common import ServiceContext
    from services.mapper import MapperService

    svc = MapperService(ServiceContext("mapper", "t9", {}, ExplorationConfig(), TransportConfig(), {}))
    published: list[MapMsg] = []
    svc.publish = lambda topic, msg, robot=None: published.append(svc.check_output(topic, msg))  # no session needed here
    geom = GridGeometry(0.1, (40, 40))
    scan = LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.inf, np.float32))
    svc.on_message("t9", "clock", ClockMsg(0, 0.0, geom, episode=11), 0.0)
    for k in range(4):
        svc.on_message("t9", "scan", ScanMsg(k, scan, Pose2D(1.0 + 0.3 * k, 2.0, 0.0), episode=11), 0.0)
    svc.on_message("t9", "clock", ClockMsg(1, 0.25, geom, episode=11), 0.0)  # handled after the scan of step 3
    assert svc.map_step == 3 and (svc.map.to_occupancy_grid() != -1).sum() > 100
    svc.on_message("t9", "clock", ClockMsg(0, 0.0, geom, episode=12), 0.0)
    assert svc.map_step == -1 and (svc.map.to_occupancy_grid() != -1).sum() == 0
    svc.on_message("t9", "scan", ScanMsg(0, scan, Pose2D(2.0, 2.0, 0.0), episode=12), 0.0)
    assert svc.map_step == 0 and published[-1].step == 0
    explored_12 = (svc.map.to_occupancy_grid() != -1).sum()
    # The next episode's first scan before its clock (the sim sends the scan first): a new map at once.
    svc.on_message("t9", "scan", ScanMsg(0, scan, Pose2D(3.0, 2.0, 0.0), episode=13), 0.0)
    assert svc.episode == 13 and svc.map_step == 0 and published[-1].step == 0
    grid = svc.map.to_occupancy_grid()
    assert 0 < (grid != -1).sum() and (grid[:, :15] != -1).sum() == 0, "nothing of episode 12's map (around x = 2 m) is kept"
    svc.on_message("t9", "clock", ClockMsg(0, 0.0, geom, episode=13), 0.0)  # its clock, late: nothing more happens
    assert svc.map_step == 0 and (svc.map.to_occupancy_grid() != -1).sum() == (grid != -1).sum() and explored_12 > 0


# --- end to end ---------------------------------------------------------------------------------------


def test_up_limo_ros2_explores_a_fake_limo_and_its_recording_rebuilds_the_map(tmp_path: Path):
    port = free_tcp_port()
    runs = tmp_path / "runs"
    limo = subprocess.Popen(
        [sys.executable, "-m", "robot_sim.fake_limo", "--listen", loopback_endpoint(port), "--namespace", "limo1", "--scene", SCENE, "--speed", "3"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    up = None
    try:
        up = subprocess.Popen(
            [
                sys.executable, "-m", "cso_runtime.cli", "up", "--profile", "limo-ros2",
                "--connect", loopback_endpoint(port), "--namespace", "limo1",
                "--record", "--no-live", "--runs-dir", str(runs),
            ],
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )  # fmt: skip
        # The services talk to one another through the run's own router on loopback, and only that router joins the
        # robot's: with `router.embedded: false` every service (and the recorder) held a session to the robot's router,
        # and each message between two services crossed the robot's link twice.
        keys = RobotKeys("r0")
        # The run file is written first in state "starting", with no endpoints until the run's router is open.
        own = wait_for(lambda: [e for f in runs.glob("*/run.json") for e in json.loads(f.read_text())["endpoints"]], 30, "the run's endpoints")
        assert own and loopback_endpoint(port) not in own, own
        services = {"ros2_bridge", "mapper", "frontier", "policy", "planner"}
        with open_session(TransportConfig(mode="client", connect=own)) as watch:

            def all_up() -> bool:
                replies = watch.liveliness().get(keys.alive("*"), timeout=0.5)
                return services <= {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok}

            wait_for(all_up, 40, "every service")
        assert _connections_to_port(port) == 1, "one session on the robot's router: the run's own router's"
        try:
            out, _ = up.communicate(timeout=50)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGINT)  # the launcher stops its services
            out, _ = up.communicate(timeout=30)
            logs = "".join(f"--- {f.name}\n{f.read_text()[-1500:]}" for f in sorted(runs.glob("*/logs/*.log")))
            raise AssertionError(f"up did not finish the exploration within 50 s:\n{out[-2000:]}\n{logs}") from None
        assert up.returncode == 0, out[-3000:]
    finally:
        limo.send_signal(signal.SIGINT)
        try:
            limo_out, _ = limo.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            _kill_group(limo)
            limo_out = ""
        if up is not None:
            _kill_group(up)
        left = [p for p in _run_pids(runs) if pid_alive(p)]
        for p in left:
            os.kill(p, signal.SIGKILL)
    assert not left, f"processes left: {left}"
    assert "stopped after" in limo_out and " 0 commands" not in limo_out, limo_out[-2000:]

    (run_dir,) = [p.parent for p in runs.glob("*/summary.json")]
    row = next(iter(json.loads((run_dir / "summary.json").read_text())["methods"].values()))
    plan = resolve_scenes(SCENE)[0].load()
    free_m2 = float(plan.free.sum()) * plan.geometry.cell_area_m2
    assert row["terminated_by"] == {"no_frontier": 1}, row
    assert row["explored_area_m2"] > 0.9 * free_m2, f"explored {row['explored_area_m2']} m2 of {free_m2:.1f} m2 free"
    # Why it ended, in the frontier service's words, reaches the bridge's result as the sim's: the run's files and the
    # launcher's closing line say it (they said "no_frontier" alone on a real robot).
    (why,) = [e["why"] for e in row["ended_why"]]
    assert why.startswith("no frontier left"), why
    with (run_dir / "episodes.csv").open(newline="") as fh:
        assert [r["ended_why"] for r in csv.DictReader(fh)] == [why]
    assert any(line.endswith(f"; {why}; results in {run_dir}") for line in (run_dir / "logs" / "launcher.log").read_text().splitlines())

    # The recording: every step's clock and scan, and the mapper's maps. Replayed at full speed into a
    # fresh mapper, it rebuilds the map the run's mapper had at its last published step.
    recording = run_dir / "recording.mcap"
    # Once the episode is over (the policy's goal came back empty) the scans and maps go on until `up` has stopped its
    # services, but the frontier service asks for no decision more: no frontiers for RViz over the robot's link.
    end_step = min(g.step for g in (decode(m.payload, GoalMsg) for m in read_recording(recording, ["goal"])) if g.decided and not g.has_goal)
    after_end = [f for f in (decode(m.payload, FrontiersMsg) for m in read_recording(recording, ["frontiers"])) if f.step > end_step]
    asked = [f.step for f in after_end if f.decide]
    assert len(after_end) > 0 and asked == [], f"decisions asked at steps {asked} of {len(after_end)} after the end at step {end_step}"
    assert (run_dir / "logs" / "frontier.log").read_text().count("no more decisions until a new episode") == 1
    keys = RobotKeys("r0")
    maps = [decode(m.payload, MapMsg) for m in read_recording(recording, ["map"])]
    final = max(maps, key=lambda m: m.step)
    assert final.step > 50 and (final.grid != -1).sum() > 1000
    scan_steps = sorted({decode(m.payload, ScanMsg).step for m in read_recording(recording, ["scan"])})
    assert scan_steps[: final.step + 1] == list(range(final.step + 1)), "the recording misses scans"

    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    router = TransportConfig(mode="router", listen=[loopback_endpoint(free_tcp_port())])
    client = TransportConfig(mode="client", connect=router.listen)
    with open_session(router) as session:
        fresh_maps: dict[int, MapMsg] = {}
        sub = session.declare_subscriber(keys.map, lambda s: fresh_maps.setdefault((m := decode(s.payload.to_bytes(), MapMsg)).step, m))
        # The run's exploration config (the profile's LiDAR mount offset places the footprint the mapper clears).
        exploration = from_dict(ExplorationConfig, load_profile("limo-ros2", connect=["tcp/127.0.0.1:7447"])[0].exploration, where="exploration")
        fresh = MapperService(ServiceContext("mapper", "r0", {}, exploration, client, {"restore_timeout_s": 0.1}))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(fresh, stop), daemon=True)
        thread.start()
        try:
            wait_for(lambda: any(r.ok for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5)), 15, "the fresh mapper")
            with open_session(client) as play:
                stats = replay(play, recording, "max", topics=["clock", "scan"])
            assert stats.per_key[keys.clock] > final.step and stats.per_key[keys.scan] > final.step
            wait_for(lambda: final.step in fresh_maps, 20, f"the fresh mapper's map of step {final.step}")
        finally:
            stop.set()
            thread.join(10)
            sub.undeclare()
    assert fresh_maps[final.step].geometry == final.geometry
    differ = int((fresh_maps[final.step].grid != final.grid).sum())
    assert differ == 0, f"{differ} cells differ; fresh mapper status: rejected {fresh.rejected}, maps of steps {sorted(fresh_maps)[:5]}..."


def test_a_bridge_killed_outright_leaves_the_robot_stopped_by_the_launcher(tmp_path: Path):
    """SIGKILL (OOM, a segfault) gives the ROS 2 bridge no chance to send its last zero Twist: the robot would go
    on with its last command until limo_base's own timeout, if it has one. The launcher, on the robot's router
    too, sends the zero Twist on the robot's ``cmd_vel`` key as soon as it sees the bridge gone, before the
    restart, and counts it in its status. The robot here is a Zenoh router of the test's own (what
    zenoh-bridge-ros2dds is on the LIMO) and the run has the bridge alone: no robot data, so no Twist of the
    bridge's own."""
    import time

    import yaml
    import zenoh

    from cso_runtime import ros2_cdr
    from cso_runtime.messages import LauncherStatusMsg

    profile = yaml.safe_load(find_profile("limo-ros2").read_text())
    profile["services"] = {"ros2_bridge": profile["services"]["ros2_bridge"]}
    profile["supervision"]["backoff_s"] = 1.0
    profile_path = tmp_path / "bridge-only.yaml"
    profile_path.write_text(yaml.safe_dump(profile))
    port = free_tcp_port()
    runs = tmp_path / "runs"
    keys = RobotKeys("r0")
    twists: list[tuple[float, bytes]] = []
    bridge_back: list[float] = []
    killed_at: list[float] = []
    up = None
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as robot:
        sub = robot.declare_subscriber("limo1/cmd_vel", lambda s: twists.append((time.monotonic(), s.payload.to_bytes())))

        first_start: list[str] = []  # the token of the bridge's first start (its incarnation's key)

        def on_alive(sample) -> None:
            # The restarted bridge's token is the one of another start (``alive/ros2_bridge/<incarnation>``): a PUT of
            # the first start's token heard again after the kill (a router re-announcing it as the links change) is
            # no restart.
            if killed_at and sample.kind == zenoh.SampleKind.PUT and str(sample.key_expr) not in first_start:
                bridge_back.append(time.monotonic())

        alive = robot.liveliness().declare_subscriber(keys.alive_incarnation("ros2_bridge", "*"), on_alive)
        try:
            up = subprocess.Popen(
                [
                    sys.executable, "-m", "cso_runtime.cli", "up", "--profile", str(profile_path),
                    "--connect", loopback_endpoint(port), "--namespace", "limo1", "--no-live", "--runs-dir", str(runs),
                ],
                cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
            )  # fmt: skip
            wait_for(lambda: any(r.ok for r in robot.liveliness().get(keys.alive("ros2_bridge"), timeout=0.5)), 60, "the bridge")
            wait_for(
                lambda: first_start.extend(str(r.ok.key_expr) for r in robot.liveliness().get(keys.alive_incarnation("ros2_bridge", "*"), timeout=0.5) if r.ok) or first_start,
                10, "the token of the bridge's first start",
            )  # fmt: skip
            (run_file,) = runs.glob("*/run.json")
            pid = int(json.loads(run_file.read_text())["services"]["ros2_bridge"]["pid"])
            assert not twists, "the bridge had nothing to command: no Twist of its own"
            killed_at.append(time.monotonic())
            os.kill(pid, signal.SIGKILL)
            wait_for(lambda: twists, 10, "a zero Twist on limo1/cmd_vel after the bridge died")
            t_zero, raw = twists[0]
            cmd = ros2_cdr.twist_from_cdr(raw)
            assert (cmd.linear_mps, cmd.angular_radps) == (0.0, 0.0)
            assert not bridge_back or t_zero < bridge_back[0], "the zero Twist goes out before the bridge is restarted"

            def status():
                replies = [decode(r.ok.payload.to_bytes(), LauncherStatusMsg) for r in robot.get(keys.launcher_status, timeout=1.0) if r.ok]
                return replies[0].services["ros2_bridge"] if replies else None

            st = wait_for(lambda: (s := status()) and s.get("restarts") == 1 and s, 30, "the restarted bridge")
            assert st["robot_stops"] == 1, st
            wait_for(lambda: bridge_back, 30, "the token of the restarted bridge's start")
            assert t_zero < bridge_back[0], "the zero Twist went out before the restarted bridge came up"
        finally:
            if up is not None and up.poll() is None:
                os.killpg(up.pid, signal.SIGINT)  # the launcher stops its services
                try:
                    out, _ = up.communicate(timeout=30)
                except subprocess.TimeoutExpired:
                    _kill_group(up)
                    out = ""
            else:
                out = up.communicate()[0] if up is not None else ""
            alive.undeclare()
            sub.undeclare()
            left = [p for p in _run_pids(runs) if pid_alive(p)]
            for p in left:
                os.kill(p, signal.SIGKILL)
    assert not left, f"processes left: {left}"
    assert "ros2_bridge exited (code -9): sent a zero Twist on limo1/cmd_vel" in out, out[-3000:]


def test_a_pause_from_ros_is_logged_with_how_to_resume_it_from_ros(tmp_path, caplog):
    """``ros2 topic pub --once /limo1/explore/resume std_msgs/msg/Bool "{data: false}"`` paused the robot, and the
    launcher's log told the ROS user that it "holds still until `cso-runtime resume`": a pause heard on the robot's
    ``explore/resume`` now names ``{data: true}`` on that topic too; one from ``cso-runtime pause`` names the command."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import ROS_RESUME_BY, ExploreResumeMsg

    profile, data = load_profile("limo-ros2", connect=["tcp/10.0.0.7:7447"], namespace="limo1")
    launcher = Launcher(profile, data, tmp_path)
    with caplog.at_level("INFO", logger="cso.launcher"):
        launcher.on_pause(ExploreResumeMsg(False, f"{ROS_RESUME_BY}limo1/explore/resume"))
        launcher.on_pause(ExploreResumeMsg(True, f"{ROS_RESUME_BY}limo1/explore/resume"))
        launcher.on_pause(ExploreResumeMsg(False, "me@laptop", "inspecting"))
    paused = [r.getMessage() for r in caplog.records if "exploration paused" in r.getMessage()]
    resume = f"`cso-runtime resume --runs-dir {tmp_path.parent}`"  # of this run's runs folder: a plain one asks ./runs
    assert paused == [
        f"exploration paused by ros2 limo1/explore/resume: the robot holds still until `{{data: true}}` on limo1/explore/resume or {resume}",
        f"exploration paused by me@laptop (inspecting): the robot holds still until {resume}",
    ], paused
