"""A node in any language: a profile's ``services.<name>.command`` names an executable that ``up`` starts as one of the
run's services, under a guard that leads its process group (``cso_runtime.node_guard``), with the run's Zenoh config
and keys in its environment; ``status``, ``run.json`` and ``dataflow`` show it, and no process of it outlives the run,
nor a launcher killed outright (docs/own-service.md, A node in any language)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml

from cso_runtime.config import ConfigError
from cso_runtime.run_profile import load_profile
from cso_runtime.status import query_status, render_table, status_of
from cso_runtime.supervision import pid_alive, python_module_argv
from services import waited_for_at_start
from services.dataflow import nodes_of
from tests.conftest import HANG_DEADLINE_S
from tests.test_own_service import docs_block, up_from_this_checkout
from tests.test_runtime import PROFILES, REPO, SCENE, cli, in_process_result, kill_leftovers, run_pids, wait_for

NODE = REPO / "tests" / "command_node_example.py"
STEPS_HEARD = "tests.own_service_example:StepsHeard"


def node_profile(tmp_path: Path, node: dict[str, Any], others: dict[str, Any] | None = None, **sim_params: Any) -> Path:
    """The lockstep profile on the small scene with the command node ``map_listener`` (``node``: its section), and the
    services ``others``."""
    data = yaml.safe_load((PROFILES / "lockstep.yaml").read_text())
    data["scene"] = SCENE
    data["services"]["sim"].update(sim_params)
    data["services"]["map_listener"] = node
    data["services"].update(others or {})
    data["supervision"] = {**(data.get("supervision") or {}), "stop_timeout_s": 1.0}
    path = tmp_path / "node.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def listener(*args: str) -> dict[str, Any]:
    """The section of the test's command node: the example script with ``args``, reading the map, with its token."""
    return {
        "command": [sys.executable, str(NODE), "maps.txt", *args],
        "inputs": ["map"],
        "outputs": ["ext/map_listener/steps"],
        "alive_token": True,
    }


@contextmanager
def detached_node_run(
    tmp_path: Path, node: dict[str, Any], others: dict[str, Any] | None = None, min_step_period_s: float = 0.25
) -> Iterator[tuple[Path, dict[str, Any]]]:
    """``up --detach`` of ``node_profile`` (the services of one's own in ``others`` imported from this checkout); yields
    the runs folder and ``current.json``; ``down`` and a kill of whatever is left afterwards (the node's own pids too).
    The default step period gives 36 steps some 9 s to look at the run meanwhile."""
    runs = tmp_path / "runs"
    profile = node_profile(tmp_path, node, others, min_step_period_s=min_step_period_s)
    try:
        r = up_from_this_checkout("--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr
        yield runs, json.loads((runs / "current.json").read_text())
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        own = [int(p.read_text()) for p in runs.glob("*/map_listener*.pid")]
        assert kill_leftovers(runs, extra=own) == []


def node_pids(run_dir: Path) -> list[int]:
    """The pids the example node wrote: its own, and its ``sleep``'s with ``--stubborn``."""
    return [int(p.read_text()) for p in sorted(run_dir.glob("map_listener*.pid"))]


def test_up_runs_a_command_node_that_joins_the_run_from_its_environment_alone(tmp_path: Path):
    """A real lockstep episode with the example node (its own Zenoh session, no cso-runtime code): step 0 waits for its
    token, so it gets every map from step 0's; ``status`` shows it running with its pid and no status of its own;
    run.json names its command, dataflow.md draws it; after ``down`` none of its processes is left. It publishes the
    steps it heard on a topic of its own (``ext/map_listener/steps``), which a Python service of one's own counts."""
    # Steps of 0.1 s: what is looked at in the run (its status, the node's) stays there once the episode has ended.
    with detached_node_run(tmp_path, listener(), {"steps_heard": {"class": STEPS_HEARD}}, min_step_period_s=0.1) as (runs, current):
        run_dir = Path(current["run_dir"])
        assert current["services"]["map_listener"]["command"] == listener()["command"]
        status = lambda: query_status(current["endpoints"], current["robot"], timeout_s=0.5)  # noqa: E731
        wait_for(lambda: (s := status()) and s["state"] == "exploring" and s["step"] >= 2, 60, "the episode to start")
        r = cli("status", "--json", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0, r.stdout + r.stderr
        node = json.loads(r.stdout)["services"]["map_listener"]
        assert (
            node["command"]
            and node["process_alive"]
            and node["alive"]
            and node["pid"] == current["services"]["map_listener"]["pid"]
        ), node
        r = cli("status", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert f"alive, pid {node['pid']}, no status: a command node" in " ".join(r.stdout.split()), r.stdout
        final = wait_for(
            lambda: (s := status()) and s["state"] in ("done", "failed") and s, 90, "the end of the episode", period_s=0.2
        )
        assert final["state"] == "done", final
        heard = lambda: (status() or {}).get("services", {}).get("steps_heard", {}).get("counters", {}).get("heard", 0)  # noqa: E731
        lines = wait_for(
            lambda: (maps := (tmp_path / "maps.txt").read_text().splitlines()) and heard() == len(maps) and maps,
            10,
            "every step heard",
        )
        pids = node_pids(run_dir)
        assert len(pids) == 1 and all(pid_alive(p) for p in pids)
    expected = in_process_result(SCENE)
    assert lines[0] == "map 0" and {int(line.split()[1]) for line in lines} == set(range(expected.steps + 1)), lines
    log = (run_dir / "logs" / "map_listener.log").read_text()
    assert (
        "map_listener: joins tcp/127.0.0.1:" in log
        and "map_listener: listening on cso/r0/map" in log
        and "map_listener: stopped" in log
    ), log
    launcher_log = (run_dir / "logs" / "launcher.log").read_text()
    assert f"started map_listener (command {sys.executable} {NODE} maps.txt, pid" in launcher_log, launcher_log
    dataflow = (run_dir / "dataflow.md").read_text()
    exe = Path(sys.executable).name
    assert f'map_listener["map_listener (command {exe})"]' in dataflow and 'mapper -->|"map"| map_listener' in dataflow, dataflow
    assert 'map_listener -->|"ext/map_listener/steps"| steps_heard' in dataflow, dataflow
    assert f"heard {len(lines)} steps on ext/map_listener/steps" in (run_dir / "logs" / "steps_heard.log").read_text()
    assert not any(pid_alive(p) for p in [*run_pids(runs), *pids])


def test_a_command_node_that_ignores_sigterm_does_not_outlive_its_killed_launcher(tmp_path: Path):
    """The launcher SIGKILLed mid-episode: a Python service stops by itself (PR_SET_PDEATHSIG, then ``ORPHAN_STOP_S``);
    an executable of one's own cannot be asked to, so its guard stops its whole process group, SIGTERM and, for a
    node that ignores it, SIGKILL ``stop_timeout_s`` (1 s here) later; the ``sleep`` it started goes with it, and so does
    the daemon it started out of its group (on Linux, where the guard is a child subreaper)."""
    daemon = sys.platform.startswith("linux")
    with detached_node_run(tmp_path, listener("--stubborn", *(["--daemon"] if daemon else []))) as (_, current):
        run_dir = Path(current["run_dir"])
        guard = current["services"]["map_listener"]["pid"]
        wait_for(lambda: "listening" in (run_dir / "logs" / "map_listener.log").read_text(), 60, "the node to listen")
        wait_for(lambda: len(node_pids(run_dir)) == 2 + daemon, 10, "the node's pids")
        pids = [guard, *node_pids(run_dir)]
        assert len(pids) == 3 + daemon and all(pid_alive(p) for p in pids), pids
        os.kill(current["launcher_pid"], signal.SIGKILL)
        wait_for(
            lambda: not any(pid_alive(p) for p in pids),
            15,
            f"the guard, the node and its sleep ({pids}) to be gone",
            period_s=0.05,
        )
    log = (run_dir / "logs" / "map_listener.log").read_text()
    assert (
        "node_guard: the launcher is gone: stopping the node's process group" in log
        and "still runs 1 s after SIGTERM: SIGKILL" in log
    ), log


def test_a_command_node_that_dies_is_restarted_without_its_leftovers_and_down_stops_it_with_its_children(tmp_path: Path):
    """The node SIGKILLed: its guard stops the ``sleep`` it left in its group and exits as the node did, and the launcher
    restarts it as a crashed service. ``down``: the launcher's stop reaches the new node's whole group, SIGINT (which
    the example node takes as its stop) first; a run that ends leaves no pid of it."""
    with detached_node_run(tmp_path, listener("--stubborn")) as (runs, current):
        run_dir = Path(current["run_dir"])
        listening = lambda n: (run_dir / "logs" / "map_listener.log").read_text().count("listening") >= n  # noqa: E731
        wait_for(lambda: listening(1), 60, "the node to listen")
        sleep, node = node_pids(run_dir)  # map_listener.child.pid, map_listener.pid
        os.kill(node, signal.SIGKILL)
        wait_for(lambda: listening(2), 60, "the node to be restarted and listen again")
        assert not pid_alive(sleep) and not pid_alive(node)
        info = json.loads((run_dir / "run.json").read_text())["services"]["map_listener"]
        assert info["restarts"] == 1 and info["pid"] != current["services"]["map_listener"]["pid"], info
        pids = [info["pid"], *node_pids(run_dir)]
        assert len(pids) == 3 and all(pid_alive(p) for p in pids) and node not in pids, pids
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert not any(pid_alive(p) for p in pids)
    text = (run_dir / "logs" / "map_listener.log").read_text()
    assert f"node_guard: the node exited and left 1 process(es) ([{sleep}]): stopping them" in text, text
    assert "map_listener: stopped" in text
    launcher_log = (run_dir / "logs" / "launcher.log").read_text()
    assert f"map_listener exited (code -{int(signal.SIGKILL)}); restart 1/" in launcher_log, launcher_log


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a child subreaper is Linux's")
def test_down_stops_a_daemon_a_command_node_started_out_of_its_process_group(tmp_path: Path):
    """A node that starts a daemon (a double fork and ``setsid``: out of the node's process group and session, its parent
    gone) left it running after ``down``, which signals the guard's group. The guard is a child subreaper (Linux): the
    orphan becomes its child, and it stops its descendants with its group."""
    with detached_node_run(tmp_path, listener("--daemon")) as (runs, current):
        run_dir = Path(current["run_dir"])
        guard = current["services"]["map_listener"]["pid"]
        daemon_pid = run_dir / "map_listener.daemon.pid"
        wait_for(lambda: daemon_pid.exists() and daemon_pid.read_text(), 60, "the node's daemon")
        daemon = int(daemon_pid.read_text())
        assert pid_alive(daemon) and os.getpgid(daemon) != guard and os.getsid(daemon) != os.getsid(guard)
        parent = int(Path(f"/proc/{daemon}/stat").read_text().rsplit(")", 1)[-1].split()[1])
        assert parent == guard, "orphaned, the daemon is the guard's (a subreaper), not init's"
        r = cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert not pid_alive(daemon) and not pid_alive(guard)


ESCAPING_NODE = """
import os, signal, sys, time
for sig in (signal.SIGINT, signal.SIGTERM):
    signal.signal(sig, signal.SIG_IGN)  # kept by its daemon, across fork and exec
first = os.fork()
if first == 0:
    os.setsid()
    if os.fork() == 0:
        print(os.getpid(), flush=True)
        os.execvp("sleep", ["sleep", sys.argv[1]])
    os._exit(0)
os.waitpid(first, 0)
time.sleep(600)
"""
"""A node that ignores SIGINT and SIGTERM and starts a daemon (a double fork, ``setsid``) that ignores them too and
sleeps ``argv[1]`` seconds; the daemon's pid on stdout."""


@contextmanager
def guarded_escaping_node(tmp_path: Path, node_arg: object, node: str = ESCAPING_NODE) -> Iterator[tuple[subprocess.Popen, int]]:
    """The guard (``--stop-timeout 1``, a session of its own as the launcher starts it) running ``node`` (its daemon's
    pid on stdout) with ``node_arg`` (``ESCAPING_NODE``'s: how long its daemon sleeps); yields the guard and its
    daemon's pid; SIGKILL to its group, as the launcher's last stop signal, and to the daemon afterwards."""
    guard = subprocess.Popen(
        [*python_module_argv("cso_runtime.node_guard"), "--stop-timeout", "1", "--", sys.executable, "-c", node, str(node_arg)],
        cwd=tmp_path, stdout=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    daemon = None
    try:
        assert guard.stdout is not None
        daemon = int(guard.stdout.readline())
        yield guard, daemon
    finally:
        os.killpg(guard.pid, signal.SIGKILL)
        guard.wait(10)
        if daemon is not None and pid_alive(daemon):
            os.kill(daemon, signal.SIGKILL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a child subreaper is Linux's")
def test_the_guard_kills_a_daemon_that_left_its_group_and_ignores_sigterm_before_the_launchers_sigkill(tmp_path: Path):
    """The launcher's SIGKILL to the group takes the guard; a daemon of the node's that left the group and ignores
    SIGINT and SIGTERM would then be left running. The guard SIGKILLs it half ``--stop-timeout`` after SIGTERM."""
    with guarded_escaping_node(tmp_path, 600) as (guard, daemon):
        assert pid_alive(daemon) and os.getsid(daemon) != guard.pid
        os.killpg(guard.pid, signal.SIGTERM)  # the launcher's second stop signal
        wait_for(lambda: not pid_alive(daemon), HANG_DEADLINE_S, "the guard to kill the daemon", period_s=0.05)
        assert guard.poll() is None, "the guard (its node ignores SIGTERM) still runs: the daemon's end is its doing"


STOPPED_DAEMON_NODE = """
import os, signal, sys, time
signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the node stays: the guard with it
first = os.fork()
if first == 0:
    os.setsid()
    if os.fork() == 0:
        signal.signal(signal.SIGTERM, lambda *_: (open(sys.argv[1], "w").write("clean"), os._exit(0)))
        print(os.getpid(), flush=True)
        while True:
            time.sleep(1)
    os._exit(0)
os.waitpid(first, 0)
time.sleep(600)
"""
"""A node that ignores SIGTERM and starts a daemon (a double fork, ``setsid``) that stops cleanly on SIGTERM, writing
"clean" to ``argv[1]``; the daemon's pid on stdout."""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a child subreaper is Linux's")
def test_the_guard_continues_a_stopped_daemon_it_passes_a_stop_signal_on_to(tmp_path: Path):
    """The launcher sends each stop signal with a SIGCONT to the guard's group (``stop_children``): a stopped process acts
    on its signal only once continued. A stopped daemon of the node's, out of the group, got the guard's SIGTERM and no
    SIGCONT: it waited, stopped, to be SIGKILLed half ``--stop-timeout`` later, its clean stop never run."""
    from cso_runtime.supervision import process_state

    done = tmp_path / "daemon.done"
    with guarded_escaping_node(tmp_path, done, STOPPED_DAEMON_NODE) as (guard, daemon):
        os.kill(daemon, signal.SIGSTOP)
        wait_for(lambda: process_state(daemon) == "T", HANG_DEADLINE_S, "the daemon to be stopped", period_s=0.01)
        os.killpg(guard.pid, signal.SIGTERM)  # the launcher's second stage, as stop_children sends it
        os.killpg(guard.pid, signal.SIGCONT)
        wait_for(lambda: not pid_alive(daemon), HANG_DEADLINE_S, "the daemon to stop", period_s=0.01)
        assert done.exists() and done.read_text() == "clean", "the stopped daemon was killed, not continued to stop cleanly"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a child subreaper is Linux's")
def test_the_guard_reaps_an_orphaned_daemon_of_its_node_that_exits(tmp_path: Path):
    """A subreaper inherits the node's orphans: one that exits is the guard's to reap, or it stays a zombie under it."""
    with guarded_escaping_node(tmp_path, 0.5) as (guard, daemon):
        parent = lambda: int(Path(f"/proc/{daemon}/stat").read_text().rsplit(")", 1)[-1].split()[1])  # noqa: E731
        wait_for(lambda: parent() == guard.pid, HANG_DEADLINE_S, "the orphaned daemon to become the guard's child", period_s=0.01)
        wait_for(lambda: not Path(f"/proc/{daemon}").exists(), HANG_DEADLINE_S, "the guard to reap its daemon once it exited")


@pytest.mark.parametrize(
    ("section", "said"),
    [
        (
            {"command": ["./no_such_node"]},
            "executable './no_such_node' not found (a relative path is from the folder `up` runs from",
        ),
        ({"command": "no_such_node_on_path --x"}, "executable 'no_such_node_on_path' not found on PATH"),
        ({"command": [str(REPO / "README.md")]}, "is not executable (chmod +x it"),
        ({"command": [], "inputs": ["map"]}, "services.map_listener.command: empty"),
        ({"command": {"exe": "x"}}, "expected a list of arguments or one string"),
        ({"command": "python3 'unclosed"}, "cannot split"),
        ({"command": ["true"], "class": "tests.own_service_example:CoverageLogger"}, "both class and command"),
        ({"command": ["true"], "csv_path": "x.csv"}, "a command node takes no 'csv_path'"),
        (
            {"command": ["true"], "inputs": ["coverage"]},
            "services.map_listener.inputs: 'coverage' is none of the runtime's topics",
        ),
        ({"command": ["true"], "outputs": "map"}, "services.map_listener.outputs: expected a list of topic names"),
        ({"command": ["true"], "alive_token": "yes"}, "alive_token: expected true or false"),
    ],
)
def test_a_command_node_that_cannot_run_is_refused_before_anything_starts(tmp_path: Path, section: dict, said: str):
    with pytest.raises(ConfigError) as exc:
        load_profile(str(node_profile(tmp_path, section)))
    assert said in str(exc.value)


def test_a_command_node_cannot_stand_in_for_a_referee_and_up_refuses_it_with_exit_2(tmp_path: Path):
    data = yaml.safe_load(node_profile(tmp_path, {"command": ["true"]}).read_text())
    data["services"]["sim"] = {"command": ["true"]}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    r = cli("up", "--profile", str(path), "--runs-dir", str(tmp_path / "runs"), "--no-live", cwd=tmp_path)
    assert r.returncode == 2 and "the built-in sim cannot be replaced by a node of your own" in r.stderr, r.stderr
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").glob("*/run.json"))


def test_a_command_node_is_in_the_dataflow_with_the_topics_it_declares_and_step_0_waits_only_for_its_token(tmp_path: Path):
    """A command string split as a shell would; the node in place of the built-in policy publishes the goals (nothing
    is awaited from elsewhere); without ``alive_token`` the sim's step 0 does not wait for it (it would wait
    ``wait_for_services_s`` for a token that never comes)."""
    profile = node_profile(tmp_path, {"command": "true --rate 10", "inputs": ["map", "odom"], "outputs": []})
    prof, _ = load_profile(
        str(profile), settings={"services.policy": {"command": ["true"], "inputs": ["frontiers"], "outputs": ["goal"]}}
    )
    assert (
        prof.command_nodes() == {"map_listener": ["true", "--rate", "10"], "policy": ["true"]} and prof.awaited_services() == []
    )
    nodes = {n.name: n for n in nodes_of(list(prof.services), prof.services)}
    assert nodes["map_listener"].inputs == ("map", "odom") and nodes["map_listener"].label == "map_listener (command true)"
    assert nodes["policy"].outputs == ("goal",)
    assert not waited_for_at_start(prof.services["map_listener"]) and waited_for_at_start(
        {"command": ["true"], "alive_token": True}
    )
    assert waited_for_at_start({}) and waited_for_at_start({"class": "tests.own_service_example:CoverageLogger"})


def test_status_says_a_command_node_runs_and_has_no_status_of_its_own():
    launcher = {
        "run_id": "x",
        "state": "running",
        "services": {"map_listener": {"pid": 41, "process_alive": True, "liveliness": False, "restarts": 0, "command": True}},
    }
    seen = status_of("r0", None, launcher, {}, set())
    assert seen["services"]["map_listener"]["command"] and seen["services"]["map_listener"]["process_alive"]
    from rich.console import Console

    console = Console(width=200, record=True)
    console.print(render_table(seen))
    assert "service map_listener │ running, pid 41, no status: a command node" in console.export_text()
    launcher["services"]["map_listener"]["process_alive"] = False
    console = Console(width=200, record=True)
    console.print(render_table(status_of("r0", None, launcher, {}, set())))
    assert "service map_listener │ DOWN, pid 41, no status: a command node" in console.export_text()


@pytest.mark.parametrize(
    ("command", "code"),
    [
        (["sh", "-c", "exit 7"], 7),
        (["sh", "-c", "kill -USR2 $$"], -signal.SIGUSR2),
        (["sh", "-c", "kill -KILL $$"], -signal.SIGKILL),
        (["./no_such_node"], 2),
    ],
)
def test_the_guard_exits_as_its_node_did(tmp_path: Path, command: list[str], code: int):
    """The launcher restarts or gives up on a command node by its guard's exit: the node's code, or the signal it died of
    (2, a configuration not restarted: an executable gone since ``up`` checked it)."""
    r = subprocess.run(
        [*python_module_argv("cso_runtime.node_guard"), "--", *command], cwd=tmp_path, capture_output=True, text=True, timeout=30
    )
    assert r.returncode == code, r.stderr


LAUNCHER_SEEN = (
    "import json, os; from cso_runtime.processes import launcher_gone;"
    " print(json.dumps([os.environ.get('CSO_PARENT_PID'), os.getppid(), launcher_gone()]))"
)
"""A node that prints what a Python service of the runtime sees of its launcher: ``CSO_PARENT_PID``, its parent's pid,
and ``launcher_gone()``."""


@pytest.mark.parametrize("wrapper", [[], ["nice", "-n", "1"], ["env", "CSO_NODE_EXTRA=1"]])
@pytest.mark.parametrize("by_launcher", [True, False])
def test_a_python_service_run_as_a_command_node_takes_its_guard_for_its_launcher(wrapper: list[str], by_launcher: bool):
    """A command node that runs one of the runtime's Python services (``python -m services.mapper``, through ``nice``
    or ``env`` as one pins or renices a node) got the launcher's pid in ``CSO_PARENT_PID``, while its parent is the
    guard: ``launcher_gone`` said the launcher gone as it started, and the service stopped at once. Its guard, which
    stops it once the launcher is gone, is its launcher; a guard no launcher started (by hand) gives it none."""
    env = {k: v for k, v in os.environ.items() if k != "CSO_PARENT_PID"}
    if by_launcher:
        env["CSO_PARENT_PID"] = str(os.getpid())  # this test is the guard's launcher, as `supervision.Child` starts it
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    guard = subprocess.Popen(
        [*python_module_argv("cso_runtime.node_guard"), "--", *wrapper, sys.executable, "-c", LAUNCHER_SEEN],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    out, err = guard.communicate(timeout=30)
    assert guard.returncode == 0, err
    parent_pid_env, parent, gone = json.loads(out)
    assert parent == guard.pid, "the node is the guard's child (its wrapper exec'd it)"
    assert gone is None, f"the node takes its launcher ({gone}) for gone while it runs"
    assert parent_pid_env == (str(guard.pid) if by_launcher else None), (parent_pid_env, guard.pid)


def test_the_docs_command_node_section_is_what_up_takes(tmp_path: Path):
    """docs/own-service.md's command node section, its executable the example's: a profile ``up`` takes, with the
    node's inputs in the dataflow."""
    section = yaml.safe_load(docs_block("yaml")[1])["services"]["map_listener"]
    section["command"] = [sys.executable, str(NODE), "maps.txt"]
    prof, _ = load_profile(str(node_profile(tmp_path, section)))
    nodes = {n.name: n for n in nodes_of(list(prof.services), prof.services)}
    assert nodes["map_listener"].inputs == ("map",) and prof.services["map_listener"]["alive_token"] is True


def test_logs_place_a_command_nodes_unstamped_lines_after_its_start_not_before_the_whole_run(tmp_path: Path):
    """A command node's own output has no time stamps: ``cso-runtime logs`` sorted all of it before the launcher's
    first line ("merged in time order"), tracebacks of its restarts included. Its guard writes a stamped line as it
    starts it, so each start's lines follow that line."""
    from cso_runtime.runs import log_files, read_logs

    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "launcher.log").write_text("2000-01-01 00:00:00,000 INFO cso.launcher: started map_listener (command sh, pid 1)\n")
    with (logs / "map_listener.log").open("w") as log:
        r = subprocess.run([*python_module_argv("cso_runtime.node_guard"), "--", "sh", "-c", "echo listening"], stdout=log, stderr=log, timeout=30)
    assert r.returncode == 0
    lines, _ = read_logs(log_files(tmp_path))
    said = [(line.service, line.text.split(": ", 1)[-1] if line.service == "launcher" else line.text) for line in lines]
    assert said[0] == ("launcher", "started map_listener (command sh, pid 1)") and said[-1] == ("map_listener", "listening"), said
    assert "INFO node_guard: starting sh -c 'echo listening'" in said[1][1], said


def test_a_run_stopped_for_a_node_that_crashes_at_every_start_says_why_in_run_json_and_runs(tmp_path: Path):
    """A node that crashes as it starts (a camera it cannot open) is restarted ``max_restarts`` times, given up on, and
    once no one serves it for ``given_up_grace_s`` the run stops, exit 1. Its run.json said "failed" and no more: no
    reason, so ``runs`` listed "failed, 3 restarts" and the why was in the launcher's log alone. It now names the
    service given up on, its exit code and restarts."""
    runs = tmp_path / "runs"
    crasher = {"command": [sys.executable, "-c", "raise SystemExit('cannot open the camera')"], "inputs": ["map"]}
    profile = node_profile(tmp_path, crasher, min_step_period_s=0.25)
    data = yaml.safe_load(profile.read_text())
    data["supervision"].update(backoff_s=0.05, backoff_max_s=0.1, given_up_grace_s=1.0)
    profile.write_text(yaml.safe_dump(data))
    try:
        r = up_from_this_checkout("--profile", str(profile), "--detach", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert r.returncode == 0, r.stderr
        run_dir = Path(json.loads((runs / "current.json").read_text())["run_dir"])
        run = wait_for(lambda: (d := json.loads((run_dir / "run.json").read_text())) and d["state"] == "stopped" and d, 60, "the run to stop")
        assert (run["outcome"], run["exit_code"]) == ("failed", 1), run
        assert run["reason"].startswith("gave up on map_listener: exited (code 1) after 3 restarts"), run
        r = cli("runs", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=20)
        assert r.returncode == 0 and "gave up on map_listener" in " ".join(r.stdout.split()), r.stdout
    finally:
        cli("down", "--runs-dir", str(runs), cwd=tmp_path, timeout_s=60)
        assert kill_leftovers(runs) == []
