"""Floor plan -> MuJoCo world: occupied cells become 1 m high wall boxes, merged into few rectangles.

Outside the plan counts as wall (as in ``cso_runtime.raycast``), so the grid is padded by one ring of
occupied cells before merging. Optionally only wall cells 8-adjacent to free space are kept: a ray or
a robot entering a wall region from free space always crosses such a cell first, so a hollow shell
is indistinguishable from a solid wall (fewer boxes for blobby walls; for the rectilinear Dungeon
plans solid walls merge into fewer boxes, hence the default).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy import ndimage

from cso_runtime.config import RobotConfig, SensorConfig
from cso_runtime.scenes import FloorPlan
from robot_sim.config import MujocoSimConfig, limo_sensor
from robot_sim.limo import GROUP_FLOOR, GROUP_WALLS, exact, limo_mjcf


def merge_rectangles(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the True cells of ``mask`` exactly by disjoint rectangles ``(iy0, ix0, iy1, ix1)`` (ends exclusive).

    Greedy row-run merge: each maximal run of a row is grown over the following rows while they are
    True on the whole run. Not minimal, but few boxes for walls made of straight segments.
    """
    remaining = np.asarray(mask, dtype=bool).copy()
    ny = remaining.shape[0]
    rects: list[tuple[int, int, int, int]] = []
    for y in range(ny):
        row = remaining[y]
        if not row.any():
            continue
        edges = np.diff(np.concatenate(([0], row.astype(np.int8), [0])))
        for x0, x1 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            y1 = y + 1
            while y1 < ny and remaining[y1, x0:x1].all():
                y1 += 1
            remaining[y:y1, x0:x1] = False
            rects.append((y, int(x0), y1, int(x1)))
    return rects


def wall_cells(plan: FloorPlan, boundary_only: bool = False) -> np.ndarray:
    """Occupied cells of the plan padded by one ring (outside = wall); grid cell (0, 0) is padded (1, 1)."""
    occupied = np.pad(plan.occupied, 1, constant_values=True)
    if not boundary_only:
        return occupied
    near_free = ndimage.binary_dilation(~occupied, structure=np.ones((3, 3), dtype=bool))
    return occupied & near_free


def wall_boxes(plan: FloorPlan, boundary_only: bool = False) -> np.ndarray:
    """Wall rectangles in metres, one row per box: (centre_x, centre_y, half_x, half_y)."""
    res = plan.resolution_m
    rects = np.array(merge_rectangles(wall_cells(plan, boundary_only)), dtype=float).reshape(-1, 4)
    y0, x0, y1, x1 = (rects[:, k] - 1.0 for k in range(4))  # undo the padding
    return np.stack([0.5 * (x0 + x1) * res, 0.5 * (y0 + y1) * res, 0.5 * (x1 - x0) * res, 0.5 * (y1 - y0) * res], axis=1)


def _frames_note(plan: FloorPlan) -> str:
    """Which frame the file's x and y are in: the plan's, whose origin is the grid's lower-left corner; for a scene with a
    map_origin (a map_server YAML's ``origin``), where that corner lies in the scene's own map frame."""
    o = plan.map_origin
    if (o.x_m, o.y_m, o.yaw_rad) == (0.0, 0.0, 0.0):
        return "x and y are in the plan's map frame"
    return (
        f"x and y are in the plan's frame, the runtime's odom, not the map YAML's map frame, where that corner is at its "
        f"origin ({o.x_m:g}, {o.y_m:g}) m, yaw {o.yaw_rad:g} rad"
    )


def _world_header(plan: FloorPlan, robot: RobotConfig, sim: MujocoSimConfig, lidar_mount_x_m: float, robot_at_start: bool) -> str:
    """An XML comment for whoever opens the file on its own: units, frames, the default pose and the key, controls and
    what the simulator's Python does with them, sensors and the LiDAR, geom groups and the parameters the world was
    built with."""
    values = {**dataclasses.asdict(sim), "lidar_mount_x_m": lidar_mount_x_m}
    params = " ".join(f"{k}={str(v).lower() if isinstance(v, bool) else f'{v:g}'}" for k, v in values.items())
    default_pose = (
        """The default pose qpos0 (what the viewer shows on opening the file and after Reset, and mj_resetData gives) is
  the plan's start pose, where an episode starts; key "start" holds the same pose (for code that loads it)."""
        if robot_at_start
        else """qpos0 is the map origin, inside the boundary wall: this is the model the simulator steps, which sets the start
  pose itself (robot_sim/limo.py says why); the files it writes for users have qpos0 at the start (key "start")."""
    )
    return f"""<!-- The MuJoCo LIMO in a floor plan, as cso-runtime's simulator builds it (robot_sim/scene.py).
  Units: metres, kilograms, seconds, radians. Frames follow REP-103: z up; the origin is the plan's lower-left corner
  ({_frames_note(plan)}); the LIMO's x forward, y left. qpos = (x_m, y_m, yaw_rad) of the robot centre in that frame.
  {default_pose}
  Controls, velocity servos in the body frame: drive_forward m/s, drive_lateral m/s (held near 0), drive_yaw rad/s.
  The simulator's Python, not this file, drives them: a command (v, w) every {robot.control_period_s:g} s (the control period),
  clamped to {robot.max_linear_mps:g} m/s and {robot.max_angular_radps:g} rad/s, ramped to each physics step through acceleration limits of
  {sim.max_linear_accel_mps2:g} m/s^2 and {sim.max_angular_accel_radps2:g} rad/s^2; drive_lateral gets only the centripetal feed-forward
  v * w * actuator_time_constant_s. Each control's ctrlrange is the most the simulator ever sends on it.
  Sensors: base_pos, base_quat (the base's pose in that frame), base_vel, base_gyro (its body-frame velocity), lidar_pos.
  The LiDAR is no rangefinder array (one per beam would cast all its rays on every physics step): the simulator
  casts the beams with mj_multiRay from site lidar, level in the scan plane, seeing geom group 0 only, the LIMO's
  body excluded, when a scan fires.
  Geom groups: 0 walls (all the LiDAR rays see), 1 chassis, 2 wheels (visual), 3 floor (no contacts); site lidar.
  Parameters (configs/robot_sim.yaml documents each; the watchdog, acceleration limits and odometry act in the
  simulator's Python, not in this file): {params} -->"""


def world_mjcf(
    plan: FloorPlan, robot: RobotConfig, sim: MujocoSimConfig, lidar_mount_x_m: float, robot_at_start: bool = True
) -> tuple[str, int]:
    """The MJCF of the whole world (walls, floor, LIMO) and its number of wall boxes.

    The model's default pose (qpos0; ``qpos`` is x_m, y_m, yaw_rad) is the plan's start pose, so the file on its own
    opens with the LIMO where an episode starts (``python -m mujoco.viewer --mjcf FILE``); the keyframe ``start``
    holds it too. ``robot_at_start=False``: qpos0 at the map origin, the model the simulator steps (``limo_mjcf``).
    """
    start = plan.start
    boxes = wall_boxes(plan, sim.walls_boundary_only)
    h = 0.5 * sim.wall_height_m
    walls = "\n".join(
        f'    <geom name="wall{i}" type="box" pos="{cx:.6g} {cy:.6g} {h:.6g}" size="{hx:.6g} {hy:.6g} {h:.6g}"/>'
        for i, (cx, cy, hx, hy) in enumerate(boxes)
    )
    limo = limo_mjcf(robot, sim, lidar_mount_x_m, start if robot_at_start else None)
    g = plan.geometry
    # The plan's name is a file's stem: quoted, so a name with a quote, '&' or '<' still makes well-formed XML.
    xml = f"""{_world_header(plan, robot, sim, lidar_mount_x_m, robot_at_start)}
<mujoco model={quoteattr(f"limo_{plan.name}")}>
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{sim.timestep_s:.6g}" integrator="implicitfast" gravity="0 0 -9.81"/>
  <size memory="8M"/>
  <default>
    <geom type="box" group="{GROUP_WALLS}" contype="1" conaffinity="1" rgba="0.5 0.5 0.5 1"
          friction="{sim.wall_friction:.6g} 0.005 0.0001" solref="{sim.contact_time_constant_s:.6g} 1"/>
  </default>
  <worldbody>
    <light pos="{0.5 * g.width_m:.6g} {0.5 * g.height_m:.6g} 10" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" pos="{0.5 * g.width_m:.6g} {0.5 * g.height_m:.6g} 0"
          size="{0.5 * g.width_m + 1:.6g} {0.5 * g.height_m + 1:.6g} 0.1" contype="0" conaffinity="0"
          group="{GROUP_FLOOR}" rgba="0.76 0.76 0.76 1"/>
{walls}
{limo.body_xml}
  </worldbody>
  <actuator>{limo.actuator_xml}
  </actuator>
  <sensor>{limo.sensor_xml}
  </sensor>
  <keyframe>
    <key name="start" qpos="{exact(start.x_m)} {exact(start.y_m)} {exact(start.yaw_rad)}"/>
  </keyframe>
</mujoco>
"""
    return xml, len(boxes)


def write_mujoco_world(path: Path, plan: FloorPlan, robot: RobotConfig | None = None, sim: MujocoSimConfig | None = None,
                       sensor: SensorConfig | None = None) -> Path:
    """Write the world ``MujocoSimulator`` builds for ``plan`` (defaults: the LIMO, its LiDAR where the LIMO carries it,
    ``limo_sensor()``) as an MJCF file."""
    sim = sim or MujocoSimConfig()
    xml, _ = world_mjcf(plan, robot or RobotConfig(), sim, sim.lidar_mount_for(sensor or limo_sensor()))
    path.write_text(xml, encoding="utf-8")
    return path
