"""What every service shares: arguments, the profile file, the Zenoh session, one event loop.

A service subclasses ``Service``: it names its inputs (topic -> message type), handles each decoded
message in ``on_message`` and may act periodically in ``on_tick``. ``run_service`` opens the session
(the shared transport helper, multicast scouting off), declares the status queryable and the
service's publishers, warms the service up (``warm_up``), then declares the liveliness token
``cso/<robot>/alive/<name>``, and handles inputs one at a time
(``ServiceInputs``): in real time from a queue filled by Zenoh's callback (bounded: ``INBOX_LIMIT``, the oldest
dropped and counted past it), in lockstep at once on Zenoh's network thread. Payloads that fail validation are logged and counted per key, never
crash the service. SIGINT/SIGTERM stop the loop; ``shutdown`` runs while the session is still open
(last messages, e.g. the bridge's zero Twist); the ``with`` blocks close the session. A service with
command-line options of its own declares them in ``add_arguments`` and folds them into its profile
parameters in ``apply_arguments``. A service of the user's own is a subclass too, which a profile names in
``services.<name>.class`` (docs/own-service.md).
"""

from __future__ import annotations

import argparse
import atexit
import collections
import contextlib
import cProfile
import faulthandler
import functools
import json
import logging
import os
import pstats
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, NoReturn, TypeVar

import numpy as np
import zenoh

from cso_runtime.config import (
    EXIT_BAD_CONFIG,
    EXIT_NO_ZENOH,
    LOG_FORMAT,
    ConfigError,
    ExplorationConfig,
    check_field_types,
    check_seed,
    from_dict,
    load_yaml,
)
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.keys import KeyExprError, RobotKeys, check_robot_id, is_control_key, robot_of, topic_of
from cso_runtime.messages import (
    DEFAULT_MAX_GRID_CELLS,
    CmdVelMsg,
    ExploreResumeMsg,
    Message,
    MessageError,
    ServiceStatusMsg,
    clipped,
    decode,
    encode,
    set_max_grid_cells,
)

M = TypeVar("M", bound=Message)
from cso_runtime.observation import Observation, ObservationBuilder
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.processes import (
    INCARNATION_ENV,
    PARENT_CHECK_PERIOD_S,
    PARENT_PID_ENV,
    REALTIME_HOWTO,
    dump_stacks_on_signal,
    keep_freed_memory,
    launcher_gone,
    set_from_signal_handler,
    signal_on_parent_death,
    use_realtime_priority,
)
from cso_runtime.run_profile import REALTIME_PRIORITY_BOUND, Profile, profile_exploration_config, unknown_top_level_keys
from cso_runtime.transport import STOPPED, TransportConfig, TransportError, guarded_callback, open_session

log = logging.getLogger("cso.service")

TRACE_DIR_ENV = "CSO_TRACE_DIR"
"""Environment variable: a folder where each service writes ``<name>.trace.json`` (``MessageTrace``)."""


class MessageTrace:
    """Where a step's time goes, per message: each handled input as ``["handle", topic, step, received_s,
    started_s, done_s]`` (Zenoh callback, handler start after the queue and ``decode``, handler end) and
    each publication as ``["put", topic, step, started_s, done_s, bytes]`` (``encode`` is before
    ``started_s``), on ``time.monotonic`` (one clock for every process of a machine). Events are kept in
    memory (the newest ``max_events``) and written when the service stops, so tracing adds no file I/O to
    the chain. ``benchmarks/bench_runtime.py --trace`` turns them into a per-hop breakdown."""

    def __init__(self, path: Path, max_events: int = 500_000) -> None:
        self.path = path
        self.events: collections.deque[tuple] = collections.deque(maxlen=max_events)

    def handled(self, topic: str, step: int, received_s: float, started_s: float, done_s: float) -> None:
        self.events.append(("handle", topic, step, received_s, started_s, done_s))

    def put(self, topic: str, step: int, started_s: float, done_s: float, nbytes: int) -> None:
        self.events.append(("put", topic, step, started_s, done_s, nbytes))

    def write(self) -> None:
        """Write the events (a failure is logged: tracing never stops a service)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text(json.dumps(list(self.events)))
        except OSError as exc:
            log.error("cannot write the message trace %s: %s", self.path, exc)


@dataclass(frozen=True)
class KeptPayload:
    """A message kept as the bytes it came in (``Service.keep_latest``), served as they are: the planner's state and
    plan, which ride encoded on its ``cmd_vel`` and which the referee never decodes (no cost on the lockstep chain).
    ``step`` and ``episode`` are those of the ``cmd_vel`` that carried it."""

    step: int
    episode: int
    payload: bytes


@dataclass
class ServiceContext:
    """Everything a service is started with."""

    name: str
    robot: str
    profile: dict[str, Any]
    exploration: ExplorationConfig
    transport: TransportConfig
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def keys(self) -> RobotKeys:
        return RobotKeys(self.robot)

    @property
    def lockstep(self) -> bool:
        """The profile's ``lockstep``: every service handles steps strictly in order (deterministic)."""
        return bool(self.profile.get("lockstep", False))


def load_profile_for_service(path: Path, name: str, cls: type[Service] | None = None) -> tuple[dict[str, Any], ExplorationConfig, dict[str, Any]]:
    """The profile mapping, its exploration config and this service's parameter section (without the ``class`` that
    picks a service of one's own). ``cls``: the class about to run as ``name``; a ConfigError when it is the built-in
    one and the profile runs a class of its own in its place (it would serve the robot beside the profile's)."""
    from services import SERVICE_NAMES, command_argv, own_class_spec, service_params  # noqa: PLC0415

    profile = load_yaml(path)
    check_field_types(Profile, profile, where=str(path))  # the keys it reads one by one (m_per_px, scene), as `up` converts them
    if (unknown := unknown_top_level_keys(profile)) is not None:  # `up` refuses them; a file run by hand goes on
        log.warning("%s: %s: ignored (a service started by hand reads only the keys it knows; `up` refuses the file)", path, unknown)
    services = profile.get("services") or {}
    if not isinstance(services, dict):
        raise ConfigError(f"{path}: services must be a mapping")
    # With the MuJoCo LIMO: its LiDAR mount and box body, as eval --sim mujoco (every service must agree)
    exploration = profile_exploration_config(profile.get("exploration"), services, where=f"{path}:exploration")
    params = services.get(name) or {}
    if not isinstance(params, dict):
        raise ConfigError(f"{path}: services.{name} must be a mapping")
    spec = own_class_spec(params)
    if spec is not None and cls is not None and name in SERVICE_NAMES and module_of(cls) == f"services.{name}":
        raise ConfigError(f"{path}: the profile runs {spec} as its {name}, not the built-in one: start it with `cso-runtime service {spec}`")
    argv = command_argv(params)
    if argv is not None and cls is not None and name in SERVICE_NAMES and module_of(cls) == f"services.{name}":
        raise ConfigError(f"{path}: the profile runs the command {' '.join(argv)} as its {name}, not the built-in one")
    return profile, exploration, service_params(params)


class Service:
    """Base of every service, built in or of one's own (docs/own-service.md): inputs, handlers, publishing, health."""

    name: ClassVar[str] = ""
    inputs: ClassVar[dict[str, type[Message]]] = {}
    """Topic name (see ``cso_runtime.keys.TOPICS``) -> expected message type. An instance may narrow a
    type to a view of the same schema that decodes less (the policy service does, for its method)."""
    outputs: ClassVar[dict[str, type[Message]]] = {}
    """Topic name -> the message type this service publishes there. With ``inputs`` it is the service's
    node in the dataflow (``cso-runtime dataflow``); ``publish`` refuses anything not declared here."""
    params_class: ClassVar[type | None] = None
    """A service of one's own: the dataclass of its parameters (its profile section, ``services.<name>``, less
    ``class``). ``up`` checks the section against it before anything starts, as it does the built-in services'
    (``config.from_dict``: an unknown key or a bad value is refused), and the service gets it as ``self.params``.
    None: ``ctx.params``, the section as a mapping, unchecked."""
    optional_inputs: ClassVar[tuple[str, ...]] = ()
    """Inputs the service works without (the sim's ``cmd_vel_ahead``, a speed-up): ``up`` warns of any other input that no
    service of the run publishes (``services.dataflow.unfed_inputs``)."""
    tick_period_s: ClassVar[float] = 0.2
    serves_latest: ClassVar[tuple[str, ...]] = ()
    """Topics whose latest accepted message (``keep_latest``) this service answers on
    ``cso/<robot>/cache/<topic>``. The referee keeps the map a restarted mapper resumes from: it receives
    every map anyway, so no other process has to be woken for each one."""

    params: Any
    """The service's parameters: a ``params_class`` instance when it declares one (the built-in services set their own)."""

    def __init__(self, ctx: ServiceContext) -> None:
        self.ctx = ctx
        if self.params_class is not None:
            self.params = from_dict(self.params_class, ctx.params, where=f"services.{ctx.name}")
        self.session: zenoh.Session | None = None
        self.subscribe_robot = ctx.robot
        """Robot id whose inputs are subscribed; ``*`` serves every robot on the network."""
        self.rejected: dict[str, int] = {}
        self.processed = 0
        self.rejected_by_robot: dict[str, dict[str, int]] = {}
        """The rejections of each robot's inputs (``rejected`` counts them all): a service serving several robots
        answers each one's status with its own counts."""
        self.processed_by_robot: collections.Counter[str] = collections.Counter()
        self.heard_from_s: dict[str, float] = {}
        """Robot -> when its last input came (``time.monotonic()``), accepted or rejected: when to ``forget_robot`` it."""
        self.callback_errors = 0
        """Exceptions raised in the service's Zenoh callbacks besides its inputs' (its status, cache and own queryables,
        a liveliness subscriber: ``guarded``) or in its ``extra_status``: logged, and counted as the status's
        ``callback_errors``."""
        self.cache_unanswered = 0
        """Restores at start (``restore_from_cache``) that got no answer from the referee's cache in time, the service
        started afresh: counted as the status's ``cache_unanswered`` (told apart from a cache with nothing kept)."""
        self.realtime_priority = 0
        """The SCHED_FIFO priority this process runs under (the profile's ``realtime_priority``, set once it has warmed
        up: ``use_profile_realtime_priority``); 0: the normal scheduling. The status's ``realtime_priority`` count."""
        self.step_guard = StepGuard()
        self.last_step = 0
        self._state_and_reason = ("running", "")
        """The service's state and why, one pair set at once (``set_state``): the status queryable reads it on Zenoh's
        thread while the loop sets it, and two attributes set one after the other could be read half-set."""
        self._publishers: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._inbox: queue.Queue | None = None
        self.latest: dict[str, Message | KeptPayload] = {}
        """Topic -> the message served on its ``cache`` key (``serves_latest``)."""
        self.trace: MessageTrace | None = None
        """Per-message timings, when ``CSO_TRACE_DIR`` is set (diagnostics; off by default)."""
        self.network_profile: cProfile.Profile | None = None
        """With ``CSO_PROFILE_DIR``: the profile of the handlers run on Zenoh's network thread (lockstep), which
        the main thread's profile cannot see (a profiler follows one thread)."""
        self.stop_event: threading.Event | None = None
        """The event that stops the service's loop (``run_service``'s), set once it is asked to stop."""
        self.stop_signal: int | None = None
        """The signal (SIGINT, SIGTERM) that asked the service to stop, recorded by the handler itself: the event is
        set by a thread of its own a moment later, and the signal that stops a service's process group may end
        its helper process first (``stopping``)."""

    def stopping(self) -> bool:
        """Whether the service has been asked to stop (a signal, or its stop event set): a helper process gone
        now went with the service's own stop, and a warm-up can be cut short."""
        return self.stop_signal is not None or (self.stop_event is not None and self.stop_event.is_set())

    # --- hooks -----------------------------------------------------------------------------------
    def helper_pids(self) -> list[int]:
        """The processes of its own this service runs its work in (the frontier service's layer helper): they get the
        service's scheduling (``use_profile_realtime_priority``). None by default."""
        return []

    def warm_up(self) -> None:
        """Called once the session is open, before the liveliness token says the service is up: pay
        one-off costs here (a helper process's start, a traced network, first calls of the algorithms
        on ``warm_up_observation``), not at the episode's first step. Default: nothing (the publishers
        of ``outputs`` are declared for every service)."""

    def start(self) -> None:
        """Called once the session is open (late-joiner queries, queryables)."""

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        """Handle one input: ``msg``, of the type ``inputs`` gives for ``topic``, decoded and validated (a payload that
        is not never comes here: it is logged and counted in ``rejected``), from robot ``robot`` (the service's own
        unless it subscribes to every robot), received at ``received_s`` (``time.monotonic()``). One at a time; an
        exception stops the service."""
        raise NotImplementedError

    def on_tick(self, now_s: float) -> None:
        """Called at least every ``tick_period_s`` (staleness checks, real-time stepping)."""

    def extra_status(self) -> dict[str, int]:
        """The service's own counts by name, sent as ``counters`` in its status (``status`` shows them under
        the service). Called from the status queryable's thread: take the service's own lock. Default: none."""
        return {}

    def shutdown(self) -> None:
        """Called once when the loop has stopped, before the session closes: the last chance to publish."""

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Declare this service's own command-line options (beyond ``--config``, ``--robot``...)."""

    @classmethod
    def apply_arguments(cls, args: argparse.Namespace, params: dict[str, Any]) -> dict[str, Any]:
        """This service's profile parameters with its own command-line options applied (they win)."""
        return params

    # --- helpers ---------------------------------------------------------------------------------
    def publish(self, topic: str, msg: Message | bytes, robot: str | None = None) -> None:
        """Send ``msg`` on ``topic``, one of ``outputs``: a message of the runtime's, encoded; bytes as they are, on a
        topic of one's own (``ext/<name>``, declared as ``bytes``)."""
        key = RobotKeys(robot or self.ctx.robot).topic(topic)
        pub = self._publishers.get(key)
        if pub is None:
            self.check_output(topic, msg)
            pub = self.declare_publisher(key)
        payload = msg if isinstance(msg, bytes) else encode(msg)
        t0 = time.monotonic()
        pub.put(payload)
        if self.trace is not None:
            self.trace.put(topic, getattr(msg, "step", -1), t0, time.monotonic(), len(payload))

    def declare_publisher(self, key: str) -> Any:
        """The publisher of ``key`` (declared once; ``run_service`` declares the service's own robot's
        outputs before the service says it is up)."""
        pub = self._publishers.get(key)
        if pub is None:
            assert self.session is not None
            pub = self._publishers[key] = self.session.declare_publisher(key)
        return pub

    def keep_latest(self, topic: str, msg: Message | KeptPayload) -> None:
        """Serve ``msg`` on ``cache/<topic>`` from now on, unless a later step of its episode is already
        kept (a late message never replaces a newer one; a new episode's first message does)."""
        old = self.latest.get(topic)
        if old is None or getattr(old, "episode", 0) != getattr(msg, "episode", 0) or getattr(msg, "step", 0) >= getattr(old, "step", 0):
            self.latest[topic] = msg

    def keep_carried(self, cmd: CmdVelMsg, own_episode: int) -> None:
        """Keep the planner's state and plan that ``cmd`` carries, as they came (served on ``cache/planner/state`` and
        ``cache/planner/plan``, never decoded here), unless ``cmd`` is of another episode than ``own_episode`` (the
        referee's: rejected and counted under ``planner_state``). A plan is kept until a newer one comes."""
        if (cmd.planner_state is None and cmd.planner_plan is None) or self.of_another_episode("planner_state", cmd, own_episode):
            return
        for topic, payload in (("planner_state", cmd.planner_state), ("planner_plan", cmd.planner_plan)):
            if payload is not None:
                self.keep_latest(topic, KeptPayload(cmd.step, cmd.episode, payload))

    def kept(self, topic: str, cls: type[M]) -> M | None:
        """The message kept for ``topic`` (``keep_latest``) when it is a ``cls``; None otherwise: typed for its reader."""
        msg = self.latest.get(topic)
        return msg if isinstance(msg, cls) else None

    def answer_cache_query(self, topic: str, query: zenoh.Query) -> None:
        """The kept message, or an error reply when there is none yet (an answer all the same: the
        asker need not wait for one, ``query_latest``)."""
        msg = self.latest.get(topic)
        if msg is not None:
            query.reply(self.ctx.keys.cache(topic), msg.payload if isinstance(msg, KeptPayload) else encode(msg))
        else:
            query.reply_err(f"no {topic} yet".encode())

    def forget_robot(self, robot: str) -> None:
        """Drop what this service keeps of ``robot``, another robot than its own: its counts, its steps, when it was last
        heard, the publishers of its keys. A service serving every robot forgets those gone, so that it does not grow
        with every robot a long deployment sees; one that comes back is counted and step-checked afresh."""
        with self._lock:
            self.rejected_by_robot.pop(robot, None)
        self.processed_by_robot.pop(robot, None)
        self.heard_from_s.pop(robot, None)
        self.step_guard.forget(robot)
        prefix = RobotKeys(robot).prefix + "/"
        for key in [k for k in self._publishers if k.startswith(prefix)]:
            self._publishers.pop(key).undeclare()

    def check_output(self, topic: str, msg: Message | bytes) -> Message | bytes:
        """``msg`` itself when ``outputs`` declares it on ``topic``; a TypeError (a bug, not bad input) otherwise."""
        declared = self.outputs.get(topic)
        if declared is None or not isinstance(msg, declared):
            raise TypeError(f"{self.name} publishes {type(msg).__name__} on {topic!r}, which its outputs do not declare ({', '.join(self.outputs) or 'none'})")
        return msg

    def backlog(self) -> int:
        """Inputs received but not handled yet. In real time a service whose work is slower than its
        input rate skips work while newer inputs wait (it acts on the newest), so it never falls
        behind without bound."""
        return self._inbox.qsize() if self._inbox is not None else 0

    def reject(self, topic: str, why: str, robot: str | None = None, count: int = 1) -> None:
        """Count (and log, the first few and every hundredth) a rejected input of ``robot`` (None: of no robot the key
        names) on ``topic``; ``count`` of them dropped at once (``keep_newest_within``), logged in one line."""
        with self._lock:
            before = self.rejected.get(topic, 0)
            n = self.rejected[topic] = before + count
            if robot is not None:
                own = self.rejected_by_robot.setdefault(robot, {})
                own[topic] = own.get(topic, 0) + count
        if before < 5 or before // 100 != n // 100:  # one by one: n <= 5 or n % 100 == 0
            log.warning("%s: rejected payload on %s (%d so far): %s", self.name, topic, n, why)

    def keep_newest_within(
        self, topic: str, pending: dict[int, Any], n: int, item_bytes: int | None, waiting_for: str, robot: str | None = None
    ) -> None:
        """Real time: ``keep_newest`` of ``pending`` (inputs on ``topic`` waiting for ``waiting_for``) at most ``n`` steps,
        and of a large input (``item_bytes``: what each step holds, the newest's; None for a small one: no byte budget)
        at most ``PENDING_MAX_BYTES`` of them (``steps_kept``). The steps dropped are counted and logged as rejections of
        ``topic`` (``reject``: one call, one log line at most, per trim). O(1) but for a trim."""
        kept = n if item_bytes is None else steps_kept(item_bytes, n)
        dropped = keep_newest(pending, kept)
        if not dropped:
            return
        bound = f"at most {n}"
        if item_bytes is not None:
            bound += f", and {PENDING_MAX_BYTES >> 20} MiB: {item_bytes / 2**20:.1f} MiB each"
        steps = f"step {dropped[0]}" if len(dropped) == 1 else f"{len(dropped)} steps ({dropped[0]} to {dropped[-1]})"
        why = f"{topic} of {steps} dropped unused: {waiting_for} did not come while {kept} newer ones waited ({bound})"
        self.reject(topic, why, robot, len(dropped))

    def of_another_episode(self, topic: str, msg: Message, own_episode: int) -> bool:
        """Whether ``msg`` belongs to an episode other than ``own_episode`` (a referee's: the sim's, the ROS bridge's)
        and is rejected, counted: still in flight from before a restart. Id 0, a publisher without ids, is taken."""
        episode = getattr(msg, "episode", 0)
        if episode in (0, own_episode):
            return False
        self.reject(topic, f"{topic} of episode {episode}, not of this one ({own_episode}): still in flight from before a restart")
        return True

    @property
    def state(self) -> str:
        """``running`` or ``stale`` (``set_state``)."""
        return self._state_and_reason[0]

    @property
    def reason(self) -> str:
        """Why the service is in its ``state`` ("" when nothing to say)."""
        return self._state_and_reason[1]

    def set_state(self, state: str, reason: str = "", quiet: bool = False) -> None:
        """Set the state and its reason as one pair (one store): a status read meanwhile shows the old pair or the
        new one, never a new state with the old reason. A change is logged unless ``quiet`` (a reason that only
        brings a figure up to date)."""
        if not quiet and (state, reason) != self._state_and_reason:
            log.info("%s: %s%s", self.name, state, f" ({reason})" if reason else "")
        self._state_and_reason = (state, reason)

    def guarded(self, callback: Callable[..., None]) -> Callable[..., None]:
        """``callback`` for Zenoh, beside the inputs' (a queryable, a subscriber of one's own, a liveliness subscriber),
        or for another library's thread (the Foxglove server's listener): an exception in it reached only that library's
        own log line, in no count, and a status queryable that raised left the service unanswering, killed and restarted
        by its launcher as hung. Here it is logged with its traceback (the first few) and counted (``callback_errors``,
        in the status's counters), a query it was answering gets an error reply at once (``transport.guarded_callback``);
        the service goes on."""
        return guarded_callback(callback, self.callback_failed)

    def callback_failed(self, name: str) -> None:
        """Count (and log with its traceback, the first few and every hundredth) an exception raised in ``name``."""
        with self._lock:
            self.callback_errors += 1
            n = self.callback_errors
        if n <= 5 or n % 100 == 0:
            log.exception("%s: %s raised (%d callback errors so far); the service goes on", self.name, name, n)

    def status_msg(self) -> ServiceStatusMsg:
        try:
            own = self.extra_status()
        except Exception:  # noqa: BLE001 - a service of one's own's counts: its status goes out without them, the error counted
            self.callback_failed("extra_status")
            own = {}
        with self._lock:
            rejected = dict(self.rejected)
            errors = self.callback_errors
            unanswered = self.cache_unanswered
        # Counts only (what the schema carries): anything else would make the whole status undecodable.
        counters = {str(k): v for k, v in own.items() if isinstance(v, int) and not isinstance(v, bool) and v >= 0}
        if errors:
            counters["callback_errors"] = errors
        if unanswered:
            counters["cache_unanswered"] = unanswered
        if self.realtime_priority:
            counters["realtime_priority"] = self.realtime_priority
        state, reason = self._state_and_reason  # read once: the pair set together
        # Clipped to what the schema takes: a longer reason (a policy server's, naming each of its stale robots) made the
        # whole status undecodable, and `status` showed the service as not answering.
        return ServiceStatusMsg(self.name, self.ctx.robot, state, self.last_step, clipped(reason), rejected, self.processed, counters)

    def query_latest(self, key: str, expected: type[Message], timeout_s: float = 1.0, retry_period_s: float = 0.05) -> Message | None:
        """The newest valid reply to ``key`` (by ``step``), for late joiners and restarts (``query_answered``)."""
        return self.query_answered(key, expected, timeout_s, retry_period_s)[0]

    def restore_from_cache(self, name: str, expected: type[M], timeout_s: float) -> M | None:
        """What the referee keeps of ``name`` (its ``cache`` key) for this service restarted, waiting at most ``timeout_s``
        for the answer. Each outcome but the restore (the caller says what it restored) is said in the log: the cache had
        nothing (a first start, or nothing kept yet in this episode), or no answer in time (a loaded host, links not yet up:
        the service starts afresh all the same, counted as ``cache_unanswered``)."""
        key = self.ctx.keys.cache(name)
        msg, answered = self.query_answered(key, expected, timeout_s)
        if not answered:
            with self._lock:
                self.cache_unanswered += 1
            log.warning("%s: no answer from the cache on %s within %g s: starting afresh (nothing of it restored)", self.name, key, timeout_s)
            return None
        if not isinstance(msg, expected):
            log.info("%s: the cache had no %s for this episode: starting afresh", self.name, name)
            return None
        return msg

    def query_answered(self, key: str, expected: type[Message], timeout_s: float = 1.0, retry_period_s: float = 0.05) -> tuple[Message | None, bool]:
        """The newest valid reply to ``key`` (by ``step``), and whether any queryable answered at all (an error reply,
        "nothing yet", is an answer): (None, False) is no answer within ``timeout_s``, (None, True) an answer of nothing.

        While no queryable has answered at all, it asks again every ``retry_period_s`` until ``timeout_s``: a peer that
        has just joined reaches the other peers' queryables only once it has links to them, a moment after its session
        opens."""
        assert self.session is not None
        deadline = time.monotonic() + timeout_s
        while True:
            best: Message | None = None
            answered = False
            for reply in self.session.get(key, target=zenoh.QueryTarget.ALL, timeout=max(deadline - time.monotonic(), 0.01)):
                answered = True
                if reply.ok is None:
                    continue
                try:
                    msg = decode(reply.ok.payload.to_bytes(), expected)
                except MessageError as exc:
                    self.reject(expected.SCHEMA, f"query reply: {exc}")
                    continue
                if best is None or getattr(msg, "step", 0) >= getattr(best, "step", 0):
                    best = msg
            if answered or time.monotonic() + retry_period_s >= deadline:
                return best, answered
            time.sleep(retry_period_s)

    def pause_in_force(self) -> ExploreResumeMsg | None:
        """The operator's pause in force as this service starts (the launcher's ``cache/explore/resume``): a service
        (re)started while the robot is paused obeys it as if it had heard it. None: exploring, or lockstep (which
        ignores a pause)."""
        if self.ctx.lockstep:
            return None
        latest = self.query_latest(self.ctx.keys.cache("explore_resume"), ExploreResumeMsg)
        return latest if isinstance(latest, ExploreResumeMsg) and not latest.resume else None


def _install_stop_handlers(stop: threading.Event, service: Service | None = None) -> None:
    def handler(signum: int, _frame: Any) -> None:
        if service is not None:
            service.stop_signal = signum  # at once, on the main thread: before it can see its helper gone
        set_from_signal_handler(stop)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGHUP, handler)  # its terminal's (a service started by hand)

    def continued(signum: int, _frame: Any) -> None:
        # The kernel's on the launcher's death (``_die_with_launcher``): a stopped service is continued by it, a running
        # one only hears it. Gone: stop as on SIGTERM; not yet seen gone: the exit-once-orphaned thread looks again.
        if launcher_gone() is not None:
            handler(signal.SIGTERM, _frame)

    signal.signal(signal.SIGCONT, continued)


LOOP_STUCK_S = 5.0
"""How long one input's handler (or one tick) may run before the service stops answering its status query
(``ServiceInputs.stuck_for_s``): a loop stuck in it (a deadlock) is then hung to the launcher, which kills and
restarts it after ``supervision.hang_timeout_s`` more, while Zenoh's thread would have answered for it for good.
The slowest handlers take well under a second (a decision on a large map)."""


INBOX_LIMIT = 100_000
"""The most inputs a service keeps waiting for its loop (real time; lockstep, until it handles them on arrival), and
``INBOX_MAX_BYTES`` the most bytes of their payloads: past either the oldest data input is dropped, a rejection of its
topic (``status`` shows it), never a control (an operator's pause) while data waits (``Inbox``). Unbounded, a handler slower than its inputs come (a mapper on a large grid, a flood on one key)
grew the service's memory, and the age of what it acted on, for as long as it ran. A service keeps up with its inputs
but for bursts: ``replay --speed max`` of an hour's recording (36,000 scans of 1.5 kB) fits, and loses nothing."""

INBOX_MAX_BYTES = 256 << 20
"""The most bytes of payloads waiting for a service's loop (``INBOX_LIMIT``)."""


Item = tuple[str, bytes, float]
"""An input waiting for a service's loop: ``(key, payload, received_s)``."""


class Inbox(queue.Queue[Item]):
    """``queue.Queue`` of a service's inputs ``(key, payload, received_s)`` that keeps the bytes of their payloads
    (``nbytes``), counted under the queue's own lock as items come and go. Controls (``keys.is_control_key``: an
    operator's pause or resume) wait in a line of their own beside the data, each input numbered as it comes, so that
    ``get`` still hands every input out in the order it came while ``drop_oldest`` drops the oldest data input at the
    cost of one ``popleft``: under an overload a pause among the data was dropped as the oldest input, and the robot
    did not stop. Only an inbox of controls alone (a flood of them) drops its oldest control: the newest says the state."""

    def _init(self, maxsize: int) -> None:
        self.data: collections.deque[tuple[int, Item]] = collections.deque()
        self.controls: collections.deque[tuple[int, Item]] = collections.deque()
        self.arrivals = 0
        self.nbytes = 0

    def _qsize(self) -> int:
        return len(self.data) + len(self.controls)

    def _put(self, item: Item) -> None:
        self.nbytes += len(item[1])
        self.arrivals += 1
        (self.controls if is_control_key(item[0]) else self.data).append((self.arrivals, item))

    def _get(self) -> Item:
        data, controls = self.data, self.controls
        line = controls if controls and (not data or controls[0][0] < data[0][0]) else data
        item = line.popleft()[1]
        self.nbytes -= len(item[1])
        return item

    def drop_oldest(self) -> Item | None:
        """Take out the oldest data input (the oldest control when only controls wait); None when nothing waits."""
        with self.mutex:
            line = self.data or self.controls
            if not line:
                return None
            item = line.popleft()[1]
            self.nbytes -= len(item[1])
            return item


def topic_name(key: str) -> str:
    """The last part of a key (its topic, for a robot's): what a handler stuck on it is said to handle."""
    return key.rsplit("/", 1)[-1]


class ServiceInputs:
    """Where a service's inputs are handled, one at a time (one lock for handlers, ticks and shutdown).

    Zenoh's callback runs on Zenoh's network thread (``indirect=False``), not on a Python thread of its
    own, which saves one thread wake-up per delivery. In real time it only queues the payload: the loop's
    thread handles it and a slow handler can see its ``backlog`` and act on the newest input. In lockstep,
    once ``start`` has run (``go_direct``), the callback handles the input at once. That saves the wake-up
    of the loop's thread on every hop of the serial chain. docs/experiments/runtime-overhead.md has both measurements.
    A handler that raises stops the service, as it would on the loop's thread."""

    def __init__(self, service: Service, stop: threading.Event) -> None:
        self.service, self.stop = service, stop
        # queue.Queue, not SimpleQueue: Python 3.11's SimpleQueue.get(timeout=...) waits forever once a signal
        # handler runs past the deadline (its retry's timeout goes negative), so SIGINT and SIGTERM were lost on
        # the loop's thread now and then (tests/test_processes.py); Queue waits on a lock that checks the deadline.
        self.queue = Inbox()
        self.handling = threading.Lock()
        self.direct = False
        self.failure: BaseException | None = None
        self._switching = threading.Lock()
        self.busy_since_s: float | None = None
        """``time.monotonic()`` when the handler or tick now running started (None between them)."""
        self.busy_with = ""
        """What it handles (``scan, step 12``, ``a tick``): the log's words when it is stuck."""
        self.stuck_said_for: float | None = None
        """The ``busy_since_s`` whose stuck handler the log has named (once per stuck handler)."""

    @contextlib.contextmanager
    def working(self, what: str) -> Iterator[None]:
        """Hold the handling lock while one input's handler or a tick runs, noting since when (``stuck_for_s``)."""
        with self.handling:
            self.busy_since_s, self.busy_with = time.monotonic(), what
            try:
                yield
            finally:
                self.busy_since_s = None

    def handle(self, key: str, payload: bytes, received_s: float) -> None:
        """``_dispatch`` one input under ``working``: its topic, then its step once decoded, name it."""
        with self.working(topic_name(key)):
            _dispatch(self.service, key, payload, received_s, self)

    def stuck_for_s(self, now_s: float) -> float:
        """How long the handler or tick now running has run (0 between them)."""
        since = self.busy_since_s
        return 0.0 if since is None else now_s - since

    def on_sample(self, sample: zenoh.Sample) -> None:
        item = (str(sample.key_expr), sample.payload.to_bytes(), time.monotonic())
        if not self.direct:
            with self._switching:
                if not self.direct:
                    inbox = self.queue
                    while inbox.qsize() >= INBOX_LIMIT or inbox.nbytes + len(item[1]) > INBOX_MAX_BYTES:
                        if not self.drop_oldest():  # the loop far behind: the oldest go, counted
                            break
                    inbox.put(item)
                    return
        with self.working(topic_name(item[0])):
            if self.stop.is_set():
                return
            prof = self.service.network_profile
            if prof is not None:
                prof.enable()  # this thread only, and one handler at a time (the lock): its own profiler
            try:
                _dispatch(self.service, *item, self)
            except BaseException as exc:  # noqa: BLE001 - re-raised on the loop's thread
                self.failure = exc
                self.stop.set()
            finally:
                if prof is not None:
                    prof.disable()

    def drop_oldest(self) -> bool:
        """Drop the oldest data input waiting (the inbox is full; never a control while data waits: ``Inbox.drop_oldest``),
        counted as a rejection of its topic and robot; False when none waits (the loop took the last one meanwhile).
        Called under ``_switching``, by the one thread that puts."""
        dropped = self.queue.drop_oldest()
        if dropped is None:
            return False
        key = dropped[0]
        robot: str | None
        try:
            robot, topic = robot_of(key), topic_of(key)
        except ValueError:
            robot, topic = None, key_topic(key)
        service = self.service
        if robot is not None and robot != service.ctx.robot and robot not in service.heard_from_s:
            # A robot the service has never heard from (a service serving every robot, flooded with keys of robots made
            # up): counted under the topic alone. Its own count would never be forgotten, since it was never heard from
            # (``forget_robot``), and the service grew by one entry per robot a sender made up.
            robot = None
        why = f"dropped unhandled: the inbox was full ({INBOX_LIMIT} inputs, {INBOX_MAX_BYTES >> 20} MiB): its handlers are slower than its inputs come"
        service.reject(topic, why, robot)
        return True

    def go_direct(self) -> None:
        """Handle what is queued, then every later input on arrival (in order: no input overtakes)."""
        with self._switching:
            while True:
                try:
                    item = self.queue.get_nowait()
                except queue.Empty:
                    break
                self.handle(*item)
            self.direct = True

    def next_queued(self, timeout_s: float) -> tuple[str, bytes, float] | None:
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None


def own_incarnation_token(session: zenoh.Session, keys: RobotKeys, name: str) -> Any | None:
    """The token ``alive/<name>/<incarnation>`` of this start (``INCARNATION_ENV``, which the launcher that started the
    service set: ``RobotKeys.alive_incarnation``), declared beside ``alive/<name>``; None for a service started by hand
    (no incarnation), which its launcher, if any, does not supervise."""
    incarnation = os.environ.get(INCARNATION_ENV, "")
    if not incarnation:
        return None
    try:
        key = keys.alive_incarnation(name, incarnation)
    except KeyExprError as exc:  # not the launcher's: the launcher then sees it start and never come up
        log.warning("%s: %s=%r is no key chunk (%s): no incarnation token", name, INCARNATION_ENV, incarnation, exc)
        return None
    return session.liveliness().declare_token(key)


def run_service(service: Service, stop: threading.Event | None = None) -> int:
    """Open the session and run the service's event loop until ``stop`` is set (or a signal)."""
    ctx = service.ctx
    stop = stop or threading.Event()
    service.stop_event = stop
    inputs = ServiceInputs(service, stop)
    service._inbox = inputs.queue
    sub_robot = service.subscribe_robot
    keys = RobotKeys(sub_robot)

    def on_status_query(query: zenoh.Query) -> None:
        stuck_s = inputs.stuck_for_s(time.monotonic())
        if stuck_s > LOOP_STUCK_S:  # no answer: hung to the launcher, which kills and restarts the service
            if inputs.stuck_said_for != inputs.busy_since_s:
                inputs.stuck_said_for = inputs.busy_since_s
                log.error(
                    "%s: its loop has been in one handler (%s) for %.1f s (a deadlock?): no status answer until it returns, "
                    "so that the launcher restarts this service as hung", service.name, inputs.busy_with, stuck_s,
                )  # fmt: skip
            return
        query.reply(ctx.keys.service_status(service.name), encode(service.status_msg()))

    try:
        # With the stop: a service stopped as it starts (its launcher killed, its router gone with it) does not wait for
        # that router up to the connect timeout, to be ended as stuck by ``_exit_once_orphaned``.
        opened = open_session(ctx.transport, stop)
    except TransportError as exc:
        if exc.cause != STOPPED:
            raise
        _say_if_launcher_gone(service.name)
        log.info("%s: stopped before it joined the network", service.name)
        return 0
    with opened as session:
        service.session = session
        handler = zenoh.handlers.Callback(inputs.on_sample, indirect=False)
        subs = [session.declare_subscriber(keys.topic(t), handler) for t in service.inputs]
        status_q = session.declare_queryable(ctx.keys.service_status(service.name), service.guarded(on_status_query))
        cache_qs = [session.declare_queryable(ctx.keys.cache(t), service.guarded(functools.partial(service.answer_cache_query, t))) for t in service.serves_latest]
        for t in service.outputs:
            service.declare_publisher(ctx.keys.topic(t))
        t0 = time.perf_counter()
        try:
            service.warm_up()
            log.info("%s: warmed up in %.0f ms", service.name, (time.perf_counter() - t0) * 1e3)
        except Exception:  # only a speed-up: the first step pays the one-off costs instead
            log.exception("%s: warm-up failed after %.0f ms; starting without it", service.name, (time.perf_counter() - t0) * 1e3)
        service.realtime_priority = use_profile_realtime_priority(service)  # Zenoh's threads and the helpers too
        own = own_incarnation_token(session, ctx.keys, service.name)  # first: its launcher's sign that this process is up
        token = session.liveliness().declare_token(ctx.keys.alive(service.name))
        log.info("%s: up for robot %s (inputs: %s)", service.name, sub_robot, ", ".join(service.inputs) or "none")
        try:
            service.start()
            if ctx.lockstep:
                inputs.go_direct()
            next_tick = time.monotonic()
            while not stop.is_set():
                wait_s = min(max(0.0, next_tick - time.monotonic()), 0.1)
                if inputs.direct:
                    stop.wait(wait_s)
                elif (item := inputs.next_queued(wait_s)) is not None:
                    inputs.handle(*item)
                now = time.monotonic()
                if now >= next_tick and not stop.is_set():
                    with inputs.working("a tick"):
                        service.on_tick(now)
                    next_tick = now + service.tick_period_s
            _say_if_launcher_gone(service.name)
            if inputs.failure is not None:
                raise inputs.failure
        finally:
            try:
                with inputs.handling:
                    service.shutdown()
            finally:
                token.undeclare()
                if own is not None:
                    own.undeclare()
                status_q.undeclare()
                for s in subs:
                    s.undeclare()
                for q in cache_qs:
                    q.undeclare()
                service.session = None
    log.info("%s: stopped", service.name)
    return 0


def _say_if_launcher_gone(name: str) -> None:
    """Log why a service stops when it is because its launcher is gone (``launcher_gone``)."""
    if (gone := launcher_gone()) is not None:
        log.warning("%s: stopping: the launcher (pid %d) is gone (killed? crashed?), and no service outlives it", name, gone)


PENDING_STEPS_KEPT = 256
"""Real time: how many steps of a large per-step input (a map, a scan) a service keeps while it waits for its partner
of the same step (``keep_newest``: the 256 newest, at most 288): the frontier service's maps waiting for their
odometry, the planner's scans for theirs. Real time acts on the newest step that has both and drops every older one,
so of these only the newest ever matters, and they wait only while their odometry is in flight: the referee (sim,
ROS 2 bridge, a replay) sends a step's odometry with its scan, and the mapper builds each map from a scan, not from
the odometry. While the odometry was silent, each map (two bytes a cell decoded: 8 MB at the default
``max_grid_cells``) was kept for as long as the episode ran. Small inputs have ``PENDING_SMALL_STEPS_KEPT``; maps,
``PENDING_MAX_BYTES`` besides. Each step dropped is counted as a rejection of its topic (``Service.keep_newest_within``)."""

PENDING_MAX_BYTES = 256 << 20
"""Real time: the most bytes of one large input a service keeps waiting for its partner (``Service.keep_newest_within``,
``steps_kept``: the newest always stays), each one dropped counted as a rejection of its topic: the frontier service's
maps waiting for their odometry (decoded: their explored and occupied grids, one byte a cell each; fewer than
``PENDING_STEPS_KEPT`` maps once a map is larger than about 0.9 MiB), and the planner's decisions waiting for their
goal (``planner.PENDING_DECISIONS_KEPT``: their frontiers' grids, and apart from them their distance maps). 256 maps
of the largest grid ``max_grid_cells`` allows were 2.0 GB at its default (4,000,000 cells: 8 MB a map, 288 kept
before a trim: 2.3 GB) and 25.6 GB at its ceiling (``messages.MAX_GRID_CELLS``, 50,000,000 cells: 100 MB a map,
28.8 GB before a trim), held for as long as the odometry was silent (a sim stalled, a bridge reading the wrong
odometry topic); now at most this (2 maps at the ceiling: 200 MB). The odometry comes with its step's scan, before
the map built from it, so maps wait for it only while it is in flight: this keeps the 30 newest maps (33 before a
trim) of the default bound's largest grid (3 s at 10 Hz), and the whole ``PENDING_STEPS_KEPT`` of the shipped scenes'
(at most 640 x 480 cells: 0.6 MB a map). The planner's scans need no such bound: 288 of the largest (100,000 float32
ranges, ``messages.MAX_BEAMS``) are 115 MB."""

PENDING_SMALL_STEPS_KEPT = INBOX_LIMIT
"""Real time: how many steps of a small per-step input (odometry, the planner's reports: about 0.4 kB each decoded, a
report's path ahead besides, 16 bytes a point) a service keeps while it waits for its partner of the same step or for
a decision (``keep_newest``: the 100,000 newest, at most 112,500): the frontier service's odometry and planner reports
waiting for maps, the planner's odometry waiting for scans. The partner may lag far: ``replay --speed max`` into a
fresh pipeline sends the odometry thousands of steps ahead of a mapper that recomputes the maps, and each map needs
the odometry of its own step; trimmed to 256 steps, the frontier service decided nothing until the maps were within
256 steps of the odometry. As many as the inbox holds (``INBOX_LIMIT``): whatever lag the inbox takes without a loss,
the steps waiting here take too. A partner that is dead (a mapper given up on, a LiDAR driver that stopped) no longer
grows the service for as long as the episode runs: about 50 MB of odometry at most. Each step dropped is counted as a
rejection of its topic (``Service.keep_newest_within``, with no byte budget)."""


def keep_newest(pending: dict[int, Any], n: int) -> list[int]:
    """Keep the ``n`` newest steps of ``pending`` (in place), and at most ``n + n // 8``: past that it drops all but the
    ``n`` newest, so the sort is paid once per ``n // 8`` steps kept (a partner silent for long costs no sort of
    100,000 steps per input). Below that it costs one ``len``. The steps dropped, oldest first (mostly none)."""
    if len(pending) <= n + n // 8:
        return []
    dropped = sorted(pending)[:-n]
    for step in dropped:
        del pending[step]
    return dropped


def steps_kept(item_bytes: int, n: int = PENDING_STEPS_KEPT, max_bytes: int = PENDING_MAX_BYTES) -> int:
    """The ``n`` to give ``keep_newest`` for steps of ``item_bytes`` each (maps of one grid) so that what it keeps, an
    eighth more before a trim included, holds at most ``max_bytes``: at most ``n``, and never less than 1 (the newest
    step stays, whatever its size). O(1): ``k + k // 8 <= m`` for ``k = 8 * (m // 9) + min(m % 9, 7)``, the largest."""
    m = max_bytes // max(1, item_bytes)
    return max(1, min(n, 8 * (m // 9) + min(m % 9, 7)))


STEP_JUMP_LIMIT = 500
"""Steps one message may leap ahead of the last one on its key (robot, topic) before ``StepGuard`` holds it."""


class StepGuard:
    """Out-of-range steps: a robot's inputs move a step at a time, so a message that leaps more than ``limit``
    steps ahead of the robot's last one is rejected (a stray or forged message would otherwise become the
    service's newest step and every real one after it look old). The reference is the later of the key's own last
    step and the last step on any key of the robot: a key that only decisions use (``goal``) may be quiet for more
    than ``limit`` steps while odometry and scans go on. The step after a rejected leap confirms it when it follows
    on from it: a service cut off for a while picks up the episode again."""

    def __init__(self, limit: int = STEP_JUMP_LIMIT) -> None:
        self.limit = limit
        self.last: dict[tuple[str, str], int] = {}
        self.recent: dict[str, int] = {}
        """Robot -> the step of the last message accepted on any of its keys."""
        self.held: dict[tuple[str, str], int] = {}
        """Key -> the step of a rejected leap, which the next message may confirm."""

    def check(self, key: tuple[str, str], step: int) -> str:
        """Why a message of ``step`` on ``key`` (robot, topic) is rejected, or "" (then it is the key's last step)."""
        known = [s for s in (self.last.get(key), self.recent.get(key[0])) if s is not None]
        last, held = (max(known) if known else None), self.held.pop(key, None)
        if last is not None and step > last + self.limit and not (held is not None and 0 <= step - held <= self.limit):
            self.held[key] = step
            return f"step {step} leaps more than {self.limit} steps past the last one ({last})"
        self.last[key] = self.recent[key[0]] = step  # a step back is a new episode or a retry: the services judge those
        return ""

    def forget(self, robot: str) -> None:
        """Drop ``robot``'s steps: its next message is its first (``Service.forget_robot``)."""
        self.recent.pop(robot, None)
        for steps in (self.last, self.held):
            for key in [k for k in steps if k[0] == robot]:
                del steps[key]


EPISODES_REMEMBERED = 16
"""Ended episode ids an ``EpisodeWatch`` keeps, to tell their late messages from a new episode's."""


class EpisodeWatch:
    """Which episode a robot's messages belong to. Every publisher of steps draws an id per episode
    (``new_episode_id``) and stamps it on what it sends, and what is computed from it carries it on
    (scan and odometry -> map -> frontiers and D -> goal). So a service sees a new episode at its first
    message, whatever its step: a real-time frontier service skips steps, so the policy may never see a
    new episode's step 0, and a lost step 0 left a service waiting for the old episode's step count
    with no word. A message of an episode that has ended is still in flight from before a restart:
    the caller rejects it (counted). Id 0 comes from a publisher without ids (another tool, a map from
    ROS): it never changes the episode; where no message has had an id, step 0 after later steps
    starts a new one, as step 0 alone did before ids, and so does the first id after them (a sim
    with ids after a tool without: its steps start again below those handled)."""

    def __init__(self) -> None:
        self.current: int | None = None
        """The id of the episode being served (None: none seen yet)."""
        self.ended: collections.deque[int] = collections.deque(maxlen=EPISODES_REMEMBERED)
        self.progressed_without_id = False
        """The caller has handled steps past 0 of an episode without ids: the first id then starts a new one."""

    def classify(self, episode: int, step: int, progressed: bool, from_referee: bool = False) -> str:
        """``"same"``, ``"new"`` (a new episode has started: the caller starts afresh) or ``"ended"``
        (a message of an episode before the current one). ``progressed``: the caller has handled
        steps past 0 of the current episode (only id 0 needs it). ``from_referee``: the message comes
        straight from the sim or the ROS bridge (odometry, scans), which runs one episode at a time: its id
        is the episode being run, even one ended here by a late message of an episode this watch never saw
        (a service restarted about when the sim was hears the new episode first)."""
        if episode == 0:
            if self.current is not None:
                return "same"
            if step == 0 and progressed:
                self.progressed_without_id = False
                return "new"
            self.progressed_without_id |= progressed
            return "same"
        if episode == self.current:
            return "same"
        if episode in self.ended:
            if not from_referee:
                return "ended"
            self.ended.remove(episode)
        started = self.current is not None or self.progressed_without_id
        if self.current is not None:
            self.ended.append(self.current)
        self.current, self.progressed_without_id = episode, False
        return "new" if started else "same"


class NoFrontierEnd:
    """A referee's end of an episode on an empty goal (``no_frontier``: the sim's, the ROS 2 bridge's). The episode ends
    at that goal's step with the frontier service's reason (``frontiers/ended_why``: the result's ``ended_why``, the
    status's ``reason``) once heard, at once if it already was; without one after ``wait_s`` (wall clock), or at once
    where no frontier service runs to say it."""

    def __init__(self, wait_s: float) -> None:
        self.wait_s = wait_s
        self.heard: tuple[int, str] | None = None
        """The frontier service's reason why the decision of a step found no goal (step, words), once heard."""
        self.empty_goal: tuple[int, float] | None = None
        """The step of an empty goal and when it came (``time.monotonic()``), while the end waits for its reason."""

    def why_now(self, now_s: float, frontier_runs: bool) -> str | None:
        """The reason to end the episode with now ("": none, nor any to wait for), or None: no empty goal yet, or its
        reason still awaited."""
        if self.empty_goal is None:
            return None
        step, since_s = self.empty_goal
        if self.heard is not None and self.heard[0] == step:
            return self.heard[1]
        if not frontier_runs:
            return ""
        if now_s - since_s < self.wait_s:
            return None
        log.warning("no reason from the frontier service why the goal of step %d is empty: the episode ends no_frontier without one", step)
        return ""


UNKNOWN_KEY = "unknown_key"
"""What ``rejected`` counts a payload under whose key names no topic (``key_topic``)."""


def key_topic(key: str) -> str:
    """The topic a rejection of a payload on ``key`` is counted under: the key's, else ``UNKNOWN_KEY``. Never the key
    itself: a service subscribed to every robot (``cso/*/...``) hears keys of any robot chunk, and counted by key its
    ``rejected`` (and its status) grew by one entry per key a sender made up."""
    try:
        return topic_of(key)
    except ValueError:
        return UNKNOWN_KEY


def _dispatch(service: Service, key: str, payload: bytes, received_s: float, inputs: ServiceInputs | None = None) -> None:
    try:
        robot, topic = robot_of(key), topic_of(key)
    except ValueError as exc:
        service.reject(key_topic(key), str(exc))
        return
    service.heard_from_s[robot] = received_s
    expected = service.inputs.get(topic)
    if expected is None:
        service.reject(topic, "unexpected topic", robot)
        return
    # A topic of one's own is declared as bytes (``own_service_class``; the ClassVar's type leaves it out, so that the
    # services' handlers keep taking a Message): its payload is handed over as it came, unchecked.
    declared: type = expected
    try:
        msg: Any = payload if declared is bytes else decode(payload, expected)
    except MessageError as exc:
        service.reject(topic, str(exc), robot)
        return
    step = getattr(msg, "step", None)
    if isinstance(step, int) and (why := service.step_guard.check((robot, topic), step)):
        service.reject(topic, why, robot)
        return
    service.processed += 1
    service.processed_by_robot[robot] += 1
    if inputs is not None and isinstance(step, int):
        inputs.busy_with = f"{topic}, step {step}"
    t0 = time.monotonic()
    service.on_message(robot, topic, msg, received_s)
    if service.trace is not None:
        service.trace.handled(topic, getattr(msg, "step", -1), received_s, t0, time.monotonic())


LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
"""What a service's ``--log-level`` takes, in any case."""


def module_of(cls: type) -> str | None:
    """The module ``cls`` is defined in, by the name it is imported as: ``services.mapper`` also when it runs as
    ``python -m services.mapper`` (where it is ``__main__``); None for a class of a script run as a file."""
    module = cls.__module__
    if module != "__main__":
        return module
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    return spec.name if spec is not None else None


def default_prog(name: str, cls: type[Service] | None) -> str | None:
    """How a service's usage line names its command when not run as ``cso-runtime service``: ``python -m services.NAME``
    for a built-in one, ``python -m MODULE`` for a class of one's own in a module, the script's own name (argparse's
    default, None) for one run as a script."""
    module = module_of(cls) if cls is not None else f"services.{name}"
    return f"python -m {module}" if module else None


def service_parser(name: str, cls: type[Service] | None = None, prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of a service's command line: the common service options, plus those ``cls.add_arguments`` declares;
    ``prog`` names the command in the usage line (``python -m services.NAME`` unless run as ``cso-runtime service NAME``)."""
    p = argparse.ArgumentParser(prog=prog or default_prog(name, cls), description=f"cso-runtime {name} service")
    p.add_argument("--config", type=Path, default=None, help="Profile YAML (cso_runtime/profiles/*.yaml or your own); required unless --attach")
    p.add_argument("--robot", default=None, help="Robot id: namespaces every key (cso/<robot>/...); default r0, or the run's with --attach")
    p.add_argument("--connect", action="append", default=[], help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--listen", action="append", default=[], help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--mode", default="client", help="Zenoh mode: client, peer or router")
    p.add_argument(
        "--zenoh-config", default=None, help="Zenoh config file (JSON5) to start from: credentials, TLS; default: the profile's router.zenoh_config, else $CSO_ZENOH_CONFIG"
    )
    p.add_argument(
        "--log-level", type=str.upper, choices=LOG_LEVELS, default=None, metavar="LEVEL",
        help="Logging level: debug, info, warning or error (default info; under `cso-runtime -v service`, debug)",
    )  # fmt: skip
    p.add_argument(
        "--attach", action="store_true",
        help="Join the current run of --runs-dir: its profile.yaml, router and robot unless given (a viewer's bridge beside a running episode)",
    )  # fmt: skip
    p.add_argument("--runs-dir", type=Path, default=Path("runs"), help="Where --attach finds the current run (runs/current.json)")
    if cls is not None:
        cls.add_arguments(p)
    return p


def parse_args(name: str, argv: list[str] | None = None, cls: type[Service] | None = None, prog: str | None = None) -> argparse.Namespace:
    """``argv`` parsed by ``service_parser``, ``--attach`` resolved to the current run's profile, router and robot."""
    p = service_parser(name, cls, prog)
    args = p.parse_args(argv)
    if args.attach:
        from cso_runtime.current_run import read_current_run  # noqa: PLC0415  (only to attach)
        from cso_runtime.status import current_run_not_joinable  # noqa: PLC0415

        found = read_current_run(args.runs_dir)
        if (not_yet := current_run_not_joinable(found, args.runs_dir)) is not None:  # starting (an `up ... &` just typed), or ending
            p.error(f"--attach: {not_yet.said}")
        info = found or {}
        try:
            run_dir, endpoints, robot = Path(info["run_dir"]), list(info["endpoints"]), str(info["robot"])
        except (KeyError, TypeError):
            p.error(f"--attach: no current run in {args.runs_dir} (start one with `cso-runtime up`, or give --config and --connect)")
        args.config = args.config or run_dir / "profile.yaml"
        args.connect = args.connect or endpoints
        args.robot = args.robot or robot
    elif args.config is None:
        p.error("--config is required (or --attach, to join the current run)")
    args.robot = args.robot or "r0"
    return args


def service_main(cls: type[Service], argv: list[str] | None = None, prog: str | None = None, exit_process: bool = True) -> int:
    """``python -m services.<name>`` entry point: parse, load the profile, run; config errors exit 2. Once the service has
    stopped (its session closed, its trace and profile written), ``exit_process`` ends the process at once with that
    code (``exit_now``), without the interpreter's slow teardown; False returns the code (a caller of its own)."""
    code = _service_main(cls, argv, prog)
    if exit_process:
        exit_now(code)
    return code


def exit_now(code: int) -> NoReturn:
    """End the process with ``code`` now, without the interpreter's teardown: a service that imports torch took 1.5 to
    3.4 s after its "stopped" line to exit on 2 busy cores (modules and objects freed one by one), past the launcher's
    ``stop_timeout_s``, which then said it was "still running after SIGINT" and sent SIGTERM. What an exit does that
    matters is done first: the ``atexit`` functions (logging's flush and close, multiprocessing's join of its helper
    processes, ``weakref.finalize``'s), then stdout and stderr flushed."""
    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):  # closed, or a pipe gone: nothing more to write there
                stream.flush()
        os._exit(code)


def use_profile_realtime_priority(service: Service) -> int:
    """The profile's ``realtime_priority`` (``Profile``) set on every thread of this service's process and of its helper
    processes (``processes.use_realtime_priority``, ``Service.helper_pids``), said in its log either way: the priority
    once set; 0 where the profile asks for none, or where it is not permitted here (the service then runs with normal
    scheduling, as ``up`` said before it started it). Called once the service has warmed up, before it says it is up:
    a warm-up (imports, a first decision) under real-time scheduling would take the CPUs from everything else for a
    second or more."""
    name, priority = service.name, int(service.ctx.profile.get("realtime_priority") or 0)
    if not priority:
        return 0
    why = use_realtime_priority(priority, [os.getpid(), *service.helper_pids()])
    if why is None:
        log.info("%s: real-time scheduling, SCHED_FIFO priority %d (realtime_priority)", name, priority)
        return priority
    log.warning("%s: realtime_priority %d: %s; running with normal scheduling (%s)", name, priority, why, REALTIME_HOWTO)
    return 0


def _service_main(cls: type[Service], argv: list[str] | None, prog: str | None) -> int:
    """``service_main``'s run: the service's exit code."""
    args = parse_args(cls.name, argv, cls, prog)
    # Under `cso-runtime service` the command line has set logging up already (-v: debug), and basicConfig then
    # does nothing: the level given is set on the root logger itself.
    logging.basicConfig(level=args.log_level or logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
    if args.log_level:
        logging.getLogger().setLevel(args.log_level)
    dump_stacks_on_signal()  # a hang the launcher has to kill leaves its stacks in this log
    try:
        check_robot_id(args.robot)
        profile, exploration, params = load_profile_for_service(args.config, cls.name, cls)
        set_max_grid_cells(profile.get("max_grid_cells", DEFAULT_MAX_GRID_CELLS))  # before any message is decoded
        check_seed(profile.get("seed", 0))  # as `up` checks it: the services read it with int(), which took 1e400 or [1] badly
        REALTIME_PRIORITY_BOUND.check("realtime_priority", profile.get("realtime_priority") or 0)
        params = cls.apply_arguments(args, dict(params))
        transport = TransportConfig(mode=args.mode, connect=list(args.connect), listen=list(args.listen))
        router = r if isinstance(r := profile.get("router"), dict) else {}
        transport.zenoh_config_file = args.zenoh_config or str(router.get("zenoh_config") or "") or transport.zenoh_config_file
        transport.validate()
        service = cls(ServiceContext(cls.name, args.robot, profile, exploration, transport, params))
    except (ConfigError, TransportError, ValueError, OverflowError, MemoryError) as exc:
        # What a bad profile raises as the service is made from it: its checks' ConfigError, a value no type takes
        # (ValueError), a size too large to count (OverflowError: 1e308 m at 1 mm) or to allocate (MemoryError) in a
        # service of one's own that checks none (the built-in ones check their grids: ``messages.check_configured_grid``).
        log.error("%s: bad configuration: %s", cls.name, exc)
        return EXIT_BAD_CONFIG
    stop = threading.Event()
    _install_stop_handlers(stop, service)
    _die_with_launcher(cls.name, stop)
    keep_freed_memory()
    trace_dir = os.environ.get(TRACE_DIR_ENV)
    if trace_dir:
        service.trace = MessageTrace(Path(trace_dir) / f"{cls.name}.trace.json")
    prof_dir = os.environ.get("CSO_PROFILE_DIR")
    if prof_dir:
        prof = cProfile.Profile()
        service.network_profile = cProfile.Profile()
        prof.enable()
    try:
        return run_service(service, stop)
    except ConfigError as exc:  # refused once on the network (a ROS robot another run's bridge drives): not restarted
        log.error("%s: bad configuration: %s", cls.name, exc)
        return EXIT_BAD_CONFIG
    except TransportError as exc:
        log.error("%s: %s", cls.name, exc)
        return EXIT_NO_ZENOH
    finally:
        if service.trace is not None:
            service.trace.write()
        if prof_dir:
            prof.disable()
            write_profile([prof, service.network_profile], Path(prof_dir) / f"{cls.name}.prof")


def write_profile(profiles: list[cProfile.Profile | None], path: Path) -> None:
    """Dump a service's cProfile (``CSO_PROFILE_DIR``): its main thread's and its network thread's, merged;
    creating the folder. A failure is logged, since a profile must never turn a clean stop into a crash."""
    recorded = [p for p in profiles if p is not None and p.getstats()]  # a profiler never enabled has nothing
    if not recorded:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        pstats.Stats(*recorded).dump_stats(str(path))
    except OSError as exc:
        log.error("cannot write the profile %s: %s", path, exc)


ORPHAN_STOP_S = 10.0
"""How long a service whose launcher is gone has to stop cleanly before it exits outright (``_exit_once_orphaned``):
a clean stop then takes 0.3 to 0.5 s, but the kernel's SIGTERM only sets the stop event, which a loop stuck in a
handler never looks at."""


def _exit_once_orphaned(name: str, stop: threading.Event) -> None:
    """Exit ``ORPHAN_STOP_S`` after the launcher has gone (``launcher_gone``) if the service has not stopped by then
    (its loop stuck in a handler): its threads' stacks to its log first, as for a hang the launcher kills."""
    while (gone := launcher_gone()) is None:
        time.sleep(PARENT_CHECK_PERIOD_S)
    stop.set()  # as the kernel's SIGTERM does, in case its handler never ran
    time.sleep(ORPHAN_STOP_S)
    log.error("%s: still running %g s after its launcher (pid %d) went (stuck?): its threads' stacks, then exit", name, ORPHAN_STOP_S, gone)
    with contextlib.suppress(ValueError, OSError):  # stderr is the service's log; none to write to: exit all the same
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    os._exit(1)


def _die_with_launcher(name: str, stop: threading.Event) -> None:
    """When started by a launcher, get SIGCONT if it dies (Linux; the stop handlers' ``continued`` then stops the
    service as SIGTERM does, and a service stopped by SIGSTOP or a debugger is continued first: SIGTERM would wait
    behind the stop for good), and exit ``ORPHAN_STOP_S`` later if that did not stop the service, so no service
    outlives it."""
    parent = os.environ.get(PARENT_PID_ENV)
    if not parent or not parent.isdigit():
        return
    threading.Thread(target=_exit_once_orphaned, args=(name, stop), daemon=True, name="exit-once-orphaned").start()
    if not signal_on_parent_death(signal.SIGCONT):
        return
    if os.getppid() != int(parent):
        os.kill(os.getpid(), signal.SIGTERM)


def warm_up_map(resolution_m: float = 0.05) -> tuple[OccupancyMap, Pose2D]:
    """A small synthetic map for ``warm_up``: a 6 m square, the robot in its centre, what lies within
    2.5 m of it explored, and a 1.5 m wall 1 m ahead of it. The algorithms of an episode's first step
    run once on it (obstacles inflated, frontiers around the explored disk), with no scene."""
    n = int(round(6.0 / resolution_m))
    geometry = GridGeometry(resolution_m, (n, n))
    occupancy = OccupancyMap(geometry)
    iy, ix = np.mgrid[0:n, 0:n]
    centre = (n - 1) / 2.0
    occupancy.explored[:] = np.hypot(iy - centre, ix - centre) * resolution_m <= 2.5
    wall_ix, half_len = int(centre + 1.0 / resolution_m), int(0.75 / resolution_m)
    occupancy.occupied[int(centre) - half_len : int(centre) + half_len, wall_ix] = True
    x_m, y_m = geometry.cell_to_world(int(centre), int(centre))
    return occupancy, Pose2D(float(x_m), float(y_m), 0.0)


def warm_up_observation(config: ExplorationConfig) -> Observation:
    """A decision's Observation on ``warm_up_map`` (what a policy or planner warms up on)."""
    occupancy, pose = warm_up_map()
    return ObservationBuilder(config.frontier, config.robot).build(occupancy, pose, np.array([pose.xy]))
