"""MuJoCo simulation of the AgileX LIMO for cso-runtime (issue 3).

``MujocoSimulator`` implements ``cso_runtime.simulator.Simulator`` with physics: a LIMO model
(``limo``) in a world built from a floor plan (``scene``), LiDAR by ``mujoco.mj_multiRay``, odometry
with configurable drift, a command watchdog, and a lockstep or real-time clock (``RealTimePacer``).
"""

import os

from robot_sim.config import MujocoSimConfig
from robot_sim.scene import merge_rectangles, wall_boxes, world_mjcf

try:
    import mujoco  # noqa: F401  (here, to say what a failure means before robot_sim.sim needs it)
except Exception as _exc:  # any failure of MuJoCo's import is the finding
    _gl = os.environ.get("MUJOCO_GL")
    if _gl is None:
        raise
    # mujoco's own __init__ sets up MUJOCO_GL's renderer: a bad value, or one whose library is missing (osmesa without
    # libOSMesa fails as "'NoneType' object has no attribute 'glGetError'"), breaks the import of a simulator that
    # renders nothing.
    raise ImportError(
        f"cannot import mujoco with MUJOCO_GL={_gl!r} ({type(_exc).__name__}: {_exc}); the simulator renders nothing and "
        "needs no MUJOCO_GL: unset it (or install that backend's library: libegl1 for egl, libosmesa6 for osmesa)"
    ) from _exc

from robot_sim.sim import MujocoSimulator, RealTimePacer

__all__ = ["MujocoSimConfig", "MujocoSimulator", "RealTimePacer", "merge_rectangles", "wall_boxes", "world_mjcf"]
