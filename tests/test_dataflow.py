"""The dataflow is made from the services' declarations, and docs/messages.md must say the same."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from cso_runtime.config import ExplorationConfig
from cso_runtime.geometry import GridGeometry
from cso_runtime.keys import TOPICS
from cso_runtime.messages import GoalMsg, MapMsg
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.run_profile import load_profile
from cso_runtime.transport import TransportConfig
from services import SERVICE_NAMES
from services.common import ServiceContext
from services.dataflow import LAUNCHER, Edge, edges_of, missing_producers, nodes_of, to_markdown, to_mermaid, unconnected

ROOT = Path(__file__).resolve().parents[1]
NODE_NAMES = (*SERVICE_NAMES, LAUNCHER)


def _names_in(cell: str) -> set[str]:
    return set(re.findall(r"\b(" + "|".join(NODE_NAMES) + r")\b", cell))


def docs_table() -> dict[str, list[str]]:
    """Key suffix -> the cells of its row in docs/messages.md's key table: key, schema, publisher, subscribers, body
    (tests/test_wire_conformance.py holds the schema and body cells to the code)."""
    rows = {}
    for line in (ROOT / "docs" / "messages.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 5 and cells[0].startswith("`"):
            rows[cells[0].strip("`")] = cells
    return rows


def _docs_rows() -> dict[str, tuple[str, str]]:
    """Key suffix -> (Publisher, Subscribers) cells of the key table in docs/messages.md."""
    return {key: (cells[2], cells[3]) for key, cells in docs_table().items()}


def test_docs_key_table_names_exactly_the_publishers_and_subscribers_the_code_declares():
    nodes = nodes_of(list(SERVICE_NAMES))
    rows = _docs_rows()
    for topic, key in TOPICS.items():
        assert key in rows, f"docs/messages.md has no row for {key}"
        publishers = {n.name for n in nodes if topic in n.outputs}
        subscribers = {n.name for n in nodes if topic in n.inputs}
        doc_pub, doc_sub = rows[key]
        assert _names_in(doc_pub) == publishers, (key, doc_pub)
        assert _names_in(doc_sub) == subscribers, (key, doc_sub)


@pytest.mark.parametrize("profile", ["sim", "lockstep", "limo-ros2"])
def test_every_input_of_a_shipped_profile_has_a_publisher(profile):
    prof, _ = load_profile(profile, {}, connect=["tcp/127.0.0.1:7447"])
    assert unconnected(nodes_of(list(prof.services))) == {}
    assert prof.awaited_services() == prof.left_out_services() == []


def test_the_services_an_episode_waits_for_are_the_producers_of_its_inputs_that_the_profile_lacks():
    """A profile that leaves a service out (no ``without:`` needed) waits for it: the one producer of an input no
    listed service publishes, and then that one's own inputs. A topic two services can publish (the referee's scan)
    names neither, and a listener's inputs (the foxglove bridge's) are not waited for."""
    pipeline = ["sim", "mapper", "frontier", "policy", "planner"]
    assert missing_producers(pipeline) == missing_producers([*pipeline, "foxglove_bridge"]) == []
    assert missing_producers([n for n in pipeline if n != "policy"]) == ["policy"]
    assert missing_producers([n for n in pipeline if n != "planner"]) == ["planner"]
    assert missing_producers(["sim", "mapper", "frontier"]) == ["policy", "planner"]
    assert missing_producers(["sim"]) == ["mapper", "frontier", "policy", "planner"]  # and the frontier for the planner's frontiers
    assert missing_producers(["ros2_bridge", "mapper", "frontier", "planner"]) == ["policy"]
    assert missing_producers(["mapper", "frontier", "policy", "planner"]) == []  # sim or ros2_bridge: the robot's to say
    assert missing_producers(["foxglove_bridge"]) == []
    prof, _ = load_profile("lockstep", {}, without=["policy"])
    assert prof.awaited_services() == prof.left_out_services() == ["policy"]


def test_dataflow_draws_a_service_the_profile_leaves_out_as_one_the_run_does_not_start(tmp_path):
    """A profile with no policy reads as ``--without policy`` does: ``dataflow`` draws the policy as not started by
    the run (it printed notes that nothing publishes the goal), and ``up --dry-run`` says so."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    data = yaml.safe_load((ROOT / "configs" / "profiles" / "lockstep.yaml").read_text())
    del data["services"]["policy"]
    path = tmp_path / "no-policy.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    runner = CliRunner()
    r = runner.invoke(app, ["dataflow", "--profile", str(path)])
    assert r.exit_code == 0 and "note:" not in r.output, r.output
    r = runner.invoke(app, ["dataflow", "--profile", str(path), "--format", "markdown"])
    assert "\n| policy (not started by this run) | `frontiers` (frontier) |" in r.output, r.output
    r = runner.invoke(app, ["dataflow", "--profile", str(path), "--format", "mermaid"])
    assert '  policy["policy (not started by this run)"]\n' in r.output and "  class policy outside\n" in r.output, r.output
    r = runner.invoke(app, ["up", "--profile", str(path), "--dry-run"])
    assert r.exit_code == 0 and "would start sim, mapper, frontier, planner for robot r0 (without policy: not started by this run)" in r.output, r.output


def test_sim_profile_dataflow_holds_the_lockstep_chain():
    prof, _ = load_profile("sim", {})
    nodes = nodes_of(list(prof.services))
    assert [n.name for n in nodes] == ["sim", "mapper", "frontier", "policy", "planner", LAUNCHER]
    edges = set(edges_of(nodes))
    chain = [Edge("sim", "scan", "mapper"), Edge("mapper", "map", "frontier"), Edge("frontier", "frontiers", "planner"), Edge("planner", "cmd_vel", "sim")]
    decision = [Edge("frontier", "frontiers", "policy"), Edge("policy", "goal", "planner")]
    assert set(chain + decision) <= edges
    assert not any(e.source == LAUNCHER for e in edges)  # the launcher only listens
    assert Edge("policy", "goal", "mapper") not in edges  # only declared inputs are edges
    mermaid = to_mermaid(nodes)
    assert mermaid.startswith("flowchart LR\n") and '  planner -->|"cmd_vel, cmd_vel/ahead, planner/contacts"| sim\n' in mermaid
    assert '  frontier -->|"frontiers"| policy\n' in mermaid
    md = to_markdown("sim", nodes)
    assert "```mermaid\nflowchart LR" in md and "| policy | `frontiers` (frontier) | `goal` (sim, frontier, planner, launcher) |" in md


def test_publish_refuses_what_the_outputs_do_not_declare():
    from services.mapper import MapperService

    class Session:
        def __init__(self):
            self.put = []

        def declare_publisher(self, key):
            session = self

            class Pub:
                def put(self, payload):
                    session.put.append((key, payload))

            return Pub()

    ctx = ServiceContext("mapper", "r0", {"lockstep": True}, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {})
    svc = MapperService(ctx)
    svc.session = Session()  # type: ignore[assignment]
    g = GridGeometry(0.05, (4, 4))
    svc.publish("map", MapMsg.of(0, OccupancyMap(g)))
    assert [k for k, _ in svc.session.put] == ["cso/r0/map"]
    with pytest.raises(TypeError, match="mapper publishes GoalMsg on 'goal'"):
        svc.publish("goal", GoalMsg(0, True))
    with pytest.raises(TypeError, match="publishes GoalMsg on 'map'"):
        svc.check_output("map", GoalMsg(0, True))
    assert len(svc.session.put) == 1


def test_dataflow_and_version_commands():
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    runner = CliRunner()
    r = runner.invoke(app, ["dataflow", "--profile", "lockstep", "--format", "mermaid"])
    assert r.exit_code == 0 and r.output.startswith("flowchart LR\n") and '  sim -->|"scan, clock"| mapper\n' in r.output
    r = runner.invoke(app, ["dataflow", "--profile", "limo-ros2"])
    assert r.exit_code == 0 and "ros2_bridge" in r.output and "note:" not in r.output
    assert runner.invoke(app, ["dataflow", "--format", "dot"]).exit_code == 2
    assert runner.invoke(app, ["dataflow", "--profile", "no-such-profile"]).exit_code == 2
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.startswith("cso-runtime ")


def test_the_frontier_service_takes_its_parameters_from_a_profile(tmp_path):
    """``services.frontier`` in a profile sets ``FrontierParams`` (the layer helper, the real-time goal
    wait); a key it does not know is an error before anything starts."""
    from cso_runtime.config import ConfigError

    data = yaml.safe_load((ROOT / "cso_runtime" / "profiles" / "lockstep.yaml").read_text())
    data["services"]["frontier"] = {"layer_helper": False, "goal_wait_s": 1.5}
    (tmp_path / "ok.yaml").write_text(yaml.safe_dump(data))
    prof, _ = load_profile(str(tmp_path / "ok.yaml"), {})
    assert prof.services["frontier"] == {"layer_helper": False, "goal_wait_s": 1.5}
    data["services"]["frontier"] = {"layer_helpr": True}
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="layer_helpr"):
        load_profile(str(tmp_path / "bad.yaml"), {})
