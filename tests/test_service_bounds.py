"""What a running service keeps while one of its inputs is silent or comes faster than it handles them: bounded,
and what it has to let go of is counted where ``status`` shows it."""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from cso_runtime.config import ExplorationConfig
from cso_runtime.geometry import GridGeometry, LaserScan, Pose2D
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import (
    DEFAULT_MAX_GRID_CELLS,
    ClockMsg,
    DistanceMapMsg,
    FrontiersMsg,
    GoalMsg,
    MapMsg,
    OdometryMsg,
    PlannerFeedbackMsg,
    PlannerFrontiersMsg,
    ScanMsg,
    ServiceStatusMsg,
    decode,
    encode,
)
from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session
from services.common import PENDING_MAX_BYTES, PENDING_STEPS_KEPT, steps_kept, topic_name
from services.frontier import FrontierService
from services.planner import PlannerService
from tests.conftest import HANG_DEADLINE_S, wait_for
from tests.test_service_logic import _explorer_at, _feed, _inputs, _service


def _small_bound(monkeypatch: pytest.MonkeyPatch, n: int = 64) -> int:
    """``PENDING_SMALL_STEPS_KEPT`` lowered to ``n`` in the frontier service and the planner (the real one, 100,000, is
    too many steps to feed a test); the highest number of steps ``keep_newest`` then keeps."""
    from services import frontier, planner

    for module in (frontier, planner):
        monkeypatch.setattr(module, "PENDING_SMALL_STEPS_KEPT", n)
    return n + n // 8


def test_keep_newest_keeps_the_n_newest_steps_and_trims_once_an_eighth_more_wait():
    """The n newest always stay (a partner lagging fewer steps loses nothing); at most n + n // 8 are kept, and the
    sort is paid once per n // 8 steps, not on every step past n."""
    from services.common import keep_newest

    pending: dict[int, None] = {}
    sizes = []
    for step in range(1, 200):
        pending[step] = None
        keep_newest(pending, 64)
        assert set(range(max(1, step - 63), step + 1)) <= set(pending)
        sizes.append(len(pending))
    trims = [step for step, (a, b) in enumerate(itertools.pairwise(sizes), start=2) if b < a]
    assert max(sizes) == 64 + 8 and trims == list(range(73, 200, 9))  # back to 64 once past 72: every 9th step
    late = {5: "a", 1: "b", 9: "c", 3: "d"}  # out of order: the newest steps stay, whatever order they came in
    keep_newest(late, 2)
    assert late == {5: "a", 9: "c"}


def test_a_real_time_frontier_service_whose_maps_stopped_keeps_a_bounded_number_of_steps_and_decides_on_the_next_map(monkeypatch):
    """The mapper gone (died, given up on): odometry and the planner's reports go on at the control rate, and the
    frontier service kept every one of them, waiting for its map, for as long as the episode ran. Each one it lets go
    of is counted as a rejection of its topic, for its robot (they were dropped with nothing in its status)."""
    most = _small_bound(monkeypatch)
    frontier, out = _service(FrontierService, lockstep=False)
    ex = _explorer_at(0)
    _, odom0, _ = _inputs(ex, 0)
    last = 3 * most
    for step in range(1, last + 1):
        _feed(frontier, OdometryMsg(step, 0.1 * step, odom0.pose))
        _feed(frontier, PlannerFeedbackMsg(step, "idle", "command"))
        assert len(frontier.odoms) <= most and len(frontier.feedback) <= most
    assert set(range(last - 63, last + 1)) <= set(frontier.odoms) and set(range(last - 63, last + 1)) <= set(frontier.feedback)
    dropped = {"odom": last - len(frontier.odoms), "planner_feedback": last - len(frontier.feedback)}
    assert frontier.rejected == frontier.rejected_by_robot["r0"] == dropped and min(dropped.values()) > 0
    _feed(frontier, MapMsg.of(last, ex.map))  # the mapper back: the newest step is decided at once
    assert [(t, m.step, m.decide) for t, m in out if t == "frontiers"] == [("frontiers", last, True)]
    assert not frontier.odoms and not frontier.maps
    assert frontier.rejected == dropped  # what a decision lets go of (the steps before it) is no drop


def test_a_real_time_frontier_service_whose_maps_lag_far_behind_its_odometry_decides_on_each_map_as_it_comes():
    """``replay run.mcap --topics clock,odom,scan --speed max`` into a fresh pipeline (docs/hardware.md): the odometry and
    the planner's reports come thousands of steps ahead of a mapper that recomputes the maps. Each map needs the
    odometry of its own step: with 256 steps of odometry kept, every map found its odometry trimmed, and the frontier
    service decided nothing until the maps were within 256 steps of it. The odometry waits for its map now."""
    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    ex = _explorer_at(0)
    _, odom0, _ = _inputs(ex, 0)
    ahead = 2000
    for step in range(ahead + 1):
        _feed(frontier, OdometryMsg(step, odom0.stamp_s + 0.25 * step, odom0.pose))
        _feed(frontier, PlannerFeedbackMsg(step, "idle", "command"))
    maps = 30
    for step in range(maps):
        _feed(frontier, MapMsg.of(step, ex.map))
        assert [m.step for t, m in out if t == "frontiers"][-1:] == [step], f"map {step} was not decided on"
    decided = [(m.step, m.decide) for t, m in out if t == "frontiers"]
    assert decided == [(0, True)] + [(step, False) for step in range(1, maps)]  # each after the first waits for its goal
    assert min(frontier.odoms) == maps and len(frontier.odoms) == ahead + 1 - maps  # the decided steps' are let go


def test_a_real_time_frontier_service_whose_odometry_stopped_keeps_a_bounded_number_of_maps():
    frontier, out = _service(FrontierService, lockstep=False)
    ex = _explorer_at(0)
    for step in range(1, 2 * PENDING_STEPS_KEPT + 1):
        _feed(frontier, MapMsg.of(step, ex.map))
        assert len(frontier.maps) <= PENDING_STEPS_KEPT + PENDING_STEPS_KEPT // 8
    assert set(range(PENDING_STEPS_KEPT + 1, 2 * PENDING_STEPS_KEPT + 1)) <= set(frontier.maps) and out == []
    assert frontier.rejected["map"] == 2 * PENDING_STEPS_KEPT - len(frontier.maps)  # each map dropped unused, counted


def test_steps_kept_is_the_most_steps_keep_newest_may_keep_within_the_bytes_and_never_none():
    for budget in range(200):
        kept = steps_kept(1, n=10**6, max_bytes=budget)
        assert kept == max([k for k in range(1, budget + 1) if k + k // 8 <= budget], default=1)
    assert steps_kept(1) == PENDING_STEPS_KEPT and steps_kept(PENDING_MAX_BYTES + 1) == 1  # the newest step stays


def _largest_default_grid_map() -> tuple[tuple[GridGeometry, np.ndarray, np.ndarray], OdometryMsg]:
    """The map of step 0 in the corner of the largest grid the default ``max_grid_cells`` allows (2000 x 2000: 8 MB
    decoded, explored and occupied), and the odometry of its step."""
    m, odom, _ = _inputs(_explorer_at(0), 0)
    side = math.isqrt(DEFAULT_MAX_GRID_CELLS)
    g = m.geometry
    grid = GridGeometry(g.resolution_m, (side, side), g.origin_x_m, g.origin_y_m)
    explored, occupied = np.zeros(grid.shape, dtype=bool), np.zeros(grid.shape, dtype=bool)
    explored[: g.shape[0], : g.shape[1]], occupied[: g.shape[0], : g.shape[1]] = m.explored, m.occupied
    return (grid, explored, occupied), odom


def test_a_real_time_frontier_service_whose_odometry_stopped_keeps_at_most_pending_max_bytes_of_maps_of_the_largest_grid():
    """Odometry silent (a sim stalled, a bridge reading the wrong odometry topic) while the mapper goes on, on the
    largest grid the default ``max_grid_cells`` allows (2000 x 2000: 8 MB a map decoded): the frontier service kept
    256 maps, 288 before a trim (2.3 GB; 28.8 GB at ``MAX_GRID_CELLS``). Now at most ``PENDING_MAX_BYTES`` of them,
    the newest kept, each dropped counted; and the odometry of the newest step, when it comes, is decided on with it."""
    frontier, out = _service(FrontierService, lockstep=False)
    (grid, explored, occupied), odom = _largest_default_grid_map()
    map_bytes = explored.nbytes + occupied.nbytes
    last, most_held = 2 * PENDING_STEPS_KEPT, 0
    for step in range(1, last + 1):
        # As decoded from the wire, less the codec (512 decodes of 8 MB): every message holds grids of its own there,
        # and is counted so here.
        frontier.on_message("r0", "map", MapMsg(step, grid, explored, occupied), time.monotonic())
        most_held = max(most_held, len(frontier.maps) * map_bytes)
        assert step in frontier.maps  # the newest is always kept
    assert most_held <= PENDING_MAX_BYTES, f"{most_held / 2**20:.0f} MiB of maps held waiting for their odometry"
    kept = steps_kept(map_bytes)
    assert set(range(last - kept + 1, last + 1)) <= set(frontier.maps) and out == []
    assert frontier.rejected["map"] == frontier.rejected_by_robot["r0"]["map"] == last - len(frontier.maps)
    _feed(frontier, OdometryMsg(last, odom.stamp_s, odom.pose))  # the odometry back: the newest map is decided on
    assert [(t, msg.step) for t, msg in out] == [("frontiers", last), ("distance_map", last)] and out[0][1].decide
    assert out[1][1].geometry == grid and not frontier.maps


def test_a_real_time_planner_whose_policy_is_down_keeps_at_most_pending_max_bytes_of_decisions_of_the_largest_grid():
    """A policy that is down: the frontier service asks again every ``goal_wait_s``, and the planner kept 16 decisions
    (18 before a trim) waiting for their goal, each its frontiers' three grids and its D (11 bytes a cell decoded): on
    the largest grid the default ``max_grid_cells`` allows, 792 MB (9.9 GB at ``MAX_GRID_CELLS``). Now at most
    ``PENDING_MAX_BYTES`` of each, the newest kept, each dropped counted; the goal of the newest decision is planned."""
    from services.planner import PENDING_DECISIONS_KEPT

    frontier, decided = _service(FrontierService, lockstep=False)
    (grid, explored, occupied), odom = _largest_default_grid_map()
    _feed(frontier, MapMsg(0, grid, explored, occupied))
    _feed(frontier, odom)
    (_, f), (_, d) = decided
    assert isinstance(f, FrontiersMsg) and f.decide and isinstance(d, DistanceMapMsg) and d.geometry == grid
    f = decode(encode(f), PlannerFrontiersMsg)  # the grids the planner decodes: traversable, occupied, explored
    f_bytes, d_bytes = sum(a.nbytes for a in f.arrays.values()), d.distance_m.nbytes
    planner, out = _service(PlannerService, lockstep=False)
    last, most_held = 3 * PENDING_DECISIONS_KEPT, {"frontiers": 0, "distance_map": 0}
    for step in range(1, last + 1):
        # As decoded from the wire, less the codec: every message holds grids of its own there, and is counted so here.
        planner.on_message("r0", "frontiers", dataclasses.replace(f, step=step), time.monotonic())
        planner.on_message("r0", "distance_map", dataclasses.replace(d, step=step), time.monotonic())
        most_held["frontiers"] = max(most_held["frontiers"], len(planner.frontiers) * f_bytes)
        most_held["distance_map"] = max(most_held["distance_map"], len(planner.distance_maps) * d_bytes)
        assert step in planner.frontiers and step in planner.distance_maps  # the newest are always kept
    assert max(most_held.values()) <= PENDING_MAX_BYTES, f"MiB of decisions held waiting for their goal: { {k: v >> 20 for k, v in most_held.items()} }"
    assert set(range(last - steps_kept(d_bytes, PENDING_DECISIONS_KEPT) + 1, last + 1)) <= set(planner.distance_maps)
    assert set(range(last - PENDING_DECISIONS_KEPT + 1, last + 1)) <= set(planner.frontiers)  # 12 MB each: all 16 fit
    dropped = {"frontiers": last - len(planner.frontiers), "distance_map": last - len(planner.distance_maps)}
    assert planner.rejected == planner.rejected_by_robot["r0"] == dropped and out == []
    far = max((c for c in decode(encode(decided[0][1]), FrontiersMsg).clusters if np.isfinite(c["distance_m"])), key=lambda c: c["distance_m"])
    _feed(planner, GoalMsg(last, True, *far["goal_xy_m"], 0, far["distance_m"]))  # the policy back: the newest is planned
    assert planner.planner.status.value == "following" and planner.goal_step == last


def test_a_real_time_planner_whose_lidar_stopped_keeps_a_bounded_number_of_odometry_steps_and_commands_the_next_scan(monkeypatch):
    """A LiDAR driver that stopped: the planner said it was stale (no scan), and kept every odometry message (50 Hz
    on a robot) waiting for its scan, for as long as the run went on. Each one it lets go of is counted as a rejected
    ``odom`` of its robot, and the other way round each scan as a rejected ``scan``."""
    most = _small_bound(monkeypatch)
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    _, odom, scan = _inputs(ex, 0)
    last = 3 * most
    for step in range(1, last + 1):
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.1 * step, odom.pose))
        assert len(planner.odoms) <= most
    dropped = {"odom": last - len(planner.odoms)}
    assert planner.rejected == planner.rejected_by_robot["r0"] == dropped and dropped["odom"] > 0
    _feed(planner, ScanMsg(last, scan.scan, scan.sensor_pose))
    assert [m.step for t, m in out if t == "cmd_vel"] == [last]
    assert planner.rejected == dropped  # what a command lets go of (the steps before it) is no drop
    scans = 2 * PENDING_STEPS_KEPT
    for step in range(last + 1, last + 1 + scans):  # and the other way round
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose))
        assert len(planner.scans) <= PENDING_STEPS_KEPT + PENDING_STEPS_KEPT // 8
    dropped["scan"] = scans - len(planner.scans)
    assert planner.rejected == planner.rejected_by_robot["r0"] == dropped and dropped["scan"] > 0


def test_a_real_time_planner_whose_goals_find_no_decision_keeps_a_bounded_number_and_counts_each_dropped():
    """Goals whose decision (frontiers) never came (lost to a full inbox, a frontier service restarted): the planner
    keeps ``PENDING_DECISIONS_KEPT`` of them, and dropped the older ones with nothing in its status. Each one dropped
    is counted as a rejected ``goal`` of its robot."""
    from services.planner import PENDING_DECISIONS_KEPT

    planner, out = _service(PlannerService, lockstep=False)
    last = 3 * PENDING_DECISIONS_KEPT
    for step in range(1, last + 1):
        _feed(planner, GoalMsg(step, True, 1.0, 1.0, 0, 1.0))
        assert step in planner.goals and len(planner.goals) <= PENDING_DECISIONS_KEPT + PENDING_DECISIONS_KEPT // 8
    dropped = {"goal": last - len(planner.goals)}
    assert planner.rejected == planner.rejected_by_robot["r0"] == dropped and dropped["goal"] > 0 and out == []


def test_the_steps_one_trim_drops_are_counted_whole_and_logged_in_one_line_at_most(caplog):
    """A trim of small inputs drops an eighth of 100,000 steps at once (``PENDING_SMALL_STEPS_KEPT``): counted one by
    one, that was 125 log lines in a burst. All are counted, in one line; inputs rejected one at a time are logged as
    before, the first five and every hundredth."""
    from services.common import Service, ServiceContext

    svc = Service(ServiceContext("probe", "t1", {}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {}))
    pending: dict[int, None] = dict.fromkeys(range(1000))
    with caplog.at_level("WARNING", logger="cso.service"):
        svc.keep_newest_within("odom", pending, 800, 1, "the map of its step", "t1")
        assert sorted(pending) == list(range(200, 1000))
        assert svc.rejected == svc.rejected_by_robot["t1"] == {"odom": 200}
        why = "odom of 200 steps (0 to 199) dropped unused: the map of its step did not come while 800 newer ones waited"
        assert [r.getMessage() for r in caplog.records] == [
            f"{svc.name}: rejected payload on odom (200 so far): {why} (at most 800, and 256 MiB: 0.0 MiB each)"
        ]
        caplog.clear()
        svc.keep_newest_within("odom", pending, 800, None, "the map of its step", "t1")  # within the bound: nothing
        pending.update(dict.fromkeys(range(1000, 1101)))
        svc.keep_newest_within("odom", pending, 800, None, "the map of its step")  # 101 more: past 300, logged again
        assert svc.rejected == {"odom": 301} and svc.rejected_by_robot == {"t1": {"odom": 200}} and len(pending) == 800
        why = "odom of 101 steps (200 to 300) dropped unused: the map of its step did not come while 800 newer ones waited"
        assert [r.getMessage() for r in caplog.records] == [f"{svc.name}: rejected payload on odom (301 so far): {why} (at most 800)"]
        caplog.clear()
        for _ in range(250):
            svc.reject("scan", "a bad one", "t1")
        assert [r.getMessage() for r in caplog.records] == [f"{svc.name}: rejected payload on scan ({n} so far): a bad one" for n in (1, 2, 3, 4, 5, 100, 200)]


def test_a_real_time_planner_whose_scans_lag_far_behind_its_odometry_commands_each_scan_as_it_comes():
    """Scans far behind the odometry (a LiDAR driver that stalled, then caught up): the odometry of their steps waits
    for them, as the frontier service's waits for its maps."""
    planner, out = _service(PlannerService, lockstep=False)
    ex = _explorer_at(0)
    _, odom, scan = _inputs(ex, 0)
    for step in range(1, 1001):
        _feed(planner, OdometryMsg(step, odom.stamp_s + 0.1 * step, odom.pose))
    for step in range(1, 11):
        _feed(planner, ScanMsg(step, scan.scan, scan.sensor_pose))
    assert [m.step for t, m in out if t == "cmd_vel"] == list(range(1, 11))


@pytest.mark.parametrize("bound", ["INBOX_LIMIT", "INBOX_MAX_BYTES"])
def test_a_real_time_service_behind_its_inputs_keeps_a_bounded_inbox_and_counts_what_it_drops(monkeypatch, bound):
    """Real time, a service's inputs wait in a queue for its loop: one whose handler is slower than its inputs come (a
    mapper on a large grid, a flood on one of its keys) grew it, and its memory, without bound, each input acted on
    older than the last, with nothing in its status. Past ``INBOX_LIMIT`` inputs or ``INBOX_MAX_BYTES`` of payloads
    the oldest input is dropped and counted as a rejection of its topic; the service goes on and handles what comes next."""
    from services import common
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    limit, extra = 20, 30
    scan = LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.inf, np.float32))
    one_scan_bytes = len(encode(ScanMsg(1, scan, Pose2D(2.0, 2.0, 0.0))))
    monkeypatch.setattr(common, bound, limit if bound == "INBOX_LIMIT" else limit * one_scan_bytes)
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        maps: list[int] = []
        sub = session.declare_subscriber(keys.map, lambda s: maps.append(decode(s.payload.to_bytes(), MapMsg).step))
        svc = MapperService(ServiceContext("mapper", "t1", {}, ExplorationConfig(), client, {"restore_timeout_s": 0.2}))
        assert not svc.ctx.lockstep
        entered, release = threading.Event(), threading.Event()
        handle = svc.on_message

        def slow_on_scans(robot: str, topic: str, msg: Any, received_s: float) -> None:
            if topic == "scan" and not release.is_set():
                entered.set()
                release.wait(30)  # its handler far slower than its inputs come
            handle(robot, topic, msg, received_s)

        svc.on_message = slow_on_scans
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)

        def status() -> ServiceStatusMsg | None:
            replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(keys.service_status("mapper"), timeout=HANG_DEADLINE_S) if r.ok]
            return replies[0] if replies else None

        thread.start()
        try:
            wait_for(status, HANG_DEADLINE_S, "the mapper's status")
            session.put(keys.clock, encode(ClockMsg(0, 0.0, GridGeometry(0.1, (40, 40)))))
            session.put(keys.scan, encode(ScanMsg(0, scan, Pose2D(2.0, 2.0, 0.0))))
            assert entered.wait(HANG_DEADLINE_S), "the scan's handler never ran"
            for step in range(1, limit + extra + 1):
                session.put(keys.scan, encode(ScanMsg(step, scan, Pose2D(2.0, 2.0, 0.0))))
            wait_for(lambda: (s := status()) is not None and s.rejected.get("scan") == extra, HANG_DEADLINE_S, f"{extra} scans dropped and counted")
            assert svc.backlog() == limit
            release.set()
            wait_for(lambda: limit + extra in maps, HANG_DEADLINE_S, "the map of the newest scan")
            assert maps == [0, *range(extra + 1, limit + extra + 1)], "the oldest waiting were dropped, the newest handled in order"
            session.put(keys.scan, encode(ScanMsg(limit + extra + 1, scan, Pose2D(2.0, 2.0, 0.0))))
            wait_for(lambda: limit + extra + 1 in maps, HANG_DEADLINE_S, "a map for the next scan")
            final = status()
            assert final is not None and final.rejected == {"scan": extra} and final.processed == 1 + limit + 2  # the clock, scan 0, the kept, the next
        finally:
            release.set()
            stop.set()
            thread.join(10)
            sub.undeclare()
    assert not thread.is_alive()


def test_an_exception_in_a_services_queryable_is_counted_in_its_status_and_its_status_still_answers(caplog):
    """A service's queryables run on Zenoh's thread: an exception there reached only Zenoh's own log line and no count,
    and one raised by a service's ``extra_status`` (its own counts, a service of one's own's code) left its status
    query unanswered: its launcher killed and restarted it as hung, again and again. Now the status goes out without
    those counts, and every such exception is logged and counted (``callback_errors``)."""
    from services.common import Service, ServiceContext, run_service

    class Probe(Service):
        name = "probe"
        inputs = {"scan": ScanMsg}
        serves_latest = ("map",)

        def on_message(self, robot: str, topic: str, msg: Any, received_s: float) -> None:
            pass

        def extra_status(self) -> dict[str, int]:
            raise KeyError("a bug in its own counts")

        def answer_cache_query(self, topic: str, query: Any) -> None:
            raise RuntimeError(f"a bug in its {topic} cache")

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        svc = Probe(ServiceContext("probe", "t1", {}, ExplorationConfig(), client, {}))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)

        def status() -> ServiceStatusMsg | None:
            replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(keys.service_status("probe"), timeout=2.0) if r.ok]
            return replies[0] if replies else None

        thread.start()
        try:
            wait_for(lambda: any(True for r in session.liveliness().get(keys.alive("probe"), timeout=0.5) if r.ok), HANG_DEADLINE_S, "the probe's token")
            with caplog.at_level("ERROR", logger="cso.service"):
                first = status()
                assert first is not None, "the status query went unanswered"
                assert first.counters == {"callback_errors": 1} and first.state == "running"
                assert not [r for r in session.get(keys.cache("map"), timeout=0.5) if r.ok]
                wait_for(lambda: (s := status()) is not None and s.counters["callback_errors"] == 3, HANG_DEADLINE_S, "the cache query's error counted")
            assert "probe: extra_status raised (1 callback errors so far)" in caplog.text and "a bug in its map cache" in caplog.text
        finally:
            stop.set()
            thread.join(10)
    assert not thread.is_alive()


def test_a_late_joiner_asking_the_real_time_mapper_for_its_map_gets_the_map_last_published_not_one_half_integrated(monkeypatch):
    """In real time the mapper's loop integrates each scan into its map while Zenoh's thread answers the map query of
    a late joiner (a restarted frontier service): the answer was built from the map being integrated into, a scan
    half in under the step before it, or a map every receiver refuses (its explored cells copied before a scan, its
    occupied ones after). The answer is the map last published, whole."""
    from services import mapper as mapper_module
    from services.common import ServiceContext, run_service
    from services.mapper import MapperService

    integrated, release = threading.Event(), threading.Event()
    real_integrate = mapper_module.integrate_observation

    def integrate_then_wait(occupancy: Any, pose: Pose2D, scan: LaserScan, config: Any) -> int:
        newly = real_integrate(occupancy, pose, scan, config)
        if pose.x_m > 3.0:  # the second scan: the query comes while its handler is still at it
            integrated.set()
            release.wait(30)
        return newly

    monkeypatch.setattr(mapper_module, "integrate_observation", integrate_then_wait)
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        maps: list[MapMsg] = []
        sub = session.declare_subscriber(keys.map, lambda s: maps.append(decode(s.payload.to_bytes(), MapMsg)))
        svc = MapperService(ServiceContext("mapper", "t1", {}, ExplorationConfig(), client, {"restore_timeout_s": 0.2}))
        stop = threading.Event()
        thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
        thread.start()
        try:
            wait_for(lambda: any(True for r in session.liveliness().get(keys.alive("mapper"), timeout=0.5) if r.ok), HANG_DEADLINE_S, "the mapper's token")
            session.put(keys.clock, encode(ClockMsg(0, 0.0, GridGeometry(0.1, (40, 60)))))
            scan = LaserScan(-np.pi, np.pi / 180, 0.1, 1.5, np.full(360, np.inf, np.float32))
            session.put(keys.scan, encode(ScanMsg(0, scan, Pose2D(1.5, 2.0, 0.0), 7)))
            wait_for(lambda: maps, HANG_DEADLINE_S, "the map of step 0")
            session.put(keys.scan, encode(ScanMsg(1, scan, Pose2D(4.5, 2.0, 0.0), 7)))
            assert integrated.wait(HANG_DEADLINE_S), "the second scan was never integrated"
            replies = [r.ok.payload.to_bytes() for r in session.get(keys.map, timeout=HANG_DEADLINE_S) if r.ok]
            assert len(replies) == 1
            late = decode(replies[0], MapMsg)  # a map the receiver refuses fails here
            assert (late.step, late.episode) == (0, 7)
            np.testing.assert_array_equal(late.grid, maps[0].grid)  # not scan 1's cells under step 0
            release.set()
            wait_for(lambda: len(maps) == 2, HANG_DEADLINE_S, "the map of step 1")
            late = next(decode(r.ok.payload.to_bytes(), MapMsg) for r in session.get(keys.map, timeout=HANG_DEADLINE_S) if r.ok)
            assert late.step == 1 and np.array_equal(late.grid, maps[1].grid)
        finally:
            release.set()
            stop.set()
            thread.join(10)
            sub.undeclare()
    assert not thread.is_alive()


def test_a_policy_server_counts_payloads_on_keys_of_no_robot_under_their_topic_not_one_entry_per_key_made_up():
    """A policy serving every robot subscribes to ``cso/*/frontiers``, so it hears keys of any robot chunk: a rejection
    of a key that names no valid robot was counted under the key itself, and every key a sender made up added an entry
    to its ``rejected`` and to its status, without bound. They are counted under the topic; a valid robot is still
    served after them."""
    from cso_runtime.messages import GoalMsg, frontiers_from_observation
    from tests.test_messages import _observation
    from tests.test_runtime import shared_policy_server

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        goals: list[GoalMsg] = []
        sub = session.declare_subscriber(RobotKeys("a").goal, lambda s: goals.append(decode(s.payload.to_bytes(), GoalMsg)))
        with shared_policy_server(session, client) as svc:
            try:
                made_up = 200
                for i in range(made_up):
                    session.put(f"cso/not.a.robot{i}/frontiers", b"anything")
                payload = encode(frontiers_from_observation(0, "no_goal", _observation(), 1.0))
                session.put(RobotKeys("a").frontiers, payload)
                wait_for(lambda: goals, HANG_DEADLINE_S, "robot a's goal after the made-up keys")
                replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(RobotKeys("a").service_status("policy"), timeout=HANG_DEADLINE_S) if r.ok]
                assert replies and replies[0].rejected == {"frontiers": made_up}, replies
                assert svc.rejected == {"frontiers": made_up}
            finally:
                sub.undeclare()


def test_a_policy_server_with_many_stale_robots_still_sends_a_status_that_decodes():
    """A policy serving every robot names each robot it does not command in its status's reason: past the schema's 4096
    characters (40 robots of long ids gone quiet) its whole status was refused by every reader, and ``status`` showed
    the policy as not answering. The reason is clipped to fit."""
    from cso_runtime.messages import MAX_TEXT_CHARS, FrontiersMsg, frontiers_from_observation
    from services.policy import PolicyService
    from tests.test_messages import _observation

    policy, _ = _service(PolicyService, lockstep=False, params={"serve_all_robots": True})
    decision = decode(encode(frontiers_from_observation(0, "no_goal", _observation(), 1.0)), FrontiersMsg)
    now_s = time.monotonic()
    robots = [f"robot{i:02d}" + "x" * 57 for i in range(40)]
    for robot in robots:
        policy.on_message(robot, "frontiers", decision, now_s)
    policy.on_tick(now_s + 2 * policy.params.stale_after_s)
    assert policy.state == "stale" and len(policy.reason) > MAX_TEXT_CHARS
    status = decode(encode(policy.status_msg()), ServiceStatusMsg)
    assert status.state == "stale" and len(status.reason) == MAX_TEXT_CHARS and status.reason.endswith("…")
    assert status.reason.startswith(policy.reason[:100])


@contextlib.contextmanager
def _running(svc: Any) -> Iterator[None]:
    """``svc`` run by ``run_service`` on a thread of its own; stopped and joined on the way out."""
    from services.common import run_service

    stop = threading.Event()
    thread = threading.Thread(target=run_service, args=(svc, stop), daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(10)
    assert not thread.is_alive()


def _status_of(session: Any, keys: RobotKeys, name: str) -> ServiceStatusMsg | None:
    replies = [decode(r.ok.payload.to_bytes(), ServiceStatusMsg) for r in session.get(keys.service_status(name), timeout=2.0) if r.ok]
    return replies[0] if replies else None


def _alive(session: Any, keys: RobotKeys, name: str) -> bool:
    return any(True for r in session.liveliness().get(keys.alive(name), timeout=0.5) if r.ok)


def _raise(*_args: Any) -> None:
    raise RuntimeError("a bug in a callback")


def test_an_exception_in_the_sims_queryables_is_counted_in_its_status_and_its_status_still_answers(monkeypatch):
    """The sim declared its episode status and result queryables (and its liveliness subscriber) bare: an exception in
    one reached Zenoh's own log line alone, in no count. They go through ``Service.guarded`` as every service's."""
    from services.common import ServiceContext
    from services.sim import SimService

    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 3, "services": {"sim": {}, "mapper": {}}}
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        svc = SimService(ServiceContext("sim", "t1", profile, ExplorationConfig(), client, {"start_delay_s": 0.0}))
        svc._on_status_query = _raise  # type: ignore[method-assign]  # as start() declares it
        with _running(svc):
            wait_for(lambda: _alive(session, keys, "sim"), HANG_DEADLINE_S, "the sim's token")
            assert not [r for r in session.get(keys.episode_status, timeout=1.0) if r.ok]
            status = _status_of(session, keys, "sim")
            assert status is not None, "the sim's status went unanswered"
            assert status.counters.get("callback_errors") == 1, status.counters


def test_an_exception_in_the_ros2_bridges_callbacks_is_counted_in_its_status_and_its_status_still_answers(monkeypatch):
    """The ROS 2 bridge declared its ROS subscribers (scan, odometry, resume) and its queryables bare: a scan whose
    handling raised (a bug in its conversion) was in Zenoh's log alone, counted nowhere. They go through
    ``Service.guarded``."""
    from services.common import ServiceContext
    from services.ros2_bridge import Ros2BridgeService

    monkeypatch.setenv("CSO_PARENT_PID", str(os.getppid()))  # as up starts it: no claim to settle first
    port = free_tcp_port()
    client = TransportConfig(mode="client", connect=[loopback_endpoint(port)])
    keys = RobotKeys("t1")
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as session:
        svc = Ros2BridgeService(ServiceContext("ros2_bridge", "t1", {"method": "greedy-dist"}, ExplorationConfig(), client, {"namespace": "limo1"}))
        svc._on_ros_scan = _raise  # type: ignore[method-assign]  # as start() declares it
        svc._on_status_query = _raise  # type: ignore[method-assign]
        with _running(svc):
            wait_for(lambda: svc._ros_subs, HANG_DEADLINE_S, "the bridge's ROS subscriptions")
            with session.declare_publisher("limo1/scan") as publisher:
                wait_for(lambda: publisher.matching_status.matching, HANG_DEADLINE_S, "the bridge's scan subscription at the router")
                publisher.put(b"a LaserScan")
            wait_for(lambda: (s := _status_of(session, keys, "ros2_bridge")) is not None and s.counters.get("callback_errors") == 1,
                     HANG_DEADLINE_S, "the scan's error counted")  # fmt: skip
            assert not [r for r in session.get(keys.episode_status, timeout=1.0) if r.ok]
            status = _status_of(session, keys, "ros2_bridge")
            assert status is not None and status.counters.get("callback_errors") == 2, status


def test_a_real_time_frontier_service_under_a_sustained_flood_still_decides():
    """Real time, the frontier service leaves a ready map to a newer one while inputs wait (``backlog() > 0``): under a
    flood above its handling rate the inbox never emptied, and no decision was ever made however long it lasted. It
    decides anyway after ``DEFER_MAX_INPUTS`` inputs or ``DEFER_MAX_S`` seconds, on the newest pair it holds."""
    from services.frontier import DEFER_MAX_INPUTS, DEFER_MAX_S

    frontier, out = _service(FrontierService, lockstep=False, params={"goal_wait_s": 30.0})
    ex = _explorer_at(0)
    _, odom0, _ = _inputs(ex, 0)
    frontier._inbox.put("newer input")  # a backlog that never empties
    _feed(frontier, odom0)
    step = 0
    while not out and step <= DEFER_MAX_INPUTS:  # each map finds its odometry, and newer inputs waiting
        step += 1
        _feed(frontier, OdometryMsg(step, odom0.stamp_s + 0.1 * step, odom0.pose))
        _feed(frontier, MapMsg.of(step, ex.map))
    frontiers = [(m.step, m.decide) for t, m in out if t == "frontiers"]
    assert frontiers == [(step, True)], frontiers
    # Each input that leaves a ready pair counts (the odometry of a step whose map is in counts too).
    assert step == DEFER_MAX_INPUTS // 2 + 1, step
    out.clear()
    _feed(frontier, OdometryMsg(step + 1, odom0.stamp_s, odom0.pose))
    _feed(frontier, MapMsg.of(step + 1, ex.map))  # deferred again, the count afresh
    assert out == [] and frontier.deferred_inputs == 1
    assert frontier.deferred_since_s is not None
    frontier.deferred_since_s -= DEFER_MAX_S  # a second has gone by with the backlog never empty
    _feed(frontier, OdometryMsg(step + 2, odom0.stamp_s, odom0.pose))  # the next input: decided, on the newest pair
    assert [(m.step, m.decide) for t, m in out if t == "frontiers"] == [(step + 1, False)]  # the last goal not in yet


def test_a_lockstep_frontier_service_never_decides_before_its_step_whatever_waits():
    """The bound on deferring is real time's: lockstep decides each step in order as before, backlog or not."""
    frontier, out = _service(FrontierService, lockstep=True)
    ex = _explorer_at(0)
    m0, odom0, _ = _inputs(ex, 0)
    frontier._inbox.put("newer input")
    _feed(frontier, odom0)
    _feed(frontier, m0)
    assert [(m.step, m.decide) for t, m in out if t == "frontiers"] == [(0, True)]
    assert frontier.deferred_inputs == 0 and frontier.deferred_since_s is None


def test_inputs_dropped_from_a_full_inbox_of_robots_never_heard_from_are_counted_under_their_topic_alone(monkeypatch):
    """A service serving every robot, its inbox full of keys of robots made up: each dropped input was counted under
    its robot too, an entry per robot that ``forget_robot`` never forgets (the robot was never heard from, its input
    dropped before it was handled), so the service grew without bound. Counted under the topic alone; the robots it
    heard from are still counted as theirs."""
    from services import common
    from services.common import ServiceInputs
    from tests.test_service_logic import _Recorder

    monkeypatch.setattr(common, "INBOX_LIMIT", 2)
    ctx = common.ServiceContext("recorder", "r0", {}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    svc = _Recorder(ctx)
    svc.subscribe_robot = "*"
    svc.heard_from_s["known"] = 0.0
    inputs = ServiceInputs(svc, threading.Event())
    payload = encode(OdometryMsg(1, 0.25, Pose2D(0.0, 0.0, 0.0)))

    class Sample:
        def __init__(self, robot: str) -> None:
            self.key_expr, self.payload = f"cso/{robot}/odom", self

        def to_bytes(self) -> bytes:
            return payload

    for robot in ("known", "r0", *(f"madeup{i}" for i in range(50)), "x", "y"):
        inputs.on_sample(Sample(robot))
    assert svc.rejected == {"odom": 52}
    assert svc.rejected_by_robot == {"known": {"odom": 1}, "r0": {"odom": 1}}
    assert inputs.queue.qsize() == 2 and inputs.queue.nbytes == 2 * len(payload)


def test_a_status_whose_reason_names_an_undecodable_file_name_still_encodes():
    """A reason may carry a lone surrogate (a file name of bytes that are no UTF-8, as ``os.fsdecode`` gives it): the
    whole status failed to encode, and its query went unanswered (the launcher restarting the service as hung). It is
    escaped; multi-byte characters are kept whole, as many as the decoder takes."""
    from cso_runtime.messages import MAX_TEXT_CHARS
    from services.policy import PolicyService

    policy, _ = _service(PolicyService, lockstep=False)
    policy.set_state("stale", "cannot read " + os.fsdecode(b"/runs/\xff.yaml"))
    status = decode(encode(policy.status_msg()), ServiceStatusMsg)
    assert status.reason == "cannot read /runs/\\udcff.yaml"
    policy.set_state("stale", "é" * (MAX_TEXT_CHARS + 10))
    status = decode(encode(policy.status_msg()), ServiceStatusMsg)
    assert status.reason == "é" * (MAX_TEXT_CHARS - 1) + "…"


class _KeySample:
    """What Zenoh hands a subscriber callback: a key expression and a payload."""

    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr, self.payload, self._bytes = key, self, payload

    def to_bytes(self) -> bytes:
        return self._bytes


def test_a_full_inbox_drops_its_oldest_data_never_a_pause_waiting_among_them(monkeypatch):
    """An operator's pause shares a real-time service's inbox with its data: under a sustained overload the inbox
    dropped its oldest input, the pause as any other, and the planner never stopped the robot. The oldest data input is
    dropped instead; every input left still comes out in the order it came."""
    from cso_runtime.messages import ExploreResumeMsg
    from services import common
    from services.common import ServiceInputs

    limit = 4
    monkeypatch.setattr(common, "INBOX_LIMIT", limit)
    planner, _ = _service(PlannerService, lockstep=False)
    inputs = ServiceInputs(planner, threading.Event())
    keys = RobotKeys("r0")

    def odometry(step: int) -> _KeySample:
        return _KeySample(keys.odom, encode(OdometryMsg(step, 0.25 * step, Pose2D(1.0, 1.0, 0.0))))

    inputs.on_sample(odometry(1))
    inputs.on_sample(_KeySample(keys.explore_resume, encode(ExploreResumeMsg(False, "op@host"))))
    for step in range(2, 12):  # the flood: 11 odometry messages, 3 of them kept beside the pause
        inputs.on_sample(odometry(step))
    assert planner.rejected == {"odom": 8} and inputs.queue.qsize() == limit
    queued = [item for _ in range(limit) if (item := inputs.next_queued(0.0)) is not None]
    assert [topic_name(key) for key, _, _ in queued] == ["resume", "odom", "odom", "odom"]
    assert [decode(payload, OdometryMsg).step for key, payload, _ in queued[1:]] == [9, 10, 11]
    for item in queued:
        inputs.handle(*item)
    assert planner.paused is not None and planner.paused.by == "op@host"
    # A flood of controls alone: the oldest go, the newest (which says the state) stays.
    for i in range(2 * limit):
        inputs.on_sample(_KeySample(keys.explore_resume, encode(ExploreResumeMsg(i % 2 == 1, f"op{i}"))))
    left = [decode(item[1], ExploreResumeMsg).by for _ in range(limit) if (item := inputs.next_queued(0.0)) is not None]
    assert left == [f"op{i}" for i in range(limit, 2 * limit)] and inputs.queue.nbytes == 0


def test_a_guarded_queryable_that_raises_answers_its_querier_at_once_with_an_error_naming_it(caplog):
    """A guarded queryable (``Service.guarded``) that raised left its query to be finalized whenever the ``Query``
    object was freed: a log handler that keeps the record (pytest's own, a memory handler) keeps its traceback, and
    with it the query, so the querier waited out its whole timeout for nothing. It replies with an error that names
    the callback and ends the query at once."""
    from services.common import Service, ServiceContext

    svc = Service(ServiceContext("probe", "t1", {}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {}))

    def episode_status_query(query: Any) -> None:
        raise RuntimeError("a bug in the reply")

    port = free_tcp_port()
    with (
        caplog.at_level("ERROR", logger="cso.service"),
        open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as router,
        open_session(TransportConfig(mode="client", connect=[loopback_endpoint(port)])) as session,
        session.declare_queryable("t1/probe/q", svc.guarded(episode_status_query)),
        router.declare_querier("t1/probe/q", timeout=10.0) as querier,
    ):
        wait_for(lambda: querier.matching_status.matching, HANG_DEADLINE_S, "the queryable at the router")
        started_s = time.monotonic()
        replies = list(querier.get())
        took_s = time.monotonic() - started_s
    assert svc.callback_errors == 1 and "episode_status_query raised" in caplog.text
    assert [r.ok for r in replies] == [None] and replies[0].err is not None, replies
    assert replies[0].err.payload.to_string() == "episode_status_query raised RuntimeError: a bug in the reply"
    assert took_s < 5.0, f"the querier waited {took_s:.1f} s for a query that had failed"


def test_a_guarded_queryable_that_raises_system_exit_is_counted_and_answers_its_querier_at_once(caplog):
    """``transport.guarded_callback`` caught ``Exception`` alone: a ``SystemExit`` (or ``KeyboardInterrupt``) raised in a
    callback went by it into Zenoh's thread, in no count, its query answered with no error, and Zenoh's log record of it
    (kept here by pytest's handler, as by any handler that keeps records) kept the query: the querier waited out its
    whole timeout. It is counted and answered like any error, then raised on."""
    from cso_runtime.transport import guarded_callback

    failed: list[str] = []

    def episode_status_query(query: Any) -> None:
        raise SystemExit("stop here")

    port = free_tcp_port()
    with (
        caplog.at_level("ERROR"),
        open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])) as router,
        open_session(TransportConfig(mode="client", connect=[loopback_endpoint(port)])) as session,
        session.declare_queryable("t1/probe/q", guarded_callback(episode_status_query, failed.append)),
        router.declare_querier("t1/probe/q", timeout=8.0) as querier,
    ):
        wait_for(lambda: querier.matching_status.matching, HANG_DEADLINE_S, "the queryable at the router")
        started_s = time.monotonic()
        replies = list(querier.get())
        took_s = time.monotonic() - started_s
    assert failed == ["episode_status_query"]
    assert [r.ok for r in replies] == [None] and replies[0].err is not None, replies
    assert replies[0].err.payload.to_string() == "episode_status_query raised SystemExit: stop here"
    assert took_s < 4.0, f"the querier waited {took_s:.1f} s for a query that had failed"
