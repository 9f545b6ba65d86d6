"""The MuJoCo world as a file (keyframe ``start``, ``scenes --mjcf``) and the sim service's viewer window.

No test opens a window (CI has no display): the viewer runs on a stand-in for ``launch_passive``'s
handle that records what the window would get, and the display check is forced both ways."""

from __future__ import annotations

import contextlib
import re

import mujoco
import numpy as np
import pytest
from typer.testing import CliRunner

from cso_runtime.cli import app
from cso_runtime.config import ConfigError, ExplorationConfig, RobotConfig, SensorConfig
from cso_runtime.geometry import Pose2D, VelocityCommand
from cso_runtime.scene_generator import generate_floor_plan
from cso_runtime.scenes import FloorPlan
from cso_runtime.transport import TransportConfig
from robot_sim import MujocoSimConfig, MujocoSimulator
from robot_sim import viewer as viewer_module
from robot_sim.scene import write_mujoco_world
from robot_sim.viewer import GOAL_HEIGHT_M, SimViewer
from services.common import ServiceContext


class FakeHandle:
    """What ``mujoco.viewer.launch_passive`` returns, minus the window: counts syncs, keeps the overlay."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData):
        self.model, self.data = model, data
        self.user_scn = mujoco.MjvScene(model, 10)
        self.synced_xy: list[tuple[float, float]] = []
        self.running = True
        self.closed = 0

    def is_running(self) -> bool:
        return self.running

    def lock(self) -> contextlib.AbstractContextManager:
        return contextlib.nullcontext()

    def sync(self) -> None:
        self.synced_xy.append((float(self.data.qpos[0]), float(self.data.qpos[1])))

    def close(self) -> None:
        self.closed += 1


def test_the_world_file_opens_with_the_limo_at_the_start_pose(tmp_path):
    plan = generate_floor_plan("small", 5)
    path = write_mujoco_world(tmp_path / "w.xml", plan)
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("start").id)
    mujoco.mj_forward(model, data)
    assert np.allclose(data.qpos, [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad])
    assert data.ncon == 0  # the LIMO stands free of the walls there
    sim = MujocoSimulator(plan, SensorConfig())  # the simulator's own world is the same file
    assert model.ngeom == sim.model.ngeom and np.allclose(model.geom_size, sim.model.geom_size)
    assert np.allclose(sim.data.qpos, data.qpos)


def _heading_rad(data: mujoco.MjData, body: str) -> float:
    xmat = data.body(body).xmat
    return float(np.arctan2(xmat[3], xmat[0]))


@pytest.mark.parametrize("yaw_rad", [None, 2.5, -1.0])  # the plan's own start, and turned ones (a map YAML's start: [x, y, yaw])
def test_the_world_file_opened_as_it_is_has_the_limo_at_the_start_pose(tmp_path, yaw_rad):
    """``python -m mujoco.viewer --mjcf FILE`` (or ``MjData(model)``, ``mj_resetData``, the viewer's Reset) starts at
    qpos0, which was the map origin: the LIMO inside the boundary wall, whose contact threw it off the map unless the
    user knew to load the key ``start``. qpos0 is the start pose now (exactly: where eval's episodes start), the
    joints still world-aligned (qpos is the map pose anywhere), and the key kept for code that loads it."""
    plan = generate_floor_plan("small", 5)
    if yaw_rad is not None:
        plan = FloorPlan(plan.name, plan.free, plan.resolution_m, Pose2D(plan.start.x_m, plan.start.y_m, yaw_rad))
    start = plan.start
    model = mujoco.MjModel.from_xml_path(str(write_mujoco_world(tmp_path / "w.xml", plan)))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.qpos.tolist() == [start.x_m, start.y_m, start.yaw_rad]
    assert np.array_equal(model.key("start").qpos, model.qpos0)
    assert np.allclose(data.body("limo").xpos, [start.x_m, start.y_m, 0.0], atol=1e-12)
    assert _heading_rad(data, "limo") == pytest.approx(start.yaw_rad, abs=1e-12)
    assert data.ncon == 0  # free of the walls
    mujoco.mj_step(model, data, 400)  # 2 s with nothing pressed: it stays there
    assert np.allclose(data.qpos, model.qpos0, atol=1e-9) and data.ncon == 0
    data.qpos[:] = [start.x_m + 0.3, start.y_m - 0.2, start.yaw_rad + 0.5]  # away from the start, qpos is the map pose
    mujoco.mj_forward(model, data)
    assert np.allclose(data.body("limo").xpos, [start.x_m + 0.3, start.y_m - 0.2, 0.0], atol=1e-12)
    turned_rad = np.arctan2(np.sin(start.yaw_rad + 0.5), np.cos(start.yaw_rad + 0.5))
    assert _heading_rad(data, "limo") == pytest.approx(turned_rad, abs=1e-12)


def test_the_simulator_steps_the_world_of_its_file():
    """``sim.mjcf`` (the file ``scenes --mjcf`` writes) has qpos0 at the start; the model the simulator steps keeps it at
    the map origin, since MuJoCo places the base at body_pos + (qpos - qpos0) and a start there would change the last
    bits of every episode. Both are one world: driven alike into a wall, they stay together to far below a millimetre."""
    plan = generate_floor_plan("small", 0)
    sim = MujocoSimulator(plan, SensorConfig())
    assert sim.model.qpos0.tolist() == [0.0, 0.0, 0.0] and sim.model.body("limo").pos.tolist() == [0.0, 0.0, 0.0]
    model = mujoco.MjModel.from_xml_string(sim.mjcf)
    assert model.qpos0.tolist() == [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad]
    data = mujoco.MjData(model)
    for m, d in ((model, data), (sim.model, sim.data)):
        mujoco.mj_resetData(m, d)
        d.qpos[:] = [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad]
        d.ctrl[:] = [0.8, 0.0, 0.3]
    contacts = 0
    for _ in range(800):  # 4 s: it reaches a wall and scrapes along it
        mujoco.mj_step(model, data)
        mujoco.mj_step(sim.model, sim.data)
        contacts += data.ncon > 0
        assert data.ncon == sim.data.ncon
    assert contacts > 100
    assert np.allclose(data.qpos, sim.data.qpos, atol=1e-9) and np.allclose(data.qvel, sim.data.qvel, atol=1e-9)


def test_the_world_file_says_its_units_frames_controls_and_parameters(tmp_path):
    """Opened on its own (``python -m mujoco.viewer --mjcf FILE``), the file said nothing of its units, frames,
    default pose (qpos0) and key, controls, geom groups or the parameters it was built with."""
    import dataclasses

    plan = generate_floor_plan("small", 0)
    config = MujocoSimConfig(mass_kg=5.5, timestep_s=0.0025)
    path = write_mujoco_world(tmp_path / "w.xml", plan, sim=config, sensor=SensorConfig(mount_x_m=0.103))
    text = path.read_text()
    header = re.fullmatch(r"<!--(.*?)-->\n<mujoco .*", text, re.DOTALL)
    assert header is not None, text[:300]
    about = " ".join(header.group(1).split())
    for said in ("metres", "radians", "REP-103", 'key "start"', "default pose qpos0", "is the plan's start pose", "drive_forward m/s",
                 "drive_yaw rad/s", "0 walls", "configs/robot_sim.yaml", "every 0.25 s", "2 m/s^2", "3 rad/s^2", "1 m/s",
                 "0.78 rad/s", "mj_multiRay", "geom group 0", "no rangefinder", "base_vel"):  # fmt: skip
        assert said in about, (said, about)
    resolved = {**dataclasses.asdict(config), "lidar_mount_x_m": 0.103}
    assert re.findall(r"(\w+)=(\S+)", about) == [(k, f"{v:g}" if isinstance(v, float) else str(v).lower()) for k, v in resolved.items()]
    model = mujoco.MjModel.from_xml_path(str(path))  # the comment keeps the file a valid MJCF
    assert model.opt.timestep == 0.0025 and model.body("limo").mass[0] == pytest.approx(5.5)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert data.qpos.tolist() == [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad] and data.ncon == 0  # as it says


def _limits(robot: RobotConfig, sim: MujocoSimConfig) -> list[list[float]]:
    lateral_mps = robot.max_linear_mps * robot.max_angular_radps * sim.actuator_time_constant_s
    v_mps, w_radps = robot.max_linear_mps, robot.max_angular_radps
    return [[-v_mps, v_mps], [-lateral_mps, lateral_mps], [-w_radps, w_radps]]


@pytest.mark.parametrize("robot", [RobotConfig(), RobotConfig(max_linear_mps=0.6, max_angular_radps=1.3)])
def test_the_controls_are_limited_to_what_the_simulator_sends(tmp_path, robot):
    """The actuators had no ctrlrange: the viewer's sliders went from -1 to 1 whatever the robot's limits, and
    drive_lateral (the centripetal feed-forward, a few cm/s at most) invited driving a skid-steer robot sideways. Each
    control is now limited to the most the simulator ever sends, in the file and in the model it steps, so the limit
    never acts in an episode: commands at and over the robot's limits stay inside it, step after step."""
    plan = generate_floor_plan("small", 0)
    config = MujocoSimConfig()
    sim = MujocoSimulator(plan, SensorConfig(), robot, config=config)
    file_model = mujoco.MjModel.from_xml_path(str(write_mujoco_world(tmp_path / "w.xml", plan, robot, config)))
    for model in (file_model, sim.model):
        assert model.actuator_ctrllimited.tolist() == [1, 1, 1]
        assert model.actuator_ctrlrange.tolist() == _limits(robot, config)
    low, high = sim.model.actuator_ctrlrange.T
    most = np.zeros(3)
    rng = np.random.default_rng(0)
    for i in range(60):  # at, just over and far over the limits, both signs, each for 1 s: the ramps reach them
        over = [1.0, 1.0 + 1e-12, 5.0][i % 3]
        v, w = (over * limit * rng.choice([-1.0, 1.0]) for limit in (robot.max_linear_mps, robot.max_angular_radps))
        sim.set_command(VelocityCommand(v, w))
        for _ in range(200):
            sim.advance(config.timestep_s)
            assert np.all(low <= sim.data.ctrl) and np.all(sim.data.ctrl <= high), sim.data.ctrl
            most = np.maximum(most, np.abs(sim.data.ctrl))
    assert most.tolist() == high.tolist()  # each range is the most the simulator sends, no more


def test_the_world_file_has_pose_and_velocity_sensors(tmp_path):
    """The file had no sensors: a MuJoCo user got no pose or velocity readings of the LIMO. It has the base's map pose
    (framepos, framequat), its body-frame velocity (velocimeter, gyro: what drive_forward and drive_yaw command) and the
    LiDAR's position; the model the simulator steps has the same ones (the viewer copies its data into the file's)."""
    plan = generate_floor_plan("small", 0)
    start = plan.start
    model = mujoco.MjModel.from_xml_path(str(write_mujoco_world(tmp_path / "w.xml", plan)))
    names = [model.sensor(i).name for i in range(model.nsensor)]
    assert names == ["base_pos", "base_quat", "base_vel", "base_gyro", "lidar_pos"]
    data = mujoco.MjData(model)
    data.ctrl[:] = [0.4, 0.4 * 0.3 * 0.02, 0.3]  # v, the centripetal feed-forward v * w * tau, w (as the header says)
    mujoco.mj_step(model, data, 200)  # 1 s: the servos have reached the command (time constant 20 ms)
    mujoco.mj_forward(model, data)  # the readings of the state after the last step
    x, y, yaw = data.qpos
    assert np.allclose(data.sensor("base_pos").data, [x, y, 0.0], atol=1e-12)
    assert np.allclose(data.sensor("base_quat").data, [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)], atol=1e-12)
    vx, vy, _ = data.qvel
    body_vel = [np.cos(yaw) * vx + np.sin(yaw) * vy, -np.sin(yaw) * vx + np.cos(yaw) * vy, 0.0]
    assert np.allclose(data.sensor("base_vel").data, body_vel, atol=1e-12)
    assert np.allclose(data.sensor("base_vel").data, [0.4, 0.0, 0.0], atol=1e-3)
    assert np.allclose(data.sensor("base_gyro").data, [0.0, 0.0, 0.3], atol=1e-3)
    assert np.allclose(data.sensor("lidar_pos").data, [x + 0.103 * np.cos(yaw), y + 0.103 * np.sin(yaw), 0.2], atol=1e-12)
    assert (x, y) != (start.x_m, start.y_m)
    sim = MujocoSimulator(plan, SensorConfig())  # its model has them too (the same sizes), not computed while it steps
    assert [sim.model.sensor(i).name for i in range(sim.model.nsensor)] == names and sim.model.nsensordata == model.nsensordata
    assert sim.model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_SENSOR
    view = SimViewer(sim, launch=FakeHandle)  # the window shows the readings of the state it shows
    sim.step(VelocityCommand(0.5, 0.2))
    assert view.show()
    x, y, yaw = sim.data.qpos
    assert np.allclose(view.handle.data.sensor("base_pos").data, [x, y, 0.0], atol=1e-12)
    assert np.allclose(view.handle.data.sensor("base_gyro").data, [0.0, 0.0, sim.data.qvel[2]], atol=1e-12)


def test_the_wheels_are_turned_exactly_upright(tmp_path):
    """The visual wheels were turned by euler="1.5708", 3.7e-6 rad short of a right angle; they carry no mass, so the
    exact angle changes no dynamics."""
    model = mujoco.MjModel.from_xml_path(str(write_mujoco_world(tmp_path / "w.xml", generate_floor_plan("small", 0))))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for wheel in ("wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr"):
        assert abs(data.geom(wheel).xmat[8]) < 1e-15  # the cylinder's axis is level
        assert model.geom(wheel).contype == 0 and model.geom(wheel).conaffinity == 0


@pytest.mark.parametrize("name", ['my "lab"', "lab & office", "a<b"])
def test_a_plan_name_with_xml_characters_makes_a_well_formed_world(tmp_path, name):
    """The plan's name (a PNG's or map YAML's file stem) went into the model name unescaped: a quote made
    ``MujocoSimulator`` fail with MuJoCo's XML parse error, '&' and '<' wrote a file other XML tools reject."""
    import xml.etree.ElementTree as ET

    plan = generate_floor_plan("small", 0)
    plan = FloorPlan(name, plan.free, plan.resolution_m, plan.start)
    sim = MujocoSimulator(plan, SensorConfig())
    assert sim.model.names.split(b"\0")[0].decode() == f"limo_{name}"
    path = write_mujoco_world(tmp_path / "w.xml", plan)
    assert ET.parse(path).getroot().get("model") == f"limo_{name}"


def test_scenes_writes_a_mujoco_world_per_plan(tmp_path):
    out = tmp_path / "worlds"
    result = CliRunner().invoke(app, ["scenes", "generated:small:2:0", "--mjcf", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["gen_small_0.xml", "gen_small_1.xml"]
    assert f"MuJoCo worlds in {out}" in " ".join(result.output.split())
    model = mujoco.MjModel.from_xml_path(str(out / "gen_small_1.xml"))
    start = generate_floor_plan("small", 1).start
    assert np.allclose(model.key("start").qpos, [start.x_m, start.y_m, start.yaw_rad])


def test_scenes_writes_the_world_of_a_sim_config(tmp_path):
    """``scenes --mjcf`` wrote every world with the default parameters, so the world an ``eval --sim mujoco
    --sim-config FILE`` ran in could not be written out; ``--sim-config`` gives it (``sim.mjcf`` from Python)."""
    params = tmp_path / "limo.yaml"
    params.write_text("wall_height_m: 0.5\nlidar_height_m: 0.3\nmass_kg: 5.5\n")
    out = tmp_path / "worlds"
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(out), "--sim-config", str(params)])
    assert result.exit_code == 0, result.output
    text = (out / "gen_small_0.xml").read_text()
    sim = MujocoSimulator(generate_floor_plan("small", 0), SensorConfig(mount_x_m=0.103), config=MujocoSimConfig(wall_height_m=0.5, lidar_height_m=0.3, mass_kg=5.5))
    assert text == sim.mjcf
    model = mujoco.MjModel.from_xml_path(str(out / "gen_small_0.xml"))
    assert model.body("limo").mass[0] == pytest.approx(5.5) and model.geom("wall0").size[2] == pytest.approx(0.25)
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--sim-config", str(params)])
    assert result.exit_code == 2 and "needs --mjcf" in result.output
    params.write_text("wall_height: 0.5\n")
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(out), "--sim-config", str(params)])
    assert result.exit_code == 2 and "unknown key" in result.output


@pytest.mark.parametrize(
    ("params", "error"),
    [
        ("lidar_mount_x_m: 0.2\n", r"lidar_mount_x_m: 0.2 is not the sensor's mount \(0.103 m\)"),
        # 50 Hz odometry is one 20 ms step; the 0.25 s control period is 12.5 of them
        ("timestep_s: 0.02\nodometry_rate_hz: 50\nactuator_time_constant_s: 0.04\ncontact_time_constant_s: 0.04\n", r"control_period_s \(0.25 s\) must be a whole"),
    ],
)
def test_scenes_refuses_a_sim_config_that_eval_refuses(tmp_path, params, error):
    """``scenes --mjcf --sim-config FILE`` writes "the world eval --sim mujoco --sim-config FILE runs in", but it
    read FILE with the bare dataclass: it wrote a world with the LiDAR at 0.2 m, or a physics step the control
    period is no whole number of, that eval refuses to run."""
    from cso_runtime.evaluation import EvalRequest

    config = tmp_path / "limo.yaml"
    config.write_text(params)
    with pytest.raises(ConfigError, match=error):
        EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=config).validate()
    out = tmp_path / "worlds"
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(out), "--sim-config", str(config)])
    assert result.exit_code == 2, result.output
    assert re.search(error, " ".join(result.output.split())) and not list(out.glob("*.xml")), result.output
    if "lidar_mount_x_m" in params:  # scenes takes no key for the sensor's mount: the way out is to drop this one
        assert "fixed here: leave this key out" in " ".join(result.output.split()) and "set sensor.mount_x_m" not in result.output


def test_the_viewer_gets_every_state_and_the_goal_until_its_window_closes():
    sim = MujocoSimulator(generate_floor_plan("small", 0), SensorConfig(), config=MujocoSimConfig())
    view = SimViewer(sim, launch=FakeHandle)
    handle = view.handle
    assert view.show() and handle.user_scn.ngeom == 0  # no goal yet: nothing drawn
    sim.step(VelocityCommand(0.5, 0.0))
    assert view.show([3.0, 2.5])
    ball = handle.user_scn.geoms[0]
    assert handle.user_scn.ngeom == 1 and np.allclose(ball.pos, [3.0, 2.5, GOAL_HEIGHT_M])
    assert handle.synced_xy[1] == pytest.approx(tuple(sim.true_pose().xy))
    assert handle.synced_xy[1][0] > handle.synced_xy[0][0]  # the window saw the robot move
    handle.running = False  # the user closed the window
    assert not view.show([3.0, 2.5]) and not view.show()
    assert view.frames == 2 and len(handle.synced_xy) == 2
    view.close()
    assert handle.closed == 0  # nothing left to close


class MeddlingHandle(FakeHandle):
    """A window whose user presses Reset and sets the Physics panel's timestep: the passive viewer's sync applies both
    to the model and data it was given (simulate's Sync: ``mj_resetData``, ``m->opt`` from the panel)."""

    def sync(self) -> None:
        super().sync()
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        self.model.opt.timestep = 0.02


def test_what_the_user_does_in_the_window_stays_in_the_window():
    """The window was given the simulator's own model and data: Reset (Backspace) in it put the LIMO at the stepped
    model's qpos0, the map origin inside the boundary wall, in the middle of the episode, and a timestep set in the
    Physics panel changed the physics the episode runs. The window shows copies; a reset one shows the start pose."""
    plan = generate_floor_plan("small", 0)
    sim = MujocoSimulator(plan, SensorConfig(), config=MujocoSimConfig())
    view = SimViewer(sim, launch=MeddlingHandle)
    sim.step(VelocityCommand(0.5, 0.0))
    pose = sim.true_pose()
    assert view.show()
    assert sim.true_pose() == pose and sim.model.opt.timestep == 0.005 and sim.data.ncon == 0
    assert view.handle.data.qpos.tolist() == [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad]  # its Reset: the start
    sim.step(VelocityCommand(0.5, 0.0))
    assert view.show()
    assert view.handle.synced_xy == [pytest.approx(pose.xy), pytest.approx(sim.true_pose().xy)]  # the window follows the sim


def _sim_context(params: dict) -> ServiceContext:
    profile = {"lockstep": True, "scene": "generated:small:1:0", "services": {"sim": params}}
    return ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), params)


def test_the_sim_service_shows_each_step_and_refuses_a_viewer_it_cannot_open(monkeypatch):
    from services.sim import SimService

    with pytest.raises(ConfigError, match="viewer needs backend mujoco"):
        SimService(_sim_context({"backend": "kinematic", "viewer": True}))
    monkeypatch.setattr(viewer_module, "display_problem", lambda: "no display to open a window on")
    with pytest.raises(ConfigError, match="services.sim.viewer: no display"):
        SimService(_sim_context({"backend": "mujoco", "viewer": True}))

    monkeypatch.setattr(viewer_module, "display_problem", lambda: None)
    monkeypatch.setattr(viewer_module, "launch_passive", FakeHandle)
    svc = SimService(_sim_context({"backend": "mujoco", "viewer": True}))
    svc.publish = lambda topic, msg, robot=None: None  # type: ignore[method-assign]
    svc.goal_xy = [2.0, 1.5]
    svc.publish_step()
    svc.advance(VelocityCommand(0.4, 0.0))
    handle = svc.viewer.handle
    assert len(handle.synced_xy) == 2 and handle.user_scn.ngeom == 1
    svc.shutdown()
    assert handle.closed == 1
    assert SimService(_sim_context({"backend": "mujoco"})).viewer is None  # off by default


def test_up_refuses_a_viewer_without_a_display_before_anything_starts(monkeypatch):
    from cso_runtime.run_profile import load_profile

    monkeypatch.setattr(viewer_module, "display_problem", lambda: "no display to open a window on")
    with pytest.raises(ConfigError, match="services.sim.viewer: no display"):
        load_profile("sim", {}, settings={"services.sim.viewer": True})
    load_profile("sim", {})  # no viewer asked for: no display needed
    monkeypatch.setattr(viewer_module, "display_problem", lambda: None)
    profile, _ = load_profile("sim", {}, settings={"services.sim.viewer": True})
    assert profile.services["sim"]["viewer"] is True


def test_a_viewer_made_from_python_without_a_display_says_why(monkeypatch):
    """``SimViewer(sim)`` from a script went straight to ``launch_passive``: without a display GLFW printed "could not
    initialize GLFW" and the whole process exited with code 1, episode and all. It now raises with the reason."""
    launched = []
    monkeypatch.setattr(viewer_module, "display_problem", lambda: "no display to open a window on")
    monkeypatch.setattr(viewer_module, "launch_passive", lambda model, data: launched.append(model) or FakeHandle(model, data))
    sim = MujocoSimulator(generate_floor_plan("small", 0), seed=0)
    with pytest.raises(RuntimeError, match="no display to open a window on"):
        SimViewer(sim)
    assert not launched
    assert SimViewer(sim, launch=FakeHandle).frames == 0  # a launcher of one's own is not checked


def test_the_world_file_says_which_frame_a_map_yamls_scene_is_in(tmp_path):
    """A map_server scene's walls and qpos are in the plan's frame (origin at the grid's corner), not the map YAML's: the
    header said "the map frame", yet a LIMO at qpos (3, 2) stands at (-7, -3) in the map RViz shows."""
    from PIL import Image

    from cso_runtime.scenes import load_map_scene

    free = np.zeros((60, 80), dtype=np.uint8)
    free[1:-1, 1:-1] = 254
    Image.fromarray(np.flipud(free)).save(tmp_path / "room.pgm")
    (tmp_path / "room.yaml").write_text("image: room.pgm\nresolution: 0.05\norigin: [-10.0, -5.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    plan = load_map_scene(tmp_path / "room.yaml")
    header = write_mujoco_world(tmp_path / "w.xml", plan).read_text(encoding="utf-8").split("-->")[0]
    assert "not the map YAML's map frame, where that corner is at its origin (-10, -5) m, yaw 0 rad" in header
    plain = write_mujoco_world(tmp_path / "g.xml", generate_floor_plan("small", 0)).read_text(encoding="utf-8")
    assert "x and y are in the plan's map frame" in plain.split("-->")[0]


def test_scenes_refusal_of_walls_too_soft_suggests_no_robot_key_it_has_not(tmp_path):
    """``scenes --mjcf --sim-config FILE`` writes its worlds with the LIMO's own robot (``RobotConfig()``): no key of it
    sets the robot. Its refusal of walls too soft for the LIMO's top speed still said "Use robot.max_linear_mps 0.22
    m/s or less", a key scenes does not take; the one way out it has is the contact in FILE, which it now names alone."""
    import yaml

    from robot_sim.config import through_wall_problem

    config, out = tmp_path / "soft.yaml", tmp_path / "worlds"
    config.write_text("contact_time_constant_s: 0.5\n")
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(out), "--sim-config", str(config)])
    said = " ".join(result.output.split())
    assert result.exit_code == 2 and "pass through them" in said, result.output
    assert "max_linear_mps 0.22" not in said and "Use contact_time_constant_s 0.11 s or less" in said, said
    config.write_text(yaml.safe_dump({"contact_time_constant_s": 0.11}))  # the way out said, taken
    result = CliRunner().invoke(app, ["scenes", "generated:small:1:0", "--mjcf", str(out), "--sim-config", str(config)])
    assert result.exit_code == 0, result.output
    # eval's config sets the robot: its refusal still names its top speed (tests/test_config.py, each way out of eval's)
    assert "Use robot.max_linear_mps 0.22 m/s or less" in str(through_wall_problem(MujocoSimConfig(contact_time_constant_s=0.5), RobotConfig()))
