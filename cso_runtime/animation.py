"""Animated GIFs of an exploration: the robot's map, path, goal and pose after each decision, and the final map.

Two sources, one picture (``cso_runtime.frames``): an in-process episode (``EpisodeAnimation``, what ``eval
--animate`` writes per episode) and a recording of a run (``animate_recording``, ``cso-runtime animate``: a ``up
--record`` run of the simulator or of a real LIMO, from its ``map``, ``odom``, ``frontiers`` and ``goal`` messages).
Frames after a decision show its frontiers F_t (orange); the final one shows the map alone. A frame is a
``PALETTE``-indexed image, one byte a pixel; at most ``max_frames`` are kept, by dropping every other frame and
then keeping every other decision each time the limit is reached, so a 3000-step episode on a large plan stays a
few megabytes in memory and on disk.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cso_runtime.config import RobotConfig
from cso_runtime.frames import PALETTE, frame_scale, map_frame_indexed
from cso_runtime.geometry import Pose2D
from cso_runtime.keys import topic_of
from cso_runtime.messages import (
    EPISODE_OVER,
    EpisodeStatusMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    MessageError,
    OdometryMsg,
    decode,
    frontiers_reading,
)
from cso_runtime.outputs import write_whole

log = logging.getLogger("cso.animation")

PROGRESS_EVERY = 500
"""``animate_recording`` reports its progress every this many messages read."""


class FrameSequence:
    """The frames of one animation, thinned to at most ``max_frames``."""

    def __init__(self, max_frames: int = 200) -> None:
        if max_frames < 2:
            raise ValueError(f"max_frames must be at least 2, got {max_frames}")
        self.max_frames = max_frames
        self.frames: list[np.ndarray] = []
        self.every = 1
        """Keep one decision in this many (doubles each time the frames are thinned)."""
        self._offered = 0

    def offer(self) -> bool:
        """A decision happened: whether its frame is to be drawn (one in ``every``)."""
        self._offered += 1
        return (self._offered - 1) % self.every == 0

    def add(self, frame: np.ndarray) -> None:
        if self.frames and (frame.shape != self.frames[-1].shape):
            log.warning("the map changed size (%s -> %s): the animation starts again from this frame", self.frames[-1].shape, frame.shape)
            self.frames = []
        if self.frames and np.array_equal(frame, self.frames[-1]):
            return  # nothing moved (an episode that ended at a decision): a GIF would merge the two anyway
        if len(self.frames) >= self.max_frames:  # thinned before the new frame goes in, so the last (the final map) stays
            self.frames = self.frames[::2]
            self.every *= 2
        self.frames.append(frame)

    def save_gif(self, path: Path, frame_ms: int = 120, last_frame_ms: int = 2000) -> Path:
        """Write the frames as an animated GIF (looping; the final map held ``last_frame_ms``; an animated PNG for a
        ``.png`` path), whole or not at all: written beside it, then renamed over it, so that a full disk or a kill
        leaves the earlier file (a report links it), never a cut one."""
        from PIL import Image  # noqa: PLC0415  (only animations need it)

        if not self.frames:
            raise ValueError("no frames to save")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        images = []
        for f in self.frames:
            im = Image.frombytes("P", (f.shape[1], f.shape[0]), f.tobytes())
            im.putpalette(PALETTE.ravel().tolist())
            images.append(im)
        durations = [frame_ms] * (len(images) - 1) + [last_frame_ms]
        image_format = Image.registered_extensions().get(path.suffix.lower(), "GIF")  # the partial file's name says none
        write_whole(path, lambda partial: images[0].save(partial, format=image_format, save_all=True, append_images=images[1:], duration=durations, loop=0, optimize=False))
        return path


def draw(
    explored: np.ndarray,
    occupied: np.ndarray,
    geometry: Any,
    pose: Pose2D,
    trajectory_xy_m: list,
    goal_xy_m: tuple | None,
    robot_radius_m: float,
    frontier: np.ndarray | None = None,
) -> np.ndarray:
    """One animation frame at the scale ``frame_scale`` picks for the map; ``frontier``: the decision's F_t."""
    return map_frame_indexed(
        explored,
        occupied,
        geometry,
        pose,
        robot_radius_m=robot_radius_m,
        frontier=frontier if frontier is not None and frontier.shape == explored.shape else None,
        trajectory_xy_m=np.array(trajectory_xy_m, dtype=float).reshape(-1, 2),
        goals_xy_m=np.array([goal_xy_m]) if goal_xy_m is not None else None,
        scale=frame_scale(geometry.shape),
    )


class EpisodeAnimation(FrameSequence):
    """An in-process episode's frames (``run_episode(..., on_step=animation.on_step)``, then ``finish()``)."""

    def __init__(self, max_frames: int = 200) -> None:
        super().__init__(max_frames)
        self._decisions_seen = 0
        self.explorer: Any = None
        """The episode's explorer (``cso_runtime.episode.Explorer``), seen at its last step."""

    def on_step(self, explorer: Any) -> None:
        """``run_episode``'s ``on_step``: a frame after each step in which a goal was chosen."""
        self.explorer = explorer
        if explorer.decisions != self._decisions_seen:
            self._decisions_seen = explorer.decisions
            if self.offer():
                self._draw(explorer)

    def finish(self) -> bool:
        """The last frame: the map the episode ended with (the explorer of the last step, which no later
        decision changed). False when the episode took no step: nothing to animate."""
        if self.explorer is None:
            return False
        self._draw(self.explorer, final=True)
        return True

    def _draw(self, explorer: Any, final: bool = False) -> None:
        m, goal = explorer.map, explorer.goal
        goal_xy = (goal.x_m, goal.y_m) if goal is not None else None
        frontier = None if final else explorer.decision_frontier  # the final frame: the map alone
        self.add(draw(m.explored, m.occupied, m.geometry, explorer.sim.true_pose(), explorer.trajectory, goal_xy, explorer.config.robot.radius_m, frontier))


@dataclass
class RecordingAnimationStats:
    """What ``animate_recording`` read and drew."""

    path: Path
    robot: str
    frames: int
    decisions: int
    maps: int
    rejected: int
    """Payloads of the keys read that did not decode (left out, as a service would)."""


ANIMATED: dict[str, type[Message]] = {
    "map": MapMsg,
    "odom": OdometryMsg,
    "goal": GoalMsg,
    "frontiers": frontiers_reading(("frontier",), clusters=False),
    "episode_status": EpisodeStatusMsg,
}
"""The keys a recording's animation reads, with the message type each must carry (the status: where an episode ended)."""


class DecisionCount:
    """The decisions of a recording as the sim counts them (``up``'s summary) and the in-process episode does
    (``eval``): every decided goal, but a goal decided on the map of the step at which its episode ended (the frontier
    service hears of the end after the map: no robot acts on that goal). Its empty goal, the ``no_frontier`` end
    itself, counts. The end's status may come before or after that goal: one counted since the episode's latest map
    is taken back when the status comes."""

    def __init__(self) -> None:
        self.count = 0
        self.ended: dict[int, int] = {}
        """Episode id -> the step its referee ended it at (a done or failed status)."""
        self.since_map: list[GoalMsg] = []
        """The goals counted since the latest map."""

    def acted_on(self, g: GoalMsg) -> bool:
        """Whether decided goal ``g`` counts (and so is drawn): not one of the step at which its episode ended."""
        end = self.ended.get(g.episode)
        if end is not None and g.step >= end and g.has_goal:
            return False
        self.count += 1
        self.since_map.append(g)
        return True

    def on_map(self, m: MapMsg) -> None:
        self.since_map = []
        if m.step < self.ended.get(m.episode, m.step + 1):  # a restart under the same id (a recording before ids)
            self.ended.pop(m.episode, None)

    def on_status(self, status: EpisodeStatusMsg) -> None:
        if status.state not in EPISODE_OVER:
            self.ended.pop(status.episode, None)
            return
        self.ended[status.episode] = status.step
        late = [g for g in self.since_map if g.episode == status.episode and g.step >= status.step and g.has_goal]
        self.count -= len(late)
        self.since_map = [g for g in self.since_map if g not in late]


def animate_recording(
    recording: Path,
    out: Path,
    robot: str | None = None,
    max_frames: int = 200,
    robot_radius_m: float = RobotConfig().radius_m,
    progress: Callable[[int, int | None], None] | None = None,
) -> RecordingAnimationStats:
    """A GIF of ``robot``'s run (default: the recording's only robot): a frame at the first map after each decided
    goal, and the last map. The path is the odometry's, started afresh when a new episode's map comes (a restarted
    sim). Raises RecordingError for an unreadable recording, an unknown robot, or one with no map."""
    from cso_runtime.recording import RecordingError, read_recording, recorded_robot  # noqa: PLC0415  (Zenoh and mcap: not for eval)

    robot, total = recorded_robot(recording, robot)
    prefix = f"cso/{robot}/"
    seq = FrameSequence(max_frames)
    latest_map: MapMsg | None = None
    pose: Pose2D | None = None
    trajectory: list[tuple[float, float]] = []
    goal_xy: tuple[float, float] | None = None
    frontier: np.ndarray | None = None
    decided, counted, maps, rejected, seen = False, DecisionCount(), 0, 0, 0
    for seen, m in enumerate(read_recording(recording, topics=ANIMATED), 1):
        if progress is not None and seen % PROGRESS_EVERY == 0:
            progress(seen, total)
        if not m.key.startswith(prefix):
            continue
        topic = topic_of(m.key)  # episode/status: episode_status
        try:
            msg = decode(m.payload, ANIMATED[topic], accept_legacy=True)  # a recording outlives a version
        except MessageError:
            rejected += 1
            continue
        if isinstance(msg, FrontiersMsg):
            if msg.decide and msg.arrays is not None and msg.arrays.get("frontier") is not None:
                frontier = msg.arrays["frontier"]
        elif isinstance(msg, OdometryMsg):
            pose = msg.pose
            trajectory.append((pose.x_m, pose.y_m))
        elif isinstance(msg, GoalMsg):
            if msg.decided and counted.acted_on(msg):
                decided = True
                goal_xy = msg.goal_xy_m
        elif isinstance(msg, EpisodeStatusMsg):
            counted.on_status(msg)
        elif isinstance(msg, MapMsg):
            counted.on_map(msg)
            if latest_map is not None and msg.episode != latest_map.episode:
                trajectory = trajectory[-1:]  # a new episode: its path starts where its robot is
            latest_map, maps = msg, maps + 1
            if decided and pose is not None:
                decided = False
                if seq.offer():
                    seq.add(draw(msg.explored, msg.occupied, msg.geometry, pose, trajectory, goal_xy, robot_radius_m, frontier))
    if progress is not None:
        progress(total if total is not None else seen, total)
    if latest_map is None or pose is None:
        raise RecordingError(f"{recording} holds no map and odometry of robot {robot}: nothing to animate")
    seq.add(draw(latest_map.explored, latest_map.occupied, latest_map.geometry, pose, trajectory, goal_xy, robot_radius_m))
    seq.save_gif(out)
    return RecordingAnimationStats(Path(out), robot, len(seq.frames), counted.count, maps, rejected)
