"""A goal selector of the user's own, named ``module.path:Attribute`` wherever a method is taken: ``eval --method``
(beside the built-in ones), ``up --method`` and a profile's ``method:``, the policy service in its own process."""

from __future__ import annotations

import csv
import json
import os
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cso_runtime.cli import app
from cso_runtime.config import ConfigError
from cso_runtime.evaluation import own_method_code_sha256
from cso_runtime.policies import make_policy
from cso_runtime.run_profile import load_profile
from cso_runtime.supervision import pid_alive, python_module_argv
from tests.own_method_example import NearestStraightLine
from tests.test_runtime import PROFILES, REPO, SCENE, in_process_result, kill_leftovers, run_pids, write_profile

OWN = "tests.own_method_example:NearestStraightLine"
OWN_FOLDER = "tests.own_method_example_NearestStraightLine"
"""Where its episodes go: the spec as a folder name (``outputs.file_stem``: the colon becomes ``_``)."""


def test_eval_runs_a_method_of_ones_own_beside_a_builtin_one_and_resume_keeps_its_episodes(tmp_path: Path):
    out = tmp_path / "o"
    args = ["eval", "--method", f"{OWN},greedy-dist", "--maps", "generated:small:1:0", "--out", str(out), "--max-steps", "30"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["methods"]) == [OWN, "greedy-dist"]  # results under the spec, as given
    with (out / "episodes.csv").open() as fh:
        assert sorted(row["method"] for row in csv.DictReader(fh)) == sorted([OWN, "greedy-dist"])
    assert (out / "episodes" / OWN_FOLDER / "gen_small_0.npz").is_file()
    assert (out / "maps" / OWN_FOLDER / "gen_small_0.yaml").is_file()
    again = CliRunner().invoke(app, [*args, "--resume"])
    assert again.exit_code == 0, again.output
    assert json.loads((out / "summary.json").read_text())["meta"]["resumed_episodes"] == 2


def test_a_factory_builds_the_selector_and_make_policy_resets_it():
    assert isinstance(make_policy("tests.own_method_example:make_nearest", seed=3), NearestStraightLine)
    assert isinstance(make_policy(OWN), NearestStraightLine)


@pytest.mark.parametrize(
    ("method", "said"),
    [
        ("no_such_module_here:Nearest", ["cannot import module 'no_such_module_here'", "must be importable", "PYTHONPATH"]),
        (
            "tests.own_method_example:NearestStraighLine",
            ["tests.own_method_example has no attribute 'NearestStraighLine' (did you mean NearestStraightLine?)"],
        ),
        ("tests.own_method_example:NOT_A_SELECTOR", ["not a GoalSelector: it has no name, reset, select"]),
        ("tests.own_method_example:", ["module.path:Attribute"]),
    ],
)
def test_a_method_of_ones_own_that_cannot_be_used_is_said_before_anything_runs(tmp_path: Path, method: str, said: list[str]):
    out = tmp_path / "o"
    r = CliRunner().invoke(app, ["eval", "--method", f"greedy-dist,{method}", "--maps", "generated:small:1:0", "--out", str(out)])
    assert r.exit_code == 2, r.output
    for words in said:
        assert words in " ".join(r.output.split()), r.output
    assert "Traceback" not in r.output and not out.exists()
    with pytest.raises(ConfigError, match="module.path:Attribute|no attribute|not a GoalSelector|cannot import"):
        load_profile("lockstep", {"method": method})  # `up --method` and a profile's method:
    with pytest.raises(ConfigError, match=r"services\.policy\.method"):
        load_profile("lockstep", settings={"services.policy.method": method})


def test_the_settings_fingerprint_counts_the_source_file_of_a_method_of_ones_own(tmp_path: Path, monkeypatch):
    (tmp_path / "my_selectors.py").write_text("from tests.own_method_example import NearestStraightLine as Nearest\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = own_method_code_sha256("my_selectors:Nearest")
    assert before and own_method_code_sha256("greedy-dist") == ""
    (tmp_path / "my_selectors.py").write_text("from tests.own_method_example import NearestStraightLine as Nearest  # tuned\n")
    assert own_method_code_sha256("my_selectors:Nearest") != before


def test_up_runs_the_episode_with_a_method_of_ones_own_in_the_policy_service(tmp_path: Path):
    """Real processes in lockstep: the policy service imports the method as ``up`` did (the module on PYTHONPATH,
    which the services inherit), and the episode is the one ``run_episode`` gives with the same selector."""
    assert "policy" in (PROFILES / "lockstep.yaml").read_text()
    profile = write_profile(tmp_path, SCENE, OWN)
    runs = tmp_path / "runs"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    try:
        r = subprocess.run(
            [*python_module_argv("cso_runtime.cli"), "up", "--profile", str(profile), "--no-live", "--runs-dir", str(runs)],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 0, r.stderr[-3000:]
        (summary_path,) = list(runs.glob("*/summary.json"))
        metrics = json.loads(summary_path.read_text())["methods"][OWN]
        expected = in_process_result(SCENE, OWN)
        assert metrics["steps"] == expected.steps and metrics["terminated_by"] == {expected.terminated_by: 1}
        assert (summary_path.parent / "episodes" / OWN_FOLDER / f"{expected.scene}.npz").is_file()
        assert f"serving robot r0 with {OWN}" in (summary_path.parent / "logs" / "policy.log").read_text()
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
    finally:
        kill_leftovers(runs)


def test_an_installed_package_registers_a_method_by_a_short_name(tmp_path: Path, monkeypatch):
    """``cso_runtime.methods`` entry points: the short name runs the spec it stands for and names the results; a
    built-in name is not taken over."""
    import importlib.metadata

    from cso_runtime.policies import METHOD_ENTRY_POINTS, own_method_spec

    registered = [
        importlib.metadata.EntryPoint("nearest-line", OWN, METHOD_ENTRY_POINTS),
        importlib.metadata.EntryPoint("greedy-dist", OWN, METHOD_ENTRY_POINTS),
    ]
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: [ep for ep in registered if ep.group == group])
    assert own_method_spec("nearest-line") == OWN and own_method_spec("greedy-dist") is None
    assert isinstance(make_policy("nearest-line"), NearestStraightLine)
    assert type(make_policy("greedy-dist")).__name__ == "GreedyDist"
    out = tmp_path / "o"
    r = CliRunner().invoke(
        app, ["eval", "--method", "nearest-line", "--maps", "generated:small:1:0", "--out", str(out), "--max-steps", "5"]
    )
    assert r.exit_code == 0, r.output
    assert list(json.loads((out / "summary.json").read_text())["methods"]) == ["nearest-line"]


def test_the_docs_example_is_the_selector_the_tests_run():
    import re

    text = (REPO / "docs" / "own-method.md").read_text(encoding="utf-8")
    (example,) = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert example in (REPO / "tests" / "own_method_example.py").read_text(encoding="utf-8")
