"""ROS 2 messages as CDR bytes, for zenoh-bridge-ros2dds and ROS 2 bags: LaserScan, Odometry, Twist, TwistStamped,
OccupancyGrid, PoseStamped, Path, TFMessage and explore_lite-style frontier MarkerArrays.

Encoding and decoding use the rosbags typestore (the CDR payloads carry their 4-byte encapsulation
header), never a hand-written serializer. Conversions follow REP-103/REP-117: +inf (or range_max) is "no return",
-inf "too close" and NaN "invalid"; everything the LaserScan header says is honoured.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from cso_runtime.geometry import (
    UNTURNED_YAW_TOLERANCE_RAD,
    GridGeometry,
    LaserScan,
    Pose2D,
    VelocityCommand,
    no_return_mask,
    rounded_pose,
)

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore
    from rosbags.typesys.stores.ros2_humble import (
        builtin_interfaces__msg__Time,
        geometry_msgs__msg__Point,
        geometry_msgs__msg__Pose,
        geometry_msgs__msg__Quaternion,
        geometry_msgs__msg__Twist,
        geometry_msgs__msg__Vector3,
        std_msgs__msg__ColorRGBA,
        std_msgs__msg__Header,
        visualization_msgs__msg__Marker,
    )

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
PATH = "nav_msgs/msg/Path"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
BOOL = "std_msgs/msg/Bool"


ROS_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$")
"""A relative ROS name (a namespace or topic, no leading slash), as zenoh-bridge-ros2dds turns it into a Zenoh key."""


def is_ros_name(name: str) -> bool:
    """Whether ``name`` (its leading and trailing slashes taken off) is a ROS name that can stand in a Zenoh key."""
    return bool(ROS_NAME.match(name.strip("/")))


FRAME_ID_RULE = "not empty, no leading '/', no spaces"
"""What ``is_frame_id`` asks of a frame id, as an error message says it."""


def is_frame_id(frame: str) -> bool:
    """Whether ``frame`` can be a tf2 frame id (``FRAME_ID_RULE``): tf2 refuses one with a leading ``/``."""
    return bool(frame) and not frame.startswith("/") and not any(c.isspace() for c in frame)


class CdrError(ValueError):
    """A payload is not a valid CDR message of the expected type."""


@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """The ROS 2 Humble message definitions, built once, on first use (rosbags is imported only when ROS is used)."""
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415 - import cost only when ROS is used

    return get_typestore(Stores.ROS2_HUMBLE)


def _types() -> dict[str, Any]:
    return typestore().types


def decode(raw: bytes, typename: str) -> Any:
    """Deserialize CDR (with encapsulation header) into a rosbags message object (of ``typename``'s class)."""
    try:
        return typestore().deserialize_cdr(bytes(raw), typename)
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types; all mean "bad payload"
        raise CdrError(f"not a valid {typename} CDR payload: {exc}") from None


def encode(msg: object, typename: str) -> bytes:
    """A rosbags message object as CDR bytes with the encapsulation header, as ROS 2 and the bridge send it."""
    return bytes(typestore().serialize_cdr(msg, typename))


NS_PER_S = 1_000_000_000


def stamp_ns_from_seconds(stamp_s: float) -> int:
    """A stamp in float seconds (our messages' unit) as integer nanoseconds, to the nearest one: the one place a
    float stamp becomes a ROS time. A stamp already in nanoseconds (a bag's time) goes to ``time_msg`` as it is:
    float seconds near 1.8e9 s are only good to ~240 ns."""
    return round(stamp_s * NS_PER_S)


def time_msg(stamp_ns: int) -> builtin_interfaces__msg__Time:
    """builtin_interfaces/Time of a stamp in integer nanoseconds, exactly (``sec`` + ``nanosec``). A float is a
    TypeError, not a silent misreading of seconds as nanoseconds: ``stamp_ns_from_seconds`` converts one."""
    if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, (int, np.integer)):
        raise TypeError(f"a stamp is integer nanoseconds, not {type(stamp_ns).__name__} (stamp_ns_from_seconds converts seconds)")
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return _types()["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def header_msg(stamp_ns: int, frame_id: str) -> std_msgs__msg__Header:
    """std_msgs/Header of a stamp in integer nanoseconds and a frame."""
    return _types()["std_msgs/msg/Header"](stamp=time_msg(stamp_ns), frame_id=frame_id)


def header_stamp_ns(header: std_msgs__msg__Header) -> int:
    """A header's ``sec`` + ``nanosec`` stamp as integer nanoseconds, exactly."""
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)


def stamp_seconds(header: std_msgs__msg__Header) -> float:
    """A header's ``sec`` + ``nanosec`` stamp as float seconds, the time unit of our own messages."""
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rad) of a quaternion of any non-zero norm: the form without the unit-norm shortcut
    ``1 - 2(y^2 + z^2)``, so a driver's un-normalised orientation still gives its true heading."""
    if not all(math.isfinite(v) for v in (x, y, z, w)) or x * x + y * y + z * z + w * w < 1e-12:
        raise CdrError(f"quaternion ({x}, {y}, {z}, {w}) has no orientation (zero norm or non-finite)")
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def _quaternion(yaw_rad: float) -> geometry_msgs__msg__Quaternion:
    return _types()["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw_rad / 2), w=math.cos(yaw_rad / 2))


@dataclass(frozen=True)
class ScanConversion:
    """A decoded LaserScan and what had to be cleaned: counts of NaN, -inf and out-of-range beams. ``stamp_ns``: the
    header's stamp exactly (``scan.stamp_s`` is it in float seconds), for what is stamped with the scan's time."""

    scan: LaserScan
    frame_id: str
    invalid_beams: int
    too_close_beams: int
    no_return_beams: int
    stamp_ns: int


def laserscan_from_cdr(raw: bytes) -> ScanConversion:
    """sensor_msgs/LaserScan CDR -> our LaserScan, honouring the header's angles and limits.

    NaN (invalid), 0 m (what some drivers send for no reading) and a finite negative reading (no distance: kept, it
    made our ``ScanMsg`` refuse the whole scan) become 0 m, which the mapper and the planner ignore (even with
    ``range_min`` 0); NaN and negative readings are counted ``invalid_beams``. Too close (REP-117: -inf, or a reading below ``range_min``) is something
    there: a reading below ``range_min`` is kept, and -inf becomes the float just below ``range_min``; the mapper
    ignores both, and the planner's stop check counts them (with ``range_min`` 0 there is no such float: 0 m).
    +inf, ``range_max`` itself (how many drivers, the LIMO's among them, report "nothing") and anything beyond become
    +inf (no return: free space up to the max range; ``no_return_mask``).
    """
    msg = decode(raw, LASER_SCAN)
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    values = (msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max)
    if not all(math.isfinite(v) for v in values) or msg.angle_increment == 0.0 or ranges.size == 0:
        raise CdrError("LaserScan header has non-finite angles/limits, a zero increment, or no ranges")
    span = msg.angle_max - msg.angle_min
    expected = int(round(span / msg.angle_increment)) + 1 if math.isfinite(span) else ranges.size
    if abs(expected - ranges.size) > 1:
        raise CdrError(f"LaserScan has {ranges.size} ranges but its angles imply {expected}")
    invalid = np.isnan(ranges) | (np.isfinite(ranges) & (ranges < 0.0))
    too_close = ~invalid & (ranges < msg.range_min)
    no_return = no_return_mask(ranges, msg.range_max)
    nearer_than_range_min_m = float(np.nextafter(np.float32(msg.range_min), np.float32(0.0)))  # 0 when range_min is 0
    clean = np.where(invalid, 0.0, np.where(no_return, np.inf, np.where(np.isneginf(ranges), nearer_than_range_min_m, ranges)))
    if msg.angle_increment < 0:  # beams listed clockwise: reverse so angles increase
        clean = clean[::-1]
        angle_min, increment = msg.angle_min + msg.angle_increment * (ranges.size - 1), -msg.angle_increment
    else:
        angle_min, increment = msg.angle_min, msg.angle_increment
    scan = LaserScan(float(angle_min), float(increment), float(msg.range_min), float(msg.range_max), clean.astype(np.float32), stamp_seconds(msg.header))
    return ScanConversion(scan, msg.header.frame_id, int(invalid.sum()), int(too_close.sum()), int(no_return.sum()), header_stamp_ns(msg.header))


def laserscan_to_cdr(scan: LaserScan, stamp_ns: int, frame_id: str = "laser", scan_time_s: float = 0.0) -> bytes:
    """Our LaserScan, stamped ``stamp_ns`` (not its ``stamp_s``) -> sensor_msgs/LaserScan CDR. A 0 m beam, our "no
    reading" (how ``laserscan_from_cdr`` keeps the robot's NaN beams), goes out as NaN, REP-117's invalid
    measurement, not as a range; ``inf`` stays "no return", and a too-close beam stays below ``range_min``.
    ``scan_time_s``: sensor_msgs/LaserScan's ``scan_time``, the time between scans (0: unknown). ``time_increment``
    (the time between two beams, by which tools such as laser_geometry's projector spread the beams over the robot's
    motion) is 0: the scan is instantaneous as we hold it, every beam cast at one instant (the simulator's), and the
    mapper integrates a real robot's scan at the one sensor pose of its stamp too, so a bag's consumer puts each beam
    where the mapper did."""
    n = len(scan.ranges_m)
    ranges = np.asarray(scan.ranges_m, dtype=np.float32)
    ranges = np.where(ranges == 0.0, np.float32(np.nan), ranges)
    msg = _types()[LASER_SCAN](
        header=header_msg(stamp_ns, frame_id),
        angle_min=float(scan.angle_min_rad),
        angle_max=float(scan.angle_min_rad + scan.angle_increment_rad * (n - 1)),
        angle_increment=float(scan.angle_increment_rad),
        time_increment=0.0,
        scan_time=float(scan_time_s),
        range_min=float(scan.range_min_m),
        range_max=float(scan.range_max_m),
        ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32),
    )
    return encode(msg, LASER_SCAN)


@dataclass(frozen=True)
class OdometrySample:
    """A decoded nav_msgs/Odometry in our units: planar pose, body-frame velocity, stamp (s) and its two frames."""

    pose: Pose2D
    velocity: VelocityCommand
    stamp_s: float
    frame_id: str
    child_frame_id: str


def odometry_from_cdr(raw: bytes) -> OdometrySample:
    """nav_msgs/Odometry CDR -> pose, twist and stamp (a non-finite value is a CdrError, never a pose)."""
    msg = decode(raw, ODOMETRY)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    values = (p.x, p.y, q.x, q.y, q.z, q.w, msg.twist.twist.linear.x, msg.twist.twist.angular.z)
    if not all(math.isfinite(v) for v in values):
        raise CdrError("Odometry has non-finite values")
    pose = Pose2D(float(p.x), float(p.y), yaw_from_quaternion(q.x, q.y, q.z, q.w))
    vel = VelocityCommand(float(msg.twist.twist.linear.x), float(msg.twist.twist.angular.z))
    return OdometrySample(pose, vel, stamp_seconds(msg.header), msg.header.frame_id, msg.child_frame_id)


ODOMETRY_COVARIANCE_DIAGONAL = (0.1, 0.1, 0.1, 1.0, 1.0, 1.0)
"""The diagonal of an Odometry's pose and twist covariances that ``odometry_to_cdr`` writes, off-diagonal zero: x, y,
z (m^2; the twist's (m/s)^2) and roll, pitch, yaw (rad^2; (rad/s)^2). The pose's is the one AgileX's LIMO ROS 2 driver
publishes (limo_base ``LimoDriver::publishOdometry``); that driver leaves the twist's all zero, which filters such as
robot_localization refuse as no uncertainty at all, so the twist gets the same diagonal. Nominal values, not measured
on our robot or simulator."""


def odometry_to_cdr(
    pose: Pose2D, velocity: VelocityCommand, stamp_ns: int, frame_id: str = "odom", child_frame_id: str = "base_link",
    covariance_diagonal: tuple[float, ...] = ODOMETRY_COVARIANCE_DIAGONAL,
    twist_covariance_diagonal: tuple[float, ...] | None = None,
) -> bytes:  # fmt: skip
    """Our pose and velocity -> nav_msgs/Odometry CDR, as a bag's ``/odom`` holds it: pose and twist covariances both
    diagonal, ``covariance_diagonal`` (x, y, z, roll, pitch, yaw); the twist's is ``twist_covariance_diagonal``, the
    pose's when None (all zeros: what AgileX's LIMO driver sends)."""
    twist_diagonal = covariance_diagonal if twist_covariance_diagonal is None else twist_covariance_diagonal
    for name, diagonal in (("covariance_diagonal", covariance_diagonal), ("twist_covariance_diagonal", twist_diagonal)):
        if len(diagonal) != 6:
            raise ValueError(f"{name}: expected 6 variances (x, y, z, roll, pitch, yaw), got {len(diagonal)}")
    t = _types()
    point = t["geometry_msgs/msg/Point"](x=pose.x_m, y=pose.y_m, z=0.0)
    cov = np.diag(np.asarray(covariance_diagonal, dtype=np.float64)).ravel()
    twist_cov = np.diag(np.asarray(twist_diagonal, dtype=np.float64)).ravel()
    msg = t[ODOMETRY](
        header=header_msg(stamp_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=t["geometry_msgs/msg/Pose"](position=point, orientation=_quaternion(pose.yaw_rad)), covariance=cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=_twist(velocity), covariance=twist_cov),
    )
    return encode(msg, ODOMETRY)


def _twist(cmd: VelocityCommand) -> geometry_msgs__msg__Twist:
    t = _types()
    v3 = t["geometry_msgs/msg/Vector3"]
    return t[TWIST](linear=v3(x=float(cmd.linear_mps), y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=float(cmd.angular_radps)))


def twist_to_cdr(cmd: VelocityCommand) -> bytes:
    """Our velocity command -> geometry_msgs/Twist CDR for the LIMO's ``cmd_vel``."""
    return encode(_twist(cmd), TWIST)


def _command_of(twist: geometry_msgs__msg__Twist) -> VelocityCommand:
    if not (math.isfinite(twist.linear.x) and math.isfinite(twist.angular.z)):
        raise CdrError("Twist has non-finite values")
    return VelocityCommand(float(twist.linear.x), float(twist.angular.z))


def twist_from_cdr(raw: bytes) -> VelocityCommand:
    """geometry_msgs/Twist CDR -> our velocity command (forward m/s, yaw rad/s); a non-finite value is a CdrError."""
    return _command_of(decode(raw, TWIST))


def twist_stamped_to_cdr(cmd: VelocityCommand, stamp_ns: int, frame_id: str = "base_link") -> bytes:
    """Our velocity command -> geometry_msgs/TwistStamped CDR (``header``, then ``twist``), what ROS 2 Jazzy's
    diff_drive_controller takes on its ``cmd_vel`` and Nav2 sends with ``enable_stamped_cmd_vel``: stamped
    ``stamp_ns`` in the robot's clock, ``frame_id`` its base frame, as Nav2's controller_server stamps its own."""
    return encode(_types()[TWIST_STAMPED](header=header_msg(stamp_ns, frame_id), twist=_twist(cmd)), TWIST_STAMPED)


def twist_stamped_from_cdr(raw: bytes) -> tuple[VelocityCommand, int, str]:
    """geometry_msgs/TwistStamped CDR -> our velocity command, its stamp (integer ns) and frame_id."""
    msg = decode(raw, TWIST_STAMPED)
    return _command_of(msg.twist), header_stamp_ns(msg.header), str(msg.header.frame_id)


def bool_to_cdr(value: bool) -> bytes:
    """std_msgs/Bool CDR (explore_lite's ``explore/resume``: false pauses, true resumes)."""
    return encode(_types()[BOOL](data=bool(value)), BOOL)


def bool_from_cdr(raw: bytes) -> bool:
    """std_msgs/Bool CDR -> its ``data``; a CdrError for anything else."""
    return bool(decode(raw, BOOL).data)


def occupancy_grid_to_cdr(grid: np.ndarray, geometry: GridGeometry, stamp_ns: int, frame_id: str = "map", origin: Pose2D | None = None) -> bytes:
    """int8 grid (-1/0/100, row 0 at the origin) -> nav_msgs/OccupancyGrid CDR. ``origin``: the pose of cell (0, 0)'s
    corner in ``frame_id`` (``GridGeometry.corner_pose``: a yaw turns the grid, as map_server turns a map by its
    ``origin``'s); None: ``geometry``'s corner, unturned (``geometry`` is in ``frame_id``). Either is written
    ``rounded_pose``, as a map_server YAML's ``origin`` (``map_files.save_map``): ``-5.275``, not the float sum's
    ``-5.2749999999999995``."""
    t = _types()
    grid = np.asarray(grid, dtype=np.int8)
    if grid.shape != tuple(geometry.shape):
        raise ValueError("grid and geometry shapes differ")
    corner = rounded_pose(geometry.corner_pose() if origin is None else origin)
    origin_msg = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=corner.x_m, y=corner.y_m, z=0.0), orientation=_quaternion(corner.yaw_rad)
    )
    info = t["nav_msgs/msg/MapMetaData"](
        map_load_time=time_msg(stamp_ns), resolution=float(geometry.resolution_m), width=int(geometry.shape[1]), height=int(geometry.shape[0]), origin=origin_msg
    )
    msg = t[OCCUPANCY_GRID](header=header_msg(stamp_ns, frame_id), info=info, data=grid.ravel())
    return encode(msg, OCCUPANCY_GRID)


MAP_QUATERNION_NORM_TOLERANCE = 1e-2
"""How far from 1 the squared norm of an OccupancyGrid's ``info.origin.orientation`` may be: tf2's and RViz 2's own
tolerance for a quaternion (tf2 ``QUATERNION_NORMALIZATION_TOLERANCE``, rviz_common ``validateQuaternions``), so a map
they place is read; beyond it the quaternion is bad input, refused."""


def _map_origin(origin: geometry_msgs__msg__Pose) -> Pose2D:
    """An OccupancyGrid's ``info.origin`` as the planar pose of cell (0, 0)'s corner: a CdrError, saying what was
    given, for a non-finite position or orientation, a quaternion off unit norm (``MAP_QUATERNION_NORM_TOLERANCE``), or
    one that tilts the grid out of the plane (roll or pitch beyond ``UNTURNED_YAW_TOLERANCE_RAD``); a yaw within
    ``UNTURNED_YAW_TOLERANCE_RAD`` is 0. ``z`` is not read: a grid lifted off the floor lies over the same cells."""
    p, q = origin.position, origin.orientation
    if not (math.isfinite(p.x) and math.isfinite(p.y)):
        raise CdrError(f"OccupancyGrid has a non-finite origin position ({p.x}, {p.y})")
    x, y, z, w = (float(v) for v in (q.x, q.y, q.z, q.w))
    if not all(math.isfinite(v) for v in (x, y, z, w)):
        raise CdrError(f"OccupancyGrid has a non-finite origin orientation ({x}, {y}, {z}, {w})")
    norm2 = x * x + y * y + z * z + w * w
    if abs(norm2 - 1.0) > MAP_QUATERNION_NORM_TOLERANCE:
        raise CdrError(
            f"OccupancyGrid origin orientation ({x}, {y}, {z}, {w}) is not a unit quaternion (squared norm {norm2};"
            f" tf2 and RViz take 1 +- {MAP_QUATERNION_NORM_TOLERANCE})"
        )
    tilt_rad = 2.0 * math.atan2(math.hypot(x, y), math.hypot(z, w))  # the swing of the grid's normal away from z
    if tilt_rad > UNTURNED_YAW_TOLERANCE_RAD:
        raise CdrError(
            f"OccupancyGrid origin orientation ({x}, {y}, {z}, {w}) tilts the grid out of the plane by {tilt_rad:.6g} rad"
            f" (roll or pitch): a grid here is planar, turned about z only (within +-{UNTURNED_YAW_TOLERANCE_RAD} rad)"
        )
    yaw_rad = yaw_from_quaternion(x, y, z, w)
    return Pose2D(float(p.x), float(p.y), 0.0 if abs(yaw_rad) <= UNTURNED_YAW_TOLERANCE_RAD else yaw_rad)


def occupancy_grid_and_origin_from_cdr(raw: bytes) -> tuple[np.ndarray, GridGeometry, Pose2D]:
    """nav_msgs/OccupancyGrid CDR -> int8 grid (row 0 at the origin), its geometry in the grid's own frame (cell
    (0, 0)'s corner at (0, 0), rows along y) and ``info.origin``, that corner's pose in the message's frame, yaw
    included (map_server's counterclockwise turn of a map by its YAML ``origin``): ``occupancy_grid_to_cdr``'s
    ``origin`` read back; a point p of the grid's frame is at ``compose_xy(origin, p)`` there. A yaw within
    ``UNTURNED_YAW_TOLERANCE_RAD`` is 0. A CdrError for a bad payload, a resolution that is not a positive finite
    number, or an origin that places the grid nowhere (``_map_origin``: NaN, a non-unit or tilting quaternion)."""
    msg = decode(raw, OCCUPANCY_GRID)
    h, w = int(msg.info.height), int(msg.info.width)
    data = np.asarray(msg.data, dtype=np.int8)
    if data.size != h * w:
        raise CdrError(f"OccupancyGrid has {data.size} cells, expected {h} x {w}")
    resolution_m = float(msg.info.resolution)
    if not (math.isfinite(resolution_m) and resolution_m > 0):
        raise CdrError(f"OccupancyGrid resolution must be a positive finite number, got {resolution_m}")
    return data.reshape(h, w), GridGeometry(resolution_m, (h, w)), _map_origin(msg.info.origin)


def occupancy_grid_from_cdr(raw: bytes) -> tuple[np.ndarray, GridGeometry]:
    """nav_msgs/OccupancyGrid CDR -> int8 grid (row 0 at the origin) and where it lies in the message's frame:
    ``occupancy_grid_to_cdr`` read back. A ``GridGeometry`` is axis-aligned, so a map whose origin turns it (a yaw
    beyond ``UNTURNED_YAW_TOLERANCE_RAD``, as map_server sends a map whose YAML ``origin`` has one) is a CdrError
    naming the yaw, not a grid placed unturned; ``occupancy_grid_and_origin_from_cdr`` reads it (and says what else is
    refused: a NaN or non-unit quaternion among them)."""
    grid, own, origin = occupancy_grid_and_origin_from_cdr(raw)
    if origin.yaw_rad != 0.0:
        raise CdrError(
            f"OccupancyGrid origin turns the grid by yaw {origin.yaw_rad} rad: occupancy_grid_from_cdr gives an"
            f" axis-aligned grid, its origin's yaw within +-{UNTURNED_YAW_TOLERANCE_RAD} rad;"
            " occupancy_grid_and_origin_from_cdr reads it, the grid in its own frame and its corner's pose, the yaw included"
        )
    return grid, GridGeometry(own.resolution_m, own.shape, origin.x_m, origin.y_m)


def pose_stamped_to_cdr(x_m: float, y_m: float, yaw_rad: float, stamp_ns: int, frame_id: str = "map") -> bytes:
    """A planar goal pose (m, rad) -> geometry_msgs/PoseStamped CDR, as the ROS 2 bridge and bags publish the goal."""
    t = _types()
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=x_m, y=y_m, z=0.0), orientation=_quaternion(yaw_rad))
    return encode(t[POSE_STAMPED](header=header_msg(stamp_ns, frame_id), pose=pose), POSE_STAMPED)


def _segment_headings(xy: np.ndarray) -> np.ndarray:
    """The heading (rad) of each step of a polyline; a step of no length (a repeated point) keeps the heading of the
    step before it (the first ones, of the step after), not atan2(0, 0) = 0; all 0 when no step has a length."""
    d = np.diff(xy, axis=0)
    moved = np.hypot(d[:, 0], d[:, 1]) > 0
    if not moved.any():
        return np.zeros(len(d))
    last_move = np.maximum.accumulate(np.where(moved, np.arange(len(d)), -1))
    return np.arctan2(d[:, 1], d[:, 0])[np.where(last_move >= 0, last_move, int(np.argmax(moved)))]


def path_to_cdr(path_xy_m: np.ndarray, stamp_ns: int, frame_id: str = "map") -> bytes:
    """A planned path (n x 2 metres, robot first) -> nav_msgs/Path CDR, each pose facing the next point (the last
    one as the one before it)."""
    t = _types()
    xy = np.asarray(path_xy_m, dtype=float).reshape(-1, 2)
    yaws = np.append(_segment_headings(xy), 0.0)[: len(xy)]
    if len(xy) > 1:
        yaws[-1] = yaws[-2]
    poses = [
        t[POSE_STAMPED](
            header=header_msg(stamp_ns, frame_id),
            pose=t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0), orientation=_quaternion(float(yaw))),
        )
        for (x, y), yaw in zip(xy, yaws)
    ]
    return encode(t[PATH](header=header_msg(stamp_ns, frame_id), poses=poses), PATH)


def transforms_to_cdr(transforms: list[tuple[str, str, Pose2D]], stamp_ns: int) -> bytes:
    """Planar transforms (parent frame, child frame, the child's pose in the parent) -> tf2_msgs/TFMessage CDR."""
    t = _types()
    v3 = t["geometry_msgs/msg/Vector3"]
    stamped = [
        t["geometry_msgs/msg/TransformStamped"](
            header=header_msg(stamp_ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](translation=v3(x=float(p.x_m), y=float(p.y_m), z=0.0), rotation=_quaternion(float(p.yaw_rad))),
        )
        for parent, child, p in transforms
    ]
    return encode(t[TF_MESSAGE](transforms=stamped), TF_MESSAGE)


def pose_stamped_from_cdr(raw: bytes) -> tuple[Pose2D, float]:
    """geometry_msgs/PoseStamped CDR -> planar pose (m, rad) and stamp (s): ``pose_stamped_to_cdr`` read back."""
    msg = decode(raw, POSE_STAMPED)
    p, q = msg.pose.position, msg.pose.orientation
    if not (math.isfinite(p.x) and math.isfinite(p.y)):
        raise CdrError("PoseStamped has a non-finite position")
    return Pose2D(float(p.x), float(p.y), yaw_from_quaternion(q.x, q.y, q.z, q.w)), stamp_seconds(msg.header)


def frontier_markers_to_cdr(frontier_points_xy_m: list[np.ndarray], goal_xy_m: list[tuple[float, float]], stamp_ns: int, frame_id: str = "map") -> bytes:
    """explore_lite's frontier visualisation: one POINTS marker per frontier cluster (namespace
    ``frontiers``) and one SPHERE at each cluster's goal (namespace ``frontiers_goals``); a DELETEALL
    first clears the previous set."""
    t = _types()
    marker_t, point_t = t["visualization_msgs/msg/Marker"], t["geometry_msgs/msg/Point"]
    color_t, vec_t = t["std_msgs/msg/ColorRGBA"], t["geometry_msgs/msg/Vector3"]
    dur = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    identity = t["geometry_msgs/msg/Pose"](position=point_t(x=0.0, y=0.0, z=0.0), orientation=_quaternion(0.0))

    def marker(
        ns: str, mid: int, mtype: int, action: int, pose: geometry_msgs__msg__Pose, scale: geometry_msgs__msg__Vector3,
        color: std_msgs__msg__ColorRGBA, points: list[geometry_msgs__msg__Point],
    ) -> visualization_msgs__msg__Marker:
        return marker_t(
            header=header_msg(stamp_ns, frame_id), ns=ns, id=mid, type=mtype, action=action, pose=pose,
            scale=scale, color=color, lifetime=dur, frame_locked=False, points=points, colors=[],
            texture_resource="", texture=t["sensor_msgs/msg/CompressedImage"](header=header_msg(stamp_ns, frame_id), format="", data=np.zeros(0, dtype=np.uint8)),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, dtype=np.uint8)),
            mesh_use_embedded_materials=False,
        )

    # DELETEALL with no namespace: RViz 2 then clears every namespace (with one, only that one: the goal spheres
    # of clusters that have gone would stay).
    markers = [marker("", 0, marker_t.POINTS, marker_t.DELETEALL, identity, vec_t(x=0.0, y=0.0, z=0.0), color_t(r=0.0, g=0.0, b=0.0, a=0.0), [])]
    for i, pts in enumerate(frontier_points_xy_m):
        points = [point_t(x=float(x), y=float(y), z=0.0) for x, y in np.asarray(pts, dtype=float).reshape(-1, 2)]
        markers.append(marker("frontiers", i + 1, marker_t.POINTS, marker_t.ADD, identity, vec_t(x=0.05, y=0.05, z=0.05), color_t(r=0.0, g=0.0, b=1.0, a=1.0), points))
    for i, (x, y) in enumerate(goal_xy_m):
        pose = t["geometry_msgs/msg/Pose"](position=point_t(x=float(x), y=float(y), z=0.0), orientation=_quaternion(0.0))
        markers.append(marker("frontiers_goals", i + 1, marker_t.SPHERE, marker_t.ADD, pose, vec_t(x=0.2, y=0.2, z=0.2), color_t(r=0.0, g=1.0, b=0.0, a=1.0), []))
    return encode(t[MARKER_ARRAY](markers=markers), MARKER_ARRAY)
