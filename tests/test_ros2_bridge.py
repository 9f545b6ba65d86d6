"""The ROS 2 bridge: a fake LIMO speaking ROS 2 CDR on zenoh-bridge-ros2dds keys, and our runtime.

The fake robot's CDR bytes are made by the rosbags typestore directly (message objects and
``serialize_cdr``), never by ``cso_runtime.ros2_cdr``'s encoders; what the bridge sends to the robot is
decoded with rosbags too. Loopback only, free ports, multicast scouting off, waits with deadlines,
everything stopped in ``finally`` blocks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from cso_runtime import ros2_cdr
from cso_runtime.config import ExplorationConfig
from cso_runtime.geometry import GridGeometry, Pose2D, VelocityCommand
from cso_runtime.keys import RobotKeys, robot_driver_token
from cso_runtime.messages import (
    ClockMsg,
    CmdVelMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    OdometryMsg,
    ScanMsg,
    ServiceStatusMsg,
    decode,
    encode,
)
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from robot_sim.fake_limo import odometry_cdr
from services.ros2_bridge import OdometryBuffer, Ros2BridgeParams
from tests.conftest import HANG_DEADLINE_S, wait_for

REPO = Path(__file__).resolve().parents[1]
PROFILES = REPO / "cso_runtime" / "profiles"



# --- the fake LIMO's bytes, made by rosbags ----------------------------------------------------------


def _t():
    return ros2_cdr.typestore().types


def _header(stamp_s: float, frame: str):
    t = _t()
    sec = math.floor(stamp_s)
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamp_s - sec) * 1e9)), frame_id=frame
    )


def ros_scan(
    stamp_s: float,
    ranges: np.ndarray,
    angle_min: float = -math.pi / 2,
    angle_max: float = math.pi / 2,
    n_angles: int | None = None,
) -> bytes:
    """A LaserScan like the LIMO's (front 180 degrees, 0.1-8 m); ``n_angles`` fakes a header/ranges mismatch."""
    n = len(ranges) if n_angles is None else n_angles
    msg = _t()["sensor_msgs/msg/LaserScan"](
        header=_header(stamp_s, "laser_link"),
        angle_min=angle_min,
        angle_max=angle_max,
        angle_increment=(angle_max - angle_min) / (n - 1),
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=8.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )
    return bytes(ros2_cdr.typestore().serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))


def ros_odom(stamp_s: float, x: float, y: float, yaw: float, v: float = 0.0, w: float = 0.0) -> bytes:
    """Odometry CDR built by rosbags (the fake LIMO's own builder, not our encoder)."""
    return odometry_cdr(stamp_s, Pose2D(x, y, yaw), v, w)


def rosbags_decode(raw: bytes, typename: str):
    return ros2_cdr.typestore().deserialize_cdr(raw, typename)


def test_fake_limo_odometry_has_the_limo_drivers_covariance():
    """The fake LIMO's odometry carries the pose covariance AgileX's driver publishes (diagonal
    ``ODOMETRY_COVARIANCE_DIAGONAL``, off-diagonal zero) and, like that driver, an all-zero twist covariance.
    Before, its pose covariance was all zero too, which no real LIMO sends."""
    odom = rosbags_decode(ros_odom(1000.5, 1.0, 2.0, 0.3, v=0.2, w=0.1), "nav_msgs/msg/Odometry")
    np.testing.assert_array_equal(np.asarray(odom.pose.covariance).reshape(6, 6), np.diag(ros2_cdr.ODOMETRY_COVARIANCE_DIAGONAL))
    np.testing.assert_array_equal(odom.twist.covariance, np.zeros(36))


def test_fake_limo_scans_say_their_period_as_a_lidar_driver_does():
    """sensor_msgs/LaserScan's ``scan_time`` is the time between scans (0.125 s for the 8 Hz LiDAR); the fake LIMO sent
    0, which ROS tools read as unknown. ``time_increment`` stays 0: the simulator casts every beam at one instant."""
    from cso_runtime.scene_generator import generate_floor_plan
    from robot_sim.fake_limo import FakeLimo
    from robot_sim.sim import MujocoSimulator

    class Recorder:
        def __init__(self) -> None:
            self.puts: list[bytes] = []

        def put(self, payload: bytes) -> None:
            self.puts.append(payload)

    class Session:
        def __init__(self) -> None:
            self.publishers: dict[str, Recorder] = {}

        def declare_publisher(self, key: str) -> Recorder:
            return self.publishers.setdefault(key, Recorder())

        def declare_subscriber(self, key: str, callback: object) -> None:
            return None

    session = Session()
    robot = FakeLimo(session, MujocoSimulator(generate_floor_plan("small", 0), seed=0))
    robot.sim.step(VelocityCommand(0.3, 0.0))
    robot.publish_due()
    scans = [rosbags_decode(raw, "sensor_msgs/msg/LaserScan") for raw in session.publishers["scan"].puts]
    assert len(scans) == 3 and all(s.scan_time == 0.125 and s.time_increment == 0.0 for s in scans)


# --- time matching --------------------------------------------------------------------------------


def _sample(t: float, x: float, yaw: float = 0.0) -> ros2_cdr.OdometrySample:
    return ros2_cdr.OdometrySample(Pose2D(x, 0.0, yaw), VelocityCommand(), t, "odom", "base_link")


def test_odometry_buffer_interpolates_and_names_every_miss():
    buf = OdometryBuffer(history_s=2.0, tolerance_s=0.05, max_gap_s=0.25, max_lag_s=0.5)
    assert buf.match(10.0) == (None, "no_odometry")
    assert buf.add(_sample(10.0, 0.0, 3.0)) and buf.add(_sample(10.2, 1.0, -3.0))
    assert not buf.add(_sample(10.1, 5.0)), "an older sample is refused"
    pose = buf.match(10.05)[0].pose
    assert pose.x_m == pytest.approx(0.25)
    assert abs(abs(pose.yaw_rad) - (3.0 + 0.25 * (2 * math.pi - 6.0))) < 1e-9, "yaw along the shorter arc through pi"
    assert buf.match(10.2)[0].pose.x_m == 1.0
    assert buf.match(10.23)[0].pose.x_m == 1.0, "nearest within the tolerance"
    assert buf.match(10.3) == (None, "waiting")
    assert buf.add(_sample(11.0, 2.0))
    assert buf.match(10.6) == (None, "gap"), "0.8 s between samples: no interpolation, nothing near"
    assert buf.match(10.4) == (None, "stale"), "more than 0.5 s behind the newest odometry"
    assert buf.add(_sample(13.5, 3.0)) and len(buf.samples) == 1, "history is trimmed"


def test_params_validate_names_and_build_keys():
    from cso_runtime.config import ConfigError, from_dict

    p = from_dict(Ros2BridgeParams, {"namespace": "/limo1/"})
    assert p.ros_key("scan") == "limo1/scan" and p.ros_key("explore/frontiers") == "limo1/explore/frontiers"
    assert from_dict(Ros2BridgeParams, {}).ros_key("cmd_vel") == "cmd_vel"
    with pytest.raises(ConfigError):
        from_dict(Ros2BridgeParams, {"namespace": "bad ns"})
    with pytest.raises(ConfigError):
        from_dict(Ros2BridgeParams, {"cmd_timeout_s": 0})


def test_hardware_md_names_every_bridge_parameter_with_its_default():
    """docs/hardware.md lists the bridge's parameters for those who tune it on the robot; the topic names (to move
    ``map`` and ``goal_pose`` aside from Nav2's, as it advises), ``odom_history_s`` and ``log_period_s`` were missing,
    so a user read the profile's few keys as all there is. Every ``Ros2BridgeParams`` field is named, and a default
    quoted beside one (`name` (value)) is the default."""
    doc = (REPO / "docs" / "hardware.md").read_text(encoding="utf-8")
    fields = {f.name: f.default for f in dataclasses.fields(Ros2BridgeParams)}
    assert [name for name in fields if f"`{name}`" not in doc] == []
    quoted = re.findall(r"`(" + "|".join(fields) + r")` \(`?([\w./-]+)`?[,:;)]", doc)
    assert len(quoted) >= 20, quoted
    is_default = lambda name, text: str(fields[name]) in (text, text.capitalize()) or (re.fullmatch(r"[\d.]+", text) and float(text) == fields[name])  # noqa: E731
    assert [(name, text) for name, text in quoted if not is_default(name, text)] == []


@pytest.mark.parametrize("stamped", [False, True])
def test_fake_limo_drives_on_the_command_type_it_is_told(stamped: bool):
    """``--cmd-vel-stamped``: the fake LIMO takes TwistStamped on ``cmd_vel``, as ROS 2 Jazzy's diff_drive_controller, so
    that a run with ``cmd_vel_stamped`` can be tried without a robot; the other type is undecodable, counted, not driven
    (before, it took Twist only: a run with ``cmd_vel_stamped`` never drove it)."""
    from types import SimpleNamespace

    from robot_sim.fake_limo import FakeLimo

    session = SimpleNamespace(declare_publisher=lambda key: None, declare_subscriber=lambda key, callback: None)
    driven: list[VelocityCommand] = []
    sim = SimpleNamespace(set_command=lambda cmd: driven.append(cmd) or True)
    robot = FakeLimo(session, sim, cmd_vel_stamped=stamped)  # type: ignore[arg-type]
    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731
    right, wrong = ros2_cdr.twist_to_cdr(VelocityCommand(0.3, -0.2)), ros2_cdr.twist_stamped_to_cdr(VelocityCommand(0.1, 0.1), 5, "base_link")
    if stamped:
        right, wrong = wrong, right
    robot._on_twist(sample(right))
    robot._on_twist(sample(wrong))
    assert driven == [VelocityCommand(0.1, 0.1) if stamped else VelocityCommand(0.3, -0.2)]
    assert (robot.commands, robot.bad_commands) == (1, 1)
    nan = VelocityCommand(float("nan"), 0.0)  # decoded by ros2_cdr, as the bridge does: non-finite is undecodable
    robot._on_twist(sample(ros2_cdr.twist_stamped_to_cdr(nan, 5, "base_link") if stamped else ros2_cdr.twist_to_cdr(nan)))
    assert len(driven) == 1 and (robot.commands, robot.bad_commands) == (1, 2)


def test_fake_limo_refuses_a_namespace_that_is_no_ros_name(capsys):
    """``python -m robot_sim.fake_limo --namespace 'a*b'`` loaded its scene, then died with a Zenoh traceback
    (``Invalid Key Expr a*b/odom``); it is now a usage error (exit 2) naming the flag, as the bridge's own check."""
    from robot_sim import fake_limo

    with pytest.raises(SystemExit) as exit_info:
        fake_limo.main(["--listen", "tcp/127.0.0.1:1", "--namespace", "a*b"])
    assert exit_info.value.code == 2 and "--namespace 'a*b' is not a ROS name" in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--speed", "--odom-rate-hz"])
def test_fake_limo_refuses_an_infinite_rate(capsys, flag):
    """``--speed inf`` passed the flag check, loaded the scene and opened the router, then died in the real-time pacer
    (a ValueError traceback): a usage error (exit 2) like a zero or negative one."""
    from robot_sim import fake_limo

    with pytest.raises(SystemExit) as exit_info:
        fake_limo.main(["--listen", "tcp/127.0.0.1:1", flag, "inf"])
    assert exit_info.value.code == 2 and "must be positive and finite" in capsys.readouterr().err


class _SimulatorBuilt(Exception):
    """Raised by a stand-in for ``MujocoSimulator``: the fake LIMO got as far as building its simulator."""


@pytest.mark.parametrize(("flags", "mount_x_m"), [([], 0.103), (["--lidar-mount-x-m", "0.05"], 0.05)])
def test_fake_limo_casts_its_rays_from_the_mount_its_flag_gives(monkeypatch, flags, mount_x_m):
    """The fake LIMO's LiDAR sat at the LIMO's 0.103 m with no flag, so a run with another
    ``exploration.sensor.mount_x_m`` could not be tried against it; ``--lidar-mount-x-m`` gives it (the LIMO's by default,
    as the limo-ros2 profile's), and one off the robot, or not finite, is a usage error (exit 2)."""
    from robot_sim import fake_limo

    built: list = []

    def simulator(plan, sensor, robot, seed):
        built.append(sensor)
        raise _SimulatorBuilt

    monkeypatch.setattr(fake_limo, "MujocoSimulator", simulator)
    with pytest.raises(_SimulatorBuilt):
        fake_limo.main(["--listen", "tcp/127.0.0.1:1", *flags])
    assert [sensor.mount_x_m for sensor in built] == [mount_x_m]


@pytest.mark.parametrize("mount", ["0.5", "nan"])
def test_fake_limo_refuses_a_lidar_mount_off_the_robot(capsys, mount):
    from robot_sim import fake_limo

    with pytest.raises(SystemExit) as exit_info:
        fake_limo.main(["--listen", "tcp/127.0.0.1:1", "--lidar-mount-x-m", mount])
    assert exit_info.value.code == 2 and f"--lidar-mount-x-m {mount}: " in capsys.readouterr().err


def _bridge_without_zenoh(params: dict | None = None, services: dict | None = None):
    """The bridge service with its ROS callbacks fed by hand: what it publishes is collected, no session. ``services``:
    the profile's (none: a bridge started on its own, with no frontier service to wait for)."""
    from types import SimpleNamespace

    from cso_runtime.transport import TransportConfig as _TC
    from services.common import ServiceContext
    from services.ros2_bridge import Ros2BridgeService

    profile = {"method": "greedy-dist", **({"services": services} if services is not None else {})}
    ctx = ServiceContext("ros2_bridge", "r0", profile, ExplorationConfig(), _TC(connect=["tcp/127.0.0.1:1"]), params or {})
    svc = Ros2BridgeService(ctx)
    out: list[tuple[str, Any]] = []
    svc.publish = lambda topic, msg, robot=None: out.append((topic, decode(encode(svc.check_output(topic, msg)), type(msg))))  # type: ignore[method-assign]
    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731

    def step(t: float, x: float, y: float = 0.0, yaw: float = 0.0) -> None:
        """The robot's odometry and a scan at the same stamp, as limo_base and the LiDAR send them."""
        svc._on_ros_odom(sample(ros_odom(t, x, y, yaw)))
        svc._on_ros_scan(sample(ros_scan(t, np.full(181, 2.0, np.float32))))

    return svc, out, step


def test_the_bridges_episode_status_carries_the_robots_last_odometry_and_none_before_its_first_scan():
    """``status`` shows where the robot is from the episode status: on a real robot, the odometry the bridge matched to
    its newest scan (the ``odom`` of that step, pose and twist); none before the first scan, and none again in a new
    episode until its first scan."""
    from types import SimpleNamespace

    svc, out, _ = _bridge_without_zenoh()
    assert (svc.episode_status().pose, svc.episode_status().twist) == (None, None)
    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731
    for i in range(3):
        svc._on_ros_odom(sample(ros_odom(1000.0 + 0.1 * i, 0.5 + 0.02 * i, -0.25, 0.3, v=0.2, w=-0.1)))
        svc._on_ros_scan(sample(ros_scan(1000.0 + 0.1 * i, np.full(181, 2.0, np.float32))))
    (last,) = [m for topic, m in out if topic == "odom" and m.step == svc.step]
    status = decode(encode(svc.episode_status()), EpisodeStatusMsg)
    assert status.step == last.step == 2 and status.pose == last.pose and status.twist == last.twist
    assert status.pose is not None and status.pose.as_list() == pytest.approx([0.54, -0.25, 0.3]) and status.twist == VelocityCommand(0.2, -0.1)
    svc._new_episode("test", "clock_jumps_back")
    assert (svc.episode_status().pose, svc.episode_status().twist) == (None, None)


def test_a_robot_clock_that_starts_again_starts_a_new_episode_instead_of_dropping_everything():
    """limo_base restarted (or a bag played again with use_sim_time): stamps go back by minutes. Every later
    sample used to be dropped as out of order until the new clock passed the old one: the robot stood still
    with nothing in the log but drop counts. Now, as tf2 clears its buffer on a jump back in time, the bridge
    starts a new episode on the new clock and goes on; a small step back is still only out of order."""
    svc, out, step = _bridge_without_zenoh()
    for i in range(5):
        step(1000.0 + 0.1 * i, 0.01 * i)
    first = svc.episode
    assert svc.step == 4
    step(1000.35, 0.04)  # 50 ms back: out of order, dropped and counted
    assert svc.rejected == {"ros_odom:out_of_order": 1, "ros_scan:out_of_order": 1} and svc.episode == first
    for i in range(10):
        step(100.0 + 0.1 * i, 0.0)
    assert svc.episode != first, "a new episode on the new clock"
    assert svc.step == 9 and svc.counters["clock_jumps_back"] == 1
    assert svc.rejected == {"ros_odom:out_of_order": 1, "ros_scan:out_of_order": 1}, "nothing else dropped"
    scans = [m for topic, m in out if topic == "scan" and m.episode == svc.episode]
    clocks = [m for topic, m in out if topic == "clock" and m.episode == svc.episode]
    assert [m.step for m in scans] == list(range(10)) and clocks[0].step == 0 and clocks[0].arena is not None
    assert scans[0].scan.stamp_s == pytest.approx(100.0)
    assert svc.episode_status().state == "exploring" and svc.path_length_m == 0.0


def test_odometry_that_jumps_is_dropped_and_a_lasting_jump_starts_a_new_episode():
    """Odometry that moves faster than the robot can drive is not integrated (it smeared the map and added metres
    to the path): a one-sample glitch is dropped and counted, and odometry that goes on from a jump for
    ``odom_jump_confirm_s`` (limo_base restarted: odometry back at its origin) starts a new episode from there."""
    svc, out, step = _bridge_without_zenoh({"odom_jump_confirm_s": 1.0})
    for i in range(5):
        step(1000.0 + 0.1 * i, 5.0 + 0.05 * i)
    first = svc.episode
    step(1000.5, 9.0)  # 3.8 m in 0.1 s: a glitch
    step(1000.6, 5.3)  # back where it was
    assert svc.rejected.get("ros_odom:jump") == 1 and svc.episode == first
    assert svc.path_length_m == pytest.approx(0.3) and svc.step == 6, "the glitch's scan is placed between the good samples around it"
    assert all(m.pose.x_m < 5.5 for topic, m in out if topic == "odom")
    for i in range(12):  # odometry reset to its origin, and going on from there
        step(1000.7 + 0.1 * i, 0.02 * i)
    assert svc.episode != first and svc.counters["odometry_resets"] == 1
    assert svc.rejected.get("ros_odom:jump") == 1 + 10, "dropped until the jump had lasted 1 s"
    new = [m for topic, m in out if topic == "odom" and m.episode == svc.episode]
    assert new and new[0].step == 0 and new[-1].pose.x_m == pytest.approx(0.22)
    assert svc.path_length_m == pytest.approx(0.22 - new[0].pose.x_m)


def test_a_glitch_that_good_odometry_could_go_on_from_too_drops_one_sample_not_a_second_and_the_map():
    """A glitch 10 ms after a good sample, and the next good sample within the robot's reach of both: that sample went
    on from the glitch (the jump was checked first), and so did every later one: a second of odometry dropped, its
    scans unmatched, and a new episode (a new map) though odometry never reset. Good odometry goes on from the
    samples it strains less (``OdometryBuffer.strain``): the glitch alone is dropped."""
    svc, _out, step = _bridge_without_zenoh({"odom_jump_confirm_s": 1.0})
    for i in range(5):
        step(1000.0 + 0.1 * i, 5.0 + 0.05 * i)  # 0.5 m/s; the robot's top speed is 1 m/s
    first = svc.episode
    step(1000.41, 5.75)  # 0.55 m in 10 ms: a glitch
    for i in range(15):
        step(1000.5 + 0.1 * i, 5.25 + 0.05 * i)  # driving on as before
    assert svc.episode == first and svc.counters["odometry_resets"] == 0
    assert svc.rejected == {"ros_odom:jump": 1}
    assert svc.step == 5 + 1 + 15 - 1 and svc.path_length_m == pytest.approx(0.05 * 19)


def test_a_frame_that_tf2_refuses_is_a_config_error_and_odometry_in_another_frame_is_warned_of(caplog):
    """``map_frame_id: /odom`` (a ROS 1 habit) was taken as it is: every map, goal and frontiers went out in a frame
    that tf2 in ROS 2 refuses ("frame_ids cannot start with a '/'"), and RViz showed nothing. And odometry in another
    frame than ``map_frame_id`` (``limo1/odom`` in a multi-robot TF tree) put the map, which is built in the odometry's
    frame, in the wrong one without a word. The first is now a ConfigError; the second is warned of once and counted."""
    from cso_runtime.config import ConfigError, from_dict

    for bad in ("/odom", "", "my odom"):
        with pytest.raises(ConfigError, match="map_frame_id"):
            from_dict(Ros2BridgeParams, {"map_frame_id": bad})
    assert from_dict(Ros2BridgeParams, {"map_frame_id": "limo1/odom"}).map_frame_id == "limo1/odom"

    from types import SimpleNamespace

    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731

    def odom_in(frame: str, t: float) -> bytes:
        msg = rosbags_decode(ros_odom(t, 0.0, 0.0, 0.0), "nav_msgs/msg/Odometry")
        msg = dataclasses.replace(msg, header=dataclasses.replace(msg.header, frame_id=frame))
        return bytes(ros2_cdr.typestore().serialize_cdr(msg, "nav_msgs/msg/Odometry"))

    svc, _, _ = _bridge_without_zenoh({"namespace": "limo1"})
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        for i in range(3):
            svc._on_ros_odom(sample(odom_in("limo1/odom", 1000.0 + 0.1 * i)))
    assert svc.counters["odom_in_another_frame"] == 3 and svc.counters["received:odom"] == 3
    assert caplog.text.count("odometry is in frame 'limo1/odom'") == 1 and "map_frame_id" in caplog.text, caplog.text
    assert len(svc.odometry.samples) == 3, "the odometry is used all the same"
    caplog.clear()
    svc, _, _ = _bridge_without_zenoh({"namespace": "limo1", "map_frame_id": "limo1/odom"})
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        svc._on_ros_odom(sample(odom_in("limo1/odom", 1000.0)))
        svc._on_ros_odom(sample(odom_in("", 1000.1)))  # a driver that leaves it empty says nothing to check against
    assert svc.counters["odom_in_another_frame"] == 0 and "frame" not in caplog.text

    # With TwistStamped commands, their frame_id (base_frame_id) against the odometry's child_frame_id (base_link).
    def odom_of(child: str, t: float) -> bytes:
        msg = rosbags_decode(ros_odom(t, 0.0, 0.0, 0.0), "nav_msgs/msg/Odometry")
        return bytes(ros2_cdr.typestore().serialize_cdr(dataclasses.replace(msg, child_frame_id=child), "nav_msgs/msg/Odometry"))

    for stamped, expected in ((True, 2), (False, 0)):
        caplog.clear()
        svc, _, _ = _bridge_without_zenoh({"cmd_vel_stamped": stamped})
        with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
            svc._on_ros_odom(sample(odom_of("limo1/base_link", 1000.0)))
            svc._on_ros_odom(sample(odom_of("limo1/base_link", 1000.1)))
            svc._on_ros_odom(sample(odom_of("", 1000.2)))  # empty: nothing to check against
        assert svc.counters["base_in_another_frame"] == expected, stamped
        assert caplog.text.count("base_frame_id: limo1/base_link") == (1 if stamped else 0), caplog.text
    svc, _, _ = _bridge_without_zenoh({"cmd_vel_stamped": True})
    svc._on_ros_odom(sample(odom_of("base_link", 1000.0)))
    assert svc.counters["base_in_another_frame"] == 0


def test_a_scan_wider_or_narrower_than_the_configured_sensor_is_warned_of(caplog):
    """The policy (its weights are chosen by the field of view) and the planner (the turn to a goal out of view, the
    no_frontier reason) take the LiDAR's field of view from ``exploration.sensor.fov_deg`` (the LIMO's 180 degrees),
    never from the robot's LaserScan: a LiDAR that sees all around (or a narrower one) was mapped as it is while both
    went on with 180 degrees, without a word. The first scan that disagrees is now warned of, and each is counted."""
    from types import SimpleNamespace

    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731
    svc, _, _ = _bridge_without_zenoh()
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        svc._on_ros_scan(sample(ros_scan(1000.0, np.full(181, 2.0, np.float32))))  # the LIMO's: front 180 degrees
        assert svc.counters["scan_fov_mismatch"] == 0 and caplog.text == ""
        ring = np.full(360, 2.0, np.float32)
        for i in range(2):
            svc._on_ros_scan(sample(ros_scan(1000.1 + 0.1 * i, ring, -math.pi, math.pi - 2 * math.pi / 360)))
    assert svc.counters["scan_fov_mismatch"] == 2
    assert caplog.text.count("covers 360 degrees") == 1 and "exploration.sensor.fov_deg is 180" in caplog.text, caplog.text


def test_after_the_episode_ended_the_robot_is_held_still():
    """A real robot's scans go on after its episode ends (and a detached run stays up, for ``save-map``): the frontier
    service and the policy go on deciding on each scan, and a frontier that opens later (a door, a person moving, drift)
    gave the planner a goal that the bridge drove the robot to, while ``status`` said ``done``. As explore_lite stops
    once exploration is over, the bridge now sends a zero Twist for every command once the episode is over (counted as
    ``commands_after_episode``, warned of once), and one at the end itself; a new episode (a restarted robot clock)
    drives again."""
    svc, _, step = _bridge_without_zenoh()
    sent: list[tuple[str, bytes]] = []
    svc._put_ros = lambda topic, payload: sent.append((topic, payload))  # type: ignore[method-assign]
    step(1000.0, 0.0)
    twists = lambda: [ros2_cdr.twist_from_cdr(raw) for topic, raw in sent if topic == "cmd_vel"]  # noqa: E731
    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.3, 0.2)), 50.0)
    assert twists() == [VelocityCommand(0.3, 0.2)]
    svc.take_goal(GoalMsg(1, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    assert svc.episode_status().state == "done"
    assert twists()[1:] == [VelocityCommand()]  # a stop at the end itself, not cmd_timeout_s later from the watchdog
    svc.on_message("r0", "cmd_vel", CmdVelMsg(5, VelocityCommand(0.4, -0.1)), 50.1)
    svc.on_message("r0", "cmd_vel", CmdVelMsg(6, VelocityCommand(0.4, -0.1)), 50.2)
    assert twists()[1:] == [VelocityCommand()] * 3 and svc.counters["commands_after_episode"] == 2
    for i in range(3):  # the robot's clock starts again: a new episode
        step(100.0 + 0.1 * i, 0.0)
    svc.on_message("r0", "cmd_vel", CmdVelMsg(1, VelocityCommand(0.2, 0.0)), 50.3)
    assert twists()[-1] == VelocityCommand(0.2, 0.0)


def test_the_bridge_drives_on_each_cmd_vel_and_keeps_the_planners_state_and_plan_it_carries_as_they_came():
    """On a robot the ros2_bridge is the referee: the planner's state (every command) and plan (when it changed) ride on its
    ``cmd_vel``, and the bridge serves them unread, byte for byte, on ``cache/planner/state`` and ``cache/planner/plan``
    (the newest of its episode; a plan until a newer one). A command of another episode still drives the robot, as
    before it carried an id, but what it carries is rejected and counted; a planner of one's own carries nothing."""
    from types import SimpleNamespace

    svc, _, step = _bridge_without_zenoh()
    sent: list[tuple[str, bytes]] = []
    svc._put_ros = lambda topic, payload: sent.append((topic, payload))  # type: ignore[method-assign]
    step(1000.0, 0.0)

    def served(topic: str) -> bytes | str:
        replies: list[tuple[str, bytes]] = []
        svc.answer_cache_query(topic, SimpleNamespace(reply=lambda key, payload: replies.append((key, payload)), reply_err=lambda payload: replies.append(("error", payload))))
        ((key, payload),) = replies
        return payload.decode() if key == "error" else payload

    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.3, 0.2)), 50.0)  # a planner of one's own
    assert served("planner_state") == "no planner_state yet" and served("planner_plan") == "no planner_plan yet"
    state_1, state_2, plan_1 = b"state of step 1", b"state of step 2", b"plan of step 1"  # opaque: never decoded here
    svc.on_message("r0", "cmd_vel", CmdVelMsg(1, VelocityCommand(0.2, 0.0), episode=svc.episode, planner_state=state_1, planner_plan=plan_1), 50.1)
    svc.on_message("r0", "cmd_vel", CmdVelMsg(2, VelocityCommand(0.2, 0.1), episode=svc.episode, planner_state=state_2), 50.2)
    svc.on_message("r0", "cmd_vel", CmdVelMsg(3, VelocityCommand(0.1, 0.0), episode=svc.episode + 1, planner_state=b"late", planner_plan=b"late"), 50.3)
    assert (served("planner_state"), served("planner_plan")) == (state_2, plan_1) and svc.rejected == {"planner_state": 1}
    assert [ros2_cdr.twist_from_cdr(raw) for topic, raw in sent if topic == "cmd_vel"][-3:] == [VelocityCommand(0.2, 0.0), VelocityCommand(0.2, 0.1), VelocityCommand(0.1, 0.0)]


def test_cmd_vel_stamped_sends_twist_stamped_in_the_robots_clock_every_command_and_every_stop():
    """ROS 2 Jazzy's diff_drive_controller takes only geometry_msgs/TwistStamped on its ``cmd_vel``, and Nav2 Kilted
    sends TwistStamped by default: the bridge sent Twist only, which such a robot never hears. With ``cmd_vel_stamped``
    every command is a TwistStamped in ``base_frame_id``, stamped in the robot's clock when it is sent (the newest scan's
    stamp plus the time since it came, as Nav2 stamps its own when it sends them): the commands, the watchdog's zero,
    the zero at the episode's end and after it. Before any scan the stamp is 0 (diff_drive_controller's own now).
    Without the parameter the bytes are the Twist they were."""
    plain, _, plain_step = _bridge_without_zenoh()
    plain_sent: list[tuple[str, bytes]] = []
    plain._put_ros = lambda topic, payload: plain_sent.append((topic, payload))  # type: ignore[method-assign]
    plain_step(1000.0, 0.0)
    plain.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.3, 0.2)), 50.0)
    assert plain_sent == [("cmd_vel", ros2_cdr.twist_to_cdr(VelocityCommand(0.3, 0.2)))]

    svc, _, step = _bridge_without_zenoh({"cmd_vel_stamped": True, "base_frame_id": "limo1/base_link"})
    sent: list[tuple[str, bytes]] = []
    svc._put_ros = lambda topic, payload: sent.append((topic, payload))  # type: ignore[method-assign]

    def commands() -> list[tuple[VelocityCommand, int]]:
        """What went to cmd_vel, decoded by rosbags: (linear.x, angular.z) and the stamp (ns); the frame checked."""
        out = []
        for topic, raw in sent:
            assert topic == "cmd_vel"
            msg = rosbags_decode(raw, "geometry_msgs/msg/TwistStamped")
            assert msg.header.frame_id == "limo1/base_link"
            assert (msg.twist.linear.y, msg.twist.linear.z, msg.twist.angular.x, msg.twist.angular.y) == (0.0,) * 4
            out.append((VelocityCommand(msg.twist.linear.x, msg.twist.angular.z), ros2_cdr.header_stamp_ns(msg.header)))
        return out

    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.1, 0.0)), 10.0)  # no scan yet: the robot's time unknown
    assert commands() == [(VelocityCommand(0.1, 0.0), 0)]
    step(1000.0, 0.0)
    scan_ns = 1000 * 1_000_000_000
    came_s = svc.robot_clock[1]
    assert svc.robot_clock == (scan_ns, came_s)
    sent.clear()
    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.3, 0.2)), came_s + 0.25)
    assert commands() == [(VelocityCommand(0.3, 0.2), scan_ns + 250_000_000)]
    svc.on_tick(came_s + 0.25 + svc.params.cmd_timeout_s + 0.1)  # no command for cmd_timeout_s: the watchdog's zero
    assert commands()[1:] == [(VelocityCommand(), scan_ns + 850_000_000)] and svc.counters["watchdog_stops"] == 1
    svc.on_message("r0", "cmd_vel", CmdVelMsg(0, VelocityCommand(0.2, 0.0)), came_s + 1.0)
    svc.take_goal(GoalMsg(1, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    svc.on_message("r0", "cmd_vel", CmdVelMsg(1, VelocityCommand(0.4, -0.1)), came_s + 1.5)
    (_, go_ns), (end, end_ns), (after, after_ns) = commands()[2:]
    assert go_ns == scan_ns + 1_000_000_000
    assert end == after == VelocityCommand() and svc.counters["commands_after_episode"] == 1
    assert end_ns >= scan_ns and after_ns == scan_ns + 1_500_000_000  # the end's zero: stamped when it went out
    key, zero = svc.params.stop_command(svc.robot_time_ns(came_s + 2.0))  # what shutdown sends last
    assert key == "cmd_vel" and ros2_cdr.twist_stamped_from_cdr(zero) == (VelocityCommand(), scan_ns + 2_000_000_000, "limo1/base_link")


def test_the_launchers_stop_for_a_dead_bridge_is_the_bridges_command_type():
    """The launcher sends the zero command for a bridge that died (``robot_stop_commands``), made before the robot sent
    any time: a Twist by default, and with ``cmd_vel_stamped`` a TwistStamped stamped 0, which diff_drive_controller
    takes as its own now (a Twist would never reach a Jazzy diff_drive_controller, and the robot would drive on)."""
    from cso_runtime.launcher import robot_stop_commands
    from cso_runtime.run_profile import load_profile

    def stop_of(settings: dict) -> tuple[str, bytes]:
        profile, _ = load_profile("limo-ros2", connect=["tcp/127.0.0.1:1"], namespace="limo1", settings=settings)
        return robot_stop_commands(profile)["ros2_bridge"]

    assert stop_of({}) == ("limo1/cmd_vel", ros2_cdr.twist_to_cdr(VelocityCommand()))
    key, raw = stop_of({"services.ros2_bridge.cmd_vel_stamped": True})
    msg = rosbags_decode(raw, "geometry_msgs/msg/TwistStamped")
    assert key == "limo1/cmd_vel" and (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (0, 0, "base_link")
    assert (msg.twist.linear.x, msg.twist.angular.z) == (0.0, 0.0)


def test_after_the_episode_ended_a_decision_is_not_shown_and_its_asker_hears_the_end():
    """Once the episode is over the frontier service asks for no decision (``steps_after_episode``), but one that did
    not hear the end (restarted since: the bridge says its status only while exploring and at the end) decides again,
    at once and whenever its goal is reached, blocked or due, and each decision's frontiers went to RViz over the
    robot's WiFi. The bridge now sends no frontiers after the end (``decisions_after_episode``) and says its status
    again, which that frontier service ends on."""
    from services.common import ServiceContext
    from services.frontier import FrontierService

    svc, out, step = _bridge_without_zenoh()
    sent: list[str] = []
    svc._put_ros = lambda topic, payload: sent.append(topic)  # type: ignore[method-assign]
    step(1000.0, 0.0)
    svc.on_message("r0", "frontiers", dataclasses.replace(_frontiers_msg(1), episode=svc.episode), 0.0)
    assert sent == ["explore/frontiers"]
    svc.take_goal(GoalMsg(1, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    out.clear()
    svc.on_message("r0", "frontiers", dataclasses.replace(_frontiers_msg(2), episode=svc.episode), 0.0)
    assert sent == ["explore/frontiers"] and svc.counters["decisions_after_episode"] == 1
    (status,) = [m for topic, m in out if topic == "episode_status"]
    assert status.state == "done" and status.terminated_by == "no_frontier" and status.episode == svc.episode

    ctx = ServiceContext("frontier", "r0", {"lockstep": False}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    frontier = FrontierService(ctx)
    frontier.on_message("r0", "episode_status", decode(encode(status), EpisodeStatusMsg), 0.0)
    assert frontier.episode_over == "done (no_frontier)"


def test_after_the_episode_ended_a_goal_is_not_shown_nor_counted_as_a_decision():
    """A frontier service that did not hear the end (restarted since) asks once more, and the policy answers with a
    goal: the bridge held the robot still and sent no frontiers, but it sent that goal to RViz (``goal_pose``, a goal
    the robot never drives to) and counted it among the episode's decisions, so that ``status`` went on counting
    decisions of an episode that had ended. A goal after the end is now neither shown nor counted
    (``goals_after_episode``); a new episode's goals are, as before."""
    svc, _, step = _bridge_without_zenoh()
    sent: list[str] = []
    svc._put_ros = lambda topic, payload: sent.append(topic)  # type: ignore[method-assign]
    step(1000.0, 0.0)
    svc.take_goal(GoalMsg(1, True, 0.5, 0.2, 0, 1.0, method="greedy-dist", episode=svc.episode))
    assert sent == ["goal_pose"] and svc.decisions == 1
    svc.take_goal(GoalMsg(2, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    assert svc.episode_status().state == "done" and svc.decisions == 2
    svc.on_message("r0", "goal", GoalMsg(9, True, 1.5, -0.4, 0, 2.0, method="greedy-dist", episode=svc.episode), 0.0)
    assert sent == ["goal_pose"], "no goal goes to RViz after the end"
    assert svc.decisions == 2 and svc.episode_status().decisions == 2 and svc.counters["goals_after_episode"] == 1
    for i in range(3):  # the robot's clock starts again: a new episode
        step(100.0 + 0.1 * i, 0.0)
    svc.take_goal(GoalMsg(1, True, 1.5, -0.4, 0, 2.0, method="greedy-dist", episode=svc.episode))
    assert sent == ["goal_pose", "goal_pose"] and svc.decisions == 1


def test_explore_resume_from_ros_pauses_and_resumes_exploration():
    """``ros2 topic pub --once /limo1/explore/resume std_msgs/msg/Bool "{data: false}"`` (explore_lite's): the bridge
    sends it on ``cso/<robot>/explore/resume``, saying where it came from; a payload that is no Bool is counted."""
    from types import SimpleNamespace

    svc, out, _ = _bridge_without_zenoh({"namespace": "limo1"})
    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731
    svc._on_ros_resume(sample(ros2_cdr.bool_to_cdr(False)))
    svc._on_ros_resume(sample(ros2_cdr.bool_to_cdr(True)))
    svc._on_ros_resume(sample(b"\x00\x01"))
    msgs = [m for t, m in out if t == "explore_resume"]
    assert [(m.resume, m.by) for m in msgs] == [(False, "ros2 limo1/explore/resume"), (True, "ros2 limo1/explore/resume")]
    assert msgs[0].stamp_s > 0
    assert svc.counters["received:resume"] == 3 and svc.counters["dropped:ros_resume:bad_cdr"] == 1


def test_maps_go_to_ros_at_most_every_map_period_s_and_the_newest_always_goes_out():
    """The mapper makes a map per scan (10 Hz, a few hundred kB each): every one was sent to the robot's
    router as an OccupancyGrid. Now at most one per ``map_period_s``, and the newest once nothing newer comes."""
    svc, _, step = _bridge_without_zenoh({"map_period_s": 0.5})
    sent: list[tuple[str, bytes]] = []
    svc._put_ros = lambda topic, payload: sent.append((topic, payload))  # type: ignore[method-assign]
    for i in range(6):
        step(1000.0 + 0.1 * i, 0.01 * i)
    geom = GridGeometry(0.1, (6, 8), -1.0, -2.0)
    t0 = 50.0
    for k in range(6):  # six maps in 0.25 s
        grid = np.full(geom.shape, -1, np.int8)
        grid[0, : k + 1] = 0
        svc.on_message("r0", "map", MapMsg.from_grid(k, geom, grid, svc.episode), t0 + 0.05 * k)
    assert [t for t, _ in sent] == ["map"], "only the first of the burst"
    svc.on_tick(t0 + 0.3)
    assert len(sent) == 1, "not before map_period_s"
    svc.on_tick(t0 + 0.55)
    assert len(sent) == 2
    og = rosbags_decode(sent[1][1], "nav_msgs/msg/OccupancyGrid")
    assert (np.asarray(og.data).reshape(geom.shape)[0] == 0).sum() == 6, "the newest map"
    assert og.header.stamp.sec == 1000 and abs(og.header.stamp.nanosec - 500_000_000) < 1000, "stamped with its step's scan"
    svc.on_tick(t0 + 2.0)
    assert len(sent) == 2, "each map once"
    assert svc.latest["map"].step == 5, "the referee keeps every map all the same (save-map, a restarted mapper)"


def test_a_map_that_reaches_the_arenas_edge_is_said_in_status_and_the_log(caplog):
    """The bridge maps a fixed arena (20 x 20 m around the first pose). On the fake LIMO in a scene larger than the
    arena, the episode ended ``done (no_frontier)`` with the rooms beyond the arena's edge unexplored and nothing in
    ``status`` or the logs to say why. A map with open cells on the arena's edge (beams went on past it) is now
    warned of once, counted (``arena_edge_reached``) and named in the episode status's ``reason``, also at its end."""
    svc, out, step = _bridge_without_zenoh({"resolution_m": 0.1, "arena_width_m": 2.0, "arena_height_m": 2.0})
    svc._put_ros = lambda topic, payload: None  # type: ignore[method-assign]  # what goes to ROS is not looked at here
    step(1000.0, 0.0)
    geom = svc.arena
    assert geom is not None and geom.shape == (20, 20)
    inside = np.full(geom.shape, -1, np.int8)
    inside[5:15, 5:15] = 0
    inside[4, 4:16] = 100  # a room inside the arena, walled or not: nothing on the edge
    svc.on_message("r0", "map", MapMsg.from_grid(0, geom, inside, svc.episode), 50.0)
    assert svc.episode_status().reason == "" and svc.counters["arena_edge_reached"] == 0
    walls = inside.copy()
    walls[0, :] = 100  # a wall on the edge is no open space beyond it
    svc.on_message("r0", "map", MapMsg.from_grid(0, geom, walls, svc.episode), 50.1)
    assert svc.episode_status().reason == ""
    step(1000.1, 0.0)
    reaching = inside.copy()
    reaching[10, 5:] = 0  # free up to the last column: the beam went on past it
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        svc.on_message("r0", "map", MapMsg.from_grid(1, geom, reaching, svc.episode), 50.2)
        svc.on_message("r0", "map", MapMsg.from_grid(1, geom, reaching, svc.episode), 50.3)
    reason = svc.episode_status().reason
    assert "the map reached the edge of its 2.0 x 2.0 m arena at step 1" in reason and "arena_width_m" in reason, reason
    assert svc.counters["arena_edge_reached"] == 1 and caplog.text.count("reached the edge") == 1, caplog.text
    svc.take_goal(GoalMsg(2, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    final = [m for topic, m in out if topic == "episode_status"][-1]
    assert final.state == "done" and final.terminated_by == "no_frontier" and final.reason == reason
    assert "the episode ends (no_frontier), but the map reached the edge" in caplog.text


def test_an_episode_that_ends_no_frontier_on_a_real_robot_says_why_as_in_the_sim():
    """On a real robot the bridge is the referee: on an empty goal it ended the episode at once, and the frontier
    service's reason (``frontiers/ended_why``) reached nobody: the result's ``ended_why`` and the status's ``reason``
    were empty, so the launcher's line, ``summary.json``, ``episodes.csv`` and ``status`` said "no_frontier" alone,
    where the sim profile says why. The bridge now waits for it as the sim does (``ended_why_wait_s``), heard before
    or after the goal; without it the episode ends after that wait, and at once where no frontier service runs."""
    from cso_runtime.messages import EndedWhyMsg

    pipeline = {"ros2_bridge": {}, "mapper": {}, "frontier": {}, "policy": {}, "planner": {}}
    why = "no frontier left: 3 frontier cells, all given up around goals reached"

    def ended(out: list) -> tuple[EpisodeStatusMsg, EpisodeResultMsg]:
        statuses = [m for topic, m in out if topic == "episode_status"]
        (result,) = [m for topic, m in out if topic == "episode_result"]
        return statuses[-1], result

    for why_first in (True, False):
        svc, out, step = _bridge_without_zenoh(services=pipeline)
        svc._put_ros = lambda topic, payload: None  # type: ignore[method-assign]
        step(1000.0, 0.0)
        if why_first:
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode), time.monotonic())
        svc.take_goal(GoalMsg(0, True, None, None, method="greedy-dist", episode=svc.episode))
        if not why_first:
            assert svc.episode_status().state == "exploring" and not [m for topic, m in out if topic == "episode_result"]  # waits
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode + 1), time.monotonic())  # another episode's
            assert not [m for topic, m in out if topic == "episode_result"]
            step(1000.1, 0.0)  # the robot's scans go on meanwhile: they do not end it another way
            svc.on_message("r0", "ended_why", EndedWhyMsg(0, why, svc.episode), time.monotonic())
        status, result = ended(out)
        assert (status.state, status.terminated_by, status.reason) == ("done", "no_frontier", why)
        assert (result.terminated_by, result.ended_why) == ("no_frontier", why)
        assert svc.final_result is not None and svc.final_result.ended_why == why  # the queryable's, for a launcher that missed the publication

    svc, out, step = _bridge_without_zenoh(services=pipeline)
    svc._put_ros = lambda topic, payload: None  # type: ignore[method-assign]
    step(1000.0, 0.0)
    svc.take_goal(GoalMsg(0, True, None, None, method="greedy-dist", episode=svc.episode))
    svc.on_tick(time.monotonic() + svc.params.ended_why_wait_s / 2)
    assert not [m for topic, m in out if topic == "episode_result"]
    svc.on_tick(time.monotonic() + svc.params.ended_why_wait_s)
    status, result = ended(out)
    assert (status.state, status.terminated_by, status.reason, result.ended_why) == ("done", "no_frontier", "", "")


def test_the_result_query_answers_the_final_result_as_published_once_the_episode_has_ended():
    """After the end the bridge's result queryable built a fresh result at each query: the robot's scans go on coming
    (the LiDAR does not stop with the episode), so its ``steps``, path and trajectory kept growing, and a launcher that
    missed the publication and asked got another result than the one published. It answers the final result as
    published, frozen; before the end, an error (no result yet)."""
    from types import SimpleNamespace

    svc, out, step = _bridge_without_zenoh()
    svc._put_ros = lambda topic, payload: None  # type: ignore[method-assign]
    replies: list[tuple[str, bytes]] = []
    query = SimpleNamespace(reply=lambda key, payload: replies.append((key, payload)), reply_err=lambda payload: replies.append(("error", payload)))
    for i in range(3):
        step(1000.0 + 0.1 * i, 0.1 * i)
    svc._on_result_query(query)
    assert replies == [("error", b"episode not finished")]
    svc.take_goal(GoalMsg(2, True, None, None, method="greedy-dist", episode=svc.episode))  # no frontier left: the end
    (published,) = [m for topic, m in out if topic == "episode_result"]
    assert published.steps == 2 and len(published.trajectory_xy_m) == 3
    for i in range(3, 8):  # the robot's scans go on after the end
        step(1000.0 + 0.1 * i, 0.1 * i)
    assert svc.step == 7
    replies.clear()
    svc._on_result_query(query)
    ((key, payload),) = replies
    answered = decode(payload, EpisodeResultMsg)
    assert key == RobotKeys("r0").episode_result
    assert (answered.steps, answered.path_length_m, answered.terminated_by) == (published.steps, published.path_length_m, "no_frontier")
    assert answered.episode == published.episode == svc.episode != 0  # whose result: never taken for a later episode's
    np.testing.assert_array_equal(answered.trajectory_xy_m, published.trajectory_xy_m)


def test_no_scan_on_the_robots_key_is_said_in_status_and_the_log(caplog):
    """With ``--namespace limo9`` where the robot's bridge runs ``-n /limo1`` (or with no bridge running), ``status``
    stayed ``starting`` with every service alive and the bridge's log showed ``counters: {}``: nothing said that no
    scan came, nor what to check. After ``no_scan_warn_s`` without a LaserScan the episode status says so (published
    at once, for the live view) and the log warns once; the note goes when scans come, and comes back on a silence."""
    svc, out, step = _bridge_without_zenoh({"namespace": "limo9", "no_scan_warn_s": 5.0})
    start = svc.last_scan_wall_s
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        svc.on_tick(start + 4.0)
        assert svc.episode_status().reason == "" and not out
        svc.on_tick(start + 5.5)
        svc.on_tick(start + 6.0)
    reason = svc.episode_status().reason
    assert reason.startswith("no LaserScan on limo9/scan for 6 s (since the bridge started)") and "--namespace" in reason, reason
    assert [m.reason for topic, m in out if topic == "episode_status"] == [reason], "published once, at once"
    assert caplog.text.count("no LaserScan on limo9/scan") == 1
    svc.on_tick(start + 23.2)  # the note says how long the silence has lasted (it stayed "for 6 s"); said once
    assert svc.episode_status().reason.startswith("no LaserScan on limo9/scan for 23 s (since the bridge started)")
    assert len([m for topic, m in out if topic == "episode_status"]) == 1 and caplog.text.count("no LaserScan on limo9/scan") == 1
    step(1000.0, 0.0)  # scans come: the note goes
    assert svc.episode_status().reason == "" and svc.episode_status().state == "exploring"
    svc.on_tick(svc.last_scan_wall_s + 5.5)  # the LiDAR stops
    assert "(since the last one)" in svc.episode_status().reason


def test_no_scan_note_names_the_namespace_the_robots_scans_arrive_in(caplog):
    """The classic ROS mistake, ``--namespace limo9`` against a robot bridge started ``-n /limo1`` (or without ``-n``):
    the note asked "is --namespace its -n?" and left the user to find the robot's namespace. While no scan comes, the
    bridge listens for LaserScans on any ``**/scan`` key and the note names the keys they arrive on and the
    ``--namespace`` to give (said in the log and published again once); our own services' keys are not the robot's."""
    from types import SimpleNamespace

    svc, out, step = _bridge_without_zenoh({"namespace": "limo9", "no_scan_warn_s": 5.0})
    start = svc.last_scan_wall_s
    heard = lambda key: svc._on_probe_scan(SimpleNamespace(key_expr=key))  # noqa: E731
    with caplog.at_level("WARNING", logger="cso.ros2_bridge"):
        heard("limo1/scan")  # before the silence is said: not yet listened for
        svc.on_tick(start + 5.5)
        assert "arrive on" not in svc.episode_status().reason
        for key in ("cso/r0/scan", "limo9/scan", "limo1/scan", "scan", "limo1/scan"):
            heard(key)
        svc.on_tick(start + 6.5)
        svc.on_tick(start + 7.5)
    reason = svc.episode_status().reason
    assert reason.startswith("no LaserScan on limo9/scan for 8 s (since the bridge started): LaserScans arrive on limo1/scan, scan instead: "
                             "if that is this robot, give --namespace limo1 or no --namespace (its zenoh-bridge-ros2dds -n)"), reason
    assert len([m for topic, m in out if topic == "episode_status"]) == 2 and caplog.text.count("no LaserScan on limo9/scan") == 2
    step(1000.0, 0.0)  # scans come on ours: the note and what was heard elsewhere go
    assert svc.episode_status().reason == "" and svc.scans_elsewhere == []


def test_goals_frontiers_and_maps_carry_their_scans_exact_time_and_never_zero():
    """What goes back to ROS is stamped with its step's scan time, to the nanosecond (it went through float seconds).
    A step older than the stamps the bridge holds was stamped 0 (1970: RViz's and Foxglove's TF lookups fail, plots
    jump); now it takes the newest scan's time, counted as an approximation and logged once."""
    from services.ros2_bridge import STAMPS_HELD

    svc, _, step = _bridge_without_zenoh()
    sent: list[tuple[str, bytes]] = []
    svc._put_ros = lambda topic, payload: sent.append((topic, payload))  # type: ignore[method-assign]
    base_s = 1_796_546_483.0  # a robot clock of today: float seconds there are only good to ~240 ns
    times_s = [base_s + 0.1 * i + 0.000_000_123 for i in range(STAMPS_HELD + 5)]
    for i, t in enumerate(times_s):
        step(t, 0.001 * i)
    scan_ns = [int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec) for h in (_header(t, "laser_link") for t in times_s)]

    def stamps_of(topic: str, typename: str) -> list[int]:
        msgs = [rosbags_decode(raw, typename) for tp, raw in sent if tp == topic]
        return [ros2_cdr.header_stamp_ns(m.markers[0].header if hasattr(m, "markers") else m.header) for m in msgs]

    newest = svc.step
    svc.on_message("r0", "goal", GoalMsg(newest, True, 1.0, 2.0, episode=svc.episode), 0.0)
    svc.on_message("r0", "frontiers", dataclasses.replace(_frontiers_msg(newest), episode=svc.episode), 0.0)
    assert stamps_of("goal_pose", "geometry_msgs/msg/PoseStamped") == [scan_ns[newest]], "exactly the scan's stamp"
    assert stamps_of("explore/frontiers", "visualization_msgs/msg/MarkerArray") == [scan_ns[newest]]
    assert svc.counters["approximate_stamps"] == 0
    sent.clear()
    svc.on_message("r0", "goal", GoalMsg(0, True, 3.0, 4.0, episode=svc.episode), 0.0)  # step 0's time is no longer held
    svc.on_message("r0", "frontiers", dataclasses.replace(_frontiers_msg(0), episode=svc.episode), 0.0)
    assert stamps_of("goal_pose", "geometry_msgs/msg/PoseStamped") == [scan_ns[-1]], "the newest scan's time, not 0"
    assert stamps_of("explore/frontiers", "visualization_msgs/msg/MarkerArray") == [scan_ns[-1]]
    assert svc.counters["approximate_stamps"] == 2


# --- the service in-process, against a fake LIMO -----------------------------------------------------


def _frontiers_msg(step: int) -> FrontiersMsg:
    geom = GridGeometry(0.1, (10, 12), -0.5, -0.5)
    arrays = {name: np.zeros(geom.shape, dtype=dt) for name, dt in FrontiersMsg.GRIDS.items()}
    cluster = {
        "goal_cell": (3, 4),
        "goal_xy_m": (0.0, -0.1),
        "distance_m": 1.0,
        "size_m": 0.3,
        "entropy": 3.0,
        "centroid_xy_m": (0.0, 0.0),
        "cells": np.array([[3, 4], [3, 5], [4, 5]], dtype=np.int32),
    }
    return FrontiersMsg(step, True, "no_goal", Pose2D(0, 0, 0), geom, arrays, [cluster], 1.0)


@pytest.mark.parametrize("namespace", ["", "limo1"])
def test_fake_limo_through_the_bridge(namespace: str):
    from services.common import ServiceContext, run_service
    from services.ros2_bridge import Ros2BridgeService

    ros = (lambda topic: f"{namespace}/{topic}") if namespace else (lambda topic: topic)
    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    exploration = ExplorationConfig()
    exploration.sensor.mount_x_m = 0.1
    params = {"namespace": namespace, "cmd_timeout_s": 0.5, "resolution_m": 0.1, "arena_width_m": 8.0, "arena_height_m": 6.0}
    ours: dict[str, list[Any]] = {}
    to_robot: dict[str, list[tuple[float, bytes]]] = {}
    lock = threading.Lock()

    def on_ours(sample) -> None:
        topic = str(sample.key_expr).split("/", 2)[2]
        with lock:
            ours.setdefault(topic, []).append(decode(sample.payload.to_bytes()))

    def on_robot(sample) -> None:
        with lock:
            to_robot.setdefault(str(sample.key_expr), []).append((time.monotonic(), sample.payload.to_bytes()))

    with open_session(router) as session:
        subs = [session.declare_subscriber("cso/t1/**", on_ours)]
        subs += [session.declare_subscriber(ros(t), on_robot) for t in ("cmd_vel", "map", "goal_pose", "explore/frontiers")]
        svc = Ros2BridgeService(ServiceContext("ros2_bridge", "t1", {"method": "greedy-dist"}, exploration, client, params))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
        thread.start()
        try:
            wait_for(
                lambda: any(r.ok for r in session.liveliness().get(keys.alive("ros2_bridge"), timeout=0.5)),
                10,
                "the bridge's liveliness token",
            )
            wait_for(lambda: svc._ros_subs, HANG_DEADLINE_S, "the bridge's ROS subscriptions")
            # Declared in the bridge's client session, they reach this router a moment later: a put before that is
            # routed to no one (the test then waited for odometry that was dropped, under CI's load).
            for topic in ("odom", "scan"):
                with session.declare_publisher(ros(topic)) as publisher:
                    wait_for(lambda: publisher.matching_status.matching, HANG_DEADLINE_S, f"the bridge's subscription to {ros(topic)} at the router")
            # It says which robot it drives, so that a second run on this robot is refused (keys.robot_driver_token).
            def drivers() -> list[str]:
                return [str(r.ok.key_expr) for r in session.liveliness().get(robot_driver_token(ros("cmd_vel"), "*"), timeout=1.0) if r.ok]

            wait_for(lambda: drivers(), 10, "the bridge's driver token")  # one query under load may miss it: ask until it answers
            assert drivers() == [robot_driver_token(ros("cmd_vel"), "t1")], drivers()
            # Odometry first (the bridge holds a scan that is newer than every odometry sample).
            session.put(ros("odom"), ros_odom(100.0, 1.0, 2.0, 0.0, 0.2, 0.0))
            session.put(ros("odom"), ros_odom(100.1, 1.1, 2.0, 0.2, 0.2, 0.1))
            wait_for(lambda: svc.counters["received:odom"] >= 2, HANG_DEADLINE_S, "odometry at the bridge")
            ranges = np.linspace(0.5, 3.0, 181).astype(np.float32)
            ranges[10] = np.inf
            session.put(ros("scan"), ros_scan(100.05, ranges))
            wait_for(lambda: len(ours.get("scan", [])) >= 1, HANG_DEADLINE_S, "the first scan as our message")
            scan0, odom0, clock0 = ours["scan"][0], ours["odom"][0], ours["clock"][0]
            assert isinstance(scan0, ScanMsg) and isinstance(odom0, OdometryMsg) and isinstance(clock0, ClockMsg)
            assert scan0.step == odom0.step == clock0.step == 0
            assert scan0.episode == odom0.episode == clock0.episode == svc.episode != 0  # the services tell episodes by it
            assert scan0.scan.stamp_s == pytest.approx(100.05) and odom0.stamp_s == pytest.approx(100.05)
            assert scan0.scan.angle_min_rad == pytest.approx(-math.pi / 2) and len(scan0.scan.ranges_m) == 181
            np.testing.assert_allclose(scan0.scan.ranges_m[:10], ranges[:10])
            assert np.isinf(scan0.scan.ranges_m[10])
            assert odom0.pose.x_m == pytest.approx(1.05) and odom0.pose.yaw_rad == pytest.approx(0.1), (
                "interpolated at the scan time"
            )
            assert odom0.twist.linear_mps == pytest.approx(0.2)
            assert scan0.sensor_pose.x_m == pytest.approx(1.05 + 0.1 * math.cos(0.1)), "the sensor mount is applied"
            assert clock0.arena is not None and clock0.arena.shape == (60, 80)
            assert (clock0.arena.origin_x_m, clock0.arena.origin_y_m) == pytest.approx((1.05 - 4.0, 2.0 - 3.0))

            # NaN and too-close beams are counted (NaN cleaned); another angle range is honoured.
            nan_ranges = np.full(361, 2.0, np.float32)
            nan_ranges[:5] = np.nan
            nan_ranges[5] = 0.05
            session.put(ros("scan"), ros_scan(100.08, nan_ranges, -math.pi, math.pi))
            wait_for(lambda: len(ours.get("scan", [])) >= 2, HANG_DEADLINE_S, "the NaN scan")
            scan1 = ours["scan"][1]
            assert scan1.step == 1 and scan1.scan.angle_min_rad == pytest.approx(-math.pi) and len(scan1.scan.ranges_m) == 361
            assert (scan1.scan.ranges_m[:5] == 0).all() and svc.counters["invalid_beams"] == 6
            assert scan1.scan.ranges_m[5] == pytest.approx(0.05), "too close: something there, for the planner's stop check"
            # A header that does not fit its ranges, a stale scan, an out-of-order one: dropped and counted.
            session.put(ros("scan"), ros_scan(100.09, ranges, n_angles=90))
            session.put(ros("odom"), ros_odom(102.0, 1.2, 2.0, 0.2))
            wait_for(lambda: svc.counters["received:odom"] >= 3, HANG_DEADLINE_S, "the newer odometry")
            session.put(ros("scan"), ros_scan(101.0, ranges))
            session.put(ros("scan"), ros_scan(100.07, ranges))
            session.put(ros("scan"), b"\x00\x01\x00\x00garbage")
            wait_for(lambda: svc.counters["received:scan"] >= 6, HANG_DEADLINE_S, "every scan at the bridge")
            status = wait_for(
                lambda: [
                    decode(r.ok.payload.to_bytes(), ServiceStatusMsg)
                    for r in session.get(keys.service_status("ros2_bridge"), timeout=1.0)
                    if r.ok
                ],
                5,
                "the bridge's status",
            )[0]
            assert status.rejected == {"ros_scan:bad_cdr": 2, "ros_scan:stale": 1, "ros_scan:out_of_order": 1}, status.rejected
            assert len(ours["scan"]) == 2 and status.last_step == 1
            # The bridge's own counts travel in its status too (`status` shows them), not only its rejections.
            assert status.counters["received:scan"] >= 6 and status.counters["received:odom"] >= 3, status.counters
            assert status.counters["invalid_beams"] == 6 and status.counters["dropped:ros_scan:bad_cdr"] == 2, status.counters

            # Our velocity command -> a clamped Twist; then the watchdog's zero Twist after 0.5 s.
            session.put(keys.cmd_vel, encode(CmdVelMsg(1, VelocityCommand(2.0, -1.5))))
            wait_for(lambda: to_robot.get(ros("cmd_vel")), HANG_DEADLINE_S, "a Twist on cmd_vel")
            t_cmd, raw = to_robot[ros("cmd_vel")][0]
            twist = rosbags_decode(raw, "geometry_msgs/msg/Twist")
            assert (twist.linear.x, twist.angular.z) == (1.0, pytest.approx(-0.78))
            wait_for(lambda: len(to_robot[ros("cmd_vel")]) >= 2, HANG_DEADLINE_S, "the watchdog's zero Twist")
            t_zero, raw = to_robot[ros("cmd_vel")][1]
            zero = rosbags_decode(raw, "geometry_msgs/msg/Twist")
            assert (zero.linear.x, zero.angular.z) == (0.0, 0.0)
            assert t_zero - t_cmd >= 0.45, "not before the 0.5 s timeout"
            assert svc.counters["watchdog_stops"] == 1 and svc.counters["clamped_commands"] == 1

            # Map, goal and frontiers come out as ROS messages for RViz.
            geom = GridGeometry(0.1, (6, 8), -1.0, -2.0)
            grid = np.full(geom.shape, -1, np.int8)
            grid[1:4, 2:6] = 0
            grid[0, :] = 100
            session.put(keys.map, encode(MapMsg.from_grid(1, geom, grid)))
            session.put(keys.goal, encode(GoalMsg(1, True, 0.5, -0.3, 0, 1.0, 2.0, "greedy-dist")))
            session.put(keys.frontiers, encode(_frontiers_msg(1)))
            wait_for(
                lambda: all(to_robot.get(ros(t)) for t in ("map", "goal_pose", "explore/frontiers")), 5, "map, goal and frontiers"
            )
            og = rosbags_decode(to_robot[ros("map")][0][1], "nav_msgs/msg/OccupancyGrid")
            assert (og.info.width, og.info.height, og.info.resolution) == (8, 6, pytest.approx(0.1))
            assert (og.info.origin.position.x, og.info.origin.position.y) == (-1.0, -2.0) and og.header.frame_id == "odom"
            np.testing.assert_array_equal(np.asarray(og.data).reshape(6, 8), grid)
            assert og.header.stamp.sec == 100 and abs(og.header.stamp.nanosec - 80_000_000) < 1000, (
                "stamped with the step's scan time"
            )
            ps = rosbags_decode(to_robot[ros("goal_pose")][0][1], "geometry_msgs/msg/PoseStamped")
            assert (ps.pose.position.x, ps.pose.position.y) == (0.5, -0.3)
            ma = rosbags_decode(to_robot[ros("explore/frontiers")][0][1], "visualization_msgs/msg/MarkerArray")
            assert [m.ns for m in ma.markers] == ["", "frontiers", "frontiers_goals"]
            assert ma.markers[0].action == 3 and len(ma.markers[1].points) == 3  # DELETEALL, then the cluster's cells
            assert ma.markers[1].points[0].x == pytest.approx(-0.5 + 4.5 * 0.1) and ma.markers[1].points[0].y == pytest.approx(
                -0.5 + 3.5 * 0.1
            )

            # A goal still in flight from before this bridge started (another episode id) neither counts nor ends it.
            session.put(keys.goal, encode(GoalMsg(2, True, None, None, method="greedy-dist", episode=svc.episode + 1)))
            # No reachable frontier left: the episode ends, and the result can be fetched.
            session.put(keys.goal, encode(GoalMsg(2, True, None, None, method="greedy-dist", episode=svc.episode)))
            wait_for(
                lambda: any(isinstance(m, EpisodeStatusMsg) and m.state == "done" for m in ours.get("episode/status", [])),
                5,
                "the end of the episode",
            )
            result = [
                decode(r.ok.payload.to_bytes(), EpisodeResultMsg) for r in session.get(keys.episode_result, timeout=2.0) if r.ok
            ]
            assert result and result[0].terminated_by == "no_frontier" and result[0].decisions == 2
            assert svc.rejected.get("goal") == 1
            assert result[0].explored_area_m2 == pytest.approx((grid != -1).sum() * 0.01)
            assert result[0].final_map is not None  # the robot's map, for the run's map_server files
            np.testing.assert_array_equal(result[0].final_map.grid, grid)
        finally:
            stop.set()
            thread.join(10)
            for s in subs:
                s.undeclare()
    assert not thread.is_alive()


def test_the_map_reaches_a_ros_subscriber_that_comes_after_the_episode(monkeypatch):
    """RViz's Map display and Nav2's static layer subscribe to ``/map`` transient-local (map_server's QoS): for such a
    subscriber zenoh-bridge-ros2dds declares a Zenoh subscriber that asks the publishers on the key for their last
    sample (zenoh-ext's advanced subscriber with late-publisher detection). The bridge put its maps plainly: an RViz or
    a Nav2 started once exploration had ended (its map sent, no newer one to come) got no map at all. The bridge now
    keeps the last OccupancyGrid for such subscribers, as a latched ``/map``; goal and frontiers stay volatile.
    zenoh-bridge-ros2dds releases from before its advanced subscriber (1.0.x among them) ask instead with a query on
    ``@ros2_pub_cache/*/<key>`` that takes replies on any key, which nothing answered: they get the last map too."""
    import zenoh
    import zenoh.ext

    from services.common import ServiceContext, run_service
    from services.ros2_bridge import Ros2BridgeService

    monkeypatch.setenv("CSO_PARENT_PID", str(os.getppid()))  # as up starts it: no claim to settle first
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session, contextlib.ExitStack() as undeclare:
        svc = Ros2BridgeService(ServiceContext("ros2_bridge", "t1", {"method": "greedy-dist"}, ExplorationConfig(), client, {"namespace": "limo1"}))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
        thread.start()
        late: list[bytes] = []
        try:
            wait_for(lambda: svc._ros_subs, 10, "the bridge's ROS subscriptions")
            with session.declare_publisher(keys.map) as publisher:  # its subscription reaches the router a moment later
                wait_for(lambda: publisher.matching_status.matching, 10, "the bridge's subscription to the map at the router")
            geom = GridGeometry(0.1, (6, 8), -1.0, -2.0)
            grids = [np.full(geom.shape, -1, np.int8) for _ in range(2)]
            grids[1][1:4, 2:6], grids[1][0, :] = 0, 100
            for step, grid in enumerate(grids):
                session.put(keys.map, encode(MapMsg.from_grid(step, geom, grid)))
                wait_for(lambda step=step: svc.counters["sent:map"] > step, 5, f"map {step} sent to ROS")
            # A transient-local ROS subscriber appears now, as zenoh-bridge-ros2dds subscribes for it.
            transient_local = zenoh.ext.declare_advanced_subscriber(
                session, "limo1/map", lambda sample: late.append(sample.payload.to_bytes()),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )  # fmt: skip
            undeclare.callback(transient_local.undeclare)
            wait_for(lambda: late, HANG_DEADLINE_S, "the last map for a late transient-local subscriber")
            og = rosbags_decode(late[-1], "nav_msgs/msg/OccupancyGrid")
            np.testing.assert_array_equal(np.asarray(og.data).reshape(geom.shape), grids[1])
            assert len(late) == 1, "the last map only"
            # An older zenoh-bridge-ros2dds's transient-local route asks as its QueryingSubscriber did.
            legacy = [
                r.ok
                for r in session.get(
                    "@ros2_pub_cache/*/limo1/map", target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                    accept_replies=zenoh.ReplyKeyExpr.ANY, timeout=5.0,
                )
                if r.ok is not None
            ]  # fmt: skip
            assert [str(r.key_expr) for r in legacy] == ["limo1/map"] and legacy[0].payload.to_bytes() == late[-1]
            matching = [r.ok for r in session.get("@ros2_pub_cache/**", timeout=5.0) if r.ok is not None]
            assert [str(r.key_expr).split("/")[-2:] for r in matching] == [["limo1", "map"]] and str(matching[0].key_expr).startswith("@ros2_pub_cache/")
            assert matching[0].payload.to_bytes() == late[-1]
            # An ordinary (volatile) subscriber still gets every new map. Its declaration reaches the bridge's session a
            # moment after it is made (a map sent before that reaches no one, as with ROS's volatile QoS): a new map
            # each round, each one sent to ROS, until one arrives; none of them the latched one.
            volatile: list[bytes] = []
            volatile_sub = session.declare_subscriber("limo1/map", lambda sample: volatile.append(sample.payload.to_bytes()))
            undeclare.callback(volatile_sub.undeclare)
            deadline_s = time.monotonic() + 10.0
            for step in itertools.count(2):
                sent = svc.counters["sent:map"]
                session.put(keys.map, encode(MapMsg.from_grid(step, geom, grids[0])))
                wait_for(lambda sent=sent: svc.counters["sent:map"] > sent, 5, f"map {step} sent to ROS")
                if volatile or time.monotonic() > deadline_s:
                    break
            assert volatile, f"none of the maps of steps 2 to {step} reached a plain subscriber"
            for heard in volatile:
                np.testing.assert_array_equal(np.asarray(rosbags_decode(heard, "nav_msgs/msg/OccupancyGrid").data).reshape(geom.shape), grids[0])
        finally:
            stop.set()
            thread.join(10)
    assert not thread.is_alive()


def test_a_bridge_refuses_a_robot_that_another_runs_bridge_drives(monkeypatch):
    """``up`` refuses a run whose bridge would drive a robot another run's bridge drives; a bridge started by hand (or
    one of two runs started at once) got past that and sent its Twists beside the other's. It now refuses on start
    (ConfigError: exit 2, which the launcher does not restart), before any command; its own robot's token (a
    restarted bridge's, still held for a moment) does not count."""
    from cso_runtime.config import ConfigError
    from services.common import ServiceContext, run_service
    from services.ros2_bridge import Ros2BridgeService

    monkeypatch.delenv("CSO_PARENT_PID", raising=False)  # started by hand
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        twists: list[bytes] = []
        sub = session.declare_subscriber("limo1/cmd_vel", lambda sample: twists.append(sample.payload.to_bytes()))
        held = session.liveliness().declare_token(robot_driver_token("limo1/cmd_vel", "r7"))
        try:
            svc = Ros2BridgeService(ServiceContext("ros2_bridge", "t1", {"method": "greedy-dist"}, ExplorationConfig(), client, {"namespace": "limo1"}))
            refused: list[Exception] = []
            stop = threading.Event()

            def run() -> None:
                try:
                    run_service(svc, stop)
                except ConfigError as exc:
                    refused.append(exc)

            thread = threading.Thread(target=run, daemon=True)
            thread.start()
            thread.join(15)  # it stops by itself
            stop.set()
            thread.join(10)
            assert refused and "robot r7's run already drives limo1/cmd_vel" in str(refused[0]), refused
            held.undeclare()
            held = session.liveliness().declare_token(robot_driver_token("limo1/cmd_vel", "t1"))  # its own, from before a restart
            monkeypatch.setenv("CSO_PARENT_PID", str(os.getppid()))  # as its launcher restarts it (by hand: another's, refused)
            stop = threading.Event()
            svc = Ros2BridgeService(ServiceContext("ros2_bridge", "t1", {"method": "greedy-dist"}, ExplorationConfig(), client, {"namespace": "limo1"}))
            thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
            thread.start()
            try:
                wait_for(lambda: svc._ros_subs, 10, "the bridge's ROS subscriptions")
            finally:
                stop.set()
                thread.join(10)
        finally:
            held.undeclare()
            sub.undeclare()
    assert twists == [] and not thread.is_alive()


BRIDGE_AT_ONCE = """
import sys
from services.ros2_bridge import main
print("ready", flush=True)
sys.stdin.readline()  # the barrier: the test lets every bridge go at once
raise SystemExit(main(sys.argv[1:]))
"""


def test_of_bridges_started_by_hand_at_once_on_one_robot_exactly_one_drives_it(tmp_path: Path):
    """A bridge started by hand (``python -m services.ros2_bridge``, as docs/hardware.md says) took no claim on the
    robot it drives, as ``up`` does for its bridge: two started at the same moment both went on (and one of the robot
    id of a run or bridge already driving it never looked), each sending the robot its Twists. It now claims the
    robot behind its ``cmd_vel`` (``cso_runtime.claims``): of bridges started at once on one namespace exactly one goes
    on, the others exit 2 saying who has it; one on another namespace goes on beside it, and a later one (of the same
    robot id too) is refused by the one that drives, as is ``up``'s check of a run that would drive it."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import load_profile

    cfg = tmp_path / "limo.yaml"
    cfg.write_text((PROFILES / "limo-ros2.yaml").read_text())
    port = free_tcp_port()
    env = {k: v for k, v in os.environ.items() if k != "CSO_PARENT_PID"}  # started by hand, not by a launcher

    def bridge(i: int, robot: str, namespace: str) -> subprocess.Popen:
        argv = ["--config", str(cfg), "--robot", robot, "--namespace", namespace, "--connect", loopback_endpoint(port)]
        log = (tmp_path / f"bridge{i}.log").open("w")
        return subprocess.Popen(
            [sys.executable, "-c", BRIDGE_AT_ONCE, *argv], cwd=REPO, env=env, stdin=subprocess.PIPE, stdout=log, stderr=subprocess.STDOUT, text=True, start_new_session=True
        )

    def said(i: int) -> str:
        return (tmp_path / f"bridge{i}.log").read_text()

    runs = [("r1", "limo1"), ("r1", "limo1"), ("r2", "limo1"), ("r3", "limo2")]
    procs = [bridge(i, robot, namespace) for i, (robot, namespace) in enumerate(runs)]
    try:
        with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
            wait_for(lambda: all(said(i).startswith("ready") for i in range(len(procs))), 60, "every bridge to have imported")
            for p in procs:  # go: each line is sent at once, before any bridge could have claimed
                p.stdin.write("\n")
                p.stdin.flush()
            driving = lambda i: "bridging ROS keys" in said(i)  # noqa: E731
            wait_for(lambda: all(driving(i) or procs[i].poll() is not None for i in range(len(procs))), 90, "every bridge to decide")
            same = [i for i in range(3) if driving(i)]
            assert len(same) == 1 and driving(3) and procs[3].poll() is None, [said(i)[-1500:] for i in range(len(procs))]
            for i in set(range(3)) - set(same):
                assert procs[i].wait(10) == 2, said(i)[-2000:]
                assert "the robot behind limo1/cmd_vel is claimed by another run or bridge on this network" in said(i) or (
                    "already drives limo1/cmd_vel" in said(i)
                ), said(i)[-2000:]
                assert "--namespace" in said(i) and "bridging ROS keys" not in said(i), said(i)[-2000:]
            winner_robot = runs[same[0]][0]
            later = bridge(9, winner_robot, "limo1")  # of the same robot id as the one that drives: refused all the same
            procs.append(later)
            later.stdin.write("\n")
            later.stdin.flush()
            assert later.wait(60) == 2 and "limo1/cmd_vel" in said(9) and "bridging ROS keys" not in said(9), said(9)[-2000:]
            other, data = load_profile("limo-ros2", {"robot": "r5"}, connect=[loopback_endpoint(port)], namespace="limo1")
            taken = Launcher(other, data, tmp_path / "run").robot_already_served(session)
            assert "limo1/cmd_vel is already driven by" in taken or "limo1/cmd_vel is being claimed by another run" in taken, taken
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)


@pytest.mark.parametrize("stamped", [False, True])
def test_bridge_process_takes_namespace_and_stops_the_robot_on_sigint(tmp_path: Path, stamped: bool):
    """``python -m services.ros2_bridge --namespace NS``: the ROS keys follow NS, and SIGINT sends a
    last zero Twist (the watchdog is set far away so the zero can only come from the shutdown). With
    ``cmd_vel_stamped`` each is a TwistStamped in ``base_frame_id``, stamped in the robot's clock: from the robot's
    scan on, at or after its stamp."""
    profile = yaml.safe_load((PROFILES / "limo-ros2.yaml").read_text())
    profile["services"]["ros2_bridge"]["cmd_timeout_s"] = 60.0
    if stamped:
        profile["services"]["ros2_bridge"].update(cmd_vel_stamped=True, base_frame_id="limo7/base_link")
    cfg = tmp_path / "limo.yaml"
    cfg.write_text(yaml.safe_dump(profile))
    port = free_tcp_port()
    keys = RobotKeys("t2")
    twists: list[bytes] = []
    scan_s = 1_796_546_483.5
    scan_ns = 1_796_546_483_500_000_000

    def command(raw: bytes) -> tuple[float, float, int]:
        """(linear.x, angular.z, stamp in ns: 0 for a Twist) of what went to the robot, decoded by rosbags."""
        if not stamped:
            msg = rosbags_decode(raw, "geometry_msgs/msg/Twist")
            return msg.linear.x, msg.angular.z, 0
        msg = rosbags_decode(raw, "geometry_msgs/msg/TwistStamped")
        assert msg.header.frame_id == "limo7/base_link"
        return msg.twist.linear.x, msg.twist.angular.z, ros2_cdr.header_stamp_ns(msg.header)

    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        sub = session.declare_subscriber("limo7/cmd_vel", lambda s: twists.append(s.payload.to_bytes()))
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.ros2_bridge",
                "--config",
                str(cfg),
                "--robot",
                "t2",
                "--namespace",
                "limo7",
                "--connect",
                loopback_endpoint(port),
            ],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            wait_for(
                lambda: any(r.ok for r in session.liveliness().get(keys.alive("ros2_bridge"), timeout=0.5)),
                20,
                "the bridge process",
            )
            scan = ros_scan(scan_s, np.full(181, 2.0, np.float32))
            wait_for(
                lambda: session.put("limo7/scan", scan) or session.put(keys.cmd_vel, encode(CmdVelMsg(0, VelocityCommand(0.3, 0.1)))) or twists,
                10,
                "a Twist on limo7/cmd_vel",
            )
            first = command(twists[0])
            assert first[:2] == (pytest.approx(0.3), pytest.approx(0.1))
            assert not any(command(t)[0] == 0.0 for t in twists)
            os.killpg(proc.pid, signal.SIGINT)
            assert proc.wait(15) == 0
            wait_for(lambda: twists and command(twists[-1])[0] == 0.0, HANG_DEADLINE_S, "the final zero Twist")
            last = command(twists[-1])
            assert last[:2] == (0.0, 0.0)
            if stamped:  # a command before the scan came is stamped 0 (the robot's own now); the scan then sets the time
                stamps = [command(t)[2] for t in twists]
                assert stamps == sorted(stamps) and scan_ns <= last[2] < scan_ns + 60 * 1_000_000_000, stamps
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
            sub.undeclare()


# --- end to end: a fake LIMO explored through the bridge by the unchanged services -------------------


class FakeLimo:
    """The kinematic simulator as a ROS 2 robot: Odometry and LaserScan CDR (made by rosbags) on the bare
    keys ``odom``/``scan`` every control period (sped up by ``speedup``), Twist commands from ``cmd_vel``."""

    def __init__(self, session, plan, speedup: float):
        from cso_runtime.simulator import KinematicSimulator

        self.session, self.sim, self.period_s = session, KinematicSimulator(plan, seed=0), 0.25 / speedup
        self.sim.reset(0)
        self.command = VelocityCommand()
        self.commands = 0
        self.sub = session.declare_subscriber("cmd_vel", self._on_twist)

    def _on_twist(self, sample) -> None:
        msg = rosbags_decode(sample.payload.to_bytes(), "geometry_msgs/msg/Twist")
        self.command = VelocityCommand(float(msg.linear.x), float(msg.angular.z))
        self.commands += 1

    def run(self, stop: threading.Event) -> None:
        base_s = 1000.0
        while not stop.is_set():
            t = base_s + self.sim.time_s
            p = self.sim.odometry()
            self.session.put("odom", ros_odom(t, p.x_m, p.y_m, p.yaw_rad, self.command.linear_mps, self.command.angular_radps))
            scan = self.sim.scan()
            self.session.put(
                "scan",
                ros_scan(
                    t, scan.ranges_m, scan.angle_min_rad, scan.angle_min_rad + scan.angle_increment_rad * (len(scan.ranges_m) - 1)
                ),
            )
            if stop.wait(self.period_s):
                break
            self.sim.step(self.command)


def test_fake_limo_is_explored_through_the_limo_ros2_profile():
    from cso_runtime.episode import GroundTruthMetrics
    from cso_runtime.occupancy import OccupancyMap
    from cso_runtime.scenes import resolve_scenes
    from services.common import ServiceContext, load_profile_for_service, run_service
    from services.frontier import FrontierService
    from services.mapper import MapperService
    from services.planner import PlannerService
    from services.policy import PolicyService
    from services.ros2_bridge import Ros2BridgeService

    plan = resolve_scenes("generated:small:1:0")[0].load()
    g = plan.geometry
    profile_path = PROFILES / "limo-ros2.yaml"
    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("r0")
    services = []
    for cls in (Ros2BridgeService, MapperService, FrontierService, PolicyService, PlannerService):
        profile, exploration, params = load_profile_for_service(profile_path, cls.name)
        exploration.sensor.mount_x_m = 0.0  # the simulated LIMO's sensor sits at its centre
        if cls is Ros2BridgeService:  # map exactly the plan's grid, to measure coverage against it
            params = {
                **params,
                "arena_origin_xy_m": [g.origin_x_m, g.origin_y_m],
                "resolution_m": g.resolution_m,
                "arena_width_m": g.width_m,
                "arena_height_m": g.height_m,
            }
        services.append(cls(ServiceContext(cls.name, "r0", profile, exploration, client, params)))
    stop = threading.Event()
    threads = [threading.Thread(target=run_service, args=(s, stop), daemon=True) for s in services]
    statuses: list[EpisodeStatusMsg] = []
    with open_session(router) as session:
        sub = session.declare_subscriber(
            keys.episode_status, lambda s: statuses.append(decode(s.payload.to_bytes(), EpisodeStatusMsg))
        )
        robot = FakeLimo(session, plan, speedup=4.0)
        robot_thread = threading.Thread(target=robot.run, args=(stop,), daemon=True)
        try:
            for t in threads:
                t.start()
            for s in services:
                wait_for(
                    lambda s=s: any(r.ok for r in session.liveliness().get(keys.alive(s.name), timeout=0.5)),
                    15,
                    f"the {s.name} service",
                )
            robot_thread.start()
            wait_for(lambda: statuses and statuses[-1].state == "done", 35, "the end of the exploration")
        finally:
            stop.set()
            for t in [robot_thread, *threads]:
                if t.ident is not None:  # a service that never came up: the robot's thread was never started
                    t.join(10)
            robot.sub.undeclare()
            sub.undeclare()
    mapper = services[1]
    coverage = GroundTruthMetrics(plan).coverage_pct(
        OccupancyMap.from_occupancy_grid(mapper.map.to_occupancy_grid(), mapper.map.geometry)
    )
    print(
        f"coverage {coverage:.1f}% after {statuses[-1].step} scans, {robot.commands} commands, {statuses[-1].decisions} decisions"
    )
    assert statuses[-1].terminated_by == "no_frontier" and robot.commands > 0
    assert coverage > 90.0, f"coverage {coverage:.1f}%"
    assert not any(t.is_alive() for t in threads)


def test_odometry_no_subscriber_can_decode_is_dropped_with_its_scan_and_never_breaks_the_episode_status():
    """A robot's odometry whose values are finite but out of what ``odom`` allows (a twist over 100 m/s or rad/s: a
    driver's glitch) was published as the step's ``odom``, which every subscriber rejects, and kept as the robot's last
    pose and twist: the bridge's ``episode_status`` (v4 carries them) could then not be decoded by the launcher or
    ``status`` until the next good step, its final one at the episode's end included. The step is dropped and counted,
    as a scan no subscriber could decode is, and the status stays the last good odometry's."""
    from types import SimpleNamespace

    svc, _, step = _bridge_without_zenoh()
    sent: list[tuple[str, Any]] = []
    svc.publish = lambda topic, msg, robot=None: sent.append((topic, msg))  # type: ignore[method-assign]  # as published, undecoded
    sample = lambda raw: SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))  # noqa: E731
    for i in range(3):
        step(1000.0 + 0.1 * i, 0.02 * i)
    svc._on_ros_odom(sample(ros_odom(1000.3, 0.06, 0.0, 0.0, v=150.0)))
    svc._on_ros_scan(sample(ros_scan(1000.3, np.full(181, 2.0, np.float32))))
    for topic, msg in sent:
        decode(encode(msg), type(msg))  # whatever went out, its subscribers can read
    status = decode(encode(svc.episode_status()), EpisodeStatusMsg)
    assert status.step == svc.step == 2 and status.twist == VelocityCommand(0.0, 0.0)
    assert svc.counters["dropped:ros_odom:invalid"] == 1 and svc.rejected.get("ros_odom:invalid") == 1
