"""``cso-runtime doctor``: every check on this machine, and what a failing one says."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cso_runtime import doctor
from cso_runtime.cli import app


def test_doctor_passes_every_check_on_a_working_install(tmp_path):
    """The real checks, in a process of their own as a user runs them: libraries, a Zenoh message on loopback, the
    MuJoCo LIMO driven a step, every weights file, every profile, the runs folder (not made by the check)."""
    r = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "doctor", "--json"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    results = {c["check"]: c for c in json.loads(r.stdout)}
    assert list(results) == ["python", "libraries", "zenoh loopback", "mujoco LIMO", "foxglove bridge", "weights", "profiles", "real-time scheduling", "runs folder"]
    assert re.fullmatch(r"a Foxglove WebSocket server answered on 127\.0\.0\.1:[1-9]\d*", results["foxglove bridge"]["detail"])  # the test extra has it
    assert all(c["ok"] for c in results.values()), results
    assert "eclipse-zenoh" in results["libraries"]["detail"] and "torch 2." in results["libraries"]["detail"]
    assert "optional: foxglove-sdk 0." in results["libraries"]["detail"]  # the test extra installs both extras
    assert "no viewer window here" in results["mujoco LIMO"]["detail"] or "a viewer window can open here" in results["mujoco LIMO"]["detail"]
    assert "cso.pt" in results["weights"]["detail"] and "sim" in results["profiles"]["detail"]
    assert "will be made in" in results["runs folder"]["detail"] and not (tmp_path / "runs").exists()
    from cso_runtime.processes import realtime_refusal

    refusal = realtime_refusal(1)  # an option: said either way, not failed
    realtime = results["real-time scheduling"]["detail"]
    assert realtime == "permitted: a profile's realtime_priority runs its services under SCHED_FIFO" if refusal is None else realtime.startswith(refusal)


def test_a_failing_check_says_why_and_the_others_still_run(tmp_path, monkeypatch):
    def broken() -> str:
        raise ConnectionError("no route to 127.0.0.1")

    results = doctor.run_checks(tmp_path, only=[("broken", broken), ("fine", lambda: "all good")])
    assert [(r.name, r.ok) for r in results] == [("broken", False), ("fine", True)]
    assert results[0].detail.startswith("ConnectionError: no route to 127.0.0.1 (test_doctor.py:") and results[1].detail == "all good"
    (tmp_path / "a_file").write_text("")
    with pytest.raises(RuntimeError, match="cannot hold it"):
        doctor.check_runs_folder(tmp_path / "a_file" / "runs")
    with pytest.raises(RuntimeError, match="is a file, not a folder"):
        doctor.check_runs_folder(tmp_path / "a_file")
    assert doctor.check_runs_folder(tmp_path) == f"{tmp_path.resolve()} is writable"

    monkeypatch.setattr(doctor, "checks", lambda runs_dir: [("broken", broken), ("fine", lambda: "all good")])
    r = CliRunner().invoke(app, ["doctor", "--runs-dir", str(tmp_path)], env={"COLUMNS": "120"})
    assert r.exit_code == 1 and "FAIL" in r.output and "1 of 2 checks passed; failed: broken" in r.output


def test_a_missing_extra_is_reported_not_failed(monkeypatch):
    real_version = doctor.importlib.metadata.version

    def version(dist: str) -> str:
        if dist == "tensorboardX":
            raise doctor.importlib.metadata.PackageNotFoundError(dist)
        return real_version(dist)

    monkeypatch.setattr(doctor.importlib.metadata, "version", version)
    assert "tensorboardX not installed (train --tensorboard needs it)" in doctor.check_libraries()
    real_find_spec = doctor.importlib.util.find_spec
    monkeypatch.setattr(doctor.importlib.util, "find_spec", lambda name, *a: None if name == "foxglove" else real_find_spec(name, *a))
    assert doctor.check_foxglove() == "foxglove-sdk not installed (optional: up --foxglove needs it)"


def test_the_profiles_check_names_every_bad_profile(tmp_path, monkeypatch):
    """Your own ``./configs/profiles/`` take precedence over the packaged ones: each that does not load is named
    with its reason, not only the first (a user fixed one, ran doctor again, and met the next), and the good
    ones are counted."""
    own = tmp_path / "configs" / "profiles"
    own.mkdir(parents=True)
    (own / "mine.yaml").write_text("name: mine\nscene: generated:small:1:0\n")
    (own / "sim.yaml").write_text("name: sim\nscene: generated:small:1:0\nfoo: 1\n")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError) as exc:
        doctor.check_profiles()
    why = str(exc.value)
    assert why.startswith("2 of 4 profiles do not load:"), why
    assert "configs/profiles/mine.yaml: a profile must list at least one service" in why
    assert "configs/profiles/sim.yaml: unknown key(s) foo" in why
    assert "profiles/lockstep.yaml" not in why


def test_the_profiles_check_says_the_weights_problem_once_not_once_per_profile(tmp_path, monkeypatch):
    """With a ``CSO_WEIGHTS_DIR`` that is no folder, the weights row says why, and the profiles row repeated it for
    every profile that runs a learned method ("limo-ros2.yaml ...: method cso: CSO_WEIGHTS_DIR=...: no such folder
    ...; sim.yaml ...: method cso: CSO_WEIGHTS_DIR=...: no such folder ..."). The profiles it stops are named, the
    reason said once; a profile wrong for its own reason is still named with it."""
    own = tmp_path / "configs" / "profiles"
    own.mkdir(parents=True)
    (own / "mine.yaml").write_text("name: mine\nscene: generated:small:1:0\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CSO_WEIGHTS_DIR", str(tmp_path / "no-such-folder"))
    with pytest.raises(ValueError) as exc:
        doctor.check_profiles()
    why = str(exc.value)
    problem = f"CSO_WEIGHTS_DIR={tmp_path / 'no-such-folder'}: no such folder"
    assert why.count(problem) == 1, why
    assert why.startswith("3 of 4 profiles do not load: limo-ros2, sim: their method's weights: " + problem), why
    assert "configs/profiles/mine.yaml: a profile must list at least one service" in why


def test_weights_trained_with_another_entropy_window_are_noted_with_the_set_that_runs_them_not_failed(tmp_path, monkeypatch):
    """``CSO_WEIGHTS_DIR`` of a ``train --set entropy_window_m=4`` run: the weights row failed ("... trained with
    frontier.entropy_window_m 4 m, this run's is 2 m") though doctor has no run, and the profiles row repeated it for
    each profile of a learned method. The weights load as a run with their window loads them; both rows say what they
    compared with (the default config's 2 m, the profile's own) and the ``--set`` a run takes, and pass. A file that does not load still fails."""
    import dataclasses

    import torch

    from cso_runtime.learned.ppo import Args, build_model, save_weights
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    monkeypatch.chdir(tmp_path)  # no profiles of the user's
    wide = Args(variant="cso", entropy_window_m=4.0, out_dir=str(tmp_path / "wide"))
    save_weights(tmp_path / "wide", build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0, "args": dataclasses.asdict(wide)})
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path / "wide"))

    said = doctor.check_weights()
    assert said.startswith(f"1 weights files load ({tmp_path / 'wide'}): cso.pt; note, not a failure"), said
    assert "trained with frontier.entropy_window_m 4 m, the default config's is 2 m" in said and "this run's" not in said
    assert "run with --set frontier.entropy_window_m=4 (up: --set exploration.frontier.entropy_window_m=4)" in said
    profiles = doctor.check_profiles()
    assert profiles == (
        "3 profiles valid: limo-ros2, lockstep, sim; limo-ros2, sim run their method's weights (the weights row) with"
        " --set exploration.frontier.entropy_window_m=4, not with their own window (not a failure)"
    ), profiles

    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "cso.pt").write_bytes(b"not a checkpoint")
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path / "broken"))
    results = {r.name: r for r in doctor.run_checks(tmp_path, only=[("weights", doctor.check_weights)])}
    detail = results["weights"].detail
    assert not results["weights"].ok and f"{tmp_path / 'broken' / 'cso.pt'}: not a cso-runtime checkpoint" in detail, detail


def test_a_profile_wrong_for_its_own_window_still_fails_beside_weights_of_another_window(tmp_path, monkeypatch):
    """Beside weights trained with another entropy window, a profile that did not load was tried again with that window
    given over its own and, where that loaded, noted and passed: a profile of the user's with an ``entropy_window_m`` of
    -1, which fails without those weights, then passed too. Only a profile refused for the weights' window is retried;
    the ``--set`` the note names is the window itself (``3.1234567``, not ``:g``'s ``3.12346``, refused in turn)."""
    import dataclasses

    import torch

    from cso_runtime.learned.ppo import Args, build_model, save_weights
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)
    own = tmp_path / "configs" / "profiles"
    own.mkdir(parents=True)
    sim = (Path(doctor.__file__).parent / "profiles" / "sim.yaml").read_text(encoding="utf-8")
    (own / "mine.yaml").write_text(sim.replace("name: sim", "name: mine").replace("exploration: {}", "exploration: {frontier: {entropy_window_m: -1}}"))
    monkeypatch.chdir(tmp_path)
    wide = Args(variant="cso", entropy_window_m=3.1234567, out_dir=str(tmp_path / "wide"))
    save_weights(tmp_path / "wide", build_model(wide, torch.device("cpu")), wide, {"ppo_decisions": 0, "args": dataclasses.asdict(wide)})
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path / "wide"))

    with pytest.raises(ValueError) as exc:
        doctor.check_profiles()
    why = str(exc.value)
    assert why.startswith("1 of 4 profiles do not load: configs/profiles/mine.yaml: exploration.frontier.entropy_window_m must be in"), why
    (own / "mine.yaml").unlink()
    profiles = doctor.check_profiles()
    assert profiles.endswith(
        "limo-ros2, sim run their method's weights (the weights row) with --set exploration.frontier.entropy_window_m=3.1234567, not with their own window (not a failure)"
    ), profiles
