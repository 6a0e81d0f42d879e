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

import numpy as np

from coster_sumo.avoidability.candidates import SearchContext
from coster_sumo.avoidability.clearance import hits_adversary, outer_reach, too_close
from coster_sumo.avoidability.evasion import (
    DEFAULT_REACTION_S,
    DT_S,
    Avoidability,
    Escape,
    Manoeuvre,
    Motion,
    contact_kind,
    threat_time,
)
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import (
    box_signed_distance,
    make_boxes,
)
from coster_sumo.geometry.drivable import DrivableArea

# HORIZON_AFTER_TCOL_S (coster_sumo.core.plan) [s]: an escape must stay clear and on the road this long after t_col
MIN_CLEARANCE_M = 0.3  # [m] smallest gap an escape keeps to every box (the SUMO replay is the arbiter)
REACTION_TIMES_S = (0.5, 1.0, 1.5)  # [s] reaction times reported for every variant
ACT_SPACING_S = 0.2  # [s] moments to act are searched on this grid (plus the reaction moments)
# candidates clear of the adversary and blocked only by traffic that reacts, tried in SUMO per
# reaction time without an escape: the least demanding few (docs/method.md step 8)
BLOCKED_TRIED_PER_REACTION = 2
EARLY_CHUNK = 5  # moments to act before the shortest reaction, built at a time (latest first)


# ----------------------------------------------------------------------------- the search

def assess(scene: Scene, target: int, plan: AdversaryPlan, drivable: DrivableArea | None,
           reaction_times: tuple[float, ...] = REACTION_TIMES_S, reaction_time_s: float = DEFAULT_REACTION_S,
           reactive_others: bool = False, shared: dict[tuple[float, float], SearchContext] | None = None
           ) -> Avoidability:
    """Search the target's escapes from ``plan`` in ``scene`` (module docstring); kinematic only
    (the SUMO replay, :mod:`coster_sumo.avoidability.proof`, confirms or refutes each escape).

    ``reactive_others``: the other vehicles are SUMO's drivers in the proof (a SUMO configuration);
    then, for every reaction time without an escape, the :data:`BLOCKED_TRIED_PER_REACTION` least
    demanding plans that keep clear of the adversary but not of another vehicle are kept in
    ``Avoidability.blocked`` for the proof to try: there that vehicle reacts.

    ``shared``: a dict a caller keeps while it labels several plans of one scene, target and
    drivable area. The target's candidates (poses, kinematic limits, road check, the other vehicles
    near its path) depend on the time grid alone, that is on the plan's appearance and t_col, so
    plans that share the grid (a snapshot's variants do) share them: the same numbers, built once."""
    t_col = plan.t_col
    key = (float(plan.t_start), float(t_col))
    ctx = shared.get(key) if shared is not None else None
    if ctx is None:
        ctx = SearchContext.build(scene, target, plan.t_start, t_col, drivable)
        if shared is not None:
            shared[key] = ctx
    times, nx, ny, nyaw, nv = ctx.times, ctx.nx, ctx.ny, ctx.nyaw, ctx.nv
    length, width, limits, man = ctx.length, ctx.width, ctx.limits, ctx.man
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

    ax, ay, ayaw, _ = plan.sample(times)
    adv_box = make_boxes(ax, ay, ayaw, plan.length, plan.width)  # (T, 5): its plan, then along the road
    t_acts_all = times[act_k]
    # the moments before the shortest reaction serve only the last moment to act, which is searched
    # from the latest moment back: they are computed only when no later moment has an escape, a
    # few moments at a time from the latest (each row is computed on its own: the same answer)
    late = t_acts_all >= t_threat + min(reaction_times) - 1e-6
    late_cand = _Candidates(ctx, act_k[late], adv_box) if late.any() else None
    last_moment = late_cand.last_moment(t_col) if late_cand is not None else None
    early = act_k[~late]
    for stop in range(len(early), 0, -EARLY_CHUNK):
        if last_moment is not None:
            break
        last_moment = _Candidates(ctx, early[max(0, stop - EARLY_CHUNK):stop], adv_box).last_moment(t_col)
    blocked: dict[tuple[float, Manoeuvre], Escape] = {}
    if late_cand is not None:
        for r in reaction_times:
            escapes[r] = late_cand.least_escape(t_threat + r)
            if reactive_others and escapes[r] is None:
                for e in late_cand.blocked_escapes(t_threat + r, BLOCKED_TRIED_PER_REACTION):
                    blocked.setdefault((round(e.t_act, 3), e.manoeuvre), e)
    return Avoidability(t_col, plan.t_start, t_threat, kind, limits.name, last_moment, escapes, reaction_time_s,
                        candidates=int(len(act_k) * len(man)), blocked=list(blocked.values()))


class _Candidates:
    """The (act, manoeuvre) candidates of the moments to act ``act_k`` (steps of the time grid): their
    poses, kinematic feasibility and clearance to the adversary and the other vehicles.

    Every row (one moment to act) is computed on its own, each candidate's tests over its own steps
    after acting, so a subset of the moments gives the same rows as the whole grid.
    """

    def __init__(self, ctx: SearchContext, act_k: np.ndarray, adv_box: np.ndarray) -> None:
        """``adv_box`` (n, 5): the adversary's boxes on ``ctx``'s grid (its plan, then along the road)."""
        self.ctx, self.act_k = ctx, act_k
        pos, yaw, v, after, feasible, self.demand, self.peak_decel, self.peak_lat = ctx.rows_of(act_k)
        after = after[:, None, :]  # (K, 1, n)
        # clearance to the adversary (its plan, then constant velocity) and to every other vehicle
        self.adv_box = adv_box  # (n, 5)
        # boxes grown by the clearance on every side: an overlap (SAT, no corners) means too close
        grown = (ctx.length + 2 * MIN_CLEARANCE_M, ctx.width + 2 * MIN_CLEARANCE_M)
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
        self.on_road = _RoadCheck(ctx, act_k, pos, yaw, after[:, 0])
        self.t_acts = ctx.times[act_k]
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


class _RoadCheck:
    """Whether candidate escapes stay on the drivable area, computed on demand and remembered.

    The test (footprints every :data:`OFF_ROAD_SPACING_S` against the area) costs most of the
    search when run on every clear candidate; the search needs it for few of them.
    """

    CHUNK = 8  # candidates tested at a time, in order of demand

    def __init__(self, ctx: SearchContext, act_k: np.ndarray, pos: np.ndarray, yaw: np.ndarray, acted: np.ndarray):
        """``pos`` (K, M, n, 2) [m] and ``yaw`` (K, M, n) [rad]: the candidates' poses on ``ctx``'s time
        grid, acting at its steps ``act_k`` (K,); ``acted`` (K, n): the steps after acting. What is
        known is kept in ``ctx`` (by act step and manoeuvre): every plan of the grid shares it."""
        drivable, length, width = ctx.drivable, ctx.length, ctx.width
        self.drivable, self.pos, self.yaw, self.length, self.width = drivable, pos, yaw, length, width
        self.acted = acted  # (K, n): steps after acting
        self.sub = ctx.road_steps
        self.act_k = act_k.tolist()
        self.known = ctx.road_known
        self.nominal_off = ctx.nominal_off  # where the log itself is off the road: forgiven

    def __call__(self, kk: np.ndarray, mm: np.ndarray) -> np.ndarray:
        """(G,) on the road, for candidates (kk[i], mm[i])."""
        if self.drivable is None or self.nominal_off is None:
            return np.ones(len(kk), bool)
        keys = [(self.act_k[k], m) for k, m in zip(kk.tolist(), mm.tolist(), strict=True)]
        todo = [i for i, key in enumerate(keys) if key not in self.known]
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
            for i, bad in zip(todo, bad_any, strict=True):
                self.known[keys[i]] = not bad
        return np.array([self.known[key] for key in keys], bool)

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
