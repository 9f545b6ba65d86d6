"""Topics of one's own: a service of one's own (a Python class or a command node) publishes and subscribes keys under
``cso/<robot>/ext/<name>/...`` with any payload, which the runtime neither decodes nor checks; ``dataflow`` shows
them; the runtime's own topics keep their schemas (docs/own-service.md, Topics of your own)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from cso_runtime.config import ConfigError
from cso_runtime.keys import KeyExprError, RobotKeys, is_ext_topic, topic_key, topic_of
from cso_runtime.messages import MapMsg
from cso_runtime.run_profile import load_profile
from services import own_service_class
from services.common import Service, _dispatch
from services.dataflow import nodes_of, to_mermaid, unfed_inputs, wiring_of
from tests.own_service_example import StepsHeard
from tests.test_command_node import node_profile
from tests.test_service_logic import _service


def service_class(name: str, **ports: dict) -> type[Service]:
    """A ``Service`` subclass named ``name`` with ``ports`` (its ``inputs``, its ``outputs``), as a profile imports one."""
    return type(name, (Service,), {"name": name, **ports})


ExtMapNotBytes = service_class("ext_map", outputs={"ext/my_map": MapMsg})
"""Declares a topic of its own with a message class of the runtime's."""
BytesOnMap = service_class("bytes_on_map", inputs={"map": bytes})
"""Declares bytes on one of the runtime's topics, whose schema stays strict."""
ExtTalker = service_class("ext_talker", outputs={"ext/talker/hello": bytes})
"""Publishes on a topic of its own."""


def test_an_ext_topic_is_its_own_key_under_the_robot_and_nothing_else_is():
    assert RobotKeys("r3").topic("ext/my_node/count") == "cso/r3/ext/my_node/count"
    assert topic_of("cso/r3/ext/my_node/count") == "ext/my_node/count" and topic_key("planner_feedback") == "planner/feedback"
    for bad in ("ext", "ext/", "ext/a*", "ext/**", "ext/a//b", "ext/a b", "map/ext/a", "ext/" + "a" * 65):
        assert not is_ext_topic(bad), bad
        with pytest.raises(KeyExprError):
            topic_key(bad)
    with pytest.raises(KeyExprError):
        topic_of("cso/r3/coverage")


def test_a_service_receives_and_sends_the_bytes_of_a_topic_of_its_own_as_they_are():
    svc, _ = _service(StepsHeard, lockstep=True)
    _dispatch(svc, "cso/r0/ext/map_listener/steps", b"7", time.monotonic())
    assert svc.heard == 1 and svc.last_step == 7 and svc.rejected == {}
    _dispatch(svc, "cso/r0/ext/someone_else/steps", b"8", time.monotonic())  # not declared: refused as any topic
    assert svc.heard == 1 and svc.rejected == {"ext/someone_else/steps": 1}
    talker, _ = _service(ExtTalker, lockstep=True)
    assert Service.check_output(talker, "ext/talker/hello", b"\x00any") == b"\x00any"
    with pytest.raises(TypeError):
        Service.check_output(talker, "ext/talker/hello", "text, not bytes")


@pytest.mark.parametrize(
    ("spec", "said"),
    [
        (
            "tests.test_ext_topics:ExtMapNotBytes",
            "outputs['ext/my_map'] is a topic of your own, which carries bytes: declare it as `bytes`",
        ),
        ("tests.test_ext_topics:BytesOnMap", "inputs['map'] must be a message class of cso_runtime.messages"),
    ],
)
def test_a_topic_of_ones_own_carries_bytes_and_the_runtimes_topics_keep_their_schemas(spec: str, said: str):
    with pytest.raises(ConfigError) as exc:
        own_service_class(spec)
    assert said in str(exc.value)


def test_a_command_node_may_declare_topics_of_its_own_and_no_other(tmp_path: Path):
    with pytest.raises(ConfigError) as exc:
        load_profile(str(node_profile(tmp_path, {"command": ["true"], "outputs": ["ext/a*"]})))
    assert "'ext/a*' is none of the runtime's topics" in str(exc.value) and "nor one of your own, ext/<name>" in str(exc.value)


def test_dataflow_draws_topics_of_ones_own_and_up_does_not_wait_for_them(tmp_path: Path):
    node = {"command": ["true"], "inputs": ["map", "ext/elsewhere/x"], "outputs": ["ext/map_listener/steps"]}
    prof, _ = load_profile(str(node_profile(tmp_path, node, {"steps_heard": {"class": "tests.own_service_example:StepsHeard"}})))
    nodes = nodes_of(list(prof.services), prof.services)
    assert 'map_listener -->|"ext/map_listener/steps"| steps_heard' in to_mermaid(nodes)
    wiring = {w.name: w for w in wiring_of(nodes)}
    assert wiring["map_listener"].outputs == [("ext/map_listener/steps", ["steps_heard"])]
    assert ("ext/elsewhere/x", []) in wiring["map_listener"].inputs
    assert "map_listener" not in unfed_inputs(nodes) and prof.awaited_services() == []
