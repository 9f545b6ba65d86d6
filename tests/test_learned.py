"""The learned CSO policy: masks inside the policy, equivariance, the env API, PPO, checkpoints."""

from __future__ import annotations

import contextlib
import copy
import csv
import dataclasses
import importlib.util
import json
import math
import os
import pickle
import re
import shlex
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_reset_options, check_reset_return_type, check_reset_seed_determinism
from gymnasium.utils.passive_env_checker import env_reset_passive_checker, env_step_passive_checker

from cso_runtime.cli import TRAIN_STOP_DEADLINE_S
from cso_runtime.config import MaskConfig, SensorConfig
from cso_runtime.episode import Explorer, rollout_choice
from cso_runtime.geometry import Pose2D
from cso_runtime.learned.env import ENV_ID, EnvConfig, ExplorationEnv, expert_action
from cso_runtime.learned.graph import GraphConfig, build_graph, node_features
from cso_runtime.learned.network import GRAPH_KEYS, GraphActorCritic, NetworkConfig, to_torch, trace_decision
from cso_runtime.learned.ppo import (
    Args,
    build_model,
    check_training_inputs,
    compute_gae,
    episode_returns,
    model_chooser,
    parameter_groups,
    random_chooser,
    train,
)
from cso_runtime.learned.registry import LearnedPolicy, has_method, load_checkpoint, save_checkpoint
from cso_runtime.learned.vector_env import EnvWorkerDied, WatchedAsyncVectorEnv
from cso_runtime.learned.weights import weights_path
from cso_runtime.masks import valid_distance_mask
from cso_runtime.policies import Goal, goal_of, make_policy
from cso_runtime.scenes import FloorPlan
from cso_runtime.simulator import KinematicSimulator
from tests.conftest import TerminalFile, unset_weights_env


def rooms_plan(n_rooms: int = 2, res: float = 0.1, start: Pose2D | None = None) -> FloorPlan:
    """``n_rooms`` rooms of 3 x 3 m in a row, joined by 0.8 m doors."""
    room = int(round(3.0 / res))
    ny, nx = room + 4, n_rooms * room + 4
    free = np.zeros((ny, nx), dtype=bool)
    free[2:-2, 2:-2] = True
    door = slice(int(1.1 / res) + 2, int(1.9 / res) + 2)
    for k in range(1, n_rooms):
        wall = 2 + k * room
        free[:, wall - 1 : wall + 1] = False
        free[door, wall - 1 : wall + 1] = True
    return FloorPlan(f"rooms{n_rooms}", free, res, start or Pose2D(1.0, 1.7, 0.0))


@pytest.fixture(scope="module")
def observation():
    """A decision a few goals into an episode on two rooms: several clusters at various distances."""
    explorer = Explorer(KinematicSimulator(rooms_plan(2)))
    obs = explorer.observe()
    for _ in range(3):
        explorer.apply_goal(obs, make_policy("greedy-dist").select(obs))
        while explorer.decision_reason() is None and not explorer.done:
            explorer.advance()
        explorer.handle_reason(explorer.decision_reason() or "no_goal")
        obs = explorer.observe()
    assert len(obs.clusters) >= 2
    return obs


def untrained_policy(mask_config: MaskConfig, seed: int = 0) -> LearnedPolicy:
    torch.manual_seed(seed)
    return LearnedPolicy("cso", GraphActorCritic(), GraphConfig(), mask_config)


@pytest.mark.parametrize(
    ("near_m", "far_m", "rule"),
    [(0.2, 2.0, None), (0.0, 100.0, "range"), (100.0, 200.0, "no_near"), (0.0, 1e-3, "all")],
)
def test_valid_distance_mask_zeroes_exactly_the_masked_actions(observation, near_m, far_m, rule):
    cfg = MaskConfig(beta_near_m=near_m, beta_far_m=far_m, use_stuck=False)
    policy = untrained_policy(cfg)
    mask = policy.action_mask(observation)
    expected, applied = valid_distance_mask(observation.goal_distance_m, near_m, far_m)
    if rule is not None:
        assert applied == rule
    n = len(observation.clusters)
    np.testing.assert_array_equal(mask[:n], expected)
    assert not mask[n:].any()
    probs = policy.probabilities(observation, mask)
    assert np.all(probs[~mask] == 0.0)
    assert np.all(probs[mask] > 0.0)
    assert probs.sum() == pytest.approx(1.0, abs=1e-5)
    goal = policy.select(observation)
    assert goal is not None and mask[goal.cluster_index]


def test_stuck_mask_with_goals_zeroes_the_goals_chosen_before(observation):
    """``stuck_avoid: goals``: the learned policy records each goal it chooses, and once stuck it never
    chooses again within alpha_3 of the three it chose."""
    cfg = MaskConfig(use_valid_distance=False, alpha3_m=1.0, stuck_avoid="goals")
    policy = untrained_policy(cfg)
    chosen = [policy.select(observation) for _ in range(2)]
    assert [(g.x_m, g.y_m) for g in chosen] == list(policy.masker.stuck.goals)
    mask = policy.action_mask(observation)
    assert policy.masker.stuck.is_stuck()
    n = len(observation.clusters)
    near = np.zeros(n, dtype=bool)
    for g in chosen:
        near |= observation.goal_distances_from((g.x_m, g.y_m)) < cfg.alpha3_m
    assert near[[g.cluster_index for g in chosen]].all() and (~near).any()
    np.testing.assert_array_equal(mask[:n], ~near)


def test_stuck_mask_zeroes_goals_near_recent_positions(observation):
    cfg = MaskConfig(use_valid_distance=False, alpha3_m=1.5)
    policy = untrained_policy(cfg)
    for _ in range(2):  # same place, no new area: the third decision is stuck
        policy.select(observation)
    mask = policy.action_mask(observation)
    assert policy.masker.stuck.is_stuck()
    near = observation.goal_distances_from((observation.pose.x_m, observation.pose.y_m)) < cfg.alpha3_m
    n = len(observation.clusters)
    if (~near).any():
        np.testing.assert_array_equal(mask[:n], ~near)
    else:  # every goal near: the stuck mask steps aside rather than mask everything
        np.testing.assert_array_equal(mask[:n], np.ones(n, dtype=bool))
    probs = policy.probabilities(observation, mask)
    assert np.all(probs[~mask] == 0.0) and np.all(probs[mask] > 0.0)


def test_masks_switched_off_allow_every_reachable_cluster(observation):
    policy = untrained_policy(MaskConfig(use_valid_distance=False, use_stuck=False))
    mask = policy.action_mask(observation)
    n = len(observation.clusters)
    np.testing.assert_array_equal(mask[:n], np.isfinite(observation.goal_distance_m))


def _random_graph(rng: np.random.Generator, n_frontier: int, n_path: int, config: GraphConfig) -> dict[str, np.ndarray]:
    n, k = n_frontier + n_path, config.neighbours
    g = {
        "nodes": np.zeros((config.max_nodes, 6), np.float32),
        "node_valid": np.zeros(config.max_nodes, bool),
        "neighbours": np.zeros((config.max_nodes, k), np.int64),
        "neighbour_valid": np.zeros((config.max_nodes, k), bool),
        "edges": np.zeros((config.max_nodes, k, 2), np.float32),
        "robot": np.array(n - 1),
    }
    g["nodes"][:n] = rng.normal(size=(n, 6))
    g["node_valid"][:n] = True
    g["neighbours"][:n] = rng.integers(0, n, size=(n, k))
    g["neighbour_valid"][:n] = rng.random((n, k)) < 0.8
    g["edges"][:n] = rng.random((n, k, 2))
    return g


@pytest.mark.parametrize("edge_messages", [False, True])
def test_network_is_permutation_equivariant_over_frontier_nodes(edge_messages):
    config = GraphConfig()
    rng = np.random.default_rng(3)
    nf, npath = 30, 5
    g = _random_graph(rng, nf, npath, config)
    perm = np.arange(config.max_nodes)
    perm[:nf] = rng.permutation(nf)  # new node i is old node perm[i]
    inv = np.argsort(perm)
    gp = dict(g)
    gp["nodes"] = g["nodes"][perm]
    gp["node_valid"] = g["node_valid"][perm]
    gp["neighbours"] = inv[g["neighbours"][perm]]
    gp["neighbour_valid"] = g["neighbour_valid"][perm]
    gp["edges"] = g["edges"][perm]
    gp["robot"] = np.array(inv[int(g["robot"])])
    torch.manual_seed(0)
    model = GraphActorCritic(NetworkConfig(edge_messages=edge_messages)).eval()
    assert (model.layers[0].edge_kv is not None) == edge_messages
    mask = torch.zeros(1, config.max_frontier_nodes, dtype=torch.bool)
    mask[0, :nf] = True
    with torch.no_grad():
        logits = model.masked_logits(to_torch(g, batch=True), mask)[0, :nf]
        logits_p = model.masked_logits(to_torch(gp, batch=True), mask)[0, :nf]
        value = model.get_value(to_torch(g, batch=True))
        value_p = model.get_value(to_torch(gp, batch=True))
    torch.testing.assert_close(logits_p, logits[torch.as_tensor(perm[:nf])], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(value_p, value, atol=1e-5, rtol=1e-5)
    assert logits.std() > 0  # not trivially constant


@pytest.mark.parametrize("nf, edge_messages", [(1, False), (30, False), (GraphConfig().max_frontier_nodes, False), (30, True)])
def test_traced_decision_network_matches_the_eager_one(nf, edge_messages):
    """Run-time decisions use a frozen trace on the fixed-size graph: same logits as the eager model,
    which cuts the padding, for any number of frontier nodes."""
    config = GraphConfig()
    g = to_torch(_random_graph(np.random.default_rng(nf), nf, 5, config), batch=True)
    mask = torch.zeros(1, config.max_frontier_nodes, dtype=torch.bool)
    mask[0, :nf] = True
    torch.manual_seed(1)
    model = GraphActorCritic(NetworkConfig(edge_messages=edge_messages)).eval()
    example = to_torch(_random_graph(np.random.default_rng(99), 7, 3, config), batch=True)
    traced = trace_decision(model, example, mask)  # traced on another graph: nothing baked in
    assert traced is not None
    with torch.inference_mode():
        eager = model.masked_logits(g, mask)
        fast = traced(*[g[k] for k in GRAPH_KEYS], mask)
    torch.testing.assert_close(fast[0, :nf], eager[0, :nf], atol=1e-5, rtol=1e-5)
    assert (fast[0, nf:] == eager[0, nf:]).all()  # masked actions stay masked
    assert nf == 1 or eager[0, :nf].std() > 0


def test_graph_from_observation_is_scale_free_and_complete(observation):
    config = GraphConfig()
    g = build_graph(observation, config)
    nf = len(observation.clusters)
    n = int(g["node_valid"].sum())
    assert n == nf + len(observation.path_nodes_xy_m)
    robot = int(g["robot"])
    assert g["nodes"][robot, 3] == 1.0 and np.allclose(g["nodes"][robot, :2], 0.0)
    assert np.all(g["nodes"][:nf, 2] == 1.0) and np.all(g["nodes"][nf:n, 2] == 0.0)
    # every node hears the robot, over the geodesic distance of the robot's distance map
    assert np.all(g["neighbours"][:n, -1] == robot)
    np.testing.assert_allclose(g["edges"][:nf, -1, 0], observation.goal_distance_m / config.distance_scale_m, rtol=1e-5)
    assert np.all(g["neighbours"][:n][g["neighbour_valid"][:n]] < n)
    no_info = build_graph(observation, dataclasses.replace(config, use_entropy=False))
    assert np.all(no_info["nodes"][:, 4] == 0.0) and np.any(g["nodes"][:nf, 4] > 0.0)


def test_compute_gae_matches_hand_computation():
    rewards = torch.tensor([[1.0], [0.0], [2.0]])
    values = torch.tensor([[0.5], [0.2], [0.1]])
    dones = torch.tensor([[0.0], [0.0], [1.0]])  # step 2 starts a new episode
    adv, ret = compute_gae(rewards, values, dones, torch.tensor([0.3]), torch.tensor([0.0]), 0.9, 0.8)
    d1 = 0.0 - 0.2  # no bootstrap: the next observation starts a new episode
    d0 = 1.0 + 0.9 * 0.2 - 0.5
    d2 = 2.0 + 0.9 * 0.3 - 0.1
    a1 = d1
    a0 = d0 + 0.9 * 0.8 * a1
    torch.testing.assert_close(adv[:, 0], torch.tensor([a0, a1, d2]))
    torch.testing.assert_close(ret, adv + values)


def test_compute_gae_takes_each_transitions_own_discount():
    """The semi-MDP discount (``Args.gamma_per_step``): a tensor of discounts, one per transition; a
    tensor of one value gives exactly the scalar's result."""
    rewards = torch.tensor([[1.0, 0.5], [0.0, 0.0], [2.0, 1.0]])
    values = torch.tensor([[0.5, 0.1], [0.2, 0.3], [0.1, 0.2]])
    dones = torch.zeros((3, 2))
    next_value, next_done = torch.tensor([0.3, 0.4]), torch.zeros(2)
    scalar = compute_gae(rewards, values, dones, next_value, next_done, 0.9, 0.8)
    same = compute_gae(rewards, values, dones, next_value, next_done, torch.full((3, 2), 0.9), 0.8)
    torch.testing.assert_close(same, scalar)
    g = torch.tensor([[0.9], [0.5], [0.7]])  # e.g. 0.99 ** k for decisions of different lengths
    adv, _ = compute_gae(rewards[:, :1], values[:, :1], dones[:, :1], next_value[:1], next_done[:1], g, 0.8)
    d2 = 2.0 + 0.7 * 0.3 - 0.1
    d1 = 0.0 + 0.5 * 0.1 - 0.2
    d0 = 1.0 + 0.9 * 0.2 - 0.5
    a1 = d1 + 0.5 * 0.8 * d2
    torch.testing.assert_close(adv[:, 0], torch.tensor([d0 + 0.9 * 0.8 * a1, a1, d2]))


def test_env_reports_the_control_steps_each_decision_took():
    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    steps, done = 0, False
    while not done:
        action = expert_action(env.obs, info["action_mask"])
        goal_xy_m = tuple(env.obs.goal_xy_m[action])
        _, _, terminated, truncated, info = env.step(action)
        assert env.masker.stuck.goals[-1] == pytest.approx(goal_xy_m)  # the stuck mask's past goals
        assert info["decision_steps"] >= 1
        steps += info["decision_steps"]
        done = terminated or truncated
    assert steps == info["steps"] > 1


def test_resets_info_has_every_key_of_a_steps_with_the_starts_values():
    """Gymnasium wrappers and loggers expect one set of info keys: ``reset``'s lacked ``terminated_by`` and
    ``decision_steps``, which every ``step`` gives. At the start no decision was taken and the episode goes on."""
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, reset_info = env.reset(seed=0)
    _, _, _, _, step_info = env.step(expert_action(env.obs, reset_info["action_mask"]))
    assert sorted(reset_info) == sorted(step_info)
    assert reset_info["terminated_by"] is None and reset_info["decision_steps"] == 0
    envs = gym.vector.SyncVectorEnv([lambda: ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))] * 2, autoreset_mode=AutoresetMode.SAME_STEP)
    try:
        _, info = envs.reset(seed=0)
        assert list(info["decision_steps"]) == [0, 0] and list(info["terminated_by"]) == [None, None]
    finally:
        envs.close()


def test_every_info_has_the_same_keys_and_types_masked_actions_included():
    """``info["invalid_action"]`` came only with a masked action's step: a vector env then adds the key (and its
    ``_invalid_action`` flags) on some steps only, and loggers that take the first info's keys miss it. Every info
    has it now: the masked action taken, or -1 where the step's action was allowed (and at ``reset``)."""
    import gymnasium as gym

    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    types = {key: type(value) for key, value in info.items()}
    assert info["invalid_action"] == -1
    masked = int(np.flatnonzero(info["action_mask"] == 0)[0])
    infos = [env.step(masked)[4], env.step(expert_action(env.obs, info["action_mask"]))[4]]
    assert [i["invalid_action"] for i in infos] == [masked, -1]
    for step_info in infos:
        assert {key: type(value) for key, value in step_info.items() if key != "terminated_by"} == {k: t for k, t in types.items() if k != "terminated_by"}
    envs = gym.vector.SyncVectorEnv([lambda: ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))] * 2)
    try:
        _, info = envs.reset(seed=0)
        assert list(info["invalid_action"]) == [-1, -1] and info["_invalid_action"].all()
        _, _, _, _, info = envs.step([masked, expert_action(envs.envs[1].unwrapped.obs, info["action_mask"][1])])
        assert list(info["invalid_action"]) == [masked, -1] and info["_invalid_action"].all()
    finally:
        envs.close()


def test_an_episode_cut_by_the_step_limit_ends_on_its_real_state_one_that_finished_on_the_empty_graph():
    """PPO bootstraps a truncated episode with V(final observation): that must be the graph of the state the
    cut left (frontiers still open), not the all-padding graph, whose value is one constant for every cut."""
    from cso_runtime.learned.graph import empty_graph, frontier_count

    def run(max_steps: int, cut_observation: str = "state") -> tuple[ExplorationEnv, dict[str, np.ndarray], bool, bool, dict]:
        env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=max_steps, cut_observation=cut_observation))
        _, info = env.reset(seed=0)
        terminated = truncated = False
        while not (terminated or truncated):
            graph, _, terminated, truncated, info = env.step(expert_action(env.obs, info["action_mask"]))
        return env, graph, terminated, truncated, info

    env, graph, terminated, truncated, info = run(30)
    assert truncated and not terminated and info["terminated_by"] == "max_steps"
    cut = env.explorer.observe()  # the state the cut left (one more path node: the same pose again)
    nf = frontier_count(cut, env.config.graph)
    assert nf > 0 and graph["node_valid"][:nf].all()
    np.testing.assert_array_equal(graph["nodes"][:nf], build_graph(cut, env.config.graph)["nodes"][:nf])
    with pytest.raises(RuntimeError, match="after the episode ended"):
        env.step(0)
    for max_steps, cut_observation in ((5000, "state"), (30, "empty")):  # explored to its end; or cut, as the shipped weights were trained
        env, graph, terminated, truncated, info = run(max_steps, cut_observation)
        assert (terminated, truncated) == ((True, False) if max_steps == 5000 else (False, True))
        for key, value in empty_graph(env.config.graph).items():
            np.testing.assert_array_equal(graph[key], value)
    assert Args().env_config().cut_observation == "state"
    with pytest.raises(ValueError, match="cut_observation must be state or empty"):
        Args(cut_observation="zero").validate()


def test_an_episode_over_at_reset_ends_at_its_first_step_instead_of_refusing_it():
    """A plan that the first scan explores whole (one room, a 360-degree LiDAR in its middle) has no decision to take:
    ``reset`` returned its end, and ``step`` then raised "called before reset() or after the episode ended", which
    stopped a vector env (it steps every env it reset) and training with it. The first step ends it, at no cost."""
    import gymnasium as gym

    from cso_runtime.config import ExplorationConfig

    exploration = dataclasses.replace(ExplorationConfig(), sensor=SensorConfig.preset("lidar", 360.0))
    config = EnvConfig(exploration=exploration, max_steps=200)
    whole_at_once = rooms_plan(1, start=Pose2D(1.5, 1.5, 0.0))
    env = ExplorationEnv([whole_at_once], config)
    obs, info = env.reset(seed=0)
    assert info["terminated_by"] == "coverage" and info["steps"] == 0  # explored: as eval's Explorer.run ends it
    assert env.observation_space.contains(obs) and env.action_space.sample(info["action_mask"]) == 0
    again, reward, terminated, truncated, end = env.step(0)
    assert (reward, terminated, truncated) == (0.0, True, False) and sorted(end) == sorted(info)
    assert all(np.array_equal(again[k], obs[k]) for k in obs) and end["decision_steps"] == 0 and end["invalid_action"] == -1
    with pytest.raises(RuntimeError, match="after the episode ended"):
        env.step(0)
    assert episode_returns(env, lambda _graph, mask, _rng: int(np.argmax(mask)), [0, 1]) == [0.0, 0.0]
    envs = gym.vector.SyncVectorEnv(
        [lambda: ExplorationEnv([whole_at_once], config), lambda: ExplorationEnv([rooms_plan(2)], config)],
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,  # as training steps them: each step ends and resets env 0
    )
    try:
        _, info = envs.reset(seed=0)
        for _ in range(4):
            _, _, terminated, _, info = envs.step(envs.action_space.sample(tuple(info["action_mask"])))
            assert terminated[0]
    finally:
        envs.close()


def test_scene_scaled_reward_is_eq6_times_the_reference_over_the_scene_area():
    """``scene_scale_area_m2``: the same episode (same choices), every reward scaled by one factor per scene."""
    from cso_runtime.learned.env import RewardConfig

    rewards = {}
    for scale_m2 in (0.0, 50.0):
        env = ExplorationEnv([rooms_plan(2)], EnvConfig(reward=RewardConfig(scene_scale_area_m2=scale_m2), max_steps=200))
        _, info = env.reset(seed=0)
        out, done = [], False
        while not done:
            _, r, terminated, truncated, info = env.step(expert_action(env.obs, info["action_mask"]))
            out.append(r)
            done = terminated or truncated
        rewards[scale_m2] = np.array(out)
        area_m2 = env.explorer.region_area_m2
    assert len(rewards[0.0]) == len(rewards[50.0]) > 2 and area_m2 > 0
    np.testing.assert_allclose(rewards[50.0], rewards[0.0] * 50.0 / area_m2, rtol=1e-9)
    with pytest.raises(ValueError, match="reward_scene_scale_area_m2"):
        Args(reward_scene_scale_area_m2=-1.0).validate()


def test_the_action_mask_is_gymnasiums_so_the_action_space_samples_allowed_actions():
    """Gymnasium's spaces take a mask of ``np.int8`` (``Discrete.sample(mask)``, ``MultiDiscrete`` per env):
    ``info["action_mask"]`` is one, of the action space's size, so a random agent that respects the mask is
    ``env.action_space.sample(info["action_mask"])``, in one env and in a vector env."""
    import gymnasium as gym

    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    mask = info["action_mask"]
    assert mask.dtype == np.int8 and mask.shape == (env.action_space.n,) and set(np.unique(mask)) <= {0, 1} and mask.any()
    for seed in range(20):
        env.action_space.seed(seed)
        assert mask[env.action_space.sample(mask)] == 1
    _, _, _, _, info = env.step(env.action_space.sample(mask))
    assert info["action_mask"].dtype == np.int8 and info["invalid_actions"] == 0
    envs = gym.vector.SyncVectorEnv([lambda: ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))] * 2)
    try:
        _, info = envs.reset(seed=0)
        assert info["action_mask"].dtype == np.int8 and info["action_mask"].shape == (2, env.action_space.n)
        actions = envs.action_space.sample(tuple(info["action_mask"]))
        assert all(info["action_mask"][i, a] == 1 for i, a in enumerate(actions))
    finally:
        envs.close()


def test_the_env_gives_its_action_mask_through_action_masks_as_maskable_ppo_asks():
    """sb3-contrib's ``MaskablePPO`` asks the env for ``action_masks()`` (a bool array; through wrappers with
    ``get_wrapper_attr``, through a vector env with ``call``): the env had none, so it refused the env as unmasked."""
    import gymnasium as gym

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", config=EnvConfig(max_steps=120))
    _, info = env.reset(seed=3)
    masks = env.get_wrapper_attr("action_masks")()
    assert masks.dtype == bool and np.array_equal(masks, info["action_mask"] == 1)
    masks[:] = False  # a copy: the caller's changes do not reach the env
    _, _, _, _, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
    assert np.array_equal(env.get_wrapper_attr("action_masks")(), info["action_mask"] == 1)
    envs = gym.vector.SyncVectorEnv([lambda: ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))] * 2)
    try:
        _, info = envs.reset(seed=0)
        assert np.array_equal(np.stack(envs.call("action_masks")), info["action_mask"] == 1)
    finally:
        envs.close()


def test_the_default_env_fits_the_shipped_weights_and_other_graphs_say_what_to_pass():
    """``gymnasium.make`` without a config gives the graph the shipped weights read (the recipe's, so training
    is unchanged), and they run in it; weights given graphs of another feature size say which graph to build,
    not torch's "mat1 and mat2 shapes cannot be multiplied"."""
    import gymnasium as gym

    from cso_runtime.config import from_dict, load_yaml

    recipe = from_dict(Args, load_yaml(Path(__file__).parents[1] / "configs" / "train.yaml"), "train.yaml")
    assert recipe.env_config().graph == EnvConfig().graph
    for sensor in (SensorConfig.preset("lidar", 360.0), SensorConfig.preset("lidar")):  # cso.pt and cso@fov180.pt
        model, graph, _ = load_checkpoint(weights_path("cso", sensor))
        assert graph == EnvConfig().graph and model.config.node_features == len(node_features(EnvConfig().graph))
    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4").unwrapped
    assert np.isfinite(episode_returns(env, model_chooser(model), [0], max_decisions=3)[0])
    other = ExplorationEnv([rooms_plan(2)], EnvConfig(graph=GraphConfig()))  # the paper's six features
    with pytest.raises(ValueError, match=re.escape("have 6 node features, the weights' network reads 7")) as caught:
        episode_returns(other, model_chooser(model), [0], max_decisions=3)
    assert "EnvConfig(graph=load_checkpoint(path)[1])" in str(caught.value)


def test_env_follows_the_gymnasium_api():
    """Besides Gymnasium's checks (which pass arrays of any dtype), every observation's arrays have the dtypes its
    space declares: ``node_valid`` and ``neighbour_valid`` came as bool from the env but as the ``MultiBinary``'s int8
    from a vector env, so the same agent code saw other arrays (``~valid`` of int8 is -1 and -2: every entry true)."""
    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    check_reset_return_type(env)
    check_reset_seed_determinism(env)
    check_reset_options(env)

    def in_its_space(obs: dict[str, np.ndarray]) -> bool:
        return env.observation_space.contains(obs) and all(obs[k].dtype == space.dtype for k, space in env.observation_space.items())

    obs, info = env_reset_passive_checker(env, seed=0)
    assert in_its_space(obs)
    assert info["action_mask"].shape == (env.action_space.n,) and info["action_mask"].any()
    obs, _, _, _, rejected = env.step(int(np.flatnonzero(info["action_mask"] == 0)[0]))  # a masked action: a counted no-op
    assert in_its_space(obs)
    assert rejected["invalid_actions"] == 1 and rejected["steps"] == info["steps"]
    with pytest.raises(ValueError, match="outside the action space"):
        env.step(-1)
    total_steps, done = 0, False
    while not done:
        action = expert_action(env.obs, info["action_mask"])
        obs, reward, terminated, truncated, info = env_step_passive_checker(env, action)
        assert isinstance(reward, float) and reward >= -0.01 * 200
        assert in_its_space(obs)
        done = terminated or truncated
        total_steps += 1
    assert info["terminated_by"] in ("coverage", "no_frontier", "max_steps")
    assert truncated == (info["terminated_by"] == "max_steps")


def test_the_observation_space_bounds_each_feature_that_has_a_bound_and_holds_every_observation():
    """The graph's boxes were -inf to inf throughout (``check_env`` warns of it): the 0/1 labels, the unexplored
    fraction and the non-negative distances have their bounds now; the positions relative to the robot, the lengths
    and the entropy have none above (scenes have no size limit), and stay so. Every observation of episodes with each
    optional feature lies in its space."""
    config = GraphConfig(use_cluster_size=True, use_unknown_area=True)
    space = ExplorationEnv([rooms_plan(2)], EnvConfig(graph=config)).observation_space
    ranges = dict(zip(node_features(config), zip(space["nodes"].low[0], space["nodes"].high[0], strict=True), strict=True))
    assert ranges == {
        "dx": (-np.inf, np.inf), "dy": (-np.inf, np.inf), "frontier": (0, 1), "current": (0, 1), "entropy": (0, np.inf),
        "geodesic": (0, np.inf), "size": (0, np.inf), "unknown": (0, 1),
    }  # fmt: skip
    assert (space["nodes"].low == space["nodes"].low[0]).all() and (space["nodes"].high == space["nodes"].high[0]).all()
    assert (space["edges"].low == 0).all() and (space["edges"].high == np.inf).all()
    for graph in (config, GraphConfig(egocentric=True, geodesic_edge_bound=True)):
        env = ExplorationEnv([rooms_plan(3)], EnvConfig(graph=graph, max_steps=200))
        obs, info = env.reset(seed=0)
        done = False
        while not done:
            assert env.observation_space.contains(obs)
            obs, _, terminated, truncated, info = env.step(expert_action(env.obs, info["action_mask"]))
            done = terminated or truncated
        assert env.observation_space.contains(obs)


def test_reset_options_choose_the_episodes_plan_and_info_names_it():
    """Gymnasium's ``reset(seed=..., options=...)``: the options were silently ignored (a mistyped key too), and nothing
    said which plan an episode ran on. ``options={"plan": NAME_OR_INDEX}`` chooses it, every other draw staying as
    without it; other keys and plans the env does not have are refused; ``info["plan"]`` names it at every decision."""
    import gymnasium as gym

    env = ExplorationEnv([rooms_plan(2), rooms_plan(3)], EnvConfig(max_steps=200))
    drawn = {seed: env.reset(seed=seed)[1]["plan"] for seed in range(6)}
    assert set(drawn.values()) == {"rooms2", "rooms3"}  # both plans are drawn: the options below choose against the draw
    for seed, plan in drawn.items():
        obs, info = env.reset(seed=seed, options={"plan": plan})  # the plan the seed draws: the very same episode
        plain_obs, plain_info = env.reset(seed=seed, options={})
        assert info["plan"] == plain_info["plan"] == plan and all(np.array_equal(obs[k], plain_obs[k]) for k in obs)
        for chosen in ("rooms2", "rooms3", 0, 1, np.int64(1)):
            _, info = env.reset(seed=seed, options={"plan": chosen})
            assert info["plan"] == env.plan_name == ("rooms2" if chosen in ("rooms2", 0) else "rooms3")
            assert env.reset()[1]["plan"] == drawn_after(env, seed)  # the next reset draws as after reset(seed=seed)
    _, info = env.reset(seed=0, options={"plan": "rooms3"})
    _, _, _, _, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
    assert info["plan"] == "rooms3"
    for options, said in [
        ({"plna": 0}, "reset options: unknown key(s) 'plna' (did you mean plan?); this env takes plan"),
        ({"plan": "rooms4"}, "reset options: no plan 'rooms4' (did you mean rooms3?) in this env; its plans: rooms2, rooms3"),
        ({"plan": 2}, "plan index 2 out of range: this env has 2 plans (0 to 1)"),
        ({"plan": True}, "plan must be a plan's name (str) or its index (int), got bool"),
    ]:
        with pytest.raises(ValueError, match=re.escape(said)):
            env.reset(seed=0, options=options)
    with pytest.raises(TypeError, match="reset options must be a dict"):
        env.reset(options=["plan"])
    envs = gym.vector.SyncVectorEnv([lambda: ExplorationEnv([rooms_plan(2), rooms_plan(3)], EnvConfig(max_steps=200))] * 2)
    try:
        _, info = envs.reset(seed=0, options={"plan": "rooms3"})
        assert list(info["plan"]) == ["rooms3", "rooms3"]
    finally:
        envs.close()


def drawn_after(env: ExplorationEnv, seed: int) -> str:
    """The plan of the reset that follows ``reset(seed=seed)`` (no options) in ``env``."""
    env.reset(seed=seed)
    return env.reset()[1]["plan"]


def test_short_ppo_run_beats_a_random_policy(tmp_path):
    """Pure PPO (no warm start) on three rooms, masks off so that choices matter. The greedy trained
    policy must beat uniformly random valid choices and its own initial network on the same seeds
    (with this seed the initial network wanders: about -2.7 against about -0.5 for random)."""
    plan = rooms_plan(3, start=Pose2D(4.5, 1.5, 1.57))
    args = Args(
        variant="cso-no-mask", out_dir=str(tmp_path), seed=0, total_decisions=192, num_envs=2, num_steps=32, num_minibatches=2,
        learning_rate=2e-3, anneal_lr=False, clip_coef=0.2, ent_coef=0.0, target_kl=0.0, max_steps=300, progress=False,
    )
    torch.manual_seed(args.seed)  # train() seeds torch the same way before building its network
    initial = build_model(args, torch.device("cpu")).eval()
    record = train(args, log=lambda _msg: None, plans=[plan])
    assert record["ppo_decisions"] == 192
    assert (tmp_path / "cso-no-mask_log.csv").is_file() and (tmp_path / "cso-no-mask_curve.png").is_file()
    model, _, _ = load_checkpoint(tmp_path / "cso-no-mask.pt")
    env = ExplorationEnv([plan], args.env_config())
    seeds = [100, 101, 102, 103]
    trained = np.mean(episode_returns(env, model_chooser(model), seeds))
    before = np.mean(episode_returns(env, model_chooser(initial), seeds))
    random = np.mean(episode_returns(env, random_chooser, seeds))
    assert trained > random + 0.1, (trained, random)
    assert trained > before + 0.1, (trained, before)  # learned, not a lucky initialisation


def test_trainings_first_line_counts_one_scene_and_one_update_in_the_singular(tmp_path):
    """A training on one plan said "training cso on 1 scenes ... (1 envs x 8 steps" (the warm start's line, beside it, was
    fixed to "1 scene"): a count of one is singular on every line of the log that counts scenes, processes, updates, envs."""
    from cso_runtime.learned.ppo import counted

    said: list[str] = []
    args = Args(variant="cso", out_dir=str(tmp_path), seed=0, total_decisions=8, num_envs=1, num_steps=8, num_minibatches=1, max_steps=20, progress=False)
    train(args, log=said.append, plans=[rooms_plan(2)])
    assert any(line.startswith("training cso on 1 scene, device ") and "1 PPO update of 8 decisions (1 env x 8 steps;" in line for line in said), said
    assert [counted(n, "process", "processes") for n in (0, 1, 2)] == ["0 processes", "1 process", "2 processes"]
    assert counted(1, "scene") == "1 scene" and counted(3, "scene") == "3 scenes"


def test_training_with_the_per_step_discount_runs_through_episode_ends(tmp_path):
    """``gamma_per_step``: every decision discounted by its own length, through finished and truncated
    episodes (their last decision's length comes from ``final_info``), in both vector envs' shape."""
    args = Args(
        variant="cso", out_dir=str(tmp_path), seed=0, total_decisions=64, num_envs=2, num_steps=16, num_minibatches=2,
        max_steps=40, gamma_per_step=0.99, progress=False,
    )
    record = train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
    assert record["ppo_decisions"] == 64
    rows = list(csv.DictReader((tmp_path / "cso_log.csv").open()))
    assert sum(int(r["episodes"]) for r in rows) >= 2 and all(np.isfinite(float(r["value_loss"])) for r in rows)
    with pytest.raises(ValueError, match="gamma_per_step"):
        dataclasses.replace(args, gamma_per_step=1.0).validate()


def _tensorboard_scalars(folder) -> dict[str, list[tuple[int, float]]]:
    """Every scalar in the TensorBoard event files of ``folder`` (TFRecord framing: length, CRC, event, CRC)."""
    import struct

    from tensorboardX.proto.event_pb2 import Event

    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        at = 0
        while at < len(data):
            (length,) = struct.unpack("<Q", data[at : at + 8])
            event = Event.FromString(data[at + 12 : at + 12 + length])
            at += 12 + length + 4
            if event.session_log.status == event.session_log.START:  # as TensorBoard reads it: a restart drops the points from its step on
                scalars = {tag: [(step, v) for step, v in points if step < event.step] for tag, points in scalars.items()}
            for value in event.summary.value:
                scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_training_writes_the_csv_figures_as_tensorboard_events(tmp_path, monkeypatch):
    """``tensorboard: true``: each update's CSV row as CleanRL-style scalars over PPO decisions; without
    tensorboardX the run stops with the install hint before it trains."""
    import sys

    from cso_runtime.learned import ppo

    args = Args(variant="cso", out_dir=str(tmp_path), seed=0, total_decisions=64, num_envs=2, num_steps=16, num_minibatches=2,
                max_steps=40, progress=False, tensorboard=True)
    train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
    rows = list(csv.DictReader((tmp_path / "cso_log.csv").open()))
    scalars = _tensorboard_scalars(tmp_path / "tensorboard")
    assert [step for step, _ in scalars["losses/value_loss"]] == [int(r["decisions"]) for r in rows] == [32, 64]
    assert [v for _, v in scalars["losses/value_loss"]] == pytest.approx([float(r["value_loss"]) for r in rows], rel=1e-6)
    assert [v for _, v in scalars["charts/learning_rate"]] == pytest.approx([float(r["lr"]) for r in rows], rel=1e-6)
    returns = [(int(r["decisions"]), float(r["mean_return"])) for r in rows if r["mean_return"]]
    assert [(s, pytest.approx(v, rel=1e-6)) for s, v in scalars.get("charts/episodic_return", [])] == returns
    every_update = set(ppo.TENSORBOARD_TAGS.values()) - {"charts/episodic_return", "charts/coverage_pct", "charts/episodic_length"}  # those once an episode ended
    assert set(scalars) >= every_update | {"charts/SPS"}

    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # not installed
    bare = tmp_path / "bare"
    with pytest.raises(ValueError, match=r"pip install 'cso-runtime\[tensorboard\]'"):
        train(dataclasses.replace(args, out_dir=str(bare)), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert not (bare / "cso_log.csv").exists()


def test_train_ends_saying_its_files_and_the_eval_that_runs_its_weights_as_trained(tmp_path, monkeypatch):
    """A run of configs/train.yaml trains with the 360-degree LiDAR and eval runs the LIMO's 180 degrees unless told,
    and a run trained with other stuck-mask settings is evaluated with eval's own: train's last lines named the folder
    alone. They now list its files and the eval command that runs the weights with the run's sensor and masks, which
    eval takes as it is."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned.ppo import matching_eval_command

    unset_weights_env(monkeypatch)  # eval's --weights sets one in this process: put back as it was after the test
    assert matching_eval_command(Args(out_dir="runs/x")) == "cso-runtime eval --method cso --weights runs/x"
    assert matching_eval_command(Args(out_dir="runs/x", sensor="depth")) == "cso-runtime eval --method cso --weights runs/x --sensor depth"
    # a setting the variant's masks do not use is not given: cso-sm has no valid distance mask to conflict with
    cso_sm = Args(out_dir="runs/x", variant="cso-sm", stuck_avoid="goals", mask_conflict="stuck")
    assert matching_eval_command(cso_sm) == "cso-runtime eval --method cso-sm --weights runs/x --set masks.stuck_avoid=goals"
    out = tmp_path / "my run"
    tiny = ["--set", "dungeon_dir=null", "--set", "generated=[generated:small:1:0]", "--set", "num_steps=4", "--set", "num_minibatches=1",
            "--set", "max_steps=40", "--num-envs", "1", "--total-decisions", "4", "--variant", "cso", "--out", str(out),
            "--set", "stuck_avoid=goals", "--set", "mask_conflict=stuck"]  # fmt: skip
    r = CliRunner().invoke(app, ["train", *tiny])
    assert r.exit_code == 0, r.output
    assert f"-> {out}: cso.pt, cso_log.csv, cso_curve.png, cso.json, checkpoint.pt" in r.output
    said = re.search(r"evaluate it as it was trained: (.*) \(and your --maps, --out\)", r.output)
    assert said and shlex.split(said.group(1)) == [
        "cso-runtime", "eval", "--method", "cso", "--weights", str(out), "--lidar-fov", "360",
        "--set", "masks.stuck_avoid=goals", "--set", "masks.conflict=stuck",
    ]  # fmt: skip
    r = CliRunner().invoke(app, [*shlex.split(said.group(1))[1:], "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(tmp_path / "eval")])
    assert r.exit_code == 0 and "trained with" not in r.output, r.output
    meta = json.loads((tmp_path / "eval" / "summary.json").read_text())["meta"]
    assert meta["config"]["sensor"]["fov_deg"] == 360 and meta["config"]["masks"]["stuck_avoid"] == "goals" and meta["config"]["masks"]["conflict"] == "stuck"


def test_a_resumed_runs_tensorboard_curves_hold_each_update_once(tmp_path):
    """A run stopped after logging updates its checkpoint does not hold runs them again on ``--resume``: the CSV log
    drops their rows, but their TensorBoard points stayed, so the curves had two values at those steps. The resumed
    run's events now start with TensorBoard's restart marker at the checkpoint's step, which drops the orphans."""
    import shutil

    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40,
              "progress": False, "tensorboard": True}  # fmt: skip
    train(Args(total_decisions=16, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    shutil.copy(tmp_path / "checkpoint.pt", tmp_path / "at_update_2.pt")
    train(Args(total_decisions=24, resume=str(tmp_path / "checkpoint.pt"), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    # As if that run had stopped after logging update 3 but before its checkpoint: resume from update 2's.
    train(Args(total_decisions=32, resume=str(tmp_path / "at_update_2.pt"), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    rows = list(csv.DictReader((tmp_path / "cso_log.csv").open()))
    scalars = _tensorboard_scalars(tmp_path / "tensorboard")
    assert [step for step, _ in scalars["losses/value_loss"]] == [int(r["decisions"]) for r in rows] == [8, 16, 24, 32]
    assert [v for _, v in scalars["losses/value_loss"]] == pytest.approx([float(r["value_loss"]) for r in rows], rel=1e-6)


def test_the_training_bar_shows_the_latest_return_coverage_and_rate(tmp_path, monkeypatch):
    """As CleanRL prints its episodic return and SPS: after each update the bar's text is the mean return and
    coverage of the last finished episodes and the decisions per second."""
    import io

    from rich.console import Console

    from cso_runtime.learned import ppo

    shown: list[str | None] = []

    class RecordingBar(ppo._Bar):
        def advance(self, n: int = 1, stats: str | None = None) -> None:
            shown.append(stats)
            super().advance(n, stats)

    out = io.StringIO()
    monkeypatch.setattr(ppo, "_progress", lambda enabled, total, completed=0: RecordingBar(total, console=Console(file=out, width=200), completed=completed) if enabled else None)
    args = Args(variant="cso", out_dir=str(tmp_path), seed=0, total_decisions=64, num_envs=2, num_steps=16, num_minibatches=2, max_steps=40, progress=True)
    train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
    rows = list(csv.DictReader((tmp_path / "cso_log.csv").open()))
    assert len(shown) == len(rows) == 2
    finished = [r for r in rows if int(r["episodes"])]
    assert finished and re.fullmatch(r"return -?\d+\.\d\d  coverage \d+\.\d % \(last \d+ episodes\)  \d+ decisions/s", shown[-1] or "")
    assert "decisions/s" in out.getvalue()
    assert ppo.progress_stats([], 100, 4.0) == "25 decisions/s"
    two = [{"return": 1.0, "coverage_pct": 90.0}, {"return": 2.0, "coverage_pct": 100.0}]
    assert ppo.progress_stats(two, 100, 0.0) == "return 1.50  coverage 95.0 % (last 2 episodes)  "


@pytest.mark.parametrize("width", [80, 200])
def test_the_training_bar_keeps_its_count_and_time_left_in_an_80_column_terminal(width):
    """In an 80-column terminal the figures after the bar (return, coverage, decisions/s: 64 characters) squeezed
    rich's columns to nothing: the bar read `PPO updates left return -0.25 ...`, with no update count, bar or time
    left. The figures go on a line of their own under the bar, so every column of the bar keeps its width."""
    from rich.console import Console

    from cso_runtime.learned import ppo

    out = TerminalFile()  # a terminal: its isatty() is true (live_view.writes_to_a_terminal)
    stats = "return -0.25  coverage 99.6 % (last 20 episodes)  96 decisions/s"
    bar = ppo._Bar(100, console=Console(file=out, width=width, force_terminal=True, color_system=None))
    bar.advance(stats=stats)
    bar.close()
    shown = out.getvalue()
    assert "PPO updates" in shown and "1/100" in shown and "left" in shown
    assert stats in shown and "PPO updates 1/100 (" not in shown  # the bar, not a log's line


def test_training_progress_in_a_log_file_is_plain_lines():
    """No terminal (nohup, CI, a cluster job): lines that say how far the run is, at most every line_every_s and
    at the end, instead of a bar nobody sees until the run ends."""
    import io

    from rich.console import Console

    from cso_runtime.learned import ppo

    out = io.StringIO()
    bar = ppo._Bar(3, console=Console(file=out, width=60), line_every_s=0.0)
    for i in range(3):
        bar.advance(stats=f"return {i}.00  a long text that must stay on one line however narrow the console is")
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 3 and lines[0].startswith("PPO updates 1/3 (") and " s left): return 0.00  a long" in lines[0]
    assert lines[2].startswith("PPO updates 3/3 (") and "left" not in lines[2] and lines[2].endswith("however narrow the console is")
    quiet = io.StringIO()
    bar = ppo._Bar(3, "teacher decisions", console=Console(file=quiet, width=60), line_every_s=1e9)
    bar.advance(2)
    bar.advance(1)
    assert quiet.getvalue().splitlines() == [quiet.getvalue().splitlines()[0]] and quiet.getvalue().startswith("teacher decisions 3/3 (")


def test_a_resumed_runs_bar_counts_the_updates_of_the_whole_run(tmp_path, monkeypatch):
    """`train --resume` of a run at update 2 of 4 showed `PPO updates 2/2` (this process's updates alone), so a run
    that had 2 of 4 updates left read as done from the start and as finished at update 4 of 8 (the same command with
    a larger total_decisions). The bar counts the run's updates; the time left is this process's pace."""
    import io

    from rich.console import Console

    from cso_runtime.learned import ppo

    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 2, "num_steps": 8, "num_minibatches": 2, "max_steps": 40,
              "checkpoint_every": 1, "progress": True}  # fmt: skip
    out = io.StringIO()
    monkeypatch.setattr(ppo, "_progress", lambda enabled, total, completed=0: ppo._Bar(total, console=Console(file=out, width=200), **({"completed": completed} if completed else {})))
    train(Args(total_decisions=32, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert out.getvalue().startswith("PPO updates 2/2 (")
    out.truncate(0)
    out.seek(0)
    train(Args(total_decisions=64, resume=str(tmp_path / "checkpoint.pt"), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert out.getvalue().startswith("PPO updates 4/4 (")
    lines = io.StringIO()
    bar = ppo._Bar(8, console=Console(file=lines, width=200), line_every_s=0.0, completed=4)
    bar.advance()
    bar.close()
    assert re.fullmatch(r"PPO updates 5/8 \(\d+ s, about \d+ s left\)", lines.getvalue().strip())


def test_policies_of_one_model_share_one_trace(observation):
    """Eval makes a policy per episode: the model is traced once, not at every episode's first decision."""
    model = GraphActorCritic().eval()
    a, b = (LearnedPolicy("cso", model, GraphConfig(), MaskConfig()) for _ in range(2))
    a.select(observation)
    b.select(observation)
    assert a._traced and a._traced is b._traced


def test_warm_up_traces_before_the_first_decision_and_changes_no_decision(observation):
    """A policy server warms its selector up before it says it is up: the trace is built on an
    all-padding graph (the shapes are fixed), and decisions are those of a policy traced on a real one."""
    model = GraphActorCritic().eval()
    warm, cold = (LearnedPolicy("cso", m, GraphConfig(), MaskConfig()) for m in (model, copy.deepcopy(model)))
    warm.warm_up()
    assert warm._traced
    traced = warm._traced
    mask = warm.action_mask(observation)
    cold.action_mask(observation)
    p_warm, p_cold = warm.probabilities(observation, mask), cold.probabilities(observation, mask)
    assert warm._traced is traced and cold._traced and cold._traced is not traced
    np.testing.assert_allclose(p_warm, p_cold, rtol=1e-5, atol=1e-7)
    assert (p_warm[~mask] == 0).all() and p_warm[mask].sum() == pytest.approx(1.0, abs=1e-5)


def test_checkpoint_round_trip_gives_the_same_actions(tmp_path, observation):
    torch.manual_seed(5)
    model = GraphActorCritic(NetworkConfig(hidden=32, heads=2, layers=1)).eval()
    config = GraphConfig(knn=6)
    save_checkpoint(tmp_path / "m.pt", model, config, "cso")
    loaded, loaded_config, ckpt = load_checkpoint(tmp_path / "m.pt")
    assert loaded_config == config and ckpt["variant"] == "cso"
    mask_cfg = MaskConfig(use_valid_distance=False, use_stuck=False)
    a = LearnedPolicy("cso", model, config, mask_cfg)
    b = LearnedPolicy("cso", loaded, loaded_config, mask_cfg)
    mask = a.action_mask(observation)
    np.testing.assert_array_equal(a.probabilities(observation, mask), b.probabilities(observation, mask))
    assert a.select(observation) == b.select(observation)


def test_make_policy_cso_uses_the_shipped_weights():
    assert has_method("cso"), "the cso weights must ship in cso_runtime/data/weights/cso.pt"
    policy = make_policy("cso", MaskConfig(), seed=0)
    assert policy.name == "cso"
    explorer = Explorer(KinematicSimulator(rooms_plan(2)))
    policy.reset(0)
    goal = policy.select(explorer.observe())
    assert isinstance(goal, Goal)
    assert not has_method("no-such-variant")
    # The very network of the shipped file for each field of view (the 180-degree LiDAR's own weights where they
    # ship), not a fresh one of the same shape: every tensor equal to the checkpoint's.
    files = set()
    for sensor in (SensorConfig(), SensorConfig(fov_deg=360.0)):
        served = make_policy("cso", MaskConfig(), seed=0, sensor=sensor).model.state_dict()
        path = weights_path("cso", sensor)
        shipped = load_checkpoint(path)[0].state_dict()
        assert served.keys() == shipped.keys()
        assert all(torch.equal(served[k], shipped[k]) for k in shipped), path
        files.add(path.name)
    assert files == {"cso.pt", "cso@fov180.pt"}


@pytest.mark.parametrize("variant", ["cso", "cso-no-info", "cso-no-mask", "cso-sm", "cso-vdm", "gnn-baseline"])
def test_shipped_weights_match_the_training_config(variant, monkeypatch):
    """configs/train.yaml says it reproduces the shipped weights: each shipped checkpoint's graph and network
    settings are the ones ``train --config configs/train.yaml --variant V`` builds, and its JSON record names
    that command."""
    import json

    from cso_runtime.cli import training_args
    from cso_runtime.learned.weights import weights_path

    unset_weights_env(monkeypatch)  # the shipped weights, whatever folder or file the developer's environment gives
    config = Path(__file__).resolve().parents[1] / "configs" / "train.yaml"
    # The plan folder exists on the build machine only (training_args checks the scenes); it does not shape the network.
    args = training_args(config, {"variant": variant}, ["dungeon_dir=null"])
    model, graph, _ = load_checkpoint(weights_path(variant))
    expected = build_model(args, torch.device("cpu")).config
    assert graph == args.env_config().graph
    assert model.config == expected
    record = json.loads(weights_path(variant).with_suffix(".json").read_text())
    assert record["command"] == f"cso-runtime train --config configs/train.yaml --variant {variant}"
    assert record["args"]["cluster_size_feature"] == args.cluster_size_feature


def test_fine_tuning_starts_from_the_given_weights_and_checks_the_variant(tmp_path):
    """``init_from`` loads the weights before PPO (no warm start); a file of another variant is refused."""
    plan = rooms_plan(2)
    common = {"out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 100, "progress": False}
    torch.manual_seed(3)
    start = GraphActorCritic(NetworkConfig(hidden=32, heads=4, layers=2)).eval()
    save_checkpoint(tmp_path / "start.pt", start, Args(**common).env_config().graph, "cso")
    args = Args(variant="cso", init_from=str(tmp_path / "start.pt"), total_decisions=8, learning_rate=0.0, warm_start_decisions=50, **common)
    record = train(args, log=lambda _msg: None, plans=[plan])
    assert record["init_from"] == str(tmp_path / "start.pt") and record["warm_start_decisions"] == 0
    tuned, _, _ = load_checkpoint(tmp_path / "cso.pt")
    for name, value in start.state_dict().items():  # learning rate 0: the weights come through unchanged
        torch.testing.assert_close(tuned.state_dict()[name], value)
    with pytest.raises(ValueError, match="variant"):
        train(Args(variant="cso-no-mask", init_from=str(tmp_path / "start.pt"), total_decisions=8, **common), log=lambda _m: None, plans=[plan])


def test_warm_start_teacher_runs_through_subprocess_envs(tmp_path):
    """The greedy teacher is asked through the vector env's ``call``, so async (one process per env) works."""
    from cso_runtime.learned.ppo import collect_teacher, make_vector_env

    args = Args(num_envs=2, async_envs=True, max_steps=100)
    envs = make_vector_env(args, [rooms_plan(2)])
    lines: list[str] = []
    try:
        data = collect_teacher(envs, 6, 0.98, seed=0, log=lines.append)
    finally:
        envs.close()
    masks, actions = data.masks, data.actions
    assert not np.isfinite(data.outcome_steps).any()  # a score-based teacher simulates nothing
    assert actions.shape == (6,) and masks[np.arange(6), actions].all()  # every teacher choice is allowed
    assert [line.split(" decisions")[0] for line in lines] == ["warm start: 2/6 greedy-dist", "warm start: 4/6 greedy-dist"]
    env = ExplorationEnv([rooms_plan(2)], args.env_config())
    _, info = env.reset(seed=0)
    assert actions[0] == expert_action(env.obs, info["action_mask"])  # the same seed, the same first choice


def test_a_stop_in_the_teacher_collection_closes_its_progress_bar(monkeypatch):
    """A stop (``stop_requested``, or Ctrl-C) in ``collect_teacher`` left its progress bar running: rich's live display
    went on drawing while train stopped and never showed the terminal's cursor again. It is closed as the PPO bar is."""
    from cso_runtime.learned import ppo

    bars: list = []

    class Bar:
        def __init__(self, total: int, what: str) -> None:
            self.advanced, self.closed = 0, False
            bars.append(self)

        def advance(self, n: int = 1) -> None:
            self.advanced += n

        def close(self) -> None:
            self.closed = True

    monkeypatch.setattr(ppo, "_Bar", Bar)
    asked: list[bool] = []
    envs = ppo.make_vector_env(Args(num_envs=1, async_envs=False, max_steps=100), [rooms_plan(2)])
    try:
        with pytest.raises(KeyboardInterrupt):
            ppo.collect_teacher(envs, 6, 0.98, seed=0, progress=True, stop_requested=lambda: asked.append(True) or len(asked) > 2)
    finally:
        envs.close()
    assert len(bars) == 1 and bars[0].advanced == 2 and bars[0].closed


def test_warm_start_teacher_is_the_chosen_baseline_under_the_mask():
    """The warm start imitates the configured baseline (its own score, e.g. explore_lite's utility),
    restricted to the allowed actions; greedy-dist stays the default; an unknown teacher is refused."""
    from cso_runtime.policies import Utility

    env = ExplorationEnv([rooms_plan(3)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    differ, checked = 0, 0
    while checked < 12:
        obs, mask = env.obs, info["action_mask"]
        n = len(obs.clusters)
        reachable = np.zeros(len(mask), dtype=bool)
        reachable[:n] = np.isfinite(obs.goal_distance_m[:n])
        allowed = np.flatnonzero(mask & reachable)
        utility = Utility().cost(obs)
        assert expert_action(obs, mask, "utility") == allowed[np.argmin(utility[allowed])]
        assert expert_action(obs, mask) == expert_action(obs, mask, "greedy-dist") == allowed[np.argmin(obs.goal_distance_m[allowed])]
        assert env.teacher_action("utility") == expert_action(obs, mask, "utility")
        differ += expert_action(obs, mask, "utility") != expert_action(obs, mask)
        checked += 1
        _, _, terminated, truncated, info = env.step(expert_action(obs, mask, "utility"))
        if terminated or truncated:
            _, info = env.reset(seed=checked)
    assert differ > 0  # the two teachers do disagree on these rooms
    with pytest.raises(ValueError, match="teacher"):
        expert_action(env.obs, info["action_mask"], "random")
    with pytest.raises(ValueError, match="warm_start_teacher"):
        Args(warm_start_teacher="random").validate()


def test_weights_dir_override_serves_other_weights(tmp_path, monkeypatch, observation):
    """``CSO_WEIGHTS_DIR`` makes eval and the policy service use a training run's weights."""
    from cso_runtime.learned import registry

    unset_weights_env(monkeypatch)  # a CSO_WEIGHTS_FILE of the developer's would take cso's place
    torch.manual_seed(11)
    mine = GraphActorCritic().eval()
    save_checkpoint(tmp_path / "cso.pt", mine, GraphConfig(), "cso")
    monkeypatch.setenv(registry.WEIGHTS_DIR_ENV, str(tmp_path))
    assert registry.weights_path("cso") == tmp_path / "cso.pt" and not has_method("gnn-baseline")
    policy = make_policy("cso", MaskConfig(), seed=0)
    for name, value in mine.state_dict().items():
        torch.testing.assert_close(policy.model.state_dict()[name], value)


def test_weights_trained_with_the_sensor_serve_episodes_with_that_field_of_view(tmp_path, monkeypatch):
    """``<method>@fov<deg>.pt`` serves episodes whose sensor has that field of view (the shipped ``cso`` has
    one for the LIMO's 180-degree LiDAR); every other sensor gets ``<method>.pt``. eval, the policy service
    and the run records all take the file from ``weights_path``."""
    from cso_runtime.config import SensorConfig
    from cso_runtime.learned import registry
    from cso_runtime.learned.weights import weights_provenance

    unset_weights_env(monkeypatch)  # the shipped weights first, whatever the developer's environment gives
    lidar180, lidar360, depth = SensorConfig(), SensorConfig.preset("lidar", 360), SensorConfig.preset("depth")
    assert registry.weights_path("cso", lidar180).name == "cso@fov180.pt"
    assert registry.weights_path("cso", lidar360).name == registry.weights_path("cso", depth).name == registry.weights_path("cso").name == "cso.pt"
    assert registry.weights_path("cso-sm", lidar180).name == "cso-sm.pt"  # no 180-degree file for the ablations
    assert weights_provenance("cso", lidar180)["sha256"] != weights_provenance("cso", lidar360)["sha256"]

    torch.manual_seed(12)
    wide, narrow = GraphActorCritic().eval(), GraphActorCritic().eval()
    save_checkpoint(tmp_path / "cso.pt", wide, GraphConfig(), "cso")
    monkeypatch.setenv(registry.WEIGHTS_DIR_ENV, str(tmp_path))
    assert registry.weights_path("cso", lidar180) == tmp_path / "cso.pt"  # a training run's folder: its one file
    save_checkpoint(tmp_path / "cso@fov180.pt", narrow, GraphConfig(), "cso")
    for sensor, expected in ((lidar180, narrow), (lidar360, wide), (None, wide)):
        policy = make_policy("cso", MaskConfig(), seed=0, sensor=sensor)
        for name, value in expected.state_dict().items():
            torch.testing.assert_close(policy.model.state_dict()[name], value)


def test_the_shipped_180_degree_weights_are_the_recorded_training_run(monkeypatch):
    """``cso@fov180.pt`` is ``train --config configs/train.yaml`` with the 180-degree LiDAR: same graph and
    network as the recipe builds with that sensor, and its record names the command."""
    import json

    from cso_runtime.cli import training_args
    from cso_runtime.config import SensorConfig
    from cso_runtime.learned.weights import weights_path

    unset_weights_env(monkeypatch)  # the shipped weights, whatever folder or file the developer's environment gives
    config = Path(__file__).resolve().parents[1] / "configs" / "train.yaml"
    args = training_args(config, {"variant": "cso", "seed": 2}, ["dungeon_dir=null", "lidar_fov_deg=null"])
    path = weights_path("cso", SensorConfig())
    model, graph, ckpt = load_checkpoint(path)
    assert ckpt["variant"] == "cso" and args.env_config().exploration.sensor.fov_deg == 180.0
    assert graph == args.env_config().graph and model.config == build_model(args, torch.device("cpu")).config
    record = json.loads(path.with_suffix(".json").read_text())
    assert record["command"] == "cso-runtime train --config configs/train.yaml --variant cso --seed 2 --set lidar_fov_deg=null"
    assert record["args"]["lidar_fov_deg"] is None and record["args"]["seed"] == 2


def test_the_environment_is_registered_with_gymnasium():
    """``gymnasium.make`` builds the training environment by id; a step runs the robot to the chosen
    frontier and pays Eq. 6's reward, and the mask comes with every observation."""
    import gymnasium as gym

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", config=EnvConfig(max_steps=120))
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs) and info["action_mask"].any()
    action = int(np.flatnonzero(info["action_mask"])[0])
    obs, reward, terminated, truncated, info = env.step(action)
    assert env.observation_space.contains(obs) and np.isfinite(reward) and reward != 0.0
    assert isinstance(terminated, bool) and isinstance(truncated, bool)
    env.close()
    with pytest.raises(Exception, match="generated"):
        gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:huge:1:0")


def test_the_environments_spec_serialises_so_it_can_be_recorded_and_made_again():
    """``EnvSpec.to_json`` (what dataset and experiment tools record of an env) refused the spec: its entry point was
    the function itself, and Gymnasium serialises only an entry point given by name."""
    import gymnasium as gym
    from gymnasium.envs.registration import EnvSpec

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4")
    spec = EnvSpec.from_json(env.spec.to_json())
    assert spec.kwargs == {"scenes": "generated:small:1:4"}
    again = gym.make(spec)
    try:
        first, second = env.reset(seed=3)[0], again.reset(seed=3)[0]
        assert all(np.array_equal(first[k], second[k]) for k in first)
    finally:
        env.close()
        again.close()


# The positions relative to the robot and the distances have no bound (scenes have no size limit; every feature that
# has one is bounded: graph.FEATURE_RANGES); the checker's advice about infinite Box bounds does not apply to them.
@pytest.mark.filterwarnings("ignore:.*A Box observation space (minimum|maximum) value is:UserWarning")
def test_the_environment_passes_gymnasiums_checker_and_rejects_masked_actions_as_counted_no_ops():
    """Gymnasium's ``check_env`` steps with ``action_space.sample()``, as a random agent does: a masked
    action is accepted as Taxi's illegal move is (nothing happens, one step penalty, counted in ``info``), the
    same decision is asked again, and too many in a row truncate the episode instead of looping forever."""
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    config = EnvConfig(max_steps=120, invalid_action_limit=3)
    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", config=config).unwrapped
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=3)
    masked = int(np.flatnonzero(info["action_mask"] == 0)[0])
    again, reward, terminated, truncated, info2 = env.step(masked)
    assert all(np.array_equal(again[k], obs[k]) for k in obs) and np.array_equal(info2["action_mask"], info["action_mask"])
    assert reward == config.reward.r_step and not terminated and not truncated
    assert info2["invalid_action"] == masked and info2["invalid_actions"] == 1 and info2["steps"] == info["steps"]
    valid = int(np.flatnonzero(info["action_mask"])[0])
    _, reward, _, _, info3 = env.step(valid)  # a valid choice still acts, and resets the run of rejections
    assert reward != config.reward.r_step and info3["steps"] > info["steps"] and info3["invalid_actions"] == 1
    masked = int(np.flatnonzero(info3["action_mask"] == 0)[0])
    ends = [env.step(masked)[3] for _ in range(3)]
    assert ends == [False, False, True] and env.invalid_actions == 4
    with pytest.raises(RuntimeError, match="after the episode ended"):
        env.step(masked)
    env.reset(seed=4)
    assert env.invalid_actions == 0
    with pytest.raises(ValueError, match="outside the action space"):
        env.step(env.action_space.n)


def test_eval_weights_flag_uses_a_training_folder_and_records_which_weights(tmp_path, monkeypatch):
    """``eval --weights DIR`` serves the learned methods from DIR, and summary.json says which file (and
    its SHA-256) produced the results; a folder without the method's file, or no folder, exits 2."""
    import hashlib
    import json
    import subprocess
    import sys

    from typer.testing import CliRunner

    from cso_runtime.cli import app

    # --weights sets the weights folder in the environment, for the workers: monkeypatch takes it back out afterwards
    # (a folder left there would serve every later test's learned methods); none of the developer's is given to the commands.
    unset_weights_env(monkeypatch)
    torch.manual_seed(5)
    run = tmp_path / "run"
    run.mkdir()
    save_checkpoint(run / "cso.pt", GraphActorCritic().eval(), GraphConfig(), "cso")
    exe = [sys.executable, "-m", "cso_runtime.cli", "eval", "--maps", "generated:small:1:3", "--max-steps", "30"]
    env = dict(os.environ)
    ok = subprocess.run(exe + ["--method", "cso", "--weights", str(run), "--out", str(tmp_path / "mine")], capture_output=True, text=True, timeout=180, env=env)
    assert ok.returncode == 0, ok.stderr
    weights = json.loads((tmp_path / "mine" / "summary.json").read_text())["meta"]["weights"]["cso"]
    assert weights["path"] == str((run / "cso.pt").resolve()) and not weights["shipped"]
    assert weights["sha256"] == hashlib.sha256((run / "cso.pt").read_bytes()).hexdigest()
    shipped = subprocess.run(exe + ["--method", "cso", "--out", str(tmp_path / "shipped")], capture_output=True, text=True, timeout=180, env=env)
    assert shipped.returncode == 0, shipped.stderr
    weights = json.loads((tmp_path / "shipped" / "summary.json").read_text())["meta"]["weights"]["cso"]
    assert weights["shipped"] and weights["sha256"] != hashlib.sha256((run / "cso.pt").read_bytes()).hexdigest()
    # The refusals come before any episode: in this process (a command of its own costs seconds of torch imports).
    missing = CliRunner().invoke(app, [*exe[3:], "--method", "gnn-baseline", "--weights", str(run), "--out", str(tmp_path / "x")])
    assert missing.exit_code == 2 and "gnn-baseline.pt" in missing.stderr and str(run.resolve()) in missing.stderr
    nowhere = CliRunner().invoke(app, [*exe[3:], "--method", "cso", "--weights", str(tmp_path / "nowhere"), "--out", str(tmp_path / "y")])
    assert nowhere.exit_code == 2 and f"--weights {tmp_path / 'nowhere'}: no such file or folder" in " ".join(nowhere.stderr.split())
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_a_corrupt_weights_file_is_one_clear_error_before_anything_runs(tmp_path, monkeypatch):
    """A truncated, foreign or mismatched weights file: ``load_checkpoint`` names the file and the cause in
    one line (not torch's traceback, nor its advice to turn weights_only off); ``eval`` exits 2 before any
    episode; the launcher refuses a file that cannot be a checkpoint before it starts a process."""
    import subprocess
    import sys

    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import ConfigError
    from cso_runtime.learned import registry
    from cso_runtime.learned.weights import weights_file_problem
    from cso_runtime.run_profile import find_profile, load_profile

    unset_weights_env(monkeypatch)  # a CSO_WEIGHTS_FILE of the developer's would take cso's place
    good = tmp_path / "good.pt"
    save_checkpoint(good, GraphActorCritic().eval(), GraphConfig(), "cso")
    ckpt = torch.load(good, weights_only=True)
    first = next(iter(ckpt["state_dict"]))
    files = {
        "empty or truncated": b"",
        "not a torch file": bytes(range(256)) * 4,
        r"\(not a torch file\)": b"hello\n",  # a text file: torch's unpickler fails on its memo, "no 101 entry" it said
        "not a torch file of plain tensors": pickle.dumps({"a": 1}, protocol=4),  # and torch warned of the protocol
    }
    for why, content in files.items():
        (tmp_path / "bad.pt").write_bytes(content)
        with warnings.catch_warnings(record=True) as seen, pytest.raises(registry.CheckpointError, match=why) as err:
            warnings.simplefilter("always")
            load_checkpoint(tmp_path / "bad.pt")
        assert str(tmp_path / "bad.pt") in str(err.value) and "\n" not in str(err.value)
        assert not [str(w.message) for w in seen]
    torch.save({"state_dict": ckpt["state_dict"]}, tmp_path / "bad.pt")
    with pytest.raises(registry.CheckpointError, match="no 'graph' entry"):
        load_checkpoint(tmp_path / "bad.pt")
    torch.save({**ckpt, "state_dict": {**ckpt["state_dict"], first: torch.zeros(3)}}, tmp_path / "bad.pt")
    with pytest.raises(registry.CheckpointError, match="RuntimeError"):
        load_checkpoint(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")

    run = tmp_path / "run"
    run.mkdir()
    (run / "cso.pt").write_bytes(bytes(range(256)) * 4)
    monkeypatch.setenv(registry.WEIGHTS_DIR_ENV, str(run))
    assert "not a torch checkpoint" in weights_file_problem("cso")
    with pytest.raises(ConfigError, match="not a torch checkpoint"):
        load_profile(str(find_profile("lockstep")), {"method": "cso"})
    monkeypatch.setenv(registry.WEIGHTS_DIR_ENV, str(tmp_path))
    (tmp_path / "cso.pt").write_bytes(good.read_bytes())
    assert weights_file_problem("cso") == ""
    monkeypatch.delenv(registry.WEIGHTS_DIR_ENV)

    exe = [sys.executable, "-m", "cso_runtime.cli", "eval", "--maps", "generated:small:2:3", "--max-steps", "30", "--method", "greedy-dist,cso"]
    bad = subprocess.run(exe + ["--weights", str(run), "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "not a cso-runtime checkpoint" in bad.stderr and "Traceback" not in bad.stderr
    assert str(run / "cso.pt") in " ".join(bad.stderr.split())  # the message may wrap the path
    assert not (tmp_path / "out").exists()
    # Another variant's weights under the method's name: refused, not run and labelled as that method.
    # (In this process: the same refusal before any episode, without a command's seconds of torch imports.)
    save_checkpoint(run / "cso.pt", GraphActorCritic().eval(), GraphConfig(), "gnn-baseline")
    refused = CliRunner().invoke(app, [*exe[3:], "--weights", str(run), "--out", str(tmp_path / "out")])
    assert refused.exit_code == 2 and "holds weights trained as 'gnn-baseline', not 'cso'" in " ".join(refused.stderr.split()), refused.stderr
    assert not (tmp_path / "out").exists()


def test_cluster_size_feature_is_optional_and_round_trips(tmp_path, observation):
    """``cluster_size_feature`` adds one node column (each cluster's length, scale-free); graphs and
    networks without it keep six columns. A checkpoint with it reloads with
    it and decides as before."""
    plain, sized = GraphConfig(), GraphConfig(use_cluster_size=True)
    g0, g1 = build_graph(observation, plain), build_graph(observation, sized)
    nf = min(len(observation.clusters), plain.max_frontier_nodes)
    assert g0["nodes"].shape[1] == 6 and g1["nodes"].shape[1] == 7
    np.testing.assert_array_equal(g1["nodes"][:, :6], g0["nodes"])
    sizes = np.array([c.size_m for c in observation.clusters[:nf]])
    np.testing.assert_allclose(g1["nodes"][:nf, 6], np.log1p(sizes / plain.distance_scale_m), rtol=1e-6)
    assert (g1["nodes"][nf:, 6] == 0).all() and sizes.min() < sizes.max()
    args = Args(cluster_size_feature=True)
    assert args.env_config().graph == sized and build_model(args, torch.device("cpu")).config.node_features == 7
    assert build_model(Args(), torch.device("cpu")).config.node_features == 6
    torch.manual_seed(2)
    model = GraphActorCritic(NetworkConfig(node_features=7)).eval()
    save_checkpoint(tmp_path / "cso.pt", model, sized, "cso")
    loaded, graph, _ = load_checkpoint(tmp_path / "cso.pt")
    assert graph == sized and loaded.config.node_features == 7
    a, b = (LearnedPolicy("cso", m, sized, MaskConfig()) for m in (model, loaded))
    assert a.select(observation) == b.select(observation)


def test_unknown_area_feature_counts_unexplored_cells_around_each_cluster(observation):
    """``unknown_area_feature`` adds one node column: the unexplored fraction of a square window around each
    cluster's centroid (a brute-force count here), 0 on path nodes; the other columns are unchanged."""
    base, extra = GraphConfig(use_cluster_size=True), GraphConfig(use_cluster_size=True, use_unknown_area=True, unknown_window_m=3.0)
    g0, g1 = build_graph(observation, base), build_graph(observation, extra)
    assert node_features(extra)[-1] == "unknown" and g1["nodes"].shape[1] == g0["nodes"].shape[1] + 1
    np.testing.assert_array_equal(g1["nodes"][:, :-1], g0["nodes"])
    nf = min(len(observation.clusters), extra.max_frontier_nodes)
    geo, unknown = observation.geometry, ~observation.explored
    half = int(round(3.0 / geo.resolution_m / 2))
    expected = []
    for c in observation.clusters[:nf]:
        iy, ix = (int(v) for v in geo.world_to_cell(*c.centroid_xy_m))
        window = unknown[max(iy - half, 0) : iy + half + 1, max(ix - half, 0) : ix + half + 1]
        expected.append(window.sum() / (2 * half + 1) ** 2)
    np.testing.assert_allclose(g1["nodes"][:nf, -1], expected, rtol=1e-6)
    assert 0 < min(expected) < max(expected) <= 1 and (g1["nodes"][nf:, -1] == 0).all()
    args = Args(cluster_size_feature=True, unknown_area_feature=True)
    assert args.env_config().graph.use_unknown_area and build_model(args, torch.device("cpu")).config.node_features == 8


def test_training_sensor_follows_the_config():
    """Training episodes use the configured sensor (the tables evaluate with a 360-degree LiDAR)."""
    assert Args().env_config().exploration.sensor.fov_deg == 180.0
    assert Args(lidar_fov_deg=360).env_config().exploration.sensor.fov_deg == 360.0
    depth = Args(sensor="depth").env_config().exploration.sensor
    assert depth.range_max_m == 3.0 and depth.fov_deg == 79.0


def test_egocentric_frame_rotates_node_positions_into_the_robot_frame(observation):
    """``egocentric_frame``: dx, dy are in the robot's frame (x forward, y left); every other feature and
    the graph's structure are the same as with the map's axes."""
    from cso_runtime.geometry import Pose2D

    p = observation.pose
    turned = dataclasses.replace(observation, pose=Pose2D(p.x_m, p.y_m, math.pi / 2))  # facing +y
    axes, ego = build_graph(turned, GraphConfig()), build_graph(turned, GraphConfig(egocentric=True))
    n = int(axes["node_valid"].sum())
    assert n > 2
    # facing +y: a node at +y on the map is ahead (+x), a node at +x on the map is to the right (-y)
    np.testing.assert_allclose(ego["nodes"][:n, 0], axes["nodes"][:n, 1], atol=1e-6)
    np.testing.assert_allclose(ego["nodes"][:n, 1], -axes["nodes"][:n, 0], atol=1e-6)
    np.testing.assert_array_equal(ego["nodes"][:, 2:], axes["nodes"][:, 2:])
    for key in ("neighbours", "neighbour_valid", "edges", "node_valid", "robot"):
        np.testing.assert_array_equal(ego[key], axes[key])
    assert Args(egocentric_frame=True).env_config().graph.egocentric and not Args().env_config().graph.egocentric


def test_geodesic_edge_bound_lengthens_edges_to_the_geodesic_lower_bound(observation):
    """``geodesic_edge_bound``: an edge between non-robot nodes is max(Euclidean, |l_i - l_j|), never
    shorter than with Euclidean lengths; robot edges, neighbours and node features are unchanged."""
    plain, bound = build_graph(observation, GraphConfig()), build_graph(observation, GraphConfig(geodesic_edge_bound=True))
    n, robot, knn = int(plain["node_valid"].sum()), int(plain["robot"]), GraphConfig().knn
    assert n > 3
    for key in ("nodes", "neighbours", "neighbour_valid", "node_valid", "robot"):
        np.testing.assert_array_equal(bound[key], plain[key])
    np.testing.assert_array_equal(bound["edges"][:, knn], plain["edges"][:, knn])  # the robot column: geodesic already
    np.testing.assert_array_equal(bound["edges"][robot], plain["edges"][robot])
    scale = GraphConfig().distance_scale_m
    geo = np.expm1(plain["nodes"][:n, 5].astype(float)) * scale  # the node's geodesic feature, back in metres
    valid = plain["neighbour_valid"][:robot, :knn]
    nbr = plain["neighbours"][:robot, :knn]
    expected = np.maximum(plain["edges"][:robot, :knn, 0].astype(float), np.abs(geo[:robot, None] - geo[nbr]) / scale)
    np.testing.assert_allclose(bound["edges"][:robot, :knn, 0][valid], expected[valid], rtol=1e-5, atol=1e-6)
    assert (bound["edges"][:robot, :knn, 0] >= plain["edges"][:robot, :knn, 0]).all()
    assert (bound["edges"][:robot, :knn, 0][valid] > plain["edges"][:robot, :knn, 0][valid] + 1e-6).any()
    assert Args(geodesic_edge_bound=True).env_config().graph.geodesic_edge_bound and not Args().env_config().graph.geodesic_edge_bound


def test_distance_scale_divides_positions_and_distances(observation):
    """``distance_scale_m`` (a training argument): twice the scale halves dx, dy and the edges' l / scale,
    and the log features become log(1 + l / 20 m); labels, entropy and neighbours are unchanged."""
    ten, twenty = build_graph(observation, GraphConfig()), build_graph(observation, GraphConfig(distance_scale_m=20.0))
    n = int(ten["node_valid"].sum())
    assert n > 2
    np.testing.assert_allclose(twenty["nodes"][:n, 0:2], ten["nodes"][:n, 0:2] / 2, atol=1e-6)
    np.testing.assert_array_equal(twenty["nodes"][:, 2:5], ten["nodes"][:, 2:5])
    geo_m = np.expm1(ten["nodes"][:n, 5].astype(float)) * 10.0
    np.testing.assert_allclose(twenty["nodes"][:n, 5], np.log1p(geo_m / 20.0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(twenty["edges"][..., 0], ten["edges"][..., 0] / 2, atol=1e-6)
    for key in ("neighbours", "neighbour_valid", "node_valid", "robot"):
        np.testing.assert_array_equal(twenty[key], ten[key])
    assert Args(distance_scale_m=20.0).env_config().graph.distance_scale_m == 20.0
    assert Args().env_config().graph.distance_scale_m == GraphConfig().distance_scale_m


def test_rollout_teacher_takes_the_try_that_finishes_first_without_touching_the_episode():
    """``rollout_choice`` finishes the episode from each candidate with the base policy on a copy and keeps
    the fewest steps; the explorer it copies is left as it was. In the env the teacher stays in the mask."""
    greedy = make_policy("greedy-dist")
    explorer = Explorer(KinematicSimulator(rooms_plan(3)))
    obs = explorer.observe()
    explorer.apply_goal(obs, greedy.select(obs))
    while explorer.decision_reason() is None:
        explorer.advance()
    explorer.handle_reason(explorer.decision_reason())
    obs = explorer.observe()
    reachable = np.flatnonzero(np.isfinite(obs.goal_distance_m))
    assert len(reachable) >= 2
    candidates = reachable[np.argsort(obs.goal_distance_m[reachable])][:3]
    steps_before, goal_before = explorer.steps, explorer.goal
    finish = []
    for c in candidates:
        trial = copy.deepcopy(explorer)
        trial.apply_goal(obs, goal_of(obs, int(c)))
        trial.advance()
        finish.append(trial.run(greedy).steps)
    chosen = rollout_choice(explorer, obs, candidates, greedy)
    assert chosen == candidates[int(np.argmin(finish))]
    assert rollout_choice(explorer, obs, candidates[:1], greedy) == candidates[0]
    assert (explorer.steps, explorer.goal) == (steps_before, goal_before)

    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    for _ in range(3):
        a, outcome_steps = env.teacher_label("rollout")
        tried = np.flatnonzero(np.isfinite(outcome_steps))
        assert 1 <= len(tried) <= 3 and info["action_mask"][tried].all() and a in tried
        assert outcome_steps[a] == outcome_steps[tried].min()  # the choice is the try that finished first
        assert env.teacher_action("rollout") == a  # deterministic on the same state
        _, _, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break
    Args(warm_start_teacher="rollout").validate()


def test_soft_targets_weigh_each_tried_cluster_by_how_soon_its_episode_ended():
    """softmax(-(steps - best) / T) over the tried clusters; untried ones get nothing; rows without outcomes
    (score-based teachers) and T = 0 give the one-hot choice."""
    from cso_runtime.learned.ppo import soft_targets

    inf = math.inf
    steps = torch.tensor([[100.0, 102.0, inf, 110.0], [inf, inf, inf, inf]])
    actions = torch.tensor([0, 2])
    t = soft_targets(steps, actions, 2.0)
    w = torch.tensor([1.0, math.exp(-1.0), math.exp(-5.0)])
    torch.testing.assert_close(t[0], torch.tensor([w[0], w[1], 0.0, w[2]]) / w.sum())
    torch.testing.assert_close(t[1], torch.tensor([0.0, 0.0, 1.0, 0.0]))
    torch.testing.assert_close(soft_targets(steps, actions, 0.0), torch.nn.functional.one_hot(actions, 4).float())


def test_teacher_data_round_trips_through_a_file_and_feeds_the_warm_start(tmp_path):
    """Collected once, saved, loaded (several files concatenated) and imitated by ``train`` without collecting
    again; a file that is not teacher data is a clear error."""
    from cso_runtime.learned.ppo import TeacherData, collect_teacher, make_vector_env

    args = Args(num_envs=1, max_steps=100)
    envs = make_vector_env(args, [rooms_plan(2)])
    try:
        data = collect_teacher(envs, 4, 0.98, seed=0, teacher="rollout")
    finally:
        envs.close()
    assert np.isfinite(data.outcome_steps).any(axis=1).all()  # every rollout decision tried something
    data.save(tmp_path / "a.npz")
    both = TeacherData.load([tmp_path / "a.npz", tmp_path / "a.npz"])
    assert len(both) == 2 * len(data)
    np.testing.assert_array_equal(both.actions[len(data):], data.actions)
    np.testing.assert_array_equal(both.outcome_steps[: len(data)], data.outcome_steps)
    for k, v in data.graphs.items():
        np.testing.assert_array_equal(both.graphs[k][len(data):], v)
    np.savez(tmp_path / "bad.npz", something=np.zeros(3))
    with pytest.raises(ValueError, match="not a teacher-data file"):
        TeacherData.load([tmp_path / "bad.npz"])
    with pytest.raises(ValueError, match="no such file"):
        Args(warm_start_data=[str(tmp_path / "missing.npz")]).validate()

    run = Args(num_envs=1, num_steps=4, num_minibatches=1, total_decisions=4, max_steps=100, warm_start_epochs=2,
               warm_start_soft_steps=2.0, warm_start_data=[str(tmp_path / "a.npz")], out_dir=str(tmp_path / "run"), progress=False)
    record = train(run, log=lambda _m: None, plans=[rooms_plan(2)])
    assert record["warm_start_decisions"] == len(data)
    assert (tmp_path / "run" / "cso_warm.pt").is_file()
    collected = dataclasses.replace(run, warm_start_data=[], warm_start_decisions=4, out_dir=str(tmp_path / "run2"))
    assert train(collected, log=lambda _m: None, plans=[rooms_plan(2)])["warm_start_decisions"] == 4
    assert len(TeacherData.load([tmp_path / "run2" / "teacher_data.npz"])) == 4  # kept for the next run


def test_collect_teacher_command_writes_a_file_that_train_reads(tmp_path):
    """``cso-runtime collect-teacher`` runs workers in their own processes and writes teacher data that loads;
    a bad setting is refused before anything starts."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned.ppo import TeacherData

    out = tmp_path / "teacher.npz"
    scenes = ["--set", "dungeon_dir=null", "--set", "generated=[generated:small:2:0]", "--set", "max_steps=60"]
    result = CliRunner().invoke(app, ["collect-teacher", "--out", str(out), "--teacher", "greedy-dist", "--workers", "2",
                                      "--decisions", "6", "--config", str(tmp_path / "none.yaml"), *scenes])
    assert result.exit_code == 2 and "config file not found" in result.output
    result = CliRunner().invoke(app, ["collect-teacher", "--out", str(out), "--teacher", "greedy-dist", "--workers", "2",
                                      "--decisions", "6", "--seed", "3", *scenes])
    assert result.exit_code == 0, result.output
    assert "done: 6 greedy-dist decisions" in result.output and "exists" not in result.output
    data = TeacherData.load([out])
    assert len(data) == 6 and data.masks[np.arange(6), data.actions].all()
    data.save(tmp_path / "t5.txt")  # the very name given (numpy alone would write t5.txt.npz)
    assert (tmp_path / "t5.txt").is_file() and len(TeacherData.load([tmp_path / "t5.txt"])) == 6
    again = CliRunner().invoke(app, ["collect-teacher", "--out", str(out), "--teacher", "greedy-dist", "--workers", "1", "--decisions", "2", *scenes])
    assert again.exit_code == 0 and f"note: {out} exists (an earlier collection?); this one replaces it" in again.output, again.output
    bad = CliRunner().invoke(app, ["collect-teacher", "--out", str(out), "--teacher", "nobody", *scenes])
    assert bad.exit_code == 2 and "unknown warm_start_teacher" in bad.output
    below_a_file = out / "more.npz"  # its folder cannot be made: said before the rollouts, not after them
    bad = CliRunner().invoke(app, ["collect-teacher", "--out", str(below_a_file), "--teacher", "greedy-dist", *scenes])
    assert bad.exit_code == 2 and "cannot create the folder" in bad.output and "decisions" not in bad.output
    # A folder as --out (as record --out DIR/ takes one): said before the rollouts; it was a traceback after them,
    # the collected decisions lost, when the file was renamed over the folder.
    bad = CliRunner().invoke(app, ["collect-teacher", "--out", str(tmp_path), "--teacher", "greedy-dist", *scenes])
    assert bad.exit_code == 2 and f"--out {tmp_path} is a folder; give the file to write" in bad.output and "decisions" not in bad.output, bad.output
    bad = CliRunner().invoke(app, ["train", "--out", str(below_a_file), *scenes])
    assert bad.exit_code == 2 and f"out_dir {below_a_file}: cannot create the folder" in bad.output


def test_train_refuses_what_it_cannot_use_before_it_starts(tmp_path, monkeypatch):
    """A checkpoint, weights, teacher data, device or network shape that training cannot use is one error
    line and exit 2 before any environment starts, not a traceback from torch later. The device case runs on any
    host: torch's view of CUDA is set here (no GPU, then one GPU for ``cuda:1``)."""
    import torch
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned.registry import weights_path

    fake = tmp_path / "fake.png"
    fake.write_bytes(b"\x89PNG\r\n\x1a\n not a checkpoint")
    shipped = weights_path("cso", SensorConfig.preset("lidar", 360))
    cases = [
        (["--resume", str(tmp_path / "nosuch.pt")], "--resume .*nosuch.pt: no such file"),
        (["--resume", str(fake)], "not a checkpoint torch can read"),
        # A run's folder, as eval --weights takes it: named as such, not "cut short or corrupt (IsADirectoryError)".
        (["--resume", str(tmp_path)], f"--resume {re.escape(str(tmp_path))}: a folder; it holds no checkpoint.pt; give the checkpoint.pt"),
        (["--resume", str(shipped)], "not a training checkpoint .*--init-from"),
        (["--init-from", str(tmp_path / "nosuch.pt")], "--init-from .*nosuch.pt: no such file"),
        (["--init-from", str(fake)], "--init-from .*fake.png: not a cso-runtime checkpoint"),
        (["--init-from", str(shipped.with_name("gnn-baseline.pt"))], "holds variant 'gnn-baseline', not 'cso'"),
        (["--set", "sensor=sonar"], "sensor: unknown sensor preset 'sonar'"),
        (["--set", "hidden=0"], r"hidden must be in \[1, 4,096\] \(MAX_NETWORK_WIDTH\), got 0"),
        (["--set", "heads=3"], "hidden divisible by heads; got hidden 32, heads 3"),
        (["--set", f"warm_start_data=[{fake}]"], "fake.png: not a teacher-data file"),
    ]
    cases.append((["--device", "cuda"], "device cuda: .*; train with --device cpu"))
    scenes = ["--set", "dungeon_dir=null", "--set", "generated=[generated:small:2:1000]", "--out", str(tmp_path / "run")]
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for extra, said in cases:
        r = CliRunner().invoke(app, ["train", *scenes, *extra])
        assert r.exit_code == 2 and re.search(f"error: .*{said}", r.output) and "training cso on" not in r.output, (extra, r.output[-2000:])
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    r = CliRunner().invoke(app, ["train", *scenes, "--device", "cuda:1"])
    assert r.exit_code == 2 and re.search(r"error: .*device cuda:1: only 1 CUDA device\(s\) here; train with --device cpu", r.output), r.output[-2000:]


def test_train_outside_the_repository_uses_the_packaged_recipe_and_refuses_missing_plans(tmp_path, monkeypatch):
    """Run where there is no ``configs/train.yaml`` (an installed package), ``train`` reads the packaged copy of the
    recipe; a plan folder that is not there, a validation set or a bad generated spec is one error line and exit 2
    before anything is set up (they used to be a traceback from inside the trainer)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import PACKAGED_TRAIN_CONFIG, app

    repo_recipe = Path(__file__).resolve().parents[1] / "configs" / "train.yaml"
    assert PACKAGED_TRAIN_CONFIG.read_text() == repo_recipe.read_text()
    monkeypatch.chdir(tmp_path)
    out = ["--out", str(tmp_path / "run")]
    result = CliRunner().invoke(app, ["train", *out])  # the recipe's dungeon_dir exists on the build machine only
    assert result.exit_code == 2, result.output
    assert "note: no configs/train.yaml here; using the packaged" in result.output
    assert "dungeon_dir ../shared/maps/dungeon/train: no such folder" in result.output and "--dungeon-dir" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "run").exists()
    validation = tmp_path / "maps" / "easy"
    validation.mkdir(parents=True)
    result = CliRunner().invoke(app, ["train", "--dungeon-dir", str(validation), *out])
    assert result.exit_code == 2 and "looks like a validation set" in result.output
    result = CliRunner().invoke(app, ["collect-teacher", "--out", str(tmp_path / "t.npz"), "--set", "dungeon_dir=null",
                                      "--set", "generated=[generated:huge:1:0]"])
    assert result.exit_code == 2 and "generated scale must be one of small, middle, large, super_large" in result.output


def test_distance_prior_starts_the_actor_at_greedy_dist_and_round_trips(tmp_path, observation):
    """With ``distance_prior`` the untrained actor's argmax is greedy-dist's goal under the same masks
    (its learned part starts at zero), the trace keeps the prior, and a checkpoint restores it."""
    torch.manual_seed(2)
    model = GraphActorCritic(NetworkConfig(distance_prior=20.0)).eval()
    config = GraphConfig()
    masks = MaskConfig()
    policy = LearnedPolicy("cso", model, config, masks)
    mask = policy.action_mask(observation)
    assert mask.sum() >= 2, "the decision must offer a choice"
    masked_distance = np.where(mask[: len(observation.clusters)], observation.goal_distance_m, np.inf)
    probs = policy.probabilities(observation, mask)
    assert int(np.argmax(probs)) == int(np.argmin(masked_distance))
    assert probs[~mask].sum() == 0.0 and probs.max() < 1.0  # a sampling policy, not a hard rule
    eager = model.masked_logits(to_torch(build_graph(observation, config), batch=True), torch.as_tensor(mask).unsqueeze(0))
    torch.testing.assert_close(torch.softmax(eager, -1)[0], torch.as_tensor(probs), atol=1e-5, rtol=1e-4)
    # without the prior the same untrained weights score frontiers by noise, not by distance
    plain = GraphActorCritic(NetworkConfig()).eval()
    plain.load_state_dict(model.state_dict())
    plain_probs = LearnedPolicy("cso", plain, config, masks).probabilities(observation, mask)
    assert np.allclose(plain_probs[mask], 1.0 / mask.sum())
    save_checkpoint(tmp_path / "prior.pt", model, config, "cso")
    loaded, _, _ = load_checkpoint(tmp_path / "prior.pt")
    assert loaded.config.distance_prior == 20.0
    np.testing.assert_allclose(LearnedPolicy("cso", loaded, config, masks).probabilities(observation, mask), probs, atol=1e-6)
    with pytest.raises(ValueError, match="distance_prior"):
        Args(distance_prior=-1.0).validate()


def test_a_dead_environment_process_stops_training_with_a_clear_error_not_a_hang():
    """An environment process killed mid-training (as by the OOM killer) is noticed while its answer is
    awaited: ``EnvWorkerDied`` names it, and closing terminates the others. Workers ignore Ctrl-C."""
    import functools
    import signal

    import gymnasium as gym

    envs = WatchedAsyncVectorEnv([functools.partial(gym.make, "CartPole-v1")] * 2, context="spawn")
    try:
        envs.reset(seed=0)
        os.kill(envs.processes[0].pid, signal.SIGINT)  # Ctrl-C reaches the workers too: only the parent acts on it
        envs.step(np.zeros(2, dtype=np.int64))
        assert envs.processes[0].is_alive()
        victim = envs.processes[1]
        os.kill(victim.pid, signal.SIGKILL)
        victim.join(10)
        with pytest.raises(EnvWorkerDied, match=r"environment process 1 \(pid \d+\) died with exit code -9"):
            envs.step(np.zeros(2, dtype=np.int64))
    finally:
        envs.close()
    assert envs.closed and not any(p.is_alive() for p in envs.processes)


def test_closing_environment_processes_that_never_answer_nor_end_is_bounded_and_kills_them():
    """Closing waited without a bound: for a step under way (polling for as long as its process lived), for each
    process's answer to ``close``, and on joining a process that ignored SIGTERM. Processes stuck in a step that ignore
    SIGTERM are now killed: ``close`` ends within ``close_grace_s`` per stage (the step, SIGTERM, SIGKILL)."""
    import signal
    import threading

    from tests.stuck_env import StuckEnv

    envs = WatchedAsyncVectorEnv([StuckEnv] * 2, context="spawn")
    envs.close_grace_s = 0.5
    pids = [p.pid for p in envs.processes]
    closing = threading.Thread(target=envs.close, name="close-stuck-envs", daemon=True)
    try:
        envs.reset(seed=0)
        envs.step_async(np.zeros(2, dtype=np.int64))  # never answered
        started = time.monotonic()
        closing.start()
        closing.join(3 * envs.close_grace_s + 10)
        assert not closing.is_alive(), f"close still waits on its stuck environment processes after {time.monotonic() - started:.0f} s"
        assert envs.closed and not any(p.is_alive() for p in envs.processes)
        assert [p.exitcode for p in envs.processes] == [-signal.SIGKILL] * 2  # SIGTERM ignored, then killed
    finally:
        for pid in pids:  # where close hung (before the fix), the test leaves no process behind
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def test_a_constructor_stopped_while_its_environment_processes_start_stops_them():
    """Ctrl-C while ``WatchedAsyncVectorEnv``'s constructor waits on its processes (here for ever: they never finish
    building their env, and ignore SIGTERM) leaves no object to close: the constructor stops them itself, within
    ``close_grace_s`` per stage, where the half-built object's ``__del__`` would join them with no bound."""
    import multiprocessing
    import signal
    import threading

    from tests.conftest import wait_for
    from tests.stuck_env import StuckInitEnv

    before = set(multiprocessing.active_children())
    started: list = []

    def ignores_sigterm(pid: int) -> bool:  # its env under way: SIGTERM ignored (Linux's /proc)
        with contextlib.suppress(OSError, StopIteration, ValueError):
            status = Path(f"/proc/{pid}/status").read_text().splitlines()
            return bool(int(next(line for line in status if line.startswith("SigIgn:")).split()[1], 16) & (1 << (signal.SIGTERM - 1)))
        return False

    def interrupt_once_both_wait() -> None:
        wait_for(lambda: len(set(multiprocessing.active_children()) - before) == 2, 60, "the 2 environment processes to start")
        started.extend(set(multiprocessing.active_children()) - before)
        wait_for(lambda: all(ignores_sigterm(p.pid) for p in started), 60, "the environment processes to build their env")
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    interrupter = threading.Thread(target=interrupt_once_both_wait, daemon=True)
    saved_grace = WatchedAsyncVectorEnv.close_grace_s
    WatchedAsyncVectorEnv.close_grace_s = 0.5
    try:
        interrupter.start()
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            WatchedAsyncVectorEnv([StuckInitEnv] * 2, context="spawn")
        stopped_s = time.monotonic() - t0
        interrupter.join(10)
        assert len(started) == 2 and not any(p.is_alive() for p in started), started
        assert [p.exitcode for p in started] == [-signal.SIGKILL] * 2  # SIGTERM ignored, then killed
        assert stopped_s < 60 + 3 * WatchedAsyncVectorEnv.close_grace_s + 10
    finally:
        WatchedAsyncVectorEnv.close_grace_s = saved_grace
        signal.signal(signal.SIGINT, previous)
        for process in started:
            if process.is_alive():
                process.kill()


def test_ensemble_of_benchmarks_averages_the_members_probabilities(tmp_path, observation):
    """benchmarks/eval_ensemble.py: the mean of the members' masked probabilities (one member: itself)."""
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    torch.manual_seed(7)
    members = [GraphActorCritic(NetworkConfig(hidden=32, heads=2, layers=1)).eval() for _ in range(2)]
    mask_cfg = MaskConfig(use_valid_distance=False, use_stuck=False)
    singles = [LearnedPolicy("cso", m, GraphConfig(), mask_cfg) for m in members]
    mask = singles[0].action_mask(observation)
    probs = [p.probabilities(observation, mask) for p in singles]
    assert not np.allclose(probs[0], probs[1])
    both = ensemble.EnsemblePolicy(members, singles[0], seed=0)
    np.testing.assert_allclose(both.probabilities(observation, mask), (probs[0] + probs[1]) / 2, rtol=1e-5, atol=1e-7)
    alone = ensemble.EnsemblePolicy(members[:1], singles[0], seed=0)
    np.testing.assert_allclose(alone.probabilities(observation, mask), probs[0], rtol=1e-5, atol=1e-7)
    assert (both.probabilities(observation, mask)[~mask] == 0).all()


def test_training_episodes_use_the_configured_valid_distance_bound():
    """``beta_far_m`` reaches the training episodes' masks (only where the variant uses Eq. 5's mask)."""
    assert Args(variant="cso").env_config().exploration.masks.beta_far_m == 2.0
    masks = Args(variant="cso", beta_far_m=1.5).env_config().exploration.masks
    assert masks.beta_far_m == 1.5 and masks.use_valid_distance and masks.use_stuck
    assert not Args(variant="cso-sm", beta_far_m=1.5).env_config().exploration.masks.use_valid_distance
    with pytest.raises(ValueError, match="beta_far_m"):
        Args(variant="cso", beta_far_m=0.0).validate()


def test_encoder_learning_rate_scale_gives_the_encoder_its_own_annealed_rate(tmp_path):
    """``encoder_lr_scale``: the node and edge layers and the attention rounds learn at that multiple of the
    heads' rate, both annealed; scale 1 keeps one group, as every earlier checkpoint has."""
    model = build_model(Args(), torch.device("cpu"))
    assert len(parameter_groups(model, Args())) == 1
    heads, encoder = parameter_groups(model, Args(encoder_lr_scale=3.0, learning_rate=1e-4))
    assert {id(p) for p in heads["params"]}.isdisjoint(id(p) for p in encoder["params"])
    assert len(heads["params"]) + len(encoder["params"]) == len(list(model.parameters()))
    assert {id(p) for p in model.layers.parameters()} <= {id(p) for p in encoder["params"]}
    assert {id(p) for p in model.actor.parameters()} <= {id(p) for p in heads["params"]}
    assert encoder["lr"] == pytest.approx(3e-4)
    args = Args(
        variant="cso", out_dir=str(tmp_path), seed=0, total_decisions=64, num_envs=2, num_steps=16, num_minibatches=2,
        max_steps=40, encoder_lr_scale=3.0, learning_rate=1e-4, progress=False,
    )
    train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=False)["optimizer"]["param_groups"]
    assert [g["lr_scale"] for g in saved] == [1.0, 3.0]
    assert saved[1]["lr"] == pytest.approx(3 * saved[0]["lr"]) and saved[0]["lr"] == pytest.approx(1e-4 / 2)  # annealed at update 2 of 2
    with pytest.raises(ValueError, match="encoder_lr_scale"):
        Args(encoder_lr_scale=0.0).validate()


def test_a_resumed_training_logs_each_update_once_and_counts_its_time_before_the_resume(tmp_path, monkeypatch):
    """A run that crashed after logging an update its checkpoint does not hold: ``--resume`` runs that update
    again, so the log keeps each update once (the curve would plot it twice), and ``wall_s`` goes on from the
    training time the checkpoint holds instead of starting again at 0; so does the bar's decisions per second,
    which divided every decision so far by this session's time alone (ten times the real rate on a resume)."""
    import csv

    from cso_runtime.learned import ppo

    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40,
              "checkpoint_every": 1, "progress": False}  # fmt: skip
    train(Args(total_decisions=24, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    log_path = tmp_path / "cso_log.csv"
    rows = list(csv.DictReader(log_path.open()))
    assert [r["update"] for r in rows] == ["1", "2", "3"]
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ckpt["update"] == 3 and ckpt["wall_s"] >= float(rows[-1]["wall_s"]) > 0
    with log_path.open("a", newline="") as fh:  # the crashed run's update 4, logged after its last checkpoint
        csv.DictWriter(fh, fieldnames=list(rows[0])).writerow({**rows[-1], "update": "4"})
    ckpt["wall_s"] = 1000.0  # as if the first run had trained for 1000 s
    torch.save(ckpt, tmp_path / "checkpoint.pt")
    rates: list[tuple[int, float]] = []
    stats = ppo.progress_stats
    monkeypatch.setattr(ppo, "progress_stats", lambda recent, decisions, wall_s: rates.append((decisions, wall_s)) or stats(recent, decisions, wall_s))
    record = train(Args(total_decisions=32, resume=str(tmp_path / "checkpoint.pt"), **{**common, "progress": True}), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert [d for d, _ in rates] == [32] and rates[0][1] >= 1000.0  # 32 decisions in 1000 s and more, not in this session's second
    resumed = list(csv.DictReader(log_path.open()))
    assert [r["update"] for r in resumed] == ["1", "2", "3", "4"] and resumed[:3] == rows
    assert float(resumed[3]["wall_s"]) >= 1000.0 and record["wall_time_s"] >= 1000.0
    with pytest.raises(ValueError, match="a checkpoint of cso, not of cso-sm"):  # the same shapes, other masks
        train(Args(**{**common, "variant": "cso-sm"}, total_decisions=40, resume=str(tmp_path / "checkpoint.pt")), log=lambda _msg: None, plans=[rooms_plan(2)])
    with pytest.raises(ValueError, match=r"max_path_nodes must be in \[1, 10,000\] \(MAX_GRAPH_NODES\), got 0"):
        Args(max_path_nodes=0).validate()


@pytest.mark.filterwarnings("ignore:.*A Box observation space (minimum|maximum) value is:UserWarning")
@pytest.mark.filterwarnings("ignore:.*The HumanRendering wrapper is being applied:UserWarning")  # what the test asks for
def test_gymnasium_make_adds_its_render_wrappers_for_the_modes_built_on_rgb_array():
    """``gymnasium.make`` gives ``render_mode="rgb_array_list"`` (a list of the frames since the last render) and
    ``"human"`` (a window) to an env that renders ``rgb_array``, reading the entry point's ``metadata``: the
    registered function had none, so both were passed on to the env, which refused them."""
    import gymnasium as gym

    def wrappers(env: gym.Env) -> list[str]:
        names = []
        while isinstance(env, gym.Wrapper):
            names.append(type(env).__name__)
            env = env.env
        return names

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", render_mode="rgb_array_list")
    _, info = env.reset(seed=3)
    env.step(int(np.flatnonzero(info["action_mask"])[0]))
    frames = env.render()
    assert "RenderCollection" in wrappers(env) and len(frames) == 2 and frames[0].ndim == 3
    env.close()
    human = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", render_mode="human")
    assert "HumanRendering" in wrappers(human) and human.unwrapped.render_mode == "rgb_array"  # the window opens at render


@pytest.mark.filterwarnings("ignore:.*A Box observation space (minimum|maximum) value is:UserWarning")
@pytest.mark.filterwarnings("ignore:.*render_mode='ansi' that is not in the possible render_modes:UserWarning")  # refused below
def test_rgb_array_render_shows_the_map_the_path_the_goals_by_mask_and_the_robot():
    """``render_mode="rgb_array"`` (Gymnasium's checker runs its render checks): an upright image of M_t, one
    map cell per ``render_scale`` pixels, with the candidate goals coloured by ``info["action_mask"]`` and the
    robot at its pose; without a render mode ``render()`` is None, and an unknown mode is refused."""
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    from cso_runtime import frames
    from cso_runtime.geometry import GridGeometry, Pose2D

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", render_mode="rgb_array", render_scale=3).unwrapped
    check_env(env)
    _, info = env.reset(seed=3)
    frame = env.render()
    rows, cols = env.explorer.map.geometry.shape
    assert frame.shape == (rows * 3, cols * 3, 3) and frame.dtype == np.uint8
    geometry, o = env.explorer.map.geometry, env.obs

    def pixel(x_m: float, y_m: float) -> tuple[int, ...]:
        iy, ix = geometry.world_to_cell(x_m, y_m)
        return tuple(frame[(rows - 1 - int(iy)) * 3 + 1, int(ix) * 3 + 1])  # upright: the map's top row first

    assert pixel(o.pose.x_m, o.pose.y_m) in (frames.ROBOT, frames.HEADING)
    n = len(o.clusters)
    shown = {}
    for i, (x, y) in enumerate(o.goal_xy_m[:n]):
        if np.hypot(x - o.pose.x_m, y - o.pose.y_m) > 0.5:  # clear of the robot's disc
            shown[i] = pixel(x, y)
            assert shown[i] == (frames.ALLOWED if info["action_mask"][i] else frames.MASKED), i
    assert set(shown.values()) == {frames.ALLOWED, frames.MASKED}, shown  # goals of both kinds were looked at
    unknown = np.argwhere(~env.explorer.map.explored)[0]
    assert tuple(frame[(rows - 1 - unknown[0]) * 3, unknown[1] * 3]) == frames.UNKNOWN
    # A corner: an occupied cell of the top map row is the image's first rows.
    g = GridGeometry(0.1, (4, 5))
    occupied = np.zeros((4, 5), bool)
    occupied[3, 0] = True
    img = frames.map_frame(np.ones((4, 5), bool), occupied, g, Pose2D(0.45, 0.15, 0.0), robot_radius_m=0.0, scale=1)
    assert tuple(img[0, 0]) == frames.OCCUPIED and tuple(img[3, 0]) == frames.FREE and tuple(img[2, 4]) == frames.HEADING
    assert tuple(img[3, 4]) == frames.ROBOT and tuple(img[2, 0]) == frames.FREE  # a disc of 3 pixels at least, heading along +x

    with pytest.warns(UserWarning, match="render_mode"):  # as Gymnasium's envs warn
        assert gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4").unwrapped.render() is None
    with pytest.raises(ValueError, match="renders rgb_array"):  # "human" is gymnasium.make's HumanRendering over rgb_array
        gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes="generated:small:1:4", render_mode="ansi")


TRAIN_STAGE_DEADLINE_S = 300.0
"""The most one stage of a ``train`` subprocess may take in a test (to its first checkpoint, a resume's one update).
Each waits on its real condition; on 2 cores with two busy loops beside it they took 33 s and 42 s, and with six the
resume took 154 s, past its old fixed bound (120 s): 2 pytest-xdist workers on 2 shared cores (the other worker's run
of 6 service processes) load it as much now and then. A bound this far out only ends a run that hangs. A test of
such stages raises pytest's own limit (``timeout`` in pyproject.toml, 300 s for a whole test) above the sum of its
stages' bounds, so that the stage that hangs fails with its own message (and the command's output), not pytest's."""

TRAIN_STOP_WAIT_S = TRAIN_STOP_DEADLINE_S + 30.0
"""How long a test waits for ``train`` to end after its stop signal: its own bound (``cli.TRAIN_STOP_DEADLINE_S``,
past which it ends at once, saying where it waited) and time to exit. It took 4 s with two busy loops beside it."""


@pytest.mark.timeout(2 * TRAIN_STAGE_DEADLINE_S + TRAIN_STOP_WAIT_S + 60)
def test_train_closed_by_its_terminal_stops_its_env_workers_and_says_how_to_resume(tmp_path):
    """SIGHUP (its terminal closed) reaches ``train`` alone and ends it as Ctrl-C does: exit code 130, the
    environment processes gone with it, the checkpoint kept and the ``--resume`` hint said; a resume from that
    checkpoint then continues after its update. Every stage waits on its real condition, within a bound of its own
    (``TRAIN_STAGE_DEADLINE_S``, ``TRAIN_STOP_WAIT_S``) that fails with what the command said."""
    import signal
    import subprocess
    import sys

    from tests.conftest import process_group, wait_for

    out = tmp_path / "run"
    tiny = ["--set", "dungeon_dir=null", "--set", 'generated=["generated:small:2:0"]', "--set", "num_steps=8", "--set", "checkpoint_every=1", "--set", "max_steps=100"]
    cmd = [sys.executable, "-m", "cso_runtime.cli", "train", "--config", "configs/train.yaml", "--out", str(out), "--num-envs", "2", "--async-envs", *tiny]
    with process_group(cmd, cwd=Path(__file__).parents[1]) as proc:  # on leaving: no environment process left
        wait_for(lambda: (out / "checkpoint.pt").is_file() or proc.poll() is not None, TRAIN_STAGE_DEADLINE_S, "the first checkpoint")
        assert proc.poll() is None, "training ended before the signal: " + proc.communicate()[0][-2000:]
        proc.send_signal(signal.SIGHUP)
        try:
            output = proc.communicate(timeout=TRAIN_STOP_WAIT_S)[0]
        except subprocess.TimeoutExpired as exc:
            said = exc.output.decode(errors="replace") if isinstance(exc.output, bytes) else exc.output or ""
            raise AssertionError(f"train had not ended {TRAIN_STOP_WAIT_S:g} s after its SIGHUP; it said:\n{said[-4000:]}") from None
    assert proc.returncode == 130, output[-2000:]
    assert f"interrupted; continue from the last checkpoint with --resume {out / 'checkpoint.pt'}" in output
    stopped_at = torch.load(out / "checkpoint.pt", weights_only=False)["update"]
    # The resume steps its envs in its own process (where they run is no part of the recipe): it spawns no
    # workers, which cost seconds of imports each and are what the interrupted run above checks.
    resume = [*(a for a in cmd if a != "--async-envs"), "--resume", str(out / "checkpoint.pt"), "--time-limit-s", "0.1"]
    resumed = subprocess.run(resume, cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=TRAIN_STAGE_DEADLINE_S)
    assert resumed.returncode == 0 and f"resumed from {out / 'checkpoint.pt'} at update {stopped_at + 1}" in resumed.stdout, resumed.stdout[-2000:] + resumed.stderr[-2000:]
    # The run's record says the command that ran it (its flags as typed, in the order of the recipe's fields).
    command = shlex.split(json.loads((out / "cso.json").read_text())["command"])
    flags = resume[4:]
    assert command[:2] == ["cso-runtime", "train"] and sorted(command[2:]) == sorted(flags), command


def test_a_resume_with_another_recipe_is_refused_with_what_it_changes(tmp_path):
    """A checkpoint loads into any configuration with the same parameter shapes: a resume with another distance
    prior, graph, discount or batch would go on as a different run (and save its weights under this configuration)
    without a word. It is refused, naming each changed field; where and how long it runs may change."""
    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40,
              "distance_prior": 4.0, "progress": False}  # fmt: skip
    train(Args(total_decisions=8, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    checkpoint = str(tmp_path / "checkpoint.pt")
    for change, said in [({"distance_prior": 0.0}, "distance_prior 4.0 -> 0.0"), ({"max_frontier_nodes": 100}, "max_frontier_nodes 200 -> 100"),
                         ({"num_steps": 4, "gamma": 0.5}, "num_steps 8 -> 4, gamma 0.98 -> 0.5")]:  # fmt: skip
        with pytest.raises(ValueError, match=re.escape(f"changes the recipe of the run it continues ({said})")):
            check_training_inputs(Args(**{**common, **change, "out_dir": str(tmp_path / "other")}, total_decisions=16, resume=checkpoint))
    said: list[str] = []
    record = train(Args(**{**common, "out_dir": str(tmp_path / "longer")}, total_decisions=16, resume=checkpoint, checkpoint_every=3), log=said.append, plans=[rooms_plan(2)])
    assert record["ppo_decisions"] == 16 and "total_decisions 8 -> 16: 2 updates in all, the learning rate anneals over them from here" in said


def test_a_resume_writes_beside_its_checkpoint_and_continues_that_runs_log(tmp_path, monkeypatch):
    """``train --resume RUN/checkpoint.pt`` without ``--out`` wrote into the config's ``out_dir`` (``runs/train/cso``),
    not the run it continues: its weights, curve and log went to another folder, the log there began at the resumed
    update, and an earlier run's log in that folder had the resumed rows appended to its own. A resume now writes
    beside its checkpoint unless ``--out`` says otherwise, and its log goes on from the rows of the run it continues."""
    import csv

    from cso_runtime.cli import training_args

    recipe = {"variant": "cso", "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False}
    run, other = tmp_path / "run", tmp_path / "other"
    train(Args(**recipe, out_dir=str(run), total_decisions=24), log=lambda _msg: None, plans=[rooms_plan(2)])
    train(Args(**{**recipe, "seed": 5}, out_dir=str(other), total_decisions=16), log=lambda _msg: None, plans=[rooms_plan(2)])
    checkpoint = run / "checkpoint.pt"
    # docs/training.md: the run's record gives back the env it stepped.
    assert Args(**json.loads((run / "cso.json").read_text())["args"]).env_config() == Args(**recipe).env_config()
    monkeypatch.chdir(tmp_path)  # the default out_dir, were it used, is runs/train in here
    settings = [f"{k}={v}" for k, v in recipe.items()]
    assert Path(training_args(None, {"resume": str(checkpoint)}, settings).out_dir) == run
    assert Path(training_args(None, {"resume": str(checkpoint), "out_dir": str(other)}, settings).out_dir) == other
    before = list(csv.DictReader((run / "cso_log.csv").open()))
    train(Args(**recipe, out_dir=str(other), total_decisions=32, resume=str(checkpoint)), log=lambda _msg: None, plans=[rooms_plan(2)])
    continued = list(csv.DictReader((other / "cso_log.csv").open()))
    assert [r["update"] for r in continued] == ["1", "2", "3", "4"] and continued[:3] == before


def test_the_training_log_has_cleanrls_figures_and_a_resume_over_an_older_log_keeps_its_columns_aligned(tmp_path):
    """Besides the losses, KL and clip fraction, the CSV log has CleanRL's explained variance, episode length and
    SPS (decisions per second). A resume appending to a log of an older version (fewer columns) rewrites its
    header, so every row's values stay under their own column."""
    import csv

    from cso_runtime.learned import ppo

    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 16, "num_minibatches": 1, "max_steps": 40,
              "checkpoint_every": 1, "progress": False}  # fmt: skip
    train(Args(total_decisions=32, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    log_path = tmp_path / "cso_log.csv"
    rows = list(csv.DictReader(log_path.open()))
    assert list(rows[0]) == ppo.LOG_FIELDS and {"explained_variance", "mean_episode_steps", "sps"} <= set(ppo.LOG_FIELDS)
    for r in rows:
        assert float(r["explained_variance"]) <= 1.0 and abs(int(r["decisions"]) / float(r["sps"]) - float(r["wall_s"])) < 0.06  # wall_s to 0.1 s
        assert (r["mean_episode_steps"] == "") == (int(r["episodes"]) == 0)
    ended = [r for r in rows if int(r["episodes"])]
    assert ended and all(0 < float(r["mean_episode_steps"]) <= 40 for r in ended)
    assert ppo.explained_variance(torch.tensor([1.0, 2.0]), torch.tensor([1.0, 2.0])) == 1.0
    assert ppo.explained_variance(torch.tensor([0.0, 0.0]), torch.tensor([1.0, 1.0])) == ""

    older = ppo.LOG_FIELDS[:13]  # the log as the version before these columns wrote it
    with log_path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=older, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    train(Args(total_decisions=48, resume=str(tmp_path / "checkpoint.pt"), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    with log_path.open(newline="") as fh:
        lines = list(csv.reader(fh))
    assert lines[0] == ppo.LOG_FIELDS and all(len(line) == len(ppo.LOG_FIELDS) for line in lines)
    resumed = list(csv.DictReader(log_path.open()))
    assert [r["update"] for r in resumed] == ["1", "2", "3"] and resumed[0]["sps"] == "" and float(resumed[2]["sps"]) > 0
    assert resumed[2]["lr"] == str(float(resumed[2]["lr"])) and float(resumed[2]["wall_s"]) >= float(resumed[1]["wall_s"])


def test_a_training_checkpoint_resumes_onto_another_device_with_its_rng_state_on_the_cpu(tmp_path):
    """``--resume`` with ``--device cuda`` loaded the whole checkpoint onto that device, torch's RNG state too, which
    ``torch.set_rng_state`` refuses (it takes a CPU byte tensor only): a resume on a GPU failed. The checkpoint now
    loads on the CPU whatever the device (load_state_dict moves the weights and Adam's state to the model), so it
    loads for a ``cuda`` run even where this torch has no CUDA, and its RNG state can be set."""
    from torch import optim

    from cso_runtime.learned.ppo import load_resume_checkpoint

    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False}
    train(Args(total_decisions=8, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    args = Args(total_decisions=16, resume=str(tmp_path / "checkpoint.pt"), **common)
    model = build_model(args, torch.device("cpu"))
    ckpt = load_resume_checkpoint(args.resume, model, optim.Adam(parameter_groups(model, args)), torch.device("cuda"), "cso", args)
    assert ckpt["torch_rng"].device.type == "cpu" and ckpt["update"] == 1
    torch.set_rng_state(ckpt["torch_rng"])


def test_weights_given_as_a_link_named_for_its_method_is_that_methods_file(tmp_path, monkeypatch):
    """``--weights FILE`` reads the method from the file's name, but took the name of the link's target: a
    ``best/cso.pt`` linked to a run's ``step_100.pt`` was refused as not named for its method, and a ``cso-sm.pt``
    linked to a ``cso.pt`` was taken for cso's weights. The name given is the one read; the folder is still resolved."""
    import shutil

    from cso_runtime.learned.registry import weights_path
    from cso_runtime.learned.weights import WEIGHTS_FILE_ENV, use_weights

    unset_weights_env(monkeypatch)
    run, best = tmp_path / "run", tmp_path / "best"
    run.mkdir()
    best.mkdir()
    shutil.copy(weights_path("cso", SensorConfig.preset("lidar", 360)), run / "step_100.pt")
    (best / "cso.pt").symlink_to(run / "step_100.pt")
    assert use_weights(best / "cso.pt") == best.resolve() / "cso.pt"
    assert os.environ[WEIGHTS_FILE_ENV] == str(best.resolve() / "cso.pt")
    assert weights_path("cso") == best.resolve() / "cso.pt"
    shutil.copy(run / "step_100.pt", run / "cso.pt")
    (best / "cso-sm.pt").symlink_to(run / "cso.pt")
    assert use_weights(best / "cso-sm.pt").name == "cso-sm.pt" and weights_path("cso-sm").name == "cso-sm.pt"


def test_weights_given_as_a_runs_file_or_as_an_unfinished_run_are_said_plainly(tmp_path, monkeypatch):
    """``--weights`` took only a folder; a run's ``cso.pt`` given directly was refused as "not a folder", and a
    folder holding only ``checkpoint.pt`` (a run stopped before its end) passed, to fail later as "no weights for
    cso". A method's file is now that method's weights; a training checkpoint is named as one, with how to finish it."""
    import shutil

    from cso_runtime.learned.registry import weights_path
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV, use_weights

    unset_weights_env(monkeypatch)
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(weights_path("cso", SensorConfig.preset("lidar", 360)), run / "cso.pt")
    assert use_weights(run / "cso.pt") == (run / "cso.pt").resolve()
    assert os.environ[WEIGHTS_FILE_ENV] == str((run / "cso.pt").resolve()) and WEIGHTS_DIR_ENV not in os.environ
    before = os.environ.get(WEIGHTS_FILE_ENV)
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (unfinished / "checkpoint.pt").write_bytes(b"PK\x03\x04 a checkpoint")
    for given in (unfinished, unfinished / "checkpoint.pt"):
        with pytest.raises(ValueError, match=rf"only a training checkpoint .*train --resume {re.escape(str(unfinished.resolve() / 'checkpoint.pt'))}"):
            use_weights(given)
    assert os.environ.get(WEIGHTS_FILE_ENV) == before


def test_weights_given_as_a_file_not_named_for_its_method_is_refused_not_swapped_for_the_folders(tmp_path, monkeypatch):
    """``--weights RUN/mybest.pt`` (or a run's warm start, ``cso_warm.pt``) served the folder's ``cso.pt`` instead,
    another file than the one named, without a word (or failed with "no weights for cso in RUN"). Weights are found
    by their method's name, so such a file is refused, saying how to use it."""
    import shutil

    from cso_runtime.learned.registry import weights_path
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV, use_weights

    unset_weights_env(monkeypatch)
    run = tmp_path / "run"
    run.mkdir()
    shipped = weights_path("cso", SensorConfig.preset("lidar", 360))
    for name in ("cso.pt", "mybest.pt", "cso_warm.pt"):
        shutil.copy(shipped, run / name)
    for name in ("mybest.pt", "cso_warm.pt"):
        with pytest.raises(ValueError, match=rf"--weights {re.escape(str(run / name))}: .*named for its method .*cso\.pt"):
            use_weights(run / name)
    # A folder of no method's file: said so, up front, not "no weights for cso" once eval starts; a run stopped after its
    # warm start (checkpoint.pt beside cso_warm.pt) is an unfinished run, as one with checkpoint.pt alone.
    unnamed, warm_only = tmp_path / "unnamed", tmp_path / "warm_only"
    for folder, names in ((unnamed, ["mybest.pt"]), (warm_only, ["checkpoint.pt", "cso_warm.pt"])):
        folder.mkdir()
        for name in names:
            shutil.copy(shipped, folder / name)
    with pytest.raises(ValueError, match=r"no file named for a learned method's weights in it \(cso\.pt, .*\); it holds mybest\.pt"):
        use_weights(unnamed)
    with pytest.raises(ValueError, match=rf"only a training checkpoint .*train --resume {re.escape(str(warm_only.resolve() / 'checkpoint.pt'))}"):
        use_weights(warm_only)
    # A finished run's checkpoint.pt: its folder serves the run's weights.
    shutil.copy(shipped, run / "checkpoint.pt")
    with pytest.raises(ValueError, match=rf"a training checkpoint \(what train --resume goes on from\), not a method's weights; give its folder {re.escape(str(run.resolve()))}"):
        use_weights(run / "checkpoint.pt")
    assert os.environ.get(WEIGHTS_DIR_ENV) is None and os.environ.get(WEIGHTS_FILE_ENV) is None
    assert use_weights(run / "cso.pt") == use_weights(run / "cso.pt") == (run / "cso.pt").resolve()
    shutil.copy(shipped, run / "cso@fov180.pt")
    assert use_weights(run / "cso@fov180.pt") == (run / "cso@fov180.pt").resolve()  # one sensor's weights of a method
    assert use_weights(run) == run.resolve() and os.environ[WEIGHTS_DIR_ENV] == str(run.resolve()) and WEIGHTS_FILE_ENV not in os.environ


def test_weights_given_that_are_not_there_are_said_as_the_path_given_before_anything_starts(tmp_path, monkeypatch):
    """``--weights RUN/cso.pt`` of a file not there was said as "not a folder (give a training run's --out)";
    ``CSO_WEIGHTS_FILE`` of one as "no weights for cso in" the shipped weights folder (eval), or not at all (the policy
    service ran the shipped weights for a file named for no method). Each is now one error naming exactly the path given,
    exit 2 before anything starts, in eval, up, the policy service (``make_policy``) and doctor; a run of no learned
    method is not concerned."""
    from typer.testing import CliRunner

    from cso_runtime import doctor
    from cso_runtime.cli import app
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV, use_weights, weights_file_refusal

    unset_weights_env(monkeypatch)
    missing = tmp_path / "nope" / "cso.pt"
    with pytest.raises(ValueError, match=rf"^--weights {re.escape(str(missing))}: no such file or folder$"):
        use_weights(missing)
    named = tmp_path / "cso.pt"
    named.symlink_to(missing)
    with pytest.raises(ValueError, match=rf"^--weights {re.escape(str(named))}: no such file or folder \(a link to {re.escape(str(missing))}, which is not there\)$"):
        use_weights(named)
    assert os.environ.get(WEIGHTS_DIR_ENV) is None and os.environ.get(WEIGHTS_FILE_ENV) is None
    runner = CliRunner()
    for command in (["eval", "--method", "cso", "--dry-run"], ["up", "--dry-run"]):
        r = runner.invoke(app, [*command, "--weights", str(missing)])
        assert r.exit_code == 2 and f"--weights {missing}: no such file or folder" in " ".join(r.output.split()), (command, r.output)
    unnamed = tmp_path / "model.pt"
    unnamed.write_bytes(b"PK\x03\x04")
    for given, problem in (
        ({WEIGHTS_FILE_ENV: str(missing)}, f"{WEIGHTS_FILE_ENV}={missing}: no such file"),
        ({WEIGHTS_FILE_ENV: str(tmp_path / "nope" / "model.pt")}, f"{WEIGHTS_FILE_ENV}={tmp_path / 'nope' / 'model.pt'}: no such file"),
        ({WEIGHTS_FILE_ENV: str(tmp_path)}, f"{WEIGHTS_FILE_ENV}={tmp_path}: a folder, not a file"),
        ({WEIGHTS_FILE_ENV: str(unnamed)}, f"{WEIGHTS_FILE_ENV}={unnamed}: not named for a learned method's weights (cso.pt, "),
        ({WEIGHTS_DIR_ENV: str(tmp_path / "nodir")}, f"{WEIGHTS_DIR_ENV}={tmp_path / 'nodir'}: no such folder"),
    ):
        unset_weights_env(monkeypatch)
        for name, value in given.items():
            monkeypatch.setenv(name, value)
        assert weights_file_refusal(["cso"]).startswith(problem) and weights_file_refusal(["greedy-dist"]) == ""
        with pytest.raises(ValueError, match=f"^{re.escape(problem)}"):  # the policy service's selector: exit 2 (services.common)
            make_policy("cso", MaskConfig(), sensor=SensorConfig())
        for command in (["eval", "--method", "cso", "--dry-run"], ["up", "--dry-run"])[: 2 if given == {WEIGHTS_FILE_ENV: str(missing)} else 1]:
            r = runner.invoke(app, command)
            assert r.exit_code == 2 and problem in " ".join(r.output.split()), (command, r.output)
        (checked,) = doctor.run_checks(tmp_path, only=[("weights", doctor.check_weights)])
        assert not checked.ok and problem in checked.detail, checked
    assert runner.invoke(app, ["eval", "--method", "greedy-dist", "--dry-run"]).exit_code == 0  # no learned method: the folder is not read


def test_train_into_an_earlier_runs_folder_says_it_replaces_it(tmp_path):
    """CleanRL gives every run a folder of its own; ``train --out`` into an earlier run's folder replaced its log at
    once and its checkpoint at the first save without a word. It now says so, how that run would be continued until
    the new one starts its log, and what it removed then."""
    from cso_runtime.learned.ppo import earlier_run_files

    out = tmp_path / "run"
    out.mkdir()
    assert earlier_run_files(out, "cso") == []
    (out / "cso_log.csv").write_text("update\n")
    (out / "checkpoint.pt").write_bytes(b"PK\x03\x04")
    (out / "gnn-baseline.pt").write_bytes(b"PK\x03\x04")  # another variant's weights: not this run's to replace
    assert earlier_run_files(out, "cso") == ["checkpoint.pt", "cso_log.csv"]
    said: list[str] = []
    tiny = Args(dungeon_dir=None, generated=["generated:small:1:0"], num_envs=1, num_steps=4, num_minibatches=1, total_decisions=4, max_steps=20,
                out_dir=str(out), progress=False)
    train(tiny, log=said.append)
    assert (
        f"note: {out} holds an earlier run (checkpoint.pt, cso_log.csv): this run replaces it, removing its files as it starts its log"
        f" (until then, --resume {out / 'checkpoint.pt'} would continue it)"
    ) in said
    assert f"note: removed the earlier run's checkpoint.pt from {out}" in said


def test_keep_checkpoints_keeps_each_checkpoints_weights_for_eval(tmp_path, monkeypatch):
    """Training overwrote its one ``checkpoint.pt``, so the policies along the learning curve could not be evaluated
    (SB3's ``CheckpointCallback`` keeps them). ``keep_checkpoints``: the weights of each checkpoint, in a folder
    ``eval --weights`` serves (``checkpoints/update_<N>/``); off, the default, none. A resume may switch it on."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned.ppo import earlier_run_files
    from cso_runtime.learned.weights import use_weights

    common = {"variant": "cso", "seed": 0, "num_envs": 1, "num_steps": 4, "num_minibatches": 1, "max_steps": 20, "checkpoint_every": 2, "progress": False}
    plain = tmp_path / "plain"
    train(Args(total_decisions=12, out_dir=str(plain), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert not (plain / "checkpoints").exists()
    out = tmp_path / "kept"
    record = train(Args(total_decisions=12, keep_checkpoints=True, out_dir=str(out), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert record["ppo_updates"] == 3  # checkpoints after updates 2 and 3 (the last)
    kept = out / "checkpoints"
    assert sorted(p.name for p in kept.iterdir()) == ["update_0002", "update_0003"]
    assert sorted(p.name for p in (kept / "update_0002").iterdir()) == ["cso.json", "cso.pt"]
    final = torch.load(out / "cso.pt", weights_only=True)["state_dict"]
    at = {n: torch.load(kept / n / "cso.pt", weights_only=True)["state_dict"] for n in ("update_0002", "update_0003")}
    assert all(torch.equal(final[k], at["update_0003"][k]) for k in final)
    assert not all(torch.equal(final[k], at["update_0002"][k]) for k in final)  # the policy of update 2, not the last
    kept_record = json.loads((kept / "update_0002" / "cso.json").read_text())
    assert (kept_record["ppo_updates"], kept_record["ppo_decisions"]) == (2, 8) and kept_record["args"] == record["args"]
    model, _, _ = load_checkpoint(kept / "update_0002" / "cso.pt")  # a weights file, as the run's own
    assert all(torch.equal(model.state_dict()[k], at["update_0002"][k]) for k in final)

    unset_weights_env(monkeypatch)  # eval's --weights sets one in this process: put back as it was after the test
    r = CliRunner().invoke(app, ["eval", "--method", "cso", "--weights", str(kept / "update_0002"), "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(tmp_path / "eval")])
    assert r.exit_code == 0, r.output
    weights = json.loads((tmp_path / "eval" / "summary.json").read_text())["meta"]["weights"]["cso"]
    assert weights["path"] == str((kept / "update_0002" / "cso.pt").resolve())
    with pytest.raises(ValueError, match="its folders update_0002, update_0003 hold such files: give one of them"):
        use_weights(kept)

    assert earlier_run_files(out, "cso") == ["checkpoint.pt", "cso.pt", "cso_log.csv", "checkpoints/"]
    said: list[str] = []  # a new run in that folder keeping fewer checkpoints: none of the old run's is left to evaluate
    train(Args(total_decisions=4, keep_checkpoints=True, out_dir=str(out), **{**common, "checkpoint_every": 1}), log=said.append, plans=[rooms_plan(2)])
    assert sorted(p.name for p in kept.iterdir()) == ["update_0001"] and any("removed the earlier run's 2 kept checkpoints" in m for m in said), said
    resumed = {**common, "keep_checkpoints": True, "resume": str(plain / "checkpoint.pt"), "out_dir": str(plain)}
    train(Args(total_decisions=16, **resumed), log=lambda _msg: None, plans=[rooms_plan(2)])  # a run that kept none
    assert sorted(p.name for p in (plain / "checkpoints").iterdir()) == ["update_0004"]
    timed = tmp_path / "timed"  # stopped by its time limit: the checkpoint it writes then is kept too
    train(Args(total_decisions=12, keep_checkpoints=True, time_limit_s=1e-9, out_dir=str(timed), **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert sorted(p.name for p in (timed / "checkpoints").iterdir()) == ["update_0001"]
    cli_out = tmp_path / "cli"  # train's last lines name them and how to evaluate one
    tiny = ["--set", "dungeon_dir=null", "--set", "generated=[generated:small:1:0]", "--set", "num_steps=4", "--set", "num_minibatches=1",
            "--set", "max_steps=20", "--set", "checkpoint_every=1", "--set", "keep_checkpoints=true", "--num-envs", "1", "--total-decisions", "8",
            "--variant", "cso", "--out", str(cli_out)]  # fmt: skip
    r = CliRunner().invoke(app, ["train", *tiny])
    assert r.exit_code == 0, r.output
    assert f"-> {cli_out}: cso.pt, cso_log.csv, cso_curve.png, cso.json, checkpoint.pt, checkpoints/ (2 kept: update_0001 to update_0002)" in r.output
    assert f"a kept checkpoint likewise, with --weights {cli_out / 'checkpoints' / 'update_0002'} (the last;" in r.output


def test_the_resume_hint_names_only_this_runs_checkpoint(tmp_path, monkeypatch):
    """Ctrl-C before a new run's first checkpoint said "continue ... with --resume OUT/checkpoint.pt" whenever that
    file existed: an earlier run's, which would continue another run. Only this run's (or the one it resumed) counts;
    without one it says there is nothing to resume yet (it said a bare "interrupted")."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.learned import ppo

    def stopped(args, log, command=None, stop_requested=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(ppo, "train", stopped)
    out = tmp_path / "run"
    out.mkdir()
    (out / "checkpoint.pt").write_bytes(b"PK\x03\x04")
    os.utime(out / "checkpoint.pt", (1_000_000_000, 1_000_000_000))  # an earlier run's
    argv = ["train", "--set", "dungeon_dir=null", "--set", "generated=[generated:small:1:0]", "--out", str(out)]
    r = CliRunner().invoke(app, argv)
    assert r.exit_code == 130 and "interrupted" in r.output and "--resume" not in r.output, r.output
    # and it says so, rather than leaving the user to look for a checkpoint (the config's checkpoint_every is 2)
    assert "no checkpoint of this run yet (the first comes after PPO update 2): nothing to resume" in r.output, r.output

    def saved_then_stopped(args, log, command=None, stop_requested=None):
        (out / "checkpoint.pt").write_bytes(b"PK\x03\x04 this run's")
        raise KeyboardInterrupt

    monkeypatch.setattr(ppo, "train", saved_then_stopped)
    r = CliRunner().invoke(app, argv)
    assert r.exit_code == 130 and f"continue from the last checkpoint with --resume {out / 'checkpoint.pt'}" in r.output, r.output


def test_expert_action_refuses_the_rollout_teacher_it_cannot_score():
    # `rollout` is a teacher (TEACHERS) but no baseline: expert_action used to fail with a bare KeyError from
    # BASELINES; it says that teacher_label is the way to ask it.
    env = ExplorationEnv([rooms_plan(2)], EnvConfig(max_steps=200))
    _, info = env.reset(seed=0)
    with pytest.raises(ValueError, match="teacher_label"):
        expert_action(env.obs, info["action_mask"], "rollout")


def test_train_resume_alone_goes_on_with_the_checkpoints_own_configuration(tmp_path, monkeypatch):
    """``train --resume RUN/checkpoint.pt`` without ``--config`` read ``configs/train.yaml``, so a run trained with any
    other ``--set`` (a checkpoint left by Ctrl-C, whose record ``<variant>.json`` is not written yet) could only be
    resumed by typing every flag again: anything else was refused as a change of recipe. The checkpoint holds the
    run's configuration: a resume alone takes it; flags still change what may change, and a ``--config`` given
    with it is still held to the checkpoint's recipe."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    monkeypatch.chdir(Path(__file__).parents[1])  # where configs/train.yaml is the default recipe
    run = tmp_path / "run"
    recipe = {"variant": "cso", "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "gamma": 0.9,
              "generated": ["generated:small:1:0"], "progress": False}  # fmt: skip
    train(Args(**recipe, out_dir=str(run), total_decisions=8), log=lambda _msg: None, plans=[rooms_plan(2)])
    checkpoint = run / "checkpoint.pt"
    r = CliRunner().invoke(app, ["train", "--resume", str(checkpoint), "--total-decisions", "16"])
    assert r.exit_code == 0 and f"resumed from {checkpoint} at update 2" in r.output, r.output[-2000:]
    saved = json.loads((run / "cso.json").read_text())["args"]
    assert (saved["gamma"], saved["num_steps"], saved["generated"], saved["total_decisions"]) == (0.9, 8, ["generated:small:1:0"], 16)
    r = CliRunner().invoke(app, ["train", "--config", "configs/train.yaml", "--set", "dungeon_dir=null", "--resume", str(checkpoint)])
    assert r.exit_code == 2 and "changes the recipe of the run it continues" in r.output, r.output[-2000:]


def test_fine_tuning_names_what_differs_and_starts_from_a_training_checkpoint_too(tmp_path):
    """``--init-from`` weights of another shape said only "trained with another graph or network configuration",
    leaving the user to guess which of a dozen fields; it now names each, with the ``--set`` that fits the weights.
    A training checkpoint (``checkpoint.pt``, all a stopped run leaves) was refused as "not a cso-runtime checkpoint
    (no 'graph' entry)"; its weights now start the run, as a finished run's ``<variant>.pt`` does."""
    from cso_runtime.learned.ppo import initial_weights

    plan = rooms_plan(2)
    common = {"seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False, "hidden": 16, "knn": 4}
    train(Args(**common, out_dir=str(tmp_path / "run"), total_decisions=8), log=lambda _msg: None, plans=[plan])
    with pytest.raises(ValueError, match=re.escape("another graph or network configuration (hidden 16 -> 32, knn 4 -> 8); --set hidden=16 --set knn=4 fits them")):
        initial_weights(Args(init_from=str(tmp_path / "run" / "cso.pt")), torch.device("cpu"))
    ckpt = tmp_path / "run" / "checkpoint.pt"
    with pytest.raises(ValueError, match=re.escape("(hidden 16 -> 32, knn 4 -> 8)")):
        initial_weights(Args(init_from=str(ckpt)), torch.device("cpu"))
    start = initial_weights(Args(**common, init_from=str(ckpt)), torch.device("cpu"))
    saved = torch.load(ckpt, weights_only=True)["state_dict"]
    assert start.keys() == saved.keys() and all(torch.equal(start[k], saved[k]) for k in saved)


def test_fine_tuning_from_the_shipped_weights_names_the_file_it_started_from(tmp_path):
    """``train --init-from shipped`` said only "initialised from shipped", and its record ``init_from: shipped``: which
    of the shipped files (``cso.pt`` or ``cso@fov180.pt``, by the training sensor) the run started from, and which
    version of it, was left to guess. The line and the record name the file, the record with its SHA-256."""
    import hashlib

    from cso_runtime.config import from_dict, load_yaml

    recipe = dataclasses.asdict(from_dict(Args, load_yaml(Path(__file__).parents[1] / "configs" / "train.yaml"), "train.yaml"))
    recipe.update(out_dir=str(tmp_path), num_envs=1, num_steps=4, num_minibatches=1, max_steps=40, progress=False, init_from="shipped", total_decisions=4)
    said: list[str] = []
    record = train(Args(**recipe), log=said.append, plans=[rooms_plan(2)])
    shipped = weights_path("cso", SensorConfig.preset("lidar", 360.0))  # the recipe's 360-degree LiDAR: cso.pt
    assert shipped.name == "cso.pt"
    assert f"initialised from shipped weights {shipped}" in said, said
    digest = hashlib.sha256(shipped.read_bytes()).hexdigest()
    assert record["init_from"] == "shipped" and record["init_from_weights"] == {"path": str(shipped), "sha256": digest}


def test_a_fine_tuned_runs_record_keeps_the_file_it_started_from_through_a_resume(tmp_path, monkeypatch):
    """``<variant>.json``'s ``init_from_weights`` (the file ``--init-from`` named, with its SHA-256) was written by the
    run that started from it alone: a ``--resume`` of that run (``init_from`` is none of the resumed run's own fields)
    wrote a record with neither ``init_from`` nor ``init_from_weights``, so a fine-tuned run that was stopped and
    resumed said it started from a fresh network. The checkpoint carries them on. A path given relative to the
    working folder is recorded as the absolute path of the file read; a run from a fresh network records none."""
    import hashlib

    monkeypatch.chdir(tmp_path)
    common = {"seed": 0, "num_envs": 1, "num_steps": 4, "num_minibatches": 1, "max_steps": 40, "progress": False, "hidden": 16, "knn": 4}
    fresh = train(Args(**common, out_dir="a", total_decisions=4), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert "init_from" not in fresh and "init_from_weights" not in fresh  # --init-from none: no file to name
    started = {"path": str((tmp_path / "a" / "cso.pt").resolve()), "sha256": hashlib.sha256((tmp_path / "a" / "cso.pt").read_bytes()).hexdigest()}
    record = train(Args(**common, out_dir="b", init_from="a/cso.pt", total_decisions=4, checkpoint_every=1), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert (record["init_from"], record["init_from_weights"]) == ("a/cso.pt", started)
    (tmp_path / "a" / "cso.pt").unlink()  # the record says what the run started from, not what is there now
    resumed = train(Args(**common, out_dir="b", total_decisions=8, resume="b/checkpoint.pt"), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert resumed["ppo_updates"] == 2
    assert (resumed["init_from"], resumed["init_from_weights"]) == ("a/cso.pt", started)
    written = json.loads((tmp_path / "b" / "cso.json").read_text())
    assert (written["init_from"], written["init_from_weights"]) == ("a/cso.pt", started)


def test_a_fine_tuned_runs_checkpoint_from_before_started_from_still_names_what_it_started_from(tmp_path, monkeypatch):
    """A checkpoint written before ``started_from`` (the test above) resumes as before, but its resume wrote a record
    with neither ``init_from`` nor ``init_from_weights``, as a run from a fresh network, though the checkpoint's
    ``args`` hold the ``--init-from`` the run was given. The resume records that ``init_from``, and carries it on in
    its own checkpoints; no ``init_from_weights``, whose SHA-256 would be of the file as it is now, not as it was read."""
    from cso_runtime.learned.ppo import started_from

    monkeypatch.chdir(tmp_path)
    common = {"seed": 0, "num_envs": 1, "num_steps": 4, "num_minibatches": 1, "max_steps": 40, "progress": False, "hidden": 16, "knn": 4}
    train(Args(**common, out_dir="a", total_decisions=4), log=lambda _msg: None, plans=[rooms_plan(2)])
    train(Args(**common, out_dir="b", init_from="a/cso.pt", total_decisions=4, checkpoint_every=1), log=lambda _msg: None, plans=[rooms_plan(2)])
    older = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)
    assert older.pop("started_from") == {"init_from": "a/cso.pt", "init_from_weights": json.loads((tmp_path / "b" / "cso.json").read_text())["init_from_weights"]}
    torch.save(older, tmp_path / "b" / "checkpoint.pt")  # as the version before wrote it
    resumed = train(Args(**common, out_dir="b", total_decisions=8, checkpoint_every=1, resume="b/checkpoint.pt"), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert resumed["ppo_updates"] == 2 and resumed["init_from"] == "a/cso.pt" and "init_from_weights" not in resumed, resumed
    assert json.loads((tmp_path / "b" / "cso.json").read_text())["init_from"] == "a/cso.pt"
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)["started_from"] == {"init_from": "a/cso.pt"}  # a resume of the resume keeps it
    # an older resume's checkpoint: its args' init_from (a --init-from given with --resume) is none it started from
    assert started_from({"args": {"resume": "b/checkpoint.pt", "init_from": "other.pt"}}) == {} and started_from({"args": {"init_from": None}}) == {}


def test_a_stopped_training_run_leaves_its_learning_curve_so_far(tmp_path):
    """Ctrl-C (or a dead environment process) left the CSV log and the checkpoint but no ``<variant>_curve.png``:
    the curve was drawn only at the end, so the run a user stopped because it looked wrong had no picture to show
    why. The curve of the updates logged so far is now drawn on the way out, as the CSV log holds them."""
    common = {"seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False, "checkpoint_every": 1}

    def stop_at_update_3(message: str) -> None:
        if message.startswith("update 3/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(Args(**common, out_dir=str(tmp_path), total_decisions=80), log=stop_at_update_3, plans=[rooms_plan(2)])
    assert (tmp_path / "cso_curve.png").is_file() and not (tmp_path / "cso.pt").exists()
    assert [r["update"] for r in csv.DictReader((tmp_path / "cso_log.csv").open())] == ["1", "2", "3"]


def test_a_learning_curve_that_fails_to_save_leaves_the_last_one_and_nothing_else(tmp_path, monkeypatch):
    """Redrawn at every checkpoint, a curve whose saving failed (a full disk) left its ``.tmp`` file in the run folder
    and its figure open, one more at each checkpoint (matplotlib warns past 20). The last curve stays whole, and
    nothing else does."""
    import errno

    from matplotlib.figure import Figure

    from cso_runtime.learned import ppo

    log_csv = tmp_path / "cso_log.csv"
    log_csv.write_text("update,decisions,mean_return\n1,8,0.5\n2,16,0.7\n")
    png = tmp_path / "cso_curve.png"
    ppo.plot_learning_curve(log_csv, png, "cso")
    drawn = png.read_bytes()
    figures_open = ppo.pyplot().get_fignums()  # other tests' figures may be open: this one's must not stay

    def disk_full(self: Figure, fname: Path, **kwargs: object) -> None:
        Path(fname).write_bytes(drawn[:100])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Figure, "savefig", disk_full)
    with pytest.raises(OSError, match="No space left"):
        ppo.plot_learning_curve(log_csv, png, "cso")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cso_curve.png", "cso_log.csv"] and png.read_bytes() == drawn
    assert ppo.pyplot().get_fignums() == figures_open


def test_the_learning_curve_is_redrawn_at_each_checkpoint_not_only_at_the_end(tmp_path, monkeypatch):
    """A run of hours drew ``<variant>_curve.png`` only when it ended (or was stopped): a user watching the file (as
    CleanRL users watch TensorBoard) saw nothing, or the last run's curve, until then. It is now redrawn from the CSV
    log at each checkpoint (at most every ``CURVE_REDRAW_EVERY_S``, here every time), with the updates logged so far."""
    from cso_runtime.learned import ppo

    rows_drawn: list[int] = []
    draw = ppo.plot_learning_curve

    def counting_draw(csv_path: Path, png_path: Path, title: str) -> None:
        rows_drawn.append(len(list(csv.DictReader(Path(csv_path).read_text().splitlines()))))
        draw(csv_path, png_path, title)
        assert png_path.is_file() and not [p for p in png_path.parent.iterdir() if p.name.endswith((".tmp", ".partial"))]  # replaced whole

    monkeypatch.setattr(ppo, "plot_learning_curve", counting_draw)
    monkeypatch.setattr(ppo, "CURVE_REDRAW_EVERY_S", 0.0)
    common = {"seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False, "checkpoint_every": 2}
    train(Args(**common, out_dir=str(tmp_path), total_decisions=32), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert rows_drawn == [2, 4, 4]  # after the checkpoints of updates 2 and 4, then at the end
    rows_drawn.clear()  # the first checkpoint draws it whatever the time, so that a long run shows it early on
    monkeypatch.setattr(ppo, "CURVE_REDRAW_EVERY_S", 1e9)
    train(Args(**common, out_dir=str(tmp_path / "again"), total_decisions=32), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert rows_drawn == [2, 4]


def test_two_runs_of_one_seed_write_the_same_log_but_for_its_times_in_one_process_or_several(tmp_path):
    """docs/training.md promises what a CleanRL user checks first: the same configuration and seed give the same CSV log,
    the times (``wall_s``, ``sps``) aside, whether the environments step in this process or in their own; and two
    resumes from one checkpoint give the same log too."""
    common = {"seed": 3, "num_envs": 2, "num_steps": 8, "num_minibatches": 2, "max_steps": 40, "progress": False, "total_decisions": 48}
    logs = []
    for name, async_envs in (("sync", False), ("async", True)):
        train(Args(**common, out_dir=str(tmp_path / name), async_envs=async_envs), log=lambda _msg: None, plans=[rooms_plan(2), rooms_plan(3)])
        rows = list(csv.DictReader((tmp_path / name / "cso_log.csv").open()))
        logs.append([{k: v for k, v in row.items() if k not in ("wall_s", "sps")} for row in rows])
    assert len(logs[0]) == 3 and logs[0] == logs[1]
    import shutil

    resumed = []  # two resumes from one checkpoint go on alike (the torch generators are in it, the envs reseeded)
    for name in ("resume1", "resume2"):
        shutil.copytree(tmp_path / "sync", tmp_path / name)
        args = Args(**{**common, "total_decisions": 64}, out_dir=str(tmp_path / name), resume=str(tmp_path / name / "checkpoint.pt"))
        train(args, log=lambda _msg: None, plans=[rooms_plan(2), rooms_plan(3)])
        rows = list(csv.DictReader((tmp_path / name / "cso_log.csv").open()))
        resumed.append([{k: v for k, v in row.items() if k not in ("wall_s", "sps")} for row in rows])
    assert len(resumed[0]) == 4 and resumed[0] == resumed[1] and resumed[0][:3] == logs[0]


def test_a_run_stopped_by_its_time_limit_says_how_to_go_on(tmp_path):
    """``time_limit_s`` stopped a run with "time limit reached after update 1", then "done: ..." as if it had finished:
    nothing said that it had trained 8 of its 24 decisions, nor that ``--resume`` goes on (for the same time again,
    the checkpoint holding the limit)."""
    said: list[str] = []
    common = {"seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False}
    train(Args(**common, out_dir=str(tmp_path), total_decisions=24, time_limit_s=1e-9), log=said.append, plans=[rooms_plan(2)])
    assert (
        f"time limit reached after update 1 (8 of 24 decisions); --resume {tmp_path / 'checkpoint.pt'} goes on from here,"
        " for 1e-09 s more (the limit counts each process's time; add --time-limit-s 0 for none)"
    ) in said, said


def test_training_loads_its_plotting_before_the_first_update_so_a_ctrl_c_cannot_cut_that_import_short(tmp_path):
    """The curve drawn at the first checkpoint imported matplotlib there (1 to 2 s): a Ctrl-C in that window (found by
    pressing it in a terminal soon after the run started) left it half-imported, and the run stopped without its curve
    ("could not be drawn (AttributeError: module 'matplotlib' has no attribute 'get_data_path')"). A fresh process
    shows when it is loaded: before the first update ends."""
    import subprocess
    import sys

    script = f"""
import sys
from tests.test_learned import rooms_plan
from cso_runtime.learned.ppo import Args, train
seen = []
def log(message):
    if message.startswith("update 1/"):
        seen.append("matplotlib.pyplot" in sys.modules)
args = Args(seed=0, num_envs=1, num_steps=8, num_minibatches=1, max_steps=40, progress=False, total_decisions=8, out_dir={str(tmp_path)!r})
train(args, log=log, plans=[rooms_plan(2)])
print("loaded before the first update ended:", seen)
"""
    done = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=120)
    assert "loaded before the first update ended: [True]" in done.stdout, done.stdout[-2000:] + done.stderr[-2000:]


def test_a_resume_past_its_budget_writes_the_checkpoints_weights_and_says_so(tmp_path, monkeypatch):
    """``eval --weights`` of a stopped run (a ``checkpoint.pt``, no ``<variant>.pt``) says to resume it; a resume with a
    ``--total-decisions`` the checkpoint has already passed writes its weights as they are, but said "1 updates in all,
    the learning rate anneals over them from here", as if it trained. It now says that no update is left, and the
    weights written are the checkpoint's, which ``eval --weights`` then runs."""
    from cso_runtime.learned.weights import use_weights

    unset_weights_env(monkeypatch)  # use_weights sets one for this process: put back as it was after the test
    common = {"seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False, "out_dir": str(tmp_path)}
    train(Args(**common, total_decisions=24), log=lambda _msg: None, plans=[rooms_plan(2)])
    (tmp_path / "cso.pt").unlink()  # as a stopped run leaves it
    with pytest.raises(ValueError, match=re.escape("or add --total-decisions 1 to write its weights as they are")):
        use_weights(tmp_path)
    said: list[str] = []
    record = train(Args(**common, total_decisions=1, resume=str(tmp_path / "checkpoint.pt")), log=said.append, plans=[rooms_plan(2)])
    assert record["ppo_decisions"] == 24 and not any("anneals" in line for line in said), said
    assert any("no update left: the weights written are the checkpoint's (update 3, 24 decisions)" in line for line in said), said
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)["state_dict"]
    written, _, _ = load_checkpoint(tmp_path / "cso.pt")
    assert all(torch.equal(written.state_dict()[k], v) for k, v in saved.items())
    assert use_weights(tmp_path) == tmp_path.resolve()


def test_a_new_run_stopped_before_its_first_checkpoint_leaves_no_earlier_checkpoint_to_resume(tmp_path, monkeypatch):
    """A new run in an earlier run's folder replaced its log at once but kept its ``checkpoint.pt``, weights, record
    and curve until its own came: stopped before then, ``--resume`` of the old checkpoint went on with the new run's
    rows in the old run's log, and ``eval --weights`` served the old weights beside the new log. The new run removes
    them before it writes its log (the checkpoint first), after reading its own inputs, which may be among them."""
    from cso_runtime.learned import ppo

    common = {"variant": "cso", "seed": 0, "num_envs": 1, "num_steps": 4, "num_minibatches": 1, "max_steps": 20, "progress": False, "out_dir": str(tmp_path)}
    train(Args(total_decisions=4, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    assert {"checkpoint.pt", "cso.pt", "cso.json", "cso_curve.png", "cso_log.csv"} <= {p.name for p in tmp_path.iterdir()}

    def stopped(*_args: object, **_kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(ppo, "compute_gae", stopped)  # Ctrl-C in the new run's first update
    said: list[str] = []
    with pytest.raises(KeyboardInterrupt):  # its first weights from the earlier run's checkpoint: read before it goes
        train(Args(total_decisions=400, checkpoint_every=50, init_from=str(tmp_path / "checkpoint.pt"), **common), log=said.append, plans=[rooms_plan(2)])
    assert f"initialised from {tmp_path / 'checkpoint.pt'}" in said
    assert f"note: removed the earlier run's checkpoint.pt, cso.pt, cso.json, cso_curve.png from {tmp_path}" in said
    left = {p.name for p in tmp_path.iterdir()}
    assert not left & {"checkpoint.pt", "cso.pt", "cso.json"}, left
    with (tmp_path / "cso_log.csv").open() as fh:
        assert list(csv.DictReader(fh)) == []  # the new run's log: no row of the earlier run's


def test_weights_stopped_while_they_are_saved_leave_the_earlier_file_whole(tmp_path, monkeypatch):
    """The final ``<variant>.pt`` was written in place: a Ctrl-C while torch wrote it left half a file that no load
    reads. It is written through a temporary file renamed over it, as ``checkpoint.pt`` is (one helper for both)."""
    model = GraphActorCritic(NetworkConfig())
    path = tmp_path / "cso.pt"
    save_checkpoint(path, model, GraphConfig(), "cso")
    before = path.read_bytes()
    real_save = torch.save

    def cut_short(obj: object, f: str | Path) -> None:
        real_save(obj, f)
        Path(f).write_bytes(Path(f).read_bytes()[:100])  # half written when the Ctrl-C came
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", cut_short)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, model, GraphConfig(), "cso")
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["cso.pt"]  # no temporary file left
    load_checkpoint(path)


def test_repeated_signals_while_a_command_stops_keep_its_exit_code(tmp_path):
    """A second SIGTERM while ``train`` wrote what finished cut that short, and one while Python ended (its handlers
    back to the default by then) ended it with -15 although everything was written. After the first signal (the
    command's stop), a second only says that it is stopping, a third ends the stop where it is (KeyboardInterrupt,
    as ``up``'s stop may still be forced), and Python's end ignores them: the exit code stays 130."""
    import subprocess
    import sys

    script = """
import os, signal, sys, time
from cso_runtime.cli import interrupt_on_sigterm

class SignalAtTheEnd:  # a signal while Python ends, after its handlers were given back
    def __init__(self):
        self.kill, self.pid, self.sig = os.kill, os.getpid(), signal.SIGTERM
    def __del__(self):
        self.kill(self.pid, self.sig)

def signalled(sig):
    os.kill(os.getpid(), sig)
    for _ in range(200):
        time.sleep(0.005)

interrupt_on_sigterm(wait_on_second=True)
at_the_end = SignalAtTheEnd()
try:
    signalled(signal.SIGTERM)
except KeyboardInterrupt:
    signalled(signal.SIGHUP)
    print("the stop went on after the second signal", flush=True)
    try:
        signalled(signal.SIGINT)
    except KeyboardInterrupt:
        print("the third ended it", flush=True)
sys.exit(130)
"""
    done = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=60)
    assert done.stdout.splitlines() == ["the stop went on after the second signal", "the third ended it"], done.stdout + done.stderr
    assert "stopping: writing what finished; signal once more to stop at once" in done.stderr
    assert done.returncode == 130, done.stderr


@pytest.mark.timeout(TRAIN_STAGE_DEADLINE_S + 60)
def test_train_stops_on_a_signal_whose_interrupt_python_dropped_in_a_garbage_collection(tmp_path):
    """A stop signal that comes while Python collects garbage has its handler run inside the collector's callbacks
    (weakref callbacks, ``__del__``), where Python reports its ``KeyboardInterrupt`` as "Exception ignored" and drops
    it: ``train`` went on to its last update (hours with the recipe; a CI run's SIGHUP waited past pytest's 300 s).
    The signal also marks the stop as asked for, and training stops at its next step as on the interrupt itself: exit
    code 130, the checkpoint of the update before and the ``--resume`` hint."""
    import subprocess
    import sys

    out = tmp_path / "run"
    script = f"""
import gc, os, signal, sys
from cso_runtime import cli
from cso_runtime.learned import ppo

saved, sent = ppo._save_resumable, []

def signal_in_a_collection(phase, info):  # a callback of the collector: the handler runs in here
    if phase == "start" and not sent:
        sent.append(True)
        os.kill(os.getpid(), signal.SIGHUP)

def save_then_collect(path, model, optimizer, args, update, *rest):
    saved(path, model, optimizer, args, update, *rest)
    if update == 2:
        gc.callbacks.append(signal_in_a_collection)
        gc.collect()

ppo._save_resumable = save_then_collect
sys.argv = ["cso-runtime", "train", "--config", "configs/train.yaml", "--out", {str(out)!r}, "--sync-envs", "--num-envs", "2",
            "--total-decisions", "640", "--set", "dungeon_dir=null", "--set", 'generated=["generated:small:2:0"]', "--set", "num_steps=8",
            "--set", "checkpoint_every=1", "--set", "max_steps=100"]
cli.main()
"""
    done = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=TRAIN_STAGE_DEADLINE_S)
    said = done.stdout[-2000:] + done.stderr[-3000:]
    assert "Exception ignored" in done.stderr, said  # the interrupt was dropped, as in the run that hung
    assert done.returncode == 130 and f"interrupted; continue from the last checkpoint with --resume {out / 'checkpoint.pt'}" in done.stderr, said
    assert torch.load(out / "checkpoint.pt", weights_only=False)["update"] == 2
    assert [row["update"] for row in csv.DictReader((out / "cso_log.csv").open())] == ["1", "2"]


def test_a_stop_that_hangs_ends_at_its_deadline_with_the_stacks_its_children_killed_and_its_last_words():
    """``train``'s stop is bounded (``interrupt_on_sigterm``'s ``stop_deadline_s``): where it has not ended that long
    after its first signal, whatever it waits on, it ends with exit code 130, says where each thread was, kills its
    worker processes (here one that ignores SIGTERM) and says its last words (train's ``--resume`` hint)."""
    import signal
    import subprocess
    import sys

    from cso_runtime.supervision import pid_alive
    from tests.conftest import wait_for

    script = """
import multiprocessing, os, signal, threading
from cso_runtime.cli import interrupt_on_sigterm

def stuck():
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    threading.Event().wait()

def the_stop_that_hangs():
    threading.Event().wait()

interrupt_on_sigterm(wait_on_second=True, stop_deadline_s=1.0, last_words=lambda: "interrupted; continue with --resume here")
child = multiprocessing.get_context("fork").Process(target=stuck, daemon=True)
child.start()
print(child.pid, flush=True)
try:
    os.kill(os.getpid(), signal.SIGHUP)
    threading.Event().wait()
except KeyboardInterrupt:
    the_stop_that_hangs()
"""
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=Path(__file__).parents[1], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    child_pid = None
    try:
        child_pid = int(proc.stdout.readline() or 0) or None
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert "error: the stop took more than 1 s; ended at once" in err and "the_stop_that_hangs" in err, err
        assert err.rstrip().endswith("interrupted; continue with --resume here"), err
        assert child_pid is not None
        wait_for(lambda: not pid_alive(child_pid), 10, f"the worker {child_pid} to be killed with the stop")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        if child_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child_pid, signal.SIGKILL)


def test_a_signal_while_the_exit_waits_for_a_stuck_worker_ends_it_with_130():
    """After the first signal Python's end ignored the stop signals (to keep exit code 130), but multiprocessing's own
    exit function then joins every non-daemon child with no bound: a worker that never ended (stuck, or ignoring
    SIGTERM) left a process that neither Ctrl-C nor ``kill`` could stop. The exit now waits for such children while
    a stop signal ends it at once (exit code 130), and ignores the signals only after."""
    import signal
    import subprocess
    import sys

    script = """
import multiprocessing, os, signal, sys, time
from cso_runtime.cli import interrupt_on_sigterm

def stuck():
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    time.sleep(60)

interrupt_on_sigterm()
child = multiprocessing.get_context("fork").Process(target=stuck)  # not a daemon: the exit joins it
child.start()
print(child.pid, flush=True)
try:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)
except KeyboardInterrupt:
    sys.exit(130)
"""
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=Path(__file__).parents[1], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    child_pid = None
    try:
        child_pid = int(proc.stdout.readline())
        wchan = Path(f"/proc/{proc.pid}/wchan")
        seen = set()
        for _ in range(400):  # until the exit waits for the child (waitpid), at most 20 s
            with contextlib.suppress(OSError):
                seen.add(wchan.read_text().strip())
            if "do_wait" in seen or proc.poll() is not None:
                break
            time.sleep(0.05)
        else:
            if seen <= {"", "0"}:
                pytest.skip("this kernel does not say where a process waits (/proc/PID/wchan)")
        assert proc.poll() is None, proc.stderr.read()  # it waits for the stuck child, as multiprocessing's end does
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if child_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child_pid, signal.SIGKILL)


def test_trains_record_names_the_software_that_trained_the_weights(tmp_path):
    """``<variant>.json`` had the torch version and the command, not the package version, commit, Python or numpy."""
    from cso_runtime.provenance import software_provenance

    args = Args(variant="cso", seed=0, num_envs=1, num_steps=4, num_minibatches=1, max_steps=20, progress=False, out_dir=str(tmp_path), total_decisions=4)
    train(args, log=lambda line: None, plans=[rooms_plan(2)])
    record = json.loads((tmp_path / "cso.json").read_text())
    assert record["software"] == software_provenance() and record["software"]["packages"]["torch"] == record["torch"]


def test_train_removes_the_partial_files_a_killed_train_left(tmp_path):
    """``kill -9`` while ``train`` wrote its weights or checkpoint left ``.<variant>.pt.<pid>.partial`` (or
    ``.checkpoint.pt.<pid>.partial``) in its folder, and nothing removed it. A train into that folder, new or
    ``--resume``, removes those it finds (under its folder lock: none is another train's), kept checkpoints' too; only
    those of the files a train writes: another command's in the same folder (eval's summary, a tool of one's own) are
    not train's to remove, even with their writer gone."""
    from cso_runtime.learned.ppo import is_a_train_file

    common = {"variant": "cso", "seed": 0, "num_envs": 1, "num_steps": 4, "num_minibatches": 1, "max_steps": 20, "progress": False, "out_dir": str(tmp_path)}
    kept = tmp_path / "checkpoints" / "update_0001"
    others: list[Path] = []

    def left_by_a_kill() -> list[Path]:
        from tests.conftest import exited_pid

        dead = exited_pid()  # a kill's: its writer runs no more (a live one's are being written, and stay)
        stale = [tmp_path / f".cso.pt.{dead}.partial", tmp_path / f".checkpoint.pt.{dead}.partial", kept / f".cso.json.{dead}.partial"]
        stale += [tmp_path / f".gnn-baseline_log.csv.{dead}.partial", tmp_path / f".teacher_data.npz.{dead}.partial"]  # another variant's train
        others.extend([tmp_path / f".summary.json.{dead}.partial", tmp_path / f".notes.txt.{dead}.partial", kept / f".notes.txt.{dead}.partial"])
        for path in stale + others:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"PK\x03\x04 cut short by kill -9")
        return stale

    (tmp_path / ".notes").write_text("a hidden file of the user's")
    for resume in (None, str(tmp_path / "checkpoint.pt")):
        stale, said = left_by_a_kill(), []
        train(Args(total_decisions=4, resume=resume, **common), log=said.append, plans=[rooms_plan(2)])
        assert not [path for path in stale if path.exists()], resume
        assert f"note: removed {stale[1]}, left by a train that was killed while writing it" in said, said
    assert (tmp_path / ".notes").is_file() and sorted(tmp_path.rglob("*.partial")) == sorted(others)
    assert not is_a_train_file(tmp_path, tmp_path / "checkpoints" / "cso.pt") and not is_a_train_file(tmp_path / "run", tmp_path / "cso.pt")


def test_train_removes_the_temporary_files_a_train_killed_before_whole_file_writes_left(tmp_path):
    """Before ``write_whole``, the checkpoint, weights, log and curve were written to ``checkpoint.tmp`` (later
    ``checkpoint.pt.tmp``), ``<variant>.pt.tmp``, ``<variant>_log.tmp`` and ``<variant>_curve.png.tmp`` and renamed;
    a kill left them for good. A train's start-up removes those exact names too, kept checkpoints' included, and
    no other file (another variant's, the user's)."""
    names = ["checkpoint.tmp", "checkpoint.pt.tmp", "cso.pt.tmp", "cso_log.tmp", "cso_curve.png.tmp", "checkpoints/update_0001/cso.pt.tmp"]
    stale = [tmp_path / name for name in names]
    kept = [tmp_path / "gnn-baseline.pt.tmp", tmp_path / "notes.tmp", tmp_path / "checkpoints" / "update_0001" / "notes.tmp"]
    for path in stale + kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"cut short by kill -9")
    said: list[str] = []
    args = Args(variant="cso", seed=0, num_envs=1, num_steps=4, num_minibatches=1, max_steps=20, progress=False, out_dir=str(tmp_path), total_decisions=4)
    train(args, log=said.append, plans=[rooms_plan(2)])
    assert not [path for path in stale if path.exists()]
    assert f"note: removed {stale[2]}, left by a train that was killed while writing it" in said, said
    assert all(path.is_file() for path in kept)


def test_a_second_train_into_a_folder_another_train_is_writing_is_refused(tmp_path):
    """Two trains into one ``--out`` (a second terminal, a job resubmitted) wrote over each other's checkpoint, log and
    weights; and a train removing a killed one's partial files must not take those another is writing. The second is
    refused before it writes anything, naming the first's pid; once the first ended, the folder is free again."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.config import ConfigError
    from cso_runtime.current_run import hold_lock_file
    from cso_runtime.learned import ppo

    out = tmp_path / "run"
    theirs = out / ".cso.pt.4242.partial"  # the first train's weights, being written
    theirs.parent.mkdir()
    theirs.write_bytes(b"PK")
    first = hold_lock_file(out / ppo.TRAIN_LOCK)  # as the first train holds it, from its start to its end
    assert first is not None
    args = Args(variant="cso", seed=0, num_envs=1, num_steps=4, num_minibatches=1, max_steps=20, total_decisions=4, progress=False, out_dir=str(out))
    try:
        with pytest.raises(ConfigError, match=re.escape(f"{out} is being written by another train (pid {os.getpid()}): wait for it to end")):
            train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
        tiny = ["--set", "dungeon_dir=null", "--set", 'generated=["generated:small:1:0"]', "--set", "num_steps=4", "--set", "max_steps=20"]
        r = CliRunner().invoke(app, ["train", "--config", "configs/train.yaml", "--out", str(out), "--num-envs", "1", "--total-decisions", "4", *tiny])
        assert r.exit_code == 2 and f"is being written by another train (pid {os.getpid()})" in " ".join(r.output.split()), r.output
        assert sorted(p.name for p in out.iterdir()) == [".cso.pt.4242.partial", ppo.TRAIN_LOCK]  # nothing written, nothing removed
    finally:
        os.close(first)
    train(args, log=lambda _msg: None, plans=[rooms_plan(2)])
    assert (out / "cso.pt").is_file() and not theirs.exists()  # the first one's gone: a leftover now


def test_a_train_on_a_file_system_without_locks_runs_and_leaves_the_partial_files_alone(tmp_path, monkeypatch):
    """Where ``flock`` fails (NFS without its lock service: ENOLCK) a train runs as before its lock, says that a second
    one would not be refused, and leaves alone the partial files it finds: they may be such a train's."""
    import errno
    import fcntl

    from cso_runtime.learned import ppo

    def no_locks(fd: int, operation: int) -> None:
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(fcntl, "flock", no_locks)
    maybe_being_written = tmp_path / ".checkpoint.pt.4242.partial"
    maybe_being_written.write_bytes(b"PK")
    said: list[str] = []
    args = Args(variant="cso", seed=0, num_envs=1, num_steps=4, num_minibatches=1, max_steps=20, total_decisions=4, progress=False, out_dir=str(tmp_path))
    train(args, log=said.append, plans=[rooms_plan(2)])
    assert (tmp_path / "cso.pt").is_file() and maybe_being_written.is_file()
    assert f"warning: cannot lock {tmp_path / ppo.TRAIN_LOCK} (No locks available): a second train into {tmp_path} at the same time would not be refused" in said, said


def test_the_trainer_file_runs_as_a_script_as_cleanrls_does(tmp_path):
    """CleanRL runs its trainer as a file (``python ppo.py --total-timesteps ...``); ``python -m
    cso_runtime.learned.ppo --help`` printed nothing and exited 0, a silent no-op. It is ``cso-runtime train``."""
    import subprocess
    import sys

    env = {**os.environ, "COLUMNS": "200"}
    shown = subprocess.run([sys.executable, "-m", "cso_runtime.learned.ppo", "--help"], capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "Usage: cso-runtime train" in shown.stdout and "--total-decisions" in shown.stdout and "--config" in shown.stdout
    refused = subprocess.run([sys.executable, "-m", "cso_runtime.learned.ppo", "--num-envs", "0", "--set", "dungeon_dir=null"],
                             capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)  # fmt: skip
    assert refused.returncode == 2 and "num_envs" in refused.stderr and not (tmp_path / "runs").exists()


def test_the_trainer_run_as_a_script_starts_its_environment_processes_without_torch(tmp_path):
    """``--async-envs`` starts each environment process with ``spawn``, which imports the parent's main module in it.
    Under ``cso-runtime train`` that is the CLI's (no torch: an environment needs none); under ``python -m
    cso_runtime.learned.ppo`` it was the trainer itself, so every environment process imported torch (about 300 MB
    and a second more each, where one needs about 80 MB). The script's processes start from the CLI's module too."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import multiprocessing, runpy, sys
        from cso_runtime import cli

        def train_with_an_environment_process():  # what train's AsyncVectorEnv does first
            with multiprocessing.get_context("spawn").Pool(1) as pool:
                print("torch in the environment process:", pool.apply(eval, ("'torch' in __import__('sys').modules",)))

        cli.main = train_with_an_environment_process
        sys.argv = ["ppo.py"]
        runpy.run_module("cso_runtime.learned.ppo", run_name="__main__", alter_sys=True)  # python -m cso_runtime.learned.ppo
        """
    )
    ran = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path, check=False)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.strip() == "torch in the environment process: False", ran.stdout


def test_train_resume_refuses_an_init_from_other_than_what_its_run_started_from(tmp_path, monkeypatch):
    """``train --resume CKPT --init-from X`` went on from the checkpoint and ignored ``X`` in silence. Other weights than
    the run started from are refused, one line, exit 2, before anything trains, however they are given (``--init-from``,
    ``--set init_from=``, a config file's ``init_from``), naming both flags and how to fine-tune instead; the run's own
    ``init_from`` (the text it was given, the same file written otherwise, or the configuration its checkpoint holds,
    ``init_from`` and all, as a config file) is taken in silence, and so is a resume without one."""
    import yaml
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    tiny = ["--set", "dungeon_dir=null", "--set", "generated=[generated:small:1:0]", "--set", "num_steps=4", "--set", "num_minibatches=1",
            "--set", "max_steps=40", "--set", "hidden=16", "--set", "knn=4", "--set", "checkpoint_every=1", "--set", "progress=false",
            "--num-envs", "1", "--sync-envs", "--total-decisions", "4", "--device", "cpu"]  # fmt: skip
    for run in (["--out", "a"], ["--out", "b", "--init-from", "a/cso.pt"]):
        r = CliRunner().invoke(app, ["train", *tiny, *run])
        assert r.exit_code == 0, r.output[-2000:]
    resume = ["train", "--resume", "b/checkpoint.pt", "--total-decisions", "4"]  # none left: writes the weights, trains no further
    saved = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)["args"]
    own = tmp_path / "own.yaml"
    own.write_text(yaml.safe_dump({k: v for k, v in saved.items() if k not in ("resume", "out_dir")}))
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({**yaml.safe_load(own.read_text()), "init_from": "shipped"}))
    refused = [
        (["--init-from", "shipped"], "--init-from shipped with --resume b/checkpoint.pt"),
        (["--set", "init_from=a/cso_log.csv"], "--set init_from=a/cso_log.csv with --resume b/checkpoint.pt"),
        (["--config", str(other)], f"init_from shipped in {other} with --resume b/checkpoint.pt"),
    ]
    for extra, said in refused:
        r = CliRunner().invoke(app, [*resume, *extra])
        lines = [line for line in r.output.splitlines() if line.startswith("error:")]
        assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {said}: --resume continues that run"), (extra, r.output[-2000:])
        assert "(it started from a/cso.pt)" in lines[0] and "--init-from" in lines[0] and "without --resume" in lines[0], lines[0]
        assert "resumed from" not in r.output and "done:" not in r.output, r.output
    # a run from a fresh network started from no weights: any --init-from with its resume is refused
    r = CliRunner().invoke(app, ["train", "--resume", "a/checkpoint.pt", "--init-from", "a/cso.pt"])
    assert r.exit_code == 2 and "(it started from a fresh network)" in r.output, r.output[-2000:]
    for extra in ([], ["--init-from", "a/cso.pt"], ["--init-from", str(tmp_path / "a" / "cso.pt")], ["--set", "init_from=./a/cso.pt"], ["--config", str(own)]):
        r = CliRunner().invoke(app, [*resume, *extra])
        assert r.exit_code == 0 and "error" not in r.output and "done:" in r.output, (extra, r.output[-2000:])


def test_a_resume_refuses_the_runs_own_init_from_text_where_it_names_other_weights_now(tmp_path, monkeypatch):
    """The run's own ``init_from`` was taken by its text alone: ``a/cso.pt`` typed again in another folder (or through a
    link repointed since) names other weights than the run started from, and those were ignored in silence, what
    ``init_from_with_resume_problem`` is for. Where the text names a file that is not the one recorded
    (``init_from_weights``), the resume is refused, naming both files; the same text where no such file is (the run's
    own configuration used from another folder) and any spelling of the recorded file are still taken."""
    from cso_runtime.learned.ppo import Args, init_from_with_resume_problem

    run, elsewhere = tmp_path / "p", tmp_path / "q"
    for folder in (run / "a", run / "z", elsewhere / "a"):
        folder.mkdir(parents=True)
        (folder / "cso.pt").write_bytes(str(folder).encode())
    (run / "latest").symlink_to(run / "a")
    ckpt = tmp_path / "checkpoint.pt"
    for started in ("a/cso.pt", "latest/cso.pt"):
        torch.save({"args": {"resume": None, "init_from": started},
                    "started_from": {"init_from": started, "init_from_weights": {"path": str(run / "a" / "cso.pt"), "sha256": "-"}}}, ckpt)  # fmt: skip

        def problem(init_from: str, cwd: Path, started: str = started) -> str | None:
            monkeypatch.chdir(cwd)
            return init_from_with_resume_problem(Args(resume=str(ckpt), init_from=init_from), f"--init-from {init_from}")

        assert problem(started, run) is None
        assert problem(str(run / "a" / "cso.pt"), elsewhere) is None
        assert problem("../a/cso.pt", run / "z") is None
        assert problem(started, tmp_path) is None  # no such file there: the run's own configuration, from another folder
        if started == "a/cso.pt":
            refused = problem(started, elsewhere)  # another run's a/ there
            assert refused is not None and f"(it started from a/cso.pt, {run / 'a' / 'cso.pt'}; here a/cso.pt is {elsewhere / 'a' / 'cso.pt'})" in refused, refused
    (run / "latest").unlink()
    (run / "latest").symlink_to(run / "z")  # the link names another run's weights now
    refused = problem("latest/cso.pt", run)
    assert refused is not None and f"here latest/cso.pt is {run / 'z' / 'cso.pt'}" in refused, refused


def test_a_run_whose_entropy_window_scales_the_networks_input_otherwise_is_refused_naming_the_setting(tmp_path, monkeypatch):
    """``eval --method cso --set frontier.entropy_window_m=4`` ran the shipped weights (trained with 2 m) without a word:
    the frontier service counts I over the run's window and the graph divides it by the trained one, so the network's
    entropy input doubled. Every load now compares the run's frontier settings with the weights' training: the window
    is refused, naming the parameter, both values and the ``--set`` that matches them; the variants that do not read I
    take any window; a matching window loads."""
    from cso_runtime.config import FrontierConfig
    from cso_runtime.learned.registry import CheckpointError, check_weights

    unset_weights_env(monkeypatch)
    wider = FrontierConfig(entropy_window_m=4.0)
    path = weights_path("cso", SensorConfig())
    said = (
        f"the weights of cso ({path}) were trained with frontier.entropy_window_m 2 m, this run's is 4 m: the network's entropy"
        " input would be about 2 times what it learned on; run with --set frontier.entropy_window_m=2"
        " (up: --set exploration.frontier.entropy_window_m=2), or with weights trained with a 4 m window"
        " (cso-runtime train --config configs/train.yaml --set entropy_window_m=4)"
    )
    with pytest.raises(CheckpointError) as refused:
        check_weights("cso", sensor=SensorConfig(), frontier=wider)
    assert str(refused.value) == said
    with pytest.raises(ValueError, match=re.escape(said)):  # make_policy: eval's episodes, the policy service
        make_policy("cso", MaskConfig(), seed=0, sensor=SensorConfig(), frontier=wider)
    assert check_weights("cso", sensor=SensorConfig(), frontier=FrontierConfig()) == []
    assert make_policy("cso", MaskConfig(), seed=0, sensor=SensorConfig()).input_warnings == []  # None: the defaults
    for blind in ("cso-no-info", "gnn-baseline"):  # no entropy input: the window changes nothing they read
        assert make_policy(blind, MaskConfig(), seed=0, frontier=wider).input_warnings == []


def test_a_shorter_minimum_cluster_is_warned_of_not_refused(tmp_path, monkeypatch):
    """``frontier.min_cluster_size_m`` decides which clusters become the network's actions, not what a node's inputs
    mean: another value than the weights were trained with loads, with one warning naming it and both values."""
    from cso_runtime.config import FrontierConfig

    unset_weights_env(monkeypatch)
    path = weights_path("cso-sm")
    policy = make_policy("cso-sm", MaskConfig(), seed=0, frontier=FrontierConfig(min_cluster_size_m=0.5))
    said = (
        f"the weights of cso-sm ({path}) were trained with frontier.min_cluster_size_m 0.3 m, this run's is 0.5 m: its candidate"
        " goals would be other frontier clusters than it learned to choose among; --set frontier.min_cluster_size_m=0.3"
        " (up: --set exploration.frontier.min_cluster_size_m=0.3) runs them as trained"
    )
    assert policy.input_warnings == [said]


def test_checkpoints_record_their_frontier_settings_and_older_ones_load_as_trained_with_the_recipes(tmp_path, monkeypatch):
    """``train`` writes the frontier settings of its episodes into the weights (``frontier``), which a load compares
    with the run's. The shipped files predate the record and are left as they are (their SHA-256 is in every table's
    ``meta.weights``): they load, read as trained with the recipe's 0.3 m and their graph's 2 m window; an older file
    whose graph says another window is read as trained with that one."""
    from cso_runtime.config import FrontierConfig
    from cso_runtime.learned.ppo import matching_eval_command, save_weights
    from cso_runtime.learned.registry import TRAINED_FRONTIER_BEFORE_RECORD, CheckpointError, check_weights, trained_frontier
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV

    unset_weights_env(monkeypatch)
    assert TRAINED_FRONTIER_BEFORE_RECORD == FrontierConfig()  # the defaults train has always built its episodes with
    for shipped in sorted(weights_path("cso").parent.glob("*.pt")):
        ckpt = torch.load(shipped, weights_only=True)
        assert "frontier" not in ckpt
        assert trained_frontier(ckpt, GraphConfig(**ckpt["graph"])) == FrontierConfig(min_cluster_size_m=0.3, entropy_window_m=2.0)
    args = Args(variant="cso")
    save_weights(tmp_path / "run", build_model(args, torch.device("cpu")), args, {"ppo_decisions": 0})
    assert torch.load(tmp_path / "run" / "cso.pt", weights_only=True)["frontier"] == dataclasses.asdict(FrontierConfig())
    wide = Args(variant="cso", entropy_window_m=4.0, out_dir=str(tmp_path / "wide"))  # train --set entropy_window_m=4
    save_weights(tmp_path / "wide", build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0})
    ckpt = torch.load(tmp_path / "wide" / "cso.pt", weights_only=True)
    assert ckpt["frontier"]["entropy_window_m"] == ckpt["graph"]["entropy_window_m"] == 4.0
    assert matching_eval_command(wide).endswith("--set frontier.entropy_window_m=4")
    assert "entropy_window_m" not in matching_eval_command(args)
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path / "wide"))
    assert check_weights("cso", frontier=FrontierConfig(entropy_window_m=4.0)) == []
    with pytest.raises(CheckpointError, match=r"trained with frontier.entropy_window_m 4 m, this run's is 2 m"):
        check_weights("cso")
    old = tmp_path / "old"
    old.mkdir()
    save_checkpoint(old / "cso.pt", GraphActorCritic().eval(), GraphConfig(entropy_window_m=4.0), "cso")
    ckpt = torch.load(old / "cso.pt", weights_only=True)
    del ckpt["frontier"]  # as written before the record
    torch.save(ckpt, old / "cso.pt")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(old))
    assert check_weights("cso", frontier=FrontierConfig(entropy_window_m=4.0)) == []
    with pytest.raises(CheckpointError, match=r"trained with frontier.entropy_window_m 4 m, this run's is 2 m"):
        check_weights("cso", frontier=FrontierConfig())


def test_the_window_a_refusal_and_trains_eval_command_give_runs_the_weights(tmp_path, monkeypatch):
    """The ``--set`` a refusal names, and the ``eval`` command ``train`` prints at its end, wrote the entropy window with
    ``:g``'s six digits: weights trained with ``entropy_window_m=2.1234567`` were told to run with
    ``--set frontier.entropy_window_m=2.12346``, which is refused in turn, and ``2.0000001`` against 2 was said as "trained
    with 2 m, this run's is 2 m". Each value is written so that it reads back as itself; a short one stays short."""
    from cso_runtime.config import FrontierConfig
    from cso_runtime.learned.ppo import matching_eval_command, save_weights
    from cso_runtime.learned.registry import CheckpointError, check_weights
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV

    unset_weights_env(monkeypatch)
    odd = Args(variant="cso", entropy_window_m=2.1234567, out_dir=str(tmp_path / "odd"))
    save_weights(tmp_path / "odd", build_model(odd, torch.device("cpu")), odd, {"ppo_decisions": 0})
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path / "odd"))
    words = shlex.split(matching_eval_command(odd))
    window = float(words[words.index("--set") + 1].split("=", 1)[1])
    assert check_weights("cso", frontier=FrontierConfig(entropy_window_m=window)) == []  # the command train prints runs them
    with pytest.raises(CheckpointError) as refused:
        check_weights("cso", frontier=FrontierConfig(entropy_window_m=2.0))
    said = str(refused.value)
    assert "trained with frontier.entropy_window_m 2.1234567 m, this run's is 2 m" in said, said
    suggested = float(re.search(r"run with --set frontier.entropy_window_m=(\S+) ", said).group(1))
    assert check_weights("cso", frontier=FrontierConfig(entropy_window_m=suggested)) == []  # the way out it names runs them
    unset_weights_env(monkeypatch)
    with pytest.raises(CheckpointError, match=re.escape("trained with frontier.entropy_window_m 2 m, this run's is 2.0000001 m")):
        check_weights("cso", sensor=SensorConfig(), frontier=FrontierConfig(entropy_window_m=2.0000001))


def test_a_resume_of_a_checkpoint_from_before_the_window_setting_refuses_another_window(tmp_path):
    """A training checkpoint written before ``entropy_window_m`` was a setting holds no such field in its ``args``, and
    a field a checkpoint lacks is not compared: ``train --resume OLD/checkpoint.pt --set entropy_window_m=4`` went on
    training, with a 4 m window, a network that had learned its entropy input over 2 m (the only window ``train`` had),
    and saved it as trained with 4 m. It is refused as a resume of a run that recorded its window is."""
    common = {"variant": "cso", "out_dir": str(tmp_path), "seed": 0, "num_envs": 1, "num_steps": 8, "num_minibatches": 1, "max_steps": 40, "progress": False}
    train(Args(total_decisions=8, **common), log=lambda _msg: None, plans=[rooms_plan(2)])
    checkpoint = tmp_path / "checkpoint.pt"
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=False)
    recorded = dict(ckpt["args"])
    del ckpt["args"]["entropy_window_m"]  # as written before the setting
    torch.save(ckpt, tmp_path / "old.pt")
    for resumed in (checkpoint, tmp_path / "old.pt"):
        with pytest.raises(ValueError, match=re.escape("changes the recipe of the run it continues (entropy_window_m 2.0 -> 4.0)")):
            check_training_inputs(Args(**{**common, "out_dir": str(tmp_path / "other")}, total_decisions=16, entropy_window_m=4.0, resume=str(resumed)))
        check_training_inputs(Args(**{**common, "out_dir": str(tmp_path / "other")}, total_decisions=16, resume=str(resumed)))  # its own window goes on
    assert recorded["entropy_window_m"] == 2.0


def test_an_env_whose_graph_and_episodes_have_other_entropy_windows_is_refused(tmp_path):
    """The env counts I over ``exploration.frontier.entropy_window_m`` and its graph divides it by
    ``GraphConfig.entropy_window_m``: two settings of one window. ``EnvConfig(graph=load_checkpoint(path)[1])`` (the
    docs' way to run other weights in the env) of weights trained with ``train --set entropy_window_m=4`` counted I over
    2 m and divided it by 4: the network read half the entropy it learned on, without a word. An env whose two windows
    differ is refused, naming both; ``train``'s own env (``Args.env_config``) counts I over its ``entropy_window_m``."""
    from cso_runtime.config import ExplorationConfig, FrontierConfig

    wide = GraphConfig(use_cluster_size=True, entropy_window_m=4.0)  # a checkpoint's graph, trained with 4 m
    with pytest.raises(ValueError, match=re.escape("GraphConfig.entropy_window_m 4 m, exploration.frontier.entropy_window_m 2 m")):
        ExplorationEnv([rooms_plan(2)], EnvConfig(graph=wide))
    ExplorationEnv([rooms_plan(2)], EnvConfig(graph=dataclasses.replace(wide, use_entropy=False)))  # reads no I: any window
    agreed = EnvConfig(graph=wide, exploration=dataclasses.replace(ExplorationConfig(), frontier=FrontierConfig(entropy_window_m=4.0)), max_steps=200)
    for config in (agreed, Args(variant="cso", entropy_window_m=4.0).env_config()):
        env = ExplorationEnv([rooms_plan(2)], config)
        env.reset(seed=0)
        assert env.explorer is not None and env.explorer.builder.frontier_config.entropy_window_m == 4.0


def test_ensemble_of_benchmarks_runs_its_episodes_and_checks_each_members_window(tmp_path, monkeypatch, capsys):
    """benchmarks/eval_ensemble.py replaced ``registry.make_learned_policy`` with a function of the arguments it had
    before ``sensor`` (and now ``frontier``) were passed: every episode failed (``TypeError: make_ensemble() got an
    unexpected keyword argument 'sensor'``). It takes them now, and its members, loaded by their paths, are held to the
    run's frontier settings as the weights it serves are (``registry.input_mismatches``)."""
    from cso_runtime import cli
    from cso_runtime.learned import registry
    from cso_runtime.learned.ppo import save_weights

    unset_weights_env(monkeypatch)
    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)
    monkeypatch.setattr(registry, "make_learned_policy", registry.make_learned_policy)  # main() replaces it: given back after
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    wide = Args(variant="cso", entropy_window_m=4.0, out_dir=str(tmp_path / "wide"))
    save_weights(tmp_path / "wide", build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0})
    runs = {"shipped": weights_path("cso", SensorConfig.preset("lidar", 360.0)), "wide": tmp_path / "wide" / "cso.pt"}
    for name, member in runs.items():
        with pytest.raises(SystemExit):
            ensemble.main(["--member", str(member), "--", "--method", "cso", "--lidar-fov", "360", "--workers", "1", "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(tmp_path / name)])
    summary = json.loads((tmp_path / "shipped" / "summary.json").read_text())
    assert summary["methods"]["cso"]["episodes"] == 1, summary.get("failures")
    # refused before any episode, as eval refuses the weights of a method (registry.check_weights: the members' too)
    assert "trained with frontier.entropy_window_m 4 m, this run's is 2 m" in capsys.readouterr().err
    assert not (tmp_path / "wide" / "summary.json").exists()


def test_ensemble_of_benchmarks_decides_over_its_members_graph_not_the_served_weights(tmp_path, monkeypatch):
    """benchmarks/eval_ensemble.py built each decision's graph with the graph of the weights it serves (the shipped
    ``cso.pt``: knn 8, distance scale 10 m), not its members': members trained with ``knn=4`` and ``distance_scale_m=5``
    were given graphs of 8 neighbours and distances at half their scale, without a word (the node features' count is
    the same). The members must share one graph; the ensemble decides over it."""
    from cso_runtime import cli
    from cso_runtime.learned import registry
    from cso_runtime.learned.ppo import save_weights

    unset_weights_env(monkeypatch)
    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)
    monkeypatch.setattr(registry, "make_learned_policy", registry.make_learned_policy)  # main() replaces it: given back after
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    other = Args(variant="cso", knn=4, distance_scale_m=5.0, cluster_size_feature=True, out_dir=str(tmp_path / "other"))
    save_weights(tmp_path / "other", build_model(other, torch.device("cpu")), other, {"ppo_decisions": 0})
    seen: list[GraphConfig] = []
    decide = ensemble.EnsemblePolicy.probabilities
    monkeypatch.setattr(ensemble.EnsemblePolicy, "probabilities", lambda self, obs, mask: (seen.append(self.graph_config), decide(self, obs, mask))[1])
    with pytest.raises(SystemExit):
        ensemble.main(["--member", str(tmp_path / "other" / "cso.pt"), "--", "--method", "cso", "--lidar-fov", "360", "--workers", "1",
                       "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(tmp_path / "out")])
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["methods"]["cso"]["episodes"] == 1, summary.get("failures")
    assert seen and {(g.knn, g.distance_scale_m, g.use_entropy) for g in seen} == {(4, 5.0, True)}, seen[:1]


def test_ensemble_of_benchmarks_refuses_members_of_another_variant(tmp_path, monkeypatch, capsys):
    """A member trained as ``cso-no-info`` (its entropy input 0 throughout training) in an ensemble run as
    ``--method cso`` was fed the entropy input it never saw, where the method's own weights file of another variant is
    refused (``registry._model_for``). It is refused so, naming the member."""
    from cso_runtime import cli
    from cso_runtime.learned import registry
    from cso_runtime.learned.ppo import save_weights

    unset_weights_env(monkeypatch)
    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)
    monkeypatch.setattr(registry, "make_learned_policy", registry.make_learned_policy)  # main() replaces it: given back after
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    blind = Args(variant="cso-no-info", cluster_size_feature=True, out_dir=str(tmp_path / "blind"))
    save_weights(tmp_path / "blind", build_model(blind, torch.device("cpu")), blind, {"ppo_decisions": 0})
    with pytest.raises(SystemExit):
        ensemble.main(["--member", str(tmp_path / "blind" / "cso-no-info.pt"), "--", "--method", "cso", "--lidar-fov", "360", "--workers", "1",
                       "--maps", "generated:small:1:0", "--max-steps", "5", "--out", str(tmp_path / "out")])
    failed = capsys.readouterr().err  # before any episode, as eval refuses a method's own weights file of another variant
    assert "cso-no-info.pt holds weights trained as 'cso-no-info'" in failed, failed[:2000]
    assert not (tmp_path / "out" / "summary.json").exists()


def test_ensemble_of_benchmarks_warns_of_its_members_minimum_cluster_as_every_loader_does(tmp_path, monkeypatch, caplog):
    """benchmarks/eval_ensemble.py held its members to the run's frontier settings with a copy of the loaders' split of
    refused and warned, which kept the refusals only: members trained with ``frontier.min_cluster_size_m`` 0.3 m ran with
    0.5 m without the warning eval gives for a method's own weights. The members' warnings (``registry.input_verdict``,
    the one decision every loader takes) are said once by eval, and held by the policy as ``make_learned_policy``'s are."""
    import shutil

    from cso_runtime import cli
    from cso_runtime.learned import registry

    unset_weights_env(monkeypatch)
    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)
    monkeypatch.setattr(registry, "make_learned_policy", registry.make_learned_policy)  # main() gives them back; in case it fails
    monkeypatch.setattr(registry, "check_weights", registry.check_weights)
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    member = tmp_path / "member" / "cso.pt"  # the shipped weights by another path: the warning names the member, not them
    member.parent.mkdir()
    shutil.copy(weights_path("cso", SensorConfig.preset("lidar", 360.0)), member)
    said = (
        f"the weights of cso ({member}) were trained with frontier.min_cluster_size_m 0.3 m, this run's is 0.5 m: its candidate"
        " goals would be other frontier clusters than it learned to choose among"
    )
    held: list[list[str]] = []
    decide = ensemble.EnsemblePolicy.probabilities
    monkeypatch.setattr(ensemble.EnsemblePolicy, "probabilities", lambda self, obs, mask: (held.append(self.input_warnings), decide(self, obs, mask))[1])
    with caplog.at_level("WARNING"), pytest.raises(SystemExit):
        ensemble.main(["--member", str(member), "--", "--method", "cso", "--lidar-fov", "360", "--workers", "1", "--maps", "generated:small:1:0",
                       "--max-steps", "5", "--set", "frontier.min_cluster_size_m=0.5", "--out", str(tmp_path / "out")])
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["methods"]["cso"]["episodes"] == 1
    assert said in caplog.text
    assert held and all(len(warned) == 1 and warned[0].startswith(said) for warned in held), held[:1]
    assert registry.check_weights is ensemble.registry.check_weights and registry.check_weights.__name__ == "check_weights"  # given back


def test_a_checkpoints_header_reads_without_torch_as_torch_loads_it_and_runs_none_of_its_code(tmp_path):
    """``weights.checkpoint_header`` (``up``'s window check before anything starts) reads what ``torch.load`` gives of a
    checkpoint's plain data, and the frontier settings every load compares (``registry.trained_frontier``); a pickle
    that would call anything but torch's tensor rebuilding is not read (None), nor is a file of another kind."""
    import pickle
    import zipfile

    from cso_runtime.config import FrontierConfig
    from cso_runtime.learned.ppo import save_weights
    from cso_runtime.learned.registry import trained_frontier
    from cso_runtime.learned.weights import checkpoint_header, recorded_frontier

    wide = Args(variant="cso", entropy_window_m=4.0, out_dir=str(tmp_path))
    save_weights(tmp_path, build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0})
    ckpt = torch.load(tmp_path / "cso.pt", map_location="cpu", weights_only=True)
    header = checkpoint_header(tmp_path / "cso.pt")
    assert header is not None and {k: v for k, v in header.items() if k != "state_dict"} == {k: v for k, v in ckpt.items() if k != "state_dict"}
    assert header["state_dict"].keys() == ckpt["state_dict"].keys() and all(v is None for v in header["state_dict"].values())
    assert recorded_frontier(tmp_path / "cso.pt") == trained_frontier(ckpt, GraphConfig(**ckpt["graph"])) == FrontierConfig(entropy_window_m=4.0)
    assert recorded_frontier(weights_path("cso")) == FrontierConfig(min_cluster_size_m=0.3, entropy_window_m=2.0)  # before the record: its graph's

    class Loud:
        def __reduce__(self):
            return (print, ("ran",))

    with zipfile.ZipFile(tmp_path / "loud.pt", "w") as archive:
        archive.writestr("loud/data.pkl", pickle.dumps({"graph": {"entropy_window_m": 4.0}, "frontier": Loud()}))
    assert checkpoint_header(tmp_path / "loud.pt") is None and recorded_frontier(tmp_path / "loud.pt") is None
    assert checkpoint_header(tmp_path / "cso.json") is None and checkpoint_header(tmp_path / "none.pt") is None


def test_a_crafted_checkpoint_header_costs_no_memory_nor_a_crash(tmp_path):
    """``weights.checkpoint_header`` reads a file before anything starts (``up``), so a crafted one must cost neither
    memory nor a traceback: a ``data.pkl`` compressed to a bomb (``zipfile`` inflates it whole before cutting it to the
    size said: 201 bytes of bzip2 made 141 MiB), a 9-byte pickle naming memo index 2**23 (the C unpickler grows its memo
    to it: 64 MiB), a pickle over the size cap (about 70 bytes of objects per byte), and numbers no float holds (an
    OverflowError out of ``up``)."""
    import struct
    import tracemalloc
    import zipfile

    from cso_runtime.config import FrontierConfig
    from cso_runtime.learned.weights import checkpoint_frontier, checkpoint_header, recorded_frontier

    def archive(name: str, data: bytes, compress_type: int = zipfile.ZIP_STORED, said_size: int | None = None) -> Path:
        path = tmp_path / f"{name}.pt"
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr(zipfile.ZipInfo(f"{name}/data.pkl"), data, compress_type=compress_type)
        if said_size is not None:  # the size the archive says, in its local header and its central directory
            raw = bytearray(path.read_bytes())
            for signature, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
                at = raw.index(signature) + offset
                raw[at : at + 4] = struct.pack("<I", said_size)
            path.write_bytes(bytes(raw))
        return path

    crafted = [
        archive("bomb", b"\0" * (32 << 20), zipfile.ZIP_BZIP2, said_size=10),
        archive("memo", b"\x80\x02}r" + struct.pack("<I", 1 << 23) + b"."),
        archive("wide", b"\x80\x02" + b"}" * (1 << 20) + b"."),
    ]
    for path in crafted:
        tracemalloc.start()
        try:
            header = checkpoint_header(path)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 8 << 20, (path.name, peak)
        assert header is None or header == {}, path.name
    huge = 10**400
    assert recorded_frontier(archive("huge", pickle.dumps({"graph": {"entropy_window_m": huge}}, protocol=2))) is None
    assert checkpoint_frontier({"frontier": {"entropy_window_m": huge, "min_cluster_size_m": 0.5}}, 2.0) == FrontierConfig(min_cluster_size_m=0.5, entropy_window_m=2.0)


@pytest.mark.parametrize("workers", [["--workers", "2"], ["--workers=3"]])
def test_ensemble_of_benchmarks_refuses_eval_workers_that_would_run_the_served_weights(tmp_path, monkeypatch, workers):
    """benchmarks/eval_ensemble.py sets the ensemble up in its own process (``registry.make_learned_policy`` replaced);
    eval's ``--workers`` above 1 runs the episodes in spawned processes that import the registry afresh: they ran the
    weights served, not the ensemble, under the ensemble's run and without a word (its docstring only asked to keep
    ``--workers 1``). It is refused before eval runs."""
    from cso_runtime import cli
    from cso_runtime.learned import registry

    unset_weights_env(monkeypatch)
    monkeypatch.setattr(registry, "make_learned_policy", registry.make_learned_policy)
    monkeypatch.setattr(registry, "check_weights", registry.check_weights)
    ran: list[list[str]] = []
    monkeypatch.setattr(cli, "app", ran.append)
    spec = importlib.util.spec_from_file_location("eval_ensemble", Path(__file__).parents[1] / "benchmarks" / "eval_ensemble.py")
    ensemble = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ensemble)
    member = str(weights_path("cso", SensorConfig.preset("lidar", 360.0)))
    with pytest.raises(SystemExit, match="give --workers 1"):
        ensemble.main(["--member", member, "--", "--method", "cso", *workers, "--out", str(tmp_path / "out")])
    assert ran == []
    assert ensemble.main(["--member", member, "--", "--method", "cso", "--workers", "1", "--out", str(tmp_path / "out")]) == 0
    assert ran == [["eval", "--method", "cso", "--workers", "1", "--out", str(tmp_path / "out")]]
