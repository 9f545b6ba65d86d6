"""Whether a run has a ground truth (its coverage measured) is one answer: ``run_profile.measures_coverage``.

A review found that a run with a referee of one's own (a command node: neither sim nor ros2_bridge) had its coverage
said n/a by report.html, the live view and the launcher's line, while ``status`` and ``runs`` showed a number. Each
view is asked here of the same run, for the three kinds of run, and all must agree."""

from __future__ import annotations

import logging
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

COVERAGE = 42.5
"""What the referee says of coverage in every run here: a number shown, or n/a."""


def own_referee_profile(tmp_path: Path) -> Path:
    """The lockstep profile with its sim replaced by a referee of one's own, a command node (docs/own-service.md)."""
    from cso_runtime.run_profile import find_profile

    data = yaml.safe_load(find_profile("lockstep").read_text())
    del data["services"]["sim"]
    data["name"], data["lockstep"] = "own-referee", False
    data["services"]["referee"] = {"command": ["python3", "my_referee.py"], "outputs": ["episode_status", "episode_result"]}
    path = tmp_path / "own-referee.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def views_of(tmp_path: Path, kind: str, caplog: pytest.LogCaptureFixture, said: bool | None = None, rows: dict | None = None) -> dict[str, bool]:
    """Each view of one ended episode of ``kind``'s run: whether it shows the referee's coverage as a number.
    ``said``: what the referee's ``episode_status`` says of it (``coverage_measured``; None: nothing, as before).
    ``rows``: filled with the coverage row of ``status`` and of the live view, and the launcher's status
    (``launcher_status``)."""
    from rich.console import Console

    from cso_runtime.cli import app
    from cso_runtime.keys import RobotKeys
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import NO_COVERAGE, NO_GROUND_TRUTH, NO_OWN_GROUND_TRUTH, LiveView
    from cso_runtime.messages import EpisodeResultMsg, EpisodeStatusMsg, encode
    from cso_runtime.run_profile import find_profile, load_profile
    from cso_runtime.runs import summarize_run
    from cso_runtime.status import render_table, status_of

    if kind == "own-referee":
        profile, data = load_profile(str(own_referee_profile(tmp_path)), {"method": "greedy-dist"})
    else:
        profile, data = load_profile(str(find_profile(kind)), {"method": "greedy-dist"}, connect=["tcp/127.0.0.1:7447"] if kind == "limo-ros2" else None)
    run_dir = tmp_path / "runs" / f"20261207-120000-{kind}-r0"
    launcher = Launcher(profile, data, run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "profile.yaml").write_text(yaml.safe_dump(data))
    msg = EpisodeStatusMsg(state="done", step=10, scene="s", method="greedy-dist", episode=7, coverage_pct=COVERAGE, explored_area_m2=1.2, coverage_measured=said)
    launcher._on_sample(SimpleNamespace(key_expr=RobotKeys(profile.robot).episode_status, payload=SimpleNamespace(to_bytes=lambda: encode(msg))))
    launcher.ended_status = msg
    free = np.ones((3, 4), bool)
    result = EpisodeResultMsg("s", 10, 1.2, COVERAGE, 1.3, 4.5, "coverage", 3, np.ones(3), np.zeros((4, 2)), np.linspace(0, COVERAGE, 4), free, free, 0.1, "greedy-dist", 0)
    with caplog.at_level(logging.INFO, logger="cso.launcher"):
        caplog.clear()
        launcher.write_outputs(result)
    (line,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("episode coverage:")]
    launcher.write_run_file("stopped")

    def text(renderable: object) -> str:
        console = Console(width=200, record=True)
        console.print(renderable)
        return console.export_text()

    def coverage_row(table: str, view: str) -> bool:
        (row,) = [r for r in table.splitlines() if re.match(r"│ coverage +│", r)]
        assert ("42.5" in row) + (NO_GROUND_TRUTH in row) + (NO_OWN_GROUND_TRUTH in row) == 1, row
        if rows is not None:
            rows[view] = row
        return "42.5" in row

    status = status_of(profile.robot, msg.to_dict(), launcher.launcher_status().to_dict(), {}, set(launcher.alive_services))
    if rows is not None:
        rows["launcher_status"] = launcher.launcher_status()
    runs = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "runs")], env={"COLUMNS": "200"})
    (runs_row,) = [r for r in runs.output.splitlines() if run_dir.name in r]
    cell = runs_row.split()[-3]  # ... cover %, m2, m2/step
    assert runs.exit_code == 0 and cell in ("42.5", NO_COVERAGE), runs.output
    table1 = (run_dir / "report.html").read_text().split("<h2>Table 1</h2>")[1].split("</table>")[0]
    assert ("<td>42.50" in table1) != (f"<td>{NO_COVERAGE}</td>" in table1), table1
    return {
        "status": coverage_row(text(render_table(status)), "status"),
        "status --json": status.get("coverage_measured", "absent"),
        "runs": cell == "42.5",
        "runs --json": summarize_run(run_dir).as_dict().get("coverage_measured", "absent"),
        "live view": coverage_row(text(LiveView(launcher).render()), "live view"),
        "progress line": "coverage 42.5 %" in launcher.progress_log_line(launcher.step_changed_s),
        "launcher line": "42.50% coverage" in line,
        "report": "<td>42.50" in table1,
    }


@pytest.mark.parametrize(("kind", "measured"), [("lockstep", True), ("limo-ros2", False), ("own-referee", False)])
def test_every_view_agrees_whether_a_runs_coverage_was_measured(tmp_path, caplog, kind, measured):
    """The sim knows the scene: its coverage is a number everywhere. A real robot (ros2_bridge) and a referee of
    one's own have no ground truth the runtime knows of: n/a everywhere, while summary.json keeps the 0 (or whatever
    the referee sent) and says ``meta.coverage_measured``."""
    import json

    views = views_of(tmp_path, kind, caplog)
    shown = {k: v for k, v in views.items() if "--json" not in k}  # what each view prints
    assert shown == dict.fromkeys(shown, measured), shown
    assert views == dict.fromkeys(views, measured), views  # and what --json says, beside coverage_pct
    (summary,) = (tmp_path / "runs").glob("*/summary.json")
    assert json.loads(summary.read_text())["meta"]["coverage_measured"] is measured


@pytest.mark.parametrize(("kind", "referee"), [("lockstep", "sim"), ("limo-ros2", "ros2_bridge"), ("own-referee", "own")])
def test_status_and_the_live_view_word_an_unmeasured_coverage_as_the_runs_referee_is(tmp_path, caplog, kind, referee):
    """``status`` and the live view said "n/a: a real robot (no ground truth)" of a run whose referee is one of one's own
    (a command node, no real robot), which report.html words as the run's own referee's. The launcher's status says
    which kind of referee the run has (``launcher_status.referee``, from the profile's services), and both word it as
    report.html does; the sim's coverage is a number, a real robot's n/a as before (with no launcher answering, nothing
    says which referee: today's words, ``test_status_with_no_launcher_to_ask_takes_the_referees_own_word``)."""
    from cso_runtime.live_view import NO_GROUND_TRUTH, NO_OWN_GROUND_TRUTH
    from cso_runtime.messages import LauncherStatusMsg, decode, encode

    rows: dict = {}
    views_of(tmp_path, kind, caplog, rows=rows)
    launcher_status = rows.pop("launcher_status")
    assert launcher_status.referee == referee and decode(encode(launcher_status), LauncherStatusMsg).referee == referee
    words = {"sim": "42.5", "ros2_bridge": NO_GROUND_TRUTH, "own": NO_OWN_GROUND_TRUTH}[referee]
    assert all(words in rows[view] for view in ("status", "live view")), rows
    if referee == "own":
        assert not any("real robot" in rows[view] for view in ("status", "live view")), rows


@pytest.mark.parametrize("said", [True, False])
def test_a_referee_of_ones_own_says_whether_it_measures_coverage_and_every_view_takes_its_word(tmp_path, caplog, said):
    """A referee of one's own with a ground truth (a simulator of one's own publishing the sim's keys) could not say so:
    the launcher judged by the services' names alone, so its coverage was n/a everywhere. Its ``episode_status`` says
    ``coverage_measured``, and the launcher (its status, live view, lines, summary.json's ``meta.coverage_measured``),
    ``status``, ``runs`` and report.html all take its word; one that says nothing is judged as before (above)."""
    import json

    views = views_of(tmp_path, "own-referee", caplog, said)
    assert views == dict.fromkeys(views, said), views
    (summary,) = (tmp_path / "runs").glob("*/summary.json")
    assert json.loads(summary.read_text())["meta"]["coverage_measured"] is said


def referees_own_status(referee: str, said: bool | None = None) -> dict:
    """The ``episode_status`` that ``referee`` answers before its episode starts, as ``status`` decodes it: the real
    sim's and ros2_bridge's (no Zenoh), or one of one's own saying ``said`` (``coverage_measured``)."""
    from cso_runtime.config import ExplorationConfig
    from cso_runtime.messages import EpisodeStatusMsg, decode, encode
    from cso_runtime.transport import TransportConfig
    from services.common import ServiceContext

    if referee == "ros2_bridge":
        from tests.test_ros2_bridge import _bridge_without_zenoh

        msg = _bridge_without_zenoh()[0].episode_status()
    elif referee == "sim":
        from services.sim import SimService

        profile = {"lockstep": True, "scene": "generated:small:1:0", "seed": 0}
        msg = SimService(ServiceContext("sim", "r0", profile, ExplorationConfig(), TransportConfig(connect=["tcp/127.0.0.1:1"]), {"start_delay_s": 0.0})).episode_status()
    else:
        msg = EpisodeStatusMsg("exploring", 3, coverage_pct=COVERAGE, episode=7, coverage_measured=said)
    status = decode(encode(msg), EpisodeStatusMsg)
    return {**status.to_dict(), "coverage_pct": COVERAGE}  # a number to show, or not


@pytest.mark.parametrize(("referee", "said", "measured"), [("sim", None, True), ("ros2_bridge", None, False), ("referee", True, True), ("referee", False, False)])
def test_status_with_no_launcher_to_ask_takes_the_referees_own_word(referee, said, measured):
    """``status`` of a run whose launcher does not answer (services started by hand, or only the referee's queryable
    reached) said a real robot's coverage was 0.00 %: with no launcher it judged by the five services of the sim's
    profile, the sim among them. The referee's own ``episode_status`` says whether it measures coverage: the ROS 2
    bridge no, the sim yes, a referee of one's own as it says; and it has the last word over a launcher's judgement by
    the services' names (a launcher that has not heard the referee yet, or an older one)."""
    from rich.console import Console

    from cso_runtime.live_view import NO_GROUND_TRUTH
    from cso_runtime.status import render_table, status_of

    episode = referees_own_status(referee, said)
    for launcher in (None, {"run_id": "run1", "state": "running", "services": {referee: {"pid": 1}, "mapper": {"pid": 2}}, "coverage_measured": not measured}):
        status = status_of("r0", episode, launcher, {}, {referee, "mapper"})
        console = Console(record=True, width=200)
        console.print(render_table(status))
        (row,) = [r for r in console.export_text().splitlines() if re.match(r"│ coverage +│", r)]
        assert status["coverage_measured"] is measured and (NO_GROUND_TRUTH not in row) is measured and ("42.50 %" in row) is measured, row
        assert status["referee"] is None  # neither a launcher that answers none nor an older one says which: today's words
        assert status["coverage_pct"] == COVERAGE  # --json keeps what the referee sent


def test_status_of_a_referee_that_says_nothing_with_no_launcher_is_judged_as_before():
    """A referee from before ``coverage_measured`` (its ``episode_status`` without it) and no launcher: the services
    ``status`` lists then (the sim profile's) say, as before."""
    from cso_runtime.status import status_of

    episode = {"state": "exploring", "step": 3, "coverage_pct": COVERAGE}
    assert status_of("r0", episode, None, {}, {"sim", "mapper"})["coverage_measured"] is True


@pytest.mark.parametrize(("referee", "measured"), [("sim", True), ("ros2_bridge", False), ("referee", False)])
def test_status_of_an_older_launcher_judges_by_the_runs_services(referee, measured):
    """A launcher that does not say ``coverage_measured`` (an older version's): ``status`` judges by its services."""
    from cso_runtime.status import status_of

    launcher = {"run_id": "run1", "state": "running", "services": {referee: {"pid": 1, "restarts": 0}, "mapper": {"pid": 2, "restarts": 0}}}
    assert status_of("r0", {"state": "exploring", "coverage_pct": 0.0}, launcher, {}, {referee})["coverage_measured"] is measured


def test_a_summary_of_an_older_version_is_judged_by_its_profile_as_before():
    """summary.json written before ``meta.coverage_measured``: its profile's services say (the sim's is measured), and
    a profile with no services (a hand-made meta) falls back on the simulator's traces (``sim_settings``, sim time)."""
    from cso_runtime.report import coverage_measured

    def summary(meta: dict, sim_time_s: float | None = None) -> dict:
        return {"meta": {"command": "cso-runtime up", **meta}, "methods": {"cso": {"sim_time_s": sim_time_s}}}

    assert coverage_measured(summary({"profile": {"services": {"sim": {}, "mapper": {}}}, "sim_settings": {}}, 12.5))
    assert not coverage_measured(summary({"profile": {"services": {"ros2_bridge": {}, "mapper": {}}}}))
    assert not coverage_measured(summary({"profile": {"services": {"referee": {"command": ["x"]}, "mapper": {}}}}))
    assert not coverage_measured(summary({"profile": {"name": "limo-ros2"}}))
    assert coverage_measured(summary({"profile": {"name": "sim"}, "sim_settings": {}}, 12.5))
    assert coverage_measured({"meta": {"command": "cso-runtime eval"}, "methods": {"cso": {"sim_time_s": 3.0}}})  # eval: the simulator's
    assert not coverage_measured(summary({"profile": {"services": {"sim": {}}}, "coverage_measured": False}))  # what the run said
