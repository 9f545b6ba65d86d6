"""The learned methods by name: their networks, with the inputs and masks each variant uses (``policies.VARIANTS``), and their weights.

``policies.make_policy`` calls ``has_method`` and ``make_learned_policy``; a variant is available only
when ``cso_runtime/data/weights/<name>.pt`` exists (or ``$CSO_WEIGHTS_DIR/<name>.pt`` when that is set;
``weights.py`` says where, without torch).
"""

from __future__ import annotations

import dataclasses
import functools
import pickle
import warnings
import weakref
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cso_runtime.config import FrontierConfig, MaskConfig, SensorConfig
from cso_runtime.learned.graph import GraphConfig, build_graph, empty_graph, frontier_count
from cso_runtime.learned.network import GRAPH_KEYS, GraphActorCritic, NetworkConfig, to_torch, trace_decision
from cso_runtime.learned.weights import (  # noqa: F401 - WEIGHTS_DIR_ENV, INPUT_CHECKS, InputMismatch and input_mismatches re-exported
    INPUT_CHECKS,
    TRAINED_FRONTIER_BEFORE_RECORD,
    WEIGHTS_DIR_ENV,
    InputMismatch,
    checkpoint_frontier,
    has_weights,
    input_mismatches,
    input_verdict,
    weights_file_refusal,
    weights_path,
)
from cso_runtime.observation import Observation
from cso_runtime.outputs import write_whole
from cso_runtime.policies import VARIANTS, ActionMasker, Goal, goal_of

_DECISION_TRACES: weakref.WeakKeyDictionary[GraphActorCritic, dict[tuple, Any]] = weakref.WeakKeyDictionary()
"""Traced decision networks per model object and input shapes (False: tracing failed); die with the model."""


@functools.cache
def _cached_model(path: str, device: str) -> tuple[GraphActorCritic, GraphConfig, str | None, FrontierConfig]:
    """The weights at ``path``, the variant they were trained as and the frontier settings of their training episodes
    (``trained_frontier``), loaded once per process (eval builds a policy per episode)."""
    model, graph, ckpt = load_checkpoint(path, device)
    variant = ckpt.get("variant")
    return model, graph, variant if isinstance(variant, str) else None, trained_frontier(ckpt, graph)


def _model_for(name: str, device: str, sensor: SensorConfig | None, frontier: FrontierConfig | None) -> tuple[GraphActorCritic, GraphConfig, list[str]]:
    """``name``'s network and graph, and the warnings of ``input_verdict`` (the run's ``frontier`` settings against
    those the weights were trained with; None: ``FrontierConfig``'s defaults, what ``ObservationBuilder()`` uses).
    Every loader of a method's weights comes here (``check_weights``, ``make_learned_policy``: eval, its workers, the
    policy service, ``doctor``). CheckpointError when the file holds another variant's weights (a ``--weights``
    folder whose ``cso.pt`` came from ``train --variant gnn-baseline``), or when a setting of this run would feed the
    network inputs of another scale than it was trained on (``INPUT_CHECKS``)."""
    path = weights_path(name, sensor)
    model, graph, variant, trained = _cached_model(str(path), str(device))
    if variant is not None and variant != name:
        raise CheckpointError(f"{path} holds weights trained as {variant!r}, not {name!r}: the file must be named for its variant ({variant}.pt)")
    verdict = input_verdict(name, path, trained, frontier, graph.use_entropy)
    if verdict.refused:
        raise CheckpointError(verdict.refusal)
    return model, graph, list(verdict.warned)


def check_weights(name: str, device: str = "cpu", sensor: SensorConfig | None = None, frontier: FrontierConfig | None = None) -> list[str]:
    """Load ``name``'s weights for ``sensor`` now (kept for the episodes), so that a corrupt file, one of another
    variant, or one trained on inputs this run's ``frontier`` settings would scale otherwise (``input_mismatches``) is
    one clear error before any episode starts rather than a failure per scene. Returns the warnings of
    ``input_mismatches`` (one line each) for the caller to say. Raises CheckpointError."""
    return _model_for(name, str(device), sensor, frontier)[2]


def has_method(name: str, sensor: SensorConfig | None = None) -> bool:
    """True when ``name`` is a learned variant whose weights are shipped (for ``sensor``)."""
    return name in VARIANTS and has_weights(name, sensor)


def save_whole(obj: Any, path: str | Path) -> None:
    """``torch.save`` whole (``outputs.write_whole``: a file beside ``path``, then renamed over it): a run stopped while it writes
    (Ctrl-C, a signal, a full disk) leaves the earlier file whole, never half of one that no load reads, and no
    temporary file. Every weights file and training checkpoint is written so."""
    write_whole(path, lambda partial: torch.save(obj, partial))


def save_checkpoint(
    path: str | Path, model: GraphActorCritic, graph: GraphConfig, variant: str, extra: dict[str, Any] | None = None, frontier: FrontierConfig | None = None
) -> None:
    """Weights plus everything needed to rebuild the network and its graph (plain data only), written whole (``save_whole``),
    with ``frontier``, the frontier settings its observations were built with (``train``'s episodes': ``FrontierConfig``'s
    defaults when not given), which every load compares with the run's (``input_mismatches``)."""
    save_whole(
        {
            "variant": variant,
            "network": dataclasses.asdict(model.config),
            "graph": dataclasses.asdict(graph),
            "frontier": dataclasses.asdict(frontier or FrontierConfig()),
            "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "extra": extra or {},
        },
        path,
    )


def trained_frontier(ckpt: dict[str, Any], graph: GraphConfig) -> FrontierConfig:
    """The frontier settings the weights of ``ckpt`` (with its ``graph``) were trained with (``weights.checkpoint_frontier``)."""
    return checkpoint_frontier(ckpt, graph.entropy_window_m)


class CheckpointError(ValueError):
    """A weights file that is not a checkpoint ``save_checkpoint`` wrote (corrupt, truncated, another
    program's, or a network this version cannot rebuild): one line naming the file, not torch's traceback."""


def _why_unloadable(exc: Exception) -> str:
    """One short line for ``load_checkpoint``'s error (torch's own advice to turn weights_only off is
    not one to give for a file of unknown origin)."""
    if isinstance(exc, EOFError):
        return "empty or truncated file"
    if isinstance(exc, pickle.UnpicklingError):
        return "not a torch file of plain tensors and numbers"
    if isinstance(exc, KeyError):  # a checkpoint's missing entry; a number is the unpickler's memo: not a pickle at all
        return f"no {exc} entry" if exc.args and isinstance(exc.args[0], str) else "not a torch file"
    first_line = (str(exc).strip().splitlines() or [""])[0]
    return f"{type(exc).__name__}: {first_line}" if first_line else type(exc).__name__


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[GraphActorCritic, GraphConfig, dict[str, Any]]:
    """Rebuild the network from a checkpoint written by ``save_checkpoint``; raises CheckpointError
    (FileNotFoundError for a missing file) when the file cannot give the network back."""
    path = Path(path)
    try:
        with warnings.catch_warnings():  # torch's advice on a plain pickle's protocol: noise before the one-line error
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            ckpt = torch.load(path, map_location=device, weights_only=True)
        graph = GraphConfig(**ckpt["graph"])
        model = GraphActorCritic(NetworkConfig(**ckpt["network"]), graph.max_frontier_nodes).to(device)
        model.load_state_dict(ckpt["state_dict"])
    except FileNotFoundError:
        raise
    except Exception as exc:  # torch raises pickle, EOF, zip, key and shape errors alike  # noqa: BLE001
        raise CheckpointError(f"{path}: not a cso-runtime checkpoint ({_why_unloadable(exc)})") from None
    model.eval()
    return model, graph, ckpt


class LearnedPolicy:
    """The GoalSelector of a trained variant: graph -> network -> masks -> argmax (or a sample)."""

    def __init__(
        self, name: str, model: GraphActorCritic, graph: GraphConfig, mask_config: MaskConfig, seed: int | None = None, device: str = "cpu", greedy: bool = True, torch_threads: int | None = 1
    ) -> None:
        """``torch_threads`` (process-wide, CPU only): the network is far too small to gain from
        threads, and on a busy machine torch's thread pool turns a 3 ms decision into 150 ms.
        None leaves torch's setting alone."""
        if torch_threads is not None and str(device).startswith("cpu"):
            torch.set_num_threads(torch_threads)
        self.name = name
        self.model = model.to(device).eval()
        self.graph_config = graph
        self.grids: tuple[str, ...] = ("explored", "traversable") if graph.use_unknown_area else ("traversable",)
        """What ``select`` reads of the Observation's grids (``GoalSelector.grids``): the traversable grid
        for the stuck mask's distance maps, the explored one for the unknown-area feature."""
        self.masker = ActionMasker(mask_config)
        self.device = device
        self.greedy = greedy
        self.generator = torch.Generator()
        self._traced: Any = None
        """The traced decision network (None: not built yet; False: tracing failed, stay eager)."""
        self.input_warnings: list[str] = []
        """What ``make_learned_policy`` found of the run's settings against the weights' training that is warned of,
        not refused (``input_mismatches``), one line each."""
        self.reset(seed)

    def reset(self, seed: int | None = None) -> None:
        self.masker.reset()
        if seed is not None:
            self.generator.manual_seed(int(seed))

    def action_mask(self, obs: Observation) -> np.ndarray:
        """The masks over the kept frontier nodes (records the decision for Algorithm 1)."""
        nf = frontier_count(obs, self.graph_config)
        mask = np.zeros(self.graph_config.max_frontier_nodes, dtype=bool)
        mask[:nf] = self.masker.mask(obs)[:nf]
        if not mask.any():
            mask[:nf] = np.isfinite(obs.goal_distance_m[:nf])
        return mask

    @torch.inference_mode()
    def probabilities(self, obs: Observation, mask: np.ndarray) -> np.ndarray:
        """Masked action probabilities over the frontier nodes (zero exactly where masked)."""
        g = to_torch(build_graph(obs, self.graph_config), self.device, batch=True)
        m = torch.as_tensor(mask, device=self.device).unsqueeze(0)
        return torch.softmax(self._logits(g, m), -1).squeeze(0).cpu().numpy()

    def _logits(self, g: dict[str, torch.Tensor], m: torch.Tensor) -> torch.Tensor:
        """The network's masked logits. On CPU it runs as a TorchScript trace of the same module (built
        at the first call of the first policy on this model, or by ``warm_up``; every graph has the same
        padded shape), eager elsewhere or if tracing fails."""
        if self._traced is None and str(self.device).startswith("cpu"):
            # One trace per loaded model and graph shape, not per episode (eval makes a policy per episode).
            traces = _DECISION_TRACES.setdefault(self.model, {})
            shape = tuple(tuple(t.shape) for t in (*[g[k] for k in GRAPH_KEYS], m))
            if shape not in traces:
                traces[shape] = trace_decision(self.model, g, m) or False
            self._traced = traces[shape]
        if self._traced:
            return self._traced(*[g[k] for k in GRAPH_KEYS], m)
        return self.model.masked_logits(g, m)

    @torch.inference_mode()
    def warm_up(self) -> None:
        """Trace and run the network once on an all-padding graph of the fixed shape, so that the first
        real decision does not pay the trace (about 0.1 s). A policy server calls this before it says it
        is up; the decisions are unchanged (the trace depends on the shapes only)."""
        g = to_torch(empty_graph(self.graph_config), self.device, batch=True)
        m = torch.zeros((1, self.graph_config.max_frontier_nodes), dtype=torch.bool, device=self.device)
        m[0, 0] = True
        self._logits(g, m)

    def select(self, obs: Observation) -> Goal | None:
        if not obs.clusters or not np.isfinite(obs.goal_distance_m).any():
            self.masker.mask(obs)  # still a decision for the stuck history
            return None
        mask = self.action_mask(obs)
        probs = self.probabilities(obs, mask)
        if self.greedy:
            a = int(np.argmax(probs))
        else:
            a = int(torch.multinomial(torch.as_tensor(probs), 1, generator=self.generator).item())
        goal = goal_of(obs, a)
        self.masker.chose(goal)
        return goal


def device_problem(name: str) -> str:
    """Why this torch cannot run on device ``name`` (``cpu``, ``cuda``, ``cuda:N``), or empty: said as such, not as a
    weights file that does not load onto it."""
    device = torch.device(name)
    if device.type != "cuda":
        return ""
    if not torch.cuda.is_available():
        return f"device {name}: {'this torch was built without CUDA' if torch.version.cuda is None else 'no CUDA device is visible'}"
    if device.index is not None and device.index >= torch.cuda.device_count():
        return f"device {name}: only {torch.cuda.device_count()} CUDA device(s) here"
    return ""


def make_learned_policy(
    name: str, mask_config: MaskConfig, seed: int | None = None, device: str = "cpu", sensor: SensorConfig | None = None, frontier: FrontierConfig | None = None
) -> LearnedPolicy:
    """Load the shipped weights of ``name`` (those trained with ``sensor``'s field of view where they
    ship, ``weights.weights_path``); the variant's switches override the mask settings. ``frontier``: the settings the
    run's observations are built with (None: ``FrontierConfig``'s defaults), checked against the weights' training
    (``input_mismatches``: CheckpointError for a refused one; the policy's ``input_warnings`` hold the others, for the
    caller to say once rather than per episode)."""
    if name not in VARIANTS:
        raise ValueError(f"unknown learned method {name!r}; known: {', '.join(VARIANTS)}")
    if refusal := weights_file_refusal([name]):  # a weights file or folder given that is not there, or another method's
        raise ValueError(refusal)
    if not has_method(name, sensor):
        raise FileNotFoundError(f"no weights for {name!r} (expected {weights_path(name, sensor)}); train it with `cso-runtime train`")
    if problem := device_problem(str(device)):
        raise ValueError(f"{problem}; run the policy on cpu")
    v = VARIANTS[name]
    model, graph, input_warnings = _model_for(name, str(device), sensor, frontier)
    graph = dataclasses.replace(graph, use_entropy=v.use_entropy)
    masks = dataclasses.replace(mask_config, use_valid_distance=v.use_valid_distance, use_stuck=v.use_stuck)
    policy = LearnedPolicy(name, model, graph, masks, seed=seed, device=device)
    policy.input_warnings = input_warnings
    return policy
