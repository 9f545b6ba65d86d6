"""MuJoCo simulation of the AgileX LIMO for cso-runtime (issue 3).

``MujocoSimulator`` implements ``cso_runtime.simulator.Simulator`` with physics: a LIMO model
(``limo``) in a world built from a floor plan (``scene``), LiDAR by ``mujoco.mj_multiRay``, odometry
with configurable drift, a command watchdog, and a lockstep or real-time clock (``RealTimePacer``).
"""

from robot_sim.config import MujocoSimConfig
from robot_sim.scene import merge_rectangles, wall_boxes, world_mjcf
from robot_sim.sim import MujocoSimulator, RealTimePacer

__all__ = ["MujocoSimConfig", "MujocoSimulator", "RealTimePacer", "merge_rectangles", "wall_boxes", "world_mjcf"]
