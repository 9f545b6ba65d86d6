"""Runtime overhead of Zenoh: per-step latencies and the wall time of a lockstep episode vs in-process.

Runs the ``lockstep`` profile with ``up``'s launcher (five service processes, loopback router), while
this process listens to scan, map, frontiers and goal and stamps each arrival on one clock:

- scan -> map: from the sim's scan of step k to the mapper's map of step k (integrate_scan + 2 hops);
- map -> goal: from the map of step k to the policy's goal of step k (planner check, decision rule,
  ObservationBuilder when a decision is due, select; 4 hops), reported for decision steps and all steps;
- wall-time ratio: step 0 to the episode's end through Zenoh, against ``run_episode`` in one process
  on the same scene and seed (target <= 1.5x). Process start-up is reported separately.

    python benchmarks/bench_runtime.py --scene generated:middle:1:0 [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import run_episode
from cso_runtime.keys import RobotKeys
from cso_runtime.launcher import Launcher, find_profile, load_profile
from cso_runtime.messages import EpisodeStatusMsg, FrontiersMsg, GoalMsg, MapMsg, ScanMsg, decode
from cso_runtime.policies import make_policy
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def in_process(scene: str, method: str, seed: int) -> tuple[float, int, float]:
    plan = resolve_scenes(scene)[0].load()
    t0 = time.perf_counter()
    r = run_episode(KinematicSimulator(plan, seed=seed), make_policy(method, seed=seed), ExplorationConfig(), seed=seed)
    return time.perf_counter() - t0, r.steps, r.coverage_pct


def through_zenoh(scene: str, method: str, seed: int, service_mode: str = "client") -> dict:
    port = free_tcp_port()
    overrides = {"scene": scene, "method": method, "seed": seed, "lockstep": True}
    profile, data = load_profile(str(find_profile("lockstep")), overrides)
    profile.router.listen = [loopback_endpoint(port)]
    profile.router.service_mode = service_mode
    data["router"] = {"listen": [loopback_endpoint(port)], "service_mode": service_mode}
    stamps: dict[str, dict[int, float]] = {"scan": {}, "map": {}, "goal": {}, "decide": {}}
    done = threading.Event()
    end: dict[str, object] = {}

    def on_sample(sample) -> None:
        now = time.perf_counter()
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        topic = key.split("/", 2)[2]
        if topic == "scan":
            stamps["scan"].setdefault(decode(payload, ScanMsg).step, now)
        elif topic == "map":
            stamps["map"].setdefault(decode(payload, MapMsg).step, now)
        elif topic == "goal":
            stamps["goal"].setdefault(decode(payload, GoalMsg).step, now)
        elif topic == "frontiers":
            f = decode(payload, FrontiersMsg)
            if f.decide:
                stamps["decide"].setdefault(f.step, now)
        elif topic == "episode/status":
            st = decode(payload, EpisodeStatusMsg)
            if st.state in ("done", "failed") and not done.is_set():
                end.update(t=now, steps=st.step, coverage=st.coverage_pct, state=st.state)
                done.set()

    with tempfile.TemporaryDirectory() as tmp:
        launcher = Launcher(profile, data, Path(tmp) / "run")
        t_start = time.perf_counter()
        thread = threading.Thread(target=launcher.run, kwargs={"live": False}, daemon=True)
        thread.start()
        time.sleep(0.3)
        keys = RobotKeys(profile.robot)
        with open_session(TransportConfig(mode="client", connect=[loopback_endpoint(port)])) as session:
            subs = [session.declare_subscriber(keys.topic(t), on_sample) for t in ("scan", "map", "goal", "frontiers", "episode_status")]
            if not done.wait(600):
                raise RuntimeError("episode did not end within 600 s")
            for s in subs:
                s.undeclare()
        thread.join(60)
    t0 = stamps["scan"].get(0, t_start)
    steps = sorted(set(stamps["scan"]) & set(stamps["map"]))
    scan_map_ms = [1e3 * (stamps["map"][k] - stamps["scan"][k]) for k in steps]
    goal_steps = sorted(set(stamps["map"]) & set(stamps["goal"]))
    map_goal_ms = [1e3 * (stamps["goal"][k] - stamps["map"][k]) for k in goal_steps]
    decision_ms = [1e3 * (stamps["goal"][k] - stamps["map"][k]) for k in goal_steps if k in stamps["decide"]]
    return {
        "state": end.get("state"),
        "steps": end.get("steps"),
        "coverage_pct": end.get("coverage"),
        "startup_s": t0 - t_start,
        "episode_s": float(end["t"]) - t0,  # type: ignore[arg-type]
        "scan_to_map_ms": {"p50": pct(scan_map_ms, 50), "p99": pct(scan_map_ms, 99), "n": len(scan_map_ms)},
        "map_to_goal_ms_all_steps": {"p50": pct(map_goal_ms, 50), "p99": pct(map_goal_ms, 99), "n": len(map_goal_ms)},
        "map_to_goal_ms_decisions": {"p50": pct(decision_ms, 50), "p99": pct(decision_ms, 99), "n": len(decision_ms)},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="generated:middle:1:0")
    p.add_argument("--method", default="greedy-dist")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--service-mode", default="client", choices=("client", "peer"), help="Zenoh mode of the services")
    p.add_argument("--json", type=Path, default=None, help="Also write the figures here")
    args = p.parse_args(argv)
    import logging

    logging.basicConfig(level=logging.WARNING)
    local_s, local_steps, local_cov = in_process(args.scene, args.method, args.seed)
    z = through_zenoh(args.scene, args.method, args.seed, args.service_mode)
    report = {
        "scene": args.scene,
        "method": args.method,
        "seed": args.seed,
        "service_mode": args.service_mode,
        "in_process": {"episode_s": local_s, "steps": local_steps, "coverage_pct": local_cov},
        "zenoh_lockstep": z,
        "wall_time_ratio": z["episode_s"] / local_s,
        "wall_time_ratio_with_startup": (z["episode_s"] + z["startup_s"]) / local_s,
    }
    print(yaml.safe_dump(report, sort_keys=False))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
