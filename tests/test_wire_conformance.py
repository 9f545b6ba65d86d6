"""docs/messages.md as someone writing a service in another language reads it: every schema built by hand from the
docs alone (msgpack, numpy and zlib; nothing of ``cso_runtime.messages`` but ``decode`` and ``encode``), decoded by the
project to the same values, and the project's own payloads read back by hand the same way. So the documented wire
format (envelope, field names, array records, dtypes, byte and bit order, codecs, version and rejection rules) cannot
drift from ``cso_runtime/messages.py``. tests/test_messages.py tests the codec against itself; tests/test_docs.py holds
the docs' version paragraph, and tests/test_dataflow.py the key table's publishers and subscribers, to the code."""

from __future__ import annotations

import contextlib
import copy
import json
import math
import re
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import yaml

from cso_runtime.geometry import Pose2D
from cso_runtime.keys import TOPICS, RobotKeys
from cso_runtime.messages import (
    MESSAGE_TYPES,
    ClockMsg,
    CmdVelMsg,
    DistanceMapMsg,
    EndedWhyMsg,
    EpisodeResultMsg,
    EpisodeStatusMsg,
    ExploreResumeMsg,
    FrontiersMsg,
    GoalMsg,
    LauncherStatusMsg,
    MapMsg,
    MessageError,
    OdometryMsg,
    PathMsg,
    PlannerContactsMsg,
    PlannerFeedbackMsg,
    PlannerPlanMsg,
    PlannerStateMsg,
    ScanMsg,
    ServiceStatusMsg,
    decode,
    encode,
)
from tests.test_dataflow import docs_table
from tests.test_own_service import up_from_this_checkout
from tests.test_runtime import PROFILES, SCENE, cli, in_process_result, kill_leftovers, wait_for

# --- the wire format, as docs/messages.md states it ----------------------------------------------

WIRE_DTYPES = {
    "bool": "|b1",
    "int8": "<i1",
    "int16": "<i2",
    "int32": "<i4",
    "int64": "<i8",
    "uint8": "|u1",
    "uint16": "<u2",
    "float32": "<f4",
    "float64": "<f8",
}
"""The dtype names an array record may carry (docs: "Arrays"), each with its little-endian numpy dtype."""


def bits_of(cells: np.ndarray) -> bytes:
    """Boolean cells packed 8 to a byte, row-major, cell ``8 j + k`` in bit ``k`` (value ``2**k``) of byte ``j``, the
    last byte's unused high bits 0: the docs' words, without ``numpy.packbits``."""
    flat = np.asarray(cells, dtype=bool).ravel().astype(np.uint8)
    flat = np.concatenate([flat, np.zeros(-flat.size % 8, np.uint8)]).reshape(-1, 8)
    return bytes((flat.astype(np.uint16) << np.arange(8, dtype=np.uint16)).sum(axis=1).astype(np.uint8).tolist())


def cells_of(packed: bytes, n: int) -> np.ndarray:
    """``bits_of`` inverted: the first ``n`` cells."""
    byte = np.frombuffer(packed, dtype=np.uint8)
    return ((byte[:, None] >> np.arange(8, dtype=np.uint8)) & 1).ravel()[:n].astype(bool)


def record(a: np.ndarray, dtype: str, z: bool | str = False) -> dict[str, Any]:
    """One array as the docs' record ``{dtype, shape, z, data}``: raw little-endian row-major bytes; ``z`` true: those
    bytes zlib-compressed; ``"bits"`` (boolean only): bit-packed, then zlib-compressed."""
    a = np.asarray(a)
    if z == "bits":
        data = zlib.compress(bits_of(a))
    else:
        data = np.ascontiguousarray(a, dtype=np.dtype(WIRE_DTYPES.get(dtype, dtype)).newbyteorder("<")).tobytes()
        data = zlib.compress(data) if z else data
    return {"dtype": dtype, "shape": list(a.shape), "z": z, "data": data}


def read_record(rec: dict[str, Any]) -> np.ndarray:
    """An array record read by hand, as the docs describe it (its dtype the record's)."""
    assert set(rec) == {"dtype", "shape", "z", "data"} and isinstance(rec["data"], bytes), rec
    n = math.prod(rec["shape"])
    if rec["z"] == "bits":
        assert rec["dtype"] == "bool"
        packed = zlib.decompress(rec["data"])
        assert len(packed) == (n + 7) // 8
        return cells_of(packed, n).reshape(rec["shape"])
    raw = zlib.decompress(rec["data"]) if rec["z"] is True else rec["data"]
    assert rec["z"] in (True, False)
    return np.frombuffer(raw, dtype=np.dtype(WIRE_DTYPES[rec["dtype"]])).reshape(rec["shape"])


def is_record(v: Any) -> bool:
    return isinstance(v, dict) and set(v) == {"dtype", "shape", "z", "data"}


def envelope(schema: str, version: int, body: dict[str, Any]) -> bytes:
    """The docs' envelope: a msgpack map of exactly ``schema``, ``v`` and ``body``; strings as msgpack str, bytes as bin."""
    return msgpack.packb({"schema": schema, "v": version, "body": body}, use_bin_type=True)


def read_payload(payload: bytes) -> tuple[str, int, dict[str, Any]]:
    raw = msgpack.unpackb(payload, raw=False)
    assert set(raw) == {"schema", "v", "body"}
    return raw["schema"], raw["v"], raw["body"]


def by_hand(value: Any) -> Any:
    """A body with every array record read by hand: ``("array", dtype, shape, values)``, whatever its ``z``."""
    if is_record(value):
        a = read_record(value)
        return ("array", value["dtype"], tuple(a.shape), a.tolist())
    if isinstance(value, dict):
        return {k: by_hand(v) for k, v in value.items()}
    if isinstance(value, list):
        return [by_hand(v) for v in value]
    return value


def bits_promised(value: Any, path: str = "") -> set[str]:
    """The paths of the records sent ``"z": "bits"`` (what the docs promise bit-packed)."""
    if is_record(value):
        return {path} if value["z"] == "bits" else set()
    if isinstance(value, dict):
        return set().union(*(bits_promised(v, f"{path}.{k}") for k, v in value.items()))
    if isinstance(value, list):
        return set().union(*(bits_promised(v, f"{path}[{i}]") for i, v in enumerate(value)))
    return set()


# --- one body per schema, from the docs ------------------------------------------------------------

GEOMETRY = {"resolution_m": 0.1, "shape": [4, 5], "origin": [-0.2, -0.25]}
"""(ny, nx) = (4, 5) cells of 0.1 m, cell (0, 0)'s corner at (-0.2, -0.25) m."""
EXPLORED = np.array([[1, 1, 1, 0, 0], [1, 1, 1, 1, 0], [0, 1, 1, 1, 0], [0, 0, 0, 0, 0]], dtype=bool)
OCCUPIED = np.array([[1, 0, 0, 0, 0], [0, 0, 0, 1, 0], [0, 0, 0, 0, 0], [0, 0, 0, 0, 0]], dtype=bool)
FRONTIER = np.array([[0, 0, 1, 0, 0], [0, 0, 0, 0, 0], [0, 1, 1, 1, 0], [0, 0, 0, 0, 0]], dtype=bool)
ENTROPY = np.array([[0, 0, 3, 0, 0], [0, 0, 0, 0, 0], [0, 7, 250, 1, 0], [0, 0, 0, 0, 0]], dtype=np.int64)
DISTANCE = np.array([[0.3, 0.2, 0.1, np.inf, np.inf], [0.2, 0.1, 0.0, np.inf, np.inf], [np.inf, 0.2, 0.1, 0.2, np.inf], [np.inf] * 5])
EPISODE = 0xBEEF0000CAFE


def map_body(step: int = 12) -> dict[str, Any]:
    return {"step": step, "geometry": GEOMETRY, "explored": record(EXPLORED, "bool", "bits"), "occupied": record(OCCUPIED, "bool", "bits"), "episode": EPISODE}


def decision_body() -> dict[str, Any]:
    mask = ENTROPY != 0
    traversable = EXPLORED & ~OCCUPIED
    return {
        "step": 12,
        "decide": True,
        "reason": "reached",
        "episode": EPISODE,
        "pose": [0.0, -0.1, 1.5],
        "geometry": GEOMETRY,
        "arrays": {
            "explored": record(EXPLORED, "bool", "bits"),
            "occupied": record(OCCUPIED, "bool", "bits"),
            "traversable": record(traversable, "bool", "bits"),
            "frontier": record(FRONTIER, "bool", "bits"),
            "entropy": record(ENTROPY[mask], "uint8"),  # the non-zero counts, row by row, in the smallest type
        },
        "masks": {"entropy": record(mask, "bool", "bits")},
        "clusters": [
            {
                "goal_cell": [2, 1],  # [iy, ix]
                "goal_xy_m": [-0.05, 0.0],  # its centre: origin + (index + 0.5) * resolution
                "distance_m": 0.2,
                "size_m": 0.4,
                "entropy": 258.0,
                "centroid_xy_m": [0.0, -0.05],
                "cells": record(np.array([[0, 2], [2, 1], [2, 2], [2, 3]]), "int32"),  # (k, 2) [iy, ix]
            }
        ],
        "open_area_m2": 0.09,
        "path_nodes_xy_m": record(np.array([[0.0, -0.1], [0.1, 0.05]]), "float64"),
        "path_nodes_distance_m": record(np.array([0.0, np.inf]), "float64"),  # inf: unreachable
        "build_ms": 3.5,
    }


BODIES: dict[str, list[dict[str, Any]]] = {
    "clock": [{"step": 3, "time_s": 0.75, "episode": EPISODE, "geometry": GEOMETRY}, {"step": 4, "time_s": 1.0, "episode": EPISODE}],
    "scan": [
        {
            "step": 3,
            "stamp_s": 0.75,
            "angle_min_rad": -1.5,
            "angle_increment_rad": 0.5,
            "range_min_m": 0.1,
            "range_max_m": 8.0,
            "ranges_m": record(np.array([1.0, np.inf, 2.5, 8.0, 0.0625, 3.0, 4.0]), "float32"),
            "sensor_pose": [1.0, 2.0, 0.25],
            "episode": EPISODE,
        }
    ],
    "odom": [{"step": 3, "stamp_s": 0.75, "pose": [0.875, 2.0, 0.25], "twist": [0.2, -0.5], "episode": EPISODE}],
    "cmd_vel": [{"step": 3, "linear_mps": 0.25, "angular_radps": -0.5, "reason": "", "new_goal": True}],
    "map": [map_body()],
    "frontiers": [{"step": 11, "decide": False, "reason": "", "episode": EPISODE}, decision_body()],
    "distance_map": [
        {
            "step": 12,
            "geometry": GEOMETRY,
            "pose": [0.0, -0.1, 1.5],
            "finite": record(np.isfinite(DISTANCE), "bool", "bits"),
            "distance_m": record(DISTANCE[np.isfinite(DISTANCE)], "float64"),  # the finite ones, row by row
            "episode": EPISODE,
        }
    ],
    "ended_why": [{"step": 40, "why": "2 frontier cells left: both unreachable", "episode": EPISODE}],
    "goal": [
        {"step": 12, "decided": True, "goal": [-0.05, 0.0, 0, 0.2], "decision_ms": 4.5, "method": "greedy-dist", "reason": "reached", "episode": EPISODE},
        {"step": 40, "decided": True, "goal": None, "decision_ms": 1.0, "method": "greedy-dist", "reason": "no_goal", "episode": EPISODE},
    ],
    "path": [{"step": 12, "path_xy_m": record(np.array([[0.0, -0.1], [-0.05, -0.05]]), "float32")}],
    "planner_feedback": [
        {
            "step": 12,
            "episode": EPISODE,
            "status": "following",
            "phase": "command",
            "set_goal_blocked": False,
            "reason": "",
            "path_ahead_xy_m": record(np.array([[0.0, -0.1], [-0.05, -0.05]]), "float64"),
            "goal_step": 12,
        }
    ],
    "planner_contacts": [{"step": 14, "contacts_xy_m": record(np.array([[0.125, -0.075], [0.175, -0.075]]), "float64"), "episode": EPISODE}],
    "planner_plan": [
        {
            "step": 12,
            "episode": EPISODE,
            "path_xy_m": record(np.array([[0.0, -0.1], [-0.05, -0.05]]), "float64"),
            "free": {
                "geometry": GEOMETRY, "traversable": record(EXPLORED & ~OCCUPIED, "bool", "bits"), "occupied": record(OCCUPIED, "bool", "bits"),
                "explored": record(EXPLORED, "bool", "bits"),
            },
        },
        {"step": 40, "episode": EPISODE, "path_xy_m": record(np.zeros((0, 2)), "float64"), "free": None},
    ],
    "planner_state": [
        {
            "step": 14,
            "episode": EPISODE,
            "plan_step": 12,
            "goal_step": 12,
            "no_frontier": False,
            "cmd": {"step": 14, "linear_mps": 0.25, "angular_radps": -0.5, "reason": "backup", "new_goal": False},
            "set_goal_blocked": False,
            "status": "following",
            "progress_index": 1,
            "progress_anchor": [0.0, -0.1, 3.25],
            "stall": {
                "last": [0.0, -0.1, 1.5, 3.5, 0.25, -0.5], "stalled_periods": 2, "backing_up": 1, "backups": 1, "last_started_now": False,
                "backup_from": [0.0, -0.05, 1.5, 3.0],
            },
            "recovery": {"recoveries_left": 1, "heading_rad": 0.75, "drive_left_m": 0.125, "escape_periods": 4, "escapes": 1, "started_s": 2.5},
            "replan_pending": True,
            "blocked_why": "",
            "contacts": 2,
        },
        {
            "step": 40,
            "episode": EPISODE,
            "plan_step": 40,
            "goal_step": 40,
            "no_frontier": True,
            "cmd": {"step": 40, "linear_mps": 0.0, "angular_radps": 0.0, "reason": "no_frontier", "new_goal": True},
            "set_goal_blocked": False,
            "status": "idle",
            "progress_index": 0,
            "progress_anchor": None,
            "stall": {"last": None, "stalled_periods": 0, "backing_up": 0, "backups": 0, "last_started_now": False, "backup_from": None},
            "recovery": {"recoveries_left": 2, "heading_rad": None, "drive_left_m": 0.0, "escape_periods": 0, "escapes": 0, "started_s": 0.0},
            "replan_pending": False,
            "blocked_why": "",
        },
    ],
    "episode_status": [
        {
            "state": "exploring",
            "step": 12,
            "scene": "generated:small:1:0",
            "method": "greedy-dist",
            "coverage_pct": 42.5,
            "explored_area_m2": 10.25,
            "path_length_m": 3.5,
            "goal_xy_m": [-0.05, -0.05],
            "decisions": 2,
            "last_decision_ms": 4.5,
            "terminated_by": "",
            "reason": "",
            "lockstep_timeouts": 0,
            "episode": EPISODE,
            "map_origin": [1.0, -2.0, 0.5],
            "pose": [0.5, -0.25, 3.0],
            "twist": [0.2, -0.5],
            "coverage_measured": True,  # optional: the sim measures coverage
        },
        {  # no odometry yet (a ros2_bridge before its first scan): pose and twist nil
            "state": "starting",
            "step": 0,
            "scene": "ros2:/",
            "method": "greedy-dist",
            "coverage_pct": 0.0,
            "explored_area_m2": 0.0,
            "path_length_m": 0.0,
            "goal_xy_m": None,
            "decisions": 0,
            "last_decision_ms": 0.0,
            "terminated_by": "",
            "reason": "",
            "lockstep_timeouts": 0,
            "episode": EPISODE,
            "map_origin": [0.0, 0.0, 0.0],
            "pose": None,
            "twist": None,
            "coverage_measured": False,  # a real robot: no ground truth
        },
    ],
    "episode_result": [
        {
            "explored_area_m2": 10.25,
            "coverage_pct": 99.5,
            "traversable_area_m2": 11.0,
            "path_length_m": 30.5,
            "resolution_m": 0.1,
            "scene": "generated:small:1:0",
            "steps": 40,
            "terminated_by": "no_frontier",
            "decisions": 2,
            "method": "greedy-dist",
            "seed": -3,
            "decision_ms": record(np.array([4.5, 1.0]), "float64"),
            "trajectory_xy_m": record(np.array([[0.0, -0.1], [0.1, 0.0]]), "float64"),
            "coverage_curve_pct": record(np.array([10.0, 99.5]), "float64"),
            "explored_free": record(EXPLORED & ~OCCUPIED, "bool", "bits"),
            "plan_free": record(EXPLORED, "bool", "bits"),
            "final_map": map_body(40),
            "map_origin": [1.0, -2.0, 0.5],
            "ended_why": "2 frontier cells left: both unreachable",
            "episode": EPISODE,  # optional: the id of the episode it is the result of
        }
    ],
    "service_status": [
        {"service": "policy", "robot": "r0", "state": "running", "last_step": 12, "reason": "", "rejected": {"frontiers": 1}, "processed": 13, "counters": {"decisions": 2}}
    ],
    "launcher_status": [
        {"run_id": "20261207-000000-r0", "state": "running", "services": {"policy": {"pid": 123, "process_alive": True, "command": True, "restarts": 1, "gave_up": False, "hung_kills": 0, "robot_stops": 0}}, "rejected": {}, "handler_errors": {}},
        {
            "run_id": "20261207-000000-r0",
            "state": "running",
            "services": {"policy": {"liveliness": True, "outside": True, "awaited": True}},
            "rejected": {"episode_status": 1},
            "handler_errors": {},
            "last_episode": {
                "state": "exploring", "step": 12, "episode": EPISODE, "age_s": 0.5, "terminated_by": "", "scene": "s", "method": "m",
                "coverage_pct": 42.5, "explored_area_m2": 10.25, "path_length_m": 3.5, "decisions": 2, "reason": "",
                "map_origin": [1.0, -2.0, 0.5], "pose": [1.25, 2.0, 0.5], "twist": [0.2, -0.1],
            },
            "real_time_factor": 2.0,
            "lost_router": "tcp/127.0.0.1:7447",
            "run_dir_lost": 1,
            "pause": {"paused": True, "by": "me@host", "reason": "lunch", "for_s": 3.0, "total_s": 3.0, "refused": ""},
            "coverage_measured": False,
            "referee": "own",  # optional: a referee of one's own
            "lost_results": [{"episode": EPISODE, "state": "done", "step": 31, "running": EPISODE + 1}],  # optional: a result a restart lost
        },
    ],
    "explore_resume": [{"resume": False, "by": "me@host", "reason": "lunch", "stamp_s": 1.8e9}],
}
"""Bodies built from the docs alone, with every field the code sends (the project re-encodes them to the same)."""

BODIES["cmd_vel"].append(  # the project's planner's: its state and plan ride on it, the encoded payloads the cache serves
    {
        "step": 14, "linear_mps": 0.25, "angular_radps": -0.5, "reason": "backup", "new_goal": False, "episode": EPISODE,
        "planner_state": envelope("planner_state", 1, BODIES["planner_state"][0]), "planner_plan": envelope("planner_plan", 1, BODIES["planner_plan"][0]),
    }
)

CASES = [(schema, i) for schema, bodies in BODIES.items() for i in range(len(bodies))]


def test_every_schema_has_a_body_built_from_the_docs():
    assert set(BODIES) == set(MESSAGE_TYPES)


@pytest.mark.parametrize(("schema", "index"), CASES)
def test_a_payload_built_by_hand_from_the_docs_decodes_and_encodes_back_to_the_same_values(schema: str, index: int):
    """decode(hand-built) then encode: the same fields, dtypes, shapes and values when read by hand, and the boolean
    grids the docs promise bit-packed are."""
    body = BODIES[schema][index]
    cls = MESSAGE_TYPES[schema]
    msg = decode(envelope(schema, cls.VERSION, body), cls)
    out_schema, out_version, out_body = read_payload(encode(msg))
    assert (out_schema, out_version) == (schema, cls.VERSION)
    assert by_hand(out_body) == by_hand(body)
    assert bits_promised(out_body) == bits_promised(body)


def test_the_values_decoded_are_the_ones_the_docs_describe():
    """What a hand-built payload means to the project, field by field, in the docs' units, frames and orders."""
    bodies = {schema: [decode(envelope(schema, MESSAGE_TYPES[schema].VERSION, b)) for b in bs] for schema, bs in BODIES.items()}
    clock, no_arena = bodies["clock"]
    assert isinstance(clock, ClockMsg) and isinstance(no_arena, ClockMsg)
    assert (clock.step, clock.time_s, clock.episode, no_arena.arena) == (3, 0.75, EPISODE, None)
    assert clock.arena is not None and clock.arena.shape == (4, 5) and (clock.arena.origin_x_m, clock.arena.origin_y_m) == (-0.2, -0.25)
    # a cell's centre is the origin (cell (0, 0)'s corner) plus (index + 0.5) resolutions; [iy, ix], row = y
    assert np.allclose(clock.arena.cell_to_world(2, 1), (-0.05, 0.0)) and clock.arena.world_to_cell(-0.05, 0.0) == (2, 1)
    (scan,) = bodies["scan"]
    assert isinstance(scan, ScanMsg) and scan.scan.ranges_m.dtype == np.float32
    assert scan.scan.ranges_m.tolist() == [1.0, math.inf, 2.5, 8.0, 0.0625, 3.0, 4.0] and scan.sensor_pose.as_list() == [1.0, 2.0, 0.25]
    (odom,) = bodies["odom"]
    assert isinstance(odom, OdometryMsg) and (odom.pose.x_m, odom.pose.yaw_rad, odom.twist.linear_mps, odom.twist.angular_radps) == (0.875, 0.25, 0.2, -0.5)
    cmd, carrying = bodies["cmd_vel"]
    assert isinstance(cmd, CmdVelMsg) and (cmd.command.linear_mps, cmd.command.angular_radps, cmd.new_goal) == (0.25, -0.5, True)
    assert (cmd.episode, cmd.planner_state, cmd.planner_plan) == (0, None, None)  # a foreign planner's: none of them
    assert isinstance(carrying, CmdVelMsg) and carrying.episode == EPISODE and carrying.planner_state is not None and carrying.planner_plan is not None
    assert decode(carrying.planner_state, PlannerStateMsg) == bodies["planner_state"][0] and decode(carrying.planner_plan, PlannerPlanMsg).step == 12
    (m,) = bodies["map"]
    assert isinstance(m, MapMsg) and (m.explored == EXPLORED).all() and (m.occupied == OCCUPIED).all()
    assert m.grid.tolist()[0] == [100, 0, 0, -1, -1]  # the OccupancyGrid values, row 0 at the origin
    keep, decision = bodies["frontiers"]
    assert isinstance(keep, FrontiersMsg) and isinstance(decision, FrontiersMsg) and not keep.decide and keep.arrays == {}
    assert (decision.arrays["entropy"] == ENTROPY).all() and (decision.arrays["frontier"] == FRONTIER).all()
    (cluster,) = decision.clusters
    assert cluster["goal_cell"] == (2, 1) and cluster["cells"].tolist() == [[0, 2], [2, 1], [2, 2], [2, 3]]
    assert decision.path_nodes_distance_m.tolist() == [0.0, math.inf]
    (dist,) = bodies["distance_map"]
    assert isinstance(dist, DistanceMapMsg) and np.array_equal(dist.distance_m, DISTANCE)
    goal, no_goal = bodies["goal"]
    assert isinstance(goal, GoalMsg) and isinstance(no_goal, GoalMsg)
    assert (goal.goal_xy_m, goal.cluster_index, goal.distance_m, no_goal.has_goal) == ((-0.05, 0.0), 0, 0.2, False)
    (path,) = bodies["path"]
    assert isinstance(path, PathMsg) and path.path_xy_m.dtype == np.float32 and path.path_xy_m.shape == (2, 2)
    (feedback,) = bodies["planner_feedback"]
    assert isinstance(feedback, PlannerFeedbackMsg) and (feedback.status, feedback.goal_step, feedback.episode) == ("following", 12, EPISODE)
    (contacts,) = bodies["planner_contacts"]
    plan, no_plan = bodies["planner_plan"]
    assert isinstance(plan, PlannerPlanMsg) and plan.free is not None and plan.free.occupied is not None and no_plan.free is None  # type: ignore[union-attr]
    assert np.array_equal(plan.free.traversable, EXPLORED & ~OCCUPIED) and plan.free.geometry.origin_x_m == -0.2 and len(no_plan.path_xy_m) == 0  # type: ignore[attr-defined]
    state, idle = bodies["planner_state"]
    assert isinstance(state, PlannerStateMsg) and state.follow.stall_last is not None and state.cmd.reason == "backup"
    assert state.follow.stall_last[0].yaw_rad == 1.5 and state.follow.stall_last[2].angular_radps == -0.5 and state.follow.escape_heading_rad == 0.75
    assert idle.follow.progress_anchor is None and idle.follow.escape_heading_rad is None and idle.no_frontier  # type: ignore[attr-defined]
    assert state.contacts == 2 and idle.contacts is None  # type: ignore[attr-defined]  # optional: how many contacts it had
    assert isinstance(contacts, PlannerContactsMsg) and contacts.contacts_xy_m.tolist() == [[0.125, -0.075], [0.175, -0.075]] and contacts.episode == EPISODE
    (why,) = bodies["ended_why"]
    assert isinstance(why, EndedWhyMsg) and why.why.startswith("2 frontier cells")
    status, no_odometry = bodies["episode_status"]
    assert isinstance(status, EpisodeStatusMsg) and status.map_origin.as_list() == [1.0, -2.0, 0.5]
    assert status.pose is not None and status.twist is not None and status.pose.as_list() == [0.5, -0.25, 3.0]  # scene's frame
    assert (status.twist.linear_mps, status.twist.angular_radps) == (0.2, -0.5)
    assert isinstance(no_odometry, EpisodeStatusMsg) and (no_odometry.pose, no_odometry.twist) == (None, None)
    assert (status.coverage_measured, no_odometry.coverage_measured) == (True, False)
    (result,) = bodies["episode_result"]
    assert isinstance(result, EpisodeResultMsg) and result.final_map is not None and result.final_map.step == 40 and result.seed == -3
    assert result.episode == EPISODE
    (service,) = bodies["service_status"]
    assert isinstance(service, ServiceStatusMsg) and (service.rejected, service.counters) == ({"frontiers": 1}, {"decisions": 2})
    _, launcher = bodies["launcher_status"]
    assert isinstance(launcher, LauncherStatusMsg) and launcher.pause is not None and launcher.pause["paused"] and launcher.run_dir_lost == 1 and launcher.referee == "own"
    assert launcher.lost_results == [{"episode": EPISODE, "state": "done", "step": 31, "running": EPISODE + 1}]
    (resume,) = bodies["explore_resume"]
    assert isinstance(resume, ExploreResumeMsg) and not resume.resume


def test_arrays_may_come_in_any_of_the_three_codings_and_any_documented_dtype():
    """A sender picks ``z`` (the project compresses arrays of 4096 bytes or more, and bit-packs the boolean grids the docs
    name): a receiver reads all three, and an integer count in any documented integer dtype."""
    base = decision_body()
    mask = ENTROPY != 0
    for z in (False, True):
        body = {**base, "masks": {"entropy": record(mask, "bool", z)}}
        body["arrays"] = {k: record(read_record(v), v["dtype"], z) if v["z"] == "bits" else v for k, v in base["arrays"].items()}
        for dtype in ("uint8", "uint16", "int8", "int16", "int32", "int64"):
            body["arrays"]["entropy"] = record(ENTROPY[mask], dtype, z)
            if dtype == "int8":
                body["arrays"]["entropy"] = record(np.minimum(ENTROPY[mask], 127), dtype, z)
            msg = decode(envelope("frontiers", FrontiersMsg.VERSION, body), FrontiersMsg)
            assert (msg.arrays["explored"] == EXPLORED).all() and (msg.arrays["entropy"] != 0).sum() == 4
    dist = BODIES["distance_map"][0]
    for z in (True, False):
        assert np.array_equal(decode(envelope("distance_map", 2, {**dist, "distance_m": record(DISTANCE[np.isfinite(DISTANCE)], "float64", z)}), DistanceMapMsg).distance_m, DISTANCE)


FLOAT_FIELDS = [
    # (schema, index in BODIES, field, the dtype the project sends and computes in, the decoded array)
    ("scan", 0, "ranges_m", np.float32, lambda m: m.scan.ranges_m),
    ("path", 0, "path_xy_m", np.float32, lambda m: m.path_xy_m),
    ("planner_feedback", 0, "path_ahead_xy_m", np.float64, lambda m: m.path_ahead_xy_m),
    ("planner_contacts", 0, "contacts_xy_m", np.float64, lambda m: m.contacts_xy_m),
    ("planner_plan", 0, "path_xy_m", np.float64, lambda m: m.path_xy_m),
    ("frontiers", 1, "path_nodes_xy_m", np.float64, lambda m: m.path_nodes_xy_m),
    ("frontiers", 1, "path_nodes_distance_m", np.float64, lambda m: m.path_nodes_distance_m),
    ("distance_map", 0, "distance_m", np.float64, lambda m: m.distance_m[np.isfinite(m.distance_m)]),
    ("episode_result", 0, "trajectory_xy_m", np.float64, lambda m: m.trajectory_xy_m),
    ("episode_result", 0, "decision_ms", np.float64, lambda m: m.decision_ms),
    ("episode_result", 0, "coverage_curve_pct", np.float64, lambda m: m.coverage_curve_pct),
]


@pytest.mark.parametrize(("schema", "index", "path", "computes_in", "decoded"), FLOAT_FIELDS, ids=[f"{s}.{p}" for s, _, p, _, _ in FLOAT_FIELDS])
def test_a_float_array_may_come_in_float32_or_float64_and_is_read_in_the_dtype_the_code_computes_in(schema, index, path, computes_in, decoded):
    """One rule for every float array (docs: "Arrays"): a node written to the old spec ("any dtype of the list") that
    sends its path nodes as float32 had every decision refused once the decoders named one float dtype. Either float
    is read, converted to the dtype the code computes in, equal within float32's precision; a bool or an integer is
    never read as metres."""
    body = BODIES[schema][index]
    sent = read_record(body[path])
    for dtype in ("float32", "float64"):
        msg = decode(envelope(schema, MESSAGE_TYPES[schema].VERSION, changed(body, path, record(sent, dtype))))
        got = decoded(msg)
        assert got.dtype == computes_in and got.shape == sent.shape
        np.testing.assert_allclose(got, sent.astype(dtype), rtol=1e-7 if dtype == "float32" else 0)
        np.testing.assert_allclose(got, sent, rtol=1e-6)
    for dtype in ("bool", "int8", "int32", "int64", "uint8", "uint16"):
        assert rejected(schema, changed(body, path, record(sent != 0 if dtype == "bool" else np.zeros(sent.shape), dtype)))


def test_a_float64_beyond_float32s_range_is_refused_where_a_finite_float32_is_computed_with():
    """The path is computed in float32: a finite float64 of 1e300 would become inf there, where only finite metres are
    read."""
    body = BODIES["path"][0]
    assert not rejected("path", changed(body, "path_xy_m", record(np.array([[0.0, 3.0e38]]), "float64")))
    assert rejected("path", changed(body, "path_xy_m", record(np.array([[0.0, 1e300]]), "float64")))


def test_a_bit_packed_grids_padding_is_ignored_and_its_length_is_exact():
    """``ceil(n / 8)`` packed bytes: what is in the last byte's unused bits does not matter, a byte more or less is rejected."""
    body = map_body()
    n = EXPLORED.size  # 20 cells: 3 bytes, 4 bits of padding
    padded = bytearray(bits_of(EXPLORED))
    padded[-1] |= 0xF0
    assert (decode(envelope("map", 3, {**body, "explored": {**body["explored"], "data": zlib.compress(bytes(padded))}}), MapMsg).explored == EXPLORED).all()
    for wrong in (bits_of(EXPLORED) + b"\0", bits_of(EXPLORED)[: (n + 7) // 8 - 1]):
        with pytest.raises(MessageError, match="packed bytes"):
            decode(envelope("map", 3, {**body, "explored": {**body["explored"], "data": zlib.compress(wrong)}}), MapMsg)


@pytest.mark.parametrize("z", [True, "bits"])
def test_compressed_data_is_one_whole_zlib_stream_and_nothing_after_it(z: bool | str):
    """The docs' ``z``: the bytes as a zlib stream, as zlib's ``compress`` writes it: bytes after its end, or a stream cut
    before its end (its Adler-32 checksum, or more), are rejected, though the bytes inflated so far fit the shape."""
    body = map_body() if z == "bits" else BODIES["path"][0]
    field, schema = ("explored", "map") if z == "bits" else ("path_xy_m", "path")
    rec = record(EXPLORED, "bool", "bits") if z == "bits" else record(np.array([[0.0, -0.1], [-0.05, -0.05]]), "float32", True)
    assert not rejected(schema, {**body, field: rec})
    for data, said in ((rec["data"] + b"\0", "1 bytes after the compressed data"), (rec["data"] + zlib.compress(b""), "bytes after"), (rec["data"][:-4], "truncated"), (rec["data"][:-1], "truncated")):
        with pytest.raises(MessageError, match=said):
            decode(envelope(schema, MESSAGE_TYPES[schema].VERSION, {**body, field: {**rec, "data": data}}), MESSAGE_TYPES[schema])


def rejected(schema: str, body: Any, version: int | None = None, **envelope_extra: Any) -> bool:
    v = MESSAGE_TYPES[schema].VERSION if version is None else version
    payload = msgpack.packb({"schema": schema, "v": v, "body": body, **envelope_extra}, use_bin_type=True)
    try:
        decode(payload, MESSAGE_TYPES[schema])
    except MessageError:
        return True
    return False


def changed(body: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``body`` with the field at the dotted ``path`` set to ``value`` (deleted when ``value`` is ``DELETE``)."""
    head, _, rest = path.partition(".")
    out = dict(body)
    if rest:
        out[head] = changed(body[head], rest, value)
    elif value is DELETE:
        del out[head]
    else:
        out[head] = value
    return out


DELETE = object()


@pytest.mark.parametrize(
    ("schema", "index", "path", "value"),
    [
        # the envelope's rules are tested below; a body's: a missing field, an integer sent as a float, NaN, inf
        ("odom", 0, "step", DELETE),
        ("odom", 0, "step", 3.0),
        ("odom", 0, "step", -1),
        ("odom", 0, "stamp_s", math.nan),
        ("odom", 0, "pose", [math.inf, 0.0, 0.0]),
        ("odom", 0, "pose", [0.0, 0.0, 11.0]),  # yaw beyond +-10 rad
        ("cmd_vel", 0, "linear_mps", 101.0),
        ("cmd_vel", 0, "new_goal", 1),  # a boolean is msgpack true/false, not 1
        ("scan", 0, "ranges_m", record(np.array([1.0, math.nan]), "float32")),  # NaN: no return is inf, not NaN
        ("scan", 0, "ranges_m", record(np.array([1.0, -1.0]), "float32")),
        ("scan", 0, "angle_increment_rad", -0.5),  # beams go counter-clockwise
        ("scan", 0, "range_min_m", 8.0),  # range_min_m < range_max_m
        ("map", 0, "occupied", record(~EXPLORED, "bool", "bits")),  # only explored cells can be occupied
        ("map", 0, "explored", record(EXPLORED[:, :4], "bool", "bits")),  # the geometry's shape
        ("map", 0, "explored", record(EXPLORED, "uint8", True)),  # a grid's dtype is bool
        ("map", 0, "explored", {**record(EXPLORED, "bool", "bits"), "data": "text"}),  # data is msgpack bin, not str
        ("map", 0, "explored", {**record(EXPLORED, "bool", "bits"), "extra": 1}),  # a record has exactly its four fields
        ("map", 0, "explored", {**record(EXPLORED, "bool", "bits"), "data": zlib.compress(bits_of(EXPLORED), wbits=-15)}),  # raw deflate
        ("map", 0, "explored", {**record(EXPLORED, "bool", "bits"), "data": zlib.compress(bits_of(EXPLORED), wbits=31)}),  # gzip
        ("map", 0, "geometry.shape", [4, 0]),
        ("map", 0, "geometry.resolution_m", 0.0),
        ("path", 0, "path_xy_m", record(np.zeros((2, 2)), "uint32")),  # not a documented dtype
        ("path", 0, "path_xy_m", record(np.zeros((2, 3)), "float32")),
        ("path", 0, "path_xy_m", record(np.array([[0.0, math.inf]]), "float32")),  # inf only where it means no return or unreachable
        ("distance_map", 0, "distance_m", record(np.full(int(np.isfinite(DISTANCE).sum()), math.inf), "float64")),  # the finite values only
        ("distance_map", 0, "distance_m", record(DISTANCE[np.isfinite(DISTANCE)], "int64")),  # a float
        ("distance_map", 0, "distance_m", record(DISTANCE[np.isfinite(DISTANCE)][:-1], "float64")),  # one value per set cell
        ("frontiers", 1, "clusters", [{**decision_body()["clusters"][0], "extra": 1}]),  # a cluster has exactly its fields
        ("frontiers", 1, "arrays.entropy", record(np.array([3, 7, 250, 1]), "float64")),  # counts are integers
        ("frontiers", 1, "arrays.extra", record(EXPLORED, "bool", "bits")),  # arrays has exactly its five grids
        ("frontiers", 1, "path_nodes_distance_m", record(np.array([0.0, -1.0]), "float64")),
        # a float array (metres, ms, percent) in float32 or float64, never an integer or bool; the grids in the dtype the
        # table names; entropy counts an integer of the list, at most 2^31 - 1; a cluster's cells a signed integer
        ("path", 0, "path_xy_m", record(np.zeros((2, 2)), "int64")),
        ("path", 0, "path_xy_m", record(np.zeros((2, 2)), "bool")),
        ("frontiers", 1, "path_nodes_xy_m", record(np.array([[0, -1], [1, 0]]), "int32")),
        ("frontiers", 1, "path_nodes_distance_m", record(np.array([True, False]), "bool")),
        ("scan", 0, "ranges_m", record(np.array([1, 2, 3]), "uint16")),
        ("planner_feedback", 0, "path_ahead_xy_m", record(np.zeros((2, 2)), "int16")),
        ("planner_contacts", 0, "contacts_xy_m", record(np.ones((2, 2)), "bool")),
        ("frontiers", 1, "clusters", [{**decision_body()["clusters"][0], "cells": record(np.array([[0, 2], [2, 1]]), "uint8")}]),
        ("frontiers", 1, "arrays.entropy", record(np.array([3, 7, 2**31, 1]), "int64")),  # wrapped to -2^31 in the int32 grid
        ("episode_result", 0, "trajectory_xy_m", record(np.array([[0, -1], [1, 0]]), "int64")),
        ("episode_result", 0, "decision_ms", record(np.array([True, False]), "bool")),
        ("episode_result", 0, "coverage_curve_pct", record(np.array([10.0, 99.5]), "int64")),
        ("episode_result", 0, "explored_free", record(EXPLORED & ~OCCUPIED, "uint8", True)),
        ("episode_result", 0, "decision_ms", record(np.array([-4.5, 1.0]), "float64")),  # a time is >= 0
        ("episode_result", 0, "coverage_curve_pct", record(np.array([-1.0, 99.5]), "float64")),
        # one byte per bool, 0 or 1: numpy keeps a 2 as a true whose ~ is true too (an unexplored cell seen as explored)
        ("map", 0, "explored", {**record(EXPLORED, "bool"), "data": (EXPLORED.astype(np.uint8) * 2).tobytes()}),
        ("goal", 0, "goal", [1.0, 2.0, 0]),
        ("planner_feedback", 0, "status", "lost"),
        ("planner_state", 0, "status", "stale"),  # the service's, never its follower's
        ("planner_plan", 0, "free.traversable", record(EXPLORED[:3], "bool", "bits")),  # on the plan's geometry
        ("episode_status", 0, "state", "paused"),
        ("episode_status", 0, "pose", DELETE),  # nil while unknown, never absent
        ("episode_status", 0, "twist", DELETE),
        ("episode_status", 0, "pose", [0.5, math.nan, 3.0]),  # a pose as every pose: three finite numbers, yaw within +-10
        ("episode_status", 0, "pose", [0.5, -0.25]),
        ("episode_status", 0, "pose", [0.5, -0.25, 10.5]),
        ("episode_status", 0, "twist", [0.2, math.inf]),  # a twist as odom's: two finite numbers within +-100
        ("episode_status", 0, "twist", [0.2, -0.5, 0.0]),
        ("episode_status", 0, "twist", [-100.5, 0.0]),
        ("service_status", 0, "state", "idle"),
        ("service_status", 0, "counters", {"decisions": -1}),
    ],
)
def test_what_the_docs_say_a_receiver_rejects_is_rejected(schema: str, index: int, path: str, value: Any):
    body = BODIES[schema][index]
    assert not rejected(schema, body)
    assert rejected(schema, changed(body, path, value))


def test_the_envelope_is_exactly_schema_v_and_body_of_the_current_version():
    body = BODIES["odom"][0]
    assert not rejected("odom", body)
    assert rejected("odom", body, version=OdometryMsg.VERSION + 1)
    assert rejected("odom", body, version=1)  # an older version is for the offline tools only
    assert rejected("odom", body, version=True)
    assert rejected("odom", body, extra=1)
    with pytest.raises(MessageError, match="expected schema 'goal'"):
        decode(envelope("odom", OdometryMsg.VERSION, body), GoalMsg)  # another schema on a key
    single = msgpack.packb({"schema": "odom", "v": OdometryMsg.VERSION, "body": body}, use_bin_type=True, use_single_float=True)
    assert decode(single, OdometryMsg).pose.x_m == 0.875  # a number packed as a msgpack float32 is a number too
    # a body field the schema does not have is ignored (a newer sender's), an absent optional one is its default
    assert decode(envelope("odom", OdometryMsg.VERSION, {**body, "covariance": [1.0]}), OdometryMsg).step == 3
    result = {k: v for k, v in BODIES["episode_result"][0].items() if k not in ("ended_why", "episode")}  # an older referee's
    older = decode(envelope("episode_result", EpisodeResultMsg.VERSION, result), EpisodeResultMsg)
    assert (older.ended_why, older.episode) == ("", 0)
    assert "episode" not in read_payload(encode(older))[2]  # no id: sent as no field, the body an older reader got
    status = {k: v for k, v in BODIES["episode_status"][0].items() if k != "coverage_measured"}  # a referee that does not say
    assert decode(envelope("episode_status", EpisodeStatusMsg.VERSION, status), EpisodeStatusMsg).coverage_measured is None


def test_the_project_sends_the_documented_dtypes_and_bit_packed_grids():
    """Messages the services build (not re-encoded hand bodies), read by hand: the dtypes the docs' table names."""
    from tests.test_messages import _observation  # a real Observation

    obs = _observation()
    from cso_runtime.messages import frontiers_from_observation

    decision = read_payload(encode(frontiers_from_observation(5, "no_goal", obs, 2.0, EPISODE)))[2]
    arrays = {k: read_record(v) for k, v in decision["arrays"].items()}
    mask = read_record(decision["masks"]["entropy"])
    assert {k: decision["arrays"][k]["z"] for k in ("explored", "occupied", "traversable", "frontier")} == dict.fromkeys(("explored", "occupied", "traversable", "frontier"), "bits")
    assert decision["masks"]["entropy"]["z"] == "bits" and decision["arrays"]["entropy"]["dtype"] in ("uint8", "uint16", "int32")
    entropy = np.zeros(mask.shape, np.int64)
    entropy[mask] = arrays["entropy"]
    assert np.array_equal(entropy, obs.entropy) and np.array_equal(arrays["traversable"], obs.traversable)
    assert decision["path_nodes_distance_m"]["dtype"] == decision["path_nodes_xy_m"]["dtype"] == "float64"
    distance = read_payload(encode(DistanceMapMsg(5, obs.geometry, obs.pose, obs.distance_m, EPISODE)))[2]
    finite = read_record(distance["finite"])
    d = np.full(finite.shape, np.inf)
    d[finite] = read_record(distance["distance_m"])
    assert distance["distance_m"]["dtype"] == "float64" and np.array_equal(d, obs.distance_m)
    m = read_payload(encode(MapMsg.of(5, _map_of(obs), EPISODE)))[2]
    assert m["explored"]["z"] == m["occupied"]["z"] == "bits" and np.array_equal(read_record(m["explored"]), obs.explored)
    scan = read_payload(encode(ScanMsg(1, _scan_of(), obs.pose, EPISODE)))[2]
    assert scan["ranges_m"]["dtype"] == "float32" and scan["ranges_m"]["z"] is False
    path = read_payload(encode(PathMsg(1, np.zeros((3, 2)))))[2]
    assert path["path_xy_m"]["dtype"] == "float32" and read_record(path["path_xy_m"]).shape == (3, 2)
    feedback = read_payload(encode(PlannerFeedbackMsg(1, "idle", "command")))[2]
    assert feedback["path_ahead_xy_m"]["dtype"] == "float64" and read_record(feedback["path_ahead_xy_m"]).shape == (0, 2)


def _map_of(obs: Any) -> Any:
    from cso_runtime.occupancy import OccupancyMap

    return OccupancyMap.from_masks(obs.explored, obs.occupied & obs.explored, obs.geometry)


def _scan_of() -> Any:
    from cso_runtime.geometry import LaserScan

    return LaserScan(-1.5, 0.5, 0.1, 8.0, np.array([1.0, np.inf], np.float32), 0.25)


# --- the docs' table names every field ------------------------------------------------------------


def table_rows() -> dict[str, tuple[str, str]]:
    """Key suffix -> (schema, body cell) of the key table in docs/messages.md."""
    return {key: (cells[1].strip("`"), " | ".join(cells[4:])) for key, cells in docs_table().items()}


DYNAMIC_KEYS = {"rejected", "counters", "handler_errors", "services"}
"""Fields whose keys are names (topics, counters, services), not field names; their entries' fields are checked."""


def field_names(body: dict[str, Any]) -> set[str]:
    """Every field name of a body, nested ones too, but not those inside array records."""
    names: set[str] = set()
    for k, v in body.items():
        names.add(k)
        if is_record(v):
            continue
        if k in DYNAMIC_KEYS and isinstance(v, dict):
            for entry in v.values():
                if isinstance(entry, dict):
                    names |= field_names(entry)
        elif isinstance(v, dict) and k not in ("final_map", "geometry"):  # a map body, and the clock's geometry (its row)
            names |= field_names(v)
        elif isinstance(v, list):
            for item in v:
                if isinstance(item, dict):
                    names |= field_names(item)
    return names


@pytest.mark.parametrize("schema", sorted(MESSAGE_TYPES))
def test_the_docs_table_names_every_field_the_code_sends(schema: str):
    """Each field of each body (every field the code sends: ``BODIES`` re-encode to themselves) is in the docs' row of
    the schema's key: the top-level ones quoted as `name`, the nested ones by name."""
    rows = {s: cell for s, cell in reversed(list(table_rows().values()))}  # the first row of each schema
    assert schema in rows, f"docs/messages.md has no row with schema {schema}"
    cell = rows[schema]
    for body in BODIES[schema]:
        top = set(body)
        missing_top = {k for k in top if f"`{k}`" not in cell}
        missing_nested = {k for k in field_names(body) - top if not re.search(rf"\b{k}\b", cell)}
        assert not missing_top and not missing_nested, (schema, missing_top, missing_nested)


def test_the_docs_table_gives_each_key_the_schema_its_publishers_send():
    """tests/test_dataflow.py holds the table's publishers and subscribers to the services' declarations; this, its
    schema column, and the keys of the queryables and tokens that no service declares as an output."""
    from services import SERVICE_NAMES, service_class

    rows = table_rows()
    sent = {TOPICS[topic]: cls.SCHEMA for name in SERVICE_NAMES for topic, cls in service_class(name).outputs.items()}
    assert {key: rows[key][0] for key in sent} == sent
    keys = RobotKeys("r0")
    for key, schema, full in [
        ("service/<name>/status", "service_status", keys.service_status("<name>")),
        ("launcher/status", "launcher_status", keys.launcher_status),
        ("cache/map", "map", keys.cache("map")),
        ("cache/goal", "goal", keys.cache("goal")),
        ("cache/planner/contacts", "planner_contacts", keys.cache("planner_contacts")),
        ("cache/planner/plan", "planner_plan", keys.cache("planner_plan")),
        ("cache/planner/state", "planner_state", keys.cache("planner_state")),
        ("alive/<name>", "liveliness token", keys.alive("<name>")),
        ("alive/<name>/<incarnation>", "liveliness token", keys.alive_incarnation("<name>", "*").replace("*", "<incarnation>")),
    ]:
        assert rows[key][0] == schema and full == f"cso/r0/{key}", (key, rows[key][0], full)


# --- a node written from the docs alone, in a real run ---------------------------------------------

POLICY_NODE = Path(__file__).resolve().parent / "command_policy_example.py"
PLANNER_NODE = Path(__file__).resolve().parent / "command_planner_example.py"
FRONTIER_NODE = Path(__file__).resolve().parent / "command_frontier_example.py"


def test_the_example_policy_speaks_the_current_versions():
    """A schema's version bump left the example node rejecting every ``frontiers``: the run test then failed only after a
    minute of lockstep retries, saying no decision came. Here it fails at once, naming the schema."""
    from tests.command_policy_example import VERSIONS

    assert VERSIONS == {schema: MESSAGE_TYPES[schema].VERSION for schema in VERSIONS}


@contextlib.contextmanager
def foreign_node_run(tmp_path: Path, name: str, section: dict[str, Any], max_steps: int | None = None) -> Iterator[tuple[Path, Path]]:
    """A detached, recorded lockstep run of the small scene with the built-in service ``name`` replaced by the command
    node ``section``, steps of at least 0.1 s (time to ask for the status while the episode runs); yields (runs folder,
    run folder) and stops the run, leaving no process behind, whatever happened."""
    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    data["scene"], data["method"] = SCENE, "greedy-dist"
    data["services"][name] = section
    data["services"]["sim"]["min_step_period_s"] = 0.1
    data["supervision"] = {**(data.get("supervision") or {}), "stop_timeout_s": 1.0}
    if max_steps is not None:
        data["exploration"]["episode"]["max_steps"] = max_steps
    profile, runs = tmp_path / "foreign.yaml", tmp_path / "runs"
    profile.write_text(yaml.safe_dump(data))
    try:
        r = up_from_this_checkout("--profile", str(profile), "--detach", "--record", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr
        yield runs, Path(json.loads((runs / "current.json").read_text())["run_dir"])
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []


def node_status_row(tmp_path: Path, runs: Path, name: str, counter: str) -> dict[str, Any] | None:
    """``status --json``'s row of the node ``name`` once its own status answer counts ``counter``; None before."""
    r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
    row = json.loads(r.stdout)["services"].get(name) if r.returncode == 0 else None
    return row if row and row.get("counters", {}).get(counter) else None


def test_a_policy_written_from_the_docs_alone_stands_in_for_the_builtin_one_step_for_step(tmp_path: Path):
    """The lockstep profile on the small scene with its policy replaced by tests/command_policy_example.py (only Zenoh,
    msgpack and docs/messages.md): the episode is the in-process greedy-dist one step for step, and ``status`` shows
    the node's own status answer (its state and counts) besides its pid."""
    section = {"command": [sys.executable, str(POLICY_NODE)], "inputs": ["frontiers"], "outputs": ["goal"], "alive_token": True}
    with foreign_node_run(tmp_path, "policy", section) as (runs, run_dir):
        row = wait_for(lambda: node_status_row(tmp_path, runs, "policy", "decisions"), 60, "the node's first decision in its status")
        assert row["command"] and row["alive"] and row["state"] == "running" and row["processed"] >= 1, row
        wait_for(lambda: (run_dir / "summary.json").exists(), 90, "the episode's results")
    expected = in_process_result(SCENE)
    metrics = json.loads((run_dir / "summary.json").read_text())["methods"]["greedy-dist"]
    assert metrics["steps"] == expected.steps and metrics["terminated_by"] == {expected.terminated_by: 1}, metrics
    log = (run_dir / "logs" / "policy.log").read_text()
    assert "policy: deciding for cso/r0" in log and "policy: stopped" in log, log
    # What a strict receiver gets on the wire: every payload of the run decodes by hand, its integer fields (steps,
    # counts, indices, ids, shapes) msgpack integers and every other number a msgpack float (the docs: float64 is sent).
    from cso_runtime.recording import read_recording

    schemas = set()
    for recorded in read_recording(run_dir / "recording.mcap"):
        schema, version, body = read_payload(recorded.payload)
        assert version == MESSAGE_TYPES[schema].VERSION
        schemas.add(schema)
        for path, value in numbers_of(body):
            assert isinstance(value, int) == (path.rsplit(".", 1)[-1] in INTEGER_FIELDS), (schema, path, value)
    assert {"scan", "odom", "clock", "map", "frontiers", "distance_map", "goal", "cmd_vel", "planner_feedback", "path"} <= schemas


@pytest.mark.parametrize("node", [PLANNER_NODE, FRONTIER_NODE])
def test_the_example_nodes_speak_the_current_versions(node: Path):
    versions = __import__(f"tests.{node.stem}", fromlist=["VERSIONS"]).VERSIONS
    assert versions == {schema: MESSAGE_TYPES[schema].VERSION for schema in versions}


def recorded_messages(run_dir: Path) -> dict[str, list[Any]]:
    """Every message of a run's recording, decoded (strictly, as the services do), by schema in the order recorded."""
    from cso_runtime.messages import decode
    from cso_runtime.recording import read_recording

    by_schema: dict[str, list[Any]] = {}
    for recorded in read_recording(run_dir / "recording.mcap"):
        by_schema.setdefault(read_payload(recorded.payload)[0], []).append(decode(recorded.payload))
    return by_schema


FOREIGN_PLANNER = {"command": [sys.executable, str(PLANNER_NODE)], "inputs": ["odom", "frontiers", "goal"], "outputs": ["cmd_vel", "planner_feedback"], "alive_token": True}
FOREIGN_FRONTIER = {
    "command": [sys.executable, str(FRONTIER_NODE)],
    "inputs": ["map", "odom", "planner_feedback", "goal"],
    "outputs": ["frontiers", "ended_why"],
    "alive_token": True,
}


@pytest.mark.parametrize(("name", "section", "counter"), [("planner", FOREIGN_PLANNER, "commands"), ("frontier", FOREIGN_FRONTIER, None)])
def test_a_planner_or_frontier_service_written_from_the_docs_alone_runs_a_lockstep_episode_to_its_end(tmp_path: Path, name: str, section: dict, counter: str | None):
    """The lockstep profile with its planner, or its frontier service, replaced by a command node written from the docs'
    handshake alone (Zenoh, msgpack, numpy; docs/own-service.md, What each one must publish, and when): the planner's a
    ``cmd_vel`` then a ``planner/feedback`` of each step, once its odometry, frontiers and, on a decision step, goal are
    in; the frontier service's one ``frontiers`` of each step once its map, odometry and the planner's report on the
    step before are in, waiting for a decision's goal. Step 0 waits for the node's token; the episode runs to its end
    with the built-in services on the node's messages, without one lockstep re-publication (a step that waited for
    what the node did not send); ``status`` shows the node (with its own status answer, the planner's)."""
    max_steps = 60
    with foreign_node_run(tmp_path, name, section, max_steps=max_steps) as (runs, run_dir):
        if counter is not None:
            row = wait_for(lambda: node_status_row(tmp_path, runs, name, counter), 60, "the node's first steps in its status")
            assert row["command"] and row["alive"] and row["state"] == "running" and row["processed"] >= 1, row
        wait_for(lambda: (run_dir / "summary.json").exists(), 90, "the episode's results")
    log = (run_dir / "logs" / f"{name}.log").read_text()
    assert f"{name}: stopped" in log, log
    metrics = json.loads((run_dir / "summary.json").read_text())["methods"]["greedy-dist"]
    by_schema = recorded_messages(run_dir)  # what the node sent decodes
    (result,) = by_schema["episode_result"]
    assert result.terminated_by in ("max_steps", "coverage", "no_frontier") and 0 < result.steps <= max_steps, result
    assert metrics["steps"] == result.steps and result.path_length_m > 0.5, metrics  # the robot explored
    steps = set(range(result.steps))
    assert steps <= {m.step for m in by_schema["cmd_vel"]} and steps <= {m.step for m in by_schema["frontiers"]}
    assert steps <= {m.step for m in by_schema["planner_feedback"] if m.phase == "command"}
    decided = {m.step for m in by_schema["frontiers"] if m.decide}  # decided again on the planner's reports
    assert len(decided) >= 2 and result.decisions >= 2 and decided == {m.step for m in by_schema["goal"]}, (decided, result.decisions)
    assert {m.step for m in by_schema["cmd_vel"] if m.new_goal} == decided & set(range(result.steps + 1))
    (last,) = [s for s in by_schema["episode_status"] if s.state == "done"][-1:]
    assert last.lockstep_timeouts == 0, last  # no step needed the sim's re-publication: the handshake is complete


INTEGER_FIELDS = {
    "step", "episode", "decisions", "lockstep_timeouts", "goal_step", "steps", "seed", "goal_cell", "shape", "goal[2]",
    "plan_step", "progress_index", "stalled_periods", "backing_up", "backups", "recoveries_left", "escape_periods", "escapes",
}  # fmt: skip
"""The integer fields of the bodies a run publishes (by their last name; ``goal[2]``: a goal's cluster index)."""


def numbers_of(value: Any, path: str = "") -> list[tuple[str, int | float]]:
    """(path, number) of every number of a body outside its array records; a list's items are named as the list
    (``.geometry.shape``, ``.clusters.goal_cell``, a pose), but a goal's by their place (``.goal[2]``: its cluster index)."""
    if is_record(value):
        return []
    if isinstance(value, dict):
        return [n for k, v in value.items() for n in numbers_of(v, f"{path}.{k}")]
    if isinstance(value, list):
        return [n for i, v in enumerate(value) for n in numbers_of(v, f"{path}[{i}]" if path.endswith(".goal") else path)]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [(path, value)]
    return []


def test_a_planner_state_or_plan_of_an_older_planner_still_decodes():
    """``stall.backup_from``, ``recovery.started_s`` and ``free.explored`` are optional: an older planner counted its
    back-up in periods to go (``backing_up``) and sent none of them. Its running back-up and escape go on as if
    started at its last period (``stall.last``); its plan checks no unknown cells behind the robot."""
    old = copy.deepcopy(BODIES["planner_state"][0])
    del old["stall"]["backup_from"], old["recovery"]["started_s"]
    old["stall"]["backing_up"] = 3
    follow = decode(envelope("planner_state", PlannerStateMsg.VERSION, old), PlannerStateMsg).follow
    assert follow.backing_up == (Pose2D(0.0, -0.1, 1.5), 3.5) and follow.escape_started_s == 3.5
    old["stall"]["backing_up"] = 0
    assert decode(envelope("planner_state", PlannerStateMsg.VERSION, old), PlannerStateMsg).follow.backing_up is None
    plan = copy.deepcopy(BODIES["planner_plan"][0])
    del plan["free"]["explored"]
    free = decode(envelope("planner_plan", PlannerPlanMsg.VERSION, plan), PlannerPlanMsg).free
    assert free is not None and free.explored is None and free.occupied is not None


def test_a_planner_states_backing_up_is_checked_and_says_whether_a_back_up_runs_beside_its_backup_from():
    """``stall.backing_up`` is a required count whatever else the state carries: with ``backup_from`` beside it, a float,
    a string, nil or no ``backing_up`` at all is rejected as without it, and 0 (no back-up runs) is not read as a
    running back-up from ``backup_from``."""
    for bad in (2.5, "1", None, ...):
        body = copy.deepcopy(BODIES["planner_state"][0])
        if bad is ...:
            del body["stall"]["backing_up"]
        else:
            body["stall"]["backing_up"] = bad
        with pytest.raises(MessageError, match="backing_up"):
            decode(envelope("planner_state", PlannerStateMsg.VERSION, body), PlannerStateMsg)
    body = copy.deepcopy(BODIES["planner_state"][0])
    body["stall"]["backing_up"] = 0
    assert decode(envelope("planner_state", PlannerStateMsg.VERSION, body), PlannerStateMsg).follow.backing_up is None
