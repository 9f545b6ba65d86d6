"""Work spread over processes: one dead process costs its own job only, and nothing hangs."""

from __future__ import annotations

import os

import pytest

from cso_runtime.processes import WorkerDied, run_each_in_own_process


def _square_or_die(n: int) -> int:
    """Killed (as by the OOM killer) on 3; raises on -1; otherwise n squared."""
    if n == 3:
        os._exit(9)
    if n == -1:
        raise ValueError("a bad job")
    return n * n


def test_a_dead_process_costs_only_its_own_job():
    results: dict[int, object] = {}
    run_each_in_own_process(_square_or_die, [1, 2, 3, 4], 2, results.__setitem__)
    assert {k: v for k, v in results.items() if k != 3} == {1: 1, 2: 4, 4: 16}
    assert isinstance(results[3], WorkerDied) and "died" in str(results[3])


def test_an_exception_of_a_job_is_raised_not_swallowed():
    with pytest.raises(ValueError, match="a bad job"):
        run_each_in_own_process(_square_or_die, [2, -1], 2, lambda job, result: None)


def _sleep_then_square(n: int) -> int:
    import time

    time.sleep(n)
    return n * n


def test_an_error_stops_the_running_processes_at_once():
    """An exception (or Ctrl-C) while jobs run: the running processes are stopped, not waited for."""
    import time

    def stop_on_first(job, result):
        raise RuntimeError(f"stop after job {job}")

    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="stop after job 0"):
        run_each_in_own_process(_sleep_then_square, [0, 60], 2, stop_on_first)
    assert time.monotonic() - t0 < 20  # the 60 s job was terminated
