"""What the runtime's messages cost to encode and decode: every decision message and map of one episode.

Runs one in-process episode, keeps the Observation of each decision and the map of each step, then times
``encode`` and ``decode`` of the ``frontiers`` messages built from them (what the frontier service
publishes and the policy and the planner decode; with their largest size and each part's mean size) and
of the ``map`` messages (best of ``--repeats``);
then the small messages every lockstep step carries (scan, odometry, velocity command, the planner's
report and path, a keep-goal verdict), built from the same episode's states.

    python benchmarks/bench_messages.py [--scene generated:middle:1:0] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import msgpack
import numpy as np

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import Explorer, run_episode
from cso_runtime.geometry import VelocityCommand
from cso_runtime.messages import (
    CmdVelMsg,
    FrontiersMsg,
    MapMsg,
    OdometryMsg,
    PathMsg,
    PlannerFeedbackMsg,
    ScanMsg,
    decode,
    encode,
    frontiers_from_observation,
)
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


def kb_by_part(messages: list[FrontiersMsg]) -> dict[str, float]:
    """Mean KB of each part of a decision message's body (each grid of ``arrays`` on its own): what
    its size is made of."""
    sizes: dict[str, list[int]] = {}
    for m in messages:
        body = m.body()
        parts = {f"arrays.{k}": v for k, v in body.pop("arrays").items()} | body
        for name, value in parts.items():
            sizes.setdefault(name, []).append(len(msgpack.packb(value, use_bin_type=True)))
    return {name: round(float(np.mean(v)) / 1e3, 2) for name, v in sorted(sizes.items(), key=lambda kv: -np.mean(kv[1]))}


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

    per_step: dict[str, list] = {name: [] for name in ("scan", "odom", "cmd_vel", "planner_feedback", "path", "frontiers_keep")}

    def keep_map(explorer: Explorer) -> None:
        k = explorer.steps
        maps.append(MapMsg.of(k, explorer.map))
        sim, ahead = explorer.sim, explorer.planner.remaining_path()
        per_step["scan"].append(ScanMsg(k, explorer.last_scan, sim.sensor_pose(), 1))
        per_step["odom"].append(OdometryMsg(k, sim.time_s, sim.odometry()))
        per_step["cmd_vel"].append(CmdVelMsg(k, VelocityCommand(0.3, 0.1)))
        per_step["planner_feedback"].append(PlannerFeedbackMsg(k, explorer.planner.status.value, "command", False, "", ahead, k))
        per_step["path"].append(PathMsg(k, ahead))
        per_step["frontiers_keep"].append(FrontiersMsg(k, False))

    run_episode(KinematicSimulator(plan, seed=0), Recording(), ExplorationConfig(), seed=0, on_step=keep_map)
    decisions = [frontiers_from_observation(k, "timeout", obs, 0.0) for k, obs in enumerate(observations)]
    decision_bytes = [encode(m) for m in decisions]
    map_bytes = [encode(m) for m in maps]
    report = {
        "scene": args.scene,
        "frontiers_decision": {
            "messages": len(decisions),
            "kb_mean": round(float(np.mean([len(b) for b in decision_bytes])) / 1e3, 1),
            "kb_max": round(max(len(b) for b in decision_bytes) / 1e3, 1),
            "encode_ms": round(best_ms(encode, decisions, args.repeats), 3),
            "decode_ms": round(best_ms(lambda b: decode(b, FrontiersMsg), decision_bytes, args.repeats), 3),
            "kb_mean_by_part": kb_by_part(decisions),
        },
        "map": {
            "messages": len(maps),
            "kb_mean": round(float(np.mean([len(b) for b in map_bytes])) / 1e3, 1),
            "encode_ms": round(best_ms(encode, maps, args.repeats), 3),
            "decode_ms": round(best_ms(lambda b: decode(b, MapMsg), map_bytes, args.repeats), 3),
        },
    }
    for name, msgs in per_step.items():
        cls, wire = type(msgs[0]), [encode(m) for m in msgs]
        report[name] = {
            "messages": len(msgs),
            "kb_mean": round(float(np.mean([len(b) for b in wire])) / 1e3, 2),
            "encode_ms": round(best_ms(encode, msgs, args.repeats), 4),
            "decode_ms": round(best_ms(lambda b, cls=cls: decode(b, cls), wire, args.repeats), 4),
        }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
