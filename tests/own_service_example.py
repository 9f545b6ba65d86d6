"""Services of one's own, the examples of docs/own-service.md (the tests run this file, the page quotes it): a
listener that logs the explored area of each map, a mapper that can stand in for the built-in one, and a listener of
a topic of one's own (``ext/<name>``) that a command node publishes."""

from __future__ import annotations

import csv
import logging
from dataclasses import dataclass

from cso_runtime.config import ConfigError
from cso_runtime.geometry import Pose2D
from cso_runtime.messages import ClockMsg, MapMsg, Message, OdometryMsg, ScanMsg
from cso_runtime.occupancy import OccupancyMap, integrate_observation
from services.common import Service, ServiceContext, service_main

log = logging.getLogger("coverage_logger")


@dataclass
class CoverageLogParams:
    """Parameters of the coverage logger (``services.coverage_logger`` in a profile)."""

    csv_path: str = "coverage.csv"
    """The file the rows go to (relative: to the folder the service runs in, ``up``'s)."""
    every_steps: int = 1
    """Write a row for every this many steps' map."""

    def validate(self) -> None:
        if self.every_steps < 1:
            raise ConfigError(f"every_steps must be at least 1, got {self.every_steps}")


class CoverageLogger(Service):
    """Writes a CSV row per map: the step, the explored area and the robot's latest odometry pose."""

    name = "coverage_logger"
    inputs = {"map": MapMsg, "odom": OdometryMsg}
    outputs = {}  # it only listens: nothing waits for it, and `publish` would refuse anything
    params_class = CoverageLogParams  # `up` checks services.coverage_logger against it before anything starts

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)  # sets self.params, a CoverageLogParams
        self.pose: Pose2D | None = None
        self.rows = 0

    def start(self) -> None:
        with open(self.params.csv_path, "w", newline="") as fh:
            csv.writer(fh).writerow(["episode", "step", "explored_m2", "x_m", "y_m"])

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, OdometryMsg):
            self.pose = msg.pose
        elif isinstance(msg, MapMsg) and msg.step % self.params.every_steps == 0:
            explored_m2 = float(msg.explored.sum()) * msg.geometry.resolution_m**2
            x_m, y_m = (self.pose.x_m, self.pose.y_m) if self.pose is not None else ("", "")
            with open(self.params.csv_path, "a", newline="") as fh:  # each row on disk at once
                csv.writer(fh).writerow([msg.episode, msg.step, f"{explored_m2:.3f}", x_m, y_m])
            self.rows += 1
            self.last_step = msg.step  # `status` shows it

    def extra_status(self) -> dict[str, int]:
        return {"rows": self.rows}  # `status` shows the service's own counts under it

    def shutdown(self) -> None:
        log.info("wrote %d rows to %s", self.rows, self.params.csv_path)


class OwnMapper(Service):
    """A mapper of one's own: the occupancy grid of every scan on the arena the clock announces, a new grid for each
    new episode. Named ``mapper``, it stands in for the built-in one."""

    name = "mapper"
    inputs = {"clock": ClockMsg, "scan": ScanMsg}
    outputs = {"map": MapMsg}

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.map: OccupancyMap | None = None
        self.episode: int | None = None
        self.map_step = -1
        self.waiting: list[ScanMsg] = []  # scans that came before the first clock of their episode

    def on_message(self, robot: str, topic: str, msg: Message, received_s: float) -> None:
        if isinstance(msg, ClockMsg):
            if msg.episode != self.episode and msg.arena is not None:
                self.map, self.episode, self.map_step = OccupancyMap(msg.arena), msg.episode, -1
            waiting, self.waiting = self.waiting, []
            for scan in waiting:
                self.on_message(robot, "scan", scan, received_s)
        elif isinstance(msg, ScanMsg):
            if self.map is None or msg.episode != self.episode:
                self.waiting = [*self.waiting[-20:], msg]  # its episode's clock is on its way
                return
            if msg.step > self.map_step:  # a step sent again (a lockstep retry) is mapped once, published again
                try:
                    integrate_observation(self.map, msg.sensor_pose, msg.scan, self.ctx.exploration)
                except ValueError as exc:  # a scan that does not fit the grid: logged and counted in `status`
                    self.reject("scan", str(exc), robot)
                    return
                self.map_step = msg.step
            self.last_step = self.map_step
            self.publish("map", MapMsg.of(self.map_step, self.map, msg.episode))


class StepsHeard(Service):
    """Counts the steps that the command node of tests/command_node_example.py says it heard, on a topic of its own."""

    name = "steps_heard"
    inputs = {"ext/map_listener/steps": bytes}  # a topic of one's own (cso/<robot>/ext/...): its bytes, as published
    outputs = {}

    def __init__(self, ctx: ServiceContext) -> None:
        super().__init__(ctx)
        self.heard = 0

    def on_message(self, robot: str, topic: str, msg: bytes, received_s: float) -> None:
        self.heard += 1
        self.last_step = int(msg.decode())  # the node's own payload: the step as text

    def extra_status(self) -> dict[str, int]:
        return {"heard": self.heard}

    def shutdown(self) -> None:
        log.info("heard %d steps on ext/map_listener/steps", self.heard)


if __name__ == "__main__":  # `python tests/own_service_example.py --attach` runs the logger beside a run
    raise SystemExit(service_main(CoverageLogger))
