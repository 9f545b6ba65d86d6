"""cso_runtime.comparison: each method against a baseline scene by scene (eval's paired.csv, `cso-runtime compare`)."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cso_runtime.comparison import CSV_FIELDS, bootstrap_mean_ci, compare_to_baseline, efficiency_by_scene, read_episodes
from tests.conftest import write_episodes_csv

FIELDS = ("method", "map", "scale", "seed", "traversable_area_m2", "efficiency_m2_per_step")


def rows(method: str, scale: str, efficiencies: dict[str, float]) -> list[dict]:
    return [dict(zip(FIELDS, (method, name, scale, 0, 100.0, e))) for name, e in efficiencies.items()]


def test_each_method_is_compared_per_scale_on_the_scenes_both_ran():
    episodes = (
        rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 2.0, "d": 1.0, "only_base": 5.0})
        + rows("cso", "large", {"a": 1.5, "b": 0.5, "c": 2.0, "d": 1.1, "only_cso": 9.0})
        + rows("greedy-dist", "super_large", {"a": 1.0, "b": 1.0})
        + rows("cso", "super_large", {"a": 2.0, "b": 2.0})  # two shared scenes: too few to compare
        + rows("random", "large", {"a": 0.5, "b": 0.5, "c": 1.0, "d": float("nan")})  # a NaN row is left out
    )
    comparisons = compare_to_baseline(efficiency_by_scene(episodes), "greedy-dist")
    assert [(c.method, c.scale, c.scenes) for c in comparisons] == [("cso", "large", 4), ("random", "large", 3)]
    cso, rand = comparisons
    # Means 5.1 / 5.0: +2 %; per-scene ratios 1.5, 0.5, 1.0, 1.1: mean 1.025, +2.5 %; won 2, lost 1, level 1.
    assert cso.change_of_means_pct == pytest.approx(2.0) and cso.per_scene_pct == pytest.approx(2.5)
    assert (cso.won, cso.lost) == (2, 1) and cso.ci_low_pct < 2.5 < cso.ci_high_pct
    assert rand.per_scene_pct == pytest.approx(-50.0) and rand.ci_low_pct == pytest.approx(-50.0) == rand.ci_high_pct
    assert (rand.won, rand.lost) == (0, 3)
    assert compare_to_baseline(efficiency_by_scene(episodes), "utility") == []  # the baseline did not run


def test_the_markdown_row_tells_lost_scenes_from_level_ones():
    """Scenes where the method and the baseline are level (common on small scenes, seen whole in a few steps) are
    neither won nor lost: the markdown of ``compare`` and ``benchmarks/paired.py`` says how many were lost, so that
    "2 of 4" does not read as two scenes lost when one of them is a tie."""
    episodes = rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 2.0, "d": 1.0}) + rows("cso", "large", {"a": 1.5, "b": 0.5, "c": 2.0, "d": 1.1})
    (cso,) = compare_to_baseline(efficiency_by_scene(episodes), "greedy-dist")
    assert (cso.won, cso.lost) == (2, 1)
    assert "| 2 of 4 (1 lost) |" in cso.markdown_row()


def test_the_geometric_mean_of_the_per_scene_ratios_lets_a_doubling_and_a_halving_cancel_out():
    """Ratios 2, 0.5, 1, 1: arithmetic mean +12.5 %, geometric mean 0 %; its interval comes from the same
    resamples as the arithmetic mean's. A method that explored nothing on a scene has no geometric mean."""
    episodes = rows("greedy-dist", "large", {"a": 1.0, "b": 2.0, "c": 1.0, "d": 3.0}) + rows("cso", "large", {"a": 2.0, "b": 1.0, "c": 1.0, "d": 3.0})
    episodes += rows("random", "large", {"a": 0.0, "b": 1.0, "c": 1.0, "d": 3.0})
    cso, rand = compare_to_baseline(efficiency_by_scene(episodes), "greedy-dist")
    assert cso.per_scene_pct == pytest.approx(12.5) and cso.geomean_pct == pytest.approx(0.0, abs=1e-9)
    assert cso.geomean_ci_low_pct < 0.0 < cso.geomean_ci_high_pct and cso.geomean_ci_high_pct <= cso.ci_high_pct
    assert rand.geomean_pct is None and rand.geomean_ci_low_pct is None
    assert "n/a" in rand.markdown_row() and "+0.0 % [" in cso.markdown_row()


def test_the_seeds_of_one_plan_are_resampled_together_not_as_more_scenes():
    """The paper runs each scene several times: episodes of one plan under two seeds are one scene resampled
    twice, so two identical seeds give the interval of one seed, where resampling episodes one by one would
    narrow it by about a factor of 1.4, as if there were twice the plans."""
    ratios = {"a": 1.5, "b": 0.5, "c": 1.0, "d": 1.1, "e": 1.3, "f": 0.9}
    one = rows("greedy-dist", "large", dict.fromkeys(ratios, 1.0)) + rows("cso", "large", ratios)
    two = [dict(r, seed=seed) for r in one for seed in (0, 1)]
    (c1,), (c2,) = compare_to_baseline(efficiency_by_scene(one)), compare_to_baseline(efficiency_by_scene(two))
    assert c2.scenes == 12 and c1.scenes == 6 and c2.per_scene_pct == pytest.approx(c1.per_scene_pct)
    assert (c2.ci_low_pct, c2.ci_high_pct) == pytest.approx((c1.ci_low_pct, c1.ci_high_pct))
    assert (c2.geomean_ci_low_pct, c2.geomean_ci_high_pct) == pytest.approx((c1.geomean_ci_low_pct, c1.geomean_ci_high_pct))
    unit = bootstrap_mean_ci(np.array([ratios[n] for n in ratios for _ in (0, 1)]))  # the episodes one by one: narrower
    assert unit[1] - unit[0] < (c1.ci_high_pct - c1.ci_low_pct) / 100 * 0.85


def test_with_several_seeds_the_minimum_counts_plans_and_the_counts_say_episodes_plan_seed(tmp_path: Path):
    """With ``eval --seeds`` (or ``compare`` of one-seed folders) a "scene" was an episode (plan, seed): one plan under
    3 seeds passed the minimum of 3 scenes and gave an "interval" of one plan (its seeds resampled together), a point,
    and "5 of 6" scenes won read as 6 plans. The minimum counts plans; the counts say episodes (plan, seed), and a
    ``plans`` field is added (the CSV/JSON fields kept)."""
    from cso_runtime.comparison import paired_cells

    one_plan = [dict(r, seed=seed) for seed in (0, 1, 2) for r in rows("greedy-dist", "large", {"a": 1.0}) + rows("cso", "large", {"a": 1.0 + seed})]
    assert compare_to_baseline(efficiency_by_scene(one_plan)) == []
    ratios = {"a": 1.5, "b": 0.5, "c": 1.2}
    three = [dict(r, seed=seed) for seed in (0, 1) for r in rows("greedy-dist", "large", dict.fromkeys(ratios, 1.0)) + rows("cso", "large", ratios)]
    (c,) = compare_to_baseline(efficiency_by_scene(three))
    assert (c.scenes, c.plans, c.won, c.lost) == (6, 3, 4, 2)
    assert "| 3 plans, 6 episodes (plan, seed) |" in c.markdown_row() and "| 4 of 6 episodes (plan, seed), 2 lost |" in c.markdown_row()
    assert paired_cells(dataclasses.asdict(c))[2] == "3 plans, 6 episodes (plan, seed)"
    assert CSV_FIELDS[-1] == "plans" and {"scenes", "won", "lost"} <= set(CSV_FIELDS)  # a field added, none renamed
    (single,) = compare_to_baseline(efficiency_by_scene([r for r in three if r["seed"] == 0]))
    assert single.plans == single.scenes == 3 and "| 3 |" in single.markdown_row() and "| 2 of 3 (1 lost) |" in single.markdown_row()
    old = {k: v for k, v in dataclasses.asdict(single).items() if k != "plans"}  # a summary.json written before plans was counted
    assert paired_cells(old)[2] == "3"
    episodes = write_episodes_csv(tmp_path / "episodes.csv", [r for r in three if r["map"] != "c"], FIELDS)
    said = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "compare", str(episodes)], capture_output=True, text=True, timeout=60)
    assert said.returncode == 1 and "no method shares 3 or more scenes (plans: the seeds of one plan count once) of one scale" in said.stderr


def test_the_metrics_of_one_set_of_plans_share_their_resamples_and_get_the_intervals_of_fresh_draws():
    """A summary's metrics of one method and scale are resampled over the same plans: the resamples are drawn once
    for all of them (drawing them anew for each metric was most of a summary's time), and every interval is the one
    a fresh draw of the same seed gives, to the bit."""
    from cso_runtime import comparison

    def fresh(values: np.ndarray, labels: list[str], seed: int = 0) -> tuple[float, float]:
        """The bootstrap of ``bootstrap_mean_ci``, with its resamples drawn anew."""
        ids = {c: i for i, c in enumerate(dict.fromkeys(labels))}
        index = np.array([ids[c] for c in labels])
        picks = np.random.default_rng(seed).integers(0, len(ids), size=(10_000, len(ids)))
        means = np.bincount(index, weights=values)[picks].sum(axis=1) / np.bincount(index)[picks].sum(axis=1)
        lo, hi = np.percentile(means, [2.5, 97.5])
        return float(lo), float(hi)

    rng = np.random.default_rng(3)
    plans = [f"plan{i % 7}" for i in range(20)]  # 7 plans, several episodes of each
    comparison._cluster_bootstrap.cache_clear()
    metrics = [rng.normal(size=20) for _ in range(5)]
    assert [bootstrap_mean_ci(v, clusters=plans) for v in metrics] == [fresh(v, plans) for v in metrics]
    assert comparison._cluster_bootstrap.cache_info().misses == 1  # one draw for the five metrics
    assert bootstrap_mean_ci(metrics[0], clusters=plans, seed=1) == fresh(metrics[0], plans, seed=1)
    comparison._bootstrap_picks.cache_clear()
    plain = [rng.normal(size=9) for _ in range(3)]
    expected = [tuple(np.percentile(v[np.random.default_rng(0).integers(0, 9, size=(10_000, 9))].mean(axis=1), [2.5, 97.5])) for v in plain]
    assert [bootstrap_mean_ci(v) for v in plain] == expected and comparison._bootstrap_picks.cache_info().misses == 1


def test_a_bad_efficiency_or_a_file_that_is_not_episodes_csv_is_a_clear_error(tmp_path: Path):
    with pytest.raises(ValueError, match="cso on a: efficiency 'fast' is not a number"):
        efficiency_by_scene([dict(zip(FIELDS, ("cso", "a", "large", 0, 100, "fast")))])
    other = tmp_path / "other.csv"
    other.write_text("x,y\n1,2\n")
    with pytest.raises(ValueError, match="not an episodes.csv written by eval: no column method") as err:
        read_episodes([other])
    assert str(err.value).startswith(f"{other}: ")
    binary = tmp_path / "binary.csv"  # say a PNG given by mistake: the file is named, no UnicodeDecodeError
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(ValueError, match="not UTF-8 text") as err:
        read_episodes([binary])
    assert str(binary) in str(err.value)
    bad_row = tmp_path / "bad_row.csv"
    write_episodes_csv(bad_row, [dict(zip(FIELDS, ("cso", "a", "large", 0, 100, "fast")))], FIELDS)
    with pytest.raises(ValueError, match="bad_row.csv: cso on a: efficiency 'fast' is not a number"):
        read_episodes([bad_row])


def test_a_file_cut_short_mid_row_or_a_summary_json_given_to_compare_is_a_clear_error(tmp_path: Path):
    """An episodes.csv cut short mid-row (an interrupted copy) read its last row's missing cells as None and a number
    cut short as a smaller one, and compared it; a summary.json given in place of episodes.csv said only that it has
    no column method."""
    whole = write_episodes_csv(tmp_path / "whole.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.25}), FIELDS)
    text = whole.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rindex("100.0") + 2])  # the last row cut in its traversable area: 10, no efficiency
    assert len(read_episodes([whole])[("greedy-dist", "large")]) == 3
    with pytest.raises(ValueError, match=r"cut.csv: line 4 has 5 cells, the header 6 columns \(a file cut short"):
        read_episodes([cut])
    extra = tmp_path / "extra.csv"
    extra.write_text(text.replace("1.25", "1,25"))
    with pytest.raises(ValueError, match="extra.csv: line 4 has 7 cells, the header 6 columns"):
        read_episodes([extra])
    summary = tmp_path / "run" / "summary.json"
    summary.parent.mkdir()
    summary.write_text('{"meta": {"command": "cso-runtime eval"}}')
    with pytest.raises(ValueError, match=f"no column method.*compare reads episodes.csv: give {summary.parent}/ or its episodes.csv"):
        read_episodes([summary])


def write(path: Path, episodes: list[dict]) -> Path:
    return write_episodes_csv(path, episodes, FIELDS)


def test_compare_cli_pools_labelled_files_and_writes_json_and_csv(tmp_path: Path):
    """Scenes pair within a label only: the same plan name under two labels is two scenes."""
    easy = write(tmp_path / "easy.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0}) + rows("cso", "large", {"a": 1.2, "b": 1.2}))
    medium = write(tmp_path / "medium.csv", rows("greedy-dist", "large", {"a": 2.0, "c": 1.0}) + rows("cso", "large", {"a": 2.0, "c": 0.8}))
    exe = [sys.executable, "-m", "cso_runtime.cli", "compare"]
    out = subprocess.run(exe + [f"easy={easy}", f"medium={medium}", "--json", "--out", str(tmp_path / "p.csv")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    (row,) = json.loads(out.stdout)["comparisons"]
    assert row["scenes"] == 4 and row["per_scene_pct"] == pytest.approx(5.0) and (row["won"], row["lost"]) == (2, 1)
    with (tmp_path / "p.csv").open() as fh:
        written = list(csv.DictReader(fh))
    assert tuple(written[0]) == CSV_FIELDS and float(written[0]["per_scene_pct"]) == pytest.approx(5.0)

    markdown = subprocess.run(exe + [str(easy), str(medium)], capture_output=True, text=True, timeout=60)
    assert markdown.returncode == 0 and "| large | cso | 3 |" in markdown.stdout  # unlabelled: medium's "a" replaces easy's
    two = subprocess.run(exe + [str(easy)], capture_output=True, text=True, timeout=60)  # two scenes: nothing to say
    assert two.returncode == 1 and two.stdout == "" and "no method shares 3 or more scenes" in two.stderr  # no table of headers alone
    missing = subprocess.run(exe + [str(tmp_path / "nope.csv")], capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "no such file" in missing.stderr
    # A folder is the episodes.csv in it (eval --out): easy's folder and medium's file give the labelled result.
    (tmp_path / "eval_easy").mkdir()
    easy.rename(tmp_path / "eval_easy" / "episodes.csv")
    folder = subprocess.run(exe + [f"easy={tmp_path / 'eval_easy'}", f"medium={medium}", "--json"], capture_output=True, text=True, timeout=60)
    assert folder.returncode == 0 and json.loads(folder.stdout)["comparisons"][0]["scenes"] == 4, folder.stderr
    empty = subprocess.run(exe + [str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert empty.returncode == 2 and f"no such file: {tmp_path / 'episodes.csv'}" in empty.stderr
    easy = tmp_path / "eval_easy" / "episodes.csv"
    # --exclude leaves maps out (the plans a training run drew): medium's "c" (the one cso lost) is gone.
    kept = subprocess.run(exe + [f"easy={easy}", f"medium={medium}", "--exclude", "c", "--exclude", "zz,", "--json"], capture_output=True, text=True, timeout=60)
    assert kept.returncode == 0, kept.stderr
    (row,) = json.loads(kept.stdout)["comparisons"]
    assert row["scenes"] == 3 and (row["won"], row["lost"]) == (2, 0)
    # A name no file has (a typo) leaves nothing out: said, where it left the plans meant to be out in silently.
    assert "note: --exclude zz: no such map in these files; nothing left out for it" in kept.stderr and "--exclude c" not in kept.stderr


def test_compare_cli_says_when_the_baseline_or_the_csv_path_is_wrong(tmp_path: Path):
    """A --baseline that no file holds names the methods there; --out makes its folder, and a path it cannot write
    is exit 2 with the reason (it was a traceback)."""
    episodes = write(tmp_path / "e.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.0}) + rows("cso", "large", {"a": 1.1, "b": 1.1, "c": 1.1}))
    exe = [sys.executable, "-m", "cso_runtime.cli", "compare", str(episodes)]
    typo = subprocess.run(exe + ["--baseline", "greedy_dist"], capture_output=True, text=True, timeout=60)
    assert typo.returncode == 2 and "--baseline 'greedy_dist' has no episodes in these files; their methods: cso, greedy-dist" in typo.stderr
    nested = tmp_path / "new" / "deeper" / "p.csv"
    made = subprocess.run(exe + ["--out", str(nested)], capture_output=True, text=True, timeout=60)
    assert made.returncode == 0 and nested.is_file(), made.stderr
    (tmp_path / "blocker").write_text("a file where a folder should be")
    blocked = subprocess.run(exe + ["--out", str(tmp_path / "blocker" / "p.csv")], capture_output=True, text=True, timeout=60)
    assert blocked.returncode == 2 and "--out" in blocked.stderr and "cannot write" in blocked.stderr and "Traceback" not in blocked.stderr


def test_compare_says_when_a_later_file_replaces_a_methods_episodes_of_an_earlier_one(tmp_path: Path):
    """Two evals that both ran cso (the shipped weights, then a training run's with --weights): the later file's cso
    takes the earlier one's place, so the order of the files decides the result. A note on stderr names both files
    and the scenes whose figures changed; greedy-dist, the same in both, is no news."""
    base = rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.0})
    shipped = write(tmp_path / "shipped.csv", base + rows("cso", "large", {"a": 1.2, "b": 1.2, "c": 1.1}))
    trained = write(tmp_path / "trained.csv", base + rows("cso", "large", {"a": 0.9, "b": 0.9, "c": 1.1}))
    replaced: list = []
    (cso,) = compare_to_baseline(read_episodes([shipped, trained], replaced=replaced))
    assert cso.per_scene_pct == pytest.approx(-3.333)  # the trained run's cso (rounded to 3 places)
    assert [(r.method, r.earlier, r.later, r.scenes) for r in replaced] == [("cso", shipped, trained, 2)]
    exe = [sys.executable, "-m", "cso_runtime.cli", "compare"]
    out = subprocess.run(exe + [str(shipped), str(trained)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert f"note: {trained}'s cso replaces {shipped}'s on 2 scenes with other figures" in out.stderr
    assert "greedy-dist" not in out.stderr and "| large | cso | 3 | -3.3 % |" in out.stdout
    alone = subprocess.run(exe + [str(shipped)], capture_output=True, text=True, timeout=60)
    assert alone.returncode == 0 and alone.stderr == ""


def test_compare_renames_a_method_of_one_file_to_set_two_runs_of_it_side_by_side(tmp_path: Path):
    """The shipped cso and a training run's are both ``cso`` in their episodes.csv: ``--rename FILE:METHOD=NEW``
    compares one file's under another name, beside the other instead of in its place (no note of a replacement).
    FILE is as given (a folder, a label); a rename of no file given, of a method the file lacks, to a method the
    file has, or not of the form FILE:METHOD=NEW is exit 2 with the reason (asked of the app in this process, where
    a command of its own costs a second of start-up)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    base = rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.0})
    shipped = write(tmp_path / "shipped.csv", base + rows("cso", "large", {"a": 1.2, "b": 1.2, "c": 1.1}))
    (tmp_path / "mine").mkdir()
    write(tmp_path / "mine" / "episodes.csv", base + rows("cso", "large", {"a": 0.9, "b": 0.9, "c": 1.1}))
    mine = tmp_path / "mine"
    exe = [sys.executable, "-m", "cso_runtime.cli", "compare"]
    out = subprocess.run(exe + [str(shipped), str(mine), "--rename", f"{mine}:cso=cso-mine", "--json"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stderr == "", out.stderr
    by_method = {c["method"]: c for c in json.loads(out.stdout)["comparisons"]}
    assert set(by_method) == {"cso", "cso-mine"}
    assert by_method["cso"]["per_scene_pct"] == pytest.approx(16.667) and by_method["cso-mine"]["per_scene_pct"] == pytest.approx(-3.333)
    labelled_too = [f"easy={shipped}", f"easy={mine}", "--rename", f"easy={mine}:cso=cso-mine", "--rename", f"{shipped}:cso=shipped", "--json"]
    out = subprocess.run(exe + labelled_too, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and {c["method"] for c in json.loads(out.stdout)["comparisons"]} == {"shipped", "cso-mine"}, out.stderr
    for rename, said in (
        (f"{tmp_path / 'other.csv'}:cso=x", f"--rename {tmp_path / 'other.csv'}:cso=x: {tmp_path / 'other.csv'} is not one of the files compared"),
        (f"{mine}:cso-sm=x", f"{mine / 'episodes.csv'}: --rename {mine}:cso-sm=x: no episodes of cso-sm in it; its methods: cso, greedy-dist"),
        (f"{mine}:cso=greedy-dist", "greedy-dist would hold the episodes of two methods of this file"),
        (f"{mine}=cso-mine", "--rename expects FILE:METHOD=NEW"),
        (f"medium={mine}:cso=x", "is not one of the files compared"),  # the label must be the file's
    ):
        wrong = CliRunner().invoke(app, ["compare", str(shipped), str(mine), "--rename", rename])  # usage errors: in this process
        assert wrong.exit_code == 2 and said in " ".join(wrong.stderr.split()) and not isinstance(wrong.exception, Exception), (rename, wrong.stderr, wrong.exception)
    help_text = subprocess.run(exe + ["--help"], capture_output=True, text=True, timeout=60, env={**os.environ, "COLUMNS": "200"})
    assert "--rename" in help_text.stdout and "FILE:METHOD=NEW" in help_text.stdout


def test_compare_warns_when_its_files_mix_episodes_of_different_sensors_on_the_same_plans(tmp_path: Path):
    """A 360-degree LiDAR's eval and a 180-degree one's were pooled with no word (episodes.csv had no sensor column):
    the paired figures then compare sensors, not methods alone. episodes.csv now says each episode's setup
    (``sensor_fov_deg``, ``sim``, ``cell_size_m``) and ``compare`` warns, naming the values and their files, when
    the same plans ran under different ones; a file of an eval before the columns is read from the summary.json
    beside it, and without one it is not checked (files of none at all say nothing, as before)."""
    setup = ("sensor_fov_deg", "sim", "cell_size_m")

    def run(folder: str, method: str, efficiencies: dict[str, float], fov: float, sim: str = "2d") -> Path:
        (tmp_path / folder).mkdir()
        episodes = [{**r, "sensor_fov_deg": fov, "sim": sim, "cell_size_m": 0.05} for r in rows(method, "large", efficiencies)]
        return write_episodes_csv(tmp_path / folder / "episodes.csv", episodes, FIELDS + setup)

    base = run("base", "greedy-dist", {"a": 1.0, "b": 1.0, "c": 1.0}, 180.0)
    ring = run("ring", "cso", {"a": 1.2, "b": 1.2, "c": 1.1}, 360.0)
    front = run("front", "cso", {"a": 1.2, "b": 1.2, "c": 1.1}, 180.0)
    exe = [sys.executable, "-m", "cso_runtime.cli", "compare"]
    mixed = subprocess.run(exe + [str(base), str(ring)], capture_output=True, text=True, timeout=60)
    assert mixed.returncode == 0 and "| large | cso | 3 |" in mixed.stdout, mixed.stderr
    said = " ".join(mixed.stderr.split())
    assert f"warning: the same plans ran with different sensor_fov_deg: 180 ({base}), 360 ({ring}) on 3 plans (a, b, c)" in said, said
    assert "sim" not in said.replace("sensor_fov_deg", ""), said
    same = subprocess.run(exe + [str(base), str(front)], capture_output=True, text=True, timeout=60)
    assert same.returncode == 0 and same.stderr == "", same.stderr
    # An older file (no setup columns) is read from its summary.json's meta; with none it is not checked.
    (tmp_path / "old").mkdir()
    old = write(tmp_path / "old" / "episodes.csv", rows("cso", "large", {"a": 1.2, "b": 1.2, "c": 1.1}))
    alone = subprocess.run(exe + [str(base), str(old)], capture_output=True, text=True, timeout=60)
    assert alone.returncode == 0 and f"note: {old} says no setup (sensor_fov_deg, sim, cell_size_m, max_steps:" in " ".join(alone.stderr.split()), alone.stderr
    meta = {"sim": "mujoco", "config": {"sensor": {"fov_deg": 180.0}}, "cell_sizes_m": [0.05]}
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"meta": meta, "methods": {}}))
    read = subprocess.run(exe + [str(base), str(old)], capture_output=True, text=True, timeout=60)
    said = " ".join(read.stderr.split())
    assert read.returncode == 0 and f"the same plans ran with different sim: 2d ({base}), mujoco ({old})" in said and "sensor_fov_deg" not in said, said


def test_compare_warns_when_its_files_ran_the_same_plans_under_different_step_limits(tmp_path: Path):
    """``compare A B`` of a greedy-dist eval run to coverage (--max-steps 300) and a random one cut at 40 steps said
    random +36 % m2/step without a word: an episode cut short keeps the m2/step of its first steps, the most efficient.
    episodes.csv now says each episode's step limit (``max_steps``, the last column) and ``compare`` warns of it as of
    the sensor; a file of an eval before the column is read from the summary.json beside it."""
    from cso_runtime.comparison import SETUP_COLUMNS, mixed_setups_said

    assert SETUP_COLUMNS[-1] == "max_steps"
    setup = {"sensor_fov_deg": 180.0, "sim": "2d", "cell_size_m": 0.05}

    def run(folder: str, method: str, max_steps: int | None) -> Path:
        (tmp_path / folder).mkdir()
        episodes = [{**r, **setup, **({"max_steps": max_steps} if max_steps else {})} for r in rows(method, "middle", {"a": 1.0, "b": 1.1, "c": 0.9})]
        return write_episodes_csv(tmp_path / folder / "episodes.csv", episodes, FIELDS + tuple(setup) + (("max_steps",) if max_steps else ()))

    full, cut, also_full = run("full", "greedy-dist", 300), run("cut", "random", 40), run("also_full", "random", 300)
    (said,) = mixed_setups_said([("", full), ("", cut)])
    assert said.startswith(f"warning: the same plans ran with different max_steps: 300 ({full}), 40 ({cut}) on 3 plans (a, b, c)"), said
    assert mixed_setups_said([("", full), ("", also_full)]) == []
    old = run("old", "random", None)  # an eval before the column: its summary.json says the step limit
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"meta": {"sim": "2d", "config": {"sensor": {"fov_deg": 180.0}, "episode": {"max_steps": 40}}}, "methods": {}}))
    (said,) = mixed_setups_said([("", full), ("", old)])
    assert said.startswith(f"warning: the same plans ran with different max_steps: 300 ({full}), 40 ({old})"), said


def test_compare_warns_of_different_step_limits_only_where_an_episode_reached_the_lower_one(tmp_path: Path):
    """An eval with ``--max-steps 5000`` against one of the default 3000, every episode of both ended by coverage within
    600 steps: compare warned "their figures compare those too, not the methods alone", though each episode ended as
    it would have under either limit. Step limits are warned of where an episode of the plan took as many steps as the
    lowest limit (cut by it, or running past it under the other)."""
    from cso_runtime.comparison import mixed_setups_said

    def run(folder: str, method: str, max_steps: int, steps: dict[str, int]) -> Path:
        (tmp_path / folder).mkdir()
        setup = {"sensor_fov_deg": 180.0, "sim": "2d", "cell_size_m": 0.05, "max_steps": max_steps}
        episodes = [{**r, **setup, "steps": steps[r["map"]]} for r in rows(method, "large", {"a": 1.0, "b": 1.1, "c": 0.9})]
        return write_episodes_csv(tmp_path / folder / "episodes.csv", episodes, FIELDS + ("steps", *setup))

    base = run("base", "greedy-dist", 3000, {"a": 400, "b": 550, "c": 600})
    longer = run("longer", "cso", 5000, {"a": 380, "b": 500, "c": 590})
    assert mixed_setups_said([("", base), ("", longer)]) == []
    past = run("past", "cso", 5000, {"a": 380, "b": 3400, "c": 590})  # b ran past 3000 steps: greedy-dist's limit would have cut it
    (said,) = mixed_setups_said([("", base), ("", past)])
    assert said.startswith(f"warning: the same plans ran with different max_steps: 3000 ({base}), 5000 ({past}) on 1 plan (b)"), said


def test_compare_does_not_warn_of_a_plan_run_at_two_cell_sizes_by_every_method(tmp_path: Path):
    """``compare easy=A_0.05 easy=A_0.1`` (BENCHMARKS.md pools the Dungeon plans so, as ``tables.py`` does): a plan of one
    name at two cell sizes is two scenes (two traversable areas), each method's episodes paired at one cell size only,
    yet compare warned "the same plans ran with different cell_size_m ... their figures compare those too" (and of a
    step limit or a sensor that differed between the two evals). Setups are compared within a scene, as compare pairs
    episodes; methods of one scene that differ are still warned of."""
    from cso_runtime.comparison import mixed_setups_said

    def run(folder: str, cell_m: float, fov: float = 180.0, methods: tuple[str, ...] = ("greedy-dist", "cso")) -> Path:
        (tmp_path / folder).mkdir()
        setup = {"sensor_fov_deg": fov, "sim": "2d", "cell_size_m": cell_m, "max_steps": 3000 if cell_m == 0.05 else 1500}
        episodes = [
            {**r, **setup, "traversable_area_m2": 100.0 * (cell_m / 0.1) ** 2, "scale": "large" if cell_m == 0.1 else "middle"}
            for m in methods for r in rows(m, "large", {"a": 1.0, "b": 1.1, "c": 0.9})
        ]
        return write_episodes_csv(tmp_path / folder / "episodes.csv", episodes, FIELDS + tuple(setup))

    fine, coarse = run("fine", 0.05), run("coarse", 0.1)
    assert mixed_setups_said([("easy", fine), ("easy", coarse)]) == []
    ring = run("ring", 0.1, fov=360.0, methods=("cso",))  # cso again on the coarse scenes, with another sensor
    (said,) = mixed_setups_said([("easy", fine), ("easy", coarse), ("easy", ring)])
    assert said.startswith(f"warning: the same plans ran with different sensor_fov_deg: 180 ({coarse}), 360 ({ring}) on 3 plans (a, b, c)"), said


def test_compare_says_why_a_baseline_with_episodes_has_none_to_compare(tmp_path: Path):
    """``--baseline greedy-dist`` whose episodes have no m2/step (episodes of no step: the empty cell, or a value that
    is not finite), or are all on the maps ``--exclude`` leaves out, was told "has no episodes in these files; their
    methods: cso", untrue: they are there. It says why none is left to compare (exit 1: read, nothing to compare, as
    too few scenes), and a baseline the files do not hold is said as before."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    cso = rows("cso", "large", {"a": 1.1, "b": 1.1, "c": 1.1})
    no_steps = rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.0})
    for row, value in zip(no_steps, ("", "nan", "-inf"), strict=True):
        row["efficiency_m2_per_step"] = value
    episodes = write(tmp_path / "e.csv", no_steps + cso)
    r = CliRunner().invoke(app, ["compare", str(episodes)])
    assert r.exit_code == 1 and "has no episodes in these files" not in r.stderr, r.output
    assert "error: --baseline 'greedy-dist' has no episode to compare: none of its 3 in these files has an m2/step (an episode of no step has none)" in r.stderr, r.output
    episodes = write(tmp_path / "e.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0}) + cso)
    r = CliRunner().invoke(app, ["compare", str(episodes), "--exclude", "a,b"])
    assert r.exit_code == 1 and "error: --baseline 'greedy-dist' has no episode to compare: its 2 in these files are all on maps --exclude leaves out" in r.stderr, r.output
    r = CliRunner().invoke(app, ["compare", str(episodes), "--baseline", "greedy_dist"])
    assert r.exit_code == 2 and "--baseline 'greedy_dist' has no episodes in these files; their methods: cso, greedy-dist" in r.stderr, r.output


def test_compare_says_why_of_a_baseline_where_no_method_has_an_episode_left_to_compare(tmp_path: Path):
    """The baseline's words (a typo in ``--baseline``, exit 2; a baseline whose episodes have no m2/step or lie on maps
    ``--exclude`` leaves out, exit 1) were said only where another method had episodes left: where none had (every
    episode excluded, or of no step), a typo was "no method shares 3 or more scenes ... with greedy_dist", exit 1,
    as if it were a method of the files; and a baseline without m2/step the same, not why."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    episodes = write(tmp_path / "e.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0}) + rows("cso", "large", {"a": 1.1, "b": 1.1}))
    r = CliRunner().invoke(app, ["compare", str(episodes), "--exclude", "a,b", "--baseline", "greedy_dist"])
    assert r.exit_code == 2 and "error: --baseline 'greedy_dist' has no episodes in these files; their methods: cso, greedy-dist" in r.stderr, r.output
    r = CliRunner().invoke(app, ["compare", str(episodes), "--exclude", "a,b"])
    assert r.exit_code == 1 and "error: --baseline 'greedy-dist' has no episode to compare: its 2 in these files are all on maps --exclude leaves out" in r.stderr, r.output
    no_steps = rows("greedy-dist", "large", {"a": 1.0, "b": 1.0}) + rows("cso", "large", {"a": 1.1, "b": 1.1})
    for row in no_steps:
        row["efficiency_m2_per_step"] = ""
    episodes = write(tmp_path / "e.csv", no_steps)
    r = CliRunner().invoke(app, ["compare", str(episodes)])
    assert r.exit_code == 1 and "error: --baseline 'greedy-dist' has no episode to compare: none of its 2 in these files has an m2/step" in r.stderr, r.output
    r = CliRunner().invoke(app, ["compare", str(episodes), "--exclude", "a"])  # map a is there, its episodes of no step
    assert r.exit_code == 1 and "no such map" not in r.stderr and "none of its 1 in these files has an m2/step" in r.stderr, r.output
    r = CliRunner().invoke(app, ["compare", str(write(tmp_path / "none.csv", []))])  # a file of no episode: said, not a baseline's fault
    assert r.exit_code == 1 and "error: these files hold no episode" in r.stderr, r.output


def test_compare_takes_a_folder_whose_name_holds_an_equals_sign(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``compare lr=3e-4 lr=1e-3`` (the folders of a sweep, as hydra names its runs: ``lr=0.001,seed=1``) said "no such
    file: 3e-4": the argument was read as LABEL=FILE. A path that exists whole is that path, unlabelled, where the
    labelled reading names nothing; ``easy=FILE`` is still a label."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.comparison import labelled

    monkeypatch.chdir(tmp_path)
    for name, cso in (("lr=3e-4", 1.2), ("lr=1e-3,seed=1", 0.9)):
        Path(name).mkdir()
        write(Path(name) / "episodes.csv", rows("greedy-dist", "large", {"a": 1.0, "b": 1.0, "c": 1.0}) + rows(f"cso-{name[:2]}{cso}", "large", {"a": cso, "b": cso, "c": cso}))
    assert labelled("lr=3e-4") == ("", Path("lr=3e-4/episodes.csv"))
    assert labelled("easy=lr=3e-4") == ("easy", Path("lr=3e-4/episodes.csv"))
    assert labelled("easy=nope.csv") == ("easy", Path("nope.csv"))  # neither exists: the label's, as before
    r = CliRunner().invoke(app, ["compare", "lr=3e-4", "lr=1e-3,seed=1", "--json"])
    assert r.exit_code == 0, r.output
    assert sorted(row["method"] for row in json.loads(r.stdout)["comparisons"]) == ["cso-lr0.9", "cso-lr1.2"]
