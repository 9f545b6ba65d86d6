"""benchmarks/geodesic_entropy.py: Eq. 4's literal count leaves out the frontier cells behind a wall."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

from cso_runtime.geodesic import geodesic_distance
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.observation import ObservationBuilder
from cso_runtime.occupancy import OccupancyMap


def load_script():
    spec = importlib.util.spec_from_file_location("geodesic_entropy", Path(__file__).parents[1] / "benchmarks" / "geodesic_entropy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def two_rooms() -> OccupancyMap:
    """3 m x 3 m at 5 cm: the left 2 m seen, a wall across it at row 30; the frontier is column 39 in both rooms."""
    geometry = GridGeometry(0.05, (60, 60))
    explored = np.zeros(geometry.shape, dtype=bool)
    explored[:, :40] = True
    occupied = np.zeros(geometry.shape, dtype=bool)
    occupied[30, :40] = True
    return OccupancyMap.from_masks(explored, occupied, geometry)


def test_the_literal_count_leaves_out_the_room_behind_the_wall():
    script = load_script()
    occupancy = two_rooms()
    obs = ObservationBuilder().build(occupancy, Pose2D(0.5, 24 * 0.05 + 0.025, 0.0))
    top = obs.clusters[0]
    assert top.goal_cell == (24, 39)
    assert top.entropy == 26 + 14  # Figure 3's square (41 x 41 cells) reaches both rooms
    (literal, *_) = script.geodesic_counts(obs, occupancy.open, window_m=2.0)
    in_reach = literal * math.pi / 4
    assert 24 <= in_reach <= 26  # the top room's frontier within 1 m (rows 5-29), none of the bottom room's


def test_the_cli_wrapper_puts_the_literal_count_into_every_observation(monkeypatch):
    script = load_script()
    from cso_runtime import observation

    monkeypatch.setattr(observation.ObservationBuilder, "build", observation.ObservationBuilder.build)  # undone after the test
    script.use_geodesic_entropy()
    occupancy = two_rooms()
    obs = ObservationBuilder().build(occupancy, Pose2D(0.5, 24 * 0.05 + 0.025, 0.0))
    assert obs.clusters[0].entropy == script.geodesic_counts(obs, occupancy.open, 2.0)[0] < 40


def corridor_map(explored_to_x_m: float) -> OccupancyMap:
    """A corridor 3.0 x 0.9 m (x 0.1-3.1, y 0.1-1.0) walled all round at 0.05 m cells, known up to ``explored_to_x_m``:
    the frontier is the column of open cells there."""
    g = GridGeometry(0.05, (22, 64))
    occupied = np.ones(g.shape, dtype=bool)
    occupied[2:20, 2:62] = False
    explored = np.zeros(g.shape, dtype=bool)
    explored[:, : int(round(explored_to_x_m / 0.05))] = True
    return OccupancyMap.from_masks(explored, occupied & explored, g)


def test_a_robot_inside_the_inflated_obstacles_may_move_out_of_them():
    """A robot 0.08 m from a wall (a start placed there, lrot.yaml's) stands inside the obstacles inflated by its
    0.2 m radius: the traversable cells began beyond its own few passable cells, so no frontier was reachable
    and the episode ended at once (no_frontier). It may now move out through the open cells its body covers;
    a robot on traversable cells decides on the same D as before."""
    builder = ObservationBuilder()
    occupancy = corridor_map(2.0)
    near_wall = builder.build(occupancy, Pose2D(1.0, 0.18, 0.0))
    assert [c.goal_cell[1] for c in near_wall.clusters] == [39]  # the frontier column at x 1.95-2.0 m
    assert 1.0 < near_wall.clusters[0].distance_m < 1.2
    free = builder.build(occupancy, Pose2D(1.0, 0.55, 0.0))
    assert np.array_equal(free.traversable, builder.traversable(occupancy))
    assert np.array_equal(free.distance_m, geodesic_distance(free.traversable, occupancy.geometry, np.array([1.0, 0.55])))


def test_an_episode_that_ends_with_no_frontier_says_what_is_left_and_why():
    """The reviewer read "no_frontier" at 93 % as a bug: the run now says which frontier cells are left and what
    kept each from being a goal (out of reach through the inflated obstacles, too short a cluster, given up)."""
    from cso_runtime.episode import mark_dead_frontier, no_frontier_why

    g = GridGeometry(0.05, (22, 64))
    occupied = np.ones(g.shape, dtype=bool)
    occupied[2:20, 2:62] = False
    occupied[2:20, 40] = True
    occupied[10:13, 40] = False  # a 0.15 m gap: too narrow for a robot of radius 0.2 m
    explored = np.zeros(g.shape, dtype=bool)
    explored[:, :44] = True  # the frontier is column 43, behind the gap: 18 cells, out of reach
    explored[5, 10] = False  # one unknown cell: a cluster of its 4 neighbours, shorter than 0.3 m
    explored[15, 20] = False  # another, given up around a goal reached there
    occupancy = OccupancyMap.from_masks(explored, occupied & explored, g)
    dead = np.zeros(g.shape, dtype=bool)
    mark_dead_frontier(dead, g, g.cell_to_world(15, 20), 0.1)
    obs = ObservationBuilder().build(occupancy, Pose2D(0.5, 0.5, 0.0), exclude_frontier=dead)
    assert obs.clusters == []
    why = no_frontier_why(obs, dead, 0.3, 0.2)
    assert why == (
        "no frontier left that the robot can reach: 26 frontier cells (1.30 m) remain: 18 in 1 cluster(s) the robot cannot "
        "reach through known free space (obstacles inflated by robot.radius_m, 0.2 m); 4 in clusters shorter than "
        "frontier.min_cluster_size_m (0.3 m); 4 given up around goals reached, or failed, while still frontiers (unobservable)"
    )
    closed = OccupancyMap.from_masks(np.ones(g.shape, dtype=bool), occupied, g)
    assert no_frontier_why(ObservationBuilder().build(closed, Pose2D(0.5, 0.5, 0.0)), dead, 0.3, 0.2) == (
        "no frontier left: the map has no open cell next to unknown space"
    )


def test_an_entropy_window_wider_than_the_map_counts_the_whole_map_without_padding_it_by_its_width():
    """``frontier.entropy_window_m: 1e300`` (``up`` and the frontier service took it) padded the map by 1e301 cells: numpy's
    ValueError in the frontier layer helper (a 1 km window at 0.05 m, a MemoryError). A window wider than twice the map
    counts every frontier cell of it wherever it is centred: it is computed at that width, the same counts."""
    from cso_runtime.frontiers import frontier_entropy

    rng = np.random.default_rng(0)
    frontier = rng.random((7, 11)) < 0.3
    whole = np.full(frontier.shape, int(frontier.sum()), dtype=np.int32)
    for window_m in (2.3, 1e3, 1e300):
        assert np.array_equal(frontier_entropy(frontier, window_m, 0.1), whole)
    assert not np.array_equal(frontier_entropy(frontier, 0.5, 0.1), whole)  # a window narrower than the map counts less


def test_a_goal_tolerance_wider_than_the_map_marks_every_cell_without_a_disk_of_its_width():
    """``episode.goal_tolerance_m: 1e300`` (``eval`` took it) failed every episode whose goal was given up on: the dead
    frontier's disk of 1e301 cells was more than numpy makes (a 100 km one, 4e12 cells). A disk past the map's farthest
    corner holds every cell of it, as one that reaches that corner does: it is made that large, the same cells."""
    from cso_runtime.episode import mark_dead_frontier
    from cso_runtime.geodesic import disk_cells

    g = GridGeometry(0.1, (7, 11), 0.0, 0.0)
    for xy in ((0.35, 0.55), (-0.5, 2.0)):  # a centre on the map, and one off it (its disk reaches in)
        whole = sorted(zip(*(a.tolist() for a in disk_cells(g, xy, 40))))
        assert len(whole) == 7 * 11 or xy[0] < 0
        assert sorted(zip(*(a.tolist() for a in disk_cells(g, xy, 10**301)))) == whole
        assert len(disk_cells(g, xy, 3)[0]) < len(whole)  # a disk inside the map holds less
    dead = np.zeros(g.shape, dtype=bool)
    mark_dead_frontier(dead, g, (0.35, 0.55), 1e300)
    assert dead.all()
