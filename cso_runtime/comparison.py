"""Paired comparison of methods run on the same scenes: how far is a method ahead of a baseline?

Table 1 reports each method's mean efficiency; two methods run on the same scenes can also be compared
scene by scene, which separates them with far fewer scenes (plans differ more from each other than
methods do). For every method and scale this gives the change of mean efficiency (m2/step) against the
baseline on the shared scenes, the arithmetic and the geometric mean of the per-scene ratios, each with a
95 % bootstrap interval (the plans resampled with replacement, the episodes of one plan under several seeds kept
together as the paper's repeated tests of a scene are, a fixed seed), and the scenes won and lost. An interval that
contains 0 % says these scenes do not tell the two methods apart. With several seeds a scene is an episode (plan, seed):
the counts say so, and a comparison needs ``MIN_SCENES`` plans, however many seeds each ran. ``eval`` writes it to ``paired.csv``
and ``summary.json`` whenever the baseline ran too; ``cso-runtime compare`` pools ``episodes.csv`` files.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
from collections import defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from cso_runtime.outputs import write_text_atomic
from cso_runtime.scenes import scale_rank

SceneKey = tuple[str, str, str, str, str]
"""(label, map, scale, traversable area, seed): an episode's scene. The label keeps apart plans of
different folders that share a name (Dungeon's ``easy/img_4`` and ``medium/img_4``)."""
EfficiencyTable = dict[tuple[str, str], dict[SceneKey, float]]
"""(method, scale) -> {scene: efficiency m2/step}."""

EPISODE_COLUMNS = ("method", "map", "scale", "traversable_area_m2", "seed", "efficiency_m2_per_step")
"""What a comparison reads of each ``episodes.csv`` row."""
SETUP_COLUMNS = ("sensor_fov_deg", "sim", "cell_size_m", "max_steps")
"""``episodes.csv``'s columns of what an episode ran with beyond its method, plan and seed: the sensor's field of view
(degrees), the simulator (``2d``, ``mujoco``; empty on a real robot), the plan's cell size (m: ``--m-per-px`` for a
PNG plan) and the step limit (``episode.max_steps``: an episode cut at 40 steps has the m2/step of its first steps,
the most efficient, and beat one run to coverage). Episodes of one plan (one scene, as compare pairs them) that differ
in one of them do not measure the methods alone: ``compare`` warns (``mixed_setups_said``; of step limits where an
episode of the plan took as many steps as the lowest: one that ended before every limit ends so under any). Files of an eval before these columns have none
(``file_setup`` reads their summary.json)."""
MIN_SCENES = 3
"""Fewer shared scenes than this give no comparison (an interval needs a few). Plans are counted: the seeds of one plan
are resampled together (``bootstrap_mean_ci``), so one plan under 3 seeds gives an interval of one plan, a point."""
TOO_FEW_SCENES = f"{MIN_SCENES} or more scenes (plans: the seeds of one plan count once) of one scale"
"""What a method lacks that gets no comparison: ``compare`` and ``eval`` say ``no method shares`` it."""


@dataclass(frozen=True)
class PairedComparison:
    """One method against the baseline at one scale, on the scenes both ran."""

    scale: str
    method: str
    baseline: str
    scenes: int
    change_of_means_pct: float
    """Mean m2/step of the method against the baseline's, on the shared scenes, in per cent."""
    per_scene_pct: float
    """Mean of the per-scene efficiency ratios, minus 1, in per cent."""
    ci_low_pct: float
    ci_high_pct: float
    """95 % bootstrap interval of ``per_scene_pct``."""
    won: int
    lost: int
    """Scenes where the method was more (less) efficient than the baseline; the rest are level."""
    geomean_pct: float | None = None
    """Geometric mean of the per-scene ratios, minus 1, in per cent: the mean log-ratio, so that a scene
    twice as efficient and one half as efficient cancel out (the arithmetic mean counts them +25 %). None
    when the method explored nothing on some scene (a ratio of 0 has no logarithm)."""
    geomean_ci_low_pct: float | None = None
    geomean_ci_high_pct: float | None = None
    """95 % bootstrap interval of ``geomean_pct`` (the same resamples as the arithmetic mean's)."""
    plans: int | None = None
    """The plans among ``scenes``: with several seeds, ``scenes``, ``won`` and ``lost`` count episodes (plan, seed), and
    the interval resamples plans. None in a comparison written before it was counted."""

    def markdown_row(self) -> str:
        return (
            f"| {self.scale} | {self.method} | {scenes_said(asdict(self))} | {self.change_of_means_pct:+.1f} % | "
            f"{format_interval(self.per_scene_pct, self.ci_low_pct, self.ci_high_pct)} | {won_said(asdict(self))} | "
            f"{format_interval(self.geomean_pct, self.geomean_ci_low_pct, self.geomean_ci_high_pct)} |"
        )


def _of_seeds(c: Mapping[str, Any]) -> bool:
    """Whether comparison ``c`` (``as_dicts``) counts episodes (plan, seed), not plans: several seeds of a plan."""
    return c.get("plans") is not None and c["plans"] != c["scenes"]


def scenes_said(c: Mapping[str, Any]) -> str:
    """The ``scenes`` cell of comparison ``c``: ``12``, or with several seeds ``6 plans, 12 episodes (plan, seed)``."""
    return f"{c['plans']} plans, {c['scenes']} episodes (plan, seed)" if _of_seeds(c) else str(c["scenes"])


def won_said(c: Mapping[str, Any]) -> str:
    """The ``scenes won`` cell of comparison ``c``: ``2 of 4 (1 lost)``, or ``5 of 12 episodes (plan, seed), 3 lost``."""
    if _of_seeds(c):
        return f"{c['won']} of {c['scenes']} episodes (plan, seed), {c['lost']} lost"
    return f"{c['won']} of {c['scenes']} ({c['lost']} lost)"


def format_interval(pct: float | None, low_pct: float | None, high_pct: float | None) -> str:
    """``+2.9 % [-1.0, +6.8]``; ``n/a`` when there is no such mean."""
    if pct is None or low_pct is None or high_pct is None:
        return "n/a"
    return f"{pct:+.1f} % [{low_pct:+.1f}, {high_pct:+.1f}]"


PAIRED_COLUMNS = ("method", "scale", "scenes", "m2/step vs baseline", "per-scene ratio [95 % CI]", "won / lost", "geometric mean [95 % CI]")
"""The columns of a comparison (a ``paired`` entry of summary.json) on the console and in report.html."""


def paired_cells(c: dict) -> list[str]:
    """One comparison of summary.json's ``paired`` as the ``PAIRED_COLUMNS`` cells."""
    return [
        c["method"],
        c["scale"],
        scenes_said(c),
        f"{c['change_of_means_pct']:+.1f} %",
        format_interval(c["per_scene_pct"], c["ci_low_pct"], c["ci_high_pct"]),
        f"{c['won']} / {c['lost']}",
        format_interval(c.get("geomean_pct"), c.get("geomean_ci_low_pct"), c.get("geomean_ci_high_pct")),
    ]


MARKDOWN_HEADER = (
    "| scale | method | scenes | m2/step vs baseline (ratio of means) | per-scene ratio: mean [95 % CI] | scenes won | per-scene ratio: geometric mean [95 % CI] |\n"
    "| --- | --- | --- | --- | --- | --- | --- |"
)
CSV_FIELDS = tuple(f.name for f in fields(PairedComparison))


def scene_key(row: Mapping[str, Any], label: str = "") -> SceneKey:
    """An ``episodes.csv`` row's scene (``SceneKey``): what ``compare`` pairs episodes by, and ``benchmarks/tables.py``
    pools them by. Without its seed (``[:4]``), the plan, whose seeds the bootstrap resamples together."""
    return (label, str(row["map"]), str(row["scale"]), str(row["traversable_area_m2"]), str(row["seed"]))


def efficiency_by_scene(episodes: Iterable[Mapping[str, Any]], label: str = "", into: EfficiencyTable | None = None) -> EfficiencyTable:
    """Efficiency per method, scale and scene from ``episodes.csv`` rows (or ``eval``'s own rows). A later
    row of the same method and scene replaces an earlier one; rows without a finite efficiency are left out."""
    table: EfficiencyTable = defaultdict(dict) if into is None else into
    for row in episodes:
        value = row.get("efficiency_m2_per_step")
        try:
            efficiency = float(value) if value not in (None, "") else math.nan
        except (TypeError, ValueError):
            raise ValueError(f"{row.get('method')} on {row.get('map')}: efficiency {value!r} is not a number") from None
        if not math.isfinite(efficiency):
            continue
        table.setdefault((str(row["method"]), str(row["scale"])), {})[scene_key(row, label)] = efficiency
    return table


def labelled(arg: str) -> tuple[str, Path]:
    """A command-line ``LABEL=FILE`` -> (LABEL, FILE); a plain FILE has the empty label. A folder stands for
    the ``episodes.csv`` in it (an ``eval --out`` folder, or a run folder of ``up``). A file or folder whose own
    name holds ``=`` (a sweep's ``lr=3e-4``, hydra's ``lr=0.001,seed=1``) is that path, unlabelled, where the
    labelled reading names nothing: it was read as the label ``lr`` of a missing ``3e-4``."""
    label, sep, rest = arg.partition("=")
    as_labelled = bool(sep) and "/" not in label and (Path(rest).exists() or not Path(arg).exists())
    label, path = (label, Path(rest)) if as_labelled else ("", Path(arg))
    return label, path / "episodes.csv" if path.is_dir() else path


@dataclass(frozen=True)
class Rename:
    """``--rename FILE:METHOD=NEW``: the episodes of ``method`` in one of the files compared count as ``new``'s, so
    that two runs of one method (the shipped ``cso`` and a training run's, both called ``cso`` in their
    ``episodes.csv``) are set side by side instead of one replacing the other."""

    arg: str
    """As given, for messages."""
    label: str
    """The file's label when the argument gives one (``easy=A/:cso=mine``); empty: the file under any label."""
    path: Path
    method: str
    new: str

    def applies_to(self, label: str, path: Path) -> bool:
        return Path(path).resolve() == self.path.resolve() and self.label in ("", label)


def parse_rename(arg: str) -> Rename:
    """``FILE:METHOD=NEW`` -> Rename. FILE as it is given among the files (a folder for its ``episodes.csv``,
    optionally ``LABEL=FILE``); METHOD the ``method`` column's value there; NEW the name to compare it under."""
    head, sep, new = arg.rpartition("=")
    file, colon, method = head.rpartition(":")
    if not (sep and colon and file and method.strip() and new.strip()):
        raise ValueError(f"--rename expects FILE:METHOD=NEW, such as runs/mine:cso=cso-mine, got {arg!r}")
    label, path = labelled(file)
    return Rename(arg, label, path, method.strip(), new.strip())


def split_names(args: Iterable[str]) -> list[str]:
    """Command-line names, each argument one name or several separated by commas (``--exclude a,b --exclude c``)."""
    return [name for arg in args for name in arg.split(",") if name]


@dataclass(frozen=True)
class Replacement:
    """The episodes of one method that a later ``episodes.csv`` gave other figures for than an earlier one, on the
    same scenes (``read_episodes``): the later file's take their place, which puts a candidate in the place of the
    shipped ``cso`` (``compare base/ candidate/``), but also makes the order of the files decide the result."""

    method: str
    earlier: Path
    later: Path
    scenes: int

    def note(self) -> str:
        """One line for the console."""
        return (
            f"{self.later}'s {self.method} replaces {self.earlier}'s on {self.scenes} scene{'s' if self.scenes != 1 else ''} with other"
            f" figures (a later file's episodes of a method take an earlier file's place; compare each file alone to see both)"
        )


def whole_rows(reader: csv.DictReader[str]) -> Iterator[dict[str, str]]:
    """The rows of ``reader``, each with the header's cells: a row of other cells (a file cut short mid-row, a stray
    comma) would read its missing cells as None, or a number cut short as a smaller one, so it is a ValueError
    naming its line, rather than a figure compared or pooled."""
    for row in reader:
        if None in row or None in row.values():
            cells = sum(v is not None for k, v in row.items() if k is not None) + len(row.get(None) or [])
            raise ValueError(
                f"line {reader.line_num} has {cells} cells, the header {len(reader.fieldnames or [])} columns "
                "(a file cut short or a row mangled): not an episodes.csv as eval writes it"
            )
        yield row


def read_episodes(
    files: Sequence[Path | tuple[str, Path]], exclude_maps: Iterable[str] = (), replaced: list[Replacement] | None = None, renames: Sequence[Rename] = ()
) -> EfficiencyTable:
    """``efficiency_by_scene`` over ``episodes.csv`` files, each optionally ``(label, path)``, without the
    episodes of the maps named in ``exclude_maps`` (for instance the plans a training run drew), with the methods
    that ``renames`` name under their new names. A later file's episode of a method replaces an earlier file's on
    the same scene; ``replaced`` (when given) receives a ``Replacement`` per method and pair of files where that
    changed a figure. A rename of no file given, of a method its file lacks, or to a method it has is a ValueError."""
    excluded = set(exclude_maps)
    items = [item if isinstance(item, tuple) else ("", Path(item)) for item in files]
    for rename in renames:
        if not any(rename.applies_to(label, path) for label, path in items):
            given = ", ".join(f"{label}={path}" if label else str(path) for label, path in items)
            raise ValueError(f"--rename {rename.arg}: {rename.path} is not one of the files compared ({given})")
    table: EfficiencyTable = defaultdict(dict)
    source: dict[tuple[str, SceneKey], Path] = {}
    """(method, scene) -> the file its episode in ``table`` came from."""
    for label, path in items:
        rows = file_episodes(label, path, excluded, renames)
        try:
            own = efficiency_by_scene(rows, label)
        except ValueError as exc:  # an efficiency that is no number: the file named, as file_episodes names it
            raise ValueError(f"{path}: {exc}") from None
        changed: dict[tuple[str, Path], int] = defaultdict(int)
        for (method, scale), scenes in own.items():
            pooled = table[(method, scale)]
            for scene, efficiency in scenes.items():
                if scene in pooled and pooled[scene] != efficiency:
                    changed[(method, source[(method, scene)])] += 1
                pooled[scene] = efficiency
                source[(method, scene)] = Path(path)
        if replaced is not None:
            replaced.extend(Replacement(method, earlier, Path(path), count) for (method, earlier), count in sorted(changed.items(), key=lambda kv: (kv[0][0], str(kv[0][1]))))
    return table


def file_episodes(label: str, path: Path, exclude_maps: Iterable[str] = (), renames: Sequence[Rename] = ()) -> list[dict[str, str]]:
    """The rows of one ``episodes.csv`` (``label``: its label) as ``read_episodes`` reads them, whatever their
    efficiency: without the episodes of the maps of ``exclude_maps``, the methods of ``renames`` that apply to it under
    their new names. A file that is not one eval wrote (a column missing, a row cut short, not UTF-8) is a ValueError
    naming it."""
    excluded = set(exclude_maps)
    try:
        with Path(path).open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in EPISODE_COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                hint = f" (compare reads episodes.csv: give {Path(path).parent}/ or its episodes.csv)" if Path(path).name == "summary.json" else ""
                raise ValueError(f"not an episodes.csv written by eval: no column {', '.join(missing)}{hint}")
            rows = [row for row in whole_rows(reader) if row["map"] not in excluded]
        return renamed_methods(rows, [r for r in renames if r.applies_to(label, path)])
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not an episodes.csv written by eval: not UTF-8 text") from None
    except (ValueError, csv.Error) as exc:  # every message names the file: several are read at once
        raise ValueError(f"{path}: {exc}") from None


def file_setup(path: Path) -> dict[str, str]:
    """The ``SETUP_COLUMNS`` an ``episodes.csv`` of an eval before them would have said, from the summary.json beside
    it (``meta.config.sensor.fov_deg``, ``meta.sim``, ``meta.cell_sizes_m`` when one, ``meta.config.episode.max_steps``);
    {} without one."""
    try:
        meta = json.loads((Path(path).parent / "summary.json").read_text(encoding="utf-8"))["meta"]
        fov = meta.get("config", {}).get("sensor", {}).get("fov_deg")
        cells = meta.get("cell_sizes_m") or []
        max_steps = meta.get("config", {}).get("episode", {}).get("max_steps")
        known = {"sensor_fov_deg": fov, "sim": meta.get("sim"), "cell_size_m": cells[0] if len(cells) == 1 else None, "max_steps": max_steps}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}
    return {column: setup_value(value) for column, value in known.items() if value not in (None, "")}


def _number(value: Any) -> float:
    """An ``episodes.csv`` cell as a number; inf where it holds none (empty, or not a number: unknown, so the largest)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return math.inf
    return number if not math.isnan(number) else math.inf


def setup_value(value: Any) -> str:
    """A ``SETUP_COLUMNS`` cell as one spelling: ``180`` for 180.0 and "180.0", the text of any other."""
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def mixed_setups_said(files: Sequence[tuple[str, Path]], exclude_maps: Iterable[str] = ()) -> list[str]:
    """What ``compare`` says of ``files`` (read already: whole ``episodes.csv`` files) whose episodes of one plan ran
    with different ``SETUP_COLUMNS``: a warning per column, naming its values, their files and the plans; and a note
    per file that says none of them (an eval before the columns, no summary.json beside it) where another file does,
    as its episodes cannot be checked. [] where nothing differs or nothing is known. A plan is a scene as compare
    pairs episodes (``SceneKey``: a map of one label, of one traversable area): the plans of one name at two cell sizes
    (``easy=A_0.05 easy=A_0.1``) are two, whose episodes are never paired with each other's."""
    excluded = set(exclude_maps)
    seen: dict[str, dict[tuple[str, ...], dict[str, list[Path]]]] = {c: defaultdict(dict) for c in SETUP_COLUMNS}
    """column -> plan (``scene_key`` without the seed) -> value -> the files that ran the plan with it."""
    longest: dict[tuple[str, ...], float] = {}
    """plan -> the most steps an episode of it took (inf where one does not say)."""
    unknown: list[Path] = []
    for label, path in files:
        with Path(path).open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            fallback = {} if all(c in (reader.fieldnames or []) for c in SETUP_COLUMNS) else file_setup(path)
            said = False
            for row in whole_rows(reader):
                if row["map"] in excluded:
                    continue
                plan = scene_key(row, label)[:4]
                longest[plan] = max(longest.get(plan, 0.0), _number(row.get("steps")))
                for column in SETUP_COLUMNS:
                    value = setup_value(row[column]) if row.get(column) else fallback.get(column)
                    if value is not None:
                        said = True
                        holders = seen[column][plan].setdefault(value, [])
                        if Path(path) not in holders:
                            holders.append(Path(path))
            if not said:
                unknown.append(Path(path))

    def differs(column: str, plan: tuple[str, ...], values: dict[str, list[Path]]) -> bool:
        """Whether the plan's episodes ran with different ``column``s that can change them: step limits only where one
        of its episodes took as many steps as the lowest (an episode that ended before every limit ends so under any)."""
        if len(values) < 2:
            return False
        return column != "max_steps" or longest[plan] >= min(_number(v) for v in values)

    lines = []
    for column, plans in seen.items():
        mixed = {plan: values for plan, values in plans.items() if differs(column, plan, values)}
        if not mixed:
            continue
        values: dict[str, list[Path]] = {}
        for by_value in mixed.values():
            for value, holders in by_value.items():
                known = values.setdefault(value, [])
                known += [h for h in holders if h not in known]
        names = sorted({plan[1] for plan in mixed})
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        lines.append(
            f"warning: the same plans ran with different {column}: "
            + ", ".join(f"{value} ({', '.join(map(str, holders))})" for value, holders in sorted(values.items()))
            + f" on {len(names)} plan{'' if len(names) == 1 else 's'} ({shown}): their figures compare those too, not the methods alone"
        )
    if len(unknown) < len(files):
        lines += [f"note: {path} says no setup ({', '.join(SETUP_COLUMNS)}: an eval before those columns, no summary.json beside it): its episodes are not checked against the others'" for path in unknown]
    return lines


def pooled_episodes(files: Sequence[tuple[str, Path]], exclude: Iterable[str], renames: Iterable[str]) -> tuple[EfficiencyTable, list[Replacement]]:
    """What ``compare`` and ``benchmarks/paired.py`` read from their arguments: ``read_episodes`` of the files with
    the maps of ``exclude`` (``split_names``) left out and the ``--rename`` arguments applied, and the replacements
    to note. A bad argument or file is a ValueError."""
    replaced: list[Replacement] = []
    table = read_episodes(files, split_names(exclude), replaced, [parse_rename(arg) for arg in renames])
    return table, replaced


def no_episode_said(files: Sequence[tuple[str, Path]]) -> str:
    """What ``compare`` (and ``benchmarks/tables.py``) say of ``files`` that hold no episode (exit 1)."""
    return f"these files hold no episode: {', '.join(str(path) for _, path in files)}"


def no_baseline_said(baseline: str, methods: Iterable[str]) -> str:
    """What ``compare`` (and ``benchmarks/tables.py``) say of a ``--baseline`` none of whose episodes are in the files,
    which hold ``methods``' (exit 2: a typo, most likely)."""
    return f"--baseline {baseline!r} has no episodes in these files; their methods: {', '.join(sorted(methods))}"


def episodes_by_method(files: Sequence[tuple[str, Path]], renames: Iterable[str], exclude: Iterable[str] = ()) -> dict[str, int]:
    """How many episodes (rows) each method has in ``files`` (as ``pooled_episodes`` read them, the ``--rename``
    arguments applied), whatever their efficiency, without those on the maps of ``exclude``: what ``compare`` says of
    a baseline that has episodes but none it can compare. Files ``pooled_episodes`` has read."""
    excluded, parsed = split_names(exclude), [parse_rename(arg) for arg in renames]
    counts: dict[str, int] = defaultdict(int)
    for label, path in files:
        for row in file_episodes(label, path, excluded, parsed):
            counts[row["method"]] += 1
    return dict(counts)


def renamed_methods(rows: list[dict[str, str]], renames: Sequence[Rename]) -> list[dict[str, str]]:
    """One file's ``episodes.csv`` rows with each renamed method under its new name (ValueError for a method the
    rows lack, or a new name that is another of their methods: two methods' episodes would mix)."""
    methods = {row["method"] for row in rows}
    new_names: dict[str, str] = {}
    for rename in renames:
        if rename.method not in methods:
            raise ValueError(f"--rename {rename.arg}: no episodes of {rename.method} in it; its methods: {', '.join(sorted(methods))}")
        new_names[rename.method] = rename.new
    kept, new = methods - set(new_names), list(new_names.values())
    if clash := sorted({name for name in new if name in kept or new.count(name) > 1}):
        raise ValueError(f"--rename: {', '.join(clash)} would hold the episodes of two methods of this file; choose another new name")
    return [{**row, "method": new_names.get(row["method"], row["method"])} for row in rows] if new_names else rows


def bootstrap_mean_ci(values: np.ndarray, resamples: int = 10_000, seed: int = 0, clusters: Sequence[Any] | None = None) -> tuple[float, float]:
    """95 % percentile interval of the mean, resampling the values with replacement; with ``clusters`` (one label
    per value), resampling whole clusters: the episodes of one plan under several seeds are not independent
    scenes, and resampling them one by one would make the interval too narrow."""
    labels = tuple(clusters) if clusters is not None else ()
    if not labels or len(set(labels)) == len(labels):  # one value per cluster: the plain bootstrap
        means = values[_bootstrap_picks(len(values), resamples, seed)].mean(axis=1)
    else:
        index, picks, picked_counts = _cluster_bootstrap(labels, resamples, seed)
        means = np.bincount(index, weights=values)[picks].sum(axis=1) / picked_counts
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


BOOTSTRAPS_KEPT = 4
"""Resamplings ``bootstrap_mean_ci`` keeps for its next calls: a table's metrics of one method and scale (eval's
summary, ``compare``, benchmarks/tables.py) are resampled over the same plans, and drawing the same resamples anew
for each metric was most of a summary's time (BENCHMARKS.md's Table 1 pooling: 6.5 s, 2.6 s with them kept). The
largest, 10,000 resamples of a few hundred episodes, are tens of MB."""


@functools.lru_cache(maxsize=BOOTSTRAPS_KEPT)
def _bootstrap_picks(n: int, resamples: int, seed: int) -> np.ndarray:
    """The plain bootstrap's resamples of ``n`` values (``resamples`` x ``n`` indices; read-only: they are shared)."""
    picks = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    picks.flags.writeable = False
    return picks


@functools.lru_cache(maxsize=BOOTSTRAPS_KEPT)
def _cluster_bootstrap(labels: tuple[Any, ...], resamples: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cluster bootstrap's resamples of ``labels``' clusters: each value's cluster index, the picked clusters
    (``resamples`` x clusters) and how many values each resample holds (read-only: they are shared)."""
    ids = {c: i for i, c in enumerate(dict.fromkeys(labels))}
    index = np.array([ids[c] for c in labels])
    picks = np.random.default_rng(seed).integers(0, len(ids), size=(resamples, len(ids)))
    picked_counts = np.bincount(index)[picks].sum(axis=1)
    for array in (index, picks, picked_counts):
        array.flags.writeable = False
    return index, picks, picked_counts


def compare_to_baseline(table: EfficiencyTable, baseline: str = "greedy-dist", min_scenes: int = MIN_SCENES) -> list[PairedComparison]:
    """Every other method against ``baseline`` per scale, on the scenes both ran (small to super large, then by method)."""
    out = []
    for (method, scale), eff in sorted(table.items(), key=lambda kv: (scale_rank(kv[0][1]), kv[0][1], kv[0][0])):
        base = table.get((baseline, scale))
        if method == baseline or base is None:
            continue
        scenes = sorted(s for s in set(eff) & set(base) if base[s] > 0)
        plans = [s[:4] for s in scenes]  # the scene without its seed
        if len(set(plans)) < min_scenes:  # the seeds of a plan are resampled together: they count once
            continue
        m = np.array([eff[s] for s in scenes])
        b = np.array([base[s] for s in scenes])
        ratio = m / b
        lo, hi = bootstrap_mean_ci(ratio, clusters=plans)
        geo: tuple[float, float, float] | tuple[None, None, None] = (None, None, None)
        if (ratio > 0).all():  # a scene the method explored nothing of has no log-ratio
            log_ratio = np.log(ratio)
            geo = tuple(round(100 * math.expm1(v), 3) for v in (log_ratio.mean(), *bootstrap_mean_ci(log_ratio, clusters=plans)))  # type: ignore[assignment]
        out.append(
            PairedComparison(
                scale=scale,
                method=method,
                baseline=baseline,
                scenes=len(scenes),
                change_of_means_pct=round(100 * (m.mean() / b.mean() - 1), 3),
                per_scene_pct=round(100 * (ratio.mean() - 1), 3),
                ci_low_pct=round(100 * (lo - 1), 3),
                ci_high_pct=round(100 * (hi - 1), 3),
                won=int((ratio > 1).sum()),
                lost=int((ratio < 1).sum()),
                geomean_pct=geo[0],
                geomean_ci_low_pct=geo[1],
                geomean_ci_high_pct=geo[2],
                plans=len(set(plans)),
            )
        )
    return out


def markdown_table(comparisons: Sequence[PairedComparison]) -> str:
    """The comparisons as a Markdown table (``compare``'s default output), ready to paste into BENCHMARKS.md."""
    return "\n".join([MARKDOWN_HEADER, *(c.markdown_row() for c in comparisons)])


def write_csv(path: Path, comparisons: Sequence[Mapping[str, Any]]) -> None:
    """``comparisons`` as ``as_dicts`` gives them (the rows of ``summary.json``'s ``paired``)."""
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=list(CSV_FIELDS))
    writer.writeheader()
    writer.writerows(comparisons)
    write_text_atomic(Path(path), table.getvalue())


def as_dicts(comparisons: Sequence[PairedComparison]) -> list[dict[str, Any]]:
    """The comparisons as plain dicts: the rows of ``summary.json``'s ``paired``, ``compare --json`` and ``write_csv``."""
    return [asdict(c) for c in comparisons]
