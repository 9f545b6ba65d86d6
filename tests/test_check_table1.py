"""benchmarks/check_table1.py: fresh eval episodes against Table 1's committed ones, episode by episode."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from cso_runtime.evaluation import CSV_FIELDS
from tests.conftest import write_episodes_csv

BENCHMARKS = Path(__file__).parents[1] / "benchmarks"


@pytest.fixture
def check(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))  # it imports tables.py beside it, as when run as a script
    spec = importlib.util.spec_from_file_location("check_table1", BENCHMARKS / "check_table1.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def episode(method: str, map_: str, steps: int, explored: float = 100.0, coverage: float = 99.5) -> dict:
    return {
        "method": method,
        "map": map_,
        "scale": "large",
        "seed": 0,
        "explored_area_m2": explored,
        "coverage_pct": coverage,
        "steps": steps,
        "efficiency_m2_per_step": round(explored / steps, 6),
        "path_length_m": steps / 10,
        "decision_ms_p50": 10.0,
        "decision_ms_p99": 20.0,
        "terminated_by": "coverage",
        "traversable_area_m2": 101.0,
        "decisions": 10,
        "wall_s": 1.0,
    }


def folder(path: Path, rows: list[dict]) -> Path:
    path.mkdir()
    write_episodes_csv(path / "episodes.csv", rows, CSV_FIELDS)
    return path


def test_same_episodes_exit_0_and_a_later_committed_file_replaces_an_earlier_one(tmp_path, check, capsys):
    """The committed files pool as Table 1's: the second file's cso (the 1.5 m bound) is the one compared; decision times
    and wall time, which differ between sessions, do not count."""
    old = folder(tmp_path / "old", [episode("greedy-dist", "img_1", 100), episode("cso", "img_1", 120)])
    far15 = folder(tmp_path / "far15", [episode("cso", "img_1", 80)])
    fresh_rows = [episode("greedy-dist", "img_1", 100), episode("cso", "img_1", 80)]
    fresh_rows[1]["decision_ms_p50"] = fresh_rows[1]["wall_s"] = 33.0
    fresh = folder(tmp_path / "fresh", fresh_rows)
    assert check.main([f"easy_0.05={fresh}", "--committed", f"easy_0.05={old}", "--committed", f"easy_0.05={far15}"]) == 0
    out = capsys.readouterr().out
    assert "all 2 fresh episodes are the committed ones" in out
    assert "| cso | all | 1 | +25.00 % | +25.00 % |" in out  # 1.25 m2/step against 1.0


def test_a_differing_or_unmatched_episode_is_named_and_exits_1(tmp_path, check, capsys):
    committed = folder(
        tmp_path / "committed", [episode("greedy-dist", "img_1", 100), episode("cso", "img_1", 100), episode("cso", "img_2", 50)]
    )
    fresh = folder(
        tmp_path / "fresh",
        [episode("greedy-dist", "img_1", 100), episode("cso", "img_1", 80, coverage=99.1), episode("cso", "img_3", 50)],
    )
    assert check.main([f"easy_0.05={fresh}", "--committed", f"easy_0.05={committed}"]) == 1
    out = capsys.readouterr().out
    assert "cso easy_0.05/img_1 seed 0: steps 100 -> 80, coverage_pct 99.5 -> 99.1, path_length_m 10 -> 8" in out
    assert "cso easy_0.05/img_3 seed 0: no committed episode" in out
    assert "| cso | 1 (1 without a committed episode) | 0 | +25.00 % / +25.00 % | -20.00 % |" in out
    assert "| cso | all | 1 | +0.00 % | +25.00 % |" in out
    assert "2 of 3 fresh episodes are not the committed ones" in out


def test_labels_must_match_across_files(tmp_path, check, capsys):
    """A plan of another set (medium/img_1 against easy/img_1) is not the same plan."""
    committed = folder(tmp_path / "committed", [episode("cso", "img_1", 100)])
    fresh = folder(tmp_path / "fresh", [episode("cso", "img_1", 100)])
    assert check.main([f"medium_0.05={fresh}", "--committed", f"easy_0.05={committed}"]) == 1
    assert "cso medium_0.05/img_1 seed 0: no committed episode" in capsys.readouterr().out


def test_table1_files_follow_benchmarks_md(check, tmp_path):
    for f in (
        "easy_360",
        "validation_all/easy_0.1",
        "validation_all/far15_easy_0.1",
        "far15_default/validation/cso-vdm_easy_0.1",
        "gen_middle_360",
    ):
        (tmp_path / f).mkdir(parents=True)
        (tmp_path / f / "episodes.csv").write_text("method\n")
    assert [p.parent.relative_to(tmp_path).as_posix() for p in check.table1_files("easy_0.1", tmp_path)] == [
        "easy_360",
        "validation_all/easy_0.1",
        "validation_all/far15_easy_0.1",
        "far15_default/validation/cso-vdm_easy_0.1",
    ]
    assert [p.parent.name for p in check.table1_files("middle", tmp_path)] == ["gen_middle_360"]
    with pytest.raises(ValueError, match="no Table 1 files for label 'hard_0.05'"):
        check.table1_files("hard_0.05", tmp_path)


def test_the_committed_table1_files_exist_for_every_label(check):
    """Every label names committed files: Table 1's folders are where the script looks."""
    for label in ("small", "middle", *(f"{s}_{m}" for s in check.SETS for m in check.SCALES_M)):
        assert check.table1_files(label), label
