"""``cso-runtime runs`` and ``logs``: the run folders ``up`` leaves in ``runs/``, listed and read back.

Each ``up`` writes ``runs/<run-id>/`` (``run.json``: processes and state; ``profile.yaml``; ``summary.json`` when
the episode ended; ``logs/<service>.log`` and ``logs/launcher.log``). ``runs`` lists them with their Table 1 row,
like ``docker compose ls``; ``logs`` merges a run's service logs in time order with the service in front of
each line, like ``docker compose logs [-f]``, and follows a running one until its launcher exits. No Zenoh: a
finished run's folder is all it reads.
"""

from __future__ import annotations

import calendar
import heapq
import json
import re
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cso_runtime.config import yaml_load
from cso_runtime.current_run import (
    CURRENT_RUN,
    LAUNCHER_DIED,
    STOPPED_BY_DOWN,
    current_launcher_alive,
    read_current_run,
    run_file_problem,
    runs_command,
)
from cso_runtime.outputs import closes_a_run
from cso_runtime.report import whole_count
from cso_runtime.supervision import run_process_alive

LOG_DIR = "logs"
LOG_STAMP = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")
"""The ``logging`` default time stamp every service's log line starts with (``asctime``)."""


UNKNOWN_RUN_STATE = "unknown"
"""How ``runs`` lists a run whose run.json cannot be read (not JSON, not an object): neither how it ended nor whether it
runs is known."""


class RunError(ValueError):
    """No such run, or no run at all: the command says why and exits non-zero."""


@dataclass
class RunSummary:
    """One run folder as ``runs`` lists it."""

    run_id: str
    run_dir: Path
    state: str
    """``running`` (its launcher is alive; ``done``/``failed`` for a detached run that waits for ``down``),
    else how it ended: ``done``, ``failed``, ``interrupted`` (stopped before the episode ended) or
    ``launcher died`` (killed before it could stop its run) or ``stopped`` (a run file from before outcomes
    were recorded); ``UNKNOWN_RUN_STATE`` where its run.json cannot be read (``reason`` says why)."""
    profile: str = ""
    robot: str = ""
    scene: str = ""
    """The scene spec it explored (the profile's, else the default); empty for a real robot's run."""
    real_robot: bool = False
    """A real robot's run (``ros2_bridge``, no simulator): no scene."""
    coverage_measured: bool = True
    """The run had a ground truth (``run_profile.measures_coverage``: summary.json's ``meta.coverage_measured``, else
    its profile's sim): else its ``coverage_pct`` 0 is no measure, ``runs`` says ``NO_COVERAGE``."""
    method: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    """The method's Table 1 row from ``summary.json`` (empty until the episode ended)."""
    restarts: int = 0
    """Service restarts by the launcher, all services together."""
    reason: str = ""
    """Why a run failed before it started any service, as its launcher wrote it (run.json's ``reason``: ``refused: robot
    r0 is already run by another launcher ...``, no router); "" when none was written."""
    stopped_at_step: int | None = None
    """The step its episode was at as the run stopped (run.json's ``last_step``: the last episode status its launcher
    heard) when it has no results to give its steps (interrupted, failed); None otherwise, or not known."""
    lost_results: list[dict[str, Any]] = field(default_factory=list)
    """The episodes whose result a restart of the referee lost (run.json's ``lost_results``, as ``launcher_status``
    names them; a malformed list is none): the run went on with another episode, whose results are the run's."""
    referee: str | None = None
    """Which kind of referee ran its episodes (``run_profile.referee_kind`` of its profile's services); None when its
    profile names none."""
    duration_s: float | None = None
    """How long the run took to the end of its episode (``episode_ended_at - started_at`` of run.json; a detached
    run then waits for ``down``), else to its stop (``ended_at``), or has been running; None for a run file from
    before the times were recorded, or a run whose launcher died."""

    def as_dict(self) -> dict[str, Any]:
        keys = ("explored_area_m2", "coverage_pct", "steps", "efficiency_m2_per_step", "path_length_m")
        return {
            "run_id": self.run_id,
            "run_dir": str(self.run_dir),
            "state": self.state,
            "profile": self.profile,
            "robot": self.robot,
            "scene": self.scene,
            "real_robot": self.real_robot,
            "coverage_measured": self.coverage_measured,
            "method": self.method,
            **{k: self.metrics.get(k) for k in keys},
            "steps": whole_count(self.metrics.get("steps")),  # a run is one episode: summary.json's mean over its one episode
            "terminated_by": next(iter(self.metrics.get("terminated_by") or {}), None),
            "restarts": self.restarts,
            "duration_s": None if self.duration_s is None else round(self.duration_s, 1),
            "stopped_at_step": self.stopped_at_step,
            "lost_results": self.lost_results,
            "reason": self.reason,
        }


def read_json_object(path: Path) -> dict[str, Any] | None:
    """A JSON object file (``run.json``, ``summary.json``), or None when it is missing, unreadable or not an object."""
    return json_object_and_problem(path)[0]


def json_object_and_problem(path: Path) -> tuple[dict[str, Any] | None, str]:
    """``read_json_object`` and, where it is None, why, in words (``not JSON (Expecting value at line 1 column 1)``,
    ``a JSON list, not an object``, ``No such file or directory``); "" where the object is read."""
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        return None, f"not JSON ({exc.msg} at line {exc.lineno} column {exc.colno})"
    except OSError as exc:
        return None, exc.strerror or str(exc)
    except ValueError as exc:  # not UTF-8 text
        return None, f"not JSON ({exc})"
    if not isinstance(data, dict):
        kind = {list: "list", str: "string", int: "number", float: "number", bool: "true/false", type(None): "null"}.get(type(data), type(data).__name__)
        return None, f"a JSON {kind}, not an object"
    return data, ""


def run_dirs(runs_dir: Path) -> list[Path]:
    """The run folders under ``runs_dir`` (those with a ``run.json``), oldest first: their names start with
    the UTC time they started."""
    if not runs_dir.is_dir():
        return []
    return sorted((p.parent for p in runs_dir.glob("*/run.json")), key=lambda p: p.name)


def summarize_run(run_dir: Path) -> RunSummary:
    """A run folder as ``runs`` lists it, read from its run.json, profile.yaml and summary.json; a missing or broken
    file leaves its fields empty instead of failing the listing."""
    read, unreadable = json_object_and_problem(run_dir / "run.json")
    info = read or {}
    try:
        profile = yaml_load((run_dir / "profile.yaml").read_text()) or {}
    except (OSError, yaml.YAMLError):
        profile = {}
    profile = profile if isinstance(profile, dict) else {}
    from cso_runtime.run_profile import measures_coverage, profile_scene, referee_kind, runs_a_real_robot  # noqa: PLC0415 - loads the scenes' code: only where runs are read

    real_robot = runs_a_real_robot(profile)

    summary = read_json_object(run_dir / "summary.json") or {}
    methods = m if isinstance(m := summary.get("methods"), dict) else {}
    meta = m if isinstance(m := summary.get("meta"), dict) else {}
    method = str(profile.get("method", "")) or next(iter(methods), "")
    if unreadable:  # nothing known of how it ended, nor whether it runs: not "stopped", which it may not be
        state = UNKNOWN_RUN_STATE
    elif info and current_launcher_alive(info):
        state = str(info.get("state", "running"))
    elif info.get("reason") == STOPPED_BY_DOWN:  # `down` wrote its end for it (failed): the listing says why
        state = LAUNCHER_DIED
    elif info.get("outcome"):
        state = str(info["outcome"])
    elif info.get("state") not in (None, "stopped"):
        state = LAUNCHER_DIED  # it never wrote that it stopped: killed (SIGKILL, out of memory) or the host went down
    else:
        state = "done" if methods else "stopped"
    services = s if isinstance(s := info.get("services"), dict) else {}
    from cso_runtime.messages import MessageError, lost_results_of  # noqa: PLC0415 - as the launcher's status reads them

    try:
        lost_results = lost_results_of(info.get("lost_results"), "run.json's lost_results")
    except MessageError:  # a file not this version's launcher wrote: nothing known of it
        lost_results = []
    # A run took until its episode ended (a detached run then waits for `down`), else until it stopped.
    started, ended = info.get("started_at"), info.get("episode_ended_at", info.get("ended_at"))
    duration_s = None
    if isinstance(started, (int, float)):
        if isinstance(ended, (int, float)):
            duration_s = max(0.0, float(ended) - float(started))
        elif state not in (LAUNCHER_DIED, "stopped") and current_launcher_alive(info):
            duration_s = max(0.0, time.time() - float(started))
    return RunSummary(
        run_id=str(info.get("run_id") or run_dir.name),
        run_dir=run_dir,
        state=state,
        profile=str(profile.get("name", "")),
        robot=str(info.get("robot") or profile.get("robot", "")),
        scene="" if real_robot or not profile else profile_scene(profile),
        real_robot=real_robot,
        coverage_measured=measures_coverage(profile, meta.get("coverage_measured")),
        method=method,
        metrics=dict(methods.get(method) or {}),
        restarts=sum(int(s.get("restarts") or 0) for s in services.values() if isinstance(s, dict)),
        duration_s=duration_s,
        reason=f"its run.json cannot be read: {unreadable}" if unreadable else "" if info.get("reason") == STOPPED_BY_DOWN else str(info.get("reason") or ""),  # down's: the state says it
        lost_results=lost_results,
        referee=referee_kind(profile["services"]) if isinstance(profile.get("services"), dict) else None,
        stopped_at_step=None if methods.get(method) or state == "running" or not isinstance(last := info.get("last_step"), int) or isinstance(last, bool) else last,
    )


def list_runs(runs_dir: Path, limit: int | None = None) -> list[RunSummary]:
    """The newest ``limit`` runs (all when None), oldest first."""
    dirs = run_dirs(runs_dir)
    return [summarize_run(d) for d in (dirs[-limit:] if limit else dirs)]


# --- prune -----------------------------------------------------------------------------------------

DAY_S = 86400.0


def run_started_s(run_dir: Path) -> float | None:
    """When a run started (Unix time, s): run.json's ``started_at``, else the UTC time its folder's name starts with
    (``new_run_dir``), else None."""
    started = (read_json_object(run_dir / "run.json") or {}).get("started_at")
    if isinstance(started, (int, float)) and not isinstance(started, bool):
        return float(started)
    try:
        return float(calendar.timegm(time.strptime(run_dir.name[:15], "%Y%m%d-%H%M%S")))
    except ValueError:
        return None


def folder_bytes(folder: Path) -> int:
    """The size of the files under ``folder`` (what deleting it frees, links aside)."""
    total = 0
    for path in folder.rglob("*"):
        try:
            if path.is_file() and not path.is_symlink():
                total += path.stat().st_size
        except OSError:
            continue
    return total


@dataclass
class PrunePlan:
    """The run folders ``runs --keep/--older-than`` selects: those it deletes, those it never touches though
    selected (the current run, or one whose launcher or a service of it still runs), and the folders of ``runs_dir``
    with a ``run.json`` that are no run folder ``up`` wrote (``not_a_run_folder``): never selected, never counted."""

    prune: list[Path]
    spared: list[Path]
    not_runs: dict[Path, str] = field(default_factory=dict)
    """Folder -> why it is no run folder."""


def not_a_run_folder(folder: Path) -> str:
    """Why ``folder`` (of ``run_dirs``) is no run folder that ``up`` wrote, so that pruning never deletes it; "" when it
    is one. A link (to a folder elsewhere: deleting it is not deleting a run of this runs folder), or a ``run.json`` that
    is not a launcher's run file (a folder of one's own that has a file of that name; a ``run.json`` that is a folder)."""
    if folder.is_symlink():
        return "a link, not a run folder of this runs folder"
    info = read_json_object(folder / "run.json") if (folder / "run.json").is_file() else None
    if info is None or run_file_problem(info) or not isinstance(info.get("launcher_pid"), int):
        return "its run.json is not one `up` wrote"
    return ""


def run_processes_alive(run_dir: Path) -> bool:
    """Whether the run's launcher, or one of the services its run file names as running (a pid with its start time),
    still runs: a run whose launcher died leaves its services writing their logs into its folder until ``down``."""
    info = read_json_object(run_dir / "run.json")
    if info is None:
        return False
    if current_launcher_alive(info):
        return True
    services = s if isinstance(s := info.get("services"), dict) else {}
    return any(
        isinstance(svc, dict) and isinstance(svc.get("pid"), int) and isinstance(svc.get("start_ticks"), int) and run_process_alive(svc["pid"], svc["start_ticks"])
        for svc in services.values()
    )


def plan_prune(runs_dir: Path, keep: int | None = None, older_than_days: float | None = None, now_s: float | None = None) -> PrunePlan:
    """The runs of ``runs_dir`` (folders with a run.json that ``up`` wrote) beyond the newest ``keep`` and (when given)
    started more than ``older_than_days`` ago, oldest first; both given: only those both select. A run whose start is
    unknown is never older than anything. The current run (``runs/current.json``) and every run whose launcher or one of
    whose services is alive are spared; a folder that is no run folder (``not_a_run_folder``) is neither selected nor counted."""
    found = run_dirs(runs_dir)
    not_runs = {d: why for d in found if (why := not_a_run_folder(d))}
    dirs = [d for d in found if d not in not_runs]
    selected = dirs if keep is None else dirs[: max(len(dirs) - keep, 0)]
    if older_than_days is not None:
        now = time.time() if now_s is None else now_s
        selected = [d for d in selected if (started := run_started_s(d)) is not None and now - started > older_than_days * DAY_S]
    current = read_current_run(runs_dir) or {}
    current_dir = Path(str(current["run_dir"])).resolve() if current.get("run_dir") else None

    def spared(d: Path) -> bool:
        return d.resolve() == current_dir or d.name == current.get("run_id") or run_processes_alive(d)

    return PrunePlan([d for d in selected if not spared(d)], [d for d in selected if spared(d)], not_runs)


def delete_runs(dirs: Iterable[Path]) -> list[str]:
    """Delete each run folder; what could not be deleted, one line each (the rest are deleted regardless)."""
    errors = []
    for d in dirs:
        try:
            shutil.rmtree(d)
        except OSError as exc:
            errors.append(f"{d}: {exc.strerror or exc}")
    return errors


def resolve_run(runs_dir: Path, run: str | None = None) -> Path:
    """The run folder ``logs`` reads: ``run`` (a run id under ``runs_dir``, or a folder), else the current
    run (``runs/current.json``), else the newest one."""
    if run:
        for candidate in (Path(run), runs_dir / run):
            if (candidate / "run.json").is_file() or (candidate / LOG_DIR).is_dir():
                return candidate
        known = ", ".join(d.name for d in reversed(run_dirs(runs_dir)[-5:])) or "none"
        raise RunError(f"no run {run!r} in {runs_dir} (newest first: {known}; {runs_command('runs', runs_dir)} lists them)")
    current = read_current_run(runs_dir)
    if current is not None and Path(str(current.get("run_dir", ""))).is_dir():
        return Path(current["run_dir"])
    dirs = run_dirs(runs_dir)
    if not dirs:
        raise RunError(f"no runs in {runs_dir} (no {runs_dir / CURRENT_RUN}, no run folder with a run.json)")
    return dirs[-1]


def run_is_live(run_dir: Path) -> bool:
    """Whether the run's launcher still runs (so its logs may still grow) and has not ended the run (``run_has_ended``:
    a launcher used as a library lives on in its program)."""
    info = read_json_object(run_dir / "run.json")
    return info is not None and current_launcher_alive(info) and not run_has_ended(run_dir, info)


def run_is_exploring(run_dir: Path) -> bool:
    """Whether the run's episode goes on: its launcher runs and has not written the episode's end (a detached run
    stays up after it, for ``status``, until ``down``). What ``logs -f`` follows of a detached run (``logs_grow``)."""
    info = read_json_object(run_dir / "run.json")
    return info is not None and info.get("state") in ("starting", "running") and current_launcher_alive(info)


def logs_grow(run_dir: Path) -> bool:
    """What ``logs -f`` follows: a detached run until its episode ends (``run_is_exploring``: it then stays up, for
    ``status``, until ``down``), a foreground one until its launcher exits or has ended the run (``run_has_ended``: a
    launcher used as a library, in a program that goes on). It stopped at the episode's end too, and said the run
    "stays up until down" of an ``up`` that was then stopping its services and writing its results: neither their lines
    nor its last, where the results went, came out."""
    info = read_json_object(run_dir / "run.json")
    if info is not None and info.get("detached"):
        return run_is_exploring(run_dir)
    return info is not None and current_launcher_alive(info) and not run_has_ended(run_dir, info)


LOG_TAIL_BYTES = 16384
"""How much of the end of ``launcher.log`` ``run_has_ended`` reads for its last line."""


def run_has_ended(run_dir: Path, info: dict[str, Any]) -> bool:
    """Whether the launcher has ended the run of ``run_dir`` (its ``run.json``, ``info``): it says ``stopped``, and the
    launcher's closing line (``outputs.closes_a_run``), which it logs right after, is its log's last; a run that started
    no service (refused, interrupted) has none, its reason logged before. Its process may live on after it."""
    if info.get("state") != "stopped":
        return False
    if not info.get("services"):
        return True
    try:
        with (run_dir / LOG_DIR / "launcher.log").open("rb") as fh:
            fh.seek(max(0, fh.seek(0, 2) - LOG_TAIL_BYTES))
            lines = fh.read().decode("utf-8", "replace").splitlines()
    except OSError:
        return False
    last = next((line for line in reversed(lines) if line.strip()), "")
    return closes_a_run(last)


# --- logs ------------------------------------------------------------------------------------------


@dataclass(frozen=True, order=True)
class LogLine:
    """One line of a service's log, ordered by its time stamp; a line without one (a traceback, a stack
    dump) takes the stamp of the line before it in the same file, so it stays with it."""

    stamp: str
    source: int
    """Position of the service in the listing (ties of one millisecond: a fixed order)."""
    index: int
    """Line number in its file (keeps a file's own order)."""
    service: str = field(compare=False)
    text: str = field(compare=False)


def log_files(run_dir: Path) -> dict[str, Path]:
    """``service name -> log file`` of a run, the launcher first."""
    files = {p.stem: p for p in sorted((run_dir / LOG_DIR).glob("*.log"))}
    return dict(sorted(files.items(), key=lambda kv: (kv[0] != "launcher", kv[0])))


def await_service_logs(run_dir: Path, services: Iterable[str], wait: Callable[[float], None] | None = None, period_s: float = 0.2) -> None:
    """Wait while the run of ``run_dir`` is starting (its launcher alive, its state ``starting``: its services not all
    spawned yet) and one of ``services`` has no log yet. ``logs -f planner`` right after ``up ... &`` (which it waits
    for) said "no log for planner in this run (it has: launcher)" and ended. A run past its start, or ended, returns at
    once: ``select_services`` then says which logs it has (a name it does not run waits for its start only)."""
    wanted = list(services)
    while True:
        info = read_json_object(run_dir / "run.json")
        if info is None or info.get("state") != "starting" or not current_launcher_alive(info):
            return
        if all(s in log_files(run_dir) for s in wanted):
            return
        (wait or time.sleep)(period_s)


def select_services(files: dict[str, Path], services: Iterable[str]) -> dict[str, Path]:
    """``logs``' service names narrowed to their files (all of them when none is named); a name without a log is a RunError."""
    wanted = list(services)
    unknown = [s for s in wanted if s not in files]
    if unknown:
        raise RunError(f"no log for {', '.join(unknown)} in this run (it has: {', '.join(files) or 'none'})")
    return {s: files[s] for s in wanted} if wanted else files


class LogReader:
    """Reads one log file incrementally: whole lines only (a line still being written waits for the next
    read), continuation lines stamped like the line before them."""

    def __init__(self, service: str, path: Path, source: int) -> None:
        self.service, self.path, self.source = service, path, source
        self.offset = 0
        self.partial = b""
        self.last_stamp = ""
        self.count = 0

    def read_new(self) -> list[LogLine]:
        try:
            with self.path.open("rb") as fh:
                if self.path.stat().st_size < self.offset:  # truncated or replaced: start over
                    self.offset, self.partial = 0, b""
                fh.seek(self.offset)
                data = fh.read()
        except OSError:
            return []
        self.offset += len(data)
        *complete, self.partial = (self.partial + data).split(b"\n")
        return [self._line(raw) for raw in complete]

    def flush(self) -> list[LogLine]:
        """The last line when the file ends without a newline (its writer is gone)."""
        raw, self.partial = self.partial, b""
        return [self._line(raw)] if raw else []

    def _line(self, raw: bytes) -> LogLine:
        text = raw.decode("utf-8", "replace").rstrip("\r")
        m = LOG_STAMP.match(text)
        if m:
            self.last_stamp = m.group(1)
        self.count += 1
        return LogLine(self.last_stamp, self.source, self.count - 1, self.service, text)


def merge(batches: Iterable[list[LogLine]]) -> list[LogLine]:
    """Lines of several files in time order, each file's own order kept."""
    return list(heapq.merge(*batches))


def read_logs(files: dict[str, Path], tail: int | None = None, finished: bool = True) -> tuple[list[LogLine], list[LogReader]]:
    """Every line so far (the last ``tail`` of each service when given, as ``docker compose logs --tail``),
    in time order, and the readers to follow on from. ``finished``: the writers are gone, so a last line
    without its newline (a killed process) is a line too."""
    readers = [LogReader(name, path, i) for i, (name, path) in enumerate(files.items())]
    batches = []
    for r in readers:
        lines = r.read_new() + (r.flush() if finished else [])
        batches.append(lines if tail is None else lines[max(len(lines) - tail, 0) :])
    return merge(batches), readers


def follow_logs(
    run_dir: Path,
    readers: list[LogReader],
    emit: Callable[[LogLine], None],
    alive: Callable[[], bool],
    wait: Callable[[float], None] = time.sleep,
    period_s: float = 0.2,
    pick_up_new: bool = True,
) -> None:
    """Emit new lines as they are written until the run's launcher has exited (``alive`` false: one last
    read, then return; Ctrl-C in ``wait`` ends it too). ``pick_up_new``: a log that appears later (a
    service started late) is followed as well; false when only some services were asked for."""
    while True:
        running = alive()
        if pick_up_new:
            known = {r.service for r in readers}
            for name, path in log_files(run_dir).items():
                if name not in known:
                    readers.append(LogReader(name, path, len(readers)))
        for line in merge(r.read_new() for r in readers):
            emit(line)
        if not running:
            for line in merge(r.flush() for r in readers):
                emit(line)
            return
        wait(period_s)
