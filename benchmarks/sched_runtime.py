"""Where the runtime's threads wait for a CPU: the kernel's per-thread scheduler statistics during a lockstep episode.

Runs ``cso-runtime up --profile lockstep`` with ``CSO_TRACE_DIR`` (to know when step 0 and the last step
happened), samples ``/proc/<pid>/task/<tid>/schedstat`` of every process of the run meanwhile, and prints,
per service and thread, the time it ran and the time it spent runnable but waiting for a CPU (the run
queue) between step 0 and the last step. On a machine with fewer cores than busy threads the second
figure is what each message's hop pays on top of its work. Linux only.

    python benchmarks/sched_runtime.py [--scene generated:middle:1:0] [--method cso] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ThreadKey = tuple[str, str]
"""(process directory under /proc, thread directory)."""


def role_of(cmdline: str) -> str | None:
    """Which part of the run a process is (None: not ours)."""
    if "services." in cmdline:
        return cmdline.split("services.")[1].split()[0]
    if "multiprocessing" in cmdline and "spawn" in cmdline:
        return "frontier.helper"
    if "cso_runtime.cli" in cmdline or "cso-runtime" in cmdline:
        return "launcher"
    return None


def discover(pids: set[int], tasks: dict[ThreadKey, tuple[str, str]]) -> None:
    """Add the run's processes (the launcher and its descendants) and their threads to ``tasks``."""
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        role = role_of(cmdline)
        if role is None or not (int(proc.name) in pids or ppid in pids):
            continue
        pids.add(int(proc.name))
        for task in proc.glob("task/*"):
            try:
                tasks.setdefault((str(proc), str(task)), (role, (task / "comm").read_text().strip()))
            except OSError:
                continue


def snapshot(tasks: dict[ThreadKey, tuple[str, str]]) -> dict[ThreadKey, tuple[int, int]]:
    """(ns on a CPU, ns waiting on the run queue) per known thread that still exists."""
    out: dict[ThreadKey, tuple[int, int]] = {}
    for key in tasks:
        try:
            run_ns, wait_ns, _ = map(int, Path(key[1], "schedstat").read_text().split())
        except (OSError, ValueError):
            continue
        out[key] = (run_ns, wait_ns)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="generated:middle:1:0")
    parser.add_argument("--method", default="cso")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    trace_dir = Path(tempfile.mkdtemp(prefix="cso-sched-"))
    env = {**os.environ, "CSO_TRACE_DIR": str(trace_dir)}
    cmd = [sys.executable, "-m", "cso_runtime.cli", "up", "--profile", "lockstep", "--scene", args.scene, "--method", args.method, "--no-live"]
    launcher = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.nice(10)  # this sampler yields the CPUs to the run it measures
    pids = {launcher.pid}
    tasks: dict[ThreadKey, tuple[str, str]] = {}
    samples: list[tuple[float, dict]] = []
    last_discovery = 0.0
    while launcher.poll() is None:
        now = time.monotonic()
        if now - last_discovery > 0.5:  # new processes and threads (start-up, a restart); cheap reads otherwise
            discover(pids, tasks)
            last_discovery = time.monotonic()
        samples.append((time.monotonic(), snapshot(tasks)))
        time.sleep(0.02)
    sim = json.loads((trace_dir / "sim.trace.json").read_text())
    scans = [e[3] for e in sim if e[0] == "put" and e[1] == "scan"]  # monotonic seconds, like the samples
    t0, t1 = min(scans), max(scans)
    before = [s for s in samples if s[0] <= t0]
    if not before:
        raise SystemExit("no sample before step 0")
    after = [s for s in samples if s[0] >= t1]
    start, end = before[-1], (after[0] if after else samples[-1])
    per_thread: dict[tuple[str, str], list[float]] = {}
    for key, (run_ns, wait_ns) in end[1].items():
        if key in start[1]:
            role, comm = tasks[key]
            run0, wait0 = start[1][key]
            acc = per_thread.setdefault((role, comm), [0.0, 0.0])
            acc[0] += (run_ns - run0) / 1e6
            acc[1] += (wait_ns - wait0) / 1e6
    rows = sorted(((r, c, run, wait) for (r, c), (run, wait) in per_thread.items() if run or wait), key=lambda x: -x[3])
    print(f"{args.scene}, {args.method}: episode {t1 - t0:.3f} s (sampled over {end[0] - start[0]:.3f} s), {os.cpu_count()} CPUs")
    print(f"{'process':16s} {'thread':16s} {'on a CPU ms':>12s} {'run queue ms':>13s}")
    for role, comm, run, wait in rows:
        print(f"{role:16s} {comm:16s} {run:12.1f} {wait:13.1f}")
    total_run, total_wait = sum(r[2] for r in rows), sum(r[3] for r in rows)
    print(f"{'all':33s} {total_run:12.1f} {total_wait:13.1f}")
    if args.json:
        args.json.write_text(json.dumps({
            "scene": args.scene, "method": args.method, "episode_s": t1 - t0, "cpus": os.cpu_count(),
            "threads": [{"process": r, "thread": c, "on_cpu_ms": round(run, 2), "run_queue_ms": round(wait, 2)} for r, c, run, wait in rows],
            "total_on_cpu_ms": round(total_run, 1), "total_run_queue_ms": round(total_wait, 1),
        }, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
