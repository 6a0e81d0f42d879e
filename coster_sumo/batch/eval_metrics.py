"""What ``eval scenarios`` computes of a method's variants besides the registry's rates: the paired
diversity differences between methods, the adversaries' states at t_col against the nominal
traffic, and the avoidability table (docs/method.md, Steps 7 and 8)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from coster_sumo.batch.generator_summary import AvoidabilityStats, PairedDiversity, VariantRecord
from coster_sumo.metrics import (
    MetricSample,
    RunOutcome,
    circular_std_deg,
    collision_position_diversity,
    collision_speed_diversity,
    compute,
    scene_bootstrap,
)

# the diversity metrics and what they read of a scene's contacts: 0 relative speeds, 1 impact angles
# (for the paired differences, which compare two methods on the same scenes)
DIVERSITY: dict[str, tuple[Callable[[np.ndarray], float], int]] = {
    "CSD": (collision_speed_diversity, 0), "CPD": (collision_position_diversity, 1),
    "CPD_circular": (circular_std_deg, 1)}
REFERENCE_METHOD = "COSTER"


def paired_diversity(per_scene: dict[str, dict[str, tuple[list[float | None], list[float | None]]]]
                     ) -> dict[str, PairedDiversity]:
    """CSD and CPD of :data:`REFERENCE_METHOD` minus those of every other method, on the scenes both
    generated for, with 95 % intervals from resampling those scenes (:func:`scene_bootstrap`): is
    an ordering a property of the methods or of the scenes drawn? Empty without the reference."""
    ref = per_scene.get(REFERENCE_METHOD)
    if ref is None:
        return {}
    out: dict[str, PairedDiversity] = {}
    for name, scenes in per_scene.items():
        if name == REFERENCE_METHOD:
            continue
        shared = [k for k in ref if k in scenes]
        differences = {}
        for col, (fn, which) in DIVERSITY.items():
            a = [np.asarray(ref[k][which], float) for k in shared]
            b = [np.asarray(scenes[k][which], float) for k in shared]
            differences[col] = scene_bootstrap(fn, a, b)  # (difference, low, high)
        out[f"{REFERENCE_METHOD} - {name}"] = PairedDiversity(len(shared), differences["CSD"], differences["CPD"],
                                                              differences["CPD_circular"])
    return out


def record_outcome(r: VariantRecord, scene: str = "") -> RunOutcome:
    """A variant's record of :func:`method_task` (``snapshot`` added by the aggregation) as the
    metrics read it; the adversary's size is checked against the corpus's vehicle classes
    (:data:`~coster_sumo.method.plausible.VEHICLE_CLASSES`) here."""
    from coster_sumo.method.plausible import VEHICLE_CLASSES

    eps = 1e-6
    length, width = r.adversary_length, r.adversary_width
    in_class = (r.adversary_speed is not None and length is not None and width is not None and any(
        l0 - eps <= length <= l1 + eps and w0 - eps <= width <= w1 + eps
        for (l0, l1), (w0, w1) in VEHICLE_CLASSES.values()))
    return RunOutcome(scene=scene, adversary_contact=r.collision, adversary_off_road=r.adversary_off_road,
                      relative_speed=r.relative_speed, impact_angle=r.impact_angle, avoidable=r.avoidable,
                      adversary_speed=r.adversary_speed, adversary_lane_type=r.adversary_lane_type,
                      adversary_size_in_class=in_class, snapshot=r.snapshot)


def adversaries_by_lane_type(sample: MetricSample) -> dict[str, int]:
    """How many adversaries (with a recorded state at t_col) stood on each lane type."""
    return dict(Counter(str(o.adversary_lane_type) for o in sample.outcomes if o.adversary_speed is not None))


def snapshot_state_metrics(records: Sequence[VariantRecord], nominal_by_type: Mapping[str, np.ndarray]
                           ) -> dict[str, Any]:
    """The adversaries' states at t_col against the nominal traffic (None where not recorded), from
    the registry of :mod:`coster_sumo.metrics` (docs/method.md, Step 7).

    ``VDD_tcol``: per lane type, the Jensen-Shannon divergence between the histograms of the
    adversaries' speeds at t_col on that type and the nominal speeds on it (an adversary on a
    freeway lane is compared with freeway traffic), averaged weighted by the adversaries on each.
    ``VDD_tcol_floor``: the same divergence for a generator that draws its speeds from the nominal
    traffic itself, with as many adversaries on each lane type (mean of
    :data:`~coster_sumo.metrics.FLOOR_DRAWS` seeded draws): a histogram of a few dozen values over
    100 bins is never near a smooth one, so this is the lowest ``VDD_tcol`` the sample size allows.
    Records with the same ``snapshot`` key (the variants of one scene share their snapshot) count as
    one draw repeated as often; a record without the key is a draw of its own.
    ``size_in_class``: share of adversaries whose length and width both lie in the range of one
    vehicle class of the corpus.
    """
    sample = MetricSample(tuple(record_outcome(r) for r in records),
                          nominal_speed_hist_by_lane_type=dict(nominal_by_type))
    return {**{name: compute(name, sample).value for name in ("VDD_tcol", "VDD_tcol_floor", "size_in_class")},
            "adversaries_by_lane_type": adversaries_by_lane_type(sample)}


def avoidability_summary(records: Sequence[VariantRecord]) -> AvoidabilityStats:
    """The labels of a method's variants (:func:`coster_sumo.avoidability.labels.avoidability_table`)."""
    from coster_sumo.avoidability.labels import avoidability_table

    return AvoidabilityStats.from_json(avoidability_table([r.to_json() for r in records]))
