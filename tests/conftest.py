"""Shared test helpers: small synthetic floor plans with known geometry."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import settings
from typer.testing import CliRunner

# Property tests draw the same examples on every run and machine (CI's failure is the one a developer gets), and
# keep no example database in the checkout: a derandomized profile, the default unless HYPOTHESIS_PROFILE names another.
settings.register_profile("deterministic", derandomize=True, database=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

from cso_runtime.geometry import Pose2D
from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV
from cso_runtime.messages import DEFAULT_MAX_GRID_CELLS, set_max_grid_cells
from cso_runtime.scenes import FloorPlan
from cso_runtime.transport import ZENOH_CONFIG_ENV
from services.common import TRACE_DIR_ENV

HANG_DEADLINE_S = 120.0
"""A bound on a wait for real processes (a helper's start or answer, a service's step) that only ends a hang: CI's
2-core host, loaded by the other test worker and its services, has been seen to take tens of seconds for what takes
milliseconds idle. Tests wait on the real condition up to this, never on a deadline a loaded host can outrun."""


def unset_weights_env(monkeypatch: pytest.MonkeyPatch) -> None:
    """No weights folder nor file in the environment (``CSO_WEIGHTS_DIR``, ``CSO_WEIGHTS_FILE``), each put back as it
    was after the test: ``--weights`` (``use_weights``) sets one in this process."""
    from cso_runtime.learned.weights import WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV

    for name in (WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV):
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)


# The variables a user may export that change what eval, up, train and the services do (weights, Zenoh config,
# profiling and tracing dumps): unset for every test, so the suite runs the same on a developer's shell as in CI.
# A test that needs one sets it with monkeypatch; child processes inherit the test's environment.
USER_ENV_VARIABLES = (WEIGHTS_DIR_ENV, WEIGHTS_FILE_ENV, ZENOH_CONFIG_ENV, TRACE_DIR_ENV, "CSO_PROFILE_DIR")


@pytest.fixture(autouse=True)
def no_user_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each of ``USER_ENV_VARIABLES`` unset for the test, put back after it."""
    for name in USER_ENV_VARIABLES:
        monkeypatch.delenv(name, raising=False)


@pytest.fixture(autouse=True)
def default_grid_bound() -> Iterator[None]:
    """Each test starts and ends with the default ``max_grid_cells``: a command run in the test's process (CliRunner,
    a Launcher of a profile that raises it) sets the bound for the whole process."""
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)
    yield
    set_max_grid_cells(DEFAULT_MAX_GRID_CELLS)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@pytest.fixture(autouse=True)
def own_stop_handlers() -> Iterator[None]:
    """Each test ends with the stop signals' handlers it started with. A command run in the test's process (CliRunner,
    ``cli.main``) installs its own (``cli.interrupt_on_sigterm``), and they stayed for the rest of the worker's tests:
    ``train``'s bounds its stop, so a later test that sends its own process SIGINT (Ctrl-C as ``up --detach`` waits)
    armed a watch that ended the pytest worker 60 s later (``processes.end_overdue_stop``: ``os._exit(130)``), in the
    middle of whatever test then ran ("node down: Not properly terminated", in three of four CI runs)."""
    kept = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    yield
    for sig, handler in kept.items():
        if handler is not None and signal.getsignal(sig) is not handler:
            signal.signal(sig, handler)


class TerminalFile(io.StringIO):
    """A fake terminal for rich's console: its text kept as a StringIO's, and ``isatty()`` true, as
    ``live_view.writes_to_a_terminal`` tells a terminal (``force_terminal`` alone no longer makes one: a file under
    ``FORCE_COLOR`` is laid out as a file)."""

    def isatty(self) -> bool:
        return True


class TerminalRunner(CliRunner):
    """Typer's ``CliRunner`` whose stdout and stderr are a terminal (``isatty()`` true, ``live_view.writes_to_a_terminal``),
    for a command's output as on a terminal; give ``TTY_COMPATIBLE``/``FORCE_COLOR`` too for rich's own idea of one."""

    @contextlib.contextmanager
    def isolation(self, *args: Any, **kwargs: Any) -> Iterator[Any]:
        with super().isolation(*args, **kwargs) as streams:
            for stream in (sys.stdout, sys.stderr):
                stream.isatty = lambda: True  # type: ignore[method-assign]
            yield streams


def super_large_summary() -> dict:
    """``eval``'s summary of greedy-dist and greedy-info on three super-large plans, 20 steps each: a Table 1 whose
    spreads ("3.3902 ± 0.0100") make it wider than 80 columns, for the tests of how its console table is written."""
    from cso_runtime.evaluation import summarize

    def row(method: str, name: str, eff: float) -> dict:
        return {"method": method, "map": name, "seed": 0, "traversable_area_m2": 514.56, "scale": "super_large", "terminated_by": "max_steps",
                "explored_area_m2": 67.6, "coverage_pct": 13.37, "steps": 20.0, "efficiency_m2_per_step": eff, "path_length_m": 0.2,
                "decision_ms_p50": 8.2, "decision_ms_p99": 9.1}

    rows = [row(m, n, e + i / 100) for m, e in (("greedy-dist", 3.3802), ("greedy-info", 3.4101)) for i, n in enumerate(("img_1", "img_2", "img_3"))]
    return summarize(rows, [], ["greedy-dist", "greedy-info"], {})


def box_room(width_m: float = 4.0, height_m: float = 3.0, resolution_m: float = 0.05, wall_cells: int = 2) -> FloorPlan:
    """A closed rectangular room: free interior of width x height metres, walls all round."""
    nx = int(round(width_m / resolution_m)) + 2 * wall_cells
    ny = int(round(height_m / resolution_m)) + 2 * wall_cells
    free = np.zeros((ny, nx), dtype=bool)
    free[wall_cells:-wall_cells, wall_cells:-wall_cells] = True
    start = Pose2D((wall_cells * resolution_m) + width_m / 2, (wall_cells * resolution_m) + height_m / 2, 0.0)
    return FloorPlan("box", free, resolution_m, start)


def l_shaped(resolution_m: float = 0.1) -> FloorPlan:
    """An L-shaped corridor 1.2 m wide: east along the bottom, then north. Start at the west end."""
    free = np.zeros((80, 80), dtype=bool)  # 8 x 8 m
    free[2:14, 2:78] = True  # bottom leg: y 0.2-1.4 m
    free[2:78, 64:76] = True  # right leg: x 6.4-7.6 m
    return FloorPlan("l_shape", free, resolution_m, Pose2D(0.8, 0.8, 0.0))


def two_rooms(resolution_m: float = 0.1) -> FloorPlan:
    """Two 3 x 3 m rooms joined by a 1 m door."""
    free = np.zeros((34, 66), dtype=bool)
    free[2:32, 2:32] = True
    free[2:32, 34:64] = True
    free[12:22, 32:34] = True  # door
    return FloorPlan("two_rooms", free, resolution_m, Pose2D(1.5, 1.7, 0.0))


@pytest.fixture
def room() -> FloorPlan:
    return box_room()


def process_group_gone(pgid: int) -> bool:
    """True once no process of the group ``pgid`` is left running (a command started with ``start_new_session``). One
    that has exited but is not reaped yet (a zombie) is gone: an orphan of the group (multiprocessing's resource
    tracker, which outlives its command by a moment) is reaped by PID 1, which in a container may be no real init and
    reap it only seconds later (1.4 to 2 s on this project's 2-core host, more under load), however soon it exited."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            state, _ppid, pgrp = (proc / "stat").read_text().rsplit(")", 1)[1].split()[:3]
        except (OSError, ValueError):  # gone meanwhile, or no /proc of this kind
            continue
        if int(pgrp) == pgid and state not in ("Z", "X"):
            return False
    return Path("/proc/self/stat").is_file()  # without Linux's /proc, only killpg's answer counts


@contextlib.contextmanager
def process_group(cmd: list[str], **popen: Any) -> Iterator[subprocess.Popen]:
    """Run ``cmd`` in a process group of its own (its text output piped); on leaving, SIGKILL the group if the
    command still runs, then wait (at most 10 s each) for it and until none of its processes (workers too) is left."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True, **popen)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):  # its output's pipe held by a process outside the group
                proc.communicate(timeout=10)
        wait_for(lambda: process_group_gone(proc.pid), 10, f"the processes of {' '.join(cmd[:4])} to exit")


def wait_for(cond: Callable[[], Any], timeout_s: float, what: str) -> Any:
    """Poll ``cond`` until it returns something truthy, or fail with ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def walled_grid(rng: np.random.Generator) -> np.ndarray:
    """A 120 x 160 grid of open space with random wall segments and blobs (some cut off)."""
    grid = np.ones((120, 160), dtype=bool)
    grid[[0, -1], :] = grid[:, [0, -1]] = False
    for _ in range(14):
        y, x = rng.integers(5, 115), rng.integers(5, 155)
        if rng.random() < 0.5:
            grid[y : y + rng.integers(10, 40), x : x + 2] = False
        else:
            grid[y : y + 2, x : x + rng.integers(10, 40)] = False
    grid &= rng.random(grid.shape) > 0.02  # speckle
    return grid


def write_episodes_csv(path: Path, episodes: Iterable[dict], fields: Sequence[str]) -> Path:
    """An ``episodes.csv`` as eval writes it, with the given columns (tests of the tools that read it)."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(fields))
        writer.writeheader()
        writer.writerows(episodes)
    return path


@pytest.fixture
def tls_config(tmp_path: Path) -> Path:
    """A Zenoh config file (JSON5) for TLS on loopback: a throwaway certificate authority (its certificate as
    ``root_ca_certificate``) and a server certificate it signs for 127.0.0.1 and localhost, made with openssl in
    ``tmp_path``; the test is skipped without the openssl command."""
    if shutil.which("openssl") is None:
        pytest.skip("needs the openssl command to make certificates")
    ca_key, ca, key, request, cert = (tmp_path / n for n in ("ca-key.pem", "ca.pem", "server-key.pem", "server.csr", "server.pem"))
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    for argv in (
        ["req", "-x509", *ec, "-keyout", ca_key, "-out", ca, "-days", "1", "-subj", "/CN=cso-test-ca"],
        ["req", *ec, "-keyout", key, "-out", request, "-subj", "/CN=localhost"],
        ["x509", "-req", "-in", request, "-CA", ca, "-CAkey", ca_key, "-CAcreateserial", "-out", cert, "-days", "1", "-extfile", "/dev/stdin"],
    ):
        subprocess.run(["openssl", *map(str, argv)], input="subjectAltName=IP:127.0.0.1,DNS:localhost\n", text=True, check=True, capture_output=True)
    tls = {"root_ca_certificate": str(ca), "listen_certificate": str(cert), "listen_private_key": str(key)}
    path = tmp_path / "zenoh-tls.json5"
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return path


def exited_pid() -> int:
    """The pid of a process that has run and been reaped: no process runs under it (until the pids wrap round)."""
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid
