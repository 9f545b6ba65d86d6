"""Work spread over processes that survives one of them dying (killed, out of memory).

A dead worker breaks a whole ``ProcessPoolExecutor`` (and hangs a ``multiprocessing.Pool.map``), so long
runs (an evaluation of hundreds of episodes, hours of teacher rollouts) would lose everything to one kill.
``run_each_in_own_process`` gives every job a process of its own, so a death costs that job only.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

J = TypeVar("J")
R = TypeVar("R")


class WorkerDied(RuntimeError):
    """The process running a job died before it returned."""


def ignore_sigint() -> None:
    """Pool initializer: Ctrl-C in a terminal reaches every process of the group, but only the parent
    should act on it (and stop the workers), or a worker's death would look like a crash."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_each_in_own_process(fn: Callable[[J], R], jobs: Sequence[J], workers: int, on_result: Callable[[J, R | WorkerDied], Any]) -> None:
    """``fn(job)`` for every job, each in a fresh spawned process, ``workers`` at a time. ``on_result(job,
    result)`` gets each result as it comes (one call at a time), or a ``WorkerDied`` for a job whose
    process died. ``fn`` and the jobs must be picklable; an exception ``fn`` raises is raised here."""
    ctx = multiprocessing.get_context("spawn")
    lock = threading.Lock()

    def one(job: J) -> None:
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=ignore_sigint) as pool:
            try:
                result: R | WorkerDied = pool.submit(fn, job).result()
            except BrokenProcessPool as exc:
                result = WorkerDied(f"its worker process died (killed, or out of memory?): {exc}")
        with lock:
            on_result(job, result)

    threads = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        for _ in threads.map(one, jobs):
            pass  # re-raises the first exception of a job, after the ones before it
    finally:
        threads.shutdown(wait=True, cancel_futures=True)  # on Ctrl-C: no new job; the running ones end
