"""MCAP recording and replay: exact payloads, schemas the mcap tools list, and a replayed scan stream
that rebuilds the same map in a fresh mapper.

Loopback only (a router session on a free port, clients connecting to it, multicast scouting off);
every wait is a condition with a deadline; sessions and threads are closed in ``finally`` blocks.
"""

from __future__ import annotations

import re
import threading
import time
import types
from pathlib import Path

import msgpack
import numpy as np
import pytest

from cso_runtime.config import ExplorationConfig
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, VelocityCommand
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import (
    MESSAGE_TYPES,
    ClockMsg,
    CmdVelMsg,
    DistanceMapMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    OdometryMsg,
    PathMsg,
    PlannerFeedbackMsg,
    ScanMsg,
    decode,
    encode,
)
from cso_runtime.recording import (
    JSON_ENCODING,
    MCAP_MAGIC,
    RAW_ENCODING,
    RecordedMessage,
    RecordStats,
    ReplayStats,
    parse_speed,
    payload_from_json,
    payload_to_json,
    read_recording,
    record,
    replay,
    write_recording,
)
from cso_runtime.scenes import resolve_scenes
from cso_runtime.simulator import KinematicSimulator
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from tests.conftest import HANG_DEADLINE_S, wait_for
from tests.test_bag_export import T0_NS, episode, legacy

PROBE = encode(ClockMsg(0, 0.0))
"""Published until a subscriber sees it: proves the subscription reached the router."""



def sample_payloads(keys: RobotKeys) -> list[tuple[str, bytes]]:
    """One of each kind of message, plus payloads that have no exact JSON form."""
    geom = GridGeometry(0.1, (30, 40), -2.0, -1.5)
    grid = np.full(geom.shape, -1, np.int8)
    grid[5:20, 5:30] = 0
    grid[5, 5:30] = 100
    scan = LaserScan(-np.pi / 2, np.pi / 180, 0.1, 8.0, np.r_[np.full(90, 2.5), np.full(91, np.inf)].astype(np.float32), 12.25)
    out = [
        (keys.clock, encode(ClockMsg(3, 0.75, geom))),
        (keys.odom, encode(OdometryMsg(3, 0.75, Pose2D(1.0, -0.5, 0.3), VelocityCommand(0.2, 0.1)))),
        (keys.scan, encode(ScanMsg(3, scan, Pose2D(1.1, -0.5, 0.3)))),
        (keys.map, encode(MapMsg.from_grid(3, geom, grid))),
        (keys.frontiers, encode(FrontiersMsg(3, False, "keep"))),
        (keys.goal, encode(GoalMsg(3, True, 2.0, 1.0, 0, 3.5, 4.2, "greedy-dist"))),
        (keys.path, encode(PathMsg(3, np.array([[1.0, -0.5], [2.0, 1.0]])))),
        (keys.cmd_vel, encode(CmdVelMsg(3, VelocityCommand(0.5, -0.2)))),
        (keys.scan, b"\x00 not msgpack at all"),
        (keys.goal, msgpack.packb({"schema": "goal", "v": 1, "body": {"x": float("nan")}})),
        (keys.map, msgpack.packb({"schema": "map", "v": 1, "body": {"f32": 1.5}}, use_single_float=True)),
    ]
    return out


def replay_to_a_subscriber(out: Path, robot: str, expected: int) -> tuple[ReplayStats, list[tuple[str, bytes]]]:
    """Replay ``out`` at full speed into a fresh router's subscriber to ``cso/<robot>/**``: the replay's stats and
    the (key, payload) pairs that arrived, in order, the probe that waited for the subscription left out."""
    port = free_tcp_port()
    probe = RobotKeys(robot).episode_status
    got: list[tuple[str, bytes]] = []
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as sub_session, open_session(
        TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    ) as play_session:
        sub = sub_session.declare_subscriber(f"cso/{robot}/**", lambda s: got.append((str(s.key_expr), s.payload.to_bytes())))
        try:
            wait_for(lambda: play_session.put(probe, PROBE) or got, 10, "the replay subscriber")
            stats = replay(play_session, out, "max")
            wait_for(lambda: len([k for k, _ in got if k != probe]) >= expected, 10, "every replayed message")
        finally:
            sub.undeclare()
    return stats, [(k, p) for k, p in got if k != probe]


def test_json_form_is_exact_or_refused():
    keys = RobotKeys("t1")
    exact = 0
    for _key, payload in sample_payloads(keys):
        converted = payload_to_json(payload)
        if converted is None:
            continue
        exact += 1
        assert payload_from_json(converted[1]) == payload
    assert exact == 8, "every well-formed message has an exact JSON form"
    assert payload_to_json(b"\xc1") is None
    assert payload_to_json(msgpack.packb({"$base64": "looks tagged"})) is None
    assert parse_speed("max") == float("inf") and parse_speed("2") == 2.0


def test_record_then_replay_gives_identical_payloads_in_order(tmp_path: Path):
    from mcap.reader import make_reader

    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    out = tmp_path / "run.mcap"
    sent = sample_payloads(keys) * 3
    with open_session(router) as pub_session, open_session(client) as rec_session:
        stop, ready, stats = threading.Event(), threading.Event(), RecordStats()
        thread = threading.Thread(target=record, args=(rec_session, "t1", out, stop, ready, stats), daemon=True)
        thread.start()
        try:
            assert ready.wait(10)
            # The subscription must have reached the router before publishing: probe until one arrives.
            probe = RobotKeys("t1").topic("episode_status")
            wait_for(lambda: pub_session.put(probe, PROBE) or stats.messages > 0, 10, "the recorder's subscription")
            for key, payload in sent:
                pub_session.put(key, payload)
            pub_session.put("cso/other/scan", b"another robot: not recorded")
            wait_for(lambda: stats.messages - stats.per_key[probe] >= len(sent), 10, "every message recorded")
        finally:
            stop.set()
            thread.join(10)
    assert not thread.is_alive()
    assert stats.raw == 3 * 3 and set(stats.per_key) == {k for k, _ in sent} | {probe}

    with out.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        schema_names = {s.name for s in summary.schemas.values()}
        assert {
            "cso.scan",
            "cso.odom",
            "cso.map",
            "cso.goal",
            "cso.cmd_vel",
            "cso.frontiers",
            "cso.path",
            "cso.clock",
        } <= schema_names
        assert all(s.encoding == "jsonschema" for s in summary.schemas.values())
        encodings = {(c.topic, c.message_encoding) for c in summary.channels.values()}
        assert (keys.scan, JSON_ENCODING) in encodings and (keys.scan, RAW_ENCODING) in encodings
        assert summary.statistics.message_count == stats.messages

    recorded = [(m.key, m.payload) for m in read_recording(out) if m.key != probe]
    assert recorded == sent

    # Replay at full speed into a fresh subscriber: byte-identical payloads, in the original order.
    result, got = replay_to_a_subscriber(out, "t1", len(sent))
    assert result.messages == stats.messages
    assert got == sent


def test_replay_keeps_the_recorded_timing(tmp_path: Path):
    from mcap.writer import Writer

    out = tmp_path / "timed.mcap"
    payload = encode(ClockMsg(0, 0.0))
    with out.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("cso.clock", "jsonschema", b"{}")
        cid = w.register_channel("cso/t2/clock", JSON_ENCODING, sid)
        for i in range(3):
            w.add_message(cid, log_time=1_000_000_000 + i * 300_000_000, data=payload_to_json(payload)[1], publish_time=0)
        w.finish()
    port = free_tcp_port()
    with open_session(TransportConfig(mode="peer", listen=[loopback_endpoint(port)])) as session:
        stats = replay(session, out, 2.0)
    assert stats.messages == 3 and abs(stats.recorded_s - 0.6) < 1e-9
    assert 0.29 <= stats.duration_s < 1.5, "0.6 s recorded at 2x takes about 0.3 s"


def test_a_replayed_run_rebuilds_the_same_map_in_a_fresh_mapper(tmp_path: Path):
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    plan = resolve_scenes("generated:small:1:0")[0].load()
    sim = KinematicSimulator(plan, seed=0)
    sim.reset(0)
    keys = RobotKeys("t3")
    port = free_tcp_port()
    router = TransportConfig(mode="router", listen=[loopback_endpoint(port)])
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    out = tmp_path / "mapper.mcap"
    n_steps = 30

    def start_mapper() -> tuple[MapperService, threading.Event, threading.Thread]:
        g = plan.geometry
        assert (g.origin_x_m, g.origin_y_m) == (0.0, 0.0)
        params = {"restore_timeout_s": 0.1, "resolution_m": g.resolution_m, "width_m": g.width_m, "height_m": g.height_m}
        svc = MapperService(ServiceContext("mapper", "t3", {}, ExplorationConfig(), client, params))
        ev = threading.Event()
        th = threading.Thread(target=run_service, args=(svc, ev), daemon=True)
        th.start()
        return svc, ev, th

    with open_session(router) as session, open_session(client) as rec_session:
        mapper, mstop, mthread = start_mapper()
        rstop, ready, stats = threading.Event(), threading.Event(), RecordStats()
        rthread = threading.Thread(target=record, args=(rec_session, "t3", out, rstop, ready, stats), daemon=True)
        rthread.start()
        try:
            assert ready.wait(10)
            wait_for(lambda: any(r.ok for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5)), 10, "the mapper")
            wait_for(lambda: session.put(keys.episode_status, PROBE) or stats.messages, 10, "the recorder")
            # No clock: the grid is configured, and scans alone keep their order (one key, one
            # subscriber). A replay with clocks, handled out of order with the scans, is in
            # tests/test_limo_ros2.py (the mapper tells episodes apart by the clock's episode id).
            for k in range(n_steps):
                session.put(keys.odom, encode(OdometryMsg(k, sim.time_s, sim.odometry())))
                session.put(keys.scan, encode(ScanMsg(k, sim.scan(), sim.sensor_pose())))
                sim.step(VelocityCommand(0.3, 0.5))
            wait_for(lambda: mapper.map_step == n_steps - 1, 20, "the original mapper's last map")
            wait_for(lambda: stats.per_key[keys.map] >= 1 and stats.per_key[keys.scan] >= n_steps, 10, "the recording")
        finally:
            mstop.set()
            rstop.set()
            mthread.join(10)
            rthread.join(10)
        original = mapper.map.to_occupancy_grid()
        assert (original != -1).sum() > 200

        fresh, fstop, fthread = start_mapper()
        try:
            wait_for(
                lambda: any(r.ok for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5)), 10, "the fresh mapper"
            )
            with open_session(client) as play_session:
                # The replay runs at full speed at once: first make sure this new session's puts reach the
                # mapper (a malformed scan, rejected and counted), or the first scans can go before the route.
                wait_for(lambda: play_session.put(keys.scan, b"probe") or fresh.rejected.get("scan", 0) > 0, 10, "the fresh mapper's scan route")
                replay(play_session, out, "max")
            wait_for(lambda: fresh.map_step == n_steps - 1, 20, "the fresh mapper's last map")
        finally:
            fstop.set()
            fthread.join(10)
    np.testing.assert_array_equal(fresh.map.to_occupancy_grid(), original)


def test_replay_publishes_an_old_recording_in_todays_versions(tmp_path: Path):
    """A recording made before odom, goal, frontiers, frontiers/distance and planner/feedback carried the episode
    id: replay publishes those as today's versions (id 0), which a live service's strict ``decode`` takes, and
    counts them; every other payload goes out byte for byte, one of a version no build reads included (the
    services reject and count it, as before)."""
    keys = RobotKeys("t4")
    geom = GridGeometry(0.1, (4, 5), -0.2, -0.2)
    d = np.full(geom.shape, np.inf)
    d[1:3, 1:4] = 0.5
    today = [
        (keys.odom, encode(OdometryMsg(3, 0.75, Pose2D(1.0, -0.5, 0.3), VelocityCommand(0.2, 0.1)))),
        (keys.frontiers, encode(FrontiersMsg(3, False, "keep"))),
        (keys.topic("distance_map"), encode(DistanceMapMsg(3, geom, Pose2D(0.0, 0.0, 0.0), d))),
        (keys.goal, encode(GoalMsg(3, True, 2.0, 1.0, 0, 3.5, 4.2, "greedy-dist"))),
        (keys.planner_feedback, encode(PlannerFeedbackMsg(3, "following", "command", False, "", np.array([[1.0, 2.0]]), 3))),
    ]
    old = [(key, legacy(payload)) for key, payload in today]
    assert all(o != t for (_, o), (_, t) in zip(old, today))
    scan = LaserScan(-np.pi / 2, np.pi / 180, 0.1, 8.0, np.full(181, 2.5, np.float32), 0.75)
    as_recorded = [
        (keys.scan, encode(ScanMsg(3, scan, Pose2D(1.1, -0.5, 0.3)))),
        (keys.odom, msgpack.packb({"schema": "odom", "v": 99, "body": {}}, use_bin_type=True)),  # a version no build reads
        (keys.scan, b"\x00 not msgpack at all"),
    ]
    recorded = old + as_recorded
    out = tmp_path / "old.mcap"
    write_recording(out, "t4", [RecordedMessage(key, T0_NS + i * 1000, payload) for i, (key, payload) in enumerate(recorded)])

    stats, got = replay_to_a_subscriber(out, "t4", len(recorded))
    assert [k for k, _ in got] == [k for k, _ in recorded]
    assert stats.messages == len(recorded) and stats.upgraded == {key: 1 for key, _ in old}
    assert stats.unreadable == {keys.odom: 1, keys.scan: 1}
    for (key, payload), (_, want) in zip(got, today):
        schema = msgpack.unpackb(want)["schema"]
        msg = decode(payload, MESSAGE_TYPES[schema])  # strict, as every live service decodes
        assert msg.episode == 0 and encode(msg) == want, key
    assert got[len(old):] == as_recorded


def test_a_replayed_old_recording_drives_todays_planner(tmp_path: Path):
    """Odometry, decisions and goals of the versions before the episode id, replayed into a running planner:
    taken (not rejected as an unknown version), so the planner follows the recorded goals and commands each step."""
    from services.common import ServiceContext, run_service
    from services.planner import PlannerService

    keys = RobotKeys("t5")
    messages = [RecordedMessage(m.key.replace("/r0/", "/t5/"), m.log_time_ns, legacy(m.payload)) for m in episode(RobotKeys("r0"), 5, T0_NS, 1_000_000)]
    out = tmp_path / "old.mcap"
    write_recording(out, "t5", messages)
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        planner = PlannerService(ServiceContext("planner", "t5", {}, ExplorationConfig(), client, {}))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(planner, stop), daemon=True)
        thread.start()
        try:
            wait_for(lambda: any(r.ok for r in session.liveliness().get(keys.alive("planner"), timeout=0.5)), 20, "the planner")
            probes: list[bytes] = []

            def probe() -> bool:
                probes.append(b"probe")
                play_session.put(keys.odom, probes[-1])
                return planner.rejected.get("odom", 0) > 0

            with open_session(client) as play_session:
                # Make sure this session's puts reach the planner first (a malformed odometry, rejected and counted).
                wait_for(probe, 10, "the planner's odometry route")
                stats = replay(play_session, out, "max", topics=["odom", "scan", "frontiers", "goal"])
            assert sum(stats.upgraded.values()) == 3 * 5 and not stats.unreadable  # odom, frontiers, goal of 5 steps
            wait_for(lambda: planner.cmd_step == 4 and planner.goal_step == 4, 20, "the planner's commands on the old recording")
        finally:
            stop.set()
            thread.join(10)
    assert planner.rejected == {"odom": len(probes)}, "only the probes"


def test_a_broken_recording_is_one_clear_error(tmp_path: Path):
    """An empty or truncated MCAP file: RecordingError naming the file and why, never a blank reason."""
    from cso_runtime.recording import RecordingError

    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty file"):
        list(read_recording(empty))
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(MCAP_MAGIC + b"\x01\x02")
    with pytest.raises(RecordingError, match=r"cannot read .*truncated.mcap: it ends before its first chunk of messages"):
        list(read_recording(truncated))
    from mcap.writer import Writer

    corrupt = tmp_path / "corrupt.mcap"  # a whole file whose only payload is not the JSON it says it is
    with corrupt.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        channel = writer.register_channel(RobotKeys("r0").odom, JSON_ENCODING, writer.register_schema("cso.odom", "jsonschema", b"{}"))
        writer.add_message(channel, log_time=1, data=b"{not json", publish_time=1)
        writer.finish()
    with pytest.raises(RecordingError, match=r"cannot read .*corrupt.mcap: \S"):
        list(read_recording(corrupt))


def _written_scans(path: Path, count: int) -> tuple[list[RecordedMessage], Path]:
    """``count`` distinct scans of robot r0, 10 ms apart, and the finished recording of them at ``path``."""
    from cso_runtime.recording import write_recording

    scan_key = RobotKeys("r0").scan
    scans = [
        RecordedMessage(scan_key, 10**9 + k * 10**7, encode(ScanMsg(k, LaserScan(-np.pi, np.pi / 180, 0.1, 8.0, np.linspace(0.2, 7.9, 360).astype(np.float32) + k, k * 0.1), Pose2D(k * 0.01, 0.0, 0.0))))
        for k in range(count)
    ]
    write_recording(path, "r0", scans)
    return scans, path


def test_a_recording_whose_recorder_was_killed_is_read_up_to_where_it_stops(tmp_path: Path, caplog):
    """A recorder killed before it finished the file (SIGKILL, power) leaves its chunks without the summary
    the seeking reader starts from: every message it holds is read front to back, with a warning, and a
    file cut inside a chunk gives the messages before the cut."""
    scans, whole = _written_scans(tmp_path / "whole.mcap", 1500)
    data = whole.read_bytes()
    footer = data[-len(MCAP_MAGIC) - 29 : -len(MCAP_MAGIC)]  # opcode, length, summary_start, summary_offset_start, crc
    assert footer[0] == 0x02
    summary_start = int.from_bytes(footer[9:17], "little")
    killed = tmp_path / "killed.mcap"
    killed.write_bytes(data[:summary_start])  # the chunks, no summary and no footer
    with caplog.at_level("WARNING", logger="cso.recording"):
        back = list(read_recording(killed))
    assert [(m.key, m.log_time_ns, m.payload) for m in back] == [(m.key, m.log_time_ns, m.payload) for m in scans]
    assert "ends early" in caplog.text and "read 1500 messages" in caplog.text
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: summary_start * 2 // 3])  # inside a chunk
    head = list(read_recording(cut))
    assert 0 < len(head) < len(scans) and [m.payload for m in head] == [m.payload for m in scans[: len(head)]]


def test_a_recording_cut_inside_its_summary_is_read_through_not_a_traceback(tmp_path: Path):
    """A recorder killed while it wrote the summary (or a copy cut short) leaves every chunk but a partial summary:
    the seeking reader then reads a short footer (struct.error, not an McapError). ``recording_contents`` (which
    export-bag, replay and animate ask first) reads such a file through, as one without a summary, at every cut."""
    from cso_runtime.recording import recording_contents

    scans, whole = _written_scans(tmp_path / "whole.mcap", 20)
    data = whole.read_bytes()
    summary_start = int.from_bytes(data[-len(MCAP_MAGIC) - 29 : -len(MCAP_MAGIC)][9:17], "little")
    cut = tmp_path / "cut.mcap"
    for end in range(summary_start, len(data)):
        cut.write_bytes(data[:end])
        keys, _total = recording_contents(cut)
        assert keys == [scans[0].key], end


def test_a_recording_changed_after_it_was_written_is_refused_not_read_wrong(tmp_path: Path):
    """A flipped byte inside a chunk can decompress into a different payload with no error at all: the chunk CRCs
    the writer stores are checked, so such a file is refused (by ``read_recording`` and the summary reader) rather
    than replayed or exported with a wrong message. And a recorder killed before its first chunk says so."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    from cso_runtime.recording import RecordingError, _McapSink, recording_contents, zlib_error

    keys = RobotKeys("r0")
    scans, whole = _written_scans(tmp_path / "whole.mcap", 400)
    data = whole.read_bytes()
    with whole.open("rb") as fh:
        chunk = make_reader(fh).get_summary().chunk_indexes[0]
    damaged = tmp_path / "damaged.mcap"
    silent = None  # the first flip inside the chunk's compressed bytes that an unchecked reader reads as another payload
    for offset in range(chunk.chunk_start_offset + chunk.chunk_length - 1, chunk.chunk_start_offset + chunk.chunk_length - 400, -1):
        flipped = bytearray(data)
        flipped[offset] ^= 0x10
        damaged.write_bytes(bytes(flipped))
        try:
            with damaged.open("rb") as fh:
                unchecked = [bytes(m.data) for _s, _c, m in make_reader(fh).iter_messages(log_time_order=True)]
        except (McapError, ValueError, zlib_error()):
            unchecked = []  # this flip broke the decompression: not the silent case looked for
        if len(unchecked) == len(scans) and unchecked != [payload_to_json(m.payload)[1] for m in scans]:
            silent = offset
            break
    assert silent is not None, "some flip in 400 bytes of compressed data changes a message without an error"
    with pytest.raises(RecordingError, match=r"cannot read .*damaged.mcap: damaged: a Chunk's CRC does not match"):
        list(read_recording(damaged))
    with damaged.open("rb") as fh:  # the index is intact: the summary still counts; reading the messages refuses
        assert make_reader(fh).get_summary().statistics.message_count == len(scans)
    assert len(list(read_recording(whole))) == len(scans)
    assert recording_contents(whole) == ([keys.scan], len(scans))

    killed = tmp_path / "killed.mcap"  # the header and metadata a recorder writes at once, then nothing
    with killed.open("wb") as fh:
        _McapSink(fh, "r0")
    with pytest.raises(RecordingError, match=r"killed.mcap: it ends before its first chunk of messages \(its recorder was killed"):
        list(read_recording(killed))


def test_a_recording_never_replaces_an_earlier_file(tmp_path: Path, monkeypatch):
    """``record --out FILE`` and ``up --record-out FILE`` refuse a file that exists (exit 2, before connecting or
    starting anything; ``up --dry-run`` too), ``--out DIR/`` means a folder even before it exists, and the Foxglove bridge's
    ``mcap_path`` moves to the next free ``-<n>`` name instead of writing over an earlier run's file."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.recording import recording_path, unused_path

    earlier = tmp_path / "run.mcap"
    earlier.write_bytes(b"an earlier recording")
    r = CliRunner().invoke(app, ["record", "--out", str(earlier), "--connect", "tcp/127.0.0.1:1"])
    assert r.exit_code == 2 and f"{earlier} exists" in r.output
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--record-out", str(earlier), "--runs-dir", str(tmp_path / "runs"), "--no-live"])
    assert r.exit_code == 2 and "the file exists" in r.output and not (tmp_path / "runs").exists()
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--record-out", str(earlier), "--dry-run"])  # says now what the run would say
    assert r.exit_code == 2 and "the file exists" in r.output, r.output
    assert earlier.read_bytes() == b"an earlier recording"
    assert recording_path(f"{tmp_path}/new/", Path("recordings"), "r0-T") == tmp_path / "new" / "r0-T.mcap"
    assert recording_path(str(tmp_path / "new"), Path("recordings"), "r0-T") == tmp_path / "new"  # no slash, not there: a file
    with pytest.raises(FileExistsError):
        record(None, "r0", earlier, threading.Event())  # type: ignore[arg-type]  # refused before the session is used
    assert unused_path(tmp_path / "fresh.mcap") == tmp_path / "fresh.mcap"
    assert unused_path(earlier) == tmp_path / "run-1.mcap"
    (tmp_path / "run-1.mcap").write_bytes(b"")
    assert unused_path(earlier) == tmp_path / "run-2.mcap"


def test_replay_command_names_a_missing_recording_before_anything_else(tmp_path: Path):
    """A wrong path is the first thing to say, even with no run to replay into."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    missing = tmp_path / "nowhere.mcap"
    r = CliRunner().invoke(app, ["replay", str(missing), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 2 and f"no such recording {missing}" in r.output
    recording = tmp_path / "run.mcap"
    recording.write_bytes(b"")
    r = CliRunner().invoke(app, ["replay", str(recording), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 2 and f"cannot read {recording}: empty file" in r.output  # a broken file, said first too
    recording.write_bytes(b"PK\x03\x04 a zip, not a recording")
    r = CliRunner().invoke(app, ["replay", str(recording), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 2 and "not an MCAP file" in r.output
    r = CliRunner().invoke(app, ["replay", str(tmp_path), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 2 and f"{tmp_path} is a folder" in r.output
    _written_scans(recording, 1)  # a readable one: a topic that does not exist is said before connecting
    r = CliRunner().invoke(app, ["replay", str(recording), "--topics", "scan,scans", "--connect", "tcp/127.0.0.1:1"])
    assert r.exit_code == 2 and "unknown topic(s) scans; known: scan, odom" in r.output
    for nothing in (",", " , "):  # a list of no topic would replay nothing, silently
        r = CliRunner().invoke(app, ["replay", str(recording), "--topics", nothing, "--connect", "tcp/127.0.0.1:1"])
        assert r.exit_code == 2 and "--topics names no topic" in r.output, r.output
    # then the missing run is what stops it
    r = CliRunner().invoke(app, ["replay", str(recording), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 2 and "no current run" in r.output


def test_replay_topics_take_the_keys_as_docs_and_dataflow_name_them(tmp_path: Path, monkeypatch):
    """``replay --topics planner/feedback,frontiers/distance``: the key names of docs/messages.md, `dataflow` and
    the recording's own channels replay the topics they name (they were refused as unknown; only the
    ``planner_feedback`` spelling was known)."""
    import contextlib
    import signal

    from typer.testing import CliRunner

    from cso_runtime import recording as recording_module
    from cso_runtime import transport
    from cso_runtime.cli import app

    wanted: list[object] = []
    monkeypatch.setattr(transport, "open_session", lambda config: contextlib.nullcontext())
    monkeypatch.setattr(recording_module, "replay", lambda session, path, speed, stop, topics: wanted.append(topics) or recording_module.ReplayStats())
    recording = tmp_path / "run.mcap"
    _written_scans(recording, 1)  # a readable recording (replay checks it before connecting)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        r = CliRunner().invoke(app, ["replay", str(recording), "--topics", "planner/feedback, frontiers/distance,scan", "--connect", "tcp/127.0.0.1:1"])
        assert r.exit_code == 0, r.output
        assert wanted == [["planner_feedback", "distance_map", "scan"]]
        r = CliRunner().invoke(app, ["replay", str(recording), "--topics", "planner/feedbacks", "--connect", "tcp/127.0.0.1:1"])
        assert r.exit_code == 2 and "unknown topic(s) planner/feedbacks" in r.output
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def test_a_recording_folder_gets_a_file_named_for_the_run(tmp_path: Path, monkeypatch):
    """``record --out FOLDER`` and ``up --record-out FOLDER`` write a file inside the folder (they used to try to
    open the folder itself and fail); a file path is kept as it is."""
    from cso_runtime.launcher import RECORDING_NAME, _record_path
    from cso_runtime.recording import recording_path

    monkeypatch.chdir(tmp_path)
    assert recording_path(None, Path("recordings"), "r0-T") == Path("recordings/r0-T.mcap")
    assert recording_path(tmp_path, Path("recordings"), "r0-T") == tmp_path / "r0-T.mcap"
    assert recording_path(Path(""), Path("recordings"), "r0-T") == Path("r0-T.mcap")
    assert recording_path(tmp_path / "mine.mcap", Path("recordings"), "r0-T") == tmp_path / "mine.mcap"
    run_dir = tmp_path / "runs" / "20261201-000000-sim-r0"
    assert _record_path(run_dir, True) == run_dir / RECORDING_NAME and _record_path(run_dir, False) is None
    assert _record_path(run_dir, tmp_path) == tmp_path / "20261201-000000-sim-r0.mcap"
    assert _record_path(run_dir, tmp_path / "x.mcap") == tmp_path / "x.mcap"


def test_record_and_replay_without_a_zenoh_session_exit_3_as_up_does(tmp_path: Path, monkeypatch):
    """The exit codes (docs/commands.md) are the same for every command: no Zenoh session is 3 (it was 2 for record, 1 for replay)."""
    from typer.testing import CliRunner

    from cso_runtime import transport
    from cso_runtime.cli import app

    def no_router(config):
        raise transport.TransportError("cannot open zenoh session (client): Timeout!")

    import signal

    monkeypatch.setattr(transport, "open_session", no_router)
    recording = tmp_path / "run.mcap"
    _written_scans(recording, 1)  # a readable recording (replay checks it before connecting)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # both commands set their own
    try:
        r = CliRunner().invoke(app, ["replay", str(recording), "--connect", "tcp/127.0.0.1:7447"])
        assert r.exit_code == 3 and "cannot open zenoh session" in r.output
        r = CliRunner().invoke(app, ["record", "--out", str(tmp_path / "r.mcap"), "--connect", "tcp/127.0.0.1:7447"])
        assert r.exit_code == 3 and "cannot open zenoh session" in r.output
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def test_record_refuses_a_bad_robot_id_before_connecting(tmp_path: Path, monkeypatch):
    """``record --robot a/b`` is a usage error (exit 2) before any session; '*' (every robot) goes on to connect. So is an
    ``--out`` whose folder cannot be made."""
    import signal

    from typer.testing import CliRunner

    from cso_runtime import transport
    from cso_runtime.cli import app

    opened: list[object] = []

    def no_router(config):
        opened.append(config)
        raise transport.TransportError("cannot open zenoh session (client): Timeout!")

    monkeypatch.setattr(transport, "open_session", no_router)
    args = ["record", "--out", str(tmp_path / "r.mcap"), "--connect", "tcp/127.0.0.1:7447", "--robot"]
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # record sets its own
    try:
        r = CliRunner().invoke(app, [*args, "a/b"])
        assert r.exit_code == 2 and "--robot: robot id 'a/b' must be" in r.output and not opened
        r = CliRunner().invoke(app, [*args, "*"])
        assert r.exit_code == 3 and len(opened) == 1
        (tmp_path / "notes.txt").write_text("a file where the recording's folder would be")
        r = CliRunner().invoke(app, ["record", "--out", str(tmp_path / "notes.txt" / "r.mcap"), "--connect", "tcp/127.0.0.1:7447"])
        assert r.exit_code == 2 and "notes.txt: cannot create the folder" in r.output and len(opened) == 1, r.output  # as up --record-out
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert not (tmp_path / "r.mcap").exists()



def test_record_and_replay_given_a_malformed_endpoint_exit_2_before_anything_is_made(tmp_path: Path, monkeypatch):
    """``record --connect notanendpoint`` made ./recordings/ and exited 3 ("no Zenoh session"), and so did ``replay``:
    a malformed endpoint is a usage error, exit 2 (docs/commands.md), as for ``status``, said before any folder is made."""
    import signal

    from typer.testing import CliRunner

    from cso_runtime import transport
    from cso_runtime.cli import app

    opened: list[object] = []

    def no_router(config):
        opened.append(config)
        raise transport.TransportError("cannot open zenoh session (client): Timeout!")

    monkeypatch.setattr(transport, "open_session", no_router)
    monkeypatch.chdir(tmp_path)
    recording = tmp_path / "run.mcap"
    _written_scans(recording, 1)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # both commands set their own
    try:
        for args in (["record", "--robot", "r0"], ["record"], ["replay", str(recording)]):
            r = CliRunner().invoke(app, [*args, "--connect", "notanendpoint"])
            assert r.exit_code == 2 and r.stderr == "error: bad zenoh endpoint 'notanendpoint'; expected PROTO/HOST:PORT, e.g. tcp/127.0.0.1:7447\n", (args, r.output)
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert not opened and sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


@pytest.mark.parametrize("stop_signal", ["SIGHUP", "SIGINT"])
def test_record_stopped_under_a_dense_stream_finishes_its_file(tmp_path: Path, stop_signal: str):
    """SIGHUP (the terminal ``record`` ran in was closed) stops it as Ctrl-C (SIGINT) does: the MCAP file is
    finished, summary and all (SIGHUP used to kill it at once and leave 0 bytes). Both while scans keep coming
    every 2 ms, which never leave the recorder's queue empty for the 50 ms it used to wait for before it looked
    at the stop (it then recorded on until the stream ended). The signal goes once a first chunk is on disk, so
    the recorder has provably received messages; what it holds is the stream's start, in order, with no gap."""
    import signal
    import subprocess
    import sys

    from mcap.reader import make_reader

    port = free_tcp_port()
    out = tmp_path / "stopped.mcap"
    keys = RobotKeys("r0")
    rng = np.random.default_rng(0)
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cso_runtime.cli", "record", "--connect", loopback_endpoint(port), "--robot", "r0", "--out", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        try:
            wait_for(lambda: any(line.startswith("recording cso/r0/**") for line in lines), 30, "the recorder to connect")
            publisher = session.declare_publisher(keys.scan)
            wait_for(lambda: publisher.matching_status.matching, 10, "the recorder's subscription to reach the router")
            scans = [encode(ScanMsg(k, LaserScan(-np.pi, np.pi / 180, 0.1, 8.0, rng.uniform(0.1, 8.0, 360).astype(np.float32), 0.25 * k), Pose2D(0.0, 0.0, 0.0))) for k in range(2000)]

            def keep_publishing() -> None:  # on past the signal, until the recorder has exited (or the scans run out)
                for payload in scans:
                    if proc.poll() is not None:
                        return
                    publisher.put(payload)
                    time.sleep(0.002)

            stream = threading.Thread(target=keep_publishing, daemon=True)
            stream.start()
            wait_for(lambda: out.stat().st_size > 1024, 30, "the recorder's first chunk on disk")
            proc.send_signal(getattr(signal, stop_signal))
            proc.wait(timeout=30)
            reader.join(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
    output = "".join(lines)
    assert proc.returncode == 0 and "messages on" in output, output
    with out.open("rb") as fh:
        assert make_reader(fh).get_summary() is not None  # finished: the seeking reader's summary is there
    recorded = list(read_recording(out))
    assert 0 < len(recorded) < len(scans) and {m.key for m in recorded} == {keys.scan}  # stopped mid-stream, not at its end
    assert [m.payload for m in recorded] == scans[: len(recorded)]  # exact, in order, no gap


def test_replay_closed_by_its_terminal_stops_at_once_and_says_what_it_sent(tmp_path: Path):
    """SIGHUP (its terminal closed) stops ``replay`` as Ctrl-C does: it stops publishing mid-recording, exits 0
    and says how many messages it sent (it used to die on the signal with nothing said), once: its summary came
    twice, on stdout and again as a log line ("replayed N messages in ... s") on stderr."""
    import signal
    import subprocess
    import sys

    from cso_runtime.recording import write_recording

    keys = RobotKeys("r0")
    odoms = [RecordedMessage(keys.odom, 10**9 + k * 10**8, encode(OdometryMsg(k, 0.1 * k, Pose2D(0.01 * k, 0.0, 0.0)))) for k in range(100)]
    recording = tmp_path / "odom.mcap"
    write_recording(recording, "r0", odoms)  # 9.9 s at the recorded speed
    port = free_tcp_port()
    received: list[int] = []
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        sub = session.declare_subscriber(keys.odom, lambda s: received.append(decode(s.payload.to_bytes()).step))
        proc = subprocess.Popen(
            [sys.executable, "-m", "cso_runtime.cli", "replay", str(recording), "--connect", loopback_endpoint(port)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
        try:
            wait_for(lambda: received, 30, "the first replayed message")
            proc.send_signal(signal.SIGHUP)
            output, _ = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
            sub.undeclare()
    match = re.search(r"replayed (\d+) messages on 1 keys", output)
    assert proc.returncode == 0 and match and output.count("replayed") == 1, output
    assert 1 <= int(match.group(1)) < len(odoms)  # stopped mid-recording, not at its end
    assert received == list(range(received[0], received[0] + len(received)))  # in order, none after the stop lost mid-way


def test_a_recorder_stopped_with_a_backlog_writes_it_for_drain_s_then_finishes_its_file(tmp_path: Path, monkeypatch, caplog):
    """A recorder behind a dense stream (a busy machine) holds a backlog when it is stopped; it wrote all of it,
    however long that took, and the launcher's stop waited (``up --record``; ``down`` then killed a launcher still
    writing). With ``drain_s`` it writes for that long, leaves the rest out and says how many, and the file is
    finished (its summary written): the run's start, in order, with no gap."""
    from mcap.reader import make_reader

    from cso_runtime import recording

    keys = RobotKeys("r0")
    scans = [encode(ScanMsg(k, LaserScan(-np.pi, np.pi / 180, 0.1, 8.0, np.full(360, 1.0 + k % 7, np.float32), 0.25 * k), Pose2D(0.0, 0.0, 0.0))) for k in range(200)]
    stop = threading.Event()

    class Session:  # delivers the whole stream at once when the recorder subscribes, then the stop comes
        def declare_subscriber(self, key_expr, on_sample):
            for payload in scans:
                on_sample(types.SimpleNamespace(key_expr=keys.scan, payload=types.SimpleNamespace(to_bytes=lambda p=payload: p)))
            stop.set()
            return types.SimpleNamespace(undeclare=lambda: None)

    write = recording._write
    monkeypatch.setattr(recording, "_write", lambda *args: (time.sleep(0.005), write(*args)))  # 1 s for the whole backlog
    out = tmp_path / "stopped.mcap"
    with caplog.at_level("WARNING", logger="cso.recording"):
        stats = recording.record(Session(), "r0", out, stop, drain_s=0.1)
    assert 0 < stats.messages < len(scans) and stats.left_out == len(scans) - stats.messages, stats
    assert f"{stats.left_out} messages that had arrived were left out of {out}" in caplog.text
    with out.open("rb") as fh:
        assert make_reader(fh).get_summary() is not None
    assert [m.payload for m in read_recording(out)] == scans[: stats.messages]


def test_replay_refuses_a_network_where_a_robot_of_the_recording_runs(tmp_path: Path):
    """``replay`` publishes into the current run's router by default. Into a live ``limo-ros2`` run it fed the old
    scans, maps and frontiers to the run's services and the recorded ``cmd_vel`` to its ROS 2 bridge, which sent
    them to the robot as Twists. A robot of the recording whose launcher answers, or whose referee (sim, ROS 2
    bridge) is alive, is now refused (exit 2) before anything is published; a pipeline started by hand to be fed
    the recording (a mapper alone) still gets it."""
    import signal

    from typer.testing import CliRunner

    from cso_runtime.cli import app

    keys = RobotKeys("r0")
    recording = tmp_path / "run.mcap"
    commands = [encode(CmdVelMsg(step, VelocityCommand(0.5, 0.1))) for step in range(3)]
    write_recording(recording, "r0", [RecordedMessage(keys.cmd_vel, T0_NS + i * 1000, payload) for i, payload in enumerate(commands)])
    endpoint = loopback_endpoint(free_tcp_port())
    heard: list[bytes] = []
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        with open_session(TransportConfig(mode="router", listen=[endpoint])) as session:
            sub = session.declare_subscriber(keys.cmd_vel, lambda sample: heard.append(sample.payload.to_bytes()))
            for how in ("ros2_bridge", "launcher"):
                if how == "launcher":
                    held = session.declare_queryable(keys.launcher_status, lambda query: query.reply(keys.launcher_status, b"x"))
                else:
                    held = session.liveliness().declare_token(keys.alive(how))
                try:
                    r = CliRunner().invoke(app, ["replay", str(recording), "--speed", "max", "--connect", endpoint])
                finally:
                    held.undeclare()
                assert r.exit_code == 2 and "robot r0 runs on this network" in r.output, r.output
                assert ("its ros2_bridge is alive" if how == "ros2_bridge" else "its launcher answers") in r.output, r.output
            assert heard == []  # nothing published
            pipeline = session.liveliness().declare_token(keys.alive("mapper"))
            try:
                r = CliRunner().invoke(app, ["replay", str(recording), "--speed", "max", "--connect", endpoint])
                assert r.exit_code == 0 and "replayed 3 messages" in r.output, r.output
                wait_for(lambda: len(heard) == 3, HANG_DEADLINE_S, "the replayed commands")
            finally:
                pipeline.undeclare()
                sub.undeclare()
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def test_replay_refuses_a_damaged_recording_before_it_publishes_anything(tmp_path: Path):
    """A chunk changed after it was written, however far into the file, is found before the first message goes out:
    a replay into a pipeline never feeds it the run up to the damage and then stops. A recording cut short (its
    recorder killed) still replays up to the cut."""
    from mcap.reader import make_reader
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.recording import RecordingError, check_chunks

    scans, whole = _written_scans(tmp_path / "whole.mcap", 1500)
    data = bytearray(whole.read_bytes())
    with whole.open("rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) >= 2, "the damage is in a chunk after the first"
    last = chunks[-1]
    data[last.chunk_start_offset + last.chunk_length - 10] ^= 0x10  # in the last chunk's compressed bytes
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))

    class CountingSession:
        """A peer session whose publishers are counted (every replayed message has one on its key)."""

        def __init__(self, session) -> None:
            self.session, self.publishers = session, 0

        def __getattr__(self, name):
            return getattr(self.session, name)

        def declare_publisher(self, *args, **kwargs):
            self.publishers += 1
            return self.session.declare_publisher(*args, **kwargs)

    with open_session(TransportConfig(mode="peer", listen=[loopback_endpoint(free_tcp_port())])) as session:
        counting = CountingSession(session)
        with pytest.raises(RecordingError, match=r"damaged.mcap: damaged: a Chunk's CRC does not match"):
            replay(counting, damaged, "max")
        assert counting.publishers == 0
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(bytes(whole.read_bytes()[: last.chunk_start_offset + 10]))  # the chunks before the last
        stats = replay(counting, cut, "max")
    assert 0 < stats.messages < len(scans) and counting.publishers == 1
    r = CliRunner().invoke(app, ["replay", str(damaged), "--connect", "tcp/127.0.0.1:1"])  # said before connecting
    assert r.exit_code == 2 and "damaged: a Chunk's CRC does not match" in r.output, r.output
    # Cut before its first chunk (its recorder killed at once): nothing to replay, said before connecting as
    # export-bag and animate say it (exit 2), not after the session opened (it was exit 1, or "no current run").
    early = tmp_path / "early.mcap"
    early.write_bytes(whole.read_bytes()[:100])
    with pytest.raises(RecordingError, match=r"early.mcap: it ends before its first chunk of messages"):
        check_chunks(early)
    for where in (["--connect", "tcp/127.0.0.1:1"], ["--runs-dir", str(tmp_path)]):
        r = CliRunner().invoke(app, ["replay", str(early), *where])
        assert r.exit_code == 2 and "it ends before its first chunk of messages" in r.output, r.output


def test_replay_upgrades_the_old_messages_of_a_run_that_raised_max_grid_cells(tmp_path: Path, monkeypatch):
    """``replay`` reads a recording's payloads to upgrade the old ones (``upgrade_payload``) as the other one-shot tools
    that read a run's grids do (``export-bag``, ``animate``, ``save-map``): up to the format's ceiling, not the default
    ``max_grid_cells``. A run that raised the bound recorded grids above the default: replay published those of an older
    version as recorded, "not readable by this build", where today's services of such a run would have taken them
    upgraded."""
    import contextlib
    import signal

    from typer.testing import CliRunner

    from cso_runtime import recording as recording_module
    from cso_runtime import transport
    from cso_runtime.cli import app
    from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, MAX_GRID_CELLS, set_max_grid_cells

    keys = RobotKeys("r0")
    big = GridGeometry(0.05, (2001, 2000), 0.0, 0.0)  # 4,002,000 cells: a 100 m x 100 m arena and a row
    d = np.full(big.shape, np.inf)
    d[:40, :50] = 1.5
    set_max_grid_cells(MAX_GRID_CELLS)  # the run that recorded it (the autouse fixture puts the default back)
    old = legacy(encode(DistanceMapMsg(3, big, Pose2D(0.0, 0.0, 0.0), d)))
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)
    stats = ReplayStats()

    def fake_replay(session, path, speed, stop, topics) -> ReplayStats:
        recording_module._current_payload(RecordedMessage(keys.topic("distance_map"), T0_NS, old), stats)
        return stats

    monkeypatch.setattr(transport, "open_session", lambda config: contextlib.nullcontext())
    monkeypatch.setattr(recording_module, "replay", fake_replay)
    recording = tmp_path / "run.mcap"
    _written_scans(recording, 1)  # a readable recording (replay checks it before connecting)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        r = CliRunner().invoke(app, ["replay", str(recording), "--connect", "tcp/127.0.0.1:1"])
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert r.exit_code == 0, r.output
    assert stats.upgraded == {keys.topic("distance_map"): 1} and not stats.unreadable, (stats, r.output)


def test_replay_and_record_say_a_bad_flag_with_no_run_too(tmp_path: Path):
    """``replay FILE --speed abc`` with no current run said "no current run; give --connect ENDPOINT", and once a run
    was found, that the speed was bad: two tries for two mistakes of one command line. So did ``record --out FILE``
    of a recording that exists. The flags are said first now, with no run as with one (exit 2, nothing made)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    recording = tmp_path / "run.mcap"
    _written_scans(recording, 1)
    no_run = ["--runs-dir", str(tmp_path / "runs")]
    r = CliRunner().invoke(app, ["replay", str(recording), "--speed", "abc", *no_run])
    assert r.exit_code == 2 and "speed must be a positive number or 'max', got 'abc'" in r.output, r.output
    r = CliRunner().invoke(app, ["replay", str(recording), "--topics", "scans", *no_run])
    assert r.exit_code == 2 and "unknown topic(s) scans" in r.output, r.output
    r = CliRunner().invoke(app, ["record", "--out", str(recording), *no_run])
    assert r.exit_code == 2 and f"{recording} exists; give another --out" in r.output, r.output
    assert not (tmp_path / "runs").exists()


def test_record_and_replay_of_a_run_that_is_starting_or_ending_say_so_not_no_current_run(tmp_path: Path):
    """``up ... &`` then ``record`` (or ``replay``) as the run's router opened: its run file said ``starting``, with no
    endpoints yet, and they said "no current run; give --connect ENDPOINT" (exit 2, a usage error) of a run that was
    there. They say it is starting (exit 1, as ``status`` does); of a run whose launcher has ended it and is exiting
    (its run file ``stopped``), that it has ended; with no run at all, "no current run" as before."""
    import json
    import os

    from typer.testing import CliRunner

    from cso_runtime.cli import app

    recording = tmp_path / "in.mcap"
    _written_scans(recording, 1)
    runs = tmp_path / "runs"
    run_dir = runs / "run1"
    run_dir.mkdir(parents=True)
    starting = {"run_id": "run1", "run_dir": str(run_dir), "robot": "r0", "endpoints": [], "launcher_pid": os.getpid(), "state": "starting", "services": {}}
    ending = {**starting, "endpoints": ["tcp/127.0.0.1:1"], "state": "stopped", "outcome": "interrupted", "exit_code": 130}
    for info, said in (
        (starting, "error: run run1 (robot r0) is starting: its router is not open yet; ask again in a moment"),
        (ending, f"error: run run1 has ended (interrupted) and its launcher is exiting; `cso-runtime runs --runs-dir {runs}` lists it"),
    ):
        (runs / "current.json").write_text(json.dumps(info))
        for command in (["record", "--out", str(tmp_path / "out.mcap")], ["replay", str(recording)]):
            r = CliRunner().invoke(app, [*command, "--runs-dir", str(runs)])
            assert r.exit_code == 1 and r.output.strip() == said, (command, r.exit_code, r.output)
    assert not (tmp_path / "out.mcap").exists()
    (runs / "current.json").unlink()
    r = CliRunner().invoke(app, ["record", "--out", str(tmp_path / "out.mcap"), "--runs-dir", str(runs)])
    assert r.exit_code == 2 and "no current run; give --connect ENDPOINT" in r.output, r.output


def test_replay_refuses_a_speed_too_slow_to_wait_for():
    """``replay --speed 1e-320`` ended mid-replay in ``OverflowError: timestamp out of range for platform time_t`` (a
    wait between two messages past the platform's longest); ``1e-12`` waited centuries. The slowest speed is
    ``recording.MIN_REPLAY_SPEED``, said before anything is published (exit 2, as any bad --speed)."""
    from cso_runtime.recording import MIN_REPLAY_SPEED

    for slow in ("1e-320", "1e-12", str(MIN_REPLAY_SPEED / 2)):
        with pytest.raises(ValueError, match=r"speed must be at least 0.001 \(recording.MIN_REPLAY_SPEED: 1000 times slower than recorded\) or 'max'"):
            parse_speed(slow)
    assert parse_speed(str(MIN_REPLAY_SPEED)) == MIN_REPLAY_SPEED and parse_speed("inf") == float("inf")
