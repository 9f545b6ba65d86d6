"""A fake LIMO for development and tests: the MuJoCo LIMO speaking only ROS 2, as zenoh-bridge-ros2dds
would expose a real one.

    python -m robot_sim.fake_limo --listen tcp/127.0.0.1:7447 [--namespace limo1] [--scene SPEC] [--speed 4] [--cmd-vel-stamped]
        [--lidar-mount-x-m 0.103]
    cso-runtime up --profile limo-ros2 --connect tcp/127.0.0.1:7447 [--namespace limo1]

It opens its own Zenoh router on ``--listen`` (like the bridge on the robot, multicast scouting off),
runs ``MujocoSimulator`` in real time (``--speed`` x), and publishes on the bare keys ``[NS/]odom``
(nav_msgs/Odometry) and ``[NS/]scan`` (sensor_msgs/LaserScan, the front 180 degrees) the CDR bytes
that the rosbags typestore serialises from its own message classes; it drives the robot with the
geometry_msgs/Twist it receives on ``[NS/]cmd_vel`` (the simulator's watchdog stops it when they stop); with
``--cmd-vel-stamped``, geometry_msgs/TwistStamped, as ROS 2 Jazzy's diff_drive_controller takes (the run then needs
``--set services.ros2_bridge.cmd_vel_stamped=true``; the stamps are not checked).
Nothing of our own message format is used. Each scan goes out with an odometry sample at its exact
stamp (and odometry is also published at ``--odom-rate-hz``), so the scan/odometry matching is exact.
The LiDAR sits ``--lidar-mount-x-m`` ahead of base_link (the LIMO's 0.103 m, ``limo_sensor()``, as the ``limo-ros2``
profile's ``exploration.sensor.mount_x_m`` says; a run against another mount needs ``--set
exploration.sensor.mount_x_m=...`` with the same value, as no TF is sent).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import signal
import sys
import threading
from typing import Any

from cso_runtime import ros2_cdr
from cso_runtime.config import ConfigError, ExplorationConfig, check_seed
from cso_runtime.geometry import LaserScan, Pose2D, VelocityCommand
from cso_runtime.processes import set_from_signal_handler
from cso_runtime.scenes import SceneError, resolve_scenes
from cso_runtime.transport import TransportConfig, open_session
from robot_sim.config import limo_sensor
from robot_sim.sim import MujocoSimulator, RealTimePacer

log = logging.getLogger("cso.fake_limo")

BASE_STAMP_S = 1000.0
"""Robot clock at the simulation's time 0 (a real robot's stamps are far from zero)."""


LIMO_TWIST_COVARIANCE_DIAGONAL = (0.0,) * 6
"""AgileX's LIMO driver leaves the twist's covariance all zero (limo_base ``LimoDriver::publishOdometry``)."""


def odometry_cdr(stamp_s: float, pose: Pose2D, linear_mps: float, angular_radps: float) -> bytes:
    """nav_msgs/Odometry of base_link in odom, with the covariances AgileX's LIMO driver publishes: the pose's
    diagonal ``ODOMETRY_COVARIANCE_DIAGONAL``, the twist's all zero."""
    stamp_ns = ros2_cdr.stamp_ns_from_seconds(stamp_s)
    velocity = VelocityCommand(linear_mps, angular_radps)
    return ros2_cdr.odometry_to_cdr(pose, velocity, stamp_ns, "odom", "base_link", twist_covariance_diagonal=LIMO_TWIST_COVARIANCE_DIAGONAL)


def laserscan_cdr(stamp_s: float, scan: LaserScan, scan_time_s: float = 0.0) -> bytes:
    """sensor_msgs/LaserScan in laser_link (``scan_time_s``, the time between scans; a beam with no reading as NaN,
    as a real LiDAR driver sends it)."""
    return ros2_cdr.laserscan_to_cdr(scan, ros2_cdr.stamp_ns_from_seconds(stamp_s), "laser_link", scan_time_s)


class FakeLimo:
    """The MuJoCo LIMO on one Zenoh session, in ROS 2 terms only."""

    def __init__(
        self, session: Any, sim: MujocoSimulator, namespace: str = "", odom_rate_hz: float = 20.0, cmd_vel_stamped: bool = False
    ) -> None:
        self.session, self.sim = session, sim
        self.cmd_vel_type = ros2_cdr.TWIST_STAMPED if cmd_vel_stamped else ros2_cdr.TWIST
        self.prefix = f"{namespace.strip('/')}/" if namespace.strip("/") else ""
        self.odom_period_s = 1.0 / odom_rate_hz
        self.last_odom_s = -math.inf
        self.commands = 0
        self.bad_commands = 0
        self.scans = 0
        self._lock = threading.Lock()
        self.pub_odom = session.declare_publisher(self.prefix + "odom")
        self.pub_scan = session.declare_publisher(self.prefix + "scan")
        self.sub = session.declare_subscriber(self.prefix + "cmd_vel", self._on_twist)

    def _on_twist(self, sample: Any) -> None:
        """A command through ros2_cdr's decoders: one of the other type, or with a NaN or infinite value, is counted
        and not driven."""
        raw = sample.payload.to_bytes()
        try:
            command = ros2_cdr.twist_stamped_from_cdr(raw)[0] if self.cmd_vel_type == ros2_cdr.TWIST_STAMPED else ros2_cdr.twist_from_cdr(raw)
        except ros2_cdr.CdrError as exc:
            self.bad_commands += 1
            log.warning("undecodable %s (%d so far): %s", self.cmd_vel_type.rsplit("/", 1)[-1], self.bad_commands, exc)
            return
        with self._lock:
            if self.sim.set_command(command):
                self.commands += 1

    def _put_odom(self, time_s: float, base_pose: Pose2D) -> None:
        if time_s <= self.last_odom_s:
            return
        v, _, w = self.sim.body_velocity()
        self.pub_odom.put(odometry_cdr(BASE_STAMP_S + time_s, base_pose, v, w))
        self.last_odom_s = time_s

    def publish_due(self) -> None:
        """Every scan fired since the last call (each preceded by odometry at its stamp), then odometry."""
        with self._lock:
            fired = self.sim.drain_scans()
            now_s, odom = self.sim.time_s, self.sim.odometry()
        for sensor_pose, scan in fired:
            self._put_odom(scan.stamp_s, sensor_pose.compose_offset(-self.sim.lidar_mount_x_m))
            self.pub_scan.put(laserscan_cdr(BASE_STAMP_S + scan.stamp_s, scan, 1.0 / self.sim.sensor.rate_hz))
            self.scans += 1
        if now_s - self.last_odom_s >= self.odom_period_s:
            self._put_odom(now_s, odom)

    def run(self, stop: threading.Event, speed: float, poll_period_s: float = 0.005) -> None:
        """Real time at ``speed`` x until ``stop``."""
        pacer = RealTimePacer(self.sim, speed=speed)
        pacer.start()
        while not stop.is_set():
            with self._lock:
                pacer.poll()
            self.publish_due()
            stop.wait(poll_period_s)

    def close(self) -> None:
        self.sub.undeclare()
        self.pub_odom.undeclare()
        self.pub_scan.undeclare()


def main(argv: list[str] | None = None) -> int:
    """``python -m robot_sim.fake_limo``: run the fake LIMO until SIGINT or SIGTERM; exit code 0, or 2 for bad flags."""
    p = argparse.ArgumentParser(prog="python -m robot_sim.fake_limo", description="A MuJoCo LIMO speaking ROS 2 CDR over Zenoh")
    p.add_argument("--listen", action="append", required=True, help="Zenoh endpoint of the robot's router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--namespace", default="", help="ROS namespace: keys NS/scan, NS/odom, NS/cmd_vel")
    p.add_argument("--scene", default="generated:small:1:0", help="Scene spec: builtin, DIR, FILE.png, generated:SCALE:N:SEED")
    p.add_argument("--m-per-px", type=float, default=0.1, help="Metres per pixel of PNG plans")
    p.add_argument("--speed", type=float, default=1.0, help="Real-time factor")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--odom-rate-hz", type=float, default=20.0, help="Odometry rate besides the samples at each scan")
    p.add_argument(
        "--cmd-vel-stamped", action="store_true",
        help="Take geometry_msgs/TwistStamped on cmd_vel (ROS 2 Jazzy's diff_drive_controller), not Twist; the run needs "
        "services.ros2_bridge.cmd_vel_stamped: true",
    )  # fmt: skip
    p.add_argument(
        "--lidar-mount-x-m", type=float, default=limo_sensor().mount_x_m, metavar="M",
        help="The LiDAR's mount ahead of base_link, m (default: the LIMO's, %(default)s, as the limo-ros2 profile's "
        "exploration.sensor.mount_x_m; another value needs --set exploration.sensor.mount_x_m=M on up)",
    )  # fmt: skip
    p.add_argument("--log-level", type=str.upper, choices=("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"), default="INFO", metavar="LEVEL")
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if not (0 < args.speed < math.inf and 0 < args.odom_rate_hz < math.inf):
        p.error("--speed and --odom-rate-hz must be positive and finite")
    if args.namespace.strip("/") and not ros2_cdr.is_ros_name(args.namespace):
        p.error(f"--namespace {args.namespace!r} is not a ROS name (letters, digits, '_', '/')")
    exploration = ExplorationConfig(sensor=dataclasses.replace(limo_sensor(), mount_x_m=args.lidar_mount_x_m))
    try:  # on the robot, as a profile's sensor.mount_x_m must be
        if not math.isfinite(args.lidar_mount_x_m):
            raise ConfigError("the mount must be a finite number of metres")
        exploration.validate()
    except ConfigError as exc:
        p.error(f"--lidar-mount-x-m {args.lidar_mount_x_m:g}: {exc}")
    try:
        check_seed(args.seed, "--seed")
    except ConfigError as exc:
        p.error(str(exc))
    try:  # a missing, corrupt or unusable plan is a bad --scene (exit 2, one line), as for the sim service
        refs = resolve_scenes(args.scene, limit=1, resolution_m=args.m_per_px)
        if not refs:
            p.error(f"scene {args.scene!r} resolves to no scene")
        plan = refs[0].load()
        sim = MujocoSimulator(plan, exploration.sensor, exploration.robot, seed=args.seed)
    except (SceneError, ConfigError) as exc:
        p.error(f"--scene {args.scene} (--m-per-px {args.m_per_px:g}): {exc}")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: set_from_signal_handler(stop))
    with open_session(TransportConfig(mode="router", listen=list(args.listen))) as session:
        robot = FakeLimo(session, sim, args.namespace, args.odom_rate_hz, args.cmd_vel_stamped)
        log.info("fake LIMO on %s in %s at %.1fx: keys %sscan, %sodom, %scmd_vel", ", ".join(args.listen), plan.name, args.speed, *[robot.prefix] * 3)
        try:
            robot.run(stop, args.speed)
        finally:
            robot.close()
    log.info("stopped after %d scans and %d commands", robot.scans, robot.commands)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
