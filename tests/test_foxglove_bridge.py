"""The Foxglove bridge: a WebSocket server a viewer connects to, fed with export-bag's ROS 2 messages.

The service runs in this process on a free port; what it serves is read back from its MCAP sink (the same
channels and messages as the WebSocket's), and a raw WebSocket handshake checks the server speaks Foxglove's
protocol."""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.reader import make_reader

from cso_runtime import ros2_cdr
from cso_runtime.bag_export import EXPORTED, ROS_TOPICS, ROS_TYPES, BagConverter, BagFrames, shows_something
from cso_runtime.config import ConfigError, ExplorationConfig
from cso_runtime.geometry import Pose2D, compose_pose
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import GoalMsg, Message, MessageError, decode, deferred, encode
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from services.common import ServiceContext, _dispatch
from services.foxglove_bridge import FoxgloveBridgeService, websocket_handshake
from tests.conftest import HANG_DEADLINE_S, wait_for
from tests.test_bag_export import (
    GEOM,
    SCENE_ORIGIN,
    T0_NS,
    _map,
    approx_pose,
    as_tuple,
    bag_frames,
    episode,
    msg_pose,
    read_bag,
    scans_fired_early,
    tf_pose,
    with_status,
)


def _bridge(params: dict, lidar_mount_x_m: float = 0.0) -> FoxgloveBridgeService:
    profile = {"lockstep": True, "services": {"foxglove_bridge": params}}
    exploration = ExplorationConfig()
    exploration.sensor.mount_x_m = lidar_mount_x_m
    ctx = ServiceContext("foxglove_bridge", "r0", profile, exploration, TransportConfig(connect=["tcp/127.0.0.1:1"]), params)
    return FoxgloveBridgeService(ctx)


def _feed(bridge: FoxgloveBridgeService, steps: int) -> None:
    """Steps of a lockstep-like episode (the goal changes at step 2), each payload as the service receives it."""
    for m in episode(RobotKeys("r0"), steps, T0_NS, 1_000_000):
        if m.key.rsplit("/", 1)[1] in bridge.inputs:  # the clock is not an input
            _dispatch(bridge, m.key, m.payload, 0.0)


def _receive(bridge: FoxgloveBridgeService, topic: str, msg: Message | bytes) -> None:
    """One message (or payload) on ``topic`` of robot r0, as the service receives it."""
    _dispatch(bridge, RobotKeys("r0").topic(topic), msg if isinstance(msg, bytes) else encode(msg), 0.0)


def _served(path) -> list[tuple[str, str, object]]:
    """(topic, ROS type, deserialized message) of every message in the MCAP file, in order."""
    store = ros2_cdr.typestore()
    out = []
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
            assert b"\ntime " not in b"\n" + schema.data  # ROS 2 definitions (builtin_interfaces/Time), not ROS 1's `time`
            out.append((channel.topic, schema.name, store.deserialize_cdr(message.data, schema.name)))
    return out


def test_the_bridge_serves_an_episode_as_export_bags_ros_messages(tmp_path):
    mcap = tmp_path / "live.mcap"
    bridge = _bridge({"port": 0, "mcap_path": str(mcap), "map_period_s": 0.0})
    assert bridge.server.port > 0 and bridge.url == f"ws://127.0.0.1:{bridge.server.port}"
    reply = websocket_handshake("127.0.0.1", bridge.server.port)
    assert reply.startswith(b"HTTP/1.1 101") and b"foxglove.sdk.v1" in reply
    _feed(bridge, 3)
    for topic in ("/map", "/tf_static"):  # a viewer subscribes late: the latest of each again
        bridge.subscriptions.on_subscribe(None, SimpleNamespace(topic=topic))
    bridge.on_tick(0.0)
    bridge.shutdown()
    served = _served(mcap)
    counts = Counter(topic for topic, _, _ in served)
    assert counts == {"/tf_static": 2, "/odom": 3, "/tf": 6, "/scan": 3, "/map": 4, "/explore/frontiers": 2,
                      "/goal_pose": 2, "/plan": 3, "/cmd_vel": 3}, counts
    assert {topic: ros_type for topic, ros_type, _ in served} == {topic: ROS_TYPES[topic] for topic in counts}
    last_map = [m for topic, _, m in served if topic == "/map"][-1]
    expected = _map(2).grid
    assert (last_map.info.height, last_map.info.width) == expected.shape and last_map.header.frame_id == "map"
    assert np.array_equal(np.asarray(last_map.data).reshape(expected.shape), expected)  # -1/0/100, row 0 at the bottom
    assert bridge.served["/map"] == 3  # the fourth is the latest one sent again


def test_maps_are_thinned_to_map_period_s_and_the_newest_still_goes_out(tmp_path):
    mcap = tmp_path / "thin.mcap"
    bridge = _bridge({"port": 0, "mcap_path": str(mcap), "map_period_s": 3600.0})
    for step in range(3):
        _receive(bridge, "map", _map(step))
    assert bridge.served["/map"] == 1 and bridge.converter.pending_map is not None
    bridge.on_tick(0.0)  # within the period: still held
    assert bridge.served["/map"] == 1
    bridge.converter.map_period_ns = 0  # the period has passed and nothing newer came
    bridge.on_tick(0.0)
    assert bridge.served["/map"] == 2 and bridge.converter.pending_map is None
    bridge.shutdown()
    maps = [m for topic, _, m in _served(mcap) if topic == "/map"]
    assert np.array_equal(np.asarray(maps[-1].data).reshape(_map(2).grid.shape), _map(2).grid)
    again = _bridge({"port": 0, "mcap_path": str(mcap)})  # a restarted bridge, or the same profile run again
    _receive(again, "map", _map(0))
    again.shutdown()
    assert len([m for topic, _, m in _served(mcap) if topic == "/map"]) == 2  # the earlier file is kept whole
    assert [topic for topic, _, _ in _served(tmp_path / "thin-1.mcap")] == ["/tf_static", "/map"]


def test_a_map_sent_when_it_stopped_being_held_starts_the_next_period():
    """The held map a live viewer is sent late (``finish(sent_ns)``) counts as the last map sent: the next map
    within ``map_period_s`` of it is held too, instead of going out at once against the one before it."""
    period_ns = 500_000_000
    converter = BagConverter(map_period_s=period_ns / 1e9, time="received")

    def topics(rows: list[tuple[str, bytes, int]]) -> list[str]:
        return [topic for topic, _, _ in rows]

    assert "/map" in topics(converter.convert(_map(0), 0))
    assert "/map" not in topics(converter.convert(_map(1), 100_000_000))  # held
    assert topics(converter.finish(sent_ns=600_000_000)) == ["/map"]  # sent on the bridge's tick, later
    assert "/map" not in topics(converter.convert(_map(2), 700_000_000))  # 0.1 s after that one: held as well
    assert converter.pending_map is not None and converter.last_map_ns == 600_000_000
    assert "/map" in topics(converter.convert(_map(3), 1_200_000_000))  # a period after the late one


def test_the_converter_converts_only_wanted_topics_and_sends_the_latest_again_at_once():
    """What the bridge builds on: a topic nobody wants is neither converted nor held back (a map held for a viewer
    that has left never goes out over a newer one), and ``again`` sends a viewer that has just subscribed the
    latest map or goal even within ``map_period_s`` of the last one, or when the goal has not changed."""
    from cso_runtime.messages import GoalMsg

    def only(*wanted: str):
        return lambda topic: topic in wanted

    def topics(rows: list[tuple[str, bytes, int]]) -> list[str]:
        return [topic for topic, _, _ in rows]

    converter = BagConverter(map_period_s=0.5, time="received")
    assert converter.convert(_map(0), 0, wanted=only()) == [] and (converter.last_map_ns, converter.pending_map) == (None, None)
    assert topics(converter.convert(_map(0), 100_000_000, wanted=only("/map"))) == ["/map"]  # no /tf_static: not wanted
    assert converter.convert(_map(1), 200_000_000, wanted=only("/map")) == [] and converter.pending_map is not None  # held
    assert converter.convert(_map(2), 300_000_000, wanted=only()) == []  # the viewer has left
    latest = _map(3)
    assert converter.convert(latest, 400_000_000, wanted=only()) == []
    rows = converter.convert(latest, 450_000_000, wanted=only("/map"), again=True)  # a viewer subscribes
    assert topics(rows) == ["/map"] and converter.pending_map is None and converter.last_map_ns == 450_000_000
    assert np.array_equal(ros2_cdr.occupancy_grid_from_cdr(rows[0][1])[0], latest.grid)
    goal = GoalMsg(4, True, 3.0, -1.0, 0, 1.0, 2.0, "greedy-dist")
    assert converter.convert(goal, 500_000_000, wanted=only()) == []
    assert converter.convert(goal, 600_000_000, wanted=only("/goal_pose")) == []  # not a new goal
    assert topics(converter.convert(goal, 700_000_000, wanted=only("/goal_pose"), again=True)) == ["/goal_pose"]
    assert topics([converter.static_transforms(800_000_000)]) == ["/tf_static"]
    assert topics(converter.convert(goal, 900_000_000, again=True)) == ["/goal_pose"]  # /tf_static was sent already


def test_a_port_in_use_a_bad_port_or_no_foxglove_sdk_is_a_configuration_error(monkeypatch):
    first = _bridge({"port": 0})
    try:
        with pytest.raises(ConfigError, match=f"cannot serve on 127.0.0.1:{first.server.port}"):
            _bridge({"port": first.server.port})
    finally:
        first.shutdown()
    with pytest.raises(ConfigError, match="port must be in 0..65535"):
        _bridge({"port": 70000})
    monkeypatch.setitem(sys.modules, "foxglove", None)
    with pytest.raises(ConfigError, match=r"pip install 'cso-runtime\[foxglove\]'"):
        _bridge({"port": 0})


def test_up_foxglove_adds_the_bridge_once_and_refuses_it_without_the_sdk_or_its_port(monkeypatch):
    import services.foxglove_bridge as bridge_module
    from cso_runtime.run_profile import load_profile
    from cso_runtime.transport import free_tcp_port

    port = free_tcp_port()
    with socket.create_server(("127.0.0.1", port)), pytest.raises(ConfigError, match=f"cannot listen on 127.0.0.1:{port}: .*port=0 picks a free port"):
        load_profile("sim", {}, foxglove=True, settings={"services.foxglove_bridge.port": port})  # another viewer's bridge holds it
    monkeypatch.setattr(bridge_module, "port_problem", lambda params: None)  # whether 8765 is free here does not matter
    prof, data = load_profile("sim", {}, foxglove=True)
    assert list(prof.services) == ["sim", "mapper", "frontier", "policy", "planner", "foxglove_bridge"]
    assert data["services"]["foxglove_bridge"] == {}
    prof, _ = load_profile("sim", {}, foxglove=True, settings={"services.foxglove_bridge.port": 9000})
    assert prof.services["foxglove_bridge"] == {"port": 9000}  # the profile's own parameters are kept
    assert "foxglove_bridge" not in load_profile("sim", {})[0].services
    import importlib.util

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "foxglove" else real_find_spec(name, *a))
    with pytest.raises(ConfigError, match=r"up --foxglove\) needs foxglove-sdk: pip install 'cso-runtime\[foxglove\]'"):
        load_profile("sim", {}, foxglove=True)


def test_the_live_view_says_where_to_point_foxglove(tmp_path, monkeypatch):
    from rich.console import Console

    import services.foxglove_bridge as bridge_module
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.run_profile import load_profile

    monkeypatch.setattr(bridge_module, "port_problem", lambda params: None)
    profile, data = load_profile("lockstep", {}, foxglove=True, settings={"services.foxglove_bridge.port": 9123})
    launcher = Launcher(profile, data, tmp_path / "run")
    # A child as the launcher's status reads it too (the live view shows what `status` does).
    launcher.children.append(SimpleNamespace(name="foxglove_bridge", alive=True, gave_up=False, proc=None, restarts=0, hung_kills=0, robot_stops=0, command=None, came_up=False))
    console = Console(width=200, record=True)
    console.print(LiveView(launcher).render())
    assert "foxglove_bridge │ starting, pid -, restarts 0; Foxglove: open ws://127.0.0.1:9123" in console.export_text()
    narrow = Console(width=40, record=True)  # the URL wraps over two lines, but all of it is there
    narrow.print(LiveView(launcher).render())
    text = narrow.export_text()
    assert "…" not in text
    assert "ws://127.0.0.1:9123" in "".join(line.split("│")[2].strip() for line in text.splitlines() if line.count("│") == 3)


class _Viewer:
    """A bare Foxglove WebSocket client on loopback: text frames only, enough to subscribe and unsubscribe."""

    def __init__(self, port: int):
        import base64
        import os

        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                           f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode())
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self.buf += self.sock.recv(4096)
        assert self.buf.startswith(b"HTTP/1.1 101"), self.buf
        self.buf = self.buf.split(b"\r\n\r\n", 1)[1]

    def _read(self, n: int) -> bytes:
        while len(self.buf) < n:
            chunk = self.sock.recv(65536)
            assert chunk, "the server closed the connection"
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def _frame(self) -> tuple[int, bytes]:
        """The next frame from the server (unmasked, unfragmented): its WebSocket opcode and payload."""
        import struct

        head = self._read(2)
        n = head[1] & 0x7F
        n = struct.unpack(">H", self._read(2))[0] if n == 126 else struct.unpack(">Q", self._read(8))[0] if n == 127 else n
        return head[0] & 0x0F, self._read(n)

    def json_op(self, op: str) -> dict:
        """The next text message whose ``op`` is ``op`` (binary message data is skipped)."""
        import json

        while True:
            kind, payload = self._frame()
            if kind == 1 and (msg := json.loads(payload))["op"] == op:
                return msg

    def message_data(self) -> tuple[int, bytes]:
        """The next message the server sends on a subscription (text messages are skipped): its subscription id
        and the message (Foxglove's binary "message data": opcode 1, subscription id, log time, message)."""
        import struct

        while True:
            kind, payload = self._frame()
            if kind == 2 and payload[0] == 1:
                return struct.unpack("<I", payload[1:5])[0], payload[13:]

    def send(self, msg: dict) -> None:
        import json
        import struct

        data = json.dumps(msg).encode()  # a zero mask: the payload goes as it is
        self.sock.sendall(bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(data)) + b"\0\0\0\0" + data)

    def close(self) -> None:
        self.sock.sendall(b"\x88\x80\x00\x00\x00\x00")
        self.sock.close()


def _subscribe(bridge: FoxgloveBridgeService, viewer: _Viewer, sub_id: int, channel_id: int) -> None:
    """Subscribe and wait until the bridge's listener has heard of it (its callback has run)."""
    bridge.subscriptions.new.clear()
    viewer.send({"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": channel_id}]})
    wait_for(bridge.subscriptions.new.is_set, 5.0, f"the bridge to hear of subscription {sub_id}")


def test_a_viewer_that_subscribes_and_unsubscribes_gets_no_error_logged(caplog):
    """Foxglove unsubscribes whenever a panel closes or the viewer leaves; the server calls the listener's
    ``on_unsubscribe`` then, which the bridge once lacked: each call was logged as an ERROR
    ("Callback failed: AttributeError...")."""
    import logging

    bridge = _bridge({"port": 0, "map_period_s": 0.0})
    try:
        _receive(bridge, "map", _map(0))
        viewer = _Viewer(bridge.server.port)
        channels = {c["topic"]: c["id"] for c in viewer.json_op("advertise")["channels"]}
        assert {"/map", "/tf_static"} <= set(channels)
        with caplog.at_level(logging.WARNING):
            _subscribe(bridge, viewer, 1, channels["/map"])  # the latest map goes out again on the next tick
            viewer.send({"op": "unsubscribe", "subscriptionIds": [1]})
            _subscribe(bridge, viewer, 2, channels["/map"])  # handled after the unsubscription: its callback has run (and logged whatever it did)
            viewer.close()
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert errors == []
    finally:
        bridge.shutdown()


def test_nothing_is_converted_for_a_topic_nobody_watches_and_a_late_viewer_gets_the_latest(monkeypatch):
    """Like ROS's foxglove_bridge, the bridge converts only the topics a viewer subscribes to: with no viewer (and
    no MCAP file) an episode costs it no conversion at all (it once converted every message for nobody). A viewer that subscribes later is sent the latest map and goal at once, converted then;
    after that, what it subscribes to goes out as it comes, and what it does not stays unconverted."""
    conversions: Counter = Counter()
    for name in [n for n in dir(ros2_cdr) if n.endswith("_to_cdr")]:

        def counted(*args, _real=getattr(ros2_cdr, name), _name=name, **kwargs):
            conversions[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(ros2_cdr, name, counted)
    bridge = _bridge({"port": 0, "map_period_s": 0.0})
    try:
        _feed(bridge, 3)
        assert conversions == Counter() and bridge.served == {}
        viewer = _Viewer(bridge.server.port)
        channels = {c["topic"]: c["id"] for c in viewer.json_op("advertise")["channels"]}
        assert set(channels) == set(ROS_TYPES)  # every topic is offered, though none has been sent yet
        _subscribe(bridge, viewer, 1, channels["/map"])
        _subscribe(bridge, viewer, 2, channels["/goal_pose"])
        bridge.on_tick(0.0)
        assert conversions == {"occupancy_grid_to_cdr": 1, "pose_stamped_to_cdr": 1}
        received = dict(viewer.message_data() for _ in range(2))
        grid, _ = ros2_cdr.occupancy_grid_from_cdr(received[1])
        assert np.array_equal(grid, _map(2).grid)  # the latest map, not the first
        goal, _ = ros2_cdr.pose_stamped_from_cdr(received[2])
        assert (goal.x_m, goal.y_m) == (3.0, -1.0)  # the goal of step 2, sent at step 2 when nobody watched
        _feed(bridge, 1)  # another step (a new goal): its map and goal go out, its scan, odometry, path... do not
        assert conversions == {"occupancy_grid_to_cdr": 2, "pose_stamped_to_cdr": 2}
        assert bridge.served == {"/map": 1, "/goal_pose": 1}
        received = dict(viewer.message_data() for _ in range(2))
        assert np.array_equal(ros2_cdr.occupancy_grid_from_cdr(received[1])[0], _map(0).grid)
        assert ros2_cdr.pose_stamped_from_cdr(received[2])[0].x_m == 1.0
        viewer.close()
        wait_for(lambda: not bridge.watched("/map") and not bridge.watched("/goal_pose"), HANG_DEADLINE_S, "the viewer's subscriptions to end")
        _feed(bridge, 3)
        bridge.shutdown()  # nor at the end
        assert conversions == {"occupancy_grid_to_cdr": 2, "pose_stamped_to_cdr": 2}
    finally:
        bridge.shutdown()


def _count_decodes(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """Schema -> bodies decoded (checked, arrays unpacked and inflated) from now on, of every input of the bridge."""
    decodes: Counter = Counter()
    for cls in set(EXPORTED.values()):

        def counted(klass, body, *args, _real=cls.from_body.__func__, **kwargs):
            decodes[klass.SCHEMA] += 1
            return _real(klass, body, *args, **kwargs)

        monkeypatch.setattr(cls, "from_body", classmethod(counted))
    return decodes


def test_with_no_viewer_nothing_is_decoded_and_a_late_viewer_gets_the_latest_decoded_then(monkeypatch):
    """With no viewer the bridge keeps each input as it came and decodes none (it once decoded every message, its
    arrays unpacked and its maps inflated, to convert none of them): only its envelope and step are read, for the
    service's step and the latest that shows something. A viewer that subscribes later gets the latest map at once,
    decoded then; after that the watched topics are decoded as they come, the others still not."""
    decodes = _count_decodes(monkeypatch)
    bridge = _bridge({"port": 0, "map_period_s": 0.0})
    try:
        _feed(bridge, 3)
        assert decodes == Counter() and bridge.rejected == {}
        assert bridge.last_step == 2 and bridge.processed == 3 * len(EXPORTED)
        viewer = _Viewer(bridge.server.port)
        channels = {c["topic"]: c["id"] for c in viewer.json_op("advertise")["channels"]}
        _subscribe(bridge, viewer, 1, channels["/map"])
        _subscribe(bridge, viewer, 2, channels["/explore/frontiers"])
        bridge.on_tick(0.0)
        assert decodes == {"map": 1, "frontiers": 1}  # the latest map, and the latest frontiers that decided
        received = dict(viewer.message_data() for _ in range(2))
        assert np.array_equal(ros2_cdr.occupancy_grid_from_cdr(received[1])[0], _map(2).grid)
        _feed(bridge, 1)
        assert decodes == {"map": 2, "frontiers": 2}
        assert np.array_equal(ros2_cdr.occupancy_grid_from_cdr(dict([viewer.message_data()])[1])[0], _map(0).grid)
        viewer.close()
    finally:
        bridge.shutdown()


def _corrupt_map() -> bytes:
    """A map payload whose envelope is fine and whose explored grid does not inflate."""
    import msgpack

    raw = msgpack.unpackb(encode(_map(1)))
    raw["body"]["explored"]["data"] = b"not zlib"
    return msgpack.packb(raw, use_bin_type=True)


def test_a_malformed_payload_is_rejected_when_it_is_decoded(monkeypatch, caplog):
    """Decoding is deferred until someone watches: a payload whose body is malformed is rejected (counted, logged)
    when a viewer subscribes to its topic, once; one whose envelope is not even a message's, at once. The malformed
    one was the latest, so a viewer that subscribes then gets no map until the next good one (before, the bad map was
    rejected on arrival and the viewer got the map before it). While watched, a bad map is rejected as it comes."""
    import logging

    bridge = _bridge({"port": 0, "map_period_s": 0.0})
    try:
        _receive(bridge, "map", _map(0))
        _receive(bridge, "map", _corrupt_map())
        _receive(bridge, "map", b"not a message")
        assert bridge.rejected == {"map": 1}
        viewer = _Viewer(bridge.server.port)
        channels = {c["topic"]: c["id"] for c in viewer.json_op("advertise")["channels"]}
        with caplog.at_level(logging.WARNING):
            _subscribe(bridge, viewer, 1, channels["/map"])
            bridge.on_tick(0.0)
        assert bridge.rejected == {"map": 2}
        assert any("rejected payload on map" in r.getMessage() and "explored" in r.getMessage() for r in caplog.records)
        viewer.send({"op": "unsubscribe", "subscriptionIds": [1]})
        _subscribe(bridge, viewer, 2, channels["/map"])  # the viewer subscribes again
        bridge.on_tick(0.0)
        assert bridge.rejected == {"map": 2}  # counted once: it is no longer the latest
        _receive(bridge, "map", _corrupt_map())
        assert bridge.rejected == {"map": 3}  # watched: decoded, and rejected, as it comes
        _receive(bridge, "map", _map(2))
        sub_id, data = viewer.message_data()  # the good map, and nothing before it
        assert sub_id == 2 and np.array_equal(ros2_cdr.occupancy_grid_from_cdr(data)[0], _map(2).grid)
        viewer.close()
    finally:
        bridge.shutdown()


def test_a_message_kept_undecoded_is_judged_as_it_decodes_and_converts_to_its_ros_topics_only():
    """What the bridge decides before decoding holds to what decoding gives: the step, whether it shows something
    (a deciding frontiers message, a goal with a goal), and which ROS topics it converts to (``ROS_TOPICS``: a message
    none of whose topics is watched is never decoded)."""
    converter = BagConverter(map_period_s=0.0, time="received")
    messages = episode(RobotKeys("r0"), 3, T0_NS, 1_000_000)
    converted: set[str] = set()
    for topic, payload in [(m.key.rsplit("/", 1)[1], m.payload) for m in messages] + [("goal", encode(GoalMsg(3, True)))]:
        if topic not in EXPORTED:
            continue
        kept = decode(payload, deferred(EXPORTED[topic]))
        msg = kept.decoded()
        assert type(msg) is EXPORTED[topic] and kept.step == msg.step and encode(kept) == payload
        assert shows_something(kept) == shows_something(msg)
        own, others = set(ROS_TOPICS[topic]), set(ROS_TYPES) - set(ROS_TOPICS[topic]) - {"/tf_static"}
        assert converter.converts(topic, own.__contains__) and not converter.converts(topic, others.__contains__)
        rows = {ros_topic for ros_topic, _, _ in converter.convert(msg, T0_NS, again=True)} - {"/tf_static"}
        assert rows <= own, (topic, rows)
        converted |= rows
    assert converted == set(ROS_TYPES) - {"/tf_static"}
    assert {shows_something(decode(encode(m), deferred(type(m)))) for m in (GoalMsg(3, True), _map(0))} == {False, True}


def _header_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def test_the_bridge_places_a_map_server_scene_in_its_map_frame_as_export_bag_does(tmp_path):
    """A map_server scene whose ``origin`` is not zero, live: ``map`` -> ``odom`` is the scene's map origin (from the
    episode's status, an input of the bridge now), the map, goal, path and frontiers are in the map frame, the laser
    hangs from ``base_link`` by the profile's LiDAR mount, each scan exactly at its sensor pose, and the odometry has a
    covariance. The status comes after the first map: that map waits for it, and goes out in the map frame too.
    Before, everything was in the plan's frame with map -> odom the identity, the laser under odom, no covariance."""
    mcap = tmp_path / "scene.mcap"
    bridge = _bridge({"port": 0, "mcap_path": str(mcap), "map_period_s": 0.0}, lidar_mount_x_m=0.103)
    keys = RobotKeys("r0")
    messages = with_status(episode(keys, 3, T0_NS, 1_000_000, episode_id=7), keys, 7, SCENE_ORIGIN)
    for m in messages:
        if m.key == keys.episode_status:
            assert bridge.served.get("/map", 0) == 0  # step 0's map waits for its episode's map origin
        if m.key.rsplit("/", 1)[1] in bridge.inputs or m.key == keys.episode_status:
            _dispatch(bridge, m.key, m.payload, 0.0)
    bridge.shutdown()
    served = [(topic, m) for topic, _, m in _served(mcap)]

    statics = [(i, m) for i, (topic, m) in enumerate(served) if topic == "/tf_static"]
    last = {(tf.header.frame_id, tf.child_frame_id): tf_pose(tf) for tf in statics[-1][1].transforms}
    assert as_tuple(last[("map", "odom")]) == approx_pose(SCENE_ORIGIN)
    assert as_tuple(last[("base_link", "laser")]) == approx_pose(Pose2D(0.103, 0.0, 0.0))
    maps = [(i, m) for i, (topic, m) in enumerate(served) if topic == "/map"]
    assert len(maps) == 3 and maps[0][0] > statics[-1][0]  # the first map after map -> odom is known
    corner = compose_pose(SCENE_ORIGIN, Pose2D(GEOM.origin_x_m, GEOM.origin_y_m, 0.0))
    assert all(m.header.frame_id == "map" and as_tuple(msg_pose(m.info.origin)) == approx_pose(corner) for _, m in maps)
    goals = [m for topic, m in served if topic == "/goal_pose"]
    first_goal = compose_pose(SCENE_ORIGIN, Pose2D(1.0, 2.0, 0.0))
    assert (goals[0].header.frame_id, goals[0].pose.position.x, goals[0].pose.position.y) == ("map", pytest.approx(first_goal.x_m), pytest.approx(first_goal.y_m))
    for odom in [m for topic, m in served if topic == "/odom"]:
        assert list(np.asarray(odom.pose.covariance).reshape(6, 6).diagonal()) == [0.1, 0.1, 0.1, 1.0, 1.0, 1.0]
    base_at = {_header_ns(tf): tf_pose(tf) for topic, m in served if topic == "/tf" for tf in m.transforms if tf.child_frame_id == "base_link"}
    scans = [m for topic, m in served if topic == "/scan"]
    assert len(scans) == 3
    for k, scan in enumerate(scans):  # the recorded sensor pose, which is not the odometry pose plus 0.103 m
        laser = compose_pose(base_at[_header_ns(scan)], last[("base_link", "laser")])
        assert as_tuple(laser) == approx_pose(Pose2D(0.1 * k + 0.1, 0.0, 0.05 * k), 1e-12)


def test_a_map_that_no_status_places_waits_only_so_long(tmp_path, monkeypatch):
    """An episode whose status never comes (lost, or a publisher that sends none): its map goes out in the map origin
    last known once ``MAP_ORIGIN_WAIT_S`` has passed."""
    import services.foxglove_bridge as bridge_module

    mcap = tmp_path / "nostatus.mcap"
    bridge = _bridge({"port": 0, "mcap_path": str(mcap), "map_period_s": 0.0})
    try:
        _receive(bridge, "map", _map(0, episode_id=9))
        bridge.on_tick(0.0)
        assert bridge.served.get("/map", 0) == 0
        monkeypatch.setattr(bridge_module, "MAP_ORIGIN_WAIT_S", 0.0)
        bridge.on_tick(0.0)
        assert bridge.served["/map"] == 1
        _receive(bridge, "map", _map(1, episode_id=9))
        assert bridge.served["/map"] == 2
    finally:
        bridge.shutdown()


def test_an_mcap_path_the_bridge_cannot_write_is_a_configuration_error_said_before_the_run(tmp_path, monkeypatch):
    """A file where the MCAP file's folder should be, or a folder given as the file: refused when ``up`` loads the
    profile and by the bridge itself (exit 2, not restarted), not a bridge that crashes three times and then stops the
    run with no results."""
    import services.foxglove_bridge as bridge_module
    from cso_runtime.run_profile import load_profile

    (tmp_path / "notes.txt").write_text("a file")
    in_a_file = str(tmp_path / "notes.txt" / "fox.mcap")
    for mcap_path, why in ((in_a_file, "notes.txt is not a folder"), (str(tmp_path), "is a folder, not a file")):
        with pytest.raises(ConfigError, match=f"services.foxglove_bridge: mcap_path .*{why}"):
            _bridge({"port": 0, "mcap_path": mcap_path})
        with pytest.raises(ConfigError, match=f"services.foxglove_bridge: mcap_path .*{why}"):
            load_profile("sim", {}, foxglove=True, settings={"services.foxglove_bridge.port": 0, "services.foxglove_bridge.mcap_path": mcap_path})
    monkeypatch.setattr(bridge_module, "port_problem", lambda params: None)
    new_folder = tmp_path / "new" / "fox.mcap"  # a folder not made yet is fine: the bridge makes it
    assert load_profile("sim", {}, foxglove=True, settings={"services.foxglove_bridge.mcap_path": str(new_folder)})[0]
    assert not (tmp_path / "new").exists()  # loading a profile writes nothing


def test_the_bridges_mcap_path_and_evals_out_are_checked_by_one_walk_to_the_nearest_folder(tmp_path, monkeypatch):
    """``mcap_path_problem`` and ``check_output_dir`` each walked up to the nearest existing folder and asked the same
    questions (a file in the way, a folder this process cannot write in): one helper, ``folder_problem``, now answers
    both, each in its own words. Root ignores modes, so the unwritable folder is one ``os.access`` says no to."""
    import errno
    import os

    from cso_runtime.config import FolderProblem, check_output_dir, folder_problem
    from services.foxglove_bridge import FoxgloveBridgeParams, mcap_path_problem

    (tmp_path / "notes.txt").write_text("a file")
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != locked and real_access(path, mode))
    cases = {
        tmp_path / "new" / "deeper": None,
        tmp_path: None,
        tmp_path / "notes.txt": FolderProblem(tmp_path / "notes.txt", errno.EEXIST),
        tmp_path / "notes.txt" / "below": FolderProblem(tmp_path / "notes.txt", errno.ENOTDIR),
        locked: FolderProblem(locked, errno.EACCES),
        locked / "new": FolderProblem(locked, errno.EACCES),
    }
    for folder, expected in cases.items():
        assert folder_problem(folder) == expected, folder
    assert mcap_path_problem(FoxgloveBridgeParams(mcap_path=str(tmp_path / "new" / "f.mcap"))) is None
    assert mcap_path_problem(FoxgloveBridgeParams(mcap_path=str(locked / "f.mcap"))) == f"mcap_path {locked / 'f.mcap'}: cannot write in {locked}"
    below = tmp_path / "notes.txt" / "f.mcap"
    assert mcap_path_problem(FoxgloveBridgeParams(mcap_path=str(below))) == f"mcap_path {below}: {tmp_path / 'notes.txt'} is not a folder"
    with pytest.raises(ConfigError, match=r"^--out .*locked: cannot write in the folder \(Permission denied\)$"):
        check_output_dir(locked)
    with pytest.raises(ConfigError, match=r"^--out .*new: cannot create the folder \(Permission denied\)$"):
        check_output_dir(locked / "new")
    with pytest.raises(ConfigError, match=r"^--out .*below: cannot create the folder \(Not a directory\)$"):
        check_output_dir(tmp_path / "notes.txt" / "below")
    with pytest.raises(ConfigError, match=r"^--out .*notes.txt: cannot create the folder \(File exists\)$"):
        check_output_dir(tmp_path / "notes.txt")


def test_a_foxglove_server_that_never_stops_does_not_hang_the_bridges_shutdown(caplog, monkeypatch):
    """foxglove-sdk's ``stop()`` once never returned in the test suite (in Rust, after a viewer's connection closed),
    and the bridge's shutdown, and the whole test run, hung on it. The bridge waits ``SERVER_STOP_TIMEOUT_S`` at
    most, says so, and goes on; a server that stops is waited for."""
    import services.foxglove_bridge as fb

    release = threading.Event()
    stuck = SimpleNamespace(stop=lambda: release.wait(60))
    start = time.monotonic()
    try:
        assert fb.stop_server(stuck, 0.2) is False
        assert time.monotonic() - start < 5.0 and "did not stop within 0.2 s" in caplog.text
    finally:
        release.set()
    stopped: list[bool] = []
    assert fb.stop_server(SimpleNamespace(stop=lambda: stopped.append(True)), 5.0) is True and stopped == [True]
    bridge = _bridge({"port": 0, "map_period_s": 0.0})
    real_server = bridge.server
    monkeypatch.setattr(fb, "SERVER_STOP_TIMEOUT_S", 0.2)
    bridge.server = stuck
    release.clear()
    start = time.monotonic()
    try:
        bridge.shutdown()
        assert time.monotonic() - start < 5.0
    finally:
        release.set()
        real_server.stop()


def test_evals_dry_run_refuses_the_folders_the_run_would_refuse_though_root_passes_os_access(tmp_path):
    """Root passes every ``os.access`` check, /proc included, so ``eval --dry-run --out /proc/new`` said "a new folder"
    and the run itself then stopped at ``make_output_dir`` (``cannot create the folder``). ``folder_problem`` now also
    tries what the run will do in the nearest existing folder (a folder made there, or a file written in it, removed at
    once), and the dry run says the run's own words; a folder it can write in is left as it was."""
    from cso_runtime.config import check_output_dir, folder_problem, make_output_dir
    from services.foxglove_bridge import FoxgloveBridgeParams, mcap_path_problem

    for folder in (Path("/proc"), Path("/proc/new")):
        with pytest.raises(ConfigError) as run:
            make_output_dir(folder)
        with pytest.raises(ConfigError) as dry_run:
            check_output_dir(folder)
        assert str(dry_run.value) == str(run.value), folder
    assert mcap_path_problem(FoxgloveBridgeParams(mcap_path="/proc/new/f.mcap")) == "mcap_path /proc/new/f.mcap: cannot write in /proc"
    assert folder_problem(tmp_path) is None and folder_problem(tmp_path / "new" / "deeper") is None
    assert list(tmp_path.iterdir()) == []  # the probes are gone


def test_the_bridges_scans_carry_the_scan_period_export_bag_gives_the_same_run(tmp_path):
    """The live /scan said ``scan_time`` 0 where ``export-bag`` of the same run says the period between its scans: both
    read it off the scans' stamps with one ``ScanPeriod`` (the bag its first scans before it writes, the bridge the
    scans as they come), so the bridge says the bag's once it has seen as many scans (0 before two), whether a scan
    fired early or one was lost; ``time_increment`` 0 in both."""
    from cso_runtime.bag_export import export_bag
    from cso_runtime.messages import ScanMsg
    from cso_runtime.recording import write_recording

    keys = RobotKeys("r0")
    messages = scans_fired_early(episode(keys, 6, T0_NS, 2_000_000), keys, 0.1)
    run = [m for m in messages if not (m.key == keys.scan and decode(m.payload, ScanMsg).step == 4)]  # a scan lost
    write_recording(tmp_path / "run.mcap", "r0", run)
    stats = export_bag(tmp_path / "run.mcap", tmp_path / "bag")
    bagged = [m.scan_time for _, m in read_bag(tmp_path / "bag")["/scan"]]
    bridge = _bridge({"port": 0, "mcap_path": str(tmp_path / "live.mcap")})
    for m in run:
        if m.key.rsplit("/", 1)[1] in bridge.inputs:
            _dispatch(bridge, m.key, m.payload, 0.0)
    bridge.shutdown()
    live = [m for topic, _, m in _served(tmp_path / "live.mcap") if topic == "/scan"]
    assert bagged == [0.25] * 5 and stats.scan_period_s == bridge.converter.scan_period_s == 0.25
    assert [s.scan_time for s in live] == pytest.approx([0.0, 0.15, 0.2, 0.25, 0.25], rel=1e-6)  # float32 and all(s.time_increment == 0.0 for s in live)


def test_the_bridge_names_its_frames_as_export_bag_does_and_checks_them_alike(tmp_path, monkeypatch):
    """``export-bag --laser-frame laser_link`` (and the map, odom and base frames) matched the bag to a LIMO's TF tree,
    but the live bridge said ``laser`` beside it. Its params ``map_frame``, ``odom_frame``, ``base_frame`` and
    ``laser_frame`` (export-bag's defaults) name them in every header and transform; ``up --foxglove --set
    services.foxglove_bridge.laser_frame=...`` passes them, and a name tf2 refuses or one frame named twice is refused
    before anything starts, in export-bag's words (``BagFrames.check``)."""
    import services.foxglove_bridge as bridge_module
    from cso_runtime.run_profile import load_profile

    mcap = tmp_path / "limo.mcap"
    names = {"map_frame": "world", "odom_frame": "odom_wheel", "base_frame": "base_footprint", "laser_frame": "laser_link"}
    bridge = _bridge({"port": 0, "mcap_path": str(mcap), "map_period_s": 0.0, **names})
    _feed(bridge, 3)
    bridge.shutdown()
    served: dict[str, list[tuple[int, object]]] = {}
    for topic, _, m in _served(mcap):
        served.setdefault(topic, []).append((0, m))
    assert bag_frames(served) == {
        "/scan": {"laser_link"}, "/tf_static": {"world", "odom_wheel", "base_footprint", "laser_link"},
        "/tf": {"odom_wheel", "base_footprint"}, "/odom": {"odom_wheel", "base_footprint"},
        "/map": {"world"}, "/plan": {"world"}, "/goal_pose": {"world"}, "/explore/frontiers": {"world"}, "/cmd_vel": set(),
    }  # fmt: skip

    monkeypatch.setattr(bridge_module, "port_problem", lambda params: None)
    prof, _ = load_profile("sim", {}, foxglove=True, settings={"services.foxglove_bridge.laser_frame": "laser_link"})
    assert prof.services["foxglove_bridge"] == {"laser_frame": "laser_link"}
    for bad, said in (({"laser_frame": "/laser"}, "the laser frame '/laser' is no tf2 frame id"),
                      ({"base_frame": "base link"}, "the base frame 'base link' is no tf2 frame id"),
                      ({"laser_frame": "base_link"}, "'base_link' twice")):  # fmt: skip
        with pytest.raises(ConfigError, match=f"--foxglove: services.foxglove_bridge: .*{said}"):
            load_profile("sim", {}, foxglove=True, settings={f"services.foxglove_bridge.{k}": v for k, v in bad.items()})
        with pytest.raises(ConfigError, match=said):
            _bridge({"port": 0, **bad})


def test_the_bridge_counts_for_its_scan_period_only_the_scans_that_decode_would_take():
    """The bridge reads each scan's episode and stamp for its period before decoding it (its ranges: it converts only
    what a viewer watches), with its own copy of ``ScanMsg``'s checks: a scan without an episode id counted as episode
    0, one of a negative stamp or episode counted, all of which decoding rejects. Both now check them with
    ``messages.scan_episode_and_stamp``: a scan counts exactly when its episode and stamp decode."""
    from cso_runtime.bag_export import ScanPeriod
    from cso_runtime.messages import ScanMsg

    keys = RobotKeys("r0")
    good = next(decode(m.payload, ScanMsg) for m in episode(keys, 2, T0_NS, 1_000_000) if m.key == keys.scan).body()
    bodies = {
        "good": good,
        "no episode": {k: v for k, v in good.items() if k != "episode"},
        "episode null": {**good, "episode": None},
        "negative episode": {**good, "episode": -1},
        "episode true": {**good, "episode": True},
        "negative stamp": {**good, "stamp_s": -0.5},
        "stamp nan": {**good, "stamp_s": float("nan")},
        "stamp text": {**good, "stamp_s": "0.5"},
    }
    bridge = _bridge({"port": 0})
    try:
        for name, body in bodies.items():
            bridge.scan_period = ScanPeriod()
            bridge.learn_scan_period(body)
            try:
                ScanMsg.from_body(body)
                decodes = True
            except MessageError:
                decodes = False
            assert (bridge.scan_period.seen == 1) == decodes == (name == "good"), name
    finally:
        bridge.shutdown()


def test_service_foxglove_bridge_takes_export_bags_frame_flags_with_export_bags_words(tmp_path, caplog):
    """``export-bag`` had ``--map-frame``, ``--odom-frame``, ``--base-frame`` and ``--laser-frame``, while ``cso-runtime
    service foxglove_bridge`` (a viewer's bridge started by hand beside a robot's run) could only name its frames in a
    profile. It takes the same four flags, from the same definitions (``frame_names.FRAME_OPTIONS``): the same names,
    defaults and help; each sets its profile parameter over the profile's, and a name tf2 refuses is refused as the
    profile's would be (exit 2, before the bridge starts)."""
    import typer.main
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.frame_names import FRAME_OPTIONS
    from services.common import parse_args, service_main, service_parser

    export_bag = {o: p for p in typer.main.get_command(app).commands["export-bag"].params for o in p.opts}
    bridge = service_parser("foxglove_bridge", FoxgloveBridgeService)._option_string_actions
    for option in FRAME_OPTIONS.values():
        assert option.flag in export_bag and option.flag in bridge, option.flag
        assert export_bag[option.flag].default == option.default and export_bag[option.flag].help == option.help
        assert (bridge[option.flag].help or "").startswith(option.help) and bridge[option.flag].default is None
    r = CliRunner().invoke(app, ["service", "foxglove_bridge", "--help"], terminal_width=200)
    assert r.exit_code == 0 and all(o.flag in r.output for o in FRAME_OPTIONS.values()), r.output

    profile = tmp_path / "p.yaml"
    profile.write_text("services:\n  foxglove_bridge: {port: 0, odom_frame: odom_wheel, map_frame: world}\n")
    args = parse_args("foxglove_bridge", ["--config", str(profile), "--connect", "tcp/127.0.0.1:1", "--laser-frame", "laser_link", "--map-frame", "earth"], FoxgloveBridgeService)
    params = FoxgloveBridgeService.apply_arguments(args, {"port": 0, "odom_frame": "odom_wheel", "map_frame": "world"})
    assert params == {"port": 0, "odom_frame": "odom_wheel", "map_frame": "earth", "laser_frame": "laser_link"}  # the flags win; the rest is the profile's
    assert _bridge(params).params.frames() == BagFrames("earth", "odom_wheel", "base_link", "laser_link")
    argv = ["--config", str(profile), "--connect", "tcp/127.0.0.1:1", "--laser-frame", "/laser"]
    assert service_main(FoxgloveBridgeService, argv, exit_process=False) == 2  # refused before any session opens
    assert "the laser frame '/laser' is no tf2 frame id" in caplog.text


def test_an_exception_in_the_bridges_server_listener_is_counted_in_its_status_and_its_status_still_answers(monkeypatch):
    """The Foxglove server calls the bridge's listener on its own thread: an exception there (a bug in it) reached the
    server's log line alone, in no count. The listener goes through ``Service.guarded``, as every service's callbacks:
    logged, counted as ``callback_errors`` in the bridge's status, which still answers."""
    from services import foxglove_bridge
    from services.common import run_service
    from services.foxglove_bridge import FoxgloveBridgeService
    from tests.test_service_bounds import _status_of

    def subscribed_with_a_bug(self, client, channel) -> None:
        raise RuntimeError("a bug in the listener")

    monkeypatch.setattr(foxglove_bridge._Subscriptions, "subscribed", subscribed_with_a_bug)
    port = free_tcp_port()
    keys = RobotKeys("r0")
    params = {"port": 0, "map_period_s": 0.0}
    profile = {"lockstep": False, "services": {"foxglove_bridge": params}}
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        bridge = FoxgloveBridgeService(ServiceContext("foxglove_bridge", "r0", profile, ExplorationConfig(), client, params))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(bridge, stop), daemon=True)
        thread.start()
        try:
            wait_for(lambda: _status_of(session, keys, "foxglove_bridge") is not None, HANG_DEADLINE_S, "the bridge's status")
            viewer = _Viewer(bridge.server.port)
            channels = {c["topic"]: c["id"] for c in viewer.json_op("advertise")["channels"]}
            viewer.send({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels["/map"]}]})
            wait_for(lambda: bridge.callback_errors == 1, HANG_DEADLINE_S, "the listener's error counted")
            viewer.close()
            status = _status_of(session, keys, "foxglove_bridge")
            assert status is not None, "the bridge's status went unanswered"
            assert status.counters.get("callback_errors") == 1, status.counters
        finally:
            stop.set()
            thread.join(10)
    assert not thread.is_alive()
