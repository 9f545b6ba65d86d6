"""Wire format of the runtime's messages: round trips and rejection of anything untrustworthy."""

from __future__ import annotations

import functools
import math
import tracemalloc
import zlib

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cso_runtime.config import MAX_EPISODE_STEPS, ConfigError, EpisodeConfig
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D, VelocityCommand
from cso_runtime.keys import KeyExprError, RobotKeys, check_robot_id, robot_of, topic_of
from cso_runtime.messages import (
    DEFAULT_MAX_GRID_CELLS,
    LEGACY_UPGRADES,
    LOST_RESULTS_KEPT,
    MAX_PLANNER_STATE_BYTES,
    MAX_STEP_POINTS,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    ClockMsg,
    CmdVelMsg,
    DistanceMapMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    FrontiersMsg,
    GoalMsg,
    LauncherStatusMsg,
    MapMsg,
    Message,
    MessageError,
    OdometryMsg,
    PathMsg,
    PlannerContactsMsg,
    PlannerFeedbackMsg,
    PlannerFrontiersMsg,
    PlannerPlanMsg,
    ScanMsg,
    ServiceStatusMsg,
    decode,
    encode,
    frontiers_from_observation,
    frontiers_reading,
    max_grid_cells,
    max_planner_plan_bytes,
    observation_from_frontiers,
    pack_array,
    set_max_grid_cells,
    unpack_array,
    upgrade_payload,
)
from cso_runtime.observation import ObservationBuilder
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.policies import make_policy

GEOM = GridGeometry(0.1, (30, 40), 0.0, 0.0)


def _scan(ranges=None) -> ScanMsg:
    r = np.array([1.0, np.inf, 2.5, 0.05], dtype=np.float32) if ranges is None else ranges
    return ScanMsg(7, LaserScan(-math.pi / 2, 0.01, 0.1, 8.0, r, 1.75), Pose2D(1.0, 2.0, 0.3))


def _observation():
    """A real Observation: a room scanned once from its centre."""
    m = OccupancyMap(GEOM)
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    m.integrate_scan(Pose2D(2.0, 1.5, 0.0), LaserScan(-math.pi, angles[1] - angles[0], 0.1, 1.2, np.full(360, np.inf, np.float32)))
    return ObservationBuilder().build(m, Pose2D(2.0, 1.5, 0.0), np.array([[2.0, 1.5]]))


def _wire(schema: str, body: dict, version: int | None = None) -> bytes:
    """An envelope by hand; ``version`` defaults to the schema's current one."""
    if version is None:
        version = MESSAGE_TYPES[schema].VERSION if schema in MESSAGE_TYPES else SCHEMA_VERSION
    return msgpack.packb({"schema": schema, "v": version, "body": body}, use_bin_type=True)


def _body(msg) -> dict:
    return msgpack.unpackb(encode(msg), raw=False)["body"]


# --- round trips ---------------------------------------------------------------------------------


def test_scan_round_trip_keeps_inf_and_values():
    msg = decode(encode(_scan()), ScanMsg)
    assert isinstance(msg, ScanMsg)
    assert msg.step == 7 and msg.sensor_pose == Pose2D(1.0, 2.0, 0.3)
    np.testing.assert_array_equal(msg.scan.ranges_m, _scan().scan.ranges_m)
    assert msg.scan.stamp_s == 1.75 and msg.scan.angle_min_rad == -math.pi / 2


@pytest.mark.parametrize(
    "msg",
    [
        OdometryMsg(3, 0.75, Pose2D(1.0, -2.0, 3.1), VelocityCommand(0.4, -0.2)),
        CmdVelMsg(3, VelocityCommand(0.5, 0.1), ""),
        CmdVelMsg(4, VelocityCommand(), "stale: odom 3.0 s old"),
        GoalMsg(5, True, 1.5, 2.5, 2, 3.25, 12.5, "greedy-dist", "reached"),
        GoalMsg(5, True, decision_ms=1.0, method="greedy-dist"),
        CmdVelMsg(5, VelocityCommand(0.2, 0.0), "", new_goal=True),
        ClockMsg(2, 0.5, GEOM),
        ClockMsg(2, 0.5),
        EpisodeStatusMsg("exploring", 12, "gen_small_0", "greedy-dist", 45.5, 10.0, 3.2, [1.0, 2.0], 4, 11.0),
        ServiceStatusMsg("mapper", "r0", "running", 12, "", {"scan": 3}, 40),
        ServiceStatusMsg("ros2_bridge", "r0", "running", 12, "", {}, 40, {"received:scan": 41, "sent:cmd_vel": 39, "watchdog_stops": 1}),
        LauncherStatusMsg("run1", "running", {"sim": {"pid": 12, "restarts": 0}}, {"path": 1}),
        LauncherStatusMsg("run1", "running", {"ros2_bridge": {"pid": 12, "restarts": 1, "robot_stops": 1}}),
        LauncherStatusMsg("run1", "running", last_episode={"state": "exploring", "step": 41, "episode": 7, "age_s": 12.5}),
        LauncherStatusMsg("run1", "stopping", last_episode={"state": "done", "step": 90, "episode": 7, "age_s": 0.5, "terminated_by": "coverage", "scene": "s",
                                                            "method": "cso", "coverage_pct": 99.5, "explored_area_m2": 40.0, "path_length_m": 12.25, "decisions": 9}),
        LauncherStatusMsg("run1", "running", real_time_factor=2.125),
        LauncherStatusMsg("run1", "stopping", last_episode={"state": "done", "step": 90, "episode": 7, "age_s": 0.5, "map_origin": [1.0, -2.0, 0.5],
                                                            "pose": [0.5, 0.25, 0.1], "twist": [0.2, -0.1]}),
        LauncherStatusMsg("run1", "stopping", last_episode={"state": "exploring", "step": 0, "episode": 7, "age_s": 0.5, "pose": None, "twist": None}),
    ],
)
def test_small_messages_round_trip(msg):
    assert decode(encode(msg), type(msg)) == msg


def test_planner_feedback_carries_the_exact_path_ahead():
    """The frontier service re-runs the planner's blocked check on this path: it must arrive bit-exact."""
    path = np.array([[0.1, 0.2], [1.0 / 3.0, 2.0 / 7.0], [1e-9, 5.123456789012345]])
    back = decode(encode(PlannerFeedbackMsg(9, "following", "command", True, "", path)), PlannerFeedbackMsg)
    assert isinstance(back, PlannerFeedbackMsg)
    assert (back.step, back.status, back.phase, back.set_goal_blocked) == (9, "following", "command", True)
    assert back.path_ahead_xy_m.dtype == np.float64
    np.testing.assert_array_equal(back.path_ahead_xy_m, path)
    empty = decode(encode(PlannerFeedbackMsg(2, "idle", "command")), PlannerFeedbackMsg)
    assert empty.path_ahead_xy_m.shape == (0, 2)


def test_planner_contacts_arrive_bit_exact_and_bad_ones_are_refused():
    """A restarted planner plans round the contacts its cache gives back: the same cell centres, bit for bit, in the
    order kept; (n, 2) finite floats only."""
    contacts = np.array([[0.125, 1.0 / 3.0], [2.0 / 7.0, -5.123456789012345]])
    back = decode(encode(PlannerContactsMsg(14, contacts, 7)), PlannerContactsMsg)
    assert isinstance(back, PlannerContactsMsg) and (back.step, back.episode) == (14, 7)
    assert back.contacts_xy_m.dtype == np.float64
    np.testing.assert_array_equal(back.contacts_xy_m, contacts)
    assert decode(encode(PlannerContactsMsg(0, np.zeros((0, 2)))), PlannerContactsMsg).contacts_xy_m.shape == (0, 2)
    good = _body(PlannerContactsMsg(3, contacts, 7))
    for bad, said in [
        ({**good, "contacts_xy_m": pack_array(np.zeros((2, 3)))}, "does not fit \\[n, 2\\]"),
        ({**good, "contacts_xy_m": pack_array(np.zeros(4))}, "does not fit \\[n, 2\\]"),
        ({**good, "contacts_xy_m": pack_array(np.zeros((2, 2), np.int64))}, "expected float32 or float64, got int64"),
        ({**good, "contacts_xy_m": _body(PlannerContactsMsg(3, np.array([[np.nan, 0.0]])))["contacts_xy_m"]}, "contacts_xy_m"),
        ({**good, "step": -1}, "step"),
        ({k: v for k, v in good.items() if k != "episode"}, "missing field 'episode'"),
    ]:
        with pytest.raises(MessageError, match=said):
            decode(_wire("planner_contacts", bad), PlannerContactsMsg)


def test_keep_goal_frontiers_round_trip():
    back = decode(encode(FrontiersMsg(6, False, "")), FrontiersMsg)
    assert isinstance(back, FrontiersMsg) and back.step == 6 and not back.decide and not back.clusters


def test_map_round_trip_is_compressed():
    m = OccupancyMap(GridGeometry(0.05, (200, 300)))
    grid = m.to_occupancy_grid()
    grid[10:20, 10:50] = 0
    grid[15, 10:50] = 100
    payload = encode(MapMsg.from_grid(4, m.geometry, grid))
    assert len(payload) < grid.size / 20
    back = decode(payload, MapMsg)
    assert isinstance(back, MapMsg) and back.geometry == m.geometry
    np.testing.assert_array_equal(back.grid, grid)
    np.testing.assert_array_equal(back.explored, grid >= 0)
    np.testing.assert_array_equal(back.occupied, grid == 100)
    np.testing.assert_array_equal(back.occupancy().open, grid == 0)


def test_a_map_message_is_a_snapshot_of_the_map():
    """``MapMsg.of`` keeps the channels as they were: the mapper goes on integrating into its map."""
    m = OccupancyMap(GridGeometry(0.1, (20, 30)))
    m.explored[2:5, 2:5] = True
    m.occupied[3, 3] = True
    m.occupied[10, 10] = True  # not explored: not occupied in the message (as in the OccupancyGrid)
    msg = MapMsg.of(7, m, 2)
    m.explored[:] = True
    assert msg.explored.sum() == 9 and msg.occupied.sum() == 1 and msg.grid[3, 3] == 100 and msg.grid[10, 10] == -1


@pytest.mark.parametrize("shape", [(30, 40), (7, 13), (1, 1), (0, 5)])
def test_boolean_grids_travel_bit_packed_and_come_back_exactly(shape):
    rng = np.random.default_rng(3)
    grid = rng.random(shape) < 0.3
    rec = pack_array(grid, compress=True)
    assert rec["z"] == "bits" and rec["dtype"] == "bool"
    assert len(zlib.decompress(rec["data"])) == (grid.size + 7) // 8  # 8 cells to a byte
    back = unpack_array(rec, "grid", ndim=2)
    assert back.dtype == np.bool_ and back.shape == shape and back.flags.writeable
    np.testing.assert_array_equal(back, grid)


@pytest.mark.parametrize("dtype", ["int8", "int32", "float32", "float64"])
def test_compressed_arrays_of_every_width_round_trip(dtype):
    """zlib-compressed arrays (at least ``COMPRESS_MIN_BYTES``, e.g. a large cluster's cells) come back whole."""
    a = np.arange(3001 * 2, dtype=dtype).reshape(3001, 2)
    rec = pack_array(a)
    assert rec["z"] is True
    np.testing.assert_array_equal(unpack_array(rec, "a", ndim=2), a)
    with pytest.raises(MessageError):  # one element more than the shape says
        unpack_array(dict(rec, data=zlib.compress(a.tobytes() + a.tobytes()[: a.itemsize])), "a", ndim=2)


def test_bad_bit_packed_grids_are_rejected():
    rec = pack_array(np.ones((7, 13), bool), compress=True)
    packed = zlib.decompress(rec["data"])
    cases = [
        dict(rec, dtype="uint8"),  # bit-packed data is boolean only
        dict(rec, data=zlib.compress(packed[:-1])),  # a byte short
        dict(rec, data=zlib.compress(packed + b"\x00")),  # a byte too many
        dict(rec, data=b"not zlib"),
        dict(rec, data=zlib.compress(b"\x00" * 50_000_000)),  # inflates far beyond the grid: stops one byte past it
        dict(rec, z="lz4"),  # an unknown codec
    ]
    for bad in cases:
        with pytest.raises(MessageError):
            unpack_array(bad, "grid", ndim=2)


def _zlib_bomb(mib: int = 1024) -> bytes:
    """The start of a valid zlib stream that inflates to ``mib`` MiB of zeros, about 1 kB a MiB, made in milliseconds:
    one deflate block of 1 MiB of zeros, fully flushed (so that it stands alone), repeated."""
    deflate = zlib.compressobj(9)
    head = deflate.compress(b"")
    block = deflate.compress(bytes(1 << 20)) + deflate.flush(zlib.Z_FULL_FLUSH)
    return head + block * mib


def _peak_bytes(decode_it) -> int:
    """The most memory (bytes, Python's allocators: numpy's arrays and zlib's output included) ``decode_it()`` held at
    once, which must raise MessageError."""
    tracemalloc.start()
    try:
        with pytest.raises(MessageError) as raised:
            decode_it()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        del raised


def test_a_zlib_bomb_is_refused_by_the_size_its_record_declares_not_by_running_out_of_memory():
    """A megabyte that inflates to a gigabyte, in a record that declares 4 floats or 1200 bit-packed cells: inflated
    one byte past the declared size, then refused."""
    bomb = _zlib_bomb()
    for rec in ({"dtype": "float32", "shape": [2, 2], "z": True, "data": bomb}, {"dtype": "bool", "shape": [30, 40], "z": "bits", "data": bomb}):
        assert _peak_bytes(functools.partial(unpack_array, rec, "a")) < 4 << 20


def test_a_record_whose_shape_its_message_contradicts_is_refused_before_its_data_is_inflated():
    """A 30 x 40 map whose explored grid declares 50 million cells, a distance map with 50 million finite values for
    its 1200 cells: both declare a size ``unpack_array`` accepts, but not the one the message implies (the geometry's,
    one value per set cell of the mask), and are refused before anything is inflated (they were refused after
    inflating 50 MB and 400 MB)."""
    bomb = _zlib_bomb()
    good_map = _body(MapMsg(1, GEOM, np.ones(GEOM.shape, bool), np.zeros(GEOM.shape, bool)))
    big_grid = {"dtype": "bool", "shape": [5000, 10_000], "z": True, "data": bomb}
    payload = _wire("map", {**good_map, "explored": big_grid})
    assert _peak_bytes(lambda: decode(payload)) < 4 << 20  # the payload's 1 MB bin, copied by msgpack
    good_d = _body(DistanceMapMsg(1, GEOM, Pose2D(1.0, 1.0, 0.0), np.zeros(GEOM.shape)))
    many = {"dtype": "float64", "shape": [50_000_000], "z": True, "data": bomb}
    payload = _wire("distance_map", {**good_d, "distance_m": many})
    assert _peak_bytes(lambda: decode(payload)) < 4 << 20


def test_the_clusters_of_a_decision_together_hold_no_more_cells_than_its_grid():
    """Each cluster's cells are one record, and there may be any number of clusters: twenty records of a million zero
    cells (16 kB of zlib each) inflated to 320 MB, and were accepted (cell [0, 0] is inside the grid). The clusters share
    the grid's cells (each frontier cell is in one), so the cells left to them bound each record before it is inflated."""
    obs = _observation()
    good = _body(frontiers_from_observation(3, "no_goal", obs, 1.0))
    ny, nx = obs.geometry.shape
    assert decode(_wire("frontiers", good), FrontiersMsg).clusters  # at most ny * nx cells in all: fine
    half = dict(good["clusters"][0], cells=pack_array(np.zeros((ny * nx // 2, 2), np.int32), compress=True))
    assert len(decode(_wire("frontiers", {**good, "clusters": [half, half]}), FrontiersMsg).clusters) == 2
    with pytest.raises(MessageError, match="too large"):
        decode(_wire("frontiers", {**good, "clusters": [half, half, half]}))
    bomb = dict(good["clusters"][0], cells={"dtype": "int64", "shape": [1_000_000, 2], "z": True, "data": zlib.compress(bytes(16_000_000), 9)})
    payload = _wire("frontiers", {**good, "clusters": [bomb] * 20})
    assert _peak_bytes(lambda: decode(payload)) < 4 << 20


def test_a_scan_declaring_more_beams_than_a_scan_may_have_is_refused_before_its_ranges_are_inflated():
    """A scan may hold at most MAX_BEAMS ranges, which ``unpack_array`` knew only after inflating them: a 16 kB stream
    declaring a million float64 ranges was inflated to 8 MB (and copied) before the beam count refused it; 50 million
    ranges, 800 MB."""
    good = _body(_scan())
    many = {"dtype": "float64", "shape": [1_000_000], "z": True, "data": _zlib_bomb(16)}
    payload = _wire("scan", {**good, "ranges_m": many})
    assert _peak_bytes(lambda: decode(payload)) < 4 << 20
    with pytest.raises(MessageError, match="too large"):
        decode(payload)


def test_free_length_arrays_declaring_more_entries_than_an_episode_has_steps_are_refused_before_they_are_inflated():
    """A decision's path nodes (one per decision) and a result's trajectory, decision times and coverage curve (one per
    step or decision) are free-length, and each could declare MAX_GRID_CELLS elements (400 MB of float64), whatever
    the message's grid: a small payload made a receiver inflate 80 MB per record here (three records in a result,
    gigabytes at MAX_GRID_CELLS). Each holds at most MAX_STEP_POINTS entries (``episode.max_steps`` is at most
    MAX_EPISODE_STEPS), checked on its record."""
    five_million_points = {"dtype": "float64", "shape": [5_000_000, 2], "z": True, "data": _zlib_bomb(80)}
    five_million = {"dtype": "float64", "shape": [5_000_000], "z": True, "data": _zlib_bomb(40)}
    decision = _body(frontiers_from_observation(3, "no_goal", _observation(), 1.0))
    result = _body(_episode_result(3))
    for schema, body in [
        ("frontiers", {**decision, "path_nodes_xy_m": five_million_points}),
        ("episode_result", {**result, "trajectory_xy_m": five_million_points}),
        ("episode_result", {**result, "decision_ms": five_million}),
        ("episode_result", {**result, "coverage_curve_pct": five_million}),
    ]:
        payload = _wire(schema, body)
        assert len(payload) < 100_000
        assert _peak_bytes(lambda payload=payload: decode(payload)) < 4 << 20
        with pytest.raises(MessageError, match=f"too large \\(10000000 elements, at most {2 * MAX_STEP_POINTS}\\)|too large \\(5000000 elements, at most {MAX_STEP_POINTS}\\)"):
            decode(payload)


def _episode_result(steps: int, geometry: GridGeometry = GEOM, free: np.ndarray | None = None) -> EpisodeResultMsg:
    """A result of ``steps`` steps, one decision a step: as long as its arrays may be (constant values: quick to zlib)."""
    free = np.ones(geometry.shape, bool) if free is None else free
    n = steps + 1
    return EpisodeResultMsg(
        "dungeon_1", steps, 10.0, 50.0, 20.0, 30.0, "max_steps", n, np.full(n, 4.5), np.full((n, 2), 1.5), np.full(n, 50.0), free, free, geometry.resolution_m
    )


def test_the_largest_legitimate_messages_still_pass_the_bounds():
    """A decision on a 640 x 480 map (a Dungeon floor plan's size at 0.05 m) with a path node per decision of the longest
    episode allowed, and that episode's result on the same grid: every array at its bound is read back whole."""
    geometry = GridGeometry(0.05, (480, 640), 0.0, 0.0)
    m = OccupancyMap(geometry)
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    m.integrate_scan(Pose2D(16.0, 12.0, 0.0), LaserScan(-math.pi, angles[1] - angles[0], 0.1, 8.0, np.full(720, np.inf, np.float32)))
    obs = ObservationBuilder().build(m, Pose2D(16.0, 12.0, 0.0), np.array([[16.0, 12.0]]))
    body = _body(frontiers_from_observation(3, "timeout", obs, 12.0))
    body["path_nodes_xy_m"] = pack_array(np.tile([[16.0, 12.0]], (MAX_STEP_POINTS, 1)))  # a node per decision, each step
    body["path_nodes_distance_m"] = pack_array(np.zeros(MAX_STEP_POINTS))
    back = decode(_wire("frontiers", body), FrontiersMsg)
    assert back.geometry == geometry and back.path_nodes_xy_m.shape == (MAX_STEP_POINTS, 2) and len(back.clusters) == len(obs.clusters)
    np.testing.assert_array_equal(back.arrays["entropy"], obs.entropy)
    result = decode(encode(_episode_result(MAX_EPISODE_STEPS, geometry, m.explored & ~m.occupied)), EpisodeResultMsg)
    assert result.trajectory_xy_m.shape == (MAX_STEP_POINTS, 2) and result.decision_ms.size == result.coverage_curve_pct.size == MAX_STEP_POINTS
    too_long = _body(_episode_result(MAX_EPISODE_STEPS + 1))
    with pytest.raises(MessageError, match="too large"):
        decode(_wire("episode_result", too_long))


def test_episode_max_steps_is_at_most_what_a_result_message_holds():
    EpisodeConfig(max_steps=MAX_EPISODE_STEPS).validate()
    with pytest.raises(ConfigError, match=r"episode\.max_steps must be in \[1, 1,000,000\] .*got 1,000,001$"):
        EpisodeConfig(max_steps=MAX_EPISODE_STEPS + 1).validate()


def test_an_empty_array_with_a_huge_dimension_is_a_message_error():
    """0 elements, so no size limit stops it, but numpy cannot shape it: a MessageError, not numpy's ValueError."""
    for shape in ([0, 2**62], [2**40, 0]):
        with pytest.raises(MessageError, match="bad shape"):
            unpack_array({"dtype": "int32", "shape": shape, "z": False, "data": b""}, "cells", ndim=2)


def test_path_and_result_round_trip():
    p = decode(encode(PathMsg(3, np.array([[0.0, 0.0], [1.0, 0.5]]))), PathMsg)
    np.testing.assert_allclose(p.path_xy_m, [[0.0, 0.0], [1.0, 0.5]])
    free = np.zeros((5, 6), bool)
    free[1:4, 1:5] = True
    res = EpisodeResultMsg(
        "s", 10, 1.2, 98.0, 1.3, 4.5, "coverage", 3, np.array([1.0, 2.0]), np.zeros((11, 2)), np.linspace(0, 98, 11), free, free, 0.1, "greedy-dist", 0
    )
    back = decode(encode(res), EpisodeResultMsg)
    assert back.steps == 10 and back.terminated_by == "coverage" and back.method == "greedy-dist"
    np.testing.assert_array_equal(back.explored_free, free)
    np.testing.assert_allclose(back.coverage_curve_pct, res.coverage_curve_pct)
    assert back.final_map is None  # no map arrived: none is invented

    # With the referee's last map (v3): the same grid comes back, so the launcher can write it.
    geometry = GridGeometry(0.1, (5, 6), -1.0, 2.0)
    explored = free.copy()
    occupied = np.zeros_like(free)
    occupied[1, 1:5] = True
    res.final_map = MapMsg(9, geometry, explored, occupied)
    back = decode(encode(res), EpisodeResultMsg)
    assert back.final_map is not None and back.final_map.geometry == geometry and back.final_map.step == 9
    np.testing.assert_array_equal(back.final_map.grid, res.final_map.grid)
    body = msgpack.unpackb(encode(res))
    body["body"]["final_map"]["occupied"] = body["body"]["final_map"]["explored"]
    body["body"]["final_map"]["explored"] = pack_array(np.zeros((5, 6), bool), compress=True)  # occupied but never seen
    with pytest.raises(MessageError, match="episode_result.final_map.occupied"):
        decode(msgpack.packb(body), EpisodeResultMsg)
    body["body"]["final_map"] = [1, 2]
    with pytest.raises(MessageError, match="final_map"):
        decode(msgpack.packb(body), EpisodeResultMsg)


def test_frontiers_rebuild_the_same_observation_and_decision():
    obs = _observation()
    assert obs.clusters, "the fixture must have frontier clusters"
    back = decode(encode(frontiers_from_observation(3, "no_goal", obs, 4.5)), FrontiersMsg)
    assert isinstance(back, FrontiersMsg) and back.decide and back.reason == "no_goal"
    rebuilt = observation_from_frontiers(back)
    for name in ("explored", "occupied", "traversable", "frontier", "entropy"):
        np.testing.assert_array_equal(getattr(rebuilt, name), getattr(obs, name))
    assert rebuilt.geometry == obs.geometry and rebuilt.pose == obs.pose
    assert [c.goal_cell for c in rebuilt.clusters] == [c.goal_cell for c in obs.clusters]
    for name in ("greedy-dist", "greedy-info", "utility", "cso"):
        assert make_policy(name).select(rebuilt) == make_policy(name).select(obs)
        # Decoded as the policy service does: only the grids the selector reads (the baselines: none).
        grids = make_policy(name).grids
        assert grids == (() if name != "cso" else ("traversable",))
        narrow = decode(encode(frontiers_from_observation(3, "no_goal", obs, 4.5)), frontiers_reading(grids))
        assert set(narrow.arrays) == set(grids)
        assert make_policy(name).select(observation_from_frontiers(narrow)) == make_policy(name).select(obs)
    assert rebuilt.distance_m is None  # the graph policy read D at the path nodes only: no pass was needed
    np.testing.assert_array_equal(rebuilt.distance_map(), obs.distance_m)  # computed again: the same values


def test_the_planner_reads_the_verdict_and_its_three_grids_and_validates_those():
    """``PlannerFrontiersMsg`` decodes what the planner uses (the grid it plans on, with the pose and
    geometry; the obstacles and the seen cells it checks before reversing); a bad grid it reads is rejected, a bad one it does not read is the policy's to reject."""
    obs = _observation()
    msg = frontiers_from_observation(3, "no_goal", obs, 4.5)
    view = decode(encode(msg), PlannerFrontiersMsg)
    assert isinstance(view, PlannerFrontiersMsg) and view.decide and (view.step, view.reason) == (3, "no_goal")
    assert view.pose == obs.pose and view.geometry == obs.geometry and set(view.arrays) == {"traversable", "occupied", "explored"}
    np.testing.assert_array_equal(view.arrays["traversable"], obs.traversable)
    np.testing.assert_array_equal(view.arrays["occupied"], obs.occupied)  # checked before the robot reverses
    np.testing.assert_array_equal(view.arrays["explored"], obs.explored)  # unknown behind the robot: no reverse
    keep = decode(encode(FrontiersMsg(4, False)), PlannerFrontiersMsg)
    assert (keep.step, keep.decide) == (4, False)
    body = _body(msg)
    body["arrays"]["entropy"]["data"] = b"junk"
    assert decode(_wire("frontiers", body), PlannerFrontiersMsg).decide  # not read here
    with pytest.raises(MessageError):
        decode(_wire("frontiers", body), FrontiersMsg)
    body["arrays"]["traversable"]["data"] = b"junk"
    with pytest.raises(MessageError, match="traversable"):
        decode(_wire("frontiers", body), PlannerFrontiersMsg)


def test_observation_reads_d_at_path_nodes_and_computes_it_again_for_other_cells():
    obs = _observation()
    nodes = np.array([[2.0, 1.5], [2.5, 1.5], [0.35, 0.35], [-5.0, 1.0]])  # the robot, reachable, unknown, off the map
    obs = type(obs)(**{**obs.__dict__, "path_nodes_xy_m": nodes})
    msg = decode(encode(frontiers_from_observation(3, "no_goal", obs, 1.0)), FrontiersMsg)
    expected = obs.distance_at(nodes)
    assert np.isfinite(expected[:2]).all() and np.isinf(expected[2:]).all()
    np.testing.assert_array_equal(msg.path_nodes_distance_m, expected)
    rebuilt = observation_from_frontiers(msg)
    np.testing.assert_array_equal(rebuilt.distance_at(nodes[::-1]), expected[::-1])
    assert rebuilt.distance_m is None
    other = np.array([[1.6, 1.2]])  # not a path node: D is computed again, once
    assert rebuilt.distance_at(other)[0] == obs.distance_at(other)[0] and np.isfinite(obs.distance_at(other)[0])
    np.testing.assert_array_equal(rebuilt.distance_m, obs.distance_m)


# --- rejections ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"garbage",
        b"\xc1\xc1\xc1",
        msgpack.packb([1, 2, 3]),
        msgpack.packb({"schema": "scan", "v": 1}),
        _wire("nope", {}),
        _wire("scan", {}, version=2),
        _wire("scan", {}, version=True),
        _wire("scan", []),
    ],
)
def test_malformed_envelopes_are_rejected(payload):
    with pytest.raises(MessageError):
        decode(payload)


def test_unknown_version_says_so():
    body = _body(_scan())
    with pytest.raises(MessageError, match="unknown version"):
        decode(_wire("scan", body, version=ScanMsg.VERSION + 1))


def test_clock_scan_and_episode_status_carry_the_episode_and_reject_version_1():
    """The three schemas gained the episode id in v2: a v1 payload (no id) is an unknown version."""
    clock = ClockMsg(3, 0.75, GridGeometry(0.1, (4, 5)), episode=2**47 + 5)
    assert decode(encode(clock)) == clock
    status = EpisodeStatusMsg("exploring", 3, episode=7)
    assert decode(encode(status)).episode == 7
    scan = _scan()
    scan.episode = 9
    assert decode(encode(scan)).episode == 9
    for msg in (clock, status, scan):
        body = _body(msg)
        del body["episode"]
        with pytest.raises(MessageError, match="unknown version 1"):
            decode(_wire(msg.SCHEMA, body, version=1))
        with pytest.raises(MessageError, match="episode"):
            decode(_wire(msg.SCHEMA, body))


# --- older versions, in recordings ---------------------------------------------------------------


def _legacy_cases() -> list[tuple[bytes, Message]]:
    """(payload of the version before the episode id, written by hand, the message it means today: episode 0)."""
    obs = _observation()
    decision = frontiers_from_observation(4, "no_goal", obs, 2.5)
    path = np.array([[1.0, 2.0], [1.5, 2.5]])
    return [
        (
            _wire("odom", {"step": 3, "stamp_s": 0.75, "pose": [1.0, -0.5, 0.3], "twist": [0.2, 0.1]}, version=1),
            OdometryMsg(3, 0.75, Pose2D(1.0, -0.5, 0.3), VelocityCommand(0.2, 0.1)),
        ),
        (
            _wire("goal", {"step": 4, "decided": True, "goal": [2.0, 1.0, 0, 3.5], "decision_ms": 4.2, "method": "greedy-dist", "reason": ""}, version=1),
            GoalMsg(4, True, 2.0, 1.0, 0, 3.5, 4.2, "greedy-dist"),
        ),
        (_wire("goal", {"step": 5, "decided": False, "goal": None, "decision_ms": 0.0, "method": "", "reason": ""}, version=1), GoalMsg(5, False)),
        (_wire("frontiers", {"step": 6, "decide": False, "reason": "keep"}, version=6), FrontiersMsg(6, False, "keep")),
        (_wire("frontiers", {k: v for k, v in _body(decision).items() if k != "episode"}, version=6), decision),
        (
            _wire("distance_map", {k: v for k, v in _body(DistanceMapMsg(4, obs.geometry, obs.pose, obs.distance_m)).items() if k != "episode"}, version=1),
            DistanceMapMsg(4, obs.geometry, obs.pose, obs.distance_m),
        ),
        (
            _wire(
                "planner_feedback",
                {"step": 7, "status": "following", "phase": "command", "set_goal_blocked": False, "reason": "", "path_ahead_xy_m": pack_array(path), "goal_step": 4},
                version=2,
            ),
            PlannerFeedbackMsg(7, "following", "command", False, "", path, 4),
        ),
    ]


def test_each_older_version_upgrades_to_the_current_one_with_episode_0_offline_only():
    """The five schemas that gained the episode id (odom, goal, distance_map v2; planner_feedback v3;
    frontiers v7): a payload of the version before reads as today's message with id 0 ("no id") in the
    offline tools; a live service's ``decode`` still rejects it as an unknown version."""
    cases = _legacy_cases()
    # (service_status v1, which lacked the counters, episode_status v2 / episode_result v3, the map origin, and
    # episode_status v3, the robot's pose, not the episode id: their own tests below)
    others = {("service_status", 1), ("episode_status", 2), ("episode_status", 3), ("episode_result", 3), ("cmd_vel", 2)}
    assert {(msgpack.unpackb(p)["schema"], msgpack.unpackb(p)["v"]) for p, _ in cases} | others == set(LEGACY_UPGRADES)
    for payload, expected in cases:
        cls = type(expected)
        with pytest.raises(MessageError, match=rf"{cls.SCHEMA}: unknown version {cls.VERSION - 1} \(this build speaks v{cls.VERSION}\)"):
            decode(payload, cls)
        upgraded = upgrade_payload(payload)
        assert msgpack.unpackb(upgraded)["v"] == cls.VERSION
        for msg in (decode(upgraded, cls), decode(payload, cls, accept_legacy=True)):
            assert type(msg) is cls and msg.episode == 0
            assert encode(msg) == encode(expected), cls.SCHEMA  # the same message, field for field (arrays included)
    assert FrontiersMsg.VERSION == 7, "the episode id came with v7 (b3bfa9e wrote it under v6)"


def test_a_service_status_of_v1_reads_offline_with_no_counters_and_live_stays_strict():
    """v2 added the service's own counts (``counters``, ``Service.extra_status``); a recorded v1 reads with none."""
    v1 = _wire("service_status", {k: v for k, v in _body(ServiceStatusMsg("mapper", "r0", "running", 3, "", {"scan": 1}, 4)).items() if k != "counters"}, version=1)
    with pytest.raises(MessageError, match=r"service_status: unknown version 1 \(this build speaks v2\)"):
        decode(v1, ServiceStatusMsg)
    for msg in (decode(upgrade_payload(v1), ServiceStatusMsg), decode(v1, ServiceStatusMsg, accept_legacy=True)):
        assert msg == ServiceStatusMsg("mapper", "r0", "running", 3, "", {"scan": 1}, 4, {})
    with pytest.raises(MessageError, match="service_status: missing field 'counters'"):  # v2 must carry them
        decode(_wire("service_status", msgpack.unpackb(v1)["body"]), ServiceStatusMsg)


def test_episode_status_and_result_carry_the_scenes_map_origin_and_older_ones_read_with_none():
    """v3 / v4 carry the scene's pose in the user's map frame (a map_server scene's ``origin``), which ``status``,
    ``save-map`` and ``up``'s map files use; a recorded episode_status v2 or episode_result v3 reads as the scene's
    frame being the map frame, as it was taken then."""
    status = EpisodeStatusMsg("exploring", 5, scene="office", goal_xy_m=[1.0, 1.5], episode=3, map_origin=Pose2D(-3.5, 2.0, 0.5))
    assert decode(encode(status), EpisodeStatusMsg) == status
    free = np.ones((3, 4), dtype=bool)
    result = EpisodeResultMsg("office", 9, 1.0, 50.0, 2.0, 3.0, "coverage", 2, np.ones(2), np.zeros((3, 2)), np.ones(3), free, free, 0.5, map_origin=Pose2D(-3.5, 2.0, 0.0))
    assert decode(encode(result), EpisodeResultMsg).map_origin == Pose2D(-3.5, 2.0, 0.0)
    for msg, older in ((status, 2), (result, 3)):
        body = {k: v for k, v in _body(msg).items() if k != "map_origin"}
        payload = _wire(msg.SCHEMA, body, version=older)
        with pytest.raises(MessageError, match=rf"{msg.SCHEMA}: unknown version {older}"):
            decode(payload, type(msg))
        for read in (decode(upgrade_payload(payload), type(msg)), decode(payload, type(msg), accept_legacy=True)):
            assert read.map_origin == Pose2D(0.0, 0.0, 0.0)
            assert not isinstance(read, EpisodeStatusMsg) or (read.pose, read.twist) == (None, None)  # nor the robot's pose
    with pytest.raises(MessageError, match="episode_status: missing field 'map_origin'"):  # v3 must carry it
        decode(_wire("episode_status", {k: v for k, v in _body(status).items() if k != "map_origin"}), EpisodeStatusMsg)


def test_episode_status_carries_the_robots_pose_and_twist_and_a_v3_one_reads_with_none():
    """v4 carries the robot's odometry pose and twist (what ``status`` and the live view show of where the robot is); a
    recorded v3 reads offline with none, unknown, and a live service still rejects it as an unknown version."""
    status = EpisodeStatusMsg("exploring", 5, goal_xy_m=[1.0, 1.5], episode=3, map_origin=Pose2D(-3.5, 2.0, 0.5), pose=Pose2D(1.25, -0.5, 3.0), twist=VelocityCommand(0.25, -0.1))
    assert decode(encode(status), EpisodeStatusMsg) == status
    assert _body(status)["pose"] == [1.25, -0.5, 3.0] and _body(status)["twist"] == [0.25, -0.1]
    unknown = EpisodeStatusMsg("starting", 0)  # a ROS 2 bridge before its first scan: no odometry yet
    assert _body(unknown)["pose"] is None and decode(encode(unknown), EpisodeStatusMsg) == unknown
    v3 = _wire("episode_status", {k: v for k, v in _body(status).items() if k not in ("pose", "twist")}, version=3)
    with pytest.raises(MessageError, match=r"episode_status: unknown version 3 \(this build speaks v4\)"):
        decode(v3, EpisodeStatusMsg)
    for read in (decode(upgrade_payload(v3), EpisodeStatusMsg), decode(v3, EpisodeStatusMsg, accept_legacy=True)):
        assert read == EpisodeStatusMsg("exploring", 5, goal_xy_m=[1.0, 1.5], episode=3, map_origin=Pose2D(-3.5, 2.0, 0.5))
    for missing in ("pose", "twist"):  # v4 must carry both (null while unknown)
        with pytest.raises(MessageError, match=f"episode_status: missing field '{missing}'"):
            decode(_wire("episode_status", {k: v for k, v in _body(status).items() if k != missing}), EpisodeStatusMsg)


def test_episode_status_may_say_whether_its_referee_measures_coverage_and_a_body_without_it_still_reads():
    """A referee says whether it has a ground truth, its ``coverage_pct`` a measure (``coverage_measured``: the sim yes,
    a ROS 2 bridge no, a referee of one's own as it knows), so that ``status`` can say n/a with no launcher to ask. The
    field is optional in v4, no version bump: a body without it (every referee before it, or one that does not say)
    reads as not said (None), and none is sent then, so an older reader gets the body it always got; a newer reader's
    older peer ignores the field (docs/messages.md: a receiver ignores a body field it does not know)."""
    assert EpisodeStatusMsg.VERSION == 4
    for said in (True, False):
        status = EpisodeStatusMsg("exploring", 5, coverage_pct=12.5, episode=3, coverage_measured=said)
        assert _body(status)["coverage_measured"] is said and decode(encode(status), EpisodeStatusMsg) == status
    unsaid = EpisodeStatusMsg("exploring", 5, coverage_pct=12.5, episode=3)
    assert "coverage_measured" not in _body(unsaid) and decode(encode(unsaid), EpisodeStatusMsg) == unsaid
    assert unsaid.coverage_measured is None and "coverage_measured" not in unsaid.to_dict()
    older = _body(unsaid)  # a v4 body as every referee sent it before the field
    assert decode(_wire("episode_status", older), EpisodeStatusMsg).coverage_measured is None
    assert decode(_wire("episode_status", {**older, "coverage_measured": None}), EpisodeStatusMsg).coverage_measured is None
    for wrong in (1, 0, "yes"):  # a flag is msgpack true/false, not 0/1
        with pytest.raises(MessageError, match=r"episode_status\.coverage_measured: expected true/false"):
            decode(_wire("episode_status", {**older, "coverage_measured": wrong}), EpisodeStatusMsg)
    v3 = _wire("episode_status", {k: v for k, v in older.items() if k not in ("pose", "twist")}, version=3)
    assert decode(v3, EpisodeStatusMsg, accept_legacy=True).coverage_measured is None  # a recording: not said either


def test_cmd_vel_carries_the_planners_state_and_plan_opaque_and_bounded_and_a_foreign_one_needs_neither():
    """v3: the project's planner hands the referee its state (every step) and plan (when it changed) on ``cmd_vel``, as the
    encoded messages, which ``cmd_vel``'s decoding leaves unread (the referee serves them as they came). Each is bounded
    before its receiver keeps it; a command without them (a foreign planner's, a v2 one in a recording) is the same
    command, with neither."""
    plan = encode(PlannerPlanMsg(3, np.array([[0.0, 0.0], [1.0, 0.5]]), None, 7))
    state = b"\x93not decoded here"  # opaque to cmd_vel: only the cache's reader decodes it
    cmd = CmdVelMsg(3, VelocityCommand(0.2, -0.1), "", True, 7, state, plan)
    assert decode(encode(cmd), CmdVelMsg) == cmd and _body(cmd)["planner_state"] == state
    plain = CmdVelMsg(3, VelocityCommand(0.2, -0.1), "", True)
    assert set(_body(plain)) == {"step", "linear_mps", "angular_radps", "reason", "new_goal"}  # a foreign planner's body: v3 all the same
    for nil in (None, 0):
        foreign = {**_body(plain), "planner_state": None, "planner_plan": None, "episode": nil}
        assert decode(_wire("cmd_vel", foreign), CmdVelMsg) == plain
    with pytest.raises(MessageError, match="cmd_vel.planner_state: too large"):
        decode(_wire("cmd_vel", {**_body(plain), "planner_state": bytes(MAX_PLANNER_STATE_BYTES + 1)}), CmdVelMsg)
    with pytest.raises(MessageError, match="cmd_vel.planner_plan: expected bytes or null"):
        decode(_wire("cmd_vel", {**_body(plain), "planner_plan": "a plan"}), CmdVelMsg)
    small = 64 * 64
    try:
        set_max_grid_cells(small)  # a run of small grids: the plan's bound follows the run's
        assert max_planner_plan_bytes() == 16 * small + small // 4 + 65536
        assert decode(_wire("cmd_vel", {**_body(plain), "planner_plan": bytes(max_planner_plan_bytes())}), CmdVelMsg).planner_plan is not None
        with pytest.raises(MessageError, match="cmd_vel.planner_plan: too large"):
            decode(_wire("cmd_vel", {**_body(plain), "planner_plan": bytes(max_planner_plan_bytes() + 1)}), CmdVelMsg)
    finally:
        set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)
    v2 = _wire("cmd_vel", _body(plain), version=2)
    with pytest.raises(MessageError, match=r"cmd_vel: unknown version 2 \(this build speaks v3\)"):
        decode(v2, CmdVelMsg)
    assert decode(upgrade_payload(v2), CmdVelMsg) == plain == decode(v2, CmdVelMsg, accept_legacy=True)


def test_a_current_payload_is_not_touched_and_a_v6_frontiers_with_its_id_keeps_it():
    current = encode(OdometryMsg(3, 0.75, Pose2D(1.0, -0.5, 0.3), episode=11))
    assert upgrade_payload(current) is current  # replayed byte for byte
    assert decode(current, OdometryMsg, accept_legacy=True).episode == 11
    # b3bfa9e sent the id under v6 (its version bump was missed): such a payload keeps its id.
    interim = _wire("frontiers", {"step": 6, "decide": False, "reason": "keep", "episode": 5}, version=6)
    assert decode(upgrade_payload(interim), FrontiersMsg).episode == 5


@pytest.mark.parametrize(
    ("payload", "match"),
    [
        (_wire("odom", {}, version=99), r"odom: unknown version 99 \(this build reads v2, v1\)"),
        (_wire("odom", {}, version=True), r"odom: unknown version True \(this build reads v2, v1\)"),
        (_wire("frontiers", {}, version=5), r"frontiers: unknown version 5 \(this build reads v7, v6\)"),
        (_wire("scan", {}, version=1), r"scan: unknown version 1 \(this build reads v2\)"),
        (_wire("goal", {"step": 4, "decided": True}, version=1), r"goal: missing field 'goal'"),  # an older body that is not one
        (_wire("odom", [], version=1), r"odom: body is not a mapping"),
        (b"garbage", r"not a msgpack payload"),
    ],
    ids=["future", "bool", "older-than-known", "not-upgraded", "bad-old-body", "not-a-body", "not-msgpack"],
)
def test_what_no_version_of_this_build_reads_is_still_a_clear_error_offline(payload, match):
    with pytest.raises(MessageError, match=match):
        upgrade_payload(payload)
    with pytest.raises(MessageError, match=match):
        decode(payload, accept_legacy=True)


def test_wrong_schema_for_the_key_is_rejected():
    with pytest.raises(MessageError, match="expected schema"):
        decode(encode(_scan()), MapMsg)


@pytest.mark.parametrize(
    "ranges",
    [np.array([1.0, np.nan], np.float32), np.array([1.0, -0.5], np.float32), np.zeros(0, np.float32), np.array([[1.0]], np.float32)],
)
def test_bad_scan_ranges_are_rejected(ranges):
    with pytest.raises(MessageError):
        decode(encode(_scan(ranges)))


def _mutate(msg, **changes) -> bytes:
    body = _body(msg)
    body.update(changes)
    return _wire(msg.SCHEMA, body)


@pytest.mark.parametrize(
    "payload",
    [
        _mutate(_scan(), sensor_pose=[1.0, float("nan"), 0.0]),
        _mutate(_scan(), sensor_pose=[1.0, 2.0]),
        _mutate(_scan(), range_max_m=float("inf")),
        _mutate(_scan(), range_max_m=1e12),
        _mutate(_scan(), angle_increment_rad=0.0),
        _mutate(_scan(), angle_increment_rad=-0.01),
        _mutate(_scan(), range_min_m=9.0),
        _mutate(_scan(), step=-1),
        _mutate(_scan(), step=True),
        _mutate(_scan(), step=1.5),
        _mutate(CmdVelMsg(1, VelocityCommand()), linear_mps=float("inf")),
        _mutate(CmdVelMsg(1, VelocityCommand()), angular_radps="fast"),
        _mutate(OdometryMsg(1, 0.0, Pose2D(0, 0, 0)), pose=[0.0, 0.0, float("nan")]),
        _mutate(GoalMsg(1, True, 1.0, 2.0, 0, 1.0), goal=[1.0, float("nan"), 0, 1.0]),
        _mutate(PlannerFeedbackMsg(1, "following", "map"), status="dancing"),
        _mutate(PlannerFeedbackMsg(1, "following", "command"), path_ahead_xy_m=pack_array(np.array([[0.0, np.inf]]))),
        _mutate(PlannerFeedbackMsg(1, "following", "command"), path_ahead_xy_m=pack_array(np.zeros((2, 3)))),
        _mutate(CmdVelMsg(1, VelocityCommand()), new_goal=1),
        _mutate(EpisodeStatusMsg("exploring", 1), coverage_pct=250.0),
        _mutate(EpisodeStatusMsg("exploring", 1), pose=[1.0, float("nan"), 0.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), pose=[float("inf"), 0.0, 0.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), pose=[1.0, 2.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), pose=[1.0, 2.0, 11.0]),  # a yaw within +-10 rad, as every pose's
        _mutate(EpisodeStatusMsg("exploring", 1), pose=[1.0, True, 0.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), twist=[0.2, float("inf")]),
        _mutate(EpisodeStatusMsg("exploring", 1), twist=[float("nan"), 0.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), twist=[0.2]),
        _mutate(EpisodeStatusMsg("exploring", 1), twist=[250.0, 0.0]),
        _mutate(EpisodeStatusMsg("exploring", 1), twist="fast"),
        _mutate(ClockMsg(1, 0.25), time_s=-1.0),
        _mutate(ServiceStatusMsg("mapper", "r0", "running"), rejected={"scan": -1}),
        _mutate(ServiceStatusMsg("mapper", "r0", "running"), counters={"received:scan": -1}),
        _mutate(ServiceStatusMsg("mapper", "r0", "running"), counters={"received:scan": 1.5}),
        _mutate(ServiceStatusMsg("mapper", "r0", "running"), counters=[1]),
        # What `status --json` writes: bytes used to crash it, NaN to make invalid JSON, a list pass as a count.
        _mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"pid": b"12"}}),
        _mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"restarts": float("nan")}}),
        _mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"hung_kills": [1]}}),
        _mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"gave_up": 1}}),
        _mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"restarts": -1}}),
        _mutate(LauncherStatusMsg("run1", "running"), services={"ros2_bridge": {"robot_stops": -1}}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "exploring", "step": 41, "episode": 7, "age_s": -1.0}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "exploring", "step": 41}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "coverage_pct": -1.0}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "scene": 3}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode=[1]),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "pose": [1.0, 2.0]}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "pose": [1.0, float("nan"), 0.0]}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "twist": [1e9, 0.0]}),
        _mutate(LauncherStatusMsg("run1", "running"), last_episode={"state": "done", "step": 41, "episode": 7, "age_s": 1.0, "map_origin": None}),
        _mutate(LauncherStatusMsg("run1", "running"), real_time_factor=-1.0),
        _mutate(LauncherStatusMsg("run1", "running"), real_time_factor=float("nan")),
        _mutate(LauncherStatusMsg("run1", "running"), real_time_factor=float("inf")),
        _mutate(LauncherStatusMsg("run1", "running"), real_time_factor="2.0x"),
        _mutate(LauncherStatusMsg("run1", "running"), real_time_factor=True),
    ],
)
def test_out_of_range_and_non_finite_fields_are_rejected(payload):
    with pytest.raises(MessageError):
        decode(payload)


def test_a_launcher_status_says_which_kind_of_referee_its_run_has_optionally():
    """``launcher_status.referee`` (``sim``, ``ros2_bridge``, ``own``): sent when known, absent from an older launcher's
    (None: ``status`` words an unmeasured coverage as a real robot's), and a string or nothing."""
    own = LauncherStatusMsg("run1", "running", referee="own")
    assert _body(own)["referee"] == "own" and decode(encode(own)) == own
    older = LauncherStatusMsg("run1", "running")
    assert "referee" not in _body(older) and decode(encode(older)).referee is None
    with pytest.raises(MessageError, match=r"launcher_status\.referee: expected a string"):
        decode(_wire("launcher_status", {**_body(older), "referee": 3}))


def test_a_launcher_status_names_the_episodes_whose_result_a_restart_lost_optionally():
    """``launcher_status.lost_results``: each episode's id, its end's state and step, and the episode the run went on
    with; absent while none (and from an older launcher: none), and checked as ``status --json`` writes it."""
    lost = [{"episode": 2**48 - 1, "state": "done", "step": 31, "running": 8}]
    msg = LauncherStatusMsg("run1", "running", lost_results=lost)
    assert _body(msg)["lost_results"] == lost and decode(encode(msg)) == msg
    older = LauncherStatusMsg("run1", "running")
    assert "lost_results" not in _body(older) and decode(encode(older)).lost_results == []
    assert decode(_wire("launcher_status", {**_body(older), "lost_results": None})).lost_results == []
    for bad in (
        {"episode": 7},
        [{"episode": 7, "state": "done", "step": -1, "running": 8}],
        [{"episode": 7, "state": "done", "step": 3}],
        [{"episode": "7", "state": "done", "step": 3, "running": 8}],
        [{"episode": 7, "state": 1, "step": 3, "running": 8}],
        [7],
        [{"episode": 7, "state": "done", "step": 3, "running": 8}] * (LOST_RESULTS_KEPT + 1),
    ):
        with pytest.raises(MessageError, match=r"launcher_status\.lost_results"):
            decode(_wire("launcher_status", {**_body(older), "lost_results": bad}))


def test_a_launcher_status_field_this_side_does_not_know_is_left_out():
    msg = decode(_mutate(LauncherStatusMsg("run1", "running"), services={"sim": {"pid": 12, "gave_up": False, "newer": b"\x00"}}))
    assert msg.services == {"sim": {"pid": 12, "gave_up": False}}


def test_bad_maps_are_rejected():
    grid = np.zeros(GEOM.shape, np.int8)
    good = _body(MapMsg.from_grid(1, GEOM, grid))
    nothing = np.zeros(GEOM.shape, bool)
    occupied_unexplored = nothing.copy()
    occupied_unexplored[0, 0] = True
    cases = [
        {**good, "explored": pack_array(nothing, compress=True), "occupied": pack_array(occupied_unexplored, compress=True)},
        {**good, "occupied": pack_array(np.zeros((3, 4), bool), compress=True)},
        {**good, "explored": pack_array(np.zeros(GEOM.shape, np.int8), compress=True)},
        {k: v for k, v in good.items() if k != "occupied"},
        {**good, "explored": {**good["explored"], "data": b"\x00\x01"}},
        {**good, "explored": {**good["explored"], "data": zlib.compress(b"\x00" * 7)}},
        {**good, "explored": {**good["explored"], "dtype": "object"}},
        {**good, "geometry": {**good["geometry"], "resolution_m": 0.0}},
        {**good, "geometry": {**good["geometry"], "shape": [0, 4]}},
        {**good, "geometry": {**good["geometry"], "origin": [float("nan"), 0.0]}},
    ]
    decode(_wire("map", good))  # the good body itself passes
    for body in cases:
        with pytest.raises(MessageError):
            decode(_wire("map", body))


def test_frontiers_send_i_as_its_masked_values_and_restore_it_exactly():
    obs = _observation()
    entropy = obs.entropy.copy()
    entropy[:, : entropy.shape[1] // 2] = 0  # far from frontiers, I is 0
    obs = type(obs)(**{**obs.__dict__, "entropy": entropy})
    msg = frontiers_from_observation(3, "no_goal", obs, 1.0)
    back = decode(encode(msg), FrontiersMsg)
    assert isinstance(back, FrontiersMsg)
    np.testing.assert_array_equal(back.arrays["entropy"], obs.entropy)  # 0 away from frontiers
    assert back.arrays["entropy"].dtype == np.int32
    sent = _body(msg)["arrays"]
    assert "distance_m" not in sent  # D stays home (path nodes only)
    assert sent["entropy"]["shape"] == [int(np.count_nonzero(obs.entropy))] == [obs.entropy.size // 2]  # only the non-zero counts
    assert _body(msg)["masks"]["entropy"]["z"] == "bits"
    empty = type(obs)(**{**obs.__dict__, "entropy": np.zeros_like(obs.entropy)})
    back = decode(encode(frontiers_from_observation(4, "no_goal", empty, 1.0)), FrontiersMsg)
    assert not back.arrays["entropy"].any()


def test_distance_map_travels_as_its_finite_values_and_comes_back_exactly():
    obs = _observation()
    assert np.isinf(obs.distance_m).any() and np.isfinite(obs.distance_m).any()
    msg = DistanceMapMsg(3, obs.geometry, obs.pose, obs.distance_m)
    back = decode(encode(msg), DistanceMapMsg)
    assert isinstance(back, DistanceMapMsg) and back.step == 3 and back.geometry == obs.geometry and back.pose == obs.pose
    np.testing.assert_array_equal(back.distance_m, obs.distance_m)  # inf where unreachable
    assert _body(msg)["distance_m"]["shape"] == [int(np.isfinite(obs.distance_m).sum())]
    good = _body(msg)
    d = obs.distance_m.copy()
    d[np.isfinite(d)] *= -1.0
    cases = [
        _body(DistanceMapMsg(3, obs.geometry, obs.pose, np.where(np.isfinite(obs.distance_m), np.nan, np.inf))),
        _body(DistanceMapMsg(3, obs.geometry, obs.pose, d)),  # negative distances
        {**good, "distance_m": pack_array(np.zeros(3))},  # not one value per finite cell
        {**good, "distance_m": pack_array(np.zeros(int(np.isfinite(obs.distance_m).sum()), np.int64))},  # metres are floats
        {**good, "finite": pack_array(np.ones((2, 2), bool), compress=True)},  # not the grid's shape
        {k: v for k, v in good.items() if k != "pose"},
    ]
    for body in cases:
        with pytest.raises(MessageError):
            decode(_wire("distance_map", body))


def test_bad_frontiers_are_rejected():
    obs = _observation()
    good = _body(frontiers_from_observation(3, "no_goal", obs, 1.0))
    bad_cluster = dict(good["clusters"][0], goal_cell=[999, 0])
    cases = [
        {**good, "path_nodes_distance_m": pack_array(np.array([np.nan]))},
        {**good, "path_nodes_distance_m": pack_array(np.array([-1.0]))},
        {**good, "path_nodes_distance_m": pack_array(np.array([0.0, 1.0]))},  # two values for one path node
        {**good, "path_nodes_distance_m": pack_array(np.array([0], dtype=np.int32))},
        {k: v for k, v in good.items() if k != "path_nodes_distance_m"},
        {**good, "clusters": [bad_cluster]},
        {**good, "clusters": [dict(good["clusters"][0], distance_m=float("nan"))]},
        {**good, "arrays": {k: v for k, v in good["arrays"].items() if k != "entropy"}},
        {**good, "masks": {}},  # the entropy mask missing
        {**good, "masks": dict(good["masks"], entropy=pack_array(np.arange(obs.entropy.size).reshape(obs.geometry.shape) % 2 == 0, compress=True))},  # fewer set cells than values
        {**good, "masks": dict(good["masks"], entropy=dict(good["masks"]["entropy"], shape=[obs.geometry.shape[0] - 1, obs.geometry.shape[1]]))},  # not the grid's shape
        {**good, "arrays": dict(good["arrays"], distance_m=good["arrays"]["entropy"])},  # an unknown grid
        {**good, "masks": dict(good["masks"], entropy=good["arrays"]["entropy"])},  # not a boolean mask
        {**good, "arrays": dict(good["arrays"], entropy=pack_array(np.ones(int(np.count_nonzero(obs.entropy)))))},  # floats, not counts
        {**good, "arrays": dict(good["arrays"], entropy=dict(good["arrays"]["entropy"], data=good["arrays"]["entropy"]["data"][:-1], shape=[good["arrays"]["entropy"]["shape"][0] - 1]))},  # a value short
        {**good, "path_nodes_xy_m": _body(PathMsg(0, np.array([[np.inf, 0.0]])))["path_xy_m"]},
    ]
    for body in cases:
        with pytest.raises(MessageError):
            decode(_wire("frontiers", body))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_only_ever_raise_message_error(data):
    try:
        decode(data)
    except MessageError:
        pass


def _every_kind_of_message() -> list[Message]:
    """One valid message of each schema a service decodes, the grids and arrays of a real decision included."""
    obs = _observation()
    m = OccupancyMap(GEOM)
    m.integrate_scan(Pose2D(2.0, 1.5, 0.0), LaserScan(-math.pi, 2 * math.pi / 360, 0.1, 1.2, np.full(360, np.inf, np.float32)))
    d = np.full(GEOM.shape, np.inf)
    d[5:10, 5:12] = 0.5
    return [
        _scan(), MapMsg.of(3, m), frontiers_from_observation(3, "no_goal", obs, 4.5), FrontiersMsg(4, False, "keep"),
        DistanceMapMsg(3, GEOM, Pose2D(2.0, 1.5, 0.0), d), OdometryMsg(3, 0.75, Pose2D(1.0, -2.0, 3.1), VelocityCommand(0.4, -0.2)),
        GoalMsg(5, True, 1.5, 2.5, 2, 3.25, 12.5, "greedy-dist", "reached"), PathMsg(3, np.array([[1.0, -0.5], [2.0, 1.0]])),
        CmdVelMsg(3, VelocityCommand(0.5, 0.1), ""), ClockMsg(2, 0.5, GEOM),
        PlannerFeedbackMsg(3, "following", "command", False, "", np.array([[1.0, 2.0]]), 3),
        PlannerContactsMsg(3, np.array([[1.0, 2.0], [1.05, 2.0]]), 7),
        EpisodeStatusMsg("exploring", 12, "gen_small_0", "greedy-dist", 45.5, 10.0, 3.2, [1.0, 2.0], 4, 11.0),
        ServiceStatusMsg("ros2_bridge", "r0", "running", 12, "", {"scan": 1}, 40, {"received:scan": 41}),
    ]


def test_mutated_messages_of_every_schema_only_ever_raise_message_error():
    """Every schema's decoder, fed valid bodies with fields deleted, replaced by values of any type (NaN, huge
    integers, bytes, nested lists) or mutated inside their arrays (dtype, shape, a flipped bit, cut data): a
    message or a MessageError, never another exception (a service counts a MessageError; anything else would
    kill its handler). Seeded, so every run tries the same 3000 mutants."""
    import random

    rng = random.Random(60)
    weird = [None, True, -1, 0, 2**63, -(2**63), 1e308, math.nan, math.inf, -0.0, "", "xyz", b"", b"\x00\x01", [], [1, 2], {}, {"a": 1}, [[1.0, 2.0]]]

    def mutate(value):
        if isinstance(value, dict):
            value = dict(value)
            if value and rng.random() < 0.8:
                key = rng.choice(list(value))
                roll = rng.random()
                if roll < 0.2:
                    del value[key]
                else:
                    value[key] = rng.choice(weird) if roll < 0.55 else mutate(value[key])
            else:
                value[rng.choice(["dtype", "shape", "data", "z", "step"])] = rng.choice(weird)
            return value
        if isinstance(value, list):
            value = list(value)
            if value and rng.random() < 0.6:
                i = rng.randrange(len(value))
                value[i] = mutate(value[i]) if rng.random() < 0.5 else rng.choice(weird)
            elif value and rng.random() < 0.5:
                value.pop()
            else:
                value.append(rng.choice(weird))
            return value
        if isinstance(value, bytes) and value:
            cut = bytearray(value)
            if rng.random() < 0.5:
                cut[rng.randrange(len(cut))] ^= 1 << rng.randrange(8)
                return bytes(cut)
            return bytes(cut[: rng.randrange(len(cut))])
        return rng.choice(weird)

    bodies = [(msg.SCHEMA, _body(msg)) for msg in _every_kind_of_message()]
    decoded = 0
    for _ in range(3000):
        schema, body = rng.choice(bodies)
        for _ in range(rng.randint(1, 3)):
            body = mutate(body)
        payload = _wire(schema, body)
        for expected in (None, PlannerFrontiersMsg) if schema == "frontiers" else (None,):
            try:
                decode(payload, expected)
                decoded += 1
            except MessageError:
                pass
    assert 100 < decoded < 3000  # both ways out were taken: harmless changes decode, the rest are refused


VALID_ODOMETRY_BODY = {"step": 3, "stamp_s": 0.75, "pose": [1.0, 2.0, 0.5], "twist": [0.0, 0.0], "episode": 0}


@settings(max_examples=150, deadline=None)
@given(st.dictionaries(
    st.sampled_from([*VALID_ODOMETRY_BODY, "x"]),
    st.one_of(st.none(), st.integers(-(2**63), 2**64 - 1), st.floats(), st.text(max_size=3), st.lists(st.floats(), min_size=2, max_size=4)),
    max_size=2,
))
def test_random_odometry_bodies_decode_or_raise_message_error(changes):
    """A valid body with up to two fields replaced (or one added): either a message whose every value is a usable
    one, or a MessageError, never another exception. The empty change (and lists of the right length of finite
    floats) decode, so the first branch runs too."""
    try:
        msg = decode(_wire("odom", {**VALID_ODOMETRY_BODY, **changes}), OdometryMsg)
    except MessageError:
        return
    assert isinstance(msg, OdometryMsg) and msg.step >= 0 and math.isfinite(msg.stamp_s)
    assert all(math.isfinite(v) for v in (msg.pose.x_m, msg.pose.y_m, msg.pose.yaw_rad, msg.twist.linear_mps, msg.twist.angular_radps))


def test_the_valid_odometry_body_of_the_property_test_decodes():
    assert _body(OdometryMsg(3, 0.75, Pose2D(1.0, 2.0, 0.5))) == VALID_ODOMETRY_BODY
    assert decode(_wire("odom", VALID_ODOMETRY_BODY), OdometryMsg).pose == Pose2D(1.0, 2.0, 0.5)


# --- keys ---------------------------------------------------------------------------------------


def test_keys_are_namespaced_by_robot():
    k = RobotKeys("robot_2")
    assert k.scan == "cso/robot_2/scan"
    assert k.planner_feedback == "cso/robot_2/planner/feedback"
    assert k.topic("planner_contacts") == "cso/robot_2/planner/contacts" and k.cache("planner_contacts") == "cso/robot_2/cache/planner/contacts"
    assert k.alive("mapper") == "cso/robot_2/alive/mapper"
    assert RobotKeys("*").frontiers == "cso/*/frontiers"
    assert robot_of("cso/robot_2/episode/status") == "robot_2"
    assert topic_of("cso/robot_2/episode/status") == "episode_status"


@pytest.mark.parametrize("bad", ["", "a/b", "r 1", "*", "x" * 65, "r?"])
def test_bad_robot_ids_are_rejected(bad):
    with pytest.raises(KeyExprError):
        check_robot_id(bad)


def test_a_pause_is_kept_timed_and_said_and_the_launchers_status_carries_it():
    """``PauseClock``: a second pause is no new one, the seconds paused add up over pauses; ``launcher_status``'s
    ``pause`` round-trips (and is optional: an older launcher's status has none); ``pause_note`` is what ``status`` adds."""
    from cso_runtime.messages import ExploreResumeMsg, LauncherStatusMsg
    from cso_runtime.pause import LOCKSTEP_REFUSAL, PauseClock, pause_note

    clock = PauseClock()
    assert clock.heard(ExploreResumeMsg(False, "ann@lab", "look"), 10.0) and not clock.heard(ExploreResumeMsg(False, "bob"), 12.0)
    assert clock.paused and clock.paused_for_s(14.0) == 4.0
    assert clock.heard(ExploreResumeMsg(True, "ann@lab"), 15.0) and not clock.heard(ExploreResumeMsg(True), 16.0)
    clock.heard(ExploreResumeMsg(False, "ann@lab"), 20.0)
    pause = clock.status(22.5)
    assert pause == {"paused": True, "by": "ann@lab", "reason": "", "for_s": 2.5, "total_s": 7.5, "refused": ""}
    assert pause_note(pause) == "; paused (by ann@lab, for 2 s)" and pause_note(None) == "" and pause_note({**pause, "paused": False}) == ""
    msg = LauncherStatusMsg("run", "running", pause=PauseClock().status(0.0, LOCKSTEP_REFUSAL))
    back = decode(encode(msg), LauncherStatusMsg)
    assert back.pause == {"paused": False, "by": "", "reason": "", "for_s": 0.0, "total_s": 0.0, "refused": LOCKSTEP_REFUSAL}
    assert decode(encode(LauncherStatusMsg("run", "running")), LauncherStatusMsg).pause is None
    assert decode(encode(ExploreResumeMsg(False, "ros2 explore/resume", "why", 1.7e9)), ExploreResumeMsg) == ExploreResumeMsg(False, "ros2 explore/resume", "why", 1.7e9)


def test_pause_refuses_a_lockstep_run_and_says_why(monkeypatch, capsys, tmp_path):
    """``cso-runtime pause`` on a lockstep run: exit 2 with the reason, nothing sent."""
    import contextlib

    from cso_runtime import status as status_module
    from cso_runtime.messages import LauncherStatusMsg
    from cso_runtime.pause import LOCKSTEP_REFUSAL, PauseClock

    sent: list = []
    session = type("S", (contextlib.nullcontext,), {"put": lambda self, *a: sent.append(a)})()
    monkeypatch.setattr(status_module, "reachable_target", lambda *a: status_module.RunTarget(["tcp/127.0.0.1:1"], "r0", None))
    monkeypatch.setattr(status_module, "_client_session", lambda *a: session)
    monkeypatch.setattr(status_module, "launcher_pause", lambda *a, **k: LauncherStatusMsg("run-1", "running", pause=PauseClock().status(0.0, LOCKSTEP_REFUSAL)))
    assert status_module.explore_resume_main([], None, tmp_path, resume=False) == 2
    assert f"cannot pause robot r0 (run run-1): {LOCKSTEP_REFUSAL}" in capsys.readouterr().err and sent == []


@pytest.mark.parametrize("state", ["exploring", "done"])
def test_pause_of_an_ended_episode_says_the_robot_stands_already(monkeypatch, capsys, tmp_path, state):
    """``cso-runtime pause`` after a LIMO's episode ended (the run stays up, detached) said "it holds still until
    `cso-runtime resume`", as if it had stopped a robot that was driving: it says the episode has ended and what
    the pause is for then (a new episode starts paused)."""
    import contextlib

    from cso_runtime import status as status_module
    from cso_runtime.messages import ExploreResumeMsg, LauncherStatusMsg
    from cso_runtime.pause import PauseClock

    clock = PauseClock()
    answers = iter([clock.status(0.0), (clock.heard(ExploreResumeMsg(False, "me@laptop"), 1.0), clock.status(1.0))[1]])
    session = type("S", (contextlib.nullcontext,), {"put": lambda self, *a: None})()
    monkeypatch.setattr(status_module, "reachable_target", lambda *a: status_module.RunTarget(["tcp/127.0.0.1:1"], "r0", None))
    monkeypatch.setattr(status_module, "_client_session", lambda *a: session)
    last = {"state": state, "step": 188, "episode": 7, "age_s": 0.1}
    monkeypatch.setattr(status_module, "launcher_pause", lambda *a, **k: LauncherStatusMsg("run-1", "running", last_episode=last, pause=next(answers)))
    assert status_module.explore_resume_main([], None, tmp_path, resume=False) == 0
    said = capsys.readouterr().out
    if state == "done":
        assert said.startswith("paused robot r0 (run run-1) at step 188: its episode has ended (done), so it stands already; a new episode"), said
    else:
        # the resume of this run's runs folder: a plain `cso-runtime resume` asks the run of ./runs
        assert said == f"paused robot r0 (run run-1) at step 188: it holds still until `cso-runtime resume --runs-dir {tmp_path}`\n", said
        clock = PauseClock()
        answers = iter([clock.status(0.0), (clock.heard(ExploreResumeMsg(False, "me@laptop"), 1.0), clock.status(1.0))[1]])
        assert status_module.explore_resume_main(["tcp/127.0.0.1:1"], None, tmp_path / "runs", resume=False) == 0  # asked at an endpoint
        said = capsys.readouterr().out
        assert said.endswith("until `cso-runtime resume --connect tcp/127.0.0.1:1 --robot r0`\n"), said
    # a launcher that does not confirm: the status to look at is this run's too
    monkeypatch.setattr(status_module, "PAUSE_CONFIRM_S", 0.05)
    monkeypatch.setattr(status_module, "launcher_pause", lambda *a, **k: LauncherStatusMsg("run-1", "running", last_episode=last, pause=PauseClock().status(0.0)))
    assert status_module.explore_resume_main([], None, tmp_path, resume=False) == 1
    assert capsys.readouterr().err.endswith(f"has not said so within 0.05 s; see `cso-runtime status --runs-dir {tmp_path}`\n")


@pytest.fixture
def grid_bound():
    """Restores the process's ``max_grid_cells`` after a test that sets it."""
    yield
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)


def _forged_bits(n_cells: int, last: int = 0) -> bytes:
    """A valid zlib stream of ``n_cells`` bit-packed cells, all clear but the last byte's ``last`` bits: a few kB for
    49 million cells (zlib's ratio on zeros is about 1000:1)."""
    z = zlib.compressobj(9)
    return z.compress(bytes((n_cells + 7) // 8 - 1)) + z.compress(bytes([last])) + z.flush()


def test_a_forged_grid_larger_than_the_runs_bound_is_refused_before_any_of_it_is_inflated():
    """A 12 kB map declaring a 7000 x 7000 grid (49 million cells: under MAX_GRID_CELLS, the only bound before) whose two
    channels are valid streams, refused only because an occupied cell is not explored: the receiver inflated and
    unpacked both (141 MB of peak RSS, measured in docs/messages.md) before refusing it. Every grid, and the arrays that
    stand alone in their message (a path, the path ahead, the contacts; a result's grids), is now bound by the run's
    ``max_grid_cells`` and refused on its declared size."""
    ny = nx = 7000
    n = ny * nx
    assert n <= 50_000_000 and n > max_grid_cells()
    good_map = _body(MapMsg(1, GEOM, np.ones(GEOM.shape, bool), np.zeros(GEOM.shape, bool)))
    geometry = {"resolution_m": 0.05, "shape": [ny, nx], "origin": [0.0, 0.0]}
    explored = {"dtype": "bool", "shape": [ny, nx], "z": "bits", "data": _forged_bits(n)}
    occupied = {"dtype": "bool", "shape": [ny, nx], "z": "bits", "data": _forged_bits(n, 0x80)}
    payload = _wire("map", {**good_map, "geometry": geometry, "explored": explored, "occupied": occupied})
    assert len(payload) < 16_000
    assert _peak_bytes(lambda: decode(payload)) < 1 << 20
    with pytest.raises(MessageError, match=r"map.geometry.shape: a 7000 x 7000 grid has 49_000_000 cells, more than this run's max_grid_cells \(4_000_000"):
        decode(payload)
    bomb = _zlib_bomb(8)  # 8 kB, 8 MiB of zeros
    points = {"dtype": "float64", "shape": [5_000_000, 2], "z": True, "data": bomb}  # 10 million elements: 2.5 times the bound
    result = _body(_episode_result(3))
    for schema, body in [
        ("path", {"step": 1, "path_xy_m": points}),
        ("planner_feedback", {**_body(PlannerFeedbackMsg(1, "following", "command")), "path_ahead_xy_m": points}),
        ("planner_contacts", {"step": 1, "episode": 0, "contacts_xy_m": points}),
        ("episode_result", {**result, "explored_free": explored, "plan_free": explored}),
    ]:
        payload = _wire(schema, body)
        assert _peak_bytes(lambda payload=payload: decode(payload)) < 1 << 20, schema
        with pytest.raises(MessageError, match=r"too large \((10000000|49000000) elements, at most (8000000|4000000)\)"):
            decode(payload)


def test_real_large_maps_decode_and_the_runs_grid_bound_is_what_it_says(grid_bound):
    """A map of exactly ``max_grid_cells`` (2000 x 2000, a 100 m square at 0.05 m) round-trips, with its decision and
    distance map; one more row is refused by its receiver and by its sender (which says how to raise the bound); a run
    whose profile raises the bound (``set_max_grid_cells``, as each service does) reads it."""
    geometry = GridGeometry(0.05, (2000, 2000), -50.0, -50.0)
    m = OccupancyMap(geometry)
    m.explored[:1000] = True
    m.occupied[:10] = True
    back = decode(encode(MapMsg.of(5, m)), MapMsg)
    assert back.geometry == geometry and (back.explored == m.explored).all() and (back.occupied == (m.occupied & m.explored)).all()
    d = np.where(m.explored, 1.0, np.inf)
    assert (decode(encode(DistanceMapMsg(5, geometry, Pose2D(0.0, 0.0, 0.0), d)), DistanceMapMsg).distance_m == d).all()
    taller = GridGeometry(0.05, (2001, 2000), -50.0, -50.0)
    bigger = OccupancyMap(taller)
    with pytest.raises(MessageError, match=r"geometry: a 2001 x 2000 grid has 4_002_000 cells, more than this run's max_grid_cells \(4_000_000; a profile's max_grid_cells raises it\)"):
        encode(MapMsg.of(5, bigger))
    set_max_grid_cells(2001 * 2000)
    payload = encode(MapMsg.of(5, bigger))
    assert decode(payload, MapMsg).geometry == taller
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)
    with pytest.raises(MessageError, match="map.geometry.shape: a 2001 x 2000 grid has 4_002_000 cells"):
        decode(payload)
    for bad in (0, 50_000_001, 1.5, True):
        with pytest.raises(ValueError, match="max_grid_cells must be an integer"):
            set_max_grid_cells(bad)  # type: ignore[arg-type]
    assert max_grid_cells() == DEFAULT_MAX_GRID_CELLS


def test_a_decisions_path_nodes_are_bound_by_the_episodes_steps_not_by_the_runs_grid(grid_bound):
    """The distances at a decision's path nodes are one per node (at most ``MAX_STEP_POINTS``, as the nodes), not a grid:
    a run whose ``max_grid_cells`` is just its small scene's grid still reads a decision of an episode with more
    decisions than that grid has cells."""
    obs = _observation()
    set_max_grid_cells(GEOM.shape[0] * GEOM.shape[1])  # 1200 cells: the bound tight on the run's own grid
    nodes = 3 * GEOM.shape[0] * GEOM.shape[1]
    body = _body(frontiers_from_observation(3, "timeout", obs, 12.0))
    body["path_nodes_xy_m"] = pack_array(np.tile([[1.0, 1.0]], (nodes, 1)))
    body["path_nodes_distance_m"] = pack_array(np.zeros(nodes))
    back = decode(_wire("frontiers", body), FrontiersMsg)
    assert back.path_nodes_xy_m.shape == (nodes, 2) and back.path_nodes_distance_m.shape == (nodes,)


def test_a_plans_path_is_bound_as_the_path_it_is_published_as(grid_bound):
    """``planner_plan.path_xy_m`` is the very path ``path`` publishes (a point per cell of the run's grid at most): one
    that ``path`` carries, the plan carries too, where it was bound by half as many points and a restarted planner found
    no plan to resume."""
    set_max_grid_cells(GEOM.shape[0] * GEOM.shape[1])
    points = np.tile([[1.0, 2.0]], (GEOM.shape[0] * GEOM.shape[1], 1))  # a point per cell: twice the bound's elements
    assert decode(encode(PathMsg(3, points)), PathMsg).path_xy_m.shape == points.shape
    assert decode(encode(PlannerPlanMsg(3, points, None, 7)), PlannerPlanMsg).path_xy_m.shape == points.shape
    with pytest.raises(MessageError, match="planner_plan.path_xy_m: too large"):
        decode(encode(PlannerPlanMsg(3, np.vstack([points, points[:1]]), None, 7)), PlannerPlanMsg)


def test_a_results_grids_are_refused_by_their_sender_beyond_the_runs_bound(grid_bound):
    """docs/messages.md: a grid of more cells than ``max_grid_cells`` is refused by its receiver and by its sender, which
    says how to raise the bound: a result's ``explored_free`` and ``plan_free`` (grids without a ``geometry``) too, where
    the sender sent them and only the launcher refused them, losing the episode's result."""
    set_max_grid_cells(GEOM.shape[0] * GEOM.shape[1] - 1)
    with pytest.raises(MessageError, match=r"episode_result.explored_free: a 30 x 40 grid has 1_200 cells, more than this run's max_grid_cells \(1_199"):
        encode(_episode_result(3))
    set_max_grid_cells(GEOM.shape[0] * GEOM.shape[1])
    assert decode(encode(_episode_result(3)), EpisodeResultMsg).explored_free.shape == GEOM.shape


def test_an_episode_id_is_never_0_which_messages_read_as_no_id(monkeypatch):
    """0 is "no id" where an episode id is optional (``episode_result``'s ``episode``, ``cmd_vel``'s): a sim or ROS 2
    bridge that drew 0 (48 random bits) sent its result with no id, taken for whichever end a launcher judges, and its
    planner's commands as of no episode. A draw of 0 is drawn again."""
    import secrets

    from cso_runtime.messages import new_episode_id

    draws = iter([0, 0, 12345])
    monkeypatch.setattr(secrets, "randbits", lambda k: next(draws))
    assert new_episode_id() == 12345
