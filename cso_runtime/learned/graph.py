"""The graph G(F_t, Omega_t) of section 3.4, built from an Observation as padded numpy arrays.

Nodes are the frontier clusters (the actions, first ``max_frontier_nodes`` in distance order, i.e.
the nearest ones are kept) followed by the path nodes (the last ``max_path_nodes`` decision
positions, the newest one being the robot's current position w_t). Arrays are padded to a fixed
size so one Gymnasium ``Dict`` space describes every scene and rollouts stack without copies.

Node features (``NODE_FEATURES``), all scale-free:
  dx, dy        position relative to the robot, divided by ``distance_scale_m`` (along the map's axes, or
                in the robot's frame with ``GraphConfig.egocentric``);
  frontier      semantic label, 1 for a frontier node, 0 for a path node;
  current       history label, 1 for w_t, 0 for earlier decision positions and frontiers;
  entropy       I at the cluster's goal cell (Eq. 4) times resolution / window: the frontier length
                in the window per window side (0 when the entropy input is switched off);
  geodesic      log(1 + l / distance_scale_m) of the geodesic distance from the robot (an addition
                to the paper's five features: the robot<->node edge repeated on the node, so the
                actor sees it without a message-passing hop);
  size          only with ``GraphConfig.use_cluster_size`` (another addition, on in the shipped
                weights): log(1 + cluster length / distance_scale_m), the gain that explore_lite's
                utility weighs against the distance; I alone is local to the goal cell. When the
                learned policy leaves greedy-dist's order, it is mostly for a shorter cluster a little
                further away, which the paper's features cannot tell apart (docs/experiments/learned-policy.md).
  unknown       only with ``GraphConfig.use_unknown_area``: the fraction of unexplored cells in a square
                of side ``unknown_window_m`` around the cluster's centroid (cells off the map count as
                explored). A short frontier with little unknown behind it is a pocket that is cheap to
                close now and dear to come back to.

Edges (a choice made for speed, stated here as the docstring must): computing geodesic distances
between all pairs of nodes would need one fast-marching pass per node. Instead, the robot's own
distance map D (``obs.distance_at``) gives the exact geodesic distance l for every robot<->node edge,
and every other pair uses the Euclidean distance (or, with ``GraphConfig.geodesic_edge_bound``, the larger of
it and |l_i - l_j|, also a lower bound of the geodesic l_ij). Each node is connected to its ``knn`` nearest
nodes (Euclidean, itself included; geodesic for the robot's own list) plus the robot node, so the graph is sparse
(N x (knn + 1) edges) and the encoder's cost grows linearly with the number of frontiers.
Edge inputs are (l / scale, log(1 + l / scale)); the network's edge MLP lifts them to 32 dims.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cso_runtime.observation import Observation

NODE_FEATURES = ("dx", "dy", "frontier", "current", "entropy", "geodesic")
"""The node features every graph has; ``node_features`` adds the optional ones."""
EDGE_FEATURE_NAMES = ("edge_length", "edge_log_length")
"""The edge features: l / distance_scale_m and log(1 + l / distance_scale_m)."""
EDGE_FEATURES = len(EDGE_FEATURE_NAMES)

FEATURE_RANGES: dict[str, tuple[float, float]] = {
    "dx": (-np.inf, np.inf),
    "dy": (-np.inf, np.inf),
    "frontier": (0.0, 1.0),
    "current": (0.0, 1.0),
    "entropy": (0.0, np.inf),
    "geodesic": (0.0, np.inf),
    "size": (0.0, np.inf),
    "unknown": (0.0, 1.0),
    "edge_length": (0.0, np.inf),
    "edge_log_length": (0.0, np.inf),
}
"""Each node feature's range, and the edges' two (``EDGE_FEATURE_NAMES``), as the observation space gives
them (padding is 0, in every range). Positions relative to the robot have no bound (a scene has no size limit), nor
do lengths and distances, nor the entropy (a frontier-cell count: its largest value follows the map's cell size)."""


@dataclass
class GraphConfig:
    """Size limits and normalisation of the graph (one network serves every scene scale)."""

    max_frontier_nodes: int = 200
    """Frontier clusters kept as actions (the nearest ones); the action space size."""
    max_path_nodes: int = 20
    """Past decision positions kept as path nodes (the newest ones, w_t included)."""
    knn: int = 8
    """Neighbours per node (itself included) besides the robot node."""
    distance_scale_m: float = 10.0
    """Coordinates and distances are divided by this."""
    use_entropy: bool = True
    """Feed the frontier-based entropy I (False for cso-no-info and gnn-baseline)."""
    entropy_window_m: float = 2.0
    """gamma of Eq. 4, used to make I scale-free (match FrontierConfig.entropy_window_m)."""
    use_cluster_size: bool = False
    """Add the ``size`` node feature (each frontier cluster's length)."""
    use_unknown_area: bool = False
    """Add the ``unknown`` node feature (unexplored fraction around each cluster)."""
    unknown_window_m: float = 5.0
    """Side of the square window of the ``unknown`` feature."""
    geodesic_edge_bound: bool = False
    """Between two non-robot nodes, use max(Euclidean, |l_i - l_j|) as the edge length (l: geodesic
    distance from the robot): a lower bound of the true geodesic l_ij, at no extra fast marching, that
    tells apart two nodes close in a straight line but on either side of a wall. Off in the shipped weights."""
    egocentric: bool = False
    """Rotate dx, dy into the robot's frame (x forward, y left), so the network sees which frontiers lie
    behind the robot (turning in place is slow). Off in the shipped weights: there, dx, dy are along the
    map's axes."""

    @property
    def max_nodes(self) -> int:
        return self.max_frontier_nodes + self.max_path_nodes

    @property
    def neighbours(self) -> int:
        return self.knn + 1


def node_features(config: GraphConfig) -> tuple[str, ...]:
    """The node feature columns of graphs built with ``config``."""
    return NODE_FEATURES + (("size",) if config.use_cluster_size else ()) + (("unknown",) if config.use_unknown_area else ())


def empty_graph(config: GraphConfig) -> dict[str, np.ndarray]:
    """All-padding arrays of the fixed shapes (also the Gymnasium observation layout)."""
    n, k = config.max_nodes, config.neighbours
    return {
        "nodes": np.zeros((n, len(node_features(config))), dtype=np.float32),
        "node_valid": np.zeros(n, dtype=bool),
        "neighbours": np.zeros((n, k), dtype=np.int64),
        "neighbour_valid": np.zeros((n, k), dtype=bool),
        "edges": np.zeros((n, k, EDGE_FEATURES), dtype=np.float32),
        "robot": np.zeros((), dtype=np.int64),
    }


def frontier_count(obs: Observation, config: GraphConfig) -> int:
    """Number of clusters that become action nodes."""
    return min(len(obs.clusters), config.max_frontier_nodes)


def build_graph(obs: Observation, config: GraphConfig) -> dict[str, np.ndarray]:
    """Observation -> padded graph arrays. Frontier node i is action i (``obs.clusters[i]``)."""
    g = empty_graph(config)
    nf = frontier_count(obs, config)
    path = np.asarray(obs.path_nodes_xy_m, dtype=float).reshape(-1, 2)
    robot_xy = np.array([obs.pose.x_m, obs.pose.y_m])
    if len(path) == 0 or not np.allclose(path[-1], robot_xy):
        path = np.vstack([path, robot_xy[None, :]])  # w_t is always the newest path node
    path = path[-config.max_path_nodes :]
    npath = len(path)
    fxy = obs.goal_xy_m[:nf]
    xy = np.vstack([fxy, path]) if nf else path
    n = nf + npath
    scale = config.distance_scale_m

    # geodesic distance from the robot to each node (path nodes: the distance map at their cell)
    geo = np.empty(n)
    geo[:nf] = obs.goal_distance_m[:nf]
    geo[nf:] = obs.distance_at(path)
    euclid_robot = np.hypot(xy[:, 0] - robot_xy[0], xy[:, 1] - robot_xy[1])
    geo = np.where(np.isfinite(geo), geo, euclid_robot)  # unreachable old positions: straight line
    robot = n - 1
    geo[robot] = 0.0

    rel = (xy - robot_xy) / scale
    if config.egocentric:
        c, s = np.cos(obs.pose.yaw_rad), np.sin(obs.pose.yaw_rad)
        rel = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)
    feats = g["nodes"]
    feats[:n, 0:2] = rel
    feats[:nf, 2] = 1.0
    feats[robot, 3] = 1.0
    if config.use_entropy and nf:
        ent = np.array([c.entropy for c in obs.clusters[:nf]], dtype=float)
        feats[:nf, 4] = ent * obs.geometry.resolution_m / config.entropy_window_m
    feats[:n, 5] = np.log1p(geo / scale)
    columns = node_features(config)
    if config.use_cluster_size and nf:
        feats[:nf, columns.index("size")] = np.log1p(np.array([c.size_m for c in obs.clusters[:nf]], dtype=float) / scale)
    if config.use_unknown_area and nf:
        feats[:nf, columns.index("unknown")] = unknown_fraction(obs, nf, config.unknown_window_m)
    g["node_valid"][:n] = True

    # neighbours: the knn nearest non-robot nodes by Euclidean distance (itself included), found with
    # a k-d tree; the robot's own list uses the geodesic distances. The robot node is appended to
    # every list with the geodesic distance as the edge.
    k = min(config.knn, n - 1)
    nbr = g["neighbours"]
    valid = g["neighbour_valid"]
    edge_l = np.zeros((n, config.neighbours))
    if k > 0:
        others = xy[:robot]
        dd, ii = cKDTree(others).query(xy[:robot], k=k)
        dd, ii = dd.reshape(robot, k), ii.reshape(robot, k)
        if config.geodesic_edge_bound:
            dd = np.maximum(dd, np.abs(geo[:robot, None] - geo[ii]))
        nbr[:robot, :k] = ii
        edge_l[:robot, :k] = dd
        near_robot = np.argsort(geo[:robot], kind="stable")[:k]
        nbr[robot, :k] = near_robot
        edge_l[robot, :k] = geo[near_robot]
        valid[:n, :k] = True
    nbr[:n, config.knn] = robot
    valid[:n, config.knn] = True
    edge_l[:, config.knn] = geo
    l_ij = edge_l / scale
    g["edges"][:n, :, 0] = l_ij
    g["edges"][:n, :, 1] = np.log1p(l_ij)
    g["robot"] = np.array(robot, dtype=np.int64)
    return g


def unknown_fraction(obs: Observation, nf: int, window_m: float) -> np.ndarray:
    """Fraction of unexplored cells in a ``window_m`` square around each of the first ``nf`` clusters'
    centroids, from one summed-area table of the map (cells off the map count as explored)."""
    unknown = ~np.asarray(obs.explored, dtype=bool)
    table = np.zeros((unknown.shape[0] + 1, unknown.shape[1] + 1), dtype=np.int64)
    np.cumsum(np.cumsum(unknown, axis=0, dtype=np.int64), axis=1, out=table[1:, 1:])
    cxy = np.array([c.centroid_xy_m for c in obs.clusters[:nf]], dtype=float).reshape(-1, 2)
    iy, ix = obs.geometry.world_to_cell(cxy[:, 0], cxy[:, 1])
    half = max(1, int(round(window_m / obs.geometry.resolution_m / 2)))
    h, w = unknown.shape
    y0, y1 = np.clip(iy - half, 0, h), np.clip(iy + half + 1, 0, h)
    x0, x1 = np.clip(ix - half, 0, w), np.clip(ix + half + 1, 0, w)
    count = table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]
    return count / float((2 * half + 1) ** 2)
