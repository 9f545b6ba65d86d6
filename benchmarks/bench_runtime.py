"""Runtime overhead of Zenoh: per-step latencies and the wall time of a lockstep episode vs in-process.

Runs the ``lockstep`` profile with ``up``'s launcher (five service processes, loopback router), while
this process listens to scan, map, frontiers and goal and stamps each arrival on one clock:

- scan -> map: from the sim's scan of step k to the mapper's map of step k (integrate_scan + 2 hops);
- map -> goal: from the map of step k to the policy's goal of step k on decision steps (decision rule,
  ObservationBuilder, select; 2 hops); on the other steps the policy is not in the loop;
- a breakdown of the mean step time into scan -> map -> frontiers -> cmd_vel -> next scan;
- wall-time ratio: step 0 to the episode's end through Zenoh, against ``run_episode`` in one process
  on the same scene and seed (target <= 1.5x). Process start-up is reported separately;
- CPU floor of that ratio: the CPU every process of the run spent during the Zenoh episode, spread
  perfectly over this machine's cores, against the in-process episode's wall time. No scheduling of
  the same work can bring the wall-time ratio below it on this machine.

    python benchmarks/bench_runtime.py --scene generated:middle:1:0 [--repeats 5] [--json out.json]

The details (latencies, breakdown, CPU) are those of the last pair.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import run_episode
from cso_runtime.keys import RobotKeys
from cso_runtime.launcher import Launcher
from cso_runtime.messages import CmdVelMsg, EpisodeStatusMsg, FrontiersMsg, GoalMsg, MapMsg, ScanMsg, decode
from cso_runtime.policies import make_policy
from cso_runtime.processes import keep_freed_memory, use_realtime_priority
from cso_runtime.run_profile import find_profile, load_profile
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from services.common import TRACE_DIR_ENV


def stat_fields(raw: str) -> list[str]:
    """The fields of a ``/proc/<pid>/stat`` line after the command name (state, ppid, ...)."""
    return raw[raw.rindex(")") + 2 :].split()


def stat_cpu_s(raw: str, tick: int) -> float:
    """User + system CPU seconds of a ``/proc/<pid>/stat`` (or a task's ``stat``) line."""
    fields = stat_fields(raw)
    return (int(fields[11]) + int(fields[12])) / tick


def processes() -> Iterator[tuple[int, str, str | None]]:
    """(pid, its ``stat`` line, its service module such as ``services.mapper`` or None) of every process."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            raw = Path(f"/proc/{entry}/stat").read_text()
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        yield int(entry), raw, next((c.decode() for c in cmd if c.startswith(b"services.")), None)


def process_cpu_s() -> dict[str, float]:
    """CPU seconds (user + system) of this process and every descendant, by command (Linux /proc); a
    service's own child process (the frontier service's helper) as ``services.<name>.helper``."""
    tick = os.sysconf("SC_CLK_TCK")
    found = {pid: (int(stat_fields(raw)[1]), service, stat_cpu_s(raw, tick)) for pid, raw, service in processes()}

    def name_of(pid: int) -> str:
        ppid, service, _ = found[pid]
        parent = found.get(ppid, (0, None, 0.0))[1]
        return service or (f"{parent}.helper" if parent else "launcher+router+bench")

    stats = {pid: (ppid, name_of(pid), cpu) for pid, (ppid, _, cpu) in found.items()}
    me, out = os.getpid(), {}
    for pid, (_, name, cpu) in stats.items():
        p = pid
        while p in stats and p != me:
            p = stats[p][0]
        if p == me:
            out[name] = out.get(name, 0.0) + cpu
    return out


def thread_cpu_s() -> dict[str, float]:
    """CPU seconds of every thread of the service processes, by ``service:thread name`` (Linux /proc; names
    with a trailing number, such as Zenoh's runtime workers, summed together)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, float] = {}
    for pid, _, service in processes():
        if service is None:
            continue
        try:
            for tid in os.listdir(f"/proc/{pid}/task"):
                raw = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
                comm = raw[raw.index("(") + 1 : raw.rindex(")")].rstrip("0123456789-_ ")
                key = f"{service.removeprefix('services.')}:{'main' if int(tid) == pid else comm}"
                out[key] = out.get(key, 0.0) + stat_cpu_s(raw, tick)
        except OSError:
            continue
    return out


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


KEEP_CHAIN = (("sim", "scan"), ("mapper", "map"), ("frontier", "frontiers"), ("planner", "cmd_vel"), ("sim", "scan"))
DECISION_CHAIN = (("sim", "scan"), ("mapper", "map"), ("frontier", "frontiers"), ("policy", "goal"), ("planner", "cmd_vel"), ("sim", "scan"))
"""A lockstep step's serial chain: (service, the topic it publishes next); the last scan is the next step's."""


def hop_breakdown(trace_dir: Path) -> dict[str, dict[str, float]]:
    """Mean ms of each hop of the chain from the services' message traces (``CSO_TRACE_DIR``), keep-goal
    and decision steps apart. Per hop: ``transit`` (the sender's put done -> the receiver's Zenoh
    callback), ``queue+decode`` (callback -> the handler starts), ``work`` (handler start -> the
    receiver's next put starts, encoding included)."""
    events = {f.name.split(".")[0]: json.loads(f.read_text()) for f in trace_dir.glob("*.trace.json")}

    def first(service: str, kind: str, topic: str) -> dict[int, list]:
        out: dict[int, list] = {}
        for e in events.get(service, []):
            if e[0] == kind and e[1] == topic:
                out.setdefault(e[2], e)
        return out

    puts = {(svc, topic): first(svc, "put", topic) for svc, topic in set(KEEP_CHAIN + DECISION_CHAIN)}
    handles = {(svc, topic): first(svc, "handle", topic) for svc, topic in [("mapper", "scan"), ("frontier", "map"), ("planner", "frontiers"), ("policy", "frontiers"), ("planner", "goal"), ("sim", "cmd_vel")]}
    decisions = set(puts[("policy", "goal")])
    out: dict[str, dict[str, float]] = {}
    for kind, chain in (("keep_goal_steps", KEEP_CHAIN), ("decision_steps", DECISION_CHAIN)):
        rows: dict[str, list[float]] = {}
        for k in sorted(puts[("sim", "scan")]):
            if (k in decisions) != (kind == "decision_steps"):
                continue
            segments: dict[str, float] = {}
            for (sender, topic), (receiver, next_topic) in itertools.pairwise(chain):
                next_step = k + 1 if receiver == "sim" else k
                sent, got, nxt = puts[(sender, topic)].get(k), handles[(receiver, topic)].get(k), puts[(receiver, next_topic)].get(next_step)
                if sent is None or got is None or nxt is None:
                    break
                hop = f"{sender}->{receiver}"
                segments[f"{hop} transit"] = got[3] - sent[4]
                segments[f"{hop} queue+decode"] = got[4] - got[3]
                segments[f"{receiver} work"] = nxt[3] - got[4]
            else:
                segments["step"] = puts[("sim", "scan")][k + 1][3] - puts[("sim", "scan")][k][3] if k + 1 in puts[("sim", "scan")] else float("nan")
                for name, v in segments.items():
                    rows.setdefault(name, []).append(1e3 * v)
        out[kind] = {name: round(float(np.nanmean(v)), 3) for name, v in rows.items()} | {"steps": len(rows.get("step", []))}
    # The episode's first steps against the median decision step: what one-off costs (first calls, a
    # helper still starting) add at the start, which services' ``warm_up`` is there to remove.
    scans = puts[("sim", "scan")]
    steps_ms = {k: 1e3 * (scans[k + 1][3] - scans[k][3]) for k in sorted(scans) if k + 1 in scans}
    decision_ms = [v for k, v in steps_ms.items() if k in decisions and k > 2]
    out["first_steps"] = {f"step {k} ms": round(steps_ms[k], 2) for k in range(3) if k in steps_ms} | {
        "median decision step ms": round(float(np.median(decision_ms)), 2) if decision_ms else float("nan")
    }
    return out


def in_process(scene: str, method: str, seed: int, realtime_priority: int = 0) -> tuple[float, int, float, float]:
    """The episode in this process; with ``realtime_priority``, on a thread of its own under SCHED_FIFO at that priority,
    as the services of the Zenoh side run (the same scheduling on both sides of the ratio)."""
    if not realtime_priority:
        return _in_process(scene, method, seed)
    out: list = []

    def run() -> None:
        why = use_realtime_priority(realtime_priority)
        out.append(_in_process(scene, method, seed) if why is None else why)

    worker = threading.Thread(target=run, name="in-process-episode")
    worker.start()
    worker.join()
    if not out or isinstance(out[0], str):
        raise SystemExit(f"--realtime-priority {realtime_priority}: {out[0] if out else 'the episode failed'}")
    return out[0]


def _in_process(scene: str, method: str, seed: int) -> tuple[float, int, float, float]:
    plan = resolve_scenes(scene)[0].load()
    c0 = time.process_time()
    t0 = time.perf_counter()
    config = ExplorationConfig()
    r = run_episode(KinematicSimulator(plan, seed=seed), make_policy(method, seed=seed, sensor=config.sensor), config, seed=seed)
    return time.perf_counter() - t0, r.steps, r.coverage_pct, time.process_time() - c0


def through_zenoh(
    scene: str, method: str, seed: int, service_mode: str | None = None, wall_time_only: bool = False, trace: bool = False, foxglove: bool = False, realtime_priority: int = 0
) -> dict:
    port = free_tcp_port()
    overrides = {"scene": scene, "method": method, "seed": seed, "lockstep": True}
    bridge = {"services.foxglove_bridge.port": 0} if foxglove else None  # a free port: never one a viewer holds
    profile, data = load_profile(str(find_profile("lockstep")), overrides, settings=bridge, foxglove=foxglove)
    profile.router.listen = [loopback_endpoint(port)]
    profile.router.service_mode = service_mode or profile.router.service_mode
    data["router"] = {"listen": [loopback_endpoint(port)], "service_mode": profile.router.service_mode}
    profile.realtime_priority = data["realtime_priority"] = realtime_priority
    stamps: dict[str, dict[int, float]] = {"scan": {}, "map": {}, "frontiers": {}, "goal": {}, "cmd_vel": {}, "decide": {}}
    done = threading.Event()
    started = threading.Event()
    end: dict[str, object] = {}
    cpu: dict[str, dict[str, float]] = {}

    arrivals: list[tuple[float, str, bytes]] = []
    """(time, topic, payload): decoded after the episode, so this listener adds no work to the chain."""

    def on_sample(sample) -> None:
        now = time.perf_counter()
        topic = str(sample.key_expr).split("/", 2)[2]
        payload = sample.payload.to_bytes()
        if topic != "episode/status":
            arrivals.append((now, topic, payload))
            if topic == "scan" and "start" not in cpu and decode(payload, ScanMsg).step == 0:
                cpu["start"] = process_cpu_s()
                cpu["threads_start"] = thread_cpu_s()
                started.set()
        elif topic == "episode/status":
            st = decode(payload, EpisodeStatusMsg)
            if st.state in ("done", "failed") and not done.is_set():
                cpu["end"] = process_cpu_s()
                cpu["threads_end"] = thread_cpu_s()
                end.update(t=now, steps=st.step, coverage=st.coverage_pct, state=st.state)
                done.set()

    with tempfile.TemporaryDirectory() as tmp:
        trace_dir = Path(tmp) / "trace"
        if trace:
            trace_dir.mkdir()
            os.environ[TRACE_DIR_ENV] = str(trace_dir)  # the launcher passes its environment to the services
        launcher = Launcher(profile, data, Path(tmp) / "run")
        t_start = time.perf_counter()
        thread = threading.Thread(target=launcher.run, kwargs={"live": False}, daemon=True)
        thread.start()
        time.sleep(0.3)
        keys = RobotKeys(profile.robot)
        topics = ("scan", "episode_status") if wall_time_only else ("scan", "map", "goal", "frontiers", "cmd_vel", "episode_status")
        with open_session(TransportConfig(mode="client", connect=[loopback_endpoint(port)])) as session:
            subs = [session.declare_subscriber(keys.topic(t), on_sample) for t in topics]
            if wall_time_only and started.wait(600):
                # Only step 0's scan is needed: stop listening to scans so that this listener (and the
                # router forwarding to it) costs the episode as little CPU as it can.
                subs.pop(0).undeclare()
            if not done.wait(600):
                raise RuntimeError("episode did not end within 600 s")
            for s in subs:
                s.undeclare()
        thread.join(60)
        os.environ.pop(TRACE_DIR_ENV, None)
        hops = hop_breakdown(trace_dir) if trace else None
    schemas = {"scan": ScanMsg, "map": MapMsg, "goal": GoalMsg, "cmd_vel": CmdVelMsg, "frontiers": FrontiersMsg}
    for now, topic, payload in arrivals:
        msg = decode(payload, schemas[topic])
        stamps[topic].setdefault(msg.step, now)
        if isinstance(msg, FrontiersMsg) and msg.decide:
            stamps["decide"].setdefault(msg.step, now)
    t0 = stamps["scan"].get(0, t_start)
    steps = sorted(set(stamps["scan"]) & set(stamps["map"]))
    scan_map_ms = [1e3 * (stamps["map"][k] - stamps["scan"][k]) for k in steps]
    goal_steps = sorted(set(stamps["map"]) & set(stamps["goal"]))
    decision_ms = [1e3 * (stamps["goal"][k] - stamps["map"][k]) for k in goal_steps if k in stamps["decide"]]
    cmd_steps = sorted(set(stamps["map"]) & set(stamps["cmd_vel"]))
    map_cmd_ms = [1e3 * (stamps["cmd_vel"][k] - stamps["map"][k]) for k in cmd_steps]
    # Where a step's time goes: mean ms of each segment of the chain, keep-goal and decision steps apart.
    segments = {"scan->map": ("scan", "map"), "map->frontiers": ("map", "frontiers"), "frontiers->cmd_vel": ("frontiers", "cmd_vel")}
    breakdown: dict[str, dict[str, float]] = {}
    for kind in ("keep_goal_steps", "decision_steps"):
        ks = [k for k in steps if (k in stamps["decide"]) == (kind == "decision_steps") and k in stamps["cmd_vel"] and k + 1 in stamps["scan"]]
        row = {name: float(np.mean([1e3 * (stamps[b][k] - stamps[a][k]) for k in ks])) if ks else float("nan") for name, (a, b) in segments.items()}
        row["cmd_vel->next scan"] = float(np.mean([1e3 * (stamps["scan"][k + 1] - stamps["cmd_vel"][k]) for k in ks])) if ks else float("nan")
        row["steps"] = len(ks)
        breakdown[kind] = row
    cpu_s = {name: round(cpu["end"][name] - cpu["start"].get(name, 0.0), 3) for name in cpu.get("end", {})}
    thread_s = {name: round(cpu["threads_end"][name] - cpu["threads_start"].get(name, 0.0), 3) for name in cpu.get("threads_end", {})}
    latencies = {
        "step_breakdown_ms": breakdown,
        "scan_to_map_ms": {"p50": pct(scan_map_ms, 50), "p99": pct(scan_map_ms, 99), "n": len(scan_map_ms)},
        "map_to_cmd_vel_ms_all_steps": {"p50": pct(map_cmd_ms, 50), "p99": pct(map_cmd_ms, 99), "n": len(map_cmd_ms)},
        "map_to_goal_ms_decisions": {"p50": pct(decision_ms, 50), "p99": pct(decision_ms, 99), "n": len(decision_ms)},
    }
    return {
        **({} if wall_time_only else latencies),
        **({"hop_breakdown_ms": hops} if hops is not None else {}),
        "service_mode": profile.router.service_mode,
        "cpu_s_during_episode": dict(sorted(cpu_s.items())) | {"total": round(sum(cpu_s.values()), 3)},
        "cpu_s_by_thread": {k: v for k, v in sorted(thread_s.items()) if v > 0},
        "state": end.get("state"),
        "steps": end.get("steps"),
        "coverage_pct": end.get("coverage"),
        "startup_s": t0 - t_start,
        "episode_s": float(end["t"]) - t0,  # type: ignore[arg-type]
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="generated:middle:1:0")
    p.add_argument("--method", default="greedy-dist")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--service-mode", default=None, choices=("client", "peer"), help="Zenoh mode of the services (default: the lockstep profile's, peer)")
    p.add_argument("--repeats", type=int, default=1, help="Pairs of episodes (in-process, Zenoh), interleaved; the median ratio is reported")
    p.add_argument(
        "--wall-time-only", action="store_true", help="Listen only to step 0's scan and to the status (the listener-side latencies need every key; listening costs the router process CPU)"
    )
    p.add_argument("--trace", action="store_true", help="Services trace every message (CSO_TRACE_DIR): adds each hop's transit, queue+decode and work")
    p.add_argument("--foxglove", action="store_true", help="Add the foxglove_bridge service (up --foxglove) to the Zenoh episodes: what watching costs")
    p.add_argument(
        "--realtime-priority",
        type=int,
        default=None,
        help="The services' realtime_priority (SCHED_FIFO 1-99; 0: normal scheduling), and the in-process episode's thread's; default: the lockstep profile's (0)",
    )
    p.add_argument("--json", type=Path, default=None, help="Also write the figures here")
    args = p.parse_args(argv)
    import logging  # noqa: PLC0415  (configured only when run as a script, not when imported)

    logging.basicConfig(level=logging.WARNING)
    pairs = []
    keep_freed_memory()  # the allocator settings of the services, for the in-process side too (same rules)
    rt = args.realtime_priority if args.realtime_priority is not None else load_profile(str(find_profile("lockstep")), {})[0].realtime_priority
    in_process(args.scene, args.method, args.seed, rt)  # warm-up, not counted: the first episode of a process pays imports and caches
    for _ in range(args.repeats):  # interleaved, so both sides of each ratio see the same machine
        local = in_process(args.scene, args.method, args.seed, rt)
        pairs.append((local, through_zenoh(args.scene, args.method, args.seed, args.service_mode, args.wall_time_only, args.trace, args.foxglove, rt)))
    (local_s, local_steps, local_cov, local_cpu_s), z = pairs[-1]
    ratios = [zz["episode_s"] / ll[0] for ll, zz in pairs]
    cores = len(os.sched_getaffinity(0))
    cpu_floors = [zz["cpu_s_during_episode"]["total"] / cores / ll[0] for ll, zz in pairs]
    report = {
        "scene": args.scene,
        "method": args.method,
        "seed": args.seed,
        "service_mode": z["service_mode"],
        "foxglove_bridge": args.foxglove,
        "realtime_priority": rt,
        "in_process": {"episode_s": local_s, "cpu_s": local_cpu_s, "steps": local_steps, "coverage_pct": local_cov},
        "zenoh_lockstep": z,
        "wall_time_ratio": z["episode_s"] / local_s,
        "wall_time_ratio_with_startup": (z["episode_s"] + z["startup_s"]) / local_s,
        "repeats": {
            "in_process_episode_s": [ll[0] for ll, _ in pairs],
            "zenoh_episode_s": [zz["episode_s"] for _, zz in pairs],
            "wall_time_ratios": ratios,
            "median_wall_time_ratio": float(np.median(ratios)),
            "zenoh_cpu_s": [zz["cpu_s_during_episode"]["total"] for _, zz in pairs],
            "in_process_cpu_s": [ll[3] for ll, _ in pairs],
            "cores": cores,
            "cpu_floor_ratios": cpu_floors,
            "median_cpu_floor_ratio": float(np.median(cpu_floors)),
            "same_result_every_time": all(zz["steps"] == ll[1] and zz["coverage_pct"] == ll[2] for ll, zz in pairs),
        },
    }
    print(yaml.safe_dump(report, sort_keys=False))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
