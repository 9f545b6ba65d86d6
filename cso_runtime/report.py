"""``report.html``: an evaluation's (or a run's) results on one page, for a browser.

The Table 1 rows of ``summary.json`` (one block per scale, as the paper's), Table 2's layout when the run has
ablations, the paired comparison with the baseline, every episode of ``episodes.csv`` (collapsed), the failures, and the figures already in the folder (coverage curves, efficiency by scale, the paired
scatter, each map's trajectories, animations and final maps), linked by relative paths so the folder can be moved or served
as it is. Written by ``eval`` and ``up`` next to ``summary.json``; nothing here computes a metric.
"""

from __future__ import annotations

import csv
import html
from pathlib import Path
from typing import Any

from cso_runtime.comparison import PAIRED_COLUMNS, format_interval, paired_cells, whole_rows
from cso_runtime.live_view import NO_COVERAGE, NO_GROUND_TRUTH, NO_OWN_GROUND_TRUTH
from cso_runtime.outputs import (
    COVERAGE_FIGURE,
    EFFICIENCY_FIGURE,
    PAIRED_FIGURE,
    REPORT_NAME,
    episode_animation_path,
    episode_map_path,
    trajectory_plot_path,
    write_text_atomic,
)
from cso_runtime.policies import LEARNED_METHODS
from cso_runtime.scenes import SCALES, scale_rank

FIGURES = (
    (COVERAGE_FIGURE, "Coverage against step (Fig. 4)"),
    (EFFICIENCY_FIGURE, "Efficiency by scale, and each method against the baseline (Fig. 5)"),
    (PAIRED_FIGURE, "Each scene's m2/step against the baseline's"),
)
TABLE1_COLUMNS = ("method", "scale", "episodes", "explored m2", "coverage %", "steps", "m2/step", "path m", "decision ms p50/p99")
TABLE1_DEFINITIONS = (
    ("explored m2", "the traversable floor (free space 4-connected to the start) that the robot's map holds as free at the end"),
    ("coverage %", "explored m2 over the traversable floor's m2"),
    ("steps", "control periods (robot.control_period_s, 0.25 s) until the episode ended: by coverage, no reachable frontier or the step limit"),
    ("m2/step", "the mean of each episode's explored m2 / steps (not the mean area over the mean steps; an episode of no step is left out)"),
    ("path m", "metres the robot drove, from its true pose"),
    ("decision ms p50/p99", "median and 99th percentile of each episode's decision times (frontiers, fast marching, entropy, masks, goal choice)"),
)
"""How each Table 1 column is computed (docs/eval.md, Outputs); every figure is a mean over the row's episodes.
The steps' period is the run's own: ``table1_definitions``."""


def of_a_real_robot(summary: dict[str, Any]) -> bool:
    """Whether ``summary`` is of a run of ``up`` on a real robot: a profile, no simulator (no ``sim_settings`` and no
    simulated time), so its steps are no control periods. Whether its coverage was measured is ``coverage_measured``'s."""
    meta = summary.get("meta") or {}
    no_sim_time = all(isinstance(e, dict) and e.get("sim_time_s") is None for e in summary["methods"].values())
    return isinstance(meta.get("profile"), dict) and "sim_settings" not in meta and no_sim_time


def of_an_own_referee(summary: dict[str, Any]) -> bool:
    """Whether ``summary`` is of a run of ``up`` whose referee is one of one's own (``of_a_real_robot``, with a profile
    whose services have neither referee of ``run_profile.REFEREES``: a command node publishing ``episode_status`` and
    ``episode_result``, a simulator of one's own, say): no real robot, its steps as that referee counts them. A profile
    with no services (a summary of an older version, a hand-made meta) says nothing of it: a real robot's, as before."""
    from cso_runtime.run_profile import OWN_REFEREE, referee_kind  # noqa: PLC0415 - loads the scenes' code: only where reports are made

    profile = (summary.get("meta") or {}).get("profile")
    services = profile.get("services") if isinstance(profile, dict) else None
    return of_a_real_robot(summary) and isinstance(services, dict) and referee_kind(services) == OWN_REFEREE


def no_ground_truth_said(summary: dict[str, Any]) -> str:
    """What report.html says of the coverage of ``summary``'s run where it was not measured: ``NO_GROUND_TRUTH`` (a real
    robot's), or ``NO_OWN_GROUND_TRUTH`` with a referee of one's own (``of_an_own_referee``), which is no real robot."""
    return NO_OWN_GROUND_TRUTH if of_an_own_referee(summary) else NO_GROUND_TRUTH


def coverage_measured(summary: dict[str, Any]) -> bool:
    """Whether ``summary``'s run had a ground truth, its coverage measured (``run_profile.measures_coverage``, the one
    answer ``status``, ``runs`` and the live view give): what ``up`` wrote (``meta.coverage_measured``), else, of an
    older version's summary, its profile's services (``meta.profile``: the sim's), and of a profile with none, the
    simulator's traces (``of_a_real_robot``); an eval summary (no profile) ran the simulator."""
    from cso_runtime.run_profile import measures_coverage  # noqa: PLC0415 - loads the scenes' code: only where reports are made

    meta = summary.get("meta") or {}
    profile = meta.get("profile")
    if isinstance(meta.get("coverage_measured"), bool) or (isinstance(profile, dict) and isinstance(profile.get("services"), dict)):
        return measures_coverage(profile if isinstance(profile, dict) else {}, meta.get("coverage_measured"))
    return not of_a_real_robot(summary)


def table1_definitions(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """``TABLE1_DEFINITIONS`` with the steps said as the run counted them: its control period (``meta.config``'s
    ``robot.control_period_s``, which ``--set`` changes), or, for a run of ``up`` on a real robot
    (``of_a_real_robot``), its scans, and with a referee of one's own (``of_an_own_referee``), that referee's steps;
    coverage is ``no_ground_truth_said`` where not ``coverage_measured``."""
    meta = summary.get("meta") or {}
    robot = (meta.get("config") or {}).get("robot") or {}
    period_s = robot.get("control_period_s", 0.25)
    if of_an_own_referee(summary):
        steps = "steps as the run's own referee counted them (a referee of one's own, neither the sim nor the ros2_bridge) until the episode ended: by coverage, no reachable frontier or the step limit"
    elif of_a_real_robot(summary):
        steps = "scans of the real robot (about 10 Hz on the LIMO) until the episode ended: by coverage, no reachable frontier or the step limit"
    else:
        steps = f"control periods (robot.control_period_s, {period_s:g} s) until the episode ended: by coverage, no reachable frontier or the step limit"
    said = {"steps": steps, **({} if coverage_measured(summary) else {"coverage %": f"{no_ground_truth_said(summary)}; summary.json and episodes.csv hold 0"})}
    return [(column, said.get(column, words)) for column, words in TABLE1_DEFINITIONS]
STD_SUFFIX = "_std"
"""``summary.json``'s key of a metric's sample standard deviation (ddof=1) over the episodes, beside its mean:
``coverage_pct_std``."""
CI95_SUFFIX = "_ci95"
"""``summary.json``'s key of a metric's 95 % bootstrap interval of the mean over plans, [low, high]:
``coverage_pct_ci95``."""
CI95_NOTE = "A row's tooltip: the 95 % interval of each mean, the bootstrap over plans of compare (summary.json's <metric>_ci95); none under two plans."
SPREAD_NOTE = "mean ± sample standard deviation (ddof=1) over the row's episodes; the mean alone for a row of one episode"
"""What a Table 1 cell shows, said under the table on the console and in the report."""
MEANS_NOTE = "means over the row's episodes; each with its standard deviation in report.html and summary.json (<metric>_std)"
"""Under the console's Table 1 when the spread would not fit the terminal's width."""


def _fmt(v: Any, nd: int) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def whole_count(count: Any) -> Any:
    """One episode's count (its steps) as the whole number it is: ``summary.json`` writes it as a mean (36.0)."""
    return int(count) if isinstance(count, float) and count.is_integer() else count


def _fmt_spread(e: dict[str, Any], metric: str, nd: int) -> str:
    """``12.3 ± 1.2``: the metric's mean and its sample standard deviation; the mean alone where there is none
    (one episode, or a summary.json from before the spread was written)."""
    std = e.get(metric + STD_SUFFIX)
    return _fmt(e[metric], nd) if std is None or e[metric] is None else f"{e[metric]:.{nd}f} ± {std:.{nd}f}"


def table1_rows(summary: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    """``(method, scale, metrics)`` in the paper's layout: a method's one scale, or each of its scales then ``all``."""
    rows = []
    for method, e in summary["methods"].items():
        scales = e.get("by_scale") or {}
        if len(scales) == 1:
            rows.append((method, next(iter(scales)), e))
            continue
        rows += [(method, scale, part) for scale, part in scales.items()]
        rows.append((method, "all", e))
    return rows


TABLE1_METRICS = (
    ("explored m2", "explored_area_m2", 1),
    ("coverage %", "coverage_pct", 2),
    ("steps", "steps", 1),
    ("m2/step", "efficiency_m2_per_step", 4),
    ("path m", "path_length_m", 1),
    ("decision ms p50", "decision_ms_p50", 1),
    ("decision ms p99", "decision_ms_p99", 1),
)
"""Table 1's figures after its episode count: the column, its ``summary.json`` metric and the decimals it is shown
with (the cells, their spread and their intervals); the two decision times share one column."""


# NO_COVERAGE (live_view's, as ``runs`` says it): a coverage cell of a run with no ground truth (not
# ``coverage_measured``: a real robot's, a referee of one's own), whose 0 is no measure (no ground truth, ``NO_GROUND_TRUTH``); summary.json and episodes.csv keep the 0.


def table1_cells(e: dict[str, Any], spread: bool = True, no_coverage: bool = False) -> list[str]:
    """One Table 1 row's values after its method and scale, as the console and the report print them: each mean
    ± its sample standard deviation (``SPREAD_NOTE``), or the means alone without ``spread``; coverage
    ``NO_COVERAGE`` with ``no_coverage`` (a run with no ground truth: not ``coverage_measured``)."""

    def cell(metric: str, nd: int) -> str:
        if no_coverage and metric == "coverage_pct":
            return NO_COVERAGE
        return _fmt_spread(e, metric, nd) if spread else _fmt(e[metric], nd)

    # A row of one episode: its steps as counted (261), as the episode's own line and `runs` say them, not "261.0".
    one_count = whole_count(e["steps"]) if e["episodes"] == 1 else None
    cells = {metric: str(one_count) if metric == "steps" and isinstance(one_count, int) else cell(metric, nd) for _, metric, nd in TABLE1_METRICS}
    decisions = f"{cells.pop('decision_ms_p50')}/{cells.pop('decision_ms_p99')}"
    return [str(e["episodes"]), *cells.values(), decisions]


def table2(summary: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The paper's Table 2 layout: a row per method, a column per scale present, each cell the mean m2/step and,
    where summary.json has the paired comparison, the per-scene change against the baseline [95 % CI]."""
    scales = [s for s in SCALES if any(s in (e.get("by_scale") or {}) for e in summary["methods"].values())]
    paired = {(c["method"], c["scale"]): c for c in (summary.get("paired") or {}).get("comparisons", [])}
    rows = []
    for method, e in summary["methods"].items():
        cells = [method]
        for scale in scales:
            part = (e.get("by_scale") or {}).get(scale)
            cell = "-" if part is None else _fmt(part["efficiency_m2_per_step"], 4)
            c = paired.get((method, scale))
            if c is not None:
                cell += f" ({format_interval(c['per_scene_pct'], c['ci_low_pct'], c['ci_high_pct'])})"
            cells.append(cell)
        rows.append(cells)
    return ["method", *scales], rows


def shows_ablations(summary: dict[str, Any]) -> bool:
    """Two or more learned methods (cso and its ablations): the run reproduces Table 2, so it is laid out too."""
    return sum(m in LEARNED_METHODS for m in summary["methods"]) >= 2




def ci95_text(e: dict[str, Any]) -> str:
    """A Table 1 row's tooltip: each mean's 95 % bootstrap interval over plans (``<metric>_ci95``); "" where there
    is none (one plan, or a summary.json from before the intervals were written)."""
    shown = [f"{col} [{ci[0]:.{nd}f}, {ci[1]:.{nd}f}]" for col, metric, nd in TABLE1_METRICS if (ci := e.get(metric + CI95_SUFFIX))]
    return "95 % interval of the mean (bootstrap over plans): " + "; ".join(shown) if shown else ""


def _table(header: list[str] | tuple[str, ...], rows: list[list[str]], titles: list[str] | None = None) -> str:
    """An HTML table; ``titles``, one per row, are the rows' tooltips ("" for none)."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    tips = titles or [""] * len(rows)
    body = "".join(
        (f'<tr title="{html.escape(t)}">' if t else "<tr>") + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
        for r, t in zip(rows, tips, strict=True)
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


SCENE_COLUMNS = ("plan", "method", "scale", "seed", "coverage %", "steps", "m2/step", "terminated by")
"""The per-scene table: one row per episode of ``episodes.csv``."""


def scene_rows(out_dir: Path, summary: dict[str, Any]) -> list[list[str]]:
    """Each episode of ``out_dir/episodes.csv`` as a ``SCENE_COLUMNS`` row, by scale, plan, then method as in Table 1,
    so the methods on one plan stand together; only ``summary``'s methods and plans (its ``maps``, where written);
    coverage ``NO_COVERAGE`` where it was not measured (``coverage_measured``). [] without the file (a folder of an older version, or one that lost it)."""
    return scene_table(out_dir, summary)[0]


def scene_table(out_dir: Path, summary: dict[str, Any]) -> tuple[list[list[str]], str]:
    """``scene_rows``, and what the report must say of them: "" where they are every episode ``summary`` counts;
    otherwise how many of them it shows and why (a row of ``episodes.csv`` cut short or mangled is not shown, nor any
    after it: ``comparison.whole_rows``; a file cut at a line's end, or changed since, holds fewer rows)."""
    problem = ""
    episodes: list[dict[str, str]] = []
    try:
        with (out_dir / "episodes.csv").open(newline="", encoding="utf-8") as fh:
            episodes.extend(whole_rows(csv.DictReader(fh)))  # the rows before a bad one stay, when it raises
    except FileNotFoundError:  # a folder of an older version, or one that lost it
        return [], "no episodes.csv in the folder: no per-scene table" if any(e.get("episodes") for e in summary["methods"].values()) else ""
    except ValueError as exc:  # UnicodeDecodeError too
        problem = f"{exc}; "
    except (OSError, csv.Error) as exc:
        problem = f"cannot read it ({exc}); "
    rows = _scene_rows(episodes, summary)
    counted = [n for e in summary["methods"].values() if isinstance(n := e.get("episodes"), int)]
    if len(counted) == len(summary["methods"]) and len(rows) < sum(counted):  # summaries of every version count them
        problem += f"the table shows {len(rows)} of the {sum(counted)} episodes summary.json counts"
    elif problem:
        problem += f"the table shows the {len(rows)} episodes before it"
    return rows, f"episodes.csv: {problem}" if problem else ""


def _scene_rows(episodes: list[dict[str, str]], summary: dict[str, Any]) -> list[list[str]]:
    """``scene_rows`` of the rows read from ``episodes.csv``."""
    methods = summary["methods"]
    order = list(methods)
    measured = coverage_measured(summary)

    def shown(r: dict[str, str]) -> bool:
        e = methods.get(r.get("method"))
        return e is not None and ("maps" not in e or r.get("map") in e["maps"])

    def number(r: dict[str, str], key: str, nd: int) -> str:
        try:
            return _fmt(float(r[key]), nd)
        except (KeyError, TypeError, ValueError):
            return "-"

    def seed(r: dict[str, str]) -> tuple[int, str]:
        text = r.get("seed") or ""
        return (int(text), text) if text.lstrip("-").isdigit() else (0, text)

    kept = sorted(filter(shown, episodes), key=lambda r: (scale_rank(r.get("scale") or ""), r.get("scale") or "", r.get("map") or "", order.index(r["method"]), seed(r)))
    return [
        [r.get("map") or "", r["method"], r.get("scale") or "", r.get("seed") or "", number(r, "coverage_pct", 2) if measured else NO_COVERAGE,
         r.get("steps") or "-", number(r, "efficiency_m2_per_step", 4), r.get("terminated_by") or ""]
        for r in kept
    ]


def _img(out_dir: Path, path: Path, alt: str, css_class: str = "") -> str:
    rel = path.relative_to(out_dir).as_posix()
    cls = f' class="{css_class}"' if css_class else ""
    return f'<a href="{html.escape(rel)}"><img src="{html.escape(rel)}" alt="{html.escape(alt)}"{cls} loading="lazy"></a>'


def _captioned(img: str, caption: str) -> str:
    """One picture with its own caption: a ``<figure>`` holds one ``<figcaption>`` (HTML), so each method's animation
    and map is a figure of its own inside the plan's."""
    return f"<figure>{img}<figcaption>{caption}</figcaption></figure>"


def _final_map(out_dir: Path, method: str, name: str) -> str:
    """The robot's final map of one episode as map_server serves it (its PNG, cells drawn as squares), captioned
    with a link to its YAML; "" where the episode wrote none (an older folder, a run without its map)."""
    yaml_path = episode_map_path(out_dir, method, name)
    image = yaml_path.with_suffix(".png")
    if not (yaml_path.is_file() and image.is_file()):
        return ""
    yaml_rel = html.escape(yaml_path.relative_to(out_dir).as_posix())
    caption = f'{html.escape(method)}, final map (Nav2 map_server: <a href="{yaml_rel}">{html.escape(yaml_path.name)}</a>)'
    return _captioned(_img(out_dir, image, f"{name}: {method}, final map", "grid"), caption)


def _map_figures(out_dir: Path, summary: dict[str, Any]) -> dict[str, list[str]]:
    """Each plan's trajectory plot, animations and each method's final map, as HTML by plan name. Only the plans and methods of
    ``summary`` (its ``maps``), so that an earlier run's files left in an ``eval --out`` folder stay out; a
    summary.json from before ``maps`` was written shows every file of the folder."""
    methods = summary["methods"]
    by_map: dict[str, list[str]] = {}
    if not all("maps" in e for e in methods.values()):
        for p in sorted((out_dir / "trajectories").glob("*.png")):
            by_map.setdefault(p.stem, []).append(_img(out_dir, p, f"{p.stem}: trajectories"))
        for p in sorted((out_dir / "animations").glob("*/*.gif")):
            by_map.setdefault(p.stem, []).append(_captioned(_img(out_dir, p, f"{p.stem}: {p.parent.name}"), f"{html.escape(p.parent.name)}, animated"))
        return by_map
    for name in sorted({m for e in methods.values() for m in e["maps"]}):
        path = trajectory_plot_path(out_dir, name)
        if path.is_file():
            by_map.setdefault(name, []).append(_img(out_dir, path, f"{name}: trajectories"))
    for method, e in methods.items():
        for name in e["maps"]:
            path = episode_animation_path(out_dir, method, name)
            if path.is_file():
                by_map.setdefault(name, []).append(_captioned(_img(out_dir, path, f"{name}: {method}"), f"{html.escape(method)}, animated"))
            final_map = _final_map(out_dir, method, name)
            if final_map:
                by_map.setdefault(name, []).append(final_map)
    return by_map


def failure_said(failure: dict[str, Any]) -> str:
    """One failed episode of ``summary.json``'s ``failures`` as the console and the report say it: method, plan, with
    ``--seeds`` its seed (the same plan failed under two seeds is two failures), and the first line of why."""
    why = failure["error"].splitlines()[0] if failure.get("error") else ""
    seed = f" (seed {failure['seed']})" if "seed" in failure else ""
    return f"{failure['method']} {failure['map']}{seed}: {why}"


def run_settings_text(meta: dict[str, Any]) -> str:
    """The run's header line: what made the table, with the sensor's field of view and the step limit, which decide
    whether it compares with the paper's (360 degrees, 3000 steps); ``meta.config`` is absent from older summaries."""
    parts = [f"{k}: {meta[k]}" for k in ("command", "version", "maps", "m_per_px", "cell_sizes_m", "seed", "seeds", "sim") if meta.get(k) is not None]
    software = meta.get("software")
    if isinstance(software, dict) and software.get("git_commit"):  # run from a checkout (provenance.software_provenance)
        parts.insert(sum(meta.get(k) is not None for k in ("command", "version")), f"commit: {str(software['git_commit'])[:12]}{' (modified)' if software.get('git_modified') else ''}")
    profile = meta.get("profile")
    if isinstance(profile, dict):  # a run of `up`: its profile, as run, stands for eval's flags
        shown = {"profile": profile.get("name"), "scene": profile.get("scene"), "seed": profile.get("seed")}
        parts += [f"{k}: {v}" for k, v in shown.items() if v is not None]
        parts.append("lockstep" if profile.get("lockstep") else "real time")
    config = meta.get("config") or {}
    fov_deg = (config.get("sensor") or {}).get("fov_deg")
    max_steps = (config.get("episode") or {}).get("max_steps")
    if fov_deg is not None:
        parts.append(f"sensor field of view: {fov_deg:g} degrees")
    if max_steps is not None:
        parts.append(f"step limit: {max_steps}")
    return ", ".join(parts)


def lost_results_said(lost: Any, meta: dict[str, Any]) -> str:
    """What report.html says of the episodes of a run of ``up`` whose result a restart of the referee lost before
    the episode of its results ended (``meta.lost_results``, as run.json's), each as ``status`` says it; a malformed
    list (a summary.json edited by hand) is said to be one."""
    from cso_runtime.messages import MessageError, lost_results_of  # noqa: PLC0415 - the launcher's status's reading
    from cso_runtime.run_profile import referee_kind  # noqa: PLC0415
    from cso_runtime.status import lost_result_words  # noqa: PLC0415

    profile = meta.get("profile")
    services = profile.get("services") if isinstance(profile, dict) else None
    try:
        entries = lost_results_of(lost, "meta.lost_results")
    except MessageError as exc:
        return f"results of earlier episodes were lost to a restart of the referee ({exc})"
    referee = referee_kind(services) if isinstance(services, dict) else None
    return "; ".join(lost_result_words(e, referee) for e in entries)


def write_report(out_dir: Path, summary: dict[str, Any]) -> Path:
    """Write ``out_dir/report.html`` from ``summary`` and the figures found in ``out_dir``; returns its path."""
    out_dir = Path(out_dir)
    meta = summary.get("meta") or {}
    parts = [
        # The folder's name in the tab: several reports open side by side are told apart.
        f"<!doctype html><html><head><meta charset='utf-8'><title>cso-runtime results: {html.escape(out_dir.resolve().name)}</title><style>",
        "body{font-family:system-ui,sans-serif;margin:1.5em;max-width:1400px}table{border-collapse:collapse;margin:.5em 0 1.5em}",
        "td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}td:first-child,td:nth-child(2),th{text-align:left}",
        "img{max-width:100%;height:auto;border:1px solid #eee}.maps{display:flex;flex-wrap:wrap;gap:1em}.maps>figure{margin:0;max-width:100%}",
        ".maps figure figure{display:inline-block;vertical-align:top;margin:.5em 1em .5em 0;max-width:480px}img.grid{image-rendering:pixelated;min-width:320px}",
        "</style></head><body>",
        f"<h1>Results in {html.escape(str(out_dir))}</h1>",
        "<p>" + html.escape(run_settings_text(meta)) + "</p>",
    ]
    if meta.get("seeds"):  # eval --seeds: every seed's episodes pooled here; each seed's trajectories and maps in its folder
        links = ", ".join(f'<a href="seed{int(s)}/{REPORT_NAME}">seed {int(s)}</a>' for s in meta["seeds"])
        parts.append(f"<p>The episodes of {len(meta['seeds'])} seeds pooled; each seed's episodes, trajectories and maps: {links}.</p>")
    stopped = meta.get("interrupted")
    if stopped:  # a table of the episodes that finished: it must not pass for the whole run's
        parts.append(
            f"<p style='color:#b00'><b>Interrupted: {stopped.get('episodes_finished')} of {stopped.get('episodes_planned')} episodes finished</b>; "
            "the tables and figures cover those only. The same command with --resume runs the rest.</p>"
        )
    if lost := meta.get("lost_results"):  # `up`'s: the episode of these results is not the run's first to end
        parts.append(f"<p style='color:#b00'>{html.escape(lost_results_said(lost, meta))}.</p>")
    no_coverage = not coverage_measured(summary)
    parts += [
        "<h2>Table 1</h2>",
        _table(TABLE1_COLUMNS, [[m, s, *table1_cells(e, no_coverage=no_coverage)] for m, s, e in table1_rows(summary)], [ci95_text(e) for _, _, e in table1_rows(summary)]),
        f"<p>Each cell: {html.escape(SPREAD_NOTE)}.</p>",
        f"<p>{html.escape(CI95_NOTE)}</p>",
        "<dl>" + "".join(f"<dt>{html.escape(c)}</dt><dd>{html.escape(d)}</dd>" for c, d in table1_definitions(summary)) + "</dl>",
    ]
    if shows_ablations(summary):
        parts.append("<h2>Table 2: efficiency, m2/step (per-scene change against the baseline)</h2>")
        parts.append(_table(*table2(summary)))
    paired = summary.get("paired") or {}
    if paired.get("comparisons"):
        parts.append(f"<h2>Against {html.escape(str(paired['baseline']))}, scene by scene</h2>")
        parts.append(_table(PAIRED_COLUMNS, [paired_cells(c) for c in paired["comparisons"]]))
    scenes, scenes_lacking = scene_table(out_dir, summary)
    if scenes_lacking:  # a cut episodes.csv: the table must not pass for every episode of Table 1
        parts.append(f"<p style='color:#b00'><b>Every episode, scene by scene: {html.escape(scenes_lacking)}</b></p>")
    if scenes:
        parts.append(f"<details><summary><b>Every episode, scene by scene</b> ({len(scenes)}, by scale then plan)</summary>")
        parts += [_table(SCENE_COLUMNS, scenes), "</details>"]
    if summary.get("failures"):
        parts.append("<h2>Failures</h2><ul>")
        parts += [f"<li>{html.escape(failure_said(f))}</li>" for f in summary["failures"]]
        parts.append("</ul>")
    figures = [(out_dir / name, title) for name, title in FIGURES if (out_dir / name).is_file()]
    if figures:
        parts.append("<h2>Figures</h2>")
        # A run with no ground truth (a real robot's) has a coverage curve of its row's 0 at every step: said n/a, as
        # its cells (the file stays written).
        parts += [
            f"<p>{html.escape(t)}: {html.escape(no_ground_truth_said(summary))}</p>" if no_coverage and p.name == COVERAGE_FIGURE
            else f"<figure>{_img(out_dir, p, t)}<figcaption>{html.escape(t)}</figcaption></figure>"
            for p, t in figures
        ]  # fmt: skip
    by_map = _map_figures(out_dir, summary)
    if by_map:
        parts.append("<h2>Maps</h2><div class='maps'>")
        parts += [f"<figure><figcaption><b>{html.escape(name)}</b></figcaption>{''.join(items)}</figure>" for name, items in by_map.items()]
        parts.append("</div>")
    parts.append("</body></html>\n")
    path = out_dir / REPORT_NAME
    write_text_atomic(path, "\n".join(parts))
    return path
