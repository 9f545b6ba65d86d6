"""``cso-runtime export-bag``: a recording as a ROS 2 bag of standard types, read back with rosbags' own reader."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader

from cso_runtime import ros2_cdr
from cso_runtime.bag_export import ROS_TYPES, BagConverter, BagExportError, export_bag
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, VelocityCommand, compose_pose
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import (
    ClockMsg,
    CmdVelMsg,
    EpisodeStatusMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    OdometryMsg,
    PathMsg,
    ScanMsg,
    decode,
    encode,
)
from cso_runtime.recording import RecordedMessage, write_recording

GEOM = GridGeometry(0.1, (20, 30), -1.0, -0.5)
T0_NS = 1_800_000_000_000_000_000
"""Reception time of the first message (wall clock, ns)."""


def _map(step: int, episode_id: int = 0) -> MapMsg:
    grid = np.full(GEOM.shape, -1, np.int8)
    grid[2:10, 2 : 5 + step] = 0
    grid[2, 2 : 5 + step] = 100
    return MapMsg.from_grid(step, GEOM, grid, episode_id)


def _frontiers(step: int, episode_id: int = 0) -> FrontiersMsg:
    arrays = {name: np.zeros(GEOM.shape, dtype=dt) for name, dt in FrontiersMsg.GRIDS.items()}
    cluster = {
        "goal_cell": (3, 4),
        "goal_xy_m": (-0.55, -0.15),
        "distance_m": 1.0,
        "size_m": 0.3,
        "entropy": 3.0,
        "centroid_xy_m": (-0.5, -0.1),
        "cells": np.array([[3, 4], [3, 5], [4, 5]], dtype=np.int32),
    }
    return FrontiersMsg(step, True, "no_goal", Pose2D(0, 0, 0), GEOM, arrays, [cluster], 1.0, episode=episode_id)


def _scan(step: int, stamp_s: float) -> LaserScan:
    return LaserScan(-math.pi / 2, math.pi / 180, 0.1, 8.0, np.r_[np.full(90, 2.0 + step), np.full(91, np.inf)].astype(np.float32), stamp_s)


def episode(keys: RobotKeys, steps: int, first_ns: int, every_ns: int, goal_changes_at: int = 2, episode_id: int = 0) -> list[RecordedMessage]:
    """A lockstep-like run: messages of step k arrive ``every_ns`` apart (fast), the robot's clock says 0.25 s a step.
    ``episode_id``: the id its messages carry (0: a publisher without ids)."""
    out: list[RecordedMessage] = []
    for k in range(steps):
        t = first_ns + k * every_ns
        stamp = 0.25 * k
        pose = Pose2D(0.1 * k, 0.0, 0.05 * k)
        goal = (1.0, 2.0) if k < goal_changes_at else (3.0, -1.0)
        for i, msg in enumerate(
            [
                ClockMsg(k, stamp, episode=episode_id),
                OdometryMsg(k, stamp, pose, VelocityCommand(0.4, 0.2), episode_id),
                ScanMsg(k, _scan(k, stamp), Pose2D(pose.x_m + 0.1, pose.y_m, pose.yaw_rad), episode_id),
                _map(k, episode_id),
                _frontiers(k, episode_id) if k % 2 == 0 else FrontiersMsg(k, False, "keep", episode=episode_id),
                GoalMsg(k, k % 2 == 0, *goal, 0, 1.0, 2.0, "greedy-dist", episode=episode_id),
                PathMsg(k, np.array([[pose.x_m, pose.y_m], [goal[0], goal[1]]])),
                CmdVelMsg(k, VelocityCommand(0.4, 0.2)),
            ]
        ):
            topic = {"ClockMsg": "clock", "OdometryMsg": "odom", "ScanMsg": "scan", "MapMsg": "map", "FrontiersMsg": "frontiers",
                     "GoalMsg": "goal", "PathMsg": "path", "CmdVelMsg": "cmd_vel"}[type(msg).__name__]
            out.append(RecordedMessage(keys.topic(topic), t + i * 1000, encode(msg)))
    return out


PREVIOUS_VERSIONS = {"odom": 1, "goal": 1, "frontiers": 6, "distance_map": 1, "planner_feedback": 2}
"""The version of each schema before it carried the episode id (b3bfa9e, 2aebc8d)."""


def legacy(payload: bytes) -> bytes:
    """``payload`` as a build before the episode id wrote it (its previous version, no ``episode``); others unchanged."""
    env = msgpack.unpackb(payload, raw=False)
    if env["schema"] not in PREVIOUS_VERSIONS:
        return payload
    del env["body"]["episode"]
    return msgpack.packb({"schema": env["schema"], "v": PREVIOUS_VERSIONS[env["schema"]], "body": env["body"]}, use_bin_type=True)


def read_bag(folder: Path) -> dict[str, list[tuple[int, object]]]:
    """Topic -> [(bag time ns, deserialized message)], checking each connection's type."""
    got: dict[str, list[tuple[int, object]]] = {}
    with Reader(folder) as reader:
        for conn in reader.connections:
            assert conn.msgtype == ROS_TYPES[conn.topic]
        for conn, t_ns, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t_ns, ros2_cdr.decode(raw, conn.msgtype)))
    return got


def stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def test_a_recording_becomes_a_bag_of_standard_types_on_the_robots_own_clock(tmp_path: Path):
    keys = RobotKeys("r0")
    messages = episode(keys, 5, T0_NS, 2_000_000)  # 2 ms a step: a fast lockstep run
    messages.insert(3, RecordedMessage(keys.scan, T0_NS + 1500, b"\x00 not msgpack"))  # malformed: counted, left out
    messages.insert(4, RecordedMessage(keys.odom, T0_NS + 1600, encode(GoalMsg(0, False))))  # a goal on the odometry key
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", messages)
    stats = export_bag(recording, tmp_path / "bag", map_period_s=0.6)
    bag = read_bag(tmp_path / "bag")

    assert stats.rejected == {"scan": 1, "odom": 1} and stats.left_out == {"clock": 5}
    assert {t: len(v) for t, v in bag.items()} == dict(stats.written) == {
        "/tf_static": 1, "/odom": 5, "/tf": 5, "/scan": 5, "/map": 3, "/plan": 5, "/goal_pose": 2, "/explore/frontiers": 3, "/cmd_vel": 5,
    }
    # The robot's clock: step k at T0 + 0.25 s k whatever the reception times; every header says the bag time.
    for topic in ("/odom", "/scan", "/plan", "/cmd_vel"):
        times = [t for t, _ in bag[topic]]
        assert times == [T0_NS + k * 250_000_000 for k in range(5)], topic
    # Every header stamp is the bag time to the nanosecond (a float-seconds stamp near 1.8e9 s was up to ~120 ns off).
    for topic in ("/odom", "/scan", "/map", "/plan", "/goal_pose"):
        assert [stamp_ns(m.header) for _, m in bag[topic]] == [t for t, _ in bag[topic]], topic
    assert all(stamp_ns(p.header) == t for t, m in bag["/plan"] for p in m.poses)
    assert all(stamp_ns(mk.header) == t for t, m in bag["/explore/frontiers"] for mk in m.markers)
    assert all(stamp_ns(tf.header) == t for t, m in bag["/tf"] + bag["/tf_static"] for tf in m.transforms)
    assert all(m.info.map_load_time.sec * 1_000_000_000 + m.info.map_load_time.nanosec == t for t, m in bag["/map"])
    # Maps at most one per 0.6 s (steps 0, 3) and the last one (step 4), each the map of its step.
    assert [t for t, _ in bag["/map"]] == [T0_NS, T0_NS + 750_000_000, T0_NS + 1_000_000_000] and stats.maps_thinned == 2
    last_map = bag["/map"][-1][1]
    grid = np.asarray(last_map.data, dtype=np.int8).reshape(last_map.info.height, last_map.info.width)
    np.testing.assert_array_equal(grid, _map(4).grid)
    assert (last_map.info.origin.position.x, last_map.info.origin.position.y, last_map.info.resolution) == (-1.0, -0.5, pytest.approx(0.1))
    assert last_map.header.frame_id == "map"
    # Scans in the laser frame, which hangs from base_link by the LiDAR's mount (step 0's scan 0.1 m ahead of its
    # odometry); the robot placed by its odometry, once a time (each scan shares its step's).
    scan = bag["/scan"][2][1]
    assert scan.header.frame_id == "laser" and np.array_equal(scan.ranges, _scan(2, 0.5).ranges_m)
    assert scan.angle_min == pytest.approx(-math.pi / 2) and scan.angle_max == pytest.approx(-math.pi / 2 + 180 * math.pi / 180)
    tfs = [(t, tf) for t, m in bag["/tf"] for tf in m.transforms]
    assert [(tf.header.frame_id, tf.child_frame_id) for _, tf in tfs] == [("odom", "base_link")] * 5
    assert tfs[2][1].transform.translation.x == pytest.approx(0.2)
    assert ros2_cdr.yaw_from_quaternion(**{a: getattr(tfs[2][1].transform.rotation, a) for a in "xyzw"}) == pytest.approx(0.1)
    map_odom, base_laser = bag["/tf_static"][0][1].transforms
    assert (map_odom.header.frame_id, map_odom.child_frame_id, map_odom.transform.translation.x, map_odom.transform.rotation.w) == ("map", "odom", 0.0, 1.0)
    assert (base_laser.header.frame_id, base_laser.child_frame_id, base_laser.transform.translation.x, base_laser.transform.rotation.w) == ("base_link", "laser", 0.1, 1.0)
    odom = bag["/odom"][1][1]
    assert (odom.header.frame_id, odom.child_frame_id, odom.twist.twist.linear.x) == ("odom", "base_link", pytest.approx(0.4))
    # A goal pose when the goal changes; the path as poses; the frontiers as explore_lite's markers.
    assert [(m.pose.position.x, m.pose.position.y) for _, m in bag["/goal_pose"]] == [(1.0, 2.0), (3.0, -1.0)]
    plan = bag["/plan"][4][1]
    assert [(p.pose.position.x, p.pose.position.y) for p in plan.poses] == [(pytest.approx(0.4), 0.0), (3.0, -1.0)]
    markers = bag["/explore/frontiers"][0][1].markers
    assert [m.ns for m in markers] == ["", "frontiers", "frontiers_goals"]  # DELETEALL of every namespace, as RViz 2 reads an empty ns
    assert markers[0].action == markers[0].DELETEALL
    # metadata.yaml of version 8: each topic's QoS profiles a YAML string, which Humble's rosbag2 reads (9's list it cannot).
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 8
    assert all(isinstance(t["topic_metadata"]["offered_qos_profiles"], str) for t in meta["topics_with_message_count"])
    assert [(p.x, p.y) for p in markers[1].points] == [pytest.approx(GEOM.cell_to_world(3, 4)), pytest.approx(GEOM.cell_to_world(3, 5)), pytest.approx(GEOM.cell_to_world(4, 5))]


def test_a_second_episode_follows_the_first_and_received_time_keeps_the_recording_s(tmp_path: Path, monkeypatch):
    keys = RobotKeys("r0")
    first = episode(keys, 3, T0_NS, 2_000_000)
    second = episode(keys, 2, T0_NS + 10_000_000, 2_000_000)  # the robot's clock starts again at 0
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", first + second)
    monkeypatch.setattr("cso_runtime.bag_export.PROGRESS_EVERY", 10)
    calls: list[tuple[int, int | None]] = []
    export_bag(recording, tmp_path / "sim", map_period_s=0, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(10, 40), (20, 40), (30, 40), (40, 40), (40, 40)]  # 5 steps of 8 messages, then the end
    times = [t for t, _ in read_bag(tmp_path / "sim")["/scan"]]
    assert times == [T0_NS + k * 250_000_000 for k in range(5)]  # 0, 0.25, 0.5, then 0.75 and 1.0 s
    export_bag(recording, tmp_path / "received", map_period_s=0, time="received")
    bag = read_bag(tmp_path / "received")
    assert [t for t, _ in bag["/scan"]] == [m.log_time_ns for m in first + second if m.key == keys.scan]
    assert len(bag["/map"]) == 5


def test_a_recording_of_the_versions_before_the_episode_id_exports_the_same_bag(tmp_path: Path):
    """A recording made before odom, goal and frontiers carried the episode id gives the bag today's would;
    a payload of a version this build does not know is still counted and left out."""
    keys = RobotKeys("r0")
    current = episode(keys, 5, T0_NS, 2_000_000)
    old = [RecordedMessage(m.key, m.log_time_ns, legacy(m.payload)) for m in current]
    assert sum(m.payload != o.payload for m, o in zip(current, old)) == 3 * 5  # odom, frontiers, goal of each step
    future = msgpack.packb({"schema": "odom", "v": 99, "body": {}}, use_bin_type=True)
    old.insert(3, RecordedMessage(keys.odom, T0_NS + 1500, future))
    write_recording(tmp_path / "current.mcap", "r0", current)
    write_recording(tmp_path / "old.mcap", "r0", old)
    export_bag(tmp_path / "current.mcap", tmp_path / "current", map_period_s=0)
    stats = export_bag(tmp_path / "old.mcap", tmp_path / "old", map_period_s=0)
    assert stats.rejected == {"odom": 1}
    assert dict(stats.written) == {"/tf_static": 1, "/odom": 5, "/tf": 5, "/scan": 5, "/map": 5, "/plan": 5, "/goal_pose": 2, "/explore/frontiers": 3, "/cmd_vel": 5}
    with Reader(tmp_path / "current") as want, Reader(tmp_path / "old") as got:
        assert [(c.topic, t, raw) for c, t, raw in got.messages()] == [(c.topic, t, raw) for c, t, raw in want.messages()]


def test_bad_exports_are_refused_and_leave_nothing_behind(tmp_path: Path):
    recording = tmp_path / "two.mcap"
    write_recording(recording, "*", episode(RobotKeys("a"), 1, T0_NS, 1000) + episode(RobotKeys("b"), 1, T0_NS + 10**6, 1000))
    with pytest.raises(BagExportError, match="robots a, b: give --robot"):
        export_bag(recording, tmp_path / "bag")
    with pytest.raises(BagExportError, match="no messages of robot 'c'"):
        export_bag(recording, tmp_path / "bag", robot="c")
    assert not (tmp_path / "bag").exists()
    stats = export_bag(recording, tmp_path / "bag", robot="b")
    assert stats.robot == "b" and stats.written["/scan"] == 1
    with pytest.raises(BagExportError, match="exists"):
        export_bag(recording, tmp_path / "bag", robot="b")
    with pytest.raises(ValueError, match="time must be one of"):
        export_bag(recording, tmp_path / "other", robot="b", time="wall")
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(recording.read_bytes()[: len(recording.read_bytes()) // 2])
    with pytest.raises(BagExportError, match="broken.mcap"):
        export_bag(broken, tmp_path / "from_broken")
    assert not (tmp_path / "from_broken").exists() and not (tmp_path / "other").exists()
    with pytest.raises(ValueError, match="map_period_s"):
        BagConverter(-1.0)


def test_a_recording_with_nothing_to_convert_is_refused_not_written_as_an_empty_bag(tmp_path: Path):
    """A recording of the robot's clock alone (its pipeline never came up), or one whose every message of a converted
    topic fails to decode, is no bag: rosbag2 would list one of no topics, starting at INT64_MAX."""
    keys = RobotKeys("r0")
    clock_only = [m for m in episode(keys, 3, T0_NS, 1000) if m.key == keys.topic("clock")]
    recording = tmp_path / "clock.mcap"
    write_recording(recording, "r0", clock_only)
    with pytest.raises(BagExportError, match=r"clock\.mcap holds nothing of robot r0 to export .*clock 3.*no bag written"):
        export_bag(recording, tmp_path / "bag")
    assert not (tmp_path / "bag").exists()
    bad_scan = RecordedMessage(keys.scan, T0_NS + 10**6, msgpack.packb({"schema": "scan", "v": 99, "body": {}}))
    write_recording(recording, "r0", [*clock_only, bad_scan])
    with pytest.raises(BagExportError, match=r"left out, did not decode: scan 1"):
        export_bag(recording, tmp_path / "bag")
    assert not (tmp_path / "bag").exists()


def test_an_interrupted_export_leaves_no_bag_that_looks_whole(tmp_path: Path, monkeypatch):
    from cso_runtime import bag_export

    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 3, T0_NS, 1000))
    monkeypatch.setattr(bag_export, "PROGRESS_EVERY", 5)

    def ctrl_c(read: int, total: int | None) -> None:
        if read >= 10:  # some messages are written by then
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        export_bag(recording, tmp_path / "bag", progress=ctrl_c)
    assert not (tmp_path / "bag").exists()


def test_an_export_that_fails_unforeseen_halfway_leaves_no_folder_behind(tmp_path: Path, monkeypatch):
    """Any error halfway (a converter bug, MemoryError on a huge map) leaves no half-written folder that a second
    export would then refuse as existing: the writer aborts without metadata.yaml but keeps the cut .mcap."""
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 3, T0_NS, 1000))
    convert, calls = BagConverter.convert, []

    def fails_at_the_tenth(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 10:  # some messages are written by then
            raise MemoryError
        return convert(self, *args, **kwargs)

    monkeypatch.setattr(BagConverter, "convert", fails_at_the_tenth)
    with pytest.raises(MemoryError):
        export_bag(recording, tmp_path / "bag")
    assert not (tmp_path / "bag").exists()


def test_export_bag_command_writes_beside_the_recording_and_says_what(tmp_path: Path):
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 2, T0_NS, 1000))
    done = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert f"wrote {tmp_path / 'run'} (robot r0): " in done.stdout and "/scan 2" in done.stdout
    assert "base_link -> laser: (0.1 m, 0 m, 0 rad)" in done.stdout and "map -> odom" not in done.stdout  # a plan that is its own map frame
    assert (tmp_path / "run" / "metadata.yaml").is_file()
    again = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording)], capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "exists" in again.stderr
    missing = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "export-bag", str(tmp_path / "nope.mcap")], capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "no such recording" in missing.stderr


def test_export_bag_refuses_bad_settings_by_their_flags(tmp_path: Path):
    """A bad ``--map-period-s`` or ``--time`` is refused in the flag's name, not the Python parameter's
    (``map_period_s``, ``time``), before any folder is made."""
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 2, T0_NS, 1000))
    cli = [sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording)]
    for flags, said in ((["--map-period-s", "-1"], "--map-period-s must be a number of seconds >= 0, not -1"),
                        (["--map-period-s", "inf"], "--map-period-s must be a number of seconds >= 0, not inf"),
                        (["--time", "wall"], "--time must be one of sim, received, not 'wall'")):  # fmt: skip
        done = subprocess.run([*cli, *flags], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and said in done.stderr, (flags, done.stderr)
        assert "map_period_s" not in done.stderr and "time must" not in done.stderr.replace("--time must", ""), done.stderr
    assert not (tmp_path / "run").exists()


def test_export_bag_namespace_puts_topics_and_frames_under_the_robots_name(tmp_path: Path):
    """Two robots' bags, merged, collided: both had /scan, /odom... and frames odom, base_link, laser on one /tf.
    ``--namespace limo1`` names them as multi-robot ROS 2 setups do (tf2 has no tf_prefix): /limo1/scan, frames
    limo1/odom, limo1/base_link...; /tf and /tf_static stay global, the frames' prefix keeping each robot's tree apart."""
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 3, T0_NS, 1000))
    done = subprocess.run(
        [sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording), "--out", str(tmp_path / "ns"), "--namespace", "limo1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    plain = read_bag(export_bag(recording, tmp_path / "plain").path)
    got: dict[str, list[object]] = {}
    with Reader(tmp_path / "ns") as reader:
        for conn in reader.connections:
            plain_topic = conn.topic if conn.topic in ("/tf", "/tf_static") else conn.topic.removeprefix("/limo1")
            assert conn.msgtype == ROS_TYPES[plain_topic], conn.topic
        for conn, _, raw in reader.messages():
            got.setdefault(conn.topic, []).append(ros2_cdr.decode(raw, conn.msgtype))
    assert sorted(got) == sorted(t if t in ("/tf", "/tf_static") else f"/limo1{t}" for t in plain)
    assert {t: len(v) for t, v in got.items()} == {(t if t in ("/tf", "/tf_static") else f"/limo1{t}"): len(v) for t, v in plain.items()}
    frames = set().union(*bag_frames({topic: [(0, m) for m in msgs] for topic, msgs in got.items()}).values())
    assert frames == {"limo1/map", "limo1/odom", "limo1/base_link", "limo1/laser"}, frames
    bad = subprocess.run(
        [sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording), "--out", str(tmp_path / "bad"), "--namespace", "1-robot"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert bad.returncode == 2 and "no ROS name" in bad.stderr and not (tmp_path / "bad").exists(), bad.stderr


SCENE_ORIGIN = Pose2D(2.0, -1.0, 0.5)
"""A map_server scene's ``origin`` (x, y and yaw): the plan's pose in the user's map frame."""


def with_status(messages: list[RecordedMessage], keys: RobotKeys, episode_id: int, map_origin: Pose2D) -> list[RecordedMessage]:
    """``messages`` with the episode's status right after its first map, where the sim first publishes it."""
    first_map = next(i for i, m in enumerate(messages) if m.key == keys.map)
    status = EpisodeStatusMsg("exploring", 0, "plan", "greedy-dist", episode=episode_id, map_origin=map_origin)
    at_ns = messages[first_map].log_time_ns + 1
    return [*messages[: first_map + 1], RecordedMessage(keys.episode_status, at_ns, encode(status)), *messages[first_map + 1 :]]


def scans_fired_early(messages: list[RecordedMessage], keys: RobotKeys, early_s: float) -> list[RecordedMessage]:
    """``messages`` with each scan after step 0 fired ``early_s`` before its step's odometry, at the sensor pose it has
    (a real-time MuJoCo LIMO's: its LiDAR fires at 8 Hz, the step's odometry is of the step's end)."""
    out = []
    for m in messages:
        if m.key == keys.scan and (scan := decode(m.payload, ScanMsg)).step > 0:
            fired = dataclasses.replace(scan.scan, stamp_s=scan.scan.stamp_s - early_s)
            m = RecordedMessage(m.key, m.log_time_ns, encode(ScanMsg(scan.step, fired, scan.sensor_pose, scan.episode)))
        out.append(m)
    return out


def tf_pose(tf) -> Pose2D:
    """A planar TransformStamped as the child's pose in its parent."""
    q = tf.transform.rotation
    return Pose2D(tf.transform.translation.x, tf.transform.translation.y, ros2_cdr.yaw_from_quaternion(q.x, q.y, q.z, q.w))


def msg_pose(pose) -> Pose2D:
    """A geometry_msgs/Pose as a planar pose."""
    q = pose.orientation
    return Pose2D(pose.position.x, pose.position.y, ros2_cdr.yaw_from_quaternion(q.x, q.y, q.z, q.w))


def approx_pose(p: Pose2D, abs_tol: float = 1e-9):
    return pytest.approx((p.x_m, p.y_m, p.yaw_rad), abs=abs_tol)


def as_tuple(p: Pose2D) -> tuple[float, float, float]:
    return (p.x_m, p.y_m, p.yaw_rad)


def test_a_map_server_scenes_bag_is_in_its_map_frame_as_amcl_places_odom(tmp_path: Path):
    """A map_server scene whose ``origin`` is not zero: the robot explores in the plan's frame, which the bag makes
    ``odom`` (drift-free) under a ``map`` -> ``odom`` equal to the scene's ``map_origin`` (from the recording's
    episode/status, which comes only after the first map), as AMCL places odom; the map, goals, paths and frontiers are
    in ``map``, so the grid overlays the user's own map cell for cell. The LiDAR hangs from ``base_link`` by a static
    transform (its mount, as the recording shows it), each scan still exactly at its sensor pose, and the odometry has
    a covariance robot_localization accepts. Before, map -> odom was the identity, the grid at the plan's corner, the
    laser under odom and the covariance all zero. A scene whose origin is zero exports as before, to the byte."""
    keys = RobotKeys("r0")
    recording = tmp_path / "run.mcap"
    messages = scans_fired_early(episode(keys, 4, T0_NS, 2_000_000, episode_id=7), keys, 0.1)
    write_recording(recording, "r0", with_status(messages, keys, 7, SCENE_ORIGIN))
    stats = export_bag(recording, tmp_path / "bag", map_period_s=0)
    bag = read_bag(tmp_path / "bag")
    assert stats.left_out == {"clock": 4, "episode/status": 1}
    assert (stats.map_origins, stats.lidar_mount) == ({7: SCENE_ORIGIN}, Pose2D(0.1, 0.0, 0.0))

    (static,) = bag["/tf_static"]
    frames = {(tf.header.frame_id, tf.child_frame_id): tf_pose(tf) for tf in static[1].transforms}
    assert set(frames) == {("map", "odom"), ("base_link", "laser")}
    assert as_tuple(frames[("map", "odom")]) == approx_pose(SCENE_ORIGIN)
    assert as_tuple(frames[("base_link", "laser")]) == approx_pose(Pose2D(0.1, 0.0, 0.0))  # step 0's scan, 0.1 m ahead of its odometry

    # The grid in the map frame, the first one too (its status came after it): its corner is the plan's corner placed
    # by the origin, turned as map_server turns a map by its origin's yaw; a cell's centre lands where map -> odom puts it.
    for _, grid in bag["/map"]:
        assert grid.header.frame_id == "map"
        corner = msg_pose(grid.info.origin)
        assert as_tuple(corner) == approx_pose(compose_pose(SCENE_ORIGIN, Pose2D(GEOM.origin_x_m, GEOM.origin_y_m, 0.0)))
        iy, ix = 7, 12
        via_grid = compose_pose(corner, Pose2D((ix + 0.5) * grid.info.resolution, (iy + 0.5) * grid.info.resolution, 0.0))
        via_tf = compose_pose(frames[("map", "odom")], Pose2D(*GEOM.cell_to_world(iy, ix), 0.0))
        assert (via_grid.x_m, via_grid.y_m) == pytest.approx((via_tf.x_m, via_tf.y_m), abs=1e-6)
    assert len(bag["/map"]) == 4

    # Goals, paths and frontiers: in the map frame, each point the plan frame's placed by the origin.
    def in_map(x_m: float, y_m: float) -> tuple[float, float]:
        p = compose_pose(SCENE_ORIGIN, Pose2D(x_m, y_m, 0.0))
        return pytest.approx((p.x_m, p.y_m), abs=1e-6)  # a path travels as float32

    assert [m.header.frame_id for _, m in bag["/goal_pose"]] == ["map", "map"]
    assert [(m.pose.position.x, m.pose.position.y) for _, m in bag["/goal_pose"]] == [in_map(1.0, 2.0), in_map(3.0, -1.0)]
    plan = bag["/plan"][3][1]
    assert plan.header.frame_id == "map" and [(p.pose.position.x, p.pose.position.y) for p in plan.poses] == [in_map(0.3, 0.0), in_map(3.0, -1.0)]
    markers = bag["/explore/frontiers"][0][1].markers
    assert [(p.x, p.y) for p in markers[1].points] == [in_map(*GEOM.cell_to_world(iy, ix)) for iy, ix in [(3, 4), (3, 5), (4, 5)]]
    assert (markers[2].pose.position.x, markers[2].pose.position.y) == in_map(-0.55, -0.15)

    # The odometry in odom (the plan's frame), as recorded, with the LIMO driver's diagonal covariance.
    diagonal = [0.1, 0.1, 0.1, 1.0, 1.0, 1.0]
    for _, odom in bag["/odom"]:
        for cov in (odom.pose.covariance, odom.twist.covariance):
            assert list(np.asarray(cov).reshape(6, 6).diagonal()) == diagonal and np.count_nonzero(cov) == 6
    assert (bag["/odom"][2][1].pose.pose.position.x, bag["/odom"][2][1].header.frame_id) == (pytest.approx(0.2), "odom")

    # Each scan, in `laser` at its own stamp (fired 0.1 s before its step's odometry), exactly at its sensor pose, which
    # is not the odometry's pose plus the mount: odom -> base_link at the scan's time is its sensor pose less the mount.
    tfs = [(t, tf) for t, m in bag["/tf"] for tf in m.transforms]
    assert {(tf.header.frame_id, tf.child_frame_id) for _, tf in tfs} == {("odom", "base_link")}
    base_at = {t: tf_pose(tf) for t, tf in tfs}
    assert len(base_at) == len(tfs) == 1 + 2 * 3  # step 0's odometry and scan share a time; one transform a time (tf2 keeps the first)
    assert [t for t, _ in bag["/scan"]] == [T0_NS] + [T0_NS + k * 250_000_000 - 100_000_000 for k in (1, 2, 3)]
    assert [t for t, _ in bag["/odom"]] == [T0_NS + k * 250_000_000 for k in range(4)]
    for k, (t, scan) in enumerate(bag["/scan"]):
        assert scan.header.frame_id == "laser" and stamp_ns(scan.header) == t
        laser = compose_pose(base_at[t], frames[("base_link", "laser")])
        assert as_tuple(laser) == approx_pose(Pose2D(0.1 * k + 0.1, 0.0, 0.05 * k), 1e-12)
    for t, odom in bag["/odom"]:
        assert as_tuple(base_at[t]) == approx_pose(msg_pose(odom.pose.pose), 0.0)  # the robot by its odometry at the odometry's time


    # Dungeon, generated and builtin plans are their own map frame (map_origin zeros): their status changes nothing, to the byte.
    plain = episode(keys, 3, T0_NS, 2_000_000, episode_id=7)
    write_recording(tmp_path / "plain.mcap", "r0", plain)
    write_recording(tmp_path / "zero.mcap", "r0", with_status(plain, keys, 7, Pose2D(0.0, 0.0, 0.0)))
    export_bag(tmp_path / "plain.mcap", tmp_path / "plain", map_period_s=0)
    export_bag(tmp_path / "zero.mcap", tmp_path / "zero", map_period_s=0)
    with Reader(tmp_path / "plain") as want, Reader(tmp_path / "zero") as got:
        assert [(c.topic, t, raw) for c, t, raw in got.messages()] == [(c.topic, t, raw) for c, t, raw in want.messages()]


def test_a_second_episode_in_another_scene_moves_map_to_odom_from_its_first_message(tmp_path: Path):
    """A recording of two episodes in two map_server scenes: each episode's map -> odom is its own scene's map origin,
    sent again on /tf_static with the second episode's first message (tf2 then replaces it), and each map is placed by
    its own episode's origin, the second's first map included (its status comes after it)."""
    keys, other = RobotKeys("r0"), Pose2D(-3.0, 4.0, -1.0)
    first = with_status(episode(keys, 3, T0_NS, 2_000_000, episode_id=7), keys, 7, SCENE_ORIGIN)
    second = with_status(episode(keys, 2, T0_NS + 10_000_000, 2_000_000, episode_id=8), keys, 8, other)
    write_recording(tmp_path / "two.mcap", "r0", first + second)
    export_bag(tmp_path / "two.mcap", tmp_path / "bag", map_period_s=0)
    bag = read_bag(tmp_path / "bag")
    statics = [(t, {(tf.header.frame_id, tf.child_frame_id): tf_pose(tf) for tf in m.transforms}) for t, m in bag["/tf_static"]]
    assert [as_tuple(s[("map", "odom")]) for _, s in statics] == [approx_pose(SCENE_ORIGIN), approx_pose(other)]
    assert statics[1][0] == T0_NS + 3 * 250_000_000  # the second episode's first step, a step after the first's last
    corners = [msg_pose(m.info.origin) for _, m in bag["/map"]]
    expected = [compose_pose(o, Pose2D(GEOM.origin_x_m, GEOM.origin_y_m, 0.0)) for o in [SCENE_ORIGIN] * 3 + [other] * 2]
    assert [as_tuple(c) for c in corners] == [approx_pose(e) for e in expected]


def test_a_cut_recording_is_said_once_with_all_it_holds(tmp_path: Path, caplog):
    """Export and animate read a recording cut short (its recorder killed) several times (its robot, the LiDAR mount,
    the map origins, the messages): one warning, counting every message read, not one per pass with the count of
    the topics that pass asked for."""
    from cso_runtime.animation import animate_recording

    whole = tmp_path / "whole.mcap"
    write_recording(whole, "r0", episode(RobotKeys("r0"), 600, T0_NS, 1_000_000))
    data = whole.read_bytes()
    summary_start = int.from_bytes(data[-8 - 29 : -8][9:17], "little")  # the footer's summary_start
    killed = tmp_path / "killed.mcap"
    killed.write_bytes(data[:summary_start])  # the chunks, no summary and no footer
    for run in (lambda: export_bag(killed, tmp_path / "bag"), lambda: animate_recording(killed, tmp_path / "killed.gif")):
        caplog.clear()
        with caplog.at_level("WARNING", logger="cso.recording"):
            run()
        warned = [r.getMessage() for r in caplog.records if "ends early" in r.getMessage()]
        assert len(warned) == 1 and "read 4800 messages up to there" in warned[0], warned


def test_a_recording_of_a_run_that_raised_max_grid_cells_exports_its_large_map(tmp_path: Path):
    """A run whose profile raised ``max_grid_cells`` records maps above the default bound; ``export-bag`` (a one-shot
    tool, not a service that stays up) reads them up to the format's ceiling instead of leaving the map out."""
    from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, MAX_GRID_CELLS, MessageError, decode, set_max_grid_cells

    keys = RobotKeys("r0")
    messages = episode(keys, 2, T0_NS, 1000)
    big = GridGeometry(0.05, (2001, 2000), 0.0, 0.0)  # 4,002,000 cells: a 100 m x 100 m arena and a row
    assert big.shape[0] * big.shape[1] > DEFAULT_MAX_GRID_CELLS
    grid = np.full(big.shape, -1, np.int8)
    grid[:50, :60] = 0
    set_max_grid_cells(MAX_GRID_CELLS)  # the run that recorded it (the autouse fixture puts the default back)
    payload = encode(MapMsg.from_grid(2, big, grid))
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)
    with pytest.raises(MessageError, match="max_grid_cells"):
        decode(payload, MapMsg)  # what a service of a default run would say
    recording = tmp_path / "big.mcap"
    write_recording(recording, "r0", [*messages, RecordedMessage(keys.topic("map"), T0_NS + 10_000_000, payload)])
    done = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording), "--map-period-s", "0"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "/map 3" in done.stdout and "did not decode" not in done.stdout, done.stdout
    maps = read_bag(tmp_path / "big")["/map"]
    assert (maps[-1][1].info.height, maps[-1][1].info.width) == big.shape


def bag_frames(bag: dict[str, list[tuple[int, object]]]) -> dict[str, set[str]]:
    """Topic -> every frame id its messages name (headers, child frames, transforms' both ends)."""
    frames: dict[str, set[str]] = {}
    for topic, msgs in bag.items():
        seen = frames.setdefault(topic, set())
        for _, m in msgs:
            if topic in ("/tf", "/tf_static"):
                seen |= {f for tf in m.transforms for f in (tf.header.frame_id, tf.child_frame_id)}
            elif topic == "/explore/frontiers":
                seen |= {marker.header.frame_id for marker in m.markers if marker.action != 3}  # DELETEALL carries one too
            elif topic == "/odom":
                seen |= {m.header.frame_id, m.child_frame_id}
            elif hasattr(m, "header"):
                seen.add(m.header.frame_id)
    return frames


def test_export_bag_names_the_frames_as_the_robots_tf_tree(tmp_path: Path):
    """A ROS 2 user's LIMO names its LiDAR's frame ``laser_link`` (AgileX's driver): the bag's ``laser`` hung beside it
    in their TF tree and RViz dropped the scans. ``--laser-frame`` (and ``--base-frame``, ``--odom-frame``,
    ``--map-frame``) name the frames, the same name in /scan's header, /tf, /tf_static and every other header, under a
    ``--namespace`` too; the default bag is the one written before, to the byte. A name tf2 refuses, or one frame named
    twice (a loop), is refused before any folder is made."""
    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 3, T0_NS, 1000))
    cli = [sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording)]
    done = subprocess.run([*cli, "--out", str(tmp_path / "limo"), "--laser-frame", "laser_link"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "base_link -> laser_link: (0.1 m, 0 m, 0 rad)" in done.stdout, done.stdout
    limo = bag_frames(read_bag(tmp_path / "limo"))
    assert limo["/scan"] == {"laser_link"} and limo["/tf_static"] == {"map", "odom", "base_link", "laser_link"}
    assert limo["/tf"] == limo["/odom"] == {"odom", "base_link"} and limo["/map"] == {"map"}

    from cso_runtime.bag_export import BagFrames

    names = BagFrames(map="world", odom="odom_wheel", base="base_footprint", laser="laser_link")
    export_bag(recording, tmp_path / "all", frames=names, namespace="limo1")
    with Reader(tmp_path / "all") as reader:
        namespaced = [(conn.topic.removeprefix("/limo1"), t, ros2_cdr.decode(raw, conn.msgtype)) for conn, t, raw in reader.messages()]
    frames = bag_frames({topic: [(t, m) for other, t, m in namespaced if other == topic] for topic, _, _ in namespaced})
    assert frames == {
        "/scan": {"limo1/laser_link"}, "/tf_static": {"limo1/world", "limo1/odom_wheel", "limo1/base_footprint", "limo1/laser_link"},
        "/tf": {"limo1/odom_wheel", "limo1/base_footprint"}, "/odom": {"limo1/odom_wheel", "limo1/base_footprint"},
        "/map": {"limo1/world"}, "/plan": {"limo1/world"}, "/goal_pose": {"limo1/world"}, "/explore/frontiers": {"limo1/world"},
        "/cmd_vel": set(),  # a Twist: no header
    }  # fmt: skip

    export_bag(recording, tmp_path / "default")
    export_bag(recording, tmp_path / "named", frames=BagFrames("map", "odom", "base_link", "laser"))
    with Reader(tmp_path / "default") as want, Reader(tmp_path / "named") as got:
        assert [(c.topic, t, raw) for c, t, raw in got.messages()] == [(c.topic, t, raw) for c, t, raw in want.messages()]

    for flags, said in ((["--laser-frame", "/laser"], "no tf2 frame id"), (["--base-frame", "base link"], "no tf2 frame id"),
                        (["--laser-frame", "base_link"], "'base_link' twice")):  # fmt: skip
        bad = subprocess.run([*cli, "--out", str(tmp_path / "bad"), *flags], capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and said in bad.stderr and not (tmp_path / "bad").exists(), (flags, bad.stderr)


def test_bag_scans_carry_the_recordings_scan_period_and_no_time_increment(tmp_path: Path):
    """Every /scan had ``scan_time`` 0 (unknown to ROS tools): it is the period between the recording's scans (the
    median step of their stamps: 0.25 s for the simulator's scan a step, whether or not a scan fired early or one was
    lost), 0 where a recording has a single scan. ``time_increment`` stays 0: each scan is taken at one instant, at the
    one sensor pose of its stamp, where the mapper integrated it (a consumer that spread its beams over the robot's
    motion would put them elsewhere)."""
    keys = RobotKeys("r0")
    messages = scans_fired_early(episode(keys, 6, T0_NS, 2_000_000), keys, 0.1)
    lost = [m for m in messages if not (m.key == keys.scan and decode(m.payload, ScanMsg).step == 4)]  # a scan lost: 0.5 s
    write_recording(tmp_path / "run.mcap", "r0", lost)
    stats = export_bag(tmp_path / "run.mcap", tmp_path / "bag")
    scans = [m for _, m in read_bag(tmp_path / "bag")["/scan"]]
    assert len(scans) == 5 and [s.scan_time for s in scans] == [0.25] * 5 and all(s.time_increment == 0.0 for s in scans)
    assert stats.scan_period_s == 0.25

    from cso_runtime.bag_export import recorded_scan_period

    write_recording(tmp_path / "one.mcap", "r0", episode(keys, 1, T0_NS, 1000))
    assert recorded_scan_period(tmp_path / "one.mcap", "r0") == 0.0
    assert all(s.scan_time == 0.0 for _, s in read_bag(export_bag(tmp_path / "one.mcap", tmp_path / "one").path)["/scan"])
    # Two episodes whose clocks start again: the step between them is no period.
    write_recording(tmp_path / "two.mcap", "r0", episode(keys, 1, T0_NS, 1000, episode_id=1) + episode(keys, 1, T0_NS + 10**6, 1000, episode_id=2))
    assert recorded_scan_period(tmp_path / "two.mcap", "r0") == 0.0


def test_a_bags_map_origin_is_rounded_as_save_maps_yaml(tmp_path: Path):
    """The bag's /map said ``info.origin`` -5.2749999999999995 (a real robot's arena corner as the float sum gave it),
    where save-map's YAML says -5.275: both are rounded to the nanometre by one function (``rounded_pose``), so the
    bag's map and the saved map lie at the same origin; a scene's map origin placing the grid is rounded alike."""
    from cso_runtime.map_files import save_map

    keys = RobotKeys("r0")
    arena = GridGeometry(0.05, (4, 5), -5.2749999999999995, -6.725)  # the limo-ros2 arena's corner, as the bridge had it
    grid = np.zeros(arena.shape, np.int8)
    maps = [RecordedMessage(keys.map, T0_NS + 10**6, encode(MapMsg.from_grid(0, arena, grid)))]
    write_recording(tmp_path / "robot.mcap", "r0", episode(keys, 1, T0_NS, 1000) + maps)
    (_, last), *_ = reversed(read_bag(export_bag(tmp_path / "robot.mcap", tmp_path / "robot", map_period_s=0).path)["/map"])
    saved = yaml.safe_load(save_map(tmp_path / "robot.yaml", grid, arena).read_text())["origin"]
    assert [last.info.origin.position.x, last.info.origin.position.y] == saved[:2] == [-5.275, -6.725]

    origin = Pose2D(0.7, 0.7, 0.0)  # a map_server scene's, where GEOM's corner lands at (-0.30000000000000004, 0.19999999999999996)
    assert compose_pose(origin, Pose2D(GEOM.origin_x_m, GEOM.origin_y_m, 0.0)).x_m != -0.3
    write_recording(tmp_path / "scene.mcap", "r0", with_status(episode(keys, 1, T0_NS, 1000, episode_id=3), keys, 3, origin))
    (_, scene_map), *_ = read_bag(export_bag(tmp_path / "scene.mcap", tmp_path / "scene").path)["/map"]
    saved = yaml.safe_load(save_map(tmp_path / "scene.yaml", _map(0).grid, GEOM, map_origin=origin).read_text())["origin"]
    assert [scene_map.info.origin.position.x, scene_map.info.origin.position.y] == saved[:2] == [-0.3, 0.2]

    from cso_runtime.geometry import rounded_pose

    assert rounded_pose(Pose2D(-0.0, 1e-12, -5.2749999999999995)) == Pose2D(0.0, 0.0, -5.275)


def test_an_episode_after_one_of_one_or_two_steps_follows_it_by_its_episode_id(tmp_path: Path):
    """The timeline told a new episode only by step numbers going back by more than one: an episode after one of one
    or two steps (steps 0 then 0, or 0, 1 then 0) was laid over it, its scans at the times of the one before. The
    messages' episode id now tells it; a late message of the episode just left keeps that episode's time."""
    keys = RobotKeys("r0")
    runs = [episode(keys, n, T0_NS + i * 10_000_000, 2_000_000, episode_id=100 + i) for i, n in enumerate((1, 2, 1, 3))]
    write_recording(tmp_path / "run.mcap", "r0", [m for run in runs for m in run])
    export_bag(tmp_path / "run.mcap", tmp_path / "bag", map_period_s=0)
    bag = read_bag(tmp_path / "bag")
    steps = 1 + 2 + 1 + 3
    for topic in ("/scan", "/odom", "/map", "/cmd_vel"):
        assert [t for t, _ in bag[topic]] == [T0_NS + k * 250_000_000 for k in range(steps)], topic

    # The timeline alone: a late odometry and map of the episode left keep its times.
    from cso_runtime.bag_export import StepTimeline

    timeline = StepTimeline(T0_NS)
    assert [timeline.stamp(k, 0.25 * k, 7) for k in (0, 1)] == [T0_NS, T0_NS + 250_000_000]
    assert timeline.stamp(0, 0.0, 8) == T0_NS + 500_000_000  # episode 8's first step, one step after 7's last
    assert timeline.stamp(1, 0.25, 7) == T0_NS + 250_000_000 and timeline.at(1, 7) == T0_NS + 250_000_000  # late, of 7
    assert timeline.stamp(1, 0.25, 8) == T0_NS + 750_000_000 and timeline.at(1, 8) == T0_NS + 750_000_000
    # No ids (a recording before them): step numbers going back tell a new episode, as before.
    legacy_timeline = StepTimeline(T0_NS)
    assert [legacy_timeline.stamp(k, 0.25 * k) for k in (0, 1, 2, 0)] == [T0_NS + k * 250_000_000 for k in range(4)]


def test_a_late_message_of_any_episode_left_keeps_its_times_and_one_of_an_episode_to_come_is_not_laid_back():
    """The timeline kept the times of the episode left last alone: a message of the one before it, late after an episode
    of one step (episodes 1, 2 of one step, 3: odometry of 1 after 3's first scan), was taken for a new episode, and
    3's next step for another, both laid after everything before (3's steps shifted by a step). A map of an episode
    whose first scan is still to come (another key, handled first) took the time of the same step in the episode before,
    back at its start."""
    from cso_runtime.bag_export import StepTimeline

    timeline = StepTimeline(T0_NS)

    def stamp(step: int, episode: int) -> float:
        return (timeline.stamp(step, 0.25 * step, episode) - T0_NS) / 1e9

    assert [stamp(0, 1), stamp(1, 1), stamp(2, 1), stamp(0, 2), stamp(0, 3)] == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert stamp(2, 1) == 0.5 and timeline.at(2, 1) == T0_NS + 500_000_000  # late, of episode 1: its own times
    assert stamp(1, 3) == 1.25 and stamp(0, 2) == 0.75  # episode 3 goes on where it was; 2 keeps its time
    assert timeline.at(5, 1) == T0_NS + 500_000_000  # a late one of a step episode 1 has no time for: its last
    assert timeline.at(0, 4) == T0_NS + 1_250_000_000  # episode 4's map before its scan: the latest, not 3's (or 1's) step 0
    assert stamp(0, 4) == 1.5 and timeline.at(0, 4) == T0_NS + 1_500_000_000
    # Without ids (a recording before them) a message's step is looked up in the current episode, as before.
    legacy = StepTimeline(T0_NS)
    assert [legacy.stamp(k, 0.25 * k) for k in (0, 1, 2, 0)] == [T0_NS + k * 250_000_000 for k in range(4)]
    assert legacy.at(0) == T0_NS + 750_000_000 and legacy.at(1) == T0_NS + 750_000_000 and legacy.at(1, 9) == T0_NS + 750_000_000
    # An episode of ids, then one of none told by its steps: a late map of the first keeps its time.
    mixed = StepTimeline(T0_NS)
    assert [mixed.stamp(k, 0.25 * k, 5) for k in (0, 1, 2)] + [mixed.stamp(k, 0.25 * k) for k in (0, 1)] == [T0_NS + k * 250_000_000 for k in range(5)]
    assert mixed.at(1, 5) == T0_NS + 250_000_000 and mixed.at(1) == T0_NS + 1_000_000_000


def test_a_long_recording_of_many_episodes_keeps_every_step_time_of_the_last_episodes_left_alone():
    """``StepTimeline`` kept the time of every step of every episode left, for their late messages: a recording of many
    episodes grew by one time per step for the whole export. The last ``LEFT_EPISODES_STEPS_KEPT`` episodes left keep
    every step's; the ones before, their last (a late map of one takes it; a late scan, its own stamp's time still)."""
    from cso_runtime.bag_export import LEFT_EPISODES_STEPS_KEPT, StepTimeline

    timeline = StepTimeline(T0_NS)
    episodes, steps = LEFT_EPISODES_STEPS_KEPT + 24, 30
    for episode in range(1, episodes + 1):
        for k in range(steps):
            timeline.stamp(k, 0.25 * k, episode)
    kept = sum(len(by_step) for _, by_step in timeline.left.values())
    assert len(timeline.left) == episodes - 1 and kept == LEFT_EPISODES_STEPS_KEPT * steps + (episodes - 1 - LEFT_EPISODES_STEPS_KEPT), kept
    episode_s = steps * 0.25  # each episode follows the one before by one step
    first_last_ns = T0_NS + round((steps - 1) * 0.25 * 1e9)
    assert timeline.at(3, 1) == first_last_ns  # a late map of the first episode: its last time
    assert timeline.stamp(3, 0.75, 1) == T0_NS + 750_000_000  # a late scan of it: its own time
    recent = episodes - 1  # the one left last: each step's time still
    assert timeline.at(3, recent) == T0_NS + round(((recent - 1) * episode_s + 0.75) * 1e9)


def test_export_bag_refuses_a_map_period_too_long_to_count_in_nanoseconds(tmp_path: Path):
    """``export-bag --map-period-s 1e308`` ended in ``OverflowError: cannot convert float infinity to integer`` (the
    period made nanoseconds), exit 1. Refused now above ``bag_export.MAX_MAP_PERIOD_S`` in the flag's name, exit 2,
    before any folder is made; the longest taken writes the first and the last map."""
    from cso_runtime.bag_export import MAX_MAP_PERIOD_S

    recording = tmp_path / "run.mcap"
    write_recording(recording, "r0", episode(RobotKeys("r0"), 3, T0_NS, 1000))
    cli = [sys.executable, "-m", "cso_runtime.cli", "export-bag", str(recording)]
    done = subprocess.run([*cli, "--map-period-s", "1e308"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--map-period-s must be at most 1e+09 s" in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert not (tmp_path / "run").exists()
    done = subprocess.run([*cli, "--map-period-s", f"{MAX_MAP_PERIOD_S:g}"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "/map 2" in done.stdout, (done.stdout, done.stderr)
