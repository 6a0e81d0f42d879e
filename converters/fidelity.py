"""How closely the converted net follows WOMD, and the WOMD -> SUMO lane / link / signal mapping.

:func:`measure_fidelity` compares every WOMD lane (junction-interior lanes included) with the SUMO
lane(s) built from it and counts the WOMD links that became SUMO connections; its mapping is what
``lane_map.json`` holds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from coster_sumo.core.scene import Lanes, Scene
from coster_sumo.geometry.boxes import project_points

from .netconvert import NetInfo
from .to_sumo_net import PlainNet

MATCH_DISTANCE_M = 0.5  # [m] a WOMD lane is matched when its mean distance to its SUMO lane is below


def _mean_max_distance(points: np.ndarray, shape: np.ndarray) -> tuple[float, float]:
    if len(shape) == 0:
        return float("inf"), float("inf")
    _, lat, _ = project_points(points, shape)
    d = np.abs(lat)
    return float(d.mean()), float(d.max())


def measure_fidelity(plain: PlainNet, scene: Scene, info: NetInfo) -> tuple[dict, dict]:
    """Fidelity figures and the WOMD -> SUMO lane / link / signal mapping.

    Every WOMD lane (junction-interior lanes included) is compared with the SUMO lane(s) built
    from it: road lanes with their piece lane(s), interior lanes realised as connection shapes with
    the internal lanes of those connections. Distances are from each WOMD centreline point to the
    SUMO lane polyline.
    """
    lanes = scene.road_map.lanes
    built = _Realised.collect(plain, info, lanes)
    per_lane, lane_map, point_at = _match_lanes(plain, lanes, built)
    fidelity = _figures(lanes, per_lane, built.links, point_at)
    mapping = {
        "lanes": lane_map,
        "links": {f"{lanes.ids[a]}->{lanes.ids[b]}": list(v) for (a, b), v in sorted(built.link_to_sumo.items())},
        "tls": {t: {"links": v} for t, v in sorted(built.tls_links.items())},
    }
    return fidelity, mapping


@dataclass(slots=True)
class _Realised:
    """What the net's connections realise of WOMD, read off the connections netconvert kept.

    Attributes:
        plain, info: the lane graph and the net built from it.
        links: WOMD links realised by a SUMO connection.
        link_to_sumo: WOMD link -> (from SUMO lane, to SUMO lane) of its first connection.
        interior_shapes: WOMD interior lane -> the internal-lane paths of the connections through it.
        interior_sumo: WOMD interior lane -> those internal lanes' ids.
        join_shape: (piece, "in"/"out") -> the internal-lane path of a straight join at that end.
        tls_links: SUMO traffic light -> per link index, the WOMD lane whose logged signal drives it.
    """

    plain: PlainNet
    info: NetInfo
    links: set[tuple[int, int]] = field(default_factory=set)
    link_to_sumo: dict[tuple[int, int], tuple[str, str]] = field(default_factory=dict)
    interior_shapes: dict[int, list[np.ndarray]] = field(default_factory=dict)
    interior_sumo: dict[int, list[str]] = field(default_factory=dict)
    join_shape: dict[tuple[int, str], np.ndarray] = field(default_factory=dict)
    tls_links: dict[str, list[str | None]] = field(default_factory=dict)

    @classmethod
    def collect(cls, plain: PlainNet, info: NetInfo, lanes: Lanes) -> _Realised:
        out = cls(plain, info, tls_links={t: [None] * k for t, k in info.tls.items()})
        for c in plain.connections:
            a, b = plain.pieces[c.src], plain.pieces[c.dst]
            got = info.connections.get((a.sumo_lane, b.sumo_lane))
            if got is None:
                continue
            chain, tl, idx = got
            for lk in c.links:
                out.links.add(lk)
                out.link_to_sumo.setdefault(lk, (a.sumo_lane, b.sumo_lane))
            if c.via_lanes:
                shape = np.concatenate([info.lane_shapes[v] for v in chain if v in info.lane_shapes]) \
                    if chain else np.zeros((0, 2))
                for v in c.via_lanes:
                    out.interior_shapes.setdefault(v, []).append(shape)
                    out.interior_sumo.setdefault(v, []).extend(
                        x for x in chain if x not in out.interior_sumo.get(v, []))
            if tl and 0 <= idx < len(out.tls_links.get(tl, [])) and c.signal_lane >= 0:
                out.tls_links[tl][idx] = str(lanes.ids[c.signal_lane])
            if not c.via_lanes and chain:  # a straight join: its internal lanes carry both lane ends
                joined = np.concatenate([info.lane_shapes[v] for v in chain if v in info.lane_shapes])
                out.join_shape.setdefault((c.src, "out"), joined)
                out.join_shape.setdefault((c.dst, "in"), joined)
        return out

    def shapes(self, i: int) -> tuple[list[np.ndarray], list[str]]:
        """The SUMO shapes that may realise WOMD lane ``i`` (any one of them) and its SUMO lanes."""
        plain, lane_shapes = self.plain, self.info.lane_shapes
        if i in plain.connectors:  # several connections may share an interior lane
            return self.interior_shapes.get(i, []), self.interior_sumo.get(i, [])
        # the lane's pieces in order, with the straight joins that carry their ends between and
        # around them (set_womd_geometry lends a lane's ends to those joins' internal lanes)
        parts = []
        for k, p in enumerate(plain.lane_pieces[i]):
            if k == 0 and (p, "in") in self.join_shape:
                parts.append(self.join_shape[(p, "in")])
            parts.append(lane_shapes.get(plain.pieces[p].sumo_lane, np.zeros((0, 2))))
            if (p, "out") in self.join_shape:
                parts.append(self.join_shape[(p, "out")])
        return [np.concatenate(parts)], [plain.pieces[p].sumo_lane for p in plain.lane_pieces[i]]


def _match_lanes(plain: PlainNet, lanes: Lanes, built: _Realised
                 ) -> tuple[list[dict], dict[str, list[str]], dict[int, set[int]]]:
    """Each WOMD lane against the SUMO lane(s) that realise it.

    Returns per lane ``{"lane", "matched", "mean_m", "max_m"}``, the WOMD lane -> SUMO lanes map,
    and for each stub of one point the lanes whose SUMO lane it lies on.
    """
    per_lane: list[dict] = []
    lane_map: dict[str, list[str]] = {}
    skipped = set(plain.skipped)
    point_at: dict[int, set[int]] = {}  # stub of one point -> the lanes whose SUMO lane it lies on
    for i in range(len(lanes)):
        lid = str(lanes.ids[i])
        pts = np.asarray(lanes.centerline[i], np.float64)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if i in skipped:
            dists, lane_map[lid], on = _match_point_lane(plain, built, i, pts)
            if on:
                point_at.setdefault(i, set()).update(on)
        else:
            shapes, lane_map[lid] = built.shapes(i)
            dists = [_mean_max_distance(pts, s) for s in shapes]
        mean, mx = min(dists) if dists else (float("inf"), float("inf"))
        per_lane.append({"lane": lid, "matched": bool(mean < MATCH_DISTANCE_M),
                         "mean_m": mean if np.isfinite(mean) else None,
                         "max_m": mx if np.isfinite(mx) else None})
    return per_lane, lane_map, point_at


def _match_point_lane(plain: PlainNet, built: _Realised, i: int, pts: np.ndarray
                      ) -> tuple[list[tuple[float, float]], list[str], list[int]]:
    """A lane with no length (WOMD's map crop leaves lanes of one point) is not a SUMO lane; it is
    realised where it sits: at the end of a lane it follows or the start of one it leads to, so its
    point must lie on the SUMO lane(s) of those.

    Returns the distances to the lanes it lies on, their SUMO lanes, and (for a stub, which has no
    link across it to realise) the lanes it lies on.
    """
    before, after = plain.point_ends.get(i, ([], []))
    dists: list[tuple[float, float]] = []
    sumo: list[str] = []
    on: list[int] = []
    for j in ([*before, *after] if len(pts) else []):
        shapes, ids = built.shapes(j)
        best = (float("inf"), float("inf"))
        for sh in shapes:
            best = min(best, _mean_max_distance(pts, sh))
        if best[0] < MATCH_DISTANCE_M:
            dists.append(best)
            if j not in plain.connectors:  # the SUMO lane of that end only
                ids = ids[-1:] if j in before else ids[:1]
            sumo.extend(x for x in ids if x not in sumo)
            if not before or not after:  # a stub: no link across it to realise
                on.append(j)
    return dists, sumo, on


def _figures(lanes: Lanes, per_lane: list[dict], realised_links: set[tuple[int, int]],
             point_at: dict[int, set[int]]) -> dict:
    """The fidelity figures of ``summary.json``: lanes matched, links realised, distances."""
    n = len(lanes)
    matched = sum(p["matched"] for p in per_lane)
    means = np.array([p["mean_m"] for p in per_lane if p["mean_m"] is not None])
    maxes = np.array([p["max_m"] for p in per_lane if p["max_m"] is not None])
    all_links = {(int(a), int(b)) for a in range(n) for b in lanes.successors[a] if int(b) != a}
    all_links |= {(int(p), int(b)) for b in range(n) for p in lanes.predecessors[b] if int(p) != b}
    # a link to or from a stub of one point is realised where the stub sits on the lane it links
    realised = realised_links | {(a, b) for a, b in all_links
                                 if b in point_at.get(a, ()) or a in point_at.get(b, ())}
    return {
        "lanes": n,
        "lanes_matched": int(matched),
        "lanes_matched_share": matched / n if n else 1.0,
        "links": len(all_links),
        "links_realised": len(realised & all_links),
        "links_realised_share": len(realised & all_links) / len(all_links) if all_links else 1.0,
        "centreline_mean_m": float(means.mean()) if len(means) else None,
        "centreline_max_m": float(maxes.max()) if len(maxes) else None,
        "unmatched_lanes": [p["lane"] for p in per_lane if not p["matched"]],
    }
