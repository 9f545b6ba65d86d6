"""``cso-runtime eval``: run methods over scenes and write Table 1 metrics, curves and trajectory plots.

Outputs (contract relied on by scripts): ``summary.json``, ``episodes.csv``,
``episodes/<method>/<map>.npz`` (explored, trajectory, coverage_curve), ``maps/<method>/<map>.yaml`` and
``.png`` (the robot's final map, Nav2 map_server files), ``coverage_curves.png``, ``efficiency_by_scale.png`` and
``trajectories/<map>.png``; with the baseline, ``paired.csv`` and ``paired_efficiency.png``.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import importlib.util
import io
import json
import logging
import math
import multiprocessing
import os
import sys
import time
import traceback
import zipfile
import zlib
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rich.markup import escape

if TYPE_CHECKING:
    from rich.progress import TaskID

from cso_runtime import __version__
from cso_runtime.animation import EpisodeAnimation
from cso_runtime.comparison import (
    PAIRED_COLUMNS,
    SETUP_COLUMNS,
    TOO_FEW_SCENES,
    as_dicts,
    bootstrap_mean_ci,
    compare_to_baseline,
    efficiency_by_scene,
    paired_cells,
)
from cso_runtime.comparison import write_csv as write_paired_csv
from cso_runtime.config import (
    EPISODE_BOUNDS,
    EXIT_INTERRUPTED,
    LIDAR_FOVS_DEG,
    LIDAR_FOVS_SAID,
    MAX_PROCESSES,
    Bound,
    ConfigError,
    ExplorationConfig,
    SensorConfig,
    check_output_dir,
    check_seed,
    commented_yaml,
    field_types,
    from_dict_with_hints,
    load_yaml,
    make_output_dir,
    refuse_a_flag_and_a_setting_that_disagree,
    refuse_a_setting_read_as_another_type,
    set_dotted,
    set_said,
    to_dict,
    utf8_text,
    with_mujoco_limo_defaults,
    with_nearest,
)
from cso_runtime.current_run import folder_lock, hold_lock_file
from cso_runtime.episode import EpisodeResult, run_episode
from cso_runtime.geometry import MAP_FRAME_ORIGIN, Pose2D
from cso_runtime.live_view import fit_off_a_terminal, table_console
from cso_runtime.map_files import save_map
from cso_runtime.outputs import (
    COVERAGE_FIGURE,
    EFFICIENCY_FIGURE,
    PAIRED_FIGURE,
    episode_animation_path,
    episode_map_path,
    episode_npz_path,
    file_sha256,
    file_stem,
    remove_stale_partial_files,
    results_said,
    trajectory_plot_path,
    write_npz_whole,
    write_text_atomic,
)
from cso_runtime.pace import real_time_factor
from cso_runtime.policies import (
    BASELINES,
    LEARNED_METHODS,
    available_methods,
    check_method,
    make_policy,
    own_method_spec,
    unknown_methods_said,
    weights_held_said,
)
from cso_runtime.processes import WorkerDied, run_each_in_own_process, terminate_workers, worker_init
from cso_runtime.provenance import software_provenance
from cso_runtime.report import (
    CI95_SUFFIX,
    MEANS_NOTE,
    SPREAD_NOTE,
    STD_SUFFIX,
    TABLE1_COLUMNS,
    failure_said,
    shows_ablations,
    table1_cells,
    table1_rows,
    table2,
    write_report,
)
from cso_runtime.scenes import M_PER_PX_BOUND, SCALES, FloorPlan, SceneError, SceneRef, resolve_scenes, scale_of, scale_rank
from cso_runtime.simulator import (
    SIMULATORS,
    MountSetting,
    make_simulator,
    mujoco_config,
    simulator_settings,
    watchdog_within_a_step_said,
)

log = logging.getLogger(__name__)

METRICS = (
    "explored_area_m2",
    "coverage_pct",
    "steps",
    "efficiency_m2_per_step",
    "path_length_m",
    "decision_ms_p50",
    "decision_ms_p99",
)
PACE = ("sim_time_s", "real_time_factor")
"""How fast the simulator ran: an episode's simulated seconds and those over its wall-clock seconds (``pace``)."""
CSV_FIELDS = ("method", "map", "scale", "seed") + METRICS + ("terminated_by", "traversable_area_m2", "decisions", "wall_s") + PACE + ("ended_why",) + SETUP_COLUMNS
"""``episodes.csv``'s columns, in this order (a contract: a new column goes at the end). ``ended_why``: why the episode
ended ``no_frontier`` (``EpisodeResult.ended_why``), empty for any other end; then what it ran with
(``comparison.SETUP_COLUMNS``: ``run_setup`` of the run's meta, and its plan's cell size)."""


def run_setup(meta: dict[str, Any]) -> dict[str, Any]:
    """The ``SETUP_COLUMNS`` every episode of a run shares, from its summary.json's ``meta``: the sensor's field of
    view (``config.sensor.fov_deg``), the simulator (``sim``: None on a real robot) and the step limit
    (``config.episode.max_steps``); None where it is not said."""
    config = meta.get("config") or {}
    sensor, episode = config.get("sensor") or {}, config.get("episode") or {}
    return {"sensor_fov_deg": sensor.get("fov_deg"), "sim": meta.get("sim"), "max_steps": episode.get("max_steps")}


DEFAULT_M_PER_PX = 0.1
"""``--m-per-px``'s default: the metres per pixel of PNG plans."""


@dataclass
class EvalRequest:
    """What the eval command was asked to do (CLI flags and config file)."""

    methods: list[str]
    maps: str = "builtin"
    limit: int | None = None
    out_dir: Path = Path("results/eval")
    m_per_px: float = DEFAULT_M_PER_PX
    seed: int = 0
    max_steps: int | None = None
    """``--max-steps``: the step limit per episode; None keeps the config's ``episode.max_steps`` (3000)."""
    lidar_fov_deg: float = 180.0
    sensor: str = "lidar"
    workers: int = 1
    sim: str = "2d"
    config_path: Path | None = None
    sim_config_path: Path | None = None
    """``--sim-config``: the MuJoCo LIMO's parameters (``configs/robot_sim.yaml``'s keys: physics, odometry drift)
    over its defaults; ``--sim mujoco`` only."""
    resume: bool = False
    """Reuse episodes already finished in ``out_dir`` (same method, map and seed)."""
    overwrite: bool = False
    """Run again, in place, the episodes ``out_dir`` holds of this run's methods and plans from another configuration
    (``episodes_of_another_configuration``); without it such a folder is refused before any episode."""
    baseline: str = "greedy-dist"
    """Every other method is compared with this one scene by scene (``paired.csv``) when it ran too."""
    animate: bool = False
    """Also write ``animations/<method>/<map>.gif``: the robot's map at each decision (``frames.EpisodeAnimation``)."""
    settings: dict[str, Any] = dataclasses.field(default_factory=dict)
    """``--set KEY=VALUE``: dotted exploration parameters set over the config file (``masks.beta_far_m=2.0``)."""
    seeds: list[int] = dataclasses.field(default_factory=list)
    """``--seeds``: several seeds in one eval, in place of ``seed``: each seed's episodes in ``OUT/seed<S>/``
    (``seed_folder``: the folder ``--seed S --out OUT/seed<S>`` writes), all of them pooled in ``OUT``'s
    summary.json, episodes.csv, paired.csv, figures and report.html; [] for the one ``seed``."""

    def __post_init__(self) -> None:
        # ``--method greedy-dist,greedy-dist`` means the method once: twice would run every scene twice and
        # count both in its means.
        self.methods = list(dict.fromkeys(self.methods))
        self.seeds = list(dict.fromkeys(self.seeds))  # a seed given twice would count its episodes twice

    def check_seeds(self) -> None:
        """``--seeds``' own checks (each seed's eval checks the rest)."""
        for seed in self.seeds:
            check_seed(seed, "--seeds")
        refuse_seed_with_seeds(self.seed or None, self.seeds)  # seed 0 is the default: no --seed given

    def for_seed(self, seed: int) -> EvalRequest:
        """The eval of one of ``seeds``: ``--seed SEED`` into ``seed_folder(out_dir, SEED)``."""
        return dataclasses.replace(self, seed=seed, seeds=[], out_dir=seed_folder(self.out_dir, seed))

    def exploration_config(self) -> ExplorationConfig:
        """The config file (if any) with the CLI's sensor and step-limit flags applied on top."""
        if self.max_steps is not None:  # --max-steps over the file's episode.max_steps, but never over --set's other value
            flag = {"episode.max_steps": (f"--max-steps {self.max_steps}", self.max_steps)}
            refuse_a_flag_and_a_setting_that_disagree(flag, self.settings, {"episode.max_steps": int})
        if self.settings:  # `--set planner.KEY=1` of a text key: how to write it, where the config takes it as text

            def takes(texts: dict[str, Any]) -> object:  # the config with those values as text (no hint again)
                return dataclasses.replace(self, settings=texts).exploration_config()

            refuse_a_setting_read_as_another_type(self.settings, field_types(ExplorationConfig), takes)
        data: dict[str, Any] = load_yaml(self.config_path) if self.config_path else {}
        for key, value in self.settings.items():
            set_dotted(data, key, value)
        where = str(self.config_path or "config")
        if self.settings:  # an error names the flags that changed the file, as `up --set` does
            where = f"{self.config_path or 'eval'} with " + " ".join(set_said(self.settings, k) for k in self.settings)
        cfg = from_dict_with_hints(ExplorationConfig, data, where)
        # The sensor is the --sensor preset (its field of view from --lidar-fov), with every other sensor key the
        # config file or --set gives explicitly on top: an ablation of the range or the resolution must not run
        # silently on the preset's values.
        explicit = data.get("sensor") or {}
        preset = SensorConfig.preset(self.sensor, fov_deg=self.lidar_fov_deg if self.sensor == "lidar" else None)
        if "fov_deg" in explicit and cfg.sensor.fov_deg != preset.fov_deg:  # the flags' own value is taken: `eval --resolved` writes it
            given = f"--sensor {self.sensor}" + (f" --lidar-fov {self.lidar_fov_deg:g}" if self.sensor == "lidar" else "")  # as run: 180 unless given
            set_alone: dict[str, Any] = {}
            for key, value in self.settings.items():
                set_dotted(set_alone, key, value)
            if "fov_deg" in (set_alone.get("sensor") or {}):  # `--set sensor.fov_deg=360`: no file, no resolved run
                by, fix = "--set", (
                    f"give --lidar-fov {cfg.sensor.fov_deg:g} in place of the --set"
                    if self.sensor == "lidar" and cfg.sensor.fov_deg in LIDAR_FOVS_DEG
                    else "leave sensor.fov_deg out of the --set (the --sensor preset and --lidar-fov set it)"
                )
            else:
                by, fix = "the config", "give the --sensor and --lidar-fov it was resolved with, or leave sensor.fov_deg out of the file"
            raise ConfigError(
                f"{where}: sensor.fov_deg is set by eval's --lidar-fov ({LIDAR_FOVS_SAID}) or the --sensor preset, not by {by} "
                f"(it says {cfg.sensor.fov_deg:g}; {given} gives {preset.fov_deg:g}): {fix}"
            )
        for key in explicit:
            setattr(preset, key, getattr(cfg.sensor, key))
        cfg.sensor = preset
        if self.sim == "mujoco":
            with_mujoco_limo_defaults(cfg, data)  # its LiDAR's mount (the planner must know it) and box body, unless set
        try:
            cfg.sensor.validate()
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc} (the {self.sensor} preset with the config's sensor keys)") from None
        if self.max_steps is not None:
            EPISODE_BOUNDS["max_steps"].check("--max-steps", self.max_steps)  # as the config's episode.max_steps
            cfg.episode = dataclasses.replace(cfg.episode, max_steps=int(self.max_steps))
        return cfg

    def mujoco_parameters(self) -> dict[str, Any]:
        """The ``--sim-config`` file's MuJoCo parameters, checked with the exploration config's robot and sensor
        (``simulator.mujoco_config``) whenever the sim is MuJoCo; {} without a file."""
        if self.sim_config_path is not None and self.sim != "mujoco":
            raise ConfigError(f"--sim-config sets the MuJoCo LIMO's parameters: it needs --sim mujoco, not --sim {self.sim}")
        if self.sim != "mujoco":
            return {}
        data = load_yaml(self.sim_config_path) if self.sim_config_path is not None else {}
        cfg = self.exploration_config()
        mount = MountSetting(file=str(self.config_path or "a --config file"), command="eval")  # eval's config sets the sensor
        mujoco_config(data, cfg.sensor, where=str(self.sim_config_path or "--sim mujoco"), robot=cfg.robot, mount=mount, exploration=cfg)
        return data

    def as_record(self) -> dict[str, Any]:
        """The request as JSON values (paths as strings), for ``summary.json``'s ``meta.request``."""
        return {f.name: str(v) if isinstance(v := getattr(self, f.name), Path) else v for f in dataclasses.fields(self)}

    def validate(self) -> None:
        known = set(BASELINES) | set(LEARNED_METHODS)
        unknown = [m for m in self.methods if m not in known and own_method_spec(m) is None]
        if not self.methods:
            raise ConfigError("no --method given")
        if unknown:
            raise ConfigError(unknown_methods_said(unknown, groups=True))
        for method in self.methods:
            check_method(method)  # a method of the user's own: imported and built once, before any episode
        folders: dict[str, str] = {}
        for method in self.methods:
            if (other := folders.setdefault(file_stem(method), method)) != method:
                raise ConfigError(f"methods {other!r} and {method!r} would share the results folder episodes/{file_stem(method)}/: run them in two evals")
        if self.baseline not in known and self.baseline not in self.methods:
            raise ConfigError(f"unknown --baseline {with_nearest(self.baseline, known, shown=repr(self.baseline))}; available: {', '.join(sorted(known))}")
        from cso_runtime.learned.weights import weights_file_refusal  # noqa: PLC0415

        if refusal := weights_file_refusal(self.methods):
            raise ConfigError(refusal)
        untrained = [m for m in self.methods if m in LEARNED_METHODS and m not in available_methods()]
        if untrained:
            from cso_runtime.learned.weights import weights_dir  # noqa: PLC0415

            missing = ", ".join(f"{m}.pt" for m in untrained)
            fix = weights_held_said() or "train with `cso-runtime train --variant NAME`"
            raise ConfigError(f"no weights for {', '.join(untrained)} in {weights_dir()} ({missing}); {fix}")
        if self.sim not in SIMULATORS:
            raise ConfigError(f"unknown --sim {self.sim!r}; choose {' or '.join(SIMULATORS)}")
        if self.max_steps is not None:
            EPISODE_BOUNDS["max_steps"].check("--max-steps", self.max_steps)  # as the config's episode.max_steps
        self.mujoco_parameters()
        Bound(1, MAX_PROCESSES, why="a process each: config.MAX_PROCESSES").check("--workers", self.workers)  # a process each: 5000 started 5,000 processes
        check_seed(self.seed, "--seed")
        self.check_seeds()
        M_PER_PX_BOUND.check("--m-per-px", self.m_per_px)  # as resolve_scenes and train's dungeon_m_per_px
        if self.limit is not None and self.limit <= 0:
            raise ConfigError(f"--limit must be positive, got {self.limit}")
        if self.sensor == "lidar" and self.lidar_fov_deg not in LIDAR_FOVS_DEG:
            raise ConfigError(f"--lidar-fov must be {LIDAR_FOVS_SAID}")
        # Last: it loads torch and the weights (kept for the episodes), which the checks above need not wait for.
        learned = [m for m in self.methods if m in LEARNED_METHODS]
        if learned:
            from cso_runtime.learned.registry import CheckpointError, check_weights  # noqa: PLC0415 - torch only for learned methods

            for method in learned:
                try:
                    check_weights(method, sensor=self.exploration_config().sensor, frontier=self.exploration_config().frontier)
                except CheckpointError as exc:
                    raise ConfigError(f"method {method}: {exc}") from None


@dataclass
class EpisodeJob:
    """One (method, scene) episode of an eval: all a worker process needs to run it and write its files."""

    method: str
    scene: SceneRef
    seed: int
    sim: str
    config: ExplorationConfig
    out_dir: Path
    settings: str = ""
    """Fingerprint of what else decides the episode (config, simulator, weights file): ``--resume``
    reuses an episode only when it matches, so a changed flag or new weights never mix into a table."""
    animate: bool = False
    """Write the episode's animation (``episode_animation_path``); it changes nothing of the episode."""
    mujoco: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The MuJoCo LIMO's parameters over its defaults (``EvalRequest.sim_config_path``)."""

    @property
    def npz_path(self) -> Path:
        return episode_npz_path(self.out_dir, self.method, self.scene.name)


def scene_fingerprint(plan: FloorPlan) -> str:
    """A short hash of the ground truth an episode explored (its floor cells, cell size and start pose):
    ``--resume`` reuses an episode only on the very same scene, not on a plan of the same name at another
    ``--m-per-px`` or from another folder. A map scene's origin counts when it is not the map frame's own (the
    robot's map files are written at it), so plans without one keep their fingerprints."""
    h = hashlib.sha256()
    fields: dict[str, Any] = {"shape": list(plan.free.shape), "resolution_m": plan.resolution_m, "start": [plan.start.x_m, plan.start.y_m, plan.start.yaw_rad]}
    if plan.map_origin != MAP_FRAME_ORIGIN:
        fields["map_origin"] = [plan.map_origin.x_m, plan.map_origin.y_m, plan.map_origin.yaw_rad]
    h.update(json.dumps(fields).encode())
    h.update(np.packbits(plan.free).tobytes())
    return h.hexdigest()[:16]


CONFIG_KEYS_ADDED: dict[str, Any] = {}
"""Exploration config keys (dotted, as ``--set`` names them) added after episodes recorded their settings, each with
the value that does what the versions before it did: at that value a key counts neither in the fingerprint nor as a
difference, so an upgrade that adds it keeps a sweep's episodes for ``--resume``. A key added without one here (its
earlier behaviour is not one value of it) makes every earlier episode another configuration, its refusal naming it."""

SIM_SETTINGS_BEFORE_FINGERPRINTED: dict[str, dict[str, Any]] = {
    "2d": {"collision_radius_m": 0.12, "substeps": 5},
    "mujoco": {
        "timestep_s": 0.005, "watchdog_s": 0.5, "max_linear_accel_mps2": 2.0, "max_angular_accel_radps2": 3.0, "actuator_time_constant_s": 0.02,
        "traction_force_n": 38.0, "yaw_torque_nm": 6.0, "wall_friction": 0.3, "contact_time_constant_s": 0.01, "wall_height_m": 1.0,
        "walls_boundary_only": False, "mass_kg": 4.8, "body_height_m": 0.251, "wheelbase_m": 0.2, "track_m": 0.175, "wheel_radius_m": 0.045,
        "lidar_height_m": 0.2, "odometry_rate_hz": 40.0, "odom_trans_noise_frac": 0.0, "odom_rot_noise_frac": 0.0, "odom_rot_per_trans_noise_radpm": 0.0,
    },
}  # fmt: skip
"""What each simulator ran with in the episodes written before the fingerprint took in its settings (``simulator_settings``):
the 2D simulator's fixed 0.12 m disc (before it followed ``robot.width_m``) and its substeps; the MuJoCo LIMO's defaults
(``robot_sim.MujocoSimConfig``), written out here so that an upgrade that changes one makes the episodes run before it
another configuration (the fingerprint had counted only the keys a ``--sim-config`` file set). A setting counts where it
differs from these, so those episodes keep their fingerprints and one run otherwise does not; a setting that is not here
(one a later version adds) counts always."""

SIM_SETTINGS_COUNTED_ELSEWHERE = frozenset({"lidar_mount_x_m"})
"""Simulator settings that follow from the exploration config, which counts already: where the MuJoCo LIMO's rays are
cast from is the sensor's ``mount_x_m``."""


def _same_value(a: Any, b: Any) -> bool:
    """Equal, floats to rounding (``0.5 * width_m + 0.01`` is the 0.12 m written)."""
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool) and not isinstance(b, bool):
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


def as_before(key: str, value: Any) -> bool:
    """Whether ``value`` of the config key ``key`` (dotted) is what versions before the key existed did (``CONFIG_KEYS_ADDED``)."""
    return key in CONFIG_KEYS_ADDED and _same_value(CONFIG_KEYS_ADDED[key], value)


def _without_keys_as_before(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``tree`` (``to_dict`` of a config) less the added keys at their earlier behaviour's value (``as_before``)."""
    kept: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            kept[key] = _without_keys_as_before(value, f"{prefix}{key}.")
        elif not as_before(f"{prefix}{key}", value):
            kept[key] = value
    return kept


def sim_settings_counted(sim: str, sim_settings: dict[str, Any] | None, mujoco: dict[str, Any] | None = None) -> dict[str, Any]:
    """The simulator settings that count in the fingerprint: those that differ from what the episodes written before
    they counted ran with (``SIM_SETTINGS_BEFORE_FINGERPRINTED``), less those that count otherwise: the keys of the
    ``--sim-config`` file ``mujoco`` (counted as the file gives them, as before) and those of the config
    (``SIM_SETTINGS_COUNTED_ELSEWHERE``)."""
    before = SIM_SETTINGS_BEFORE_FINGERPRINTED.get(sim)
    if before is None or not sim_settings:
        return {}
    elsewhere = SIM_SETTINGS_COUNTED_ELSEWHERE | set(mujoco or {})
    return {k: v for k, v in sim_settings.items() if k not in elsewhere and (k not in before or not _same_value(before[k], v))}


def settings_fingerprint(
    config: ExplorationConfig,
    sim: str,
    weights_sha256: str = "",
    mujoco: dict[str, Any] | None = None,
    code_sha256: str = "",
    sim_settings: dict[str, Any] | None = None,
) -> str:
    """A short hash of the settings an episode ran with (see ``EpisodeJob.settings``): the config, the simulator and
    what it ran with (``sim_settings``, ``simulator_settings``), the weights. MuJoCo parameters, the code of a method of
    the user's own (``own_method_code_sha256``), simulator settings and config keys count only where they differ from
    what runs before them did (``sim_settings_counted``, ``CONFIG_KEYS_ADDED``), so the episodes of those runs keep
    their fingerprints."""
    fields: dict[str, Any] = {"config": _without_keys_as_before(to_dict(config)), "sim": sim, "weights": weights_sha256}
    if mujoco:
        fields["mujoco"] = mujoco
    if code_sha256:
        fields["code"] = code_sha256
    if counted := sim_settings_counted(sim, sim_settings, mujoco):
        fields["sim_settings"] = counted
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def own_method_code_sha256(method: str) -> str:
    """The sha256 of the source file of the module a method of the user's own names (``module.path:Attribute``), so
    that ``--resume`` runs its episodes again once that file changed; "" for a built-in method. Code that module
    imports from other files does not count."""
    spec = own_method_spec(method)
    if spec is None:
        return ""
    found = importlib.util.find_spec(spec.partition(":")[0])
    origin = found.origin if found is not None else None
    return file_sha256(Path(origin)) if origin else ""


@dataclass
class EpisodeOutcome:
    """What a worker sends back: the metric row, or the failure, plus arrays for the plots."""

    method: str
    map: str
    row: dict[str, Any] | None = None
    error: str | None = None
    free: np.ndarray | None = None
    resolution_m: float = 0.0
    explored: np.ndarray | None = None
    trajectory_xy_m: np.ndarray | None = None
    coverage_curve_pct: np.ndarray | None = None
    kept: bool = False
    """Read back from an earlier run's files by ``--resume``, not run now."""
    map_origin: Pose2D = MAP_FRAME_ORIGIN
    """The plan's pose in the user's map frame (``FloorPlan.map_origin``): the trajectory plots are drawn there."""
    seed: int | None = None
    """The seed it ran with, where an eval of several seeds (``--seeds``) pools its outcomes; None otherwise (its row says it)."""

    @classmethod
    def finished(
        cls, method: str, result: EpisodeResult, row: dict[str, Any], free: np.ndarray, resolution_m: float, map_origin: Pose2D = MAP_FRAME_ORIGIN
    ) -> EpisodeOutcome:
        """The outcome of an episode that ran to its end (in-process or through the runtime)."""
        return cls(
            method,
            result.scene,
            row=row,
            free=free,
            resolution_m=resolution_m,
            explored=result.explored_free,
            trajectory_xy_m=result.trajectory_xy_m,
            coverage_curve_pct=result.coverage_curve_pct,
            map_origin=map_origin,
        )


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def episode_row(method: str, seed: int, result: EpisodeResult, wall_s: float, real_time_factor: float | None = None) -> dict[str, Any]:
    """One CSV row / JSON record of Table 1 metrics, then how fast the simulator ran: ``real_time_factor`` as
    measured by the caller (``pace``: eval's over ``wall_s``, ``up``'s over the episode's statuses); then why it ended
    ``no_frontier`` (empty for any other end)."""
    return {
        "method": method,
        "map": result.scene,
        "scale": scale_of(result.traversable_area_m2),
        "seed": seed,
        "explored_area_m2": round(result.explored_area_m2, 4),
        "coverage_pct": round(result.coverage_pct, 4),
        "steps": result.steps,
        "efficiency_m2_per_step": round(result.efficiency_m2_per_step, 6),
        "path_length_m": round(result.path_length_m, 4),
        "decision_ms_p50": round(result.decision_ms_p50, 4),
        "decision_ms_p99": round(result.decision_ms_p99, 4),
        "terminated_by": result.terminated_by,
        "traversable_area_m2": round(result.traversable_area_m2, 4),
        "decisions": result.decisions,
        "wall_s": round(wall_s, 3),
        "sim_time_s": _rounded(result.sim_time_s, 3),
        "real_time_factor": _rounded(real_time_factor, 3),
        "ended_why": result.ended_why,
    }


def save_episode_files(
    out_dir: Path, method: str, scene: str, result: EpisodeResult, row: dict[str, Any], settings: str = "", scene_hash: str = "", map_origin: Pose2D = MAP_FRAME_ORIGIN,
    animation_sha256: str = "",
) -> None:
    """The episode's npz and, when its map is known, the robot's final map as map_server files (PNG:
    an evaluation writes hundreds). The npz holds ``explored`` in the plan's pixel layout (row 0 at the
    top, like the PNG), the trajectory in metres in the plan's frame with ``map_origin`` (the plan's pose in the
    user's map frame, ``FloorPlan.map_origin``) beside it, and the metric row as JSON (``metrics``) with the
    settings' and the scene's fingerprints so an interrupted eval can resume; it is written last, so an episode whose
    npz is there has its map too. The map files are in the map frame: their ``origin`` overlays the user's own map.
    ``animation_sha256``: the sha256 of the episode's GIF (``--animate``, written before), "" for none: what ties that
    GIF to this episode (``animation_is_the_episodes``)."""
    if result.map_grid is not None and result.map_geometry is not None:
        save_map(episode_map_path(out_dir, method, scene), result.map_grid, result.map_geometry, image_format="png", map_origin=map_origin)
    path = episode_npz_path(out_dir, method, scene)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "explored": np.flipud(result.explored_free),
        "trajectory": result.trajectory_xy_m.astype(np.float32),
        "map_origin": np.array([map_origin.x_m, map_origin.y_m, map_origin.yaw_rad], dtype=np.float64),
        "coverage_curve": result.coverage_curve_pct.astype(np.float32),
        "metrics": np.array(json.dumps(json_row(row), allow_nan=False)),
        "settings": np.array(settings),
        "scene": np.array(scene_hash),
        "animation": np.array(animation_sha256),
    }
    write_npz_whole(path, arrays)  # a half-written file never looks finished


@dataclass
class HeldEpisode:
    """An episode's npz as ``save_episode_files`` wrote it, read back."""

    row: dict[str, Any]
    explored: np.ndarray
    trajectory_xy_m: np.ndarray
    coverage_curve_pct: np.ndarray
    settings: str | None
    """``EpisodeJob.settings`` it ran with; None in a file of a run before the fingerprints."""
    scene: str | None
    """``scene_fingerprint`` of its plan; None in a file of a run before the fingerprints."""
    animation_sha256: str | None = None
    """The sha256 of its GIF ("" for none); None in a file of a run before it was recorded."""

    def same_run(self, job: EpisodeJob) -> bool:
        """Whether it ran as ``job`` would, its plan aside (``scene``): the same method, seed and settings."""
        return self.row.get("seed") == job.seed and self.row.get("method") == job.method and self.settings == job.settings


def read_held_episode(path: Path) -> HeldEpisode | None:
    """The episode file at ``path``; None when there is none, or none that reads whole (it is no result: an interrupted
    copy of the folder, a full disk, a file system without atomic renames leave files cut short)."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            return HeldEpisode(
                row=json.loads(str(data["metrics"])),
                explored=np.flipud(data["explored"]).copy(),
                trajectory_xy_m=data["trajectory"].astype(float),
                coverage_curve_pct=data["coverage_curve"].astype(float),
                settings=str(data["settings"]) if "settings" in data.files else None,
                scene=str(data["scene"]) if "scene" in data.files else None,
                animation_sha256=str(data["animation"]) if "animation" in data.files else None,
            )
    except (OSError, EOFError, KeyError, ValueError, AttributeError, zipfile.BadZipFile, zlib.error):  # cut short, empty, not ours
        return None


def is_an_episode_file(path: Path) -> bool:
    """Whether ``path`` reads whole as the episode file of the plan its name says (``<map>.partial.npz``: the episode
    of a plan named ``<map>.partial``, not a file an earlier version left half-written, or whole but of ``<map>``)."""
    held = read_held_episode(path)
    return held is not None and file_stem(str(held.row.get("map", ""))) == path.stem


def animation_is_the_episodes(held: HeldEpisode, npz_path: Path, gif: Path) -> bool:
    """Whether ``gif`` is the animation of the episode in ``npz_path``: the GIF that episode's run wrote (its sha256 in
    the npz), not one of another run (``kill -9`` between the two files: a GIF written by a run with other settings,
    or left from an earlier run beside an episode that had none). An npz of before the sha256 was recorded: a GIF
    written after it (those runs wrote the npz first), as its own run did."""
    if not gif.is_file():
        return False
    if held.animation_sha256 is not None:
        return held.animation_sha256 != "" and file_sha256(gif) == held.animation_sha256
    try:
        return gif.stat().st_mtime_ns >= npz_path.stat().st_mtime_ns
    except OSError:
        return False


def remove_a_gif_not_its_own(job: EpisodeJob) -> None:
    """Remove the GIF beside ``job``'s kept episode when it is not the episode's own (``animation_is_the_episodes``):
    the report would show it as this episode's."""
    held = read_held_episode(job.npz_path)
    gif = episode_animation_path(job.out_dir, job.method, job.scene.name)
    if held is not None and not animation_is_the_episodes(held, job.npz_path, gif):
        gif.unlink(missing_ok=True)


def load_finished(job: EpisodeJob) -> EpisodeOutcome | None:
    """The outcome of an episode a previous run already finished with the same settings, if any; with ``--animate``
    only one with its own GIF (else it runs again, and writes it). Reads only (``--dry-run``)."""
    held = read_held_episode(job.npz_path)
    if held is None or not held.same_run(job):
        return None
    if job.animate and not animation_is_the_episodes(held, job.npz_path, episode_animation_path(job.out_dir, job.method, job.scene.name)):
        return None
    try:
        plan = job.scene.load()
    except (OSError, ValueError, SceneError):
        return None
    if held.scene != scene_fingerprint(plan):  # another plan under the same name (another scale, another folder)
        return None
    return EpisodeOutcome(job.method, plan.name, row=held.row, free=plan.free, resolution_m=plan.resolution_m, explored=held.explored,
                          trajectory_xy_m=held.trajectory_xy_m, coverage_curve_pct=held.coverage_curve_pct, kept=True, map_origin=plan.map_origin)


def _scene_hashes() -> Callable[[SceneRef], str | None]:
    """``scene_fingerprint`` of a scene, None where it does not load; a plan is loaded once, however many methods ran on it."""
    scene_hashes: dict[int, str | None] = {}

    def scene_hash(ref: SceneRef) -> str | None:
        if id(ref) not in scene_hashes:
            try:
                scene_hashes[id(ref)] = scene_fingerprint(ref.load())
            except (OSError, ValueError, SceneError):
                scene_hashes[id(ref)] = None  # its episode fails to load and says so; what the folder holds stays
        return scene_hashes[id(ref)]

    return scene_hash


def _of_another_plan(held: HeldEpisode, job: EpisodeJob, scene_hash: Callable[[SceneRef], str | None]) -> bool:
    """Whether ``held`` ran on another plan than ``job``'s under the same name (one that does not load aside)."""
    return held.scene != scene_hash(job.scene) and scene_hash(job.scene) is not None


def episodes_of_another_configuration(jobs: list[EpisodeJob], scene_hash: Callable[[SceneRef], str | None] | None = None) -> list[EpisodeJob]:
    """The jobs whose episode file the output folder already holds from another configuration: another seed,
    settings (config, simulator, weights, a method's code) or plan under the same name (another ``--m-per-px``,
    another folder). Running them would write over those results, silently before: ``plan_eval`` refuses them
    unless ``--overwrite``. A file that does not read whole is no result and does not count. ``scene_hash``: the
    plans' fingerprints already taken (``_scene_hashes``)."""
    scene_hash = scene_hash or _scene_hashes()
    others = []
    for job in jobs:
        held = read_held_episode(job.npz_path)
        if held is None:
            continue
        if not held.same_run(job) or _of_another_plan(held, job, scene_hash):
            others.append(job)
    return others


def episodes_held_otherwise(jobs: list[EpisodeJob], scene_hash: Callable[[SceneRef], str | None] | None = None) -> tuple[int, int]:
    """Of ``jobs``' episode files, how many recorded no settings (a version before the fingerprints wrote them), and
    how many of the others ran on another plan under the same name: what a refusal says beside ``summary.json``."""
    scene_hash = scene_hash or _scene_hashes()
    unrecorded = another_plan = 0
    for job in jobs:
        held = read_held_episode(job.npz_path)
        if held is not None and held.settings is None:
            unrecorded += 1
        elif held is not None and held.scene is not None and _of_another_plan(held, job, scene_hash):
            another_plan += 1
    return unrecorded, another_plan


CHANGES_SHOWN = 4
"""The refusal of a folder of another configuration names this many of the settings that differ."""


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    """``value``'s leaves by dotted key (``episode.max_steps``), as ``--set`` names them."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in _flat(item, f"{prefix}{key}.").items()}
    return {prefix.rstrip("."): value}


def _earlier_meta(out_dir: Path) -> dict[str, Any] | None:
    """``meta`` of the ``summary.json`` in ``out_dir``; None when there is none that reads."""
    try:
        meta = json.loads((Path(out_dir) / "summary.json").read_text()).get("meta")
    except (OSError, ValueError, AttributeError):
        return None
    return meta if isinstance(meta, dict) else None


def configuration_changes(
    out_dir: Path,
    request: EvalRequest,
    config: ExplorationConfig,
    sim_settings: dict[str, Any],
    weights: dict[str, dict[str, Any]],
    mujoco: dict[str, Any] | None = None,
) -> list[str]:
    """What this run sets otherwise than the earlier run whose ``summary.json`` is in ``out_dir`` (``KEY: THERE there,
    HERE here``, dotted as ``--set`` takes them; the simulator's as ``sim_settings.KEY``, a learned method's weights by
    their sha256), and the keys one side has alone (another version's: ``key K: not recorded there (added in a later
    version), D here``) unless at what the versions before them did (they count in no fingerprint:
    ``CONFIG_KEYS_ADDED``, ``SIM_SETTINGS_BEFORE_FINGERPRINTED``); last, the keys the ``--sim-config`` files set
    otherwise (``mujoco``, its keys here; the fingerprint counts them as the file gives them) where the settings they
    give do not differ (a file that sets a default, no file); [] when it has none to compare, or none differs."""
    earlier = _earlier_meta(out_dir)
    if earlier is None:
        return []
    request_there = earlier.get("request") or {}
    flags = [k for k in ("seed", "sim", "m_per_px", "sensor") if k in request_there]
    there = {**_flat(earlier.get("config") or {}), **{k: request_there[k] for k in flags}}
    here = {**_flat(to_dict(config)), **{k: getattr(request, k) for k in flags}}
    same_sim = request_there.get("sim", request.sim) == request.sim  # another simulator (said as sim) has other settings
    if same_sim and isinstance(earlier.get("sim_settings"), dict):
        there.update(_flat({"sim_settings": earlier["sim_settings"]}))
        here.update(_flat({"sim_settings": sim_settings}))
    elif same_sim:  # a version before meta.sim_settings: those that count in the fingerprint are new there
        here.update(_flat({"sim_settings": sim_settings_counted(request.sim, sim_settings, mujoco)}))
    there.update({f"weights of {m}": w.get("sha256", "")[:12] for m, w in (earlier.get("weights") or {}).items() if isinstance(w, dict)})
    here.update({f"weights of {m}": w["sha256"][:12] for m, w in weights.items()})
    counted_sim = {f"sim_settings.{k}" for k in sim_settings_counted(request.sim, sim_settings, mujoco)}
    changes = []
    for key, value in here.items():
        if key in there:
            if not _same_value(there[key], value):
                changes.append(f"{key}: {there[key]} there, {value} here")
        elif not key.startswith("weights of ") and not as_before(key, value) and (not key.startswith("sim_settings.") or key in counted_sim):
            changes.append(f"key {key}: not recorded there (added in a later version), {value} here")
    changes += [f"key {key}: {there[key]} there, not in this version" for key in there if key not in here and not key.startswith("weights of ")]
    if same_sim:
        changes += sim_config_keys_changed((earlier.get("mujoco") or {}).get("parameters") or {}, mujoco or {}, changes)
    return changes


def sim_config_keys_changed(there: dict[str, Any], here: dict[str, Any], changes: list[str]) -> list[str]:
    """The keys the ``--sim-config`` file of an earlier run (``there``: its ``meta.mujoco.parameters``) and this one's
    (``here``) set otherwise, each unless ``changes`` names its setting already (``sim_settings.KEY``)."""
    named = {change.split(":", 1)[0].removeprefix("key ") for change in changes}

    def given(params: dict[str, Any], key: str) -> str:
        return f"{params[key]}" if key in params else "not set"

    return [
        f"--sim-config {key}: {given(there, key)} there, {given(here, key)} here"
        for key in sorted(set(there) | set(here))
        if f"sim_settings.{key}" not in named and (key not in there or key not in here or not _same_value(there[key], here[key]))
    ]


def another_configuration_said(out_dir: Path, others: list[EpisodeJob], changes: list[str], unrecorded: int = 0, another_plan: int = 0) -> str:
    """The refusal of ``out_dir``, whose episodes ``others`` ran with another configuration, naming what differs: that
    ``unrecorded`` of them recorded no settings (written before the fingerprints), that ``another_plan`` ran on another
    plan of the same name, the settings its ``summary.json`` has otherwise (``changes``), or, where none of these
    tells, that the summary does not say. Where another version wrote them, it says how to keep them."""
    names = ", ".join(f"{job.method} {job.scene.name}" for job in others[:3]) + (", ..." if len(others) > 3 else "")
    version = str((_earlier_meta(out_dir) or {}).get("version") or "") or None
    written_by = f"cso-runtime {version}" if version else "an earlier cso-runtime"

    def which(count: int) -> str:
        return ("it" if count == 1 else f"all {count}") if count == len(others) else f"{count} of them"

    reasons = [f"{which(unrecorded)} recorded no settings (written by {written_by} or older)"] if unrecorded else []
    if another_plan:
        reasons.append(f"{which(another_plan)} ran on another plan under the same name (another --m-per-px, folder or map origin)")
    if changes:
        reasons.append(f"its summary.json differs in {'; '.join(changes[:CHANGES_SHOWN])}{'; ...' if len(changes) > CHANGES_SHOWN else ''}")
    elif not (unrecorded or another_plan):
        summary = "it has no summary.json to compare with" if _earlier_meta(out_dir) is None else "no setting its summary.json records differs"
        reasons.append(f"{summary}: a method of one's own whose code changed, or settings summary.json does not record")
    another_version = bool(unrecorded) or any(c.startswith("key ") for c in changes)
    keep = f"; to keep them, go on with that sweep with the version that wrote them ({written_by})" if another_version else ""
    return (
        f"{out_dir} holds {len(others)} episode{'' if len(others) == 1 else 's'} of this run's methods and plans from another configuration "
        f"({names}; {'; '.join(reasons)}): this run would write over them; give another --out, the earlier command (summary.json's meta.request) "
        f"to go on with those, or --overwrite to run them again here{keep}"
    )


def refuse_another_configuration(request: EvalRequest, plan: EvalPlan) -> None:
    """Raise ConfigError, unless ``--overwrite``, when ``--out`` holds episodes of ``plan``'s jobs from another
    configuration (``episodes_of_another_configuration``), naming what differs. ``plan_eval`` checks before any
    work and ``run_eval`` again once it holds the folder's lock: an eval into it may have ended in between."""
    if request.overwrite or not (others := episodes_of_another_configuration(plan.jobs, plan.scene_hash)):
        return
    out = Path(request.out_dir)
    changes = configuration_changes(out, request, plan.config, plan.sim_settings, plan.weights, plan.mujoco)
    raise ConfigError(another_configuration_said(out, others, changes, *episodes_held_otherwise(others, plan.scene_hash)))


def run_job(job: EpisodeJob) -> EpisodeOutcome:
    """Run one episode; any failure (bad map, crash) is returned, never raised."""
    try:
        plan = job.scene.load()
    except SceneError as exc:
        return EpisodeOutcome(job.method, job.scene.name, error=str(exc))
    try:
        policy = make_policy(job.method, job.config.masks, seed=job.seed, sensor=job.config.sensor, frontier=job.config.frontier)
        warm_up = getattr(policy, "warm_up", None)
        if warm_up is not None:  # the network's one-off trace, outside the decision latencies (as the policy service does)
            warm_up()
        t0 = time.perf_counter()
        sim = make_simulator(job.sim, plan, job.config.sensor, job.config.robot, seed=job.seed, mujoco=job.mujoco)
        animation = EpisodeAnimation() if job.animate else None
        result = run_episode(sim, policy, job.config, seed=job.seed, on_step=animation.on_step if animation else None)
        wall_s = time.perf_counter() - t0  # the frames' drawing included, when animated
        row = episode_row(job.method, job.seed, result, wall_s, real_time_factor(result.sim_time_s, wall_s))
        gif = episode_animation_path(job.out_dir, job.method, job.scene.name)
        if animation is not None and animation.finish():  # before the npz, which records it: a kill between leaves no pair
            animation.save_gif(gif)
        else:
            gif.unlink(missing_ok=True)  # an earlier run's animation of this episode would show another episode
        save_episode_files(
            job.out_dir, job.method, job.scene.name, result, row, job.settings, scene_fingerprint(plan), plan.map_origin, file_sha256(gif)
        )
    except Exception as exc:  # one bad episode must not stop the run; it is reported
        log.debug("episode failed", exc_info=True)
        return EpisodeOutcome(job.method, job.scene.name, error=f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}")
    return EpisodeOutcome.finished(job.method, result, row, plan.free, plan.resolution_m, plan.map_origin)


WORKER_DIED = "its worker process died twice (killed, or out of memory?)"


def run_in_processes(jobs: list[EpisodeJob], workers: int, done: Callable[[EpisodeOutcome], None], episode: Callable[[EpisodeJob], EpisodeOutcome] = run_job) -> None:
    """Run ``episode`` on every job in ``workers`` processes, calling ``done`` with each outcome.

    A worker that dies (killed, out of memory) breaks the whole pool, and every episode the pool had not
    finished with it; those run again, each in a process of its own (still ``workers`` at a time), so
    that one dead process never takes the run down or costs the other episodes. An episode whose
    process dies again is reported as a failure (``WORKER_DIED``)."""
    retry = []
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init)
    try:
        futures = {pool.submit(episode, job): job for job in jobs}
        for fut in as_completed(futures):
            try:
                done(fut.result())
            except BrokenProcessPool:
                retry.append(futures[fut])
    except BaseException:  # Ctrl-C: stop the running episodes now; the pending ones are dropped below
        terminate_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    if not retry:
        return
    log.warning("a worker process died; running the %d unfinished episode(s) again, one process each", len(retry))

    def again(job: EpisodeJob, outcome: EpisodeOutcome | WorkerDied) -> None:
        if isinstance(outcome, WorkerDied):
            log.error("%s on %s: %s", job.method, job.scene.name, WORKER_DIED)
            outcome = EpisodeOutcome(job.method, job.scene.name, error=WORKER_DIED)
        done(outcome)

    run_each_in_own_process(episode, retry, workers, again)


def _rows_with(rows: list[dict[str, Any]], key: str) -> list[tuple[float, dict[str, Any]]]:
    """``(value, row)`` of each row that has a finite ``key``."""
    # Rows read back from episodes.csv (benchmarks/tables.py) hold text, "" for a cell left empty (sim_time_s on a real robot).
    return [(float(v), r) for r in rows if (v := r.get(key)) not in (None, "") and math.isfinite(float(v))]


def _values(rows: list[dict[str, Any]], key: str) -> list[float]:
    return [v for v, _ in _rows_with(rows, key)]


def _mean(rows: list[dict[str, Any]], key: str) -> float | None:
    values = _values(rows, key)
    return round(float(np.mean(values)), 6) if values else None


def _std(rows: list[dict[str, Any]], key: str) -> float | None:
    """The sample standard deviation (ddof=1) of ``key`` over the episodes that have it; None under two episodes:
    one episode's spread is unknown, not 0."""
    values = _values(rows, key)
    return round(float(np.std(values, ddof=1)), 6) if len(values) >= 2 else None


def _ci95(rows: list[dict[str, Any]], key: str) -> list[float] | None:
    """95 % interval of ``key``'s mean by the bootstrap of ``compare`` (``bootstrap_mean_ci``: the plans resampled,
    a plan's episodes kept together, a fixed seed, so the same episodes give the same interval); None under two
    plans: one plan gives nothing to resample. The episodes are taken in episodes.csv's order (by plan, then seed),
    whatever order they finished in: the bootstrap's resamples pick by position, so an eval with ``--workers``, or one
    ``--resume`` finished (its kept episodes first), gave the same episodes another interval."""
    kept = sorted(_rows_with(rows, key), key=lambda vr: (str(vr[1]["map"]), str(vr[1].get("traversable_area_m2")), str(vr[1].get("seed")), vr[0]))
    plans = [(str(r["map"]), str(r.get("traversable_area_m2"))) for _, r in kept]  # a plan as compare tells it: one name at two cell sizes is two
    if len(set(plans)) < 2:
        return None
    low, high = bootstrap_mean_ci(np.array([v for v, _ in kept]), clusters=plans)
    return [round(low, 6), round(high, 6)]


def table1_stats(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Each Table 1 metric's mean over ``rows``, with its sample standard deviation (``<metric>_std``) and the 95 %
    bootstrap interval of the mean over plans (``<metric>_ci95``, [low, high]) beside it."""
    return {
        key: value
        for k in METRICS
        for key, value in ((k, _mean(rows, k)), (f"{k}{STD_SUFFIX}", _std(rows, k)), (f"{k}{CI95_SUFFIX}", _ci95(rows, k)))
    }


def _efficiency_episodes(rows: list[dict[str, Any]]) -> int:
    """Episodes behind the efficiency mean: an episode of no step (its first scan saw everything) has none."""
    return sum(1 for r in rows if r.get("efficiency_m2_per_step") is not None and math.isfinite(float(r["efficiency_m2_per_step"])))


AGGREGATION = {
    "rows": "one row of episodes.csv per episode; every figure of methods (and of methods.<method>.by_scale) aggregates "
    "the method's episodes (of that scale) alone, each episode counted once",
    "<metric>": "the mean over those episodes; efficiency_m2_per_step: the mean of each episode's m2/step (not the mean area "
    "over the mean steps), episodes of no step left out (efficiency_episodes counts the others)",
    "<metric>_std": "the sample standard deviation (ddof=1) over the same episodes, in the metric's unit; null for one episode",
    "<metric>_ci95": "[low, high]: the 95 % percentile bootstrap interval of the mean, 10,000 resamples of the plans with "
    "replacement (the episodes of one plan kept together), seed 0; null under two plans",
    "paired": "paired.csv's rows: each method against the baseline on the scenes both ran, per scale",
}
"""``summary.json``'s ``aggregation``: how each figure of it is computed from ``episodes.csv``, said in the file, so that
a reader of the JSON alone (pandas, a notebook) need not look it up."""


def summarize(rows: list[dict[str, Any]], failures: list[dict[str, Any]], methods: list[str], meta: dict[str, Any], baseline: str = "greedy-dist") -> dict[str, Any]:
    """Per-method means of the Table 1 metrics with their sample standard deviations, a per-scale breakdown, the failures, and each method
    against ``baseline`` scene by scene (``cso_runtime.comparison``; empty when it did not run)."""
    summary: dict[str, Any] = {"meta": meta, "aggregation": AGGREGATION, "methods": {}}
    failures = sorted(failures, key=lambda f: (str(f["method"]), str(f["map"]), str(f.get("seed", ""))))  # not in the order they happened
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        entry: dict[str, Any] = table1_stats(mine)
        entry.update({k: _mean(mine, k) for k in PACE})  # None where no episode has them (a real robot, an older run's)
        entry["episodes"] = len(mine)
        entry["efficiency_episodes"] = _efficiency_episodes(mine)
        entry["terminated_by"] = {t: sum(1 for r in mine if r["terminated_by"] == t) for t in sorted({r["terminated_by"] for r in mine})}
        # Why each of its episodes that ended no_frontier did (rows of older runs have no such column, and none is said).
        entry["ended_why"] = sorted(  # by plan and seed, as episodes.csv: not the order episodes finished in (--workers, --resume)
            ({"map": r["map"], "seed": r["seed"], "why": r["ended_why"]} for r in mine if r.get("ended_why")), key=lambda e: (str(e["map"]), str(e["seed"]))
        )
        entry["by_scale"] = {}
        for scale in SCALES:
            part = [r for r in mine if r["scale"] == scale]
            if part:
                entry["by_scale"][scale] = {**table1_stats(part), "episodes": len(part), "efficiency_episodes": _efficiency_episodes(part)}
        entry["failures"] = [f for f in failures if f["method"] == method]
        entry["maps"] = sorted({r["map"] for r in mine})  # what the report shows of the folder: not an earlier run's files
        summary["methods"][method] = entry
    summary["failures"] = failures
    paired = compare_to_baseline(efficiency_by_scene(rows), baseline) if baseline in methods else []
    paired.sort(key=lambda c: (scale_rank(c.scale), c.scale, methods.index(c.method)))  # as Table 1
    summary["paired"] = {"baseline": baseline, "comparisons": as_dicts(paired)}
    return summary


def missing(value: Any) -> bool:
    """A value the row has none to give: None, or a float with none (NaN, the efficiency of an episode of no step)."""
    return value is None or (isinstance(value, float) and not math.isfinite(value))


def json_row(row: dict[str, Any]) -> dict[str, Any]:
    """``row`` as strict JSON takes it: a missing value is null (``NaN`` is no JSON, and strict readers refuse it);
    the readers of the row (the tables, ``csv_cell``) take None as they take NaN."""
    return {k: None if missing(v) else v for k, v in row.items()}


def csv_cell(value: Any) -> Any:
    """``value`` as an ``episodes.csv`` cell: a missing value (None, or a float with none to give: NaN, the efficiency
    of an episode of no step) is one empty cell, which csv readers and pandas read as missing (``nan`` would read as a
    number, and two spellings of one thing make every reader handle both); summary.json's null for the same values."""
    return "" if missing(value) else value


def write_outputs(
    out_dir: Path, rows: list[dict[str, Any]], failures: list[dict[str, Any]], methods: list[str], meta: dict[str, Any], baseline: str = "greedy-dist"
) -> dict[str, Any]:
    """summary.json, episodes.csv, and paired.csv when there is a comparison with the baseline."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summarize(rows, failures, methods, meta, baseline)
    write_text_atomic(out_dir / "summary.json", json.dumps(summary, indent=2, allow_nan=False, default=str))
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=list(CSV_FIELDS), extrasaction="ignore")
    writer.writeheader()
    setup = run_setup(meta)
    for r in sorted(rows, key=lambda r: (r["method"], r["map"])):
        writer.writerow({k: csv_cell(v) for k, v in {**setup, **r}.items()})
    write_text_atomic(out_dir / "episodes.csv", table.getvalue())
    if summary["paired"]["comparisons"]:
        write_paired_csv(out_dir / "paired.csv", summary["paired"]["comparisons"])
    else:
        (out_dir / "paired.csv").unlink(missing_ok=True)  # an earlier run's, in the same folder
    return summary


SEEDED_METHODS = ("random",)
"""The methods whose choices the episode seed draws; every other one decides the same on the same map."""


def seed_changes_nothing(methods: list[str], config: ExplorationConfig, sim: str) -> bool:
    """Whether every episode of ``methods`` is the same under any seed: the seed draws the ``random`` method's choices
    and the sensor's range noise, and the start pose is the plan's. (MuJoCo's odometry drift is seeded too: not claimed.)
    A method of the user's own may draw on its seed (``reset(seed)``): not claimed either."""
    return sim == "2d" and config.sensor.range_noise_std_m == 0 and not any(m in SEEDED_METHODS or own_method_spec(m) for m in methods)


def _earlier_methods(out_dir: Path) -> dict[str, Any]:
    """The ``methods`` of an earlier run's summary.json in ``out_dir``; {} when there is none (or it is unreadable)."""
    try:
        earlier = json.loads((out_dir / "summary.json").read_text()).get("methods", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return earlier if isinstance(earlier, dict) else {}


def methods_summarized_elsewhere(out_dir: Path, methods: list[str]) -> list[str]:
    """The methods an earlier run's summary.json in ``out_dir`` holds that ``methods`` leaves out."""
    return sorted(m for m in _earlier_methods(out_dir) if m not in methods)


def methods_summarized_elsewhere_said(out_dir: Path, others: list[str]) -> str:
    """The warning of ``methods_summarized_elsewhere``: results this run's summary.json and episodes.csv replace."""
    return (
        f"{out_dir} holds the results of {', '.join(others)}: this run's summary.json and episodes.csv replace them (their episode files stay); "
        "give another --out, or run every method in one eval"
    )


def seeds_pooled_elsewhere(out_dir: Path, seeds: list[int]) -> list[int]:
    """The seeds an earlier ``eval --seeds``' pooled files in ``out_dir`` hold (``seeds_pooled_in``) that ``seeds`` leaves out."""
    return sorted(s for s in seeds_pooled_in(out_dir) if s not in seeds)


def pooled_results_replaced_said(request: EvalRequest) -> list[str]:
    """``eval --seeds`` into a folder whose pooled summary.json and episodes.csv hold other methods or other seeds: the
    warnings, as a one-seed eval's of other methods (``methods_summarized_elsewhere``), that this run replaces them."""
    out = Path(request.out_dir)
    said = []
    others = methods_summarized_elsewhere(out, request.methods)
    if others:
        said.append(methods_summarized_elsewhere_said(out, others))
    seeds = seeds_pooled_elsewhere(out, request.seeds)
    if seeds:
        every = ",".join(map(str, sorted({*seeds_pooled_in(out), *request.seeds})))
        said.append(
            f"{out} holds the results of seed(s) {', '.join(map(str, seeds))} pooled: this run's summary.json and episodes.csv replace them "
            f"(their seed<S>/ folders stay); give another --out, or run every seed in one eval (--seeds {every} --resume pools them all, "
            "running only the episodes not yet run)"
        )
    return said


def maps_summarized_elsewhere(out_dir: Path, methods: list[str], maps: list[str]) -> list[str]:
    """The plans whose episodes of ``methods`` an earlier run's summary.json in ``out_dir`` holds and ``maps`` leaves
    out: an eval of one plan into a folder, to run it again, would drop the others from its tables."""
    earlier = _earlier_methods(out_dir)
    held = {name for m in methods if isinstance(earlier.get(m), dict) for name in earlier[m].get("maps") or []}
    return sorted(held - set(maps))


@dataclass
class EvalPlan:
    """What an eval would run, resolved and checked before any episode (``run_eval``, ``eval --dry-run``)."""

    config: ExplorationConfig
    scenes: list[SceneRef]
    jobs: list[EpisodeJob]
    weights: dict[str, dict[str, Any]]
    """Each learned method's weights file and SHA-256 (``weights_provenance``)."""
    mujoco: dict[str, Any]
    """The ``--sim-config`` file's MuJoCo parameters ({} without one)."""
    warnings: list[str]
    """What the user should know before the episodes run (results the run would replace, a seed that changes nothing,
    weights trained otherwise)."""
    sim_settings: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Every parameter the simulator runs with (``simulator_settings``)."""
    scene_hash: Callable[[SceneRef], str | None] = dataclasses.field(default_factory=_scene_hashes)
    """Each scene's fingerprint, taken once: the folder is checked before the lock and again under it."""
    seed_plans: list[tuple[EvalRequest, EvalPlan]] = dataclasses.field(default_factory=list)
    """With ``--seeds``: each seed's eval (``EvalRequest.for_seed``) and its plan; ``jobs`` holds all of theirs."""


def refuse_seed_with_seeds(seed: int | None, seeds: list[int]) -> None:
    """``eval --seed S --seeds ...``: a ConfigError, ``--seed 0`` included when the command line gives it (``seed`` not
    None): ``--seeds`` runs each of its seeds in place of the one ``--seed``."""
    if seeds and seed is not None:
        raise ConfigError(f"--seed {seed} and --seeds: give one (--seeds {','.join(map(str, seeds))} runs each of those seeds)")


def seed_folder(out_dir: Path | str, seed: int) -> Path:
    """Where ``eval --seeds`` writes the episodes of ``seed``: an eval folder of that seed, inside ``--out``."""
    return Path(out_dir) / f"seed{seed}"


def seed_changes_nothing_said(flag: str) -> str:
    """The warning of a seed (``--seed 3``, ``--seeds 0,1``) that changes no episode (``seed_changes_nothing``)."""
    return (
        f"{flag} changes no episode here: it draws the random method's choices and the sensor's range noise, which is 0 "
        "(sensor.range_noise_std_m), and every episode starts at the plan's start pose, so these episodes are those of any "
        "seed; give --set sensor.range_noise_std_m=0.01 (metres) for repeated tests that differ"
    )


def seeds_pooled_in(out_dir: Path | str) -> list[int]:
    """The seeds of the ``eval --seeds`` whose pooled files ``out_dir`` holds (its summary.json's ``meta.seeds``); []
    for any other folder (one of a one-seed eval, or a parent of ``--seed`` runs' folders of one's own)."""
    seeds = (_earlier_meta(Path(out_dir)) or {}).get("seeds")
    return [s for s in seeds if isinstance(s, int) and not isinstance(s, bool)] if isinstance(seeds, list) else []


def refuse_the_other_kind_of_eval(request: EvalRequest) -> None:
    """Raise ConfigError where ``--out`` holds the other kind of eval: ``--seeds`` into a one-seed eval's folder (its
    ``episodes/``), or a one-seed eval into the folder of ``--seeds`` (``seeds_pooled_in``), whose summary.json and
    episodes.csv either would replace. ``plan_eval`` checks before any work and ``run_eval`` again under the lock."""
    out = Path(request.out_dir)
    if request.seeds and (out / "episodes").is_dir():
        raise ConfigError(
            f"{out} holds the episodes of a one-seed eval ({out}/episodes/): --seeds writes each seed's episodes in {out}/seed<S>/ and "
            f"pools them in {out}'s summary.json and episodes.csv, which would replace that eval's; give another --out"
        )
    if not request.seeds and (pooled := seeds_pooled_in(out)):
        raise ConfigError(
            f"{out} holds the episodes of eval --seeds {','.join(map(str, pooled))} ({out}/seed<S>/) pooled in its summary.json and "
            f"episodes.csv, which a one-seed eval would replace (and --seeds --resume would then refuse the folder); give another --out, "
            f"or --out {out}/seed<S> to go on with one seed's episodes"
        )


def plan_seeds(request: EvalRequest, out_checked: bool = True) -> EvalPlan:
    """``plan_eval`` of an eval of several seeds (``--seeds``): each seed's plan, checked before any episode, and one
    plan of all their jobs (config, scenes, weights and settings are the same for every seed). A ``--out`` that holds a
    one-seed eval's episodes is refused: the pooled summary.json and episodes.csv would replace that eval's."""
    if out_checked:
        refuse_the_other_kind_of_eval(request)
    plans = [(one, plan_eval(one, out_checked)) for one in map(request.for_seed, request.seeds)]
    each = [said for one, plan in plans for said in plan.warnings if said != seed_changes_nothing_said(f"--seed {one.seed}")]
    warnings = (pooled_results_replaced_said(request) if out_checked else []) + list(dict.fromkeys(each))
    first = plans[0][1]
    if seed_changes_nothing(request.methods, first.config, request.sim):
        warnings.append(seed_changes_nothing_said(f"--seeds {','.join(map(str, request.seeds))}"))
    jobs = [job for _, plan in plans for job in plan.jobs]
    return EvalPlan(first.config, first.scenes, jobs, first.weights, first.mujoco, warnings, first.sim_settings, first.scene_hash, seed_plans=plans)


def plan_eval(request: EvalRequest, out_checked: bool = True) -> EvalPlan:
    """Check ``request`` and resolve what it would run: config, scenes, episodes, weights, warnings; runs and writes
    nothing (raises ConfigError, SceneError). With ``--seeds``, ``plan_seeds``. ``out_checked`` False (``eval
    --resolved`` alone, the configuration to run later, elsewhere): the ``--out`` folder is neither read nor refused
    (another configuration's episodes, the other kind of eval), nor warned of."""
    if request.seeds:
        request.check_seeds()
        return plan_seeds(request, out_checked)
    request.validate()
    config = request.exploration_config()
    scenes = resolve_scenes(request.maps, request.limit, request.m_per_px)
    refuse_scenes_sharing_files(scenes)
    out = Path(request.out_dir)
    if out_checked:
        refuse_the_other_kind_of_eval(request)
    warnings: list[str] = []
    others = methods_summarized_elsewhere(out, request.methods) if out_checked else []
    if others:
        warnings.append(methods_summarized_elsewhere_said(out, others))
    dropped = maps_summarized_elsewhere(out, request.methods, [s.name for s in scenes]) if out_checked else []
    if dropped:
        warnings.append(
            f"{out} holds episodes of {len(dropped)} plan(s) this run leaves out ({', '.join(dropped[:5])}{', ...' if len(dropped) > 5 else ''}): "
            "its summary.json and episodes.csv will not count them (their episode files stay); to run some episodes again in that folder, "
            "delete their episodes/<method>/<map>.npz and give the earlier command (its meta.request in summary.json) with --resume"
        )
    if request.seed != 0 and seed_changes_nothing(request.methods, config, request.sim):
        warnings.append(seed_changes_nothing_said(f"--seed {request.seed}"))
    if request.m_per_px != DEFAULT_M_PER_PX and not any(ref.scaled_by_m_per_px for ref in scenes):  # the default: not known to be given
        warnings.append(f"--m-per-px {request.m_per_px:g} is ignored: it scales PNG plans only, and these scenes (generated plans, map files) have their own cell size")
    weights: dict[str, dict[str, Any]] = {}
    if any(m in LEARNED_METHODS for m in request.methods):
        from cso_runtime.learned.weights import mask_mismatches, sensor_mismatches, weights_provenance  # noqa: PLC0415

        weights = {m: weights_provenance(m, config.sensor) for m in request.methods if m in LEARNED_METHODS}
        warnings += [f"{m} (a policy does best with the sensor it was trained with)" for m in sensor_mismatches(list(weights), config.sensor)]
        warnings += [f"{m} (a policy does best with the masks it was trained under)" for m in mask_mismatches(list(weights), config.masks, config.sensor)]
        from cso_runtime.learned.registry import check_weights  # noqa: PLC0415 - loaded already: the request's validate checked them

        warnings += [said for m in weights for said in check_weights(m, sensor=config.sensor, frontier=config.frontier)]
    mujoco = request.mujoco_parameters()
    sim_settings = simulator_settings(request.sim, config.sensor, config.robot, mujoco)
    watchdog_key = f"{request.sim_config_path}: watchdog_s" if request.sim_config_path is not None else f"--sim {request.sim}'s default watchdog_s"
    advice = "eval hands every step its command, none goes stale: give --sim-config FILE with watchdog_s: at least robot.control_period_s"
    watchdog = watchdog_within_a_step_said(sim_settings, config.robot, watchdog_key, advice=advice)
    warnings += [watchdog] if watchdog is not None else []
    settings = {
        m: settings_fingerprint(config, request.sim, weights[m]["sha256"] if m in weights else "", mujoco, own_method_code_sha256(m), sim_settings)
        for m in request.methods
    }
    jobs = [
        EpisodeJob(m, s, request.seed, request.sim, config, out, settings[m], animate=request.animate, mujoco=mujoco)
        for s in scenes
        for m in request.methods
    ]
    plan = EvalPlan(config, scenes, jobs, weights, mujoco, warnings, sim_settings)
    if out_checked:
        refuse_another_configuration(request, plan)
    return plan


def refuse_scenes_sharing_files(scenes: list[SceneRef]) -> None:
    """Raise ConfigError where two scenes of a spec would write the same files: the same name (``a.yaml`` and ``a.yml``
    in one folder), or names that ``file_stem`` makes one (``room 1.png`` and ``room_1.png``). Each episode would write
    over the other's npz, map and trajectory plot, one plan's results lost from the folder (and ``--resume`` would then
    refuse it, the file of another plan under its name)."""

    def said(r: SceneRef) -> str:
        if not r.path:
            return repr(r.name)
        # A path of bytes that are no UTF-8 as those bytes: escaped as stderr writes it, ``img_\xff.png`` read as the
        # very ``img_\udcff.png`` of the file beside it whose name is that text, the one its name is escaped to.
        path = r.path if utf8_text(r.path) == r.path else f"{os.fsencode(r.path)!r}, a name of bytes that are no UTF-8"
        return f"{r.name!r} ({path})"

    seen: dict[str, SceneRef] = {}
    for ref in scenes:
        other = seen.setdefault(file_stem(ref.name), ref)
        if other is not ref:
            raise ConfigError(
                f"scenes {said(other)} and {said(ref)} would share the files episodes/<method>/{file_stem(ref.name)}.npz, its map and "
                "trajectory plot, one plan's results written over by the other's: rename one of them, or run them in two evals, each with its own --out"
            )


DRY_RUN_SCENES_SHOWN = 5
"""``eval --dry-run`` names this many scenes; the rest it counts."""


def plan_said(request: EvalRequest, plan: EvalPlan, out_checked: bool = True) -> tuple[list[str], list[str]]:
    """What ``eval --dry-run`` says of ``plan``: lines of what it would run, and the scenes that would fail to load
    (a PNG or map file that is missing or no plan), which a real eval counts as failed episodes. Loads each plan to
    tell its scale (generated ones say theirs); reads the ``--out`` folder (``out_checked`` False: says it is not
    checked), writes nothing."""
    scales: dict[str, int] = {}
    unloadable: list[str] = []
    for ref in plan.scenes:
        if ref.generated is not None:
            scale = ref.generated[0]
        else:
            try:
                scale = ref.load().scale
            except (OSError, SceneError, ValueError) as exc:
                unloadable.append(f"{ref.name}: {exc}")
                continue
        scales[scale] = scales.get(scale, 0) + 1
    names = ", ".join(ref.name for ref in plan.scenes[:DRY_RUN_SCENES_SHOWN]) + (", ..." if len(plan.scenes) > DRY_RUN_SCENES_SHOWN else "")
    by_scale = ", ".join(f"{scales[s]} {s}" for s in sorted(scales, key=scale_rank))
    sensor = plan.config.sensor
    methods = [f"{m} (weights {plan.weights[m]['path']}, sha256 {plan.weights[m]['sha256'][:12]})" if m in plan.weights else m for m in request.methods]
    cell = f"{request.m_per_px:g} m/px (PNG plans)" if any(ref.scaled_by_m_per_px for ref in plan.scenes) else "each scene's own (generated plans, map files)"
    out = Path(request.out_dir)
    held = episodes_held(plan, out) if out_checked else 0
    if not out_checked:
        folder = "not checked (--dry-run checks it)"
    elif not out.is_dir():
        folder = "a new folder"
    elif request.resume:
        folder = f"exists: --resume keeps the {held} of these episodes it holds with the same settings, runs the other {len(plan.jobs) - held}"
    else:
        folder = f"exists, holding {held} of these episodes: without --resume every episode runs again, its files written over" if held else "exists, holding none of these episodes"
    seeds = f" x {len(request.seeds)} seeds" if request.seeds else ""
    lines = [
        f"eval, valid: would run {len(plan.jobs)} episode(s), {len(request.methods)} method(s) x {len(plan.scenes)} scene(s){seeds}, nothing run or written now",
        f"methods: {', '.join(methods)}",
        f"scenes: {request.maps}: {by_scale or 'none loadable'}; {names}",
        f"cell size: {cell}",
        (
            f"sensor: {request.sensor}, {sensor.fov_deg:g} degrees, {sensor.resolution_deg:g}-degree beams, "
            f"{sensor.range_min_m:g}-{sensor.range_max_m:g} m, {sensor.mount_x_m:g} m ahead of the centre"
        ),
        f"simulator: {request.sim}; {seeds_said(request)}; at most {plan.config.episode.max_steps} steps an episode; workers: {request.workers}",
        f"output: {out}: {folder}",
    ]
    return lines, unloadable


def seeds_said(request: EvalRequest) -> str:
    """``seed 0``, or ``seeds 0, 1, 2 (each in OUT/seed<S>/, pooled in OUT/)``."""
    if not request.seeds:
        return f"seed {request.seed}"
    return f"seeds {', '.join(map(str, request.seeds))} (each in {request.out_dir}/seed<S>/, pooled in {request.out_dir}/)"


EVAL_LOCK = ".eval.lock"
"""An eval holds an exclusive lock on ``<out>/.eval.lock`` (its pid in it) from its first episode to its last file:
one eval per output folder, or two would run every episode twice, writing over each other's files."""


def hold_eval_lock(out_dir: Path) -> int | None:
    """Take ``out_dir``'s eval lock (``EVAL_LOCK``); its file descriptor, or None when another eval holds it. OSError
    where no lock can be had (``hold_lock_file``)."""
    return hold_lock_file(Path(out_dir) / EVAL_LOCK)


def run_eval(request: EvalRequest, progress: RichProgress | None = None, plan: EvalPlan | None = None) -> dict[str, Any]:
    """Run every (method, scene) episode and write all outputs; returns the summary. ``plan``: ``plan_eval(request)``
    when the caller made it already. Raises ConfigError, before any episode, while another eval writes ``out_dir``.
    With ``--seeds``, each seed's eval in its folder, then the pooled files (``_run_seeds``)."""
    plan = plan if plan is not None else plan_eval(request)
    with folder_lock(Path(request.out_dir) / EVAL_LOCK, "eval", lambda said: log.warning("%s", said)) as locked:
        refuse_the_other_kind_of_eval(request)  # again: an eval of the other kind may have written the folder since plan_eval
        if plan.seed_plans:
            return _run_seeds(request, plan, progress)
        return _run_eval_locked(request, plan, progress, locked=locked)


def _run_eval_locked(request: EvalRequest, plan: EvalPlan, progress: RichProgress | None, locked: bool = True) -> dict[str, Any]:
    """``run_eval`` while it holds the output folder's lock; ``locked`` False where none could be had, and the partial
    files there may be another eval's, being written."""
    refuse_another_configuration(request, plan)  # again: an eval into the folder may have ended since plan_eval
    for warning in plan.warnings:
        log.warning("%s", warning)
    software = software_provenance()  # before the episodes: the commit that runs them, not one checked out meanwhile
    outcomes, interrupted = _run_episodes(request, plan, progress, locked)
    return _write_results(request, plan, outcomes, interrupted, software, progress)


def _run_seeds(request: EvalRequest, plan: EvalPlan, progress: RichProgress | None) -> dict[str, Any]:
    """``run_eval`` of several seeds (``--seeds``) while it holds ``--out``'s lock: each seed's eval in its folder
    (``seed_folder``, under that folder's lock too), as ``--seed S`` writes it, one after the other; then ``--out``'s
    files of every seed's episodes pooled. A Ctrl-C stops after the seed it interrupts, as a one-seed eval's: during a
    seed's episodes, or between two seeds, the episodes that finished are written (that seed's folder, then the pooled
    files, which say it was interrupted: ``--resume`` runs the rest); while a seed's files are written, it stops there
    (``eval_main`` says which folder's files may be missing: ``--resume`` writes them)."""
    for warning in plan.warnings:
        log.warning("%s", warning)
    software = software_provenance()
    outcomes: list[EpisodeOutcome] = []
    interrupted = False
    for one, one_plan in plan.seed_plans:
        folder = Path(one.out_dir)
        mine: list[EpisodeOutcome] = []
        writing = False
        try:
            folder.mkdir(parents=True, exist_ok=True)
            with folder_lock(folder / EVAL_LOCK, "eval", lambda said: log.warning("%s", said)) as locked:
                refuse_another_configuration(one, one_plan)
                mine, interrupted = _run_episodes(one, one_plan, progress, locked, label=f"eval seed {one.seed}")
                writing = True
                _write_results(one, one_plan, mine, interrupted, software, progress)
                writing = False
        except KeyboardInterrupt:
            if writing:  # its files half written: stop here, as a one-seed eval does
                raise
            interrupted = True  # before its episodes, or once its files were written: the pooled files say what finished
            log.warning("interrupted at seed %d, after %d of %d episodes", one.seed, len(outcomes) + len(mine), len(plan.jobs))
        for outcome in mine:
            outcome.seed = one.seed
        outcomes += mine
        if interrupted:
            break
    return _write_results(request, plan, outcomes, interrupted, software, progress)


def _run_episodes(
    request: EvalRequest, plan: EvalPlan, progress: RichProgress | None, locked: bool, label: str = "eval"
) -> tuple[list[EpisodeOutcome], bool]:
    """Run ``plan``'s episodes (those ``--resume`` keeps read back); their outcomes, and whether a Ctrl-C stopped them."""
    jobs = plan.jobs
    out = Path(request.out_dir)
    for stale in remove_stale_partial_files(out, [job.npz_path for job in jobs], is_an_episode_file) if locked else []:  # a killed eval's
        log.info("removed %s, left by an eval that was killed while writing it", stale)
    outcomes: list[EpisodeOutcome] = []
    total = len(jobs)
    if progress is not None:
        progress.start(total, label)

    def done(outcome: EpisodeOutcome) -> None:
        outcomes.append(outcome)
        if progress is not None:
            progress.advance(outcome)

    if request.resume:
        todo = []
        for job in jobs:
            finished = load_finished(job)
            if finished is None:
                todo.append(job)
            else:
                remove_a_gif_not_its_own(job)
                done(finished)
        jobs = todo
    interrupted = False
    try:
        if request.workers == 1:
            for job in jobs:
                done(run_job(job))
        else:
            run_in_processes(jobs, request.workers, done)
    except KeyboardInterrupt:
        interrupted = True  # the episodes that finished are written below; --resume runs the rest
        log.warning("interrupted after %d of %d episodes", len(outcomes), total)
    return outcomes, interrupted


def _write_results(
    request: EvalRequest, plan: EvalPlan, outcomes: list[EpisodeOutcome], interrupted: bool, software: dict[str, Any], progress: RichProgress | None
) -> dict[str, Any]:
    """summary.json, episodes.csv, paired.csv, the figures and report.html of ``outcomes`` in ``request.out_dir``; the
    summary. With ``--seeds`` (every seed's outcomes pooled), no trajectory plot: each seed's folder has its own."""
    config, scenes, weights, mujoco = plan.config, plan.scenes, plan.weights, plan.mujoco
    out = Path(request.out_dir)
    rows = [{**o.row, "cell_size_m": o.resolution_m} for o in outcomes if o.row is not None]  # each plan's own (episodes.csv)
    failures: list[dict[str, Any]] = [
        {"method": o.method, "map": o.map, "error": o.error or "", **({"seed": o.seed} if o.seed is not None else {})} for o in outcomes if o.row is None
    ]
    meta = {
        "command": "cso-runtime eval",
        "version": __version__,  # which code made the table
        "software": software,  # its checkout's commit, Python and libraries, the command line
        "maps": request.maps,
        # The flag's scale of PNG plans; null where none ran (generated plans and map files: their own, in cell_sizes_m).
        "m_per_px": request.m_per_px if any(ref.scaled_by_m_per_px for ref in scenes) else None,
        "cell_sizes_m": sorted({o.resolution_m for o in outcomes if o.row is not None}),  # what the scenes ran at (generated: 0.05, maps: their own)
        "seed": None if request.seeds else request.seed,  # --seeds: no one seed; each row says its own
        "sim": request.sim,
        "sim_settings": simulator_settings(request.sim, config.sensor, config.robot, mujoco),  # all of them, defaults too
        "scenes": len(scenes),
        "request": request.as_record(),  # every flag the run was given (--limit, --method, --workers, ...): enough to run it again
        "config": to_dict(config),
    }
    if request.seeds:
        meta["seeds"] = list(request.seeds)
    if request.resume:
        meta["resumed_episodes"] = sum(o.kept for o in outcomes)  # kept from the earlier run; the rest ran now
    if interrupted:
        meta["interrupted"] = {"episodes_finished": len(outcomes), "episodes_planned": len(plan.jobs), "resume": "run the same command with --resume"}
    if weights:
        meta["weights"] = weights
    if mujoco:
        meta["mujoco"] = {"file": str(request.sim_config_path), "parameters": mujoco}
    if progress is not None:  # hundreds of plans take a while to plot: say so rather than sit at N/N
        progress.writing(out, 0 if request.seeds else len({o.map for o in outcomes if o.row is not None}), pooled_seeds=len(request.seeds))
    summary = write_outputs(out, rows, failures, request.methods, meta, request.baseline)
    from cso_runtime.plots import plot_coverage_curves, plot_efficiency_by_scale, plot_paired_efficiency, plot_trajectories  # noqa: PLC0415 - matplotlib is slow to import

    if rows:
        plot_coverage_curves(out / COVERAGE_FIGURE, [o for o in outcomes if o.row is not None], request.methods)
        plot_efficiency_by_scale(out / EFFICIENCY_FIGURE, summary)
    else:  # no episode: no figure (an earlier run's in --out would describe that run), none linked from the report
        (out / COVERAGE_FIGURE).unlink(missing_ok=True)
        (out / EFFICIENCY_FIGURE).unlink(missing_ok=True)
    if summary["paired"]["comparisons"]:
        plot_paired_efficiency(out / PAIRED_FIGURE, efficiency_by_scene(rows), request.baseline, request.methods)
    else:
        (out / PAIRED_FIGURE).unlink(missing_ok=True)
    by_map: dict[str, list[EpisodeOutcome]] = {}
    for o in outcomes:
        if o.row is not None and not request.seeds:
            by_map.setdefault(o.map, []).append(o)
    for name, group in by_map.items():
        plot_trajectories(trajectory_plot_path(out, name), name, sorted(group, key=lambda o: request.methods.index(o.method)))
    write_report(out, summary)
    return summary


def clock_text(seconds: float) -> str:
    """``H:MM:SS``, as rich's elapsed and remaining columns show time."""
    whole = max(0, round(seconds))
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


def time_left_s(elapsed_s: float, ran: int, remaining: int) -> float | None:
    """Seconds the ``remaining`` episodes should take at the pace of the ``ran`` episodes run in ``elapsed_s`` (the
    workers together); None before the first. Episodes ``--resume`` kept took no time and do not count."""
    return elapsed_s / ran * remaining if ran > 0 else None


class RichProgress:
    """Progress bar on stderr with the last episode's result."""

    TIME_LEFT_FIELD = "time_left"
    UNKNOWN_TIME = "-:--:--"
    """The bar's time left before the first episode run now (rich's own placeholder)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn  # noqa: PLC0415

        from cso_runtime.live_view import console_that_survives_its_reader, progress_with_stats_below, redraws_in_place  # noqa: PLC0415

        console = console_that_survives_its_reader(stderr=True, tell=False)  # `eval ... | head`: the episodes go on
        self.on_terminal = redraws_in_place(console)
        """A bar redrawn in place on a terminal; else (a log, CI, a pipe: the output's own ``isatty()``, not rich's
        ``is_terminal``, which ``FORCE_COLOR`` makes true there) one plain line per episode, no cursor control."""
        # The last episode's result, then what is being written, on a line under the bar (the task's ``stats``): after
        # it, in an 80-column terminal, they squeezed the count and the times to nothing, as the training bar's figures did.
        self.progress = progress_with_stats_below(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            # The time left of ``time_left_s``, as the log lines say it: rich's own estimate would count the episodes
            # ``--resume`` kept, read back in a burst, as run at once (about 0 left).
            TextColumn(f"{{task.fields[{self.TIME_LEFT_FIELD}]}}", style="progress.remaining"),
            console=console,
            markup=True,
            get_time=clock,
            disable=not self.on_terminal,  # logs and CI get one line per episode instead of a bar
        )
        self.task: TaskID | None = None
        """The bar's task, from ``start`` on."""
        self.done = 0
        self.total = 0
        self.ran = 0
        """Episodes run by this command (not kept by ``--resume``): the pace of the time left."""
        self.clock = clock
        self.started_s = 0.0
        self.writing_to: Path | None = None
        """The folder ``writing`` said the results are being written to, once the episodes are over."""
        self.label = "eval"
        """The bar's name: ``eval``, or ``eval seed S`` for each seed of ``--seeds`` (which the log lines say first)."""

    def start(self, total: int, label: str = "eval") -> None:
        """A bar of ``total`` episodes, named ``label`` (``eval seed 1`` for each seed of ``--seeds``)."""
        self.total = total
        self.done = self.ran = 0
        self.started_s = self.clock()
        self.writing_to = None  # a seed of --seeds after the one written: its episodes, not files, now
        self.progress.start()
        fields: dict[str, Any] = {self.TIME_LEFT_FIELD: self.UNKNOWN_TIME, "stats": ""}
        for task in self.progress.tasks:  # --seeds: the line under the bars is the running seed's
            self.progress.update(task.id, stats="")
        self.task = self.progress.add_task(label, total=total, **fields)
        self.label = label

    def advance(self, outcome: EpisodeOutcome) -> None:
        if outcome.row is not None:
            r = outcome.row
            kept = ", kept from the earlier run" if outcome.kept else ""
            # Why it ended no_frontier, from its row: that of an episode run now, or the npz's of one --resume kept
            # (none in the rows of runs before the column).
            why = f": {r['ended_why']}" if r.get("ended_why") else ""
            text = escape(f"{outcome.method} {outcome.map}: {r['coverage_pct']:.1f}% in {r['steps']} steps ({r['terminated_by']}{kept}){why}")
        else:
            text = f"[red]{escape(f'{outcome.method} {outcome.map}')}: FAILED"
        self.done += 1
        if not outcome.kept:
            self.ran += 1
        left_s = self.time_left_s()
        left = self.UNKNOWN_TIME if left_s is None else clock_text(left_s)
        assert self.task is not None  # start() came first
        fields: dict[str, Any] = {self.TIME_LEFT_FIELD: left}
        self.progress.update(self.task, advance=1, stats=text, **fields)
        if not self.on_terminal:  # logs and CI: one line per finished episode, with the bar's times
            which = "" if self.label == "eval" else f"{escape(self.label.removeprefix('eval '))} "  # --seeds: the seed first
            self.progress.console.print(f"{which}{escape(f'[{self.done}/{self.total}]')} {text}{self.times_text(outcome)}", highlight=False, soft_wrap=True)  # one line, however long

    def times_text(self, outcome: EpisodeOutcome) -> str:
        """`` [0:01:05 elapsed, about 0:20:10 left]`` after an episode run now: what the bar's time columns show a
        terminal, for a long eval followed in its log. Nothing after an episode ``--resume`` kept."""
        if outcome.kept:
            return ""
        left_s = self.time_left_s()
        left = f", about {clock_text(left_s)} left" if left_s else ""
        return escape(f" [{clock_text(self.clock() - self.started_s)} elapsed{left}]")

    def time_left_s(self) -> float | None:
        """``time_left_s`` now: the bar's and the log lines' time left, at the pace of the episodes run now."""
        return time_left_s(self.clock() - self.started_s, self.ran, self.total - self.done)

    def writing(self, out: Path, trajectory_plots: int, pooled_seeds: int = 0) -> None:
        """After the episodes: the bar says what is being written (and a log gets the same line); ``pooled_seeds``:
        ``--seeds``' files of that many seeds pooled, which have no trajectory plot (each seed's folder has its own)."""
        self.writing_to = out
        plots = f"curves and {trajectory_plots} trajectory plot{'' if trajectory_plots == 1 else 's'}"
        text = escape(f"writing {out}/: summary.json, episodes.csv, {f'curves of the {pooled_seeds} seeds pooled' if pooled_seeds else plots}")
        assert self.task is not None  # start() came first
        self.progress.update(self.task, stats=text)
        if not self.on_terminal:
            self.progress.console.print(text, highlight=False, soft_wrap=True)

    def stop(self) -> None:
        self.progress.stop()


def print_summary(summary: dict[str, Any], out_dir: Path) -> None:
    """``eval``'s results on the terminal: Table 1, Table 2 when the run has ablations, the paired comparison with the
    baseline (or why there is none), the failed episodes, and where the files are."""
    from rich.measure import Measurement  # noqa: PLC0415
    from rich.table import Table  # noqa: PLC0415

    def table1(spread: bool) -> Table:
        table = Table(title=escape(f"Table 1 metrics ({out_dir}/summary.json)"), caption=SPREAD_NOTE if spread else MEANS_NOTE)  # a [name] in the path is not markup
        table.add_column("method", no_wrap=True)  # method names are what a reader looks for: never cut
        table.add_column("scale", no_wrap=True)
        for col in TABLE1_COLUMNS[2:]:
            table.add_column(col, justify="right")
        for method, scale, e in table1_rows(summary):  # as the paper's Table 1: one block per scale
            table.add_row(method, scale, *table1_cells(e, spread))
        return table

    console = table_console()
    table = table1(spread=True)
    fit_off_a_terminal(console, table)  # a file, a pipe: as wide as the spreads need, so they are kept there
    if Measurement.get(console, console.options.update_width(10**6), table).maximum > console.width:  # "0.5768 ±" over "0.0425" is unreadable: means alone
        table = table1(spread=False)
    print_table_or_rows(console, table, labels=2)
    if shows_ablations(summary):
        header, rows = table2(summary)
        ablations = Table(title="Table 2: m2/step (per-scene change against the baseline)")
        for col in header:
            ablations.add_column(col, no_wrap=True, justify="left" if col == "method" else "right")
        for cells in rows:
            ablations.add_row(*cells)
        print_table_or_rows(console, ablations, labels=1)
    paired = summary.get("paired") or {}
    if paired.get("comparisons"):
        against = Table(title=escape(f"Against {paired['baseline']}, scene by scene ({out_dir}/paired.csv)"))
        for col in PAIRED_COLUMNS:
            against.add_column(col, no_wrap=col in ("method", "scale"), justify="left" if col in ("method", "scale") else "right")
        for c in paired["comparisons"]:
            against.add_row(*paired_cells(c))
        print_table_or_rows(console, against, labels=2)
    elif paired.get("baseline") in summary["methods"] and len(summary["methods"]) > 1:  # say why there is no comparison
        console.print(escape(f"no comparison with {paired['baseline']} scene by scene (paired.csv): no other method shares "
                             f"{TOO_FEW_SCENES} with it"), soft_wrap=True, highlight=False)
    elif paired.get("baseline") and len(summary["methods"]) > 1:  # `--method cso,utility`, `--baseline X` of a method not run
        console.print(escape(f"no comparison scene by scene (paired.csv): its baseline {paired['baseline']} did not run; add it to --method, "
                             f"or give --baseline one of {', '.join(summary['methods'])}"), soft_wrap=True, highlight=False)
    for f in summary["failures"]:
        console.print(f"[red]failed[/red] {escape(failure_said(f))}", soft_wrap=True)  # a path in it must stay whole; --seeds: its seed
    console.print(escape(closing_said(summary, out_dir)), soft_wrap=True, highlight=False)


def print_table_or_rows(console: Any, table: Any, labels: int) -> None:
    """``table`` on ``console`` where its columns fit; on a terminal too narrow for them (Table 1's nine columns on 80
    characters), rich would cut its cells to "…" (an m2/step of ``3.3…``): then its title, one line per row (its first
    ``labels`` cells, then each value after its column's name), and its caption, wrapped, every number whole."""
    import io  # noqa: PLC0415

    from rich.console import Console  # noqa: PLC0415
    from rich.text import Text  # noqa: PLC0415

    fit_off_a_terminal(console, table)  # a file, a pipe: the whole table, each cell on its line
    laid_out = io.StringIO()
    Console(file=laid_out, width=console.width, color_system=None).print(table)  # as it would be there: rich's own ellipsis
    if "…" not in laid_out.getvalue():
        console.print(table)
        return
    if table.title:
        console.print(table.title, soft_wrap=True, highlight=False)
    headers = [Text.from_markup(str(c.header)).plain for c in table.columns]
    for cells in zip(*(list(c.cells) for c in table.columns)):
        plain = [Text.from_markup(cell).plain if isinstance(cell, str) else str(cell) for cell in cells]
        said = ", ".join(f"{name} {value}" for name, value in zip(headers[labels:], plain[labels:]))
        console.print(escape(f"{' '.join(plain[:labels])}: {said}"), soft_wrap=True, highlight=False)
    if table.caption:
        console.print(table.caption, soft_wrap=True, highlight=False)


def closing_said(summary: dict[str, Any], out_dir: Path) -> str:
    """``eval``'s last line: where the results are (``results_said``); where no episode finished, that no metric and no
    figure was written (all failed: the report and summary.json list the failures)."""
    if any(entry.get("episodes") for entry in summary["methods"].values()):
        return results_said(out_dir)
    failed = len(summary["failures"])
    if failed:
        return (f"{'all ' if failed > 1 else 'the '}{failed} episode{'s' if failed > 1 else ''} failed (above): no metrics and no figures; "
                f"{out_dir}/report.html and summary.json list the failures, episodes.csv holds no row")  # fmt: skip
    return f"no episode finished: no metrics and no figures in {out_dir}/"


def episodes_held(plan: EvalPlan, out_dir: Path) -> int:
    """How many of ``plan``'s episodes ``out_dir`` holds: one meaning of "holding", with or without ``--resume``, the
    episodes ``--resume`` keeps (whole, same settings and plan, with their own GIF under ``--animate``), not every
    episode file (a cut one, one ``--animate`` runs again). ``--dry-run`` and an eval's first line in a log say it."""
    return sum(load_finished(job) is not None for job in plan.jobs) if Path(out_dir).is_dir() else 0


def eval_start_said(request: EvalRequest, plan: EvalPlan) -> str:
    """The first line of an eval written to a log (no terminal, no bar): what runs and where its results go; with
    ``--resume``, how many of its episodes are kept from the earlier run and how many run now."""

    def count(n: int, what: str) -> str:
        return f"{n} {what}{'' if n == 1 else 's'}"

    sensor = f"{request.sensor} {plan.config.sensor.fov_deg:g} degrees"
    seeds = f" x {count(len(request.seeds), 'seed')} ({', '.join(map(str, request.seeds))})" if request.seeds else ""
    held = episodes_held(plan, Path(request.out_dir)) if request.resume else 0
    kept = f" ({held} kept from the earlier run, {len(plan.jobs) - held} to run)" if held else ""
    return (
        f"eval: {count(len(plan.jobs), 'episode')}{kept}, {count(len(request.methods), 'method')} ({', '.join(request.methods)}) "
        f"x {count(len(plan.scenes), 'scene')} ({request.maps}){seeds}, {sensor}, sim {request.sim}, {count(request.workers, 'worker')}; "
        f"results in {request.out_dir}/"
    )


def run_eval_cli(request: EvalRequest, dry_run: bool = False, resolved: bool = False) -> int:
    """CLI entry: clear errors for bad arguments, exit code 0 when every episode ran. ``dry_run``: check and say what
    would run, run and write nothing (exit 1 where a scene would fail to load, as its episodes would); ``resolved``: the
    same save the ``--out`` folder, which only ``dry_run`` checks (as ``up --resolved``: the configuration to run later,
    elsewhere), and print the exploration configuration (``meta.config``) as YAML that ``--config`` takes back."""
    out_checked = dry_run or not resolved
    try:
        plan = plan_eval(request, out_checked)  # also refuses an --out of another configuration's episodes, before any runs
        if dry_run:
            check_output_dir(request.out_dir)
        elif not resolved:
            make_output_dir(request.out_dir)
    except (ConfigError, SceneError, ValueError) as exc:
        from rich.console import Console  # noqa: PLC0415

        Console(stderr=True).print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)  # brackets are text; paths unbroken
        return 2
    except KeyboardInterrupt:  # the first seconds: every plan loaded and checked, --out compared with this configuration
        print("interrupted before any episode ran, while checking the plans; nothing written")
        return EXIT_INTERRUPTED
    if dry_run or resolved:
        lines, unloadable = plan_said(request, plan, out_checked)
        for warning in plan.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        for failure in unloadable:
            print(f"error: scene {failure}", file=sys.stderr)
        if resolved:
            lines += [
                "the exploration configuration the episodes would run with, defaults filled in (summary.json's meta.config):",
                "give it back with --config FILE and the same --sensor, --lidar-fov and --sim",
            ]
            print(commented_yaml(lines, to_dict(plan.config)), end="")
        else:
            print("\n".join(lines))
        return 1 if unloadable else 0
    progress = RichProgress()
    out = Path(request.out_dir)
    if not progress.on_terminal:  # a log: what runs, before the first episode's line (minutes, on a large plan)
        progress.progress.console.print(escape(eval_start_said(request, plan)), highlight=False, soft_wrap=True)
    try:
        summary = run_eval(request, progress, plan)
    except ConfigError as exc:  # another eval writes the folder
        progress.stop()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # not during the episodes (run_eval writes what finished): before them, or while writing it
        progress.stop()
        if progress.writing_to is not None:  # with --seeds, the folder of the seed being written, or --out's pooled files
            print(f"interrupted while writing the results in {progress.writing_to}/ (report.html and the figures may be missing); the episodes that "
                  "finished are kept: the same command with --resume writes them (and runs any episode left)")
        else:
            print(f"interrupted before any episode ran; the same command with --resume runs them, keeping the episodes {out}/ holds")
        return EXIT_INTERRUPTED
    finally:
        progress.stop()
    print_summary(summary, Path(request.out_dir))
    stopped = summary["meta"].get("interrupted")
    if stopped:
        print(f"interrupted: {stopped['episodes_finished']} of {stopped['episodes_planned']} episodes finished; the same command with --resume runs the rest")
        return EXIT_INTERRUPTED
    return 1 if summary["failures"] else 0
