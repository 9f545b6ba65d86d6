"""The current run of a runs folder: ``runs/current.json`` (what ``status``, ``down``, ``logs`` and ``save-map``
read to find the running launcher and its router), the folder's launcher lock (one run per runs folder), new run
folders, and ``down``, which stops the current run from another process.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cso_runtime.outputs import partial_path, results_said, write_text_atomic
from cso_runtime.supervision import pid_alive, process_start_ticks, process_state, run_process_alive, signal_group

if TYPE_CHECKING:  # `up` imports this module first of all (``record_starting_up``): not the profile's modules yet
    from cso_runtime.run_profile import Profile

log = logging.getLogger("cso.launcher")

CURRENT_RUN = "current.json"


def new_run_dir(runs_dir: Path, profile: Profile) -> Path:
    """A new run's folder under ``runs_dir`` (not made here): UTC start time, profile and robot, with ``-2``, ``-3``...
    when a run of the same second has the name."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    base = runs_dir / f"{stamp}-{profile.name}-{profile.robot}"
    run_dir, n = base, 1
    while run_dir.exists():
        n += 1
        run_dir = base.with_name(f"{base.name}-{n}")
    return run_dir


def read_current_run(runs_dir: Path, warn: bool = True) -> dict[str, Any] | None:
    """The current run's file (``runs/current.json``), or None when there is none or it is not one a
    launcher wrote (half-written, edited by hand: said in a warning, and then treated as absent). ``warn`` False: not
    said (a second look at a file the first look warned of)."""
    path = runs_dir / CURRENT_RUN
    try:
        info = json.loads(path.read_text())
    except (FileNotFoundError, NotADirectoryError):  # no run file, or no runs folder (a file there): the command says so
        return None
    except (OSError, ValueError) as exc:
        if warn:
            log.warning("ignoring %s: not readable as JSON (%s)", path, exc)
        return None
    problem = run_file_problem(info)
    if problem:
        if warn:
            log.warning("ignoring %s: %s", path, problem)
        return None
    return info


def run_file_problem(info: Any) -> str | None:
    """What makes a parsed run file unusable by ``status``, ``down`` and ``logs``, or None."""
    if not isinstance(info, dict):
        return f"a run file is a JSON object, not {type(info).__name__}"
    if not isinstance(info.get("run_id"), str) or not isinstance(info.get("run_dir", ""), str):
        return "run_id and run_dir must be strings"
    for key in ("launcher_pid", "launcher_start_ticks"):
        if info.get(key) is not None and (not isinstance(info[key], int) or isinstance(info[key], bool)):
            return f"{key} must be an integer"
    if info.get("launcher_pid") is not None and info["launcher_pid"] <= 0:  # os.kill's 0 and -1 are process groups: `down` signals it
        return "launcher_pid must be a process id (positive)"
    endpoints = info.get("endpoints", [])
    if not isinstance(endpoints, list) or not all(isinstance(e, str) for e in endpoints):
        return "endpoints must be a list of strings"
    services = info.get("services", {})
    if not isinstance(services, dict) or not all(
        isinstance(s, dict) and all(s.get(k) is None or (isinstance(s[k], int) and not isinstance(s[k], bool)) for k in ("pid", "start_ticks"))
        for s in services.values()
    ):
        return "services must map each service to its pid and start_ticks (integers)"
    return None


def current_launcher_alive(info: dict[str, Any]) -> bool:
    """Whether the launcher of a run file (``read_current_run``) still runs."""
    return run_process_alive(info.get("launcher_pid"), info.get("launcher_start_ticks"))


def starting_run(info: dict[str, Any] | None) -> str | None:
    """What to say of a current run whose launcher has not opened its router yet (state ``starting``, no endpoints:
    the launcher writes its run file first): nothing can be asked or joined yet, but it runs. None otherwise (its
    launcher gone included)."""
    if info is None or info.get("state") != "starting" or info.get("endpoints") or not current_launcher_alive(info):
        return None
    return f"run {info['run_id']} (robot {info.get('robot')}) is starting: its router is not open yet{ASK_AGAIN}"


ASK_AGAIN = "; ask again in a moment"
"""How ``starting_run``'s line ends (``status --watch`` waits instead)."""


DOWN_MARGIN_S = 10.0
"""``down`` gives a launcher three stop stages of its ``stop_timeout_s`` and this much more before it escalates: the
launcher bounds what it does beyond the stages (a hung service's stacks, its recording, its GIF: ``launcher.STOP_EXTRAS_S``)
to fit in it."""

DOWN_TERM_WAIT_S = 3.0
"""How long ``down`` waits after its SIGTERM before SIGKILL. A process dies of a signal only once it gets a CPU: on
a host that stalls it longer, SIGKILL follows a SIGTERM that had already ended it."""


STARTING_LAUNCHER = "launcher.starting.json"
"""``up --detach`` writes ``<run-dir>/launcher.starting.json`` (its launcher's pid and start time) as it spawns the
launcher, and removes it once the start is over, however it ended: ``down`` in the seconds before the launcher has
written its run file (it still imports) stops that launcher, where it answered "nothing running" while the run came up."""


STARTING_UP_GLOB = ".up-*.starting.json"
"""``up`` writes ``<runs-dir>/.up-<pid>.starting.json`` (``starting_up_path``: its own pid and start time) as its first
act (``cli.main``, before typer parses its command line; this module imports no numpy for it), and removes it once its
launcher has written the run file (``current.json``) or as it ends (``record_starting_up``): ``down`` while ``up`` still
checks its profile (seconds: a learned method's weights, a scene, a method of one's own to import) stops that ``up``,
where it answered "nothing running" and the ``up`` then started its run all the same."""


def starting_up_path(runs_dir: Path, pid: int) -> Path:
    """The file that names ``up`` process ``pid`` to ``down`` until its run file does (``STARTING_UP_GLOB``)."""
    return runs_dir / f".up-{pid}.starting.json"


def stopped_words(pid: int) -> tuple[str, str] | None:
    """How ``status`` says that process ``pid``, a run's launcher or an ``up`` still starting, is stopped (Ctrl-Z or
    SIGSTOP: state T in /proc), and how to go on; None when it is not stopped. Nothing it does comes meanwhile."""
    if process_state(pid) != "T":
        return None
    return "is stopped (Ctrl-Z or SIGSTOP)", f"`kill -CONT {pid}` (or `fg` in its terminal) to go on"


def starting_up_line(runs_dir: Path) -> str | None:
    """What ``status`` says while an ``up`` of ``runs_dir`` still checks its profile and has written no run file
    (``STARTING_UP_GLOB``: its first second or more, a learned method's weights or a scene to load), else None: it said
    "nothing running (no current run)" of an ``up ... &`` just typed, and ``status --watch`` ended there. An ``up``
    stopped meanwhile (Ctrl-Z) is said to be (``stopped_words``): ``status --watch`` and ``logs -f`` wait for it as long."""
    for path in sorted(runs_dir.glob(STARTING_UP_GLOB)):
        found = _starting_process(path, "up_pid", "up_start_ticks")
        if found is not None and found[0] != os.getpid() and run_process_alive(*found):
            starting = f"`up` (pid {found[0]}) is starting in {runs_dir}: it has not written its run file yet"
            stopped = stopped_words(found[0])
            return f"{starting}, and it {stopped[0]}: {stopped[1]}" if stopped else f"{starting}{ASK_AGAIN}"
    return None


def record_starting_up(runs_dir: Path) -> Callable[[], None]:
    """Name this ``up`` (its pid and start time, pid-reuse safe as a run file's) in ``runs_dir`` for ``down``
    (``STARTING_UP_GLOB``), making the folder if need be; returns what removes the file, and the folders made here
    while they are still empty (an ``up`` refused by its check leaves no runs folder behind). A folder that cannot be
    written is left to ``up``'s own check of it (``--runs-dir``), which says why: nothing is named then."""
    made = [folder for folder in [runs_dir, *runs_dir.parents] if not folder.exists()]  # innermost first
    pid = os.getpid()
    path = starting_up_path(runs_dir, pid)
    try:
        runs_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps({"up_pid": pid, "up_start_ticks": process_start_ticks(pid)}))
    except OSError:
        made = [folder for folder in made if folder.exists()]

    def remove() -> None:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        for folder in made:
            try:
                folder.rmdir()
            except OSError:  # the run's folders are in it (or another's): kept
                break

    return remove


def _starting_process(path: Path, pid_key: str, ticks_key: str) -> tuple[int, int | None] | None:
    """The pid and start ticks a starting file names, or None when it is gone (the start over) or half-written."""
    try:
        info = json.loads(path.read_text())
        pid, ticks = info[pid_key], info.get(ticks_key)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(pid, int) or isinstance(pid, bool):
        return None
    return pid, ticks if isinstance(ticks, int) and not isinstance(ticks, bool) else None


def _stop_starting(pid: int, timeout_s: float) -> None:
    """SIGTERM (quiet for a process still importing; a clean stop once its handlers are in), SIGKILL after ``timeout_s``."""
    for sig, wait_s in ((signal.SIGTERM, timeout_s), (signal.SIGKILL, 2.0)):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)
        deadline = time.monotonic() + wait_s
        while pid_alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        if not pid_alive(pid):
            break


def stop_starting_launchers(runs_dir: Path, timeout_s: float) -> list[str]:
    """Stop every ``up`` of ``runs_dir`` whose run has not started (``STARTING_UP_GLOB``: still checking its profile,
    or waiting for its detached launcher, which it then stops itself), then every launcher that ``up --detach`` has
    spawned there and that has not written its run file yet (``STARTING_LAUNCHER``; one whose ``up`` had to be killed):
    SIGTERM, SIGKILL after ``timeout_s``. Their lines for ``down``. The file of an ``up`` that is gone (killed) is
    removed."""
    said = []
    for path in sorted(runs_dir.glob(STARTING_UP_GLOB)):
        found = _starting_process(path, "up_pid", "up_start_ticks")
        if found is None:
            continue
        pid, ticks = found
        if run_process_alive(pid, ticks):
            if pid == os.getpid():  # this very `up`, cleaning up with `down` after its launcher died: neither stopped nor unnamed
                continue
            _stop_starting(pid, timeout_s)
            said.append(f"stopped `up` (pid {pid}) before its run had started (before it had written {runs_dir / CURRENT_RUN}): no run was started")
        with contextlib.suppress(OSError):  # it removes it as it ends; not when killed
            path.unlink(missing_ok=True)
    for path in sorted(runs_dir.glob(f"*/{STARTING_LAUNCHER}")):
        found = _starting_process(path, "launcher_pid", "launcher_start_ticks")
        if found is None or not run_process_alive(*found):  # gone as the start ended
            continue
        pid = found[0]
        _stop_starting(pid, timeout_s)
        said.append(f"stopped run {path.parent.name} as it started (launcher pid {pid}, before it had written {runs_dir / CURRENT_RUN})")
    return said


def down(runs_dir: Path, timeout_s: float | None = None, stop_starting: bool = True) -> tuple[bool, str]:
    """Stop the current run: SIGINT to the launcher (it stops its services and writes its results), then
    escalate. ``timeout_s``: how long the launcher may take (None: from the run's ``stop_timeout_s``). With no run
    file yet, an ``up`` still checking its profile, and a launcher that ``up --detach`` has spawned but that has not
    written its run file yet, are stopped (``stop_starting_launchers``); so are they beside a run file whose launcher has
    died (killed, a reboot), which ``up`` does not take for a run. ``stop_starting`` False: neither (an ``up`` cleaning up
    after its own launcher died leaves another ``up`` of the folder to start)."""
    from cso_runtime.run_profile import SupervisionConfig  # noqa: PLC0415 - see TYPE_CHECKING above

    there_at_first = (runs_dir / CURRENT_RUN).exists()  # an unusable one is warned of by the first look, not again
    info = read_current_run(runs_dir)
    starting: list[str] = []
    if stop_starting and (info is None or not current_launcher_alive(info)):  # a run file its launcher outlived does not keep an `up` from starting
        starting = stop_starting_launchers(runs_dir, 3 * SupervisionConfig.stop_timeout_s + DOWN_MARGIN_S if timeout_s is None else timeout_s)
    if info is None:
        if starting:
            return True, "; ".join(starting)
        info = read_current_run(runs_dir, warn=not there_at_first)  # written (and its launcher's file removed) since the first look
    if info is None:
        if not (runs_dir / CURRENT_RUN).exists():  # the common case: every run has ended (or none was started here)
            return False, f"nothing running (no current run in {runs_dir}; {runs_command('runs', runs_dir)} lists past runs)"
        return False, f"nothing running (no usable {runs_dir / CURRENT_RUN})"
    if timeout_s is None:
        timeout_s = 3 * float(info.get("stop_timeout_s") or SupervisionConfig.stop_timeout_s) + DOWN_MARGIN_S
    launcher_alive = current_launcher_alive(info)
    pid = int(info.get("launcher_pid") or 0) if launcher_alive else 0
    # A service the file names with no start time was not running when it was written (where this system
    # gives start times at all, as the launcher's own shows): its pid may be anyone's since, so left alone.
    ticks_known = info.get("launcher_start_ticks") is not None
    services = [(int(s["pid"]), s.get("start_ticks")) for s in info.get("services", {}).values() if s.get("pid")]
    service_pids = [
        spid for spid, ticks in services if not (ticks_known and ticks is None) and run_process_alive(spid, ticks)  # not a pid reused since
    ]
    continued, escalated = False, ""
    for sig, wait_s in ((signal.SIGINT, timeout_s), (signal.SIGTERM, DOWN_TERM_WAIT_S), (signal.SIGKILL, 2.0)):
        if not pid_alive(pid):
            break
        try:
            continued = continued or process_state(pid) == "T"
            os.kill(pid, sig)
            if sig != signal.SIGINT:  # once sent: a launcher that ends just before has stopped on its own, if late
                escalated = signal.Signals(sig).name
            # A stopped launcher (Ctrl-Z on `up`, SIGSTOP) would only get its SIGINT once continued: down waited
            # out every stage and killed it, and its run was left unfinished (run.json "running", no outcome).
            # Continued, it handles the SIGINT and stops its services and its run as it always does. SIGCONT does
            # nothing to a running process, and discards a SIGSTOP sent but not yet taken.
            if sig != signal.SIGKILL:
                os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + wait_s
        while pid_alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
    killed = [spid for spid in service_pids if pid_alive(spid)]  # whatever the launcher could not stop
    for spid in killed:
        signal_group(spid, signal.SIGKILL)
    deadline = time.monotonic() + 2.0  # SIGKILL is not instant: a process goes once the kernel has reaped it
    while any(pid_alive(p) for p in (pid, *killed)) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [p for p in [pid, *service_pids] if pid_alive(p)]
    if not left and not launcher_alive:  # before its current-run file goes: a reader that finds none (`status --watch` of
        record_launcher_died(info)  # a starting run) reads its run.json for how it ended, and found it still "starting"
    cur = read_current_run(runs_dir)
    if cur is not None and cur.get("run_id") == info.get("run_id"):
        clear_current_run(runs_dir, str(info.get("run_id")))
    if left:
        return False, "; ".join([f"processes still running: {left}", *starting])
    notes = ["its launcher was stopped (Ctrl-Z, SIGSTOP): continued so that it could stop"] if continued else []
    if not launcher_alive:  # killed, crashed, a reboot: nothing of the run was stopped here but its leftovers
        leftovers = f"killed the {len(killed)} service(s) it left running; " if killed else ""
        notes.append(f"its launcher, pid {info.get('launcher_pid')}, had already exited: {leftovers}{runs_dir / CURRENT_RUN} cleared")
    if escalated:  # its results (summary.json, run.json's outcome) may be missing: say so rather than a plain "stopped"
        notes.append(f"its launcher did not stop on SIGINT within {timeout_s:g} s: {escalated}")
    run_left = [where] if launcher_alive and (where := what_a_stopped_run_left(info)) else []
    return True, "; ".join([f"stopped run {info.get('run_id')}" + (f" ({'; '.join(notes)})" if notes else ""), *run_left, *starting])


def clear_current_run(runs_dir: Path, run_id: str) -> None:
    """Remove ``runs_dir``'s current-run file if it is run ``run_id``'s, never another run's: ``down``, which holds no
    runs lock (the launcher holds it for its whole run, and a second launcher that finds it held refuses to start), read
    the file and then unlinked it, and a new run's launcher writing its own in between (``write_text_atomic``, a rename)
    lost it. The file is taken aside by a rename (atomic: whichever file is there then, whole), read, and removed only if
    it is ``run_id``'s; another's is linked back, unless a newer one has been written since, which stands."""
    path = runs_dir / CURRENT_RUN
    taken = partial_path(path)
    try:
        os.rename(path, taken)
    except OSError:  # gone meanwhile (the launcher removed its own), or the folder cannot be written
        return
    try:
        info = json.loads(taken.read_text())
        mine = isinstance(info, dict) and info.get("run_id") == run_id
    except (OSError, ValueError):
        mine = False
    if not mine:
        try:
            os.link(taken, path)  # back where it was, unless a newer one is there now (EEXIST): that one stands
        except FileExistsError:
            pass
        except OSError:  # a file system without hard links: back by a rename, where no newer one is there
            with contextlib.suppress(OSError):
                if not path.exists():
                    os.rename(taken, path)
    with contextlib.suppress(OSError):
        taken.unlink(missing_ok=True)


def what_a_stopped_run_left(info: dict[str, Any]) -> str:
    """Where the run that ``down`` stopped left what it wrote, as a foreground ``up``'s last line says it: its results
    (a detached run after its episode), else its map so far (stopped before its episode ended); "" when neither is
    there. ``down`` said "stopped run X" alone: a detached run's own last line is in its launcher.log, unseen."""
    from cso_runtime.launcher import LAST_MAP  # noqa: PLC0415 - the launcher's module imports this one

    if not info.get("run_dir"):
        return ""
    run_dir = Path(str(info["run_dir"]))
    if (run_dir / "summary.json").is_file():
        return results_said(run_dir)
    if (run_dir / LAST_MAP).is_file():
        return f"no results (its episode had not ended); its map so far: {run_dir / LAST_MAP}"
    return ""


LAUNCHER_DIED = "launcher died"
"""How ``runs`` lists a run whose launcher was killed before it could write how the run ended."""

STOPPED_BY_DOWN = f"{LAUNCHER_DIED}; stopped by down"
"""``run.json``'s ``reason`` once ``down`` has cleaned up after a dead launcher (``record_launcher_died``)."""


def record_launcher_died(info: dict[str, Any]) -> None:
    """Write in the run's ``run.json`` that it ended, once ``down`` has cleaned up after its dead launcher: state
    ``stopped``, outcome ``failed``, reason ``STOPPED_BY_DOWN`` and when (``stopped_by_down_at``; no ``ended_at``: when
    the launcher died is not known), whole (``write_text_atomic``, as the launcher writes it). A run file that already
    says how its run ended, or that is another run's, is left as it is; one that cannot be written, too (``runs``
    still lists the run as ``launcher died``)."""
    if not info.get("run_dir"):
        return
    path = Path(str(info["run_dir"])) / "run.json"
    try:
        run = json.loads(path.read_text())
        if not isinstance(run, dict) or run.get("run_id") != info.get("run_id") or run.get("outcome"):
            return
        run.update(state="stopped", outcome="failed", reason=STOPPED_BY_DOWN, stopped_by_down_at=round(time.time(), 3))
        write_text_atomic(path, json.dumps(run, indent=2))
    except (OSError, ValueError) as exc:
        log.warning("cannot record in %s that its run's launcher died: %s", path, exc)


RUNS_LOCK = ".up.lock"
"""A launcher holds an exclusive lock on ``<runs-dir>/.up.lock`` for as long as it runs (released by the
kernel however it ends): one run per runs folder, even when two ``up`` start at the same moment. A lock file deleted
while it runs (the whole runs folder removed) is taken again on the launcher's next round (``keep_runs_lock``)."""


def hold_runs_lock(runs_dir: Path) -> int | None:
    """Take the runs folder's launcher lock; its file descriptor, or None when another launcher holds it (or, as
    before ``hold_lock_file`` told them apart, when the file system takes no lock)."""
    try:
        return hold_lock_file(runs_dir / RUNS_LOCK)
    except OSError as exc:
        if exc.filename is not None:  # the lock file could not be made or opened: raised as it always was
            raise
        return None


def hold_lock_file(path: Path) -> int | None:
    """Take an exclusive lock on ``path`` (made, with its folder, if missing) and write this process's pid in it; the
    file descriptor that holds it (the kernel releases it however the process ends), or None when another holds it.
    OSError where no lock can be had at all: the file cannot be made or opened, or its file system takes no lock (NFS
    without its lock service: ENOLCK), which is not another holder."""
    import fcntl  # noqa: PLC0415  (POSIX only, like the process groups the launcher uses)

    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:  # EWOULDBLOCK: another holds it
        os.close(fd)
        return None
    except OSError:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    return fd


@contextlib.contextmanager
def folder_lock(path: Path, command: str, warn: Callable[[str], None]) -> Iterator[bool]:
    """Hold the lock file ``path`` (``hold_lock_file``) for the block: one ``command`` writing ``path``'s folder at a
    time. Yields True; False where no lock can be had (NFS without its lock service: said through ``warn``), where the
    command goes on as before the lock but must leave alone the partial files it finds (another's, being written).
    Raises ConfigError naming the holder's pid, before the block, while another holds it."""
    try:
        fd = hold_lock_file(path)
    except OSError as exc:
        warn(f"cannot lock {path} ({exc.strerror or exc}): a second {command} into {path.parent} at the same time would not be refused")
        yield False
        return
    if fd is None:
        try:
            holder = f" (pid {path.read_text().strip()})"
        except OSError:
            holder = ""
        from cso_runtime.config import ConfigError  # noqa: PLC0415  (numpy: not for `up`'s first act, ``record_starting_up``)

        raise ConfigError(f"{path.parent} is being written by another {command}{holder}: wait for it to end, or give another --out")
    try:
        yield True
    finally:
        os.close(fd)


def runs_lock_file_is(runs_dir: Path, fd: int) -> bool:
    """Whether ``<runs-dir>/.up.lock`` is the very file ``fd`` is open on: not deleted, nor replaced by another."""
    try:
        named, held = os.stat(runs_dir / RUNS_LOCK), os.fstat(fd)
    except OSError:
        return False
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


def keep_runs_lock(runs_dir: Path, fd: int) -> int | None:
    """The lock a running launcher holds on ``fd``, kept: ``fd`` while the lock file is still its file; else (the file,
    or the whole runs folder, was deleted: a lock on a file with no name stops no one, and a second ``up`` would start
    beside this one) the lock taken again on a new lock file, its descriptor returned and ``fd`` closed. None when
    another launcher took the new file first (``fd`` stays open)."""
    if runs_lock_file_is(runs_dir, fd):
        return fd
    new_fd = hold_runs_lock(runs_dir)
    if new_fd is not None:
        os.close(fd)
    return new_fd


def down_command(runs_dir: Path) -> str:
    """The ``down`` that stops the run of ``runs_dir``, as a hint says it: ``--runs-dir`` named unless it is the
    default, so that a user running several robots (one runs folder each) is not sent to stop another's run."""
    return runs_command("down", runs_dir)


def runs_command(command: str, runs_dir: Path) -> str:
    """``cso-runtime COMMAND`` of the run of ``runs_dir`` as a hint says it (``down_command``): ``--runs-dir`` named
    unless it is the default (a plain ``cso-runtime logs -f`` looks in ./runs)."""
    return f"`cso-runtime {command}`" if Path(runs_dir) == Path("runs") else f"`cso-runtime {command} --runs-dir {runs_dir}`"

