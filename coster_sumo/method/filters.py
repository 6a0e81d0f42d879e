"""Filters of candidates (docs/method.md step 6): a generated plan is kept only when it meets the
target at t_col, not before, and runs into no other vehicle on its way.

Both checks read the nominal scene at its own rate (10 Hz): the target's and the other vehicles'
logged boxes against the plan's, from the plan's start to t_col minus a tolerance.

What a variant's SUMO pass must show to be kept is the injection's
(:mod:`coster_sumo.sim.outcomes`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import CONTACT_TOLERANCE_M, box_signed_distance, make_boxes


def _checked_steps(plan: AdversaryPlan, times: np.ndarray, tolerance_s: float) -> np.ndarray:
    """(T,) bool: the scene steps from the plan's start to t_col - ``tolerance_s``, with half a step
    of margin against the log's timestamp jitter (the steps the contact filters look at)."""
    half_step = 0.5 * float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    return (times >= plan.t_start - 1e-9) & (times < plan.t_col - tolerance_s - half_step)


def early_contact(plan: AdversaryPlan, scene: Scene, target: int, tolerance_s: float = 0.1) -> float | None:
    """Time [s] at which ``plan`` would overlap the target's nominal path before t_col - tolerance.

    Checked at the nominal scene's own rate (10 Hz) against the target's logged boxes; a variant
    that hits the target early is not the snapshot's collision and is not kept. The steps within
    ``tolerance_s`` of t_col are not checked, whatever the log's timestamp jitter (half a step of
    margin): with the default, touching one step early is allowed, two steps is not.
    """
    t = scene.tracks
    times = scene.timestamps
    sel = _checked_steps(plan, times, tolerance_s) & t.valid[target]
    if not sel.any():
        return None
    x, y, yaw, _ = plan.sample(times[sel])
    adv = make_boxes(x, y, yaw, plan.length, plan.width)
    tgt = make_boxes(t.x[target, sel], t.y[target, sel], t.heading[target, sel], t.length[target, sel],
                     t.width[target, sel])
    hit = box_signed_distance(adv, tgt) <= CONTACT_TOLERANCE_M
    return float(times[sel][np.argmax(hit)]) if hit.any() else None


def bystander_contact(plan: AdversaryPlan, scene: Scene, target: int, tolerance_s: float = 0.1
                      ) -> tuple[float, str] | None:
    """(time [s], vehicle id) of the first overlap of ``plan`` with a vehicle other than the target
    on its nominal path before t_col - tolerance, or None.

    An adversary that hits another vehicle on its way ends its run in that wreck instead of at the
    target (on a freeway: a 25 m/s car running into the queue ahead of it). The nominal paths are
    what the other vehicles would do without the adversary; in a simulated scene they may still
    brake for it, so this filter removes the plans that certainly hit someone else, not every one.
    Same window and tolerance as :func:`early_contact`.
    """
    t = scene.tracks
    others = np.flatnonzero(np.arange(t.num_agents) != target)
    times = scene.timestamps
    cols = np.flatnonzero(_checked_steps(plan, times, tolerance_s))
    if not len(cols) or not len(others):
        return None
    x, y, yaw, _ = plan.sample(times[cols])
    valid = t.valid[np.ix_(others, cols)]
    ox, oy = t.x[np.ix_(others, cols)], t.y[np.ix_(others, cols)]
    # only pairs whose centres are within reach of each other (half diagonals plus the tolerance)
    reach = 0.5 * (np.hypot(plan.length, plan.width) + np.hypot(t.length[np.ix_(others, cols)],
                                                                 t.width[np.ix_(others, cols)]))
    near = valid & (np.hypot(ox - x, oy - y) <= reach + CONTACT_TOLERANCE_M)
    if not near.any():
        return None
    a, s = np.nonzero(near)
    adv = make_boxes(x[s], y[s], yaw[s], plan.length, plan.width)
    rows, c = others[a], cols[s]
    oth = make_boxes(t.x[rows, c], t.y[rows, c], t.heading[rows, c], t.length[rows, c], t.width[rows, c])
    hit = box_signed_distance(adv, oth) <= CONTACT_TOLERANCE_M
    if not hit.any():
        return None
    first = np.flatnonzero(hit)[np.argmin(c[hit])]
    return float(times[c[first]]), str(t.ids[rows[first]])



def keep_clear_plans(plans: Sequence[AdversaryPlan], scene: Scene, target: int
                     ) -> tuple[list[AdversaryPlan], list[dict[str, Any]]]:
    """The plans that hit neither the target nor another vehicle before t_col, renamed
    ``adversary0``, ``adversary1``, ... in order, and one entry (candidate index, reason) per plan
    left out."""
    kept: list[AdversaryPlan] = []
    dropped: list[dict[str, Any]] = []
    for i, plan in enumerate(plans):
        early = early_contact(plan, scene, target)
        other = bystander_contact(plan, scene, target) if early is None else None
        if early is not None:
            dropped.append({"candidate": i, "reason": f"would hit the target at {early:.1f} s, before "
                                                      "t_col (on the target's nominal path)"})
        elif other is not None:
            dropped.append({"candidate": i, "reason": f"would hit {other[1]} at {other[0]:.1f} s, before "
                                                      "t_col (on its nominal path)"})
        else:
            kept.append(plan.replaced(vehicle_id=f"adversary{len(kept)}"))
    return kept, dropped
