"""``cso-runtime runs`` and ``logs`` on run folders written here (the end-to-end use is in test_runtime.py)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cso_runtime.cli import app
from cso_runtime.runs import (
    RunError,
    follow_logs,
    list_runs,
    log_files,
    read_logs,
    resolve_run,
    run_is_exploring,
    select_services,
)
from cso_runtime.supervision import process_start_ticks

STAMP = "2026-12-03 09:10:{:02d},{:03d}"


def line(s: int, ms: int, text: str) -> str:
    return f"{STAMP.format(s, ms)} INFO {text}\n"


def make_run(
    runs: Path, run_id: str, *, outcome: str | None = None, summary: dict | None = None, alive: bool = False, logs: dict | None = None, state: str | None = None,
    times: tuple[float, float | None] | None = None, detached: bool = False,
) -> Path:
    """A run folder as ``up`` leaves it: run.json (the launcher this test process when ``alive``), profile.yaml,
    summary.json when given, logs/*.log."""
    d = runs / run_id
    (d / "logs").mkdir(parents=True)
    info = {
        "run_id": run_id,
        "run_dir": str(d),
        "robot": "r0",
        "launcher_pid": os.getpid() if alive else 2**22 + 12345,
        "launcher_start_ticks": process_start_ticks(os.getpid()) if alive else None,
        "state": state or ("running" if alive else "stopped"),
        "services": {"sim": {"pid": 1, "restarts": 0}, "mapper": {"pid": 2, "restarts": 2}},
    }
    if outcome is not None:
        info["outcome"] = outcome
    if detached:  # `up --detach`'s launcher says so
        info["detached"] = True
    if times is not None:  # (started_at, ended_at) as the launcher writes them (Unix time)
        info["started_at"] = times[0]
        if times[1] is not None:
            info["ended_at"] = times[1]
    (d / "run.json").write_text(json.dumps(info))
    (d / "profile.yaml").write_text(yaml.safe_dump({"name": "lockstep", "robot": "r0", "scene": "generated:small:1:0", "method": "cso"}))
    if summary is not None:
        (d / "summary.json").write_text(json.dumps({"methods": {"cso": summary}}))
    for name, text in (logs or {}).items():
        (d / "logs" / f"{name}.log").write_text(text)
    return d


ROW = {"explored_area_m2": 21.85, "coverage_pct": 99.66, "steps": 36.0, "efficiency_m2_per_step": 0.6069, "path_length_m": 1.07, "terminated_by": {"coverage": 1}}


def test_runs_lists_each_run_with_its_state_and_table_1_row(tmp_path):
    runs = tmp_path / "runs"
    make_run(runs, "20261203-091000-lockstep-r0", outcome="interrupted", times=(1000.0, 1065.4))
    make_run(runs, "20261203-091100-lockstep-r0", summary=ROW)  # a run file from before outcomes were recorded
    make_run(runs, "20261203-091200-lockstep-r0", outcome="failed", times=(2000.0, 2007.0))
    make_run(runs, "20261203-091300-lockstep-r0", alive=True, times=(time.time() - 30.0, None))
    (runs / "not-a-run").mkdir()
    listed = [r.as_dict() for r in list_runs(runs)]
    broken = make_run(runs, "20261203-091400-lockstep-r0", summary=ROW)
    for name, text in (("run.json", "{not json"), ("profile.yaml", "[: bad"), ("summary.json", '{"methods": 3}')):
        (broken / name).write_text(text)
    assert list_runs(runs)[-1].as_dict() | {"run_dir": ""} == {
        "run_id": broken.name, "run_dir": "", "state": "unknown", "profile": "", "robot": "", "scene": "", "real_robot": False, "coverage_measured": True, "method": "",
        "explored_area_m2": None, "coverage_pct": None, "steps": None, "efficiency_m2_per_step": None, "path_length_m": None,
        "terminated_by": None, "restarts": 0, "duration_s": None, "stopped_at_step": None, "lost_results": [],
        "reason": "its run.json cannot be read: not JSON (Expecting property name enclosed in double quotes at line 1 column 2)",
    }  # fmt: skip  (a corrupt file is a run with nothing known, not a traceback; nor "stopped", which it may not be)
    # In the table: its state and why, no ", " line for a scene and method not known.
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "200"})
    lines = r.output.splitlines()
    at = next(i for i, ln in enumerate(lines) if broken.name in ln)
    assert r.exit_code == 0 and "unknown: its run.json cannot be read: not JSON" in lines[at] and not any(ln.strip().startswith(",") for ln in lines), r.output
    (broken / "run.json").write_text("[]")
    assert list_runs(runs)[-1].state == "unknown" and list_runs(runs)[-1].reason == "its run.json cannot be read: a JSON list, not an object"
    shutil.rmtree(broken)
    killed = make_run(runs, "20261203-091500-lockstep-r0", state="running")  # its launcher is gone, the file says running
    assert list_runs(runs)[-1].state == "launcher died"
    shutil.rmtree(killed)
    assert [r["run_id"][9:15] for r in listed] == ["091000", "091100", "091200", "091300"]  # oldest first
    assert [r["state"] for r in listed] == ["interrupted", "done", "failed", "running"]
    done = listed[1]
    assert done["steps"] == 36 and isinstance(done["steps"], int) and done["coverage_pct"] == 99.66 and done["efficiency_m2_per_step"] == 0.6069
    assert done["terminated_by"] == "coverage" and done["method"] == "cso" and done["scene"] == "generated:small:1:0"
    assert done["restarts"] == 2 and listed[0]["steps"] is None
    # how long each took: stopped runs from their two times, a running one so far, an old run file nothing
    assert [r["duration_s"] for r in listed[:3]] == [65.4, None, 7.0] and 30.0 <= listed[3]["duration_s"] < 60.0
    assert [r.run_id for r in list_runs(runs, limit=2)] == ["20261203-091200-lockstep-r0", "20261203-091300-lockstep-r0"]
    # A detached run waits for `down` after its episode: it took until the episode ended, not the 12 idle minutes after.
    idle = make_run(runs, "20261203-091600-lockstep-r0", outcome="done", times=(3000.0, 3000.0 + 12 * 60 + 19), summary=ROW)
    info = json.loads((idle / "run.json").read_text())
    (idle / "run.json").write_text(json.dumps(info | {"episode_ended_at": 3041.5}))
    assert list_runs(runs)[-1].duration_s == 41.5
    shutil.rmtree(idle)

    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--json", "--limit", "3"])
    assert r.exit_code == 0 and [x["state"] for x in json.loads(r.output)] == ["done", "failed", "running"]
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "120"})
    assert r.exit_code == 0
    row = next(ln for ln in r.output.splitlines() if "091100" in ln)
    assert "done, 2 restarts" in row and "36" in row and "99.7" in row and "21.9" in row and "0.607" in row
    assert "1 min 5 s" in next(ln for ln in r.output.splitlines() if "091000" in ln)
    assert " 7 s " in next(ln for ln in r.output.splitlines() if "091200" in ln)
    piped = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "80"})  # a pipe, a log, CI
    assert "m2/step" in piped.output and "0.607" in next(ln for ln in piped.output.splitlines() if "091100" in ln)  # was cut at 80
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "none")])  # no such folder: said so (test_runs_of_a_folder_that_does_not_exist_says_so)
    assert r.exit_code == 1 and "no runs folder" in r.output


def test_runs_shows_the_step_an_interrupted_run_stopped_at(tmp_path):
    """``runs`` showed "-" for the steps of an interrupted run (no summary.json), though its launcher knew the step it
    stopped at: run.json keeps it (``last_step``), and ``runs`` shows it as where the run stopped (``--json``:
    ``stopped_at_step``); a run with results shows its episode's steps as before."""
    runs = tmp_path / "runs"
    stopped = make_run(runs, "20261203-091000-lockstep-r0", outcome="interrupted", times=(1000.0, 1065.4))
    (stopped / "run.json").write_text(json.dumps(json.loads((stopped / "run.json").read_text()) | {"last_step": 120}))
    done = make_run(runs, "20261203-091100-lockstep-r0", outcome="done", summary=ROW)
    (done / "run.json").write_text(json.dumps(json.loads((done / "run.json").read_text()) | {"last_step": 40}))
    old = make_run(runs, "20261203-091200-lockstep-r0", outcome="interrupted")  # a run file from before last_step
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--json"])
    assert [(x["steps"], x["stopped_at_step"]) for x in json.loads(r.output)] == [(None, 120), (36, None), (None, None)], r.output
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "120"})
    assert "120 (stopped)" in next(ln for ln in r.output.splitlines() if stopped.name in ln), r.output
    assert "(stopped)" not in next(ln for ln in r.output.splitlines() if done.name in ln), r.output
    assert "(stopped)" not in next(ln for ln in r.output.splitlines() if old.name in ln), r.output


def test_logs_merge_services_in_time_order_keeping_each_files_own_order(tmp_path):
    """A traceback's lines (no time stamp) stay after the line they follow; a killed process's last line
    without its newline is shown; ``--tail`` counts per service, as ``docker compose logs --tail``."""
    traceback = "Traceback (most recent call last):\n  File \"x.py\", line 1\nValueError: bad\n"
    d = make_run(
        tmp_path / "runs",
        "20261203-091000-lockstep-r0",
        outcome="failed",
        logs={
            "sim": line(1, 0, "sim a") + line(3, 0, "sim b") + traceback + line(5, 0, "sim c"),
            "mapper": line(2, 0, "mapper a") + line(3, 0, "mapper b") + line(4, 0, "mapper c") + "2026-12-03 09:10:06,000 INFO mapper cut",
            "launcher": line(0, 500, "launcher a") + line(3, 0, "launcher b"),
        },
    )
    files = log_files(d)
    assert list(files) == ["launcher", "mapper", "sim"]  # the launcher first, then by name
    lines, _ = read_logs(files)
    got = [(ln.service, ln.text.split(" INFO ")[-1]) for ln in lines]
    assert got == [
        ("launcher", "launcher a"), ("sim", "sim a"), ("mapper", "mapper a"),
        ("launcher", "launcher b"), ("mapper", "mapper b"), ("sim", "sim b"),
        ("sim", "Traceback (most recent call last):"), ("sim", '  File "x.py", line 1'), ("sim", "ValueError: bad"),
        ("mapper", "mapper c"), ("sim", "sim c"), ("mapper", "mapper cut"),
    ]  # fmt: skip
    lines, _ = read_logs(files, tail=1)
    assert [ln.text.split(" INFO ")[-1] for ln in lines] == ["launcher b", "sim c", "mapper cut"]
    assert read_logs(files, tail=0)[0] == []
    assert list(select_services(files, ["sim"])) == ["sim"]
    with pytest.raises(RunError, match="no log for planner in this run \\(it has: launcher, mapper, sim\\)"):
        select_services(files, ["sim", "planner"])

    r = CliRunner().invoke(app, ["logs", "sim", "--run", d.name, "--runs-dir", str(tmp_path / "runs"), "--tail", "2"])
    assert r.exit_code == 0
    assert r.output.splitlines() == ["sim      | ValueError: bad", f"sim      | {STAMP.format(5, 0)} INFO sim c"]


def test_logs_follow_a_running_run_until_its_launcher_exits(tmp_path):
    """What is written between two reads comes out at the next one, a half-written line only once it is
    whole, a log that appears later (a late service) is followed too; after the launcher is gone, one last
    read and the end."""
    d = make_run(tmp_path / "runs", "20261203-091000-lockstep-r0", alive=True, logs={"sim": line(1, 0, "sim a")})
    lines, readers = read_logs(log_files(d), finished=False)
    assert [ln.text for ln in lines] == [line(1, 0, "sim a").rstrip()]
    writes = [
        lambda: (d / "logs" / "sim.log").open("a").write(line(2, 0, "sim b") + "2026-12-03 09:10:03,000 INFO sim hal"),
        lambda: (d / "logs" / "mapper.log").write_text(line(2, 500, "mapper a")),
        lambda: (d / "logs" / "sim.log").open("a").write("f\n" + line(4, 0, "sim c")),
    ]
    emitted: list[tuple[str, str]] = []
    polls = {"n": 0}

    def alive() -> bool:
        return polls["n"] < len(writes)

    def wait(period_s: float) -> None:
        assert period_s == 0.2
        writes[polls["n"]]()
        polls["n"] += 1

    follow_logs(d, readers, lambda ln: emitted.append((ln.service, ln.text.split(" INFO ")[-1])), alive, wait)
    assert emitted == [("sim", "sim b"), ("mapper", "mapper a"), ("sim", "sim half"), ("sim", "sim c")]


def test_logs_follow_of_a_detached_run_ends_with_its_episode(tmp_path, monkeypatch):
    """A detached run stays up after its episode (``status`` answers until ``down``): ``logs -f`` used to follow it
    forever, so ``up --detach && logs -f`` never returned. It ends once run.json says the episode is over, saying the
    ``down`` that stops it: of its own runs folder (plain `cso-runtime down` stopped the run of ./runs, another robot's)."""
    d = make_run(tmp_path / "runs-r1", "20261203-091000-lockstep-r1", alive=True, state="done", detached=True, logs={"sim": line(1, 0, "episode coverage: 99 %")})
    r = CliRunner().invoke(app, ["logs", "-f", "--run", d.name, "--runs-dir", str(tmp_path / "runs-r1")])
    assert r.exit_code == 0 and "episode coverage: 99 %" in r.output
    stays = f"run {d.name}'s episode has ended; the run stays up (for status) until `cso-runtime down"
    assert f"{stays} --runs-dir {tmp_path / 'runs-r1'}`" in r.output, r.output
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["logs", "-f", "--run", str(d)])  # a run folder named, not under --runs-dir (./runs)
    assert r.exit_code == 0 and f"{stays} --runs-dir {d.parent}`" in r.output, r.output
    shutil.move(tmp_path / "runs-r1", tmp_path / "runs")  # the default folder: plain `cso-runtime down`
    r = CliRunner().invoke(app, ["logs", "-f", "--run", d.name])
    assert r.exit_code == 0 and f"{stays}`" in r.output, r.output
    d = tmp_path / "runs" / d.name
    assert not run_is_exploring(d) and run_is_exploring(make_run(tmp_path / "runs", "20261203-091100-lockstep-r0", alive=True))


def test_logs_follow_of_a_foreground_run_goes_on_until_its_launcher_exits(tmp_path):
    """A foreground ``up`` stops its services and writes its results after its episode: ``logs -f`` stopped at the
    episode's end, missed those lines and the launcher's last (where the results went), and said that the run "stays up
    (for status) until down" of a run that was ending by itself. It follows it until its launcher exits and says so."""
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        d = make_run(tmp_path / "runs", "20261203-091000-sim-r0", state="done", logs={"launcher": line(1, 0, "episode coverage: 99 %")})
        info = json.loads((d / "run.json").read_text())
        info.update(launcher_pid=launcher.pid, launcher_start_ticks=process_start_ticks(launcher.pid))
        (d / "run.json").write_text(json.dumps(info))

        def end_of_run() -> None:  # the launcher's last line, then it exits
            time.sleep(0.5)
            with (d / "logs" / "launcher.log").open("a") as f:
                f.write(line(2, 0, f"results in {d}/: report.html"))
            launcher.kill()

        ender = threading.Thread(target=end_of_run)
        ender.start()
        r = CliRunner().invoke(app, ["logs", "-f", "--runs-dir", str(tmp_path / "runs")])
        ender.join()
        assert r.exit_code == 0 and f"results in {d}/: report.html" in r.output, r.output
        assert f"run {d.name} has ended" in r.output and "stays up" not in r.output, r.output
    finally:
        launcher.kill()
        launcher.wait(timeout=30)


def test_logs_follow_of_a_foreground_run_ends_with_the_run_though_its_process_lives_on(tmp_path):
    """``up`` run inside a long-lived program (the launcher used as a library): its process never exits, and ``logs -f``
    followed it forever after the run had stopped. It ends once run.json says the run stopped and the launcher's
    closing line (where its results went) is written, both, as it writes them at its end, and says the run has ended."""
    from cso_runtime.outputs import results_said

    program = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # the program the launcher ran in
    timer = threading.Timer(60.0, program.kill)  # a logs -f that never ends fails the test, rather than hanging it
    try:
        d = make_run(tmp_path / "runs", "20261203-091000-sim-r0", state="done", logs={"launcher": line(1, 0, "cso_runtime.launcher: episode coverage: 99 %")})
        info = json.loads((d / "run.json").read_text())
        info.update(launcher_pid=program.pid, launcher_start_ticks=process_start_ticks(program.pid))
        (d / "run.json").write_text(json.dumps(info))

        def end_of_run() -> None:  # as Launcher.run ends: run.json says stopped, then its closing line
            time.sleep(0.5)
            (d / "run.json").write_text(json.dumps({**info, "state": "stopped", "outcome": "done", "exit_code": 0}))
            time.sleep(0.5)  # not ended at run.json alone: its last line is still to come
            with (d / "logs" / "launcher.log").open("a") as f:
                f.write(line(2, 0, f"cso_runtime.launcher: {results_said(d)}"))

        ender = threading.Thread(target=end_of_run)
        ender.start()
        timer.start()
        r = CliRunner().invoke(app, ["logs", "-f", "--runs-dir", str(tmp_path / "runs")])
        ender.join()
        assert program.poll() is None, "logs -f ended only when the program was killed"
        assert r.exit_code == 0 and results_said(d) in r.output, r.output
        assert f"run {d.name} has ended" in r.output and "stays up" not in r.output, r.output
        from cso_runtime.outputs import closes_a_run

        # a run with no results ends on its own closing line; any other last line is no end
        assert closes_a_run(line(3, 0, f"cso_runtime.launcher: no results: the run's profile and logs are in {d}/")) and not closes_a_run(line(3, 0, "stopping services"))
    finally:
        timer.cancel()
        program.kill()
        program.wait(timeout=30)


def test_logs_follow_right_after_up_waits_for_the_run_it_starts(tmp_path):
    """``up ... &`` then ``logs -f``: for its first second or more ``up`` has written no run file, and ``logs -f`` said
    "no runs in runs" or, with older runs there, followed the newest of those and ended at once. It waits for the run
    that ``up`` starts (``current.json``) and follows that one."""
    from cso_runtime.current_run import starting_up_path

    runs = tmp_path / "runs"
    make_run(runs, "20261203-091000-sim-r0", outcome="done", logs={"sim": line(1, 0, "the last run")})
    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # the `up` checking its profile
    launcher = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))

        def up_starts_its_run() -> None:
            time.sleep(0.5)
            d = make_run(runs, "20261203-091100-sim-r0", state="done", logs={"sim": line(2, 0, "the new run")})
            info = {**json.loads((d / "run.json").read_text()), "launcher_pid": launcher.pid, "launcher_start_ticks": process_start_ticks(launcher.pid)}
            (d / "run.json").write_text(json.dumps(info))
            (runs / "current.json").write_text(json.dumps(info))
            time.sleep(0.5)
            launcher.kill()

        starter = threading.Thread(target=up_starts_its_run)
        starter.start()
        r = CliRunner().invoke(app, ["logs", "-f", "--runs-dir", str(runs)])
        starter.join()
        assert r.exit_code == 0 and f"`up` (pid {up.pid}) is starting in {runs}" in r.output, r.output
        assert "the new run" in r.output and "the last run" not in r.output and "run 20261203-091100-sim-r0 has ended" in r.output, r.output
    finally:
        for proc in (up, launcher):
            proc.kill()
            proc.wait(timeout=30)


def test_report_of_a_run_without_results_says_why_not_that_it_is_no_run_folder(tmp_path):
    """``report runs/<run-id>`` of a run stopped before its episode ended (Ctrl-C, ``down``) said "(not an `eval --out`
    folder or a run folder?)" of a run folder: such a run writes no summary.json. It says so, as ``runs`` lists the run,
    and where its map so far is; a run still exploring has its results to come; any other folder is answered as before."""
    stopped = make_run(tmp_path / "runs", "20261203-091000-sim-r0", outcome="interrupted")
    (stopped / "last_map.yaml").write_text("image: last_map.png\n")
    r = CliRunner().invoke(app, ["report", str(stopped)])
    assert r.exit_code == 2 and "not an `eval --out` folder" not in r.output, r.output
    assert f"run {stopped.name} has no results: a run stopped before its episode ended writes none (`runs` lists it as interrupted)" in r.output, r.output
    assert str(stopped / "last_map.yaml") in r.output, r.output
    running = make_run(tmp_path / "runs", "20261203-091100-sim-r0", alive=True)
    r = CliRunner().invoke(app, ["report", str(running)])
    assert r.exit_code == 2 and f"run {running.name} is running: its results are written when its episode ends" in r.output, r.output
    r = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert r.exit_code == 2 and "(not an `eval --out` folder or a run folder?)" in r.output, r.output
    # A run that did not stop before its end (failed: results that could not be written, a service given up on), or whose
    # run.json cannot be read, was said to be "stopped before its episode ended": what `runs` says of it, and where to read why.
    failed = make_run(tmp_path / "runs", "20261203-091200-sim-r0", outcome="failed")
    r = CliRunner().invoke(app, ["report", str(failed)])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "stopped before its episode ended" not in said, said
    assert f"run {failed.name} has no results (`runs` lists it as failed); its launcher's log says why: `cso-runtime logs launcher --run {failed}`" in said, said
    (failed / "run.json").write_text("{not json")
    r = CliRunner().invoke(app, ["report", str(failed)])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and f"run {failed.name} has no results; its run.json cannot be read: not JSON" in said and "stopped before" not in said, said



def test_report_of_a_failed_run_says_the_reason_its_run_json_records(tmp_path):
    """``report`` of a run that failed before it started a service (its robot claimed by another launcher, a refused
    profile, no router) said only "its launcher's log says why", where its run.json records the reason, which ``runs``
    lists: the reason is said, and the launcher's log still named for more; a failed run without one is said as before."""
    failed = make_run(tmp_path / "runs", "20261203-091300-sim-r0", outcome="failed")
    reason = "refused: robot r0 is already run by another launcher (pid 4242)"
    info = json.loads((failed / "run.json").read_text())
    (failed / "run.json").write_text(json.dumps({**info, "reason": reason}))
    r = CliRunner().invoke(app, ["report", str(failed)])
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and f"run {failed.name} has no results (`runs` lists it as failed): {reason}; more in its launcher's log: `cso-runtime logs launcher --run {failed}`" in said, said
    assert "says why" not in said, said


def test_runs_and_report_say_an_episodes_result_lost_to_a_restart_of_the_sim(tmp_path):
    """A run whose episode ended while its result was lost to a restart of the sim (run.json's ``lost_results``, as
    the launcher's status has them) read in ``runs`` as any other: done with the next episode's results, or stopped
    with none, and ``report`` of one stopped said only that it stopped before its episode ended. ``runs`` says whose
    result was lost (``--json``: ``lost_results``), and so does ``report``; a malformed entry is no entry."""
    runs = tmp_path / "runs"
    lost = [{"episode": 0x2A, "state": "done", "step": 31, "running": 0x2B}]
    done = make_run(runs, "20261203-091000-lockstep-r0", outcome="done", summary=ROW)
    stopped = make_run(runs, "20261203-091100-lockstep-r0", outcome="interrupted")
    plain = make_run(runs, "20261203-091200-lockstep-r0", outcome="done", summary=ROW)
    bad = make_run(runs, "20261203-091300-lockstep-r0", outcome="done", summary=ROW)
    for d in (done, stopped, plain, bad):  # as the launcher writes it: the profile's services, the sim the referee
        (d / "profile.yaml").write_text(yaml.safe_dump({"name": "lockstep", "robot": "r0", "scene": "generated:small:1:0", "method": "cso", "services": {"sim": {}, "mapper": {}}}))
    for d, entries in ((done, lost), (stopped, lost), (bad, [{"episode": "7"}])):
        (d / "run.json").write_text(json.dumps(json.loads((d / "run.json").read_text()) | {"lost_results": entries, "last_step": 12}))
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--json"])
    assert r.exit_code == 0 and [x["lost_results"] for x in json.loads(r.output)] == [lost, lost, [], []], r.output
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": "250"})
    said = "result of episode 00000000002a lost: the sim restarted before it came"
    text = r.output
    assert r.exit_code == 0 and text.count(said) == 2, text
    assert said not in "".join(ln for ln in text.splitlines() if plain.name in ln or bad.name in ln), text
    r = CliRunner().invoke(app, ["report", str(stopped)])
    out = " ".join(r.output.split())
    assert r.exit_code == 2 and f"run {stopped.name} has no results: a run stopped before its episode ended writes none" in out, out
    assert "episode 00000000002a ended (done at step 31), but its result was lost: the sim restarted before it came; the run went on with episode 00000000002b" in out, out


def test_the_run_logs_reads_is_the_named_one_else_the_current_one_else_the_newest(tmp_path):
    runs = tmp_path / "runs"
    with pytest.raises(RunError, match="no runs in"):
        resolve_run(runs)
    old = make_run(runs, "20261203-091000-lockstep-r0", outcome="done")
    new = make_run(runs, "20261203-091100-lockstep-r0", outcome="done")
    assert resolve_run(runs) == new
    (runs / "current.json").write_text(json.dumps({"run_id": old.name, "run_dir": str(old)}))
    assert resolve_run(runs) == old
    assert resolve_run(runs, new.name) == new and resolve_run(runs, str(new)) == new
    with pytest.raises(RunError, match="no run 'nope' in .*newest first: 20261203-091100-lockstep-r0, 20261203-091000-lockstep-r0"):
        resolve_run(runs, "nope")
    r = CliRunner().invoke(app, ["logs", "--runs-dir", str(tmp_path / "empty")])
    assert r.exit_code == 1 and "error: no runs in" in r.output
    # A run without a log (its logs/ deleted, or a run file and nothing else) printed nothing and exited 0.
    r = CliRunner().invoke(app, ["logs", "--run", old.name, "--runs-dir", str(runs)])
    assert r.exit_code == 1 and r.output == f"error: run {old.name} has no log: {old / 'logs'}/ holds no .log file\n", r.output
    shutil.rmtree(old / "logs")
    r = CliRunner().invoke(app, ["logs", "--run", str(old)])  # not "logs/ holds no .log file": there is no logs/
    assert r.exit_code == 1 and r.output == f"error: run {old.name} has no log: it has no {old / 'logs'}/ folder\n", r.output


def test_runs_keep_and_older_than_list_old_runs_and_delete_them_only_with_yes_never_the_current_one(tmp_path):
    """``runs/`` kept one folder per ``up`` for ever: ``runs --keep N`` / ``--older-than DAYS`` list the runs beyond the
    newest N / started before, and delete them with ``--yes``; the current run and a running one are never touched."""
    from cso_runtime.runs import DAY_S, plan_prune

    runs = tmp_path / "runs"
    now = time.time()
    old = [make_run(runs, f"2026120{i}-090000-lockstep-r0", outcome="done", times=(now - (9 - i) * DAY_S, None)) for i in range(1, 5)]
    live = make_run(runs, "20261205-090000-lockstep-r0", alive=True, times=(now - 10 * DAY_S, None))  # running for 10 days
    newest = make_run(runs, "20261206-090000-lockstep-r0", outcome="done", times=(now - 60.0, None))
    (runs / "current.json").write_text(json.dumps({"run_id": old[0].name, "run_dir": str(old[0])}))  # the current run, however old
    (old[1] / "logs" / "sim.log").write_text("x" * 2_000_000)

    plan = plan_prune(runs, keep=2)
    assert plan.prune == old[1:] and plan.spared == [old[0]]
    plan = plan_prune(runs, older_than_days=5.5)
    assert plan.prune == old[1:3] and plan.spared == [old[0], live]  # started 6 and 7 days ago (8: the current run; 10: a running one)
    assert plan_prune(runs, keep=4, older_than_days=6.5).prune == [old[1]]  # both: beyond the newest 4 and that old
    assert plan_prune(runs, keep=0).prune == [*old[1:], newest]

    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--keep", "2"])
    assert r.exit_code == 0, r.output
    assert r.output.startswith(f"would delete 3 run(s) in {runs} (2.0 MB):") and "nothing deleted: add --yes" in r.output, r.output
    assert f"kept: {old[0].name}" in r.output and live.name not in r.output
    assert all(d.is_dir() for d in [*old, live, newest])  # listed, not deleted
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--older-than", "5.5", "--yes", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["deleted"] is True and [x["run_id"] for x in out["runs"]] == [d.name for d in old[1:3]] and out["runs"][0]["bytes"] > 2_000_000
    assert out["spared"] == [str(old[0]), str(live)] and out["errors"] == []
    assert [d.name for d in sorted(p for p in runs.iterdir() if p.is_dir())] == [old[0].name, old[3].name, live.name, newest.name]
    assert (runs / "current.json").is_file()
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--yes"])
    assert r.exit_code == 2 and "--keep N or --older-than DAYS" in r.output


def test_runs_prune_never_deletes_a_folder_that_is_no_run_or_a_run_whose_services_still_run(tmp_path):
    """``runs --keep 0 --yes`` deleted every folder of the runs folder that had a file named run.json: a folder of one's
    own (a training run's run.json), a run.json that is a folder, a link to a run elsewhere (an error: rmtree of a link),
    and the folder of a run whose launcher died while its services still ran and wrote their logs there. Those are
    left alone (said, and in ``--json``'s ``not_runs``) or spared, and none counts toward ``--keep``."""
    from cso_runtime.runs import plan_prune

    runs = tmp_path / "runs"
    old = make_run(runs, "20261201-090000-lockstep-r0", outcome="done")
    orphaned = make_run(runs, "20261201-091000-lockstep-r0", state="running")  # its launcher died, a service of it runs
    info = json.loads((orphaned / "run.json").read_text())
    info["services"]["sim"] = {"pid": os.getpid(), "start_ticks": process_start_ticks(os.getpid()), "restarts": 0}
    (orphaned / "run.json").write_text(json.dumps(info))
    (runs / "notes").mkdir()
    (runs / "notes" / "run.json").write_text(json.dumps({"epochs": 3}))
    (runs / "list").mkdir()
    (runs / "list" / "run.json").write_text("[1, 2]")
    (runs / "dirjson" / "run.json").mkdir(parents=True)
    elsewhere = make_run(tmp_path / "elsewhere", "20261201-080000-lockstep-r0", outcome="done")
    (runs / "20261201-085000-link").symlink_to(elsewhere)

    plan = plan_prune(runs, keep=0)
    assert plan.prune == [old] and plan.spared == [orphaned], plan
    assert sorted(d.name for d in plan.not_runs) == ["20261201-085000-link", "dirjson", "list", "notes"]
    assert plan_prune(runs, keep=1).prune == [old]  # the folders that are no run do not count toward the newest 1
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--keep", "0", "--yes", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert [x["run_id"] for x in out["runs"]] == [old.name] and out["errors"] == [] and out["spared"] == [str(orphaned)]
    assert out["not_runs"][str(runs / "notes")] == "its run.json is not one `up` wrote"
    assert sorted(p.name for p in runs.iterdir()) == ["20261201-085000-link", orphaned.name, "dirjson", "list", "notes"]
    assert (elsewhere / "run.json").is_file() and (runs / "notes" / "run.json").is_file()
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs), "--keep", "0"])
    assert "left alone: notes (its run.json is not one `up` wrote)" in r.output and f"kept: {orphaned.name}" in r.output, r.output


def test_a_real_robots_run_names_no_scene_of_a_simulator_in_runs_and_the_launchers_first_line():
    """A ``limo-ros2`` run has no simulator: the launcher's first line said "scene generated:small:1:0" (the profile
    default, never run) and ``runs`` listed its row as ", cso". Both now say that the robot explores where it is;
    a simulated run without a ``scene`` key names the default scene it ran."""
    from cso_runtime.run_profile import REAL_ROBOT_SCENE, Profile, load_profile, profile_scene

    real = {"name": "limo-ros2", "method": "cso", "services": {"ros2_bridge": {}, "mapper": {}, "frontier": {}, "policy": {}, "planner": {}}}
    assert profile_scene(real) == REAL_ROBOT_SCENE and "robot" in REAL_ROBOT_SCENE
    assert profile_scene({"services": {"sim": {}}}) == Profile.scene and profile_scene({"scene": "builtin", "services": {"sim": {}}}) == "builtin"
    assert load_profile("limo-ros2", connect=["tcp/127.0.0.1:7447"])[0].scene_label == REAL_ROBOT_SCENE
    assert load_profile("lockstep")[0].scene_label == "generated:small:1:0"


def test_runs_lists_a_real_robots_run_as_exploring_where_the_robot_is(tmp_path):
    from cso_runtime.run_profile import REAL_ROBOT_SCENE
    from cso_runtime.runs import summarize_run

    d = make_run(tmp_path / "runs", "20261206-205536-limo-ros2-r0", outcome="done", summary={"coverage_pct": 0.0, "steps": 196})
    (d / "profile.yaml").write_text(yaml.safe_dump({"name": "limo-ros2", "robot": "r0", "method": "cso", "services": {"ros2_bridge": {}, "planner": {}}}))
    assert summarize_run(d).real_robot and summarize_run(d).as_dict()["scene"] == ""  # --json: no scene, as before
    assert not summarize_run(make_run(tmp_path / "runs", "20261206-205537-lockstep-r0", outcome="done")).real_robot
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "runs")], env={"COLUMNS": "200"})
    assert r.exit_code == 0 and f"{REAL_ROBOT_SCENE}, cso" in r.output and "\n    , cso" not in r.output, r.output


def test_runs_lists_no_coverage_for_a_real_robots_run(tmp_path):
    """``runs`` listed a LIMO's run with "cover % 0.0" (no ground truth: its summary's 0), read as an exploration that
    mapped nothing: the column says n/a there; ``--json`` keeps the summary's 0."""
    d = make_run(tmp_path / "runs", "20261206-205536-limo-ros2-r0", outcome="done", summary={"coverage_pct": 0.0, "steps": 196, "explored_area_m2": 22.6})
    (d / "profile.yaml").write_text(yaml.safe_dump({"name": "limo-ros2", "robot": "r0", "method": "cso", "services": {"ros2_bridge": {}, "planner": {}}}))
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "runs")], env={"COLUMNS": "200"})
    (row,) = [line for line in r.output.splitlines() if "20261206-205536-limo-ros2-r0" in line]
    assert r.exit_code == 0 and row.split()[-4:-2] == ["196", "n/a"], r.output
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "runs"), "--json"])
    assert json.loads(r.output)[0]["coverage_pct"] == 0.0, r.output


def test_runs_says_a_real_robots_coverage_in_the_one_word_of_the_report_and_the_live_view(tmp_path, monkeypatch):
    """``runs`` wrote its own literal "n/a": the cell is ``live_view.NO_COVERAGE``, the one report.html's tables use."""
    from cso_runtime import live_view, report

    assert report.NO_COVERAGE is live_view.NO_COVERAGE
    monkeypatch.setattr(live_view, "NO_COVERAGE", "no-truth")
    d = make_run(tmp_path / "runs", "20261206-205536-limo-ros2-r0", outcome="done", summary={"coverage_pct": 0.0, "steps": 196, "explored_area_m2": 22.6})
    (d / "profile.yaml").write_text(yaml.safe_dump({"name": "limo-ros2", "robot": "r0", "method": "cso", "services": {"ros2_bridge": {}, "planner": {}}}))
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "runs")], env={"COLUMNS": "200"})
    (row,) = [line for line in r.output.splitlines() if "20261206-205536-limo-ros2-r0" in line]
    assert r.exit_code == 0 and row.split()[-4:-2] == ["196", "no-truth"], r.output


def test_the_hints_of_nothing_running_name_the_runs_folder_looked_in(tmp_path, capsys, monkeypatch):
    """``status``, ``down`` and ``logs --run`` of a runs folder of one's own (``--runs-dir``) with no such run said
    "`cso-runtime runs` lists past runs": that lists ./runs, another folder (or "no runs"), not the one looked in. The
    hint names it, as every other hint of a run does (``current_run.runs_command``); the default folder's stays plain."""
    from cso_runtime.current_run import down
    from cso_runtime.status import reachable_target

    mine = tmp_path / "robot1-runs"
    make_run(mine, "20261203-091000-lockstep-r0", outcome="done")
    assert reachable_target([], None, mine) == 1
    assert f"`cso-runtime runs --runs-dir {mine}` lists past runs" in capsys.readouterr().out
    stopped, said = down(mine)
    assert not stopped and f"`cso-runtime runs --runs-dir {mine}` lists past runs" in said, said
    with pytest.raises(RunError, match=f"`cso-runtime runs --runs-dir {mine}` lists them"):
        resolve_run(mine, "nope")
    plain = Path("runs")  # the default, as a plain `cso-runtime runs` reads it
    assert reachable_target([], None, tmp_path / plain) == 1 and "`cso-runtime runs --runs-dir" in capsys.readouterr().out
    monkeypatch.chdir(tmp_path)
    assert reachable_target([], None, plain) == 1
    assert "; `cso-runtime runs` lists past runs" in capsys.readouterr().out


def test_logs_follow_of_a_service_waits_for_its_log_while_the_run_starts(tmp_path, monkeypatch):
    """``up ... &`` then ``logs -f planner``: ``logs -f`` waits for the run file, and then the run is ``starting``, its
    services not spawned yet, with the launcher's log alone: it said "no log for planner in this run (it has:
    launcher)" and exit 1. It waits for the service's log while the run starts; a run past its start says so at once."""
    runs = tmp_path / "runs"
    d = make_run(runs, "20261203-091000-sim-r0", alive=True, state="starting", logs={"launcher": line(1, 0, "started sim")})
    waits = []

    def spawned(seconds: float) -> None:  # the launcher spawns its services, the episode runs, its launcher exits
        waits.append(seconds)
        (d / "logs" / "mapper.log").write_text(line(2, 0, "mapper: first map"))
        info = json.loads((d / "run.json").read_text())
        (d / "run.json").write_text(json.dumps({**info, "state": "stopped", "outcome": "done", "launcher_pid": 2**22 + 12345, "launcher_start_ticks": None}))

    monkeypatch.setattr(time, "sleep", spawned)
    r = CliRunner().invoke(app, ["logs", "-f", "mapper", "--runs-dir", str(runs)])
    assert r.exit_code == 0 and "mapper: first map" in r.output and f"run {d.name} has ended" in r.output, r.output
    assert len(waits) == 1
    # Past its start (a typo, or a service this run does not run): said at once, as before.
    make_run(runs, "20261203-091100-sim-r0", alive=True, state="running", logs={"launcher": line(1, 0, "started sim")})
    r = CliRunner().invoke(app, ["logs", "-f", "plannr", "--run", "20261203-091100-sim-r0", "--runs-dir", str(runs)])
    assert r.exit_code == 1 and "no log for plannr in this run (it has: launcher)" in r.output and len(waits) == 1, r.output


def test_an_up_starting_is_seen_past_the_run_file_of_a_launcher_that_died(tmp_path, capsys, monkeypatch):
    """A launcher killed (SIGKILL, out of memory) leaves ``runs/current.json``; an ``up`` started then has written no run
    file of its own for its first second or more. ``status`` said the dead launcher's "nothing running (run X's
    launcher ... has exited)", ``status --watch`` ended there, and ``logs -f`` followed the dead run's logs and ended at
    once: the ``up`` starting was seen only where no run file was. A run file whose launcher is gone hides it no more."""
    from cso_runtime.current_run import starting_up_path
    from cso_runtime.status import await_started_run, reachable_target

    runs = tmp_path / "runs"
    killed = make_run(runs, "20261203-091000-sim-r0", state="running", logs={"sim": line(1, 0, "the killed run")})  # its launcher gone
    (runs / "current.json").write_text((killed / "run.json").read_text())
    up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])  # the `up` checking its profile
    waits: list[float] = []

    def up_ends(seconds: float) -> None:  # refused by its check, say: no run of its own
        waits.append(seconds)
        up.kill()
        up.wait()  # no timeout: Popen's would sleep, and sleep is this

    try:
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))
        assert reachable_target([], None, runs) == 1
        said = capsys.readouterr().out
        assert f"`up` (pid {up.pid}) is starting in {runs}" in said and "has exited" not in said, said
        monkeypatch.setattr(time, "sleep", up_ends)
        assert await_started_run(runs, False, 0.5) is None  # `status --watch`: waited for it, then went on
        assert waits == [0.5] and f"`up` (pid {up.pid}) is starting in {runs}: it has not written its run file yet; waiting for it..." in capsys.readouterr().out
        up = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        starting_up_path(runs, up.pid).write_text(json.dumps({"up_pid": up.pid, "up_start_ticks": process_start_ticks(up.pid)}))
        r = CliRunner().invoke(app, ["logs", "-f", "--runs-dir", str(runs)])
        assert r.exit_code == 0 and len(waits) == 2 and f"`up` (pid {up.pid}) is starting in {runs}" in r.output, r.output
    finally:
        up.kill()
        up.wait(timeout=30)


def test_a_run_file_whose_process_ids_name_no_process_is_no_live_run(tmp_path):
    """(Older than the merges reviewed here.) A run file edited by hand or mangled: ``launcher_pid: -1`` passed as an
    integer, and ``os.kill(-1, 0)`` succeeds (-1 is every process this user may signal), so its launcher read as alive
    and ``down`` would have sent its SIGINT to pid -1; ``launcher_pid: "x"`` in a run folder's run.json made ``runs``,
    ``logs`` and ``report`` end in a TypeError traceback. Neither names a process: no run is live there."""
    from cso_runtime.current_run import read_current_run
    from cso_runtime.supervision import pid_alive

    assert not pid_alive(-1) and not pid_alive(0) and not pid_alive("x")  # type: ignore[arg-type]
    runs = tmp_path / "runs"
    d = make_run(runs, "20261203-091000-sim-r0", state="running")
    info = json.loads((d / "run.json").read_text())
    (runs / "current.json").write_text(json.dumps({**info, "launcher_pid": -1}))
    assert read_current_run(runs) is None  # not a run file a launcher wrote: ignored, with a warning
    (d / "run.json").write_text(json.dumps({**info, "launcher_pid": "x"}))
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)])
    assert r.exit_code == 0 and "launcher died" in r.output and r.exception is None, r.output


def test_down_says_once_that_the_run_file_is_not_usable(tmp_path, caplog):
    """``down`` with a ``current.json`` that is not JSON warned "ignoring runs/current.json: not readable as JSON" twice:
    it reads the file again (a run file written since its first look), and that second read warned again. Once."""
    import logging

    from cso_runtime.current_run import down

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "current.json").write_text("{not json")
    with caplog.at_level(logging.WARNING):
        ok, message = down(runs, 1.0)
    warned = [r.getMessage() for r in caplog.records if "not readable as JSON" in r.getMessage()]
    assert not ok and message == f"nothing running (no usable {runs / 'current.json'})" and len(warned) == 1, (message, warned)


def test_down_never_removes_a_run_file_a_new_run_wrote_after_its_last_look(tmp_path, monkeypatch):
    """``down`` read ``current.json`` (its run's) and then unlinked it, without the runs folder's lock: a new run's
    launcher that wrote its own in between (a rename over it) lost it, and ``status``, ``down`` and ``logs`` saw no run
    while it ran. ``down`` now takes the file aside by a rename, reads what it took, and removes only its own run's: the
    new run's is put back. Its own run's file it still removes."""
    from cso_runtime import current_run
    from cso_runtime.outputs import write_text_atomic

    runs = tmp_path / "runs"
    runs.mkdir()
    path = runs / "current.json"
    new_run = json.dumps({"run_id": "new", "run_dir": ""})
    real_read = current_run.read_current_run
    reads: list[str] = []

    def read_then_a_new_run_writes(runs_dir: Path, warn: bool = True):  # the new launcher's write right after down's last look
        info = real_read(runs_dir, warn)
        reads.append(str(info and info.get("run_id")))
        if len(reads) == 2:
            write_text_atomic(path, new_run)
        return info

    monkeypatch.setattr(current_run, "read_current_run", read_then_a_new_run_writes)
    path.write_text(json.dumps({"run_id": "old", "run_dir": ""}))  # its launcher gone (no pid): down clears its file
    ok, said = current_run.down(runs, 1.0)
    assert ok and said.startswith("stopped run old") and reads == ["old", "old"], (said, reads)
    assert path.read_text() == new_run and [p.name for p in runs.iterdir()] == ["current.json"]
    monkeypatch.setattr(current_run, "read_current_run", real_read)
    path.write_text(json.dumps({"run_id": "old", "run_dir": ""}))
    assert current_run.down(runs, 1.0)[0] and not path.exists() and not list(runs.iterdir())
    current_run.clear_current_run(runs, "old")  # none there: nothing to do
    write_text_atomic(path, new_run)
    current_run.clear_current_run(runs, "old")  # another run's: left as it is
    assert path.read_text() == new_run and [p.name for p in runs.iterdir()] == ["current.json"]


def test_runs_of_a_folder_that_does_not_exist_says_so(tmp_path):
    """``runs --runs-dir nosuch`` answered "no runs in nosuch", exit 0, as of an empty runs folder: a folder that is not
    there (a typo, another working folder) is said as such, exit 1, as ``logs``, ``status`` and ``down`` answer of it;
    so are its prune (``--keep``) and ``--json``, and a file given as the folder. An empty folder still has no runs."""
    missing = tmp_path / "nosuch"
    for extra in ([], ["--json"], ["--keep", "1"], ["--older-than", "3"]):
        r = CliRunner().invoke(app, ["runs", "--runs-dir", str(missing), *extra])
        assert r.exit_code == 1 and r.stdout == "" and r.stderr.startswith(f"error: no runs folder {missing}: it does not exist"), (extra, r.output)
    (tmp_path / "file").write_text("")
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "file")])
    assert r.exit_code == 1 and r.stderr.startswith(f"error: no runs folder {tmp_path / 'file'}: it is a file"), r.output
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(tmp_path / "empty")])
    assert r.exit_code == 0 and r.output == f"no runs in {tmp_path / 'empty'}\n", r.output
    assert not missing.exists()


def test_runs_reads_a_profile_yaml_as_utf_8_whatever_the_locale_and_lists_a_broken_one(tmp_path):
    """A run's profile.yaml is UTF-8 (written so, its non-ASCII text as it is): ``runs`` read it in the locale's
    encoding, so under ``LC_ALL=C`` a scene named ``küche`` ended the listing with UnicodeDecodeError, as did a
    profile.yaml that is no UTF-8 at all in any locale, where a broken file leaves its fields empty. It reads UTF-8,
    and lists a broken one with its fields empty."""
    from cso_runtime.config import yaml_dump
    from cso_runtime.runs import summarize_run

    runs = tmp_path / "runs"
    kept = make_run(runs, "20261203-091300-lockstep-r0", outcome="done")
    (kept / "profile.yaml").write_text(yaml_dump({"name": "lockstep", "robot": "r0", "scene": "/maps/küche.yaml", "method": "cso"}), encoding="utf-8")
    code = f"from pathlib import Path; from cso_runtime.runs import summarize_run; s = summarize_run(Path({str(kept)!r})); print(ascii((s.method, s.scene)))"
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONCOERCECLOCALE": "0"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("('cso', ") and "k\\xfcche" in done.stdout, (done.stdout, done.stderr[-2000:])
    broken = make_run(runs, "20261203-091400-lockstep-r0", outcome="done")
    (broken / "profile.yaml").write_bytes(b"name: lockstep\nscene: caf\xe9\n")  # Latin-1, no UTF-8
    assert summarize_run(broken).run_id == broken.name
