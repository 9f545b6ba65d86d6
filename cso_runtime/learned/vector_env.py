"""Environments in processes for training, that fail loudly: a dead environment process (killed, out of
memory) or Ctrl-C stops training at once with a clear error, never a hang on a pipe; closing them takes a bounded
time, whatever their processes do (``close_grace_s``).

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

from cso_runtime.processes import stop_processes


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
    naming the process, and closing then terminates the others. Closing never waits without a bound: an
    environment process that does not answer (stuck in a step) or does not end (ignoring SIGTERM) is killed after
    ``close_grace_s``, and one of a constructor stopped half way (Ctrl-C while they start) is stopped there."""

    poll_period_s = 0.5
    close_grace_s = 5.0
    """The most closing waits at each stage: for a step under way and the processes' answers to ``close``, then for
    them to end after SIGTERM, then after SIGKILL."""
    worker_died = False

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], **kwargs: Any) -> None:
        try:
            super().__init__([functools.partial(_worker_env, fn) for fn in env_fns], **kwargs)
        except BaseException:  # Ctrl-C or an error while the processes start: no object to close, so stop them here
            stop_processes(getattr(self, "processes", []), self.close_grace_s)
            for pipe in getattr(self, "parent_pipes", []):
                if pipe is not None:
                    pipe.close()
            raise

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
        """Gymnasium's close, bounded: without ``terminate`` it waits (at most ``timeout``, else ``close_grace_s``) for a
        step under way and each process's answer to ``close``; a process that has not answered by then, or any with
        ``terminate`` (or after one died), gets SIGTERM, then SIGKILL (``processes.stop_processes``). Gymnasium's own
        waits on the answer to ``close`` and joins the processes with no bound."""
        grace = self.close_grace_s if timeout is None else timeout
        deadline = time.monotonic() + grace
        if not (terminate or self.worker_died):
            terminate = not self._closed_by_asking(deadline)
        self._state = AsyncState.DEFAULT
        for pipe in self.parent_pipes:
            if pipe is not None:
                pipe.close()
        if terminate:
            stop_processes(self.processes, grace)
        else:  # each answered: its process ends on its own, at once
            for process in self.processes:
                process.join(max(0.0, deadline - time.monotonic()))
            stop_processes(self.processes, grace)  # any still running (nothing to do where each has ended)

    def _closed_by_asking(self, deadline: float) -> bool:
        """Gymnasium's clean close, each wait bounded by ``deadline``: the step (or reset, call) under way finished,
        then ``close`` sent to each process and its answer read. False where any of it did not happen in time or failed
        (a dead process, a broken pipe): the processes are to be terminated."""
        try:
            if self._state != AsyncState.DEFAULT:
                pending = getattr(self, f"{self._state.value}_wait")
                pending(max(0.0, deadline - time.monotonic()))
            pipes = [pipe for pipe in self.parent_pipes if pipe is not None and not pipe.closed]
            for pipe in pipes:
                pipe.send(("close", None))
            for pipe in pipes:
                if not pipe.poll(max(0.0, deadline - time.monotonic())):
                    return False
                pipe.recv()
        except Exception:  # noqa: BLE001  (a timeout, a dead process, an error of its env: all end in terminating)
            return False
        return True
