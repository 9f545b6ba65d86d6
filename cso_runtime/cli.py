"""The ``cso-runtime`` command line (typer). Each command is a thin wrapper over library code."""

from __future__ import annotations

import sys

from cso_runtime import exit_interrupted_early as _interrupted_early  # the package's own: imported already

try:
    import shlex
    import time
    from collections.abc import Callable, Iterator, Mapping
    from contextlib import contextmanager
    from pathlib import Path
    from typing import TYPE_CHECKING, Any, NoReturn, overload

    import typer

    from cso_runtime.frame_names import FRAME_OPTIONS  # export-bag's options, shared with `service foxglove_bridge`
except KeyboardInterrupt:
    _interrupted_early()

if TYPE_CHECKING:
    from cso_runtime.config import Settings
    from cso_runtime.learned.ppo import Args
    from cso_runtime.run_profile import Profile
    from cso_runtime.runs import LogLine
    from cso_runtime.status import RunTarget

app = typer.Typer(
    name="cso-runtime",
    help="Active scene mapping with CSO: evaluate, train, and run the Zenoh services.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)

# --- shell completion (`cso-runtime --install-completion`): cheap lookups, no torch, no Zenoh session ---------


def _complete_profiles(incomplete: str) -> list[str]:
    from cso_runtime.run_profile import profile_names  # noqa: PLC0415

    return [n for n in profile_names() if n.startswith(incomplete)]


def _complete_methods(incomplete: str) -> list[str]:
    """One method's name (``up --method``)."""
    from cso_runtime.policies import BASELINES, LEARNED_METHODS  # noqa: PLC0415

    return [m for m in [*BASELINES, *LEARNED_METHODS] if m.startswith(incomplete)]


def _complete_method_list(incomplete: str) -> list[str]:
    """Method names and groups; after a comma (``eval --method a,b``) the last one is completed."""
    from cso_runtime.policies import METHOD_GROUPS  # noqa: PLC0415

    head, _, last = incomplete.rpartition(",")
    prefix = f"{head}," if head else ""
    return [prefix + m for m in [*_complete_methods(last), *METHOD_GROUPS] if m.startswith(last)]


def _complete_run_ids(ctx: typer.Context, incomplete: str) -> list[str]:
    from cso_runtime.runs import run_dirs  # noqa: PLC0415

    runs_dir = Path(ctx.params.get("runs_dir") or "runs")
    return [d.name for d in reversed(run_dirs(runs_dir)) if d.name.startswith(incomplete)]


def _complete_services(ctx: typer.Context, incomplete: str) -> list[str]:
    """A service of the profile given (``--without``), but the referees, which a run cannot go without."""
    from cso_runtime.config import ConfigError, load_yaml  # noqa: PLC0415
    from cso_runtime.run_profile import REFEREES, find_profile  # noqa: PLC0415

    try:
        services = load_yaml(find_profile(ctx.params.get("profile") or "sim")).get("services") or {}
    except (ConfigError, OSError, ValueError):
        return []
    given = ctx.params.get("without") or []
    return [n for n in services if n.startswith(incomplete) and n not in REFEREES and n not in given]


def _complete_log_services(ctx: typer.Context, incomplete: str) -> list[str]:
    """The services with a log in the run ``logs`` would read."""
    from cso_runtime.runs import RunError, log_files, resolve_run  # noqa: PLC0415

    try:
        names = list(log_files(resolve_run(Path(ctx.params.get("runs_dir") or "runs"), ctx.params.get("run"))))
    except RunError:
        return []
    given = ctx.params.get("services") or []
    return [n for n in names if n.startswith(incomplete) and n not in given]


METHODS_HELP = (
    "Comma-separated methods: the baselines greedy-dist, greedy-info, utility, random; the learned cso and its Table 2"
    " ablations cso-no-info, cso-no-mask, cso-sm, cso-vdm, gnn-baseline; or the groups all, baselines, learned;"
    " or a goal selector of your own as module.path:Attribute (importable: on PYTHONPATH or installed; docs/own-method.md)"
)
"""Every method by name (a test checks it against ``policies``), so ``--help`` need not import them."""

DEFAULT_TRAIN_CONFIG = Path("configs/train.yaml")
PACKAGED_CONFIGS = Path(__file__).resolve().parent / "data"
"""``configs/train.yaml``, ``eval.yaml`` and ``robot_sim.yaml`` inside the package (links in the repository), so that
an installed package finds the files the help, README and docs name: the recipe of the shipped weights, the documented
defaults of every exploration and MuJoCo parameter."""
PACKAGED_TRAIN_CONFIG = PACKAGED_CONFIGS / "train.yaml"


@overload
def _packaged_if_missing(path: Path) -> Path: ...
@overload
def _packaged_if_missing(path: None) -> None: ...
def _packaged_if_missing(path: Path | None) -> Path | None:
    """``configs/NAME.yaml`` as the help names it, run outside the repository (where there is no such file): the
    package's own copy, said on stderr. Any other path is left as given (a missing one is then a clear error)."""
    if path is None or path.is_file() or path.parent != Path("configs") or not (PACKAGED_CONFIGS / path.name).is_file():
        return path
    typer.echo(f"note: no {path} here; using the packaged {PACKAGED_CONFIGS / path.name}", err=True)
    return PACKAGED_CONFIGS / path.name


def _fail(message: str, code: int) -> NoReturn:
    """Say what is wrong on stderr in one line (``error: ...``) and exit with ``code`` (docs/commands.md's exit codes)."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code) from None


def _bounded(low: float, high: float | None = None, unit: str = "", low_open: bool = False) -> dict[str, Any]:
    """A number flag's ``min``/``max`` (shown in its help, ``0.1<=x<=3600``) with a parser that holds it to them and says
    so itself, in ``config.Bound``'s words (the one way a number's range is checked and said: ``must be in [0.1, 3,600]
    s, got nan``): typer's own check told ``--period nan`` "Input should be less than or equal to 3600", untrue of nan.
    ``high`` None: no largest; ``low_open``: ``low`` itself refused. ``typer.Option(1.0, "--period", **_bounded(0.1, 3600.0, "s"))``."""
    import math  # noqa: PLC0415

    def parse(given: object) -> float:
        from cso_runtime.config import Bound  # noqa: PLC0415 - config imports yaml: only once a value is given

        bound = Bound(low, math.inf if high is None else high, unit, low_open=low_open)
        try:
            value = float(given)  # type: ignore[arg-type]  # the text typed, or the default
        except (TypeError, ValueError):
            raise typer.BadParameter(f"must be a number {bound.within()}, got {given}") from None
        if (problem := bound.problem(value)) is not None:
            raise typer.BadParameter(problem)
        return value

    return {"min": None if low_open else low, "max": high, "parser": parse}


STOPPING_NOTE = "stopping: writing what finished; signal once more to stop at once"
"""What ``interrupt_on_sigterm(wait_on_second=True)`` says to a second signal while the command stops."""

TRAIN_STOP_DEADLINE_S = 60.0
"""The most ``train``'s stop may take after its first stop signal (``interrupt_on_sigterm``'s ``stop_deadline_s``): it
closes its environment processes (``WatchedAsyncVectorEnv.close_grace_s`` per stage) and draws its learning curve, about a
second on a quiet 2-core host; past this it ends at once, saying where it waited."""


def interrupt_on_sigterm(wait_on_second: bool = False, stop_deadline_s: float | None = None, last_words: Callable[[], str] | None = None) -> Callable[[], bool]:
    """SIGTERM (``kill``, a job scheduler's stop) and SIGHUP (its terminal closed) end a long command as Ctrl-C does: its worker processes stopped,
    what finished written, exit code 130 and how to resume. Python's default would end it at once, writing
    nothing and leaving its workers to run their jobs to the end.

    After the first of them (or Ctrl-C), the command is stopping. With ``wait_on_second`` (``train``, whose stop
    writes its learning curve) a second one only says so (``STOPPING_NOTE``) and the stop goes on, as ``up``'s does on
    a repeated Ctrl-C; a third ends the stop where it is (KeyboardInterrupt, exit code 130 still). Without, each one
    does. Once the command has ended, Python's own end ignores them: it puts their default action back, which would
    end a process that wrote everything by the signal (exit code -15) instead of 130. Before that, the end waits for
    the command's non-daemon child processes (multiprocessing's own end would join them with no bound, the signals
    ignored) while one more signal ends it at once, exit code 130: a stuck child cannot make it unstoppable.

    Returns ``stop_requested``, True once the first of them came: the handler's ``KeyboardInterrupt`` is lost where
    Python runs the handler inside a finalizer (a garbage collection's weakref callback, a ``__del__``), so a long
    command also asks this as it goes (``learned.ppo.raise_if_stop_requested``). With ``stop_deadline_s``, the stop is
    bounded: where the command has not ended that long after the first signal, it ends at once with every thread's
    stack, its worker processes killed and ``last_words()`` said (``processes.end_overdue_stop``), exit code 130."""
    import atexit  # noqa: PLC0415
    import os  # noqa: PLC0415
    import signal  # noqa: PLC0415

    from cso_runtime.config import EXIT_INTERRUPTED  # noqa: PLC0415

    if stop_deadline_s is not None:
        # Bound now, before the handler is in place, not imported in it: an import in a signal handler waits on the
        # import lock, which the main thread it interrupted may hold (a signal in the middle of an import), and
        # processes is not imported at module level as it costs the CLI's start-up (multiprocessing, concurrent.futures).
        from cso_runtime.processes import end_overdue_stop  # noqa: PLC0415

    # SIGHUP not under nohup: processes.stop_signals, not imported here (its cost, above)
    stop_signals = (signal.SIGINT, signal.SIGTERM) + (() if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN else (signal.SIGHUP,))
    received = 0

    def end_at_once(signum: int, frame: object) -> None:
        os._exit(EXIT_INTERRUPTED)  # the command has ended: nothing of it is left to write

    def ignore_stop_signals() -> None:
        for sig in stop_signals:
            signal.signal(sig, end_at_once)
        if (processes := sys.modules.get("multiprocessing.process")) is not None:
            for child in processes.active_children():
                if not child.daemon:  # multiprocessing's end terminates the daemons; it would wait for these
                    child.join()
        for sig in stop_signals:
            signal.signal(sig, signal.SIG_IGN)  # SIG_IGN is the one handler Python's end leaves in place

    def raise_interrupt(signum: int, frame: object) -> None:
        nonlocal received
        received += 1
        if received == 1:
            atexit.register(ignore_stop_signals)  # last registered, first run: the rest of the exit included
            if stop_deadline_s is not None:
                end_overdue_stop(stop_deadline_s, EXIT_INTERRUPTED, last_words)
        elif received == 2 and wait_on_second:
            try:
                os.write(2, f"{STOPPING_NOTE}\n".encode())  # not sys.stderr: the handler may have cut one of its writes short
            except OSError:
                pass
            return
        raise KeyboardInterrupt

    for sig in stop_signals:  # SIGHUP: its terminal closed, the same clean stop
        signal.signal(sig, raise_interrupt)
    return lambda: received > 0


def _print_version(value: bool) -> None:
    if value:
        from cso_runtime.provenance import version_lines  # noqa: PLC0415

        typer.echo(version_lines())
        raise typer.Exit(0)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Debug logging"),
    show_version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit"),
    zenoh_config: Path | None = typer.Option(
        None,
        "--zenoh-config",
        help="Zenoh config file (JSON5) every session of this command starts from (credentials, TLS): status, record, replay, save-map, pause, resume, service, up, router "
        "(sets $CSO_ZENOH_CONFIG)",
    ),
) -> None:
    """Active scene mapping with CSO (ACM MM 2024) on a LIMO robot: eval, train, and the Zenoh runtime."""
    import logging  # noqa: PLC0415

    from cso_runtime.config import LOG_FORMAT  # noqa: PLC0415

    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format=LOG_FORMAT)
    if zenoh_config is not None:
        _use_zenoh_config(zenoh_config)


def _use_zenoh_config(path: Path) -> None:
    """Check ``path`` (exit 2 when Zenoh would refuse it) and make it the base of every Zenoh session of this
    process and of those it starts (``$CSO_ZENOH_CONFIG``, absolute: the services may start in another folder)."""
    import os  # noqa: PLC0415

    from cso_runtime.transport import ZENOH_CONFIG_ENV, TransportError, load_zenoh_config_file  # noqa: PLC0415

    try:
        load_zenoh_config_file(path)
    except TransportError as exc:
        _fail(f"--zenoh-config: {exc}", 2)
    os.environ[ZENOH_CONFIG_ENV] = str(path.absolute())


def _use_weights(given: Path) -> Path:
    """``--weights``: serve the learned methods from a training run's folder, or one method from exactly the file
    given; the folder or file, or exit 2 saying why."""
    from cso_runtime.learned.weights import use_weights  # noqa: PLC0415

    try:
        return use_weights(given)
    except ValueError as exc:
        _fail(str(exc), 2)


def _warn_of_unfed_inputs(prof: Profile) -> None:
    """``up``: say which service reads a key that no service of the run publishes, nor one it leaves to another process:
    a service of the user's own in place of a built-in one that does not publish all the built-in one did (a planner
    without ``planner/feedback``) would leave the others waiting for it, a lockstep episode until it fails."""
    from cso_runtime.keys import topic_key  # noqa: PLC0415
    from services.dataflow import nodes_of, unfed_inputs  # noqa: PLC0415

    own = {**prof.own_services(), **{name: f"the command {shlex.join(argv)}" for name, argv in prof.command_nodes().items()}}
    for name, topics in unfed_inputs(nodes_of([*prof.services, *prof.left_out_services()], prof.services)).items():
        keys = ", ".join(topic_key(t) for t in topics)
        typer.echo(
            f"warning: {name} reads {keys}, which no service of this run publishes"
            + "".join(f"; services.{n} runs {spec}" for n, spec in own.items() if n != name)
            + " (`cso-runtime dataflow` shows who publishes what)",
            err=True,
        )


def _warn_of_weights_trained_otherwise(prof: Profile) -> None:
    """``up``: say when the policy service's learned weights were trained with another field of view than the
    profile's sensor (``--weights`` of a run of ``configs/train.yaml``, 360 degrees, on the LIMO's 180), or under other
    stuck-mask settings than the profile's (``--set exploration.masks.KEY=VALUE`` runs them as trained), as eval does;
    and with other frontier settings that the policy service runs anyway and warns of as it starts (another
    ``frontier.min_cluster_size_m``: ``weights.INPUT_CHECKS``), in its words, here before anything starts rather than
    in its log alone (``weights.recorded_input_verdict``; those it refuses, ``up`` refuses first: ``Profile.validate``)."""
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415

    if "policy" in prof.services and prof.policy_method in LEARNED_METHODS:
        from cso_runtime.learned.weights import mask_mismatches, recorded_input_verdict, sensor_mismatches  # noqa: PLC0415

        exploration = prof.exploration_config()
        for mismatch in sensor_mismatches([prof.policy_method], exploration.sensor, eval_hint=False):
            typer.echo(f"warning: {mismatch} (a policy does best with the sensor it was trained with)", err=True)
        for mismatch in mask_mismatches([prof.policy_method], exploration.masks, exploration.sensor, prefix="exploration."):
            typer.echo(f"warning: {mismatch} (a policy does best with the masks it was trained under)", err=True)
        if "policy" not in {*prof.own_services(), *prof.command_nodes()}:  # the built-in policy service loads the weights
            for said in recorded_input_verdict(prof.policy_method, exploration.frontier, exploration.sensor).warned:
                typer.echo(f"warning: {said}", err=True)


def _warn_of_a_watchdog_within_a_step(prof: Profile) -> None:
    """``up``: say when the MuJoCo LIMO's ``watchdog_s`` is shorter than a control step (it brakes in every step); the
    run goes on as asked."""
    settings = prof.simulator_settings()
    if settings is not None:
        from cso_runtime.simulator import watchdog_within_a_step_said  # noqa: PLC0415

        said = watchdog_within_a_step_said(settings, prof.exploration_config().robot, "services.sim.mujoco.watchdog_s", "exploration.robot.control_period_s")
        if said is not None:
            typer.echo(f"warning: {said}", err=True)


def _warn_of_a_start_in_a_wall(prof: Profile) -> None:
    """``up``: say, in the sim service's own words, when the robot overlaps a wall at the scene's start pose (the MuJoCo
    LIMO's box, the 2D simulator's disc: ``Profile.start_overlap_said``), which the sim logs in runs/<run>/logs/sim.log alone; the run goes on as asked."""
    said = prof.start_overlap_said()
    if said is not None:
        typer.echo(f"warning: {said}", err=True)


def _warn_of_realtime_not_permitted(prof: Profile) -> None:
    """``up``: say when the profile's ``realtime_priority`` cannot be set here (no CAP_SYS_NICE, no ``rtprio`` limit: its
    services would each say so in their logs alone); the run goes on with normal scheduling."""
    if prof.realtime_priority:
        from cso_runtime.processes import REALTIME_HOWTO, realtime_refusal  # noqa: PLC0415

        why = realtime_refusal(prof.realtime_priority)
        if why is not None:
            typer.echo(f"warning: realtime_priority {prof.realtime_priority}: {why}; the services run with normal scheduling ({REALTIME_HOWTO})", err=True)


@app.command("eval", rich_help_panel="Evaluation (Table 1)")
def eval_command(
    method: str = typer.Option("greedy-dist", "--method", autocompletion=_complete_method_list, help=METHODS_HELP),
    maps: str = typer.Option("builtin", "--maps", "--scene", help="Folder of PNG plans, one PNG, a map_server FILE.yaml, 'builtin', or generated:SCALE:N:SEED (--scene, as in `up`, is the same option)"),
    limit: int | None = typer.Option(None, "--limit", help="Use at most N scenes (default: every scene of the spec)"),
    out: Path = typer.Option(Path("results/eval"), "--out", help="Output folder"),
    m_per_px: float = typer.Option(0.1, "--m-per-px", help="Metres per pixel for PNG plans (0.1 super large, 0.05 large)"),
    seed: int | None = typer.Option(None, "--seed", help="Episode seed (random policy, sensor noise); default 0"),
    seeds: list[str] | None = typer.Option(
        None, "--seeds", help="Several seeds in one eval, in place of --seed (0,1,2 or repeatable): each seed's episodes in OUT/seed<S>/, all pooled in OUT's summary.json, episodes.csv (the seed column) and report.html"
    ),
    max_steps: int | None = typer.Option(
        None, "--max-steps", help="Step limit per episode (one step = 0.25 s), 1 to 1,000,000; default: the --config file's episode.max_steps, 3000 (a --set episode.max_steps of another value is refused)"
    ),
    lidar_fov: float | None = typer.Option(None, "--lidar-fov", help="LiDAR field of view in degrees: 180 (LIMO, the default) or 360; --sensor lidar only"),
    sensor: str = typer.Option("lidar", "--sensor", help="Sensor preset: lidar or depth"),
    workers: int = typer.Option(1, "--workers", help="Parallel worker processes"),
    sim: str = typer.Option("2d", "--sim", help="Simulator: 2d (fast kinematic) or mujoco (physics)"),
    config: Path | None = typer.Option(None, "--config", help="YAML with exploration parameters (see configs/eval.yaml)"),
    sim_config: Path | None = typer.Option(
        None, "--sim-config", help="YAML with the MuJoCo LIMO's parameters (see configs/robot_sim.yaml: physics, odometry drift); --sim mujoco only"
    ),
    resume: bool = typer.Option(False, "--resume", help="Keep episodes already finished in --out (same method, map, seed, config, simulator and weights)"),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Run again in --out the episodes it holds of these methods and plans from another configuration (refused without it)"
    ),
    baseline: str = typer.Option("greedy-dist", "--baseline", help="Compare every other method with this one, scene by scene (paired.csv), when it runs too"),
    weights: Path | None = typer.Option(
        None, "--weights", help="Folder of <method>.pt (a `train --out` folder: each method its file, or its <method>@fov<deg>.pt for a sensor of that field of view; sets CSO_WEIGHTS_DIR), or one <method>.pt file, which that method then uses exactly, whatever the sensor (sets CSO_WEIGHTS_FILE), instead of the shipped weights"
    ),
    animate: bool = typer.Option(False, "--animate", help="Also write animations/<method>/<map>.gif: the robot's map, path and goal at each decision"),
    settings: list[str] | None = typer.Option(
        None, "--set", help="KEY=VALUE over the --config file, dotted, repeatable: masks.beta_far_m=2.0, episode.replan_every_steps=12"
    ),
    dry_run: bool = typer.Option(
        False, "--dry-run", help="Validate (methods, weights, scenes, --out), say what would run: scenes per scale, sensor, simulator, --out and --resume; run and write nothing"
    ),
    resolved: bool = typer.Option(
        False,
        "--resolved",
        help="Validate, print the exploration configuration the episodes would run with, defaults filled in (YAML, summary.json's meta.config, for --config); the --out folder is checked with --dry-run only",
    ),
) -> None:
    """Run exploration episodes and write the paper's Table 1 metrics, curves and trajectory plots."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.evaluation import EvalRequest, refuse_seed_with_seeds, run_eval_cli  # noqa: PLC0415 - keep CLI start fast
    from cso_runtime.policies import parse_methods  # noqa: PLC0415

    if lidar_fov is not None and sensor != "lidar":  # the preset's own field of view would be used, silently
        _fail(f"--lidar-fov sets the LiDAR's field of view; --sensor {sensor} has its own", 2)
    if weights is not None:
        _use_weights(weights)
    try:
        parameters = parse_settings(settings or [])
        seed_list = parse_seeds(seeds or [])
        refuse_seed_with_seeds(seed, seed_list)  # None: no --seed given (typer's default), so --seed 0 is refused too
    except ConfigError as exc:
        _fail(str(exc), 2)

    request = EvalRequest(
        methods=parse_methods(method),
        maps=maps,
        limit=limit,
        out_dir=out,
        m_per_px=m_per_px,
        seed=0 if seed is None else seed,
        max_steps=max_steps,
        lidar_fov_deg=180.0 if lidar_fov is None else lidar_fov,
        sensor=sensor,
        workers=workers,
        sim=sim,
        config_path=_packaged_if_missing(config),
        sim_config_path=_packaged_if_missing(sim_config),
        resume=resume,
        overwrite=overwrite,
        baseline=baseline,
        animate=animate,
        settings=parameters,
        seeds=seed_list,
    )
    if dry_run or resolved:
        raise typer.Exit(run_eval_cli(request, dry_run=dry_run, resolved=resolved))
    interrupt_on_sigterm()
    raise typer.Exit(run_eval_cli(request))


@app.command("compare", rich_help_panel="Evaluation (Table 1)")
def compare_command(
    episodes: list[str] = typer.Argument(..., help="episodes.csv files written by eval (or their folders), each optionally LABEL=FILE (scenes pair only within a label); a later file's episodes of a method replace an earlier file's on the same scenes (a note says so)"),
    baseline: str = typer.Option("greedy-dist", "--baseline", help="The method every other one is compared with"),
    as_json: bool = typer.Option(False, "--json", help="JSON instead of a markdown table"),
    out: Path | None = typer.Option(None, "--out", help="Also write the comparison as CSV"),
    exclude: list[str] | None = typer.Option(None, "--exclude", help="Leave out these maps (the `map` column; repeatable or comma-separated), e.g. the plans a training run drew"),
    rename: list[str] | None = typer.Option(None, "--rename", help="FILE:METHOD=NEW: compare that file's METHOD as NEW (FILE as given above; repeatable), e.g. `compare shipped/ mine/ --rename mine/:cso=cso-mine` sets your cso beside the shipped one instead of in its place"),
) -> None:
    """Each method against a baseline scene by scene: change of mean m2/step, per-scene ratio (mean and geometric mean, each with a 95 % bootstrap interval), scenes won."""
    import json  # noqa: PLC0415

    from cso_runtime.comparison import (  # noqa: PLC0415
        TOO_FEW_SCENES,
        as_dicts,
        compare_to_baseline,
        episodes_by_method,
        file_episodes,
        labelled,
        markdown_table,
        mixed_setups_said,
        no_baseline_said,
        no_episode_said,
        pooled_episodes,
        split_names,
        write_csv,
    )

    files = [labelled(arg) for arg in episodes]
    missing = [str(path) for _, path in files if not path.is_file()]
    if missing:
        _fail(f"no such file: {', '.join(missing)}", 2)
    try:
        table, replaced = pooled_episodes(files, exclude or [], rename or [])
    except ValueError as exc:
        _fail(str(exc), 2)
    for replacement in replaced:
        typer.echo(f"note: {replacement.note()}", err=True)
    for said in mixed_setups_said(files, split_names(exclude or [])):  # a 360-degree LiDAR's episodes against a 180-degree one's
        typer.echo(said, err=True)
    if exclude:  # a name that matches no episode leaves out nothing: a typo would compare the plans meant to be out
        held = {row["map"] for label, path in files for row in file_episodes(label, path)}  # of no m2/step too: there
        if unmatched := [name for name in split_names(exclude) if name not in held]:
            typer.echo(f"note: --exclude {', '.join(unmatched)}: no such map in these files; nothing left out for it", err=True)
    if baseline not in {method for method, _ in table}:  # none of its episodes left: why (of every method's none too)
        counts = episodes_by_method(files, rename or [])
        if not counts:
            _fail(no_episode_said(files), 1)
        if baseline not in counts:  # a typo in --baseline, not "too few scenes"
            _fail(no_baseline_said(baseline, counts), 2)
        # It has episodes, none comparable: said so, not "no episodes" (exit 1, as too few scenes)
        left = episodes_by_method(files, rename or [], exclude or []).get(baseline, 0)
        why = (f"its {counts[baseline]} in these files are all on maps --exclude leaves out" if not left
               else f"none of its {left} in these files has an m2/step (an episode of no step has none)")
        _fail(f"--baseline {baseline!r} has no episode to compare: {why}", 1)
    comparisons = compare_to_baseline(table, baseline)
    if out is not None:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            write_csv(out, as_dicts(comparisons))
        except OSError as exc:
            _fail(f"--out {out}: cannot write ({exc.strerror or exc})", 2)
    if as_json:
        typer.echo(json.dumps({"baseline": baseline, "comparisons": as_dicts(comparisons)}, indent=2))
    elif comparisons:  # no table of headers alone: the line below says why there is none
        typer.echo(markdown_table(comparisons))
    if not comparisons:
        typer.echo(f"no method shares {TOO_FEW_SCENES} with {baseline}", err=True)
        raise typer.Exit(1)


# Further commands (service, up, status, down, train, record, replay) register below.


@app.command("report", rich_help_panel="Evaluation (Table 1)")
def report_command(
    folder: Path = typer.Argument(..., help="An `eval --out` folder or a run folder (runs/<run-id>) with its summary.json"),
) -> None:
    """Write FOLDER/report.html again from its summary.json and the figures now in it (an older folder, new animations)."""
    import json  # noqa: PLC0415

    from cso_runtime.report import write_report  # noqa: PLC0415

    if folder.is_file():  # its summary.json given: "summary.json/summary.json: Not a directory" said nothing useful
        _fail(f"{folder} is a file; report takes the folder that holds summary.json: cso-runtime report {folder.parent}", 2)
    try:
        summary = json.loads((folder / "summary.json").read_text())
        if not isinstance(summary, dict) or not isinstance(summary.get("methods"), dict):
            raise TypeError("not an eval or run summary (no methods)")
        path = write_report(folder, summary)
    except OSError as exc:
        where = exc.filename or folder
        if not (folder / "summary.json").exists() and (folder / "run.json").is_file():  # a run folder: say why it has none
            _fail(f"{where}: {exc.strerror or exc}; {_run_without_results(folder)}", 2)
        _fail(f"{where}: {exc.strerror or exc}" + (" (not an `eval --out` folder or a run folder?)" if not (folder / "summary.json").exists() else ""), 2)
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:  # valid JSON of another shape too
        _fail(f"{folder / 'summary.json'}: not a summary eval or up wrote ({type(exc).__name__}: {exc})", 2)
    typer.echo(f"wrote {path}")


def _run_without_results(run_dir: Path) -> str:
    """Why a run folder has no summary.json for ``report``, as ``runs`` lists its state: ``report`` said "not an `eval
    --out` folder or a run folder?" of a run stopped before its episode ended (Ctrl-C, ``down``), which writes none."""
    from cso_runtime.current_run import LAUNCHER_DIED  # noqa: PLC0415
    from cso_runtime.launcher import LAST_MAP  # noqa: PLC0415
    from cso_runtime.runs import UNKNOWN_RUN_STATE, summarize_run  # noqa: PLC0415
    from cso_runtime.status import lost_result_words  # noqa: PLC0415

    run = summarize_run(run_dir)
    state = run.state
    if state in ("starting", "running"):
        return f"run {run_dir.name} is {state}: its results are written when its episode ends"
    kept = f" (its map so far: {run_dir / LAST_MAP})" if (run_dir / LAST_MAP).is_file() else ""
    kept += "".join(f"; {lost_result_words(lost, run.referee)}" for lost in run.lost_results)  # an end it had, with no result
    if state == UNKNOWN_RUN_STATE:
        return f"run {run_dir.name} has no results; {run.reason}{kept}"
    if state in ("interrupted", "stopped", LAUNCHER_DIED):
        return f"run {run_dir.name} has no results: a run stopped before its episode ended writes none (`runs` lists it as {state}){kept}"
    # failed (results that could not be written, a service given up on), or done and its summary.json since removed
    log = f"`cso-runtime logs launcher --run {run_dir}`"
    if run.reason:  # run.json says why (refused, no router): said, and where to read more
        return f"run {run_dir.name} has no results (`runs` lists it as {state}): {run.reason}; more in its launcher's log: {log}{kept}"
    return f"run {run_dir.name} has no results (`runs` lists it as {state}); its launcher's log says why: {log}{kept}"


def _read_grids_of_any_run() -> None:
    """A one-shot tool (``save-map``, ``export-bag``, ``animate``, ``replay``) reads the grids of any run, whatever ``max_grid_cells``
    its profile raised the bound to: up to the format's ceiling (``messages.MAX_GRID_CELLS``). The bound of a run's
    services and launcher guards processes that stay up against forged messages; this process ends with its file."""
    from cso_runtime.messages import MAX_GRID_CELLS, set_max_grid_cells  # noqa: PLC0415

    set_max_grid_cells(MAX_GRID_CELLS)


@app.command("record", rich_help_panel="Recordings")
def record_command(
    out: str | None = typer.Option(None, "--out", help="A new MCAP file, or a folder (existing, or ending in /) for <robot>-<UTC time>.mcap in it (default: recordings/)"),
    robot: str | None = typer.Option(None, "--robot", help="Robot id, or '*' for every robot (default: the current run's, else the one robot at --connect, else r0)"),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """Record every cso/<robot>/** message to MCAP (Foxglove and the mcap tools open it; `export-bag` turns it into a ROS 2 bag) until Ctrl-C."""
    import signal  # noqa: PLC0415
    import threading  # noqa: PLC0415
    import time  # noqa: PLC0415

    from cso_runtime.config import EXIT_NO_ZENOH  # noqa: PLC0415
    from cso_runtime.keys import KeyExprError, check_robot_id  # noqa: PLC0415
    from cso_runtime.processes import set_from_signal_handler, stop_signals  # noqa: PLC0415
    from cso_runtime.recording import names_a_folder, record, recording_path  # noqa: PLC0415
    from cso_runtime.status import AmbiguousRobotError, RunTarget, client_transport, robot_at_endpoint  # noqa: PLC0415
    from cso_runtime.transport import TransportError, open_session  # noqa: PLC0415

    if out is not None and not names_a_folder(out) and Path(out).exists():  # said with no run too, as replay's flags
        _fail(f"{out} exists; give another --out, or remove it first", 2)
    (endpoints, run_robot, zenoh_config_file), not_yet = (RunTarget(list(connect), None, None), "") if connect else _current_run_target(runs_dir)
    try:  # before connecting: a bad id is a usage error whether or not a router answers
        check_robot_id(robot or run_robot or "r0", allow_wildcard=True)
    except KeyExprError as exc:
        _fail(f"--robot: {exc}", 2)
    if not_yet:
        _fail(not_yet, 1)
    if not endpoints:
        _fail("no current run; give --connect ENDPOINT", 2)
    _endpoints_or_exit(endpoints, zenoh_config_file)
    if robot is None and connect:  # the one robot there, not r0 whatever answers
        try:
            run_robot = robot_at_endpoint(endpoints, zenoh_config_file, wildcard_too=True)
        except AmbiguousRobotError as exc:
            _fail(str(exc), 2)
    robot = robot or run_robot or "r0"
    path = recording_path(out, Path("recordings"), f"{robot.replace('*', 'all')}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}")
    if path.exists():  # as `ros2 bag record -o`: an earlier recording is never written over
        _fail(f"{path} exists; give another --out, or remove it first", 2)
    output_dir_or_exit(path.parent, f"--out {out}: its folder" if out is not None else "the recordings folder")  # before connecting, as `up --record-out`
    stop = threading.Event()
    for sig in stop_signals():  # SIGHUP: its terminal closed (not under nohup)
        signal.signal(sig, lambda *_: set_from_signal_handler(stop))
    try:
        with open_session(client_transport(endpoints, zenoh_config_file)) as session:
            typer.echo(f"recording cso/{robot}/** from {', '.join(endpoints)} into {path} (Ctrl-C to stop)")
            stats = record(session, robot, path, stop)
    except TransportError as exc:  # no router to record from: the exit code of `up` without a Zenoh session
        _fail(str(exc), EXIT_NO_ZENOH)
    except ValueError as exc:
        _fail(str(exc), 2)
    except OSError as exc:  # the recording's folder or file cannot be made
        _fail(f"cannot record into {path}: {exc.strerror or exc}", 2)
    typer.echo(f"{stats.messages} messages on {len(stats.per_key)} keys ({stats.raw} kept verbatim) -> {path}")


@app.command("replay", rich_help_panel="Recordings")
def replay_command(
    file: Path = typer.Argument(..., help="An MCAP file written by `cso-runtime record`"),
    speed: str = typer.Option("1.0", "--speed", help="Playback speed factor (0.001 or more), or 'max' for as fast as possible"),
    topics: str | None = typer.Option(
        None, "--topics", help="Comma-separated topics to replay, by name or key (e.g. clock,odom,scan,planner/feedback); default all"
    ),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """Publish a recording back into Zenoh with the exact original payloads, at recorded or faster speed."""
    import signal  # noqa: PLC0415
    import threading  # noqa: PLC0415

    from cso_runtime.config import EXIT_NO_ZENOH  # noqa: PLC0415
    from cso_runtime.keys import TOPICS  # noqa: PLC0415
    from cso_runtime.processes import set_from_signal_handler, stop_signals  # noqa: PLC0415
    from cso_runtime.recording import RecordingError, ReplayRefused, check_chunks, parse_speed, replay  # noqa: PLC0415
    from cso_runtime.status import RunTarget, client_transport  # noqa: PLC0415
    from cso_runtime.transport import TransportError, open_session  # noqa: PLC0415

    try:
        check_chunks(file)  # a wrong, broken or damaged file is the first thing to say
    except RecordingError as exc:
        _fail(str(exc), 2)
    by_key = {key: name for name, key in TOPICS.items()}  # planner/feedback, as docs/messages.md and `dataflow` name it
    wanted = [by_key.get(t.strip(), t.strip()) for t in topics.split(",") if t.strip()] if topics else None
    unknown = [t for t in wanted or [] if t not in TOPICS]  # a typo would replay nothing, silently
    try:
        parse_speed(speed)
        if unknown:
            raise ValueError(f"--topics: unknown topic(s) {', '.join(unknown)}; known: {', '.join(TOPICS)}")
        if wanted == []:  # "," or " ": it would replay nothing, silently
            raise ValueError(f"--topics names no topic; name some ({', '.join(TOPICS)}), or leave --topics out for all")
    except ValueError as exc:
        _fail(str(exc), 2)
    # the flags, then where to replay into: a bad --speed is said with no run too, not only once a run is found
    (endpoints, _, zenoh_config_file), not_yet = (RunTarget(list(connect), None, None), "") if connect else _current_run_target(runs_dir)
    if not_yet:
        _fail(not_yet, 1)
    if not endpoints:
        _fail("no current run; give --connect ENDPOINT", 2)
    _endpoints_or_exit(endpoints, zenoh_config_file)
    stop = threading.Event()
    for sig in stop_signals():  # SIGHUP: its terminal closed (not under nohup)
        signal.signal(sig, lambda *_: set_from_signal_handler(stop))
    _read_grids_of_any_run()  # it upgrades a recording's old payloads: a run's grids, whatever bound that run had
    try:
        with open_session(client_transport(endpoints, zenoh_config_file)) as session:
            stats = replay(session, file, speed, stop, wanted)
    except TransportError as exc:  # no router to replay into: the exit code of `up` without a Zenoh session
        _fail(str(exc), EXIT_NO_ZENOH)
    except ReplayRefused as exc:  # nothing published
        _fail(str(exc), 2)
    except RecordingError as exc:
        _fail(str(exc), 1)
    typer.echo(f"replayed {stats.messages} messages on {len(stats.per_key)} keys in {stats.duration_s:.2f} s (recorded span {stats.recorded_s:.2f} s)")
    if stats.upgraded:
        typer.echo(f"  published as the current version, recorded in an older one: {', '.join(f'{k} {n}' for k, n in sorted(stats.upgraded.items()))}")
    if stats.unreadable:
        typer.echo(f"  published as recorded, not readable by this build: {', '.join(f'{k} {n}' for k, n in sorted(stats.unreadable.items()))}")


def _current_run_target(runs_dir: Path) -> tuple[RunTarget, str]:
    """The current run's router, robot and Zenoh config (``status.endpoints_of_run``), for ``record`` and ``replay``, of
    one read of its run file, and why it cannot be joined though it lives ("" where it can, or there is none:
    ``status.current_run_not_joinable``, starting, or ended and its launcher exiting), which they say (exit 1): ``up ...
    &`` then ``record`` said "no current run; give --connect ENDPOINT" (exit 2, a usage error) of a run whose router
    was opening."""
    from cso_runtime.current_run import read_current_run  # noqa: PLC0415
    from cso_runtime.status import current_run_not_joinable, endpoints_of_run  # noqa: PLC0415

    info = read_current_run(runs_dir)
    not_yet = current_run_not_joinable(info, runs_dir)
    return endpoints_of_run(info), not_yet.said if not_yet is not None else ""


def _endpoints_or_exit(endpoints: list[str], zenoh_config_file: str | None) -> None:
    """Exit 2 saying why where ``endpoints`` cannot name a router (``notanendpoint``, a port out of range): a usage
    error before anything is made, as ``status`` says it, not "no Zenoh session" (exit 3) once a session fails to open."""
    from cso_runtime.status import client_transport  # noqa: PLC0415
    from cso_runtime.transport import TransportError  # noqa: PLC0415

    try:
        client_transport(endpoints, zenoh_config_file).validate()
    except TransportError as exc:
        _fail(str(exc), 2)


@contextmanager
def _count_progress(label: str, unit: str = "messages") -> Iterator[Callable[[int, int | None], None]]:
    """A progress bar on stderr over things done (a terminal only; logs and scripts get the last line alone)."""
    from rich.console import Console  # noqa: PLC0415
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn  # noqa: PLC0415

    from cso_runtime.live_view import redraws_in_place  # noqa: PLC0415

    console = Console(stderr=True)
    # A terminal is the output's own isatty(): under FORCE_COLOR rich takes a file for one, and the bar's redraws
    # (cursor moves, line erases) landed in the log.
    with Progress(TextColumn(f"[bold]{label}"), BarColumn(), MofNCompleteColumn(), TextColumn(unit), TimeElapsedColumn(),
                  console=console, disable=not redraws_in_place(console), transient=True) as bar:
        task = bar.add_task("", total=None)
        yield lambda done, total: bar.update(task, completed=done, total=total)


@app.command("export-bag", rich_help_panel="Recordings")
def export_bag_command(
    file: Path = typer.Argument(..., help="An MCAP file written by `cso-runtime record` (or `up --record`)"),
    out: Path | None = typer.Option(None, "--out", help="The new bag folder (default: the recording's name without .mcap, beside it)"),
    robot: str | None = typer.Option(None, "--robot", help="Whose messages (default: the recording's only robot)"),
    map_period_s: float = typer.Option(1.0, "--map-period-s", help="At most one /map per this many seconds of the run, and the last (0: every map; at most 1e9)"),
    time_base: str = typer.Option("sim", "--time", help="sim: each message at its step's robot time (0.25 s a step, even in lockstep); received: at its reception"),
    namespace: str = typer.Option("", "--namespace", help="Put every topic but /tf and /tf_static under /NS/ and every frame id under NS/ (robot1/base_link), so that several robots' bags can be merged"),
    map_frame: str = typer.Option(FRAME_OPTIONS["map"].default, FRAME_OPTIONS["map"].flag, help=FRAME_OPTIONS["map"].help),
    odom_frame: str = typer.Option(FRAME_OPTIONS["odom"].default, FRAME_OPTIONS["odom"].flag, help=FRAME_OPTIONS["odom"].help),
    base_frame: str = typer.Option(FRAME_OPTIONS["base"].default, FRAME_OPTIONS["base"].flag, help=FRAME_OPTIONS["base"].help),
    laser_frame: str = typer.Option(FRAME_OPTIONS["laser"].default, FRAME_OPTIONS["laser"].flag, help=FRAME_OPTIONS["laser"].help),
) -> None:
    """Convert a recording into a ROS 2 bag (rosbag2, MCAP storage) of standard types: /scan, /odom, /tf, /map, /plan, /goal_pose, /explore/frontiers, /cmd_vel, for RViz, Foxglove and `ros2 bag play`."""
    from cso_runtime.bag_export import BagExportError, BagFrames, check_export_settings, export_bag  # noqa: PLC0415
    from cso_runtime.recording import RecordingError, check_recording  # noqa: PLC0415

    _read_grids_of_any_run()
    frames = BagFrames(map_frame, odom_frame, base_frame, laser_frame)
    try:
        check_export_settings(map_period_s, time_base, ("--map-period-s", "--time"))  # the flags, not the Python names
        frames.check()
        check_recording(file)
        target = out if out is not None else file.with_suffix("")
        if target == file:
            raise BagExportError(f"--out {out} is the recording itself")
        interrupt_on_sigterm()
        with _count_progress("export-bag") as progress:
            stats = export_bag(file, target, robot, map_period_s, time_base, progress, namespace, frames=frames)
    except (RecordingError, BagExportError, ValueError) as exc:
        _fail(str(exc), 2)
    except KeyboardInterrupt:
        from cso_runtime.config import EXIT_INTERRUPTED  # noqa: PLC0415

        _fail(f"interrupted; no bag written ({target} removed)", EXIT_INTERRUPTED)
    written = ", ".join(f"{topic} {n}" for topic, n in sorted(stats.written.items()))
    typer.echo(f"wrote {stats.path} (robot {stats.robot}): {sum(stats.written.values())} messages: {written}")
    if stats.maps_thinned:
        typer.echo(f"  {stats.maps_thinned} maps thinned out by --map-period-s {map_period_s:g}")
    placed = sorted({(p.x_m, p.y_m, p.yaw_rad) for p in stats.map_origins.values()} - {(0.0, 0.0, 0.0)})
    if placed:
        typer.echo(f"  {frames.map} -> {frames.odom}: the scene's map origin {', '.join(f'({x:g} m, {y:g} m, {yaw:g} rad)' for x, y, yaw in placed)}")
    mount = stats.lidar_mount
    typer.echo(f"  {frames.base} -> {frames.laser}: ({mount.x_m:g} m, {mount.y_m:g} m, {mount.yaw_rad:g} rad), the LiDAR's mount as the recording shows it")
    if stats.scan_period_s:
        typer.echo(f"  /scan scan_time: {stats.scan_period_s:g} s, the period between the recording's scans")
    if stats.rejected:
        typer.echo(f"  left out, did not decode: {', '.join(f'{k} {n}' for k, n in sorted(stats.rejected.items()))}")


@app.command("animate", rich_help_panel="Recordings")
def animate_command(
    file: Path = typer.Argument(..., help="An MCAP file written by `cso-runtime record` (or `up --record`)"),
    out: Path | None = typer.Option(None, "--out", help="The GIF to write (default: the recording's name with .gif, beside it)"),
    robot: str | None = typer.Option(None, "--robot", help="Whose run (default: the recording's only robot)"),
    max_frames: int = typer.Option(200, "--max-frames", min=2, help="At most this many frames (every other decision, and so on, beyond it)"),
) -> None:
    """An animated GIF of a recorded run: the robot's map, path, goal and pose after each decision, then the final map."""
    from cso_runtime.animation import animate_recording  # noqa: PLC0415
    from cso_runtime.recording import RecordingError, check_recording  # noqa: PLC0415

    _read_grids_of_any_run()

    target = out if out is not None else file.with_suffix(".gif")
    try:
        check_recording(file)
        if target.resolve() == file.resolve():
            raise RecordingError(f"--out {out} is the recording itself")
        if target.is_dir() or target.suffix.lower() not in (".gif", ".png"):
            raise RecordingError(f"--out {out} must be a file ending in .gif (or .png, an animated PNG)")
        with _count_progress("animate") as progress:
            stats = animate_recording(file, target, robot, max_frames, progress=progress)
    except RecordingError as exc:
        _fail(str(exc), 2)
    except OSError as exc:
        _fail(f"cannot write {target}: {exc.strerror or exc}", 2)
    typer.echo(f"wrote {stats.path} (robot {stats.robot}): {stats.frames} frames from {stats.decisions} decisions and {stats.maps} maps")
    if stats.rejected:
        typer.echo(f"  left out, did not decode: {stats.rejected} payloads")


@app.command("scenes", rich_help_panel="Evaluation (Table 1)")
def scenes_command(
    spec: str = typer.Argument("builtin", help="Scene spec: builtin, a folder of PNG plans or map YAMLs, FILE.png, FILE.yaml, generated:SCALE:N:SEED"),
    m_per_px: float = typer.Option(0.1, "--m-per-px", help="Metres per pixel for PNG plans, as in eval (0.1 super large, 0.05 large)"),
    limit: int | None = typer.Option(None, "--limit", min=1, help="At most N scenes (default: every scene of the spec)"),
    preview: Path | None = typer.Option(None, "--preview", help="Also write a PNG of each plan into this folder: reachable free space, start pose"),
    mjcf: Path | None = typer.Option(None, "--mjcf", help="Also write each plan's MuJoCo world (walls, floor, the LIMO, whose default pose qpos0 is the start pose, as is keyframe 'start') into this folder as NAME.xml, for `python -m mujoco.viewer --mjcf FILE`"),
    sim_config: Path | None = typer.Option(
        None, "--sim-config", help="With --mjcf: write the worlds with these MuJoCo LIMO parameters (the keys of configs/robot_sim.yaml), as eval --sim mujoco --sim-config FILE builds them"
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table"),
) -> None:
    """Each scene of a spec: size, traversable area, the paper's scale class and start pose; unusable plans with why (exit 1)."""
    import json  # noqa: PLC0415

    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.plots import plot_scene  # noqa: PLC0415
    from cso_runtime.scenes import M_PER_PX_BOUND, SceneError, describe_scene, resolve_scenes  # noqa: PLC0415
    from robot_sim.scene import write_mujoco_world  # noqa: PLC0415

    try:
        M_PER_PX_BOUND.check("--m-per-px", m_per_px)  # named as typed, as eval's --m-per-px
        refs = resolve_scenes(spec, limit, m_per_px)
    except (ConfigError, SceneError) as exc:
        _fail(str(exc), 2)
    if preview is not None:
        output_dir_or_exit(preview, "--preview")
    world_config = None
    # eval --sim mujoco's LiDAR (its 0.103 m mount) and robot: the worlds are the ones eval runs in, and a
    # --sim-config that eval refuses (another mount, a step the control period is no whole number of) is refused here too.
    from cso_runtime.config import RobotConfig  # noqa: PLC0415
    from robot_sim.config import limo_sensor  # noqa: PLC0415

    world_sensor = limo_sensor()
    if sim_config is not None:
        from cso_runtime.config import ConfigError, load_yaml  # noqa: PLC0415
        from cso_runtime.simulator import mujoco_config  # noqa: PLC0415

        if mjcf is None:
            _fail("--sim-config sets the parameters of the MuJoCo worlds that --mjcf writes: it needs --mjcf", 2)
        sim_config = _packaged_if_missing(sim_config)
        try:
            world_config = mujoco_config(load_yaml(sim_config) or {}, world_sensor, where=str(sim_config), robot=RobotConfig(), mount=None)
        except (ConfigError, OSError) as exc:
            _fail(str(exc), 2)
    if mjcf is not None:
        output_dir_or_exit(mjcf, "--mjcf")
    rows: list[dict] = []
    with _count_progress("reading", "scenes") as progress:
        for ref in refs:
            try:
                plan = ref.load()
                rows.append(describe_scene(plan))
                if preview is not None:
                    plot_scene(preview / f"{ref.name}.png", plan)
                if mjcf is not None:
                    write_mujoco_world(mjcf / f"{ref.name}.xml", plan, sim=world_config, sensor=world_sensor)
            except SceneError as exc:
                rows.append({"scene": ref.name, "error": str(exc)})
            progress(len(rows), len(refs))
    bad = [r for r in rows if "error" in r]
    if as_json:
        from cso_runtime.geometry import rounded_floats  # noqa: PLC0415

        typer.echo(json.dumps(rounded_floats(rows), indent=2))  # 4.725 m, not 4.7250000000000005
    else:
        from rich import box  # noqa: PLC0415
        from rich.markup import escape  # noqa: PLC0415
        from rich.table import Table  # noqa: PLC0415

        from cso_runtime.live_view import table_console  # noqa: PLC0415

        table = Table(title=escape(f"scenes of {spec}"), box=box.SIMPLE_HEAD)
        table.add_column("scene", overflow="fold")
        for col in ("size m", "m/px", "traversable m2", "scale", "start x, y m, yaw rad"):
            table.add_column(col, justify="left" if col == "scale" else "right")
        for r in rows:
            if "error" in r:
                table.add_row(escape(r["scene"]), "[red]unusable[/red]")  # why, whole, below the table
                continue
            st = r["start"]
            table.add_row(
                escape(r["scene"]), f"{r['width_m']:.1f} x {r['height_m']:.1f}", f"{r['resolution_m']:g}", f"{r['traversable_area_m2']:.1f}",
                r["scale"].replace("_", " "), f"{st['x_m']:.2f}, {st['y_m']:.2f}, {st['yaw_rad']:.2f}",
            )
        console = table_console(table)  # `scenes > list.txt`: each scene's path on its line
        console.print(table)
        for r in bad:  # a reason names a file: a column would fold it and cut it off
            console.print(f"[red]unusable[/red] {escape(r['scene'])}: {escape(r['error'])}", soft_wrap=True, highlight=False)
        scales: dict[str, int] = {}
        for r in rows:
            if "error" not in r:
                scales[r["scale"]] = scales.get(r["scale"], 0) + 1
        counts = ", ".join(f"{n} {sc.replace('_', ' ')}" for sc, n in scales.items())
        written = [f"previews in {preview}"] * (preview is not None) + [f"MuJoCo worlds in {mjcf}"] * (mjcf is not None)
        typer.echo(f"{len(rows) - len(bad)} usable ({counts or 'none'}), {len(bad)} unusable" + "".join(f"; {w}" for w in written))
    if bad:
        raise typer.Exit(1)


@app.command("service", context_settings={"allow_extra_args": True, "ignore_unknown_options": True}, add_help_option=False, rich_help_panel="Runtime (Zenoh services)")
def service_command(
    ctx: typer.Context,
    name: str | None = typer.Argument(
        None, help="sim, mapper, frontier, policy, planner, ros2_bridge or foxglove_bridge, or a service of your own as module.path:Attribute (docs/own-service.md)"
    ),
) -> None:
    """Run one service in this process (same as python -m services.NAME; pass --config FILE --robot ID --connect EP, or --attach; `service NAME --help` lists that service's options)."""
    from services import command_service_class  # noqa: PLC0415
    from services.common import service_main  # noqa: PLC0415

    if name is None or name in ("-h", "--help"):  # --help goes on to the service: its own options are there
        typer.echo(ctx.get_help())
        raise typer.Exit(0 if name else 2)
    try:
        cls = command_service_class(name)
    except ValueError as exc:
        _fail(str(exc), 2)
    raise typer.Exit(service_main(cls, list(ctx.args), prog=f"cso-runtime service {name}"))


@app.command("up", rich_help_panel="Runtime (Zenoh services)")
def up_command(
    ctx: typer.Context,
    profile: str = typer.Option("sim", "--profile", autocompletion=_complete_profiles, help="Profile name (./configs/profiles/, then the packaged cso_runtime/profiles/) or a YAML path"),
    scene: str | None = typer.Option(None, "--scene", help="Scene spec (overrides the profile): builtin, DIR, FILE.png, FILE.yaml (a map_server map), generated:SCALE:N:SEED; one episode, on its first plan"),
    method: str | None = typer.Option(None, "--method", autocompletion=_complete_methods, help="Goal selector (overrides the profile): a method's name or your own as module.path:Attribute (docs/own-method.md)"),
    robot: str | None = typer.Option(None, "--robot", help="Robot id (overrides the profile)"),
    seed: int | None = typer.Option(None, "--seed", help="Episode seed (overrides the profile; default: the profile's seed, 0 in the shipped ones)"),
    lockstep: bool | None = typer.Option(None, "--lockstep/--real-time", help="Deterministic lockstep or real time (overrides the profile)"),
    detach: bool = typer.Option(False, "--detach", help="Run in the background until `cso-runtime down`"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where runs/<run-id>/ (logs, results) go"),
    live: bool = typer.Option(True, "--live/--no-live", help="Show the live view (foreground only)"),
    connect: list[str] | None = typer.Option(
        None, "--connect", help="Router to join, repeatable (a LIMO's zenoh-bridge-ros2dds: tcp/ROBOT_IP:7447); appended to router.connect"
    ),
    namespace: str | None = typer.Option(None, "--namespace", help="ROS namespace of the robot's topics (limo-ros2: the ROS 2 bridge's namespace)"),
    zenoh_config: Path | None = typer.Option(
        None, "--zenoh-config", help="Zenoh config file (JSON5) the router and every service start from: user/password, TLS (router.zenoh_config)"
    ),
    record: bool = typer.Option(False, "--record", help="Record the run to runs/<run-id>/recording.mcap"),
    record_out: str | None = typer.Option(None, "--record-out", help="Record the run to this new MCAP file, or to <run-id>.mcap in this folder (existing, or ending in /; implies --record)"),
    weights: Path | None = typer.Option(None, "--weights", help="Folder of <method>.pt (a `train --out` folder: each method its file, or its <method>@fov<deg>.pt for a sensor of that field of view; sets CSO_WEIGHTS_DIR), or one <method>.pt file, which that method then uses exactly, whatever the sensor (sets CSO_WEIGHTS_FILE), for the policy service instead of the shipped weights"),
    settings: list[str] | None = typer.Option(
        None, "--set", help="KEY=VALUE into the profile, repeatable, a dotted KEY for a nested one (seed=3, services.sim.viewer=true; --dry-run prints the profile)"
    ),
    dry_run: bool = typer.Option(False, "--dry-run", help="Validate, print the profile as the services would read it (YAML), start nothing"),
    resolved: bool = typer.Option(
        False,
        "--resolved",
        help="Validate, print every parameter the run would use, defaults filled in (YAML, itself a profile), start nothing; the folders the run would write in (--runs-dir, --record-out) are checked with --dry-run only",
    ),
    animate: bool = typer.Option(
        False, "--animate", help="At the end, also write the episode as a GIF under animations/, as eval does (records the run to do so, as --record)"
    ),
    foxglove: bool = typer.Option(
        False, "--foxglove", help="Also serve the episode live to Foxglove on ws://127.0.0.1:8765 (the foxglove_bridge service; needs foxglove-sdk)"
    ),
    without: list[str] | None = typer.Option(
        None,
        "--without",
        autocompletion=_complete_services,
        help="Leave this service of the profile out of the run, repeatable (--without policy: another run's shared policy serves this robot); not sim nor ros2_bridge",
    ),
) -> None:
    """Start the router and every service of a profile, supervise them, write results when the episode ends."""
    import threading  # noqa: PLC0415

    from cso_runtime.processes import restore_signal_handlers, stop_on_signals  # noqa: PLC0415

    # First: Ctrl-C, SIGTERM or SIGHUP from here on is kept, and acted on where `up` can stop cleanly (before it
    # makes its run folder, or the launcher's own checks), never a traceback or a run left half-started.
    stop = threading.Event()
    previous_handlers = stop_on_signals(stop)
    ctx.call_on_close(lambda: restore_signal_handlers(previous_handlers))  # however `up` ends (run inside another program)
    from cso_runtime.config import EXIT_INTERRUPTED, LOG_FORMAT, ConfigError  # noqa: PLC0415
    from cso_runtime.current_run import current_launcher_alive, down_command, read_current_run  # noqa: PLC0415
    from cso_runtime.processes import StopRequested, stop_raises  # noqa: PLC0415

    if not (dry_run or resolved):  # `down` finds this `up` however long its check takes (current_run.STARTING_UP_GLOB)
        ctx.call_on_close(_named_starting_up(runs_dir))
    try:
        # The check starts nothing: a stop (`down`, Ctrl-C) ends it where it is, however long it would still take.
        with stop_raises(stop):
            from cso_runtime.launcher import run_foreground, start_detached  # noqa: PLC0415
            from cso_runtime.run_profile import REAL_ROBOT_SCENE, UNUSED_BY_A_REAL_ROBOT, load_profile  # noqa: PLC0415

            weights_given = None if weights is None else _use_weights(weights)
            try:
                overrides = {"scene": scene, "method": method, "robot": robot, "seed": seed, "lockstep": lockstep}
                prof, data = load_profile(
                    profile, overrides, connect=list(connect or []), namespace=namespace, settings=parse_settings(settings or []), foxglove=foxglove, without=list(without or []),
                    zenoh_config=None if zenoh_config is None else str(zenoh_config),
                )
            except (ConfigError, ValueError) as exc:
                _fail(str(exc), 2)
            _warn_of_weights_trained_otherwise(prof)
            _warn_of_unfed_inputs(prof)
            _warn_of_a_watchdog_within_a_step(prof)
            _warn_of_a_start_in_a_wall(prof)
            _warn_of_realtime_not_permitted(prof)
            checks_folders = dry_run or not resolved  # --resolved alone: the profile to run later, wherever it will write
            if record_out is not None and checks_folders:
                from cso_runtime.recording import names_a_folder  # noqa: PLC0415

                if not names_a_folder(record_out) and Path(record_out).exists():  # as `record --out`: an earlier recording is never written over
                    _fail(f"--record-out {record_out}: the file exists; give another, or a folder, or remove it first", 2)
            if dry_run or resolved:
                from cso_runtime.config import commented_yaml  # noqa: PLC0415

                if checks_folders:
                    _up_folders_or_exit(record_out, runs_dir, make=False)  # `up` would refuse them: not "valid", nothing made
                outside = prof.left_out_services()
                left_out = f" (without {', '.join(outside)}: not started by this run)" if outside else ""
                comments = [f"profile {prof.name}, valid: `up` would start {', '.join(prof.services)} for robot {prof.robot}{left_out}"]
                comments.append(f"read from {_profile_file_said(profile)}")  # ./configs/profiles/ goes before the packaged ones
                if resolved:
                    comments.append("every parameter as the run would use it, defaults filled in (`up --dry-run`: the profile as written)")
                    if prof.scene_label == REAL_ROBOT_SCENE:
                        comments.append(f"scene: {REAL_ROBOT_SCENE} ({' and '.join(UNUSED_BY_A_REAL_ROBOT)} left out: never loaded)")
                    if weights_given is not None:  # a setting of the run that no profile key holds: the profile alone would run the shipped weights
                        from cso_runtime.learned.weights import method_of_file  # noqa: PLC0415

                        whose = "the learned methods'" if weights_given.is_dir() else f"{method_of_file(weights_given)}'s"
                        comments.append(f"{whose} weights from --weights {weights_given} (no profile key: give it again with this profile)")
                    comments += _fixed_simulator_settings_said(prof)
                typer.echo(commented_yaml(comments, prof.effective() if resolved else data), nl=False)
                return
            current = read_current_run(runs_dir)
            if current is not None and current_launcher_alive(current):
                # One current run per runs folder: a second one would take over runs/current.json and leave the first
                # beyond the reach of `status` and `down`, whichever robot it drives.
                _fail(
                    f"run {current.get('run_id')} (robot {current.get('robot')}) is already running from {runs_dir}; "
                    f"{down_command(runs_dir)} first, or start this one with its own --runs-dir",
                    2,
                )
    except StopRequested:
        _fail("interrupted (`cso-runtime down`, Ctrl-C or a signal) while checking the profile: no run was started", EXIT_INTERRUPTED)
    recording: bool | Path = record if record_out is None else Path(record_out)
    _up_folders_or_exit(record_out, runs_dir)  # before the router and the services start
    if stop.is_set():
        _fail("interrupted; no run was started", EXIT_INTERRUPTED)
    if detach:
        code, message = start_detached(prof, data, runs_dir, record=recording, animate=animate, stop_event=stop)
        typer.echo(message, err=code != 0)
        raise typer.Exit(code)
    import logging  # noqa: PLC0415

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    raise typer.Exit(run_foreground(prof, data, runs_dir, live=live, record=recording, animate=animate, stop_event=stop))


def _fixed_simulator_settings_said(prof: Profile) -> list[str]:
    """``up --resolved``'s word of the simulator's settings that no profile key of their own holds (the 2D simulator's
    collision disc, from ``exploration.robot``, and its substeps), which the run records in ``meta.sim_settings`` as it does the MuJoCo LIMO's (``services.sim.mujoco``,
    in the YAML): the whole configuration, the YAML still a profile that runs the same."""
    fixed = prof.simulator_settings()
    if not fixed or prof.simulator() == "mujoco":  # none to run (a real robot), or each one in services.sim.mujoco
        return []
    said = ", ".join(f"{key} {value}" for key, value in fixed.items())
    return [f"the {prof.simulator()} simulator's settings as the run records them (summary.json's meta.sim_settings, no profile key of their own): {said}"]


@app.command("status", rich_help_panel="Runtime (Zenoh services)")
def status_command(
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table"),
    watch: bool = typer.Option(False, "--watch", help="Refresh every --period seconds until Ctrl-C or the run ends (a detached run: its episode)"),
    period_s: float = typer.Option(1.0, "--period", **_bounded(0.1, 3600.0, "s"), help="Seconds between two --watch refreshes (0.1 to 3600)"),
    robot: str | None = typer.Option(None, "--robot", help="Robot id (default: the current run's)"),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """State, step, coverage, explored area, path length, goal, decisions and service health of the running episode."""
    from cso_runtime.status import status_main  # noqa: PLC0415

    raise typer.Exit(status_main(list(connect or []), robot, as_json, watch, runs_dir, period_s))


@app.command("save-map", rich_help_panel="Runtime (Zenoh services)")
def save_map_command(
    out: str = typer.Option("map", "--out", "-f", help="Where to write: OUT.yaml and OUT.pgm (or .png), as map_saver_cli -f; a folder (existing, or ending in /) gets map.yaml"),
    image_format: str = typer.Option("pgm", "--format", "--fmt", help="Image format: pgm or png (--fmt, as map_saver_cli)"),
    robot: str | None = typer.Option(None, "--robot", help="Robot id (default: the current run's)"),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """Save the running episode's map as Nav2 map_server files (YAML + image), like map_saver_cli."""
    from cso_runtime.map_files import IMAGE_FORMATS  # noqa: PLC0415
    from cso_runtime.status import save_map_main  # noqa: PLC0415

    if image_format.lower() not in IMAGE_FORMATS:  # any case, as map_saver_cli's --fmt
        _fail(f"--format {image_format!r}: expected one of {', '.join(IMAGE_FORMATS)}", 2)
    _read_grids_of_any_run()
    raise typer.Exit(save_map_main(list(connect or []), robot, out, image_format.lower(), runs_dir))


@app.command("pause", rich_help_panel="Runtime (Zenoh services)")
def pause_command(
    reason: str = typer.Option("", "--reason", help="Why (shown by `status`; at most 1,024 characters)"),
    robot: str | None = typer.Option(None, "--robot", help="Robot id (default: the current run's)"),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """Pause exploration: the robot holds still (zero velocity), the run goes on, until `resume` (explore_lite's explore/resume false)."""
    from cso_runtime.config import utf8_text  # noqa: PLC0415
    from cso_runtime.messages import MAX_RESUME_REASON_CHARS  # noqa: PLC0415
    from cso_runtime.status import explore_resume_main  # noqa: PLC0415

    reason = utf8_text(reason)  # a byte UTF-8 cannot carry (a Latin-1 terminal's): escaped, not a traceback on sending
    if len(reason) > MAX_RESUME_REASON_CHARS:  # every service would drop the pause: the robot would go on
        _fail(f"--reason is {len(reason):,} characters; at most {MAX_RESUME_REASON_CHARS:,} (messages.MAX_RESUME_REASON_CHARS): say it shorter", 2)
    raise typer.Exit(explore_resume_main(list(connect or []), robot, runs_dir, resume=False, reason=reason))


@app.command("resume", rich_help_panel="Runtime (Zenoh services)")
def resume_command(
    robot: str | None = typer.Option(None, "--robot", help="Robot id (default: the current run's)"),
    connect: list[str] | None = typer.Option(None, "--connect", help="Zenoh endpoint (default: the current run's router)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
) -> None:
    """Resume exploration after `pause`: the robot moves on toward its goal (explore_lite's explore/resume true)."""
    from cso_runtime.status import explore_resume_main  # noqa: PLC0415

    raise typer.Exit(explore_resume_main(list(connect or []), robot, runs_dir, resume=True))


@app.command("down", rich_help_panel="Runtime (Zenoh services)")
def down_command(
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the current run file lives"),
    timeout: float | None = typer.Option(
        None, "--timeout-s", **_bounded(0.0, unit="s"),  # "\\[": typer renders help as rich markup, which drops an unescaped [word ...] as a tag
        help="How long the launcher may take to stop its services and write its results before escalating \\[default: three times the run's supervision.stop_timeout_s, plus 10 s]",
    ),
) -> None:
    """Stop the running episode and every service process (SIGINT, then SIGTERM, then SIGKILL)."""
    from cso_runtime.current_run import down  # noqa: PLC0415

    ok, message = down(runs_dir, timeout)
    typer.echo(message, err=not ok)
    raise typer.Exit(0 if ok else 1)


@app.command("router", rich_help_panel="Runtime (Zenoh services)")
def router_command(
    ctx: typer.Context,
    listen: list[str] | None = typer.Option(
        None, "--listen", help="Endpoint to listen on, repeatable (default tcp/0.0.0.0:7447: Zenoh's port on every interface, as zenohd; port 0: any free port)"
    ),
    connect: list[str] | None = typer.Option(None, "--connect", help="Another router to join, repeatable (a robot's zenoh-bridge-ros2dds: tcp/ROBOT_IP:7447)"),
    connect_timeout_s: float | None = typer.Option(
        None, "--connect-timeout-s", **_bounded(0.0, unit="s", low_open=True), help="How long to wait to reach the routers of --connect before giving up, exit 3 (default 10 s, as for `up`)"
    ),
    zenoh_config: Path | None = typer.Option(None, "--zenoh-config", help="Zenoh config file (JSON5) the router starts from: user/password, TLS, access control"),
    as_json: bool = typer.Option(False, "--json", help="Print the endpoints it listens on as one line of JSON"),
) -> None:
    """Run the Zenoh router that `up` embeds, alone, until Ctrl-C: for runs, services and tools on several hosts to join (no zenohd needed)."""
    import json  # noqa: PLC0415
    import threading  # noqa: PLC0415

    from cso_runtime.config import EXIT_INTERRUPTED, EXIT_NO_ZENOH, ConfigError, seconds  # noqa: PLC0415
    from cso_runtime.processes import restore_signal_handlers, stop_on_signals  # noqa: PLC0415
    from cso_runtime.transport import (  # noqa: PLC0415
        JOIN_TIMEOUT_S,
        LISTEN_IN_USE,
        ROUTER_LISTEN,
        STOPPED,
        UNREACHABLE,
        TransportConfig,
        TransportError,
        listen_in_use_hint,
        open_router,
    )

    stop = threading.Event()  # Ctrl-C, SIGTERM and SIGHUP stop the router cleanly, exit 0, from here on
    previous_handlers = stop_on_signals(stop)
    ctx.call_on_close(lambda: restore_signal_handlers(previous_handlers))
    if zenoh_config is not None:
        _use_zenoh_config(zenoh_config)  # exit 2 for a file Zenoh or the runtime would refuse
    endpoints, joined = list(listen or [ROUTER_LISTEN]), list(connect or [])
    connect_timeout_s = JOIN_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s
    try:  # a malformed endpoint, or a timeout a profile's router.connect_timeout_s may not be, is a usage error (exit 2), before anything opens
        seconds("connect_timeout_s", positive=True)["connect_timeout_s"].check("--connect-timeout-s", connect_timeout_s)
        TransportConfig(mode="router", listen=endpoints, connect=joined, connect_timeout_s=connect_timeout_s).validate()
    except (ConfigError, TransportError) as exc:
        _fail(str(exc), 2)
    if joined:  # a router to join that is off is only said once the timeout has passed: say the wait meanwhile
        typer.echo(f"joining {', '.join(joined)} (up to {connect_timeout_s:g} s, --connect-timeout-s)", err=True)
    try:
        session, endpoints = open_router(endpoints, joined, connect_timeout_s, stop=stop)
    except TransportError as exc:
        if exc.cause == STOPPED:
            _fail("interrupted before the router opened", EXIT_INTERRUPTED)
        if exc.cause == LISTEN_IN_USE:
            pick = " ".join(f"--listen {ep.rpartition(':')[0]}:PORT" for ep in endpoints)
            _fail(f"{exc}; {listen_in_use_hint(endpoints, 'the router', pick)}; is a router (zenohd, a zenoh bridge, `up`) already running there?", EXIT_NO_ZENOH)
        _fail(f"{exc}" + ("; is the router to join running and reachable?" if exc.cause == UNREACHABLE else ""), EXIT_NO_ZENOH)
    with session:
        if as_json:
            typer.echo(json.dumps({"listen": endpoints, "connect": joined, "zid": str(session.zid())}))
        else:
            typer.echo(f"router {session.zid()} listening on {', '.join(endpoints)}" + (f", joined to {', '.join(joined)}" if joined else "") + " (Ctrl-C to stop)")
            typer.echo(f"  join it with --connect {endpoints[0].replace('/0.0.0.0:', '/THIS_HOST:').replace('/[::]:', '/THIS_HOST:')}", err=True)
        while not stop.wait(1.0):
            pass
    typer.echo("router stopped", err=True)


@app.command("runs", rich_help_panel="Runtime (Zenoh services)")
def runs_command(
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the run folders are"),
    limit: int = typer.Option(20, "--limit", min=1, help="Show the newest N runs"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table"),
    keep: int | None = typer.Option(None, "--keep", min=0, help="Prune: the runs beyond the newest N (listed; --yes deletes them; default: none pruned)"),
    older_than: float | None = typer.Option(None, "--older-than", **_bounded(0.0, unit="days"), help="Prune: the runs started over DAYS days ago (listed; --yes deletes them; default: none pruned)"),
    yes: bool = typer.Option(False, "--yes", help="Delete the runs --keep/--older-than select (never the current or a running one)"),
) -> None:
    """List the runs `up` left in --runs-dir: state, scene, method and the episode's Table 1 row; or prune old ones."""
    import json  # noqa: PLC0415

    from cso_runtime.runs import list_runs  # noqa: PLC0415

    if not runs_dir.is_dir():  # a typo, another working folder: not "no runs in nosuch" and exit 0, as of an empty one
        what = "it is a file" if runs_dir.exists() else "it does not exist"
        _fail(f"no runs folder {runs_dir}: {what} (`up` makes it; give --runs-dir of the folder `up` used)", 1)
    if keep is not None or older_than is not None:
        raise typer.Exit(_prune_runs(runs_dir, keep, older_than, yes, as_json))
    if yes:
        _fail("--yes deletes the runs that --keep N or --older-than DAYS select: give one of them", 2)
    listed = list_runs(runs_dir, limit)
    rows = [r.as_dict() for r in listed]
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        typer.echo(f"no runs in {runs_dir}")
        return
    from rich import box  # noqa: PLC0415
    from rich.markup import escape  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    from cso_runtime.live_view import NO_COVERAGE, table_console  # noqa: PLC0415 - the one word status, the live view and report.html use
    from cso_runtime.run_profile import REAL_ROBOT_SCENE  # noqa: PLC0415

    def num(value: object, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    table = Table(title=escape(f"runs in {runs_dir}"), box=box.SIMPLE_HEAD)
    table.add_column("run: scene, method", overflow="fold", min_width=34)
    table.add_column("state", overflow="fold", min_width=6)
    for col in ("took", "steps", "cover %", "m2", "m2/step"):
        table.add_column(col, justify="right", no_wrap=True)
    from cso_runtime.status import lost_results_short  # noqa: PLC0415

    for run, r in zip(listed, rows, strict=True):
        restarts = r["restarts"]
        state = r["state"] + (f", {restarts} restart{'s' if restarts != 1 else ''}" if restarts else "") + (f": {r['reason']}" if r["reason"] else "")
        if r["lost_results"]:  # the run went on with another episode: its results, if any, are that one's
            state += f"; {lost_results_short(r['lost_results'], run.referee)}"
        took = "-" if r["duration_s"] is None else f"{int(r['duration_s'] // 60)} min {r['duration_s'] % 60:.0f} s" if r["duration_s"] >= 60 else f"{r['duration_s']:.0f} s"
        steps = f"{r['stopped_at_step']} (stopped)" if r["steps"] is None and r["stopped_at_step"] is not None else num(r["steps"], ".0f")
        table.add_row(
            escape(r["run_id"] + "".join(f"\n  {known}" for known in [", ".join(filter(None, (REAL_ROBOT_SCENE if r["real_robot"] else r["scene"], r["method"])))] if known)),
            state, took, steps,
            num(r["coverage_pct"], ".1f") if r["coverage_measured"] else NO_COVERAGE, num(r["explored_area_m2"], ".1f"), num(r["efficiency_m2_per_step"], ".3f"),
        )
    table_console(table).print(table)  # `runs > runs.txt`, `runs | grep`: a long scene or reason on its line, not folded


LOG_COLOURS = ("cyan", "green", "yellow", "magenta", "blue", "bright_red", "bright_cyan", "bright_green")


def _prune_runs(runs_dir: Path, keep: int | None, older_than_days: float | None, delete: bool, as_json: bool) -> int:
    """``runs --keep/--older-than``: list the run folders selected, and delete them with ``--yes``; the exit code."""
    import json  # noqa: PLC0415

    from cso_runtime.runs import delete_runs, folder_bytes, plan_prune, summarize_run  # noqa: PLC0415

    plan = plan_prune(runs_dir, keep, older_than_days)
    sizes = {d: folder_bytes(d) for d in plan.prune}
    rows = [{**summarize_run(d).as_dict(), "bytes": sizes[d]} for d in plan.prune]
    errors = delete_runs(plan.prune) if delete else []
    if as_json:
        spared = [str(d) for d in plan.spared]
        not_runs = {str(d): why for d, why in plan.not_runs.items()}
        typer.echo(json.dumps({"runs_dir": str(runs_dir), "deleted": delete and not errors, "runs": rows, "spared": spared, "errors": errors, "not_runs": not_runs}, indent=2))
    else:
        mb = sum(sizes.values()) / 1e6
        said = "deleted" if delete else "would delete"
        typer.echo(f"{said} {len(rows)} run(s) in {runs_dir} ({mb:.1f} MB)" + (":" if rows else ""))
        for r in rows:
            typer.echo(f"  {r['run_id']}  {r['state']}, {r['bytes'] / 1e6:.1f} MB")
        for d in plan.spared:
            typer.echo(f"  kept: {d.name} (the current run, or its launcher or one of its services runs)")
        for d, why in plan.not_runs.items():
            typer.echo(f"  left alone: {d.name} ({why})")
        if rows and not delete:
            typer.echo("nothing deleted: add --yes to delete them")
    for error in errors:
        typer.echo(f"error: cannot delete {error}", err=True)
    return 1 if errors else 0


@app.command("logs", rich_help_panel="Runtime (Zenoh services)")
def logs_command(
    services: list[str] | None = typer.Argument(None, metavar="SERVICE", autocompletion=_complete_log_services, help="Services to show (default: all, the launcher's own log included)"),
    run: str | None = typer.Option(None, "--run", autocompletion=_complete_run_ids, help="Run id under --runs-dir, or a run folder (default: the current run, else the newest)"),
    follow: bool = typer.Option(False, "--follow", "-f", help="Keep printing new lines until the run ends (or Ctrl-C)"),
    tail: int | None = typer.Option(None, "--tail", "-n", min=0, help="Only the last N lines of each service (default: every line)"),
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="Where the run folders are"),
) -> None:
    """A run's service logs merged in time order, each line after its service's name (like `docker compose logs`)."""
    from cso_runtime.runs import (  # noqa: PLC0415
        LOG_DIR,
        RunError,
        await_service_logs,
        follow_logs,
        log_files,
        logs_grow,
        read_logs,
        resolve_run,
        run_is_live,
        select_services,
    )

    if follow and run is None:  # `up ... &` then `logs -f`: the run it starts, not "no runs" (or the last run's logs)
        _await_starting_up(runs_dir)
    try:
        run_dir = resolve_run(runs_dir, run)
        if follow and services:  # a starting run's services have no log until they are spawned
            await_service_logs(run_dir, services)
        files = select_services(log_files(run_dir), services or [])
    except RunError as exc:
        _fail(str(exc), 1)
    except KeyboardInterrupt:
        raise typer.Exit(0) from None
    live = logs_grow(run_dir)
    if not files and not (follow and live):  # said, not an empty output and exit 0 (a run that is starting: followed)
        where = f"{run_dir / LOG_DIR}/ holds no .log file" if (run_dir / LOG_DIR).is_dir() else f"it has no {run_dir / LOG_DIR}/ folder"
        _fail(f"run {run_dir.name} has no log: {where}", 1)
    width = max([len(n) for n in log_files(run_dir)] + [8])
    colours: dict[str, str] = {}

    def emit(line: LogLine) -> None:
        colour = colours.setdefault(line.service, LOG_COLOURS[len(colours) % len(LOG_COLOURS)])
        typer.echo(typer.style(f"{line.service:<{width}} | ", fg=colour) + line.text)

    lines, readers = read_logs(files, tail, finished=not (follow and live))
    for line in lines:
        emit(line)
    if follow:
        if live:
            try:
                follow_logs(run_dir, readers, emit, alive=lambda: logs_grow(run_dir), pick_up_new=not services)
            except KeyboardInterrupt:
                return
        if run_is_live(run_dir):  # a detached run after its episode: up for `status` until `down`, nothing more to follow
            from cso_runtime.current_run import down_command  # noqa: PLC0415

            # `--run FOLDER` may name a run outside --runs-dir: its down is that of the folder it is in
            its_runs_dir = runs_dir if run_dir.parent.resolve() == runs_dir.resolve() else run_dir.parent
            typer.echo(f"run {run_dir.name}'s episode has ended; the run stays up (for status) until {down_command(its_runs_dir)}", err=True)
        else:
            typer.echo(f"run {run_dir.name} has ended", err=True)  # also when it had before -f started: nothing to wait for


def _await_starting_up(runs_dir: Path, period_s: float = 0.2) -> None:
    """Wait while an ``up`` of ``runs_dir`` has written no run file yet (``current_run.starting_up_line``: its first
    second or more), saying so once (again if it changes: the ``up`` stopped, continued): ``logs -f`` right after ``up ... &`` answered "no runs in runs", or followed the
    previous run's logs and ended at once. Ctrl-C ends the command."""
    import time  # noqa: PLC0415

    from cso_runtime.current_run import ASK_AGAIN, current_launcher_alive, read_current_run, starting_up_line  # noqa: PLC0415

    said = ""
    try:  # a run file of a launcher gone (killed) is no run: the `up` starting writes its own
        while ((info := read_current_run(runs_dir)) is None or not current_launcher_alive(info)) and (starting := starting_up_line(runs_dir)):
            line = f"{starting.removesuffix(ASK_AGAIN)}; waiting for it..."
            if line != said:  # once, and again when it changes: an `up` stopped meanwhile (Ctrl-Z), or continued
                typer.echo(line, err=True)
                said = line
            time.sleep(period_s)
    except KeyboardInterrupt:
        raise typer.Exit(0) from None


@app.command("dataflow", rich_help_panel="Runtime (Zenoh services)")
def dataflow_command(
    profile: str = typer.Option("sim", "--profile", autocompletion=_complete_profiles, help="Profile name (./configs/profiles/, then the packaged ones) or a YAML path"),
    fmt: str = typer.Option("table", "--format", help="table, mermaid (a flowchart for Markdown viewers) or markdown (as runs/<run-id>/dataflow.md)"),
    without: list[str] | None = typer.Option(
        None, "--without", autocompletion=_complete_services, help="As `up --without`: the profile minus this service, repeatable, shown as not started by the run"
    ),
) -> None:
    """Show which service feeds which in a profile: every node's inputs and outputs (dora-rs style), from the code."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.keys import topic_key  # noqa: PLC0415
    from cso_runtime.run_profile import load_profile  # noqa: PLC0415
    from services.dataflow import OUTSIDE_NOTE, nodes_of, to_markdown, to_mermaid, unconnected, wiring_of  # noqa: PLC0415

    if fmt not in ("table", "mermaid", "markdown"):
        _fail(f"--format must be table, mermaid or markdown, got {fmt!r}", 2)
    try:
        # Nothing is joined here: a profile that needs a router to join (limo-ros2) gets a stand-in.
        prof, _ = load_profile(profile, {}, connect=["tcp/127.0.0.1:7447"], without=list(without or []))
    except (ConfigError, ValueError) as exc:
        _fail(str(exc), 2)
    outside = prof.left_out_services()
    nodes = nodes_of([*prof.services, *outside], prof.services)
    if fmt == "mermaid":
        typer.echo(to_mermaid(nodes, outside), nl=False)
        return
    if fmt == "markdown":
        typer.echo(to_markdown(prof.name, nodes, outside), nl=False)
        return
    from rich.table import Table  # noqa: PLC0415

    from cso_runtime.live_view import table_console  # noqa: PLC0415

    table = Table(title=f"profile {prof.name}: keys under cso/{prof.robot}/")
    for col in ("node", "inputs (from)", "outputs (to)"):
        table.add_column(col, overflow="fold")  # on a narrow terminal a node's class of one's own (module.path:Attribute) wraps, not cut to "…"
    labels = {n.name: n.label for n in nodes}
    for w in wiring_of(nodes):
        ins = "\n".join(f"{key} <- {', '.join(peers) or '(none)'}" for key, peers in w.inputs)
        outs = "\n".join(f"{key} -> {', '.join(peers) or '(none)'}" for key, peers in w.outputs)
        table.add_row(f"{w.name} ({OUTSIDE_NOTE})" if w.name in outside else labels[w.name], ins or "-", outs or "-")
    table_console(table).print(table)  # a file gets each cell unwrapped
    for name, topics in unconnected(nodes).items():
        typer.echo(f"note: nothing in this profile publishes {', '.join(topic_key(t) for t in topics)} for {name}")


@app.command("doctor", rich_help_panel="Set-up")
def doctor_command(
    runs_dir: Path = typer.Option(Path("runs"), "--runs-dir", help="The runs folder `up` would write to"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table"),
) -> None:
    """Check that this machine can run everything: libraries, Zenoh on loopback, the MuJoCo LIMO, weights, profiles (exit 1 if not)."""
    import json  # noqa: PLC0415

    from cso_runtime.doctor import run_checks  # noqa: PLC0415

    results = run_checks(runs_dir)
    if as_json:
        typer.echo(json.dumps([r.as_dict() for r in results], indent=2))
    else:
        from rich.markup import escape  # noqa: PLC0415
        from rich.table import Table  # noqa: PLC0415

        from cso_runtime.live_view import table_console  # noqa: PLC0415

        table = Table(title="cso-runtime doctor", show_header=False)
        for r in results:
            table.add_row(r.name, "[green]ok[/green]" if r.ok else "[red]FAIL[/red]", escape(r.detail))
        table_console(table).print(table)  # `doctor > report.txt`: each check's detail on its line
        failed = [r.name for r in results if not r.ok]
        typer.echo(f"{len(results) - len(failed)} of {len(results)} checks passed" + (f"; failed: {', '.join(failed)}" if failed else ""))
    if not all(r.ok for r in results):
        raise typer.Exit(1)


@app.command("train", context_settings={"allow_extra_args": True, "ignore_unknown_options": True}, rich_help_panel="Learned policy")
def train_command(
    ctx: typer.Context,
    config: Path | None = typer.Option(
        None, "--config", help="YAML with the fields of learned.ppo.Args (default configs/train.yaml, the recipe; a field a file of your own leaves out takes Args' default, not the recipe's; with --resume, the checkpoint's own configuration)"
    ),
    variant: str | None = typer.Option(None, "--variant", help="cso, cso-no-info, cso-no-mask, cso-sm, cso-vdm or gnn-baseline"),
    out: Path | None = typer.Option(None, "--out", help="Output folder (overrides out_dir)"),
    seed: int | None = typer.Option(None, "--seed", help="Seed (overrides the config; default: the config's seed)"),
    total_decisions: int | None = typer.Option(None, "--total-decisions", help="PPO budget in goal choices (default: the config's total_decisions)"),
    time_limit: float | None = typer.Option(None, "--time-limit-s", help="Stop after this many seconds of wall time (0 = none; default: the config's time_limit_s)"),
    resume: Path | None = typer.Option(None, "--resume", help="checkpoint.pt to continue from"),
    device: str | None = typer.Option(None, "--device", help="auto, cpu, cuda or cuda:N"),
    init_from: str | None = typer.Option(None, "--init-from", help="Fine-tune: start from these weights (a run's <variant>.pt or checkpoint.pt, or 'shipped')"),
    num_envs: int | None = typer.Option(None, "--num-envs", help="Parallel environments (default: the config's num_envs)"),
    async_envs: bool | None = typer.Option(None, "--async-envs/--sync-envs", help="One process per environment, or all in this one"),
    dungeon_dir: Path | None = typer.Option(None, "--dungeon-dir", help="Folder of Dungeon training plans"),
    tensorboard: bool | None = typer.Option(None, "--tensorboard/--no-tensorboard", help="Also write TensorBoard events into OUT/tensorboard (needs tensorboardX)"),
    settings: list[str] | None = typer.Option(None, "--set", help="KEY=VALUE for any field of the config (YAML value), repeatable"),
) -> None:
    """Train a learned CSO variant with PPO (optional greedy warm start); writes weights, CSV log and curve.

    Every field of learned.ppo.Args is also a flag, as in CleanRL: --learning-rate 3e-4 is --set learning_rate=3e-4
    (--no-anneal-lr for a false switch; a list field's flag given again adds to its list: --generated A --generated B)."""
    from cso_runtime.config import EXIT_INTERRUPTED, ConfigError  # noqa: PLC0415
    from cso_runtime.learned.ppo import KEPT_CHECKPOINTS_DIR, matching_eval_command, train  # noqa: PLC0415 - torch only for this command
    from cso_runtime.learned.vector_env import EnvWorkerDied  # noqa: PLC0415

    overrides = {"variant": variant, "out_dir": str(out) if out else None, "seed": seed, "total_decisions": total_decisions,
                 "time_limit_s": time_limit, "resume": str(resume) if resume else None, "device": device,
                 "init_from": init_from, "num_envs": num_envs, "async_envs": async_envs,
                 "dungeon_dir": str(dungeon_dir) if dungeon_dir else None, "tensorboard": tensorboard}
    try:
        field_flags = args_field_flags(ctx.args)  # CleanRL's flags
        refuse_two_values_of_a_field(overrides, field_flags, settings or [])
    except ConfigError as exc:
        _fail(str(exc), 2)
    # One pair a field, its last value (a field flag given twice; its --set of the same value): the command recorded in
    # <variant>.json runs again as it is, where one --set key given twice with other values is refused.
    settings = list({item.partition("=")[0].strip(): item for item in [*field_flags, *(settings or [])]}.values())
    if config is None and resume is None:
        config = DEFAULT_TRAIN_CONFIG  # a resume without --config goes on with its checkpoint's configuration
    args = training_args(config, overrides, settings)
    output_dir_or_exit(args.out_dir, "out_dir")
    checkpoint = Path(args.out_dir) / "checkpoint.pt"
    started = time.time()

    def resume_hint() -> str:
        # This run's checkpoint (or the one it resumed from), not an earlier run's left in the same folder.
        ours = checkpoint.is_file() and (checkpoint.stat().st_mtime >= started or args.resume and Path(args.resume).resolve() == checkpoint.resolve())
        if ours:
            return f"; continue from the last checkpoint with --resume {checkpoint}"
        return f"; no checkpoint of this run yet (the first comes after PPO update {args.checkpoint_every}): nothing to resume, run the command again"

    stop_requested = interrupt_on_sigterm(wait_on_second=True, stop_deadline_s=TRAIN_STOP_DEADLINE_S, last_words=lambda: f"interrupted{resume_hint()}")
    words = ["cso-runtime", "train", *(["--config", str(config)] if config is not None else [])]
    command = shlex.join(words + [w for flag in training_flags(overrides, settings) for w in flag])  # recorded in <variant>.json
    try:
        record = train(args, log=typer.echo, command=command, stop_requested=stop_requested)
    except ConfigError as exc:  # another train is writing --out
        _fail(str(exc), 2)
    except (EnvWorkerDied, KeyboardInterrupt) as exc:
        why = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"error: training stopped: {exc}"
        typer.echo(f"{why}{resume_hint()}", err=True)
        raise typer.Exit(EXIT_INTERRUPTED if isinstance(exc, KeyboardInterrupt) else 1) from None
    out = Path(args.out_dir)
    files = ", ".join(name for name in (f"{args.variant}.pt", f"{args.variant}_log.csv", f"{args.variant}_curve.png", f"{args.variant}.json", "checkpoint.pt") if (out / name).is_file())
    kept = sorted((out / KEPT_CHECKPOINTS_DIR).glob(f"update_*/{args.variant}.pt")) if args.keep_checkpoints else []
    if kept:
        files += f", {KEPT_CHECKPOINTS_DIR}/ ({len(kept)} kept: {kept[0].parent.name} to {kept[-1].parent.name})"
    typer.echo(f"done: {record['ppo_decisions']} PPO decisions, {record['warm_start_decisions']} warm-start decisions, {record['wall_time_s']} s -> {out}: {files}")
    typer.echo(f"evaluate it as it was trained: {matching_eval_command(args)} (and your --maps, --out)")
    if kept:
        typer.echo(f"a kept checkpoint likewise, with --weights {kept[-1].parent} (the last; each update_<N> holds the weights after the log's update N)")


@app.command("collect-teacher", rich_help_panel="Learned policy")
def collect_teacher_command(
    out: Path = typer.Option(..., "--out", help="Teacher-data file to write (.npz); train with --set warm_start_data=[FILE]"),
    config: Path | None = typer.Option(DEFAULT_TRAIN_CONFIG, "--config", help="YAML with the fields of learned.ppo.Args (scenes, variant, masks)"),
    teacher: str | None = typer.Option(None, "--teacher", help="greedy-dist, utility, greedy-info or rollout (default: rollout, or --set warm_start_teacher's)"),
    workers: int = typer.Option(2, "--workers", min=1, help="Processes, one environment each"),
    decisions: int = typer.Option(1200, "--decisions", min=1, help="Decisions in all (the time limit may stop earlier)"),
    time_limit: float = typer.Option(0.0, "--time-limit-s", **_bounded(0.0, unit="s"), help="Each worker stops after this wall time (0 = none)"),
    seed: int | None = typer.Option(None, "--seed", help="Worker i uses seed + i (default: the config's seed)"),
    dungeon_dir: Path | None = typer.Option(None, "--dungeon-dir", help="Folder of Dungeon training plans"),
    settings: list[str] | None = typer.Option(None, "--set", help="KEY=VALUE for any field of the config (YAML value), repeatable"),
) -> None:
    """Collect a warm-start teacher's decisions once (the rollout teacher costs seconds per decision) for several training runs to imitate."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.learned.ppo import ARGS_BOUNDS, collect_teacher_parallel  # noqa: PLC0415 - torch only for this command
    from cso_runtime.learned.vector_env import EnvWorkerDied  # noqa: PLC0415

    overrides: dict[str, object] = {"seed": seed, "warm_start_teacher": teacher, "dungeon_dir": str(dungeon_dir) if dungeon_dir else None}
    try:
        ARGS_BOUNDS["num_envs"].check("--workers", workers)  # a process each, as train's num_envs with async_envs
        refuse_two_values_of_a_field(overrides, [], settings or [])  # --seed 3 --set seed=4, as train refuses it
        # The default teacher, over the config file's (train's warm start's): no flag the user typed, so no error names it
        fixed = {"warm_start_teacher": "rollout"} if teacher is None and "warm_start_teacher" not in parse_settings(settings or []) else {}
    except ConfigError as exc:
        _fail(str(exc), 2)
    args = training_args(config, overrides, settings, fixed)
    if out.is_dir():  # said before hours of rollouts: the file was to be renamed over the folder at the end, a traceback
        _fail(f"--out {out} is a folder; give the file to write, such as {out / 'teacher.npz'}", 2)
    output_dir_or_exit(out.parent, f"--out {out}: its folder")  # before hours of rollouts, not after
    if out.is_file():  # as train says of an earlier run in its folder: an earlier collection is not replaced unsaid
        typer.echo(f"note: {out} exists (an earlier collection?); this one replaces it when it ends (a Ctrl-C before then keeps it)")
    from cso_runtime.config import EXIT_INTERRUPTED  # noqa: PLC0415

    t0 = time.time()
    interrupt_on_sigterm()
    try:
        collected = collect_teacher_parallel(args, workers, decisions, time_limit, log=typer.echo)
    except EnvWorkerDied as exc:
        _fail(f"{exc}; nothing was written", 1)
    except KeyboardInterrupt:
        _fail("interrupted; nothing was written (--time-limit-s stops the workers and keeps what they collected)", EXIT_INTERRUPTED)
    out.parent.mkdir(parents=True, exist_ok=True)
    collected.save(out)
    typer.echo(f"done: {len(collected)} {args.warm_start_teacher} decisions in {time.time() - t0:.0f} s -> {out}")


def output_dir_or_exit(path: Path | str, label: str, make: bool = True) -> None:
    """Make the folder a long command will write to before it starts, or exit 2 saying why. ``make`` False: only
    check that it could be made and written in (a dry run), making nothing."""
    from cso_runtime.config import ConfigError, check_output_dir, make_output_dir  # noqa: PLC0415

    try:
        (make_output_dir if make else check_output_dir)(path, label)
    except ConfigError as exc:
        _fail(str(exc), 2)


def _up_folders_or_exit(record_out: str | None, runs_dir: Path, make: bool = True) -> None:
    """The folders ``up`` writes in, made (``make`` False: checked, as ``up --dry-run`` does) or exit 2 saying why:
    ``--record-out``'s (a folder, where the launcher puts <run-id>.mcap, or a file's folder) and ``--runs-dir``."""
    from cso_runtime.recording import names_a_folder  # noqa: PLC0415

    if record_out is not None:
        if names_a_folder(record_out):
            output_dir_or_exit(Path(record_out), "--record-out", make)
        else:
            output_dir_or_exit(Path(record_out).parent, f"--record-out {record_out}: its folder", make)
    output_dir_or_exit(runs_dir, "--runs-dir", make)


def training_args(config: Path | None, overrides: Mapping[str, object], settings: list[str] | None, fixed: Mapping[str, object] | None = None) -> Args:
    """``learned.ppo.Args`` from the YAML file (without one, for a ``resume``: the configuration its checkpoint holds),
    then ``fixed`` (the command's own values of fields no flag set: ``collect-teacher``'s default teacher), then the
    command's flags, then ``--set`` pairs; a missing file or a bad value exits with a clear error (code 2) before
    anything starts, naming the file and the flags as typed. A ``--set`` of a text field that YAML reads as another
    type (``out_dir=2024``) says how to write it (``--set out_dir='2024'``), as ``up`` and ``eval`` do, where the
    configuration takes that text (``variant=1``: ``'1'`` is no variant either, so the value's own error is said)."""
    from cso_runtime.config import (  # noqa: PLC0415
        ConfigError,
        field_types,
        from_dict,
        from_dict_with_hints,
        load_yaml,
        refuse_a_setting_read_as_another_type,
        set_said,
    )
    from cso_runtime.learned.ppo import (  # noqa: PLC0415
        Args,
        check_training_inputs,
        init_from_with_resume_problem,
        resumed_run_settings,
        training_scene_refs,
    )

    config = _packaged_if_missing(config)  # run outside the repository: the packaged recipe
    try:
        if config is None and overrides.get("resume"):
            data = resumed_run_settings(str(overrides["resume"]))
            if data:
                typer.echo(f"note: resuming with the configuration {overrides['resume']} holds (its run's --config and --set)", err=True)
        else:
            data = load_yaml(config) if config is not None else {}
        data.update({**(fixed or {}), **{k: v for k, v in overrides.items() if v is not None}})
        unset = dict(data)  # the configuration before the --set pairs: what a hint's values are weighed against
        pairs = parse_settings(settings or [], last_counts=True)  # field flags and --set, checked against each other
        data.update(pairs)
        if data.get("resume") and overrides.get("out_dir") is None and "out_dir" not in pairs:
            data["out_dir"] = str(Path(str(data["resume"])).parent)  # a resume goes on in its run's folder, not the config's out_dir
        where = str(config or "train")  # an error names the file, and the flags that changed it, as eval's and up's do
        flags = training_flags(overrides, settings)
        if flags:
            where += " with " + " ".join(" ".join(words) for words in flags)

        def check(args: Args) -> None:
            """What is checked of the configuration once it is read, before anything starts (a ConfigError or ValueError):
            the one check of the command and of the values a hint suggests."""
            training_scene_refs(args)  # a missing plan folder or a bad scene spec is said now, not after the set-up
            check_training_inputs(args)  # so are a device, checkpoint, weights or teacher data it cannot use
            if args.resume and args.init_from:  # a resume reads no init_from: other weights than its run's are refused
                if "init_from" in pairs:
                    said = set_said(pairs, "init_from")
                elif overrides.get("init_from") is not None:
                    said = " ".join(_flag_of("init_from", overrides["init_from"]))
                else:
                    said = f"init_from {args.init_from} in {config}"
                if problem := init_from_with_resume_problem(args, said):
                    raise ConfigError(problem)

        if pairs:  # `--set out_dir=2024` alone: how to write it, as `up` and `eval` say it, where the text is taken

            def refusal(values: dict[str, object]) -> str | None:
                try:
                    check(from_dict(Args, values, where))
                except (ConfigError, ValueError) as exc:
                    return str(exc)
                return None

            def takes(texts: dict[str, object]) -> object:  # the configuration with those values as text (no hint again)
                taken = from_dict(Args, {**data, **texts}, where)
                # Taken by the check too (`--set generated=1` suggested generated='1', no scene spec; `init_from=1`, no
                # file), unless what the check refuses is not theirs: the configuration without those values has it too.
                # Only the values the hint writes as text are left out: another --set refused by the check (`--set
                # init_from=gone.pt` beside `--set out_dir=2024`) is refused either way, and the hint is said first.
                if (refused := refusal({**data, **texts})) is not None:
                    hinted = {k for k, v in texts.items() if v != pairs.get(k)}
                    without = {k: v for k, v in data.items() if k not in hinted} | {k: unset[k] for k in hinted if k in unset}
                    if refused != refusal(without):
                        raise ConfigError(refused)
                return taken

            refuse_a_setting_read_as_another_type(pairs, field_types(Args), takes)
        args = from_dict_with_hints(Args, data, where)
        if config is not None and not data.get("resume"):  # once the configuration is taken: an error alone is one line
            _say_fields_left_at_defaults(config, data)
        check(args)
    except (ConfigError, ValueError) as exc:
        _fail(str(exc), 2)
    return args


def _say_fields_left_at_defaults(config: Path, data: Mapping[str, object]) -> None:
    """A note on stderr naming the fields a training config file leaves at ``learned.ppo.Args``' defaults where the
    packaged recipe (``configs/train.yaml``) has other values: a small file of a few fields is not the recipe with
    those fields changed."""
    from cso_runtime.config import load_yaml  # noqa: PLC0415
    from cso_runtime.learned.ppo import fields_left_at_defaults  # noqa: PLC0415

    left = fields_left_at_defaults(data, load_yaml(PACKAGED_CONFIGS / "train.yaml"))
    if left:
        said = ", ".join(f"{name} {default} (recipe: {value})" for name, default, value in left)
        typer.echo(
            f"note: {config} leaves {len(left)} fields at learned.ppo.Args' defaults, not configs/train.yaml's recipe: {said};"
            " to train the recipe with a few fields changed, leave out --config and give those with --set FIELD=VALUE (or --FIELD VALUE),"
            " or copy configs/train.yaml and edit the copy",
            err=True,
        )


TRAIN_FLAG_NAMES = {"out_dir": "--out", "resume": "--resume", "init_from": "--init-from", "warm_start_teacher": "--teacher"}
"""The flags of ``train`` and ``collect-teacher`` whose name is not the Args field's with dashes."""


def _flag_of(field_name: str, value: object) -> list[str]:
    """The command-line flag that set an ``Args`` field, as the words the user typed (``--num-envs 0``, ``--sync-envs``)."""
    if isinstance(value, bool):
        on, off = {"async_envs": ("--async-envs", "--sync-envs")}.get(field_name, (f"--{field_name.replace('_', '-')}", f"--no-{field_name.replace('_', '-')}"))
        return [on if value else off]
    return [TRAIN_FLAG_NAMES.get(field_name, "--" + field_name.replace("_", "-")), str(value)]


def training_flags(overrides: Mapping[str, object], settings: list[str] | None) -> list[list[str]]:
    """The flags and ``--set`` pairs a training command was given, each as its words: what its errors name and
    what ``train`` records as its command."""
    return [_flag_of(k, v) for k, v in overrides.items() if v is not None] + [["--set", item] for item in settings or []]


def args_field_flags(words: list[str]) -> list[str]:
    """The words ``train`` has no option of its own for, as ``--set`` pairs: each field of ``learned.ppo.Args`` is a
    flag, as each field of CleanRL's ``Args`` is (``--learning-rate 3e-4`` or ``--learning-rate=3e-4``:
    ``learning_rate=3e-4``; a switch alone, ``--norm-adv``, is true, ``--no-norm-adv`` false). A list field's flag
    adds to its list each time it is given, as ``eval --seeds`` and ``up --without`` do (``--generated A --generated
    B,C``: ``generated=[A, B, C]``), and takes several values after it, as CleanRL's tyro does (``--generated A B``);
    any other flag given twice keeps its last value, as typer does with ``train``'s own options. Anything else is a
    ``ConfigError`` that names the flag, and the field it may have meant."""
    import difflib  # noqa: PLC0415
    import typing  # noqa: PLC0415

    from cso_runtime.config import ConfigError, field_value, flag_value, text_field, yaml_text  # noqa: PLC0415
    from cso_runtime.learned.ppo import Args  # noqa: PLC0415

    types = typing.get_type_hints(Args)
    pairs: list[str] = []
    lists: dict[str, list[object]] = {}
    rest = list(words)
    while rest:
        word = rest.pop(0)
        if not word.startswith("--") or word == "--":
            raise ConfigError(f"unexpected argument {word!r} (train takes no arguments; its flags: cso-runtime train --help)")
        flag, given, value = word.partition("=")
        name = flag[2:].replace("-", "_")
        if name not in types and name.startswith("no_") and name[3:] in types:
            switch = f"--{name[3:].replace('_', '-')}"
            if types[name[3:]] is not bool:
                raise ConfigError(f"{flag}: {name[3:]} is not a switch (true or false); give {switch} VALUE")
            if given or (rest and not rest[0].startswith("--")):  # --no-progress=false, --no-progress false
                typed = word if given else f"{flag} {rest[0]}"
                raise ConfigError(
                    f"{typed}: {flag} takes no value (it sets {name[3:]} to false); write {flag} for false, {switch} for true, or {switch}=VALUE"
                )
            pairs.append(f"{name[3:]}=false")
            continue
        if name not in types:
            close = difflib.get_close_matches(name, list(types), n=1)
            meant = f": did you mean --{close[0].replace('_', '-')}?" if close else ""
            raise ConfigError(f"no such option {flag}{meant} (each field of learned.ppo.Args is a flag, as --set FIELD=VALUE is; cso-runtime train --help)")
        if typing.get_origin(types[name]) is list:
            values = [value] if given else []
            while not given and rest and not rest[0].startswith("--"):
                values.append(rest.pop(0))
            if not values:
                raise ConfigError(f"{flag} needs a value ({flag} VALUE, or several: {flag} A B, as --set {name}=A,B)")
            for one in values:
                lists.setdefault(name, []).extend(field_value(flag_value(one, types[name]), types[name], flag))
            continue
        if not given:
            if rest and not rest[0].startswith("--"):
                value = rest.pop(0)
            elif types[name] is bool:
                value = "true"
            else:
                raise ConfigError(f"{flag} needs a value ({flag} VALUE, as --set {name}=VALUE)")
        pairs.append(f"{name}={yaml_text(flag_value(value, types[name])) if text_field(types[name]) else value}")  # text as it is: 2024, on
    return pairs + [f"{name}={yaml_text(items)}" for name, items in lists.items()]


TRAIN_PATH_FIELDS: dict[str, Callable[[str], bool]] = {"out_dir": bool, "resume": bool, "dungeon_dir": bool, "init_from": lambda text: bool(text) and text != "shipped"}
"""The ``Args`` fields that name a path, each with its test of which texts are paths (``config.place_of``):
``--out runs/a``, ``--out-dir runs/a/`` and ``--set out_dir=$PWD/runs/a`` set one value; ``--init-from shipped``
names the shipped weights, not a file."""


def _profile_file_said(profile: str) -> str:
    """The file ``up --profile PROFILE`` reads, and whose it is: the working folder's ``configs/profiles/NAME.yaml``
    takes the place of the packaged profile of that name (``run_profile.profile_search_path``)."""
    from cso_runtime.run_profile import PACKAGED_PROFILES, find_profile  # noqa: PLC0415

    path = find_profile(profile)
    if Path(profile).suffix in (".yaml", ".yml"):  # a path given, as find_profile tells one from a name (sim.v2): the file itself
        return str(path)
    if path.parent == PACKAGED_PROFILES:
        return f"{path} (packaged)"
    shadowed = any((PACKAGED_PROFILES / f"{profile}{ext}").is_file() for ext in (".yaml", ".yml"))
    return f"{path} (the working folder's" + (f", ahead of the packaged {profile})" if shadowed else ")")


def refuse_two_values_of_a_field(overrides: Mapping[str, object], field_flags: list[str], settings: list[str]) -> None:
    """``train``'s own options (``--out``), its field flags (``--out-dir``, ``args_field_flags``' pairs) and ``--set``
    all set fields of ``learned.ppo.Args``: two of them that give one field different values are a ConfigError that
    names both (one of them took over the other in silence). The same value twice is fine; so is one flag given
    twice, whose last value counts, as typer's own options' does (a ``--set`` key twice is not: ``parse_settings``).
    A ``--set`` of a text field that YAML reads as another type is ``training_args``' to say, as ``up`` and ``eval``
    say it: with the configuration it would make."""
    import typing  # noqa: PLC0415

    from cso_runtime.config import (  # noqa: PLC0415
        field_value,
        place_of,
        refuse_two_values,
        set_said,
        text_field,
        yaml_text,
    )
    from cso_runtime.learned.ppo import Args  # noqa: PLC0415

    types = typing.get_type_hints(Args)

    def field_flag(name: str, value: object) -> str:
        dashed = name.replace("_", "-")
        if isinstance(value, bool):
            return f"--{dashed}" if value else f"--no-{dashed}"
        return f"--{dashed} {value if isinstance(value, str) and text_field(types.get(name)) else yaml_text(value)}"  # as typed

    def read(name: str, value: object) -> object:
        value = field_value(value, types[name], name)  # a ConfigError: from_dict says what is wrong with it
        return place_of(value, TRAIN_PATH_FIELDS[name]) if name in TRAIN_PATH_FIELDS else value

    given: dict[str, list[tuple[str, object]]] = {}
    for name, value in overrides.items():
        if value is not None:
            given.setdefault(name, []).append((" ".join(_flag_of(name, value)), value))
    for name, value in parse_settings(field_flags, last_counts=True).items():
        given.setdefault(name, []).append((field_flag(name, value), value))
    pairs = parse_settings(settings)
    for name, value in pairs.items():
        given.setdefault(name, []).append((set_said(pairs, name), value))
    refuse_two_values({name: said for name, said in given.items() if name in types}, read)  # a key no field is: from_dict names it


def parse_seeds(items: list[str]) -> list[int]:
    """``eval --seeds``' arguments, each one seed or several separated by commas (``--seeds 0,1 --seeds 2``)."""
    from cso_runtime.comparison import split_names  # noqa: PLC0415
    from cso_runtime.config import ConfigError  # noqa: PLC0415

    seeds = []
    for word in split_names(item.replace(" ", "") for item in items):
        try:
            seeds.append(int(word))
        except ValueError:
            raise ConfigError(f"--seeds: {word!r} is not a seed (whole numbers separated by commas: --seeds 0,1,2)") from None
    if items and not seeds:  # `--seeds ""` (an empty variable) named none: not a one-seed eval of seed 0
        raise ConfigError(f"--seeds: no seed given in {' '.join(map(repr, items))} (whole numbers separated by commas: --seeds 0,1,2)")
    return seeds


def parse_settings(items: list[str], last_counts: bool = False) -> Settings:
    """``KEY=VALUE`` pairs with YAML values (``gamma=0.995``, ``generated=[a, b]``), each VALUE's text kept as typed
    for the messages that name it (``config.Settings``). A KEY given twice with another value is a ConfigError naming
    both ``--set`` as typed, as a key given twice in one YAML mapping is (``config.YamlLoader``): the first one would
    be dropped in silence; so is a key and a section that holds it (``episode.max_steps=5``, ``episode={max_steps:
    6}``: ``config.settings_by_key``). The same value twice is fine, a number written two ways too (``1`` and
    ``1.0``: ``config.yaml_value_compared``); the last is kept. ``last_counts``: the last one counts instead (train's field flags, ``--lr 1 --lr 2``, as
    typer's own options; and their pairs merged with ``--set`` once ``refuse_two_values_of_a_field`` checked them)."""
    import yaml  # noqa: PLC0415

    from cso_runtime.config import (  # noqa: PLC0415
        ConfigError,
        Settings,
        not_yaml_said,
        refuse_two_values,
        settings_by_key,
        yaml_load,
        yaml_value_compared,
    )

    out = Settings()
    given: list[tuple[str, str, object]] = []
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            out[key] = yaml_load(value)
        except yaml.YAMLError as exc:
            raise ConfigError(not_yaml_said(f"--set {item}", exc)) from None
        out.typed[key] = value.strip()
        given.append((key, f"--set {key}={value.strip()}", out[key]))
    if not last_counts:  # 1 and 1.0: one number; 1 and true, [1] and [true]: other values
        refuse_two_values(settings_by_key(given), lambda _key, value: yaml_value_compared(value))
    return out


_starting_up: tuple[Path, Callable[[], None]] | None = None
"""The file that names this ``up`` to ``down`` (``current_run.STARTING_UP_GLOB``) when ``main`` wrote it, before typer
parsed the command line: its runs folder, and what removes it. ``up`` takes it over (``_named_starting_up``)."""


def _up_runs_dir(args: list[str]) -> Path | None:
    """The runs folder of an ``up`` command line that may start a run (not ``--help``, ``--dry-run``, ``--resolved``),
    read before typer parses it (``main``); None for any other command line. Only a head start: ``up`` checks it
    against the folder typer gives it."""
    if not args or args[0] != "up":
        return None
    runs_dir = Path("runs")  # up's --runs-dir default
    rest = args[1:]
    for i, arg in enumerate(rest):
        if arg == "--":
            break
        if arg in ("--help", "--dry-run", "--resolved"):
            return None
        if arg == "--runs-dir" and i + 1 < len(rest):
            runs_dir = Path(rest[i + 1])
        elif arg.startswith("--runs-dir="):
            runs_dir = Path(arg.partition("=")[2])
    return runs_dir


def _name_starting_up_early(args: list[str]) -> None:
    """``up``'s first act, in ``main`` before typer and the commands are even built: name this ``up`` in its runs folder
    for ``down`` (``current_run.record_starting_up``), which otherwise answered "nothing running" for the first quarter
    second of an ``up`` (imports and parsing) that then started its run all the same."""
    global _starting_up
    runs_dir = _up_runs_dir(args)
    if runs_dir is not None and _starting_up is None:
        import signal  # noqa: PLC0415

        from cso_runtime.current_run import record_starting_up  # noqa: PLC0415  (no numpy: cheap)

        for sig in (signal.SIGTERM, signal.SIGHUP):  # until `up` puts in its own (processes.stop_on_signals)
            if signal.getsignal(sig) == signal.SIG_DFL:  # not one ignored (nohup), nor a host program's
                signal.signal(sig, _killed_before_up_ran)
                _early_handlers.append(sig)
        with _early_signals_held():  # the file is never written and not yet named (a signal then left it)
            _starting_up = (runs_dir, record_starting_up(runs_dir))


_early_handlers: list[int] = []
"""The signals ``_name_starting_up_early`` handles (``_killed_before_up_ran``), given back to the default as ``main`` ends."""


@contextmanager
def _early_signals_held() -> Iterator[None]:
    """The signals of ``_early_handlers`` held back (blocked, then acted on once let through) while ``_starting_up`` and
    the file it names change together: a SIGTERM between writing the file and naming it, or between unnaming it and
    removing it, ran ``_killed_before_up_ran`` with nothing named, and the process died leaving the file behind."""
    import signal  # noqa: PLC0415

    held = signal.pthread_sigmask(signal.SIG_BLOCK, _early_handlers)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def _killed_before_up_ran(signum: int, frame: object) -> None:
    """SIGTERM or SIGHUP in ``up``'s first moments, before its own handlers (``down``, ``kill``, a closed terminal):
    the file ``main`` wrote for ``down`` (and the folders made for it) goes, then the process dies of the signal, as
    it did before it wrote one. It left the file and a runs folder behind."""
    import os  # noqa: PLC0415
    import signal  # noqa: PLC0415

    global _starting_up
    early, _starting_up = _starting_up, None
    if early is not None:
        early[1]()
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


def _named_starting_up(runs_dir: Path) -> Callable[[], None]:
    """What removes the file that names this ``up`` in ``runs_dir`` for ``down``: the one ``main`` wrote when it read the
    same folder (kept, never a moment without it), else one written now (and ``main``'s, of a folder misread, removed)."""
    global _starting_up
    from cso_runtime.current_run import record_starting_up  # noqa: PLC0415

    early, _starting_up = _starting_up, None
    if early is not None and early[0] == runs_dir:
        return early[1]
    remove = record_starting_up(runs_dir)
    if early is not None:
        early[1]()
    return remove


def main() -> None:
    """The ``cso-runtime`` script's entry point: a Ctrl-C before any command handles it exits 130 with one line; every
    output whose reader left (a command's, ``--help``'s) ends as a shell tool does, with exit 141. ``up`` names itself
    for ``down`` first of all (``_name_starting_up_early``)."""
    global _starting_up
    sys.argv[1:] = home_in_option_values(sys.argv[1:])
    try:
        _name_starting_up_early(sys.argv[1:])
        from cso_runtime.provenance import record_command_line  # noqa: PLC0415
        from cso_runtime.reader_gone import ends_quietly_when_its_reader_leaves  # noqa: PLC0415

        record_command_line(["cso-runtime", *sys.argv[1:]])  # what the results files it writes record (software_provenance)

        with ends_quietly_when_its_reader_leaves():
            app(prog_name="cso-runtime")  # one name (and completion variable) for the script and python -m cso_runtime.cli
    except KeyboardInterrupt:  # before typer's own handling (which exits 130) or a command's
        _interrupted_early()
    finally:
        with _early_signals_held():  # unnamed and removed at once
            early, _starting_up = _starting_up, None
            if early is not None:  # no `up` took it over: typer refused the command line, or `up` never ran
                early[1]()
        _give_back_early_handlers()


def home_in_option_values(args: list[str]) -> list[str]:
    """``args`` with a ``~`` that starts the value of a ``--flag=~/...`` (or ``--flag=~``) made the home folder, as
    the shell makes it in ``--flag ~/...``: the shell leaves the ``=`` form alone (bash, sh; zsh only with
    magic_equal_subst), so ``eval --out=~/results`` wrote into a folder named ``~`` in the current one (which a
    later ``rm -rf ~`` empties the home folder for). A value written otherwise (``--set key=~/x``, ``~user``) is
    kept as typed, and so is everything after ``--``."""
    import os  # noqa: PLC0415

    expanded: list[str] = []
    for k, arg in enumerate(args):
        if arg == "--":
            return [*expanded, *args[k:]]
        flag, equals, value = arg.partition("=")
        if arg.startswith("--") and equals and (value == "~" or value.startswith("~/")):
            arg = f"{flag}={os.path.expanduser(value)}"
        expanded.append(arg)
    return expanded


def _give_back_early_handlers() -> None:
    """The default again for each signal ``_name_starting_up_early`` handled, where no one has put another since."""
    import signal  # noqa: PLC0415

    while _early_handlers:
        sig = _early_handlers.pop()
        if signal.getsignal(sig) is _killed_before_up_ran:
            signal.signal(sig, signal.SIG_DFL)


if __name__ == "__main__":
    main()
