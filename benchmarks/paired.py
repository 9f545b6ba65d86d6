"""Paired comparison of each method with a baseline on the same scenes, from eval ``episodes.csv`` files.

    python benchmarks/paired.py --baseline greedy-dist benchmarks/results/sl20/episodes.csv [more.csv ...]

Episodes are paired by scene (map, scale, traversable area, seed); for every method and scale it prints
a markdown row: the change of mean efficiency (m2/step) against the baseline, as in the Table 1 rows, then
the mean of the per-scene ratios with a 95 % bootstrap interval (10,000 resamples of the scenes, fixed seed),
and on how many scenes the method beat the baseline. An interval that contains 0 % says the scenes do
not tell the two apart.

Plans of different folders can share a name (Dungeon's `easy/img_4` and `medium/img_4` are different plans,
with the same traversable area too): to pool such sets, label each file, `LABEL=FILE`. Scenes pair only
within a label, so a label's greedy-dist episodes may still come from another file than its cso ones:

    python benchmarks/paired.py easy=runs/val/easy/episodes.csv medium=runs/val/medium/episodes.csv
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

HEADER = (
    "| scale | method | scenes | m2/step vs baseline (ratio of means) | per-scene ratio: mean [95 % CI] | scenes won |\n"
    "| --- | --- | --- | --- | --- | --- |"
)


def labelled(arg: str) -> tuple[str, Path]:
    """``LABEL=FILE`` -> (LABEL, FILE); a plain FILE has the empty label."""
    label, sep, rest = arg.partition("=")
    return (label, Path(rest)) if sep and "/" not in label else ("", Path(arg))


def load(paths: list[Path | tuple[str, Path]]) -> dict[tuple[str, str], dict[tuple, float]]:
    """(method, scale) -> {scene key: efficiency m2/step}; a (label, path) keeps its scenes apart."""
    table: dict[tuple[str, str], dict[tuple, float]] = defaultdict(dict)
    for item in paths:
        label, path = item if isinstance(item, tuple) else ("", item)
        with path.open(newline="") as f:
            for row in csv.DictReader(f):
                scene = (label, row["map"], row["scale"], row["traversable_area_m2"], row["seed"])
                table[(row["method"], row["scale"])][scene] = float(row["efficiency_m2_per_step"])
    return table


def bootstrap_mean_ci(values: np.ndarray, resamples: int = 10_000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile interval of the mean, resampling the scenes with replacement."""
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, len(values), size=(resamples, len(values)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


def rows(table: dict[tuple[str, str], dict[tuple, float]], baseline: str) -> list[str]:
    out = []
    for (method, scale), eff in sorted(table.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        base = table.get((baseline, scale))
        if method == baseline or base is None:
            continue
        scenes = sorted(set(eff) & set(base))
        if len(scenes) < 3:
            continue
        m = np.array([eff[s] for s in scenes])
        b = np.array([base[s] for s in scenes])
        ratio = m / b
        lo, hi = bootstrap_mean_ci(ratio)
        out.append(
            f"| {scale} | {method} | {len(scenes)} | {100 * (m.mean() / b.mean() - 1):+.1f} % | "
            f"{100 * (ratio.mean() - 1):+.1f} % [{100 * (lo - 1):+.1f}, {100 * (hi - 1):+.1f}] | {int((ratio > 1).sum())} of {len(scenes)} |"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("episodes", nargs="+", type=labelled, help="episodes.csv files written by cso-runtime eval, each optionally LABEL=FILE")
    p.add_argument("--baseline", default="greedy-dist")
    args = p.parse_args(argv)
    missing = [str(path) for _, path in args.episodes if not path.is_file()]
    if missing:
        p.error(f"no such file: {', '.join(missing)}")
    print(HEADER)
    for line in rows(load(args.episodes), args.baseline):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
