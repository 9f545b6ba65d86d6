"""MJCF model of the AgileX LIMO in four-wheel differential (skid-steer) mode.

Base model choice: a *planar base* (slide x, slide y, hinge yaw joints on the world frame) driven by
three velocity servos, with the four wheels as visuals only. Why:

* A skid-steer robot turns by scrubbing its tyres sideways. Wheel-friction contacts reproduce that
  only with friction and torque parameters the real robot gives no numbers for, and four wheel
  contacts make the 5 ms step sensitive to them. The LIMO's own controller already turns (v, w)
  into wheel speeds; what the runtime needs is "the base follows (v, w) within its acceleration
  limits and grip, and a wall stops it".
* Velocity servos with force limits (grip) are unconditionally stable at 5 ms (kv * dt / m = 0.25)
  and are integrated implicitly, while the body stays a real rigid box that collides with the walls:
  pushing into a wall, the servo force saturates at the grip limit and the contact holds it, so
  the robot stops at walls and never passes through them (it moves at most 5 mm per step at 1 m/s
  and walls are at least one cell, 5-10 cm, thick).
* Body-frame servos: the three velocity actuators act through a site at the robot centre (site
  transmission), so their controls are the body-frame forward speed, lateral speed (held at zero,
  the tyres' lateral grip, with a centripetal feed-forward) and yaw rate: no per-step frame
  transform, and a constant command needs no Python work between physics steps.

Frames follow REP-103: the base body's origin is the robot centre at floor height, x forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cso_runtime.config import RobotConfig
from cso_runtime.geometry import Pose2D
from robot_sim.config import MujocoSimConfig

ROBOT_BODY = "limo"
LIDAR_SITE = "lidar"
JOINTS = ("base_x", "base_y", "base_yaw")
BASE_SITE = "base"
ACTUATORS = ("drive_forward", "drive_lateral", "drive_yaw")

GROUP_WALLS = 0
"""Geom group of walls: the only group LiDAR rays see."""
GROUP_ROBOT = 1
GROUP_WHEELS = 2
GROUP_FLOOR = 3


SENSORS = ("base_pos", "base_quat", "base_vel", "base_gyro", "lidar_pos")
"""The base's map pose, its body-frame linear and angular velocity, the LiDAR's position: a few numbers per step, which
the simulator does not read (its LiDAR casts rays itself) but a MuJoCo user of the world file does."""


@dataclass(frozen=True)
class LimoMjcf:
    """MJCF fragments of the robot: its body (goes into <worldbody>), its actuators and its sensors."""

    body_xml: str
    actuator_xml: str
    sensor_xml: str


def lateral_feedforward_mps(linear_mps: float, angular_radps: float, time_constant_s: float) -> float:
    """drive_lateral's command while driving at (v, w): the centripetal feed-forward v * w * tau, without which a servo
    holding zero lateral speed lags by that much. The simulator sends nothing else on this control."""
    return linear_mps * angular_radps * time_constant_s


def _f(x: float) -> str:
    return f"{x:.6g}"


def exact(x: float) -> str:
    """``x`` written so that MuJoCo reads back the same double (a pose the simulator compares bit for bit)."""
    return repr(float(x) + 0.0)  # + 0.0: no "-0.0"


def _base_joints_xml(default_pose: Pose2D | None) -> tuple[str, str]:
    """The base body's placement attributes and its three joints, with qpos0 at ``default_pose``.

    MuJoCo's qpos0 (``mj_resetData``, a viewer opening the file or pressing Reset) is each joint's ``ref``, the joint
    value at which the body sits where the file places it. The slides act in the body's frame, so a body turned by
    the start's yaw gets slide axes turned back by it: they stay the map's x and y, and qpos stays the map pose.
    """
    refs: tuple[str, ...]
    axes, refs, placement = ("1 0 0", "0 1 0", "0 0 1"), ("", "", ""), 'pos="0 0 0"'
    if default_pose is not None:
        x, y, yaw = default_pose.x_m, default_pose.y_m, default_pose.yaw_rad
        refs = tuple(f' ref="{exact(v)}"' for v in (x, y, yaw))
        placement = f'pos="{exact(x)} {exact(y)} 0"'
        if yaw != 0.0:
            c, s = math.cos(yaw), math.sin(yaw)
            axes = (f"{exact(c)} {exact(-s)} 0", f"{exact(s)} {exact(c)} 0", "0 0 1")
            placement += f' euler="0 0 {exact(yaw)}"'
    joints = "\n      ".join(
        f'<joint name="{name}" type="{kind}" axis="{axis}"{ref}/>'
        for name, kind, axis, ref in zip(JOINTS, ("slide", "slide", "hinge"), axes, refs)
    )
    return placement, joints


def limo_mjcf(robot: RobotConfig, sim: MujocoSimConfig, lidar_mount_x_m: float, default_pose: Pose2D | None = None) -> LimoMjcf:
    """The LIMO: box body, four visual wheels, LiDAR site, planar servos.

    Its joints are world-aligned (slides before the yaw hinge), so ``qpos[:3]`` is the robot's pose
    (x_m, y_m, yaw_rad) in the map frame. ``default_pose`` is the model's qpos0, where the body is placed;
    None: the map origin (the body at the world origin, no ``ref``), the model the simulator steps: MuJoCo
    places the body at body_pos + (qpos - qpos0), whose last bits differ from qpos itself when qpos0 is not 0.
    """
    length, width, height = robot.length_m, robot.width_m, sim.body_height_m
    clearance = sim.wheel_radius_m
    box_half_z = 0.5 * (height - clearance)
    box_z = clearance + box_half_z
    # Inertia of a solid box of the LIMO's size and mass about its centre.
    m = sim.mass_kg
    ixx = m * (width**2 + (height - clearance) ** 2) / 12.0
    iyy = m * (length**2 + (height - clearance) ** 2) / 12.0
    izz = m * (length**2 + width**2) / 12.0
    wheels = []
    for name, sx, sy in (("fl", 1, 1), ("fr", 1, -1), ("rl", -1, 1), ("rr", -1, -1)):
        wx, wy = 0.5 * sx * sim.wheelbase_m, 0.5 * sy * sim.track_m
        wheels.append(
            f'<geom name="wheel_{name}" type="cylinder" size="{_f(sim.wheel_radius_m)} 0.0225" '
            f'pos="{_f(wx)} {_f(wy)} {_f(sim.wheel_radius_m)}" euler="{exact(0.5 * math.pi)} 0 0" '
            f'contype="0" conaffinity="0" group="{GROUP_WHEELS}" rgba="0.1 0.1 0.1 1" mass="0"/>'
        )
    kv_lin = m / sim.actuator_time_constant_s
    kv_yaw = izz / sim.actuator_time_constant_s
    placement, joints = _base_joints_xml(default_pose)
    body = f"""
    <body name="{ROBOT_BODY}" {placement}>
      {joints}
      <inertial pos="0 0 {_f(box_z)}" mass="{_f(m)}" diaginertia="{_f(ixx)} {_f(iyy)} {_f(izz)}"/>
      <geom name="chassis" type="box" size="{_f(0.5 * length)} {_f(0.5 * width)} {_f(box_half_z)}" pos="0 0 {_f(box_z)}"
            group="{GROUP_ROBOT}" contype="1" conaffinity="1" condim="3" friction="{_f(sim.wall_friction)} 0.005 0.0001"
            solref="{_f(sim.contact_time_constant_s)} 1"
            rgba="0.9 0.9 0.9 1" mass="0"/>
      {"".join(wheels)}
      <site name="{BASE_SITE}" pos="0 0 0" size="0.01"/>
      <site name="{LIDAR_SITE}" pos="{_f(lidar_mount_x_m)} 0 {_f(sim.lidar_height_m)}" size="0.03"/>
    </body>"""
    grip = f'forcelimited="true" forcerange="{_f(-sim.traction_force_n)} {_f(sim.traction_force_n)}"'
    v_max, w_max = robot.max_linear_mps, robot.max_angular_radps
    lateral_max_mps = lateral_feedforward_mps(v_max, w_max, sim.actuator_time_constant_s)
    forward, lateral, yaw = _ctrl_range(v_max), _ctrl_range(lateral_max_mps), _ctrl_range(w_max)
    actuators = f"""
    <velocity name="drive_forward" site="{BASE_SITE}" gear="1 0 0 0 0 0" kv="{_f(kv_lin)}" {grip} {forward}/>
    <velocity name="drive_lateral" site="{BASE_SITE}" gear="0 1 0 0 0 0" kv="{_f(kv_lin)}" {grip} {lateral}/>
    <velocity name="drive_yaw" site="{BASE_SITE}" gear="0 0 0 0 0 1" kv="{_f(kv_yaw)}" forcelimited="true"
              forcerange="{_f(-sim.yaw_torque_nm)} {_f(sim.yaw_torque_nm)}" {yaw}/>"""
    base_pos, base_quat, base_vel, base_gyro, lidar_pos = SENSORS
    sensors = f"""
    <framepos name="{base_pos}" objtype="site" objname="{BASE_SITE}"/>
    <framequat name="{base_quat}" objtype="site" objname="{BASE_SITE}"/>
    <velocimeter name="{base_vel}" site="{BASE_SITE}"/>
    <gyro name="{base_gyro}" site="{BASE_SITE}"/>
    <framepos name="{lidar_pos}" objtype="site" objname="{LIDAR_SITE}"/>"""
    return LimoMjcf(body, actuators, sensors)


def _ctrl_range(limit: float) -> str:
    """A control limited to +-``limit``, the most the simulator ever sends on it, written exactly: the simulator's
    commands stay inside, so MuJoCo's clamping never changes one (a slider in the viewer covers what the LIMO does)."""
    return f'ctrllimited="true" ctrlrange="{exact(-limit)} {exact(limit)}"'
