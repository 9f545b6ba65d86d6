"""How good would a warm-start teacher be? Baselines with and without the cso action masks, in one process.

    python benchmarks/teacher_ceiling.py --maps ../shared/maps/dungeon/train --limit 20 --m-per-px 0.05 \
        --methods greedy-dist,utility,utility+masks

A method ``NAME+masks`` is the baseline NAME choosing only among the actions the cso masks allow (the valid
distance mask and the stuck mask, as ``cso-runtime train`` imitates it with ``warm_start_teacher``), which is
the ceiling of imitating that teacher. Prints the mean efficiency per scale and the change against the first
method, on the 360-degree LiDAR of the tables, seed 0, two worker processes.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from cso_runtime.config import MaskConfig
from cso_runtime.episode import run_episode
from cso_runtime.evaluation import EvalRequest, make_simulator
from cso_runtime.learned.env import expert_action
from cso_runtime.observation import Observation
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


def run_one(job: tuple[SceneRef, str, float]) -> tuple[str, str, float, str]:
    ref, method, m_per_px = job
    cfg = EvalRequest(methods=["greedy-dist"], m_per_px=m_per_px, lidar_fov_deg=360.0).exploration_config()
    plan = ref.load()
    sim = make_simulator("2d", plan, cfg.sensor, cfg.robot, seed=0)
    base, _, masked = method.partition("+")
    policy = MaskedBaseline(base) if masked == "masks" else make_policy(base, seed=0)
    r = run_episode(sim, policy, cfg, seed=0)
    return ref.name, method, r.efficiency_m2_per_step, scale_of(r.traversable_area_m2)


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
    for scene, method, value, scale in results:
        eff[method][scene] = (value, scale)
    reference = methods[0]
    for method in methods:
        for scale in sorted({sc for _, sc in eff[method].values()}):
            scenes = [s for s, (_, sc) in eff[method].items() if sc == scale]
            e = np.mean([eff[method][s][0] for s in scenes])
            b = np.mean([eff[reference][s][0] for s in scenes])
            print(f"{method:24s} {scale:12s} scenes {len(scenes):3d}  m2/step {e:.4f}  vs {reference}: {100 * (e / b - 1):+.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
