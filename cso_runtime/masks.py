"""Action masks of section 3.3: the valid distance mask (Eq. 5) and the stuck mask (Algorithm 1)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cso_runtime.config import MaskConfig


def valid_distance_mask(distances_m: np.ndarray, beta_near_m: float, beta_far_m: float) -> tuple[np.ndarray, str]:
    """Eq. 5 with both fallbacks of section 3.3.

    Keeps frontiers whose geodesic distance lies in [beta_near, beta_far]. If none does, drops the
    near bound ([0, beta_far]); if still none, drops the far bound too (every reachable frontier).
    Returns the boolean mask (True = may be chosen) and which rule applied: ``"range"``,
    ``"no_near"`` or ``"all"``. Unreachable (infinite) frontiers are never valid.
    """
    d = np.asarray(distances_m, dtype=float)
    reachable = np.isfinite(d)
    mask = reachable & (d >= beta_near_m) & (d <= beta_far_m)
    if mask.any():
        return mask, "range"
    mask = reachable & (d <= beta_far_m)
    if mask.any():
        return mask, "no_near"
    return reachable.copy(), "all"


@dataclass(frozen=True)
class DecisionRecord:
    """Where the robot was when it chose a goal, and how much it had explored then."""

    position_xy_m: tuple[float, float]
    explored_area_m2: float
    moved_m: float
    """Distance from the previous decision position: geodesic, or straight-line where the previous position
    is off the traversable space (inf for the first decision)."""


DistanceFrom = Callable[[tuple[float, float], float], np.ndarray]
"""Given a source position and a bound (metres), geodesic distances from the source to each candidate
goal: exact below the bound; candidates farther away may read inf."""


class StuckMask:
    """Algorithm 1: when the last decisions neither moved nor explored, mask goals near them.

    Keeps the positions and explored areas of the last three decisions (w_t, w_{t-1}, w_{t-2}) and the
    last three goals chosen; ``config.stuck_avoid`` says which of the two the new goal must keep away from.
    """

    def __init__(self, config: MaskConfig) -> None:
        self.config = config
        self.history: deque[DecisionRecord] = deque(maxlen=3)
        self.goals: deque[tuple[float, float]] = deque(maxlen=3)

    def reset(self) -> None:
        self.history.clear()
        self.goals.clear()

    def record(self, position_xy_m: tuple[float, float], explored_area_m2: float, moved_m: float) -> None:
        """Add the current decision (w_t, ||M_t||) and the geodesic distance moved since the last one."""
        self.history.append(DecisionRecord((float(position_xy_m[0]), float(position_xy_m[1])), float(explored_area_m2), float(moved_m)))

    def record_goal(self, goal_xy_m: tuple[float, float]) -> None:
        """Add the goal the current decision chose."""
        self.goals.append((float(goal_xy_m[0]), float(goal_xy_m[1])))

    def reference_points(self) -> list[tuple[float, float]]:
        """What a new goal keeps alpha_3 away from when stuck: the last three decision positions, or
        the last three goals chosen (``config.stuck_avoid``)."""
        if self.config.stuck_avoid == "goals":
            return list(self.goals)
        return [record.position_xy_m for record in self.history]

    def is_stuck(self) -> bool:
        """l_max < alpha_1 and c_max < alpha_2 over the last three decisions."""
        if len(self.history) < 3:
            return False
        h = list(self.history)
        l_max = max(h[1].moved_m, h[2].moved_m)
        c_max = max(abs(h[1].explored_area_m2 - h[0].explored_area_m2), abs(h[2].explored_area_m2 - h[1].explored_area_m2))
        return l_max < self.config.alpha1_m and c_max < self.config.alpha2_m2

    def mask(self, n_candidates: int, distance_from: DistanceFrom) -> np.ndarray:
        """True for candidates that may be chosen. When stuck, candidates closer than alpha_3 to any
        of the reference points (``reference_points``) are masked; ``distance_from`` is only called
        then, and only distances below alpha_3 are asked for (a bounded fast-marching pass is enough)."""
        allowed = np.ones(n_candidates, dtype=bool)
        if n_candidates == 0 or not self.is_stuck():
            return allowed
        alpha3 = self.config.alpha3_m
        for point in self.reference_points():
            allowed &= ~(np.asarray(distance_from(point, alpha3), dtype=float) < alpha3)
        return allowed
