"""The robot's map M_t as an image: ``ExplorationEnv.render()`` (Gymnasium's ``rgb_array``) and the animations
(``cso_runtime.animation``: ``eval --animate``, ``cso-runtime animate``).

Pure numpy, no matplotlib: a training run's ``RecordVideo`` renders one frame per decision, an animated evaluation
one per decision of every episode. The image is upright (its top row is the map's largest y, REP-103's map frame
seen from above), one map cell per ``scale`` x ``scale`` pixels: unknown grey, explored free space light, occupied
cells dark, frontier cells orange, the path so far red, the candidate goals as squares (green: allowed by the action
mask, red: masked), the robot a blue disc with its heading as a dark line. Frames are drawn as indices into
``PALETTE`` (one byte a pixel, what a GIF stores) and turned into RGB only for ``map_frame``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cso_runtime.geometry import GridGeometry, Pose2D

UNKNOWN = (128, 128, 128)
FREE = (236, 236, 236)
OCCUPIED = (32, 32, 32)
FRONTIER = (255, 150, 0)
PATH = (220, 30, 30)
ALLOWED = (0, 170, 0)
MASKED = (200, 0, 0)
ROBOT = (30, 90, 230)
HEADING = (0, 20, 90)
PALETTE = np.array([UNKNOWN, FREE, OCCUPIED, FRONTIER, PATH, ALLOWED, MASKED, ROBOT, HEADING], dtype=np.uint8)
"""Row ``i`` is the colour of index ``i`` in ``map_frame_indexed``'s images."""
(I_UNKNOWN, I_FREE, I_OCCUPIED, I_FRONTIER, I_PATH, I_ALLOWED, I_MASKED, I_ROBOT, I_HEADING) = range(len(PALETTE))


def map_frame_indexed(
    explored: np.ndarray,
    occupied: np.ndarray,
    geometry: GridGeometry,
    pose: Pose2D,
    *,
    robot_radius_m: float = 0.2,
    frontier: np.ndarray | None = None,
    trajectory_xy_m: np.ndarray | None = None,
    goals_xy_m: np.ndarray | None = None,
    allowed: np.ndarray | None = None,
    scale: int = 2,
) -> np.ndarray:
    """An ``(rows * scale, cols * scale)`` uint8 image of ``PALETTE`` indices: the map (``explored``/``occupied``/
    ``frontier``: boolean ``[iy, ix]`` grids on ``geometry``), the path, the goals (``allowed[i]`` for goal ``i``;
    all allowed when None) and the robot."""
    if scale < 1:
        raise ValueError(f"scale must be at least 1, got {scale}")
    rows, cols = geometry.shape
    img = np.full((rows, cols), I_UNKNOWN, dtype=np.uint8)
    img[explored & ~occupied] = I_FREE
    img[occupied] = I_OCCUPIED
    if frontier is not None:
        img[frontier] = I_FRONTIER
    img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    px_per_m = scale / geometry.resolution_m

    def to_px(xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel (row, col) of metric points, row 0 at the bottom (flipped at the end)."""
        xy = np.atleast_2d(np.asarray(xy_m, dtype=float))
        return np.floor((xy[:, 1] - geometry.origin_y_m) * px_per_m).astype(int), np.floor((xy[:, 0] - geometry.origin_x_m) * px_per_m).astype(int)

    def put(r: np.ndarray, c: np.ndarray, index: int) -> None:
        ok = (r >= 0) & (r < img.shape[0]) & (c >= 0) & (c < img.shape[1])
        img[r[ok], c[ok]] = index

    if trajectory_xy_m is not None and len(trajectory_xy_m) > 1:
        traj = np.asarray(trajectory_xy_m, dtype=float)
        seg_m = np.linalg.norm(np.diff(traj, axis=0), axis=1)
        n = np.maximum(1, np.ceil(seg_m * px_per_m * 2).astype(int))  # two samples a pixel: no gaps
        t = np.concatenate([np.linspace(0.0, 1.0, k, endpoint=False) for k in n])
        i = np.repeat(np.arange(len(n)), n)
        put(*to_px(traj[i] + t[:, None] * (traj[i + 1] - traj[i])), I_PATH)
    if goals_xy_m is not None and len(goals_xy_m):
        half = max(2, scale)
        dr, dc = np.mgrid[-half : half + 1, -half : half + 1]
        r0, c0 = to_px(goals_xy_m)
        ok = np.ones(len(r0), bool) if allowed is None else np.asarray(allowed, bool)[: len(r0)]
        for j in range(len(r0)):
            put(r0[j] + dr.ravel(), c0[j] + dc.ravel(), I_ALLOWED if ok[j] else I_MASKED)
    radius_px = max(3.0, robot_radius_m * px_per_m)  # visible on a large plan at a cell a pixel
    span = int(np.ceil(radius_px))
    dr, dc = np.mgrid[-span : span + 1, -span : span + 1]
    inside = dr**2 + dc**2 <= radius_px**2
    rr, cc = to_px(np.array([pose.x_m, pose.y_m]))
    put(rr[0] + dr[inside], cc[0] + dc[inside], I_ROBOT)
    ahead = np.linspace(0.0, 1.8 * radius_px, int(4 * radius_px) + 2)
    put(np.floor(rr[0] + ahead * np.sin(pose.yaw_rad)).astype(int), np.floor(cc[0] + ahead * np.cos(pose.yaw_rad)).astype(int), I_HEADING)
    return np.ascontiguousarray(img[::-1])


def map_frame(*args: Any, **kwargs: Any) -> np.ndarray:
    """``map_frame_indexed`` as an ``(rows * scale, cols * scale, 3)`` uint8 RGB image (the same arguments)."""
    return PALETTE[map_frame_indexed(*args, **kwargs)]


def frame_scale(shape: tuple[int, int], target_px: int = 480) -> int:
    """Pixels per map cell so that the longer side is about ``target_px`` (a small plan is enlarged, a large
    one kept at a cell a pixel)."""
    return max(1, int(round(target_px / max(shape))))
