"""Avoidability of a generated variant: could the target have escaped, how late, how hard.

A generated collision is a planner's *defect* only where the target could have avoided it
(docs/method.md, "Step 8 Avoidability"). This module searches the target's evasive plans with what
generation already knows, before any planner runs:

- the adversary follows its plan to t_col and then drives on along the lane it is on at its speed
  (what the injection pass does with an adversary whose contact was avoided, both through
  :meth:`coster_sumo.core.plan.AdversaryPlan.sample`; :mod:`coster_sumo.geometry.road_follow`);
- every other vehicle follows its nominal trajectory (the scene at 10 Hz);
- the target follows its nominal trajectory until it acts at ``t_act``; from then on it keeps to
  its nominal path, shifted sideways by a lateral profile (none, a swerve inside its lane, a lane
  change to either side) and driven with a longitudinal profile (its nominal speeds, hold the
  speed, jerk-limited braking at several decelerations up to its class's emergency deceleration,
  jerk-limited acceleration);
- a plan counts when its boxes keep at least :data:`MIN_CLEARANCE_M` from the adversary and from
  every other vehicle, it stays on the drivable area, both up to :data:`HORIZON_AFTER_TCOL_S` after
  t_col, and it respects the limits of a kinematic bicycle model (curvature from the steering
  limit, lateral and combined acceleration from the friction limit).

All candidate plans of a variant (every moment to act x every manoeuvre) are built and checked as
one batch of arrays; there is no Python loop over candidates or time steps.

The limits, manoeuvres and profiles it combines, and the :class:`~coster_sumo.avoidability.evasion.Escape` and
:class:`~coster_sumo.avoidability.evasion.Avoidability` it returns, are in :mod:`coster_sumo.avoidability.evasion`.

Times are simulation seconds, distances metres, accelerations m/s^2.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from coster_sumo.avoidability.clearance import hits_adversary, other_boxes, outer_reach, too_close
from coster_sumo.avoidability.evasion import (
    DEFAULT_REACTION_S,
    DT_S,
    Avoidability,
    ClassLimits,
    Escape,
    Manoeuvre,
    Motion,
    contact_kind,
    lateral_profile,
    manoeuvres,
    speed_profiles,
    threat_time,
    vehicle_class,
)
from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import (
    box_signed_distance,
    make_boxes,
    point_at_arc_length,
    project_points,
)
from coster_sumo.geometry.drivable import DrivableArea

# HORIZON_AFTER_TCOL_S (coster_sumo.core.plan) [s]: an escape must stay clear and on the road this long after t_col
MIN_CLEARANCE_M = 0.3  # [m] smallest gap an escape keeps to every box (the SUMO replay is the arbiter)
REACTION_TIMES_S = (0.5, 1.0, 1.5)  # [s] reaction times reported for every variant
ACT_SPACING_S = 0.2  # [s] moments to act are searched on this grid (plus the reaction moments)
OFF_ROAD_SPACING_S = 0.2  # [s] on-road checks every other step (a car moves < 8 m in it)
# candidates clear of the adversary and blocked only by traffic that reacts, tried in SUMO per
# reaction time without an escape: the least demanding few (docs/method.md step 8)
BLOCKED_TRIED_PER_REACTION = 2
EARLY_CHUNK = 5  # moments to act before the shortest reaction, built at a time (latest first)




# ----------------------------------------------------------------------------- the target's path

def _path(xy: np.ndarray, heading: np.ndarray, extend_m: float) -> np.ndarray:
    """The target's nominal path as a polyline with points >= 0.2 m apart, extended straight
    by ``extend_m`` at both ends (an escape may drive further or back less far than the log)."""
    keep = [0]
    pts_list = xy.tolist()  # Python floats: a numpy call per point costs more than the test
    lx, ly = pts_list[0]
    for i in range(1, len(pts_list)):  # once per variant over the target's own log, not per candidate
        x, y = pts_list[i]
        if math.hypot(x - lx, y - ly) >= 0.2:
            keep.append(i)
            lx, ly = x, y
    pts = xy[keep]
    h0 = heading[0] if len(pts) < 2 else np.arctan2(*(pts[1] - pts[0])[::-1])
    h1 = heading[-1] if len(pts) < 2 else np.arctan2(*(pts[-1] - pts[-2])[::-1])
    start = pts[0] - extend_m * np.array([np.cos(h0), np.sin(h0)])
    end = pts[-1] + extend_m * np.array([np.cos(h1), np.sin(h1)])
    return np.concatenate([start[None], pts, end[None]])


# ----------------------------------------------------------------------------- the search

def assess(scene: Scene, target: int, plan: AdversaryPlan, drivable: DrivableArea | None,
           reaction_times: tuple[float, ...] = REACTION_TIMES_S, reaction_time_s: float = DEFAULT_REACTION_S,
           reactive_others: bool = False) -> Avoidability:
    """Search the target's escapes from ``plan`` in ``scene`` (module docstring); kinematic only
    (the SUMO replay, :mod:`coster_sumo.avoidability.proof`, confirms or refutes each escape).

    ``reactive_others``: the other vehicles are SUMO's drivers in the proof (a SUMO configuration);
    then, for every reaction time without an escape, the :data:`BLOCKED_TRIED_PER_REACTION` least
    demanding plans that keep clear of the adversary but not of another vehicle are kept in
    ``Avoidability.blocked`` for the proof to try: there that vehicle reacts."""
    tr = scene.tracks
    ts = scene.timestamps
    valid_t = tr.valid[target]
    t_col = plan.t_col
    times = np.round(np.arange(plan.t_start, t_col + HORIZON_AFTER_TCOL_S + 1e-9, DT_S), 6)  # (T,)
    # the target's nominal state on the grid (its log's nearest step)
    idx = np.clip(np.searchsorted(ts, times - 1e-6), 0, len(ts) - 1)
    prev = np.clip(idx - 1, 0, len(ts) - 1)
    idx = np.where(np.abs(ts[prev] - times) < np.abs(ts[idx] - times), prev, idx)
    ok = valid_t[idx]
    steps_valid = np.flatnonzero(valid_t)
    last_valid = steps_valid[-1]
    idx = np.where(ok, idx, np.minimum(idx, last_valid))
    length = float(np.median(tr.length[target][valid_t]))
    width = float(np.median(tr.width[target][valid_t]))
    path = _path(np.stack([tr.x[target][valid_t], tr.y[target][valid_t]], 1), tr.heading[target][valid_t], 400.0)
    # what the target can do: its class's limits and the manoeuvres they allow
    limits = vehicle_class(int(tr.object_type[target]), length, width)
    man = manoeuvres(limits)
    nx, ny, nyaw = tr.x[target, idx], tr.y[target, idx], tr.heading[target, idx]
    nv = np.hypot(tr.vx[target, idx], tr.vy[target, idx])
    # after the log ends the nominal target drives on at its last speed (only the horizon needs it)
    beyond = times > ts[last_valid] + 1e-6
    if beyond.any():
        extra = times[beyond] - ts[last_valid]
        nx[beyond] += nv[beyond] * np.cos(nyaw[beyond]) * extra
        ny[beyond] += nv[beyond] * np.sin(nyaw[beyond]) * extra
    tcol_k = int(np.argmin(np.abs(times - t_col)))
    # the kind of contact, from both states at t_col
    ax_c, ay_c, ayaw_c, av_c = (float(v[0]) for v in plan.sample(np.array([t_col])))
    kind = contact_kind(Motion(float(nx[tcol_k]), float(ny[tcol_k]), float(nyaw[tcol_k]), float(nv[tcol_k]), length,
                               width), Motion(ax_c, ay_c, ayaw_c, av_c, plan.length, plan.width))
    upto = slice(0, tcol_k + 1)
    t_threat = threat_time(times[upto], Motion(nx[upto], ny[upto], nyaw[upto], nv[upto], length, width),
                           Motion(*plan.sample(times[upto]), plan.length, plan.width))
    # moments to act: a grid from the appearance to t_col plus each reaction moment
    grid = np.arange(plan.t_start, t_col + 1e-9, ACT_SPACING_S)
    react = np.array([t_threat + r for r in reaction_times])
    acts = np.unique(np.round(np.concatenate([grid, react[react < t_col]]) / DT_S) * DT_S)
    act_k = np.clip(np.round((acts - plan.t_start) / DT_S).astype(int), 0, tcol_k)
    act_k = np.unique(act_k)
    escapes: dict[float, Escape | None] = {r: None for r in reaction_times}
    if not len(act_k):
        return Avoidability(t_col, plan.t_start, t_threat, kind, limits.name, None, escapes, reaction_time_s)

    ctx = _SearchContext(scene, target, plan, drivable, man, limits, times, nx, ny, nyaw, nv, length, width, path)
    t_acts_all = times[act_k]
    # the moments before the shortest reaction serve only the last moment to act, which is searched
    # from the latest moment back: they are computed only when no later moment has an escape, a
    # few moments at a time from the latest (each row is computed on its own: the same answer)
    late = t_acts_all >= t_threat + min(reaction_times) - 1e-6
    late_cand = _Candidates(ctx, act_k[late]) if late.any() else None
    last_moment = late_cand.last_moment(t_col) if late_cand is not None else None
    early = act_k[~late]
    for stop in range(len(early), 0, -EARLY_CHUNK):
        if last_moment is not None:
            break
        last_moment = _Candidates(ctx, early[max(0, stop - EARLY_CHUNK):stop]).last_moment(t_col)
    blocked: dict[tuple[float, Manoeuvre], Escape] = {}
    if late_cand is not None:
        for r in reaction_times:
            escapes[r] = late_cand.least_escape(t_threat + r)
            if reactive_others and escapes[r] is None:
                for e in late_cand.blocked_escapes(t_threat + r, BLOCKED_TRIED_PER_REACTION):
                    blocked.setdefault((round(e.t_act, 3), e.manoeuvre), e)
    return Avoidability(t_col, plan.t_start, t_threat, kind, limits.name, last_moment, escapes, reaction_time_s,
                        candidates=int(len(act_k) * len(man)), blocked=list(blocked.values()))


@dataclass(frozen=True)
class _SearchContext:
    """What every candidate of one variant's search shares: the scene, the plan, the target's nominal
    states on the time grid (nx, ny, nyaw, nv), its size and its path."""

    scene: Scene
    target: int
    plan: AdversaryPlan
    drivable: DrivableArea | None
    man: list[Manoeuvre]
    limits: ClassLimits
    times: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    nyaw: np.ndarray
    nv: np.ndarray
    length: float
    width: float
    path: np.ndarray

    @functools.cached_property
    def adv_box(self) -> np.ndarray:
        """(T, 5) the adversary's boxes on the grid (its plan, then along the road)."""
        ax, ay, ayaw, _ = self.plan.sample(self.times)
        return make_boxes(ax, ay, ayaw, self.plan.length, self.plan.width)

    @functools.cached_property
    def others(self) -> tuple[tuple[np.ndarray, np.ndarray] | None, np.ndarray]:
        """The other vehicles near the path (:func:`~coster_sumo.avoidability.clearance.other_boxes`)."""
        return other_boxes(self.scene, self.target, self.times, self.path)

    @functools.cached_property
    def nominal_off(self) -> np.ndarray | None:
        """(S,) where the log itself is off the drivable area, at the road check's steps (None: no
        area). A map that misses a driveway: forgiven."""
        if self.drivable is None:
            return None
        sub = self.road_steps
        return self.drivable.off_road(self.nx[sub], self.ny[sub], self.nyaw[sub], np.asarray(self.length),
                                      np.asarray(self.width))

    @functools.cached_property
    def nominal_along(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T,) each: the nominal states' arc length along the path and sideways offset from it [m],
        and the nominal longitudinal acceleration [m/s^2]: what every batch of candidates starts from."""
        s_nom, d_nom, _ = project_points(np.stack([self.nx, self.ny], 1), self.path)
        a_nom = np.gradient(self.nv, DT_S) if len(self.times) > 1 else np.zeros(len(self.times))
        return s_nom, d_nom, a_nom

    @property
    def road_steps(self) -> np.ndarray:
        """The grid steps the road check tests (every :data:`OFF_ROAD_SPACING_S`)."""
        return np.arange(0, len(self.times), max(1, round(OFF_ROAD_SPACING_S / DT_S)))


class _Candidates:
    """The (act, manoeuvre) candidates of the moments to act ``act_k`` (steps of the time grid): their
    poses, kinematic feasibility and clearance to the adversary and the other vehicles.

    Every row (one moment to act) is computed on its own, each candidate's tests over its own steps
    after acting, so a subset of the moments gives the same rows as the whole grid.
    """

    def __init__(self, ctx: _SearchContext, act_k: np.ndarray) -> None:
        self.ctx, self.act_k = ctx, act_k
        nx, ny, nyaw, times = ctx.nx, ctx.ny, ctx.nyaw, ctx.times
        n = len(times)
        # the profiles of the distinct longitudinal and lateral parts, each computed once and shared
        # by every manoeuvre that combines them (the same numbers as computing each manoeuvre's own)
        s_u, v_u, a_u, d_u, lon_of, lat_of = _profiles(ctx, act_k)
        # poses: along the path plus the sideways shift; the nominal part is the log itself
        xy_u, hd_u = point_at_arc_length(ctx.path, s_u)  # (K, L, n, 2), (K, L, n)
        v, a_lon, d = v_u[:, lon_of], a_u[:, lon_of], d_u[:, lat_of]  # (K, M, n)
        hd = hd_u[:, lon_of]
        # x and y each in an array of its own (contiguous for the gradients), stacked at the end
        px = xy_u[..., 0][:, lon_of] + d * -np.sin(hd_u)[:, lon_of]
        py = xy_u[..., 1][:, lon_of] + d * np.cos(hd_u)[:, lon_of]
        dd = np.gradient(d_u, DT_S, axis=-1)[:, lat_of]
        yaw = hd + np.arctan2(dd, np.maximum(v, 0.5))
        pre = np.arange(n)[None, :] < act_k[:, None]  # (K, n) steps before acting: the log
        for j, k in enumerate(act_k.tolist()):  # written in place: px, py and yaw are new arrays
            px[j, :, :k] = nx[:k]
            py[j, :, :k] = ny[:k]
            yaw[j, :, :k] = nyaw[:k]
        # kinematic limits: curvature and accelerations from the poses themselves
        dyaw = np.gradient(_unwrapped(yaw), DT_S, axis=-1)
        speed_pos = np.hypot(np.gradient(px, DT_S, axis=-1), np.gradient(py, DT_S, axis=-1))
        pos = np.stack([px, py], -1)  # (K, M, n, 2)
        a_lat = np.abs(dyaw * speed_pos)
        after = ~pre[:, None, :]  # (K, 1, n)
        moving = speed_pos > 1.0
        curv = np.where(moving, np.abs(dyaw) / np.maximum(speed_pos, 1e-6), 0.0)
        # a sideways shift at a crawl turns the wheels further than they go: that is the curvature check
        slow_shift = (np.abs(dd) > 0.05) & (speed_pos <= 1.0)
        a_comb = np.hypot(a_lon, np.where(moving, a_lat, 0.0))
        limits, length, width = ctx.limits, ctx.length, ctx.width
        feasible = ~(after & ((curv > limits.max_curvature(length) * 1.02) | slow_shift
                              | (a_comb > limits.emergency_decel * 1.02))).any(-1)  # (K, M)
        # clearance to the adversary (its plan, then constant velocity) and to every other vehicle
        self.adv_box = ctx.adv_box  # (n, 5)
        # boxes grown by the clearance on every side: an overlap (SAT, no corners) means too close
        grown = (length + 2 * MIN_CLEARANCE_M, width + 2 * MIN_CLEARANCE_M)
        good = feasible.copy()
        kk, mm = np.nonzero(good)
        if len(kk):  # the adversary first: it rules out most candidates
            hit = hits_adversary(pos[kk, mm], yaw[kk, mm], grown, self.adv_box, after[kk, 0])
            good[kk[hit], mm[hit]] = False
        self.clear_of_adversary = good.copy()
        self.others, self.other_ids = ctx.others
        kk, mm = np.nonzero(good)
        if self.others is not None and len(kk):
            o_box, o_valid = self.others  # (N, n, 5), (N, n)
            hit = too_close(pos[kk, mm], yaw[kk, mm], grown, o_box, o_valid, after[kk, 0])
            good[kk[hit], mm[hit]] = False
        # only what is clear is checked against the road (the costlier test), and only as far as the
        # answer needs it: the least demanding escape per reaction time and the last moment to act
        self.on_road = _RoadCheck(ctx, pos, yaw, after[:, 0])
        self.demand = np.max(np.where(after, a_comb, 0.0), -1)  # (K, M)
        self.peak_decel = np.max(np.where(after, np.maximum(-a_lon, 0.0), 0.0), -1)
        self.peak_lat = np.max(np.where(after & moving, a_lat, 0.0), -1)
        self.t_acts = times[act_k]
        self.pos, self.yaw, self.v, self.after, self.good = pos, yaw, v, after, good

    def last_moment(self, t_col: float) -> float | None:
        """[s] before t_col: the latest of these moments with an escape on the road (None: none)."""
        good = self.good
        for k in np.flatnonzero(good.any(1))[::-1]:
            if self.on_road(np.full(int(good[k].sum()), k), np.flatnonzero(good[k])).any():
                return float(t_col - self.t_acts[k])
        return None

    def least_escape(self, t_from: float) -> Escape | None:
        """The least demanding escape acting at ``t_from`` [s] or later: smallest peak acceleration;
        then the earlier act; then the first manoeuvre (longitudinal before lateral, the gentler
        first)."""
        allowed = self.t_acts >= t_from - 1e-6
        ok_r = self.good & allowed[:, None]
        if not ok_r.any():
            return None
        best = self.on_road.least(ok_r, self.demand)
        if best is None:
            return None
        return self._escape(*best)

    def blocked_escapes(self, t_from: float, count: int) -> list[Escape]:
        """Up to ``count`` plans acting at ``t_from`` [s] or later that keep clear of the adversary
        and stay on the road but come too close to another vehicle, least demanding first; each
        names the vehicles in its way (``Escape.blocked_by``)."""
        allowed = self.clear_of_adversary & ~self.good & (self.t_acts >= t_from - 1e-6)[:, None]
        flat = np.flatnonzero(allowed)
        flat = flat[np.lexsort((flat, self.demand.ravel()[flat]))]
        out: list[Escape] = []
        for start in range(0, len(flat), _RoadCheck.CHUNK):
            kk, mm = np.unravel_index(flat[start:start + _RoadCheck.CHUNK], allowed.shape)
            ok = self.on_road(kk, mm)
            out += [self._escape(int(k), int(m)) for k, m in zip(kk[ok], mm[ok], strict=True)][:count - len(out)]
            if len(out) >= count:
                break
        return out

    def _escape(self, kb: int, mb: int) -> Escape:
        """Candidate (kb, mb) as an :class:`Escape`, its clearance and the vehicles closer than
        :data:`MIN_CLEARANCE_M` (none for an escape)."""
        pos, yaw, ctx = self.pos, self.yaw, self.ctx
        acted = self.after[kb, 0]
        # the steps after acting only: the clearance counts nowhere else
        box = make_boxes(pos[kb, mb, acted, 0], pos[kb, mb, acted, 1], yaw[kb, mb, acted], ctx.length, ctx.width)
        gap = box_signed_distance(box, self.adv_box[acted]).min()
        blocked_by: tuple[str, ...] = ()
        if self.others is not None:
            o_box, o_valid = self.others[0][:, acted], self.others[1][:, acted]
            # a pair whose centres are farther apart than their half diagonals plus the larger of
            # this gap and the clearance is at least that far apart: it changes neither; the exact
            # distance is computed for the others only
            reach = outer_reach((ctx.length, ctx.width), o_box[..., 3], o_box[..., 4])
            centres = np.hypot(o_box[..., 0] - box[None, :, 0], o_box[..., 1] - box[None, :, 1])
            need = o_valid & (centres - reach <= max(gap, MIN_CLEARANCE_M) + 1e-6)
            per = np.full_like(o_box[..., 0], np.inf)  # (N, steps after acting)
            if need.any():
                per[need] = box_signed_distance(np.broadcast_to(box[None], o_box.shape)[need], o_box[need])
            near = per.min(1) if per.shape[1] else np.full(len(per), np.inf)
            gap = min(gap, near.min())
            blocked_by = tuple(self.other_ids[near < MIN_CLEARANCE_M].tolist())
        return Escape(t_act=float(self.t_acts[kb]), manoeuvre=ctx.man[mb], times=ctx.times.copy(),
                      x=pos[kb, mb, :, 0].copy(), y=pos[kb, mb, :, 1].copy(),
                      yaw=(yaw[kb, mb] + np.pi) % (2 * np.pi) - np.pi, speed=self.v[kb, mb].copy(),
                      clearance_m=float(gap), peak_decel=float(self.peak_decel[kb, mb]),
                      peak_lateral_accel=float(self.peak_lat[kb, mb]), peak_accel=float(self.demand[kb, mb]),
                      blocked_by=blocked_by)


def _profiles(ctx: _SearchContext, act_k: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidates' profiles, each part computed once: for every moment to act and distinct
    longitudinal part (L of them) the arc length along the path [m], speed [m/s] and longitudinal
    acceleration [m/s^2], each (K, L, T); for every moment and distinct lateral part (A) the sideways
    shift [m], (K, A, T); and each manoeuvre's longitudinal and lateral part, (M,) indices. The
    nominal log before acting, the part's profile from then on."""
    nv, man, times = ctx.nv, ctx.man, ctx.times
    n = len(times)
    lon_keys = list(dict.fromkeys((m.longitudinal, m.accel) for m in man))
    lat_keys = list(dict.fromkeys((m.lateral_m, m.lateral_accel) for m in man))
    lon_of = np.array([lon_keys.index((m.longitudinal, m.accel)) for m in man])
    lat_of = np.array([lat_keys.index((m.lateral_m, m.lateral_accel)) for m in man])
    l_count, a_count, k_count = len(lon_keys), len(lat_keys), len(act_k)
    s_nom, d_nom, a_nom = ctx.nominal_along  # (T,) each
    v_cap = float(max(nv.max(), 1.0) * 1.2 + 2.0)
    # longitudinal: arc length along the path for every (act, longitudinal part) pair
    goals = np.array([acc for _, acc in lon_keys])
    nominal = np.array([kind == "nominal" for kind, _ in lon_keys])
    tau = np.arange(n) * DT_S  # time since acting, long enough for the earliest act
    s = np.empty((k_count, l_count, n))
    v = np.empty((k_count, l_count, n))
    a_lon = np.empty((k_count, l_count, n))
    d_prof = lateral_profile(tau, np.array([d for d, _ in lat_keys]), np.array([a for _, a in lat_keys]))  # (A, n)
    d = np.empty((k_count, a_count, n))
    for j, k in enumerate(act_k):  # once per moment to act; each call is batched over the parts and steps
        rest = n - k
        sp, ac = speed_profiles(float(nv[k]), float(a_nom[k]), goals, rest - 1, v_cap)  # (L, rest)
        sp[nominal] = nv[k:]
        ac[nominal] = a_nom[k:]
        ds = np.concatenate([np.zeros((l_count, 1)), np.cumsum(0.5 * (sp[:, 1:] + sp[:, :-1]) * DT_S, 1)], 1)
        s[j, :, :k] = s_nom[:k]
        s[j, :, k:] = np.where(nominal[:, None], s_nom[k:], s_nom[k] + ds)
        v[j, :, :k] = nv[:k]
        v[j, :, k:] = sp
        a_lon[j, :, :k] = a_nom[:k]
        a_lon[j, :, k:] = ac
        d[j, :, :k] = d_nom[:k]
        d[j, :, k:] = d_nom[k] + d_prof[:, :rest]
    return s, v, a_lon, d, lon_of, lat_of


def _unwrapped(yaw: np.ndarray) -> np.ndarray:
    """``np.unwrap(yaw, axis=-1)``, run only on the rows that jump by pi or more between two steps
    (few do: a candidate's heading follows its path). A row without such a jump is its own
    unwrapping (numpy adds a zero correction to it), so the numbers are the same."""
    jump = (np.abs(np.diff(yaw, axis=-1)) >= np.pi).any(-1)
    if not jump.any():
        return yaw
    out = yaw.copy()
    out[jump] = np.unwrap(yaw[jump], axis=-1)
    return out


class _RoadCheck:
    """Whether candidate escapes stay on the drivable area, computed on demand and remembered.

    The test (footprints every :data:`OFF_ROAD_SPACING_S` against the area) costs most of the
    search when run on every clear candidate; the search needs it for few of them.
    """

    CHUNK = 8  # candidates tested at a time, in order of demand

    def __init__(self, ctx: _SearchContext, pos: np.ndarray, yaw: np.ndarray, acted: np.ndarray):
        """``pos`` (K, M, n, 2) [m] and ``yaw`` (K, M, n) [rad]: the candidates' poses on ``ctx``'s time
        grid; ``acted`` (K, n): the steps after acting."""
        drivable, length, width = ctx.drivable, ctx.length, ctx.width
        self.drivable, self.pos, self.yaw, self.length, self.width = drivable, pos, yaw, length, width
        self.acted = acted  # (K, n): steps after acting
        self.sub = ctx.road_steps
        self.known: dict[tuple[int, int], bool] = {}
        self.nominal_off = ctx.nominal_off  # where the log itself is off the road: forgiven

    def __call__(self, kk: np.ndarray, mm: np.ndarray) -> np.ndarray:
        """(G,) on the road, for candidates (kk[i], mm[i])."""
        if self.drivable is None or self.nominal_off is None:
            return np.ones(len(kk), bool)
        todo = [i for i, key in enumerate(zip(kk.tolist(), mm.tolist(), strict=True)) if key not in self.known]
        if todo:
            tk, tm = kk[todo], mm[todo]
            sub = self.sub
            # a footprint counts after acting, where the log itself is on the road; a path's test stops
            # at its first footprint off the road
            bad_rows = self.drivable.any_off_road(
                self.pos[tk, tm][:, sub, 0], self.pos[tk, tm][:, sub, 1], self.yaw[tk, tm][:, sub],
                np.asarray(self.length), np.asarray(self.width),
                where=self.acted[tk][:, sub] & ~self.nominal_off[None, :])
            bad_any: list[bool] = bad_rows.tolist()
            for k, m, bad in zip(tk.tolist(), tm.tolist(), bad_any, strict=True):
                self.known[(k, m)] = not bad
        return np.array([self.known[key] for key in zip(kk.tolist(), mm.tolist(), strict=True)], bool)

    def least(self, allowed: np.ndarray, demand: np.ndarray) -> tuple[int, int] | None:
        """The allowed candidate on the road with the smallest demand (ties within 1e-9: the first
        in (act, manoeuvre) order), or None."""
        flat = np.flatnonzero(allowed)
        flat = flat[np.lexsort((flat, demand.ravel()[flat]))]  # by demand, then position
        shape = allowed.shape
        for start in range(0, len(flat), self.CHUNK):
            chunk = flat[start:start + self.CHUNK]
            kk, mm = np.unravel_index(chunk, shape)
            ok = self(kk, mm)
            if ok.any():
                low = float(demand.ravel()[chunk[np.argmax(ok)]])
                near = flat[demand.ravel()[flat] <= low + 1e-9]  # every tie, tested too
                kk, mm = np.unravel_index(near, shape)
                ok_near = near[self(kk, mm)]
                first = int(ok_near.min())
                return int(first // shape[1]), int(first % shape[1])
        return None
