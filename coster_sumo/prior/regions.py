"""Local regions along lane centrelines: the traffic prior's tokens (docs/method.md step 1).

Construction
------------
Every lane centreline is resampled with :func:`coster_sumo.geometry.boxes.resample_polylines` in ``even``
mode: ``n = max(1, round(L / spacing))`` equal gaps from the lane's start to its end, so the whole
lane is covered and every gap lies within [2/3, 3/2] of ``spacing`` (default 5 m; only lanes
shorter than ``spacing / 2`` have shorter regions). Each pair of adjacent points (q1, q2) spans a
region: a rectangle with origin q1, **y-axis along q2 - q1** (the driving direction), **x-axis to
its right** (y rotated by -90 degrees, a right-handed frame), height |q2 - q1| and width
``REGION_WIDTH`` = 5 m centred on the centreline.

Region-frame quantities of an agent: ``local_xy`` = (x across to the right, y along from q1) [m];
``normalised_xy`` = (x / width, y / height - 0.5), in [-0.5, 0.5]^2 inside the rectangle;
``heading`` relative to the region direction [rad]; velocity in the same axes.

Assignment of agents to regions (TrafficGen-style, per timestep)
----------------------------------------------------------------
A valid agent of an allowed type (vehicles by default) is a candidate for every region whose
rectangle contains its centre and whose direction agrees with its heading within
``max_heading_diff_deg`` (45 degrees). It goes to the candidate with the nearest region centre.
When several agents choose the same region, the one nearest to the region centre keeps it and the
others stay unassigned at that step: one agent per region, each agent in at most one region (so
hiding a region hides its agent completely).

Everything is batched over timesteps. :func:`neighbourhood` restricts the work to the regions
whose centres lie within a radius of a point per timestep (the target), nearest first.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from sklearn.neighbors import KDTree

from coster_sumo.core.scene import ObjectType, RoadMap, SignalState, SignalStates, Tracks
from coster_sumo.geometry.boxes import resample_polylines, to_local
from coster_sumo.geometry.frames import wrap_angle

REGION_SPACING = 5.0  # [m] target distance between sample points along a lane = region height
REGION_WIDTH = 5.0  # [m] region extent across the lane (half-width 2.5 m, as in the authors' code)
MAX_HEADING_DIFF_DEG = 45.0  # [deg] agent heading vs region direction for assignment
NEIGHBOURHOOD_RADIUS = 40.0  # [m] default radius around the target for the prior
MAX_REGIONS = 256  # default cap on regions per neighbourhood (nearest first)


@dataclass(frozen=True, slots=True)
class Regions:
    """Regions of a map (or a subset of them).

    Attributes:
        q1: (num_regions, 2) float64 [m] region origin (earlier point along the lane).
        q2: (num_regions, 2) float64 [m] the next point; the region's y-axis points from q1 to q2.
        lane_index: (num_regions,) int64 index into ``RoadMap.lanes``.
        lane_type: (num_regions,) int8 :class:`~coster_sumo.core.scene.LaneType` of the lane.
        is_junction: (num_regions,) bool, the lane lies inside a junction.
        width: region width [m] (across the lane).
        speed_limit: (num_regions,) float64 [m/s] of the lane, 0 where unknown (None: not known for
            any region).
    """

    q1: np.ndarray
    q2: np.ndarray
    lane_index: np.ndarray
    lane_type: np.ndarray
    is_junction: np.ndarray
    width: float = REGION_WIDTH
    speed_limit: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.lane_index)

    @property
    def centre(self) -> np.ndarray:
        """(num_regions, 2) [m] rectangle centre."""
        return 0.5 * (self.q1 + self.q2)

    @property
    def height(self) -> np.ndarray:
        """(num_regions,) [m] |q2 - q1|."""
        d = self.q2 - self.q1
        return np.hypot(d[:, 0], d[:, 1])

    @property
    def heading(self) -> np.ndarray:
        """(num_regions,) [rad] direction of the region's y-axis (q1 -> q2), CCW from +x."""
        d = self.q2 - self.q1
        return np.arctan2(d[:, 1], d[:, 0])

    def select(self, index: np.ndarray) -> Regions:
        """The regions at ``index`` (any integer or boolean index over regions)."""
        return Regions(q1=self.q1[index], q2=self.q2[index], lane_index=self.lane_index[index],
                       lane_type=self.lane_type[index], is_junction=self.is_junction[index], width=self.width,
                       speed_limit=None if self.speed_limit is None else self.speed_limit[index])

    def to_region_frame(self, points: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """World points (..., 2) -> (x across to the right, y along from q1) [m] in regions ``index``.

        ``index`` (...) selects the region of each point (default: point i in region i, broadcasting
        over leading axes with the regions last).
        """
        q1 = self.q1 if index is None else self.q1[index]
        hd = self.heading if index is None else self.heading[index]
        # to_local gives (along, left); the region frame is (right, along)
        loc = to_local(points, q1, hd)
        return np.stack([-loc[..., 1], loc[..., 0]], axis=-1)

    def from_normalised(self, normalised_xy: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Normalised region positions (..., 2) in [-0.5, 0.5]^2 -> world points (..., 2) [m]."""
        q1 = self.q1 if index is None else self.q1[index]
        hd = self.heading if index is None else self.heading[index]
        h = self.height if index is None else self.height[index]
        across = normalised_xy[..., 0] * self.width
        along = (normalised_xy[..., 1] + 0.5) * h
        c, s = np.cos(hd), np.sin(hd)
        # along the direction (c, s), across to the right (s, -c)
        return q1 + np.stack([along * c + across * s, along * s - across * c], axis=-1)


def build_regions(road_map: RoadMap, spacing: float = REGION_SPACING, width: float = REGION_WIDTH,
                  lanes: np.ndarray | None = None) -> Regions:
    """Regions along the centrelines of all lanes (or of ``lanes``, an index array).

    Lanes with fewer than two distinct points yield no region. Regions are ordered by lane, then
    along the lane.
    """
    all_lanes = road_map.lanes
    lane_idx = np.arange(len(all_lanes)) if lanes is None else np.asarray(lanes, np.int64)
    lines = [all_lanes.centerline[int(i)] for i in lane_idx]
    pts = resample_polylines(lines, spacing, even=True)
    n_reg = np.maximum(pts.lengths() - 1, 0)
    owner = np.repeat(np.arange(len(lane_idx)), n_reg)  # position in lane_idx
    # region j of item i uses points offsets[i] + j and offsets[i] + j + 1
    first = np.repeat(pts.offsets[:-1], n_reg) + (np.arange(len(owner)) - np.repeat(np.cumsum(n_reg) - n_reg,
                                                                                       n_reg))
    q1, q2 = pts.values[first], pts.values[first + 1]
    keep = np.hypot(*(q2 - q1).T) > 1e-6
    li = lane_idx[owner][keep]
    return Regions(q1=q1[keep], q2=q2[keep], lane_index=li, lane_type=all_lanes.lane_type[li].astype(np.int8),
                   is_junction=all_lanes.is_junction[li].astype(bool), width=width,
                   speed_limit=np.nan_to_num(np.asarray(all_lanes.speed_limit, np.float64)[li]))


def regions_near(regions: Regions, points: np.ndarray, radius: float) -> np.ndarray:
    """Sorted indices of the regions whose centre lies within ``radius`` [m] of any of ``points`` (P, 2)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if len(regions) == 0 or len(pts) == 0:
        return np.zeros(0, np.int64)
    tree = KDTree(regions.centre)
    hits = tree.query_radius(pts, r=radius)
    return np.unique(np.concatenate(list(hits)).astype(np.int64))


def neighbourhood(regions: Regions, centres: np.ndarray, radius: float = NEIGHBOURHOOD_RADIUS,
                  max_regions: int = MAX_REGIONS) -> tuple[np.ndarray, np.ndarray]:
    """Per timestep, the regions whose centre lies within ``radius`` of that step's centre.

    Args:
        regions: the candidate regions.
        centres: (T, 2) [m] one point per step (e.g. the target's position).
        radius: [m].
        max_regions: at most this many per step, the nearest first.

    Returns:
        index: (T, K) int64 region indices, nearest first, padded with -1; K = the largest count
            (at most ``max_regions``, at least 1).
        mask: (T, K) bool, True where ``index`` is a real region.
    """
    c = np.asarray(centres, np.float64).reshape(-1, 2)
    T, R = len(c), len(regions)
    if R == 0:
        return np.full((T, 1), -1, np.int64), np.zeros((T, 1), bool)
    d2 = np.sum((regions.centre[None] - c[:, None]) ** 2, axis=-1)  # (T, R)
    d2 = np.where(np.isfinite(d2), d2, np.inf)
    d2 = np.where(d2 <= radius * radius, d2, np.inf)
    k = int(min(max_regions, R))
    part = np.argpartition(d2, k - 1, axis=1)[:, :k] if k < R else np.broadcast_to(np.arange(R), (T, R))
    part_d = np.take_along_axis(d2, part, axis=1)
    order = np.argsort(part_d, axis=1, kind="stable")
    idx = np.take_along_axis(part, order, axis=1)
    dd = np.take_along_axis(part_d, order, axis=1)
    mask = np.isfinite(dd)
    width = max(1, int(mask.sum(axis=1).max()))
    return np.where(mask, idx, -1)[:, :width], mask[:, :width]


def signal_category(state: np.ndarray) -> np.ndarray:
    """WOMD signal states -> 0 none/unknown, 1 stop, 2 caution, 3 go (int8, same shape)."""
    table = np.zeros(max(int(s) for s in SignalState) + 1, np.int8)
    for s in (SignalState.ARROW_STOP, SignalState.STOP, SignalState.FLASHING_STOP):
        table[s] = 1
    for s in (SignalState.ARROW_CAUTION, SignalState.CAUTION, SignalState.FLASHING_CAUTION):
        table[s] = 2
    for s in (SignalState.ARROW_GO, SignalState.GO):
        table[s] = 3
    st = np.asarray(state, np.int64)
    return table[np.clip(st, 0, len(table) - 1)]


def region_signals(regions: Regions, signals: SignalStates, num_lanes: int) -> np.ndarray:
    """(T, num_regions) int8 signal category (see :func:`signal_category`) of each region's lane."""
    per_lane = signals.per_lane(num_lanes)  # (T, num_lanes)
    return signal_category(per_lane[:, regions.lane_index])


@dataclass(frozen=True, slots=True)
class Occupancy:
    """Agents assigned to regions, per timestep.

    Attributes:
        agent: (T, R) int64 index into the tracks, -1 where the region is empty.
        local_xy: (T, R, 2) float64 [m] agent centre in the region frame (x right, y along from q1).
        normalised_xy: (T, R, 2) float64 local_xy normalised to [-0.5, 0.5]^2 (x / width, y / height - 0.5).
        heading: (T, R) float64 [rad] agent heading minus region direction, wrapped to (-pi, pi].
        velocity: (T, R, 2) float64 [m/s] in the region frame (x right, y along).
        speed: (T, R) float64 [m/s].
        length: (T, R) float64 [m].
        width: (T, R) float64 [m].
        Values are 0 where ``agent`` is -1.
    """

    agent: np.ndarray
    local_xy: np.ndarray
    normalised_xy: np.ndarray
    heading: np.ndarray
    velocity: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray

    @property
    def present(self) -> np.ndarray:
        """(T, R) bool."""
        return self.agent >= 0


def assign_agents(regions: Regions, tracks: Tracks, steps: np.ndarray | None = None,
                  object_types: Sequence[int] = (ObjectType.VEHICLE,),
                  max_heading_diff_deg: float = MAX_HEADING_DIFF_DEG) -> Occupancy:
    """Assign agents to regions at every step (rule in the module docstring).

    Args:
        regions: R regions.
        tracks: the agents.
        steps: (T,) step indices into ``tracks`` (default all).
        object_types: agent types that occupy regions.
        max_heading_diff_deg: heading agreement tolerance [deg].

    Returns:
        :class:`Occupancy` with leading shape (T, R).
    """
    st = np.arange(tracks.num_steps) if steps is None else np.asarray(steps, np.int64)
    return occupancy_of(regions, tracks, assigned_agent(regions, tracks, st, object_types, max_heading_diff_deg), st)


def assigned_agent(regions: Regions, tracks: Tracks, st: np.ndarray,
                   object_types: Sequence[int] = (ObjectType.VEHICLE,),
                   max_heading_diff_deg: float = MAX_HEADING_DIFF_DEG) -> np.ndarray:
    """(T, R) int64 the agent in each region at steps ``st`` (T,), -1 where none
    (:func:`assign_agents` without the region-frame attributes)."""
    T, R = len(st), len(regions)
    agent = np.full((T, R), -1, np.int64)
    if R > 0 and tracks.num_agents > 0 and T > 0:
        ok_type = np.isin(tracks.object_type, np.asarray(object_types, np.int64))
        valid = tracks.valid[:, st] & ok_type[:, None]  # (A, T)
        a_idx, t_idx = np.nonzero(valid)
        pts = np.stack([tracks.x[a_idx, st[t_idx]], tracks.y[a_idx, st[t_idx]]], -1)  # (P, 2)
        if len(pts):
            height = regions.height
            reach = float(np.sqrt((0.5 * height.max()) ** 2 + (0.5 * regions.width) ** 2)) + 1e-6
            hits = KDTree(regions.centre).query_radius(pts, r=reach)
            n_hits = np.fromiter(map(len, hits), np.int64, count=len(hits))
            p = np.repeat(np.arange(len(pts)), n_hits)  # pair -> point
            r = np.concatenate(hits).astype(np.int64) if n_hits.sum() else np.zeros(0, np.int64)
            loc = regions.to_region_frame(pts[p], r)
            rel_h = wrap_angle(tracks.heading[a_idx[p], st[t_idx[p]]] - regions.heading[r])
            inside = ((np.abs(loc[:, 0]) <= 0.5 * regions.width) & (loc[:, 1] >= 0.0)
                      & (loc[:, 1] <= height[r]) & (np.abs(rel_h) <= np.radians(max_heading_diff_deg)))
            p, r = p[inside], r[inside]
            dist = np.hypot(*(pts[p] - regions.centre[r]).T)
            # each point: nearest candidate region
            order = np.lexsort((dist, p))
            first = np.ones(len(order), bool)
            first[1:] = p[order][1:] != p[order][:-1]
            sel = order[first]
            p, r, dist = p[sel], r[sel], dist[sel]
            # each (step, region): nearest agent
            t_of = t_idx[p]
            key = t_of * R + r
            order = np.lexsort((dist, key))
            first = np.ones(len(order), bool)
            first[1:] = key[order][1:] != key[order][:-1]
            sel = order[first]
            agent[t_of[sel], r[sel]] = a_idx[p[sel]]
    return agent


def occupancy_of(regions: Regions, tracks: Tracks, agent: np.ndarray, steps: np.ndarray) -> Occupancy:
    """Region-frame attributes for a given assignment ``agent`` (T, R) (-1 = empty) at ``steps`` (T,)."""
    T, R = agent.shape
    present = agent >= 0
    a = np.where(present, agent, 0)
    s = np.broadcast_to(np.asarray(steps, np.int64)[:, None], (T, R))
    if tracks.num_agents == 0:
        zeros = np.zeros((T, R))
        return Occupancy(agent=agent, local_xy=np.zeros((T, R, 2)), normalised_xy=np.zeros((T, R, 2)),
                         heading=zeros, velocity=np.zeros((T, R, 2)), speed=zeros, length=zeros, width=zeros)
    xy = np.stack([tracks.x[a, s], tracks.y[a, s]], -1)
    ridx = np.broadcast_to(np.arange(R), (T, R))
    loc = regions.to_region_frame(xy, ridx) if R else np.zeros((T, R, 2))
    height = regions.height[ridx] if R else np.ones((T, R))
    norm = np.stack([loc[..., 0] / regions.width, loc[..., 1] / np.maximum(height, 1e-9) - 0.5], -1)
    rh = regions.heading[ridx] if R else np.zeros((T, R))
    rel_h = wrap_angle(tracks.heading[a, s] - rh)
    c, sn = np.cos(rh), np.sin(rh)
    vx, vy = tracks.vx[a, s], tracks.vy[a, s]
    vel = np.stack([vx * sn - vy * c, vx * c + vy * sn], -1)  # (right, along)
    m = present.astype(np.float64)
    return Occupancy(agent=agent, local_xy=loc * m[..., None], normalised_xy=norm * m[..., None],
                     heading=rel_h * m, velocity=vel * m[..., None], speed=np.hypot(vx, vy) * m,
                     length=tracks.length[a, s] * m, width=tracks.width[a, s] * m)
