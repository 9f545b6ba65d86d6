"""Gymnasium environment over the exploration loop: one action = one goal choice, reward Eq. 6.

``reset`` picks a floor plan (seeded; ``options={"plan": NAME_OR_INDEX}`` chooses it), ``step(a)`` sends the robot to frontier cluster ``a`` and runs
the control loop until the Explorer asks for a new goal or the episode ends. The reward of a
decision is the sum over the control steps it took of R_step + lambda_c * (new open area, m2).
The action mask (valid distance + stuck masks, via ``ActionMasker``, as the policy applies them at
run time) is returned in ``info["action_mask"]`` as Gymnasium's spaces take one: ``np.int8`` of the action
space's size, 1 where the action is allowed, so ``env.action_space.sample(info["action_mask"])`` samples an
allowed action; ``action_masks()`` gives it as bool, as sb3-contrib's ``MaskablePPO`` asks an env. ``info["plan"]`` is
the name of the episode's floor plan.

Observation: the padded graph of ``graph.py`` as a ``spaces.Dict`` of fixed-shape boxes, so the
standard vector envs can stack it (``spaces.Graph`` has no fixed shape and cannot be batched); every entry has at
least one axis (``robot``, the robot node's index, is a one-element array), as Stable-Baselines3 needs.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cso_runtime.config import ExplorationConfig, MaskConfig, check_max_steps, setting_text, with_nearest
from cso_runtime.episode import TERMINATED_MAX_STEPS, Explorer, best_outcome, nearest_clusters, rollout_outcomes
from cso_runtime.learned.graph import (
    EDGE_FEATURE_NAMES,
    FEATURE_RANGES,
    GraphConfig,
    build_graph,
    empty_graph,
    frontier_count,
    node_features,
)
from cso_runtime.observation import Observation
from cso_runtime.policies import BASELINES, SCORE_BASELINES, ActionMasker, goal_of
from cso_runtime.scenes import FloorPlan, SceneRef
from cso_runtime.simulator import KinematicSimulator

RESET_OPTIONS = ("plan",)
"""The keys ``ExplorationEnv.reset(options=...)`` takes: ``plan``, the floor plan of the episode, by its name
(``info["plan"]``) or its index in the env's plans, instead of the seeded draw."""

NO_INVALID_ACTION = -1
"""``info["invalid_action"]`` where the step's action was allowed (and at ``reset``): the key is in every info, an int,
so that vector envs and loggers see one set of keys; a masked action's step holds that action."""

ROLLOUT_TRIES = 3
"""Clusters the rollout teacher tries per decision (the nearest allowed ones)."""


@dataclass
class RewardConfig:
    """Eq. 6: R_step per control step plus lambda_c per square metre of newly opened area."""

    r_step: float = -0.01
    """Step penalty R_step (per 0.25 s control step)."""
    lambda_c: float = 0.02
    """Weight lambda_c of the coverage reward (per m2 of new open space)."""
    scene_scale_area_m2: float = 0.0
    """> 0: every reward of a scene is multiplied by this over the scene's traversable area (ground truth,
    training only), so that scenes of every size weigh alike in the advantages and the value loss, while
    Eq. 6's trade-off between steps and area within a scene stays the same. 0: Eq. 6 as it is."""


def shipped_graph_config() -> GraphConfig:
    """The graph the shipped weights read (``configs/train.yaml``: the paper's node features plus each cluster's
    length, ``use_cluster_size``), ``EnvConfig``'s default so that the bare env's observations fit them."""
    return GraphConfig(use_cluster_size=True)


@dataclass
class EnvConfig:
    """What one training environment needs besides its scenes. Training builds its own from the recipe
    (``ppo.Args.env_config``); these defaults are the bare env's (``gymnasium.make``)."""

    exploration: ExplorationConfig = field(default_factory=ExplorationConfig)
    graph: GraphConfig = field(default_factory=shipped_graph_config)
    """The graph of the observations: the shipped weights' (``shipped_graph_config``). Other weights need the
    graph they were trained with: ``EnvConfig(graph=load_checkpoint(path)[1])``."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    max_steps: int = 800
    """Control steps per training episode (truncation; shorter than eval to see more scenes)."""
    invalid_action_limit: int = 100
    """Masked actions in a row after which the episode is truncated, so that an agent which ignores
    ``info["action_mask"]`` cannot loop forever (each one is a no-op costing one step penalty)."""
    cut_observation: str = "state"
    """The observation an episode cut by ``max_steps`` ends on, which PPO bootstraps through the cut with:
    ``state``, the graph of the state the cut left (textbook PPO), or ``empty``, the all-padding graph whose
    value is one constant for every cut (what the shipped weights were trained with; ``Args.cut_observation``)."""


def feature_box(features: tuple[str, ...], shape: tuple[int, ...]) -> spaces.Box:
    """A float32 Box of ``shape`` + one column per feature, each column bounded by its ``FEATURE_RANGES``."""
    low, high = (np.tile(np.array([FEATURE_RANGES[f][i] for f in features], np.float32), (*shape, 1)) for i in (0, 1))
    return spaces.Box(low, high, dtype=np.float32)


ROBOT_INDEX_SHAPE = (1,)
"""The shape of the observation's ``robot`` entry, the robot node's index: a one-element array, not ``build_graph``'s
0-d one, because Stable-Baselines3 takes no 0-d entry (its ``check_env`` fails on one, its ``MultiInputPolicy``
cannot flatten it and its rollout buffers give it back with an axis). The network reads either."""

LEGACY_ROBOT_INDEX_SHAPE = ()
"""``robot``'s shape in ``CSOExploration-v0`` (``LEGACY_ENV_ID``), kept for code written against that version."""


def graph_space(config: GraphConfig, robot_index_shape: tuple[int, ...] = ROBOT_INDEX_SHAPE) -> spaces.Dict:
    """The observation space of the frontier graph the network reads: fixed ``max_nodes`` x ``neighbours`` arrays,
    padded, with the ``*_valid`` masks marking the real entries (a Gymnasium space must have one shape), and the robot
    node's index (``ROBOT_INDEX_SHAPE``). Each feature has its range (``graph.FEATURE_RANGES``); positions and
    distances have no upper bound, so ``check_env`` still warns of infinite bounds."""
    n, k = config.max_nodes, config.neighbours
    return spaces.Dict(
        {
            "nodes": feature_box(node_features(config), (n,)),
            "node_valid": spaces.MultiBinary(n),
            "neighbours": spaces.Box(0, n - 1, (n, k), np.int64),
            "neighbour_valid": spaces.MultiBinary((n, k)),
            "edges": feature_box(EDGE_FEATURE_NAMES, (n, k)),
            "robot": spaces.Box(0, n - 1, robot_index_shape, np.int64),
        }
    )


def observation_of(graph: dict[str, np.ndarray], space: spaces.Dict) -> dict[str, np.ndarray]:
    """``graph`` (``build_graph``'s arrays) as ``space`` holds it: each array in its entry's dtype and shape (the valid
    flags as ``MultiBinary``'s int8, not bool; ``robot`` with the space's axis), as a vector env stacks them, so an
    agent sees the same arrays from one env and from many. The numbers are the graph's."""
    return {k: np.asarray(v, dtype=space[k].dtype).reshape(space[k].shape) for k, v in graph.items()}


def observation_layout(config: GraphConfig) -> dict[str, np.ndarray]:
    """The all-padding observation of the env (``empty_graph`` as the observation space holds it): the shapes and
    dtypes that training stores and that teacher-data files hold."""
    return observation_of(empty_graph(config), graph_space(config))


def entropy_window_problem(config: EnvConfig) -> str:
    """Why ``config``'s episodes and graph disagree on the entropy window, or empty: the episodes count I over
    ``exploration.frontier.entropy_window_m`` and the graph divides it by ``GraphConfig.entropy_window_m``, so two
    windows feed the network I scaled by their ratio (``EnvConfig(graph=load_checkpoint(path)[1])`` of weights trained
    with another window than the default 2 m). A graph that reads no I (``use_entropy`` false) takes any."""
    graph_m, frontier_m = config.graph.entropy_window_m, config.exploration.frontier.entropy_window_m
    if not config.graph.use_entropy or float(graph_m) == float(frontier_m):
        return ""
    return (
        f"EnvConfig: GraphConfig.entropy_window_m {setting_text(graph_m)} m, exploration.frontier.entropy_window_m {setting_text(frontier_m)} m: the"
        f" network would read I counted over one window and divided by the other (about {frontier_m / graph_m:g} times its"
        " scale); give both the window the weights were trained with: EnvConfig(graph=graph, exploration=dataclasses.replace("
        "ExplorationConfig(), frontier=FrontierConfig(entropy_window_m=graph.entropy_window_m)))"
    )


class ExplorationEnv(gym.Env):
    """One goal choice per step over ``KinematicSimulator``; plans drawn from ``plans`` each reset."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 4}  # type: ignore[misc]  # RUF012 vs gym.Env
    """``rgb_array``: ``render()`` is the robot's map at the current decision (``cso_runtime.frames``), one frame
    per goal choice, so ``gymnasium.wrappers.RecordVideo`` films the exploration."""

    def __init__(
        self,
        plans: list[FloorPlan] | Callable[[], list[FloorPlan]],
        config: EnvConfig | None = None,
        render_mode: str | None = None,
        render_scale: int = 2,
        robot_index_shape: tuple[int, ...] = ROBOT_INDEX_SHAPE,
    ) -> None:
        super().__init__()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r}: this environment renders {', '.join(self.metadata['render_modes'])} (or None)")
        self.render_mode = render_mode
        self.render_scale = render_scale
        """Image pixels per map cell along each axis."""
        self.config = config or EnvConfig()
        if problem := entropy_window_problem(self.config):
            raise ValueError(problem)
        self._plans_source = plans
        self._plans: list[FloorPlan] | None = None
        self.observation_space: spaces.Dict = graph_space(self.config.graph, robot_index_shape)
        self.action_space: spaces.Discrete = spaces.Discrete(self.config.graph.max_frontier_nodes)
        self.masker = ActionMasker(self.config.exploration.masks)
        self.explorer: Explorer | None = None
        self.obs: Observation | None = None
        self.mask = np.zeros(self.config.graph.max_frontier_nodes, dtype=bool)
        self._graph: dict[str, np.ndarray] | None = None  # the current decision's observation
        self.plan_name = ""
        """The name of the episode's floor plan (``info["plan"]``)."""
        self.invalid_actions = 0
        """Masked actions taken this episode (each rejected: ``info["invalid_actions"]``)."""
        self._invalid_in_a_row = 0
        self._over_at_reset = False
        """The episode ended before its first decision (``_end_at_first_step``)."""

    @property
    def plans(self) -> list[FloorPlan]:
        if self._plans is None:  # loaded lazily so a subprocess env loads its own copy
            self._plans = list(self._plans_source() if callable(self._plans_source) else self._plans_source)
            if not self._plans:
                raise ValueError("ExplorationEnv needs at least one floor plan")
        return self._plans

    def _explorer_config(self) -> ExplorationConfig:
        cfg = self.config.exploration
        return dataclasses.replace(cfg, episode=dataclasses.replace(cfg.episode, max_steps=self.config.max_steps))

    def _decide(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Advance to the next decision with at least one candidate; observe and mask it."""
        ex = self.explorer
        assert ex is not None
        while not ex.done:
            reason = ex.decision_reason()
            if reason is None:
                ex.advance()
                continue
            ex.handle_reason(reason)
            obs = ex.observe()
            if not obs.clusters:
                ex.apply_goal(obs, None)  # no reachable frontier: the episode ends
                break
            self.obs = obs
            self.mask = np.zeros(self.config.graph.max_frontier_nodes, dtype=bool)
            nf = frontier_count(obs, self.config.graph)
            self.mask[:nf] = self.masker.mask(obs)[:nf]
            if not self.mask.any():  # every kept candidate masked: fall back to all reachable ones
                self.mask[:nf] = np.isfinite(obs.goal_distance_m[:nf])
            self._graph = self._observation(build_graph(obs, self.config.graph))
            return self._graph, self._info()
        self.obs = None
        self.mask = np.zeros(self.config.graph.max_frontier_nodes, dtype=bool)
        self.mask[0] = True  # the episode is over: keep the distribution defined
        if ex.terminated_by == TERMINATED_MAX_STEPS and self.config.cut_observation == "state":
            # Cut by the step limit, not finished: PPO bootstraps through the cut with V of this observation,
            # so it must be the real state (the empty graph would give every cut episode the same constant).
            # Not masked: Algorithm 1's history has no decision here.
            final = ex.observe()
            if final.clusters:
                return self._observation(build_graph(final, self.config.graph)), self._info()
        return self._observation(empty_graph(self.config.graph)), self._info()

    def _observation(self, graph: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``graph`` as ``observation_space`` holds it (``observation_of``)."""
        return observation_of(graph, self.observation_space)

    def _info(self) -> dict[str, Any]:
        """The info of ``reset`` and ``step`` alike (Gymnasium wrappers expect one set of keys): ``decision_steps`` is 0
        until ``step`` sets the control steps its decision took; ``terminated_by`` is None while the episode goes on;
        ``invalid_action`` is ``NO_INVALID_ACTION`` until a masked action's step sets it."""
        ex = self.explorer
        assert ex is not None
        return {
            "action_mask": self.mask.astype(np.int8),  # Gymnasium's mask dtype (Discrete.sample(mask)); self.mask stays bool
            "coverage_pct": ex.coverage_pct(),
            "steps": ex.steps,
            "explored_area_m2": ex.explored_area_m2(),
            "invalid_actions": self.invalid_actions,
            "plan": self.plan_name,
            "terminated_by": ex.terminated_by,
            "decision_steps": 0,
            "invalid_action": NO_INVALID_ACTION,
        }

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """A new episode on a plan drawn from the env's plans (seeded), or on ``options["plan"]`` (``RESET_OPTIONS``):
        a plan's name or index. The draw happens either way, so that a chosen plan changes no other draw (the sensor
        noise's seed, the next resets' plans). Other option keys are refused (ValueError)."""
        super().reset(seed=seed)
        drawn = int(self.np_random.integers(len(self.plans)))
        chosen = self._chosen_plan(options)
        plan = self.plans[drawn if chosen is None else chosen]
        sim_seed = int(self.np_random.integers(2**31))  # sensor noise, when configured
        sim = KinematicSimulator(plan, self.config.exploration.sensor, self.config.exploration.robot, seed=sim_seed)
        self.explorer = Explorer(sim, self._explorer_config())
        self.explorer.end_if_covered()  # as eval's Explorer.run starts: a first scan that explored enough ends it
        self.masker.reset()
        self.plan_name = plan.name
        self.invalid_actions = self._invalid_in_a_row = 0
        graph, info = self._decide()
        self._over_at_reset = self.obs is None
        if self._over_at_reset:
            self._graph = graph
        return graph, info

    def _chosen_plan(self, options: dict[str, Any] | None) -> int | None:
        """The index of the plan ``options`` choose (``RESET_OPTIONS``), None where they choose none; a ValueError
        (TypeError for options that are no mapping) that says what it takes otherwise."""
        if options is None:
            return None
        if not isinstance(options, Mapping):
            raise TypeError(f"reset options must be a dict (keys: {', '.join(RESET_OPTIONS)}), got {type(options).__name__}")
        unknown = [str(key) for key in options if key not in RESET_OPTIONS]
        if unknown:
            said = ", ".join(with_nearest(key, RESET_OPTIONS, shown=repr(key)) for key in unknown)
            raise ValueError(f"reset options: unknown key(s) {said}; this env takes {', '.join(RESET_OPTIONS)} (a plan's name or index)")
        if "plan" not in options:
            return None
        plan, names = options["plan"], [p.name for p in self.plans]
        if isinstance(plan, str):
            if plan not in names:
                shown = ", ".join(names[:10]) + (f", ... ({len(names)} in all)" if len(names) > 10 else "")
                raise ValueError(f"reset options: no plan {with_nearest(plan, names, shown=repr(plan))} in this env; its plans: {shown}")
            return names.index(plan)
        if isinstance(plan, (int, np.integer)) and not isinstance(plan, bool):
            if not 0 <= plan < len(names):
                raise ValueError(f"reset options: plan index {plan} out of range: this env has {len(names)} plans (0 to {len(names) - 1})")
            return int(plan)
        raise ValueError(f"reset options: plan must be a plan's name (str) or its index (int), got {type(plan).__name__}")

    def step(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        ex = self.explorer
        if ex is None or (self.obs is None and not self._over_at_reset):
            raise RuntimeError("step() called before reset() or after the episode ended")
        a = int(action)
        if not self.action_space.contains(a):
            raise ValueError(f"action {a} is outside the action space Discrete({self.action_space.n})")
        if self._over_at_reset:
            return self._end_at_first_step()
        assert self.obs is not None  # the episode goes on: checked above
        if not self.mask[a]:
            return self._reject(a)
        self._invalid_in_a_row = 0
        area0, steps0 = ex.map.open_area_m2(), ex.steps
        goal = goal_of(self.obs, a)
        self.masker.chose(goal)
        ex.apply_goal(self.obs, goal)
        if not ex.done:
            ex.advance()  # the decision costs at least one control step
        graph, info = self._decide()
        r = self.config.reward
        reward = r.r_step * (ex.steps - steps0) + r.lambda_c * (ex.map.open_area_m2() - area0)
        if r.scene_scale_area_m2 > 0:
            reward *= r.scene_scale_area_m2 / max(ex.region_area_m2, 1e-9)
        truncated = ex.done and ex.terminated_by == TERMINATED_MAX_STEPS
        terminated = ex.done and not truncated
        info["decision_steps"] = ex.steps - steps0
        return graph, float(reward), terminated, truncated, info

    def _end_at_first_step(self) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """An episode over at ``reset`` (the first scan explored the plan, or left no reachable frontier) has no decision
        to take; a Gymnasium reset cannot say so, and vector envs and training loops step every env they reset, so its
        first step, whatever its action, ends it as ``reset`` left it: the same observation, no reward."""
        ex = self.explorer
        assert ex is not None and self._graph is not None
        self._over_at_reset = False
        truncated = ex.terminated_by == TERMINATED_MAX_STEPS
        graph = {k: v.copy() for k, v in self._graph.items()}
        return graph, 0.0, not truncated, truncated, self._info()

    def _reject(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """A masked action, as Gymnasium's Taxi treats an illegal move: nothing happens, the same decision is
        asked again, and it costs one step penalty; counted in ``info``, truncated after too many in a row."""
        assert self._graph is not None
        self.invalid_actions += 1
        self._invalid_in_a_row += 1
        truncated = self._invalid_in_a_row >= self.config.invalid_action_limit
        info = self._info()
        info["invalid_action"] = action
        if truncated:
            info["terminated_by"] = "invalid_actions"
            self.obs = None  # the episode is over: step() again needs reset()
        graph = {k: v.copy() for k, v in self._graph.items()}  # new arrays: the caller keeps the ones it had
        return graph, float(self.config.reward.r_step), False, truncated, info

    def close(self) -> None:
        """Let go of the episode (simulator, maps, the current graph) and of the loaded floor plans, which a closed env
        kept alive, and stepped on; ``step`` now needs a ``reset``, which loads the plans again."""
        self.explorer = None
        self.obs = None
        self._graph = None
        self._plans = None
        self._over_at_reset = False
        super().close()

    def action_masks(self) -> np.ndarray:
        """The current decision's action mask as bool (``info["action_mask"]`` holds it as ``np.int8``): the method
        sb3-contrib's ``MaskablePPO`` calls on an env (``get_action_masks``), and ``call("action_masks")`` in a vector
        env."""
        return self.mask.copy()

    def render(self) -> np.ndarray | None:
        """The map M_t, the path so far, the candidate goals (green allowed, red masked by the action mask) and
        the robot, as an RGB array (``render_mode="rgb_array"``); None without a render mode, with Gymnasium's warning."""
        if self.render_mode is None:
            gym.logger.warn(
                'render() without a render mode returns None: make the env with render_mode="rgb_array" '
                f'(gymnasium.make("{ENV_ID}", ..., render_mode="rgb_array")) for an image of the map'
            )
            return None
        ex = self.explorer
        if ex is None:
            raise RuntimeError("render() called before reset()")
        from cso_runtime.frames import map_frame  # noqa: PLC0415  (only rendering environments need it)

        obs = self.obs
        n = frontier_count(obs, self.config.graph) if obs is not None else 0
        return map_frame(
            ex.map.explored,
            ex.map.occupied,
            ex.map.geometry,
            obs.pose if obs is not None else ex.sim.true_pose(),
            robot_radius_m=self.config.exploration.robot.radius_m,
            frontier=obs.frontier if obs is not None else None,
            trajectory_xy_m=np.array(ex.trajectory, dtype=float),
            goals_xy_m=obs.goal_xy_m[:n] if obs is not None else None,
            allowed=self.mask[:n],
            scale=self.render_scale,
        )

    def teacher_action(self, teacher: str = "greedy-dist") -> int:
        """The warm-start teacher's choice for the current observation (callable through any vector env)."""
        return self.teacher_label(teacher)[0]

    def teacher_label(self, teacher: str = "greedy-dist") -> tuple[int, np.ndarray]:
        """The teacher's choice and, for the rollout teacher, each tried cluster's episode length in control
        steps (``inf`` for clusters not tried; all ``inf`` for the score-based teachers)."""
        steps = np.full(self.config.graph.max_frontier_nodes, np.inf, dtype=np.float32)
        if self.obs is None or self.explorer is None:
            return int(np.argmax(self.mask)), steps
        if teacher != "rollout":
            return expert_action(self.obs, self.mask, teacher), steps
        n = frontier_count(self.obs, self.config.graph)
        candidates = nearest_clusters(self.obs.goal_distance_m[:n], self.mask[:n], ROLLOUT_TRIES)
        if len(candidates) == 0:
            return int(np.argmax(self.mask)), steps
        outcomes = rollout_outcomes(self.explorer, self.obs, candidates, BASELINES["greedy-dist"]())
        steps[candidates] = [s for s, _ in outcomes]
        return best_outcome(candidates, outcomes), steps


TEACHERS = ("greedy-dist", "utility", "greedy-info", "rollout")
"""What the warm start can imitate: a baseline's score taken under the variant's masks, or ``rollout``
(greedy-dist's best continuation found by simulating; slow: about ``ROLLOUT_TRIES`` episodes' worth of
control steps per decision)."""


def expert_action(obs: Observation, mask: np.ndarray, teacher: str = "greedy-dist") -> int:
    """The ``teacher`` baseline's choice under the mask (bool, or the env's ``np.int8`` of 0 and 1): the allowed
    reachable cluster of lowest cost (greedy-dist: the nearest)."""
    mask = np.asarray(mask, dtype=bool)  # an int8 mask would index by position
    if teacher not in TEACHERS:
        raise ValueError(f"unknown warm-start teacher {teacher!r}; choose one of {', '.join(TEACHERS)}")
    if teacher not in SCORE_BASELINES:
        why = "ExplorationEnv.teacher_label gives its choice"
        raise ValueError(f"the {teacher} teacher has no score to take under a mask: {why}")
    n = min(len(obs.clusters), len(mask))
    cost = np.full(len(mask), np.inf)
    if n:
        cost[:n] = np.where(np.isfinite(obs.goal_distance_m[:n]), SCORE_BASELINES[teacher]().cost(obs)[:n], np.inf)
    cost[~mask] = np.inf
    return int(np.argmin(cost)) if np.isfinite(cost).any() else int(np.argmax(mask))


def mask_config_for(use_valid_distance: bool, use_stuck: bool, base: MaskConfig | None = None) -> MaskConfig:
    """A copy of ``base`` with the two masks switched as a variant needs."""
    return dataclasses.replace(base or MaskConfig(), use_valid_distance=use_valid_distance, use_stuck=use_stuck)


ENV_ID = "CSOExploration-v1"
"""Registered with Gymnasium when this module is imported, so the standard entry point works without
any other import: ``gymnasium.make("cso_runtime.learned.env:CSOExploration-v1", scenes="generated:middle:8:0")``.
v1: ``robot`` is a one-element array (``ROBOT_INDEX_SHAPE``)."""

LEGACY_ENV_ID = "CSOExploration-v0"
"""The version before: the same env with ``robot`` a 0-d array (``LEGACY_ROBOT_INDEX_SHAPE``), still registered."""


def make_env(
    scenes: str = "builtin",
    limit: int | None = None,
    m_per_px: float = 0.05,
    config: EnvConfig | None = None,
    render_mode: str | None = None,
    render_scale: int = 2,
    robot_index_shape: tuple[int, ...] = ROBOT_INDEX_SHAPE,
    max_steps: int | None = None,
) -> ExplorationEnv:
    """An ``ExplorationEnv`` over a scene spec (as ``eval --maps``: ``builtin``, a folder of PNG plans,
    ``generated:SCALE:N:SEED``); PNG plans at ``m_per_px`` (0.05: Dungeon's large scale, where ``eval --m-per-px`` takes
    0.1, super large, unless told). The plans load at the first reset. ``max_steps``, given, is the episode's step
    limit in control steps of 0.25 s (``EnvConfig.max_steps``, over ``config``'s; Gymnasium's own
    ``max_episode_steps`` counts decisions): an integer (NumPy's too) from 1 to ``config.MAX_EPISODE_STEPS``."""
    from cso_runtime.scenes import resolve_scenes  # noqa: PLC0415

    if max_steps is not None:
        if isinstance(max_steps, bool) or not isinstance(max_steps, numbers.Integral) or max_steps < 1:  # np.int64 too
            raise ValueError(f"max_steps must be a positive number of control steps (0.25 s each), got {max_steps!r}")
        check_max_steps(int(max_steps), "max_steps")  # as episode.max_steps is bounded (a ConfigError, a ValueError)
        config = dataclasses.replace(config or EnvConfig(), max_steps=int(max_steps))
    refs = resolve_scenes(scenes, limit, m_per_px)  # a bad spec fails here, not at the first reset
    plans = functools.partial(_load_scenes, refs)  # not a lambda: the env pickles (multiprocessing, copies of a run's env)
    return ExplorationEnv(plans, config, render_mode=render_mode, render_scale=render_scale, robot_index_shape=robot_index_shape)


def _load_scenes(refs: list[SceneRef]) -> list[FloorPlan]:
    return [ref.load() for ref in refs]


def make_legacy_env(**kwargs: Any) -> ExplorationEnv:
    """``make_env`` with ``LEGACY_ENV_ID``'s observation layout (``robot`` 0-d)."""
    return make_env(**kwargs, robot_index_shape=LEGACY_ROBOT_INDEX_SHAPE)


# gymnasium.make reads the entry point's render modes, so that it wraps render_mode="human" (HumanRendering) and
# "rgb_array_list" (RenderCollection)
make_env.metadata = make_legacy_env.metadata = ExplorationEnv.metadata  # type: ignore[attr-defined]
gym.register(id=ENV_ID, entry_point=f"{__name__}:{make_env.__name__}")  # by name, so that env.spec.to_json() works
gym.register(id=LEGACY_ENV_ID, entry_point=f"{__name__}:{make_legacy_env.__name__}")
