"""Decision latency against one bare fast-marching call (issue: exploration core, target <= 2.0x).

On a 640x480 Dungeon plan explored to about half by greedy-dist, times one full decision
(frontiers, clusters, geodesic map, entropy, both masks, greedy choice) and one bare
``skfmm.distance`` on the same grid, interleaved in the same run so machine noise hits both.
Also times integrating one 180-degree LiDAR scan.

    python benchmarks/bench_decision.py [--plan PNG] [--repeats 30] [--json F]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import skfmm

from cso_runtime.config import ExplorationConfig, MaskConfig, SensorConfig
from cso_runtime.doctor import machine_facts
from cso_runtime.episode import Explorer
from cso_runtime.observation import ObservationBuilder
from cso_runtime.policies import ActionMasker, GreedyDist, goal_of
from cso_runtime.scenes import builtin_scene_dir, load_floor_plan
from cso_runtime.simulator import KinematicSimulator


def half_explored(plan_path: str) -> Explorer:
    plan = load_floor_plan(plan_path, 0.1)
    cfg = ExplorationConfig(sensor=SensorConfig.preset("lidar", fov_deg=180))
    explorer = Explorer(KinematicSimulator(plan, cfg.sensor, cfg.robot), cfg)
    policy = GreedyDist()
    while explorer.coverage_pct() < 50.0 and not explorer.done:
        reason = explorer.decision_reason()
        if reason:
            explorer.handle_reason(reason)
            obs = explorer.observe()
            explorer.apply_goal(obs, policy.select(obs))
        explorer.advance()
    return explorer


def full_decision(builder: ObservationBuilder, masker: ActionMasker, explorer: Explorer):
    obs = builder.build(explorer.map, explorer.sim.odometry())
    allowed = masker.mask(obs)
    d = np.where(allowed, obs.goal_distance_m, np.inf)
    return goal_of(obs, int(np.argmin(d))) if np.isfinite(d).any() else None


def bare_fmm(traversable: np.ndarray, source_cell: tuple[int, int], dx: float) -> None:
    phi = np.ones(traversable.shape)
    phi[source_cell] = -1.0
    skfmm.distance(np.ma.MaskedArray(phi, ~traversable), dx=dx)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plan", default=str(builtin_scene_dir() / "img_1.png"))
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here, with the machine they were taken on")
    args = ap.parse_args()

    explorer = half_explored(args.plan)
    g = explorer.map.geometry
    builder = ObservationBuilder(explorer.config.frontier, explorer.config.robot)
    obs = builder.build(explorer.map, explorer.sim.odometry())
    sy, sx = g.world_to_cell(*explorer.sim.odometry().xy)
    source = (int(sy), int(sx))
    full_grid = np.ones(g.shape, dtype=bool)
    decision_ms, fmm_ms, fmm_unmasked_ms = [], [], []
    for _ in range(args.repeats):
        masker = ActionMasker(MaskConfig())
        t0 = time.perf_counter()
        full_decision(builder, masker, explorer)
        t1 = time.perf_counter()
        bare_fmm(obs.traversable, source, g.resolution_m)
        t2 = time.perf_counter()
        bare_fmm(full_grid, source, g.resolution_m)
        t3 = time.perf_counter()
        decision_ms.append((t1 - t0) * 1e3)
        fmm_ms.append((t2 - t1) * 1e3)
        fmm_unmasked_ms.append((t3 - t2) * 1e3)

    scan_ms = []
    sim = explorer.sim
    scan = sim.scan()
    for _ in range(args.repeats * 3):
        t0 = time.perf_counter()
        explorer.map.integrate_scan(sim.sensor_pose(), scan)
        scan_ms.append((time.perf_counter() - t0) * 1e3)

    med = statistics.median
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print(f"plan: {args.plan} {g.shape[1]}x{g.shape[0]} at {g.resolution_m} m/px, coverage {explorer.coverage_pct():.1f}%, "
          f"{len(obs.clusters)} frontier clusters, {args.repeats} repeats (medians)")
    print(f"full decision                      : {med(decision_ms):8.2f} ms")
    print(f"bare skfmm.distance (traversable)  : {med(fmm_ms):8.2f} ms   ratio {med(decision_ms) / med(fmm_ms):.2f}x (target <= 2.0x)")
    print(f"bare skfmm.distance (whole grid)   : {med(fmm_unmasked_ms):8.2f} ms   ratio {med(decision_ms) / med(fmm_unmasked_ms):.2f}x")
    print(f"integrate one {len(scan.ranges_m)}-beam scan      : {med(scan_ms):8.2f} ms")
    if args.json:
        report = {
            "command": f"python benchmarks/bench_decision.py --plan {args.plan} --repeats {args.repeats}",
            "machine": machine_facts(),
            "grid": [g.shape[1], g.shape[0]],
            "resolution_m": g.resolution_m,
            "coverage_pct": round(explorer.coverage_pct(), 2),
            "frontier_clusters": len(obs.clusters),
            "full_decision_ms_median": round(med(decision_ms), 3),
            "bare_fmm_traversable_ms_median": round(med(fmm_ms), 3),
            "bare_fmm_whole_grid_ms_median": round(med(fmm_unmasked_ms), 3),
            "decision_over_bare_fmm": round(med(decision_ms) / med(fmm_ms), 3),
            "integrate_scan_ms_median": round(med(scan_ms), 3),
            "scan_beams": len(scan.ranges_m),
        }
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
