"""Geometry (docs/spec/fbcpp.md sections 1-2): poses, footprint sizes, F, feasibility."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from smorphi_rl import _kernels as k
from smorphi_rl.errors import MorphologyError
from smorphi_rl.geometry import (
    Morphology,
    all_corners,
    cells_along,
    footprint_matrix,
    footprint_size,
    format_footprint,
    is_feasible,
    overlap_area,
)

S = 0.17
angles = st.floats(min_value=0.0, max_value=180.0, allow_nan=False)
int_angles = st.integers(min_value=0, max_value=180)

BOUNDING_BOXES = [
    ((0, 0, 0), 4, 1),
    ((0, 180, 0), 2, 2),
    ((180, 0, 180), 2, 2),
    ((180, 180, 180), 1, 4),
    ((0, 0, 180), 3, 2),
    ((180, 180, 0), 2, 3),
    ((90, 90, 90), 4, 4),
    ((45, 45, 45), 4.8284, 2.7071),
    ((95, 59, 103), 2.7863, 4.8909),
]

GOLDEN_F = {
    (0, 0, 0): "#######\n#######",
    (0, 180, 0): "###\n###\n###",
    (90, 90, 90): "##.....\n##.....\n..#....\n..#....\n...##..\n.....##\n.....##",
    (95, 59, 103): "##..\n..#.\n..#.\n...#\n..##\n...#\n...#\n...#",
}


@pytest.mark.parametrize(("theta", "w_units", "l_units"), BOUNDING_BOXES)
def test_footprint_size_matches_spec_table(theta, w_units, l_units):
    w, l = footprint_size(Morphology.of(theta), S)
    assert w / S == pytest.approx(w_units, abs=1e-4)
    assert l / S == pytest.approx(l_units, abs=1e-4)


@pytest.mark.parametrize(("theta", "text"), GOLDEN_F.items())
def test_footprint_matrix_golden(theta, text):
    f = footprint_matrix(Morphology.of(theta), 0.1, S)
    assert format_footprint(f) == text


@pytest.mark.parametrize("theta", GOLDEN_F)
def test_compiled_footprint_equals_reference(theta):
    buf = np.zeros((k.buffer_side(S, 0.1),) * 2, np.uint8)
    feasible, l, w, w_m, l_m = k.footprint_into(*map(float, theta), S, 0.1, buf)
    assert feasible
    assert np.array_equal(buf[:l, :w].astype(bool), footprint_matrix(Morphology.of(theta), 0.1, S))
    assert (w_m, l_m) == footprint_size(Morphology.of(theta), S)


def _union_area_by_sampling(theta, n=300) -> float:
    blocks = all_corners(Morphology.of(theta), S)
    pts = np.array([p for b in blocks for p in b])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    xs = lo[0] + (np.arange(n) + 0.5) * (hi[0] - lo[0]) / n
    ys = lo[1] + (np.arange(n) + 0.5) * (hi[1] - lo[1]) / n
    gx, gy = np.meshgrid(xs, ys)
    inside = np.zeros_like(gx, dtype=bool)
    for b in blocks:
        (x0, y0), (x1, y1), _, (x3, y3) = b
        ex, ey, fx, fy = x1 - x0, y1 - y0, x3 - x0, y3 - y0
        u = ((gx - x0) * ex + (gy - y0) * ey) / (S * S)
        v = ((gx - x0) * fx + (gy - y0) * fy) / (S * S)
        inside |= (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    return inside.mean() * (hi[0] - lo[0]) * (hi[1] - lo[1])


@given(int_angles, int_angles, int_angles)
def test_union_of_blocks_is_four_squares(t1, t2, t3):
    theta = (t1, t2, t3)
    assert is_feasible(Morphology.of(theta), S)
    assert _union_area_by_sampling(theta) == pytest.approx(4 * S * S, rel=0.03)


@given(angles, angles, angles)
def test_blocks_are_rigid_squares_chained_at_hinges(t1, t2, t3):
    blocks = all_corners(Morphology.of((t1, t2, t3)), S)
    for b in blocks:
        sides = [math.dist(b[i], b[(i + 1) % 4]) for i in range(4)]
        assert sides == pytest.approx([S] * 4, abs=1e-12)
        assert math.dist(b[0], b[2]) == pytest.approx(S * math.sqrt(2), abs=1e-12)
    # every hinge is a shared corner of the two blocks it joins
    for i in range(3):
        shared = min(math.dist(p, q) for p in blocks[i] for q in blocks[i + 1])
        assert shared == pytest.approx(0.0, abs=1e-12)


def _sorted_distances(theta) -> np.ndarray:
    pts = np.array([p for b in all_corners(Morphology.of(theta), S) for p in b])
    return np.sort(np.linalg.norm(pts[:, None] - pts[None], axis=-1).ravel())


@given(angles, angles, angles)
def test_reversed_chain_is_congruent(t1, t2, t3):
    """Reading the chain from B4 gives the same rigid shape: (t1, t2, t3) ~ (t3, t2, t1)."""
    np.testing.assert_allclose(_sorted_distances((t1, t2, t3)), _sorted_distances((t3, t2, t1)), atol=1e-12)


@given(angles, angles, angles, st.floats(-math.pi, math.pi), st.floats(-5, 5), st.floats(-5, 5))
def test_overlap_area_is_invariant_under_rigid_motion(t1, t2, t3, a, dx, dy):
    blocks = all_corners(Morphology.of((t1, t2, t3)), S)
    c, s = math.cos(a), math.sin(a)

    def move(b):
        return [(c * x - s * y + dx, s * x + c * y + dy) for x, y in b]

    for i in range(4):
        for j in range(i + 1, 4):
            assert overlap_area(move(blocks[i]), move(blocks[j])) == pytest.approx(
                overlap_area(blocks[i], blocks[j]), abs=1e-12
            )


def test_overlap_area_detects_overlap():
    sq = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    shifted = [(x + 0.5, y + 0.25) for x, y in sq]
    assert overlap_area(sq, shifted) == pytest.approx(0.5 * 0.75)
    touching = [(x + 1.0, y) for x, y in sq]
    assert overlap_area(sq, touching) == pytest.approx(0.0, abs=1e-15)


@given(angles, angles, angles)
def test_compiled_footprint_equals_reference_everywhere(t1, t2, t3):
    m = Morphology.of((t1, t2, t3))
    for r in (0.1, 0.05, 0.037):
        buf = np.zeros((k.buffer_side(S, r),) * 2, np.uint8)
        feasible, l, w, w_m, l_m = k.footprint_into(t1, t2, t3, S, r, buf)
        assert feasible == is_feasible(m, S)
        assert np.array_equal(buf[:l, :w].astype(bool), footprint_matrix(m, r, S))
        assert (w_m, l_m) == footprint_size(m, S)


def test_no_morphology_self_overlaps_at_2_degree_steps():
    """The spec's chain alternates hinge sides, so blocks never overlap: a full sweep finds none."""
    g = np.arange(0, 181, 2.0)
    thetas = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    out, _ = k.footprints_batch(thetas, S, 0.1, k.buffer_side(S, 0.1))
    assert out[:, k.COL_FEASIBLE].all()


@pytest.mark.parametrize("bad", [(-1, 0, 0), (0, 180.5, 0), (0, 0, float("nan")), ("a", 0, 0), (True, 0, 0)])
def test_morphology_rejects_bad_angles(bad):
    with pytest.raises(MorphologyError, match="hinge angle t"):
        Morphology.of(bad)


def test_morphology_needs_three_angles():
    with pytest.raises(MorphologyError, match="3 hinge angles"):
        Morphology.of((1, 2))


@pytest.mark.parametrize("resolution", [0.01, 0.03, 0.05, 0.07, 0.085, 0.1, 0.13, 0.17])
def test_the_o_and_the_i_rasterise_to_full_rectangles_of_cells_along_their_sides(resolution):
    """`cells_along` is what the robot-fits check (maps.check_robot_fits) assumes of F (section 2)."""
    o, i1, i4 = (cells_along(n * S, resolution) for n in (2, 1, 4))
    for angles, shape in (((0, 180, 0), (o, o)), ((0, 0, 0), (i1, i4)), ((180, 180, 180), (i4, i1))):
        f = footprint_matrix(Morphology(*angles), resolution)
        assert f.shape == shape and f.all()


def test_an_angle_read_back_rounded_finds_its_lattice_angle():
    """float32 and a table's 6 significant digits move a lattice angle by far less than a step; the nearest lattice
    angle is `lattice_axis`'s own value, 180 held at 180, and nothing falls outside [0, 180]."""
    from smorphi_rl.geometry import lattice_axis, nearest_on_lattice

    step = 180 / 31
    axis = lattice_axis(step)
    rounded = np.array([axis[5].astype(np.float32), float(f"{axis[17]:g}"), 180.0004, -0.0002])
    assert nearest_on_lattice(rounded, step).tolist() == [axis[5], axis[17], 180.0, 0.0]
