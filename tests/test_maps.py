"""Map loading (nav2 semantics), saving, the generator, and map errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from smorphi_rl.errors import MapError
from smorphi_rl.maps import Cell, Map, check_fits, generate_map, load_map, save_map

MAPS = Path(__file__).resolve().parent.parent / "maps"
THRESHOLDS = {"negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.25}
DESIGNER = Path(__file__).resolve().parents[1] / "smorphi_rl" / "policies" / "designer"


def write_map(tmp_path: Path, pixels: np.ndarray, name: str = "m", suffix: str = "pgm", **meta) -> Path:
    mode = "LA" if pixels.ndim == 3 and pixels.shape[2] == 2 else None
    Image.fromarray(pixels.astype(np.uint8), mode=mode).save(tmp_path / f"{name}.{suffix}")
    doc = {"image": f"{name}.{suffix}", "resolution": 0.05, "origin": [1.0, -2.0, 0.0]} | THRESHOLDS | meta
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_first_image_row_is_highest_y(tmp_path):
    pixels = np.full((3, 4), 254)
    pixels[0, 0] = 0  # top-left pixel of the image
    m = load_map(write_map(tmp_path, pixels))
    assert m.cells.shape == (3, 4)
    assert m.cells[2, 0] == Cell.OCCUPIED and m.counts[Cell.OCCUPIED] == 1
    assert m.resolution_m == 0.05 and m.origin == (1.0, -2.0, 0.0)
    assert m.cell_of(1.0 + 0.01, -2.0 + 2 * 0.05 + 0.01) == (2, 0)


def test_trinary_thresholds_are_strict_like_nav2(tmp_path):
    # p = (255 - v) / 255: v=89 -> p=0.65098 (> 0.65 occupied); v=90 -> 0.647 (unknown);
    # v=192 -> p=0.24706 (< 0.25 free); v=191 -> 0.25098 (unknown)
    pixels = np.array([[89, 90, 191, 192, 0, 255]])
    m = load_map(write_map(tmp_path, pixels, occupied_thresh=0.65, free_thresh=0.25))
    assert m.cells[0].tolist() == [Cell.OCCUPIED, Cell.UNKNOWN, Cell.UNKNOWN, Cell.FREE, Cell.OCCUPIED, Cell.FREE]
    # at a threshold, nav2's own arithmetic decides: p = 1 - 204/255 = 0.19999999999999996 < 0.2 is free (ROS 1's
    # (255 - 204)/255 = 0.2 would not be); p = 1 - 102/255 = 0.5999999999999999778 is not above 0.6: unknown
    m = load_map(write_map(tmp_path, np.array([[204, 102, 0, 255]]), name="edge", free_thresh=0.2, occupied_thresh=0.6))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.UNKNOWN, Cell.OCCUPIED, Cell.FREE]


def test_map_saver_s_unknown_grey_read_as_free_is_counted_and_said(tmp_path, capsys):
    """nav2's depot map (free_thresh 0.25) reads its 8,894 cells of grey 205 as free floor, as nav2 does, and nothing
    said so: the planner covered and scored floor no robot had seen."""
    from smorphi_rl.cli import main

    pixels = np.full((20, 20), 254)
    pixels[:3] = 205  # map_saver's unknown
    pixels[5, :] = 0
    m = load_map(write_map(tmp_path, pixels, free_thresh=0.25))
    assert m.counts[Cell.FREE] == 380 and m.unknown_read_free == 60
    assert m.warnings() == [m.unknown_warning()] and "60 cells of grey 205" in m.warnings()[0]
    seen = load_map(write_map(tmp_path, pixels, name="saved", free_thresh=0.196))  # map_saver's own: unknown
    assert seen.counts[Cell.UNKNOWN] == 60 and seen.unknown_read_free == 0 and seen.warnings() == []
    assert main(["maps", "show", str(tmp_path / "m.yaml"), "--png", str(tmp_path / "m.png")]) == 0
    assert "free_thresh: 0.196 in its YAML reads them as unknown" in capsys.readouterr().err


@pytest.mark.parametrize(("alpha", "meta", "fix"), [
    (True, {"free_thresh": 0.196}, "; the image saved without its alpha channel reads them as unknown"),
    (False, {"mode": "scale", "free_thresh": 0.196}, "; mode: trinary in its YAML reads them as unknown"),
    (True, {}, "; free_thresh: 0.196 in its YAML and the image saved without its alpha channel read them as unknown"),
])  # fmt: skip
def test_unknown_grey_read_as_free_through_an_opaque_alpha_or_scale_mode_is_said(tmp_path, alpha, meta, fix):
    """A map given an opaque alpha channel by an image editor averages 205 up to 217.5 (free under 0.196), and mode
    scale reads 205 as 0 % occupied: as nav2 does, unknown space became free floor, and nothing said so."""
    pixels = np.full((10, 10), 254)
    pixels[:2] = 205
    image = np.stack([pixels, np.full_like(pixels, 255)], axis=-1) if alpha else pixels
    m = load_map(write_map(tmp_path, image, suffix="png", **meta))
    assert m.counts[Cell.FREE] == 100 and m.unknown_read_free == 20
    assert m.warnings() == [m.unknown_warning()] and m.warnings()[0].endswith(fix)


@pytest.mark.parametrize("command", [
    ["maps", "crop", "{map}", "--out", "{tmp}/out/c.yaml"],
    ["evaluate-policy", "--checkpoint", str(DESIGNER), "--map", "{map}"],
    ["evaluate", "--map", "{map}", "--angles", "90", "90", "90"],
])  # fmt: skip
def test_commands_that_read_a_map_say_its_unknown_grey_reads_as_free(tmp_path, capsys, command):
    """`maps crop` (whose map then reads the grey as free in silence) and `evaluate-policy` said nothing."""
    from smorphi_rl.cli import main

    pixels = np.full((80, 80), 254)
    pixels[:10] = 205
    pixels[[10, -1], :] = pixels[:, [0, -1]] = 0
    path = write_map(tmp_path, pixels, free_thresh=0.25)
    assert main([a.format(map=path, tmp=tmp_path) for a in command]) == 0
    assert "cells of grey 205, which map_saver writes for unknown space" in capsys.readouterr().err


def test_trinary_mode_averages_alpha_in_as_nav2_does(tmp_path):
    """A transparent white pixel: (3 x 255 + 0) / 4 = 191.25, p = 0.25, unknown under 0.65 / 0.196 (it read free)."""
    pixels = np.stack([np.array([[255, 255, 0]]), np.array([[0, 255, 255]])], axis=-1)
    m = load_map(write_map(tmp_path, pixels, suffix="png"))
    assert m.cells[0].tolist() == [Cell.UNKNOWN, Cell.FREE, Cell.OCCUPIED]


@pytest.mark.parametrize("colour", [False, True])
def test_a_pngs_transparent_colour_is_alpha_as_nav2_reads_it(tmp_path, colour):
    """A grey or RGB PNG may mark one colour transparent (tRNS; PNG optimisers write a grey+alpha map so): nav2
    averages its alpha in (trinary) or calls it unknown (scale); it read as opaque, unknown space as free floor."""
    grey = np.array([[254, 0, 255, 205]], dtype=np.uint8)
    image = Image.fromarray(np.stack([grey] * 3, axis=-1) if colour else grey)
    image.save(tmp_path / "key.png", transparency=(255, 255, 255) if colour else 255)
    for mode, cells in [("trinary", [Cell.FREE, Cell.OCCUPIED, Cell.UNKNOWN, Cell.FREE]),
                        ("scale", [Cell.FREE, Cell.OCCUPIED, Cell.UNKNOWN, Cell.FREE])]:  # fmt: skip
        doc = {"image": "key.png", "resolution": 0.05, "mode": mode} | THRESHOLDS
        (tmp_path / "key.yaml").write_text(yaml.safe_dump(doc))
        assert load_map(tmp_path / "key.yaml").cells[0].tolist() == cells, mode


def test_a_16_bit_grey_pngs_transparent_grey_is_alpha_too(tmp_path):
    """Pillow reads a 16-bit grey PNG with a transparent grey as mode I;16 and keeps the key aside: it read opaque."""
    grey = np.array([[65_278, 0, 65_535, 52_685]], dtype=np.uint16)  # 254, 0, 255, 205 on 8 bits
    Image.fromarray(grey).save(tmp_path / "key16.png", transparency=65_535)
    doc = {"image": "key16.png", "resolution": 0.05, "mode": "scale"} | THRESHOLDS
    (tmp_path / "key16.yaml").write_text(yaml.safe_dump(doc))
    assert load_map(tmp_path / "key16.yaml").cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.UNKNOWN, Cell.FREE]


def test_scale_mode_frees_a_grey_whose_occupancy_rounds_to_0(tmp_path):
    """nav2 writes rint(100 (p - free) / (occupied - free)) between the thresholds: just above free_thresh that is 0,
    which an OccupancyGrid reads as free. Grey 205 under 0.65 / 0.196: p = 0.19608, 0.0 after rounding."""
    gray = np.array([[205, 128, 255]])
    alpha = np.full((1, 3), 255)
    m = load_map(write_map(tmp_path, np.stack([gray, alpha], axis=-1), suffix="png", mode="scale", free_thresh=0.196))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.FREE]


def test_raw_mode_reads_a_16_bit_image_on_nav2_s_0_255_scale(tmp_path):
    """nav2 takes round(255 shade): 16-bit 100 is 0.39 -> 0, free; 25,700 is 100, occupied; 26,000 is 101, unknown."""
    Image.fromarray(np.array([[100, 25_700, 26_000, 65_535]], dtype=np.uint16)).save(tmp_path / "raw16.png")
    doc = {"image": "raw16.png", "resolution": 0.05, "mode": "raw"} | THRESHOLDS
    (tmp_path / "raw16.yaml").write_text(yaml.safe_dump(doc))
    m = load_map(tmp_path / "raw16.yaml")
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.UNKNOWN, Cell.UNKNOWN]


@pytest.mark.parametrize(("free", "occupied"), [(0.0, 0.65), (0.196, 1.0)])
def test_a_threshold_no_grey_can_pass_is_refused(tmp_path, free, occupied):
    """Compared strictly, p < 0 frees nothing and p > 1 occupies nothing (every wall would read unknown)."""
    path = write_map(tmp_path, np.array([[254, 0]]), free_thresh=free, occupied_thresh=occupied)
    with pytest.raises(MapError, match=r"need 0 < free_thresh < occupied_thresh < 1"):
        load_map(path)


def test_negate_flips_the_probability(tmp_path):
    m = load_map(write_map(tmp_path, np.array([[0, 255]]), negate=1))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED]


def test_negate_and_mode_are_read_as_map_server_reads_them(tmp_path):
    """map_server reads negate as an integer (any but 0 negates) and nav2 lower-cases the mode: both were refused."""
    m = load_map(write_map(tmp_path, np.array([[0, 255]]), negate=2, mode="Trinary"))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED]
    assert load_map(write_map(tmp_path, np.array([[0, 255]]), mode="RAW")).cells[0].tolist() == [
        Cell.FREE, Cell.UNKNOWN]  # fmt: skip
    with pytest.raises(MapError, match=r"'negate' must be an integer \(0, or any other to negate\), got 'yes please'"):
        load_map(write_map(tmp_path, np.array([[0, 255]]), negate="yes please"))


def test_map_saver_unknown_205_stays_unknown(tmp_path):
    m = load_map(write_map(tmp_path, np.array([[254, 0, 205]]), free_thresh=0.196))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.UNKNOWN]


def test_scale_mode_uses_alpha_and_keeps_partial_cells_not_free(tmp_path):
    gray = np.array([[255, 0, 128, 255]])
    alpha = np.array([[255, 255, 255, 0]])
    m = load_map(write_map(tmp_path, np.stack([gray, alpha], axis=-1), suffix="png", mode="scale"))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.OCCUPIED, Cell.UNKNOWN]


def test_raw_mode_reads_occupancy_values(tmp_path):
    m = load_map(write_map(tmp_path, np.array([[0, 100, 50, 255]]), mode="raw"))
    assert m.cells[0].tolist() == [Cell.FREE, Cell.OCCUPIED, Cell.OCCUPIED, Cell.UNKNOWN]


@pytest.mark.parametrize("fmt", ["pgm", "png"])
def test_save_load_round_trip(tmp_path, fmt):
    rng = np.random.default_rng(3)
    cells = rng.integers(0, 3, size=(17, 23)).astype(np.uint8)
    cells[0, 0] = Cell.FREE
    original = Map(cells, 0.05, origin=(0.5, -1.5, 0.0), name="rt")
    path = save_map(original, tmp_path / "rt.yaml", image_format=fmt)
    loaded = load_map(path)
    assert np.array_equal(loaded.cells, original.cells)
    assert loaded.resolution_m == original.resolution_m and loaded.origin == original.origin


@pytest.mark.parametrize(
    ("name", "density"), [("map-1", 0.188), ("map-2", 0.222), ("val-1", 0.15), ("val-2", 0.20), ("val-3", 0.26)]
)
def test_shipped_maps(name, density):
    m = load_map(MAPS / f"{name}.yaml")
    assert (m.width, m.height, m.resolution_m) == (50, 50, 0.1)
    assert m.fraction(Cell.OCCUPIED) == pytest.approx(density, abs=0.002)
    assert m.counts[Cell.UNKNOWN] == 0


def test_generator_is_seeded_dense_as_asked_and_connected():
    a = generate_map(np.random.default_rng(7), obstacle_density=0.25)
    b = generate_map(np.random.default_rng(7), obstacle_density=0.25)
    c = generate_map(np.random.default_rng(8), obstacle_density=0.25)
    assert np.array_equal(a.cells, b.cells) and not np.array_equal(a.cells, c.cells)
    assert a.fraction(Cell.OCCUPIED) == pytest.approx(0.25, abs=0.005)
    from smorphi_rl.maps import _free_is_connected

    assert _free_is_connected(a.cells == Cell.OCCUPIED)


def test_a_generator_needing_more_than_twenty_thousand_rectangles_still_reaches_its_density():
    """1-cell obstacles on a 40 m square: 32,000 of them; a fixed cap of 20,000 tries once ended it at 12.5 %."""
    m = generate_map(np.random.default_rng(1), 40, 40, 0.1, 0.2, min_obstacle_m=0.1, max_obstacle_m=0.1)
    from smorphi_rl.maps import _free_is_connected

    assert m.fraction(Cell.OCCUPIED) == 0.2 and _free_is_connected(m.cells == Cell.OCCUPIED)


@pytest.mark.parametrize("seed", range(12))
def test_the_local_connectivity_tests_decide_as_the_whole_map_flood_fill(seed):
    """`_keeps_free_connected` answers from the ring and a window where it can; each answer, on dense random maps
    whose rectangles touch and enclose, is the flood fill's of the whole map."""
    from smorphi_rl.maps import _free_is_connected, _keeps_free_connected

    rng = np.random.default_rng(seed)
    occupied = generate_map(rng, 12, 3, 0.1, 0.55, min_obstacle_m=0.1, max_obstacle_m=0.5).cells == Cell.OCCUPIED
    for _ in range(300):
        rh, rw = (int(v) for v in rng.integers(1, 6, size=2))
        r, c = int(rng.integers(0, occupied.shape[0] - rh + 1)), int(rng.integers(0, occupied.shape[1] - rw + 1))
        trial = occupied.copy()
        trial[r : r + rh, c : c + rw] = True
        assert _keeps_free_connected(occupied, r, c, rh, rw) == _free_is_connected(trial)


def test_map_from_text_orientation(room12):
    assert room12.cells.shape == (12, 12)
    assert room12.cells[0, 2] == Cell.FREE and room12.cells[2, 2] == Cell.OCCUPIED  # '#' at text rows 9-10
    assert room12.counts[Cell.OCCUPIED] == 4 + 6 + 2


@pytest.mark.parametrize(
    ("yaml_text", "message"),
    [
        ("image: [unclosed", "malformed YAML"),
        ("- just\n- a list\n", "not a map_server YAML"),
        ("resolution: 0.1\n", "missing key 'image'"),
        ("image: m.pgm\n", "missing key 'resolution'"),
        ("image: m.pgm\nresolution: 0\n", "'resolution' must be 0.001-10 m a cell"),
        ("image: m.pgm\nresolution: -0.1\n", "'resolution' must be 0.001-10 m a cell"),
        ("image: m.pgm\nresolution: fine\n", "'resolution' must be a number"),
        ("image: m.pgm\nresolution: 0.1\nmode: fancy\n", "'mode' must be trinary"),
        ("image: m.pgm\nresolution: 0.1\norigin: [0, 0]\n", "'origin' must be"),
        ("image: m.pgm\nresolution: 0.1\n", r"missing key 'negate' \(map_saver writes negate: 0, occupied_thresh"),
        ("image: m.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\n", "missing key 'free_thresh'"),
        (
            "image: m.pgm\nresolution: 0.1\nfree_thresh: 0.9\nnegate: 0\noccupied_thresh: 0.65\n",
            "free_thresh < occupied_thresh",
        ),
        (
            "image: missing.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            "map image not found",
        ),
        (
            "image: bad.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            "not a readable PGM/PNG image",
        ),
        (
            "image: black.pgm\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            "has no free cell",
        ),
        (
            "image: m.jpg\nresolution: 0.1\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            r"not a readable PGM/PNG image \(map images are read as PGM or PNG only: convert it to one\)",
        ),
    ],
)
def test_bad_maps_raise_one_clear_error(tmp_path, yaml_text, message):
    Image.fromarray(np.full((4, 4), 254, np.uint8)).save(tmp_path / "m.pgm")
    Image.fromarray(np.full((4, 4), 254, np.uint8)).save(tmp_path / "m.jpg")  # a JPEG, as map_server reads
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "black.pgm")
    (tmp_path / "bad.pgm").write_bytes(b"P5 this is not an image")
    path = tmp_path / "x.yaml"
    path.write_text(yaml_text)
    with pytest.raises(MapError, match=message):
        load_map(path)


@pytest.mark.parametrize("key", ["origin", "mode", "negate", "image"])
def test_a_huge_bad_value_is_named_in_a_short_line(tmp_path, key):
    """A crafted YAML's value can be a megabyte long: the message shows its start."""
    Image.fromarray(np.full((4, 4), 254, np.uint8)).save(tmp_path / "m.pgm")
    doc = {"image": "m.pgm", "resolution": 0.1} | THRESHOLDS | {key: list(range(5_000))}
    (tmp_path / "x.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(MapError, match=f"'{key}'") as refused:
        load_map(tmp_path / "x.yaml")
    assert len(str(refused.value)) < len(str(tmp_path)) + 200


def test_an_origin_in_exponent_notation_is_a_number(tmp_path):
    """YAML 1.1 reads 1e3 (no dot) as a string, as `resolution` already allowed for."""
    Image.fromarray(np.full((4, 4), 254, np.uint8)).save(tmp_path / "m.pgm")
    (tmp_path / "x.yaml").write_text(
        "image: m.pgm\nresolution: 1e-1\norigin: [1e3, -2e1, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    assert load_map(tmp_path / "x.yaml").origin == (1000.0, -20.0, 0.0)


def test_missing_yaml(tmp_path):
    with pytest.raises(MapError, match="map file not found"):
        load_map(tmp_path / "nope.yaml")


def test_map_rejects_bad_resolution_and_values():
    with pytest.raises(MapError, match="resolution must be > 0"):
        Map(np.zeros((2, 2), np.uint8), 0.0)
    with pytest.raises(MapError, match="cell values"):
        Map(np.full((2, 2), 7, np.uint8), 0.1)


def test_two_generates_into_one_folder_at_once_write_it_once(tmp_path):
    """Of two `maps generate --kind` racing for the same floors, exactly one writes them; the other says so."""
    import subprocess
    import sys

    for round_ in range(3):
        out = tmp_path / f"r{round_}"
        argv = [sys.executable, "-m", "smorphi_rl.cli", "maps", "generate", "--kind", "rooms", "--count", "4",
                "--seed", "5", "--out", str(out)]  # fmt: skip
        procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
        results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]  # type: ignore[union-attr]
        assert sorted(code for code, _ in results) == [0, 1], results
        loser = next(err for code, err in results if code == 1)
        assert "exists" in loser and "pass --force" in loser and loser.count("\n") == 1
        assert len(list(out.glob("*.yaml"))) == 4 and all(p.stat().st_size > 0 for p in out.iterdir())


@pytest.mark.parametrize(
    ("rows", "cols", "fits"),
    [(3, 3, True), (2, 7, True), (7, 2, True), (2, 6, False), (6, 2, False), (2, 5, False)],
)
def test_a_floor_must_hold_the_robot_as_an_o_or_an_i(rows, cols, fits):
    cells = np.full((12, 12), Cell.OCCUPIED, dtype=np.uint8)
    cells[2 : 2 + rows, 3 : 3 + cols] = Cell.FREE
    grid_map = Map(cells, 0.1, name="room")
    assert check_fits(grid_map, 0.17) == 0.17  # the paper planner: 9 free cells or more, the O's
    if fits:
        assert check_fits(grid_map, 0.17, whole_footprint=True) == 0.17
    else:
        with pytest.raises(MapError, match="the robot fits nowhere on its free cells"):
            check_fits(grid_map, 0.17, whole_footprint=True)


def test_a_floor_must_hold_as_many_free_cells_as_the_robots_smallest_footprint():
    cells = np.full((12, 12), Cell.OCCUPIED, dtype=np.uint8)
    cells[0, :8] = Cell.FREE  # 8 cells against the O's 3 x 3
    with pytest.raises(MapError, match=r"its 8 free cells are fewer than the robot's smallest footprint \(the O"):
        check_fits(Map(cells.copy(), 0.1, name="room"), 0.17)
    cells[5, 5] = Cell.FREE
    assert check_fits(Map(cells, 0.1, name="room"), 0.17) == 0.17


def test_an_image_name_too_long_for_the_os_names_the_yaml_and_its_key(tmp_path):
    """The OS's own words ("File name too long: aaaa...", 5,000 characters) named neither the file nor the key."""
    (tmp_path / "long.yaml").write_text(yaml.safe_dump({"image": "a" * 5000 + ".pgm", "resolution": 0.1} | THRESHOLDS))
    with pytest.raises(MapError, match=r"long\.yaml: its 'image' 'aaa.* cannot be read \(File name too long\)") as e:
        load_map(tmp_path / "long.yaml")
    assert len(str(e.value)) < len(str(tmp_path)) + 120


def test_a_map_image_is_decoded_only_as_png_or_pgm_whatever_its_name(tmp_path, monkeypatch):
    """An EPS named map.png reached Pillow's EPS plugin, which runs Ghostscript where it is installed."""
    from PIL import EpsImagePlugin

    opened: list[str] = []
    monkeypatch.setattr(EpsImagePlugin.EpsImageFile, "_open", lambda self: opened.append("eps"))
    (tmp_path / "map.png").write_text("%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 50 50\nshowpage\n")
    (tmp_path / "map.yaml").write_text("image: map.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
                                       "occupied_thresh: 0.65\nfree_thresh: 0.196\n")  # fmt: skip
    with pytest.raises(MapError, match=r"map\.png: not a readable PGM/PNG image"):
        load_map(tmp_path / "map.yaml")
    assert opened == []


def test_a_colour_image_reads_as_the_mean_of_its_channels(tmp_path):
    """map_server averages the channels; read a channel at a time, the result is the grey image's to the cell."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    rgb[::4, ::4] = 254  # some free floor
    grey = (rgb.astype(np.uint16).sum(axis=2) // 3).astype(np.uint8)
    keep = rgb.astype(np.uint16).sum(axis=2) % 3 == 0  # only pixels whose mean is a whole grey level
    rgb[~keep], grey[~keep] = 0, 0
    header = "resolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    for name, array in (("rgb", rgb), ("grey", grey)):
        Image.fromarray(array).save(tmp_path / f"{name}.png")
        (tmp_path / f"{name}.yaml").write_text(f"image: {name}.png\n{header}")
    assert np.array_equal(load_map(tmp_path / "rgb.yaml").cells, load_map(tmp_path / "grey.yaml").cells)


def test_a_floor_set_refused_for_a_file_there_names_the_file_that_is(tmp_path, capsys):
    """Only the image of a floor left in the folder: the line named its YAML, which did not exist."""
    from smorphi_rl.cli import main

    (tmp_path / "rooms-0001000.png").write_bytes(b"")
    assert (
        main(["maps", "generate", "--kind", "rooms", "--seed", "1000", "--format", "png", "--out", str(tmp_path)]) == 1
    )
    err = capsys.readouterr().err
    assert f"{tmp_path / 'rooms-0001000.png'} exists (1 of the 1 floors have a file there); pass --force" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rooms-0001000.png"]


@pytest.mark.parametrize("resolution", ["0", "-0", "1e-170", "1e200", "0.0005", "10.5"])
def test_a_map_no_map_file_may_hold_is_refused_before_it_is_written(tmp_path, capsys, resolution):
    """`--resolution 0` divided by zero, 1e200 overflowed (tracebacks), and 0.0005 or 10.5 wrote a map that every
    command then refused to read."""
    from smorphi_rl.cli import main

    out = tmp_path / "g" / "a.yaml"
    assert main(["maps", "generate", "--out", str(out), "--resolution", resolution, "--width-m", "1",
                 "--height-m", "1"]) == 1  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--resolution must be 0.001-10 m a cell" in err, err
    assert not (tmp_path / "g").exists()
    big = save_map(Map(np.zeros((100, 100), np.uint8), 1.0, name="big"), tmp_path / "big.yaml")
    argv = ["maps", "resample", str(big), "--resolution", "20", "--out", str(tmp_path / "b20.yaml")]
    assert main(argv) == 1 and "--resolution must be 0.001-10 m a cell, got 20" in capsys.readouterr().err
    assert not (tmp_path / "b20.yaml").exists()


def test_a_folder_where_a_floor_file_goes_is_refused_before_any_floor_is_written(tmp_path, capsys):
    """With --force, a folder in place of the second floor's image left the first floor written and said only
    "Is a directory"."""
    from smorphi_rl.cli import main

    (tmp_path / "rooms-0000001.pgm").mkdir()
    assert main(["maps", "generate", "--kind", "rooms", "--count", "3", "--out", str(tmp_path), "--force"]) == 1
    err = capsys.readouterr().err
    assert f"cannot write {tmp_path / 'rooms-0000001.pgm'}: a folder is there; nothing was written" in err
    assert [p.name for p in tmp_path.iterdir()] == ["rooms-0000001.pgm"]
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "a.pgm").mkdir()
    assert main(["maps", "generate", "--out", str(tmp_path / "one" / "a.yaml"), "--force"]) == 1
    assert "a folder is there; nothing was written" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "one").iterdir()] == ["a.pgm"]


def test_a_large_map_shows_its_progress_and_a_density_of_zero_is_done(tmp_path, capsys):
    """Past a million cells `maps generate` draws a progress bar; with nothing to place it once divided by zero."""
    from smorphi_rl.cli import main

    assert main(["maps", "generate", "--out", str(tmp_path / "z.yaml"), "--width-m", "101", "--height-m", "100",
                 "--density", "0"]) == 0  # fmt: skip
    out, err = capsys.readouterr()
    assert "occupied 0.00 %" in out and "obstacle cells placed" in err and "warning" not in err


def test_a_small_room_in_a_large_unknown_frame_is_warned_of():
    """A 5 x 5 m room in a 4000 x 4000-cell frame: `design --exact` ran 13 minutes (25 s once cropped), unwarned."""
    from smorphi_rl.maps import SPARSE_FRAME_CELLS, Cell, Map

    side = int(SPARSE_FRAME_CELLS**0.5) + 1
    cells = np.full((side, side), Cell.UNKNOWN, dtype=np.uint8)
    cells[10:60, 20:120] = Cell.FREE
    warning = Map(cells, 0.05, (0.0, 0.0, 0.0), "frame").frame_warning()
    assert warning is not None and "known area (100 x 50 cells) is 2.0 % of its 501 x 501 frame" in warning
    assert "maps crop" in warning
    small = cells[:400, :400].copy()  # a frame under the size warned of
    assert Map(small, 0.05, (0.0, 0.0, 0.0), "small").frame_warning() is None
    known = np.full((side, side), Cell.FREE, dtype=np.uint8)
    assert Map(known, 0.05, (0.0, 0.0, 0.0), "known").frame_warning() is None


@pytest.mark.parametrize("resolution", [0.05, 0.1, 0.15, 0.3])
def test_a_point_on_a_cell_edge_is_in_the_cell_that_edge_starts(resolution):
    """1.2 / 0.1 is 11.999...: a free point on an edge was refused as on the occupied cell below it, and one point
    named two cells on two frames of one floor."""
    grid_map = Map(np.zeros((200, 200), np.uint8), resolution, origin=(-3.0, -1.7, 0.0))
    for k in range(200):
        edge = k * resolution
        assert grid_map.cell_of(-3.0 + edge, -1.7 + edge) == (k, k)
    with pytest.raises(MapError, match="outside the map"):
        grid_map.cell_of(-3.0 + 200 * resolution, 0.0)  # the far edge starts no cell of this map


def test_a_built_wheel_ships_every_map_and_its_default_map_loads_anywhere(tmp_path):
    """A wheel held no maps/: an installed smorphi-rl named its own default map missing. The clone's maps/ is now
    shipped as smorphi_rl/shipped_maps; a README path away from the clone names the shipped file."""
    import shutil
    import subprocess
    import sys

    root, src = MAPS.parent, tmp_path / "src"  # built from a copy: the build writes beside its sources
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for name in ("smorphi_rl", "maps"):
        shutil.copytree(root / name, src / name, ignore=skip)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(root / name, src / name)
    pip = [sys.executable, "-m", "pip", "-q", "--disable-pip-version-check"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "dist"), str(src)],
                   check=True, capture_output=True, timeout=300)  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    site = tmp_path / "site"
    subprocess.run([*pip, "install", "--no-deps", "--no-index", "--target", str(site), str(wheel)], check=True,
                   capture_output=True, timeout=300)  # fmt: skip
    shipped = sorted(p.relative_to(MAPS) for p in MAPS.rglob("*") if p.is_file())
    assert len(shipped) > 100 and [p for p in shipped if not (site / "smorphi_rl" / "shipped_maps" / p).is_file()] == []
    package = [p.relative_to(root) for p in (root / "smorphi_rl").rglob("*") if p.suffix in (".py", ".json", ".npz")]
    assert [p for p in package if not (site / p).is_file() and "__pycache__" not in p.parts] == []  # pyproject's list
    probe = ("from smorphi_rl.maps import SHIPPED_DEFAULT_MAP, SHIPPED_MAPS, load_map\n"
             "print(SHIPPED_DEFAULT_MAP, load_map(SHIPPED_DEFAULT_MAP).name)\n"
             "assert all(load_map(p) for p in SHIPPED_MAPS.rglob('*.yaml'))\n"
             "try:\n    load_map('maps/val-2.yaml')\nexcept Exception as exc:\n    print(exc)\n")  # fmt: skip
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = subprocess.run([sys.executable, "-c", probe], cwd=elsewhere, capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": str(site)}, timeout=120).stdout.splitlines()  # fmt: skip
    there = site / "smorphi_rl" / "shipped_maps"
    assert out[0] == f"{there / 'map-1.yaml'} map-1"
    assert out[1] == f"map file not found: maps/val-2.yaml (the shipped one is {there / 'val-2.yaml'})"
