"""Soak of the runtime: memory, file descriptors and threads over many episodes, then repeated up/down cycles.

Episodes: one detached lockstep ``up``. Each time its episode is done, the sim is killed; the launcher restarts
it, and a restarted sim starts a new episode (the same scene and seed) that the same mapper, frontier, policy
and planner processes serve. After each episode it samples every service's RSS, open file descriptors and
threads from /proc (the frontier service with its helper process): a cache or list that grows per step or
per episode shows as a rise from one episode to the next, where a healthy process levels off after the first.

Cycles: ``up --detach``, a status, ``down``, repeated: after each ``down`` no process of the run is left, no
``current.json``, and ``run.json`` says how the run ended.

    python benchmarks/soak_runtime.py [--episodes 10] [--cycles 5] [--scene generated:middle:1:0] [--method greedy-dist] [--json out.json]

Linux only (/proc). BENCHMARKS.md, "Soak", has the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cso_runtime.status import query_status
from cso_runtime.supervision import python_module_argv


def proc_stats(pid: int) -> tuple[float, int, int]:
    """RSS (MiB), open file descriptors and threads of one process, with those of its children."""
    rss_mb, fds, threads = 0.0, 0, 0
    for p in [pid, *children(pid)]:
        fields = dict(line.split(":", 1) for line in Path(f"/proc/{p}/status").read_text().splitlines() if ":" in line)
        rss_mb += int(fields["VmRSS"].split()[0]) / 1024
        threads += int(fields["Threads"])
        fds += len(os.listdir(f"/proc/{p}/fd"))
    return round(rss_mb, 1), fds, threads


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (the frontier service's helper), by /proc."""
    out: list[int] = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            out += [int(c) for c in Path(f"/proc/{pid}/task/{task}/children").read_text().split()]
        except OSError:
            pass
    return out


def cli(*args: str, runs: Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([*python_module_argv("cso_runtime.cli"), *args, "--runs-dir", str(runs)], check=False, capture_output=True, text=True, timeout=timeout_s, env=env)


def run_processes(runs: Path) -> list[int]:
    """Processes whose command line names ``runs``: the launcher, its services and their helpers."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if str(runs) in cmdline and int(entry) != os.getpid():
                pids.append(int(entry))
    return pids


def wait_for(cond, timeout_s: float, what: str, period_s: float = 0.2):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if value := cond():
            return value
        time.sleep(period_s)
    raise RuntimeError(f"timed out after {timeout_s} s waiting for {what}")


def soak_episodes(runs: Path, scene: str, method: str, episodes: int) -> list[dict]:
    r = cli("up", "--profile", "lockstep", "--scene", scene, "--method", method, "--detach", "--set", f"supervision.max_restarts={episodes + 1}", runs=runs)
    if r.returncode != 0:
        raise RuntimeError(f"up failed: {r.stdout}{r.stderr}")
    rows = []
    try:
        seen: set[int] = set()
        for n in range(episodes):
            info = json.loads((runs / "current.json").read_text())

            def done_episode(info=info):
                s = query_status(info["endpoints"], info["robot"])
                return s if s and s["state"] in ("done", "failed") and s["episode"] not in seen else None

            status = wait_for(done_episode, 300, f"episode {n + 1} to end")
            seen.add(status["episode"])
            info = json.loads((runs / "current.json").read_text())
            row = {"episode": n + 1, "steps": status["step"], "state": status["state"]}
            for name, svc in info["services"].items():
                row[name] = proc_stats(int(svc["pid"]))
            rows.append(row)
            print(json.dumps(row), flush=True)
            os.kill(int(info["services"]["sim"]["pid"]), signal.SIGKILL)  # the restarted sim starts a new episode
    finally:
        cli("down", runs=runs)
    return rows


def soak_cycles(runs: Path, scene: str, method: str, cycles: int) -> list[dict]:
    rows = []
    for n in range(cycles):
        t0 = time.monotonic()
        up = cli("up", "--profile", "lockstep", "--scene", scene, "--method", method, "--detach", runs=runs)
        up_s = time.monotonic() - t0
        info = json.loads((runs / "current.json").read_text())
        wait_for(lambda info=info: (s := query_status(info["endpoints"], info["robot"])) and s["state"] != "starting", 120, "the episode to start")
        status = cli("status", "--json", runs=runs)  # as a user asks, while it explores (or is done)
        t0 = time.monotonic()
        down = cli("down", runs=runs)
        down_s = time.monotonic() - t0
        time.sleep(0.5)  # SIGKILLed groups are reaped by then
        last = max((p for p in runs.iterdir() if (p / "run.json").exists()), key=lambda p: p.name)
        run = json.loads((last / "run.json").read_text())
        row = {
            "cycle": n + 1, "up_rc": up.returncode, "up_s": round(up_s, 2), "status": json.loads(status.stdout.splitlines()[-1])["state"],
            "down_rc": down.returncode, "down_s": round(down_s, 2), "left_processes": len(run_processes(runs)),
            "current_json": (runs / "current.json").exists(), "outcome": run.get("outcome"),
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--cycles", type=int, default=5)
    p.add_argument("--scene", default="generated:middle:1:0")
    p.add_argument("--method", default="greedy-dist")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="cso-soak-") as tmp:
        episodes = soak_episodes(Path(tmp) / "episodes", args.scene, args.method, args.episodes) if args.episodes else []
        cycles = soak_cycles(Path(tmp) / "cycles", args.scene, args.method, args.cycles) if args.cycles else []
    growth = {}
    if len(episodes) >= 3:  # from the second episode (the first warms caches and the allocator) to the last
        for name in ("sim", "mapper", "frontier", "policy", "planner"):
            first, last = episodes[1][name], episodes[-1][name]
            growth[name] = {"rss_mb": round(last[0] - first[0], 1), "fds": last[1] - first[1], "threads": last[2] - first[2]}
        print("growth from episode 2 to", len(episodes), json.dumps(growth))
    clean = all(c["left_processes"] == 0 and not c["current_json"] and c["down_rc"] == 0 and c["outcome"] for c in cycles)
    print(f"cycles: {len(cycles)}, all clean: {clean}")
    if args.json:
        args.json.write_text(json.dumps({"args": vars(args) | {"json": str(args.json)}, "episodes": episodes, "growth": growth, "cycles": cycles}, indent=1))
    return 0 if clean else 1


if __name__ == "__main__":
    raise SystemExit(main())
