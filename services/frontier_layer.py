"""The frontier service's helper process: the frontier layer (F_t, I, F_t's components) beside D.

An Observation is one fast-marching pass (D) plus the frontier layer, which does not need D
(``cso_runtime.observation.frontier_layer``). scikit-fmm holds the GIL for the whole pass, so a thread
cannot overlap them; a helper process can, on another core: the frontier service hands it the map and
computes D meanwhile, then clusters with the helper's layer. The same function computes the layer in
both places, so the Observation is the one ``ObservationBuilder.build`` gives in one process.

The arrays travel through one shared-memory file per map shape (inputs: explored, occupied, excluded
cells; outputs: F_t, I, the components' cells); a pipe carries the requests and replies. The file is unlinked as soon
as both processes have mapped it, so nothing is left behind whatever happens to either. The helper
exits when the pipe closes (its service stopped or died); a service whose helper is gone, late or
failing computes the layer itself (logged as a warning), so a decision never waits more than ``timeout_s``, and
starts a new helper (``FrontierService.tend_layer_helper``, a bounded number of times); so it does for a helper that
never starts (``not_started_within``).
A helper that ends with its service's stop (the launcher's SIGTERM reaches the whole process group, and a
helper still importing dies of it) is no failure: that is not a warning.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from cso_runtime.observation import FrontierLayer, frontier_layer
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.processes import keep_freed_memory, worker_init

log = logging.getLogger("cso.frontier")

_FIELDS = (
    ("explored", np.bool_, True),
    ("occupied", np.bool_, True),
    ("exclude", np.bool_, True),
    ("frontier", np.bool_, True),
    ("entropy", np.int32, True),
    ("cells_iy", np.int32, False),
    ("cells_ix", np.int32, False),
    ("splits", np.int32, False),
)
"""(name, dtype, a grid of the map's shape or else a flat array of as many entries, of which a reply says how many count)."""


def _views(path: str, shape: tuple[int, int], create: bool) -> tuple[np.memmap, dict[str, np.ndarray]]:
    """The shared file mapped as one array per field (in ``_FIELDS`` order)."""
    cells = shape[0] * shape[1]
    size = sum(cells * np.dtype(dt).itemsize for _, dt, _ in _FIELDS)
    buf = np.memmap(path, dtype=np.uint8, mode="w+" if create else "r+", shape=(size,))
    views, offset = {}, 0
    for name, dt, grid in _FIELDS:
        n = cells * np.dtype(dt).itemsize
        v = buf[offset : offset + n].view(dt)
        views[name] = v.reshape(shape) if grid else v
        offset += n
    return buf, views


def _shared_dir() -> str:
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else tempfile.gettempdir()


def worker_main(conn: Connection) -> None:
    """The helper's loop: map a shared file, compute layers into it, until the pipe closes."""
    views: dict[str, np.ndarray] = {}  # views of the shared file (they keep its mapping alive)
    # Ctrl-C (or ``down``) reaches the whole process group: the service stops and closes the pipe,
    # which ends this loop; the helper itself has nothing to say about it (and it exits with its service).
    worker_init()
    keep_freed_memory(mmap_threshold_bytes=256 << 20)
    reply: tuple | None = ("ready",)  # each request's answer, sent before the next is read
    while True:
        try:
            if reply is not None:
                conn.send(reply)
            request = conn.recv()
        except (EOFError, OSError):  # the pipe closed (the service stopped), also as this helper still started or answered
            return
        reply = None
        kind = request[0]
        try:
            if kind == "map":
                _, path, shape = request
                _, views = _views(path, tuple(shape), create=False)
                reply = ("mapped",)
            elif kind == "layer":
                _, seq, window_m, resolution_m, has_exclude = request
                explored, occupied = views["explored"], views["occupied"]
                out = (views["frontier"], views["entropy"])
                fl = frontier_layer(explored & ~occupied, explored, views["exclude"] if has_exclude else None, window_m, resolution_m, out)
                iy, ix, splits = fl.components
                views["cells_iy"][: len(iy)] = iy
                views["cells_ix"][: len(ix)] = ix
                views["splits"][: len(splits)] = splits
                reply = ("layer", seq, len(iy), len(splits))
        except Exception as exc:  # noqa: BLE001 - reported to the service, which computes the layer itself
            reply = ("error", request[1] if kind == "layer" else -1, f"{type(exc).__name__}: {exc}")


class FrontierLayerWorker:
    """A helper process computing frontier layers for one service (``submit`` then ``result``)."""

    def __init__(self, entropy_window_m: float, timeout_s: float = 2.0, stopping: Callable[[], bool] = lambda: False) -> None:
        self.entropy_window_m = entropy_window_m
        self.timeout_s = timeout_s
        self.stopping = stopping
        """Whether the service is stopping (``Service.stopping``): a helper lost then went with the stop."""
        ctx = multiprocessing.get_context("spawn")  # the service runs Zenoh threads: never fork it
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=worker_main, args=(child,), name="cso-frontier-layer", daemon=True)
        self.proc.start()
        self.started_s = time.monotonic()
        """When the helper was spawned (``time.monotonic``): how long it has been starting (``not_started_within``)."""
        child.close()
        self.shape: tuple[int, int] | None = None
        self.views: dict[str, np.ndarray] = {}
        self.seq = 0
        self.ready = False
        """The helper has started (imports done); until then the service computes layers itself."""
        self.pending: int | None = None
        self.broken = ""
        """Why this helper is no longer used (empty while it is); the service may start a new one in its place."""
        self.lost_to_stop = False
        """The helper was lost while the service was stopping: the stop's doing, not a failure."""
        self.layers_computed = 0
        """Layers the helper computed (the rest were computed by the service itself)."""

    def _reply(self) -> tuple | None:
        if not self.conn.poll(self.timeout_s):
            return None
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            return None

    def _give_up(self, why: str) -> None:
        self.broken = why
        if self.stopping():  # the stop's signal reached the helper too: a plain stop, said by the service
            self.lost_to_stop = True
            log.debug("frontier layer helper gone as the service stops: %s", why)
        else:
            log.warning("frontier layer helper (pid %s) lost: %s", self.proc.pid, why)  # the service says what follows: a new helper, or none
        self.close()

    def _map_shape(self, shape: tuple[int, int]) -> bool:
        path = Path(_shared_dir()) / f"cso-frontier-layer-{os.getpid()}-{self.seq}"
        try:
            _, self.views = _views(str(path), shape, create=True)  # the views keep the mapping alive
            self.conn.send(("map", str(path), shape))
            reply = self._reply()
        except OSError as exc:  # the helper died since ``usable`` looked (its pipe closed): a lost helper, as in ``submit``
            self._give_up(f"cannot reach the helper ({exc})")
            return False
        finally:
            path.unlink(missing_ok=True)  # both mapped it (or gave up): nothing to leave behind
        if reply != ("mapped",):
            self._give_up(f"no answer to mapping the shared arrays ({reply!r})")
            return False
        self.shape = shape
        return True

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait at most ``timeout_s`` for the helper to have started (its imports), and no longer once the service
        is stopping; True when it has."""
        if self.ready or self.broken:
            return self.ready and not self.broken
        deadline = time.monotonic() + timeout_s
        try:
            while not self.conn.poll(max(0.0, min(0.1, deadline - time.monotonic()))):
                if self.stopping() or time.monotonic() >= deadline:
                    return False
            first = self.conn.recv()
        except (EOFError, OSError):
            first = None
        if first != ("ready",):
            self._give_up(f"unexpected first message from the helper ({first!r})")
            return False
        self.ready = True
        log.info("frontier layer helper ready (pid %d)", self.proc.pid)
        return True

    def starting_for_s(self, now_s: float) -> float:
        """How long the helper has been starting at ``now_s`` (``time.monotonic``): 0 once it has started, or failed. Reads
        its "ready" if it has come meanwhile (``wait_ready``, without waiting)."""
        if self.broken or self.wait_ready(0.0):
            return 0.0
        return max(0.0, now_s - self.started_s)

    def not_started_within(self, now_s: float, limit_s: float) -> bool:
        """Give the helper up (``broken``, its process ended, a warning) when it has not started ``limit_s`` after it was
        spawned (``now_s``: ``time.monotonic``): hung in its imports, or stopped (SIGSTOP). Without it a helper that
        never started went unnoticed: never lost, never replaced, its service computing every layer itself and saying
        nothing. True when given up now."""
        starting_s = self.starting_for_s(now_s)
        if starting_s < limit_s or starting_s == 0.0:
            return False
        self._give_up(f"not started {starting_s:.1f} s after it was spawned (hung?)")
        return True

    def usable(self) -> bool:
        """Whether the helper can still be used: False once it failed, or once its process has exited (killed, crashed:
        given up then, and logged)."""
        if self.broken:
            return False
        if not self.proc.is_alive():
            self._give_up(f"the helper process exited (code {self.proc.exitcode})")
            return False
        return True

    def submit(self, occupancy: OccupancyMap, exclude_frontier: np.ndarray | None) -> bool:
        """Start the layer of this map; False when the helper is not used (compute it yourself)."""
        if not self.usable():
            return False
        if not self.wait_ready(0.0):
            return False  # still starting (or broken): this layer is computed by the service
        shape = occupancy.geometry.shape
        if self.shape != shape and not self._map_shape(shape):
            return False
        v = self.views
        np.copyto(v["explored"], occupancy.explored)
        np.copyto(v["occupied"], occupancy.occupied)
        if exclude_frontier is not None:
            np.copyto(v["exclude"], exclude_frontier)
        self.seq += 1
        try:
            self.conn.send(("layer", self.seq, self.entropy_window_m, occupancy.geometry.resolution_m, exclude_frontier is not None))
        except OSError as exc:
            self._give_up(f"cannot reach the helper ({exc})")
            return False
        self.pending = self.seq
        return True

    def result(self) -> FrontierLayer | None:
        """The layer submitted last (views of the shared arrays, valid until the next ``submit``), or
        None when the helper failed (then it is not used again)."""
        seq, self.pending = self.pending, None
        reply = self._reply()
        if reply is None or reply[0] != "layer" or reply[1] != seq:
            self._give_up(f"no layer for request {seq} within {self.timeout_s} s (got {reply!r})")
            return None
        self.layers_computed += 1
        v, n, n_splits = self.views, int(reply[2]), int(reply[3])
        components = (v["cells_iy"][:n].astype(np.intp), v["cells_ix"][:n].astype(np.intp), v["splits"][:n_splits].astype(np.intp))
        return FrontierLayer(v["frontier"], v["entropy"], components)

    def close(self) -> None:
        try:
            self.conn.close()
        except OSError:
            pass
        self.proc.join(timeout=1.0)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(timeout=1.0)
