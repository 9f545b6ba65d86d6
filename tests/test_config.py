"""Typed configs: YAML files fill the dataclasses; bad keys and values are clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest

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
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml(bad)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_yaml(listy)


def test_train_set_overrides_parse_yaml_values_and_reject_bad_pairs():
    from cso_runtime.cli import parse_settings  # noqa: PLC0415

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
    for bad in ("1e", "e5", "2.0m", "nan"):
        with pytest.raises(ConfigError, match="expected a number"):
            from_dict(ExplorationConfig, {"masks": {"beta_far_m": bad}})
