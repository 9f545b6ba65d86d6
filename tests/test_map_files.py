"""The robot's map as Nav2 map_server files: what map_server would read back, and clear errors on bad files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from cso_runtime.geometry import GridGeometry
from cso_runtime.map_files import MapFileError, load_map, map_yaml_path, save_map


def _grid() -> tuple[np.ndarray, GridGeometry]:
    """A 4 x 5 map, row 0 at the origin: unknown on top, a wall at the bottom row, free in between."""
    grid = np.full((4, 5), -1, dtype=np.int8)
    grid[0, :] = 100
    grid[1:3, :] = 0
    grid[1, 4] = 100
    return grid, GridGeometry(0.05, (4, 5), -1.25, 0.5)


@pytest.mark.parametrize("image_format", ["pgm", "png"])
def test_saved_map_reads_back_the_same_grid_and_geometry(tmp_path: Path, image_format: str):
    grid, geometry = _grid()
    yaml_path = save_map(tmp_path / "office.yaml", grid, geometry, image_format)
    meta = yaml.safe_load(yaml_path.read_text())
    assert meta["image"] == f"office.{image_format}" and meta["mode"] == "trinary" and meta["negate"] == 0
    assert meta["resolution"] == 0.05 and meta["origin"] == [-1.25, 0.5, 0.0]
    with Image.open(tmp_path / f"office.{image_format}") as im:
        pixels = np.asarray(im)
    # map_saver's convention: the image's first row is the map's top (row 3 here, unknown), the wall last.
    assert pixels.dtype == np.uint8 and pixels.shape == (4, 5)
    assert (pixels[0] == 205).all() and (pixels[3] == 0).all() and pixels[2, 4] == 0 and pixels[1, 0] == 254
    back, back_geometry = load_map(yaml_path)
    assert back_geometry == geometry
    np.testing.assert_array_equal(back, grid)


def test_maps_written_by_other_tools_load_with_their_thresholds_and_negate(tmp_path: Path):
    """A map_saver map with Nav2's thresholds, a negated one, and a scale-mode one with a transparent pixel."""
    pixels = np.array([[0, 100, 205, 254]], dtype=np.uint8)
    Image.fromarray(pixels).save(tmp_path / "m.png")
    meta = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.25}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(meta))
    grid, geometry = load_map(tmp_path / "m.yaml")
    assert geometry.shape == (1, 4) and geometry.resolution_m == 0.1
    assert grid.tolist() == [[100, -1, 0, 0]]  # grey 100 is an occupancy of 0.61; with free_thresh 0.25, grey 205 is free
    (tmp_path / "n.yaml").write_text(yaml.safe_dump({**meta, "negate": 1}))
    assert load_map(tmp_path / "n.yaml")[0].tolist() == [[0, -1, 100, 100]]
    rgba = np.zeros((1, 3, 4), dtype=np.uint8)
    rgba[0, :, :3] = np.array([0, 128, 255], dtype=np.uint8)[:, None]
    rgba[0, :, 3] = [255, 255, 0]
    Image.fromarray(rgba, "RGBA").save(tmp_path / "s.png")
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**meta, "image": "s.png", "mode": "scale"}))
    assert load_map(tmp_path / "s.yaml")[0].tolist() == [[100, 62, -1]]  # 128: occupancy 0.498, scaled between


def test_bad_map_files_give_clear_errors(tmp_path: Path):
    grid, geometry = _grid()
    good = save_map(tmp_path / "map.yaml", grid, geometry)
    meta = yaml.safe_load(good.read_text())
    cases = {
        "missing 'resolution'": {k: v for k, v in meta.items() if k != "resolution"},
        "resolution must be positive": {**meta, "resolution": 0},
        "origin must be": {**meta, "origin": [0.0, 0.0]},
        "rotated origin": {**meta, "origin": [0.0, 0.0, 0.5]},
        "unknown mode": {**meta, "mode": "fancy"},
        "free_thresh < occupied_thresh": {**meta, "free_thresh": 0.7},
        "cannot read the map image": {**meta, "image": "nowhere.pgm"},
    }
    for why, bad in cases.items():
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
        with pytest.raises(MapFileError, match=why):
            load_map(tmp_path / "bad.yaml")
    (tmp_path / "bad.yaml").write_text("image: [unclosed")
    with pytest.raises(MapFileError, match="bad.yaml: not valid YAML: ") as raised:  # the words of a config file's
        load_map(tmp_path / "bad.yaml")
    # One line, whole: eval's console and report.html show a failure's first line, which cut YAML's
    # "while parsing a flow node" off before where and what.
    assert "\n" not in str(raised.value) and "line 1, column" in str(raised.value)
    (tmp_path / "bad.yaml").write_bytes(b"image: \xa4\xff map.pgm\n")  # not UTF-8: a clear error, not a traceback
    with pytest.raises(MapFileError, match="not valid YAML"):
        load_map(tmp_path / "bad.yaml")
    (tmp_path / "corrupt.pgm").write_bytes(b"P5 not really")
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({**meta, "image": "corrupt.pgm"}))
    with pytest.raises(MapFileError, match="corrupt.pgm"):
        load_map(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="does not match the geometry"):
        save_map(tmp_path / "x.yaml", grid[:2], geometry)
    with pytest.raises(ValueError, match="image format"):
        save_map(tmp_path / "x.yaml", grid, geometry, "jpg")


def test_map_yaml_path_reads_minus_f_as_map_saver_cli_does(tmp_path, monkeypatch):
    """``save-map -f OUT`` writes OUT.yaml; a folder (or ``-f ""``, the current folder: it used to end in a
    traceback) gets map.yaml inside it; only a map file's own suffix is replaced."""
    monkeypatch.chdir(tmp_path)
    assert map_yaml_path(tmp_path / "office") == tmp_path / "office.yaml"
    assert map_yaml_path(tmp_path / "office.yaml") == tmp_path / "office.yaml"
    assert map_yaml_path(tmp_path / "office.PNG") == tmp_path / "office.yaml"
    assert map_yaml_path(tmp_path / "office.v2") == tmp_path / "office.v2.yaml"
    assert map_yaml_path(tmp_path) == tmp_path / "map.yaml"
    assert map_yaml_path(Path("")) == Path("map.yaml") and map_yaml_path("") == Path("map.yaml")
    assert map_yaml_path(tmp_path / "new_folder" / "m") == tmp_path / "new_folder" / "m.yaml"


def test_save_map_minus_f_ending_in_a_slash_is_a_folder_even_a_new_one(tmp_path, monkeypatch):
    """``save-map -f maps/`` names a folder, as record's ``--out DIR/`` does: map.yaml inside it, the folder made
    if need be. The option was a Path, which drops the slash, so a new folder's name became the map's
    (``maps.yaml`` beside it)."""
    from typer.testing import CliRunner

    from cso_runtime import status
    from cso_runtime.cli import app

    monkeypatch.chdir(tmp_path)
    assert map_yaml_path("new_folder/") == Path("new_folder") / "map.yaml"
    assert map_yaml_path(str(tmp_path / "a" / "b") + "/") == tmp_path / "a" / "b" / "map.yaml"
    assert map_yaml_path("office") == Path("office.yaml")
    given: list[object] = []
    monkeypatch.setattr(status, "save_map_main", lambda connect, robot, out, image_format, runs_dir: given.append(out) or 0)
    assert CliRunner().invoke(app, ["save-map", "-f", "maps/"]).exit_code == 0
    assert map_yaml_path(given[0]) == Path("maps") / "map.yaml"


@pytest.mark.parametrize("width_px", [6000, 20000])
def test_a_map_image_too_large_to_explore_is_refused_from_its_header(tmp_path: Path, width_px: int):
    """A 6000 x 6000 map would take minutes and gigabytes before its first step, and Pillow's own
    decompression-bomb check raised a traceback for a 20000 x 20000 one: both are a clear error, read
    from the header alone (the files here hold almost no pixels)."""
    (tmp_path / "huge.pgm").write_bytes(f"P5\n{width_px} {width_px}\n255\n".encode() + bytes(100))
    meta = {"image": "huge.pgm", "resolution": 0.05, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}
    (tmp_path / "huge.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(MapFileError, match="huge.pgm: the image is too large.*coarser resolution"):
        load_map(tmp_path / "huge.yaml")


@pytest.mark.parametrize("suffix", ["pgm", "png"])
def test_a_16_bit_grey_map_reads_on_its_full_range(tmp_path: Path, suffix: str):
    """A 16-bit PGM (maxval 65535) or PNG: Pillow's 8-bit conversion clipped every value over 255 to white,
    so unknown grey and mid greys read as free. map_server reads the shade on the image's own range."""
    grey16 = np.array([[0, 65535, 52685, 32768]], dtype=np.uint16)  # black, white, map_saver's unknown 205, mid grey
    if suffix == "pgm":
        (tmp_path / "m.pgm").write_bytes(b"P5\n4 1\n65535\n" + grey16.astype(">u2").tobytes())
    else:
        Image.fromarray(grey16).save(tmp_path / "m.png")
    meta = {"image": f"m.{suffix}", "resolution": 0.05, "origin": [0.0, 0.0, 0.0], "negate": 0}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({**meta, "occupied_thresh": 0.65, "free_thresh": 0.196}))
    assert load_map(tmp_path / "m.yaml")[0].tolist() == [[100, 0, -1, -1]]
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({**meta, "mode": "raw"}))
    assert load_map(tmp_path / "m.yaml")[0].tolist() == [[0, -1, -1, -1]]  # 255, 205 and 128 are no raw values


def test_a_yaml_without_thresholds_loads_with_the_defaults_and_says_so_once(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """Both ROS map_servers refuse a YAML without occupied_thresh / free_thresh; here it loads, with a warning."""
    Image.fromarray(np.array([[0, 205, 254]], dtype=np.uint8)).save(tmp_path / "m.png")
    meta = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0]}
    (tmp_path / "bare.yaml").write_text(yaml.safe_dump(meta))
    (tmp_path / "full.yaml").write_text(yaml.safe_dump({**meta, "occupied_thresh": 0.65, "free_thresh": 0.196}))
    with caplog.at_level("WARNING", logger="cso.map_files"):
        assert load_map(tmp_path / "full.yaml")[0].tolist() == [[100, -1, 0]]
        assert caplog.records == []
        assert load_map(tmp_path / "bare.yaml")[0].tolist() == [[100, -1, 0]]
        load_map(tmp_path / "bare.yaml")
    assert len(caplog.records) == 1
    message = caplog.records[0].getMessage()
    assert str(tmp_path / "bare.yaml") in message
    assert "occupied_thresh 0.65" in message and "free_thresh 0.196" in message


def test_a_map_whose_free_thresh_reads_the_unknown_grey_as_free_says_so_once(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """ROS 2's map_saver_cli writes ``free_thresh: 0.25`` beside its unknown grey 205 (an occupancy of 0.196), which
    map_server, and so this loader, then reads as free (slam_toolbox#587): a SLAM map's unknown margin became floor,
    and a scene of it ``scenes`` listed with the unknown's area in its traversable area, without a word. The map still
    loads as map_server reads it; a warning names the file, the cells and the threshold that keeps them unknown."""
    Image.fromarray(np.array([[0, 205, 205, 254]], dtype=np.uint8)).save(tmp_path / "m.png")
    Image.fromarray(np.array([[0, 254, 254, 254]], dtype=np.uint8)).save(tmp_path / "known.png")
    meta = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65}
    (tmp_path / "ros2.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.25}))
    (tmp_path / "ros1.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.196}))
    (tmp_path / "known.yaml").write_text(yaml.safe_dump({**meta, "image": "known.png", "free_thresh": 0.25}))
    (tmp_path / "negated.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.25, "negate": 1}))
    with caplog.at_level("WARNING", logger="cso.map_files"):
        assert load_map(tmp_path / "ros1.yaml")[0].tolist() == [[100, -1, -1, 0]]
        assert load_map(tmp_path / "known.yaml")[0].tolist() == [[100, 0, 0, 0]]
        assert load_map(tmp_path / "negated.yaml")[0].tolist() == [[0, 100, 100, 100]]
        assert caplog.records == []
        assert load_map(tmp_path / "ros2.yaml")[0].tolist() == [[100, 0, 0, 0]]  # as map_server reads it
        load_map(tmp_path / "ros2.yaml")
    assert len(caplog.records) == 1
    message = caplog.records[0].getMessage()
    assert message.startswith(f"{tmp_path / 'ros2.yaml'}: free_thresh 0.25 reads the unknown grey 205")
    assert "2 cells (0.02 m2)" in message and "free_thresh: 0.196" in message


@pytest.mark.parametrize(
    ("mode", "expected"),
    [
        # Nav2 averages alpha in with R, G, B: (3 grey + alpha) / 4; an opaque 205 is then an occupancy of 0.147: free.
        ("trinary", [-1, 0, 0, -1, 100, 100, 100]),
        ("scale", [-1, 0, 0, 67, -1, 100, -1]),  # not fully opaque: unknown; 128 is between the thresholds
        ("raw", [-1, -1, -1, -1, 0, 0, 50]),  # alpha ignored: the grey itself, over 100 unknown
    ],
)
def test_alpha_is_read_per_mode_as_nav2_map_server_reads_it(tmp_path: Path, mode: str, expected: list[int]):
    grey = np.array([254, 254, 205, 128, 0, 0, 50], dtype=np.uint8)
    alpha = np.array([0, 255, 255, 255, 0, 255, 0], dtype=np.uint8)
    rgba = np.stack([grey, grey, grey, alpha], axis=-1)[None]
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    meta = {"image": "a.png", "mode": mode, "resolution": 0.1, "origin": [0.0, 0.0, 0.0]}
    meta.update(negate=0, occupied_thresh=0.65, free_thresh=0.196)
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(meta))
    assert load_map(tmp_path / "a.yaml")[0].tolist() == [expected]


def _write_map_yaml(folder: Path, image: str, mode: str = "trinary") -> Path:
    meta = {"image": image, "mode": mode, "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}
    (folder / "m.yaml").write_text(yaml.safe_dump(meta))
    return folder / "m.yaml"


def test_a_colour_pixel_reads_as_the_average_of_its_channels_as_nav2_reads_it(tmp_path: Path):
    # Nav2's map_io: shade = (R + G + B) / 3, not the luma. Pure green (0, 255, 0): luma 150 (occupancy 0.41,
    # unknown), average 85 (occupancy 0.67, occupied). (255, 255, 0): luma 226 (0.11, free), average 170 (0.33, unknown).
    rgb = np.array([[[0, 255, 0], [255, 255, 0], [254, 254, 254]]], dtype=np.uint8)
    Image.fromarray(rgb, "RGB").save(tmp_path / "c.png")
    assert load_map(_write_map_yaml(tmp_path, "c.png"))[0].tolist() == [[100, -1, 0]]
    Image.fromarray(np.concatenate([rgb, np.full((1, 3, 1), 255, np.uint8)], axis=-1), "RGBA").save(tmp_path / "c.png")
    # Opaque: trinary averages alpha 255 in, (R + G + B + 255) / 4: 127.5 (0.5, unknown), 191.25 (0.25, unknown), 254.25 (free).
    assert load_map(_write_map_yaml(tmp_path, "c.png"))[0].tolist() == [[-1, -1, 0]]
    assert load_map(_write_map_yaml(tmp_path, "c.png", "scale"))[0].tolist() == [[100, 30, 0]]  # alpha left out: the average


@pytest.mark.parametrize(("mode", "expected"), [("trinary", [-1, 0, 100]), ("scale", [-1, 0, 100]), ("raw", [-1, -1, 0])])
def test_a_palette_png_with_a_transparent_entry_keeps_its_transparency(tmp_path: Path, mode: str, expected: list[int]):
    # Nav2 (GraphicsMagick) reads a palette PNG's tRNS entry as alpha; Pillow's "L" conversion dropped it.
    im = Image.fromarray(np.array([[0, 1, 2]], dtype=np.uint8), "P")
    im.putpalette([254, 254, 254, 254, 254, 254, 0, 0, 0] + [0] * (256 - 3) * 3)
    im.save(tmp_path / "p.png", transparency=0)  # entry 0: white, fully transparent
    # trinary: (3 * 254 + 0) / 4 = 190.5, occupancy 0.25: unknown; scale: not opaque, unknown; raw: alpha ignored, 254 > 100 unknown.
    assert load_map(_write_map_yaml(tmp_path, "p.png", mode))[0].tolist() == [expected]


def test_save_maps_format_is_taken_in_any_case_as_map_saver_cli_takes_it(tmp_path: Path):
    """``save-map --format PNG`` was refused (exit 2, "expected one of pgm, png"), where Nav2's map_saver_cli
    lower-cases its ``--fmt``: the format is read in any case, and a wrong one still refused."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    runs = str(tmp_path / "runs")
    r = CliRunner().invoke(app, ["save-map", "-f", str(tmp_path / "m"), "--format", "PNG", "--runs-dir", runs])
    assert r.exit_code == 1 and "nothing running" in r.output, r.output  # past the format: no run to ask
    r = CliRunner().invoke(app, ["save-map", "-f", str(tmp_path / "m"), "--format", "JPG", "--runs-dir", runs])
    assert r.exit_code == 2 and "--format 'JPG': expected one of pgm, png" in r.output, r.output


def test_the_unknown_grey_read_free_in_scale_mode_is_not_told_to_take_the_threshold_it_has(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """In scale mode a grey at or just above free_thresh scales to 0, free, as in Nav2, so map_saver's unknown grey 205
    is floor there whatever the threshold. Since the warning was counted after the scaling, a scale-mode map with
    ROS 1's free_thresh 0.196 was told "free_thresh 0.196 reads the unknown grey 205 ... as free ...; set free_thresh:
    0.196 to keep them unknown", the threshold it had, and which keeps nothing unknown there. The warning names
    trinary mode, which keeps them unknown."""
    Image.fromarray(np.array([[0, 205, 205, 254]], dtype=np.uint8)).save(tmp_path / "m.png")
    meta = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "mode": "scale"}
    (tmp_path / "ros1.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.196}))
    (tmp_path / "trinary.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.196, "mode": "trinary"}))
    with caplog.at_level("WARNING", logger="cso.map_files"):
        assert load_map(tmp_path / "trinary.yaml")[0].tolist() == [[100, -1, -1, 0]]
        assert caplog.records == []
        assert load_map(tmp_path / "ros1.yaml")[0].tolist() == [[100, 0, 0, 0]]  # as map_server reads it
    (record,) = caplog.records
    message = record.getMessage()
    assert message.startswith(f"{tmp_path / 'ros1.yaml'}: free_thresh 0.196 reads the unknown grey 205") and "2 cells (0.02 m2)" in message
    assert "set free_thresh: 0.196" not in message and "mode: trinary" in message, message


def test_the_unknown_grey_read_free_with_an_alpha_channel_is_said_too(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """A PNG map with an alpha channel has its alpha averaged in with its colour in trinary mode (as Nav2), so map_saver's
    opaque unknown grey 205 is read as a shade of 217.5, an occupancy of 0.147: free at ROS 2's free_thresh 0.25 and at
    ROS 1's 0.196 alike. The warning that says the unknown became floor compared the averaged shade with 205 and never
    fired for such a map (docs/scenes.md promises it); it is said, with the threshold that would keep those cells unknown."""
    grey = np.array([[0, 205, 205, 254]], dtype=np.uint8)
    Image.fromarray(np.stack([grey, np.full_like(grey, 255)], axis=-1), "LA").save(tmp_path / "m.png")
    meta = {"image": "m.png", "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65}
    (tmp_path / "ros2.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.25}))
    (tmp_path / "kept.yaml").write_text(yaml.safe_dump({**meta, "free_thresh": 0.14}))
    with caplog.at_level("WARNING", logger="cso.map_files"):
        assert load_map(tmp_path / "kept.yaml")[0].tolist() == [[100, -1, -1, 0]]
        assert caplog.records == []
        assert load_map(tmp_path / "ros2.yaml")[0].tolist() == [[100, 0, 0, 0]]  # as map_server reads it
    (record,) = caplog.records
    message = record.getMessage()
    assert message.startswith(f"{tmp_path / 'ros2.yaml'}: free_thresh 0.25 reads the unknown grey 205") and "2 cells (0.02 m2)" in message
    assert "alpha" in message and "at most 0.147" in message


def test_save_map_takes_map_saver_clis_fmt_and_writes_a_round_origin(tmp_path: Path):
    """A Nav2 user types ``save-map -f lab --fmt png`` as for map_saver_cli: ``--fmt`` was "No such option". And the
    YAML said ``origin: [-5.2749999999999995, ...]`` (the arena's corner as the float sum gave it), where map_saver_cli
    writes -5.275: the origin is written rounded to a nanometre, and reads back as the same geometry to the cell."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    runs = str(tmp_path / "runs")
    r = CliRunner().invoke(app, ["save-map", "-f", str(tmp_path / "m"), "--fmt", "png", "--runs-dir", runs])
    assert r.exit_code == 1 and "nothing running" in r.output, r.output  # past the format: no run to ask
    r = CliRunner().invoke(app, ["save-map", "-f", str(tmp_path / "m"), "--fmt", "jpg", "--runs-dir", runs])
    assert r.exit_code == 2 and "expected one of pgm, png" in r.output, r.output
    grid, _ = _grid()
    geometry = GridGeometry(0.05, (4, 5), -5.2749999999999995, -6.725)  # the limo-ros2 arena's corner, as the bridge had it
    yaml_path = save_map(tmp_path / "lab.yaml", grid, geometry)
    assert "origin:\n- -5.275\n- -6.725\n- 0.0\n" in yaml_path.read_text(), yaml_path.read_text()
    back, back_geometry = load_map(yaml_path)
    assert back_geometry.shape == geometry.shape and abs(back_geometry.origin_x_m - geometry.origin_x_m) < 1e-9
    np.testing.assert_array_equal(back, grid)


def test_a_map_yaml_number_written_with_an_exponent_is_read_as_map_server_reads_it(tmp_path: Path):
    """``resolution: 5e-2`` (an exponent without a dot, which PyYAML's YAML 1.1 reads as text, and map_server's yaml-cpp
    as the number) was refused: "resolution must be finite numbers, got '5e-2'", untrue. It is read as the number, as
    ``--set`` and the config files read it; a value that is no number is said as one value, in words that fit it."""
    grid, geometry = _grid()
    good = save_map(tmp_path / "map.yaml", grid, geometry)
    meta = yaml.safe_load(good.read_text())
    text = good.read_text().replace(f"resolution: {meta['resolution']}", "resolution: 5e-2").replace("occupied_thresh: 0.65", "occupied_thresh: 65E-2")
    assert "5e-2" in text and "65E-2" in text, text
    (tmp_path / "exp.yaml").write_text(text)
    read, read_geometry = load_map(tmp_path / "exp.yaml")
    assert read_geometry.resolution_m == 0.05 and np.array_equal(read, load_map(good)[0])
    for value, said in (("abc", "resolution must be a finite number, got 'abc'"), (".nan", "resolution must be a finite number, got nan")):
        (tmp_path / "bad.yaml").write_text(text.replace("resolution: 5e-2", f"resolution: {value}"))
        with pytest.raises(MapFileError, match=re.escape(said)):
            load_map(tmp_path / "bad.yaml")
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({**meta, "origin": [0.0, float("nan"), 0.0]}))
    with pytest.raises(MapFileError, match=re.escape("origin must be three finite numbers [x_m, y_m, yaw_rad], got nan")):
        load_map(tmp_path / "bad.yaml")


def test_load_map_of_a_map_with_a_turned_origin_says_how_to_read_it(tmp_path: Path):
    """``eval`` and ``up`` write the robot's map of a map_server scene whose ``origin`` has a yaw with that yaw, and
    docs/eval.md pointed at ``load_map`` to read such files back: it refused them with "grids here are axis-aligned",
    naming no way to read this project's own output. The refusal names ``load_map_and_meta(path,
    rotated_origin_ok=True)``, which reads it, the grid in its own frame and the yaw in the YAML's ``origin``."""
    from cso_runtime.geometry import Pose2D
    from cso_runtime.map_files import load_map_and_meta

    grid, geometry = _grid()
    path = save_map(tmp_path / "turned.yaml", grid, geometry, map_origin=Pose2D(1.0, 2.0, 0.5))
    with pytest.raises(MapFileError) as refused:
        load_map(path)
    assert "load_map_and_meta(path, rotated_origin_ok=True)" in str(refused.value), refused.value
    read, read_geometry, meta = load_map_and_meta(path, rotated_origin_ok=True)
    assert read.tolist() == grid.tolist() and read_geometry.shape == geometry.shape and meta["origin"][2] == pytest.approx(0.5)


def test_a_map_yaml_number_written_with_a_sign_and_a_leading_dot_is_read_as_map_server_reads_it(tmp_path: Path):
    """``origin: [-.5, +.5, 0]``: YAML 1.2 (and map_server's yaml-cpp) reads ``-.5`` as -0.5, PyYAML's YAML 1.1 as text
    (its float needs a digit before the dot once signed), and the map was refused: "origin must be three finite numbers
    [x_m, y_m, yaw_rad], got '-.5'". Read as the number, as ``5e-2`` is; ``--set`` of a float key the same."""
    from cso_runtime.config import ConfigError, ExplorationConfig, from_dict

    grid, geometry = _grid()
    good = save_map(tmp_path / "map.yaml", grid, geometry)
    meta = yaml.safe_load(good.read_text())
    assert isinstance(yaml.safe_load("[-.5, +.5, -.5e+1]")[0], str)  # PyYAML's text, which the reading turns into numbers
    (tmp_path / "dot.yaml").write_text(yaml.safe_dump({k: v for k, v in meta.items() if k != "origin"}) + "origin: [-.5, +.5, 0]\n")
    _, read_geometry = load_map(tmp_path / "dot.yaml")
    assert (read_geometry.origin_x_m, read_geometry.origin_y_m) == (-0.5, 0.5)
    assert from_dict(ExplorationConfig, {"planner": {"lookahead_m": "+.5"}}).planner.lookahead_m == 0.5
    for text in ("-.", "+.e1", "-.5.5", "- .5"):  # no number in YAML 1.2 either: still refused
        with pytest.raises(ConfigError, match="expected a number"):
            from_dict(ExplorationConfig, {"planner": {"lookahead_m": text}})


def test_a_map_yamls_numbers_are_read_as_yaml_1_2_reads_them_not_as_yaml_1_1(tmp_path: Path):
    """``origin: [010, -0.5, 0]`` was read by PyYAML's YAML 1.1 as x = 8 (an octal), where map_server's yaml-cpp reads
    10; ``resolution: 1_000`` (YAML 1.1: 1000) and an origin of ``1:30`` (YAML 1.1: 90, base 60) were read as
    numbers that map_server refuses. Read as YAML 1.2 does (``config.yaml_load``): 10, and the others refused as texts."""
    grid, geometry = _grid()
    good = save_map(tmp_path / "map.yaml", grid, geometry)
    meta = yaml.safe_load(good.read_text())
    rest = yaml.safe_dump({k: v for k, v in meta.items() if k not in ("origin", "resolution")})
    (tmp_path / "zero.yaml").write_text(rest + "resolution: 0.050\norigin: [010, -0.5, 0]\n")
    back, back_geometry = load_map(tmp_path / "zero.yaml")
    assert (back_geometry.origin_x_m, back_geometry.origin_y_m, back_geometry.resolution_m) == (10.0, -0.5, 0.05)
    np.testing.assert_array_equal(back, grid)
    for lines, said in [
        ("resolution: 1_000\norigin: [0, 0, 0]\n", "resolution must be a finite number, got '1_000'"),
        ("resolution: 0.05\norigin: [1:30, 0, 0]\n", "origin must be three finite numbers [x_m, y_m, yaw_rad], got '1:30'"),
    ]:
        (tmp_path / "bad.yaml").write_text(rest + lines)
        with pytest.raises(MapFileError, match=re.escape(said)):
            load_map(tmp_path / "bad.yaml")


def test_a_map_yaml_number_too_large_for_a_float_or_a_key_given_twice_is_refused(tmp_path: Path):
    """``resolution: 1000...0`` (400 digits, an integer YAML reads whole; ``0x`` and 300 digits alike) ended the read
    with Python's OverflowError, a traceback, where any other number no float holds (``1e400``, ``.inf``) is said as
    not finite. A key given twice (``resolution`` twice) was read as its last value, where map_server's yaml-cpp
    takes the first: the two readers drew another map from one file. Both are refused as a MapFileError."""
    grid, geometry = _grid()
    meta = yaml.safe_load(save_map(tmp_path / "map.yaml", grid, geometry).read_text())
    rest = yaml.safe_dump({k: v for k, v in meta.items() if k not in ("origin", "resolution")})
    huge = "1" + "0" * 400
    for lines, said in [
        (f"resolution: {huge}\norigin: [0, 0, 0]\n", "resolution must be a finite number"),
        (f"resolution: 0.05\norigin: [0x{'F' * 300}, 0, 0]\n", "origin must be three finite numbers"),
        ("resolution: 1e400\norigin: [0, 0, 0]\n", "resolution must be a finite number, got inf"),
        ("resolution: 0.05\norigin: [0, 0, 0]\nresolution: 0.1\n", "found key 'resolution' twice (first at line"),
    ]:
        (tmp_path / "bad.yaml").write_text(rest + lines)
        with pytest.raises(MapFileError, match=re.escape(said)):
            load_map(tmp_path / "bad.yaml")


def test_a_map_yaml_whose_image_is_null_or_empty_says_so(tmp_path: Path):
    """``image:`` left empty (or ``~``, YAML's null) was read as the file ``None``: "None: cannot read the map image
    ([Errno 2] No such file or directory: 'None')", a file the user never named; ``image: ""`` as the map's own
    folder ("Is a directory"). map_server refuses both (no file name); so does load_map, naming the key."""
    grid, geometry = _grid()
    meta = yaml.safe_load(save_map(tmp_path / "map.yaml", grid, geometry).read_text())
    rest = yaml.safe_dump({k: v for k, v in meta.items() if k != "image"})
    for value in ("", "~", "null", '""', "[a.pgm]", "true"):
        (tmp_path / "bad.yaml").write_text(rest + f"image: {value}\n")
        with pytest.raises(MapFileError, match=re.escape(f"{tmp_path / 'bad.yaml'}: image must name the map's image file (a PGM or PNG), got ")):
            load_map(tmp_path / "bad.yaml")
