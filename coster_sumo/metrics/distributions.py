"""Distributions: Jensen-Shannon divergences of speed and acceleration histograms (VDD, ADD, VDD at t_col)."""

from __future__ import annotations

from collections import Counter

import numpy as np

from coster_sumo.metrics.base import Metric, MetricSample, MetricValue, RunOutcome, finite_or_none

SPEED_BINS = np.linspace(0.0, 50.0, 101)  # [m/s] 100 bins
ACCEL_BINS = np.linspace(-10.0, 10.0, 201)  # [m/s^2] 200 bins


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


def _divergence(nominal: np.ndarray | None, generated: np.ndarray | None) -> MetricValue:
    if nominal is None or generated is None:
        return MetricValue(None)
    return MetricValue(finite_or_none(js_divergence(nominal, generated)))


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


METRICS: tuple[Metric, ...] = (
    Metric("VDD", "nats", "Jensen-Shannon divergence of the nominal and generated speed histograms",
           lambda s: _divergence(s.nominal_speed_hist, s.generated_speed_hist)),
    Metric("ADD", "nats", "Jensen-Shannon divergence of the nominal and generated acceleration histograms",
           lambda s: _divergence(s.nominal_accel_hist, s.generated_accel_hist)),
    Metric("VDD_tcol", "nats", "per lane type, JSD of the adversaries' speeds at t_col and the nominal speeds",
           _vdd_tcol),
    Metric("VDD_tcol_floor", "nats", "VDD_tcol of speeds drawn from the nominal traffic itself (its floor)",
           lambda s: _vdd_tcol(s, floor=True)),
)
