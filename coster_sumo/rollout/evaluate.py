"""Evaluation of reverse rollouts: ``coster-sumo eval rollout --data ... --json OUT``.

Every agent of the class evaluated (``--agent-class``: vehicles by default) with a full 5 s past
(``max_horizon`` valid 2 Hz steps before t_rev) at every t_rev of every scene is reconstructed by
each method; errors are on the box centre over the
reverse steps 1..H (metres):

- minADE / minFDE: over ``num_samples`` (5) samples, the smallest average / final displacement
  error, each minimised independently; avgADE / avgFDE: their means over the samples. The
  deterministic baselines have one trajectory, so their min and avg coincide.
- time per trajectory [s]: wall time of everything after loading (context encoding and the model,
  or the baseline) divided by the number of trajectories produced, on this machine's CPU.

Methods: constant velocity, constant lane, the CVAE without DSA and the CVAE with DSA (each from
its own checkpoint when given).
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING

import numpy as np

from coster_sumo.core.snapshot import AgentState
from coster_sumo.errors import InputError
from coster_sumo.metrics import ade_fde
from coster_sumo.rollout.baselines import LaneIndex, constant_lane_backward, constant_velocity_backward
from coster_sumo.rollout.data import ExampleSet, to_frame, to_tensors
from coster_sumo.rollout.records import DisplacementErrors, GroupErrors, MethodErrors, RolloutEvaluation

if TYPE_CHECKING:
    from coster_sumo.rollout.cache import CachedExamples
    from coster_sumo.rollout.model import RolloutCVAE

BASELINES = ("constant_velocity", "constant_lane")


def baselines_for(agent_class: str) -> tuple[str, ...]:
    """The baselines scored for a class: constant lane follows a lane of the road map, where vehicles
    and cyclists ride; the maps hold no sidewalks, so for a pedestrian only constant velocity."""
    return ("constant_velocity",) if agent_class == "pedestrian" else BASELINES


def _summary(ade: np.ndarray, fde: np.ndarray, elapsed_s: float) -> MethodErrors:
    """ade, fde (R, S) per context and sample (:func:`~coster_sumo.metrics.ade_fde`) -> the metrics."""
    return MethodErrors(DisplacementErrors.of(ade, fde), time_per_trajectory_s=elapsed_s / max(ade.size, 1))


# neighbour counts at t_rev (the vehicles the model sees around the one it reconstructs), for
# the breakdown by_neighbours: where dynamic surrounding attention has something to attend to
NEIGHBOUR_BUCKETS = ((0, 0), (1, 3), (4, 9), (10, 10**9))

# an agent in the vehicle's lane close ahead or behind at t_rev (within 30 m along the heading,
# under 2 m aside, heading within about 25 degrees): the car-following interaction, where attending
# to the neighbours' motion pays most (docs/method.md, "Where DSA helps")
LANE_NEIGHBOUR_ALONG_M = 30.0
LANE_NEIGHBOUR_ASIDE_M = 2.0
LANE_NEIGHBOUR_MIN_COS = 0.9


def has_lane_neighbour(nbr: np.ndarray, nbr_mask: np.ndarray, pos_scale_m: float) -> np.ndarray:
    """(R,) True where a neighbour at t_rev is in the vehicle's lane close ahead or behind;
    ``nbr`` (R, H+1, N, 12) and ``nbr_mask`` (R, H+1, N) as :mod:`coster_sumo.rollout.data` encodes them."""
    at0, valid = nbr[:, 0], nbr_mask[:, 0]
    along, aside = at0[..., 0] * pos_scale_m, at0[..., 1] * pos_scale_m
    same_lane = ((np.abs(along) <= LANE_NEIGHBOUR_ALONG_M) & (np.abs(aside) < LANE_NEIGHBOUR_ASIDE_M)
                 & (at0[..., 4] > LANE_NEIGHBOUR_MIN_COS))
    return (same_lane & valid).any(-1)


def cvae_predictions(model: RolloutCVAE, examples: ExampleSet | CachedExamples, rows: np.ndarray, num_samples: int,
                     seed: int = 0, batch_size: int = 64
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, dict[str, np.ndarray]]:
    """Samples of ``rows``: pred (R, S, H, 2), truth (R, H, 2), mask (R, H) in the t_rev frames,
    the wall time [s] spent encoding and sampling, and per context (R,) at t_rev: ``neighbours``
    (how many) and ``lane_neighbour`` (:func:`has_lane_neighbour`)."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    preds, truths, masks, nbrs, lane = [], [], [], [], []
    elapsed = 0.0
    h = model.cfg.max_horizon
    for start in range(0, len(rows), batch_size):
        t0 = time.perf_counter()
        arrays = examples.batch(rows[start:start + batch_size], model.cfg, horizon=h)
        truth, mask = arrays.pop("traj"), arrays.pop("step_mask")
        arrays.pop("origin")
        nbrs.append(arrays["nbr_mask"][:, 0].sum(-1))
        lane.append(has_lane_neighbour(arrays["nbr"], arrays["nbr_mask"], model.cfg.pos_scale_m))
        poses = model.sample(to_tensors(arrays, model.device), num_samples, generator=gen)  # (B, S, H, 3)
        elapsed += time.perf_counter() - t0
        preds.append(poses[..., :2].cpu().double().numpy())
        truths.append(truth[..., :2].astype(np.float64))
        masks.append(mask)
    if not preds:
        return (np.zeros((0, num_samples, h, 2)), np.zeros((0, h, 2)), np.zeros((0, h), bool), 0.0,
                {"neighbours": np.zeros(0, np.int64), "lane_neighbour": np.zeros(0, bool)})
    info = {"neighbours": np.concatenate(nbrs), "lane_neighbour": np.concatenate(lane)}
    return np.concatenate(preds), np.concatenate(truths), np.concatenate(masks), elapsed, info


def _groups(ade: np.ndarray, fde: np.ndarray, key: str, groups: list[tuple[str, np.ndarray]]
            ) -> tuple[GroupErrors, ...]:
    """minADE / minFDE of each (label, selection) group of contexts, empty groups left out;
    ``ade``, ``fde`` (R, S) per context and sample."""
    return tuple(GroupErrors(group=key, label=label, contexts=int(sel.sum()), min_ade=float(ade[sel].min(-1).mean()),
                             min_fde=float(fde[sel].min(-1).mean())) for label, sel in groups if sel.any())


def by_neighbours(ade: np.ndarray, fde: np.ndarray, neighbours: np.ndarray) -> tuple[GroupErrors, ...]:
    """minADE / minFDE per bucket of :data:`NEIGHBOUR_BUCKETS` (empty buckets left out); ``ade``,
    ``fde`` (R, S) per context and sample, ``neighbours`` (R,)."""
    return _groups(ade, fde, "neighbours", [
        (str(lo) if lo == hi else (f"{lo}+" if hi >= 10**9 else f"{lo}-{hi}"), (neighbours >= lo) & (neighbours <= hi))
        for lo, hi in NEIGHBOUR_BUCKETS])


def by_lane_neighbour(ade: np.ndarray, fde: np.ndarray, lane_neighbour: np.ndarray) -> tuple[GroupErrors, ...]:
    """minADE / minFDE of the contexts with and without a neighbour in their lane close ahead or
    behind (:func:`has_lane_neighbour`; empty groups left out)."""
    return _groups(ade, fde, "lane_neighbour", [("yes", lane_neighbour), ("no", ~lane_neighbour)])


def cvae_errors(model: RolloutCVAE, examples: ExampleSet | CachedExamples, rows: np.ndarray, num_samples: int = 5,
                seed: int = 0, batch_size: int = 64) -> MethodErrors:
    """minADE / minFDE / avgADE / avgFDE [m] and time per trajectory [s] of the CVAE on ``rows``,
    ``by_neighbours`` (:func:`by_neighbours`) and ``by_lane_neighbour`` (:func:`by_lane_neighbour`)."""
    pred, truth, mask, elapsed, info = cvae_predictions(model, examples, rows, num_samples, seed, batch_size)
    ade, fde = ade_fde(pred, truth, mask)
    return dataclasses.replace(_summary(ade, fde, elapsed), by_neighbours=by_neighbours(ade, fde, info["neighbours"]),
                               by_lane_neighbour=by_lane_neighbour(ade, fde, info["lane_neighbour"]))


def baseline_errors(name: str, examples: ExampleSet, rows: np.ndarray, horizon: int) -> MethodErrors:
    """The metrics of one baseline (``constant_velocity`` or ``constant_lane``) on ``rows``."""
    if name not in BASELINES:
        raise InputError(f"unknown baseline {name!r} (choose from {', '.join(BASELINES)})")
    rel = -0.5 * np.arange(1, horizon + 1)
    lane_index: dict[int, LaneIndex] = {}
    preds, truths, masks = [], [], []
    elapsed = 0.0
    from coster_sumo.rollout.data import reverse_targets

    for s, a, t, _h in examples.index[rows]:
        cache = examples.caches[int(s)]
        scene = cache.scene
        truth, mask = reverse_targets(scene, int(a), int(t), horizon)
        t0 = time.perf_counter()
        state = AgentState.from_tracks(scene.tracks, int(a), int(t))
        if name == "constant_velocity":
            poses = constant_velocity_backward(state, rel)
        else:
            if int(s) not in lane_index:
                lane_index[int(s)] = LaneIndex.build(scene.road_map)
            poses = constant_lane_backward(state, rel, scene.road_map, lane_index[int(s)])
        x, y, _ = to_frame(poses[:, 0], poses[:, 1], poses[:, 2], (state.x, state.y, state.yaw))
        elapsed += time.perf_counter() - t0
        preds.append(np.stack([x, y], -1)[None])
        truths.append(truth[:, :2].astype(np.float64))
        masks.append(mask)
    if not preds:
        return _summary(np.zeros((0, 1)), np.zeros((0, 1)), 0.0)
    return _summary(*ade_fde(np.stack(preds), np.stack(truths), np.stack(masks)), elapsed)


def evaluate_rollout(examples: ExampleSet, models: dict[str, RolloutCVAE], *, horizon: int = 10,
                     num_samples: int = 5, seed: int = 0, batch_size: int = 64,
                     max_examples: int = 0, agent_class: str = "vehicle") -> RolloutEvaluation:
    """Score the baselines of ``agent_class`` (:func:`baselines_for`), the class of the examples, and
    every model on the examples with a full ``horizon`` past (``max_examples`` > 0: a seeded subset
    of that many)."""
    rows = np.flatnonzero(examples.index[:, 3] >= horizon) if len(examples) else np.zeros(0, np.int64)
    if max_examples > 0 and len(rows) > max_examples:
        rows = np.sort(np.random.default_rng(seed).choice(rows, max_examples, replace=False))
    if len(rows) == 0:
        raise InputError(f"no {agent_class} with a full {horizon * 0.5:g} s past to evaluate on")
    methods: dict[str, MethodErrors] = {}
    for name in baselines_for(agent_class):
        methods[name] = baseline_errors(name, examples, rows, horizon)
    for name, model in models.items():
        if model.cfg.max_horizon < horizon:
            raise InputError(f"{name}: the model reconstructs at most {model.cfg.max_horizon} steps, "
                             f"the evaluation needs {horizon}")
        methods[name] = cvae_errors(model, examples, rows, num_samples, seed, batch_size)
    return RolloutEvaluation(num_examples=int(len(rows)), horizon_steps=horizon, methods=methods)
