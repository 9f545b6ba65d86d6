"""Seeded apartment- and office-like floor plans for every scale class of the paper (section 4.1).

The Dungeon plans are all "large" or "super large", so the small (< 30 m2) and middle (30-100 m2)
classes come from this generator; its large (100-260 m2) and super-large (> 260 m2) plans let an
installed package, which ships only five Dungeon plans, evaluate and train at those scales on as
many seeded scenes as wanted. Layout rules (``LayoutRules`` holds the numbers):

1. The plan is a rectangle with an outer wall all round; its size is drawn so that the free
   area lands in the requested scale class (small: 10-28 m2, middle: 32-97 m2, large: 105-250 m2,
   super large: 270-600 m2 targeted, the last about the Dungeon plans' range at 0.1 m/px), with at
   least 2 rooms (small), 4 (middle), 8 (large) or 16 (super large).
2. The inside is split recursively by straight walls (a guillotine split) into rectangular rooms
   no narrower than ``min_room_m``. The first split of a large enough plan may instead lay a
   corridor (``corridor_m`` wide) along the plan's long side, with rooms on both sides.
3. Every split wall gets one door between a room on each side, so all rooms are connected (by
   induction over the split tree). Every room along a corridor also gets its own door onto it.
   Doors are ``door_m`` wide (0.8-1.0 m, so a robot of radius 0.2 m passes) and lie entirely
   within both rooms they join, at least ``door_margin_m`` from the rooms' corners.
4. Walls are ``wall_m`` thick inside and ``outer_wall_m`` thick outside.
5. The robot starts in a room (a corridor only if there is no room), at least
   ``start_clearance_m`` from every wall, heading yaw 0.

Only ``numpy.random.default_rng(seed)`` is used, so one seed always gives the same plan. A draw
that misses the scale class (or breaks a rule) is discarded and the same generator draws again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from cso_runtime.geometry import Pose2D
from cso_runtime.scenes import SCALES, FloorPlan, SceneError, scale_of

GENERATED_SCALES = SCALES
"""Every scale class of the paper can be generated."""


@dataclass(frozen=True)
class LayoutRules:
    """The numbers behind the layout rules in the module docstring (metres, square metres)."""

    wall_m: float = 0.15
    """Interior wall thickness (at least 0.1 m; rounded up to whole cells)."""
    outer_wall_m: float = 0.2
    """Outer wall thickness."""
    door_m: tuple[float, float] = (0.8, 1.0)
    """Door width range; 0.8 m leaves 0.4 m for the centre of a robot of radius 0.2 m."""
    door_margin_m: float = 0.1
    """Least distance from a door to a room corner (a door frame)."""
    min_room_m: float = 1.8
    """Narrowest side of a room."""
    room_area_m2: tuple[float, float] = (7.0, 18.0)
    """A block smaller than a value drawn from this range is not split further."""
    corridor_m: tuple[float, float] = (1.0, 1.4)
    """Corridor width range."""
    corridor_min_plan_m2: float = 30.0
    """Only plans at least this large may get a corridor."""
    corridor_probability: float = 0.6
    """Chance that a plan large enough for a corridor gets one."""
    aspect: tuple[float, float] = (1.0, 1.8)
    """Long side over short side of the plan."""
    target_area_m2: dict[str, tuple[float, float]] = field(
        default_factory=lambda: {"small": (10.0, 28.0), "middle": (32.0, 97.0), "large": (105.0, 250.0), "super_large": (270.0, 600.0)}
    )
    """Free area drawn per scale class (kept inside the paper's class bounds)."""
    min_rooms: dict[str, int] = field(default_factory=lambda: {"small": 2, "middle": 4, "large": 8, "super_large": 16})
    """Fewest rooms (corridor included) per scale class, so no plan is seen whole from the start."""
    wall_fill: float = 0.95
    """Rough share of the inside left free by the walls, to size the plan from the target area."""
    start_clearance_m: float = 0.4
    """Least distance from the start pose to any wall."""
    max_attempts: int = 50
    """Draws before giving up with SceneError (a bound, never reached in practice)."""


@dataclass(frozen=True)
class _Rect:
    """Half-open block of cells [x0, x1) x [y0, y1) (x: columns, y: rows with row 0 at the bottom)."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0


@dataclass(frozen=True)
class _Link:
    """A wall between two groups of rooms that needs a door: one, or (``every_room``) one per room pair."""

    side_a: tuple[int, ...]
    side_b: tuple[int, ...]
    vertical: bool  # True: the wall runs along y at columns [pos, pos + thickness)
    pos: int
    every_room: bool = False


class _Draft:
    """One attempt at a plan, in whole cells."""

    def __init__(self, rng: np.random.Generator, rules: LayoutRules, resolution_m: float) -> None:
        self.rng = rng
        self.rules = rules
        self.res = resolution_m
        self.wall = self._cells_up(rules.wall_m)
        self.outer = self._cells_up(rules.outer_wall_m)
        self.min_room = self._cells_up(rules.min_room_m)
        self.margin = self._cells_up(rules.door_margin_m)
        self.rooms: list[_Rect] = []
        self.corridors: set[int] = set()
        self.links: list[_Link] = []

    def _cells_up(self, length_m: float) -> int:
        return max(1, math.ceil(length_m / self.res - 1e-9))

    def _area_m2(self, r: _Rect) -> float:
        return r.width * r.height * self.res**2

    def partition(self, block: _Rect, top: bool) -> tuple[int, ...]:
        """Split ``block`` into rooms; returns the indices of the rooms made inside it."""
        rules, rng = self.rules, self.rng
        can_cut_x = block.width >= 2 * self.min_room + self.wall  # a vertical wall splits the width
        can_cut_y = block.height >= 2 * self.min_room + self.wall
        if top and self._area_m2(block) >= rules.corridor_min_plan_m2 and rng.random() < rules.corridor_probability:
            rooms = self._corridor(block)
            if rooms is not None:
                return rooms
        if not (can_cut_x or can_cut_y) or self._area_m2(block) < rng.uniform(*rules.room_area_m2):
            self.rooms.append(block)
            return (len(self.rooms) - 1,)
        if can_cut_x and can_cut_y:
            cut_x = (block.width >= block.height) == (rng.random() < 0.8)  # mostly cut the long side
        else:
            cut_x = can_cut_x
        lo, hi = (block.x0, block.x1) if cut_x else (block.y0, block.y1)
        pos = int(rng.integers(lo + self.min_room, hi - self.min_room - self.wall + 1))
        if cut_x:
            a, b = _Rect(block.x0, block.y0, pos, block.y1), _Rect(pos + self.wall, block.y0, block.x1, block.y1)
        else:
            a, b = _Rect(block.x0, block.y0, block.x1, pos), _Rect(block.x0, pos + self.wall, block.x1, block.y1)
        side_a, side_b = self.partition(a, False), self.partition(b, False)
        self.links.append(_Link(side_a, side_b, cut_x, pos))
        return side_a + side_b

    def _corridor(self, block: _Rect) -> tuple[int, ...] | None:
        """Lay a corridor along the block's long side with room strips on both sides, if it fits."""
        width = max(self._cells_up(self.rules.corridor_m[0]), int(round(self.rng.uniform(*self.rules.corridor_m) / self.res)))
        along_y = block.height >= block.width  # corridor parallel to the long side
        lo, hi = (block.x0, block.x1) if along_y else (block.y0, block.y1)
        first = lo + self.min_room  # where the corridor's first wall may start, at the earliest
        last = hi - self.min_room - 2 * self.wall - width
        if last < first:
            return None
        pos = int(self.rng.integers(first, last + 1))
        c0, c1 = pos + self.wall, pos + self.wall + width
        if along_y:
            a = _Rect(block.x0, block.y0, pos, block.y1)
            corridor = _Rect(c0, block.y0, c1, block.y1)
            b = _Rect(c1 + self.wall, block.y0, block.x1, block.y1)
        else:
            a = _Rect(block.x0, block.y0, block.x1, pos)
            corridor = _Rect(block.x0, c0, block.x1, c1)
            b = _Rect(block.x0, c1 + self.wall, block.x1, block.y1)
        self.rooms.append(corridor)
        ci = len(self.rooms) - 1
        self.corridors.add(ci)
        side_a, side_b = self.partition(a, False), self.partition(b, False)
        self.links.append(_Link(side_a, (ci,), along_y, pos, every_room=True))
        self.links.append(_Link((ci,), side_b, along_y, c1, every_room=True))
        return side_a + (ci,) + side_b

    def door_width_cells(self) -> int:
        lo_m, hi_m = self.rules.door_m
        lo, hi = math.ceil(lo_m / self.res - 1e-9), math.floor(hi_m / self.res + 1e-9)
        return int(np.clip(round(self.rng.uniform(lo_m, hi_m) / self.res), lo, max(lo, hi)))

    def doors(self, free: np.ndarray) -> bool:
        """Cut the doors of every link into ``free``; False if some wall has no room for a door."""
        for link in self.links:
            pairs = []
            for i in link.side_a:
                for j in link.side_b:
                    a, b = self.rooms[i], self.rooms[j]
                    if link.vertical and a.x1 == link.pos and b.x0 == link.pos + self.wall:
                        pairs.append((max(a.y0, b.y0), min(a.y1, b.y1)))
                    elif not link.vertical and a.y1 == link.pos and b.y0 == link.pos + self.wall:
                        pairs.append((max(a.x0, b.x0), min(a.x1, b.x1)))
            width = self.door_width_cells()
            spans = [(lo, hi) for lo, hi in pairs if hi - lo >= width + 2 * self.margin]
            if not spans:
                return False
            chosen = spans if link.every_room else [spans[int(self.rng.integers(len(spans)))]]
            for lo, hi in chosen:
                start = int(self.rng.integers(lo + self.margin, hi - self.margin - width + 1))
                if link.vertical:
                    free[start : start + width, link.pos : link.pos + self.wall] = True
                else:
                    free[link.pos : link.pos + self.wall, start : start + width] = True
        return True

    def start_pose(self, free: np.ndarray) -> Pose2D | None:
        """A random spot in a random room, ``start_clearance_m`` from the walls (checked on the grid)."""
        rooms = [i for i in range(len(self.rooms)) if i not in self.corridors] or sorted(self.corridors)
        room = self.rooms[rooms[int(self.rng.integers(len(rooms)))]]
        keep = self._cells_up(self.rules.start_clearance_m) + 1
        if room.width <= 2 * keep or room.height <= 2 * keep:
            return None
        ix = int(self.rng.integers(room.x0 + keep, room.x1 - keep))
        iy = int(self.rng.integers(room.y0 + keep, room.y1 - keep))
        # Distance from this cell's centre to the nearest wall cell's edge.
        clearance_m = (ndimage.distance_transform_edt(free)[iy, ix] - 0.5) * self.res
        if clearance_m < self.rules.start_clearance_m:
            return None
        return Pose2D((ix + 0.5) * self.res, (iy + 0.5) * self.res, 0.0)


def _draw_plan(rng: np.random.Generator, scale: str, rules: LayoutRules, resolution_m: float) -> tuple[np.ndarray, Pose2D] | None:
    """One attempt: plan size, rooms, doors, start. None when a rule could not be met."""
    draft = _Draft(rng, rules, resolution_m)
    gross_m2 = rng.uniform(*rules.target_area_m2[scale]) / rules.wall_fill
    aspect = rng.uniform(*rules.aspect)
    long_m, short_m = math.sqrt(gross_m2 * aspect), math.sqrt(gross_m2 / aspect)
    width_m, height_m = (long_m, short_m) if rng.random() < 0.5 else (short_m, long_m)
    outer = draft.outer
    nx, ny = int(round(width_m / resolution_m)), int(round(height_m / resolution_m))
    inside = _Rect(outer, outer, outer + nx, outer + ny)
    draft.partition(inside, top=True)
    if len(draft.rooms) < rules.min_rooms[scale]:
        return None
    free = np.zeros((ny + 2 * outer, nx + 2 * outer), dtype=bool)
    for r in draft.rooms:
        free[r.y0 : r.y1, r.x0 : r.x1] = True
    if not draft.doors(free):
        return None
    start = draft.start_pose(free)
    if start is None:
        return None
    return free, start


def generate_floor_plan(scale: str, seed: int, resolution_m: float = 0.05, rules: LayoutRules | None = None) -> FloorPlan:
    """A seeded apartment-like plan whose traversable area is in ``scale``'s class (``scenes.SCALES``).

    Same ``seed``, same plan. Raises SceneError for an unknown scale, a negative seed or a
    resolution too coarse for the layout rules.
    """
    rules = rules or LayoutRules()
    if scale not in GENERATED_SCALES:
        raise SceneError(f"generated scale must be one of {GENERATED_SCALES}, got {scale!r}")
    if int(seed) < 0:
        raise SceneError(f"generator seed must be >= 0, got {seed}")
    if not 0.0 < resolution_m <= rules.wall_m:
        raise SceneError(f"resolution_m must be in (0, {rules.wall_m}] m so walls are at least one cell, got {resolution_m}")
    rng = np.random.default_rng(int(seed))
    name = f"gen_{scale}_{int(seed)}"
    for _ in range(rules.max_attempts):
        drawn = _draw_plan(rng, scale, rules, resolution_m)
        if drawn is None:
            continue
        free, start = drawn
        plan = FloorPlan(name, free, float(resolution_m), start, source=f"scene_generator:{scale}:{int(seed)}")
        region = plan.traversable_region()
        if np.count_nonzero(region) == np.count_nonzero(free) and scale_of(plan.traversable_area_m2()) == scale:
            return plan
    raise SceneError(f"{name}: no plan met the layout rules in {rules.max_attempts} draws")
