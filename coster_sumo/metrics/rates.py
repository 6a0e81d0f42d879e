"""Rates: shares of runs with their Wilson 95 % intervals (SUR, CR, ORR, RCR, defect rates, size in class)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from coster_sumo.metrics.base import Metric, MetricSample, MetricValue, RunOutcome


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


def _sur(s: MetricSample) -> MetricValue:
    hit = {o.scene for o in s.contacts}
    return rate_value([k in hit for k in s.scenes], lambda f: success_rate(len(f), sum(f)))


def _hit_in_horizon(o: RunOutcome) -> bool:
    return bool(o.contact_in_horizon if o.contact_in_horizon is not None else o.target_collision)


METRICS: tuple[Metric, ...] = (
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
    Metric("size_in_class", "fraction", "adversaries whose length and width fit one vehicle class of the corpus",
           lambda s: rate_value([o.adversary_size_in_class for o in s.outcomes if o.adversary_speed is not None])),
)
