"""``cso-runtime doctor``: is this machine ready to run, as ``ros2 doctor`` asks of a ROS install.

Each check does the real thing on a small scale and says what it found: the libraries import (with their
versions, and whether torch sees a GPU), two Zenoh sessions exchange a message on loopback with multicast
scouting off (what ``up`` needs), the MuJoCo LIMO is built in a small scene and driven for a step, a Foxglove
server answers a WebSocket handshake (when that optional extra is installed), every shipped
weights file loads, every packaged profile validates, and the runs folder can be written. A failed check names
its error, and the command exits 1, so a fresh machine's problem is found before a long run.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import importlib.util
import logging
import os
import platform
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cso_runtime.config import SensorConfig


@dataclass
class CheckResult:
    """One ``doctor`` check's outcome: what it found, or its error, and how long it took (``seconds``)."""

    name: str
    ok: bool
    detail: str
    seconds: float

    def as_dict(self) -> dict[str, object]:
        return {"check": self.name, "ok": self.ok, "detail": self.detail, "seconds": round(self.seconds, 3)}


LIBRARIES = (
    ("eclipse-zenoh", "zenoh"),
    ("torch", "torch"),
    ("mujoco", "mujoco"),
    ("scikit-fmm", "skfmm"),
    ("numpy", "numpy"),
    ("msgpack", "msgpack"),
    ("typer", "typer"),
    ("mcap", "mcap"),
    ("rosbags", "rosbags"),
)
"""(distribution, module) of the libraries the runtime imports."""
OPTIONAL_LIBRARIES = (
    ("foxglove-sdk", "up --foxglove"),
    ("tensorboardX", "train --tensorboard"),
)
"""(distribution, what needs it) of the extras: reported, never a failure."""


def cpu_name() -> str:
    """The processor's model name, as ``lscpu`` says it (for the record of a training run or a benchmark)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_facts() -> dict[str, object]:
    """What a measurement was taken on: processor, CPUs, Python and the numeric libraries' versions."""
    facts: dict[str, object] = {"cpu": cpu_name(), "cpus": os.cpu_count(), "python": platform.python_version()}
    for dist, _ in LIBRARIES:
        try:
            facts[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            continue
    return facts


def check_python() -> str:
    """The cso-runtime version and the Python and platform it runs on."""
    from cso_runtime import __version__  # noqa: PLC0415

    return f"cso-runtime {__version__} on Python {platform.python_version()} ({platform.machine()}, {platform.system()})"


def check_libraries() -> str:
    """The required libraries import (with their versions), whether torch sees a GPU, and which optional extras are
    installed; raises naming every required one that does not import."""
    found, missing = [], []
    for dist, module in LIBRARIES:
        try:
            importlib.import_module(module)
            found.append(f"{dist} {importlib.metadata.version(dist)}")
        except Exception as exc:  # noqa: BLE001 - an import that fails in any way is the finding
            missing.append(f"{dist} ({type(exc).__name__}: {exc})")
    if missing:
        raise RuntimeError("cannot import " + "; ".join(missing))
    import torch  # noqa: PLC0415

    gpu = f"CUDA {torch.version.cuda}, {torch.cuda.device_count()} GPU(s)" if torch.cuda.is_available() else "CPU only"
    optional = []
    for dist, needed_by in OPTIONAL_LIBRARIES:
        try:
            optional.append(f"{dist} {importlib.metadata.version(dist)}")
        except importlib.metadata.PackageNotFoundError:
            optional.append(f"{dist} not installed ({needed_by} needs it)")
    return ", ".join(found) + f"; torch: {gpu}; optional: " + ", ".join(optional)


def check_zenoh(timeout_s: float = 5.0) -> str:
    """A router and a client on loopback (multicast off, as ``up``'s), one message from one to the other."""
    from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session  # noqa: PLC0415

    endpoint = loopback_endpoint(free_tcp_port())
    got = threading.Event()
    t0 = time.monotonic()
    with open_session(TransportConfig(mode="router", listen=[endpoint])) as router, open_session(TransportConfig(mode="client", connect=[endpoint])) as client:
        sub = router.declare_subscriber("cso/doctor/ping", lambda _sample: got.set())
        deadline = time.monotonic() + timeout_s
        while not got.is_set() and time.monotonic() < deadline:
            client.put("cso/doctor/ping", b"ping")
            got.wait(0.05)
        sub.undeclare()
    if not got.is_set():
        raise RuntimeError(f"no message crossed loopback {endpoint} within {timeout_s:.0f} s (a firewall on 127.0.0.1?)")
    return f"a message from a client to a router on {endpoint} in {1000 * (time.monotonic() - t0):.0f} ms (sessions included)"


def check_mujoco() -> str:
    """The MuJoCo LIMO in a small generated scene: built, scanned, driven one step."""
    from cso_runtime.config import ExplorationConfig  # noqa: PLC0415
    from cso_runtime.geometry import VelocityCommand  # noqa: PLC0415
    from cso_runtime.scene_generator import generate_floor_plan  # noqa: PLC0415
    from cso_runtime.simulator import make_simulator  # noqa: PLC0415
    from robot_sim.config import limo_sensor  # noqa: PLC0415 - robot_sim imports MuJoCo

    sensor = dataclasses.replace(limo_sensor(), fov_deg=180.0)  # mounted where the MuJoCo model carries it, as eval --sim mujoco
    sim = make_simulator("mujoco", generate_floor_plan("small", 0), sensor, ExplorationConfig().robot, seed=0)
    sim.reset(0)
    before = sim.true_pose()
    sim.step(VelocityCommand(0.3, 0.0))
    moved_m = float(((sim.true_pose().x_m - before.x_m) ** 2 + (sim.true_pose().y_m - before.y_m) ** 2) ** 0.5)
    beams = int((sim.scan().ranges_m < float("inf")).sum())
    if not moved_m > 0:
        raise RuntimeError("the LIMO did not move on a forward command")
    from robot_sim.viewer import display_problem  # noqa: PLC0415

    problem = display_problem()  # not a failure: the viewer window is optional
    window = "a viewer window can open here" if problem is None else f"no viewer window here, {problem}"
    return f"LIMO built and driven: {moved_m * 100:.1f} cm in one 0.25 s step, {beams} LiDAR returns; {window}"


def check_foxglove() -> str:
    """``up --foxglove``'s server on a free loopback port answers a Foxglove WebSocket handshake (an optional extra:
    not installed is said, not failed)."""
    if importlib.util.find_spec("foxglove") is None:
        return "foxglove-sdk not installed (optional: up --foxglove needs it)"
    import foxglove  # noqa: PLC0415

    from services.foxglove_bridge import websocket_handshake  # noqa: PLC0415

    sdk_log = logging.getLogger("foxglove")
    level = sdk_log.level
    sdk_log.setLevel(logging.WARNING)  # its server's start and stop lines would land in the report
    try:
        server = foxglove.start_server(name="cso-runtime doctor", host="127.0.0.1", port=0, context=foxglove.Context())
        port = server.port
        try:
            reply = websocket_handshake("127.0.0.1", port)
        finally:
            server.stop()
    finally:
        sdk_log.setLevel(level)
    if not reply.startswith(b"HTTP/1.1 101"):
        raise RuntimeError(f"the Foxglove server on 127.0.0.1:{port} refused the WebSocket upgrade: {reply[:80]!r}")
    return f"a Foxglove WebSocket server answered on 127.0.0.1:{port}"


DEFAULT_CONFIG = "the default config's"
"""Whose frontier settings ``doctor`` compares weights with (``weights.input_verdict``'s ``against``): it has no run, so
``FrontierConfig``'s defaults, what ``eval`` and the profiles run without a ``--set`` (configs/eval.yaml's)."""


def _weights_files() -> list[tuple[str, SensorConfig, Path]]:
    """(method, sensor, file) of each weights file there is, once per file: for eval's 360-degree sensor and the LIMO's
    180 (``up --profile sim``)."""
    from cso_runtime.config import SensorConfig  # noqa: PLC0415
    from cso_runtime.learned.weights import weights_path  # noqa: PLC0415
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415

    found: list[tuple[str, SensorConfig, Path]] = []
    for fov_deg in (360.0, 180.0):  # eval's --lidar-fov 360, and the LIMO's 180 of `up --profile sim`
        sensor = SensorConfig.preset("lidar", fov_deg=fov_deg)
        for method in LEARNED_METHODS:
            path = weights_path(method, sensor)
            if path.is_file() and path.name not in {p.name for _, _, p in found}:
                found.append((method, sensor, path))
    return found


def check_weights() -> str:
    """Every shipped weights file of the learned methods loads, for eval's 360-degree sensor and the LIMO's 180; raises
    when the ``cso`` file ``up --profile sim`` needs is missing, or a weights file or folder the environment gives is
    not there (``given_weights_problem``: named as given, not as the shipped folder's missing file). Weights trained with
    other frontier settings than the default config's (``CSO_WEIGHTS_DIR`` of a ``train --set entropy_window_m=4``) load
    as a run with their settings loads them, and are noted with the ``--set`` that runs them, not failed: doctor has no run
    whose settings they would contradict."""
    from cso_runtime.config import FrontierConfig, SensorConfig  # noqa: PLC0415
    from cso_runtime.learned.registry import check_weights as load  # noqa: PLC0415
    from cso_runtime.learned.weights import given_weights_problem, input_verdict, recorded_frontier, weights_path  # noqa: PLC0415

    if problem := given_weights_problem():
        raise RuntimeError(problem)
    loaded: list[str] = []
    notes: list[str] = []
    for method, sensor, path in _weights_files():
        trained = recorded_frontier(path)  # None: no record read without torch; the load compares with the defaults
        load(method, sensor=sensor, frontier=trained)
        loaded.append(path.name)
        if trained is not None:
            verdict = input_verdict(method, path, trained, FrontierConfig(), against=DEFAULT_CONFIG)
            notes += [*verdict.refused, *verdict.warned]
    if not weights_path("cso", SensorConfig.preset("lidar", fov_deg=180.0)).is_file():
        raise RuntimeError("no cso weights (the default method of `up --profile sim`)")
    note = f"; note, not a failure (doctor compares with the default config; a run given the --set said uses them as trained): {'; '.join(notes)}" if notes else ""
    return f"{len(loaded)} weights files load ({weights_path('cso').parent}): {', '.join(loaded)}{note}"


def _trained_windows() -> list[float]:
    """The entropy windows other than the default config's that weights files were trained with (``recorded_frontier``)."""
    from cso_runtime.config import FrontierConfig  # noqa: PLC0415
    from cso_runtime.learned.weights import recorded_frontier  # noqa: PLC0415

    default = FrontierConfig().entropy_window_m
    windows = {f.entropy_window_m for _, _, path in _weights_files() if (f := recorded_frontier(path)) is not None}
    return sorted(w for w in windows if w != default)


def check_profiles() -> str:
    """Every profile loads (yours in ./configs/profiles/ and the packaged ones); each one that does not is named
    with its reason. Those stopped by the weights the environment names (``given_weights_problem``, the weights
    row's failure) are named together and the reason said once, not once per profile. Those that load with the
    entropy window their method's weights were trained with (``--set exploration.frontier.entropy_window_m=4``, the
    weights row's note) are noted with it, not failed."""
    from cso_runtime.config import ConfigError, setting_text  # noqa: PLC0415
    from cso_runtime.learned.weights import given_weights_problem  # noqa: PLC0415
    from cso_runtime.run_profile import load_profile, profile_names  # noqa: PLC0415

    names = profile_names()
    problem = given_weights_problem()
    windows = None if problem else _trained_windows()
    stand_in = "tcp/127.0.0.1:7447"  # a profile that joins a robot's router gets one: no flag of the user's to name
    bad, by_weights, by_window = [], [], {}
    for name in names:
        try:
            load_profile(name, {}, connect=[stand_in])
        except ConfigError as exc:
            if problem and problem in str(exc):
                by_weights.append(name)
            elif (window := _loads_with_a_window(name, windows or [], stand_in, str(exc))) is not None:
                by_window[name] = window
            else:
                bad.append(str(exc).replace(f" with --connect {stand_in}", "", 1))
    if bad or by_weights:
        said = ([f"{', '.join(by_weights)}: their method's weights: {problem}"] if by_weights else []) + bad
        raise ValueError(f"{len(bad) + len(by_weights)} of {len(names)} profiles do not load: " + "; ".join(said))
    noted = "".join(
        f"; {', '.join(n for n, w in by_window.items() if w == window)} run their method's weights (the weights row) with"
        f" --set exploration.frontier.entropy_window_m={setting_text(window)}, not with their own window (not a failure)"
        for window in sorted(set(by_window.values()))
    )
    return f"{len(names)} profiles valid: {', '.join(names)}{noted}"


def _loads_with_a_window(name: str, windows: list[float], stand_in: str, why: str) -> float | None:
    """The first of ``windows`` (``_trained_windows``) with which profile ``name`` loads, of those its error ``why`` is the
    refusal of (weights trained with it: ``weights.trained_with_said``); None for none. Any other error is the
    profile's own, which a window given over its own would hide (an ``entropy_window_m`` of -1, say)."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.learned.weights import trained_with_said  # noqa: PLC0415
    from cso_runtime.run_profile import load_profile  # noqa: PLC0415

    for window in windows:
        if trained_with_said("entropy_window_m", window) not in why:
            continue
        try:
            load_profile(name, {}, connect=[stand_in], settings={"exploration.frontier.entropy_window_m": window})
        except ConfigError:
            continue
        return window
    return None


def check_runs_folder(runs_dir: Path) -> str:
    """A file can be made in the runs folder, or the folder in its nearest existing parent (made by ``up``, not here)."""
    runs_dir = runs_dir.resolve()
    if runs_dir.exists() and not runs_dir.is_dir():
        raise RuntimeError(f"{runs_dir} is a file, not a folder: `up` could not write its runs there")
    if runs_dir.is_dir():
        with tempfile.NamedTemporaryFile(dir=runs_dir, prefix=".doctor-"):
            pass
        return f"{runs_dir} is writable"
    parent = next(p for p in runs_dir.parents if p.exists())
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise RuntimeError(f"{runs_dir} does not exist and {parent} cannot hold it")
    return f"{runs_dir} will be made in {parent} (writable)"


def check_realtime() -> str:
    """Whether a profile's ``realtime_priority`` can be set here (an option: not permitted is said, not failed)."""
    from cso_runtime.processes import REALTIME_HOWTO, realtime_refusal  # noqa: PLC0415

    why = realtime_refusal(1)
    if why is None:
        return "permitted: a profile's realtime_priority runs its services under SCHED_FIFO"
    return f"{why}: a profile's realtime_priority would run with normal scheduling (optional; {REALTIME_HOWTO})"


def checks(runs_dir: Path) -> list[tuple[str, Callable[[], str]]]:
    """``doctor``'s checks in the order it runs them, as (name, check); a check returns what it found or raises."""
    return [
        ("python", check_python),
        ("libraries", check_libraries),
        ("zenoh loopback", check_zenoh),
        ("mujoco LIMO", check_mujoco),
        ("foxglove bridge", check_foxglove),
        ("weights", check_weights),
        ("profiles", check_profiles),
        ("real-time scheduling", check_realtime),
        ("runs folder", lambda: check_runs_folder(runs_dir)),
    ]


def run_checks(runs_dir: Path, only: list[tuple[str, Callable[[], str]]] | None = None) -> list[CheckResult]:
    """Every check, each on its own: one that fails says why and the others still run."""
    results = []
    for name, fn in only if only is not None else checks(runs_dir):
        t0 = time.monotonic()
        try:
            detail, ok = fn(), True
        except Exception as exc:  # noqa: BLE001 - the check's finding, whatever failed
            last = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
            where = f" ({Path(last.filename).name}:{last.lineno})" if last else ""
            detail, ok = f"{type(exc).__name__}: {exc}{where}", False
        results.append(CheckResult(name, ok, detail, time.monotonic() - t0))
    return results
