"""One exploration episode: map, decide, plan, move, until section 4.1's termination criteria hold.

``Explorer`` is the loop every caller shares (eval, the training environment, tests): it is driven
step by step so the Gymnasium environment can stop at each decision. ``run_episode`` runs it to the
end with a goal selector and returns the Table 1 metrics.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from cso_runtime.config import EpisodeConfig, ExplorationConfig
from cso_runtime.frontiers import frontier_cells, frontier_components
from cso_runtime.geodesic import disk_cells
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.observation import Observation, ObservationBuilder
from cso_runtime.occupancy import OccupancyMap, integrate_observation
from cso_runtime.planner import LocalPlanner, PlannerStatus
from cso_runtime.policies import Goal, GoalSelector, goal_of
from cso_runtime.scenes import FloorPlan
from cso_runtime.simulator import Simulator

TERMINATED_COVERAGE = "coverage"
TERMINATED_NO_FRONTIER = "no_frontier"
TERMINATED_MAX_STEPS = "max_steps"


@dataclass
class EpisodeResult:
    """Table 1 metrics of one episode plus what the plots need."""

    scene: str
    steps: int
    explored_area_m2: float
    coverage_pct: float
    traversable_area_m2: float
    path_length_m: float
    terminated_by: str
    decisions: int
    decision_ms: list[float]
    trajectory_xy_m: np.ndarray
    coverage_curve_pct: np.ndarray
    explored_free: np.ndarray
    """Explored free cells on the plan's grid (row 0 at the bottom)."""
    map_grid: np.ndarray | None = None
    """The robot's own map M_t at the end, as OccupancyGrid values (-1/0/100, row 0 at the origin):
    what the mapping produced, for ``map_files.save_map``. None when the episode's map is not known."""
    map_geometry: GridGeometry | None = None
    sim_time_s: float | None = None
    """Simulated seconds the episode ran (the simulator's clock at its end); None where no simulator ran (a real robot)."""
    ended_why: str = ""
    """Why it ended, where ``terminated_by`` alone does not say (``no_frontier``: the frontier cells left and what kept
    each from being a goal, ``no_frontier_why``); empty otherwise."""

    @property
    def efficiency_m2_per_step(self) -> float:
        """Explored area per control step; NaN for an episode of no step (its first scan saw everything:
        no rate to speak of, left out of the means and the comparisons rather than counted as area / 1)."""
        return self.explored_area_m2 / self.steps if self.steps > 0 else float("nan")

    @property
    def decision_ms_p50(self) -> float:
        return float(np.percentile(self.decision_ms, 50)) if self.decision_ms else float("nan")

    @property
    def decision_ms_p99(self) -> float:
        return float(np.percentile(self.decision_ms, 99)) if self.decision_ms else float("nan")


@dataclass
class GroundTruthMetrics:
    """Coverage of a map against a plan's traversable region (section 4.1). Ground truth: only the
    evaluator (in-process ``Explorer`` or the runtime's sim service) may use it."""

    plan: FloorPlan
    config: EpisodeConfig = field(default_factory=EpisodeConfig)

    def __post_init__(self) -> None:
        self.region = self.plan.traversable_region()
        self.region_area_m2 = float(np.count_nonzero(self.region)) * self.plan.resolution_m**2

    def explored_free(self, occupancy: OccupancyMap) -> np.ndarray:
        """The cells of the plan's traversable region that the map has seen open: what coverage counts."""
        return occupancy.open & self.region

    def explored_area_m2(self, occupancy: OccupancyMap) -> float:
        return float(np.count_nonzero(self.explored_free(occupancy))) * occupancy.geometry.cell_area_m2

    def coverage_pct(self, occupancy: OccupancyMap) -> float:
        return self.coverage_pct_of(self.explored_area_m2(occupancy))

    def coverage_done(self, occupancy: OccupancyMap) -> bool:
        return self.done_at(self.explored_area_m2(occupancy))

    def coverage_pct_of(self, explored_m2: float) -> float:
        """Coverage (%) of an explored area already measured (callers that need the area, the coverage
        and the end test of one map count its cells once)."""
        return 100.0 * explored_m2 / max(self.region_area_m2, 1e-9)

    def done_at(self, explored_m2: float) -> bool:
        """Section 4.1's end of an episode: coverage above ``done_coverage_pct`` and less than
        ``done_unexplored_m2`` left to explore. Everything explored is the end too, so that
        ``done_coverage_pct: 100`` (which no coverage is above) ends by coverage, not by running out of frontiers."""
        e = self.config
        coverage = self.coverage_pct_of(explored_m2)
        return (coverage > e.done_coverage_pct or coverage >= 100.0) and self.region_area_m2 - explored_m2 < e.done_unexplored_m2


def goal_still_frontier(occupancy: OccupancyMap, goal: Goal | None) -> bool:
    """The goal cell is open and still touches unknown space, diagonals included. This is looser than
    F_t's 4-connected test (``frontiers.frontier_cells``): a goal whose only unknown neighbour is
    diagonal is kept a little longer. It stays so because every table of BENCHMARKS.md was made with it."""
    if goal is None:
        return False
    g = occupancy.geometry
    iy, ix = map(int, g.world_to_cell(goal.x_m, goal.y_m))
    if not g.in_bounds(iy, ix) or not occupancy.open[iy, ix]:
        return False
    win = occupancy.explored[max(iy - 1, 0) : iy + 2, max(ix - 1, 0) : ix + 2]
    return not win.all()


def decision_reason(
    goal: Goal | None, planner_status: PlannerStatus, occupancy: OccupancyMap, steps_since_decision: int, replan_every_steps: int
) -> str | None:
    """The re-decision rule every caller shares (in-process Explorer, the runtime's frontier service):
    why a new goal is needed now, or None to keep following the current one."""
    if goal is None:
        return "no_goal"
    if planner_status != PlannerStatus.FOLLOWING:
        return PlannerStatus(planner_status).value
    if not goal_still_frontier(occupancy, goal):
        return "not_frontier"
    if steps_since_decision >= replan_every_steps:
        return "timeout"
    return None


def goal_failed_in_place(reason: str, goal: Goal, occupancy: OccupancyMap, pose: Pose2D) -> bool:
    """A goal reached that is still a frontier is unobservable noise, and one the robot made no
    progress towards is out of its reach in practice: either is marked dead so it is not chosen again
    (explore_lite blacklists such goals the same way)."""
    if not goal_still_frontier(occupancy, goal):
        return False
    return reason in ("reached", "no_progress")


def mark_dead_frontier(dead: np.ndarray, geometry: GridGeometry, xy: tuple[float, float], goal_tolerance_m: float) -> None:
    """Mark the frontier cells within the goal tolerance of ``xy`` as dead (not actions any more)."""
    dead[disk_cells(geometry, xy, max(1, int(math.ceil(goal_tolerance_m / geometry.resolution_m))))] = True


def no_frontier_why(obs: Observation, dead: np.ndarray, min_cluster_size_m: float, robot_radius_m: float) -> str:
    """Why a decision found no goal (the episode ends ``no_frontier``), in a user's terms: how many frontier cells
    the robot's map still holds and what kept each from being a goal. ``dead``: the cells blacklisted around goals
    that failed (``mark_dead_frontier``)."""
    explored = obs.explored
    left = frontier_cells(explored & ~obs.occupied, explored)
    if not left.any():
        return "no frontier left: the map has no open cell next to unknown space"
    res = obs.geometry.resolution_m
    min_cells = max(1, int(np.ceil(min_cluster_size_m / res - 1e-9)))
    blacklisted = int(np.count_nonzero(left & dead))
    small = out_of_reach = out_of_reach_clusters = reachable = 0
    iy, ix, splits = frontier_components(left & ~dead)
    distance = obs.distance_map()
    for cy, cx in zip(np.split(iy, splits), np.split(ix, splits)) if len(iy) else ():
        if len(cy) < min_cells:
            small += len(cy)
        elif not np.isfinite(distance[cy, cx]).any():
            out_of_reach += len(cy)
            out_of_reach_clusters += 1
        else:
            reachable += len(cy)
    parts = []
    if out_of_reach:
        parts.append(
            f"{out_of_reach} in {out_of_reach_clusters} cluster(s) the robot cannot reach through known free space "
            f"(obstacles inflated by robot.radius_m, {robot_radius_m:g} m)"
        )
    if small:
        parts.append(f"{small} in clusters shorter than frontier.min_cluster_size_m ({min_cluster_size_m:g} m)")
    if blacklisted:
        parts.append(f"{blacklisted} given up around goals reached, or failed, while still frontiers (unobservable)")
    if reachable:
        parts.append(f"{reachable} reachable, which the policy chose none of")
    total = int(np.count_nonzero(left))
    return f"no frontier left that the robot can reach: {total} frontier cells ({total * res:.2f} m) remain: " + "; ".join(parts)


def ended_no_frontier_why(obs: Observation, dead: np.ndarray, config: ExplorationConfig) -> str:
    """``no_frontier_why`` with ``config``'s settings, and, where frontiers were given up and the sensor sees less than
    all around without turning to a goal behind it, that setting named: the reason an episode ended ``no_frontier``,
    the same in-process (``Explorer``) and on the runtime (the frontier service)."""
    why = no_frontier_why(obs, dead, config.frontier.min_cluster_size_m, config.robot.radius_m)
    fov_deg = config.sensor.fov_deg
    if dead.any() and fov_deg < 360 and fov_deg >= config.planner.face_goal_below_fov_deg:
        # the 180-degree LiDAR by default: a goal reached behind it was given up without being looked at
        why += f" (the {fov_deg:g}-degree sensor does not turn to a goal behind it: planner.face_goal_below_fov_deg=360 makes it)"
    return why


@dataclass
class Explorer:
    """The exploration loop around a simulator. Ground truth is used only for metrics and stopping."""

    sim: Simulator
    config: ExplorationConfig = field(default_factory=ExplorationConfig)

    def __post_init__(self) -> None:
        self.builder = ObservationBuilder(self.config.frontier, self.config.robot)
        self.metrics = GroundTruthMetrics(self.sim.plan, self.config.episode)
        self.region = self.metrics.region
        self.region_area_m2 = self.metrics.region_area_m2
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self.sim.reset(seed)
        self.map = OccupancyMap(self.sim.plan.geometry)
        self.planner = LocalPlanner.for_config(self.config)
        self.steps = 0
        self.goal: Goal | None = None
        self.steps_since_decision = 0
        self.decisions = 0
        self.decision_ms: list[float] = []
        self.dead_frontier = np.zeros(self.map.geometry.shape, dtype=bool)
        self.path_nodes: list[tuple[float, float]] = []
        self.decision_frontier: np.ndarray | None = None
        """F_t of the latest decision (``observe``), for animations."""
        self.trajectory: list[tuple[float, float]] = [tuple(self.sim.true_pose().xy)]
        self.path_length_m = 0.0
        self.terminated_by: str | None = None
        self.ended_why = ""
        self._integrate()
        self.coverage_curve: list[float] = [self.coverage_pct()]

    # --- metrics (ground truth) ---
    def explored_free(self) -> np.ndarray:
        return self.metrics.explored_free(self.map)

    def explored_area_m2(self) -> float:
        return self.metrics.explored_area_m2(self.map)

    def coverage_pct(self) -> float:
        return self.metrics.coverage_pct(self.map)

    def coverage_done(self) -> bool:
        return self.metrics.coverage_done(self.map)

    # --- the loop ---
    def _integrate(self) -> None:
        self.last_scan = self.sim.scan()
        integrate_observation(self.map, self.sim.sensor_pose(), self.last_scan, self.config)

    def _goal_still_frontier(self) -> bool:
        return goal_still_frontier(self.map, self.goal)

    def decision_reason(self) -> str | None:
        """Why a new goal is needed now, or None to keep following the current one."""
        return decision_reason(self.goal, self.planner.status, self.map, self.steps_since_decision, self.config.episode.replan_every_steps)

    def _mark_dead(self, xy: tuple[float, float]) -> None:
        mark_dead_frontier(self.dead_frontier, self.map.geometry, xy, self.config.episode.goal_tolerance_m)

    def observe(self) -> Observation:
        """The state at a decision (frontiers minus those marked dead)."""
        pose = self.sim.odometry()
        self.path_nodes.append((pose.x_m, pose.y_m))
        obs = self.builder.build(self.map, pose, np.array(self.path_nodes), exclude_frontier=self.dead_frontier)
        self.decision_frontier = obs.frontier  # for pictures of the episode; the loop passes obs on itself
        return obs

    def handle_reason(self, reason: str) -> None:
        """Bookkeeping before a decision: forget goals that failed in place (reached, or no progress
        right next to them, and still frontiers: unobservable noise)."""
        if self.goal is not None and goal_failed_in_place(reason, self.goal, self.map, self.sim.odometry()):
            self._mark_dead((self.goal.x_m, self.goal.y_m))

    def apply_goal(self, obs: Observation, goal: Goal | None) -> None:
        """Send the robot to ``goal`` (None ends the episode: no reachable frontier)."""
        self.goal = goal
        self.steps_since_decision = 0
        self.decisions += 1
        if goal is None:
            self.planner.clear()
            self.terminated_by = TERMINATED_NO_FRONTIER
            self.ended_why = ended_no_frontier_why(obs, self.dead_frontier, self.config)
            return
        status = self.planner.set_goal(obs.traversable, obs.geometry, obs.pose, np.array([goal.x_m, goal.y_m]), obs.distance_map(), occupied=obs.occupied, explored=obs.explored)
        if status == PlannerStatus.BLOCKED:
            self._mark_dead((goal.x_m, goal.y_m))

    def advance(self) -> None:
        """One control period: command, move, scan, map, metrics, termination."""
        result = self.planner.update(self.sim.odometry(), self.sim.time_s, self.last_scan)
        before = self.sim.true_pose()
        self.sim.step(result.command)
        after = self.sim.true_pose()
        self.path_length_m += math.hypot(after.x_m - before.x_m, after.y_m - before.y_m)
        self.trajectory.append((after.x_m, after.y_m))
        self.steps += 1
        self.steps_since_decision += 1
        self._integrate()
        self.planner.check_blocked(self.map.occupied, self.map.geometry, self.sim.odometry())
        explored_m2 = self.explored_area_m2()
        self.coverage_curve.append(self.metrics.coverage_pct_of(explored_m2))
        if self.metrics.done_at(explored_m2):
            self.terminated_by = TERMINATED_COVERAGE
        elif self.steps >= self.config.episode.max_steps:
            self.terminated_by = TERMINATED_MAX_STEPS

    @property
    def done(self) -> bool:
        return self.terminated_by is not None

    def end_if_covered(self) -> None:
        """End the episode by coverage if the map already covers the plan (section 4.1's end, which ``advance`` tests
        only after a step): before the first decision, where the first scan may have explored enough. ``run`` and the
        training env (``learned.env.ExplorationEnv.reset``) both start so, so that training never asks for a decision
        in an episode that evaluation ends at once."""
        if not self.done and self.coverage_done():
            self.terminated_by = TERMINATED_COVERAGE

    def run(self, policy: GoalSelector, on_step: Callable[[Explorer], None] | None = None) -> EpisodeResult:
        """Explore with ``policy`` from the current state until termination (``on_step(self)`` after
        each step). A copy of an explorer taken at a decision can be run on with another policy."""
        self.end_if_covered()
        while not self.done:
            reason = self.decision_reason()
            if reason is not None:
                self.handle_reason(reason)
                t0 = time.perf_counter()
                obs = self.observe()
                goal = policy.select(obs)
                self.decision_ms.append((time.perf_counter() - t0) * 1e3)
                self.apply_goal(obs, goal)
                if self.done:
                    break
            self.advance()
            if on_step is not None:
                on_step(self)
        return self.result()

    def result(self) -> EpisodeResult:
        return EpisodeResult(
            scene=self.sim.plan.name,
            steps=self.steps,
            explored_area_m2=self.explored_area_m2(),
            coverage_pct=self.coverage_pct(),
            traversable_area_m2=self.region_area_m2,
            path_length_m=self.path_length_m,
            terminated_by=self.terminated_by or "running",
            decisions=self.decisions,
            decision_ms=list(self.decision_ms),
            trajectory_xy_m=np.array(self.trajectory, dtype=float),
            coverage_curve_pct=np.array(self.coverage_curve, dtype=float),
            explored_free=self.explored_free(),
            map_grid=self.map.to_occupancy_grid(),
            map_geometry=self.map.geometry,
            sim_time_s=float(self.sim.time_s),
            ended_why=self.ended_why,
        )


def nearest_clusters(distance_m: np.ndarray, allowed: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` nearest clusters that are ``allowed`` and reachable (finite distance), nearest first."""
    ok = np.flatnonzero(allowed & np.isfinite(distance_m))
    return ok[np.argsort(distance_m[ok], kind="stable")][:k]


def rollout_outcomes(explorer: Explorer, obs: Observation, candidates: Sequence[int] | np.ndarray, base: GoalSelector) -> list[tuple[int, float]]:
    """For each cluster of ``candidates``: (steps, explored m2) at the end of the episode when the robot goes
    there now and ``base`` decides from then on, each tried on a copy of ``explorer`` taken at this decision
    (observed, goal not applied yet). Bertsekas' rollout compares these; the warm start can learn from all of
    them (``soft_targets``), not only from the best."""
    outcomes = []
    for action in candidates:
        trial = copy.deepcopy(explorer)
        trial.apply_goal(obs, goal_of(obs, int(action)))
        if not trial.done:
            trial.advance()  # as the loop does after a decision
        r = trial.run(base)
        outcomes.append((r.steps, r.explored_area_m2))
    return outcomes


def best_outcome(candidates: Sequence[int] | np.ndarray, outcomes: Sequence[tuple[int, float]]) -> int:
    """The candidate whose episode ended in the fewest steps (ties: more explored area; then the earlier one)."""
    scores = [(steps, -area_m2, i) for i, (steps, area_m2) in enumerate(outcomes)]
    return int(candidates[min(scores)[2]])


def rollout_choice(explorer: Explorer, obs: Observation, candidates: Sequence[int] | np.ndarray, base: GoalSelector) -> int:
    """Bertsekas' rollout: of the clusters ``candidates``, the one after which ``base`` ends the episode in
    the fewest steps (``rollout_outcomes``, ``best_outcome``). It looks into the unexplored scene through
    the simulator, so it is a teacher or a ceiling (``benchmarks/teacher_ceiling.py``), never a run-time
    policy."""
    return best_outcome(candidates, rollout_outcomes(explorer, obs, candidates, base))


def run_episode(sim: Simulator, policy: GoalSelector, config: ExplorationConfig | None = None, seed: int | None = None, on_step: Callable[[Explorer], None] | None = None) -> EpisodeResult:
    """Explore one scene with ``policy`` until termination; ``on_step(explorer)`` is called each step."""
    explorer = Explorer(sim, config or ExplorationConfig())
    sim.reset(seed)
    explorer.reset()
    policy.reset(seed)
    return explorer.run(policy, on_step)
