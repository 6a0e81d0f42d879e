"""Scenario and model metrics, one function each, with one registry.

Conventions (docs/method.md, Reference figures (metric conventions)): Jensen-Shannon divergence with the
natural log (maximum ln 2); speed histograms over 0-50 m/s in 100 bins; acceleration histograms
over -10..10 m/s^2 in 200 bins; MMD with one Gaussian kernel whose bandwidth is the mean pairwise
squared distance of the pooled samples, biased estimate; impact angle = atan2 of the adversary's
position in the target frame; relative speed = |v_target - v_adv| (vector difference).

Every function takes plain numpy arrays (or sequences of per-scenario records) so that it is usable
from evaluation scripts, notebooks and tests alike.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

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


def rate_with_ci(flags: Sequence[bool]) -> dict[str, Any]:
    """{"rate", "ci_low", "ci_high", "k", "n"} of boolean outcomes (Wilson 95 %)."""
    n = len(flags)
    k = int(sum(bool(f) for f in flags))
    lo, hi = wilson_interval(k, n)
    return {"rate": k / n if n else None, "ci_low": lo if n else None, "ci_high": hi if n else None, "k": k, "n": n}


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


REGISTRY: dict[str, Callable[..., object]] = {
    "SUR": success_rate,
    "CR": collision_rate,
    "ORR": off_road_rate,
    "VDD": velocity_distribution_divergence,
    "ADD": acceleration_distribution_divergence,
    "CSD": collision_speed_diversity,
    "CPD": collision_position_diversity,
    "CPD_circular": circular_std_deg,
    "minADE_minFDE": min_ade_fde,
    "avgADE_avgFDE": avg_ade_fde,
    "MMD": mmd,
    "JSD": js_divergence,
}
