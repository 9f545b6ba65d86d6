"""``up``'s live view: a rich table of the episode's progress and each service's health, refreshed a few times a
second, with the launcher's log lines printed above it rather than inside it."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import sys
import time
from typing import TYPE_CHECKING, Any

from cso_runtime.config import EXIT_INTERRUPTED
from cso_runtime.messages import EPISODE_OVER
from cso_runtime.pace import real_time_words

log = logging.getLogger("cso.launcher")

if TYPE_CHECKING:

    from rich.console import Console
    from rich.live import Live
    from rich.table import Table

    from cso_runtime.launcher import Launcher
    from cso_runtime.messages import EpisodeStatusMsg


NO_GROUND_TRUTH = "n/a: a real robot (no ground truth)"
"""What the tables say of coverage on a run with no ground truth (not ``run_profile.measures_coverage``: a real robot's,
or a referee's of one's own), where ``coverage_pct`` is 0 (``status --json``, ``summary.json``,
``episodes.csv``): a "0.00 %" beside a map being explored read as a failure."""
NO_OWN_GROUND_TRUTH = "n/a: the run's own referee measured no coverage (no ground truth)"
"""``NO_GROUND_TRUTH`` where the run's referee is one of one's own, no real robot (report.html: ``of_an_own_referee``;
``status`` and the live view: the launcher's status's ``referee``, ``no_ground_truth_words``)."""


def no_ground_truth_words(referee: str | None) -> str:
    """What ``status`` and the live view say of a run's coverage where it has no ground truth: ``NO_OWN_GROUND_TRUTH``
    where the launcher's status says its referee is one of one's own (``launcher_status.referee``:
    ``run_profile.OWN_REFEREE``), else ``NO_GROUND_TRUTH`` (a real robot's, or no launcher answered to say)."""
    from cso_runtime.run_profile import OWN_REFEREE  # noqa: PLC0415 - loads the scenes' code: only where it is said

    return NO_OWN_GROUND_TRUTH if referee == OWN_REFEREE else NO_GROUND_TRUTH


NO_COVERAGE = "n/a"
"""``NO_GROUND_TRUTH`` in a table's coverage cell (``runs``' "cover %", report.html's and the console's Table 1 and
episodes): the one word, its reason said in the table's definitions or title."""


def pace_text(real_time_factor: float | None) -> str:
    """``, 1.00x real time`` (simulated over wall-clock seconds), or nothing when unknown (a real robot, too early)."""
    return "" if real_time_factor is None else f", {real_time_words(real_time_factor)}"


def robot_time_words(step: int, sim_step_s: float | None) -> list[str]:
    """``["10.5 s robot time"]`` for a simulated episode (``sim_step_s`` a step), ``[]`` on a real robot: its steps are
    its scans (about 10 Hz on the LIMO), not control periods, so a step count says nothing of its time."""
    return [] if sim_step_s is None else [f"{step * sim_step_s:.1f} s robot time"]


def ended_goal_words(status: EpisodeStatusMsg) -> str | None:
    """``none: the episode ended (coverage)`` once the episode is over (its last status keeps its last goal, which no one
    drives to any more), else None: the goal to show."""
    if status.state not in EPISODE_OVER:
        return None
    verb = "ended" if status.state == "done" else status.state
    why = status.terminated_by or status.reason
    return f"none: the episode {verb}" + (f" ({why})" if why else "")


def progress_line(status: EpisodeStatusMsg, sim_step_s: float | None, real_time_factor: float | None = None, coverage_measured: bool | None = None) -> str:
    """The episode's progress in one log line (the live view's figures, for a log that is followed). ``sim_step_s``:
    the simulated time of a step, None on a real robot. ``coverage_measured``: whether the run has a ground truth
    (``run_profile.measures_coverage``; None: a simulated one's, ``sim_step_s`` given); its coverage is left out if not."""
    if coverage_measured is None:
        coverage_measured = sim_step_s is not None
    from cso_runtime.status import pose_words  # noqa: PLC0415 - as the view's render: status opens Zenoh sessions

    goal_m = status.goal_in_map_frame
    goal = ended_goal_words(status) or ("none" if goal_m is None else f"({goal_m[0]:.2f}, {goal_m[1]:.2f}) m")
    pose_m, twist = status.pose_in_map_frame, status.twist
    pose = pose_words(None if pose_m is None else pose_m.as_list(), None if twist is None else [twist.linear_mps, twist.angular_radps])
    rate = f" ({status.explored_area_m2 / status.step:.3f} m2/step)" if status.step else ""
    time_words = ", ".join(robot_time_words(status.step, sim_step_s))
    when = f" ({time_words}{pace_text(real_time_factor)})" if time_words else ""
    return (
        f"step {status.step}{when}: " + (f"coverage {status.coverage_pct:.1f} %, " if coverage_measured else "") +
        f"{status.explored_area_m2:.2f} m2 explored{rate}, path {status.path_length_m:.2f} m, pose {pose}, {status.decisions} decisions, goal {goal}"
    )


def console_that_survives_its_reader(stderr: bool = False, tell: bool = True) -> Console:
    """Rich's console on stdout (or stderr), but one whose broken pipe (``up | head``: the reader gone) is not rich's
    ``SystemExit(1)``, which flew through the launcher's clean-up and left the services unstopped and the run
    unfinished, and stopped ``eval`` after an episode with no results. Quiet from then on: nothing more is written.
    ``tell``: the broken pipe is an ``OSError`` for the caller to handle (``LiveView.terminal_gone``); else the work
    goes on as if the lines were read (``eval``'s progress)."""
    from rich.console import Console  # noqa: PLC0415

    class QuietOnBrokenPipe(Console):
        def on_broken_pipe(self) -> None:
            self.quiet = True
            if tell:
                raise BrokenPipeError(errno.EPIPE, os.strerror(errno.EPIPE))

    return QuietOnBrokenPipe(stderr=stderr)


PIPED_TABLE_MIN_WIDTH = 120
"""The fewest columns a table is laid out in off a terminal (rich's own default there is 80, which cut the last columns)."""


def writes_to_a_terminal(console: Console) -> bool:
    """Whether ``console`` writes to a terminal: its file's own ``isatty()``. Not rich's ``is_terminal``, which
    ``FORCE_COLOR`` (and rich 14's ``TTY_COMPATIBLE``) make true for a file or a pipe: CI sets ``FORCE_COLOR=1`` for
    coloured logs, and ``FORCE_COLOR=1 runs > runs.txt`` was laid out in 80 columns, its cells folded. The colours
    stay as ``FORCE_COLOR`` asks; only the layout is a file's."""
    try:
        return bool(console.file.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, a closed file: no terminal
        return False


def redraws_in_place(console: Console) -> bool:
    """Whether a display that redraws itself (``eval``'s and ``train``'s bars, ``status --watch``, ``up``'s live view,
    the count bars) is drawn in place on ``console``: it writes to a terminal (``writes_to_a_terminal``) that rich draws
    in place on. Not a dumb one (``TERM=dumb``: Emacs' shell, some IDE consoles), one rich is told is no terminal
    (``TTY_COMPATIBLE=0``, ``FORCE_COLOR`` empty) nor one it is told is not interactive (``TTY_INTERACTIVE=0``, rich's
    ``is_interactive``: its live display moves the cursor back to redraw only there, and draws nothing before its end
    elsewhere): there rich draws a live display only once, at its end, so a bar kept for such a terminal showed nothing
    for a whole run (a training of hours), and none of the lines a log gets either. Those get the log's lines; the
    layout of a table stays a terminal's (``fit_off_a_terminal``). Rich's own rule (``Live.refresh``, its
    ``process_renderables``): a refresh draws where ``is_terminal and not is_dumb_terminal``, in place where
    ``is_interactive``; Jupyter and IDLE are no terminal to its ``is_terminal``."""
    return writes_to_a_terminal(console) and console.is_terminal and not console.is_dumb_terminal and console.is_interactive


def fit_off_a_terminal(console: Console, *tables: Any) -> Console:
    """``console`` (returned, for ``fit_off_a_terminal(console, table).print(table)``), made wide enough off a terminal
    (a file, a pipe, CI) for ``tables`` to be written with no cell folded or wrapped, nor a title: at least
    ``PIPED_TABLE_MIN_WIDTH`` columns, and as wide as the widest table needs, so that ``grep`` and ``awk`` find each
    row whole on its line (a long scene path or reason folded at 120 columns broke them). A table whose title is wider
    than its columns is given that width (``min_width``), as a title wider than its table wraps. On a terminal
    nothing changes: it keeps its width (``COLUMNS`` where set), and cells fold there as before. Whether it is a
    terminal is ``writes_to_a_terminal``'s word, not rich's (``FORCE_COLOR=1 runs > runs.txt``, common in CI)."""
    if writes_to_a_terminal(console):
        return console
    from rich.measure import Measurement  # noqa: PLC0415
    from rich.text import Text  # noqa: PLC0415

    wide = console.options.update_width(10**6)
    for table in tables:
        title = getattr(table, "title", None)
        if title is not None:
            said = title.cell_len if isinstance(title, Text) else console.render_str(str(title)).cell_len
            table.min_width = max(table.min_width or 0, said)
    console.width = max(console.width, PIPED_TABLE_MIN_WIDTH, *(Measurement.get(console, wide, table).maximum for table in tables))
    return console


def table_console(*tables: Any) -> Console:
    """Rich's console on stdout for commands that print tables (``runs``, ``status``, ``eval``, ``scenes``,
    ``doctor``, ``dataflow``): ``console_that_survives_its_reader`` (``runs | head``: the reader gone ends the
    command quietly), wide enough off a terminal for ``tables`` (``fit_off_a_terminal``: ``runs > runs.txt`` has each
    cell on its one line); a terminal keeps its width."""
    return fit_off_a_terminal(console_that_survives_its_reader(), *tables)


def progress_with_stats_below(*columns: Any, markup: bool = False, **kwargs: Any) -> Any:
    """A rich ``Progress`` that shows each task's ``stats`` field on a line of its own under its bar, cut to the
    terminal's width: after the bar, on one line, a long text (the training figures, 64 characters; eval's last
    episode or its "writing OUT/: summary.json, ..." line) squeezed rich's columns in an 80-column terminal until the
    count, the bar and the times were gone. ``markup``: the field is rich markup (eval's red FAILED), else plain text.
    The bars of ``train`` (``learned.ppo._Bar``) and ``eval`` (``evaluation.RichProgress``)."""
    from rich.progress import Progress  # noqa: PLC0415
    from rich.text import Text  # noqa: PLC0415

    class ProgressWithStatsBelow(Progress):
        def get_renderables(self) -> Any:
            yield self.make_tasks_table(self.tasks)
            for task in self.tasks:
                if stats := task.fields.get("stats"):
                    text = Text.from_markup("  " + str(stats)) if markup else Text("  " + str(stats))
                    text.no_wrap, text.overflow = True, "ellipsis"
                    yield text

    return ProgressWithStatsBelow(*columns, **kwargs)


class LiveView:
    """A rich table refreshed a few times a second: episode progress and service health."""

    def __init__(self, launcher: Launcher, console: Console | None = None) -> None:
        self.launcher = launcher
        self.console = console  # None: rich's console on stdout
        self._live: Live | None = None
        """Rich's live display, on a terminal only (``redraws_in_place``), from ``start`` on."""
        self._in_a_file: Console | None = None
        """Off a terminal (a file, a pipe, CI; under ``FORCE_COLOR`` too; a dumb terminal), the console the last table is written to
        once, by ``stop``: no live display there, whose redraws (cursor moves, line erases) landed in the file."""
        self._last = 0.0
        self._rerouted: list[tuple[logging.StreamHandler, Any]] = []
        """Log handlers on stderr sent through the live display while it runs, with the stream to give back."""

    BAR_CELLS = 20
    """Width of the coverage bar, in characters."""

    def render(self) -> Table:
        """The table as the launcher's state stands now (rebuilt on each refresh, not updated in place)."""
        from rich.markup import escape  # noqa: PLC0415
        from rich.progress_bar import ProgressBar  # noqa: PLC0415
        from rich.table import Table  # noqa: PLC0415

        from cso_runtime.status import (  # noqa: PLC0415
            COMMAND_NODE_NOTE,
            NOT_ANSWERING,
            after_end_words,
            lost_result_words,
            pose_words,
            presence_words,
            status_of,
            waiting_note,
        )

        la = self.launcher
        st = la.status
        # As `status` reads the launcher's status: the services this run left to other processes, and which of them
        # the episode waits for while none serves it (a profile with no policy: step 0 would wait with every row up).
        seen = status_of(la.profile.robot, None if st is None else st.to_dict(), la.launcher_status().to_dict(), {}, la.alive_services)
        waits = waiting_note(seen["waiting_for"], None if st is not None and st.state in EPISODE_OVER else seen["pause"])
        # Short title, no header: on an 80-column terminal a title wider than the table wraps.
        t = Table(title=f"cso-runtime {la.run_id}", show_header=False)
        t.add_column("field")
        t.add_column("value", overflow="fold")  # a narrow terminal wraps a long URL or path, never cuts it with an ellipsis
        t.add_row("robot / method", escape(f"{la.profile.robot} / {la.profile.method}, {'lockstep' if la.profile.lockstep else 'real time'}"))
        if st is None:
            t.add_row("state", escape("starting" + waits))
        else:
            goal_m = st.goal_in_map_frame
            goal = "-" if goal_m is None else f"({goal_m[0]:.2f}, {goal_m[1]:.2f}) m"
            if la.exit_code == EXIT_INTERRUPTED and st.state not in EPISODE_OVER:  # the last table after Ctrl-C or `down`
                state = "interrupted: no results"  # the step row says where; the log above it, more
            else:
                state = st.state + (f" ({st.terminated_by})" if st.terminated_by else "") + (f": {st.reason}" if st.reason else "") + waits
            t.add_row("state", escape(state))
            t.add_row("scene", escape(st.scene))
            since = f"{time.monotonic() - la.started_s:.0f} s since start"
            when = ", ".join([*robot_time_words(st.step, la.sim_step_s), since])
            ended_at = la.ended_at_step()  # a real robot's scans go on after its episode's end: the step it ended at
            steps = st.step if ended_at is None else ended_at
            t.add_row("step", f"{st.step} ({when}{pace_text(la.real_time_factor)})" + after_end_words({"step": st.step, "ended_at_step": ended_at}))
            if not la.coverage_measured:
                t.add_row("coverage", no_ground_truth_words(seen["referee"]))
            else:
                coverage = Table.grid(padding=(0, 1))
                coverage.add_row(ProgressBar(total=100.0, completed=min(st.coverage_pct, 100.0), width=self.BAR_CELLS), f"{st.coverage_pct:.1f} %")
                t.add_row("coverage", coverage)
            for k, v in (
                ("explored", f"{st.explored_area_m2:.2f} m2" + (f", {st.explored_area_m2 / steps:.3f} m2/step" if steps else "")),
                ("path length", f"{st.path_length_m:.2f} m"),
                ("goal", ended_goal_words(st) or goal + ("" if la.path_ahead_m is None or st.goal_xy_m is None else f", {la.path_ahead_m:.2f} m ahead on the path")),
                ("pose", pose_words(seen["pose"], seen["twist"])),  # in the map frame, as the goal and `status`
                ("decisions", f"{st.decisions} (last {st.last_decision_ms:.1f} ms)"),
            ):
                t.add_row(k, escape(v))  # text, not markup: a scene file's name may hold brackets
        for lost in seen["lost_results"]:  # an episode before this one ended, its result lost: as `status` says it
            t.add_row("lost result", escape(lost_result_words(lost, seen["referee"])))
        for c in la.children:
            # its process runs, its token not there: starting, or gone since it came up (stopped, hung) until the hang check kills it
            waits = NOT_ANSWERING if c.came_up else "starting"
            health = "up" if c.alive and c.name in la.alive_services else (waits if c.alive else ("gave up" if c.gave_up else "restarting"))
            if c.command is not None and c.alive and not (c.awaits_token and c.name not in la.alive_services):
                health = "running"
            note = la.service_notes.get(c.name) or (COMMAND_NODE_NOTE if c.command is not None else None)
            t.add_row(f"[bold]{c.name}", f"{health}, pid {c.proc.pid if c.proc else '-'}, restarts {c.restarts}" + (f"; {escape(note)}" if note else ""))
        for name, service in seen["services"].items():
            if service.get("outside"):  # not started by this run: no pid, no restarts here
                over = st.state if st is not None and st.state in EPISODE_OVER else ""
                t.add_row(f"[bold]{name}", escape(", ".join(presence_words(name, service, seen["waiting_for"], episode_over=over))))
        return t

    def start(self) -> None:
        from rich.live import Live  # noqa: PLC0415

        stderr = sys.stderr
        console = self.console if self.console is not None else console_that_survives_its_reader()
        if not redraws_in_place(console):  # not rich's is_terminal, which FORCE_COLOR=1 (CI) makes true for a file
            self._in_a_file = console
            return
        self._live = Live(self.render(), console=console, refresh_per_second=4, transient=False)
        self._live.start()
        if sys.stderr is not stderr:
            # On a terminal rich replaces sys.stderr with a proxy that prints above the table; a log handler
            # still holds the old stream, and its lines would land inside the table and shift its redraws.
            for handler in logging.getLogger().handlers:
                if isinstance(handler, logging.StreamHandler) and handler.stream is stderr:
                    self._rerouted.append((handler, handler.setStream(sys.stderr)))

    @property
    def on_terminal(self) -> bool:
        """The table is redrawn in place on a terminal; in a file it is written once, at the end."""
        return self._live is not None

    def update(self) -> None:
        if self._live is not None and time.monotonic() - self._last > 0.25:
            self._last = time.monotonic()
            try:
                self._live.update(self.render())
            except OSError as exc:
                self.terminal_gone(exc)

    def stop(self) -> None:
        if self._in_a_file is not None:
            console, self._in_a_file = self._in_a_file, None
            try:
                table = self.render()
                fit_off_a_terminal(console, table).print(table)  # the last table, once: no cell folded
            except OSError as exc:
                self.terminal_gone(exc)
        if self._live is not None:
            live = self._live
            try:
                live.update(self.render())
                self.give_back_log_streams()
                live.stop()
            except OSError as exc:
                self.terminal_gone(exc)

    def give_back_log_streams(self) -> None:
        """Give the log handlers ``start`` sent through the live display their own streams back."""
        for handler, stream in self._rerouted:
            handler.setStream(stream)
        self._rerouted.clear()

    def terminal_gone(self, exc: OSError) -> None:
        """The terminal it draws on is gone (closed: EIO; a pipe's reader gone: EPIPE): no more drawing, said once in
        the launcher's log (its file keeps it). The run goes on, or stops as the terminal's SIGHUP asked, never with
        this error: it would skip the services' stop and the run file's end."""
        live, self._live = self._live, None
        self.give_back_log_streams()
        if live is not None:
            with contextlib.suppress(Exception):  # its refresh thread, which would meet the same error
                live.stop()
        log.warning("the live view stops: its terminal is gone (%s)", exc.strerror or exc)
