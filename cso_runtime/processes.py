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


def terminate_workers(pool: ProcessPoolExecutor) -> None:
    """Stop a pool's processes now (Ctrl-C, an error): ``shutdown`` alone waits for running jobs."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def run_each_in_own_process(fn: Callable[[J], R], jobs: Sequence[J], workers: int, on_result: Callable[[J, R | WorkerDied], Any]) -> None:
    """``fn(job)`` for every job, each in a fresh spawned process, ``workers`` at a time. ``on_result(job,
    result)`` gets each result as it comes (one call at a time), or a ``WorkerDied`` for a job whose
    process died. ``fn`` and the jobs must be picklable; an exception ``fn`` or ``on_result`` raises, or
    Ctrl-C, stops every running process at once and is raised here."""
    ctx = multiprocessing.get_context("spawn")
    lock = threading.Lock()
    running: set[ProcessPoolExecutor] = set()
    stopping = threading.Event()

    def one(job: J) -> None:
        if stopping.is_set():
            return
        pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=ignore_sigint)
        with lock:
            running.add(pool)
        try:
            result: R | WorkerDied = pool.submit(fn, job).result()
        except BrokenProcessPool as exc:
            result = WorkerDied(f"its worker process died (killed, or out of memory?): {exc}")
        finally:
            with lock:
                running.discard(pool)
            pool.shutdown(wait=True, cancel_futures=True)
        with lock:
            if not stopping.is_set():
                on_result(job, result)

    threads = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        for _ in threads.map(one, jobs):
            pass  # re-raises the first exception of a job, after the ones before it
    except BaseException:
        stopping.set()
        with lock:
            for pool in running:
                terminate_workers(pool)
        raise
    finally:
        threads.shutdown(wait=True, cancel_futures=True)
