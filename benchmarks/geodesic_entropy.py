"""Eq. 4 read literally: frontier cells within geodesic distance of a goal, not in a square window (an experiment).

The paper's Eq. 4 counts the frontiers within geodesic distance gamma of a cell; its Figure 3 and text count them in
the gamma x gamma submap centred on it, which `cso_runtime.frontiers.frontier_entropy` does. Here each frontier
cluster's entropy (the network's `entropy` node feature) becomes the number of frontier cells within geodesic distance
gamma / 2 of its goal cell through open cells, times 4 / pi (the disc against the square of side gamma, so that the
feature keeps its scale): frontier cells behind a wall no longer count.

    python benchmarks/geodesic_entropy.py compare --maps runs/dev/plans --m-per-px 0.05 --limit 8
    python benchmarks/geodesic_entropy.py cli train --config configs/train.yaml --out runs/train/cso-geoent-s1 --seed 1
    python benchmarks/geodesic_entropy.py cli eval --method cso --weights runs/train/cso-geoent-s1 --lidar-fov 360 \\
        --workers 1 --maps runs/dev/plans --m-per-px 0.05 --out runs/dev/cso-geoent-s1_0.05

``compare`` runs greedy-dist episodes and compares both counts at every cluster of every decision. ``cli`` runs any
``cso-runtime`` command with the literal count in place (training without ``--async-envs`` and ``eval --workers 1``
keep it in this process). docs/experiments/learned-policy.md, "Eq. 4 read literally", has the results: not shipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys

import numpy as np
from scipy.stats import spearmanr

from cso_runtime import observation
from cso_runtime.config import ExplorationConfig, SensorConfig
from cso_runtime.episode import run_episode
from cso_runtime.geodesic import geodesic_distance
from cso_runtime.policies import GreedyDist
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import make_simulator


def geodesic_counts(obs: observation.Observation, open_cells: np.ndarray, window_m: float) -> np.ndarray:
    """Frontier cells within geodesic distance window_m / 2 of each cluster's goal cell, through open cells, x 4/pi."""
    half = window_m / 2.0
    counts = []
    for c in obs.clusters:
        d = geodesic_distance(open_cells, obs.geometry, np.array(c.goal_xy_m), within_m=half * 1.0001)
        counts.append(float(np.count_nonzero(obs.frontier & (d < half))) * 4.0 / math.pi)
    return np.array(counts)


def use_geodesic_entropy() -> None:
    """Every Observation built in this process from now on carries the literal count as its clusters' entropy."""
    build = observation.ObservationBuilder.build

    def literal(self, occupancy, pose, path_nodes_xy_m=None, exclude_frontier=None, layer=None):
        obs = build(self, occupancy, pose, path_nodes_xy_m, exclude_frontier, layer)
        counts = geodesic_counts(obs, occupancy.open, self.frontier_config.entropy_window_m)
        obs.clusters = [dataclasses.replace(c, entropy=float(n)) for c, n in zip(obs.clusters, counts)]
        return obs

    observation.ObservationBuilder.build = literal


class _Recorder(GreedyDist):
    """greedy-dist that keeps (square count, literal count) of every cluster of every decision."""

    def __init__(self, window_m: float):
        super().__init__()
        self.window_m = window_m
        self.decisions: list[np.ndarray] = []

    def select(self, obs):
        counts = geodesic_counts(obs, obs.explored & ~obs.occupied, self.window_m)
        self.decisions.append(np.stack([[c.entropy for c in obs.clusters], counts], axis=1) if obs.clusters else np.zeros((0, 2)))
        return super().select(obs)


def compare(maps: str, m_per_px: float, limit: int) -> None:
    config = ExplorationConfig()
    config.sensor = SensorConfig.preset("lidar", 360)
    decisions: list[np.ndarray] = []
    for ref in resolve_scenes(maps, limit, m_per_px):
        plan = ref.load()
        recorder = _Recorder(config.frontier.entropy_window_m)
        run_episode(make_simulator("2d", plan, config.sensor, config.robot, seed=0), recorder, config, seed=0)
        decisions += recorder.decisions
    pairs = np.concatenate(decisions)
    square, literal = pairs[:, 0], pairs[:, 1]
    ranked = [d for d in decisions if len(d) >= 3 and np.ptp(d[:, 0]) > 0 and np.ptp(d[:, 1]) > 0]
    rho = np.array([spearmanr(d[:, 0], d[:, 1]).statistic for d in ranked])
    same_top = np.mean([np.argmax(d[:, 0]) == np.argmax(d[:, 1]) for d in ranked])
    print(f"{len(pairs)} clusters at {len(decisions)} decisions: mean count {square.mean():.1f} (square) and {literal.mean():.1f} (literal, x 4/pi)")
    print(f"correlation over all clusters {np.corrcoef(square, literal)[0, 1]:.3f}")
    print(f"within a decision of 3+ clusters ({len(ranked)}): rank correlation median {np.median(rho):.3f}, 10th percentile {np.quantile(rho, 0.1):.3f}; "
          f"the same cluster has the most entropy in {100 * same_top:.0f} %")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["cli"]:
        from cso_runtime.cli import app  # noqa: PLC0415

        use_geodesic_entropy()
        app(argv[1:])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("compare", help="both counts at every cluster of greedy-dist's decisions")
    c.add_argument("--maps", required=True)
    c.add_argument("--m-per-px", type=float, default=0.05)
    c.add_argument("--limit", type=int, default=8)
    sub.add_parser("cli", help="a cso-runtime command with the literal count (the rest of the line)")
    args = parser.parse_args(argv)
    compare(args.maps, args.m_per_px, args.limit)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
