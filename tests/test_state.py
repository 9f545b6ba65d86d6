"""The state of Eq. 2: frontiers, geodesic distance map (Eq. 3) and frontier entropy (Eq. 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from cso_runtime.frontiers import frontier_cells, frontier_components, frontier_entropy
from cso_runtime.geodesic import disk, geodesic_distance, inflate, traversable_cells
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.observation import ObservationBuilder
from cso_runtime.occupancy import OccupancyMap


def room_with_door() -> OccupancyMap:
    """A 2 x 2 m explored room (0.1 m cells) with walls all round and a 0.6 m open door east."""
    g = GridGeometry(0.1, (40, 40))
    m = OccupancyMap(g)
    m.explored[5:26, 5:26] = True
    m.occupied[5, 5:26] = m.occupied[25, 5:26] = True
    m.occupied[5:26, 5] = m.occupied[5:26, 25] = True
    m.occupied[12:18, 25] = False  # the door: open cells with unknown beyond
    return m


def test_frontiers_in_a_known_room_are_the_door():
    m = room_with_door()
    f = frontier_cells(m.open, m.explored)
    iy, ix = np.nonzero(f)
    assert set(ix.tolist()) == {25} and sorted(iy.tolist()) == list(range(12, 18))


def test_frontier_clusters_have_goal_size_and_entropy():
    m = room_with_door()
    obs = ObservationBuilder().build(m, Pose2D(1.5, 1.5, 0.0))
    assert len(obs.clusters) == 1
    c = obs.clusters[0]
    assert c.size_m == pytest.approx(0.6)
    assert c.goal_cell[1] == 25 and 12 <= c.goal_cell[0] < 18
    assert math.isfinite(c.distance_m) and c.distance_m == pytest.approx(obs.distance_m[c.goal_cell])
    # Goal cell is reachable: the robot (0.2 m radius) fits through the 0.6 m door's centre.
    assert obs.traversable[c.goal_cell]
    assert c.entropy == obs.entropy[c.goal_cell] > 0


def test_frontier_components_group_every_frontier_cell_by_its_8_connected_component():
    """Each component's cells in row-major order, components in label order (scipy's), every cell once."""
    from scipy import ndimage

    frontier = np.random.default_rng(2).random((61, 47)) < 0.08
    iy, ix, splits = frontier_components(frontier)
    labels, count = ndimage.label(frontier, structure=np.ones((3, 3), dtype=bool))
    groups = list(zip(np.split(iy, splits), np.split(ix, splits)))
    assert count > 50 and len(groups) == count and len(iy) == frontier.sum()
    for label, (cy, cx) in enumerate(groups, start=1):
        ey, ex = np.nonzero(labels == label)
        assert np.array_equal(cy, ey) and np.array_equal(cx, ex)
    empty = frontier_components(np.zeros((4, 4), dtype=bool))
    assert all(len(a) == 0 for a in empty)


def test_small_clusters_are_dropped():
    m = room_with_door()
    m.occupied[12:17, 25] = True  # door narrowed to one cell
    obs = ObservationBuilder().build(m, Pose2D(1.5, 1.5, 0.0))
    assert obs.clusters == []


def test_geodesic_distance_around_l_shaped_wall_matches_analytic():
    """A wall from the floor to y = 4 m at x = 3 m: the path must go round its top corner."""
    res = 0.05
    g = GridGeometry(res, (120, 120))  # 6 x 6 m
    traversable = np.ones(g.shape, dtype=bool)
    traversable[0:80, 59:61] = False  # wall x in [2.95, 3.05], y in [0, 4.0]
    d = geodesic_distance(traversable, g, np.array([1.0, 1.0]))
    target = (int(1.0 / res), int(5.0 / res))  # (iy, ix) of (5.0, 1.0)
    tx, ty = g.cell_to_world(*target)
    analytic = math.hypot(2.95 - 1.0, 4.0 - 1.0) + 0.1 + math.hypot(tx - 3.05, 4.0 - ty)
    assert d[target] == pytest.approx(analytic, rel=0.03)
    # Straight line in the open is exact to a few percent too.
    ox, oy = g.cell_to_world(20, 50)
    assert d[20, 50] == pytest.approx(math.hypot(ox - 1.0, oy - 1.0), rel=0.03)


def test_unreachable_cells_are_infinite():
    g = GridGeometry(0.1, (30, 30))
    traversable = np.ones(g.shape, dtype=bool)
    traversable[:, 15] = False  # wall splits the map in two
    d = geodesic_distance(traversable, g, np.array([0.5, 0.5]))
    assert np.isinf(d[:, 16:]).all() and np.isinf(d[:, 15]).all()
    assert np.isfinite(d[:, :15]).all()
    assert d.max() == np.inf and np.nanmax(d[np.isfinite(d)]) < 10.0


@pytest.mark.parametrize("within_m", [None, 1.0])
@pytest.mark.parametrize(("x_m", "y_m"), [(2.98, 1.0), (2.93, 1.0), (1.0, 1.98), (1.0, 1.93), (2.99, 1.99), (0.01, 0.01)])
def test_a_source_within_two_cells_of_any_map_edge_gets_a_distance_map(x_m, y_m, within_m):
    """A robot near the top or right edge of its map (a SLAM map that has not grown past it yet): the 5 x 5 patch
    around the source was cut by the map on one side only, and fast marching failed with a broadcast ValueError."""
    g = GridGeometry(0.05, (40, 60))  # 3 x 2 m
    traversable = np.ones(g.shape, dtype=bool)
    d = geodesic_distance(traversable, g, np.array([x_m, y_m]), within_m)
    iy, ix = (int(v) for v in g.world_to_cell(x_m, y_m))
    assert d[iy, ix] < g.resolution_m
    cx, cy = g.cell_to_world(*np.nonzero(np.isfinite(d)))
    straight = np.hypot(cx - x_m, cy - y_m)
    assert np.allclose(d[np.isfinite(d)], straight, atol=0.02)  # open space: fast marching's straight line
    if within_m is None:
        assert np.isfinite(d).all()


def test_inflation_and_traversable_keep_unknown_uninflated():
    g = GridGeometry(0.1, (20, 20))
    occ = np.zeros(g.shape, dtype=bool)
    occ[10, 10] = True
    inflated = inflate(occ, 0.2, 0.1)
    assert inflated[10, 12] and inflated[12, 10] and not inflated[10, 13] and not inflated[12, 12]
    open_cells = np.ones(g.shape, dtype=bool)
    open_cells[:, :3] = False  # unknown strip
    t = traversable_cells(open_cells & ~occ, occ, 0.2, 0.1)
    assert t[5, 3]  # next to unknown is still traversable
    assert not t[10, 11]


@pytest.mark.parametrize("shape", [(24, 2), (2, 24), (1, 1), (3, 3), (5, 9)])
def test_inflation_of_a_map_narrower_than_the_robot_is_the_disk_dilation(shape):
    """A grid fewer cells wide than the inflation radius (a SLAM map's first scans): a disk offset as long as the grid
    made a slice end negative, which wrapped round, and the shifted OR failed with a broadcast ValueError."""
    occ = np.zeros(shape, dtype=bool)
    occ[shape[0] // 2, shape[1] // 2] = True
    occ[0, 0] = True
    for radius_m, cells in [(0.2, 4), (0.1, 2), (0.05, 1)]:
        expected = ndimage.binary_dilation(occ, structure=disk(cells))
        assert (inflate(occ, radius_m, 0.05) == expected).all()


def test_entropy_counts_frontier_cells_in_window():
    res = 0.1
    f = np.zeros((40, 40), dtype=bool)
    cells = [(10, 10), (10, 12), (14, 10), (30, 30), (20, 20), (20, 21)]
    for c in cells:
        f[c] = True
    window_m = 1.0  # 11 x 11 cells
    ent = frontier_entropy(f, window_m, res)
    brute = np.zeros_like(ent)
    for y in range(40):
        for x in range(40):
            brute[y, x] = f[max(y - 5, 0) : y + 6, max(x - 5, 0) : x + 6].sum()
    np.testing.assert_array_equal(ent, brute)
    assert ent[10, 10] == 3 and ent[30, 30] == 1 and ent[0, 39] == 0


@pytest.mark.parametrize(("window_m", "side_cells"), [(0.3, 3), (0.5, 5), (0.7, 7), (1.1, 11), (1.5, 15), (2.0, 21), (0.72, 7), (0.05, 1)])
def test_entropy_window_is_gamma_wide_not_two_cells_wider(window_m, side_cells):
    """Eq. 4's window is a square of side gamma: gamma / resolution cells when that is odd (the window is centred on
    its cell), the next odd number when it is even. Halving gamma / resolution before rounding once made an odd
    count two cells too wide whenever the float division landed at or above the half (1.1 m at 0.1 m cells: 13 cells,
    1.5 m: 17, 0.72 m: 9); even counts, and so the default 2 m at 0.05 or 0.1 m cells, were never affected."""
    res = 0.1
    f = np.zeros((41, 41), dtype=bool)
    f[20, :] = True  # a frontier row: the count at its middle is the window's side in cells
    assert frontier_entropy(f, window_m, res)[20, 20] == side_cells
