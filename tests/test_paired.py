"""benchmarks/paired.py: the per-scene comparison BENCHMARKS.md's tables come from."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest

FIELDS = ("method", "map", "scale", "seed", "traversable_area_m2", "efficiency_m2_per_step")


def load_paired():
    spec = importlib.util.spec_from_file_location("paired", Path(__file__).parents[1] / "benchmarks" / "paired.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write(path: Path, rows: list[tuple]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(FIELDS)
        w.writerows(rows)
    return path


def test_pairs_each_method_with_the_baseline_scene_by_scene(tmp_path, capsys):
    """Ratio of means, mean per-scene ratio and scenes won; a later file's method overrides per scene within
    its label, and scenes with the same name under different labels stay apart."""
    base = write(tmp_path / "base.csv", [("greedy-dist", m, "large", 0, 100, 1.0) for m in ("a", "b", "c", "d")] + [("cso", m, "large", 0, 100, 0.1) for m in ("a", "b", "c", "d")])
    cso = write(tmp_path / "cso.csv", [("cso", "a", "large", 0, 100, 1.2), ("cso", "b", "large", 0, 100, 1.2), ("cso", "c", "large", 0, 100, 0.9), ("cso", "d", "large", 0, 100, 0.9)])
    other = write(tmp_path / "other.csv", [("greedy-dist", "a", "large", 0, 100, 2.0), ("cso", "a", "large", 0, 100, 2.0)] * 1 + [("greedy-dist", m, "large", 0, 100, 1.0) for m in ("x", "y")] + [("cso", m, "large", 0, 100, 1.0) for m in ("x", "y")])
    paired = load_paired()
    assert paired.main([f"set1={base}", f"set1={cso}", f"set2={other}"]) == 0
    row = [line for line in capsys.readouterr().out.splitlines() if "| cso |" in line]
    # set1: 1.2, 1.2, 0.9, 0.9 against 1.0 each; set2: three scenes level (one of them named "a" too, 2.0 vs 2.0).
    # Means 8.2/7 against 8/7: +2.5 %; per-scene ratios 7.2/7: +2.9 %, with a bootstrap interval around it.
    assert len(row) == 1
    cells = [c.strip() for c in row[0].strip("|").split("|")]
    assert cells[:4] == ["large", "cso", "7", "+2.5 %"] and cells[5] == "2 of 7 (2 lost)"  # three level
    mean, interval = cells[4].split(" % [")
    lo, hi = (float(v) for v in interval.rstrip("]").split(","))
    assert mean == "+2.9" and lo < 2.9 < hi and lo > -20 and hi < 20
    # The geometric mean of the same ratios, last: exp(mean(log r)) - 1 = (1.2^2 * 0.9^2)^(1/7) - 1 = +2.2 %.
    assert cells[6].startswith("+2.2 % [")


def test_a_missing_file_is_a_clear_error(tmp_path, capsys):
    paired = load_paired()
    with pytest.raises(SystemExit) as exc:
        paired.main([f"easy={tmp_path / 'nope.csv'}"])
    assert exc.value.code == 2 and "no such file" in capsys.readouterr().err


def test_rename_sets_two_runs_of_one_method_side_by_side(tmp_path, capsys):
    """``--rename FILE:METHOD=NEW``, as ``cso-runtime compare``: one file's cso compared as another method."""
    base = [("greedy-dist", m, "large", 0, 100, 1.0) for m in ("a", "b", "c")]
    shipped = write(tmp_path / "shipped.csv", base + [("cso", m, "large", 0, 100, 1.2) for m in ("a", "b", "c")])
    mine = write(tmp_path / "mine.csv", base + [("cso", m, "large", 0, 100, 0.9) for m in ("a", "b", "c")])
    paired = load_paired()
    assert paired.main([str(shipped), str(mine), "--rename", f"{mine}:cso=cso-mine"]) == 0
    out = capsys.readouterr()
    assert "| large | cso | 3 | +20.0 % |" in out.out and "| large | cso-mine | 3 | -10.0 % |" in out.out and out.err == ""
    with pytest.raises(SystemExit) as exc:
        paired.main([str(shipped), "--rename", f"{mine}:cso=cso-mine"])
    assert exc.value.code == 2 and "is not one of the files compared" in capsys.readouterr().err
