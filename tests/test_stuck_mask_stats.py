"""benchmarks/stuck_mask_stats.py: ``--weights`` is eval's, through the one resolver (``weights.use_weights``)."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
from pathlib import Path
from types import ModuleType

import pytest

from cso_runtime.config import SensorConfig
from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV, weights_path
from tests.conftest import unset_weights_env


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("stuck_mask_stats", Path(__file__).parents[1] / "benchmarks" / "stuck_mask_stats.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_weights_is_evals_a_folder_or_a_file_and_one_not_there_is_said_before_anything_runs(tmp_path, monkeypatch, capsys):
    """It set ``CSO_WEIGHTS_DIR`` to whatever it was given: a ``cso.pt`` file became a folder of that name (no weights),
    a ``CSO_WEIGHTS_FILE`` left in the environment still won over the folder given, and a path not there was said as
    "no weights for cso" once eval ran. It now takes a folder or a file as eval does, and refuses what is not there."""
    from cso_runtime import policies

    unset_weights_env(monkeypatch)  # the shipped weights to copy, whatever the developer's environment gives
    script = _script()
    monkeypatch.setattr(policies.ActionMasker, "mask", policies.ActionMasker.mask)  # the script wraps it to count: put back after
    ran: list[Path] = []
    monkeypatch.setattr(script, "run_eval", lambda request: ran.append(weights_path("cso", SensorConfig.preset("lidar", request.lidar_fov_deg))))
    shipped = weights_path("cso", SensorConfig.preset("lidar", 360))
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(shipped, run / "cso.pt")
    elsewhere = tmp_path / "elsewhere" / "cso.pt"  # a developer's, left in the environment
    elsewhere.parent.mkdir()
    shutil.copy(shipped, elsewhere)
    for given in (run, run / "cso.pt"):
        unset_weights_env(monkeypatch)
        monkeypatch.setenv(WEIGHTS_FILE_ENV, str(elsewhere))
        assert script.main(["--maps", "builtin", "--limit", "1", "--out", str(tmp_path / "out"), "--weights", str(given)]) == 0
        assert ran.pop() == (run / "cso.pt").resolve(), given
        assert (WEIGHTS_DIR_ENV in os.environ) == given.is_dir() and (WEIGHTS_FILE_ENV in os.environ) == given.is_file()
    missing = tmp_path / "nope" / "cso.pt"
    with pytest.raises(SystemExit) as exit_:
        script.main(["--maps", "builtin", "--weights", str(missing)])
    assert exit_.value.code == 2 and re.search(rf"--weights {re.escape(str(missing))}: no such file or folder", capsys.readouterr().err)
    assert ran == []
