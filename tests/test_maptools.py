"""Map preparation: cropping keeps every cell where it was, coarsening is conservative, small islands go."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import random_map, realmap

from smorphi_rl.cli import main
from smorphi_rl.errors import MapError
from smorphi_rl.maps import Cell, Map, load_map
from smorphi_rl.maptools import coarsen, crop_to_known, drop_islands

ROOT = Path(__file__).resolve().parents[1]
ISLANDS = """
????????????
?...#####.??
?...#...#.??
?...#####.??
???????????.
"""


def test_crop_keeps_every_known_cell_at_its_world_position():
    grid_map = Map.from_text(ISLANDS, 0.5, name="islands")
    cropped = crop_to_known(grid_map)
    assert cropped.cells.shape == (4, 11) and cropped.counts[Cell.FREE] == grid_map.counts[Cell.FREE]
    for row, col in np.argwhere(grid_map.cells != Cell.UNKNOWN):
        x = grid_map.origin[0] + (col + 0.5) * 0.5
        y = grid_map.origin[1] + (row + 0.5) * 0.5
        assert cropped.cells[cropped.cell_of(x, y)] == grid_map.cells[row, col]
    assert crop_to_known(grid_map, margin_m=0.5).cells.shape == (5, 12)  # one cell each side, clipped


def test_a_crops_origin_is_the_metres_a_user_wrote_not_their_float_sum():
    """`maps crop` wrote `origin: [-3.8499999999999996, ...]` (23 cells of 0.05 m from -5.0)."""
    from smorphi_rl.maptools import crop_to_rect

    grid_map = Map(np.zeros((200, 200), dtype=np.uint8), 0.05, origin=(-5.0, -5.0, 0.0), name="m")
    assert crop_to_rect(grid_map, -3.85, -2.8, 1.0, 1.0).origin == (-3.85, -2.8, 0.0)


def test_coarsening_is_conservative():
    rng = np.random.default_rng(3)
    fine = random_map(rng, 30, 41, 0.05, 0.02)
    coarse = coarsen(fine, 3)
    assert coarse.resolution_m == pytest.approx(0.3) and coarse.cells.shape == (10, 14)
    for row, col in np.argwhere(coarse.cells == Cell.FREE):
        assert (fine.cells[3 * row : 3 * row + 3, 3 * col : 3 * col + 3] == Cell.FREE).all()
    assert coarsen(fine, 1) is fine
    with pytest.raises(MapError, match="whole number"):
        coarsen(fine, 0)


def test_small_islands_are_dropped_and_the_largest_area_kept():
    grid_map = Map.from_text(ISLANDS, 0.5, name="islands")
    kept, dropped = drop_islands(grid_map, min_area_m2=1.0)  # areas of 9, 3, 3 and 1 cells of 0.25 m^2
    assert dropped.count == 3 and dropped.area_m2 == pytest.approx(0.75 + 0.75 + 0.25)
    assert kept.counts[Cell.FREE] == 9
    assert drop_islands(grid_map, 0.5)[1].count == 1  # only the single cell
    assert drop_islands(grid_map, 0.0)[1].count == 0
    everything, _ = drop_islands(grid_map, 1e9)
    assert everything.counts[Cell.FREE] == 9  # the largest area stays, however small


def test_maps_crop_then_resample_a_real_map_and_refuse_to_overwrite(tmp_path, capsys):
    source = realmap("tb3_world")
    cropped, coarse = tmp_path / "tb3.yaml", tmp_path / "tb3-10cm.yaml"
    assert main(["maps", "crop", str(source), "--out", str(cropped), "--min-island", "0.05"]) == 0
    assert main(["maps", "resample", str(cropped), "--resolution", "0.1", "--out", str(coarse)]) == 0
    printed = capsys.readouterr().out
    prepared, original = load_map(coarse), load_map(source)
    assert printed.count("wrote") == 2 and "islands  3 dropped" in printed and prepared.resolution_m == 0.1
    assert prepared.cells.size * 20 < original.cells.size
    assert main(["maps", "crop", str(source), "--out", str(cropped)]) != 0
    assert "exists" in capsys.readouterr().err and load_map(cropped).cells.shape == (112, 121)


def test_a_crop_that_cuts_nothing_says_so(tmp_path, capsys):
    """`maps crop` of a map without an unknown margin wrote an identical copy without a word."""
    from smorphi_rl.maps import Map, save_map

    assert main(["maps", "crop", str(ROOT / "maps" / "map-1.yaml"), "--out", str(tmp_path / "same.yaml")]) == 0
    said = capsys.readouterr().out.splitlines()[-1]
    assert said == "note     nothing cut: no unknown margin beyond --margin 0.2 m"
    framed = np.full((30, 30), Cell.UNKNOWN, dtype=np.uint8)
    framed[5:25, 5:25] = Cell.FREE
    save_map(Map(framed, 0.1, name="framed"), tmp_path / "framed.yaml")
    assert main(["maps", "crop", str(tmp_path / "framed.yaml"), "--out", str(tmp_path / "cut.yaml")]) == 0
    assert "note" not in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["maps", "resample", "maps/map-1.yaml", "--resolution", "0.05"], "only to a coarser resolution"),
        (["maps", "resample", "maps/map-1.yaml", "--resolution", "0.25"], "not a whole multiple"),
        (["maps", "crop", "maps/map-1.yaml", "--rect", "4", "4", "6", "6"], "is not inside map map-1"),
        (["maps", "crop", "maps/map-1.yaml", "--rect", "2", "2", "1", "3"], "is empty"),
        (["maps", "show", "maps/map-1.pgm"], "is an image: give the map_server YAML"),
    ],
)
def test_bad_map_tool_input_is_one_line(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    out = ["--out", str(tmp_path / "x.yaml")] if argv[1] in ("crop", "resample") else []
    assert main(argv + out) != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.yaml").exists()


def test_a_resampled_map_has_the_resolution_asked_for_and_holds_a_block_of_one_cell(tmp_path):
    """0.1 x 3 wrote `resolution: 0.30000000000000004`, and its own advice (`--block-side 0.3`) was then refused."""
    from smorphi_rl.geometry import check_block_side

    out = tmp_path / "coarse.yaml"
    assert main(["maps", "resample", str(ROOT / "maps" / "map-1.yaml"), "--resolution", "0.3", "--out", str(out)]) == 0
    assert load_map(out).resolution_m == 0.3 and "resolution: 0.3\n" in out.read_text()
    assert check_block_side(0.3, 0.1 * 3) == 0.3
    assert main(["evaluate", "--map", str(out), "--angles", "0", "180", "0", "--block-side", "0.3"]) == 0
