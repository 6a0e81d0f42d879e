"""The metric base types and the registry every figure of ``run``, ``regress`` and ``eval scenarios`` comes from.

A :class:`Metric` computes one :class:`MetricValue` of one :class:`MetricSample` (a :class:`RunOutcome` per
variant driven, and more). The families (:mod:`.rates`, :mod:`.distributions`, :mod:`.impacts`) define their
metrics; :mod:`coster_sumo.metrics` registers them, in the order the reports list them, with
:func:`register_metric`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np


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


REGISTRY: dict[str, Metric] = {}


def register_metric(metric: Metric) -> Metric:
    """Add ``metric`` to :data:`REGISTRY` (a second metric of the same name is a programming error)."""
    if metric.name in REGISTRY:
        raise ValueError(f"metric {metric.name!r} is registered twice")
    REGISTRY[metric.name] = metric
    return metric


def compute(name: str, sample: MetricSample) -> MetricValue:
    """The metric ``name`` of :data:`REGISTRY` on ``sample``: how ``run``, ``regress`` and ``eval
    scenarios`` get every figure of this registry."""
    return REGISTRY[name].compute(sample)


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, None where it is NaN or infinite (a figure JSON can hold)."""
    return float(x) if math.isfinite(x) else None
