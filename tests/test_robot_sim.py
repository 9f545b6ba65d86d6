"""MuJoCo LIMO simulator (issue 3): LiDAR, driving, walls, planner, watchdog, clocks, determinism."""

from __future__ import annotations

import dataclasses
import math
import re
import threading
from pathlib import Path

import numpy as np
import pytest

from cso_runtime.config import ConfigError, EpisodeConfig, ExplorationConfig, RobotConfig, SensorConfig, from_dict, load_yaml
from cso_runtime.episode import run_episode
from cso_runtime.geodesic import geodesic_distance, traversable_cells
from cso_runtime.geometry import Pose2D, VelocityCommand, wrap_angle_rad
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.planner import LocalPlanner, PlannerStatus
from cso_runtime.policies import make_policy
from cso_runtime.scenes import FloorPlan, SceneError
from cso_runtime.simulator import Simulator
from robot_sim import MujocoSimConfig, MujocoSimulator, RealTimePacer, merge_rectangles, wall_boxes
from robot_sim.config import whole_steps

RES = 0.05


def box_room(size_m: float = 4.0, start: Pose2D = Pose2D(2.0, 2.0, 0.0)) -> FloorPlan:
    """A closed square room; the inner wall faces are at RES and size_m - RES."""
    n = int(round(size_m / RES))
    free = np.zeros((n, n), dtype=bool)
    free[1:-1, 1:-1] = True
    return FloorPlan("box", free, RES, start)


def l_plan(start: Pose2D = Pose2D(0.6, 0.6, 0.0)) -> FloorPlan:
    """L-shaped corridor: along x at y in [0.05, 1.25], then up along y at x in [2.85, 4.05]; plus a
    closed room (x in [5, 6], y in [3, 4]) that no path reaches."""
    free = np.zeros((90, 130), dtype=bool)
    free[1:25, 1:81] = True  # horizontal leg
    free[1:85, 57:81] = True  # vertical leg
    free[60:80, 100:120] = True  # sealed room
    return FloorPlan("L", free, RES, start)


def analytic_ranges(origin: np.ndarray, angles: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Distance from ``origin`` inside the square [lo, hi]^2 to its boundary along each angle."""
    dx, dy = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(dx > 0, (hi - origin[0]) / dx, np.where(dx < 0, (lo - origin[0]) / dx, np.inf))
        ty = np.where(dy > 0, (hi - origin[1]) / dy, np.where(dy < 0, (lo - origin[1]) / dy, np.inf))
    return np.minimum(tx, ty)


# --- world building ---
def test_merge_rectangles_covers_mask_exactly_with_few_boxes() -> None:
    rng = np.random.default_rng(3)
    mask = rng.random((40, 50)) < 0.4
    rects = merge_rectangles(mask)
    cover = np.zeros(mask.shape, dtype=int)
    for y0, x0, y1, x1 in rects:
        cover[y0:y1, x0:x1] += 1
    assert np.array_equal(cover, mask.astype(int))  # exact and disjoint
    walls = np.zeros((100, 120), dtype=bool)
    walls[10:14, :] = True
    walls[:, 60:63] = True
    assert len(merge_rectangles(walls)) <= 3
    # A plan's walls become a closed shell: a 4 m room is 4 boxes, outside of the grid included.
    assert len(wall_boxes(box_room())) == 4


def test_hollow_walls_scan_like_solid_ones() -> None:
    free = np.zeros((80, 80), dtype=bool)
    free[4:-4, 4:-4] = True
    free[30:50, 20:60] = False  # a thick block in the middle of the room
    plan = FloorPlan("block", free, RES, Pose2D(0.6, 0.6, 0.3))
    solid = MujocoSimulator(plan, SensorConfig(fov_deg=360.0), seed=0)
    hollow = MujocoSimulator(plan, SensorConfig(fov_deg=360.0), seed=0, config=MujocoSimConfig(walls_boundary_only=True))
    for pose in (Pose2D(0.6, 0.6, 0.3), Pose2D(2.0, 3.2, -1.0), Pose2D(3.5, 1.0, 2.5)):
        np.testing.assert_allclose(hollow.cast_scan(pose).ranges_m, solid.cast_scan(pose).ranges_m, atol=1e-5)
    assert len(wall_boxes(plan)) < len(wall_boxes(plan, boundary_only=True))


def test_yaml_defaults_match_the_dataclass() -> None:
    path = Path(__file__).resolve().parents[1] / "configs" / "robot_sim.yaml"
    assert from_dict(MujocoSimConfig, load_yaml(path), "robot_sim") == MujocoSimConfig()
    with pytest.raises(ConfigError):
        from_dict(MujocoSimConfig, {"timestep": 0.01}, "robot_sim")


def test_simulator_protocol_and_config_errors() -> None:
    sim = MujocoSimulator(box_room(), seed=0)
    assert isinstance(sim, Simulator)
    assert sim.time_s == 0.0 and sim.true_pose() == sim.plan.start == sim.odometry()
    with pytest.raises(ConfigError):
        MujocoSimulator(box_room(), config=MujocoSimConfig(timestep_s=0.007))  # 0.25 s is not whole steps
    with pytest.raises(ConfigError):
        MujocoSimulator(box_room(), config=MujocoSimConfig(lidar_height_m=1.5))
    with pytest.raises(ValueError):
        sim.step(VelocityCommand(float("nan"), 0.0))
    assert not sim.set_command(VelocityCommand(0.0, float("inf"))) and sim.rejected_commands == 2


def test_parameters_the_model_cannot_honour_are_config_errors() -> None:
    """An odometry rate whose period is not whole physics steps ran silently at another rate (30 Hz at 5 ms
    ticked every 7 steps, 28.6 Hz; 1000 Hz ran at 200 Hz), which changes how much the drift noise adds up; a
    wheel radius (the body's clearance) above the body's height came out as MuJoCo's XML error; walls lower than that
    clearance let the robot drive through them."""
    for kwargs, match in (
        ({"odometry_rate_hz": 30.0}, r"odometry_rate_hz \(30 Hz\).*nearest such rate: 28.5714 Hz"),
        ({"odometry_rate_hz": 1000.0}, r"odometry_rate_hz \(1000 Hz\).*200 Hz"),
        ({"timestep_s": 0.002}, r"odometry_rate_hz \(40 Hz\).*gives 12.5"),
        ({"wheel_radius_m": 0.3}, r"wheel_radius_m \(0.3 m.*below body_height_m"),
        # Walls below the body's clearance: the LiDAR (below them) sees them and the body drove over them, out of the plan.
        ({"wall_height_m": 0.04, "lidar_height_m": 0.03}, r"wall_height_m \(0.04 m\) must be above wheel_radius_m \(0.045 m"),
        ({"track_m": 0.0}, r"track_m must be in \(0, 4\] m \(.*\), got 0$"),
    ):
        with pytest.raises(ConfigError, match=match):
            MujocoSimConfig(**kwargs).validate()
    MujocoSimConfig(odometry_rate_hz=50.0).validate()  # 4 steps of 5 ms
    MujocoSimConfig(timestep_s=0.0025).validate()  # 40 Hz is 10 steps


@pytest.mark.parametrize("timestep_s", [0.002, 0.003, 0.00333333])
def test_the_odometry_rate_an_error_suggests_is_accepted(timestep_s: float) -> None:
    """A finer physics step makes the default 40 Hz odometry no whole number of steps; the error names the
    nearest rate that is, to 6 digits (41.6667 Hz for 2 ms), and that rate was refused in turn (11.99999 steps
    missed the whole-step check by 1e-5). A rate or step written to 6 digits is whole to that precision."""
    with pytest.raises(ConfigError, match="nearest such rate") as refused:
        MujocoSimConfig(timestep_s=timestep_s).validate()
    suggested = re.search(r"nearest such rate: ([0-9.]+) Hz", str(refused.value))
    assert suggested is not None, refused.value
    MujocoSimConfig(timestep_s=timestep_s, odometry_rate_hz=float(suggested.group(1))).validate()
    assert whole_steps(0.25, 0.00333333, "robot.control_period_s") == 75  # 1/300 s written to 6 digits


# --- LiDAR ---
@pytest.mark.parametrize(
    "sensor",
    [SensorConfig(mount_x_m=0.103), SensorConfig(fov_deg=360.0, mount_x_m=0.103), dataclasses.replace(SensorConfig.preset("depth"), mount_x_m=0.103)],
    ids=["lidar180", "lidar360", "depth"],
)
def test_lidar_matches_analytic_box_room(sensor: SensorConfig) -> None:
    """The rays leave from the sensor's mount, the LIMO's 0.103 m here."""
    start = Pose2D(1.0, 1.4, 0.3)  # looking across the room: about half the depth beams exceed 3 m
    sim = MujocoSimulator(box_room(start=start), sensor, seed=0)
    scan = sim.scan()
    n = round(sensor.fov_deg / sensor.resolution_deg)
    assert len(scan.ranges_m) == (n if sensor.fov_deg >= 360 else n + 1)
    assert scan.range_min_m == sensor.range_min_m and scan.range_max_m == sensor.range_max_m
    assert scan.angle_min_rad == pytest.approx(-math.radians(sensor.fov_deg) / 2)
    origin = start.compose_offset(0.103)
    assert sim.sensor_pose().xy == pytest.approx(origin.xy) and sim.sensor_pose().yaw_rad == pytest.approx(0.3)
    expected = analytic_ranges(origin.xy, scan.angles_rad + origin.yaw_rad, RES, 4.0 - RES)
    within = expected <= sensor.range_max_m - 1e-3
    # Every beam sees a wall (never the robot's own body, even the rear beams of the 360 ring).
    assert within.sum() >= 0.4 * len(within)
    np.testing.assert_allclose(scan.ranges_m[within], expected[within], atol=0.01)
    beyond = expected > sensor.range_max_m + 1e-3
    assert np.isinf(scan.ranges_m[beyond]).all()
    if sensor.range_max_m < 3.5:  # the depth preset: beams longer than 3 m have no return
        assert beyond.sum() >= 0.4 * len(beyond)


@pytest.mark.parametrize("mount_x_m", [0.103, 0.0, 0.2])
def test_the_runtime_casts_the_rays_from_the_sensors_own_mount(mount_x_m: float) -> None:
    """``make_simulator("mujoco")`` (eval, the sim service, doctor) puts the LiDAR where ``sensor.mount_x_m``
    says, the mount the mapper's footprint and the planner's clearance use; a second mount of the model's own
    would put every wall a few centimetres off for them."""
    from cso_runtime.simulator import make_simulator

    start = Pose2D(1.0, 2.0, 0.0)  # facing the wall at x = 4 - RES
    sim = make_simulator("mujoco", box_room(start=start), SensorConfig(mount_x_m=mount_x_m), RobotConfig(), seed=0)
    assert sim.sensor_pose().x_m == pytest.approx(start.x_m + mount_x_m)
    scan = sim.scan()
    ahead = scan.ranges_m[np.argmin(np.abs(scan.angles_rad))]
    assert ahead == pytest.approx(4.0 - RES - start.x_m - mount_x_m, abs=0.01)


def test_the_runtime_takes_the_mujoco_limos_parameters_and_refuses_a_second_mount() -> None:
    """eval's ``--sim-config`` and a profile's ``services.sim.mujoco`` reach the model through ``make_simulator``
    (odometry drift here); a LiDAR mount other than the sensor's is refused, and MuJoCo parameters for the 2D
    simulator are an error rather than silently ignored."""
    from cso_runtime.simulator import make_simulator, mujoco_config

    plan = box_room(size_m=8.0, start=Pose2D(1.0, 4.0, 0.0))
    drift = {"odom_trans_noise_frac": 0.05, "odom_rot_per_trans_noise_radpm": 0.05}
    sims = [make_simulator("mujoco", plan, SensorConfig(), RobotConfig(), seed=2, mujoco=m) for m in (drift, None)]
    assert sims[0].config.odom_trans_noise_frac == 0.05 and sims[1].config == MujocoSimConfig(lidar_mount_x_m=None)
    for sim in sims:
        for _ in range(20):
            sim.step(VelocityCommand(1.0, 0.1))
    errors = [math.dist(s.true_pose().xy, s.odometry().xy) for s in sims]
    assert errors[0] > 1e-4 and errors[1] < 1e-6
    yaml_file = load_yaml(Path(__file__).resolve().parents[1] / "configs" / "robot_sim.yaml")  # the defaults, the mount left out
    assert mujoco_config(yaml_file, SensorConfig(mount_x_m=0.0)).lidar_mount_x_m is None
    assert mujoco_config({"lidar_mount_x_m": 0.103}, SensorConfig(mount_x_m=0.103)).lidar_mount_x_m is None  # the same mount
    with pytest.raises(ConfigError, match=r"lidar_mount_x_m: 0.103 is not the sensor's mount \(0.0 m\).*set sensor.mount_x_m"):
        mujoco_config({"lidar_mount_x_m": 0.103}, SensorConfig(mount_x_m=0.0))
    with pytest.raises(ConfigError, match="unknown key"):
        mujoco_config({"odom_noise": 0.1}, SensorConfig())
    with pytest.raises(ConfigError, match="need the mujoco simulator"):
        make_simulator("2d", plan, SensorConfig(), RobotConfig(), mujoco=drift)


def test_the_simulator_casts_its_rays_from_the_sensors_mount_and_refuses_a_second_one(tmp_path: Path) -> None:
    """One LiDAR mount, ``SensorConfig.mount_x_m``: the mapper and the planner take it from the sensor, so the rays
    must leave from it too. ``MujocoSimConfig.lidar_mount_x_m`` defaulted to the LIMO's 0.103 m whatever the sensor
    said, and a sensor at 0 m (``SensorConfig()``) got its scans from 0.103 m ahead with only an info line: a map
    shifted silently. No sensor is the LIMO's (0.103 m, the mount then said so too); an old config's second mount is
    taken where it agrees and refused where it does not."""
    from robot_sim.scene import write_mujoco_world

    plan = box_room()
    at_centre = MujocoSimulator(plan, SensorConfig(mount_x_m=0.0))
    assert at_centre.lidar_mount_x_m == 0.0
    assert math.dist(at_centre.sensor_pose().xy, at_centre.odometry().xy) < 1e-9
    limo = MujocoSimulator(plan)
    assert limo.sensor.mount_x_m == limo.lidar_mount_x_m == 0.103
    assert MujocoSimulator(plan, SensorConfig(mount_x_m=0.05), config=MujocoSimConfig(lidar_mount_x_m=0.05)).lidar_mount_x_m == 0.05
    with pytest.raises(ConfigError, match=r"lidar_mount_x_m: 0.2 is not the sensor's mount \(0.0 m\).*set SensorConfig.mount_x_m"):
        MujocoSimulator(plan, SensorConfig(), config=MujocoSimConfig(lidar_mount_x_m=0.2))
    site = re.compile(r'<site name="lidar" pos="(\S+) ')
    assert site.search(write_mujoco_world(tmp_path / "centre.xml", plan, sensor=SensorConfig()).read_text()).group(1) == "0"
    assert site.search(write_mujoco_world(tmp_path / "limo.xml", plan).read_text()).group(1) == "0.103"


class _SimulatorBuilt(Exception):
    """Raised by a stand-in for a simulator's constructor, once it has seen the sensor it was given."""


def test_every_entry_point_runs_the_mujoco_limo_with_the_one_lidar_mount_and_body(tmp_path: Path, monkeypatch) -> None:
    """The MuJoCo LIMO's LiDAR mount and box body were set in six places (eval --sim mujoco, a MuJoCo profile, doctor,
    scenes --mjcf, the fake LIMO, the simulator given no sensor), each with its own copy of the rule or the value; one rule
    now (``with_mujoco_limo_defaults``), and every entry point resolves the same mount (and, where a planner runs, body)
    as the limo-ros2 profile that drives the fake LIMO, so that none can drift alone."""
    from typer.testing import CliRunner

    from cso_runtime import doctor, simulator
    from cso_runtime.cli import app
    from cso_runtime.config import LIMO_BODY, LIMO_LIDAR_MOUNT_X_M
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import PACKAGED_PROFILES, load_profile, profile_exploration_config
    from robot_sim import fake_limo
    from robot_sim.config import limo_sensor

    configs = {
        "eval --sim mujoco": EvalRequest(methods=["greedy-dist"], sim="mujoco").exploration_config(),
        "up --profile sim": load_profile("sim", {})[0].exploration_config(),
        "a profile whose sim is MuJoCo": profile_exploration_config(None, {"sim": {"backend": "mujoco"}}),
        "limo-ros2": from_dict(ExplorationConfig, load_yaml(PACKAGED_PROFILES / "limo-ros2.yaml")["exploration"]),
    }
    mounts = {name: config.sensor.mount_x_m for name, config in configs.items()}
    assert {name: config.planner.body for name, config in configs.items()} == dict.fromkeys(configs, LIMO_BODY)

    seen: list[SensorConfig] = []

    def built(*args, **kwargs):
        seen.append(next(a for a in (*args, *kwargs.values()) if isinstance(a, SensorConfig)))
        raise _SimulatorBuilt

    monkeypatch.setattr(simulator, "make_simulator", built)
    with pytest.raises(_SimulatorBuilt):
        doctor.check_mujoco()
    monkeypatch.setattr(fake_limo, "MujocoSimulator", built)
    with pytest.raises(_SimulatorBuilt):
        fake_limo.main(["--listen", "tcp/127.0.0.1:1"])
    mounts.update({"doctor": seen[0].mount_x_m, "fake_limo": seen[1].mount_x_m, "no sensor": limo_sensor().mount_x_m})
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(tmp_path / "worlds")])
    assert result.exit_code == 0, result.output
    site = re.search(r'<site name="lidar" pos="(\S+) ', (tmp_path / "worlds" / "gen_small_0.xml").read_text())
    mounts["scenes --mjcf"] = float(site.group(1))
    assert mounts == dict.fromkeys(mounts, LIMO_LIDAR_MOUNT_X_M)


def test_lidar_noise_is_seeded_and_fires_at_sensor_rate() -> None:
    noisy = SensorConfig(fov_deg=360.0, range_noise_std_m=0.02)
    a = MujocoSimulator(box_room(), noisy, seed=7)
    b = MujocoSimulator(box_room(), noisy, seed=7)
    clean = MujocoSimulator(box_room(), SensorConfig(fov_deg=360.0), seed=7)
    err = a.scan().ranges_m - clean.scan().ranges_m
    assert 0.015 < float(np.std(err)) < 0.025
    np.testing.assert_array_equal(a.scan().ranges_m, b.scan().ranges_m)
    a.drain_scans()
    a.step(VelocityCommand(0.5, 0.2))
    scans = a.drain_scans()  # 8 Hz: two scans per 0.25 s step, the last one at the end of the step
    assert [s.stamp_s for _, s in scans] == pytest.approx([0.125, 0.25])
    assert scans[-1][1] is a.scan() and scans[-1][0] == a.sensor_pose()
    assert scans[0][0].x_m < scans[1][0].x_m  # each scan comes with the sensor pose at its time


# --- driving and walls ---
def corner_of_body(sim: MujocoSimulator) -> np.ndarray:
    """The chassis's four corners in the map frame (ground truth)."""
    p = sim.true_pose()
    hl, hw = 0.5 * sim.robot.length_m, 0.5 * sim.robot.width_m
    return np.array([p.compose_offset(sx * hl, sy * hw).xy for sx in (-1, 1) for sy in (-1, 1)])


def test_drives_straight_corridor_and_turns_a_corner() -> None:
    sim = MujocoSimulator(l_plan(), seed=0)
    for _ in range(15):  # 3.75 s at 0.5 m/s along the corridor (0.25 s to reach the speed)
        sim.step(VelocityCommand(0.5, 0.0))
    p = sim.true_pose()
    assert p.x_m == pytest.approx(0.6 + 0.5 * 3.75 - 0.5 * 0.5 * 0.25, abs=0.03)
    assert abs(p.y_m - 0.6) < 1e-3 and abs(p.yaw_rad) < 1e-3
    while sim.true_pose().yaw_rad < math.pi / 2 - 0.05:  # a 1 m radius arc left into the vertical leg
        sim.step(VelocityCommand(0.5, 0.5))
        assert sim.time_s < 15.0
    p = sim.true_pose()
    assert p.x_m == pytest.approx(2.4 + 1.0, abs=0.1) and p.y_m == pytest.approx(0.6 + 1.0, abs=0.15)
    for _ in range(12):
        sim.step(VelocityCommand(0.6, 0.0))
    for _ in range(4):
        sim.step(VelocityCommand(0.0, 0.0))
    p = sim.true_pose()
    assert 2.85 < p.x_m < 4.05 and 3.0 < p.y_m < 4.0, p  # up the second leg
    while sim.true_pose().yaw_rad > 0.0:  # rotate in place half a turn (clockwise)
        sim.step(VelocityCommand(0.0, -0.78))
        assert sim.time_s < 30.0
    assert math.hypot(*(sim.true_pose().xy - p.xy)) < 0.01
    assert sim.collisions == 0
    assert sim.odometry().xy == pytest.approx(sim.true_pose().xy)


@pytest.mark.parametrize("yaw_rad", [0.0, 0.5])
def test_stops_at_wall_without_crossing(yaw_rad: float) -> None:
    sim = MujocoSimulator(box_room(start=Pose2D(2.5, 2.0, yaw_rad)), seed=0)
    wall_x = 4.0 - RES
    worst = -math.inf
    for _ in range(int(4.0 / 0.02)):  # full speed into the east wall for 4 s, checked every 20 ms
        sim.set_command(VelocityCommand(1.0, 0.0))
        sim.advance(0.02)
        worst = max(worst, float(corner_of_body(sim)[:, 0].max()))
    assert worst < wall_x + 0.005  # never through the wall (a few mm of contact softness at most)
    assert sim.true_pose().x_m < wall_x - 0.5 * sim.robot.width_m
    assert sim.collisions == 1 and sim.contact_steps > 100  # one collision, then resting on the wall
    v, _, _ = sim.body_velocity()
    if yaw_rad == 0.0:
        assert abs(v) < 1e-3  # head-on: stopped against the wall
        assert sim.true_pose().x_m == pytest.approx(wall_x - 0.5 * sim.robot.length_m, abs=0.005)


# --- planner on the physics robot ---
@pytest.mark.parametrize("radius_m", [0.2, 0.25])
def test_local_planner_reaches_goal_in_l_plan_and_reports_blocked(radius_m: float) -> None:
    plan = l_plan()
    robot = RobotConfig(radius_m=radius_m)
    sim = MujocoSimulator(plan, SensorConfig(mount_x_m=0.103), robot, seed=1)
    trav = traversable_cells(plan.free, plan.occupied, robot.radius_m, plan.resolution_m)
    planner = LocalPlanner(robot, goal_tolerance_m=0.3, sensor_mount_x_m=0.103)
    pose = sim.odometry()
    dist = geodesic_distance(trav, plan.geometry, pose.xy)
    assert planner.set_goal(trav, plan.geometry, pose, np.array([5.5, 3.5]), dist) == PlannerStatus.BLOCKED
    assert planner.set_goal(trav, plan.geometry, pose, np.array([3.45, 3.6]), dist) == PlannerStatus.FOLLOWING
    wall_faces = np.array([2.85, 0.05])  # the inner corner's walls: x >= 2.85 above y = 1.25, y >= 0.05
    for _ in range(240):  # 60 s
        result = planner.update(sim.odometry(), sim.time_s, sim.scan())
        if result.status != PlannerStatus.FOLLOWING:
            break
        sim.step(result.command)
        corners = corner_of_body(sim)
        assert corners[:, 1].min() > wall_faces[1] - 0.005
        assert corners[corners[:, 1] > 1.3, 0].min(initial=np.inf) > wall_faces[0] - 0.005  # never through a wall
    assert planner.status == PlannerStatus.REACHED, (planner.status, sim.true_pose(), sim.time_s)
    assert math.hypot(sim.true_pose().x_m - 3.45, sim.true_pose().y_m - 3.6) < 0.35
    if radius_m >= 0.25:
        # The LIMO's box sweeps a 0.195 m circle when it turns in place: planning with the default
        # 0.2 m inflation, paths that hug the inflated corner let it scrape the wall while turning
        # (the walls stop it); with a little more margin it never touches.
        assert sim.collisions == 0


# --- control: watchdog, limits, clocks ---
def test_watchdog_stops_robot_when_commands_cease() -> None:
    sim = MujocoSimulator(box_room(start=Pose2D(0.6, 2.0, 0.0)), seed=0)
    # Fresh commands every 0.1 s keep it moving past the 0.5 s watchdog.
    for k in range(10):
        sim.set_command(VelocityCommand(0.5, 0.0), stamp_s=0.1 * k)
        sim.advance(0.1)
    assert sim.body_velocity()[0] == pytest.approx(0.5, abs=0.01) and sim.watchdog_stops == 0
    last_stamp = sim.time_s
    sim.set_command(VelocityCommand(0.5, 0.0))
    sim.advance(0.45)  # within the watchdog period: still driving
    assert sim.body_velocity()[0] == pytest.approx(0.5, abs=0.01)
    sim.advance(0.6)  # trips at 0.5 s, then brakes at the acceleration limit (0.25 s)
    assert sim.watchdog_stops == 1
    assert abs(sim.body_velocity()[0]) < 1e-3
    x = sim.true_pose().x_m
    sim.advance(1.0)
    assert sim.true_pose().x_m == pytest.approx(x, abs=1e-4)
    assert sim.time_s - last_stamp > 2.0



def test_under_the_sim_service_the_mujoco_watchdog_never_fires_and_the_docs_say_which_one_does() -> None:
    """Two command watchdogs guard a MuJoCo run (docs/runtime.md, Command watchdogs): the sim service's
    ``cmd_timeout_s`` (wall clock) and the MuJoCo LIMO's ``watchdog_s`` (simulated). The service steps the simulator
    a control period at a time with its command afresh (``step``), so ``watchdog_s`` never fires there while it is at
    least the period, and brakes within every step when shorter; the docs and docstrings say so, with the defaults."""
    import inspect

    from services.sim import SimParams

    for watchdog_s, stops in ((MujocoSimConfig.watchdog_s, 0), (RobotConfig.control_period_s, 0), (0.1, 6)):
        sim = MujocoSimulator(box_room(start=Pose2D(0.6, 2.0, 0.0)), seed=0, config=MujocoSimConfig(watchdog_s=watchdog_s))
        for _ in range(6):
            sim.step(VelocityCommand(0.3, 0.0))  # as the sim service does, real time or lockstep
        assert sim.watchdog_stops == stops, watchdog_s
    docs = " ".join((Path(__file__).resolve().parents[1] / "docs" / "runtime.md").read_text(encoding="utf-8").split())
    section = docs[docs.index("### Command watchdogs") :][:3000]
    cmd_timeout = f"`services.sim.cmd_timeout_s`: the sim steps with a stop instead of a command older than this | wall clock | {SimParams.cmd_timeout_s} s"
    watchdog = f"`services.sim.mujoco.watchdog_s` (`configs/robot_sim.yaml`'s `watchdog_s`): the base brakes to a stop | simulated time | {MujocoSimConfig.watchdog_s} s"
    assert cmd_timeout in section and watchdog in section
    assert "lower `services.sim.cmd_timeout_s`, not `services.sim.mujoco.watchdog_s`" in section
    assert "docs/runtime.md, Command watchdogs" in " ".join(inspect.getsource(SimParams).split())
    assert "docs/runtime.md, Command watchdogs" in " ".join(inspect.getsource(MujocoSimConfig).split())


def test_up_and_eval_warn_of_a_mujoco_watchdog_shorter_than_a_control_step(tmp_path: Path, monkeypatch) -> None:
    """``services.sim.mujoco.watchdog_s`` below ``exploration.robot.control_period_s`` brakes the MuJoCo LIMO within
    every step (above): ``up`` says so at start, naming both keys and the one to tune, and runs as asked (a warning,
    exit 0 here with ``--dry-run``); at the default, or equal to the period, it says nothing; eval's ``--sim-config``
    the same."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)  # the packaged profiles
    for watchdog_s, warned in ((0.1, True), (RobotConfig.control_period_s, False), (MujocoSimConfig.watchdog_s, False)):
        r = CliRunner().invoke(app, ["up", "--profile", "sim", "--set", f"services.sim.mujoco.watchdog_s={watchdog_s}", "--dry-run"])
        assert r.exit_code == 0, r.output
        said = "warning: services.sim.mujoco.watchdog_s 0.1 s is shorter than a control step (exploration.robot.control_period_s, 0.25 s)"
        assert (said in r.stderr) == warned, r.stderr
        assert ("services.sim.cmd_timeout_s" in r.stderr) == warned
    slow = CliRunner().invoke(app, ["up", "--profile", "sim", "--set", "services.sim.mujoco.watchdog_s=0.3", "--set", "exploration.robot.control_period_s=0.5", "--dry-run"])
    assert slow.exit_code == 0 and "watchdog_s 0.3 s is shorter than a control step (exploration.robot.control_period_s, 0.5 s)" in slow.stderr
    (tmp_path / "fast.yaml").write_text("watchdog_s: 0.1\n")
    r = CliRunner().invoke(app, ["eval", "--sim", "mujoco", "--sim-config", "fast.yaml", "--maps", "generated:small:1:0", "--out", "o", "--dry-run"])
    assert r.exit_code == 0 and "warning: fast.yaml: watchdog_s 0.1 s is shorter than a control step (robot.control_period_s, 0.25 s)" in r.stderr
    assert not (tmp_path / "o").exists()


def test_eval_warns_of_a_default_mujoco_watchdog_within_a_longer_control_step(tmp_path: Path, monkeypatch) -> None:
    """Without ``--sim-config`` the MuJoCo LIMO's default ``watchdog_s`` (0.5 s) is within a 1 s control step: eval's warning
    names the key as the default, not a ``None`` file, and says what eval can change (``--sim-config``'s ``watchdog_s``),
    not ``services.sim.cmd_timeout_s``, a setting of ``up``'s sim service that eval has none of."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    args = ["eval", "--sim", "mujoco", "--set", "robot.control_period_s=1.0", "--maps", "generated:small:1:0", "--out", "o", "--dry-run"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "warning: --sim mujoco's default watchdog_s 0.5 s is shorter than a control step (robot.control_period_s, 1 s)" in r.stderr, r.stderr
    assert "None" not in r.stderr and "cmd_timeout_s" not in r.stderr
    assert "--sim-config FILE with watchdog_s: at least robot.control_period_s" in r.stderr
    (tmp_path / "fast.yaml").write_text("watchdog_s: 0.1\n")
    r = CliRunner().invoke(app, ["eval", "--sim", "mujoco", "--sim-config", "fast.yaml", "--maps", "generated:small:1:0", "--out", "o", "--dry-run"])
    assert "warning: fast.yaml: watchdog_s 0.1 s" in r.stderr and "cmd_timeout_s" not in r.stderr, r.stderr


def test_real_time_pacer_follows_the_clock() -> None:
    sim = MujocoSimulator(box_room(), seed=0)
    now = [100.0]
    pacer = RealTimePacer(sim, speed=2.0, max_lag_s=0.5, clock=lambda: now[0])
    pacer.start()
    now[0] += 0.1
    assert pacer.poll() == 40 and sim.time_s == pytest.approx(0.2)
    now[0] += 0.0012  # less than one physics step of simulated time (0.0024 s < 0.005 s)... rounds down
    assert pacer.poll() == 0
    now[0] += 5.0  # the machine stalled: the backlog is dropped, not simulated in a burst
    assert pacer.poll() == 0 and pacer.overruns == 1 and sim.time_s == pytest.approx(0.2)
    # run(): polls until stopped; here a fake clock advancing 10 ms per reading stops it after 50 readings.
    stop = threading.Event()
    readings = [0]

    def clock() -> float:
        readings[0] += 1
        if readings[0] >= 50:
            stop.set()
        return 0.01 * readings[0]

    sim.set_command(VelocityCommand(0.4, 0.0))
    RealTimePacer(sim, clock=clock).run(stop, period_s=0.0)
    assert sim.time_s == pytest.approx(0.2 + 0.01 * 49, abs=0.006)
    assert sim.watchdog_stops == 0 and sim.body_velocity()[0] == pytest.approx(0.4, abs=0.01)


def test_velocity_and_acceleration_limits_hold() -> None:
    cfg = MujocoSimConfig()
    sim = MujocoSimulator(box_room(size_m=8.0, start=Pose2D(2.0, 4.0, 0.0)), seed=0, config=cfg)
    prev = sim.body_velocity()
    vs, ws = [], []
    for k in range(300):  # 1.5 s of an absurd command, then a reversal
        sim.set_command(VelocityCommand(5.0 if k < 200 else -5.0, 5.0 if k < 200 else -5.0))
        sim.advance(cfg.timestep_s)
        v, lateral, w = sim.body_velocity()
        assert abs(v) <= 1.0 + 1e-6 and abs(w) <= 0.78 + 1e-6 and abs(lateral) < 0.01  # (transient servo lag while ramping)
        assert abs(v - prev[0]) <= cfg.max_linear_accel_mps2 * cfg.timestep_s + 1e-6
        assert abs(w - prev[2]) <= cfg.max_angular_accel_radps2 * cfg.timestep_s + 1e-6
        prev = (v, lateral, w)
        vs.append(v)
        ws.append(w)
    assert max(vs) > 0.95 and max(ws) > 0.74  # the limits are reached, not just respected


def test_lockstep_same_seed_same_trajectory() -> None:
    sensor = SensorConfig(fov_deg=360.0, range_noise_std_m=0.02)
    cfg = MujocoSimConfig(odom_trans_noise_frac=0.05, odom_rot_noise_frac=0.05, odom_rot_per_trans_noise_radpm=0.05)
    config = ExplorationConfig(sensor=sensor, episode=EpisodeConfig(max_steps=30))

    def episode(seed: int) -> tuple[np.ndarray, Pose2D, np.ndarray]:
        sim = MujocoSimulator(l_plan(), sensor, seed=seed, config=cfg)
        result = run_episode(sim, make_policy("greedy-dist"), config, seed=seed)
        return result.trajectory_xy_m, sim.odometry(), sim.scan().ranges_m

    a, b, c = episode(5), episode(5), episode(6)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]
    np.testing.assert_array_equal(a[2], b[2])
    assert len(a[0]) > 5 and np.hypot(*(a[0][-1] - a[0][0])) > 0.5  # the robot explored
    assert a[1] != c[1]  # another seed, other odometry drift


def test_a_scan_between_control_steps_is_mapped_at_the_pose_it_was_taken() -> None:
    """The depth camera fires at 15 Hz, the controller at 4 Hz: the latest scan of a step is up to 1/15 s
    old. ``sensor_pose()`` is its pose, so a robot turning in place maps the walls where they are; at
    the pose of now every turn smeared walls into the room (0.6 m2 of free space mapped occupied on a
    small generated scene, which ended the episode at 97 % with no frontier left)."""
    sim = MujocoSimulator(box_room(start=Pose2D(0.6, 0.6, 0.3)), SensorConfig.preset("depth"), seed=0)  # in a corner
    occupancy = OccupancyMap(sim.plan.geometry)
    stale = 0
    for _ in range(24):
        sim.step(VelocityCommand(0.0, 0.78))
        fired = sim.drain_scans()
        assert sim.sensor_pose() == fired[-1][0]  # the pose of the scan that scan() returns
        now = sim.odometry().compose_offset(sim.lidar_mount_x_m)
        stale += abs(wrap_angle_rad(now.yaw_rad - fired[-1][0].yaw_rad)) > math.radians(1.0)
        occupancy.integrate_scan(sim.sensor_pose(), sim.scan())
    assert stale >= 12  # most steps' scans were taken before the step ended
    inside = np.zeros_like(sim.plan.free)
    inside[2:-2, 2:-2] = True  # a cell or more away from the inner wall faces
    assert occupancy.explored[inside].sum() > 1000
    assert not (occupancy.occupied & inside).any()


def test_odometry_drift_and_sensor_pose() -> None:
    cfg = MujocoSimConfig(odom_trans_noise_frac=0.05, odom_rot_per_trans_noise_radpm=0.05)
    sim = MujocoSimulator(box_room(size_m=8.0, start=Pose2D(1.0, 4.0, 0.0)), seed=2, config=cfg)
    for _ in range(20):
        sim.step(VelocityCommand(1.0, 0.1))
    truth, odom = sim.true_pose(), sim.odometry()
    err = math.hypot(truth.x_m - odom.x_m, truth.y_m - odom.y_m)
    assert 1e-4 < err < 0.3  # drift is there, and of the configured order (5 % of ~4.6 m at most)
    assert sim.sensor_pose() == odom.compose_offset(0.103)


@pytest.mark.parametrize("stamp_s", [float("nan"), float("inf"), -float("inf")])
def test_a_command_with_a_non_finite_stamp_is_rejected(stamp_s: float) -> None:
    """A NaN or infinite stamp was accepted, and every later ``advance`` died computing the watchdog's deadline
    (ValueError: cannot convert float NaN to integer; OverflowError for inf): the command is refused instead."""
    sim = MujocoSimulator(box_room(), seed=0)
    sim.set_command(VelocityCommand(0.5, 0.0))
    assert not sim.set_command(VelocityCommand(0.2, 0.0), stamp_s=stamp_s) and sim.rejected_commands == 1
    assert sim.advance(0.4) == 80  # within the watchdog: the last good command still drives it
    assert sim.body_velocity()[0] == pytest.approx(0.5, abs=0.01)


@pytest.mark.parametrize(
    ("start", "match"),
    [
        (Pose2D(0.02, 2.0, 0.0), "not on free space"),  # inside the boundary wall
        (Pose2D(-3.0, 2.0, 0.0), r"off the plan \(4 x 4 m"),  # wrapped round to a free cell (negative index)
        (Pose2D(9.0, 2.0, 0.0), "off the plan"),
        (Pose2D(math.nan, 2.0, 0.0), "not finite"),
        (Pose2D(2.0, 2.0, math.inf), "not finite"),
    ],
)
def test_a_start_the_limo_cannot_stand_on_is_refused(start: Pose2D, match: str) -> None:
    """A start in a wall was only warned of, and the contact shot the LIMO 1.45 m out of it in the first step; one off
    the plan drove outside every wall; a NaN start went into the MJCF as "nan" and MuJoCo reset the unstable state to
    the map origin. Each is a SceneError before the world is built, as ``traversable_region`` says of the plan."""
    plan = box_room(start=start)
    with pytest.raises(SceneError, match=match):
        MujocoSimulator(plan, seed=0)
    with pytest.raises(SceneError, match=match):
        plan.traversable_region()
    with pytest.raises(SceneError, match="not on free space"):
        MujocoSimulator(FloorPlan("solid", np.zeros((40, 40), dtype=bool), RES, Pose2D(1.0, 1.0, 0.0)), seed=0)


def test_the_limo_warns_of_a_start_overlapping_a_wall_in_the_words_up_says_before_it_starts(caplog) -> None:
    """The MuJoCo LIMO's warning of a body that overlaps a wall at the start is ``scenes.start_overlap_said``, the one
    check ``up`` makes before anything starts: the same condition (the box body against the wall cells, as the model's
    contacts after ``mj_forward`` had it) and the same words, at every reset; none for a start clear of the walls."""
    import logging

    from cso_runtime.scenes import start_overlap_said

    against = box_room(start=Pose2D(RES + 0.13, 2.0, 0.0))  # the LIMO's half length is 0.161 m
    said = start_overlap_said(against, RobotConfig().length_m, RobotConfig().width_m)
    assert said is not None
    with caplog.at_level(logging.WARNING, logger="robot_sim.sim"):
        sim = MujocoSimulator(against, seed=0)
        sim.reset(1)
    assert [r.getMessage() for r in caplog.records if "overlaps a wall" in r.getMessage()] == [said, said]
    assert sim.data.ncon  # the model has the contact the check said
    caplog.clear()
    clear = box_room(start=Pose2D(RES + 0.13, 2.0, 0.5 * math.pi))  # turned across the wall: its half width, 0.11 m
    assert start_overlap_said(clear, RobotConfig().length_m, RobotConfig().width_m) is None
    with caplog.at_level(logging.WARNING, logger="robot_sim.sim"):
        sim = MujocoSimulator(clear, seed=0)
    assert not sim.data.ncon and not [r for r in caplog.records if "overlaps a wall" in r.getMessage()]


def test_the_headless_simulator_needs_no_display_and_a_bad_mujoco_gl_is_explained() -> None:
    """The simulator renders nothing: without DISPLAY or MUJOCO_GL it builds and steps. ``import mujoco`` sets up the
    renderer MUJOCO_GL names, and an unusable one (osmesa without libOSMesa: "'NoneType' object has no attribute
    'glGetError'") broke ``import robot_sim`` with nothing said about MUJOCO_GL: the error now says to unset it."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    script = (
        "import numpy as np; from cso_runtime.scenes import FloorPlan; from cso_runtime.geometry import Pose2D, VelocityCommand;"
        "from robot_sim import MujocoSimulator; free = np.zeros((40, 40), bool); free[1:-1, 1:-1] = True;"
        "sim = MujocoSimulator(FloorPlan('box', free, 0.05, Pose2D(1.0, 1.0, 0.0)), seed=0); sim.step(VelocityCommand(0.5, 0.0));"
        "print(sim.odometry().x_m > 1.0, len(sim.scan().ranges_m))"
    )
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.split() == ["True", "181"], run.stderr
    bad = subprocess.run([sys.executable, "-c", "import robot_sim"], env={**env, "MUJOCO_GL": "nosuch"}, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1
    assert "cannot import mujoco with MUJOCO_GL='nosuch'" in bad.stderr and "needs no MUJOCO_GL: unset it" in bad.stderr, bad.stderr


@pytest.mark.parametrize(
    ("robot", "sensor", "match"),
    [
        (RobotConfig(max_linear_mps=math.nan), SensorConfig(), "robot.max_linear_mps must be positive and finite"),
        (RobotConfig(max_angular_radps=0.0), SensorConfig(), "robot.max_angular_radps must be positive"),
        (RobotConfig(length_m=0.0), SensorConfig(), "robot.length_m must be positive"),
        (RobotConfig(control_period_s=math.inf), SensorConfig(), "robot.control_period_s must be positive and finite"),
        (RobotConfig(), SensorConfig(rate_hz=1000.0), r"sensor.rate_hz \(1000 Hz\) is above the physics rate \(200 Hz"),
    ],
)
def test_a_robot_or_sensor_the_model_cannot_honour_is_a_config_error(robot: RobotConfig, sensor: SensorConfig, match: str) -> None:
    """The simulator validated its sensor and physics but not the robot: a NaN speed limit went into the MJCF as "nan"
    and the LIMO never moved ("Nan, Inf or huge value in CTRL"); a zero turn rate or body length came out as MuJoCo's
    XML error, an infinite control period as an OverflowError. A LiDAR faster than the physics fired several scans
    with the same stamp and pose each step (a 1 kHz LiDAR: 64 scans of 13 stamps per 0.25 s step, 186 dropped)."""
    with pytest.raises(ConfigError, match=match):
        MujocoSimulator(box_room(), sensor, robot, seed=0)


@pytest.mark.parametrize(("kwargs", "match"), [({"speed": math.inf}, "speed"), ({"max_lag_s": math.nan}, "max_lag_s"), ({"max_lag_s": -1.0}, "max_lag_s")])
def test_a_real_time_pacer_refuses_what_it_cannot_keep(kwargs: dict, match: str) -> None:
    """An infinite speed was taken and its first poll died in ``advance(inf)``; a NaN lag never dropped a backlog, and a
    negative one dropped every poll's steps, so the simulation never moved."""
    with pytest.raises(ValueError, match=f"{match} must be positive and finite"):
        RealTimePacer(MujocoSimulator(box_room(), seed=0), **kwargs)


@pytest.mark.parametrize(
    ("flags", "said"),
    [
        (["--scene", "{tmp}/truncated.png"], "truncated.png: not a readable image"),
        (["--scene", "{tmp}/missing.png"], "missing.png: file not found"),
        (["--scene", "generated:tiny:1:0"], "generated scale must be one of"),
        (["--scene", "{tmp}/walled_in.png"], "start pose is not on free space"),
        (["--seed", "-1"], "--seed must be an integer from 0"),
    ],
)
def test_the_fake_limo_says_what_is_wrong_with_its_scene_or_seed_and_exits_2(tmp_path: Path, capsys, flags: list[str], said: str) -> None:
    """A corrupt, missing or unusable plan (or a negative seed) ended the fake LIMO in a traceback (a SceneError or
    numpy's "expected non-negative integer"), exit code 1; it is a bad flag: exit 2 with one line, as for the sim service."""
    from PIL import Image

    from robot_sim import fake_limo

    good = Path(__file__).resolve().parents[1] / "cso_runtime" / "data" / "scenes"
    png = next(good.glob("*.png")).read_bytes()
    (tmp_path / "truncated.png").write_bytes(png[: len(png) // 2])
    rgb = np.full((8, 8, 3), (195, 195, 194), dtype=np.uint8)
    rgb[2:5, 2:5] = (255, 216, 0)  # a start marker, a ring whose centre ...
    rgb[3, 3] = (127, 127, 127)  # ... is a wall
    Image.fromarray(rgb).save(tmp_path / "walled_in.png")
    with pytest.raises(SystemExit) as exited:
        fake_limo.main(["--listen", "tcp/127.0.0.1:1", *(f.format(tmp=tmp_path) for f in flags)])
    assert exited.value.code == 2
    assert said in capsys.readouterr().err


def test_every_yaw_wraps_into_minus_pi_to_pi_the_float_just_below_minus_pi_included() -> None:
    """``wrap_angle_rad`` (odometry, ground truth, REP-103 yaws) gave +pi for the float just below -pi: ``(-ulp) % 2 pi``
    rounds to 2 pi itself, so the result lay outside its own [-pi, pi)."""
    below = float(np.nextafter(-math.pi, -math.inf))
    for angle in (below, below - 2 * math.pi, below + 4 * math.pi, -math.pi, math.pi, 3 * math.pi, 0.0, -1e-300, 7.0, -7.0):
        wrapped = wrap_angle_rad(angle)
        assert -math.pi <= wrapped < math.pi, (angle, wrapped)
        assert math.isclose(math.cos(wrapped), math.cos(angle), abs_tol=1e-12) and math.isclose(math.sin(wrapped), math.sin(angle), abs_tol=1e-12)
    assert wrap_angle_rad(below) == -math.pi
    assert math.isnan(wrap_angle_rad(math.nan))
    plan = box_room(start=Pose2D(2.0, 2.0, below))
    assert plan.to_map_frame(plan.start).yaw_rad == -math.pi  # compose_pose wraps it
    assert MujocoSimulator(plan, seed=0).true_pose().yaw_rad == -math.pi


@pytest.mark.parametrize("backend", ["2d", "mujoco"])
def test_both_simulators_report_the_start_yaw_in_minus_pi_to_pi(backend: str) -> None:
    """The 2D simulator reported a plan's start yaw as given (4 rad) in its odometry, ground truth and sensor pose until
    its first step, where it wrapped it; the MuJoCo LIMO wraps it at once. Both now say the same REP-103 yaw."""
    from cso_runtime.simulator import make_simulator

    sim = make_simulator(backend, box_room(start=Pose2D(2.0, 2.0, 4.0)), SensorConfig(), RobotConfig(), seed=0)
    for pose in (sim.odometry(), sim.true_pose(), sim.sensor_pose()):
        assert pose.yaw_rad == pytest.approx(4.0 - 2 * math.pi, abs=1e-12)


@pytest.mark.parametrize("backend", ["2d", "mujoco"])
@pytest.mark.parametrize(("control_period_s", "max_linear_mps"), [(0.25, 1.0), (1.0, 5.0), (2.0, 2.0)])
def test_no_robot_the_config_takes_drives_through_a_one_cell_wall(backend: str, control_period_s: float, max_linear_mps: float) -> None:
    """The 2D simulator checks each of its substeps at its end only, and took five per step whatever the step's length:
    with a 1 s step at 5 m/s (robot limits it accepts) each was 1 m, and the disc jumped a 5 cm wall onto the floor
    behind it (x 5.75 m after 4 s). A substep is now at most the disc's radius at full speed."""
    from cso_runtime.simulator import make_simulator

    free = np.zeros((80, 120), dtype=bool)
    free[1:-1, 1:-1] = True
    free[:, 60] = False  # a wall one cell thick, x from 3.0 to 3.05 m
    plan = FloorPlan("wall", free, RES, Pose2D(2.5, 2.0, 0.0))
    robot = RobotConfig(control_period_s=control_period_s, max_linear_mps=max_linear_mps)
    sim = make_simulator(backend, plan, SensorConfig(), robot, seed=0)
    for _ in range(int(round(4.0 / control_period_s))):
        sim.step(VelocityCommand(max_linear_mps, 0.0))
    assert 2.7 < sim.true_pose().x_m < 3.0 - 0.1  # it drove up to the wall, and stopped at it


@pytest.mark.parametrize(
    ("resolution_m", "start_x_m", "control_period_s", "max_linear_mps"),
    [(0.02, 2.99, 0.25, 1.0), (0.02, 2.995, 0.25, 1.0), (0.05, 2.98, 1.0, 5.0)],
)
def test_a_2d_robot_that_starts_against_a_thin_wall_does_not_drive_through_it(resolution_m: float, start_x_m: float, control_period_s: float, max_linear_mps: float) -> None:
    """A robot in contact (a start on a free cell next to a wall, closer than the disc's radius) may move where its
    clearance does not shrink: a substep longer than the wall's thickness plus twice that clearance ended beyond the
    wall, as clear of it as the start, and was taken. The LIMO's own 5 cm substeps crossed a 2 cm cell's wall from 1 cm
    (x 4.99 m after 2 s). The robot stays at the wall, and can still slide along it and back away."""
    from cso_runtime.simulator import KinematicSimulator

    cols = int(round(6.0 / resolution_m))
    free = np.zeros((int(round(4.0 / resolution_m)), cols), dtype=bool)
    free[1:-1, 1:-1] = True
    free[:, cols // 2] = False  # a wall one cell thick, from x 3.0 m
    plan = FloorPlan("wall", free, resolution_m, Pose2D(start_x_m, 2.0, 0.0))
    robot = RobotConfig(control_period_s=control_period_s, max_linear_mps=max_linear_mps)
    sim = KinematicSimulator(plan, SensorConfig(), robot, seed=0)
    for _ in range(int(round(2.0 / control_period_s))):
        sim.step(VelocityCommand(max_linear_mps, 0.0))
    assert sim.true_pose().x_m == start_x_m and sim.collisions > 0  # it stayed where it touched the wall
    for yaw_rad, moved in ((math.pi / 2, (0.0, 0.1)), (math.pi, (-0.1, 0.0))):  # along the wall, and away from it
        sim = KinematicSimulator(dataclasses.replace(plan, start=Pose2D(start_x_m, 2.0, yaw_rad)), SensorConfig(), robot, seed=0)
        sim.step(VelocityCommand(0.1 / control_period_s, 0.0))
        assert (sim.true_pose().x_m, sim.true_pose().y_m) == pytest.approx((start_x_m + moved[0], 2.0 + moved[1]), abs=1e-9)


def thin_wall_room(wall_m: float) -> FloorPlan:
    """A 5 x 3 m room split at x = 2.5 m by a wall one cell (``wall_m``) thick; the LIMO at x = 1 m facing it."""
    free = np.zeros((int(round(3.0 / wall_m)), int(round(5.0 / wall_m))), dtype=bool)
    free[1:-1, 1:-1] = True
    free[:, int(round(2.5 / wall_m))] = False
    return FloorPlan("thin_wall", free, wall_m, Pose2D(1.0, 1.5, 0.0))


def test_settings_whose_walls_cannot_stop_the_robot_at_top_speed_are_refused_with_settings_that_work(monkeypatch) -> None:
    """At the coarsest settings each bound took (``timestep_s`` 0.05, so ``contact_time_constant_s`` 0.1; ``robot.max_linear_mps``
    5, 100 m/s2, the strongest servo) the LIMO moved 25 cm a physics step and drove through a 1 or 5 cm wall. Contacts are
    soft: at 5 m/s the body sinks that far into a 0.1 s contact even at a 5 ms step, and MuJoCo pushes a body past a wall's
    middle out on the far side. ``contact_time_constant_s`` x ``robot.max_linear_mps`` (which bounds ``timestep_s`` x it:
    the contact is two steps or more) is now at most half the robot's smaller side, refused before anything starts with a
    speed and a contact (and step) that work; at each of those, the same drive stops at the wall."""
    from cso_runtime.simulator import mujoco_config
    from robot_sim.config import MAX_TIMESTEP_S

    coarse = {"timestep_s": MAX_TIMESTEP_S, "max_linear_accel_mps2": 100.0, "traction_force_n": 10_000.0, "odometry_rate_hz": 20.0,
              "actuator_time_constant_s": 0.1, "contact_time_constant_s": 0.1}
    fast = RobotConfig(max_linear_mps=5.0)
    said = (r"contact_time_constant_s \(0.1 s\) x robot.max_linear_mps \(5 m/s\) is 0.5 m, more than half the robot's smaller side "
            r"\(robot.width_m 0.22 m: 0.11 m; timestep_s \(0.05 s\) x it: 0.25 m a physics step\).* Use robot.max_linear_mps 1.1 m/s or less, "
            r"or contact_time_constant_s 0.022 s or less with timestep_s 0.01 s or finer")
    with pytest.raises(ConfigError, match=said):
        MujocoSimulator(thin_wall_room(0.05), robot=fast, config=MujocoSimConfig(**coarse))
    with pytest.raises(ConfigError, match="^services.sim.mujoco: " + said):  # eval's and up's check, before anything starts
        mujoco_config(coarse, SensorConfig(), where="services.sim.mujoco", robot=fast)
    with pytest.raises(ConfigError, match=r"0.5 m.* Use robot.max_linear_mps 1.1 m/s or less, or contact_time_constant_s 0.022 s or less$"):
        mujoco_config({"contact_time_constant_s": 0.1, "traction_force_n": 10_000.0}, SensorConfig(), robot=fast)  # at a 5 ms step too

    def drive(robot: RobotConfig, config: MujocoSimConfig, wall_m: float) -> float:
        sim = MujocoSimulator(thin_wall_room(wall_m), robot=robot, seed=0, config=config)
        for _ in range(12):  # 3 s at full speed into the wall
            sim.step(VelocityCommand(robot.max_linear_mps, 0.0))
        return sim.true_pose().x_m

    with monkeypatch.context() as unchecked:  # what the check keeps out: through the wall and on across the room
        unchecked.setattr("robot_sim.sim.check_walls_hold", lambda *_: None)
        assert drive(fast, MujocoSimConfig(**coarse), 0.05) > 2.6
        assert drive(fast, MujocoSimConfig(contact_time_constant_s=0.1, traction_force_n=10_000.0, max_linear_accel_mps2=100.0), 0.01) > 2.6
    stiffer = dataclasses.replace(MujocoSimConfig(**coarse), timestep_s=0.01, contact_time_constant_s=0.022, actuator_time_constant_s=0.022)
    for wall_m in (0.01, 0.05):  # either way out the error names stops the LIMO at the wall
        assert drive(RobotConfig(max_linear_mps=1.1), MujocoSimConfig(**coarse), wall_m) < 2.5
        assert drive(fast, stiffer, wall_m) < 2.5
    # The defaults, and the coarsest step at the LIMO's own top speed, stay valid.
    mujoco_config({}, SensorConfig(), robot=RobotConfig())
    mujoco_config(coarse, SensorConfig(), robot=RobotConfig())
    mujoco_config({}, SensorConfig(), robot=fast)


@pytest.mark.parametrize(
    ("robot", "sim"),
    [
        # 0.25 s / 6 = 0.0416667 s: twice that, 0.0833334 s, is above the contact said (0.0833333 s), and was refused
        (RobotConfig(max_linear_mps=1.32), {"timestep_s": 0.05, "contact_time_constant_s": 0.1, "actuator_time_constant_s": 0.1, "odometry_rate_hz": 4.0}),
        (RobotConfig(max_linear_mps=5.0), {"timestep_s": 0.05, "contact_time_constant_s": 0.1, "actuator_time_constant_s": 0.1, "odometry_rate_hz": 20.0}),
        (RobotConfig(max_linear_mps=2.47, length_m=0.052, width_m=0.119, control_period_s=0.3),
         {"timestep_s": 0.3 / 19, "contact_time_constant_s": 0.683, "actuator_time_constant_s": 0.1, "odometry_rate_hz": 1 / (0.3 / 19 * 3)}),
        (RobotConfig(max_linear_mps=3.0), {"contact_time_constant_s": 0.2}),
    ],
)
def test_each_way_out_a_through_wall_refusal_names_is_taken_as_written(robot: RobotConfig, sim: dict[str, float]) -> None:
    """The speed, and the contact (with the physics step, where the step is too coarse for it), that the refusal of
    walls too soft for the robot's top speed names, written back as the message writes them, are each taken by every
    check of the MuJoCo LIMO's settings (``mujoco_config``: ``validate``'s two physics steps a contact, whole steps of the
    control and odometry periods, the walls). The step was the quotient of the control period rounded for the message:
    a step a hair above half the contact said (or rounded up to it) was refused by ``validate`` in turn."""
    from cso_runtime.simulator import mujoco_config

    with pytest.raises(ConfigError) as refused:
        mujoco_config(sim, SensorConfig(), robot=robot)
    said = re.search(r"Use (?:robot.max_linear_mps (\S+) m/s or less, or )?contact_time_constant_s (\S+) s or less(?: with timestep_s (\S+) s or finer)?", str(refused.value))
    assert said is not None, refused.value
    speed, contact, step = said.groups()
    if speed is not None:  # named only where the exploration config takes it (not below planner.backup_speed_mps: test_config)
        mujoco_config(sim, SensorConfig(), robot=dataclasses.replace(robot, max_linear_mps=float(speed)))
    mujoco_config({**sim, "contact_time_constant_s": float(contact), **({"timestep_s": float(step)} if step else {})}, SensorConfig(), robot=robot)
