"""benchmarks/make_dev_set.py: the plans for choosing a recipe are never plans that training uses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from cso_runtime.learned.ppo import Args, training_scene_refs

ROOT = Path(__file__).parents[1]


def test_dev_set_leaves_out_the_training_subset_and_is_reproducible(tmp_path):
    plans = tmp_path / "train"
    plans.mkdir()
    for i in range(12):
        (plans / f"{i}.png").write_bytes(b"not read")
    config = tmp_path / "train.yaml"
    config.write_text(f"seed: 3\ndungeon_dir: {plans}\ndungeon_plans: 5\ndungeon_m_per_px: [0.1]\n")
    used = {Path(r.path).name for r in training_scene_refs(Args(seed=3, dungeon_dir=str(plans), dungeon_plans=5, dungeon_m_per_px=[0.1], generated=[]))}
    assert len(used) == 5

    def run(out: Path, count: int) -> subprocess.CompletedProcess:
        cmd = [sys.executable, str(ROOT / "benchmarks" / "make_dev_set.py"), "--config", str(config), "--out", str(out), "--count", str(count)]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)

    first = run(tmp_path / "dev", 6)
    assert first.returncode == 0, first.stderr
    chosen = sorted(p.name for p in (tmp_path / "dev").iterdir())
    assert len(chosen) == 6 and not set(chosen) & used
    assert all((tmp_path / "dev" / n).resolve() == (plans / n).resolve() for n in chosen)
    assert (tmp_path / "dev.txt").read_text().split() == chosen
    assert run(tmp_path / "again", 6).returncode == 0
    assert (tmp_path / "again.txt").read_text() == (tmp_path / "dev.txt").read_text()
    too_many = run(tmp_path / "x", 8)  # only 7 unused
    assert too_many.returncode == 2 and "only 7 plans" in too_many.stderr
