"""Polyline helpers of the plain net: WOMD centrelines cleaned, and cut between arc lengths."""

from __future__ import annotations

import numpy as np

from coster_sumo.geometry.boxes import polyline_arc_length

DUPLICATE_POINT_M = 1e-3  # [m] consecutive points closer than this are one point


def clean_polyline(points: np.ndarray) -> np.ndarray:
    """Drop non-finite points and consecutive repeats. Returns (m, 2)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 2:
        return p
    if np.all(np.hypot(*np.diff(p, axis=0).T) >= DUPLICATE_POINT_M):
        return p  # the usual case: nothing to drop
    keep = np.ones(len(p), bool)
    last = p[0]
    for i in range(1, len(p)):  # sequential: a run of tiny steps must still be dropped
        if np.hypot(*(p[i] - last)) < DUPLICATE_POINT_M:
            keep[i] = False
        else:
            last = p[i]
    return p[keep]


def cut_polyline(points: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of a polyline between arc lengths s0 < s1, end points interpolated. (m, 2)."""
    cum = polyline_arc_length(points)
    inner = (cum > s0 + DUPLICATE_POINT_M) & (cum < s1 - DUPLICATE_POINT_M)
    a = np.array([np.interp(s0, cum, points[:, 0]), np.interp(s0, cum, points[:, 1])])
    b = np.array([np.interp(s1, cum, points[:, 0]), np.interp(s1, cum, points[:, 1])])
    return np.concatenate([a[None], points[inner], b[None]])
