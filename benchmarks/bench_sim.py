"""MuJoCo LIMO simulator speed: lockstep real-time factor and the cost of one LiDAR scan.

Run on one core:  OMP_NUM_THREADS=1 python benchmarks/bench_sim.py [--plan PNG] [--steps N]

* scan cost: ``mj_multiRay`` from the LiDAR site (180 and 360 degrees, 1 degree, 8 m) at random
  free poses of the plan, next to the 2D simulator's grid ray casting for reference;
* physics only: ``step`` with a scripted drive (the LiDAR fires at 8 Hz but no scan is cast);
* sim + LiDAR + mapper: a reactive wander where every scan fired at 8 Hz is cast and integrated into
  an ``OccupancyMap`` (no policy, no planner): the simulator's share of an exploration run;
* full loop: ``run_episode`` with greedy-dist (mapper, frontiers, policy, local planner) where every
  scan the LiDAR fires at 8 Hz is cast and integrated by the mapper (``OccupancyMap.integrate_scan``):
  the runner integrates the scan at the end of each 0.25 s step, the ``on_step`` hook the one fired
  mid-step. Real-time factor (RTF) = simulated seconds / seconds (target >= 20x on one core), by
  wall clock and by this process's CPU time (the better estimate on a busy shared machine).
* ``--compare N``: coverage and steps of greedy-dist with the 360-degree LiDAR, MuJoCo vs the 2D
  simulator, on the first N plans of ``--plans-dir`` (slow: minutes per plan).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path
from typing import final

import numpy as np

from cso_runtime.config import EpisodeConfig, ExplorationConfig
from cso_runtime.episode import Explorer, run_episode
from cso_runtime.geometry import Pose2D, VelocityCommand
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.policies import make_policy
from cso_runtime.scenes import FloorPlan, builtin_scene_dir, load_floor_plan
from cso_runtime.simulator import KinematicSimulator
from robot_sim import MujocoSimulator
from robot_sim.config import limo_sensor

SHARED_PLAN = Path("/work/shared/maps/dungeon/easy/img_1.png")


def default_plan() -> Path:
    builtin = builtin_scene_dir() / "img_1.png"
    return builtin if builtin.is_file() else SHARED_PLAN


def random_free_poses(plan: FloorPlan, n: int, seed: int = 0) -> list[Pose2D]:
    rng = np.random.default_rng(seed)
    iy, ix = np.nonzero(plan.traversable_region())
    k = rng.choice(len(iy), n)
    xs, ys = plan.geometry.cell_to_world(iy[k], ix[k])
    return [Pose2D(float(x), float(y), float(a)) for x, y, a in zip(xs, ys, rng.uniform(-math.pi, math.pi, n))]


@final
class Clock:
    """Wall and CPU seconds of a block. On a shared machine the CPU time of this single-threaded
    process is the better estimate of what one free core would do; both are reported."""

    def __enter__(self) -> Clock:
        self._wall, self._cpu = time.perf_counter(), time.process_time()
        self.wall_s = self.cpu_s = 0.0
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall_s = time.perf_counter() - self._wall
        self.cpu_s = time.process_time() - self._cpu


def bench_scan(plan: FloorPlan, fov_deg: float, n: int = 500) -> tuple[float, float]:
    """CPU ms per scan: (MuJoCo mj_multiRay, 2D grid ray casting)."""
    sensor = dataclasses.replace(limo_sensor(), fov_deg=fov_deg)
    sim = MujocoSimulator(plan, sensor, seed=0)
    kin = KinematicSimulator(plan, sensor, seed=0)
    poses = random_free_poses(plan, n)
    with Clock() as mj:
        for k, p in enumerate(poses):
            sim.cast_scan(p, k)
    with Clock() as grid:
        for p in poses:
            kin._pose = p
            kin.scan()
    return mj.cpu_s * 1e3 / n, grid.cpu_s * 1e3 / n


def bench_physics(plan: FloorPlan, steps: int) -> dict[str, float]:
    """``step`` alone, driving a scripted slalom (wall contacts included); the LiDAR fires but no scan is cast."""
    sim = MujocoSimulator(plan, limo_sensor(), seed=0)
    with Clock() as clock:
        for k in range(steps):
            sim.step(VelocityCommand(0.8, 0.6 * math.sin(0.1 * k)))
    return {"rtf_wall": sim.time_s / clock.wall_s, "rtf_cpu": sim.time_s / clock.cpu_s}


def bench_mapping(plan: FloorPlan, steps: int, fov_deg: float) -> dict[str, float]:
    """Simulator + LiDAR + mapper, both at 8 Hz, with a reactive wander (no policy or planner)."""
    sensor = dataclasses.replace(limo_sensor(), fov_deg=fov_deg)
    sim = MujocoSimulator(plan, sensor, seed=0)
    occupancy = OccupancyMap(plan.geometry)
    sim.drain_scans()
    scans = 0
    mapper_cpu_s = 0.0
    with Clock() as clock:
        for k in range(steps):
            scan = sim.scan()
            r = np.where(np.isfinite(scan.ranges_m), scan.ranges_m, scan.range_max_m)
            ahead = (np.abs(np.sin(scan.angles_rad)) * r < 0.2) & (np.cos(scan.angles_rad) > 0)  # within the body's width
            front = float(np.min(np.where(ahead, r, np.inf)))
            sim.step(VelocityCommand(0.8, 0.3 * math.sin(0.05 * k)) if front > 0.6 else VelocityCommand(0.0, 0.78))
            fired = sim.drain_scans()
            with Clock() as mapping:
                for pose, s in fired:
                    occupancy.integrate_scan(pose, s)
            mapper_cpu_s += mapping.cpu_s
            scans += len(fired)
    return {
        "rtf_wall": sim.time_s / clock.wall_s,
        "rtf_cpu": sim.time_s / clock.cpu_s,
        "rtf_cpu_without_mapper": sim.time_s / (clock.cpu_s - mapper_cpu_s),
        "mapper_ms_per_scan": mapper_cpu_s * 1e3 / scans,
        "scans_per_sim_s": scans / sim.time_s,
        "collisions": sim.collisions,
    }


def bench_episode(plan: FloorPlan, steps: int, fov_deg: float) -> dict[str, float]:
    """Full exploration loop with the LiDAR and the mapper at 8 Hz."""
    sensor = dataclasses.replace(limo_sensor(), fov_deg=fov_deg)
    config = ExplorationConfig(sensor=sensor, episode=EpisodeConfig(max_steps=steps))
    sim = MujocoSimulator(plan, sensor, config.robot, seed=0)
    integrated = [0]

    def on_step(explorer: Explorer) -> None:
        fired = sim.drain_scans()
        for pose, scan in fired[:-1]:  # the runner already integrated the last one (sim.scan())
            explorer.map.integrate_scan(pose, scan)
        integrated[0] += len(fired)

    with Clock() as clock:
        result = run_episode(sim, make_policy("greedy-dist"), config, seed=0, on_step=on_step)
    return {
        "rtf_wall": sim.time_s / clock.wall_s,
        "rtf_cpu": sim.time_s / clock.cpu_s,
        "steps": result.steps,
        "sim_s": sim.time_s,
        "scans_per_sim_s": integrated[0] / max(sim.time_s, 1e-9),
        "coverage_pct": result.coverage_pct,
        "collisions": sim.collisions,
    }


def compare(plans: list[Path], resolution_m: float) -> None:
    sensor = dataclasses.replace(limo_sensor(), fov_deg=360.0)
    config = ExplorationConfig(sensor=sensor)
    print(f"{'plan':<10} {'sim':<7} {'coverage %':>10} {'steps':>6} {'terminated':>11} {'collisions':>10} {'wall s':>7}")
    for path in plans:
        plan = load_floor_plan(path, resolution_m)
        for name in ("2d", "mujoco"):
            sim = MujocoSimulator(plan, sensor, config.robot, seed=0) if name == "mujoco" else KinematicSimulator(plan, sensor, config.robot, seed=0)
            with Clock() as clock:
                r = run_episode(sim, make_policy("greedy-dist"), config, seed=0)
            print(
                f"{plan.name:<10} {name:<7} {r.coverage_pct:>10.1f} {r.steps:>6} {r.terminated_by:>11} {sim.collisions:>10} "
                f"{clock.wall_s:>7.1f}",
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plan", type=Path, default=None, help="Dungeon PNG (default: the builtin img_1, else the shared one)")
    ap.add_argument("--resolution", type=float, default=0.1, help="metres per pixel")
    ap.add_argument("--steps", type=int, default=400, help="control steps (0.25 s) per timed run")
    ap.add_argument("--compare", type=int, default=0, help="also compare coverage with the 2D sim on N plans")
    ap.add_argument("--plans-dir", type=Path, default=SHARED_PLAN.parent)
    args = ap.parse_args()

    path = args.plan or default_plan()
    plan = load_floor_plan(path, args.resolution)
    sim = MujocoSimulator(plan, seed=0)
    print(f"plan {path} ({plan.free.shape[1]}x{plan.free.shape[0]} px at {args.resolution} m/px): {sim.n_wall_boxes} wall boxes")
    row = "{:<52} {:>10} {:>10}"
    print(row.format("measure", "wall", "cpu"))
    for fov in (180.0, 360.0):
        mj_ms, grid_ms = bench_scan(plan, fov)
        print(row.format(f"scan cost {fov:.0f} deg, mj_multiRay (ms)", "", f"{mj_ms:.3f}"))
        print(row.format(f"scan cost {fov:.0f} deg, 2D grid ray casting (ms)", "", f"{grid_ms:.3f}"))
    e = bench_physics(plan, args.steps)
    print(row.format("RTF physics only (sim s / s)", f"{e['rtf_wall']:.1f}", f"{e['rtf_cpu']:.1f}"))
    for fov in (180.0, 360.0):
        e = bench_mapping(plan, args.steps, fov)
        print(row.format(f"RTF sim + LiDAR {fov:.0f} deg + mapper, {e['scans_per_sim_s']:.0f} Hz", f"{e['rtf_wall']:.1f}", f"{e['rtf_cpu']:.1f}"))
        print(row.format("  the same without the mapper's time", "", f"{e['rtf_cpu_without_mapper']:.1f}"))
        print(row.format("  mapper integrate_scan (ms per scan)", "", f"{e['mapper_ms_per_scan']:.2f}"))
    for fov in (180.0, 360.0):
        e = bench_episode(plan, args.steps, fov)
        label = f"RTF episode greedy-dist, LiDAR {fov:.0f} deg, mapper {e['scans_per_sim_s']:.0f} Hz"
        print(row.format(label, f"{e['rtf_wall']:.1f}", f"{e['rtf_cpu']:.1f}"))
        print(f"  ({e['steps']} steps, {e['sim_s']:.0f} sim s, coverage {e['coverage_pct']:.1f} %, {e['collisions']} collisions)")
    if args.compare:
        compare(sorted(args.plans_dir.glob("*.png"), key=lambda p: int("".join(c for c in p.stem if c.isdigit()) or 0))[: args.compare], args.resolution)


if __name__ == "__main__":
    main()
