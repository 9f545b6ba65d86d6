#!/usr/bin/env python3
"""A frontier service in place of the built-in one, written as a node in another language would be (docs/own-service.md,
What each one must publish, and when): nothing of cso-runtime, only the Zenoh binding, msgpack, numpy and
docs/messages.md. A profile runs it as ``services.frontier: {command: [python3, tests/command_frontier_example.py],
inputs: [map, odom, planner_feedback, goal], outputs: [frontiers, ended_why], alive_token: true}``.

Its lockstep handshake: for step k, once the step's ``map`` and ``odom`` are in and, from step 1 on, the planner's
``planner/feedback`` of step k - 1: one ``frontiers`` of step k; after a decision (``decide: true``) it waits for that
decision's ``goal`` before it handles step k + 1, and when that goal is null it publishes ``frontiers/ended_why``. A map
of the step it has answered, coming again (the sim's re-publication), is answered again. It leaves out the optional
``frontiers/distance`` (the planner then computes D itself). Its decisions are the simplest there are: at step 0 and
whenever the planner's report is not ``following``; the grids from the map (obstacles inflated by ``RADIUS_M``), the
frontier cells' 8-connected clusters, their distances by a 4-connected breadth-first search from the robot (a
cluster's goal: its nearest cell at least ``MIN_GOAL_M`` away, that the planner does not find reached at once)."""

import math
import os
import signal
import threading
import time
import zlib
from collections import deque

import msgpack
import numpy as np
import zenoh

VERSIONS = {"map": 3, "odom": 2, "planner_feedback": 3, "goal": 2, "frontiers": 7, "ended_why": 1}
"""The versions this node speaks (docs/messages.md)."""
RADIUS_M = 0.2
WINDOW_M = 2.0
MIN_CLUSTER_CELLS = 3
MIN_GOAL_M = 0.5
"""Farther than the planner's `exploration.episode.goal_tolerance_m` (0.3 m): a goal within it is `reached` at once."""


def envelope(schema: str, body: dict) -> bytes:
    return msgpack.packb({"schema": schema, "v": VERSIONS[schema], "body": body}, use_bin_type=True)


def bits(grid: np.ndarray) -> dict:
    """A boolean grid as docs/messages.md's array record: cells packed 8 to a byte, least significant bit first, zlib."""
    return {"dtype": "bool", "shape": list(grid.shape), "z": "bits", "data": zlib.compress(np.packbits(grid, bitorder="little").tobytes())}


def raw(a: np.ndarray, dtype: str) -> dict:
    """An array record of little-endian ``dtype`` values, uncompressed."""
    a = np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<"))
    return {"dtype": dtype, "shape": list(a.shape), "z": False, "data": a.tobytes()}


def grid_of(record: dict) -> np.ndarray:
    """A boolean grid record read back (the mapper sends ``"bits"``; ``true`` and ``false`` read too)."""
    n = math.prod(record["shape"])
    if record["z"] == "bits":
        return np.unpackbits(np.frombuffer(zlib.decompress(record["data"]), np.uint8), count=n, bitorder="little").astype(bool).reshape(record["shape"])
    data = zlib.decompress(record["data"]) if record["z"] else record["data"]
    return np.frombuffer(data, np.uint8).astype(bool).reshape(record["shape"])


def dilate(mask: np.ndarray, r: int) -> np.ndarray:
    """``mask`` grown by a disc of ``r`` cells."""
    out = mask.copy()
    ny, nx = mask.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dy * dy + dx * dx <= r * r and (dy or dx):
                out[max(dy, 0) : ny + min(dy, 0), max(dx, 0) : nx + min(dx, 0)] |= mask[max(-dy, 0) : ny + min(-dy, 0), max(-dx, 0) : nx + min(-dx, 0)]
    return out


def bfs_m(free: np.ndarray, start: tuple[int, int], res_m: float) -> np.ndarray:
    """Distance (m, 4-connected steps) from ``start`` over ``free`` cells; inf where unreachable."""
    d = np.full(free.shape, np.inf)
    d[start] = 0.0
    todo = deque([start])
    while todo:
        y, x = todo.popleft()
        for ny, nx in ((y + 1, x), (y - 1, x), (y, x + 1), (y, x - 1)):
            if 0 <= ny < free.shape[0] and 0 <= nx < free.shape[1] and free[ny, nx] and d[ny, nx] == np.inf:
                d[ny, nx] = d[y, x] + res_m
                todo.append((ny, nx))
    return d


def components(cells: np.ndarray) -> list[list[tuple[int, int]]]:
    """The 8-connected groups of the set cells."""
    seen = np.zeros(cells.shape, bool)
    groups = []
    for start in zip(*np.nonzero(cells)):
        if seen[start]:
            continue
        seen[start] = True
        group, todo = [], [start]
        while todo:
            y, x = todo.pop()
            group.append((int(y), int(x)))
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ny, nx = y + dy, x + dx
                    if 0 <= ny < cells.shape[0] and 0 <= nx < cells.shape[1] and cells[ny, nx] and not seen[ny, nx]:
                        seen[ny, nx] = True
                        todo.append((ny, nx))
        groups.append(sorted(group))
    return groups


def decision(step: int, reason: str, episode: int, m: dict, pose: list, path_nodes: list) -> dict:
    """The ``frontiers`` body of a decision on map body ``m`` from ``pose``."""
    t0 = time.perf_counter()
    g = m["geometry"]
    res, (ox, oy) = g["resolution_m"], g["origin"]
    explored, occupied = grid_of(m["explored"]), grid_of(m["occupied"])
    open_cells = explored & ~occupied
    traversable = open_cells & ~dilate(occupied, math.ceil(RADIUS_M / res))
    unknown = np.pad(~explored, 1, constant_values=False)
    near_unknown = unknown[:-2, 1:-1] | unknown[2:, 1:-1] | unknown[1:-1, :-2] | unknown[1:-1, 2:]
    frontier = open_cells & near_unknown
    w = int(round(WINDOW_M / res)) // 2  # Eq. 4: frontier cells in the window around each cell (an integral image)
    s = np.pad(frontier.astype(np.int64), ((w + 1, w), (w + 1, w))).cumsum(0).cumsum(1)
    entropy = (s[2 * w + 1 :, 2 * w + 1 :] - s[: -2 * w - 1, 2 * w + 1 :] - s[2 * w + 1 :, : -2 * w - 1] + s[: -2 * w - 1, : -2 * w - 1]).astype(np.int32)
    ny, nx = explored.shape
    robot = (min(max(int((pose[1] - oy) // res), 0), ny - 1), min(max(int((pose[0] - ox) // res), 0), nx - 1))
    d = bfs_m(traversable, robot, res)
    clusters = []
    for cells in components(frontier):
        # traversable ones (the planner plans on that grid) farther than the planner's "reached"
        reachable = [c for c in cells if MIN_GOAL_M <= d[c] < np.inf]
        if len(cells) < MIN_CLUSTER_CELLS or not reachable:
            continue
        goal = min(reachable, key=lambda c: (d[c], c))
        centre = lambda c: [ox + (c[1] + 0.5) * res, oy + (c[0] + 0.5) * res]  # noqa: E731
        xy = np.array([centre(c) for c in cells])
        clusters.append(
            {
                "goal_cell": list(goal), "goal_xy_m": centre(goal), "distance_m": float(d[goal]), "size_m": len(cells) * res,
                "entropy": float(sum(int(entropy[c]) for c in cells)), "centroid_xy_m": xy.mean(axis=0).tolist(),
                "cells": raw(np.array(cells), "int32"),
            }
        )
    clusters.sort(key=lambda c: (c["distance_m"], c["goal_cell"]))  # nearest first: a goal's index is its place here
    nodes = np.array(path_nodes, dtype=float).reshape(-1, 2)
    node_cells = [(int((y - oy) // res), int((x - ox) // res)) for x, y in nodes]
    node_d = [float(d[c]) if 0 <= c[0] < ny and 0 <= c[1] < nx else math.inf for c in node_cells]
    mask = entropy != 0
    return {
        "step": step, "decide": True, "reason": reason, "episode": episode, "pose": pose, "geometry": g,
        "arrays": {"explored": bits(explored), "occupied": bits(occupied), "traversable": bits(traversable), "frontier": bits(frontier), "entropy": raw(entropy[mask], "int32")},
        "masks": {"entropy": bits(mask)},
        "clusters": clusters,
        "open_area_m2": float(open_cells.sum()) * res * res,
        "path_nodes_xy_m": raw(nodes, "float64"),
        "path_nodes_distance_m": raw(np.array(node_d), "float64"),
        "build_ms": (time.perf_counter() - t0) * 1e3,
    }


class Frontier:
    """The service's state in one episode."""

    def __init__(self, episode: int) -> None:
        self.episode = episode
        self.maps: dict[int, dict] = {}
        self.odoms: dict[int, dict] = {}
        self.feedback: dict[int, dict] = {}
        self.done_step = -1
        self.last_out: bytes | None = None
        self.awaiting: int | None = None  # the step of the decision whose goal has not come yet
        self.path_nodes: list[list[float]] = []

    def handle(self) -> list[tuple[str, bytes]]:
        """(key, payload) to publish: the next steps whose inputs are all in, in order."""
        out = []
        while self.awaiting is None:
            k = self.done_step + 1 if self.done_step >= 0 else min(set(self.maps) & set(self.odoms), default=None)
            if k is None or k not in self.maps or k not in self.odoms or (k > 0 and self.done_step >= 0 and k - 1 not in self.feedback):
                break
            fb = self.feedback.get(k - 1)
            status = "idle" if fb is None else fb["status"]
            pose = self.odoms[k]["pose"]
            if status == "following" and not fb["set_goal_blocked"]:
                body = {"step": k, "decide": False, "reason": "", "episode": self.episode}
            else:
                self.path_nodes.append(pose[:2])
                reason = {"idle": "no_goal", "stale": "blocked", "following": "blocked"}.get(status, status)
                body = decision(k, reason, self.episode, self.maps[k], pose, self.path_nodes)
                self.awaiting = k
            self.last_out, self.done_step = envelope("frontiers", body), k
            out.append(("frontiers", self.last_out))
            for d in (self.maps, self.odoms, self.feedback):
                for s in [s for s in d if s < k - 1]:
                    d.pop(s)
        return out


def serve(stop: threading.Event) -> None:
    prefix, name = os.environ["CSO_KEY_PREFIX"], os.environ["CSO_NODE_NAME"]
    lock = threading.Lock()
    state = {"frontier": Frontier(0)}
    ended: set[int] = set()
    with zenoh.open(zenoh.Config.from_env()) as session:
        publishers = {key: session.declare_publisher(f"{prefix}/{key}") for key in ("frontiers", "frontiers/ended_why")}

        def on_input(sample: zenoh.Sample) -> None:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            schema = msg.get("schema") if isinstance(msg, dict) else None
            if schema not in ("map", "odom", "planner_feedback", "goal") or msg.get("v") != VERSIONS[schema]:
                return
            body, out = msg["body"], []
            with lock:
                f, k = state["frontier"], body["step"]
                if body["episode"] in ended:
                    return  # still in flight from an episode that has ended
                if body["episode"] != f.episode:  # a new episode, on whichever key: start afresh
                    ended.add(f.episode)
                    f = state["frontier"] = Frontier(body["episode"])
                if schema == "goal":
                    if body["decided"] and k == f.awaiting:
                        f.awaiting = None
                        if body["goal"] is None:  # nothing left: the episode ends no_frontier, and the sim waits for why
                            why = {"step": k, "why": "no reachable frontier cluster left", "episode": f.episode}
                            out.append(("frontiers/ended_why", envelope("ended_why", why)))
                elif schema == "planner_feedback":
                    if body["phase"] == "command":
                        f.feedback[k] = body
                elif k <= f.done_step:
                    if schema == "map" and k == f.done_step and f.last_out is not None:
                        out.append(("frontiers", f.last_out))  # a lockstep retry: answered again
                else:
                    (f.maps if schema == "map" else f.odoms)[k] = body
                out.extend(f.handle())
            for key, payload in out:
                publishers[key].put(payload)

        subscribers = [session.declare_subscriber(f"{prefix}/{key}", on_input) for key in ("map", "odom", "planner/feedback", "goal")]
        token = session.liveliness().declare_token(os.environ["CSO_ALIVE_KEY"])  # ready: step 0 may start
        print(f"{name}: deciding on {prefix}/map", flush=True)
        stop.wait()
        token.undeclare()
        for subscriber in subscribers:
            subscriber.undeclare()
        for publisher in publishers.values():
            publisher.undeclare()


def main() -> int:
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    serve(stop)
    print(f"{os.environ['CSO_NODE_NAME']}: stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
