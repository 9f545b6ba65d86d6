"""ROS 2 CDR conversions: bytes made by the rosbags library, round trips, REP-117 range handling."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from cso_runtime import ros2_cdr as cdr
from cso_runtime.geometry import UNTURNED_YAW_TOLERANCE_RAD, GridGeometry, LaserScan, Pose2D, VelocityCommand, compose_xy


def limo_scan_bytes(ranges, angle_min=-math.pi / 2, angle_max=math.pi / 2, range_min=0.1, range_max=8.0):
    """A LaserScan as the real LIMO publishes it, serialized by rosbags (not by our encoder)."""
    ts = cdr.typestore()
    t = ts.types
    n = len(ranges)
    msg = t[cdr.LASER_SCAN](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=12, nanosec=500_000_000), frame_id="laser_link"),
        angle_min=angle_min, angle_max=angle_max, angle_increment=(angle_max - angle_min) / (n - 1),
        time_increment=0.0, scan_time=0.125, range_min=range_min, range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float32), intensities=np.zeros(0, dtype=np.float32),
    )
    return bytes(ts.serialize_cdr(msg, cdr.LASER_SCAN))


def test_limo_front_scan_is_decoded_with_its_own_angles():
    raw = limo_scan_bytes([1.0] * 181)
    assert raw[:2] in (b"\x00\x01", b"\x00\x00")  # CDR encapsulation header
    conv = cdr.laserscan_from_cdr(raw)
    assert conv.frame_id == "laser_link" and conv.scan.stamp_s == pytest.approx(12.5)
    assert conv.scan.angles_rad[0] == pytest.approx(-math.pi / 2) and conv.scan.angles_rad[-1] == pytest.approx(math.pi / 2, abs=1e-5)
    assert conv.scan.range_max_m == 8.0


def test_other_angle_range_nan_and_inf_are_handled():
    ranges = [np.nan, -np.inf, 0.05, 2.0, np.inf, 12.0]
    conv = cdr.laserscan_from_cdr(limo_scan_bytes(ranges, angle_min=-0.5, angle_max=0.5, range_min=0.1, range_max=10.0))
    assert conv.scan.angle_min_rad == pytest.approx(-0.5)
    r = conv.scan.ranges_m
    assert r[0] == 0.0  # invalid: no reading
    assert 0.0 < r[1] < 0.1 and r[1] == pytest.approx(0.1) and r[2] == pytest.approx(0.05)  # too close: something there
    assert r[3] == pytest.approx(2.0) and np.isinf(r[4]) and np.isinf(r[5])  # beyond range_max: no return
    assert (conv.invalid_beams, conv.too_close_beams, conv.no_return_beams) == (1, 2, 2)
    conv.scan.validate()  # no NaN reaches the mapper


def test_a_beam_at_range_max_is_no_return_and_draws_no_wall():
    """The LIMO's driver reports "nothing" as range_max itself: taken as a return, every scan drew a ring of wall
    at 8 m. It is decoded as +inf (no return), counted, and clears free space up to range_max."""
    from cso_runtime.occupancy import OccupancyMap

    conv = cdr.laserscan_from_cdr(limo_scan_bytes([8.0, 8.0, 7.5], angle_min=-0.1, angle_max=0.1, range_min=0.1, range_max=8.0))
    assert np.isinf(conv.scan.ranges_m[:2]).all() and conv.scan.ranges_m[2] == pytest.approx(7.5)
    assert conv.no_return_beams == 2
    g = GridGeometry(0.05, (400, 400))
    occupancy = OccupancyMap(g)
    occupancy.integrate_scan(Pose2D(1.0, 10.0, 0.0), conv.scan)
    hits = np.argwhere(occupancy.occupied)
    assert len(hits) == 1  # the 7.5 m return only
    assert occupancy.open[g.world_to_cell(1.0 + 7.9 * math.cos(-0.1), 10.0 + 7.9 * math.sin(-0.1))]


def test_too_close_beams_stop_the_robot_but_mark_nothing_on_the_map():
    """REP-117's -inf (and a reading below range_min) is an object too close to measure: the bridge passed it on
    as 0 m, no reading, so the planner's stop check drove into what the LiDAR said was right in front."""
    from cso_runtime.config import PlannerConfig, RobotConfig
    from cso_runtime.occupancy import OccupancyMap
    from cso_runtime.planner import PathFollower

    follower = PathFollower(RobotConfig(), PlannerConfig(), sensor_mount_x_m=0.103)
    for too_close in (-np.inf, 0.08):
        ranges = [np.inf, too_close, np.inf]  # straight ahead, nothing else in view
        conv = cdr.laserscan_from_cdr(limo_scan_bytes(ranges, angle_min=-0.1, angle_max=0.1, range_min=0.1, range_max=8.0))
        travel_m, _ = follower.clearance_ahead(conv.scan)
        assert travel_m < 0.1, f"{too_close}: the obstacle right in front is not seen ({travel_m} m to drive)"
        occupancy = OccupancyMap(GridGeometry(0.05, (100, 100)))
        occupancy.integrate_scan(Pose2D(2.5, 2.5, 0.0), conv.scan)
        assert not occupancy.occupied.any()
    clear = cdr.laserscan_from_cdr(limo_scan_bytes([np.inf, np.nan, 0.0], angle_min=-0.1, angle_max=0.1, range_min=0.1, range_max=8.0))
    assert follower.clearance_ahead(clear.scan)[0] == math.inf  # NaN and 0 m are no reading


def test_invalid_beams_of_a_scan_with_range_min_zero_mark_nothing_on_the_map():
    """REP-117 allows range_min 0: the NaN and -inf beams it decodes to 0 m must still be ignored, not
    become an obstacle in the robot's own cell; the beam with a real return still marks its wall."""
    from cso_runtime.occupancy import OccupancyMap

    ranges = [np.nan, -np.inf, 2.0, np.inf]
    conv = cdr.laserscan_from_cdr(limo_scan_bytes(ranges, angle_min=-0.3, angle_max=0.3, range_min=0.0, range_max=8.0))
    assert conv.scan.range_min_m == 0.0 and conv.invalid_beams == 1 and conv.too_close_beams == 1
    g = GridGeometry(0.05, (200, 200))
    occupancy = OccupancyMap(g)
    occupancy.integrate_scan(Pose2D(5.0, 5.0, 0.0), conv.scan)
    hits = np.argwhere(occupancy.occupied)
    assert len(hits) == 1
    hy, hx = g.world_to_cell(5.0 + 2.0 * math.cos(0.1), 5.0 + 2.0 * math.sin(0.1))
    assert tuple(hits[0]) == (int(hy), int(hx))


def test_a_negative_reading_is_one_invalid_beam_not_a_scan_the_bridge_drops():
    """A finite negative range (a driver's "no reading", or garbage) was kept as "below range_min": our ScanMsg
    refuses negative ranges, so the ROS 2 bridge dropped the whole scan (``ros_scan:invalid``) for one such beam.
    It is invalid, 0 m (no reading), counted with the NaNs; the scan's other beams go on to the mapper."""
    from cso_runtime.messages import ScanMsg, decode, encode

    conv = cdr.laserscan_from_cdr(limo_scan_bytes([2.0, -1.0, 0.05, np.nan], angle_min=-0.3, angle_max=0.3, range_min=0.1))
    assert conv.scan.ranges_m[0] == pytest.approx(2.0) and conv.scan.ranges_m[1] == 0.0 and conv.scan.ranges_m[3] == 0.0
    assert (conv.invalid_beams, conv.too_close_beams) == (2, 1)
    decode(encode(ScanMsg(0, conv.scan, Pose2D(0.0, 0.0, 0.0))), ScanMsg)  # what the bridge checks before it publishes


@pytest.mark.parametrize(
    ("angle_min", "angle_max", "why"),
    [(-0.5, 0.5, "7 ranges but its angles imply 3"), (0.5, 0.5, "a zero increment")],
    ids=["more-beams-than-angles", "zero-increment"],
)
def test_a_scan_whose_header_does_not_fit_its_ranges_is_refused(angle_min, angle_max, why):
    """The bridge drops and counts (``ros_scan:bad_cdr``) a scan whose angles imply another number of beams, or that
    has a zero increment, rather than spread its ranges over the wrong angles."""
    raw = limo_scan_bytes([1.0] * 3, angle_min=angle_min, angle_max=angle_max)
    if angle_min != angle_max:  # the header of 3 beams over [-0.5, 0.5], sent with 7 ranges
        ts = cdr.typestore()
        msg = cdr.decode(raw, cdr.LASER_SCAN)
        msg.ranges = np.ones(7, dtype=np.float32)
        raw = bytes(ts.serialize_cdr(msg, cdr.LASER_SCAN))
    with pytest.raises(cdr.CdrError, match=why):
        cdr.laserscan_from_cdr(raw)


def test_clockwise_scan_is_reordered():
    conv = cdr.laserscan_from_cdr(limo_scan_bytes([1.0, 2.0, 3.0], angle_min=0.5, angle_max=-0.5))
    assert conv.scan.angle_increment_rad > 0
    assert conv.scan.angles_rad[0] == pytest.approx(-0.5) and conv.scan.ranges_m[0] == pytest.approx(3.0)


def test_laserscan_round_trip():
    scan = LaserScan(-1.0, 0.01, 0.1, 8.0, np.linspace(0.5, 7.5, 201).astype(np.float32), 3.25)
    conv = cdr.laserscan_from_cdr(cdr.laserscan_to_cdr(scan, 3_250_000_000))
    back = conv.scan
    np.testing.assert_allclose(back.ranges_m, scan.ranges_m)
    assert back.angle_min_rad == pytest.approx(-1.0) and back.stamp_s == pytest.approx(3.25) and conv.stamp_ns == 3_250_000_000


def test_beams_with_no_reading_go_to_ros_as_nan_and_no_return_as_inf():
    """The robot's NaN beams reach our scans as 0 m ("no reading"); an exported bag and the Foxglove bridge wrote
    them back as ranges of 0.0 m. REP-117 has NaN for an invalid measurement (+inf stays no return), so a ROS tool
    that does not check range_min takes no 0 m obstacle at the sensor. Too-close beams go out below range_min."""
    conv = cdr.laserscan_from_cdr(limo_scan_bytes([np.nan, -np.inf, 0.05, 2.0, np.inf], angle_min=-0.4, angle_max=0.4))
    out = cdr.decode(cdr.laserscan_to_cdr(conv.scan, 1_000_000_000), cdr.LASER_SCAN)
    r = np.asarray(out.ranges)
    assert np.isnan(r[0]) and 0.0 < r[1] < 0.1 and r[2] == pytest.approx(0.05), r  # range_min 0.1: ROS drops r[1:3]
    assert r[3] == pytest.approx(2.0) and np.isposinf(r[4]), r
    assert cdr.laserscan_from_cdr(cdr.laserscan_to_cdr(conv.scan, 1_000_000_000)).scan.ranges_m.tolist() == conv.scan.ranges_m.tolist()


def test_odometry_and_twist_round_trip():
    raw = cdr.odometry_to_cdr(Pose2D(1.5, -2.0, 2.5), VelocityCommand(0.4, -0.3), 7_125_000_000)
    odo = cdr.odometry_from_cdr(raw)
    assert odo.pose.x_m == pytest.approx(1.5) and odo.pose.y_m == pytest.approx(-2.0) and odo.pose.yaw_rad == pytest.approx(2.5)
    assert odo.velocity.linear_mps == pytest.approx(0.4) and odo.stamp_s == pytest.approx(7.125)
    assert odo.frame_id == "odom" and odo.child_frame_id == "base_link"
    cmd = cdr.twist_from_cdr(cdr.twist_to_cdr(VelocityCommand(0.8, 0.5)))
    assert cmd == VelocityCommand(0.8, 0.5)


def test_odometry_twist_covariance_and_scan_time_are_the_callers():
    """The fake LIMO sends odometry with the LIMO driver's all-zero twist covariance and scans with their period, through
    these encoders (one LaserScan / Odometry encoder in the project, not a second one in the fake robot)."""
    raw = cdr.odometry_to_cdr(Pose2D(0.0, 0.0, 0.0), VelocityCommand(0.1, 0.0), 0, twist_covariance_diagonal=(0.0,) * 6)
    odom = cdr.decode(raw, cdr.ODOMETRY)
    np.testing.assert_array_equal(np.asarray(odom.pose.covariance).reshape(6, 6), np.diag(cdr.ODOMETRY_COVARIANCE_DIAGONAL))
    np.testing.assert_array_equal(odom.twist.covariance, np.zeros(36))
    default = cdr.decode(cdr.odometry_to_cdr(Pose2D(0.0, 0.0, 0.0), VelocityCommand(0.1, 0.0), 0), cdr.ODOMETRY)
    np.testing.assert_array_equal(default.twist.covariance, default.pose.covariance)
    with pytest.raises(ValueError, match="twist_covariance_diagonal"):
        cdr.odometry_to_cdr(Pose2D(0.0, 0.0, 0.0), VelocityCommand(0.0, 0.0), 0, twist_covariance_diagonal=(0.0,))
    scan = LaserScan(-1.0, 0.5, 0.1, 8.0, np.array([0.0, 1.0, 2.0, np.inf, 3.0], dtype=np.float32), 1.0)
    out = cdr.decode(cdr.laserscan_to_cdr(scan, 1_000_000_000, "laser_link", scan_time_s=0.125), cdr.LASER_SCAN)
    assert out.scan_time == 0.125 and out.time_increment == 0.0 and out.header.frame_id == "laser_link"
    assert cdr.decode(cdr.laserscan_to_cdr(scan, 0), cdr.LASER_SCAN).scan_time == 0.0


def test_bool_round_trip_is_ros_std_msgs_bool():
    """explore_lite's ``explore/resume``: std_msgs/Bool, a 4-byte CDR header and one byte of data."""
    assert cdr.bool_from_cdr(cdr.bool_to_cdr(True)) is True
    assert cdr.bool_from_cdr(cdr.bool_to_cdr(False)) is False
    assert cdr.bool_to_cdr(True) == b"\x00\x01\x00\x00\x01"  # little-endian CDR, as `ros2 topic pub` sends it
    with pytest.raises(cdr.CdrError):
        cdr.bool_from_cdr(b"\x00")


def test_occupancy_grid_round_trip():
    g = GridGeometry(0.05, (30, 40), origin_x_m=-1.0, origin_y_m=2.0)
    grid = np.full(g.shape, -1, dtype=np.int8)
    grid[5:10, 5:20] = 0
    grid[5, 5:20] = 100
    back, g2 = cdr.occupancy_grid_from_cdr(cdr.occupancy_grid_to_cdr(grid, g, 1_000_000_000))
    np.testing.assert_array_equal(back, grid)
    assert g2.shape == g.shape and (g2.origin_x_m, g2.origin_y_m) == (-1.0, 2.0)
    assert g2.resolution_m == pytest.approx(0.05)  # float32 on the wire


def _grid_with_origin(x_m: float, y_m: float, quaternion: tuple[float, float, float, float], resolution_m: float = 0.05) -> bytes:
    """A 3 x 4 OccupancyGrid made by our encoder, its ``info.origin`` then set as another ROS node may send it (a
    quaternion that ``occupancy_grid_to_cdr``'s yaw never gives: off unit norm, tilted, NaN)."""
    grid = np.zeros((3, 4), dtype=np.int8)
    grid[0, 0] = 100
    msg = cdr.decode(cdr.occupancy_grid_to_cdr(grid, GridGeometry(0.05, (3, 4)), 1_000_000_000), cdr.OCCUPANCY_GRID)
    msg.info.resolution = resolution_m
    msg.info.origin.position.x, msg.info.origin.position.y = x_m, y_m
    o = msg.info.origin.orientation
    o.x, o.y, o.z, o.w = quaternion
    return cdr.encode(msg, cdr.OCCUPANCY_GRID)


def _yaw_quaternion(yaw_rad: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw_rad / 2), math.cos(yaw_rad / 2))


def test_an_occupancy_grid_whose_origin_turns_it_is_refused_naming_its_yaw_not_read_unturned():
    """map_server turns a map by its YAML ``origin``'s yaw, and sends that yaw in ``info.origin.orientation``;
    ``occupancy_grid_from_cdr`` dropped it and gave the grid axis-aligned at the corner's x and y: every cell but the
    corner's in the wrong place, silently. Its geometry cannot turn, so it refuses such a map, saying the yaw given
    and what it reads; ``occupancy_grid_and_origin_from_cdr`` reads it, the grid in its own frame and its corner's
    pose, yaw included, in the message's frame."""
    grid = np.full((30, 40), -1, dtype=np.int8)
    grid[5, 5:20] = 100
    geometry = GridGeometry(0.05, (30, 40))
    raw = cdr.occupancy_grid_to_cdr(grid, geometry, 1_000_000_000, origin=Pose2D(1.0, 2.0, 0.5))
    with pytest.raises(cdr.CdrError) as refused:
        cdr.occupancy_grid_from_cdr(raw)
    said = str(refused.value)
    assert "yaw 0.5 rad" in said and f"within +-{UNTURNED_YAW_TOLERANCE_RAD} rad" in said, said
    assert "occupancy_grid_and_origin_from_cdr" in said, said
    back, own, origin = cdr.occupancy_grid_and_origin_from_cdr(raw)
    np.testing.assert_array_equal(back, grid)
    assert own.shape == geometry.shape and (own.origin_x_m, own.origin_y_m) == (0.0, 0.0)
    assert own.resolution_m == pytest.approx(0.05)  # float32 on the wire
    assert (origin.x_m, origin.y_m) == (1.0, 2.0) and origin.yaw_rad == pytest.approx(0.5, abs=1e-12)
    # Cell (0, 1)'s centre, 0.075 m along the grid's x and 0.025 m along its y, in the map frame: turned by 0.5 rad.
    centre = compose_xy(origin, np.array(own.cell_to_world(0, 1)).reshape(1, 2))[0]
    c, s = math.cos(0.5), math.sin(0.5)
    np.testing.assert_allclose(centre, [1.0 + c * 0.075 - s * 0.025, 2.0 + s * 0.075 + c * 0.025], atol=1e-12)


def test_an_occupancy_grid_origin_yaw_within_the_tolerance_is_read_as_zero():
    """A yaw within ``UNTURNED_YAW_TOLERANCE_RAD`` (the nanoradian to which origins are written) is no turn: the
    grid is read axis-aligned at the corner, as before; just beyond it, refused."""
    _, g = cdr.occupancy_grid_from_cdr(_grid_with_origin(-1.0, 2.0, _yaw_quaternion(0.5 * UNTURNED_YAW_TOLERANCE_RAD)))
    assert (g.origin_x_m, g.origin_y_m, g.shape) == (-1.0, 2.0, (3, 4))
    _, g, origin = cdr.occupancy_grid_and_origin_from_cdr(_grid_with_origin(-1.0, 2.0, _yaw_quaternion(-0.5 * UNTURNED_YAW_TOLERANCE_RAD)))
    assert origin == Pose2D(-1.0, 2.0, 0.0) and (g.origin_x_m, g.origin_y_m) == (0.0, 0.0)
    with pytest.raises(cdr.CdrError, match=r"by yaw -3\.0*\d*e-09 rad"):
        cdr.occupancy_grid_from_cdr(_grid_with_origin(-1.0, 2.0, _yaw_quaternion(-3 * UNTURNED_YAW_TOLERANCE_RAD)))


@pytest.mark.parametrize(
    ("quaternion", "said"),
    [
        ((0.0, 0.0, 0.0, 2.0), "not a unit quaternion (squared norm 4.0"),
        ((0.0, 0.0, 0.0, 0.9), "not a unit quaternion (squared norm 0.81"),
        ((0.0, 0.0, 0.0, 0.0), "not a unit quaternion (squared norm 0.0"),
        ((0.0, 0.0, float("nan"), 1.0), "non-finite origin orientation (0.0, 0.0, nan, 1.0)"),
        ((0.0, 0.0, 0.0, float("inf")), "non-finite origin orientation"),
        ((math.sin(0.05), 0.0, 0.0, math.cos(0.05)), "tilts the grid out of the plane by 0.1 rad"),
        ((0.0, math.sin(-0.1), math.sin(0.2), math.cos(0.2)), "tilts the grid out of the plane"),
    ],
)
def test_an_occupancy_grid_origin_with_a_bad_quaternion_is_refused(quaternion, said):
    """A map origin whose orientation is no planar turn is bad input, not a grid placed somewhere: off unit norm
    beyond tf2's and RViz's own tolerance, NaN or infinite, or tilting the grid out of the plane (roll or pitch)."""
    raw = _grid_with_origin(0.0, 0.0, quaternion)
    for read in (cdr.occupancy_grid_from_cdr, cdr.occupancy_grid_and_origin_from_cdr):
        with pytest.raises(cdr.CdrError, match=re.escape(said)):
            read(raw)


def test_an_occupancy_grid_origin_quaternion_within_tf2s_norm_tolerance_is_read():
    """tf2 and RViz 2 take a quaternion whose squared norm is within 0.01 of 1 (a rounded one, written with a few
    decimals); so does the map's origin, its yaw read from it as it is."""
    _, g = cdr.occupancy_grid_from_cdr(_grid_with_origin(0.5, 0.25, (0.0, 0.0, 0.0, 1.004)))
    assert (g.origin_x_m, g.origin_y_m) == (0.5, 0.25)
    _, _, origin = cdr.occupancy_grid_and_origin_from_cdr(_grid_with_origin(0.5, 0.25, (0.0, 0.0, 0.7071, 0.7071)))
    assert origin.yaw_rad == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    ("position", "resolution_m", "said"),
    [((float("nan"), 0.0), 0.05, "non-finite origin position (nan, 0.0)"), ((0.0, float("-inf")), 0.05, "non-finite origin position"),
     ((0.0, 0.0), 0.0, "resolution must be a positive finite number, got 0.0"), ((0.0, 0.0), float("nan"), "resolution must be a positive")],
)
def test_an_occupancy_grid_with_no_place_or_cell_size_is_refused(position, resolution_m, said):
    """A grid with a NaN corner or a resolution that is not a positive number lies nowhere: refused, not a geometry."""
    with pytest.raises(cdr.CdrError, match=re.escape(said)):
        cdr.occupancy_grid_from_cdr(_grid_with_origin(*position, _yaw_quaternion(0.0), resolution_m=resolution_m))


def test_pose_and_markers_encode():
    pose, stamp = cdr.pose_stamped_from_cdr(cdr.pose_stamped_to_cdr(1.0, 2.0, 0.5, 4_000_000_000))
    assert pose.yaw_rad == pytest.approx(0.5) and stamp == pytest.approx(4.0)
    raw = cdr.frontier_markers_to_cdr([np.array([[0.0, 0.0], [0.1, 0.0]]), np.array([[3.0, 1.0]])], [(0.05, 0.0), (3.0, 1.0)], 1_000_000_000)
    msg = cdr.decode(raw, cdr.MARKER_ARRAY)
    # The DELETEALL first, with no namespace: RViz 2 clears every namespace then (with one, only that one, and the
    # goal spheres of clusters that have gone would stay on screen).
    assert [m.ns for m in msg.markers] == ["", "frontiers", "frontiers", "frontiers_goals", "frontiers_goals"]
    assert msg.markers[0].action == 3 and len(msg.markers[1].points) == 2


def test_yaw_of_an_unnormalised_quaternion_is_its_heading_and_a_zero_one_is_refused():
    # A driver may publish a quaternion scaled by any factor; the unit-norm shortcut gave 0.5 rad as 1.31 rad at
    # scale 2 (and the heading of a pure-z quaternion of norm 0.5 as 0).
    for scale in (0.5, 1.0, 2.0, 10.0):
        q = [scale * v for v in (0.0, 0.0, math.sin(0.25), math.cos(0.25))]
        assert cdr.yaw_from_quaternion(*q) == pytest.approx(0.5)
    assert cdr.yaw_from_quaternion(0.0, 0.0, 0.5, 0.0) == pytest.approx(math.pi)
    with pytest.raises(cdr.CdrError, match="no orientation"):
        cdr.yaw_from_quaternion(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(cdr.CdrError, match="no orientation"):
        cdr.yaw_from_quaternion(0.0, 0.0, float("nan"), 1.0)


def test_garbage_is_a_clear_error():
    with pytest.raises(cdr.CdrError, match="LaserScan"):
        cdr.laserscan_from_cdr(b"\x00\x01\x00\x00garbage")
    with pytest.raises(cdr.CdrError):
        cdr.odometry_from_cdr(b"")


@pytest.mark.parametrize(("stamp_s", "sec", "nanosec"), [(12.5, 12, 500_000_000), (1.9999999999, 2, 0), (0.0, 0, 0), (1000.000000001, 1000, 1)])
def test_stamps_round_to_the_nearest_nanosecond_and_carry_into_seconds(stamp_s, sec, nanosec):
    stamp = cdr.time_msg(cdr.stamp_ns_from_seconds(stamp_s))
    assert (stamp.sec, stamp.nanosec) == (sec, nanosec)


def test_stamps_in_nanoseconds_are_exact_and_seconds_are_refused():
    """A bag time (ns) becomes sec + nanosec exactly; through float seconds, 1796546483.725553157 s read back as
    ...725553152 (a double near 1.8e9 s is good to ~240 ns), so a header disagreed with the bag's own time."""
    t_ns = 1_796_546_483_725_553_157
    msg = cdr.decode(cdr.pose_stamped_to_cdr(1.0, 2.0, 0.0, t_ns), cdr.POSE_STAMPED)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_796_546_483, 725_553_157)
    assert cdr.header_stamp_ns(msg.header) == t_ns
    assert cdr.time_msg(np.int64(t_ns)).nanosec == 725_553_157
    with pytest.raises(TypeError, match="nanoseconds"):
        cdr.time_msg(1796546483.725553)  # seconds where nanoseconds are meant: an error, not a time near 1970


def test_path_poses_face_along_the_path_even_across_a_repeated_point():
    """nav_msgs/Path: each pose faces the next point (REP-103 yaw, counter-clockwise from +x). A point repeated (a
    path of one cell, the goal on the last cell's centre) has no direction of its own: it keeps the heading of the
    way it is on, never a spurious yaw 0 (RViz's arrows, a controller that reads the poses' yaw)."""
    path = np.array([[0.0, 0.0], [0.0, 1.0], [0.0, 1.0], [-1.0, 1.0], [-1.0, 1.0]])
    msg = cdr.decode(cdr.path_to_cdr(path, 1_000_000_000, "map"), cdr.PATH)
    yaws = [cdr.yaw_from_quaternion(p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w) for p in msg.poses]
    assert np.allclose(yaws, [math.pi / 2, math.pi / 2, math.pi, math.pi, math.pi])
    assert msg.header.frame_id == "map" and all(p.header.frame_id == "map" for p in msg.poses)
    still = cdr.decode(cdr.path_to_cdr(np.array([[2.0, 3.0], [2.0, 3.0]]), 1_000_000_000), cdr.PATH)
    assert [p.pose.orientation.w for p in still.poses] == [1.0, 1.0]  # no direction at all: the identity


@pytest.mark.parametrize("distro", ["ROS2_JAZZY", "ROS2_KILTED"])
def test_twist_stamped_is_the_header_then_the_twist_that_jazzy_and_kilted_read(distro: str):
    """ROS 2 Jazzy's diff_drive_controller takes only geometry_msgs/TwistStamped on its ``cmd_vel`` (Nav2 Kilted sends
    it by default): ``std_msgs/Header header`` then ``Twist twist``. Our Humble typestore's bytes are those a Jazzy or
    Kilted node reads (decoded with that distribution's rosbags typestore), to the nanosecond, frame included."""
    from rosbags.typesys import Stores, get_typestore

    stamp_ns = 1_796_546_483_123_456_789
    raw = cdr.twist_stamped_to_cdr(VelocityCommand(0.3, -0.2), stamp_ns, "limo1/base_link")
    store = get_typestore(getattr(Stores, distro))
    msg = store.deserialize_cdr(raw, "geometry_msgs/msg/TwistStamped")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (1_796_546_483, 123_456_789, "limo1/base_link")
    assert (msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z) == (0.3, 0.0, 0.0)
    assert (msg.twist.angular.x, msg.twist.angular.y, msg.twist.angular.z) == (0.0, 0.0, -0.2)
    assert bytes(store.serialize_cdr(msg, "geometry_msgs/msg/TwistStamped")) == raw
    assert cdr.twist_stamped_from_cdr(raw) == (VelocityCommand(0.3, -0.2), stamp_ns, "limo1/base_link")
    with pytest.raises(cdr.CdrError):
        cdr.twist_stamped_from_cdr(cdr.twist_to_cdr(VelocityCommand(0.3, -0.2)))  # a bare Twist is not one
