"""The numbers behind :mod:`coster_sumo.exports.opendrive_fit`: SUMO shapes in a reference line's
frame, lane borders solved from wanted lane centres, curves simplified into OpenDRIVE records.

Frames: a reference line is given by stations ``s`` (S,) [m] along it and its x, y [m] and heading
[rad] at each; a lateral offset ``t`` [m] is positive to the left of the line's direction.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.optimize import nnls
from scipy.spatial import cKDTree

from coster_sumo.exports.opendrive_bend import discrete_curvature

STATION_M = 0.25  # [m] spacing of the stations the borders are solved at
RECORD_TOLERANCE_M = 0.002  # [m] simplification of the border and width curves into records
WIDTH_WEIGHT = 0.02  # least-squares weight of "keep SUMO's width" against "keep the centre" (1)
FILLER_WEIGHT = 0.001  # ... and of "no room between two lanes"
END_TOLERANCE_M = 0.05  # [m] a SUMO point further than this beyond a reference line's end is outside it
PROJECTION_ITERATIONS = 4
SMOOTH_WINDOW_M = 4.0  # [m] averaging window of a road's reference line (WOMD lanes jitter)
REFERENCE_STEP_M = 2.0  # [m] length of the cubic pieces of a road's reference line
TANGENT_M = 0.25  # [m] the heading at the ends of a road of one piece: its polyline's direction over this much
MIN_WIDTH_M = 0.01  # [m] narrowest a lane with a SUMO shape gets (readers take a 0 width for no lane)
# [m] lanes that start or end closer together than this do so together: pyxodr samples a road every
# 0.1 m and fails on a lane section with fewer than two samples; commonroad makes a lanelet of no
# area of a section of millimetres
MIN_SECTION_M = 0.25
# [-] a road's reference line is its longest lane's unless a lane border beside it would turn at
# this fold ratio or tighter (reference_axis; opendrive_bend.FOLD_RATIO for connecting roads)
AXIS_FOLD_RATIO = 0.9
MERGE_SLOPE = 1e-6  # [-] a record whose slope and start value continue the one before within these
MERGE_VALUE_M = 1e-5  # [m] is left out (at most 0.1 mm off over 100 m; records are written to 8 digits)


def project(ref_x: np.ndarray, ref_y: np.ndarray, ref_h: np.ndarray, s: np.ndarray, shape: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray] | None:
    """A SUMO shape (K, 2) in the frame of a reference line sampled at stations ``s`` (S,) (x, y,
    heading at each): station [m] and lateral offset [m] (left positive) of its points (the shape
    every :data:`STATION_M`) beside the line, in station order (None: fewer than two)."""
    pts = shapely.get_coordinates(shapely.segmentize(shapely.LineString(shape), STATION_M))
    sp, t, along = station_of(ref_x, ref_y, ref_h, s, pts)
    # beside the line: on a normal (a point beyond an end stays off it; so does one where the
    # normals of a tight wiggle cross before reaching it)
    ok = np.abs(along) <= END_TOLERANCE_M
    if ok.sum() < 2:
        return None
    order = np.argsort(sp[ok], kind="stable")
    return sp[ok][order], t[ok][order]


def station_of(ref_x: np.ndarray, ref_y: np.ndarray, ref_h: np.ndarray, s: np.ndarray, pts: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Station [m], lateral offset [m] and the remaining along offset [m] (0 where the point is
    beside the line) of points (P, 2).

    OpenDRIVE offsets a lane along the normal of the line's heading, which is not quite the normal
    of the sampled polyline: starting from the nearest polyline point, each station moves until
    the point lies on its heading's normal.
    """
    sp = locate(ref_x, ref_y, s, pts)
    for _ in range(PROJECTION_ITERATIONS):
        along, _, _, _ = _frame(ref_x, ref_y, ref_h, s, sp, pts)
        sp = np.clip(sp + along, s[0], s[-1])
    along, t, _, _ = _frame(ref_x, ref_y, ref_h, s, sp, pts)
    return sp, t, along


def _frame(ref_x: np.ndarray, ref_y: np.ndarray, ref_h: np.ndarray, s: np.ndarray, sp: np.ndarray, pts: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Along and lateral offsets [m] of points (P, 2) from the line at stations ``sp`` (P,), and the
    line's unit direction there (x, y)."""
    hx, hy = np.interp(sp, s, ref_x), np.interp(sp, s, ref_y)
    # heading at the station: interpolate the unit vector (headings wrap)
    cx, cy = np.interp(sp, s, np.cos(ref_h)), np.interp(sp, s, np.sin(ref_h))
    norm = np.hypot(cx, cy)
    cx, cy = cx / norm, cy / norm
    dx, dy = pts[:, 0] - hx, pts[:, 1] - hy
    return dx * cx + dy * cy, -dx * cy + dy * cx, cx, cy


def locate(ref_x: np.ndarray, ref_y: np.ndarray, s: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(P,) station [m] of the point of the reference polyline (stations ``s`` (S,) at ``ref_x``,
    ``ref_y``) nearest to each point (P, 2): nearest station, then the better of its two segments."""
    ref = np.column_stack([ref_x, ref_y])
    _, i = cKDTree(ref).query(pts)
    best_s = s[i].astype(np.float64)
    best_d = np.hypot(*(pts - ref[i]).T)
    for lo in (i - 1, i):  # segment (lo, lo + 1)
        ok = (lo >= 0) & (lo + 1 < len(s))
        a, b = ref[np.clip(lo, 0, len(s) - 1)], ref[np.clip(lo + 1, 0, len(s) - 1)]
        ab = b - a
        ll = np.maximum((ab ** 2).sum(axis=1), 1e-18)
        u = np.clip(((pts - a) * ab).sum(axis=1) / ll, 0.0, 1.0)
        d = np.hypot(*(pts - a - u[:, None] * ab).T)
        seg_s = s[np.clip(lo, 0, len(s) - 1)] + u * (s[np.clip(lo + 1, 0, len(s) - 1)] - s[np.clip(lo, 0, len(s) - 1)])
        better = ok & (d < best_d)
        best_s[better], best_d[better] = seg_s[better], d[better]
    return best_s


def extent(ref_x: np.ndarray, ref_y: np.ndarray, ref_h: np.ndarray, s: np.ndarray, shape: np.ndarray
            ) -> tuple[float, float] | None:
    """First and last station [m] of a SUMO shape beside a reference line (None: not beside it)."""
    if len(shape) < 2:
        return None
    got = project(ref_x, ref_y, ref_h, s, shape)
    return None if got is None else (float(got[0][0]), float(got[0][-1]))


def lateral(ref_x: np.ndarray, ref_y: np.ndarray, ref_h: np.ndarray, s: np.ndarray, shape: np.ndarray,
            ends: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The lateral offset [m] of a SUMO shape at each station (S,) and whether it covers it:
    between ``ends`` (its :func:`extent`, computed once: where its end stations were put), else
    between its first and last station here."""
    got = project(ref_x, ref_y, ref_h, s, shape)
    if got is None:
        return None
    sk, tk = got
    first, last = ends if ends is not None else (float(sk[0]), float(sk[-1]))
    # a shape that reaches an end of the line to within END_TOLERANCE_M covers it to that end
    first = s[0] if first <= s[0] + END_TOLERANCE_M else first
    last = s[-1] if last >= s[-1] - END_TOLERANCE_M else last
    covered = (s >= first - 1e-6) & (s <= last + 1e-6)
    return np.interp(s, sk, tk), covered


def runs_of(present: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) station index of each run of stations where the same lanes are present
    (``present`` (S, n) bool)."""
    change = np.flatnonzero((present[1:] != present[:-1]).any(axis=1)) + 1
    starts = np.concatenate([[0], change])
    return list(zip(starts.tolist(), (np.append(change, len(present)) - 1).tolist(), strict=True))


def merge_short_runs(s: np.ndarray, present: np.ndarray, min_m: float = MIN_SECTION_M) -> np.ndarray:
    """``present`` (S, n) with every run of stations shorter than ``min_m`` [m] (up to the next
    run's start) given the lanes of the run before it (the first run: of the one after), so that
    lanes that start or end within ``min_m`` of each other start or end together (a lane moves its
    start or end by less than ``min_m``; see :data:`MIN_SECTION_M` for why). On a road shorter than
    twice ``min_m`` every run is short and merging would drop a lane that covers only part of it
    (two SUMO lanes of 0.2 m, 0.12 m apart along the road): there every lane present anywhere is
    present throughout."""
    if s[-1] - s[0] < 2 * min_m:
        return np.repeat(np.any(present, axis=0, keepdims=True), len(s), axis=0)
    out = present.copy()
    while True:
        runs = runs_of(out)
        if len(runs) < 2:
            return out
        ends = [s[r[1] + 1] if r[1] + 1 < len(s) else s[-1] for r in runs]
        short = [k for k, (r, e) in enumerate(zip(runs, ends, strict=True)) if e - s[r[0]] < min_m]
        if not short:
            return out
        k = short[0]
        i, j = runs[k]
        out[i:j + 1] = out[runs[k - 1][0]] if k > 0 else out[runs[1][0]]


def solve_borders(centres: np.ndarray, present: np.ndarray, widths: np.ndarray, fillers: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left border and lane widths at each station from the wanted lane centres.

    Args:
        centres: (S, n) float64 [m] wanted centre offsets (left positive), lane -1 first.
        present: (S, n) bool, the lane has a SUMO shape at the station (else its width is 0).
        widths: (n,) float64 [m] SUMO widths.
        fillers: a filler lane between each two neighbours takes up the room between them (else
            lanes touch).

    Returns:
        ``offset`` (S,) [m] the left border (``laneOffset``), ``width`` (S, n) [m] and ``filler``
        (S, n - 1) [m] (zeros without fillers), widths >= :data:`MIN_WIDTH_M` where the lane is
        present, 0 where not, fillers >= 0; centre = offset - widths of the lanes
        and fillers before - half its own width; solved in least squares: centres weight 1, widths
        towards SUMO's (:data:`WIDTH_WEIGHT`), fillers towards 0 (:data:`FILLER_WEIGHT`).
    """
    n_st, n = centres.shape
    nf = n - 1 if fillers else 0
    offset = np.zeros(n_st)
    width = np.zeros((n_st, n))
    filler = np.zeros((n_st, max(n - 1, 0)))
    prev = 0.0
    for i in range(n_st):
        idx = np.flatnonzero(present[i])
        if len(idx) == 0:
            offset[i] = prev
            continue
        m = len(idx)
        base = centres[i, idx[0]] + widths[idx[0]] / 2  # expected left border: shifted by p - q
        cols = 2 + m + nf  # p, q, present lanes' widths, fillers
        a = np.zeros((2 * m + 2 + nf, cols))
        rhs = np.zeros(len(a))
        # a present lane's width is MIN_WIDTH_M + its variable (a lane squeezed to nothing between
        # two neighbours still has a centre, and a zero width means "no lane here")
        for r in range(m):  # centre rows: base + p - q - sum(w, f before) - w / 2 = c
            a[r, 0], a[r, 1] = 1.0, -1.0
            a[r, 2:2 + r] = -1.0
            a[r, 2 + r] = -0.5
            a[r, 2 + m:2 + m + min(int(idx[r]), nf)] = -1.0  # fillers 1..k-1 lie before lane k
            rhs[r] = centres[i, idx[r]] - base + (r + 0.5) * MIN_WIDTH_M
        for r in range(m):  # width rows
            a[m + r, 2 + r] = WIDTH_WEIGHT
            rhs[m + r] = WIDTH_WEIGHT * (widths[idx[r]] - MIN_WIDTH_M)
        a[2 * m, 0] = a[2 * m + 1, 1] = WIDTH_WEIGHT  # p, q towards 0
        for j in range(nf):  # fillers towards 0, weaker: room between lanes rather than odd widths
            a[2 * m + 2 + j, 2 + m + j] = FILLER_WEIGHT
        x, _ = nnls(a, rhs)
        offset[i] = prev = base + x[0] - x[1]
        width[i, idx] = x[2:2 + m] + MIN_WIDTH_M
        filler[i, :nf] = x[2 + m:]
    return offset, width, filler


def centre_error(centres: np.ndarray, present: np.ndarray, offset: np.ndarray, width: np.ndarray,
                 filler: np.ndarray) -> float:
    """[m] largest distance between a wanted centre and the solved one over the present lanes."""
    n = width.shape[1]
    left = offset.copy()
    worst = 0.0
    for k in range(n):
        got = left - width[:, k] / 2
        if present[:, k].any():
            worst = max(worst, float(np.abs(got - centres[:, k])[present[:, k]].max()))
        left = left - width[:, k] - (filler[:, k] if k < n - 1 else 0.0)
    return worst


def simplify(s: np.ndarray, v: np.ndarray, tol: float = RECORD_TOLERANCE_M) -> np.ndarray:
    """Indices of the breakpoints of a piecewise-linear curve through (s, v) (S,) within ``tol``
    of every sample (Ramer-Douglas-Peucker on the values)."""
    keep = np.zeros(len(s), bool)
    keep[[0, -1]] = True
    stack = [(0, len(s) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        k = np.arange(i + 1, j)
        line = v[i] + (v[j] - v[i]) * (s[k] - s[i]) / max(s[j] - s[i], 1e-12)
        err = np.abs(v[k] - line)
        worst = int(np.argmax(err))
        if err[worst] > tol:
            mid = int(k[worst])
            keep[mid] = True
            stack += [(i, mid), (mid, j)]
    return np.flatnonzero(keep)


def records(s: np.ndarray, v: np.ndarray, runs: list[tuple[int, int]]) -> list[tuple[float, float, float]]:
    """(s, value, slope) of each piece of the curve through (s, v), simplified run by run: a run
    (first, last) is a stretch of stations where the same lanes are present; the curve may jump
    between runs (a lane starting makes the borders outside it jump by its width)."""
    out = []
    for i, j in runs:
        br = i + simplify(s[i:j + 1], v[i:j + 1])
        if len(br) == 1:
            out.append((float(s[i]), float(v[i]), 0.0))
        for a, b in zip(br[:-1], br[1:], strict=True):
            ds = s[b] - s[a]
            out.append((float(s[a]), float(v[a]), float((v[b] - v[a]) / ds) if ds > 0 else 0.0))
    merged = out[:1]
    for rec in out[1:]:  # a piece that only continues the one before says nothing new
        s0, a0, b0 = merged[-1]
        # (readers count two records that agree to 1e-6 in value and slope as one declared twice)
        if abs(rec[2] - b0) <= MERGE_SLOPE and abs(a0 + b0 * (rec[0] - s0) - rec[1]) <= MERGE_VALUE_M:
            continue
        merged.append(rec)
    return merged




def smooth_polyline(shape: np.ndarray, window_m: float = SMOOTH_WINDOW_M, step: float = 0.5) -> np.ndarray:
    """(K, 2) a polyline (N, 2) resampled every ``step`` m and averaged over ``window_m``; its ends
    stay where they were: near an end the window shrinks to what lies between the point and that
    end on either side, so that the line also leaves its ends in their own direction (a window
    running over the line mirrored through an end turned an end in a curve of curvature k by
    k x window / 4: 0.4 rad on a WOMD lane turning on 2.5 m)."""
    line = shapely.LineString(shape)
    length = float(line.length)
    if length < 1e-6:
        return np.asarray(shape, np.float64)[[0, -1]]
    n = max(int(np.ceil(length / step)), 1)
    pts = shapely.get_coordinates(shapely.line_interpolate_point(line, np.linspace(0.0, length, n + 1)))
    half = int(round(window_m / step)) // 2
    half = min(half, len(pts) - 1)
    if half < 1:
        return pts
    i = np.arange(len(pts))
    r = np.minimum(np.minimum(i, len(pts) - 1 - i), half)  # each point's window: i - r .. i + r
    cum = np.concatenate([np.zeros((1, 2)), np.cumsum(pts, axis=0)])
    return (cum[i + r + 1] - cum[i - r]) / (2 * r + 1)[:, None]


def reference_axis(shapes: list[np.ndarray], widths: np.ndarray) -> np.ndarray:
    """(K, 2) [m] the smoothed polyline (:func:`smooth_polyline`) a normal road's reference line
    follows: its longest lane's (``shapes`` (N_k, 2) [m], ``widths`` (n,) [m]); where a lane border
    would turn about that line at :data:`AXIS_FOLD_RATIO` or tighter (:func:`border_fold`: a WOMD
    road 23 m wide whose lanes turn 0.5 rad together, the line on its outermost lane), the lane's
    whose borders turn least about theirs (the longer on a tie)."""
    order = sorted(range(len(shapes)), key=lambda k: -float(np.hypot(*np.diff(shapes[k], axis=0).T).sum()))
    best: tuple[float, np.ndarray] | None = None
    for k in order:
        if len(shapes[k]) < 2:
            continue
        axis = smooth_polyline(shapes[k])
        fold = border_fold(axis, shapes, widths)
        if best is None and fold < AXIS_FOLD_RATIO:
            return axis
        if best is None or fold < best[0]:
            best = (fold, axis)
    return best[1] if best is not None else smooth_polyline(shapes[0])


def border_fold(axis: np.ndarray, shapes: list[np.ndarray], widths: np.ndarray) -> float:
    """[-] the largest fold ratio of a lane border about a reference polyline ``axis`` (K, 2) [m]:
    curvature times the border's lateral offset (1: the border stops, beyond it runs backwards;
    :mod:`~coster_sumo.exports.opendrive_bend`), over the stations each lane of ``shapes`` covers."""
    if len(axis) < 3:
        return 0.0
    d = np.diff(axis, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    h = np.append(h, h[-1])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*d.T))])
    k = discrete_curvature(axis)
    worst = 0.0
    for shape, width in zip(shapes, widths, strict=True):
        got = lateral(axis[:, 0], axis[:, 1], h, s, shape) if len(shape) >= 2 else None
        if got is not None and got[1].any():
            t, covered = got  # the border on the inner side of the turn
            worst = max(worst, float((k * t + np.abs(k) * 0.5 * float(width))[covered].max()))
    return worst


def hermite_pieces(points: np.ndarray, step: float = REFERENCE_STEP_M) -> list[dict[str, float]]:
    """A smooth curve through a polyline (N, 2), resampled about every ``step`` m: one cubic
    (OpenDRIVE paramPoly3, normalised range) per piece, tangents continuous at the joints. Each
    piece: x, y, hdg [rad] of its start, length [m] (arc length), aU..dV."""
    line = shapely.LineString(points)
    length = float(line.length)
    n = max(int(np.ceil(length / step)), 1)
    at = np.linspace(0.0, length, n + 1)
    pts = shapely.get_coordinates(shapely.line_interpolate_point(line, at))
    if n > 1:
        d = np.gradient(pts, axis=0)
    else:
        # a road of one piece: the polyline's own direction at its two ends, over TANGENT_M (the
        # chord between them drew a short road on a tight turn as a straight line, its lanes
        # meeting the next roads at an angle as large as half its turn)
        reach = min(TANGENT_M, length / 4)
        ahead = shapely.get_coordinates(shapely.line_interpolate_point(line, np.minimum(at + reach, length)))
        behind = shapely.get_coordinates(shapely.line_interpolate_point(line, np.maximum(at - reach, 0.0)))
        d = ahead - behind
    heading = np.arctan2(d[:, 1], d[:, 0])
    return cubic_pieces(pts, heading, samples=32)


def cubic_pieces(points: np.ndarray, heading: np.ndarray, samples: int) -> list[dict[str, float]]:
    """One parametric cubic (paramPoly3, normalised parameter) per segment of ``points`` (N, 2) [m],
    leaving point i at ``heading[i]`` and reaching point i+1 at ``heading[i+1]`` [rad]; each piece's
    arc length integrated with the trapezoid rule over ``samples`` steps of its parameter."""
    out = []
    for i in range(len(points) - 1):
        h0 = heading[i]
        c, sn = np.cos(h0), np.sin(h0)
        dx, dy = points[i + 1] - points[i]
        u1, v1 = c * dx + sn * dy, -sn * dx + c * dy  # end point in the start's frame
        chord = float(np.hypot(u1, v1))
        turn = (heading[i + 1] - h0 + np.pi) % (2 * np.pi) - np.pi
        cu, su = chord * np.cos(turn), chord * np.sin(turn)
        coef = {"aU": 0.0, "bU": chord, "cU": 3 * u1 - 2 * chord - cu, "dU": -2 * u1 + chord + cu,
                "aV": 0.0, "bV": 0.0, "cV": 3 * v1 - su, "dV": -2 * v1 + su}
        q = np.linspace(0.0, 1.0, samples + 1)
        du = coef["bU"] + 2 * coef["cU"] * q + 3 * coef["dU"] * q ** 2
        dv = 2 * coef["cV"] * q + 3 * coef["dV"] * q ** 2
        speed = np.hypot(du, dv)
        arc = float(np.sum((speed[1:] + speed[:-1]) / 2) / samples)
        out.append({"x": float(points[i, 0]), "y": float(points[i, 1]), "hdg": float(h0), "length": arc, **coef})
    return out


def hermite_through(points: np.ndarray, start_heading: float, end_heading: float,
                    min_step: float = 0.01) -> list[dict[str, float]]:
    """Cubic pieces (as :func:`hermite_pieces`) through every point of a polyline (N, 2) (points
    closer than ``min_step`` [m] to the previous one dropped), leaving the first point at
    ``start_heading`` and reaching the last at ``end_heading`` [rad]; inside, each point's tangent
    is the direction from its predecessor to its successor, so the heading is continuous at every
    joint of two pieces."""
    pts = [np.asarray(points[0], np.float64)]
    for p in np.asarray(points, np.float64)[1:]:
        if np.hypot(*(p - pts[-1])) >= min_step:
            pts.append(p)
    if len(pts) < 2:  # everything within min_step: one piece to the last point
        pts.append(np.asarray(points[-1], np.float64))
    elif np.hypot(*(np.asarray(points[-1]) - pts[-1])) > 0:
        pts[-1] = np.asarray(points[-1], np.float64)  # end exactly at the last point
    p = np.stack(pts)
    heading = np.empty(len(p))
    heading[0], heading[-1] = start_heading, end_heading
    if len(p) > 2:
        d = p[2:] - p[:-2]
        heading[1:-1] = np.arctan2(d[:, 1], d[:, 0])
    return cubic_pieces(p, heading, samples=64)
