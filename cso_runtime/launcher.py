"""``cso-runtime up``: an embedded Zenoh router, one OS process per service, supervision, results.

A profile (``cso_runtime.run_profile``) lists the services and their parameters, the scene, the method and the
Zenoh endpoints, like a dora-rs dataflow file; it is validated completely before anything starts. The launcher opens a Zenoh
session in router mode on loopback (no external router to install; ``--connect`` joins other routers,
e.g. a LIMO's zenoh-bridge-ros2dds), spawns ``python -m services.<name>`` per service (``python -m services
module.path:Attribute`` for a service of one's own, docs/own-service.md) with its own process group and log file in ``runs/<run-id>/logs/``, restarts a crashed service with exponential
back-off (and gives up after ``max_restarts``, saying so), keeps the latest goal for restarted
services (the referee, sim or ros2_bridge, keeps the latest map), shows a live view, optionally
records every ``cso/<robot>/**`` message to MCAP on its own session (``--record``), and writes the
same ``summary.json``, trajectory plot and final map as ``eval`` when the episode ends. Ctrl-C,
SIGTERM and ``cso-runtime down`` stop every process group: SIGINT, then SIGTERM, then SIGKILL, each
with a deadline.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import zenoh

from cso_runtime import __version__
from cso_runtime.claims import DECIDE_WITHIN_S, LostClaim, RunClaim, declare_claims, settle_claims
from cso_runtime.config import (
    EXIT_BAD_CONFIG,
    EXIT_INTERRUPTED,
    EXIT_NO_ZENOH,
    LOG_FORMAT,
    from_dict,
    load_yaml,
    to_dict,
    yaml_dump,
    yaml_load,
)
from cso_runtime.current_run import (
    CURRENT_RUN,
    DOWN_MARGIN_S,
    RUNS_LOCK,
    STARTING_LAUNCHER,
    down,
    down_command,
    hold_runs_lock,
    keep_runs_lock,
    new_run_dir,
    read_current_run,
    runs_command,
    starting_up_path,
)
from cso_runtime.keys import (
    WILDCARD,
    RobotKeys,
    alive_token_of,
    driver_claim_subject,
    robot_claim_subject,
    robot_driver_token,
    topic_of,
)
from cso_runtime.live_view import LiveView, progress_line
from cso_runtime.messages import (
    EPISODE_OVER,
    LAST_EPISODE_FIGURES,
    LOST_RESULTS_KEPT,
    ROS_RESUME_BY,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    GoalMsg,
    LauncherStatusMsg,
    Message,
    MessageError,
    PathMsg,
    decode,
    encode,
    set_max_grid_cells,
)
from cso_runtime.outputs import NO_RESULTS, results_said, write_text_atomic
from cso_runtime.pace import StepPace
from cso_runtime.pause import LOCKSTEP_REFUSAL, PauseClock
from cso_runtime.plots import import_pyplot_in_background
from cso_runtime.processes import restore_signal_handlers, stop_on_signals
from cso_runtime.provenance import command_line, record_command_line, software_provenance
from cso_runtime.run_folder import RunFolderWatch
from cso_runtime.run_profile import HANG_CHECK_PERIOD_S, REFEREES, Profile, SupervisionConfig, measures_coverage, referee_kind
from cso_runtime.runs import LOG_DIR
from cso_runtime.supervision import (
    STACK_DUMP_WAIT_S,
    Child,
    dump_stacks,
    process_start_ticks,
    python_module_argv,
    signal_group,
    stop_children,
)
from cso_runtime.transport import (
    LISTEN_IN_USE,
    STOPPED,
    TransportConfig,
    TransportError,
    any_loopback_port,
    callback_name,
    guarded_callback,
    listen_in_use_hint,
    open_router,
    open_session,
    track_liveliness,
)
from services import waited_for_at_start

if TYPE_CHECKING:
    from cso_runtime.recording import RecordStats

log = logging.getLogger("cso.launcher")

LAUNCHER_INPUTS: dict[str, type[Message]] = {
    "episode_status": EpisodeStatusMsg, "episode_result": EpisodeResultMsg, "goal": GoalMsg, "path": PathMsg, "explore_resume": ExploreResumeMsg,
}  # fmt: skip
"""What the launcher listens to: the episode for its live view and results, the goal for its cache, the
path (a few times a second) for the live view, an operator's pause (``cso-runtime pause``, ROS's
``explore/resume``), which it keeps for restarted services and reports. Not the map: a restarted mapper resumes from the
referee's (``Service.serves_latest``), so the launcher is not woken on every step."""

LAUNCHER_OPTIONAL_INPUTS = ("explore_resume",)
"""Of ``LAUNCHER_INPUTS``, those no service of a profile need publish (``cso-runtime pause`` sends the pause)."""

RUNS_DIR = Path("runs")

NODE_ZENOH_CONFIG = "zenoh-node.json5"
"""The Zenoh config file in the run folder that command nodes open their sessions with (``Launcher.node_zenoh_config``)."""


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals a stop sends before SIGKILL: a service that exited of one of them was not killed outright."""


def robot_stop_commands(profile: Profile) -> dict[str, tuple[str, bytes]]:
    """Service -> (key, payload) that stops the robot it commands, for the services that command a robot
    directly: the launcher sends it when that service's process exits without being asked (``stop_robot``).

    Only the ``ros2_bridge``: its last Twist stands on a real robot until the next one, and a bridge killed
    outright (SIGKILL, the OOM killer, a segfault) sends no zero Twist of its own (its watchdog and its
    stop went with it); limo_base's own cmd_vel timeout is not to be relied on. The launcher is on the
    robot's router too, so it sends the zero Twist on the robot's ``cmd_vel`` key (the bridge's own,
    ``Ros2BridgeParams.stop_command``). A planner that dies needs nothing: on a robot the bridge's watchdog
    sends a zero Twist after ``cmd_timeout_s``; in the ``sim`` profile the sim stops the robot on a command
    older than its ``cmd_timeout_s`` (real time), and in lockstep it waits for the next step's command."""
    if "ros2_bridge" not in profile.services:
        return {}
    from services.ros2_bridge import Ros2BridgeParams  # noqa: PLC0415  (a ROS profile's only)

    params = from_dict(Ros2BridgeParams, profile.services["ros2_bridge"] or {}, where="services.ros2_bridge")
    return {"ros2_bridge": params.stop_command()}


WATCH_BEHIND_S = 2 * HANG_CHECK_PERIOD_S + 2.0
"""``StatusWatch``: a round of queries takes at most ``HANG_CHECK_PERIOD_S`` and the next one follows
``HANG_CHECK_PERIOD_S`` later; a round this much later than the last one means the launcher itself did not run."""


class StatusWatch:
    """Asks every service of a robot for its status (its queryable) every ``HANG_CHECK_PERIOD_S``, on a thread
    of its own, and keeps when each one last answered: a process that runs but does not answer is hung."""

    def __init__(self, session: Any, keys: RobotKeys, stop: threading.Event) -> None:
        self.answered_s: dict[str, float] = {}
        """Service -> ``time.monotonic()`` of its last answer."""
        self.asked_s = time.monotonic()
        """``time.monotonic()`` when its last round of queries ended: a service's silence is a hang only while the
        watch asks (``behind``)."""
        self.resumed_s = -np.inf
        """When it asked again after not running for more than ``WATCH_BEHIND_S`` (the launcher stopped, Ctrl-Z or
        SIGSTOP, or starved of CPU): no service's silence counts from before."""
        self._session, self._keys, self._stop = session, keys, stop
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="status-watch", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self, timeout_s: float = HANG_CHECK_PERIOD_S + 1.0) -> None:
        """Stop asking, and wait (``timeout_s`` at most) for the query in flight to end: the run's session closes
        next, and closing it under a query (``up`` Ctrl-C'd as its services were about to start) raised "Already
        borrowed" out of ``up`` and aborted the process at its end ("FATAL: exception not rethrown")."""
        self._closed.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        key = self._keys.service_status("*")
        while not (self._stop.is_set() or self._closed.is_set()):
            try:
                for reply in self._session.get(key, timeout=HANG_CHECK_PERIOD_S):
                    if reply.ok is not None:  # cso/<robot>/service/<name>/status
                        self.answered_s[str(reply.ok.key_expr).rsplit("/", 2)[-2]] = time.monotonic()
            except Exception:  # the session closing under it at the end of the run
                if not self._stop.is_set():
                    log.debug("status query failed", exc_info=True)
            now = time.monotonic()
            if now - self.asked_s > WATCH_BEHIND_S:
                self.resumed_s = now
                log.warning(
                    "the launcher did not ask its services for their status for %.0f s (was it stopped, Ctrl-Z or SIGSTOP, or starved "
                    "of CPU?): their silence meanwhile is not taken for a hang", now - self.asked_s,
                )
            self.asked_s = now
            if self._stop.is_set():
                break
            self._closed.wait(HANG_CHECK_PERIOD_S)

    def behind(self, now: float) -> bool:
        """Whether it has not asked for longer than ``WATCH_BEHIND_S``: what it knows says nothing of the services
        now (the launcher was stopped and has just been continued, before this watch's thread asked again)."""
        return now - self.asked_s > WATCH_BEHIND_S


class RecorderError(RuntimeError):
    """``up --record`` cannot write its recording: the run stops before any service starts."""


@dataclass
class Recorder:
    """``up --record``'s recorder: the thread that writes the recording, the event that stops it, and what it has written."""

    stop: threading.Event
    thread: threading.Thread
    stats: RecordStats


RECORDING_DRAIN_S = 3.0
"""How long a stopped recorder goes on writing the messages it still holds before it leaves the rest out and finishes
its file (``recording.record``'s ``drain_s``): normally there is next to nothing left (lockstep runs of 390 to 4,800
messages, small and large scene, were finished within 40 ms of the stop), but a recorder behind a dense stream on a
busy machine can hold a long backlog."""

RECORDING_STOP_S = 5.0
"""How long the launcher waits for its stopped recorder to finish (``finish_recording``): its ``RECORDING_DRAIN_S``,
the file's summary and its session's close. One still at it then is left to finish on its own, and the launcher's
log says so and what the file holds so far: the launcher's own stop must fit in ``down``'s margin."""

ANIMATION_STOPPING_S = 3.0
"""How much longer ``up --animate``'s GIF may take once the run is being stopped (``down``, Ctrl-C, SIGTERM): a
whole lockstep episode's took 0.1 s (small scene, 25 frames) and 0.6 to 1.4 s (large, 150 frames); it grows with
the recording. Beyond that it is given up, and the launcher's log gives the ``cso-runtime animate`` command that
draws it from the recording; without a stop, the GIF takes the time it needs."""

PYPLOT_IMPORT_STOP_S = 1.0
"""How long a stop waits for pyplot's import in the background (``import_pyplot_in_background``, about 1 s on a
2-core host) once its figures are drawn or none will be: a run stopped before its results has none to draw, and a first
run's matplotlib builds its font cache (tens of seconds) before the import ends. The figures themselves wait for it
(they draw once it is done), so a stop that writes results has it done by then; past this the process ends with the
import unfinished, which it does cleanly."""

LAST_MAP = "last_map.yaml"
"""Where in its run folder an episode stopped before its end keeps its map so far (``Launcher.keep_last_map``; the PNG
beside it): it has no results, and ``save-map`` can no longer ask once the run is stopped."""
LAST_MAP_IMAGE_FORMAT = "png"
"""``LAST_MAP``'s image (``last_map.png``): as ``save-map --format png`` writes it, and as eval and ``up`` write every
robot's map of a results folder (``save-map``'s default, like map_saver_cli's, is PGM; map_server reads both)."""

STALLED_STEP_S = 5.0
"""How long an exploring episode may make no new step before its progress line says so: a step takes 0.25 s in real
time, less in lockstep (where the sim re-publishes a step after ``lockstep_timeout_s``, 1 s), about 0.1 s on a robot."""

EPISODES_BEFORE_KEPT = 4 * LOST_RESULTS_KEPT
"""How many of the episodes a restart of the sim left behind the launcher knows as such (``episodes_before``): the
latest, well over the ``LOST_RESULTS_KEPT`` whose ends ``ends_behind`` and ``lost_results`` may name, so that a late
status of any of them is still told from the running episode's; a sim restarted without end grows it no more."""

STOP_EXTRAS_S = STACK_DUMP_WAIT_S + RECORDING_STOP_S + ANIMATION_STOPPING_S
"""What the launcher's stop may take beyond its services' three stop stages: the stacks of a hung service, the
recording, the GIF. ``down`` waits ``DOWN_MARGIN_S`` beyond the stages, which must hold it (a test holds them to it)."""


@dataclass
class EpisodeEnd:
    """The ended episode's results, recording and GIF being written on a thread of their own
    (``Launcher.start_episode_end``): seconds of plots, report and GIF, while the run loop goes on supervising."""

    status: EpisodeStatusMsg
    """The status that said the episode ended."""
    result: EpisodeResultMsg | None
    """Its result (None: none came, and no summary.json is written)."""
    thread: threading.Thread
    outputs_done: threading.Event
    """Set once its results are written, or failed to be (``written``); the recording and GIF follow."""
    written: bool = False


class _AnimationGivenUp(Exception):
    """The run is being stopped and its GIF is taking longer than ``ANIMATION_STOPPING_S``."""


# --- the launcher ----------------------------------------------------------------------------------


class Launcher:
    """Runs one profile: router, services, supervision, live state, results."""

    def __init__(
        self,
        profile: Profile,
        profile_data: dict[str, Any],
        run_dir: Path,
        record_path: Path | None = None,
        animate: bool = False,
        stop_event: threading.Event | None = None,
    ) -> None:
        self.profile = profile
        set_max_grid_cells(profile.max_grid_cells)  # the results and paths it reads are bound as its services' messages
        self.record_path = record_path
        """MCAP file recording every ``cso/<robot>/**`` message of the run (None: no recording)."""
        self.animate = animate and record_path is not None
        """At the end, draw the recording as ``animations/<method>/<scene>.gif`` (``up --animate``, as ``eval``'s)."""
        self.data = profile_data
        self.run_dir = run_dir
        self.run_id = run_dir.name
        self.keys = RobotKeys(profile.robot)
        self.stop_event = stop_event if stop_event is not None else threading.Event()
        """Set by Ctrl-C, SIGTERM, SIGHUP or ``down`` (``stop_event`` given: the one ``up`` set on a signal since its first line)."""
        self.launcher_pid = os.getpid()
        """The launcher's process in ``run.json`` (a detached one that never wrote its run file: its own, not ``up``'s)."""
        self.software = software_provenance()
        """The software that runs the profile (``meta.software``), taken as it starts: not a commit checked out meanwhile."""
        self.children: list[Child] = []
        self.endpoints: list[str] = []
        self.status: EpisodeStatusMsg | None = None
        self.status_heard_at_s = 0.0
        """``time.monotonic()`` when ``status`` came: its age in the launcher's status."""
        self.step_changed_s = 0.0
        """``time.monotonic()`` when the episode's step (or state: step 0 starts) last changed; a status of the same step
        again does not count."""
        self.alive_services: set[str] = set()
        self.alive_incarnations: set[tuple[str, str]] = set()
        """(service, incarnation) of each ``alive/<name>/<incarnation>`` token present: the starts of Python services a
        launcher started (``Child.incarnation``). A child's own marks it up; ``alive_services`` (any process's
        ``alive/<name>``) does only for a child with no incarnation, a command node (``token_seen``)."""
        self.left_out = profile.left_out_services()
        """The services this run leaves to other processes (``up --without``, or needed and not in the profile)."""
        self.awaited_services = set(profile.awaited_services())
        """The services the episode waits for that this run does not start: its status says so while none is alive."""
        self.outside_services: set[str] = set(self.left_out)
        """Services this run did not start that came up under its robot's keys (a shared policy server's
        ``serve_all_robots`` policy, a bridge started by hand), and those it left out (DOWN until one comes up): its
        status lists them, DOWN once they go."""
        self.latest_goal: bytes | None = None
        """The payload of the latest goal (``cache/goal``)."""
        self.pause = PauseClock()
        """Whether the operator paused exploration (``explore/resume``), served on ``cache/explore/resume`` to a
        planner that restarts while paused, and how long the robot stood (its status, summary.json's ``paused_s``)."""
        self.rejected: dict[str, int] = {}
        self.handler_errors: dict[str, int] = {}
        """Zenoh callback -> how many times it raised (a bug: logged with its traceback, counted, the run goes on)."""
        self.result: EpisodeResultMsg | None = None
        """The latest result published on ``episode_result`` (else it is asked for, ``wait_for_result``): the result of
        the end judged only if it is of that end's episode (``result_of``). A late one of an end left behind
        (``lost_results``) is never kept."""
        self.path_ahead_m: float | None = None
        """Length of the planner's latest path, robot to goal (live view)."""
        self.outputs_written = False
        self.episode_ended_at: float | None = None
        self.detached = False
        """A detached run (``stay_after_done``): it stays up after its episode until ``down``; its run file says so, for
        ``status --watch`` to end with the episode."""
        self.episode_state: str | None = None
        """How the episode ended (``done``, ``failed``) once its results are written: what the run file says from
        then on while the launcher still runs, also when a restart rewrites it."""
        """When the episode ended (Unix time, s): a detached run stays up after it until ``down``."""
        self.written_result: EpisodeResultMsg | None = None
        """The result whose outputs were written (its scene and method name the animation)."""
        self.last_map_step: int | None = None
        """The step of the map an episode stopped before its end kept (``keep_last_map``), None when none was."""
        self.stop_reason = ""
        """Why a run that started no service stopped (``stop_before_start``), for run.json's ``reason``: ``runs`` says it."""
        self.exit_code = 0
        self._lock = threading.Lock()
        self.started_s = time.monotonic()
        self.started_at = time.time()
        """When the run started (Unix time, s): ``run.json``'s ``started_at``, with ``ended_at`` once it stopped."""
        self.ended_status: EpisodeStatusMsg | None = None
        """The status that said the episode ended, while its result is awaited."""
        self.exploring_since_end: EpisodeStatusMsg | None = None
        """The first status of the ended episode exploring that ``episode_goes_on`` saw since that end: the sim
        stepping on from it shows an end that claimed a step ahead of the sim's stray."""
        self.end_heard: EpisodeStatusMsg | None = None
        """The latest status that said the episode is over (``EPISODE_OVER``) since the run loop last looked
        (``episode_end_heard``): one of the episode exploring can replace ``status`` before the loop, which looks every
        0.1 s, gets to it (a stray end followed by the sim's next step's), and that end was neither judged nor counted.
        An end of an episode a restart left behind (``episodes_before``) is kept here only while none is: it never
        takes the place of an end of the running episode (it waits in ``ends_behind``)."""
        self.ends_behind: list[EpisodeStatusMsg] = []
        """Ends of episodes a restart left behind (``episodes_before``) heard while another end waited in ``end_heard``
        (or waiting there when an end of the running episode came), one per episode: the run loop judges each, one a
        look, once no other end waits (``episode_end_heard``), and the run's end leaves those still here behind
        (``leave_ends_behind``). Dropped, as they were, ``lost_results`` never named them. The latest ``LOST_RESULTS_KEPT``
        only (``lost_results`` names no more): a referee replaying the ends of many episodes never grows it for good."""
        self.results_not_kept: dict[int, int] = {}
        """Episodes a restart left behind whose late result came after another episode's and was not kept (``_on_sample``),
        each with that episode: their end left behind says their result came (``end_left_behind``), not that none did.
        The latest ``LOST_RESULTS_KEPT``."""
        self.stray_judged: EpisodeStatusMsg | None = None
        """The latest end judged not the run's end (a stray, ``stray_end``; one of an episode a restart left behind,
        ``end_left_behind``): while it stays ``status`` (the sim says nothing more for a while), the run loop's next
        looks (``episode_end_heard``) do not judge, log and count it again."""
        self.episode_running: int | None = None
        """The episode the referee's latest status of a running episode (starting, exploring) names: an end of
        another it ran before (a late one of the episode before a restarted sim's, a forged one) is not the run's end
        (``judge_episode_end``)."""
        self.episodes_before: dict[int, None] = {}
        """The episodes heard running before ``episode_running`` (a restarted sim's is a new one), in the order left
        (a dict as an ordered set), the latest ``EPISODES_BEFORE_KEPT`` only: a sim restarted over and over never grows
        it for good, and an episode left that long ago sends nothing late any more. An end of one of
        them is left behind at once (``end_left_behind``), unless its result is here; a late status of one of them is
        none of the running episode's: it does not make it the running one again, nor replace ``status`` (the launcher's
        status, the pace, the end the run loop judges: a late end of it after the running one's hid that). An end of an episode never heard running (a restarted sim's
        that ended before it said it runs) is awaited, and judged by its result."""
        self.lost_results: list[dict[str, Any]] = []
        """The episodes whose end was left behind with no result (``end_left_behind``), as ``launcher_status``'s
        ``lost_results`` names them (the latest ``LOST_RESULTS_KEPT``): ``status`` says that their results were lost."""
        self.status_watch: StatusWatch | None = None
        """Which services answer the launcher's status queries (their hang check), once the session is open."""
        self.service_notes: dict[str, str] = {}
        """Service -> what the launcher's log and live view say beside its health (where to point a viewer)."""
        if "foxglove_bridge" in profile.services:
            from services.foxglove_bridge import FoxgloveBridgeParams  # noqa: PLC0415

            fox = from_dict(FoxgloveBridgeParams, profile.services["foxglove_bridge"] or {}, where="services.foxglove_bridge")
            where = f"ws://{fox.host}:{fox.port}" if fox.port else f"ws://{fox.host}:<a free port, in logs/foxglove_bridge.log>"
            self.service_notes["foxglove_bridge"] = f"Foxglove: open {where}"
        self.control_period_s = profile.exploration_config().robot.control_period_s
        """The period each command is assumed to last (``exploration.robot``); a simulated step lasts one."""
        self.simulated = profile.simulator() is not None
        """A sim service runs the robot: its steps are simulated time (on a real robot, none is)."""
        self.coverage_measured = measures_coverage({"services": profile.services})
        """The run has a ground truth (``run_profile.measures_coverage``: its sim's): else its coverage is no measure,
        left out of its lines and live view, and summary.json's ``meta.coverage_measured`` says so to ``runs`` and
        report.html. Judged by the profile's services until the referee says (its ``episode_status``'s
        ``coverage_measured``: a referee of one's own with a ground truth of its own), then the referee's word."""
        self.sim_step_s = self.control_period_s if self.simulated else None
        """The simulated time of a step (one control period), None on a real robot, whose steps are its scans."""
        self.pace = StepPace(self.control_period_s)
        """The episode's real-time factor, measured on its statuses as they arrive (``real_time_factor``)."""
        self.robot_stop_commands = robot_stop_commands(profile)
        """Service -> the key and payload that stop the robot it commands, sent when it dies (``stop_robot``)."""
        self.session: Any = None
        """The launcher's Zenoh session while it runs (``stop_robot`` sends on it)."""
        self.claim_tokens: list[Any] = []
        """This run's claims on its robot (``cso_runtime.claims``), held until the router it joined answers for the run
        (``seen_at_router``; while it runs when it joined as a client), so that a run starting meanwhile is refused."""
        self.run_file_unwritten = False
        """The last write of the run file failed (a full disk): said once, until a write works again."""
        self.run_file_state = "starting"
        """The state the run file was last written with (``write_run_file``): the run folder made again
        (``tend_run_folder``) says it as it was, a run still starting too, not "running" before its router is open."""
        self.writes_current_run = True
        """Whether this launcher's run file goes to the runs folder's current-run file too. False for the run of a
        launcher that ``up --detach`` gave up on, ended from ``up`` (``_stop_unstarted_launcher``): that file is the
        running launcher's, by then maybe another run's, which writing it "stopped" and removing it took from ``status``
        and ``down``; its run.json alone is written."""
        self.current_run_named = False
        """Whether the runs folder's current-run file has named this run (``write_run_file``): until then run.json goes
        first, so that a reader led to the run by the current-run file (``logs -f``) finds its run.json."""
        self.router_lost_at: float | None = None
        """``time.monotonic()`` when the launcher's session lost its route to a router it joined (``--connect``: the
        robot's), while it is lost (``router_is_reachable``)."""
        self.routers_joined = 0
        """How many routers the launcher's session had routes to once it opened (those in ``--connect``)."""
        self.router_back_s = -np.inf
        """``time.monotonic()`` when that router came back: no service's silence counts from before."""
        self.runs_lock_fd: int | None = None
        """The runs folder's lock this launcher holds (``run_until_stopped``), kept on each round (``tend_runs_lock``)."""
        self.runs_lock_lost = False
        """Whether another launcher took the runs folder's lock after its file was deleted (said once)."""
        self.run_folder = RunFolderWatch(run_dir)
        """Notices the run folder deleted mid-run, and copies back the logs its processes still write (``tend_run_folder``)."""

    # --- files ------------------------------------------------------------------------------------
    @property
    def profile_path(self) -> Path:
        return self.run_dir / "profile.yaml"

    def write_profile(self) -> None:
        """The run's ``profile.yaml``, whole (``write_text_atomic``): every service reads it as it starts, and one
        that starts while it is written again (the run folder made again) must not read half of it."""
        write_text_atomic(self.profile_path, yaml_dump(self.data, sort_keys=False))

    def write_run_file(self, state: str) -> None:
        """``run.json`` and the runs folder's current-run file: the run's state, endpoints and processes, which
        ``status``, ``down`` and ``runs`` read. ``starting`` until its services are spawned (no endpoints before its
        router opens); ``running`` after the episode ended is its end state."""
        if state == "running" and self.episode_state is not None:
            state = self.episode_state
        self.run_file_state = state
        info = {
            "run_id": self.run_id,
            "run_dir": str(self.run_dir.resolve()),
            "robot": self.profile.robot,
            "endpoints": self.endpoints,
            **({"zenoh_config": self.profile.router.zenoh_config} if self.profile.router.zenoh_config else {}),
            "launcher_pid": self.launcher_pid,
            "launcher_start_ticks": process_start_ticks(self.launcher_pid),
            "stop_timeout_s": self.profile.supervision.stop_timeout_s,
            "state": state,
            **({"detached": True} if self.detached else {}),
            "started_at": round(self.started_at, 3),
            **({"outcome": self.outcome(), "exit_code": self.exit_code, "ended_at": round(time.time(), 3)} if state == "stopped" else {}),
            # the step the episode was at as it stopped (its last status): `runs` shows where a run without results stopped
            **({"last_step": self.status.step} if state == "stopped" and self.status is not None else {}),
            **({"reason": self.stop_reason} if state == "stopped" and self.stop_reason else {}),
            **({"episode_ended_at": round(self.episode_ended_at, 3)} if self.episode_ended_at is not None else {}),
            **({"lost_router": self.joined_router()} if self.router_lost_at is not None else {}),
            **({"run_dir_lost": self.run_folder.losses} if self.run_folder.losses else {}),
            # the episodes whose result a restart of the referee lost (`end_left_behind`): `runs` and `report` say so
            **({"lost_results": list(self.lost_results)} if self.lost_results else {}),
            "services": {
                c.name: {
                    "pid": c.proc.pid if c.proc else None,
                    "start_ticks": process_start_ticks(c.proc.pid) if c.alive and c.proc else None,
                    "restarts": c.restarts,
                    "gave_up": c.gave_up,
                    **({"command": c.command} if c.command is not None else {}),
                }
                for c in self.children
            },
        }
        text = json.dumps(info, indent=2)
        # The current-run file first: `up --detach` says "started" once run.json names the services and endpoints, and a
        # script's `status` right after reads current.json, which was then still the "starting" one with no endpoints
        # (its client had nothing to connect to) when the launcher was slow to write it (a busy host). But not before
        # the run has a run.json: `logs -f` goes from the current-run file to the run's run.json, and, finding none
        # there (its first write, "starting"), took the run for ended and left at once.
        current, run_json = self.run_dir.parent / CURRENT_RUN, self.run_dir / "run.json"
        paths = (current, run_json) if self.current_run_named else (run_json, current)
        for path in paths if self.writes_current_run else (run_json,):
            try:
                write_text_atomic(path, text)
            except OSError as exc:  # a full disk: the run goes on, `status` and `down` go by the file written before
                if not self.run_file_unwritten:
                    log.error(
                        "cannot write %s (%s): the run goes on, but `status`, `down` and `runs` see it as it was when it was last written",
                        path, exc.strerror or exc,
                    )  # fmt: skip
                self.run_file_unwritten = True
                return
            self.current_run_named = self.current_run_named or path == current
        self.run_file_unwritten = False

    def outcome(self) -> str:
        """How a stopped run ended, for ``cso-runtime runs``: done (results written), interrupted (stopped
        before the episode ended) or failed."""
        if self.outputs_written and self.exit_code == 0:
            return "done"
        return "interrupted" if self.exit_code == EXIT_INTERRUPTED else "failed"

    def stop_before_start(self, exit_code: int, reason: str = "") -> int:
        """End a run that started no service (refused, no router, or interrupted while its router opened) with
        a run file that says how it ended and ``reason``, why (``runs`` lists it as failed: why, rather than as a
        launcher that died or not at all; the folder is the record of the refusal, its launcher.log with it); no
        current run is left behind. Returns ``exit_code``."""
        self.stop_event.set()  # its status watch, if started, stops asking
        self.exit_code = exit_code
        self.stop_reason = reason
        self.write_run_file("stopped")
        self.remove_current_pointer()
        return exit_code

    def remove_current_pointer(self) -> None:
        if not self.writes_current_run:
            return
        cur = self.run_dir.parent / CURRENT_RUN
        try:
            if json.loads(cur.read_text()).get("run_id") == self.run_id:
                cur.unlink()
        except (OSError, ValueError):
            pass

    # --- zenoh side -------------------------------------------------------------------------------
    def _guarded(self, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """``callback`` for Zenoh: an exception in it would only reach Zenoh's own stderr print, unseen in
        the launcher's log and status; here it is logged with its traceback and counted, and a query it was answering
        gets an error reply at once (``transport.guarded_callback``, as the services' ``Service.guarded``)."""
        return guarded_callback(callback, self._handler_failed, callback_name(callback).lstrip("_"))

    def _handler_failed(self, name: str) -> None:
        """Count (``handler_errors``) and log, the first few with their traceback, an exception raised in ``name``."""
        with self._lock:
            n = self.handler_errors[name] = self.handler_errors.get(name, 0) + 1
        if n <= 5:
            log.exception("launcher: %s raised (%d so far); the run goes on", name, n)

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        try:
            topic = topic_of(key)
        except ValueError:
            return
        payload = sample.payload.to_bytes()
        expected = LAUNCHER_INPUTS.get(topic)
        if expected is None:
            return
        try:
            msg = decode(payload, expected)
        except MessageError as exc:
            with self._lock:
                n = self.rejected[topic] = self.rejected.get(topic, 0) + 1
            if n <= 5:
                log.warning("rejected payload on %s: %s", key, exc)
            return
        if isinstance(msg, EpisodeStatusMsg):
            now = time.monotonic()
            with self._lock:  # one with the end heard: the run loop, between them, would take one end twice
                if msg.episode in self.episodes_before:
                    # Late (or replayed), of an episode a restart left behind: it runs no more (ids are drawn anew per
                    # episode), and its status is none of the running one's (the launcher's status, the pace, the
                    # end the run loop judges). Its end is judged all the same (its result may be here), never in
                    # place of an end of the running episode heard before it.
                    if msg.state in EPISODE_OVER:
                        self.hear_end_behind(msg)
                    return
                before = self.status
                if before is None or (before.episode, before.step, before.state) != (msg.episode, msg.step, msg.state):
                    self.step_changed_s = now
                self.status, self.status_heard_at_s = msg, now
                if msg.state in EPISODE_OVER:
                    waiting, self.end_heard = self.end_heard, msg
                    if waiting is not None and waiting.episode != msg.episode and waiting.episode in self.episodes_before:
                        self.hear_end_behind(waiting)  # heard before its episode was left behind: judged all the same
                else:
                    if self.episode_running is not None and self.episode_running != msg.episode:
                        self.episodes_before.pop(self.episode_running, None)
                        self.episodes_before[self.episode_running] = None
                        while len(self.episodes_before) > EPISODES_BEFORE_KEPT:
                            del self.episodes_before[next(iter(self.episodes_before))]  # the oldest
                    self.episode_running = msg.episode
            if msg.coverage_measured is not None:  # the referee's word on its ground truth, over the services' names
                self.coverage_measured = msg.coverage_measured
            if msg.state != "starting":  # the sim waits for the services before step 0: not its pace
                self.pace.observe(msg.episode, msg.step, time.monotonic())
        elif isinstance(msg, EpisodeResultMsg):
            if self.left_behind(msg.episode):  # never kept: its end heard again would end the run with it, and it would hide the running episode's
                log.warning(
                    "the result of episode %d came after its end was left behind: it is not the run's, which goes on with episode %s",
                    msg.episode, self.episode_running,
                )  # fmt: skip
                return
            with self._lock:  # late, from the sim before a restart, after the running episode's (or a later one's): never in its place, its end awaits it
                kept = self.result
                if kept is None or kept.episode in (0, msg.episode) or msg.episode not in self.episodes_before or kept.episode in self.episodes_before:
                    self.result, kept = msg, None
                else:
                    self.results_not_kept.pop(msg.episode, None)
                    self.results_not_kept[msg.episode] = kept.episode
                    while len(self.results_not_kept) > LOST_RESULTS_KEPT:
                        del self.results_not_kept[next(iter(self.results_not_kept))]
            if kept is not None:
                log.warning("a late result of episode %d, which a restart left behind, came after episode %d's: it is not the run's", msg.episode, kept.episode)
        elif isinstance(msg, GoalMsg):
            self.latest_goal = payload
        elif isinstance(msg, PathMsg):
            xy = msg.path_xy_m
            self.path_ahead_m = float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0
        elif isinstance(msg, ExploreResumeMsg):
            self.on_pause(msg)

    def hear_end_behind(self, end: EpisodeStatusMsg) -> None:
        """An end of an episode a restart left behind (``episodes_before``) for the run loop to judge: in ``end_heard``
        while none waits there, else in ``ends_behind`` (once per episode: a replayed one adds nothing). Under ``_lock``."""
        if self.end_heard is None:
            self.end_heard = end
        elif self.end_heard.episode != end.episode and all(e.episode != end.episode for e in self.ends_behind):
            self.ends_behind.append(end)
            del self.ends_behind[:-LOST_RESULTS_KEPT]  # the latest: a referee replaying many episodes' ends grows it no more

    def on_pause(self, msg: ExploreResumeMsg) -> None:
        """An operator's pause or resume: kept and logged; a lockstep run refuses it (``LOCKSTEP_REFUSAL``)."""
        what = "resume" if msg.resume else "pause"
        by = f" by {msg.by}" if msg.by else ""
        if self.profile.lockstep:
            log.warning("%s%s refused: %s", what, by, LOCKSTEP_REFUSAL)
            return
        with self._lock:
            changed = self.pause.heard(msg, time.monotonic())
        if changed and msg.resume:
            log.info("exploration resumed%s (paused %.1f s in all)", by, self.pause.total_s(time.monotonic()))
        elif changed:
            ros_key = msg.by.removeprefix(ROS_RESUME_BY) if msg.by.startswith(ROS_RESUME_BY) else ""
            resume = runs_command("resume", self.run_dir.parent)  # of this runs folder: a plain one asks the run of ./runs
            until = f"`{{data: true}}` on {ros_key} or {resume}" if ros_key else resume
            log.info("exploration paused%s%s: the robot holds still until %s", by, f" ({msg.reason})" if msg.reason else "", until)

    def _on_cache_query(self, query: Any) -> None:
        if self.latest_goal is not None:
            query.reply(self.keys.cache("goal"), self.latest_goal)

    def _on_pause_query(self, query: Any) -> None:
        """``cache/explore/resume``: the last pause or resume heard (none yet: exploring)."""
        with self._lock:
            latest = self.pause.latest
        if latest is not None:
            query.reply(self.keys.cache("explore_resume"), encode(latest))
        else:
            query.reply_err(b"never paused")

    def pause_status(self) -> dict[str, Any]:
        """``launcher_status``'s ``pause``."""
        with self._lock:
            return self.pause.status(time.monotonic(), LOCKSTEP_REFUSAL if self.profile.lockstep else "")

    def _on_status_query(self, query: Any) -> None:
        query.reply(self.keys.launcher_status, encode(self.launcher_status()))

    def _on_alive(self, sample: Any) -> None:
        """A liveliness token of the robot came or went: ``alive/<name>`` (any process serving ``name``) or
        ``alive/<name>/<incarnation>`` (one start of a service a launcher started). A child is marked up (``seen_up``)
        by its own current process's token only (``token_seen``): a predecessor's, heard late, is not its."""
        parsed = alive_token_of(str(sample.key_expr))
        if parsed is None:
            return
        name, incarnation = parsed
        if incarnation:
            if str(sample.kind).endswith("PUT"):
                self.alive_incarnations.add(parsed)
            else:
                self.alive_incarnations.discard(parsed)
        else:
            track_liveliness(self.alive_services, sample)
        if name in self.profile.services:
            for c in self.children:  # came up now, not at the hang check's next round (``kill_hung``)
                if c.name == name and c.alive and self.token_seen(c):
                    c.seen_up(time.monotonic())
            return
        if incarnation:  # a start of a service of this robot that no child of this run is: its `alive/<name>` says the rest
            return
        if name in self.alive_services:
            if name not in self.outside_services or name in self.left_out:
                self.outside_services.add(name)
                log.info("%s, which this run did not start, serves robot %s (%s)", name, self.profile.robot, sample.key_expr)
        elif name in self.outside_services:
            if self.status is not None and self.status.state in EPISODE_OVER:  # nothing waits for it any more
                log.info("%s, which this run did not start, is gone (%s); the episode has ended", name, sample.key_expr)
                return
            meanwhile = "waits for it" if name in self.awaited_services else "goes on without it"
            log.warning("%s, which this run did not start, is gone (%s); the episode %s until one comes back", name, sample.key_expr, meanwhile)

    def token_seen(self, c: Child) -> bool:
        """Whether ``c``'s current process has its liveliness token: its own ``alive/<name>/<incarnation>`` (a Python
        service), or, for a child with no incarnation (a command node, which declares ``$CSO_ALIVE_KEY`` alone),
        ``alive/<name>``, as any process's."""
        incarnation = c.incarnation  # read once: a spawn on the run loop renews it
        return (c.name, incarnation) in self.alive_incarnations if incarnation else c.name in self.alive_services

    def launcher_status(self) -> LauncherStatusMsg:
        services = {
            c.name: {
                "pid": c.proc.pid if c.proc else 0,
                "process_alive": c.alive,
                "liveliness": c.name in self.alive_services,
                "came_up": c.came_up,  # seen alive since it started: a token gone again is no start (SIGSTOP, hung)
                "restarts": c.restarts,
                "gave_up": c.gave_up,
                "hung_kills": c.hung_kills,
                "robot_stops": c.robot_stops,
                **({"command": True} if c.command is not None else {}),
            }
            for c in self.children
        }
        for name in sorted(self.outside_services):  # not ours, but this robot's episode needs it as much
            services.setdefault(name, {"liveliness": name in self.alive_services, "outside": True, "awaited": name in self.awaited_services})
        with self._lock:
            rejected, handler_errors = dict(self.rejected), dict(self.handler_errors)
            lost_results = [dict(e) for e in self.lost_results]
        state = "stopping" if self.stop_event.is_set() else "running"
        heard = self.status
        last = None
        if heard is not None:
            last = {"state": heard.state, "step": heard.step, "episode": heard.episode, "age_s": round(time.monotonic() - self.status_heard_at_s, 3)}
            body = heard.body()  # the wire forms (a pose as [x_m, y_m, yaw_rad]), as episode_status carries them
            last.update({key: body[key] for key in LAST_EPISODE_FIGURES})
        pace = None if self.real_time_factor is None else round(self.real_time_factor, 3)
        lost = self.joined_router() if self.router_lost_at is not None else None
        return LauncherStatusMsg(
            self.run_id, state, services, rejected, handler_errors, last, pace, lost, self.run_folder.losses, self.pause_status(), self.coverage_measured,
            referee_kind(self.profile.services), lost_results,
        )

    # --- supervision ------------------------------------------------------------------------------
    def stop_robot(self, c: Child, code: int | None) -> None:
        """Stop the robot that ``c`` commands (``robot_stop_commands``), whose process has exited (``code``)
        without being asked: its last command would otherwise stand. Logged, counted in ``c.robot_stops``
        (the launcher's status). Nothing for a service that commands no robot, or before the session is open."""
        stop = self.robot_stop_commands.get(c.name)
        if stop is None or self.session is None:
            return
        key, payload = stop
        try:
            self.session.put(key, payload)
        except zenoh.ZError as exc:  # a closing session: said, the supervision goes on
            log.error("%s exited (code %s): could not send a zero Twist on %s to stop the robot: %s", c.name, code, key, exc)
            return
        c.robot_stops += 1
        log.warning("%s exited (code %s): sent a zero Twist on %s to stop the robot (%d so far)", c.name, code, key, c.robot_stops)

    def spawn_all(self) -> None:
        for name in self.profile.services:
            if self.stop_event.is_set():  # stopped while the first ones started: no more of them to start and stop
                break
            node = self.profile.command_nodes().get(name)
            if node is not None:  # an executable of the user's own, under its guard
                self.spawn_command_node(name, node)
                continue
            mode = self.profile.router.service_mode
            own = self.profile.own_services().get(name)  # a class of the user's own: `python -m services module.path:Attribute`
            command = [*python_module_argv("services"), own] if own else python_module_argv(f"services.{name}")
            argv = [*command, "--config", str(self.profile_path), "--robot", self.profile.robot, "--mode", mode]
            for ep in self.endpoints:
                argv += ["--connect", ep]
            if mode == "peer":
                argv += ["--listen", any_loopback_port(self.endpoints if self.profile.router.embedded else [])]
            if self.profile.router.zenoh_config:  # said on the command line, as --connect (the profile has it too)
                argv += ["--zenoh-config", self.profile.router.zenoh_config]
            child = Child(name, argv, self.run_dir / "logs" / f"{name}.log")
            child.spawn()
            self.children.append(child)
            log.info("started %s (%spid %d)", name, f"{own}, " if own else "", child.proc.pid if child.proc else -1)
        if "foxglove_bridge" in self.service_notes:
            log.info("%s (Open connection -> Foxglove WebSocket)", self.service_notes["foxglove_bridge"])
        for name in self.left_out:
            if name in self.profile.without:
                log.info("%s left out of this run (--without): another process is to serve robot %s", name, self.profile.robot)
            else:
                log.warning(
                    "profile %s has no %s service, and the episode needs one: it waits until another process serves robot %s "
                    "(a shared policy server, `cso-runtime service %s --attach`; `without: [%s]` in the profile says this is meant)",
                    self.profile.name, name, self.profile.robot, name, name,
                )

    def node_zenoh_config(self) -> Path:
        """The Zenoh config file (JSON5) a command node opens its session with, written once: a client of the run's
        router, multicast scouting off, on top of the profile's ``router.zenoh_config`` (its authentication and TLS,
        so the file is the user's alone to read). ``$ZENOH_CONFIG`` names it: ``zenoh.Config.from_env()``."""
        from cso_runtime.transport import zenoh_config  # noqa: PLC0415

        path = self.run_dir / NODE_ZENOH_CONFIG
        if not path.exists():
            config = zenoh_config(TransportConfig(mode="client", connect=list(self.endpoints), zenoh_config_file=self.profile.router.zenoh_config))
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w") as fh:
                fh.write(str(config))
        return path

    def node_env(self, name: str) -> dict[str, str]:
        """The environment a command node gets beside the launcher's (docs/own-service.md, A node in any language)."""
        return {
            "ZENOH_CONFIG": str(self.node_zenoh_config().resolve()),
            "CSO_ZENOH_ENDPOINTS": ",".join(self.endpoints),
            "CSO_ROBOT": self.profile.robot,
            "CSO_NODE_NAME": name,
            "CSO_KEY_PREFIX": self.keys.prefix,
            "CSO_ALIVE_KEY": self.keys.alive(name),
            "CSO_RUN_DIR": str(self.run_dir.resolve()),
            "CSO_PROFILE": str(self.profile_path.resolve()),
        }

    def spawn_command_node(self, name: str, command: list[str]) -> None:
        """Start the command node ``name`` (``services.<name>.command``) under its guard (``cso_runtime.node_guard``),
        its output in ``logs/<name>.log``, supervised as the services are."""
        guard = [*python_module_argv("cso_runtime.node_guard"), "--stop-timeout", f"{self.profile.supervision.stop_timeout_s:g}", "--"]
        awaits = waited_for_at_start(self.profile.services[name])
        child = Child(name, [*guard, *command], self.run_dir / "logs" / f"{name}.log", command=command, awaits_token=awaits, env=self.node_env(name))
        child.spawn()
        self.children.append(child)
        log.info("started %s (command %s, pid %d)", name, shlex.join(command), child.proc.pid if child.proc else -1)

    def kill_hung(self, now: float) -> None:
        """Kill each service whose process runs but that is hung: come up (its liveliness token, which a stopped
        process loses again when its lease runs out) and silent to the status query for
        ``supervision.hang_timeout_s`` since it started or last answered, or not come up
        ``supervision.start_timeout_s`` after it started. Its stacks go to its log first; ``supervise`` then
        restarts it as a crashed one."""
        sup = self.profile.supervision
        watch = self.status_watch
        # The launcher stopped (Ctrl-Z on `up`, SIGSTOP) and continued, or starved of CPU: the services' silence
        # meanwhile is its own. It killed every service it checked as hung, the sim first (a new episode); now the
        # check waits for the watch to ask again, and counts from then.
        if watch is not None and watch.behind(now):
            return
        if not self.router_is_reachable(now):  # every service is silent at once, and none of them is to blame
            return
        resumed_s = max(watch.resumed_s if watch is not None else -np.inf, self.router_back_s)
        for c in self.children:
            if c.gave_up or not c.alive or c.proc is None:
                continue
            if self.token_seen(c):  # its token came while no round looked (``_on_alive`` saw it come)
                c.seen_up(now)
            if c.command is not None and (c.came_up or not c.awaits_token):  # answers no status query: only its start is judged
                continue
            if not c.came_up:  # still starting (importing, warming up), or hung before it came up
                if sup.start_timeout_s <= 0 or now - max(c.spawned_at, resumed_s) < sup.start_timeout_s:
                    continue
                log.error("%s (pid %d) runs but has not come up in %.0f s (hung while starting? see its log): killing it to restart it", c.name, c.proc.pid, now - c.spawned_at)
            else:
                if sup.hang_timeout_s <= 0 or watch is None:
                    continue
                # From when it came up: one that took longer than hang_timeout_s to start (a loaded machine, a slow
                # import) was killed the moment its token came, before the watch had asked it even once.
                since = max(c.came_up_at, watch.answered_s.get(c.name, -np.inf), resumed_s)
                if now - since < sup.hang_timeout_s:
                    continue
                log.error("%s (pid %d) runs but has not answered for %.0f s (hung? stopped?): killing it to restart it", c.name, c.proc.pid, now - since)
            dump_stacks([c])
            signal_group(c.proc.pid, signal.SIGKILL)
            try:
                c.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                log.error("%s (pid %d) survived SIGKILL", c.name, c.proc.pid)
            c.hung_kills += 1

    def joined_router(self) -> str:
        """The router(s) this run joined (``--connect``: the robot's zenoh bridge), with or without its own."""
        return ", ".join(self.profile.router.connect)

    def count_joined_routers(self) -> int:
        """How many routers the launcher's session has a route to now (the embedded router's: those it joined)."""
        return len(list(self.session.info.routers_zid()))

    def router_is_reachable(self, now: float) -> bool:
        """Whether the services can still be reached: false while the router the run joined instead of opening its own
        (``router.embedded: false``) is lost. When that router dies (the robot's bridge), every service goes silent at
        once: the launcher says it lost the router, in its log and run.json (``lost_router``, which ``status`` quotes),
        and kills no service as hung until the router is back, then counts their silence from then. With its own router
        (the services on loopback) a lost router it joined (``--connect``: the robot's) is said the same way, and the
        services, still reachable, are supervised as usual."""
        router = self.profile.router
        if not router.connect or self.session is None:
            return True
        try:
            routes = self.count_joined_routers()
        except zenoh.ZError:  # the session closing at the end of the run
            return True
        self.routers_joined = max(self.routers_joined, routes)  # a router joined after the session opened counts too
        reachable = routes >= self.routers_joined if router.embedded else routes > 0
        if not reachable and self.router_lost_at is None:
            self.router_lost_at = now
            consequence = (
                "the robot's scans and odometry stop, its commands are not delivered"
                if router.embedded
                else "its services cannot be reached; none is killed as hung until it is back"
            )
            log.error(
                "lost the router at %s (the launcher's Zenoh session has no route to it): %s (is the robot or its zenoh bridge down?)",
                self.joined_router(), consequence,
            )  # fmt: skip
            self.write_run_file("running")
        elif reachable and self.router_lost_at is not None:
            log.warning("the router at %s is back after %.0f s", self.joined_router(), now - self.router_lost_at)
            self.router_lost_at, self.router_back_s = None, now
            self.write_run_file("running")
        return reachable or router.embedded

    def supervise(self, now: float | None = None) -> None:
        """Restart the services that exited (after their back-off), or give up on them; ``now``: the launcher's
        ``time.monotonic()`` (given by tests)."""
        sup = self.profile.supervision
        now = time.monotonic() if now is None else now
        self.kill_hung(now)
        changed = False
        for c in self.children:
            if c.gave_up or c.alive:
                continue
            if c.restart_at is None:
                code = c.proc.returncode if c.proc is not None else -1
                c.exit_codes.append(code)
                self.stop_robot(c, code)  # first, before a restart or giving up
                if code == EXIT_BAD_CONFIG and self.config_lost_since_spawn(c):
                    log.warning(
                        "%s exited (code %d: %s) after the run folder, its profile.yaml with it, was deleted: made again, so it is restarted",
                        c.name, code, c.last_error() or "no error logged",
                    )  # fmt: skip
                elif code == EXIT_BAD_CONFIG:
                    c.gave_up, c.gave_up_at = True, now  # the same configuration would fail the same way: no restart
                    log.error("%s refused its configuration (exit code %d): not restarting it: %s (see %s)", c.name, code, c.last_error() or "no error logged", c.log_path)
                    changed = True
                    continue
                recent = c.recent_restarts(now, sup.restart_window_s)
                if recent >= sup.max_restarts:
                    c.gave_up, c.gave_up_at = True, now
                    within = f" within {sup.restart_window_s:g} s" if sup.restart_window_s > 0 else ""
                    log.error("%s exited (code %s) and was restarted %d times%s: giving up on it: %s (see %s)", c.name, code, recent, within, c.last_error() or "no error logged", c.log_path)
                    changed = True
                    continue
                delay = min(sup.backoff_s * (2**recent), sup.backoff_max_s)
                c.restart_at = now + delay
                log.warning("%s exited (code %s); restart %d/%d in %.1f s", c.name, code, recent + 1, sup.max_restarts, delay)
            elif now >= c.restart_at:
                c.restarted_at.append(now)
                c.spawn()
                changed = True
                log.info("restarted %s (pid %d)", c.name, c.proc.pid if c.proc else -1)
        if changed:
            self.write_run_file("running")

    def config_lost_since_spawn(self, c: Child) -> bool:
        """Whether the run folder, with the ``profile.yaml`` ``c`` reads as it starts, was deleted since ``c`` started
        (made again since, or still gone: the next round makes it again before the restart): its refusal may be of a
        missing file rather than of its configuration."""
        watch = self.run_folder
        return watch.made_again_s >= c.spawned_at or (bool(watch.read_files) and watch.lost())

    def tend_runs_lock(self) -> None:
        """On each round of the run loop: the runs folder's lock file deleted (the whole runs folder removed) leaves the
        lock on a file with no name, which stops no second ``up``: take it again on a new file, or say that another
        launcher has it (it started in this folder meanwhile)."""
        if self.runs_lock_fd is None:
            return
        runs_dir = self.run_dir.parent
        kept = keep_runs_lock(runs_dir, self.runs_lock_fd)
        if kept is not None:
            if kept != self.runs_lock_fd:
                log.warning("the runs folder's lock %s was deleted while the run ran: taken again", runs_dir / RUNS_LOCK)
            self.runs_lock_fd, self.runs_lock_lost = kept, False
        elif not self.runs_lock_lost:
            self.runs_lock_lost = True
            log.error(
                "the runs folder's lock %s was deleted while the run ran and another `cso-runtime up` took it: two runs share %s",
                runs_dir / RUNS_LOCK, runs_dir,
            )  # fmt: skip

    def tend_run_folder(self, lost: bool = False) -> None:
        """On each round of the run loop: when the run folder (or its ``logs/``) was deleted, make it again with
        ``run.json``, ``profile.yaml``, ``dataflow.md`` and ``logs/``, copy back every file the launcher and its services
        still write there (their logs, a recording: ``RunFolderWatch``, kept up to date until the run ends), and say so
        on stderr, in ``launcher.log`` and in the launcher's status (``run_dir_lost``). The run goes on: a robot is not
        stopped for a folder; what the run had written and closed before (results, a kept map) is lost, and said.
        ``lost``: known to have been deleted, whatever is there now."""
        watch = self.run_folder
        if not lost and not watch.lost():
            watch.sync()
            return
        try:
            (self.run_dir / LOG_DIR).mkdir(parents=True, exist_ok=True)
            self.write_profile()
            self.write_dataflow()
        except OSError as exc:  # the disk, or a folder above it, gone too: the run goes on, said once a round
            log.error("the run folder %s was deleted and cannot be made again (%s): the logs written from now on are lost", self.run_dir, exc.strerror or exc)
            return
        pids = [os.getpid(), *(c.proc.pid for c in self.children if c.alive and c.proc is not None)]
        rescued = watch.rescue(pids)
        self.write_run_file(self.run_file_state)  # a run still starting is still starting: "running" had no endpoints yet
        closed = "its results and " if self.written_result is not None else ""
        log.error(
            "the run folder %s (or its %s/) was deleted while the run ran: made it again, with run.json, profile.yaml and "
            "dataflow.md; copied back the %d files the run still writes (%s), kept up to date until the run ends; %s"
            "whatever else it held is lost",
            self.run_dir, LOG_DIR, len(rescued), ", ".join(str(p.relative_to(watch.run_dir)) for p in rescued) or "none found", closed,
        )  # fmt: skip

    def unserved_services(self, now: float) -> list[str]:
        """The services the launcher gave up on that no process has served (liveliness token) for
        ``supervision.given_up_grace_s`` since: without them the episode cannot go on."""
        grace = self.profile.supervision.given_up_grace_s
        return [
            c.name for c in self.children if c.gave_up and c.gave_up_at is not None and now - c.gave_up_at >= grace and c.name not in self.alive_services
        ]

    def given_up_said(self, c: Child) -> str:
        """Why the launcher gave up on ``c``, for run.json's ``reason``: its last exit code, its restarts, and its log's
        last error where it has one."""
        code = c.exit_codes[-1] if c.exit_codes else None
        how = "refused its configuration" if code == EXIT_BAD_CONFIG else f"exited (code {code}) after {c.restarts} restart{'s' if c.restarts != 1 else ''}"
        error = c.last_error()
        return f"{how}{f': {error}' if error else ''} (see {c.log_path})"

    # --- results ----------------------------------------------------------------------------------
    def result_of(self, end: EpisodeStatusMsg | None) -> EpisodeResultMsg | None:
        """The result heard (``result``) if it can be ``end``'s (``result_is_of``; any, with no end), else None."""
        result = self.result
        return result if result is not None and (end is None or result_is_of(result, end)) else None

    def fetch_result(self, session: Any, timeout_s: float = 3.0, end: EpisodeStatusMsg | None = None) -> EpisodeResultMsg | None:
        """The referee's answer to a query for the result: the first that can be ``end``'s (``result_is_of``)."""
        for reply in session.get(self.keys.episode_result, timeout=timeout_s):
            if reply.ok is None:
                continue
            try:
                msg = decode(reply.ok.payload.to_bytes(), EpisodeResultMsg)
            except MessageError as exc:
                log.warning("bad episode result: %s", exc)
                continue
            assert isinstance(msg, EpisodeResultMsg)
            if end is not None and not result_is_of(msg, end):
                log.debug("a result of episode %d answered while episode %d's is awaited: not its", msg.episode, end.episode)
                continue
            return msg
        return None

    def wait_for_result(self, session: Any, wait_s: float = 15.0, meanwhile: Callable[[], None] | None = None) -> EpisodeResultMsg | None:
        """The finished episode's result: the one published on ``episode_result``, else the answer to a
        query (the sim and the ros2_bridge answer once finished), asked again until ``wait_s`` has passed
        or the launcher is stopped. On a loaded machine one query can time out before the answer comes.
        Between its queries (3 s at most each) it calls ``meanwhile`` (the run loop's supervision and live view;
        ``supervise`` when not given): a service that crashes or hangs while the result is awaited is restarted. None
        at once when the episode goes on (``episode_goes_on``), or another has started since it ended (a restarted sim's:
        the result of the ended one went with the process that ran it). Only a result of the ended episode is its
        result (``result_of``): a late one of another episode (one a restart left behind) is not."""
        tend = self.supervise if meanwhile is None else meanwhile
        deadline = time.monotonic() + wait_s
        while self.result_of(self.ended_status) is None and not self.stop_event.is_set():
            left = deadline - time.monotonic()
            if left <= 0 or self.episode_goes_on() or (self.ended_status is not None and self.of_another_episode(self.ended_status)):
                return None
            result = self.fetch_result(session, timeout_s=min(3.0, left), end=self.ended_status)
            if result is not None:
                return result
            if not self.stop_event.wait(min(0.1, left)):  # a stop's services are stopped, never restarted
                tend()
        return self.result_of(self.ended_status)

    def judge_episode_end(self, session: Any, over: EpisodeStatusMsg, meanwhile: Callable[[], None]) -> tuple[EpisodeStatusMsg, EpisodeResultMsg | None] | None:
        """The run loop's judgement of an end heard (``episode_end_heard``): the end and its result (None: it never
        arrived), or None for an end that is not the run's: the episode goes on. A stray end is ignored (counted in
        ``rejected["episode_status"]``, logged). An end of an episode heard running before the one running
        (``of_another_episode``: the sim restarted since, into a new episode) whose result is not here, heard so or
        while its result is awaited, is left behind (``end_left_behind``): no result of it will come, and the run goes on
        with the episode running, as after any restart of the sim. Heard again (late, replayed), an end left behind is
        left behind again, whatever result of it came since: that result is not the run's (``left_behind``)."""
        if self.of_another_episode(over) and (self.result_of(over) is None or self.left_behind(over.episode)):
            self.end_left_behind(over)  # once left behind, whatever result of it came since (not the run's): heard again
            return None
        self.ended_status, self.exploring_since_end = over, None
        result = self.wait_for_result(session, meanwhile=meanwhile)
        if result is None and self.of_another_episode(over):
            self.end_left_behind(over)
            return None
        if result is None and self.episode_goes_on() and (now := self.status) is not None:
            self.stray_end(over, f"the episode goes on (step {now.step})")
            return None
        self.leave_ends_behind(over.episode)
        self.ended_status = over = self.end_of_result(over, result) if result is not None else over
        return over, result

    def leave_ends_behind(self, run_episode: int) -> None:
        """The run's end is judged (``judge_episode_end``): the ends of episodes a restart left behind heard beside it
        and not judged yet (``ends_behind``, one waiting in ``end_heard``) are left behind (``end_left_behind``): their
        results are not the run's, and ``lost_results`` names them. The end judged is set again after (it clears it).
        Never an end of ``run_episode``, the episode the run ends with (one a restart left behind whose own result came):
        heard again (replayed) since the run loop took it, it is the run's end, its result not lost."""
        with self._lock:
            ends, self.ends_behind = [e for e in self.ends_behind if e.episode != run_episode], []
            if self.end_heard is not None and self.end_heard.episode in self.episodes_before:
                if self.end_heard.episode != run_episode:
                    ends.append(self.end_heard)
                self.end_heard = None
        stray = self.stray_judged
        for end in ends:
            self.end_left_behind(end)
        self.stray_judged = stray

    def of_another_episode(self, end: EpisodeStatusMsg) -> bool:
        """Whether ``end`` names an episode heard running before the one running (``episodes_before``): not the one
        running, nor one never heard running (none known, or a restarted sim's episode that ended before it said so)."""
        running = self.episode_running
        return running is not None and end.episode != running and end.episode in self.episodes_before

    def stray_end(self, end: EpisodeStatusMsg, why: str) -> None:
        """``end`` was no end (``judge_episode_end``): counted in ``rejected["episode_status"]``, logged, ignored."""
        with self._lock:
            self.rejected["episode_status"] = self.rejected.get("episode_status", 0) + 1
        log.warning("an episode status said %s of episode %d at step %d, but %s: ignored", end.state, end.episode, end.step, why)
        self.ended_status, self.stray_judged = None, end

    def left_behind(self, episode: int) -> bool:
        """Whether the end of ``episode`` (an id; 0, none, never) was left behind (``end_left_behind``, ``lost_results``):
        its result, if it comes late, is not the run's."""
        with self._lock:  # lost_results: written by the run loop, read by the Zenoh threads too
            return episode != 0 and any(e["episode"] == episode for e in self.lost_results)

    def end_left_behind(self, end: EpisodeStatusMsg) -> None:
        """``end`` is of an episode the referee ran before the one running (``judge_episode_end``): the sim restarted since,
        into a new episode, and the ended one's result, never heard, went with the process that ran it. No stray (not
        counted in ``rejected``: the status may well be that episode's real end), and not the run's end either: the run
        goes on with the episode running, whose end and results are the run's, as after any restart of the sim. Logged,
        and named in the launcher's status (``lost_results``: ``status`` says so), once per episode."""
        # A ROS 2 bridge starts a new episode in the same process (the robot's odometry or clock started again).
        restarted, lost_with = ("the sim restarted", " with the process that ran it") if self.simulated else ("the referee started a new one", "")
        with self._lock:
            after = self.results_not_kept.get(end.episode)
        came = (
            f"no result of episode {end.episode} came: it is lost{lost_with}" if after is None
            else f"its result came late, after episode {after}'s, and was not kept: it is not the run's"
        )  # fmt: skip
        log.warning(
            "episode %d ended (%s at step %d), but episode %d has started since (%s) and %s; the run goes on with episode %d, whose results will be the run's",
            end.episode, end.state, end.step, self.episode_running, restarted, came, self.episode_running,
        )  # fmt: skip
        lost = {"episode": end.episode, "state": end.state, "step": end.step, "running": self.episode_running or 0}
        self.ended_status, self.stray_judged = None, end
        if lost in self.lost_results:  # its end heard again (late, replayed): nothing new to keep or write
            return
        with self._lock:  # read by the status queryable's thread
            self.lost_results = [e for e in self.lost_results if e["episode"] != end.episode][-(LOST_RESULTS_KEPT - 1) :] + [lost]
        self.write_run_file("running")  # run.json says it from now on: `runs` of a launcher killed later still does

    def end_of_result(self, awaited: EpisodeStatusMsg, result: EpisodeResultMsg) -> EpisodeStatusMsg:
        """The end ``result`` belongs to: the episode's real end and its result can come while a stray end is awaited,
        and the stray's state (``failed``) would say how the run ended. Of the end awaited and the latest heard since
        (``latest_end_heard``; not one of another episode, nor of another episode than the result's, ``result_is_of``),
        the latest that ended as the result says (its ``terminated_by``), else the latest."""
        later = self.latest_end_heard()
        ends = [awaited] if later is None or later is awaited or self.of_another_episode(later) or not result_is_of(result, later) else [later, awaited]
        return next((end for end in ends if end.terminated_by == result.terminated_by), ends[0])

    def episode_end_heard(self) -> EpisodeStatusMsg | None:
        """The status that says an episode is over, for the run loop to judge: ``latest_end_heard``, else an end of an
        episode a restart left behind that waited beside another (``ends_behind``), one a look."""
        if (latest := self.latest_end_heard()) is not None:
            return latest
        with self._lock:
            return self.ends_behind.pop(0) if self.ends_behind else None

    def latest_end_heard(self) -> EpisodeStatusMsg | None:
        """The status that says the episode is over: the current one, else the latest that said so since the run loop
        last asked, though one of the episode exploring came after it (``end_heard``)."""
        with self._lock:  # the status and the end heard as ``_on_sample`` left them together
            heard, self.end_heard = self.end_heard, None
            st = self.status
        if st is not None and st.state in EPISODE_OVER and st is not self.stray_judged:
            return st
        return heard

    def episode_goes_on(self) -> bool:
        """Whether the sim has reported the episode exploring again since it was said to end (the same episode): at
        the end's step or later, or stepping on from its first status of it exploring seen since (an end that claimed
        a step ahead of the sim's, ``exploring_since_end``). That end was no end (a stray or forged status), and no
        result will come. One status of an earlier step alone shows nothing: it can be a late one from before a real end."""
        ended, now = self.ended_status, self.status
        if ended is None or now is None or now is ended or now.state != "exploring" or now.episode != ended.episode:
            return False
        if self.exploring_since_end is None:
            self.exploring_since_end = now
        return now.step >= ended.step or now.step > self.exploring_since_end.step

    def progress_log_line(self, now: float) -> str:
        """The episode's progress line (``progress_log_s``), with how long it has made no new step once that is
        ``STALLED_STEP_S`` or more (a stopped sim, a stalled lockstep pipeline): the figures alone read as all well.
        The launcher's own silence (stopped, Ctrl-Z or SIGSTOP, and continued: the steps it did not hear) is not the
        episode's, as for the hang check: the stall counts from when its status watch asked again, and none is said
        while the watch has not (``StatusWatch.behind``)."""
        assert self.status is not None
        watch = self.status_watch
        if watch is not None and watch.behind(now):
            return progress_line(self.status, self.sim_step_s, self.real_time_factor, self.coverage_measured)
        stalled_s = now - max(self.step_changed_s, watch.resumed_s if watch is not None else -np.inf)
        return progress_line(self.status, self.sim_step_s, self.real_time_factor, self.coverage_measured) + (f"; no new step for {stalled_s:.0f} s" if stalled_s >= STALLED_STEP_S else "")

    def ended_at_step(self) -> int | None:
        """On a real robot, the step its ended episode ended at (its written result's) while the status shown is of
        that episode's end: the ROS 2 bridge's steps go on counting the robot's scans after it (``status``'s
        ``ended_at_step``). None otherwise (a sim's steps end with its episode; another episode; no result written)."""
        st, ended, result = self.status, self.ended_status, self.written_result
        if self.simulated or st is None or ended is None or result is None or st.state not in EPISODE_OVER or st.episode != ended.episode:
            return None
        return result.steps

    @property
    def real_time_factor(self) -> float | None:
        """Simulated seconds per wall-clock second of the episode so far, start-up left out (``pace.StepPace``); None
        on a real robot or before two statuses some steps apart have arrived."""
        return self.pace.real_time_factor if self.simulated else None

    def write_outputs(self, result: EpisodeResultMsg) -> Path:
        meta: dict[str, Any] = {"command": "cso-runtime up", "version": __version__, "software": self.software, "profile": self.data}
        meta["paused_s"] = self.pause_status()["total_s"]  # the robot held still (real time went on, and its steps)
        meta["config"] = to_dict(self.profile.exploration_config())  # every exploration parameter, as eval's summary
        if self.ended_status is not None:  # whose results these are: a robot may go on in another episode after this end
            meta["episode"] = self.ended_status.episode
        if self.lost_results:  # episodes before it whose result a restart of the referee lost: report.html says so
            meta["lost_results"] = list(self.lost_results)
        meta["coverage_measured"] = self.coverage_measured  # whether coverage_pct is a measure: `runs` and report.html read it
        meta["sim"] = self.profile.simulator()  # 2d or mujoco, as eval's; null on a real robot (episodes.csv's sim)
        sim_settings = self.profile.simulator_settings()
        if sim_settings is not None:  # every parameter of the sim service's simulator, defaults too (as eval's)
            meta["sim_settings"] = sim_settings
        from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415

        if result.method in LEARNED_METHODS:
            from cso_runtime.learned.weights import weights_provenance  # noqa: PLC0415

            sensor = self.profile.exploration_config().sensor
            meta["weights"] = {result.method: weights_provenance(result.method, sensor)}  # what the policy service loaded
        row = write_episode_outputs(self.run_dir, result, self.wall_s(), meta, self.sim_time_s(result), self.real_time_factor)
        self.written_result = result
        log.info("%s%s; results in %s", episode_figures(row, self.coverage_measured), ended_why_said(result), self.run_dir)
        return self.run_dir

    def wall_s(self) -> float:
        """Wall-clock seconds since the launcher started (episodes.csv's ``wall_s``)."""
        return time.monotonic() - self.started_s

    def sim_time_s(self, result: EpisodeResultMsg) -> float | None:
        """The episode's simulated time: one control period a step (None on a real robot)."""
        return None if self.sim_step_s is None else result.steps * self.sim_step_s

    def write_outputs_or_say(self, result: EpisodeResultMsg) -> bool:
        """``write_outputs``, or False with the file and the reason logged when one cannot be written (a full disk,
        a run folder made read-only): the launcher then stops its services and ends as failed (exit code 1), never
        with a traceback that skips their stop."""
        try:
            self.write_outputs(result)
        except OSError as exc:
            log.error(
                "cannot write the episode's results: %s: %s; the run stops, its outputs in %s are incomplete",
                exc.filename or self.run_dir, exc.strerror or exc, self.run_dir,
            )  # fmt: skip
            _, row = episode_record(result, self.wall_s(), self.sim_time_s(result), self.real_time_factor)
            log.warning("%s%s; not written to %s", episode_figures(row, self.coverage_measured), ended_why_said(result), self.run_dir)  # the terminal keeps them
            return False
        return True

    def start_episode_end(self, status: EpisodeStatusMsg, result: EpisodeResultMsg | None, recorder: Recorder | None) -> EpisodeEnd:
        """Write the ended episode's results, then finish its recording and draw its GIF (``finish_recording``, with
        its time bounds), on a thread of their own: the run loop goes on restarting crashed or hung services and
        updating the live view and the launcher's status meanwhile. ``settle_episode_end`` takes the outcome."""

        def write() -> None:
            try:
                end.written = result is not None and self.write_outputs_or_say(result)
            except Exception:  # a bug: said, and the run ends as failed, its services stopped as usual
                log.exception("writing the episode's results raised: the run stops, its outputs in %s are incomplete", self.run_dir)
            finally:
                end.outputs_done.set()
            try:
                self.finish_recording(recorder)
            except Exception:
                log.exception("finishing the recording raised")

        end = EpisodeEnd(status, result, threading.Thread(target=write, name="episode-end", daemon=True), threading.Event())
        end.thread.start()
        return end

    def settle_episode_end(self, end: EpisodeEnd) -> None:
        """Once ``end``'s results are written (or failed to be): the run's exit code and its run file say how the
        episode ended (``episode_ended_at``), while its recording and GIF may still be on their way. Once only."""
        if self.outputs_written or not end.outputs_done.is_set():
            return
        self.outputs_written, self.episode_ended_at, self.episode_state = True, time.time(), end.status.state
        if not (end.status.state == "done" and end.written):
            self.exit_code = 1
        self.write_run_file(end.status.state)

    def start_recorder(self) -> Recorder | None:
        """Record the run from before the first service starts, on a session of its own: its link and
        receive thread are not shared with the launcher's callbacks, so a busy launcher cannot make the
        router drop messages on their way to the recording."""
        path = self.record_path
        if path is None:
            return None
        from cso_runtime.recording import RecordStats, record  # noqa: PLC0415 - mcap only when recording

        stop, ready = threading.Event(), threading.Event()
        transport = TransportConfig(mode="client", connect=list(self.endpoints), zenoh_config_file=self.profile.router.zenoh_config)
        failure: list[str] = []
        stats = RecordStats(path)

        def run() -> None:
            try:
                with open_session(transport) as session:
                    record(session, self.profile.robot, path, stop, ready, stats, drain_s=RECORDING_DRAIN_S)
            except (OSError, TransportError) as exc:  # said by start_recorder (or logged once recording)
                failure.append(exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc))
                if ready.is_set():  # before that, start_recorder says why
                    log.error("recording into %s stopped: %s", self.record_path, failure[-1])

        thread = threading.Thread(target=run, name="recorder", daemon=True)
        thread.start()
        deadline = time.monotonic() + 10.0
        while not ready.wait(0.05) and thread.is_alive() and time.monotonic() < deadline:
            pass
        if not ready.is_set():
            stop.set()
            raise RecorderError(f"cannot record into {self.record_path}: {failure[0] if failure else 'the recorder did not start within 10 s'}")
        log.info("recording cso/%s/** into %s", self.profile.robot, self.record_path)
        return Recorder(stop, thread, stats)

    def finish_recording(self, recorder: Recorder | None) -> None:
        """Stop the recorder (it writes what arrived and the file's summary), then draw ``--animate``'s GIF (when
        the episode ended, and again in ``run``'s clean-up when it did not). Neither may hold up the launcher's
        stop, which ``down`` waits for only so long: a recorder not finished within ``RECORDING_STOP_S`` is left
        to finish on its own (a thread of the launcher's, ended with it) and no GIF is drawn from its file."""
        if recorder is None:
            return
        recorder.stop.set()
        recorder.thread.join(RECORDING_STOP_S)
        if recorder.thread.is_alive():
            gif = self.animation_path()
            no_gif = f"; no animation drawn (`cso-runtime animate {self.record_path} --out {gif}` draws one from it)" if gif is not None else ""
            log.warning(
                "recording not finished within %g s of its stop (a backlog on a busy machine, or its session's close hung?): "
                "the launcher goes on without it; %s holds at most the first %d messages and, until it finishes, no summary "
                "(it reads up to its last complete chunk)%s",
                RECORDING_STOP_S, self.record_path, recorder.stats.messages, no_gif,
            )
            return
        self.write_animation()

    def animation_path(self) -> Path | None:
        """Where ``up --animate`` draws the run's GIF, as ``eval --animate`` does; None when none is due (no
        ``--animate``, or a run stopped before its episode ended: it gets none, as it gets no summary.json)."""
        result = self.written_result
        if not self.animate or self.record_path is None or result is None:
            return None
        from cso_runtime.outputs import episode_animation_path  # noqa: PLC0415

        return episode_animation_path(self.run_dir, result.method or "unknown", result.scene)

    def write_animation(self) -> None:
        """``up --animate``: the finished run's recording as a GIF (``animation_path``)."""
        path = self.animation_path()
        if path is None or self.record_path is None:
            return
        from cso_runtime.animation import animate_recording  # noqa: PLC0415
        from cso_runtime.recording import RecordingError  # noqa: PLC0415

        stopping_since_s: float | None = None

        def give_up_once_stopping(seen: int, total: int | None) -> None:
            nonlocal stopping_since_s
            if not self.stop_event.is_set():
                return
            if stopping_since_s is None:
                stopping_since_s = time.monotonic()
            elif time.monotonic() - stopping_since_s > ANIMATION_STOPPING_S:
                raise _AnimationGivenUp

        try:
            stats = animate_recording(
                self.record_path, path, self.profile.robot, robot_radius_m=self.profile.exploration_config().robot.radius_m, progress=give_up_once_stopping,
            )
        except (RecordingError, OSError) as exc:
            log.error("no animation: %s", exc)
            return
        except _AnimationGivenUp:
            log.warning(
                "animation skipped: the run is stopping, and the GIF was not drawn within %g s of that; `cso-runtime animate %s --out %s` draws it",
                ANIMATION_STOPPING_S, self.record_path, path,
            )
            return
        log.info("animation in %d frames: %s", stats.frames, path)
        try:
            from cso_runtime.report import write_report  # noqa: PLC0415

            write_report(self.run_dir, json.loads((self.run_dir / "summary.json").read_text()))  # with the animation now
        except (OSError, ValueError) as exc:
            log.error("report.html not updated: %s", exc)

    def write_dataflow(self) -> None:
        """``dataflow.md``: who feeds whom in this run (Mermaid graph and table), from the services' declarations."""
        from services.dataflow import nodes_of, to_markdown  # noqa: PLC0415 - services import zenoh

        nodes = nodes_of([*self.profile.services, *self.left_out], self.profile.services)
        (self.run_dir / "dataflow.md").write_text(to_markdown(self.profile.name, nodes, outside=self.left_out))

    def robot_already_served(self, session: Any, timeout_s: float = 1.0) -> str:
        """Why this run cannot join the network, with what to change, or "": another run's launcher answers for its
        robot id, one of the services this run would start is alive under it, another run's ROS 2 bridge already
        drives the robot this run's would (``keys.robot_driver_token``), or another run started at the same moment
        takes the robot id or that robot (``cso_runtime.claims``: this run claims both before it asks, on
        ``session``, a client of the router it joins, and holds its claims in ``claim_tokens``). Two runs of one id
        would cross-feed every key (maps cleared by each other's episodes, one cmd_vel for two robots); two runs on
        one robot's namespace would each send it a command every step."""
        subjects = {robot_claim_subject(self.profile.robot): ""}
        subjects.update({driver_claim_subject(cmd_key): name for name, (cmd_key, _) in self.robot_stop_commands.items()})
        claim = RunClaim.new(self.run_id)
        self.claim_tokens = declare_claims(session, list(subjects), claim)
        went_on, lost = settle_claims(session, list(subjects), claim, timeout_s, stop=self.stop_event)
        self.claim_tokens += went_on
        # Asked after the claims are settled: a run that won, then withdrew its claims once the router answered for it
        # (``seen_at_router``), is seen here by a run that waited for it and saw its claim go.
        taken = self.robot_taken(session, timeout_s) or ("" if lost is None else self.claim_lost_said(lost, subjects[lost.subject]))
        if taken:  # withdrawn at once: a run that waits for this one's decision goes on
            self.withdraw_claims()
        return taken

    def withdraw_claims(self) -> None:
        """Undeclare this run's claims (``robot_already_served``)."""
        for token in self.claim_tokens:
            token.undeclare()
        self.claim_tokens = []

    def claim_lost_said(self, lost: LostClaim, driver: str) -> str:
        """Why this run does not start when another run started at the same moment has its robot id (``driver``: ""), or
        the robot its ``driver`` service would command, with what to change."""
        if lost.stopped:
            return "stopped while another run started at the same moment was deciding whether it goes on"
        other = f"run {lost.winner.run_id}" + (f" has not said within {DECIDE_WITHIN_S:g} s whether it goes on; try again" if lost.undecided else " goes on")
        if not driver:
            return f"robot {self.profile.robot} is being started by another run on this network at the same moment ({other}); give this run another --robot, or stop that run first"
        cmd_key = lost.subject.removeprefix(driver_claim_subject(""))
        return (
            f"the robot behind {cmd_key} is being claimed by another run starting on this network at the same moment ({other}): "
            f"this run's {driver} would send it commands too; give this run the --namespace of another robot, or stop that run first"
        )

    def robot_taken(self, session: Any, timeout_s: float) -> str:
        """Why this run cannot join the network as it is now (``robot_already_served`` without the claims), or ""."""
        another_id = "give this run another --robot"
        for reply in session.get(self.keys.launcher_status, timeout=timeout_s):
            if reply.ok is not None:
                return f"robot {self.profile.robot} is already run by another launcher on this network (its {self.keys.launcher_status} answers); {another_id}"
        mine = set(self.profile.services)
        for reply in session.liveliness().get(self.keys.alive("*"), timeout=timeout_s):
            if reply.ok is not None and (name := str(reply.ok.key_expr).rsplit("/", 1)[-1]) in mine:
                return f"robot {self.profile.robot} already has a {name} service on this network ({reply.ok.key_expr} is alive); {another_id}"
        for name, (cmd_key, _) in self.robot_stop_commands.items():
            for reply in session.liveliness().get(robot_driver_token(cmd_key, WILDCARD), timeout=timeout_s):
                if reply.ok is not None:
                    other = str(reply.ok.key_expr).rsplit("/", 1)[-1]
                    return (
                        f"the robot behind {cmd_key} is already driven by robot {other}'s run on this network ({reply.ok.key_expr} is alive): "
                        f"this run's {name} would send it commands too; give this run the --namespace of another robot, or stop that run first"
                    )
        return ""

    def seen_at_router(self, session: Any, timeout_s: float = 10.0) -> bool:
        """Whether ``session`` (a client of the router this run joined) sees this run as ``robot_taken`` asks: its
        launcher answers for the robot id, and it holds the token of each robot its bridge will drive; false after
        ``timeout_s`` (a run then keeps its claims while it runs) or once the run is stopped."""
        deadline_s = time.monotonic() + timeout_s
        while not self.stop_event.is_set() and time.monotonic() < deadline_s:
            if any(r.ok is not None for r in session.get(self.keys.launcher_status, timeout=1.0)) and all(
                any(r.ok is not None for r in session.liveliness().get(robot_driver_token(cmd_key, self.profile.robot), timeout=1.0))
                for cmd_key, _ in self.robot_stop_commands.values()
            ):
                return True
            self.stop_event.wait(0.05)
        return False

    def client_config(self) -> TransportConfig:
        """A session that joins the routers of ``router.connect`` as a client."""
        router = self.profile.router
        return TransportConfig(mode="client", connect=list(router.connect), connect_timeout_s=router.connect_timeout_s, zenoh_config_file=router.zenoh_config)

    # --- main loop --------------------------------------------------------------------------------
    def run(self, live: bool = False, stay_after_done: bool = False) -> int:
        """Start everything and supervise until the episode ends (or until stopped when ``stay_after_done``)."""
        self.detached = stay_after_done
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # First: `status` and `down` find the run while its router opens and its services spawn (seconds), not "no current run".
        self.write_run_file("starting")
        (self.run_dir / STARTING_LAUNCHER).unlink(missing_ok=True)  # `down` finds this launcher by its run file from now on
        with contextlib.suppress(OSError):  # and a foreground `up`, this very process, by it too (STARTING_UP_GLOB)
            starting_up_path(self.run_dir.parent, os.getpid()).unlink(missing_ok=True)
        self.write_profile()
        self.run_folder.expect(self.profile_path)  # every service reads it as it starts
        self.write_dataflow()
        if self.run_folder.writes_nameless([os.getpid()]):  # deleted since `up` made it and opened this one's log there
            self.tend_run_folder(lost=True)
        if self.stop_event.is_set():  # Ctrl-C (or SIGTERM) since `up` started: no router is opened
            log.warning("interrupted before any service was started")
            return self.stop_before_start(EXIT_INTERRUPTED)
        pr = self.profile  # which run this is, and where to look, before the router's and the services' lines
        log.info(
            "run %s: profile %s, scene %s, method %s, robot %s; logs, then results, in %s/",
            self.run_id, pr.name, pr.scene_label, pr.method, pr.robot, self.run_dir,
        )  # fmt: skip
        router = self.profile.router
        if router.connect:  # a robot that is off is only said once the timeout has passed: say the wait meanwhile
            log.info("joining %s (up to %g s, router.connect_timeout_s)", ", ".join(router.connect), router.connect_timeout_s)
        if router.embedded:
            session, self.endpoints = open_router(list(router.listen), list(router.connect), router.connect_timeout_s, router.zenoh_config, self.stop_event)
        else:  # join the existing router(s) instead of opening one
            self.endpoints = list(router.connect)
            session = open_session(self.client_config(), self.stop_event)
        view = LiveView(self) if live else None
        self.session = session
        if router.connect:
            self.routers_joined = self.count_joined_routers()
        with session, contextlib.ExitStack() as claiming:
            if router.connect:
                # Asked on a client of the router joined, which orders this run's claims before its questions (an
                # embedded router answers from what has reached it so far), and holds the claims until the run is seen.
                claims_session = session if not router.embedded else claiming.enter_context(open_session(self.client_config(), self.stop_event))
                if taken := self.robot_already_served(claims_session):
                    if self.stop_event.is_set():
                        log.warning("interrupted before any service was started")
                        return self.stop_before_start(EXIT_INTERRUPTED)
                    log.error("%s; no service was started", taken)
                    return self.stop_before_start(EXIT_BAD_CONFIG, f"refused: {taken}")
            subs = [session.declare_subscriber(self.keys.topic(t), self._guarded(self._on_sample)) for t in LAUNCHER_INPUTS]
            qs = [
                session.declare_queryable(self.keys.cache("goal"), self._guarded(self._on_cache_query)),
                session.declare_queryable(self.keys.cache("explore_resume"), self._guarded(self._on_pause_query)),
                session.declare_queryable(self.keys.launcher_status, self._guarded(self._on_status_query)),
            ]
            # The robot this run's bridge will drive is this run's from now on, through a bridge's start or restart.
            drivers = [session.liveliness().declare_token(robot_driver_token(cmd_key, self.profile.robot)) for cmd_key, _ in self.robot_stop_commands.values()]
            if router.connect and self.seen_at_router(claims_session):
                self.withdraw_claims()  # a run started from now on is refused by what it sees of this one
                claiming.close()
            alive_subs = [
                session.liveliness().declare_subscriber(key, self._guarded(self._on_alive), history=True)
                for key in (self.keys.alive("*"), self.keys.alive_incarnation("*", "*"))
            ]
            if self.profile.supervision.hang_timeout_s > 0:
                self.status_watch = StatusWatch(session, self.keys, self.stop_event)
                self.status_watch.start()
                claiming.callback(self.status_watch.close)  # before the session closes, however the run ends
            if self.stop_event.is_set():  # Ctrl-C (or a detached start given up on) before anything started
                log.warning("interrupted before any service was started")
                return self.stop_before_start(EXIT_INTERRUPTED)
            try:
                recorder = self.start_recorder()
            except RecorderError as exc:
                log.error("%s: no service was started", exc)
                return self.stop_before_start(EXIT_BAD_CONFIG, str(exc))
            ending: EpisodeEnd | None = None  # the ended episode's results being written (start_episode_end)
            pyplot_import: threading.Thread | None = None
            try:
                self.spawn_all()
                pyplot_import = import_pyplot_in_background()  # for the episode's figures, drawn once it ends
                self.write_run_file("running")
                if view is not None:
                    view.start()

                def tend() -> None:
                    """What the run loop does on every round, and in its waits: the runs folder's lock, the run folder,
                    supervision and the live view."""
                    self.tend_runs_lock()
                    self.tend_run_folder()
                    self.supervise()
                    if view is not None:
                        view.update()

                logged_s = time.monotonic()
                while not self.stop_event.wait(0.1):
                    tend()
                    st = self.status
                    every_s = self.profile.progress_log_s
                    if every_s > 0 and (view is None or not view.on_terminal) and time.monotonic() - logged_s >= every_s:
                        logged_s = time.monotonic()
                        if st is not None and st.state == "exploring":
                            log.info("%s", self.progress_log_line(time.monotonic()))
                    over = self.episode_end_heard()
                    if ending is None and over is not None and not self.outputs_written:
                        judged = self.judge_episode_end(session, over, tend)
                        if judged is None:  # a stray end: ignored, counted, logged
                            continue
                        over, result = judged
                        if result is None:
                            log.error("the episode is %s but its result never arrived: no summary.json was written", over.state)
                        # The recording ends with the episode: a detached run's file is finished (and its GIF
                        # drawn) now, not only at `down`; the loop goes on supervising meanwhile.
                        ending, recorder = self.start_episode_end(over, result, recorder), None
                    if ending is not None:
                        finished = not ending.thread.is_alive()  # before settling: its results are written then
                        self.settle_episode_end(ending)
                        if finished:
                            if not stay_after_done or (ending.result is not None and not ending.written):  # nothing to stay for
                                break
                            ending = None
                    referee = [c for c in self.children if c.name in REFEREES]
                    if referee and all(c.gave_up for c in referee):
                        log.error("the %s service is gone for good: stopping", referee[0].name)
                        self.stop_reason = f"gave up on {referee[0].name}: {self.given_up_said(referee[0])}"
                        self.exit_code = 1
                        break
                    unserved = [] if self.outputs_written or ending is not None else self.unserved_services(time.monotonic())
                    if unserved:
                        log.error(
                            "no process serves %s since the launcher gave up on it (%.0f s): the episode cannot go on, stopping (see %s)",
                            ", ".join(unserved), self.profile.supervision.given_up_grace_s, self.run_dir / "logs",
                        )
                        # run.json's reason, which `runs` and `report` show: it said "failed" and no more
                        self.stop_reason = "; ".join(f"gave up on {c.name}: {self.given_up_said(c)}" for c in self.children if c.name in unserved)
                        self.exit_code = 1
                        break
                else:  # stopped from outside (Ctrl-C, SIGTERM, `down`), not by one of the breaks above
                    if not self.outputs_written and ending is None:
                        step = self.status.step if self.status is not None else 0
                        log.warning("interrupted at step %d, before the episode ended: no summary.json was written", step)
                        self.exit_code = EXIT_INTERRUPTED
            finally:
                if view is not None:
                    try:
                        view.stop()
                    except Exception:  # a bug in drawing it: said, and the services are stopped all the same
                        log.exception("the live view's last redraw raised")
                if ending is None and not self.outputs_written:  # no results: the map so far, while the services still run
                    self.keep_last_map(session)
                log.info("stopping services")
                self.stop_event.set()
                stopping_s = time.monotonic()
                stop_children(self.children, self.profile.supervision.stop_timeout_s)
                log.info("services stopped in %.1f s", time.monotonic() - stopping_s)
                for c in self.children:  # killed at the last stage (hung), or died of a signal meanwhile: its own last zero Twist never went out
                    code = c.proc.returncode if c.proc is not None else None
                    if c.proc is not None and c.restart_at is None and not c.gave_up and (code is None or (code < 0 and -code not in STOP_SIGNALS)):
                        self.stop_robot(c, code)
                if ending is not None:  # its GIF is given up ANIMATION_STOPPING_S after the stop, its recorder RECORDING_STOP_S after its own
                    ending.thread.join()
                    self.settle_episode_end(ending)
                self.finish_recording(recorder)
                if pyplot_import is not None:  # done once figures were drawn; with none to draw, not waited out
                    pyplot_import.join(PYPLOT_IMPORT_STOP_S)
                    if pyplot_import.is_alive():
                        log.info("pyplot's import (for the figures; a first run builds matplotlib's font cache) is not done: the stop does not wait for it")
                if self.run_folder.lost():  # deleted since the last round: the stop's lines and the run's end are kept too
                    self.tend_run_folder()
                for a in alive_subs:
                    a.undeclare()
                for q in qs:
                    q.undeclare()
                for d in drivers:
                    d.undeclare()
                for s in subs:
                    s.undeclare()
                self.write_run_file("stopped")
                self.remove_current_pointer()
                log.info("%s", self.closing_line())
                self.run_folder.close()  # after the last line: the launcher's log copied back whole
        self.session = None
        return self.exit_code

    def keep_last_map(self, session: Any) -> None:
        """An episode stopped before its end (Ctrl-C, ``down``, a service given up on) keeps no results, but its map so far
        is worth keeping (minutes of a robot's mapping): the newest one the run answers for (``save-map``'s) goes to
        ``LAST_MAP`` in the run folder, as map_server files in the user's map frame. At most ``timeout_s`` of the stop."""
        from cso_runtime.map_files import save_map  # noqa: PLC0415
        from cso_runtime.status import newest_map  # noqa: PLC0415

        if self.status is None or self.status.state == "starting":
            return
        try:
            msg, why, map_origin = newest_map(session, self.profile.robot, timeout_s=1.0, run_dir=self.run_dir)
        except zenoh.ZError as exc:  # the session closing under it: no map, said
            msg, why, map_origin = None, str(exc), None
        if msg is None:
            log.warning("the episode's map is not kept: %s", why)
            return
        try:
            save_map(self.run_dir / LAST_MAP, msg.grid, msg.geometry, image_format=LAST_MAP_IMAGE_FORMAT, map_origin=map_origin)
        except (OSError, ValueError) as exc:
            log.error("the episode's map at step %d is not kept: %s", msg.step, getattr(exc, "strerror", None) or exc)
            return
        self.last_map_step = msg.step
        log.info("the episode's map at step %d kept: %s", msg.step, self.run_dir / LAST_MAP)

    def closing_line(self) -> str:
        """The run's last line, under the services' stop: where its results are and what to open first, or, for a
        run stopped before its episode's results were written, what it kept and how to read it."""
        if self.written_result is not None:
            return results_said(self.run_dir)
        # The episode ended and its results were not written (a full disk, no result came: said above), or it never ended.
        why = "the episode's results could not be written (see above); " if self.outputs_written else ""
        if self.last_map_step is not None:
            why += f"the episode's map at step {self.last_map_step} is in {self.run_dir / LAST_MAP}; "
        return f"{NO_RESULTS}{why}the run's profile and logs are in {self.run_dir}/ (`cso-runtime logs --run {self.run_dir}`)"


def result_is_of(result: EpisodeResultMsg, end: EpisodeStatusMsg) -> bool:
    """Whether ``result`` can be the result of the episode ``end`` says ended: of its episode (``result.episode``), or
    either without an id (0: a referee from before results named their episode, or one of one's own without ids),
    taken as before ids. A result of another episode (a late one of an episode a restart left behind) is not."""
    return result.episode == 0 or end.episode == 0 or result.episode == end.episode


def episode_record(result: EpisodeResultMsg, wall_s: float, sim_time_s: float | None = None, real_time_factor: float | None = None) -> tuple[Any, dict[str, Any]]:
    """The episode's ``EpisodeResult`` and its row of episodes.csv (Table 1's metrics), from its result message."""
    from cso_runtime.episode import EpisodeResult  # noqa: PLC0415
    from cso_runtime.evaluation import episode_row  # noqa: PLC0415

    er = EpisodeResult(
        scene=result.scene,
        steps=result.steps,
        explored_area_m2=result.explored_area_m2,
        coverage_pct=result.coverage_pct,
        traversable_area_m2=result.traversable_area_m2,
        path_length_m=result.path_length_m,
        terminated_by=result.terminated_by,
        decisions=result.decisions,
        decision_ms=[float(v) for v in result.decision_ms],
        trajectory_xy_m=result.trajectory_xy_m,
        coverage_curve_pct=result.coverage_curve_pct,
        explored_free=result.explored_free,
        map_grid=result.final_map.grid if result.final_map is not None else None,
        map_geometry=result.final_map.geometry if result.final_map is not None else None,
        sim_time_s=sim_time_s,
        ended_why=result.ended_why,
    )
    return er, episode_row(result.method or "unknown", result.seed, er, wall_s, real_time_factor)


def episode_figures(row: dict[str, Any], simulated: bool = True) -> str:
    """The episode's Table 1 figures in words, from its row: the launcher's line once its results are written (or not).
    An episode of no step has no m2/step (episodes.csv's empty cell): the line says so rather than ``nan``. A run with
    no ground truth (``simulated`` False: not ``run_profile.measures_coverage``, a real robot's) has no coverage (its
    row's 0): the line leaves it out."""
    from cso_runtime.evaluation import missing  # noqa: PLC0415

    efficiency = row["efficiency_m2_per_step"]
    per_step = "no m2/step (no step)" if missing(efficiency) else f"{efficiency:.4f} m2/step"
    return (
        f"episode {row['terminated_by']}: " + (f"{row['coverage_pct']:.2f}% coverage " if simulated else "") + f"in {row['steps']} steps; {row['explored_area_m2']:.2f} m2 explored, "
        f"{per_step}, path {row['path_length_m']:.2f} m, {row['decisions']} decisions"
    )


def ended_why_said(result: EpisodeResultMsg) -> str:
    """Why the episode ended, after its figures on the launcher's line (as after eval's progress line), where its end
    alone does not say (``no_frontier``: the frontier cells left and what kept each from being a goal); empty otherwise."""
    return f"; {result.ended_why}" if result.ended_why else ""


def write_episode_outputs(
    out_dir: Path, result: EpisodeResultMsg, wall_s: float, meta: dict[str, Any], sim_time_s: float | None = None, real_time_factor: float | None = None
) -> dict[str, Any]:
    """The same files as ``eval`` for one episode: summary.json, episodes.csv, the episode's npz, the
    robot's final map (map_server YAML and PNG),
    the coverage curve and the trajectory plot (reusing ``cso_runtime.evaluation`` writers). Returns the
    episode's row of episodes.csv (``sim_time_s`` and ``real_time_factor``: None on a real robot)."""
    from cso_runtime.evaluation import EpisodeOutcome, save_episode_files, write_outputs  # noqa: PLC0415
    from cso_runtime.outputs import COVERAGE_FIGURE, trajectory_plot_path  # noqa: PLC0415
    from cso_runtime.plots import plot_coverage_curves, plot_trajectories  # noqa: PLC0415
    from cso_runtime.report import write_report  # noqa: PLC0415

    er, row = episode_record(result, wall_s, sim_time_s, real_time_factor)
    method = row["method"]
    summary = write_outputs(out_dir, [{**row, "cell_size_m": result.resolution_m}], [], [method], meta)  # the plan's, as eval's episodes.csv
    save_episode_files(out_dir, method, result.scene, er, row, map_origin=result.map_origin)
    outcome = EpisodeOutcome.finished(method, er, row, result.plan_free, result.resolution_m, result.map_origin)
    plot_coverage_curves(out_dir / COVERAGE_FIGURE, [outcome])
    plot_trajectories(trajectory_plot_path(out_dir, result.scene), result.scene, [outcome])
    write_report(out_dir, summary)
    return row


# --- entry points -----------------------------------------------------------------------------------


def run_until_stopped(launcher: Launcher, live: bool, stay_after_done: bool) -> int:
    """``Launcher.run`` with Ctrl-C, SIGTERM and SIGHUP (its terminal closed) stopping it, in the foreground
    or detached, holding the runs folder's lock; its exit code."""
    # First: a stop from now on is the run's clean stop, never a traceback; the handlers before go back at the end.
    previous_handlers = stop_on_signals(launcher.stop_event)
    runs_dir = launcher.run_dir.parent
    launcher.runs_lock_fd = hold_runs_lock(runs_dir)  # taken again if its file is deleted as it runs (keep_runs_lock)
    try:
        if launcher.runs_lock_fd is None:
            log.error(
                "another `cso-runtime up` is running from %s (it holds %s); %s first, or give this one its own --runs-dir",
                runs_dir, runs_dir / RUNS_LOCK, down_command(runs_dir),
            )
            return EXIT_BAD_CONFIG
        return launcher.run(live=live, stay_after_done=stay_after_done)
    except TransportError as exc:  # the router to join (a robot's) is down, or a listen port is taken
        if exc.cause == STOPPED:  # Ctrl-C or SIGTERM while a session opened (a router to join that is not there)
            log.warning("interrupted before any service was started")
            return launcher.stop_before_start(EXIT_INTERRUPTED)
        log.error("%s; no service was started (%s)", exc, transport_error_hint(exc, launcher.profile.router.listen))
        return launcher.stop_before_start(EXIT_NO_ZENOH, str(exc))
    finally:
        if launcher.runs_lock_fd is not None:
            os.close(launcher.runs_lock_fd)
        restore_signal_handlers(previous_handlers)


def transport_error_hint(exc: TransportError, listen: list[str]) -> str:
    """What to do about ``up``'s router or session that did not open: a port the embedded router is to listen on
    (``listen``, the profile's ``router.listen``) is held by another process, or the router to join is not there."""
    if exc.cause == LISTEN_IN_USE:
        return listen_in_use_hint(listen, "the embedded router", f"the profile's router.listen or `--set 'router.listen=[{any_loopback_port(listen)}]'`")
    return "is the router to join running and reachable?"


RECORDING_NAME = "recording.mcap"
"""``up --record`` writes ``runs/<run-id>/recording.mcap`` unless given a file."""


def run_foreground(
    profile: Profile,
    data: dict[str, Any],
    runs_dir: Path,
    live: bool = True,
    stay_after_done: bool = False,
    record: bool | Path = False,
    animate: bool = False,
    stop_event: threading.Event | None = None,
) -> int:
    """Run in this process; ``record``: True for ``runs/<run-id>/recording.mcap``, or a file; ``animate``: draw
    that recording as a GIF at the end (records to the run folder when ``record`` is False); ``stop_event``: set
    on a signal since ``up`` started (a stop before the launcher's own handlers ends the run cleanly too)."""
    run_dir = new_run_dir(runs_dir, profile)
    launcher = Launcher(profile, data, run_dir, _record_path(run_dir, record or animate), animate, stop_event=stop_event)
    # The launcher's own lines go to logs/launcher.log too, as a detached launcher's do (its stdout).
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    # A path of bytes that are no UTF-8 (the scene's) is escaped, as stderr writes it: a strict file raised at every line.
    handler = logging.FileHandler(run_dir / "logs" / "launcher.log", encoding="utf-8", errors="backslashreplace")
    handler.setFormatter(logging.Formatter(LOG_FORMAT))
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        return run_until_stopped(launcher, live=live, stay_after_done=stay_after_done)
    finally:
        root.removeHandler(handler)
        handler.close()


def _record_path(run_dir: Path, record: bool | Path) -> Path | None:
    if record is False or record is None:
        return None
    from cso_runtime.recording import recording_path  # noqa: PLC0415

    return run_dir / RECORDING_NAME if record is True else recording_path(Path(record), run_dir, run_dir.name)


def start_detached(
    profile: Profile,
    data: dict[str, Any],
    runs_dir: Path,
    ready_timeout_s: float = 30.0,
    record: bool | Path = False,
    animate: bool = False,
    stop_event: threading.Event | None = None,
) -> tuple[int, str]:
    """Start a launcher in the background (own session); returns once its services are spawned. ``stop_event``:
    set by ``up``'s signal handlers (Ctrl-C, SIGTERM, SIGHUP); without it a Ctrl-C (KeyboardInterrupt) stops
    the start the same way. A start given up on stops its launcher and leaves a run file that says so."""
    stop = stop_event if stop_event is not None else threading.Event()
    if stop.is_set():
        return EXIT_INTERRUPTED, "interrupted before the launcher started: no run was started"
    run_dir = new_run_dir(runs_dir, profile)
    record_path = _record_path(run_dir, record or animate)
    run_dir.mkdir(parents=True, exist_ok=True)
    data_path = run_dir / "profile.requested.yaml"
    write_text_atomic(data_path, yaml_dump(data, sort_keys=False))
    log_path = run_dir / "logs" / "launcher.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    profile_text = yaml_dump(data, sort_keys=False).encode()
    with log_path.open("ab") as fh:
        proc = subprocess.Popen(
            [*python_module_argv("cso_runtime.launcher"), "--profile-data", STDIN_PATH, "--run-dir", str(run_dir)]
            + (["--command-line", line] if (line := command_line()) is not None else [])  # up's, for the run's software_provenance
            + (["--record", str(record_path.resolve())] if record_path is not None else [])
            + (["--animate"] if animate else []),
            stdout=fh,
            stderr=subprocess.STDOUT,
            stdin=subprocess.PIPE,
            start_new_session=True,
        )
    starting = run_dir / STARTING_LAUNCHER  # `down` finds the launcher by it until its run file does (current_run.down)
    try:
        # Named first, the moment it runs: a `down` while its profile was written to it found neither this nor a run file
        # ("nothing running"), and the run came up all the same.
        with contextlib.suppress(OSError):  # the run folder deleted as the launcher starts (which makes it again): not found then
            write_text_atomic(starting, json.dumps({"launcher_pid": proc.pid, "launcher_start_ticks": process_start_ticks(proc.pid)}))
        # On its stdin, not from profile.requested.yaml (kept for the record): a run folder deleted in the second the
        # launcher takes to start would leave it nothing to run (the run goes on, as for a folder deleted later).
        assert proc.stdin is not None
        with contextlib.suppress(OSError), proc.stdin:  # a launcher dead at once: its exit code says why, below
            proc.stdin.write(profile_text)
        return _wait_for_detached(proc, profile, data, run_dir, record_path, animate, log_path, ready_timeout_s, stop)
    finally:
        starting.unlink(missing_ok=True)


def _wait_for_detached(
    proc: subprocess.Popen, profile: Profile, data: dict[str, Any], run_dir: Path, record_path: Path | None, animate: bool, log_path: Path, ready_timeout_s: float, stop: threading.Event
) -> tuple[int, str]:
    """``start_detached``'s wait for its launcher to be ready, or its end."""
    deadline = time.monotonic() + ready_timeout_s
    try:
        while time.monotonic() < deadline and not stop.is_set():
            # Its exit first, then its run.json: read the other way round, a launcher that wrote its last run.json and
            # exited between the two looks (0 after a `down` of a done run) was said by its exit code alone, 0 as 1.
            exit_code = proc.poll()
            info: Any = None
            with contextlib.suppress(OSError, ValueError):
                info = json.loads((run_dir / "run.json").read_text())
            # Ended before this look, after it spawned its services (they failed at once, a `down`): not "started". One that
            # spawned none (refused, no router) exits with its own code, said below as `up` says it.
            if isinstance(info, dict) and info.get("state") == "stopped" and info.get("services"):
                return _detached_start_stopped(proc, info, run_dir, log_path)
            # Its exit before its run.json: a launcher killed (SIGKILL) after it spawned its services left a run.json that
            # names them, and `up --detach` said "started" (exit 0) of a run with no launcher, its services orphaned.
            if exit_code in (-signal.SIGTERM, -signal.SIGKILL):  # `down` as it started (STARTING_LAUNCHER), before its handlers
                _stop_unstarted_launcher(proc, Launcher(profile, data, run_dir, record_path, animate), EXIT_INTERRUPTED)
                return EXIT_INTERRUPTED, f"the launcher (pid {proc.pid}) was stopped as it started (`cso-runtime down`?): no run was started; see {log_path}"
            if exit_code is not None:  # its own code (2: refused, 3: no router), so `up --detach` says the same as `up`
                return exit_code or 1, f"the launcher exited with code {exit_code}; see {log_path}:\n{log_tail(log_path)}"
            if isinstance(info, dict) and info.get("services") and info.get("endpoints"):
                follow = runs_command("logs -f", run_dir.parent)  # of this runs folder: a plain `logs -f` reads ./runs
                return 0, (
                    f"run {run_dir.name} started (launcher pid {proc.pid}, router {', '.join(info['endpoints'])}); logs in {run_dir / 'logs'} "
                    f"({follow} follows them), results in {run_dir}/ once its episode ends"
                )
            stop.wait(0.05)
    except KeyboardInterrupt:  # Ctrl-C while waiting, without up's handlers: the same as with them
        stop.set()
    if stop.is_set():  # the user wants no run, not one left in the background
        _stop_unstarted_launcher(proc, Launcher(profile, data, run_dir, record_path, animate), EXIT_INTERRUPTED)
        return EXIT_INTERRUPTED, f"interrupted while the launcher started: stopped it (launcher pid {proc.pid}); see {log_path}"
    _stop_unstarted_launcher(proc, Launcher(profile, data, run_dir, record_path, animate), 1)
    return 1, f"the launcher did not start within {ready_timeout_s:.0f} s: stopped it; see {log_path}"


DETACHED_EXIT_WAIT_S = 10.0
"""How long ``up --detach`` waits for a launcher that has ended its run (run.json ``stopped``) to exit, for its log's end."""


def _detached_start_stopped(proc: subprocess.Popen, info: dict[str, Any], run_dir: Path, log_path: Path) -> tuple[int, str]:
    """``start_detached``'s answer when the launcher's run.json already says the run stopped (it failed at once, or
    ``down`` stopped it) by the time ``up --detach`` looked: how it ended and the run's exit code (``status --watch``'s
    ``run_end_exit_code``), not "started", exit 0, of a run that is over. Its launcher, exiting, is waited for a while."""
    from cso_runtime.status import run_end_exit_code  # noqa: PLC0415 - only for this answer

    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=DETACHED_EXIT_WAIT_S)
    reason = f" ({info['reason']})" if info.get("reason") else ""
    if info.get("outcome") == "done":  # a short episode on a busy host: over, and well, before this look
        return 0, f"run {run_dir.name} started and has ended already: done{reason} (launcher pid {proc.pid}); results in {run_dir}/"
    return run_end_exit_code(info), (
        f"run {run_dir.name} stopped as it started: {info.get('outcome') or 'failed'}{reason} (launcher pid {proc.pid}); see {log_path}:\n{log_tail(log_path)}"
    )


def log_tail(path: Path, tail_chars: int = 2000) -> str:
    """The end of a log for a message; what happened to it when it cannot be read (its run folder deleted)."""
    try:
        return path.read_text(errors="replace")[-tail_chars:]
    except OSError as exc:
        return f"(cannot read it: {exc.strerror or exc}; was the run folder deleted?)"


def _stop_unstarted_launcher(proc: subprocess.Popen, run: Launcher, exit_code: int) -> None:
    """Stop a detached launcher that never got going (``_stop_launcher``) and leave its run as a launcher that
    stopped before its services would: a run file that says how it ended (the launcher's own, if it wrote one
    as it stopped; else one written here) and no current run, whatever service it had started stopped."""
    _stop_launcher(proc)
    runs_dir = run.run_dir.parent
    current = read_current_run(runs_dir)
    if current is not None and current.get("run_id") == run.run_id:  # killed, not stopped, after it spawned services
        down(runs_dir, timeout_s=0.0, stop_starting=False)  # its run's leftovers only: another `up` of the folder starts
    try:
        if json.loads((run.run_dir / "run.json").read_text()).get("state") == "stopped":
            return
    except (OSError, ValueError):
        pass
    run.launcher_pid = proc.pid
    # run.json only: the current-run file no longer names this run (down cleared it above), and another `up` of the folder
    # may have started since its launcher died: written "stopped" and removed, it left that run to no `status` or `down`.
    run.writes_current_run = False
    run.stop_before_start(exit_code)


def _stop_launcher(proc: subprocess.Popen, timeout_s: float = 3 * SupervisionConfig.stop_timeout_s + DOWN_MARGIN_S) -> None:
    """Stop a detached launcher that never got going, then kill it. SIGTERM, not SIGINT: once its handlers are
    installed (the first thing it does) it stops whatever it spawned, as on SIGINT; before that (still importing)
    it ends quietly, where SIGINT would leave a KeyboardInterrupt traceback in its log."""
    for sig, wait_s in ((signal.SIGTERM, timeout_s), (signal.SIGKILL, 2.0)):
        if proc.poll() is not None:
            return
        proc.send_signal(sig)
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            continue


STDIN_PATH = "-"
"""``--profile-data -``: the profile's data comes on the launcher's stdin (``start_detached``)."""


def main(argv: list[str] | None = None) -> int:
    """Detached launcher process (started by ``up --detach``): runs until ``down``."""
    p = argparse.ArgumentParser(prog="python -m cso_runtime.launcher")
    p.add_argument("--profile-data", type=Path, required=True, help="The profile's data (YAML), as up validated it; -: on stdin")
    p.add_argument("--run-dir", type=Path, required=True)
    p.add_argument("--record", type=Path, default=None, help="MCAP file recording the run")
    p.add_argument("--animate", action="store_true", help="Draw the recording as a GIF when the run stops")
    p.add_argument("--command-line", default=None, help="The command that started this launcher (up --detach's), recorded in the run's results")
    stop = threading.Event()
    stop_on_signals(stop)  # first: `up --detach` given up on (SIGTERM) while this one loads its profile is a clean stop
    args = p.parse_args(argv)
    if args.command_line is not None:
        record_command_line(shlex.split(args.command_line))
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    from_up = str(args.profile_data) == STDIN_PATH
    data = yaml_load(sys.stdin.buffer) if from_up else load_yaml(args.profile_data)  # bytes: UTF-8 as up wrote it, whatever the locale
    if from_up and not data:  # stdin closed with nothing on it: `up --detach` killed (SIGKILL) before its handover
        log.error("no profile came from `up --detach` (was it killed as it started this launcher?): no run was started")
        return EXIT_INTERRUPTED
    profile = from_dict(Profile, data or {}, where="the profile from up" if from_up else str(args.profile_data))
    return run_until_stopped(Launcher(profile, data, args.run_dir, args.record, args.animate, stop_event=stop), live=False, stay_after_done=True)


if __name__ == "__main__":
    raise SystemExit(main())

