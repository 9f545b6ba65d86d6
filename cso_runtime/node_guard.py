"""``python -m cso_runtime.node_guard --stop-timeout S -- EXECUTABLE [ARG...]``: how ``up`` starts a command node (a
profile's ``services.<name>.command``, an executable in any language; docs/own-service.md, A node in any language).

The guard leads the node's process group, which the launcher signals as it does a Python service's (SIGINT, then
SIGTERM, then SIGKILL; ``down`` through the guard's pid in ``run.json``), and gives the node the guarantee a Python
service keeps itself: it never outlives its launcher. An executable of one's own cannot be asked to watch for that, so
the guard does: when the launcher is gone (SIGKILL, a crash; the kernel's SIGTERM, ``PR_SET_PDEATHSIG``) it sends the
node's whole group SIGTERM, then SIGKILL after ``--stop-timeout``. The node itself gets SIGTERM should the guard die
first (the OOM killer). On Linux the guard is a child subreaper: what the node starts and then leaves its process group
(``setsid``, a daemon's double fork) becomes the guard's child when orphaned instead of init's, so the guard stops it
with the group: it passes the launcher's SIGINT and SIGTERM on to it, and SIGKILL half ``--stop-timeout`` after SIGTERM
(before the launcher's SIGKILL to the group takes the guard). The guard exits as the node did (its exit code, or the
signal it died of), so the launcher restarts it, or gives up on it, as it would a service. It imports nothing beyond the standard library: it costs a few
MB and milliseconds per node."""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import shlex
import signal
import subprocess
import sys
import time

from cso_runtime.processes import (
    PARENT_CHECK_PERIOD_S,
    PARENT_PID_ENV,
    STACK_DUMP_SIGNAL,
    launcher_gone,
    signal_on_parent_death,
    starting_launcher_pid,
)

EXIT_NOT_STARTED = 2
"""The node's executable could not be started (gone or made not executable since ``up`` checked it): a configuration
the launcher does not restart (``EXIT_BAD_CONFIG``)."""


def say(level: str, text: str) -> None:
    """One line of the guard's in the node's log (its stderr), time-stamped as the services' lines are: ``cso-runtime
    logs`` places the node's own lines, which have no stamp, after the guard's line before them (its start)."""
    now_s = time.time()
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(now_s)) + f",{int(now_s % 1 * 1000):03d}"
    print(f"{stamp} {level} node_guard: {text}", file=sys.stderr, flush=True)


PR_SET_CHILD_SUBREAPER = 36
"""Linux ``prctl`` option: orphaned descendants of the process re-parent to it, not to init."""


def become_subreaper() -> bool:
    """Make the guard a child subreaper (Linux), so that a process of the node's that left its group and lost its parent
    stays among the guard's descendants (``leftovers``); False where it cannot (another system)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except OSError:
        return False


def _node_death_signal() -> None:
    """In the node's process, before its executable runs: SIGTERM when the guard dies."""
    signal_on_parent_death(signal.SIGTERM)


def node_environment() -> dict[str, str]:
    """The node's environment: the guard's, but for ``CSO_PARENT_PID`` (``processes.PARENT_PID_ENV``), the guard's own
    pid when a launcher started the guard, unset when none did (the guard started by hand). The guard is the node's
    parent and stops it when the launcher is gone (``PR_SET_PDEATHSIG``, ``stop_group``): to a node that runs one of the
    runtime's Python services (``python -m services.NAME``, or through ``nice``, ``taskset``, ``env``, which exec it),
    the guard is its launcher, and the service stops cleanly, or exits ``ORPHAN_STOP_S`` later, once the guard is gone
    (``services.common._die_with_launcher``). Given the launcher's pid, that service's parent (the guard) was never that
    pid: ``processes.launcher_gone`` said the launcher gone at once, and the service stopped as it started. A wrapper
    that stays its parent (forks it and waits) is its parent instead of the guard, and does the same. The launcher gives
    a command node an empty ``CSO_INCARNATION``: such a service declares its ``alive/<name>`` token alone, which (its
    name the node's) is the node's coming up."""
    env = dict(os.environ)
    if starting_launcher_pid() is None:
        env.pop(PARENT_PID_ENV, None)
    else:
        env[PARENT_PID_ENV] = str(os.getpid())
    return env


def stop_group(stop_timeout_s: float, node: subprocess.Popen) -> None:
    """The launcher is gone: SIGTERM to the guard's process group (the node and whatever it started), then SIGKILL to
    what is left of it ``stop_timeout_s`` later (the guard with it)."""
    os.killpg(os.getpgrp(), signal.SIGTERM)  # the guard's own handler passes it on to what escaped the group
    try:
        node.wait(timeout=stop_timeout_s)
    except subprocess.TimeoutExpired:
        say("WARNING", f"the node (pid {node.pid}) still runs {stop_timeout_s:g} s after SIGTERM: SIGKILL to its group")
    signal_escaped(signal.SIGKILL)
    os.killpg(os.getpgrp(), signal.SIGKILL)


def leftovers(escaped_only: bool = False) -> list[int]:
    """The other live processes of the guard's process group and its descendants (Linux ``/proc``; none elsewhere): what
    the node started, in its group or out of it (``setsid``: re-parented to the guard, a subreaper, once orphaned).
    ``escaped_only``: only the descendants out of the group, which a signal to the group misses."""
    me, group = os.getpid(), os.getpgrp()
    table: dict[int, tuple[str, int, int]] = {}  # pid -> (state, parent, group)
    for entry in os.listdir("/proc") if os.path.isdir("/proc") else []:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                state, parent, pgrp = fh.read().rsplit(")", 1)[-1].split()[:3]
            table[int(entry)] = (state, int(parent), int(pgrp))
        except (OSError, ValueError):
            continue
    children: dict[int, list[int]] = {}
    for pid, (_, parent_pid, _) in table.items():
        children.setdefault(parent_pid, []).append(pid)
    descendants: set[int] = set()
    todo = [me]
    while todo:
        for child in children.get(todo.pop(), []):
            descendants.add(child)
            todo.append(child)
    in_group = {pid for pid, (_, _, pgrp) in table.items() if pgrp == group}
    found = descendants - in_group if escaped_only else descendants | in_group
    return sorted(pid for pid in found if pid != me and table[pid][0] not in ("Z", "X"))


def signal_escaped(sig: int) -> None:
    """Send ``sig`` to the node's processes that left the guard's group, which a signal to the group misses."""
    for pid in leftovers(escaped_only=True):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, sig)


def on_stop_signal(sig: int, stop_timeout_s: float) -> None:
    """The launcher's SIGINT or SIGTERM to the group (or the kernel's, the launcher gone): passed on to what escaped the
    group; after SIGTERM, SIGKILL to it half ``stop_timeout_s`` later, before the launcher's SIGKILL to the group (which
    takes the guard with it). Each with a SIGCONT, as the launcher's to the group (``supervision.stop_children``): a stopped
    one acts on its signal only once continued, else it waited, stopped, to be killed."""
    signal_escaped(sig)
    signal_escaped(signal.SIGCONT)
    if sig == signal.SIGTERM and signal.getitimer(signal.ITIMER_REAL)[0] == 0:
        signal.signal(signal.SIGALRM, lambda *_: signal_escaped(signal.SIGKILL))
        signal.setitimer(signal.ITIMER_REAL, stop_timeout_s / 2)


def reap_orphans(node_pid: int) -> None:
    """Reap the guard's exited children other than the node: orphans re-parented to it (a subreaper), zombies else."""
    while True:
        try:
            info = os.waitid(os.P_ALL, 0, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return
        if info is None or info.si_pid == node_pid:
            return  # the node's status is the Popen's to collect
        with contextlib.suppress(ChildProcessError):
            os.waitpid(info.si_pid, 0)


def stop_leftovers(stop_timeout_s: float) -> None:
    """The node has exited: SIGTERM to what it left (in its group or out of it), SIGKILL to what is left of that
    ``stop_timeout_s`` later, so that a restarted node (a new group) never finds its predecessor's children still
    running."""
    left = leftovers()
    if not left:
        return
    say("WARNING", f"the node exited and left {len(left)} process(es) ({left}): stopping them")
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in left:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline_s = time.monotonic() + stop_timeout_s
        while (left := leftovers()) and time.monotonic() < deadline_s:
            time.sleep(0.05)
        if not left:
            return


def exit_as(node: subprocess.Popen) -> int:
    """The guard's exit as the node's: its code, or death by the same signal (default action restored first)."""
    code = node.returncode
    if code is not None and code < 0:
        sig = -code
        if sig != signal.SIGKILL:  # SIGKILL's action is the default already, and cannot be set
            signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), sig)
        return 128 + sig  # a signal whose default is not to end the process
    return code or 0


def main(argv: list[str] | None = None) -> int:
    """Run the node until it exits; the guard's exit is the node's (``exit_as``), 2 when it could not start."""
    # First: the launcher's stop signals reach the whole group, the node included; the guard waits for the node.
    # A hung node's stack dump is asked of the guard, which has none. Handled, not ignored: an ignored signal would stay
    # ignored in the node's executable, a handled one is back to its default there.
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, STACK_DUMP_SIGNAL):
        signal.signal(sig, lambda *_: None)
    p = argparse.ArgumentParser(prog="python -m cso_runtime.node_guard")
    p.add_argument("--stop-timeout", type=float, default=3.0, help="Seconds from SIGTERM to SIGKILL once the launcher is gone")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- EXECUTABLE [ARG...]")
    args = p.parse_args(argv)
    for sig in (signal.SIGINT, signal.SIGTERM):  # passed on to what leaves the group
        signal.signal(sig, lambda signum, _frame: on_stop_signal(signum, args.stop_timeout))
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        p.error("give the node's command after --")
    if os.getpgrp() != os.getpid():  # started by hand, not by the launcher (a session of its own): a group of its own,
        os.setpgid(0, 0)  # as the group it stops is the node's, never its starter's
    signal_on_parent_death(signal.SIGTERM)
    subreaper = become_subreaper()
    say("INFO", f"starting {shlex.join(command)} (guard pid {os.getpid()})")  # before the node's first line
    try:
        node = subprocess.Popen(command, stdin=subprocess.DEVNULL, env=node_environment(), preexec_fn=_node_death_signal)  # noqa: PLW1509 - the guard has one thread
    except OSError as exc:
        say("ERROR", f"cannot start {command[0]!r}: {exc.strerror or exc}")
        return EXIT_NOT_STARTED
    while node.poll() is None:
        if launcher_gone() is not None:
            say("WARNING", "the launcher is gone: stopping the node's process group")
            stop_group(args.stop_timeout, node)
        if subreaper:
            reap_orphans(node.pid)
        try:
            node.wait(timeout=PARENT_CHECK_PERIOD_S)
        except subprocess.TimeoutExpired:
            continue
    stop_leftovers(args.stop_timeout)
    return exit_as(node)


if __name__ == "__main__":
    raise SystemExit(main())
