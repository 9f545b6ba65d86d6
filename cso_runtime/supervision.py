"""Supervised service processes: spawn with a log file, stop in stages, dump stacks of a hung one, and tell
whether a recorded process still runs (a pid alone may have been reused since a run file named it).

The launcher (``cso_runtime.launcher``) decides when to restart and when to give up; this module only does
what the operating system is asked.
"""

from __future__ import annotations

import logging
import os
import re
import secrets
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cso_runtime.processes import INCARNATION_ENV, PARENT_PID_ENV, STACK_DUMP_SIGNAL

log = logging.getLogger("cso.launcher")

LOGGED_LINE = re.compile(r"^\d{4}-\d\d-\d\d[ T]\d\d:\d\d:\d\d")
"""A line of a service's own logging (``LOG_FORMAT`` starts with the time), not one the interpreter wrote."""


def python_module_argv(module: str) -> list[str]:
    """``python -m MODULE`` without the working folder on the module path: a user's own ``services`` package or
    ``robot_sim.py`` in the folder ``up`` runs from must not replace the installed ones (``-P`` from Python 3.11)."""
    if sys.version_info >= (3, 11):
        return [sys.executable, "-P", "-m", module]
    return [sys.executable, "-c", f"import runpy, sys; del sys.path[0]; runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"]


OWN_GROUP: dict[str, Any] = {"start_new_session": True}
"""How a service is spawned: leading a session (and so a process group) of its own, its helpers with it
(``signal_group``), out of the reach of Ctrl-C or Ctrl-Z of ``up``'s terminal. Not a group in the launcher's session:
where the kernel schedules by session (``/proc/sys/kernel/sched_autogroup_enabled``), five services in one session
with their launcher made the lockstep chain about 5 % slower on the middle scene (docs/experiments/runtime-overhead.md).
A service stopped (SIGSTOP, a debugger) when its launcher is killed is continued by the kernel all the same: its
parent-death signal is SIGCONT (``services.common``), and it then stops on its launcher's death as a running one does."""

OWN_SESSION: dict[str, Any] = {"start_new_session": True}
"""How a command node's guard is spawned: a session of its own, without the terminal of a foreground ``up``, which a
program of any kind may open (a password prompt on /dev/tty), and be stopped for (SIGTTIN) in a group in the
background of that terminal, instead of failing at once. Its guard, not the node, is what a killed launcher leaves."""


@dataclass
class Child:
    """One supervised service process."""

    name: str
    argv: list[str]
    log_path: Path
    proc: subprocess.Popen | None = None
    restarted_at: list[float] = field(default_factory=list)
    """``time.monotonic()`` of each restart of the run (``restarts``, ``recent_restarts``)."""
    gave_up: bool = False
    gave_up_at: float | None = None
    """``time.monotonic()`` when the launcher gave up on it."""
    restart_at: float | None = None
    exit_codes: list[int] = field(default_factory=list)
    spawned_at: float = 0.0
    """``time.monotonic()`` when its current process started."""
    hung_kills: int = 0
    """Times the launcher killed it for not answering while its process ran (``Launcher.kill_hung``)."""
    robot_stops: int = 0
    """Times the launcher stopped the robot this service commands after its process exited unasked (``Launcher.stop_robot``)."""
    came_up: bool = False
    """Whether its current process has declared its liveliness token (a stopped one loses it when its Zenoh
    lease runs out: it is then hung, not still starting)."""
    command: list[str] | None = None
    """A command node's own argv (``services.<name>.command``; ``argv`` runs it under ``cso_runtime.node_guard``): it
    speaks no status protocol, so it is never killed as hung but for ``start_timeout_s`` when it declares its
    liveliness token (``awaits_token``); None for a Python service."""
    awaits_token: bool = True
    """Whether it declares its liveliness token (a command node only with ``alive_token``), so that coming up means
    something."""
    env: dict[str, str] = field(default_factory=dict)
    """Environment variables it gets beside the launcher's own (a command node's: ``Launcher.node_env``)."""
    came_up_at: float = 0.0
    """``time.monotonic()`` when the launcher saw its current process come up: its hang check counts from then, not
    from its start (a start longer than ``hang_timeout_s`` is ``start_timeout_s``'s to judge)."""
    incarnation: str = ""
    """The nonce its current process was given (``INCARNATION_ENV``), new at each ``spawn`` of a Python service: its
    ``alive/<name>/<incarnation>`` token is that process's coming up, a predecessor's token never is. Empty for a
    command node (it declares ``$CSO_ALIVE_KEY`` alone, which is its coming up) and before the first spawn."""

    @property
    def restarts(self) -> int:
        """Restarts over the whole run (what ``status`` and ``runs`` show)."""
        return len(self.restarted_at)

    def recent_restarts(self, now: float, window_s: float) -> int:
        """Restarts within the last ``window_s`` seconds (0: over the whole run): what counts towards giving up."""
        if window_s <= 0:
            return self.restarts
        return sum(1 for t in self.restarted_at if now - t < window_s)

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def last_error(self, tail_bytes: int = 16384) -> str:
        """The last error its log holds (a logged ERROR, or a traceback's exception line), so that the
        launcher's own message says why a service exited; else the log's last line when the interpreter wrote
        it, not the service's logging (``No module named services.sim``: it died before logging began); empty
        when the log has none of these."""
        try:
            with self.log_path.open("rb") as fh:
                fh.seek(max(0, self.log_path.stat().st_size - tail_bytes))
                lines = fh.read().decode("utf-8", "replace").splitlines()
        except OSError:
            return ""
        for line in reversed(lines):
            if " ERROR " in line:
                return line.split(" ERROR ", 1)[1].strip()
            if re.match(r"^[\w.]+(Error|Exception|Interrupt)\b", line):
                return line.strip()
        last = next((line.strip() for line in reversed(lines) if line.strip()), "")
        return "" if LOGGED_LINE.match(last) else last

    def seen_up(self, now: float) -> None:
        """Its liveliness token was seen (heard come, or there at a round of the hang check): its current process came
        up at ``now``, unless it was seen already. Once up it stays so until its next ``spawn``: a token gone again is
        a service stopped or hung (``not answering``), never one still starting.

        Called on a Zenoh thread (``Launcher._on_alive``) while the run loop's hang check reads ``came_up``, then
        ``came_up_at``, with no lock: ``came_up_at`` is written first, so that a check between the two writes never
        counts the new process's silence from its previous process's coming up (and kills it as hung as it comes)."""
        if not self.came_up:
            self.came_up_at = now
            self.came_up = True

    def spawn(self) -> None:
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self.came_up = False  # before its process runs: a token it declares at once is its own coming up, never undone
        self.incarnation = secrets.token_hex(8) if self.command is None else ""  # before it runs, as ``came_up``
        with self.log_path.open("ab") as fh:
            env = {**os.environ, "PYTHONUNBUFFERED": "1", PARENT_PID_ENV: str(os.getpid()), INCARNATION_ENV: self.incarnation, **self.env}
            self.proc = subprocess.Popen(self.argv, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env, **(OWN_GROUP if self.command is None else OWN_SESSION))
        self.restart_at = None
        self.spawned_at = time.monotonic()


def signal_group(pid: int, sig: int) -> None:
    """Send ``sig`` to the process group ``pid`` leads (a service and its children); one gone already is not an error."""
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


STACK_DUMP_WAIT_S = 0.5
"""How long a service that ignored SIGINT and SIGTERM gets to write its stacks before SIGKILL."""


def stop_children(children: list[Child], stage_timeout_s: float) -> None:
    """SIGINT every process group, then SIGTERM, then SIGKILL, each stage with a deadline. A service
    still running at the last stage is asked for its threads' stacks first, so its log says where it hung.
    A service that has not come up gets SIGTERM at the first stage: it may still be importing, before its
    own handlers, where SIGINT would end it with a KeyboardInterrupt traceback in its log (a ``down`` right
    after ``up`` left one in every service's log); SIGTERM ends it quietly, or reaches its handler. A command node
    (``Child.command``), which may never say it came up, gets SIGINT first as any program stopped by Ctrl-C would, and is
    not asked for stacks (its guard has none). Each signal but SIGKILL comes with a SIGCONT: a stopped service (SIGSTOP,
    a debugger let go) waited out every stage, its signals pending, and was killed without a clean stop."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        running = [c for c in children if c.alive]
        if not running:
            break
        if sig == signal.SIGKILL:
            dump_stacks([c for c in running if c.command is None])
        for c in running:
            assert c.proc is not None
            signal_group(c.proc.pid, signal.SIGTERM if sig == signal.SIGINT and not c.came_up and c.command is None else sig)
            if sig != signal.SIGKILL:  # a stopped one (SIGSTOP, Ctrl-Z of its own) acts on it only once continued
                signal_group(c.proc.pid, signal.SIGCONT)
        deadline = time.monotonic() + stage_timeout_s
        for c in running:
            assert c.proc is not None
            try:
                c.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s (pid %d) still running after %s", c.name, c.proc.pid, signal.Signals(sig).name)
    for c in children:  # the groups may hold grandchildren
        if c.proc is not None:
            signal_group(c.proc.pid, signal.SIGKILL)


def dump_stacks(children: list[Child]) -> None:
    """``STACK_DUMP_SIGNAL`` to each service process (not its group: a helper would die of it), then a
    moment for faulthandler to write; each log then holds the stacks of that service's threads."""
    for c in children:
        assert c.proc is not None
        try:
            os.kill(c.proc.pid, STACK_DUMP_SIGNAL)
        except (ProcessLookupError, PermissionError):
            continue
        stopped = process_state(c.proc.pid) == "T"  # SIGSTOPped or traced: it cannot write them until it runs again
        where = "it is stopped (SIGSTOP?), so its log cannot hold them" if stopped else f"they are in {c.log_path}"
        log.warning("%s (pid %d): asked for the stacks of its threads; %s", c.name, c.proc.pid, where)
    time.sleep(STACK_DUMP_WAIT_S)


def process_state(pid: int) -> str:
    """The kernel's one-letter state of a process (R, S, D, T, Z, ...; Linux /proc), or "" where unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return stat.rsplit(")", 1)[-1].split()[0] if ")" in stat else ""


def pid_alive(pid: int | None) -> bool:
    """Whether process ``pid`` is still running (a zombie is not; one of another user is). Only a positive integer
    names one process: ``os.kill`` takes 0 and -1 for process groups (-1: every process this user may signal), and a
    run file edited by hand may hold either, or text."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # OverflowError: no pid is that large
        return False
    except PermissionError:
        return True
    try:  # a zombie is not running
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def process_start_ticks(pid: int) -> int | None:
    """When the process started (clock ticks since boot, ``/proc/<pid>/stat`` field 22); None when unknown.
    With its pid it names one process for good: a pid alone may have been reused since a run file was written."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return int(fh.read().rsplit(")", 1)[-1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def process_started_s(pid: int) -> float | None:
    """When process ``pid`` started, wall clock (seconds since the epoch, to a clock tick): its start after boot
    (``process_start_ticks``) placed by the time since boot now, read on the clock that start is counted on
    (``CLOCK_BOOTTIME``; a time namespace shifts both alike); None where unknown (no ``/proc``, not Linux; the process
    gone). With a file's mtime it tells a process that took a dead writer's pid from the writer. Not ``/proc/uptime``:
    LXCFS (LXD, Incus, some Docker and Kubernetes hosts) makes it the container's age while the start stays counted
    from the host's boot, which placed every process's start in the future, so a live writer was judged a stranger."""
    ticks = process_start_ticks(pid)
    if ticks is None:
        return None
    try:
        since_boot_s = time.clock_gettime(time.CLOCK_BOOTTIME)
        ticks_per_s = os.sysconf("SC_CLK_TCK")
    except (AttributeError, OSError, ValueError):  # no CLOCK_BOOTTIME: not Linux
        return None
    return time.time() - (since_boot_s - ticks / ticks_per_s)


def run_process_alive(pid: int | None, start_ticks: int | None) -> bool:
    """``pid_alive``, and still the process a run file named (same start time, when the file recorded one):
    ``down`` must never signal a process that took a dead launcher's pid."""
    if pid is None or not pid_alive(pid):
        return False
    now = process_start_ticks(pid) if start_ticks is not None else None
    return now is None or now == start_ticks
