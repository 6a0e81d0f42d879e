"""PreparedPolyline.project gives project_points' numbers, bit for bit."""

from __future__ import annotations

import numpy as np

from coster_sumo.geometry.boxes import project_points
from coster_sumo.sim.corridor import PreparedPolyline


def test_prepared_projection_is_project_points():
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 60):
        line = np.cumsum(rng.normal(size=(n, 2)) * 4.0, axis=0)
        if n > 2:
            line[2] = line[1]  # a zero-length segment
        prepared = PreparedPolyline(line)
        assert len(prepared) == n
        for points in (rng.uniform(-80, 80, (40, 2)), rng.uniform(-80, 80, 2), line):
            got = prepared.project(points)
            want = project_points(points, line)
            for g, w in zip(got, want, strict=True):
                assert g.shape == np.shape(w)
                assert np.array_equal(g, w)


def test_segment_headings():
    prepared = PreparedPolyline(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]]))
    assert np.allclose(prepared.heading, [0.0, np.pi / 2])
