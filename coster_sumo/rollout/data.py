"""Inputs and targets of the rollout CVAE, in the reconstructed vehicle's frame at t_rev.

Frame: origin at the vehicle's box centre at t_rev, +x along its heading (``yaw = 0``), metres and
radians. Time runs backwards: reverse step ``k = 1..H`` is the scene step ``t_rev - k`` (2 Hz, so
``k * 0.5`` s before t_rev).

One **context** (one vehicle at one t_rev) holds:

- ``state`` (4,): speed / vel_scale, length / 5 m, width / 2 m, stopped flag (speed < 0.5 m/s).
  Only what a collision snapshot knows (speed along the heading, size): the same encoding serves
  training (from the log) and sampling (from a snapshot).
- the map: lane centrelines resampled every ``lane_spacing_m`` and cut into chunks of
  ``chunk_vectors`` vectors; the ``max_map_chunks`` chunks nearest to the vehicle within
  ``map_radius_m``. ``map_vec`` (M, P, 6): per vector start x, y, end x, y (/ pos_scale) and unit
  direction; ``map_attr`` (M, 9): lane type one-hot (4), junction flag, signal class at t_rev
  one-hot (unknown/uncontrolled, stop, caution, go); ``map_pos`` (M, 4): the chunk's first and last
  point (/ pos_scale), the part of the map key that is relative to the sample's position.
- neighbours at every step ``k = 0..H`` (k = 0 is t_rev): the agents of the scene at that step
  (never the vehicle itself), up to ``max_neighbors`` nearest to the vehicle's t_rev position
  within ``neighbor_select_radius_m``. ``nbr`` (H+1, N, 12): x, y (/ pos_scale), vx, vy
  (/ vel_scale), cos and sin of the heading, length / 5, width / 2, object type one-hot (vehicle,
  pedestrian, cyclist, other). The model masks, per sample and step, those farther than
  ``neighbor_radius_m`` from the sample.

Targets (training, evaluation): ``traj`` (H, 3) the true poses x, y, yaw at reverse steps 1..H and
``step_mask`` (H,) True while the vehicle is valid without a gap going back from t_rev.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from coster_sumo.core.scene import Scene, SignalState
from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import resample_polylines
from coster_sumo.rollout.config import AGENT_CLASSES, RolloutConfig

if TYPE_CHECKING:
    import torch

ROLLOUT_HZ = 2.0  # [1/s]
STATE_FEATURES = 4
MAP_VEC_FEATURES = 6
MAP_ATTR_FEATURES = 9
MAP_POS_FEATURES = 4
NBR_FEATURES = 12
REL_FEATURES = 4  # x, y, vx, vy: the part of a neighbour's (and a map chunk's) key relative to the sample
LENGTH_SCALE_M = 5.0  # [m]
WIDTH_SCALE_M = 2.0  # [m]
STOPPED_MPS = 0.5  # [m/s]

_STOP = (SignalState.ARROW_STOP, SignalState.STOP, SignalState.FLASHING_STOP)
_CAUTION = (SignalState.ARROW_CAUTION, SignalState.CAUTION, SignalState.FLASHING_CAUTION)
_GO = (SignalState.ARROW_GO, SignalState.GO)


Pose = Sequence[float] | np.ndarray  # (x [m], y [m], yaw [rad])


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


def to_frame(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, origin: Pose
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World poses (...) into the frame of ``origin`` = (x, y, yaw)."""
    ox, oy, oh = (float(v) for v in origin)
    c, s = np.cos(oh), np.sin(oh)
    dx, dy = np.asarray(x) - ox, np.asarray(y) - oy
    return c * dx + s * dy, -s * dx + c * dy, wrap_angle(np.asarray(yaw) - oh)


def from_frame(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, origin: Pose
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`to_frame` (headings are not wrapped)."""
    ox, oy, oh = (float(v) for v in origin)
    c, s = np.cos(oh), np.sin(oh)
    x, y = np.asarray(x), np.asarray(y)
    return ox + c * x - s * y, oy + s * x + c * y, np.asarray(yaw) + oh


def check_rate(scene: Scene) -> None:
    """Raise InputError unless ``scene`` is at the rollout's 2 Hz."""
    if scene.num_steps >= 2 and abs(scene.dt - 1.0 / ROLLOUT_HZ) > 0.05:  # WOMD timestamps jitter
        raise InputError(f"scene {scene.scenario_id}: the rollout needs a 2 Hz scene (dt 0.5 s), "
                         f"got dt {scene.dt:.3f} s; use coster_sumo.core.scene.resample(scene, 2.0)")


@dataclass(frozen=True)
class SceneCache:
    """Per-scene preprocessing shared by every context of one 2 Hz scene (world frame).

    Attributes:
        scene: the 2 Hz scene.
        chunk_pts: (num_chunks, P + 1, 2) float64 [m] chunk points (padded by repeating the last).
        chunk_vec_mask: (num_chunks, P) bool, real vectors.
        chunk_lane: (num_chunks,) int64 lane of each chunk.
        lane_attr: (num_lanes, 5) float32 lane type one-hot and junction flag.
        signal_class: (num_steps, num_lanes) int8: 0 unknown/uncontrolled, 1 stop, 2 caution, 3 go.
    """

    scene: Scene
    chunk_pts: np.ndarray
    chunk_vec_mask: np.ndarray
    chunk_lane: np.ndarray
    lane_attr: np.ndarray
    signal_class: np.ndarray


def build_cache(scene: Scene, cfg: RolloutConfig) -> SceneCache:
    """Cut the lanes of a 2 Hz scene into chunks and tabulate lane attributes (vectorised)."""
    check_rate(scene)
    lanes = scene.road_map.lanes
    p = cfg.chunk_vectors
    pts_r = resample_polylines(lanes.centerline, cfg.lane_spacing_m, even=True)
    pts = pts_r.values.reshape(-1, 2)
    item = pts_r.item_index()
    same = item[1:] == item[:-1] if len(pts) else np.zeros(0, bool)
    vec_start = np.flatnonzero(same)  # index of each vector's first point
    vec_lane = item[vec_start]
    # index of each vector within its lane, then its chunk
    vec_in_lane = vec_start - pts_r.offsets[vec_lane] if len(vec_start) else np.zeros(0, np.int64)
    n_vec_lane = np.bincount(vec_lane, minlength=len(lanes)) if len(vec_lane) else np.zeros(len(lanes), np.int64)
    n_chunk_lane = (n_vec_lane + p - 1) // p
    chunk_offset = np.concatenate([[0], np.cumsum(n_chunk_lane)]).astype(np.int64)
    num_chunks = int(chunk_offset[-1])
    chunk_of_vec = chunk_offset[vec_lane] + vec_in_lane // p
    slot = vec_in_lane % p
    chunk_pts = np.zeros((num_chunks, p + 1, 2))
    mask = np.zeros((num_chunks, p), bool)
    chunk_pts[chunk_of_vec, slot] = pts[vec_start]
    chunk_pts[chunk_of_vec, slot + 1] = pts[vec_start + 1]
    mask[chunk_of_vec, slot] = True
    # pad: repeat each chunk's last real point
    n_real = mask.sum(axis=1)
    if num_chunks:
        last = chunk_pts[np.arange(num_chunks), n_real]  # (num_chunks, 2)
        pad = np.arange(p + 1)[None, :] > n_real[:, None]
        chunk_pts = np.where(pad[..., None], last[:, None, :], chunk_pts)
    chunk_lane = np.repeat(np.arange(len(lanes)), n_chunk_lane).astype(np.int64)
    lane_attr = np.zeros((len(lanes), 5), np.float32)
    lt = np.clip(lanes.lane_type.astype(np.int64), 0, 3)
    lane_attr[np.arange(len(lanes)), lt] = 1.0
    lane_attr[:, 4] = lanes.is_junction.astype(np.float32)
    per_lane = scene.signals.per_lane(len(lanes))  # (T, L)
    cls = np.zeros(per_lane.shape, np.int8)
    cls[np.isin(per_lane, _STOP)] = 1
    cls[np.isin(per_lane, _CAUTION)] = 2
    cls[np.isin(per_lane, _GO)] = 3
    return SceneCache(scene=scene, chunk_pts=chunk_pts, chunk_vec_mask=mask, chunk_lane=chunk_lane,
                      lane_attr=lane_attr, signal_class=cls)


@dataclass(frozen=True)
class Context:
    """Model inputs of one vehicle at one t_rev (see the module docstring for the layout).

    Attributes:
        origin: (3,) float64 world pose (x [m], y [m], yaw [rad]) of the frame.
        state: (4,) float32.
        map_vec: (M, P, 6) float32; map_vec_mask: (M, P) bool.
        map_attr: (M, 9) float32; map_pos: (M, 4) float32; map_mask: (M,) bool.
        nbr: (H + 1, N, 12) float32; nbr_mask: (H + 1, N) bool.
    """

    origin: np.ndarray
    state: np.ndarray
    map_vec: np.ndarray
    map_vec_mask: np.ndarray
    map_attr: np.ndarray
    map_pos: np.ndarray
    map_mask: np.ndarray
    nbr: np.ndarray
    nbr_mask: np.ndarray

    @property
    def horizon(self) -> int:
        return int(self.nbr.shape[0]) - 1


def encode_state(speed: float, length: float, width: float, cfg: RolloutConfig) -> np.ndarray:
    """(4,) float32 state features (see the module docstring)."""
    return np.array([speed / cfg.vel_scale_mps, length / LENGTH_SCALE_M, width / WIDTH_SCALE_M,
                     float(speed < STOPPED_MPS)], np.float32)


def encode_map(cache: SceneCache, origin: Pose, t_index: int, cfg: RolloutConfig
               ) -> tuple[np.ndarray, ...]:
    """The ``max_map_chunks`` chunks nearest to ``origin``: map_vec, map_vec_mask, map_attr, map_pos,
    map_mask (shapes in :class:`Context`), padded to ``max_map_chunks``."""
    m, p = cfg.max_map_chunks, cfg.chunk_vectors
    out_vec = np.zeros((m, p, MAP_VEC_FEATURES), np.float32)
    out_vmask = np.zeros((m, p), bool)
    out_attr = np.zeros((m, MAP_ATTR_FEATURES), np.float32)
    out_pos = np.zeros((m, MAP_POS_FEATURES), np.float32)
    out_mask = np.zeros(m, bool)
    pts = cache.chunk_pts
    if len(pts) == 0:
        return out_vec, out_vmask, out_attr, out_pos, out_mask
    ox, oy, oh = (float(v) for v in origin)
    d = np.hypot(pts[..., 0] - ox, pts[..., 1] - oy).min(axis=1)  # (num_chunks,)
    near = np.flatnonzero(d <= cfg.map_radius_m)
    if len(near) > m:
        near = near[np.argpartition(d[near], m - 1)[:m]]
    near = near[np.argsort(d[near], kind="stable")]
    k = len(near)
    c, s = np.cos(oh), np.sin(oh)
    rel = pts[near] - np.array([ox, oy])  # (k, P+1, 2)
    loc = np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], -1) / cfg.pos_scale_m
    start, end = loc[:, :-1], loc[:, 1:]  # (k, P, 2)
    seg = end - start
    unit = seg / np.maximum(np.linalg.norm(seg, axis=-1, keepdims=True), 1e-9)
    vmask = cache.chunk_vec_mask[near]
    out_vec[:k] = np.concatenate([start, end, unit], -1) * vmask[..., None]
    out_vmask[:k] = vmask
    lane = cache.chunk_lane[near]
    out_attr[:k, :5] = cache.lane_attr[lane]
    t = int(np.clip(t_index, 0, cache.signal_class.shape[0] - 1))
    sig = cache.signal_class[t, lane] if cache.signal_class.shape[1] else np.zeros(k, np.int8)
    out_attr[np.arange(k), 5 + sig] = 1.0
    n_real = vmask.sum(axis=1)
    out_pos[:k, :2] = loc[:, 0]
    out_pos[:k, 2:] = loc[np.arange(k), n_real]
    out_mask[:k] = n_real > 0
    return out_vec, out_vmask, out_attr, out_pos, out_mask


def encode_neighbors(scene: Scene, origin: Pose, t_index: int, horizon: int,
                     exclude: Iterable[int], cfg: RolloutConfig) -> tuple[np.ndarray, np.ndarray]:
    """Neighbours at steps ``t_index - k``, ``k = 0..horizon``: nbr (H+1, N, 12), nbr_mask (H+1, N)."""
    n = cfg.max_neighbors
    h1 = horizon + 1
    nbr = np.zeros((h1, n, NBR_FEATURES), np.float32)
    mask = np.zeros((h1, n), bool)
    tr = scene.tracks
    if tr.num_agents == 0 or n == 0:
        return nbr, mask
    steps = t_index - np.arange(h1)  # (H+1,)
    ok_step = steps >= 0
    st = np.clip(steps, 0, tr.num_steps - 1)
    x, y = tr.x[:, st], tr.y[:, st]  # (A, H+1)
    valid = tr.valid[:, st] & ok_step[None, :]
    ex = np.fromiter(exclude, dtype=np.int64)
    valid[ex[(ex >= 0) & (ex < tr.num_agents)]] = False
    ox, oy, oh = (float(v) for v in origin)
    dist = np.where(valid, np.hypot(x - ox, y - oy), np.inf)
    dist = np.where(dist <= cfg.neighbor_select_radius_m, dist, np.inf)
    order = np.argsort(dist, axis=0, kind="stable")[:n]  # (n', H+1) nearest agents per step
    kk = order.shape[0]
    cols = np.arange(h1)[None, :]
    sel_valid = np.isfinite(dist[order, cols])  # (n', H+1)
    c, s = np.cos(oh), np.sin(oh)

    def g(a: np.ndarray) -> np.ndarray:
        return a[:, st][order, cols]  # (n', H+1)

    dx, dy = g(tr.x) - ox, g(tr.y) - oy
    vx, vy = g(tr.vx), g(tr.vy)
    hd = g(tr.heading) - oh
    typ = np.clip(tr.object_type.astype(np.int64), 1, 4)[order] - 1  # (n', H+1)
    feat = np.zeros((kk, h1, NBR_FEATURES), np.float32)
    feat[..., 0] = (c * dx + s * dy) / cfg.pos_scale_m
    feat[..., 1] = (-s * dx + c * dy) / cfg.pos_scale_m
    feat[..., 2] = (c * vx + s * vy) / cfg.vel_scale_mps
    feat[..., 3] = (-s * vx + c * vy) / cfg.vel_scale_mps
    feat[..., 4] = np.cos(hd)
    feat[..., 5] = np.sin(hd)
    feat[..., 6] = g(tr.length) / LENGTH_SCALE_M
    feat[..., 7] = g(tr.width) / WIDTH_SCALE_M
    np.put_along_axis(feat[..., 8:], typ[..., None], 1.0, axis=-1)
    feat *= sel_valid[..., None]
    nbr[:, :kk] = feat.transpose(1, 0, 2)
    mask[:, :kk] = sel_valid.T
    return nbr, mask


def encode_context(cache: SceneCache, pose: Pose, speed: float, size: tuple[float, float],
                   t_index: int, horizon: int, cfg: RolloutConfig, exclude: Iterable[int] = ()) -> Context:
    """One context: the vehicle at world ``pose`` = (x, y, yaw) with ``speed`` [m/s] and ``size`` =
    (length, width) [m] at step ``t_index`` of the 2 Hz scene, reconstructed ``horizon`` steps back;
    agents ``exclude`` are never neighbours (the vehicle itself when it is in the scene)."""
    length, width = size
    origin = np.asarray(pose, np.float64).reshape(3)
    if horizon > t_index:
        raise InputError(f"horizon {horizon} reaches before the scene start (t_index {t_index})")
    mv, mvm, ma, mp, mm = encode_map(cache, origin, t_index, cfg)
    nbr, nmask = encode_neighbors(cache.scene, origin, t_index, horizon, exclude, cfg)
    return Context(origin=origin, state=encode_state(speed, length, width, cfg), map_vec=mv,
                   map_vec_mask=mvm, map_attr=ma, map_pos=mp, map_mask=mm, nbr=nbr, nbr_mask=nmask)


def agent_context(cache: SceneCache, agent: int, t_index: int, horizon: int, cfg: RolloutConfig) -> Context:
    """The context of a logged agent of the scene at ``t_index`` (itself excluded from neighbours)."""
    tr = cache.scene.tracks
    pose = (tr.x[agent, t_index], tr.y[agent, t_index], tr.heading[agent, t_index])
    speed = float(np.hypot(tr.vx[agent, t_index], tr.vy[agent, t_index]))
    size = (float(tr.length[agent, t_index]), float(tr.width[agent, t_index]))
    return encode_context(cache, pose, speed, size, t_index, horizon, cfg, exclude=(agent,))


def reverse_targets(scene: Scene, agent: int, t_index: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """True poses at reverse steps 1..H in the agent's frame at ``t_index``.

    Returns:
        traj: (H, 3) float32 x, y [m], yaw [rad] (yaw unwrapped along the segment);
        step_mask: (H,) bool, True up to the first invalid step going back.
    """
    tr = scene.tracks
    steps = t_index - np.arange(1, horizon + 1)
    ok = steps >= 0
    st = np.clip(steps, 0, tr.num_steps - 1)
    valid = tr.valid[agent, st] & ok
    mask = np.cumprod(valid).astype(bool)
    origin = (tr.x[agent, t_index], tr.y[agent, t_index], tr.heading[agent, t_index])
    x, y, yaw = to_frame(tr.x[agent, st], tr.y[agent, st], tr.heading[agent, st], origin)
    yaw = np.unwrap(np.concatenate([[0.0], yaw]))[1:]
    traj = np.stack([x, y, yaw], -1) * mask[:, None]
    return traj.astype(np.float32), mask


def enumerate_examples(scene: Scene, cfg: RolloutConfig, *, min_steps: int = 2, full_only: bool = False,
                       t_indices: Sequence[int] | None = None, class_only: bool = True
                       ) -> list[tuple[int, int, int]]:
    """(agent, t_index, horizon) of every agent of the model's class (``cfg.agent_class``: vehicle,
    pedestrian or cyclist tracks by their object type; ``class_only=False``: every agent) with at
    least ``min_steps`` valid steps before t_index (``full_only``: the whole ``max_horizon``),
    horizon = min(max_horizon, t_index), at every step or at ``t_indices`` (negative ones count from
    the end: -1 is the last step)."""
    tr = scene.tracks
    of_class = tr.object_type == AGENT_CLASSES[cfg.agent_class]
    out: list[tuple[int, int, int]] = []
    h_max = cfg.max_horizon
    ts = range(1, scene.num_steps) if t_indices is None else [t % scene.num_steps for t in t_indices]
    for t in ts:
        if t <= 0 or t >= scene.num_steps:
            continue
        h = min(h_max, t)
        need = h_max if full_only else min(min_steps, h)
        if full_only and h < h_max:
            continue
        past = tr.valid[:, t - need:t + 1]  # (A, need+1)
        ok = np.all(past, axis=1)
        if class_only:
            ok &= of_class
        out.extend((int(a), int(t), h) for a in np.flatnonzero(ok))
    return out


# ----------------------------------------------------------------------------- batches

_CTX_FIELDS = ("state", "map_vec", "map_vec_mask", "map_attr", "map_pos", "map_mask", "nbr", "nbr_mask")


def stack_contexts(contexts: Sequence[Context]) -> dict[str, np.ndarray]:
    """Stack contexts (padding the horizon with masked steps) into arrays with a leading axis C."""
    h1 = max(c.nbr.shape[0] for c in contexts)
    out: dict[str, np.ndarray] = {}
    for name in _CTX_FIELDS:
        arrs = [getattr(c, name) for c in contexts]
        if name in ("nbr", "nbr_mask"):
            arrs = [np.concatenate([a, np.zeros((h1 - a.shape[0], *a.shape[1:]), a.dtype)]) for a in arrs]
        out[name] = np.stack(arrs)
    out["origin"] = np.stack([c.origin for c in contexts])
    return out


def to_tensors(arrays: dict[str, np.ndarray], device: Any = "cpu") -> dict[str, torch.Tensor]:
    """numpy batch -> torch tensors (float32 / bool); ``origin`` stays float64."""
    import torch

    out = {}
    for k, v in arrays.items():
        if v.dtype == np.bool_:
            out[k] = torch.from_numpy(np.ascontiguousarray(v)).to(device)
        elif k == "origin":
            out[k] = torch.from_numpy(np.ascontiguousarray(v, dtype=np.float64)).to(device)
        else:
            out[k] = torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)).to(device)
    return out


@dataclass
class ExampleSet:
    """Training / evaluation examples over many scenes.

    Attributes:
        caches: one :class:`SceneCache` per scene.
        index: (num_examples, 4) int64 rows (scene, agent, t_index, horizon).
    """

    caches: list[SceneCache]
    index: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    def batch(self, rows: Sequence[int] | np.ndarray, cfg: RolloutConfig, horizon: int | None = None
              ) -> dict[str, np.ndarray]:
        """Contexts and targets of ``rows``, padded to ``horizon`` (default: the batch's longest)."""
        ctxs = []
        trajs = []
        masks = []
        sel = self.index[np.asarray(rows, dtype=np.int64)]
        h_pad = int(sel[:, 3].max()) if horizon is None else horizon
        for s, a, t, h in sel:
            cache = self.caches[int(s)]
            ctx = agent_context(cache, int(a), int(t), int(h), cfg)
            traj, m = reverse_targets(cache.scene, int(a), int(t), h_pad)
            m[int(h):] = False
            ctxs.append(ctx)
            trajs.append(traj)
            masks.append(m)
        arrays = stack_contexts(ctxs)
        if arrays["nbr"].shape[1] < h_pad + 1:
            pad = h_pad + 1 - arrays["nbr"].shape[1]
            for k in ("nbr", "nbr_mask"):
                a = arrays[k]
                arrays[k] = np.concatenate([a, np.zeros((a.shape[0], pad, *a.shape[2:]), a.dtype)], axis=1)
        arrays["traj"] = np.stack(trajs)
        arrays["step_mask"] = np.stack(masks)
        return arrays


def build_examples(scenes: Iterable[Scene], cfg: RolloutConfig, **kwargs: Any) -> ExampleSet:
    """Resample every scene to 2 Hz, cache it and enumerate its examples (``kwargs`` go to
    :func:`enumerate_examples`)."""
    from coster_sumo.core.scene import resample

    caches: list[SceneCache] = []
    rows: list[tuple[int, int, int, int]] = []
    for scene in scenes:
        low = resample(scene, ROLLOUT_HZ)
        ex = enumerate_examples(low, cfg, **kwargs)
        if not ex:
            continue
        rows.extend((len(caches), a, t, h) for a, t, h in ex)
        caches.append(build_cache(low, cfg))
    index = np.asarray(rows, np.int64).reshape(-1, 4)
    return ExampleSet(caches=caches, index=index)

