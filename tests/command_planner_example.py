#!/usr/bin/env python3
"""A planner in place of the built-in one, written as a node in another language would be (docs/own-service.md, What
each one must publish, and when): nothing of cso-runtime, only the Zenoh binding, msgpack and docs/messages.md. A
profile runs it as ``services.planner: {command: [python3, tests/command_planner_example.py], inputs: [odom, frontiers,
goal], outputs: [cmd_vel, planner_feedback], alive_token: true}``.

Its lockstep handshake: for step k, once the step's ``odom`` and ``frontiers`` (and, when they decide, the step's
``goal``) are in, one ``cmd_vel`` of step k (``new_goal`` true when it follows the goal decided at k), then one
``planner/feedback`` of step k with ``phase: command``, which the frontier service decides step k + 1 on. Inputs of a
step it has answered, coming again (the sim's re-publication), are answered again; step k's odometry coming again
before step k is answered brings step k - 1's feedback again. Its driving is the simplest there is: turn towards the
goal, drive when facing it, report ``reached`` within ``REACHED_M`` and ``no_progress`` when it has come no closer
for ``PATIENCE_STEPS`` (the frontier service then decides again)."""

import math
import os
import signal
import threading

import msgpack
import numpy as np
import zenoh

VERSIONS = {"odom": 2, "frontiers": 7, "goal": 2, "cmd_vel": 3, "planner_feedback": 3, "service_status": 2}
"""The versions this node speaks (docs/messages.md): a payload of another version is rejected, and counted."""
REACHED_M = 0.3
PATIENCE_STEPS = 12
MAX_LINEAR_MPS = 0.3
MAX_ANGULAR_RADPS = 1.0


def envelope(schema: str, body: dict) -> bytes:
    """A payload: the msgpack map {schema, v, body} (strings as msgpack str, bytes as bin)."""
    return msgpack.packb({"schema": schema, "v": VERSIONS[schema], "body": body}, use_bin_type=True)


def no_path() -> dict:
    """An empty path ahead: an array record of float64, shape (0, 2), raw (docs/messages.md, arrays)."""
    return {"dtype": "float64", "shape": [0, 2], "z": False, "data": b""}


class Planner:
    """The planner's state in one episode, and its answer to each step."""

    def __init__(self, episode: int) -> None:
        self.episode = episode
        self.odoms: dict[int, dict] = {}
        self.frontiers: dict[int, dict] = {}
        self.goals: dict[int, dict] = {}
        self.answered: dict[int, tuple[bytes, bytes]] = {}  # step -> (cmd_vel, planner_feedback) payloads
        self.goal_xy: tuple[float, float] | None = None
        self.goal_step = -1
        self.best_m = math.inf
        self.since_best = 0

    def drive(self, pose: list) -> tuple[float, float, str, str]:
        """(linear_mps, angular_radps, cmd_vel reason, feedback status) from the pose towards the goal."""
        if self.goal_xy is None:
            return 0.0, 0.0, "no_goal", "idle"
        dx, dy = self.goal_xy[0] - pose[0], self.goal_xy[1] - pose[1]
        dist = math.hypot(dx, dy)
        if dist < REACHED_M:
            return 0.0, 0.0, "reached", "reached"
        if dist < self.best_m - 0.05:
            self.best_m, self.since_best = dist, 0
        else:
            self.since_best += 1
        if self.since_best > PATIENCE_STEPS:
            return 0.0, 0.0, "no_progress", "no_progress"
        err = math.atan2(math.sin(math.atan2(dy, dx) - pose[2]), math.cos(math.atan2(dy, dx) - pose[2]))
        linear = MAX_LINEAR_MPS * max(0.0, math.cos(err)) if abs(err) < 0.8 else 0.0
        return linear, float(np.clip(1.5 * err, -MAX_ANGULAR_RADPS, MAX_ANGULAR_RADPS)), "", "following"

    def answer(self) -> list[bytes]:
        """The payloads of every step whose inputs are all in, in step order (lockstep: one step at a time)."""
        out = []
        for k in sorted(set(self.odoms) & set(self.frontiers)):
            if k in self.answered:
                continue
            decide = self.frontiers[k]["decide"]
            if decide and k not in self.goals:
                break  # the decision's goal is on its way
            if decide:
                goal = self.goals[k]["goal"]
                self.goal_xy = None if goal is None else (float(goal[0]), float(goal[1]))
                self.goal_step, self.best_m, self.since_best = k, math.inf, 0
            linear, angular, reason, status = self.drive(self.odoms[k]["pose"])
            cmd = {"step": k, "linear_mps": linear, "angular_radps": angular, "reason": reason, "new_goal": bool(decide)}
            feedback = {
                "step": k, "episode": self.episode, "status": status, "phase": "command", "set_goal_blocked": False,
                "reason": reason, "path_ahead_xy_m": no_path(), "goal_step": self.goal_step,
            }
            self.answered[k] = (envelope("cmd_vel", cmd), envelope("planner_feedback", feedback))
            out.extend(self.answered[k])
            for d in (self.odoms, self.frontiers, self.goals, self.answered):
                for s in [s for s in d if s < k - 1]:
                    d.pop(s)
        return out


def serve(stop: threading.Event) -> None:
    prefix, name = os.environ["CSO_KEY_PREFIX"], os.environ["CSO_NODE_NAME"]
    lock = threading.Lock()
    counts = {"processed": 0, "last_step": 0, "commands": 0, "rejected": 0}
    state = {"planner": Planner(0)}
    ended: set[int] = set()
    with zenoh.open(zenoh.Config.from_env()) as session:
        cmd_pub = session.declare_publisher(f"{prefix}/cmd_vel")
        feedback_pub = session.declare_publisher(f"{prefix}/planner/feedback")

        def send(payloads: list[bytes]) -> None:
            for payload in payloads:
                (cmd_pub if msgpack.unpackb(payload, raw=False)["schema"] == "cmd_vel" else feedback_pub).put(payload)

        def on_input(sample: zenoh.Sample) -> None:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            schema = msg.get("schema") if isinstance(msg, dict) else None
            if schema not in ("odom", "frontiers", "goal") or msg.get("v") != VERSIONS[schema]:
                with lock:
                    counts["rejected"] += 1
                return
            body = msg["body"]
            with lock:
                counts["processed"] += 1
                planner, k = state["planner"], body["step"]
                if body["episode"] in ended:
                    return  # still in flight from an episode that has ended
                if body["episode"] != planner.episode:  # a new episode, on whichever key: start afresh
                    ended.add(planner.episode)
                    planner = state["planner"] = Planner(body["episode"])
                if k in planner.answered:  # sent again: answered again
                    send(list(planner.answered[k]))
                    return
                if schema == "odom" and k in planner.odoms and k - 1 in planner.answered:
                    send([planner.answered[k - 1][1]])  # the frontier service may have missed step k - 1's feedback
                {"odom": planner.odoms, "frontiers": planner.frontiers, "goal": planner.goals}[schema][k] = body
                out = planner.answer()
                counts["commands"] += len(out) // 2
                counts["last_step"] = max(planner.answered, default=counts["last_step"])
            send(out)

        def on_status(query: zenoh.Query) -> None:
            with lock:
                body = {
                    "service": name, "robot": os.environ["CSO_ROBOT"], "state": "running", "last_step": counts["last_step"],
                    "reason": "", "rejected": {"inputs": counts["rejected"]} if counts["rejected"] else {},
                    "processed": counts["processed"], "counters": {"commands": counts["commands"]},
                }
            query.reply(f"{prefix}/service/{name}/status", envelope("service_status", body))

        subscribers = [session.declare_subscriber(f"{prefix}/{key}", on_input) for key in ("odom", "frontiers", "goal")]
        status = session.declare_queryable(f"{prefix}/service/{name}/status", on_status)
        token = session.liveliness().declare_token(os.environ["CSO_ALIVE_KEY"])  # ready: step 0 may start
        print(f"{name}: commanding {prefix}", flush=True)
        stop.wait()
        token.undeclare()
        status.undeclare()
        for subscriber in subscribers:
            subscriber.undeclare()
        feedback_pub.undeclare()
        cmd_pub.undeclare()


def main() -> int:
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    serve(stop)
    print(f"{os.environ['CSO_NODE_NAME']}: stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
