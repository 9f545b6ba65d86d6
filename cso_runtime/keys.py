"""Zenoh key expressions: everything of one robot lives under ``cso/<robot>/...``.

The table with schemas is in docs/messages.md. ``--robot ID`` changes only the ``<robot>`` part, so
several robots share one network, and a service may subscribe with the wildcard robot ``*``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

ROOT = "cso"
WILDCARD = "*"
_ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_INCARNATION = _ROBOT_ID
"""What a start's nonce may be (``RobotKeys.alive_incarnation``): one plain key chunk."""

class KeyExprError(ValueError):
    """A robot id or key expression is not valid."""


TOPICS = {
    "scan": "scan",
    "odom": "odom",
    "cmd_vel": "cmd_vel",
    "cmd_vel_ahead": "cmd_vel/ahead",
    "map": "map",
    "frontiers": "frontiers",
    "distance_map": "frontiers/distance",
    "ended_why": "frontiers/ended_why",
    "goal": "goal",
    "path": "path",
    "planner_feedback": "planner/feedback",
    "planner_contacts": "planner/contacts",
    "clock": "clock",
    "episode_status": "episode/status",
    "episode_result": "episode/result",
    "explore_resume": "explore/resume",
}
"""Topic name -> key suffix under ``cso/<robot>/``."""

CONTROL_TOPICS = ("explore_resume",)
"""Topics that are controls, not data of a step (an operator's pause or resume): a service's inbox, full under an
overload, drops its oldest data input and never one of these while data waits (``services.common.Inbox``)."""

_CONTROL_SUFFIXES = frozenset(TOPICS[name] for name in CONTROL_TOPICS)
_CONTROL_ENDINGS = tuple(f"/{suffix}" for suffix in _CONTROL_SUFFIXES)


def is_control_key(key_expr: str) -> bool:
    """Whether the concrete key ``cso/<robot>/<suffix>`` is of a control topic (``CONTROL_TOPICS``; not a topic of one's
    own that ends as one, ``ext/explore/resume``). Cheap enough for every input a service queues: a data key costs one
    ``endswith``."""
    if not key_expr.endswith(_CONTROL_ENDINGS):
        return False
    parts = key_expr.split("/", 2)
    return len(parts) == 3 and parts[0] == ROOT and parts[2] in _CONTROL_SUFFIXES

CARRIED = {"planner_plan": "planner/plan", "planner_state": "planner/state"}
"""What rides on another topic and has only a cache key (``cache/<suffix>``): the planner's plan and state, which its
``cmd_vel`` carries (``CmdVelMsg.planner_plan``, ``.planner_state``) so that the lockstep chain pays no message for them."""

PLANNER_KEPT = ("planner_contacts", *CARRIED)
"""What of the planner's the referee (sim or ros2_bridge) keeps the latest of and serves on ``cache/<...>``: what a
planner restarted mid-episode resumes from (``services/planner.py``, ``start``). Its contacts come on their own topic,
its plan and state on ``cmd_vel`` (``CARRIED``)."""

EXT = "ext"
EXT_TOPIC = re.compile(r"^ext(/[A-Za-z0-9_-]{1,64}){1,8}$")
"""A topic of one's own, ``ext/<name>[/<more>]`` (1 to 8 names of letters, digits, ``_`` or ``-``): its key is
``cso/<robot>/ext/<name>/...``, its payload any bytes, which the runtime neither decodes nor checks
(docs/own-service.md, Topics of your own)."""


def is_ext_topic(topic: object) -> bool:
    """Whether ``topic`` names a topic of one's own (``EXT_TOPIC``)."""
    return isinstance(topic, str) and EXT_TOPIC.match(topic) is not None


def topic_key(topic: str) -> str:
    """The key suffix under ``cso/<robot>/`` of ``topic``: the runtime's (``TOPICS``), or a topic of one's own, whose
    name is its key suffix; a KeyExprError for any other."""
    if topic in TOPICS:
        return TOPICS[topic]
    if is_ext_topic(topic):
        return topic
    raise KeyExprError(f"unknown topic {topic!r}: one of the runtime's ({', '.join(TOPICS)}) or one of your own, ext/<name>")


def check_robot_id(robot: str, allow_wildcard: bool = False) -> str:
    """``robot`` when it can stand in a key expression (``cso/<robot>/...``): 1-64 letters, digits, ``_`` or ``-``
    (or ``*`` with ``allow_wildcard``); a KeyExprError otherwise."""
    if allow_wildcard and robot == WILDCARD:
        return robot
    if not _ROBOT_ID.match(robot):
        raise KeyExprError(f"robot id {robot!r} must be 1-64 letters, digits, '_' or '-'")
    return robot


@dataclass(frozen=True)
class RobotKeys:
    """All key expressions of one robot (or of every robot, with ``robot='*'``)."""

    robot: str

    def __post_init__(self) -> None:
        check_robot_id(self.robot, allow_wildcard=True)

    @property
    def prefix(self) -> str:
        """``cso/<robot>``: every key of the robot is under it."""
        return f"{ROOT}/{self.robot}"

    def topic(self, name: str) -> str:
        return f"{ROOT}/{self.robot}/{topic_key(name)}"

    @property
    def scan(self) -> str:
        return self.topic("scan")

    @property
    def odom(self) -> str:
        return self.topic("odom")

    @property
    def cmd_vel(self) -> str:
        return self.topic("cmd_vel")

    @property
    def map(self) -> str:
        return self.topic("map")

    @property
    def frontiers(self) -> str:
        return self.topic("frontiers")

    @property
    def goal(self) -> str:
        return self.topic("goal")

    @property
    def path(self) -> str:
        return self.topic("path")

    @property
    def planner_feedback(self) -> str:
        return self.topic("planner_feedback")

    @property
    def clock(self) -> str:
        return self.topic("clock")

    @property
    def episode_status(self) -> str:
        return self.topic("episode_status")

    @property
    def episode_result(self) -> str:
        return self.topic("episode_result")

    @property
    def explore_resume(self) -> str:
        """The operator's pause/resume of exploration (``ExploreResumeMsg``; explore_lite's ``explore/resume``)."""
        return self.topic("explore_resume")

    def alive(self, service: str) -> str:
        """Liveliness token of one service (``*`` for all)."""
        return f"{ROOT}/{self.robot}/alive/{service}"

    def alive_incarnation(self, service: str, incarnation: str) -> str:
        """Liveliness token of one start of a service that a launcher started (``*`` for any), beside its ``alive``
        token: ``incarnation`` is the nonce that start was given (``processes.INCARNATION_ENV``), so that the launcher
        tells its own process's token from a predecessor's. ``alive("*")`` (one chunk) does not match it: every other
        reader of ``alive/<name>`` sees what it always saw."""
        if incarnation != WILDCARD and not _INCARNATION.match(incarnation):
            raise KeyExprError(f"incarnation {incarnation!r} must be 1-64 letters, digits, '_' or '-'")
        return f"{ROOT}/{self.robot}/alive/{service}/{incarnation}"

    def service_status(self, service: str) -> str:
        """Queryable with a service's own health (``ServiceStatusMsg``)."""
        return f"{ROOT}/{self.robot}/service/{service}/status"

    @property
    def launcher_status(self) -> str:
        """Queryable of the launcher that runs this robot's services (``LauncherStatusMsg``)."""
        return f"{ROOT}/{self.robot}/launcher/status"

    def cache(self, name: str) -> str:
        """Queryable with the latest ``map``, ``planner_contacts``, ``planner_plan`` or ``planner_state`` (held by the
        referee, sim or ros2_bridge) or ``goal`` (held by the launcher), for restarted services."""
        return f"{ROOT}/{self.robot}/cache/{TOPICS[name] if name in TOPICS else CARRIED[name]}"


def robot_of(key_expr: str) -> str:
    """The robot id of a concrete key ``cso/<robot>/...``."""
    parts = str(key_expr).split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise KeyExprError(f"{key_expr!r} is not a cso/<robot>/... key")
    return check_robot_id(parts[1])


def alive_token_of(key_expr: str) -> tuple[str, str] | None:
    """``(service, incarnation)`` of a concrete liveliness key ``cso/<robot>/alive/<service>`` (incarnation ``""``) or
    ``cso/<robot>/alive/<service>/<incarnation>`` (``RobotKeys.alive_incarnation``); None for any other key."""
    parts = str(key_expr).split("/")
    if len(parts) not in (4, 5) or parts[0] != ROOT or parts[2] != "alive":
        return None
    return parts[3], parts[4] if len(parts) == 5 else ""


def topic_of(key_expr: str) -> str:
    """The topic name of a concrete key (inverse of ``RobotKeys.topic``)."""
    suffix = "/".join(str(key_expr).split("/")[2:])
    for name, s in TOPICS.items():
        if s == suffix:
            return name
    if is_ext_topic(suffix):
        return suffix
    raise KeyExprError(f"{key_expr!r} is not a known topic")


ROBOT_DRIVERS = f"{ROOT}/@ros2"
"""Where the runs that command a ROS robot say so: a verbatim chunk (``@``), which no ``cso/*/...`` or ``cso/**``
expression matches, so these tokens never look like a robot's keys."""


def robot_driver_token(cmd_vel_key: str, robot: str) -> str:
    """Liveliness token of the run (robot id ``robot``; ``*`` for any) whose ROS 2 bridge sends Twists on
    ``cmd_vel_key``, a zenoh-bridge-ros2dds key outside ``cso/`` (``limo1/cmd_vel``): two runs of different ids on
    one robot's namespace would both drive it, each step's two commands fighting."""
    check_robot_id(robot, allow_wildcard=True)
    return f"{ROBOT_DRIVERS}/{cmd_vel_key}/{robot}"


RUN_CLAIMS = f"{ROOT}/@claim"
"""Where a starting run claims what it is to run (``cso_runtime.claims``): a verbatim chunk, as ``ROBOT_DRIVERS``."""


def robot_claim_subject(robot: str) -> str:
    """What a run of robot id ``robot`` claims before it starts: the id's keys (``cso/<robot>/**``)."""
    return f"robot/{check_robot_id(robot)}"


def driver_claim_subject(cmd_vel_key: str) -> str:
    """What a run whose ROS 2 bridge would send Twists on ``cmd_vel_key`` claims before it starts: that robot."""
    return f"drives/{cmd_vel_key}"


def run_claim_token(subject: str, claim: str = WILDCARD) -> str:
    """Liveliness token of a run's claim (``claims.RunClaim.chunk``; ``*`` for any) on ``subject``: the claim first,
    so that ``*`` stands for it whatever the subject's length (``drives/ns/cmd_vel``), and one access-control rule on
    ``cso/@claim/**`` covers them all."""
    return f"{RUN_CLAIMS}/{claim}/{subject}"


def run_goes_on_token(subject: str, claim: str = WILDCARD) -> str:
    """Liveliness token of a claimant that has won ``subject`` and goes on (``*`` for any); no subject starts with
    ``go/``, so a claim's token never matches another's go-on token."""
    return f"{RUN_CLAIMS}/{claim}/go/{subject}"
