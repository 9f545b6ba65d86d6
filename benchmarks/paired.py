"""Paired comparison of each method with a baseline on the same scenes, from eval ``episodes.csv`` files
(the same as ``cso-runtime compare``; ``cso_runtime/comparison.py`` computes it).

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

Two runs of one method (the shipped ``cso`` and a training run's, both ``cso`` in their files) are set side by side
with ``--rename FILE:METHOD=NEW`` (FILE as given; repeatable), as in ``cso-runtime compare``:

    python benchmarks/paired.py runs/shipped runs/mine --rename runs/mine:cso=cso-mine
"""

from __future__ import annotations

import argparse
import sys

from cso_runtime.comparison import compare_to_baseline, labelled, markdown_table, pooled_episodes


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("episodes", nargs="+", type=labelled, help="episodes.csv files written by cso-runtime eval, each optionally LABEL=FILE")
    p.add_argument("--baseline", default="greedy-dist")
    p.add_argument("--exclude", action="append", default=[], help="Leave out these maps (repeatable or comma-separated)")
    p.add_argument("--rename", action="append", default=[], help="FILE:METHOD=NEW: compare that file's METHOD as NEW (repeatable)")
    args = p.parse_args(argv)
    missing = [str(path) for _, path in args.episodes if not path.is_file()]
    if missing:
        p.error(f"no such file: {', '.join(missing)}")
    try:
        table, replaced = pooled_episodes(args.episodes, args.exclude, args.rename)
    except ValueError as exc:
        p.error(str(exc))
    for replacement in replaced:
        print(f"note: {replacement.note()}", file=sys.stderr)
    print(markdown_table(compare_to_baseline(table, args.baseline)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
