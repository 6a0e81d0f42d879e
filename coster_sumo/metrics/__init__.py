"""Scenario and model metrics, one function each, with one registry.

Conventions (docs/method.md, Reference figures (metric conventions)): Jensen-Shannon divergence with the
natural log (maximum ln 2); speed histograms over 0-50 m/s in 100 bins; acceleration histograms
over -10..10 m/s^2 in 200 bins; MMD with one Gaussian kernel whose bandwidth is the mean pairwise
squared distance of the pooled samples, biased estimate; impact angle = atan2 of the adversary's
position in the target frame; relative speed = |v_target - v_adv| (vector difference).

Every function takes plain numpy arrays, usable from scripts, notebooks and tests alike. The figures
the commands report come from :data:`REGISTRY`: each :class:`Metric` computes one
:class:`MetricValue` of one :class:`MetricSample` (a :class:`RunOutcome` per variant driven, and more).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

SPEED_BINS = np.linspace(0.0, 50.0, 101)  # [m/s] 100 bins
ACCEL_BINS = np.linspace(-10.0, 10.0, 201)  # [m/s^2] 200 bins


# ----------------------------------------------------------------------------- rates

def success_rate(num_scenes: int, num_generated: int) -> float:
    """SUR: share of raw scenes that yield a collision scenario (num_generated / num_scenes)."""
    return float(num_generated) / num_scenes if num_scenes else float("nan")


def collision_rate(collided: Sequence[bool] | np.ndarray) -> float:
    """CR: share of generated scenarios in which adversary and target collide."""
    c = np.asarray(collided, dtype=bool)
    return float(c.mean()) if c.size else float("nan")


def off_road_rate(off_road: Sequence[bool] | np.ndarray) -> float:
    """ORR: share of adversary trajectories that leave the drivable road."""
    o = np.asarray(off_road, dtype=bool)
    return float(o.mean()) if o.size else float("nan")


def route_completion_rate(completed: Sequence[bool] | np.ndarray) -> float:
    """RCR: share of runs in which the target completes its route."""
    c = np.asarray(completed, dtype=bool)
    return float(c.mean()) if c.size else float("nan")


WILSON_Z = 1.959963984540054  # two-sided 95 %


def wilson_interval(successes: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); (nan, nan) when n = 0."""
    if n <= 0:
        return float("nan"), float("nan")
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


# ----------------------------------------------------------------------------- distributions

def js_divergence(p: np.ndarray, q: np.ndarray) -> float:
    """Jensen-Shannon divergence of two histograms (normalised here), natural log: in [0, ln 2]."""
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    if p.sum() <= 0 or q.sum() <= 0:
        return float("nan")
    p = p / p.sum()
    q = q / q.sum()
    m = 0.5 * (p + q)

    def kl(a: np.ndarray, b: np.ndarray) -> float:
        nz = a > 0
        return float(np.sum(a[nz] * np.log(a[nz] / b[nz])))

    return 0.5 * kl(p, m) + 0.5 * kl(q, m)


def speeds_and_accels(xy: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Pooled speeds [m/s] and longitudinal accelerations [m/s^2] of trajectories.

    Args:
        xy: (num_traj, num_steps, 2) float64 [m].
        valid: (num_traj, num_steps) bool.
        dt: step length [s].
    Returns: 1-D arrays of all valid speeds and all valid accelerations (finite differences; a
    difference counts only where both of its ends are valid).
    """
    d = np.linalg.norm(np.diff(xy, axis=1), axis=-1) / dt  # (N, T-1)
    v_ok = valid[:, 1:] & valid[:, :-1]
    acc = np.diff(d, axis=1) / dt  # (N, T-2)
    a_ok = v_ok[:, 1:] & v_ok[:, :-1]
    return d[v_ok], acc[a_ok]


def velocity_distribution_divergence(raw_speeds: np.ndarray, gen_speeds: np.ndarray) -> float:
    """VDD: JSD between speed histograms (0-50 m/s, 100 bins) of raw and generated trajectories."""
    h_raw, _ = np.histogram(np.clip(raw_speeds, 0, 50), bins=SPEED_BINS)
    h_gen, _ = np.histogram(np.clip(gen_speeds, 0, 50), bins=SPEED_BINS)
    return js_divergence(h_raw, h_gen)


def acceleration_distribution_divergence(raw_accels: np.ndarray, gen_accels: np.ndarray) -> float:
    """ADD: JSD between acceleration histograms (-10..10 m/s^2, 200 bins), raw vs generated."""
    h_raw, _ = np.histogram(np.clip(raw_accels, -10, 10), bins=ACCEL_BINS)
    h_gen, _ = np.histogram(np.clip(gen_accels, -10, 10), bins=ACCEL_BINS)
    return js_divergence(h_raw, h_gen)


# ----------------------------------------------------------------------------- impacts

def impact_angle_deg(target_xy: np.ndarray, target_yaw: np.ndarray, adv_xy: np.ndarray) -> np.ndarray:
    """Angle of the adversary's position in the target frame [deg] in (-180, 180].

    0 = straight ahead of the target, 90 = on its left, -90 = on its right, 180 = behind.
    Args: target_xy (..., 2), target_yaw (...) [rad], adv_xy (..., 2).
    """
    d = np.asarray(adv_xy, float) - np.asarray(target_xy, float)
    c, s = np.cos(target_yaw), np.sin(target_yaw)
    lon = c * d[..., 0] + s * d[..., 1]
    lat = -s * d[..., 0] + c * d[..., 1]
    return np.degrees(np.arctan2(lat, lon))


def relative_speed(target_v: np.ndarray, adv_v: np.ndarray) -> np.ndarray:
    """|v_target - v_adv| [m/s] of velocity vectors (..., 2)."""
    return np.linalg.norm(np.asarray(target_v, float) - np.asarray(adv_v, float), axis=-1)


def collision_speed_diversity(rel_speeds: Sequence[float] | np.ndarray) -> float:
    """CSD: standard deviation of the relative speed at first contact [m/s] (population std)."""
    r = np.asarray(rel_speeds, float)
    return float(r.std()) if r.size else float("nan")


def collision_position_diversity(angles_deg: Sequence[float] | np.ndarray) -> float:
    """CPD: standard deviation of the impact angle in the target frame [deg] (linear, as peers do)."""
    a = np.asarray(angles_deg, float)
    return float(a.std()) if a.size else float("nan")


def circular_range_deg(angles_deg: Sequence[float] | np.ndarray) -> float:
    """[deg] Width of the smallest arc of the circle that holds every angle (0 for one angle;
    -180 and 180 are the same angle): 360 minus the widest gap between neighbouring angles."""
    a = np.sort(np.mod(np.asarray(angles_deg, np.float64), 360.0))
    if len(a) < 2:
        return 0.0
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    return float(360.0 - gaps.max())


def circular_std_deg(angles_deg: Sequence[float] | np.ndarray) -> float:
    """Circular standard deviation sqrt(-2 ln R) of angles [deg], R = mean resultant length.

    Unlike the linear std it treats -179 and 179 degrees as neighbours.
    """
    a = np.radians(np.asarray(angles_deg, float))
    if a.size == 0:
        return float("nan")
    r = np.hypot(np.cos(a).mean(), np.sin(a).mean())
    # R rounds to 1 or a hair past it for identical angles: clamp so the result is +0, not -0.0 or nan
    return float(np.degrees(np.sqrt(max(0.0, -2.0 * np.log(max(r, 1e-300))))))


BOOTSTRAP_DRAWS = 1000


def scene_bootstrap(stat: Callable[[np.ndarray], float], scenes: Sequence[np.ndarray],
                    other: Sequence[np.ndarray] | None = None, draws: int = BOOTSTRAP_DRAWS,
                    seed: int = 0) -> tuple[float, float, float]:
    """A pooled statistic (CSD, CPD) with a 95 % percentile interval from resampling scenes.

    ``scenes`` holds one array per scene (its variants' values; the variants of a scene share a
    snapshot, so the scene, not the variant, is the independent draw). With ``other`` (one array
    per scene, the same scenes in the same order: a second method on them), the statistic is the
    difference ``stat(scenes) - stat(other)``, both pooled over the same resampled scenes (a paired
    comparison). Returns (value, low, high); NaN where a pool is empty.
    """
    def pooled(arrays: Sequence[np.ndarray], idx: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(arrays[i], float).ravel() for i in idx]) if len(idx) else np.zeros(0)

    def value(idx: np.ndarray) -> float:
        a = pooled(scenes, idx)
        v = stat(a) if a.size else float("nan")
        if other is not None:
            b = pooled(other, idx)
            v = v - stat(b) if b.size else float("nan")
        return float(v)

    n = len(scenes)
    if other is not None and len(other) != n:
        raise ValueError(f"paired bootstrap needs the same scenes: {n} against {len(other)}")
    full = value(np.arange(n))
    if n == 0:
        return full, float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    reps = np.array([value(rng.integers(0, n, n)) for _ in range(draws)])
    reps = reps[np.isfinite(reps)]
    if reps.size == 0:
        return full, float("nan"), float("nan")
    lo, hi = np.percentile(reps, [2.5, 97.5])
    return full, float(lo), float(hi)


# ----------------------------------------------------------------------------- trajectories

def ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Average and final displacement error per sample.

    Args:
        pred: (..., num_samples, num_steps, 2) [m].
        truth: (..., num_steps, 2) [m].
        valid: (..., num_steps) bool or None.
    Returns: ade, fde each (..., num_samples); the final step is the last valid one.
    """
    err = np.linalg.norm(pred - truth[..., None, :, :], axis=-1)  # (..., S, T)
    if valid is None:
        valid = np.ones(truth.shape[:-1], bool)
    w = valid[..., None, :].astype(float)
    ade = (err * w).sum(-1) / np.maximum(w.sum(-1), 1.0)
    last = valid.shape[-1] - 1 - np.argmax(valid[..., ::-1], axis=-1)  # (...)
    fde = np.take_along_axis(err, np.broadcast_to(last[..., None, None], err.shape[:-1] + (1,)),
                             axis=-1)[..., 0]
    return ade, fde


def min_ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """minADE / minFDE over the samples axis (each minimised independently)."""
    ade, fde = ade_fde(pred, truth, valid)
    return ade.min(-1), fde.min(-1)


def avg_ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """avgADE / avgFDE: mean over the samples axis."""
    ade, fde = ade_fde(pred, truth, valid)
    return ade.mean(-1), fde.mean(-1)


def mmd(x: np.ndarray, y: np.ndarray) -> float:
    """Biased MMD^2 estimate with one Gaussian kernel, bandwidth = mean pairwise squared distance.

    k(a, b) = exp(-|a - b|^2 / h), h = mean of |a - b|^2 over all pairs of the pooled samples.
    Args: x (n, d), y (m, d) (1-D inputs are treated as d = 1).
    """
    x = np.asarray(x, float).reshape(len(x), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    if len(x) == 0 or len(y) == 0:
        return float("nan")
    z = np.concatenate([x, y])
    sq = np.sum(z * z, axis=1)
    d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * z @ z.T, 0.0)
    h = d2.mean()
    if h <= 0:
        return 0.0
    k = np.exp(-d2 / h)
    n = len(x)
    return float(k[:n, :n].mean() + k[n:, n:].mean() - 2.0 * k[:n, n:].mean())


# ----------------------------------------------------------------------------- the registry

@dataclass(frozen=True)
class MetricValue:
    """What a metric computes: its value and, where it has one, its 95 % interval.

    Attributes:
        value: the figure in the metric's unit; None where it is undefined (no runs, no contact).
        ci_low, ci_high: the interval (a rate's Wilson interval, a diversity's scene bootstrap);
            None where the metric has none or has no runs.
        k, n: for a rate, the runs that count and the runs it is over; None otherwise.
    """

    value: float | None
    ci_low: float | None = None
    ci_high: float | None = None
    k: int | None = None
    n: int | None = None

    def rate_json(self) -> dict[str, float | int | None]:
        """A rate as the reports write it: ``{"rate", "ci_low", "ci_high", "k", "n"}``."""
        return {"rate": self.value, "ci_low": self.ci_low, "ci_high": self.ci_high, "k": self.k, "n": self.n}


@dataclass(frozen=True)
class RunOutcome:
    """One variant as one planner drove it: everything a scenario metric reads of it.

    Attributes:
        scene: the scene it was generated for (SUR counts scenes; the diversities resample them).
        adversary_contact: the adversary touched the target (our box check).
        target_collision: the target touched the adversary or any other vehicle.
        adversary_off_road, target_off_road: more than 0.5 m^2 of the box left the drivable area.
        route_completed: the target finished its route.
        relative_speed: [m/s] at the adversary's contact; impact_angle: [deg] in the target's frame.
        min_ttc: [s] the smallest time to collision before the contact (None: never closing).
        avoidable: the variant's avoidability label (None: unlabelled); contact_in_horizon: the
            target was hit within the label's horizon (None: not recorded, the collision counts).
        adversary_speed: [m/s] at t_col; adversary_lane_type: the :class:`~coster_sumo.core.scene.LaneType`
            name under it then; adversary_size_in_class: its length and width fit one vehicle class
            of the corpus; snapshot: the key of its collision snapshot (a scene's variants share one).
    """

    scene: str = ""
    adversary_contact: bool = False
    target_collision: bool = False
    adversary_off_road: bool = False
    target_off_road: bool = False
    route_completed: bool = False
    relative_speed: float | None = None
    impact_angle: float | None = None
    min_ttc: float | None = None
    avoidable: bool | None = None
    contact_in_horizon: bool | None = None
    adversary_speed: float | None = None
    adversary_size_in_class: bool = False
    adversary_lane_type: str | None = None
    snapshot: str | None = None


@dataclass(frozen=True)
class MetricSample:
    """What every scenario metric computes on.

    Attributes:
        outcomes: the variants' outcomes.
        scenes: the scenes tried, in order (SUR's denominator; the draws of the scene bootstrap).
        nominal_speed_hist, generated_speed_hist: (100,) counts over :data:`SPEED_BINS` of the
            nominal and the generated trajectories; nominal_accel_hist, generated_accel_hist:
            (200,) counts over :data:`ACCEL_BINS` (None: not recorded).
        nominal_speed_hist_by_lane_type: (100,) counts of the nominal vehicles' speeds at 2 Hz per
            lane type name (VDD at t_col).
    """

    outcomes: tuple[RunOutcome, ...] = ()
    scenes: tuple[str, ...] = ()
    nominal_speed_hist: np.ndarray | None = None
    generated_speed_hist: np.ndarray | None = None
    nominal_accel_hist: np.ndarray | None = None
    generated_accel_hist: np.ndarray | None = None
    nominal_speed_hist_by_lane_type: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def contacts(self) -> list[RunOutcome]:
        return [o for o in self.outcomes if o.adversary_contact]


@dataclass(frozen=True)
class Metric:
    """A scenario metric: a name, its unit and meaning, and one ``compute(sample) -> MetricValue``."""

    name: str
    unit: str
    description: str
    fn: Callable[[MetricSample], MetricValue]

    def compute(self, sample: MetricSample) -> MetricValue:
        return self.fn(sample)


def rate_value(flags: Sequence[bool], share: Callable[[Sequence[bool]], float] | None = None) -> MetricValue:
    """The share of true ``flags`` (k / n, or what ``share`` computes of them) with its Wilson 95 %
    interval, k and n; value and interval None without flags."""
    n, k = len(flags), int(sum(bool(f) for f in flags))
    if not n:
        return MetricValue(None, None, None, k, n)
    lo, hi = wilson_interval(k, n)
    return MetricValue(share(flags) if share else k / n, lo, hi, k, n)


def rate_with_ci(flags: Sequence[bool]) -> dict[str, float | int | None]:
    """{"rate", "ci_low", "ci_high", "k", "n"} of boolean outcomes (Wilson 95 %)."""
    return rate_value(flags).rate_json()


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _sur(s: MetricSample) -> MetricValue:
    hit = {o.scene for o in s.contacts}
    return rate_value([k in hit for k in s.scenes], lambda f: success_rate(len(f), sum(f)))


def _divergence(nominal: np.ndarray | None, generated: np.ndarray | None) -> MetricValue:
    return MetricValue(None if nominal is None or generated is None else _finite(js_divergence(nominal, generated)))


def _diversity(stat: Callable[[np.ndarray], float], of: Callable[[RunOutcome], float | None]
               ) -> Callable[[MetricSample], MetricValue]:
    """A diversity of the contacts' values ``of(outcome)`` with its interval from resampling scenes."""
    def compute(s: MetricSample) -> MetricValue:
        pooled = [of(o) for o in s.contacts]  # a missing value (None) is NaN, as in the plain functions
        per_scene = [np.asarray([of(o) for o in s.contacts if o.scene == k], np.float64) for k in s.scenes]
        _, lo, hi = scene_bootstrap(stat, per_scene)
        return MetricValue(_finite(stat(np.asarray(pooled, np.float64))) if pooled else None, lo, hi)
    return compute


def _hit_in_horizon(o: RunOutcome) -> bool:
    return bool(o.contact_in_horizon if o.contact_in_horizon is not None else o.target_collision)


def _of(stat: Callable[[np.ndarray], float], values: Sequence[float | None]) -> MetricValue:
    """``stat`` of ``values`` (None: NaN); None without values."""
    return MetricValue(float(stat(np.asarray(values, np.float64))) if len(values) else None)


FLOOR_DRAWS = 200  # draws from the nominal traffic behind ``VDD_tcol_floor``


def _lane_types(s: MetricSample) -> list[tuple[int, np.ndarray, list[tuple[int, RunOutcome]]]]:
    """Per lane type under the adversaries at t_col (first seen first) with nominal traffic: how many, the
    nominal speed histogram, the (index, outcome)s among the outcomes with a recorded adversary."""
    rows = [o for o in s.outcomes if o.adversary_speed is not None]
    counts = Counter(o.adversary_lane_type for o in rows)
    out = []
    for kind, n in counts.items():
        nominal = np.asarray(s.nominal_speed_hist_by_lane_type.get(str(kind), ()), np.float64)
        if nominal.sum() > 0:
            out.append((n, nominal, [(i, o) for i, o in enumerate(rows) if o.adversary_lane_type == kind]))
    return out


def _vdd_tcol(s: MetricSample, floor: bool = False) -> MetricValue:
    """Per lane type, the JSD of the adversaries' speeds at t_col and the nominal speeds on that type,
    averaged weighted by the adversaries on each (docs/method.md, Step 7). ``floor``: the same for
    speeds drawn from the nominal traffic itself, as many draws as distinct snapshots on the type (a
    snapshot shared by k variants counts k times), mean of :data:`FLOOR_DRAWS` seeded draws."""
    kinds = _lane_types(s)
    weight = sum(n for n, _, _ in kinds)
    rng = np.random.default_rng(0)
    total = 0.0
    for n, nominal, on_kind in kinds:
        if not floor:
            hist = np.histogram(np.clip([o.adversary_speed for _, o in on_kind], 0, 50), bins=SPEED_BINS)[0]
            total += n * float(js_divergence(nominal, hist))
            continue
        repeats = np.array(list(Counter(o.snapshot or f"#{i}" for i, o in on_kind).values()))
        drawn = rng.choice(len(nominal), size=(FLOOR_DRAWS, len(repeats)), p=nominal / nominal.sum())
        total += n * float(np.mean([js_divergence(nominal, np.bincount(d, weights=repeats, minlength=len(nominal)))
                                    for d in drawn]))
    return MetricValue(total / weight if weight else None)


REGISTRY: dict[str, Metric] = {m.name: m for m in (
    Metric("SUR", "fraction", "scenes with at least one variant whose adversary touches the target", _sur),
    Metric("CR", "fraction", "variants whose adversary touches the target",
           lambda s: rate_value([o.adversary_contact for o in s.outcomes], collision_rate)),
    Metric("ORR", "fraction", "variants whose adversary leaves the drivable area",
           lambda s: rate_value([o.adversary_off_road for o in s.outcomes], off_road_rate)),
    Metric("CR_target", "fraction", "runs in which the target touches the adversary or any other vehicle",
           lambda s: rate_value([o.target_collision for o in s.outcomes], collision_rate)),
    Metric("ORR_target", "fraction", "runs in which the target leaves the drivable area",
           lambda s: rate_value([o.target_off_road for o in s.outcomes], off_road_rate)),
    Metric("RCR", "fraction", "runs in which the target completes its route",
           lambda s: rate_value([o.route_completed for o in s.outcomes], route_completion_rate)),
    Metric("defect_rate", "fraction", "runs on avoidable variants whose target is hit within the label's horizon",
           lambda s: rate_value([_hit_in_horizon(o) for o in s.outcomes if o.avoidable])),
    Metric("unavoidable_contact_rate", "fraction", "the same on unavoidable variants",
           lambda s: rate_value([_hit_in_horizon(o) for o in s.outcomes if o.avoidable is False])),
    Metric("VDD", "nats", "Jensen-Shannon divergence of the nominal and generated speed histograms",
           lambda s: _divergence(s.nominal_speed_hist, s.generated_speed_hist)),
    Metric("ADD", "nats", "Jensen-Shannon divergence of the nominal and generated acceleration histograms",
           lambda s: _divergence(s.nominal_accel_hist, s.generated_accel_hist)),
    Metric("CSD", "m/s", "standard deviation of the relative speed at contact",
           _diversity(collision_speed_diversity, lambda o: o.relative_speed)),
    Metric("CPD", "deg", "standard deviation of the impact angle in the target's frame",
           _diversity(collision_position_diversity, lambda o: o.impact_angle)),
    Metric("CPD_circular", "deg", "circular standard deviation of the impact angle in the target's frame",
           _diversity(circular_std_deg, lambda o: o.impact_angle)),
    Metric("impact_angle_spread", "deg", "the smallest arc that holds every impact angle",
           lambda s: _of(circular_range_deg, [o.impact_angle for o in s.contacts])),
    Metric("median_min_ttc", "s", "median smallest time to collision of the runs without the adversary's contact",
           lambda s: _of(np.median, [o.min_ttc for o in s.outcomes if o.min_ttc is not None
                                     and not o.adversary_contact])),
    Metric("mean_relative_speed", "m/s", "mean relative speed at the adversary's contact",
           lambda s: _of(np.mean, [o.relative_speed for o in s.outcomes if o.relative_speed is not None])),
    Metric("VDD_tcol", "nats", "per lane type, JSD of the adversaries' speeds at t_col and the nominal speeds",
           _vdd_tcol),
    Metric("VDD_tcol_floor", "nats", "VDD_tcol of speeds drawn from the nominal traffic itself (its floor)",
           lambda s: _vdd_tcol(s, floor=True)),
    Metric("size_in_class", "fraction", "adversaries whose length and width fit one vehicle class of the corpus",
           lambda s: rate_value([o.adversary_size_in_class for o in s.outcomes if o.adversary_speed is not None])),
)}


def compute(name: str, sample: MetricSample) -> MetricValue:
    """The metric ``name`` of :data:`REGISTRY` on ``sample``: how ``run``, ``regress`` and ``eval
    scenarios`` get every figure of this registry."""
    return REGISTRY[name].compute(sample)
