"""Collision snapshot (docs/method.md step 4): placing the adversary at t_col, and the random-offset
baseline. The collision time itself comes from :mod:`coster_sumo.method.collision_time`.

Everything works on a 2 Hz scene (:func:`coster_sumo.core.scene.resample`).

**Placement** (``--init snapshot``): in the ellipse at t_col, the region with the highest presence
probability, leaving out the one the target itself fills (the most likely region of all, whose
heads describe the target's own motion); heading, speed and size sampled from its heads and made
plausible (a real vehicle class's size, no standstill in moving traffic:
:mod:`coster_sumo.method.plausible`); the candidate box translated towards the target at fixed relative
heading until the boxes touch; among the contact placements (from the expected position, and from
each of the target's four sides) the one with the highest position log-probability is kept.
Placements that overlap another agent or leave the drivable area are rejected, and so are
placements that do not close in on the target (relative velocity pointing away from it: the boxes
would have overlapped just before); the next region is tried.

**Random offset** (``--init random``, Adv-BMT-style baseline): at the fixed collision time, a random
approach direction around the target and a random relative heading, the adversary (4.5 x 1.9 m
sedan, the target's speed scaled by a random factor) translated along that direction until it
touches the target; same rejection rules, up to ``RANDOM_TRIES`` tries.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import shapely

from coster_sumo.core.scene import Scene
from coster_sumo.core.snapshot import AgentState, CollisionSnapshot
from coster_sumo.errors import NoSnapshot
from coster_sumo.geometry.boxes import (
    box_signed_distance,
    boxes_overlap,
    make_boxes,
    touch_translation,
    translate_boxes,
)
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.collision_time import (
    candidate_steps,
    choose_collision_time,
    entropy_search,
    in_ellipse,
    search_window,
    target_pose,
)
from coster_sumo.method.plausible import local_speeds, moving_speed_class, stop_plausible, vehicle_size

RANDOM_TRIES = 200
START_DISTANCE_M = 30.0  # [m] candidates start this far out and are translated towards the target
ADV_LENGTH_M, ADV_WIDTH_M = 4.5, 1.9  # [m] the baseline's adversary size (a sedan)


@dataclass(frozen=True)
class Obstacles:
    """Other agents at one step: (K, 5) boxes (cx, cy, heading, length, width)."""

    boxes: np.ndarray

    @classmethod
    def at_step(cls, scene: Scene, step: int, exclude: Sequence[int]) -> Obstacles:
        t = scene.tracks
        keep = t.valid[:, step].copy()
        keep[list(exclude)] = False
        return cls(make_boxes(t.x[keep, step], t.y[keep, step], t.heading[keep, step],
                              t.length[keep, step], t.width[keep, step]))


def contact_placements(target: AgentState, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
                       start_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translate candidate boxes from ``start_xy`` towards the target until they touch it.

    Args:
        target: the target's state.
        heading, length, width: (N,) candidate attributes (kept fixed while translating).
        start_xy: (N, 2) candidate start centres.
    Returns:
        boxes: (N, 5) placed boxes (NaN rows where the line of travel misses the target).
        signed_distance: (N,) [m] to the target after placement (>= 0, practically 0).
    """
    tbox = make_boxes(target.x, target.y, target.yaw, target.length, target.width)
    cand = make_boxes(start_xy[:, 0], start_xy[:, 1], heading, length, width)  # (N, 5)
    direction = np.array([target.x, target.y]) - start_xy  # (N, 2)
    dist = touch_translation(cand, tbox[None, :], direction)
    placed = translate_boxes(cand, direction, np.nan_to_num(dist))
    placed[np.isnan(dist)] = np.nan
    return placed, box_signed_distance(placed, tbox[None, :])


def acceptable(boxes: np.ndarray, obstacles: Obstacles, drivable: DrivableArea | None) -> np.ndarray:
    """(N,) bool: placed boxes (N, 5) that overlap no obstacle and stay on the drivable area."""
    ok = ~np.isnan(boxes).any(axis=-1)
    if len(obstacles.boxes):
        ok &= ~boxes_overlap(boxes[:, None, :], obstacles.boxes[None, :, :]).any(axis=1)
    if drivable is not None and ok.any():
        b = boxes[ok]
        ok[ok] = ~drivable.off_road(b[:, 0], b[:, 1], b[:, 2], b[:, 3], b[:, 4])
    return ok


APART_BEFORE_S = 0.5  # [s] one 2 Hz step before contact ...
APART_BEFORE_M = 0.1  # [m] ... the boxes were this far apart (they close in, not slide along each other)


def closing(boxes: np.ndarray, speed: np.ndarray, target: AgentState, strict: bool = True) -> np.ndarray:
    """(N,) bool: the placed adversaries (N, 5) at ``speed`` (N,) run into the target.

    A snapshot is a collision only if the two boxes approach each other at contact (the relative
    velocity points from the adversary towards the target); otherwise they were overlapping just
    before it. ``strict`` also asks that, moved back along their relative velocity by one 2 Hz step
    (:data:`APART_BEFORE_S`), they are at least :data:`APART_BEFORE_M` apart: boxes that slide
    along each other (a stopped vehicle touching the side of one driving past) touched before t_col
    too, and every approach to such a placement hits the target early.
    """
    v_adv = speed[:, None] * np.stack([np.cos(boxes[:, 2]), np.sin(boxes[:, 2])], axis=1)
    rel = v_adv - target.velocity[None, :]  # (N, 2)
    to_target = np.array([target.x, target.y])[None, :] - boxes[:, :2]
    ok = np.sum(rel * to_target, axis=1) > 0.0
    if strict:
        before = boxes.copy()
        before[:, :2] -= rel * APART_BEFORE_S
        tgt_box = make_boxes(target.x, target.y, target.yaw, target.length, target.width)
        ok &= box_signed_distance(np.broadcast_to(tgt_box, before.shape), before) >= APART_BEFORE_M
    return ok


def random_snapshot(scene: Scene, target: int, rng: np.random.Generator, drivable: DrivableArea | None,
                    collision_time: str = "last", seed: int = 0, exclude: Collection[int] = (),
                    strict: bool = True) -> CollisionSnapshot:
    """The Adv-BMT-style baseline: a random pose offset from the target, in contact at t_col.

    ``exclude``: 2 Hz steps not to choose as t_col (those of snapshots already taken).
    """
    window = search_window(scene, target, exclude)
    t_col = choose_collision_time(window, "last" if collision_time == "entropy" else collision_time, rng)
    tgt = AgentState.from_tracks(scene.tracks, target, t_col)
    obstacles = Obstacles.at_step(scene, t_col, [target])
    approach = rng.uniform(-np.pi, np.pi, RANDOM_TRIES)
    rel_heading = rng.uniform(-np.pi, np.pi, RANDOM_TRIES)
    speed = max(tgt.speed, 2.0) * rng.uniform(0.5, 1.5, RANDOM_TRIES)
    start = np.array([tgt.x, tgt.y]) + START_DISTANCE_M * np.stack([np.cos(approach), np.sin(approach)], 1)
    boxes, sd = contact_placements(tgt, tgt.yaw + rel_heading, np.full(RANDOM_TRIES, ADV_LENGTH_M),
                                   np.full(RANDOM_TRIES, ADV_WIDTH_M), start)
    ok = acceptable(boxes, obstacles, drivable)
    ok &= closing(np.nan_to_num(boxes), speed, tgt, strict)
    if not ok.any():
        if drivable is not None:
            gap = float(drivable.geometry.distance(shapely.Point(tgt.x, tgt.y)))
            if not np.isfinite(gap) or gap > START_DISTANCE_M:
                raise NoSnapshot("no lanes near the target: the drivable area is "
                                 + ("empty" if not np.isfinite(gap) else f"{gap:.0f} m away at t_col"))
        raise NoSnapshot(f"no random placement of {RANDOM_TRIES} tries is on the road and free of other agents",
                         t_index=t_col)
    k = int(np.flatnonzero(ok)[0])
    b = boxes[k]
    adv = AgentState(x=float(b[0]), y=float(b[1]), yaw=float(np.angle(np.exp(1j * b[2]))),
                     speed=float(speed[k]), length=float(b[3]), width=float(b[4]))
    return CollisionSnapshot(scenario_id=scene.scenario_id, target_id=str(scene.tracks.ids[target]),
                             t_index=t_col, time=float(scene.timestamps[t_col]), target=tgt, adversary=adv,
                             signed_distance=float(sd[k]),
                             collision_time_method="last" if collision_time == "entropy" else collision_time,
                             init_method="random", seed=seed)


# ----------------------------------------------------------------------------- prior-based snapshot

SIDE_START_M = 12.0  # [m] the four-side candidates start this far from the target's centre
MAX_REGIONS_TRIED = 24


def scene_adaptation(model: Any, data: Any, scene: Scene, target: int, steps: np.ndarray | None = None) -> Any:
    """What the traffic around the target says (the prior adapted to the scene's visible traffic,
    docs/method.md step 2), fitted over the whole search window (one step sees little), or over
    ``steps`` of it: those around the candidate collision times (every step of a window up to
    :data:`~coster_sumo.method.collision_time.LONG_WINDOW_STEPS`, the neighbourhoods of the
    candidate times of a longer one: :func:`~coster_sumo.method.collision_time.candidate_steps`)."""
    from coster_sumo.prior.data import scene_tokens
    from coster_sumo.prior.infer import fit_scene_adaptation

    full = search_window(scene, target) if steps is None else steps
    full_pose = target_pose(scene, target, full)
    cfg = model.config
    context = scene_tokens(data, full, full_pose, cfg, visible="context", hide_radius=cfg.hide_radius)
    return fit_scene_adaptation(model, data, full, full_pose, context)


@dataclass
class PriorMemo:
    """What the prior computes once for one scene and target and keeps across draws (it depends on
    nothing a draw changes; None until computed).

    Attributes:
        data: the prior's regions near the target's whole path, the agents in them at the steps
            read so far (:func:`~coster_sumo.prior.data.prepare_around`).
        entropy: (num_steps,) the velocity entropy over the search window (:func:`entropy_curve`).
        adaptation: the prior adapted to the traffic around the target (:func:`scene_adaptation`,
            fitted around the candidate collision times).
    """

    data: Any = None
    entropy: np.ndarray | None = None
    adaptation: Any = None


def _scene_prior(model: Any, scene: Scene, target: int, memo: PriorMemo) -> tuple[Any, np.ndarray]:
    """The prior's regions and agents near the target's whole path and the entropy curve, from
    ``memo`` or computed into it (with the adaptation)."""
    from coster_sumo.prior.data import at_prior_rate, prepare_around

    if memo.data is None:
        # regions near the target's whole path, the agents in them at the steps the prior reads
        # only (a long life's search reads a few of them); the velocity heads at every candidate
        # step first, then every head at t_col only (the 1,600-class position head is costly)
        memo.data = prepare_around(at_prior_rate(scene), target, radius=model.config.radius,
                                   spacing=model.config.region_spacing, width=model.config.region_width)
    data = memo.data
    if len(data.regions.centre) == 0:
        raise NoSnapshot("no lanes near the target: the prior has no region to place an adversary in")
    if memo.entropy is None:
        memo.entropy, _ = entropy_search(model, data, scene, target)
        memo.adaptation = scene_adaptation(model, data, scene, target, candidate_steps(scene, target, memo.entropy))
    return data, memo.entropy


def _plausible_sample(pred: Any, k: int, scene: Scene, t_col: int, target: int, rng: np.random.Generator
                      ) -> tuple[np.ndarray, float, float, float, float]:
    """A vehicle drawn from region ``k``'s heads at t_col, made plausible (:mod:`coster_sumo.method.plausible`):
    expected position (2,) [m], heading [rad], length [m], width [m], speed [m/s]."""
    s = pred.sample(rng, np.array([0]), np.array([k]))
    heading = float(s["world_heading"][0])
    length, width, _ = vehicle_size(float(s["length"][0]), float(s["width"][0]))  # a real vehicle's size
    speed = float(s["speed"][0])
    lane = int(pred.regions.lane_index[pred.region_index[0, k]])
    if speed < pred.bins.stopped_speed and not stop_plausible(scene, t_col, target, lane, s["world_xy"][0]):
        cls = moving_speed_class(pred.probs["speed"][0, k], pred.bins.centres("speed"), 0, rng,
                                 fastest=float(np.max(local_speeds(scene, t_col, target))))
        speed = float(pred.bins.speed_in_bin(np.array([cls]), rng)[0])
    return s["world_xy"][0], heading, length, width, speed


def prior_snapshot(request: PlacementRequest, *, model: Any = None,
                   regions_out: dict[str, np.ndarray] | None = None) -> CollisionSnapshot:
    """COSTER's snapshot: t_col from the velocity entropy, placement from the prior (module docstring).

    The request's ``scene`` is at 2 Hz. ``model`` defaults to ``prior.pt`` in its ``models_dir``
    (default: the shipped models folder). ``regions_out``, when given, receives the region centres
    ``xy`` (K, 2) [m] and presence probabilities ``presence`` (K,) around the target at t_col, for
    pictures. Its ``memo``: kept by the caller across draws for the same scene, target and model: the
    regions, the entropy curve and the prior's adaptation to the traffic around (fitted over the
    whole search window) are computed once in it (:class:`PriorMemo`; they depend on nothing else).
    """
    from coster_sumo.infra import weights
    from coster_sumo.prior.infer import load_prior, predict_scene

    scene, target, rng, drivable, seed = request.scene, request.target, request.rng, request.drivable, request.seed
    collision_time, models_dir, exclude, strict = (request.collision_time, request.models_dir, request.exclude,
                                                   request.strict)
    memo = request.memo

    if model is None:
        model = weights.load_cached(weights.weights_path(weights.PRIOR, models_dir), load_prior)
    window = search_window(scene, target, exclude)
    if len(window) == 0:
        raise NoSnapshot("the target is not valid inside the collision-time search window")
    tr = scene.tracks
    memo = PriorMemo() if memo is None else memo
    data, entropy = _scene_prior(model, scene, target, memo)
    t_col = choose_collision_time(window, collision_time, rng, entropy)
    at_col = np.array([t_col])
    pred = predict_scene(model, data, target, steps=at_col, pose=target_pose(scene, target, at_col),
                         calibrate=memo.adaptation or True)
    tgt = AgentState.from_tracks(tr, target, t_col)
    obstacles = Obstacles.at_step(scene, t_col, [target])
    centres_col = pred.regions.centre[np.maximum(pred.region_index[0], 0)]  # (K, 2)
    if regions_out is not None:
        real = pred.mask[0]
        regions_out["xy"] = centres_col[real]
        regions_out["presence"] = pred.presence[0][real]
    # the region the target itself occupies is not a place for another vehicle: it is always the most
    # likely one (a vehicle stands there), and an adversary drawn from it copies the target's own motion
    cands = np.flatnonzero(pred.mask[0] & in_ellipse(centres_col, tgt) & (pred.observed_agent[0] != target))
    if len(cands) == 0:
        raise NoSnapshot(f"no map region inside the target's ellipse at {scene.timestamps[t_col]:.1f} s", t_index=t_col)
    order = cands[np.argsort(-pred.presence[0, cands], kind="stable")][:MAX_REGIONS_TRIED]
    reasons = []
    fwd = np.array([np.cos(tgt.yaw), np.sin(tgt.yaw)])
    left = np.array([-fwd[1], fwd[0]])
    centre = np.array([tgt.x, tgt.y])
    for k in order:
        expected_xy, heading, length, width, speed = _plausible_sample(pred, k, scene, t_col, target, rng)
        starts = np.stack([expected_xy, centre + SIDE_START_M * fwd, centre - SIDE_START_M * fwd,
                           centre + SIDE_START_M * left, centre - SIDE_START_M * left])  # (5, 2)
        boxes, sd = contact_placements(tgt, np.full(5, heading), np.full(5, max(length, 1.0)),
                                       np.full(5, max(width, 0.5)), starts)
        logp = pred.position_log_prob(boxes[:, :2], np.zeros(5, np.int64), np.full(5, k))
        logp = np.where(np.isnan(boxes).any(axis=1), np.nan, logp)
        ok = acceptable(boxes, obstacles, drivable)
        ok &= closing(np.nan_to_num(boxes), np.full(5, speed), tgt, strict)
        if not ok.any():
            reasons.append(f"region {int(pred.region_index[0, k])}: no contact placement is on the road, "
                           "free of other agents and closing in on the target")
            continue
        score = np.where(ok, np.nan_to_num(logp, nan=-np.inf, neginf=-1e9), -np.inf)
        score[0] = score[0] + 1e-9 if ok[0] else score[0]  # ties: prefer the expected position's approach
        best = int(np.argmax(score))
        b = boxes[best]
        adv = AgentState(x=float(b[0]), y=float(b[1]), yaw=float(np.angle(np.exp(1j * b[2]))),
                         speed=speed, length=float(b[3]), width=float(b[4]))
        return CollisionSnapshot(
            scenario_id=scene.scenario_id, target_id=str(tr.ids[target]), t_index=t_col,
            time=float(scene.timestamps[t_col]), target=tgt, adversary=adv,
            region_id=int(pred.region_index[0, k]), presence_prob=float(pred.presence[0, k]),
            position_logprob=float(logp[best]), signed_distance=float(sd[best]),
            entropy=tuple(float(v) for v in entropy), collision_time_method=collision_time,
            init_method="snapshot", seed=seed)
    raise NoSnapshot("; ".join(reasons[:3]) or "no acceptable placement", t_index=t_col)


@dataclass(frozen=True)
class PlacementRequest:
    """What a snapshot init is asked for: a collision snapshot of ``target`` in ``scene``.

    Attributes:
        scene: the nominal scene at 2 Hz.
        target: the target's agent index.
        rng: the generation's seeded generator (the collision time and the placement draw from it).
        drivable: the drivable area placements must stay on (None: no check).
        collision_time: a rule of :data:`~coster_sumo.method.collision_time.COLLISION_TIME_RULES`.
        seed: recorded in the snapshot.
        models_dir: the models folder (None: the shipped one).
        exclude: 2 Hz steps not to take as t_col.
        strict: only placements that close in on the target (:func:`closing`).
        memo: kept by the caller across draws for one scene and target (what they compute once).
    """

    scene: Scene
    target: int
    rng: np.random.Generator
    drivable: DrivableArea | None
    collision_time: str
    seed: int = 0
    models_dir: Path | None = None
    exclude: Collection[int] = ()
    strict: bool = True
    memo: PriorMemo | None = None


class SnapshotPlacer(Protocol):
    """A way to place the adversary at t_col: the snapshot, or :class:`NoSnapshot` when the scene
    has none (with ``t_index`` when only the chosen collision time has none)."""

    def __call__(self, request: PlacementRequest) -> CollisionSnapshot: ...


@dataclass(frozen=True)
class SnapshotInit:
    """A snapshot init of ``--init``: how it places, and the files it needs from the models folder
    (checked before any work)."""

    place: SnapshotPlacer
    weights: tuple[str, ...] = ()


def _prior_init(request: PlacementRequest) -> CollisionSnapshot:
    return prior_snapshot(request)


def _random_init(request: PlacementRequest) -> CollisionSnapshot:
    r = request
    return random_snapshot(r.scene, r.target, r.rng, r.drivable, collision_time=r.collision_time, seed=r.seed,
                           exclude=r.exclude, strict=r.strict)


# Snapshot inits (``--init``): a new one is one function and one line here.
SNAPSHOT_INITS: dict[str, SnapshotInit] = {
    "snapshot": SnapshotInit(_prior_init, weights=("prior.pt",)),  # COSTER: the traffic prior's placement
    "random": SnapshotInit(_random_init),  # baseline: a random pose offset in contact with the target
}


ATTEMPTS_PER_TIME = 5  # snapshot + rollout draws at one collision time before the next best is tried
STRICT_PER_TIME = 3  # of those, the first take only placements that close in on the target


def place_closing_first(init: SnapshotInit, request: PlacementRequest) -> tuple[CollisionSnapshot, bool]:
    """A snapshot of ``init`` and whether it closes in on the target (:func:`closing`,
    ``request.strict``); a grazing one when strict and nothing closes in at the collision time drawn.

    The generation asks for closing-in placements in the first :data:`STRICT_PER_TIME` of its
    :data:`ATTEMPTS_PER_TIME` draws at one collision time, then for grazing ones too
    (:func:`coster_sumo.method.generation.plan_scenario`).
    """
    try:
        return init.place(request), request.strict
    except NoSnapshot as exc:
        if not request.strict or exc.t_index is None:
            raise
    return init.place(dataclasses.replace(request, strict=False)), False
