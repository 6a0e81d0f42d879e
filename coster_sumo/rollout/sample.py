"""Oversampling, clustering and refinement of adversary trajectories (docs/method.md step 6).

The injection pipeline calls, for one collision snapshot:

1. :func:`sample_trajectories`: N (default 1000) reverse rollouts of the CVAE in one batched pass,
   as 2 Hz poses from ``t_col - H * 0.5 s`` to ``t_col`` whose last pose is the snapshot exactly;
2. :func:`select_representatives`: K-means (K = 5) on lateral-displacement and arc-length features,
   one representative per cluster (the member closest to its centroid), every transition snapped
   to the motion vocabulary (chained back from the snapshot, so contact is kept exactly), and
   rejection of representatives that leave the drivable area or overlap other agents before
   t_col, falling back to the next member of the cluster;

or both at once through :func:`plan_variants`, which loads the shipped models and returns
:class:`~coster_sumo.core.plan.AdversaryPlan` objects.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from coster_sumo.core.scene import Scene
from coster_sumo.core.snapshot import AgentState, CollisionSnapshot
from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import boxes_overlap, make_boxes
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.rollout.data import (
    SceneCache,
    build_cache,
    check_rate,
    encode_context,
    from_frame,
    stack_contexts,
    to_tensors,
)
from coster_sumo.rollout.vocab import MotionVocab, project_backward

if TYPE_CHECKING:
    from coster_sumo.core.plan import AdversaryPlan
    from coster_sumo.rollout.model import RolloutCVAE
    from coster_sumo.rollout.request import RolloutRequest

DEFAULT_SAMPLES = 1000
DEFAULT_CLUSTERS = 5
KMEANS_ITERATIONS = 50

OffRoadFn = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


# ----------------------------------------------------------------------------- sampling

def _snapshot_parts(snapshot: CollisionSnapshot | tuple[AgentState, int]) -> tuple[AgentState, int]:
    if isinstance(snapshot, CollisionSnapshot):
        return snapshot.adversary, int(snapshot.t_index)
    state, t_index = snapshot
    return state, int(t_index)


def rollout_horizon(model: RolloutCVAE, t_index: int, horizon: int | None = None) -> int:
    """Steps reconstructed before ``t_index``: ``min(max_horizon, t_index)`` (or ``horizon`` if
    smaller): shorter when the collision is early in the scene."""
    h = min(model.cfg.max_horizon, t_index)
    return h if horizon is None else max(0, min(h, horizon))


def trajectory_times(scene_2hz: Scene, t_index: int, horizon: int) -> np.ndarray:
    """(H + 1,) [s] scene times of the trajectory's poses, t_col last."""
    return np.asarray(scene_2hz.timestamps[t_index - horizon: t_index + 1], np.float64)


def sample_trajectories(model: RolloutCVAE, scene_2hz: Scene, snapshot: CollisionSnapshot | tuple[AgentState, int],
                        n: int = DEFAULT_SAMPLES, seed: int = 0, *, horizon: int | None = None,
                        exclude: Iterable[int] = (), cache: SceneCache | None = None) -> np.ndarray:
    """Oversample the adversary's approach backwards from the collision snapshot, in one batched pass.

    Args:
        model: a trained :class:`~coster_sumo.rollout.model.RolloutCVAE` (see
            :func:`coster_sumo.rollout.checkpoint.load_model`).
        scene_2hz: the nominal scene at 2 Hz (:func:`coster_sumo.core.scene.resample`); its agents over
            time are the neighbours, its map the map. The adversary is not one of its agents.
        snapshot: the :class:`~coster_sumo.core.scene.CollisionSnapshot` (its ``adversary`` state and
            ``t_index``), or ``(AgentState, t_index)``: centre x, y [m], yaw [rad], speed [m/s],
            length, width [m] at step ``t_index`` (= t_col) of ``scene_2hz``.
        n: number of trajectories N.
        seed: seeds the latent noise; the same seed gives the same trajectories.
        horizon: at most this many steps (default and upper bound ``min(max_horizon, t_index)``).
        exclude: agent indices of ``scene_2hz`` that must not be neighbours (e.g. when the
            adversary replaces a logged agent).
        cache: :func:`~coster_sumo.rollout.data.build_cache` of ``scene_2hz`` when sampling several
            snapshots of one scene.

    Returns:
        (N, H + 1, 3) float64 centre x, y [m] and yaw [rad] (CCW from +x, unwrapped) in the scene's
        coordinates, 2 Hz, in time order from ``t_col - H * 0.5 s`` to ``t_col``. ``[:, -1]`` is the
        snapshot exactly. Times: :func:`trajectory_times`.
    """
    import torch

    check_rate(scene_2hz)
    state, t_index = _snapshot_parts(snapshot)
    if not 0 <= t_index < scene_2hz.num_steps:
        raise InputError(f"snapshot step {t_index} is outside the scene's {scene_2hz.num_steps} steps")
    if n < 1:
        raise InputError(f"number of samples must be >= 1, got {n}")
    h = rollout_horizon(model, t_index, horizon)
    last = np.array([state.x, state.y, state.yaw], np.float64)
    if h == 0:
        return np.broadcast_to(last, (n, 1, 3)).copy()
    cache = cache if cache is not None else build_cache(scene_2hz, model.cfg)
    ctx = encode_context(cache, last, state.speed, (state.length, state.width), t_index, h, model.cfg,
                         exclude=exclude)
    arrays = stack_contexts([ctx])
    arrays.pop("origin")
    gen = torch.Generator().manual_seed(int(seed))
    poses = model.sample(to_tensors(arrays), n, generator=gen)[0]  # (N, H, 3)
    p = poses.double().numpy()
    x, y, yaw = from_frame(p[..., 0], p[..., 1], p[..., 2], last)
    out = np.empty((n, h + 1, 3))
    out[:, :h] = np.stack([x, y, yaw], axis=-1)[:, ::-1]  # reverse steps H..1 = oldest first
    out[:, h] = last
    return out


# ----------------------------------------------------------------------------- selection

@dataclass(frozen=True)
class Trajectory:
    """One selected adversary trajectory (2 Hz, time order, the last pose is the snapshot).

    Attributes:
        times: (T,) [s] scene times (relative ``-(T-1) * 0.5 .. 0`` when none were given).
        poses: (T, 3) centre x, y [m], yaw [rad] after refinement.
        raw: (T, 3) the CVAE sample it came from.
        cluster: rank of its cluster by size (0 = largest); cluster_size: members of that cluster.
        rank: 0 for the member closest to the centroid, i for the i-th fallback.
        sample_index: row of the sample in the input.
        refine_error_m: [m] largest box-corner error between ``poses`` and ``raw`` (0 unrefined).
        refined: whether the motion vocabulary was applied.
    """

    times: np.ndarray
    poses: np.ndarray
    raw: np.ndarray
    cluster: int
    cluster_size: int
    rank: int
    sample_index: int
    refine_error_m: float
    refined: bool

    @property
    def x(self) -> np.ndarray:
        return self.poses[:, 0]

    @property
    def y(self) -> np.ndarray:
        return self.poses[:, 1]

    @property
    def yaw(self) -> np.ndarray:
        return self.poses[:, 2]


@dataclass(frozen=True)
class OtherAgents:
    """Other agents' boxes at the trajectory's times.

    Attributes:
        boxes: (A, T, 5) float64 (cx, cy, heading, length, width), see :mod:`coster_sumo.geometry.boxes`.
        valid: (A, T) bool.
        ids: (A,) str.
    """

    boxes: np.ndarray
    valid: np.ndarray
    ids: np.ndarray


def others_from_scene(scene_2hz: Scene, t_index: int, horizon: int, exclude: Iterable[int] = ()) -> OtherAgents:
    """Boxes of every agent of ``scene_2hz`` (the target too) at steps ``t_index - horizon .. t_index``."""
    tr = scene_2hz.tracks
    steps = np.arange(t_index - horizon, t_index + 1)
    keep = np.ones(tr.num_agents, bool)
    ex = np.fromiter(exclude, dtype=np.int64)
    keep[ex[(ex >= 0) & (ex < tr.num_agents)]] = False
    a = np.flatnonzero(keep)
    sel = tr.select(agents=a, steps=steps)
    return OtherAgents(boxes=make_boxes(sel.x, sel.y, sel.heading, sel.length, sel.width), valid=sel.valid,
                       ids=sel.ids)


def cluster_features(trajs: np.ndarray) -> np.ndarray:
    """(N, T, 3) trajectories -> (N, 2 (T - 1)) standardised features.

    In the frame of the last pose (the snapshot): the lateral displacement of every earlier pose
    and the arc length travelled from it to t_col. Each feature is centred; each of the two groups
    is divided by its overall standard deviation, so that lateral and longitudinal variation weigh
    alike while the growth of the spread along the horizon is kept.
    """
    t = np.asarray(trajs, np.float64)
    last = t[:, -1]  # (N, 3)
    c, s = np.cos(last[:, 2])[:, None], np.sin(last[:, 2])[:, None]
    dx, dy = t[:, :-1, 0] - last[:, None, 0], t[:, :-1, 1] - last[:, None, 1]
    lateral = -s * dx + c * dy  # (N, T-1)
    seg = np.linalg.norm(np.diff(t[..., :2], axis=1), axis=-1)  # (N, T-1)
    arc = np.cumsum(seg[:, ::-1], axis=1)[:, ::-1]  # from each pose to t_col
    feats = []
    for block in (lateral, arc):
        centred = block - block.mean(axis=0, keepdims=True)
        sd = float(centred.std())
        feats.append(centred / (sd if sd > 1e-9 else 1.0))
    return np.concatenate(feats, axis=1)


def farthest_point_init(x: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """(k,) row indices: a seeded first row, then repeatedly the row farthest from those chosen."""
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(x)))]
    d = np.linalg.norm(x - x[chosen[0]], axis=1)
    for _ in range(1, k):
        j = int(np.argmax(d))
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(x - x[j], axis=1))
    return np.asarray(chosen, np.int64)


def cluster_trajectories(trajs: np.ndarray, k: int = DEFAULT_CLUSTERS, seed: int = 0
                         ) -> list[np.ndarray]:
    """K-means (farthest-point initialisation, :data:`KMEANS_ITERATIONS` iterations) on
    :func:`cluster_features`; deterministic per seed.

    Returns:
        one array of sample indices per cluster, largest cluster first, members ordered by distance
        to the centroid (closest first). Fewer than ``k`` clusters when there are fewer distinct
        trajectories.
    """
    from sklearn.cluster import KMeans

    x = cluster_features(trajs)
    n = len(x)
    if n == 0:
        return []
    distinct = len(np.unique(np.round(x, 9), axis=0))
    k = max(1, min(k, distinct))
    init = x[farthest_point_init(x, k, seed)]
    km = KMeans(n_clusters=k, init=init, n_init=1, max_iter=KMEANS_ITERATIONS, random_state=seed, tol=1e-6)
    labels = km.fit_predict(x)
    dist = np.linalg.norm(x - km.cluster_centers_[labels], axis=1)
    clusters = []
    for c in range(k):
        members = np.flatnonzero(labels == c)
        if len(members):
            clusters.append(members[np.lexsort((members, dist[members]))])
    clusters.sort(key=lambda m: (-len(m), int(m[0])))
    return clusters


def _off_road(drivable: DrivableArea | OffRoadFn, poses: np.ndarray, length: float, width: float) -> np.ndarray:
    """(R,) any pose of (R, T, 3) off the drivable area."""
    ln = np.full(poses.shape[:2], length)
    wd = np.full(poses.shape[:2], width)
    if isinstance(drivable, DrivableArea):  # areas only up to each path's first pose off the road
        return drivable.any_off_road(poses[..., 0], poses[..., 1], poses[..., 2], ln, wd)
    off = np.asarray(drivable(poses[..., 0], poses[..., 1], poses[..., 2], ln, wd), bool)
    return np.any(np.asarray(off, bool).reshape(poses.shape[:2]), axis=1)  # type: ignore[no-any-return]


def _with_midpoints(states: np.ndarray) -> np.ndarray:
    """(..., 2T-1, C) ``states`` (..., T, C) (x, y, heading, ...) with the halfway state between
    each two steps: positions and the rest averaged, the heading the short way round."""
    mid = 0.5 * (states[..., :-1, :] + states[..., 1:, :])
    turn = np.angle(np.exp(1j * (states[..., 1:, 2] - states[..., :-1, 2])))
    mid[..., 2] = states[..., :-1, 2] + 0.5 * turn
    out = np.empty((*states.shape[:-2], 2 * states.shape[-2] - 1, states.shape[-1]))
    out[..., 0::2, :] = states
    out[..., 1::2, :] = mid
    return out


def _hits_others(others: OtherAgents, poses: np.ndarray, length: float, width: float) -> np.ndarray:
    """(R,) any pose of (R, T, 3) overlapping a valid other agent at the same step or halfway
    between two steps (0.25 s at 2 Hz: two cars crossing at 10 m/s each miss each other at both
    2 Hz steps yet overlap in between, and the 10 Hz check of the plans drops such a variant).

    Only pairs whose centres are within reach of each other (half diagonals) are tested: the
    others are every agent of the scene, 3,600 in a city, and a few are ever near the samples.
    """
    hit = np.zeros(len(poses), bool)
    if others.boxes.shape[0] == 0 or poses.shape[1] == 0 or len(poses) == 0:
        return hit
    dense, boxes = _with_midpoints(poses), _with_midpoints(others.boxes)  # (R, T', 3), (A, T', 5)
    valid = np.repeat(others.valid, 2, axis=1)[:, :-1]  # a halfway state counts where both ends do
    valid[:, 1::2] = others.valid[:, :-1] & others.valid[:, 1:]
    mine = 0.5 * float(np.hypot(length, width))
    theirs = 0.5 * np.hypot(boxes[..., 3], boxes[..., 4])  # (A, T')
    # others that come near the samples' bounding box at all (most of a city never does)
    lo, hi = dense[..., :2].min(axis=(0, 1)), dense[..., :2].max(axis=(0, 1))
    gap = np.maximum(np.maximum(lo - boxes[..., :2], boxes[..., :2] - hi), 0.0)  # (A, T', 2)
    near = valid & (np.hypot(gap[..., 0], gap[..., 1]) <= mine + theirs)
    rows = np.flatnonzero(near.any(axis=1))
    if not len(rows):
        return hit
    boxes, valid, theirs = boxes[rows], near[rows], theirs[rows]  # (A', T', ...)
    d = np.hypot(dense[:, None, :, 0] - boxes[None, ..., 0], dense[:, None, :, 1] - boxes[None, ..., 1])
    r, a, t = np.nonzero(valid[None] & (d <= mine + theirs[None]))  # (R, A', T') pairs within reach
    if not len(r):
        return hit
    me = make_boxes(dense[r, t, 0], dense[r, t, 1], dense[r, t, 2], length, width)
    over = boxes_overlap(me, boxes[a, t])
    hit[r[over]] = True
    return hit


@dataclass(frozen=True)
class _Checks:
    """How candidate trajectories (R, T, 3) are refined and checked before t_col: the vocabulary, the
    drivable area and the other agents up to the step before t_col (None: no such check; always
    None for T < 2), the adversary's size [m] and the times stored in the results."""

    vocab: MotionVocab | None
    drivable: DrivableArea | OffRoadFn | None
    others: OtherAgents | None
    length: float
    width: float
    times: np.ndarray

    def usable_as_drawn(self, trajs: np.ndarray) -> np.ndarray:
        """(N,) bool: samples that, as drawn, stay on the road and clear of the others before t_col."""
        usable = np.ones(len(trajs), bool)
        if self.others is not None:
            usable &= ~_hits_others(self.others, trajs[:, :-1], self.length, self.width)
        if self.drivable is not None and usable.any():
            usable[usable] = ~_off_road(self.drivable, trajs[usable, :-1], self.length, self.width)
        return usable

    def representative(self, trajs: np.ndarray, members: np.ndarray, tries: np.ndarray, ci: int
                       ) -> tuple[Trajectory | None, int, int]:
        """The first of ``tries`` (members in order of distance to the centroid) that is acceptable once
        refined, and how many of those tried hit another agent and how many left the road."""
        hit_count = off_count = 0
        t = trajs.shape[1]
        for start in range(0, len(tries), 32):  # refine and check a few members at a time
            chunk = tries[start:start + 32]
            raw = trajs[chunk]
            if self.vocab is not None and t >= 2:
                poses, err = project_backward(raw, self.vocab, self.length, self.width)
            else:
                poses, err = raw.copy(), np.zeros(len(chunk))
            bad = np.zeros(len(chunk), bool)
            before = poses[:, :-1]  # contact at t_col is the point; only earlier poses are checked
            if self.others is not None:
                bad |= _hits_others(self.others, before, self.length, self.width)
                hit_count += int(bad.sum())
            if self.drivable is not None:
                todo = ~bad
                if todo.any():
                    off = np.zeros(len(chunk), bool)
                    off[todo] = _off_road(self.drivable, before[todo], self.length, self.width)
                    off_count += int(off.sum())
                    bad |= off
            ok = np.flatnonzero(~bad)
            if len(ok):
                j = int(ok[0])
                return (Trajectory(times=self.times.copy(), poses=poses[j], raw=raw[j].copy(), cluster=ci,
                                   cluster_size=len(members), rank=start + j, sample_index=int(chunk[j]),
                                   refine_error_m=float(err[j]), refined=self.vocab is not None),
                        hit_count, off_count)
        return None, hit_count, off_count


def select_representatives(trajs: np.ndarray, k: int = DEFAULT_CLUSTERS, seed: int = 0,
                           vocab: MotionVocab | None = None, drivable: DrivableArea | OffRoadFn | None = None,
                           others: OtherAgents | None = None, *, size: tuple[float, float],
                           times: np.ndarray | None = None, max_tries: int | None = None,
                           rejected: list[dict[str, Any]] | None = None) -> list[Trajectory]:
    """Cluster oversampled trajectories and keep one feasible, refined representative per cluster.

    Args:
        trajs: (N, T, 3) from :func:`sample_trajectories` (time order; the last pose is the snapshot).
        k: number of K-means clusters.
        seed: seeds the farthest-point initialisation (deterministic per seed).
        vocab: motion vocabulary; every transition is snapped to it (:func:`project_backward`),
            keeping the last pose exactly. None: no refinement.
        drivable: :class:`~coster_sumo.geometry.drivable.DrivableArea` or a function
            ``(x, y, yaw, length, width) -> bool off-road`` on arrays; None: no off-road check.
        others: other agents' boxes at the same T times (:func:`others_from_scene`); None: none.
        size: (length, width) [m] of the adversary.
        times: (T,) [s] stored in the results (default relative times, 0 at t_col).
        max_tries: at most this many members of a cluster are tried (default all).
        rejected: where given, one entry per cluster that yields nothing is appended to it
            (``cluster``, ``members``, ``reason``: one line, how many members hit another agent and
            how many left the road before t_col).

    Returns:
        Up to ``k`` :class:`Trajectory`, largest cluster first. A pose **before** t_col that is
        off-road (:meth:`DrivableArea.off_road`) or overlaps a valid other agent makes a sample
        unusable. When at least ``k`` samples are usable as drawn, only those are clustered;
        otherwise all are. Each cluster's members are refined and checked again in order of
        distance to the centroid; the first acceptable one represents it, and a cluster with no
        acceptable member yields nothing.
    """
    trajs = np.asarray(trajs, np.float64)
    if trajs.ndim != 3 or trajs.shape[2] != 3:
        raise InputError(f"trajectories must be (N, T, 3), got {trajs.shape}")
    n, t, _ = trajs.shape
    length, width = (float(v) for v in size)
    if times is None:
        times = (np.arange(t) - (t - 1)) * 0.5
    if others is not None and others.boxes.shape[1] != t:
        raise InputError(f"others have {others.boxes.shape[1]} steps but trajectories have {t}")
    checks = _Checks(vocab, drivable if t >= 2 else None,
                     OtherAgents(others.boxes[:, :-1], others.valid[:, :-1], others.ids)
                     if others is not None and t >= 2 else None,
                     length, width, np.asarray(times, np.float64))
    usable = checks.usable_as_drawn(trajs)
    # the clusters are made of usable samples (a cluster of samples that all leave the road gives
    # no variant: the demo got 3 of 5); with fewer usable samples than clusters, of all of them, as
    # the vocabulary's refinement moves poses by decimetres and can make a sample usable
    pool = np.flatnonzero(usable) if usable.sum() >= k else np.arange(n)
    out: list[Trajectory] = []
    for ci, in_pool in enumerate(cluster_trajectories(trajs[pool], k, seed)):
        members = pool[in_pool]
        tries = members if max_tries is None else members[:max_tries]
        rep, hit_count, off_count = checks.representative(trajs, members, tries, ci)
        if rep is not None:
            out.append(rep)
        elif rejected is not None:
            rejected.append({"cluster": ci, "members": len(members),
                             "reason": _cluster_reason(len(tries), hit_count, off_count)})
    return out


def _cluster_reason(tried: int, hit: int, off: int) -> str:
    """One line: why no member of a cluster of candidate trajectories was kept."""
    parts = (([f"{hit} overlap{'s' if hit == 1 else ''} another vehicle"] if hit else [])
             + ([f"{off} leave{'s' if off == 1 else ''} the road"] if off else []))
    what = "its one trajectory is" if tried == 1 else f"all {tried} trajectories of its cluster are"
    return f"{what} unusable before t_col (" + (", ".join(parts) or "none checked") + ")"


# ----------------------------------------------------------------------------- pipeline entry

def plan_variants(request: RolloutRequest,
                  exclude: Sequence[int] = ()) -> tuple[list[AdversaryPlan], np.ndarray, dict[str, Any]]:
    """Oversample, cluster, refine and check: the adversary plans of one snapshot.

    Args:
        request: the scene at 2 Hz, the target (it stays a neighbour and an obstacle before t_col),
            the snapshot, the drivable area (None: no check), ``samples`` N, ``variants`` K, the
            seed and the folder with ``rollout.pt`` and optionally ``vocab.npz`` (None: ``models/``).
        exclude: agents that are neither neighbours nor obstacles.

    Returns:
        (plans, samples_xy (N, T, 2) of all samples, info) with one
        :class:`~coster_sumo.core.plan.AdversaryPlan` per accepted representative (possibly none).
    """
    from coster_sumo.core.plan import AdversaryPlan

    scene_2hz, snapshot, models_dir = request.scene_2hz, request.snapshot, request.models_dir
    n, k, seed = request.samples, request.variants, request.seed
    t0 = time.perf_counter()
    from coster_sumo.infra import weights
    from coster_sumo.rollout.checkpoint import load_model
    from coster_sumo.rollout.vocab import MotionVocab

    model = weights.load_cached(weights.weights_path(weights.ROLLOUT, models_dir), load_model)
    vocab_file = weights.weights_path(weights.VOCAB, models_dir, required=False)
    vocab = weights.load_cached(vocab_file, MotionVocab.load) if vocab_file.is_file() else None
    t1 = time.perf_counter()
    trajs = sample_trajectories(model, scene_2hz, snapshot, n=n, seed=seed, exclude=exclude)
    t2 = time.perf_counter()
    h = trajs.shape[1] - 1
    times = trajectory_times(scene_2hz, snapshot.t_index, h)
    others = others_from_scene(scene_2hz, snapshot.t_index, h, exclude=exclude)
    adv = snapshot.adversary
    rejected: list[dict[str, Any]] = []
    reps = select_representatives(trajs, k=k, seed=seed, vocab=vocab, drivable=request.drivable, others=others,
                                  size=(adv.length, adv.width), times=times, rejected=rejected)
    t3 = time.perf_counter()
    plans = [AdversaryPlan.from_knots(r.times, r.poses, adv) for r in reps]
    info: dict[str, Any] = {
        "rollout": "cvae", "samples": n, "clusters": k, "horizon_steps": h, "target": int(request.target),
        "use_dsa": bool(model.cfg.use_dsa), "vocab_tokens": len(vocab) if vocab is not None else None,
        "representatives": [{"cluster": r.cluster, "cluster_size": r.cluster_size, "rank": r.rank,
                             "sample_index": r.sample_index, "refine_error_m": r.refine_error_m} for r in reps],
        "rejected_clusters": rejected,
        "time_load_s": t1 - t0, "time_sample_s": t2 - t1, "time_select_s": t3 - t2,
    }
    return plans, trajs[..., :2].copy(), info

