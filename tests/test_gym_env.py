"""The training environment as a Gymnasium user meets it: its observation layout for other RL libraries
(Stable-Baselines3, CleanRL), its registered versions, vector envs and ``close``."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

from cso_runtime.learned.env import ENV_ID, EnvConfig, ExplorationEnv, make_env, observation_layout
from cso_runtime.learned.graph import GraphConfig, build_graph, empty_graph
from cso_runtime.learned.network import to_torch
from cso_runtime.learned.ppo import TeacherData, obs_to_torch
from cso_runtime.learned.registry import load_checkpoint
from cso_runtime.learned.weights import weights_path

SCENES = "generated:small:1:4"

# Positions and distances have no bound (graph.FEATURE_RANGES); the checker's advice about infinite bounds does not apply.
pytestmark = pytest.mark.filterwarnings("ignore:.*A Box observation space (minimum|maximum) value is:UserWarning")


def test_every_observation_entry_has_an_axis_so_stable_baselines3_takes_it():
    """``robot`` was a 0-d Box: Stable-Baselines3's ``check_env`` failed on it (its bounds check calls ``np.where``,
    which refuses 0-d arrays), its ``MultiInputPolicy`` could not flatten it and its rollout buffers gave it back
    as (batch, 1). It is a one-element array now; the network reads the same index as from ``build_graph``."""
    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES, config=EnvConfig(max_steps=120))
    space = env.observation_space
    assert isinstance(space, spaces.Dict)
    assert all(len(sub.shape) >= 1 for sub in space.spaces.values()), {k: sub.shape for k, sub in space.spaces.items()}
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    for key, sub in space.spaces.items():  # what Stable-Baselines3's check_env asserts of each entry
        assert obs[key].shape == sub.shape and np.can_cast(obs[key].dtype, sub.dtype)
        if isinstance(sub, spaces.Box):
            assert len(np.where(np.logical_or(obs[key] < sub.low, obs[key] > sub.high))[0]) == 0
    graph = build_graph(env.unwrapped.obs, env.unwrapped.config.graph)
    assert obs["robot"].tolist() == [int(graph["robot"])]
    model = load_checkpoint(weights_path("cso"))[0]  # the shipped weights
    mask = torch.ones((1, model.max_frontier_nodes), dtype=torch.bool)
    with torch.no_grad():
        from_env = model.masked_logits(obs_to_torch({k: v[None] for k, v in obs.items()}, torch.device("cpu")), mask)
        from_graph = model.masked_logits(to_torch(graph, batch=True), mask)
    torch.testing.assert_close(from_env, from_graph, rtol=0, atol=0)
    env.close()


def test_the_step_limit_is_a_keyword_of_gymnasium_make():
    """``gymnasium.make(ENV, max_steps=50)`` was a TypeError from the env's creator (only ``config=EnvConfig(...)``
    set it), though the step limit is the first thing an RL user shortens. ``max_steps`` (control steps of 0.25 s,
    not decisions: Gymnasium's ``max_episode_steps`` counts those) is a keyword over ``config``'s, for
    ``gymnasium.make`` and ``make_vec`` alike; the episode is truncated there, as at the default 800."""
    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES, max_steps=12)
    assert env.unwrapped.config.max_steps == 12
    _, info = env.reset(seed=0)
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
    assert truncated and not terminated and info["terminated_by"] == "max_steps" and info["steps"] >= 12
    env.close()
    over = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES, config=EnvConfig(max_steps=120, invalid_action_limit=7), max_steps=30)
    assert over.unwrapped.config.max_steps == 30 and over.unwrapped.config.invalid_action_limit == 7  # the rest of config kept
    vec = gym.make_vec(f"cso_runtime.learned.env:{ENV_ID}", num_envs=2, vectorization_mode="sync", scenes=SCENES, max_steps=40)
    assert vec.get_attr("config")[0].max_steps == 40
    vec.close()
    with pytest.raises(ValueError, match="max_steps must be a positive number of control steps"):
        make_env(scenes=SCENES, max_steps=0)


def test_the_step_limit_keyword_takes_numpy_integers_and_is_bounded_as_the_configs():
    """``gymnasium.make(ENV, max_steps=np.int64(5))`` (a limit drawn or read with NumPy) was refused, only Python ints
    taken, while ``max_steps=10**7`` was taken, past the bound ``episode.max_steps`` has (``MAX_EPISODE_STEPS``). A
    NumPy integer is taken (as an int), a bool of either kind still refused, and the config's bound applies."""
    from cso_runtime.config import MAX_EPISODE_STEPS

    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES, max_steps=np.int64(5))
    assert env.unwrapped.config.max_steps == 5 and type(env.unwrapped.config.max_steps) is int
    env.close()
    assert make_env(scenes=SCENES, max_steps=np.uint16(MAX_EPISODE_STEPS % 2**16)).config.max_steps == MAX_EPISODE_STEPS % 2**16
    assert make_env(scenes=SCENES, max_steps=MAX_EPISODE_STEPS).config.max_steps == MAX_EPISODE_STEPS
    for wrong in (True, np.True_, np.int64(0), 5.0):
        with pytest.raises(ValueError, match="max_steps must be a positive number of control steps"):
            make_env(scenes=SCENES, max_steps=wrong)
    for over in (MAX_EPISODE_STEPS + 1, np.int64(10**12)):
        with pytest.raises(ValueError, match=r"max_steps must be in \[1, 1,000,000\]"):
            make_env(scenes=SCENES, max_steps=over)


def test_vector_envs_stack_the_robot_index_with_one_axis_and_give_each_envs_action_mask():
    """CleanRL's and Gymnasium's vector envs stack each entry with a leading env axis: ``robot`` is (num_envs, 1)."""
    vec = gym.make_vec(f"cso_runtime.learned.env:{ENV_ID}", num_envs=2, vectorization_mode="sync", scenes=SCENES)
    try:
        obs, info = vec.reset(seed=0)
        assert obs["robot"].shape == (2, 1) and obs["nodes"].shape[0] == 2
        masks = vec.call("action_masks")
        assert len(masks) == 2 and all(np.array_equal(m, i.astype(bool)) for m, i in zip(masks, info["action_mask"]))
    finally:
        vec.close()


def test_the_observation_layout_changed_with_the_envs_version_and_v0_keeps_its_own():
    """A changed observation space is a new version (Gymnasium's rule): v1 has the one-element ``robot``; v0, still
    registered for code written against it, keeps its 0-d one, and Gymnasium says that v1 is out when it is made."""
    assert ENV_ID == "CSOExploration-v1"
    new = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES)
    with pytest.warns(DeprecationWarning, match="CSOExploration-v0 is out of date.*upgrading to version `v1`"):
        old = gym.make("cso_runtime.learned.env:CSOExploration-v0", scenes=SCENES)  # Gymnasium tells of the newer one
    try:
        assert new.observation_space["robot"].shape == (1,) and old.observation_space["robot"].shape == ()
        first, second = new.reset(seed=3)[0], old.reset(seed=3)[0]
        assert old.observation_space.contains(second) and second["robot"].shape == ()
        assert all(np.array_equal(first[k], second[k]) for k in first if k != "robot")
        assert first["robot"].tolist() == [int(second["robot"])]
    finally:
        new.close()
        old.close()
    assert observation_layout(GraphConfig())["robot"].shape == (1,)
    assert observation_layout(GraphConfig()).keys() == empty_graph(GraphConfig()).keys()


def test_teacher_data_of_the_0d_layout_loads_in_the_current_one(tmp_path):
    """Teacher-data files collected before hold ``robot`` as one number per decision: they load with its axis, so
    they still warm-start and mix with new files."""
    layout = observation_layout(GraphConfig())
    old_graphs = {k: np.repeat(v[None], 2, axis=0) for k, v in empty_graph(GraphConfig()).items()}
    old_graphs["robot"] = np.array([5, 7], dtype=np.int64)
    n = GraphConfig().max_frontier_nodes
    old = TeacherData(old_graphs, np.ones((2, n), bool), np.zeros(2, np.int64), np.zeros(2, np.float32), np.full((2, n), np.inf))
    assert old.graphs["robot"].tolist() == [[5], [7]]
    old.save(tmp_path / "old.npz")
    with np.load(tmp_path / "old.npz") as f:
        legacy = {k: f[k] for k in f.files}
    legacy["graph_robot"] = np.array([5, 7], dtype=np.int64)  # as a file of the 0-d layout holds it
    np.savez(tmp_path / "legacy.npz", **legacy)
    new_graphs = {k: np.repeat(v[None], 1, axis=0) for k, v in layout.items()}
    new = TeacherData(new_graphs, np.ones((1, n), bool), np.zeros(1, np.int64), np.zeros(1, np.float32), np.full((1, n), np.inf))
    new.save(tmp_path / "new.npz")
    both = TeacherData.load([tmp_path / "legacy.npz", tmp_path / "new.npz"])
    assert both.graphs["robot"].tolist() == [[5], [7], [0]]
    assert all(both.graphs[k].shape[1:] == v.shape for k, v in layout.items())


def test_close_releases_the_episode_and_the_loaded_plans():
    """``close`` kept the simulator, the maps and every loaded floor plan alive, and the closed env went on stepping."""
    env = make_env(SCENES)
    env.reset(seed=0)
    env.close()
    assert env.explorer is None and env.obs is None and env._plans is None
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(0)
    env.close()  # closing twice is harmless, as Gymnasium's envs allow
    assert env.reset(seed=0)[1]["plan"]  # and a closed env may be reset again: it loads its plans anew
    env.close()


def test_a_bare_env_built_from_plans_still_holds_them_after_close():
    """Plans given as a list (not a loader) are the caller's: ``close`` lets go of them but a reset finds them."""
    plans = make_env(SCENES).plans
    env = ExplorationEnv(plans)
    env.reset(seed=0)
    env.close()
    assert env.reset(seed=0)[1]["plan"] == plans[0].name
    env.close()


def test_the_env_pickles_before_and_during_an_episode():
    """``make_env`` (``gymnasium.make``'s entry point) gave the env a lambda that loads its plans, so pickling it (a
    ``multiprocessing`` pool, a copy of a run's env) failed with "Can't pickle local object"; the copy goes on alike."""
    env = make_env(SCENES)
    fresh = pickle.loads(pickle.dumps(env))
    assert fresh.reset(seed=0)[1]["plan"] == env.reset(seed=0)[1]["plan"]
    copy = pickle.loads(pickle.dumps(env))  # mid-episode: the copy takes the same steps
    action = int(np.flatnonzero(env.action_masks())[0])
    original, copied = env.step(action), copy.step(action)
    assert original[1:4] == copied[1:4] and all(np.array_equal(original[0][k], copied[0][k]) for k in original[0])
    env.close()


def test_render_without_a_render_mode_warns_as_gymnasiums_envs_do():
    """``env.render()`` of an env made without ``render_mode`` returned None in silence (then ``plt.imshow(None)``
    failed far from the cause); Gymnasium's own envs warn, naming the keyword. It still returns None."""
    env = gym.make(f"cso_runtime.learned.env:{ENV_ID}", scenes=SCENES)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match=r'render_mode="rgb_array"'):
        assert env.unwrapped.render() is None
    env.close()
