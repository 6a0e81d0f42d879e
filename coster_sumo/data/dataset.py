"""The nominal dataset: WOMD-like clips of simulated (or converted) traffic, one scene per file.

Folder format::

    DATASET/
      manifest.json        what was simulated: sources, seeds, demand scales, counts, hours
      scenes/<name>.npz    one clip each (coster_sumo.formats.scene_file.save_scene): what training reads
      heldout/<name>.npz   clips of held-out networks: never listed by list_scenes, so never trained on
      stats/<run>.npz      per-run statistics for the corpus card (coster_sumo.batch.card)
      nets/                networks generated for the dataset (netgenerate), with their demand

Every clip looks like a WOMD scenario: 10 Hz, :data:`CLIP_STEPS` = 91 steps (9.1 s),
``current_time_index`` = 10 (1 s of history), timestamps starting at 0. ``sdc_index`` is the
clip's **target**: a vehicle valid in all 91 steps. The map is cropped to what lies within
:data:`CROP_RADIUS_M` of the target's trajectory, and agents to those that come that close.

This module is pure numpy (no SUMO): cutting clips out of a long recorded scene
(:func:`cut_clips`), cropping (:func:`crop_map`, :func:`crop_scene`), listing, splitting and reading
a dataset, and its manifest. ``coster-sumo simulate``
(:mod:`coster_sumo.batch.simulate`)
and ``coster-sumo corpus`` (:mod:`coster_sumo.batch.corpus`) write datasets in this format.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import Lanes, ObjectType, Polylines, Ragged, RoadMap, Scene, SignalStates, Tracks
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.infra.atomic import write_json

CLIP_HZ = 10.0  # [1/s]
CLIP_STEPS = 91  # 9.1 s like WOMD
CURRENT_TIME_INDEX = 10  # 1 s of history, 8 s of future
CROP_RADIUS_M = 120.0  # [m] map and agents kept around the target's trajectory
MIN_TARGET_PATH_M = 5.0  # [m] a target moves at least this far in its clip (no parked cars)
MIN_TARGET_SEPARATION_M = 40.0  # [m] targets of clips cut from the same window stand this far apart
MANIFEST = "manifest.json"
SCENES_DIR = "scenes"
HELDOUT_DIR = "heldout"  # clips of held-out networks: a folder training never reads
NETS_DIR = "nets"
FORMAT_NAME = "coster-sumo-dataset"
FORMAT_VERSION = 1


# ----------------------------------------------------------------------------- cropping

def _remap_ragged(r: Ragged, keep: np.ndarray, new_index: np.ndarray | None = None) -> Ragged:
    """Keep the items where ``keep``; with ``new_index`` (old -> new, -1 = dropped) also rewrite the
    values (lane indices) and drop references to removed items."""
    items = [r[int(i)] for i in np.flatnonzero(keep)]
    if new_index is not None:
        items = [new_index[v][new_index[v] >= 0] for v in items]
    inner = r.values.shape[1:]
    return Ragged.from_list(items, dtype=r.values.dtype, inner_shape=inner)


def _near_items(polys: Ragged, points: np.ndarray, radius_m: float) -> np.ndarray:
    """(num_items,) bool: which polylines pass within ``radius_m`` of any of ``points`` (P, 2).

    Distances are to the polylines' segments, not only their vertices: SUMO lanes on straight
    roads have two points hundreds of metres apart.
    """
    n = len(polys)
    out = np.zeros(n, dtype=bool)
    if n == 0 or len(points) == 0 or len(polys.values) == 0:
        return out
    vals = polys.values
    item = polys.item_index()
    # segments between consecutive points of the same item, plus every vertex as a 0-length
    # segment so that one-point items count too
    same = item[1:] == item[:-1]
    s0 = np.concatenate([vals[:-1][same], vals])  # (S, 2)
    s1 = np.concatenate([vals[1:][same], vals])
    seg_item = np.concatenate([item[:-1][same], item])
    # a vehicle's path repeats points while it stands; sorted points make compact blocks below
    points = np.unique(np.asarray(points, np.float64).reshape(-1, 2), axis=0)
    lo, hi = points.min(axis=0) - radius_m, points.max(axis=0) + radius_m
    seg_lo, seg_hi = np.minimum(s0, s1), np.maximum(s0, s1)
    cand = np.all(seg_hi >= lo, axis=1) & np.all(seg_lo <= hi, axis=1)  # bounding-box prefilter
    s0, s1, seg_item = s0[cand], s1[cand], seg_item[cand]
    seg_lo, seg_hi = seg_lo[cand], seg_hi[cand]
    if len(s0) == 0:
        return out
    hit = np.zeros(len(s0), dtype=bool)
    for start in range(0, len(points), 64):  # blocks of points, each against the segments near it
        block = points[start:start + 64]
        b_lo, b_hi = block.min(axis=0) - radius_m, block.max(axis=0) + radius_m
        near = np.flatnonzero(~hit & np.all(seg_hi >= b_lo, axis=1) & np.all(seg_lo <= b_hi, axis=1))
        if len(near) == 0:
            continue
        a, e = s0[near][:, None, :], (s1[near] - s0[near])[:, None, :]  # (S, 1, 2)
        p = block[None, :, :]  # (1, P, 2)
        t = np.sum((p - a) * e, axis=-1) / np.maximum(np.sum(e * e, axis=-1), 1e-12)
        t = np.clip(t, 0.0, 1.0)
        d = p - a - t[..., None] * e  # (S, P, 2)
        hit[near] |= np.any(np.hypot(d[..., 0], d[..., 1]) <= radius_m, axis=1)
    np.logical_or.at(out, seg_item[hit], True)
    return out


def _crop_polylines(p: Polylines, points: np.ndarray, radius_m: float) -> Polylines:
    keep = _near_items(p.points, points, radius_m)
    return Polylines(points=_remap_ragged(p.points, keep), kind=p.kind[keep])


def crop_map(road_map: RoadMap, points: np.ndarray, radius_m: float = CROP_RADIUS_M
             ) -> tuple[RoadMap, np.ndarray]:
    """Keep the parts of a map within ``radius_m`` of ``points``.

    Args:
        road_map: the full map.
        points: (P, 2) float64 [m], e.g. the target's trajectory.
        radius_m: [m] a lane (polyline, stop sign) is kept when any of its segments comes this close.

    Returns:
        The cropped map, and ``lane_index``: (num_lanes_before,) int64, the old lane index ->
        the new one, -1 for lanes dropped. Lane topology (successors, neighbours, stop-sign lanes)
        is re-indexed, with links to dropped lanes removed.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    lanes = road_map.lanes
    keep = _near_items(lanes.centerline, points, radius_m)
    new_index = np.full(len(lanes), -1, dtype=np.int64)
    new_index[keep] = np.arange(int(keep.sum()))
    cropped_lanes = Lanes(
        ids=lanes.ids[keep], centerline=_remap_ragged(lanes.centerline, keep), width=lanes.width[keep],
        lane_type=lanes.lane_type[keep], speed_limit=lanes.speed_limit[keep],
        is_junction=lanes.is_junction[keep],
        **{f: _remap_ragged(getattr(lanes, f), keep, new_index)
           for f in ("predecessors", "successors", "left_neighbors", "right_neighbors")})
    if len(road_map.stop_sign_xy):
        d = np.linalg.norm(road_map.stop_sign_xy[:, None, :] - points[None, :, :], axis=-1)  # (K, P)
        keep_signs = d.min(axis=1) <= radius_m
    else:
        keep_signs = np.zeros(0, dtype=bool)
    cropped = RoadMap(
        lanes=cropped_lanes,
        road_lines=_crop_polylines(road_map.road_lines, points, radius_m),
        road_edges=_crop_polylines(road_map.road_edges, points, radius_m),
        crosswalks=_crop_polylines(road_map.crosswalks, points, radius_m),
        junctions=_crop_polylines(road_map.junctions, points, radius_m),
        stop_sign_xy=road_map.stop_sign_xy[keep_signs],
        stop_sign_lanes=_remap_ragged(road_map.stop_sign_lanes, keep_signs, new_index),
    )
    return cropped, new_index


def crop_scene(scene: Scene, radius_m: float = CROP_RADIUS_M, target: int | None = None,
               agent_radius_m: float | None = None, more_targets: Sequence[int] = ()) -> Scene:
    """Crop a scene around its target's trajectory (``target`` or else ``scene.sdc_index``).

    The map keeps what lies within ``radius_m`` of the target's valid positions; agents are kept
    when they come within ``agent_radius_m`` (default ``radius_m``; ``inf``: every agent) of the
    target's position at the same step (the target itself always). ``more_targets`` are treated
    like the target (several targets of one run: the union around all of them). Signals keep the
    controlled lanes that remain. Returns the scene unchanged when it has no target.
    """
    target = scene.sdc_index if target is None else target
    if target < 0:
        return scene
    tr = scene.tracks
    centres = list(dict.fromkeys([target, *more_targets]))
    path = np.concatenate([tr.xy_of(c, tr.valid[c]) for c in centres])  # (T, 2)
    road_map, new_index = crop_map(scene.road_map, path, radius_m)
    agent_radius_m = radius_m if agent_radius_m is None else agent_radius_m
    if math.isinf(agent_radius_m):
        near = np.ones(tr.num_agents, bool)
    else:
        near = np.zeros(tr.num_agents, bool)
        for c in centres:
            both = tr.valid & tr.valid[c][None, :]  # (A, T)
            dist = np.hypot(tr.x - tr.x[c][None, :], tr.y - tr.y[c][None, :])  # (A, T)
            near |= np.any(both & (dist <= agent_radius_m), axis=1)
    near[centres] = True
    agents = np.flatnonzero(near)
    tracks = tr if len(agents) == len(near) else tr.select(agents=agents)
    sig = scene.signals
    lane_new = new_index[sig.lane_index] if len(sig.lane_index) else np.zeros(0, np.int64)
    kept_sig = lane_new >= 0
    signals = SignalStates(lane_index=lane_new[kept_sig], state=sig.state[:, kept_sig],
                           stop_point=sig.stop_point[kept_sig])
    return dataclasses.replace(scene, tracks=tracks, road_map=road_map,
                               signals=signals, sdc_index=int(np.searchsorted(agents, target)))


# ----------------------------------------------------------------------------- clips

def eligible_targets(tracks: Tracks, start: int, num_steps: int = CLIP_STEPS,
                     min_path_m: float = MIN_TARGET_PATH_M) -> np.ndarray:
    """(K,) int64 agents that may be a clip's target: vehicles valid in every step of the window
    ``start .. start + num_steps`` that travel at least ``min_path_m`` in it."""
    window = slice(start, start + num_steps)
    ok = np.all(tracks.valid[:, window], axis=1) & (tracks.object_type == ObjectType.VEHICLE)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return idx.astype(np.int64)
    xy = tracks.xy_of(idx, window)  # (K, T, 2)
    travelled = np.sum(np.linalg.norm(np.diff(xy, axis=1), axis=-1), axis=1)
    return idx[travelled >= min_path_m].astype(np.int64)


def clip_scene(scene: Scene, start: int, target: int, *, num_steps: int = CLIP_STEPS,
               current_time_index: int = CURRENT_TIME_INDEX, radius_m: float = CROP_RADIUS_M,
               scenario_id: str | None = None) -> Scene:
    """One WOMD-like clip: steps ``start .. start + num_steps`` of ``scene`` with ``target`` as
    ``sdc_index``, timestamps from 0, cropped around the target (see :func:`crop_scene`).

    ``meta`` gains ``start_time_s`` (the clip's first step in the source scene's time [s]) and
    ``target_id``.
    """
    if start < 0 or start + num_steps > scene.num_steps:
        raise InputError(f"{scene.scenario_id}: clip {start}..{start + num_steps} is outside "
                         f"the scene's {scene.num_steps} steps")
    steps = np.arange(start, start + num_steps)
    tr = scene.tracks
    seen = np.any(tr.valid[:, steps], axis=1)
    seen[target] = True
    agents = np.flatnonzero(seen)
    sig = scene.signals
    target_id = str(tr.ids[target])
    t0 = float(scene.timestamps[start])
    meta = dict(scene.meta)
    meta.update({"start_time_s": round(t0, 6), "target_id": target_id,
                 "source_scenario_id": scene.scenario_id})
    clip = dataclasses.replace(
        scene,
        scenario_id=scenario_id or f"{scene.scenario_id}_{t0:07.1f}_{target_id}",
        timestamps=scene.timestamps[steps] - t0,
        tracks=tr.select(agents=agents, steps=steps),
        signals=SignalStates(lane_index=sig.lane_index, state=sig.state[steps], stop_point=sig.stop_point),
        sdc_index=int(np.searchsorted(agents, target)),
        current_time_index=current_time_index,
        meta=meta,
    )
    return crop_scene(clip, radius_m)


@dataclasses.dataclass(frozen=True)
class ClipRules:
    """How :func:`plan_clips` chooses clips, checked when made.

    Attributes:
        targets_per_window: targets drawn per window at the most.
        warmup_s: [s] the windows start this long after the scene's first step.
        prefer: vehicle ids drawn first where they are eligible.
        num_steps: steps per window (a clip's length).
        min_path_m: [m] a target drives at least this far in its window (:func:`eligible_targets`).
        min_separation_m: [m] targets of one window stand at least this far apart at its current step.
    """

    targets_per_window: int = 3
    warmup_s: float = 0.0
    prefer: Sequence[str] = ()
    num_steps: int = CLIP_STEPS
    min_path_m: float = MIN_TARGET_PATH_M
    min_separation_m: float = MIN_TARGET_SEPARATION_M

    def __post_init__(self) -> None:
        if self.targets_per_window < 1:
            raise InputError(f"targets per window must be >= 1, not {self.targets_per_window}")
        if self.num_steps < 1:
            raise InputError(f"a clip needs at least one step, not {self.num_steps}")
        if self.warmup_s < 0:
            raise InputError(f"the warm-up must be >= 0 s, not {self.warmup_s}")


def plan_clips(scene: Scene, max_clips: int, rng: np.random.Generator,
               rules: ClipRules | None = None) -> list[tuple[int, int]]:
    """Choose up to ``max_clips`` (start step, target agent) pairs from a long 10 Hz scene, as the
    ``rules`` say (None: the defaults of :class:`ClipRules`).

    Windows of ``num_steps`` steps follow each other without overlap from ``warmup_s``. In each,
    up to ``targets_per_window`` eligible targets (:func:`eligible_targets`) are drawn with ``rng``,
    vehicles named in ``prefer`` first, each at least ``min_separation_m`` from the others at the
    window's current step. When ``max_clips`` is the limit, clips are spread over the windows
    (first one target per window, then a second, ...). Deterministic for a given ``rng`` state.
    """
    r = rules or ClipRules()
    targets_per_window, prefer, num_steps = r.targets_per_window, r.prefer, r.num_steps
    first = int(np.searchsorted(scene.timestamps, scene.timestamps[0] + r.warmup_s - 1e-9))
    tr = scene.tracks
    per_window: list[list[tuple[int, int]]] = []
    for start in range(first, scene.num_steps - num_steps + 1, num_steps):
        cand = eligible_targets(tr, start, num_steps, r.min_path_m)
        if len(cand) == 0:
            continue
        preferred = [c for c in cand if str(tr.ids[c]) in prefer]
        others = [c for c in rng.permutation(cand) if str(tr.ids[c]) not in prefer]
        now = start + min(CURRENT_TIME_INDEX, num_steps - 1)
        chosen: list[int] = []
        for c in preferred + others:
            if len(chosen) >= targets_per_window:
                break
            if all(np.hypot(tr.x[c, now] - tr.x[o, now], tr.y[c, now] - tr.y[o, now]) >= r.min_separation_m
                   for o in chosen):
                chosen.append(int(c))
        per_window.append([(start, c) for c in chosen])
    out: list[tuple[int, int]] = []
    for rank in range(targets_per_window):
        for picks in per_window:
            if rank < len(picks) and len(out) < max_clips:
                out.append(picks[rank])
    return sorted(out)


def cut_clips(scene: Scene, max_clips: int, seed: int = 0, rules: ClipRules | None = None) -> list[Scene]:
    """:func:`plan_clips` then :func:`clip_scene` for each pick."""
    rng = np.random.default_rng(seed)
    picks = plan_clips(scene, max_clips, rng, rules)
    return [clip_scene(scene, start, target) for start, target in picks]


def safe_name(text: str) -> str:
    """A file-name-safe version of ``text`` (ids may hold '#', ':' or '/')."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-") or "x"


def clip_name(run_id: str, t0: float, target_id: str) -> str:
    """A corpus clip's name: its run (``NET_rRUN``), its window's start [s] in the run and its target.
    A window gives one clip per target, and those clips share their agents (:func:`clip_window`)."""
    return f"{run_id}_{t0:07.1f}_{safe_name(target_id)}"


_CLIP = re.compile(r"^(.+?_r\d+_\d+\.\d)_.+$")


def clip_window(scenario_id: str) -> str:
    """The recorded window a clip of :func:`clip_name` was cut from (``NET_rRUN_START``), whatever
    its target id holds (``veh_mw1816``, ``O10.16``); any other id is its own window."""
    m = _CLIP.match(scenario_id)
    return m.group(1) if m else scenario_id


# ----------------------------------------------------------------------------- reading

def scenes_dir(dataset: str | Path) -> Path:
    return Path(dataset) / SCENES_DIR


def heldout_dir(dataset: str | Path) -> Path:
    return Path(dataset) / HELDOUT_DIR


def list_heldout(dataset: str | Path) -> list[Path]:
    """Sorted clip files of the dataset's held-out networks (``DATASET/heldout/*.npz``)."""
    folder = heldout_dir(dataset)
    return sorted(p for p in folder.glob("*.npz") if not p.name.endswith(".tmp.npz")) if folder.is_dir() else []


def list_scenes(dataset: str | Path) -> list[Path]:
    """Sorted scene files of a dataset folder (``DATASET/scenes/*.npz``), or of a plain folder of
    ``.npz`` files. Half-written temporaries are skipped. Raises :class:`InputError` if the folder
    does not exist.

    Never the held-out networks' clips (``DATASET/heldout/``, :func:`list_heldout`): every training
    and validation split is drawn from this list, so they are excluded by construction."""
    root = Path(dataset)
    if not root.is_dir():
        raise not_found(root, "folder")
    folder = root / SCENES_DIR if (root / SCENES_DIR).is_dir() else root
    return sorted(p for p in folder.glob("*.npz") if not p.name.endswith(".tmp.npz"))


def split(paths: Iterable[str | Path], val_fraction: float, seed: int = 0) -> tuple[list[Path], list[Path]]:
    """Deterministic train / validation split by a hash of each file **name** (and ``seed``).

    A file stays on its side when other files are added or removed, and when the dataset moves.
    Returns ``(train, val)``, each sorted.
    """
    if not 0.0 <= val_fraction <= 1.0:
        raise InputError(f"val_fraction must be within [0, 1], got {val_fraction}")
    train: list[Path] = []
    val: list[Path] = []
    for p in sorted(Path(x) for x in paths):
        h = hashlib.sha256(f"{seed}:{p.name}".encode()).digest()
        u = int.from_bytes(h[:8], "big") / 2.0**64  # uniform in [0, 1)
        (val if u < val_fraction else train).append(p)
    return train, val


def iter_scenes(source: str | Path | Iterable[str | Path]) -> Iterator[Scene]:
    """Load scenes one at a time from a dataset folder or from an iterable of scene paths."""
    paths = list_scenes(source) if isinstance(source, str | Path) else [Path(p) for p in source]
    for p in paths:
        yield load_scene(p)


# ----------------------------------------------------------------------------- manifest

def new_manifest() -> dict:
    return {"format": FORMAT_NAME, "version": FORMAT_VERSION, "hz": CLIP_HZ, "clip_steps": CLIP_STEPS,
            "current_time_index": CURRENT_TIME_INDEX, "crop_radius_m": CROP_RADIUS_M, "runs": [],
            "counts": {"runs": 0, "runs_failed": 0, "scenes": 0}, "simulated_hours": 0.0}


def read_manifest(dataset: str | Path) -> dict:
    """The dataset's manifest, or a new empty one when there is none yet."""
    path = Path(dataset) / MANIFEST
    if not path.exists():
        return new_manifest()
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a dataset manifest ({exc})") from None
    if data.get("format") != FORMAT_NAME:
        raise InputError(f"{path}: not a {FORMAT_NAME} manifest")
    return data


def write_manifest(dataset: str | Path, manifest: dict) -> Path:
    """Recompute the totals from ``manifest["runs"]`` and write it atomically."""
    runs = manifest.get("runs", [])
    ok = [r for r in runs if r.get("status") == "ok"]
    manifest["counts"] = {"runs": len(ok), "runs_failed": len(runs) - len(ok),
                          "scenes": int(sum(r.get("clips", 0) for r in ok))}
    manifest["simulated_hours"] = round(sum(float(r.get("duration_s", 0.0)) for r in ok) / 3600.0, 6)
    path = Path(dataset) / MANIFEST
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_json(path, manifest)
