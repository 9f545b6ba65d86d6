"""Figures like the paper's: coverage against step (Fig. 4) and explored map with path (Fig. 6)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np


def _pyplot():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def plot_coverage_curves(path: Path, outcomes: Sequence[Any]) -> None:
    """Mean coverage (%) against step per method; each episode's curve is held at its final value."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    methods: dict[str, list[np.ndarray]] = {}
    for o in outcomes:
        methods.setdefault(o.method, []).append(np.asarray(o.coverage_curve_pct))
    for method, curves in methods.items():
        n = max(len(c) for c in curves)
        padded = np.stack([np.pad(c, (0, n - len(c)), mode="edge") for c in curves])
        ax.plot(np.arange(n), padded.mean(axis=0), label=f"{method} ({len(curves)} ep.)")
    ax.set_xlabel("step (0.25 s)")
    ax.set_ylabel("coverage (%)")
    ax.set_ylim(0, 101)
    ax.grid(alpha=0.3)
    if methods:
        ax.legend(loc="lower right")
    ax.set_title("Coverage against step")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_trajectories(path: Path, name: str, outcomes: Sequence[Any]) -> None:
    """One panel per method: ground truth (grey), explored free space (light blue), path (red)."""
    plt = _pyplot()
    n = len(outcomes)
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4), squeeze=False)
    for ax, o in zip(axes[0], outcomes):
        free = np.asarray(o.free, dtype=bool)
        h, w = free.shape
        res = o.resolution_m
        img = np.ones((h, w, 3))
        img[free] = (0.75, 0.75, 0.75)
        img[~free] = (0.25, 0.25, 0.25)
        img[np.asarray(o.explored, dtype=bool)] = (0.62, 0.82, 0.98)
        ax.imshow(img, origin="lower", extent=(0, w * res, 0, h * res), interpolation="nearest")
        traj = np.asarray(o.trajectory_xy_m)
        if len(traj):
            ax.plot(traj[:, 0], traj[:, 1], color="red", lw=1.0)
            ax.plot(traj[0, 0], traj[0, 1], "o", color="green", ms=5)
            ax.plot(traj[-1, 0], traj[-1, 1], "s", color="red", ms=5)
        r = o.row
        ax.set_title(f"{o.method}: {r['coverage_pct']:.1f}% in {r['steps']} steps", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
