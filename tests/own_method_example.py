"""A goal selector of one's own, as docs/own-method.md writes it: ``--method tests.own_method_example:NearestStraightLine``."""

from __future__ import annotations

import numpy as np

from cso_runtime.observation import Observation
from cso_runtime.policies import Goal, goal_of


class NearestStraightLine:
    """The reachable frontier cluster whose goal is nearest in a straight line from the robot."""

    name = "nearest-straight-line"
    grids: tuple[str, ...] = ()  # reads the clusters only: a policy service decodes no grid for it

    def reset(self, seed: int | None = None) -> None:
        pass  # no history, no randomness

    def select(self, obs: Observation) -> Goal | None:
        reachable = [i for i, c in enumerate(obs.clusters) if np.isfinite(c.distance_m)]
        if not reachable:
            return None  # nothing left to explore

        def straight_line_m(i: int) -> float:
            x_m, y_m = obs.clusters[i].goal_xy_m
            return float(np.hypot(x_m - obs.pose.x_m, y_m - obs.pose.y_m))

        return goal_of(obs, min(reachable, key=straight_line_m))


def make_nearest() -> NearestStraightLine:
    """A zero-argument factory: ``--method tests.own_method_example:make_nearest`` takes it as well as the class."""
    return NearestStraightLine()


NOT_A_SELECTOR = dict
"""Callable, but what it builds has no ``reset`` or ``select``: ``--method tests.own_method_example:NOT_A_SELECTOR`` is refused."""
