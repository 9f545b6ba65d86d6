"""The command line's flags, consistent with each other: train's field flags (a list field's flag repeated adds to it,
two flags naming one field with different values are refused, ``--no-X=VALUE`` says what to write), ``eval --seed``
with ``--seeds``, and a Ctrl-C while the ``cso-runtime`` script imports the CLI."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import cso_runtime

REPO = Path(cso_runtime.__file__).resolve().parent.parent


@pytest.fixture
def train_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list:
    """The ``ppo.Args`` each ``train`` of the test ran with (the trainer itself replaced: nothing trains)."""
    from cso_runtime.learned import ppo

    ran: list = []
    monkeypatch.setattr(ppo, "train", lambda args, log=None, command="", stop_requested=None: ran.append(args) or {"ppo_decisions": 0, "warm_start_decisions": 0, "wall_time_s": 0.0})
    return ran


@pytest.fixture
def collect_teacher_stub(monkeypatch: pytest.MonkeyPatch) -> list:
    """``(args, workers)`` of each collection a ``collect-teacher`` of the test started (the rollouts replaced by an
    empty set, saved as an empty file: nothing is collected)."""
    from cso_runtime.learned import ppo

    class Collected:
        def __len__(self) -> int:
            return 0

        def save(self, path: Path) -> None:
            path.write_text("")

    ran: list = []
    monkeypatch.setattr(ppo, "collect_teacher_parallel", lambda args, workers, *rest, **kwargs: ran.append((args, workers)) or Collected())
    monkeypatch.setattr("cso_runtime.cli.interrupt_on_sigterm", lambda **_kwargs: None)
    return ran


def train(tmp_path: Path, *flags: str) -> tuple[int, str]:
    """``cso-runtime train`` with a one-plan config, ``--out`` in ``tmp_path`` unless the flags give one."""
    from cso_runtime.cli import app

    recipe = tmp_path / "mine.yaml"
    recipe.write_text("dungeon_dir: null\ngenerated: [generated:small:1:1000]\n")
    out = [] if "--out" in flags else ["--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, ["train", "--config", str(recipe), *out, *flags])
    return result.exit_code, " ".join(result.output.split())


def test_a_repeated_list_field_flag_adds_to_the_list_as_eval_seeds_does(tmp_path: Path, train_runs: list):
    """``train --generated A --generated B`` trained on B alone: a list field's flag given twice kept its last value,
    where the CLI's other list options (``eval --seeds``, ``up --without``) add each one. It adds now (and takes
    several values after it, as CleanRL's tyro does); a scalar flag given twice keeps its last value, as typer does
    with train's own options (``--seed 1 --seed 2``)."""
    a, b, c = "generated:small:1:1", "generated:small:1:2", "generated:middle:1:3"
    for flags, generated in [
        (["--generated", a, "--generated", b], [a, b]),
        (["--generated", a, "--generated", f"{b},{c}"], [a, b, c]),
        ([f"--generated={a}", "--generated", f"[{b}]"], [a, b]),
        (["--generated", a, b, "--gamma", "0.9"], [a, b]),
        (["--generated", a, "--set", f"generated=[{a}]"], [a]),  # the same value twice: fine
    ]:
        code, said = train(tmp_path, *flags)
        assert code == 0, said
        assert train_runs[-1].generated == generated, flags
    code, said = train(tmp_path, "--dungeon-m-per-px", "0.1", "--dungeon-m-per-px", "0.05,0.2")
    assert code == 0 and train_runs[-1].dungeon_m_per_px == [0.1, 0.05, 0.2], said
    code, said = train(tmp_path, "--seed", "1", "--seed", "2", "--gamma", "0.9", "--gamma", "0.95", "--no-norm-adv", "--norm-adv")
    assert code == 0 and (train_runs[-1].seed, train_runs[-1].gamma, train_runs[-1].norm_adv) == (2, 0.95, True), said
    code, said = train(tmp_path, "--generated", "--gamma", "0.9")
    assert code == 2 and "--generated needs a value" in said, said


def test_a_text_fields_flag_takes_its_text_as_it_is(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``train --out-dir 2024`` failed with "out_dir: expected a string, got 2024", and ``--generated A null`` with
    "expected a list": a field flag's text was read as YAML, as ``--set``'s is, so a text field's ``2024``, ``on`` or
    ``null`` turned into a number, true or nothing. A text field's flag (``config.text_field``) takes the text as it
    is, as CleanRL's tyro does; a nullable one's ``null`` is still None, and other fields still read YAML."""
    from cso_runtime.cli import args_field_flags, parse_settings

    monkeypatch.chdir(tmp_path)
    code, said = train(tmp_path, "--out", "2024", "--out-dir", "2024")  # the same value twice: fine
    assert code == 0 and train_runs[-1].out_dir == "2024", said
    code, said = train(tmp_path, "--out", "2024", "--out-dir", "2025")
    assert code == 2 and "--out 2024 and --out-dir 2025 both set out_dir, to different values" in said, said
    assert parse_settings(args_field_flags(["--generated", "a", "null", "--warm-start-data", "on,2024"])) == {
        "generated": ["a", "null"],
        "warm_start_data": ["on", "2024"],
    }
    assert parse_settings(args_field_flags(["--device", "on", "--dungeon-dir", "null", "--init-from", "2024", "--gamma", "0.9", "--lidar-fov-deg", "null"])) == {
        "device": "on",
        "dungeon_dir": None,
        "init_from": "2024",
        "gamma": 0.9,
        "lidar_fov_deg": None,
    }


def test_two_flags_setting_one_field_to_different_values_are_refused_naming_both(tmp_path: Path, train_runs: list):
    """``train --out A --out-dir B`` wrote into B, silently (the field flag went over train's own option), and so did
    any ``--set`` over a flag. Two flags that set one field to different values are refused before anything starts
    (exit 2), naming both; the same value given twice (a path with or without its slash) is fine."""
    out, other = tmp_path / "a", tmp_path / "b"
    for flags, said in [
        (["--out", str(out), "--out-dir", str(other)], f"--out {out} and --out-dir {other} both set out_dir, to different values: give one"),
        (["--out-dir", str(other), "--out", str(out)], f"--out {out} and --out-dir {other} both set out_dir"),
        (["--seed", "3", "--set", "seed=4"], "--seed 3 and --set seed=4 both set seed"),
        (["--gamma", "0.9", "--set", "gamma=0.99"], "--gamma 0.9 and --set gamma=0.99 both set gamma"),
        (["--async-envs", "--no-async-envs"], "--async-envs and --no-async-envs both set async_envs"),
        (["--generated", "generated:small:1:1", "--set", "generated=generated:small:1:2"], "both set generated"),
    ]:
        code, output = train(tmp_path, *flags)
        assert code == 2 and said in output, (flags, output)
    assert not train_runs and not out.exists() and not other.exists()
    for flags in (["--out", str(out), "--out-dir", f"{out}/"], ["--seed", "3", "--set", "seed=3"], ["--num-envs", "2", "--set", "num_envs=2"]):
        code, output = train(tmp_path, *flags)
        assert code == 0, (flags, output)
    assert Path(train_runs[0].out_dir) == out


def test_a_false_switch_given_a_value_says_what_to_write(tmp_path: Path, train_runs: list):
    """``train --no-progress=false`` said "progress is not a switch", which it is. ``--no-FIELD`` takes no value:
    the refusal says so and what to write for either value; a field that is no switch is still said to be none."""
    for flags in (["--no-progress=false"], ["--no-progress", "false"]):
        code, said = train(tmp_path, *flags)
        assert code == 2, said
        assert f"{' '.join(flags)}: --no-progress takes no value (it sets progress to false); write --no-progress for false, --progress for true, or --progress=VALUE" in said
        assert "not a switch" not in said
    code, said = train(tmp_path, "--no-gamma")
    assert code == 2 and "--no-gamma: gamma is not a switch (true or false); give --gamma VALUE" in said, said
    for flags, progress in [(["--no-progress"], False), (["--progress=false"], False), (["--progress", "true"], True)]:
        code, said = train(tmp_path, *flags)
        assert code == 0 and train_runs[-1].progress is progress, said


def test_eval_refuses_a_seed_given_with_seeds_zero_included(tmp_path: Path):
    """``eval --seed 3 --seeds 1,2`` was refused, but ``--seed 0 --seeds 1,2`` ran the seeds in silence: 0 was the
    default, so a --seed given could not be told from none. Any --seed given with --seeds is refused now; --seed
    alone (0 included) and --seeds alone run as before."""
    from cso_runtime.cli import app

    common = ["eval", "--method", "random", "--maps", "generated:small:1:0", "--dry-run"]
    for seed in ("0", "3"):
        r = CliRunner().invoke(app, [*common, "--out", str(tmp_path / "o"), "--seed", seed, "--seeds", "1,2"])
        assert r.exit_code == 2, r.output
        assert f"--seed {seed} and --seeds: give one (--seeds 1,2 runs each of those seeds)" in " ".join(r.stderr.split())
    for given, said in [(["--seed", "0"], "seed 0"), (["--seed", "3"], "seed 3"), ([], "seed 0"), (["--seeds", "1,2"], "seeds 1, 2")]:
        r = CliRunner().invoke(app, [*common, "--out", str(tmp_path / f"o{len(given)}{given[-1] if given else ''}"), *given])
        assert r.exit_code == 0 and said in r.output, (given, r.output, r.stderr)


@pytest.mark.parametrize("where", ["finding the CLI's module", "building the commands"])
def test_a_ctrl_c_while_the_script_imports_the_cli_exits_130_in_one_line(tmp_path: Path, where: str):
    """A Ctrl-C in any command's first ~0.05 s, while the ``cso-runtime`` script imported ``cso_runtime.cli`` (its
    entry point) outside the module's own ``try``, ended in a KeyboardInterrupt traceback. The entry point is the
    package's ``main`` now, which imports the CLI within its ``try``: one line, exit 130. The test runs the script
    pip writes for ``[project.scripts]`` with the Ctrl-C raised at a fixed point of that import (no timing)."""
    entry = re.search(r'^cso-runtime = "([\w.]+):(\w+)"$', (REPO / "pyproject.toml").read_text(), re.MULTILINE)
    assert entry is not None
    interrupt = {
        "finding the CLI's module": "class Interrupt:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'cso_runtime.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupt())\n",
        "building the commands": "import typer\ndef interrupt(*args, **kwargs):\n    raise KeyboardInterrupt\ntyper.Typer.__init__ = interrupt\n",
    }[where]
    script = tmp_path / "cso-runtime"
    script.write_text(f"import sys\n{interrupt}from {entry[1]} import {entry[2]}\nif __name__ == '__main__':\n    sys.exit({entry[2]}())\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}  # this checkout's package
    r = subprocess.run([sys.executable, str(script), "status", "--help"], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)
    assert (r.returncode, r.stderr, r.stdout) == (130, "error: interrupted\n", ""), r.stderr


@pytest.mark.parametrize(
    ("command", "said"),
    [
        (["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--set", "planner.lookahead_m=0"], "planner.lookahead_m must be in (0, 100] m (the local planner's longest distance: MAX_PLANNER_DISTANCE_M), got 0"),
        (["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--set", "planner.lookahead_m=1e9"], "planner.lookahead_m must be in (0, 100] m (the local planner's longest distance: MAX_PLANNER_DISTANCE_M), got 1,000,000,000"),
        (["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--set", "planner.backup_distance_m=-1"], "planner.backup_distance_m must be in (0, 5] m"),
        (["up", "--profile", "sim", "--set", "exploration.planner.lookahead_m=0"], "exploration.planner.lookahead_m must be in (0, 100] m"),
        (["up", "--profile", "sim", "--set", "exploration.episode.replan_every_steps=0"], "exploration.episode.replan_every_steps must be in [1, 1,000,000]"),
    ],
)
def test_an_out_of_range_value_ends_the_command_at_once_naming_the_key_value_and_range(tmp_path: Path, command: list[str], said: str):
    """``cso-runtime eval --set planner.lookahead_m=0`` (or 1e9 m) was taken and ran its episodes with it; ``up`` with
    the same key started the services. The real command now exits 2 at once (no episode, no service, nothing written
    in --out or --runs-dir), in one line that names the key, the value and the range."""
    place = ["--out", str(tmp_path / "out")] if command[0] == "eval" else ["--runs-dir", str(tmp_path / "runs"), "--no-live"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}  # this checkout's package
    r = subprocess.run([sys.executable, "-m", "cso_runtime.cli", *command, *place], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert said in " ".join(r.stderr.split()) and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def test_eval_refuses_max_steps_with_a_set_step_limit_of_another_value(tmp_path: Path):
    """``eval --max-steps 5 --set episode.max_steps=9`` ran 5 steps an episode, in silence (the flag took over the
    ``--set``). Refused now, as ``train --seed 3 --set seed=4`` is (one shared check: ``config.refuse_two_values``),
    naming both; the same value twice runs."""
    from cso_runtime.cli import app

    common = ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run"]
    for given, said in [
        (["--max-steps", "5", "--set", "episode.max_steps=9"], "--max-steps 5 and --set episode.max_steps=9 both set episode.max_steps, to different values: give one"),
        (["--set", "episode={max_steps: 7}", "--max-steps", "5"], "--max-steps 5 and --set episode={max_steps: 7} both set episode.max_steps"),
    ]:
        r = CliRunner().invoke(app, [*common, *given])
        assert r.exit_code == 2 and said in " ".join(r.stderr.split()), (given, r.output)
    r = CliRunner().invoke(app, [*common, "--max-steps", "5", "--set", "episode.max_steps=5"])
    assert r.exit_code == 0 and "at most 5 steps an episode" in r.output, r.output


def test_a_number_written_two_ways_says_the_fields_type_error_not_different_values(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``eval --max-steps 40 --set episode.max_steps=40.0`` was refused as "different values", where the one problem is
    that 40.0 is no integer: 40 and 40.0 are one value (``config.yaml_value_compared``), and the field's own type error
    is said, as ``--set episode.max_steps=40.0`` alone says it; ``up`` and ``train`` (``--seed 3 --set seed=3.0``)
    likewise. Another number is still "different values"."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    cases = [
        (["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run", "--max-steps", "40",
          "--set", "episode.max_steps=40.0"], "episode.max_steps: expected an integer, got 40.0"),
        (["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run", "--seed", "3", "--set", "seed=3.0"], "seed: expected an integer, got 3.0"),
        (["train", "--out", str(tmp_path / "t"), "--seed", "3", "--set", "seed=3.0"], "seed: expected an integer, got 3.0"),
    ]
    for command, said in cases:
        r = CliRunner().invoke(app, command)
        assert r.exit_code == 2 and said in " ".join(r.stderr.split()) and "different values" not in r.stderr, (command, r.output)
    r = CliRunner().invoke(app, [*cases[0][0][:-2], "--set", "episode.max_steps=41.0"])
    assert r.exit_code == 2 and "--max-steps 40 and --set episode.max_steps=41.0 both set episode.max_steps, to different values" in " ".join(r.stderr.split()), r.output
    assert not train_runs and not (tmp_path / "o").exists() and not (tmp_path / "t").exists()


def test_up_refuses_a_flag_and_a_set_of_the_same_key_with_another_value(tmp_path: Path):
    """``up --seed 3 --set seed=4`` ran seed 4, ``up --namespace a --set services.ros2_bridge.namespace=b`` namespace
    a: one of the two took over the other in silence. Each such pair is refused (exit 2, naming both) before anything
    starts; the same value twice is fine."""
    from cso_runtime.cli import app

    common = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    for given, said in [
        (["--seed", "3", "--set", "seed=4"], "--seed 3 and --set seed=4 both set seed, to different values: give one"),
        (["--real-time", "--set", "lockstep=true"], "--real-time and --set lockstep=true both set lockstep"),
        (["--scene", "generated:small:1:0", "--set", "scene=builtin"], "--scene generated:small:1:0 and --set scene=builtin both set scene"),
        (["--method", "utility", "--set", "method=greedy-dist"], "--method utility and --set method=greedy-dist both set method"),
        (
            ["--profile", "limo-ros2", "--connect", "tcp/127.0.0.1:7447", "--namespace", "a", "--set", "services.ros2_bridge.namespace=b"],
            "--namespace a and --set services.ros2_bridge.namespace=b both set services.ros2_bridge.namespace",
        ),
    ]:
        r = CliRunner().invoke(app, [*common, *given])
        assert r.exit_code == 2 and said in " ".join(r.stderr.split()), (given, r.output)
    for given in (["--seed", "3", "--set", "seed=3"], ["--lockstep", "--set", "lockstep=true"], ["--seed", "3", "--set", "exploration.episode.max_steps=9"]):
        r = CliRunner().invoke(app, [*common, *given])
        assert r.exit_code == 0, (given, r.output)
    assert not (tmp_path / "runs").exists()


def test_collect_teacher_refuses_a_flag_and_a_set_of_the_same_field_with_another_value(tmp_path: Path, collect_teacher_stub: list):
    """``collect-teacher --seed 3 --set seed=4`` collected with seed 4, in silence; ``train`` refused it. Both commands
    refuse it now through the one check, before any rollout; equal values run, and ``--set warm_start_teacher``
    without ``--teacher`` is taken (the default teacher, rollout, is no flag given)."""
    from cso_runtime.cli import app

    ran = collect_teacher_stub
    recipe = tmp_path / "mine.yaml"
    recipe.write_text("dungeon_dir: null\ngenerated: [generated:small:1:1000]\nwarm_start_teacher: greedy-dist\n")
    common = ["collect-teacher", "--config", str(recipe), "--out", str(tmp_path / "t.npz")]
    for given, said in [
        (["--seed", "3", "--set", "seed=4"], "--seed 3 and --set seed=4 both set seed, to different values: give one"),
        (["--teacher", "utility", "--set", "warm_start_teacher=greedy-dist"], "--teacher utility and --set warm_start_teacher=greedy-dist both set warm_start_teacher"),
    ]:
        r = CliRunner().invoke(app, [*common, *given])
        assert r.exit_code == 2 and said in " ".join(r.output.split()), (given, r.output)
    assert not ran
    for given, seed, teacher in [
        (["--seed", "3", "--set", "seed=3"], 3, "rollout"),
        (["--set", "warm_start_teacher=utility"], None, "utility"),
        (["--teacher", "greedy-info", "--set", "warm_start_teacher=greedy-info"], None, "greedy-info"),
    ]:
        r = CliRunner().invoke(app, [*common, *given])
        assert r.exit_code == 0, (given, r.output)
        args = ran[-1][0]
        assert args.warm_start_teacher == teacher and (seed is None or args.seed == seed), given


def test_python_m_cso_runtime_runs_the_command(tmp_path: Path):
    """``python -m cso_runtime --version`` (the way to run a package's command without its script on PATH, a venv
    not activated) said "No module named cso_runtime.__main__; 'cso_runtime' is a package and cannot be directly
    executed". It runs the ``cso-runtime`` command, as the script does."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}  # this checkout's package
    r = subprocess.run([sys.executable, "-m", "cso_runtime", "--version"], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith(f"cso-runtime {cso_runtime.__version__}\n"), (r.stdout, r.stderr)


def test_collect_teacher_bounds_its_workers_as_train_bounds_num_envs(tmp_path: Path, collect_teacher_stub: list):
    """``collect-teacher --workers 5000`` started 5,000 processes (one environment each), where ``train --num-envs 5000``
    is refused since the bounds (``learned.ppo.ARGS_BOUNDS``: at most ``MAX_ENVS``, no machine has more cores). The
    same bound, exit 2 before any rollout; 1,024 is taken."""
    from cso_runtime.cli import app
    from cso_runtime.learned import ppo

    recipe = tmp_path / "mine.yaml"
    recipe.write_text("dungeon_dir: null\ngenerated: [generated:small:1:1000]\n")
    common = ["collect-teacher", "--config", str(recipe), "--out", str(tmp_path / "t.npz"), "--teacher", "greedy-dist"]
    ran = collect_teacher_stub
    r = CliRunner().invoke(app, [*common, "--workers", str(ppo.MAX_ENVS + 1)])
    assert r.exit_code == 2 and "--workers must be in [1, 1,024] (MAX_ENVS), got 1,025" in " ".join(r.output.split()), r.output
    assert not ran
    r = CliRunner().invoke(app, [*common, "--workers", str(ppo.MAX_ENVS)])
    assert r.exit_code == 0 and [workers for _args, workers in ran] == [ppo.MAX_ENVS], r.output


def test_status_watch_period_is_bounded_before_anything_is_asked(tmp_path: Path):
    """``status --watch --period 1e300`` was taken, and its wait overflowed Python's own timeout while a run went on.
    Refused at once now (exit 2, typer's range check), as 0.05 already was; the bounds themselves are taken."""
    from cso_runtime.cli import app

    for period in ("1e300", "3600.5", "0.05"):
        r = CliRunner().invoke(app, ["status", "--watch", "--period", period, "--runs-dir", str(tmp_path / "runs")])
        assert r.exit_code == 2 and "--period" in r.output, (period, r.output)
    r = CliRunner().invoke(app, ["status", "--period", "3600", "--runs-dir", str(tmp_path / "runs")])
    assert r.exit_code == 1, r.output  # taken: nothing runs here, which status says (exit 1)


def test_a_set_read_as_a_number_where_the_flag_gives_text_says_so_not_different_values(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``up --robot 1 --set robot=1`` was refused as "different values": ``--set`` reads YAML, so ``robot=1`` is the
    number 1 where ``--robot 1`` gives the text "1" (and ``--set robot=1`` alone is refused: a robot id is text).
    The refusal says that now, and how to write it (``--set robot='1'``, which runs); ``train --out-dir 2024 --set
    out_dir=2024`` and ``eval --max-steps 5 --set episode.max_steps='5'`` likewise. Different values are still
    "different values"."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    said = "--set robot=1 is read as a number, and robot is text (as --robot 1 gives it): write --set robot='1', or give --robot 1 alone"
    for given in (["--robot", "1", "--set", "robot=1"], ["--set", "robot=1", "--robot", "1"]):
        r = CliRunner().invoke(app, [*up, *given])
        assert r.exit_code == 2 and said in " ".join(r.stderr.split()) and "different values" not in r.stderr, (given, r.output)
    r = CliRunner().invoke(app, [*up, "--robot", "on", "--set", "robot=on"])  # YAML 1.1's on: true
    assert r.exit_code == 2 and "--set robot=on is read as true/false, and robot is text (as --robot on gives it): write --set robot='on'" in " ".join(r.stderr.split()), r.output  # as typed
    r = CliRunner().invoke(app, [*up, "--robot", "1", "--set", "robot='1'"])
    assert r.exit_code == 0 and "robot: '1'" in r.output, r.output
    r = CliRunner().invoke(app, [*up, "--robot", "2", "--set", "robot=1"])
    assert r.exit_code == 2 and "--robot 2 and --set robot=1 both set robot, to different values: give one" in " ".join(r.stderr.split()), r.output
    assert not (tmp_path / "runs").exists()

    code, out = train(tmp_path, "--out", "2024", "--out-dir", "2024", "--set", "out_dir=2024")
    assert code == 2 and "--set out_dir=2024 is read as a number, and out_dir is text (as --out 2024 gives it): write --set out_dir='2024', or give --out 2024 alone" in out, out
    code, out = train(tmp_path, "--out", "2024", "--set", "out_dir=2024")
    assert code == 2 and "--set out_dir=2024 is read as a number, and out_dir is text (as --out 2024 gives it)" in out, out
    assert not train_runs
    code, out = train(tmp_path, "--out", "2024", "--out-dir", "2024", "--set", "out_dir='2024'")
    assert code == 0 and train_runs[-1].out_dir == "2024", out

    r = CliRunner().invoke(app, ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run", "--max-steps", "5", "--set", "episode.max_steps='5'"])
    said = "--set episode.max_steps='5' is read as text, and episode.max_steps is a number (as --max-steps 5 gives it): write --set episode.max_steps=5"
    assert r.exit_code == 2 and said in " ".join(r.stderr.split()), r.output


def test_a_set_alone_read_as_a_number_where_the_field_is_text_says_how_to_write_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --set robot=1`` alone said only "robot: expected a string, got 1", where beside ``--robot 1`` it said how to
    write it: the same hint now (``config.read_as_another_type``), and ``--set robot='1'`` runs."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    r = CliRunner().invoke(app, [*up, "--set", "robot=1"])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "--set robot=1 is read as a number, and robot is text: write --set robot='1'" in said and "expected a string" not in said, r.output
    r = CliRunner().invoke(app, [*up, "--set", "robot='1'"])
    assert r.exit_code == 0 and "robot: '1'" in r.output, r.output
    r = CliRunner().invoke(app, [*up, "--set", "robot=[1]"])  # no text that the field takes: its own type error, as before
    assert r.exit_code == 2 and "robot: expected a string" in " ".join(r.stderr.split()), r.output
    assert not (tmp_path / "runs").exists()


def test_a_set_of_a_nested_key_read_as_a_number_where_the_field_is_text_says_how_to_write_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The hint of ``up --set robot=1`` (``config.read_as_another_type``) was given for top-level keys alone: ``--set
    services.foxglove_bridge.mcap_path=2024`` (a file named 2024) said only "expected a string, got 2024", and
    ``--set router.zenoh_config=2024`` blamed the profile file ("sim.yaml: router.zenoh_config must be a file path").
    A key of a service (``services.NAME.``), of a section (``router.``) or of the exploration (``exploration.planner.``,
    eval's ``planner.``) gets it too, and the hint is given only where the text it suggests is taken (``--set
    method=1`` suggested ``method='1'``, an unknown method; ``planner.body`` takes disc or box alone): otherwise the
    value's own error, naming the flag."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    for key in ("services.foxglove_bridge.mcap_path", "services.foxglove_bridge.map_frame"):
        r = CliRunner().invoke(app, [*up, "--foxglove", "--set", f"{key}=2024"])
        said = " ".join(r.stderr.split())
        assert r.exit_code == 2 and f"--set {key}=2024 is read as a number, and {key} is text: write --set {key}='2024'" in said, (key, r.output)
        r = CliRunner().invoke(app, [*up, "--foxglove", "--set", f"{key}='2024'"])
        assert r.exit_code == 0 and f"{key.rpartition('.')[2]}: '2024'" in r.output, (key, r.output)
    # A Zenoh config file is named with its extension: 2024 is no file path as text either, so no hint; the flag is named, not the profile.
    (tmp_path / "2024").write_text("{}\n")
    r = CliRunner().invoke(app, [*up, "--set", "router.zenoh_config=2024"])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "write --set" not in said and "with --set router.zenoh_config=2024: router.zenoh_config must be a file path (text), got 2024" in said, r.output
    for given in (["--set", "method=1"], ["--set", "exploration.planner.body=1"]):  # a text that is refused too: no hint
        r = CliRunner().invoke(app, [*up, *given])
        said = " ".join(r.stderr.split())
        assert r.exit_code == 2 and "write --set" not in said and f"with --set {given[-1]}" in said, (given, r.output)
    r = CliRunner().invoke(app, ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run", "--set", "planner.body=1"])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "write --set" not in said and "planner.body: expected a string, got 1" in said, r.output
    assert not (tmp_path / "runs").exists()


def test_a_train_set_alone_read_as_a_number_where_the_field_is_text_says_how_to_write_it(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """docs/training.md: "``--set out_dir=2024`` is the number 2024, which the refusal says: ``--set out_dir='2024'``".
    Beside ``--out 2024`` it did; alone, ``train`` said "out_dir: expected a string, got 2024", and ``--set
    dungeon_dir=2024`` (a folder named for its year) "dungeon_dir: 2024 does not fit str | None", a Python type
    where ``up --set robot=1`` alone says how to write it. ``train`` and ``collect-teacher`` say it as ``up`` does
    (where the folder is there: the hint's value passes the command's check, as
    ``test_a_train_set_hint_suggests_only_a_value_the_training_check_takes`` says)."""
    import shutil

    from cso_runtime.cli import app
    from cso_runtime.scenes import builtin_scene_dir

    monkeypatch.chdir(tmp_path)
    shutil.copytree(builtin_scene_dir(), tmp_path / "2024")  # a folder of plans named for its year
    for command, key in (("train", "out_dir"), ("train", "dungeon_dir"), ("collect-teacher", "dungeon_dir")):
        out = ["--out", str(tmp_path / "t.npz")] if command == "collect-teacher" else []
        r = CliRunner().invoke(app, [command, *out, "--set", f"{key}=2024"])
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and f"--set {key}=2024 is read as a number, and {key} is text: write --set {key}='2024'" in said, (command, said)
    assert not train_runs


def test_a_train_set_read_as_a_number_whose_text_is_refused_too_gets_no_hint(tmp_path: Path, train_runs: list):
    """``up`` and ``eval`` give the how-to-write-it hint of ``--set KEY=1`` only where the text is taken (``--set
    method=1`` would suggest ``method='1'``, an unknown method); ``train`` and ``collect-teacher`` used the same
    helper without that check: ``--set variant=1`` said "write --set variant='1'", which is refused in turn ("unknown
    variant '1'"), and so did ``device=0`` and ``warm_start_teacher=1``. They say the value's own error, naming the
    flag, as ``up`` does; ``out_dir=2024`` keeps its hint."""
    from cso_runtime.cli import app

    npz = ["--out", str(tmp_path / "t.npz")]
    for command, key in (("train", "variant"), ("train", "device"), ("train", "warm_start_teacher"), ("collect-teacher", "variant"), ("collect-teacher", "warm_start_teacher")):
        r = CliRunner().invoke(app, [command, *(npz if command == "collect-teacher" else []), "--set", f"{key}=1"])
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and "write --set" not in said and f"--set {key}=1: {key}: expected a string, got 1" in said, (command, said)
    r = CliRunner().invoke(app, ["train", "--set", "out_dir=2024", "--set", "variant=1"])  # each its own: no hint of a config refused either way
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "write --set" not in said, said
    assert not train_runs


def test_one_path_written_two_ways_is_one_value(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``up --scene ./plans --set scene=plans`` and ``up --zenoh-config ./z.json5 --set router.zenoh_config=$PWD/z.json5``
    were refused as "different values": one path, written two ways. A path-valued field's values are compared as the
    command resolves them, against the current folder (``train --out`` and ``--set out_dir`` too); a scene spec that
    is no path (``builtin``, ``generated:...``) is compared as text, so ``./builtin`` (a folder of that name) is another
    value than ``builtin``, as is a folder elsewhere of the same name."""
    import shutil

    from cso_runtime.cli import app
    from cso_runtime.scenes import builtin_scene_dir

    monkeypatch.chdir(tmp_path)
    (tmp_path / "plans").mkdir()
    (tmp_path / "sub").mkdir()
    shutil.copy(next(builtin_scene_dir().glob("*.png")), tmp_path / "plans")
    (tmp_path / "z.json5").write_text("{}\n")
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    for given, shown in [
        (["--scene", "./plans", "--set", "scene=plans"], f"scene: {tmp_path.resolve() / 'plans'}"),
        (["--scene", str(tmp_path / "plans"), "--set", "scene=./sub/../plans/"], f"scene: {tmp_path.resolve() / 'plans'}"),
        (["--scene", "builtin", "--set", "scene=builtin"], "scene: builtin"),
        (["--zenoh-config", "./z.json5", "--set", f"router.zenoh_config={tmp_path / 'z.json5'}"], f"zenoh_config: {tmp_path / 'z.json5'}"),
        (["--zenoh-config", str(tmp_path / "z.json5"), "--set", "router={zenoh_config: ./z.json5}"], f"zenoh_config: {tmp_path / 'z.json5'}"),
    ]:
        r = CliRunner().invoke(app, [*up, *given])
        assert r.exit_code == 0 and shown in r.output, (given, r.output)
    for given, said in [
        (["--scene", "builtin", "--set", "scene=./builtin"], "--scene builtin and --set scene=./builtin both set scene, to different values"),
        (["--scene", "generated:small:1:0", "--set", "scene=./generated:small:1:0"], "--scene generated:small:1:0 and --set scene=./generated:small:1:0 both set scene"),
        (["--scene", "./plans", "--set", "scene=../plans"], "--scene ./plans and --set scene=../plans both set scene, to different values"),
        (["--zenoh-config", "z.json5", "--set", "router.zenoh_config=../z.json5"], "--zenoh-config z.json5 and --set router.zenoh_config=../z.json5 both set router.zenoh_config"),
    ]:
        r = CliRunner().invoke(app, [*up, *given])
        assert r.exit_code == 2 and said in " ".join(r.stderr.split()), (given, r.output)
    assert not (tmp_path / "runs").exists()

    code, out = train(tmp_path, "--out", "./runs/a", "--set", f"out_dir={tmp_path / 'runs' / 'a'}")
    assert code == 0 and Path(train_runs[-1].out_dir).resolve() == (tmp_path / "runs" / "a").resolve(), out
    code, out = train(tmp_path, "--out", "runs/a", "--set", "out_dir=../runs/a")
    assert code == 2 and "--out runs/a and --set out_dir=../runs/a both set out_dir, to different values" in out, out
    code, out = train(tmp_path, "--init-from", "shipped", "--set", "init_from=./shipped")  # the shipped weights, or a file named shipped
    assert code == 2 and "--init-from shipped and --set init_from=./shipped both set init_from, to different values" in out, out


def test_a_set_value_that_is_not_yaml_is_said_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``--set "a=[1"`` printed YAML's own error over eight lines (its caret drawing included), where every other error
    of the CLI is one line (docs/commands.md); so did a config file that is not YAML, over three."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run", "--set", "exploration=[1"])
    assert r.exit_code == 2 and r.stderr.startswith("error: --set exploration=[1: not valid YAML: while parsing a flow sequence") and r.stderr.count("\n") == 1, r.stderr
    (tmp_path / "bad.yaml").write_text("a: [1, 2\n")
    r = CliRunner().invoke(app, ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run", "--config", "bad.yaml"])
    assert r.exit_code == 2 and r.stderr.startswith("error: bad.yaml: not valid YAML") and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "runs").exists()


def test_an_error_of_a_value_up_was_given_by_a_flag_names_the_flag_not_the_profile_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --connect notanendpoint`` said "sim.yaml: router: bad zenoh endpoint ...", and ``up --zenoh-config
    nosuch.json5`` "sim.yaml: router: zenoh config ...: No such file": the profile file blamed for a flag's value. The
    error names the flags that changed the profile, as it does those of ``--set``, ``--scene`` and ``--without``."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    for given in (["--connect", "notanendpoint"], ["--zenoh-config", "nosuch.json5"]):
        r = CliRunner().invoke(app, [*up, *given])
        said = " ".join(r.stderr.split())
        assert r.exit_code == 2 and f"sim.yaml with {' '.join(given)}: router: " in said, (given, said)
    assert not (tmp_path / "runs").exists()


def test_up_dry_run_checks_the_folders_up_would_write_in(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --dry-run --runs-dir FILE`` (or a ``--record-out`` whose folder cannot be made) said "valid: `up` would start
    sim, mapper, ..." and exited 0, where ``up`` refuses them (exit 2) before anything starts. The dry run checks them
    in the same words, as ``eval --dry-run`` checks ``--out``, and makes nothing."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("")
    for given, said in [
        (["--runs-dir", "notes.txt"], "error: --runs-dir notes.txt: cannot create the folder"),
        (["--runs-dir", str(tmp_path / "runs"), "--record-out", "notes.txt/run.mcap"], "error: --record-out notes.txt/run.mcap: its folder notes.txt: cannot create the folder"),
        (["--runs-dir", str(tmp_path / "runs"), "--record-out", "notes.txt/sub/"], "error: --record-out notes.txt/sub: cannot create the folder"),
    ]:
        dry = CliRunner().invoke(app, ["up", "--dry-run", *given])
        assert dry.exit_code == 2 and dry.stderr.startswith(said) and "would start" not in dry.output, (given, dry.output)
    r = CliRunner().invoke(app, ["up", "--dry-run", "--runs-dir", str(tmp_path / "new" / "runs"), "--record-out", "rec/"])
    assert r.exit_code == 0 and "would start" in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]  # nothing made



def test_up_resolved_prints_the_profile_wherever_the_run_would_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --resolved`` prints the profile as the run would use it, a file to run again later (elsewhere, with other
    folders): it took ``--dry-run``'s check of ``--runs-dir`` and ``--record-out`` (``up --dry-run`` checks the folders
    up would write in) and refused to print where the runs folder cannot be made here, though neither is in what it
    prints. It prints the profile; ``--dry-run``, alone or with ``--resolved``, checks the folders as before."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("")
    (tmp_path / "old.mcap").write_text("")
    plain = CliRunner().invoke(app, ["up", "--resolved"])
    assert plain.exit_code == 0 and "robot: r0" in plain.stdout, plain.output
    for given in (["--runs-dir", "notes.txt"], ["--record-out", "notes.txt/run.mcap"], ["--record-out", "old.mcap"]):
        r = CliRunner().invoke(app, ["up", "--resolved", *given])
        assert r.exit_code == 0 and r.stdout == plain.stdout and "error" not in r.output, (given, r.output)
        dry = CliRunner().invoke(app, ["up", "--resolved", "--dry-run", *given])
        assert dry.exit_code == 2 and dry.stderr.startswith(f"error: {given[0]} ") and "robot: r0" not in dry.output, (given, dry.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "old.mcap"]  # nothing made

def test_a_nan_given_to_a_bounded_number_flag_is_said_as_such_not_as_out_of_one_bound(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``status --period nan`` said "Input should be less than or equal to 3600", and ``runs --older-than nan`` "greater
    than or equal to 0": untrue of nan, which is neither. A bounded number flag says its range and the value given, for
    nan and for a value out of it; a value within it is taken as before."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    for args, said in [  # in config.Bound's words, as a config key's range is said
        (["status", "--period", "nan"], "must be in [0.1, 3,600] s, got nan"),
        (["status", "--period", "5000"], "must be in [0.1, 3,600] s, got 5,000"),
        (["runs", "--older-than", "nan"], "must be >= 0 days, got nan"),
        (["runs", "--older-than", "-1"], "must be >= 0 days, got -1"),
        (["down", "--timeout-s", "nan"], "must be >= 0 s, got nan"),
        (["router", "--connect-timeout-s", "nan"], "must be > 0 s, got nan"),
        (["router", "--connect-timeout-s", "0"], "must be > 0 s, got 0"),
        (["collect-teacher", "--out", "t.npz", "--time-limit-s", "nan"], "must be >= 0 s, got nan"),
        (["status", "--period", "soon"], "must be a number in [0.1, 3,600] s, got soon"),
    ]:
        r = CliRunner().invoke(app, args)
        said_now = " ".join(r.output.split())
        assert r.exit_code == 2 and said in said_now and "Input should be" not in said_now, (args, r.output)
    (tmp_path / "empty").mkdir()  # a runs folder that does not exist is said so, exit 1
    r = CliRunner().invoke(app, ["runs", "--older-than", "1.5", "--runs-dir", str(tmp_path / "empty")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["status", "--help"])
    assert "0.1<=x<=3600" in " ".join(r.output.split()), r.output  # the range is still in the help
    # --connect-timeout-s holds router.connect_timeout_s's rule, as a profile's: 0.0005 s was refused (">= 0.001") where a
    # profile takes it; the endpoint's own error comes next here. Its largest is the key's, said in the same words.
    r = CliRunner().invoke(app, ["router", "--connect-timeout-s", "0.0005", "--connect", "notanendpoint"])
    assert r.exit_code == 2 and r.stderr.startswith("error: bad zenoh endpoint 'notanendpoint'"), r.output
    r = CliRunner().invoke(app, ["router", "--connect-timeout-s", "1e9"])
    said_now = " ".join(r.output.split())
    assert r.exit_code == 2 and "must be in (0, 86,400] s (a day: config.MAX_WAIT_S), got 1,000,000,000" in said_now, r.output


def test_an_error_of_a_section_a_set_broke_names_the_set_where_up_connect_or_foxglove_reads_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --connect E --set router=5`` said "sim.yaml: router must be a mapping", the profile file blamed for the
    ``--set`` (without --connect, the same error names it); so did ``--set router.connect=5`` beside ``--connect`` and
    ``--set services=5`` beside ``--foxglove`` or ``--without``: the blocks that apply those flags read the profile before
    its flags were named. Their errors name the flags that changed it, as every other error of the profile does."""
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    up = ["up", "--runs-dir", str(tmp_path / "runs"), "--dry-run"]
    for given, said in [
        (["--connect", "tcp/127.0.0.1:7447", "--set", "router=5"], "sim.yaml with --connect tcp/127.0.0.1:7447 --set router=5: router must be a mapping"),
        (["--connect", "tcp/127.0.0.1:7447", "--set", "router.connect=5"], "sim.yaml with --connect tcp/127.0.0.1:7447 --set router.connect=5: router.connect"),
        (["--foxglove", "--set", "services=5"], "sim.yaml with --set services=5 --foxglove: services must be a mapping"),
        (["--without", "policy", "--set", "services=5"], "sim.yaml with --set services=5 --without policy: services must be a mapping"),
    ]:
        r = CliRunner().invoke(app, [*up, *given])
        said_now = " ".join(r.stderr.split())
        assert r.exit_code == 2 and said in said_now, (given, r.output)
    assert not (tmp_path / "runs").exists()


SAME_MISTAKES = {  # the one mistake of each kind, as each command's keys write it: (its --set items, the words said)
    "up": {
        "a number for a text field": (["robot=1"], "--set robot=1"),
        "a key twice": (["seed=1", "seed=2"], "--set seed=1 and --set seed=2 both set seed, to different values: give one"),
        "a key twice in one value": (["exploration.episode={max_steps: 1, max_steps: 2}"], "found key 'max_steps' twice"),
        "an underscore number": (["seed=1_000"], "--set seed=1_000: seed: expected an integer, got '1_000' (YAML 1.2 reads a number with _ as text: write 1000)"),
        "nan": (["exploration.planner.lookahead_m=nan"], "--set exploration.planner.lookahead_m=nan: exploration.planner.lookahead_m: must be finite, got nan"),
        "YAML's nan": (["exploration.planner.lookahead_m=.nan"], "--set exploration.planner.lookahead_m=.nan: exploration.planner.lookahead_m: must be finite, got nan"),
        "YAML's infinity": (["exploration.planner.lookahead_m=-.inf"], "--set exploration.planner.lookahead_m=-.inf: exploration.planner.lookahead_m: must be finite, got -inf"),
        "an unknown key": (["nosuch=1"], "--set nosuch=1: unknown key(s) nosuch; known:"),
        "an out-of-bounds value": (["exploration.planner.lookahead_m=0"], "--set exploration.planner.lookahead_m=0: exploration.planner.lookahead_m must be in (0, 100] m"),
    },
    "eval": {
        "a number for a text field": (["planner.body=1"], "--set planner.body=1: planner.body: expected a string, got 1"),
        "a key twice": (["episode.max_steps=5", "episode.max_steps=6"], "--set episode.max_steps=5 and --set episode.max_steps=6 both set episode.max_steps, to different values: give one"),
        "a key twice in one value": (["episode={max_steps: 1, max_steps: 2}"], "found key 'max_steps' twice"),
        "an underscore number": (["episode.max_steps=1_000"], "--set episode.max_steps=1_000: episode.max_steps: expected an integer, got '1_000' (YAML 1.2 reads a number with _ as text: write 1000)"),
        "nan": (["planner.lookahead_m=nan"], "--set planner.lookahead_m=nan: planner.lookahead_m: must be finite, got nan"),
        "YAML's nan": (["planner.lookahead_m=.nan"], "--set planner.lookahead_m=.nan: planner.lookahead_m: must be finite, got nan"),
        "YAML's infinity": (["planner.lookahead_m=-.inf"], "--set planner.lookahead_m=-.inf: planner.lookahead_m: must be finite, got -inf"),
        "an unknown key": (["nosuch=1"], "--set nosuch=1: unknown key(s) nosuch; known:"),
        "an out-of-bounds value": (["planner.lookahead_m=0"], "--set planner.lookahead_m=0: planner.lookahead_m must be in (0, 100] m"),
    },
    "train": {
        "a number for a text field": (["warm_start_teacher=1"], "--set warm_start_teacher=1: warm_start_teacher: expected a string, got 1"),
        "a key twice": (["seed=1", "seed=2"], "--set seed=1 and --set seed=2 both set seed, to different values: give one"),
        "a key twice in one value": (["generated={a: 1, a: 2}"], "found key 'a' twice"),
        "an underscore number": (["seed=1_000"], "--set seed=1_000: seed: expected an integer, got '1_000' (YAML 1.2 reads a number with _ as text: write 1000)"),
        "nan": (["gamma=nan"], "--set gamma=nan: gamma: must be finite, got nan"),
        "YAML's nan": (["gamma=.nan"], "--set gamma=.nan: gamma: must be finite, got nan"),
        "YAML's infinity": (["gamma=-.inf"], "--set gamma=-.inf: gamma: must be finite, got -inf"),
        "an unknown key": (["nosuch=1"], "--set nosuch=1: unknown key(s) nosuch; known:"),
        "an out-of-bounds value": (["gamma=2"], "--set gamma=2: gamma must be in (0, 1], got 2"),
    },
}
SAME_MISTAKES["collect-teacher"] = SAME_MISTAKES["train"]


@pytest.mark.parametrize(("command", "mistake"), [(command, mistake) for command, cases in SAME_MISTAKES.items() for mistake in cases])
def test_each_command_that_takes_set_says_the_same_mistake_alike(tmp_path: Path, command: str, mistake: str, train_runs: list, collect_teacher_stub: list):
    """The same bad ``--set`` through each command that takes one (``up``, ``eval``, ``train``, ``collect-teacher``):
    each exits 2 before anything runs, in one line on stderr that names the ``--set`` as typed and the same words for
    the same mistake. Before: a key given twice (``--set seed=1 --set seed=2``) ran with the last in silence in all
    four; ``train`` and ``collect-teacher`` said a note on their config file's fields before the error (two lines), and
    hinted ``--set warm_start_teacher='1'``, a teacher they then refused, where ``up`` and ``eval`` hint only a text
    the configuration takes; ``collect-teacher`` named ``--teacher rollout``, its default, among the flags given."""
    from cso_runtime.cli import app

    recipe = tmp_path / "mine.yaml"
    recipe.write_text("dungeon_dir: null\ngenerated: [generated:small:1:1000]\n")  # a few fields: train's note on the rest
    place = {
        "up": ["--runs-dir", str(tmp_path / "runs"), "--dry-run"],
        "eval": ["--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "out"), "--dry-run"],
        "train": ["--config", str(recipe), "--out", str(tmp_path / "out")],
        "collect-teacher": ["--config", str(recipe), "--out", str(tmp_path / "out" / "t.npz")],
    }[command]
    items, said = SAME_MISTAKES[command][mistake]
    r = CliRunner().invoke(app, [command, *place, *(word for item in items for word in ("--set", item))])
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert r.stderr.startswith("error: ") and r.stderr.count("\n") == 1, r.stderr
    assert said in r.stderr and f"--set {items[-1]}" in r.stderr, r.stderr
    assert "--teacher" not in r.stderr, r.stderr  # collect-teacher's default teacher is no flag the user typed
    assert not train_runs and not collect_teacher_stub and not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()


def test_a_set_key_given_twice_is_refused_unless_its_value_is_the_same():
    """``--set seed=1 --set seed=2`` ran seed 2, the first dropped in silence (a key twice in one YAML mapping is
    refused). Refused now through ``config.refuse_two_values``, naming both as typed; the same value twice is fine, and
    train's field flags (``last_counts``) keep their last value, as typer's options do."""
    from cso_runtime.cli import parse_settings
    from cso_runtime.config import ConfigError

    with pytest.raises(ConfigError, match=re.escape("--set seed=1 and --set seed=on both set seed, to different values: give one")):
        parse_settings(["seed=1", "seed=on"])
    assert parse_settings(["seed=1", " seed = 01"]) == {"seed": 1}
    assert parse_settings(["seed=1", "seed=2"], last_counts=True) == {"seed": 2}


@pytest.mark.parametrize(
    ("first", "second"),
    [("1", "1.0"), ("1e3", "1000"), ("0x10", "16"), (".nan", ".nan"), ("[1, {a: 2}]", "[1.0, {a: 2e0}]"), ("{a: 1, b: 2}", "{b: 2, a: 1}")],
)
def test_a_set_key_given_twice_with_the_same_number_is_one_value(first: str, second: str):
    """``--set gamma=1 --set gamma=1.0`` was refused as two values (``both set gamma, to different values``): the
    same number, written two ways, as ``refuse_two_values`` takes ``1e3`` and ``1000.0`` for a flag and its ``--set``.
    One value now, numbers compared as numbers, in a list or a mapping too (and ``.nan`` twice: the same text);
    the last is kept."""
    from cso_runtime.cli import parse_settings

    assert parse_settings([f"k={first}", f"k={second}"]).typed == {"k": second}


@pytest.mark.parametrize(("first", "second"), [("1", "true"), ("0", "false"), ("[1]", "[true]"), ("{a: 0}", "{a: false}"), ("1", "'1'"), ("[1, 2]", "[2, 1]")])
def test_a_set_key_given_twice_with_values_alike_only_to_python_is_refused(first: str, second: str):
    """``1 == True`` in Python, and ``[1] == [True]``: ``--set generated=[1] --set generated=[true]`` was taken as the
    same value twice, the first dropped in silence. true is no number, nor a text a number, in a list too."""
    from cso_runtime.cli import parse_settings
    from cso_runtime.config import ConfigError

    with pytest.raises(ConfigError, match=re.escape(f"--set k={first} and --set k={second} both set k, to different values: give one")):
        parse_settings([f"k={first}", f"k={second}"])


@pytest.mark.parametrize(
    ("items", "said"),
    [
        (["episode.max_steps=5", "episode={max_steps: 6}"], "--set episode.max_steps=5 and --set episode={max_steps: 6} both set episode.max_steps, to different values: give one"),
        (["episode={max_steps: 6}", "episode.max_steps=5"], "--set episode={max_steps: 6} and --set episode.max_steps=5 both set episode.max_steps, to different values: give one"),
        (["a.b.c=1", "a={b: {c: 2}}"], "--set a.b.c=1 and --set a={b: {c: 2}} both set a.b.c, to different values: give one"),
        (
            ["episode.max_steps=5", "episode={replan_every_steps: 3}"],
            (
                "--set episode={replan_every_steps: 3} replaces all of episode, without episode.max_steps: --set episode.max_steps=5 would be dropped;"
                " give it in episode's value, or after it"
            ),
        ),
    ],
)
def test_a_set_key_and_its_section_given_other_values_are_refused(items: list[str], said: str):
    """``--set episode.max_steps=5 --set 'episode={max_steps: 6}'`` ran 6 (a later section replaces the key, as
    ``set_dotted`` does), and ``--set 'episode={max_steps: 6}' --set episode.max_steps=5`` ran 5: one field given two
    values, the first dropped in silence, where the same key twice is refused. Refused alike now; and a section given
    after a key of it, without that key, which dropped the key's value in silence."""
    from cso_runtime.cli import parse_settings
    from cso_runtime.config import ConfigError

    with pytest.raises(ConfigError, match=re.escape(said)):
        parse_settings(items)


@pytest.mark.parametrize(
    "items",
    [
        ["episode.max_steps=5", "episode={max_steps: 5.0, replan_every_steps: 3}"],  # the same value: fine
        ["episode={max_steps: 5}", "episode.replan_every_steps=3"],  # a key of the section after it: one more key
        ["episode.max_steps=5", "episode.replan_every_steps=3", "episodes=1"],  # not a section of each other
    ],
)
def test_a_set_key_and_its_section_that_agree_are_taken(items: list[str]):
    from cso_runtime.cli import parse_settings

    assert list(parse_settings(items)) == [item.partition("=")[0] for item in items]


def test_train_takes_one_number_given_twice_and_records_it_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``train --set gamma=1 --set gamma=1.0`` (the same number) runs, and records one pair, which runs again."""
    import shlex

    from cso_runtime.learned import ppo

    commands: list[str] = []
    monkeypatch.setattr(ppo, "train", lambda args, log=None, command="", stop_requested=None: commands.append(command) or {"ppo_decisions": 0, "warm_start_decisions": 0, "wall_time_s": 0.0})
    code, said = train(tmp_path, "--set", "gamma=1", "--set", "gamma=1.0", "--gamma", "1")
    assert code == 0, said
    words = shlex.split(commands[-1])
    assert [w for w in words if w.startswith("gamma=")] == ["gamma=1.0"], commands[-1]
    code, said = train(tmp_path, *words[2:])
    assert code == 0 and shlex.split(commands[-1]) == words, said


@pytest.mark.parametrize("value", ["0", "nan", "20"])
def test_m_per_px_out_of_its_range_is_said_alike_by_eval_and_scenes(tmp_path: Path, value: str):
    """``scenes --m-per-px 0`` said "metres per pixel must be a number in (0, 10]" and ``eval --m-per-px 0`` "--m-per-px
    must be a positive number of metres per pixel" (its 20 refused in resolve_scenes' words): two checks of one range. One now
    (``scenes.M_PER_PX_BOUND``, a ``config.Bound``), said in the same words by both, naming the flag."""
    from cso_runtime.cli import app

    said = f"error: --m-per-px must be in (0, 10] m (scenes.MAX_M_PER_PX), got {value}\n"
    for command in (["scenes", "generated:small:1:0"], ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--dry-run"]):
        r = CliRunner().invoke(app, [*command, "--m-per-px", value])
        assert r.exit_code == 2 and r.stderr == said, (command, r.output)


def test_train_records_a_command_that_runs_again_with_one_pair_a_field(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``train --gamma 0.9 --gamma 0.95`` (a field flag given twice keeps its last value) recorded ``--set gamma=0.9
    --set gamma=0.95`` in its command, which, run again, a --set key given twice with other values refuses. The
    command holds one pair a field, its last value, and runs again as recorded."""
    import shlex

    from cso_runtime.learned import ppo

    commands: list[str] = []
    monkeypatch.setattr(ppo, "train", lambda args, log=None, command="", stop_requested=None: commands.append(command) or {"ppo_decisions": 0, "warm_start_decisions": 0, "wall_time_s": 0.0})
    code, said = train(tmp_path, "--gamma", "0.9", "--gamma", "0.95", "--set", "gamma=0.95", "--seed", "1")
    assert code == 0, said
    words = shlex.split(commands[-1])
    assert [w for w in words if w.startswith("gamma=")] == ["gamma=0.95"], commands[-1]
    code, said = train(tmp_path, *words[2:])
    assert code == 0 and shlex.split(commands[-1]) == words, said


def test_the_stop_signals_handler_imports_nothing(monkeypatch: pytest.MonkeyPatch):
    """``interrupt_on_sigterm``'s handler imported ``processes.end_overdue_stop`` at ``train``'s first stop signal: an
    import in a signal handler waits on the import lock, which the main thread it interrupted may hold (the signal
    landing in an import), so the stop could hang before its bound was even set. It is bound with the handler, before
    any signal; the handler imports nothing, and bounds the stop as before."""
    import atexit
    import builtins
    import signal

    from cso_runtime import cli, processes
    from cso_runtime.config import EXIT_INTERRUPTED

    bounded: list[tuple] = []
    monkeypatch.setattr(processes, "end_overdue_stop", lambda *args: bounded.append(args))  # no watch thread that ends pytest
    monkeypatch.setattr(atexit, "register", lambda fn: fn)  # the test's process keeps its own end

    def words() -> str:
        return "interrupted; continue with --resume"

    signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    kept = {sig: signal.getsignal(sig) for sig in signals}
    try:
        stop_requested = cli.interrupt_on_sigterm(wait_on_second=True, stop_deadline_s=60.0, last_words=words)
        handler = signal.getsignal(signal.SIGTERM)
    finally:
        for sig, previous in kept.items():
            signal.signal(sig, previous)
    assert callable(handler) and not stop_requested()
    imported: list[str] = []
    real_import = builtins.__import__

    def tracked(name: str, *args: object, **kwargs: object) -> object:
        imported.append(name)
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    interrupted = False
    builtins.__import__ = tracked
    try:
        handler(signal.SIGTERM, None)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        builtins.__import__ = real_import
    assert interrupted and stop_requested()
    assert imported == [], imported
    assert bounded == [(60.0, EXIT_INTERRUPTED, words)], bounded


def test_a_train_set_hint_suggests_only_a_value_the_training_check_takes(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``train --set generated=1`` said "write --set generated='1'", and ``--set init_from=1`` "write --set
    init_from='1'": each refused in turn ("scene spec '1' is not a folder, ...", "--init-from 1: no such file"), the
    hint taken from the fields' types alone. A hint's values now pass the check the command makes of its configuration
    before anything starts (``training_args``' ``check``: scenes, checkpoint, weights); else the value's own error is
    said. A folder of plans named 2024 gets the hint, which runs; and a refusal that is not the value's (the config's
    Dungeon folder missing) leaves the hint of ``out_dir=2024`` as it was."""
    import shutil

    from cso_runtime.scenes import builtin_scene_dir

    monkeypatch.chdir(tmp_path)
    for key in ("generated", "init_from", "resume"):
        code, out = train(tmp_path, "--set", f"{key}=1")
        assert code == 2 and "write --set" not in out and f"--set {key}=1" in out, (key, out)
    shutil.copytree(builtin_scene_dir(), tmp_path / "2024")
    code, out = train(tmp_path, "--set", "generated=2024")
    assert code == 2 and "--set generated=2024 is read as a number, and generated is text: write --set generated='2024'" in out, out
    code, out = train(tmp_path, "--set", "generated='2024'")
    assert code == 0 and train_runs[-1].generated == ["2024"], out
    no_dungeon = tmp_path / "no_dungeon.yaml"
    no_dungeon.write_text("dungeon_dir: not_here\n")
    from cso_runtime.cli import app

    r = CliRunner().invoke(app, ["train", "--config", str(no_dungeon), "--set", "out_dir=2024"])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "--set out_dir=2024 is read as a number, and out_dir is text: write --set out_dir='2024'" in said, said
    assert len(train_runs) == 1


def test_a_train_set_hint_is_said_beside_another_set_the_check_refuses(tmp_path: Path, train_runs: list, monkeypatch: pytest.MonkeyPatch):
    """``train --set dungeon_dir=2024 --set init_from=gone.pt``: the hint's configuration (``dungeon_dir='2024'``) was
    weighed against one without any ``--set``, which has no ``init_from`` to refuse, so the refusal of ``gone.pt`` was
    taken for the hint's and ``dungeon_dir: expected a string, got 2024`` was said instead of how to write it, as
    before the hints were checked. Only the values the hint writes as text are left out of that configuration."""
    import shutil

    from cso_runtime.scenes import builtin_scene_dir

    monkeypatch.chdir(tmp_path)
    shutil.copytree(builtin_scene_dir(), tmp_path / "2024")  # a folder of plans named for its year
    code, out = train(tmp_path, "--set", "dungeon_dir=2024", "--set", "init_from=gone.pt")
    assert code == 2 and "--set dungeon_dir=2024 is read as a number, and dungeon_dir is text: write --set dungeon_dir='2024'" in out, out
    code, out = train(tmp_path, "--set", "dungeon_dir='2024'", "--set", "init_from=gone.pt")
    assert code == 2 and "gone.pt: no such file" in out, out  # the hint taken: the other value's own refusal
    code, out = train(tmp_path, "--set", "generated=1", "--set", "init_from=gone.pt")
    assert code == 2 and "write --set" not in out, out  # '1' is no scene spec either: no hint that fails in turn
    assert not train_runs


def test_a_home_folder_in_a_flag_equals_value_is_the_home_folder(tmp_path: Path):
    """``eval --out=~/results`` (the ``=`` form, where bash and sh leave the ``~`` alone) wrote into a folder named
    ``~`` in the current folder, one a later ``rm -rf ~`` would take for the home folder. ``--flag=~/...`` is now
    the home folder, as ``--flag ~/...`` is after the shell; other values are kept as typed."""
    from cso_runtime.cli import home_in_option_values

    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    env = {**os.environ, "HOME": str(home), "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    r = subprocess.run([sys.executable, "-m", "cso_runtime", "eval", "--maps", "generated:small:1:0", "--out=~/results", "--dry-run"], capture_output=True, text=True, cwd=work, env=env, timeout=60)
    assert r.returncode == 0, r.stderr
    assert f"output: {home / 'results'}: a new folder" in r.stdout, r.stdout
    assert not (work / "~").exists()
    kept = ["--set", "out=~/x", "--set=key=~/x", "--robot=~user", "--reason=a~/b", "~/typed-alone", "--", "--out=~/after"]
    assert home_in_option_values(kept) == kept
    assert home_in_option_values(["--out=~", "-v", "--runs-dir=~/runs"]) == [f"--out={Path('~').expanduser()}", "-v", f"--runs-dir={Path('~/runs').expanduser()}"]


def test_a_config_file_that_is_a_folder_or_unreadable_is_one_line_not_a_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``eval --config FOLDER`` said "config file not found" of a folder that is there; a config file the user may not
    read (another user's, mode 0600) ended in a PermissionError traceback (``config.load_yaml`` caught YAML errors
    only; a map YAML's reader said it in one line). Both are one line now, exit 2, naming the path."""
    from cso_runtime.cli import app

    folder = tmp_path / "configs"
    folder.mkdir()
    result = CliRunner().invoke(app, ["eval", "--maps", "generated:small:1:0", "--config", str(folder), "--dry-run"])
    assert result.exit_code == 2 and f"{folder} is a folder; give the YAML file" in " ".join(result.output.split()), result.output
    locked = tmp_path / "theirs.yaml"
    locked.write_text("episode: {max_steps: 5}\n")
    real_open = Path.open

    def no_permission(self: Path, *args: object, **kwargs: object):  # root reads a 0000 file: refuse it as for a user
        if self == locked:
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "open", no_permission)
    result = CliRunner().invoke(app, ["eval", "--maps", "generated:small:1:0", "--config", str(locked), "--dry-run"])
    assert result.exit_code == 2, result.exception
    assert f"{locked}: cannot read the config file (Permission denied)" in " ".join(result.output.split()), result.output


def test_every_number_flag_says_its_default():
    """``eval --limit``, ``logs --tail``, ``train --total-decisions`` and others said what a number is but not what
    it is when left out (all the scenes? every line? the recipe's?), where ``status --period`` shows ``[default:
    1.0]``. Every option that takes a number says its default now: typer's ``[default: ...]`` or ``default`` in its
    help."""
    import typer

    from cso_runtime.cli import app

    silent = []
    for name, command in typer.main.get_command(app).commands.items():
        for param in command.params:
            annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
            if param.param_type_name != "option" or annotation not in (int, float, int | None, float | None):
                continue
            shown = param.show_default is not False and param.default is not None
            if not shown and "default" not in (param.help or ""):
                silent.append(f"{name} {param.opts[0]}")
    assert silent == [], silent


def test_pause_says_a_reason_no_receiver_would_take_before_sending_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``pause --reason`` of 5,000 characters was sent, refused by the launcher and every service (a pause's reason
    holds at most 1,024), and the robot went on exploring; a reason of a byte UTF-8 cannot carry (``$'\\xff'`` from a
    Latin-1 terminal) ended in a UnicodeEncodeError traceback as it was sent. The first is refused before anything is
    sent (exit 2, saying the limit), the second escaped (``\\udcff``), as every other text of a message is."""
    from cso_runtime import status
    from cso_runtime.cli import app
    from cso_runtime.messages import MAX_RESUME_REASON_CHARS, ExploreResumeMsg, decode, encode

    sent: list[str] = []
    monkeypatch.setattr(status, "explore_resume_main", lambda connect, robot, runs_dir, resume, reason="": sent.append(reason) or 0)
    r = CliRunner().invoke(app, ["pause", "--runs-dir", str(tmp_path), "--reason", "x" * (MAX_RESUME_REASON_CHARS + 1)])
    assert r.exit_code == 2 and "--reason is 1,025 characters; at most 1,024" in " ".join(r.output.split()) and sent == [], r.output
    r = CliRunner().invoke(app, ["pause", "--runs-dir", str(tmp_path), "--reason", "x" * MAX_RESUME_REASON_CHARS])
    assert r.exit_code == 0 and len(sent[-1]) == MAX_RESUME_REASON_CHARS, r.output
    r = CliRunner().invoke(app, ["pause", "--runs-dir", str(tmp_path), "--reason", "caf\udcff"])
    assert r.exit_code == 0 and sent[-1] == "caf\\udcff", r.output
    for reason in sent:  # what the receivers take
        assert decode(encode(ExploreResumeMsg(False, "me@here", reason, 1.0))).reason == reason
