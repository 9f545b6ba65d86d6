"""Evaluate an ensemble of trained ``cso`` weights: each decision takes the mean of the members' masked
action probabilities (same graph, same masks), then the argmax. Everything else is ``cso-runtime eval``.

Tried on the development set (docs/experiments/learned-policy.md, "Choosing on a development set"); not shipped.

    python benchmarks/eval_ensemble.py --member cso_runtime/data/weights/cso.pt --member benchmarks/results/cluster_size_prior/train_seed2/cso.pt \
        --member benchmarks/results/cluster_size_prior/train_seed3/cso.pt -- --method cso --lidar-fov 360 --workers 1 --maps runs/dev/plans \
        --m-per-px 0.05 --out runs/dev/cso-ens3_0.05

Arguments after ``--`` go to ``cso-runtime eval``; ``--workers`` other than 1 is refused: the ensemble is set up in this
process, and eval's spawned workers would run the weights served instead.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

from cso_runtime.config import FrontierConfig
from cso_runtime.learned import registry
from cso_runtime.learned.graph import GraphConfig, build_graph
from cso_runtime.learned.network import GraphActorCritic, to_torch
from cso_runtime.learned.weights import InputVerdict
from cso_runtime.observation import Observation


class EnsemblePolicy(registry.LearnedPolicy):
    """``LearnedPolicy`` whose probabilities are the mean of several networks' masked probabilities, over the graph
    ``graph`` (the members' own; None: ``base``'s); ``base`` gives the name, masks and device."""

    def __init__(self, members: list[GraphActorCritic], base: registry.LearnedPolicy, seed: int | None, graph: GraphConfig | None = None):
        # members[0] as its model: what warm_up traces reads the members' graph (the served weights' may read another)
        super().__init__(base.name, members[0], graph or base.graph_config, base.masker.config, seed=seed, device=base.device)
        self.members = members

    @torch.inference_mode()
    def probabilities(self, obs: Observation, mask: np.ndarray) -> np.ndarray:
        g = to_torch(build_graph(obs, self.graph_config), self.device, batch=True)
        m = torch.as_tensor(mask, device=self.device).unsqueeze(0)
        p = sum(torch.softmax(member.masked_logits(g, m), -1) for member in self.members) / len(self.members)
        return p.squeeze(0).cpu().numpy()


def _workers_asked(eval_args: list[str]) -> str | None:
    """The value of the last ``--workers`` among eval's arguments (``--workers N`` or ``--workers=N``); None: not given."""
    value = None
    for i, arg in enumerate(eval_args):
        if arg == "--workers" and i + 1 < len(eval_args):
            value = eval_args[i + 1]
        elif arg.startswith("--workers="):
            value = arg.split("=", 1)[1]
    return value


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, eval_args = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--member", action="append", required=True, help="a checkpoint (.pt) of the ensemble; repeat")
    args = ap.parse_args(ours)
    if (workers := _workers_asked(eval_args)) not in (None, "1"):
        # eval's worker processes are spawned: they import the registry afresh and would run the weights served, not
        # the ensemble set up here, under the ensemble's name and without a word
        raise SystemExit(f"--workers {workers}: the ensemble is set up in this process, which eval's workers are not; give --workers 1")
    loaded = [registry.load_checkpoint(path) for path in args.member]
    members = [model for model, _, _ in loaded]
    if len({str(graph) for _, graph, _ in loaded}) != 1:
        raise SystemExit("the members must share one graph configuration")
    make, check = registry.make_learned_policy, registry.check_weights

    def check_members(name: str, frontier: FrontierConfig | None) -> list[str]:
        """The members, loaded by their paths, held to method ``name`` and the run's frontier settings as the weights of
        a method are (``registry._model_for``): CheckpointError for a member of another variant, or for what
        ``registry.input_verdict`` refuses; its warnings (each member's, one line each) returned for the caller to say."""
        others = [f"{path} holds weights trained as {ckpt['variant']!r}" for path, (_, _, ckpt) in zip(args.member, loaded, strict=True) if ckpt.get("variant") not in (None, name)]
        if others:  # as a method's own weights file of another variant is refused (registry._model_for)
            raise registry.CheckpointError(f"{'; '.join(others)}, not {name!r}: an ensemble of --method {name} takes members trained as {name}")
        verdict = sum(
            (registry.input_verdict(name, Path(path), registry.trained_frontier(ckpt, graph), frontier, graph.use_entropy) for path, (_, graph, ckpt) in zip(args.member, loaded, strict=True)),
            InputVerdict(),
        )
        if verdict.refused:
            raise registry.CheckpointError(verdict.refusal)
        return list(verdict.warned)

    def check_ensemble(name, device="cpu", sensor=None, frontier=None):
        # As check_weights is called (eval's request, before any episode; its plan says the warnings once): the weights
        # served, which give the policy its name and masks, then the members, which decide, and whose warnings are said.
        check(name, device=device, sensor=sensor, frontier=frontier)
        return check_members(name, frontier)

    def make_ensemble(name, mask_config, seed=None, device="cpu", sensor=None, frontier=None):
        # As make_learned_policy is called (make_policy passes the run's sensor and frontier settings).
        base = make(name, mask_config, seed=seed, device=device, sensor=sensor, frontier=frontier)
        warned = check_members(name, frontier)
        # The members' graph (their knn, distance scale, node limits...), not the weights served's, which only stand in
        # for the policy's name and masks: the variant's entropy switch on it, as make_learned_policy sets it.
        graph = dataclasses.replace(loaded[0][1], use_entropy=base.graph_config.use_entropy)
        policy = EnsemblePolicy(members, base, seed, graph)
        policy.input_warnings = warned  # the members', which decide (the policy service says them, as make_learned_policy's)
        return policy

    registry.make_learned_policy, registry.check_weights = make_ensemble, check_ensemble
    try:
        from cso_runtime.cli import app  # noqa: PLC0415

        app(["eval", *eval_args])
    finally:  # the process's own loaders again (main() called in a process that goes on: the tests)
        registry.make_learned_policy, registry.check_weights = make, check
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
