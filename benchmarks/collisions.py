"""How often the controller drives the 2D robot into a wall: collision substeps per episode (``KinematicSimulator.collisions``,
each a substep the simulator refused because the robot's disc would have entered a wall), with a chosen sensor.

    python benchmarks/collisions.py --maps generated:large:3:0 --sensor depth --json F

The narrow depth camera (79 degrees, nothing nearer than 0.3 m) is where the controller used to lose walls: beams
under ``range_min`` were dropped, so a wall closer than that read as open space.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from cso_runtime.config import ExplorationConfig, SensorConfig
from cso_runtime.episode import run_episode
from cso_runtime.policies import make_policy
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", default="generated:large:3:0", help="scene spec (as eval --maps)")
    ap.add_argument("--sensor", default="depth", choices=("lidar", "depth"))
    ap.add_argument("--mount-x-m", type=float, default=0.0, help="sensor.mount_x_m (0.103: the LIMO's)")
    ap.add_argument("--method", default="greedy-dist")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args()
    config = ExplorationConfig()
    config.sensor = dataclasses.replace(SensorConfig.preset(args.sensor), mount_x_m=args.mount_x_m)
    episodes = []
    for ref in resolve_scenes(args.maps):
        sim = KinematicSimulator(ref.load(), config.sensor, config.robot, seed=0)
        t0 = time.perf_counter()
        result = run_episode(sim, make_policy(args.method, seed=0, sensor=config.sensor), config, seed=0)
        episodes.append({"map": ref.name, "collision_substeps": sim.collisions, "steps": result.steps, "coverage_pct": round(result.coverage_pct, 3),
                         "terminated_by": result.terminated_by, "wall_s": round(time.perf_counter() - t0, 1)})
        print(json.dumps(episodes[-1]), flush=True)
    out = {"maps": args.maps, "sensor": args.sensor, "mount_x_m": args.mount_x_m, "method": args.method, "episodes": episodes,
           "collision_substeps_total": sum(e["collision_substeps"] for e in episodes)}
    print(f"collision substeps: {out['collision_substeps_total']} in {len(episodes)} episodes")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
