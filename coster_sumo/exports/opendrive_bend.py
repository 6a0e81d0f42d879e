"""Connecting roads whose lane's inner border does not fold back where they turn.

A lane border lies at a lateral offset ``t`` (left positive) from a road's reference line; where
the line turns with curvature ``k`` [1/m] (left positive), the border moves forward at ``1 - k t``
times the line's speed. Where ``k t`` reaches 1 the border stops, beyond it runs backwards: the
lane's outline crosses itself (a folded border; readers that build lane polygons, such as
commonroad-scenario-designer, get an invalid polygon). For a lane centred on its connecting road's
reference line: where half its width times the curvature (the *fold ratio*) reaches 1.

Two causes, measured on the exports of ``docs/sumo.md §12a``:

- the **fit** (most): the curve through every point of the connecting road's SUMO polyline
  (:func:`~coster_sumo.exports.opendrive_solve.hermite_through`) leaves its contacts at the linked
  lanes' headings; where the polyline leaves at another angle (netconvert's internal lanes, a few
  degrees; logged WOMD lanes, up to 0.4 rad) or its next point lies a centimetre from the contact,
  one short cubic piece takes the heading back within centimetres (radii down to 0.01 m), and the
  tangents of unevenly spaced points make cubic pieces overshoot. :func:`smooth_path` draws a curve
  along the polyline that bends no tighter than the lane can follow wherever that is possible;
- the **geometry**: where the contacts' positions and headings and the lane's width leave no room
  (a connecting road of 0.6-2 m that turns by 0.4-1 rad with a lane 3.2-5.5 m wide: SUMO's corner
  lanes on game/grid6, logged WOMD lanes wider than the diameter of their turn), every curve
  between the two contacts folds; :func:`fold_ratio` tells which. There the lane may narrow where
  it turns (:func:`bend` with ``narrow``, :func:`untangle`), keeping the linked lanes' widths at
  the contacts; only where the contacts leave no room for that either does the lane fold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FOLD_RATIO = 0.9  # [-] the fold ratio smooth_path keeps below where it can (1: the border stops)
PATH_STEP_M = 0.25  # [m] spacing of the points of a connecting road's smoothed centre line
MIN_POINTS = 12  # ... at least this many steps (a short turn needs room to spread its bending)
# A finer grid for short roads where no curve on the default one keeps the lane whole: a lane
# 3-4 m wide moving 4.6 m sideways within 2.8 m (a converted fokr_bs_demo junction) needs turns of
# under 0.5 m radius, which points 0.44 m apart cannot draw. Its cost grows with the cube of the
# points (one dense solve a round), so only roads up to FINE_MAX_M get it.
FINE_STEP_M = 0.05  # [m]
FINE_MIN_POINTS = 48
FINE_MAX_M = 12.0  # [m]
BASE_STIFFNESS = 1e-4  # [m^4] bending weight against 1 for the squared distance to a SUMO vertex
MAX_STIFFNESS = 1e3  # [m^4] ... its ceiling (the vertices no longer count; the system stays well conditioned)
STIFFEN = 10.0  # [-] most the bending weight grows (or shrinks) in one round
STIFFEN_ROUNDS = 30
STIFFEN_SPREAD = 2  # points on each side of a folding point that share its need
TAPER = 1.0  # [-] most a narrowed lane's half width changes per metre along its road
MIN_HALF_WIDTH_M = 0.9  # [m] no lane is narrowed below twice this
# Where even that folds (a U-turn of 4.7 m, the length of a half circle of radius 1.5 m, by a lane
# 3.2 m wide: SUMO's turnarounds on the corpus nets' cuts), the lane may narrow this fast and this far:
# a narrower lane that readers can build, rather than one whose outline crosses itself.
TIGHT_TAPER = 4.0  # [-]
TIGHT_MIN_HALF_WIDTH_M = 0.3  # [m]


@dataclass(frozen=True)
class Narrowing:
    """How a lane may narrow where its curve turns: by at most ``taper`` [m per m] of half width,
    down to ``min_half_m`` [m] (half its width)."""

    taper: float = TAPER
    min_half_m: float = MIN_HALF_WIDTH_M


NARROW = Narrowing()
TIGHT = Narrowing(TIGHT_TAPER, TIGHT_MIN_HALF_WIDTH_M)


def discrete_curvature(p: np.ndarray) -> np.ndarray:
    """(N,) [1/m] signed curvature (left positive) of a polyline (N, 2) at each point: the turn
    between its two segments over their mean length (0 at the two ends)."""
    a, b = p[1:-1] - p[:-2], p[2:] - p[1:-1]
    turn = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(axis=1))
    mean = np.maximum(0.5 * (np.hypot(*a.T) + np.hypot(*b.T)), 1e-12)
    return np.concatenate([[0.0], turn / mean, [0.0]])


def smooth_path(points: np.ndarray, start_heading: float, end_heading: float, start_width: float,
                end_width: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`bend` with the lane's width changing linearly (its points and headings)."""
    p, heading, _ = bend(points, start_heading, end_heading, start_width, end_width)
    return p, heading


def narrowed_half_width(s: np.ndarray, tight: np.ndarray, start_width: float, end_width: float,
                        narrowing: Narrowing = NARROW) -> np.ndarray:
    """(N,) [m] half a lane's width at stations ``s`` (N,) [m] of a curve whose |curvature| there is
    ``tight`` (N,) [1/m]: the width that changes linearly from ``start_width`` to ``end_width``,
    narrowed where the curve turns tighter than that lane could follow (to :data:`FOLD_RATIO`
    over the curvature, not below ``narrowing.min_half_m``), changing by no more than
    ``narrowing.taper`` per metre, and the two given widths kept at the ends (the linked lanes')."""
    taper = narrowing.taper
    lin = 0.5 * (start_width + (end_width - start_width) * s / max(float(s[-1]), 1e-12))
    room = np.maximum((1.0 - 1e-9) * FOLD_RATIO / np.maximum(tight, 1e-12), narrowing.min_half_m)
    want = np.minimum(lin, room)
    # the widest profile below `want` that changes by at most `taper` per metre ...
    below = (want[None, :] + taper * np.abs(s[:, None] - s[None, :])).min(axis=1)
    # ... and that reaches the linked lanes' widths at both ends
    ends = np.maximum(lin[0] - taper * s, lin[-1] - taper * (s[-1] - s))
    return np.minimum(lin, np.maximum(below, ends))


def _clamped_system(pts: np.ndarray, sigma: np.ndarray, s: np.ndarray, step: float, start_heading: float,
                    end_heading: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The linear pieces of :func:`bend`'s least squares over the points 0..n at stations ``s``
    (n + 1,) [m], ``step`` apart, along a polyline ``pts`` (V + 2, 2) [m] whose vertices lie at arc
    lengths ``sigma``: ``basis`` (n + 3, n - 1) and ``const`` (n + 3, 2), so that ``basis @ x + const``
    are the points with one before and one after (clamped ends) for x the free points 1..n-1;
    ``at`` (V, n + 3), the curve at each inner vertex; ``d2`` (n + 1, n + 3), second differences / step^2.
    """
    n = len(s) - 1
    t0 = np.array([np.cos(start_heading), np.sin(start_heading)])
    t1 = np.array([np.cos(end_heading), np.sin(end_heading)])
    # e: the points 0..n with a point before and after, placed so that the central difference at
    # each end runs along its heading (a clamped end): e = basis @ x + const, x the points 1..n-1
    m = n - 1
    basis = np.zeros((n + 3, m))
    basis[2:n + 1] = np.eye(m)
    basis[0, 0] = basis[n + 2, m - 1] = 1.0
    const = np.zeros((n + 3, 2))
    const[1], const[n + 1] = pts[0], pts[-1]
    const[0], const[n + 2] = -2.0 * step * t0, 2.0 * step * t1
    # the curve at each inner vertex: linear between the two grid points around it (V, n + 3)
    inner = sigma[1:-1]
    j = np.clip(np.searchsorted(s, inner, side="right") - 1, 0, n - 1) + 1
    f = (inner - s[j - 1]) / step
    at = np.zeros((len(inner), n + 3))
    at[np.arange(len(inner)), j] += 1.0 - f
    at[np.arange(len(inner)), j + 1] += f
    # second differences / step^2 at the points 0..n: (n + 1, n + 3)
    d2 = np.zeros((n + 1, n + 3))
    rows = np.arange(n + 1)
    d2[rows, rows], d2[rows, rows + 1], d2[rows, rows + 2] = 1.0, -2.0, 1.0
    d2 /= step ** 2
    return basis, const, at, d2


def bend(points: np.ndarray, start_heading: float, end_heading: float, start_width: float,
         end_width: float, narrow: Narrowing | None = None, step_m: float = PATH_STEP_M,
         min_points: int = MIN_POINTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A connecting road's centre line along its polyline (N, 2) [m] (first and last point: the
    contacts with its two lanes), leaving the first point at ``start_heading`` and reaching the last
    at ``end_heading`` [rad], bending no tighter than its lane's border can follow.

    Points p every ``step_m`` (at least ``min_points`` + 1 of them) along the polyline minimise the
    squared distances from the polyline's inner vertices to the curve plus
    sum mu_i |second difference_i / step^2|^2 (the squared curvature), the two contacts held and
    the ends clamped to their headings (the points one step outside each end lie so that the
    central difference there runs along the heading):
    with a small mu (:data:`BASE_STIFFNESS`) a smooth curve through the vertices. Where the
    curvature of the points or of the cubic pieces written between them, times half the lane's width
    (changing linearly between the two lanes'), exceeds :data:`FOLD_RATIO`, mu grows (by up to
    :data:`STIFFEN` a round, up to :data:`MAX_STIFFNESS`); where the lane has room it shrinks back:
    the curve keeps to the SUMO shape except where a lane that wide could not follow it.

    With ``narrow``, the lane may also narrow where the curve turns, as far and as fast as it says
    (:func:`narrowed_half_width`),
    and the curve stiffens only where that is not enough (near the two contacts, which keep the
    linked lanes' widths).

    Returns the points (K, 2) [m], the heading [rad] at each (the two given ones at the ends), for
    :func:`~coster_sumo.exports.opendrive_solve.cubic_pieces`, and half the lane's width at each [m].
    """
    origin = np.asarray(points[0], np.float64)
    pts = np.asarray(points, np.float64) - origin  # (WOMD coordinates are kilometres: keep digits)
    sigma = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])  # arc length of each vertex
    length = float(sigma[-1])
    n = max(int(np.ceil(length / step_m)), min_points)
    step = max(length / n, 1e-6)
    s = np.linspace(0.0, length, n + 1)
    basis, const, at, d2 = _clamped_system(pts, sigma, s, step, start_heading, end_heading)
    e = const.copy()
    half = 0.5 * (start_width + (end_width - start_width) * s / max(length, 1e-12))  # (n + 1,) [m]
    mu = np.full(n + 1, BASE_STIFFNESS)
    at_x, d2_x = at @ basis, d2 @ basis
    data_lhs = at_x.T @ at_x
    data_rhs = at_x.T @ (pts[1:-1] - at @ const)
    d2_const = d2 @ const
    heading = np.zeros(n + 1)
    ratio = np.zeros(n + 1)
    for _ in range(STIFFEN_ROUNDS):
        x = np.linalg.solve(data_lhs + d2_x.T @ (mu[:, None] * d2_x), data_rhs - d2_x.T @ (mu[:, None] * d2_const))
        e = basis @ x + const
        p = e[1:-1]
        heading = _headings(p, start_heading, end_heading)
        # the pieces written, not only the points, must bend no tighter (a cubic between two points
        # overshoots where the curvature changes fast): each point takes the tighter of its two pieces
        piece = piece_curvature(p, heading)  # (n,)
        tight = np.maximum(np.abs(discrete_curvature(e)[1:-1]),
                           np.maximum(np.append(piece, 0.0), np.insert(piece, 0, 0.0)))
        if narrow is not None:
            half = narrowed_half_width(s, tight, start_width, end_width, narrow)
        ratio = tight * half / FOLD_RATIO  # (n + 1,) above 1: folds
        if not (ratio > 1.0).any():
            break
        # stiffer where the lane would fold, softer where it has room: the bending moves to where
        # the lane can take it
        need = np.convolve(ratio, np.ones(2 * STIFFEN_SPREAD + 1), "same") / (2 * STIFFEN_SPREAD + 1)
        worst = np.maximum(need, ratio)
        mu = np.clip(mu * np.clip(worst ** 2, 1.0 / STIFFEN, STIFFEN), BASE_STIFFNESS, MAX_STIFFNESS)
    return e[1:-1] + origin, heading, half


def outline(pieces: list[dict[str, float]], half: np.ndarray, samples: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The closed outline (2 K, 2) [m] of a lane centred on cubic pieces (``cubic_pieces``' dicts)
    whose half width changes linearly piece by piece between ``half`` (len(pieces) + 1,) [m]: its
    left border forwards, then its right border backwards; and the station [m] of each point."""
    coef = {k: np.array([pc[k] for pc in pieces]) for k in ("x", "y", "hdg", "bU", "cU", "dU", "cV", "dV", "length")}
    q = np.linspace(0.0, 1.0, samples + 1)[:-1, None]  # (Q, 1)
    u = coef["bU"] * q + coef["cU"] * q ** 2 + coef["dU"] * q ** 3
    v = coef["cV"] * q ** 2 + coef["dV"] * q ** 3
    du, dv = coef["bU"] + 2 * coef["cU"] * q + 3 * coef["dU"] * q ** 2, 2 * coef["cV"] * q + 3 * coef["dV"] * q ** 2
    c, sn = np.cos(coef["hdg"]), np.sin(coef["hdg"])
    x, y = coef["x"] + c * u - sn * v, coef["y"] + sn * u + c * v  # (Q, pieces)
    h = coef["hdg"] + np.arctan2(dv, du)
    w = half[:-1] + q * (half[1:] - half[:-1])
    st = np.concatenate([[0.0], np.cumsum(coef["length"])])
    at = st[:-1] + q * coef["length"]
    last = pieces[-1]
    end_x, end_y = piece_points([last], 1)[-1]
    end_h = last["hdg"] + np.arctan2(2 * last["cV"] + 3 * last["dV"], last["bU"] + 2 * last["cU"] + 3 * last["dU"])
    cx, cy = np.append(x.T.reshape(-1), end_x), np.append(y.T.reshape(-1), end_y)
    hh, ww = np.append(h.T.reshape(-1), end_h), np.append(w.T.reshape(-1), half[-1])
    ss = np.append(at.T.reshape(-1), st[-1])
    nx, ny = -np.sin(hh), np.cos(hh)
    left = np.column_stack([cx + ww * nx, cy + ww * ny])
    right = np.column_stack([cx - ww * nx, cy - ww * ny])
    return np.vstack([left, right[::-1]]), np.concatenate([ss, ss[::-1]])


def crossings(ring: np.ndarray) -> np.ndarray:
    """(C, 2) indices of the first points of each two segments of a closed ring (N, 2) that cross
    (segments that share a point left out)."""
    a, b = ring, np.roll(ring, -1, axis=0)
    n = len(ring)
    i, j = np.triu_indices(n, 2)
    keep = ~((i == 0) & (j == n - 1))
    i, j = i[keep], j[keep]

    def side(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    d1, d2 = side(a[i], b[i], a[j]), side(a[i], b[i], b[j])
    d3, d4 = side(a[j], b[j], a[i]), side(a[j], b[j], b[i])
    cross = (d1 * d2 < 0) & (d3 * d4 < 0)
    return np.column_stack([i[cross], j[cross]])


def untangle(pieces: list[dict[str, float]], half: np.ndarray, start_width: float, end_width: float,
             narrowing: Narrowing = NARROW, rounds: int = 20) -> np.ndarray | None:
    """Half widths (len(pieces) + 1,) [m] at the pieces' ends, narrowed further (within
    ``narrowing``, the two ends kept) until the lane's outline (:func:`outline`) crosses itself nowhere:
    a lane wider than the diameter of a sharp turn crosses its own inner border between the
    stretches before and after the turn, also where no border folds. None where that cannot be
    done."""
    s = np.concatenate([[0.0], np.cumsum([pc["length"] for pc in pieces])])
    lin = 0.5 * (start_width + (end_width - start_width) * s / max(float(s[-1]), 1e-12))
    half = half.copy()
    for _ in range(rounds):
        ring, at = outline(pieces, half)
        hit = crossings(ring)
        if len(hit) == 0:
            return half
        lo, hi = float(at[hit].min()), float(at[hit].max())
        want = np.where((s >= lo - 0.5) & (s <= hi + 0.5), np.maximum(0.8 * half, narrowing.min_half_m), half)
        below = (want[None, :] + narrowing.taper * np.abs(s[:, None] - s[None, :])).min(axis=1)
        ends = np.maximum(lin[0] - narrowing.taper * s, lin[-1] - narrowing.taper * (s[-1] - s))
        new = np.minimum(half, np.maximum(below, ends))
        if np.allclose(new, half):
            return None
        half = new
    return None


def _headings(p: np.ndarray, start_heading: float, end_heading: float) -> np.ndarray:
    """(N,) [rad] the heading at each point of a polyline (N, 2) (N >= 3): the tangents of the
    cubic spline through the points with continuous curvature (uniform parameter, its ends clamped
    to the given headings with the length of their first and last step), so that the cubic pieces
    between the points join without a kink in the curvature either."""
    n = len(p) - 1
    m0 = np.hypot(*(p[1] - p[0])) * np.array([np.cos(start_heading), np.sin(start_heading)])
    mn = np.hypot(*(p[-1] - p[-2])) * np.array([np.cos(end_heading), np.sin(end_heading)])
    # m[i-1] + 4 m[i] + m[i+1] = 3 (p[i+1] - p[i-1]) for the inner points: tridiagonal (n - 1)
    rhs = 3.0 * (p[2:] - p[:-2])
    rhs[0] -= m0
    rhs[-1] -= mn
    lhs = 4.0 * np.eye(n - 1) + np.eye(n - 1, k=1) + np.eye(n - 1, k=-1)
    m = np.linalg.solve(lhs, rhs)
    return np.concatenate([[start_heading], np.arctan2(m[:, 1], m[:, 0]), [end_heading]])


def piece_curvature(points: np.ndarray, heading: np.ndarray, samples: int = 16) -> np.ndarray:
    """(N - 1,) [1/m] the largest |curvature| of each cubic piece that
    :func:`~coster_sumo.exports.opendrive_solve.cubic_pieces` writes between consecutive points
    (N, 2) [m] with these headings (N,) [rad], sampled at ``samples`` + 1 parameters."""
    c, sn = np.cos(heading[:-1]), np.sin(heading[:-1])
    dx, dy = (points[1:] - points[:-1]).T
    u1, v1 = c * dx + sn * dy, -sn * dx + c * dy  # each end in its start's frame
    chord = np.hypot(u1, v1)
    turn = (heading[1:] - heading[:-1] + np.pi) % (2 * np.pi) - np.pi
    cu, su = chord * np.cos(turn), chord * np.sin(turn)
    b_u, c_u, d_u = chord, 3 * u1 - 2 * chord - cu, -2 * u1 + chord + cu
    c_v, d_v = 3 * v1 - su, -2 * v1 + su
    q = np.linspace(0.0, 1.0, samples + 1)[:, None]  # (Q, 1)
    du, dv = b_u + 2 * c_u * q + 3 * d_u * q ** 2, 2 * c_v * q + 3 * d_v * q ** 2
    ddu, ddv = 2 * c_u + 6 * d_u * q, 2 * c_v + 6 * d_v * q
    speed = np.maximum(np.hypot(du, dv), 1e-12)
    return (np.abs(du * ddv - dv * ddu) / speed ** 3).max(axis=0)


def fold_ratio(pieces: list[dict[str, float]], start_width: float, end_width: float, samples: int = 16,
               half: np.ndarray | None = None) -> float:
    """[-] the largest |curvature| x half width over cubic pieces (``cubic_pieces``' dicts) of a lane
    centred on them whose width changes linearly from ``start_width`` to ``end_width`` [m], or
    linearly piece by piece between the half widths ``half`` (len(pieces) + 1,) [m] at their ends
    (1 or more: its inner border folds)."""
    if not pieces:
        return 0.0
    coef = {k: np.array([pc[k] for pc in pieces]) for k in ("bU", "cU", "dU", "cV", "dV", "length")}
    q = np.linspace(0.0, 1.0, samples + 1)[:, None]  # (Q, 1)
    du = coef["bU"] + 2 * coef["cU"] * q + 3 * coef["dU"] * q ** 2
    dv = 2 * coef["cV"] * q + 3 * coef["dV"] * q ** 2
    ddu, ddv = 2 * coef["cU"] + 6 * coef["dU"] * q, 2 * coef["cV"] + 6 * coef["dV"] * q
    k = np.abs(du * ddv - dv * ddu) / np.maximum(np.hypot(du, dv), 1e-12) ** 3  # (Q, pieces)
    s = np.concatenate([[0.0], np.cumsum(coef["length"])])
    at = s[:-1] + q * coef["length"]
    if half is None:
        w = 0.5 * (start_width + (end_width - start_width) * at / max(float(s[-1]), 1e-12))
    else:
        w = half[:-1] + q * (half[1:] - half[:-1])
    return float((k * w).max())


def piece_points(pieces: list[dict[str, float]], samples: int = 8) -> np.ndarray:
    """(len(pieces) x samples + 1, 2) [m] points along cubic pieces (``cubic_pieces``' dicts), each
    at ``samples`` steps of its parameter, and the last piece's end."""
    coef = {k: np.array([pc[k] for pc in pieces]) for k in ("x", "y", "hdg", "bU", "cU", "dU", "cV", "dV")}
    q = np.linspace(0.0, 1.0, samples + 1)[:, None]  # (Q, 1)
    u = coef["bU"] * q + coef["cU"] * q ** 2 + coef["dU"] * q ** 3
    v = coef["cV"] * q ** 2 + coef["dV"] * q ** 3
    c, sn = np.cos(coef["hdg"]), np.sin(coef["hdg"])
    x, y = coef["x"] + c * u - sn * v, coef["y"] + sn * u + c * v  # (Q, pieces)
    pts = np.stack([x[:-1].T.reshape(-1), y[:-1].T.reshape(-1)], axis=1)
    return np.vstack([pts, [[x[-1, -1], y[-1, -1]]]])


def deviation(pieces: list[dict[str, float]], polyline: np.ndarray) -> float:
    """[m] how far cubic pieces and a polyline (N, 2) lie apart: the larger of the farthest point of
    the pieces from the polyline and the farthest vertex of the polyline from the pieces."""
    import shapely

    curve = piece_points(pieces)
    line, drawn = shapely.LineString(polyline), shapely.LineString(curve)
    return float(max(shapely.distance(line, shapely.points(curve)).max(),
                     shapely.distance(drawn, shapely.points(polyline)).max()))

