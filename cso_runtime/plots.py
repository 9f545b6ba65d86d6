"""Figures like the paper's: coverage against step (Fig. 4) and explored map with path (Fig. 6)."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from cso_runtime.outputs import write_whole


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` on the Agg backend (files only: eval and train run headless), imported on first use as it is
    slow (``import_pyplot_in_background`` gives the launcher a head start; ``train`` loads it before its first update)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def import_pyplot_in_background() -> threading.Thread:
    """Start ``pyplot``'s import (about 1 s of a 2-core host's time) on a daemon thread, for a process that draws its
    figures only after a wait of its own: the launcher, while its services start and its episode runs, drew them
    that much later once the episode had ended. A figure drawn before the import is done waits for it (Python's
    import lock); an import that fails here fails again, and is said, where the figure is drawn."""

    def run() -> None:
        try:
            pyplot()
        except Exception:  # noqa: BLE001, S110 - only a head start: the figure's own import raises it where it is said
            pass

    thread = threading.Thread(target=run, name="import-pyplot", daemon=True)
    thread.start()
    return thread


def _save(fig: Any, path: Path, dpi: int) -> None:
    """Write a figure as a PNG (making its folder) and free it: eval writes hundreds."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:  # whole: report.html links it, and a resumed eval's report keeps it
        write_whole(path, lambda partial: fig.savefig(partial, dpi=dpi, format="png"))
    finally:
        pyplot().close(fig)


LINE_STYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">")
HATCHES = ("", "//", "..", "xx", "\\\\", "oo", "--", "++", "||", "**")


def method_style(index: int) -> dict[str, str]:
    """Method ``index``'s look in every figure: its colour (``C<index>``, matplotlib's default cycle) and, because
    that cycle's green and red (methods 3 and 4) look alike to red-green colour-blind readers, a line style, a
    marker and a bar hatch that differ from its neighbours' too."""
    return {
        "color": f"C{index % 10}",
        "linestyle": LINE_STYLES[index % len(LINE_STYLES)],
        "marker": MARKERS[index % len(MARKERS)],
        "hatch": HATCHES[index % len(HATCHES)],
    }


def plot_coverage_curves(path: Path, outcomes: Sequence[Any], methods: Sequence[str] = ()) -> None:
    """``coverage_figure`` written as a PNG."""
    _save(coverage_figure(outcomes, methods), path, 110)


def held_mean_curves(curves_by_method: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray]:
    """Each method's mean coverage curve over its episodes, every episode held at its final coverage to the end of
    the longest episode of any method (a finished episode keeps what it explored: dropping it, or ending a method's
    line at its own longest episode, would compare methods over different steps)."""
    n = max((len(c) for curves in curves_by_method.values() for c in curves), default=0)
    return {m: np.stack([np.pad(c, (0, n - len(c)), mode="edge") for c in curves]).mean(axis=0) for m, curves in curves_by_method.items()}


DEFAULT_STEP_S = 0.25
"""``robot.control_period_s``'s default: the step of an episode whose row does not say (an older run's)."""


def step_words(outcomes: Sequence[Any]) -> str:
    """What a step on the coverage figure's axis is: the control period the episodes ran with (``sim_time_s`` over
    ``steps`` of their rows: ``--set robot.control_period_s`` changes it), or, on a real robot (no simulated time),
    its scans, which come as they come (about 10 Hz on the LIMO)."""
    rows = [o.row for o in outcomes if o.row]
    if rows and all("sim_time_s" in r and r["sim_time_s"] is None for r in rows):
        return "step (a scan of the real robot)"
    periods = {round(r["sim_time_s"] / r["steps"], 6) for r in rows if r.get("sim_time_s") and r.get("steps")}
    period_s = next(iter(periods)) if len(periods) == 1 else DEFAULT_STEP_S if not periods else None
    return "step" if period_s is None else f"step ({period_s:g} s)"


def coverage_figure(outcomes: Sequence[Any], methods: Sequence[str] = ()) -> Any:
    """Mean coverage (%) against step per method, like the paper's Fig. 4; each episode's curve is held at its
    final value to the end of the panel's longest episode (``held_mean_curves``), so every method's line spans the
    same steps. One panel per scene scale when the episodes span several (a mean over a small and a super-large
    scene says little about either), titled with the plan's name when every episode ran on one (a run of ``up``);
    each method keeps its colour across panels, and with ``methods`` (the run's
    order, as ``summary.json`` lists them) the colour the efficiency figure gives it, whatever order the episodes
    finished in."""
    from matplotlib.ticker import MaxNLocator  # noqa: PLC0415  (matplotlib is slow to import)

    from cso_runtime.scenes import SCALES  # noqa: PLC0415  (keeps this module's import light)

    plt = pyplot()
    by_scale: dict[str, dict[str, list[np.ndarray]]] = {}
    styles: dict[str, dict[str, str]] = {m: method_style(i) for i, m in enumerate(dict.fromkeys(methods))}
    for o in outcomes:
        scale = (o.row or {}).get("scale", "")
        by_scale.setdefault(scale, {}).setdefault(o.method, []).append(np.asarray(o.coverage_curve_pct))
        styles.setdefault(o.method, method_style(len(styles)))
    order = {sc: i for i, sc in enumerate(SCALES)}
    scales = sorted(by_scale, key=lambda sc: order.get(sc, len(order))) or [""]
    plans = {o.map for o in outcomes}
    on_plan = f" on {next(iter(plans))}" if len(plans) == 1 and len(scales) == 1 else ""  # a run of up, an eval of one plan
    fig, axes = plt.subplots(1, len(scales), figsize=(7 if len(scales) == 1 else 4.6 * len(scales), 4.5), squeeze=False, layout="constrained")
    for ax, scale in zip(axes[0], scales):
        by_method = by_scale.get(scale, {})
        curves_by_method = {m: by_method[m] for m in styles if m in by_method}  # the run's order, as the other figures' keys
        for method, mean in held_mean_curves(curves_by_method).items():
            style = styles[method]
            one_point = style["marker"] if len(mean) == 1 else ""  # episodes of no step: a line of one point draws nothing
            ax.plot(np.arange(len(mean)), mean, label=f"{method} ({len(curves_by_method[method])} ep.)", color=style["color"], linestyle=style["linestyle"], marker=one_point)
        ax.set_xlabel(f"{step_words(outcomes)}; an episode that ended holds its final coverage")
        ax.set_ylabel("mean coverage (%)")
        ax.set_ylim(0, 101)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # steps are counted: no 0.2 step
        ax.grid(alpha=0.3)
        if curves_by_method:
            ax.set_xlim(0, max(len(ax.lines[0].get_xdata()) - 1, 1))
            small = len(scales) > 1
            ax.legend(loc="lower right", fontsize=8 if small else 10, title="mean over episodes,\nended ones held", title_fontsize=7 if small else 9)
        ax.set_title("Coverage against step" + (f": {scale.replace('_', ' ')}" if len(scales) > 1 else "") + on_plan)
    return fig


def draw_plan_image(ax: Any, img: np.ndarray, resolution_m: float, map_origin: Any = None) -> None:
    """Draw a plan-shaped RGB image (row 0 at the plan's bottom edge) where the plan lies in the user's map frame:
    moved and turned by ``map_origin`` (a ``Pose2D``, ``FloorPlan.map_origin``; None: the plan's frame is the map
    frame), so that axes read as the map frame that ``scenes``, ``status`` and a map_server YAML's ``start`` use.
    The axes take the turned plan's bounds and an equal aspect."""
    from matplotlib.transforms import Affine2D  # noqa: PLC0415  (matplotlib is slow to import)

    h, w = img.shape[:2]
    x0, y0, yaw = (0.0, 0.0, 0.0) if map_origin is None else (map_origin.x_m, map_origin.y_m, map_origin.yaw_rad)
    to_map = Affine2D().rotate(yaw).translate(x0, y0)
    image = ax.imshow(img, origin="lower", extent=(0, w * resolution_m, 0, h * resolution_m), interpolation="nearest")
    image.set_transform(to_map + ax.transData)
    corners = to_map.transform([(0, 0), (w * resolution_m, 0), (0, h * resolution_m), (w * resolution_m, h * resolution_m)])
    ax.set_xlim(corners[:, 0].min(), corners[:, 0].max())
    ax.set_ylim(corners[:, 1].min(), corners[:, 1].max())
    ax.set_aspect("equal")


def map_frame_points(xy_m: np.ndarray, map_origin: Any = None) -> np.ndarray:
    """Points (n x 2 metres) of the plan's frame in the user's map frame (``draw_plan_image``'s frame)."""
    from cso_runtime.geometry import compose_xy  # noqa: PLC0415  (keeps this module's import light)

    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    return xy if map_origin is None else compose_xy(map_origin, xy)


WALL_RGB = (0.25, 0.25, 0.25)
UNEXPLORED_FREE_RGB = (0.75, 0.75, 0.75)
EXPLORED_FREE_RGB = (0.62, 0.82, 0.98)


def plot_trajectories(path: Path, name: str, outcomes: Sequence[Any]) -> None:
    """``trajectory_figure`` written as a PNG."""
    _save(trajectory_figure(name, outcomes), path, 100)


TRAJECTORY_COLUMNS = 3
"""Panels in a row of the trajectory figure: five methods in one row made a strip 35 inches wide whose titles and
axes were unreadable at the report's width; more methods go on further rows."""


def trajectory_figure(name: str, outcomes: Sequence[Any]) -> Any:
    """One panel per method, like the paper's Fig. 6: walls (dark), free space not explored (grey), explored
    free space (light blue), the path (red) from its start (green dot) to its end (red square), with a key, in the
    user's map frame (each outcome's ``map_origin``: a map_server scene's ``origin``). Panels take the plan's aspect
    ratio, so that tall and wide plans alike keep their axis labels, at most ``TRAJECTORY_COLUMNS`` to a row."""
    plt = pyplot()
    from matplotlib.lines import Line2D  # noqa: PLC0415  (matplotlib is slow to import)
    from matplotlib.patches import Patch  # noqa: PLC0415

    n = len(outcomes)
    h0, w0 = np.asarray(outcomes[0].free).shape
    panel_w_in = float(np.clip(4.2 * w0 / max(h0, 1), 3.0, 7.0))
    rows = -(-n // TRAJECTORY_COLUMNS)
    cols = -(-n // rows)  # the rows as full as each other: four methods in two rows of two, not three and one
    fig, axes = plt.subplots(rows, cols, figsize=(panel_w_in * cols + 0.4, 4.8 + 4.2 * (rows - 1)), squeeze=False, layout="constrained")
    for ax in axes.flat[n:]:  # the last row's empty places
        ax.remove()
    for ax, o in zip(axes.flat, outcomes):
        free = np.asarray(o.free, dtype=bool)
        h, w = free.shape
        res = o.resolution_m
        img = np.empty((h, w, 3))
        img[free] = UNEXPLORED_FREE_RGB
        img[~free] = WALL_RGB
        img[np.asarray(o.explored, dtype=bool)] = EXPLORED_FREE_RGB
        map_origin = getattr(o, "map_origin", None)
        draw_plan_image(ax, img, res, map_origin)
        traj = map_frame_points(o.trajectory_xy_m, map_origin)
        if len(traj):
            ax.plot(traj[:, 0], traj[:, 1], color="red", lw=1.0)
            ax.plot(traj[0, 0], traj[0, 1], "o", color="green", ms=5)
            ax.plot(traj[-1, 0], traj[-1, 1], "s", color="red", ms=5)
        r = o.row
        title = f"{o.method}: {r['coverage_pct']:.1f}% in {r['steps']} steps"
        if "path_length_m" in r:
            title += f", {r['path_length_m']:.1f} m path"  # to 0.1 m: small scenes' paths differ by tenths
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    key = [
        Patch(color=WALL_RGB, label="wall"),
        Patch(color=UNEXPLORED_FREE_RGB, label="free, not explored"),
        Patch(color=EXPLORED_FREE_RGB, label="explored"),
        Line2D([], [], color="red", lw=1.0, label="path"),
        Line2D([], [], color="green", marker="o", ls="", ms=5, label="start"),
        Line2D([], [], color="red", marker="s", ls="", ms=5, label="end"),
    ]
    fig.legend(handles=key, loc="outside lower center", ncols=len(key) if n > 1 else 3, fontsize=8, frameon=False)
    fig.suptitle(name)
    # Constrained layout places the fixed-aspect panels and the key below them anew at each draw, and its first
    # placement leaves the panels' titles over the plan's name (the middle panel's, with an odd number of
    # methods): one placement here, so that the draw that saves the figure starts from it and lays it out clear.
    fig.get_layout_engine().execute(fig)
    return fig


UNREACHABLE_FREE_RGB = (0.93, 0.87, 0.72)


def plot_scene(path: Path, plan: Any) -> None:
    """``scene_figure`` written as a PNG."""
    _save(scene_figure(plan), path, 100)


def scene_figure(plan: Any) -> Any:
    """A floor plan as the explorer meets it: walls, the free space reachable from the start (what coverage
    counts), free space it cannot reach (beige), and the start pose as an arrow along its yaw, in the user's map
    frame (``plan.map_origin``: the start where ``scenes`` lists it); the title gives the traversable area and the
    paper's scale class."""
    plt = pyplot()
    from matplotlib.patches import Patch  # noqa: PLC0415  (matplotlib is slow to import)

    free = np.asarray(plan.free, dtype=bool)
    reachable = plan.traversable_region()
    h, w = free.shape
    res = plan.resolution_m
    img = np.empty((h, w, 3))
    img[~free] = WALL_RGB
    img[free] = UNREACHABLE_FREE_RGB
    img[reachable] = UNEXPLORED_FREE_RGB
    fig, ax = plt.subplots(figsize=(float(np.clip(4.8 * w / max(h, 1), 3.2, 8.0)) + 0.4, 5.0), layout="constrained")
    draw_plan_image(ax, img, res, plan.map_origin)
    arrow_m = 0.04 * max(w, h) * res
    s = plan.to_map_frame(plan.start)
    ax.annotate("", xy=(s.x_m + arrow_m * np.cos(s.yaw_rad), s.y_m + arrow_m * np.sin(s.yaw_rad)), xytext=(s.x_m, s.y_m),
                arrowprops={"arrowstyle": "-|>", "color": "green", "lw": 1.5})
    ax.plot(s.x_m, s.y_m, "o", color="green", ms=5, label="start")
    area_m2 = float(np.count_nonzero(reachable)) * res**2
    from cso_runtime.scenes import scale_of  # noqa: PLC0415  (keeps this module's import light)

    ax.set_title(f"{plan.name}: {w * res:.1f} x {h * res:.1f} m at {res:g} m/px, {area_m2:.1f} m2 traversable ({scale_of(area_m2).replace('_', ' ')})", fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    key = [Patch(color=WALL_RGB, label="wall"), Patch(color=UNEXPLORED_FREE_RGB, label="free, reachable")]
    if np.count_nonzero(free) > np.count_nonzero(reachable):
        key.append(Patch(color=UNREACHABLE_FREE_RGB, label="free, not reachable from the start"))
    handles, _ = ax.get_legend_handles_labels()
    fig.legend(handles=key + handles, loc="outside lower center", ncols=4, fontsize=8, frameon=False)
    return fig


def plot_paired_efficiency(path: Path, table: dict[tuple[str, str], dict[tuple, float]], baseline: str, order: Sequence[str] = ()) -> None:
    """One panel per method (in ``order``, the run's, where given), each scene's efficiency (m2/step) against the
    baseline's on the same scene, coloured and marked by scale (an ordered scale of its own, viridis, not the
    methods' colours of the other figures); points above the diagonal are scenes the method explored more
    efficiently."""
    from cso_runtime.scenes import SCALES  # noqa: PLC0415  (keeps this module's import light)

    plt = pyplot()
    scale_colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(SCALES)))  # 0.85: no pale yellow on white
    shown = {m for m, _ in table if m != baseline}
    methods = [m for m in dict.fromkeys(order) if m in shown] + sorted(shown - set(order))
    # Square panels, laid out with their titles: at 4.2 in high, a row of square panels was limited by the height and
    # the layout pushed the titles off the top edge (tight_layout then set_aspect cut them too); 4.6 in leaves the room.
    fig, axes = plt.subplots(1, len(methods), figsize=(4.2 * len(methods), 4.6), squeeze=False, layout="constrained")
    for ax, method in zip(axes[0], methods):
        top = 0.0
        for scale in SCALES:
            mine, base = table.get((method, scale), {}), table.get((baseline, scale), {})
            scenes = sorted(set(mine) & set(base))
            if not scenes:
                continue
            x, y = np.array([base[s] for s in scenes]), np.array([mine[s] for s in scenes])
            k = SCALES.index(scale)  # one colour and marker per scale in every panel
            ax.scatter(x, y, s=16, alpha=0.8, label=f"{scale} ({len(scenes)})", color=scale_colours[k], marker=MARKERS[k])
            top = max(top, float(x.max()), float(y.max()))
        top = top or 1.0  # no shared scene: an empty panel
        ax.plot([0, top * 1.05], [0, top * 1.05], color="grey", lw=1, ls="--")
        ax.set_xlim(0, top * 1.05)
        ax.set_ylim(0, top * 1.05)
        ax.set_box_aspect(1)  # a square panel, as its x and y limits are the same: one unit as long on either axis
        ax.set_xlabel(f"{baseline}, m2/step")
        ax.set_ylabel(f"{method}, m2/step")
        ax.set_title(f"{method} against {baseline}")
        ax.grid(alpha=0.3)
        if ax.collections:
            ax.legend(loc="lower right", fontsize=8)
    _save(fig, path, 110)


def plot_efficiency_by_scale(path: Path, summary: dict[str, Any]) -> None:
    """``efficiency_figure`` written as a PNG."""
    _save(efficiency_figure(summary), path, 110)


def efficiency_figure(summary: dict[str, Any]) -> Any:
    """Like the paper's Fig. 5, from an ``eval`` summary: each method's mean efficiency (m2/step) per scene
    scale (top), and below, when the baseline ran, each method's per-scene change against it with its 95 %
    bootstrap interval (``summary["paired"]``: the same figures as paired.csv)."""
    from cso_runtime.scenes import SCALES  # noqa: PLC0415  (keeps this module's import light)

    plt = pyplot()
    methods = list(summary["methods"])
    scales = [sc for sc in SCALES if any(sc in summary["methods"][m]["by_scale"] for m in methods)]
    comparisons = summary["paired"]["comparisons"]
    baseline = summary["paired"]["baseline"]
    rows = 2 if comparisons else 1
    fig, axes = plt.subplots(rows, 1, figsize=(max(5.0, 1.2 + 0.9 * len(scales) * max(len(methods), 1) ** 0.5), 3.2 * rows), squeeze=False, layout="constrained")
    x = np.arange(len(scales))
    width = 0.8 / max(len(methods), 1)

    def offset(i: int) -> float:
        """Method i's place within its scale's group, the same in both panels."""
        return (i - (len(methods) - 1) / 2) * width

    top = axes[0][0]
    for i, method in enumerate(methods):
        by_scale = summary["methods"][method]["by_scale"]
        at = [j for j, sc in enumerate(scales) if by_scale.get(sc, {}).get("efficiency_m2_per_step") is not None]
        heights = [by_scale[scales[j]]["efficiency_m2_per_step"] for j in at]
        style = method_style(i)
        top.bar(np.array(at, dtype=float) + offset(i), heights, width, label=method, color=style["color"], hatch=style["hatch"], edgecolor="white")
        for j, sc in enumerate(scales):  # episodes, but none with a step (the first scan saw everything): no m2/step to draw
            if j not in at and sc in by_scale:
                top.text(j + offset(i), 0.0, "no step", rotation=90, ha="center", va="bottom", fontsize=8, color=style["color"])
    top.set_xticks(x, [sc.replace("_", " ") for sc in scales])
    top.set_ylabel("efficiency (m2/step)")
    top.set_ylim(bottom=0.0)
    top.set_title("Exploration efficiency per scene scale")
    top.set_xlim(-0.5, len(scales) - 0.5)
    top.grid(axis="y", alpha=0.3)
    top.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    if comparisons:
        bottom = axes[1][0]
        for i, method in enumerate(methods):
            found = {c["scale"]: c for c in comparisons if c["method"] == method}
            at = [j for j, sc in enumerate(scales) if sc in found]
            mid = np.array([found[scales[j]]["per_scene_pct"] for j in at])
            low = mid - np.array([found[scales[j]]["ci_low_pct"] for j in at])
            high = np.array([found[scales[j]]["ci_high_pct"] for j in at]) - mid
            if at:
                style = method_style(i)
                bottom.errorbar(np.array(at, dtype=float) + offset(i), mid, yerr=[low, high], fmt=style["marker"], capsize=3, label=method, color=style["color"])
        bottom.axhline(0.0, color="grey", lw=1)
        bottom.set_xticks(x, [sc.replace("_", " ") for sc in scales])
        bottom.set_xlim(-0.5, len(scales) - 0.5)
        bottom.set_ylabel(f"per-scene change\nagainst {baseline} (%)")
        bottom.set_title(f"Efficiency against {baseline}, scene by scene (95 % CI)", fontsize=10)
        bottom.grid(axis="y", alpha=0.3)
        if bottom.containers:  # each method's marker, as the bars' key above gives its hatch
            bottom.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig

