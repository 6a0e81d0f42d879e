"""Projection of many points onto one fixed polyline, its segments prepared once.

:func:`coster_sumo.geometry.boxes.project_points` derives the polyline's segments, lengths and arc
lengths at every call; the reaction test of reactive traffic (:mod:`coster_sumo.sim.reactive`)
projects the agents onto the target's route at every 0.1 s step, always the same route.
:class:`PreparedPolyline` keeps those arrays and projects with the same operations in the same order
(the same numbers, ``tests/sim/test_corridor.py``).
"""

from __future__ import annotations

import numpy as np

from coster_sumo.geometry.boxes import _EPS, polyline_arc_length


class PreparedPolyline:
    """An (n, 2) polyline [m] (n >= 1; one point is a zero-length segment) ready for :meth:`project`."""

    def __init__(self, polyline: np.ndarray) -> None:
        line = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
        self.given = len(line)  # points given (len(): a caller's "at least two points" test)
        if len(line) == 1:
            line = np.concatenate([line, line])
        self.points = line
        self.s0 = line[:-1]  # (S, 2)
        self.e = line[1:] - self.s0
        self.seg_len = np.hypot(self.e[:, 0], self.e[:, 1])
        self.denominator = np.maximum(self.seg_len**2, _EPS)
        self.cum = polyline_arc_length(line)
        self.heading = np.arctan2(self.e[:, 1], self.e[:, 0])  # (S,) [rad] of each segment

    def __len__(self) -> int:
        return self.given

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``project_points(points, polyline)``: arc length, signed lateral offset (> 0 left) and
        segment index of the closest point, each shaped as ``points`` without its last axis."""
        p = np.asarray(points, dtype=np.float64)
        shape = p.shape[:-1]
        p = p.reshape(-1, 2)
        rel = p[:, None, :] - self.s0  # (N, S, 2)
        t = np.clip(np.sum(rel * self.e, -1) / self.denominator, 0.0, 1.0)  # (N, S)
        diff = rel - t[..., None] * self.e
        dist2 = np.sum(diff * diff, -1)
        k = np.argmin(dist2, axis=-1)  # (N,)
        rows = np.arange(len(p))
        arc = self.cum[k] + t[rows, k] * self.seg_len[k]
        ek, relk = self.e[k], rel[rows, k]
        cross = ek[:, 0] * relk[:, 1] - ek[:, 1] * relk[:, 0]
        dist = np.sqrt(dist2[rows, k])
        lateral = np.where(cross >= 0.0, dist, -dist)
        return arc.reshape(shape), lateral.reshape(shape), k.reshape(shape)
