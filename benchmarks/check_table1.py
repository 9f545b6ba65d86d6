"""Check that fresh eval episodes reproduce BENCHMARKS.md's Table 1: each fresh episode against the committed one.

    python benchmarks/check_table1.py easy_0.05=FRESH/easy_0.05 complex_0.1=FRESH/complex_0.1 middle=FRESH/gen_middle

Each argument is ``LABEL=FOLDER`` (or ``LABEL=FOLDER/episodes.csv``), a fresh ``cso-runtime eval --out`` folder of
one Table 1 plan set: LABEL is ``small`` or ``middle`` (``generated:small:20:0``, ``generated:middle:20:0``) or
``SET_M`` for the Dungeon validation plans, SET ``easy``, ``medium`` or ``complex`` and M the ``--m-per-px``, 0.05 or
0.1. The committed episodes of that label are Table 1's files for it, pooled in BENCHMARKS.md's order (a later
file's episode of a method replaces an earlier one's, ``tables.pooled_rows``); ``--committed LABEL=FILE`` (repeatable,
in order) gives others instead. A fresh episode is matched by label, method, map and seed, and compared on its
steps, coverage, explored area, path length, scale and ending (``FIELDS``), exactly as the files write them.

It prints every episode that differs (committed -> fresh) or has no committed counterpart, then per method the
episodes the same, and, where they differ, the mean per-scene change of m2/step and steps; then each method against
``--baseline`` on the sample's scenes that both ran in both: the mean per-scene m2/step ratio, committed and fresh
(``cso_runtime.comparison.compare_to_baseline``, every scale pooled as one, then per scale). Exit 0 when every fresh
episode is its committed one, 1 when any differs or has none to compare with, 2 for a usage error.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from collections import defaultdict
from pathlib import Path

from tables import pooled_rows

from cso_runtime.comparison import compare_to_baseline, efficiency_by_scene, labelled

RESULTS = Path(__file__).parent / "results"
FIELDS = ("steps", "coverage_pct", "explored_area_m2", "path_length_m", "scale", "terminated_by")
"""What must be the same for a fresh episode to be the committed one (``efficiency_m2_per_step`` follows from them)."""
SETS = ("easy", "medium", "complex")
SCALES_M = ("0.05", "0.1")


def table1_files(label: str, results: Path = RESULTS) -> list[Path]:
    """Table 1's committed ``episodes.csv`` files of one plan set, in the order BENCHMARKS.md pools them (its shell
    loop under Table 1); the ones not there are left out. ValueError for a label Table 1 has no files for."""
    if label == "small":
        folders = ["gen_small_360", "far15_default/small"]
    elif label == "middle":
        folders = ["gen_middle_360", "cluster_size_shipped/middle", "far15_default/middle"]
    else:
        plan_set, _, m = label.partition("_")
        if plan_set not in SETS or m not in SCALES_M:
            raise ValueError(
                f"no Table 1 files for label {label!r}: small, middle, or SET_M with SET one of {', '.join(SETS)} and M 0.05 or 0.1"
            )
        folders = ["easy_360"] if label == "easy_0.1" else []
        folders += [f"validation_all/{label}", f"validation_all/far15_{label}"]
        folders += [
            f"cluster_size_shipped/validation/{v}_{label}"
            for v in ("cso-no-info", "cso-no-mask", "cso-sm", "cso-vdm", "gnn-baseline")
        ]
        folders += [f"far15_default/validation/{v}_{label}" for v in ("cso-no-info", "cso-vdm")]
        folders += [f"table1_baselines/{b}_{label}" for b in ("greedy-info_utility", "random")]
    return [results / f / "episodes.csv" for f in folders if (results / f / "episodes.csv").is_file()]


def keyed(rows: list[dict]) -> dict[tuple[str, str, str], dict]:
    """``pooled_rows``' episodes by (method, LABEL/map, seed)."""
    return {(r["method"], r["map"], str(r["seed"])): r for r in rows}


def same(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def per_scene_pct(pairs: list[tuple[dict, dict]]) -> tuple[float, float]:
    """Mean per-scene change (fresh over committed, minus 1, in %) of m2/step and of steps."""
    eff = [100 * (f["efficiency_m2_per_step"] / c["efficiency_m2_per_step"] - 1) for c, f in pairs if c["efficiency_m2_per_step"]]
    steps = [100 * (f["steps"] / c["steps"] - 1) for c, f in pairs if c["steps"]]
    return (statistics.fmean(eff) if eff else float("nan"), statistics.fmean(steps) if steps else float("nan"))


def paired_ratios(rows: list[dict], baseline: str) -> dict[tuple[str, str], tuple[float, int]]:
    """(method, scale or 'all') -> (mean per-scene m2/step ratio against ``baseline`` - 1 in %, scenes)."""
    out = {}
    for scale_of in (lambda r: "all", lambda r: r["scale"]):
        table = efficiency_by_scene({**r, "scale": scale_of(r)} for r in rows)
        for c in compare_to_baseline(table, baseline, min_scenes=1):
            out[(c.method, c.scale)] = (c.per_scene_pct, c.scenes)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("fresh", nargs="+", type=labelled, help="LABEL=FOLDER of a fresh eval (or its episodes.csv)")
    p.add_argument(
        "--committed",
        action="append",
        type=labelled,
        default=[],
        help="LABEL=FILE instead of Table 1's files of LABEL (repeatable, in order)",
    )
    p.add_argument("--baseline", default="greedy-dist", help="method the others are paired with")
    args = p.parse_args(argv)
    if unlabelled := [str(path) for label, path in args.fresh if not label]:
        p.error(f"give each fresh folder a label, LABEL=FOLDER: {', '.join(unlabelled)}")
    labels = list(dict.fromkeys(label for label, _ in args.fresh))
    committed_files = args.committed or [(label, f) for label in labels for f in table1_files_or_error(p, label)]
    missing = [str(path) for _, path in [*args.fresh, *committed_files] if not path.is_file()]
    if missing:
        p.error(f"no such file: {', '.join(missing)}")
    try:
        fresh_rows, committed_rows = pooled_rows(args.fresh), pooled_rows(committed_files)
    except ValueError as exc:
        p.error(str(exc))
    fresh, committed = keyed(fresh_rows), keyed(committed_rows)

    pairs: dict[str, list[tuple[dict, dict]]] = defaultdict(list)
    unmatched: dict[str, int] = defaultdict(int)
    differing: dict[str, list[tuple[dict, dict]]] = defaultdict(list)
    for key, f in fresh.items():
        method, map_, seed = key
        c = committed.get(key)
        if c is None:
            unmatched[method] += 1
            print(f"{method} {map_} seed {seed}: no committed episode")
            continue
        pairs[method].append((c, f))
        changes = [(field, c.get(field), f.get(field)) for field in FIELDS if not same(c.get(field), f.get(field))]
        if changes:
            differing[method].append((c, f))
            said = ", ".join(
                f"{field} {a:g} -> {b:g}" if isinstance(a, float) and isinstance(b, float) else f"{field} {a} -> {b}"
                for field, a, b in changes
            )
            print(f"{method} {map_} seed {seed}: {said}")

    print()
    print(
        "| method | episodes compared | the same | m2/step change per scene (all / those that differ) | steps change per scene (all) |"
    )
    print("| --- | --- | --- | --- | --- |")
    for method in sorted(set(pairs) | set(unmatched)):
        n, d = len(pairs[method]), len(differing[method])
        eff_all, steps_all = per_scene_pct(pairs[method])
        eff_diff, _ = per_scene_pct(differing[method])
        extra = f" ({unmatched[method]} without a committed episode)" if unmatched[method] else ""
        said_diff = f"{eff_diff:+.2f} %" if d else "-"
        print(f"| {method} | {n}{extra} | {n - d} | {eff_all:+.2f} % / {said_diff} | {steps_all:+.2f} % |")

    # the methods against the baseline on the scenes the sample holds both of, committed and fresh
    both = {key for key in fresh if key in committed}
    scenes_of = {method: {(m, s) for mm, m, s in both if mm == method} for method in {k[0] for k in both}}
    rows_c, rows_f = [], []
    for method, scenes in scenes_of.items():
        shared = scenes & scenes_of.get(args.baseline, set()) if method != args.baseline else scenes
        rows_c += [committed[(method, m, s)] for m, s in shared]
        rows_f += [fresh[(method, m, s)] for m, s in shared]
    before, now = paired_ratios(rows_c, args.baseline), paired_ratios(rows_f, args.baseline)
    if before:
        print()
        print(f"| method | scale | scenes | per-scene m2/step vs {args.baseline}: committed | fresh |")
        print("| --- | --- | --- | --- | --- |")
        for (method, scale), (pct, scenes) in sorted(before.items(), key=lambda kv: (kv[0][0], kv[0][1] != "all", kv[0][1])):
            fresh_pct = now.get((method, scale), (float("nan"), 0))[0]
            print(f"| {method} | {scale} | {scenes} | {pct:+.2f} % | {fresh_pct:+.2f} % |")

    total = sum(len(v) for v in pairs.values())
    bad = sum(len(v) for v in differing.values()) + sum(unmatched.values())
    print()
    if bad:
        print(f"{bad} of {total + sum(unmatched.values())} fresh episodes are not the committed ones")
        return 1
    print(f"all {total} fresh episodes are the committed ones")
    return 0


def table1_files_or_error(p: argparse.ArgumentParser, label: str) -> list[Path]:
    try:
        files = table1_files(label)
    except ValueError as exc:
        p.error(str(exc))
    if not files:
        p.error(f"no committed Table 1 files for {label} under {RESULTS}")
    return files


if __name__ == "__main__":
    sys.exit(main())
