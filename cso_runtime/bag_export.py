"""``cso-runtime export-bag``: a recording as a ROS 2 bag that RViz, Foxglove and ``ros2 bag play`` show.

A ``cso-runtime record`` file keeps our own msgpack messages (byte-exact, for ``replay``); Foxglove can open
it but only as raw fields. This turns one robot's messages into the standard ROS 2 types, in a rosbag2
folder with MCAP storage (``metadata.yaml`` + ``.mcap``), with the names a Nav2 user expects:

| ROS topic | type | from |
| --- | --- | --- |
| ``/scan`` | sensor_msgs/msg/LaserScan (frame ``laser``; ``scan_time`` the recording's period between scans, ``recorded_scan_period``; ``time_increment`` 0), at the scan's own stamp | ``scan`` |
| ``/odom`` | nav_msgs/msg/Odometry (``odom`` -> ``base_link``; covariances diagonal, ``ros2_cdr.ODOMETRY_COVARIANCE_DIAGONAL``) | ``odom`` |
| ``/tf`` | tf2_msgs/msg/TFMessage: ``odom`` -> ``base_link`` at each odometry's time, and at each scan's (its sensor pose less the LiDAR's mount) | ``odom``, ``scan`` |
| ``/tf_static`` | tf2_msgs/msg/TFMessage: ``map`` -> ``odom`` (the scene's map origin) and ``base_link`` -> ``laser`` (the LiDAR's mount) | ``episode/status`` |
| ``/map`` | nav_msgs/msg/OccupancyGrid (-1/0/100, frame ``map``), at most one per ``map_period_s`` of the run, and the last | ``map`` |
| ``/plan`` | nav_msgs/msg/Path (frame ``map``) | ``path`` |
| ``/goal_pose`` | geometry_msgs/msg/PoseStamped (frame ``map``), each new goal | ``goal`` |
| ``/explore/frontiers`` | visualization_msgs/msg/MarkerArray (explore_lite's markers, frame ``map``), each decision | ``frontiers`` |
| ``/cmd_vel`` | geometry_msgs/msg/Twist | ``cmd_vel`` |

Frames, as AMCL and Nav2 lay them out (REP-105): every pose on our network is in the scene's own frame, the robot's
odometry frame, in which the mapper maps too: it is ``odom`` here, and ``map`` -> ``odom`` (AMCL's correction of the
odometry's drift) is a constant, the scene's ``map_origin`` (its pose in the user's map frame: a map_server scene's
YAML ``origin``, else zeros), on ``/tf_static``. It is read from the recording's ``episode/status`` messages before the
export (each episode's, by its id: the first status comes after the first map); a later episode with another
origin sends ``/tf_static`` again, and an episode with no status keeps the origin before it (zeros). The map, path,
goal and frontiers are turned into ``map`` with it, as Nav2's planner and explore_lite publish them in the global
frame: the grid's ``info.origin`` is the plan's corner placed there (its yaw turns the grid, as map_server's does), so
it overlays the user's own map cell for cell; a goal's orientation is the origin's yaw (a goal has no heading of its
own: the identity of the scene's frame). With ``map_origin`` zero (Dungeon, generated and builtin plans, a real
robot) nothing is turned and the messages are as they were. ``base_link`` -> ``laser`` is the LiDAR's mount as the
recording shows it (``recorded_lidar_mount``: the MuJoCo LIMO's 0.103 m ahead, the identity for a LiDAR at the
centre). Each scan stays exactly where it was taken: ``odom`` -> ``base_link`` at the scan's own time is its sensor
pose less the mount, so tf2 puts ``laser`` there whether or not an odometry message shares that time (a real-time
MuJoCo LIMO's LiDAR fires before its step's odometry); where one does (lockstep, the ROS 2 bridge), both say the
same pose and only the first is sent (tf2 keeps the first transform of a time).

The four frames' names are ``BagFrames``'s (``--map-frame``, ``--odom-frame``, ``--base-frame``, ``--laser-frame``:
``laser_link`` for AgileX's LIMO driver's tree), each used wherever its frame appears; the defaults are the names
above. The map's ``info.origin`` is ``geometry.rounded_pose``'d, as ``save-map``'s YAML ``origin``.

Time (``time``): ``sim`` (default) puts every message at the robot's own time (each scan and odometry at its stamp,
another message at its step's first: 0.25 s a step in the simulator, however fast a lockstep run went; a later
episode of the same recording, whose steps start again, follows the one before: told by its messages' episode id,
``StepTimeline``), ``received`` at its reception time
in the recording. Every header is stamped
with that same time, so that transforms are found at the time of each scan. The conversions are ``cso_runtime.ros2_cdr``'s, the same as
the ROS 2 bridge's; the other keys (clock, status, feedback, distance maps) are counted and left out.
"""

from __future__ import annotations

import logging
import math
import shutil
import statistics
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cso_runtime import ros2_cdr
from cso_runtime.frame_names import BASE_FRAME, LASER_FRAME, MAP_FRAME, ODOM_FRAME
from cso_runtime.geometry import MAP_FRAME_ORIGIN, Pose2D, compose_pose, compose_xy, relative_pose, rounded, rounded_pose
from cso_runtime.messages import (
    CmdVelMsg,
    DeferredMsg,
    EpisodeStatusMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    Message,
    MessageError,
    OdometryMsg,
    PathMsg,
    ScanMsg,
    decode,
)
from cso_runtime.recording import RecordingError, read_recording, recorded_robot

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

log = logging.getLogger("cso.bag_export")


@dataclass(frozen=True)
class BagFrames:
    """The names of the four frames ``map`` -> ``odom`` -> ``base_link`` -> ``laser`` in a bag (before ``namespace``),
    used in every header and transform that names them (``/scan``'s header, ``/tf``, ``/tf_static``, ``/odom``, the
    map-frame messages): a bag whose TF tree matches the user's robot (the LIMO's ROS driver names its LiDAR's frame
    ``laser_link``). The defaults are the names a bag has always had."""

    map: str = MAP_FRAME
    odom: str = ODOM_FRAME
    base: str = BASE_FRAME
    laser: str = LASER_FRAME

    def check(self) -> None:
        """ValueError unless each name is a tf2 frame id and the four are distinct (one named twice makes a TF loop)."""
        names = {"map": self.map, "odom": self.odom, "base": self.base, "laser": self.laser}
        for what, frame in names.items():
            if not ros2_cdr.is_frame_id(frame):
                raise ValueError(f"the {what} frame {frame!r} is no tf2 frame id ({ros2_cdr.FRAME_ID_RULE})")
        if len(set(names.values())) < len(names):
            twice = sorted({f for f in names.values() if list(names.values()).count(f) > 1})
            raise ValueError(f"the frames must have four different names, not {', '.join(repr(f) for f in twice)} twice: tf2 cannot make a tree of them")


DEFAULT_FRAMES = BagFrames()
ROS_TYPES = {
    "/scan": ros2_cdr.LASER_SCAN,
    "/odom": ros2_cdr.ODOMETRY,
    "/tf": ros2_cdr.TF_MESSAGE,
    "/tf_static": ros2_cdr.TF_MESSAGE,
    "/map": ros2_cdr.OCCUPANCY_GRID,
    "/plan": ros2_cdr.PATH,
    "/goal_pose": ros2_cdr.POSE_STAMPED,
    "/explore/frontiers": ros2_cdr.MARKER_ARRAY,
    "/cmd_vel": ros2_cdr.TWIST,
}
"""Every topic of an exported bag and its ROS 2 type."""
LATCHED = ("/map", "/tf_static")
"""Offered as transient-local (like map_server and tf2's static broadcaster): late subscribers get the last one."""
SENSOR_AT_BASE = Pose2D(0.0, 0.0, 0.0)
"""A LiDAR mounted at the robot's centre: ``base_link`` -> ``laser`` is the identity (it is sent all the same)."""
GLOBAL_TOPICS = ("/tf", "/tf_static")
"""Not namespaced (``namespace``): one /tf carries every robot's frames, told apart by their prefix, so that merged
bags play into one TF tree (tf2 listens on /tf) with each robot's subtree under its own ``NS/map``."""


def namespaced(name: str, namespace: str) -> str:
    """``name`` (a topic ``/scan`` or a frame ``base_link``) under ``namespace`` as multi-robot ROS 2 setups name it:
    ``/NS/scan``, frame ``NS/base_link`` (tf2 has no tf_prefix; frames carry the prefix themselves). ``/tf`` and
    ``/tf_static`` stay global (``GLOBAL_TOPICS``). No namespace: ``name`` itself."""
    ns = namespace.strip("/")
    if not ns or name in GLOBAL_TOPICS:
        return name
    return f"/{ns}{name}" if name.startswith("/") else f"{ns}/{name}"


MAX_MAP_PERIOD_S = 1e9
"""The longest ``map_period_s`` (``export-bag --map-period-s``), about 32 years: any longer is the same bag (the last map
alone), and 1e308 s overflowed when made nanoseconds (``int(inf)``): a traceback, not an error."""


def check_export_settings(map_period_s: float, time: str, names: tuple[str, str] = ("map_period_s", "time")) -> None:
    """Refuse a ``map_period_s`` below 0 (or not finite) and a ``time`` not in ``TIME_MODES``, naming them as ``names``
    (``export-bag`` passes its flags, ``--map-period-s`` and ``--time``)."""
    if not (math.isfinite(map_period_s) and map_period_s >= 0):
        raise ValueError(f"{names[0]} must be a number of seconds >= 0, not {map_period_s:g}")
    if map_period_s > MAX_MAP_PERIOD_S:  # 1e308 s: an OverflowError traceback once in nanoseconds
        raise ValueError(f"{names[0]} must be at most {MAX_MAP_PERIOD_S:g} s (bag_export.MAX_MAP_PERIOD_S: longer than any run, its last map alone), not {map_period_s:g}")
    if time not in TIME_MODES:
        raise ValueError(f"{names[1]} must be one of {', '.join(TIME_MODES)}, not {time!r}")


class BagExportError(RuntimeError):
    """The recording cannot be exported (unreadable, no such robot, several robots and none chosen)."""


@dataclass
class BagExportStats:
    """What an export read and wrote."""

    path: Path = field(default_factory=Path)
    robot: str = ""
    messages_read: int = 0
    written: Counter = field(default_factory=Counter)
    """ROS topic -> messages written."""
    left_out: Counter = field(default_factory=Counter)
    """Our topic -> messages with no ROS counterpart here (clock, status...)."""
    rejected: Counter = field(default_factory=Counter)
    """Our topic -> payloads that did not decode (malformed messages a run received and counted too)."""
    maps_thinned: int = 0
    """Maps left out by ``map_period_s``."""
    lidar_mount: Pose2D = SENSOR_AT_BASE
    """``base_link`` -> ``laser``, as exported."""
    scan_period_s: float = 0.0
    """Each ``/scan``'s ``scan_time``: the period between scans the recording shows (0: unknown)."""
    frames: BagFrames = DEFAULT_FRAMES
    """The frames' names, as exported (before the namespace)."""
    map_origins: dict[int, Pose2D] = field(default_factory=dict)
    """Episode id -> its ``map`` -> ``odom`` (the episodes whose status the recording has)."""


TIME_MODES = ("sim", "received")

LEFT_EPISODES_STEPS_KEPT = 16
"""How many of the episodes left last ``StepTimeline`` keeps every step's time of, for their late messages; of the ones
before, only their offset and last time (a recording of many episodes would otherwise keep a time per step of all)."""


class StepTimeline:
    """Bag time of each message from the robot's own clock: the stamps of the scans and odometry, each its own, laid
    after the first reception time; a step's other messages at the time of its first scan or odometry. A new episode
    (its clock and steps start again) follows the last time of the one before by one ``step_s``. Its start is told by
    the episode id its scans and odometry carry (``messages.new_episode_id``: an episode of one step is as new as any);
    a message of an episode left, late, keeps that episode's times (however many episodes of a step or two came
    between), and one of an episode whose first scan or odometry is still to come (another key, handled first) takes
    the latest time, not a step of the episode before. Messages of no id (0: a recording before the ids, a publisher
    without them) tell it by their step numbers going back (by more than the one step a message can lag), which misses
    an episode after one of fewer than three steps. It keeps every step's time of the last ``LEFT_EPISODES_STEPS_KEPT``
    episodes left, and of the ones before their last alone (a late message of one takes its last time, or its own stamp's
    for a scan or odometry): a long recording costs a few numbers per episode, not one per step."""

    def __init__(self, start_ns: int, step_s: float = 0.25) -> None:
        self.start_ns, self.step_s = start_ns, step_s
        self.first_stamp_s: float | None = None
        self.offset_s = 0.0
        self.last_s = 0.0
        self.max_step = -1
        self.by_step: dict[int, float] = {}
        self.episode = 0
        """The current episode's id (0: none known)."""
        self.left: dict[int, tuple[float, dict[int, float]]] = {}
        """The episodes left, by id: their offsets and times by step (of the ones before the last
        ``LEFT_EPISODES_STEPS_KEPT``, their last step's alone), for their late messages."""
        self.left_whole: deque[int] = deque()
        """The ids of the episodes left whose times of every step ``left`` still keeps, the oldest first."""

    def ns(self, t_s: float) -> int:
        """The bag time of ``t_s`` on this timeline."""
        return self.start_ns + ros2_cdr.stamp_ns_from_seconds(t_s)

    def stamp(self, step: int, stamp_s: float, episode: int = 0) -> int:
        """The bag time (ns) of a step of ``episode`` (its id; 0: none) whose scan or odometry carries ``stamp_s``."""
        if self.first_stamp_s is None:
            self.first_stamp_s = stamp_s
        if episode and episode != self.episode and episode in self.left:  # late, of an episode left
            offset_s, by_step = self.left[episode]
            t = stamp_s - self.first_stamp_s + offset_s
            by_step.setdefault(step, t)
            return self.ns(t)
        new = episode != self.episode if episode and self.episode else step < self.max_step - 1
        if new:  # a new episode: its clock and steps start again
            if self.episode:
                self.leave(self.episode)
            self.offset_s = self.last_s + self.step_s - (stamp_s - self.first_stamp_s)
            self.by_step = {}
            self.max_step = -1
        if new or episode:  # an episode told by its steps alone has no id; one with an id has it from its first message
            self.episode = episode
        t = stamp_s - self.first_stamp_s + self.offset_s  # its own: a real-time sim's scan fired before its step's odometry
        self.by_step.setdefault(step, t)
        self.max_step = max(self.max_step, step)
        self.last_s = max(self.last_s, t)
        return self.ns(t)

    def leave(self, episode: int) -> None:
        """Keep the current episode's times as ``episode``'s, left; of the one left ``LEFT_EPISODES_STEPS_KEPT`` before,
        its last step's time alone."""
        self.left[episode] = (self.offset_s, self.by_step)
        self.left_whole.append(episode)
        if len(self.left_whole) > LEFT_EPISODES_STEPS_KEPT:
            old = self.left_whole.popleft()
            if old in self.left:
                offset_s, by_step = self.left[old]
                last = max(by_step, key=by_step.__getitem__, default=None)
                self.left[old] = (offset_s, {} if last is None else {last: by_step[last]})

    def at(self, step: int, episode: int = 0) -> int:
        """The bag time of a message that carries only its step (a map, a goal...) and perhaps its episode id: its
        step's in its episode (an episode left, for a late one: its step's, else its last), else the latest (also for
        an episode the timeline has not begun: its first scan or odometry is yet to come)."""
        if episode and episode != self.episode:
            if episode in self.left:
                by_step = self.left[episode][1]
                return self.ns(by_step.get(step, max(by_step.values(), default=self.last_s)))
            if self.episode:  # not the current one, nor one left: one to come (with no id known now, any of them)
                return self.ns(self.last_s)
        return self.ns(self.by_step.get(step, self.last_s))


def every_topic(ros_topic: str) -> bool:
    """``BagConverter.convert``'s default: every ROS topic is wanted (a bag, an MCAP file)."""
    return True


def shows_something(msg: Message) -> bool:
    """Whether ``BagConverter.convert`` can make a ROS message of ``msg`` at all: frontiers that decide nothing and a
    goal message without a goal cannot (a viewer that subscribes late is sent the last one that could). A message
    not decoded yet (``DeferredMsg``) is judged by the same field of its body, read as it came: one that would not
    decode is rejected when it is."""
    if isinstance(msg, DeferredMsg):
        if msg.SCHEMA == FrontiersMsg.SCHEMA:
            return msg.kept_body.get("decide") is True
        if msg.SCHEMA == GoalMsg.SCHEMA:
            return msg.kept_body.get("goal") is not None
        return True
    if isinstance(msg, FrontiersMsg):
        return bool(msg.decide)
    if isinstance(msg, GoalMsg):
        return bool(msg.has_goal)
    return True


Rows = list[tuple[str, bytes, int]]
"""What a conversion gives: (ROS topic, CDR bytes, time ns) of each ROS message."""
BASE_TF_TIMES_KEPT = 8
"""How many times of ``odom`` -> ``base_link`` transforms a converter remembers, to send none twice at one time (a
step's scan and odometry arrive together)."""
MAP_FRAME_TOPICS = ("map", "path", "goal", "frontiers")
"""Our topics whose ROS messages are in the ``map`` frame, so need their episode's map origin."""


class BagConverter:
    """One robot's messages, in arrival order -> (ROS topic, CDR bytes, time ns). Pure: no files, no Zenoh.

    Frames (the module's docstring): our messages' poses are in the scene's own frame, ``odom`` here; ``map`` ->
    ``odom`` on ``/tf_static`` is the scene's ``map_origin`` (``episode_status.map_origin``), and the map, goal, path and
    frontiers are turned into ``map`` with it. ``map_origins`` gives each episode's (by its id); ``learn_map_origin``
    adds one. An episode whose map origin is not known keeps the one before (zeros before any), as does a message of
    no episode (a path). ``lidar_mount``: the LiDAR's pose on the robot, ``base_link`` -> ``laser`` on ``/tf_static``.
    ``frames``: the four frames' names (``BagFrames``). ``scan_period_s``: each ``/scan``'s ``scan_time``, the time
    between scans (0: unknown; ``recorded_scan_period``); its ``time_increment`` is 0 (``ros2_cdr.laserscan_to_cdr``)."""

    def __init__(
        self, map_period_s: float = 1.0, time: str = "sim", namespace: str = "",
        lidar_mount: Pose2D = SENSOR_AT_BASE, map_origins: Mapping[int, Pose2D] | None = None,
        frames: BagFrames = DEFAULT_FRAMES, scan_period_s: float = 0.0,
    ) -> None:  # fmt: skip
        if namespace and not ros2_cdr.is_ros_name(namespace):
            raise ValueError(f"namespace {namespace!r} is no ROS name (letters, digits and _, parts joined by /, e.g. robot1)")
        frames.check()
        self.map_frame, self.odom_frame, self.base_frame, self.laser_frame = (
            namespaced(f, namespace) for f in (frames.map, frames.odom, frames.base, frames.laser)
        )
        """The frame ids (``NS/map``... under a ``namespace``); the topics are namespaced by the bag's writer."""
        if not (math.isfinite(scan_period_s) and scan_period_s >= 0):
            raise ValueError("scan_period_s must be >= 0")
        self.scan_period_s = scan_period_s
        check_export_settings(map_period_s, time)
        self.time = time
        self.timeline: StepTimeline | None = None
        self.map_period_ns = int(map_period_s * 1e9)
        self.last_map_ns: int | None = None
        self.pending_map: tuple[MapMsg, int, Pose2D] | None = None
        """The newest map not written because of ``map_period_s`` (written at the end if none follows), with the map
        origin it is in."""
        self.last_goal_xy: tuple[float, float] | None = None
        self.maps_thinned = 0
        self.lidar_mount = lidar_mount
        self.map_origins: dict[int, Pose2D] = dict(map_origins or {})
        """Episode id -> its map origin."""
        self.episode: int | None = None
        """The episode of the latest message that carries one."""
        self.map_origin = MAP_FRAME_ORIGIN
        """The map origin converted with now: the current episode's, or the last one known."""
        self.static_sent: Pose2D | None = None
        """The map origin ``/tf_static`` last said (None: not sent yet)."""
        self.base_tf_times_ns: deque[int] = deque(maxlen=BASE_TF_TIMES_KEPT)
        """The times of the last ``odom`` -> ``base_link`` transforms sent."""

    def begin(self, received_ns: int) -> None:
        """The robot's first message of the recording arrived then (of any topic): the bag's time starts there."""
        if self.timeline is None:
            self.timeline = StepTimeline(received_ns)

    def bag_time_ns(self, msg: Message, received_ns: int) -> int:
        if self.time == "received":
            return received_ns
        self.begin(received_ns)
        assert self.timeline is not None
        if isinstance(msg, ScanMsg):
            return self.timeline.stamp(msg.step, msg.scan.stamp_s, msg.episode)
        if isinstance(msg, OdometryMsg):
            return self.timeline.stamp(msg.step, msg.stamp_s, msg.episode)
        episode = getattr(msg, "episode", 0)
        return self.timeline.at(int(getattr(msg, "step", -1)), episode if isinstance(episode, int) else 0)

    def knows_map_origin(self, episode: int | None = None) -> bool:
        """Whether the map origin of ``episode`` (None: the current one) is known: its status said it, or it has no id
        (0: a publisher without ids, whose messages take the last one known)."""
        episode = self.episode if episode is None else episode
        return not episode or episode in self.map_origins

    def observe_episode(self, episode: int, t_ns: int, wanted: Callable[[str], bool] = every_topic) -> Rows:
        """A message of ``episode`` (its id) came at ``t_ns``: that episode's map origin, if known, applies from now on;
        ``/tf_static`` again when that moves ``map`` -> ``odom``."""
        self.episode = episode
        return self._apply_map_origin(self.map_origins.get(episode), t_ns, wanted)

    def learn_map_origin(self, episode: int, map_origin: Pose2D, t_ns: int, wanted: Callable[[str], bool] = every_topic) -> Rows:
        """``episode``'s map origin (its ``episode_status``'s), heard at ``t_ns``: applied at once if it is the current
        episode's (or no episode has been seen), with ``/tf_static`` again when ``map`` -> ``odom`` moves."""
        self.map_origins[episode] = map_origin
        if self.episode not in (None, episode):
            return []
        self.episode = episode
        return self._apply_map_origin(map_origin, t_ns, wanted)

    def _apply_map_origin(self, map_origin: Pose2D | None, t_ns: int, wanted: Callable[[str], bool]) -> Rows:
        if map_origin is None or map_origin == self.map_origin:
            return []
        self.map_origin = map_origin
        return [self.static_transforms(t_ns)] if self.static_sent is not None and wanted("/tf_static") else []

    def to_map_frame(self, xy_m: np.ndarray) -> np.ndarray:
        """Points (n x 2 metres) of the scene's frame in the map frame (unchanged, to the bit, when the map origin is zero)."""
        return xy_m if self.map_origin == MAP_FRAME_ORIGIN else compose_xy(self.map_origin, xy_m)

    def base_pose_of_scan(self, sensor_pose: Pose2D) -> Pose2D:
        """Where ``base_link`` was when the LiDAR at ``sensor_pose`` took its scan (the sensor pose less the mount, as
        the mapper puts the robot's footprint), so that ``odom`` -> ``base_link`` -> ``laser`` is the scan's exact pose."""
        if self.lidar_mount == SENSOR_AT_BASE:
            return sensor_pose
        return compose_pose(sensor_pose, Pose2D(*relative_pose(self.lidar_mount, SENSOR_AT_BASE)))

    def base_transform(self, pose: Pose2D, t_ns: int) -> Rows:
        """``/tf`` ``odom`` -> ``base_link`` at ``t_ns``, unless one of that time went out already: tf2 keeps the first
        transform of a time (and warns of a repeat); a step's scan and odometry of one time agree (the LiDAR at the
        odometry pose plus the mount), so the second adds nothing."""
        if t_ns in self.base_tf_times_ns:
            return []
        self.base_tf_times_ns.append(t_ns)
        return [("/tf", ros2_cdr.transforms_to_cdr([(self.odom_frame, self.base_frame, pose)], t_ns), t_ns)]

    def convert(self, msg: Message, received_ns: int, wanted: Callable[[str], bool] = every_topic, again: bool = False) -> Rows:
        """The ROS messages of one of ours, received at ``received_ns`` (empty: nothing to show for it).
        ``wanted(ros_topic)``: whether that topic is wanted now (a live viewer's subscriptions); the others are not
        converted at all, and a map nobody wants is not held back for ``map_period_s`` either. ``again``: the
        message is sent once more, to a viewer that has just subscribed: a goal already sent and a map within
        ``map_period_s`` of the last one go out too."""
        t_ns = self.bag_time_ns(msg, received_ns)
        out: Rows = []
        episode = getattr(msg, "episode", None)
        if isinstance(episode, int):
            out += self.observe_episode(episode, t_ns, wanted)
        if self.static_sent is None and wanted("/tf_static"):
            out.append(self.static_transforms(t_ns))
        if isinstance(msg, OdometryMsg):
            if wanted("/odom"):
                out.append(("/odom", ros2_cdr.odometry_to_cdr(msg.pose, msg.twist, t_ns, self.odom_frame, self.base_frame), t_ns))
            if wanted("/tf"):
                out += self.base_transform(msg.pose, t_ns)
        elif isinstance(msg, ScanMsg):
            if wanted("/tf"):
                out += self.base_transform(self.base_pose_of_scan(msg.sensor_pose), t_ns)
            if wanted("/scan"):
                out.append(("/scan", ros2_cdr.laserscan_to_cdr(msg.scan, t_ns, self.laser_frame, self.scan_period_s), t_ns))
        elif isinstance(msg, MapMsg) and wanted("/map"):
            self.maps_thinned += self.pending_map is not None and self.pending_map[0] is not msg  # a held map is superseded either way
            if again or self.last_map_ns is None or t_ns - self.last_map_ns >= self.map_period_ns:
                self.last_map_ns, self.pending_map = t_ns, None
                out.append(self._map_row(msg, t_ns, self.map_origin))
            else:
                self.pending_map = (msg, t_ns, self.map_origin)  # converted only if it stays the last
        elif isinstance(msg, PathMsg) and wanted("/plan"):
            out.append(("/plan", ros2_cdr.path_to_cdr(self.to_map_frame(msg.path_xy_m), t_ns, self.map_frame), t_ns))
        elif isinstance(msg, GoalMsg):
            goal = None if (xy := msg.goal_xy_m) is None else (float(xy[0]), float(xy[1]))
            if goal is not None and (goal != self.last_goal_xy or again) and wanted("/goal_pose"):
                pose = Pose2D(*goal, 0.0) if self.map_origin == MAP_FRAME_ORIGIN else compose_pose(self.map_origin, Pose2D(*goal, 0.0))
                out.append(("/goal_pose", ros2_cdr.pose_stamped_to_cdr(pose.x_m, pose.y_m, pose.yaw_rad, t_ns, self.map_frame), t_ns))
            self.last_goal_xy = goal
        elif isinstance(msg, FrontiersMsg) and msg.decide and wanted("/explore/frontiers"):
            points, goals = msg.cluster_points_xy_m()
            points = [self.to_map_frame(p) for p in points]
            goals = goals if not goals else [(float(x), float(y)) for x, y in self.to_map_frame(np.asarray(goals, dtype=float))]
            out.append(("/explore/frontiers", ros2_cdr.frontier_markers_to_cdr(points, goals, t_ns, self.map_frame), t_ns))
        elif isinstance(msg, CmdVelMsg) and wanted("/cmd_vel"):
            out.append(("/cmd_vel", ros2_cdr.twist_to_cdr(msg.command), t_ns))
        return out

    def converts(self, topic: str, wanted: Callable[[str], bool]) -> bool:
        """Whether ``convert`` may make anything ``wanted`` of a message on our ``topic`` (one of ``EXPORTED``): one of
        its ROS topics (``ROS_TOPICS``) is wanted, or ``/tf_static`` that goes out with the first message. A message
        for which it may not need not even be decoded."""
        return (self.static_sent is None and wanted("/tf_static")) or any(wanted(ros_topic) for ros_topic in ROS_TOPICS[topic])

    def static_transforms(self, t_ns: int) -> tuple[str, bytes, int]:
        """``/tf_static``: ``map`` -> ``odom`` (the map origin) and ``base_link`` -> ``laser`` (the LiDAR's mount), sent with
        the first message, again when the map origin changes, or to a viewer that subscribes to it."""
        self.static_sent = self.map_origin
        transforms = [(self.map_frame, self.odom_frame, self.map_origin), (self.base_frame, self.laser_frame, self.lidar_mount)]
        return ("/tf_static", ros2_cdr.transforms_to_cdr(transforms, t_ns), t_ns)

    def finish(self, sent_ns: int | None = None) -> Rows:
        """The last map, when ``map_period_s`` held it back: a bag always ends with the final map. ``sent_ns``: a
        live viewer is sent it then and the conversion goes on, so ``map_period_s`` counts from then."""
        if self.pending_map is None:
            return []
        msg, t_ns, map_origin = self.pending_map
        self.pending_map = None
        self.last_map_ns = t_ns if sent_ns is None else sent_ns
        return [self._map_row(msg, t_ns, map_origin)]

    def _map_row(self, msg: MapMsg, t_ns: int, map_origin: Pose2D) -> tuple[str, bytes, int]:
        """``/map`` in the map frame: the grid's corner placed by ``map_origin`` (as map_server places a map by its
        ``origin``), so that it overlays the user's map cell for cell."""
        corner = None if map_origin == MAP_FRAME_ORIGIN else msg.geometry.corner_pose(map_origin)
        return ("/map", ros2_cdr.occupancy_grid_to_cdr(msg.grid, msg.geometry, t_ns, self.map_frame, origin=corner), t_ns)


PROGRESS_EVERY = 500
"""Messages read between two ``progress`` calls."""
EXPORTED: dict[str, type[Message]] = {
    "scan": ScanMsg, "odom": OdometryMsg, "map": MapMsg, "path": PathMsg, "goal": GoalMsg, "frontiers": FrontiersMsg, "cmd_vel": CmdVelMsg,
}
"""Our topics that become ROS messages, and the message each must carry (another one is rejected, as a service would)."""
ROS_TOPICS: dict[str, tuple[str, ...]] = {
    "scan": ("/tf", "/scan"), "odom": ("/odom", "/tf"), "map": ("/map",), "path": ("/plan",), "goal": ("/goal_pose",),
    "frontiers": ("/explore/frontiers",), "cmd_vel": ("/cmd_vel",),
}
"""Our topic -> the ROS topics ``BagConverter.convert`` makes of it (besides ``/tf_static``, with the first message)."""


MOUNT_SEARCH_MESSAGES = 200
"""How many of a robot's first scans and odometry messages ``recorded_lidar_mount`` looks at for a pair of one time."""


def recorded_map_origins(recording: Path, robot: str) -> dict[int, Pose2D]:
    """Episode id -> the scene's map origin, from ``robot``'s ``episode_status`` messages in ``recording`` (the sim
    publishes one only after the first map, so it is read before the export: the first map is in the map frame too).
    ``episode_result`` carries the same origin (and its episode id only from referees that send one), and comes after a status of its episode."""
    prefix = f"cso/{robot}/"
    origins: dict[int, Pose2D] = {}
    for m in read_recording(recording, topics=("episode_status",), quiet=True):
        if m.key.startswith(prefix):
            try:
                status = decode(m.payload, EpisodeStatusMsg, accept_legacy=True)
            except MessageError:
                continue  # counted when the export reads it
            origins.setdefault(status.episode, status.map_origin)
    return origins


def recorded_lidar_mount(recording: Path, robot: str) -> Pose2D:
    """The LiDAR's pose on ``robot`` (``base_link`` -> ``laser``), as its messages in ``recording`` show it: a scan's
    sensor pose relative to the odometry pose of its step, for the first scan and odometry of one episode, step and
    stamp (the sim's in lockstep and at the start, the ROS 2 bridge's always: both put the LiDAR at odometry pose plus
    ``exploration.sensor.mount_x_m``, the MuJoCo LIMO's 0.103 m). None such among the first
    ``MOUNT_SEARCH_MESSAGES``: ``SENSOR_AT_BASE``."""
    prefix = f"cso/{robot}/"
    seen: dict[tuple[str, int, int, float], Pose2D] = {}
    messages = read_recording(recording, topics=("scan", "odom"), quiet=True)
    try:
        for m in messages:
            if not m.key.startswith(prefix):
                continue
            try:
                msg = decode(m.payload, EXPORTED[m.key[len(prefix):]], accept_legacy=True)
            except MessageError:
                continue
            if isinstance(msg, ScanMsg):
                kind, stamp_s, pose, other = "scan", msg.scan.stamp_s, msg.sensor_pose, "odom"
            else:
                assert isinstance(msg, OdometryMsg)
                kind, stamp_s, pose, other = "odom", msg.stamp_s, msg.pose, "scan"
            match = seen.get((other, msg.episode, msg.step, stamp_s))
            if match is not None:
                base, sensor = (match, pose) if kind == "scan" else (pose, match)
                return rounded_pose(Pose2D(*relative_pose(base, sensor)))  # what float arithmetic left of it, rounded off
            seen[(kind, msg.episode, msg.step, stamp_s)] = pose
            if len(seen) >= MOUNT_SEARCH_MESSAGES:
                break
    finally:
        messages.close()  # the reader's file, at once
    return SENSOR_AT_BASE


SCAN_PERIOD_SCANS = 50
"""How many of a robot's first scans ``ScanPeriod`` reads (``recorded_scan_period``, the Foxglove bridge)."""


class ScanPeriod:
    """The period between one robot's scans as their stamps show it (each ``/scan``'s ``scan_time``,
    sensor_msgs/LaserScan's time between scans): the median of the steps between consecutive scans of one episode,
    among its first ``SCAN_PERIOD_SCANS`` scans (a dropped scan or a LiDAR that fired early moves it not), ``rounded``
    (0.25 s for the simulator's scan a step, the LiDAR's own on a real robot); 0 (unknown) before two scans of one
    episode, or while the stamps never advance. The one computation of it: ``export-bag`` reads a recording's first
    scans with it before it writes (``recorded_scan_period``), the Foxglove bridge the scans as they come, so that a
    run's live view and its bag say the same period once the bridge has seen as many scans."""

    def __init__(self) -> None:
        self.steps: list[float] = []
        self.last: tuple[int, float] | None = None
        """The latest scan's episode and stamp."""
        self.seen = 0

    @property
    def complete(self) -> bool:
        """Whether ``SCAN_PERIOD_SCANS`` scans were seen: later ones change the period no more."""
        return self.seen >= SCAN_PERIOD_SCANS

    def add(self, episode: int, stamp_s: float) -> None:
        """One more scan, of ``episode`` at ``stamp_s`` (nothing once ``complete``)."""
        if self.complete:
            return
        if self.last is not None and self.last[0] == episode and stamp_s > self.last[1]:
            self.steps.append(stamp_s - self.last[1])
        self.last = (episode, stamp_s)
        self.seen += 1

    @property
    def period_s(self) -> float:
        return rounded(statistics.median(self.steps)) if self.steps else 0.0


def recorded_scan_period(recording: Path, robot: str) -> float:
    """The period between ``robot``'s scans in ``recording`` (``ScanPeriod`` of its first scans)."""
    prefix = f"cso/{robot}/"
    period = ScanPeriod()
    messages = read_recording(recording, topics=("scan",), quiet=True)
    try:
        for m in messages:
            if not m.key.startswith(prefix):
                continue
            try:
                msg = decode(m.payload, ScanMsg, accept_legacy=True)
            except MessageError:
                continue
            period.add(msg.episode, msg.scan.stamp_s)
            if period.complete:
                break
    finally:
        messages.close()  # the reader's file, at once
    return period.period_s


def nothing_exported(stats: BagExportStats) -> str:
    """Why an export wrote no message: what the robot's messages of the recording were instead."""
    kept = ", ".join(f"{topic} {n}" for topic, n in sorted(stats.left_out.items()))
    *others, last = EXPORTED
    why = f"no {', '.join(others)} or {last} message; it has {stats.messages_read} messages" + (f": {kept}" if kept else "")
    if stats.rejected:
        why += "; left out, did not decode: " + ", ".join(f"{topic} {n}" for topic, n in sorted(stats.rejected.items()))
    return why


def export_bag(
    recording: Path,
    out_dir: Path,
    robot: str | None = None,
    map_period_s: float = 1.0,
    time: str = "sim",
    progress: Callable[[int, int | None], None] | None = None,
    namespace: str = "",
    lidar_mount: Pose2D | None = None,
    frames: BagFrames = DEFAULT_FRAMES,
) -> BagExportStats:
    """Write ``recording``'s messages of ``robot`` (default: its only robot) as a rosbag2 folder ``out_dir``.
    ``namespace``: every topic but /tf and /tf_static, and every frame id, under it (``namespaced``), so that the bags
    of several robots can be merged. ``frames``: the names of ``map``, ``odom``, ``base_link`` and ``laser``
    (``BagFrames``; ``laser_link`` for the LIMO's driver's). ``lidar_mount``: ``base_link`` -> ``laser`` (None: as the
    recording shows it, ``recorded_lidar_mount``). Each ``/scan``'s ``scan_time`` is ``recorded_scan_period``. ``map`` -> ``odom`` is each episode's map origin (``recorded_map_origins``).
    ``progress(read, total)`` is called every few hundred messages (total: all robots' messages, None when
    the recording has no summary), so that a long recording does not convert in silence. BagExportError, and no
    folder left, when nothing of the robot converts (``nothing_exported``): an empty bag is no run to look at."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime  # noqa: PLC0415  (rosbags loads only here)
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError  # noqa: PLC0415

    recording, out_dir = Path(recording), Path(out_dir)
    converter = BagConverter(map_period_s, time, namespace, frames=frames)  # checks the settings before any file is touched
    if out_dir.exists():
        raise BagExportError(f"{out_dir} exists; a bag is written to a new folder (give another --out or remove it)")
    try:
        robot, total = recorded_robot(recording, robot)
    except RecordingError as exc:
        raise BagExportError(str(exc)) from None
    try:
        converter.lidar_mount = recorded_lidar_mount(recording, robot) if lidar_mount is None else lidar_mount
        converter.map_origins.update(recorded_map_origins(recording, robot))
        converter.scan_period_s = recorded_scan_period(recording, robot)
    except RecordingError as exc:
        raise BagExportError(str(exc)) from None
    stats = BagExportStats(
        out_dir, robot, lidar_mount=converter.lidar_mount, map_origins=dict(converter.map_origins), scan_period_s=converter.scan_period_s, frames=frames,
    )
    never = QosTime(sec=0, nsec=0)
    latched = [Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, never, never, QosLiveliness.AUTOMATIC, never, False)]
    prefix = f"cso/{robot}/"
    try:
        # Version 8: its QoS profiles are a YAML string, which Humble's and Iron's rosbag2 read (version 9's list fails there).
        with Writer(out_dir, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
            connections: dict[str, Connection] = {}

            def write(rows: list[tuple[str, bytes, int]]) -> None:
                for ros_topic, data, t_ns in rows:
                    topic = namespaced(ros_topic, namespace)
                    conn = connections.get(topic)
                    if conn is None:
                        conn = connections[topic] = writer.add_connection(
                            topic, ROS_TYPES[ros_topic], typestore=ros2_cdr.typestore(), offered_qos_profiles=latched if ros_topic in LATCHED else ()
                        )
                    writer.write(conn, t_ns, data)
                    stats.written[topic] += 1

            for seen, m in enumerate(read_recording(recording), 1):
                if progress is not None and seen % PROGRESS_EVERY == 0:
                    progress(seen, total)
                if not m.key.startswith(prefix):
                    continue
                stats.messages_read += 1
                converter.begin(m.log_time_ns)
                topic = m.key[len(prefix):]
                if topic not in EXPORTED:
                    stats.left_out[topic] += 1
                    continue
                try:
                    msg = decode(m.payload, EXPORTED[topic], accept_legacy=True)  # a recording outlives a version
                except MessageError as exc:
                    if not stats.rejected[topic]:
                        log.warning("%s: a payload that does not decode is left out (%s); later ones are only counted", m.key, exc)
                    stats.rejected[topic] += 1
                    continue
                write(converter.convert(msg, m.log_time_ns))
            write(converter.finish())
            if progress is not None:
                progress(total if total is not None else stats.messages_read, total)
    except (WriterError, OSError, RecordingError) as exc:
        shutil.rmtree(out_dir, ignore_errors=True)  # no half-written bag that looks complete
        raise BagExportError(f"cannot write {out_dir}: {exc}" if not isinstance(exc, RecordingError) else f"{exc}; no bag written") from None
    except BaseException:  # Ctrl-C (or SIGTERM, in the command), anything unforeseen: the writer left a cut .mcap
        shutil.rmtree(out_dir, ignore_errors=True)
        raise
    if not stats.written:  # rosbag2 would list a bag of no topics, starting at INT64_MAX: no bag at all
        shutil.rmtree(out_dir, ignore_errors=True)
        raise BagExportError(f"{recording} holds nothing of robot {robot} to export ({nothing_exported(stats)}): no bag written")
    stats.maps_thinned = converter.maps_thinned
    return stats
