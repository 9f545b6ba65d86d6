"""The one Zenoh configuration helper every process uses (launcher, services, status client, tests).

Multicast scouting is always off: processes find each other only through the endpoints given
(``--connect`` / ``--listen``), so two runs on one machine, or a test next to a real robot, never
cross-talk by accident.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

log = logging.getLogger("cso.transport")

MODES = ("peer", "client", "router")

ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
"""Zenoh's own variable for its Tokio runtimes (RON); a value set by the user is always kept."""
ONE_ZENOH_THREAD = "(rx: (worker_threads: 1), tx: (handover: rx), net: (handover: rx), acc: (handover: rx), app: (handover: rx))"
"""Our default for ``ZENOH_RUNTIME``: all of Zenoh's runtimes on one worker thread per process, which
receives, runs the handlers (as the services do in lockstep) and sends.

Zenoh's default is six worker threads per process (two that receive); with five services, the
launcher and its router on a small machine, every message then woke threads that only handed work
to each other. A thread of its own for sending still cost each message a wake-up and a wait for a
CPU on two cores: one thread is 3-5 % faster on the small lockstep scene and level on ``builtin``
(docs/experiments/runtime-overhead.md). A handler that publishes a message larger than the link's
queue (a distance map of several MB) from this thread still sends it at once, without waiting for
the thread to return (``tests/test_runtime.py``, with Zenoh 1.10)."""


class TransportError(RuntimeError):
    """A Zenoh session could not be configured or opened. ``cause``: why, when known, so that a caller's hint fits
    it: ``LISTEN_IN_USE`` (another process holds a port to listen on), ``UNREACHABLE`` (no router to connect to
    answered), ``STOPPED`` (given up on: the caller was stopped while it opened), else ""."""

    def __init__(self, message: str, cause: str = "") -> None:
        super().__init__(message)
        self.cause = cause


LISTEN_IN_USE = "listen_in_use"
UNREACHABLE = "unreachable"
STOPPED = "stopped"


ZENOH_CONFIG_ENV = "CSO_ZENOH_CONFIG"
"""A Zenoh config file (JSON5, Zenoh's own format) every session of this process, and of the processes it starts,
takes as its base: ``--zenoh-config FILE`` sets it (``router.zenoh_config`` in a profile, for a run)."""

OWNED_KEYS = {
    "mode": "--mode (the launcher's router, its services' router.service_mode)",
    "connect/endpoints": "--connect / router.connect",
    "listen/endpoints": "router.listen",
    "scouting/multicast/enabled": "multicast scouting, always off",
    "connect/timeout_ms": "router.connect_timeout_s",
    "connect/exit_on_failure": "router.connect_timeout_s",
}
"""Keys of a Zenoh config file that the runtime sets itself, and what sets them: a file that gives one a value
other than Zenoh's default is refused (it would be overwritten without a word)."""

TUNED_KEYS = {
    "transport/link/tx/queue/size/data": "8",
    "transport/link/tx/queue/congestion_control/drop/wait_before_drop": "20000",
    "scouting/gossip/autoconnect_strategy": '{ peer: { to_router: "always", to_peer: "greater-zid" } }',
}
"""Our values for Zenoh settings (JSON5) where Zenoh's default loses messages on a busy machine (``zenoh_config``):
a file that sets one to something else keeps its own.

``autoconnect_strategy``: of two peers that hear of each other (peer-mode services, introduced by their router), only
the one with the greater Zenoh id connects. By default both do, and with user/password authentication two such
connections at once could leave the pair without a link for good (Zenoh 1.10; its issue 2577 reports duplicate
connections refused with usrpwd): of five peers opened at once behind a password router, some pair stayed unlinked in
3 of 17 tries, none with this strategy or without a password. A lockstep run's sim then never heard one service and
failed its episode after ``lockstep_give_up_s``, as on a loaded host while sessions without the password were refused."""

LONE_ROUTER_SCOUTING_DELAY_MS = 0
"""``scouting/delay`` of a router that joins no other (``zenoh_config``): Zenoh's router waits out the whole delay (500 ms
by default) as it opens, for the peers its multicast scouting would find; multicast scouting is always off here, and
with no router to join there is no one to wait for. Every ``up`` opens one (its embedded router), as do the tests:
half a second each for nothing. A router that joins others keeps Zenoh's delay, as does a file's own value."""

FILE_KEYS = (
    "transport/auth/usrpwd/dictionary_file",
    "transport/link/tls/root_ca_certificate",
    "transport/link/tls/listen_private_key",
    "transport/link/tls/listen_certificate",
    "transport/link/tls/connect_private_key",
    "transport/link/tls/connect_certificate",
)
"""Keys naming a file that Zenoh reads only when a session opens: checked when the config file is read, so that a
missing one stops a run before anything starts rather than one service later."""


def load_zenoh_config_file(path: str | os.PathLike[str]) -> zenoh.Config:
    """The Zenoh config in ``path`` (JSON5, Zenoh's own format), checked: a file missing, not JSON5, with a key or
    value Zenoh rejects, setting a key in ``OWNED_KEYS``, or naming a file (``FILE_KEYS``) that is not there raises
    ``TransportError``."""
    try:
        cfg = zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise TransportError(f"zenoh config {path}: {str(exc).split(' at /', 1)[0].strip()}") from None
    default = zenoh.Config()
    for key, setter in OWNED_KEYS.items():
        if json.loads(cfg.get_json(key)) != json.loads(default.get_json(key)):
            raise TransportError(f"zenoh config {path}: {key} is set by cso-runtime ({setter}); remove it from the file")
    for key in FILE_KEYS:
        named = json.loads(cfg.get_json(key))
        if named and not os.path.isfile(named):
            raise TransportError(f"zenoh config {path}: {key} names {named!r}, which is not a file (relative paths are from the working folder)")
    return cfg


JOIN_TIMEOUT_S = 10.0
"""How long opening a client session, or a router's that joins others, waits to reach the routers it connects to
before it fails: services may start before their router, and a router on another host (a robot's) answers in
well under this over a LAN."""


@dataclass
class TransportConfig:
    """How a process joins the Zenoh network."""

    mode: str = "client"
    """Zenoh mode: ``client`` (services, via the launcher's router), ``peer`` or ``router``."""
    connect: list[str] = field(default_factory=list)
    """Endpoints to connect to, e.g. ``tcp/127.0.0.1:7447``."""
    listen: list[str] = field(default_factory=list)
    """Endpoints to listen on (the launcher's embedded router: ``tcp/127.0.0.1:<port>``)."""
    connect_timeout_s: float = JOIN_TIMEOUT_S
    """Client, or router with ``connect``: opening fails (``TransportError``) when the endpoints in ``connect`` cannot
    be reached within this long. A peer starts alone, as Zenoh's default."""
    zenoh_config_file: str = field(default_factory=lambda: os.environ.get(ZENOH_CONFIG_ENV, ""))
    """A Zenoh config file to start from (``load_zenoh_config_file``; default: ``$CSO_ZENOH_CONFIG``): its
    authentication, TLS and access control apply, with the settings above on top. "": Zenoh's defaults."""

    def validate(self) -> None:
        if self.mode not in MODES:
            raise TransportError(f"zenoh mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if not self.connect_timeout_s > 0:
            raise TransportError(f"the connect timeout must be positive seconds, got {self.connect_timeout_s}")
        for ep in [*self.connect, *self.listen]:
            if "/" not in ep:
                raise TransportError(f"bad zenoh endpoint {ep!r}; expected PROTO/HOST:PORT, e.g. tcp/127.0.0.1:7447")
            proto, address = ep.split("/", 1)
            if proto in ("tcp", "udp", "tls", "quic", "ws"):
                port = address.split("#", 1)[0].rpartition(":")[2]
                if not (port.isdigit() and 0 <= int(port) <= 65535):
                    raise TransportError(f"bad zenoh endpoint {ep!r}: the port must be a number from 0 to 65535")
        if self.mode == "client" and not self.connect:
            raise TransportError("client mode needs at least one --connect endpoint")
        if self.zenoh_config_file:
            load_zenoh_config_file(self.zenoh_config_file)


def zenoh_config(conf: TransportConfig) -> zenoh.Config:
    """A zenoh.Config with the mode and endpoints of ``conf`` and multicast scouting disabled, on top of the
    settings of ``conf.zenoh_config_file`` when one is given.

    Zenoh reads ``ZENOH_RUNTIME`` once, when a process first opens a session: unless the user set
    it, ``ONE_ZENOH_THREAD`` applies from here on (child processes inherit it)."""
    conf.validate()
    os.environ.setdefault(ZENOH_RUNTIME_ENV, ONE_ZENOH_THREAD)
    cfg = load_zenoh_config_file(conf.zenoh_config_file) if conf.zenoh_config_file else zenoh.Config()
    zenoh_default = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(conf.mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", json.dumps(list(conf.connect)))
    cfg.insert_json5("listen/endpoints", json.dumps(list(conf.listen)))
    # Zenoh drops a message when a link's queue stays full for longer than ``wait_before_drop`` (default
    # 1 ms, 2 batches per priority). On a busy machine (five service processes starting at once on
    # two cores) a link's sender can be off-CPU for longer than that, and whole steps went missing in a
    # recording. A deeper queue and a 20 ms grace keep them; a link congested for longer still drops.
    for key, value in TUNED_KEYS.items():
        if cfg.get_json(key) == zenoh_default.get_json(key):  # a file's own value is kept
            cfg.insert_json5(key, value)
    if conf.mode == "router" and not conf.connect and cfg.get_json("scouting/delay") == zenoh_default.get_json("scouting/delay"):
        cfg.insert_json5("scouting/delay", str(LONE_ROUTER_SCOUTING_DELAY_MS))
    if conf.mode == "client" or (conf.mode == "router" and conf.connect):
        # Keep retrying the router for a while instead of failing at once: services may start first. A router that
        # joins others would otherwise open at once and retry them in the background for ever, saying nothing: a
        # run meant to join another robot's network (or the robot itself) ran alone.
        cfg.insert_json5("connect/timeout_ms", str(round(conf.connect_timeout_s * 1000)))
        cfg.insert_json5("connect/exit_on_failure", "true")
    return cfg


STOP_POLL_S = 0.05
"""``open_session`` with a ``stop``: how often it looks at it while Zenoh opens."""

GIVEN_UP_OPEN_WAIT_S = 2.0
"""How long a process's end waits for a Zenoh open that ``open_session`` gave up on (its stop set). An open that
returned into Python while the interpreter finalized aborted the process ("FATAL: exception not rethrown", SIGABRT,
exit 134 instead of 130: ``up`` Ctrl-C'd as its router opened); a router's open takes well under a second. An open
still waiting for a router to join after this is left: it returns at its ``connect_timeout_s``, most likely after
the process is gone."""

_given_up_opens: list[threading.Thread] = []
"""The opening threads ``open_session`` gave up on, for ``_wait_for_given_up_opens`` at the process's end."""


def _wait_for_given_up_opens() -> None:
    """At the process's end (atexit, before the interpreter finalizes): let each given-up open return and close what
    it opened, within ``GIVEN_UP_OPEN_WAIT_S`` in all; one more Ctrl-C stops the wait."""
    deadline_s = time.monotonic() + GIVEN_UP_OPEN_WAIT_S
    try:
        for thread in _given_up_opens:
            thread.join(max(0.0, deadline_s - time.monotonic()))
    except KeyboardInterrupt:
        pass


def open_session(conf: TransportConfig, stop: threading.Event | None = None) -> zenoh.Session:
    """Open a Zenoh session (use it in a ``with`` block so it always closes).

    ``stop``: the caller's stop (the launcher's, set by Ctrl-C or SIGTERM). Zenoh opens in Rust code, where no Python
    signal handler runs, and waits there up to ``conf.connect_timeout_s`` for a router to join: a launcher joining a
    router that is gone sat out the whole timeout after a SIGTERM (10 s by default), then ended as "no router". With
    ``stop`` the open runs on a thread of its own and is given up as soon as ``stop`` is set (``TransportError``,
    cause ``STOPPED``); a session that opens after that is closed on that thread."""
    if stop is None:
        return _open(conf)
    opened: list[zenoh.Session | BaseException] = []
    lock = threading.Lock()
    given_up = threading.Event()

    def open_it() -> None:
        try:
            outcome: zenoh.Session | BaseException = _open(conf)
        except BaseException as exc:  # noqa: BLE001 - raised again on the caller's thread, whatever it is
            outcome = exc
        with lock:
            if not given_up.is_set():
                opened.append(outcome)
                return
        if isinstance(outcome, zenoh.Session):  # opened after the caller gave up on it: its ports go with it
            outcome.close()

    thread = threading.Thread(target=open_it, name="zenoh-open", daemon=True)
    thread.start()
    while thread.is_alive() and not stop.wait(STOP_POLL_S):
        pass
    with lock:
        if not opened:
            given_up.set()
            if not _given_up_opens:
                atexit.register(_wait_for_given_up_opens)
            _given_up_opens.append(thread)
            raise TransportError(f"stopped while opening the zenoh session ({conf.mode}, connect={conf.connect}, listen={conf.listen})", STOPPED)
    if isinstance(opened[0], BaseException):
        raise opened[0]
    return opened[0]


ZENOH_SOURCE_LINE = re.compile(r"\s+at \S+\.rs:\d+\.?(?=\]|$)")
"""The place in Zenoh's Rust source that ends its errors (``... Timeout! at /root/.cargo/git/checkouts/zenoh-.../
orchestrator.rs:388.``), or the error it quotes in brackets (a port taken: ``[127.0.0.1:7447: Address already in use
(os error 98) at /root/.cargo/.../tcp.rs:61.]``): the build machine's path, left out of what a user reads."""


def _open(conf: TransportConfig) -> zenoh.Session:
    """``open_session`` without a stop: its failures as ``TransportError``."""
    try:
        return zenoh.open(zenoh_config(conf))
    except zenoh.ZError as exc:
        cause = UNREACHABLE if "Unable to connect" in str(exc) else LISTEN_IN_USE if "in use" in str(exc) else ""
        unreached = f"cannot reach {', '.join(conf.connect)} within {conf.connect_timeout_s:g} s: " if cause == UNREACHABLE else ""
        said = ZENOH_SOURCE_LINE.sub("", str(exc))
        raise TransportError(f"{unreached}cannot open zenoh session ({conf.mode}, connect={conf.connect}, listen={conf.listen}): {said}", cause) from None
    except BaseException as exc:
        # Zenoh panics (pyo3's PanicException, a BaseException) on a ZENOH_RUNTIME it cannot parse: `up` ended in a
        # Rust traceback, exit 1, its run folder without a run.json. Said as the session that could not open.
        if type(exc).__name__ != "PanicException":
            raise
        runtime = os.environ.get(ZENOH_RUNTIME_ENV)
        hint = f" (is ZENOH_RUNTIME={runtime!r} valid? unset it for the default)" if runtime is not None and runtime != ONE_ZENOH_THREAD else ""
        raise TransportError(f"cannot open zenoh session ({conf.mode}, connect={conf.connect}, listen={conf.listen}): Zenoh failed: {exc}{hint}") from None


ROUTER_LISTEN = "tcp/0.0.0.0:7447"
"""Where ``cso-runtime router`` listens unless given ``--listen``: Zenoh's own port on every interface, as zenohd and a
robot's zenoh-bridge-ros2dds do, so that the other hosts reach it (``up``'s embedded router listens on loopback)."""

PORT_TRIES = 3
"""``open_router``: picks of a free port per start (another process may take one between the pick and the bind)."""


def open_router(
    listen: list[str],
    connect: list[str],
    connect_timeout_s: float = JOIN_TIMEOUT_S,
    zenoh_config_file: str | None = None,
    stop: threading.Event | None = None,
) -> tuple[zenoh.Session, list[str]]:
    """A router session and the endpoints it listens on: each endpoint ending in port ``:0`` gets a port free
    right now; when another process takes it before Zenoh binds it, another is picked (``PORT_TRIES`` in all).
    The routers in ``connect`` must be reached within ``connect_timeout_s`` (else ``TransportError``).
    ``zenoh_config_file``: the base config (``TransportConfig.zenoh_config_file``; None: its default); ``stop``: as
    ``open_session``'s."""
    base = {} if zenoh_config_file is None else {"zenoh_config_file": zenoh_config_file}
    picked = any(ep.endswith(":0") for ep in listen)
    for attempt in range(1, PORT_TRIES + 1):
        chosen = [f"{ep[:-2]}:{free_tcp_port()}" if ep.endswith(":0") else ep for ep in listen]
        try:
            return open_session(TransportConfig(mode="router", listen=chosen, connect=list(connect), connect_timeout_s=connect_timeout_s, **base), stop), chosen
        except TransportError as exc:
            if not picked or attempt == PORT_TRIES or exc.cause != LISTEN_IN_USE:  # only a taken port is worth another pick
                raise
            log.warning("router port taken before it was bound (%s); picking another", ", ".join(chosen))
    raise AssertionError("unreachable")


def listen_in_use_hint(listen: list[str], router: str, pick_another: str) -> str:
    """What to do when a port ``router`` (``up``'s embedded router, ``cso-runtime router``) is to listen on (``listen``) is
    held by another process (``TransportError`` cause ``LISTEN_IN_USE``); ``pick_another``: how that command picks another."""
    return f"another process holds a port {router} is to listen on ({', '.join(listen)}): stop it, or pick another port with {pick_another} (0: any free port)"


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now on ``host`` (for the embedded router and tests)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def loopback_endpoint(port: int) -> str:
    """The Zenoh endpoint of a TCP port on loopback (``tcp/127.0.0.1:PORT``)."""
    return f"tcp/127.0.0.1:{port}"


LOOPBACK_PROTOCOLS = ("tcp", "tls")
"""Protocols ``any_loopback_port`` keeps (others, e.g. udp or quic, need what a service does not set up)."""


def any_loopback_port(like: list[str]) -> str:
    """``PROTO/127.0.0.1:0`` (loopback, any free port) over the protocol of the first endpoint in ``like`` (tcp when
    none or another): a peer-mode service listens like its embedded router, as services of a run behind a TLS router
    listened on plain TCP, where a session without the CA (or, with ``enable_mtls``, without a certificate) joined
    them and read or published all that the router refused it."""
    protocol = like[0].split("/", 1)[0] if like else "tcp"
    return f"{protocol if protocol in LOOPBACK_PROTOCOLS else 'tcp'}/127.0.0.1:0"


def track_liveliness(alive: set[str], sample: Any) -> None:
    """Keep ``alive`` (service names) up to date from a liveliness sample on ``cso/<robot>/alive/<service>``:
    a token declared adds its service, one undeclared (or lost with its process) removes it."""
    name = str(sample.key_expr).rsplit("/", 1)[-1]
    if str(sample.kind).endswith("PUT"):
        alive.add(name)
    else:
        alive.discard(name)


def track_robots_liveliness(alive: set[tuple[str, str]], sample: Any) -> None:
    """``track_liveliness`` over every robot's tokens (``cso/*/alive/*``): ``alive`` holds (robot, service) pairs,
    so that one robot's services are never taken for another's."""
    parts = str(sample.key_expr).split("/")
    pair = (parts[1], parts[-1]) if len(parts) == 4 else ("", parts[-1])
    if str(sample.kind).endswith("PUT"):
        alive.add(pair)
    else:
        alive.discard(pair)


def callback_name(callback: Callable[..., Any]) -> str:
    """How a callback is named in logs and counts: its function's name (a ``functools.partial``'s function's)."""
    return str(getattr(callback, "__name__", None) or getattr(getattr(callback, "func", None), "__name__", "a callback"))


def guarded_callback(callback: Callable[..., None], failed: Callable[[str], None], name: str | None = None) -> Callable[..., None]:
    """``callback`` for Zenoh (a queryable, a subscriber, a liveliness subscriber) or another library's thread, for
    whatever arguments it is called with: an exception in it reached only that library's own log line, in no count.
    Here ``failed(name)`` is called in the ``except`` block (it counts, and logs with ``log.exception``); a ``zenoh.Query``
    among the arguments is answered with an error naming the callback and what it raised, and ended at once: left to
    be ended when the ``Query`` was freed, a log handler that kept the record (and so the traceback, and the query)
    made its querier wait out its whole timeout. The one guard of the services (``Service.guarded``) and the
    launcher's (``Launcher._guarded``). A ``BaseException`` that is no ``Exception`` (a ``SystemExit`` or
    ``KeyboardInterrupt`` raised in it) is counted and answered alike, then raised on: let through first, it was in no
    count, its query got no error, and Zenoh's own log record of it kept the query (its querier waited out its timeout).
    Raised on in a Zenoh callback it stops nothing: zenoh-python (1.10) runs callbacks on a thread of its own, catches
    any ``BaseException`` there, logs it (``zenoh.handlers``, "callback error") and goes on calling; the process does
    not exit (a signal's ``KeyboardInterrupt`` only ever comes on the main thread)."""
    said = callback_name(callback) if name is None else name

    def call(*args: Any) -> None:
        try:
            callback(*args)
        except BaseException as exc:  # counted and logged by ``failed``, then answered; raised on if no Exception
            failed(said)  # first: a querier told of the error then finds it counted in the status it asks for next
            for arg in args:
                if isinstance(arg, zenoh.Query):
                    end_failed_query(arg, f"{said} raised {type(exc).__name__}: {exc}")
            if not isinstance(exc, Exception):
                raise

    return call


def end_failed_query(query: zenoh.Query, why: str) -> None:
    """Reply ``why`` as an error to ``query`` (clipped, escaped: ``messages.clipped``) and end it now; a query that can
    no longer take a reply (already ended) is left as it is."""
    from cso_runtime.messages import clipped  # noqa: PLC0415 - the message module only where a callback failed

    with contextlib.suppress(Exception):  # zenoh.ZError, or whatever a query already dropped raises
        query.reply_err(clipped(why))
    with contextlib.suppress(Exception):
        query.drop()
