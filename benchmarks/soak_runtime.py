"""Soak of the runtime: memory, file descriptors and threads over many episodes, then repeated up/down cycles.

Episodes: one detached lockstep ``up``. Each time its episode is done, the sim is killed; the launcher restarts
it, and a restarted sim starts a new episode (the same scene and seed) that the same mapper, frontier, policy
and planner processes serve. After each episode it samples every service's RSS, open file descriptors and
threads from /proc (the frontier service with its helper process): a cache or list that grows per step or
per episode shows as a rise from one episode to the next, where a healthy process levels off after the first.

Cycles: ``up --detach``, a status, ``down``, repeated: after each ``down`` no process of the run is left, no
``current.json``, and ``run.json`` says how the run ended.

    python benchmarks/soak_runtime.py [--episodes 10] [--cycles 5] [--scene generated:middle:1:0] [--method greedy-dist] [--json out.json]

Long run (``--minutes M``, instead of the above): the same detached lockstep run, episode after episode (the sim
killed after each) for M minutes, with the launcher and every service (the frontier's helpers apart) sampled from
/proc every ``--period-s``: RSS, open file descriptors, threads, and the run folder's size and each log's size, into
``--csv``; each episode's steps, real-time factor (the launcher's, first step to done) and the sim's figures at its end. ``--json`` gets the linear
fit of each column against time (per minute, on the samples after ``--warmup-min``, and on the last half alone: a
process that levels off has a last-half slope near 0) and of the episodes' real-time factor against their index.

    python benchmarks/soak_runtime.py --minutes 10 --scene generated:small:1:0 --csv soak.csv --json soak.json

``--idle``: one episode, then the run left idle for the rest of the minutes (the sim sampled too). ``--profile sim
--record``: a real-time run, recorded. ``--status-queries N`` (instead): N ``status`` queries in a row at a run idle
after its episode, each its own client session; the launcher's and this process's RSS, fds and threads.

Linux only (/proc). BENCHMARKS.md, "Soak", has the figures.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cso_runtime.config import MAX_RESTARTS
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


def restarts_setting(restarts: int) -> list[str]:
    """``up``'s ``--set`` of ``supervision.max_restarts`` for a soak that kills the sim after each episode: ``restarts``,
    at most ``config.MAX_RESTARTS`` (more is refused, exit 2; the back-off, doubled up to ``backoff_max_s`` within
    ``restart_window_s``, lets a service restart far fewer times than that within the window anyway)."""
    return ["--set", f"supervision.max_restarts={min(restarts, MAX_RESTARTS)}"]


def soak_episodes(runs: Path, scene: str, method: str, episodes: int) -> list[dict]:
    r = cli("up", "--profile", "lockstep", "--scene", scene, "--method", method, "--detach", *restarts_setting(episodes + 1), runs=runs)
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


def sample_run(runs: Path, t_s: float, with_sim: bool = False) -> dict[str, float]:
    """One row of the long run's CSV: each process's RSS (MiB), fds and threads, the run folder's size and its logs'."""
    info = json.loads((runs / "current.json").read_text())
    row: dict[str, float] = {"t_s": round(t_s, 1)}
    # A sim restarted after each episode: its figures go with each episode's row instead (at its end).
    pids = {"launcher": int(info["launcher_pid"])} | {name: int(svc["pid"]) for name, svc in info["services"].items() if svc.get("pid") and (with_sim or name != "sim")}
    for name, pid in pids.items():
        try:
            row[f"{name}_rss_mb"], row[f"{name}_fds"], row[f"{name}_threads"] = one_proc_stats(pid)
        except (OSError, KeyError):  # a sim between its kill and its restart
            pass
    for name in ("frontier",):  # its layer helper and multiprocessing's resource tracker
        try:
            kids = [one_proc_stats(c) for c in children(pids[name])]
        except (OSError, KeyError):
            continue
        row[f"{name}_helpers_rss_mb"] = round(sum(k[0] for k in kids), 1)
        row[f"{name}_helpers_fds"] = sum(k[1] for k in kids)
    run_dir = Path(info["run_dir"])
    row["run_dir_kb"] = round(sum(f.stat().st_size for f in run_dir.rglob("*") if f.is_file()) / 1024, 1)
    for log in sorted((run_dir / "logs").glob("*.log")):
        row[f"log_{log.stem}_kb"] = round(log.stat().st_size / 1024, 2)
    return row


def status_columns(status: dict | None) -> dict[str, float]:
    """What ``status --json`` says in one CSV row: the step, the real-time factor, the status's age (s), the
    messages rejected by the services and the launcher, and the state (as text)."""
    if not status:
        return {"status_state": "none"}
    rejected = sum(n for svc in status["services"].values() for n in svc.get("rejected", {}).values())
    return {
        "status_state": status["state"], "status_step": status.get("step"), "status_rtf": status.get("real_time_factor"),
        "status_age_s": status.get("status_age_s"), "status_rejected": rejected + sum(status.get("launcher_rejected", {}).values()),
    }


def one_proc_stats(pid: int) -> tuple[float, int, int]:
    """RSS (MiB), open file descriptors and threads of one process alone."""
    fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return round(int(fields["VmRSS"].split()[0]) / 1024, 1), len(os.listdir(f"/proc/{pid}/fd")), int(fields["Threads"])


def soak_minutes(runs: Path, scene: str, method: str, minutes: float, period_s: float, profile: str = "lockstep", record: bool = False, idle: bool = False) -> tuple[list[dict], list[dict]]:
    """The long run: episodes one after another for ``minutes`` (``idle``: one, then the run left as it is, as a
    detached run waits for ``down``); (samples, episodes)."""
    extra = ["--record"] if record else []
    r = cli("up", "--profile", profile, "--scene", scene, "--method", method, "--detach", "--no-live", *extra, *restarts_setting(MAX_RESTARTS), runs=runs)
    if r.returncode != 0:
        raise RuntimeError(f"up failed: {r.stdout}{r.stderr}")
    samples: list[dict] = []
    episodes: list[dict] = []
    t0 = time.monotonic()
    next_sample_s = 0.0
    seen: set[int] = set()
    try:
        while (now := time.monotonic() - t0) < minutes * 60:
            info = json.loads((runs / "current.json").read_text())
            s = query_status(info["endpoints"], info["robot"])
            if now >= next_sample_s:
                samples.append(sample_run(runs, now, with_sim=idle) | status_columns(s))
                next_sample_s += period_s
            if s and s.get("episode") not in seen and s["state"] in ("done", "failed"):
                seen.add(s["episode"])
                rtf = s.get("real_time_factor")
                episodes.append({"episode": len(episodes) + 1, "t_s": round(now, 1), "state": s["state"], "steps": s["step"], "coverage_pct": round(s["coverage_pct"], 4), "real_time_factor": rtf})
                episodes[-1]["sim_rss_mb"], episodes[-1]["sim_fds"], episodes[-1]["sim_threads"] = one_proc_stats(int(info["services"]["sim"]["pid"]))
                print(json.dumps(episodes[-1] | {k: v for k, v in samples[-1].items() if k.endswith("_rss_mb")}), flush=True)
                if not idle:
                    os.kill(int(info["services"]["sim"]["pid"]), signal.SIGKILL)  # the restarted sim starts a new episode
            time.sleep(0.3)
    finally:
        cli("down", runs=runs)
    return samples, episodes


def soak_status_queries(runs: Path, scene: str, method: str, queries: int) -> list[dict]:
    """``queries`` status queries in a row (each its own client session, as ``status`` and each ``--watch`` line
    open) at a detached run idle after its episode: the launcher (whose router takes each session) and this process,
    sampled 15 times."""
    r = cli("up", "--profile", "lockstep", "--scene", scene, "--method", method, "--detach", runs=runs)
    if r.returncode != 0:
        raise RuntimeError(f"up failed: {r.stdout}{r.stderr}")
    rows = []
    try:
        info = json.loads((runs / "current.json").read_text())
        wait_for(lambda: (s := query_status(info["endpoints"], info["robot"])) and s["state"] in ("done", "failed"), 300, "the episode to end")
        every = max(1, queries // 15)
        t0 = time.monotonic()
        for n in range(queries + 1):
            if n % every == 0 or n == queries:
                launcher, client = one_proc_stats(int(info["launcher_pid"])), one_proc_stats(os.getpid())
                rows.append({"queries": n, "t_s": round(time.monotonic() - t0, 1), "launcher": launcher, "client": client})
                print(json.dumps(rows[-1]), flush=True)
            if n < queries:
                query_status(info["endpoints"], info["robot"])
    finally:
        cli("down", runs=runs)
    return rows


def slope(xs: list[float], ys: list[float]) -> float | None:
    """Least-squares slope of ys against xs; None with fewer than 3 points."""
    if len(xs) < 3:
        return None
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx if sxx else None


def trends(samples: list[dict], episodes: list[dict], warmup_min: float) -> dict:
    """Per column: the first and last value after the warm-up, the slope per minute after it and on its last half."""
    after = [s for s in samples if s["t_s"] >= warmup_min * 60]
    columns = sorted({k for s in after for k, v in s.items() if isinstance(v, (int, float)) and v is not None} - {"t_s"})
    out: dict = {"columns": {}}
    for col in columns:
        pts = [(s["t_s"] / 60, s[col]) for s in after if isinstance(s.get(col), (int, float))]
        half = pts[len(pts) // 2 :]
        fit = slope([p[0] for p in pts], [p[1] for p in pts])
        fit_half = slope([p[0] for p in half], [p[1] for p in half])
        out["columns"][col] = {
            "first": pts[0][1] if pts else None, "last": pts[-1][1] if pts else None,
            "per_min": None if fit is None else round(fit, 4), "per_min_last_half": None if fit_half is None else round(fit_half, 4),
        }
    done = [e for e in episodes if e["real_time_factor"]]
    out["episodes"] = len(episodes)
    out["steps"] = sorted({e["steps"] for e in episodes})
    out["coverage_pct"] = sorted({e["coverage_pct"] for e in episodes})
    if done:
        rtfs = [e["real_time_factor"] for e in done]
        third = max(1, len(rtfs) // 3)
        out["real_time_factor"] = {  # medians: one episode's factor varies a lot on a shared machine
            "first_third_median": round(statistics.median(rtfs[:third]), 2), "last_third_median": round(statistics.median(rtfs[-third:]), 2),
            "per_episode": None if (f := slope([e["episode"] for e in done], rtfs)) is None else round(f, 4),
        }
    return out


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
    p.add_argument("--minutes", type=float, default=0.0, help="Long run of this many minutes instead of --episodes and --cycles")
    p.add_argument("--period-s", type=float, default=3.0, help="Long run: seconds between /proc samples")
    p.add_argument("--warmup-min", type=float, default=1.0, help="Long run: minutes left out of the slopes")
    p.add_argument("--csv", type=Path, default=None, help="Long run: the samples")
    p.add_argument("--profile", default="lockstep", help="Long run: the profile (sim: real time)")
    p.add_argument("--status-queries", type=int, default=0, help="Instead: this many status queries at an idle run (launcher and client RSS)")
    p.add_argument("--idle", action="store_true", help="Long run: one episode, then the run left idle (detached, before down)")
    p.add_argument("--record", action="store_true", help="Long run: record it (up --record), to see what a recording adds per minute")
    args = p.parse_args()
    if args.status_queries:
        with tempfile.TemporaryDirectory(prefix="cso-soak-") as tmp:
            rows = soak_status_queries(Path(tmp), args.scene, args.method, args.status_queries)
        if args.json:
            args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "status_queries": rows}, indent=1))
        return 0
    if args.minutes:
        with tempfile.TemporaryDirectory(prefix="cso-soak-") as tmp:
            samples, episodes = soak_minutes(Path(tmp), args.scene, args.method, args.minutes, args.period_s, args.profile, args.record, args.idle)
        if args.csv:
            columns = list(dict.fromkeys(k for s in samples for k in s))
            with args.csv.open("w", newline="") as f:
                w = csv.DictWriter(f, columns)
                w.writeheader()
                w.writerows(samples)
        summary = trends(samples, episodes, args.warmup_min)
        print(json.dumps(summary, indent=1))
        if args.json:
            args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "summary": summary, "episodes": episodes}, indent=1))
        return 0
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
