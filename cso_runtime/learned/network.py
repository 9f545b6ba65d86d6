"""The GNN actor-critic of section 3.4 and the masked categorical used to sample goals.

Encoder: node features -> ``hidden`` dims; edge inputs l_ij -> 32 dims by an MLP (as in the paper);
then ``layers`` rounds of graph attention where node i attends over its neighbours j (see
``graph.py``) with logits q_i.k_j + w_h.e_ij per head h (the 32-dim edge feature enters as a
learned attention bias, which keeps the cost per edge tiny; with ``edge_messages`` it also enters the
keys and messages). Nothing depends on node order,
so the actor's scores are permutation equivariant over frontier nodes and the critic, which pools
with a masked mean and reads the robot node, is invariant.

Actor: a score per frontier node from [h_i, h_robot]. Critic: V(s) from [mean_i h_i, h_robot].
"""

from __future__ import annotations

import typing
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from cso_runtime.learned.graph import EDGE_FEATURES, NODE_FEATURES

GEODESIC_FEATURE = NODE_FEATURES.index("geodesic")

MASKED_LOGIT = -1e8
"""Logit of a masked action: its probability is exactly zero in float32."""


@dataclass
class NetworkConfig:
    """Sizes of the actor-critic (small on purpose: one decision must cost < 3 ms on one CPU core)."""

    hidden: int = 32
    """Node embedding width."""
    edge_dim: int = 32
    """Edge feature width after the edge MLP (the paper's 32)."""
    heads: int = 4
    """Attention heads per layer."""
    layers: int = 2
    """Message-passing rounds."""
    node_features: int = len(NODE_FEATURES)
    """Input features per node (``graph.node_features`` of the graphs it reads)."""
    distance_prior: float = 0.0
    """0: the paper's actor. > 0: each frontier's score is ``-distance_prior * geodesic`` (the node's
    ``log(1 + l / scale)`` feature) plus the actor's output, whose last layer starts at zero, so the
    untrained policy's argmax is greedy-dist's choice (under the same masks) and PPO learns only where
    to depart from it. The shipped weights use 4 (``configs/train.yaml``); this default is the paper's actor."""
    edge_messages: bool = False
    """Also add each edge's feature, projected, to the neighbour's key and message (as PyG's TransformerConv
    with ``edge_dim``), so what a node receives says how far away its sender is; False: edges only bias the
    attention (the shipped weights)."""


class CategoricalMasked(torch.distributions.Categorical):
    """Categorical over the valid actions only: masked logits are replaced by a huge negative number,
    and the entropy sums over valid actions so masked ones add nothing (MicroRTS-Py style)."""

    def __init__(self, logits: torch.Tensor, mask: torch.Tensor) -> None:
        self.action_mask = mask
        super().__init__(logits=torch.where(mask, logits, torch.full_like(logits, MASKED_LOGIT)))

    def entropy(self) -> torch.Tensor:
        p_log_p = self.logits * self.probs
        p_log_p = torch.where(self.action_mask, p_log_p, torch.zeros_like(p_log_p))
        return -p_log_p.sum(-1)


class GraphAttentionLayer(nn.Module):
    """One round of edge-aware multi-head attention over each node's neighbour list."""

    def __init__(self, hidden: int, edge_dim: int, heads: int, edge_messages: bool = False) -> None:
        super().__init__()
        if hidden % heads:
            raise ValueError("hidden must be a multiple of heads")
        self.heads, self.head_dim = heads, hidden // heads
        self.qkv = nn.Linear(hidden, 3 * hidden)
        self.edge_bias = nn.Linear(edge_dim, heads)
        self.edge_kv = nn.Linear(edge_dim, 2 * hidden, bias=False) if edge_messages else None
        self.out = nn.Linear(hidden, hidden)
        self.norm1 = nn.LayerNorm(hidden)
        self.norm2 = nn.LayerNorm(hidden)
        self.ff = nn.Sequential(nn.Linear(hidden, 2 * hidden), nn.ReLU(), nn.Linear(2 * hidden, hidden))

    def forward(self, h: torch.Tensor, nbr: torch.Tensor, nbr_invalid: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """``nbr_invalid`` is (b, n, k, 1), True where a neighbour slot is padding."""
        b, n, d = h.shape
        k = nbr.shape[-1]
        q, kv = self.qkv(h).split([d, 2 * d], dim=-1)
        flat = (nbr + torch.arange(b, device=h.device).view(b, 1, 1) * n).reshape(-1)
        kv_j = kv.reshape(b * n, 2 * d).index_select(0, flat).view(b, n, k, 2 * d)
        if self.edge_kv is not None:
            kv_j = kv_j + self.edge_kv(e)
        key_j = kv_j[..., :d].reshape(b, n, k, self.heads, self.head_dim)
        v_j = kv_j[..., d:]
        q = q.view(b, n, 1, self.heads, self.head_dim)
        logits = (q * key_j).sum(-1) / self.head_dim**0.5 + self.edge_bias(e)  # (b, n, k, heads)
        logits = logits.masked_fill(nbr_invalid, MASKED_LOGIT)
        att = torch.softmax(logits, dim=2).unsqueeze(-1)
        msg = (att * v_j.view(b, n, k, self.heads, self.head_dim)).sum(2).reshape(b, n, d)
        h = self.norm1(h + self.out(msg))
        return self.norm2(h + self.ff(h))


class GraphActorCritic(nn.Module):
    """``get_value`` and ``get_action_and_value`` over padded graph batches (CleanRL's Agent API)."""

    def __init__(self, config: NetworkConfig | None = None, max_frontier_nodes: int = 200) -> None:
        super().__init__()
        self.config = config or NetworkConfig()
        c = self.config
        self.max_frontier_nodes = max_frontier_nodes
        self.node_in = nn.Sequential(nn.Linear(c.node_features, c.hidden), nn.ReLU(), nn.Linear(c.hidden, c.hidden))
        # l_ij -> 32 dims; a second linear layer here would fold into each layer's edge_bias
        self.edge_mlp = nn.Sequential(nn.Linear(EDGE_FEATURES, c.edge_dim), nn.ReLU())
        self.layers = nn.ModuleList(GraphAttentionLayer(c.hidden, c.edge_dim, c.heads, c.edge_messages) for _ in range(c.layers))
        self.actor = nn.Sequential(nn.Linear(2 * c.hidden, c.hidden), nn.ReLU(), nn.Linear(c.hidden, 1))
        self.critic = nn.Sequential(nn.Linear(2 * c.hidden, c.hidden), nn.ReLU(), nn.Linear(c.hidden, 1))
        if c.distance_prior > 0:
            actor_out = typing.cast(nn.Linear, self.actor[-1])
            nn.init.zeros_(actor_out.weight)
            nn.init.zeros_(actor_out.bias)

    def encode(self, g: dict[str, torch.Tensor], cut_padding: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Node embeddings (b, n, d), the robot node's embedding (b, d) and the masked mean (b, d).

        Valid nodes come first in every graph (``graph.py``), so the batch is cut to its largest
        graph before any work: padding costs nothing. ``cut_padding=False`` keeps the fixed size
        (same values for the valid nodes: padding never reaches them), which a traced graph needs."""
        valid = g["node_valid"].bool()  # vector envs store MultiBinary as int8
        n = max(1, int(valid.sum(1).max())) if cut_padding else valid.shape[1]
        valid = valid[:, :n]
        nbr_invalid = ~g["neighbour_valid"][:, :n].bool().unsqueeze(-1)
        keep = valid.unsqueeze(-1).to(g["nodes"].dtype)
        h = self.node_in(g["nodes"][:, :n]) * keep
        e = self.edge_mlp(g["edges"][:, :n])
        for layer in self.layers:
            h = layer(h, g["neighbours"][:, :n], nbr_invalid, e) * keep
        robot = g["robot"].reshape(-1, 1, 1).expand(-1, 1, h.shape[-1])
        h_robot = torch.gather(h, 1, robot).squeeze(1)
        pooled = h.sum(1) / keep.sum(1).clamp(min=1)
        return h, h_robot, pooled

    def _heads(self, g: dict[str, torch.Tensor], with_value: bool = True, cut_padding: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        h, h_robot, pooled = self.encode(g, cut_padding)
        hf = h[:, : self.max_frontier_nodes]
        logits = self.actor(torch.cat([hf, h_robot.unsqueeze(1).expand_as(hf)], dim=-1)).squeeze(-1)
        if self.config.distance_prior > 0:
            logits = logits - self.config.distance_prior * g["nodes"][:, : logits.shape[1], GEODESIC_FEATURE]
        if logits.shape[1] < self.max_frontier_nodes:  # back to the fixed action space; the mask hides the rest
            logits = nn.functional.pad(logits, (0, self.max_frontier_nodes - logits.shape[1]), value=MASKED_LOGIT)
        if not with_value:
            return logits, None
        value = self.critic(torch.cat([pooled, h_robot], dim=-1)).squeeze(-1)
        return logits, value

    def get_value(self, g: dict[str, torch.Tensor]) -> torch.Tensor:
        value = self._heads(g)[1]
        assert value is not None  # asked for (with_value)
        return value

    def get_action_and_value(
        self, g: dict[str, torch.Tensor], mask: torch.Tensor, action: torch.Tensor | None = None, greedy: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample (or re-score ``action``): returns action, log-prob, entropy over valid actions, V(s)."""
        logits, value = self._heads(g)
        assert value is not None  # asked for (with_value)
        dist = CategoricalMasked(logits, mask)
        if action is None:
            action = dist.probs.argmax(-1) if greedy else dist.sample()
        return action, dist.log_prob(action), dist.entropy(), value

    def masked_logits(self, g: dict[str, torch.Tensor], mask: torch.Tensor, cut_padding: bool = True) -> torch.Tensor:
        """Logits with masked actions set to ``MASKED_LOGIT`` (for imitation, inspection and decisions)."""
        logits, _ = self._heads(g, with_value=False, cut_padding=cut_padding)
        return torch.where(mask, logits, torch.full_like(logits, MASKED_LOGIT))


GRAPH_KEYS = ("nodes", "node_valid", "neighbours", "neighbour_valid", "edges", "robot")
"""The tensors of one graph, in the positional order of ``DecisionLogits``."""


class DecisionLogits(nn.Module):
    """``masked_logits`` on the fixed-size graph with positional inputs: the form ``trace_decision``
    compiles for run-time decisions (no Python between the ~100 small ops of one forward)."""

    def __init__(self, model: GraphActorCritic) -> None:
        super().__init__()
        self.model = model

    def forward(self, *tensors: torch.Tensor) -> torch.Tensor:
        *graph, mask = tensors
        return self.model.masked_logits(dict(zip(GRAPH_KEYS, graph)), mask, cut_padding=False)


def trace_decision(model: GraphActorCritic, g: dict[str, torch.Tensor], mask: torch.Tensor) -> Callable[..., torch.Tensor] | None:
    """A TorchScript trace of ``DecisionLogits`` for graphs shaped like ``g`` (batch of one), about a
    third faster than eager on one CPU thread. Frozen: the model's parameters are copied in as
    constants (a few per cent faster again, same logits), so trace a model again after changing its
    weights. It runs with the JIT's profiling optimiser off, so there are no slow warm-up calls (each
    of the first two would take tens of ms). None when tracing fails (the caller stays eager). Call it
    as ``traced(*[g[k] for k in GRAPH_KEYS], mask)``."""
    example = (*[g[k] for k in GRAPH_KEYS], mask)
    try:
        with torch.inference_mode(), warnings.catch_warnings():
            # torch.jit is deprecated in favour of torch.compile, which needs a C++ toolchain and
            # seconds of compilation at the first decision; the trace takes ~0.1 s and still works.
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            traced = torch.jit.freeze(torch.jit.trace(DecisionLogits(model).eval(), example, check_trace=False))
    except (RuntimeError, AttributeError, TypeError):
        return None

    def run(*tensors: torch.Tensor) -> torch.Tensor:
        with torch.jit.optimized_execution(False):
            return traced(*tensors)

    return run


def to_torch(graph: dict, device: str | torch.device = "cpu", batch: bool = False) -> dict[str, torch.Tensor]:
    """Numpy graph arrays -> tensors; ``batch=True`` adds a leading batch dimension of one."""
    out = {}
    for key, value in graph.items():
        t = torch.as_tensor(value, device=device)
        out[key] = t.unsqueeze(0) if batch else t
    return out
