"""benchmarks/soak_runtime.py --minutes: the slopes that tell a leak from a process that levels off."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


def load_soak():
    spec = importlib.util.spec_from_file_location("soak_runtime", Path(__file__).parents[1] / "benchmarks" / "soak_runtime.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_steady_leak_keeps_its_slope_and_a_warm_up_that_levels_off_has_none_in_the_last_half():
    soak = load_soak()
    # 10 minutes sampled every 6 s: one process leaks 2 MB a minute; the other grows in its first 3 minutes, then stays.
    samples = [{"t_s": t, "leak_rss_mb": 100 + 2 * t / 60, "warm_rss_mb": 100 + min(t, 180) / 10, "status_state": "exploring"} for t in range(0, 601, 6)]
    columns = soak.trends(samples, [], warmup_min=1.0)["columns"]
    assert columns["leak_rss_mb"]["per_min"] == pytest.approx(2.0)
    assert columns["leak_rss_mb"]["per_min_last_half"] == pytest.approx(2.0)
    assert columns["warm_rss_mb"]["per_min"] > 0
    assert columns["warm_rss_mb"]["per_min_last_half"] == pytest.approx(0.0)
    assert columns["warm_rss_mb"]["first"] == 106.0 and columns["warm_rss_mb"]["last"] == 118.0  # from the end of the warm-up
    assert "status_state" not in columns  # text is kept in the CSV, not fitted


def test_episodes_pace_is_summed_up_by_medians_and_a_slope_per_episode():
    soak = load_soak()
    episodes = [{"episode": n, "steps": 36, "coverage_pct": 99.66, "real_time_factor": 20.0 - n} for n in range(1, 10)]
    summary = soak.trends([], episodes, warmup_min=0.0)
    assert summary["episodes"] == 9 and summary["steps"] == [36]
    assert summary["real_time_factor"] == {"first_third_median": 18.0, "last_third_median": 12.0, "per_episode": pytest.approx(-1.0)}


@pytest.mark.parametrize("restarts", [11, 1001, 100_000])
def test_the_soaks_restarts_are_a_value_up_takes(restarts):
    """The soak's ``up --set supervision.max_restarts=100000`` (``--minutes``), or ``--episodes`` + 1 over 1,000, was
    refused since supervision.max_restarts is bounded by config.MAX_RESTARTS: ``up`` exited 2 and the soak with
    "up failed". Every ``--set`` of the script is one ``up`` takes."""
    from cso_runtime.cli import parse_settings
    from cso_runtime.config import MAX_RESTARTS
    from cso_runtime.run_profile import load_profile

    soak = load_soak()
    words = soak.restarts_setting(restarts)
    assert words[0] == "--set"
    profile, _ = load_profile("lockstep", {}, settings=parse_settings(words[1:]))
    assert profile.supervision.max_restarts == min(restarts, MAX_RESTARTS)
    source = (Path(__file__).parents[1] / "benchmarks" / "soak_runtime.py").read_text()
    assert "supervision.max_restarts=" not in source.replace('f"supervision.max_restarts={min(restarts, MAX_RESTARTS)}"', ""), "every --set of it through restarts_setting"
