"""How good would a warm-start teacher be? Baselines with and without the cso action masks, in one process.

    python benchmarks/teacher_ceiling.py --maps ../shared/maps/dungeon/train --limit 20 --m-per-px 0.05 \
        --methods greedy-dist,utility,utility+masks

A method ``NAME+masks`` is the baseline NAME choosing only among the actions the cso masks allow (the valid
distance mask and the stuck mask, as ``cso-runtime train`` imitates it with ``warm_start_teacher``), which is
the ceiling of imitating that teacher. ``greedy-turn`` is greedy-dist charged for turning: the geodesic distance
plus ``TURN_COST_M_PER_RAD`` times the heading change towards the path's first 0.8 m (a candidate teacher for a
network that would see the robot's heading; the shipped graph's coordinates are not rotated into the robot frame).
``tour`` plans a global tour as FUEL does (the open travelling-salesman path through the nearest clusters on
geodesic distances) and goes to its first cluster: the candidate for a teacher that avoids long round trips.
``greedy-pocket:A:D`` closes a small pocket first: the nearest cluster bordering an unknown region smaller than
A m2 whose goal is at most D m further than the nearest goal (defaults 4 and 3).
``rolloutK`` (``rolloutK+masks``: among the clusters the cso masks allow) tries the K nearest clusters at every
decision, finishes the episode from each with greedy-dist on a copy of the simulation, and takes the one that
finished first (``episode.rollout_choice``): it sees the unexplored scene through the simulator, so it is the
ceiling of what choosing the order of the frontiers can give, and a teacher (``warm_start_teacher: rollout``).
Prints the mean efficiency per scale and the change against the first method, on the 360-degree LiDAR of the
tables, seed 0, two worker processes.
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from cso_runtime.config import MaskConfig
from cso_runtime.episode import Explorer, nearest_clusters, rollout_choice, run_episode
from cso_runtime.evaluation import EvalRequest, make_simulator
from cso_runtime.geometry import wrap_angle_rad
from cso_runtime.learned.env import expert_action
from cso_runtime.observation import Observation
from cso_runtime.planner import descend_path
from cso_runtime.policies import ActionMasker, Goal, goal_of, make_policy
from cso_runtime.scenes import SceneRef, resolve_scenes, scale_of


class MaskedBaseline:
    """A score baseline restricted to the actions the cso masks allow: the warm-start teacher itself."""

    def __init__(self, base: str):
        self.base = base
        self.name = f"{base}+masks"
        self.masker = ActionMasker(MaskConfig())

    def reset(self, seed: int | None = None) -> None:
        self.masker = ActionMasker(MaskConfig())

    def select(self, obs: Observation) -> Goal | None:
        if not obs.clusters:
            return None
        allowed = self.masker.mask(obs)
        if not (allowed & np.isfinite(obs.goal_distance_m)).any():
            return None
        return goal_of(obs, expert_action(obs, allowed, self.base))


TURN_COST_M_PER_RAD = 1.28
"""Turning in place at 0.78 rad/s takes as long as driving 1.28 m at 1 m/s (the LIMO limits of RobotConfig)."""


class GreedyTurn:
    """Greedy-dist plus the time of turning towards each goal's path, in metres of driving."""

    name = "greedy-turn"

    def reset(self, seed: int | None = None) -> None:
        pass

    def select(self, obs: Observation) -> Goal | None:
        cost = np.full(len(obs.clusters), np.inf)
        for i, c in enumerate(obs.clusters):
            if not np.isfinite(obs.goal_distance_m[i]):
                continue
            path = descend_path(obs.distance_m, obs.geometry, c.goal_cell)
            along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
            ahead = path[min(int(np.searchsorted(along, 0.8)), len(path) - 1)]
            dx, dy = ahead[0] - obs.pose.x_m, ahead[1] - obs.pose.y_m
            turn = abs(wrap_angle_rad(math.atan2(dy, dx) - obs.pose.yaw_rad)) if math.hypot(dx, dy) > 1e-6 else 0.0
            cost[i] = obs.goal_distance_m[i] + TURN_COST_M_PER_RAD * turn
        if not np.isfinite(cost).any():
            return None
        return goal_of(obs, int(np.argmin(cost)))


class Tour:
    """A global tour (as FUEL's): the open travelling-salesman path from the robot through the goal cells of
    the ``max_clusters`` nearest clusters, on geodesic distances (one fast-marching pass per cluster), by
    cheapest insertion and 2-opt; the goal is the tour's first cluster. For consistency (a tour recomputed
    from a new position may start elsewhere, and the robot would turn back and forth) the tour that starts
    at the previous goal's cluster is kept while it is at most ``keep_margin_m`` longer."""

    name = "tour"

    def __init__(self, max_clusters: int = 14, keep_margin_m: float = 2.0):
        self.max_clusters = max_clusters
        self.keep_margin_m = keep_margin_m
        self.previous_xy_m: np.ndarray | None = None

    def reset(self, seed: int | None = None) -> None:
        self.previous_xy_m = None

    def select(self, obs: Observation) -> Goal | None:
        d0 = obs.goal_distance_m
        order = [i for i in np.argsort(d0, kind="stable") if np.isfinite(d0[i])][: self.max_clusters]
        if not order:
            return None
        n = len(order)
        cost = np.zeros((n + 1, n + 1))  # node 0 = the robot
        cost[0, 1:] = d0[order]
        for a, i in enumerate(order):
            cost[a + 1, 1:] = obs.goal_distances_from(tuple(obs.clusters[i].goal_xy_m))[order]
        # Through the robot's position is always a way (bounds a pass that failed from a goal cell's pocket).
        via_robot = cost[0, 1:, None] + cost[0, None, 1:]
        cost[1:, 1:] = np.fmin(np.minimum(cost[1:, 1:], cost[1:, 1:].T), via_robot)
        cost[1:, 0] = 0.0  # open path: returning costs nothing
        tour = open_tour(cost)
        first = tour[0]
        if self.previous_xy_m is not None:
            gaps = np.hypot(*(obs.goal_xy_m[order] - self.previous_xy_m).T)
            k = int(np.argmin(gaps))
            if gaps[k] < 1.0 and k + 1 != first:
                kept = open_tour(cost, start=k + 1)
                if tour_length(cost, kept) <= tour_length(cost, tour) + self.keep_margin_m:
                    first = k + 1
        goal = goal_of(obs, int(order[first - 1]))
        self.previous_xy_m = np.array([goal.x_m, goal.y_m])
        return goal


def tour_length(cost: np.ndarray, tour: list[int]) -> float:
    return float(cost[0, tour[0]] + sum(cost[a, b] for a, b in itertools.pairwise(tour)))


def open_tour(cost: np.ndarray, start: int | None = None) -> list[int]:
    """Nodes 1..n in visiting order from node 0 (no return), by cheapest insertion then 2-opt;
    ``start`` fixes the first node."""
    n = cost.shape[0] - 1
    tour = [start if start is not None else int(np.argmin(cost[0, 1:])) + 1]
    rest = set(range(1, n + 1)) - set(tour)
    lo = 0 if start is None else 1
    while rest:
        best = None
        for v in rest:
            for pos in range(lo, len(tour) + 1):
                prev = 0 if pos == 0 else tour[pos - 1]
                add = cost[prev, v] + (cost[v, tour[pos]] - cost[prev, tour[pos]] if pos < len(tour) else 0.0)
                if best is None or add < best[0]:
                    best = (add, v, pos)
        _, v, pos = best
        tour.insert(pos, v)
        rest.discard(v)
    improved = True
    while improved:
        improved = False
        for i in range(lo, len(tour) - 1):
            for j in range(i + 1, len(tour)):
                cand = tour[:i] + tour[i : j + 1][::-1] + tour[j + 1 :]
                if tour_length(cost, cand) < tour_length(cost, tour) - 1e-9:
                    tour, improved = cand, True
    return tour


class Rollout:
    """``rollout_choice`` over greedy-dist at every decision: the ``k`` nearest reachable clusters are tried, the
    episode finished from each with greedy-dist on a copy of the explorer, and the one that finished in the
    fewest steps is taken. Greedy-dist's own choice is among the tries, and the simulator shows it the rest
    of the scene: the ceiling of what ordering the frontiers can give here, not a method to ship."""

    name = "rollout"

    def __init__(self, k: int = 3, masked: bool = False):
        self.k = k
        self.explorer: Explorer | None = None
        self.greedy = make_policy("greedy-dist", seed=0)
        self.masker = ActionMasker(MaskConfig()) if masked else None
        """With the cso masks: only the clusters they allow are tried (what a masked network could imitate)."""
        self.choices: list[dict[str, float]] = []
        """Each decision with a choice: the rank of the cluster taken among the tries (0 = greedy-dist's), and the
        distance, length and entropy of the cluster taken and of the nearest one (what a network would see)."""

    def reset(self, seed: int | None = None) -> None:
        pass

    def select(self, obs: Observation) -> Goal | None:
        assert self.explorer is not None, "bind the explorer first (run_rollout)"
        everything = np.ones(len(obs.clusters), dtype=bool)
        tries = nearest_clusters(obs.goal_distance_m, self.masker.mask(obs) if self.masker is not None else everything, self.k)
        if len(tries) == 0 and self.masker is not None:  # every reachable cluster masked: as the policy does, ignore the mask
            tries = nearest_clusters(obs.goal_distance_m, everything, self.k)
        if len(tries) == 0:
            return None
        action = rollout_choice(self.explorer, obs, tries, self.greedy)
        if len(tries) > 1:
            taken, near = obs.clusters[action], obs.clusters[int(tries[0])]
            self.choices.append(
                {
                    "rank": float(np.flatnonzero(tries == action)[0]),
                    "distance_m": float(obs.goal_distance_m[action]),
                    "nearest_distance_m": float(obs.goal_distance_m[tries[0]]),
                    "size_m": taken.size_m,
                    "nearest_size_m": near.size_m,
                    "entropy": taken.entropy,
                    "nearest_entropy": near.entropy,
                }
            )
        return goal_of(obs, action)


def run_rollout(sim, cfg, k: int = 3, masked: bool = False):
    """An episode with ``Rollout(k, masked)`` deciding (it needs the explorer to copy); its result and choices."""
    explorer = Explorer(sim, cfg)
    sim.reset(0)
    explorer.reset()
    policy = Rollout(k, masked)
    policy.explorer = explorer
    return explorer.run(policy), policy.choices


def print_departures(method: str, choices: list[dict[str, float]]) -> None:
    """Where the rollout leaves greedy-dist's choice, and what the cluster it takes looks like instead."""
    away = [c for c in choices if c["rank"] > 0]
    print(f"{method}: {len(away)} of {len(choices)} decisions with a choice take another cluster than the nearest")
    if away:
        further = np.median([c["distance_m"] - c["nearest_distance_m"] for c in away])
        ratio = np.median([c["distance_m"] / max(c["nearest_distance_m"], 1e-6) for c in away])
        smaller = np.mean([c["size_m"] < c["nearest_size_m"] for c in away])
        size_ratio = np.median([c["size_m"] / max(c["nearest_size_m"], 1e-6) for c in away])
        lower_info = np.mean([c["entropy"] < c["nearest_entropy"] for c in away])
        print(
            f"  then: {further:.2f} m further (median, {ratio:.2f}x the nearest), a shorter cluster in {100 * smaller:.0f} % "
            f"(median {size_ratio:.2f}x its length), lower entropy in {100 * lower_info:.0f} %"
        )


class GreedyPocket:
    """Greedy-dist that first closes a small pocket nearby: a cluster whose bordering unknown region (a
    connected component of unknown cells) is smaller than ``max_pocket_m2`` and whose goal is at most
    ``detour_m`` further than the nearest goal wins over the nearest. A pocket left behind costs a round
    trip later; the candidate for a teacher that "finishes the room before leaving"."""

    name = "greedy-pocket"

    def __init__(self, max_pocket_m2: float = 4.0, detour_m: float = 3.0):
        self.max_pocket_m2, self.detour_m = max_pocket_m2, detour_m

    def reset(self, seed: int | None = None) -> None:
        pass

    def select(self, obs: Observation) -> Goal | None:
        from scipy import ndimage  # noqa: PLC0415

        d = obs.goal_distance_m
        if not obs.clusters or not np.isfinite(d).any():
            return None
        labels, _ = ndimage.label(~obs.explored)
        sizes = np.bincount(labels.ravel()) * obs.geometry.cell_area_m2
        nearest = int(np.nanargmin(np.where(np.isfinite(d), d, np.nan)))
        best, best_d = nearest, np.inf
        for i, c in enumerate(obs.clusters):
            if not np.isfinite(d[i]) or d[i] > d[nearest] + self.detour_m:
                continue
            cells = np.asarray(c.cells).reshape(-1, 2)
            ys = np.clip(cells[:, 0][:, None] + np.array([-1, -1, -1, 0, 0, 1, 1, 1]), 0, labels.shape[0] - 1)
            xs = np.clip(cells[:, 1][:, None] + np.array([-1, 0, 1, -1, 1, -1, 0, 1]), 0, labels.shape[1] - 1)
            touched = np.unique(labels[ys, xs])
            pocket_m2 = sizes[touched[touched > 0]].sum()
            if pocket_m2 < self.max_pocket_m2 and d[i] < best_d:
                best, best_d = i, d[i]
        return goal_of(obs, best)


CANDIDATES = {"greedy-turn": GreedyTurn, "tour": Tour, "greedy-pocket": GreedyPocket}
"""Teacher candidates that are not methods of ``cso-runtime eval``."""


def run_one(job: tuple[SceneRef, str, float]) -> tuple[str, str, float, str, list[dict[str, float]]]:
    ref, method, m_per_px = job
    cfg = EvalRequest(methods=["greedy-dist"], m_per_px=m_per_px, lidar_fov_deg=360.0).exploration_config()
    plan = ref.load()
    sim = make_simulator("2d", plan, cfg.sensor, cfg.robot, seed=0)
    base, _, masked = method.partition("+")
    if base.startswith("rollout"):  # rollout or rolloutK: K clusters tried at each decision (default 3)
        r, choices = run_rollout(sim, cfg, int(base[len("rollout") :] or 3), masked == "masks")
        return ref.name, method, r.efficiency_m2_per_step, scale_of(r.traversable_area_m2), choices
    if masked == "masks":
        policy = MaskedBaseline(base)
    else:
        name, *params = base.split(":")  # NAME:P1:P2 passes numeric parameters to a candidate
        policy = CANDIDATES[name](*map(float, params)) if name in CANDIDATES else make_policy(base, seed=0)
    r = run_episode(sim, policy, cfg, seed=0)
    return ref.name, method, r.efficiency_m2_per_step, scale_of(r.traversable_area_m2), []


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", required=True)
    p.add_argument("--limit", type=int, default=20)
    p.add_argument("--m-per-px", type=float, default=0.1)
    p.add_argument("--methods", default="greedy-dist,utility,utility+masks")
    args = p.parse_args(argv)
    methods = args.methods.split(",")
    refs = resolve_scenes(args.maps, limit=args.limit, resolution_m=args.m_per_px)
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(run_one, [(r, m, args.m_per_px) for r in refs for m in methods]))
    eff: dict[str, dict[str, tuple[float, str]]] = defaultdict(dict)
    choices: dict[str, list[dict[str, float]]] = defaultdict(list)
    for scene, method, value, scale, made in results:
        eff[method][scene] = (value, scale)
        choices[method] += made
    reference = methods[0]
    for method in methods:
        for scale in sorted({sc for _, sc in eff[method].values()}):
            scenes = [s for s, (_, sc) in eff[method].items() if sc == scale]
            e = np.mean([eff[method][s][0] for s in scenes])
            b = np.mean([eff[reference][s][0] for s in scenes])
            print(f"{method:24s} {scale:12s} scenes {len(scenes):3d}  m2/step {e:.4f}  vs {reference}: {100 * (e / b - 1):+.1f} %")
    for method in methods:
        if method.startswith("rollout"):
            print_departures(method, choices[method])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
