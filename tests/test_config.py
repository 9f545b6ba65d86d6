"""Typed configs: YAML files fill the dataclasses; bad keys and values are clear errors."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

import cso_runtime
from cso_runtime.config import ConfigError, ExplorationConfig, from_dict, load_yaml, to_dict

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_eval_yaml_documents_the_defaults():
    data = load_yaml(CONFIGS / "eval.yaml")
    defaults = to_dict(ExplorationConfig())
    assert set(data) == set(defaults)
    for section, values in data.items():
        for key, value in values.items():
            assert defaults[section][key] == value, f"{section}.{key}"
    assert to_dict(from_dict(ExplorationConfig, data)) == defaults


@pytest.mark.parametrize(
    "data, message",
    [
        ({"masks": {"beta_far": 3}}, "unknown key"),
        ({"masks": {"beta_far_m": "far"}}, "expected a number"),
        ({"episode": {"max_steps": 2.5}}, "expected an integer"),
        ({"masks": {"use_stuck": "yes"}}, "true/false"),
        ({"masks": {"beta_far_m": 0.1}}, "beta_near_m < beta_far_m"),
        ({"masks": {"alpha3_m": -1.0}}, "alpha"),
        ({"sensor": {"fov_deg": 400.0}}, "fov_deg"),
        ({"robot": {"radius_m": float("nan")}}, "finite"),
        ({"sensor": 3}, "mapping"),
        ({"sensor": {"range_noise_std_m": -0.1}}, "range_noise_std_m"),
        ({"robot": {"control_period_s": 0.0}}, "control_period_s"),
        ({"robot": {"radius_m": -0.2}}, "radius_m"),
        ({"frontier": {"entropy_window_m": 0.0}}, "entropy_window_m"),
        ({"episode": {"max_steps": -3}}, "max_steps"),
        ({"episode": {"done_coverage_pct": 120.0}}, "done_coverage_pct"),
        ({"episode": {"goal_tolerance_m": 0.0}}, "goal_tolerance_m"),
        ({"planner": {"stop_distance_m": 0.8}}, "stop_distance_m <= slow_down_distance_m"),
        ({"planner": {"rotate_in_place_rad": 4.0}}, "rotate_in_place_rad"),
        ({"planner": {"progress_window_s": 0.0}}, "progress_window_s"),
        ({"planner": {"progress_recoveries": -1}}, r"planner.progress_recoveries must be in \[0, 1,000\]"),
        ({"planner": {"escape_distance_m": 0.0}}, r"planner.escape_distance_m must be in \(0, 5\] m"),
        ({"sensor": {"mount_x_m": 50.0}}, "sensor.mount_x_m .* puts the sensor off the robot"),
        ({"sensor": {"mount_x_m": -0.5}}, "sensor.mount_x_m .* puts the sensor off the robot"),
    ],
)
def test_bad_values_are_clear_errors(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(ExplorationConfig, data)


def test_load_yaml_errors(tmp_path: Path):
    with pytest.raises(ConfigError, match="not found"):
        load_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML") as unclosed:
        load_yaml(bad)
    assert str(bad) in str(unclosed.value).split("not valid YAML", 1)[1]  # YAML's own line points at the file
    assert "\n" not in str(unclosed.value)  # one line, as every error of the CLI (YAML's spans three)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"a: \xa4\xff\x00\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml(binary)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_yaml(listy)


def test_a_key_given_twice_in_a_config_is_an_error_not_a_silent_override(tmp_path: Path):
    """YAML's loaders keep the last of two equal keys: an edited profile would lose its first value unseen."""
    twice = tmp_path / "twice.yaml"
    twice.write_text("supervision:\n  hang_timeout_s: 5.0\n  max_restarts: 1\n  hang_timeout_s: 20.0\n")
    with pytest.raises(ConfigError, match=r"found key 'hang_timeout_s' twice \(first at line 2\)") as err:
        load_yaml(twice)
    assert str(twice) in str(err.value) and "line 4" in str(err.value)
    again = tmp_path / "again.yaml"  # the same key in two different mappings is two keys
    again.write_text("a: {x: 1}\nb: {x: 2}\n")
    assert load_yaml(again) == {"a": {"x": 1}, "b": {"x": 2}}
    shipped = sorted((Path(cso_runtime.__file__).parent / "profiles").glob("*.yaml"))
    assert {p.name for p in shipped} >= {"sim.yaml", "lockstep.yaml", "limo-ros2.yaml"}, shipped  # the profiles are there
    for profile in shipped:
        assert isinstance(load_yaml(profile), dict), profile  # the shipped profiles name each key once


def test_train_set_overrides_parse_yaml_values_and_reject_bad_pairs():
    from cso_runtime.cli import parse_settings

    assert parse_settings(["gamma=0.995", "generated=[a, b]", "dungeon_dir=null"]) == {"gamma": 0.995, "generated": ["a", "b"], "dungeon_dir": None}
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_settings(["gamma"])
    with pytest.raises(ConfigError, match="gamma"):
        parse_settings(["gamma=[1"])


def test_exponent_numbers_without_a_dot_are_numbers(tmp_path: Path):
    """PyYAML reads ``1e-8`` (no dot, YAML 1.1) as a string: a float field takes it as the number; other
    strings stay errors."""
    f = tmp_path / "masks.yaml"
    f.write_text("masks: {beta_far_m: 2e0, alpha3_m: 15E-1}\n")
    cfg = from_dict(ExplorationConfig, load_yaml(f))
    assert cfg.masks.beta_far_m == 2.0 and cfg.masks.alpha3_m == 1.5
    for bad in ("1e", "e5", "2.0m"):
        with pytest.raises(ConfigError, match="expected a number"):
            from_dict(ExplorationConfig, {"masks": {"beta_far_m": bad}})
    with pytest.raises(ConfigError, match="must be finite, got nan"):  # refused too, as .nan is
        from_dict(ExplorationConfig, {"masks": {"beta_far_m": "nan"}})


def test_eval_step_limit_comes_from_the_config_unless_the_flag_is_given(tmp_path: Path):
    """``eval --max-steps`` overrides ``episode.max_steps`` only when given: the flag's absence keeps the file's."""
    from cso_runtime.evaluation import EvalRequest

    f = tmp_path / "eval.yaml"
    f.write_text("episode: {max_steps: 120}\n")
    assert EvalRequest(methods=["greedy-dist"], config_path=f).exploration_config().episode.max_steps == 120
    assert EvalRequest(methods=["greedy-dist"], config_path=f, max_steps=40).exploration_config().episode.max_steps == 40
    assert EvalRequest(methods=["greedy-dist"]).exploration_config().episode.max_steps == 3000
    # A method named twice runs once, in the order first given.
    assert EvalRequest(methods=["utility", "greedy-dist", "utility"]).methods == ["utility", "greedy-dist"]
    with pytest.raises(ConfigError, match=re.escape("--max-steps must be in [1, 1,000,000] (an episode's result must fit its message: MAX_EPISODE_STEPS), got 0")):
        EvalRequest(methods=["greedy-dist"], max_steps=0).validate()
    # A process each: `--workers 5000` started 5,000 processes, as collect-teacher's and train's counts are bounded.
    from cso_runtime.config import MAX_PROCESSES

    for workers in (0, MAX_PROCESSES + 1):
        with pytest.raises(ConfigError, match=rf"--workers must be in \[1, 1,024\] .*got {workers:,}"):
            EvalRequest(methods=["greedy-dist"], workers=workers).validate()


def test_eval_set_overrides_the_config_file_and_names_itself_in_errors(tmp_path: Path):
    """``eval --set masks.beta_far_m=2.0``, as ``up --set`` and ``train --set``: dotted keys over the file."""
    from cso_runtime.evaluation import EvalRequest

    f = tmp_path / "eval.yaml"
    f.write_text("masks: {beta_far_m: 1.8, alpha3_m: 0.5}\n")
    cfg = EvalRequest(methods=["cso"], config_path=f, settings={"masks.beta_far_m": 2.0, "episode.replan_every_steps": 12}).exploration_config()
    assert (cfg.masks.beta_far_m, cfg.masks.alpha3_m, cfg.episode.replan_every_steps) == (2.0, 0.5, 12)
    with pytest.raises(ConfigError, match=r"eval.yaml with --set masks.warp=1: masks: unknown key\(s\) warp"):
        EvalRequest(methods=["cso"], config_path=f, settings={"masks.warp": 1}).exploration_config()
    with pytest.raises(ConfigError, match=r"^eval with --set masks.beta_far_m=0.1: masks: masks need"):
        EvalRequest(methods=["cso"], settings={"masks.beta_far_m": 0.1}).exploration_config()


@pytest.mark.parametrize(
    "config, settings, said",
    [
        (None, {"lookahead_m": 0.4}, "eval with --set lookahead_m=0.4: unknown key(s) lookahead_m (did you mean planner.lookahead_m?); known: episode"),
        ("planner: {min_cluster_size_m: 0.5}\n", {}, "mine.yaml: planner: unknown key(s) min_cluster_size_m (did you mean frontier.min_cluster_size_m?)"),
        (None, {"masks.goal_tolerance_m": 0.5}, "masks: unknown key(s) goal_tolerance_m (did you mean episode.goal_tolerance_m?); known: alpha1_m"),
        (None, {"planner.lookahed_m": 0.4}, "planner: unknown key(s) lookahed_m (did you mean lookahead_m?)"),  # a typo: as before
        (None, {"planer.lookahead_m": 0.4}, "unknown key(s) planer (did you mean planner?); known: episode"),  # a misspelt section: as before
        (None, {"mask.beta_far_m": 2.0}, "unknown key(s) mask (did you mean masks?); known: episode"),
    ],
)
def test_an_eval_key_in_the_wrong_section_names_the_section_it_belongs_to(config, settings, said, tmp_path: Path):
    """``eval --config``/``--set`` give the help ``up``'s profiles give: ``lookahead_m`` at the top level used to say only
    "unknown key(s) lookahead_m; known: episode, frontier, ...", not that it is ``planner.lookahead_m``."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    path = tmp_path / "mine.yaml"
    if config is not None:
        path.write_text(config)
    args = ["eval", "--limit", "1", "--out", str(tmp_path / "out")] + ["--config", str(path)] * (config is not None)
    r = CliRunner().invoke(app, [*args, *(f for k, v in settings.items() for f in ("--set", f"{k}={v}"))])
    assert r.exit_code == 2 and said in " ".join(r.output.split()), r.output
    assert not (tmp_path / "out" / "summary.json").exists()

def test_eval_takes_every_sensor_key_the_config_gives_over_the_preset(tmp_path: Path):
    """A sensor ablation through eval (``--set sensor.range_max_m=2.0``) runs with that sensor, as ``up`` does
    with the same keys; the field of view stays eval's ``--lidar-fov``, and a config that sets it is refused."""
    from cso_runtime.config import LIMO_LIDAR_MOUNT_X_M, SensorConfig
    from cso_runtime.evaluation import EvalRequest

    cfg = EvalRequest(methods=["greedy-dist"], lidar_fov_deg=360.0, settings={"sensor.range_max_m": 2.0, "sensor.resolution_deg": 2.0}).exploration_config()
    assert (cfg.sensor.range_max_m, cfg.sensor.resolution_deg, cfg.sensor.fov_deg) == (2.0, 2.0, 360.0)
    assert cfg.sensor.range_min_m == SensorConfig().range_min_m  # not given: the preset's
    depth = EvalRequest(methods=["greedy-dist"], sensor="depth", settings={"sensor.range_max_m": 2.5}).exploration_config().sensor
    assert (depth.range_max_m, depth.fov_deg, depth.range_min_m) == (2.5, 79.0, 0.3)
    assert EvalRequest(methods=["greedy-dist"], sim="mujoco").exploration_config().sensor.mount_x_m == LIMO_LIDAR_MOUNT_X_M
    assert EvalRequest(methods=["greedy-dist"], sim="mujoco", settings={"sensor.mount_x_m": 0.0}).exploration_config().sensor.mount_x_m == 0.0
    with pytest.raises(ConfigError, match="sensor.fov_deg is set by eval's --lidar-fov"):
        EvalRequest(methods=["greedy-dist"], settings={"sensor.fov_deg": 90.0}).exploration_config()
    with pytest.raises(ConfigError, match=r"sensor.range_min_m must be in \[0, range_max_m 0.2\) m, got 0.3 \(the depth preset"):
        EvalRequest(methods=["greedy-dist"], sensor="depth", settings={"sensor.range_max_m": 0.2}).exploration_config()
    with pytest.raises(ConfigError, match=r"sensor.range_max_m must be in \(0, 1,000\] m .*got 1,000,000,000,000$"):  # the mapper marches no-return beams to it
        EvalRequest(methods=["greedy-dist"], settings={"sensor.range_max_m": 1e12}).exploration_config()


def test_the_mujoco_limo_and_the_real_one_are_driven_as_a_box_the_2d_robot_as_its_disc():
    """``planner.body``: the 2D simulator's robot is the disc its collisions are computed with; the MuJoCo LIMO
    (``eval --sim mujoco``, a profile whose sim is MuJoCo) and the real one (``limo-ros2``) are a box, 4 cm longer
    at the front, unless a config says otherwise."""
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import find_profile
    from services.common import load_profile_for_service

    assert EvalRequest(methods=["greedy-dist"]).exploration_config().planner.body == "disc"
    assert EvalRequest(methods=["greedy-dist"], sim="mujoco").exploration_config().planner.body == "box"
    assert EvalRequest(methods=["greedy-dist"], sim="mujoco", settings={"planner.body": "disc"}).exploration_config().planner.body == "disc"
    bodies = {name: load_profile_for_service(find_profile(name), "planner")[1].planner.body for name in ("sim", "lockstep", "limo-ros2")}
    assert bodies == {"sim": "box", "lockstep": "disc", "limo-ros2": "box"}
    with pytest.raises(ConfigError, match="planner.body must be one of disc, box"):
        from_dict(ExplorationConfig, {"planner": {"body": "square"}})


def test_a_negative_seed_is_refused_where_it_is_given_not_inside_a_worker():
    """numpy's generators take no negative seed: eval, a runtime profile and training each say so first
    (the sim service used to refuse it after the launcher had started everything)."""
    from cso_runtime.config import MAX_SEED, check_seed
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.learned.ppo import Args
    from cso_runtime.run_profile import find_profile, load_profile

    assert check_seed(0) == 0 and check_seed(7) == 7 and check_seed(MAX_SEED) == MAX_SEED
    for bad in (-1, True, 1.5, "3", MAX_SEED + 1, 10**23):  # 10**23: msgpack would fail to send the episode's result
        with pytest.raises(ConfigError, match=f"an integer from 0 to {MAX_SEED}"):
            check_seed(bad)
    with pytest.raises(ConfigError, match="--seed must be an integer from 0 to .*, got -1"):
        EvalRequest(methods=["greedy-dist"], seed=-1).validate()
    with pytest.raises(ConfigError, match="seed must be an integer from 0 to .*, got 100000000000000000000000"):
        load_profile(str(find_profile("lockstep")), {"seed": 10**23})
    with pytest.raises(ConfigError, match="seed must be an integer from 0 to .*, got -3"):
        Args(seed=-3).validate()


def test_training_arguments_out_of_range_are_clear_errors():
    from cso_runtime.learned.ppo import Args

    Args().validate()
    Args(device="cuda:1", learning_rate=0.0).validate()  # a frozen network is a legitimate check
    for bad, message in [
        ({"device": "gpu"}, "device"),
        ({"total_decisions": 0}, "total_decisions"),
        ({"gamma": 1.5}, "gamma"),
        ({"gae_lambda": -0.1}, "gae_lambda"),
        ({"clip_coef": 0.0}, "clip_coef"),
        ({"ent_coef": -0.01}, "ent_coef"),
        ({"learning_rate": -1e-4}, "learning_rate"),
        ({"dungeon_m_per_px": [0.1, 0.0]}, "dungeon_m_per_px"),
    ]:
        with pytest.raises(ValueError, match=message):
            Args(**bad).validate()


def test_an_error_names_the_file_then_the_key_path():
    """A file's own keys follow the file after a colon, nested keys after dots: ``eval.yaml: episode.max_steps``,
    not ``eval.yaml.episode.max_steps``; a config without a file keeps its dotted path."""
    with pytest.raises(ConfigError, match=r"^configs/mine\.yaml: episode\.max_steps: expected an integer"):
        from_dict(ExplorationConfig, {"episode": {"max_steps": 2.5}}, "configs/mine.yaml")
    with pytest.raises(ConfigError, match=r"^p\.yaml with --seed 3: masks: unknown key\(s\) far"):
        from_dict(ExplorationConfig, {"masks": {"far": 1}}, "p.yaml with --seed 3")
    with pytest.raises(ConfigError, match=r"^exploration\.masks\.beta_far_m: expected a number"):
        from_dict(ExplorationConfig, {"masks": {"beta_far_m": "far"}}, "exploration")


def test_a_sections_own_check_names_the_key_path_too():
    """A value that passes its type but fails its section's check names its key path as a type error does: the MuJoCo
    LIMO's ``services.sim.mujoco.timestep_s`` (said "services.sim: mujoco: robot_sim.timestep_s": no such path),
    ``exploration.sensor.fov_deg`` (said "exploration.sensor: sensor.fov_deg"); a file's own keys after its name."""
    from cso_runtime.run_profile import load_profile
    from cso_runtime.simulator import mujoco_config

    said = {}
    bad = [("services.sim.mujoco.timestep_s", -1), ("services.sim.mujoco.timestep_s", "abc"), ("exploration.sensor.fov_deg", -1)]
    for key, value in bad:
        with pytest.raises(ConfigError) as caught:
            load_profile("sim", {}, settings={key: value})
        said[key, value] = str(caught.value).split(": ", 1)[1]  # after the file and its flags
    assert said["services.sim.mujoco.timestep_s", -1] == "services.sim.mujoco: timestep_s must be in [1e-05, 0.05] s (MAX_TIMESTEP_S), got -1"
    assert said["services.sim.mujoco.timestep_s", "abc"] == "services.sim.mujoco.timestep_s: expected a number, got 'abc'"
    assert said["exploration.sensor.fov_deg", -1] == "exploration.sensor.fov_deg must be in (0, 360] degrees, got -1"
    with pytest.raises(ConfigError, match=r"^configs/robot_sim\.yaml: wheel_radius_m \(0\.3 m"):  # eval --sim-config FILE
        mujoco_config({"wheel_radius_m": 0.3}, ExplorationConfig().sensor, where="configs/robot_sim.yaml")
    with pytest.raises(ConfigError, match=r"^mine\.yaml: sensor\.fov_deg must be in"):  # eval --config FILE
        from_dict(ExplorationConfig, {"sensor": {"fov_deg": -1}}, "mine.yaml")
    with pytest.raises(ConfigError, match=r"^exploration\.sensor\.mount_x_m \(0\.5 m\) puts the sensor off the robot"):
        from_dict(ExplorationConfig, {"sensor": {"mount_x_m": 0.5}}, "exploration")


def test_a_robot_radius_no_indoor_robot_has_is_refused():
    """An inflation radius of tens of metres used to pass the checks and crash the frontier service later."""
    from cso_runtime.config import RobotConfig

    RobotConfig(radius_m=0.2).validate()
    with pytest.raises(ConfigError, match="robot.radius_m must be from 0 to 2 m"):
        RobotConfig(radius_m=50.0).validate()


@pytest.mark.parametrize(
    ("key", "typed", "said"),
    [
        ("width_m", 220.0, r"robot\.width_m must be at most 4 m \(the LIMO's is 0\.22\), got 220: a value in millimetres\?"),
        ("length_m", 322.0, r"robot\.length_m must be at most 4 m \(the LIMO's is 0\.322\), got 322"),
        ("max_linear_mps", 1000.0, r"robot\.max_linear_mps must be at most 5 m/s \(the LIMO's is 1\), got 1000"),
        ("max_angular_radps", 45.0, r"robot\.max_angular_radps must be at most 6\.28 rad/s \(one turn a second; the LIMO's is 0\.78\), got 45: a value in degrees"),
        ("control_period_s", 250.0, r"robot\.control_period_s must be at most 5 s \(the LIMO's is 0\.25\), got 250: a value in milliseconds\?"),
    ],
)
def test_a_robot_limit_typed_in_another_unit_is_refused(key: str, typed: float, said: str) -> None:
    """A user from Nav2 or a datasheet typed the LIMO's width in millimetres (``--set robot.width_m=220``), its turn
    rate in degrees per second (``max_angular_radps=45``) or the step in milliseconds (``control_period_s=250``):
    each was taken (``eval --dry-run`` exit 0) and the episode ran with a 220 m robot, a 45 rad/s turn or 250 s steps.
    Each is now refused before anything runs, naming the LIMO's value; the LIMO's own values pass."""
    from cso_runtime.config import RobotConfig

    RobotConfig().validate()
    with pytest.raises(ConfigError, match=said):
        from_dict(ExplorationConfig, {"robot": {key: typed}}, "exploration")


def small_train_recipe(tmp_path: Path) -> Path:
    """A training config of one small generated plan (no Dungeon folder needed)."""
    recipe = tmp_path / "mine.yaml"
    recipe.write_text("dungeon_dir: null\ngenerated: [generated:small:1:1000]\n")
    return recipe


def train_refusal(recipe: Path, flags: dict, settings: list[str], capsys) -> str:
    """What ``train`` says when it refuses ``recipe`` with these flags and ``--set`` pairs (it must: exit 2)."""
    import typer

    from cso_runtime.cli import training_args

    with pytest.raises(typer.Exit) as exit_info:
        training_args(recipe, flags, settings)
    assert exit_info.value.exit_code == 2
    return capsys.readouterr().err


def test_a_train_error_names_the_file_and_the_flags_and_a_zero_distance_scale_is_refused(tmp_path: Path, capsys):
    """``distance_scale_m`` divides every position of the graph: 0 used to train on NaNs and end in a traceback;
    and an out-of-range field said neither the file nor the ``--set`` that brought it, as ``eval`` and ``up`` do."""
    recipe = small_train_recipe(tmp_path)
    for setting, said in [
        ("distance_scale_m=0", "distance_scale_m must be in (0, 5,000,000,000] m"),
        ("distance_scale_m=-10", "distance_scale_m must be in (0, 5,000,000,000] m"),
        ("gamma=2", "gamma must be in"),
        ("device=gpu", "unknown device 'gpu'"),
    ]:
        assert f"error: {recipe} with --set {setting}: {said}" in train_refusal(recipe, {}, [setting], capsys)


def test_a_partial_training_config_names_the_recipe_fields_it_leaves_at_the_defaults(tmp_path: Path, capsys):
    """A small ``train --config mine.yaml`` of a few fields (a tiny run: fewer updates, generated plans) silently
    trained another recipe than configs/train.yaml's, which the help calls the default: each field the file leaves
    out takes ``ppo.Args``' default (learning rate 1e-4 instead of 3e-4, no distance prior, no cluster-length
    feature, the 180-degree LiDAR). ``train`` says which fields, with both values, before it starts; a file that sets
    them (the recipe itself) gets no note, nor does a field a flag or ``--set`` gives."""
    from cso_runtime.cli import DEFAULT_TRAIN_CONFIG, training_args

    recipe = small_train_recipe(tmp_path)
    args = training_args(recipe, {"seed": 3}, ["learning_rate=0.0003"])
    assert args.distance_prior == 0.0  # the defaults still apply, as before: only said
    said = " ".join(capsys.readouterr().err.split())
    assert f"note: {recipe} leaves " in said and "at learned.ppo.Args' defaults, not configs/train.yaml's recipe" in said
    assert "distance_prior 0.0 (recipe: 4.0)" in said and "cluster_size_feature False (recipe: True)" in said
    assert "lidar_fov_deg None (recipe: 360)" in said
    for given in ("learning_rate", "seed", "generated", "dungeon_dir", "out_dir"):
        assert f" {given} " not in said
    training_args(Path(cso_runtime.__file__).resolve().parent.parent / DEFAULT_TRAIN_CONFIG, {}, ["dungeon_dir=null"])
    assert "leaves" not in capsys.readouterr().err


def test_train_takes_every_args_field_as_a_flag_as_cleanrl_does(tmp_path: Path, monkeypatch):
    """CleanRL's trainer takes each field of its ``Args`` as a flag (``--learning-rate 3e-4 --num-steps 128``);
    ``train --learning-rate 3e-4`` was `No such option`, with no word of ``--set learning_rate=3e-4``. Every field of
    ``learned.ppo.Args`` is a flag now (``--no-FIELD`` for a false switch), the same as its ``--set``; a flag that
    is no field is refused before anything starts (exit 2), naming the field it may have meant."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned import ppo

    ran: list[tuple[ppo.Args, str]] = []

    def fake_train(args: ppo.Args, log: object = None, command: str = "", stop_requested: object = None) -> dict:
        ran.append((args, command))
        return {"ppo_decisions": 0, "warm_start_decisions": 0, "wall_time_s": 0.0}

    monkeypatch.setattr(ppo, "train", fake_train)
    recipe = small_train_recipe(tmp_path)
    common = ["train", "--config", str(recipe), "--out", str(tmp_path / "out")]
    flags = ["--learning-rate", "3e-4", "--num-steps=8", "--no-anneal-lr", "--clip-vloss", "--r-step", "-0.02", "--num-envs", "4",
             "--generated", "[generated:small:2:1000]", "--set", "gamma=0.9"]  # fmt: skip
    result = CliRunner().invoke(app, common + flags)
    assert result.exit_code == 0, result.output
    args, command = ran[0]
    assert (args.learning_rate, args.num_steps, args.anneal_lr, args.clip_vloss, args.r_step, args.num_envs) == (3e-4, 8, False, True, -0.02, 4)
    assert args.generated == ["generated:small:2:1000"] and args.gamma == 0.9
    assert "--set learning_rate=3e-4" in command and "--set anneal_lr=false" in command  # the record's command runs it again
    for wrong, said in [
        (["--learnin-rate", "1"], "no such option --learnin-rate: did you mean --learning-rate?"),
        (["--learning-rate"], "--learning-rate needs a value"),
        (["--no-gamma"], "--no-gamma: gamma is not a switch (true or false)"),
        (["stray"], "unexpected argument 'stray'"),
    ]:
        result = CliRunner().invoke(app, common + wrong)
        assert result.exit_code == 2 and said in " ".join(result.output.split()), result.output
    assert len(ran) == 1


def test_a_list_field_takes_one_value_or_values_separated_by_commas_as_most_clis_do(tmp_path: Path, monkeypatch):
    """``--generated generated:small:2:0`` (or ``--set generated=...``) said "generated: expected a list": a list field
    had to be written ``[...]``. One value is the list of it, and values separated by commas are the list of them,
    wherever a config is read (``config._convert``: ``--set``, ``train``'s flags, a YAML file); a value's colons stay
    in it (a scene spec), a list written ``[...]`` is read as before (an item with a comma in it: ``["a,b"]``)."""
    import dataclasses

    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned import ppo

    @dataclasses.dataclass
    class Lists:
        names: list[str] = dataclasses.field(default_factory=list)
        sizes: list[float] = dataclasses.field(default_factory=list)
        pair: tuple[int, ...] = ()

    def read(**data: object) -> Lists:
        return from_dict(Lists, data, "lists.yaml")

    assert read(names="generated:small:2:0").names == ["generated:small:2:0"]
    assert read(names="generated:small:2:0,generated:middle:2:1000").names == ["generated:small:2:0", "generated:middle:2:1000"]
    assert read(names="generated:small:2:0, generated:middle:2:1000").names == ["generated:small:2:0", "generated:middle:2:1000"]
    assert read(names=["a,b", "c"]).names == ["a,b", "c"]  # a YAML list as before: its items whole
    assert read(names="null").names == ["null"]  # a string item stays the text given
    assert read(sizes=0.05).sizes == [0.05] and read(sizes="0.05,1e-1").sizes == [0.05, 0.1] and read(pair="1,2").pair == (1, 2)
    for data, said in [({"names": "a,,b"}, "lists.yaml: names: empty item in 'a,,b'"), ({"sizes": "0.05,far"}, r"lists.yaml: sizes\[1\]: expected a number, got 'far'"),
                       ({"names": {"a": 1}}, "names: expected a list")]:  # fmt: skip
        with pytest.raises(ConfigError, match=said):
            read(**data)

    ran: list[ppo.Args] = []
    monkeypatch.setattr(ppo, "train", lambda args, log=None, command="", stop_requested=None: ran.append(args) or {"ppo_decisions": 0, "warm_start_decisions": 0, "wall_time_s": 0.0})
    common = ["train", "--config", str(small_train_recipe(tmp_path)), "--out", str(tmp_path / "out")]
    for given in (["--generated", "generated:small:2:0"], ["--set", "generated=generated:small:2:0"], ["--generated=generated:small:2:0"]):
        result = CliRunner().invoke(app, common + given)
        assert result.exit_code == 0, result.output
        assert ran[-1].generated == ["generated:small:2:0"], given
    result = CliRunner().invoke(app, [*common, "--generated", "generated:small:2:0,generated:middle:2:1000", "--dungeon-m-per-px", "0.05"])
    assert result.exit_code == 0, result.output
    assert ran[-1].generated == ["generated:small:2:0", "generated:middle:2:1000"] and ran[-1].dungeon_m_per_px == [0.05]


def test_a_profiles_one_value_list_goes_with_ups_flags_that_add_to_it(tmp_path: Path):
    """A profile's ``router.connect: tcp/...`` and ``without: policy`` (one value: a list field's list of it,
    ``config._convert``) are taken alone, but ``up --connect X`` unpacked the text letter by letter ("bad zenoh endpoint
    't'") and ``up --without mapper`` refused the file ("without must be a list"): the flags add to the list read."""
    from cso_runtime.run_profile import load_profile

    profile = tmp_path / "one.yaml"
    profile.write_text("router:\n  connect: tcp/127.0.0.1:7447\nservices:\n  sim: {}\n  mapper: {}\n  frontier: {}\nwithout: policy\n")
    alone, _ = load_profile(str(profile))
    assert alone.router.connect == ["tcp/127.0.0.1:7447"] and alone.without == ["policy"]
    joined, data = load_profile(str(profile), connect=["tcp/10.0.0.1:7447"], without=["frontier"])
    assert joined.router.connect == ["tcp/127.0.0.1:7447", "tcp/10.0.0.1:7447"]
    assert joined.without == ["policy", "frontier"] and data["without"] == ["policy", "frontier"]
    profile.write_text("router:\n  connect: {a: 1}\nservices:\n  sim: {}\n")
    with pytest.raises(ConfigError, match="router.connect: expected a list"):
        load_profile(str(profile), connect=["tcp/10.0.0.1:7447"])


def test_train_refuses_a_field_of_view_eval_cannot_run_before_it_starts(tmp_path: Path, capsys):
    """``train --set lidar_fov_deg=270`` trained for minutes, then its weights could not be evaluated as trained:
    ``eval --lidar-fov`` runs 180 or 360 alone (and ran them at 180, warning). The depth preset has its own field of
    view, which eval's ``--lidar-fov`` does not change either. The fields of view eval runs are still taken."""
    from cso_runtime.cli import training_args

    recipe = small_train_recipe(tmp_path)
    for settings, said in [
        (["lidar_fov_deg=270"], "lidar_fov_deg must be 180 or 360 (the LiDARs eval --lidar-fov runs), or null for the preset's 180, got 270"),
        (["sensor=depth", "lidar_fov_deg=90"], "lidar_fov_deg sets the LiDAR's field of view; sensor depth has its own"),
    ]:
        assert said in " ".join(train_refusal(recipe, {}, settings, capsys).split())
    for settings, fov_deg in [(["lidar_fov_deg=360"], 360.0), (["lidar_fov_deg=180"], 180.0), (["lidar_fov_deg=null"], 180.0), (["sensor=depth", "lidar_fov_deg=null"], 79.0)]:
        assert training_args(recipe, {}, settings).env_config().exploration.sensor.fov_deg == fov_deg


def test_a_minibatch_count_that_does_not_divide_the_batch_says_the_numbers(tmp_path: Path, capsys):
    """``num_minibatches`` must divide num_envs x num_steps: the refusal shows the product and the count."""
    recipe = small_train_recipe(tmp_path)
    said = " ".join(train_refusal(recipe, {"num_envs": 4}, ["num_steps=64", "num_minibatches=3"], capsys).split())
    assert "num_envs x num_steps = 4 x 64 = 256 decisions per update does not divide into 3 minibatches" in said, said


def test_an_unknown_key_names_the_known_key_it_most_likely_misspells(tmp_path: Path, capsys):
    """``train --set gama=0.9`` listed all 70 known keys; the nearest one comes first now (``difflib``), for each
    unknown key that is close to one, in train's, eval's and the files' keys alike."""
    from cso_runtime.evaluation import EvalRequest

    recipe = small_train_recipe(tmp_path)
    said = " ".join(train_refusal(recipe, {}, ["gama=0.9", "num_minibatch=3", "zzz=1"], capsys).split())
    assert "unknown key(s) gama (did you mean gamma?), num_minibatch (did you mean num_minibatches?), zzz; known: adam_eps," in said, said
    with pytest.raises(ConfigError, match=re.escape("masks: unknown key(s) beta_far (did you mean beta_far_m?); known: alpha1_m")):
        EvalRequest(methods=["cso"], settings={"masks.beta_far": 1.0}).exploration_config()
    # A dotted key among train's flat ones is matched by its last part too: it said "did you mean sensor?".
    said = " ".join(train_refusal(recipe, {}, ["sensor.fov_deg=270"], capsys).split())
    assert "unknown key(s) sensor.fov_deg (did you mean lidar_fov_deg?)" in said, said



def test_a_section_of_evals_config_in_trains_flat_one_names_the_key_it_is(tmp_path: Path, capsys):
    """train's keys are flat: eval.yaml's ``masks: {beta_far_m: 2.0}`` in a recipe listed all 70 keys; it names the one
    its key is now (wrong_section, as for eval and the profiles), and eval's a profile's ``exploration:``."""
    from cso_runtime.evaluation import EvalRequest

    recipe = small_train_recipe(tmp_path)
    recipe.write_text(recipe.read_text() + "masks: {beta_far_m: 2.0}\n")
    said = " ".join(train_refusal(recipe, {}, [], capsys).split())
    assert "unknown key(s) masks (did you mean beta_far_m?); known: adam_eps," in said, said
    with pytest.raises(ConfigError, match=re.escape("unknown key(s) exploration (did you mean planner?); known: episode")):
        EvalRequest(methods=["cso"], settings={"exploration.planner.lookahead_m": 0.4}).exploration_config()


def test_a_train_error_names_the_command_flags_that_set_the_bad_value(tmp_path: Path, capsys):
    """``train --num-envs 0`` was refused naming only the file (and any ``--set``), not the flag that brought the 0."""
    recipe = small_train_recipe(tmp_path)
    said = train_refusal(recipe, {"num_envs": 0, "async_envs": False, "seed": None}, ["num_steps=8"], capsys)
    assert f"error: {recipe} with --num-envs 0 --sync-envs --set num_steps=8: num_envs must be in [1, 1,024] (MAX_ENVS), got 0" in said, said


def test_train_refuses_a_reward_of_the_wrong_sign_a_knn_beyond_the_graph_and_a_clip_of_one_or_more(tmp_path: Path, capsys):
    """``train`` took a positive step "penalty" (r_step), a zero or negative area reward (lambda_c), more neighbours
    (knn) than the nodes a graph holds besides the robot's (max_frontier_nodes + max_path_nodes - 1: the rest
    were silently padding) and a PPO clip of 1 or more, and trained on them. They are refused before training
    starts, naming the file and the flag; the values the experiments tried (r_step 0, knn 16, clip_coef 0.2, the
    largest knn a graph holds) are still taken."""
    recipe = small_train_recipe(tmp_path)
    for setting, said in [
        ("r_step=0.01", "r_step must be in [-1,000, 0] (Eq. 6's step penalty; 0: the new area alone), got 0.01"),
        ("lambda_c=0", "lambda_c must be in (0, 1,000] (Eq. 6's reward per m2 of new open area; MAX_LOSS_WEIGHT), got 0"),
        ("lambda_c=-0.02", "lambda_c must be in (0, 1,000]"),
        ("knn=220", "knn must be at most max_frontier_nodes + max_path_nodes - 1 = 219"),
        ("knn=0", "knn must be in [1, 19,999]"),
        ("clip_coef=1", "clip_coef must be in (0, 1) (PPO clips the ratio to [1 - clip_coef, 1 + clip_coef]), got 1"),
        ("gae_lambda=1.5", "gae_lambda must be in [0, 1], got 1.5"),
        ("warm_start_epochs=-1", "warm_start_epochs must be in [0, 1,000] (MAX_EPOCHS), got -1"),
    ]:
        assert f"error: {recipe} with --set {setting}: {said}" in train_refusal(recipe, {}, [setting], capsys)
    # the bound follows the graph's size: 9 nodes, 8 besides the robot's
    assert "knn must be at most max_frontier_nodes + max_path_nodes - 1 = 8" in train_refusal(recipe, {}, ["max_frontier_nodes=4", "max_path_nodes=5", "knn=9"], capsys)
    from cso_runtime.cli import training_args

    for settings in (["r_step=0"], ["knn=16"], ["clip_coef=0.2"], ["knn=219"], ["max_frontier_nodes=4", "max_path_nodes=5", "knn=8"]):
        args = training_args(recipe, {}, settings)
        assert args.env_config().graph.knn == args.knn


def test_the_mujoco_limo_control_period_must_be_whole_physics_steps_before_anything_starts():
    """A control period that is not a whole number of MuJoCo steps used to pass ``eval``'s and ``up``'s checks, then
    fail every episode (eval, exit 1) or the sim service once started; it is a bad configuration (exit 2) now."""
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import load_profile

    with pytest.raises(ConfigError, match=r"robot.control_period_s \(0.251 s\) must be a whole number of physics steps"):
        EvalRequest(methods=["greedy-dist"], sim="mujoco", settings={"robot.control_period_s": 0.251}).validate()
    EvalRequest(methods=["greedy-dist"], sim="2d", settings={"robot.control_period_s": 0.251}).validate()  # no physics step
    mujoco_4ms = {"services.sim.mujoco.timestep_s": 0.004, "services.sim.mujoco.odometry_rate_hz": 50.0}  # odometry: 5 steps
    for settings in ({"exploration.robot.control_period_s": 0.251}, mujoco_4ms):
        with pytest.raises(ConfigError, match="services.sim.mujoco: exploration.robot.control_period_s .* whole number of physics steps"):  # a profile's key
            load_profile("sim", {}, settings=settings)
    load_profile("lockstep", {}, settings={"exploration.robot.control_period_s": 0.251})  # the kinematic sim takes it
    with pytest.raises(ConfigError, match=r"odometry_rate_hz \(40 Hz\) must be a whole number of physics steps"):
        load_profile("sim", {}, settings={"services.sim.mujoco.timestep_s": 0.004})


THROUGH_WALL_WAYS_OUT = re.compile(
    r"Use (?:(?P<robot>\S+)\.max_linear_mps (?P<speed>\S+) m/s or less, or )?contact_time_constant_s (?P<contact>\S+) s or less(?: with timestep_s (?P<step>\S+) s or finer)?"
)


@pytest.mark.parametrize(
    ("settings", "speed_said"),
    [
        ({"services.sim.mujoco.contact_time_constant_s": 0.2, "exploration.robot.max_linear_mps": 2.0}, True),  # 0.55 m/s
        ({"services.sim.mujoco.contact_time_constant_s": 0.8}, False),  # 0.1375 m/s: below planner.backup_speed_mps, 0.15
        ({"services.sim.mujoco.contact_time_constant_s": 0.25, "exploration.planner.backup_speed_mps": 0.5}, False),  # 0.44 m/s
        ({"services.sim.mujoco.timestep_s": 0.05, "services.sim.mujoco.contact_time_constant_s": 0.1, "services.sim.mujoco.actuator_time_constant_s": 0.1,
          "services.sim.mujoco.odometry_rate_hz": 20.0, "exploration.robot.max_linear_mps": 5.0}, True),  # a finer step too
    ],
)
def test_each_way_out_of_up_s_through_wall_refusal_is_taken_by_the_whole_profile(settings: dict, speed_said: bool):
    """``up``'s refusal of walls too soft for the robot's top speed named ``robot.max_linear_mps``, eval's key, where a
    profile's is ``exploration.robot.max_linear_mps``; and with a contact above about 0.73 s it suggested a top speed below
    the planner's ``backup_speed_mps`` (0.15 m/s), which the exploration config then refused. Each way out it names, set as
    printed, is taken by the whole profile (exploration and sim); a top speed is named only where the config takes it."""
    from cso_runtime.run_profile import load_profile

    with pytest.raises(ConfigError) as refused:
        load_profile("sim", {}, settings=settings)
    said = str(refused.value)
    assert "services.sim.mujoco: contact_time_constant_s" in said and " robot." not in said and "(robot." not in said, said
    way = THROUGH_WALL_WAYS_OUT.search(said)
    assert way is not None, said
    assert (way["speed"] is not None) == speed_said, said
    contact = {"services.sim.mujoco.contact_time_constant_s": float(way["contact"])}
    load_profile("sim", {}, settings={**settings, **contact, **({"services.sim.mujoco.timestep_s": float(way["step"])} if way["step"] else {})})
    if speed_said:
        assert way["robot"] == "exploration.robot", said
        load_profile("sim", {}, settings={**settings, "exploration.robot.max_linear_mps": float(way["speed"])})
    else:  # the speed the walls would need is one the profile refuses: not a way out
        slow = float(re.search(r"max_linear_mps (\S+) m/s, slow enough", said)[1])
        with pytest.raises(ConfigError, match="backup_speed_mps"):
            load_profile("sim", {}, settings={**settings, "exploration.robot.max_linear_mps": slow})


def test_each_way_out_of_eval_s_through_wall_refusal_is_taken_by_eval_s_whole_config(tmp_path: Path):
    """As ``up``'s (above), with eval's keys: ``--sim-config`` holds the physics, ``--set robot.max_linear_mps`` the robot."""
    import yaml

    from cso_runtime.evaluation import EvalRequest

    sim_config = tmp_path / "soft.yaml"
    sim_config.write_text(yaml.safe_dump({"contact_time_constant_s": 0.8}))
    with pytest.raises(ConfigError) as refused:
        EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=sim_config).validate()
    said = str(refused.value)
    way = THROUGH_WALL_WAYS_OUT.search(said)
    assert way is not None and way["speed"] is None, said  # 0.1375 m/s: below planner.backup_speed_mps
    sim_config.write_text(yaml.safe_dump({"contact_time_constant_s": float(way["contact"])}))
    EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=sim_config).validate()
    sim_config.write_text(yaml.safe_dump({"contact_time_constant_s": 0.2}))
    with pytest.raises(ConfigError) as refused:
        EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=sim_config).validate()
    way = THROUGH_WALL_WAYS_OUT.search(str(refused.value))
    assert way is not None and way["robot"] == "robot" and way["speed"] is not None, refused.value  # eval's config's key
    EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=sim_config, settings={"robot.max_linear_mps": float(way["speed"])}).validate()


def test_the_policy_services_own_method_and_device_are_checked_before_anything_starts(monkeypatch):
    """``services.policy.method`` and ``device`` used to pass ``up --dry-run`` and fail only in the started policy
    service, a device torch cannot use as a weights file that "is not a cso-runtime checkpoint". Whether this host
    has a GPU or not, both cases run: torch's view of CUDA is set here."""
    import torch

    from cso_runtime.run_profile import load_profile

    for key, value, said in [
        ("services.policy.method", "bogus", "services.policy.method: unknown method 'bogus'"),
        ("services.policy.device", "banana", "services.policy.device: unknown device 'banana'"),
    ]:
        with pytest.raises(ConfigError, match=said):
            load_profile("lockstep", {}, settings={key: value})
    on_cuda = {"services.policy.method": "cso", "services.policy.device": "cuda"}
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ConfigError, match="services.policy.device: device cuda: .*; run the policy on cpu"):
        load_profile("lockstep", {}, settings=on_cuda)
    load_profile("lockstep", {}, settings={"services.policy.device": "cuda"})  # a baseline runs no network
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)  # one GPU
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    load_profile("lockstep", {}, settings=on_cuda)
    with pytest.raises(ConfigError, match=r"services.policy.device: device cuda:1: only 1 CUDA device\(s\) here; run the policy on cpu"):
        load_profile("lockstep", {}, settings={**on_cuda, "services.policy.device": "cuda:1"})


def test_up_warns_when_the_policys_weights_were_trained_with_another_field_of_view(tmp_path: Path):
    """`up --profile sim --weights RUN` of a configs/train.yaml run (360 degrees) drove the LIMO's 180-degree LiDAR
    with no word, as eval did: the run's record beside the weights says its sensor, and up warns (before a dry run's
    profile too); nothing where they match, or where the policy runs a baseline."""
    import json
    import shutil
    import subprocess
    import sys

    from cso_runtime.config import SensorConfig
    from cso_runtime.learned.weights import weights_path

    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(weights_path("cso", SensorConfig.preset("lidar", 360)), run / "cso.pt")
    (run / "cso.json").write_text(json.dumps({"variant": "cso", "args": {"sensor": "lidar", "lidar_fov_deg": 360.0}}))
    up = [sys.executable, "-m", "cso_runtime.cli", "up", "--profile", "sim", "--weights", str(run), "--dry-run"]
    said = subprocess.run([*up, "--method", "cso"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert said.returncode == 0, said.stderr
    assert said.stderr.startswith(
        f"warning: the weights of cso were trained with a 360-degree sensor ({run / 'cso.json'}), this run's sees 180 degrees"
        " (a policy does best with the sensor it was trained with)"
    )
    for quiet in (["--method", "cso", "--set", "exploration.sensor.fov_deg=360"], ["--method", "greedy-dist"]):
        out = subprocess.run([*up, *quiet], capture_output=True, text=True, timeout=60, cwd=tmp_path)
        assert out.returncode == 0 and "warning" not in out.stderr, out.stderr


def test_up_warns_when_the_policys_weights_were_trained_under_other_stuck_mask_settings(tmp_path: Path):
    """`up --weights RUN` of a run trained with ``stuck_avoid=goals`` ran the policy under the profile's stuck mask
    (positions) with no word, as eval did: the run's record says its masks, and up warns, naming the ``--set`` of up
    that runs them as trained; nothing once given."""
    import json
    import shutil
    import subprocess
    import sys

    from cso_runtime.learned.weights import weights_path

    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(weights_path("cso"), run / "cso.pt")
    (run / "cso.json").write_text(json.dumps({"variant": "cso", "args": {"variant": "cso", "sensor": "lidar", "lidar_fov_deg": None, "stuck_avoid": "goals"}}))
    up = [sys.executable, "-m", "cso_runtime.cli", "up", "--profile", "sim", "--weights", str(run), "--dry-run", "--method", "cso"]
    said = subprocess.run(up, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert said.returncode == 0, said.stderr
    assert said.stderr.startswith(
        f"warning: the weights of cso were trained with masks.stuck_avoid=goals ({run / 'cso.json'}), this run's are positions;"
        " --set exploration.masks.stuck_avoid=goals runs them as trained (a policy does best with the masks it was trained under)"
    ), said.stderr
    quiet = subprocess.run([*up, "--set", "exploration.masks.stuck_avoid=goals"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert quiet.returncode == 0 and "warning" not in quiet.stderr, quiet.stderr


def test_up_refuses_weights_trained_with_another_entropy_window_before_it_starts_anything(tmp_path: Path, monkeypatch):
    """``up --weights RUN`` of a run trained with a 4 m entropy window, under the profile's 2 m (or the shipped weights,
    2 m, under ``--set exploration.frontier.entropy_window_m=4``), passed up's checks and started every service: the
    policy service then refused the weights at its start. The checkpoint's own record (its ``frontier``, read without
    torch: ``weights.checkpoint_header``; one from before that record: its graph's window) says the window, and up
    refuses before it starts anything, with the policy service's own words (``weights.input_verdict``): the
    variants that read no entropy, another ``min_cluster_size_m`` (warned at the load) and weights that do not read
    so pass."""
    import dataclasses
    import shutil
    import subprocess
    import sys

    import torch

    from cso_runtime.config import SensorConfig
    from cso_runtime.learned.ppo import Args, build_model, save_weights
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, weights_path
    from cso_runtime.run_profile import load_profile
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    shipped = weights_path("cso", SensorConfig.preset("lidar", 180))
    wider = {"exploration.frontier.entropy_window_m": 4.0}
    said = re.escape(f"method cso: the weights of cso ({shipped}) were trained with frontier.entropy_window_m 2 m, this run's is 4 m: ")
    with pytest.raises(ConfigError, match=said + r".*up: --set exploration.frontier.entropy_window_m=2\)"):
        load_profile("sim", {"method": "cso"}, settings=wider)
    load_profile("sim", {"method": "cso-no-info"}, settings=wider)  # reads no entropy
    load_profile("sim", {"method": "cso"}, settings={"exploration.frontier.min_cluster_size_m": 0.5})  # warned, not refused

    run = tmp_path / "run"
    wide = Args(variant="cso", entropy_window_m=4.0, cluster_size_feature=True, out_dir=str(run))
    save_weights(run, build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0, "args": dataclasses.asdict(wide)})  # its record as train's
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    load_profile("sim", {"method": "cso"}, settings=wider)
    with pytest.raises(ConfigError, match=r"method cso: the weights of cso \(.*cso\.pt\) were trained with frontier.entropy_window_m 4 m, this run's is 2 m"):
        load_profile("sim", {"method": "cso"})
    (run / "cso.pt").write_bytes(b"\x80" + (run / "cso.pt").read_bytes()[1:])  # does not read without torch: the policy service's load says
    load_profile("sim", {"method": "cso"})
    unset_weights_env(monkeypatch)

    save_weights(run, build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0, "args": dataclasses.asdict(wide)})
    up = [sys.executable, "-m", "cso_runtime.cli", "up", "--profile", "sim", "--weights", str(run), "--method", "cso", "--dry-run"]
    refused = subprocess.run(up, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert refused.returncode == 2 and "trained with frontier.entropy_window_m 4 m, this run's is 2 m" in refused.stderr, refused.stderr
    assert refused.stdout == "", refused.stdout
    taken = subprocess.run([*up, "--set", "exploration.frontier.entropy_window_m=4"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert taken.returncode == 0, taken.stderr

    # A record beside the weights that tells of other weights (the shipped file copied over the run's, its 4 m record
    # left beside it) is not what up goes by: the weights' own window is (2 m), as the policy service's load reads it.
    shutil.copy(weights_path("cso"), run / "cso.pt")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    load_profile("sim", {"method": "cso"})
    with pytest.raises(ConfigError, match=r"trained with frontier.entropy_window_m 2 m, this run's is 4 m"):
        load_profile("sim", {"method": "cso"}, settings=wider)


def test_up_says_the_policys_start_warnings_on_its_terminal_before_it_starts_anything(tmp_path: Path, monkeypatch):
    """The policy service warns as it starts of a run setting other than its weights were trained with that it runs
    anyway (another ``frontier.min_cluster_size_m``: ``weights.INPUT_CHECKS``), in its own log only
    (runs/<run>/logs/policy.log): ``up``, foreground or ``--detach``, said nothing on its terminal. It now says the
    service's very lines (``weights.recorded_input_verdict``: the ``input_verdict`` of the policy's load) on stderr
    before the launcher starts anything; nothing where the settings match, or where a baseline decides."""
    from typer import echo
    from typer.testing import CliRunner

    from cso_runtime import launcher
    from cso_runtime.cli import app
    from cso_runtime.policies import make_policy
    from cso_runtime.run_profile import load_profile
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    other = {"exploration.frontier.min_cluster_size_m": 0.5}
    exploration = load_profile("sim", {"method": "cso"}, settings=other)[0].exploration_config()
    service = make_policy("cso", exploration.masks, seed=0, sensor=exploration.sensor, frontier=exploration.frontier)
    service_says = list(getattr(service, "input_warnings", ()))  # what services/policy.py logs at its start
    assert len(service_says) == 1 and "frontier.min_cluster_size_m 0.3 m, this run's is 0.5 m" in service_says[0], service_says

    def started(*args: object, **kwargs: object) -> object:  # run_foreground (live=...) or start_detached: nothing starts
        echo("LAUNCHER STARTS", err=True)
        return (0, "started") if "live" not in kwargs else 0

    monkeypatch.setattr(launcher, "run_foreground", started)
    monkeypatch.setattr(launcher, "start_detached", started)
    up = ["up", "--profile", "sim", "--method", "cso", "--runs-dir", str(tmp_path / "runs"), "--set", "exploration.frontier.min_cluster_size_m=0.5"]
    for how in ([], ["--no-live"], ["--detach"]):
        r = CliRunner().invoke(app, [*up, *how])
        assert r.exit_code == 0, r.output
        warning = f"warning: {service_says[0]}\n"
        assert warning in r.output and r.output.index(warning) < r.output.index("LAUNCHER STARTS"), r.output
    for quiet in (["--method", "cso"], ["--method", "greedy-dist", "--set", "exploration.frontier.min_cluster_size_m=0.5"]):
        r = CliRunner().invoke(app, ["up", "--profile", "sim", "--runs-dir", str(tmp_path / "runs"), "--detach", *quiet])
        assert r.exit_code == 0 and "min_cluster_size_m" not in r.output, r.output


def test_up_says_the_limos_start_in_a_wall_on_its_terminal_before_it_starts_anything(tmp_path: Path, monkeypatch):
    """The MuJoCo LIMO warns of a body that overlaps a wall at the scene's start pose in the sim service's log alone
    (runs/<run>/logs/sim.log): ``up`` said nothing on its terminal. It now says the sim's very line
    (``scenes.start_overlap_said``, of the scene ``up`` loads to check it, its start and the profile's
    ``exploration.robot`` box) on stderr before the launcher starts anything, foreground or ``--detach``; nothing for a
    start clear of the walls. The 2D simulator (``--profile lockstep``) had no such check for its disc: it says its own
    (``simulator.disc_start_overlap_said``, ``exploration.robot.disc_radius_m``), in its words."""
    import numpy as np
    from PIL import Image
    from typer import echo
    from typer.testing import CliRunner

    from cso_runtime import launcher
    from cso_runtime.cli import app
    from cso_runtime.run_profile import load_profile
    from cso_runtime.scenes import start_overlap_said

    def plan_png(name: str, start_px: tuple[int, int]) -> Path:
        rgb = np.full((20, 30, 3), (195, 195, 194), dtype=np.uint8)  # 3 x 2 m at 0.1 m a pixel
        rgb[[0, -1], :] = rgb[:, [0, -1]] = (127, 127, 127)
        rgb[start_px] = (255, 216, 0)  # one pixel: the start at its centre, yaw 0
        Image.fromarray(rgb).save(tmp_path / f"{name}.png")
        return tmp_path / f"{name}.png"

    def started(*args: object, **kwargs: object) -> object:  # run_foreground (live=...) or start_detached: nothing starts
        echo("LAUNCHER STARTS", err=True)
        return (0, "started") if "live" not in kwargs else 0

    monkeypatch.setattr(launcher, "run_foreground", started)
    monkeypatch.setattr(launcher, "start_detached", started)
    against = plan_png("against", (10, 1))  # x 0.15 m, 0.05 m from the west wall's face: the LIMO's half length is 0.161 m
    up = ["up", "--method", "greedy-dist", "--runs-dir", str(tmp_path / "runs")]
    said = "warning: against: the LIMO's body overlaps a wall at the start pose (x 0.150 m, y 0.950 m, yaw 0.000 rad): its contacts push it out as the episode starts\n"
    prof = load_profile("sim", {"scene": str(against)})[0]
    assert said == f"warning: {start_overlap_said(prof.scene_ref().load(), 0.322, 0.22)}\n" == f"warning: {prof.start_overlap_said()}\n"
    for how in ([], ["--no-live"], ["--detach"], ["--dry-run"]):
        r = CliRunner().invoke(app, [*up, "--profile", "sim", "--scene", str(against), *how])
        assert r.exit_code == 0, r.output
        assert said in r.output and ("--dry-run" in how or r.output.index(said) < r.output.index("LAUNCHER STARTS")), r.output
    near = plan_png("near", (10, 4))  # x 0.45 m, 0.35 m from the wall: clear of the LIMO's box, not of a 0.8 m long one
    for quiet in (["--profile", "sim", "--scene", str(near)], ["--profile", "lockstep", "--scene", str(near)]):
        r = CliRunner().invoke(app, [*up, "--detach", *quiet])
        assert r.exit_code == 0 and "overlaps a wall" not in r.output, r.output
    disc = "warning: against: the 2D simulator's collision disc (radius 0.12 m) overlaps a wall at the start pose (x 0.150 m, y 0.950 m, yaw 0.000 rad)"
    assert f"warning: {load_profile('lockstep', {'scene': str(against)})[0].start_overlap_said()}".startswith(disc)
    for how in ([], ["--detach"]):
        r = CliRunner().invoke(app, [*up, "--profile", "lockstep", "--scene", str(against), *how])
        assert r.exit_code == 0 and disc in r.output and r.output.index(disc) < r.output.index("LAUNCHER STARTS"), r.output
        assert "the LIMO's body" not in r.output, r.output
    r = CliRunner().invoke(app, [*up, "--detach", "--profile", "sim", "--scene", str(near), "--set", "exploration.robot.length_m=0.8"])
    assert r.exit_code == 0 and "near: the LIMO's body overlaps a wall at the start pose (x 0.450 m, y 0.950 m, yaw 0.000 rad)" in r.output, r.output


def test_up_of_a_learned_method_the_weights_folder_lacks_names_those_it_holds(tmp_path: Path, monkeypatch):
    """``train --variant cso-sm --out RUN`` then ``up --method cso --weights RUN``: up said only "no weights at
    RUN/cso.pt; train it", not that RUN's weights are cso-sm's, to run with ``--method cso-sm`` (eval said so)."""
    import shutil

    import cso_runtime
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV
    from cso_runtime.run_profile import load_profile
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)  # a CSO_WEIGHTS_FILE of the developer's would take cso's place
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(Path(cso_runtime.__file__).parent / "data" / "weights" / "cso-sm.pt", run / "cso-sm.pt")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(run))
    with pytest.raises(ConfigError, match=r"method cso: no weights at .*cso\.pt; it holds those of cso-sm \(--method cso-sm\)"):
        load_profile("sim", {"method": "cso"})
    load_profile("sim", {"method": "cso-sm"})
    (run / "cso-sm.pt").unlink()
    with pytest.raises(ConfigError, match=r"cso\.pt; train it with `cso-runtime train --variant cso`"):
        load_profile("sim", {"method": "cso"})


def test_the_lockstep_sim_gives_up_only_after_it_has_re_published_a_step():
    """``lockstep_give_up_s`` at or below ``lockstep_timeout_s`` failed an episode on one lost message, never re-published."""
    from cso_runtime.run_profile import load_profile

    with pytest.raises(ConfigError, match=r"services.sim: lockstep_give_up_s \(0.5 s\) must exceed lockstep_timeout_s \(1.0 s\)"):
        load_profile("lockstep", {}, settings={"services.sim.lockstep_give_up_s": 0.5})
    load_profile("lockstep", {}, settings={"services.sim.lockstep_give_up_s": 1.5})


def test_a_mistyped_profile_name_or_a_missing_profile_file_says_what_is_wrong(tmp_path, monkeypatch):
    """``up --profile smi`` names the profile it most likely misspells, as an unknown method does; a .yaml path
    that is not there is said to be a missing file, not an unknown profile name (a path is never a name)."""
    from cso_runtime.run_profile import find_profile

    monkeypatch.chdir(tmp_path)  # no ./configs/profiles here: the packaged profiles alone
    with pytest.raises(ConfigError, match=r"unknown profile 'smi' \(did you mean sim\?\); known profiles: limo-ros2, lockstep, sim"):
        find_profile("smi")
    with pytest.raises(ConfigError, match=r"profile file not found: nope\.yaml \(a \.yaml path; known profiles by name: limo-ros2"):
        find_profile("nope.yaml")
    with pytest.raises(ConfigError, match=r"profile file not found: .*sim\.yml"):
        find_profile(str(tmp_path / "sim.yml"))  # a path, even where its stem is a known name
    assert find_profile("sim").name == "sim.yaml"


def test_an_error_quotes_each_set_flag_as_typed_not_as_pythons_repr():
    """``up --set services.sim.viewer=true`` was refused "with --set services.sim.viewer=True", and a list as
    ``['tcp/...']``: the flags the error names are YAML again, as the user typed them."""
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import load_profile

    with pytest.raises(ConfigError, match=r"^eval with --set masks.warp=true --set masks.hop=\[a, 2\]: masks: unknown key"):
        EvalRequest(methods=["cso"], settings={"masks.warp": True, "masks.hop": ["a", 2]}).exploration_config()
    with pytest.raises(ConfigError, match=r"with --set services.planner.nope=false: services.planner: unknown key\(s\) nope"):
        load_profile("lockstep", settings={"services.planner.nope": False})


def test_an_error_quotes_a_set_flags_non_ascii_text_as_typed():
    """``--set name=café`` was named "--set name="caf\\xE9"" in the error: YAML's dump escapes non-ASCII text unless told
    not to, and the flag the user typed is that text."""
    from cso_runtime.config import set_flag_text
    from cso_runtime.run_profile import load_profile

    assert set_flag_text("services.planner.nope", "café 1 m²") == "--set services.planner.nope=café 1 m²"
    assert set_flag_text("generated", ["küche", "bad"]) == "--set generated=[küche, bad]"
    with pytest.raises(ConfigError, match=r"with --set services.planner.nope=café: services.planner: unknown key"):
        load_profile("lockstep", settings={"services.planner.nope": "café"})


def _field_docstrings(cls: type) -> dict[str, str | None]:
    """Each field of dataclass ``cls`` -> the string literal right below it (its docstring), or None."""
    import ast
    import inspect
    import textwrap

    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body
    docs: dict[str, str | None] = {}
    for node, after in zip(body, [*body[1:], None]):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            literal = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)
            docs[node.target.id] = after.value.value if literal else None
    return docs


def test_every_configuration_key_has_a_docstring():
    """Every key a YAML file, a profile or ``--set`` can give (each field of the config dataclasses, each service's
    parameters) says what it means under it, as a Nav2 parameter does: a field without one reads as the next field's
    docstring, as ``router.connect_timeout_s`` read as ``zenoh_config``'s."""
    import dataclasses

    from cso_runtime import config
    from cso_runtime.learned.network import NetworkConfig
    from cso_runtime.learned.ppo import Args
    from cso_runtime.run_profile import Profile, RouterConfig, SupervisionConfig
    from robot_sim.config import MujocoSimConfig
    from services import SERVICE_NAMES, params_class

    classes = [getattr(config, n) for n in ("SensorConfig", "RobotConfig", "MappingConfig", "FrontierConfig", "MaskConfig")]
    classes += [config.EpisodeConfig, config.PlannerConfig, ExplorationConfig, Profile, RouterConfig, SupervisionConfig]
    classes += [MujocoSimConfig, Args, NetworkConfig, *(c for n in SERVICE_NAMES if (c := params_class(n)) is not None)]
    undocumented = [f"{cls.__name__}.{name}" for cls in classes for name, doc in _field_docstrings(cls).items() if not (doc or "").strip()]
    assert undocumented == []
    assert {f.name for f in dataclasses.fields(RouterConfig)} == set(_field_docstrings(RouterConfig))
    assert "How long ``up`` waits" in _field_docstrings(RouterConfig)["connect_timeout_s"]
    assert "Zenoh config file" in _field_docstrings(RouterConfig)["zenoh_config"]


@pytest.mark.parametrize("name", ["sim", "lockstep", "limo-ros2"])
def test_up_resolved_prints_every_parameter_the_run_uses_as_a_profile_that_runs_the_same(name, tmp_path: Path, monkeypatch):
    """``up --resolved`` is the effective configuration (Nav2's ``ros2 param dump``): defaults, the file and ``--set``
    resolved, every key of every section, where ``--dry-run`` shows the file as written (``exploration: {}``); and
    what it prints, given back as a profile, runs the same."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.run_profile import load_profile
    from cso_runtime.transport import JOIN_TIMEOUT_S
    from robot_sim.config import MujocoSimConfig
    from services.mapper import MapperParams

    monkeypatch.chdir(tmp_path)  # the packaged profiles
    connect = ["--connect", "tcp/127.0.0.1:7447"] if name == "limo-ros2" else []
    args = ["up", "--profile", name, *connect, "--set", "exploration.planner.lookahead_m=0.4", "--resolved"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    assert r.output.startswith(f"# profile {name}, valid: `up` would start") and "defaults filled in" in r.output
    shown = yaml.safe_load(r.output)
    assert shown["exploration"] == {**to_dict(ExplorationConfig()), **shown["exploration"]}  # every section, every key
    assert set(shown["exploration"]["sensor"]) == set(to_dict(ExplorationConfig())["sensor"])
    assert shown["exploration"]["planner"]["lookahead_m"] == 0.4  # --set
    assert shown["router"]["connect_timeout_s"] == JOIN_TIMEOUT_S and "start_timeout_s" in shown["supervision"]
    assert shown["services"]["mapper"] == to_dict(MapperParams())
    if name == "sim":  # the MuJoCo LIMO: its LiDAR mount and box body, and every physics parameter
        assert (shown["exploration"]["sensor"]["mount_x_m"], shown["exploration"]["planner"]["body"]) == (0.103, "box")
        assert set(shown["services"]["sim"]["mujoco"]) == set(to_dict(MujocoSimConfig()))
    profile = tmp_path / "resolved.yaml"
    profile.write_text(r.output)
    assert load_profile(str(profile))[0].effective() == shown
    as_written = yaml.safe_load(CliRunner().invoke(app, ["up", "--profile", name, *connect, "--dry-run"]).output)
    assert "connect_timeout_s" not in as_written["router"]  # --dry-run: the file as written, as before



def test_up_resolved_says_the_2d_simulators_settings_the_run_records(tmp_path: Path, monkeypatch):
    """``up --resolved --profile lockstep`` said nothing of the 2D simulator's settings, which the run records in
    summary.json's ``meta.sim_settings`` (the MuJoCo LIMO's are ``services.sim.mujoco`` in the YAML): no profile key of
    their own holds them, so a comment says them, and the YAML is still a profile that runs the same."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.run_profile import load_profile

    monkeypatch.chdir(tmp_path)  # the packaged profiles
    r = CliRunner().invoke(app, ["up", "--profile", "lockstep", "--resolved"])
    assert r.exit_code == 0, r.output
    recorded = load_profile("lockstep")[0].simulator_settings()  # what write_outputs puts in meta.sim_settings
    assert recorded is not None and set(recorded) == {"collision_radius_m", "substeps"}
    said = ", ".join(f"{key} {value}" for key, value in recorded.items())
    assert f"# the 2d simulator's settings as the run records them (summary.json's meta.sim_settings, no profile key of their own): {said}\n" in r.output
    profile = tmp_path / "resolved.yaml"
    profile.write_text(r.output)
    assert load_profile(str(profile))[0].effective() == yaml.safe_load(r.output)
    sim = CliRunner().invoke(app, ["up", "--profile", "sim", "--resolved"]).output
    assert "simulator's settings" not in sim  # the MuJoCo LIMO's: every one a key of services.sim.mujoco

def test_up_resolved_of_a_real_robot_shows_no_scene_it_never_loads(tmp_path: Path, monkeypatch):
    """``up --resolved --profile limo-ros2`` printed the default ``scene: generated:small:1:0`` (and ``m_per_px``), which a
    real robot's run never loads; it says what the launcher's first line and ``runs`` say instead, and the YAML, given
    back as a profile, still runs the same."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.run_profile import REAL_ROBOT_SCENE, load_profile

    monkeypatch.chdir(tmp_path)  # the packaged profiles
    r = CliRunner().invoke(app, ["up", "--profile", "limo-ros2", "--connect", "tcp/127.0.0.1:7447", "--resolved"])
    assert r.exit_code == 0, r.output
    shown = yaml.safe_load(r.output)
    assert "scene" not in shown and "m_per_px" not in shown, shown
    assert f"# scene: {REAL_ROBOT_SCENE}" in r.output
    profile = tmp_path / "resolved.yaml"
    profile.write_text(r.output)
    assert load_profile(str(profile))[0].effective() == shown
    sim = CliRunner().invoke(app, ["up", "--profile", "sim", "--resolved"]).output
    assert yaml.safe_load(sim)["scene"] == load_profile("sim")[0].scene and "# scene:" not in sim  # a simulation's: as before

def test_up_resolved_says_the_weights_folder_it_runs_the_learned_methods_from(tmp_path: Path, monkeypatch):
    """``up --weights FOLDER --resolved`` printed a profile with no word of FOLDER (no profile key holds it): given back
    alone, it ran the shipped weights. Now a comment names the folder and says to give it again; without --weights, none."""
    import shutil

    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned.weights import weights_dir
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)  # restored after the test: --weights sets one in this process
    plain = CliRunner().invoke(app, ["up", "--profile", "sim", "--resolved"])
    assert plain.exit_code == 0 and "--weights" not in plain.output, plain.output
    mine = tmp_path / "run"
    mine.mkdir()
    shutil.copy(weights_dir() / "cso.pt", mine / "cso.pt")
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--weights", str(mine), "--resolved"])
    assert r.exit_code == 0, r.output
    assert f"# the learned methods' weights from --weights {mine.resolve()} (no profile key: give it again with this profile)" in r.output
    assert yaml.safe_load(r.output) == yaml.safe_load(plain.output)  # the profile itself is the same


def test_up_weights_file_is_the_policys_file_whatever_the_sensor(tmp_path: Path, monkeypatch):
    """``up --profile sim --weights cso_runtime/data/weights/cso.pt`` (the LIMO's 180-degree LiDAR) would have served
    ``cso@fov180.pt`` beside it: the policy service now loads the file named (the same ``weights_path`` as eval's),
    ``up`` warns that it was trained with 360 degrees, and a profile whose learned method is another is refused."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import SensorConfig
    from cso_runtime.learned.weights import weights_dir, weights_path, weights_provenance
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    given = (weights_dir() / "cso.pt").resolve()
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--weights", str(given), "--resolved"])
    assert r.exit_code == 0, r.output
    assert f"# cso's weights from --weights {given} (no profile key: give it again with this profile)" in r.output
    assert "warning: the weights of cso were trained with a 360-degree sensor" in r.output
    assert weights_path("cso", SensorConfig.preset("lidar")) == given and weights_path("cso-sm", SensorConfig.preset("lidar")).name == "cso-sm.pt"
    assert weights_provenance("cso", SensorConfig.preset("lidar"))["path"] == str(given)
    refused = CliRunner().invoke(app, ["up", "--profile", "sim", "--method", "cso-sm", "--weights", str(given), "--dry-run"])
    assert refused.exit_code == 2 and "the weights of cso alone, not of cso-sm" in refused.output, refused.output


@pytest.mark.parametrize(
    "settings, said",
    [
        ({"services.planner.lookahead_m": 0.4}, "services.planner: unknown key(s) lookahead_m (did you mean exploration.planner.lookahead_m?); known: path_period_s"),
        ({"services.mapper.footprint_clearing": False}, "services.mapper: unknown key(s) footprint_clearing (did you mean exploration.mapping.footprint_clearing?)"),
        ({"exploration.lookahead_m": 0.4}, "exploration: unknown key(s) lookahead_m (did you mean exploration.planner.lookahead_m?)"),
        ({"services.sim.timestep_s": 0.01}, "services.sim: unknown key(s) timestep_s (did you mean services.sim.mujoco.timestep_s?)"),
        ({"frontier": {"min_cluster_size_m": 0.5}}, "unknown key(s) frontier (did you mean exploration.frontier or services.frontier?); known: exploration"),
        ({"backoff_s": 1.0}, "unknown key(s) backoff_s (did you mean supervision.backoff_s?)"),
        ({"robot": {"radius_m": 0.3}}, "robot: the robot id (a string: cso/<robot>/... keys); the robot's body and limits are exploration.robot"),
        ({"exploration.planner.lookahed_m": 0.4}, "exploration.planner: unknown key(s) lookahed_m (did you mean lookahead_m?)"),  # a typo: as before
        # a misspelt section is a typo too, not its keys' homes (was: "exploraton (did you mean exploration.planner or
        # services.planner?)", and lookahead_m is no key of services.planner)
        ({"exploraton.planner.lookahead_m": 0.4}, "unknown key(s) exploraton (did you mean exploration?); known: exploration"),
        ({"servics.mapper.restore_timeout_s": 2.0}, "unknown key(s) servics (did you mean services?); known: exploration"),
    ],
)
def test_a_profile_key_in_the_wrong_section_names_the_section_it_belongs_to(settings, said):
    """A Nav2 user writes the controller's lookahead under the planner service, or an eval.yaml section at a profile's
    top level: the error names where the key goes, not the nearest spelling in the wrong section (``frontier`` at the
    top level used to suggest ``router``; ``services.sim.timestep_s``, ``cmd_timeout_s``)."""
    from cso_runtime.run_profile import load_profile

    with pytest.raises(ConfigError) as caught:
        load_profile("lockstep", {}, settings=settings)
    assert said in str(caught.value)
    assert "lockstep.yaml with --set " in str(caught.value)  # the file and the flags, as every profile error



def test_every_misplaced_key_is_named_in_one_error():
    """Three keys in the wrong sections are three fixes: the error named only the first (``wrong_section`` stopped
    there), so a user learnt of them one run at a time. Each is named with its home, a section's keys together."""
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import load_profile

    settings = {"lookahead_m": 0.4, "masks.goal_tolerance_m": 0.5, "min_cluster_size_m": 0.5}
    with pytest.raises(ConfigError) as caught:
        EvalRequest(methods=["greedy-dist"], settings=settings).exploration_config()
    said = str(caught.value)
    assert "unknown key(s) lookahead_m (did you mean planner.lookahead_m?), min_cluster_size_m (did you mean frontier.min_cluster_size_m?); known: episode" in said
    assert "masks: unknown key(s) goal_tolerance_m (did you mean episode.goal_tolerance_m?); known: alpha1_m" in said
    with pytest.raises(ConfigError) as caught:
        load_profile("lockstep", {}, settings={"services.planner.lookahead_m": 0.4, "services.sim.timestep_s": 0.01, "backoff_s": 1.0})
    said = str(caught.value)
    for home in ("exploration.planner.lookahead_m", "services.sim.mujoco.timestep_s", "supervision.backoff_s"):
        assert f"(did you mean {home}?)" in said

def test_a_misspelt_key_beside_a_misplaced_one_is_named_in_the_same_error():
    """``wrong_section`` named every misplaced key but not a misspelt one beside them, which ``from_dict`` says only
    once they are fixed: one more run to learn of it. The error names it too, with its nearest spelling."""
    from cso_runtime.evaluation import EvalRequest

    with pytest.raises(ConfigError) as caught:
        EvalRequest(methods=["greedy-dist"], settings={"lookahead_m": 0.4, "planner.lookahed_m": 0.5}).exploration_config()
    said = str(caught.value)
    assert "unknown key(s) lookahead_m (did you mean planner.lookahead_m?); known: episode" in said
    assert "planner: unknown key(s) lookahed_m (did you mean lookahead_m?); known: " in said
    with pytest.raises(ConfigError) as caught:  # a misspelt key alone: from_dict's words, as before
        EvalRequest(methods=["greedy-dist"], settings={"planner.lookahed_m": 0.5}).exploration_config()
    assert "planner: unknown key(s) lookahed_m (did you mean lookahead_m?)" in str(caught.value)


def test_a_service_of_ones_own_may_take_any_name_and_keys():
    """The misplaced-key check leaves a service of one's own alone: its name may be a section's elsewhere (``sensor``)."""
    from cso_runtime.run_profile import load_profile

    profile, _ = load_profile("lockstep", {}, settings={"services.sensor": {"command": ["/bin/true"]}})
    assert profile.services["sensor"]["command"] == ["/bin/true"]


def test_eval_yaml_names_every_exploration_key_with_its_default():
    """configs/eval.yaml is where a user looks up every exploration parameter: each one is there with its default,
    as a key or, where giving it would override a flag (the sensor preset, the MuJoCo LIMO's mount and body), as a
    commented-out line (``# range_max_m: 8.0``)."""
    import yaml

    text = (CONFIGS / "eval.yaml").read_text(encoding="utf-8")
    given = load_yaml(CONFIGS / "eval.yaml")
    commented = dict(re.findall(r"^\s*# (\w+): (\S+)", text, flags=re.MULTILINE))
    missing = []
    for section, values in to_dict(ExplorationConfig()).items():
        for key, default in values.items():
            if key in (given.get(section) or {}):
                continue
            if key not in commented or yaml.safe_load(commented[key]) != default:
                missing.append(f"{section}.{key} ({default})")
    assert missing == []


def test_every_service_parameter_refuses_a_negative_duration_or_count():
    """A negative time or count in a profile is a typo, refused naming the key before anything starts (the mapper's
    ``restore_timeout_s`` of -1 used to be taken, its start-up query cut to 10 ms). Lengths that may be negative
    (a mount behind the centre) or ignored (the mapper's grid without ``resolution_m``) aside."""
    import dataclasses
    import typing

    from services import SERVICE_NAMES, params_class

    taken = []
    for name in SERVICE_NAMES:
        cls = params_class(name)
        hints = typing.get_type_hints(cls) if cls is not None else {}
        for key in (f.name for f in dataclasses.fields(cls)) if cls is not None else ():
            if hints[key] in (int, float) and not (name == "mapper" and key in ("width_m", "height_m")):
                try:
                    from_dict(cls, {key: -1}, where=f"services.{name}")
                    taken.append(f"services.{name}.{key}")
                except ConfigError as exc:
                    assert key in str(exc), str(exc)
    assert taken == []


def test_a_scene_given_to_a_real_robots_profile_is_refused_and_its_own_default_scene_is_not():
    """``up --profile limo-ros2 --scene builtin`` would load nothing (the robot explores the room it is in): a
    ConfigError naming the flag. The profile on its own loads, and says its scene is the room it is in."""
    from cso_runtime.run_profile import REAL_ROBOT_SCENE, load_profile

    with pytest.raises(ConfigError, match="--scene builtin: .*runs a real robot .*no scene to load"):
        load_profile("limo-ros2", {"scene": "builtin"})
    profile, _ = load_profile("limo-ros2", {}, connect=["tcp/127.0.0.1:7447"])
    assert profile.scene_label == REAL_ROBOT_SCENE


def test_a_profiles_grid_bound_is_checked_against_its_own_arena_before_anything_starts():
    """``max_grid_cells`` bounds every grid the run's processes decode (docs/messages.md, Sizes): a bound out of range,
    or below the cells of the arena the profile itself sets (limo-ros2's, the mapper's explicit grid) or of its sim's
    scene, would have every service refuse every map; it is refused at load, naming the keys. The shipped profiles fit
    the default."""
    from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, MAX_GRID_CELLS
    from cso_runtime.run_profile import load_profile

    robot = ["tcp/127.0.0.1:7447"]
    profile, _ = load_profile("limo-ros2", {}, connect=robot)
    assert profile.max_grid_cells == DEFAULT_MAX_GRID_CELLS == 4_000_000
    assert load_profile("lockstep", {})[0].max_grid_cells == DEFAULT_MAX_GRID_CELLS
    for bad in (0, MAX_GRID_CELLS + 1):
        with pytest.raises(ConfigError, match=rf"max_grid_cells must be an integer in 1 \.\. 50_000_000, got {bad}"):
            load_profile("lockstep", {}, settings={"max_grid_cells": bad})
    with pytest.raises(ConfigError, match="max_grid_cells: expected an integer, got 2.5"):
        load_profile("lockstep", {}, settings={"max_grid_cells": 2.5})
    big = {"services.ros2_bridge.arena_width_m": 150.0, "services.ros2_bridge.arena_height_m": 100.0}  # 3000 x 2000 at 0.05 m
    with pytest.raises(ConfigError, match=r"arena_width_m, arena_height_m: a 150 x 100 m grid at 0.05 m is 3000 x 2000 = 6_000_000 cells, more than max_grid_cells \(4_000_000\)"):
        load_profile("limo-ros2", {}, connect=robot, settings=big)
    assert load_profile("limo-ros2", {}, connect=robot, settings={**big, "max_grid_cells": 6_000_000})[0].max_grid_cells == 6_000_000
    with pytest.raises(ConfigError, match=r"scene builtin: its grid is 640 x 480 = 307_200 cells, more than max_grid_cells \(300_000\): raise max_grid_cells"):
        load_profile("lockstep", {"scene": "builtin"}, settings={"max_grid_cells": 300_000})  # a sim's scene, as it is loaded
    assert load_profile("lockstep", {"scene": "builtin"}, settings={"max_grid_cells": 307_200})[0].max_grid_cells == 307_200


def test_a_mappers_explicit_grid_is_checked_against_the_bound_at_the_size_the_mapper_makes_it():
    """The mapper makes its explicit grid ``round(height_m / resolution_m)`` x ``round(width_m / resolution_m)`` cells;
    the profile's check of ``max_grid_cells`` counted a cell more each way where the size is not a whole number of
    cells (100.4 cells: 101), and refused a profile whose mapper's grid fits its bound exactly. Both now count the same."""
    from cso_runtime.run_profile import load_profile
    from services.mapper import MapperParams

    robot = ["tcp/127.0.0.1:7447"]
    mapper = {  # a real robot's (an explicit grid is for its arena), whose bridge's arena is 100 x 100 cells too
        "services.mapper.resolution_m": 0.1, "services.mapper.width_m": 10.04, "services.mapper.height_m": 10.04,
        "services.ros2_bridge.arena_width_m": 5.0, "services.ros2_bridge.arena_height_m": 5.0,
    }  # fmt: skip
    assert load_profile("limo-ros2", {}, connect=robot, settings={**mapper, "max_grid_cells": 10_000})[0].max_grid_cells == 10_000
    assert MapperParams(resolution_m=0.1, width_m=10.04, height_m=10.04).explicit_shape() == (100, 100)  # the mapper's map
    with pytest.raises(ConfigError, match=r"services.mapper.width_m, height_m: a 10.04 x 10.04 m grid at 0.1 m is 100 x 100 = 10_000 cells, more than max_grid_cells \(9_999\)"):
        load_profile("limo-ros2", {}, connect=robot, settings={**mapper, "services.ros2_bridge.arena_width_m": 4.0, "max_grid_cells": 9_999})


def test_an_arena_too_large_to_count_its_cells_is_refused_as_over_the_grid_bound():
    """A finite arena whose cells overflow a float (``arena_width_m: 1e308`` at 1 mm) ended ``up``'s profile check in
    an OverflowError traceback (``math.ceil`` of infinity) instead of the bound's refusal; the mapper's explicit grid
    the same (``round``). Both are refused as grids over ``max_grid_cells``, naming the keys."""
    from cso_runtime.run_profile import load_profile

    robot = ["tcp/127.0.0.1:7447"]
    huge = {"services.ros2_bridge.arena_width_m": 1e308, "services.ros2_bridge.resolution_m": 0.001}
    with pytest.raises(ConfigError, match=r"services.ros2_bridge.arena_width_m, arena_height_m: a 1e\+308 x 20 m grid at 0.001 m is too many cells to count, more than max_grid_cells"):
        load_profile("limo-ros2", {}, connect=robot, settings=huge)
    mapper = {"services.mapper.resolution_m": 0.001, "services.mapper.width_m": 10.0, "services.mapper.height_m": 1e308}
    with pytest.raises(ConfigError, match=r"services.mapper.width_m, height_m: a 10 x 1e\+308 m grid at 0.001 m is too many cells to count"):
        load_profile("limo-ros2", {}, connect=robot, settings=mapper)


@pytest.mark.parametrize(
    "service, profile, said",
    [
        ("mapper", {"services": {"mapper": {"resolution_m": 0.001, "width_m": 1e308, "height_m": 1e308}}}, "a 1e+308 x 1e+308 m grid at 0.001 m is too many cells to count"),
        ("mapper", {"services": {"mapper": {"resolution_m": 0.001, "width_m": 200.0, "height_m": 200.0}}}, "200000 x 200000 = 40_000_000_000 cells, more than max_grid_cells"),
        ("ros2_bridge", {"services": {"ros2_bridge": {"resolution_m": 0.001, "arena_width_m": 1e308}}}, "a 1e+308 x 20 m grid at 0.001 m is too many cells to count"),
        ("sim", {"scene": "generated:small:1:0", "seed": float("inf"), "services": {"sim": {}}}, "seed: expected an integer, got inf"),
        ("sim", {"scene": "generated:small:1:0", "seed": [1], "services": {"sim": {}}}, "seed: expected an integer, got [1]"),
        ("overflowing", {"services": {"overflowing": {}}}, "overflowing: bad configuration: cannot convert float infinity to integer"),
        ("sim", {"scene": "generated:small:1:0", "m_per_px": [1], "services": {"sim": {}}}, ": m_per_px: expected a number, got [1]"),
        ("sim", {"scene": 5, "services": {"sim": {}}}, ": scene: expected a string, got 5"),
        ("frontier", {"exploration": {"frontier": {"entropy_window_m": 1e300}}, "services": {"frontier": {}}}, "frontier.entropy_window_m must be in (0, 5,000,000,000] m"),
        ("planner", {"exploration": {"planner": {"lookahead_m": 1e9}}, "services": {"planner": {}}}, "planner.lookahead_m must be in (0, 100] m"),
    ],
)
def test_a_service_started_by_hand_with_absurd_sizes_says_so_in_one_line_and_exits_2(tmp_path, caplog, service, profile, said):
    """A service started by hand (``python -m services.mapper --config FILE``: no ``up`` checked its profile) with a grid
    too large to count ended in an OverflowError traceback (exit 1), one too large to allocate in a MemoryError one
    (40 GB for 200 m at 1 mm), the ROS bridge's arena only at its first odometry, and a seed no integer (``.inf``,
    ``[1]``) in the sim's ``int()``. Each is now the bad configuration it is, in one line, exit 2 (not restarted), with
    ``up``'s words for the grids (``messages.check_configured_grid``); a service of one's own that overflows on its
    config as it is made gets the same line. A top-level key of the wrong type (``m_per_px: [1]``: a TypeError traceback
    in the sim's ``float()``) is refused in ``up``'s words (``config.check_field_types``), and a frontier window longer
    than any map (``entropy_window_m: 1e300``, which the frontier service took) in ``FrontierConfig.validate``'s."""
    import yaml

    from services import service_class
    from services.common import Service, service_main

    class Overflowing(Service):
        name = "overflowing"

        def __init__(self, ctx: object) -> None:
            raise OverflowError("cannot convert float infinity to integer")

    cls = Overflowing if service == "overflowing" else service_class(service)
    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump(profile))
    assert service_main(cls, ["--config", str(path), "--connect", "tcp/127.0.0.1:1"], exit_process=False) == 2
    errors = [r for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and f"{service}: bad configuration: " in errors[0].getMessage() and said in errors[0].getMessage()
    assert errors[0].exc_info is None


def test_a_service_started_by_hand_warns_once_of_each_unknown_top_level_key_and_goes_on(tmp_path, caplog):
    """A service started by hand (``cso-runtime service NAME --config FILE``) ignored a top-level key ``up`` refuses (a
    typo: ``mehtod: cso`` ran greedy-dist in silence). It warns once, naming each, in ``up``'s words (a misspelling's
    nearest key, a misplaced key's home), and goes on with the keys it knows: refusing would stop files run by hand."""
    import logging

    import yaml

    from services.common import load_profile_for_service

    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump({"mehtod": "cso", "frontier": {"min_cluster_size_m": 0.5}, 7: 1, "services": {"mapper": {}}}))
    with caplog.at_level(logging.WARNING):
        profile, _, params = load_profile_for_service(path, "mapper")
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1, warnings
    (said,) = warnings
    assert said.startswith(f"{path}: unknown key(s) ") and "ignored" in said and "`up` refuses" in said, said
    for named in ("mehtod (did you mean method?)", "frontier (did you mean exploration.frontier or services.frontier?)", "7"):
        assert named in said, said
    assert profile["mehtod"] == "cso" and params == {}
    caplog.clear()
    path.write_text(yaml.safe_dump({"method": "cso", "services": {"mapper": {}}}))
    load_profile_for_service(path, "mapper")
    assert not [r for r in caplog.records if r.levelname == "WARNING"]


def test_a_hand_started_service_and_from_dict_say_unknown_profile_keys_in_one_wording():
    """``run_profile.unknown_top_level_keys`` (a service started by hand) wrote its own copy of ``from_dict``'s "unknown
    key(s) ...; known: ..." (``up``'s words): both are ``config.unknown_keys_said``'s, the same text for a typo."""
    from cso_runtime.config import unknown_keys_said
    from cso_runtime.run_profile import Profile, unknown_top_level_keys

    data = {"mehtod": "cso", "zzz": 1}
    with pytest.raises(ConfigError) as refused:
        from_dict(Profile, data, where="profile")
    said = unknown_top_level_keys(data)
    assert said is not None and str(refused.value) == f"profile: {said}"
    assert said.startswith("unknown key(s) mehtod (did you mean method?), zzz; known: ") and said == unknown_keys_said(["mehtod", "zzz"], Profile.__dataclass_fields__)


@pytest.mark.parametrize("key", ["frontier.entropy_window_m", "frontier.min_cluster_size_m", "episode.goal_tolerance_m"])
def test_a_length_longer_than_any_map_is_refused_naming_the_key_and_the_bound(key):
    """``frontier.entropy_window_m`` or ``episode.goal_tolerance_m`` of 1e300 m were taken by ``up`` and ``eval`` (the
    first failed in the frontier layer helper, the second in every episode that gave a goal up); a length above the
    longest side a map may have (``messages.MAX_GRID_SIDE_M``: ``MAX_GRID_CELLS`` cells in one row at the coarsest cell)
    is refused in one line that says which key and what is allowed; one up to it is taken."""
    from cso_runtime.messages import MAX_GRID_CELLS, MAX_GRID_SIDE_M, MAX_RESOLUTION_M

    section, name = key.split(".")
    assert MAX_GRID_SIDE_M == MAX_GRID_CELLS * MAX_RESOLUTION_M == 5e9
    with pytest.raises(ConfigError, match=rf"^exploration.{key} must be in [\[(]0, 5,000,000,000\] m \(the longest side a map may have: messages.MAX_GRID_SIDE_M\), got 1e\+300$"):
        from_dict(ExplorationConfig, {section: {name: 1e300}}, where="exploration")
    from_dict(ExplorationConfig, {section: {name: MAX_GRID_SIDE_M}}, where="exploration")


def test_a_service_started_by_hand_takes_a_profile_that_joins_the_router_given_on_its_command_line(tmp_path):
    """``check_field_types`` built the profile's ``router`` and ``supervision`` sections with ``from_dict``, which runs
    their ``validate``: a profile of ``router.embedded: false`` without ``router.connect`` (``up --connect ROBOT`` gives
    the endpoint, as docs/hardware.md's ``--set router.embedded=false``) was refused by a service started by hand with
    its own ``--connect`` (``router.embedded is false: give the router to join with --connect``), which it had run
    before. The hand-started check is of the values' types, in the sections too; a wrong type there is still refused."""
    import yaml

    from services.common import load_profile_for_service

    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump({"router": {"embedded": False}, "services": {"mapper": {}}}))
    _, _, params = load_profile_for_service(path, "mapper")
    assert params == {}
    path.write_text(yaml.safe_dump({"router": {"embedded": False, "connect_timeout_s": [1]}, "services": {"mapper": {}}}))
    with pytest.raises(ConfigError, match=r"router.connect_timeout_s: expected a number, got \[1\]"):
        load_profile_for_service(path, "mapper")
    path.write_text(yaml.safe_dump({"router": [1], "services": {"mapper": {}}}))
    with pytest.raises(ConfigError, match=r"router: expected a mapping, got list"):
        load_profile_for_service(path, "mapper")


def _bounded_keys() -> list[tuple[str, type, str, object]]:
    """Each key of an exploration config section that a ``config.Bound`` table bounds: (section, class, key, bound)."""
    from cso_runtime.config import (
        EPISODE_BOUNDS,
        PLANNER_BOUNDS,
        SENSOR_BOUNDS,
        EpisodeConfig,
        FrontierConfig,
        MaskConfig,
        PlannerConfig,
        SensorConfig,
        frontier_bounds,
        mask_bounds,
    )

    tables = [
        ("sensor", SensorConfig, SENSOR_BOUNDS),
        ("frontier", FrontierConfig, frontier_bounds()),
        ("masks", MaskConfig, mask_bounds()),
        ("episode", EpisodeConfig, EPISODE_BOUNDS),
        ("planner", PlannerConfig, PLANNER_BOUNDS),
    ]
    return [(section, cls, key, bound) for section, cls, table in tables for key, bound in table.items()]


@pytest.mark.parametrize(("section", "cls", "key", "bound"), _bounded_keys(), ids=lambda v: v if isinstance(v, str) else "")
def test_a_bounded_key_outside_its_range_is_refused_naming_the_key_the_value_and_the_range(section, cls, key, bound):
    """``planner.lookahead_m`` of 0, -1 or 1e9 m (and the planner's, the episode's, the masks' and the sensor's other
    numbers) was taken by ``eval``, ``up`` and a service started by hand, or failed deep inside an episode. Each is
    refused by its section's ``validate`` in one line that names the key, the value and the range (``Bound``); the
    bound itself is taken."""
    import typing

    from cso_runtime.config import number_said

    is_int = typing.get_type_hints(cls)[key] is int
    below = bound.low if bound.low_open else bound.low - 1
    above = bound.high * 10 if bound.high > 0 else 1
    for value in (below, above):
        value = int(value) if is_int else float(value)
        said = rf"^exploration\.{section}\.{key} must be in [\[(]{re.escape(number_said(bound.low))}, {re.escape(number_said(bound.high))}\]"
        with pytest.raises(ConfigError, match=said + rf".*, got {re.escape(number_said(value))}$"):
            from_dict(ExplorationConfig, {section: {key: value}}, "exploration")
    if key == "beta_near_m":
        return  # beta_far_m must be above it, and cannot be
    at_most = {key: int(bound.high) if is_int else float(bound.high)}
    if key == "stop_distance_m":
        at_most["slow_down_distance_m"] = bound.high  # stop_distance_m <= slow_down_distance_m
    from_dict(cls, at_most, section)


def _numeric_keys() -> list[tuple[str, str, type]]:
    """Every number of an exploration config: (section, key, its type)."""
    import dataclasses
    import typing

    sections = typing.get_type_hints(ExplorationConfig)
    return [
        (section, f.name, hint)
        for section, cls in sections.items()
        for f in dataclasses.fields(cls)
        if (hint := typing.get_type_hints(cls)[f.name]) in (int, float)
    ]


@pytest.mark.parametrize(("section", "key", "hint"), _numeric_keys(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_number_of_the_exploration_config_has_a_bound_on_both_sides(section, key, hint):
    """No number of the exploration config is taken unbounded: an absurd value either way (a 1e300 m lookahead, -1e300
    steps) is a ConfigError naming its key before anything starts, whatever the key (a key added without a bound fails
    here)."""
    for value in (10**15, -(10**15)) if hint is int else (1e300, -1e300):
        with pytest.raises(ConfigError, match=rf"{section}\.{key}\b"):
            from_dict(ExplorationConfig, {section: {key: value}}, "exploration")


def test_a_scan_of_more_beams_than_a_message_takes_is_refused_before_it_allocates_them():
    """``sensor.resolution_deg: 1e-6`` was taken: 180 million beams a scan, gigabytes for each ray cast (and a scan no
    receiver takes: ``messages.MAX_BEAMS``). It is refused naming the finest resolution the field of view takes."""
    from cso_runtime.config import SensorConfig
    from cso_runtime.messages import MAX_BEAMS

    with pytest.raises(ConfigError, match=r"^eval\.sensor\.resolution_deg must be at least 0\.0018 degrees for a 180-degree field of view .*got 1e-06: 180,000,000 beams$"):
        from_dict(ExplorationConfig, {"sensor": {"resolution_deg": 1e-6}}, "eval")
    SensorConfig(fov_deg=360.0, resolution_deg=360.0 / MAX_BEAMS).validate()


@pytest.mark.parametrize("resolution_deg", [5e-324, 1e-310])
def test_a_resolution_so_fine_its_beams_overflow_is_refused_not_an_overflow_error(resolution_deg):
    """``sensor.resolution_deg: 5.0e-324`` (a positive float, so in (0, fov_deg]) made ``fov_deg / resolution_deg``
    infinite, and the beams' count ``round(inf)`` an OverflowError traceback out of ``eval`` and ``up --dry-run``; it
    is refused as any resolution finer than ``messages.MAX_BEAMS`` beams allow."""
    with pytest.raises(ConfigError, match=r"^eval\.sensor\.resolution_deg must be at least 0\.0018 degrees for a 180-degree field of view "):
        from_dict(ExplorationConfig, {"sensor": {"resolution_deg": resolution_deg}}, "eval")


def test_eval_max_steps_beyond_the_longest_episode_is_refused_as_the_configs_own_key():
    """``eval --max-steps 2000000`` went round ``episode.max_steps``' bound (the flag replaced the checked value) and
    ran until the result did not fit its message; it is refused as the key would be."""
    from cso_runtime.evaluation import EvalRequest

    with pytest.raises(ConfigError, match=r"^--max-steps must be in \[1, 1,000,000\] .*got 2,000,000$"):
        EvalRequest(methods=["greedy-dist"], max_steps=2_000_000).exploration_config()
    assert EvalRequest(methods=["greedy-dist"], max_steps=1_000_000).exploration_config().episode.max_steps == 1_000_000


@pytest.mark.parametrize(
    ("settings", "refused"),
    [
        ({"episode.max_steps": 9}, "--max-steps 5 and --set episode.max_steps=9 both set episode.max_steps, to different values: give one"),
        ({"episode": {"max_steps": 7}}, "--max-steps 5 and --set episode={max_steps: 7} both set episode.max_steps"),
        ({"episode.max_steps": "9"}, "--max-steps 5 and --set episode.max_steps='9' both set episode.max_steps"),
        ({"episode.max_steps": 5}, None),
        ({"episode": {"replan_every_steps": 3}}, None),
        ({"episode.max_steps": 9, "episode": {"replan_every_steps": 3}}, None),  # the section replaced without it: --max-steps alone
    ],
)
def test_eval_refuses_max_steps_and_a_set_step_limit_that_disagree(settings, refused):
    """``eval --max-steps 5 --set episode.max_steps=9`` ran 5 steps, in silence; as ``train`` refuses ``--seed 3 --set
    seed=4`` (``config.refuse_two_values``), eval now refuses the two, naming both; the same value twice is fine."""
    from cso_runtime.evaluation import EvalRequest

    request = EvalRequest(methods=["greedy-dist"], max_steps=5, settings=settings)
    if refused is None:
        assert request.exploration_config().episode.max_steps == 5
    else:
        with pytest.raises(ConfigError, match="^" + re.escape(refused)):
            request.exploration_config()


def _service_sections() -> list[tuple[str, type]]:
    """Each section of a profile with numbers of its own: the services' parameters, the router, supervision and the
    profile's top level."""
    from cso_runtime.run_profile import Profile, RouterConfig, SupervisionConfig
    from services.foxglove_bridge import FoxgloveBridgeParams
    from services.frontier import FrontierParams
    from services.mapper import MapperParams
    from services.planner import PlannerParams
    from services.policy import PolicyParams
    from services.ros2_bridge import Ros2BridgeParams
    from services.sim import SimParams

    return [
        ("services.frontier", FrontierParams),
        ("services.mapper", MapperParams),
        ("services.sim", SimParams),
        ("services.policy", PolicyParams),
        ("services.planner", PlannerParams),
        ("services.foxglove_bridge", FoxgloveBridgeParams),
        ("services.ros2_bridge", Ros2BridgeParams),
        ("router", RouterConfig),
        ("supervision", SupervisionConfig),
        ("profile", Profile),
    ]


BOUNDED_ELSEWHERE = {
    ("services.mapper", "resolution_m"): "the explicit grid's cells: MapperParams.check_grid against max_grid_cells",
    ("services.mapper", "width_m"): "the same",
    ("services.mapper", "height_m"): "the same",
    ("services.ros2_bridge", "resolution_m"): "the arena's cells: Ros2BridgeParams' grid check against max_grid_cells",
    ("services.ros2_bridge", "arena_width_m"): "the same",
    ("services.ros2_bridge", "arena_height_m"): "the same",
    ("profile", "m_per_px"): "the scene's metres per pixel, (0, 10] (scenes)",
    ("profile", "max_grid_cells"): "messages.check_max_grid_cells",
    ("profile", "seed"): "config.check_seed",
    ("services.foxglove_bridge", "port"): "0..65535",
}
"""Numbers of a profile that its own checks bound, not a ``Bound`` table (tested where they are)."""


def _service_numbers() -> list[tuple[str, type, str, type]]:
    import dataclasses
    import typing

    return [
        (where, cls, f.name, hint)
        for where, cls in _service_sections()
        for f in dataclasses.fields(cls)
        if (hint := typing.get_type_hints(cls)[f.name]) in (int, float) and (where, f.name) not in BOUNDED_ELSEWHERE
    ]


@pytest.mark.parametrize(("where", "cls", "key", "hint"), _service_numbers(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_time_and_count_of_a_profile_is_bounded_above_naming_the_key_the_value_and_the_range(where, cls, key, hint):
    """``services.planner.stale_after_s=1e300``, ``services.sim.real_time_factor=1e9``, ``supervision.backoff_max_s=1e12``
    or ``services.mapper.max_pending_scans=100000000`` were taken by ``up --dry-run`` (and by a service started by hand),
    to be met inside a running service. A wait, period or timeout is at most a day (``config.MAX_WAIT_S``), a count of
    restarts ``config.MAX_RESTARTS``, and so on; above it the profile is refused in one line naming the key, the value
    and the range. Every number of every section is covered: one added without a bound fails here."""
    value = 10**15 if hint is int else 1e300
    with pytest.raises(ConfigError, match=rf"\b{key} must be in [\[(][01], [^\]]+\].*, got {re.escape(f'{value:,}' if hint is int else '1e+300')}$"):
        from_dict(cls, {key: value}, where)


def test_the_largest_time_a_profile_takes_is_a_day():
    """The bound itself is taken (a day: 86,400 s)."""
    from cso_runtime.config import MAX_WAIT_S
    from cso_runtime.run_profile import SupervisionConfig
    from services.planner import PlannerParams
    from services.sim import SimParams

    assert MAX_WAIT_S == 86_400
    from_dict(PlannerParams, {"stale_after_s": MAX_WAIT_S, "restore_timeout_s": MAX_WAIT_S}, "services.planner")
    from_dict(SimParams, {"lockstep_give_up_s": MAX_WAIT_S, "wait_for_services_s": MAX_WAIT_S}, "services.sim")
    from_dict(SupervisionConfig, {"backoff_s": MAX_WAIT_S, "backoff_max_s": MAX_WAIT_S, "restart_window_s": MAX_WAIT_S}, "supervision")


def _training_bounds() -> list[tuple[str, object]]:
    from cso_runtime.learned.ppo import ARGS_BOUNDS

    return list(ARGS_BOUNDS.items())


AT_MOST_BESIDE = {
    "num_minibatches": {"num_envs": 1024, "num_steps": 1_000_000},  # num_minibatches divides num_envs x num_steps
    "heads": {"hidden": 4096},  # heads divide hidden
    "knn": {"max_frontier_nodes": 10_000, "max_path_nodes": 10_000},  # knn <= max_frontier_nodes + max_path_nodes - 1
}
"""The keys a training key's largest value needs beside it (``Args.validate``'s checks between keys)."""


@pytest.mark.parametrize(("key", "bound"), _training_bounds(), ids=lambda v: v if isinstance(v, str) else "")
def test_train_refuses_a_number_outside_its_bound_before_anything_starts(tmp_path: Path, capsys, key, bound):
    """``train --num-envs 100000``, ``--hidden 1000000`` or ``--set max_steps=2000000`` were taken (processes, a network
    of gigabytes, an episode whose result no message holds), and ``--set learning_rate=1e9``, ``checkpoint_every=1e15``
    or ``ent_coef=-5`` too (lower-bound checks alone, some of whose messages said no value); each is refused before the
    set-up, naming the file and the flag, the key, the value and the range (``learned.ppo.ARGS_BOUNDS``); the bound
    itself is taken."""
    import typing

    from cso_runtime.cli import training_args
    from cso_runtime.config import number_said
    from cso_runtime.learned.ppo import Args

    is_int = typing.get_type_hints(Args)[key] is int
    above = bound.high * 10 if bound.high > 0 else 1
    below = bound.low if bound.low_open else bound.low - 1
    opening, closing = "(" if bound.low_open else "[", ")" if bound.high_open else "]"
    recipe = small_train_recipe(tmp_path)
    for value in (int(above) if is_int else float(above), int(below) if is_int else float(below)):
        said = train_refusal(recipe, {}, [f"{key}={value}"], capsys)
        assert f"error: {recipe} with --set {key}={value}: {key} must be in {opening}{number_said(bound.low)}, {number_said(bound.high)}{closing}" in said, said
        assert f"got {number_said(value)}" in said
    if bound.high_open:
        return  # a value below it is taken as any inside
    at_most = int(bound.high) if is_int else bound.high
    beside = [f"{k}={v}" for k, v in AT_MOST_BESIDE.get(key, {}).items()]
    assert getattr(training_args(recipe, {}, [*beside, f"{key}={at_most}"]), key) == at_most


def _training_numbers() -> list[tuple[str, type]]:
    import dataclasses
    import typing

    from cso_runtime.learned.ppo import Args

    hints = typing.get_type_hints(Args)
    return [(f.name, hints[f.name]) for f in dataclasses.fields(Args) if hints[f.name] in (int, float)]


@pytest.mark.parametrize(("key", "hint"), _training_numbers(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_number_of_trains_args_has_a_bound_on_both_sides(key, hint):
    """No number of ``train``'s ``Args`` is taken unbounded: an absurd value either way (a 1e300 learning rate, -1e15
    plans) is a ConfigError naming its key before anything starts (``ARGS_BOUNDS``; ``seed`` and ``beta_far_m`` have
    their own checks); a key added without a bound fails here."""
    from cso_runtime.learned.ppo import Args

    for value in (10**15, -(10**15)) if hint is int else (1e300, -1e300):
        with pytest.raises(ConfigError, match=rf"\b{key}\b"):
            from_dict(Args, {key: value}, "train.yaml")


def test_each_dungeon_scale_of_train_is_bounded_as_evals_m_per_px():
    """``dungeon_m_per_px: [0.1, 50]`` (a scale in cm) was taken; each scale is refused outside (0, 10] m as eval's
    ``--m-per-px`` is, naming the key, the value and the range."""
    from cso_runtime.learned.ppo import Args

    with pytest.raises(ConfigError, match=r"^train\.yaml: dungeon_m_per_px must be in \(0, 10\] m \(.*\), got 50$"):
        from_dict(Args, {"dungeon_m_per_px": [0.1, 50]}, "train.yaml")
    assert from_dict(Args, {"dungeon_m_per_px": [10.0]}, "train.yaml").dungeon_m_per_px == [10.0]


def _mujoco_bounds() -> list[tuple[str, object]]:
    from robot_sim.config import MUJOCO_SIM_BOUNDS

    return list(MUJOCO_SIM_BOUNDS.items())


MUJOCO_AT_MOST_BESIDE = {
    "timestep_s": {"odometry_rate_hz": 20.0, "actuator_time_constant_s": 0.1, "contact_time_constant_s": 0.1},
    "odometry_rate_hz": {"timestep_s": 0.001},
    "wheel_radius_m": {"body_height_m": 4.0, "wall_height_m": 5.0},  # below body_height_m and wall_height_m
    "lidar_height_m": {"wall_height_m": 5.0},  # below wall_height_m
}
"""The keys a MuJoCo parameter's largest value needs beside it (``MujocoSimConfig.validate``'s checks between keys)."""


@pytest.mark.parametrize(("key", "bound"), _mujoco_bounds(), ids=lambda v: v if isinstance(v, str) else "")
def test_a_mujoco_parameter_outside_its_range_is_refused_naming_the_key_the_value_and_the_range(key, bound):
    """``timestep_s: 1e9``, ``mass_kg: 4800`` (grams), ``odometry_rate_hz: 1e300`` were taken by ``eval --sim mujoco
    --sim-config F`` and ``up`` (lower-bound checks alone, whose "must be positive" said no value), to hang or blow up
    inside the physics. Each is refused by ``MujocoSimConfig.validate`` naming the file, the key, the value and the
    range (``robot_sim.config.MUJOCO_SIM_BOUNDS``); the bound itself is taken."""
    from cso_runtime.config import number_said
    from robot_sim.config import MujocoSimConfig

    below = bound.low if bound.low_open else (bound.low - 1 if bound.low <= 0 else bound.low / 10)
    opening = r"\(" if bound.low_open else r"\["
    for value in (bound.high * 10, below):
        said = rf"^sim\.yaml: {key} must be in {opening}{re.escape(number_said(bound.low))}, {re.escape(number_said(bound.high))}\]"
        with pytest.raises(ConfigError, match=said + rf".*, got {re.escape(number_said(value))}$"):
            from_dict(MujocoSimConfig, {key: value}, "sim.yaml")
    from_dict(MujocoSimConfig, {**MUJOCO_AT_MOST_BESIDE.get(key, {}), key: bound.high}, "sim.yaml")


def _mujoco_numbers() -> list[str]:
    import dataclasses
    import typing

    from robot_sim.config import MujocoSimConfig

    hints = typing.get_type_hints(MujocoSimConfig)
    return [f.name for f in dataclasses.fields(MujocoSimConfig) if hints[f.name] in (int, float)]


@pytest.mark.parametrize("key", _mujoco_numbers())
def test_every_number_of_the_mujoco_config_has_a_bound_on_both_sides(key):
    """No number of the MuJoCo LIMO's config is taken unbounded (``lidar_mount_x_m``, a float or None, must be the
    sensor's mount, which ``SensorConfig`` bounds): an absurd value either way is a ConfigError naming its key; a key
    added without a bound fails here."""
    from robot_sim.config import MujocoSimConfig

    for value in (1e300, -1e300):
        with pytest.raises(ConfigError, match=rf"\b{key}\b"):
            from_dict(MujocoSimConfig, {key: value}, "sim.yaml")


def test_eval_and_up_refuse_a_mujoco_parameter_out_of_range_before_anything_starts(tmp_path: Path):
    """``eval --sim mujoco --sim-config F`` with a mass in grams is refused in its check of the request (before any
    episode), naming the file, and ``up``'s profile (``services.sim.mujoco``) the same way."""
    from cso_runtime.evaluation import EvalRequest
    from cso_runtime.run_profile import load_profile

    params = tmp_path / "limo.yaml"
    params.write_text("mass_kg: 4800\n")
    request = EvalRequest(methods=["greedy-dist"], sim="mujoco", sim_config_path=params, out_dir=tmp_path / "o")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(params))}: mass_kg must be in \(0, 1,000\] kg \(MAX_MASS_KG\), got 4,800$"):
        request.validate()
    assert not (tmp_path / "o").exists()
    with pytest.raises(ConfigError, match=r"services\.sim\.mujoco: mass_kg must be in \(0, 1,000\] kg .*got 4,800$"):
        load_profile("sim", {}, settings={"services.sim.mujoco.mass_kg": 4800})



@dataclasses.dataclass
class _Inner:
    name: str = "a"
    count: int = 0


@dataclasses.dataclass
class _Outer:
    """A config of one section, for ``field_types``."""

    inner: _Inner = dataclasses.field(default_factory=_Inner)
    label: str = ""


def test_the_hint_of_a_set_read_as_another_type_reads_a_nested_keys_type_and_is_given_only_where_the_text_is_taken():
    """``refuse_a_setting_read_as_another_type`` looked a key's type up among the top-level fields alone: ``--set
    section.name=1`` of a text field one section down had no hint. ``field_types`` gives each dotted key's type, down
    every section; ``takes`` (the whole config built) keeps the hint to a text the config takes."""
    from cso_runtime.config import field_types, refuse_a_setting_read_as_another_type

    types = field_types(_Outer)
    assert types == {"inner": _Inner, "inner.name": str, "inner.count": int, "label": str}, types
    with pytest.raises(ConfigError, match=re.escape("--set inner.name=1 is read as a number, and inner.name is text: write --set inner.name='1'")):
        refuse_a_setting_read_as_another_type({"inner.name": 1, "inner.count": 2}, types)
    built: list[dict] = []
    with pytest.raises(ConfigError, match=re.escape("--set inner.name=true is read as true/false, and inner.name is text: write --set inner.name='true'")):
        refuse_a_setting_read_as_another_type({"inner.name": True, "inner.count": 2}, types, built.append)  # taken as text
    assert built == [{"inner.name": "true", "inner.count": 2}], built

    def refuses(_texts: dict) -> None:
        raise ConfigError("inner.name must be a or b")

    refuse_a_setting_read_as_another_type({"inner.name": 1}, types, refuses)  # the text refused too: no hint (its own error follows)
    refuse_a_setting_read_as_another_type({"inner.name": "1", "inner.count": 2, "inner": {"name": 1}}, types)  # text, a number's own field, a section: none


def test_a_nan_or_inf_written_as_most_tools_write_it_is_said_to_be_not_finite():
    """``--set planner.lookahead_m=nan`` (YAML reads ``nan`` as text: its own spelling is ``.nan``) said "expected a
    number, got 'nan'", where ``.nan`` says "must be finite": one value, one answer, whichever way it is written."""
    import yaml

    for text in ("nan", "NaN", "inf", "-inf", "+Infinity", ".nan", ".inf"):
        with pytest.raises(ConfigError, match=re.escape("planner.lookahead_m: must be finite")):
            from_dict(ExplorationConfig, {"planner": {"lookahead_m": yaml.safe_load(text)}})
    with pytest.raises(ConfigError, match=re.escape("planner.lookahead_m: expected a number, got 'far'")):
        from_dict(ExplorationConfig, {"planner": {"lookahead_m": "far"}})


def test_up_dry_run_names_the_profile_file_it_read(tmp_path, monkeypatch):
    """README: "your own [profiles] in ``./configs/profiles/`` of the working folder take precedence" over the packaged
    ones of the same name, and ``up --dry-run`` is "the profile as run". It did not say which file that was, so a
    ``configs/profiles/sim.yaml`` left in the folder ran in place of the packaged ``sim`` unseen: the dry run (and
    ``--resolved``) name the file read."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.run_profile import PACKAGED_PROFILES

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--dry-run"])
    assert r.exit_code == 0 and f"\n# read from {PACKAGED_PROFILES / 'sim.yaml'} (packaged)\n" in r.output, r.output[:400]
    own = tmp_path / "configs" / "profiles" / "sim.yaml"
    own.parent.mkdir(parents=True)
    own.write_text((PACKAGED_PROFILES / "sim.yaml").read_text())
    for flag in ("--dry-run", "--resolved"):
        r = CliRunner().invoke(app, ["up", "--profile", "sim", flag])
        assert r.exit_code == 0 and "\n# read from configs/profiles/sim.yaml (the working folder's, ahead of the packaged sim)\n" in r.output, r.output[:400]


def test_up_dry_run_says_whose_a_profile_named_with_a_dot_is(tmp_path, monkeypatch):
    """``--profile sim.v2`` is a name (``find_profile``: only a .yaml or .yml suffix makes a path), found as
    ``configs/profiles/sim.v2.yaml``; the dry run's "read from" line took its ``.v2`` for a path's suffix and said the
    file alone, not that it is the working folder's."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.run_profile import PACKAGED_PROFILES

    monkeypatch.chdir(tmp_path)
    own = tmp_path / "configs" / "profiles" / "sim.v2.yaml"
    own.parent.mkdir(parents=True)
    own.write_text((PACKAGED_PROFILES / "sim.yaml").read_text())
    r = CliRunner().invoke(app, ["up", "--profile", "sim.v2", "--dry-run"])
    assert r.exit_code == 0 and "\n# read from configs/profiles/sim.v2.yaml (the working folder's)\n" in r.output, r.output[:400]
    r = CliRunner().invoke(app, ["up", "--profile", str(own), "--dry-run"])  # a path: the file itself
    assert r.exit_code == 0 and f"\n# read from {own}\n" in r.output, r.output[:400]


def test_a_comment_of_a_dry_run_that_holds_a_line_break_stays_a_comment(tmp_path, monkeypatch):
    """``up --dry-run``/``--resolved`` print comments of what they read (the profile's name, its file, ``--weights``)
    above the YAML, each line a ``# `` line: a name with a line break in it (``name: "x\\nrobot: evil"``) put its second
    line out of the comment, so the printed YAML set ``robot: evil`` or did not load at all. Every line of a comment
    is a comment line; the output loads back as the profile it shows."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import commented_yaml

    assert yaml.safe_load(commented_yaml(["a\nrobot: evil", "b\r\nc"], {"robot": "r0"})) == {"robot": "r0"}
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.yaml").write_text('name: "x\\nrobot: evil"\nservices: {sim: {}, mapper: {}}\n')
    for flag in ("--dry-run", "--resolved"):
        r = CliRunner().invoke(app, ["up", "--profile", "p.yaml", flag])
        assert r.exit_code == 0, r.output
        shown = yaml.safe_load(r.output)
        assert (shown["name"], shown.get("robot", "r0")) == ("x\nrobot: evil", "r0"), r.output


def test_a_comment_of_a_dry_run_with_a_character_yaml_refuses_stays_yaml(tmp_path, monkeypatch):
    """A comment's line breaks are comment lines (above), but a character YAML allows nowhere in a file, in a comment
    neither (a control character: a profile's ``name: "x\\ay"``, a path with an escape sequence in it), was written as
    it is: the YAML reader refused the whole output ("unacceptable character #x0007"), so ``up --dry-run > p.yaml``
    gave no profile that loads, and a terminal was sent the raw control characters. Such a character is written as its
    escape (``\\x07``), as the YAML below the comments writes it in a value."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import commented_yaml

    written = commented_yaml(["a\x07b", "c\x1b[2Jd\x7f", "caf\u00e9\tok", "e\udcfff"], {"robot": "r0"})
    assert yaml.safe_load(written) == {"robot": "r0"}, written
    assert written.startswith("# a\\x07b\n# c\\x1b[2Jd\\x7f\n# caf\u00e9\tok\n# e\\udcfff\n"), written  # what YAML takes, as it is
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.yaml").write_text('name: "x\\ay"\nservices: {sim: {}, mapper: {}}\n')
    for flag in ("--dry-run", "--resolved"):
        r = CliRunner().invoke(app, ["up", "--profile", "p.yaml", flag])
        assert r.exit_code == 0 and "# profile x\\x07y, valid" in r.output, r.output
        assert yaml.safe_load(r.output)["name"] == "x\ay", r.output


YAML12_FORMS = {
    "leading_zero": ("010", 10),  # YAML 1.1 (PyYAML): 8, an octal
    "signed_zero": ("-007", -7),
    "hexadecimal": ("0x1F", 31),
    "octal": ("0o17", 15),  # YAML 1.2's octal; YAML 1.1: the text
    "underscores": ("1_000", "1_000"),  # YAML 1.1: 1000
    "sexagesimal": ("1:30", "1:30"),  # YAML 1.1: 90
    "sexagesimal_float": ("1:30.5", "1:30.5"),  # YAML 1.1: 90.5
    "exponent": ("5e-2", 0.05),  # YAML 1.1: the text
    "signed_dot": ("-.5", -0.5),  # YAML 1.1: the text
    "whole_exponent": ("1E3", 1000.0),
    "trailing_dot": ("2.", 2.0),
    "date": ("2024-01-01", "2024-01-01"),  # YAML 1.1: a date
    "infinity": ("-.inf", float("-inf")),
    "word_yes": ("yes", True),  # YAML 1.1's booleans are kept, as yaml-cpp's as<bool> and ROS 2's parameter files read them
    "word_Off": ("Off", False),
    "word": ("robot", "robot"),
    "tilde": ("~", None),
}
"""Scalars as YAML 1.2's core schema (and map_server's yaml-cpp) reads them, where PyYAML's YAML 1.1 reads most of
them otherwise; booleans as YAML 1.1 (and yaml-cpp, and ROS 2's rcl_yaml_param_parser) reads them."""


def _typed(data: dict) -> dict:
    """``data`` with each value's type beside it: 1 and True (and 10 and 10.0) are not one value here."""
    return {key: (type(value).__name__, value) for key, value in data.items()}


def test_config_files_set_and_flags_read_numbers_as_yaml_1_2_does(tmp_path: Path):
    """A config or profile file, ``--set`` and a field flag read scalars with PyYAML's YAML 1.1 resolver: ``010`` was
    8 (an octal), ``1_000`` was 1000, ``1:30`` was 90 (base 60), ``2024-01-01`` a date, where YAML 1.2 (map_server's
    yaml-cpp, and any YAML 1.2 reader of the same file) reads 10 and the texts; ``5e-2`` was the text, mended field by
    field (``yaml12_number``). One loader (``config.yaml_load``) now reads them all as YAML 1.2's core schema does,
    save its booleans: ``yes``/``no``/``on``/``off`` stay true/false, as yaml-cpp and ROS 2's parameter files read them."""
    from cso_runtime.cli import parse_settings
    from cso_runtime.config import flag_value, yaml_load

    expected = _typed({key: value for key, (_, value) in YAML12_FORMS.items()})
    f = tmp_path / "forms.yaml"
    f.write_text("".join(f"{key}: {text}\n" for key, (text, _) in YAML12_FORMS.items()))
    assert _typed(load_yaml(f)) == expected
    assert _typed(yaml_load(f.read_text())) == expected
    assert _typed(parse_settings([f"{key}={text}" for key, (text, _) in YAML12_FORMS.items()])) == expected
    assert _typed({key: flag_value(text, int | float | None) for key, (text, _) in YAML12_FORMS.items()}) == expected
    (tmp_path / "steps.yaml").write_text("episode: {max_steps: 0100}\nplanner: {lookahead_m: 05}\n")
    config = from_dict(ExplorationConfig, load_yaml(tmp_path / "steps.yaml"))
    assert (config.episode.max_steps, config.planner.lookahead_m) == (100, 5.0)
    for text in ("1_000", "1:30"):
        (tmp_path / "steps.yaml").write_text(f"episode: {{max_steps: {text}}}\n")
        with pytest.raises(ConfigError, match=re.escape(f"episode.max_steps: expected an integer, got '{text}'")):
            from_dict(ExplorationConfig, load_yaml(tmp_path / "steps.yaml"))
    assert parse_settings(["generated=[010, 0x10]"]) == {"generated": [10, 16]}
    assert flag_value("1_000,010", list[int]) == "1_000,010"  # a list flag's text is split and read by its field
    assert from_dict(ExplorationConfig, {"planner": {"lookahead_m": 1}}).planner.lookahead_m == 1.0


def test_texts_that_yaml_1_2_reads_as_numbers_are_written_quoted_so_they_read_back_as_text(tmp_path: Path):
    """What cso-runtime writes in YAML (``up --resolved``, a run's ``profile.yaml``, the launcher's profile, a map's
    YAML, ``--set`` texts in messages) was written by PyYAML's dumper, which quotes a text only where YAML 1.1 would
    read it otherwise: the text ``1e3`` (a robot's name, say) was written bare, which YAML 1.2 reads as 1000.0. Each
    text any YAML reader would take for another type is quoted now, and reads back as the text."""
    from cso_runtime.config import commented_yaml, yaml_dump, yaml_load, yaml_text

    texts = ["1e3", "-.5", "0o17", "0x1F", "010", "1_000", "1:30", "2024-01-01", "yes", "on", "null", "robot", ".inf", "5e-2"]
    data = {"robot": texts, "nested": {text: text for text in texts}}
    for written in (yaml_dump(data), commented_yaml(["a comment"], data)):
        assert yaml_load(written) == data, written
        (tmp_path / "back.yaml").write_text(written)
        assert load_yaml(tmp_path / "back.yaml") == data
    assert "robot: '1e3'" in yaml_dump({"robot": "1e3"})
    for text in texts:
        assert yaml_load(yaml_text(text)) == text, yaml_text(text)
    numbers = {"a": 1e-08, "b": 10, "c": -0.5, "d": float("inf"), "e": True, "f": None, "g": 1e20}
    assert yaml_load(yaml_dump(numbers)) == numbers
    from cso_runtime.run_profile import load_profile

    for name in ("sim", "lockstep"):  # what up hands its launcher, and a run's profile.yaml, read back as they were
        profile, given = load_profile(name, {"robot": "1e3"})
        assert yaml_load(yaml_dump(given, sort_keys=False)) == given and yaml_load(yaml_dump(profile.effective())) == profile.effective()


def test_up_resolved_prints_a_text_read_as_a_number_by_yaml_1_2_quoted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``up --resolved --robot 1e3`` printed ``robot: 1e3``: saved and given back as ``--profile``, YAML 1.2 reads a
    number there, not the robot's name. It prints ``robot: '1e3'``, and the saved file runs as the same profile."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import yaml_load

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["up", "--resolved", "--robot", "1e3", "--runs-dir", str(tmp_path / "runs")])
    assert r.exit_code == 0 and "robot: '1e3'" in r.stdout, r.output
    assert yaml_load(r.stdout)["robot"] == "1e3"
    (tmp_path / "saved.yaml").write_text(r.stdout)
    again = CliRunner().invoke(app, ["up", "--resolved", "--profile", str(tmp_path / "saved.yaml"), "--runs-dir", str(tmp_path / "runs")])
    assert again.exit_code == 0 and yaml_load(again.stdout) == yaml_load(r.stdout), again.output


def test_a_number_too_large_for_a_float_is_said_as_not_finite_not_a_traceback(tmp_path: Path):
    """A float field given an integer no float holds (``--set planner.lookahead_m=1000...0``, 400 digits, or YAML 1.2's
    ``0x`` and 300 digits) ended with Python's OverflowError, a traceback, where ``1e400`` or ``.inf`` is a
    ConfigError: "must be finite" for them all."""
    from cso_runtime.cli import parse_settings

    for text in ("1" + "0" * 400, "0x" + "F" * 300, "-1" + "0" * 400, "1e400"):
        value = parse_settings([f"lookahead_m={text}"])["lookahead_m"]
        with pytest.raises(ConfigError, match=r"planner\.lookahead_m: must be finite"):
            from_dict(ExplorationConfig, {"planner": {"lookahead_m": value}})


def test_a_set_value_or_a_yaml_text_giving_a_key_twice_is_refused(tmp_path: Path):
    """A config file giving a key twice is refused (its first value would be dropped without a word), but ``--set
    planner={lookahead_m: 1, lookahead_m: 2}`` and any other YAML text ``config.yaml_load`` reads took the last one
    in silence: the one reader refuses it everywhere (``010`` and ``10`` are one key in YAML 1.2)."""
    import yaml

    from cso_runtime.cli import parse_settings
    from cso_runtime.config import yaml_load

    with pytest.raises(ConfigError, match=re.escape("--set planner={lookahead_m: 1, lookahead_m: 2}: not valid YAML: ") + ".*found key 'lookahead_m' twice"):
        parse_settings(["planner={lookahead_m: 1, lookahead_m: 2}"])
    with pytest.raises(yaml.YAMLError, match="found key 10 twice"):
        yaml_load("010: a\n10: b\n")
    (tmp_path / "twice.yaml").write_text("seed: 010\n10: x\n10: y\n")
    with pytest.raises(ConfigError, match="found key 10 twice"):
        load_yaml(tmp_path / "twice.yaml")
    assert yaml_load("a: 1\nb: {a: 2}\n") == {"a": 1, "b": {"a": 2}}  # one key in two mappings: fine


def test_a_set_is_said_as_typed_and_its_hint_writes_the_text_typed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A message naming a ``--set`` wrote its value again from what YAML read, not as typed: ``up --set robot=on`` was
    told "--set robot=true is read as true/false ...: write --set robot='true'", another robot than the one meant
    (docs/runtime.md says to write ``--set robot='on'``); ``--set robot=010`` was "--set robot=10" and "write
    --set robot='10'" (YAML 1.2 reads 10); ``--set robot=1e3`` (1000.0) had no hint at all, ``1000.0`` being no robot
    id; ``eval --set episode.max_steps=1e3`` was "eval with --set
    episode.max_steps=1000.0"; ``up --seed 3 --set seed=0x10`` "--set seed=16"; ``train --set out_dir=on`` "write
    --set out_dir='true'"; ``--set robot=`` (null) "write --set robot='null'". Each says the ``--set`` as typed, and
    the hint quotes the text typed (none for an empty one: no robot id)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    runs = ["--runs-dir", str(tmp_path / "runs")]
    for typed in ("on", "010", "0x1F", "1e3"):
        r = CliRunner().invoke(app, ["up", "--set", f"robot={typed}", "--resolved", *runs])
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and f"--set robot={typed} is read as " in said and f"write --set robot='{typed}'" in said, said
        r = CliRunner().invoke(app, ["up", "--robot", typed, "--set", f"robot={typed}", "--resolved", *runs])  # one robot: the hint
        said = " ".join(r.output.split())
        assert r.exit_code == 2 and f"--set robot={typed} is read as " in said and f"write --set robot='{typed}', or give --robot {typed} alone" in said, said
    r = CliRunner().invoke(app, ["up", "--set", "robot=", "--resolved", *runs])  # empty: null, no hint to give robot 'null'
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "write --set" not in said and "with --set robot=: robot: expected a string, got None" in said, said
    r = CliRunner().invoke(app, ["up", "--seed", "3", "--set", "seed=0x10", "--resolved", *runs])
    assert r.exit_code == 2 and "--seed 3 and --set seed=0x10 both set seed" in " ".join(r.output.split()), r.output
    r = CliRunner().invoke(app, ["eval", "--maps", "generated:small:1:0", "--out", str(tmp_path / "o"), "--set", "episode.max_steps=1e3", "--dry-run"])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "eval with --set episode.max_steps=1e3: episode.max_steps: expected an integer, got 1000.0" in said, said
    r = CliRunner().invoke(app, ["train", "--set", "out_dir=on", "--total-decisions", "1"])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "--set out_dir=on is read as true/false, and out_dir is text: write --set out_dir='on'" in said, said
    assert not (tmp_path / "on").exists() and not (tmp_path / "runs").exists()


def test_what_cso_runtime_writes_in_yaml_keeps_non_ascii_text_as_written(tmp_path: Path):
    """``up --resolved``, a run's ``profile.yaml``, the launcher's profile and a map's YAML wrote each non-ASCII text
    escaped, ``scene: "/maps/caf\\xE9.yaml"``, a file the user reads and edits (``set_flag_text`` already says such
    text as typed). It is written as it is, UTF-8, and read back the same: by ``yaml_load`` from text or from bytes
    (the launcher's stdin, whatever the locale), by ``load_yaml`` and by ``load_map``."""
    import io
    import os
    import subprocess
    import sys

    import numpy as np

    from cso_runtime.config import commented_yaml, yaml_dump, yaml_load
    from cso_runtime.geometry import GridGeometry
    from cso_runtime.map_files import load_map, save_map

    data = {"scene": "/maps/café/küche.yaml", "notes": ["m²", "ok"]}
    for written in (yaml_dump(data, sort_keys=False), commented_yaml(["profile"], data)):
        assert "scene: /maps/café/küche.yaml\n" in written and "- m²\n" in written and "\\x" not in written, written
        assert yaml_load(written) == data and yaml_load(io.BytesIO(written.encode())) == data
        (tmp_path / "back.yaml").write_text(written, encoding="utf-8")
        assert load_yaml(tmp_path / "back.yaml") == data
    grid = np.zeros((2, 3), dtype=np.int8)
    saved = save_map(tmp_path / "küche.yaml", grid, GridGeometry(0.05, (2, 3)))
    assert saved.read_text(encoding="utf-8").startswith("image: küche.pgm\n")
    assert load_map(saved)[0].shape == (2, 3)
    from cso_runtime.run_profile import load_profile

    _, given = load_profile("lockstep", {})  # the profile up hands its launcher on stdin, UTF-8, read whatever the locale
    given["services"]["planner"]["küche"] = 1  # refused by the launcher (an unknown key): read, not run
    run_dir = tmp_path / "runs" / "r"
    (run_dir / "logs").mkdir(parents=True)
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0"}
    r = subprocess.run(
        [sys.executable, "-m", "cso_runtime.launcher", "--profile-data", "-", "--run-dir", str(run_dir)],
        input=yaml_dump(given, sort_keys=False).encode(), env=env, cwd=tmp_path, capture_output=True, timeout=120,
    )
    said = (r.stdout + r.stderr).decode(errors="replace")
    assert r.returncode != 0 and "the profile from up.services.planner: unknown key(s) k\\xfcche" in said and "UnicodeDecodeError" not in said, said[-3000:]
    assert not (run_dir / "run.json").exists()


def test_a_number_written_with_underscores_is_refused_saying_how_to_write_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """cso-runtime's own messages write large numbers with underscores ("more than max_grid_cells (4_000_000): raise
    max_grid_cells (at most 50_000_000)"), which YAML 1.1 read back as numbers; YAML 1.2 (fef7c32) reads
    ``6_000_000`` as text, so the value typed back from the message was refused as "expected an integer, got
    '6_000_000'" with no word of why. The refusal says how to write it (without the underscores)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    for value, field, said in [
        ("6_000_000", "episode.max_steps", "episode.max_steps: expected an integer, got '6_000_000' (YAML 1.2 reads a number with _ as text: write 6000000)"),
        ("1_000.5", "planner.lookahead_m", "planner.lookahead_m: expected a number, got '1_000.5' (YAML 1.2 reads a number with _ as text: write 1000.5)"),
    ]:
        section, key = field.split(".")
        with pytest.raises(ConfigError, match=re.escape(said)):
            from_dict(ExplorationConfig, {section: {key: value}})
    with pytest.raises(ConfigError, match=r"expected an integer, got 'a_b'$"):
        from_dict(ExplorationConfig, {"episode": {"max_steps": "a_b"}})  # no number: no such hint
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["up", "--set", "max_grid_cells=6_000_000", "--resolved", "--runs-dir", str(tmp_path / "runs")])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "max_grid_cells: expected an integer, got '6_000_000' (YAML 1.2 reads a number with _ as text: write 6000000)" in said, said


@pytest.mark.parametrize(
    ("text", "read"),
    [("1e5", 1e5), ("5e-2", 0.05), ("-.5", -0.5), ("+.5", 0.5), ("0o10", 8.0), ("0x10", None), ("010", None), ("1_000", None), ("1:30", None), (".nan", None), ("on", None)],
)
def test_a_number_field_given_as_text_is_read_as_the_yaml_reader_reads_that_text(text: str, read: float | None):
    """``yaml12_number`` (a text that came by another way than ``yaml_load``: a dict of the Python API) kept a pattern
    of its own of the texts YAML 1.2 reads as numbers and YAML 1.1 as text, beside ``YamlLoader``'s: ``0o10`` was 8
    in a file and refused given as text. It asks the loader now: a text YAML 1.1 left as text is the number the file
    reads; a text YAML 1.1 read as a number too (``010``, quoted in a file) stays a text, refused as before."""
    from cso_runtime.config import field_value, finite_number

    if read is None:
        assert finite_number(text) is None
        with pytest.raises(ConfigError, match="lookahead_m"):
            field_value(text, float, "lookahead_m")
    else:
        assert finite_number(text) == read == field_value(text, float, "lookahead_m")


@pytest.mark.parametrize(
    ("service", "params", "said"),
    [
        ("planner", {"stale_after_s": 0}, "services.planner: stale_after_s must be in (0, 86,400] s (a day: config.MAX_WAIT_S), got 0"),
        ("planner", {"path_period_s": -1}, "services.planner: path_period_s must be in [0, 86,400] s (a day: config.MAX_WAIT_S), got -1"),
        ("planner", {"restore_timeout_s": -1}, "services.planner: restore_timeout_s must be in [0, 86,400] s (a day: config.MAX_WAIT_S), got -1"),
        ("mapper", {"max_pending_scans": 0}, "services.mapper: max_pending_scans must be in [1, 10,000] (MAX_PENDING_SCANS), got 0"),
        ("mapper", {"restore_timeout_s": -1}, "services.mapper: restore_timeout_s must be in [0, 86,400] s (a day: config.MAX_WAIT_S), got -1"),
        ("frontier", {"goal_wait_s": 0}, "services.frontier: goal_wait_s must be in (0, 86,400] s"),
        ("frontier", {"helper_max_restarts": -1}, "services.frontier: helper_max_restarts must be in [0, "),
        ("sim", {"cmd_timeout_s": 0}, "services.sim: cmd_timeout_s must be in (0, "),
        ("sim", {"status_period_s": -1}, "services.sim: status_period_s must be in [0, 86,400] s"),
        ("policy", {"forget_robot_after_s": 0}, "services.policy: forget_robot_after_s must be in (0, 86,400] s"),
        ("policy", {"frontier_restart_grace_s": -1}, "services.policy: frontier_restart_grace_s must be in [0, 86,400] s"),
        ("foxglove_bridge", {"map_period_s": -1}, "services.foxglove_bridge: map_period_s must be in [0, 86,400] s"),
        ("ros2_bridge", {"log_period_s": 0}, "services.ros2_bridge: log_period_s must be in (0, 86,400] s"),
        ("ros2_bridge", {"ended_why_wait_s": -1}, "services.ros2_bridge: ended_why_wait_s must be in [0, 86,400] s"),
    ],
)
def test_a_service_time_out_of_its_range_is_said_by_its_bound_alone(service: str, params: dict, said: str):
    """Each service's times were checked twice: a hand check first (``stale_after_s must be positive``,
    ``restore_timeout_s must be >= 0 seconds``, ``map_period_s must be >= 0``: no value said), then their
    ``config.Bound`` table, which documents them. One check now, in the words every bounded key is said in (key,
    range, why, value)."""
    from services import params_class

    with pytest.raises(ConfigError) as refused:
        from_dict(params_class(service), params, f"services.{service}")
    assert str(refused.value).startswith(said) and str(refused.value).endswith(f"got {next(iter(params.values()))}")
