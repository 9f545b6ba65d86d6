"""Where PPO's gradients go in the learned policy: the policy loss's and the value loss's gradient norm per part
of the network on one minibatch of a first rollout, and (``--adam-updates N``) each parameter's gradient size
as Adam sees it after N updates of ``train``, against Adam's epsilon; ``--moved FILE``: how far each
parameter of trained weights moved from the initial values ``train`` starts from with the same seed.

    python benchmarks/ppo_gradients.py [--set init_from=shipped] [--adam-updates 2] [--set KEY=VALUE ...]
    python benchmarks/ppo_gradients.py --moved cso_runtime/data/weights/cso.pt [--set edge_messages=true ...]

Settings are those of ``configs/train.yaml`` (``--config``) with ``--set`` overrides, as ``cso-runtime train``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch
from torch import optim

from cso_runtime.cli import training_args
from cso_runtime.learned import ppo

PARTS = ("node_in", "edge_mlp", "layers.0", "layers.1", "actor", "critic")


def gradient_split(args: ppo.Args, minibatch: int = 64) -> dict[str, tuple[float, float]]:
    """{part: (|grad of the policy loss| (unclipped: ratio 1 at the rollout policy), |grad of vf_coef * value loss|)} on one minibatch."""
    ppo.seed_everything(args.seed)
    device = torch.device("cpu")
    envs = ppo.make_vector_env(args, ppo.training_scene_refs(args))
    model = ppo.build_model(args, device)
    if args.init_from:
        model.load_state_dict(ppo.initial_weights(args, device))
    steps, n_env = args.num_steps, args.num_envs
    obs_np, info = envs.reset(seed=args.seed)
    obs, mask, done = ppo.obs_to_torch(obs_np, device), ppo.mask_to_torch(info["action_mask"], device), torch.zeros(n_env)
    rollout: dict[str, list] = {k: [] for k in ("obs", "mask", "action", "value", "reward", "done")}
    for _ in range(steps):
        with torch.no_grad():
            action, _, _, value = model.get_action_and_value(obs, mask)
        for k, v in (("obs", obs), ("mask", mask), ("action", action), ("value", value), ("done", done)):
            rollout[k].append(v)
        obs_np, reward, term, trunc, info = envs.step(action.numpy())
        rollout["reward"].append(torch.as_tensor(reward, dtype=torch.float32))
        done = torch.as_tensor(np.logical_or(term, trunc), dtype=torch.float32)
        obs, mask = ppo.obs_to_torch(obs_np, device), ppo.mask_to_torch(info["action_mask"], device)
    envs.close()
    with torch.no_grad():
        next_value = model.get_value(obs)
    stack = {k: torch.stack(v) for k, v in rollout.items() if k != "obs"}
    advantages, returns = ppo.compute_gae(stack["reward"], stack["value"], stack["done"], next_value, done, torch.full((steps, n_env), args.gamma), args.gae_lambda)
    b_obs = {k: torch.cat([o[k] for o in rollout["obs"]]) for k in rollout["obs"][0]}
    idx = torch.randperm(steps * n_env)[:minibatch]
    _, logprob, _, value = model.get_action_and_value(ppo.index_obs(b_obs, idx), stack["mask"].reshape(-1, args.max_frontier_nodes)[idx], stack["action"].reshape(-1)[idx])
    adv = advantages.reshape(-1)[idx]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    losses = {"policy": -(adv * torch.exp(logprob - logprob.detach())).mean(), "value": args.vf_coef * 0.5 * ((value - returns.reshape(-1)[idx]) ** 2).mean()}
    norms: dict[str, dict[str, float]] = {}
    for name, loss in losses.items():
        model.zero_grad()
        loss.backward(retain_graph=True)
        norms[name] = {part: sum(float((p.grad**2).sum()) for n, p in model.named_parameters() if n.startswith(part) and p.grad is not None) ** 0.5 for part in PARTS}
    return {part: (norms["policy"][part], norms["value"][part]) for part in PARTS}


def adam_gradient_sizes(args: ppo.Args, updates: int) -> dict[str, float]:
    """{parameter: median bias-corrected root mean square gradient} from Adam's state after ``updates`` updates."""
    made: dict[str, object] = {}
    original_adam, original_build = ppo.optim.Adam, ppo.build_model

    class RecordedAdam(original_adam):  # type: ignore[misc,valid-type]
        def __init__(self, params, *a, **k):
            super().__init__(params, *a, **k)
            made["optimizer"] = self

    def recorded_build(a: ppo.Args, device: torch.device):
        made["model"] = model = original_build(a, device)
        return model

    ppo.optim.Adam, ppo.build_model = RecordedAdam, recorded_build
    try:
        with tempfile.TemporaryDirectory() as out:
            args.out_dir, args.total_decisions, args.progress = out, updates * args.batch_size, False
            ppo.train(args, log=lambda _line: None)
    finally:
        ppo.optim.Adam, ppo.build_model = original_adam, original_build
    opt: optim.Adam = made["optimizer"]  # type: ignore[assignment]
    beta2 = opt.param_groups[0]["betas"][1]
    sizes = {}
    for name, p in made["model"].named_parameters():  # type: ignore[union-attr]
        state = opt.state.get(p)
        if state:
            sizes[name] = float((state["exp_avg_sq"] / (1 - beta2 ** float(state["step"]))).sqrt().median())
    return sizes


def moved_from_init(args: ppo.Args, weights: Path) -> dict[str, tuple[float, float]]:
    """{parameter: (mean |initial value|, mean |trained - initial|)}; the initial values are those ``train``
    builds with ``args.seed`` (the file must hold a network of the same configuration)."""
    ppo.seed_everything(args.seed)
    model = ppo.build_model(args, torch.device("cpu"))
    trained = torch.load(weights, map_location="cpu", weights_only=False)["state_dict"]
    return {n: (float(p.abs().mean()), float((trained[n] - p).abs().mean())) for n, p in model.named_parameters()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("configs/train.yaml"))
    parser.add_argument("--set", dest="settings", action="append", default=[], help="KEY=VALUE, as cso-runtime train --set")
    parser.add_argument("--adam-updates", type=int, default=0, help="Also train this many updates and print Adam's view of each gradient")
    parser.add_argument("--moved", type=Path, help="Instead: how far these trained weights moved from their initial values")
    a = parser.parse_args()
    args = training_args(a.config, {"progress": False}, a.settings)
    torch.set_num_threads(args.torch_threads)
    if a.moved is not None:
        print(f"{'parameter':40s} {'mean |initial|':>15s} {'mean |moved|':>13s}")
        for name, (size, moved) in moved_from_init(args, a.moved).items():
            print(f"{name:40s} {size:15.4f} {moved:13.4f}")
        return
    print(f"{'part':10s} |grad| policy loss   |grad| vf_coef * value loss")
    for part, (pg, vf) in gradient_split(args).items():
        print(f"{part:10s} {pg:18.2e}   {vf:18.2e}")
    if a.adam_updates > 0:
        print(f"\nafter {a.adam_updates} updates: median root mean square gradient per parameter (Adam's eps: {args.adam_eps:g})")
        for name, size in adam_gradient_sizes(args, a.adam_updates).items():
            print(f"{name:40s} {size:.2e}")


if __name__ == "__main__":
    main()
