"""Hot-loop cost of the per-step algorithms that every process runs (BENCHMARKS.md, "Per-step algorithms").

Records the scans of one in-process `greedy-dist` episode on a scene, then times each piece on them:
the mapper's ``integrate_scan``, the simulated LiDAR's ``cast_rays``, the 2D simulator's ``clearance_m``,
``frontier_components`` on the final map's frontiers, and decoding the scene's floor plan (PNG scenes).

    python benchmarks/bench_per_step.py [--scene builtin] [--m-per-px 0.1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import cso_runtime.episode as episode_module
import cso_runtime.simulator as simulator_module
from cso_runtime.config import ExplorationConfig
from cso_runtime.frontiers import frontier_cells, frontier_components
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.policies import make_policy
from cso_runtime.scenes import resolve_scenes


def per_call_ms(fn, calls: list[tuple], repeats: int) -> float:
    """Median over ``repeats`` of the mean ms per call of ``fn`` over ``calls``."""
    means = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for args in calls:
            fn(*args)
        means.append((time.perf_counter() - t0) / len(calls) * 1e3)
    return statistics.median(means)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="builtin")
    ap.add_argument("--m-per-px", type=float, default=0.1)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    ref = resolve_scenes(args.scene, resolution_m=args.m_per_px)[0]
    plan = ref.load()
    config = ExplorationConfig()
    scans, casts = [], []
    integrate, cast = episode_module.integrate_observation, simulator_module.cast_rays

    def record_integrate(occupancy, pose, scan, cfg):
        scans.append((pose, scan))
        return integrate(occupancy, pose, scan, cfg)

    def record_cast(*a):
        casts.append(a)
        return cast(*a)

    episode_module.integrate_observation, simulator_module.cast_rays = record_integrate, record_cast
    try:
        result = episode_module.run_episode(simulator_module.KinematicSimulator(plan, seed=0), make_policy("greedy-dist", seed=0, sensor=config.sensor), config, seed=0)
    finally:
        episode_module.integrate_observation, simulator_module.cast_rays = integrate, cast
    occupancy = OccupancyMap(plan.geometry)
    map_ms = per_call_ms(lambda pose, scan: occupancy.integrate_scan(pose, scan), scans, 1)  # the episode's map, built once
    sim = simulator_module.KinematicSimulator(plan, seed=0)
    points = [(float(x), float(y)) for x, y in result.trajectory_xy_m]
    frontier = frontier_cells(occupancy.open, occupancy.explored)
    print(f"{plan.name}: grid {plan.geometry.shape[0]} x {plan.geometry.shape[1]} at {plan.geometry.resolution_m} m, {result.steps} steps")
    print(f"  integrate_scan     {map_ms:7.3f} ms per scan (building the episode's map, {len(scans)} scans)")
    print(f"  cast_rays          {per_call_ms(cast, casts, args.repeats):7.3f} ms per scan")
    print(f"  clearance_m        {per_call_ms(sim.clearance_m, points, args.repeats) * 1e3:7.1f} us per call")
    print(f"  frontier_components{per_call_ms(frontier_components, [(frontier,)] * 50, args.repeats):7.3f} ms ({int(frontier.sum())} frontier cells)")
    if ref.path is not None and str(ref.path).endswith(".png"):
        from cso_runtime.scenes import load_floor_plan  # noqa: PLC0415

        print(f"  load_floor_plan    {per_call_ms(load_floor_plan, [(ref.path, args.m_per_px)] * 10, args.repeats):7.3f} ms per plan (PNG read included)")


if __name__ == "__main__":
    main()
