"""Oriented boxes and polylines: pure batched numpy, no I/O.

Boxes
-----
A box is a ``(..., 5)`` float array ``(cx, cy, heading, length, width)``: centre [m], heading [rad]
counter-clockwise from +x, length along the heading [m], width across it [m]. Use
:func:`make_boxes` to stack separate arrays. Functions taking two boxes broadcast their leading
dimensions against each other (``(N, 1, 5)`` against ``(1, M, 5)`` gives all N x M pairs).

Corner order everywhere is counter-clockwise starting at the front-left corner: front-left,
rear-left, rear-right, front-right.

Separating-axis theorem (SAT): two convex polygons are disjoint iff their projections on one of
their edge normals are disjoint. A rectangle has two distinct edge normals (its heading and the
perpendicular), so four axes decide every pair exactly.

Sign conventions: :func:`box_signed_distance` is > 0 for the Euclidean gap between separated boxes
and < 0 for the penetration depth (minimum translation distance) of overlapping ones.
:func:`boxes_overlap` is strict: boxes that only touch (zero-area contact) do not overlap.

Polylines
---------
A polyline is an ``(n, 2)`` array of points; a set of polylines is a :class:`~coster_sumo.core.scene.Ragged`
(or a list of arrays). :func:`resample_polyline` / :func:`resample_polylines` place points at a
fixed arc-length spacing; :func:`project_points` gives arc length and signed lateral offset (left
of the driving direction is positive) of query points on one polyline.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from coster_sumo.core.scene import Ragged

ArrayLike = np.ndarray | float

_EPS = 1e-12
CONTACT_GAP = 1e-6  # [m] separation left by touch_translation so that placed boxes never overlap
MAX_BACKOFF = 0.01  # [m] the back-off along the direction never exceeds this
CONTACT_TOLERANCE_M = 0.05  # [m] boxes closer than this are in contact (the snapshot's own tolerance)


# ----------------------------------------------------------------------------- boxes


def make_boxes(cx: ArrayLike, cy: ArrayLike, heading: ArrayLike, length: ArrayLike,
               width: ArrayLike) -> np.ndarray:
    """Stack box parameters (broadcast together) into a ``(..., 5)`` float64 array."""
    parts = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64)
                                  for v in (cx, cy, heading, length, width)))
    return np.stack(parts, axis=-1)


def _as_boxes(boxes: np.ndarray) -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64)
    if b.shape[-1:] != (5,):
        raise ValueError(f"boxes must have shape (..., 5) (cx, cy, heading, length, width), got {b.shape}")
    return b


def box_corners(cx: ArrayLike, cy: ArrayLike, heading: ArrayLike, length: ArrayLike,
                width: ArrayLike) -> np.ndarray:
    """Corners of oriented boxes.

    Args:
        cx, cy: (...) centre [m]; heading: (...) [rad]; length, width: (...) [m]. Broadcast together.

    Returns:
        (..., 4, 2) float64 corners, counter-clockwise from the front-left one.
    """
    cx, cy, heading, length, width = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (cx, cy, heading, length, width)))
    c, s = np.cos(heading), np.sin(heading)
    hl, hw = 0.5 * length, 0.5 * width
    sign_l = np.array([1.0, -1.0, -1.0, 1.0])  # front, rear, rear, front
    sign_w = np.array([1.0, 1.0, -1.0, -1.0])  # left, left, right, right
    dl = hl[..., None] * sign_l  # (..., 4)
    dw = hw[..., None] * sign_w  # (..., 4)
    x = cx[..., None] + dl * c[..., None] - dw * s[..., None]
    y = cy[..., None] + dl * s[..., None] + dw * c[..., None]
    return np.stack([x, y], axis=-1)  # (..., 4, 2)


def corners_of(boxes: np.ndarray) -> np.ndarray:
    """(..., 5) boxes -> (..., 4, 2) corners (see :func:`box_corners`)."""
    b = _as_boxes(boxes)
    return box_corners(b[..., 0], b[..., 1], b[..., 2], b[..., 3], b[..., 4])


def _axes(boxes: np.ndarray) -> np.ndarray:
    """(..., 2, 2): unit heading axis and unit left axis of each box."""
    c, s = np.cos(boxes[..., 2]), np.sin(boxes[..., 2])
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=-2)


def _sat_terms(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per SAT axis: the axes, the centre offset b - a projected, and the sum of projected radii.

    Returns:
        axes (..., 4, 2), offset (..., 4), radius (..., 4), with the 4 axes being a's heading,
        a's left, b's heading, b's left.
    """
    ax_a, ax_b = _axes(a), _axes(b)
    axes = np.concatenate(np.broadcast_arrays(ax_a, ax_b), axis=-2)  # (..., 4, 2)
    delta = (b[..., :2] - a[..., :2])[..., None, :]  # (..., 1, 2)
    offset = np.sum(delta * axes, axis=-1)  # (..., 4)

    def radius(box: np.ndarray, ax: np.ndarray) -> np.ndarray:
        # half extent of ``box`` projected on each of ``axes``
        proj = np.abs(np.sum(ax[..., None, :, :] * axes[..., :, None, :], axis=-1))  # (..., 4, 2)
        return 0.5 * (box[..., 3, None] * proj[..., 0] + box[..., 4, None] * proj[..., 1])

    return axes, offset, radius(a, ax_a) + radius(b, ax_b)


def sat_overlap_depth(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest interval overlap over the 4 SAT axes [m] (> 0 iff the boxes overlap).

    For overlapping boxes this is the penetration depth (minimum translation distance); for
    separated ones, minus it is a lower bound of the Euclidean gap.

    Args:
        a, b: (..., 5) boxes, broadcast together.

    Returns:
        (...) float64.
    """
    a, b = _as_boxes(a), _as_boxes(b)
    ac, as_, bc, bs = np.cos(a[..., 2]), np.sin(a[..., 2]), np.cos(b[..., 2]), np.sin(b[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    ahl, ahw, bhl, bhw = 0.5 * a[..., 3], 0.5 * a[..., 4], 0.5 * b[..., 3], 0.5 * b[..., 4]
    ec, es = np.abs(ac * bc + as_ * bs), np.abs(as_ * bc - ac * bs)  # |cos|, |sin| of the heading difference
    # per axis: projected half extents of both boxes minus the projected centre offset
    return np.minimum(np.minimum(ahl + bhl * ec + bhw * es - np.abs(dx * ac + dy * as_),    # a's heading axis
                                 ahw + bhl * es + bhw * ec - np.abs(dy * ac - dx * as_)),   # a's left axis
                      np.minimum(bhl + ahl * ec + ahw * es - np.abs(dx * bc + dy * bs),     # b's heading axis
                                 bhw + ahl * es + ahw * ec - np.abs(dy * bc - dx * bs)))    # b's left axis


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether boxes overlap with positive area (touching boxes do not).

    Args:
        a, b: (..., 5) boxes, broadcast together.

    Returns:
        (...) bool.
    """
    return sat_overlap_depth(a, b) > 0.0


def _corners_to_box(p: np.ndarray, o: np.ndarray) -> np.ndarray:
    """Smallest distance from a corner of boxes ``p`` to boxes ``o`` (0 for a corner inside), (...)."""
    rel = corners_of(p) - o[..., None, :2]  # (..., 4, 2)
    c, s = np.cos(o[..., 2])[..., None], np.sin(o[..., 2])[..., None]
    # in o's frame o is axis aligned: the distance to it is the part of |coordinate| beyond its half extent
    lon = np.maximum(np.abs(rel[..., 0] * c + rel[..., 1] * s) - 0.5 * o[..., 3, None], 0.0)
    lat = np.maximum(np.abs(rel[..., 1] * c - rel[..., 0] * s) - 0.5 * o[..., 4, None], 0.0)
    return np.min(np.hypot(lon, lat), axis=-1)


def box_signed_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Signed distance between oriented boxes [m].

    > 0: the exact Euclidean gap between the rectangles (between disjoint convex polygons the
    closest points include a vertex of one of them: min over corner-to-box distances both ways);
    < 0: minus the penetration depth (smallest overlap over the SAT axes, i.e. the minimum
    translation distance); 0 when touching.

    Args:
        a, b: (..., 5) boxes, broadcast together.

    Returns:
        (...) float64 [m].
    """
    a, b = _as_boxes(a), _as_boxes(b)
    depth = sat_overlap_depth(a, b)
    gap = np.minimum(_corners_to_box(a, b), _corners_to_box(b, a))
    return np.where(depth > 0.0, -depth, gap)


def touch_translation(moving: np.ndarray, fixed: np.ndarray, direction: np.ndarray,
                      gap: float = CONTACT_GAP) -> np.ndarray:
    """Distance to translate ``moving`` along ``direction`` until it touches ``fixed``.

    Solved exactly by SAT interval arithmetic: on each of the 4 axes the set of translations t for
    which the projections overlap is an open interval; the boxes overlap for t in the intersection
    (t_enter, t_exit). The result is t_enter, the first contact when approaching along
    ``direction`` (negative when ``moving`` must go backwards, e.g. it already overlaps ``fixed``
    or lies beyond it), backed off so that the separation on the contact axis is ``gap``
    (at most :data:`MAX_BACKOFF` along the direction): ``box_signed_distance`` of the result is in
    [gap, ~MAX_BACKOFF], i.e. practically zero, and :func:`boxes_overlap` is False.

    Args:
        moving, fixed: (..., 5) boxes, broadcast together.
        direction: (..., 2) direction of travel (any non-zero length; normalised here).
        gap: separation [m] left on the contact axis.

    Returns:
        (...) float64 translation [m] along the unit direction; NaN where the line of travel never
        brings the boxes into contact.
    """
    moving, fixed = _as_boxes(moving), _as_boxes(fixed)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), _EPS)
    axes, offset, radius = _sat_terms(fixed, moving)  # offset: moving's centre relative to fixed's
    dn = np.sum(d[..., None, :] * axes, axis=-1)  # (..., 4) speed of the offset per unit t
    with np.errstate(divide="ignore", invalid="ignore"):
        # |offset + t dn| < radius  <=>  t in ((-radius - offset) / dn, (radius - offset) / dn)
        t1 = (-radius - offset) / dn
        t2 = (radius - offset) / dn
    moving_axis = np.abs(dn) > _EPS
    inside = np.abs(offset) < radius
    lo = np.where(moving_axis, np.minimum(t1, t2), np.where(inside, -np.inf, np.inf))
    hi = np.where(moving_axis, np.maximum(t1, t2), np.where(inside, np.inf, -np.inf))
    t_enter = np.max(lo, axis=-1)
    t_exit = np.min(hi, axis=-1)
    binding = np.argmax(lo, axis=-1)
    dn_bind = np.abs(np.take_along_axis(dn, binding[..., None], axis=-1)[..., 0])
    backoff = np.minimum(gap / np.maximum(dn_bind, _EPS), MAX_BACKOFF)
    ok = (t_enter < t_exit) & np.isfinite(t_enter)
    return np.where(ok, t_enter - backoff, np.nan)


def translate_boxes(boxes: np.ndarray, direction: np.ndarray, distance: ArrayLike) -> np.ndarray:
    """Move (..., 5) boxes by ``distance`` (...) [m] along unit-normalised ``direction`` (..., 2)."""
    b = _as_boxes(boxes)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), _EPS)
    shift = d * np.asarray(distance, dtype=np.float64)[..., None]
    b, shift = np.broadcast_arrays(b, np.concatenate([shift, np.zeros(shift.shape[:-1] + (3,))], -1))
    return b + shift


def to_local(points: np.ndarray, origin: np.ndarray, heading: ArrayLike) -> np.ndarray:
    """World points (..., 2) into frames with ``origin`` (..., 2) and x-axis along ``heading`` (...)."""
    h = np.asarray(heading, dtype=np.float64)
    c, s = np.cos(h), np.sin(h)
    d = np.asarray(points, dtype=np.float64) - origin
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def to_world(points: np.ndarray, origin: np.ndarray, heading: ArrayLike) -> np.ndarray:
    """Inverse of :func:`to_local`."""
    h = np.asarray(heading, dtype=np.float64)
    c, s = np.cos(h), np.sin(h)
    p = np.asarray(points, dtype=np.float64)
    return np.asarray(origin) + np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], -1)


# ----------------------------------------------------------------------------- polylines


def polyline_arc_length(points: np.ndarray) -> np.ndarray:
    """(n,) cumulative arc length [m] of an (n, 2) polyline, starting at 0."""
    p = np.asarray(points, dtype=np.float64)
    seg = np.hypot(*np.diff(p, axis=0).T) if len(p) > 1 else np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _as_ragged(polylines: Ragged | Sequence[np.ndarray]) -> Ragged:
    if isinstance(polylines, Ragged):
        return polylines
    return Ragged.from_list([np.asarray(p, np.float64).reshape(-1, 2) for p in polylines], np.float64, (2,))


def resample_polylines(polylines: Ragged | Sequence[np.ndarray], spacing: float, *,
                       even: bool = False) -> Ragged:
    """Resample many polylines at once (vectorised over all of them).

    Args:
        polylines: Ragged of (n_i, 2) points (or a list of arrays).
        spacing: target distance between consecutive output points [m].
        even: False: points at arc lengths 0, spacing, 2 spacing, ... plus the end point when the
            remainder is longer than 1 % of ``spacing`` (so the last gap may be shorter);
            True: ``max(1, round(L / spacing))`` equal gaps from start to end (every gap within a
            factor [2/3, 2] of ``spacing``, the whole polyline covered).

    Returns:
        Ragged of (m_i, 2) float64. Empty polylines stay empty; single points stay single points.
    """
    rag = _as_ragged(polylines)
    pts = np.asarray(rag.values, dtype=np.float64).reshape(-1, 2)
    n_items = len(rag)
    lens = rag.lengths()
    if len(pts) == 0:
        return Ragged(values=np.zeros((0, 2)), offsets=np.zeros(n_items + 1, np.int64))
    item = rag.item_index()
    seg = np.hypot(*np.diff(pts, axis=0).T)
    same = item[1:] == item[:-1]
    seg = np.where(same, seg, 0.0)
    cum = np.concatenate([[0.0], np.cumsum(seg)])  # global arc length; flat across item boundaries
    start = cum[rag.offsets[:-1].clip(max=len(pts) - 1)]
    end = cum[(rag.offsets[1:] - 1).clip(min=0)]
    total = np.where(lens > 0, end - start, 0.0)
    if even:
        n_gap = np.maximum(1, np.round(total / spacing)).astype(np.int64)
        n_out = np.where(total > 0, n_gap + 1, np.minimum(lens, 1))
    else:
        n_full = np.floor(total / spacing + 1e-9).astype(np.int64)
        remainder = total - n_full * spacing
        n_out = np.where(total > 0, n_full + 1 + (remainder > 0.01 * spacing), np.minimum(lens, 1))
    out_item = np.repeat(np.arange(n_items), n_out)
    out_offsets = np.zeros(n_items + 1, np.int64)
    np.cumsum(n_out, out=out_offsets[1:])
    k = np.arange(len(out_item)) - out_offsets[out_item]  # index within the item
    if even:
        s = total[out_item] * k / np.maximum(n_out[out_item] - 1, 1)
    else:
        s = np.minimum(k * spacing, total[out_item])
    # Make the global arc length strictly increasing across items so that one np.interp serves all
    # polylines: shift each item by its index times a margin larger than any arc length.
    margin = float(cum[-1]) + 1.0
    g = cum + item * margin
    q = start[out_item] + s + out_item * margin
    x = np.interp(q, g, pts[:, 0])
    y = np.interp(q, g, pts[:, 1])
    return Ragged(values=np.stack([x, y], -1), offsets=out_offsets)


def resample_polyline(points: np.ndarray, spacing: float, *, even: bool = False) -> np.ndarray:
    """Resample one (n, 2) polyline; see :func:`resample_polylines`. Returns (m, 2)."""
    return resample_polylines([np.asarray(points, np.float64)], spacing, even=even).values


def project_points(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project points onto one polyline (closest point on any segment).

    Args:
        points: (..., 2) [m].
        polyline: (n, 2) [m], n >= 2 (a single point is treated as a zero-length segment).

    Returns:
        arc_length: (...) [m] arc length of the closest point, in [0, L];
        lateral: (...) [m] signed distance, > 0 left of the driving direction;
        segment: (...) int64 index of the closest segment.
    """
    p = np.asarray(points, dtype=np.float64)
    line = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
    if len(line) == 1:
        line = np.concatenate([line, line])
    s0, s1 = line[:-1], line[1:]  # (S, 2)
    e = s1 - s0
    seg_len = np.hypot(e[:, 0], e[:, 1])
    cum = polyline_arc_length(line)
    rel = p[..., None, :] - s0  # (..., S, 2)
    t = np.clip(np.sum(rel * e, -1) / np.maximum(seg_len**2, _EPS), 0.0, 1.0)  # (..., S)
    diff = rel - t[..., None] * e
    dist2 = np.sum(diff * diff, -1)
    k = np.argmin(dist2, axis=-1)  # (...)
    tk = np.take_along_axis(t, k[..., None], -1)[..., 0]
    arc = cum[k] + tk * seg_len[k]
    # lateral sign from the cross product of the segment direction with the offset
    ek = e[k]
    relk = np.take_along_axis(rel, k[..., None, None].repeat(2, -1), -2)[..., 0, :]
    cross = ek[..., 0] * relk[..., 1] - ek[..., 1] * relk[..., 0]
    dist = np.sqrt(np.take_along_axis(dist2, k[..., None], -1)[..., 0])
    lateral = np.where(cross >= 0.0, dist, -dist)
    return arc, lateral, k


def point_at_arc_length(polyline: np.ndarray, arc_length: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Positions (..., 2) and tangent headings (...) [rad] at arc lengths (...) along a polyline."""
    line = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
    cum = polyline_arc_length(line)
    s = np.clip(np.asarray(arc_length, dtype=np.float64), 0.0, cum[-1])
    xy = np.stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])], -1)
    if len(line) < 2:
        return xy, np.zeros(s.shape)
    e = np.diff(line, axis=0)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(e) - 1)
    return xy, np.arctan2(e[k, 1], e[k, 0])
