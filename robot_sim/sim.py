"""The MuJoCo LIMO behind ``cso_runtime.simulator.Simulator``, with a lockstep and a real-time clock.

Lockstep (eval, tests, training checks): ``step(cmd)`` is one command and advances exactly one
control period (0.25 s = 50 physics steps at 5 ms); runs are deterministic for a seed.
Real time (``up --profile sim``): commands arrive asynchronously through ``set_command(cmd, stamp_s)``
and ``RealTimePacer`` calls ``advance(dt_s)`` against the wall clock, so the watchdog matters.

Sensing. The LiDAR fires at ``SensorConfig.rate_hz`` in simulated time (8 Hz: every 25 physics
steps, i.e. at 0.125 s and at the end of each 0.25 s step). A scan is a pure function of the sensor
pose at its firing time (walls are static) and of (seed, scan index) for the noise, so scans are cast
lazily: ``scan()`` returns the latest fired scan (in lockstep, the one taken at the end of the step,
which the episode runner integrates), ``drain_scans()`` every scan fired since the last drain (what a
real-time service publishes at 8 Hz; a benchmark uses it to map at the full rate). Ranges come from
``mujoco.mj_multiRay`` from the LiDAR site, seeing only wall geoms (geom group 0, robot body excluded).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable

import mujoco
import numpy as np

from cso_runtime.config import ConfigError, RobotConfig, SensorConfig
from cso_runtime.geometry import LaserScan, Pose2D, VelocityCommand, relative_pose, returns_as_float32, wrap_angle_rad
from cso_runtime.scenes import FloorPlan, start_overlap_said
from robot_sim.config import MujocoSimConfig, check_walls_hold, limo_sensor, whole_steps
from robot_sim.limo import ACTUATORS, GROUP_WALLS, JOINTS, LIDAR_SITE, ROBOT_BODY, lateral_feedforward_mps
from robot_sim.scene import world_mjcf

log = logging.getLogger(__name__)

_COLLISION_GAP_STEPS = 20
"""Physics steps without contact (0.1 s at 5 ms) after which a contact counts as a new collision."""
_MAX_PENDING_SCANS = 64
"""Fired scans kept for ``drain_scans`` (8 s at 8 Hz); older ones are dropped and counted."""


def _compose(a: Pose2D, dx: float, dy: float, dyaw: float) -> Pose2D:
    c, s = math.cos(a.yaw_rad), math.sin(a.yaw_rad)
    return Pose2D(a.x_m + c * dx - s * dy, a.y_m + s * dx + c * dy, wrap_angle_rad(a.yaw_rad + dyaw))


class MujocoSimulator:
    """Physics simulation of the LIMO in a floor plan; implements ``cso_runtime.simulator.Simulator``.

    Ground truth (``true_pose``) is for evaluation only; the robot's decisions use ``odometry`` and
    ``sensor_pose`` (odometry composed with the LiDAR mount). The plan's start must be a finite pose on a free cell
    (``FloorPlan.start_cell``, a SceneError otherwise); a body that still overlaps a wall there is warned of
    (``scenes.start_overlap_said``, which ``up`` says before anything starts).
    The rays are cast from ``sensor.mount_x_m`` (no sensor: ``limo_sensor()``, the LIMO's 0.103 m), the mount the
    mapper and the planner take from the same ``SensorConfig``.
    """

    def __init__(
        self,
        plan: FloorPlan,
        sensor: SensorConfig | None = None,
        robot: RobotConfig | None = None,
        seed: int | None = None,
        config: MujocoSimConfig | None = None,
    ) -> None:
        plan.start_cell()  # a SceneError for a start off the plan, in a wall, or not finite (MuJoCo would eject the body)
        self.plan = plan
        self.sensor = sensor or limo_sensor()
        self.robot = robot or RobotConfig()
        self.config = config or MujocoSimConfig()
        self.sensor.validate()
        self.robot.validate()  # its limits become the model's ctrlrange, its size the chassis
        self.config.validate()
        c = self.config
        check_walls_hold(c, self.robot)  # a body too fast for the walls' contact (or the physics step) passes through them
        if self.sensor.rate_hz * c.timestep_s > 1.0:
            raise ConfigError(
                f"sensor.rate_hz ({self.sensor.rate_hz:g} Hz) is above the physics rate ({1.0 / c.timestep_s:g} Hz, timestep_s "
                f"{c.timestep_s:g} s): the LiDAR fires at most once per physics step"
            )
        self.lidar_mount_x_m = c.lidar_mount_for(self.sensor)  # the sensor's own mount, as the mapper and the planner take it
        self.steps_per_control = whole_steps(self.robot.control_period_s, c.timestep_s, "robot.control_period_s")
        self._odom_every = max(1, int(round(1.0 / (c.odometry_rate_hz * c.timestep_s))))
        self._scan_period_steps = 1.0 / (self.sensor.rate_hz * c.timestep_s)

        self.mjcf, self.n_wall_boxes = world_mjcf(plan, self.robot, c, self.lidar_mount_x_m)
        """This simulator's world as a file (walls, floor, the LIMO; qpos0 and keyframe ``start`` at the start pose):
        ``Path("world.xml").write_text(sim.mjcf)`` saves it for ``python -m mujoco.viewer --mjcf world.xml``."""
        # The model stepped here is the same world with qpos0 at the map origin: MuJoCo places the base at
        # body_pos + (qpos - qpos0), which with the start as qpos0 differs from qpos in the last bits, and every
        # episode would drift from the ones run before. reset() puts the LIMO at the start.
        stepped_xml, _ = world_mjcf(plan, self.robot, c, self.lidar_mount_x_m, robot_at_start=False)
        self.model = mujoco.MjModel.from_xml_string(stepped_xml)
        # Its sensors (limo.SENSORS) are for the file's users: the simulator reads qpos and qvel, so it skips computing
        # them (1-2 % of a physics step) but keeps them, as the viewer copies this data into a model of the file's sizes.
        self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        self.data = mujoco.MjData(self.model)
        self._qadr = np.array([self.model.joint(j).qposadr[0] for j in JOINTS])
        self._vadr = np.array([self.model.joint(j).dofadr[0] for j in JOINTS])
        self._act = np.array([self.model.actuator(a).id for a in ACTUATORS])
        self._robot_body = self.model.body(ROBOT_BODY).id
        self._lidar_height_m = float(self.model.site(LIDAR_SITE).pos[2])
        self._geomgroup = np.zeros(6, dtype=np.uint8)
        self._geomgroup[GROUP_WALLS] = 1

        n = max(1, int(round(self.sensor.fov_deg / self.sensor.resolution_deg)))
        fov = math.radians(self.sensor.fov_deg)
        full_ring = self.sensor.fov_deg >= 360.0
        self._angle_min = -math.pi if full_ring else -fov / 2.0
        self._increment = fov / n
        self._n_beams = n if full_ring else n + 1
        self._beam_rel = self._angle_min + self._increment * np.arange(self._n_beams)
        self._ray_vec = np.zeros((self._n_beams, 3))
        self._ray_geom = np.zeros(self._n_beams, dtype=np.int32)
        self._ray_dist = np.zeros(self._n_beams)
        self._lock = threading.RLock()
        self.reset(seed)

    # --- episode ---
    def reset(self, seed: int | None = None) -> None:
        """Robot at rest at the plan's start pose, odometry there too; clocks, watchdog, noise re-seeded."""
        with self._lock:
            seq = np.random.SeedSequence(seed)
            self._scan_entropy = int(seq.generate_state(1)[0])
            self._odom_rng = np.random.default_rng(seq.spawn(1)[0])
            mujoco.mj_resetData(self.model, self.data)
            start = self.plan.start
            self.data.qpos[self._qadr] = (start.x_m, start.y_m, start.yaw_rad)
            mujoco.mj_forward(self.model, self.data)
            # The chassis box against the wall boxes, as the contacts mj_forward just found: from the plan, so that `up`
            # says it before anything starts in these words (scenes.start_overlap_said), not only this log.
            if (overlap := start_overlap_said(self.plan, self.robot.length_m, self.robot.width_m)) is not None:
                log.warning("%s", overlap)
            self._steps = 0
            self.time_s = 0.0
            self._target = VelocityCommand(0.0, 0.0)
            self._command_stamp_s = 0.0
            self._have_command = False
            self.watchdog_stops = 0
            self._watchdog_tripped = False
            self._applied_v = 0.0
            self._applied_w = 0.0
            self.collisions = 0
            self.contact_steps = 0
            self._last_contact_step = -(10**9)
            self.rejected_commands = 0
            self._odom_pose = start
            self._odom_anchor_true = start
            self._scan_index = 0
            self._next_scan_step = 0
            self._fired: deque[tuple[int, float, Pose2D, Pose2D]] = deque(maxlen=_MAX_PENDING_SCANS)
            self.dropped_scans = 0
            self._latest: tuple[int, float, Pose2D, Pose2D] | None = None
            self._latest_scan: LaserScan | None = None
            self._fire_due_scans()

    @property
    def state_lock(self) -> threading.RLock:
        """Held while the physics state changes; a reader of ``data`` from another thread (the viewer) takes it."""
        return self._lock

    # --- poses ---
    def true_pose(self) -> Pose2D:
        with self._lock:
            q = self.data.qpos[self._qadr].copy()
        return Pose2D(float(q[0]), float(q[1]), wrap_angle_rad(float(q[2])))

    def odometry(self) -> Pose2D:
        """Dead reckoning: the last odometry tick plus the (noise-free) motion since then."""
        with self._lock:
            return _compose(self._odom_pose, *relative_pose(self._odom_anchor_true, self.true_pose()))

    def sensor_pose(self) -> Pose2D:
        """The odometry pose of the LiDAR when it took the latest scan (``scan()``): where the mapper puts
        that scan. A sensor whose rate is not a multiple of the control rate (the depth camera's 15 Hz
        against 4 Hz) fired up to one period before the step ended, and the robot has moved and turned
        since; the pose of now would smear every wall it sees across free space while the robot turns."""
        with self._lock:
            if self._latest is not None:
                return self._latest[3]
            return self._odometry_sensor_pose()

    def _odometry_sensor_pose(self) -> Pose2D:
        return self.odometry().compose_offset(self.lidar_mount_x_m)

    def body_velocity(self) -> tuple[float, float, float]:
        """Ground-truth body-frame velocity (forward m/s, left m/s, yaw rad/s)."""
        v = self.data.qvel[self._vadr]
        yaw = float(self.data.qpos[self._qadr[2]])
        c, s = math.cos(yaw), math.sin(yaw)
        return c * v[0] + s * v[1], -s * v[0] + c * v[1], float(v[2])

    @property
    def applied_command(self) -> VelocityCommand:
        """The rate-limited command the servos track now."""
        return VelocityCommand(self._applied_v, self._applied_w)

    # --- control ---
    def set_command(self, command: VelocityCommand, stamp_s: float | None = None) -> bool:
        """Set the velocity target (clamped to the limits), stamped in simulated time (default: now).

        Non-finite commands or stamps are rejected (logged and counted in ``rejected_commands``); returns whether
        the command was accepted. The watchdog stops the robot ``watchdog_s`` after the newest stamp.
        """
        if not (math.isfinite(command.linear_mps) and math.isfinite(command.angular_radps)):
            self.rejected_commands += 1
            log.warning("rejected non-finite velocity command %s", command)
            return False
        if stamp_s is not None and not math.isfinite(stamp_s):  # the watchdog's deadline would be NaN or inf
            self.rejected_commands += 1
            log.warning("rejected velocity command %s with non-finite stamp %s", command, stamp_s)
            return False
        with self._lock:
            stamp = self.time_s if stamp_s is None else float(stamp_s)
            self._target = command.clamped(self.robot.max_linear_mps, self.robot.max_angular_radps)
            self._command_stamp_s = stamp
            self._have_command = True
            return True

    def step(self, command: VelocityCommand) -> None:
        """Lockstep: apply ``command`` for exactly one control period."""
        if not self.set_command(command):
            raise ValueError(f"velocity command must be finite, got {command}")
        self._advance_steps(self.steps_per_control)

    def advance(self, dt_s: float) -> int:
        """Run physics for ``dt_s`` simulated seconds (rounded down to whole steps); returns the steps run."""
        if not dt_s >= 0 or not math.isfinite(dt_s):
            raise ValueError(f"dt_s must be a finite non-negative number, got {dt_s}")
        n = int(math.floor(dt_s / self.config.timestep_s + 1e-9))
        self._advance_steps(n)
        return n

    def _advance_steps(self, n: int) -> None:
        """Run ``n`` physics steps: watchdog, acceleration limits, odometry ticks and LiDAR firings.

        While the command ramps (acceleration limit) the servo targets change every step; otherwise
        MuJoCo runs uninterrupted up to the next event (odometry tick, LiDAR firing, watchdog expiry).
        """
        c = self.config
        dt = c.timestep_s
        dv = c.max_linear_accel_mps2 * dt
        dw = c.max_angular_accel_radps2 * dt
        m, d = self.model, self.data
        ctrl = d.ctrl
        tau = c.actuator_time_constant_s
        i_fwd, i_lat, i_yaw = (int(a) for a in self._act)
        with self._lock:
            remaining = n
            while remaining > 0:
                # Watchdog: the command is live while (now - stamp) <= watchdog_s, checked before each step.
                last_live_step = -1
                if self._have_command:
                    last_live_step = int(math.floor((self._command_stamp_s + c.watchdog_s) / dt + 1e-6))
                if self._steps <= last_live_step:
                    target_v, target_w = self._target.linear_mps, self._target.angular_radps
                    self._watchdog_tripped = False
                else:
                    if self._have_command and not self._watchdog_tripped:
                        self.watchdog_stops += 1
                        self._watchdog_tripped = True
                        log.info("watchdog: no command for %.2f s, stopping", self.time_s - self._command_stamp_s)
                    target_v, target_w = 0.0, 0.0
                if self._applied_v != target_v or self._applied_w != target_w:
                    # Acceleration limits: the applied command moves towards the target at a bounded rate.
                    self._applied_v += min(max(target_v - self._applied_v, -dv), dv)
                    self._applied_w += min(max(target_w - self._applied_w, -dw), dw)
                    k = 1
                else:
                    next_odom = (self._steps // self._odom_every + 1) * self._odom_every
                    k = min(remaining, next_odom - self._steps, max(self._next_scan_step - self._steps, 1))
                    if self._steps <= last_live_step:
                        k = min(k, last_live_step - self._steps + 1)
                ctrl[i_fwd] = self._applied_v
                # Centripetal feed-forward: a P servo holding zero lateral speed while turning would
                # otherwise lag by v * w * tau (1.6 cm/s at full speed; drive_lateral's ctrlrange).
                ctrl[i_lat] = lateral_feedforward_mps(self._applied_v, self._applied_w, tau)
                ctrl[i_yaw] = self._applied_w
                mujoco.mj_step(m, d, k)
                self._steps += k
                remaining -= k
                self.time_s = self._steps * dt
                if d.ncon:  # walls are static and the floor does not collide: any contact is robot-wall
                    self._on_contact(k)
                if self._steps % self._odom_every == 0:
                    self._odometry_tick()
                if self._steps >= self._next_scan_step:
                    self._fire_due_scans()

    def _on_contact(self, steps: int) -> None:
        """Count ``contact_steps`` and ``collisions`` (a contact after at least _COLLISION_GAP_STEPS
        without one: contacts flicker while the body scrapes along a wall). Contacts are sampled at the
        end of each uninterrupted run of physics steps (at most one odometry period, 25 ms)."""
        if self._steps - steps - self._last_contact_step > _COLLISION_GAP_STEPS:
            self.collisions += 1
        self.contact_steps += steps
        self._last_contact_step = self._steps

    def _odometry_tick(self) -> None:
        """Add the base's motion since the last tick to the estimate, with drift noise."""
        c = self.config
        now = self.true_pose()
        dx, dy, dyaw = relative_pose(self._odom_anchor_true, now)
        trans = math.hypot(dx, dy)
        if c.odom_trans_noise_frac > 0 and trans > 0:
            dx, dy = dx + self._odom_rng.normal(0.0, c.odom_trans_noise_frac * trans), dy + self._odom_rng.normal(0.0, c.odom_trans_noise_frac * trans)
        rot_std = c.odom_rot_noise_frac * abs(dyaw) + c.odom_rot_per_trans_noise_radpm * trans
        if rot_std > 0:
            dyaw += self._odom_rng.normal(0.0, rot_std)
        self._odom_pose = _compose(self._odom_pose, dx, dy, dyaw)
        self._odom_anchor_true = now

    # --- LiDAR ---
    def _fire_due_scans(self) -> None:
        while self._steps >= self._next_scan_step:
            pose = self.true_pose().compose_offset(self.lidar_mount_x_m)
            fired = (self._scan_index, self.time_s, pose, self._odometry_sensor_pose())
            if len(self._fired) == self._fired.maxlen:
                self.dropped_scans += 1
            self._fired.append(fired)
            self._latest = fired
            self._latest_scan = None
            self._scan_index += 1
            self._next_scan_step = int(round(self._scan_index * self._scan_period_steps))

    def cast_scan(self, sensor_pose: Pose2D, noise_key: int | None = None, stamp_s: float = 0.0) -> LaserScan:
        """Cast the LiDAR from a true sensor pose; noise seeded by (seed, ``noise_key``) if configured."""
        ang = self._beam_rel + sensor_pose.yaw_rad
        pnt = np.array([sensor_pose.x_m, sensor_pose.y_m, self._lidar_height_m])
        with self._lock:  # the ray buffers are shared
            self._ray_vec[:, 0] = np.cos(ang)
            self._ray_vec[:, 1] = np.sin(ang)
            mujoco.mj_multiRay(
                self.model, self.data, pnt, self._ray_vec.ravel(), self._geomgroup, 1, self._robot_body,
                self._ray_geom, self._ray_dist, None, self._n_beams, self.sensor.range_max_m,
            )  # fmt: skip
            ranges = np.where((self._ray_geom >= 0) & (self._ray_dist <= self.sensor.range_max_m), self._ray_dist, np.inf)
        if self.sensor.range_noise_std_m > 0:
            rng = np.random.default_rng([self._scan_entropy, 0 if noise_key is None else noise_key])
            finite = np.isfinite(ranges)
            ranges[finite] = np.maximum(ranges[finite] + rng.normal(0.0, self.sensor.range_noise_std_m, int(finite.sum())), 0.0)
        ranges32 = returns_as_float32(ranges, self.sensor.range_max_m)
        return LaserScan(self._angle_min, self._increment, self.sensor.range_min_m, self.sensor.range_max_m, ranges32, stamp_s)

    def scan(self) -> LaserScan:
        """The latest scan the LiDAR fired (at ``rate_hz`` in simulated time), in the sensor frame."""
        with self._lock:
            if self._latest_scan is None:
                assert self._latest is not None
                index, stamp, pose, _ = self._latest
                self._latest_scan = self.cast_scan(pose, index, stamp)
            return self._latest_scan

    def drain_scans(self) -> list[tuple[Pose2D, LaserScan]]:
        """Every scan fired since the last drain, oldest first, each with the odometry sensor pose at its
        firing time (what the mapper needs). At most the last 64 are kept; drops are counted."""
        with self._lock:
            out = []
            latest_index = self._latest[0] if self._latest is not None else -1
            for index, stamp, pose, odom_sensor_pose in self._fired:
                scan = self.scan() if index == latest_index else self.cast_scan(pose, index, stamp)
                out.append((odom_sensor_pose, scan))
            self._fired.clear()
            return out


class RealTimePacer:
    """Runs a simulator's ``advance`` against the wall clock (``speed`` x real time).

    ``poll()`` advances simulated time to where the wall clock says it should be; ``run(stop)`` polls
    every ``period_s`` until ``stop`` is set. When the machine falls more than ``max_lag_s`` behind,
    the backlog is dropped (counted in ``overruns``) rather than simulated in a burst.
    """

    def __init__(
        self,
        sim: MujocoSimulator,
        speed: float = 1.0,
        max_lag_s: float = 0.5,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0 < speed < math.inf:
            raise ValueError(f"speed must be positive and finite, got {speed}")
        if not 0 < max_lag_s < math.inf:  # NaN never dropped a backlog, a negative lag dropped every poll's steps
            raise ValueError(f"max_lag_s must be positive and finite, got {max_lag_s}")
        self.sim = sim
        self.speed = speed
        self.max_lag_s = max_lag_s
        self.clock = clock
        self.overruns = 0
        self._anchor_wall_s: float | None = None
        self._anchor_sim_s = 0.0

    def start(self) -> None:
        self._anchor_wall_s = self.clock()
        self._anchor_sim_s = self.sim.time_s

    def poll(self) -> int:
        """Advance the simulation to the wall clock; returns the physics steps run."""
        if self._anchor_wall_s is None:
            self.start()
        assert self._anchor_wall_s is not None
        target = self._anchor_sim_s + (self.clock() - self._anchor_wall_s) * self.speed
        behind = target - self.sim.time_s
        if behind > self.max_lag_s * self.speed:
            self.overruns += 1
            log.warning("real-time simulation %.2f s behind the wall clock; dropping the backlog", behind)
            self.start()
            return 0
        return self.sim.advance(behind) if behind > 0 else 0

    def run(self, stop: threading.Event, period_s: float = 0.01) -> None:
        """Poll until ``stop`` is set (call from a dedicated thread)."""
        self.start()
        while not stop.is_set():
            self.poll()
            stop.wait(period_s)
