"""A runtime profile: what ``cso-runtime up`` starts, in the spirit of a dora-rs dataflow file.

A profile (``configs/profiles/<name>.yaml``, shipped in the package through ``cso_runtime/profiles``; a user's
``./configs/profiles/<name>.yaml`` wins) lists the services and their parameters, the scene, the method, the Zenoh
router and how the services are supervised. ``load_profile`` reads it, applies the command line's flags and
``--set`` keys, and validates all of it (every service's parameters, the scene, the method's weights, the MuJoCo
LIMO's physics) before anything starts: a bad profile is a ``ConfigError`` naming the file and the flags.
"""

from __future__ import annotations

import importlib.util
import os
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cso_runtime.config import (
    MAX_RESTARTS,
    Bound,
    ConfigError,
    ExplorationConfig,
    check_bounds,
    check_seed,
    field_types,
    field_value,
    from_dict,
    key_sections,
    load_yaml,
    mapping_at,
    refuse_a_flag_and_a_setting_that_disagree,
    refuse_a_setting_read_as_another_type,
    seconds,
    set_dotted,
    set_said,
    to_dict,
    unknown_keys,
    unknown_keys_said,
    with_mujoco_limo_defaults,
    with_nearest,
    wrong_section,
)
from cso_runtime.keys import check_robot_id
from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, MAX_GRID_CELLS, check_max_grid_cells
from cso_runtime.processes import REALTIME_PRIORITY_MAX
from cso_runtime.scenes import FloorPlan, SceneError, SceneRef, resolve_scenes, spec_names_a_path, start_overlap_said
from cso_runtime.transport import JOIN_TIMEOUT_S, ZENOH_CONFIG_ENV, TransportConfig, TransportError


@dataclass
class RouterConfig:
    """The launcher's embedded Zenoh router."""

    listen: list[str] = field(default_factory=lambda: ["tcp/127.0.0.1:0"])
    """Endpoints to listen on; port 0 picks a free port at start."""
    connect: list[str] = field(default_factory=list)
    """Other routers to join (services on other hosts)."""
    embedded: bool = True
    """Open our own router (on loopback; it joins the routers in ``connect``, the robot's zenoh-bridge-ros2dds in the
    ``limo-ros2`` profile), so the services' messages to one another stay on this host. False: open none and join
    the routers in ``connect`` instead; every process then connects to them directly, and every message between two
    services crosses the link to that router twice."""
    service_mode: str = "client"
    """Zenoh mode of the services: ``client`` (every message through the router) or ``peer`` (services
    also listen on a loopback port and talk directly once the router has introduced them)."""
    connect_timeout_s: float = JOIN_TIMEOUT_S
    """How long ``up`` waits to reach the routers in ``connect`` (its embedded router joining them, or its own
    session when ``embedded`` is false) before it stops, exit 3, no service started."""
    zenoh_config: str = ""
    """A Zenoh config file (JSON5, Zenoh's own format) that the launcher's router and every service start from:
    user/password authentication, TLS, access control (docs/hardware.md, Securing the network). ``up --zenoh-config``
    sets it; "" takes ``$CSO_ZENOH_CONFIG`` (``cso-runtime --zenoh-config FILE``), else Zenoh's defaults."""

    def validate(self) -> None:
        if self.service_mode not in ("client", "peer"):
            raise ConfigError(f"router.service_mode must be client or peer, got {self.service_mode!r}")
        if not self.embedded and not self.connect:
            raise ConfigError("router.embedded is false: give the router to join with --connect (e.g. tcp/ROBOT_IP:7447)")
        check_bounds("router", self, seconds("connect_timeout_s", positive=True))


@dataclass
class SupervisionConfig:
    """How crashed services are restarted and how everything is stopped."""

    max_restarts: int = 3
    """Restarts per service within ``restart_window_s`` before the launcher gives up on it (and says so)."""
    restart_window_s: float = 600.0
    """Restarts older than this no longer count towards ``max_restarts`` nor double the back-off (systemd's
    StartLimitIntervalSec): a robot running for hours keeps a service that crashes now and then, and still gives up
    on one that crashes again and again. 0: every restart of the run counts."""
    backoff_s: float = 0.5
    """Delay before the first restart; doubled after each restart within ``restart_window_s``."""
    backoff_max_s: float = 8.0
    """Longest delay between restarts."""
    stop_timeout_s: float = 3.0
    """Deadline of each stop stage (SIGINT, then SIGTERM, then SIGKILL)."""
    given_up_grace_s: float = 10.0
    """How long the episode waits for another process (another host, or one started by hand) to serve a
    service the launcher has given up on, before it stops saying so (exit 1) rather than run on with
    no one choosing goals or driving."""
    hang_timeout_s: float = 20.0
    """A service whose process runs but that has not answered the launcher's status query (asked every
    ``HANG_CHECK_PERIOD_S``) for this long is hung (a deadlock, a stopped process): the launcher writes its
    stacks to its log, kills it and restarts it like a crashed one, as Nav2's bond does. 0: never."""
    start_timeout_s: float = 60.0
    """A service whose process has run this long without coming up (its liveliness token: imports, warm-up
    and session done; a few seconds normally) is hung before it started: handled as ``hang_timeout_s``'s
    hung service. 0: never."""

    def validate(self) -> None:
        check_bounds("supervision", self, SUPERVISION_BOUNDS)  # each key's own range: the one way it is checked and said
        if self.backoff_max_s < self.backoff_s:
            raise ConfigError(f"supervision needs backoff_s <= backoff_max_s, got {self.backoff_s:g} and {self.backoff_max_s:g}")
        if not (self.hang_timeout_s == 0 or self.hang_timeout_s >= 2 * HANG_CHECK_PERIOD_S):
            raise ConfigError(f"supervision.hang_timeout_s must be 0 (off) or at least {2 * HANG_CHECK_PERIOD_S:g} s, got {self.hang_timeout_s}")
        if not (self.start_timeout_s == 0 or self.start_timeout_s >= 5.0):
            raise ConfigError(f"supervision.start_timeout_s must be 0 (off) or at least 5 s (a service's imports and warm-up), got {self.start_timeout_s}")


SUPERVISION_BOUNDS = {
    "max_restarts": Bound(0, MAX_RESTARTS, why="config.MAX_RESTARTS"),
    **seconds("restart_window_s", "backoff_s", "backoff_max_s", "given_up_grace_s", "hang_timeout_s", "start_timeout_s"),
    **seconds("stop_timeout_s", positive=True),
}
"""``SupervisionConfig``'s bounds: its times at most a day (``config.MAX_WAIT_S``), its restarts ``config.MAX_RESTARTS``."""


HANG_CHECK_PERIOD_S = 1.0
"""How often the launcher asks its services for their status (``SupervisionConfig.hang_timeout_s``)."""

REAL_ROBOT_SCENE = "none: the real robot explores where it is"
"""What a run with no simulator (a real robot through ``ros2_bridge``) names as its scene: the launcher's first
line and ``runs``; its profile's ``scene`` is never loaded."""

UNUSED_BY_A_REAL_ROBOT = ("scene", "m_per_px")
"""A profile's keys that a real robot's run never reads (its scene is the room it is in): ``up --resolved`` leaves them out."""

REFEREES = ("sim", "ros2_bridge")
"""Services that own the episode (its status and end): without them the run cannot finish (nor be left out of it,
``up --without``)."""
OWN_REFEREE = "own"
"""``referee_kind`` of a run whose services have neither of ``REFEREES``: its referee is one of one's own (a command node
publishing ``episode_status`` and ``episode_result``, a simulator of one's own), no real robot."""


def referee_kind(services: Any) -> str:
    """Which kind of referee a profile's ``services`` run the episode with: ``sim``, ``ros2_bridge`` (of ``REFEREES``),
    or ``OWN_REFEREE``, one of one's own (the launcher's status says it, ``launcher_status.referee``; report.html's
    ``of_an_own_referee``)."""
    return next((name for name in REFEREES if name in services), OWN_REFEREE)


REALTIME_PRIORITY_BOUND = Bound(0, REALTIME_PRIORITY_MAX, why="0: normal scheduling; 1 to 99: SCHED_FIFO's priorities")
"""``Profile.realtime_priority``'s range, checked by ``up`` and by a service started by hand alike."""


@dataclass
class Profile:
    """One runtime configuration: what to explore, with which services and parameters."""

    name: str = "sim"
    """Profile name (for logs and run ids)."""
    robot: str = "r0"
    """Robot id: namespaces every key (cso/<robot>/...)."""
    scene: str = "generated:small:1:0"
    """Scene spec: builtin, a folder or PNG of floor plans, or generated:SCALE:N:SEED (first scene used)."""
    m_per_px: float = 0.1
    """Metres per pixel of PNG plans."""
    method: str = "greedy-dist"
    """Goal selector of the policy service."""
    seed: int = 0
    """Episode seed (simulator noise, random policy)."""
    lockstep: bool = False
    """Deterministic lockstep (the sim waits for the pipeline) instead of real time."""
    exploration: dict[str, Any] = field(default_factory=dict)
    """ExplorationConfig overrides (sensor, robot, frontier, masks, episode, planner)."""
    router: RouterConfig = field(default_factory=RouterConfig)
    """The launcher's Zenoh router and the services' Zenoh mode (``RouterConfig``)."""
    supervision: SupervisionConfig = field(default_factory=SupervisionConfig)
    """Restarts, hang checks and stops of the services (``SupervisionConfig``)."""
    services: dict[str, Any] = field(default_factory=dict)
    """Service name -> its parameters (a mapping, possibly empty). Only listed services are started."""
    without: list[str] = field(default_factory=list)
    """Services of this robot that the run leaves to another process (``up --without policy``: a shared policy
    server's ``serve_all_robots`` policy, a bridge started by hand): not started, not in ``services``; ``status``
    lists them as not started by this run (DOWN until one comes up) and ``dataflow.md`` draws them as outside."""
    progress_log_s: float = 10.0
    """Without the live view on a terminal (``--no-live``, ``--detach``, output into a file) the launcher logs a
    line of the episode's progress this often, in seconds (0: never), so a log being followed is never silent."""
    realtime_priority: int = 0
    """The SCHED_FIFO priority (1-99) every service of the run sets on itself once it has warmed up, its Zenoh threads
    and helper processes included (``processes.use_realtime_priority``), as ROS 2 real-time nodes do; 0 (the default): the
    system's normal scheduling. It needs CAP_SYS_NICE or an ``rtprio`` limit (docs/runtime.md, Real-time scheduling);
    where it is not permitted, ``up`` says so and the services run with normal scheduling. On a loaded host it cuts the
    time a service woken by its input waits for a CPU (BENCHMARKS.md, issue 4). Not applied to command nodes."""
    max_grid_cells: int = DEFAULT_MAX_GRID_CELLS
    """The most cells a map grid of this run may have (``messages.DEFAULT_MAX_GRID_CELLS``, 4,000,000: a 100 m x 100 m
    arena at 0.05 m): every process of the run refuses a message with a larger grid before inflating any of it, so a
    forged map cannot make a service inflate hundreds of MB. Raise it for a scene or arena that large (at most
    ``messages.MAX_GRID_CELLS``); ``validate`` says when the profile's own arena is larger (docs/messages.md, Sizes)."""

    def exploration_config(self) -> ExplorationConfig:
        """The exploration settings every service of this profile runs with (raises ConfigError)."""
        return profile_exploration_config(self.exploration, self.services)

    def effective(self) -> dict[str, Any]:
        """The profile as its processes run it, every default filled in (``up --resolved``, Nav2's ``ros2 param dump``):
        each key of the profile, ``exploration`` as every service reads it (``exploration_config``: the MuJoCo LIMO's
        LiDAR mount and box body included), each built-in service's parameters over its ``Params`` defaults and, with
        the MuJoCo LIMO, every one of its ``services.sim.mujoco`` parameters; a service of one's own (``class``,
        ``command``) as given. A real robot's run leaves out ``UNUSED_BY_A_REAL_ROBOT`` (the default scene it would
        show is never loaded: ``REAL_ROBOT_SCENE``). Itself a profile that runs the same."""
        from services import SERVICE_NAMES, is_own_node, params_class  # noqa: PLC0415 - services import zenoh

        data = to_dict(self)
        if runs_a_real_robot(data):
            for key in UNUSED_BY_A_REAL_ROBOT:
                del data[key]
        data["exploration"] = to_dict(self.exploration_config())
        for name, section in self.services.items():
            params_cls = params_class(name) if name in SERVICE_NAMES and not is_own_node(section) else None
            if params_cls is not None:
                data["services"][name] = to_dict(from_dict(params_cls, section or {}, where=f"services.{name}"))
        if self.simulator() == "mujoco":
            data["services"]["sim"]["mujoco"] = self.simulator_settings()
        return data

    def simulator(self) -> str | None:
        """The simulator its sim service runs (``simulator.SIMULATORS``: ``2d`` or ``mujoco``); None without a sim service
        (a real robot's run)."""
        if "sim" not in self.services:
            return None
        from services.sim import BACKENDS, SimParams  # noqa: PLC0415 - services import zenoh

        return BACKENDS[(self.services.get("sim") or {}).get("backend", SimParams.backend)]

    def simulator_settings(self) -> dict[str, Any] | None:
        """Every parameter of the simulator its sim service runs (``simulator.simulator_settings``, as eval records
        them); None without a sim service."""
        name = self.simulator()
        if name is None:
            return None
        from cso_runtime.simulator import simulator_settings  # noqa: PLC0415 - MuJoCo only when asked for

        config = self.exploration_config()
        return simulator_settings(name, config.sensor, config.robot, (self.services.get("sim") or {}).get("mujoco"))

    def awaited_services(self) -> list[str]:
        """The services this robot's episode waits for that the run does not start (``services.dataflow.missing_producers``):
        a policy named under ``without`` or simply not listed (a shared policy server's), a planner left out. ``status``
        says the episode waits while no process serves one of them."""
        from services.dataflow import missing_producers  # noqa: PLC0415 - services import zenoh

        return missing_producers(list(self.services), self.services)

    def left_out_services(self) -> list[str]:
        """The services of this robot that the run leaves to another process: ``without`` and the awaited ones.
        ``status`` lists them from the start (DOWN until one comes up), ``dataflow.md`` draws them as outside; a
        profile that leaves its policy out reads the same whether it says so in ``without`` or not."""
        return list(dict.fromkeys([*self.without, *self.awaited_services()]))

    def own_services(self) -> dict[str, str]:
        """Service name -> the ``module.path:Attribute`` of the class of one's own the run starts under it
        (``services.<name>.class``: beside the built-in services, or in place of one; docs/own-service.md)."""
        from services import own_class_spec  # noqa: PLC0415 - services import zenoh

        return {name: spec for name, section in self.services.items() if (spec := own_class_spec(section)) is not None}

    def command_nodes(self) -> dict[str, list[str]]:
        """Service name -> the argv of the executable the run starts under it (``services.<name>.command``: a node in any
        language, beside the built-in services or in place of one; docs/own-service.md)."""
        from services import command_argv  # noqa: PLC0415 - services import zenoh

        return {name: argv for name, section in self.services.items() if (argv := command_argv(section)) is not None}

    def builtin_params(self, name: str) -> dict[str, Any]:
        """The parameters of the built-in service ``name`` as the profile gives them; empty when the profile does not
        run it, or runs a class or command of its own in its place (whose parameters mean what that one says)."""
        from services import is_own_node  # noqa: PLC0415 - services import zenoh

        section = self.services.get(name)
        return section if isinstance(section, dict) and not is_own_node(section) else {}

    @property
    def scene_label(self) -> str:
        """The scene this profile's run explores, as its log names it: ``profile_scene``."""
        return profile_scene({"scene": self.scene, "services": self.services})

    @property
    def policy_method(self) -> str:
        """The goal selector the policy service runs: its own ``services.policy.method``, else the profile's ``method``."""
        return self.builtin_params("policy").get("method") or self.method

    def scene_ref(self) -> SceneRef:
        """The scene the sim service explores: the first of ``scene`` at ``m_per_px`` (``services.sim.build_simulator``);
        a ConfigError for a spec of none, a SceneError for a bad one."""
        refs = resolve_scenes(self.scene, limit=1, resolution_m=self.m_per_px)
        if not refs:
            raise ConfigError(f"scene {self.scene!r} resolves to no scene")
        return refs[0]

    def scene_plan(self) -> FloorPlan:
        """The plan of ``scene_ref``, loaded once for ``validate`` and ``start_overlap_said`` (what ``up`` checks before
        anything starts), again only where ``scene`` or ``m_per_px`` changed since."""
        key = (self.scene, self.m_per_px)
        loaded = self.__dict__.get("_scene_plan")
        if loaded is None or loaded[0] != key:
            loaded = self.__dict__["_scene_plan"] = (key, self.scene_ref().load())
        return loaded[1]

    def start_overlap_said(self) -> str | None:
        """The simulator's warning of its robot overlapping a wall at the scene's start pose, which its sim service logs
        as it starts, for ``up`` to say before anything starts: the MuJoCo LIMO's box (``scenes.start_overlap_said``,
        ``exploration.robot``'s length and width), the 2D simulator's disc (``simulator.disc_start_overlap_said``,
        ``exploration.robot.disc_radius_m``); None where there is none, or no simulator (a real robot has no scene), on
        the plan ``validate`` loaded (``scene_plan``)."""
        simulator = self.simulator()
        if simulator is None:
            return None
        robot = self.exploration_config().robot
        plan = self.scene_plan()
        if simulator == "mujoco":
            return start_overlap_said(plan, robot.length_m, robot.width_m)
        from cso_runtime.simulator import WallClearance, disc_start_overlap_said  # noqa: PLC0415 - as simulator_settings

        return disc_start_overlap_said(WallClearance(plan, robot.disc_radius_m))

    def check_grid_bound(self) -> None:
        """ConfigError for a ``max_grid_cells`` out of range, or below the cells of the grid the profile itself sets (a
        real robot's arena, ``services.ros2_bridge``; the mapper's explicit grid), which every receiver would refuse.
        A sim's scene is checked as ``validate`` loads it."""
        try:
            check_max_grid_cells(self.max_grid_cells)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        from services.mapper import MapperParams  # noqa: PLC0415 - services import zenoh
        from services.ros2_bridge import Ros2BridgeParams  # noqa: PLC0415

        if "ros2_bridge" in self.services:
            from_dict(Ros2BridgeParams, self.builtin_params("ros2_bridge"), where="services.ros2_bridge").check_grid(self.max_grid_cells)
        if "mapper" in self.services:
            from_dict(MapperParams, self.builtin_params("mapper"), where="services.mapper").check_grid(self.max_grid_cells)

    def validate(self) -> None:
        check_robot_id(self.robot)
        check_seed(self.seed)
        check_bounds("", self, seconds("progress_log_s"))
        check_bounds("", self, {"realtime_priority": REALTIME_PRIORITY_BOUND})
        self.exploration_config()
        from services import SERVICE_NAMES, check_profile_service  # noqa: PLC0415 - services import zenoh
        if not self.services:
            raise ConfigError("a profile must list at least one service")
        for name, params in self.services.items():
            check_profile_service(name, params)
        self.check_grid_bound()
        referees = [name for name in REFEREES if name in self.services]
        if len(referees) > 1:  # a `--set services.sim.PARAM=...` on a robot's profile adds a sim beside its bridge
            raise ConfigError(
                f"services: {' and '.join(referees)} each run the episode (each publishes the robot's scans, odometry and clock, "
                "and the maps would be cleared at every step): a profile has one, the sim in a simulation or the ros2_bridge on a "
                "real robot"
            )
        if "ros2_bridge" in self.services and not self.router.connect:  # its robot would never be heard from
            raise ConfigError("ros2_bridge: give the robot's router (its zenoh-bridge-ros2dds) with --connect, e.g. tcp/ROBOT_IP:7447")
        if self.lockstep and "ros2_bridge" in self.services:
            raise ConfigError("lockstep: a real robot (ros2_bridge) does not wait for the pipeline; its profile runs in real time")
        for name in self.without:
            if name not in SERVICE_NAMES:
                raise ConfigError(f"without: unknown service {with_nearest(name, SERVICE_NAMES, shown=repr(name))}; known: {', '.join(SERVICE_NAMES)}")
            if name in self.services:
                raise ConfigError(f"without: {name} is also in services; a service is either started by the run or left out of it")
            if name in REFEREES:
                raise ConfigError(f"without: {name} owns the episode (its status and end); a run cannot go without it")
        mapper = self.builtin_params("mapper")
        if "sim" in self.services and float(mapper.get("resolution_m") or 0) > 0:
            raise ConfigError(
                "services.mapper.resolution_m: an explicit grid is for a real robot's arena (ros2_bridge); with the sim the mapper "
                "maps the scene's own grid, which the sim measures coverage on"
            )
        sim = self.services.get("sim") or {}
        if self.simulator() == "mujoco":
            # the LiDAR mount against the sensor's, the control period against the physics step, before anything starts
            from cso_runtime.simulator import MountSetting, mujoco_config  # noqa: PLC0415

            exploration = self.exploration_config()
            mount = MountSetting(key="exploration.sensor.mount_x_m", file="the profile", command="up", robot_key="exploration.robot")  # a profile's keys, not eval's
            mujoco_config(sim.get("mujoco"), exploration.sensor, where="services.sim.mujoco", robot=exploration.robot, mount=mount, exploration=exploration)
        if (self.services.get("sim") or {}).get("viewer"):  # its own process checks too; this says so before anything starts
            from robot_sim.viewer import display_problem  # noqa: PLC0415

            problem = display_problem()
            if problem is not None:
                raise ConfigError(f"services.sim.viewer: {problem}")
        if "foxglove_bridge" in self.services:
            from services.foxglove_bridge import INSTALL_HINT, FoxgloveBridgeParams, mcap_path_problem, port_problem  # noqa: PLC0415

            if importlib.util.find_spec("foxglove") is None:
                raise ConfigError(f"services.foxglove_bridge (up --foxglove) needs foxglove-sdk: {INSTALL_HINT}")
            bridge = from_dict(FoxgloveBridgeParams, self.services["foxglove_bridge"] or {}, where="services.foxglove_bridge")
            problem = mcap_path_problem(bridge) or port_problem(bridge)
            if problem is not None:
                raise ConfigError(f"services.foxglove_bridge: {problem}")
        from cso_runtime.policies import LEARNED_METHODS, available_methods, check_method, weights_held_said  # noqa: PLC0415

        check_method(self.method)  # a method of the user's own is imported and built here, as the policy service will
        policy = self.builtin_params("policy")
        method = self.policy_method
        own_policy = "policy" in {*self.own_services(), *self.command_nodes()}  # a policy of the user's own decides as it will: no method of ours runs
        if method != self.method and not own_policy:
            try:
                check_method(method)
            except ConfigError as exc:
                raise ConfigError(f"services.policy.method: {exc}") from None
        if method in LEARNED_METHODS and not own_policy:
            from cso_runtime.learned.weights import (  # noqa: PLC0415
                recorded_input_refusal,
                weights_file_problem,
                weights_file_refusal,
                weights_path,
            )

            if refusal := weights_file_refusal([method]):
                raise ConfigError(f"method {method}: {refusal}")
            sensor = self.exploration_config().sensor
            if method not in available_methods():
                fix = weights_held_said() or f"train it with `cso-runtime train --variant {method}`"
                raise ConfigError(f"method {method}: no weights at {weights_path(method, sensor)}; {fix}")
            if problem := weights_file_problem(method, sensor):
                raise ConfigError(f"method {method}: {problem}")
            # Inputs of another scale than the weights learned on (the entropy window): the policy service refuses them at its
            # start (weights.input_verdict, as registry loads them); the checkpoint's own record says so without torch, before anything starts.
            if refusal := recorded_input_refusal(method, self.exploration_config().frontier, sensor):
                raise ConfigError(f"method {method}: {refusal}")
            device = policy.get("device", "cpu")
            if device != "cpu":  # torch only for a GPU policy
                from cso_runtime.learned.registry import device_problem  # noqa: PLC0415

                if problem := device_problem(device):
                    raise ConfigError(f"services.policy.device: {problem}; run the policy on cpu")
        try:
            self.scene_ref()  # a spec of no scene, or a bad one, is said with or without a sim
            if "sim" in self.services:
                ny, nx = self.scene_plan().geometry.shape  # a missing or unusable plan is a bad configuration: say so before anything starts
                if ny * nx > self.max_grid_cells:  # every map of the run would be refused (``check_grid_bound``)
                    raise ConfigError(
                        f"scene {self.scene}: its grid is {nx} x {ny} = {ny * nx:_} cells, more than max_grid_cells ({self.max_grid_cells:_}): "
                        f"raise max_grid_cells (at most {MAX_GRID_CELLS:_}), or give a coarser --m-per-px for a PNG plan"
                    )
        except SceneError as exc:
            raise ConfigError(f"scene: {exc}") from None
        try:
            TransportConfig(mode="router", listen=self.router.listen, connect=self.router.connect, zenoh_config_file=self.router.zenoh_config).validate()
        except TransportError as exc:
            raise ConfigError(f"router: {exc}") from None


PACKAGED_PROFILES = Path(__file__).resolve().parent / "profiles"
"""The default profiles ship inside the package (package data), so an installed package finds them."""


def runs_a_real_robot(data: dict[str, Any]) -> bool:
    """Whether a profile's data (a run's ``profile.yaml``) runs a real robot: a ``ros2_bridge`` and no ``sim``; also of
    ``status``'s object, whose ``services`` are its run's."""
    services = data.get("services")
    return isinstance(services, dict) and "ros2_bridge" in services and "sim" not in services


def measures_coverage(data: dict[str, Any], said: Any = None) -> bool:
    """Whether a run has a ground truth, its coverage measured: the one answer that ``status``, ``runs``, ``up``'s live
    view and lines, and report.html give (``coverage_pct`` is 0 where it has none: no measure, ``NO_GROUND_TRUTH``).
    What the run itself said (``said``: summary.json's ``meta.coverage_measured``, which ``up`` writes; the referee's
    ``episode_status``'s ``coverage_measured``, which the launcher and ``status`` take first) when it is a bool; else
    whether its profile's data (a run's ``profile.yaml``, a summary's ``meta.profile``, ``status``'s object, whose
    ``services`` are its run's) runs the ``sim``, the one referee that knows the scene: a real robot (``ros2_bridge``)
    and a referee of one's own (a command node) that does not say have none. Data with no services (an eval summary,
    a status with no run) says nothing of a referee: its figures stand."""
    if isinstance(said, bool):
        return said
    services = data.get("services")
    return not isinstance(services, dict) or "sim" in services


def profile_scene(data: dict[str, Any]) -> str:
    """The scene a profile's data explores: its ``scene``, else the default one; for a real robot's,
    ``REAL_ROBOT_SCENE``."""
    return REAL_ROBOT_SCENE if runs_a_real_robot(data) else str(data.get("scene") or Profile.scene)


def profile_exploration_config(exploration: Any, services: Any, where: str = "exploration") -> ExplorationConfig:
    """A profile's ``exploration`` over the defaults, as every one of its services runs it: where its sim is the
    MuJoCo LIMO, with that robot's LiDAR mount (0.103 m ahead) and box body unless the profile sets them, as
    ``eval --sim mujoco`` does. One place for the services and the launcher's checks, which used to check
    ``services.sim.mujoco`` against a sensor at 0 m while the services ran it at 0.103 m."""
    config = from_dict(ExplorationConfig, exploration or {}, where=where)
    sim = services.get("sim") if isinstance(services, dict) else None
    if isinstance(sim, dict) and sim.get("backend") == "mujoco":
        with_mujoco_limo_defaults(config, exploration)
    return config


def profile_field_types() -> dict[str, Any]:
    """The type of each key of a profile by dotted key (``robot``, ``router.zenoh_config``, ``exploration.planner.body``,
    ``services.foxglove_bridge.mcap_path``): ``config.field_types`` of ``Profile``, of ``ExplorationConfig`` under
    ``exploration`` and of each built-in service's ``Params`` under ``services.NAME``."""
    from services import SERVICE_NAMES, params_class  # noqa: PLC0415 - services import zenoh

    types = {**field_types(Profile), **field_types(ExplorationConfig, "exploration")}
    for name in SERVICE_NAMES:
        if (cls := params_class(name)) is not None:
            types.update(field_types(cls, f"services.{name}"))
    return types


def profile_key_sections(mujoco: bool = True) -> dict[str, set[str]]:
    """Each mapping of a profile that takes a fixed set of keys (``""`` for the top level, ``exploration.planner``,
    ``services.sim.mujoco``...) -> those keys: its dataclass's fields, a built-in service's ``Params``. ``mujoco``: with
    ``services.sim.mujoco`` (robot_sim imports MuJoCo, which a real robot's profile need not)."""
    from services import SERVICE_NAMES, params_class  # noqa: PLC0415 - services import zenoh

    sections = {**key_sections(Profile), **key_sections(ExplorationConfig, "exploration")}
    sections["services"] = set(SERVICE_NAMES)
    sections.update({f"services.{name}": key_sections(cls)[""] for name in SERVICE_NAMES if (cls := params_class(name)) is not None})
    if mujoco:
        from robot_sim.config import MujocoSimConfig  # noqa: PLC0415 - robot_sim imports MuJoCo

        sections["services.sim.mujoco"] = key_sections(MujocoSimConfig)[""]
    return sections


def misplaced_key(data: dict[str, Any]) -> str | None:
    """What is wrong with each key of a profile's mapping that is no key of its section but one of another
    (``services.planner.lookahead_m``, Nav2's place for a controller's parameter, is ``exploration.planner``'s;
    ``frontier:`` at the top level is ``exploration.frontier`` or ``services.frontier``): ``wrong_section``'s words,
    a service of one's own left alone (any name, any keys); None when none is. A ``robot:`` mapping is the robot's body
    given where its id goes."""
    from services import is_own_node  # noqa: PLC0415 - services import zenoh

    if isinstance(data.get("robot"), dict):
        return "robot: the robot id (a string: cso/<robot>/... keys); the robot's body and limits are exploration.robot"
    sections = profile_key_sections(mujoco=bool(mapping_at(data, "services.sim.mujoco")))
    unknown = [
        (path, key)
        for path, key in unknown_keys(data, sections)
        if not (path.startswith("services.") and is_own_node(mapping_at(data, path)))
        and not (path == "services" and is_own_node(data["services"][key]))  # a service of one's own, by any name
    ]
    if unknown and "services.sim.mujoco" not in sections:
        sections = profile_key_sections()  # where a misplaced key may belong: the MuJoCo LIMO's too
    return wrong_section(unknown, sections, data)


def unknown_top_level_keys(data: dict[str, Any]) -> str | None:
    """What is wrong with each top-level key of profile ``data`` that ``Profile`` does not take, in ``up``'s words
    (``misplaced_key``'s ``frontier (did you mean exploration.frontier or services.frontier?)``, else ``from_dict``'s
    ``mehtod (did you mean method?)``) and naming every one; None when there is none. A service started by hand reads
    the keys it knows one by one and warns of these (``services.common.load_profile_for_service``): refusing them, as
    ``up`` does, would stop the files users run by hand."""
    names = key_sections(Profile)[""]
    unknown = [("", str(key)) for key in data if key not in names]  # str: a YAML key may be a number
    if not unknown:
        return None
    misplaced = wrong_section(unknown, profile_key_sections(mujoco=False), data)
    return misplaced or unknown_keys_said([key for _, key in unknown], names)


def profile_search_path() -> list[Path]:
    """Where ``--profile NAME`` is looked up: the user's ``./configs/profiles`` (overrides), then the
    profiles shipped with the package."""
    return [Path("configs") / "profiles", PACKAGED_PROFILES]


def profile_names() -> list[str]:
    """The profiles ``--profile NAME`` finds (``profile_search_path``)."""
    return sorted({f.stem for folder in profile_search_path() if folder.is_dir() for f in folder.glob("*.y*ml")})


def find_profile(name_or_path: str) -> Path:
    """The file of ``--profile``: a .yaml path as given, else ``NAME.yaml`` on ``profile_search_path``."""
    p = Path(name_or_path)
    known = ", ".join(profile_names()) or "none"
    if p.suffix in (".yaml", ".yml"):  # a path, never a name: a missing one is a missing file
        if p.is_file():
            return p
        raise ConfigError(f"profile file not found: {name_or_path} (a .yaml path; known profiles by name: {known})")
    for folder in profile_search_path():
        for ext in (".yaml", ".yml"):
            cand = folder / f"{name_or_path}{ext}"
            if cand.is_file():
                return cand
    said = with_nearest(name_or_path, profile_names(), shown=repr(name_or_path))
    raise ConfigError(f"unknown profile {said}; known profiles: {known} (or give a .yaml path)")


def load_profile(
    name_or_path: str,
    overrides: dict[str, Any] | None = None,
    connect: list[str] | None = None,
    namespace: str | None = None,
    settings: dict[str, Any] | None = None,
    foxglove: bool = False,
    without: list[str] | None = None,
    zenoh_config: str | None = None,
) -> tuple[Profile, dict[str, Any]]:
    """Load, apply CLI overrides (``None`` values ignored) and validate; returns the profile and its data.

    ``connect``: endpoints appended to ``router.connect`` (the embedded router joins them, e.g. the
    robot's zenoh-bridge-ros2dds on port 7447); ``namespace``: ``services.ros2_bridge.namespace``;
    ``settings``: dotted keys set last (``up --set services.sim.real_time_factor=4``), validated like the file;
    ``foxglove``: add the ``foxglove_bridge`` service (``up --foxglove``) unless the profile has it;
    ``without``: services of the profile left out of the run (``up --without``), moved from ``services`` to the
    profile's ``without`` list, so that the run's ``profile.yaml`` says what ran and what it expects from elsewhere;
    ``zenoh_config``: ``router.zenoh_config`` (``up --zenoh-config``); without either, ``$CSO_ZENOH_CONFIG``, so that
    the run's ``profile.yaml`` names the file every one of its processes used (an absolute path).
    """
    path = find_profile(name_or_path)
    data = load_yaml(path)
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    flag_of = {k: (("--lockstep" if v else "--real-time") if k == "lockstep" else f"--{k} {v}") for k, v in given.items()}
    # A flag and a --set of the same key with another value: one of them would take over the other in silence.
    flag_keys = {k: (flag_of[k], v) for k, v in given.items()}
    if namespace is not None:
        flag_keys["services.ros2_bridge.namespace"] = (f"--namespace {namespace}", namespace)
    if zenoh_config is not None:
        flag_keys["router.zenoh_config"] = (f"--zenoh-config {zenoh_config}", zenoh_config)
    types = profile_field_types()
    paths: dict[str, typing.Callable[[str], bool]] = {"scene": spec_names_a_path, "router.zenoh_config": bool}  # ./plans and plans: one folder
    refuse_a_flag_and_a_setting_that_disagree(flag_keys, settings or {}, {k: types.get(k, str) for k in flag_keys}, paths)
    if settings:  # `--set robot=1` alone: the same hint as beside --robot 1, a section's key too

        def takes(texts: dict[str, Any]) -> object:  # the profile with those values as text (no hint again): the hint only where it is taken
            return load_profile(name_or_path, overrides, connect, namespace, texts, foxglove, without, zenoh_config)

        refuse_a_setting_read_as_another_type(settings, types, takes)
    data.update(given)
    for key, value in (settings or {}).items():
        set_dotted(data, key, value)
    without = list(dict.fromkeys(without or []))  # repeated names: once
    # An error names the profile and the flags that changed it: a bad --scene is the flag's fault, not the file's, and a
    # section a --set broke is the --set's where --connect, --foxglove or --without read it.
    flags = list(flag_of.values()) + [f"--connect {endpoint}" for endpoint in connect or []]
    flags += [f"--namespace {namespace}"] * (namespace is not None) + [f"--zenoh-config {zenoh_config}"] * (zenoh_config is not None)
    flags += [set_said(settings or {}, k) for k in settings or {}] + ["--foxglove"] * foxglove + [f"--without {n}" for n in without]
    where = f"{path} with {' '.join(flags)}" if flags else str(path)
    if connect:
        router = data.get("router") or {}
        if not isinstance(router, dict):
            raise ConfigError(f"{where}: router must be a mapping")
        earlier = router.get("connect")  # a list field's one value is its list (config._convert), not its letters
        data["router"] = {**router, "connect": [*([] if earlier is None else field_value(earlier, list[str], f"{where}: router.connect")), *connect]}
    if namespace is not None:
        services = data.get("services") or {}
        if not isinstance(services, dict) or "ros2_bridge" not in services:
            raise ConfigError(f"--namespace needs a profile with the ros2_bridge service (e.g. limo-ros2); {path} has none")
        services["ros2_bridge"] = {**(services["ros2_bridge"] or {}), "namespace": namespace}
    if foxglove:
        services = data.get("services") or {}
        if not isinstance(services, dict):
            raise ConfigError(f"{where}: services must be a mapping")
        data["services"] = {**services, "foxglove_bridge": services.get("foxglove_bridge") or {}}
    if without:
        leave_out(data, without, path, foxglove, where)
    set_zenoh_config(data, path, zenoh_config, where)
    scene = data.get("scene")
    if isinstance(scene, str) and spec_names_a_path(scene):
        beside = path.parent / scene  # a file's own relative scene may also be beside the file (as in compose files)
        if "scene" not in given and not Path(scene).exists() and not Path(scene).is_absolute() and beside.exists():
            scene = str(beside)
        if Path(scene).exists():
            data["scene"] = str(Path(scene).resolve())  # so the run's copy of the profile works from any folder
    if "scene" in given and runs_a_real_robot(data):
        raise ConfigError(
            f"--scene {given['scene']}: profile {path} runs a real robot (ros2_bridge) and no simulator, so there is no scene to "
            "load; the robot explores the room it is in"
        )
    data.setdefault("name", path.stem)
    if (problem := misplaced_key(data)) is not None:
        raise ConfigError(f"{where}: {problem}")
    profile = from_dict(Profile, data, where=where)
    return profile, data


def set_zenoh_config(data: dict[str, Any], path: Path, zenoh_config: str | None, where: str | None = None) -> None:
    """``router.zenoh_config`` of the profile mapping from ``zenoh_config`` (a flag), else the file's own (found
    beside the file, as a scene), else ``$CSO_ZENOH_CONFIG``; made absolute, so that the run's copy of the
    profile, and the services started from another folder, find it. ``where``: the profile and the flags that changed
    it, as an error names them (``path``'s own name without)."""
    where = where or str(path)
    router = data.get("router") or {}
    if not isinstance(router, dict):
        raise ConfigError(f"{where}: router must be a mapping")
    given = zenoh_config or router.get("zenoh_config") or os.environ.get(ZENOH_CONFIG_ENV, "")
    if not given:
        return
    if not isinstance(given, str):
        raise ConfigError(f"{where}: router.zenoh_config must be a file path (text), got {given!r}")
    beside = path.parent / given
    if zenoh_config is None and router.get("zenoh_config") and not Path(given).exists() and beside.exists():
        given = str(beside)
    data["router"] = {**router, "zenoh_config": str(Path(given).absolute())}


def leave_out(data: dict[str, Any], names: list[str], path: Path, foxglove: bool = False, where: str | None = None) -> None:
    """Move ``names`` from the profile mapping's ``services`` to its ``without`` list (``up --without``), in the
    profile's order (a service of the profile's own that stands for no built-in one is only dropped); a ConfigError (nothing started) for a name that is no service, one the profile does not
    have, a referee (the episode cannot run without it) or the ``foxglove_bridge`` that ``--foxglove`` asks for.
    ``where``: the profile and the flags that changed it, as an error of its keys names them (``path`` alone without)."""
    from services import SERVICE_NAMES  # noqa: PLC0415 - services import zenoh

    where = where or str(path)
    services = data.get("services") or {}
    if not isinstance(services, dict):
        raise ConfigError(f"{where}: services must be a mapping")
    for name in names:
        if name not in SERVICE_NAMES and name not in services:
            own = [n for n in services if n not in SERVICE_NAMES]
            raise ConfigError(
                f"--without {with_nearest(name, [*SERVICE_NAMES, *own])}: no such service; known: {', '.join(SERVICE_NAMES)}, and the profile's own: {', '.join(own) or 'none'}"
            )
        if name in REFEREES:
            raise ConfigError(f"--without {name}: {name} owns the episode (its status and end); a run cannot go without it")
        if name == "foxglove_bridge" and foxglove:
            raise ConfigError("--without foxglove_bridge and --foxglove: give one or the other")
        if name not in services:
            raise ConfigError(f"--without {name}: profile {path} has no {name} service (it has {', '.join(services) or 'none'})")
    earlier = field_value(data.get("without") or [], list[str], f"{where}: without")  # one name is the list of it (config._convert)
    # A service of the profile's own that no built-in one stands for is simply not run: nothing else waits for it, and
    # the run's profile.yaml has no class left to draw it by; a built-in one is left to another process (``without``).
    data["without"] = [*earlier, *(n for n in services if n in names and n in SERVICE_NAMES)]
    data["services"] = {n: p for n, p in services.items() if n not in names}
