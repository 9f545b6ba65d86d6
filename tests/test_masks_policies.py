"""Action masks (Eq. 5, Algorithm 1) and the baseline goal selectors."""

from __future__ import annotations

import numpy as np
import pytest

from cso_runtime.config import MaskConfig
from cso_runtime.frontiers import FrontierCluster
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.masks import StuckMask, valid_distance_mask
from cso_runtime.observation import Observation, distance_maps_from, distance_source_key
from cso_runtime.policies import ActionMasker, GoalSelector, make_policy

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

    def distance_from(src):
        return np.hypot(goals[:, 0] - src[0], goals[:, 1] - src[1])

    allowed = s.mask(3, distance_from)
    # goal 0 is 0.2 m from w_{t-1}: masked; goal 1 is 0.8 m from w_t: masked; goal 2 far: kept.
    assert allowed.tolist() == [False, False, True]


def test_not_stuck_when_moving_or_exploring():
    moving = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((3.0, 1.0), 50.1, 2.0), ((3.1, 1.0), 50.2, 0.1)])
    assert not moving.is_stuck()
    exploring = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((1.1, 1.0), 55.0, 0.1), ((1.2, 1.0), 55.2, 0.1)])
    assert not exploring.is_stuck()
    short = _stuck_with([((1.0, 1.0), 50.0, np.inf), ((1.1, 1.0), 50.0, 0.1)])
    assert not short.is_stuck()
    calls = []
    assert short.mask(2, lambda src: calls.append(src) or np.zeros(2)).all() and calls == []


@pytest.mark.parametrize(
    "history, area_now, moved_now, expect",
    [
        # Moved little and explored little so far: the prediction names w_{t-2}, w_{t-1} and w_t.
        ([((1.0, 1.0), 50.0, np.inf), ((1.3, 1.0), 50.4, 0.3)], 50.9, 0.4, "stuck"),
        # Same history, but the move to w_t (unknown before the decision) was long: predicted, not stuck.
        ([((1.0, 1.0), 50.0, np.inf), ((1.3, 1.0), 50.4, 0.3)], 50.9, 1.5, "predicted only"),
        # The history alone rules it out: no prediction, and no stuck mask.
        ([((1.0, 1.0), 50.0, np.inf), ((3.0, 1.0), 50.1, 2.0)], 50.2, 0.1, "none"),
        ([((1.0, 1.0), 50.0, np.inf), ((1.1, 1.0), 50.2, 0.1)], 52.0, 0.1, "none"),
        ([((1.0, 1.0), 50.0, np.inf)], 50.0, 0.1, "none"),
    ],
)
def test_stuck_sources_predicted_before_the_decision_cover_what_the_mask_asks_for(history, area_now, moved_now, expect):
    """``sources_if_stuck`` (known before the decision's Observation) names every source ``mask`` then
    measures from; it may name sources for a decision that is not stuck, never miss one."""
    s = _stuck_with(history)
    now = (1.3, 1.4)
    predicted = s.sources_if_stuck(now, area_now)
    s.record(now, area_now, moved_now)
    asked = []
    s.mask(2, lambda src: asked.append(src) or np.full(2, 5.0))
    assert set(asked) <= set(predicted)
    if expect == "stuck":
        assert asked == predicted == [history[0][0], history[1][0], now]
    elif expect == "predicted only":
        assert asked == [] and len(predicted) == 3
    else:
        assert asked == predicted == []
    off = ActionMasker(MaskConfig(use_stuck=False))
    off.stuck = _stuck_with(history)
    assert off.distance_sources(now, area_now) == []


def test_distance_maps_computed_ahead_are_adopted_only_on_the_same_grid():
    g = GridGeometry(0.1, (40, 60))
    traversable = np.zeros(g.shape, dtype=bool)
    traversable[5:35, 5:55] = True
    traversable[5:30, 30] = False  # a wall with a gap at the bottom
    obs = Observation(g, Pose2D(1.0, 1.0, 0.0), traversable, ~traversable, traversable, np.zeros(g.shape), traversable, np.zeros(g.shape), [], 10.0)
    source = (1.00001, 2.00004)  # rounds to the same key as (1.0, 2.0)
    ahead = distance_maps_from(traversable, g, [source, (1.0, 2.0)])
    assert list(ahead) == [distance_source_key(source)] == [(1.0, 2.0)]
    fresh = Observation(g, obs.pose, traversable, ~traversable, traversable.copy(), obs.distance_m, traversable, obs.entropy, [], 10.0)
    np.testing.assert_array_equal(ahead[(1.0, 2.0)], fresh.distance_map_from(source))  # same as computed on demand
    assert np.isfinite(ahead[(1.0, 2.0)][20, 40]) and ahead[(1.0, 2.0)][20, 40] > 2.0  # around the wall, not through it
    assert obs.adopt_distance_maps(g, traversable.copy(), ahead)
    assert obs.distance_map_from(source) is ahead[(1.0, 2.0)]
    other = traversable.copy()
    other[30:, 30] = False  # the gap closed: another grid, not adopted
    late = Observation(g, obs.pose, traversable, ~traversable, traversable, obs.distance_m, traversable, obs.entropy, [], 10.0)
    assert not late.adopt_distance_maps(g, other, distance_maps_from(other, g, [source]))
    assert not late.adopt_distance_maps(GridGeometry(0.1, (40, 60), 1.0, 0.0), traversable, ahead)  # another origin
    np.testing.assert_array_equal(late.distance_map_from(source), ahead[(1.0, 2.0)])


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
    obs = make_obs([1.0, 2.0, 3.0, 4.0], [1, 1, 1, 1], [1, 1, 1, 1])
    a = [make_policy("random", seed=3).select(obs).cluster_index for _ in range(3)]
    assert len(set(a)) == 1


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


def test_action_masker_applies_valid_distance_mask():
    masker = ActionMasker(MaskConfig())
    allowed = masker.mask(make_obs([0.1, 1.5, 5.0], [1, 1, 1], [1, 1, 1]))
    assert allowed.tolist() == [False, True, False] and masker.last_rule == "range"
    off = ActionMasker(MaskConfig(use_valid_distance=False, use_stuck=False))
    assert off.mask(make_obs([0.1, 1.5, 5.0], [1, 1, 1], [1, 1, 1])).all()
