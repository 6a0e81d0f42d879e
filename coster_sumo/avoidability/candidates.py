"""The target's candidate escapes on one time grid, as far as they do not depend on the adversary.

:func:`coster_sumo.avoidability.search.assess` combines, for every moment to act, the target's
manoeuvres (:mod:`coster_sumo.avoidability.evasion`) into candidate plans along its nominal path:
their poses, speeds, kinematic feasibility and peak accelerations, the other vehicles near the
path, and whether each stays on the road. None of it depends on the adversary, only on the time
grid (the adversary's appearance to the horizon after t_col), so the variants of one snapshot,
which share the grid, share a :class:`SearchContext` and build each of these once.

Times are simulation seconds, distances metres, accelerations m/s^2.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from coster_sumo.avoidability.clearance import other_boxes
from coster_sumo.avoidability.evasion import (
    DT_S,
    ClassLimits,
    Manoeuvre,
    lateral_profile,
    manoeuvres,
    speed_profiles,
    vehicle_class,
)
from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import point_at_arc_length, project_points
from coster_sumo.geometry.drivable import DrivableArea

OFF_ROAD_SPACING_S = 0.2  # [s] on-road checks every other step (a car moves < 8 m in it)


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


# ----------------------------------------------------------------------------- the candidates

@dataclass(frozen=True)
class SearchContext:
    """What every candidate of a time grid's search shares: the scene, the target's nominal states
    on the grid (nx, ny, nyaw, nv), its size and its path, and what is built from them on demand:
    the candidates of each moment to act (``rows``) and their road checks (``road_known``)."""

    scene: Scene
    target: int
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
    rows: dict[int, tuple[np.ndarray, ...]] = field(default_factory=dict)  # act step -> candidate_rows' row
    road_known: dict[tuple[int, int], bool] = field(default_factory=dict)  # (act step, manoeuvre) -> on the road

    @staticmethod
    def build(scene: Scene, target: int, t_start: float, t_col: float, drivable: DrivableArea | None
              ) -> SearchContext:
        """The context of the grid from ``t_start`` to the horizon after ``t_col`` [s]."""
        tr = scene.tracks
        ts = scene.timestamps
        valid_t = tr.valid[target]
        times = np.round(np.arange(t_start, t_col + HORIZON_AFTER_TCOL_S + 1e-9, DT_S), 6)  # (T,)
        # the target's nominal state on the grid (its log's nearest step)
        idx = np.clip(np.searchsorted(ts, times - 1e-6), 0, len(ts) - 1)
        prev = np.clip(idx - 1, 0, len(ts) - 1)
        idx = np.where(np.abs(ts[prev] - times) < np.abs(ts[idx] - times), prev, idx)
        ok = valid_t[idx]
        last_valid = np.flatnonzero(valid_t)[-1]
        idx = np.where(ok, idx, np.minimum(idx, last_valid))
        length = float(np.median(tr.length[target][valid_t]))
        width = float(np.median(tr.width[target][valid_t]))
        path = _path(np.stack([tr.x[target][valid_t], tr.y[target][valid_t]], 1), tr.heading[target][valid_t], 400.0)
        # what the target can do: its class's limits and the manoeuvres they allow
        limits = vehicle_class(int(tr.object_type[target]), length, width)
        nx, ny, nyaw = tr.x[target, idx], tr.y[target, idx], tr.heading[target, idx]
        nv = np.hypot(tr.vx[target, idx], tr.vy[target, idx])
        # after the log ends the nominal target drives on at its last speed (only the horizon needs it)
        beyond = times > ts[last_valid] + 1e-6
        if beyond.any():
            extra = times[beyond] - ts[last_valid]
            nx[beyond] += nv[beyond] * np.cos(nyaw[beyond]) * extra
            ny[beyond] += nv[beyond] * np.sin(nyaw[beyond]) * extra
        return SearchContext(scene, target, drivable, manoeuvres(limits), limits, times, nx, ny, nyaw, nv, length,
                              width, path)

    def rows_of(self, act_k: np.ndarray) -> tuple[np.ndarray, ...]:
        """:func:`candidate_rows` of the moments ``act_k``, each row built once (a row is computed
        on its own: built with others or alone, the same numbers)."""
        todo = [k for k in act_k.tolist() if k not in self.rows]
        if todo:
            batch = candidate_rows(self, np.array(todo))
            for j, k in enumerate(todo):
                self.rows[k] = tuple(a[j] for a in batch)
        got = [self.rows[k] for k in act_k.tolist()]
        return tuple(np.stack(field_rows) for field_rows in zip(*got, strict=True))

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


def candidate_rows(ctx: SearchContext, act_k: np.ndarray) -> tuple[np.ndarray, ...]:
    """The candidates of the moments to act ``act_k`` (steps of ``ctx``'s grid) as far as they do not
    depend on the adversary, one row per moment: poses ``pos`` (K, M, n, 2) and ``yaw`` (K, M, n),
    speeds ``v`` (K, M, n), the steps after acting (K, n), kinematic feasibility (K, M), and the peak
    combined, braking and lateral accelerations (K, M) each."""
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
    limits, length = ctx.limits, ctx.length
    feasible = ~(after & ((curv > limits.max_curvature(length) * 1.02) | slow_shift
                          | (a_comb > limits.emergency_decel * 1.02))).any(-1)  # (K, M)
    demand = np.max(np.where(after, a_comb, 0.0), -1)  # (K, M)
    peak_decel = np.max(np.where(after, np.maximum(-a_lon, 0.0), 0.0), -1)
    peak_lat = np.max(np.where(after & moving, a_lat, 0.0), -1)
    return pos, yaw, v, after[:, 0], feasible, demand, peak_decel, peak_lat


def _profiles(ctx: SearchContext, act_k: np.ndarray
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
