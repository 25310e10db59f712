"""Generated floor plans: seeded, of every kind, one connected free area, a SLAM-like unknown margin."""

from __future__ import annotations

import hashlib
import itertools
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from smorphi_rl.floorplans import DEFAULT_RANGE, FloorKind, FloorRange, floor_name, generate_floor
from smorphi_rl.map_sources import (
    HELD_OUT_SEEDS,
    TRAINING_SEEDS,
    VALIDATION_SEEDS,
    MapSourceError,
    parse_generator,
    resolve,
)
from smorphi_rl.maps import Cell, load_map

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("kind", [k.value for k in FloorKind])
def test_every_kind_is_a_connected_floor_within_the_range(kind):
    for seed in range(6):
        m = generate_floor(kind, seed)
        free = m.cells == Cell.FREE
        assert ndimage.label(free, structure=[[0, 1, 0], [1, 1, 1], [0, 1, 0]])[1] == 1
        assert DEFAULT_RANGE.min_resolution_m <= m.resolution_m <= 0.2 and m.cells.size <= DEFAULT_RANGE.max_cells
        assert m.cells[0].tolist() == [Cell.UNKNOWN] * m.width  # the margin outside the outer wall
        rows, cols = np.nonzero(m.cells != Cell.UNKNOWN)
        sides = ((np.ptp(rows) + 1) * m.resolution_m, (np.ptp(cols) + 1) * m.resolution_m)
        assert min(sides) >= 2.9 and max(sides) <= 15.1, sides
        assert m.name == floor_name(kind, seed)


def test_a_floor_is_a_function_of_its_kind_and_seed():
    a, b = generate_floor("rooms", 17), generate_floor("rooms", 17)
    assert np.array_equal(a.cells, b.cells) and a.resolution_m == b.resolution_m
    assert not np.array_equal(generate_floor("rooms", 18).cells.shape, a.cells.shape) or not np.array_equal(
        generate_floor("rooms", 18).cells, a.cells
    )


def test_the_shipped_held_out_floors_are_regenerated_bit_for_bit():
    """maps/designer/held-out was written by `maps generate --kind mixed --count 50 --seed 1000000 --format png`:
    the generator still makes exactly those floors."""
    shipped = sorted((ROOT / "maps" / "designer" / "held-out").glob("*.yaml"))
    assert len(shipped) == 50
    for path in shipped[::7]:
        seed = int(path.stem.split("-")[1])
        assert HELD_OUT_SEEDS[0] <= seed and np.array_equal(load_map(path).cells, generate_floor("mixed", seed).cells)


def test_training_validation_and_held_out_seeds_never_meet():
    ranges = [TRAINING_SEEDS, VALIDATION_SEEDS, HELD_OUT_SEEDS]
    for (lo_a, hi_a), (lo_b, _) in itertools.pairwise(ranges):
        assert hi_a <= lo_b and lo_a < hi_a
    assert parse_generator("generate:mixed").split() == "training"
    for path in (ROOT / "maps" / "designer" / "validation").glob("*.yaml"):
        assert VALIDATION_SEEDS[0] <= int(path.stem.split("-")[1]) < VALIDATION_SEEDS[1]


def test_map_entries_resolve_folders_globs_and_generators(tmp_path):
    found = resolve([str(ROOT / "maps" / "val-*.yaml"), "generate:hall:5-9"])
    assert [Path(p).name for p in found[:3]] == ["val-1.yaml", "val-2.yaml", "val-3.yaml"]
    assert found[3] == "generate:hall:5-9"
    assert len(resolve([str(ROOT / "maps" / "designer" / "validation")])) == 8


def test_a_linked_map_is_read_beside_the_link_as_every_command_reads_it(tmp_path):
    """`train`, `sweep` and `evaluate-policy` followed a linked YAML to its target and read the target's image,
    while `evaluate`, `design` and nav2 read the image beside the link: two floors under one name."""
    (tmp_path / "real").mkdir()
    (tmp_path / "link").mkdir()
    shutil.copy(ROOT / "maps" / "map-1.yaml", tmp_path / "real" / "floor.yaml")
    (tmp_path / "link" / "current.yaml").symlink_to(tmp_path / "real" / "floor.yaml")
    (found,) = resolve([str(tmp_path / "link" / "current.yaml")])
    assert Path(found) == (tmp_path / "link" / "current.yaml").absolute()


@pytest.mark.parametrize(("entry", "message"), [
    ("generate:castle", "unknown floor kind 'castle'"),
    ("generate:rooms:9-3", "need 0 <= LO < HI"),
    ("generate:rooms:a-b", "LO-HI, two integers"),
])  # fmt: skip
def test_bad_generator_entries_name_the_problem(entry, message):
    with pytest.raises(MapSourceError, match=message):
        parse_generator(entry)


def test_an_empty_folder_or_a_glob_matching_nothing_is_refused(tmp_path):
    with pytest.raises(MapSourceError, match="holds no map YAML"):
        resolve([str(tmp_path)])
    with pytest.raises(MapSourceError, match="matches no map YAML"):
        resolve([str(tmp_path / "*.yaml")])


def test_a_range_outside_the_limits_is_refused():
    from smorphi_rl.errors import MapError

    with pytest.raises(MapError, match="floor sides"):
        FloorRange(min_side_m=1.0)
    with pytest.raises(MapError, match="resolutions"):
        FloorRange(max_resolution_m=0.5)


def test_floors_do_not_change_silently():
    """A digest of a few floors: a change to the generator changes every floor a shipped designer was measured on
    (regenerate maps/designer and re-measure the designer if this fails on purpose)."""
    h = hashlib.blake2b(digest_size=8)
    for kind in ("rooms", "corridor", "hall", "furniture"):
        m = generate_floor(kind, 3)
        h.update(m.cells.tobytes() + str(m.resolution_m).encode())
    assert h.hexdigest() == DIGEST


DIGEST = "5d63fbe67e32b965"
