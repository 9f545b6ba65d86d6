"""Goal selectors: the baselines of the paper and explore_lite, behind one small interface.

A selector takes an Observation and returns a Goal (or None when no frontier is reachable). The
learned CSO policy implements the same Protocol, so every caller treats them alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from cso_runtime.config import ConfigError, FrontierConfig, MaskConfig, SensorConfig, import_attribute, with_nearest
from cso_runtime.masks import StuckMask, valid_distance_mask
from cso_runtime.observation import Observation


@dataclass(frozen=True)
class Goal:
    """A long-term goal: a frontier cluster's goal cell in the map frame."""

    x_m: float
    y_m: float
    cluster_index: int
    """Index of the chosen cluster in ``Observation.clusters``."""
    distance_m: float


@runtime_checkable
class GoalSelector(Protocol):
    """Chooses the next long-term goal among the frontier clusters.

    A selector may say which of the Observation's grids ``select`` reads (``grids``, a tuple of
    explored, occupied, traversable, frontier, entropy): a policy service then decodes only those from
    a decision message (the others are None there). Without it, every grid is decoded. A selector may
    also have ``warm_up()``, which a policy service calls before it says it is up (one-off costs, such
    as building the learned policy's traced network, then stay off the first decision)."""

    name: str

    def reset(self, seed: int | None = None) -> None:
        """Forget history at the start of an episode; re-seed any randomness."""

    def select(self, obs: Observation) -> Goal | None:
        """The next goal, or None when there is no reachable frontier."""


def goal_of(obs: Observation, index: int) -> Goal:
    """The goal of the observation's cluster ``index`` (its goal point and path distance), as a policy returns it."""
    c = obs.clusters[index]
    return Goal(c.goal_xy_m[0], c.goal_xy_m[1], index, c.distance_m)


class ActionMasker:
    """Both masks of section 3.3 over an observation's clusters, as used by the learned policy.

    ``mask(obs)`` also records the decision for Algorithm 1, so call it exactly once per decision, and
    ``chose(goal)`` with the goal that decision chose.
    """

    def __init__(self, config: MaskConfig) -> None:
        self.config = config
        self.stuck = StuckMask(config)
        self.last_rule = "off"

    def reset(self) -> None:
        self.stuck.reset()

    def mask(self, obs: Observation) -> np.ndarray:
        """Which clusters may be chosen (one bool each): reachable, within the valid-distance mask (Eq. 5) and, unless the
        masks conflict (``conflict`` decides), the stuck mask (Algorithm 1); records this decision for Algorithm 1."""
        n = len(obs.clusters)
        d = obs.goal_distance_m
        allowed = np.isfinite(d)
        if self.config.use_valid_distance:
            vdm, self.last_rule = valid_distance_mask(d, self.config.beta_near_m, self.config.beta_far_m)
            allowed &= vdm
        self.stuck.record((obs.pose.x_m, obs.pose.y_m), obs.open_area_m2, self.moved_since_last_decision(obs))
        if self.config.use_stuck:
            stuck_allowed = self.stuck.mask(n, obs.goal_distances_from)
            if (allowed & stuck_allowed).any():
                allowed &= stuck_allowed
            elif self.config.use_valid_distance and self.config.conflict == "stuck" and (stuck_allowed & np.isfinite(d)).any():
                # Eq. 5's fallbacks over what the stuck mask leaves: the nearest way out of the stuck place
                allowed, self.last_rule = valid_distance_mask(np.where(stuck_allowed, d, np.inf), self.config.beta_near_m, self.config.beta_far_m)
        return allowed

    def chose(self, goal: Goal | None) -> None:
        """The goal the decision just masked chose (Algorithm 1's past goals); None chose nothing."""
        if goal is not None:
            self.stuck.record_goal((goal.x_m, goal.y_m))

    def moved_since_last_decision(self, obs: Observation) -> float:
        """Algorithm 1's moving length since the last decision: geodesic on D where the last position is
        on the traversable space, straight-line where it is not (a robot pushed into the inflation band
        by a wall, the very case the mask is for, would otherwise never count as stuck); inf at the first."""
        if not self.stuck.history:
            return np.inf
        last = self.stuck.history[-1].position_xy_m
        moved = float(obs.distance_at(np.array([last]))[0])
        if np.isfinite(moved):
            return moved
        return float(np.hypot(obs.pose.x_m - last[0], obs.pose.y_m - last[1]))


class _ScoreSelector:
    """A baseline that picks the reachable cluster with the best score (lowest cost)."""

    name = "base"
    grids: tuple[str, ...] = ()
    """The scores read the clusters only."""

    def reset(self, seed: int | None = None) -> None:
        pass

    def cost(self, obs: Observation) -> np.ndarray:
        raise NotImplementedError

    def select(self, obs: Observation) -> Goal | None:
        if not obs.clusters:
            return None
        cost = np.where(np.isfinite(obs.goal_distance_m), self.cost(obs), np.inf)
        if not np.isfinite(cost).any():
            return None
        return goal_of(obs, int(np.argmin(cost)))  # ties: the nearer cluster (clusters are sorted by distance)


class GreedyDist(_ScoreSelector):
    """Greedy-Dist: the nearest frontier cluster by geodesic distance."""

    name = "greedy-dist"

    def cost(self, obs: Observation) -> np.ndarray:
        return obs.goal_distance_m


class GreedyInfo(_ScoreSelector):
    """Greedy-Info: the cluster with the highest frontier-based entropy I (Eq. 4)."""

    name = "greedy-info"

    def cost(self, obs: Observation) -> np.ndarray:
        return -np.array([c.entropy for c in obs.clusters], dtype=float)


class Utility(_ScoreSelector):
    """explore_lite's frontier cost: potential_scale * distance - gain_scale * size (lowest wins)."""

    name = "utility"

    def __init__(self, potential_scale: float = 3.0, gain_scale: float = 1.0) -> None:
        self.potential_scale = potential_scale
        self.gain_scale = gain_scale

    def cost(self, obs: Observation) -> np.ndarray:
        size = np.array([c.size_m for c in obs.clusters], dtype=float)
        return self.potential_scale * obs.goal_distance_m - self.gain_scale * size


class RandomFrontier:
    """Random: a uniformly random reachable cluster (seeded)."""

    name = "random"
    grids: tuple[str, ...] = ()

    def __init__(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self.rng = np.random.default_rng(seed)

    def select(self, obs: Observation) -> Goal | None:
        reachable = np.flatnonzero(np.isfinite(obs.goal_distance_m))
        if reachable.size == 0:
            return None
        return goal_of(obs, int(self.rng.choice(reachable)))


SCORE_BASELINES: dict[str, Callable[[], _ScoreSelector]] = {
    "greedy-dist": GreedyDist,
    "greedy-info": GreedyInfo,
    "utility": Utility,
}
"""The baselines that rank the clusters by a score (``cost``): what the warm start can imitate under any mask."""

BASELINES: dict[str, Callable[[], GoalSelector]] = {**SCORE_BASELINES, "random": RandomFrontier}

@dataclass(frozen=True)
class Variant:
    """Table 2's switches: the entropy input and the two action masks."""

    use_entropy: bool
    use_valid_distance: bool
    use_stuck: bool


VARIANTS: dict[str, Variant] = {
    "cso": Variant(True, True, True),
    "cso-no-info": Variant(False, True, True),
    "cso-no-mask": Variant(True, False, False),
    "cso-sm": Variant(True, False, True),
    "cso-vdm": Variant(True, True, False),
    "gnn-baseline": Variant(False, False, False),
}
"""The learned methods and their switches (``learned.registry`` loads their networks); here, without torch, so that
the launcher and the CLI know them before anything starts."""

LEARNED_METHODS = tuple(VARIANTS)


def available_methods() -> list[str]:
    """The methods this install can run: every baseline, and each learned method whose weights file is found."""
    return list(BASELINES) + [m for m in LEARNED_METHODS if _learned_available(m)]


def weights_held_said() -> str:
    """The learned methods whose weights the weights folder holds, for the error of a method it has none for: a
    training run's folder holds the variant it was trained as (``train --variant cso-sm``), to run as ``--method
    cso-sm``, not as ``cso``. "" when it holds none. ``eval`` and ``up`` say it alike."""
    available = available_methods()
    held = [m for m in LEARNED_METHODS if m in available]
    return f"it holds those of {', '.join(held)} (--method {','.join(held)})" if held else ""


def unknown_methods_said(names: list[str], groups: bool = False) -> str:
    """``unknown method 'greedy-dsit' (did you mean greedy-dist?); available: ...``: the one wording of unknown
    method names, each with the known name it most likely misspells; ``groups``: the list (``--method``) also takes
    ``METHOD_GROUPS``."""
    known = [*BASELINES, *LEARNED_METHODS, *registered_methods(), *(METHOD_GROUPS if groups else ())]
    said = ", ".join(with_nearest(name, known, shown=repr(name)) for name in names)
    return f"unknown method{'s' if len(names) > 1 else ''} {said}; available: {', '.join(known)}, or a method of your own as module.path:Attribute"


METHOD_GROUPS = ("all", "baselines", "learned")
"""Names that stand for several methods in a ``--method`` list (``parse_methods``)."""


def parse_methods(spec: str) -> list[str]:
    """The methods of a comma-separated ``--method`` list, in order, each once. ``all`` is every baseline and
    every learned method whose weights are found, ``baselines`` the four frontier rules, ``learned`` the learned
    methods whose weights are found (Table 1 and Table 2 in one run). Other names are kept as given, so that
    the caller names an unknown one in its error."""
    methods: list[str] = []
    for name in (part.strip() for part in spec.split(",")):
        if name == "all":
            expanded = available_methods()
        elif name == "baselines":
            expanded = list(BASELINES)
        elif name == "learned":
            expanded = [m for m in available_methods() if m in LEARNED_METHODS]
        else:
            expanded = [name] if name else []
        methods.extend(m for m in expanded if m not in methods)
    return methods


def _learned_available(name: str) -> bool:
    from cso_runtime.learned.weights import has_weights  # noqa: PLC0415 - no torch: only where the file is

    return has_weights(name)


def make_policy(
    name: str,
    mask_config: MaskConfig | None = None,
    seed: int | None = None,
    device: str = "cpu",
    sensor: SensorConfig | None = None,
    frontier: FrontierConfig | None = None,
) -> GoalSelector:
    """Build a goal selector by name (``greedy-dist``, ``greedy-info``, ``utility``, ``random``, ``cso``...), or a
    method of the user's own (``module.path:Attribute`` or a registered name: ``own_selector``). A learned method loads the weights trained with ``sensor``'s field of view where they ship,
    and refuses (ValueError) a ``frontier`` setting that would feed its network inputs of another scale than it was trained on
    (``registry.input_verdict``; None: ``FrontierConfig``'s defaults, what ``ObservationBuilder()`` builds with)."""
    if name in BASELINES or own_method_spec(name):
        policy = BASELINES[name]() if name in BASELINES else own_selector(name)
        policy.reset(seed)
        return policy
    if name in LEARNED_METHODS:
        from cso_runtime.learned import registry  # noqa: PLC0415 - torch only when needed

        return registry.make_learned_policy(name, mask_config or MaskConfig(), seed=seed, device=device, sensor=sensor, frontier=frontier)
    raise ValueError(unknown_methods_said([name]))


METHOD_ENTRY_POINTS = "cso_runtime.methods"
"""Entry-point group under which an installed package registers its goal selectors by a short name
(``name = "module.path:Attribute"``, as ``--method`` takes it)."""

SELECTOR_MEMBERS = ("name", "reset", "select")
"""What a goal selector must have (the ``GoalSelector`` Protocol)."""


def registered_methods() -> dict[str, str]:
    """Short name -> ``module.path:Attribute`` of the methods installed packages register (``METHOD_ENTRY_POINTS``);
    a built-in name wins over a registered one."""
    from importlib.metadata import entry_points  # noqa: PLC0415 - scans the installed packages: only for a name not built in

    return {ep.name: ep.value for ep in entry_points(group=METHOD_ENTRY_POINTS) if ep.name not in BASELINES and ep.name not in LEARNED_METHODS}


def own_method_spec(name: str) -> str | None:
    """The ``module.path:Attribute`` that ``name`` stands for when it is a method of the user's own: itself when it
    has a colon, a registered method's spec for its short name; None for a built-in or unknown name."""
    if ":" in name:
        return name
    if name in BASELINES or name in LEARNED_METHODS or name in METHOD_GROUPS:
        return None
    return registered_methods().get(name)


def own_selector_factory(spec: str) -> Callable[[], object]:
    """The object ``module.path:Attribute`` names (a GoalSelector class or a zero-argument function returning one),
    imported as uvicorn or an entry point would; ConfigError saying which part is wrong."""
    found = import_attribute(spec, f"method {spec!r}", "a method of your own is written module.path:Attribute (e.g. my_package.selectors:Nearest)")
    if not callable(found):
        where = spec.replace(":", ".")
        raise ConfigError(f"method {spec!r}: {where} is a {type(found).__name__}, not a GoalSelector class or a function that returns one")
    return found


def own_selector(name: str) -> GoalSelector:
    """A new selector of the user's own method ``name`` (``own_method_spec``): its class or factory called with no
    arguments (``make_policy`` then calls ``reset(seed)``, as ``run_episode`` does before each episode); ConfigError
    when it cannot be built or is no GoalSelector (no ``name``, ``reset`` or ``select``)."""
    spec = own_method_spec(name)
    if spec is None:
        raise ConfigError(unknown_methods_said([name]))
    factory = own_selector_factory(spec)
    try:
        selector = factory()
    except Exception as exc:  # a constructor that wants arguments, or fails: the user's code, said as such
        raise ConfigError(f"method {name!r}: calling {spec} with no arguments failed: {type(exc).__name__}: {exc}") from exc
    missing = [m for m in SELECTOR_MEMBERS if not hasattr(selector, m) or (m != "name" and not callable(getattr(selector, m)))]
    if missing:
        raise ConfigError(
            f"method {name!r}: {spec}() gave a {type(selector).__name__}, not a GoalSelector: it has no {', '.join(missing)} "
            "(a goal selector has a name, reset(seed) and select(obs) -> Goal | None)"
        )
    return selector  # type: ignore[return-value]  # checked member by member above


def check_method(name: str) -> None:
    """ConfigError unless ``name`` is a built-in method or a method of the user's own that builds a GoalSelector
    (imported and built once here, so a bad one is said before anything starts). Learned weights are checked elsewhere."""
    if name in BASELINES or name in LEARNED_METHODS:
        return
    own_selector(name)
