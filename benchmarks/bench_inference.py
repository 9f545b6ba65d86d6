"""Inference cost of the learned CSO policy: one decision with 200 frontier nodes on one CPU thread.

Target (issue 5): at most 3 ms per decision for the network. Reports p50/p99 of
  network   the runtime path on a ready graph (200 frontier + 20 path nodes): encoder, actor scores,
            masked softmax, argmax, as the TorchScript trace ``LearnedPolicy`` runs per decision on
            CPU (and, for comparison, the eager module); the trace is made once per loaded model
            (``trace once`` below: tracing plus the first call);
  ppo step  ``get_action_and_value`` (adds the critic and the masked categorical; training only);
  graph     building that graph from an Observation (k-NN, features) — the rest of the policy's work;
  policy    LearnedPolicy.select end to end minus the observation itself (masks + graph + network).
Wall-clock percentiles suffer when other processes share the cores; the network's thread CPU time
is printed as well. The observation (mapping, fast marching, frontier clustering) is shared with every baseline and is
not counted here.

    python benchmarks/bench_inference.py [--weights cso_runtime/data/weights/cso.pt] [--repeats 500]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from cso_runtime.config import MaskConfig
from cso_runtime.doctor import machine_facts
from cso_runtime.frontiers import FrontierCluster
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.learned.graph import GraphConfig, build_graph
from cso_runtime.learned.network import GRAPH_KEYS, GraphActorCritic, to_torch, trace_decision
from cso_runtime.learned.registry import LearnedPolicy, load_checkpoint
from cso_runtime.observation import Observation


def synthetic_observation(n_clusters: int, n_path: int, seed: int = 0) -> Observation:
    """An open 40 x 40 m map with ``n_clusters`` frontier clusters scattered at random."""
    rng = np.random.default_rng(seed)
    geometry = GridGeometry(0.1, (400, 400))
    pose = Pose2D(20.0, 20.0, 0.0)
    iy, ix = np.mgrid[0:400, 0:400]
    distance = np.hypot((ix + 0.5) * 0.1 - 20.0, (iy + 0.5) * 0.1 - 20.0) * 1.2
    cells = rng.choice(400 * 400, size=n_clusters, replace=False)
    clusters = []
    for c in sorted(cells, key=lambda c: distance.flat[c]):
        cy, cx = divmod(int(c), 400)
        x, y = geometry.cell_to_world(cy, cx)
        clusters.append(FrontierCluster(len(clusters), np.array([[cy, cx]]), (cy, cx), (float(x), float(y)), float(distance[cy, cx]), 0.5, float(rng.integers(0, 40)), (float(x), float(y))))
    empty = np.zeros((400, 400), dtype=bool)
    path = rng.uniform(5.0, 35.0, size=(n_path, 2))
    path[-1] = pose.xy
    return Observation(geometry, pose, empty, empty, ~empty, distance, empty, np.zeros((400, 400)), clusters, 100.0, path)


def p50_p99_ms(samples_s: list[float]) -> dict[str, float]:
    ms = np.array(samples_s) * 1e3
    return {"p50_ms": round(float(np.percentile(ms, 50)), 4), "p99_ms": round(float(np.percentile(ms, 99)), 4), "n": len(ms)}


def percentiles(samples_s: list[float]) -> str:
    p = p50_p99_ms(samples_s)
    return f"p50 {p['p50_ms']:.3f} ms  p99 {p['p99_ms']:.3f} ms  (n={p['n']})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default=None, help="checkpoint to time (default: an untrained network of the default size)")
    parser.add_argument("--repeats", type=int, default=500)
    parser.add_argument("--frontiers", type=int, default=200)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here, with the machine they were taken on")
    args = parser.parse_args()
    torch.set_num_threads(1)

    if args.weights:
        model, config, _ = load_checkpoint(args.weights)
    else:
        model, config = GraphActorCritic().eval(), GraphConfig()
    obs = synthetic_observation(args.frontiers, config.max_path_nodes)
    graph = build_graph(obs, config)
    g = to_torch(graph, batch=True)
    mask = torch.zeros(1, config.max_frontier_nodes, dtype=torch.bool)
    mask[0, : args.frontiers] = True

    net, ppo_step, build, policy_t = [], [], [], []
    with torch.inference_mode():
        for _ in range(20):
            torch.softmax(model.masked_logits(g, mask), -1).argmax(-1)
        t0 = time.perf_counter()
        traced = trace_decision(model, g, mask)
        inputs = [g[k] for k in GRAPH_KEYS]
        traced(*inputs, mask)
        trace_once_s = time.perf_counter() - t0
        net_cpu, eager, eager_cpu = [], [], []
        for _ in range(20):
            torch.softmax(traced(*inputs, mask), -1).argmax(-1)
        for _ in range(args.repeats):  # alternate, so both see the same machine load
            t0, c0 = time.perf_counter(), time.thread_time()
            torch.softmax(traced(*inputs, mask), -1).argmax(-1)
            net.append(time.perf_counter() - t0)
            net_cpu.append(time.thread_time() - c0)
            t0, c0 = time.perf_counter(), time.thread_time()
            torch.softmax(model.masked_logits(g, mask), -1).argmax(-1)
            eager.append(time.perf_counter() - t0)
            eager_cpu.append(time.thread_time() - c0)
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            model.get_action_and_value(g, mask)
            ppo_step.append(time.perf_counter() - t0)
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        build_graph(obs, config)
        build.append(time.perf_counter() - t0)
    policy = LearnedPolicy("cso", model, config, MaskConfig(use_stuck=False))
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        policy.select(obs)
        policy_t.append(time.perf_counter() - t0)

    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, frontier nodes {args.frontiers}, path nodes {config.max_path_nodes}")
    print(f"network (forward + masked argmax): {percentiles(net)}  (trace: what LearnedPolicy runs on CPU)")
    print(f"  same, thread CPU time:           {percentiles(net_cpu)}  (robust to other processes on a busy machine)")
    print(f"  trace once (trace + first call): {trace_once_s * 1e3:.1f} ms")
    print(f"  eager module:                    {percentiles(eager)}")
    print(f"  eager module, thread CPU time:   {percentiles(eager_cpu)}")
    print(f"ppo step (actor + critic + sample): {percentiles(ppo_step)}")
    print(f"graph build:                       {percentiles(build)}")
    print(f"policy.select (masks+graph+net):   {percentiles(policy_t)}")
    if args.json:
        report = {
            "command": "python benchmarks/bench_inference.py" + (f" --weights {args.weights}" if args.weights else "") + f" --repeats {args.repeats} --frontiers {args.frontiers}",
            "machine": machine_facts() | {"torch_threads": torch.get_num_threads()},
            "frontier_nodes": args.frontiers,
            "path_nodes": config.max_path_nodes,
            "network_traced": p50_p99_ms(net),
            "network_traced_thread_cpu": p50_p99_ms(net_cpu),
            "network_eager": p50_p99_ms(eager),
            "trace_once_ms": round(trace_once_s * 1e3, 1),
            "ppo_step": p50_p99_ms(ppo_step),
            "graph_build": p50_p99_ms(build),
            "policy_select": p50_p99_ms(policy_t),
        }
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
