"""Progress and live views off a terminal under ``FORCE_COLOR=1`` (common in CI, for coloured logs): rich takes a file
or a pipe for a terminal then (its ``is_terminal``), so ``eval``'s bar, ``status --watch``'s table, ``up``'s live view,
``train``'s bar and the count bars (``export-bag``, ``animate``, ``scenes``) were redrawn in the file, cursor moves and line erases included.
Whether the output is a terminal is ``live_view.writes_to_a_terminal``'s word (the output's own ``isatty()``): off one
each of them writes plain appended lines, coloured as ``FORCE_COLOR`` asks; on one (``TerminalFile``,
``TerminalRunner``) they are live as before, unless rich draws nothing live there (``TERM=dumb``, ``TTY_COMPATIBLE=0``,
``TTY_INTERACTIVE=0``: ``live_view.redraws_in_place``), which gets a log's lines too."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from cso_runtime.cli import app
from tests.conftest import TerminalFile, TerminalRunner

FORCED_COLOUR = {"FORCE_COLOR": "1", "TTY_COMPATIBLE": None, "NO_COLOR": None, "TERM": "xterm-256color", "COLUMNS": "120"}
"""CI's environment: colours forced, the output a file or a pipe (None: unset)."""

CURSOR_CONTROL = re.compile(r"\x1b\[(\?25[lh]|\d*[ABCDGHJK]|2K)|\r")
"""What a live display writes to redraw itself: cursor hidden or shown, moved up (``\\x1b[1A``), a line erased
(``\\x1b[2K``), a carriage return. Colours (``\\x1b[...m``) are not among them."""


def plain(text: str) -> list[str]:
    """``text``'s lines without its colours."""
    return re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines()


@pytest.fixture
def forced_colour(monkeypatch: pytest.MonkeyPatch) -> None:
    """``FORCED_COLOUR`` in this process's environment, for the code paths run in it rather than through a runner."""
    for name, value in FORCED_COLOUR.items():
        if value is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, value)


def test_eval_under_force_color_into_a_file_writes_one_plain_line_an_episode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``FORCE_COLOR=1 cso-runtime eval ... 2> eval.log`` drew its bar in the log (hidden cursor, redraws), and none
    of the one-line-an-episode a log gets. It gets those lines now; a terminal still gets the bar."""
    from cso_runtime import cli

    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)  # the test's process keeps its own handlers
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:2:0", "--max-steps", "5"]
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "file")], env=FORCED_COLOUR)
    assert r.exit_code == 0, r.output
    assert not CURSOR_CONTROL.search(r.stderr), repr(r.stderr)
    lines = plain(r.stderr)
    assert lines[0].startswith("eval: 2 episodes"), lines
    assert [line.split(" greedy-dist ")[0] for line in lines if " greedy-dist " in line] == ["[1/2]", "[2/2]"], lines
    assert any(line.startswith(f"writing {tmp_path / 'file'}/: summary.json") for line in lines), lines
    assert "\x1b[" in r.stdout, r.stdout  # the results' tables: coloured, as FORCE_COLOR asks
    on_a_terminal = TerminalRunner().invoke(app, [*args, "--out", str(tmp_path / "terminal")], env=FORCED_COLOUR)
    assert on_a_terminal.exit_code == 0, on_a_terminal.output
    assert "\x1b[?25l" in on_a_terminal.stderr and not any(line.startswith("[1/2]") for line in plain(on_a_terminal.stderr)), repr(on_a_terminal.stderr)


def test_status_watch_under_force_color_into_a_file_appends_each_table(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``FORCE_COLOR=1 cso-runtime status --watch > watch.log`` redrew one table in place in the file (cursor moves
    and erases, the earlier tables overwritten for a reader of the file). Each status is a table after the last
    there, as without FORCE_COLOR; a terminal still gets its table redrawn in place."""
    from cso_runtime import status as status_module
    from cso_runtime.status import status_of

    seen = status_of("r0", None, {"run_id": "x", "state": "running", "services": {}}, {}, set())
    seen.update(scene="gen_small_0", method="greedy-dist", state="exploring", step=7)
    answers: list[dict[str, Any] | None] = []
    monkeypatch.setattr(status_module, "reachable_target", lambda *args, **kwargs: (["tcp/127.0.0.1:7447"], "r0", None))
    monkeypatch.setattr(status_module, "query_status", lambda *args, **kwargs: answers.pop(0))
    watch = ["status", "--watch", "--period", "0.1", "--connect", "tcp/127.0.0.1:7447", "--runs-dir", str(tmp_path / "runs")]

    answers[:] = [dict(seen), dict(seen, step=8), None]  # two statuses, then the run is gone
    r = CliRunner().invoke(app, watch, env=FORCED_COLOUR)
    assert r.exit_code == 1 and not answers, r.output
    assert not CURSOR_CONTROL.search(r.stdout), repr(r.stdout)
    lines = plain(r.stdout)
    steps = [line for line in lines if re.search(r"│ step +│", line)]
    assert len(steps) == 2 and "7" in steps[0] and "8" in steps[1], r.stdout
    assert "\x1b[" in r.stdout, r.stdout  # coloured, as asked

    answers[:] = [dict(seen), dict(seen, step=8), None]
    on_a_terminal = TerminalRunner().invoke(app, watch, env=FORCED_COLOUR)
    assert on_a_terminal.exit_code == 1 and not answers, on_a_terminal.output
    assert "\x1b[?25l" in on_a_terminal.stdout and "\x1b[1A" in on_a_terminal.stdout and "\x1b[2K" in on_a_terminal.stdout, repr(on_a_terminal.stdout)


def _launcher(tmp_path: Path) -> Any:
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import find_profile, load_profile

    profile, data = load_profile(str(find_profile("lockstep")), {})
    return Launcher(profile, data, tmp_path / "run")


def test_ups_live_view_under_force_color_into_a_file_writes_its_table_once(tmp_path: Path, forced_colour: None, capsys: pytest.CaptureFixture[str]):
    """``FORCE_COLOR=1 cso-runtime up > up.log``: the live view drew in the file (a hidden cursor, redraws), and the
    launcher, taking the view for a terminal's (``on_terminal``), left out the progress lines a followed log gets.
    Off a terminal the view writes its last table once, at the end, and is no terminal's; on one it is live."""
    from rich.console import Console

    from cso_runtime.live_view import LiveView

    view = LiveView(_launcher(tmp_path))  # rich's console on stdout: capsys's file, no terminal
    view.start()
    try:
        assert not view.on_terminal  # the launcher logs the episode's progress lines then
        view.update()
    finally:
        view.stop()
    out = capsys.readouterr().out
    assert not CURSOR_CONTROL.search(out), repr(out)
    assert sum("cso-runtime" in line for line in plain(out)) == 1 and out.endswith("\n"), out  # the table, once

    terminal = TerminalFile()
    view = LiveView(_launcher(tmp_path), console=Console(file=terminal, width=120))
    view.start()
    assert view.on_terminal
    view.stop()
    assert "\x1b[?25l" in terminal.getvalue() and "cso-runtime" in terminal.getvalue(), repr(terminal.getvalue())


def test_the_training_bar_under_force_color_into_a_file_is_plain_lines(forced_colour: None, capsys: pytest.CaptureFixture[str]):
    """``FORCE_COLOR=1 cso-runtime train > train.log`` (a cluster job, CI) drew its bar in the log instead of the
    lines that say how far the run is. It writes those lines; a terminal still gets the bar."""
    from rich.console import Console

    from cso_runtime.learned import ppo

    bar = ppo._Bar(2, line_every_s=0.0)  # rich's console on stdout: capsys's file, no terminal
    bar.advance(stats="return 1.00")
    bar.advance(stats="return 2.00")
    bar.close()
    out = capsys.readouterr().out
    assert not CURSOR_CONTROL.search(out), repr(out)
    lines = plain(out)
    assert len(lines) == 2 and lines[0].startswith("PPO updates 1/2 (") and lines[1].startswith("PPO updates 2/2 (") and lines[1].endswith("return 2.00"), lines

    terminal = TerminalFile()
    bar = ppo._Bar(2, console=Console(file=terminal, width=120), line_every_s=0.0)
    bar.advance(stats="return 1.00")
    bar.close()
    assert "\x1b[?25l" in terminal.getvalue() and "PPO updates 1/2 (" not in terminal.getvalue(), repr(terminal.getvalue())


def test_a_count_bar_under_force_color_into_a_file_draws_nothing(forced_colour: None, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch):
    """The count bars of ``export-bag``, ``animate`` and ``scenes`` (``cli._count_progress``, transient: erased at its end) drew and
    erased themselves in a file under FORCE_COLOR. A log gets nothing of them; a terminal gets the bar."""
    from cso_runtime import cli

    with cli._count_progress("export") as said:
        said(1, 3)
        said(3, 3)
    assert capsys.readouterr().err == ""

    terminal = TerminalFile()
    monkeypatch.setattr("sys.stderr", terminal)
    with cli._count_progress("export") as said:
        said(1, 3)
    assert "\x1b[?25l" in terminal.getvalue() and "export" in terminal.getvalue(), repr(terminal.getvalue())


def test_no_code_outside_live_view_asks_rich_whether_it_writes_to_a_terminal():
    """One decision point: ``live_view.writes_to_a_terminal``. Rich's ``is_terminal`` (true under FORCE_COLOR for a
    file) and ``is_interactive`` (its child) are asked nowhere else in the runtime and the services."""
    import cso_runtime

    root = Path(cso_runtime.__file__).resolve().parent.parent
    asked = [
        f"{path.relative_to(root)}:{n}"
        for folder in ("cso_runtime", "services")
        for path in sorted((root / folder).rglob("*.py"))
        if path.name != "live_view.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"\.is_terminal\b|\.is_interactive\b", line.split("#")[0])
    ]
    assert not asked, asked



DUMB_TERMINALS = [
    pytest.param({"TERM": "dumb", "FORCE_COLOR": None, "TTY_COMPATIBLE": None, "TTY_INTERACTIVE": None, "NO_COLOR": None, "COLUMNS": "120"}, id="TERM=dumb"),
    pytest.param({"TERM": "xterm-256color", "FORCE_COLOR": None, "TTY_COMPATIBLE": "0", "TTY_INTERACTIVE": None, "NO_COLOR": None, "COLUMNS": "120"}, id="TTY_COMPATIBLE=0"),
    pytest.param({"TERM": "xterm-256color", "FORCE_COLOR": None, "TTY_COMPATIBLE": None, "TTY_INTERACTIVE": "0", "NO_COLOR": None, "COLUMNS": "120"}, id="TTY_INTERACTIVE=0"),
]
"""A terminal (its ``isatty()`` true) that rich draws no live display on until its end: a dumb one (Emacs' shell, some
IDE consoles), one said to be no terminal (TTY_COMPATIBLE=0), or one said not to be interactive (TTY_INTERACTIVE=0:
rich's ``is_interactive``, which alone decides whether a refresh moves the cursor back to redraw)."""


@pytest.mark.parametrize("environment", DUMB_TERMINALS)
def test_a_terminal_rich_draws_nothing_live_on_gets_the_lines_a_log_gets(environment: dict, monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """On a terminal where rich does not redraw (``TERM=dumb``, ``TTY_COMPATIBLE=0``) the bars and live tables, kept
    for a terminal since its ``isatty()`` is true, showed nothing until their end: ``train`` hours with no line,
    ``eval`` no episode, ``up`` none of its progress lines (the view taken for a terminal's), ``status --watch`` no table
    until the run was gone. Each writes the lines it writes in a log (``live_view.redraws_in_place``)."""
    from rich.console import Console

    from cso_runtime import cli
    from cso_runtime import status as status_module
    from cso_runtime.learned import ppo
    from cso_runtime.live_view import LiveView
    from cso_runtime.status import status_of

    for name, value in environment.items():
        if value is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, value)

    terminal = TerminalFile()
    bar = ppo._Bar(2, console=Console(file=terminal), line_every_s=0.0)
    bar.advance(stats="return 1.00")
    bar.advance(stats="return 2.00")
    bar.close()
    assert [line for line in plain(terminal.getvalue()) if line.startswith("PPO updates ")][:1] == ["PPO updates 1/2 (0 s, about 0 s left): return 1.00"], repr(terminal.getvalue())

    terminal = TerminalFile()
    view = LiveView(_launcher(tmp_path), console=Console(file=terminal))
    view.start()
    assert not view.on_terminal  # the launcher logs the episode's progress lines
    view.stop()
    assert sum("cso-runtime" in line for line in plain(terminal.getvalue())) == 1, repr(terminal.getvalue())

    seen = status_of("r0", None, {"run_id": "x", "state": "running", "services": {}}, {}, set())
    seen.update(scene="gen_small_0", method="greedy-dist", state="exploring", step=7)
    answers: list[dict[str, Any] | None] = [dict(seen), dict(seen, step=8), None]
    monkeypatch.setattr(status_module, "reachable_target", lambda *args, **kwargs: (["tcp/127.0.0.1:7447"], "r0", None))
    monkeypatch.setattr(status_module, "query_status", lambda *args, **kwargs: answers.pop(0))
    monkeypatch.setattr(status_module.time, "sleep", lambda s: None)
    terminal = TerminalFile()
    code = status_module.status_main(["tcp/127.0.0.1:7447"], "r0", as_json=False, watch=True, runs_dir=tmp_path, period_s=0.1, console=Console(file=terminal))
    assert code == 1 and not answers
    assert len([line for line in plain(terminal.getvalue()) if re.search(r"│ step +│", line)]) == 2, repr(terminal.getvalue())  # a table a status

    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda: None)
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:2:0", "--max-steps", "5", "--out", str(tmp_path / "eval")]
    r = TerminalRunner().invoke(app, args, env=environment)
    assert r.exit_code == 0, r.output
    assert [line.split(" greedy-dist ")[0] for line in plain(r.stderr) if " greedy-dist " in line] == ["[1/2]", "[2/2]"], repr(r.stderr)
