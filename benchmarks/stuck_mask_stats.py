"""How often Algorithm 1's stuck test fires in `cso` episodes, and how often its moving length is read
straight-line because the previous decision position is off the distance map D (inside the inflation band).

    python benchmarks/stuck_mask_stats.py --maps runs/dev/plans --m-per-px 0.05 --limit 20 [--weights DIR_OR_FILE] [--set masks.stuck_avoid=goals]

Runs ``cso-runtime eval`` in this process (one worker; its outputs go to --out) with ``ActionMasker.mask``
wrapped to count, and prints one JSON line: decisions, decisions with a stuck history (three decisions known),
stuck decisions, and moves measured off D.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from cso_runtime import policies
from cso_runtime.cli import parse_settings
from cso_runtime.evaluation import EvalRequest, run_eval
from cso_runtime.learned.weights import use_weights


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", required=True)
    p.add_argument("--m-per-px", type=float, default=0.1)
    p.add_argument("--limit", type=int, default=None)
    p.add_argument("--lidar-fov", type=float, default=360.0)
    p.add_argument(
        "--weights", type=Path, default=None,
        help="As eval --weights: a training run's folder holding cso.pt (or cso@fov<deg>.pt), or one cso.pt file (default: the shipped weights)",
    )
    p.add_argument("--set", dest="settings", action="append", default=[], help="KEY=VALUE, as eval --set")
    p.add_argument("--out", type=Path, default=Path("runs/stuck_mask_stats"))
    args = p.parse_args(argv)
    if args.weights is not None:  # the one resolver of eval and up: a folder or a file, checked before anything runs
        try:
            use_weights(args.weights)
        except ValueError as exc:
            p.error(str(exc))

    counts = {"decisions": 0, "with_three_decisions": 0, "stuck": 0, "moves_off_distance_map": 0}
    mask = policies.ActionMasker.mask

    def counted(self: policies.ActionMasker, obs) -> np.ndarray:
        counts["decisions"] += 1
        if self.stuck.history:
            last = self.stuck.history[-1].position_xy_m
            counts["moves_off_distance_map"] += int(not np.isfinite(obs.distance_at(np.array([last]))[0]))
        allowed = mask(self, obs)
        counts["with_three_decisions"] += int(len(self.stuck.history) == 3)
        counts["stuck"] += int(self.stuck.is_stuck())
        return allowed

    policies.ActionMasker.mask = counted  # type: ignore[method-assign]
    request = EvalRequest(
        methods=["cso"], maps=args.maps, limit=args.limit, out_dir=args.out, m_per_px=args.m_per_px,
        lidar_fov_deg=args.lidar_fov, workers=1, settings=parse_settings(args.settings),
    )
    run_eval(request)
    print(json.dumps({"maps": args.maps, "m_per_px": args.m_per_px, "limit": args.limit, "settings": args.settings, **counts}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
