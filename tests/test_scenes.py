"""Floor plans: the seeded apartment generator, PNG and map_server loading, scene specs and scale classes."""

from __future__ import annotations

import json
import math
import os
import re
import zlib

import numpy as np
import pytest
import yaml
from PIL import Image
from scipy import ndimage

from cso_runtime.config import ExplorationConfig
from cso_runtime.episode import run_episode
from cso_runtime.geodesic import geodesic_distance, traversable_cells
from cso_runtime.geometry import GridGeometry, Pose2D
from cso_runtime.map_files import save_map
from cso_runtime.policies import make_policy
from cso_runtime.scene_generator import generate_floor_plan
from cso_runtime.scenes import (
    FREE_RGB,
    SCALES,
    START_RGB,
    WALL_RGB,
    FloorPlan,
    SceneError,
    builtin_scene_dir,
    floor_plan_from_rgb,
    load_floor_plan,
    load_map_scene,
    resolve_scenes,
    scale_of,
)
from cso_runtime.simulator import KinematicSimulator

SEEDS = range(6)
ROBOT_RADIUS_M = 0.2


@pytest.fixture(scope="module")
def plans():
    """A few generated plans of every scale class, built once for the whole file."""
    return [generate_floor_plan(scale, seed) for scale in SCALES for seed in SEEDS]


# --- generator ---------------------------------------------------------------------------------


def test_same_seed_same_plan_and_different_seed_different_plan():
    a, b = generate_floor_plan("middle", 11), generate_floor_plan("middle", 11)
    assert np.array_equal(a.free, b.free)
    assert a.start == b.start
    c = generate_floor_plan("middle", 12)
    assert a.free.shape != c.free.shape or not np.array_equal(a.free, c.free)


def test_generator_leaves_the_global_rng_alone():
    np.random.seed(0)
    expected = np.random.random()
    np.random.seed(0)
    generate_floor_plan("small", 4)
    assert np.random.random() == expected


def test_scale_class_name_and_start(plans):
    assert {plan.scale for plan in plans} == set(SCALES)
    for plan in plans:
        scale = plan.name.removeprefix("gen_").rsplit("_", 1)[0]
        assert plan.name.startswith(f"gen_{scale}_")
        assert plan.scale == scale, (plan.name, plan.traversable_area_m2())
        assert plan.start.yaw_rad == 0.0
        clearance = ndimage.distance_transform_edt(plan.free)
        iy, ix = plan.geometry.world_to_cell(plan.start.x_m, plan.start.y_m)
        # Distance from the start cell's centre to the nearest wall cell's edge.
        assert (clearance[int(iy), int(ix)] - 0.5) * plan.resolution_m >= 0.4, plan.name


def test_middle_areas_vary_across_the_class():
    areas = [generate_floor_plan("middle", seed).traversable_area_m2() for seed in range(20)]
    assert min(areas) < 55.0 and max(areas) > 75.0, areas


def test_every_free_cell_is_reachable_and_the_outer_wall_is_closed(plans):
    for plan in plans:
        assert np.count_nonzero(plan.traversable_region()) == np.count_nonzero(plan.free), plan.name
        wall_cells = int(np.ceil(0.1 / plan.resolution_m))
        assert not plan.free[:wall_cells].any() and not plan.free[-wall_cells:].any(), plan.name
        assert not plan.free[:, :wall_cells].any() and not plan.free[:, -wall_cells:].any(), plan.name


def test_walls_are_at_least_ten_centimetres_thick(plans):
    for plan in plans:
        k = int(np.ceil(0.1 / plan.resolution_m - 1e-9))
        walls = plan.occupied
        # Every wall cell lies inside some k x k block of wall cells: no wall is thinner than k cells.
        assert np.array_equal(ndimage.binary_opening(walls, np.ones((k, k), dtype=bool)), walls), plan.name


@pytest.mark.parametrize("radius_m", [ROBOT_RADIUS_M, 0.35])
def test_a_robot_passes_every_door(plans, radius_m):
    """The robot (radius 0.2 m) reaches every room. With a 0.35 m radius the check is strict: a door
    of 0.8 m (16 cells) still leaves a 2-cell passage after inflation, one of 0.7 m leaves none."""
    for plan in plans:
        traversable = traversable_cells(plan.free, plan.occupied, radius_m, plan.resolution_m)
        distance_m = geodesic_distance(traversable, plan.geometry, plan.start.xy)
        roomy = ndimage.distance_transform_edt(plan.free) * plan.resolution_m > radius_m + 0.05
        assert roomy.any()
        assert np.isfinite(distance_m[roomy]).all(), f"{plan.name}: {int((~np.isfinite(distance_m[roomy])).sum())} cells cut off"


def test_several_rooms_per_plan(plans):
    for plan in plans:
        # Eroding by more than half the widest door (1 m) closes the doors and splits the rooms
        # (a 1 m corridor vanishes too, so a plan keeps at least all its rooms but one).
        size = int(round(1.0 / plan.resolution_m)) + 1
        _, n = ndimage.label(ndimage.binary_erosion(plan.free, np.ones((size, size), dtype=bool)))
        least_rooms = {"small": 2, "middle": 3, "large": 7, "super_large": 15}[plan.scale]
        assert n >= least_rooms, (plan.name, n)


def test_generator_rejects_bad_arguments():
    with pytest.raises(SceneError, match="huge"):
        generate_floor_plan("huge", 0)
    with pytest.raises(SceneError, match="seed"):
        generate_floor_plan("small", -1)
    with pytest.raises(SceneError, match="resolution"):
        generate_floor_plan("small", 0, resolution_m=0.5)


@pytest.mark.parametrize("m_per_px", [0.0, -0.1, float("inf"), float("nan"), 1e300])
def test_a_scale_that_is_no_plan_scale_is_refused_for_every_spec(m_per_px):
    with pytest.raises(SceneError, match=re.escape("metres per pixel must be in (0, 10] m (scenes.MAX_M_PER_PX), got")):
        resolve_scenes("builtin", None, m_per_px)


def test_a_start_walled_into_a_cupboard_is_no_scene():
    """A plan whose start reaches almost no floor would be scored 100 % coverage in no step: refused."""
    free = np.zeros((20, 20), dtype=bool)
    free[9:11, 9:11] = True  # 4 cells of 0.05 m: 0.01 m2
    free[2:8, 2:18] = True  # floor the start cannot reach
    plan = FloorPlan("cupboard", free, 0.05, Pose2D(0.5, 0.5, 0.0))
    with pytest.raises(SceneError, match=r"only 0.01 m2 of floor is reachable from the start"):
        plan.traversable_region()


def test_generator_works_at_the_dungeon_resolution():
    plan = generate_floor_plan("middle", 2, resolution_m=0.1)
    assert plan.scale == "middle"
    assert np.count_nonzero(plan.traversable_region()) == np.count_nonzero(plan.free)


# --- PNG plans ---------------------------------------------------------------------------------


def _write_png(path, pixels_rgb: np.ndarray) -> None:
    Image.fromarray(pixels_rgb.astype(np.uint8), "RGB").save(path)


def _tiny_plan_pixels() -> np.ndarray:
    """8 rows x 10 columns: wall border, free inside, 2x2 start near the top, one wall pixel near the bottom."""
    px = np.empty((8, 10, 3), dtype=np.uint8)
    px[:] = WALL_RGB
    px[1:7, 1:9] = FREE_RGB
    px[1:3, 3:5] = START_RGB  # image rows 1-2 (top), columns 3-4
    px[6, 2] = WALL_RGB  # image row 6: grid row 1
    return px


def test_a_plan_whose_file_name_is_no_utf8_is_named_so_every_encoder_takes_it(tmp_path):
    """A file name of bytes that are no UTF-8 (``img_\\xff.png``) is, as Python reads it (``os.fsdecode``), a str with a
    lone surrogate: as the scene's name, every ``episode_status`` failed to encode (the sim exited at its first step and
    was restarted until given up), MuJoCo refused the model and episodes.csv failed to write. The name is escaped where
    it is made, whichever way the plan is given (a folder, the file, a map YAML); the file is read by its own path."""
    from cso_runtime.messages import EpisodeStatusMsg, decode, encode

    png, yaml_map = tmp_path / os.fsdecode(b"img_\xff.png"), tmp_path / "maps" / os.fsdecode(b"m\xff.yaml")
    try:
        _write_png(png, _tiny_plan_pixels())
    except OSError:  # a file system that takes only UTF-8 names (macOS): no such file to read
        pytest.skip("this file system refuses a file name of bytes that are no UTF-8")
    yaml_map.parent.mkdir()
    save_map(tmp_path / "maps" / "ok.yaml", np.zeros((6, 6), dtype=np.int8), GridGeometry(0.1, (6, 6)))
    (tmp_path / "maps" / "ok.yaml").rename(yaml_map)  # its image is ok.png, named in the YAML
    (ref,) = resolve_scenes(str(tmp_path))
    (by_file,) = resolve_scenes(str(png))
    (map_ref,) = resolve_scenes(str(yaml_map.parent))
    names = [ref.name, ref.load().name, by_file.name, load_floor_plan(png).name]
    assert names == ["img_\\udcff"] * 4 and ref.path == str(png)
    assert map_ref.name == load_map_scene(yaml_map).name == "m\\udcff"
    said = decode(encode(EpisodeStatusMsg("exploring", 1, scene=ref.load().name)), EpisodeStatusMsg)
    assert said.scene == "img_\\udcff"


def test_png_colours_start_and_y_flip(tmp_path):
    _write_png(tmp_path / "tiny.png", _tiny_plan_pixels())
    plan = load_floor_plan(tmp_path / "tiny.png", resolution_m=0.1)
    assert plan.name == "tiny"
    assert plan.free.shape == (8, 10)
    assert np.count_nonzero(plan.free) == 6 * 8 - 1  # the start square counts as free
    assert not plan.free[0].any() and not plan.free[-1].any()
    assert not plan.free[1, 2] and plan.free[6, 2]  # row 0 is the image's bottom row
    # Start square covers grid rows 5-6 and columns 3-4: centre (0.4 m, 0.6 m).
    assert plan.start.x_m == pytest.approx(0.4)
    assert plan.start.y_m == pytest.approx(0.6)
    assert plan.start.yaw_rad == 0.0
    assert plan.traversable_area_m2() == pytest.approx(47 * 0.01)
    assert np.array_equal(plan.pixels_from_grid(plan.free)[6], plan.free[1])


@pytest.mark.parametrize("dtype", [np.uint8, np.int64, np.float64])
def test_plan_colours_match_within_ten_per_channel(dtype):
    """Anti-aliased or re-encoded plans: a pixel is free (or the start) when every channel is within 10
    of the colour, whatever the image's number type; 11 off in one channel is a wall."""
    px = _tiny_plan_pixels().astype(np.int64)
    px[4, 1] += (10, -10, 10)  # free, at the tolerance in every channel
    px[4, 2] += (0, 11, 0)  # 11 off in green: a wall
    px[1, 3] = (245, 226, 10)  # start (255, 216, 0) at the tolerance
    px[2, 4] = (255, 216, 11)  # 11 off in blue: a wall, not the start
    plan = floor_plan_from_rgb("edges", px.astype(dtype), 0.1)
    grid = plan.pixels_from_grid(plan.free)
    assert grid[4, 1] and not grid[4, 2] and grid[1, 3] and not grid[2, 4]
    assert np.count_nonzero(plan.free) == 47 - 2
    assert plan.start.x_m == pytest.approx(((3 + 4 + 3) / 3 + 0.5) * 0.1)  # three start pixels left


def test_png_with_alpha_channel_loads(tmp_path):
    rgba = np.concatenate([_tiny_plan_pixels(), np.full((8, 10, 1), 255, dtype=np.uint8)], axis=2)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    assert np.count_nonzero(load_floor_plan(tmp_path / "rgba.png").free) == 47


def test_corrupt_missing_and_markerless_pngs_raise_scene_error(tmp_path):
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    with pytest.raises(SceneError, match="broken.png"):
        load_floor_plan(tmp_path / "broken.png")
    with pytest.raises(SceneError, match="missing.png"):
        load_floor_plan(tmp_path / "missing.png")
    px = _tiny_plan_pixels()
    px[px[:, :, 0] == START_RGB[0]] = FREE_RGB
    _write_png(tmp_path / "nostart.png", px)
    with pytest.raises(SceneError, match="nostart.*start"):
        load_floor_plan(tmp_path / "nostart.png")


def test_a_png_with_two_start_markers_is_a_scene_error_not_a_start_between_them(tmp_path):
    """The start is the centre of the start colour's pixels: a plan with two markers started the robot halfway between
    them, in another room or a wall (where the error blamed the start, not the markers). One marker, its pixels
    touching (a corner will do), is the start."""
    px = _tiny_plan_pixels()
    px[5:7, 7:9] = START_RGB  # a second square, bottom right
    _write_png(tmp_path / "two.png", px)
    with pytest.raises(SceneError, match="two: 2 start markers"):
        load_floor_plan(tmp_path / "two.png")
    px = _tiny_plan_pixels()
    px[3, 5] = START_RGB  # diagonal to the square's corner pixel (2, 4): the same marker
    plan = floor_plan_from_rgb("one", px, 0.1)
    assert plan.start.x_m == pytest.approx(((3 + 4 + 3 + 4 + 5) / 5 + 0.5) * 0.1)


def test_a_truncated_png_is_named_by_its_path_as_an_unreadable_one_is(tmp_path):
    """A folder of plans with a cut-off download among them: eval's failure list must say which file, by the path a
    user can open (plans of the easy and complex sets share names), as it does for a file that is no image at all."""
    whole = tmp_path / "whole.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (200, 200, 3), dtype=np.uint8)).save(whole)
    (tmp_path / "cut.png").write_bytes(whole.read_bytes()[:400])
    (tmp_path / "text.png").write_text("not an image")
    for name in ("cut.png", "text.png"):
        with pytest.raises(SceneError) as err:
            load_floor_plan(tmp_path / name)
        assert str(err.value).startswith(f"{tmp_path / name}: ")


def test_builtin_scenes_load_with_licence():
    folder = builtin_scene_dir()
    assert "MIT" in (folder / "LICENSE").read_text()
    assert (folder / "README.md").is_file()
    refs = resolve_scenes("builtin")
    assert [r.name for r in refs] == [f"img_{i}" for i in range(1, 6)]
    for ref in refs:
        plan = ref.load()
        assert plan.free.shape == (480, 640)
        assert plan.resolution_m == 0.1
        assert plan.scale == "super_large"


# --- scene specs -------------------------------------------------------------------------------


def test_resolve_generated_spec():
    refs = resolve_scenes("generated:small:3:7")
    assert [r.name for r in refs] == ["gen_small_7", "gen_small_8", "gen_small_9"]
    assert [r.generated for r in refs] == [("small", 7), ("small", 8), ("small", 9)]
    plan = refs[0].load()
    assert plan.name == "gen_small_7" and plan.scale == "small"
    assert np.array_equal(plan.free, generate_floor_plan("small", 7).free)
    assert len(resolve_scenes("generated:middle:5:0", limit=2)) == 2
    (big,) = resolve_scenes("generated:super_large:1:3")
    assert big.name == "gen_super_large_3" and big.load().scale == "super_large"


def test_resolve_folder_in_natural_order(tmp_path):
    for name in ("img_10.png", "img_2.png", "img_1.png"):
        _write_png(tmp_path / name, _tiny_plan_pixels())
    (tmp_path / "notes.txt").write_text("not a plan")
    refs = resolve_scenes(str(tmp_path), resolution_m=0.05)
    assert [r.name for r in refs] == ["img_1", "img_2", "img_10"]
    assert refs[0].load().resolution_m == 0.05
    single = resolve_scenes(str(tmp_path / "img_2.png"))
    assert [r.name for r in single] == ["img_2"]


def test_resolve_missing_png_fails_when_loaded(tmp_path):
    (ref,) = resolve_scenes(str(tmp_path / "gone.png"))
    with pytest.raises(SceneError, match="gone.png"):
        ref.load()


@pytest.mark.parametrize(
    "spec",
    ["generated:huge:1:0", "generated:small:x:0", "generated:small:1", "generated:small:1:0:9", "generated:small:0:0", "generated:middle:2:-1", "plans.txt", "nowhere"],
)
def test_bad_specs_raise_scene_error(spec):
    with pytest.raises(SceneError):
        resolve_scenes(spec)


def test_empty_folder_is_an_error(tmp_path):
    with pytest.raises(SceneError, match="no PNG floor plans or map YAMLs"):
        resolve_scenes(str(tmp_path))


@pytest.mark.parametrize(
    ("area_m2", "scale"),
    [
        (0.0, "small"),
        (29.99, "small"),
        (30.0, "middle"),
        (99.99, "middle"),
        (100.0, "large"),
        (259.99, "large"),
        (260.0, "super_large"),
    ],
)
def test_scale_of_boundaries(area_m2, scale):
    assert scale_of(area_m2) == scale


def _plan_as_map(tmp_path, plan, origin=(-3.0, 1.5), **extra):
    """``plan`` saved as a map_server map (free 0, everything else a wall), origin moved away from 0."""
    grid = np.where(plan.free, 0, 100).astype(np.int8)
    geometry = GridGeometry(plan.resolution_m, plan.free.shape, *origin)
    yaml_path = save_map(tmp_path / f"{plan.name}.yaml", grid, geometry)
    if extra:
        meta = yaml.safe_load(yaml_path.read_text())
        yaml_path.write_text(yaml.safe_dump({**meta, **extra}))
    return yaml_path


def test_a_map_server_map_is_a_scene_and_is_explored_like_its_plan(tmp_path):
    """A map your robot built (or any Nav2 map) as a scene: free cells are the floor, the start is the
    free cell farthest from walls in the largest region, and greedy-dist explores it to the end."""
    plan = generate_floor_plan("small", 3)
    yaml_path = _plan_as_map(tmp_path, plan)
    (ref,) = resolve_scenes(str(yaml_path), resolution_m=0.1)  # the map's own resolution wins
    scene = ref.load()
    assert scene.name == plan.name and scene.resolution_m == plan.resolution_m
    np.testing.assert_array_equal(scene.free, plan.free)
    iy, ix = scene.geometry.world_to_cell(scene.start.x_m, scene.start.y_m)
    clearance = ndimage.distance_transform_edt(plan.free)
    assert clearance[iy, ix] == clearance.max() and scene.traversable_area_m2() == pytest.approx(plan.traversable_area_m2())
    result = run_episode(KinematicSimulator(scene, seed=0), make_policy("greedy-dist"), ExplorationConfig(), seed=0)
    assert result.terminated_by == "coverage" and result.coverage_pct > 99.0


def test_a_map_scene_takes_its_start_from_the_yaml_and_folders_of_maps_list_the_yamls(tmp_path):
    plan = generate_floor_plan("small", 3)
    x, y = plan.start.x_m - 3.0, plan.start.y_m + 1.5  # the plan's start, in the map frame of origin (-3, 1.5)
    yaml_path = _plan_as_map(tmp_path, plan, start=[x, y, 1.0])
    scene = resolve_scenes(str(yaml_path))[0].load()
    assert (scene.start.x_m, scene.start.y_m, scene.start.yaw_rad) == pytest.approx((plan.start.x_m, plan.start.y_m, 1.0))
    assert [r.name for r in resolve_scenes(str(tmp_path))] == [plan.name]  # the YAML, not its image
    _plan_as_map(tmp_path, plan, start=[-3.0 + 0.01, 1.5 + 0.01, 0.0])  # the corner: a wall
    with pytest.raises(SceneError, match="not on a free cell"):
        resolve_scenes(str(yaml_path))[0].load()
    _plan_as_map(tmp_path, plan, start=[1.0, 1.0, 0.0])  # a start off the map: where the map lies says what to fix
    with pytest.raises(SceneError) as off:
        resolve_scenes(str(yaml_path))[0].load()
    width_m, height_m = plan.free.shape[1] * plan.resolution_m, plan.free.shape[0] * plan.resolution_m
    assert f"start (1.0, 1.0) m is off the map: in the map frame it covers x -3 to {-3 + width_m:g} m, y 1.5 to {1.5 + height_m:g} m" in str(off.value)
    _plan_as_map(tmp_path, plan, start=[1.0, "two", 0.0])
    with pytest.raises(SceneError, match=r"start must be \[x_m, y_m, yaw_rad\]"):
        resolve_scenes(str(yaml_path))[0].load()
    (tmp_path / "broken.yaml").write_text("image: nowhere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(SceneError, match="cannot read the map image"):
        resolve_scenes(str(tmp_path / "broken.yaml"))[0].load()
    with pytest.raises(SceneError, match="file not found"):
        resolve_scenes(str(tmp_path / "gone.yaml"))[0].load()


def test_a_map_scenes_start_written_with_an_exponent_is_read_as_its_origin_is(tmp_path):
    """A map YAML's numbers written with an exponent (``5e-2``, ``-3e0``: PyYAML's YAML 1.1 reads them as text, map_server's
    yaml-cpp as numbers) are read as numbers in ``resolution`` and ``origin`` (map_files): the scene's own ``start``,
    in the same file, was refused ("start must be [x_m, y_m, yaw_rad], three finite numbers") for ``[2e0, 1.5e0, 1e0]``.
    It is read by the same rule; what is no number (nan, a word) is still refused."""
    plan = generate_floor_plan("small", 3)
    x, y = plan.start.x_m - 3.0, plan.start.y_m + 1.5  # the plan's start, in the map frame of origin (-3, 1.5)
    yaml_path = _plan_as_map(tmp_path, plan)
    text = yaml_path.read_text()
    yaml_path.write_text(text + f"start: [{x!r}e0, {y * 10!r}e-1, 1e0]\n")
    assert isinstance(yaml.safe_load(yaml_path.read_text())["start"][2], str)  # PyYAML's text, as origin's would be
    scene = resolve_scenes(str(yaml_path))[0].load()
    assert (scene.start.x_m, scene.start.y_m, scene.start.yaw_rad) == pytest.approx((plan.start.x_m, plan.start.y_m, 1.0))
    for bad in ("nan", ".nan", "two", "1e400"):
        yaml_path.write_text(text + f"start: [{x!r}, {bad}, 0]\n")
        with pytest.raises(SceneError, match=r"start must be \[x_m, y_m, yaw_rad\], three finite numbers"):
            resolve_scenes(str(yaml_path))[0].load()


def test_scenes_describes_each_plan_and_flags_the_unusable_ones(tmp_path):
    """``cso-runtime scenes``: size, resolution, traversable area, scale class and start of each plan, a preview
    PNG each, and a plan that cannot be used listed with its reason (exit 1), so a folder is checked before a
    long ``eval``."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.plots import scene_figure
    from cso_runtime.scenes import describe_scene

    (tmp_path / "plans").mkdir()
    _write_png(tmp_path / "plans" / "tiny.png", _tiny_plan_pixels())
    plan = load_floor_plan(tmp_path / "plans" / "tiny.png", resolution_m=0.1)
    info = describe_scene(plan)
    assert info["width_m"] == pytest.approx(1.0) and info["height_m"] == pytest.approx(0.8) and info["cells"] == [8, 10]
    assert info["traversable_area_m2"] == pytest.approx(0.47) and info["scale"] == "small"
    assert info["start"] == {"x_m": pytest.approx(0.4), "y_m": pytest.approx(0.6), "yaw_rad": 0.0}
    fig = scene_figure(plan)
    assert "1.0 x 0.8 m at 0.1 m/px, 0.5 m2 traversable (small)" in fig.axes[0].get_title()
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["wall", "free, reachable", "start"]
    px = _tiny_plan_pixels()
    px[1:7, 6] = WALL_RGB  # columns 7-8 cut off from the start
    walled = floor_plan_from_rgb("walled", px, 0.1)
    assert describe_scene(walled)["free_area_m2"] > describe_scene(walled)["traversable_area_m2"]
    assert "free, not reachable from the start" in [t.get_text() for t in scene_figure(walled).legends[0].get_texts()]
    (tmp_path / "plans" / "broken.png").write_bytes(b"not a png")

    out = tmp_path / "preview"
    r = CliRunner().invoke(app, ["scenes", str(tmp_path / "plans"), "--json", "--preview", str(out), "--m-per-px", "0.05"])
    assert r.exit_code == 1, r.output
    listed = {s["scene"]: s for s in json.loads(r.stdout)}
    assert listed["tiny"]["resolution_m"] == 0.05 and listed["tiny"]["traversable_area_m2"] == pytest.approx(47 * 0.05**2)
    assert "broken" in listed["broken"]["error"] and "traversable_area_m2" not in listed["broken"]
    assert (out / "tiny.png").is_file() and not (out / "broken.png").exists()
    r = CliRunner().invoke(app, ["scenes", "builtin"], env={"COLUMNS": "120"})
    assert r.exit_code == 0, r.output
    row = next(ln for ln in r.output.splitlines() if "img_1" in ln)
    assert "64.0 x 48.0" in row and "514.6" in row and "super large" in row  # the packaged README's table
    r = CliRunner().invoke(app, ["scenes", "nowhere/x.txt"])
    assert r.exit_code == 2 and "error:" in r.output


def test_scenes_table_says_why_a_plan_is_unusable_in_full(tmp_path):
    """The table's reason for an unusable plan is whole on a terminal of 80 columns: it was folded into the
    narrow size column and cut off with an ellipsis, the file it names with it."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    plans = tmp_path / "a_folder_of_plans_with_a_long_name"
    plans.mkdir()
    (plans / "broken.png").write_bytes(b"not a png")
    why = json.loads(CliRunner().invoke(app, ["scenes", str(plans), "--json"]).stdout)[0]["error"]
    r = CliRunner().invoke(app, ["scenes", str(plans)], env={"COLUMNS": "80"})
    assert r.exit_code == 1
    assert f"broken: {why}" in r.output and "…" not in r.output



def _png_header_only(path, width_px: int, height_px: int) -> None:
    """A PNG's signature, IHDR and IEND chunks, no pixels: all that a size check may read."""
    ihdr = b"IHDR" + width_px.to_bytes(4, "big") + height_px.to_bytes(4, "big") + b"\x08\x02\x00\x00\x00"
    iend = bytes(4) + b"IEND" + zlib.crc32(b"IEND").to_bytes(4, "big")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + (13).to_bytes(4, "big") + ihdr + zlib.crc32(ihdr).to_bytes(4, "big") + iend)


def test_a_floor_plan_too_large_to_explore_is_a_scene_error_not_a_traceback(tmp_path):
    """Pillow's decompression-bomb check raised a traceback over 179 M pixels; a 6000 x 6000 plan loaded
    and then took minutes and gigabytes. Both are refused from the header, naming the size."""
    _png_header_only(tmp_path / "huge.png", 20000, 20000)
    with pytest.raises(SceneError, match="huge.png: the image is too large"):
        load_floor_plan(tmp_path / "huge.png")
    _png_header_only(tmp_path / "wide.png", 6000, 6000)
    with pytest.raises(SceneError, match="6000 x 6000 pixels"):
        load_floor_plan(tmp_path / "wide.png")


def test_a_png_in_other_colours_than_the_dungeon_set_says_how_to_load_it(tmp_path):
    """A building's floor plan, white floor and black walls, with a start square: it read as 0.01 m2 of
    floor 'walled in?' (only the marker had a plan colour). Now it names the colours and the YAML way."""
    px = np.full((20, 30, 3), 255, dtype=np.uint8)
    px[0], px[-1], px[:, 0], px[:, -1] = 0, 0, 0, 0
    px[10, 10] = START_RGB
    _write_png(tmp_path / "building.png", px)
    with pytest.raises(SceneError, match=r"no floor of the Dungeon free colour.*map_server map.*YAML"):
        load_floor_plan(tmp_path / "building.png")
    px[10, 10] = 255  # no start square either
    _write_png(tmp_path / "building.png", px)
    with pytest.raises(SceneError, match=r"no start marker.*other colours.*start: \[x_m, y_m, yaw_rad\]"):
        load_floor_plan(tmp_path / "building.png")


def test_a_map_with_a_rotated_origin_is_a_scene_and_its_start_turns_with_it(tmp_path):
    """map_server's ``origin`` yaw turns the grid in the map frame. It was refused ('not supported'); the plan
    is the grid itself, so only the YAML's map-frame start turns into the grid's frame."""
    plan = generate_floor_plan("small", 3)
    yaw0 = math.pi / 2  # the grid's x axis points along the map's y axis
    origin = [-3.0, 1.5, yaw0]
    # The plan's start (grid frame) in the map frame: rotate by yaw0, then add the origin.
    x = origin[0] + math.cos(yaw0) * plan.start.x_m - math.sin(yaw0) * plan.start.y_m
    y = origin[1] + math.sin(yaw0) * plan.start.x_m + math.cos(yaw0) * plan.start.y_m
    yaml_path = _plan_as_map(tmp_path, plan, origin=origin[:2], start=[x, y, yaw0 + 0.5])
    meta = yaml.safe_load(yaml_path.read_text())
    yaml_path.write_text(yaml.safe_dump({**meta, "origin": origin}))
    scene = resolve_scenes(str(yaml_path))[0].load()
    np.testing.assert_array_equal(scene.free, plan.free)
    assert (scene.start.x_m, scene.start.y_m, scene.start.yaw_rad) == pytest.approx((plan.start.x_m, plan.start.y_m, 0.5))


def test_a_map_scene_keeps_its_map_frame_in_the_listing_and_the_maps_it_writes(tmp_path):
    """The YAML's ``origin`` was dropped: ``scenes`` listed the start in the grid's frame (not the ``start:`` the
    user wrote) and the robot's maps were written at ``origin: [0, 0, 0]``, off the user's map in RViz. Now the
    listing shows the start as written and the written map overlays the source map cell for cell."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.map_files import load_map

    plan = generate_floor_plan("small", 3)
    origin = (-3.5, 2.0)
    start = [plan.start.x_m + origin[0], plan.start.y_m + origin[1], 0.25]  # the plan's start, in the map frame
    yaml_path = _plan_as_map(tmp_path, plan, origin=origin, start=start)
    yaml_path.write_text(yaml_path.read_text().replace("origin:\n- -3.5\n- 2.0\n- 0.0", "origin: [-3.5, 2.0, 0]"))
    assert yaml.safe_load(yaml_path.read_text())["origin"] == [-3.5, 2.0, 0]
    r = CliRunner().invoke(app, ["scenes", str(yaml_path), "--json"])
    assert r.exit_code == 0, r.output
    (listed,) = json.loads(r.stdout)
    assert listed["start"] == {"x_m": pytest.approx(start[0]), "y_m": pytest.approx(start[1]), "yaw_rad": pytest.approx(0.25)}
    assert listed["map_origin"] == {"x_m": -3.5, "y_m": 2.0, "yaw_rad": 0.0}
    r = CliRunner().invoke(app, ["scenes", str(yaml_path)], env={"COLUMNS": "160"})
    assert f"{start[0]:.2f}, {start[1]:.2f}, 0.25" in r.output

    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["eval", "--method", "greedy-dist", "--maps", str(yaml_path), "--max-steps", "30", "--out", str(out)])
    assert r.exit_code == 0, r.output
    written = out / "maps" / "greedy-dist" / f"{plan.name}.yaml"
    assert yaml.safe_load(written.read_text())["origin"] == [-3.5, 2.0, 0.0]
    source_grid, source_geometry = load_map(yaml_path)
    grid, geometry = load_map(written)
    assert geometry == source_geometry  # the same cells at the same places in the map frame
    seen_free = grid == 0
    assert seen_free.any() and not (seen_free & (source_grid != 0)).any()
    npz = np.load(out / "episodes" / "greedy-dist" / f"{plan.name}.npz")
    np.testing.assert_array_equal(npz["map_origin"], [-3.5, 2.0, 0.0])  # what places the plan-frame trajectory
    assert npz["trajectory"][0] == pytest.approx([plan.start.x_m, plan.start.y_m], abs=1e-5)  # unchanged: the plan's frame

    # The same plan moved to another origin: --resume refuses to mix it with the old episode; with --overwrite it
    # runs it again, so the map it writes is at the new origin.
    moved = {**yaml.safe_load(yaml_path.read_text()), "origin": [1.0, -2.0, 0.0], "start": [start[0] + 4.5, start[1] - 4.0, 0.25]}
    yaml_path.write_text(yaml.safe_dump(moved))
    resume = ["eval", "--method", "greedy-dist", "--maps", str(yaml_path), "--max-steps", "30", "--out", str(out), "--resume"]
    r = CliRunner().invoke(app, resume)
    assert r.exit_code == 2 and "another configuration" in r.output, r.output
    assert "it ran on another plan under the same name (another --m-per-px, folder or map origin)" in " ".join(r.output.split()), r.output
    r = CliRunner().invoke(app, [*resume, "--overwrite"])
    assert r.exit_code == 0, r.output
    assert json.loads((out / "summary.json").read_text())["meta"].get("resumed_episodes", 0) == 0
    assert yaml.safe_load(written.read_text())["origin"] == [1.0, -2.0, 0.0]


def test_a_rotated_map_origin_is_kept_in_the_maps_written(tmp_path):
    """An ``origin`` with a yaw: the written map carries the same rotated origin, so RViz turns it as it turns the
    user's own map, and a plan-frame pose lands where the user's map has it."""
    from cso_runtime.map_files import map_origin_of

    plan = generate_floor_plan("small", 3)
    yaml_path = _plan_as_map(tmp_path, plan, origin=(-3.0, 1.5))
    meta = yaml.safe_load(yaml_path.read_text())
    yaml_path.write_text(yaml.safe_dump({**meta, "origin": [-3.0, 1.5, math.pi / 2]}))
    scene = resolve_scenes(str(yaml_path))[0].load()
    assert scene.map_origin == Pose2D(-3.0, 1.5, math.pi / 2)
    assert map_origin_of(scene.geometry, scene.map_origin) == pytest.approx([-3.0, 1.5, math.pi / 2])
    moved = GridGeometry(scene.resolution_m, scene.free.shape, 1.0, 0.0)  # a grid one metre along the plan's x
    assert map_origin_of(moved, scene.map_origin) == pytest.approx([-3.0, 2.5, math.pi / 2])  # the map's y
    p = scene.to_map_frame(Pose2D(1.0, 2.0, 0.1))
    assert (p.x_m, p.y_m, p.yaw_rad) == pytest.approx((-5.0, 2.5, math.pi / 2 + 0.1))


@pytest.mark.parametrize(
    ("spec", "said"),
    [
        ("bulitin", "scene spec 'bulitin' (did you mean builtin?) is not a folder, a .png, a map .yaml, 'builtin' or generated:SCALE:N:SEED"),
        ("generated:super-large:2:0", "generated scale must be one of small, middle, large, super_large, got 'super-large' (did you mean super_large?)"),
        ("generated:huge:2:0", "generated scale must be one of small, middle, large, super_large, got 'huge'"),
    ],
)
def test_a_misspelt_scene_spec_is_refused_with_the_spelling_it_most_likely_meant(spec: str, said: str) -> None:
    """``--scene bulitin`` or ``generated:super-large:...`` were refused without the nearest spelling that profiles,
    methods and config keys get (``did you mean``): the user had to read the list and find their own typo."""
    from cso_runtime.scenes import SceneError, resolve_scenes

    with pytest.raises(SceneError) as caught:
        resolve_scenes(spec)
    assert str(caught.value) == said


def test_scenes_json_writes_figures_rounded_not_a_float_sums_digits():
    """``scenes --json`` wrote ``"x_m": 4.7250000000000005`` and ``"free_area_m2": 21.922500000000003``: a float sum's
    last digits, which a script compares badly and a reader takes for precision. Each float is ``geometry.rounded``
    (``WRITTEN_DECIMALS``: the nanometre, as map files write poses), as written; ints and text untouched."""
    import json
    import re

    from typer.testing import CliRunner

    from cso_runtime.cli import app
    from cso_runtime.geometry import WRITTEN_DECIMALS, rounded_floats

    assert rounded_floats({"a": [4.7250000000000005, 2, True, "x", None], "b": {"c": -1e-12}}) == {"a": [4.725, 2, True, "x", None], "b": {"c": 0.0}}
    assert repr(rounded_floats({"c": -1e-12})["c"]) == "0.0" and isinstance(rounded_floats([True])[0], bool)
    r = CliRunner().invoke(app, ["scenes", "generated:small:3:0", "--json"])
    assert r.exit_code == 0, r.output
    rows = json.loads(r.stdout)
    floats = re.findall(r"-?\d+\.(\d+)", r.stdout)
    assert floats and max(len(decimals) for decimals in floats) <= WRITTEN_DECIMALS, r.stdout
    assert rows[0]["start"]["x_m"] == 4.725 and rows[0]["free_area_m2"] == 21.9225, rows[0]


def test_a_mistyped_count_of_generated_plans_is_refused_at_once(monkeypatch: pytest.MonkeyPatch):
    """``scenes generated:small:99999999:0 --limit 1`` (a few zeros too many) listed all 10^8 plans before taking the
    first: a minute and 7.6 GB, ``eval --dry-run`` too, on a shared machine. N is bounded
    (``scenes.MAX_GENERATED_PLANS``), said at once, exit 2; under the bound, ``--limit`` lists only its plans."""
    from typer.testing import CliRunner

    from cso_runtime import scenes
    from cso_runtime.cli import app
    from cso_runtime.scenes import MAX_GENERATED_PLANS, SceneError, resolve_scenes

    with pytest.raises(SceneError, match=r"N must be in \[1, 100,000\] \(scenes.MAX_GENERATED_PLANS\), got 99,999,999"):
        resolve_scenes("generated:small:99999999:0", limit=1)
    made: list[object] = []
    real = scenes.SceneRef
    monkeypatch.setattr(scenes, "SceneRef", lambda *args, **kwargs: made.append(args) or real(*args, **kwargs))
    refs = resolve_scenes(f"generated:small:{MAX_GENERATED_PLANS}:0", limit=2)
    assert [ref.name for ref in refs] == ["gen_small_0", "gen_small_1"] and len(made) == 2
    r = CliRunner().invoke(app, ["scenes", "generated:small:99999999:0", "--limit", "1"])
    assert r.exit_code == 2 and "N must be in [1, 100,000]" in " ".join(r.output.split()), r.output


def test_a_start_whose_box_body_overlaps_a_wall_is_said_from_the_plan_alone():
    """The MuJoCo LIMO warned of a body overlapping a wall at the start pose only from its built model (MuJoCo's
    contacts after ``mj_forward``), in the sim service's log alone: ``up`` could not say it before anything starts.
    ``scenes.start_overlap_said`` says it from the plan, the start pose and the body's box (``robot.length_m`` along the
    heading by ``robot.width_m`` across), in the sim's very words; a body that only touches a wall's face overlaps none,
    and outside the plan is wall."""
    from cso_runtime.scenes import body_overlaps_walls, start_overlap_said

    free = np.zeros((24, 24), dtype=bool)
    free[1:-1, 1:-1] = True  # 0.05 m cells: the inner wall faces at x, y = 0.05 and 1.15 m

    def said(start: Pose2D, length_m: float = 0.322, width_m: float = 0.22) -> str | None:
        return start_overlap_said(FloorPlan("tiny", free, 0.05, start), length_m, width_m)

    assert said(Pose2D(0.6, 0.6, 0.0)) is None  # in the middle of the room
    against = Pose2D(0.05 + 0.13, 0.6, 0.0)  # 0.13 m from the west wall: the LIMO's half length is 0.161 m
    assert said(against) == "tiny: the LIMO's body overlaps a wall at the start pose (x 0.180 m, y 0.600 m, yaw 0.000 rad): its contacts push it out as the episode starts"
    assert said(Pose2D(0.05 + 0.13, 0.6, 0.5 * math.pi)) is None  # turned across it: its half width, 0.11 m
    assert said(against, length_m=0.25) is None  # the footprint is the config's
    assert said(Pose2D(0.05 + 0.161, 0.6, 0.0)) is None  # its front face on the wall's: touching, no overlap
    assert said(Pose2D(0.6, 0.05 + 0.1, 0.0)) is not None  # a side into the south wall
    edge = np.ones((24, 24), dtype=bool)  # no walls drawn: the grid's edge is the wall
    open_plan = FloorPlan("open", edge, 0.05, against)
    assert body_overlaps_walls(open_plan, Pose2D(0.1, 0.6, 0.0), 0.322, 0.22)  # its back 0.061 m beyond x = 0
    assert not body_overlaps_walls(open_plan, against, 0.322, 0.22) and not body_overlaps_walls(open_plan, Pose2D(0.6, 0.6, 0.3), 0.322, 0.22)
