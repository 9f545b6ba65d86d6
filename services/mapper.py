"""Mapper service: ``integrate_observation`` (the scan, then the robot's footprint) on every scan, publishes the map M_t.

The grid is sized from the clock's arena (or ``services.mapper`` width/height when set). A scan it
has already integrated is not integrated twice: the map is re-published (lockstep retries). A new
episode is recognised by the episode id that clocks and scans carry, never by the step going back:
each subscriber's callbacks run on their own thread, so a clock may be handled after scans of later
steps (the sim even sends each step's scan first). On start it restores the latest map from the
referee's cache (``cache/map``: the sim or ros2_bridge) so a restarted mapper keeps what was
explored; it answers queries on its map key so late joiners get the latest map at once.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import zenoh

from cso_runtime.config import Bound, ConfigError, check_bounds, from_dict, seconds
from cso_runtime.geometry import GridGeometry
from cso_runtime.messages import ClockMsg, MapMsg, Message, ScanMsg, check_configured_grid, encode
from cso_runtime.occupancy import OccupancyMap, integrate_observation
from services.common import Service, ServiceContext, service_main

log = logging.getLogger("cso.mapper")


MAX_PENDING_SCANS = 10_000
"""The most scans ``max_pending_scans`` may keep: 10,000 of the LIMO's 180 beams are 7 MB, of the largest scan a message
takes (``messages.MAX_BEAMS``) 4 GB."""

MAPPER_PARAMS_BOUNDS = {**seconds("restore_timeout_s"), "max_pending_scans": Bound(1, MAX_PENDING_SCANS, why="MAX_PENDING_SCANS")}
"""``MapperParams``' bounds (its explicit grid's are the run's ``max_grid_cells``: ``check_grid``)."""


@dataclass
class MapperParams:
    """Parameters of the mapper service (``services.mapper`` in a profile)."""

    resolution_m: float = 0.0
    """Grid cell size; 0 = take the arena announced on the clock topic."""
    width_m: float = 0.0
    """Grid width when ``resolution_m`` is set."""
    height_m: float = 0.0
    """Grid height when ``resolution_m`` is set."""
    restore_timeout_s: float = 1.0
    """How long (wall clock) to wait at start for the latest map the referee (sim or ros2_bridge) holds, so that a
    restarted mapper goes on from it."""
    max_pending_scans: int = 200
    """Scans kept while the grid is unknown (before the first clock); a replay at full speed can
    deliver many scans before the first clock is handled, each subscriber having its own thread."""

    def explicit_shape(self) -> tuple[int, int] | None:
        """The explicit grid's ``(ny, nx)`` cells (``resolution_m`` set), as the mapper makes it; None: the clock's arena."""
        if not self.resolution_m > 0:
            return None
        return round(self.height_m / self.resolution_m), round(self.width_m / self.resolution_m)

    def check_grid(self, bound: int | None = None) -> None:
        """ConfigError for an explicit grid of more cells than ``bound`` (this process's ``max_grid_cells`` when None)
        or too many to count (``messages.check_configured_grid``): ``up`` checks it, and the mapper before making it."""
        check_configured_grid("services.mapper.width_m, height_m", self.resolution_m, self.width_m, self.height_m, self.explicit_shape, bound)

    def validate(self) -> None:
        if self.resolution_m < 0 or (self.resolution_m > 0 and not (self.width_m > 0 and self.height_m > 0)):
            raise ConfigError("an explicit grid needs resolution_m, width_m and height_m > 0")
        check_bounds("", self, MAPPER_PARAMS_BOUNDS)  # max_pending_scans, restore_timeout_s: their one check


class MapperService(Service):
    """Integrates each step's scan into the occupancy grid and publishes the map M_t (restored from the referee's cache
    when it restarts)."""

    name = "mapper"
    inputs = {"clock": ClockMsg, "scan": ScanMsg}
    outputs = {"map": MapMsg}

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.params = from_dict(MapperParams, ctx.params, where="services.mapper")
        self.map: OccupancyMap | None = None
        self.map_step = -1
        self.episode: int | None = None
        """Episode id of the map (from the clock); None until the first clock."""
        self.pending: list[ScanMsg] = []
        self.published: MapMsg | None = None
        """The map last published (a snapshot: its own arrays), which the map queryable answers with."""
        self._queryable: zenoh.Queryable | None = None
        self.params.check_grid()  # started by hand, with no `up` to check its profile: before allocating the grid
        if (shape := self.params.explicit_shape()) is not None:
            self.map = OccupancyMap(GridGeometry(self.params.resolution_m, shape))

    def start(self) -> None:
        assert self.session is not None
        self._queryable = self.session.declare_queryable(self.ctx.keys.map, self.guarded(self._on_query))
        cached = self.restore_from_cache("map", MapMsg, self.params.restore_timeout_s)  # nothing kept, no answer: said there
        if cached is not None:
            self.restore(cached)

    def restore(self, cached: MapMsg) -> None:
        """Continue from the referee's latest map (a restarted mapper). It belongs to its episode: the
        first scan of another episode starts a new map (``enter_episode``)."""
        if self.map is not None and self.map.geometry != cached.geometry:
            return
        self.map = cached.occupancy().copy()  # integrated into: its own arrays
        self.map_step = cached.step
        self.episode = cached.episode
        self.published = cached  # its arrays are not the ones integrated into
        log.info("restored the map of step %d (episode %d) from the cache", cached.step, cached.episode)

    def _on_query(self, query: zenoh.Query) -> None:
        """Answer with the map last published. Not ``self.map``: in real time the loop's thread integrates scans into
        it while Zenoh's thread answers, and a late joiner got a scan half integrated under the step before it (or,
        the explored cells copied before a scan and the occupied after it, a map every receiver refuses)."""
        published = self.published
        if published is not None:
            query.reply(self.ctx.keys.map, encode(published))

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, ClockMsg):
            self.enter_episode(msg.episode)
            # The clock's arena, unless the profile gives a grid: at the start, and in each new episode (a restarted
            # ROS bridge announces an arena around where the robot is now, which the first one may not hold).
            fresh = self.map is None or self.map_step < 0
            if msg.arena is not None and self.params.resolution_m <= 0 and fresh and (self.map is None or self.map.geometry != msg.arena):
                self.map = OccupancyMap(msg.arena)
                log.info("map %dx%d cells at %.3f m", msg.arena.shape[1], msg.arena.shape[0], msg.arena.resolution_m)
            if self.map is not None and self.pending:
                pending, self.pending = self.pending, []
                for scan in pending:
                    self.integrate(scan)
            return
        assert isinstance(msg, ScanMsg)
        if self.map is None:
            if len(self.pending) >= self.params.max_pending_scans:
                self.reject("scan", f"no map geometry yet: dropped the scan of step {self.pending[0].step}")
                self.pending = self.pending[1:]
            self.pending.append(msg)
            self.set_state("stale", "no map geometry yet (waiting for the clock)")
            return
        self.integrate(msg)

    def enter_episode(self, episode: int) -> None:
        """Clock or scan of ``episode``: a new id (whichever of the two comes first) starts a new map."""
        if self.episode is not None and episode != self.episode:
            log.warning("new episode %d (map of episode %d at step %d): clearing the map", episode, self.episode, self.map_step)
            if self.map is not None:
                self.map = OccupancyMap(self.map.geometry)
            self.map_step, self.published = -1, None
        self.episode = episode

    def integrate(self, scan: ScanMsg) -> None:
        assert self.map is not None
        self.enter_episode(scan.episode)
        if scan.step > self.map_step:
            try:
                integrate_observation(self.map, scan.sensor_pose, scan.scan, self.ctx.exploration)
            except ValueError as exc:
                self.reject("scan", str(exc))
                return
            self.map_step = scan.step
        self.last_step = self.map_step
        self.set_state("running")
        self.published = MapMsg.of(self.map_step, self.map, scan.episode)
        self.publish("map", self.published)


def main(argv: list[str] | None = None) -> int:
    """``python -m services.mapper``'s entry point; exit code 2 for a bad config."""
    return service_main(MapperService, argv)


if __name__ == "__main__":
    raise SystemExit(main())
