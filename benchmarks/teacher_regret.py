"""Can a network learn the rollout teacher's choices from the map? Offline, on saved teacher data.

    cso-runtime collect-teacher --out T.npz ...        # the rollout teacher's decisions, with every try's outcome
    python benchmarks/teacher_regret.py --train A.npz,B.npz --val C.npz [--soft-steps 3] [--hidden 64 --layers 3]

At each rollout-teacher decision with at least two tries, each tried cluster has an outcome: the control steps
after which greedy-dist finished the episode from it. A chooser's **regret** at that decision is its cluster's
outcome minus the best try's (0 = as good as the rollout). This script fits the cso network to the teacher data
of ``--train`` with the warm start of ``cso-runtime train`` (``ppo.warm_start``: hard labels, or soft targets from
the outcomes), then reports, on the training rows and on the held-out ``--val`` rows, the mean regret of

* ``nearest``: greedy-dist's choice (the nearest tried cluster),
* ``shipped cso``: the shipped weights,
* ``fitted``: the network just fitted,

over the decisions where the chooser picked a tried cluster (an untried one has no outcome; the share is shown).
A chooser that learned something the map shows beats ``nearest`` on the held-out rows; one that only memorised
the training rows beats it there alone. Summed over an episode's decisions, regret is what the rollout gains.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from cso_runtime.learned.graph import NODE_FEATURES
from cso_runtime.learned.ppo import Args, TeacherData, build_model, obs_to_torch, warm_start
from cso_runtime.learned.registry import load_checkpoint, weights_path

GEODESIC_COLUMN = NODE_FEATURES.index("geodesic")
"""Column of the node feature ``geodesic`` (log of the geodesic distance): orders clusters by distance."""


def choices(model: torch.nn.Module, data: TeacherData) -> np.ndarray:
    """The network's greedy (argmax) cluster at every row, under the row's mask."""
    with torch.no_grad():
        logits = model.masked_logits(obs_to_torch(data.graphs, torch.device("cpu")), torch.as_tensor(data.masks))
    return logits.argmax(-1).numpy()


def regret(data: TeacherData, chosen: np.ndarray) -> dict[str, float]:
    """Mean regret (control steps) of ``chosen`` over the rows with two or more tries, and the share of those
    rows where ``chosen`` was tried at all."""
    steps = data.outcome_steps
    tried = np.isfinite(steps)
    rows = np.flatnonzero(tried.sum(1) >= 2)
    best = np.where(tried, steps, np.inf).min(1)[rows]
    hit = tried[rows, chosen[rows]]
    return {
        "decisions": int(len(rows)),
        "tried_share": float(hit.mean()),
        "regret_steps": float((steps[rows, chosen[rows]][hit] - best[hit]).mean()),
        "agrees_with_teacher": float((chosen[rows] == data.actions[rows]).mean()),
    }


def nearest(data: TeacherData) -> np.ndarray:
    """Greedy-dist's choice among the tries: the tried cluster of least geodesic distance."""
    geodesic = data.graphs["nodes"][:, : data.outcome_steps.shape[1], GEODESIC_COLUMN]
    return np.where(np.isfinite(data.outcome_steps), geodesic, np.inf).argmin(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", required=True, help="comma-separated teacher-data files to fit")
    ap.add_argument("--val", required=True, help="comma-separated held-out teacher-data files")
    ap.add_argument("--soft-steps", type=float, default=0.0, help="soft-target temperature (0 = the teacher's choice alone)")
    ap.add_argument("--epochs", type=int, default=15)
    ap.add_argument("--minibatches", type=int, default=4)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--hidden", type=int, default=32)
    ap.add_argument("--layers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="write the results here")
    opts = ap.parse_args()

    torch.manual_seed(opts.seed)
    torch.set_num_threads(1)
    train, val = TeacherData.load(opts.train.split(",")), TeacherData.load(opts.val.split(","))
    args = Args(hidden=opts.hidden, layers=opts.layers, warm_start_soft_steps=opts.soft_steps, warm_start_epochs=opts.epochs,
                num_minibatches=opts.minibatches, warm_start_lr=opts.lr)
    model = build_model(args, torch.device("cpu"))
    t0 = time.time()
    fit = warm_start(model, train, args, torch.device("cpu"), lambda _m: None)
    model.eval()
    shipped, _, _ = load_checkpoint(weights_path("cso"))
    result: dict = {"options": vars(opts), "fit": fit, "fit_s": round(time.time() - t0, 1), "train": {}, "val": {}}
    for split, data in (("train", train), ("val", val)):
        for name, chosen in (("nearest", nearest(data)), ("shipped cso", choices(shipped, data)), ("fitted", choices(model, data))):
            result[split][name] = regret(data, chosen)
    print(f"fitted on {len(train)} decisions ({result['fit_s']} s), held out {len(val)}; regret = steps lost against the best try")
    print(f"{'rows':<6} {'chooser':<12} {'decisions':>9} {'tried %':>8} {'regret steps':>13} {'= teacher %':>12}")
    for split in ("train", "val"):
        for name, r in result[split].items():
            print(f"{split:<6} {name:<12} {r['decisions']:>9} {100 * r['tried_share']:>8.1f} {r['regret_steps']:>13.2f} {100 * r['agrees_with_teacher']:>12.1f}")
    if opts.json:
        with open(opts.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
