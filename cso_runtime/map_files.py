"""The robot's map as Nav2 ``map_server`` files: an image (PGM or PNG) and its YAML.

Why: the map is what active mapping produces, and ROS users load maps with ``nav2_map_server`` (or view them
in RViz). The files follow ``map_saver``: ``mode: trinary``, occupied cells black (0), free cells white (254),
unknown cells grey (205), ``negate: 0``, thresholds 0.65 / 0.196; the image's first row is the top of the map
(largest y) and ``origin`` is the map-frame pose ``[x_m, y_m, yaw_rad]`` of the lower-left pixel's corner
(REP-103: x east, y north). ``load_map`` reads what ``map_saver`` and this module write
(``trinary``, ``scale`` and ``raw`` modes, ``negate`` 0 or 1; 8- or 16-bit grey; colour as Nav2 reads it, the
plain average of R, G and B, not the luma) back into OccupancyGrid values (-1/0/100). Alpha (an alpha channel,
or a palette's transparent entry) is read as Nav2's ``map_io`` reads it: in ``trinary`` mode it is averaged
in with the three colour channels (so an opaque grey 205 reads as free there, as in Nav2 and ROS 1's map_server),
in ``scale`` mode a pixel not fully opaque is unknown, and ``raw`` mode ignores it.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from cso_runtime.config import finite_number, not_yaml_said, one_line, yaml12_number, yaml_dump, yaml_load
from cso_runtime.geometry import UNTURNED_YAW_TOLERANCE_RAD, GridGeometry, Pose2D, rounded_pose
from cso_runtime.occupancy import FREE, OCCUPIED, UNKNOWN
from cso_runtime.outputs import write_text_atomic, write_whole

PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205
"""map_saver's trinary pixel values."""
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196
"""Occupancy probability above which a pixel is occupied, below which it is free. 0.196 as ROS 1's map_saver
writes it: the unknown grey 205 is an occupancy of 0.19608, so it loads as unknown, where Nav2's default of 0.25
would read it as free."""
IMAGE_FORMATS = ("pgm", "png")

log = logging.getLogger("cso.map_files")
_warned_default_thresholds: set[Path] = set()
"""The YAMLs already warned about for missing thresholds (the warning is once per file per process)."""
_warned_unknown_read_free: set[Path] = set()
"""The YAMLs already warned about for a ``free_thresh`` that reads the unknown grey as free (once per file per process)."""


MAP_FILE_SUFFIXES = (".yaml", ".yml", ".pgm", ".png")


def map_yaml_path(out: Path | str, default_name: str = "map") -> Path:
    """The YAML that ``map_saver_cli -f OUT`` would write: ``OUT.yaml``. A folder (``-f runs/maps/``, or an
    empty ``-f ""``, which is the current folder) gets ``map.yaml`` inside it; a map file's suffix is replaced
    (``office.png`` -> ``office.yaml``), any other is kept (``office.v2`` -> ``office.v2.yaml``). A string
    ending in a slash names a folder even where none is yet (``Path`` would drop the slash)."""
    names_folder = isinstance(out, str) and out.endswith(("/", os.sep))
    out = Path(out)
    if names_folder or out.is_dir() or not out.name:
        return out / f"{default_name}.yaml"
    if out.suffix.lower() in MAP_FILE_SUFFIXES:
        return out.with_suffix(".yaml")
    return out.with_name(f"{out.name}.yaml")


class MapFileError(ValueError):
    """A map YAML or image that cannot be read as a map_server map (the message says which file and why)."""


MAX_MAP_CELLS = 25_000_000
"""The most pixels a map or floor-plan image may have (5000 x 5000, 250 m square at 0.05 m). An episode holds
about 100 bytes a cell (1.6 GB measured for a 4000 x 4000 map), so a larger one would take minutes and
gigabytes before its first step; Pillow's own check only refuses images over 179 M pixels, with a traceback."""


def open_image(path: Path) -> Image.Image:
    """Open an image with its size checked from its header, before any pixel is decoded (close it after).
    Raises MapFileError naming the file when it is missing, unreadable or over ``MAX_MAP_CELLS``."""
    try:
        im = Image.open(path)
    except Image.DecompressionBombError:
        raise MapFileError(
            f"{path}: the image is too large: over {MAX_MAP_CELLS:,} pixels; resample it to a coarser resolution"
        ) from None
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as exc:
        raise MapFileError(f"{path}: cannot read the map image ({exc})") from None
    width, height = im.size
    if width * height > MAX_MAP_CELLS:
        im.close()
        raise MapFileError(
            f"{path}: the image is too large: {width} x {height} pixels, over {MAX_MAP_CELLS:,}; resample it to a coarser resolution"
        )
    return im


def save_map(yaml_path: Path, grid: np.ndarray, geometry: GridGeometry, image_format: str = "pgm", map_origin: Pose2D | None = None) -> Path:
    """Write ``grid`` (int8 OccupancyGrid values, row 0 at ``geometry``'s origin) as ``yaml_path`` and the
    image beside it (same stem, ``image_format`` pgm or png). Returns the YAML's path. ``map_origin``: the pose
    in the map frame of the frame ``geometry`` is in (a scene's ``FloorPlan.map_origin``, the origin of the user's
    own map_server YAML), so that the file overlays that map; None: ``geometry``'s frame is the map frame."""
    if image_format not in IMAGE_FORMATS:
        raise ValueError(f"image format {image_format!r}: expected one of {', '.join(IMAGE_FORMATS)}")
    grid = np.asarray(grid)
    if grid.shape != tuple(geometry.shape):
        raise ValueError(f"grid shape {grid.shape} does not match the geometry {geometry.shape}")
    pixels = np.full(grid.shape, PIXEL_UNKNOWN, dtype=np.uint8)
    pixels[grid == FREE] = PIXEL_FREE
    pixels[grid >= 50] = PIXEL_OCCUPIED  # as map_saver: values above its occupied threshold
    yaml_path = Path(yaml_path)
    image_path = yaml_path.with_suffix(f".{image_format}")
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    image = Image.fromarray(np.ascontiguousarray(np.flipud(pixels)))
    write_whole(image_path, lambda partial: image.save(partial, format=Image.registered_extensions()[image_path.suffix.lower()]))
    meta = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(geometry.resolution_m),
        "origin": map_origin_of(geometry, map_origin),
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
    }
    write_text_atomic(yaml_path, yaml_dump(meta, sort_keys=False))  # last: a YAML there has its image
    return yaml_path


def map_origin_of(geometry: GridGeometry, map_origin: Pose2D | None = None) -> list[float]:
    """A map_server ``origin`` ``[x_m, y_m, yaw_rad]``: the map-frame pose of ``geometry``'s lower-left corner,
    ``geometry`` being in the frame whose map-frame pose is ``map_origin`` (None: the map frame itself), ``rounded_pose``
    as an exported bag's ``/map`` carries it: ``-5.275``, as map_saver_cli writes it, not the float sum's
    ``-5.2749999999999995``."""
    return rounded_pose(geometry.corner_pose(map_origin)).as_list()


def load_map(yaml_path: Path) -> tuple[np.ndarray, GridGeometry]:
    """A map_server map as (int8 OccupancyGrid values with row 0 at the origin, its geometry)."""
    grid, geometry, _ = load_map_and_meta(yaml_path)
    return grid, geometry


def load_map_and_meta(yaml_path: Path, rotated_origin_ok: bool = False) -> tuple[np.ndarray, GridGeometry, dict]:
    """``load_map`` plus the YAML's whole mapping (keys map_server ignores, such as a scene's ``start``).
    ``rotated_origin_ok``: take an ``origin`` with a yaw (map_server's counterclockwise rotation of the grid
    in the map frame); the geometry is then the grid's own frame, axis-aligned at (x, y), and the caller
    turns map-frame poses by the yaw (a scene does: its plan is in the grid's frame anyway)."""
    yaml_path = Path(yaml_path)
    try:
        with yaml_path.open(encoding="utf-8") as stream:
            meta = yaml_load(stream)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:  # as a config file's (a key twice too), on one line
        raise MapFileError(not_yaml_said(yaml_path, exc)) from None
    except OSError as exc:
        raise MapFileError(f"{yaml_path}: cannot read the map YAML ({one_line(str(exc))})") from None
    if not isinstance(meta, dict):
        raise MapFileError(f"{yaml_path}: expected a mapping with image, resolution and origin")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise MapFileError(f"{yaml_path}: missing {key!r}")
    resolution = _number(meta["resolution"], yaml_path, "resolution")
    origin = meta["origin"]
    if not (isinstance(origin, list) and len(origin) == 3):
        raise MapFileError(f"{yaml_path}: origin must be [x_m, y_m, yaw_rad]")
    x0, y0, yaw = (_number(v, yaml_path, "origin") for v in origin)
    if not resolution > 0:
        raise MapFileError(f"{yaml_path}: resolution must be positive, got {resolution}")
    if abs(yaw) > UNTURNED_YAW_TOLERANCE_RAD and not rotated_origin_ok:
        raise MapFileError(
            f"{yaml_path}: a rotated origin (yaw {yaw} rad): load_map gives an axis-aligned grid in the map frame"
            f" (an origin yaw within +-{UNTURNED_YAW_TOLERANCE_RAD} rad);"
            " load_map_and_meta(path, rotated_origin_ok=True) reads it, the grid in its own frame and the yaw in meta['origin']"
        )
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapFileError(f"{yaml_path}: unknown mode {mode!r} (trinary, scale or raw)")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, False, True):
        raise MapFileError(f"{yaml_path}: negate must be 0 or 1")
    _warn_default_thresholds(yaml_path, meta)
    occ_t = _number(meta.get("occupied_thresh", OCCUPIED_THRESH), yaml_path, "occupied_thresh")
    free_t = _number(meta.get("free_thresh", FREE_THRESH), yaml_path, "free_thresh")
    if not 0 <= free_t < occ_t <= 1:
        raise MapFileError(f"{yaml_path}: expected 0 <= free_thresh < occupied_thresh <= 1")
    image = meta["image"]
    if isinstance(image, bool) or not isinstance(image, (str, int, float)) or not str(image).strip():  # null, empty, a list
        raise MapFileError(f"{yaml_path}: image must name the map's image file (a PGM or PNG), got {image!r}")
    image_path = Path(str(image))
    if not image_path.is_absolute():
        image_path = yaml_path.parent / image_path
    with open_image(image_path) as im:
        try:
            im.load()
            value, alpha = shade_and_alpha(im)
        except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as exc:  # Pillow's decoders raise all of these on corrupt files
            raise MapFileError(f"{image_path}: cannot read the map image ({exc})") from None
    if mode == "raw":
        value = np.rint(value)  # as Nav2: the grey on 0-255, rounded
        grid = np.clip(value, -1, 100).astype(np.int8)
        grid[value > 100] = UNKNOWN
    else:
        unknown_grey = value == PIXEL_UNKNOWN  # map_saver's unknown, by its colour (alpha may be averaged in next)
        if alpha is not None and mode == "trinary":
            value = (3.0 * value + alpha) / 4.0  # as Nav2's map_io (and ROS 1): alpha averaged in with R, G, B
        occ = value / 255.0 if negate else (255.0 - value) / 255.0
        grid = np.full(value.shape, UNKNOWN, dtype=np.int8)
        grid[occ > occ_t] = OCCUPIED
        grid[occ < free_t] = FREE
        if mode == "scale":
            between = (occ >= free_t) & (occ <= occ_t)
            grid[between] = np.rint(100 * (occ[between] - free_t) / (occ_t - free_t)).astype(np.int8)  # as Nav2
        if alpha is not None and mode == "scale":
            grid[alpha < 255] = UNKNOWN  # as Nav2: in scale mode a pixel not fully opaque is unknown
        _warn_unknown_grey_read_free(yaml_path, free_t, occ[unknown_grey & (grid == FREE)], resolution, mode)
    geometry = GridGeometry(resolution, (int(grid.shape[0]), int(grid.shape[1])), x0, y0)
    return np.flipud(grid).copy(), geometry, meta


GREY_MODES = ("1", "L", "LA")
"""Pillow modes read as one grey channel (with alpha for ``LA``); any other 8-bit mode is read as R, G, B (A)."""


def shade_and_alpha(im: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """Each pixel's shade on 0-255 as Nav2's ``map_io`` computes it, the plain average of R, G and B (not the
    luma), and its alpha (None when the image has none). Transparency is kept wherever the file has it: an
    alpha channel, or a ``tRNS`` entry of a palette, grey or RGB PNG (GraphicsMagick, Nav2's reader, applies it)."""
    if im.mode.startswith("I"):  # 16-bit grey (PGM of maxval 65535, 16-bit PNG): "L" would clip it at 255
        return np.asarray(im, dtype=np.float64) * (255.0 / 65535.0), None
    has_alpha = "A" in im.getbands() or "transparency" in im.info
    if im.mode in GREY_MODES:
        pixels = np.asarray(im.convert("LA" if has_alpha else "L"))
        channels = pixels[..., :1] if has_alpha else pixels[..., None]
    else:
        pixels = np.asarray(im.convert("RGBA" if has_alpha else "RGB"))
        channels = pixels[..., :3]
    value = channels.astype(np.float64).mean(axis=-1)
    return value, (pixels[..., -1].astype(np.float64) if has_alpha else None)


def _warn_default_thresholds(yaml_path: Path, meta: dict) -> None:
    """Say once per file which thresholds were defaulted: both map_server versions refuse a YAML without them,
    so the file would not load in ROS as it does here."""
    defaults = {"occupied_thresh": OCCUPIED_THRESH, "free_thresh": FREE_THRESH}
    missing = {key: value for key, value in defaults.items() if key not in meta}
    key = yaml_path.resolve()
    if not missing or key in _warned_default_thresholds:
        return
    _warned_default_thresholds.add(key)
    used = ", ".join(f"{name} {value}" for name, value in missing.items())
    log.warning(
        "%s: no %s in the YAML; using %s (map_server and Nav2's map_server require them: add them to load it in ROS)",
        yaml_path,
        " or ".join(missing),
        used,
    )


def _warn_unknown_grey_read_free(yaml_path: Path, free_thresh: float, read_free_occ: np.ndarray, resolution_m: float, mode: str = "trinary") -> None:
    """Say once per file that pixels of map_saver's unknown grey (205) read as free (``read_free_occ``: the occupancy
    each was read with): ROS 2's map_saver_cli writes ``free_thresh: 0.25`` beside them, above their occupancy of 0.196,
    and map_server (as this loader) then serves them free, so a SLAM map's unknown margin becomes floor
    (slam_toolbox#587). In a PNG with an alpha channel (trinary mode) the opaque alpha averaged in reads them lighter,
    at 0.147, free at 0.196 too: the threshold that keeps them unknown is said as read. In scale mode no threshold
    keeps them unknown (a grey at or just above free_thresh scales to 0, free, as in Nav2): trinary mode does."""
    key = yaml_path.resolve()
    cells = len(read_free_occ)
    if cells == 0 or key in _warned_unknown_read_free:
        return
    _warned_unknown_read_free.add(key)
    plain = (255 - PIXEL_UNKNOWN) / 255
    occupancy = float(np.min(read_free_occ))
    if mode == "scale":  # only a pixel not fully opaque is unknown there: no free_thresh keeps the grey unknown
        keep = f"mode: scale keeps no opaque pixel unknown, as Nav2's: give mode: trinary (map_saver's) with free_thresh: {FREE_THRESH:g} to keep them unknown"
        read = f"an occupancy of {occupancy:.3f}, scaled to 0 or read free"
    elif occupancy >= plain - 1e-9:
        keep = f"set free_thresh: {FREE_THRESH:g} (ROS 1 map_saver's value) to keep them unknown"
        read = f"an occupancy of {plain:.3f}"
    else:  # alpha averaged in with the grey (Nav2's trinary mode): lighter than 205 alone
        keep = f"set free_thresh at most {math.floor(occupancy * 1000) / 1000:.3f}, or save the image without its alpha channel, to keep them unknown"
        read = f"an occupancy of {occupancy:.3f} with the image's alpha averaged in, as Nav2 does"
    log.warning(
        "%s: free_thresh %g reads the unknown grey %d (%s) as free, as Nav2's map_server does: %d cells (%.2f m2) of unknown are floor here; %s",
        yaml_path, free_thresh, PIXEL_UNKNOWN, read, cells, cells * resolution_m**2, keep,
    )  # fmt: skip


def _number(v: object, path: Path, key: str) -> float:
    """The map's ``key`` as map_server reads it (YAML 1.2's numbers: ``config.finite_number``), or a MapFileError."""
    number = finite_number(v)
    if number is None:
        what = "three finite numbers [x_m, y_m, yaw_rad]" if key == "origin" else "a finite number"
        raise MapFileError(f"{path}: {key} must be {what}, got {yaml12_number(v)!r}")
    return number
