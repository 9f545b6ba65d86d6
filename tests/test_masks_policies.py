"""Action masks (Eq. 5, Algorithm 1) and the baseline goal selectors."""

from __future__ import annotations

import numpy as np
import pytest

from cso_runtime.config import ConfigError, FrontierConfig, MaskConfig, RobotConfig
from cso_runtime.frontiers import FrontierCluster
from cso_runtime.geodesic import geodesic_distance
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.masks import StuckMask, valid_distance_mask
from cso_runtime.observation import Observation, ObservationBuilder, distance_source_key
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.policies import (
    BASELINES,
    LEARNED_METHODS,
    ActionMasker,
    GoalSelector,
    available_methods,
    make_policy,
    parse_methods,
    unknown_methods_said,
)
from tests.conftest import walled_grid

INF = np.inf


def test_valid_distance_mask_range():
    mask, rule = valid_distance_mask(np.array([0.1, 0.5, 1.9, 2.5, INF]), 0.2, 2.0)
    assert rule == "range" and mask.tolist() == [False, True, True, False, False]


def test_valid_distance_mask_first_fallback_drops_near_bound():
    mask, rule = valid_distance_mask(np.array([0.1, 0.15, 2.5, INF]), 0.2, 2.0)
    assert rule == "no_near" and mask.tolist() == [True, True, False, False]


def test_valid_distance_mask_second_fallback_allows_all_reachable():
    mask, rule = valid_distance_mask(np.array([3.0, 7.5, INF]), 0.2, 2.0)
    assert rule == "all" and mask.tolist() == [True, True, False]


def test_valid_distance_mask_nothing_reachable():
    mask, rule = valid_distance_mask(np.array([INF, INF]), 0.2, 2.0)
    assert rule == "all" and not mask.any()


def _stuck_with(history):
    s = StuckMask(MaskConfig())
    for pos, area, moved in history:
        s.record(pos, area, moved)
    return s


def test_stuck_mask_scripted_history():
    # Three decisions within 0.5 m of each other and < 1 m2 of new area: stuck.
    s = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((1.3, 1.0), 50.4, 0.3), ((1.3, 1.4), 50.9, 0.4)])
    assert s.is_stuck()
    goals = np.array([[1.5, 1.0], [1.3, 2.2], [5.0, 5.0]])

    asked = []

    def distance_from(src, within_m):
        asked.append(within_m)
        return np.hypot(goals[:, 0] - src[0], goals[:, 1] - src[1])

    allowed = s.mask(3, distance_from)
    assert asked == [MaskConfig().alpha3_m] * 3  # only distances below alpha_3 are asked for
    # goal 0 is 0.2 m from w_{t-1}: masked; goal 1 is 0.8 m from w_t: masked; goal 2 far: kept.
    assert allowed.tolist() == [False, False, True]


def test_stuck_mask_keeps_new_goals_from_past_goals_when_asked():
    """``stuck_avoid: goals`` (Algorithm 1's "past 3 selected exploration goals"): a robot pinned at one
    place that kept choosing goal G is stuck, and G is masked while a candidate near the robot stays;
    ``positions`` (the default) masks near the robot instead."""
    candidates = np.array([[1.5, 0.0], [0.5, 0.0], [3.0, 0.0]])  # G, near the robot, far

    def distance_from(src, within_m):
        return np.hypot(candidates[:, 0] - src[0], candidates[:, 1] - src[1])

    allowed = {}
    for avoid in ("positions", "goals"):
        s = StuckMask(MaskConfig(stuck_avoid=avoid))
        for k in range(3):
            s.record((0.0, 0.0), 10.0 + 0.1 * k, 0.0 if k else np.inf)
            s.record_goal((1.5, 0.0))
        assert s.is_stuck()
        allowed[avoid] = s.mask(3, distance_from).tolist()
    assert allowed == {"goals": [False, True, True], "positions": [True, False, True]}
    s.reset()
    assert not s.history and not s.goals


def test_stuck_avoid_is_validated():
    with pytest.raises(ConfigError, match="stuck_avoid"):
        MaskConfig(stuck_avoid="goal").validate()


def test_a_robot_pinned_in_the_inflation_band_counts_as_stuck():
    """Algorithm 1's moving length is read on D, which is inf where the robot stood inside a wall's
    inflation band; the straight-line distance stands in there, so a robot pinned by a wall that makes
    three decisions 0.15 m apart and maps nothing new is stuck (it never was before)."""
    g = GridGeometry(0.05, (100, 100))
    explored = np.zeros(g.shape, bool)
    explored[10:90, 10:90] = True
    occupied = np.zeros(g.shape, bool)
    occupied[10:90, 50] = True  # a wall at x = 2.50-2.55 m
    occupancy = OccupancyMap.from_masks(explored, occupied, g)
    builder = ObservationBuilder(FrontierConfig(), RobotConfig())
    masker = ActionMasker(MaskConfig())
    for y_m in (2.00, 2.15, 2.30):
        obs = builder.build(occupancy, Pose2D(2.37, y_m, 0.0))  # 0.13 m from the wall, inside the 0.2 m inflation
        masker.mask(obs)
    moved = [record.moved_m for record in masker.stuck.history]
    assert np.isinf(moved[0]) and moved[1:] == pytest.approx([0.15, 0.15])
    assert masker.stuck.is_stuck()


def test_not_stuck_when_moving_or_exploring():
    moving = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((3.0, 1.0), 50.1, 2.0), ((3.1, 1.0), 50.2, 0.1)])
    assert not moving.is_stuck()
    exploring = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((1.1, 1.0), 55.0, 0.1), ((1.2, 1.0), 55.2, 0.1)])
    assert not exploring.is_stuck()
    short = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((1.1, 1.0), 50.0, 0.1)])
    assert not short.is_stuck()
    calls = []
    assert short.mask(2, lambda src, within_m: calls.append(src) or np.zeros(2)).all() and calls == []


@pytest.mark.parametrize("resolution_m", [0.05, 0.1])
def test_bounded_distance_map_is_exact_below_its_bound(resolution_m):
    """``geodesic_distance(..., within_m)`` (the stuck mask's cheap pass on a window around the source)
    gives exactly the full map's value wherever that is below the bound, so the mask is the same."""
    rng = np.random.default_rng(7)
    g = GridGeometry(resolution_m, (120, 160))
    checked = 0
    for _ in range(12):
        traversable = walled_grid(rng)
        ys, xs = np.nonzero(traversable)
        i = rng.integers(ys.size)
        x, y = g.cell_to_world(ys[i], xs[i])
        source = np.array([x + rng.uniform(-0.4, 0.4) * resolution_m, y + rng.uniform(-0.4, 0.4) * resolution_m])
        full = geodesic_distance(traversable, g, source)
        for within_m in (0.3, 1.0, 2.5):
            bounded = geodesic_distance(traversable, g, source, within_m=within_m)
            near = full < within_m
            np.testing.assert_array_equal(bounded < within_m, near)
            np.testing.assert_array_equal(bounded[near], full[near])
            checked += int(near.sum())
    assert checked > 1000


def test_observation_caches_distance_maps_per_source_and_bound():
    g = GridGeometry(0.1, (40, 60))
    traversable = np.zeros(g.shape, dtype=bool)
    traversable[5:35, 5:55] = True
    traversable[5:30, 30] = False  # a wall with a gap at the bottom
    obs = Observation(g, Pose2D(1.0, 1.0, 0.0), traversable, ~traversable, traversable, np.zeros(g.shape), traversable, np.zeros(g.shape), [], 10.0)
    source = (1.00001, 2.00004)  # rounds to the same key as (1.0, 2.0)
    assert distance_source_key(source) == (1.0, 2.0)
    full = obs.distance_map_from(source)
    assert full is obs.distance_map_from((1.0, 2.0))  # cached under the rounded key
    np.testing.assert_array_equal(full, geodesic_distance(traversable, g, np.array([1.0, 2.0])))
    assert np.isfinite(full[20, 40]) and full[20, 40] > 2.0  # around the wall, not through it
    bounded = obs.distance_map_from(source, within_m=1.0)
    assert bounded is not full and np.isinf(bounded[20, 40])  # farther than the bound: not computed
    near = full < 1.0
    np.testing.assert_array_equal(bounded[near], full[near])


def make_obs(distances, entropies, sizes, pose=Pose2D(0.0, 0.0, 0.0)) -> Observation:
    g = GridGeometry(0.1, (100, 100))
    clusters = [
        FrontierCluster(i, np.array([[i, i]]), (i, i), (float(d) if np.isfinite(d) else 9.0, 0.0), float(d), float(s), float(e), (0.0, 0.0))
        for i, (d, e, s) in enumerate(zip(distances, entropies, sizes))
    ]
    z = np.zeros(g.shape, dtype=bool)
    return Observation(g, pose, z, z, z, np.full(g.shape, np.inf), z, np.zeros(g.shape), clusters, 10.0)


def test_baselines_pick_by_their_rule():
    obs = make_obs([1.0, 4.0, 2.0, INF], [5, 30, 10, 99], [0.5, 0.4, 3.0, 9.0])
    assert make_policy("greedy-dist").select(obs).cluster_index == 0
    assert make_policy("greedy-info").select(obs).cluster_index == 1  # the unreachable 99 is ignored
    # utility cost 3*d - size: [2.5, 11.6, 3.0] -> cluster 0
    assert make_policy("utility").select(obs).cluster_index == 0
    picks = {make_policy("random", seed=s).select(obs).cluster_index for s in range(20)}
    assert picks == {0, 1, 2}


def test_random_policy_is_seeded():
    """The same seed, the same sequence of picks (from make_policy and again after ``reset(seed)``); another seed,
    another sequence; and the picks vary, so the sequence is the seeded generator's, not a constant."""
    obs = make_obs([1.0, 2.0, 3.0, 4.0], [1, 1, 1, 1], [1, 1, 1, 1])

    def picks(policy) -> list[int]:
        return [policy.select(obs).cluster_index for _ in range(30)]

    seeded = make_policy("random", seed=3)
    first = picks(seeded)
    assert first == picks(make_policy("random", seed=3)) and len(set(first)) == 4
    assert picks(make_policy("random", seed=4)) != first
    seeded.reset(3)
    assert picks(seeded) == first


def test_policies_return_none_without_reachable_frontier():
    obs = make_obs([INF], [1], [1])
    for name in ("greedy-dist", "greedy-info", "utility", "random"):
        policy = make_policy(name)
        assert isinstance(policy, GoalSelector)
        assert policy.select(obs) is None
        assert policy.select(make_obs([], [], [])) is None


def test_unknown_method_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown method"):
        make_policy("greedy-best")


def test_an_unknown_method_is_said_with_the_name_it_most_likely_misspells():
    """A typo in --method (eval, up, the policy service) names the method meant, as config keys do."""
    with pytest.raises(ValueError, match=r"unknown method 'greedy-dsit' \(did you mean greedy-dist\?\); available: greedy-dist,"):
        make_policy("greedy-dsit")
    said = unknown_methods_said(["cs0", "xyzzy"], groups=True)
    assert said.startswith("unknown methods 'cs0' (did you mean cso?), 'xyzzy'; available: ")
    assert said.endswith("gnn-baseline, all, baselines, learned, or a method of your own as module.path:Attribute")


def test_method_lists_expand_groups_in_order_each_method_once(monkeypatch, tmp_path):
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)  # the shipped weights, whatever folder or file the developer's environment gives
    assert parse_methods(" greedy-dist , cso ,,greedy-dist") == ["greedy-dist", "cso"]
    assert parse_methods("baselines") == list(BASELINES)
    assert parse_methods("cso,all") == ["cso", *[m for m in available_methods() if m != "cso"]]
    assert set(LEARNED_METHODS) <= set(parse_methods("all")), "every learned method ships weights"
    assert parse_methods("learned") == list(LEARNED_METHODS)
    assert parse_methods("greedy-dist,nope") == ["greedy-dist", "nope"], "the caller names unknown methods"
    # `all` and `learned` mean the learned methods whose weights are found (a `--weights` folder)
    (tmp_path / "cso.pt").write_bytes(b"")
    monkeypatch.setenv("CSO_WEIGHTS_DIR", str(tmp_path))
    assert parse_methods("learned") == ["cso"]
    assert parse_methods("all") == [*BASELINES, "cso"]


def test_the_help_names_every_method():
    from cso_runtime.cli import METHODS_HELP

    named = {w.strip(",;") for w in METHODS_HELP.split()}
    assert {*BASELINES, *LEARNED_METHODS} <= named


def test_action_masker_applies_valid_distance_mask():
    masker = ActionMasker(MaskConfig())
    allowed = masker.mask(make_obs([0.1, 1.5, 5.0], [1, 1, 1], [1, 1, 1]))
    assert allowed.tolist() == [False, True, False] and masker.last_rule == "range"
    off = ActionMasker(MaskConfig(use_valid_distance=False, use_stuck=False))
    assert off.mask(make_obs([0.1, 1.5, 5.0], [1, 1, 1], [1, 1, 1])).all()


@pytest.mark.parametrize(
    ("conflict", "stuck_allows", "expected", "rule"),
    [
        ("distance", [False, False, True], [True, True, False], "range"),  # the stuck mask is dropped
        ("stuck", [False, False, True], [False, False, True], "all"),  # Eq. 5's fallbacks over what it leaves
        ("stuck", [True, False, True], [True, False, False], "range"),  # no conflict: both masks apply
        ("stuck", [False, False, False], [True, True, False], "range"),  # it leaves nothing: dropped
    ],
)
def test_which_mask_wins_when_the_stuck_mask_leaves_none_of_eq5s_goals(conflict, stuck_allows, expected, rule):
    """The robot is stuck and every goal Eq. 5 keeps is one Algorithm 1 forbids: ``masks.conflict`` says
    which mask gives way (the paper does not say); a masker whose masks agree never reaches this choice."""
    masker = ActionMasker(MaskConfig(conflict=conflict))
    masker.stuck.mask = lambda n, distance_from: np.array(stuck_allows)  # stuck, with these goals allowed
    allowed = masker.mask(make_obs([0.5, 0.8, 3.0], [1, 1, 1], [1, 1, 1]))
    assert allowed.tolist() == expected and masker.last_rule == rule
    with pytest.raises(ConfigError, match="masks.conflict must be one of distance, stuck"):
        MaskConfig(conflict="both").validate()
