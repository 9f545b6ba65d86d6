"""A service of the user's own, a ``Service`` subclass named ``module.path:Attribute`` in a profile's
``services.<name>.class``: ``up`` starts it beside the built-in services or in place of one, supervises it, the sim's
step 0 waits for it, and ``dataflow``, ``dataflow.md`` and ``run.json`` show it (docs/own-service.md)."""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from cso_runtime.config import ConfigError
from cso_runtime.messages import CmdVelMsg, FrontiersMsg, GoalMsg, OdometryMsg, PlannerFeedbackMsg
from cso_runtime.run_profile import load_profile
from cso_runtime.supervision import pid_alive, python_module_argv
from services.common import Service, _dispatch
from services.dataflow import missing_producers
from tests.conftest import TerminalRunner
from tests.own_service_example import CoverageLogger
from tests.test_runtime import PROFILES, REPO, SCENE, in_process_result, kill_leftovers, run_pids
from tests.test_service_logic import _explorer_at, _inputs, _service

LOGGER = "tests.own_service_example:CoverageLogger"
MAPPER = "tests.own_service_example:OwnMapper"


class GoalNode(Service):
    """A goal selector of one's own under a name of its own (publishes the goals the built-in policy would)."""

    name = "my_policy"
    inputs = {"frontiers": FrontiersMsg}
    outputs = {"goal": GoalMsg}


class NoFeedbackPlanner(Service):
    """A planner of one's own that forgets the frontier service's report (and the optional step ahead)."""

    name = "planner"
    inputs = {"odom": OdometryMsg, "goal": GoalMsg}
    outputs = {"cmd_vel": CmdVelMsg}


class Unnamed(Service):
    """A service whose author forgot its name."""


class OffTopic(Service):
    """A service that subscribes to a topic the runtime does not have."""

    name = "off_topic"
    inputs = {"coverage": GoalMsg}


class KeyNotTopic(Service):
    """A service that names a key where a topic's name goes."""

    name = "key_not_topic"
    inputs = {"planner/feedback": PlannerFeedbackMsg}


def own_profile(tmp_path: Path, services: dict) -> Path:
    """The lockstep profile on the small scene with ``services`` added to (or replacing) its own."""
    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    data["scene"] = SCENE
    data["services"].update(services)
    path = tmp_path / "own.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def up_from_this_checkout(*args: str, cwd: Path, timeout_s: float) -> subprocess.CompletedProcess:
    """``cso-runtime up ARGS`` whose services import the services of one's own of this checkout (``tests.*``)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([*python_module_argv("cso_runtime.cli"), "up", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s)


def docs_block(language: str) -> list[str]:
    """The ``language`` code blocks of docs/own-service.md."""
    return re.findall(rf"```{language}\n(.*?)```", (REPO / "docs" / "own-service.md").read_text(encoding="utf-8"), flags=re.DOTALL)


def test_up_runs_services_of_ones_own_beside_and_in_place_of_the_builtin_ones(tmp_path: Path):
    """Real processes in lockstep, the profile of docs/own-service.md: the built-in mapper replaced by ``OwnMapper``
    and ``CoverageLogger`` added. The episode is the in-process one step for step (the same maps), the logger saw every
    map from step 0 (step 0 waited for it), and the run's files name both."""
    own_yaml = docs_block("yaml")[0]  # the second is a command node's (tests/test_command_node.py)
    profile = tmp_path / "own.yaml"
    profile.write_text(own_yaml)
    coverage = tmp_path / yaml.safe_load(own_yaml)["services"]["coverage_logger"]["csv_path"]
    runs = tmp_path / "runs"
    try:
        r = up_from_this_checkout("--profile", str(profile), "--no-live", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=120)
        assert r.returncode == 0, r.stderr[-3000:]
        (run_dir,) = [p.parent for p in runs.glob("*/summary.json")]
        expected = in_process_result(SCENE)
        metrics = json.loads((run_dir / "summary.json").read_text())["methods"]["greedy-dist"]
        assert metrics["steps"] == expected.steps and metrics["terminated_by"] == {expected.terminated_by: 1}
        with coverage.open() as fh:
            rows = list(csv.DictReader(fh))
        assert [int(row["step"]) for row in rows] == list(range(expected.steps + 1))  # every map, from step 0's on
        assert len({row["episode"] for row in rows}) == 1 and float(rows[-1]["explored_m2"]) > float(rows[0]["explored_m2"])
        launcher_log = (run_dir / "logs" / "launcher.log").read_text()
        assert f"started mapper ({MAPPER}, pid" in launcher_log and f"started coverage_logger ({LOGGER}, pid" in launcher_log
        assert f"wrote {len(rows)} rows" in (run_dir / "logs" / "coverage_logger.log").read_text()
        services = json.loads((run_dir / "run.json").read_text())["services"]
        assert {"mapper", "coverage_logger"} <= set(services) and services["coverage_logger"]["pid"] > 0
        dataflow = (run_dir / "dataflow.md").read_text()
        assert f'coverage_logger["coverage_logger ({LOGGER})"]' in dataflow and 'mapper -->|"map"| coverage_logger' in dataflow
        assert f"| mapper ({MAPPER}) |" in dataflow
        assert [p for p in run_pids(runs) if pid_alive(p)] == []
    finally:
        kill_leftovers(runs)


@pytest.mark.parametrize(
    ("section", "said"),
    [
        ({"coverage_logger": {}}, "unknown service 'coverage_logger'; known: sim, mapper"),
        ({"coverage_logger": {}}, "`coverage_logger: {class: module.path:Attribute}`, or an executable: `coverage_logger: {command: [./my_node]}` (docs"),
        ({"coverage_logger": {"class": "no_such_module_here:Logger"}}, "cannot import module 'no_such_module_here'"),
        ({"coverage_logger": {"class": "tests.own_service_example:CoverageLoger"}}, "has no attribute 'CoverageLoger' (did you mean CoverageLogger?)"),
        ({"coverage_logger": {"class": "tests.own_service_example:CoverageLogParams"}}, "not a subclass of services.common.Service"),
        ({"logger": {"class": LOGGER}}, "the class is named 'coverage_logger' (its `name`)"),
        ({"mapper": {"class": LOGGER}}, "to stand in for the built-in mapper, set its name to 'mapper'"),
        ({"x": {"class": "tests.test_own_service:Unnamed"}}, "its name: a service's name must be 1-64 letters"),
        ({"off_topic": {"class": "tests.test_own_service:OffTopic"}}, "inputs names topic 'coverage', which is none of the runtime's topics"),
        ({"key_not_topic": {"class": "tests.test_own_service:KeyNotTopic"}}, "key planner/feedback is topic 'planner_feedback'"),
        ({"coverage_logger": {"class": LOGGER, "every_steps": 0}}, "services.coverage_logger: every_steps must be at least 1"),
        ({"coverage_logger": {"class": LOGGER, "csv": "x.csv"}}, "csv"),
        ({"sim": {"class": MAPPER}}, "the built-in sim cannot be replaced"),
    ],
)
def test_a_service_of_ones_own_that_cannot_run_is_refused_before_anything_starts(tmp_path: Path, section: dict, said: str):
    with pytest.raises(ConfigError) as exc:
        load_profile(str(own_profile(tmp_path, section)))
    assert said in str(exc.value)


def test_up_warns_of_an_input_that_a_service_in_place_of_a_builtin_one_no_longer_publishes():
    """The frontier service reads ``planner/feedback``: a planner of one's own without it left a lockstep episode
    waiting until it failed, with no word before. Optional inputs (the sim's step ahead) and what only the launcher
    reads (the path) are not said; a shipped profile gets no warning."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    r = CliRunner().invoke(app, ["up", "--profile", "lockstep", "--set", "services.planner.class=tests.test_own_service:NoFeedbackPlanner", "--dry-run"])
    assert r.exit_code == 0, r.output
    warnings = [line for line in r.output.splitlines() if line.startswith("warning:")]
    said = "warning: frontier reads planner/feedback, which no service of this run publishes; services.planner runs "
    assert warnings == [f"{said}tests.test_own_service:NoFeedbackPlanner (`cso-runtime dataflow` shows who publishes what)"]
    shipped = CliRunner().invoke(app, ["up", "--profile", "lockstep", "--dry-run", "--without", "planner"])
    assert shipped.exit_code == 0 and "warning:" not in shipped.output, shipped.output


def test_the_services_an_episode_waits_for_count_those_of_ones_own():
    """A goal selector of one's own under its own name publishes the goals: the episode does not wait for a policy
    (it waited 30 s for one, and `status` said the run waited for it). A replaced mapper is the mapper."""
    sections = {n: {} for n in ("sim", "mapper", "frontier", "planner")}
    assert missing_producers(list(sections), sections) == ["policy"]
    own = {**sections, "my_policy": {"class": "tests.test_own_service:GoalNode"}}
    assert missing_producers(list(own), own) == []
    replaced = {**sections, "mapper": {"class": MAPPER}, "policy": {}}
    assert missing_producers(list(replaced), replaced) == []


def test_without_leaves_out_a_service_of_ones_own_or_the_one_in_place_of_a_builtin(tmp_path: Path):
    path = own_profile(tmp_path, {"mapper": {"class": MAPPER}, "coverage_logger": {"class": LOGGER}})
    prof, _ = load_profile(str(path), without=["coverage_logger"])
    assert "coverage_logger" not in prof.services and prof.without == [] and prof.left_out_services() == []
    prof, _ = load_profile(str(path), without=["mapper"])
    assert "mapper" not in prof.services and prof.without == ["mapper"] and prof.own_services() == {"coverage_logger": LOGGER}


def test_a_service_of_ones_own_is_started_by_hand_by_its_class_and_the_builtin_one_is_not_taken_for_it(tmp_path: Path):
    """``cso-runtime service module.path:Attribute`` (``python -m services``) runs a class of one's own; the built-in
    mapper refuses a profile that runs a class of its own as its mapper (it would serve the robot beside it)."""
    profile = own_profile(tmp_path, {"mapper": {"class": MAPPER}})
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    usage = subprocess.run([*python_module_argv("services"), LOGGER, "--help"], env=env, capture_output=True, text=True, timeout=60)
    assert usage.returncode == 0 and f"usage: python -m services {LOGGER}" in usage.stdout
    script = subprocess.run(
        [*python_module_argv("cso_runtime.cli"), "service", "mapper", "--config", str(profile), "--connect", "tcp/127.0.0.1:1"],
        env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert script.returncode == 2, script.stderr
    assert f"the profile runs {MAPPER} as its mapper, not the built-in one: start it with `cso-runtime service {MAPPER}`" in script.stderr
    unknown = subprocess.run([*python_module_argv("services"), "no_such_module_here:X"], env=env, capture_output=True, text=True, timeout=60)
    assert unknown.returncode == 2 and "cannot import module 'no_such_module_here'" in unknown.stderr and "Traceback" not in unknown.stderr


def test_the_coverage_logger_logs_and_counts_a_malformed_map_and_writes_no_row_for_it(tmp_path: Path):
    """What ``run_service`` does with every input: a payload that does not decode never reaches ``on_message``."""
    svc, _ = _service(CoverageLogger, lockstep=True, params={"csv_path": str(tmp_path / "c.csv")})
    svc.start()
    map0, odom0, _ = _inputs(_explorer_at(0), 0)
    _dispatch(svc, "cso/r0/map", b"\x93not a map", time.monotonic())
    svc.on_message("r0", "odom", odom0, 0.0)
    svc.on_message("r0", "map", map0, 0.0)
    svc.shutdown()
    assert svc.rejected == {"map": 1} and svc.status_msg().counters == {"rows": 1}
    assert len((tmp_path / "c.csv").read_text().splitlines()) == 2


def test_the_docs_example_is_the_code_the_tests_run():
    examples = docs_block("python")
    assert len(examples) == 4
    sources = [(REPO / "tests" / name).read_text(encoding="utf-8") for name in ("own_service_example.py", "command_node_example.py")]
    for example in examples:
        assert any(example in source for source in sources), example[:200]


def test_the_docs_table_of_topics_keys_and_message_classes_is_the_runtimes():
    from cso_runtime.keys import TOPICS
    from services import SERVICE_NAMES, service_class

    published = {topic: cls.__name__ for name in SERVICE_NAMES for topic, cls in service_class(name).outputs.items()}
    text = (REPO / "docs" / "own-service.md").read_text(encoding="utf-8")
    rows = re.findall(r"^  \| `(\w+)` \| `([\w/]+)` \| `(\w+)` \|$", text, flags=re.MULTILINE)
    assert {topic: (key, cls) for topic, key, cls in rows} == {topic: (key, published[topic]) for topic, key in TOPICS.items()}


def test_a_misspelt_service_name_is_refused_with_the_name_it_most_likely_meant(tmp_path: Path):
    """``service mapperr``, a profile's ``plannner:`` section and ``--without plicy`` were refused with the list of
    names alone, where a misspelt profile, method or key gets its nearest spelling (``did you mean``)."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    r = CliRunner().invoke(app, ["service", "mapperr"])
    assert r.exit_code == 2 and "unknown service 'mapperr' (did you mean mapper?); choose one of sim, mapper" in r.output, r.output
    with pytest.raises(ConfigError) as exc:
        load_profile(str(own_profile(tmp_path, {"plannner": {}})))
    assert "unknown service 'plannner' (did you mean planner?); known: sim, mapper" in str(exc.value)
    r = CliRunner().invoke(app, ["up", "--profile", "sim", "--without", "plicy", "--dry-run"])
    assert r.exit_code == 2 and "--without plicy (did you mean policy?): no such service; known: sim" in r.output, r.output


def test_dataflow_names_each_service_of_ones_own_by_its_whole_class_on_an_80_column_terminal(tmp_path: Path):
    """docs/own-service.md: ``dataflow --profile own.yaml`` shows "the graph with both, each named with its class". On
    an 80-column terminal the table cut the class to ``(tests.own_service_exa…``, so the user could not see which class
    ran: the node column wraps a long label instead."""

    from cso_runtime.cli import app

    profile = tmp_path / "own.yaml"
    profile.write_text(docs_block("yaml")[0])
    # a terminal: TerminalRunner's output (isatty() true); TTY_COMPATIBLE for rich 14 on, FORCE_COLOR for rich 13
    # (pyproject's rich>=13), which has no TTY_COMPATIBLE, for rich's own idea of one
    r = TerminalRunner().invoke(app, ["dataflow", "--profile", str(profile)], env={"COLUMNS": "80", "TTY_COMPATIBLE": "1", "FORCE_COLOR": "1", "NO_COLOR": "1"})
    assert r.exit_code == 0, r.output
    assert "…" not in r.output, r.output
    lines = re.sub(r"\x1b\[[0-9;]*m", "", r.output).splitlines()
    assert max(len(line) for line in lines) == 80, r.output
    first_column = "".join(line.split("│")[1].strip() for line in lines if line.count("│") == 4)
    assert f"mapper({MAPPER})" in first_column and f"coverage_logger({LOGGER})" in first_column, first_column


def test_dataflow_written_to_a_file_wraps_no_cell_and_an_80_column_terminal_still_folds(tmp_path: Path):
    """Off a terminal (``dataflow > flow.txt``, a pipe, CI) the table was laid out for 80 columns however wide it was:
    the class of a service of one's own was folded across two lines (``(tests.own_service_exam`` / ``ple:OwnMapper)``)
    and a key's peers wrapped, so the file could not be searched for the class it names. Off a terminal the table is
    as wide as its cells (``live_view.table_console``); on an 80-column terminal it folds (the test above). Whatever
    the environment the tests run in: a FORCE_COLOR (a CI's, for coloured logs) or TTY_COMPATIBLE=1 there made rich
    take CliRunner's output for a terminal, and this test fail."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    profile = tmp_path / "own.yaml"
    profile.write_text(docs_block("yaml")[0])
    no_terminal = {"COLUMNS": "80", "FORCE_COLOR": None, "TTY_COMPATIBLE": None}  # None: unset; CliRunner's output is then no terminal
    r = CliRunner().invoke(app, ["dataflow", "--profile", str(profile)], env=no_terminal)
    assert r.exit_code == 0, r.output
    cells = [cell.strip() for line in r.output.splitlines() if line.count("│") == 4 for cell in line.split("│")[1:4]]
    assert f"mapper ({MAPPER})" in cells and f"coverage_logger ({LOGGER})" in cells, r.output
    assert "odom -> frontier, planner, coverage_logger" in cells, r.output  # a key's peers on its one line
