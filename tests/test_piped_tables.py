"""Rich tables written off a terminal (``runs > runs.txt``, ``status | grep``, CI logs) keep each cell whole on its
line, as ``dataflow``'s does (``live_view.table_console``); on a terminal they fold to its width as before."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rich.console import Console
from rich.table import Table
from typer.testing import CliRunner

from cso_runtime.cli import app
from tests.conftest import TerminalFile, TerminalRunner, super_large_summary

NO_TERMINAL = {"COLUMNS": "80", "FORCE_COLOR": None, "TTY_COMPATIBLE": None}
"""CliRunner's output, whatever the environment the tests run in (None: unset): no terminal, as a file or a pipe."""
TERMINAL = {"COLUMNS": "80", "TTY_COMPATIBLE": "1", "FORCE_COLOR": "1", "NO_COLOR": "1"}
"""An 80-column terminal, with ``TerminalRunner`` (whose output's ``isatty()`` is true; TTY_COMPATIBLE for rich 14,
FORCE_COLOR for rich 13, for rich's own idea of one)."""
LONG_SCENE = "/data/plans/" + "/".join(f"building_{i}_floor_plans_scanned_in_2026" for i in range(4)) + "/level_3.yaml"
LONG_REASON = "refused: " + ", ".join(f"service policy_{i} could not import tests.own_service_example:OwnPolicy{i}" for i in range(3))


def a_failed_run(runs: Path, run_id: str) -> None:
    """A run folder as ``up`` leaves one refused before any service: run.json with its reason, profile.yaml."""
    d = runs / run_id
    (d / "logs").mkdir(parents=True)
    info = {"run_id": run_id, "run_dir": str(d), "robot": "r0", "launcher_pid": 2**22 + 12345, "state": "stopped", "outcome": "failed", "reason": LONG_REASON}
    (d / "run.json").write_text(json.dumps(info))
    (d / "profile.yaml").write_text(f"name: map\nrobot: r0\nscene: {LONG_SCENE}\nmethod: cso\n")


def plain(text: str) -> list[str]:
    return re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines()


def test_runs_written_to_a_file_keeps_a_long_scene_and_reason_on_their_lines(tmp_path: Path):
    """``runs > runs.txt`` folded a long scene path and a refused run's reason at 120 columns, so ``grep`` found half a
    path and ``awk`` half a row. Off a terminal the table is as wide as its cells; an 80-column terminal folds them."""
    runs = tmp_path / "runs"
    a_failed_run(runs, "20261207-090000-map-r0")
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env=NO_TERMINAL)
    assert r.exit_code == 0, r.output
    lines = plain(r.output)
    assert any(f"{LONG_SCENE}, cso" in line for line in lines), r.output
    row = next(line for line in lines if "20261207-090000-map-r0" in line)
    assert f"failed: {LONG_REASON}" in row and "m2/step" in r.output, r.output
    on_a_terminal = TerminalRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env=TERMINAL)
    assert on_a_terminal.exit_code == 0 and max(len(line) for line in plain(on_a_terminal.output)) <= 80, on_a_terminal.output
    assert not any(LONG_SCENE in line for line in plain(on_a_terminal.output)), on_a_terminal.output  # folded there, as before


def test_force_color_off_a_terminal_keeps_the_colours_and_lays_the_table_out_as_a_files(tmp_path: Path):
    """``FORCE_COLOR=1 cso-runtime runs > runs.txt`` (CI sets FORCE_COLOR for coloured logs) still folded the table at
    80 columns: rich takes a forced colour for a terminal. Off a terminal is the output's own ``isatty()``
    (``live_view.writes_to_a_terminal``): the table is as wide as its cells, coloured as FORCE_COLOR asks; and a
    forced terminal console writing to a file is laid out as a file's."""
    from cso_runtime.live_view import fit_off_a_terminal, writes_to_a_terminal

    runs = tmp_path / "runs"
    a_failed_run(runs, "20261207-090000-map-r0")
    r = CliRunner().invoke(app, ["runs", "--runs-dir", str(runs)], env={"COLUMNS": None, "FORCE_COLOR": "1", "TTY_COMPATIBLE": None, "NO_COLOR": None})
    assert r.exit_code == 0 and "\x1b[" in r.output, r.output  # coloured, as asked
    lines = plain(r.output)
    assert any(f"{LONG_SCENE}, cso" in line for line in lines), r.output
    assert any(f"failed: {LONG_REASON}" in line for line in lines), r.output
    forced = Console(file=io.StringIO(), width=80, force_terminal=True)
    assert forced.is_terminal and not writes_to_a_terminal(forced)
    wide = Table()
    wide.add_column("reason", overflow="fold")
    wide.add_row(LONG_REASON)
    assert fit_off_a_terminal(forced, wide).width == len(LONG_REASON) + 4
    assert writes_to_a_terminal(Console(file=TerminalFile())) and not writes_to_a_terminal(Console(file=io.StringIO(), force_terminal=True))


def test_doctor_written_to_a_file_keeps_each_checks_detail_on_its_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``doctor > report.txt`` laid its table out in 80 columns: a long detail (a path, a library list) was folded."""
    from cso_runtime import doctor

    detail = f"{LONG_SCENE} is writable and holds {LONG_REASON}"
    monkeypatch.setattr(doctor, "checks", lambda runs_dir: [("runs folder", lambda: detail)])
    r = CliRunner().invoke(app, ["doctor", "--runs-dir", str(tmp_path)], env=NO_TERMINAL)
    assert r.exit_code == 0 and any(detail in line for line in plain(r.output)), r.output
    on_a_terminal = TerminalRunner().invoke(app, ["doctor", "--runs-dir", str(tmp_path)], env=TERMINAL)
    assert on_a_terminal.exit_code == 0 and max(len(line) for line in plain(on_a_terminal.output)) <= 80, on_a_terminal.output


def test_scenes_written_to_a_file_keeps_a_long_plan_name_on_its_line(tmp_path: Path):
    """``scenes DIR > list.txt``: a plan's long name was folded in 80 columns, and so was the title naming the folder."""
    floor = np.full((60, 80, 3), (127, 127, 127), np.uint8)
    floor[5:55, 5:75] = (195, 195, 194)
    floor[28:32, 38:42] = (255, 216, 0)  # the start square
    name = "_".join(f"wing{i}_second_floor_survey" for i in range(6))
    Image.fromarray(floor).save(tmp_path / f"{name}.png")
    r = CliRunner().invoke(app, ["scenes", str(tmp_path)], env=NO_TERMINAL)
    lines = plain(r.output)
    assert any(name in line and "unusable" not in line for line in lines), r.output
    assert any(f"scenes of {tmp_path}" in line for line in lines), r.output
    on_a_terminal = TerminalRunner().invoke(app, ["scenes", str(tmp_path)], env=TERMINAL)  # folded there, as before
    assert "wing0_second_f" in on_a_terminal.output and not any(name in line for line in plain(on_a_terminal.output)), on_a_terminal.output


def test_status_written_to_a_file_keeps_a_long_scene_and_reason_on_their_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``status > now.txt`` (``status_main`` with rich's console off a terminal) folded the value column at 80."""
    from cso_runtime import status as status_module
    from cso_runtime.status import status_main, status_of

    seen = status_of("r0", None, {"run_id": "x", "state": "running", "services": {}}, {}, set())
    seen.update(scene=LONG_SCENE, method="cso", state="failed", reason=LONG_REASON)
    monkeypatch.setattr(status_module, "reachable_target", lambda *args, **kwargs: (["tcp/127.0.0.1:7447"], "r0", None))
    monkeypatch.setattr(status_module, "query_status", lambda *args, **kwargs: dict(seen))
    for terminal in (False, True):
        out = TerminalFile() if terminal else io.StringIO()
        console = Console(file=out, width=80, force_terminal=terminal, color_system=None)
        assert status_main([], "r0", as_json=False, watch=False, runs_dir=tmp_path, console=console) == 0
        lines = plain(out.getvalue())
        if terminal:
            assert max(len(line) for line in lines) <= 80 and not any(LONG_SCENE in line for line in lines), out.getvalue()
        else:
            assert any(f"{LONG_SCENE} / cso" in line for line in lines) and any(LONG_REASON in line for line in lines), out.getvalue()


def test_eval_results_tables_written_to_a_file_are_whole_tables_with_no_cell_cut():
    """``eval``'s tables (``print_table_or_rows``) off a terminal were laid out in 120 columns: a table wider than that
    came out as rows of "name value" instead of the table. Off a terminal the table is printed whole; an 80-column
    terminal still gets the rows, every number whole."""
    from cso_runtime.evaluation import print_table_or_rows

    def table() -> Table:
        t = Table(title="Table 1 metrics")
        t.add_column("method", no_wrap=True)
        for i in range(12):
            t.add_column(f"metric number {i}", justify="right")
        t.add_row("cso-no-info", *(f"{1000 + i}.5678 ± 0.0425" for i in range(12)))
        return t

    out = io.StringIO()
    print_table_or_rows(Console(file=out, width=120, color_system=None), table(), labels=1)
    lines = plain(out.getvalue())
    header = next(line for line in lines if "metric number 0" in line)
    row = next(line for line in lines if "cso-no-info" in line)
    assert "│" in row and "metric number 11" in header and row.count("± 0.0425") == 12 and "…" not in out.getvalue(), out.getvalue()  # one row
    terminal = TerminalFile()
    print_table_or_rows(Console(file=terminal, width=80, force_terminal=True, color_system=None), table(), labels=1)
    assert "cso-no-info: metric number 0 1000.5678 ± 0.0425" in terminal.getvalue(), terminal.getvalue()


def test_fit_off_a_terminal_widens_for_cells_and_title_and_leaves_a_terminal_as_it_is():
    from cso_runtime.live_view import fit_off_a_terminal

    table = Table(title="runs in " + LONG_SCENE)
    table.add_column("state", overflow="fold")
    table.add_row("x" * 30)
    off = fit_off_a_terminal(Console(file=io.StringIO(), width=80), table)
    assert off.width >= len("runs in " + LONG_SCENE) and table.min_width == len("runs in " + LONG_SCENE)
    wide = Table()
    wide.add_column("reason", overflow="fold")
    wide.add_row(LONG_REASON)
    assert fit_off_a_terminal(Console(file=io.StringIO(), width=80), wide).width == len(LONG_REASON) + 4  # its borders and padding
    assert fit_off_a_terminal(Console(file=io.StringIO(), width=80), Table()).width == 120  # never under 120: the last columns whole
    on = Console(file=TerminalFile(), width=80, force_terminal=True)
    kept = Table(title="runs in " + LONG_SCENE)
    assert fit_off_a_terminal(on, kept, wide).width == 80 and kept.min_width is None


def test_ups_last_table_written_to_a_file_keeps_a_long_scene_and_reason_on_their_lines(tmp_path: Path):
    """``up > up.log`` writes its live view once, at the end: laid out in rich's 80 columns there, a long scene path
    and the referee's reason were folded. Off a terminal it is as wide as its cells; a terminal keeps its width."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.live_view import LiveView
    from cso_runtime.messages import EpisodeStatusMsg
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    launcher = Launcher(profile, data, tmp_path / "run")
    launcher.status = EpisodeStatusMsg(state="exploring", step=3, scene=LONG_SCENE, method="greedy-dist", reason=LONG_REASON)
    for terminal in (False, True):
        out = TerminalFile() if terminal else io.StringIO()
        view = LiveView(launcher, console=Console(file=out, width=80, force_terminal=terminal, color_system=None))
        view.start()
        view.stop()
        lines = plain(out.getvalue())
        assert any(f"cso-runtime {launcher.run_id}" in line for line in lines), out.getvalue()  # the table, either way
        if terminal:
            assert not any(LONG_SCENE in line for line in lines), out.getvalue()
        else:
            assert any(LONG_SCENE in line for line in lines) and any(LONG_REASON in line for line in lines), out.getvalue()


def test_eval_table_1_written_to_a_file_keeps_its_spreads_however_wide(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``eval > results.txt``: Table 1 with its spreads ("3.3902 ± 0.0100") wider than the console's 120 columns was
    swapped for the means alone before the console was widened for it, so a file lost the spreads that it had room
    for (the table is as wide as its cells off a terminal). An 80-column terminal still gets the means alone."""
    from cso_runtime import evaluation
    from cso_runtime.evaluation import print_summary

    summary = super_large_summary()
    for terminal in (False, True):
        out = TerminalFile() if terminal else io.StringIO()
        monkeypatch.setattr(evaluation, "table_console", lambda f=out, t=terminal: Console(file=f, width=80 if t else 120, force_terminal=t, color_system=None))
        print_summary(summary, tmp_path)
        lines = plain(out.getvalue())
        row1 = next(line for line in lines if "greedy-dist" in line and "super_large" in line)
        if terminal:
            assert "±" not in out.getvalue(), out.getvalue()
        else:
            assert "│" in row1 and "3.3902 ± 0.0100" in row1 and "…" not in out.getvalue(), out.getvalue()
