"""An environment process that never answers a step and ignores SIGTERM: what closing training's environment
processes (``WatchedAsyncVectorEnv.close``) must still end within its bound (tests/test_learned.py)."""

from __future__ import annotations

import multiprocessing
import signal
import threading
from typing import Any

import gymnasium as gym
import numpy as np


class StuckEnv(gym.Env):
    """Resets at once; its step waits for ever. In an environment process (not the parent's own dummy env,
    which ``AsyncVectorEnv`` builds in the test's process) SIGTERM is ignored from the start."""

    observation_space = gym.spaces.Box(0.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self) -> None:
        if multiprocessing.parent_process() is not None:
            signal.signal(signal.SIGTERM, signal.SIG_IGN)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action: Any) -> Any:
        threading.Event().wait()


class StuckInitEnv(StuckEnv):
    """Its environment processes never finish building it (and ignore SIGTERM): ``AsyncVectorEnv``'s constructor
    waits on their answer for ever; only a stop (Ctrl-C) ends it. The parent's own dummy env builds at once."""

    def __init__(self) -> None:
        super().__init__()
        if multiprocessing.parent_process() is not None:
            threading.Event().wait()
