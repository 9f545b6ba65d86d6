"""benchmarks/step_timeline.py: the step timelines of BENCHMARKS.md, from the services' message traces."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest


def load_step_timeline():
    spec = importlib.util.spec_from_file_location("step_timeline", Path(__file__).parents[1] / "benchmarks" / "step_timeline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_traces(folder: Path, traces: dict[str, list[list]]) -> Path:
    for service, rows in traces.items():
        (folder / f"{service}.trace.json").write_text(json.dumps(rows))
    return folder


def test_events_are_timed_from_the_scan_of_their_step_with_decision_steps_apart(tmp_path):
    """Steps 0 and 1 keep the goal, step 2 decides (the policy published its goal); times in seconds."""
    sim = [["put", "scan", 0, 10.000, 10.0001, 960], ["put", "scan", 1, 10.010, 10.0101, 960], ["put", "scan", 2, 10.030, 10.0301, 960], ["put", "scan", 3, 10.060, 10.0601, 960]]
    mapper = [["handle", "scan", k, t + 0.001, t + 0.0015, t + 0.004] for k, t in ((0, 10.0), (1, 10.01), (2, 10.03))]
    mapper += [["put", "map", 1, 10.013, 10.0131, 1500], ["put", "map", 0, 10.005, 10.0051, 1500], ["put", "map", 2, 10.034, 10.0341, 1500]]
    policy = [["handle", "frontiers", 2, 10.040, 10.041, 10.050], ["put", "goal", 2, 10.049, 10.0491, 200]]
    step_timeline = load_step_timeline()
    timeline = step_timeline.timeline(step_timeline.load_traces(write_traces(tmp_path, {"sim": sim, "mapper": mapper, "policy": policy})))

    keep, decision = timeline["keep"], timeline["decision"]
    assert (keep["steps"], decision["steps"]) == (2, 1)  # step 3 has no next scan: no duration
    assert keep["step_ms_median"] == pytest.approx(15.0) and decision["step_ms_median"] == pytest.approx(30.0)
    assert keep["events_ms_median"]["mapper handle scan callback"] == pytest.approx(1.0)
    assert keep["events_ms_median"]["mapper handle scan end"] == pytest.approx(4.0)
    assert keep["events_ms_median"]["mapper put map"] == pytest.approx(4.0)  # 5 and 3 ms after their scans
    assert decision["events_ms_median"]["policy put goal"] == pytest.approx(19.0)
    assert "policy put goal" not in keep["events_ms_median"]
    times = list(keep["events_ms_median"].values())
    assert times == sorted(times) and next(iter(keep["events_ms_median"])) == "sim put scan"  # in order of time


def test_a_folder_without_the_sims_trace_is_a_clear_error(tmp_path):
    step_timeline = load_step_timeline()
    with pytest.raises(SystemExit, match="CSO_TRACE_DIR"):
        step_timeline.timeline(step_timeline.load_traces(tmp_path))
