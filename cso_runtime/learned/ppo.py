"""PPO for the CSO goal policy, in one readable file (CleanRL's ``ppo.py`` layout).

One env step is one goal choice (``env.ExplorationEnv``). The pieces, in order:
``Args`` (the one config, filled by ``configs/train.yaml`` and the CLI), scene loading, ``compute_gae``
(unit-tested), an optional warm start that imitates a greedy baseline (greedy-dist by default) under the same masks
(behaviour cloning of the actor plus a Monte-Carlo fit of the critic), then the PPO loop with the
action mask stored in the rollout and reused when log-probs are recomputed. Checkpoints (with the
optimizer, to resume), a CSV log, a learning-curve PNG and the final weights plus a JSON record of
the run go to ``out_dir``.
"""

from __future__ import annotations

import collections
import csv
import dataclasses
import functools
import json
import os
import random
import shlex
import shutil
import time
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode
from torch import nn, optim

from cso_runtime.config import (
    LIDAR_FOVS_DEG,
    LIDAR_FOVS_SAID,
    MAX_DONE_UNEXPLORED_M2,
    MAX_EPISODE_STEPS,
    MAX_PROCESSES,
    Bound,
    ConfigError,
    ExplorationConfig,
    FrontierConfig,
    MaskConfig,
    SensorConfig,
    check_bounds,
    check_seed,
    check_torch_device,
    frontier_bounds,
    map_length,
    setting_text,
)
from cso_runtime.current_run import folder_lock
from cso_runtime.doctor import cpu_name
from cso_runtime.learned.env import (
    ROBOT_INDEX_SHAPE,
    TEACHERS,
    EnvConfig,
    ExplorationEnv,
    RewardConfig,
    mask_config_for,
    observation_layout,
)
from cso_runtime.learned.graph import GraphConfig, node_features
from cso_runtime.learned.network import GraphActorCritic, NetworkConfig
from cso_runtime.learned.registry import (
    TRAINED_FRONTIER_BEFORE_RECORD,
    VARIANTS,
    CheckpointError,
    device_problem,
    load_checkpoint,
    save_checkpoint,
    save_whole,
    weights_path,
)
from cso_runtime.learned.vector_env import EnvWorkerDied, WatchedAsyncVectorEnv
from cso_runtime.learned.weights import mask_set_flags, mask_settings_changed, trained_mask_settings
from cso_runtime.outputs import file_sha256, remove_partial_files, write_npz_whole, write_text_atomic, write_whole
from cso_runtime.plots import pyplot
from cso_runtime.processes import WorkerDied, run_each_in_own_process
from cso_runtime.provenance import software_provenance
from cso_runtime.scenes import M_PER_PX_BOUND, FloorPlan, SceneRef, resolve_scenes

MAX_TRAINING_TIME_S = 30 * 86_400.0
"""The longest ``time_limit_s`` (30 days; 0 = none): a longer one is a value in another unit."""
MAX_ENVS = MAX_PROCESSES
"""The most environments (``num_envs``) and torch threads (``torch_threads``) a run may have (``config.MAX_PROCESSES``):
each environment is a process with ``async_envs``."""
MAX_NETWORK_WIDTH = 4096
"""The widest network (``hidden``; ``heads`` divide it): 128 times the shipped one's 32; wider allocates gigabytes per layer."""
MAX_GRAPH_NODES = 10_000
"""The most frontier or path nodes of a graph (``max_frontier_nodes``, ``max_path_nodes``): the attention over them is
quadratic, 10,000 nodes already 400 MB a head."""

MAX_TOTAL_DECISIONS = 10**10
"""The largest PPO budget (``total_decisions``, ``warm_start_decisions``): ten billion decisions, far beyond
``MAX_TRAINING_TIME_S`` at the pace docs/experiments/learned-policy.md reports (981 decisions in 517 s in one of its runs)."""
MAX_EPOCHS = 1000
"""The most passes over one rollout (``update_epochs``) or over the teacher data (``warm_start_epochs``)."""
MAX_LEARNING_RATE = 1.0
"""The largest learning rate (``learning_rate``, ``warm_start_lr``): Adam moves each weight by about this much a step."""
MAX_LR_SCALE = 1000.0
"""The largest ``encoder_lr_scale``: the encoder's learning rate at most this multiple of the heads'."""
MAX_LOSS_WEIGHT = 1000.0
"""The largest weight of a term of the losses or of the rewards (``ent_coef``, ``vf_coef``, ``distance_prior``,
``lambda_c``, ``-r_step``) and the largest ``max_grad_norm`` and ``target_kl``: the recipe's are at most 4."""
MAX_CHECKPOINT_EVERY = 1_000_000
"""The most updates between checkpoints (``checkpoint_every``)."""
MAX_TRAINING_PLANS = 100_000
"""The most Dungeon plans a run draws (``dungeon_plans``): more than a data set holds (a folder of fewer gives all it has)."""

ARGS_BOUNDS: dict[str, Bound] = {
    "dungeon_plans": Bound(0, MAX_TRAINING_PLANS, why="MAX_TRAINING_PLANS"),
    "total_decisions": Bound(1, MAX_TOTAL_DECISIONS, why="MAX_TOTAL_DECISIONS"),
    "time_limit_s": Bound(0.0, MAX_TRAINING_TIME_S, "s", why="30 days: MAX_TRAINING_TIME_S"),
    "num_envs": Bound(1, MAX_ENVS, why="MAX_ENVS"),
    "num_steps": Bound(1, MAX_EPISODE_STEPS, why="config.MAX_EPISODE_STEPS"),
    "learning_rate": Bound(0.0, MAX_LEARNING_RATE, why="MAX_LEARNING_RATE"),
    "adam_eps": Bound(0.0, 1.0, low_open=True),
    "encoder_lr_scale": Bound(0.0, MAX_LR_SCALE, low_open=True, why="MAX_LR_SCALE"),
    "gamma": Bound(0.0, 1.0, low_open=True),
    "gamma_per_step": Bound(0.0, 1.0, high_open=True, why="0: gamma per decision"),
    "gae_lambda": Bound(0.0, 1.0),
    "num_minibatches": Bound(1, MAX_ENVS * MAX_EPISODE_STEPS, why="the largest rollout: MAX_ENVS x config.MAX_EPISODE_STEPS"),
    "update_epochs": Bound(1, MAX_EPOCHS, why="MAX_EPOCHS"),
    "clip_coef": Bound(0.0, 1.0, low_open=True, high_open=True, why="PPO clips the ratio to [1 - clip_coef, 1 + clip_coef]"),
    "ent_coef": Bound(0.0, MAX_LOSS_WEIGHT, why="MAX_LOSS_WEIGHT"),
    "vf_coef": Bound(0.0, MAX_LOSS_WEIGHT, why="MAX_LOSS_WEIGHT"),
    "max_grad_norm": Bound(0.0, MAX_LOSS_WEIGHT, low_open=True, why="MAX_LOSS_WEIGHT"),
    "target_kl": Bound(0.0, MAX_LOSS_WEIGHT, why="0 = never; MAX_LOSS_WEIGHT"),
    "warm_start_decisions": Bound(0, MAX_TOTAL_DECISIONS, why="0 = no warm start; MAX_TOTAL_DECISIONS"),
    "warm_start_soft_steps": Bound(0.0, MAX_EPISODE_STEPS, "steps", why="0 = imitate the choice alone; the longest episode: config.MAX_EPISODE_STEPS"),
    "warm_start_epochs": Bound(0, MAX_EPOCHS, why="MAX_EPOCHS"),
    "warm_start_lr": Bound(0.0, MAX_LEARNING_RATE, why="MAX_LEARNING_RATE"),
    "r_step": Bound(-MAX_LOSS_WEIGHT, 0.0, why="Eq. 6's step penalty; 0: the new area alone"),
    "lambda_c": Bound(0.0, MAX_LOSS_WEIGHT, low_open=True, why="Eq. 6's reward per m2 of new open area; MAX_LOSS_WEIGHT"),
    "reward_scene_scale_area_m2": Bound(0.0, MAX_DONE_UNEXPLORED_M2, "m2", why="0 = Eq. 6 unscaled; a square kilometre: config.MAX_DONE_UNEXPLORED_M2"),
    "max_steps": Bound(1, MAX_EPISODE_STEPS, why="as eval's episode.max_steps: config.MAX_EPISODE_STEPS"),
    "hidden": Bound(1, MAX_NETWORK_WIDTH, why="MAX_NETWORK_WIDTH"),
    "heads": Bound(1, MAX_NETWORK_WIDTH, why="at most hidden: MAX_NETWORK_WIDTH"),
    "layers": Bound(0, 64),
    "knn": Bound(1, 2 * MAX_GRAPH_NODES - 1, why="the nodes besides the robot's of the largest graph: 2 x MAX_GRAPH_NODES - 1"),
    "max_frontier_nodes": Bound(1, MAX_GRAPH_NODES, why="MAX_GRAPH_NODES"),
    "max_path_nodes": Bound(1, MAX_GRAPH_NODES, why="MAX_GRAPH_NODES"),
    "distance_scale_m": map_length(low_open=True),
    "entropy_window_m": frontier_bounds()["entropy_window_m"],
    "distance_prior": Bound(0.0, MAX_LOSS_WEIGHT, why="0 = the paper's actor; MAX_LOSS_WEIGHT"),
    "checkpoint_every": Bound(1, MAX_CHECKPOINT_EVERY, why="MAX_CHECKPOINT_EVERY"),
    "torch_threads": Bound(1, MAX_ENVS, why="MAX_ENVS"),
}
"""``Args``' bounds: every number of a run (its processes, its network, its graphs, its episodes, its optimiser, its
rewards), each checked before anything starts (``config.check_bounds``), first of ``validate``'s checks. Beside them
``seed`` is ``config.check_seed``'s, ``beta_far_m`` the masks' (``masks.beta_far_m``), each of ``dungeon_m_per_px``
``scenes.M_PER_PX_BOUND``'s, ``num_minibatches`` divides ``num_envs`` x ``num_steps``, ``heads`` divides ``hidden`` and
``knn`` is at most ``max_frontier_nodes + max_path_nodes - 1``."""


@dataclass
class Args:
    """Training run configuration. The shipped weights' recipe is ``configs/train.yaml`` (``cso-runtime train``
    reads it), not these defaults: they are a short run of the plain actor (no distance prior, no cluster-length
    feature, 4096 decisions, generated plans only) for tests and for ``Args(...)`` in a notebook."""

    variant: str = "cso"
    """Which learned method to train (sets the entropy input and masks): cso, cso-no-info, ..."""
    seed: int = 1
    """Seeds python, numpy, torch and the environments."""
    out_dir: str = "runs/train"
    """Where checkpoints, the CSV log, the PNG curve and the final weights go."""
    dungeon_dir: str | None = None
    """Folder of Dungeon training PNGs (never a validation set); None to train on generated plans only."""
    dungeon_m_per_px: list[float] = field(default_factory=lambda: [0.1, 0.05])
    """Each chosen Dungeon plan is loaded at each of these scales (0.1 super large, 0.05 large)."""
    dungeon_plans: int = 40
    """How many Dungeon plans to draw (seeded) from ``dungeon_dir``."""
    generated: list[str] = field(default_factory=lambda: ["generated:small:20:1000", "generated:middle:20:2000"])
    """Generated-plan specs (``generated:SCALE:N:SEED``, any scale class; keep their seeds apart from evaluation's)."""
    total_decisions: int = 4096
    """PPO budget in env decisions (goal choices), all envs together."""
    time_limit_s: float = 0.0
    """Stop after the update that crosses this wall time (0 = no limit)."""
    num_envs: int = 2
    """Parallel environments."""
    async_envs: bool = False
    """Run the environments in subprocesses (AsyncVectorEnv) instead of in this process."""
    num_steps: int = 64
    """Decisions per environment per rollout."""
    learning_rate: float = 1e-4
    """Adam's learning rate of the PPO updates (the actor and critic heads; ``encoder_lr_scale`` scales the encoder's)."""
    adam_eps: float = 1e-5
    """Adam's epsilon (CleanRL's 1e-5). In the first updates the actor's hidden layer gets gradients of a few
    1e-6 (under the distance prior its output layer starts at zero), where 1e-5 shrinks Adam's step; 1e-8 was
    tried and trained no better (docs/experiments/learned-policy.md, "Adam's epsilon")."""
    encoder_lr_scale: float = 1.0
    """The graph encoder's learning rate (node and edge layers, attention rounds) as a multiple of
    ``learning_rate``; the actor and critic heads keep ``learning_rate``. Within the recipe's budget the encoder
    stays near its initial weights (docs/experiments/learned-policy.md, "Edges in the messages, no messages at all")."""
    anneal_lr: bool = True
    """The learning rate falls linearly to 0 over the PPO updates (CleanRL's)."""
    gamma: float = 0.98
    """Discount per decision (unless ``gamma_per_step`` is set)."""
    gamma_per_step: float = 0.0
    """> 0: discount per control step instead, so a decision that took k control steps is discounted
    ``gamma_per_step ** k`` (the semi-MDP discount: a long trip defers what follows by its length, as the
    efficiency metric counts steps, not decisions). 0: ``gamma`` per decision. PPO only: the warm start's
    critic targets (teacher data, also saved to files) keep ``gamma`` per decision."""
    gae_lambda: float = 0.95
    """lambda of generalised advantage estimation (GAE), in [0, 1]."""
    num_minibatches: int = 4
    """Minibatches per epoch of an update: must divide ``num_envs`` x ``num_steps``."""
    update_epochs: int = 4
    """Passes over each rollout per PPO update."""
    norm_adv: bool = True
    """Advantages normalised per minibatch."""
    clip_coef: float = 0.1
    """PPO clips the probability ratio to [1 - clip_coef, 1 + clip_coef]: in (0, 1)."""
    clip_vloss: bool = True
    """The value loss clipped around the rollout's values, as the policy's ratio is."""
    ent_coef: float = 0.005
    """Weight of the entropy bonus (over the valid actions) in the PPO loss."""
    vf_coef: float = 0.5
    """Weight of the value loss in the PPO loss."""
    max_grad_norm: float = 0.5
    """Gradients clipped to this global norm."""
    target_kl: float = 0.03
    """Stop the epoch loop early when the approximate KL exceeds this (0 = never)."""
    warm_start_decisions: int = 0
    """Teacher decisions (``warm_start_teacher`` under the masks) to imitate before PPO (0 = no warm start)."""
    warm_start_teacher: str = "greedy-dist"
    """What the warm start imitates under the variant's masks: greedy-dist, utility or greedy-info (their
    scores), or rollout (greedy-dist's best continuation among the nearest allowed clusters, found by
    simulating each to the end: ``episode.rollout_choice``; tens of times slower to collect)."""
    warm_start_data: list[str] = field(default_factory=list)
    """Teacher-data files (``.npz`` from ``cso-runtime collect-teacher``, or a run's ``teacher_data.npz``) to
    imitate instead of collecting ``warm_start_decisions`` anew."""
    warm_start_soft_steps: float = 0.0
    """Temperature, in control steps, of the soft imitation targets built from the rollout teacher's outcomes
    (``soft_targets``); 0 imitates the teacher's choice alone."""
    warm_start_epochs: int = 20
    """Passes over the teacher data in the warm start."""
    warm_start_lr: float = 1e-3
    """Adam's learning rate in the warm start."""
    sensor: str = "lidar"
    """Sensor preset of the training episodes (as ``eval --sensor``): lidar or depth."""
    lidar_fov_deg: float | None = None
    """The LiDAR's field of view (as ``eval --lidar-fov``): 180 or 360 (``LIDAR_FOVS_DEG``, what eval runs); None
    keeps the preset's (the LIMO LiDAR: 180; the depth preset takes none). Train with the sensor you evaluate with:
    the tables use 360."""
    r_step: float = -0.01
    """R_step of Eq. 6 per control step: a penalty, <= 0 (0: the new area alone)."""
    lambda_c: float = 0.02
    """lambda_c of Eq. 6 per m2 of new open area (> 0)."""
    reward_scene_scale_area_m2: float = 0.0
    """> 0: each scene's rewards times this over its traversable area (``RewardConfig.scene_scale_area_m2``)."""
    max_steps: int = 800
    """Control steps per training episode (truncated after)."""
    beta_far_m: float = 2.0
    """Far bound of the valid distance mask (Eq. 5, ``masks.beta_far_m``) in the training episodes. 2.0: the
    paper's, read as metres; the shipped weights were trained with it and run with ``MaskConfig``'s 1.5, which
    did better on the development set than both 2.0 and training with 1.5 (docs/experiments/learned-policy.md,
    "The valid distance mask's far bound")."""
    stuck_avoid: str = "positions"
    """What the stuck mask keeps a new goal away from in the training episodes (``masks.stuck_avoid``):
    ``positions`` (the shipped weights) or ``goals`` (Algorithm 1 read literally). Evaluate such weights with
    ``--set masks.stuck_avoid=goals``."""
    cut_observation: str = "state"
    """What PPO bootstraps a training episode cut by ``max_steps`` with (``EnvConfig.cut_observation``): V of the
    cut's real state (``state``, CleanRL's), or of the all-padding graph (``empty``), a constant: the shipped
    weights were trained so, before the review that found it (``configs/train.yaml`` keeps it to reproduce them;
    docs/experiments/learned-policy.md, "The value at the cut")."""
    mask_conflict: str = "distance"
    """``masks.conflict`` in the training episodes: which mask wins when the stuck mask leaves none of the valid
    distance mask's goals (``distance``: the shipped weights). Evaluate such weights with ``--set masks.conflict=...``."""
    hidden: int = 32
    """Node embedding width (``NetworkConfig.hidden``)."""
    heads: int = 4
    """Attention heads per layer (``NetworkConfig.heads``)."""
    layers: int = 2
    """Message-passing rounds (``NetworkConfig.layers``)."""
    knn: int = 8
    """Neighbours of each node, itself included (``GraphConfig.knn``): 1 to max_frontier_nodes + max_path_nodes - 1."""
    max_frontier_nodes: int = 200
    """Frontier clusters kept as actions, the nearest ones: the action space size (``GraphConfig.max_frontier_nodes``)."""
    max_path_nodes: int = 20
    """Past decision positions kept as path nodes, the newest ones (``GraphConfig.max_path_nodes``)."""
    cluster_size_feature: bool = False
    """Give the network each frontier cluster's length as a node feature (``graph.node_features``)."""
    unknown_area_feature: bool = False
    """Give the network the unexplored fraction around each frontier cluster (``graph.unknown_fraction``)."""
    egocentric_frame: bool = False
    """Node positions in the robot's frame instead of the map's axes (``GraphConfig.egocentric``)."""
    geodesic_edge_bound: bool = False
    """Edges between non-robot nodes as max(Euclidean, |l_i - l_j|) (``GraphConfig.geodesic_edge_bound``)."""
    distance_scale_m: float = 10.0
    """Positions and distances of the graph are divided by this (``GraphConfig.distance_scale_m``)."""
    entropy_window_m: float = 2.0
    """gamma of Eq. 4 in the training episodes (``frontier.entropy_window_m``) and the graph's entropy input
    (``GraphConfig.entropy_window_m``). The weights record it, and a run of another window refuses them
    (``registry.input_verdict``): evaluate weights trained with 4 m with ``--set frontier.entropy_window_m=4``."""
    edge_messages: bool = False
    """Edge features also enter the attention's keys and messages (``NetworkConfig.edge_messages``)."""
    distance_prior: float = 0.0
    """> 0: the actor scores a residual over greedy-dist's ``-distance_prior * log(1 + l / scale)``
    (``NetworkConfig.distance_prior``); PPO then starts from greedy-dist's choices, no warm start needed."""
    checkpoint_every: int = 5
    """Updates between resumable checkpoints."""
    keep_checkpoints: bool = False
    """Also keep the weights of every checkpoint, each in a folder of its own (``kept_checkpoint_dir``:
    ``checkpoints/update_<N>/<variant>.pt`` and its record ``<variant>.json``), which ``eval --weights`` takes as it
    takes the run's folder: the policies along the learning curve (SB3's ``CheckpointCallback``), not only the last.
    ``checkpoint.pt`` itself, what ``--resume`` goes on from, is overwritten either way."""
    tensorboard: bool = False
    """Also write each update's figures as TensorBoard events into ``out_dir/tensorboard/`` (``tensorboard
    --logdir OUT``), tagged as CleanRL tags them (``TENSORBOARD_TAGS``) over PPO decisions; needs tensorboardX
    (``pip install 'cso-runtime[tensorboard]'``). The CSV log is written either way."""
    resume: str | None = None
    """Path of a checkpoint.pt to continue from."""
    init_from: str | None = None
    """Weights file (an earlier run's ``<variant>.pt`` or ``checkpoint.pt``, or ``shipped`` for the variant's shipped
    weights) to start PPO from instead of a fresh network: fine-tuning. The warm start is skipped; the optimizer starts fresh.
    A ``resume`` reads none: with one, other weights than its run started from are refused (``init_from_with_resume_problem``)."""
    device: str = "auto"
    """auto (CUDA when available), cpu or cuda."""
    torch_threads: int = 1
    """Torch's CPU threads in the training process (``torch.set_num_threads``)."""
    progress: bool = True
    """Show a progress bar."""

    def validate(self) -> None:
        check_seed(self.seed)  # worker i uses seed + i
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown variant {self.variant!r}; known: {', '.join(VARIANTS)}")
        check_bounds("", self, ARGS_BOUNDS)
        for scale in self.dungeon_m_per_px:
            M_PER_PX_BOUND.check("dungeon_m_per_px", scale)  # as eval's --m-per-px
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ValueError(
                f"num_envs x num_steps = {self.num_envs} x {self.num_steps} = {self.batch_size} decisions per update does not divide"
                f" into {self.num_minibatches} minibatches (num_minibatches must divide num_envs x num_steps)"
            )
        check_torch_device(self.device, allow_auto=True)
        if self.warm_start_teacher not in TEACHERS:
            raise ValueError(f"unknown warm_start_teacher {self.warm_start_teacher!r}; choose one of {', '.join(TEACHERS)}")
        self.training_masks(MaskConfig()).validate()
        missing = [p for p in self.warm_start_data if not Path(p).is_file()]
        if missing:
            raise ValueError(f"warm_start_data: no such file {', '.join(missing)}")
        if self.hidden % self.heads:
            raise ValueError(f"the network needs hidden divisible by heads; got hidden {self.hidden}, heads {self.heads}")
        if self.cut_observation not in ("state", "empty"):
            raise ValueError(f"cut_observation must be state or empty, not {self.cut_observation!r}")
        others = self.max_frontier_nodes + self.max_path_nodes - 1  # a full graph's nodes besides the robot's (graph.build_graph)
        if self.knn > others:
            raise ValueError(
                f"knn must be at most max_frontier_nodes + max_path_nodes - 1 = {others}, the nodes besides the robot's that a"
                f" graph holds (each node's neighbours, itself included), got {self.knn}"
            )
        try:
            SensorConfig.preset(self.sensor, self.lidar_fov_deg)
        except ConfigError as exc:
            raise ValueError(f"sensor: {exc}") from None
        # Weights are for evaluating: train only with a sensor eval runs (eval --sensor, --lidar-fov), not one found
        # out at eval's refusal, or at its warning that the weights are run with another, after the training.
        if self.lidar_fov_deg is not None and self.sensor != "lidar":
            raise ValueError(f"lidar_fov_deg sets the LiDAR's field of view; sensor {self.sensor} has its own, as eval --sensor {self.sensor} runs it: give lidar_fov_deg null")
        if self.lidar_fov_deg is not None and float(self.lidar_fov_deg) not in LIDAR_FOVS_DEG:
            raise ValueError(f"lidar_fov_deg must be {LIDAR_FOVS_SAID} (the LiDARs eval --lidar-fov runs), or null for the preset's 180, got {self.lidar_fov_deg:g}")

    def training_masks(self, masks: MaskConfig) -> MaskConfig:
        """``masks`` with the training episodes' far bound (``beta_far_m``) and stuck reference (``stuck_avoid``),
        before the variant switches masks off."""
        return dataclasses.replace(masks, beta_far_m=self.beta_far_m, stuck_avoid=self.stuck_avoid, conflict=self.mask_conflict)

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return max(1, self.total_decisions // self.batch_size)

    def env_config(self) -> EnvConfig:
        v = VARIANTS[self.variant]
        exploration = ExplorationConfig()
        exploration.sensor = SensorConfig.preset(self.sensor, self.lidar_fov_deg)
        exploration.frontier = dataclasses.replace(exploration.frontier, entropy_window_m=self.entropy_window_m)
        exploration.masks = mask_config_for(v.use_valid_distance, v.use_stuck, self.training_masks(exploration.masks))
        graph = GraphConfig(
            self.max_frontier_nodes,
            self.max_path_nodes,
            self.knn,
            distance_scale_m=self.distance_scale_m,
            use_entropy=v.use_entropy,
            entropy_window_m=exploration.frontier.entropy_window_m,
            use_cluster_size=self.cluster_size_feature,
            use_unknown_area=self.unknown_area_feature,
            egocentric=self.egocentric_frame,
            geodesic_edge_bound=self.geodesic_edge_bound,
        )
        return EnvConfig(exploration, graph, RewardConfig(self.r_step, self.lambda_c, self.reward_scene_scale_area_m2), self.max_steps, cut_observation=self.cut_observation)


# --- scenes -----------------------------------------------------------------------------------


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and ``noun``, in the plural unless ``n`` is 1 (``plural``, else ``noun`` + s): the log's counts, "1 scene",
    "2 processes"."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def training_scene_refs(args: Args) -> list[SceneRef]:
    """Dungeon training plans (a seeded subset, at each scale) and generated plans."""
    refs: list[SceneRef] = []
    if args.dungeon_dir:
        folder = Path(args.dungeon_dir)
        if not folder.is_dir():  # the file's default folder exists on the build machine only
            raise ValueError(f"dungeon_dir {folder}: no such folder of Dungeon training plans; give --dungeon-dir FOLDER, "
                             "or --set dungeon_dir=null to train on the generated plans alone (any scale: "
                             "--set 'generated=[generated:large:40:3000,generated:super_large:40:4000]')")
        lowered = str(folder.resolve()).lower()
        if any(f"/{bad}" in lowered for bad in ("easy", "medium", "complex")):
            raise ValueError(f"{folder} looks like a validation set; train only on the training plans")
        base = resolve_scenes(str(folder))
        rng = random.Random(args.seed)
        chosen = rng.sample(base, min(args.dungeon_plans, len(base)))
        for r in chosen:
            for m in args.dungeon_m_per_px:
                refs.append(SceneRef(f"{r.name}@{m}", path=r.path, resolution_m=m))
    for spec in args.generated:
        refs.extend(resolve_scenes(spec))
    if not refs:
        raise ValueError("no training scenes: set dungeon_dir and/or generated")
    return refs


def load_plans(refs: list[SceneRef]) -> list[FloorPlan]:
    """The plans of ``refs``, each named as its ref (the name eval and the logs give the scene), loaded where it is called:
    in each environment process, not pickled to it."""
    plans = []
    for r in refs:
        p = r.load()
        p.name = r.name
        plans.append(p)
    return plans


def make_env(scenes: list[SceneRef] | list[FloorPlan], config: EnvConfig) -> Callable[[], ExplorationEnv]:
    """A picklable env factory (for AsyncVectorEnv): each process loads its own plans from refs."""
    if scenes and isinstance(scenes[0], FloorPlan):
        return functools.partial(ExplorationEnv, list(scenes), config)
    return functools.partial(ExplorationEnv, functools.partial(load_plans, typing.cast(list[SceneRef], scenes)), config)


# --- GAE --------------------------------------------------------------------------------------


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    dones: torch.Tensor,
    next_value: torch.Tensor,
    next_done: torch.Tensor,
    gamma: float | torch.Tensor,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation over a (T, E) rollout.

    ``dones[t]`` is 1 when the observation at step t starts a new episode (CleanRL's convention), so
    the bootstrap from t+1 into t is cut by ``dones[t + 1]`` (``next_done`` after the last step).
    ``gamma``: one discount for every transition, or a (T, E) tensor of each transition's own (the
    semi-MDP discount of ``Args.gamma_per_step``). Returns (advantages, returns = advantages + values).
    """
    steps = rewards.shape[0]
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(steps)):
        if t == steps - 1:
            nonterminal, nextv = 1.0 - next_done, next_value
        else:
            nonterminal, nextv = 1.0 - dones[t + 1], values[t + 1]
        discount = gamma[t] if isinstance(gamma, torch.Tensor) else gamma
        delta = rewards[t] + discount * nextv * nonterminal - values[t]
        last = delta + discount * gae_lambda * nonterminal * last
        advantages[t] = last
    return advantages, advantages + values


# --- helpers ----------------------------------------------------------------------------------


def obs_to_torch(obs: dict[str, np.ndarray], device: torch.device) -> dict[str, torch.Tensor]:
    """An observation dict's arrays as tensors on ``device``, for the network."""
    return {k: torch.as_tensor(np.asarray(v), device=device) for k, v in obs.items()}


def mask_to_torch(mask: np.ndarray, device: torch.device | str) -> torch.Tensor:
    """An action mask as the bool tensor ``CategoricalMasked`` takes: the env's ``info["action_mask"]`` is
    Gymnasium's ``np.int8`` of 0 and 1 (``torch.where`` needs bool), teacher-data files hold bool."""
    return torch.as_tensor(np.asarray(mask, dtype=bool), device=device)


def stack_obs(items: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One batched observation from several observation dicts (one per environment), key by key."""
    return {k: np.stack([it[k] for it in items]) for k in items[0]}


def index_obs(b_obs: dict[str, torch.Tensor], idx: Any) -> dict[str, torch.Tensor]:
    """The rows ``idx`` (a minibatch) of every tensor of a batched observation."""
    return {k: v[idx] for k, v in b_obs.items()}


def select_device(name: str) -> torch.device:
    """``auto`` (CUDA when there is one), ``cpu`` or ``cuda[:N]``; a CUDA device this torch cannot use is a
    ValueError that says so."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if problem := device_problem(name):
        raise ValueError(f"{problem}; train with --device cpu (or auto)")
    return torch.device(name)


RESUME_MAY_CHANGE = frozenset(
    {"out_dir", "resume", "init_from", "device", "torch_threads", "progress", "async_envs", "tensorboard", "checkpoint_every", "keep_checkpoints", "time_limit_s", "total_decisions", "dungeon_dir"}
    | {f.name for f in dataclasses.fields(Args) if f.name.startswith("warm_start_")}  # the warm start does not run again
)
"""The fields of ``Args`` a ``--resume`` may give other values than the run it continues: where and how it runs,
how long (a new ``total_decisions`` anneals the learning rate over the new total from there), the warm start (done)
and where the Dungeon plans are on this machine. Every other field is the recipe, and must be the checkpoint's."""


RESUME_OWN_FIELDS = ("out_dir", "resume", "init_from", "progress")
"""The fields of ``Args`` a ``--resume`` never takes from the checkpoint's run (``resumed_run_settings``): where it
writes (beside the checkpoint, unless ``--out``), what it continues from, and how this process shows progress."""


def resumed_run_settings(path: str | Path) -> dict[str, Any]:
    """The configuration of the run a training checkpoint continues (its ``Args``, less ``RESUME_OWN_FIELDS`` and any
    field this version lacks), what ``train --resume`` without ``--config`` starts from, so that a run trained with its
    own ``--set`` goes on without typing them again. Empty for a file that holds none (``load_resume_checkpoint`` then
    says what it is)."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001  (missing, corrupt or not a checkpoint: said when it is loaded to resume)
        return {}
    saved = ckpt.get("args") if isinstance(ckpt, dict) else None
    if not isinstance(saved, dict):
        return {}
    return {k: v for k, v in known_args(saved).items() if k not in RESUME_OWN_FIELDS}


def known_args(saved: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of ``Args`` among a checkpoint's saved ones (``dataclasses.asdict``; one of another version may hold
    fields this one lacks)."""
    names = {f.name for f in dataclasses.fields(Args)}
    return {k: v for k, v in saved.items() if k in names}


RECIPE_MACHINE_FIELDS = ("out_dir", "dungeon_dir")
"""Fields of ``configs/train.yaml`` that say where the files are on one machine, not how to train."""


def fields_left_at_defaults(given: Mapping[str, Any], recipe: Mapping[str, Any]) -> list[tuple[str, Any, Any]]:
    """``(field, Args default, recipe value)`` for each field a training configuration does not give (``given``: its
    file's fields, the flags and ``--set``) whose ``Args`` default is not the recipe's (``configs/train.yaml``): a
    file of a few fields trains ``Args``' short run of the plain actor in all the others, not the recipe."""
    defaults = dataclasses.asdict(Args())
    return [
        (name, defaults[name], value)
        for name, value in recipe.items()
        if name in defaults and name not in given and name not in RECIPE_MACHINE_FIELDS and defaults[name] != value
    ]


ARGS_BEFORE_RECORDED: dict[str, Any] = {"entropy_window_m": TRAINED_FRONTIER_BEFORE_RECORD.entropy_window_m}
"""Fields of ``Args`` whose value in a run of a version that lacked them is known (``resume_recipe_changes`` compares
them where a checkpoint's ``args`` lack them): ``entropy_window_m``, the window ``train`` built every episode with
before it was a setting (``registry.TRAINED_FRONTIER_BEFORE_RECORD``). A resume under another window would go on
training a network that learned its entropy input over that one."""


def resume_recipe_changes(saved: Mapping[str, Any], args: Args) -> list[str]:
    """``"field checkpoint_value -> this_value"`` for each recipe field whose value ``args`` changes from the
    ``saved`` run's (``dataclasses.asdict`` of its Args; a field it lacks, from an older version, is not compared,
    unless ``ARGS_BEFORE_RECORDED`` knows its value there)."""
    now = dataclasses.asdict(args)
    saved = {**ARGS_BEFORE_RECORDED, **saved}
    return [f"{k} {saved[k]!r} -> {now[k]!r}" for k in now if k not in RESUME_MAY_CHANGE and k in saved and saved[k] != now[k]]



KEPT_CHECKPOINTS_DIR = "checkpoints"
"""The folder of a run's ``--out`` that holds the weights of each checkpoint when ``keep_checkpoints`` is set."""


def kept_checkpoint_dir(out: Path, update: int) -> Path:
    """Where ``keep_checkpoints`` keeps the weights of the checkpoint after PPO update ``update`` (the CSV log's
    ``update``): ``out/checkpoints/update_<N>``, N zero-padded to 4 digits so that the folders list in update order."""
    return out / KEPT_CHECKPOINTS_DIR / f"update_{update:04d}"


TRAIN_LOCK = ".train.lock"
"""A train holds an exclusive lock on ``<out>/.train.lock`` (its pid in it) for as long as it runs: one train per
output folder, or two would write over each other's checkpoint, log and weights."""


def training_file_folders(out: Path) -> list[Path]:
    """The folders a train writes its files into (each beside itself first, ``outputs.write_whole``): ``out`` and its
    kept checkpoints' (``kept_checkpoint_dir``)."""
    return [out, *sorted(folder for folder in (out / KEPT_CHECKPOINTS_DIR).glob("update_*") if folder.is_dir())]


def training_file_names(variant: str) -> tuple[str, ...]:
    """The files a train of ``variant`` writes into its ``--out``, each whole (``outputs.write_whole``): the checkpoint,
    the teacher data of a warm start, the weights and their record, the weights after the warm start, the log, the
    curve. A kept checkpoint's folder (``kept_checkpoint_dir``) holds ``kept_checkpoint_file_names`` alone."""
    return ("checkpoint.pt", "teacher_data.npz", *kept_checkpoint_file_names(variant), f"{variant}_warm.pt", f"{variant}_log.csv", f"{variant}_curve.png")


def kept_checkpoint_file_names(variant: str) -> tuple[str, ...]:
    """The files a train of ``variant`` writes into a kept checkpoint's folder (``save_weights``): the weights and their record."""
    return (f"{variant}.pt", f"{variant}.json")


def is_a_train_file(out: Path, path: Path) -> bool:
    """Whether ``path`` is where a train (of any variant) writes one of its files in ``out`` (``training_file_names``,
    ``kept_checkpoint_file_names``): the partial files of anything else there (an eval into the same folder, a tool of
    one's own) are not train's to remove."""
    try:
        parts = Path(path).relative_to(out).parts
    except ValueError:
        return False
    if len(parts) == 1:
        return any(parts[0] in training_file_names(variant) for variant in VARIANTS)
    kept = len(parts) == 3 and parts[0] == KEPT_CHECKPOINTS_DIR and parts[1].startswith("update_")
    return kept and any(parts[2] in kept_checkpoint_file_names(variant) for variant in VARIANTS)


def remove_stale_training_files(out: Path, variant: str) -> list[Path]:
    """Remove the partial files a killed train left in ``out`` and its kept checkpoints' folders (``kill -9`` while it
    wrote its weights, checkpoint, log or curve), those of train's own files alone (``is_a_train_file``) whose writer is
    gone (``outputs.remove_partial_files``), and the temporary files of a train from before whole-file writes
    (``old_temporary_files``); the ones removed. Only while holding the folder's train lock (``TRAIN_LOCK``)."""
    folders = training_file_folders(out)
    return remove_partial_files(folders, also=old_temporary_files(folders, variant), written_for=lambda path: is_a_train_file(out, path))


def old_temporary_files(folders: list[Path], variant: str) -> list[Path]:
    """The temporary files a train killed while writing left before ``outputs.write_whole`` (which names its own
    ``.<name>.<pid>.partial``), in ``folders``: ``checkpoint.tmp`` and ``checkpoint.pt.tmp`` (the checkpoint),
    ``<variant>.pt.tmp`` (the weights), ``<variant>_log.tmp`` (the log cut back on ``--resume``) and
    ``<variant>_curve.png.tmp`` (the curve); these exact names only, nothing else of the folder."""
    names = ("checkpoint.tmp", "checkpoint.pt.tmp", f"{variant}.pt.tmp", f"{variant}_log.tmp", f"{variant}_curve.png.tmp")
    return [folder / name for folder in folders for name in names if (folder / name).is_file()]


def earlier_run_files(out: Path, variant: str) -> list[str]:
    """The files of an earlier training run of ``variant`` in ``out`` that a new run (not ``--resume``) replaces, and
    its kept checkpoints' folder (``keep_checkpoints``), whose weights of ``variant`` a new run removes
    (``drop_kept_checkpoints``)."""
    names = ("checkpoint.pt", f"{variant}.pt", f"{variant}_log.csv")
    kept = [f"{KEPT_CHECKPOINTS_DIR}/"] if any((out / KEPT_CHECKPOINTS_DIR).glob(f"update_*/{variant}.pt")) else []
    return [name for name in names if (out / name).is_file()] + kept


def earlier_run_readable_files(variant: str) -> tuple[str, ...]:
    """The files of an earlier run that a new run in its folder removes before it writes its log: what ``--resume``
    (``checkpoint.pt``, first: gone, no resume pairs it with the new log) and ``eval --weights`` (the weights and
    their record) would read, and the curve drawn from the old log. Its ``<variant>_warm.pt`` and teacher data stay:
    inputs a new run may take (``init_from``, ``warm_start_data``), of no use to a resume."""
    return ("checkpoint.pt", f"{variant}.pt", f"{variant}.json", f"{variant}_curve.png")


def drop_earlier_run(out: Path, variant: str, log: Callable[[str], None]) -> None:
    """Remove an earlier run's files of ``variant`` from ``out`` (``earlier_run_readable_files``, in that order, and
    its kept checkpoints), saying which: a new run stopped before its first checkpoint then leaves no checkpoint,
    weights or record of the old run beside its own log, only (stopped while they go) fewer of the old run's files."""
    removed = []
    for name in earlier_run_readable_files(variant):
        if (out / name).is_file():
            (out / name).unlink()
            removed.append(name)
    if removed:
        log(f"note: removed the earlier run's {', '.join(removed)} from {out}")
    if kept := drop_kept_checkpoints(out, variant):
        log(f"note: removed the earlier run's {counted(kept, 'kept checkpoint')} of {variant} from {out / KEPT_CHECKPOINTS_DIR}")


def drop_kept_checkpoints(out: Path, variant: str) -> int:
    """Remove an earlier run's kept weights of ``variant`` from ``out/checkpoints`` (and the folders left empty): left
    beside a new run's, ``eval --weights OUT/checkpoints/update_<N>`` of an update the new run has not reached would
    serve the old run's policy. Returns how many checkpoints were removed."""
    removed = 0
    for weights in sorted((out / KEPT_CHECKPOINTS_DIR).glob(f"update_*/{variant}.pt")):
        weights.unlink()
        weights.with_suffix(".json").unlink(missing_ok=True)
        removed += 1
        if not any(weights.parent.iterdir()):
            weights.parent.rmdir()
    return removed


def save_weights(folder: Path, model: GraphActorCritic, args: Args, record: dict[str, Any]) -> None:
    """``folder/<variant>.pt`` (the weights, ``registry.save_checkpoint``) and ``folder/<variant>.json`` (``record``,
    with the run's ``args``: ``eval`` reads the sensor and masks it was trained with): a folder ``eval --weights``
    serves, the run's own or a kept checkpoint's."""
    folder.mkdir(parents=True, exist_ok=True)
    env = args.env_config()
    save_checkpoint(folder / f"{args.variant}.pt", model, env.graph, args.variant, {"stage": "ppo", "decisions": record["ppo_decisions"]}, env.exploration.frontier)
    write_text_atomic(folder / f"{args.variant}.json", json.dumps(record, indent=2, default=str))  # eval --weights reads it


def run_counts(update: int, decisions: int, warm_decisions: int, env_steps: int, wall_s: float) -> dict[str, Any]:
    """The figures of a run's record (``<variant>.json``) that say how far it trained: the run's at its end, a kept
    checkpoint's at that update."""
    return {
        "ppo_updates": update,
        "ppo_decisions": decisions,
        "warm_start_decisions": warm_decisions,
        "ppo_env_steps_in_finished_episodes": env_steps,
        "wall_time_s": round(wall_s, 1),
    }


def load_resume_checkpoint(
    path: str | Path, model: GraphActorCritic, optimizer: optim.Optimizer, device: torch.device, variant: str | None = None, args: Args | None = None
) -> dict[str, Any]:
    """Load a training checkpoint (``checkpoint.pt`` of an earlier run of the same recipe) into ``model`` and
    ``optimizer``; a file that is not one, one of another network, or one of another ``variant`` (the variants'
    networks have the same shapes, their masks and inputs differ) is a ValueError that says which. With ``args``,
    so is a checkpoint whose run had another recipe (``resume_recipe_changes``): a distance prior, graph size,
    reward, discount or batch of other values loads into the same network shapes, but the run would go on as a
    different one, and its weights would be saved with this configuration."""
    if Path(path).is_dir():  # a run's folder, as `eval --weights` takes it: the file in it to give, not "corrupt"
        inside = Path(path) / "checkpoint.pt"
        held = f"give {inside}" if inside.is_file() else "it holds no checkpoint.pt; give the checkpoint.pt of a training run's --out"
        raise ValueError(f"--resume {path}: a folder; {held}")
    try:
        # On the CPU whatever the device: the RNG states must stay CPU byte tensors (torch.set_rng_state and
        # torch.cuda.set_rng_state_all refuse any other), and load_state_dict moves weights and Adam's state to the model's device.
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except FileNotFoundError:
        raise ValueError(f"--resume {path}: no such file") from None
    except Exception as exc:  # torch raises pickle, EOF and zip errors alike  # noqa: BLE001
        why = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        raise ValueError(f"--resume {path}: not a checkpoint torch can read: cut short or corrupt (a run killed while it saved?) ({why})") from None
    missing = [k for k in ("state_dict", "optimizer", "update", "decisions", "warm_decisions", "env_steps", "torch_rng") if not isinstance(ckpt, dict) or k not in ckpt]
    if missing:
        raise ValueError(f"--resume {path}: not a training checkpoint (no {', '.join(missing)}; weights to start from are --init-from)")
    if variant is not None and ckpt.get("variant", variant) != variant:
        raise ValueError(f"--resume {path}: a checkpoint of {ckpt['variant']}, not of {variant} (give --variant {ckpt['variant']}, or another --out)")
    if args is not None and isinstance(ckpt.get("args"), dict) and (changed := resume_recipe_changes(ckpt["args"], args)):
        raise ValueError(
            f"--resume {path}: this configuration changes the recipe of the run it continues ({', '.join(changed)}); resume with"
            " the checkpoint's values (the same --config and --set), or start a new run in another --out"
        )
    try:
        model.load_state_dict(ckpt["state_dict"])
        optimizer.load_state_dict(ckpt["optimizer"])
    except (RuntimeError, ValueError, KeyError) as exc:
        raise ValueError(f"--resume {path}: made with another network or optimiser than this configuration ({str(exc).splitlines()[0]})") from None
    return ckpt


def check_training_inputs(args: Args) -> None:
    """Everything ``train`` reads besides the scenes, checked before any environment starts: the device, the
    checkpoint to resume, the weights to start from and the teacher data (raises ValueError)."""
    device = select_device(args.device)
    if args.resume:
        model = build_model(args, device)
        load_resume_checkpoint(args.resume, model, optim.Adam(parameter_groups(model, args), lr=args.learning_rate), device, args.variant, args)
    elif args.init_from:
        initial_weights(args, device)
    elif args.warm_start_data:
        data = TeacherData.load(args.warm_start_data)
        expected = observation_layout(args.env_config().graph)
        wrong = sorted(k for k, v in expected.items() if k not in data.graphs or data.graphs[k].shape[1:] != np.shape(v))
        if wrong or data.masks.shape[1:] != (args.max_frontier_nodes,):
            raise ValueError(f"warm_start_data: collected with another graph layout than this configuration ({', '.join(wrong) or 'action mask'}); collect it again")


def seed_everything(seed: int) -> None:
    """Seed Python's, numpy's and torch's global generators, so a training run's random draws follow from ``--seed``."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


ARGS_OF_GRAPH_FIELDS = {"use_cluster_size": "cluster_size_feature", "use_unknown_area": "unknown_area_feature", "egocentric": "egocentric_frame"}
"""``GraphConfig`` fields that ``Args`` names otherwise; the others, and ``NetworkConfig``'s, have the same names."""


def network_changes(weights: tuple[NetworkConfig, GraphConfig], args: Args, device: torch.device) -> list[tuple[str, Any, Any]]:
    """``(field, weights_value, args_value)`` for each network or graph setting in which ``weights`` (a checkpoint's
    network and graph) differ from what ``args`` builds, by ``Args``' name and in its order where it has one
    (``node_features``, the input width, only where no graph setting explains it)."""
    saved = {**dataclasses.asdict(weights[1]), **dataclasses.asdict(weights[0])}
    wanted = {**dataclasses.asdict(args.env_config().graph), **dataclasses.asdict(build_model(args, device).config)}
    changes = [(ARGS_OF_GRAPH_FIELDS.get(k, k), saved[k], wanted[k]) for k in wanted if k in saved and saved[k] != wanted[k]]
    if len(changes) > 1:
        changes = [c for c in changes if c[0] != "node_features"]
    order = [f.name for f in dataclasses.fields(Args)]
    return sorted(changes, key=lambda c: order.index(c[0]) if c[0] in order else len(order))


def training_checkpoint_weights(path: Path, device: torch.device) -> tuple[GraphActorCritic, GraphConfig, dict[str, Any]] | None:
    """The network of a training checkpoint (``checkpoint.pt``: weights, Adam's state and the run's ``Args``), as
    ``load_checkpoint`` gives a weights file's; None for a file that is not one."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001  (not a training checkpoint: load_checkpoint's error says what it is)
        return None
    if not isinstance(ckpt, dict) or not {"state_dict", "optimizer", "args"} <= ckpt.keys() or not isinstance(ckpt["args"], dict):
        return None
    run = Args(**known_args(ckpt["args"]))
    model = build_model(run, device)
    try:
        model.load_state_dict(ckpt["state_dict"])
    except (RuntimeError, KeyError):
        return None
    return model.eval(), run.env_config().graph, ckpt


def init_from_path(args: Args) -> Path:
    """The file ``args.init_from`` names: ``shipped`` is the variant's weights for the training sensor
    (``cso.pt``, or ``cso@fov180.pt`` with the 180-degree LiDAR), anything else a path."""
    return weights_path(args.variant, args.env_config().exploration.sensor) if args.init_from == "shipped" else Path(str(args.init_from))


def initial_weights(args: Args, device: torch.device) -> dict[str, torch.Tensor]:
    """The state dict named by ``args.init_from`` (a weights file, or a training checkpoint: a stopped run's
    ``checkpoint.pt``), checked against the variant, graph and network being trained."""
    path = init_from_path(args)
    try:
        model, graph, ckpt = load_checkpoint(path, str(device))
    except FileNotFoundError:
        raise ValueError(f"--init-from {path}: no such file") from None
    except CheckpointError as exc:
        loaded = training_checkpoint_weights(path, device)
        if loaded is None:
            raise ValueError(f"--init-from {exc}") from None
        model, graph, ckpt = loaded
    if ckpt.get("variant") != args.variant:
        raise ValueError(f"{path} holds variant {ckpt.get('variant')!r}, not {args.variant!r}")
    if changes := network_changes((model.config, graph), args, device):
        said = ", ".join(f"{name} {before!r} -> {now!r}" for name, before, now in changes)
        fits = " ".join(f"--set {name}={json.dumps(before)}" for name, before, _ in changes if name in {f.name for f in dataclasses.fields(Args)})
        raise ValueError(f"{path} was trained with another graph or network configuration ({said})" + (f"; {fits} fits them" if fits else ""))
    return model.state_dict()


def parameter_groups(model: GraphActorCritic, args: Args) -> list[dict[str, Any]]:
    """Adam's parameter groups: the heads at ``learning_rate`` first (the CSV log's ``lr``), then the graph
    encoder at ``encoder_lr_scale`` times it; one group when the scale is 1 (checkpoints of either kind resume)."""
    if args.encoder_lr_scale == 1.0:
        return [{"params": list(model.parameters()), "lr_scale": 1.0}]
    encoder = [p for part in (model.node_in, model.edge_mlp, model.layers) for p in part.parameters()]
    ids = {id(p) for p in encoder}
    heads = [p for p in model.parameters() if id(p) not in ids]
    return [{"params": heads, "lr_scale": 1.0}, {"params": encoder, "lr": args.learning_rate * args.encoder_lr_scale, "lr_scale": args.encoder_lr_scale}]


def build_model(args: Args, device: torch.device) -> GraphActorCritic:
    """A fresh actor-critic for ``args``' variant (input width from its node features), on ``device``."""
    features = len(node_features(args.env_config().graph))
    config = NetworkConfig(args.hidden, 32, args.heads, args.layers, features, distance_prior=args.distance_prior, edge_messages=args.edge_messages)
    return GraphActorCritic(config, args.max_frontier_nodes).to(device)


def make_vector_env(args: Args, refs: list[SceneRef] | list[FloorPlan]) -> gym.vector.SyncVectorEnv | gym.vector.AsyncVectorEnv:
    """``args.num_envs`` training environments stepped together, in processes of their own with ``--async-envs``
    (watched: a dead one is named, not waited on); an ended episode resets in the step that ends it."""
    fns = [make_env(refs, args.env_config()) for _ in range(args.num_envs)]
    if args.async_envs:
        return WatchedAsyncVectorEnv(fns, autoreset_mode=AutoresetMode.SAME_STEP, context="spawn")
    return gym.vector.SyncVectorEnv(fns, autoreset_mode=AutoresetMode.SAME_STEP)


# --- warm start: imitate the greedy teacher ---------------------------------------------------


@dataclass
class TeacherData:
    """Teacher decisions to imitate, one row each: the graph seen, the action mask, the teacher's choice, the
    discounted return that followed (for the critic; NaN where it is not known: ``collect_teacher``) and, from the rollout teacher, each tried cluster's
    episode length in control steps (``inf`` where not tried). Saved as one compressed ``.npz``, so an
    expensive collection (``collect-teacher``) is done once and reused by several training runs."""

    graphs: dict[str, np.ndarray]
    masks: np.ndarray
    actions: np.ndarray
    returns: np.ndarray
    outcome_steps: np.ndarray

    def __post_init__(self) -> None:
        robot = self.graphs.get("robot")
        if robot is not None and robot.ndim == 1:  # collected in CSOExploration-v0's layout: one number per decision
            self.graphs = {**self.graphs, "robot": robot.reshape(-1, *ROBOT_INDEX_SHAPE)}

    def __len__(self) -> int:
        return len(self.actions)

    def save(self, path: str | Path) -> None:
        """Write the file at exactly ``path``, whole (a stopped ``collect`` or train leaves no cut file to warm-start on)."""
        arrays: dict[str, Any] = {"masks": self.masks, "actions": self.actions, "returns": self.returns}
        arrays |= {"outcome_steps": self.outcome_steps} | {f"graph_{k}": v for k, v in self.graphs.items()}
        write_npz_whole(path, arrays)

    @classmethod
    def load(cls, paths: list[str] | list[Path]) -> TeacherData:
        """Concatenate the teacher data of several files; a missing key or mismatched shape is an error."""
        parts = []
        for path in paths:
            try:
                f = np.load(path)
            except (OSError, ValueError) as exc:  # not an .npz (pickles are never loaded)
                raise ValueError(f"{path}: not a teacher-data file ({exc})") from None
            with f:
                graphs = {k.removeprefix("graph_"): f[k] for k in f.files if k.startswith("graph_")}
                try:
                    parts.append(cls(graphs, f["masks"], f["actions"], f["returns"], f["outcome_steps"]))
                except KeyError as exc:
                    raise ValueError(f"{path}: not a teacher-data file (missing {exc})") from None
        if not parts:
            raise ValueError("no teacher-data files given")
        return cls.concatenate(parts)

    @classmethod
    def concatenate(cls, parts: list[TeacherData]) -> TeacherData:
        keys = set(parts[0].graphs)
        if any(set(p.graphs) != keys for p in parts):
            raise ValueError("teacher data built with different graph layouts")
        try:
            return cls(
                {k: np.concatenate([p.graphs[k] for p in parts]) for k in sorted(keys)},
                np.concatenate([p.masks for p in parts]),
                np.concatenate([p.actions for p in parts]),
                np.concatenate([p.returns for p in parts]),
                np.concatenate([p.outcome_steps for p in parts]),
            )
        except ValueError as exc:
            raise ValueError(f"teacher data built with different graph sizes: {exc}") from None


def collect_teacher(
    envs: gym.vector.SyncVectorEnv | gym.vector.AsyncVectorEnv,
    decisions: int,
    gamma: float,
    seed: int,
    teacher: str = "greedy-dist",
    log: Callable[[str], None] | None = None,
    progress: bool = False,
    time_limit_s: float = 0.0,
    stop_requested: Callable[[], bool] | None = None,
) -> TeacherData:
    """Run the ``teacher`` (under the masks) in ``envs`` for ``decisions`` decisions, or until ``time_limit_s``
    (0 = no limit) has passed; returns what ``TeacherData`` holds, with the Monte-Carlo return of each decision
    whose episode terminated in the collection (``teacher_returns``), NaN for the others. ``log`` gets a line at every tenth of the way (the rollout teacher can take many minutes),
    ``progress`` shows a bar; ``stop_requested`` as ``train``'s."""
    graphs, masks, actions, steps, rewards, terminals, cuts = [], [], [], [], [], [], []
    obs, info = envs.reset(seed=seed)
    n = envs.num_envs
    per_env = max(1, decisions // n)
    bar = _Bar(per_env * n, "teacher decisions") if progress else None
    t0 = time.time()
    try:
        for i in range(per_env):
            raise_if_stop_requested(stop_requested)
            if time_limit_s and time.time() - t0 > time_limit_s:
                if log is not None:
                    log(f"warm start: time limit reached after {i * n} {teacher} decisions")
                break
            if log is not None and i and i % max(1, per_env // 10) == 0:
                log(f"warm start: {i * n}/{per_env * n} {teacher} decisions collected ({time.time() - t0:.0f} s)")
            labels = envs.call("teacher_label", teacher)
            chosen = np.array([a for a, _ in labels], dtype=np.int64)
            graphs.append(obs)
            masks.append(np.asarray(info["action_mask"], dtype=bool))  # the files hold bool masks
            actions.append(chosen)
            steps.append(np.stack([s for _, s in labels]))
            obs, reward, term, trunc, info = envs.step(chosen)
            rewards.append(reward)
            terminals.append(term)
            cuts.append(trunc)
            if bar is not None:
                bar.advance(n)
    finally:  # stopped too (a stop, Ctrl-C): a bar left running goes on drawing and keeps the terminal's cursor hidden
        if bar is not None:
            bar.close()
    returns = teacher_returns(np.array(rewards, dtype=np.float64), np.array(terminals, dtype=bool), np.array(cuts, dtype=bool), gamma)
    flat = {k: np.concatenate([g[k] for g in graphs]) for k in graphs[0]}
    return TeacherData(flat, np.concatenate(masks), np.concatenate(actions), returns.reshape(-1).astype(np.float32), np.concatenate(steps))


def teacher_returns(rewards: np.ndarray, terminated: np.ndarray, truncated: np.ndarray, gamma: float) -> np.ndarray:
    """The discounted return from each decision of a (T, E) collection to its episode's end, the warm start's critic
    targets: known only where the episode terminated (a finished map) within the collection. Where it was truncated
    (the step limit) or was still going when the collection stopped, what followed the cut is not in the data (PPO
    bootstraps it with V, ``_train_on``; there is no critic yet to bootstrap with here): those rows are NaN, not the
    partial sum, which would teach the critic that a cut is an end worth nothing more."""
    returns = np.full(rewards.shape, np.nan)
    running = np.zeros(rewards.shape[1:])
    known = np.zeros(rewards.shape[1:], dtype=bool)  # the collection's end: the episodes in progress are unknown
    for t in reversed(range(len(rewards))):
        ended = terminated[t] | truncated[t]
        known = np.where(ended, terminated[t], known)
        running = rewards[t] + gamma * running * (1.0 - ended)
        returns[t] = np.where(known, running, np.nan)
    return returns


def _collect_worker(job: tuple[Args, list[SceneRef], int, int, float]) -> TeacherData:
    args, refs, seed, decisions, time_limit_s = job
    torch.set_num_threads(1)
    envs = gym.vector.SyncVectorEnv([make_env(refs, args.env_config())], autoreset_mode=AutoresetMode.SAME_STEP)
    try:
        return collect_teacher(envs, decisions, args.gamma, seed, args.warm_start_teacher, time_limit_s=time_limit_s)
    finally:
        envs.close()


def collect_teacher_parallel(args: Args, workers: int, decisions: int, time_limit_s: float = 0.0, log: Callable[[str], None] = print) -> TeacherData:
    """``collect_teacher`` in ``workers`` processes, one environment each, seeds ``args.seed + i``. Unlike one
    vector env, no worker waits for the slowest (a rollout decision on a super-large plan takes many times
    one on a small plan). A worker that dies (killed, out of memory) costs only its own decisions: the
    others' are kept, and it is an error only when every worker died."""
    refs = training_scene_refs(args)
    per_worker = max(1, -(-decisions // workers))
    jobs = [(args, refs, args.seed + i, per_worker, time_limit_s) for i in range(workers)]
    log(f"collecting {args.warm_start_teacher} decisions in {counted(workers, 'process', 'processes')} on {counted(len(refs), 'scene')}")
    parts: dict[int, TeacherData] = {}

    def collected(job: tuple, part: TeacherData | WorkerDied) -> None:
        if isinstance(part, WorkerDied):
            log(f"warning: the teacher process with seed {job[2]} died (killed, or out of memory?); its decisions are lost")
        else:
            parts[job[2]] = part

    run_each_in_own_process(_collect_worker, jobs, workers, collected)
    if not parts:
        raise EnvWorkerDied(f"every one of the {workers} teacher processes died (killed, or out of memory?)")
    return TeacherData.concatenate([parts[seed] for seed in sorted(parts)])


def soft_targets(outcome_steps: torch.Tensor, actions: torch.Tensor, temperature_steps: float) -> torch.Tensor:
    """Imitation targets from the rollout's outcomes: softmax(-(steps - best) / temperature) over the tried
    clusters, so a cluster that finishes one step later than the best keeps most of the weight and one that
    finishes much later none. Rows without outcomes (score-based teachers) are one-hot on the action.
    The hard label alone says only which try won, often by a step or two of noise on a hidden scene."""
    one_hot = nn.functional.one_hot(actions, outcome_steps.shape[-1]).float()
    if temperature_steps <= 0:
        return one_hot
    tried = torch.isfinite(outcome_steps)
    best = torch.where(tried, outcome_steps, torch.inf).min(-1, keepdim=True).values
    logits = torch.where(tried, -(outcome_steps - best) / temperature_steps, -torch.inf)
    soft = torch.softmax(torch.where(tried.any(-1, keepdim=True), logits, 0.0), -1)
    return torch.where(tried.any(-1, keepdim=True), soft, one_hot)


def warm_start(
    model: GraphActorCritic, data: TeacherData, args: Args, device: torch.device, log: Callable[[str], None], stop_requested: Callable[[], bool] | None = None
) -> dict[str, float]:
    """Behaviour cloning of the actor on the teacher's choices (or on ``soft_targets`` of the rollout's
    outcomes) plus a value regression on the decisions whose return is known (``teacher_returns``; none: no value
    loss); ``stop_requested`` as ``train``'s."""
    b_obs = obs_to_torch(data.graphs, device)
    b_mask = mask_to_torch(data.masks, device)
    b_act = torch.as_tensor(data.actions, device=device)
    b_ret = torch.as_tensor(data.returns, dtype=torch.float32, device=device)
    b_known = torch.isfinite(b_ret)  # the critic fits the decisions whose return is known (``teacher_returns``)
    b_ret = torch.where(b_known, b_ret, 0.0)  # no NaN in the graph: its gradient would be NaN even where unused
    b_target = soft_targets(torch.as_tensor(data.outcome_steps, device=device), b_act, args.warm_start_soft_steps)
    opt = optim.Adam(model.parameters(), lr=args.warm_start_lr)
    n = len(b_act)
    mb = max(1, n // max(1, args.num_minibatches))
    stats: dict[str, float] = {}
    for epoch in range(args.warm_start_epochs):
        perm = torch.randperm(n, device=device)
        correct, total_ce = 0.0, 0.0
        for start in range(0, n, mb):
            raise_if_stop_requested(stop_requested)
            idx = perm[start : start + mb]
            g = index_obs(b_obs, idx)
            logits = model.masked_logits(g, b_mask[idx])
            log_p = torch.log_softmax(logits, -1)
            target = b_target[idx]
            ce = -(target * torch.where(target > 0, log_p, 0.0)).sum(-1).mean()
            known = b_known[idx]
            v_loss = torch.where(known, (model.get_value(g) - b_ret[idx]) ** 2, 0.0).sum() / known.sum().clamp(min=1)
            loss = ce + args.vf_coef * v_loss
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(model.parameters(), args.max_grad_norm)
            opt.step()
            correct += (logits.argmax(-1) == b_act[idx]).float().sum().item()
            total_ce += ce.item() * len(idx)
        stats = {"bc_accuracy": correct / n, "bc_ce": total_ce / n, "bc_value_loss": v_loss.item(), "value_decisions": int(b_known.sum())}
        log(f"warm start epoch {epoch + 1}/{args.warm_start_epochs}: accuracy {stats['bc_accuracy']:.3f} ce {stats['bc_ce']:.3f}")
    return stats


# --- PPO --------------------------------------------------------------------------------------


LOG_FIELDS = [
    "update", "decisions", "env_steps", "wall_s", "episodes", "mean_return", "mean_coverage_pct", "policy_loss", "value_loss", "entropy", "approx_kl",
    "clipfrac", "lr", "explained_variance", "mean_episode_steps", "sps",
]  # fmt: skip
"""The columns of ``<variant>_log.csv``, one row per PPO update (CleanRL's figures): ``decisions`` is CleanRL's
global step (goal choices, warm start excluded); ``mean_return``, ``mean_coverage_pct`` and ``mean_episode_steps``
(control steps) over the episodes that ended in the update (empty when none did); the losses and ``approx_kl`` of
its last minibatch and ``clipfrac`` over all its minibatches, as CleanRL logs them; ``explained_variance`` of the rollout's returns by its
values (empty when the returns do not vary); ``sps`` the PPO decisions per second of training time so far. The
docs/training.md lists them with their units (tests/test_docs.py holds it to this list)."""


def explained_variance(values: torch.Tensor, returns: torch.Tensor) -> float | str:
    """1 - Var(returns - values) / Var(returns), as CleanRL logs it: how much of the returns the critic explains
    (1 perfect, 0 no better than their mean, negative worse); empty when the returns do not vary."""
    y_pred, y_true = values.detach().cpu().double().numpy(), returns.detach().cpu().double().numpy()
    var_y = float(np.var(y_true))
    return "" if var_y == 0 else float(1.0 - np.var(y_true - y_pred) / var_y)


TENSORBOARD_TAGS = {
    "mean_return": "charts/episodic_return",
    "mean_coverage_pct": "charts/coverage_pct",
    "lr": "charts/learning_rate",
    "policy_loss": "losses/policy_loss",
    "value_loss": "losses/value_loss",
    "entropy": "losses/entropy",
    "approx_kl": "losses/approx_kl",
    "clipfrac": "losses/clipfrac",
    "explained_variance": "losses/explained_variance",
    "mean_episode_steps": "charts/episodic_length",
}
"""CSV log column -> TensorBoard tag (CleanRL's names where it has one); ``charts/SPS`` is decisions per second."""


def summary_writer_class() -> Any:
    """tensorboardX's ``SummaryWriter``; ValueError (said before any training) when tensorboardX is missing."""
    try:
        from tensorboardX import SummaryWriter  # noqa: PLC0415  (optional: the `tensorboard` extra)
    except ImportError:
        raise ValueError("tensorboard: true needs tensorboardX: pip install 'cso-runtime[tensorboard]' (or pip install tensorboardX)") from None
    return SummaryWriter


def open_tensorboard(folder: Path, resumed_at_decisions: int | None = None) -> Any:
    """A TensorBoard event writer on ``folder``. A ``--resume``d run's starts with TensorBoard's restart marker just
    after the checkpoint's step (``purge_step``): the points an earlier process logged after its checkpoint, which this
    run logs again, are dropped from the curves as the CSV log drops their rows. Each writer has a file of its own
    (tensorboardX names it by the second and would write over one opened in the same second)."""
    purge_step = None if resumed_at_decisions is None else resumed_at_decisions + 1
    return summary_writer_class()(logdir=str(folder), purge_step=purge_step, filename_suffix=f".{time.time_ns()}")


def write_tensorboard_row(writer: Any, row: dict[str, Any]) -> None:
    """One update's CSV row as scalars at step = PPO decisions so far (a figure left empty, such as the mean
    return of an update in which no episode ended, is left out)."""
    step = int(row["decisions"])
    for column, tag in TENSORBOARD_TAGS.items():
        if row.get(column) not in ("", None):
            writer.add_scalar(tag, float(row[column]), step)
    if float(row["wall_s"]) > 0:
        writer.add_scalar("charts/SPS", step / float(row["wall_s"]), step)
    writer.flush()


def raise_if_stop_requested(stop_requested: Callable[[], bool] | None) -> None:
    """Raise ``KeyboardInterrupt`` where a stop was asked for (``cli.interrupt_on_sigterm``'s ``stop_requested``) but
    training goes on: the signal handler's own ``KeyboardInterrupt`` is lost where Python runs the handler inside a
    finalizer (a garbage collection's weakref callback, a ``__del__``), which Python reports as "Exception ignored"
    and drops. A SIGHUP that came while Python collected garbage left ``train`` running to its last update."""
    if stop_requested is not None and stop_requested():
        raise KeyboardInterrupt


def train(
    args: Args, log: Callable[[str], None] = print, plans: list[FloorPlan] | None = None, command: str | None = None, stop_requested: Callable[[], bool] | None = None
) -> dict[str, Any]:
    """Train one variant; returns the run record (also written as JSON next to the weights).

    ``plans`` replaces the configured scenes (tests train on a tiny synthetic plan). ``stop_requested``: True once
    a stop signal came (``cli.interrupt_on_sigterm``); training then stops at its next step (``raise_if_stop_requested``)
    as at a ``KeyboardInterrupt``, where the signal's own was lost."""
    args.validate()
    if args.tensorboard:
        summary_writer_class()  # tensorboardX missing: said now, not after a warm start
    pyplot()  # loaded now, before any environment or file to clean up, not at the first checkpoint where a Ctrl-C could cut its import short
    t_start = time.time()
    seed_everything(args.seed)
    torch.set_num_threads(args.torch_threads)
    device = select_device(args.device)
    Path(args.out_dir).mkdir(parents=True, exist_ok=True)  # one that cannot be made fails here, not as a lock not had
    with folder_lock(Path(args.out_dir) / TRAIN_LOCK, "train", lambda said: log(f"warning: {said}")) as locked:
        return _train_locked(args, device, t_start, log, plans, command, locked, stop_requested)


def _train_locked(
    args: Args,
    device: torch.device,
    t_start: float,
    log: Callable[[str], None],
    plans: list[FloorPlan] | None,
    command: str | None,
    locked: bool,
    stop_requested: Callable[[], bool] | None,
) -> dict[str, Any]:
    """``train`` while it holds its output folder's lock (``TRAIN_LOCK``); ``locked`` False where none could be had,
    and the partial files there may be another train's, being written."""
    out = Path(args.out_dir)
    for stale in remove_stale_training_files(out, args.variant) if locked else []:  # a killed train's
        log(f"note: removed {stale}, left by a train that was killed while writing it")
    elsewhere = not args.resume or Path(args.resume).resolve().parent != out.resolve()  # not the folder of the run it continues
    replaces = elsewhere and bool(earlier := earlier_run_files(out, args.variant))
    if replaces:  # CleanRL never writes into an old run; say it, while a Ctrl-C can still keep it
        log(
            f"note: {out} holds an earlier run ({', '.join(earlier)}): this run replaces it, removing its files as it starts its log"
            f" (until then, --resume {out / 'checkpoint.pt'} would continue it)"
        )
    refs: list[SceneRef] | list[FloorPlan] = plans if plans else training_scene_refs(args)
    log(f"training {args.variant} on {counted(len(refs), 'scene')}, device {device}: {counted(args.num_updates, 'PPO update')} of {args.batch_size} decisions "
        f"({counted(args.num_envs, 'env')} x {counted(args.num_steps, 'step')}; total_decisions {args.total_decisions} in whole updates)")
    envs = make_vector_env(args, refs)
    try:
        return _train_on(envs, refs, args, device, t_start, log, command, replaces, stop_requested)
    except BaseException:  # stopped before its PPO loop (a resume, the warm start, the first reset): the workers too
        envs.close(terminate=True)
        raise


def _train_on(
    envs: gym.vector.SyncVectorEnv | gym.vector.AsyncVectorEnv,
    refs: list[SceneRef] | list[FloorPlan],
    args: Args,
    device: torch.device,
    t_start: float,
    log: Callable[[str], None],
    command: str | None,
    replaces: bool,
    stop_requested: Callable[[], bool] | None,
) -> dict[str, Any]:
    """``_train_locked`` in ``envs`` (which it closes: at its end, or when stopped in its PPO loop)."""
    out = Path(args.out_dir)
    model = build_model(args, device)
    optimizer = optim.Adam(parameter_groups(model, args), lr=args.learning_rate, eps=args.adam_eps)
    record: dict[str, Any] = {"variant": args.variant, "args": dataclasses.asdict(args), "warm_start": {}, "software": software_provenance()}
    if command is not None:  # the command line that ran it (``train`` gives it), to run it again
        record["command"] = command

    start_update, global_decisions, warm_decisions = 1, 0, 0
    env_steps = 0
    wall_before_s = 0.0
    """Training time of the run before its ``--resume`` (the log's ``wall_s`` and the record count it too)."""
    if args.resume:
        ckpt = load_resume_checkpoint(args.resume, model, optimizer, device, args.variant, args)
        start_update = ckpt["update"] + 1
        global_decisions, warm_decisions, env_steps = ckpt["decisions"], ckpt["warm_decisions"], ckpt["env_steps"]
        wall_before_s = float(ckpt.get("wall_s", 0.0))
        record["warm_start"] = ckpt.get("warm_start", {})
        record.update(started_from(ckpt))  # a fine-tuned run's init_from and init_from_weights, as it began
        torch.set_rng_state(ckpt["torch_rng"])
        if ckpt.get("cuda_rng") is not None and device.type == "cuda":
            torch.cuda.set_rng_state_all(ckpt["cuda_rng"])
        log(f"resumed from {args.resume} at update {start_update}")
        before = ckpt.get("args", {}).get("total_decisions", args.total_decisions)
        if start_update > args.num_updates:  # eval --weights of a stopped run is told to resume it so
            log(
                f"total_decisions {args.total_decisions} ({counted(args.num_updates, 'update')}): no update left:"
                f" the weights written are the checkpoint's (update {start_update - 1}, {global_decisions} decisions)"
            )
        elif before != args.total_decisions:
            log(f"total_decisions {before} -> {args.total_decisions}: {counted(args.num_updates, 'update')} in all, the learning rate anneals over them from here")
    elif args.init_from:
        model.load_state_dict(initial_weights(args, device))
        start_file = init_from_path(args).resolve()  # the file read, wherever the run is looked at from
        record["init_from"] = str(args.init_from)
        record["init_from_weights"] = {"path": str(start_file), "sha256": file_sha256(start_file)}  # which file `shipped` was
        log(f"initialised from shipped weights {start_file}" if args.init_from == "shipped" else f"initialised from {args.init_from}")
    elif args.warm_start_data or args.warm_start_decisions > 0:
        if args.warm_start_data:
            data = TeacherData.load(args.warm_start_data)
            log(f"warm start on {len(data)} teacher decisions from {', '.join(args.warm_start_data)}")
        else:
            data = collect_teacher(envs, args.warm_start_decisions, args.gamma, args.seed, args.warm_start_teacher, log, args.progress, stop_requested=stop_requested)
            data.save(out / "teacher_data.npz")
        warm_decisions = len(data)
        record["warm_start"] = warm_start(model, data, args, device, log, stop_requested)
        record["warm_start"]["decisions"] = warm_decisions
        env = args.env_config()
        save_checkpoint(out / f"{args.variant}_warm.pt", model, env.graph, args.variant, {"stage": "warm_start"}, env.exploration.frontier)

    tensorboard = open_tensorboard(out / "tensorboard", global_decisions if args.resume else None) if args.tensorboard else None

    # preallocated rollout storage (CleanRL layout: [step, env])
    T, E = args.num_steps, args.num_envs
    layout = observation_layout(args.env_config().graph)  # the env's observations, as the vector env stacks them
    obs_buf = {k: torch.zeros((T, E) + v.shape, dtype=torch.as_tensor(v).dtype, device=device) for k, v in layout.items()}
    mask_buf = torch.zeros((T, E, args.max_frontier_nodes), dtype=torch.bool, device=device)
    actions = torch.zeros((T, E), dtype=torch.long, device=device)
    logprobs = torch.zeros((T, E), device=device)
    rewards = torch.zeros((T, E), device=device)
    dones = torch.zeros((T, E), device=device)
    values = torch.zeros((T, E), device=device)
    discounts = torch.zeros((T, E), device=device)  # each transition's discount, set at every step

    next_obs_np, info = envs.reset(seed=args.seed + 10_000 * start_update)
    next_obs = obs_to_torch(next_obs_np, device)
    next_mask = mask_to_torch(info["action_mask"], device)
    next_done = torch.zeros(E, device=device)
    ep_return = np.zeros(E)
    finished: list[dict[str, float]] = []

    log_path = out / f"{args.variant}_log.csv"
    fields = LOG_FIELDS
    if replaces:  # now: this run's inputs (init_from, warm_start_data) may be among them, and are read
        drop_earlier_run(out, args.variant, log)
    continued_log = Path(args.resume).parent / log_path.name if args.resume else None
    if continued_log is not None and continued_log.is_file() and continued_log.resolve() != log_path.resolve():
        shutil.copyfile(continued_log, log_path)  # resumed into another --out: go on from the log of the run it continues
    new_log = not (args.resume and log_path.exists())
    if not new_log:  # the rows the checkpoint already holds; later ones (logged after it, before a crash) run again
        keep_log_rows_up_to(log_path, start_update - 1, fields)
    log_file = open(log_path, "w" if new_log else "a", newline="")  # noqa: SIM115  (open for the whole run; closed in the finally below)
    writer = csv.DictWriter(log_file, fieldnames=fields)
    if new_log:
        writer.writeheader()

    progress = _progress(args.progress, args.num_updates, completed=min(start_update - 1, args.num_updates))  # a resumed run's bar goes on from its update
    recent_episodes: collections.deque[dict[str, float]] = collections.deque(maxlen=20)  # for the bar's figures
    update = start_update - 1
    finished_loop = False
    curve_drawn_at = float("-inf")  # the first checkpoint draws it
    try:
        for update in range(start_update, args.num_updates + 1):
            if args.anneal_lr:
                for group in optimizer.param_groups:
                    group["lr"] = group.get("lr_scale", 1.0) * args.learning_rate * (1.0 - (update - 1.0) / args.num_updates)
            finished = []
            for step in range(T):
                raise_if_stop_requested(stop_requested)
                for k, buf in obs_buf.items():
                    buf[step] = next_obs[k]
                mask_buf[step] = next_mask
                dones[step] = next_done
                with torch.no_grad():
                    action, logprob, _, value = model.get_action_and_value(next_obs, next_mask)
                values[step] = value
                actions[step] = action
                logprobs[step] = logprob
                next_obs_np, reward, term, trunc, info = envs.step(action.cpu().numpy())
                global_decisions += E
                reward = np.asarray(reward, dtype=np.float64)
                ep_return += reward
                done = np.logical_or(term, trunc)
                discount = np.full(E, args.gamma)
                if args.gamma_per_step > 0:
                    taken = np.asarray(info.get("decision_steps", np.zeros(E)), dtype=np.float64)
                    if done.any():  # a finished env's info is its reset's; the last decision's is in final_info
                        taken = np.where(done, info["final_info"]["decision_steps"], taken)
                    discount = args.gamma_per_step**taken
                discounts[step] = torch.as_tensor(discount, dtype=torch.float32, device=device)
                if trunc.any():  # bootstrap through truncation with V(final observation)
                    final = [info["final_obs"][i] for i in np.flatnonzero(trunc)]
                    with torch.no_grad():
                        fv = model.get_value(obs_to_torch(stack_obs(final), device)).cpu().numpy()
                    reward[np.flatnonzero(trunc)] += discount[np.flatnonzero(trunc)] * fv
                rewards[step] = torch.as_tensor(reward, dtype=torch.float32, device=device)
                for i in np.flatnonzero(done):
                    fi = info["final_info"]
                    finished.append({"return": float(ep_return[i]), "coverage_pct": float(fi["coverage_pct"][i]), "steps": int(fi["steps"][i])})
                    env_steps += int(fi["steps"][i])
                    ep_return[i] = 0.0
                next_obs = obs_to_torch(next_obs_np, device)
                next_mask = mask_to_torch(info["action_mask"], device)
                next_done = torch.as_tensor(done, dtype=torch.float32, device=device)

            with torch.no_grad():
                next_value = model.get_value(next_obs)
            advantages, returns = compute_gae(rewards, values, dones, next_value, next_done, discounts, args.gae_lambda)

            b_obs = {k: v.reshape((-1,) + v.shape[2:]) for k, v in obs_buf.items()}
            b_mask = mask_buf.reshape(-1, args.max_frontier_nodes)
            b_actions, b_logprobs = actions.reshape(-1), logprobs.reshape(-1)
            b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)
            mb_size = args.batch_size // args.num_minibatches
            clipfracs, approx_kl = [], torch.zeros(())
            for _epoch in range(args.update_epochs):
                perm = torch.randperm(args.batch_size, device=device)
                for start in range(0, args.batch_size, mb_size):
                    mb = perm[start : start + mb_size]
                    _, newlogprob, entropy, newvalue = model.get_action_and_value(index_obs(b_obs, mb), b_mask[mb], b_actions[mb])
                    logratio = newlogprob - b_logprobs[mb]
                    ratio = logratio.exp()
                    with torch.no_grad():
                        approx_kl = ((ratio - 1) - logratio).mean()
                        clipfracs.append(((ratio - 1.0).abs() > args.clip_coef).float().mean().item())
                    mb_adv = b_advantages[mb]
                    if args.norm_adv and len(mb) > 1:
                        mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                    pg_loss = torch.max(-mb_adv * ratio, -mb_adv * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)).mean()
                    if args.clip_vloss:
                        v_unclipped = (newvalue - b_returns[mb]) ** 2
                        v_clipped = b_values[mb] + torch.clamp(newvalue - b_values[mb], -args.clip_coef, args.clip_coef)
                        v_loss = 0.5 * torch.max(v_unclipped, (v_clipped - b_returns[mb]) ** 2).mean()
                    else:
                        v_loss = 0.5 * ((newvalue - b_returns[mb]) ** 2).mean()
                    entropy_loss = entropy.mean()
                    loss = pg_loss - args.ent_coef * entropy_loss + args.vf_coef * v_loss
                    optimizer.zero_grad()
                    loss.backward()
                    nn.utils.clip_grad_norm_(model.parameters(), args.max_grad_norm)
                    optimizer.step()
                if args.target_kl and approx_kl > args.target_kl:
                    break

            raise_if_stop_requested(stop_requested)  # not logged nor saved: as a KeyboardInterrupt in the update would
            elapsed_s = wall_before_s + time.time() - t_start
            row = {
                "update": update,
                "decisions": global_decisions,
                "env_steps": env_steps,
                "wall_s": round(elapsed_s, 1),
                "episodes": len(finished),
                "mean_return": np.mean([f["return"] for f in finished]) if finished else "",
                "mean_coverage_pct": np.mean([f["coverage_pct"] for f in finished]) if finished else "",
                "policy_loss": pg_loss.item(),
                "value_loss": v_loss.item(),
                "entropy": entropy_loss.item(),
                "approx_kl": approx_kl.item(),
                "clipfrac": float(np.mean(clipfracs)) if clipfracs else 0.0,
                "lr": optimizer.param_groups[0]["lr"],
                "explained_variance": explained_variance(b_values, b_returns),
                "mean_episode_steps": np.mean([f["steps"] for f in finished]) if finished else "",
                "sps": round(global_decisions / elapsed_s, 1) if elapsed_s > 0 else "",
            }
            writer.writerow(row)
            log_file.flush()
            if tensorboard is not None:
                write_tensorboard_row(tensorboard, row)
            recent_episodes.extend(finished)
            if progress is not None:
                progress.advance(stats=progress_stats(recent_episodes, global_decisions, wall_before_s + time.time() - t_start))  # every decision so far, in all the time so far
            else:
                log(f"update {update}/{args.num_updates} decisions {global_decisions} return {row['mean_return']} entropy {row['entropy']:.3f}")
            at_checkpoint = update % args.checkpoint_every == 0 or update == args.num_updates
            if at_checkpoint:
                _save_resumable(out / "checkpoint.pt", model, optimizer, args, update, global_decisions, warm_decisions, env_steps, record, wall_before_s + time.time() - t_start)
            out_of_time = bool(args.time_limit_s) and time.time() - t_start > args.time_limit_s
            if out_of_time:
                if update < args.num_updates:  # a run cut short: say how to finish it (a resume keeps the run's time limit)
                    log(
                        f"time limit reached after update {update} ({global_decisions} of {args.total_decisions} decisions);"
                        f" --resume {out / 'checkpoint.pt'} goes on from here, for {args.time_limit_s:g} s more (the limit counts"
                        " each process's time; add --time-limit-s 0 for none)"
                    )
                _save_resumable(out / "checkpoint.pt", model, optimizer, args, update, global_decisions, warm_decisions, env_steps, record, wall_before_s + time.time() - t_start)
            if args.keep_checkpoints and (at_checkpoint or out_of_time):  # the weights of each checkpoint.pt written, kept
                save_weights(kept_checkpoint_dir(out, update), model, args, {**record, **run_counts(update, global_decisions, warm_decisions, env_steps, wall_before_s + time.time() - t_start)})
            if (at_checkpoint or out_of_time) and time.time() - curve_drawn_at >= CURVE_REDRAW_EVERY_S:  # it follows the run
                draw_curve_so_far(log_path, out / f"{args.variant}_curve.png", args.variant, log, say_where=False)
                curve_drawn_at = time.time()
            if out_of_time:
                break
        finished_loop = True
    finally:
        log_file.close()
        if tensorboard is not None:
            tensorboard.close()
        if progress is not None:
            progress.close()
        envs.close(terminate=not finished_loop)  # after an error or Ctrl-C, do not wait for the workers' step
        if not finished_loop:  # stopped: the curve of the updates logged so far, which the end would have drawn
            draw_curve_so_far(log_path, out / f"{args.variant}_curve.png", args.variant, log)

    wall = wall_before_s + time.time() - t_start
    record.update(
        {
            **run_counts(update, global_decisions, warm_decisions, env_steps, wall),
            "hardware": {"device": str(device), "cpu": cpu_name(), "cpus": os.cpu_count(), "torch_threads": args.torch_threads},
            "torch": torch.__version__,
            "scenes": len(refs),
        }
    )
    save_weights(out, model, args, record)
    plot_learning_curve(log_path, out / f"{args.variant}_curve.png", args.variant)
    return record


def matching_eval_command(args: Args) -> str:
    """The ``eval`` that runs a finished run's weights as they were trained: its variant, its sensor (``eval`` runs the
    LIMO's 180-degree LiDAR unless told; ``configs/train.yaml`` trains with 360 degrees), its stuck mask's settings
    where they are not ``eval``'s and its variant's masks use them (``weights.trained_mask_settings``, which ``eval``
    warns of), and its entropy window where it is not ``eval``'s and its variant reads I (``eval`` refuses another). The valid distance mask's far bound stays ``eval``'s 1.5 m, as for the shipped weights (trained under 2 m)."""
    words = ["cso-runtime", "eval", "--method", args.variant, "--weights", args.out_dir]
    if args.sensor != "lidar":
        words += ["--sensor", args.sensor]
    elif SensorConfig.preset(args.sensor, args.lidar_fov_deg).fov_deg == 360:  # eval's other LiDAR (Args takes no other angle)
        words += ["--lidar-fov", "360"]
    words += mask_set_flags(mask_settings_changed(trained_mask_settings(dataclasses.asdict(args)), MaskConfig()))
    if VARIANTS[args.variant].use_entropy and args.entropy_window_m != FrontierConfig().entropy_window_m:  # eval refuses another
        words += ["--set", f"frontier.entropy_window_m={setting_text(args.entropy_window_m)}"]
    return shlex.join(words)


def keep_log_rows_up_to(log_path: Path, update: int, fields: Sequence[str] | None = None) -> None:
    """Drop the training log's rows after ``update`` (written after the checkpoint a run resumes from), so
    that the resumed run's rows follow on without repeating an update. With ``fields`` (the columns the resumed
    run writes), the header becomes them, with any other column of the old log after them; a column the old
    log lacks (it was written by an older version) is empty in its rows."""
    with log_path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        old, rows = reader.fieldnames or [], [r for r in reader if r.get("update", "").isdigit() and int(r["update"]) <= update]
    fields = [*fields, *(f for f in old if f not in fields)] if fields is not None else old

    def write(partial: Path) -> None:
        with partial.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=fields, restval="")
            writer.writeheader()
            writer.writerows(rows)

    write_whole(log_path, write)


def started_from(ckpt: Mapping[str, Any]) -> dict[str, Any]:
    """What the run a resumable checkpoint continues was fine-tuned from, for its resume's record: the checkpoint's
    ``started_from`` (``init_from`` and ``init_from_weights``, ``_save_resumable``); one written before it held them
    names the ``init_from`` its run's ``args`` hold (no ``init_from_weights``: the file's SHA-256 now need not be the
    one it was read with), unless that run was a resume itself, whose ``init_from`` was none of its own (a ``--init-from``
    given with ``--resume`` is not read). Empty for a run that started from a fresh network, or where it is not known."""
    if "started_from" in ckpt:
        return dict(ckpt["started_from"] or {})
    saved = ckpt.get("args")
    if not isinstance(saved, Mapping) or saved.get("resume") or not saved.get("init_from"):
        return {}
    return {"init_from": str(saved["init_from"])}


def init_from_with_resume_problem(args: Args, said: str) -> str | None:
    """What is wrong with ``args.init_from`` given with ``args.resume`` (``said``: how it was given, ``--init-from X``,
    ``--set init_from=X`` or ``init_from X in FILE``), as one line naming both flags, or None where there is nothing
    to say. A resume goes on with the weights its checkpoint holds and reads no ``init_from``: one that names other
    weights than the run itself started from (``started_from``: the file it read, ``init_from_weights``, however
    written; the same text where it names no other file here; ``shipped`` is the variant's file) would be ignored in
    silence, so it is refused. The run's own value is not: a configuration of its
    own, or a flag that repeats it; nor, for a checkpoint of a resume written before ``started_from`` (which does not
    say what its run started from), the ``init_from`` its ``args`` hold. None too for a file that is no training
    checkpoint (``check_training_inputs`` says what it is)."""
    if not (args.resume and args.init_from):
        return None
    try:
        ckpt = torch.load(args.resume, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001  (said when it is loaded to resume)
        return None
    if not isinstance(ckpt, dict) or not isinstance(ckpt.get("args"), Mapping):
        return None
    began = started_from(ckpt)
    known = "started_from" in ckpt or not ckpt["args"].get("resume")
    recorded = began.get("init_from") if known else ckpt["args"].get("init_from")

    def file_of(text: str) -> Path:
        return init_from_path(dataclasses.replace(args, init_from=text)).resolve()

    given = str(args.init_from)
    what = "it started from a fresh network" if known else "its checkpoint does not say what it started from"
    if recorded:
        read = (began.get("init_from_weights") or {}).get("path")  # absolute, resolved: the file the run read
        was, now = Path(str(read)) if read else file_of(str(recorded)), file_of(given)
        if now == was:
            return None
        # The same text names the same weights unless it names another file here: a relative path typed in another
        # folder than the run's, or through a link repointed since. ``shipped`` is the variant's, wherever installed.
        if given == str(recorded) and (given == "shipped" or not read or not now.exists()):
            return None
        what = f"it started from {recorded}" + (f", {was}; here {given} is {now}" if given == str(recorded) else "")
    return (
        f"{said} with --resume {args.resume}: --resume continues that run with the weights its checkpoint holds ({what})"
        f" and reads no --init-from; to continue it, leave out {said}; to fine-tune from {given}, start a new run:"
        f" train --init-from {given} --out NEW_FOLDER, without --resume"
    )


def _save_resumable(
    path: Path, model: nn.Module, optimizer: optim.Optimizer, args: Args, update: int, decisions: int, warm: int, env_steps: int, record: dict[str, Any], wall_s: float
) -> None:
    """What ``--resume`` needs: weights, Adam's state, the counters, the training time so far, the torch
    generators and the run's ``Args`` (a resume with another recipe is refused), and what of the run's ``record`` it
    carries on: its warm start's figures, and the weights a fine-tuned run started from (``init_from``,
    ``init_from_weights``: a resume's own ``init_from`` is none). Not the environments' state: the episodes in progress
    start over on new scenes, so a resumed run goes on like the one it continues but not bit for bit."""
    save_whole(
        {
            "state_dict": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "variant": args.variant,
            "args": dataclasses.asdict(args),
            "update": update,
            "decisions": decisions,
            "warm_decisions": warm,
            "env_steps": env_steps,
            "warm_start": record["warm_start"],
            "started_from": {key: record[key] for key in ("init_from", "init_from_weights") if key in record},
            "torch_rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state_all() if torch.cuda.is_available() and torch.cuda.is_initialized() else None,
            "wall_s": round(wall_s, 1),
        },
        path,
    )


class _Bar:
    """A rich progress bar with a free text field after it (the latest training figures). In a log file or CI
    (no terminal) it prints a plain line instead, at most every ``line_every_s`` and at the end, so that a long
    run written to a file says how far it is (as CleanRL prints a line per update). ``completed``: the part done
    before this process (a ``--resume``d run's updates), counted in the bar; the time left is this process's pace."""

    def __init__(self, total: int, what: str = "PPO updates", console: Any = None, line_every_s: float = 10.0, completed: int = 0) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn  # noqa: PLC0415

        from cso_runtime.live_view import console_that_survives_its_reader, progress_with_stats_below, redraws_in_place  # noqa: PLC0415

        console = console if console is not None else console_that_survives_its_reader()  # `train | head`: exit 141, as every command
        columns = (TextColumn("{task.description}"), BarColumn(bar_width=24), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn())
        self._lines = not redraws_in_place(console)  # its own isatty() (FORCE_COLOR=1 in CI), not a dumb terminal (TERM=dumb)
        self._p = progress_with_stats_below(*columns, console=console, disable=self._lines)
        self._p.start()
        self._task = self._p.add_task(what, total=total, stats="", completed=completed)
        self._what, self._total, self._done, self._done_before = what, total, completed, completed
        self._line_every_s = line_every_s
        self._started = self._last_line = time.monotonic()

    def advance(self, n: int = 1, stats: str | None = None) -> None:
        fields: dict[str, Any] = {} if stats is None else {"stats": stats}
        self._p.update(self._task, advance=n, **fields)
        self._done += n
        now = time.monotonic()
        if self._lines and (now - self._last_line >= self._line_every_s or self._done >= self._total):
            self._last_line = now
            elapsed = now - self._started
            left = f", about {elapsed / (self._done - self._done_before) * (self._total - self._done):.0f} s left" if self._done < self._total else ""
            self._p.console.print(f"{self._what} {self._done}/{self._total} ({elapsed:.0f} s{left}): {stats or ''}".rstrip(": "), highlight=False, markup=False, soft_wrap=True)

    def close(self) -> None:
        self._p.stop()


def _progress(enabled: bool, total: int, completed: int = 0) -> _Bar | None:
    return _Bar(total, completed=completed) if enabled else None


def progress_stats(recent: Sequence[Mapping[str, float]], decisions: int, wall_s: float) -> str:
    """What the training bar shows after an update, as CleanRL prints: the mean return and coverage of the
    last finished episodes (``recent``, the rows of ``finished``) and the decisions per second so far."""
    rate = f"{decisions / wall_s:.0f} decisions/s" if wall_s > 0 else ""
    if not recent:
        return rate
    ret = float(np.mean([e["return"] for e in recent]))
    cov = float(np.mean([e["coverage_pct"] for e in recent]))
    return f"return {ret:.2f}  coverage {cov:.1f} % (last {len(recent)} episodes)  {rate}"


CURVE_REDRAW_EVERY_S = 30.0
"""The learning curve is redrawn at a checkpoint when this much time has passed since it was last drawn (a drawing
costs about 0.2 s: at most about 1 % of a run, however short its updates)."""


def draw_curve_so_far(csv_path: Path, png_path: Path, title: str, log: Callable[[str], None], say_where: bool = True) -> None:
    """``plot_learning_curve`` of the updates logged so far: at each checkpoint of a run, and when a run stopped (Ctrl-C,
    a dead environment process), then said in the log (``say_where``). A failure to draw it is only said, so that it
    never stops the training nor hides why a run stopped."""
    try:
        plot_learning_curve(csv_path, png_path, title)
    except Exception as exc:  # noqa: BLE001
        log(f"the learning curve so far could not be drawn ({type(exc).__name__}: {exc})")
    else:
        if say_where:
            log(f"learning curve so far: {png_path}")


def plot_learning_curve(csv_path: Path, png_path: Path, title: str) -> None:
    """Mean episode return per update against decisions."""
    plt = pyplot()
    xs, ys = [], []
    with open(csv_path, newline="") as f:
        for row in csv.DictReader(f):
            if row["mean_return"] not in ("", None):
                xs.append(int(row["decisions"]))
                ys.append(float(row["mean_return"]))
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot(xs, ys, marker=".", alpha=0.5, label="per update")
    if len(ys) >= 5:  # the scene mix makes single updates noisy: show a running mean too
        ax.plot(xs[4:], np.convolve(ys, np.ones(5) / 5, mode="valid"), label="mean of 5 updates")
    ax.legend(fontsize=8)
    ax.set_xlabel("PPO decisions")
    ax.set_ylabel("mean episode return (Eq. 6)")
    ax.set_title(f"{title} learning curve")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    try:  # replaced whole: an image viewer watching the file never reads half of one
        write_whole(png_path, lambda partial: fig.savefig(partial, dpi=100, format="png"))
    finally:
        plt.close(fig)


# --- evaluation of returns (tests, quick checks) ----------------------------------------------


def episode_returns(env: ExplorationEnv, choose: Callable[[dict[str, np.ndarray], np.ndarray, np.random.Generator], int], seeds: list[int], max_decisions: int = 10_000) -> list[float]:
    """Total Eq. 6 return of one episode per seed with ``choose(graph, mask, rng) -> action``."""
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        obs, info = env.reset(seed=seed)
        total, done, n = 0.0, False, 0
        while not done and n < max_decisions:
            obs, r, term, trunc, info_next = env.step(choose(obs, info["action_mask"], rng))
            info = info_next
            total += r
            done = term or trunc
            n += 1
        out.append(total)
    return out


def model_chooser(model: GraphActorCritic, device: str = "cpu") -> Callable[[dict[str, np.ndarray], np.ndarray, np.random.Generator], int]:
    """Greedy (argmax of masked probabilities) choice of a model, as at run time. Observations of another
    number of node features than the model reads (an env of another ``GraphConfig`` than the weights were
    trained with) are a ValueError that says which graph to build, not torch's shape error."""

    def choose(obs: dict[str, np.ndarray], mask: np.ndarray, rng: np.random.Generator) -> int:
        check_node_features(model, np.shape(obs["nodes"])[-1])
        with torch.no_grad():
            g = {k: torch.as_tensor(np.asarray(v), device=device).unsqueeze(0) for k, v in obs.items()}
            a, _, _, _ = model.get_action_and_value(g, mask_to_torch(mask, device).unsqueeze(0), greedy=True)
        return int(a.item())

    return choose


def check_node_features(model: GraphActorCritic, features: int) -> None:
    """ValueError unless graphs of ``features`` node features fit ``model`` (its ``NetworkConfig.node_features``)."""
    wanted = model.config.node_features
    if features != wanted:
        raise ValueError(
            f"the observations have {features} node features, the weights' network reads {wanted}: the env's GraphConfig"
            f" is not the one the weights were trained with (GraphConfig.use_cluster_size and use_unknown_area add one each;"
            f" EnvConfig()'s default is the shipped weights'); make the env with the weights' own: "
            f"EnvConfig(graph=load_checkpoint(path)[1])"
        )


def random_chooser(obs: dict[str, np.ndarray], mask: np.ndarray, rng: np.random.Generator) -> int:
    """Uniformly random among the allowed actions."""
    return int(rng.choice(np.flatnonzero(mask)))


if __name__ == "__main__":  # CleanRL runs its trainer as a file: `python -m cso_runtime.learned.ppo ARGS` is `cso-runtime train ARGS`
    import sys

    from cso_runtime import cli

    # As under `cso-runtime`, the CLI's module is the main one: `spawn` imports the main module in each environment
    # process (--async-envs), and this one would have them all import torch, which none needs (300 MB, not 80, each).
    sys.modules["__main__"] = cli
    sys.argv = ["cso-runtime", "train", *sys.argv[1:]]
    cli.main()
