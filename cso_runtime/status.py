"""``cso-runtime status`` and ``save-map``: ask a running episode over Zenoh how it is doing, or for its map.

``status`` queries the sim's episode-status queryable, the launcher's status, each service's status
queryable and the liveliness tokens; ``save-map`` the latest map the referee keeps (``cache/map``), as
Nav2's ``map_saver_cli`` does with ``/map``. Short timeouts: when nothing answers they say so quickly.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

import zenoh

from cso_runtime.geometry import MAP_FRAME_ORIGIN, Pose2D, map_frame_pose, map_frame_xy, rounded_floats
from cso_runtime.keys import WILDCARD, KeyExprError, RobotKeys, check_robot_id, robot_of
from cso_runtime.messages import (
    EPISODE_OVER,
    LAST_EPISODE_FIGURES,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    LauncherStatusMsg,
    MapMsg,
    Message,
    MessageError,
    ServiceStatusMsg,
    decode,
    encode,
)
from cso_runtime.pace import real_time_words
from cso_runtime.pause import pause_note
from cso_runtime.transport import ZENOH_CONFIG_ENV, TransportConfig, TransportError, zenoh_config

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

SERVICES = ("sim", "mapper", "frontier", "policy", "planner")
"""The services a status lists as DOWN when nothing says which the run has (no launcher answered: services
started by hand); with a launcher, its profile's services (``limo-ros2`` has a ROS 2 bridge and no sim)."""


def _collect(replies: Any) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]


M = TypeVar("M", bound=Message)


def _decoded(replies: Any, cls: type[M]) -> list[M]:
    """The replies that decode as ``cls``, in the order they came; malformed ones are left out."""
    out: list[M] = []
    for payload in _collect(replies):
        try:
            msg = decode(payload, cls)
        except MessageError:
            continue
        assert isinstance(msg, cls)
        out.append(msg)
    return out


CONNECT_TIMEOUT_MS = 500
"""How long ``status`` and ``save-map`` wait for a router's handshake: a live one on loopback answers in
milliseconds and on a LAN in tens of them, and "nothing running" must come within 2 s of the command."""


def _client_session(connect: list[str], zenoh_config_file: str | None = None) -> zenoh.Session | None:
    """A client session to ``connect`` that gives up on a silent endpoint after ``CONNECT_TIMEOUT_MS`` (None then),
    started from ``zenoh_config_file`` (None: this process's, ``$CSO_ZENOH_CONFIG``)."""
    cfg = zenoh_config(client_transport(connect, zenoh_config_file))
    cfg.insert_json5("connect/timeout_ms", str(CONNECT_TIMEOUT_MS))
    try:
        return zenoh.open(cfg)
    except zenoh.ZError:
        return None


def query_status(connect: list[str], robot: str = "r0", timeout_s: float = 0.6, zenoh_config_file: str | None = None) -> dict[str, Any] | None:
    """The episode's status as a plain dict, or None when nothing answers. ``zenoh_config_file``: as ``RunTarget``'s
    (None: this process's)."""
    session = _client_session(connect, zenoh_config_file)
    if session is None:
        return None
    keys = RobotKeys(robot)
    with session:
        # All four questions at once: each handler fills while the others wait.
        opts: dict[str, Any] = {
            "target": zenoh.QueryTarget.ALL,
            "consolidation": zenoh.ConsolidationMode.NONE,
            "timeout": timeout_s,
        }
        ep_replies = session.get(keys.episode_status, **opts)
        la_replies = session.get(keys.launcher_status, **opts)
        sv_replies = session.get(keys.service_status("*"), **opts)
        alive_replies = session.liveliness().get(keys.alive("*"), timeout=timeout_s)
        episodes = _decoded(ep_replies, EpisodeStatusMsg)
        episode = episodes[-1].to_dict() if episodes else None
        launchers = _decoded(la_replies, LauncherStatusMsg)
        launcher = launchers[-1].to_dict() if launchers else None
        services = {smsg.service: smsg.to_dict() for smsg in _decoded(sv_replies, ServiceStatusMsg)}
        alive = {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in alive_replies if r.ok is not None}
    if episode is None and launcher is None and not alive:
        return None
    return status_of(robot, episode, launcher, services, alive)


def status_of(
    robot: str, episode: dict[str, Any] | None, launcher: dict[str, Any] | None, services: dict[str, dict[str, Any]], alive: set[str]
) -> dict[str, Any]:
    """``status --json``'s object from what answered: the episode's, the launcher's and each service's status
    (their ``to_dict()``), and the services whose liveliness tokens are there. ``waiting_for``: the services the
    episode waits for that this run did not start and no process serves (a shared policy server not up, or gone)."""
    expected = set(launcher["services"]) if launcher is not None and launcher.get("services") else set(SERVICES)
    names = sorted(expected | set(services))
    table = {}
    for name in names:
        entry: dict[str, Any] = {"alive": name in alive}
        s = services.get(name)
        if s is not None:
            entry.update(state=s["state"], reason=s["reason"], last_step=s["last_step"], rejected=s["rejected"], processed=s["processed"])
            entry["counters"] = dict(s.get("counters") or {})
        lsv = (launcher or {}).get("services", {}).get(name)
        if lsv is not None and lsv.get("outside"):  # not started by this run (a shared policy server's): no pid here
            entry["outside"] = True
            if lsv.get("awaited"):  # and the episode waits for it (the policy; not a viewer's bridge started by hand)
                entry["awaited"] = True
        elif lsv is not None:
            entry.update(pid=lsv.get("pid"), restarts=lsv.get("restarts"), gave_up=lsv.get("gave_up"), hung_kills=lsv.get("hung_kills", 0))
            entry["robot_stops"] = lsv.get("robot_stops", 0)
            entry["process_alive"] = bool(lsv.get("process_alive"))  # its process runs (its token may not be there yet)
            entry["came_up"] = bool(lsv.get("came_up"))  # seen alive since its process started (an older launcher: not said)
            # Its process runs, it was up, its token is gone (stopped, hung: its lease ran out) and it does not answer:
            # not "starting" (that is before it first came up), until the hang check kills it.
            entry["not_answering"] = entry["process_alive"] and entry["came_up"] and name not in alive and s is None and not lsv.get("gave_up")
            if lsv.get("command"):  # an executable of one's own: its process is all the launcher knows of it
                entry["command"] = True
        table[name] = entry
    ep, age_s = episode_or_last_heard(episode, launcher)
    over = ep.get("state") in EPISODE_OVER
    map_origin = ep.get("map_origin", MAP_FRAME_ORIGIN.as_list())  # none in an older launcher's last-heard status
    goal = ep.get("goal_xy_m")  # none in the launcher's last-heard status
    pose = ep.get("pose")  # the robot's odometry pose in the scene's frame; none before the first odometry (last-heard: where it ended)
    pose_in_map = map_frame_pose(Pose2D(*map_origin), None if pose is None else Pose2D(*pose))  # as EpisodeStatusMsg.pose_in_map_frame
    from cso_runtime.run_profile import measures_coverage  # noqa: PLC0415 - the run's services tell whether it has a ground truth

    return {
        "robot": robot,
        "run_id": (launcher or {}).get("run_id", ""),
        "state": ep.get("state", "starting"),
        "episode": ep.get("episode", 0),
        "step": ep.get("step", 0),
        "coverage_pct": ep.get("coverage_pct", 0.0),
        "explored_area_m2": ep.get("explored_area_m2", 0.0),
        "path_length_m": ep.get("path_length_m", 0.0),
        "goal": None if goal is None else map_frame_xy(Pose2D(*map_origin), goal),  # in the user's map frame, as the scene's start
        "map_origin": map_origin,
        "pose": None if pose_in_map is None else pose_in_map.as_list(),  # [x_m, y_m, yaw_rad], as the goal
        "twist": ep.get("twist"),  # [linear_mps, angular_radps], the robot's own frame
        "decisions": ep.get("decisions", 0),
        "last_decision_ms": ep.get("last_decision_ms", 0.0),
        "terminated_by": ep.get("terminated_by", ""),
        "reason": ep.get("reason", ""),
        "scene": ep.get("scene", ""),
        "method": ep.get("method", ""),
        "lockstep_timeouts": ep.get("lockstep_timeouts", 0),
        "services": table,
        # False: coverage_pct's 0 is no measure (no ground truth): as the referee's own status said (its word, also with
        # no launcher to ask), else as the launcher said, else (an older one's, or none answered) as the run's services say
        "coverage_measured": measures_coverage({"services": table}, coverage_said(ep, launcher)),
        "waiting_for": [] if over else [name for name, e in table.items() if e.get("awaited") and not e["alive"]],
        "launcher_rejected": (launcher or {}).get("rejected", {}),
        "launcher_handler_errors": (launcher or {}).get("handler_errors", {}),
        "status_age_s": age_s,
        "real_time_factor": (launcher or {}).get("real_time_factor"),
        "lost_router": (launcher or {}).get("lost_router"),
        "run_dir_lost": (launcher or {}).get("run_dir_lost", 0),
        "lost_results": (launcher or {}).get("lost_results", []),  # episodes whose result a restart of the referee lost
        "launcher_state": (launcher or {}).get("state"),
        "pause": (launcher or {}).get("pause"),
        "referee": (launcher or {}).get("referee"),  # which kind of referee the run has (the launcher's word); None: not said
    }


def coverage_said(episode: dict[str, Any], launcher: dict[str, Any] | None) -> bool | None:
    """Whether the run measures coverage as it said so itself: its referee's ``episode_status`` (``coverage_measured``,
    the one that knows: the sim yes, a ROS 2 bridge no, a referee of one's own as it declares), else its launcher's
    status (which takes the referee's word once heard, else judges by the services' names); None where neither says
    (an older referee and launcher, or no launcher), for ``run_profile.measures_coverage`` to judge by the services."""
    for said in (episode.get("coverage_measured"), (launcher or {}).get("coverage_measured")):
        if isinstance(said, bool):
            return said
    return None


COMMAND_NODE_NOTE = "no status: a command node"
"""What ``status`` and the live view say of a command node (``services.<name>.command``) in place of its state."""

NOT_ANSWERING = "not answering (its liveliness token is gone: stopped or hung?)"
"""What ``status`` and the live view say of a service whose process runs, that came up in this process and whose
liveliness token is gone since (SIGSTOP, a hang: its Zenoh lease ran out), until the hang check kills it: "starting"
is said only before it first came up. ``status --json``: ``not_answering`` true."""

STALE = "stale"
"""``status``'s state when the sim does not answer but the launcher heard an episode status from it before
(the sim stopped by SIGSTOP, hung, or gone): the episode is not known to go on; the reason gives the age."""


def episode_or_last_heard(episode: dict[str, Any] | None, launcher: dict[str, Any] | None) -> tuple[dict[str, Any], float | None]:
    """The episode's status to show and its age in seconds (None: fresh, the sim answered). Without the sim's
    answer, the last status the launcher heard (``last_episode``): "starting" only when none was ever heard, else
    ``stale`` with the last state, step and age in the reason (an episode that was over stays over)."""
    if episode is not None:
        return episode, None
    last = (launcher or {}).get("last_episode")
    if last is None:
        return {"state": "starting"}, None
    age_s = float(last["age_s"])
    heard = {"step": last["step"], "episode": last["episode"], **{k: last[k] for k in LAST_EPISODE_FIGURES if k in last}}
    if last["state"] in EPISODE_OVER:
        return {**heard, "state": last["state"]}, age_s
    why = f"the sim does not answer; its last episode status, {age_s:.1f} s ago, said {last['state']} at step {last['step']}"
    return {**heard, "state": STALE, "reason": why}, age_s


class RunTarget(NamedTuple):
    """Whom ``status``, ``save-map``, ``record``, ``replay``, ``pause`` and ``resume`` ask, and how their sessions join."""

    connect: list[str]
    """Router endpoints (none: no run to ask)."""
    robot: str | None
    """The robot's id (None: not named; the commands take ``r0``)."""
    zenoh_config_file: str | None
    """The Zenoh config file the sessions start from; None: this process's (``$CSO_ZENOH_CONFIG``, or Zenoh's defaults)."""


def client_transport(connect: list[str], zenoh_config_file: str | None = None) -> TransportConfig:
    """A client's transport to ``connect``, from ``zenoh_config_file`` (None: the default, ``$CSO_ZENOH_CONFIG``)."""
    if zenoh_config_file is None:
        return TransportConfig(mode="client", connect=list(connect))
    return TransportConfig(mode="client", connect=list(connect), zenoh_config_file=zenoh_config_file)


def endpoints_of_run(info: dict[str, Any] | None) -> RunTarget:
    """Router endpoints, robot and Zenoh config of a run file read by ``read_current_run`` (None: no run, no endpoints).

    A run whose router asks for credentials (``up --zenoh-config``) names its Zenoh config file there: the sessions to
    it start from that file, unless this process was given one (``--zenoh-config``, ``$CSO_ZENOH_CONFIG``), so that
    ``status``, ``save-map``, ``record``, ``replay``, ``pause`` and ``resume`` of the current run need no flag more than
    ``up`` had. Reading the run file changes nothing in this process (its environment included): the file goes to the
    sessions asked."""
    if info is None:
        return RunTarget([], None, None)
    run_config = info.get("zenoh_config")
    given = ZENOH_CONFIG_ENV in os.environ
    zenoh_config_file = run_config if isinstance(run_config, str) and run_config and not given else None
    robot = info.get("robot")
    return RunTarget(list(info.get("endpoints") or []), robot if isinstance(robot, str) else None, zenoh_config_file)


def dead_launcher_of_run(info: dict[str, Any] | None, runs_dir: Path) -> str | None:
    """Why the current run cannot answer when its launcher (which holds the embedded router) has exited
    without removing ``runs/current.json`` (SIGKILL, a crash), else None. Said at once, not after a
    connect timeout to a router that is gone."""
    from cso_runtime.current_run import current_launcher_alive, down_command  # noqa: PLC0415

    if info is None or not info.get("launcher_pid") or current_launcher_alive(info):
        return None
    return f"run {info['run_id']}'s launcher, pid {info['launcher_pid']}, has exited; {down_command(runs_dir)} clears {runs_dir / 'current.json'}"


def stopped_launcher_of_run(info: dict[str, Any] | None, runs_dir: Path) -> str | None:
    """Why the current run (of ``runs_dir``) does not answer when its launcher is stopped (Ctrl-Z on ``up``, SIGSTOP):
    its embedded router is stopped with it, while every service runs. None when the launcher is not stopped."""
    from cso_runtime.current_run import current_launcher_alive, down_command, stopped_words  # noqa: PLC0415

    if info is None or not info.get("launcher_pid") or not current_launcher_alive(info) or not (stopped := stopped_words(info["launcher_pid"])):
        return None
    return f"run {info['run_id']}'s launcher, pid {info['launcher_pid']}, {stopped[0]}, and its router with it: {stopped[1]}, {down_command(runs_dir)} to stop the run"


def lost_router_of_run(info: dict[str, Any] | None) -> str | None:
    """Why the current run does not answer when its launcher lost the router it joined (the robot's bridge down):
    the launcher's run file says so (``lost_router``); None otherwise."""
    if info is None or not info.get("lost_router"):
        return None
    return f"run {info.get('run_id')}'s launcher lost the router at {info['lost_router']} (is the robot or its zenoh bridge down?)"


NOT_RUNNING = "not running"
"""``status --json``'s state when nothing answers (beside starting, exploring, done, failed and stale), so a script that
reads the JSON gets JSON then too."""


def print_json(data: dict[str, Any]) -> None:
    """One line of ``status --json`` (``--watch``: one a period), each float ``rounded_floats``: a pose's ``1.2`` m, not
    the float sum's ``1.2000000000000002``. Every line it prints comes from here."""
    print(json.dumps(rounded_floats(data)), flush=True)


def say_nothing_running(why: str, as_json: bool) -> int:
    """``nothing running (why)`` on stdout, or with ``--json`` a status object with the state ``not running``; exit 1."""
    if as_json:
        print_json({"state": NOT_RUNNING, "reason": f"nothing running ({why})"})
    else:
        print(f"nothing running ({why})")
    return 1


def reachable_target(connect: list[str], robot: str | None, runs_dir: Path, as_json: bool = False) -> RunTarget | int:
    """Whom to ask (the given endpoints and robot, else the current run's; its robot always named), or the exit code after saying why
    there is no one to ask: 1 when nothing runs, 2 when ``connect`` cannot name a router (a typo such as
    ``127.0.0.1:7447``: a usage error, not "nothing running"), ``robot`` is not one robot's id, or ``connect`` was given
    without ``robot`` and several robots answer there (which one is the user's to say; the one that answers is taken)."""
    from cso_runtime.current_run import read_current_run  # noqa: PLC0415

    # The run file read once: the endpoints and the launcher's liveness are then of one run, even when a new
    # run replaces the file in between (and a bad file is warned about once).
    return target_of_run(connect, robot, runs_dir, None if connect else read_current_run(runs_dir), as_json)


def target_of_run(connect: list[str], robot: str | None, runs_dir: Path, run_info: dict[str, Any] | None, as_json: bool = False) -> RunTarget | int:
    """``reachable_target`` of the run file ``run_info`` (``read_current_run`` of ``runs_dir``; None: none, or
    ``connect`` given), read by the caller: one that says more of the run (``save-map``, its folder) says it of the run
    it asks."""
    from cso_runtime.current_run import runs_command  # noqa: PLC0415

    given_connect = bool(connect)
    robot_named = robot is not None
    zenoh_config_file = None
    if not given_connect:
        connect, run_robot, zenoh_config_file = endpoints_of_run(run_info)
        robot = robot or run_robot
    robot = robot or "r0"
    try:  # one robot's status or map: a wildcard or a key-breaking id is a usage error, not "nothing running"
        check_robot_id(robot)
    except KeyExprError as exc:
        print(f"error: --robot: {exc}", file=sys.stderr)
        return 2
    if not given_connect and (not_yet := current_run_not_joinable(run_info, runs_dir)) is not None:
        if not_yet.state != "starting":
            return say_nothing_running(not_yet.said, as_json)
        if as_json:
            print_json({"state": "starting", "run_id": not_yet.run_id, "reason": not_yet.said})
        else:
            print(not_yet.said)
        return 1
    # Before "no current run": a launcher killed while starting left a run file with no endpoints.
    if not given_connect and (gone := dead_launcher_of_run(run_info, runs_dir)):
        return say_nothing_running(gone, as_json)
    if not connect:  # the folder looked in named: an `up` started in another working folder has its run file there
        return say_nothing_running(f"no current run in {runs_dir}; give --runs-dir of the folder `up` used, or --connect ENDPOINT to ask another host; {runs_command('runs', runs_dir)} lists past runs", as_json)
    try:
        client_transport(connect, zenoh_config_file).validate()
    except TransportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if given_connect and not robot_named:  # an endpoint of several robots' network: which one is the user's to say
        try:
            robot = robot_at_endpoint(connect, zenoh_config_file) or robot
        except AmbiguousRobotError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return RunTarget(connect, robot, zenoh_config_file)


class NotJoinable(NamedTuple):
    """Why the current run cannot be joined though its launcher (or its ``up``) lives (``current_run_not_joinable``)."""

    state: str
    """``starting`` (not yet), or ``stopped`` (no more: its launcher has ended the run and is exiting)."""
    run_id: str
    """The run's id; "" for an ``up`` that has written no run file yet."""
    said: str
    """What to tell the user."""


def current_run_not_joinable(run_info: dict[str, Any] | None, runs_dir: Path) -> NotJoinable | None:
    """Why the current run of ``runs_dir`` (its run file, ``run_info``, as ``read_current_run`` read it; None: none)
    cannot be joined, where a process of it lives: its launcher has not opened its router yet (it writes its run file
    first: ``starting_run``), an ``up`` still checks its profile and has written no run file (``starting_up_line``; one
    that a launcher gone left is no run), or its launcher has ended the run (``stopped``) and is exiting: ``status`` said
    "no current run in runs; give --runs-dir ..." of it, or waited out a client's timeout on its closing router. None:
    join it, or there is nothing of it to join (no run; its launcher gone: ``dead_launcher_of_run``). What ``status``,
    ``save-map``, ``pause``, ``resume``, ``record`` and ``replay`` say instead of "no current run"."""
    from cso_runtime.current_run import current_launcher_alive, runs_command, starting_run, starting_up_line  # noqa: PLC0415

    if run_info is not None and (starting := starting_run(run_info)):
        return NotJoinable("starting", run_info["run_id"], starting)
    if (run_info is None or not current_launcher_alive(run_info)) and (up_starting := starting_up_line(runs_dir)):
        return NotJoinable("starting", "", up_starting)
    if run_info is not None and run_info.get("state") == "stopped" and current_launcher_alive(run_info):
        outcome = run_info.get("outcome") or "stopped"
        ended = f"run {run_info['run_id']} has ended ({outcome}) and its launcher is exiting; {runs_command('runs', runs_dir)} lists it"
        return NotJoinable("stopped", run_info["run_id"], ended)
    return None


class AmbiguousRobotError(ValueError):
    """Several robots answer at the endpoint a command was given without ``--robot``."""


def robot_at_endpoint(connect: list[str], zenoh_config_file: str | None = None, wildcard_too: bool = False) -> str | None:
    """The one robot that answers at ``connect`` (None when none does, or no router answers), for a command given
    ``--connect`` and no ``--robot``; an AmbiguousRobotError naming them when several do, rather than pick one.
    ``wildcard_too``: the command also takes ``--robot '*'`` (every robot), which the error then offers."""
    robots = robots_answering(connect, zenoh_config_file)
    if len(robots) > 1:
        every = ", or '*' for every robot" if wildcard_too else ""
        raise AmbiguousRobotError(f"robots {', '.join(robots)} answer at {', '.join(connect)}: give --robot ID, one of them{every}")
    return robots[0] if robots else None


def robots_answering(connect: list[str], zenoh_config_file: str | None = None, timeout_s: float = 0.6) -> list[str]:
    """The ids of the robots whose services or launcher answer at ``connect``, sorted ([] when none, or no router)."""
    try:
        session = _client_session(connect, zenoh_config_file)
    except TransportError:  # a malformed endpoint or config: the command's own session says so
        return []
    if session is None:
        return []
    keys = RobotKeys(WILDCARD)
    with session:
        replies = [*session.liveliness().get(keys.alive(WILDCARD), timeout=timeout_s), *session.get(keys.launcher_status, timeout=timeout_s)]
        robots = set()
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                robots.add(robot_of(str(reply.ok.key_expr)))
            except KeyExprError:  # not a robot's key
                continue
    return sorted(robots)


def waiting_note(waiting: list[str], pause: dict[str, Any] | None = None) -> str:
    """What the state adds while the episode waits for services that this run did not start and no process serves
    (``status_of``'s ``waiting_for``; "" when none), or for the operator (``status_of``'s ``pause``: ``; paused (by X,
    for N s)``): ``status`` and ``up``'s live view say it alike."""
    return (f"; waiting for {', '.join(waiting)}, which no process serves" if waiting else "") + pause_note(pause)


def pose_words(pose_m: list[float] | None, twist: list[float] | None) -> str:
    """The robot's pose in the map frame and its speed as ``status`` and the live view say them:
    ``x 1.23 m  y -0.40 m  yaw 0.52 rad, 0.25 m/s 0.10 rad/s`` (``-``: no odometry yet)."""
    if pose_m is None:
        return "-"
    speed = "" if twist is None else f", {twist[0]:.2f} m/s {twist[1]:.2f} rad/s"
    return f"x {pose_m[0]:.2f} m  y {pose_m[1]:.2f} m  yaw {pose_m[2]:.2f} rad{speed}"


def presence_words(name: str, service: dict[str, Any], waiting: list[str], stopping: bool = False, episode_over: str = "") -> list[str]:
    """How a service's row begins (an entry of ``status_of``'s ``services``): alive (its token is there, or it answered
    its status query), starting (its process runs, its session is not up yet), not answering (its process runs, it came
    up, and its token is gone since: stopped or hung) or DOWN, not started by this run (another process is to serve it), and whether the episode
    waits for it; ``status`` and the live view alike.
    ``stopping``: the launcher is stopping the run, and a service gone is one it stopped ("stopping", not DOWN).
    ``episode_over``: the state of an episode that has ended (done, failed), else "": a service the episode waited for
    that this run did not start (a shared policy server) and that no longer answers for the robot is not needed any
    more, so it reads idle, not DOWN (a server restarted after the episode only announces the robots it hears from)."""
    running = service.get("command") and service.get("process_alive")  # a command node needs no liveliness token
    gone = "stopping" if stopping else "DOWN"
    if not stopping and service.get("process_alive") and not service.get("gave_up"):
        # its process runs: its session not up yet (as the live view says it), or up once and its token gone since
        gone = NOT_ANSWERING if service.get("not_answering") else "starting"
    if episode_over and service.get("outside") and service.get("awaited"):
        gone = f"idle (episode {episode_over}: not needed after it)"
    # One that answered its status query has its session up, before its token is seen: alive, not "starting, running".
    words = ["alive" if service["alive"] or service.get("state") else "running" if running else gone]
    if service.get("outside"):
        words.append("not started by this run")
    if name in waiting:
        words.append("the episode waits for it")
    return words


def lost_result_words(lost: dict[str, Any], referee: str | None) -> str:
    """What ``status`` says of an episode whose result was lost to a restart of the referee (an entry of
    ``launcher_status``'s ``lost_results``; ``referee``: its ``referee``): ``episode 00000000002a ended (done at
    step 31), but its result was lost: the sim restarted before it came; the run went on with episode 000000000008``."""
    return (
        f"episode {lost['episode']:012x} ended ({lost['state']} at step {lost['step']}), but its result was lost: {lost_how(referee)} before it came; "
        f"the run went on with episode {lost['running']:012x}"
    )


def lost_how(referee: str | None) -> str:
    """How an episode's result was lost, by the run's ``referee`` (``run_profile.referee_kind``): a ROS 2 bridge
    starts a new episode in the process that ran the old one."""
    return "the sim restarted" if referee == "sim" else "the referee started a new episode"


def lost_results_short(lost: list[dict[str, Any]], referee: str | None) -> str:
    """``runs``' words for the episodes whose result was lost (run.json's ``lost_results``; ``lost_result_words`` says
    each at length): ``result of episode 00000000002a lost: the sim restarted before it came``."""
    episodes = ", ".join(f"{e['episode']:012x}" for e in lost)
    return f"result of episode{'s' if len(lost) > 1 else ''} {episodes} lost: {lost_how(referee)} before {'they' if len(lost) > 1 else 'it'} came"


def after_end_words(status: dict[str, Any]) -> str:
    """What the step row adds on a real robot whose episode has ended (``ended_at_step``, from its results): the
    steps shown are the robot's scans since, not the episode's."""
    ended = status.get("ended_at_step")
    if ended is None or ended == status["step"]:
        return ""
    return f" (scans; the episode ended at step {ended})"


def render_table(status: dict[str, Any]) -> Table:
    """``status``'s table on a terminal: one row per field of the episode, then one per service and the launcher."""
    from rich.markup import escape  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from cso_runtime.live_view import no_ground_truth_words  # noqa: PLC0415 - rich's, as above
    from cso_runtime.run_profile import measures_coverage  # noqa: PLC0415 - a status has a profile's services

    # Every cell is text, not markup: a scene file or a service's reason may hold brackets.
    t = Table(title=escape(f"robot {status['robot']}  run {status['run_id'] or '-'}"))
    t.add_column("field")
    t.add_column("value", overflow="fold")  # a narrow terminal wraps a long URL or path, never cuts it with an ellipsis
    goal = status["goal"]
    waiting = status.get("waiting_for") or []
    waits = waiting_note(waiting, None if status["state"] in EPISODE_OVER else status.get("pause"))
    pace = "" if status.get("real_time_factor") is None else f" ({real_time_words(status['real_time_factor'])})"
    steps = status["step"] if status.get("ended_at_step") is None else status["ended_at_step"]  # the episode's, not the scans since
    for k, v in (
        ("state", status["state"] + (f" ({status['terminated_by']})" if status["terminated_by"] else "") + (f": {status['reason']}" if status["reason"] else "") + waits),
        ("scene / method", f"{status['scene']} / {status['method']}" if status["scene"] or status["method"] else "-"),  # none before the sim's first status
        ("step", f"{status['step']}{pace}" + after_end_words(status)),  # as up's live view says the sim's pace
        ("episode id", f"{status['episode']:012x}" if status["episode"] else "-"),  # 48 random bits (JSON: the integer); a new id is a new episode
        ("coverage", f"{status['coverage_pct']:.2f} %" if measures_coverage(status, status.get("coverage_measured")) else no_ground_truth_words(status.get("referee"))),
        ("explored", f"{status['explored_area_m2']:.2f} m2" + (f", {status['explored_area_m2'] / steps:.3f} m2/step" if steps else "")),
        ("path length", f"{status['path_length_m']:.2f} m"),
        ("goal", "-" if goal is None else f"({goal[0]:.2f}, {goal[1]:.2f}) m"),
        ("pose", pose_words(status.get("pose"), status.get("twist"))),  # .get: a status from before the pose
        ("decisions", f"{status['decisions']} (last {status['last_decision_ms']:.1f} ms)"),
    ):
        t.add_row(k, escape(v))
    episode_over = status["state"] in EPISODE_OVER
    stopping = status.get("launcher_state") == "stopping"
    for name, s in status["services"].items():
        bits = presence_words(name, s, waiting, stopping, status["state"] if episode_over else "")
        if s.get("state") == "stale" and episode_over:
            # Inputs stop when the episode ends; "stale" would read like a fault (JSON keeps the raw state).
            bits.append(f"idle (episode {status['state']}; last step {s.get('last_step', 0)})")
        elif s.get("state"):
            bits.append(s["state"] + (f" ({s['reason']})" if s.get("reason") else ""))
        elif s.get("command"):  # an executable of one's own speaks no status protocol
            bits.append(f"pid {s.get('pid')}, {COMMAND_NODE_NOTE}")
        elif s["alive"] and not stopping and not s.get("outside"):  # its token, no answer: stopped, or its loop stuck in a handler
            bits.append("not answering its status query (hung?)")
        if s.get("restarts"):
            hung = f", {s['hung_kills']} of them hung" if s.get("hung_kills") else ""
            bits.append(f"restarts {s['restarts']}{hung}" + (" (gave up)" if s.get("gave_up") else ""))
        if s.get("robot_stops"):  # it died unasked and the launcher sent the zero Twist it could not
            bits.append(f"the launcher stopped the robot {s['robot_stops']} times after it died")
        rejected = sum((s.get("rejected") or {}).values())
        if rejected:
            bits.append(f"rejected {rejected}")
        t.add_row(escape(f"service {name}"), escape(", ".join(bits)))
        counts = [f"{k} {v}" for k, v in sorted((s.get("counters") or {}).items()) if v]
        if counts:  # the service's own counts (the ROS 2 bridge's: received, sent, dropped, watchdog stops), non-zero ones
            t.add_row(escape(f"  {name} counts"), escape(", ".join(counts)))
    rejected = sum(status.get("launcher_rejected", {}).values())
    errors = sum(status.get("launcher_handler_errors", {}).values())
    launcher_bits = ([f"rejected {rejected}"] if rejected else []) + ([f"{errors} callback errors (see its log)"] if errors else [])
    if status.get("lost_router"):  # the run's own router answers; the robot's, which it joined, does not
        launcher_bits.insert(0, f"LOST the router at {status['lost_router']} (is the robot or its zenoh bridge down?)")
    if status.get("run_dir_lost"):  # its folder deleted mid-run: made again, the logs still written copied back
        launcher_bits.append(f"its run folder was deleted {status['run_dir_lost']} time(s) while it ran: made again (see launcher.log)")
    launcher_bits += [lost_result_words(lost, status.get("referee")) for lost in status.get("lost_results") or []]
    if stopping:
        launcher_bits.insert(0, "stopping the run's services")
    if launcher_bits:
        t.add_row("launcher", escape(", ".join(launcher_bits)))
    return t


RUN_END_WAIT_S = 5.0
"""How long ``status --watch`` waits, once the run it watched stops answering while its launcher lives, for the
launcher to write that the run stopped: it stops answering just before it writes ``run.json`` a last time."""


def run_dir_of(info: dict[str, Any] | None, robot: str) -> Path | None:
    """The folder of the current run (its run file ``info``'s ``run_dir``, as ``read_current_run`` read it) where that
    run is ``robot``'s; None when there is none, or it is another robot's (``--robot r1`` through r0's router: r1's run
    and folder are another's)."""
    return Path(info["run_dir"]) if info is not None and info.get("run_dir") and info.get("robot") == robot else None


def watched_run_dir(status: dict[str, Any], runs_dir: Path) -> Path | None:
    """The folder of the run that answered ``status``: the current run file's, when that file names the same run."""
    from cso_runtime.current_run import read_current_run  # noqa: PLC0415

    info = read_current_run(runs_dir)
    if info is None or not status.get("run_id") or info.get("run_id") != status["run_id"] or not info.get("run_dir"):
        return None
    return Path(info["run_dir"])


def stopped_run(run_dir: Path, wait_s: float = RUN_END_WAIT_S) -> dict[str, Any] | None:
    """The ``run.json`` of a watched run that no longer answers, once it says the run stopped (with its ``outcome``
    and ``exit_code``); None when it does not, at once when its launcher is gone, else after ``wait_s``."""
    from cso_runtime.current_run import current_launcher_alive  # noqa: PLC0415
    from cso_runtime.runs import read_json_object  # noqa: PLC0415

    deadline_s = time.monotonic() + wait_s
    while True:
        info = read_json_object(run_dir / "run.json")
        if info is None:
            return None
        if info.get("state") == "stopped":
            return info
        if not current_launcher_alive(info) or time.monotonic() >= deadline_s:
            return None
        time.sleep(0.05)


def run_end_exit_code(run: dict[str, Any]) -> int:
    """``status --watch``'s exit code for a run it watched end: 0 when it ended done, else ``up``'s own exit code
    (130 interrupted, 1 or more failed; 1 for a failed run that recorded none)."""
    if run.get("outcome") == "done":
        return 0
    code = run.get("exit_code")
    return code if isinstance(code, int) and not isinstance(code, bool) and code > 0 else 1


def result_steps(run_dir: Path, episode: Any = None) -> int | None:
    """The steps of the run's episode as its results say them (``summary.json``), None before they are written, or
    when they are of another episode than ``episode`` (their ``meta.episode``; None: any): a run writes its first
    episode's results only, and a robot whose driver restarted after that end goes on in a new episode."""
    from cso_runtime.report import whole_count  # noqa: PLC0415
    from cso_runtime.runs import read_json_object  # noqa: PLC0415

    summary = read_json_object(run_dir / "summary.json") or {}
    meta = summary.get("meta")
    written = meta.get("episode") if isinstance(meta, dict) else None  # none in an older version's
    if episode is not None and written is not None and written != episode:
        return None
    methods = summary.get("methods")
    if isinstance(methods, dict) and len(methods) == 1 and isinstance(row := next(iter(methods.values())), dict):
        steps = whole_count(row.get("steps"))
        if isinstance(steps, int) and not isinstance(steps, bool):
            return steps
    return None


def episode_end_step(run_dir: Path, last: dict[str, Any]) -> Any:
    """The step the watched run's episode ended at: its result's (``summary.json``'s steps), else the last status's. On
    a real robot the two differ: the ROS 2 bridge's steps go on counting the robot's scans after the end (``status``
    shows them), while the result, the bridge's log and ``episodes.csv`` say the episode's own."""
    steps = result_steps(run_dir, last.get("episode"))
    return last.get("step", 0) if steps is None else steps


def robot_ended_at(last: dict[str, Any]) -> str:
    """Where the robot was last seen, for the line ``status --watch`` ends with: ``, the robot at x 1.75 m  y 2.25 m  yaw
    0.25 rad (map frame)`` (``pose_words`` of ``last``'s ``pose``, ``status_of``'s in the map frame: the launcher's
    last-heard one of the episode's last step, else the watch's last); "" when no pose was heard."""
    pose = last.get("pose")
    return "" if pose is None else f", the robot at {pose_words(pose, None)} (map frame)"


def say_run_ended(run: dict[str, Any], run_dir: Path, last: dict[str, Any], as_json: bool) -> int:
    """The line ``status --watch`` ends with when the run it watched stopped: how it ended (its ``outcome``, the
    episode's end and ``terminated_by`` as last seen) and where its results are; ``run_end_exit_code``."""
    from cso_runtime.outputs import results_said  # noqa: PLC0415
    from cso_runtime.runs import LOG_DIR  # noqa: PLC0415

    outcome = str(run.get("outcome") or "failed")
    code = run_end_exit_code(run)
    over = last.get("state") in EPISODE_OVER
    ended_by = last.get("terminated_by") or ""
    step = episode_end_step(run_dir, last) if over else last.get("step", 0)
    episode = f"its episode {last.get('state')}" + (f" ({ended_by})" if ended_by else "") + f" at step {step}"
    where = results_said(run_dir) if outcome == "done" else f"its folder: {run_dir}/ (the logs in {run_dir / LOG_DIR}/)"
    if outcome != "done":
        from cso_runtime.launcher import LAST_MAP  # noqa: PLC0415 - only for this line

        if (run_dir / LAST_MAP).is_file():  # a run stopped before its episode ended: its one result, as `up` says it
            where += f"; the episode's map so far: {run_dir / LAST_MAP}"
    line = (f"run {run.get('run_id')} ended: {outcome}" + (f", {episode}" if over else "") + robot_ended_at(last) + (f", exit code {code}" if code else "")
            + f"; {where}")
    if as_json:
        ended = {"run_id": run.get("run_id"), "run_dir": str(run_dir), "outcome": outcome, "exit_code": code, "pose": last.get("pose")}
        episode_end = {"episode_state": last.get("state"), "terminated_by": ended_by, "step": step} if over else {}
        print_json({"state": NOT_RUNNING, "reason": f"nothing running ({line})", **ended, **episode_end})
    else:
        print(line)
    return code


def detached_run_after_episode(run_dir: Path) -> dict[str, Any] | None:
    """The ``run.json`` of a detached run whose episode has ended and whose results are written (state ``done`` or
    ``failed``, its launcher alive): it stays up, answering ``status``, until ``down``, so ``status --watch`` ends
    there, as ``logs -f`` does. None otherwise (a foreground run, in that state only while it stops, included)."""
    from cso_runtime.current_run import current_launcher_alive  # noqa: PLC0415
    from cso_runtime.runs import read_json_object  # noqa: PLC0415

    info = read_json_object(run_dir / "run.json")
    if info is None or not info.get("detached") or info.get("state") not in EPISODE_OVER:
        return None
    return info if current_launcher_alive(info) else None


def say_episode_ended(run: dict[str, Any], run_dir: Path, runs_dir: Path, last: dict[str, Any], as_json: bool) -> int:
    """The line ``status --watch`` ends with on a detached run (the current run of ``runs_dir``) whose episode ended:
    how, where its results are, and that the run stays up until ``down``; exit 0 when the episode ended done, else 1."""
    from cso_runtime.current_run import down_command  # noqa: PLC0415
    from cso_runtime.outputs import results_said  # noqa: PLC0415
    from cso_runtime.runs import LOG_DIR  # noqa: PLC0415

    state = str(run.get("state"))
    code = 0 if state == "done" else 1
    ended_by = last.get("terminated_by") or ""
    step = episode_end_step(run_dir, last)
    where = results_said(run_dir) if state == "done" else f"its folder: {run_dir}/ (the logs in {run_dir / LOG_DIR}/)"
    line = (f"run {run.get('run_id')}'s episode has ended: {state}" + (f" ({ended_by})" if ended_by else "") + f" at step {step}"
            f"{robot_ended_at(last)}; {where}; the run stays up (for status) until {down_command(runs_dir)}")
    if as_json:
        ended = {"run_id": run.get("run_id"), "run_dir": str(run_dir), "exit_code": code, "terminated_by": ended_by, "step": step,
                 "pose": last.get("pose")}
        print_json({"state": state, "reason": line, **ended})
    else:
        print(line)
    return code


def await_started_run(runs_dir: Path, as_json: bool, period_s: float) -> int | None:
    """``status --watch`` on a run that is starting (``up`` writes its run file before its router opens): wait for it
    to come up, saying so (once on a terminal or in a file; ``--json``: a ``starting`` line each period). None once
    there is no starting run (its router open: watch it), else the exit code after saying how the wait ended: its
    launcher died (exit 1, as ``status`` says it), or its start failed (how it ended, ``run_end_exit_code``)."""
    from cso_runtime.current_run import ASK_AGAIN, current_launcher_alive, read_current_run, starting_run, starting_up_line  # noqa: PLC0415

    said = ""
    seen: dict[str, Any] | None = None  # the starting run's file, as last read
    while True:
        info = read_current_run(runs_dir)
        starting = starting_run(info)
        # An `up` still checking its profile: no run file of its own yet (one there is a launcher's gone, killed).
        if starting is None and (info is None or not current_launcher_alive(info)) and seen is None:
            starting = starting_up_line(runs_dir)
            if starting is not None:
                line = f"{starting.removesuffix(ASK_AGAIN)}; waiting for it..."
                if as_json:
                    print_json({"state": "starting", "run_id": "", "reason": line})
                elif line != said:
                    print(line, flush=True)
                said = line
                time.sleep(period_s)
                continue
        if starting is None:
            if seen is None or not seen.get("run_dir") or (info is not None and (info.get("run_id") != seen["run_id"] or info.get("state") != "stopped")):
                return None  # up (or never starting, or another run, or its launcher gone): status says what there is
            # A start that failed (refused, no router) or was interrupted: its run.json says so, then its run file goes.
            run_dir = Path(seen["run_dir"])
            run = info if info is not None else stopped_run(run_dir, wait_s=0.0)
            return None if run is None else say_run_ended(run, run_dir, {}, as_json)
        seen = info
        assert info is not None
        why = stopped_launcher_of_run(info, runs_dir)  # Ctrl-Z on a starting `up`: it waits, and says why
        line = f"{starting.removesuffix(ASK_AGAIN)}; waiting for it" + (f" ({why})" if why else "") + "..."
        if as_json:
            print_json({"state": "starting", "run_id": info["run_id"], "reason": line})
        elif line != said:
            print(line, flush=True)
        said = line
        time.sleep(period_s)


def status_main(connect: list[str], robot: str | None, as_json: bool, watch: bool, runs_dir: Path, period_s: float = 1.0, console: Console | None = None) -> int:
    """The ``status`` command; exit code 1 when nothing answers. ``--watch`` on a terminal redraws one table in
    place (as ``up``'s live view does); in a file or a pipe, and with ``--json``, each status follows the last.
    ``console``: rich's console on stdout when None."""
    from rich.live import Live  # noqa: PLC0415

    from cso_runtime.live_view import console_that_survives_its_reader, fit_off_a_terminal, redraws_in_place  # noqa: PLC0415
    from cso_runtime.run_profile import runs_a_real_robot  # noqa: PLC0415 - a status has a profile's services

    console = console if console is not None else console_that_survives_its_reader()  # `status --watch | head`: ends
    given_connect = bool(connect)
    if watch and not given_connect:
        try:
            ended = await_started_run(runs_dir, as_json, period_s)
        except KeyboardInterrupt:
            return 0
        if ended is not None:
            return ended
    target = reachable_target(connect, robot, runs_dir, as_json)
    if isinstance(target, int):
        return target
    connect, robot, zenoh_config_file = target
    assert robot is not None  # reachable_target always names the robot
    # A new table a period scrolled the terminal: ~20 lines a second, each as wide as its longest cell. A terminal is the
    # output's own isatty() (FORCE_COLOR=1 in CI makes rich's is_terminal true for a file: its redraws went there).
    in_place = watch and not as_json and redraws_in_place(console)
    live: Live | None = None
    next_s = time.monotonic()
    watched: tuple[Path, dict[str, Any]] | None = None  # the run that answered (its folder) and its last fresh status
    last: dict[str, Any] = {}
    try:
        while True:
            status = query_status(connect, robot, zenoh_config_file=zenoh_config_file)
            if status is None:
                if live is not None:
                    live.stop()  # the last table stays; the line below goes under it
                # A run seen answering that stopped since: how it ended and where its results are, not "nothing running".
                if watched is not None and (run := stopped_run(watched[0])) is not None:
                    return say_run_ended(run, watched[0], last, as_json)
                from cso_runtime.current_run import read_current_run  # noqa: PLC0415

                info = None if given_connect else read_current_run(runs_dir)
                why = dead_launcher_of_run(info, runs_dir) or stopped_launcher_of_run(info, runs_dir) or lost_router_of_run(info)
                return say_nothing_running(f"no answer for robot {robot} at {', '.join(connect)}" + (f"; {why}" if why else ""), as_json)
            if status["state"] in EPISODE_OVER and runs_a_real_robot(status) and (ended_in := watched_run_dir(status, runs_dir)) is not None:
                # The bridge's steps go on with the robot's scans after the end: the step the episode ended at beside them.
                status["ended_at_step"] = result_steps(ended_in, status.get("episode"))
            shown, last = status, status
            if watch:
                if watched is None and (run_dir := watched_run_dir(status, runs_dir)) is not None:
                    watched = (run_dir, status)
                if watched is not None and status.get("status_age_s") is None:
                    watched = (watched[0], status)
                elif watched is not None and watched[1].get("episode") == status.get("episode"):
                    # The sim has stopped (the run stopping): the goal and the last decision's time as last answered, and
                    # the pose too unless the launcher's last-heard status has it (newer: of the episode's last step),
                    # with the map origin it was placed by (an older launcher's last-heard status has neither). Each
                    # pose is status_of's, in the map frame, as the goal.
                    last_answer = watched[1]
                    kept = ("goal",) if status.get("pose") is not None else ("goal", "pose", "twist", "map_origin")
                    shown = {**status, **{k: last_answer.get(k) for k in kept}, "last_decision_ms": last_answer.get("last_decision_ms", 0.0)}
                    last = shown  # the end line says where the robot ended as the last table shows it
            if as_json:
                print_json(shown)  # --watch: what the table shows, and the end line's pose after it
            elif in_place and live is None:
                live = Live(render_table(shown), console=console, auto_refresh=False)
                live.start(refresh=True)
            elif live is not None:
                live.update(render_table(shown), refresh=True)
            else:
                table = render_table(shown)
                fit_off_a_terminal(console, table).print(table)  # `status > now.txt`: a long scene or reason on its line
            if not watch:
                return 0
            if watched is not None and (run := detached_run_after_episode(watched[0])) is not None:
                if live is not None:
                    live.stop()  # the last table stays; the line below goes under it
                return say_episode_ended(run, watched[0], runs_dir, last, as_json)
            # A fixed schedule: the lines come every period_s however long a query took (a slow or silent service
            # made each one up to its 0.6 s timeout later); a period that a query overran is skipped, not made up.
            next_s += period_s
            now = time.monotonic()
            if now > next_s:
                next_s += math.ceil((now - next_s) / period_s) * period_s
            time.sleep(next_s - now)
    except KeyboardInterrupt:
        return 0
    except TransportError as exc:
        if live is not None:
            live.stop()
        return say_nothing_running(str(exc), as_json)
    finally:
        if live is not None:
            live.stop()


def query_map(
    connect: list[str], robot: str = "r0", timeout_s: float = 1.0, zenoh_config_file: str | None = None, run_dir: Path | None = None
) -> tuple[MapMsg | None, str, Pose2D]:
    """The newest map the running episode keeps, or None and why not (nothing answered, no map yet, or
    only malformed replies), and the scene's pose in the user's map frame (the episode status's ``map_origin``;
    the scene's frame itself when no status answers), which the map's files are placed by. ``zenoh_config_file``:
    as ``RunTarget``'s (None: this process's). ``run_dir``: the run's folder where it is known here (None: not known,
    a run given by ``--connect``), whose final map the why of an ended episode names (``final_map_words``)."""
    session = _client_session(connect, zenoh_config_file)
    if session is None:
        return None, f"cannot reach {', '.join(connect)}", MAP_FRAME_ORIGIN
    with session:
        return newest_map(session, robot, timeout_s, run_dir)


def newest_map(session: zenoh.Session, robot: str, timeout_s: float = 1.0, run_dir: Path | None = None) -> tuple[MapMsg | None, str, Pose2D]:
    """``query_map`` on a session already open (the launcher's own, keeping an interrupted episode's map)."""
    best: MapMsg | None = None
    map_origin = MAP_FRAME_ORIGIN
    key = RobotKeys(robot).cache("map")
    said = f"nothing answered on {key}"  # the key, for those who debug
    malformed = ""
    statuses = session.get(RobotKeys(robot).episode_status, target=zenoh.QueryTarget.ALL, timeout=timeout_s)  # asked at once: all wait together
    # The mapper's own answer on its map's key, where the cache does not answer: the sim serves the cache, and a hung
    # (stopped) sim, the run most worth keeping the map of as it is stopped, left none kept.
    mapper = session.get(RobotKeys(robot).map, target=zenoh.QueryTarget.ALL, timeout=timeout_s)
    for replies, asked in ((session.get(key, target=zenoh.QueryTarget.ALL, timeout=timeout_s), key), (mapper, RobotKeys(robot).map)):
        if best is not None:  # the cache's: the mapper's is only for want of it
            break
        for reply in replies:
            if reply.ok is None:
                said = f"{asked} answered: {reply.err.payload.to_string()}" if reply.err is not None and asked == key else said
                continue
            try:
                msg = decode(reply.ok.payload.to_bytes(), MapMsg)
            except MessageError as exc:
                malformed = f"malformed map reply: {exc}"
                continue
            assert isinstance(msg, MapMsg)
            if best is None or msg.step >= best.step:
                best = msg
    episode = None
    for status in _decoded(statuses, EpisodeStatusMsg):
        map_origin, episode = status.map_origin, status
    if best is not None:
        return best, "", map_origin
    return None, malformed or no_map_yet_words(said, episode, run_dir), map_origin


NO_MAP_YET = "the run has no map yet"
"""How ``newest_map`` begins its why when no map answered (rather than malformed ones): ``save-map`` adds that a moment
later there may be one."""


def no_map_yet_words(said: str, episode: EpisodeStatusMsg | None, run_dir: Path | None = None) -> str:
    """Why there is no map to save, as a user reads it: the run's mapper has not published one yet (the episode's
    state and step, as its status answered), or no episode status answers either (its services still starting), or
    the episode is over and none will come (where its final map is, or that none was written: ``final_map_words`` of
    ``run_dir``, the run's folder where it is known here); ``said``, what the map's key answered, for those who debug."""
    if episode is None:
        return f"{NO_MAP_YET}, and no episode status answers either: its services may still be starting ({said}; `cso-runtime status` says which state it is in)"
    if episode.state in EPISODE_OVER:  # none will come: not a moment too early (a mapper restarted after the end)
        return f"no map answers, and none will come: the episode is {episode.state}, at step {episode.step}; {final_map_words(run_dir, episode)} ({said})"
    return f"{NO_MAP_YET}: its mapper has not published one (the episode is {episode.state}, at step {episode.step}; {said})"


def final_map_words(run_dir: Path | None, episode: EpisodeStatusMsg) -> str:
    """Where the final map of an ended episode is, as its run's folder ``run_dir`` holds it: its file (``maps/``), or
    that none was written and why (results without one: an episode whose mapper published no map; no results: not
    written yet, or they could not be, the run's map at its stop where it kept one) and where to read more. Of a run
    whose folder is not known here (None: given by ``--connect``, maybe another host's), where to look there. It said
    "its final map is among the run's results" of every run, of those that wrote none too."""
    from cso_runtime.launcher import LAST_MAP  # noqa: PLC0415 - the launcher's module imports this one
    from cso_runtime.outputs import episode_map_path  # noqa: PLC0415

    if run_dir is None:
        return "its final map, where the run wrote one, is in maps/ of the run's folder on the host that runs it (`cso-runtime runs` there lists it)"
    if episode.method and episode.scene:
        final: Path | None = episode_map_path(run_dir, episode.method, episode.scene)
    else:  # an older referee's status names neither: the one map of the run's results, if any
        final = next(iter(sorted((run_dir / "maps").glob("*/*.yaml"))), None)
    if final is not None and final.is_file():
        return f"its final map is {final} (its image beside it)"
    if (run_dir / "summary.json").is_file():
        missing = f"{final} is not there: " if final is not None else ""
        return f"no final map was written: the run's results in {run_dir}/ have none ({missing}an episode whose mapper published no map ends with none)"
    if (run_dir / LAST_MAP).is_file():
        return f"the run has not written its results; its map at the run's stop is {run_dir / LAST_MAP}"
    return f"no final map is written: the run has not written its results in {run_dir}/ (yet, or they could not be written: `cso-runtime logs --run {run_dir}` says which)"


def save_map_main(connect: list[str], robot: str | None, out: Path | str, image_format: str, runs_dir: Path) -> int:
    """The ``save-map`` command: the running episode's map as map_server files, in the user's map frame (a
    map_server scene's ``origin``: the files overlay its map); exit 1 when there is none."""
    from cso_runtime.current_run import read_current_run  # noqa: PLC0415
    from cso_runtime.map_files import map_yaml_path, save_map  # noqa: PLC0415

    yaml_out = map_yaml_path(out)
    # The run file read once: the run asked and the folder its "no map" names are of one run, even when it ends or
    # another starts in between (read twice, the folder could be the next run's).
    run_info = None if connect else read_current_run(runs_dir)
    target = target_of_run(connect, robot, runs_dir, run_info)
    if isinstance(target, int):
        return target
    connect, robot, zenoh_config_file = target
    assert robot is not None  # target_of_run always names the robot
    run_dir = run_dir_of(run_info, robot)  # the run asked is the current one: its folder is here (None: --connect)
    try:
        msg, why, map_origin = query_map(connect, robot, zenoh_config_file=zenoh_config_file, run_dir=run_dir)
    except TransportError as exc:
        msg, why, map_origin = None, str(exc), MAP_FRAME_ORIGIN
    if msg is None:
        retry = "; try again in a moment" if why.startswith(NO_MAP_YET) else ""
        print(f"no map for robot {robot}: {why}{retry}")
        return 1
    try:
        yaml_path = save_map(yaml_out, msg.grid, msg.geometry, image_format, map_origin=map_origin)
    except OSError as exc:
        # A folder of the path that is a file: "File exists" (mkdir) or "Not a directory" named neither which nor why.
        file_in_way = next((d for d in Path(yaml_out).parents if d.exists() and not d.is_dir()), None)
        why = f"{file_in_way} is a file, not a folder" if file_in_way is not None else exc.strerror or str(exc)
        print(f"error: cannot write the map to {yaml_out}: {why}", file=sys.stderr)
        return 2
    g = msg.geometry
    print(f"map of step {msg.step} ({g.shape[1]} x {g.shape[0]} cells at {g.resolution_m} m): {yaml_path} and {yaml_path.with_suffix('.' + image_format).name}")
    return 0


PAUSE_CONFIRM_S = 3.0
"""How long ``pause`` and ``resume`` wait for the launcher to say the robot is paused (resumed): on loopback a few ms."""


def operator_name() -> str:
    """Who pauses (``ExploreResumeMsg.by``): user@host, as ``status`` then says."""
    import getpass  # noqa: PLC0415
    import socket  # noqa: PLC0415

    try:
        user = getpass.getuser()
    except (KeyError, OSError):  # no user name for this uid (a container)
        user = str(os.getuid())
    return f"{user}@{socket.gethostname()}"


def launcher_pause(session: zenoh.Session, robot: str, timeout_s: float = 1.0) -> LauncherStatusMsg | None:
    """The launcher's status of ``robot`` (its ``pause``), or None when no launcher answers."""
    launchers = _decoded(session.get(RobotKeys(robot).launcher_status, target=zenoh.QueryTarget.ALL, timeout=timeout_s), LauncherStatusMsg)
    return launchers[-1] if launchers else None


def explore_resume_main(connect: list[str], robot: str | None, runs_dir: Path, resume: bool, reason: str = "") -> int:
    """The ``pause`` (``resume`` false) and ``resume`` commands: send ``explore/resume`` to the running run and wait for
    its launcher to say so. Exit 0 once it does (or was so already), 1 when nothing runs or it does not confirm, 2 when
    the run cannot pause (lockstep) or the arguments are bad (as ``status``)."""
    from cso_runtime.current_run import runs_command  # noqa: PLC0415

    what = "resume" if resume else "pause"
    given_connect = bool(connect)
    target = reachable_target(connect, robot, runs_dir)
    if isinstance(target, int):
        return target
    connect, robot, zenoh_config_file = target
    assert robot is not None  # reachable_target always names the robot
    # The `resume` (`status`) to come, of this run: a plain `cso-runtime resume` asks the run of ./runs (another's, or none).
    at_endpoint = " ".join(f"--connect {endpoint}" for endpoint in connect) + f" --robot {robot}"
    resume_hint = f"`cso-runtime resume {at_endpoint}`" if given_connect else runs_command("resume", runs_dir)
    status_hint = f"`cso-runtime status {at_endpoint}`" if given_connect else runs_command("status", runs_dir)
    session = _client_session(connect, zenoh_config_file)
    if session is None:
        return say_nothing_running(f"cannot reach {', '.join(connect)}", False)
    with session:
        launcher = launcher_pause(session, robot)
        if launcher is None:
            return say_nothing_running(f"no launcher of robot {robot} answers at {', '.join(connect)}", False)
        pause = launcher.pause
        if pause is None:
            print(f"error: run {launcher.run_id}'s launcher is older than `{what}` (its status says nothing of a pause)", file=sys.stderr)
            return 2
        if pause["refused"]:
            print(f"error: cannot {what} robot {robot} (run {launcher.run_id}): {pause['refused']}", file=sys.stderr)
            return 2
        if pause["paused"] != resume:
            state = "exploring" if resume else pause_note(pause).lstrip("; ")
            print(f"robot {robot} (run {launcher.run_id}) is already {state}")
            return 0
        session.put(RobotKeys(robot).explore_resume, encode(ExploreResumeMsg(resume, operator_name(), reason, time.time())))
        deadline = time.monotonic() + PAUSE_CONFIRM_S
        while time.monotonic() < deadline:
            now = launcher_pause(session, robot, timeout_s=0.5)
            if now is not None and now.pause is not None and now.pause["paused"] != resume:
                step = (now.last_episode or {}).get("step")
                at = f" at step {step}" if step is not None else ""
                ended = (now.last_episode or {}).get("state")
                if resume:
                    print(f"resumed robot {robot} (run {now.run_id}){at}, after {pause['for_s']:.0f} s paused")
                elif ended in EPISODE_OVER:  # nothing moves it any more: the pause holds for a new episode (new odometry)
                    print(f"paused robot {robot} (run {now.run_id}){at}: its episode has ended ({ended}), so it stands already; "
                          f"a new episode would start paused, until {resume_hint}")
                else:
                    print(f"paused robot {robot} (run {now.run_id}){at}: it holds still until {resume_hint}")
                return 0
            time.sleep(0.1)
    print(f"sent {what} to robot {robot}, but its launcher has not said so within {PAUSE_CONFIRM_S:g} s; see {status_hint}", file=sys.stderr)
    return 1
