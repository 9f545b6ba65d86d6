"""PPO's correctness against CleanRL's: log-probs recomputed in the update equal the rollout's, the masked
categorical's edge cases, and the warm start's critic targets at truncations."""

from __future__ import annotations

import csv

import numpy as np
import torch

from cso_runtime.geometry import Pose2D
from cso_runtime.learned.network import CategoricalMasked
from cso_runtime.learned.ppo import (
    Args,
    build_model,
    collect_teacher,
    index_obs,
    make_vector_env,
    mask_to_torch,
    obs_to_torch,
    teacher_returns,
    train,
    warm_start,
)
from tests.test_learned import rooms_plan


def test_the_updates_log_probs_equal_the_rollouts_exactly_whatever_the_minibatch():
    """The rollout scores a batch of envs' graphs, cut to its largest graph; the update re-scores shuffled minibatches
    of other sizes, cut to theirs. For the same parameters the log-probs must be the same numbers (ratio exactly 1
    before the first step), and the entropy finite."""
    torch.manual_seed(0)
    args = Args(variant="cso", seed=0, num_envs=3, max_steps=200, distance_prior=4.0, cluster_size_feature=True)
    envs = make_vector_env(args, [rooms_plan(2), rooms_plan(3)])
    model = build_model(args, torch.device("cpu"))
    observations, masks, actions, logprobs = [], [], [], []
    try:
        obs, info = envs.reset(seed=0)
        for _ in range(8):
            g, m = obs_to_torch(obs, torch.device("cpu")), mask_to_torch(info["action_mask"], "cpu")
            with torch.no_grad():
                action, logprob, _, _ = model.get_action_and_value(g, m)
            observations.append(g), masks.append(m), actions.append(action), logprobs.append(logprob)
            obs, _, _, _, info = envs.step(action.numpy())
    finally:
        envs.close()
    b_obs = {k: torch.cat([o[k] for o in observations]) for k in observations[0]}
    b_mask, b_actions, b_logprobs = torch.cat(masks), torch.cat(actions), torch.cat(logprobs)
    assert len(set(b_obs["node_valid"].sum(1).tolist())) > 2  # graphs of several sizes, padded alike
    for size in (1, 5, len(b_actions)):
        perm = torch.randperm(len(b_actions))
        for start in range(0, len(perm), size):
            mb = perm[start : start + size]
            with torch.no_grad():
                _, newlogprob, entropy, _ = model.get_action_and_value(index_obs(b_obs, mb), b_mask[mb], b_actions[mb])
            assert torch.equal(newlogprob, b_logprobs[mb])
            assert torch.isfinite(entropy).all()


def test_the_masked_categorical_is_the_categorical_over_the_allowed_actions_with_finite_gradients():
    """Masked actions have probability 0 and add nothing to the entropy; one allowed action is certain (log-prob 0,
    entropy 0), all allowed is the plain categorical; no NaN, in the values or their gradients, in any of them."""
    torch.manual_seed(0)
    logits = (20 * torch.randn(4, 6)).requires_grad_()
    mask = torch.tensor([[0, 0, 1, 0, 0, 0], [1] * 6, [1, 0, 1, 0, 1, 0], [0] * 6], dtype=torch.bool)
    dist = CategoricalMasked(logits, mask)
    actions = torch.tensor([2, 5, 4, 0])
    logprob, entropy = dist.log_prob(actions), dist.entropy()
    (logprob.sum() + entropy.sum()).backward()
    assert torch.isfinite(logprob).all() and torch.isfinite(entropy).all() and torch.isfinite(logits.grad).all()
    assert logprob[0].item() == 0.0 and entropy[0].item() == 0.0
    assert (dist.probs[:3][~mask[:3]] == 0).all()  # the last row allows nothing: defined (uniform), never NaN
    plain = torch.distributions.Categorical(logits=logits[1].detach())
    torch.testing.assert_close(entropy[1].detach(), plain.entropy())
    subset = torch.distributions.Categorical(logits=logits[2, [0, 2, 4]].detach())
    torch.testing.assert_close(entropy[2].detach(), subset.entropy())
    torch.testing.assert_close(logprob[2].detach(), subset.log_prob(torch.tensor(2)))


def test_a_frozen_network_has_a_ratio_of_exactly_one_in_every_update(tmp_path):
    """Learning rate 0: the policy that re-scores each minibatch is the one that acted, through episode ends,
    truncations and autoresets, so the approximate KL and the clipped fraction are exactly 0 in every update."""
    args = Args(
        variant="cso",
        out_dir=str(tmp_path),
        seed=0,
        total_decisions=96,
        num_envs=2,
        num_steps=16,
        num_minibatches=4,
        max_steps=60,
        learning_rate=0.0,
        target_kl=0.0,
        progress=False,
    )
    train(args, log=lambda _m: None, plans=[rooms_plan(2), rooms_plan(3)])
    with (tmp_path / "cso_log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 and sum(int(r["episodes"]) for r in rows) >= 2
    assert all(float(r["approx_kl"]) == 0.0 and float(r["clipfrac"]) == 0.0 for r in rows), rows


def test_teacher_returns_are_known_only_where_the_episode_terminated():
    """The warm start's critic targets: a Monte-Carlo return is the true one only for an episode that terminated in
    the collection. The partial sum of an episode cut by the step limit, or still going when the collection stopped,
    is no return (PPO bootstraps it with V): it was used as if the cut were the end."""
    rewards = np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]])
    terminated = np.array([[False, False], [True, False], [False, False], [False, False]])
    truncated = np.array([[False, False], [False, False], [False, True], [False, False]])
    returns = teacher_returns(rewards, terminated, truncated, 0.5)
    np.testing.assert_array_equal(returns[:, 0], [1.5, 1.0, np.nan, np.nan])  # ended at 1; 2, 3: still going
    assert np.isnan(returns[:, 1]).all()  # cut at 2; 3: still going


def test_collected_teacher_data_gives_no_return_to_truncated_or_unfinished_episodes_and_the_critic_skips_them():
    """On two rooms, greedy-dist finishes in 19 decisions; cut at 30 control steps it is truncated at its 16th. Rows of
    an episode that did not terminate hold NaN; the warm start fits its critic on the others only, and with none
    it still trains the actor, every weight finite."""
    for max_steps, finished in ((400, 19), (30, 0)):
        args = Args(variant="cso", num_envs=1, max_steps=max_steps, num_minibatches=2, warm_start_epochs=2, progress=False)
        envs = make_vector_env(args, [rooms_plan(2)])
        try:
            data = collect_teacher(envs, 24, args.gamma, seed=0)
        finally:
            envs.close()
        known = np.isfinite(data.returns)
        assert known.tolist() == [True] * finished + [False] * (24 - finished)
        torch.manual_seed(0)
        model = build_model(args, torch.device("cpu"))
        stats = warm_start(model, data, args, torch.device("cpu"), log=lambda _m: None)
        assert stats["value_decisions"] == finished and np.isfinite(stats["bc_value_loss"])
        assert all(torch.isfinite(p).all() for p in model.parameters())


def test_the_training_env_ends_at_reset_an_episode_that_evaluation_ends_before_its_first_decision():
    """``Explorer.run`` (eval) ends an episode whose first scan already meets section 4.1's end at 0 steps; the training
    env asked for a decision there and ran it, so training saw transitions that evaluation never makes. Two rooms, a
    360-degree LiDAR and an end at 40 % coverage: the first scan covers about 70 %, a frontier still open at the door."""
    import dataclasses

    from cso_runtime.config import ExplorationConfig, SensorConfig
    from cso_runtime.episode import run_episode
    from cso_runtime.learned.env import EnvConfig, ExplorationEnv
    from cso_runtime.policies import BASELINES
    from cso_runtime.simulator import KinematicSimulator

    base = ExplorationConfig()
    exploration = dataclasses.replace(
        base,
        sensor=SensorConfig.preset("lidar", 360.0),
        episode=dataclasses.replace(base.episode, done_coverage_pct=40.0, done_unexplored_m2=100.0),
    )
    plan = rooms_plan(2)
    evaluated = run_episode(
        KinematicSimulator(plan, exploration.sensor, exploration.robot, seed=0), BASELINES["greedy-dist"](), exploration
    )
    assert (evaluated.terminated_by, evaluated.steps) == ("coverage", 0)
    env = ExplorationEnv([plan], EnvConfig(exploration=exploration, max_steps=200))
    _, info = env.reset(seed=0)
    assert (info["terminated_by"], info["steps"]) == ("coverage", 0)
    _, reward, terminated, truncated, end = env.step(0)
    assert (reward, terminated, truncated, end["steps"]) == (0.0, True, False, 0)


def test_the_trainer_bootstraps_a_truncation_with_the_value_of_its_final_observation_and_not_a_termination(tmp_path, monkeypatch):
    """What PPO's GAE is given, step by step, against what the envs returned: a step cut by the step limit gets
    gamma x V(final_obs), the observation the cut left, never the next episode's first (same-step autoreset); a
    finished map gets nothing more; and either ends the bootstrap (``dones`` of the next step). Frozen network
    (learning rate 0), so V is the saved weights'. Three rooms are cut at 10 control steps; one room is finished at once."""
    from cso_runtime.learned import ppo
    from cso_runtime.learned.registry import load_checkpoint

    steps: list[tuple] = []
    gae_inputs: list[tuple] = []
    make_vector_env_, compute_gae_ = ppo.make_vector_env, ppo.compute_gae

    def recording_envs(args, refs):
        envs = make_vector_env_(args, refs)
        step = envs.step

        def recorded(actions):
            result = step(actions)
            steps.append(
                (result[0], np.array(result[1], dtype=np.float64), *result[2:])
            )  # a copy: the trainer adds to its rewards
            return result

        envs.step = recorded
        return envs

    monkeypatch.setattr(ppo, "make_vector_env", recording_envs)
    monkeypatch.setattr(ppo, "compute_gae", lambda *given: gae_inputs.append(given) or compute_gae_(*given))
    args = Args(
        variant="cso",
        out_dir=str(tmp_path),
        seed=0,
        total_decisions=64,
        num_envs=2,
        num_steps=32,
        num_minibatches=2,
        max_steps=10,
        learning_rate=0.0,
        lidar_fov_deg=360,
        progress=False,
    )
    whole_at_once = rooms_plan(1, start=Pose2D(1.5, 1.5, 0.0))  # its first scan explores it: over at its first step
    train(args, log=lambda _m: None, plans=[rooms_plan(3), whole_at_once])
    model, _, _ = load_checkpoint(tmp_path / "cso.pt")
    assert len(steps) == 32 and len(gae_inputs) == 1
    rewards, _, dones, _, next_done, discounts, _ = gae_inputs[0]
    seen = {"terminated": 0, "truncated": 0}
    for t, (obs, reward, terminated, truncated, info) in enumerate(steps):
        expected = np.asarray(reward, dtype=np.float64).copy()
        for i in np.flatnonzero(truncated):
            final = info["final_obs"][i]
            assert not all(np.array_equal(final[k], obs[k][i]) for k in final)  # the cut's state, not the reset's
            with torch.no_grad():
                value = model.get_value(obs_to_torch({k: v[None] for k, v in final.items()}, torch.device("cpu")))
            expected[i] += args.gamma * float(value)
        np.testing.assert_allclose(rewards[t].numpy(), expected, rtol=0, atol=1e-5)
        ended = np.logical_or(terminated, truncated).astype(np.float32)
        np.testing.assert_array_equal((dones[t + 1] if t + 1 < len(steps) else next_done).numpy(), ended)
        seen["terminated"] += int(terminated.sum())
        seen["truncated"] += int(truncated.sum())
    assert seen["terminated"] and seen["truncated"], seen  # both kinds of end happened
    assert torch.equal(discounts, torch.full_like(discounts, args.gamma))
