"""benchmarks/geodesic_entropy.py: Eq. 4's literal count leaves out the frontier cells behind a wall."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

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
