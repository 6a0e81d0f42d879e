"""Clearance tests of the avoidability search (:mod:`coster_sumo.avoidability.search`): the other
vehicles' boxes near the target's path, and whether a batch of candidate paths' boxes overlap the
adversary's or another vehicle's. Every test runs the exact box overlap only on pairs whose centres
are within reach of each other (the same answer as on every pair).

Times are simulation seconds on the search's grid, distances metres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import make_boxes, sat_overlap_depth

NEAR_M = 60.0  # [m] other vehicles further than this from the target's path never matter


def other_boxes(scene: Scene, target: int, times: np.ndarray, path: np.ndarray
                 ) -> tuple[tuple[np.ndarray, np.ndarray] | None, np.ndarray]:
    """(N, T, 5) boxes and (N, T) validity of the other vehicles near the target's path on the grid
    (None: none), and their (N,) ids."""
    tr = scene.tracks
    ts = scene.timestamps
    idx = np.clip(np.searchsorted(ts, times - 1e-6), 0, len(ts) - 1)
    prev = np.clip(idx - 1, 0, len(ts) - 1)
    idx = np.where(np.abs(ts[prev] - times) < np.abs(ts[idx] - times), prev, idx)
    inside = np.abs(ts[idx] - times) <= 0.06
    others = np.flatnonzero(np.arange(tr.num_agents) != target)
    if not len(others):
        return None, np.zeros(0, str)
    valid = tr.valid[np.ix_(others, idx)] & inside[None]
    ox, oy = tr.x[np.ix_(others, idx)], tr.y[np.ix_(others, idx)]
    lo, hi = path[1:-1].min(0) - NEAR_M, path[1:-1].max(0) + NEAR_M
    near = valid & (ox >= lo[0]) & (ox <= hi[0]) & (oy >= lo[1]) & (oy <= hi[1])
    keep = near.any(1)
    if not keep.any():
        return None, np.zeros(0, str)
    rows = others[keep]
    boxes = make_boxes(tr.x[np.ix_(rows, idx)], tr.y[np.ix_(rows, idx)], tr.heading[np.ix_(rows, idx)],
                       tr.length[np.ix_(rows, idx)], tr.width[np.ix_(rows, idx)])
    return (boxes, valid[keep]), tr.ids[rows].astype(str)


def hits_adversary(centres: np.ndarray, yaws: np.ndarray, size: tuple[float, float], adv_box: np.ndarray,
                    acted: np.ndarray) -> np.ndarray:
    """(G,) whether each candidate's grown boxes overlap the adversary at a step after acting.

    Args:
        centres: (G, T, 2) candidate box centres [m]; yaws: (G, T) [rad]; size: the grown boxes'
            length and width [m]; adv_box: (T, 5); acted: (G, T).

    Two boxes overlap only where their centres are closer than the sum of their half diagonals:
    the exact test runs on those steps alone (the same answer as on every step).
    """
    reach = outer_reach(size, adv_box[0, 3], adv_box[0, 4])
    dx = centres[..., 0] - adv_box[None, :, 0]
    dy = centres[..., 1] - adv_box[None, :, 1]
    d2 = dx * dx + dy * dy
    near = acted & (d2 < reach * reach * (1.0 + 1e-9))
    # closer than the sum of the discs inside both boxes: they overlap, no exact test needed
    inner = _inner_reach(size, adv_box[..., 3], adv_box[..., 4])  # (T,)
    hit = (near & (d2 < inner * inner)).any(-1)
    near &= ~hit[:, None]
    if near.any():
        g, t = np.nonzero(near)
        boxes = make_boxes(centres[g, t, 0], centres[g, t, 1], yaws[g, t], *size)
        hit[g[sat_overlap_depth(boxes, adv_box[t]) > 0.0]] = True
    return hit


def too_close(centres: np.ndarray, yaws: np.ndarray, size: tuple[float, float], o_box: np.ndarray,
              o_valid: np.ndarray, acted: np.ndarray) -> np.ndarray:
    """(G,) whether each candidate's grown boxes overlap another vehicle at a step after acting.

    Args:
        centres: (G, T, 2) candidate box centres [m]; yaws: (G, T) [rad]; size: the boxes' length
            and width grown by the clearance [m]; o_box: (N, T, 5); o_valid: (N, T) the other
            vehicles, valid where they exist; acted: (G, T) each candidate's steps after acting.

    Only pairs whose centres are within reach of each other (half diagonals) are tested exactly.
    """
    hit = np.zeros(len(centres), bool)
    if not len(centres):
        return hit
    reach = outer_reach(size, o_box[..., 3], o_box[..., 4])  # (N, T)
    # only the (vehicle, step) pairs within reach of the box around every candidate at that step
    # can be near one: the pairwise test runs on those (a margin keeps rounding on the safe side)
    x, y = centres[..., 0], centres[..., 1]  # (G, T)
    pad = reach * (1.0 + 1e-6) + 1e-6
    ox, oy = o_box[..., 0], o_box[..., 1]
    o, t = np.nonzero(o_valid & (ox >= x.min(0) - pad) & (ox <= x.max(0) + pad)
                      & (oy >= y.min(0) - pad) & (oy <= y.max(0) + pad))
    if not len(o):
        return hit
    dx = x[:, t] - ox[o, t]  # (G, P)
    dy = y[:, t] - oy[o, t]
    d2 = dx * dx + dy * dy
    near = acted[:, t] & (d2 < (reach[o, t] * reach[o, t])[None])
    inner = _inner_reach(size, o_box[o, t, 3], o_box[o, t, 4])  # (P,)
    hit |= (near & (d2 < (inner * inner)[None])).any(-1)  # the discs inside both boxes overlap
    near &= ~hit[:, None]
    if near.any():
        c, p = np.nonzero(near)
        o, t = o[p], t[p]
        boxes = make_boxes(centres[c, t, 0], centres[c, t, 1], yaws[c, t], *size)
        hit[c[sat_overlap_depth(boxes, o_box[o, t]) > 0.0]] = True
    return hit


def outer_reach(size: tuple[float, float], length: ArrayLike, width: ArrayLike) -> np.ndarray:
    """[m] a centre distance beyond which two boxes (``size`` and ``length`` x ``width``) cannot
    overlap: the sum of their half diagonals (the circles round them)."""
    return 0.5 * (np.hypot(*size) + np.hypot(length, width))  # type: ignore[no-any-return]


def _inner_reach(size: tuple[float, float], length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """[m] a centre distance under which two boxes certainly overlap: the sum of the radii of the
    discs inside them (half the shorter side of each), less a millionth. The discs then overlap by
    more than rounding can reach, so every SAT axis does too (each box's projection holds its disc's)."""
    return 0.5 * (min(size) + np.minimum(length, width)) * (1.0 - 1e-6)  # type: ignore[no-any-return]
