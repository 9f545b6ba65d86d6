"""Environments in processes for training, that fail loudly: a dead environment process (killed, out of
memory) or Ctrl-C stops training at once with a clear error, never a hang on a pipe.

``WatchedAsyncVectorEnv`` is Gymnasium's ``AsyncVectorEnv`` with those checks; ``ppo.make_vector_env`` uses it.
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import gymnasium as gym
from gymnasium.vector.async_vector_env import AsyncState


def _worker_env(make: Callable[[], gym.Env]) -> gym.Env:
    """The env of an ``AsyncVectorEnv`` process. Ctrl-C in a terminal reaches every process of the group;
    only the parent acts on it (it closes the workers), so a worker does not die mid-step with a traceback."""
    if multiprocessing.parent_process() is not None:  # not the parent's own dummy env
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    return make()


class EnvWorkerDied(RuntimeError):
    """An environment process of an ``AsyncVectorEnv`` died (killed, out of memory)."""


class WatchedAsyncVectorEnv(gym.vector.AsyncVectorEnv):
    """``AsyncVectorEnv`` that notices a dead environment process instead of waiting for its answer
    forever or failing with a bare broken pipe: ``reset``, ``step`` and ``call`` raise ``EnvWorkerDied``
    naming the process, and closing then terminates the others."""

    poll_period_s = 0.5
    worker_died = False

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], **kwargs: Any) -> None:
        super().__init__([functools.partial(_worker_env, fn) for fn in env_fns], **kwargs)

    def _raise_if_dead(self) -> None:
        for i, process in enumerate(self.processes):
            if not process.is_alive():
                self.worker_died = True
                self._state = AsyncState.DEFAULT
                raise EnvWorkerDied(f"environment process {i} (pid {process.pid}) died with exit code {process.exitcode}")

    @contextlib.contextmanager
    def _watching(self) -> Iterator[None]:
        """A dead process breaks its pipe, on sending or on receiving: say which one died (it may take
        a moment to be reaped) and leave this env ready to close."""
        try:
            yield
        except (BrokenPipeError, ConnectionResetError, EOFError) as exc:
            self.worker_died = True
            self._state = AsyncState.DEFAULT
            for _ in range(20):
                self._raise_if_dead()
                time.sleep(0.1)
            raise EnvWorkerDied(f"lost the pipe to an environment process ({type(exc).__name__}: {exc})") from exc

    def reset(self, *args: Any, **kwargs: Any) -> Any:
        with self._watching():
            return super().reset(*args, **kwargs)

    def step(self, actions: Any) -> Any:
        with self._watching():
            return super().step(actions)

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        with self._watching():
            return super().call(name, *args, **kwargs)

    def _poll_pipe_envs(self, timeout: float | None = None) -> bool:
        """Without a timeout the base class waits on each pipe for good; a process that died without
        closing its end would never answer. Wait in short polls and check the processes in between."""
        if timeout is not None:
            return super()._poll_pipe_envs(timeout)
        self._assert_is_running()
        for pipe, process in zip(self.parent_pipes, self.processes):
            while not pipe.poll(self.poll_period_s) and process.is_alive():
                pass
        self._raise_if_dead()  # also when a pipe turned readable because it hit end-of-file
        return True

    def close_extras(self, timeout: float | None = None, terminate: bool = False) -> None:
        terminate = terminate or self.worker_died
        if terminate:
            self._state = AsyncState.DEFAULT  # terminating: do not wait for a step still under way
        super().close_extras(timeout, terminate)
