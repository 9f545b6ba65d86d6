"""Floor plans: ground-truth free space, metric scale, start pose, and the paper's scale classes.

Sources: the Dungeon PNG plans (any folder of them, or the few shipped in the package), the
seeded apartment generator (``cso_runtime.scene_generator``) and Nav2 map_server maps (a map your
robot built, ``cso_runtime.map_files``). Scene specs used by the CLI: ``DIR`` (every PNG in it, or
every map YAML when it holds any), a single ``FILE.png`` or ``FILE.yaml``, ``builtin`` (plans shipped
in the package) or ``generated:SCALE:N:SEED``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from cso_runtime.config import Bound, finite_number, utf8_text, with_nearest
from cso_runtime.geometry import MAP_FRAME_ORIGIN, GridGeometry, Pose2D, compose_pose, relative_pose, wrap_angle_rad

FREE_RGB = (195, 195, 194)
WALL_RGB = (127, 127, 127)
START_RGB = (255, 216, 0)

SCALES = ("small", "middle", "large", "super_large")
"""Section 4.1: traversable area < 30, 30-100, 100-260, > 260 m2."""


class SceneError(ValueError):
    """A floor plan is missing, corrupt or unusable."""


def scale_rank(scale: str) -> int:
    """Where a scale comes in tables: small to super large, any other name after them."""
    return SCALES.index(scale) if scale in SCALES else len(SCALES)


def scale_of(area_m2: float) -> str:
    """The paper's scale class of a scene from its traversable area."""
    if area_m2 < 30.0:
        return "small"
    if area_m2 < 100.0:
        return "middle"
    if area_m2 < 260.0:
        return "large"
    return "super_large"


MIN_TRAVERSABLE_M2 = 0.1
"""The least floor reachable from the start that makes a scene: about twice the LIMO's own footprint."""


@dataclass
class FloorPlan:
    """Ground truth of one scene. ``free[iy, ix]`` is True for floor; row 0 is the bottom (y = 0). The plan's
    frame (``start``, ``geometry``: what every algorithm works in) has its origin at the grid's lower-left corner;
    ``map_origin`` is that corner's pose in the user's map frame (a map_server YAML's ``origin``), which what users
    read is shown in (``to_map_frame``)."""

    name: str
    free: np.ndarray
    resolution_m: float
    start: Pose2D
    source: str = ""
    map_origin: Pose2D = MAP_FRAME_ORIGIN

    def to_map_frame(self, pose: Pose2D) -> Pose2D:
        """A pose in the plan's frame as the user's map frame has it."""
        return compose_pose(self.map_origin, pose)

    @property
    def geometry(self) -> GridGeometry:
        return GridGeometry(self.resolution_m, tuple(self.free.shape))

    @property
    def occupied(self) -> np.ndarray:
        return ~self.free

    def start_cell(self) -> tuple[int, int]:
        """The grid cell (iy, ix) of the start pose; a SceneError when the start is no finite pose on a free cell of
        the grid (off the plan, in a wall: a plan with no floor has no such start)."""
        s = self.start
        if not (math.isfinite(s.x_m) and math.isfinite(s.y_m) and math.isfinite(s.yaw_rad)):
            raise SceneError(f"{self.name}: the start pose {s} is not finite")
        iy, ix = (int(v) for v in self.geometry.world_to_cell(s.x_m, s.y_m))
        height, width = self.free.shape
        if not (0 <= iy < height and 0 <= ix < width):
            size = f"{width * self.resolution_m:g} x {height * self.resolution_m:g} m"
            raise SceneError(f"{self.name}: the start ({s.x_m:g}, {s.y_m:g}) m is off the plan ({size}, from (0, 0))")
        if not self.free[iy, ix]:
            raise SceneError(f"{self.name}: start pose is not on free space")
        return iy, ix

    def traversable_region(self) -> np.ndarray:
        """Free cells connected to the start: what a perfect explorer could see and count. A start walled
        into less than ``MIN_TRAVERSABLE_M2`` is no scene to explore (it would score 100 % in no step)."""
        from scipy import ndimage  # noqa: PLC0415  (0.3 s of imports: the CLI's run commands read this module)

        labels, _ = ndimage.label(self.free)
        region = labels == labels[self.start_cell()]
        area_m2 = float(np.count_nonzero(region)) * self.resolution_m**2
        if area_m2 < MIN_TRAVERSABLE_M2:
            raise SceneError(f"{self.name}: only {area_m2:.2f} m2 of floor is reachable from the start (walled in?); a scene needs at least {MIN_TRAVERSABLE_M2:g} m2")
        return region

    def traversable_area_m2(self) -> float:
        return float(np.count_nonzero(self.traversable_region())) * self.resolution_m**2

    @property
    def scale(self) -> str:
        return scale_of(self.traversable_area_m2())

    def pixels_from_grid(self, grid: np.ndarray) -> np.ndarray:
        """Turn a grid array back into the PNG's own pixel layout (row 0 at the top)."""
        return np.flipud(grid)


def body_overlaps_walls(plan: FloorPlan, pose: Pose2D, length_m: float, width_m: float) -> bool:
    """Whether a box body ``length_m`` along ``pose``'s heading by ``width_m`` across, centred on ``pose``, shares some
    area with a wall cell of ``plan``, outside the plan counting as wall (``GridGeometry.cells_overlapping_rectangle``:
    exact, and a body that only touches a wall's face overlaps none). The MuJoCo LIMO's chassis box against the wall
    boxes its world is built of (``robot_sim.scene``: the occupied cells, the plan ringed by walls)."""
    g = plan.geometry
    iy, ix = g.cells_overlapping_rectangle(pose, length_m, width_m)
    on_plan = g.in_bounds(iy, ix)
    return bool((~on_plan).any() or (~plan.free[iy[on_plan], ix[on_plan]]).any())


def start_overlap_said(plan: FloorPlan, length_m: float, width_m: float) -> str | None:
    """The MuJoCo LIMO's warning of a body (``robot.length_m`` by ``robot.width_m``) that overlaps a wall at the plan's
    start pose (``body_overlaps_walls``), or None: what its simulator logs at each reset (the run goes on, the contact
    pushing the body out) and ``up`` says on its terminal before anything starts, from the plan alone, no model built.
    The 2D simulator's disc has its own (``simulator.disc_start_overlap_said``)."""
    if not body_overlaps_walls(plan, plan.start, length_m, width_m):
        return None
    return overlap_at_start_said(plan, "the LIMO's body", "its contacts push it out as the episode starts")


def overlap_at_start_said(plan: FloorPlan, body: str, then: str) -> str:
    """A simulator's words for its ``body`` overlapping a wall at ``plan``'s start pose, and what ``then`` happens: the
    pose as the plan's frame has it."""
    start = plan.start
    return f"{plan.name}: {body} overlaps a wall at the start pose (x {start.x_m:.3f} m, y {start.y_m:.3f} m, yaw {start.yaw_rad:.3f} rad): {then}"


def describe_scene(plan: FloorPlan) -> dict[str, object]:
    """What ``cso-runtime scenes`` lists of a plan: its size, scale, traversable area and start pose (in the map
    frame, as a map_server YAML's ``start`` is written, with the ``map_origin`` that places the plan there), so a
    folder can be checked (and its ``--m-per-px`` chosen) before a long evaluation."""
    h, w = plan.free.shape
    area_m2 = plan.traversable_area_m2()
    return {
        "scene": plan.name,
        "width_m": w * plan.resolution_m,
        "height_m": h * plan.resolution_m,
        "resolution_m": plan.resolution_m,
        "cells": [int(h), int(w)],
        "free_area_m2": float(np.count_nonzero(plan.free)) * plan.resolution_m**2,
        "traversable_area_m2": area_m2,
        "scale": scale_of(area_m2),
        "start": _pose_dict(plan.to_map_frame(plan.start)),  # as the user wrote it: in the map frame
        "map_origin": _pose_dict(plan.map_origin),
        "source": plan.source,
    }


def _pose_dict(pose: Pose2D) -> dict[str, float]:
    return {"x_m": pose.x_m, "y_m": pose.y_m, "yaw_rad": pose.yaw_rad}


COLOUR_TOLERANCE = 10
"""A pixel has a plan colour when each of its channels is within this of the colour's."""


def _colour_within(rgb: np.ndarray, colour: tuple[int, int, int], tolerance: int) -> np.ndarray:
    """Pixels whose every channel lies within ``tolerance`` of ``colour``'s: two comparisons per channel
    on the image's own integers (no signed copy of the image, no ``abs``; a plan is loaded per episode)."""
    out = np.ones(rgb.shape[:2], dtype=bool)
    for channel, value in enumerate(colour):
        c = rgb[:, :, channel]
        out &= c >= value - tolerance
        out &= c <= value + tolerance
    return out


OTHER_PLANS_HINT = (
    "a PNG plan is read in the Dungeon colours (floor (195,195,194), wall (127,127,127), start square (255,216,0)); "
    "a plan of other colours (white floor, dark walls) or without a start square is a map_server map: "
    "write a YAML beside it with image, resolution, origin and start: [x_m, y_m, yaw_rad], and give the YAML"
)
"""What a PNG that is no Dungeon plan takes instead (a floor plan of the user's own building, say)."""


def scene_name(path: Path) -> str:
    """The name of the scene in file ``path``: its stem, which every table, message, log and file of a run carries, so a
    stem of bytes that are no UTF-8 is escaped (``img_\\udcff``, ``config.utf8_text``): its lone surrogates made every
    ``episode_status`` fail to encode, MuJoCo refuse the model and episodes.csv fail to write."""
    return utf8_text(path.stem)


def floor_plan_from_rgb(name: str, rgb: np.ndarray, resolution_m: float, start_yaw_rad: float = 0.0, source: str = "") -> FloorPlan:
    """Decode a Dungeon-style image: free (195,195,194), wall (127,127,127), start square (255,216,0): one marker (its
    pixels 8-connected), whose centre is the start pose; a SceneError for none or several."""
    if rgb.ndim != 3 or rgb.shape[2] < 3:
        raise SceneError(f"{name}: expected an RGB(A) image, got shape {rgb.shape}")
    rgb = rgb[:, :, :3]
    if not np.issubdtype(rgb.dtype, np.integer):
        rgb = rgb.astype(np.int16)
    start = _colour_within(rgb, START_RGB, COLOUR_TOLERANCE)
    floor = _colour_within(rgb, FREE_RGB, COLOUR_TOLERANCE)
    if not start.any():
        raise SceneError(f"{name}: no start marker (colour {START_RGB}); {OTHER_PLANS_HINT}")
    if not floor.any():
        raise SceneError(f"{name}: no floor of the Dungeon free colour {FREE_RGB}; {OTHER_PLANS_HINT}")
    from scipy import ndimage  # noqa: PLC0415  (as in traversable_region)

    _, markers = ndimage.label(start, structure=np.ones((3, 3), dtype=bool))
    if markers > 1:  # the start is the centre of the marker's pixels: of two, a point between them (in a wall, another room)
        raise SceneError(f"{name}: {markers} start markers (colour {START_RGB}); a plan has one square, whose centre is the start pose")
    free_px = floor | start
    free = np.flipud(free_px)
    sy, sx = np.nonzero(np.flipud(start))
    x = (sx.mean() + 0.5) * resolution_m
    y = (sy.mean() + 0.5) * resolution_m
    return FloorPlan(name, free.copy(), float(resolution_m), Pose2D(float(x), float(y), float(start_yaw_rad)), source)


def load_floor_plan(path: str | Path, resolution_m: float = 0.1, start_yaw_rad: float = 0.0) -> FloorPlan:
    """Load one PNG floor plan at ``resolution_m`` metres per pixel. Raises SceneError if unusable."""
    from PIL import UnidentifiedImageError  # noqa: PLC0415 - only needed for PNG input

    from cso_runtime.map_files import MapFileError, open_image  # noqa: PLC0415 - PIL only for PNG input

    p = Path(path)
    if not p.is_file():
        raise SceneError(f"{p.name}: file not found ({p})")
    if not resolution_m > 0:
        raise SceneError("metres per pixel must be positive")
    try:
        with open_image(p) as im:
            rgb = np.asarray(im.convert("RGB"))
    except MapFileError as exc:  # too large, or not an image at all
        raise SceneError(str(exc)) from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise SceneError(f"{p}: not a readable image ({exc})") from None
    return floor_plan_from_rgb(scene_name(p), rgb, resolution_m, start_yaw_rad, source=str(p))


MAP_SUFFIXES = (".yaml", ".yml")
"""A scene file with one of these suffixes is a map_server map (``load_map_scene``)."""


def _map_extent(map_origin: Pose2D, shape: tuple[int, ...], resolution_m: float) -> str:
    """Where a map's grid lies in its map frame, in words for an error (a start given off it): the span of its corners,
    which is the grid itself unless the ``origin`` turns it."""
    height_m, width_m = shape[0] * resolution_m, shape[1] * resolution_m
    corners = [compose_pose(map_origin, Pose2D(x_m, y_m, 0.0)) for x_m in (0.0, width_m) for y_m in (0.0, height_m)]
    xs, ys = [round(c.x_m, 3) for c in corners], [round(c.y_m, 3) for c in corners]
    turned = f" (its corners' span: the origin turns it by {map_origin.yaw_rad:g} rad)" if map_origin.yaw_rad else ""
    return f"in the map frame it covers x {min(xs):g} to {max(xs):g} m, y {min(ys):g} to {max(ys):g} m{turned}"


def load_map_scene(path: str | Path) -> FloorPlan:
    """A map_server map (YAML + image) as a floor plan: its free cells (0) are the floor; occupied and
    unknown cells are walls. The plan's frame is the map's lower-left corner, at the map's own
    resolution, along the grid's rows and columns; the YAML's ``origin`` (with its yaw) is kept as the plan's
    ``map_origin``, which places it in the map frame. The start is the YAML's optional ``start: [x_m, y_m, yaw_rad]`` (map frame; map_server
    ignores the key), else the free cell farthest from any wall in the largest free region."""
    from cso_runtime.map_files import MapFileError, load_map_and_meta  # noqa: PLC0415 - PIL only for map input

    p = Path(path)
    if not p.is_file():
        raise SceneError(f"{p.name}: file not found ({p})")
    try:
        grid, geometry, meta = load_map_and_meta(p, rotated_origin_ok=True)
        start = meta.get("start")
    except MapFileError as exc:
        raise SceneError(str(exc)) from None
    free = grid == 0
    if not free.any():
        raise SceneError(f"{p.name}: the map has no free cells")
    x0_m, y0_m, yaw_rad = map(float, meta["origin"])
    map_origin = Pose2D(x0_m, y0_m, yaw_rad if -math.pi <= yaw_rad < math.pi else wrap_angle_rad(yaw_rad))  # messages carry yaws in [-10, 10]
    res = geometry.resolution_m
    if start is not None:
        numbers = [n for n in map(finite_number, start) if n is not None] if isinstance(start, list) else []  # read as origin is (5e-2 too)
        if len(numbers) != 3 or len(start) != 3:
            raise SceneError(f"{p.name}: start must be [x_m, y_m, yaw_rad], three finite numbers")
        # The map frame's pose in the grid's frame, whose corner is at `origin`, turned by its yaw (map_server's).
        pose = Pose2D(*relative_pose(map_origin, Pose2D(*numbers)))
        iy, ix = GridGeometry(res, free.shape).world_to_cell(pose.x_m, pose.y_m)
        if not (0 <= iy < free.shape[0] and 0 <= ix < free.shape[1]):
            raise SceneError(f"{p.name}: start ({start[0]}, {start[1]}) m is off the map: {_map_extent(map_origin, free.shape, res)}")
        if not free[iy, ix]:
            raise SceneError(f"{p.name}: start ({start[0]}, {start[1]}) m is not on a free cell of the map")
    else:
        from scipy import ndimage  # noqa: PLC0415  (as in traversable_region)

        labels, n = ndimage.label(free)
        largest = labels == 1 + int(np.argmax(ndimage.sum_labels(free, labels, index=np.arange(1, n + 1))))
        centre_iy, centre_ix = map(int, np.unravel_index(int(np.argmax(ndimage.distance_transform_edt(largest))), free.shape))
        pose = Pose2D((centre_ix + 0.5) * res, (centre_iy + 0.5) * res, 0.0)
    return FloorPlan(scene_name(p), free, res, pose, source=str(p), map_origin=map_origin)


def _natural_key(p: Path) -> tuple:
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name))


def builtin_scene_dir() -> Path:
    """Folder of the Dungeon plans shipped inside the package (MIT licence alongside)."""
    return Path(str(resources.files("cso_runtime") / "data" / "scenes"))


@dataclass(frozen=True)
class SceneRef:
    """A scene to load lazily in a worker: a PNG path or a generator spec."""

    name: str
    path: str | None = None
    generated: tuple[str, int] | None = None  # (scale, seed)
    resolution_m: float = 0.1

    @property
    def scaled_by_m_per_px(self) -> bool:
        """A PNG plan, loaded at ``resolution_m`` (``--m-per-px``); generated plans and map files have their own cell size."""
        return self.generated is None and self.path is not None and Path(self.path).suffix.lower() not in MAP_SUFFIXES

    def load(self) -> FloorPlan:
        if self.generated is not None:
            from cso_runtime.scene_generator import generate_floor_plan  # noqa: PLC0415

            scale, seed = self.generated
            return generate_floor_plan(scale, seed)
        assert self.path is not None
        if Path(self.path).suffix.lower() in MAP_SUFFIXES:
            return load_map_scene(self.path)  # at the map's own resolution
        return load_floor_plan(self.path, self.resolution_m)


MAX_M_PER_PX = 10.0
"""The coarsest plan scale taken (``--m-per-px``): a pixel of a floor plan is never 10 m of floor."""
M_PER_PX_BOUND = Bound(0.0, MAX_M_PER_PX, "m", low_open=True, why="scenes.MAX_M_PER_PX")
"""The metres per pixel of a floor plan (``eval --m-per-px``, ``scenes --m-per-px``, train's ``dungeon_m_per_px``):
the one range of it, checked and said by ``config.Bound``."""


MAX_GENERATED_PLANS = 100_000
"""The most plans one ``generated:SCALE:N:SEED`` names: days of episodes at the smallest scale. A mistyped N
(``generated:small:99999999:0``) took minutes and 7.6 GB listing its plans, ``--limit 1`` too, before any ran."""
GENERATED_PLANS_BOUND = Bound(1, MAX_GENERATED_PLANS, why="scenes.MAX_GENERATED_PLANS")


def spec_names_a_path(spec: str) -> bool:
    """Whether scene spec ``spec`` is a path (a folder, a PNG, a map YAML), not ``builtin`` nor ``generated:...``:
    what ``up`` resolves against the current folder, and compares so when given twice (``--scene`` and ``--set``)."""
    return spec != "builtin" and not spec.startswith("generated:")


def resolve_scenes(spec: str, limit: int | None = None, resolution_m: float = 0.1) -> list[SceneRef]:
    """Expand a scene spec into scene references (see the module docstring for the forms)."""
    if (problem := M_PER_PX_BOUND.problem(resolution_m)) is not None:
        raise SceneError(f"metres per pixel {problem}")
    if spec.startswith("generated:"):
        parts = spec.split(":")
        if len(parts) != 4:
            raise SceneError(f"bad generated spec {spec!r}; use generated:SCALE:N:SEED")
        _, scale, n, seed = parts
        if scale not in SCALES:
            raise SceneError(f"generated scale must be one of {', '.join(SCALES)}, got {with_nearest(scale, SCALES, shown=repr(scale))}")
        try:
            n_i, seed_i = int(n), int(seed)
        except ValueError:
            raise SceneError(f"bad generated spec {spec!r}: N and SEED must be integers") from None
        if n_i < 1 or seed_i < 0:
            raise SceneError(f"bad generated spec {spec!r}: N must be at least 1 and SEED at least 0")
        if (problem := GENERATED_PLANS_BOUND.problem(n_i)) is not None:
            raise SceneError(f"bad generated spec {spec!r}: N {problem}")
        refs = [SceneRef(f"gen_{scale}_{seed_i + k}", generated=(scale, seed_i + k)) for k in range(n_i if limit is None else min(n_i, limit))]
    else:
        p = builtin_scene_dir() if spec == "builtin" else Path(spec)
        if p.is_dir():
            # A folder of map_server maps holds their images too: then the YAMLs are the scenes.
            files = sorted((f for f in p.iterdir() if f.suffix.lower() in MAP_SUFFIXES), key=_natural_key)
            files = files or sorted(p.glob("*.png"), key=_natural_key)
            if not files:
                raise SceneError(f"no PNG floor plans or map YAMLs in {p}")
        elif p.suffix.lower() in (".png", *MAP_SUFFIXES):
            files = [p]  # a missing file is reported per scene, as a failure
        else:
            said = with_nearest(spec, ["builtin"], shown=repr(spec)) if not p.exists() else repr(spec)
            raise SceneError(f"scene spec {said} is not a folder, a .png, a map .yaml, 'builtin' or generated:SCALE:N:SEED")
        refs = [SceneRef(scene_name(f), path=str(f), resolution_m=resolution_m) for f in files]
    return refs[:limit] if limit is not None else refs
