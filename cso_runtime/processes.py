"""Work spread over processes that survives one of them dying (killed, out of memory).

A dead worker breaks a whole ``ProcessPoolExecutor`` (and hangs a ``multiprocessing.Pool.map``), so long
runs (an evaluation of hundreds of episodes, hours of teacher rollouts) would lose everything to one kill.
``run_each_in_own_process`` gives every job a process of its own, so a death costs that job only.
"""

from __future__ import annotations

import _thread
import contextlib
import ctypes
import faulthandler
import io
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

J = TypeVar("J")
R = TypeVar("R")


class WorkerDied(RuntimeError):
    """The process running a job died before it returned."""


STACK_DUMP_SIGNAL = signal.SIGUSR1
"""The signal on which a service writes every thread's Python stack to its stderr (its log): the
launcher sends it to a service that ignored SIGINT and SIGTERM, before it kills the service, so that
the log says where it hung (``kill -USR1 PID`` does the same by hand)."""


def set_from_signal_handler(event: threading.Event) -> None:
    """Set ``event`` from a signal handler. ``Event.set`` takes the event's lock, which the interrupted main
    thread may hold (inside ``Event.wait``) or a first handler may hold when a second signal arrives (SIGINT
    then SIGTERM): the handler then waits for itself for ever. A thread of its own takes the lock once the
    main thread lets go of it."""
    _thread.start_new_thread(event.set, ())


def stop_signals() -> tuple[int, ...]:
    """The signals a long command stops on: SIGINT (Ctrl-C), SIGTERM, and SIGHUP (its terminal closed) unless it was
    started with SIGHUP ignored: ``nohup cso-runtime up &`` asked to outlive its terminal, and a handler put in over the
    ignore stopped the run when the terminal closed (the shell passes its SIGHUP on to every job). SIGINT is handled
    even where ignored: a shell without job control starts ``cmd &`` with it ignored, and ``down`` stops with it."""
    return (signal.SIGINT, signal.SIGTERM) + (() if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN else (signal.SIGHUP,))


def stop_on_signals(event: threading.Event) -> dict[int, Any]:
    """SIGINT (Ctrl-C), SIGTERM and SIGHUP (its terminal closed; not under nohup: ``stop_signals``) set ``event`` instead of raising or killing: the
    launcher (and ``up`` from its first line) acts on the stop where it can stop cleanly, never with a
    KeyboardInterrupt traceback in the middle of opening its router or writing its run file. Returns the handlers
    it replaced, for ``restore_signal_handlers`` (a command run inside another program gives them back)."""
    return {sig: signal.signal(sig, lambda signum, frame: set_from_signal_handler(event)) for sig in stop_signals()}


class StopRequested(BaseException):
    """A stop signal while ``stop_raises`` held: nothing had been started, so the command ends where it was. A
    BaseException, as KeyboardInterrupt: a handler of the user's module's errors (``config.import_attribute``) must not
    take it for one."""


@contextlib.contextmanager
def stop_raises(event: threading.Event) -> Iterator[None]:
    """While inside, SIGINT, SIGTERM and SIGHUP set ``event`` and raise ``StopRequested`` wherever the main thread is:
    ``up``'s profile check, which starts nothing, ends at once (an import or a file that blocks included) instead of
    after the check, which ``stop_on_signals`` would wait for. The first signal puts the handlers found back, so that a
    second one cannot break the clean-up; a stop already set raises on entry. Main thread only (signal handlers)."""

    def handler(signum: int, frame: Any) -> None:
        restore_signal_handlers(previous)
        set_from_signal_handler(event)
        raise StopRequested(signal.Signals(signum).name)

    previous: dict[int, Any] = {}  # filled one by one: a signal between two installs finds the handlers to put back
    try:
        for sig in stop_signals():
            previous[sig] = signal.signal(sig, handler)
        if event.is_set():
            raise StopRequested("a stop before the check")
        yield
    finally:
        restore_signal_handlers(previous)


def restore_signal_handlers(previous: dict[int, Any]) -> None:
    """Put back the handlers ``stop_on_signals`` replaced: after ``up`` run in-process (a test's CliRunner), Ctrl-C
    would otherwise go on setting that run's finished stop event instead of interrupting the program."""
    for sig, handler in previous.items():
        signal.signal(sig, signal.SIG_DFL if handler is None else handler)  # None: a handler not set from Python


def dump_stacks_on_signal() -> bool:
    """Write all threads' stacks to stderr on ``STACK_DUMP_SIGNAL`` (faulthandler: works even when the
    main thread is stuck in C code, where a Python signal handler would never run). False when stderr
    is no file (a service run inside a test that captures it): nothing is registered then."""
    try:
        faulthandler.register(STACK_DUMP_SIGNAL, file=sys.stderr, all_threads=True)
    except (AttributeError, ValueError, io.UnsupportedOperation):
        return False
    return True


PARENT_CHECK_PERIOD_S = 0.5
"""How often a worker looks whether the process that started it is still there."""


PARENT_PID_ENV = "CSO_PARENT_PID"
"""The environment variable in which the launcher gives each service it starts its own pid (``launcher_gone``)."""


INCARNATION_ENV = "CSO_INCARNATION"
"""The environment variable in which the launcher gives each Python service it starts a nonce of its own, new at each
start (``supervision.Child.spawn``): the service declares ``alive/<name>/<nonce>`` beside ``alive/<name>``
(``RobotKeys.alive_incarnation``), and the launcher takes only its current process's for that process's coming up.
Empty or unset (a service started by hand, a command node): no such token."""


def starting_launcher_pid() -> int | None:
    """The pid of the launcher that started this service (``CSO_PARENT_PID``, which ``supervision.Child`` sets); None
    for a service started by hand (``cso-runtime service``, ``python -m services.NAME``)."""
    parent = os.environ.get(PARENT_PID_ENV, "")
    return int(parent) if parent.isdigit() else None


def launcher_gone() -> int | None:
    """The pid of the launcher that started this service (``CSO_PARENT_PID``) once it is gone (killed, crashed:
    the kernel's parent-death signal that ``_die_with_launcher`` asked for, SIGCONT, is then why the service stops; a
    command node's guard asks for SIGTERM); None while it runs, or for a service no launcher started. The kernel sends
    that signal as the launcher's thread that spawned it exits,
    before the service is handed to another parent (measured: some 10 ms later, as Zenoh's threads exit): a
    launcher whose main thread is already a zombie is gone too."""
    parent = starting_launcher_pid()
    if parent is None:
        return None
    if os.getppid() != parent:
        return parent
    try:
        with open(f"/proc/{parent}/stat") as fh:
            state = fh.read().rsplit(")", 1)[-1].split()[0]
    except (OSError, IndexError):  # no /proc (not Linux)
        return None
    return parent if state in ("Z", "X", "x") else None


def signal_on_parent_death(sig: int) -> bool:
    """Ask the kernel to send this process ``sig`` when its parent dies (Linux ``PR_SET_PDEATHSIG``); False where it
    cannot (another system). Kept across ``exec`` (an executable a child of this process becomes gets it too)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, sig)  # PR_SET_PDEATHSIG
    except OSError:
        return False
    return True


REALTIME_PRIORITY_MAX = 99
"""The highest SCHED_FIFO priority Linux gives (``realtime_priority`` is 1 to this, 0 for none)."""

REALTIME_HOWTO = "docs/runtime.md#real-time-scheduling"
"""Where a user reads how to permit real-time scheduling (an ``rtprio`` limit, or CAP_SYS_NICE in a container)."""


def use_realtime_priority(priority: int, processes: Sequence[int] = ()) -> str | None:
    """Run the calling thread under SCHED_FIFO at ``priority`` (1 to 99), as ros2_control's controller manager runs its
    loop, and then every other thread of ``processes`` (process ids: this one's, ``os.getpid()``, a service's helper
    processes). The threads and processes they start from then on inherit it. None once the calling thread's is set;
    else why not (not permitted: it needs CAP_SYS_NICE or an ``rtprio`` limit; not Linux), and nothing is changed.

    Why: on a busy 2-vCPU host the default scheduler leaves a service woken by a message queued behind another on one
    vCPU while the other idles, for a millisecond or more (BENCHMARKS.md, issue 4); a real-time thread is placed on an
    idle vCPU at once."""
    if not 1 <= priority <= REALTIME_PRIORITY_MAX:
        raise ValueError(f"realtime_priority must be 0 (none) or 1 to {REALTIME_PRIORITY_MAX}; got {priority}")
    if not hasattr(os, "sched_setscheduler") or not sys.platform.startswith("linux"):
        return "this system has no SCHED_FIFO for it (Linux only)"
    param = os.sched_param(priority)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, param)
    except PermissionError:
        import resource  # noqa: PLC0415 - Unix only, and only here

        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
        limit = "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
        return f"not permitted here (it needs CAP_SYS_NICE, or an rtprio limit of at least {priority}: this user's is {limit})"
    except OSError as exc:  # EINVAL, ESRCH: no reason to expect them, said all the same
        return f"refused ({exc.strerror or exc})"
    for pid in processes:
        for tid in _threads_of(pid):
            with contextlib.suppress(OSError):  # a thread (or process) that ended meanwhile
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
    return None


def _threads_of(pid: int) -> list[int]:
    """The thread ids of process ``pid`` (Linux /proc); none for one that has ended."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def realtime_refusal(priority: int) -> str | None:
    """What ``use_realtime_priority(priority)`` says in a process this one starts (None: it would be set), tried on a
    thread of its own that then ends, so that the caller's own scheduling is left as it is (``up`` says it before any
    service starts; ``doctor``)."""
    said: list[str | None] = []
    probe = threading.Thread(target=lambda: said.append(use_realtime_priority(priority)), name="realtime-probe", daemon=True)
    probe.start()
    probe.join()
    return said[0] if said else "the check could not run"


def _exit_with_parent(parent_pid: int, period_s: float) -> None:
    while True:
        time.sleep(period_s)
        if os.getppid() != parent_pid:  # re-parented: the parent died (SIGKILL, the OOM killer)
            os._exit(1)


def worker_init() -> None:
    """Pool initializer of every worker process.

    - Ctrl-C in a terminal reaches every process of the group, but only the parent should act on it (and
      stop the workers), or a worker's death would look like a crash: workers ignore SIGINT.
    - A worker exits when its parent is gone. A killed parent cannot stop its workers, and a
      ``ProcessPoolExecutor`` worker then waits forever for its next job (it holds the job queue's write end
      itself, so the queue never reports the parent's end closed): every killed evaluation left its workers
      behind, idle, each holding its memory."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_parent, args=(os.getppid(), PARENT_CHECK_PERIOD_S), daemon=True, name="exit-with-parent").start()


def keep_freed_memory(mmap_threshold_bytes: int = 32 << 20, trim_threshold_bytes: int = 512 << 20) -> bool:
    """Let glibc's malloc keep freed memory for reuse instead of returning it to the OS (``mallopt``).

    A process that handles short bursts of large arrays (a service decoding a decision on a 640 x 480
    map, about 3 MB of grids; the frontier layer helper's temporaries) otherwise gets each from fresh
    ``mmap`` pages, or trims its heap once they are freed, and pays page faults for memory it used a
    step before: a traced decision waited 3.5 ms in the policy against 1.7 ms with this, a helper's
    layer took 3.7 instead of 2.8 ms (docs/experiments/runtime-overhead.md). The memory kept is at most the process's
    own peak. Returns whether the settings took (False off glibc: nothing to tune)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(libc.mallopt(m_mmap_threshold, mmap_threshold_bytes)) and bool(libc.mallopt(m_trim_threshold, trim_threshold_bytes))


def stop_processes(processes: Sequence[Any], grace_s: float) -> list[Any]:
    """Stop ``multiprocessing`` processes within a bound: SIGTERM to each one still running, up to ``grace_s`` for them
    to end, then SIGKILL to any left and up to ``grace_s`` more (a process stuck in the kernel outlasts even that).
    ``join`` with no timeout waits for ever on a process that ignores or never gets its SIGTERM, and ``terminate``
    alone sends SIGTERM only. A process never started is skipped. Returns those still running (normally none)."""
    started = [p for p in processes if p.pid is not None]
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for process in started:
            if process.is_alive():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(process.pid, sig)
        deadline = time.monotonic() + grace_s
        for process in started:
            process.join(max(0.0, deadline - time.monotonic()))
        started = [p for p in started if p.is_alive()]
        if not started:
            break
    return started


OVERDUE_STOP_SAY_S = 2.0
"""How long an overdue stop (``end_overdue_stop``) waits for its words (the stacks, ``last_words``) before it ends
without them."""


def end_overdue_stop(deadline_s: float, exit_code: int, last_words: Callable[[], str] | None = None, say_within_s: float = OVERDUE_STOP_SAY_S) -> None:
    """Bound a command's stop (after its first stop signal): unless it has ended ``deadline_s`` seconds from now, say so
    with every thread's stack (where it hung) and ``last_words()`` (how to go on from what it wrote), kill its
    ``multiprocessing`` children and exit with ``exit_code`` at once. A stop that waits for ever on something (a child, a
    lock, a pipe) then still ends, and says where it waited, instead of leaving a process that looks alive and does
    nothing. Its words are said by a thread of their own, waited on for ``say_within_s`` at most: a stop hangs most
    often where the process cannot write (stderr a pipe no one reads, a terminal paused with Ctrl-S, an output folder
    on a file system that hangs, which ``last_words`` may look at), and the end must not wait on them too.
    Safe to call from a signal handler: bare threads, no lock the interrupted main thread may hold."""
    said = _thread.allocate_lock()
    said.acquire()

    def say() -> None:
        with contextlib.suppress(Exception):
            os.write(2, f"error: the stop took more than {deadline_s:g} s; ended at once. Where each thread was:\n".encode())
            faulthandler.dump_traceback(file=2, all_threads=True)  # stderr's descriptor: sys.stderr may be any object
        if last_words is not None:
            with contextlib.suppress(Exception):
                os.write(2, f"{last_words()}\n".encode())
        said.release()

    def watch() -> None:
        time.sleep(deadline_s)
        _thread.start_new_thread(say, ())
        said.acquire(timeout=say_within_s)
        for child in list(getattr(multiprocessing.process, "_children", ())):  # a copy (taken whole under the GIL)
            with contextlib.suppress(Exception):
                os.kill(child.pid, signal.SIGKILL)
        os._exit(exit_code)

    _thread.start_new_thread(watch, ())


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
        pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=worker_init)
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
