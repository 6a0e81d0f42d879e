"""The time-reversed rollout of a pedestrian or cyclist adversary (docs/method.md, "Pedestrian and
cyclist adversaries", rollout).

Where the class's learned rollout is in the models folder (``rollout_pedestrian.pt``,
``rollout_cyclist.pt``: the CVAE trained on that class's tracks, :mod:`coster_sumo.method.vru.learned`)
its samples are drawn backwards from the snapshot, those outside the class's limits rejected. Else
(or when none of them is kept) the approach is sampled backwards from the snapshot under the class's
kinematics. Either way the samples are then selected as COSTER selects (K-means on lateral
displacement and arc length, the member nearest each centroid). The kinematic samples:

- speed, backwards in :data:`SUBSTEP_S` steps: a forward acceleration held for each 0.5 s, drawn
  uniformly inside the class's limits, the speed kept in [0, the class's fastest]; a pedestrian may
  have stood still before stepping out (the speed reaches 0 and stays there), and turns on the spot;
- heading: a pedestrian's turn rate is drawn per 0.5 s up to its limit; a cyclist's path curvature is
  drawn and bounded by its tightest turn and its lateral-acceleration limit at that speed;
- kept: samples whose every knot lies in the class's area, whose box overlaps neither the target
  before the last 2 Hz step nor another agent at its step, and whose densified plan stays inside the
  class's area and within its speed and acceleration limits (:func:`~coster_sumo.method.vru.classes.within_limits`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.geometry.boxes import box_signed_distance, boxes_overlap, make_boxes
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import Kinematics, VruClass, within_limits
from coster_sumo.method.vru.learned import learned_knots, within_class
from coster_sumo.rollout.methods import HORIZON_STEPS
from coster_sumo.rollout.request import RolloutRequest, RolloutResult
from coster_sumo.rollout.sample import cluster_trajectories

if TYPE_CHECKING:
    from coster_sumo.rollout.model import RolloutCVAE

SUBSTEP_S = 0.1  # [s] integration step
KNOT_S = 0.5  # [s] the 2 Hz knots
MAX_SAMPLES = 512  # the kinematic sampler is cheap, but K-means over more adds nothing
YAW_RATE_SD = {"pedestrian": 0.6, "cyclist": 0.0}  # [rad/s] a pedestrian's turn rate spread
CURVATURE_SD = 0.03  # [1/m] a cyclist's curvature spread
CHECK_HZ = 10.0  # [1/s] the densified plan is checked at SUMO's step


def sample_backwards(vru: VruClass, x: float, y: float, yaw: float, speed: float, steps: int, n: int,
                     rng: np.random.Generator) -> np.ndarray:
    """(n, steps + 1, 3) knots x, y [m], yaw [rad] at 2 Hz, the last one the given state."""
    sub = int(round(KNOT_S / SUBSTEP_S))
    total = steps * sub
    accel = rng.uniform(-vru.max_decel, vru.max_accel, (n, steps)).repeat(sub, axis=1)  # forward accel
    if vru.min_turn_radius > 0.0:
        curvature = rng.normal(0.0, CURVATURE_SD, (n, steps)).repeat(sub, axis=1)
    else:
        yaw_rate = np.clip(rng.normal(0.0, YAW_RATE_SD[vru.name], (n, steps)), -vru.max_yaw_rate,
                           vru.max_yaw_rate).repeat(sub, axis=1)
    xs = np.empty((n, total + 1))
    ys = np.empty((n, total + 1))
    ths = np.empty((n, total + 1))
    v = np.full(n, float(speed))
    xs[:, -1], ys[:, -1], ths[:, -1] = x, y, yaw
    for j in range(total - 1, -1, -1):  # backwards in time: from step j + 1 to step j
        v_prev = np.clip(v - accel[:, j] * SUBSTEP_S, 0.0, vru.fast_max)
        v_mid = 0.5 * (v + v_prev)
        if vru.min_turn_radius > 0.0:
            limit = np.full(n, 1.0 / vru.min_turn_radius)  # [1/m]
            if vru.max_lateral_accel is not None:
                limit = np.minimum(limit, vru.max_lateral_accel / np.maximum(v_mid, 1e-3) ** 2)
            rate = np.clip(curvature[:, j], -limit, limit) * v_mid
        else:
            rate = yaw_rate[:, j]  # a pedestrian turns as well standing as walking
        th_prev = ths[:, j + 1] - rate * SUBSTEP_S
        th_mid = ths[:, j + 1] - 0.5 * rate * SUBSTEP_S
        xs[:, j] = xs[:, j + 1] - v_mid * np.cos(th_mid) * SUBSTEP_S
        ys[:, j] = ys[:, j + 1] - v_mid * np.sin(th_mid) * SUBSTEP_S
        ths[:, j] = th_prev
        v = v_prev
    knots = np.stack([xs[:, ::sub], ys[:, ::sub], ths[:, ::sub]], axis=-1)  # (n, steps + 1, 3)
    return knots


def _clear(request: RolloutRequest, knots: np.ndarray, vru: VruClass, steps: np.ndarray) -> np.ndarray:
    """(n,) bool: no knot's box overlaps the target (before the last) or another valid agent at its step."""
    tr = request.scene_2hz.tracks
    n, t = knots.shape[:2]
    boxes = make_boxes(knots[..., 0], knots[..., 1], knots[..., 2], np.full((n, t), vru.length),
                       np.full((n, t), vru.width))  # (n, t, 5)
    ok = np.ones(n, bool)
    for j, step in enumerate(steps):
        valid = tr.valid[:, step].copy()
        if j == t - 1:
            valid[request.target] = False  # the contact itself
        idx = np.flatnonzero(valid)
        if len(idx) == 0:
            continue
        others = make_boxes(tr.x[idx, step], tr.y[idx, step], tr.heading[idx, step], tr.length[idx, step],
                            tr.width[idx, step])  # (m, 5)
        ok &= ~boxes_overlap(boxes[:, j, None, :], others[None, :, :]).any(axis=1)
    return ok


def vru_rollout(request: RolloutRequest, vru: VruClass, area: ClassArea, model: RolloutCVAE | None = None,
                note: str | None = None) -> RolloutResult:
    """Plans of a ``vru`` adversary ending in ``request.snapshot`` (module docstring): samples of
    ``model``, the class's learned rollout (:mod:`coster_sumo.method.vru.learned`), those outside
    the class's limits rejected; without it, or when it leaves nothing, the kinematic samples.
    ``note`` goes into the info (why the kinematic rollout ran)."""
    snap = request.snapshot
    h = min(HORIZON_STEPS, snap.t_index)
    times = request.scene_2hz.timestamps[snap.t_index - h: snap.t_index + 1]
    a = snap.adversary
    if model is not None:
        knots = learned_knots(request, model, h)
        in_limits = within_class(vru, knots)
    else:
        rng = np.random.default_rng([request.seed, snap.t_index, 62])  # the draw's own stream
        n = min(request.samples, MAX_SAMPLES)
        knots = sample_backwards(vru, a.x, a.y, a.yaw, a.speed, h, n, rng)
        in_limits = np.ones(n, bool)  # by construction
    in_area = in_limits & area.contains(knots[..., :2]).all(axis=1)
    clear = in_area & _clear(request, knots, vru, np.arange(snap.t_index - h, snap.t_index + 1))
    keep = np.flatnonzero(clear)
    info: dict[str, Any] = {"rollout": f"{'cvae' if model is not None else 'kinematic'}:{vru.name}",
                            "samples": len(knots), "in_area": int(in_area.sum()), "clear": int(clear.sum())}
    if model is not None:
        info["within_limits"] = int(in_limits.sum())
    if note:
        info["rollout_note"] = note
    plans: list[AdversaryPlan] = []
    rejected: list[dict[str, Any]] = []
    if len(keep):
        for c, members in enumerate(cluster_trajectories(knots[keep], k=request.variants, seed=request.seed)):
            for m in members:  # the member nearest the centroid whose densified plan keeps the limits and area
                plan = AdversaryPlan.from_knots(times, knots[keep[m]], a, vclass=vru.vclass)
                if plan_within_limits(plan, vru) and not densified_off_area(plan, area):
                    plans.append(plan)
                    break
            else:
                rejected.append({"cluster": c, "reason": f"all {len(members)} trajectories leave the {vru.name}'s "
                                 "area or exceed its speed or acceleration limits once densified"})
    if model is not None and not plans:  # nothing learned fits here: the kinematic samples instead
        return vru_rollout(request, vru, area, note=f"none of the {len(knots)} learned samples kept "
                           f"({info['within_limits']} within the limits, {info['clear']} also in the area and clear): "
                           f"the {vru.name}'s kinematic rollout")
    info["rejected_clusters"] = rejected
    plans = [_renamed(p, i) for i, p in enumerate(plans)]
    info["kept"] = len(plans)
    return plans, knots[keep][..., :2] if len(keep) else None, info


def _renamed(plan: AdversaryPlan, i: int) -> AdversaryPlan:

    return plan.replaced(vehicle_id=f"adversary{i}")


def plan_kinematics(plan: AdversaryPlan) -> Kinematics:
    """The densified plan's speeds and accelerations at :data:`CHECK_HZ` up to t_col."""
    t = np.arange(plan.t_start, plan.t_col + 1e-9, 1.0 / CHECK_HZ)
    x, y, yaw, _ = plan.sample(t)
    return Kinematics.of(np.stack([x, y], -1)[None], yaw[None], 1.0 / CHECK_HZ)


def densified_off_area(plan: AdversaryPlan, area: ClassArea) -> bool:
    """Whether the densified plan's centre leaves the class's area before t_col (every 1 / :data:`CHECK_HZ`)."""
    t = np.arange(plan.t_start, plan.t_col + 1e-9, 1.0 / CHECK_HZ)
    x, y, _, _ = plan.sample(t)
    return bool(area.off_area(np.stack([x, y], -1)[None])[0])


def plan_within_limits(plan: AdversaryPlan, vru: VruClass) -> bool:
    """Whether the densified plan stays within the class's speed and acceleration limits."""
    return bool(within_limits(vru, plan_kinematics(plan))[0])


VRU_CLEARANCE_M = 0.3  # [m] a VRU plan passes other agents at least this far apart before t_col


def keep_vru_clear(plans: list[AdversaryPlan], scene: Scene, target: int) -> tuple[list[AdversaryPlan],
                                                                                  list[dict[str, Any]]]:
    """The plans that pass every agent but the target at least :data:`VRU_CLEARANCE_M` apart (box gap)
    from their start to 0.1 s before t_col on the nominal scene (10 Hz), and one dropped entry per other.

    A walker or rider squeezes between vehicles where a car would not: the vehicle filter's contact
    tolerance let through a pedestrian 0.06 m from a creeping car on a WOMD scene, and in SUMO the two
    touched 1.3 s before t_col (the variant was dropped as a wreck after its whole pass).
    """
    t = scene.tracks
    others = np.flatnonzero(np.arange(t.num_agents) != target)
    kept, dropped = [], []
    for plan in plans:
        cols = np.flatnonzero((scene.timestamps >= plan.t_start - 1e-9) & (scene.timestamps < plan.t_col - 0.1))
        if not len(cols) or not len(others):
            kept.append(plan)
            continue
        x, y, yaw, _ = plan.sample(scene.timestamps[cols])
        valid = t.valid[np.ix_(others, cols)]
        reach = 0.5 * (np.hypot(plan.length, plan.width) + np.hypot(t.length[np.ix_(others, cols)],
                                                                     t.width[np.ix_(others, cols)]))
        near = valid & (np.hypot(t.x[np.ix_(others, cols)] - x, t.y[np.ix_(others, cols)] - y)
                        <= reach + VRU_CLEARANCE_M)
        a, s = np.nonzero(near)
        rows, c = others[a], cols[s]
        gap = box_signed_distance(make_boxes(x[s], y[s], yaw[s], plan.length, plan.width),
                                  make_boxes(t.x[rows, c], t.y[rows, c], t.heading[rows, c], t.length[rows, c],
                                             t.width[rows, c])) if len(a) else np.zeros(0)
        if len(gap) and float(gap.min()) < VRU_CLEARANCE_M:
            k = int(np.argmin(gap))
            dropped.append({"candidate": plan.vehicle_id, "reason": f"passes {t.ids[rows[k]]} {float(gap[k]):.2f} m "
                            f"apart at {float(scene.timestamps[c[k]]):.1f} s, closer than {VRU_CLEARANCE_M} m"})
        else:
            kept.append(plan)
    return kept, dropped
