"""Work spread over processes: one dead process costs its own job only, and nothing hangs."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cso_runtime.processes import WorkerDied, run_each_in_own_process

REPO = Path(__file__).resolve().parents[1]


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


KILLED_PARENT = textwrap.dedent("""
    import multiprocessing, os, sys, time
    from concurrent.futures import ProcessPoolExecutor
    from cso_runtime.processes import worker_init

    if __name__ == "__main__":
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init)
        print(pool.submit(os.getpid).result(), flush=True)  # the worker now waits for its next job
        time.sleep(120)
""")


def test_the_workers_of_a_killed_parent_exit(tmp_path):
    """SIGKILL (the OOM killer) gives a parent no chance to stop its pool: its workers leave on their own."""
    import signal

    from cso_runtime.supervision import pid_alive
    from tests.test_runtime import wait_for

    script = tmp_path / "parent.py"
    script.write_text(KILLED_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], cwd=REPO, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        worker = int(parent.stdout.readline())
        assert pid_alive(worker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        wait_for(lambda: not pid_alive(worker), 10, "the orphaned worker to exit")
    finally:
        parent.kill()
        if "worker" in locals() and pid_alive(worker):  # the failure under test: do not leave it running
            os.kill(worker, signal.SIGKILL)


WAIT_THROUGH_A_SLOW_SIGNAL_HANDLER = textwrap.dedent("""
    import signal, threading, time
    from services.common import ServiceInputs

    inputs = ServiceInputs(None, threading.Event())
    signal.signal(signal.SIGUSR2, lambda *_: time.sleep(0.8))  # runs past the wait's deadline
    main = threading.main_thread().ident
    threading.Timer(0.05, lambda: signal.pthread_kill(main, signal.SIGUSR2)).start()
    t0 = time.monotonic()
    print(inputs.next_queued(0.5), round(time.monotonic() - t0, 1))
""")


def test_a_service_loop_wait_returns_after_a_signal_handler_that_outlasts_it():
    """A service's loop waits for inputs with a timeout on its main thread, where signal handlers run. With
    Python 3.11's queue.SimpleQueue that wait never returned once a handler ran past its deadline, so a
    service now and then ignored the launcher's SIGINT and SIGTERM until it was killed; the wait must end."""
    repo = Path(__file__).resolve().parents[1]
    try:
        r = subprocess.run([sys.executable, "-c", WAIT_THROUGH_A_SLOW_SIGNAL_HANDLER], capture_output=True, text=True, timeout=10, cwd=repo)
    except subprocess.TimeoutExpired:
        pytest.fail("the inbox wait did not return after the signal handler (it waits forever)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[0] == "None"


def test_process_state_tells_a_stopped_process_from_a_sleeping_one():
    """The launcher's hang message says whether the stacks it asked for can be in the log: a stopped
    process writes nothing until it runs again."""
    import signal
    import subprocess
    import sys
    import time

    from cso_runtime.supervision import process_state

    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        deadline = time.monotonic() + 10
        while process_state(proc.pid) != "S" and time.monotonic() < deadline:
            time.sleep(0.02)
        assert process_state(proc.pid) == "S"
        proc.send_signal(signal.SIGSTOP)
        while process_state(proc.pid) != "T" and time.monotonic() < deadline:
            time.sleep(0.02)
        assert process_state(proc.pid) == "T"
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert process_state(proc.pid) == ""  # gone


def test_a_burst_of_stop_signals_never_deadlocks_the_stop_handler():
    """A handler that called ``Event.set`` itself waited for ever on the event's lock when a second signal
    came while it held it (SIGINT then SIGTERM; the launcher's stages, or the parent's death): found as a
    planner left running after its launcher was killed. ``set_from_signal_handler`` under 30 SIGTERMs at once."""
    import signal
    import subprocess
    import sys

    child = (
        "import signal, threading\n"
        "from cso_runtime.processes import set_from_signal_handler\n"
        "stop = threading.Event()\n"
        "signal.signal(signal.SIGTERM, lambda *_: set_from_signal_handler(stop))\n"
        "print('ready', flush=True)\n"
        "while not stop.wait(0.00001):\n"
        "    pass\n"
        # Signals of the burst still on their way once it stopped must not meet the interpreter's exit, which puts
        # SIGTERM's default action back (-15 where a loaded host delivered the burst's last ones late).
        "signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})\n"
        "print('stopped', flush=True)\n"
    )
    for _ in range(5):
        proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True)
        try:
            assert proc.stdout.readline() == "ready\n"
            for _ in range(30):
                proc.send_signal(signal.SIGTERM)
            out, _ = proc.communicate(timeout=10)  # a deadlocked handler never lets it get here
            assert proc.returncode == 0 and out == "stopped\n"
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)


@pytest.mark.parametrize("blocks", ["stderr", "last_words"])
def test_an_overdue_stop_ends_even_where_saying_so_blocks(blocks):
    """``end_overdue_stop`` bounds a stop that hangs, and a stop hangs most often where the process cannot write: its
    stderr a pipe no one reads (``train ... 2>&1 | less`` paused, a terminal paused with Ctrl-S, ``| tee`` onto a file
    system that hangs) or its output folder on a file system that hangs (``last_words``, train's ``--resume`` hint,
    looks at the checkpoint there). The watchdog said its words itself before it killed the children and exited, so it
    waited on them for ever as the stop did: it now says them beside it, at most ``say_within_s``, then ends anyway."""
    import signal

    from cso_runtime.supervision import pid_alive
    from tests.conftest import wait_for

    script = textwrap.dedent(
        f"""
        import fcntl, multiprocessing, os, signal, threading
        from cso_runtime.processes import end_overdue_stop

        def stuck():
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            threading.Event().wait()

        child = multiprocessing.get_context("fork").Process(target=stuck, daemon=True)
        child.start()
        if {blocks!r} == "stderr":  # fill stderr's pipe, which the test does not read: every write to it now blocks
            flags = fcntl.fcntl(2, fcntl.F_GETFL)
            fcntl.fcntl(2, fcntl.F_SETFL, flags | os.O_NONBLOCK)
            try:
                while True:
                    os.write(2, b"x" * 4096)
            except BlockingIOError:
                pass
            fcntl.fcntl(2, fcntl.F_SETFL, flags)
            last_words = lambda: "interrupted"
        else:  # a stat of a checkpoint on a file system that hangs
            last_words = lambda: threading.Event().wait() and "never said"
        print(child.pid, flush=True)
        end_overdue_stop(1.0, 130, last_words, say_within_s=1.0)
        threading.Event().wait()  # the stop that hangs
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    child_pid = None
    try:
        child_pid = int(proc.stdout.readline() or 0) or None
        assert child_pid is not None, "the script did not start its child"
        try:
            returncode = proc.wait(timeout=30)  # stderr unread while it runs
        except subprocess.TimeoutExpired:
            raise AssertionError(f"still running 30 s after a stop bounded to 1 s: its watchdog waits on its words ({blocks} blocks)") from None
        assert returncode == 130
        wait_for(lambda: not pid_alive(child_pid), 10, f"the worker {child_pid} to be killed with the stop")
        if blocks == "last_words":  # what could be said was: where each thread was
            err = proc.stderr.read().decode(errors="replace")
            assert "error: the stop took more than 1 s; ended at once" in err and "never said" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()
        if child_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child_pid, signal.SIGKILL)


def test_a_command_started_under_nohup_keeps_sighup_ignored():
    """``nohup cso-runtime up &`` asks the run to outlive its terminal, but ``up`` put its stop handler in over the
    ignored SIGHUP: closing the terminal (the shell passes its SIGHUP on to every job) stopped the run ("interrupted").
    An ignored SIGHUP stays ignored (``stop_signals``); SIGINT and SIGTERM stop the command as ever, even where SIGINT was
    ignored (a shell without job control starts ``cmd &`` so, and ``down`` stops a launcher with it)."""
    import signal
    import threading

    from cso_runtime.processes import restore_signal_handlers, stop_on_signals, stop_raises

    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        previous = stop_on_signals(threading.Event())
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
        assert callable(signal.getsignal(signal.SIGINT)) and callable(signal.getsignal(signal.SIGTERM))
        restore_signal_handlers(previous)
        with stop_raises(threading.Event()):
            assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN and callable(signal.getsignal(signal.SIGTERM))
        signal.signal(signal.SIGHUP, signal.SIG_DFL)  # a terminal's: SIGHUP stops the command
        previous = stop_on_signals(threading.Event())
        assert callable(signal.getsignal(signal.SIGHUP))
        restore_signal_handlers(previous)
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


REALTIME_CHILD = """
import json, os, sys, threading
from cso_runtime.processes import use_realtime_priority

said = use_realtime_priority(3)
policy = lambda: [os.sched_getscheduler(0), os.sched_getparam(0).sched_priority]
seen = {"said": said, "thread": policy()}
in_thread = []
t = threading.Thread(target=lambda: in_thread.append(policy()))
t.start()
t.join()
seen["new_thread"] = in_thread[0]
r, w = os.pipe()
pid = os.fork()
if pid == 0:
    os.write(w, json.dumps(policy()).encode())
    os._exit(0)
os.waitpid(pid, 0)
seen["child"] = json.loads(os.read(r, 100))
print(json.dumps(seen))
"""


def test_a_realtime_priority_is_set_on_the_thread_and_inherited_by_what_it_starts_or_said_why_not():
    """``use_realtime_priority``: SCHED_FIFO at the priority on the calling thread, inherited by the threads and processes it
    starts after (a service's Zenoh threads, the frontier service's layer helper); where the machine does not permit it
    (``realtime_refusal`` asks on a thread of its own, as ``up`` does), why, and the normal scheduling left as it was."""
    import json

    from cso_runtime.processes import realtime_refusal

    before = os.sched_getscheduler(0)
    refusal = realtime_refusal(3)
    assert os.sched_getscheduler(0) == before  # the probe's thread ended; this one is as it was
    out = subprocess.run([sys.executable, "-c", REALTIME_CHILD], capture_output=True, text=True, timeout=60, cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    seen = json.loads(out.stdout)
    assert seen["said"] == refusal
    expected = [os.SCHED_OTHER, 0] if refusal is not None else [os.SCHED_FIFO, 3]
    assert seen["thread"] == seen["new_thread"] == seen["child"] == expected
    if refusal is not None:
        assert refusal.startswith("not permitted here (it needs CAP_SYS_NICE, or an rtprio limit of at least 3")


def test_a_realtime_priority_not_permitted_says_the_limit_and_one_out_of_range_is_refused(monkeypatch):
    import resource

    from cso_runtime import processes

    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(processes.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(resource, "getrlimit", lambda _which: (5, 5))
    assert processes.use_realtime_priority(10) == "not permitted here (it needs CAP_SYS_NICE, or an rtprio limit of at least 10: this user's is 5)"
    assert processes.realtime_refusal(10) == processes.use_realtime_priority(10)
    for bad in (0, -1, 100):
        with pytest.raises(ValueError, match=f"realtime_priority must be 0 \\(none\\) or 1 to 99; got {bad}"):
            processes.use_realtime_priority(bad)
