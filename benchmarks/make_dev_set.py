"""A development set for choosing training recipes: Dungeon ``train`` plans that training does not use.

Picking a recipe by its score on the validation plans (``easy``, ``medium``, ``complex``) would be
selection on the test set. This script links ``--count`` plans of ``dungeon_dir`` that are not in the
training subset of ``--config`` (the seeded ``dungeon_plans`` that ``cso-runtime train`` draws) into
``--out``, so that candidates are compared there first:

    python benchmarks/make_dev_set.py --config configs/train.yaml --out runs/dev/plans
    cso-runtime eval --method greedy-dist,cso --lidar-fov 360 --maps runs/dev/plans --m-per-px 0.05 --out runs/dev/base_0.05

The chosen names are also written to ``OUT.txt`` (the folder's name plus ``.txt``).
"""

from __future__ import annotations

import argparse
import random
from pathlib import Path

from cso_runtime.config import from_dict, load_yaml
from cso_runtime.learned.ppo import Args, training_scene_refs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/train.yaml", help="training config whose Dungeon subset is left out")
    parser.add_argument("--out", default="runs/dev/plans", help="folder to fill with links to the chosen plans")
    parser.add_argument("--count", type=int, default=100, help="plans in the set")
    parser.add_argument("--seed", type=int, default=2026, help="seed of the draw among the unused plans")
    opts = parser.parse_args()

    args = from_dict(Args, {**load_yaml(opts.config), "generated": []}, "train")
    folder = Path(args.dungeon_dir).resolve()
    used = {Path(r.path).name for r in training_scene_refs(args)}
    unused = sorted(p.name for p in folder.glob("*.png") if p.name not in used)
    if len(unused) < opts.count:
        parser.error(f"only {len(unused)} plans of {folder} are unused by training, asked for {opts.count}")
    chosen = sorted(random.Random(opts.seed).sample(unused, opts.count))
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in chosen:
        link = out / name
        link.unlink(missing_ok=True)
        link.symlink_to(folder / name)
    out.with_suffix(".txt").write_text("\n".join(chosen) + "\n")
    print(f"{len(chosen)} plans of {folder} ({len(used)} used by training left out) -> {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
