"""The dataflow of a profile, from the services' own declarations (dora-rs style: nodes, inputs, outputs).

Each ``Service`` declares the topics it subscribes to (``inputs``) and publishes (``outputs``); the
launcher declares what it listens to (``LAUNCHER_INPUTS``). Joining them gives who feeds whom, so the
graph `cso-runtime dataflow` prints and `up` writes to ``runs/<run-id>/dataflow.md`` cannot drift from
the code (``publish`` refuses an undeclared output, and a test holds docs/messages.md to the same).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from cso_runtime.keys import TOPICS, is_ext_topic, topic_key
from services import SERVICE_NAMES, command_argv, command_topics, is_own_node, own_class_spec, profile_service_class

LAUNCHER = "launcher"


@dataclass(frozen=True)
class Node:
    """One process of the dataflow: its name, the topics it subscribes to and those it publishes."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    spec: str = ""
    """The ``module.path:Attribute`` of a service of one's own (``services.<name>.class``), ``command NAME`` of a command
    node (``services.<name>.command``, its executable's file name); "" for a built-in one."""
    optional: tuple[str, ...] = ()
    """The inputs it works without (``Service.optional_inputs``)."""

    @property
    def label(self) -> str:
        """The node's name, with the class of one's own it runs (``mapper (my_nodes:MyMapper)``)."""
        return f"{self.name} ({self.spec})" if self.spec else self.name


@dataclass(frozen=True)
class Edge:
    """``source`` publishes ``topic`` and ``target`` subscribes to it."""

    source: str
    topic: str
    target: str

    @property
    def key(self) -> str:
        """The key suffix under ``cso/<robot>/`` (``planner_feedback`` travels on ``planner/feedback``)."""
        return topic_key(self.topic)


def service_node(name: str, section: Any = None) -> Node:
    """The node of the service a profile runs as ``name`` with its section ``section`` (``class``: one of one's own;
    ``command``: an executable, with the ``inputs`` and ``outputs`` its section declares)."""
    argv = command_argv(section)
    if argv is not None:
        exe = os.path.basename(argv[0]).replace('"', "'")
        return Node(name, command_topics(section, "inputs"), command_topics(section, "outputs"), f"command {exe}")
    cls = profile_service_class(name, section)
    return Node(name, tuple(cls.inputs), tuple(cls.outputs), own_class_spec(section) or "", tuple(cls.optional_inputs))


def nodes_of(service_names: list[str], sections: dict[str, Any] | None = None) -> list[Node]:
    """The nodes of a profile's services (in profile order), and the launcher that watches them; ``sections``: the
    profile's ``services`` mapping, where a service of one's own names its class (the others are the built-in ones)."""
    from cso_runtime.launcher import LAUNCHER_INPUTS, LAUNCHER_OPTIONAL_INPUTS  # noqa: PLC0415

    out = [service_node(name, (sections or {}).get(name)) for name in service_names]
    return [*out, Node(LAUNCHER, tuple(LAUNCHER_INPUTS), (), "", LAUNCHER_OPTIONAL_INPUTS)]


def edges_of(nodes: list[Node]) -> list[Edge]:
    """Every (publisher, topic, subscriber) pair among ``nodes``, in node order."""
    return [Edge(src.name, topic, dst.name) for src in nodes for topic in src.outputs for dst in nodes if dst is not src and topic in dst.inputs]


@dataclass(frozen=True)
class Wiring:
    """One node's ports with their peers: (key, publishers) per input, (key, subscribers) per output."""

    name: str
    inputs: list[tuple[str, list[str]]]
    outputs: list[tuple[str, list[str]]]


def wiring_of(nodes: list[Node]) -> list[Wiring]:
    """Each node's inputs with who publishes them and outputs with who subscribes (for tables)."""
    edges = edges_of(nodes)
    return [
        Wiring(
            n.name,
            [(topic_key(t), [e.source for e in edges if e.target == n.name and e.topic == t]) for t in n.inputs],
            [(topic_key(t), [e.target for e in edges if e.source == n.name and e.topic == t]) for t in n.outputs],
        )
        for n in nodes
    ]


def unconnected(nodes: list[Node]) -> dict[str, list[str]]:
    """Inputs nobody in the profile publishes (node -> topics), optional ones left out (an operator's pause, which
    ``cso-runtime pause`` sends): a hint."""
    published = {t for n in nodes for t in n.outputs}
    missing = {n.name: [t for t in n.inputs if t not in published and t not in n.optional] for n in nodes}
    return {name: topics for name, topics in missing.items() if topics}


def unfed_inputs(nodes: list[Node]) -> dict[str, list[str]]:
    """The inputs that a service driving the episode needs and no node publishes (node -> topics): what a service of
    one's own in place of a built-in one forgot to publish (a planner without ``planner_feedback``), which the others
    would wait for. A listener's (no outputs) and the launcher's inputs only show things, and optional ones
    (``Node.optional``) are not needed, nor topics of one's own (``ext/<name>``), which nothing of the runtime waits for."""
    published = {t for n in nodes for t in n.outputs}
    drivers = [n for n in nodes if n.outputs and n.name != LAUNCHER]
    unfed = {n.name: [t for t in n.inputs if t not in published and t not in n.optional and not is_ext_topic(t)] for n in drivers}
    return {name: topics for name, topics in unfed.items() if topics}


def missing_producers(service_names: list[str], sections: dict[str, Any] | None = None) -> list[str]:
    """The services an episode of ``service_names`` waits for that none of them is, in ``SERVICE_NAMES`` order: the
    one service that publishes an input of theirs which none of them publishes (a profile with no policy: the
    goals of the planner and the frontier service), and so on for that service's own inputs. A listener (no
    outputs: the foxglove bridge) drives nothing, so its inputs are not waited for; a topic that several services
    can publish (the referee's scan: the sim's or a ros2_bridge's) names none, as which one is the robot's to say.
    ``sections``: the profile's ``services`` mapping, whose services of one's own (``class``) are taken with the
    inputs and outputs they declare (a goal selector of one's own under its own name publishes the goals), and its
    command nodes (``command``) with those their sections declare."""
    every = {n.name: n for n in nodes_of(list(SERVICE_NAMES)) if n.name != LAUNCHER}
    every.update((name, service_node(name, section)) for name, section in (sections or {}).items() if name in service_names and is_own_node(section))
    builtin_publishers = {t: [n for n in SERVICE_NAMES if t in every[n].outputs] for t in TOPICS}
    publishers = {t: [n.name for n in every.values() if t in n.outputs] for t in TOPICS}
    have, todo, missing = set(service_names), list(service_names), []
    while todo:
        node = every[todo.pop()]
        for topic in node.inputs if node.outputs else ():
            if topic in node.optional:  # worked without (an operator's pause: the ros2_bridge's, or `cso-runtime pause`)
                continue
            if not have.intersection(publishers.get(topic, [])) and len(builtin_publishers.get(topic, [])) == 1:
                name = builtin_publishers[topic][0]
                have.add(name)
                todo.append(name)
                missing.append(name)
    return [n for n in SERVICE_NAMES if n in missing]


OUTSIDE_NOTE = "not started by this run"
"""How a service left out of the run (``up --without``, served by another process) is named in its dataflow."""


def to_mermaid(nodes: list[Node], outside: list[str] | tuple[str, ...] = ()) -> str:
    """A Mermaid flowchart (GitHub and most Markdown viewers draw it): one arrow per publisher and
    subscriber, labelled with the keys it carries; the nodes in ``outside`` (left out of the run) dashed."""
    labels: dict[tuple[str, str], list[str]] = {}
    for e in edges_of(nodes):
        labels.setdefault((e.source, e.target), []).append(e.key)
    lines = ["flowchart LR"]
    for n in nodes:
        if n.name == LAUNCHER:
            lines.append(f"  {n.name}([{n.name}])")
        elif n.name in outside:
            lines.append(f'  {n.name}["{n.name} ({OUTSIDE_NOTE})"]')
        elif n.spec:
            lines.append(f'  {n.name}["{n.label}"]')
        else:
            lines.append(f"  {n.name}[{n.name}]")
    lines += [f'  {src} -->|"{", ".join(keys)}"| {dst}' for (src, dst), keys in labels.items()]
    if outside:
        lines += ["  classDef outside stroke-dasharray: 5 5", f"  class {','.join(outside)} outside"]
    return "\n".join(lines) + "\n"


def to_markdown(profile_name: str, nodes: list[Node], outside: list[str] | tuple[str, ...] = ()) -> str:
    """``dataflow.md`` of a run: the Mermaid graph and a table of each node's inputs and outputs; the nodes in
    ``outside`` are the services the run left out (``Profile.left_out_services``), which another process is to serve."""
    rows = []
    labels = {n.name: n.label for n in nodes}
    for w in wiring_of(nodes):
        ins = ", ".join(f"`{key}` ({', '.join(peers) or 'none in this profile'})" for key, peers in w.inputs)
        outs = ", ".join(f"`{key}` ({', '.join(peers) or 'no subscriber in this profile'})" for key, peers in w.outputs)
        name = f"{w.name} ({OUTSIDE_NOTE})" if w.name in outside else labels[w.name]
        rows.append(f"| {name} | {ins or '-'} | {outs or '-'} |")
    left_out = (
        [f"Left out of this run (`up --without`, or not in the profile and needed), served by another process: {', '.join(f'`{n}`' for n in outside)}.", ""]
        if outside
        else []
    )
    return "\n".join(
        [
            f"# Dataflow of profile `{profile_name}`",
            "",
            "Keys are under `cso/<robot>/` (docs/messages.md). Made from the services' declared inputs and outputs.",
            "",
            *left_out,
            "```mermaid",
            to_mermaid(nodes, outside).rstrip(),
            "```",
            "",
            "| node | inputs (from) | outputs (to) |",
            "| --- | --- | --- |",
            *rows,
            "",
        ]
    )
