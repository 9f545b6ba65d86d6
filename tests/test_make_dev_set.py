"""benchmarks/make_dev_set.py: the plans for choosing a recipe are never plans that training uses."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

from cso_runtime.learned.ppo import Args, training_scene_refs

ROOT = Path(__file__).parents[1]
SCRIPT = ROOT / "benchmarks" / "make_dev_set.py"


def test_dev_set_leaves_out_the_training_subset_and_is_reproducible(tmp_path, monkeypatch, capsys):
    plans = tmp_path / "train"
    plans.mkdir()
    for i in range(12):
        (plans / f"{i}.png").write_bytes(b"not read")
    config = tmp_path / "train.yaml"
    config.write_text(f"seed: 3\ndungeon_dir: {plans}\ndungeon_plans: 5\ndungeon_m_per_px: [0.1]\n")
    used = {Path(r.path).name for r in training_scene_refs(Args(seed=3, dungeon_dir=str(plans), dungeon_plans=5, dungeon_m_per_px=[0.1], generated=[]))}
    assert len(used) == 5

    def argv(out: Path, count: int) -> list[str]:
        return [str(SCRIPT), "--config", str(config), "--out", str(out), "--count", str(count)]

    def run_here(out: Path, count: int) -> int:
        """The script run in this process, as ``python SCRIPT`` runs it (a command of its own costs seconds of imports)."""
        monkeypatch.setattr(sys, "argv", argv(out, count))
        try:
            runpy.run_path(str(SCRIPT), run_name="__main__")
        except SystemExit as stop:
            return int(stop.code or 0)
        return 0

    assert run_here(tmp_path / "dev", 6) == 0, capsys.readouterr().err
    chosen = sorted(p.name for p in (tmp_path / "dev").iterdir())
    assert len(chosen) == 6 and not set(chosen) & used
    assert all((tmp_path / "dev" / n).resolve() == (plans / n).resolve() for n in chosen)
    assert (tmp_path / "dev.txt").read_text().split() == chosen
    # Again as its own command (another process, another hash seed): the same plans.
    again = subprocess.run([sys.executable, *argv(tmp_path / "again", 6)], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "again.txt").read_text() == (tmp_path / "dev.txt").read_text()
    capsys.readouterr()
    assert run_here(tmp_path / "x", 8) == 2  # only 7 unused
    assert "only 7 plans" in capsys.readouterr().err
