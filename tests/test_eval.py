"""Episodes end to end and the ``cso-runtime eval`` outputs."""

from __future__ import annotations

import csv
import dataclasses
import functools
import html
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cso_runtime
from cso_runtime.config import ConfigError, EpisodeConfig, ExplorationConfig, SensorConfig, to_dict
from cso_runtime.episode import GroundTruthMetrics, run_episode
from cso_runtime.evaluation import (
    CSV_FIELDS,
    METRICS,
    WORKER_DIED,
    EpisodeJob,
    EvalRequest,
    plan_eval,
    run_eval,
    run_in_processes,
    run_job,
)
from cso_runtime.map_files import load_map
from cso_runtime.policies import make_policy
from cso_runtime.scenes import builtin_scene_dir, load_floor_plan, resolve_scenes
from cso_runtime.simulator import KinematicSimulator
from tests.conftest import TerminalFile, super_large_summary, two_rooms, unset_weights_env


def test_greedy_dist_explores_two_rooms_completely():
    plan = two_rooms()
    cfg = ExplorationConfig(sensor=SensorConfig.preset("lidar", fov_deg=180))
    result = run_episode(KinematicSimulator(plan, cfg.sensor, cfg.robot), make_policy("greedy-dist"), cfg, seed=0)
    assert result.terminated_by in ("coverage", "no_frontier")
    assert result.coverage_pct > 97.0
    assert result.steps < 400
    assert len(result.coverage_curve_pct) == result.steps + 1
    assert np.all(np.diff(result.coverage_curve_pct) >= -1e-9)  # coverage never goes down
    assert result.trajectory_xy_m.shape == (result.steps + 1, 2)
    assert result.decision_ms and result.efficiency_m2_per_step > 0


def test_greedy_dist_covers_a_dungeon_plan_with_360_lidar():
    plan = load_floor_plan(builtin_scene_dir() / "img_2.png", 0.1)
    cfg = ExplorationConfig(sensor=SensorConfig.preset("lidar", fov_deg=360))
    result = run_episode(KinematicSimulator(plan, cfg.sensor, cfg.robot), make_policy("greedy-dist"), cfg, seed=0)
    assert result.terminated_by == "coverage"
    assert result.coverage_pct > 99.0
    assert result.traversable_area_m2 - result.explored_area_m2 < 1.0


def test_an_episode_ends_when_both_coverage_thresholds_hold():
    """Section 4.1: coverage above ``done_coverage_pct`` and less than ``done_unexplored_m2`` left."""
    plan = two_rooms()
    metrics = GroundTruthMetrics(plan, EpisodeConfig(done_coverage_pct=95.0, done_unexplored_m2=0.5))
    total = metrics.region_area_m2
    assert metrics.coverage_pct_of(total / 2) == pytest.approx(50.0)
    assert not metrics.done_at(0.95 * total)  # 95 % is not above 95 %, and 0.9 m2 are left
    assert not metrics.done_at(total - 0.6)  # above 96 %, but 0.6 m2 are left
    assert metrics.done_at(total - 0.4)
    every_cell = GroundTruthMetrics(plan, EpisodeConfig(done_coverage_pct=100.0, done_unexplored_m2=0.5))
    assert every_cell.done_at(total) and not every_cell.done_at(total - 0.01)  # 100 %: only everything, and then it is the end


def test_an_episode_of_no_step_has_no_efficiency_not_its_area_per_step(tmp_path: Path):
    """A 1 m2 room that the first 360-degree scan sees whole ends by coverage in 0 steps: m2/step is undefined
    there (an empty cell of episodes.csv, as every missing value there: not ``nan``, which csv readers take for a
    number), and it stays out of the mean instead of counting as its area over one step."""
    from PIL import Image

    from cso_runtime.scenes import FREE_RGB, START_RGB, WALL_RGB

    px = np.empty((14, 14, 3), dtype=np.uint8)
    px[:] = WALL_RGB
    px[2:12, 2:12] = FREE_RGB
    px[6:8, 6:8] = START_RGB
    plans = tmp_path / "plans"
    plans.mkdir()
    Image.fromarray(px, "RGB").save(plans / "cupboard.png")
    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=tmp_path / "out", lidar_fov_deg=360.0))
    (row,) = csv.DictReader((tmp_path / "out" / "episodes.csv").open())
    assert row["steps"] == "0" and row["terminated_by"] == "coverage" and float(row["coverage_pct"]) == 100.0
    assert row["efficiency_m2_per_step"] == "" and row["decision_ms_p50"] == row["decision_ms_p99"] == ""  # no decision either
    assert "nan" not in (tmp_path / "out" / "episodes.csv").read_text().lower()
    # No simulated time passed: its pace is missing, not 0.0 (which reads as infinitely slow).
    assert row["sim_time_s"] == "0.0" and row["real_time_factor"] == "" and summary["methods"]["greedy-dist"]["real_time_factor"] is None
    assert summary["methods"]["greedy-dist"]["efficiency_m2_per_step"] is None
    assert summary["methods"]["greedy-dist"]["episodes"] == 1 and summary["methods"]["greedy-dist"]["efficiency_episodes"] == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["methods"]["greedy-dist"]["explored_area_m2"] == pytest.approx(1.0)
    # The npz's metric row is strict JSON (null, not NaN), and --resume reads it back to the same tables.
    with np.load(tmp_path / "out" / "episodes" / "greedy-dist" / "cupboard.npz") as data:
        stored = json.loads(str(data["metrics"]), parse_constant=lambda name: pytest.fail(f"{name} in the npz's metrics"))
    assert stored["efficiency_m2_per_step"] is None and stored["decision_ms_p50"] is None and stored["steps"] == 0
    csv_before = (tmp_path / "out" / "episodes.csv").read_text()
    resumed = run_eval(EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=tmp_path / "out", lidar_fov_deg=360.0, resume=True))
    assert resumed["meta"]["resumed_episodes"] == 1 and resumed["methods"] == summary["methods"]
    assert (tmp_path / "out" / "episodes.csv").read_text() == csv_before


def test_episodes_csv_says_the_sensor_simulator_and_cell_size_each_episode_ran_with(tmp_path: Path):
    """episodes.csv had no column of the sensor: a 360-degree LiDAR's eval and a 180-degree one's read the same, and
    ``compare`` pooled them without a word. Its last columns now say each episode's setup (``SETUP_COLUMNS``), which
    ``compare`` checks (``mixed_setups_said``); an eval --resume into the other sensor's folder was already refused."""
    from cso_runtime.comparison import SETUP_COLUMNS, mixed_setups_said

    assert CSV_FIELDS[-len(SETUP_COLUMNS) :] == SETUP_COLUMNS == ("sensor_fov_deg", "sim", "cell_size_m", "max_steps")
    ring, front = tmp_path / "ring", tmp_path / "front"
    run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=ring, max_steps=4, lidar_fov_deg=360.0))
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=front, max_steps=4))
    with (ring / "episodes.csv").open(newline="") as fh:
        (row,) = csv.DictReader(fh)
    assert (row["sensor_fov_deg"], row["sim"], row["cell_size_m"], row["max_steps"]) == ("360.0", "2d", "0.05", "4")
    (said,) = mixed_setups_said([("", front / "episodes.csv"), ("", ring / "episodes.csv")])
    assert said.startswith(f"warning: the same plans ran with different sensor_fov_deg: 180 ({front / 'episodes.csv'}), 360 ({ring / 'episodes.csv'}) on 1 plan (gen_small_0)"), said
    with pytest.raises(ConfigError, match="differs in sensor.fov_deg: 360.0 there, 180.0 here"):
        run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=ring, max_steps=4, resume=True))


def _corridor_scene(folder: Path, name: str, start: str) -> Path:
    """The corridor of tests/test_planner.py (3.0 x 0.9 m at 0.05 m cells) as a map_server scene starting at ``start``."""
    from cso_runtime.geometry import GridGeometry
    from cso_runtime.map_files import save_map

    free = np.zeros((22, 64), dtype=bool)
    free[2:20, 2:62] = True
    scene = save_map(folder / f"{name}.yaml", np.where(free, 0, 100).astype(np.int8), GridGeometry(0.05, free.shape))
    scene.write_text(scene.read_text() + f"start: {start}\n")
    return scene


def test_eval_seeds_runs_several_seeds_in_one_command_and_pools_them_in_one_folder(tmp_path: Path, capsys):
    """The paper's repeated tests took one eval per seed, into 5 ``--out`` folders pooled with ``compare``.
    ``--seeds 0,1`` runs them in one command: each seed's episodes in ``OUT/seed<S>/`` (the folder ``--seed S`` writes,
    every file as it is), and ``OUT``'s episodes.csv (the same columns, the seed in each row), summary.json (means and
    95 % intervals over every seed's episodes, a plan's kept together), paired.csv and report.html pool them;
    ``--resume`` keeps every seed's episodes."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.comparison import bootstrap_mean_ci

    maps = tmp_path / "maps"
    maps.mkdir()
    _corridor_scene(maps, "corridor", "[1.5, 0.18, -0.5]")
    _corridor_scene(maps, "corridor_b", "[1.0, 0.5, 0.0]")
    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out, seeds=[0, 1]))

    def rows(folder: Path) -> list[dict[str, str]]:
        with (folder / "episodes.csv").open(newline="") as fh:
            reader = csv.DictReader(fh)
            assert reader.fieldnames == list(CSV_FIELDS)
            return list(reader)

    each = {seed: rows(out / f"seed{seed}") for seed in (0, 1)}
    for seed, mine in each.items():
        assert {r["seed"] for r in mine} == {str(seed)} and len(mine) == 2
        assert json.loads((out / f"seed{seed}" / "summary.json").read_text())["meta"]["seed"] == seed
        assert (out / f"seed{seed}" / "episodes" / "random" / "corridor.npz").is_file() and (out / f"seed{seed}" / "report.html").is_file()
    pooled = rows(out)
    assert sorted((r["map"], r["seed"]) for r in pooled) == [("corridor", "0"), ("corridor", "1"), ("corridor_b", "0"), ("corridor_b", "1")]
    assert sorted(map(str, pooled)) == sorted(str(r) for mine in each.values() for r in mine)
    entry = summary["methods"]["random"]
    assert entry["episodes"] == 4 and summary["meta"]["seeds"] == [0, 1] and summary["meta"]["seed"] is None
    coverage = [float(r["coverage_pct"]) for r in pooled]
    assert entry["coverage_pct"] == pytest.approx(sum(coverage) / 4, abs=1e-6)
    low, high = bootstrap_mean_ci(np.array(coverage), clusters=[r["map"] for r in pooled])
    assert entry["coverage_pct_ci95"] == [pytest.approx(low, abs=1e-6), pytest.approx(high, abs=1e-6)]
    assert json.loads((out / "summary.json").read_text())["methods"]["random"]["episodes"] == 4
    report = (out / "report.html").read_text()
    assert 'href="seed0/report.html"' in report and 'href="seed1/report.html"' in report

    resumed = run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out, seeds=[0, 1], resume=True))
    assert resumed["meta"]["resumed_episodes"] == 4 and resumed["methods"] == summary["methods"]

    capsys.readouterr()
    common = ["eval", "--method", "random", "--maps", str(maps), "--out", str(tmp_path / "new"), "--dry-run"]
    said = CliRunner().invoke(app, [*common, "--seeds", "0,1", "--seeds", "2"])
    assert said.exit_code == 0, said.output
    assert "would run 6 episode(s), 1 method(s) x 2 scene(s) x 3 seeds" in said.output and "seeds 0, 1, 2" in said.output
    for wrong, why in [(["--seeds", "0,x"], "--seeds: 'x' is not a seed"), (["--seeds", "0,1", "--seed", "3"], "--seed 3 and --seeds: give one")]:
        refused = CliRunner().invoke(app, [*common, *wrong])
        assert refused.exit_code == 2 and why in " ".join(refused.output.split()), refused.output
    one_seed = tmp_path / "one"
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=one_seed, limit=1))
    with pytest.raises(ConfigError, match="holds the episodes of a one-seed eval"):
        run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=one_seed, seeds=[0, 1]))


def test_eval_seeds_of_no_seed_is_refused_not_run_as_seed_0(tmp_path: Path):
    """``--seeds ""`` (an empty shell variable) or ``--seeds ,`` named no seed, and the eval ran as a one-seed eval of
    seed 0 (or of ``--seed``, which it was to refuse beside ``--seeds``), writing its files where ``--seeds`` would have
    pooled: it is refused as a bad ``--seeds``, as ``--seeds 0,x`` is."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    common = ["eval", "--method", "random", "--maps", "generated:small:1:0", "--out", str(tmp_path / "out"), "--dry-run"]
    for given in (["--seeds", ""], ["--seeds", ","], ["--seeds", " ", "--seed", "3"]):
        refused = CliRunner().invoke(app, [*common, *given])
        assert refused.exit_code == 2 and "--seeds: no seed given" in " ".join(refused.output.split()), (given, refused.output)


def test_m_per_px_given_with_only_generated_scenes_is_said_to_change_nothing(tmp_path: Path):
    """``--m-per-px`` scales PNG plans only: ``eval --maps generated:... --m-per-px 0.05`` ran the generated plans at
    their own cell size without a word. A value other than the default is now said to be ignored (dry run and real
    run alike: a plan's warning); with a PNG plan among the scenes, or the default, nothing is said."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    generated = ["eval", "--method", "random", "--maps", "generated:small:1:0", "--out", str(tmp_path / "out"), "--dry-run"]
    said = CliRunner().invoke(app, [*generated, "--m-per-px", "0.05"])
    assert said.exit_code == 0, said.output
    assert "warning: --m-per-px 0.05 is ignored: it scales PNG plans only" in " ".join(said.output.split()), said.output
    assert not any("--m-per-px" in w for w in plan_eval(EvalRequest(methods=["random"], maps="generated:small:1:0", out_dir=tmp_path / "o")).warnings)
    png = plan_eval(EvalRequest(methods=["random"], maps="builtin", limit=1, out_dir=tmp_path / "p", m_per_px=0.05))  # a PNG plan
    assert not any("--m-per-px" in w for w in png.warnings), png.warnings
    maps = tmp_path / "maps"
    maps.mkdir()
    _corridor_scene(maps, "corridor", "[1.5, 0.18, -0.5]")  # a map file: its own resolution too
    own = plan_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=tmp_path / "m", m_per_px=0.2))
    assert any(w.startswith("--m-per-px 0.2 is ignored") for w in own.warnings), own.warnings


def test_a_one_seed_eval_into_the_folder_of_an_eval_of_several_seeds_is_refused(tmp_path: Path):
    """``--seeds`` refuses an ``--out`` that holds a one-seed eval's episodes, but the other way round a one-seed eval
    into the folder of ``--seeds 0,1`` replaced the pooled summary.json and episodes.csv with its own (no warning),
    and left ``OUT/episodes/`` beside the seeds' folders, so ``--seeds 0,1 --resume`` then refused the folder: the
    pooled results were lost and could not be made again there. It is refused before any episode; a seed's own folder,
    and a folder of one's own holding separate ``--seed`` runs' folders, are not."""
    maps = tmp_path / "maps"
    maps.mkdir()
    _corridor_scene(maps, "corridor", "[1.5, 0.18, -0.5]")
    out = tmp_path / "out"
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out, seeds=[0, 1]))
    pooled = (out / "summary.json").read_text(), (out / "episodes.csv").read_text()
    with pytest.raises(ConfigError, match=r"holds the episodes of eval --seeds 0,1 .* give another --out"):
        run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out, seed=1))
    assert ((out / "summary.json").read_text(), (out / "episodes.csv").read_text()) == pooled and not (out / "episodes").exists()
    again = run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out, seeds=[0, 1], resume=True))
    assert again["meta"]["resumed_episodes"] == 2
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=out / "seed1", seed=1, resume=True))  # one seed's folder: as --seed wrote it
    # Planned before the other kind of eval wrote the folder, refused once it holds the folder's lock.
    late = tmp_path / "late"
    one_seed = EvalRequest(methods=["random"], maps=str(maps), out_dir=late)
    planned = plan_eval(one_seed)
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=late, seeds=[0, 1]))
    with pytest.raises(ConfigError, match="holds the episodes of eval --seeds 0,1"):
        run_eval(one_seed, plan=planned)
    assert not (late / "episodes").exists()
    seeds = EvalRequest(methods=["random"], maps=str(maps), out_dir=tmp_path / "late2", seeds=[0, 1])
    planned = plan_eval(seeds)
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=tmp_path / "late2"))
    with pytest.raises(ConfigError, match="holds the episodes of a one-seed eval"):
        run_eval(seeds, plan=planned)
    assert not (tmp_path / "late2" / "seed0").exists()
    mine = tmp_path / "mine"  # the docs' former method: a --seed run per folder, in a folder of one's own
    run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=mine / "seed0"))
    assert run_eval(EvalRequest(methods=["random"], maps=str(maps), out_dir=mine, seed=1))["meta"]["seed"] == 1


def test_evals_files_say_why_an_episode_ended_no_frontier_and_resume_keeps_it(tmp_path: Path, capsys):
    """eval's progress said why an episode ended no_frontier (``EpisodeResult.ended_why``), its files did not: a
    results folder showed "no_frontier" alone. ``episodes.csv``'s last column ``ended_why`` (empty for any other end),
    the npz's metrics and ``summary.json``'s per-method ``ended_why`` now hold it, and ``--resume`` writes the same;
    its progress line of an episode kept from the earlier run says why too, as that of an episode run again (it said
    "no_frontier" alone)."""
    from cso_runtime.evaluation import RichProgress
    maps = tmp_path / "maps"
    maps.mkdir()
    dead_end = _corridor_scene(maps, "dead_end", "[0.5, 0.5, 0.0]")  # 0.4 m of corridor behind the 180-degree LiDAR
    _corridor_scene(maps, "corridor", "[1.5, 0.18, -0.5]")  # explored to the end
    expected = run_episode(KinematicSimulator(resolve_scenes(str(dead_end))[0].load(), seed=0), make_policy("greedy-dist"), ExplorationConfig(), seed=0)
    assert expected.terminated_by == "no_frontier" and "given up around goals reached" in expected.ended_why
    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps=str(maps), out_dir=out))
    assert CSV_FIELDS[CSV_FIELDS.index("real_time_factor") + 1] == "ended_why"  # after every column before it: their order is a contract
    with (out / "episodes.csv").open(newline="") as fh:
        rows = {r["map"]: r for r in csv.DictReader(fh)}
    assert (rows["dead_end"]["terminated_by"], rows["dead_end"]["ended_why"]) == ("no_frontier", expected.ended_why)
    assert (rows["corridor"]["terminated_by"], rows["corridor"]["ended_why"]) == ("coverage", "")
    assert summary["methods"]["greedy-dist"]["ended_why"] == [{"map": "dead_end", "seed": 0, "why": expected.ended_why}]
    assert json.loads((out / "summary.json").read_text())["methods"]["greedy-dist"]["ended_why"] == summary["methods"]["greedy-dist"]["ended_why"]
    with np.load(out / "episodes" / "greedy-dist" / "dead_end.npz") as data:
        assert json.loads(str(data["metrics"]))["ended_why"] == expected.ended_why
    csv_before = (out / "episodes.csv").read_text()
    capsys.readouterr()
    resumed = run_eval(EvalRequest(methods=["greedy-dist"], maps=str(maps), out_dir=out, resume=True), RichProgress())
    assert resumed["meta"]["resumed_episodes"] == 2 and resumed["methods"] == summary["methods"]
    assert (out / "episodes.csv").read_text() == csv_before
    lines = {line.split()[2]: line for line in capsys.readouterr().err.splitlines() if line.startswith("[")}
    assert lines["dead_end:"].endswith(f" steps (no_frontier, kept from the earlier run): {expected.ended_why}"), lines
    assert lines["corridor:"].endswith(" steps (coverage, kept from the earlier run)"), lines


def test_max_steps_terminates():
    plan = load_floor_plan(builtin_scene_dir() / "img_1.png", 0.1)
    cfg = ExplorationConfig()
    cfg.episode.max_steps = 20
    result = run_episode(KinematicSimulator(plan, cfg.sensor, cfg.robot), make_policy("random", seed=1), cfg, seed=1)
    assert result.terminated_by == "max_steps" and result.steps == 20


def test_eval_writes_every_output_and_reports_bad_maps(tmp_path: Path):
    maps = tmp_path / "maps"
    maps.mkdir()
    shutil.copy(builtin_scene_dir() / "img_1.png", maps / "img_1.png")
    (maps / "img_0_corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\nthis is not a png")
    out = tmp_path / "out"
    methods = ["greedy-dist", "greedy-info", "utility", "random"]
    summary = run_eval(EvalRequest(methods=methods, maps=str(maps), out_dir=out, max_steps=60, lidar_fov_deg=360.0))

    assert set(summary["methods"]) == set(methods)
    for m in methods:
        entry = summary["methods"][m]
        assert entry["episodes"] == 1
        assert set(entry["by_scale"]) == {"super_large"}
    assert {f["map"] for f in summary["failures"]} == {"img_0_corrupt"}
    assert len(summary["failures"]) == len(methods)
    assert "img_0_corrupt" in summary["failures"][0]["error"]
    assert json.loads((out / "summary.json").read_text()) == summary

    with (out / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 and tuple(rows[0].keys()) == CSV_FIELDS
    assert all(int(r["steps"]) <= 60 for r in rows)
    # The simulator's pace, in two columns after the others (whose names and order are a contract): simulated
    # seconds from the sim's clock (one 0.25 s control period a step) and those over the episode's wall clock; then
    # why an episode ended no_frontier; then what it ran with (sensor, simulator, cell size, step limit).
    assert CSV_FIELDS[:15] == ("method", "map", "scale", "seed", *METRICS, "terminated_by", "traversable_area_m2", "decisions", "wall_s")
    assert CSV_FIELDS[15:] == ("sim_time_s", "real_time_factor", "ended_why", "sensor_fov_deg", "sim", "cell_size_m", "max_steps")
    for r in rows:
        assert float(r["sim_time_s"]) == pytest.approx(int(r["steps"]) * 0.25)
        assert float(r["real_time_factor"]) == pytest.approx(float(r["sim_time_s"]) / float(r["wall_s"]), rel=0.05, abs=0.5)
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        for k in METRICS:  # one episode each: its metrics are the method's means
            assert summary["methods"][m][k] == pytest.approx(float(mine[0][k]), rel=1e-4), (m, k)
        assert summary["methods"][m]["sim_time_s"] == pytest.approx(float(mine[0]["sim_time_s"]))
        assert summary["methods"][m]["real_time_factor"] == pytest.approx(float(mine[0]["real_time_factor"]), abs=1e-3)

    data = np.load(out / "episodes" / "greedy-dist" / "img_1.npz")
    assert data["explored"].shape == (480, 640) and data["explored"].dtype == bool
    assert data["trajectory"].shape[1] == 2 and len(data["coverage_curve"]) == len(data["trajectory"])
    # explored is in the PNG's own layout (row 0 at the top): explored cells are free pixels there.
    from PIL import Image

    png = np.asarray(Image.open(maps / "img_1.png").convert("RGB"))
    free_px = (png[:, :, 0] > 150)
    assert data["explored"].any() and not (data["explored"] & ~free_px).any()
    assert (out / "coverage_curves.png").stat().st_size > 1000
    assert (out / "efficiency_by_scale.png").stat().st_size > 1000
    assert (out / "trajectories" / "img_1.png").stat().st_size > 1000

    # The robot's own map, as map_server files: free where it saw free space, walls where it saw walls.
    grid, geometry = load_map(out / "maps" / "greedy-dist" / "img_1.yaml")
    assert geometry.shape == (480, 640) and geometry.resolution_m == pytest.approx(0.1)
    assert (out / "maps" / "greedy-dist" / "img_1.png").is_file()
    seen_free = np.flipud(grid == 0)  # in the PNG's layout
    assert seen_free.sum() >= data["explored"].sum() and (grid == 100).any() and (grid == -1).any()
    assert not (seen_free & ~free_px).any()
    assert {p.name for p in (out / "maps").iterdir()} == set(methods)  # no map for the corrupt plan

    # report.html: the same Table 1 rows, the failure, and every figure it shows is a file of the folder.
    import re

    page = (out / "report.html").read_text()
    for m in methods:
        e = summary["methods"][m]
        assert f"<td>{m}</td><td>super_large</td><td>1</td><td>{e['explored_area_m2']:.1f}</td>" in page
        assert f"<td>{e['efficiency_m2_per_step']:.4f}</td>" in page
    assert "img_0_corrupt" in page and "<h2>Failures</h2>" in page
    shown = re.findall(r'<img src="([^"]+)"', page)
    assert {"coverage_curves.png", "efficiency_by_scale.png", "trajectories/img_1.png"} <= set(shown)
    assert all((out / src).is_file() for src in shown)
    # The same folder again with the corrupt plan alone: no episode, so no figure of an earlier run, and none
    # (not even an empty coverage plot) in the report.
    (maps / "img_1.png").unlink()
    again = run_eval(EvalRequest(methods=methods, maps=str(maps), out_dir=out, max_steps=60, lidar_fov_deg=360.0))
    assert not again["methods"][methods[0]]["episodes"]
    assert not (out / "coverage_curves.png").exists() and not (out / "efficiency_by_scale.png").exists()
    assert "coverage_curves.png" not in (out / "report.html").read_text()


def test_eval_cli_runs_and_rejects_bad_arguments(tmp_path: Path):
    """The script runs an eval and ends a failed one with exit 1, in processes of their own; the usage errors (exit 2,
    one line, before anything runs) are the same app's, asked in this process (a process start each cost seconds)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    exe = [sys.executable, "-m", "cso_runtime.cli"]
    ok = subprocess.run(
        exe + ["eval", "--method", "baselines", "--maps", "generated:small:1:3", "--out", str(tmp_path / "o"), "--max-steps", "40"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stderr
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert list(summary["methods"]) == ["greedy-dist", "greedy-info", "utility", "random"]  # the group, expanded

    def usage_error(*args: str) -> str:
        """``eval ARGS``'s stderr, once it ended with exit 2 and no traceback."""
        r = CliRunner().invoke(app, ["eval", *args])
        assert r.exit_code == 2 and not isinstance(r.exception, Exception) and "Traceback" not in r.stderr, (r.exception, r.stderr)
        return r.stderr

    assert "unknown method 'greedy-dsit' (did you mean greedy-dist?)" in usage_error("--method", "greedy-dsit")
    assert "--set expects KEY=VALUE, got 'masks'" in usage_error("--set", "masks")
    assert "nowhere" in usage_error("--maps", str(tmp_path / "nowhere"))
    # `up` names the option --scene; eval takes the same spelling for the same spec.
    assert "elsewhere" in usage_error("--scene", str(tmp_path / "elsewhere"))
    # Messages are text, not rich markup, and never hard-wrapped: a path with brackets comes out whole.
    odd = tmp_path / "plans[red]" / "a_long_folder_name_that_would_wrap_at_eighty_columns"
    assert str(odd) in usage_error("--maps", str(odd))
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0.0, 0.0]\n")
    failed = subprocess.run(exe + ["eval", "--maps", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "f")], capture_output=True, text=True, timeout=60)
    assert failed.returncode == 1 and "origin must be [x_m, y_m, yaw_rad]" in failed.stdout
    below_a_file = tmp_path / "m.yaml" / "out"  # an --out that cannot be made: said before any episode runs
    assert "cannot create the folder" in usage_error("--maps", "generated:small:1:3", "--out", str(below_a_file))


def test_eval_refuses_a_lidar_field_of_view_for_the_depth_camera(tmp_path: Path):
    """``--sensor depth --lidar-fov 360``: the depth camera has its own 79 degrees, so the LiDAR's field of view
    is a usage error (exit 2) before anything runs; it was ignored and the episodes ran at 79 degrees."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    out = tmp_path / "o"
    r = CliRunner().invoke(app, ["eval", "--sensor", "depth", "--lidar-fov", "360", "--scene", "generated:small:1:0", "--out", str(out)])
    assert r.exit_code == 2 and "--lidar-fov" in r.output and "depth" in r.output
    assert not out.exists()


@pytest.mark.parametrize(("field", "value"), [("m_per_px", -1.0), ("m_per_px", 0.0), ("m_per_px", float("nan")), ("limit", 0)])
def test_eval_rejects_a_bad_scale_or_limit_before_any_episode(tmp_path: Path, field: str, value: float):
    request = EvalRequest(methods=["greedy-dist"], maps="builtin", out_dir=tmp_path / "o", **{field: value})
    with pytest.raises(ConfigError, match=field.replace("_", "-")):
        run_eval(request)
    assert not (tmp_path / "o").exists()  # nothing ran, nothing written


def test_eval_sim_config_sets_the_mujoco_limos_parameters_and_resume_tells_them_apart(tmp_path: Path):
    """``--sim-config FILE`` (configs/robot_sim.yaml's keys): the MuJoCo LIMO runs with them, the summary says
    which, ``--resume`` does not reuse an episode run without them, and they are refused with the 2D simulator."""
    drift = tmp_path / "drift.yaml"
    drift.write_text("odom_trans_noise_frac: 0.05\nodom_rot_per_trans_noise_radpm: 0.05\n")
    base = {"methods": ["greedy-dist"], "maps": "generated:small:1:0", "out_dir": tmp_path / "o", "max_steps": 12, "sim": "mujoco", "resume": True}
    plain = run_eval(EvalRequest(**base))
    with pytest.raises(ConfigError, match=r"holds 1 episode of this run's methods and plans from another configuration .*"
                       r"sim_settings.odom_trans_noise_frac: 0.0 there, 0.05 here.* or --overwrite to run them again here"):
        run_eval(EvalRequest(**base, sim_config_path=drift))  # they would be written over
    drifted = run_eval(EvalRequest(**base, sim_config_path=drift, overwrite=True))
    assert "mujoco" not in plain["meta"]
    assert drifted["meta"]["mujoco"] == {"file": str(drift), "parameters": {"odom_trans_noise_frac": 0.05, "odom_rot_per_trans_noise_radpm": 0.05}}
    # Every parameter the LIMO ran with, defaults too (meta.mujoco lists only a file's): a default run's timestep,
    # contacts and limits were nowhere in its results.
    from robot_sim.config import MujocoSimConfig

    defaults = {**dataclasses.asdict(MujocoSimConfig()), "lidar_mount_x_m": 0.103}
    assert plain["meta"]["sim_settings"] == defaults and defaults["timestep_s"] == 0.005
    assert drifted["meta"]["sim_settings"] == {**defaults, "odom_trans_noise_frac": 0.05, "odom_rot_per_trans_noise_radpm": 0.05}
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["meta"]["sim_settings"] == drifted["meta"]["sim_settings"]
    with (tmp_path / "o" / "episodes.csv").open() as fh:
        (row,) = list(csv.DictReader(fh))
    assert float(row["sim_time_s"]) == pytest.approx(int(row["steps"]) * 0.25)  # the MuJoCo clock: 50 physics steps of 5 ms a step
    assert float(row["real_time_factor"]) > 0
    assert drifted["meta"]["resumed_episodes"] == 0  # the same method, map and seed, other physics: run again
    assert run_eval(EvalRequest(**base, sim_config_path=drift))["meta"]["resumed_episodes"] == 1
    with pytest.raises(ConfigError, match="--sim-config .* needs --sim mujoco, not --sim 2d"):
        run_eval(EvalRequest(**{**base, "sim": "2d"}, sim_config_path=drift))
    drift.write_text("odom_noise: 0.05\n")
    with pytest.raises(ConfigError, match="drift.yaml: unknown key"):
        run_eval(EvalRequest(**base, sim_config_path=drift))


def test_a_second_lidar_mount_in_evals_sim_config_names_the_key_eval_sets_the_sensors_mount_with(tmp_path: Path):
    """``--sim-config``'s ``lidar_mount_x_m`` against the sensor's mount: the error said "set sensor.mount_x_m" in every
    context; in eval that key lives in the ``--config`` file (or ``eval --set``), in a profile under ``exploration.``."""
    params = tmp_path / "limo.yaml"
    params.write_text("lidar_mount_x_m: 0.2\n")
    config = tmp_path / "eval.yaml"
    config.write_text("episode:\n  max_steps: 20\n")
    request = EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=params, out_dir=tmp_path / "o")
    with pytest.raises(ConfigError, match=r"set sensor.mount_x_m: 0.2 in a --config file or with eval --set sensor.mount_x_m=0.2 instead"):
        request.validate()
    request.config_path = config
    with pytest.raises(ConfigError, match=rf"set sensor.mount_x_m: 0.2 in {config} or with eval --set sensor.mount_x_m=0.2 instead"):
        request.validate()


def test_eval_outside_the_repository_reads_the_packaged_configs_the_help_names(tmp_path: Path, monkeypatch):
    """``--config configs/eval.yaml`` and ``--sim-config configs/robot_sim.yaml`` (what the help, the README and
    docs/eval.md name) where there is no ``configs/``: the package's copies, with a note; another missing file stays an error."""
    from typer.testing import CliRunner

    from cso_runtime.cli import PACKAGED_CONFIGS, app

    repo = Path(__file__).resolve().parents[1] / "configs"
    for name in ("eval.yaml", "robot_sim.yaml", "train.yaml"):
        assert (PACKAGED_CONFIGS / name).read_text() == (repo / name).read_text()
    monkeypatch.chdir(tmp_path)
    args = ["eval", "--maps", "generated:small:1:0", "--max-steps", "4", "--sim", "mujoco", "--out", str(tmp_path / "o")]
    result = CliRunner().invoke(app, [*args, "--config", "configs/eval.yaml", "--sim-config", "configs/robot_sim.yaml"])
    assert result.exit_code == 0, result.output
    assert "note: no configs/eval.yaml here; using the packaged" in result.output and "no configs/robot_sim.yaml here" in result.output
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["meta"]["mujoco"]["file"] == str(PACKAGED_CONFIGS / "robot_sim.yaml")
    result = CliRunner().invoke(app, [*args, "--config", "mine/eval.yaml"])
    assert result.exit_code == 2 and "config file not found: mine/eval.yaml" in result.output


def test_eval_compares_each_method_with_the_baseline_scene_by_scene(tmp_path: Path):
    summary = run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:3:7", out_dir=tmp_path / "o", max_steps=40))
    (row,) = summary["paired"]["comparisons"]
    assert summary["paired"]["baseline"] == "greedy-dist" and (row["method"], row["scale"], row["scenes"]) == ("random", "small", 3)
    with (tmp_path / "o" / "episodes.csv").open() as fh:
        episodes = {(r["method"], r["map"]): float(r["efficiency_m2_per_step"]) for r in csv.DictReader(fh)}
    ratios = [episodes["random", m] / episodes["greedy-dist", m] for m in ("gen_small_7", "gen_small_8", "gen_small_9")]
    assert row["per_scene_pct"] == pytest.approx(100 * (np.mean(ratios) - 1), abs=1e-3)
    assert row["won"] == sum(r > 1 for r in ratios) and row["lost"] == sum(r < 1 for r in ratios)
    with (tmp_path / "o" / "paired.csv").open() as fh:
        assert [r["method"] for r in csv.DictReader(fh)] == ["random"]
    assert (tmp_path / "o" / "paired_efficiency.png").stat().st_size > 1000
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["paired"] == summary["paired"]

    alone = run_eval(EvalRequest(methods=["random"], maps="generated:small:3:7", out_dir=tmp_path / "r", max_steps=40))
    assert alone["paired"]["comparisons"] == [] and not (tmp_path / "r" / "paired.csv").exists()
    # Again into the first folder, without the baseline and on one other plan: nothing of the first run is shown as this one's
    again = run_eval(EvalRequest(methods=["random"], maps="generated:small:1:8", out_dir=tmp_path / "o", max_steps=40))
    assert again["methods"]["random"]["maps"] == ["gen_small_8"]
    assert not (tmp_path / "o" / "paired.csv").exists() and not (tmp_path / "o" / "paired_efficiency.png").exists()
    page = (tmp_path / "o" / "report.html").read_text()
    assert "trajectories/gen_small_8.png" in page and "gen_small_7" not in page and "gen_small_9" not in page
    assert (tmp_path / "o" / "trajectories" / "gen_small_7.png").is_file()  # left where it is, only not shown
    with pytest.raises(ConfigError, match="unknown --baseline"):
        run_eval(EvalRequest(methods=["random"], maps="generated:small:3:7", out_dir=tmp_path / "x", baseline="nearest"))


@pytest.mark.parametrize("spec", ["generated:small:2:5"])
def test_eval_on_generated_scenes_is_deterministic(tmp_path: Path, spec: str):
    """Two evals of the same request: every episode the same, row by row and step by step (its path and coverage
    curve), the seeded random method too, not only the means; only the timings may differ."""
    methods = ["greedy-dist", "random"]
    a = run_eval(EvalRequest(methods=methods, maps=spec, out_dir=tmp_path / "a", max_steps=80))
    b = run_eval(EvalRequest(methods=methods, maps=spec, out_dir=tmp_path / "b", max_steps=80))
    timings = {"decision_ms_p50", "decision_ms_p99", "wall_s", "real_time_factor"}

    def episodes(out: Path) -> list[dict]:
        with (out / "episodes.csv").open() as fh:
            return [{k: v for k, v in row.items() if k not in timings} for row in csv.DictReader(fh)]

    rows = episodes(tmp_path / "a")
    assert len(rows) == 4 and rows == episodes(tmp_path / "b")

    def untimed(value):
        """``value`` without its timings (``decision_ms_p50_std`` and the like too), at any depth."""
        if isinstance(value, dict):
            return {k: untimed(v) for k, v in value.items() if not k.startswith(tuple(timings))}
        return value

    assert untimed(a["methods"]) == untimed(b["methods"]) and untimed(a["paired"]) == untimed(b["paired"])
    for npz in sorted((tmp_path / "a" / "episodes").rglob("*.npz")):
        with np.load(npz) as first, np.load(tmp_path / "b" / npz.relative_to(tmp_path / "a")) as again:
            for key in ("explored", "trajectory", "coverage_curve"):
                np.testing.assert_array_equal(first[key], again[key], err_msg=f"{npz.name} {key}")
    # The random method's choices matter here: its paths differ from greedy-dist's on some scene.
    trajectories = {m: [np.load(p)["trajectory"] for p in sorted((tmp_path / "a" / "episodes" / m).glob("*.npz"))] for m in methods}
    assert len(trajectories["random"]) == 2 and any(
        r.shape != g.shape or not np.array_equal(r, g) for r, g in zip(trajectories["random"], trajectories["greedy-dist"])
    )


def test_resume_reuses_finished_episodes(tmp_path: Path):
    req = EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=30)
    first = run_eval(req)
    npz = tmp_path / "episodes" / "random" / "gen_small_11.npz"
    stamp = npz.stat().st_mtime_ns
    npz_other = tmp_path / "episodes" / "greedy-dist" / "gen_small_11.npz"
    npz_other.unlink()
    req.resume = True
    second = run_eval(req)
    assert npz.stat().st_mtime_ns == stamp  # not re-run
    assert npz_other.exists()  # the missing one was run again
    assert second["meta"]["resumed_episodes"] == 1 and "resumed_episodes" not in first["meta"]
    assert first["meta"]["version"] == cso_runtime.__version__ != "0+unknown"  # which code made the table
    assert first["meta"]["sim_settings"] == {"collision_radius_m": 0.12, "substeps": 5}  # the 2D simulator's own
    assert first["meta"]["m_per_px"] is None and first["meta"]["cell_sizes_m"] == [0.05]  # --m-per-px scales PNG plans only
    # and every flag it was given (meta.command alone said "cso-runtime eval"), as JSON that reads back
    request = json.loads((tmp_path / "summary.json").read_text())["meta"]["request"]
    assert request["methods"] == ["greedy-dist", "random"] and request["max_steps"] == 30 and request["limit"] is None
    assert request["out_dir"] == str(tmp_path) and second["meta"]["request"]["resume"] is True
    for m in ("greedy-dist", "random"):
        assert second["methods"][m]["coverage_pct"] == first["methods"][m]["coverage_pct"]
        assert second["methods"][m]["steps"] == first["methods"][m]["steps"]
    req.max_steps = 20  # other settings: refused (they would write over the folder's), unless --overwrite
    with pytest.raises(ConfigError, match="episode.max_steps: 30 there, 20 here"):
        run_eval(req)
    req.overwrite = True  # then nothing is reused: every episode runs again with them
    third = run_eval(req)
    assert npz.stat().st_mtime_ns != stamp
    assert third["methods"]["greedy-dist"]["steps"] <= 20 < first["methods"]["greedy-dist"]["steps"]


def test_resume_runs_again_an_episode_of_another_scene_under_the_same_name(tmp_path: Path):
    """A plan of the same name at another ``--m-per-px`` (or another plan in a folder of the same name) is
    another scene: ``--resume`` must not keep the episode of the old one."""
    plans = tmp_path / "plans"
    plans.mkdir()
    shutil.copy(Path(cso_runtime.__file__).parent / "data" / "scenes" / "img_1.png", plans / "office.png")
    req = EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=tmp_path / "out", max_steps=10, m_per_px=0.1)
    csv_path = tmp_path / "out" / "episodes.csv"

    def traversable_m2() -> float:
        (row,) = csv.DictReader(csv_path.open())
        return float(row["traversable_area_m2"])

    run_eval(req)
    npz = tmp_path / "out" / "episodes" / "greedy-dist" / "office.npz"
    stamp, area_m2 = npz.stat().st_mtime_ns, traversable_m2()
    req.resume = True
    assert run_eval(req)["meta"]["resumed_episodes"] == 1 and npz.stat().st_mtime_ns == stamp  # the same scene: kept
    req.m_per_px = 0.05
    with pytest.raises(ConfigError, match=r"another configuration \(greedy-dist office; it ran on another plan under the same name \(another "
                       r"--m-per-px, folder or map origin\); its summary.json differs in m_per_px: 0.1 there, 0.05 here\)"):
        run_eval(req)  # another plan under the name: its episode would be written over
    req.overwrite = True
    second = run_eval(req)
    assert second["meta"]["resumed_episodes"] == 0 and npz.stat().st_mtime_ns != stamp
    assert traversable_m2() == pytest.approx(area_m2 / 4, rel=1e-3)  # the plan at half the cell size
    assert second["meta"]["cell_sizes_m"] == [0.05] and second["meta"]["m_per_px"] == 0.05  # a PNG plan: the flag counts


def test_eval_refuses_two_plans_whose_names_share_one_episode_file(tmp_path: Path):
    """``room 1.png`` and ``room_1.png`` (or ``a.yaml`` and ``a.yml``) in one folder are two plans whose files are one:
    ``episodes/<method>/room_1.npz``, its map and trajectory plot. The second episode wrote over the first, one plan's
    results were lost from the folder, and ``--resume`` then refused it. The eval is refused before any episode,
    naming both plans, as two methods sharing a folder are."""
    plans = tmp_path / "plans"
    plans.mkdir()
    for name in ("room 1.png", "room_1.png", "img_2.png"):
        shutil.copy(Path(cso_runtime.__file__).parent / "data" / "scenes" / "img_1.png", plans / name)
    out = tmp_path / "out"
    request = EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=out, max_steps=10)
    with pytest.raises(ConfigError, match=r"scenes 'room 1' \(.*room 1\.png\) and 'room_1' \(.*room_1\.png\) would share the files "
                       r"episodes/<method>/room_1\.npz"):
        plan_eval(request)
    assert not out.exists()
    result = subprocess.run([sys.executable, "-m", "cso_runtime", "eval", "--maps", str(plans), "--out", str(out), "--max-steps", "10", "--dry-run"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "would share the files" in result.stderr, result.stderr
    (plans / "room 1.png").unlink()
    (plans / "yard.yaml").write_text("image: room_1.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    (plans / "yard.yml").write_text((plans / "yard.yaml").read_text())
    with pytest.raises(ConfigError, match=r"scenes 'yard' \(.*yard\.yaml\) and 'yard' \(.*yard\.yml\) would share"):
        plan_eval(request)
    (plans / "yard.yml").unlink()
    assert [job.scene.name for job in plan_eval(request).jobs] == ["yard"]  # one plan a name: runs


def test_the_report_names_the_seed_of_each_failed_episode_of_an_eval_of_several_seeds(tmp_path: Path, capsys):
    """With ``--seeds``, a plan that fails fails once a seed: the console said each failure's seed, but report.html
    listed the two as one line twice, as if the same episode were counted twice."""
    from cso_runtime.evaluation import print_summary

    plans = tmp_path / "plans"
    plans.mkdir()
    shutil.copy(Path(cso_runtime.__file__).parent / "data" / "scenes" / "img_1.png", plans / "good.png")
    (plans / "bad.png").write_text("not a picture")
    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=out, max_steps=5, seeds=[0, 1]))
    assert [(f["map"], f["seed"]) for f in summary["failures"]] == [("bad", 0), ("bad", 1)]
    page = (out / "report.html").read_text()
    failures = page.split("<h2>Failures</h2>", 1)[1].split("</ul>", 1)[0]
    assert re.findall(r"<li>greedy-dist bad \(seed (\d)\): .*?bad\.png", failures) == ["0", "1"], failures
    print_summary(summary, out)
    said = capsys.readouterr().out
    assert "failed greedy-dist bad (seed 0): " in said and "failed greedy-dist bad (seed 1): " in said


def _episode_whose_process_dies_on_one_scene(job):
    """A worker that is killed (as by the kernel's OOM killer) whenever it runs gen_small_1."""
    import os

    if job.scene.name == "gen_small_1":
        os._exit(9)
    return run_job(job)


def test_a_dead_worker_costs_only_its_own_episode(tmp_path: Path):
    """A killed worker breaks its process pool: the episodes the pool had not finished run again, and
    only the one whose process dies every time is reported, as a failure; nothing hangs or is lost."""
    scenes = resolve_scenes("generated:small:4:0")
    config = ExplorationConfig()
    jobs = [EpisodeJob("greedy-dist", s, 0, "2d", config, tmp_path) for s in scenes]
    outcomes = []
    run_in_processes(jobs, 2, outcomes.append, episode=_episode_whose_process_dies_on_one_scene)
    by_scene = {o.map: o for o in outcomes}
    assert len(outcomes) == 4 and set(by_scene) == {s.name for s in scenes}
    assert by_scene["gen_small_1"].row is None and by_scene["gen_small_1"].error == WORKER_DIED
    for name in ("gen_small_0", "gen_small_2", "gen_small_3"):
        assert by_scene[name].row is not None and by_scene[name].row["terminated_by"] == "coverage"
        assert (tmp_path / "episodes" / "greedy-dist" / f"{name}.npz").is_file()


def test_ctrl_c_stops_eval_at_once_keeps_the_finished_episodes_and_resume_runs_the_rest(tmp_path: Path):
    """Ctrl-C reaches the whole process group, as in a terminal: the workers stop, the finished episodes
    are written (summary.json says it was interrupted), exit code 130; ``--resume`` then runs the rest."""
    import os
    import signal
    import threading

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "cso_runtime.cli", "eval", "--method", "random", "--maps", "generated:middle:4:0",
           "--workers", "2", "--out", str(out)]  # 4 episodes of ~3 s: one finishes while 3 remain, for --resume
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # noqa: PLW1509  (a child of a background shell starts with SIGINT ignored)
    lines: list[str] = []
    first_done = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("[1/4]"):  # the progress line of the first finished episode
                first_done.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert first_done.wait(120) and proc.poll() is None, "no episode finished, or the evaluation ended first"
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
        reader.join(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    stdout = "".join(lines)
    assert proc.returncode == 130, stdout[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    stopped = summary["meta"]["interrupted"]
    finished = sorted((out / "episodes" / "random").glob("*.npz"))
    assert 1 <= stopped["episodes_finished"] < 4 and stopped["episodes_planned"] == 4
    assert summary["methods"]["random"]["episodes"] == stopped["episodes_finished"]
    assert len(finished) >= stopped["episodes_finished"]  # an episode whose result was still on its way is kept for --resume
    assert "--resume runs the rest" in stdout
    stamps = {p.name: p.stat().st_mtime_ns for p in finished}
    again = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert "interrupted" not in summary["meta"] and summary["methods"]["random"]["episodes"] == 4
    assert all((out / "episodes" / "random" / name).stat().st_mtime_ns == t for name, t in stamps.items())


BLOCK_ON_SEED = '''"""A goal selector of one's own that blocks in the first decision of seed BLOCK_SEED's episode (until Ctrl-C),
once it has said so by writing BLOCK_MARKER; nearest frontier otherwise."""

import os
import time
from pathlib import Path

import numpy as np

from cso_runtime.policies import goal_of


class BlockOnSeed:
    name = "block-on-seed"
    grids = ()

    def reset(self, seed=None):
        self.seed = seed

    def select(self, obs):
        marker = os.environ.get("BLOCK_MARKER")
        if marker and self.seed == int(os.environ["BLOCK_SEED"]):
            Path(marker).write_text("blocked")
            time.sleep(300)  # until Ctrl-C
        reachable = [i for i, c in enumerate(obs.clusters) if np.isfinite(c.distance_m)]
        return goal_of(obs, min(reachable, key=lambda i: obs.clusters[i].distance_m)) if reachable else None
'''
"""``test_ctrl_c_in_an_eval_of_several_seeds_...``'s method: the Ctrl-C lands in seed 1's episode, not at a time hoped for."""


def test_ctrl_c_in_an_eval_of_several_seeds_writes_what_finished_exits_130_and_resume_runs_the_rest(tmp_path: Path):
    """``eval --seeds 0,1,2`` stopped by Ctrl-C (the whole process group, as a terminal's) in seed 1's episode ends as a
    one-seed eval does: seed 0's folder whole, seed 1's with what finished (none, and says it was interrupted), no seed 2,
    the pooled files of the finished episodes saying it was interrupted, exit code 130 and the hint; ``--resume`` then
    runs seeds 1 and 2, keeping seed 0's episode, and pools all three. The method blocks in seed 1's first decision once
    it has written a file: the signal comes while that seed runs, whatever the machine's speed."""
    import signal

    from tests.conftest import process_group, wait_for

    (tmp_path / "block_on_seed.py").write_text(BLOCK_ON_SEED)
    out, marker = tmp_path / "out", tmp_path / "blocked"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])}
    method = "block_on_seed:BlockOnSeed"
    cmd = [sys.executable, "-m", "cso_runtime.cli", "eval", "--method", method, "--maps", "generated:small:1:0", "--seeds", "0,1,2",
           "--max-steps", "20", "--out", str(out)]  # fmt: skip
    blocking = {**env, "BLOCK_MARKER": str(marker), "BLOCK_SEED": "1"}
    with process_group(cmd, env=blocking, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) as proc:  # a child of a background shell starts with SIGINT ignored
        wait_for(lambda: marker.exists() or proc.poll() is not None, 120, "seed 1's first decision")
        assert proc.poll() is None, proc.communicate()[0][-2000:]
        os.killpg(proc.pid, signal.SIGINT)
        stdout = proc.communicate(timeout=60)[0]
    assert proc.returncode == 130, stdout[-2000:]
    assert "interrupted: 1 of 3 episodes finished; the same command with --resume runs the rest" in " ".join(stdout.split()), stdout[-2000:]
    pooled = json.loads((out / "summary.json").read_text())
    assert pooled["meta"]["seeds"] == [0, 1, 2] and pooled["methods"][method]["episodes"] == 1
    assert (pooled["meta"]["interrupted"]["episodes_finished"], pooled["meta"]["interrupted"]["episodes_planned"]) == (1, 3)
    assert (out / "report.html").is_file() and len(list(csv.DictReader((out / "episodes.csv").open()))) == 1
    assert "interrupted" not in json.loads((out / "seed0" / "summary.json").read_text())["meta"]
    seed1 = json.loads((out / "seed1" / "summary.json").read_text())["meta"]["interrupted"]
    assert (seed1["episodes_finished"], seed1["episodes_planned"]) == (0, 1) and not (out / "seed2").exists()
    (kept,) = (out / "seed0" / "episodes").glob("*/*.npz")
    stamp = kept.stat().st_mtime_ns
    again = subprocess.run([*cmd, "--resume"], env=env, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    pooled = json.loads((out / "summary.json").read_text())
    assert "interrupted" not in pooled["meta"] and pooled["methods"][method]["episodes"] == 3 and pooled["meta"]["resumed_episodes"] == 1
    assert kept.stat().st_mtime_ns == stamp and all("interrupted" not in json.loads((out / f"seed{s}" / "summary.json").read_text())["meta"] for s in (0, 1, 2))


def test_ctrl_c_between_two_seeds_or_while_one_is_written_ends_as_a_one_seed_evals(tmp_path: Path, monkeypatch):
    """``eval --seeds``: a Ctrl-C once seed 0's files were written and before seed 1's first episode (its folder's lock,
    its check) left no pooled files and said "interrupted while writing the results in OUT/", where nothing was being
    written; one while seed 1's files were written named OUT/, not that seed's folder. Between seeds it ends as in a
    seed's episodes (the pooled files of what finished, "--resume runs the rest"); while a seed's files are written,
    as a one-seed eval does then, naming that folder; ``--resume`` completes either."""
    from typer.testing import CliRunner

    from cso_runtime import cli, evaluation

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)  # the test's process keeps its own handlers
    out = tmp_path / "o"
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--seeds", "0,1", "--max-steps", "10", "--out", str(out)]
    run_episodes, write_report = evaluation._run_episodes, evaluation.write_report
    with monkeypatch.context() as patched:
        patched.setattr(evaluation, "_run_episodes", lambda one, *a, **k: interrupted() if one.seed == 1 else run_episodes(one, *a, **k))
        r = CliRunner().invoke(cli.app, args)
    said = " ".join(r.output.split())
    assert r.exit_code == 130 and "interrupted: 1 of 2 episodes finished; the same command with --resume runs the rest" in said, said
    stopped = json.loads((out / "summary.json").read_text())["meta"]["interrupted"]
    assert (stopped["episodes_finished"], stopped["episodes_planned"]) == (1, 2) and not (out / "seed1" / "summary.json").exists()
    with monkeypatch.context() as patched:
        patched.setattr(evaluation, "write_report", lambda folder, summary: interrupted() if Path(folder) == out / "seed1" else write_report(folder, summary))
        r = CliRunner().invoke(cli.app, [*args, "--resume"])
    said = " ".join(r.output.split())
    assert r.exit_code == 130 and f"interrupted while writing the results in {out / 'seed1'}/" in said and "--resume writes them" in said, said
    again = CliRunner().invoke(cli.app, [*args, "--resume"])
    assert again.exit_code == 0, again.output
    pooled = json.loads((out / "summary.json").read_text())
    assert "interrupted" not in pooled["meta"] and pooled["methods"]["greedy-dist"]["episodes"] == 2 and (out / "seed1" / "report.html").is_file()


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_sigterm_to_eval_alone_stops_its_workers_and_keeps_the_finished_episodes(tmp_path: Path, signame: str):
    """``kill PID`` (or a job scheduler's stop, or the terminal closing) reaches the parent only: it ends as
    Ctrl-C does, exit code 130 with the finished episodes written, and no worker process is left behind (they
    used to be, idle, forever)."""
    import signal

    from tests.conftest import process_group

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "cso_runtime.cli", "eval", "--method", "random", "--maps", "generated:middle:8:0",
           "--workers", "2", "--out", str(out)]
    with process_group(cmd) as proc:  # on leaving: no worker process left
        for line in proc.stdout:
            if line.startswith("[1/8]"):
                break
        assert proc.poll() is None, "the evaluation ended before the signal"
        proc.send_signal(getattr(signal, signame))
        stdout = proc.communicate(timeout=30)[0]
    assert proc.returncode == 130, stdout[-2000:]
    stopped = json.loads((out / "summary.json").read_text())["meta"]["interrupted"]
    assert 1 <= stopped["episodes_finished"] < 8 and "--resume runs the rest" in stdout


def test_the_console_table_has_one_block_per_scale_as_the_papers_table_1(tmp_path: Path, capsys):
    from cso_runtime.evaluation import print_summary, summarize

    def row(method: str, scale: str, m2: float) -> dict:
        return {"method": method, "map": f"{scale}_plan", "seed": 0, "traversable_area_m2": m2, "scale": scale, "terminated_by": "coverage", "explored_area_m2": m2, "coverage_pct": 99.5,
                "steps": 100, "efficiency_m2_per_step": m2 / 100, "path_length_m": 10.0, "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}

    rows = [row("greedy-dist", "small", 20.0), row("greedy-dist", "middle", 60.0), row("random", "small", 20.0)]
    print_summary(summarize(rows, [], ["greedy-dist", "random"], {}), tmp_path)
    lines = capsys.readouterr().out.splitlines()
    cells = [[c.strip() for c in line.split("│")[1:3]] for line in lines if line.startswith("│")]
    assert cells == [["greedy-dist", "small"], ["greedy-dist", "middle"], ["greedy-dist", "all"], ["random", "small"]]
    middle = next(line for line in lines if "middle" in line)
    assert "0.6000" in middle and "60.0" in middle  # that scale's own means, not the method's
    assert lines[-1] == f"results in {tmp_path}/: report.html (all of it, for a browser), summary.json, episodes.csv, the figures"



def test_the_console_tables_on_an_80_column_terminal_cut_no_number(tmp_path: Path, monkeypatch):
    """On an 80-column terminal Table 1's nine columns did not fit even without the spreads: rich cut its cells,
    and the m2/step of the run read ``3.3…``, its coverage ``13.…``. A table too wide for the terminal is said one
    line per row instead (each value after its column's name), so no number is cut; the comparison's too."""

    from rich.console import Console

    from cso_runtime import evaluation
    from cso_runtime.evaluation import print_summary

    summary = super_large_summary()
    for width, table in ((80, False), (200, True)):
        screen = TerminalFile()
        monkeypatch.setattr(evaluation, "table_console", lambda w=width, f=screen: Console(file=f, width=w, force_terminal=True, color_system=None))
        print_summary(summary, tmp_path)
        out = screen.getvalue()
        assert "…" not in out, out
        assert ("│ greedy-dist │" in out) == table, out  # a wide terminal keeps the tables
        assert max(len(line) for line in out.splitlines()) <= width or not table, out
    narrow = TerminalFile()
    monkeypatch.setattr(evaluation, "table_console", lambda: Console(file=narrow, width=80, force_terminal=True, color_system=None))
    print_summary(summary, tmp_path)
    said = " ".join(narrow.getvalue().split())
    assert "greedy-dist super_large: episodes 3, explored m2 67.6, coverage % 13.37, steps 20.0, m2/step 3.3902, path m 0.2, decision ms p50/p99 8.2/9.1" in said, said
    assert "greedy-info super_large: scenes 3, m2/step vs baseline +0.9 %" in said, said  # the comparison's rows too


def test_the_closing_line_of_an_eval_whose_every_episode_failed_says_so_not_the_figures(tmp_path: Path, capsys):
    """Every episode failed: no metric and no figure was written, so the closing line does not send the reader to
    "the figures" (nor to a report of results): it says that all failed and where the failures are listed."""
    from cso_runtime.evaluation import print_summary, summarize

    failures = [{"method": "greedy-dist", "map": f"plan{i}", "error": "boom"} for i in range(2)]
    print_summary(summarize([], failures, ["greedy-dist"], {}), tmp_path)
    last = capsys.readouterr().out.splitlines()[-1]
    assert "the figures" not in last and last.startswith("all 2 episodes failed (above): no metrics and no figures"), last
    assert f"{tmp_path}/report.html and summary.json list the failures" in last, last


def test_the_console_says_why_a_run_with_the_baseline_has_no_comparison(tmp_path: Path, capsys):
    """`eval --limit 2` with greedy-dist and cso: too few shared scenes for paired.csv (at least 3 per scale). The
    console says so, instead of leaving out the comparison without a word; with 3 scenes the table is there."""
    from cso_runtime.evaluation import print_summary, summarize

    def row(method: str, name: str, eff: float) -> dict:
        return {"method": method, "map": name, "seed": 0, "traversable_area_m2": 150.0, "scale": "large", "terminated_by": "coverage", "explored_area_m2": 150.0,
                "coverage_pct": 99.5, "steps": 150.0 / eff, "efficiency_m2_per_step": eff, "path_length_m": 10.0, "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}

    two = [row(m, n, e) for m, e in (("greedy-dist", 1.0), ("cso", 1.1)) for n in ("img_1", "img_2")]
    print_summary(summarize(two, [], ["greedy-dist", "cso"], {}), tmp_path)
    out = capsys.readouterr().out
    assert "no comparison with greedy-dist scene by scene (paired.csv): no other method shares 3 or more scenes (plans: the seeds of one plan count once) of one scale with it" in out
    three = two + [row("greedy-dist", "img_3", 1.0), row("cso", "img_3", 1.1)]
    print_summary(summarize(three, [], ["greedy-dist", "cso"], {}), tmp_path)
    out = capsys.readouterr().out
    assert "no comparison" not in out and "Against greedy-dist, scene by scene" in out
    print_summary(summarize(two, [], ["cso"], {}), tmp_path)  # the baseline did not run: nothing to explain
    assert "no comparison" not in capsys.readouterr().out
    # Two methods, neither the baseline (`--method cso,utility`, or a --baseline of a method not run): not a word was said.
    others = [row(m, n, e) for m, e in (("utility", 1.0), ("cso", 1.1)) for n in ("img_1", "img_2", "img_3")]
    print_summary(summarize(others, [], ["utility", "cso"], {}), tmp_path)
    assert ("no comparison scene by scene (paired.csv): its baseline greedy-dist did not run; add it to --method, or give --baseline one of "
            "utility, cso") in " ".join(capsys.readouterr().out.split())
    print_summary(summarize(others, [], ["utility", "cso"], {}, baseline="utility"), tmp_path)
    assert "no comparison" not in capsys.readouterr().out


def test_a_run_with_ablations_is_also_laid_out_as_the_papers_table_2(tmp_path: Path, capsys):
    """A row per method, a column per scale, m2/step with the per-scene change against the baseline; on the
    console and in report.html, only where two learned methods ran (cso and an ablation)."""
    from cso_runtime.evaluation import print_summary, summarize
    from cso_runtime.report import table2, write_report

    def row(method: str, map_: str, scale: str, eff: float) -> dict:
        return {"method": method, "map": map_, "seed": 0, "traversable_area_m2": 150.0, "scale": scale, "terminated_by": "coverage", "explored_area_m2": 100 * eff,
                "coverage_pct": 99.5, "steps": 100, "efficiency_m2_per_step": eff, "path_length_m": 10.0, "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}

    rows = [row("greedy-dist", m, "large", 1.0) for m in "abc"] + [row("greedy-dist", "d", "middle", 0.5)]
    rows += [row("cso", m, "large", 1.2) for m in "abc"] + [row("cso-no-info", m, "large", 0.9) for m in "abc"]
    summary = summarize(rows, [], ["greedy-dist", "cso", "cso-no-info"], {})
    header, cells = table2(summary)
    assert header == ["method", "middle", "large"]
    assert cells[0] == ["greedy-dist", "0.5000", "1.0000"]
    assert cells[1][0] == "cso" and cells[1][1] == "-" and cells[1][2].startswith("1.2000 (+20.0 % [")
    assert cells[2][2].startswith("0.9000 (-10.0 % [")
    print_summary(summary, tmp_path)
    out = capsys.readouterr().out
    assert "Table 2" in out and "cso-no-info" in out
    page = write_report(tmp_path, summary).read_text()
    assert "<h2>Table 2" in page and "<td>0.9000 (-10.0 % [" in page
    # the comparisons come in Table 1's order: by scale, then as the methods were given (not alphabetically)
    given = summarize(rows, [], ["greedy-dist", "cso-no-info", "cso"], {})
    assert [c["method"] for c in given["paired"]["comparisons"]] == ["cso-no-info", "cso"]
    # greedy-dist against cso alone is Table 1 and its comparison, not an ablation study
    plain = summarize(rows[:7], [], ["greedy-dist", "cso"], {})
    print_summary(plain, tmp_path)
    assert "Table 2" not in capsys.readouterr().out and "Table 2" not in write_report(tmp_path, plain).read_text()


def test_eval_warms_a_learned_policy_up_before_its_first_decision(tmp_path: Path, monkeypatch):
    """The network's one-off trace happens before the episode, so the first decision's latency in the
    table is a decision, not the trace (the policy service warms up the same way before it says it is up)."""
    from cso_runtime import evaluation
    from cso_runtime.policies import make_policy

    calls = []

    def recording_policy(method, masks, seed=0, sensor=None, frontier=None):
        policy = make_policy(method, masks, seed=seed, sensor=sensor, frontier=frontier)
        warm_up, select = policy.warm_up, policy.select
        policy.warm_up = lambda: (calls.append("warm_up"), warm_up())[1]
        policy.select = lambda obs: (calls.append("select"), select(obs))[1]
        return policy

    monkeypatch.setattr(evaluation, "make_policy", recording_policy)
    (scene,) = resolve_scenes("generated:small:1:0")
    outcome = run_job(EpisodeJob("cso", scene, 0, "2d", ExplorationConfig(), tmp_path))
    assert outcome.error is None and outcome.row["decisions"] >= 2
    assert calls[0] == "warm_up" and calls.count("warm_up") == 1 and "select" in calls


def test_an_eval_whose_progress_reader_is_gone_runs_every_episode_and_writes_its_results(tmp_path: Path):
    """``eval ... 2>&1 | head -1``: once the reader of its progress lines was gone, rich turned the broken pipe into
    ``SystemExit(1)`` at the next line, so the eval stopped after an episode or two, silently, with exit code 1 and
    neither summary.json nor episodes.csv. The progress goes quiet instead; the episodes run and their results
    are written."""
    import os
    import signal

    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "cso_runtime.cli", "eval", "--maps", "generated:small:3:0", "--max-steps", "5", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        assert proc.stderr is not None
        proc.stderr.close()  # the reader gone before the first progress line
        assert proc.wait(timeout=120) == 0
    finally:  # an eval that hangs (the failure under test) is not left running, nor its workers
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["methods"]["greedy-dist"]["episodes"] == 3 and (out / "episodes.csv").is_file()


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "--maps", "generated:small:2:0", "--max-steps", "5", "--out", "{tmp}/o"],
        ["eval", "--maps", "generated:small:2:0", "--out", "{tmp}/o", "--dry-run"],
        ["eval", "--maps", "generated:small:2:0", "--out", "{tmp}/o", "--resolved"],
        ["runs", "--runs-dir", "{tmp}"],
        ["up", "--resolved"],
        ["scenes", "generated:small:2:0"],
        ["--help"],  # typer's help, printed by rich before any command runs
        ["eval", "--help"],
        ["train", "--set", "dungeon_dir=null", "--set", "generated=[generated:small:1:0]", "--set", "num_steps=4", "--set", "num_minibatches=1",
         "--set", "max_steps=40", "--num-envs", "1", "--total-decisions", "4", "--out", "{tmp}/t"],  # its progress lines
    ],
    ids=["eval", "eval-dry-run", "eval-resolved", "runs", "up-resolved", "scenes", "help", "eval-help", "train"],
)
def test_a_command_whose_reader_left_ends_quietly_with_exit_code_141(tmp_path: Path, args: list[str]):
    """``eval ... | head -3``: the pipe closed by its reader made rich's table (or typer's echo) exit 1 after the
    results were written, as a failure. Every command ends as a shell tool does instead: exit 141 (128 + SIGPIPE),
    nothing on stderr but what it said before; ``eval`` has written its results."""
    import os

    reader, writer = os.pipe()
    os.close(reader)  # the reader gone before the first line: every write to stdout breaks
    try:
        cmd = [sys.executable, "-m", "cso_runtime.cli", *(a.replace("{tmp}", str(tmp_path)) for a in args)]
        proc = subprocess.run(cmd, stdout=writer, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(writer)
    assert proc.returncode == 141, proc.stderr
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr and "error" not in proc.stderr
    if args[0] == "eval" and "--max-steps" in args:
        assert json.loads((tmp_path / "o" / "summary.json").read_text())["methods"]["greedy-dist"]["episodes"] == 2


READER_GONE_SCRIPT = """
import sys
from cso_runtime.reader_gone import ends_quietly_when_its_reader_leaves
with ends_quietly_when_its_reader_leaves():
    sys.stdout.write("a line still in Python's buffer")  # the pipe is closed: it breaks only when flushed
    {ending}
"""


@pytest.mark.parametrize(
    ("ending", "returncode", "said"),
    [
        ("raise RuntimeError('a real error')", 1, "RuntimeError: a real error"),  # a traceback, not a quiet 141
        ("raise KeyboardInterrupt", -2, "KeyboardInterrupt"),  # Ctrl-C stays Ctrl-C (Python's own: killed by SIGINT; cli.main says one line)
        ("raise SystemExit(3)", 3, ""),  # the command's own verdict (it said why on stderr)
        ("raise SystemExit(0)", 141, ""),  # click's end of a command that went well: the reader gone is all there is
        ("pass", 141, ""),
    ],
    ids=["error", "ctrl-c", "exit-3", "exit-0", "end"],
)
def test_a_reader_gone_hides_no_error_the_command_raised(tmp_path: Path, ending: str, returncode: int, said: str):
    """The flush at the end of ``ends_quietly_when_its_reader_leaves`` broke on the closed pipe while the command's
    own exception was on its way out, and the broken pipe took its place: exit 141 and nothing said, a traceback
    lost (stderr still the terminal). The reader gone answers for the broken pipe only; the command's outcome stands,
    with nothing more said at exit about the buffer."""
    import os

    script = tmp_path / "command.py"
    script.write_text(READER_GONE_SCRIPT.format(ending=ending))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # a buffered stdout, as a plain run has
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    reader, writer = os.pipe()
    os.close(reader)
    try:
        proc = subprocess.run([sys.executable, str(script)], stdout=writer, stderr=subprocess.PIPE, text=True, timeout=60, env=env)
    finally:
        os.close(writer)
    assert proc.returncode == returncode, proc.stderr
    assert said in proc.stderr and "Exception ignored" not in proc.stderr and "BrokenPipeError" not in proc.stderr
    if returncode == 141:
        assert proc.stderr == ""


def test_an_eval_into_a_log_says_what_runs_before_the_first_episode_ends(tmp_path: Path):
    """Without a terminal (``eval ... > log 2>&1``) nothing was written until the first episode ended, minutes on a
    large plan: the log now starts with what runs (episodes, methods, scenes, sensor, workers, the output folder),
    before any episode's line."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "cso_runtime.cli", "eval", "--method", "greedy-dist,random", "--maps", "generated:small:1:0",
           "--max-steps", "4", "--out", str(out), "--workers", "1"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert done.returncode in (0, 1), done.stderr
    first = done.stderr.splitlines()[0]
    assert first == (f"eval: 2 episodes, 2 methods (greedy-dist, random) x 1 scene (generated:small:1:0), lidar 180 degrees, "
                     f"sim 2d, 1 worker; results in {out}/"), done.stderr  # fmt: skip


def test_an_eval_into_a_log_with_resume_says_how_many_episodes_are_kept_and_how_many_run(tmp_path: Path):
    """``eval --resume`` into a log began "eval: 2 episodes" where one of them was kept from the earlier run: the
    count now says how many are kept and how many run (as ``--dry-run`` says it); a new folder's line is as before."""
    from cso_runtime.evaluation import eval_start_said, plan_eval

    out = tmp_path / "out"
    first = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=out, max_steps=4)
    assert eval_start_said(first, plan_eval(first)).startswith("eval: 1 episode, 1 method (greedy-dist) x 1 scene")
    run_eval(first)
    again = dataclasses.replace(first, methods=["greedy-dist", "random"], resume=True)
    said = eval_start_said(again, plan_eval(again))
    assert said.startswith("eval: 2 episodes (1 kept from the earlier run, 1 to run), 2 methods (greedy-dist, random) x 1 scene"), said


def test_progress_lines_in_a_log_are_whole_and_say_what_was_kept(capsys):
    """Without a terminal (a log file, CI) each finished episode is one line, however long its map's name,
    and an episode ``--resume`` read back says so."""
    from cso_runtime.evaluation import EpisodeOutcome, RichProgress

    progress = RichProgress(clock=lambda: 0.0)
    progress.start(2)
    row = {"coverage_pct": 99.1, "steps": 51, "terminated_by": "coverage"}
    long_name = "a_floor_plan_with_a_name_long_enough_to_pass_the_eighty_columns_of_a_log"
    progress.advance(EpisodeOutcome("greedy-dist", long_name, row=row, kept=True))
    progress.advance(EpisodeOutcome("greedy-dist", "gen_small_0", row=row))
    progress.writing(Path("results/easy"), 2)  # the plots of hundreds of plans take a while: the log says what
    progress.stop()
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == f"[1/2] greedy-dist {long_name}: 99.1% in 51 steps (coverage, kept from the earlier run)"
    assert lines[1] == "[2/2] greedy-dist gen_small_0: 99.1% in 51 steps (coverage) [0:00:00 elapsed]"
    assert lines[2] == "writing results/easy/: summary.json, episodes.csv, curves and 2 trajectory plots"


@pytest.mark.parametrize("width", [80, 200])
def test_the_eval_bar_keeps_its_count_and_times_in_an_80_column_terminal(width, capsys):
    """In an 80-column terminal the text after the bar (the last episode's result, then "writing OUT/: summary.json,
    episodes.csv, ...", 100 characters) squeezed rich's columns until the episode count read ``1…`` and the bar and
    times were gone. The text goes on a line of its own under the bar (``live_view.progress_with_stats_below``, as
    the training bar's figures), so every column of the bar keeps its width."""
    import io

    from rich.console import Console, Group

    from cso_runtime.evaluation import EpisodeOutcome, RichProgress

    progress = RichProgress(clock=lambda: 0.0)
    progress.start(12)

    def shown() -> str:
        console = Console(file=io.StringIO(), width=width, record=True)
        console.print(Group(*progress.progress.get_renderables()))
        return console.export_text()

    row = {"coverage_pct": 99.1, "steps": 51, "terminated_by": "coverage"}
    progress.advance(EpisodeOutcome("greedy-dist", "gen_small_0", row=row))
    bar = shown()
    assert "eval" in bar and "1/12" in bar and "0:00:00" in bar, bar
    assert "greedy-dist gen_small_0: 99.1% in 51 steps (coverage)" in bar, bar
    progress.writing(Path("results/eval/greedy_vs_cso_middle"), 12)
    bar = shown()
    assert "1/12" in bar and "0:00:00" in bar and "writing results/eval/greedy_vs_cso_middle/: summary.json" in bar, bar
    progress.stop()


def test_the_writing_line_of_an_eval_of_one_plan_says_one_trajectory_plot(capsys):
    """``eval --limit 1`` said "writing ...: summary.json, episodes.csv, curves and 1 trajectory plots"."""
    from cso_runtime.evaluation import RichProgress

    progress = RichProgress(clock=lambda: 0.0)
    progress.start(1)
    progress.writing(Path("results/one"), 1)
    progress.stop()
    assert capsys.readouterr().err.splitlines() == ["writing results/one/: summary.json, episodes.csv, curves and 1 trajectory plot"]


def test_a_progress_line_says_why_an_episode_found_no_frontier(capsys):
    """``no_frontier`` alone read as a bug at 93 % coverage: the line goes on with the frontier left and why."""
    from cso_runtime.evaluation import EpisodeOutcome, RichProgress

    progress = RichProgress(clock=lambda: 0.0)
    progress.start(1)
    why = "no frontier left that the robot can reach: 21 frontier cells (1.05 m) remain: 21 in 2 cluster(s) ..."
    row = {"coverage_pct": 98.3, "steps": 54, "terminated_by": "no_frontier", "ended_why": why}
    progress.advance(EpisodeOutcome("greedy-dist", "lshape", row=row))
    progress.stop()
    assert capsys.readouterr().err.splitlines()[0] == f"[1/1] greedy-dist lshape: 98.3% in 54 steps (no_frontier): {why} [0:00:00 elapsed]"


def test_progress_lines_in_a_log_say_the_time_elapsed_and_left(capsys):
    """A long eval followed in its log (nohup, CI) gets what the bar shows a terminal: the time so far and about how
    long the rest takes, at the pace of the episodes run now (those ``--resume`` kept took no time)."""
    from cso_runtime.evaluation import EpisodeOutcome, RichProgress

    now_s = [100.0]
    progress = RichProgress(clock=lambda: now_s[0])
    progress.start(5)
    row = {"coverage_pct": 99.1, "steps": 51, "terminated_by": "coverage"}
    progress.advance(EpisodeOutcome("greedy-dist", "img_1", row=row, kept=True))
    now_s[0] = 160.0
    progress.advance(EpisodeOutcome("greedy-dist", "img_2", row=row))
    now_s[0] = 220.0
    progress.advance(EpisodeOutcome("greedy-dist", "img_3"))  # failed: it took its time too
    now_s[0] = 4000.0
    progress.advance(EpisodeOutcome("greedy-dist", "img_4", row=row))
    progress.advance(EpisodeOutcome("greedy-dist", "img_5", row=row))
    progress.stop()
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "[1/5] greedy-dist img_1: 99.1% in 51 steps (coverage, kept from the earlier run)"
    assert lines[1] == "[2/5] greedy-dist img_2: 99.1% in 51 steps (coverage) [0:01:00 elapsed, about 0:03:00 left]"
    assert lines[2] == "[3/5] greedy-dist img_3: FAILED [0:02:00 elapsed, about 0:02:00 left]"
    assert lines[3] == "[4/5] greedy-dist img_4: 99.1% in 51 steps (coverage) [1:05:00 elapsed, about 0:21:40 left]"
    assert lines[4] == "[5/5] greedy-dist img_5: 99.1% in 51 steps (coverage) [1:05:00 elapsed]"


@pytest.mark.parametrize(("rows", "cols", "methods"), [(400, 60, 1), (60, 400, 1), (200, 300, 3), (200, 300, 5)])
def test_trajectory_plots_keep_every_label_and_the_key_inside_the_figure(rows: int, cols: int, methods: int):
    """A tall, a wide and a three-method figure: no title, axis label or key entry is cut off at the edge
    (the x label of wide plans once was), and each panel shows the whole plan at its own aspect ratio."""
    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import trajectory_figure

    free = np.zeros((rows, cols), dtype=bool)
    free[5:-5, 5:-5] = True
    explored = free.copy()
    explored[: rows // 2] = False
    path = np.array([[1.0, 1.0], [cols * 0.05 - 1.0, rows * 0.05 - 1.0]])
    outcomes = [
        EpisodeOutcome(f"m{i}", "plan", {"coverage_pct": 50.0, "steps": 10, "path_length_m": 3.0}, None, free, 0.05, explored, path)
        for i in range(methods)
    ]
    fig = trajectory_figure("plan", outcomes)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = {t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text") and a.get_visible())}
    assert {"x (m)", "y (m)", "plan", "explored", "free, not explored", "path", "start", "end"} <= texts
    assert {f"m{i}: 50.0% in 10 steps, 3.0 m path" for i in range(methods)} <= texts
    drawn = fig.get_tightbbox(renderer)  # inches: everything drawn, labels and key included
    width_in, height_in = fig.get_size_inches()
    assert drawn.x0 >= -0.01 and drawn.y0 >= -0.01 and drawn.x1 <= width_in + 0.01 and drawn.y1 <= height_in + 0.01, drawn
    assert len(fig.axes) == methods
    for ax in fig.axes:
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        assert (x0, y0) == (0.0, 0.0) and np.isclose(x1, cols * 0.05) and np.isclose(y1, rows * 0.05)
    # Five methods in one row were a strip too wide to read in the report: at most three panels a row.
    assert len({round(ax.get_position().x0, 3) for ax in fig.axes}) == min(methods, 3)
    assert width_in <= 3 * 7.0 + 0.4
    fig.clf()


@pytest.mark.parametrize("yaw_rad", [0.0, np.pi / 2])
def test_trajectory_plots_and_scene_previews_are_drawn_in_the_users_map_frame(yaw_rad: float):
    """A map_server scene's origin places its plan in the user's map frame: the trajectory plot and the `scenes`
    preview read there (the start where `scenes` and the YAML's `start:` put it, the map where RViz shows it), not
    in the plan's own frame from (0, 0). An asymmetric plan: a free cell at the plan's lower-left corner only."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.geometry import Pose2D
    from cso_runtime.plots import scene_figure, trajectory_figure
    from cso_runtime.scenes import FloorPlan

    res_m, rows, cols = 0.1, 20, 40  # 4 x 2 m
    free = np.zeros((rows, cols), dtype=bool)
    free[1:5, 1:30] = True  # a corridor along the plan's bottom edge
    origin = Pose2D(-1.0, 2.0, yaw_rad)
    plan = FloorPlan("asym", free, res_m, Pose2D(0.25, 0.25, 0.0), map_origin=origin)
    start_map = plan.to_map_frame(plan.start)
    corners_map = [plan.to_map_frame(Pose2D(x, y, 0.0)) for x, y in ((0, 0), (cols * res_m, 0), (0, rows * res_m), (cols * res_m, rows * res_m))]
    bounds = (min(c.x_m for c in corners_map), max(c.x_m for c in corners_map), min(c.y_m for c in corners_map), max(c.y_m for c in corners_map))

    def image_corner_in_data(ax) -> np.ndarray:
        """Where the image's pixel of the plan's lower-left corner lands in the axes' data coordinates."""
        image = ax.get_images()[0]
        return (image.get_transform() - ax.transData).transform([(0.0, 0.0)])[0]

    path = np.array([[0.25, 0.25], [2.5, 0.3]])
    outcome = EpisodeOutcome("greedy-dist", "asym", {"coverage_pct": 90.0, "steps": 10, "path_length_m": 2.3}, None, free, res_m, free, path, map_origin=origin)
    for fig in (trajectory_figure("asym", [outcome]), scene_figure(plan)):
        ax = fig.axes[0]
        assert np.allclose(sorted(ax.get_xlim()) + sorted(ax.get_ylim()), bounds)
        assert np.allclose(image_corner_in_data(ax), [origin.x_m, origin.y_m])
        starts = [line for line in ax.lines if isinstance(line, Line2D) and line.get_marker() == "o"]
        assert np.allclose(starts[0].get_xydata()[0], [start_map.x_m, start_map.y_m])
        plt.close(fig)
    traj_fig = trajectory_figure("asym", [outcome])
    drawn_path = traj_fig.axes[0].lines[0].get_xydata()
    end_map = plan.to_map_frame(Pose2D(2.5, 0.3, 0.0))
    assert np.allclose(drawn_path[-1], [end_map.x_m, end_map.y_m])
    plt.close(traj_fig)


def test_the_efficiency_figure_shows_each_methods_mean_per_scale_and_its_change_against_the_baseline():
    """Fig. 5 of the paper from a summary: one bar per method and scale that ran (none for a scale a method
    has no episode of), and below, each non-baseline method's per-scene change with its 95 % interval."""
    from cso_runtime.plots import efficiency_figure

    def entry(values: dict[str, float]) -> dict:
        return {"by_scale": {sc: {"efficiency_m2_per_step": v} for sc, v in values.items()}}

    summary = {
        "methods": {"greedy-dist": entry({"middle": 0.4, "large": 0.6}), "cso": entry({"middle": 0.5, "large": 0.66}), "random": entry({"large": 0.2})},
        "paired": {
            "baseline": "greedy-dist",
            "comparisons": [
                {"method": "cso", "scale": "middle", "per_scene_pct": 20.0, "ci_low_pct": 10.0, "ci_high_pct": 31.0},
                {"method": "cso", "scale": "large", "per_scene_pct": 9.0, "ci_low_pct": 2.0, "ci_high_pct": 15.0},
                {"method": "random", "scale": "large", "per_scene_pct": -60.0, "ci_low_pct": -70.0, "ci_high_pct": -50.0},
            ],
        },
    }
    fig = efficiency_figure(summary)
    top, bottom = fig.axes[:2]
    assert [t.get_text() for t in top.get_xticklabels()] == ["middle", "large"]
    bars = {c.get_label(): sorted((round(p.get_x() + p.get_width() / 2, 3), p.get_height()) for p in c.patches) for c in top.containers}
    assert [h for _, h in bars["greedy-dist"]] == [0.4, 0.6] and [h for _, h in bars["cso"]] == [0.5, 0.66]
    assert [h for _, h in bars["random"]] == [0.2] and bars["random"][0][0] > 0.5  # in the large group only
    marks, spans = {}, {}
    for container in bottom.containers:  # one errorbar per method: markers, then the interval segments
        data_line, _, (segments,) = container.lines
        marks[container.get_label()] = list(zip(np.round(data_line.get_xdata(), 3), data_line.get_ydata()))
        spans[container.get_label()] = [tuple(np.round(seg[:, 1], 3)) for seg in segments.get_segments()]
    assert set(marks) == {"cso", "random"}  # nothing for the baseline itself
    assert [y for _, y in marks["cso"]] == [20.0, 9.0] and [y for _, y in marks["random"]] == [-60.0]
    assert spans["cso"] == [(10.0, 31.0), (2.0, 15.0)] and spans["random"] == [(-70.0, -50.0)]
    # each marker sits under its method's bar
    assert [x for x, _ in marks["cso"]] == [x for x, _ in bars["cso"]] and marks["random"][0][0] == bars["random"][0][0]
    fig.clf()



def test_figures_tell_methods_apart_by_more_than_colour():
    """The default colour cycle's green and red (the third and fourth method: utility and random in ``--method
    baselines``) look alike to red-green colour-blind readers: each method's line style (coverage), hatch (efficiency
    bars) and marker (change against the baseline) differ from the others' as well."""
    import matplotlib.pyplot as plt

    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import coverage_figure, efficiency_figure

    methods = ["greedy-dist", "greedy-info", "utility", "random"]
    fig = coverage_figure([EpisodeOutcome(m, "plan", {"scale": "small"}, coverage_curve_pct=np.array([0.0, 50.0])) for m in methods], methods)
    looks = [(line.get_color(), line.get_linestyle()) for line in fig.axes[0].get_lines()]
    assert len({style for _, style in looks[2:4]}) == 2 and len(set(looks)) == len(methods)
    plt.close(fig)
    entry = {"by_scale": {"small": {"efficiency_m2_per_step": 0.3}}}
    comparisons = [
        {"scale": "small", "method": m, "per_scene_pct": 5.0, "ci_low_pct": -1.0, "ci_high_pct": 9.0} for m in methods[1:]
    ]
    fig = efficiency_figure({"methods": dict.fromkeys(methods, entry), "paired": {"baseline": "greedy-dist", "comparisons": comparisons}})
    top, bottom = fig.axes[:2]
    assert len({bars.patches[0].get_hatch() for bars in top.containers}) == len(methods)
    markers = [c.lines[0].get_marker() for c in bottom.containers]
    assert len(set(markers)) == len(methods) - 1
    assert [t.get_text() for t in bottom.get_legend().get_texts()] == methods[1:]
    plt.close(fig)


def test_an_episode_of_no_step_is_drawn_not_left_an_empty_plot():
    """A plan whose first scan saw everything ends in 0 steps: its coverage curve is one point, which a line without
    a marker left invisible, and it has no m2/step, which left the efficiency figure an empty frame running to
    negative m2/step. The point is marked and the bar's place says why it is empty."""
    import matplotlib.pyplot as plt

    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import coverage_figure, efficiency_figure

    fig = coverage_figure([EpisodeOutcome("greedy-dist", "tiny", {"scale": "small"}, coverage_curve_pct=np.array([100.0]))])
    (line,) = fig.axes[0].get_lines()
    assert line.get_marker() not in ("", "None", None)
    plt.close(fig)
    summary = {"methods": {"greedy-dist": {"by_scale": {"small": {"efficiency_m2_per_step": None}}}}, "paired": {"baseline": "greedy-dist", "comparisons": []}}
    fig = efficiency_figure(summary)
    (top,) = fig.axes
    assert top.get_ylim()[0] == 0.0 and "no step" in [t.get_text() for t in top.texts]
    plt.close(fig)



def test_pyplot_is_imported_in_the_background_on_the_agg_backend_for_figures_drawn_later():
    """The launcher starts ``import_pyplot_in_background`` once its services are spawned, and draws the episode's
    figures once it ends: pyplot's import (about 1 s) is then done, on Agg (files only). Checked in a fresh process,
    where nothing imported matplotlib before: the launcher's own start does not."""
    script = (
        "import sys, threading\n"
        "import cso_runtime.launcher\n"
        "from cso_runtime.plots import import_pyplot_in_background\n"
        "assert 'matplotlib' not in sys.modules\n"
        "thread = import_pyplot_in_background()\n"
        "assert isinstance(thread, threading.Thread) and thread.daemon\n"
        "thread.join()\n"
        "import matplotlib\n"
        "print('matplotlib.pyplot' in sys.modules, matplotlib.get_backend().lower())\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env={k: v for k, v in os.environ.items() if k != "MPLBACKEND"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "agg"]

def test_the_coverage_figures_step_is_the_period_the_episodes_ran_with_or_a_real_robots_scan():
    """The x axis said "step (0.25 s)" whatever the step was: a run with another ``robot.control_period_s``, or a
    run of ``up`` on a real LIMO, whose steps are its scans (about 10 Hz, no simulated time: ``sim_time_s`` null)."""
    import matplotlib.pyplot as plt

    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import coverage_figure

    def xlabel(row: dict) -> str:
        fig = coverage_figure([EpisodeOutcome("greedy-dist", "plan", {"scale": "small", **row}, coverage_curve_pct=np.array([0.0, 50.0]))])
        label = fig.axes[0].get_xlabel()
        plt.close(fig)
        return label.split(";")[0]

    assert xlabel({"steps": 40, "sim_time_s": 10.0}) == "step (0.25 s)"
    assert xlabel({"steps": 40, "sim_time_s": 4.0}) == "step (0.1 s)"
    assert xlabel({"steps": 40, "sim_time_s": None}) == "step (a scan of the real robot)"
    assert xlabel({"steps": 40}) == "step (0.25 s)"  # a row of an older run: the default period


def test_the_paired_figure_gives_each_scale_one_colour_in_every_panel(monkeypatch, tmp_path: Path):
    """Each panel took its own colour cycle: a method without a small scene showed its middle scenes in the small
    scenes' colour of the panel beside it."""
    import matplotlib.colors as mcolors

    from cso_runtime import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path, dpi: figures.append(fig))
    table = {
        ("greedy-dist", "small"): {("a",): 1.0, ("b",): 1.1}, ("greedy-dist", "middle"): {("c",): 0.5, ("d",): 0.6},
        ("cso", "small"): {("a",): 1.2, ("b",): 1.0}, ("cso", "middle"): {("c",): 0.6, ("d",): 0.5},
        ("utility", "middle"): {("c",): 0.4, ("d",): 0.7},
    }
    plots.plot_paired_efficiency(tmp_path / "p.png", table, "greedy-dist")
    (fig,) = figures
    colours = {ax.get_title().split()[0]: {c.get_label().split()[0]: mcolors.to_hex(c.get_facecolor()[0]) for c in ax.collections} for ax in fig.axes}
    assert colours["cso"]["middle"] == colours["utility"]["middle"] != colours["cso"]["small"]
    fig.clf()


def test_the_paired_figures_titles_are_inside_the_picture(tmp_path: Path):
    """In a figure 4.2 in high, three square panels or more were limited by its height, and the paired figure's titles were cut at the
    top edge of the PNG ("greedy-info against greedy-dist" of an eval of the four baselines): the top rows of the
    picture are the background, not a title's letters."""
    from PIL import Image

    from cso_runtime import plots

    methods = ["greedy-dist", "greedy-info", "utility", "random"]
    efficiency = {"greedy-dist": (1.82, 4.95, 0.72), "greedy-info": (1.67, 4.92, 0.73), "utility": (1.56, 3.31, 0.72), "random": (1.82, 4.95, 1.02)}
    table = {(m, "small"): {(scene,): e for scene, e in zip("abc", values)} for m, values in efficiency.items()}
    plots.plot_paired_efficiency(tmp_path / "paired.png", table, "greedy-dist", methods)
    grey = np.asarray(Image.open(tmp_path / "paired.png").convert("L"))
    assert (grey[:3] > 200).all(), [int((row <= 200).sum()) for row in grey[:3]]


def test_coverage_curves_get_one_panel_per_scale_when_the_episodes_span_several():
    """Fig. 4: each method's mean curve (episodes held at their final value), one panel per scale in the paper's
    order, one method one colour in every panel; a run of one scale keeps a single panel."""
    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import coverage_figure

    def outcome(method: str, scale: str, curve: list[float]) -> EpisodeOutcome:
        return EpisodeOutcome(method, "plan", {"scale": scale}, coverage_curve_pct=np.array(curve))

    outcomes = [
        outcome("cso", "super_large", [0.0, 50.0, 100.0]),
        outcome("greedy-dist", "middle", [0.0, 40.0]),
        outcome("cso", "middle", [0.0, 60.0, 80.0, 90.0]),
        outcome("cso", "middle", [0.0, 20.0]),
    ]
    fig = coverage_figure(outcomes)
    assert [ax.get_title() for ax in fig.axes] == ["Coverage against step: middle", "Coverage against step: super large"]
    middle = {line.get_label(): line for line in fig.axes[0].get_lines()}
    assert set(middle) == {"greedy-dist (1 ep.)", "cso (2 ep.)"}
    np.testing.assert_allclose(middle["cso (2 ep.)"].get_ydata(), [0.0, 40.0, 50.0, 55.0])  # the short one held at 20
    (large,) = fig.axes[1].get_lines()
    assert large.get_label() == "cso (1 ep.)" and large.get_color() == middle["cso (2 ep.)"].get_color() != middle["greedy-dist (1 ep.)"].get_color()
    fig.clf()
    # With the run's method order, each method has the efficiency figure's colour (C0, C1, ... in summary.json's
    # order), whichever finished first (--resume, --workers).
    ordered = coverage_figure(outcomes, ["greedy-dist", "cso"])
    colours = {line.get_label(): line.get_color() for line in ordered.axes[0].get_lines()}
    assert colours == {"greedy-dist (1 ep.)": "C0", "cso (2 ep.)": "C1"}
    # and its key lists them in that order too, as the efficiency figure's (it listed them as their episodes finished)
    assert [t.get_text() for t in ordered.axes[0].get_legend().get_texts()] == ["greedy-dist (1 ep.)", "cso (2 ep.)"]
    ordered.clf()
    reordered = coverage_figure(outcomes, ["cso", "greedy-dist"])
    assert [t.get_text() for t in reordered.axes[0].get_legend().get_texts()] == ["cso (2 ep.)", "greedy-dist (1 ep.)"]
    reordered.clf()
    single = coverage_figure(outcomes[1:])
    assert [ax.get_title() for ax in single.axes] == ["Coverage against step on plan"]  # one plan: named (a run of up)
    single.clf()


def test_an_animation_has_a_frame_per_decision_and_the_final_map_and_stays_bounded(tmp_path: Path):
    """``eval --animate``: one GIF frame after each decision plus the final map (the path on it, the robot at its
    last pose); a long episode's frames are thinned to every other decision, and so on, below ``max_frames``.
    The episode itself is the one without the animation."""
    from PIL import Image

    from cso_runtime import frames
    from cso_runtime.animation import EpisodeAnimation

    plan = resolve_scenes("generated:small:1:3")[0].load()
    cfg = ExplorationConfig()
    plain = run_episode(KinematicSimulator(plan, seed=0), make_policy("greedy-dist"), cfg, seed=0)
    full, thinned = EpisodeAnimation(), EpisodeAnimation(max_frames=4)

    def both(explorer) -> None:
        full.on_step(explorer)
        thinned.on_step(explorer)

    result = run_episode(KinematicSimulator(plan, seed=0), make_policy("greedy-dist"), cfg, seed=0, on_step=both)
    assert (result.steps, result.coverage_pct) == (plain.steps, plain.coverage_pct) and result.decisions > 6
    assert full.finish() and thinned.finish()
    assert result.decisions <= len(full.frames) <= result.decisions + 1  # the final map, unless it is the last decision's
    assert len(thinned.frames) <= 4 and thinned.every >= 2 and np.array_equal(thinned.frames[-1], full.frames[-1])  # the final map kept
    last = frames.PALETTE[full.frames[-1]]
    rows = last.shape[0]
    scale = frames.frame_scale(plan.free.shape)
    x, y = result.trajectory_xy_m[-1]
    assert tuple(last[rows - 1 - int(y / plan.resolution_m * scale), int(x / plan.resolution_m * scale)]) in (frames.ROBOT, frames.HEADING)
    assert (full.frames[-1] == frames.I_PATH).any() and not (full.frames[0] == frames.I_PATH).all()
    assert (full.frames[0] == frames.I_FRONTIER).any() and not (full.frames[-1] == frames.I_FRONTIER).any()  # F_t at decisions
    gif = full.save_gif(tmp_path / "a" / "ep.gif")
    with Image.open(gif) as im:
        assert im.n_frames == len(full.frames) and im.size == (last.shape[1], rows)
        im.seek(im.n_frames - 1)
        assert np.array_equal(np.asarray(im.convert("RGB")), last)
    assert not EpisodeAnimation().finish()  # no step taken: nothing to animate

    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:3", out_dir=tmp_path / "o", max_steps=40, animate=True))
    assert summary["methods"]["greedy-dist"]["episodes"] == 1
    with Image.open(tmp_path / "o" / "animations" / "greedy-dist" / "gen_small_3.gif") as im:
        assert im.n_frames >= 2
    page = (tmp_path / "o" / "report.html").read_text()
    assert '<img src="animations/greedy-dist/gen_small_3.gif"' in page
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    (tmp_path / "o" / "report.html").unlink()
    r = CliRunner().invoke(app, ["report", str(tmp_path / "o")])  # the page again, from the folder alone
    assert r.exit_code == 0 and (tmp_path / "o" / "report.html").read_text() == page
    r = CliRunner().invoke(app, ["report", str(tmp_path / "nothing")])
    assert r.exit_code == 2 and f"error: {tmp_path / 'nothing' / 'summary.json'}: No such file" in r.output and "not an `eval --out` folder" in r.output
    r = CliRunner().invoke(app, ["report", str(tmp_path / "o" / "summary.json")])  # the file, not its folder: said so
    assert r.exit_code == 2 and f"report takes the folder that holds summary.json: cso-runtime report {tmp_path / 'o'}" in " ".join(r.output.split()), r.output
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    for broken in ({**summary, "methods": {"greedy-dist": "oops"}}, {**summary, "paired": "x"}):
        (tmp_path / "odd").mkdir(exist_ok=True)
        (tmp_path / "odd" / "summary.json").write_text(json.dumps(broken))
        r = CliRunner().invoke(app, ["report", str(tmp_path / "odd")])
        assert r.exit_code == 2 and "not a summary eval or up wrote" in r.output, r.output
    gif = tmp_path / "o" / "animations" / "greedy-dist" / "gen_small_3.gif"
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:3", out_dir=tmp_path / "o", max_steps=40, resume=True))
    assert gif.is_file(), "an episode --resume keeps keeps its animation"
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:3", out_dir=tmp_path / "o", max_steps=30, overwrite=True))
    assert not gif.exists() and "gen_small_3.gif" not in (tmp_path / "o" / "report.html").read_text(), "a new episode, not animated"


def test_resume_gives_an_animated_episode_its_own_gif_and_never_another_runs(tmp_path: Path):
    """``kill -9`` of ``eval --animate`` between an episode's two files kept it on ``--resume`` without its GIF, or
    beside a GIF another run wrote (another configuration's, written before the kill). ``--resume --animate`` runs
    such an episode again, which writes its own GIF; without ``--animate`` a GIF that is not the episode's is removed."""
    import hashlib

    from cso_runtime.evaluation import read_held_episode, run_eval_cli

    out, other = tmp_path / "o", tmp_path / "other"
    request = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:3", out_dir=out, max_steps=12)
    run_eval(request)  # not animated: as a run killed between its episode file and its GIF leaves it
    npz, gif = out / "episodes" / "greedy-dist" / "gen_small_3.npz", out / "animations" / "greedy-dist" / "gen_small_3.gif"
    assert not gif.exists()
    run_eval(dataclasses.replace(request, resume=True, animate=True))
    assert gif.is_file(), "an episode --resume --animate keeps has its GIF"
    own = gif.read_bytes()
    assert read_held_episode(npz).animation_sha256 == hashlib.sha256(own).hexdigest()

    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:3", out_dir=other, max_steps=6, animate=True))
    foreign = (other / "animations" / "greedy-dist" / "gen_small_3.gif").read_bytes()
    assert foreign != own
    gif.write_bytes(foreign)  # another configuration's GIF, its episode file never written: the kill came between
    stamp = npz.stat().st_mtime_ns
    run_eval(dataclasses.replace(request, resume=True, animate=True))
    assert gif.read_bytes() == own and npz.stat().st_mtime_ns != stamp, "run again: its own GIF, not the other run's"
    gif.write_bytes(foreign)
    assert run_eval_cli(dataclasses.replace(request, resume=True), dry_run=True) == 0 and gif.read_bytes() == foreign  # writes nothing
    summary = run_eval(dataclasses.replace(request, resume=True))
    assert summary["meta"]["resumed_episodes"] == 1 and not gif.exists(), "kept, without a GIF that is not its own"


def test_eval_removes_the_partial_files_a_killed_eval_left_and_never_reads_them(tmp_path: Path):
    """``kill -9`` while an episode file was written left ``<map>.partial.npz`` in the results folder for good (and
    that name is the episode file of a plan named ``<map>.partial``). Files are written under a hidden name no
    episode has; an eval (``--resume`` or not) removes those a killed eval left, and the old ``<map>.partial.npz``."""
    from cso_runtime.outputs import episode_npz_path, partial_path

    out = tmp_path / "o"
    assert partial_path(episode_npz_path(out, "cso", "plan")) != episode_npz_path(out, "cso", "plan.partial")
    assert not partial_path(episode_npz_path(out, "cso", "plan")).name.endswith(".npz")
    request = EvalRequest(methods=["greedy-dist"], maps="generated:small:2:0", out_dir=out, max_steps=6)
    run_eval(request)
    folder, gifs = out / "episodes" / "greedy-dist", out / "animations" / "greedy-dist"
    gifs.mkdir(parents=True)
    for again in (dataclasses.replace(request, resume=True), request):
        stale = [folder / "gen_small_0.partial.npz", partial_path(folder / "gen_small_1.npz"), partial_path(gifs / "gen_small_0.gif"),
                 partial_path(out / "summary.json")]  # and summary.json's or episodes.csv's (write_text_atomic), beside them
        for path in stale:
            path.write_bytes(b"PK\x03\x04 cut short by kill -9")
        summary = run_eval(again)
        assert summary["methods"]["greedy-dist"]["episodes"] == 2 and not summary["failures"]
        assert not [path for path in stale if path.exists()]
    assert sorted(p.name for p in folder.iterdir()) == ["gen_small_0.npz", "gen_small_1.npz"]


def test_an_eval_of_some_plans_keeps_the_episode_of_a_plan_named_as_an_old_partial_file(tmp_path: Path):
    """The clean-up of the old ``<map>.partial.npz`` removed, beside each episode this eval ran, the file of that name
    whatever it was: the finished episode of a plan named ``<map>.partial`` that an earlier eval ran into the folder,
    when this one leaves that plan out. A file that reads whole as that plan's episode is a result, and stays."""
    maps = tmp_path / "maps"
    maps.mkdir()
    corridor = _corridor_scene(maps, "corridor", "[1.5, 0.18, -0.5]")
    _corridor_scene(maps, "corridor.partial", "[1.5, 0.18, -0.5]")
    out = tmp_path / "o"
    run_eval(EvalRequest(methods=["greedy-dist"], maps=str(maps), out_dir=out, max_steps=5))
    theirs = out / "episodes" / "greedy-dist" / "corridor.partial.npz"
    assert theirs.is_file()
    run_eval(EvalRequest(methods=["greedy-dist"], maps=str(corridor), out_dir=out, max_steps=5))
    assert theirs.is_file(), "an episode of the earlier eval, removed as an old partial file"
    theirs.write_bytes(b"PK\x03\x04 cut short by kill -9")  # an old partial file indeed: removed
    run_eval(EvalRequest(methods=["greedy-dist"], maps=str(corridor), out_dir=out, max_steps=5))
    assert not theirs.exists()


def test_the_report_shows_each_methods_final_map_and_gives_each_picture_one_caption(tmp_path: Path):
    """The Maps section shows, beside the trajectories and animations, the robot's final map of each method as
    map_server serves it, linked to its YAML; every picture has its own caption (a ``<figure>`` holds one
    ``<figcaption>``: the animations' captions were all in the plan's figure), and every file the page shows or
    links is in the folder, by a relative path."""
    from html.parser import HTMLParser

    out = tmp_path / "o"
    run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:1:0", out_dir=out, max_steps=8, animate=True))
    page = (out / "report.html").read_text()

    class Figures(HTMLParser):
        def __init__(self) -> None:
            super().__init__()
            self.open: list[int] = []  # captions seen so far in each figure open now
            self.captions: list[int] = []
            self.refs: list[str] = []

        def handle_starttag(self, tag: str, attrs: list) -> None:
            self.refs += [v for k, v in attrs if k in ("src", "href")]
            if tag == "figure":
                self.open.append(0)
            elif tag == "figcaption":
                self.open[-1] += 1

        def handle_endtag(self, tag: str) -> None:
            if tag == "figure":
                self.captions.append(self.open.pop())

    parser = Figures()
    parser.feed(page)
    assert parser.captions and max(parser.captions) == 1, parser.captions
    assert not parser.open
    for method in ("greedy-dist", "random"):
        assert f'<img src="maps/{method}/gen_small_0.png"' in page
        assert f'<a href="maps/{method}/gen_small_0.yaml">' in page
        assert f"{method}, animated</figcaption>" in page
    assert all((out / ref).is_file() for ref in parser.refs), parser.refs


def test_summary_and_run_files_are_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """``write_text_atomic``: a reader sees the old file or the new one, never half of either, and a
    failed write leaves the old file and no stray temporary beside it."""
    import os

    from cso_runtime.outputs import write_text_atomic

    path = tmp_path / "summary.json"
    write_text_atomic(path, '{"old": 1}')
    write_text_atomic(path, '{"new": 2}')
    assert path.read_text() == '{"new": 2}' and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]

    def crash(*_args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="disk full"):
        write_text_atomic(path, '{"half": 3}')
    assert path.read_text() == '{"new": 2}' and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_an_eval_into_a_folder_of_other_methods_says_it_replaces_their_summary(tmp_path, caplog):
    from cso_runtime.evaluation import methods_summarized_elsewhere

    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "o", max_steps=5))
    assert methods_summarized_elsewhere(tmp_path / "o", ["greedy-dist"]) == []
    assert methods_summarized_elsewhere(tmp_path / "nothing", ["random"]) == []
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["random"], maps="generated:small:1:0", out_dir=tmp_path / "o", max_steps=5))
    assert "holds the results of greedy-dist: this run's summary.json and episodes.csv replace them" in caplog.text


def test_an_eval_of_other_seeds_into_a_pooled_folder_says_it_replaces_its_summary(tmp_path, caplog):
    """``eval --seeds 2`` into the folder of ``--seeds 0,1`` replaced the pooled summary.json and episodes.csv with
    seed 2's alone, and said nothing (as ``--seeds`` of other methods into a pooled folder of other seeds): it warns
    as an eval of other methods does (``methods_summarized_elsewhere``), and says how to pool every seed."""
    common = {"maps": "generated:small:1:0", "out_dir": tmp_path / "o", "max_steps": 5}
    run_eval(EvalRequest(methods=["greedy-dist"], seeds=[0, 1], **common))
    assert not [w for w in plan_eval(EvalRequest(methods=["greedy-dist"], seeds=[0, 1], **common)).warnings if "holds the results" in w]
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["greedy-dist"], seeds=[1, 2], **common))
    assert f"{tmp_path / 'o'} holds the results of seed(s) 0 pooled: this run's summary.json and episodes.csv replace them" in caplog.text
    assert "--seeds 0,1,2 --resume pools them all" in caplog.text
    said = plan_eval(EvalRequest(methods=["random"], seeds=[3], **common)).warnings
    assert f"{tmp_path / 'o'} holds the results of greedy-dist: this run's summary.json and episodes.csv replace them" in said[0]
    assert "holds the results of seed(s) 1, 2 pooled" in said[1]


def test_an_eval_of_fewer_plans_into_a_folder_says_its_tables_leave_the_others_out(tmp_path, caplog):
    """Running one plan again into an eval's folder (a failed one, or to check it) rewrites summary.json and
    episodes.csv with that plan alone: say so, and how to run episodes again in place (--resume)."""
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:2:0", out_dir=tmp_path / "o", max_steps=5))
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:1", out_dir=tmp_path / "o", max_steps=5))
    assert "holds episodes of 1 plan(s) this run leaves out (gen_small_0)" in caplog.text and "--resume" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):  # the same plans again, or more: nothing is left out
        run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:2:0", out_dir=tmp_path / "o", max_steps=5, resume=True))
    assert "leaves out" not in caplog.text


@pytest.mark.parametrize(("rows", "cols", "methods"), [(96, 78, 3), (480, 640, 3), (200, 300, 3), (400, 60, 5)])
def test_trajectory_plots_keep_the_plans_name_clear_of_the_panel_titles(rows: int, cols: int, methods: int):
    """The plan's name above the panels never overlaps a panel's title: with an odd number of methods it sits
    right over the middle panel's, and one layout pass of fixed-aspect panels with the key below once put them
    on top of each other (a small generated plan with three methods)."""
    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import trajectory_figure

    free = np.zeros((rows, cols), dtype=bool)
    free[5:-5, 5:-5] = True
    path = np.array([[1.0, 1.0], [cols * 0.05 - 1.0, rows * 0.05 - 1.0]])
    row = {"coverage_pct": 100.0, "steps": 21, "path_length_m": 2.2}
    outcomes = [EpisodeOutcome(f"greedy-{i}", "gen_small_2", row, None, free, 0.05, free.copy(), path) for i in range(methods)]
    fig = trajectory_figure("gen_small_2", outcomes)
    fig.savefig(io.BytesIO(), format="png", dpi=100)  # as eval writes it: the layout of that one draw
    renderer = fig.canvas.get_renderer()
    name = fig.get_suptitle() and fig._suptitle.get_window_extent(renderer)
    assert name
    for ax in fig.axes:
        title = ax.title.get_window_extent(renderer)
        assert title.y1 <= name.y0 or title.x1 <= name.x0 or title.x0 >= name.x1, (ax.get_title(), title, name)
    fig.clf()


def test_eval_of_a_learned_method_the_weights_folder_lacks_names_those_it_holds(tmp_path, monkeypatch):
    """``train --variant cso-sm --out RUN`` then ``eval --method cso --weights RUN``: the error said only that RUN has
    no cso.pt and to train one, not that RUN's weights are cso-sm's, to run with ``--method cso-sm``."""
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV

    unset_weights_env(monkeypatch)  # a CSO_WEIGHTS_FILE of the developer's would take cso's place
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(Path(cso_runtime.__file__).parent / "data" / "weights" / "cso-sm.pt", run / "cso-sm.pt")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    with pytest.raises(ConfigError, match=r"no weights for cso in .*\(cso\.pt\); it holds those of cso-sm \(--method cso-sm\)"):
        EvalRequest(methods=["cso"], maps="builtin", out_dir=tmp_path / "o").validate()
    (run / "cso-sm.pt").unlink()
    with pytest.raises(ConfigError, match=r"\(cso\.pt\); train with `cso-runtime train --variant NAME`"):
        EvalRequest(methods=["cso"], maps="builtin", out_dir=tmp_path / "o").validate()


def test_eval_warns_when_weights_were_trained_with_another_field_of_view(tmp_path, monkeypatch, caplog):
    """configs/train.yaml trains with the 360-degree LiDAR and eval runs the LIMO's 180-degree one unless told:
    `train --out RUN` then `eval --method cso --weights RUN` ran the policy with a sensor it never saw, silently.
    The run's record beside the weights (``cso.json``) says its sensor; eval warns, naming the flag that matches it,
    and says nothing where the sensors match or no record says."""
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, sensor_mismatches, weights_path

    unset_weights_env(monkeypatch)
    lidar180, lidar360 = SensorConfig(), SensorConfig.preset("lidar", 360)
    assert sensor_mismatches(["cso"], lidar180) == sensor_mismatches(["cso"], lidar360) == []  # cso@fov180.pt, cso.pt
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(weights_path("cso", lidar360), run / "cso.pt")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    assert sensor_mismatches(["cso"], lidar180) == []  # no record: nothing to say
    (run / "cso.json").write_text(json.dumps({"variant": "cso", "args": {"sensor": "lidar", "lidar_fov_deg": 360.0}}))
    (warning,) = sensor_mismatches(["cso"], lidar180)
    assert warning == (
        f"the weights of cso were trained with a 360-degree sensor ({run / 'cso.json'}), this run's sees 180 degrees;"
        " eval --lidar-fov 360 runs it with that sensor"
    )
    assert sensor_mismatches(["cso"], lidar360) == []
    assert sensor_mismatches(["cso"], SensorConfig.preset("depth"))[0].endswith("this run's sees 79 degrees")  # no --lidar-fov hint
    (run / "cso.json").write_text(json.dumps({"variant": "cso", "args": {"sensor": "depth", "lidar_fov_deg": None}}))  # train --set sensor=depth
    (depth,) = sensor_mismatches(["cso"], lidar180)
    assert depth == (
        f"the weights of cso were trained with a 79-degree sensor ({run / 'cso.json'}), this run's sees 180 degrees;"
        " eval --sensor depth runs it with that sensor"
    )
    assert sensor_mismatches(["cso"], SensorConfig.preset("depth")) == []
    (run / "cso.json").write_text(json.dumps({"variant": "cso", "args": {"sensor": "lidar", "lidar_fov_deg": 360.0}}))
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=tmp_path / "o", max_steps=5))
    assert f"{warning} (a policy does best with the sensor it was trained with)" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=tmp_path / "o360", max_steps=5, lidar_fov_deg=360.0))
    assert "trained with" not in caplog.text


def _eval_with_weights(given: Path, out: Path, methods: str = "cso") -> tuple[int, str, dict]:
    """``eval --method METHODS --weights GIVEN`` on one small scene with the LIMO's 180-degree LiDAR, in this process
    (the caller's monkeypatch puts back the environment ``--weights`` sets): its exit code, output, ``meta.weights``."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    r = CliRunner().invoke(app, ["eval", "--method", methods, "--weights", str(given), "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(out)])
    summary = out / "summary.json"
    return r.exit_code, r.output, json.loads(summary.read_text())["meta"]["weights"] if summary.is_file() else {}


def test_eval_weights_file_runs_exactly_that_file_whatever_the_sensor(tmp_path, monkeypatch, caplog):
    """``eval --method cso --weights cso_runtime/data/weights/cso.pt`` with the 180-degree LiDAR ran ``cso@fov180.pt``
    beside it (the file stood for its folder), and summary.json recorded that other file: the file named is now the
    file run and recorded, with a warning that it was trained with another field of view (its ``cso.json``: 360)."""
    import hashlib

    unset_weights_env(monkeypatch)
    shipped = Path(cso_runtime.__file__).parent / "data" / "weights"
    assert (shipped / "cso@fov180.pt").is_file()  # the file a folder would take for this sensor
    with caplog.at_level("WARNING"):
        code, output, weights = _eval_with_weights(shipped / "cso.pt", tmp_path / "file")
    assert code == 0, output
    assert weights["cso"]["path"] == str((shipped / "cso.pt").resolve()) and not weights["cso"]["shipped"]
    assert weights["cso"]["sha256"] == hashlib.sha256((shipped / "cso.pt").read_bytes()).hexdigest()
    assert "the weights of cso were trained with a 360-degree sensor" in caplog.text and "this run's sees 180 degrees" in caplog.text
    # One method's file for another learned method too: refused, not the shipped weights for that one unasked.
    code, output, _ = _eval_with_weights(shipped / "cso.pt", tmp_path / "two", "greedy-dist,cso,cso-sm")
    assert code == 2 and "the weights of cso alone, not of cso-sm" in output, output
    assert not (tmp_path / "two").exists()


def test_eval_weights_folder_still_takes_the_sensors_own_file(tmp_path, monkeypatch):
    """``--weights FOLDER`` is as it was: each method's ``<method>@fov<deg>.pt`` for a sensor of that field of view
    where the folder holds one, else its ``<method>.pt``."""
    import hashlib

    unset_weights_env(monkeypatch)
    shipped = Path(cso_runtime.__file__).parent / "data" / "weights"
    code, output, weights = _eval_with_weights(shipped, tmp_path / "folder")
    assert code == 0, output
    assert weights["cso"]["path"] == str((shipped / "cso@fov180.pt").resolve()) and not weights["cso"]["shipped"]
    assert weights["cso"]["sha256"] == hashlib.sha256((shipped / "cso@fov180.pt").read_bytes()).hexdigest()
    run = tmp_path / "run"  # a folder of cso.pt alone: that file, for this sensor too
    run.mkdir()
    shutil.copy(shipped / "cso.pt", run / "cso.pt")
    code, output, weights = _eval_with_weights(run, tmp_path / "alone")
    assert code == 0, output
    assert weights["cso"]["path"] == str((run / "cso.pt").resolve())


def test_eval_warns_when_weights_were_trained_under_other_stuck_mask_settings(tmp_path, monkeypatch, caplog):
    """``train --set stuck_avoid=goals --set mask_conflict=stuck --out RUN`` then ``eval --method cso --weights RUN``
    ran the policy under eval's own stuck mask (positions, distance) with no word, though the run's record says how it
    was trained. eval warns, naming the ``--set`` that runs it as trained; nothing once given, nothing for a setting
    the variant's masks do not use (cso-vdm has no stuck mask), nothing without a record or from a record that
    predates the settings (the shipped weights')."""
    from cso_runtime.config import MaskConfig
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, mask_mismatches, weights_path

    unset_weights_env(monkeypatch)
    lidar360 = SensorConfig.preset("lidar", 360)
    assert mask_mismatches(["cso", "cso-vdm"], MaskConfig(stuck_avoid="goals", conflict="stuck"), lidar360) == []  # shipped
    run = tmp_path / "run"
    run.mkdir()
    for name in ("cso", "cso-vdm"):
        shutil.copy(weights_path(name, lidar360), run / f"{name}.pt")
        trained = {"sensor": "lidar", "lidar_fov_deg": 360.0, "stuck_avoid": "goals", "mask_conflict": "stuck", "beta_far_m": 2.0}
        (run / f"{name}.json").write_text(json.dumps({"variant": name, "args": {"variant": name, **trained}}))
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    (warning,) = mask_mismatches(["cso", "cso-vdm"], MaskConfig(), lidar360)
    assert warning == (
        f"the weights of cso were trained with masks.stuck_avoid=goals, masks.conflict=stuck ({run / 'cso.json'}), this run's are"
        " positions, distance; --set masks.stuck_avoid=goals --set masks.conflict=stuck runs them as trained"
    )
    assert mask_mismatches(["cso"], MaskConfig(stuck_avoid="goals", conflict="stuck"), lidar360) == []
    (up,) = mask_mismatches(["cso"], MaskConfig(stuck_avoid="goals"), lidar360, prefix="exploration.")  # up's --set keys
    assert up.endswith("this run's are distance; --set exploration.masks.conflict=stuck runs them as trained")
    eval_360 = {"maps": "generated:small:1:0", "max_steps": 5, "lidar_fov_deg": 360.0}
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["cso", "cso-vdm"], out_dir=tmp_path / "o", **eval_360))
    assert f"{warning} (a policy does best with the masks it was trained under)" in caplog.text
    assert "cso-vdm were trained" not in caplog.text
    caplog.clear()
    as_trained = {"masks.stuck_avoid": "goals", "masks.conflict": "stuck"}
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["cso"], out_dir=tmp_path / "o2", settings=as_trained, **eval_360))
    assert "trained" not in caplog.text


def test_the_report_says_a_run_was_interrupted_what_it_ran_with_and_how_each_metric_is_computed(tmp_path: Path):
    """report.html is read on its own (sent to a colleague): a Table 1 of an interrupted eval says it covers only
    the episodes that finished; the header gives the sensor's field of view and the step limit, the two settings
    that decide whether a table compares with the paper's (360 degrees, 3000 steps); each column is defined."""
    from cso_runtime.evaluation import summarize
    from cso_runtime.report import write_report

    row = {"method": "greedy-dist", "map": "img_1", "seed": 0, "traversable_area_m2": 150.0, "scale": "large", "terminated_by": "coverage",
           "explored_area_m2": 150.0, "coverage_pct": 99.5, "steps": 1500, "efficiency_m2_per_step": 0.1, "path_length_m": 10.0,
           "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}
    meta = {"command": "cso-runtime eval", "config": to_dict(ExplorationConfig()), "interrupted": {"episodes_finished": 1, "episodes_planned": 4}}
    meta["config"]["sensor"]["fov_deg"] = 360.0
    page = write_report(tmp_path, summarize([row], [], ["greedy-dist"], meta)).read_text()
    assert "Interrupted: 1 of 4 episodes finished" in page and "--resume" in page
    assert "sensor field of view: 360 degrees" in page and f"step limit: {ExplorationConfig().episode.max_steps}" in page
    for column in ("explored m2", "coverage %", "steps", "m2/step", "path m", "decision ms p50/p99"):
        assert f"<dt>{column}</dt>" in page
    del meta["interrupted"]
    assert "Interrupted" not in write_report(tmp_path, summarize([row], [], ["greedy-dist"], meta)).read_text()


def _definitions(folder: Path, meta: dict, sim_time_s: float | None) -> dict[str, str]:
    """report.html's definitions under Table 1 (column -> words), for one episode of a run with ``meta``."""
    from cso_runtime.evaluation import summarize
    from cso_runtime.report import write_report

    row = {"method": "greedy-dist", "map": "img_1", "seed": 0, "traversable_area_m2": 150.0, "scale": "large", "terminated_by": "coverage",
           "explored_area_m2": 150.0, "coverage_pct": 99.5, "steps": 1500, "efficiency_m2_per_step": 0.1, "path_length_m": 10.0,
           "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}  # fmt: skip
    page = write_report(folder, summarize([{**row, "sim_time_s": sim_time_s}], [], ["greedy-dist"], meta)).read_text()
    return {html.unescape(c): html.unescape(d) for c, d in re.findall(r"<dt>(.*?)</dt><dd>(.*?)</dd>", page)}


def _steps_said(folder: Path, meta: dict, sim_time_s: float | None) -> str:
    """What report.html's definition under Table 1 says of steps, for one episode of a run with ``meta``."""
    return _definitions(folder, meta, sim_time_s)["steps"]


def test_the_reports_steps_are_defined_as_the_run_counted_them(tmp_path: Path):
    """The definition under Table 1 said "control periods (robot.control_period_s, 0.25 s)" whatever the run: an eval
    with ``--set robot.control_period_s=0.5`` steps every 0.5 s, and a run of ``up`` on a real LIMO counts its scans."""
    steps_said = functools.partial(_steps_said, tmp_path)
    config = to_dict(ExplorationConfig())
    assert steps_said({"config": config, "sim_settings": {}}, 375.0).startswith("control periods (robot.control_period_s, 0.25 s)")
    config["robot"]["control_period_s"] = 0.5
    assert steps_said({"config": config, "sim_settings": {}}, 750.0).startswith("control periods (robot.control_period_s, 0.5 s)")
    real_robot = {"command": "cso-runtime up", "profile": {"name": "limo-ros2"}, "config": config}  # no simulator: no sim_settings
    assert steps_said(real_robot, None).startswith("scans of the real robot")


def test_the_reports_steps_are_said_in_the_words_of_the_runs_referee(tmp_path: Path):
    """report.html said "scans of the real robot (about 10 Hz on the LIMO)" of every run of ``up`` without the sim, also
    of one whose referee is one's own (a command node publishing ``episode_status`` and ``episode_result``: a simulator
    of one's own, say), which is no real robot and whose steps are its own. Each referee's steps in their own words:
    the sim's control periods, the ROS 2 bridge's scans of the real robot, a referee of one's own's steps as it counts
    them, whether it measured coverage or not."""
    config = to_dict(ExplorationConfig())
    up = {"command": "cso-runtime up", "config": config}
    own = {"referee": {"command": ["python3", "my_referee.py"], "outputs": ["episode_status", "episode_result"]}, "mapper": {}}
    sim = _steps_said(tmp_path, {**up, "profile": {"services": {"sim": {}, "mapper": {}}}, "sim_settings": {}, "coverage_measured": True}, 375.0)
    limo = _steps_said(tmp_path, {**up, "profile": {"services": {"ros2_bridge": {}, "mapper": {}}}, "coverage_measured": False}, None)
    mine = _steps_said(tmp_path, {**up, "profile": {"services": own}, "coverage_measured": False}, None)
    assert sim.startswith("control periods (robot.control_period_s, 0.25 s)") and limo.startswith("scans of the real robot"), (sim, limo)
    assert mine.startswith("steps as the run's own referee counted them") and "real robot" not in mine and "control period" not in mine, mine
    assert _steps_said(tmp_path, {**up, "profile": {"services": own}, "coverage_measured": True}, None) == mine  # one with a ground truth of its own
    assert _steps_said(tmp_path, {**up, "profile": {"services": own}}, None) == mine  # up's summary from before meta.coverage_measured
    # and its coverage, where it measured none, is n/a for no ground truth of its own, not for a real robot's
    from cso_runtime.live_view import NO_GROUND_TRUTH, NO_OWN_GROUND_TRUTH

    said = _definitions(tmp_path, {**up, "profile": {"services": own}, "coverage_measured": False}, None)["coverage %"]
    assert said.startswith(f"{NO_OWN_GROUND_TRUTH}; ") and "real robot" not in said, said
    assert _definitions(tmp_path, {**up, "profile": {"services": {"ros2_bridge": {}}}, "coverage_measured": False}, None)["coverage %"].startswith(f"{NO_GROUND_TRUTH}; ")
    assert _definitions(tmp_path, {**up, "profile": {"services": own}, "coverage_measured": True}, None)["coverage %"] == "explored m2 over the traversable floor's m2"


def test_the_report_of_a_real_robots_run_says_its_coverage_is_na_as_status_does(tmp_path: Path):
    """report.html of a LIMO's run (``up --profile limo-ros2``) showed coverage 0.00 in Table 1, the episode table and
    a flat coverage curve, where ``status``, the live view and ``runs`` say ``n/a: a real robot (no ground truth)``:
    the report says n/a there too (the definition with the same words, the curve not shown), while summary.json and
    episodes.csv keep their 0. A simulated run's report shows its coverage as before."""
    from cso_runtime.evaluation import write_outputs
    from cso_runtime.live_view import NO_GROUND_TRUTH
    from cso_runtime.outputs import COVERAGE_FIGURE
    from cso_runtime.report import write_report

    row = {"method": "cso", "map": "real robot", "seed": 0, "traversable_area_m2": 0.0, "scale": "", "terminated_by": "no_frontier",
           "explored_area_m2": 22.6, "coverage_pct": 0.0, "steps": 196, "efficiency_m2_per_step": 22.6 / 196, "path_length_m": 10.0,
           "decision_ms_p50": 2.0, "decision_ms_p99": 3.0, "sim_time_s": None}  # fmt: skip
    config = to_dict(ExplorationConfig())

    def report(folder: Path, meta: dict, **fields) -> str:
        summary = write_outputs(folder, [{**row, **fields}], [], ["cso"], meta)
        (folder / COVERAGE_FIGURE).write_bytes(b"\x89PNG")  # as up writes it beside the report
        return write_report(folder, summary).read_text()

    page = report(tmp_path / "limo", {"command": "cso-runtime up", "profile": {"name": "limo-ros2"}, "config": config})
    table1 = page.split("<h2>Table 1</h2>")[1].split("</table>")[0]
    episodes = page.split("Every episode, scene by scene")[1].split("</table>")[0]
    assert "<td>n/a</td>" in table1 and "0.00" not in table1, table1
    assert "<td>n/a</td>" in episodes and "0.00" not in episodes, episodes
    assert page.split("<dt>coverage %</dt><dd>")[1].startswith(NO_GROUND_TRUTH)
    assert COVERAGE_FIGURE not in page and f"Coverage against step (Fig. 4): {NO_GROUND_TRUTH}" in page
    assert json.loads((tmp_path / "limo" / "summary.json").read_text())["methods"]["cso"]["coverage_pct"] == 0.0
    assert next(csv.DictReader((tmp_path / "limo" / "episodes.csv").open()))["coverage_pct"] in ("0.0", "0")

    sim = report(tmp_path / "sim", {"command": "cso-runtime up", "profile": {"name": "sim"}, "config": config, "sim_settings": {}},
                 coverage_pct=87.5, sim_time_s=49.0)  # fmt: skip
    assert "<td>87.50</td>" in sim and "n/a" not in sim and f'src="{COVERAGE_FIGURE}"' in sim


def test_eval_warns_when_its_seed_changes_no_episode(tmp_path: Path, caplog):
    """The paper runs each scene 5 times; `eval --seed 1` on the defaults (2D simulator, no range noise) repeats seed 0's
    episodes of every method but `random` exactly, and pooled by `compare` the copies pass for more scenes. Say so."""
    from cso_runtime.evaluation import seed_changes_nothing

    quiet = ExplorationConfig()
    noisy = ExplorationConfig()
    noisy.sensor.range_noise_std_m = 0.01
    assert seed_changes_nothing(["greedy-dist", "cso"], quiet, "2d")
    assert not seed_changes_nothing(["greedy-dist", "random"], quiet, "2d")
    assert not seed_changes_nothing(["greedy-dist"], noisy, "2d")
    assert not seed_changes_nothing(["greedy-dist"], quiet, "mujoco")  # its odometry drift is seeded
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "s1", max_steps=5, seed=1))
    assert "--seed 1 changes no episode here" in caplog.text and "sensor.range_noise_std_m" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "s0", max_steps=5))
    assert "changes no episode" not in caplog.text  # the default seed was not a choice


def test_summary_and_report_give_each_table_1_metrics_sample_standard_deviation(tmp_path: Path, capsys, monkeypatch):
    """Table 1 as researchers report it: mean ± the sample standard deviation (ddof=1) over the episodes, per method
    and per scale, in summary.json beside each mean (``<metric>_std``) and in report.html; one episode has no spread
    (null, not 0)."""
    from cso_runtime.evaluation import print_summary

    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:2:0", out_dir=out, max_steps=40))
    with (out / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    page = (out / "report.html").read_text()
    for method in ("greedy-dist", "random"):
        mine = [r for r in rows if r["method"] == method]
        assert len(mine) == 2 and mine[0]["explored_area_m2"] != mine[1]["explored_area_m2"]  # episodes that differ
        entry = summary["methods"][method]
        for part in (entry, entry["by_scale"]["small"]):
            assert part["episodes"] == 2
            for k in METRICS:
                assert part[f"{k}_std"] == pytest.approx(np.std([float(r[k]) for r in mine], ddof=1), abs=1e-6)
        assert entry["explored_area_m2_std"] > 0
        e = entry
        assert f"<td>{e['explored_area_m2']:.1f} ± {e['explored_area_m2_std']:.1f}</td>" in page
        assert f"<td>{e['efficiency_m2_per_step']:.4f} ± {e['efficiency_m2_per_step_std']:.4f}</td>" in page
    assert "mean ± sample standard deviation (ddof=1)" in page
    # The console off a terminal (captured here): mean ± std whatever COLUMNS says, the table as wide as its cells
    # (docs/commands.md, "Tables in a file or a pipe"); a narrow terminal's means alone are
    # test_the_console_table_shows_the_spread_when_it_fits_and_the_means_alone_when_not's.
    e = summary["methods"]["greedy-dist"]
    for columns in ("400", "80"):
        monkeypatch.setenv("COLUMNS", columns)
        print_summary(summary, out)
        said = capsys.readouterr().out
        assert f"{e['coverage_pct']:.2f} ± {e['coverage_pct_std']:.2f}" in said and "standard deviation in report.html" not in said, (columns, said)

    one = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "one", max_steps=40))
    saved = json.loads((tmp_path / "one" / "summary.json").read_text())["methods"]["greedy-dist"]
    assert one["methods"]["greedy-dist"]["episodes"] == 1
    for part in (saved, saved["by_scale"]["small"]):
        assert all(part[f"{k}_std"] is None for k in METRICS)
    assert "±" not in (tmp_path / "one" / "report.html").read_text().split("<h2>Table 1</h2>")[1].split("</table>")[0]


def test_summary_json_says_how_each_of_its_figures_aggregates_the_episodes():
    """A reader of summary.json alone (pandas, a notebook) finds in it what each figure is: a mean over the episodes,
    the sample standard deviation beside it, the bootstrap interval with its resamples and seed (those
    ``bootstrap_mean_ci`` runs with), without the docs."""
    import inspect

    from cso_runtime.comparison import bootstrap_mean_ci
    from cso_runtime.evaluation import summarize

    row = {"method": "m", "map": "a", "scale": "small", "seed": 0, "terminated_by": "coverage", **dict.fromkeys(METRICS, 1.0)}
    aggregation = json.loads(json.dumps(summarize([row], [], ["m"], meta={})))["aggregation"]
    assert set(aggregation) >= {"rows", "<metric>", "<metric>_std", "<metric>_ci95", "paired"}
    assert "mean" in aggregation["<metric>"] and "ddof=1" in aggregation["<metric>_std"]
    defaults = inspect.signature(bootstrap_mean_ci).parameters
    assert f"{defaults['resamples'].default:,} resamples" in aggregation["<metric>_ci95"]
    assert f"seed {defaults['seed'].default}" in aggregation["<metric>_ci95"]


def test_a_row_of_one_episode_shows_its_steps_as_the_whole_count_in_the_report_and_on_the_console(tmp_path: Path, capsys, monkeypatch):
    """report.html (and eval's console Table 1) showed one episode's steps as "261.0", a mean of one count, while the
    episode's own line and ``runs`` say 261; a row of two or more episodes keeps its mean with one decimal."""
    from cso_runtime.evaluation import print_summary, summarize
    from cso_runtime.report import write_report

    def row(scene: str, steps: int) -> dict:
        return {"method": "greedy-dist", "map": scene, "seed": 0, "scale": "small", "traversable_area_m2": 30.0, "terminated_by": "coverage",
                "explored_area_m2": 29.9, "coverage_pct": 99.5, "steps": steps, "efficiency_m2_per_step": 29.9 / steps, "path_length_m": 10.0,
                "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}

    monkeypatch.setenv("COLUMNS", "200")
    one = summarize([row("a", 261)], [], ["greedy-dist"], {})
    table = write_report(tmp_path, one).read_text().split("<h2>Table 1</h2>")[1].split("</table>")[0]
    assert "<td>261</td>" in table and "261.0" not in table, table
    print_summary(one, tmp_path)
    assert re.search(r"│ +261 +│", capsys.readouterr().out)
    two = summarize([row("a", 261), row("b", 262)], [], ["greedy-dist"], {})
    table = write_report(tmp_path, two).read_text().split("<h2>Table 1</h2>")[1].split("</table>")[0]
    assert "<td>261.5 ± 0.7</td>" in table, table


def test_the_console_table_shows_the_spread_when_it_fits_and_the_means_alone_when_not(tmp_path: Path, capsys, monkeypatch):
    from cso_runtime.evaluation import print_summary, summarize

    def row(m2: float) -> dict:
        return {"method": "greedy-dist", "map": f"plan_{m2}", "seed": 0, "scale": "small", "traversable_area_m2": m2, "terminated_by": "coverage", "explored_area_m2": m2, "coverage_pct": m2,
                "steps": 100, "efficiency_m2_per_step": m2 / 100, "path_length_m": 10.0, "decision_ms_p50": 2.0, "decision_ms_p99": 3.0}


    from rich.console import Console

    from cso_runtime import evaluation

    def on_a_terminal(columns: int) -> str:  # off one (capsys: a file) the table is as wide as its spreads need
        screen = TerminalFile()
        monkeypatch.setattr(evaluation, "table_console", lambda: Console(file=screen, width=columns, force_terminal=True, color_system=None))
        print_summary(summary, tmp_path)
        return screen.getvalue()

    summary = summarize([row(20.0), row(30.0)], [], ["greedy-dist"], {})
    wide = on_a_terminal(200)
    assert "│ greedy-dist │ small │        2 │  25.0 ± 7.1 │ 25.00 ± 7.07 │ 100.0 ± 0.0 │ 0.2500 ± 0.0707 │ 10.0 ± 0.0 │ 2.0 ± 0.0/3.0 ± 0.0 │" in wide
    narrow = on_a_terminal(120)
    assert "±" not in narrow.split("means over")[0]  # no cell cut in two lines
    assert "│ greedy-dist │ small │        2 │        25.0 │      25.00 │ 100.0 │  0.2500 │" in narrow
    assert "each with its standard deviation in report.html and summary.json" in narrow


def test_every_methods_mean_coverage_curve_spans_the_longest_episode_of_its_scale():
    """Fig. 4: a method whose episodes all ended early holds its final coverage to the end of the scale's longest
    episode (any method's), so that the lines compare the methods over the same steps; the axis and legend say so."""
    from cso_runtime.evaluation import EpisodeOutcome
    from cso_runtime.plots import coverage_figure

    def outcome(method: str, curve: list[float]) -> EpisodeOutcome:
        return EpisodeOutcome(method, "plan", {"scale": "small"}, coverage_curve_pct=np.array(curve))

    fig = coverage_figure([outcome("greedy-dist", [0.0, 90.0]), outcome("greedy-dist", [0.0, 50.0, 70.0]), outcome("cso", [0.0, 10.0, 20.0, 30.0, 40.0])])
    (ax,) = fig.axes
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(lines["greedy-dist (2 ep.)"].get_xdata(), [0, 1, 2, 3, 4])
    np.testing.assert_allclose(lines["greedy-dist (2 ep.)"].get_ydata(), [0.0, 70.0, 80.0, 80.0, 80.0])  # both held at their final coverage
    np.testing.assert_allclose(lines["cso (1 ep.)"].get_xdata(), [0, 1, 2, 3, 4])
    assert ax.get_xlim() == (0.0, 4.0)
    assert "holds its final coverage" in ax.get_xlabel()
    assert "held" in ax.get_legend().get_title().get_text()
    fig.clf()


def test_the_progress_bars_time_left_counts_only_the_episodes_run_now():
    """``--resume`` reads the kept episodes back in a burst: the bar's time left (as the log lines' does) takes the
    pace of the episodes run by this command only, not about 0 left."""
    import io

    from rich.console import Console

    from cso_runtime.evaluation import EpisodeOutcome, RichProgress

    now_s = [100.0]
    progress = RichProgress(clock=lambda: now_s[0])
    progress.start(5)
    row = {"coverage_pct": 99.1, "steps": 51, "terminated_by": "coverage"}

    def bar() -> str:
        console = Console(file=io.StringIO(), width=200, record=True)
        console.print(progress.progress.make_tasks_table(progress.progress.tasks))
        return console.export_text()

    progress.advance(EpisodeOutcome("greedy-dist", "img_1", row=row, kept=True))
    progress.advance(EpisodeOutcome("greedy-dist", "img_2", row=row, kept=True))
    assert "2/5 0:00:00 -:--:--" in bar()  # nothing run yet: no pace
    now_s[0] = 130.0
    progress.advance(EpisodeOutcome("greedy-dist", "img_3", row=row))
    assert "3/5 0:00:30 0:01:00" in bar()  # 2 left at 30 s each
    progress.stop()


def test_summary_gives_each_table_1_mean_its_95_percent_bootstrap_interval_over_plans(tmp_path: Path):
    """Researchers asked for a 95 % interval of each Table 1 mean, per method and per scale: ``<metric>_ci95`` in
    summary.json, [low, high] from the same bootstrap as ``compare`` (``bootstrap_mean_ci``, plans resampled, fixed
    seed), so it can be recomputed from episodes.csv; null with fewer than two plans (no spread to resample)."""
    from cso_runtime.comparison import bootstrap_mean_ci

    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:3:0", out_dir=out, max_steps=40))
    with (out / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    for method in ("greedy-dist", "random"):
        mine = [r for r in rows if r["method"] == method]
        assert len({r["map"] for r in mine}) == 3
        entry = summary["methods"][method]
        for part in (entry, entry["by_scale"]["small"]):
            for k in METRICS:
                expected = bootstrap_mean_ci(np.array([float(r[k]) for r in mine]), clusters=[r["map"] for r in mine])
                assert part[f"{k}_ci95"] == pytest.approx(list(expected), abs=1e-6), (method, k)
                assert part[f"{k}_ci95"][0] <= part[k] <= part[f"{k}_ci95"][1]
    assert json.loads((out / "summary.json").read_text())["methods"]["random"]["coverage_pct_ci95"] == summary["methods"]["random"]["coverage_pct_ci95"]

    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "one", max_steps=40))
    saved = json.loads((tmp_path / "one" / "summary.json").read_text())["methods"]["greedy-dist"]
    for part in (saved, saved["by_scale"]["small"]):
        assert all(f"{k}_ci95" in part and part[f"{k}_ci95"] is None for k in METRICS)


def test_the_table_1_intervals_do_not_depend_on_the_order_the_episodes_finished_in(tmp_path: Path):
    """The bootstrap picks its resamples by position, and summary.json's ``<metric>_ci95`` took the episodes in the order
    they finished: an eval finished by ``--resume`` (its kept episodes first, those it ran last) or run with
    ``--workers`` gave the very same episodes another interval. They are taken as episodes.csv lists them; so are the
    summary's lists (the why of each ``no_frontier`` end, the failures)."""
    from cso_runtime.evaluation import summarize

    out = tmp_path / "out"
    request = EvalRequest(methods=["greedy-dist"], maps="generated:small:8:0", out_dir=out, max_steps=200)
    first = run_eval(request)["methods"]["greedy-dist"]
    for name in ("gen_small_0", "gen_small_3"):
        (out / "episodes" / "greedy-dist" / f"{name}.npz").unlink()
    request.resume = True
    again = run_eval(request)
    assert again["meta"]["resumed_episodes"] == 6
    resumed = again["methods"]["greedy-dist"]
    for k in METRICS:
        if k.startswith("decision_ms"):  # timed: each run its own
            continue
        assert resumed[k] == first[k], k  # the same episodes
        assert resumed[f"{k}_ci95"] == first[f"{k}_ci95"], k

    rows = [
        {"method": "m", "map": f"p{i}", "scale": "small", "seed": 0, "terminated_by": "no_frontier" if i % 3 else "coverage",
         "ended_why": f"{i} frontier cells unreachable" if i % 3 else "", "efficiency_m2_per_step": 0.1 + 0.07 * (i % 5) + 0.01 * i,
         **{k: float(i * i % 7) for k in METRICS if k != "efficiency_m2_per_step"}}
        for i in range(12)
    ]
    failures = [{"method": "m", "map": f"q{i}", "error": "boom"} for i in range(3)]
    shuffled = rows[5:] + rows[:5][::-1]
    # The whole summary (the why of each no_frontier end, the failures too) as with the episodes in order.
    assert summarize(shuffled, failures[::-1], ["m"], {}, baseline="") == summarize(rows, failures, ["m"], {}, baseline="")


def test_the_report_lists_every_episode_in_a_collapsed_per_scene_table(tmp_path: Path):
    """report.html's per-scene table: a row per episode (plan, method, coverage %, steps, m2/step, how it ended),
    sorted by scale then plan, inside a <details> closed by default, so a reader finds the scenes a method lost;
    the sections before it stay as they were."""
    out = tmp_path / "out"
    run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:2:0", out_dir=out, max_steps=40))
    with (out / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    page = (out / "report.html").read_text()
    assert "<h2>Table 1</h2>" in page and page.count("<details") == 1 and "<details open" not in page
    section = page.split("<details", 1)[1].split("</details>", 1)[0]
    body = section.split("<tbody>", 1)[1].split("</tbody>", 1)[0]
    cells = [re.findall(r"<td>(.*?)</td>", tr) for tr in re.findall(r"<tr>(.*?)</tr>", body)]
    assert len(cells) == len(rows) == 4
    plans = [c[0] for c in cells]
    assert plans == sorted(plans)
    for r in rows:
        row = next(c for c in cells if c[:2] == [r["map"], r["method"]])
        assert row[4:] == [f"{float(r['coverage_pct']):.2f}", r["steps"], f"{float(r['efficiency_m2_per_step']):.4f}", r["terminated_by"]]


def test_the_report_says_when_its_per_scene_table_lacks_episodes_of_a_cut_episodes_csv(tmp_path: Path):
    """An episodes.csv cut short (a full disk, a copy stopped halfway) lost the per-scene table's last rows without a
    word, beside a Table 1 of every episode. The report says how many of the summary's episodes the table shows and
    why: a row cut mid-line is named as ``compare`` names it (``comparison.whole_rows``), and not shown half-empty;
    a file cut at a line's end is told by the count. A whole file says nothing."""
    from cso_runtime.report import write_report

    out = tmp_path / "out"
    summary = run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:2:0", out_dir=out, max_steps=40))
    assert "episodes.csv" not in (out / "report.html").read_text().split("<details", 1)[0].split("<h2>Table 1</h2>", 1)[1]
    lines = (out / "episodes.csv").read_text().splitlines(keepends=True)
    assert len(lines) == 5
    (out / "episodes.csv").write_text("".join(lines[:3]) + lines[3][:20])  # cut inside the third episode's row
    page = write_report(out, summary).read_text()
    assert "episodes.csv: line 4 has" in page and "the table shows 2 of the 4 episodes summary.json counts" in page, page
    section = page.split("<details", 1)[1].split("</details>", 1)[0]
    assert section.count("<tr><td>") == 2, section
    (out / "episodes.csv").write_text("".join(lines[:4]))  # cut at a line's end: whole rows, one fewer
    page = write_report(out, summary).read_text()
    assert "the table shows 3 of the 4 episodes summary.json counts" in page, page


def test_the_per_scene_table_goes_by_scale_then_plan_and_shows_only_the_summarys_episodes(tmp_path: Path):
    """Scales small to super large (not alphabetical), plans by name within a scale, Table 1's method order on a
    plan; an earlier run's episodes.csv rows of other methods or plans (not in summary.json) stay out."""
    from cso_runtime.report import scene_rows

    fields = ["method", "map", "scale", "seed", "coverage_pct", "steps", "efficiency_m2_per_step", "terminated_by"]
    episodes = [
        ("random", "b", "small"), ("greedy-dist", "a", "large"), ("random", "a", "large"), ("greedy-dist", "b", "small"),
        ("greedy-dist", "a2", "small"), ("cso", "a", "large"), ("greedy-dist", "gone", "small"),
    ]  # fmt: skip
    with (tmp_path / "episodes.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(fields)
        writer.writerows([m, p, s, 0, 90.0, 10, 0.5, "coverage"] for m, p, s in episodes)
    summary = {"methods": {"greedy-dist": {"maps": ["a", "a2", "b"]}, "random": {"maps": ["a", "b"]}}}
    assert [r[:3] for r in scene_rows(tmp_path, summary)] == [
        ["a2", "greedy-dist", "small"], ["b", "greedy-dist", "small"], ["b", "random", "small"],
        ["a", "greedy-dist", "large"], ["a", "random", "large"],
    ]  # fmt: skip
    assert scene_rows(tmp_path / "elsewhere", summary) == []


def test_report_table_1_rows_give_each_means_interval_in_their_tooltip(tmp_path: Path):
    """report.html shows summary.json's ``<metric>_ci95`` in a Table 1 row's tooltip (title), its cells as they were;
    a row of one plan has no interval and no tooltip."""
    import html as html_lib

    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:2:0", out_dir=tmp_path / "o", max_steps=40))
    e = summary["methods"]["greedy-dist"]
    table1 = (tmp_path / "o" / "report.html").read_text().split("<h2>Table 1</h2>")[1].split("</table>")[0]
    (title,) = re.findall(r'<tr title="([^"]*)">', table1)
    low, high = e["coverage_pct_ci95"]
    assert f"coverage % [{low:.2f}, {high:.2f}]" in html_lib.unescape(title) and "bootstrap over plans" in title
    assert f"<td>{e['coverage_pct']:.2f} ± {e['coverage_pct_std']:.2f}</td>" in table1
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path / "one", max_steps=40))
    assert "<tr title" not in (tmp_path / "one" / "report.html").read_text()


def _tree(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``folder`` with its size and modification time: what a command that writes nothing leaves alone."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_eval_resolved_prints_the_meta_config_a_tiny_eval_records_as_a_config_that_runs_the_same(tmp_path: Path):
    """``eval --resolved`` prints the exploration configuration the episodes run with, defaults, the file, ``--set``
    and the flags resolved: what summary.json's ``meta.config`` records after a real eval, and given back as
    ``--config`` (with the same ``--sensor``), the same configuration; with another sensor, refused, not run otherwise."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    flags = ["--maps", "generated:small:1:0", "--sensor", "depth", "--sim", "2d"]
    tuned = ["--max-steps", "5", "--set", "masks.beta_far_m=2.0", "--set", "sensor.range_max_m=2.5"]
    out = tmp_path / "eval"
    r = CliRunner().invoke(app, ["eval", *flags, *tuned, "--out", str(out), "--resolved"])
    assert r.exit_code == 0, r.output
    assert not out.exists()  # nothing run, nothing written
    shown = yaml.safe_load(r.stdout)
    assert (shown["episode"]["max_steps"], shown["masks"]["beta_far_m"], shown["sensor"]["range_max_m"], shown["sensor"]["fov_deg"]) == (5, 2.0, 2.5, 79.0)
    ran = CliRunner().invoke(app, ["eval", *flags, *tuned, "--out", str(out)])
    assert ran.exit_code == 0, ran.output
    assert shown == json.loads((out / "summary.json").read_text())["meta"]["config"]
    config = tmp_path / "resolved.yaml"
    config.write_text(r.stdout)
    given_back = EvalRequest(methods=["greedy-dist"], sensor="depth", config_path=config).exploration_config()
    assert to_dict(given_back) == shown
    with pytest.raises(ConfigError, match="sensor.fov_deg is set by eval's --lidar-fov.*says 79.*gives 180"):
        EvalRequest(methods=["greedy-dist"], config_path=config).exploration_config()  # the LiDAR's 180 degrees, not silently


def test_a_resolved_config_given_to_another_lidar_fov_names_the_flag_that_gave_the_other_view(tmp_path: Path):
    """docs/eval.md: ``eval ... --resolved > run.yaml`` then ``eval --config run.yaml`` with the same ``--lidar-fov``.
    Given with ``--lidar-fov 360`` a config of a 180-degree run was refused with "--sensor lidar gives 360", as if the
    preset gave it, not the flag the user typed: the refusal names ``--lidar-fov 360``, and how to go on."""
    import yaml

    from cso_runtime.evaluation import EvalRequest

    config = tmp_path / "run.yaml"
    config.write_text(yaml.safe_dump(to_dict(EvalRequest(methods=["greedy-dist"]).exploration_config())))  # --resolved's, 180 degrees
    with pytest.raises(ConfigError) as refused:
        EvalRequest(methods=["greedy-dist"], lidar_fov_deg=360.0, config_path=config).exploration_config()
    said = str(refused.value)
    assert "(it says 180; --sensor lidar --lidar-fov 360 gives 360)" in said, said
    assert "give the --sensor and --lidar-fov it was resolved with, or leave sensor.fov_deg out of the file" in said, said
    with pytest.raises(ConfigError, match=re.escape("(it says 79; --sensor lidar --lidar-fov 180 gives 180)")):  # no --lidar-fov: 180
        depth = tmp_path / "depth.yaml"
        depth.write_text(yaml.safe_dump(to_dict(EvalRequest(methods=["greedy-dist"], sensor="depth").exploration_config())))
        EvalRequest(methods=["greedy-dist"], config_path=depth).exploration_config()


def test_a_set_of_the_sensors_field_of_view_is_sent_to_the_flag_that_sets_it_not_to_a_file(tmp_path: Path):
    """``eval --set sensor.fov_deg=360`` (no config file) was refused with "give the --sensor and --lidar-fov it was
    resolved with, or leave sensor.fov_deg out of the file": there is no file, and nothing was resolved. A field of
    view given by ``--set`` is sent to the flag that gives it (``--lidar-fov 360`` in its place), or, where no flag
    gives that view (a depth camera's, 100 degrees), told to be left out; a config file's keeps its words."""
    from cso_runtime.evaluation import EvalRequest

    for settings in ({"sensor.fov_deg": 360}, {"sensor": {"fov_deg": 360}}):
        with pytest.raises(ConfigError) as refused:
            EvalRequest(methods=["greedy-dist"], settings=settings).exploration_config()
        said = str(refused.value)
        assert "(it says 360; --sensor lidar --lidar-fov 180 gives 180): give --lidar-fov 360 in place of the --set" in said, said
        assert "file" not in said.split("): ", 1)[1], said
    with pytest.raises(ConfigError) as refused:
        EvalRequest(methods=["greedy-dist"], sensor="depth", settings={"sensor.fov_deg": 100}).exploration_config()
    assert "--sensor depth gives 79): leave sensor.fov_deg out of the --set (the --sensor preset and --lidar-fov set it)" in str(refused.value), refused.value


def test_eval_dry_run_says_what_would_run_and_writes_nothing(tmp_path: Path):
    """``eval --dry-run`` checks what a real eval checks and says what it would run (scenes per scale and their first
    names, the m/px, the sensor, the simulator, the workers, the learned methods' weights, what it would do with an
    existing ``--out``) without running an episode or writing a file; a scene that would fail to load is exit 1."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    out = tmp_path / "eval"
    r = CliRunner().invoke(app, ["eval", "--method", "greedy-dist,cso", "--maps", "builtin", "--limit", "2", "--workers", "2", "--out", str(out), "--dry-run"])
    assert r.exit_code == 0, r.output
    assert "would run 4 episode(s), 2 method(s) x 2 scene(s)" in r.stdout
    assert "scenes: builtin: 2 super_large; img_1, img_2" in r.stdout and "0.1 m/px" in r.stdout
    assert "sensor: lidar, 180 degrees" in r.stdout and "simulator: 2d" in r.stdout and "workers: 2" in r.stdout
    assert re.search(r"cso \(weights \S+cso@fov180\.pt, sha256 [0-9a-f]{12}\)", r.stdout)
    assert f"output: {out}: a new folder" in r.stdout
    assert not out.exists()

    tiny = ["--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(out)]
    assert CliRunner().invoke(app, ["eval", *tiny]).exit_code == 0
    before = _tree(out)
    resume = CliRunner().invoke(app, ["eval", *tiny, "--resume", "--dry-run"])
    assert resume.exit_code == 0 and "--resume keeps the 1 of these episodes" in resume.stdout and "runs the other 0" in resume.stdout
    again = CliRunner().invoke(app, ["eval", *tiny, "--dry-run"])
    assert again.exit_code == 0 and "holding 1 of these episodes: without --resume every episode runs again" in again.stdout
    assert _tree(out) == before

    missing = CliRunner().invoke(app, ["eval", "--maps", str(tmp_path / "nowhere.png"), "--out", str(tmp_path / "o"), "--dry-run"])
    assert missing.exit_code == 1 and "error: scene nowhere" in missing.stderr
    assert not (tmp_path / "o").exists()


def test_eval_dry_run_says_holding_the_same_episodes_with_or_without_resume(tmp_path: Path):
    """``eval --dry-run`` without ``--resume`` counted every episode file as held, while ``--resume`` counts the ones it
    would keep: with ``--animate`` an episode without its GIF ("holding 1", "keeps the 0") and a cut episode file
    read as held without ``--resume`` alone. Both lines now count the episodes ``--resume`` would keep."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.outputs import episode_npz_path

    out = tmp_path / "eval"
    tiny = ["--maps", "generated:small:2:0", "--max-steps", "5", "--out", str(out)]
    assert CliRunner().invoke(app, ["eval", *tiny]).exit_code == 0

    def said(*flags: str) -> str:
        r = CliRunner().invoke(app, ["eval", *tiny, "--dry-run", *flags])
        assert r.exit_code == 0, r.output
        return r.stdout

    assert "--resume keeps the 2 of these episodes" in said("--resume") and "holding 2 of these episodes" in said()
    assert "--resume keeps the 0 of these episodes" in said("--resume", "--animate")  # no GIF: each runs again
    assert "holding none of these episodes" in said("--animate")
    cut = episode_npz_path(out, "greedy-dist", "gen_small_1")
    cut.write_bytes(cut.read_bytes()[:50])  # a kill while an earlier version wrote it in place
    assert "--resume keeps the 1 of these episodes" in said("--resume") and "holding 1 of these episodes" in said()


@pytest.mark.parametrize(
    "bad",
    [["--method", "greedy-dsit"], ["--max-steps", "0"], ["--set", "masks.nope=1"], ["--m-per-px", "-1"], ["--sim", "3d"], ["--out", "{file}/below"]],
)
def test_eval_dry_run_refuses_bad_input_as_a_real_eval_does(tmp_path: Path, bad: list[str]):
    """Bad input: ``--dry-run`` and ``--resolved`` exit as a real eval does, with the same error, and write nothing
    (``--out``, the folder the run would write in, is checked by ``--dry-run``, with or without ``--resolved``: see
    test_eval_resolved_prints_the_configuration_wherever_the_run_would_write)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    (tmp_path / "file").write_text("")
    bad = [arg.replace("{file}", str(tmp_path / "file")) for arg in bad]
    args = ["eval", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), *bad]
    real = CliRunner().invoke(app, args)
    assert real.exit_code == 2 and "error:" in real.stderr
    for flags in (["--dry-run"], ["--resolved", "--dry-run"], [] if "--out" in bad else ["--resolved"]):
        if flags:
            checked = CliRunner().invoke(app, [*args, *flags])
            assert (checked.exit_code, checked.stderr) == (real.exit_code, real.stderr), flags
    assert not (tmp_path / "o").exists()


def test_eval_resolved_prints_the_configuration_wherever_the_run_would_write(tmp_path: Path):
    """``eval --resolved`` prints the exploration configuration to run again later, elsewhere, as ``up --resolved``
    prints its profile; but it took ``--dry-run``'s checks of ``--out``: it refused to print where ``--out`` cannot be
    made (under a file) or holds another configuration's episodes, though ``--out`` is not in what it prints. Alone it
    prints, the same configuration, and says ``--out`` is not checked; ``--dry-run``, alone or with ``--resolved``,
    checks ``--out`` as before (and a real eval)."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    (tmp_path / "file").write_text("")
    base = ["eval", "--maps", "generated:small:1:0", "--max-steps", "5"]
    plain = CliRunner().invoke(app, [*base, "--out", str(tmp_path / "new"), "--resolved"])
    assert plain.exit_code == 0 and "error" not in plain.output, plain.output
    config = yaml.safe_load(plain.stdout)
    assert config["episode"]["max_steps"] == 5 and f"# output: {tmp_path / 'new'}: not checked (--dry-run checks it)" in plain.stdout, plain.stdout
    other = tmp_path / "other"
    assert CliRunner().invoke(app, ["eval", "--maps", "generated:small:1:0", "--max-steps", "7", "--out", str(other)]).exit_code == 0
    before = _tree(other)
    for out, said in ((tmp_path / "file" / "below", "cannot create the folder"), (other, "from another configuration")):
        r = CliRunner().invoke(app, [*base, "--out", str(out), "--resolved"])
        assert r.exit_code == 0 and "error" not in r.output and yaml.safe_load(r.stdout) == config, (out, r.output)
        for flags in (["--dry-run"], ["--dry-run", "--resolved"]):
            dry = CliRunner().invoke(app, [*base, "--out", str(out), *flags])
            assert dry.exit_code == 2 and said in " ".join(dry.stderr.split()) and "max_steps" not in dry.stdout, (out, flags, dry.output)
    assert _tree(other) == before and not (tmp_path / "new").exists()  # nothing run, nothing written


def test_eval_refuses_an_out_folder_holding_this_runs_episodes_from_another_configuration(tmp_path: Path):
    """A sweep's folder given again with another flag (``--max-steps``, a forgotten ``--lidar-fov 360``, another
    ``--seed``), with or without ``--resume``, wrote over its episodes silently, hours of results gone: it is refused
    (exit 2, before any episode), naming what differs, and ``--overwrite`` runs them again in place. The same
    configuration runs as before: again without ``--resume``, kept with it."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    out = tmp_path / "o"
    base = ["eval", "--method", "greedy-dist,random", "--maps", "generated:small:2:0", "--out", str(out)]
    assert CliRunner().invoke(app, [*base, "--max-steps", "12"]).exit_code == 0
    npz = sorted((out / "episodes").rglob("*.npz"))
    stamps = {p: p.stat().st_mtime_ns for p in npz}
    summary = (out / "summary.json").read_text()
    for other in (["--max-steps", "10"], ["--max-steps", "10", "--resume"], ["--max-steps", "12", "--seed", "1", "--resume"],
                  ["--max-steps", "10", "--dry-run"]):
        r = CliRunner().invoke(app, [*base, *other])
        said = " ".join(r.output.split())
        assert r.exit_code == 2, (other, r.output)
        assert f"{out} holds 4 episodes of this run's methods and plans from another configuration" in said, said
        assert "--overwrite" in said and "give another --out" in said
        assert ("episode.max_steps: 12 there, 10 here" if "10" in other else "seed: 0 there, 1 here") in said, said
    assert {p: p.stat().st_mtime_ns for p in npz} == stamps and (out / "summary.json").read_text() == summary  # nothing run, nothing written
    assert CliRunner().invoke(app, [*base, "--max-steps", "12", "--resume"]).exit_code == 0  # the same configuration: kept
    assert {p: p.stat().st_mtime_ns for p in npz} == stamps
    r = CliRunner().invoke(app, [*base, "--max-steps", "10", "--overwrite"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 4 and all(int(row["steps"]) <= 10 for row in rows)
    assert json.loads((out / "summary.json").read_text())["meta"]["request"]["overwrite"] is True


def test_ctrl_c_while_eval_writes_its_results_says_so_and_resume_writes_them(tmp_path: Path, monkeypatch):
    """Ctrl-C once every episode ran, while the figures and report.html of hundreds of plans are written (or a second
    Ctrl-C after the first stopped the episodes): the eval ended with exit code 130 and not a word, report.html and
    the figures missing. It says what is missing and that ``--resume`` writes it, keeping every finished episode."""
    from typer.testing import CliRunner

    from cso_runtime import cli, evaluation

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)  # the test's process keeps its own handlers
    out = tmp_path / "o"
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:2:0", "--max-steps", "10", "--out", str(out)]
    with monkeypatch.context() as patched:
        patched.setattr(evaluation, "write_report", interrupted)
        r = CliRunner().invoke(cli.app, args)
    said = " ".join(r.output.split())
    assert r.exit_code == 130, r.output
    assert f"interrupted while writing the results in {out}/" in said and "the same command with --resume writes them" in said, said
    assert not (out / "report.html").exists() and len(list((out / "episodes" / "greedy-dist").glob("*.npz"))) == 2
    again = CliRunner().invoke(cli.app, [*args, "--resume"])
    assert again.exit_code == 0, again.output
    assert (out / "report.html").is_file() and json.loads((out / "summary.json").read_text())["meta"]["resumed_episodes"] == 2


def test_ctrl_c_while_eval_checks_its_plans_says_nothing_ran_or_was_written(tmp_path: Path, monkeypatch):
    """Ctrl-C in an eval's first seconds, while it loads and checks every plan: it ended with exit code 130 and not a
    word. It says, as a later Ctrl-C does, what happened: no episode ran, nothing was written."""
    from typer.testing import CliRunner

    from cso_runtime import cli, evaluation

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)  # the test's process keeps its own handlers
    monkeypatch.setattr(evaluation, "plan_eval", interrupted)
    out = tmp_path / "o"
    r = CliRunner().invoke(cli.app, ["eval", "--method", "greedy-dist", "--maps", "generated:small:2:0", "--out", str(out)])
    assert r.exit_code == 130, r.output
    assert "interrupted before any episode ran, while checking the plans; nothing written" in " ".join(r.output.split())
    assert not out.exists()


def test_two_workers_give_the_rows_and_order_of_one(tmp_path: Path):
    """``--workers 2`` finishes episodes in any order: episodes.csv holds the same rows, in the same order, and each
    episode's files the same path and coverage as ``--workers 1`` (only the timings differ)."""
    timings = {"decision_ms_p50", "decision_ms_p99", "wall_s", "real_time_factor"}
    runs = {}
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        run_eval(EvalRequest(methods=["random", "greedy-dist"], maps="generated:small:3:0", out_dir=out, max_steps=25, workers=workers))
        with (out / "episodes.csv").open() as fh:
            runs[workers] = [{k: v for k, v in row.items() if k not in timings} for row in csv.DictReader(fh)]
    assert len(runs[1]) == 6 and runs[2] == runs[1]
    for npz in sorted((tmp_path / "w1" / "episodes").rglob("*.npz")):
        with np.load(npz) as one, np.load(tmp_path / "w2" / npz.relative_to(tmp_path / "w1")) as two:
            for key in ("trajectory", "coverage_curve", "explored"):
                np.testing.assert_array_equal(one[key], two[key], err_msg=f"{npz.name} {key}")


def test_a_second_eval_into_a_folder_another_eval_is_writing_is_refused(tmp_path: Path):
    """The same sweep started twice (a second terminal, a job resubmitted, ``--resume`` while the first still writes
    its figures) ran both into one ``--out``: every episode twice, each writing the other's files, the last summary
    winning. The second is refused before any episode, naming the first's pid; once that one ended (however: the
    kernel drops its lock, a ``kill -9`` too), the folder is free again."""
    import os

    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.evaluation import EVAL_LOCK, hold_eval_lock

    out = tmp_path / "o"
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(out)]
    first = hold_eval_lock(out)  # as the first eval holds it, from its start to its end
    assert first is not None and (out / EVAL_LOCK).read_text() == f"{os.getpid()}\n"
    try:
        r = CliRunner().invoke(app, args)
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and f"{out} is being written by another eval (pid {os.getpid()})" in said, r.output
        assert not (out / "summary.json").exists() and not (out / "episodes").exists()
        with pytest.raises(ConfigError, match="is being written by another eval"):
            run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=out, max_steps=5))
    finally:
        os.close(first)
    assert CliRunner().invoke(app, args).exit_code == 0 and (out / "summary.json").is_file()
    assert hold_eval_lock(out) is not None  # and released at its end


def test_an_eval_on_a_file_system_without_locks_runs_and_says_it_holds_no_lock(tmp_path: Path, monkeypatch, caplog):
    """NFS without its lock service answers flock with ENOLCK: the eval said "is being written by another eval" and
    refused the folder for ever, where it ran before the lock. It runs, and says that it could not take the lock (a
    second eval into the folder would not be stopped, and it leaves alone the partial files it finds, which may be
    such an eval's); the lock held by another eval is still a refusal."""
    import errno
    import fcntl
    import logging
    import os

    def no_locks(fd: int, operation: int) -> None:
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(fcntl, "flock", no_locks)
    out = tmp_path / "o"
    another_evals = out / "episodes" / "greedy-dist" / ".other.npz.4242.partial"  # with no lock: maybe being written
    another_evals.parent.mkdir(parents=True)
    another_evals.write_bytes(b"PK")
    with caplog.at_level(logging.WARNING, logger="cso_runtime.evaluation"):
        summary = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=out, max_steps=5))
    assert summary["methods"]["greedy-dist"]["episodes"] == 1 and (out / "summary.json").is_file()
    assert f"cannot lock {out / '.eval.lock'} (No locks available)" in caplog.text
    assert another_evals.is_file()  # only an eval holding the lock removes the partial files it finds


def test_eval_removes_only_the_partial_files_of_its_own_files_whose_writer_is_gone(tmp_path: Path):
    """The clean-up removed every ``.<name>.<pid>.partial`` in ``--out``: a ``train`` into the same folder (another lock)
    or a tool of one's own lost the file it was writing, and a live process's too. Now only the partial files of eval's
    own files whose writer runs no more go; a live writer's and another command's stay."""
    import sys

    from tests.conftest import exited_pid, process_group

    out = tmp_path / "o"
    request = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=out, max_steps=6)
    run_eval(request)
    folder = out / "episodes" / "greedy-dist"
    with process_group([sys.executable, "-c", "import time; time.sleep(60)"]) as live:
        dead = exited_pid()
        kept = [out / f".summary.json.{live.pid}.partial", folder / f".gen_small_0.npz.{live.pid}.partial",  # being written
                out / f".cso.pt.{dead}.partial", out / f".notes.txt.{dead}.partial", folder / f".gen_small_0.csv.{dead}.partial"]  # not eval's
        removed = [out / f".summary.json.{dead}.partial", out / f".report.html.{dead}.partial", folder / f".gen_small_0.npz.{dead}.partial"]
        for path in kept + removed:
            path.write_bytes(b"PK\x03\x04 half written")
        summary = run_eval(dataclasses.replace(request, resume=True))
        assert summary["meta"]["resumed_episodes"] == 1
        assert [path.name for path in kept if not path.exists()] == []
        assert [path.name for path in removed if path.exists()] == []


def test_resume_runs_again_an_episode_whose_file_is_cut_short(tmp_path: Path):
    """An episode file cut short or empty (an interrupted copy of a results folder, a full disk, a file system without
    atomic renames) stopped ``eval --resume`` with a BadZipFile traceback; it is no result: it runs again, the others
    are kept."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    out = tmp_path / "o"
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:3:0", "--max-steps", "10", "--out", str(out)]
    assert CliRunner().invoke(app, args).exit_code == 0
    folder = out / "episodes" / "greedy-dist"
    cut, empty = folder / "gen_small_0.npz", folder / "gen_small_1.npz"
    for again, kept in ((args, None), ([*args, "--resume"], 1)):  # without --resume too: no other configuration's results there
        cut.write_bytes(cut.read_bytes()[:300])
        empty.write_bytes(b"")
        r = CliRunner().invoke(app, again)
        assert r.exit_code == 0, r.output
        meta = json.loads((out / "summary.json").read_text())["meta"]
        assert meta.get("resumed_episodes") == kept and np.load(cut)["trajectory"].size > 0 and np.load(empty)["trajectory"].size > 0


def _rewrite_episode_file(npz: Path, drop: tuple[str, ...] = (), **fields: str) -> None:
    """Rewrite ``npz`` as another version would have written it: without ``drop``, with ``fields`` in place."""
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files if k not in drop and k not in fields}
    np.savez_compressed(npz, **arrays, **{k: np.array(v) for k, v in fields.items()})


def _rewrite_summary_meta(out: Path, change) -> None:
    summary = json.loads((out / "summary.json").read_text())
    change(summary["meta"])
    (out / "summary.json").write_text(json.dumps(summary))


def test_episodes_written_before_the_fingerprints_are_refused_saying_why_and_how_to_keep_them(tmp_path: Path):
    """An episode file of a version before the fingerprints (no ``settings`` nor ``scene``) may have run otherwise:
    refused even for the same command with ``--resume``, the refusal saying that it recorded none, by which version,
    and how to keep it (its version) or run it again (``--overwrite``): an empty list of differences said nothing."""
    req = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=10, resume=True)
    run_eval(req)
    npz = tmp_path / "episodes" / "greedy-dist" / "gen_small_11.npz"
    _rewrite_episode_file(npz, drop=("settings", "scene", "animation"))
    _rewrite_summary_meta(tmp_path, lambda meta: meta.update(version="0.0.9"))
    with pytest.raises(ConfigError) as refused:
        run_eval(req)
    said = str(refused.value)
    assert "(greedy-dist gen_small_11; it recorded no settings (written by cso-runtime 0.0.9 or older))" in said
    assert "--overwrite to run them again here" in said and "go on with that sweep with the version that wrote them (cso-runtime 0.0.9)" in said
    req.overwrite = True
    assert run_eval(req)["meta"]["resumed_episodes"] == 0  # run again, with its settings recorded now


def test_a_key_an_upgrade_added_is_no_difference_at_the_old_behaviours_value_and_is_named_where_unknown(tmp_path: Path, monkeypatch):
    """A sweep begun before an upgrade that added a config key: with the key's earlier behaviour known
    (``CONFIG_KEYS_ADDED``) and kept, ``--resume`` keeps its episodes; unknown, the refusal names the key."""
    from cso_runtime import evaluation

    def without_the_key(config):  # the version before mapping.footprint_clearing: its config had no such key
        data = to_dict(config)
        del data["mapping"]["footprint_clearing"]
        return data

    req = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=10)
    with monkeypatch.context() as older:
        older.setattr(evaluation, "to_dict", without_the_key)
        run_eval(req)
    default = to_dict(ExplorationConfig())["mapping"]["footprint_clearing"]
    req.resume = True
    with pytest.raises(ConfigError, match=rf"key mapping.footprint_clearing: not recorded there \(added in a later version\), {default} here"):
        run_eval(req)  # what the older code did is not known: the key may have changed the episodes
    monkeypatch.setitem(evaluation.CONFIG_KEYS_ADDED, "mapping.footprint_clearing", default)
    assert run_eval(req)["meta"]["resumed_episodes"] == 1  # its default is what the older code did: the same configuration
    req.settings = {"mapping.footprint_clearing": not default}
    with pytest.raises(ConfigError, match=rf"mapping.footprint_clearing: {default} there, {not default} here"):
        run_eval(req)  # set otherwise: another configuration (that resume's summary.json records the key)


def test_a_2d_episode_run_at_another_width_before_the_disc_followed_it_is_another_configuration(tmp_path: Path):
    """Before the 2D simulator's collision disc followed ``robot.width_m`` it was 0.12 m whatever the width: an
    episode of those at another width ran with another disc than today's, so ``--resume`` must not keep it. At the
    LIMO's width the disc is the same, and such an episode keeps its fingerprint."""
    from cso_runtime.evaluation import settings_fingerprint
    from cso_runtime.simulator import simulator_settings

    req = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=10, settings={"robot.width_m": 0.3})
    run_eval(req)
    config = req.exploration_config()
    npz = tmp_path / "episodes" / "greedy-dist" / "gen_small_11.npz"
    _rewrite_episode_file(npz, settings=settings_fingerprint(config, "2d"))  # the fingerprint before the sim settings counted
    _rewrite_summary_meta(tmp_path, lambda meta: meta["sim_settings"].update(collision_radius_m=0.12))  # its fixed disc
    req.resume = True
    with pytest.raises(ConfigError, match=r"sim_settings.collision_radius_m: 0.12 there, 0.16 here"):
        run_eval(req)
    limo = ExplorationConfig()
    assert settings_fingerprint(limo, "2d", sim_settings=simulator_settings("2d", limo.sensor, limo.robot)) == settings_fingerprint(limo, "2d")


def test_a_mujoco_default_an_upgrade_changes_makes_the_episodes_before_it_another_configuration(tmp_path: Path, monkeypatch):
    """The fingerprint counted only the keys a ``--sim-config`` file set: after an upgrade that changed a default of the
    MuJoCo LIMO (its wall friction, its physics step), ``--resume`` kept the episodes run before it under a summary
    that says the new value. Now the LIMO's settings count where they differ from the defaults episodes ran with before
    they counted, and the refusal names the setting; the episodes of earlier versions keep their fingerprints."""
    from cso_runtime import simulator
    from cso_runtime.evaluation import settings_fingerprint
    from cso_runtime.simulator import simulator_settings

    req = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path, max_steps=4, sim="mujoco", resume=True)
    run_eval(req)
    earlier = simulator.mujoco_config

    def upgraded(overrides, *args, **kwargs):  # a version whose LIMO slides along walls otherwise by default
        return earlier({"wall_friction": 0.6, **(overrides or {})}, *args, **kwargs)

    with monkeypatch.context() as upgrade:
        upgrade.setattr(simulator, "mujoco_config", upgraded)
        with pytest.raises(ConfigError, match=r"its summary.json differs in sim_settings.wall_friction: 0.3 there, 0.6 here"):
            run_eval(req)
    assert run_eval(req)["meta"]["resumed_episodes"] == 1  # the version that wrote them goes on with them
    # Fingerprints of the settings that counted before (the --sim-config file's keys, the config's mount) are unchanged.
    for params, settings in (({}, {}), ({"odom_trans_noise_frac": 0.05}, {}), ({"timestep_s": 0.0025}, {}), ({}, {"sensor.mount_x_m": 0.2})):
        config = dataclasses.replace(req, settings=settings).exploration_config()
        ran_with = simulator_settings("mujoco", config.sensor, config.robot, params)
        assert settings_fingerprint(config, "mujoco", mujoco=params, sim_settings=ran_with) == settings_fingerprint(config, "mujoco", mujoco=params)
    # The file's keys count as it gives them: one that sets a default is refused too, and the refusal says so (it said
    # that no setting differed).
    default_step = tmp_path / "limo.yaml"
    default_step.write_text("timestep_s: 0.005\n")
    with pytest.raises(ConfigError, match=r"its summary.json differs in --sim-config timestep_s: not set there, 0.005 here\)"):
        run_eval(dataclasses.replace(req, sim_config_path=default_step))


def test_an_eval_that_ended_in_the_folder_after_the_plan_was_checked_is_refused_under_the_lock(tmp_path: Path):
    """``plan_eval`` checks ``--out`` before the lock is taken: an eval of another configuration that finishes into it
    in between must still be refused once this one holds the lock, not written over."""
    from cso_runtime.evaluation import plan_eval

    req = EvalRequest(methods=["greedy-dist"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=10)
    plan = plan_eval(req)  # the folder is empty: nothing to refuse
    other = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:11", out_dir=tmp_path, max_steps=12))
    with pytest.raises(ConfigError, match="episode.max_steps: 12 there, 10 here"):
        run_eval(req, plan=plan)
    assert json.loads((tmp_path / "summary.json").read_text())["meta"]["config"]["episode"]["max_steps"] == 12 == other["meta"]["config"]["episode"]["max_steps"]


def test_eval_refuses_an_entropy_window_its_learned_weights_were_not_trained_with(tmp_path, monkeypatch, caplog):
    """``eval --method cso --set frontier.entropy_window_m=4`` ran the weights trained with 2 m, their entropy input
    doubled, without a word. It is now refused before any episode, naming the parameter, both values and the ``--set``
    that matches; an episode job of that configuration (eval's in-process path, a worker's) fails naming it too, rather
    than run. The window the weights were trained with runs; another ``frontier.min_cluster_size_m`` runs, warned of."""
    from cso_runtime.learned.weights import weights_path

    unset_weights_env(monkeypatch)
    said = f"the weights of cso ({weights_path('cso', SensorConfig())}) were trained with frontier.entropy_window_m 2 m, this run's is 4 m"
    wider = {"frontier.entropy_window_m": 4.0}
    with pytest.raises(ConfigError, match="^" + re.escape(f"method cso: {said}") + r".*--set frontier.entropy_window_m=2 "):
        run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=tmp_path / "o", max_steps=5, settings=wider))
    assert not (tmp_path / "o" / "summary.json").exists()
    config = EvalRequest(methods=["cso"], maps="builtin", out_dir=tmp_path / "o", settings=wider).exploration_config()
    outcome = run_job(EpisodeJob("cso", resolve_scenes("generated:small:1:0")[0], 0, "2d", config, tmp_path / "job"))
    assert outcome.row is None and outcome.error is not None and said in outcome.error
    run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=tmp_path / "same", max_steps=5, settings={"frontier.entropy_window_m": 2.0}))
    with caplog.at_level("WARNING"):
        run_eval(EvalRequest(methods=["cso"], maps="generated:small:1:0", out_dir=tmp_path / "short", max_steps=5, settings={"frontier.min_cluster_size_m": 0.5}))
    assert "were trained with frontier.min_cluster_size_m 0.3 m, this run's is 0.5 m" in caplog.text
    assert json.loads((tmp_path / "short" / "summary.json").read_text())["methods"]["cso"]["episodes"] == 1


def test_the_refusal_of_two_plans_named_alike_once_escaped_tells_their_files_apart(tmp_path: Path):
    """A plan named in bytes that are no UTF-8 (``img_\\xff.png``) is named ``img_\\udcff``, escaped: beside a file whose
    name is that very text (``img_\\udcff.png``, a backslash in it) the two share their files and the eval is refused,
    but the refusal named both by the same path (``plans/img_\\udcff.png`` twice, stderr escaping the first as the
    other is written): which to rename was not to be told. The one of bytes that are no UTF-8 is named by its bytes."""
    plans = tmp_path / "plans"
    plans.mkdir()
    raw = plans / os.fsdecode(b"img_\xff.png")
    try:
        shutil.copy(Path(cso_runtime.__file__).parent / "data" / "scenes" / "img_1.png", raw)
    except OSError:  # a file system that takes only UTF-8 names (macOS)
        pytest.skip("this file system refuses a file name of bytes that are no UTF-8")
    shutil.copy(raw, plans / "img_\\udcff.png")
    request = EvalRequest(methods=["greedy-dist"], maps=str(plans), out_dir=tmp_path / "out", max_steps=10)
    with pytest.raises(ConfigError) as exc:
        plan_eval(request)
    why = str(exc.value)
    assert "would share the files episodes/<method>/img__udcff.npz" in why, why
    assert f"({plans}/img_\\udcff.png)" in why and f"({os.fsencode(raw)!r}, a name of bytes that are no UTF-8)" in why, why
