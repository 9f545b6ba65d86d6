"""A/B of the lockstep runtime between two commits, alternated, on a noisy machine.

Each side is a ``git worktree`` of its commit in a temporary folder; each round runs
``bench_runtime.py --wall-time-only`` once per side (``--repeats`` pairs each), the order of the two
sides swapped every round, so that both see the same periods of a shared host. It prints, per side,
the median Zenoh episode, CPU of all processes and wall-time ratio, and how many rounds each side won
(paired by round), with the mean per-round change of B against A and its bootstrap 95 % CI. This is
how the A/B tables of docs/experiments/runtime-overhead.md (issue 4) were measured.

    python benchmarks/ab_runtime.py BASE_REV NEW_REV [--scene builtin] [--method greedy-dist] [--rounds 6] [--repeats 1] [--json out.json]
    python benchmarks/ab_runtime.py HEAD HEAD --b-args "--realtime-priority 10"    # one commit, without and with real-time scheduling

A revision may be ``WORKTREE`` for the working tree as it is (uncommitted changes included).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WORKTREE = "WORKTREE"


def checkout(rev: str, into: Path) -> Path:
    """The source tree of ``rev``: the working tree itself, or a detached worktree of the commit."""
    if rev == WORKTREE:
        return ROOT
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "--quiet", str(into), rev], check=True)
    return into


def bench_once(tree: Path, scene: str, repeats: int, out: Path, method: str = "greedy-dist", extra: list[str] | None = None) -> dict:
    """One ``bench_runtime.py`` run of ``tree`` (its own code on ``PYTHONPATH``), with ``extra`` arguments; its
    ``repeats`` block."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    env.pop("ZENOH_RUNTIME", None)  # each side applies its own default
    cmd = [sys.executable, str(tree / "benchmarks" / "bench_runtime.py"), "--scene", scene, "--method", method, "--repeats", str(repeats), "--wall-time-only", "--json", str(out), *(extra or [])]
    subprocess.run(cmd, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return json.loads(out.read_text())["repeats"]


def summary(rounds: list[dict]) -> dict:
    flat = lambda key: [x for r in rounds for x in r[key]]  # noqa: E731
    return {
        "zenoh_episode_s_median": statistics.median(flat("zenoh_episode_s")),
        "zenoh_episode_s": flat("zenoh_episode_s"),
        "zenoh_cpu_s_median": statistics.median(flat("zenoh_cpu_s")) if all("zenoh_cpu_s" in r for r in rounds) else None,
        "ratio_median": statistics.median(flat("wall_time_ratios")),
        "ratios": flat("wall_time_ratios"),
        "same_result_every_time": all(r.get("same_result_every_time", False) for r in rounds),
    }


def paired_change(per_round: list[tuple[float, float]], resamples: int = 4000) -> dict:
    """B's Zenoh episode against A's of the same round, in per cent: the mean and a bootstrap 95 % CI
    over rounds. A CI that spans zero means this many rounds cannot tell the two sides apart on this host."""
    changes = [100.0 * (b / a - 1.0) for a, b in per_round]
    rng = random.Random(0)
    means = sorted(statistics.fmean(rng.choices(changes, k=len(changes))) for _ in range(resamples))
    return {"per_round": [round(c, 2) for c in changes], "mean": statistics.fmean(changes), "ci95": [means[int(0.025 * resamples)], means[int(0.975 * resamples) - 1]]}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("base", help="Commit (or WORKTREE) of side A")
    p.add_argument("new", help="Commit (or WORKTREE) of side B")
    p.add_argument("--scene", default="builtin")
    p.add_argument("--method", default="greedy-dist")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--repeats", type=int, default=1, help="Pairs per side per round")
    p.add_argument("--a-args", default="", help="More bench_runtime.py arguments for side A only (e.g. '--realtime-priority 0')")
    p.add_argument("--b-args", default="", help="More bench_runtime.py arguments for side B only (e.g. '--realtime-priority 10': the same commit twice, with and without)")
    p.add_argument("--json", type=Path, help="Also write the figures here")
    args = p.parse_args()
    extra = {"A": shlex.split(args.a_args), "B": shlex.split(args.b_args)}
    with tempfile.TemporaryDirectory(prefix="ab_runtime_") as tmp:
        trees = {}
        try:
            for side, rev in (("A", args.base), ("B", args.new)):
                trees[side] = checkout(rev, Path(tmp) / side)
            results: dict[str, list[dict]] = {"A": [], "B": []}
            for i in range(args.rounds):
                order = ("A", "B") if i % 2 == 0 else ("B", "A")
                for side in order:
                    results[side].append(bench_once(trees[side], args.scene, args.repeats, Path(tmp) / f"{side}{i}.json", args.method, extra[side]))
                print(f"round {i + 1}/{args.rounds}: " + ", ".join(f"{s} {statistics.median(results[s][-1]['zenoh_episode_s']):.3f} s" for s in ("A", "B")), flush=True)
        finally:
            for tree in trees.values():
                if tree != ROOT:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
    per_round = [(statistics.median(a["zenoh_episode_s"]), statistics.median(b["zenoh_episode_s"])) for a, b in zip(results["A"], results["B"])]
    report = {
        "scene": args.scene,
        "method": args.method,
        "rounds": args.rounds,
        "repeats": args.repeats,
        "A": {"rev": args.base, "bench_args": extra["A"], **summary(results["A"])},
        "B": {"rev": args.new, "bench_args": extra["B"], **summary(results["B"])},
        "rounds_B_shorter": sum(b < a for a, b in per_round),
        "paired_change_pct": paired_change(per_round),
    }
    for side in ("A", "B"):
        r = report[side]
        print(f"{side} {r['rev']}: Zenoh episode median {r['zenoh_episode_s_median']:.3f} s, CPU median {r['zenoh_cpu_s_median'] or float('nan'):.2f} s, ratio median {r['ratio_median']:.2f}x, same result every time: {r['same_result_every_time']}")
    change = report["paired_change_pct"]
    print(
        f"B shorter in {report['rounds_B_shorter']} of {args.rounds} rounds; Zenoh episode B against A, paired by round: "
        f"mean {change['mean']:+.1f} % [95 % bootstrap CI {change['ci95'][0]:+.1f}, {change['ci95'][1]:+.1f}]"
    )
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
