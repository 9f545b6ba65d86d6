"""Occupancy map M_t, ray casting and the simulated LiDAR."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cso_runtime.config import ExplorationConfig, MappingConfig, SensorConfig
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D
from cso_runtime.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap, integrate_observation
from cso_runtime.raycast import cast_rays
from cso_runtime.simulator import KinematicSimulator
from tests.conftest import box_room


def test_cast_rays_match_analytic_wall_distances():
    plan = box_room(4.0, 3.0, 0.05)  # interior x in [0.1, 4.1], y in [0.1, 3.1]
    origin = np.array([1.1, 1.6])
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, math.atan2(1.5, 3.0)])
    ranges = cast_rays(plan.occupied, plan.geometry, origin, angles, 8.0)
    expected = [3.0, 1.5, 1.0, 1.5, math.hypot(3.0, 1.5)]
    np.testing.assert_allclose(ranges, expected, atol=1e-6)


def test_cast_rays_no_return_is_inf():
    plan = box_room(4.0, 3.0, 0.05)
    ranges = cast_rays(plan.occupied, plan.geometry, np.array([1.1, 1.6]), np.array([0.0, math.pi]), 0.5)
    assert np.all(np.isinf(ranges))


def test_cast_rays_stop_at_the_grid_edge_on_every_side():
    """A map without walls at its border (a map_server scene): beams end where they leave the grid,
    whichever edge they cross, as the docstring promises (the left and right edges once wrapped into
    another row and gave 0 m)."""
    g = GridGeometry(0.05, (40, 60), origin_x_m=-0.4, origin_y_m=0.3)  # 3.0 m wide (x), 2.0 m tall (y)
    origin = np.array([0.6, 1.3])  # 1.0 m from the left edge, 2.0 m from the right, 1.0 m from top and bottom
    angles = np.array([0.0, math.pi, math.pi / 2, -math.pi / 2, 0.3, math.pi - 0.3, -2.5])
    ranges = cast_rays(np.zeros(g.shape, dtype=bool), g, origin, angles, 8.0)
    expected = [2.0, 1.0, 1.0, 1.0, min(2.0 / math.cos(0.3), 1.0 / math.sin(0.3)), min(1.0 / math.cos(0.3), 1.0 / math.sin(0.3)),
                min(1.0 / abs(math.cos(-2.5)), 1.0 / abs(math.sin(-2.5)))]
    np.testing.assert_allclose(ranges, expected, atol=1e-9)


def exact_ranges(blocked: np.ndarray, g: GridGeometry, origin: np.ndarray, angles: np.ndarray, max_range_m: float) -> np.ndarray:
    """Reference for ``cast_rays``: each beam's entry into every blocked cell and its exit from the grid, by the slab
    test on the whole grid, the nearest kept (a beam only touching a cell's corner does not enter it)."""
    iy, ix = np.nonzero(blocked)
    lows = [np.append(g.origin_x_m + ix * g.resolution_m, -np.inf), np.append(g.origin_y_m + iy * g.resolution_m, -np.inf)]
    highs = [lows[0] + g.resolution_m, lows[1] + g.resolution_m]
    out = []
    for angle in angles:
        enter, leave = np.full(len(iy) + 1, -np.inf), np.full(len(iy) + 1, np.inf)
        for axis, d in enumerate((math.cos(angle), math.sin(angle))):
            lo, hi = lows[axis], highs[axis]
            if axis == 0:
                lo[-1], hi[-1] = g.origin_x_m, g.origin_x_m + g.width_m
            else:
                lo[-1], hi[-1] = g.origin_y_m, g.origin_y_m + g.height_m
            if d == 0.0:
                outside = (origin[axis] < lo) | (origin[axis] >= hi)
                enter[outside], leave[outside] = np.inf, -np.inf
                continue
            t0, t1 = (lo - origin[axis]) / d, (hi - origin[axis]) / d
            enter, leave = np.maximum(enter, np.minimum(t0, t1)), np.minimum(leave, np.maximum(t0, t1))
        cells = (leave > enter) & (leave > 0)
        t = min(np.maximum(enter[:-1][cells[:-1]], 0.0).min(initial=np.inf), max(leave[-1], 0.0))  # the grid's exit
        out.append(t if t <= max_range_m else np.inf)
    return np.array(out)


def test_cast_rays_stop_at_a_wall_drawn_diagonally():
    """A wall whose cells touch only at their corners (a diagonal line of cells) lets no beam through: the beams are
    marched in samples a third of a cell apart, and two samples either side of a corner the wall's cells share lay
    in the free cells beside it (127 of these 6,000 beams ended behind the wall). A range is the exact one but where
    a beam clipped a wall cell's corner between two samples and went on to the next."""
    g = GridGeometry(0.05, (60, 60))
    blocked = np.eye(60, dtype=bool)  # cells (i, i): x > y below the wall, x < y behind it
    origin = np.array([2.0, 0.7])
    angles = np.linspace(0.0, 2 * math.pi, 6000, endpoint=False)
    ranges = cast_rays(blocked, g, origin, angles, 8.0)
    end = origin[None, :] + ranges[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    assert np.isfinite(ranges).all()
    assert (end[:, 1] <= end[:, 0] + 1e-9).all()  # no beam ends behind the wall
    over_m = ranges - exact_ranges(blocked, g, origin, angles, 8.0)
    assert (over_m >= -1e-9).all()
    assert (over_m <= 1e-9).mean() > 0.9  # 329 of 6,000 clipped a corner: this wall is all corners


def test_cast_rays_stop_at_a_diagonal_gap_exactly_through_its_corner():
    """A beam straight through the corner two blocked cells share stops there (where it touches both), and one
    through the corner of a single blocked cell goes on."""
    g = GridGeometry(0.1, (10, 10))
    blocked = np.zeros(g.shape, dtype=bool)
    blocked[5, 4] = blocked[4, 5] = True  # touch at the corner (0.5, 0.5); (4, 4) and (5, 5) free
    blocked[2, 7] = True  # alone: its corner (0.7, 0.3)
    ranges = cast_rays(blocked, g, np.array([0.25, 0.25]), np.array([math.pi / 4, math.atan2(0.05, 0.45)]), 3.0)
    np.testing.assert_allclose(ranges, [math.hypot(0.25, 0.25), math.hypot(0.75, 0.75 / 9)], atol=1e-9)


def test_a_beam_along_a_cell_edge_reads_the_wall_where_it_is():
    """A beam that starts on a cell's edge and runs along it (the robot at x = 1.2 m on a 0.05 m grid, facing
    north): its cell's edge, rounded, lay a hair beyond the origin, and dividing by the beam's cos of 6e-17 read
    the wall 1.9 m ahead as 3.6 m off, beyond the 3 m range: no return, free space marked through the wall."""
    plan = box_room(3.0, 3.0, 0.05)  # the north wall's face at y = 3.1 m
    ranges = cast_rays(plan.occupied, plan.geometry, np.array([1.2, 1.2]), np.array([math.pi / 2, -math.pi / 2, 0.0, math.pi]), 3.0)
    np.testing.assert_allclose(ranges, [1.9, 1.1, 1.9, 1.1], atol=1e-9)


@pytest.mark.parametrize("scene", ["generated:small:1:0", "builtin"])
def test_ray_marching_in_chunks_does_not_change_ranges_or_maps(scene, monkeypatch):
    """Beams are marched a chunk of samples at a time and leave at their first hit (sensor) or their
    end (mapper): a speed setting only. One chunk per beam (the whole range at once) and chunks of 5
    samples give the same ranges and the same maps, bit for bit, from inside, near and outside the walls."""
    from cso_runtime import raycast
    from cso_runtime.scenes import resolve_scenes

    plan = resolve_scenes(scene)[0].load()
    g = plan.geometry
    rng = np.random.default_rng(5)
    outputs = []
    for chunk in (10**6, 5):
        monkeypatch.setattr(raycast, "SAMPLES_PER_CHUNK", chunk)
        import cso_runtime.occupancy as occupancy_module

        monkeypatch.setattr(occupancy_module, "SAMPLES_PER_CHUNK", chunk)
        rng = np.random.default_rng(5)
        occupancy = OccupancyMap(g)
        ranges_all = []
        for _ in range(25):
            origin = np.array([rng.uniform(g.origin_x_m - 0.5, g.origin_x_m + g.width_m + 0.5), rng.uniform(g.origin_y_m - 0.5, g.origin_y_m + g.height_m + 0.5)])
            angles = rng.uniform(-math.pi, math.pi) + np.linspace(0.0, 2 * math.pi, 90, endpoint=False)
            angles[:2] = (0.0, math.pi / 2)  # axis-aligned beams: the slab test's division by zero
            ranges = cast_rays(plan.occupied, g, origin, angles, 3.0)
            ranges_all.append(ranges)
            noisy = np.where(rng.random(len(ranges)) < 0.1, np.inf, ranges)
            scan = LaserScan(float(angles[0]), float(angles[1] - angles[0]), 0.05, 3.0, noisy.astype(np.float32))
            occupancy.integrate_scan(Pose2D(float(origin[0]), float(origin[1]), 0.0), scan)
        outputs.append((np.concatenate(ranges_all), occupancy.explored, occupancy.occupied, occupancy.log_odds))
    (r1, e1, o1, l1), (r2, e2, o2, l2) = outputs
    assert np.isfinite(r1).sum() > 1000 and np.isinf(r1).any()  # walls hit, and some beams beyond range
    assert np.array_equal(r1, r2)
    assert e1.sum() > 2000 and np.array_equal(e1, e2) and np.array_equal(o1, o2) and np.array_equal(l1, l2)


@pytest.mark.parametrize("origin_xy_m", [(0.0, 0.0), (-3.217, 1.05)])
def test_ray_samples_fall_in_the_cells_world_to_cell_gives(origin_xy_m):
    """The ray marcher works out its samples' cells in place, in floats, as flat indices; each one is
    the cell ``GridGeometry.world_to_cell`` gives the sample's point, and ``inside`` is ``in_bounds``,
    for beams that start inside, on an edge or outside the grid, whatever its origin."""
    from cso_runtime.raycast import sample_cells

    g = GridGeometry(0.05, (37, 53), *origin_xy_m)
    rng = np.random.default_rng(3)
    width = g.shape[1]
    inside_seen = 0
    for _ in range(40):
        origin = np.array([rng.uniform(g.origin_x_m - 1, g.origin_x_m + g.width_m + 1), rng.uniform(g.origin_y_m - 1, g.origin_y_m + g.height_m + 1)])
        origin[rng.random(2) < 0.2] = g.origin_x_m  # exactly on a cell edge now and then
        angles = rng.uniform(-math.pi, math.pi, 30)
        angles[:4] = (0.0, math.pi / 2, math.pi, -math.pi / 2)
        cos, sin = np.cos(angles), np.sin(angles)
        cell, inside, dist = sample_cells(g, origin, cos, sin, 7, 140)
        iy, ix = g.world_to_cell(origin[0] + cos[:, None] * dist[None, :], origin[1] + sin[:, None] * dist[None, :])
        assert np.array_equal(inside, g.in_bounds(iy, ix))
        assert np.array_equal(cell[inside], (iy * width + ix)[inside])
        inside_seen += int(inside.sum())
    assert inside_seen > 10_000


def test_sensor_presets():
    lidar = SensorConfig.preset("lidar")
    assert (lidar.fov_deg, lidar.range_min_m, lidar.range_max_m) == (180.0, 0.1, 8.0)
    assert SensorConfig.preset("lidar", fov_deg=360).fov_deg == 360
    depth = SensorConfig.preset("depth")
    assert depth.fov_deg == pytest.approx(79.0) and depth.range_max_m == 3.0 and depth.range_min_m == 0.3
    with pytest.raises(ValueError):
        SensorConfig.preset("sonar")


def test_simulated_scan_field_of_view():
    plan = box_room(4.0, 3.0, 0.05)
    front = KinematicSimulator(plan, SensorConfig.preset("lidar")).scan()
    assert front.angles_rad[0] == pytest.approx(-math.pi / 2) and front.angles_rad[-1] == pytest.approx(math.pi / 2)
    assert len(front.ranges_m) == 181
    ring = KinematicSimulator(plan, SensorConfig.preset("lidar", fov_deg=360)).scan()
    assert len(ring.ranges_m) == 360 and ring.angles_rad[0] == pytest.approx(-math.pi)
    # Robot at the room centre facing +x: the wall ahead is 2 m away.
    assert front.ranges_m[90] == pytest.approx(2.0, abs=1e-5)


def test_scan_integration_marks_free_and_occupied():
    plan = box_room(4.0, 3.0, 0.05)
    sim = KinematicSimulator(plan, SensorConfig.preset("lidar", fov_deg=360))
    m = OccupancyMap(plan.geometry)
    m.integrate_scan(sim.sensor_pose(), sim.scan())
    interior = plan.free
    # The whole convex room is seen from its centre: every interior cell is open.
    assert m.open[interior].mean() > 0.99
    # Wall cells hit by beams are occupied; nothing free is reported inside walls.
    assert not (m.open & plan.occupied).any()
    assert m.occupied[plan.occupied].any()
    grid = m.to_occupancy_grid()
    assert set(np.unique(grid)) <= {UNKNOWN, FREE, OCCUPIED}
    back = OccupancyMap.from_occupancy_grid(grid, plan.geometry)
    np.testing.assert_array_equal(back.to_occupancy_grid(), grid)


def test_no_return_beams_clear_up_to_max_range():
    g = GridGeometry(0.1, (100, 100))
    m = OccupancyMap(g)
    scan = LaserScan(0.0, 0.0, 0.1, 3.0, np.array([np.inf], dtype=np.float32))
    m.integrate_scan(Pose2D(1.0, 5.05, 0.0), scan)
    row = m.explored[50]
    assert row[10:39].all() and not row[41:].any()
    assert not m.occupied.any()


@pytest.mark.parametrize("reading_m", [3.0, 3.5])
def test_a_reading_at_or_beyond_range_max_is_no_return(reading_m):
    """REP-117: a range of ``range_max`` or more is not an obstacle (drivers such as the LIMO's clamp "nothing" to
    ``range_max``): the beam clears free space up to ``range_max`` and marks no occupied cell, as ``inf`` does."""
    g = GridGeometry(0.1, (100, 100))
    pose = Pose2D(1.0, 5.05, 0.0)
    m, no_return = OccupancyMap(g), OccupancyMap(g)
    m.integrate_scan(pose, LaserScan(0.0, 0.0, 0.1, 3.0, np.array([reading_m], dtype=np.float32)))
    no_return.integrate_scan(pose, LaserScan(0.0, 0.0, 0.1, 3.0, np.array([np.inf], dtype=np.float32)))
    assert not m.occupied.any()
    assert m.open[50, 10:39].all()
    np.testing.assert_array_equal(m.to_occupancy_grid(), no_return.to_occupancy_grid())


def test_a_reading_just_below_range_max_is_a_hit():
    g = GridGeometry(0.1, (100, 100))
    m = OccupancyMap(g)
    just_below_m = np.nextafter(np.float32(3.0), np.float32(0.0))
    m.integrate_scan(Pose2D(1.0, 5.05, 0.0), LaserScan(0.0, 0.0, 0.1, 3.0, np.array([just_below_m], dtype=np.float32)))
    assert m.occupied[50, 40] and np.count_nonzero(m.occupied) == 1


def test_a_simulated_wall_float32_rounds_to_range_max_stays_a_hit():
    """A wall 5e-8 m inside the simulated LiDAR's range is a return, though float32 rounds its range to
    ``range_max`` (no return): the scan reports it just below, so the mapper marks it, as before REP-117's rule."""
    plan = box_room(4.0, 3.0, 0.05)  # the wall ahead of the start (2.1, 1.6) begins at x = 4.1
    plan = dataclasses.replace(plan, start=Pose2D(2.1 + 5e-8, 1.6, 0.0))
    sensor = SensorConfig.preset("lidar")
    sensor.range_max_m = 2.0
    sim = KinematicSimulator(plan, sensor)
    ahead_m = sim.scan().ranges_m[90]
    assert np.isfinite(ahead_m) and ahead_m < 2.0
    m = OccupancyMap(plan.geometry)
    m.integrate_scan(sim.sensor_pose(), sim.scan())
    assert m.occupied[plan.geometry.world_to_cell(4.1 + 1e-3, 1.6)]


def test_nan_scan_is_rejected_and_map_unchanged():
    g = GridGeometry(0.1, (20, 20))
    m = OccupancyMap(g)
    bad = LaserScan(0.0, 0.1, 0.1, 3.0, np.array([1.0, np.nan], dtype=np.float32))
    with pytest.raises(ValueError, match="NaN"):
        m.integrate_scan(Pose2D(1.0, 1.0, 0.0), bad)
    assert not m.explored.any()


@pytest.mark.parametrize("pose", [Pose2D(math.nan, 1.0, 0.0), Pose2D(1.0, math.inf, 0.0), Pose2D(1.0, 1.0, math.nan)], ids=["nan-x", "inf-y", "nan-yaw"])
def test_a_sensor_pose_that_is_not_finite_is_rejected_and_changes_nothing(pose):
    """A NaN or infinite pose was integrated as a scan that saw nothing (numpy's cast warnings, no error): now a
    ValueError, which the mapper service counts as a rejected scan, before the footprint is cleared."""
    m = OccupancyMap(GridGeometry(0.1, (20, 20)))
    scan = LaserScan(-0.5, 0.1, 0.1, 3.0, np.full(11, 1.0, dtype=np.float32))
    with pytest.raises(ValueError, match="sensor pose is not finite"):
        integrate_observation(m, pose, scan, ExplorationConfig())
    assert not m.explored.any() and not m.occupied.any()


@pytest.mark.parametrize(
    ("scan", "why"),
    [
        (LaserScan(-0.5, 0.0, 0.1, 3.0, np.full(11, 1.0, dtype=np.float32)), "angle_increment_rad must be positive"),
        (LaserScan(0.5, -0.1, 0.1, 3.0, np.full(11, 1.0, dtype=np.float32)), "angle_increment_rad must be positive"),
        (LaserScan(-0.5, 0.1, 0.1, 3.0, np.array(["1.0", "2.0"])), "ranges must be numbers"),
        (LaserScan(-0.5, 0.1, 0.1, 1e12, np.full(11, np.inf, dtype=np.float32)), "range_max_m .* is above"),
    ],
    ids=["zero-increment", "negative-increment", "text-ranges", "huge-range-max"],
)
def test_a_scan_the_mapper_cannot_integrate_is_a_value_error_and_changes_nothing(scan, why):
    """Zero increment put every beam on one line, a negative one was taken as it came (ScanMsg refuses both), text
    ranges raised a TypeError the mapper service does not catch, and a finite 1e12 m range_max marched each
    no-return beam out to it for hours. Each is a ValueError now (a counted rejection in the mapper service)."""
    m = OccupancyMap(GridGeometry(0.1, (20, 20)))
    with pytest.raises(ValueError, match=why):
        m.integrate_scan(Pose2D(1.0, 1.0, 0.0), scan)
    assert not m.explored.any()


scan_strategy = st.lists(
    st.one_of(st.floats(0.0, 6.0), st.just(float("inf"))), min_size=1, max_size=60
)


@settings(max_examples=60, deadline=None)
@given(
    scans=st.lists(
        st.tuples(st.floats(0.5, 4.5), st.floats(0.5, 4.5), st.floats(-math.pi, math.pi), scan_strategy),
        min_size=1,
        max_size=5,
    )
)
def test_scan_integration_invariants(scans):
    """A cell seen free never becomes unknown, nothing becomes NaN, grid values stay ROS-valid."""
    m = OccupancyMap(GridGeometry(0.1, (50, 50)))
    for x, y, yaw, ranges in scans:
        before = m.explored.copy()
        n = len(ranges)
        scan = LaserScan(-math.pi, 2 * math.pi / n, 0.1, 5.0, np.array(ranges, dtype=np.float32))
        m.integrate_scan(Pose2D(x, y, yaw), scan)
        assert (m.explored | ~before).all()
        assert np.isfinite(m.log_odds).all()
        assert set(np.unique(m.to_occupancy_grid())) <= {UNKNOWN, FREE, OCCUPIED}
        assert not (m.occupied & ~m.explored).any()


def test_footprint_clearing_marks_only_unseen_cells_under_the_body_free():
    g = GridGeometry(0.05, (40, 40))
    m = OccupancyMap(g)
    pose = Pose2D(1.0, 1.0, math.pi / 2)  # facing +y: the 0.32 m length runs along y
    wall_y, wall_x = g.world_to_cell(1.0, 1.12)  # under the body, already seen as a wall
    m.explored[wall_y, wall_x] = m.occupied[wall_y, wall_x] = True
    newly = m.mark_footprint_free(pose, length_m=0.32, width_m=0.2)
    x_m, y_m = g.cell_to_world(*np.mgrid[0:40, 0:40])
    under = (np.abs(x_m - 1.0) <= 0.1) & (np.abs(y_m - 1.0) <= 0.16)
    assert newly == under.sum() - 1
    assert m.explored[under].all() and not m.explored[~under].any()
    assert m.occupied[wall_y, wall_x] and m.occupied.sum() == 1  # what a scan saw is kept
    assert (m.to_occupancy_grid()[under] == FREE).sum() == newly
    assert m.mark_footprint_free(Pose2D(-5.0, -5.0, 0.0), 0.32, 0.2) == 0  # off the grid: nothing


def test_integrate_observation_clears_the_footprint_behind_a_forward_narrow_sensor():
    """The depth camera 0.103 m ahead of the centre sees a 79-degree wedge: the cells under and behind the
    robot's centre are never in it, and without footprint clearing they stay unknown (frontiers at the
    robot's own position that no turn can observe)."""
    plan = box_room()
    sensor = dataclasses.replace(SensorConfig.preset("depth"), mount_x_m=0.103)
    sim = KinematicSimulator(plan, sensor)
    centre = plan.geometry.world_to_cell(*sim.odometry().xy)
    for clearing in (True, False):
        cfg = ExplorationConfig(sensor=sensor, mapping=MappingConfig(footprint_clearing=clearing))
        m = OccupancyMap(plan.geometry)
        integrate_observation(m, sim.sensor_pose(), sim.scan(), cfg)
        assert m.explored[centre] == clearing
        assert m.explored.sum() > 200  # the wedge itself, either way
