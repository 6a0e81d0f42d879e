"""Impacts: where and how hard adversaries touch targets, and how diverse that is (CSD, CPD, time to collision)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from coster_sumo.metrics.base import Metric, MetricSample, MetricValue, RunOutcome, finite_or_none


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


def _diversity(stat: Callable[[np.ndarray], float], of: Callable[[RunOutcome], float | None]
               ) -> Callable[[MetricSample], MetricValue]:
    """A diversity of the contacts' values ``of(outcome)`` with its interval from resampling scenes."""
    def compute(s: MetricSample) -> MetricValue:
        pooled = [of(o) for o in s.contacts]  # a missing value (None) is NaN, as in the plain functions
        per_scene = [np.asarray([of(o) for o in s.contacts if o.scene == k], np.float64) for k in s.scenes]
        _, lo, hi = scene_bootstrap(stat, per_scene)
        return MetricValue(finite_or_none(stat(np.asarray(pooled, np.float64))) if pooled else None, lo, hi)
    return compute


def _of(stat: Callable[[np.ndarray], float], values: Sequence[float | None]) -> MetricValue:
    """``stat`` of ``values`` (None: NaN); None without values."""
    return MetricValue(float(stat(np.asarray(values, np.float64))) if len(values) else None)


METRICS: tuple[Metric, ...] = (
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
)
