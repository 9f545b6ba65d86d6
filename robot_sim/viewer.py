"""A MuJoCo viewer window on the running LIMO (``services.sim.viewer``): watch it explore, as in MuJoCo's simulate.

The passive viewer (``mujoco.viewer.launch_passive``) renders in its own thread; the simulation keeps its
own clock and calls ``SimViewer.show`` after each control step, which copies the state into the window
and marks the current long-term goal. Closing the window only stops the picture: the episode goes on.
The window has its own copies of the model and data: the passive viewer applies what its user does (Reset,
Load key, the Physics panel, a dragged perturbation) to the model and data it shows, never to the episode's.
"""

from __future__ import annotations

import logging
import sys
import warnings
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from robot_sim.sim import MujocoSimulator

log = logging.getLogger("cso.sim.viewer")

GOAL_RGBA = np.array([0.9, 0.15, 0.15, 0.9], dtype=np.float32)
GOAL_RADIUS_M = 0.12
GOAL_HEIGHT_M = 0.3
"""The goal is drawn as a red ball this high above the floor, above the LIMO's body."""


def display_problem() -> str | None:
    """Why no viewer window can open in this process, or None when one can.

    Checked before ``launch_passive``, which on a machine without a display fails inside MuJoCo's
    GUI thread (the process exits, or the caller waits for a window that never comes)."""
    if sys.platform == "darwin":
        from mujoco import viewer  # noqa: PLC0415

        if getattr(viewer, "_MJPYTHON", None) is None:
            return "on macOS the MuJoCo viewer needs the mjpython launcher (run the sim service under mjpython)"
        return None
    try:
        import glfw  # noqa: PLC0415  (installed with mujoco)
    except ImportError:
        return "the glfw package (MuJoCo's window library) is not installed"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not glfw.init():
            return "no display to open a window on: DISPLAY and WAYLAND_DISPLAY are unset, or the display refused"
    return None


class ViewerUnavailable(RuntimeError):
    """No viewer window can open in this process; the message is ``display_problem``'s reason."""


def launch_passive(model: mujoco.MjModel, data: mujoco.MjData) -> Any:
    """MuJoCo's passive viewer, imported when first asked for (it loads the GUI libraries)."""
    from mujoco import viewer  # noqa: PLC0415

    return viewer.launch_passive(model, data)


class SimViewer:
    """A passive MuJoCo viewer on a ``MujocoSimulator``'s model and data."""

    def __init__(self, sim: MujocoSimulator, launch: Callable[[mujoco.MjModel, mujoco.MjData], Any] | None = None) -> None:
        """A window on ``sim`` (``launch``: a stand-in for ``launch_passive``); ViewerUnavailable, with the reason, where
        MuJoCo's window cannot open (without the check, GLFW's failure ends the whole process)."""
        if launch is None and (problem := display_problem()) is not None:
            raise ViewerUnavailable(problem)
        self.sim = sim
        # The world as a file (qpos0 at the start, where the window's Reset goes), the same sizes as the stepped model.
        self._model = mujoco.MjModel.from_xml_string(sim.mjcf)
        self._data = mujoco.MjData(self._model)
        with sim.state_lock:
            mujoco.mj_copyData(self._data, self._model, sim.data)
        self.handle = (launch or launch_passive)(self._model, self._data)
        self.frames = 0
        """State copies sent to the window (one per ``show`` while it is open)."""
        self.closed_by_user = False

    def show(self, goal_xy_m: tuple[float, float] | list[float] | None = None) -> bool:
        """Copy the current state into the window, with the goal marked; False once the window is closed."""
        if self.closed_by_user:
            return False
        if not self.handle.is_running():
            self.closed_by_user = True
            log.info("the viewer window was closed; the episode goes on without it")
            return False
        with self.handle.lock():
            scene = self.handle.user_scn
            if scene is not None:
                scene.ngeom = 0
                if goal_xy_m is not None and scene.maxgeom > 0:
                    mujoco.mjv_initGeom(
                        scene.geoms[0], mujoco.mjtGeom.mjGEOM_SPHERE, np.array([GOAL_RADIUS_M, 0.0, 0.0]),
                        np.array([float(goal_xy_m[0]), float(goal_xy_m[1]), GOAL_HEIGHT_M]), np.eye(3).ravel(), GOAL_RGBA,
                    )  # fmt: skip
                    scene.ngeom = 1
            with self.sim.state_lock:
                mujoco.mj_copyData(self._data, self._model, self.sim.data)
            mujoco.mj_forward(self._model, self._data)  # the sensor readings, which the stepped model skips
        self.handle.sync()
        self.frames += 1
        return True

    def close(self) -> None:
        if not self.closed_by_user:
            self.handle.close()
