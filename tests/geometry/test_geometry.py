from __future__ import annotations

import numpy as np
import pytest
import shapely

from coster_sumo.geometry import boxes as g


def _random_boxes(rng: np.random.Generator, n: int, spread: float = 8.0) -> np.ndarray:
    # large absolute coordinates, as in WOMD, so that precision problems show
    cx = 8123.0 + rng.uniform(-spread, spread, n)
    cy = -3456.0 + rng.uniform(-spread, spread, n)
    return g.make_boxes(cx, cy, rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 12.0, n),
                        rng.uniform(0.3, 3.0, n))


def _polygons(boxes: np.ndarray) -> np.ndarray:
    return shapely.polygons(g.corners_of(boxes))


def test_corners_of_axis_aligned_box():
    c = g.box_corners(1.0, 2.0, 0.0, 4.0, 2.0)
    np.testing.assert_allclose(c, [[3, 3], [-1, 3], [-1, 1], [3, 1]])


def test_corners_counter_clockwise_and_area():
    rng = np.random.default_rng(1)
    boxes = _random_boxes(rng, 500)
    polys = _polygons(boxes)
    assert np.all(shapely.is_ccw(shapely.get_exterior_ring(polys)))
    np.testing.assert_allclose(shapely.area(polys), boxes[:, 3] * boxes[:, 4], rtol=1e-9)


def test_overlap_and_distance_match_shapely():
    rng = np.random.default_rng(0)
    a, b = _random_boxes(rng, 5000, 5.0), _random_boxes(rng, 5000, 5.0)
    pa, pb = _polygons(a), _polygons(b)
    inter_area = shapely.area(shapely.intersection(pa, pb))
    overlap = g.boxes_overlap(a, b)
    clear = (inter_area > 1e-6) | (shapely.distance(pa, pb) > 1e-6)  # skip numerically touching pairs
    np.testing.assert_array_equal(overlap[clear], inter_area[clear] > 1e-6)
    sd = g.box_signed_distance(a, b)
    sep = ~overlap
    assert sep.sum() > 1000 and overlap.sum() > 1000
    assert np.max(np.abs(sd[sep] - shapely.distance(pa[sep], pb[sep]))) < 1e-6
    assert np.all(sd[overlap] < 0)


def test_penetration_is_minimum_translation():
    a = g.make_boxes(0.0, 0.0, 0.0, 4.0, 2.0)
    b = g.make_boxes(3.5, 0.2, 0.0, 4.0, 2.0)  # overlaps by 0.5 m along x, 1.8 m along y
    assert g.box_signed_distance(a, b) == pytest.approx(-0.5)
    moved = g.translate_boxes(b, np.array([1.0, 0.0]), 0.5)
    assert g.box_signed_distance(a, moved) == pytest.approx(0.0, abs=1e-12)
    assert not g.boxes_overlap(a, moved)


def test_penetration_resolves_overlap_on_random_pairs():
    rng = np.random.default_rng(3)
    a, b = _random_boxes(rng, 2000, 3.0), _random_boxes(rng, 2000, 3.0)
    sd = g.box_signed_distance(a, b)
    over = sd < -1e-3
    pa = _polygons(a[over])
    # no translation shorter than the depth separates them: shrinking the depth by 1 mm in every
    # direction keeps an overlap (checked along 36 directions)
    for ang in np.radians(np.arange(0, 360, 10)):
        d = np.array([np.cos(ang), np.sin(ang)])
        shifted = g.translate_boxes(b[over], d, -sd[over] - 1e-3)
        assert np.all(shapely.area(shapely.intersection(pa, _polygons(shifted))) > 0)


def test_broadcasting_all_pairs():
    rng = np.random.default_rng(4)
    a, b = _random_boxes(rng, 7), _random_boxes(rng, 5)
    sd = g.box_signed_distance(a[:, None], b[None])
    assert sd.shape == (7, 5)
    for i in range(7):
        np.testing.assert_allclose(sd[i], g.box_signed_distance(a[i], b))
    assert g.boxes_overlap(a[:, None], b[None]).shape == (7, 5)


@pytest.mark.parametrize("relative_heading_deg", range(0, 360, 5))
def test_touch_placement_every_relative_heading(relative_heading_deg):
    rng = np.random.default_rng(relative_heading_deg)
    n = 200
    fixed = g.make_boxes(8123.4, -3456.7, rng.uniform(-np.pi, np.pi, n), 4.8, 2.0)
    bearing = rng.uniform(-np.pi, np.pi, n)
    start = fixed[:, :2] + 30.0 * np.stack([np.cos(bearing), np.sin(bearing)], -1)
    heading = fixed[:, 2] + np.radians(relative_heading_deg)
    moving = g.make_boxes(start[:, 0], start[:, 1], heading, rng.uniform(3.0, 12.0, n),
                          rng.uniform(1.5, 2.6, n))
    direction = fixed[:, :2] - moving[:, :2] + rng.normal(0.0, 0.5, (n, 2))  # roughly at the target
    t = g.touch_translation(moving, fixed, direction)
    assert np.all(np.isfinite(t)) and np.all(t > 0)
    placed = g.translate_boxes(moving, direction, t)
    sd = g.box_signed_distance(placed, fixed)
    assert np.all(sd >= 0.0) and np.all(sd <= 0.05)
    assert np.median(sd) < 1e-5
    assert not np.any(g.boxes_overlap(placed, fixed))
    # a little further along the direction they overlap
    assert np.all(g.boxes_overlap(g.translate_boxes(moving, direction, t + 0.02), fixed))


def test_touch_translation_misses_and_backwards():
    fixed = g.make_boxes(0.0, 0.0, 0.0, 4.0, 2.0)
    moving = g.make_boxes(-10.0, 5.0, 0.0, 4.0, 2.0)
    assert np.isnan(g.touch_translation(moving, fixed, np.array([1.0, 0.0])))  # passes above
    overlapping = g.make_boxes(1.0, 0.0, 0.0, 4.0, 2.0)
    t = g.touch_translation(overlapping, fixed, np.array([1.0, 0.0]))
    assert t == pytest.approx(-5.0, abs=1e-5)  # back off to x = -4, touching from the -x side


def test_local_world_round_trip():
    rng = np.random.default_rng(5)
    p = rng.uniform(-1e4, 1e4, (100, 2))
    o = rng.uniform(-1e4, 1e4, (100, 2))
    h = rng.uniform(-np.pi, np.pi, 100)
    np.testing.assert_allclose(g.to_world(g.to_local(p, o, h), o, h), p, atol=1e-8)
    np.testing.assert_allclose(g.to_local(o + [[1.0, 0.0]], o, np.pi / 2)[0], [0.0, -1.0], atol=1e-9)


def test_resample_fixed_spacing():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 7.0]])  # L = 17
    out = g.resample_polyline(line, 5.0)
    np.testing.assert_allclose(out, [[0, 0], [5, 0], [10, 0], [10, 5], [10, 7]])
    even = g.resample_polyline(line, 5.0, even=True)  # round(17/5) = 3 gaps of 17/3
    assert len(even) == 4
    s, lat, _ = g.project_points(even, line)
    np.testing.assert_allclose(s, np.arange(4) * 17 / 3)  # equal gaps along the line
    np.testing.assert_allclose(lat, 0.0, atol=1e-12)
    np.testing.assert_allclose(even[[0, -1]], line[[0, -1]])


def test_resample_many_polylines_matches_one_by_one():
    rng = np.random.default_rng(6)
    lines = [np.cumsum(rng.normal(0, 3, (rng.integers(1, 30), 2)), 0) + 5000 for _ in range(40)]
    lines.append(np.zeros((0, 2)))
    rag = g.resample_polylines(lines, 2.5, even=True)
    assert len(rag) == len(lines)
    for i, line in enumerate(lines):
        expected = g.resample_polyline(line, 2.5, even=True) if len(line) else np.zeros((0, 2))
        np.testing.assert_allclose(rag[i], expected, atol=1e-9)
        if len(line) >= 2:
            assert len(rag[i]) == max(1, round(g.polyline_arc_length(line)[-1] / 2.5)) + 1


def test_project_points_arc_length_and_side():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    s, lat, seg = g.project_points(np.array([[3.0, 1.0], [3.0, -2.0], [12.0, 6.0], [-5.0, 0.0]]), line)
    np.testing.assert_allclose(s, [3.0, 3.0, 16.0, 0.0])
    np.testing.assert_allclose(lat, [1.0, -2.0, -2.0, 5.0])  # (-5, 0) is behind: 5 m, on the line
    np.testing.assert_array_equal(seg, [0, 0, 1, 0])
    xy, heading = g.point_at_arc_length(line, np.array([3.0, 16.0]))
    np.testing.assert_allclose(xy, [[3.0, 0.0], [10.0, 6.0]])
    np.testing.assert_allclose(heading, [0.0, np.pi / 2])
