"""What the runtime's messages cost to encode and decode: every decision message and map of one episode.

Runs one in-process episode, keeps the Observation of each decision and the map of each step, then times
``encode`` and ``decode`` of the ``frontiers`` messages built from them (what the frontier service
publishes and the policy and the planner decode) and of the ``map`` messages (best of ``--repeats``).

    python benchmarks/bench_messages.py [--scene generated:middle:1:0] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import Explorer, run_episode
from cso_runtime.messages import FrontiersMsg, MapMsg, decode, encode, frontiers_from_observation
from cso_runtime.observation import Observation
from cso_runtime.policies import Goal, make_policy
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator


def best_ms(fn, items: list, repeats: int) -> float:
    """Mean ms per item of the fastest of ``repeats`` passes."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for x in items:
            fn(x)
        best = min(best, (time.perf_counter() - t0) / len(items))
    return 1e3 * best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="generated:middle:1:0")
    p.add_argument("--method", default="greedy-dist")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    plan = resolve_scenes(args.scene)[0].load()
    selector = make_policy(args.method, seed=0)
    observations: list[Observation] = []
    maps: list[MapMsg] = []

    class Recording:
        """The selector, keeping every Observation it decides on."""

        name = selector.name

        def reset(self, seed: int | None = None) -> None:
            selector.reset(seed)

        def select(self, obs: Observation) -> Goal | None:
            observations.append(obs)
            return selector.select(obs)

    def keep_map(explorer: Explorer) -> None:
        maps.append(MapMsg(explorer.steps, explorer.map.geometry, explorer.map.to_occupancy_grid()))

    run_episode(KinematicSimulator(plan, seed=0), Recording(), ExplorationConfig(), seed=0, on_step=keep_map)
    decisions = [frontiers_from_observation(k, "timeout", obs, 0.0) for k, obs in enumerate(observations)]
    decision_bytes = [encode(m) for m in decisions]
    map_bytes = [encode(m) for m in maps]
    report = {
        "scene": args.scene,
        "frontiers_decision": {
            "messages": len(decisions),
            "kb_mean": round(float(np.mean([len(b) for b in decision_bytes])) / 1e3, 1),
            "encode_ms": round(best_ms(encode, decisions, args.repeats), 3),
            "decode_ms": round(best_ms(lambda b: decode(b, FrontiersMsg), decision_bytes, args.repeats), 3),
        },
        "map": {
            "messages": len(maps),
            "kb_mean": round(float(np.mean([len(b) for b in map_bytes])) / 1e3, 1),
            "encode_ms": round(best_ms(encode, maps, args.repeats), 3),
            "decode_ms": round(best_ms(lambda b: decode(b, MapMsg), map_bytes, args.repeats), 3),
        },
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
