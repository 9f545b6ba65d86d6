"""Every message the services exchange over Zenoh, and its wire format.

A payload is a msgpack map ``{"schema": NAME, "v": VERSION, "body": {...}}``. Numpy arrays travel as
``{"dtype", "shape", "z", "data"}`` with raw little-endian bytes; map-sized arrays are zlib-compressed
(``"z": true``), boolean grids packed 8 cells to a byte first (``"z": "bits"``). ``decode`` validates
everything (schema, version, types, shapes, ranges, finiteness) and raises ``MessageError`` so a
service can log and count a rejection instead of crashing. The table of keys and schemas is in
docs/messages.md.
"""

from __future__ import annotations

import functools
import math
import secrets
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar, overload

import msgpack
import numpy as np

from cso_runtime.config import MAX_EPISODE_STEPS, ConfigError, utf8_text
from cso_runtime.frontiers import FrontierCluster
from cso_runtime.geometry import (
    MAP_FRAME_ORIGIN,
    MAX_RANGE_M,
    GridGeometry,
    LaserScan,
    Pose2D,
    VelocityCommand,
    map_frame_pose,
    map_frame_xy,
)
from cso_runtime.observation import Observation
from cso_runtime.occupancy import OccupancyMap
from cso_runtime.planner import FollowCheckpoint, FreeSpace, PlannerStatus

SCHEMA_VERSION = 1
"""Version of the schemas unchanged since the first release; a schema that changes bumps its own ``VERSION``
(each class's, listed in docs/messages.md: ``clock``, ``episode_status`` and ``scan`` carry the episode id from 2,
``odom``, ``distance_map`` and ``goal`` from 2, ``planner_feedback`` from 3, ``map`` is at 3, ``frontiers`` at 7,
``episode_status`` at 4, ``service_status`` carries the service's own counters from 2).
Recordings of the versions before the last bumps stay readable offline: ``LEGACY_UPGRADES``."""
MAX_GRID_CELLS = 50_000_000
"""The format's ceiling on a grid's cells and a record's dimensions: no run's ``max_grid_cells`` may be above it."""
MAX_RESOLUTION_M = 100.0
"""The coarsest cell a grid may have, in metres (a map's ``geometry.resolution_m`` is in 1e-4 .. this)."""
MAX_GRID_SIDE_M = MAX_GRID_CELLS * MAX_RESOLUTION_M
"""The longest side any map may have (5e9 m: ``MAX_GRID_CELLS`` cells in one row at ``MAX_RESOLUTION_M``): a length
configured above it (``frontier.entropy_window_m``) is longer than every map."""
DEFAULT_MAX_GRID_CELLS = 4_000_000
"""A run's bound on a grid's cells unless its profile sets ``max_grid_cells``: a 100 m x 100 m arena at 0.05 m (2000 x
2000 cells), 13 times the largest grid a shipped scene has (the builtin and Dungeon plans, 640 x 480 = 307,200 cells at
0.1 m/px; a generated super-large plan at most about 682 x 383 = 261,206 cells at its 0.05 m; limo-ros2's 20 m arena
400 x 400 at 0.05 m). What a forged map makes a receiver inflate: 4 MB a bit-packed grid, where 49 million cells
(under ``MAX_GRID_CELLS``) cost 141 MiB of peak memory to refuse (docs/messages.md, Sizes)."""
_max_grid_cells = DEFAULT_MAX_GRID_CELLS
MAX_BEAMS = 100_000
COMPRESS_MIN_BYTES = 4096
"""Arrays at least this large are zlib-compressed."""
_DTYPES = {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "float32", "float64"}
FLOAT_DTYPES = ("float32", "float64")
"""One rule for every float array (metres, ms, percent; ``unpack_array``'s ``float_as``): it may come in either, and is
read as the dtype the code computes in; a non-float dtype (bool, an integer) is refused, never read as a quantity."""
SIGNED_DTYPES = ("int8", "int16", "int32", "int64")
INTEGER_DTYPES = (*SIGNED_DTYPES, "uint8", "uint16")
"""The integer sets docs/messages.md allows (a cluster's cells: a signed integer; entropy counts: any integer); every
other non-float array (the boolean grids) has exactly one dtype."""
MAX_STEP_POINTS = MAX_EPISODE_STEPS + 1
"""The most entries of an array of one entry per step or per decision (an episode's trajectory, decision times and
coverage curve, a decision's path nodes), step 0's included: what bounds these free-length arrays before they are
inflated (``config.MAX_EPISODE_STEPS``, the most ``episode.max_steps`` may be)."""


class MessageError(ValueError):
    """A payload is malformed, out of range, non-finite, of another schema or of an unknown version."""


def max_grid_cells() -> int:
    """The most cells a grid may have in this process's run (``set_max_grid_cells``; ``DEFAULT_MAX_GRID_CELLS``)."""
    return _max_grid_cells


def max_bin_bytes() -> int:
    """The most bytes one msgpack bin of a payload may have in this run: a grid's cells or an array of one entry per step,
    8 bytes each (``max_grid_cells``, ``MAX_STEP_POINTS``); a longer one is refused before the payload is read."""
    return max(_max_grid_cells, 2 * MAX_STEP_POINTS) * 8


def max_planner_plan_bytes() -> int:
    """The most bytes of an encoded ``planner_plan`` that ``cmd_vel`` carries (``CmdVelMsg.planner_plan``), from the run's
    grid bound (``max_grid_cells``): a path of a point per cell (16 bytes a cell as float64), its two bit-packed grids (an
    eighth of a byte a cell each) and 64 kB for the rest and zlib's overhead; at most one bin of a payload
    (``max_bin_bytes``). A real plan is far smaller (the builtin scene's: about 2 kB); the planner sends none larger
    (its state then names a plan the cache lacks: a restart starts afresh)."""
    return min(max_bin_bytes(), 16 * _max_grid_cells + _max_grid_cells // 4 + 65536)


MAX_PLANNER_STATE_BYTES = 65536
"""The most bytes of an encoded ``planner_state`` that ``cmd_vel`` carries (``CmdVelMsg.planner_state``): its two texts
(the command's ``reason`` and ``blocked_why``, each at most 4096 characters, 16 kB in UTF-8) and some thirty numbers
(about 500 bytes) with room to spare."""


def set_max_grid_cells(cells: int) -> None:
    """Bound every grid this process decodes or sends to ``cells`` (the profile's ``max_grid_cells``, set by each service
    and the launcher as they start): a larger one is refused before any of its data is inflated. ValueError outside
    1 .. ``MAX_GRID_CELLS``."""
    global _max_grid_cells  # one bound for the process, as its run's profile sets it
    check_max_grid_cells(cells)
    _max_grid_cells = cells


def check_max_grid_cells(cells: Any, where: str = "max_grid_cells") -> None:
    """ValueError unless ``cells`` is an integer in 1 .. ``MAX_GRID_CELLS`` (a profile's ``max_grid_cells``)."""
    if isinstance(cells, bool) or not isinstance(cells, int) or not 1 <= cells <= MAX_GRID_CELLS:
        raise ValueError(f"{where} must be an integer in 1 .. {MAX_GRID_CELLS:_}, got {cells!r}")


def check_configured_grid(
    where: str, resolution_m: float, width_m: float, height_m: float, shape_of: Callable[[], tuple[int, int] | None], bound: int | None = None
) -> None:
    """ConfigError for a grid a profile sets (``where``: its keys; ``shape_of``: its ``(ny, nx)`` cells as its service makes
    them, None for none) of more cells than ``bound`` (this process's ``max_grid_cells`` when None), which every receiver
    would refuse, or of sizes whose cells overflow a float (1e308 m at 1 mm). ``up`` checks the profile with it
    (``Profile.check_grid_bound``) and a service that makes the grid (the mapper, the ROS bridge) checks its own, started
    by hand, before allocating it."""
    bound = _max_grid_cells if bound is None else bound
    too_large = f"{where}: a {width_m:g} x {height_m:g} m grid at {resolution_m:g} m is"
    try:
        shape = shape_of()
    except OverflowError:  # finite sizes whose cells are no float: more than any bound
        raise ConfigError(f"{too_large} too many cells to count, more than max_grid_cells ({bound:_}): shrink the arena") from None
    if shape is not None and shape[0] * shape[1] > bound:
        raise ConfigError(
            f"{too_large} {shape[1]} x {shape[0]} = {shape[0] * shape[1]:_} cells, "
            f"more than max_grid_cells ({bound:_}): raise max_grid_cells (at most {MAX_GRID_CELLS:_}) or shrink the arena"
        )


def check_grid_fits(shape: tuple[int, int], where: str) -> None:
    """MessageError for a grid of more cells than ``max_grid_cells`` allows, saying how to raise the bound."""
    cells = shape[0] * shape[1]
    if cells > _max_grid_cells:
        raise MessageError(
            f"{where}: a {shape[0]} x {shape[1]} grid has {cells:_} cells, more than this run's max_grid_cells ({_max_grid_cells:_}; "
            "a profile's max_grid_cells raises it)"
        )


# --- low-level helpers -------------------------------------------------------------------------


_WIRE_DTYPES = {np.dtype(name): (name, np.dtype(name).newbyteorder("<")) for name in _DTYPES}
"""dtype -> (wire name, little-endian dtype); looked up once (``dtype.name`` is slow on a hot path)."""


def pack_array(a: np.ndarray, compress: bool | None = None) -> dict[str, Any]:
    """One array as a wire record; ``compress`` None: zlib when it is at least ``COMPRESS_MIN_BYTES``.

    A compressed boolean array is packed 8 cells to a byte before zlib (``"z": "bits"``): on a
    640 x 480 grid that is 10 times faster to encode, 3 times faster to decode and 5 times smaller
    than zlib over one byte per cell (docs/experiments/runtime-overhead.md)."""
    a = np.ascontiguousarray(a)
    wire = _WIRE_DTYPES.get(a.dtype) or _WIRE_DTYPES.get(a.dtype.newbyteorder("="))
    if wire is None:
        raise MessageError(f"cannot send arrays of dtype {a.dtype}")
    z = a.nbytes >= COMPRESS_MIN_BYTES if compress is None else compress
    if z and a.dtype == np.bool_:
        return {"dtype": "bool", "shape": list(a.shape), "z": "bits", "data": zlib.compress(np.packbits(a, bitorder="little").tobytes(), 1)}
    data = (a if a.dtype == wire[1] else a.astype(wire[1])).tobytes()
    return {"dtype": wire[0], "shape": list(a.shape), "z": bool(z), "data": zlib.compress(data, 1) if z else data}


def unpack_array(
    obj: Any,
    where: str,
    ndim: int | None = None,
    finite: bool = False,
    no_nan: bool = True,
    dtypes: tuple[str, ...] | None = None,
    shape: tuple[int | None, ...] | None = None,
    max_elements: int | None = None,
    float_as: type[np.floating] | None = None,
) -> np.ndarray:
    """Decode and check one array; ``finite`` rejects inf too, ``no_nan`` rejects NaN.

    ``dtypes``: the dtype names docs/messages.md allows for this array (None: any of the list). ``float_as``: a float
    array, which may come in any of ``FLOAT_DTYPES`` (it sets ``dtypes``) and is returned as this dtype (the finiteness
    checks apply after the conversion: a float64 too large for a float32 is inf). ``shape``: the shape the message
    implies (None for a free dimension; it sets ``ndim``); ``max_elements``: the most elements it may hold (None: a
    grid's bound, ``max_grid_cells``). All are checked on the record, before its data is inflated: a crafted record can
    make a receiver inflate no more than the bytes of the shape it had to declare, and that shape no larger than its
    message allows."""
    if not isinstance(obj, dict) or set(obj) != {"dtype", "shape", "z", "data"}:
        raise MessageError(f"{where}: not an array record")
    dtype, declared, data = obj["dtype"], obj["shape"], obj["data"]
    if dtype not in _DTYPES:
        raise MessageError(f"{where}: unsupported dtype {dtype!r}")
    if float_as is not None:
        dtypes = FLOAT_DTYPES
    if dtypes is not None and dtype not in dtypes:
        raise MessageError(f"{where}: expected {' or '.join(dtypes)}, got {dtype}")
    if not isinstance(declared, list) or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= MAX_GRID_CELLS for s in declared):
        raise MessageError(f"{where}: bad shape {declared!r}")
    if shape is not None:
        if len(declared) != len(shape) or not all(want is None or got == want for got, want in zip(declared, shape)):
            wanted = ", ".join("n" if want is None else str(want) for want in shape)
            raise MessageError(f"{where}: shape {declared} does not fit [{wanted}]")
    elif ndim is not None and len(declared) != ndim:
        raise MessageError(f"{where}: expected {ndim}-D, got shape {declared}")
    n = math.prod(declared)
    bound = _max_grid_cells if max_elements is None else max_elements
    if n > bound:
        raise MessageError(f"{where}: too large ({n} elements, at most {bound})")
    if not isinstance(data, bytes):
        raise MessageError(f"{where}: data is not bytes")
    if obj["z"] == "bits":
        if dtype != "bool":
            raise MessageError(f"{where}: bit-packed data must be bool, not {dtype}")
        packed = _decompress(data, (n + 7) // 8, where)
        if len(packed) != (n + 7) // 8:
            raise MessageError(f"{where}: {len(packed)} packed bytes do not fit shape {declared}")
        return np.unpackbits(np.frombuffer(packed, dtype=np.uint8), count=n, bitorder="little").view(np.bool_).reshape(declared)
    native = np.dtype(dtype)
    dt = _WIRE_DTYPES[native][1]
    if obj["z"] is True:
        data = _decompress(data, n * dt.itemsize, where)
    elif obj["z"] is not False:
        raise MessageError(f"{where}: bad compression flag")
    if len(data) != n * dt.itemsize:
        raise MessageError(f"{where}: {len(data)} bytes do not fit shape {declared} of {dtype}")
    if native == np.bool_ and n and np.frombuffer(data, dtype=np.uint8).max() > 1:
        raise MessageError(f"{where}: a bool byte is neither 0 nor 1")  # numpy would keep it, and ~ of it would be true
    if float_as is None or native == float_as:
        a = np.frombuffer(data, dtype=dt).reshape(declared).astype(native, copy=True)
    else:
        with np.errstate(over="ignore"):  # a float64 beyond float32's range becomes inf, which ``finite`` rejects
            a = np.frombuffer(data, dtype=dt).reshape(declared).astype(float_as)
    if a.dtype.kind == "f":
        if finite and not np.isfinite(a).all():
            raise MessageError(f"{where}: non-finite values")
        elif no_nan and np.isnan(a).any():
            raise MessageError(f"{where}: NaN values")
    return a


def _decompress(data: bytes, expected_bytes: int, where: str) -> bytes:
    """Inflate at most one byte more than expected: enough for the caller to reject a wrong size,
    never the memory a crafted payload could ask for. The zlib stream must be whole (its checksum
    read) and end the data: a truncated stream or bytes after it are rejected."""
    inflater = zlib.decompressobj()
    try:
        out = inflater.decompress(data, expected_bytes + 1)
    except zlib.error as exc:
        raise MessageError(f"{where}: corrupt compressed data ({exc})") from None
    if len(out) <= expected_bytes:  # else the caller rejects the size
        if not inflater.eof:
            raise MessageError(f"{where}: truncated compressed data (the zlib stream does not end)")
        if inflater.unused_data:
            raise MessageError(f"{where}: {len(inflater.unused_data)} bytes after the compressed data")
    return out


def _get(body: dict, key: str, where: str) -> Any:
    if key not in body:
        raise MessageError(f"{where}: missing field {key!r}")
    return body[key]


def _counts(body: dict, key: str, where: str, optional: bool = False) -> dict[str, int]:
    """A mapping of names to counts (>= 0); ``optional``: an absent one is empty (a field added later)."""
    v = body.get(key, {}) if optional else _get(body, key, where)
    if not isinstance(v, dict) or not all(isinstance(k, str) and isinstance(n, int) and not isinstance(n, bool) and n >= 0 for k, n in v.items()):
        raise MessageError(f"{where}.{key}: expected a mapping of counts")
    return v


def _num(body: dict, key: str, where: str, lo: float = -math.inf, hi: float = math.inf, allow_inf: bool = False) -> float:
    v = _get(body, key, where)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MessageError(f"{where}.{key}: expected a number, got {type(v).__name__}")
    v = float(v)
    if math.isnan(v) or (not allow_inf and math.isinf(v)):
        raise MessageError(f"{where}.{key}: not finite ({v})")
    if not lo <= v <= hi:
        raise MessageError(f"{where}.{key}: {v} out of range [{lo}, {hi}]")
    return v


def _int(body: dict, key: str, where: str, lo: int = 0, hi: int = 2**62) -> int:
    v = _get(body, key, where)
    if isinstance(v, bool) or not isinstance(v, int):
        raise MessageError(f"{where}.{key}: expected an integer, got {type(v).__name__}")
    if not lo <= v <= hi:
        raise MessageError(f"{where}.{key}: {v} out of range [{lo}, {hi}]")
    return v


MAX_TEXT_CHARS = 4096
"""The most characters of a message's text field (a reason, a name) unless the field says otherwise: a longer one is
refused (``_str``), so a sender clips its own (``clipped``)."""


def clipped(text: str, max_chars: int = MAX_TEXT_CHARS) -> str:
    """``text`` as it is when it fits ``max_chars``, else its start and an ellipsis in ``max_chars`` characters (the
    decoder counts characters too, ``_str``, so a multi-byte character is never cut). A character UTF-8 cannot carry (a
    lone surrogate: a file name of undecodable bytes, ``os.fsdecode``'s) is escaped first (``\\udcff``): the message
    would not encode at all, and a status that raised went unanswered (``config.utf8_text``)."""
    text = utf8_text(text)
    return text if len(text) <= max_chars else text[: max_chars - 1] + "…"


def _str(body: dict, key: str, where: str, choices: tuple[str, ...] | None = None, max_len: int = MAX_TEXT_CHARS) -> str:
    v = _get(body, key, where)
    if not isinstance(v, str) or len(v) > max_len:
        raise MessageError(f"{where}.{key}: expected a string")
    if choices is not None and v not in choices:
        raise MessageError(f"{where}.{key}: {v!r} not one of {', '.join(choices)}")
    return v


def _bool(body: dict, key: str, where: str) -> bool:
    v = _get(body, key, where)
    if not isinstance(v, bool):
        raise MessageError(f"{where}.{key}: expected true/false")
    return v


def _opaque(body: dict, key: str, where: str, max_bytes: int) -> bytes | None:
    """An optional field of bytes carried for another reader, unread here (None when absent or nil), refused above
    ``max_bytes`` before its receiver keeps it."""
    v = body.get(key)
    if v is None:
        return None
    if not isinstance(v, bytes):
        raise MessageError(f"{where}.{key}: expected bytes or null, got {type(v).__name__}")
    if len(v) > max_bytes:
        raise MessageError(f"{where}.{key}: too large ({len(v)} bytes, at most {max_bytes})")
    return v


def _pose_out(p: Pose2D) -> list[float]:
    return p.as_list()


def _twist_out(t: VelocityCommand) -> list[float]:
    return [t.linear_mps, t.angular_radps]


def _twist_in(body: dict, key: str, where: str) -> VelocityCommand:
    """``[linear_mps, angular_radps]``, each finite and within +-100."""
    tw = _get(body, key, where)
    if not isinstance(tw, list) or len(tw) != 2:
        raise MessageError(f"{where}.{key}: expected [linear_mps, angular_radps]")
    t = {"v": tw[0], "w": tw[1]}
    return VelocityCommand(_num(t, "v", f"{where}.{key}", -100, 100), _num(t, "w", f"{where}.{key}", -100, 100))


def _pose_in(body: dict, key: str, where: str) -> Pose2D:
    v = _get(body, key, where)
    if not isinstance(v, list) or len(v) != 3:
        raise MessageError(f"{where}.{key}: expected [x_m, y_m, yaw_rad]")
    d = dict(zip("xyt", v))
    return Pose2D(_num(d, "x", where + "." + key), _num(d, "y", where + "." + key), _num(d, "t", where + "." + key, -10.0, 10.0))


def _geometry_out(g: GridGeometry) -> dict[str, Any]:
    check_grid_fits(g.shape, "geometry")  # said by its sender, not only by every receiver refusing it
    return {"resolution_m": g.resolution_m, "shape": list(g.shape), "origin": [g.origin_x_m, g.origin_y_m]}


def _geometry_in(body: dict, where: str) -> GridGeometry:
    g = _get(body, "geometry", where)
    if not isinstance(g, dict):
        raise MessageError(f"{where}.geometry: expected a mapping")
    res = _num(g, "resolution_m", where + ".geometry", 1e-4, MAX_RESOLUTION_M)
    shape = _get(g, "shape", where + ".geometry")
    if not isinstance(shape, list) or len(shape) != 2 or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in shape):
        raise MessageError(f"{where}.geometry.shape: expected two positive integers")
    check_grid_fits((shape[0], shape[1]), f"{where}.geometry.shape")
    origin = _get(g, "origin", where + ".geometry")
    if not isinstance(origin, list) or len(origin) != 2:
        raise MessageError(f"{where}.geometry.origin: expected [x_m, y_m]")
    ox = _num({"x": origin[0]}, "x", where + ".geometry.origin")
    oy = _num({"y": origin[1]}, "y", where + ".geometry.origin")
    return GridGeometry(res, (shape[0], shape[1]), ox, oy)


def _grid_in(body: dict, key: str, where: str, geometry: GridGeometry, dtype: str) -> np.ndarray:
    """A grid of ``dtype`` on ``geometry`` (both checked before its data is inflated)."""
    return unpack_array(_get(body, key, where), f"{where}.{key}", finite=dtype != "float64", dtypes=(dtype,), shape=geometry.shape)


# --- messages ---------------------------------------------------------------------------------


class Message:
    """Base of every message: a schema name, a step stamp, and a body codec."""

    SCHEMA: ClassVar[str] = ""
    VERSION: ClassVar[int] = SCHEMA_VERSION
    """Wire version of this schema; ``decode`` rejects any other."""

    def body(self) -> dict[str, Any]:
        raise NotImplementedError

    @classmethod
    def from_body(cls, body: dict[str, Any]) -> Message:
        raise NotImplementedError


def scan_episode_and_stamp(b: dict[str, Any]) -> tuple[int, float]:
    """A ``scan`` body's episode id and stamp (seconds), checked as ``ScanMsg.from_body`` checks them (MessageError):
    what the Foxglove bridge reads of each scan for its period without decoding the whole scan (its ranges)."""
    return _int(b, "episode", "scan"), _num(b, "stamp_s", "scan", 0.0)


@dataclass
class ScanMsg(Message):
    """A range scan at one simulation step, with the odometry pose of the sensor when it was taken."""

    SCHEMA: ClassVar[str] = "scan"
    VERSION: ClassVar[int] = 2
    step: int
    scan: LaserScan
    sensor_pose: Pose2D
    episode: int = 0
    """Episode id, as on the clock (v2): the mapper can integrate a scan the moment it arrives, before
    the clock of its step, and still never mix two episodes in one map."""

    def body(self) -> dict[str, Any]:
        s = self.scan
        return {
            "step": self.step,
            "stamp_s": float(s.stamp_s),
            "angle_min_rad": float(s.angle_min_rad),
            "angle_increment_rad": float(s.angle_increment_rad),
            "range_min_m": float(s.range_min_m),
            "range_max_m": float(s.range_max_m),
            "ranges_m": pack_array(np.asarray(s.ranges_m, dtype=np.float32), compress=False),
            "sensor_pose": _pose_out(self.sensor_pose),
            "episode": self.episode,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> ScanMsg:
        w = "scan"
        ranges = unpack_array(_get(b, "ranges_m", w), "scan.ranges_m", shape=(None,), max_elements=MAX_BEAMS, float_as=np.float32)
        if ranges.size == 0:
            raise MessageError("scan.ranges_m: expected 1 to 100000 float ranges")
        if (ranges < 0).any():
            raise MessageError("scan.ranges_m: negative ranges")
        episode, stamp_s = scan_episode_and_stamp(b)
        scan = LaserScan(
            _num(b, "angle_min_rad", w, -2 * math.pi, 2 * math.pi),
            _num(b, "angle_increment_rad", w, 1e-6, 2 * math.pi),
            _num(b, "range_min_m", w, 0.0, MAX_RANGE_M),
            _num(b, "range_max_m", w, 0.0, MAX_RANGE_M),
            ranges,
            stamp_s,
        )
        try:
            scan.validate()
        except ValueError as exc:
            raise MessageError(f"scan: {exc}") from None
        return cls(_int(b, "step", w), scan, _pose_in(b, "sensor_pose", w), episode)


@dataclass
class OdometryMsg(Message):
    """The robot's own pose estimate (and the last applied twist) at one step."""

    SCHEMA: ClassVar[str] = "odom"
    VERSION: ClassVar[int] = 2
    step: int
    stamp_s: float
    pose: Pose2D
    twist: VelocityCommand = field(default_factory=VelocityCommand)
    episode: int = 0
    """Episode id, as on the clock (v2): the planner and the frontier service see a new episode on its
    first odometry, whatever its step (``EpisodeWatch``)."""

    def body(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "stamp_s": self.stamp_s,
            "pose": _pose_out(self.pose),
            "twist": _twist_out(self.twist),
            "episode": self.episode,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> OdometryMsg:
        w = "odom"
        return cls(_int(b, "step", w), _num(b, "stamp_s", w, 0.0), _pose_in(b, "pose", w), _twist_in(b, "twist", w), _int(b, "episode", w))


@dataclass
class CmdVelMsg(Message):
    """The velocity command for one step (lockstep: the sim advances when it has the command of its step).

    The project's planner also hands the referee (sim or ros2_bridge) its checkpoint on it (v3): ``planner_state`` every
    step and ``planner_plan`` when the plan changed, each an encoded message the referee never decodes, only keeps and
    serves (``cache/planner/state``, ``cache/planner/plan``) to a restarted planner. On the message the sim steps on
    anyway, the lockstep chain pays no delivery of its own for them."""

    SCHEMA: ClassVar[str] = "cmd_vel"
    VERSION: ClassVar[int] = 3
    step: int
    command: VelocityCommand
    reason: str = ""
    """Why the robot is stopped (``stale: ...``, ``reached``...), empty while following a path
    (``backup`` while the planner backs a pinned robot up)."""
    new_goal: bool = False
    """The command follows a goal decided at this step (a lockstep sim then also waits for that goal,
    to count the decision); false on the steps that keep the current goal."""
    episode: int = 0
    """Episode id of the inputs the command was computed on (v3, optional; 0: no id, a planner of one's own): the
    referee keeps the ``planner_state`` and ``planner_plan`` it carries only when they are of its episode."""
    planner_state: bytes | None = None
    """The encoded ``PlannerStateMsg`` after this command (optional, at most ``MAX_PLANNER_STATE_BYTES``); None: none."""
    planner_plan: bytes | None = None
    """The encoded ``PlannerPlanMsg`` made by this command (optional, only when the plan changed; at most
    ``max_planner_plan_bytes()``); None: the plan kept is still the one followed."""

    def command_body(self) -> dict[str, Any]:
        """The command alone (``planner_state.cmd``): what a retry of the step sends again."""
        c = self.command
        return {"step": self.step, "linear_mps": c.linear_mps, "angular_radps": c.angular_radps, "reason": self.reason, "new_goal": self.new_goal}

    def body(self) -> dict[str, Any]:
        b = self.command_body()
        if self.episode:
            b["episode"] = self.episode
        if self.planner_state is not None:
            b["planner_state"] = self.planner_state
        if self.planner_plan is not None:
            b["planner_plan"] = self.planner_plan
        return b

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> CmdVelMsg:
        w = "cmd_vel"
        cmd = VelocityCommand(_num(b, "linear_mps", w, -100, 100), _num(b, "angular_radps", w, -100, 100))
        episode = _int(b, "episode", w) if b.get("episode") is not None else 0
        state = _opaque(b, "planner_state", w, MAX_PLANNER_STATE_BYTES)
        plan = _opaque(b, "planner_plan", w, max_planner_plan_bytes())
        return cls(_int(b, "step", w), cmd, _str(b, "reason", w), _bool(b, "new_goal", w), episode, state, plan)


@dataclass
class MapMsg(Message):
    """The occupancy map M_t as its two channels (section 3.2), explored and occupied, each a boolean
    grid bit-packed and compressed on the wire (v3; row 0 at the origin). ``grid`` gives the ROS
    OccupancyGrid values (-1/0/100) for bridges and files. Two bit-planes rather than one int8 grid:
    the mapper encodes them about four times faster and the receivers get the masks they work on."""

    SCHEMA: ClassVar[str] = "map"
    VERSION: ClassVar[int] = 3
    step: int
    geometry: GridGeometry
    explored: np.ndarray
    """bool (ny, nx): cells seen at least once."""
    occupied: np.ndarray
    """bool (ny, nx): explored cells that are occupied (never an unexplored one)."""
    episode: int = 0
    """Episode id of the scans the map was built from (v2), so that a map still in flight from an
    earlier episode (after a sim restart) is never taken for this one's. 0: not from a sim episode."""

    @classmethod
    def of(cls, step: int, occupancy: OccupancyMap, episode: int = 0) -> MapMsg:
        """The message of a map (its occupied channel restricted to explored cells)."""
        return cls(step, occupancy.geometry, occupancy.explored.copy(), occupancy.explored & occupancy.occupied, episode)

    @classmethod
    def from_grid(cls, step: int, geometry: GridGeometry, grid: np.ndarray, episode: int = 0) -> MapMsg:
        """The message of an OccupancyGrid (values above 50 are occupied, ROS convention)."""
        return cls.of(step, OccupancyMap.from_occupancy_grid(grid, geometry), episode)

    def occupancy(self) -> OccupancyMap:
        """The map to read (it shares this message's arrays: copy it before integrating scans into it)."""
        return OccupancyMap.from_masks(self.explored, self.occupied, self.geometry)

    @property
    def grid(self) -> np.ndarray:
        """int8 OccupancyGrid values: -1 unknown, 0 free, 100 occupied."""
        return self.occupancy().to_occupancy_grid()

    def body(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "geometry": _geometry_out(self.geometry),
            "explored": pack_array(np.asarray(self.explored, dtype=bool), compress=True),
            "occupied": pack_array(np.asarray(self.occupied, dtype=bool), compress=True),
            "episode": self.episode,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any], where: str = "map") -> MapMsg:
        geometry = _geometry_in(b, where)
        explored = _grid_in(b, "explored", where, geometry, "bool")
        occupied = _grid_in(b, "occupied", where, geometry, "bool")
        if (occupied & ~explored).any():
            raise MessageError(f"{where}.occupied: only explored cells can be occupied")
        return cls(_int(b, "step", where), geometry, explored, occupied, _int(b, "episode", where))


def _masked_grid_in(values_obj: Any, mask: np.ndarray, where: str, fill: float, dtype: type) -> np.ndarray:
    """A grid sent as its values (1-D, row by row) where its boolean ``mask`` is set, ``fill`` elsewhere.
    The values must be non-negative (distances, counts), finite, and one per set cell (checked before
    they are inflated); counts may come in any integer width of the list, each within ``dtype``,
    distances in either float (``FLOAT_DTYPES``), read as ``dtype``."""
    counts = np.dtype(dtype).kind in "iu"
    n_set = int(np.count_nonzero(mask))
    if counts:
        values = unpack_array(values_obj, where, finite=True, dtypes=INTEGER_DTYPES, shape=(n_set,))
    else:
        values = unpack_array(values_obj, where, finite=True, shape=(n_set,), float_as=dtype)
    if (values < 0).any():
        raise MessageError(f"{where}: negative values")
    if counts and values.size and int(values.max()) > np.iinfo(dtype).max:
        raise MessageError(f"{where}: a count above {np.iinfo(dtype).max}")  # it would wrap around in the grid
    grid: np.ndarray = np.full(mask.shape, fill, dtype=dtype)
    grid.ravel()[np.flatnonzero(mask)] = values  # 3-4x faster than grid[mask] = values on a 640 x 480 grid
    return grid


def _narrow_counts(counts: np.ndarray) -> np.ndarray:
    """Non-negative integer counts in the smallest unsigned dtype that holds them (lossless)."""
    counts = np.asarray(counts)
    top = int(counts.max()) if counts.size else 0
    if counts.size and int(counts.min()) < 0:
        return counts.astype(np.int32)
    return counts.astype(np.uint8 if top < 2**8 else np.uint16 if top < 2**16 else np.int32)


CLUSTER_FIELDS = ("goal_cell", "goal_xy_m", "distance_m", "size_m", "entropy", "centroid_xy_m", "cells")
_CLUSTER_FIELD_SET = frozenset(CLUSTER_FIELDS)


def _xy_in(v: Any, where: str) -> tuple[float, float]:
    """A finite ``[x_m, y_m]`` pair."""
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in v)):
        raise MessageError(f"{where}: expected [x_m, y_m], two finite numbers")
    return float(v[0]), float(v[1])


@dataclass
class FrontiersMsg(Message):
    """The decision input of one step. ``decide`` false: keep the current goal (no arrays sent).

    ``decide`` true: everything a goal selector needs to rebuild the Observation without recomputing the
    fast-marching distance: explored, occupied, traversable, F, I, the clusters (each with its goal's
    geodesic distance) and the path nodes with D at each of them. D itself travels on its own
    (``DistanceMapMsg``, right after): goal selectors read it only at those nodes, so the policy does
    not wait for it; the planner decodes it while the policy decides (docs/experiments/runtime-overhead.md).
    """

    SCHEMA: ClassVar[str] = "frontiers"
    VERSION: ClassVar[int] = 7
    """2: D travels as its finite window (``distance_window``), I as the smallest unsigned type.
    3: within the window, only D's finite values travel, with the window's finite mask (``distance_finite``).
    4: boolean grids travel bit-packed (``pack_array``).
    5: D and I travel as their values where their mask (``masks``) is set: D's finite cells, I's non-zero
    ones (I was sent whole: two thirds of a decision message on a 640 x 480 map).
    6: D moved to its own message (nine tenths of a decision message on a 640 x 480 map); here only its
    values at the path nodes (``path_nodes_distance_m``).
    7: the episode id of the map it was decided on (``episode``)."""
    step: int
    decide: bool
    reason: str = ""
    pose: Pose2D | None = None
    geometry: GridGeometry | None = None
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    """explored, occupied, traversable, frontier (bool), entropy (int32)."""
    clusters: list[dict[str, Any]] = field(default_factory=list)
    open_area_m2: float = 0.0
    path_nodes_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    build_ms: float = 0.0
    path_nodes_distance_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """D at each path node's cell (inf: unreachable or off the map)."""
    episode: int = 0
    """Episode id of the map decided on (as on the clock; 0: not from a sim episode): the policy sees a new
    episode on its first decision input, which in real time is rarely that of step 0."""

    GRIDS: ClassVar[dict[str, str]] = {
        "explored": "bool",
        "occupied": "bool",
        "traversable": "bool",
        "frontier": "bool",
        "entropy": "int32",
    }
    MASKED: ClassVar[tuple[str, ...]] = ("entropy",)
    """Grids that travel as their values where a mask is set (I: non-zero)."""
    READS_GRIDS: ClassVar[tuple[str, ...] | None] = None
    """Grids ``from_body`` decodes (None: all). A subscriber that reads fewer decodes them only
    (``frontiers_reading``); the others stay None, unchecked: their readers check them."""
    READS_CLUSTERS: ClassVar[bool] = True
    """``from_body`` decodes the clusters and the path nodes (the planner does not read them)."""

    def cluster_points_xy_m(self) -> tuple[list[np.ndarray], list[tuple[float, float]]]:
        """Each frontier cluster's cell centres (n x 2, metres) and its goal, for visualisation (RViz markers)."""
        if self.geometry is None:
            return [], []
        cells = [np.asarray(c["cells"]).reshape(-1, 2) for c in self.clusters]
        points = [np.column_stack(self.geometry.cell_to_world(c[:, 0], c[:, 1])) for c in cells]
        return points, [(float(c["goal_xy_m"][0]), float(c["goal_xy_m"][1])) for c in self.clusters]

    def body(self) -> dict[str, Any]:
        b: dict[str, Any] = {"step": self.step, "decide": self.decide, "reason": self.reason, "episode": self.episode}
        if not self.decide:
            return b
        assert self.pose is not None and self.geometry is not None
        entropy = np.asarray(self.arrays["entropy"])
        masks = {"entropy": entropy != 0}
        b.update(
            pose=_pose_out(self.pose),
            geometry=_geometry_out(self.geometry),
            # Boolean grids compress 20-50x for almost nothing. I would cost more CPU to zlib than to
            # send, so it is made small instead: its values where they are non-zero (about 1 % of the
            # cells), row by row, in the smallest unsigned type that holds them, with that mask as a
            # boolean grid. Lossless.
            arrays={k: pack_array(np.asarray(self.arrays[k], dtype=dt), compress=True) for k, dt in self.GRIDS.items() if dt == "bool"}
            | {"entropy": pack_array(_narrow_counts(entropy[masks["entropy"]]), compress=False)},
            masks={k: pack_array(m, compress=True) for k, m in masks.items()},
            clusters=[
                {
                    "goal_cell": [int(c["goal_cell"][0]), int(c["goal_cell"][1])],
                    "goal_xy_m": [float(c["goal_xy_m"][0]), float(c["goal_xy_m"][1])],
                    "distance_m": float(c["distance_m"]),
                    "size_m": float(c["size_m"]),
                    "entropy": float(c["entropy"]),
                    "centroid_xy_m": [float(c["centroid_xy_m"][0]), float(c["centroid_xy_m"][1])],
                    "cells": pack_array(np.asarray(c["cells"], dtype=np.int32)),
                }
                for c in self.clusters
            ],
            open_area_m2=self.open_area_m2,
            path_nodes_xy_m=pack_array(np.asarray(self.path_nodes_xy_m, dtype=np.float64).reshape(-1, 2)),
            path_nodes_distance_m=pack_array(np.asarray(self.path_nodes_distance_m, dtype=np.float64).reshape(-1)),
            build_ms=self.build_ms,
        )
        return b

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> FrontiersMsg:
        w = "frontiers"
        step, decide, reason, episode = _int(b, "step", w), _bool(b, "decide", w), _str(b, "reason", w), _int(b, "episode", w)
        if not decide:
            return cls(step, False, reason, episode=episode)
        geometry = _geometry_in(b, w)
        raw = _get(b, "arrays", w)
        if not isinstance(raw, dict) or set(raw) != set(cls.GRIDS):
            raise MessageError(f"frontiers.arrays: expected exactly {', '.join(cls.GRIDS)}")
        reads = cls.GRIDS if cls.READS_GRIDS is None else cls.READS_GRIDS
        arrays = {k: _grid_in(raw, k, "frontiers.arrays", geometry, dt) for k, dt in cls.GRIDS.items() if dt == "bool" and k in reads}
        masks = _get(b, "masks", w)
        if not isinstance(masks, dict) or set(masks) != set(cls.MASKED):
            raise MessageError(f"frontiers.masks: expected exactly {', '.join(cls.MASKED)}")
        if "entropy" in reads:
            arrays["entropy"] = _masked_grid_in(raw["entropy"], _grid_in(masks, "entropy", "frontiers.masks", geometry, "bool"), "frontiers.arrays.entropy", 0, np.int32)
        open_area_m2 = _num(b, "open_area_m2", w, 0.0)
        if not cls.READS_CLUSTERS:
            return cls(step, True, reason, _pose_in(b, "pose", w), geometry, arrays, [], open_area_m2, episode=episode)
        clusters_raw = _get(b, "clusters", w)
        if not isinstance(clusters_raw, list):
            raise MessageError("frontiers.clusters: expected a list")
        clusters = []
        ny, nx = geometry.shape
        cells_left = ny * nx  # the clusters share the grid's cells: so many compressed records cannot inflate beyond it
        for i, c in enumerate(clusters_raw):
            cw = f"frontiers.clusters[{i}]"
            if not isinstance(c, dict) or c.keys() != _CLUSTER_FIELD_SET:
                raise MessageError(f"{cw}: expected fields {', '.join(CLUSTER_FIELDS)}")
            gc = c["goal_cell"]
            if not (isinstance(gc, list) and len(gc) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in gc)):
                raise MessageError(f"{cw}.goal_cell: expected [iy, ix]")
            if not (0 <= gc[0] < ny and 0 <= gc[1] < nx):
                raise MessageError(f"{cw}.goal_cell: outside the grid")
            cells = unpack_array(c["cells"], f"{cw}.cells", dtypes=SIGNED_DTYPES, shape=(None, 2), max_elements=2 * cells_left)
            if (cells < 0).any() or (cells >= (ny, nx)).any():
                raise MessageError(f"{cw}.cells: expected (k, 2) cell indices inside the grid")
            cells_left -= len(cells)
            clusters.append(
                {
                    "goal_cell": (gc[0], gc[1]),
                    "goal_xy_m": _xy_in(c["goal_xy_m"], f"{cw}.goal_xy_m"),
                    "distance_m": _num(c, "distance_m", cw, 0.0),
                    "size_m": _num(c, "size_m", cw, 0.0),
                    "entropy": _num(c, "entropy", cw, 0.0),
                    "centroid_xy_m": _xy_in(c["centroid_xy_m"], f"{cw}.centroid_xy_m"),
                    "cells": cells,
                }
            )
        nodes = unpack_array(  # one node per decision: at most MAX_STEP_POINTS
            _get(b, "path_nodes_xy_m", w), "frontiers.path_nodes_xy_m", finite=True, shape=(None, 2), max_elements=2 * MAX_STEP_POINTS, float_as=np.float64
        )
        node_d = unpack_array(  # one per node: bound as the nodes, not as a grid (a run's grid may have fewer cells)
            _get(b, "path_nodes_distance_m", w), "frontiers.path_nodes_distance_m", shape=(len(nodes),), max_elements=MAX_STEP_POINTS, float_as=np.float64
        )
        if (node_d < 0).any():
            raise MessageError("frontiers.path_nodes_distance_m: expected one non-negative float (inf: unreachable) per path node")
        return cls(
            step,
            True,
            reason,
            _pose_in(b, "pose", w),
            geometry,
            arrays,
            clusters,
            open_area_m2,
            nodes,
            _num(b, "build_ms", w, 0.0),
            node_d,
            episode,
        )


@functools.cache
def frontiers_reading(grids: tuple[str, ...] | None, clusters: bool = True) -> type[FrontiersMsg]:
    """``FrontiersMsg`` as a subscriber that reads only ``grids`` (None: all) and, with ``clusters``,
    the clusters and path nodes decodes it: a policy service decodes what its goal selector reads
    (``GoalSelector.grids``; the baselines read no grid), the planner the grid it plans on."""
    if grids is None and clusters:
        return FrontiersMsg
    unknown = set(grids or ()) - set(FrontiersMsg.GRIDS)
    if unknown:
        raise ValueError(f"no such decision grids: {', '.join(sorted(unknown))}")
    name = f"FrontiersReading_{'_'.join(grids) if grids is not None else 'all'}{'' if clusters else '_no_clusters'}"
    return type(name, (FrontiersMsg,), {"READS_GRIDS": grids, "READS_CLUSTERS": clusters, "__doc__": frontiers_reading.__doc__})


PlannerFrontiersMsg = frontiers_reading(("traversable", "occupied", "explored"), clusters=False)
"""A ``frontiers`` message as the planner reads it: the verdict and, on a decision, the grid it plans on
and the obstacles and seen cells it checks before reversing (with the pose and geometry). Three of the five grids and no
clusters, on the planner's network thread while a fast policy's goal may already be waiting behind it."""


class DeferredMsg(Message):
    """A message whose body is kept as it came, its arrays still packed and compressed, until ``decoded``: a
    subscriber that may never read it (a viewer's bridge with no viewer) does not pay to decode it. Its envelope
    (schema, version) and its ``step`` are checked on arrival; the rest of the body when it is decoded, which then
    raises ``MessageError`` as ``decode`` would have. A subclass per schema: ``deferred``."""

    DECODES: ClassVar[type[Message]] = Message

    def __init__(self, step: int, kept_body: dict[str, Any]) -> None:
        self.step = step
        self.kept_body = kept_body
        """The body as it came (unchecked but for ``step``)."""

    def body(self) -> dict[str, Any]:
        return self.kept_body

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> DeferredMsg:
        return cls(_int(b, "step", cls.SCHEMA), b)

    def decoded(self) -> Message:
        """The message, decoded and checked now; MessageError for a body that does not decode."""
        return _from_body(self.SCHEMA, self.DECODES, self.kept_body)


@functools.cache
def deferred(cls: type[Message]) -> type[DeferredMsg]:
    """``cls`` (a schema with a ``step``) as a subscriber that decodes it later, if at all, reads it (``DeferredMsg``)."""
    fields = {"SCHEMA": cls.SCHEMA, "VERSION": cls.VERSION, "DECODES": cls, "__doc__": DeferredMsg.__doc__}
    return type(f"Deferred{cls.__name__}", (DeferredMsg,), fields)


def frontiers_from_observation(step: int, reason: str, obs: Observation, build_ms: float, episode: int = 0) -> FrontiersMsg:
    """The decision message for ``obs`` (the frontier service's output) in episode ``episode``."""
    arrays = {k: getattr(obs, k) for k in FrontiersMsg.GRIDS}
    clusters = [
        {
            "goal_cell": c.goal_cell,
            "goal_xy_m": c.goal_xy_m,
            "distance_m": c.distance_m,
            "size_m": c.size_m,
            "entropy": c.entropy,
            "centroid_xy_m": c.centroid_xy_m,
            "cells": c.cells,
        }
        for c in obs.clusters
    ]
    nodes = np.asarray(obs.path_nodes_xy_m, dtype=float).reshape(-1, 2)
    return FrontiersMsg(step, True, reason, obs.pose, obs.geometry, arrays, clusters, obs.open_area_m2, nodes, build_ms, obs.distance_at(nodes), episode)


def observation_from_frontiers(msg: FrontiersMsg) -> Observation:
    """Rebuild the Observation a goal selector needs, without recomputing the fast-marching distance
    (D is known at the path nodes; ``Observation.distance_map`` computes the rest if ever asked)."""
    if not msg.decide or msg.geometry is None or msg.pose is None:
        raise MessageError("frontiers: no observation in a keep-goal message")
    a = msg.arrays  # the grids its subscriber decoded (``frontiers_reading``); the others None
    clusters = [
        FrontierCluster(i, c["cells"], tuple(c["goal_cell"]), tuple(c["goal_xy_m"]), c["distance_m"], c["size_m"], c["entropy"], tuple(c["centroid_xy_m"]))
        for i, c in enumerate(msg.clusters)
    ]
    return Observation(
        geometry=msg.geometry,
        pose=msg.pose,
        explored=a.get("explored"),  # type: ignore[arg-type]
        occupied=a.get("occupied"),  # type: ignore[arg-type]
        traversable=a.get("traversable"),  # type: ignore[arg-type]
        distance_m=None,
        frontier=a.get("frontier"),  # type: ignore[arg-type]
        entropy=a.get("entropy"),  # type: ignore[arg-type]
        clusters=clusters,
        open_area_m2=msg.open_area_m2,
        path_nodes_xy_m=msg.path_nodes_xy_m,
        known_distance_m=_cell_values(msg.geometry, msg.path_nodes_xy_m, msg.path_nodes_distance_m),
    )


def _cell_values(geometry: GridGeometry, xy_m: np.ndarray, values: np.ndarray) -> dict[tuple[int, int], float]:
    """{(iy, ix): value} for the points on the grid."""
    iy, ix = geometry.world_to_cell(xy_m[:, 0], xy_m[:, 1])
    inside = geometry.in_bounds(iy, ix)
    return {(int(y), int(x)): float(v) for y, x, v in zip(iy[inside], ix[inside], np.asarray(values)[inside])}


@dataclass
class DistanceMapMsg(Message):
    """D(M_t, w_t) of one decision: the geodesic distance from the robot (``pose``) over the map, inf
    where unreachable. Published by the frontier service right after the decision message of the same
    step, for the planner (a path to any goal by descending D) and anyone who wants to look at D.
    Travels as its finite values, row by row, with their mask (lossless)."""

    SCHEMA: ClassVar[str] = "distance_map"
    VERSION: ClassVar[int] = 2
    step: int
    geometry: GridGeometry
    pose: Pose2D
    distance_m: np.ndarray
    episode: int = 0
    """Episode id, as on its decision message (v2)."""

    def body(self) -> dict[str, Any]:
        d = np.asarray(self.distance_m, dtype=np.float64)
        finite = d != np.inf  # a NaN is sent, for the receiver to reject
        return {
            "step": self.step,
            "geometry": _geometry_out(self.geometry),
            "pose": _pose_out(self.pose),
            "finite": pack_array(finite, compress=True),
            "distance_m": pack_array(d[finite], compress=False),
            "episode": self.episode,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> DistanceMapMsg:
        w = "distance_map"
        geometry = _geometry_in(b, w)
        d = _masked_grid_in(_get(b, "distance_m", w), _grid_in(b, "finite", w, geometry, "bool"), f"{w}.distance_m", np.inf, np.float64)
        return cls(_int(b, "step", w), geometry, _pose_in(b, "pose", w), d, _int(b, "episode", w))


@dataclass
class GoalMsg(Message):
    """The policy's answer for one step: the current long-term goal (None: no reachable frontier)."""

    SCHEMA: ClassVar[str] = "goal"
    VERSION: ClassVar[int] = 2
    step: int
    decided: bool
    """True when this step's frontiers asked for a decision and this is its result."""
    x_m: float | None = None
    y_m: float | None = None
    cluster_index: int = -1
    distance_m: float = 0.0
    decision_ms: float = 0.0
    method: str = ""
    reason: str = ""
    episode: int = 0
    """Episode id of the decision input it answers (v2): a goal still in flight from an episode that has
    ended is never taken for the new one's."""

    @property
    def has_goal(self) -> bool:
        return self.x_m is not None

    @property
    def goal_xy_m(self) -> tuple[float, float] | None:
        """The goal's (x_m, y_m); None when there is none (``has_goal``). Typed: no reader has to assume ``y_m``."""
        return None if self.x_m is None or self.y_m is None else (self.x_m, self.y_m)

    def body(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "decided": self.decided,
            "goal": None if self.x_m is None else [self.x_m, self.y_m, self.cluster_index, self.distance_m],
            "decision_ms": self.decision_ms,
            "method": self.method,
            "reason": self.reason,
            "episode": self.episode,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> GoalMsg:
        w = "goal"
        g = _get(b, "goal", w)
        x = y = None
        idx, dist = -1, 0.0
        if g is not None:
            if not isinstance(g, list) or len(g) != 4:
                raise MessageError("goal.goal: expected [x_m, y_m, cluster_index, distance_m] or null")
            d = dict(zip(("x", "y", "i", "d"), g))
            x, y, idx, dist = _num(d, "x", w), _num(d, "y", w), _int(d, "i", w, 0, 10**9), _num(d, "d", w, 0.0)
        return cls(
            _int(b, "step", w), _bool(b, "decided", w), x, y, idx, dist, _num(b, "decision_ms", w, 0.0), _str(b, "method", w), _str(b, "reason", w), _int(b, "episode", w)
        )


@dataclass
class PathMsg(Message):
    """The planner's current path (metres, robot first); empty when idle."""

    SCHEMA: ClassVar[str] = "path"
    step: int
    path_xy_m: np.ndarray

    def body(self) -> dict[str, Any]:
        return {"step": self.step, "path_xy_m": pack_array(np.asarray(self.path_xy_m, dtype=np.float32).reshape(-1, 2))}

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> PathMsg:
        # no grid beside it: at most a point per cell of the largest grid of the run, as the path ahead and the contacts
        p = unpack_array(_get(b, "path_xy_m", "path"), "path.path_xy_m", finite=True, shape=(None, 2), max_elements=2 * _max_grid_cells, float_as=np.float32)
        return cls(_int(b, "step", "path"), p)


PLANNER_STATUSES = ("idle", "following", "reached", "blocked", "no_progress", "stale")


@dataclass
class PlannerFeedbackMsg(Message):
    """Planner status after this step's map (``check_blocked``) or command (``update``)."""

    SCHEMA: ClassVar[str] = "planner_feedback"
    VERSION: ClassVar[int] = 3
    """2: the path ahead. 3: the episode id."""
    step: int
    status: str
    phase: str
    """``command``: after this step's command (what the frontier service decides the next step on);
    ``map``: after ``check_blocked`` on this step's map (informational)."""
    set_goal_blocked: bool = False
    """True when the last new goal had no path (the decider drops it as a frontier)."""
    reason: str = ""
    path_ahead_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """The path still ahead of the robot (float64, metres), empty unless following: the frontier
    service runs the planner's blocked check on the next map with it (``path_blocked_ahead``)."""
    goal_step: int = -1
    """The decision step of the goal this report is about (-1: none yet). In real time the planner
    commands newer steps than the last decision before its goal arrives; such a report speaks of the
    previous goal and must not be read as the new goal's outcome."""
    episode: int = 0
    """Episode id of the inputs it reports on (v3): a report in flight from an ended episode is never read as
    one of the new episode's."""

    def body(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "episode": self.episode,
            "status": self.status,
            "phase": self.phase,
            "set_goal_blocked": self.set_goal_blocked,
            "reason": self.reason,
            "path_ahead_xy_m": pack_array(np.asarray(self.path_ahead_xy_m, dtype=np.float64).reshape(-1, 2)),
            "goal_step": self.goal_step,
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> PlannerFeedbackMsg:
        w = "planner_feedback"
        path = unpack_array(_get(b, "path_ahead_xy_m", w), "planner_feedback.path_ahead_xy_m", finite=True, shape=(None, 2), max_elements=2 * _max_grid_cells, float_as=np.float64)
        return cls(
            _int(b, "step", w),
            _str(b, "status", w, PLANNER_STATUSES),
            _str(b, "phase", w, ("map", "command")),
            _bool(b, "set_goal_blocked", w),
            _str(b, "reason", w),
            path,
            _int(b, "goal_step", w, lo=-1),
            _int(b, "episode", w),
        )


@dataclass
class PlannerContactsMsg(Message):
    """Every contact the planner keeps in this episode (``LocalPlanner.contacts_xy_m``: cells a pinned robot was pressed
    against, or returns nearer than the sensor's ``range_min``, which no map shows), sent whenever one is added. The
    referee keeps the latest for a restarted planner (``cache/planner/contacts``), so it does not drive into the same
    wall again; never on a step of its own, so the lockstep chain pays nothing for it."""

    SCHEMA: ClassVar[str] = "planner_contacts"
    step: int
    """The step whose command added the newest contact."""
    contacts_xy_m: np.ndarray
    """Contact cell centres (float64 (n, 2), metres, odometry frame), in the order they were added."""
    episode: int = 0
    """Episode id of the inputs the contacts were found on: another episode's are none of this one's."""

    def body(self) -> dict[str, Any]:
        return {"step": self.step, "contacts_xy_m": pack_array(np.asarray(self.contacts_xy_m, dtype=np.float64).reshape(-1, 2)), "episode": self.episode}

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> PlannerContactsMsg:
        w = "planner_contacts"
        contacts = unpack_array(_get(b, "contacts_xy_m", w), "planner_contacts.contacts_xy_m", finite=True, shape=(None, 2), max_elements=2 * _max_grid_cells, float_as=np.float64)
        return cls(_int(b, "step", w), contacts, _int(b, "episode", w))


PLANNER_FOLLOW_STATUSES = tuple(s.value for s in PlannerStatus)
"""The statuses a ``LocalPlanner`` itself is in (``stale`` is the service's, never its follower's)."""


@dataclass
class PlannerPlanMsg(Message):
    """The path the planner follows and the grid it was planned on (``LocalPlanner.path`` and ``free``), sent after the
    step whose command made a new one (a new goal's plan, a re-plan round a contact, or none: blocked, no frontier). The
    referee keeps the latest (``cache/planner/plan``) for a restarted planner, which resumes on it with
    ``planner_state``; never on a step of its own, so the lockstep chain pays nothing for it."""

    SCHEMA: ClassVar[str] = "planner_plan"
    step: int
    """The step whose command made this plan (``planner_state.plan_step`` names it)."""
    path_xy_m: np.ndarray
    """The whole path (float64 (n, 2), metres, robot first, goal last); empty: no path."""
    free: FreeSpace | None = None
    """The grid the path was planned on, less the contacts then known, and that map's obstacles (None: no path)."""
    episode: int = 0

    def body(self) -> dict[str, Any]:
        f = self.free
        free = None
        if f is not None:
            occupied = None if f.occupied is None else pack_array(np.asarray(f.occupied, dtype=bool), compress=True)
            free = {"geometry": _geometry_out(f.geometry), "traversable": pack_array(np.asarray(f.traversable, dtype=bool), compress=True), "occupied": occupied}
            if f.explored is not None:
                free["explored"] = pack_array(np.asarray(f.explored, dtype=bool), compress=True)
        path = pack_array(np.asarray(self.path_xy_m, dtype=np.float64).reshape(-1, 2))
        return {"step": self.step, "episode": self.episode, "path_xy_m": path, "free": free}

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> PlannerPlanMsg:
        w = "planner_plan"
        # at most a point per cell of the run's largest grid, as ``path``'s (decoded before the grid it was planned on)
        path = unpack_array(_get(b, "path_xy_m", w), "planner_plan.path_xy_m", finite=True, shape=(None, 2), max_elements=2 * _max_grid_cells, float_as=np.float64)
        f = _get(b, "free", w)
        free = None
        if f is not None:
            if not isinstance(f, dict):
                raise MessageError("planner_plan.free: expected a mapping or null")
            geometry = _geometry_in(f, w + ".free")
            occupied = None if _get(f, "occupied", w + ".free") is None else _grid_in(f, "occupied", w + ".free", geometry, "bool")
            explored = None if f.get("explored") is None else _grid_in(f, "explored", w + ".free", geometry, "bool")  # optional: older planners send none
            free = FreeSpace(_grid_in(f, "traversable", w + ".free", geometry, "bool"), geometry, occupied, explored)
        return cls(_int(b, "step", w), path, free, _int(b, "episode", w))


@dataclass
class PlannerStateMsg(Message):
    """The planner's state after a step's command (``LocalPlanner.checkpoint`` and what the service adds: the goal's
    step, the command sent and its report's flag), sent after that step's ``cmd_vel``, ``planner/feedback``,
    ``planner/contacts`` and ``planner/plan``. The referee keeps the latest (``cache/planner/state``): a planner
    restarted mid-episode resumes from it on the plan it names, and commands the next steps as the one killed would
    have."""

    SCHEMA: ClassVar[str] = "planner_state"
    step: int
    """The step last commanded."""
    plan_step: int
    """The ``planner_plan`` this state follows (its ``step``; -1: none sent yet)."""
    goal_step: int
    """The decision step of the goal followed (-1: none yet)."""
    no_frontier: bool
    """The last decision found no goal: the robot stays stopped."""
    cmd: CmdVelMsg
    """The command sent at ``step`` (sent again on a lockstep retry of that step)."""
    set_goal_blocked: bool
    """The step's report said the goal of this step's decision had no path."""
    follow: FollowCheckpoint
    episode: int = 0
    contacts: int | None = None
    """How many contacts the planner kept after this step's command (optional; None: not said). The contacts go out on
    ``planner_contacts`` before the ``cmd_vel`` that carries this state, and only grow in an episode (appended in order):
    a restarted planner keeps the first ``contacts`` of those cached, the ones this state had."""

    def body(self) -> dict[str, Any]:
        f = self.follow
        last = None if f.stall_last is None else [*_pose_out(f.stall_last[0]), f.stall_last[1], f.stall_last[2].linear_mps, f.stall_last[2].angular_radps]
        return {
            "step": self.step,
            "episode": self.episode,
            "plan_step": self.plan_step,
            "goal_step": self.goal_step,
            "no_frontier": self.no_frontier,
            "cmd": self.cmd.command_body(),
            "set_goal_blocked": self.set_goal_blocked,
            "status": f.status.value,
            "progress_index": f.progress_index,
            "progress_anchor": None if f.progress_anchor is None else list(f.progress_anchor),
            "stall": {
                "last": last, "stalled_periods": f.stalled_periods, "backing_up": 0 if f.backing_up is None else 1, "backups": f.backups,
                "last_started_now": f.last_started_now, "backup_from": None if f.backing_up is None else [*_pose_out(f.backing_up[0]), f.backing_up[1]],
            },
            "recovery": {
                "recoveries_left": f.recoveries_left, "heading_rad": f.escape_heading_rad, "drive_left_m": f.escape_drive_left_m,
                "escape_periods": f.escape_periods, "escapes": f.escapes, "started_s": f.escape_started_s,
            },
            "replan_pending": f.replan_pending,
            "blocked_why": f.blocked_why,
            **({} if self.contacts is None else {"contacts": self.contacts}),
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> PlannerStateMsg:
        w = "planner_state"
        cmd = _get(b, "cmd", w)
        if not isinstance(cmd, dict):
            raise MessageError("planner_state.cmd: expected a mapping")
        anchor = _get(b, "progress_anchor", w)
        if anchor is not None:
            if not isinstance(anchor, list) or len(anchor) != 3:
                raise MessageError("planner_state.progress_anchor: expected [x_m, y_m, time_s] or null")
            a = dict(zip("xyt", anchor))
            anchor = (_num(a, "x", w + ".progress_anchor"), _num(a, "y", w + ".progress_anchor"), _num(a, "t", w + ".progress_anchor"))
        stall, recovery = _get(b, "stall", w), _get(b, "recovery", w)
        if not isinstance(stall, dict) or not isinstance(recovery, dict):
            raise MessageError("planner_state.stall, .recovery: expected mappings")
        ws, wr = w + ".stall", w + ".recovery"
        last = _get(stall, "last", ws)
        if last is not None:
            if not isinstance(last, list) or len(last) != 6:
                raise MessageError("planner_state.stall.last: expected [x_m, y_m, yaw_rad, time_s, linear_mps, angular_radps] or null")
            d = dict(zip(("pose", "t", "v", "w"), ([last[0], last[1], last[2]], *last[3:])))
            last = (_pose_in(d, "pose", ws + ".last"), _num(d, "t", ws + ".last"), VelocityCommand(_num(d, "v", ws + ".last", -100, 100), _num(d, "w", ws + ".last", -100, 100)))
        heading = None if _get(recovery, "heading_rad", wr) is None else _num(recovery, "heading_rad", wr, -10.0, 10.0)
        # ``backup_from`` and ``started_s`` are optional (an older planner's state has neither, and counts its back-up
        # in periods to go): a back-up or an escape running without them goes on as if started at ``last``.
        # ``backing_up`` (required, a count) says whether a back-up runs; ``backup_from`` only where it started.
        running = _int(stall, "backing_up", ws) > 0
        backup_from = stall.get("backup_from")
        backing_up: tuple[Pose2D, float] | None = None
        if backup_from is not None:
            if not isinstance(backup_from, list) or len(backup_from) != 4:
                raise MessageError("planner_state.stall.backup_from: expected [x_m, y_m, yaw_rad, time_s] or null")
            d = {"pose": backup_from[:3], "t": backup_from[3]}
            started = (_pose_in(d, "pose", ws + ".backup_from"), _num(d, "t", ws + ".backup_from"))
            backing_up = started if running else None
        elif running and last is not None:
            backing_up = (last[0], last[1])
        started_s = _num(recovery, "started_s", wr) if recovery.get("started_s") is not None else (last[1] if last is not None else 0.0)
        follow = FollowCheckpoint(
            PlannerStatus(_str(b, "status", w, PLANNER_FOLLOW_STATUSES)),
            _int(b, "progress_index", w),
            anchor,
            last,
            _int(stall, "stalled_periods", ws),
            backing_up,
            _int(stall, "backups", ws),
            _bool(stall, "last_started_now", ws),
            _int(recovery, "recoveries_left", wr),
            heading,
            _num(recovery, "drive_left_m", wr),
            _int(recovery, "escape_periods", wr),
            _int(recovery, "escapes", wr),
            _bool(b, "replan_pending", w),
            _str(b, "blocked_why", w),
            started_s,
        )
        return cls(
            _int(b, "step", w), _int(b, "plan_step", w, lo=-1), _int(b, "goal_step", w, lo=-1), _bool(b, "no_frontier", w),
            CmdVelMsg.from_body(cmd), _bool(b, "set_goal_blocked", w), follow, _int(b, "episode", w),
            None if b.get("contacts") is None else _int(b, "contacts", w),
        )  # fmt: skip


@dataclass
class EndedWhyMsg(Message):
    """Why the decision of ``step`` found no goal (the episode ends ``no_frontier``): the frontier service's
    ``episode.ended_no_frontier_why`` on that decision's Observation and given-up frontiers, sent once the policy's
    empty goal has come back, for the referee's result (``EpisodeResultMsg.ended_why``)."""

    SCHEMA: ClassVar[str] = "ended_why"
    step: int
    why: str
    episode: int = 0
    """Episode id of the decision, as on its ``frontiers``."""

    def body(self) -> dict[str, Any]:
        return {"step": self.step, "why": self.why, "episode": self.episode}

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> EndedWhyMsg:
        w = "ended_why"
        return cls(_int(b, "step", w), _str(b, "why", w), _int(b, "episode", w))


def new_episode_id() -> int:
    """A fresh episode id (48 random bits): every publisher of ``clock`` draws one per episode, so
    subscribers detect a new episode by the id, not by the step going back (messages on different keys
    may be handled out of order). Never 0, which reads as no id where an id is optional (``EpisodeResultMsg.episode``,
    ``CmdVelMsg.episode``)."""
    while True:
        episode = secrets.randbits(48)
        if episode:
            return episode


@dataclass
class ClockMsg(Message):
    """Simulated time: the step number and its time in seconds, in one episode."""

    SCHEMA: ClassVar[str] = "clock"
    VERSION: ClassVar[int] = 2
    step: int
    time_s: float
    arena: GridGeometry | None = None
    """Extent of the area the robot may map (the mapper sizes its grid from it unless configured)."""
    episode: int = 0
    """Episode id (``new_episode_id``): a change means a new episode (the mapper starts a new map)."""

    def body(self) -> dict[str, Any]:
        b: dict[str, Any] = {"step": self.step, "time_s": self.time_s, "episode": self.episode}
        if self.arena is not None:
            b["geometry"] = _geometry_out(self.arena)
        return b

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> ClockMsg:
        arena = _geometry_in(b, "clock") if "geometry" in b else None
        return cls(_int(b, "step", "clock"), _num(b, "time_s", "clock", 0.0), arena, _int(b, "episode", "clock"))


@dataclass
class ExploreResumeMsg(Message):
    """An operator's pause or resume of exploration, as m-explore's ``explore/resume`` (std_msgs/Bool): ``resume``
    false pauses (the planner commands zero velocity, no goal is applied), true resumes. No step: a control, not
    data of a step; the launcher keeps the latest and serves it on ``cache/explore/resume`` for restarted services."""

    SCHEMA: ClassVar[str] = "explore_resume"
    resume: bool
    by: str = ""
    """Who sent it (``cso-runtime pause``: user@host; the ROS 2 bridge: ``ros2 NS/explore/resume``)."""
    reason: str = ""
    stamp_s: float = 0.0
    """When it was sent (Unix time, s; 0: unknown)."""

    def body(self) -> dict[str, Any]:
        return {"resume": self.resume, "by": self.by, "reason": self.reason, "stamp_s": self.stamp_s}

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> ExploreResumeMsg:
        w = "explore_resume"
        return cls(_bool(b, "resume", w), _str(b, "by", w, max_len=256), _str(b, "reason", w, max_len=MAX_RESUME_REASON_CHARS), _num(b, "stamp_s", w, 0.0))


MAX_RESUME_REASON_CHARS = 1024
"""The most characters of a pause's ``reason`` (``cso-runtime pause --reason``): a longer one is refused by every
receiver, so ``pause`` refuses it before sending (it was sent, dropped by all, and the robot went on)."""


ROS_RESUME_BY = "ros2 "
"""What ``ExploreResumeMsg.by`` starts with when the ROS 2 bridge heard it on ``explore/resume`` (then that key): it is
resumed there too, with ``{data: true}``."""


EPISODE_STATES = ("starting", "exploring", "done", "failed")
EPISODE_OVER = ("done", "failed")
"""The states of an episode that has ended: nothing is waited for after them."""


@dataclass
class EpisodeStatusMsg(Message):
    """Ground-truth progress of the episode, published by the sim (the only one that knows the truth)."""

    SCHEMA: ClassVar[str] = "episode_status"
    VERSION: ClassVar[int] = 4
    """2: the episode id. 3: the scene's ``map_origin``. 4: the robot's ``pose`` and ``twist``."""
    state: str
    step: int
    scene: str = ""
    method: str = ""
    coverage_pct: float = 0.0
    explored_area_m2: float = 0.0
    path_length_m: float = 0.0
    goal_xy_m: list[float] | None = None
    decisions: int = 0
    last_decision_ms: float = 0.0
    terminated_by: str = ""
    reason: str = ""
    lockstep_timeouts: int = 0
    episode: int = 0
    """Episode id, as on ``clock``."""
    map_origin: Pose2D = MAP_FRAME_ORIGIN
    """The scene's pose in the user's map frame (``FloorPlan.map_origin``): ``goal_xy_m``, like every pose on the
    network, is in the scene's own frame; ``status`` shows it in the map frame."""
    pose: Pose2D | None = None
    """The robot's odometry pose at ``step`` in the scene's own frame (that step's ``odom``), which ``status`` and the live
    view show in the map frame as they show the goal (``status.status_of``: x, y in metres, yaw in radians, REP-103);
    None before the first odometry (a ROS 2 bridge before its first scan) and in a recording from before v4."""
    twist: VelocityCommand | None = None
    """The robot's twist on that odometry (forward m/s, yaw rad/s, in its own body frame); None as ``pose``."""
    coverage_measured: bool | None = None
    """Whether the referee has a ground truth, its ``coverage_pct`` a measure: the sim's True, a ROS 2 bridge's False
    (a real robot), a referee of one's own as it knows (its own simulator publishing the sim's keys: True). What
    ``status`` and the launcher take before their judgement by the run's services (``run_profile.measures_coverage``).
    Optional within v4, no version bump: None, not said (a referee from before it, or one that does not say), is sent
    as no field at all, the body an older reader always got; a reader ignores a field it does not know."""

    def body(self) -> dict[str, Any]:
        body = {
            "state": self.state,
            "step": self.step,
            "scene": self.scene,
            "method": self.method,
            "coverage_pct": self.coverage_pct,
            "explored_area_m2": self.explored_area_m2,
            "path_length_m": self.path_length_m,
            "goal_xy_m": self.goal_xy_m,
            "decisions": self.decisions,
            "last_decision_ms": self.last_decision_ms,
            "terminated_by": self.terminated_by,
            "reason": self.reason,
            "lockstep_timeouts": self.lockstep_timeouts,
            "episode": self.episode,
            "map_origin": _pose_out(self.map_origin),
            "pose": None if self.pose is None else _pose_out(self.pose),
            "twist": None if self.twist is None else _twist_out(self.twist),
        }
        if self.coverage_measured is not None:
            body["coverage_measured"] = self.coverage_measured
        return body

    @property
    def goal_in_map_frame(self) -> list[float] | None:
        """``goal_xy_m`` in the user's map frame (``map_origin``), as ``status`` and the live view show it."""
        return None if self.goal_xy_m is None else map_frame_xy(self.map_origin, self.goal_xy_m)

    @property
    def pose_in_map_frame(self) -> Pose2D | None:
        """``pose`` in the user's map frame (``map_origin``), as ``status`` and the live view show it."""
        return map_frame_pose(self.map_origin, self.pose)

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> EpisodeStatusMsg:
        w = "episode_status"
        g = _get(b, "goal_xy_m", w)
        if g is not None:
            if not isinstance(g, list) or len(g) != 2:
                raise MessageError("episode_status.goal_xy_m: expected [x_m, y_m] or null")
            g = [_num({"x": g[0]}, "x", w), _num({"y": g[1]}, "y", w)]
        return cls(
            _str(b, "state", w, EPISODE_STATES),
            _int(b, "step", w),
            _str(b, "scene", w),
            _str(b, "method", w),
            _num(b, "coverage_pct", w, 0.0, 100.0 + 1e-6),
            _num(b, "explored_area_m2", w, 0.0),
            _num(b, "path_length_m", w, 0.0),
            g,
            _int(b, "decisions", w),
            _num(b, "last_decision_ms", w, 0.0),
            _str(b, "terminated_by", w),
            _str(b, "reason", w),
            _int(b, "lockstep_timeouts", w),
            _int(b, "episode", w),
            _pose_in(b, "map_origin", w),
            None if _get(b, "pose", w) is None else _pose_in(b, "pose", w),
            None if _get(b, "twist", w) is None else _twist_in(b, "twist", w),
            None if b.get("coverage_measured") is None else _bool(b, "coverage_measured", w),  # optional: absent or nil, not said
        )

    def to_dict(self) -> dict[str, Any]:
        return self.body()


@dataclass
class EpisodeResultMsg(Message):
    """The finished episode: what ``eval`` writes (EpisodeResult) plus the plan for the plots."""

    SCHEMA: ClassVar[str] = "episode_result"
    VERSION: ClassVar[int] = 4
    """2: the boolean grids travel bit-packed (``pack_array``). 3: the robot's final map (``final_map``).
    4: the scene's ``map_origin``."""
    scene: str
    steps: int
    explored_area_m2: float
    coverage_pct: float
    traversable_area_m2: float
    path_length_m: float
    terminated_by: str
    decisions: int
    decision_ms: np.ndarray
    trajectory_xy_m: np.ndarray
    coverage_curve_pct: np.ndarray
    explored_free: np.ndarray
    plan_free: np.ndarray
    resolution_m: float
    method: str = ""
    seed: int = 0
    final_map: MapMsg | None = None
    """The last map the referee received from the mapper (None: no map arrived), written as map_server files."""
    map_origin: Pose2D = MAP_FRAME_ORIGIN
    """The scene's pose in the user's map frame (``FloorPlan.map_origin``): where the final map's files are placed."""
    ended_why: str = ""
    """Why it ended, where ``terminated_by`` alone does not say (``EpisodeResult.ended_why``: the frontier service's
    ``ended_why`` for ``no_frontier``); empty otherwise. Optional on decoding (older referees do not send it); absent
    while empty."""
    episode: int = 0
    """Episode id of the episode it is the result of, as on its ``episode_status`` (the sim's and the ros2_bridge's):
    the launcher takes a result for the end it judges only when it is of that end's episode (``Launcher.result_of``),
    so a late result of an episode a restart left behind is never the next episode's. Optional within v4, no version
    bump: 0, no id (a referee from before it, or one of one's own without ids), is sent as no field at all, and such a
    result is taken for whichever end is judged, as before."""

    SCALARS: ClassVar[tuple[str, ...]] = ("explored_area_m2", "coverage_pct", "traversable_area_m2", "path_length_m", "resolution_m")

    def body(self) -> dict[str, Any]:
        for name in ("explored_free", "plan_free"):  # grids without a geometry: checked as ``_geometry_out`` checks one
            shape = np.shape(getattr(self, name))
            if len(shape) == 2:
                check_grid_fits((shape[0], shape[1]), f"episode_result.{name}")
        b: dict[str, Any] = {k: float(getattr(self, k)) for k in self.SCALARS}
        b.update(
            scene=self.scene,
            steps=self.steps,
            terminated_by=self.terminated_by,
            decisions=self.decisions,
            method=self.method,
            seed=self.seed,
            decision_ms=pack_array(np.asarray(self.decision_ms, dtype=np.float64)),
            trajectory_xy_m=pack_array(np.asarray(self.trajectory_xy_m, dtype=np.float64).reshape(-1, 2)),
            coverage_curve_pct=pack_array(np.asarray(self.coverage_curve_pct, dtype=np.float64)),
            explored_free=pack_array(np.asarray(self.explored_free, dtype=bool), compress=True),
            plan_free=pack_array(np.asarray(self.plan_free, dtype=bool), compress=True),
            final_map=self.final_map.body() if self.final_map is not None else None,
            map_origin=_pose_out(self.map_origin),
        )
        if self.ended_why:
            b["ended_why"] = self.ended_why
        if self.episode:
            b["episode"] = self.episode
        return b

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> EpisodeResultMsg:
        w = "episode_result"
        scalars = {k: _num(b, k, w, 0.0) for k in cls.SCALARS}
        ef = unpack_array(_get(b, "explored_free", w), w + ".explored_free", ndim=2, dtypes=("bool",))
        pf = unpack_array(_get(b, "plan_free", w), w + ".plan_free", dtypes=("bool",), shape=ef.shape)
        # one entry per step (trajectory, coverage) or per decision: at most MAX_STEP_POINTS each
        traj = unpack_array(_get(b, "trajectory_xy_m", w), w + ".trajectory_xy_m", finite=True, shape=(None, 2), max_elements=2 * MAX_STEP_POINTS, float_as=np.float64)
        decision_ms = unpack_array(_get(b, "decision_ms", w), w + ".decision_ms", finite=True, shape=(None,), max_elements=MAX_STEP_POINTS, float_as=np.float64)
        coverage = unpack_array(
            _get(b, "coverage_curve_pct", w), w + ".coverage_curve_pct", finite=True, shape=(None,), max_elements=MAX_STEP_POINTS, float_as=np.float64
        )
        if (decision_ms < 0).any() or (coverage < 0).any():
            raise MessageError(f"{w}: negative decision times or coverage")
        final_map = _get(b, "final_map", w)
        if final_map is not None and not isinstance(final_map, dict):
            raise MessageError(f"{w}.final_map: expected a map body or nil")
        return cls(
            scene=_str(b, "scene", w),
            steps=_int(b, "steps", w),
            terminated_by=_str(b, "terminated_by", w),
            decisions=_int(b, "decisions", w),
            decision_ms=decision_ms,
            trajectory_xy_m=traj,
            coverage_curve_pct=coverage,
            explored_free=ef,
            plan_free=pf,
            method=_str(b, "method", w),
            seed=_int(b, "seed", w, -(2**62)),
            final_map=MapMsg.from_body(final_map, where=f"{w}.final_map") if final_map is not None else None,
            map_origin=_pose_in(b, "map_origin", w),
            ended_why=_str(b, "ended_why", w) if "ended_why" in b else "",
            episode=_int(b, "episode", w) if b.get("episode") is not None else 0,  # optional: absent or nil, no id
            **scalars,
        )


@dataclass
class ServiceStatusMsg(Message):
    """One service's own health: what it last did, why it is not commanding, what it rejected, and its own
    counts (``counters``, from v2: ``Service.extra_status``, e.g. the ROS 2 bridge's scans received, Twists sent,
    watchdog stops)."""

    SCHEMA: ClassVar[str] = "service_status"
    VERSION: ClassVar[int] = 2
    service: str
    robot: str
    state: str
    """``running`` or ``stale`` (inputs too old: the service does not command)."""
    last_step: int = 0
    reason: str = ""
    rejected: dict[str, int] = field(default_factory=dict)
    """Rejected payloads per input key suffix (malformed, out of range, non-finite, unknown version)."""
    processed: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    """The service's own counts by name (non-negative integers; empty for a service that keeps none)."""

    def body(self) -> dict[str, Any]:
        return {
            "service": self.service,
            "robot": self.robot,
            "state": self.state,
            "last_step": self.last_step,
            "reason": self.reason,
            "rejected": dict(self.rejected),
            "processed": self.processed,
            "counters": dict(self.counters),
        }

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> ServiceStatusMsg:
        w = "service_status"
        rej = _counts(b, "rejected", w)
        return cls(
            _str(b, "service", w),
            _str(b, "robot", w),
            _str(b, "state", w, ("running", "stale")),
            _int(b, "last_step", w),
            _str(b, "reason", w),
            dict(rej),
            _int(b, "processed", w),
            dict(_counts(b, "counters", w)),
        )

    def to_dict(self) -> dict[str, Any]:
        return self.body()


LAUNCHER_SERVICE_FIELDS: dict[str, type] = {
    "pid": int,
    "process_alive": bool,
    "liveliness": bool,
    "came_up": bool,
    "restarts": int,
    "gave_up": bool,
    "hung_kills": int,
    "robot_stops": int,
    "outside": bool,
    "awaited": bool,
    "command": bool,
}
"""The fields of each service in ``launcher_status.services`` and their types (counts: non-negative integers).
Each is optional: an older launcher sends fewer (``robot_stops``, the zero Twists the launcher sent for a ROS 2
bridge that died, came later; ``outside``, a service of the robot that the launcher did not start, such as a shared
policy server's, later still; ``awaited``, beside ``outside``: the episode waits for it, a policy and not a viewer's
bridge, then; ``came_up``, whether its current process has been seen alive, its liveliness token there, so that one
whose token is gone again, a process stopped or hung, reads "not answering", not "starting", last), and a newer one's unknown fields are left out."""


LAST_EPISODE_FIGURES: dict[str, Callable[[dict, str, str], Any]] = {
    "terminated_by": lambda b, k, w: _str(b, k, w, max_len=64),
    "scene": lambda b, k, w: _str(b, k, w),
    "method": lambda b, k, w: _str(b, k, w, max_len=64),
    "coverage_pct": lambda b, k, w: _num(b, k, w, lo=0.0),
    "explored_area_m2": lambda b, k, w: _num(b, k, w, lo=0.0),
    "path_length_m": lambda b, k, w: _num(b, k, w, lo=0.0),
    "decisions": _int,
    "reason": lambda b, k, w: _str(b, k, w),
    "map_origin": lambda b, k, w: _pose_in(b, k, w).as_list(),
    "pose": lambda b, k, w: None if b[k] is None else _pose_in(b, k, w).as_list(),
    "twist": lambda b, k, w: None if b[k] is None else _twist_out(_twist_in(b, k, w)),
}
"""The figures of the last episode status that the launcher's ``last_episode`` also carries (as ``episode_status``'s
body has them), with their readers: what ``status`` shows of an episode whose sim no longer answers (an ended run
stopping its services; ``reason``: why it ended, as ``no_frontier_why`` says it, or failed; ``pose`` and ``twist``:
where the robot was then and how it moved, in the scene's frame, which ``map_origin`` places in the user's map frame)."""


LOST_RESULTS_KEPT = 16
"""How many of the run's episodes whose result was lost to a restart of the referee ``launcher_status`` names (the
latest): one per restart of the sim after an episode's end, so a handful at most."""


def lost_results_of(v: Any, where: str) -> list[dict[str, Any]]:
    """``launcher_status.lost_results`` (and run.json's, ``runs``): absent or nil (an older launcher's) is none."""
    if v is None:
        return []
    if not isinstance(v, list) or len(v) > LOST_RESULTS_KEPT or not all(isinstance(e, dict) for e in v):
        raise MessageError(f"{where}: expected a list of at most {LOST_RESULTS_KEPT} mappings")
    return [
        {"episode": _int(e, "episode", where), "state": _str(e, "state", where, max_len=64), "step": _int(e, "step", where), "running": _int(e, "running", where)}
        for e in v
    ]


@dataclass
class LauncherStatusMsg(Message):
    """The launcher's view: run id, each service process (pid, alive, restarts, given up), rejections, and
    its own callbacks that raised (``handler_errors``: optional on decoding, older launchers do not send it)."""

    SCHEMA: ClassVar[str] = "launcher_status"
    run_id: str
    state: str
    services: dict[str, dict[str, Any]] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    handler_errors: dict[str, int] = field(default_factory=dict)
    last_episode: dict[str, Any] | None = None
    """The last episode status the launcher heard (``state``, ``step``, ``episode`` and its ``LAST_EPISODE_FIGURES``,
    each optional on decoding) and ``age_s``, the seconds since: what ``status`` says when the sim does not answer
    (stopped, hung, or stopped after the episode) instead of "starting". Optional on decoding (older launchers do not
    send it); None before the first."""
    real_time_factor: float | None = None
    """The simulator's simulated seconds per wall-clock second in the episode so far, as ``up``'s live view shows it
    (``pace.StepPace``). Optional on decoding (older launchers do not send it); None on a real robot and before two
    statuses of the episode."""
    lost_router: str | None = None
    """The router(s) the run joined (``--connect``: the robot's zenoh bridge) while the launcher has lost its route to
    them; None while they are reached, or when the run joined none. Optional on decoding (older launchers do not send
    it): with the run's own router the services still answer, so ``status`` learns it only here."""
    run_dir_lost: int = 0
    """How many times the launcher found its run folder (or its ``logs/``) deleted while the run ran, and made it again
    (``Launcher.tend_run_folder``). Optional on decoding (older launchers do not send it); absent while 0."""
    pause: dict[str, Any] | None = None
    """Whether exploration is paused (``explore/resume``): ``paused``, ``by``, ``reason``, ``for_s`` (this pause),
    ``total_s`` (every pause of the run) and ``refused`` (why this run cannot pause, a lockstep one; "" when it can)
    (``pause.PauseClock.status``). Optional on decoding (older launchers do not send it)."""
    coverage_measured: bool | None = None
    """Whether the run has a ground truth, its ``coverage_pct`` a measure (``run_profile.measures_coverage``: its sim's;
    a real robot's or a referee's of one's own is not): the one answer ``status`` gives, as ``up``'s live view and
    report.html. Optional on decoding (older launchers do not send it: ``status`` then judges by the services); None,
    absent."""
    referee: str | None = None
    """Which kind of referee runs the run's episode, as its profile's services say (``run_profile.referee_kind``):
    ``sim``, ``ros2_bridge`` or ``own`` (one of one's own: a command node publishing ``episode_status``, no real robot),
    so that ``status`` words a coverage it has no ground truth for as the run's (``live_view.no_ground_truth_words``).
    Optional on decoding (older launchers do not send it: ``status`` then says a real robot's); None, absent."""
    lost_results: list[dict[str, Any]] = field(default_factory=list)
    """The episodes whose result was lost to a restart of the referee (``Launcher.end_left_behind``: the sim restarted
    into a new episode before the ended one's result came, and the run went on with the new one), oldest first, the
    latest ``LOST_RESULTS_KEPT`` of the run: each ``episode`` (its id), ``state`` and ``step`` (of its end, as its
    ``episode_status`` said) and ``running`` (the episode the run went on with), which ``status`` says in words.
    Optional on decoding (older launchers do not send it); absent while empty."""

    def body(self) -> dict[str, Any]:
        body: dict[str, Any] = {"run_id": self.run_id, "state": self.state, "services": self.services, "rejected": self.rejected, "handler_errors": self.handler_errors}
        if self.lost_results:
            body["lost_results"] = self.lost_results
        if self.coverage_measured is not None:
            body["coverage_measured"] = self.coverage_measured
        if self.referee is not None:
            body["referee"] = self.referee
        if self.pause is not None:
            body["pause"] = self.pause
        if self.run_dir_lost:
            body["run_dir_lost"] = self.run_dir_lost
        if self.last_episode is not None:
            body["last_episode"] = self.last_episode
        if self.real_time_factor is not None:
            body["real_time_factor"] = self.real_time_factor
        if self.lost_router is not None:
            body["lost_router"] = self.lost_router
        return body

    @classmethod
    def from_body(cls, b: dict[str, Any]) -> LauncherStatusMsg:
        w = "launcher_status"
        services = _get(b, "services", w)
        if not isinstance(services, dict) or not all(isinstance(k, str) and isinstance(v, dict) for k, v in services.items()):
            raise MessageError("launcher_status.services: expected a mapping of mappings")
        checked: dict[str, dict[str, Any]] = {}
        for name, entry in services.items():  # what `status` prints and writes as JSON: known fields of known types
            checked[name] = {}
            for key, value in entry.items():
                kind = LAUNCHER_SERVICE_FIELDS.get(key)
                if kind is None:
                    continue  # a newer launcher's field: left out (this side would not know how to show it)
                ok = isinstance(value, bool) if kind is bool else (isinstance(value, int) and not isinstance(value, bool) and value >= 0)
                if not ok:
                    raise MessageError(f"launcher_status.services.{name}.{key}: expected {'true or false' if kind is bool else 'a count'}, got {value!r}")
                checked[name][key] = value
        services = checked
        last = b.get("last_episode")
        if last is not None:
            if not isinstance(last, dict):
                raise MessageError("launcher_status.last_episode: expected a mapping")
            lw = "launcher_status.last_episode"
            heard = last
            last = {"state": _str(heard, "state", lw, max_len=64), "step": _int(heard, "step", lw), "episode": _int(heard, "episode", lw), "age_s": _num(heard, "age_s", lw, lo=0.0)}
            for key, read in LAST_EPISODE_FIGURES.items():  # optional: older launchers send none of them
                if key in heard:
                    last[key] = read(heard, key, lw)
        pace = None if b.get("real_time_factor") is None else _num(b, "real_time_factor", w, lo=0.0)
        lost = None if b.get("lost_router") is None else _str(b, "lost_router", w, max_len=1024)
        run_dir_lost = _int(b, "run_dir_lost", w, lo=0) if "run_dir_lost" in b else 0
        pause = None
        if b.get("pause") is not None:
            heard, pw = b["pause"], "launcher_status.pause"
            if not isinstance(heard, dict):
                raise MessageError(f"{pw}: expected a mapping")
            pause = {"paused": _bool(heard, "paused", pw), "by": _str(heard, "by", pw, max_len=256), "reason": _str(heard, "reason", pw, max_len=1024)}
            pause.update(for_s=_num(heard, "for_s", pw, lo=0.0), total_s=_num(heard, "total_s", pw, lo=0.0), refused=_str(heard, "refused", pw, max_len=1024))
        measured = None if b.get("coverage_measured") is None else _bool(b, "coverage_measured", w)
        referee = None if b.get("referee") is None else _str(b, "referee", w, max_len=64)
        return cls(
            _str(b, "run_id", w), _str(b, "state", w), services, _counts(b, "rejected", w), _counts(b, "handler_errors", w, optional=True), last, pace, lost, run_dir_lost,
            pause, measured, referee, lost_results_of(b.get("lost_results"), f"{w}.lost_results"),
        )

    def to_dict(self) -> dict[str, Any]:
        return self.body()


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.SCHEMA: cls
    for cls in (
        ScanMsg,
        OdometryMsg,
        CmdVelMsg,
        MapMsg,
        FrontiersMsg,
        DistanceMapMsg,
        GoalMsg,
        PathMsg,
        PlannerFeedbackMsg,
        PlannerContactsMsg,
        PlannerPlanMsg,
        PlannerStateMsg,
        EndedWhyMsg,
        ClockMsg,
        EpisodeStatusMsg,
        EpisodeResultMsg,
        ServiceStatusMsg,
        LauncherStatusMsg,
        ExploreResumeMsg,
    )
}


def encode(msg: Message) -> bytes:
    """The wire bytes of ``msg``."""
    return msgpack.packb({"schema": msg.SCHEMA, "v": msg.VERSION, "body": msg.body()}, use_bin_type=True)


def _envelope(payload: bytes) -> tuple[str, Any, Any]:
    """(schema, version, body) of a payload of a known schema; version and body not checked yet."""
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise MessageError("payload is not bytes")
    try:
        raw = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=True, max_bin_len=max_bin_bytes())
    except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError, TypeError) as exc:
        raise MessageError(f"not a msgpack payload ({type(exc).__name__}: {exc})") from None
    if not isinstance(raw, dict) or set(raw) != {"schema", "v", "body"}:
        raise MessageError("payload is not a {schema, v, body} envelope")
    schema, version, body = raw["schema"], raw["v"], raw["body"]
    if not isinstance(schema, str) or schema not in MESSAGE_TYPES:
        raise MessageError(f"unknown schema {schema!r}")
    return schema, version, body


def _is_current(schema: str, version: Any) -> bool:
    return not isinstance(version, bool) and isinstance(version, int) and version == MESSAGE_TYPES[schema].VERSION


def _from_body(schema: str, cls: type[Message], body: Any) -> Message:
    if not isinstance(body, dict):
        raise MessageError(f"{schema}: body is not a mapping")
    try:
        return cls.from_body(body)
    except MessageError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, OverflowError) as exc:
        raise MessageError(f"{schema}: malformed body ({type(exc).__name__}: {exc})") from None


M = TypeVar("M", bound=Message)
"""A message class ``decode`` is asked for: what it returns."""


@overload
def decode(payload: bytes, expected: type[M], accept_legacy: bool = False) -> M: ...
@overload
def decode(payload: bytes, expected: None = None, accept_legacy: bool = False) -> Message: ...
def decode(payload: bytes, expected: type[Message] | None = None, accept_legacy: bool = False) -> Message:
    """Parse and validate a payload; raises MessageError for anything it cannot trust.

    ``accept_legacy``: a payload of an older version listed in ``LEGACY_UPGRADES`` is read as the current
    one. For offline readers of recordings only; a live service stays strict (the default)."""
    schema, version, body = _envelope(payload)
    legacy = not _is_current(schema, version)
    if legacy and not accept_legacy:
        raise MessageError(f"{schema}: unknown version {version!r} (this build speaks v{MESSAGE_TYPES[schema].VERSION})")
    if expected is not None and schema != expected.SCHEMA:
        raise MessageError(f"expected schema {expected.SCHEMA!r}, got {schema!r}")
    if legacy:
        body = _upgraded_body(schema, version, body)
    # ``expected`` may be a narrower view of the schema (``PlannerFrontiersMsg``): it decodes what it reads.
    return _from_body(schema, expected or MESSAGE_TYPES[schema], body)


# --- older versions, in recordings ------------------------------------------------------------


def _episode_id_0(body: dict[str, Any]) -> dict[str, Any]:
    """A body from before its schema carried the episode id (b3bfa9e, 2aebc8d): id 0, which
    ``services.common.EpisodeWatch`` reads as "no id", as from any publisher without ids. A ``frontiers``
    body of v6 written between b3bfa9e and its version's bump to 7 already has its id, and keeps it."""
    return {"episode": 0, **body}


def _no_counters(body: dict[str, Any]) -> dict[str, Any]:
    """A ``service_status`` body from before it carried the service's own counts: none."""
    return {"counters": {}, **body}


def _map_frame_origin(body: dict[str, Any]) -> dict[str, Any]:
    """An ``episode_status`` or ``episode_result`` body from before it carried the scene's ``map_origin``: the
    scene's frame was taken as the map frame then."""
    return {"map_origin": _pose_out(MAP_FRAME_ORIGIN), **body}


def _no_robot_pose(body: dict[str, Any]) -> dict[str, Any]:
    """An ``episode_status`` body from before it carried the robot's ``pose`` and ``twist`` (v3): none, unknown (the
    recording's ``odom`` has them), as before a ROS 2 bridge's first scan."""
    return {"pose": None, "twist": None, **body}


def _command_alone(body: dict[str, Any]) -> dict[str, Any]:
    """A ``cmd_vel`` v2 body, from before it could carry the planner's episode, state and plan (all optional): as it is."""
    return body


def _map_frame_origin_no_robot_pose(body: dict[str, Any]) -> dict[str, Any]:
    """An ``episode_status`` v2 body: neither the scene's ``map_origin`` nor the robot's pose."""
    return _no_robot_pose(_map_frame_origin(body))


LEGACY_UPGRADES: dict[tuple[str, int], Callable[[dict[str, Any]], dict[str, Any]]] = {
    ("odom", 1): _episode_id_0,
    ("goal", 1): _episode_id_0,
    ("frontiers", 6): _episode_id_0,
    ("distance_map", 1): _episode_id_0,
    ("planner_feedback", 2): _episode_id_0,
    ("service_status", 1): _no_counters,
    ("episode_status", 2): _map_frame_origin_no_robot_pose,
    ("episode_status", 3): _no_robot_pose,
    ("episode_result", 3): _map_frame_origin,
    ("cmd_vel", 2): _command_alone,
}
"""(schema, older version) -> its body as a body of the current version, for the changes that only added
a field. Recordings outlive a version: the offline tools that read them (replay, export-bag, animate) read
these versions too (``upgrade_payload``, ``decode(accept_legacy=True)``). A live service does not: a
message of another version on a running network is a build out of step, to be rejected and counted."""


def _readable_versions(schema: str) -> list[int]:
    """The versions of ``schema`` the offline tools read: the current one, then the older ones, newest first."""
    older = sorted((v for s, v in LEGACY_UPGRADES if s == schema), reverse=True)
    return [MESSAGE_TYPES[schema].VERSION, *older]


def _upgraded_body(schema: str, version: Any, body: Any) -> dict[str, Any]:
    """``body`` of an older ``version`` as a body of the current one; MessageError for a version no table lists."""
    upgrade = None if isinstance(version, bool) or not isinstance(version, int) else LEGACY_UPGRADES.get((schema, version))
    if upgrade is None:
        readable = ", ".join(f"v{v}" for v in _readable_versions(schema))
        raise MessageError(f"{schema}: unknown version {version!r} (this build reads {readable})")
    if not isinstance(body, dict):
        raise MessageError(f"{schema}: body is not a mapping")
    return upgrade(body)


def upgrade_payload(payload: bytes) -> bytes:
    """The wire bytes of ``payload`` in the current version of its schema: ``payload`` itself when it is
    current (not checked further: the reader's ``decode`` does that), else, for an older version listed in
    ``LEGACY_UPGRADES``, its upgraded body, checked as ``decode`` checks a body. So a replayed recording
    drives today's services. MessageError for anything else (not an envelope, an unknown schema or version,
    a body that does not decode), naming the versions this build reads."""
    schema, version, body = _envelope(payload)
    if _is_current(schema, version):
        return payload
    cls = MESSAGE_TYPES[schema]
    body = _upgraded_body(schema, version, body)
    _from_body(f"{schema} v{version}", cls, body)
    return msgpack.packb({"schema": schema, "v": cls.VERSION, "body": body}, use_bin_type=True)
