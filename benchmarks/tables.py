"""Print Table 1-style markdown rows (per scale and method) from eval ``summary.json`` or ``episodes.csv`` files.

    python benchmarks/tables.py results/easy/summary.json [more summary.json ...]
    python benchmarks/tables.py easy=A/episodes.csv easy=B/episodes.csv medium=C/episodes.csv ... [--baseline greedy-dist]

Used to write BENCHMARKS.md from the committed results without copying numbers by hand.

With ``summary.json`` files each file's ``by_scale`` rows are printed as they are. With ``episodes.csv`` files
(optionally ``LABEL=FILE``, the label keeping apart plans of different folders that share a name) the
episodes are pooled first: a later file's row of the same method and scene replaces an earlier one (so a
rerun of one method with other settings can be laid over a run of several), every method's means per scale
are ``eval``'s own (``evaluation.summarize``), and each row also gets its paired comparison with the
baseline on the scenes both ran (``cso_runtime.comparison``: mean per-scene ratio with its 95 % bootstrap
interval, and the scenes won). ``--table2`` prints the same pooled episodes as the paper's Table 2 instead:
one row per method, one column per scale, each cell the mean m2/step and the per-scene change against the
baseline.

Exit codes, ``compare``'s: 0, the table printed; 1, the files hold no episode; 2, refused before reading a table (no
such file, files of both kinds, a file that does not read as eval's, a ``--baseline`` of no episode in them).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any, NamedTuple

from cso_runtime.comparison import (
    PairedComparison,
    as_dicts,
    compare_to_baseline,
    efficiency_by_scene,
    format_interval,
    labelled,
    mixed_setups_said,
    no_baseline_said,
    no_episode_said,
    scene_key,
    whole_rows,
)
from cso_runtime.evaluation import METRICS, summarize
from cso_runtime.policies import BASELINES, LEARNED_METHODS
from cso_runtime.report import table2

HEADER = "| scale | method | episodes | explored m2 | coverage % | steps | m2/step | path m | decision ms p50 / p99 |"
SCALES = ("small", "middle", "large", "super_large")


def fmt(v, nd: int) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def interval(c: PairedComparison) -> str:
    """A paired comparison's mean per-scene change with its 95 % interval, as the tables print it."""
    return format_interval(c.per_scene_pct, c.ci_low_pct, c.ci_high_pct)


def row(scale: str, method: str, e: dict[str, Any], paired: PairedComparison | None = None, with_paired: bool = False) -> str:
    cells = (
        f"| {scale} | {method} | {e['episodes']} | {fmt(e['explored_area_m2'], 1)} | {fmt(e['coverage_pct'], 2)} | "
        f"{fmt(e['steps'], 1)} | {fmt(e['efficiency_m2_per_step'], 4)} | {fmt(e['path_length_m'], 1)} | "
        f"{fmt(e['decision_ms_p50'], 1)} / {fmt(e['decision_ms_p99'], 1)} |"
    )
    if not with_paired:
        return cells
    if paired is None:
        return cells + " |"
    return cells + f" {interval(paired)}, {paired.won} won |"


def rows(summary: dict) -> list[str]:
    """The ``by_scale`` rows of one eval ``summary.json``."""
    return [row(scale, method, e) for method, entry in summary["methods"].items() for scale, e in entry["by_scale"].items()]


def pooled_rows(files: list[tuple[str, Path]]) -> list[dict[str, Any]]:
    """Episodes of ``episodes.csv`` files, a later file's (method, scene) replacing an earlier one's; each row
    keeps its label in ``map`` (``LABEL/MAP``) so that plans of different folders stay apart."""
    pooled: dict[tuple, dict[str, Any]] = {}
    for label, path in files:
        with path.open(newline="") as fh:
            try:
                rows = list(whole_rows(csv.DictReader(fh)))  # a row cut short is an error, not pooled
            except ValueError as exc:  # which of the files, as compare says it
                raise ValueError(f"{path}: {exc}") from None
        for r in rows:
            r = dict(r)
            r["map"] = f"{label}/{r['map']}" if label else r["map"]
            for k in METRICS:
                r[k] = float(r[k]) if r.get(k) not in (None, "") else None
            # An episode's scene as compare pairs it (comparison.scene_key): a plan of one name at two cell sizes
            # (easy=A_0.05 easy=A_0.1) is two plans, even of one scale, not one whose later episode replaces the other.
            pooled[(r["method"], *scene_key(r))] = r
    return list(pooled.values())


class NoEpisode(ValueError):
    """Files that hold no episode (``comparison.no_episode_said``): exit 1, as ``compare`` (they read, and hold nothing to table)."""


class Pooled(NamedTuple):
    """Pooled episodes: the methods (the baseline first, then the other baselines, then the learned ones),
    eval's per-scale means of each, and each method's paired comparison with the baseline per scale."""

    methods: list[str]
    scales: list[str]
    by_scale: dict[tuple[str, str], dict[str, Any]]
    paired: dict[tuple[str, str], PairedComparison]


def pool(files: list[tuple[str, Path]], baseline: str) -> Pooled:
    """The episodes of ``files`` pooled (``pooled_rows``); files of no episode (a header alone) are a ``NoEpisode``, as
    ``compare`` refuses them: a table of headers alone looks like a table of nothing to compare. A ``baseline`` of no
    episode there is a ValueError naming their methods, as ``compare`` says it: a typo in ``--baseline`` left every
    row's paired column empty, a table that looked like one of no scene in common."""
    episodes = pooled_rows(files)
    if not episodes:
        raise NoEpisode(no_episode_said(files))
    known = [baseline, *BASELINES, *LEARNED_METHODS]
    methods = sorted(dict.fromkeys(r["method"] for r in episodes), key=lambda m: known.index(m) if m in known else len(known))
    if baseline not in methods:
        raise ValueError(no_baseline_said(baseline, methods))
    summary = summarize(episodes, [], methods, meta={}, baseline="")
    by_scale = {(m, s): e for m in methods for s, e in summary["methods"][m]["by_scale"].items()}
    paired = {(c.method, c.scale): c for c in compare_to_baseline(efficiency_by_scene(episodes), baseline)}
    return Pooled(methods, [s for s in SCALES if any(s == k[1] for k in by_scale)], by_scale, paired)


def table_from_episodes(files: list[tuple[str, Path]], baseline: str) -> list[str]:
    """Table 1 rows per scale, every method of the pooled episodes, with the paired comparison to ``baseline``."""
    p = pool(files, baseline)
    cells = [(s, m) for s in p.scales for m in p.methods if (m, s) in p.by_scale]
    return [row(s, m, p.by_scale[(m, s)], p.paired.get((m, s)), with_paired=True) for s, m in cells]


def table2_from_episodes(files: list[tuple[str, Path]], baseline: str) -> list[str]:
    """Table 2 layout (``report.table2``, as eval's report prints it): a row per method, a column per scale
    present, ``m2/step (per-scene change)``."""
    p = pool(files, baseline)
    summary = {
        "methods": {m: {"by_scale": {s: p.by_scale[(m, s)] for s in p.scales if (m, s) in p.by_scale}} for m in p.methods},
        "paired": {"comparisons": as_dicts(list(p.paired.values()))},
    }
    header, rows = table2(summary)
    return ["| " + " | ".join(header) + " |", "| --- " * len(header) + "|", *("| " + " | ".join(r) + " |" for r in rows)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="+", help="summary.json files, or episodes.csv files (LABEL=FILE)")
    parser.add_argument("--baseline", default="greedy-dist", help="method episodes.csv rows are paired with")
    parser.add_argument("--table2", action="store_true", help="episodes.csv files only: a row per method, a column per scale")
    args = parser.parse_args(argv)
    files = [labelled(a) for a in args.files]
    missing = [str(p) for _, p in files if not p.is_file()]
    if missing:
        parser.error(f"no such file: {', '.join(missing)}")
    csvs = [f for f in files if f[1].suffix == ".csv"]
    if csvs and len(csvs) != len(files):
        parser.error("give either summary.json files or episodes.csv files, not both")
    if args.table2 and len(csvs) != len(files):
        parser.error("--table2 reads episodes.csv files")
    try:  # an episodes.csv cut short: one line naming it (pooled_rows), not a traceback
        if csvs:
            lines = table2_from_episodes(csvs, args.baseline) if args.table2 else table_from_episodes(csvs, args.baseline)
    except NoEpisode as exc:
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    except ValueError as exc:
        parser.error(str(exc))
    if csvs:
        # Episodes of one plan under other setups (sensor, simulator, cell size, step limit): warned of as compare
        # warns of them, the paired cells pairing as compare does (files read whole already, by the table).
        for said in mixed_setups_said(csvs):
            print(said, file=sys.stderr)
        if not args.table2:
            print(HEADER + f" per scene vs {args.baseline} [95 % CI], won |")
            print("| --- " * 10 + "|")
        for line in lines:
            print(line)
        return 0
    lines = []
    for _, p in files:  # a summary.json cut short or of another shape: one line naming it, as an episodes.csv's
        try:
            lines += rows(json.loads(p.read_text()))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            parser.error(f"{p}: not a summary.json eval wrote ({type(exc).__name__}: {exc})")
    if not lines:  # summaries of no episode ({"methods": {}}): not a table of headers alone and exit 0
        parser.exit(1, f"{parser.prog}: error: {no_episode_said(files)}\n")
    print(HEADER)
    print("| --- " * 9 + "|")
    for line in lines:
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
