"""``cso-runtime export-bag``: a recording as a ROS 2 bag that RViz, Foxglove and ``ros2 bag play`` show.

A ``cso-runtime record`` file keeps our own msgpack messages (byte-exact, for ``replay``); Foxglove can open
it but only as raw fields. This turns one robot's messages into the standard ROS 2 types, in a rosbag2
folder with MCAP storage (``metadata.yaml`` + ``.mcap``), with the names a Nav2 user expects:

| ROS topic | type | from |
| --- | --- | --- |
| ``/scan`` | sensor_msgs/msg/LaserScan (frame ``laser``) | ``scan`` |
| ``/odom`` | nav_msgs/msg/Odometry (``odom`` -> ``base_link``) | ``odom`` |
| ``/tf`` | tf2_msgs/msg/TFMessage: ``odom`` -> ``base_link`` (odometry), ``odom`` -> ``laser`` (each scan's sensor pose) | ``odom``, ``scan`` |
| ``/tf_static`` | tf2_msgs/msg/TFMessage: ``map`` -> ``odom``, identity (the mapper maps in the odometry frame) | |
| ``/map`` | nav_msgs/msg/OccupancyGrid (-1/0/100), at most one per ``map_period_s`` of the run, and the last | ``map`` |
| ``/plan`` | nav_msgs/msg/Path | ``path`` |
| ``/goal_pose`` | geometry_msgs/msg/PoseStamped, each new goal | ``goal`` |
| ``/explore/frontiers`` | visualization_msgs/msg/MarkerArray (explore_lite's markers), each decision | ``frontiers`` |
| ``/cmd_vel`` | geometry_msgs/msg/Twist | ``cmd_vel`` |

Time (``time``): ``sim`` (default) puts every message at the robot's own time of its step (the scan's and the
odometry's stamps: 0.25 s a step in the simulator, however fast a lockstep run went; a later episode of the same
recording, whose steps start again, follows the one before), ``received`` at its reception time in the recording. Every header is stamped
with that same time, so that transforms are found at the time of each scan. The conversions are ``cso_runtime.ros2_cdr``'s, the same as
the ROS 2 bridge's; the other keys (clock, status, feedback, distance maps) are counted and left out.
"""

from __future__ import annotations

import logging
import shutil
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cso_runtime import ros2_cdr
from cso_runtime.geometry import Pose2D
from cso_runtime.messages import (
    CmdVelMsg,
    DeferredMsg,
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

log = logging.getLogger("cso.bag_export")

MAP_FRAME, ODOM_FRAME, BASE_FRAME, LASER_FRAME = "map", "odom", "base_link", "laser"
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


TIME_MODES = ("sim", "received")


class StepTimeline:
    """Bag time of each message from the robot's own clock: the stamps of a step's scan and odometry, laid
    after the first reception time. Step numbers that go back (by more than the one step a message can lag)
    start a new episode, which then follows the last time of the one before by one ``step_s``."""

    def __init__(self, start_ns: int, step_s: float = 0.25) -> None:
        self.start_ns, self.step_s = start_ns, step_s
        self.first_stamp_s: float | None = None
        self.offset_s = 0.0
        self.last_s = 0.0
        self.max_step = -1
        self.by_step: dict[int, float] = {}

    def stamp(self, step: int, stamp_s: float) -> int:
        """The bag time (ns) of a step whose scan or odometry carries ``stamp_s``."""
        if self.first_stamp_s is None:
            self.first_stamp_s = stamp_s
        if step < self.max_step - 1:  # a new episode: its clock and steps start again
            self.offset_s = self.last_s + self.step_s - (stamp_s - self.first_stamp_s)
            self.by_step.clear()
            self.max_step = -1
        t = self.by_step.setdefault(step, stamp_s - self.first_stamp_s + self.offset_s)
        self.max_step = max(self.max_step, step)
        self.last_s = max(self.last_s, t)
        return self.start_ns + ros2_cdr.stamp_ns_from_seconds(t)

    def at(self, step: int) -> int:
        """The bag time of a message that carries only its step (a map, a goal...): its step's, else the latest."""
        return self.start_ns + ros2_cdr.stamp_ns_from_seconds(self.by_step.get(step, self.last_s))


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


class BagConverter:
    """One robot's messages, in arrival order -> (ROS topic, CDR bytes, time ns). Pure: no files, no Zenoh."""

    def __init__(self, map_period_s: float = 1.0, time: str = "sim", namespace: str = "") -> None:
        if namespace and not ros2_cdr.is_ros_name(namespace):
            raise ValueError(f"namespace {namespace!r} is no ROS name (letters, digits and _, parts joined by /, e.g. robot1)")
        self.map_frame, self.odom_frame, self.base_frame, self.laser_frame = (
            namespaced(f, namespace) for f in (MAP_FRAME, ODOM_FRAME, BASE_FRAME, LASER_FRAME)
        )
        """The frame ids (``NS/map``... under a ``namespace``); the topics are namespaced by the bag's writer."""
        if not map_period_s >= 0:
            raise ValueError("map_period_s must be >= 0")
        if time not in TIME_MODES:
            raise ValueError(f"time must be one of {', '.join(TIME_MODES)}, not {time!r}")
        self.time = time
        self.timeline: StepTimeline | None = None
        self.map_period_ns = int(map_period_s * 1e9)
        self.started = False
        self.last_map_ns: int | None = None
        self.pending_map: tuple[MapMsg, int] | None = None
        """The newest map not written because of ``map_period_s`` (written at the end if none follows)."""
        self.last_goal_xy: tuple[float, float] | None = None
        self.maps_thinned = 0

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
            return self.timeline.stamp(msg.step, msg.scan.stamp_s)
        if isinstance(msg, OdometryMsg):
            return self.timeline.stamp(msg.step, msg.stamp_s)
        return self.timeline.at(int(getattr(msg, "step", -1)))

    def convert(
        self, msg: Message, received_ns: int, wanted: Callable[[str], bool] = every_topic, again: bool = False
    ) -> list[tuple[str, bytes, int]]:
        """The ROS messages of one of ours, received at ``received_ns`` (empty: nothing to show for it).
        ``wanted(ros_topic)``: whether that topic is wanted now (a live viewer's subscriptions); the others are not
        converted at all, and a map nobody wants is not held back for ``map_period_s`` either. ``again``: the
        message is sent once more, to a viewer that has just subscribed: a goal already sent and a map within
        ``map_period_s`` of the last one go out too."""
        t_ns = self.bag_time_ns(msg, received_ns)
        out: list[tuple[str, bytes, int]] = []
        if not self.started and wanted("/tf_static"):
            out.append(self.static_transforms(t_ns))
        if isinstance(msg, OdometryMsg):
            if wanted("/odom"):
                out.append(("/odom", ros2_cdr.odometry_to_cdr(msg.pose, msg.twist, t_ns, self.odom_frame, self.base_frame), t_ns))
            if wanted("/tf"):
                out.append(("/tf", ros2_cdr.transforms_to_cdr([(self.odom_frame, self.base_frame, msg.pose)], t_ns), t_ns))
        elif isinstance(msg, ScanMsg):
            if wanted("/tf"):
                out.append(("/tf", ros2_cdr.transforms_to_cdr([(self.odom_frame, self.laser_frame, msg.sensor_pose)], t_ns), t_ns))
            if wanted("/scan"):
                out.append(("/scan", ros2_cdr.laserscan_to_cdr(msg.scan, t_ns, self.laser_frame), t_ns))
        elif isinstance(msg, MapMsg) and wanted("/map"):
            self.maps_thinned += self.pending_map is not None and self.pending_map[0] is not msg  # a held map is superseded either way
            if again or self.last_map_ns is None or t_ns - self.last_map_ns >= self.map_period_ns:
                self.last_map_ns, self.pending_map = t_ns, None
                out.append(_map_row(msg, t_ns, self.map_frame))
            else:
                self.pending_map = (msg, t_ns)  # converted only if it stays the last
        elif isinstance(msg, PathMsg) and wanted("/plan"):
            out.append(("/plan", ros2_cdr.path_to_cdr(msg.path_xy_m, t_ns, self.map_frame), t_ns))
        elif isinstance(msg, GoalMsg):
            goal = (float(msg.x_m), float(msg.y_m)) if msg.has_goal else None
            if goal is not None and (goal != self.last_goal_xy or again) and wanted("/goal_pose"):
                out.append(("/goal_pose", ros2_cdr.pose_stamped_to_cdr(goal[0], goal[1], 0.0, t_ns, self.map_frame), t_ns))
            self.last_goal_xy = goal
        elif isinstance(msg, FrontiersMsg) and msg.decide and wanted("/explore/frontiers"):
            points, goals = msg.cluster_points_xy_m()
            out.append(("/explore/frontiers", ros2_cdr.frontier_markers_to_cdr(points, goals, t_ns, self.map_frame), t_ns))
        elif isinstance(msg, CmdVelMsg) and wanted("/cmd_vel"):
            out.append(("/cmd_vel", ros2_cdr.twist_to_cdr(msg.command), t_ns))
        return out

    def converts(self, topic: str, wanted: Callable[[str], bool]) -> bool:
        """Whether ``convert`` may make anything ``wanted`` of a message on our ``topic`` (one of ``EXPORTED``): one of
        its ROS topics (``ROS_TOPICS``) is wanted, or ``/tf_static`` that goes out with the first message. A message
        for which it may not need not even be decoded."""
        return (not self.started and wanted("/tf_static")) or any(wanted(ros_topic) for ros_topic in ROS_TOPICS[topic])

    def static_transforms(self, t_ns: int) -> tuple[str, bytes, int]:
        """``/tf_static`` (``map`` -> ``odom``, the identity), sent with the first message (or to a viewer that
        subscribes to it); ``convert`` does not send it again."""
        self.started = True
        return ("/tf_static", ros2_cdr.transforms_to_cdr([(self.map_frame, self.odom_frame, Pose2D(0.0, 0.0, 0.0))], t_ns), t_ns)

    def finish(self, sent_ns: int | None = None) -> list[tuple[str, bytes, int]]:
        """The last map, when ``map_period_s`` held it back: a bag always ends with the final map. ``sent_ns``: a
        live viewer is sent it then and the conversion goes on, so ``map_period_s`` counts from then."""
        if self.pending_map is None:
            return []
        msg, t_ns = self.pending_map
        self.pending_map = None
        self.last_map_ns = t_ns if sent_ns is None else sent_ns
        return [_map_row(msg, t_ns, self.map_frame)]


def _map_row(msg: MapMsg, t_ns: int, frame_id: str) -> tuple[str, bytes, int]:
    return ("/map", ros2_cdr.occupancy_grid_to_cdr(msg.grid, msg.geometry, t_ns, frame_id), t_ns)


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


def export_bag(
    recording: Path,
    out_dir: Path,
    robot: str | None = None,
    map_period_s: float = 1.0,
    time: str = "sim",
    progress: Callable[[int, int | None], None] | None = None,
    namespace: str = "",
) -> BagExportStats:
    """Write ``recording``'s messages of ``robot`` (default: its only robot) as a rosbag2 folder ``out_dir``.
    ``namespace``: every topic but /tf and /tf_static, and every frame id, under it (``namespaced``), so that the bags
    of several robots can be merged.
    ``progress(read, total)`` is called every few hundred messages (total: all robots' messages, None when
    the recording has no summary), so that a long recording does not convert in silence."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime  # noqa: PLC0415  (rosbags loads only here)
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError  # noqa: PLC0415

    recording, out_dir = Path(recording), Path(out_dir)
    converter = BagConverter(map_period_s, time, namespace)  # checks the settings before any file is touched
    if out_dir.exists():
        raise BagExportError(f"{out_dir} exists; a bag is written to a new folder (give another --out or remove it)")
    try:
        robot, total = recorded_robot(recording, robot)
    except RecordingError as exc:
        raise BagExportError(str(exc)) from None
    stats = BagExportStats(out_dir, robot)
    never = QosTime(sec=0, nsec=0)
    latched = [Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, never, never, QosLiveliness.AUTOMATIC, never, False)]
    prefix = f"cso/{robot}/"
    try:
        # Version 8: its QoS profiles are a YAML string, which Humble's and Iron's rosbag2 read (version 9's list fails there).
        with Writer(out_dir, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
            connections: dict[str, object] = {}

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
    except KeyboardInterrupt:  # Ctrl-C (or SIGTERM, in the command): the writer closed a bag that would look whole
        shutil.rmtree(out_dir, ignore_errors=True)
        raise
    stats.maps_thinned = converter.maps_thinned
    return stats
