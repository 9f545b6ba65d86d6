#!/usr/bin/env python3
"""A policy in place of the built-in one, written as a node in another language would be (docs/own-service.md, In
place of a built-in service, as a command node): nothing of cso-runtime, only the Zenoh binding, msgpack and
docs/messages.md. A profile runs it as ``services.policy: {command: [python3, tests/command_policy_example.py], inputs:
[frontiers], outputs: [goal], alive_token: true}``. It answers each decision (``frontiers`` with ``decide: true``) with
the nearest frontier cluster, as ``greedy-dist`` does, answers a step sent again (a lockstep retry) again, and answers
its status queryable with a ``service_status``, so ``status`` shows its state and counts."""

import os
import signal
import threading
import time

import msgpack
import zenoh

VERSIONS = {"frontiers": 7, "goal": 2, "service_status": 2}
"""The versions this node speaks (docs/messages.md): a payload of another version is rejected, and counted."""


def envelope(schema: str, body: dict) -> bytes:
    """A payload: the msgpack map {schema, v, body} (strings as msgpack str, bytes as bin)."""
    return msgpack.packb({"schema": schema, "v": VERSIONS[schema], "body": body}, use_bin_type=True)


def nearest_goal(frontiers: dict) -> dict:
    """The ``goal`` body answering a decision: its nearest cluster (the frontier service sends the reachable clusters
    only, nearest first), or none (null: nothing left to explore, the episode ends ``no_frontier``)."""
    t0 = time.perf_counter()
    clusters = frontiers["clusters"]
    goal = None if not clusters else [clusters[0]["goal_xy_m"][0], clusters[0]["goal_xy_m"][1], 0, clusters[0]["distance_m"]]
    return {
        "step": frontiers["step"],  # the decision's step and episode: what the planner and the sim wait for
        "decided": True,
        "goal": goal,  # [x_m, y_m, cluster_index, distance_m]
        "decision_ms": frontiers["build_ms"] + (time.perf_counter() - t0) * 1e3,
        "method": "greedy-dist",
        "reason": frontiers["reason"],
        "episode": frontiers["episode"],
    }


def serve(stop: threading.Event) -> None:
    prefix, name = os.environ["CSO_KEY_PREFIX"], os.environ["CSO_NODE_NAME"]
    lock = threading.Lock()
    counts = {"processed": 0, "last_step": 0, "decisions": 0, "rejected": 0}
    with zenoh.open(zenoh.Config.from_env()) as session:
        goals = session.declare_publisher(f"{prefix}/goal")

        def on_frontiers(sample: zenoh.Sample) -> None:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            if not isinstance(msg, dict) or msg.get("schema") != "frontiers" or msg.get("v") != VERSIONS["frontiers"]:
                with lock:
                    counts["rejected"] += 1
                return
            body = msg["body"]
            with lock:
                counts["processed"] += 1
                counts["last_step"] = body["step"]
            if body["decide"]:  # decide: false keeps the current goal, and is not answered
                goals.put(envelope("goal", nearest_goal(body)))
                with lock:
                    counts["decisions"] += 1

        def on_status(query: zenoh.Query) -> None:
            with lock:
                body = {
                    "service": name,
                    "robot": os.environ["CSO_ROBOT"],
                    "state": "running",
                    "last_step": counts["last_step"],
                    "reason": "",
                    "rejected": {"frontiers": counts["rejected"]} if counts["rejected"] else {},
                    "processed": counts["processed"],
                    "counters": {"decisions": counts["decisions"]},
                }
            query.reply(f"{prefix}/service/{name}/status", envelope("service_status", body))

        subscriber = session.declare_subscriber(f"{prefix}/frontiers", on_frontiers)
        status = session.declare_queryable(f"{prefix}/service/{name}/status", on_status)
        token = session.liveliness().declare_token(os.environ["CSO_ALIVE_KEY"])  # ready: step 0 may start
        print(f"{name}: deciding for {prefix}", flush=True)
        stop.wait()
        token.undeclare()
        status.undeclare()
        subscriber.undeclare()
        goals.undeclare()


def main() -> int:
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    serve(stop)
    print(f"{os.environ['CSO_NODE_NAME']}: stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
