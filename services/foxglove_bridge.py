"""Foxglove bridge service: the running episode, live, in Foxglove (as ROS's foxglove_bridge serves a ROS graph).

It listens to one robot's scan, odometry, map, path, goal, frontiers, velocity commands and episode status, turns each into the
standard ROS 2 messages that ``export-bag`` writes (``cso_runtime.bag_export.BagConverter``, the same code: the
same topics, frames and types, CDR-encoded), and serves them on a Foxglove WebSocket server
(``ws://HOST:PORT``: in Foxglove, "Open connection" -> "Foxglove WebSocket"). A 3D panel in the ``map`` frame
shows the map, the scan, the robot, its path, goal and frontiers as the exploration goes. Optionally the same
messages are also written to an MCAP file.

Frames are export-bag's (``cso_runtime.bag_export``): the robot in ``odom`` (the scene's own frame), ``map`` ->
``odom`` the scene's map origin and ``base_link`` -> ``laser`` the profile's ``exploration.sensor.mount_x_m`` (where
the sim and the ROS 2 bridge put the LiDAR) on ``/tf_static``; the map, path, goal and frontiers in ``map``, so that a
map_server scene's grid overlays its own map. The map origin comes with the episode's ``episode/status`` (one more
input), which the sim first publishes after the episode's first map: the map, path, goal and frontiers of an episode
whose status has not come yet wait for it (the latest of each, as for a late viewer), at most ``MAP_ORIGIN_WAIT_S``,
and messages of no episode id (0) take the origin last known. The four frames' names are params
(``map_frame``, ``odom_frame``, ``base_frame``, ``laser_frame``: export-bag's ``--map-frame``... with its defaults and
its check, ``BagFrames``), which ``service foxglove_bridge`` also takes as export-bag's four flags (``frame_names``),
and each ``/scan``'s ``scan_time`` is export-bag's period between the scans, read off their stamps as they come by the
same ``ScanPeriod``.

Like ROS's foxglove_bridge, it converts only what someone watches: a topic that no viewer subscribes to (and no
MCAP file takes) is not converted at all, so the bridge costs next to nothing while nobody looks. It keeps the
latest message of each of its inputs instead, and converts it when a viewer subscribes: a viewer that connects
late sees the current map, goal, frontiers, path and robot at once (as latched ROS topics would give it). Nor does it
decode what nobody watches: it keeps each input as it came (``DeferredMsg``: the envelope and step checked, the
arrays still packed and compressed) and decodes it when a viewer watches its topic, as it comes or on subscription.
So a payload whose body is malformed is rejected (logged, counted) when it is decoded, if ever, not when it came;
counted as processed when it came, and if it was the latest of its topic a viewer that subscribes then gets nothing
on that topic until the next message.

It only listens: the episode never waits for it, in lockstep or real time. Start it with ``up --foxglove``,
``services: {foxglove_bridge: {...}}`` in a profile, or alone beside a running episode with
``cso-runtime service foxglove_bridge --config PROFILE --connect ENDPOINT``. Needs the foxglove-sdk package
(``pip install 'cso-runtime[foxglove]'``).
"""

from __future__ import annotations

import argparse
import base64
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from cso_runtime import ros2_cdr
from cso_runtime.bag_export import (
    EXPORTED,
    MAP_FRAME_TOPICS,
    ROS_TOPICS,
    ROS_TYPES,
    BagConverter,
    BagFrames,
    ScanPeriod,
    shows_something,
)
from cso_runtime.config import ConfigError, check_bounds, folder_problem, from_dict, seconds
from cso_runtime.frame_names import BASE_FRAME, LASER_FRAME, MAP_FRAME, ODOM_FRAME, add_frame_arguments, frames_given
from cso_runtime.geometry import Pose2D
from cso_runtime.messages import DeferredMsg, EpisodeStatusMsg, Message, MessageError, deferred, scan_episode_and_stamp
from cso_runtime.recording import unused_path
from services.common import Service, ServiceContext, service_main

log = logging.getLogger("cso.foxglove_bridge")

INSTALL_HINT = "pip install 'cso-runtime[foxglove]' (or pip install foxglove-sdk)"
SERVER_STOP_TIMEOUT_S = 5.0
"""How long ``shutdown`` waits for the Foxglove server to stop: foxglove-sdk's ``stop()`` runs in Rust and, rarely, never
returned (seen once in the test suite, after a viewer's connection closed); a bridge must not hang its stop on it."""
MAP_ORIGIN_WAIT_S = 2.0
"""How long the map, path, goal and frontiers of an episode wait for its status's map origin (the sim publishes its
status with the first map, the ROS 2 bridge with every map) before they go out in the origin last known."""


@dataclass
class FoxgloveBridgeParams:
    """Parameters of the Foxglove bridge (``services.foxglove_bridge`` in a profile)."""

    host: str = "127.0.0.1"
    """Address the WebSocket server listens on (``0.0.0.0``: every interface, to view from another machine)."""
    port: int = 8765
    """Its port (Foxglove's default; 0: a free one, logged)."""
    map_period_s: float = 0.5
    """At most one ``/map`` per this long (wall clock); the newest map always goes out when the episode pauses
    longer. A map of a large plan is a few hundred kB: a viewer needs no more than a couple a second."""
    mcap_path: str = ""
    """Also write every served message to this MCAP file (empty: none), which Foxglove opens afterwards. A file
    already there is kept: the bridge then writes ``<stem>-1.mcap`` (``-2``, ...) beside it, and logs the name."""
    map_frame: str = MAP_FRAME
    """The map frame's name (``export-bag --map-frame``): /map, /plan, /goal_pose, /explore/frontiers, map -> odom."""
    odom_frame: str = ODOM_FRAME
    """The odometry frame's name (``--odom-frame``): /odom, odom -> base_link on /tf, map -> odom."""
    base_frame: str = BASE_FRAME
    """The robot's base frame's name (``--base-frame``): /odom's child, odom -> base_link, base_link -> laser."""
    laser_frame: str = LASER_FRAME
    """The LiDAR's frame's name (``--laser-frame``; ``laser_link`` for the LIMO's ROS driver): /scan's header and
    base_link -> laser on /tf_static."""

    def frames(self) -> BagFrames:
        """The four frames' names, as ``export-bag`` takes them."""
        return BagFrames(self.map_frame, self.odom_frame, self.base_frame, self.laser_frame)

    def validate(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"port must be in 0..65535, got {self.port}")
        check_bounds("", self, seconds("map_period_s"))
        try:
            self.frames().check()  # export-bag's check: tf2 frame ids, four different names
        except ValueError as exc:
            raise ConfigError(str(exc)) from None


def port_problem(params: FoxgloveBridgeParams) -> str | None:
    """Why the bridge could not listen on its address now (the port taken by another viewer's bridge, an address
    not of this machine), or None. ``up`` asks before it starts anything; the bridge itself may still lose a race."""
    if params.port == 0:
        return None
    try:
        with socket.create_server((params.host, params.port)):
            return None
    except OSError as exc:
        return f"cannot listen on {params.host}:{params.port}: {exc.strerror or exc}; --set services.foxglove_bridge.port=0 picks a free port"


def mcap_path_problem(params: FoxgloveBridgeParams) -> str | None:
    """Why the bridge could not write ``mcap_path`` (a file where its folder would be, a folder given as the file, a
    folder it cannot write in), or None; nothing is made. ``up`` asks before it starts anything."""
    if not params.mcap_path:
        return None
    path = Path(params.mcap_path)
    if path.is_dir():
        return f"mcap_path {path} is a folder, not a file (give a file in it, such as {path / 'foxglove.mcap'})"
    problem = folder_problem(path.absolute().parent)
    if problem is None:
        return None
    if not problem.in_the_way:
        return f"mcap_path {path}: cannot write in {problem.existing}"
    return f"mcap_path {path}: {problem.existing} is not a folder"


def websocket_handshake(host: str, port: int, timeout_s: float = 5.0) -> bytes:
    """Open a Foxglove WebSocket connection by hand and close it again; the server's reply to the upgrade request
    (``HTTP/1.1 101 Switching Protocols`` naming ``foxglove.sdk.v1``, when a Foxglove server listens there)."""
    key = base64.b64encode(os.urandom(16)).decode()
    request = (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n")
    with socket.create_connection((host, port), timeout=timeout_s) as conn:
        conn.sendall(request.encode())
        reply = conn.recv(4096)
        conn.sendall(b"\x88\x80\x00\x00\x00\x00")  # a masked, empty close frame: a client that says goodbye
    return reply


class _Subscriptions:
    """The server's listener (on the server's thread): the topics viewers have newly subscribed to, whose latest
    message the bridge's own thread then converts and sends. The server calls ``on_unsubscribe`` too (a panel
    closed, a viewer gone): a listener without it has each call logged as an error. Each call runs through ``guarded``
    (the service's ``Service.guarded``): an exception in it is logged and counted in the service's status, where the
    server only logged it."""

    def __init__(self, guarded: Callable[[Callable[..., None]], Callable[..., None]] = lambda callback: callback) -> None:
        self.new = threading.Event()
        """Set by a subscription, until the bridge takes the topics."""
        self._lock = threading.Lock()
        self._topics: set[str] = set()
        self._on_subscribe = guarded(self.subscribed)
        self._on_unsubscribe = guarded(self.unsubscribed)

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self._on_subscribe(client, channel)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self._on_unsubscribe(client, channel)

    def subscribed(self, client: Any, channel: Any) -> None:
        """A viewer subscribed to ``channel``: its topic is taken on the bridge's thread (``take``)."""
        with self._lock:
            self._topics.add(channel.topic)
        self.new.set()

    def unsubscribed(self, client: Any, channel: Any) -> None:
        """Nothing to do: the server stops sending that channel to that viewer, and the channel then has no sink."""

    def take(self) -> set[str]:
        """The topics subscribed to since the last call."""
        with self._lock:
            topics, self._topics = self._topics, set()
        return topics


class FoxgloveBridgeService(Service):
    """Serves one robot's episode to Foxglove viewers as ROS 2 messages; it only listens, so the episode never waits for it."""

    name = "foxglove_bridge"
    inputs = {**{topic: deferred(cls) for topic, cls in EXPORTED.items()}, "episode_status": EpisodeStatusMsg}  # type: ignore[arg-type]  # a class hashes
    """Each input kept as it came and decoded only when watched (``decoded``); the episode's status, for the scene's
    map origin (``map`` -> ``odom``)."""
    outputs: ClassVar[dict[str, type[Message]]] = {}
    tick_period_s = 0.1

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(FoxgloveBridgeParams, ctx.params, where="services.foxglove_bridge")
        try:
            import foxglove  # noqa: PLC0415  (optional: the `foxglove` extra)
        except ImportError:
            raise ConfigError(f"the Foxglove bridge needs foxglove-sdk: {INSTALL_HINT}") from None
        self.foxglove = foxglove
        self.context = foxglove.Context()
        mount = Pose2D(ctx.exploration.sensor.mount_x_m, 0.0, 0.0)  # where the sim and the ROS 2 bridge put the LiDAR
        self.converter = BagConverter(map_period_s=self.params.map_period_s, time="received", lidar_mount=mount, frames=self.params.frames())
        self.scan_period = ScanPeriod()
        """The period between the robot's scans, as their stamps show it: each /scan's ``scan_time``, as export-bag
        gives the run's bag (the same once ``SCAN_PERIOD_SCANS`` scans came; 0 before two)."""
        self.awaiting_map_origin: set[str] = set()
        """Our topics (``MAP_FRAME_TOPICS``) whose latest came before its episode's map origin: sent when it comes."""
        self.awaiting_since_s: float | None = None
        self.channels = {topic: self._open_channel(topic) for topic in ROS_TYPES}
        """ROS topic -> its channel, every one advertised from the start: a viewer subscribes before anything came."""
        self.latest_shown: dict[str, DeferredMsg] = {}
        """Our topic -> its latest message that shows something, decoded and converted when a viewer subscribes (not
        ``Service.latest``, the messages a service serves on its cache keys: this bridge serves none)."""
        self.served: dict[str, int] = {}
        """ROS topic -> messages served (converted for a viewer or the MCAP file as they came)."""
        self.subscriptions = _Subscriptions(self.guarded)
        self.server: Any = None
        self.mcap: Any = None
        if (problem := mcap_path_problem(self.params)) is not None:  # a configuration error: not restarted to fail again
            raise ConfigError(f"services.foxglove_bridge: {problem}")
        try:  # here, not in warm_up: a port in use is a bad configuration (exit 2, not restarted), said before the episode
            self.server = foxglove.start_server(
                name=f"cso-runtime {ctx.robot}", host=self.params.host, port=self.params.port,
                server_listener=self.subscriptions, context=self.context,  # type: ignore[arg-type]  # duck-typed
            )  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - a port in use, a bad address: the configuration's fault
            raise ConfigError(f"services.foxglove_bridge: cannot serve on {self.params.host}:{self.params.port}: {exc}") from None
        if self.params.mcap_path:
            path = unused_path(Path(self.params.mcap_path))  # a restarted bridge, a second run: keep the earlier file
            path.parent.mkdir(parents=True, exist_ok=True)
            self.mcap = foxglove.open_mcap(str(path), allow_overwrite=False, context=self.context)
            log.info("Foxglove: writing what is served to %s", path)
        log.info("Foxglove: open %s (Open connection -> Foxglove WebSocket), robot %s", self.url, ctx.robot)

    @property
    def url(self) -> str:
        """Where a viewer connects (the real port when ``port`` was 0)."""
        return f"ws://{self.params.host}:{self.server.port if self.server is not None else self.params.port}"

    def _open_channel(self, topic: str) -> Any:
        ros_type = ROS_TYPES[topic]
        definition, _ = ros2_cdr.typestore().generate_msgdef(ros_type, ros_version=2)  # ROS 2's `builtin_interfaces/Time stamp`, as export-bag writes
        schema = self.foxglove.Schema(name=ros_type, encoding="ros2msg", data=definition.encode())
        return self.foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self.context)

    def watched(self, topic: str) -> bool:
        """Whether anything takes ``topic`` now: a viewer subscribed to it, or the MCAP file (which takes all)."""
        return bool(self.channels[topic].has_sinks())

    def serve(self, rows: list[tuple[str, bytes, int]]) -> None:
        for topic, data, t_ns in rows:
            self.channels[topic].log(data, log_time=t_ns)
            self.served[topic] = self.served.get(topic, 0) + 1

    def decoded(self, topic: str, msg: DeferredMsg) -> Message | None:
        """``msg`` on our ``topic`` decoded, or None: rejected (counted, logged) as a malformed payload, and no longer
        the latest of its topic (so rejected once)."""
        try:
            return msg.decoded()
        except MessageError as exc:
            self.reject(topic, str(exc), self.ctx.robot)
            if self.latest_shown.get(topic) is msg:
                del self.latest_shown[topic]
            return None

    def send_latest(self, topic: str) -> None:
        """A viewer has just subscribed to ``topic``: the latest of it, decoded and converted now, so that nothing it
        shows stays empty until the next message (a map or a goal may not change for a long while)."""
        now_ns = time.time_ns()
        if topic == "/tf_static":
            rows = [self.converter.static_transforms(now_ns)]
        else:
            rows = []
            for ours, kept in list(self.latest_shown.items()):  # /tf: both the odometry's and the scan's
                if ours in self.awaiting_map_origin:
                    continue  # it goes out with its map origin
                if topic in ROS_TOPICS[ours] and (msg := self.decoded(ours, kept)) is not None:
                    rows += self.converter.convert(msg, now_ns, wanted=lambda ros_topic: ros_topic == topic, again=True)
        for ros_topic, data, t_ns in rows:
            self.channels[ros_topic].log(data, log_time=t_ns)

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, EpisodeStatusMsg):
            self.serve(self.converter.learn_map_origin(msg.episode, msg.map_origin, time.time_ns(), self.watched))
            self.send_awaiting()
            return
        assert isinstance(msg, DeferredMsg)  # ``inputs``
        self.last_step = msg.step
        episode = msg.kept_body.get("episode")
        if topic == "scan":
            self.learn_scan_period(msg.kept_body)
        if isinstance(episode, int) and not isinstance(episode, bool):  # read before decoding: a bad one fails it later
            self.serve(self.converter.observe_episode(episode, time.time_ns(), self.watched))
        if shows_something(msg):
            self.latest_shown[topic] = msg
        if topic in MAP_FRAME_TOPICS and not self.converter.knows_map_origin():
            self.awaiting_map_origin.add(topic)  # its episode's status comes after the first map
            self.awaiting_since_s = self.awaiting_since_s if self.awaiting_since_s is not None else time.monotonic()
            return
        self.awaiting_map_origin.discard(topic)
        if self.converter.converts(topic, self.watched) and (decoded := self.decoded(topic, msg)) is not None:
            self.serve(self.converter.convert(decoded, time.time_ns(), wanted=self.watched))

    def learn_scan_period(self, body: dict[str, Any]) -> None:
        """One more scan's stamp for ``scan_period`` (read before decoding the scan, by ``ScanMsg``'s own check of its
        episode and stamp, ``scan_episode_and_stamp``: a scan that fails it counts not, and is rejected if it is ever
        decoded), and the converter's ``scan_time`` from it."""
        if self.scan_period.complete:
            return
        try:
            episode, stamp_s = scan_episode_and_stamp(body)
        except MessageError:
            return
        self.scan_period.add(episode, stamp_s)
        self.converter.scan_period_s = self.scan_period.period_s

    def send_awaiting(self) -> None:
        """The latest of each topic that waited for its episode's map origin, now that it is known."""
        if not self.awaiting_map_origin or not self.converter.knows_map_origin():
            return
        topics, self.awaiting_map_origin, self.awaiting_since_s = sorted(self.awaiting_map_origin), set(), None
        for topic in topics:
            kept = self.latest_shown.get(topic)
            if kept is not None and self.converter.converts(topic, self.watched) and (decoded := self.decoded(topic, kept)) is not None:
                self.serve(self.converter.convert(decoded, time.time_ns(), wanted=self.watched))

    def on_tick(self, now_s: float) -> None:
        if self.awaiting_since_s is not None and time.monotonic() - self.awaiting_since_s >= MAP_ORIGIN_WAIT_S:
            episode = self.converter.episode
            log.warning("Foxglove: no status of episode %s in %g s: its map, path, goal and frontiers go out in the last map origin known", episode, MAP_ORIGIN_WAIT_S)
            if episode is not None:
                self.converter.learn_map_origin(episode, self.converter.map_origin, time.time_ns(), self.watched)
            self.send_awaiting()
        if self.subscriptions.new.is_set():
            self.subscriptions.new.clear()
            for topic in sorted(self.subscriptions.take()):
                self.send_latest(topic)
        held = self.converter.pending_map is not None and self.watched("/map")
        if held and time.time_ns() - (self.converter.last_map_ns or 0) >= self.converter.map_period_ns:
            self.serve(self.converter.finish(sent_ns=time.time_ns()))  # the newest map, held back by map_period_s, once nothing newer came

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--port", type=int, default=None, help="WebSocket port (overrides the profile; 0: a free one)")
        parser.add_argument("--mcap", default=None, help="Also write what is served to this MCAP file (overrides mcap_path)")
        add_frame_arguments(parser)  # export-bag's --map-frame, --odom-frame, --base-frame, --laser-frame

    @classmethod
    def apply_arguments(cls, args: argparse.Namespace, params: dict[str, Any]) -> dict[str, Any]:
        given = {"port": args.port, "mcap_path": args.mcap, **frames_given(args)}
        return {**params, **{k: v for k, v in given.items() if v is not None}}

    def shutdown(self) -> None:
        if self.watched("/map"):
            self.serve(self.converter.finish())
        if self.mcap is not None:
            self.mcap.close()
        if self.server is not None:
            stop_server(self.server, SERVER_STOP_TIMEOUT_S)


def stop_server(server: Any, timeout_s: float) -> bool:
    """``server.stop()`` on a thread of its own, waited for at most ``timeout_s``: False (and a warning) when it has not
    returned by then; it is left to the process's exit, which ends it with the process."""
    thread = threading.Thread(target=server.stop, name="foxglove-stop", daemon=True)
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        log.warning("the Foxglove server did not stop within %g s: left to end with the process", timeout_s)
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    """``python -m services.foxglove_bridge``'s entry point; exit code 2 for a bad config."""
    return service_main(FoxgloveBridgeService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
