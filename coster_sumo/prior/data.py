"""Scenes -> compact per-scene prior data -> token batches (numpy only).

A scene is prepared once (:func:`prepare_scene`): regions of its map (cropped to the neighbourhoods
that can ever be asked for), the signal category of every region per step, and the occupancy in a
compact sparse form. Batches are built on the fly from (scene, centre) pairs, so a whole dataset
stays small in memory (roughly T x R int32 plus one row per agent and step).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene, Tracks, resample
from coster_sumo.data import dataset as ds
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.geometry.frames import wrap_angle
from coster_sumo.prior.bins import AttributeBins
from coster_sumo.prior.features import (
    AGENT_FEATURES,
    MAP_FEATURES,
    Tokens,
    agent_features,
    map_features,
    random_visibility,
    target_classes,
    visible_outside,
)
from coster_sumo.prior.regions import (
    NEIGHBOURHOOD_RADIUS,
    REGION_SPACING,
    REGION_WIDTH,
    Occupancy,
    Regions,
    assigned_agent,
    build_regions,
    neighbourhood,
    region_signals,
    regions_near,
)

PRIOR_HZ = 2.0  # the prior works on scenes downsampled to 2 Hz


@dataclass(frozen=True)
class CompactOccupancy:
    """Sparse :class:`~coster_sumo.prior.regions.Occupancy`.

    Attributes:
        row: (T, R) int32 row of ``values`` for the occupied (step, region) pairs, -1 elsewhere.
        agent: (n,) int32 agent index of each row.
        values: (n, 6) float32 normalised x, y, relative heading [rad], speed [m/s], length [m], width [m].
    """

    row: np.ndarray
    agent: np.ndarray
    values: np.ndarray

    @classmethod
    def from_occupancy(cls, occ: Occupancy) -> CompactOccupancy:
        t, r = np.nonzero(occ.present)
        row = np.full(occ.agent.shape, -1, np.int32)
        row[t, r] = np.arange(len(t), dtype=np.int32)
        values = np.concatenate([occ.normalised_xy[t, r], np.stack([occ.heading[t, r], occ.speed[t, r],
                                 occ.length[t, r], occ.width[t, r]], -1)], -1).astype(np.float32)
        return cls(row=row, agent=occ.agent[t, r].astype(np.int32), values=values.reshape(-1, 6))

    @classmethod
    def of_assignment(cls, regions: Regions, tracks: Tracks, agent: np.ndarray, steps: np.ndarray
                      ) -> CompactOccupancy:
        """:meth:`from_occupancy` of ``occupancy_of(regions, tracks, agent, steps)``, its attributes
        computed at the occupied (step, region) pairs only (the same numbers: each pair's are its own;
        over a long life most pairs are empty)."""
        t, r = np.nonzero(agent >= 0)
        a, s = agent[t, r], np.asarray(steps, np.int64)[t]
        row = np.full(agent.shape, -1, np.int32)
        row[t, r] = np.arange(len(t), dtype=np.int32)
        loc = regions.to_region_frame(np.stack([tracks.x[a, s], tracks.y[a, s]], -1), r)
        norm = np.stack([loc[..., 0] / regions.width, loc[..., 1] / np.maximum(regions.height[r], 1e-9) - 0.5], -1)
        rel_h = wrap_angle(tracks.heading[a, s] - regions.heading[r])
        speed = np.hypot(tracks.vx[a, s], tracks.vy[a, s])
        values = np.concatenate([norm, np.stack([rel_h, speed, tracks.length[a, s], tracks.width[a, s]], -1)],
                                -1).astype(np.float32)
        return cls(row=row, agent=a.astype(np.int32), values=values.reshape(-1, 6))

    def gather(self, t: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows at steps ``t`` and regions ``r`` (broadcast): (agent (-1 empty), present, values (..., 6))."""
        if self.row.shape[1] == 0:  # no regions at all
            shape = np.broadcast_shapes(np.shape(t), np.shape(r))
            return np.full(shape, -1, np.int64), np.zeros(shape, bool), np.zeros(shape + (6,), np.float32)
        rows = self.row[t, r]
        present = rows >= 0
        safe = np.where(present, rows, 0)
        if len(self.values) == 0:
            return np.full(rows.shape, -1, np.int64), present, np.zeros(rows.shape + (6,), np.float32)
        # +0 at empty tokens whatever row 0 holds (a built-by-step occupancy's row 0 is another pair's)
        vals = np.where(present[..., None], self.values[safe], np.float32(0.0))
        return np.where(present, self.agent[safe], -1).astype(np.int64), present, vals


class StepOccupancy:
    """:class:`CompactOccupancy` built step by step, each step when it is first read (:meth:`gather`).

    Over a target's long life the prior reads a few of its steps (the collision-time search's grid
    and its candidates' neighbourhoods, :func:`coster_sumo.method.collision_time.entropy_search`);
    assigning the agents to the regions at every step was most of the prior's data. A step's
    assignment and its region-frame attributes depend on that step alone, so what :meth:`gather`
    returns is the same as :meth:`CompactOccupancy.gather` of the whole assignment (the same bytes).

    Attributes:
        row: (T, R) int32 row of ``values`` for the occupied (step, region) pairs of the steps
            built, -1 elsewhere.
        agent: (n,) int32 agent index of each row.
        values: (n, 6) float32 as in :class:`CompactOccupancy`.
        built: (T,) bool the steps whose assignment is in ``row``.
    """

    def __init__(self, regions: Regions, tracks: Tracks) -> None:
        self._regions, self._tracks = regions, tracks
        self.row = np.full((tracks.num_steps, len(regions)), -1, np.int32)
        self.agent = np.zeros(0, np.int32)
        self.values = np.zeros((0, 6), np.float32)
        self.built = np.zeros(tracks.num_steps, bool)

    def build(self, steps: np.ndarray) -> None:
        """Assign the agents at those of ``steps`` (any shape of step indices) not built yet."""
        new = np.unique(np.asarray(steps, np.int64))
        new = new[~self.built[new]]
        if len(new) == 0:
            return
        part = CompactOccupancy.of_assignment(self._regions, self._tracks,
                                              assigned_agent(self._regions, self._tracks, new), new)
        self.row[new] = np.where(part.row >= 0, part.row + len(self.agent), -1)
        self.agent = np.concatenate([self.agent, part.agent])
        self.values = np.concatenate([self.values, part.values])
        self.built[new] = True

    def gather(self, t: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`CompactOccupancy.gather`, the steps ``t`` built first."""
        self.build(t)
        return CompactOccupancy(row=self.row, agent=self.agent, values=self.values).gather(t, r)


@dataclass(frozen=True)
class ScenePriorData:
    """Everything the prior needs from one scene (at 2 Hz).

    Attributes:
        scenario_id: str.
        regions: the scene's regions (cropped to where neighbourhoods can reach).
        signal: (T, R) int8 signal category per step.
        occupancy: sparse occupancy (T, R), whole (:class:`CompactOccupancy`) or built at the
            steps read (:class:`StepOccupancy`, :func:`prepare_around`).
        centres: (N, 2) int64 (step, agent) pairs usable as neighbourhood centres (valid vehicles;
            :func:`prepare_around`: the target's own).
        centre_pose: (N, 3) float64 x, y [m], heading [rad] of each centre.
        sdc_index: the scene's target / self-driving car (-1 if none).
    """

    scenario_id: str
    regions: Regions
    signal: np.ndarray
    occupancy: CompactOccupancy | StepOccupancy
    centres: np.ndarray
    centre_pose: np.ndarray
    sdc_index: int = -1

    @property
    def num_steps(self) -> int:
        return int(self.signal.shape[0])


def at_prior_rate(scene: Scene) -> Scene:
    """The scene at 2 Hz (unchanged when it already is, e.g. a resampled scene)."""
    return resample(scene, PRIOR_HZ) if scene.dt < 0.75 / PRIOR_HZ else scene


def prepare_scene(scene: Scene, radius: float = NEIGHBOURHOOD_RADIUS, spacing: float = REGION_SPACING,
                  width: float = REGION_WIDTH, crop: bool | np.ndarray = True) -> ScenePriorData:
    """Regions, signals, occupancy and centres of a scene given at its own rate (use 2 Hz).

    ``crop``: True keeps only regions within ``radius`` of some valid vehicle at some step; an
    (N, 2) array keeps those within ``radius`` of these points (e.g. the target's path); False keeps all.
    """
    tr = scene.tracks
    regions = build_regions(scene.road_map, spacing=spacing, width=width)
    is_vehicle = tr.object_type == ObjectType.VEHICLE
    a_idx, t_idx = np.nonzero(tr.valid & is_vehicle[:, None])
    if isinstance(crop, np.ndarray):
        regions = regions.select(regions_near(regions, crop, radius))
    elif crop:
        keep = regions_near(regions, np.stack([tr.x[a_idx, t_idx], tr.y[a_idx, t_idx]], -1), radius)
        regions = regions.select(keep)
    agent = assigned_agent(regions, tr, np.arange(tr.num_steps))
    signal = region_signals(regions, scene.signals, len(scene.road_map.lanes))
    order = np.lexsort((a_idx, t_idx))
    centres = np.stack([t_idx[order], a_idx[order]], -1).astype(np.int64).reshape(-1, 2)
    pose = np.stack([tr.x[centres[:, 1], centres[:, 0]], tr.y[centres[:, 1], centres[:, 0]],
                     tr.heading[centres[:, 1], centres[:, 0]]], -1).reshape(-1, 3)
    return ScenePriorData(scenario_id=scene.scenario_id, regions=regions, signal=signal.astype(np.int8),
                          occupancy=CompactOccupancy.of_assignment(regions, tr, agent, np.arange(tr.num_steps)),
                          centres=centres, centre_pose=pose,
                          sdc_index=scene.sdc_index)


def prepare_around(scene: Scene, target: int, radius: float = NEIGHBOURHOOD_RADIUS,
                   spacing: float = REGION_SPACING, width: float = REGION_WIDTH) -> ScenePriorData:
    """The prior's data for one target of a scene given at 2 Hz: the regions within ``radius`` of
    its path (as :func:`prepare_scene` with ``crop`` = that path), every step's signals, the
    target's own steps as the only centres, and the occupancy built at the steps the prior reads
    (:class:`StepOccupancy`): generation over a long life costs the steps it searches, not the life.
    """
    tr = scene.tracks
    regions = build_regions(scene.road_map, spacing=spacing, width=width)
    regions = regions.select(regions_near(regions, tr.xy_of(target, tr.valid[target]).reshape(-1, 2), radius))
    signal = region_signals(regions, scene.signals, len(scene.road_map.lanes))
    steps = np.flatnonzero(tr.valid[target] & (tr.object_type[target] == ObjectType.VEHICLE))
    centres = np.stack([steps, np.full(len(steps), target)], -1).astype(np.int64).reshape(-1, 2)
    pose = np.stack([tr.x[target, steps], tr.y[target, steps], tr.heading[target, steps]], -1).reshape(-1, 3)
    return ScenePriorData(scenario_id=scene.scenario_id, regions=regions, signal=signal.astype(np.int8),
                          occupancy=StepOccupancy(regions, tr), centres=centres, centre_pose=pose,
                          sdc_index=scene.sdc_index)


class TokenSettings(Protocol):
    """What tokens are made with: the model's settings (:class:`~coster_sumo.prior.model.PriorConfig`)."""

    @property
    def radius(self) -> float:
        """[m] regions within this distance of the centre are tokens."""

    @property
    def max_regions(self) -> int:
        """At most this many regions, the nearest."""

    def bins(self) -> AttributeBins:
        """The attribute bins of the target classes."""


def scene_tokens(data: ScenePriorData, steps: np.ndarray, pose: np.ndarray, cfg: TokenSettings,
                 visible: str | np.ndarray = "map", hide_radius: float = 15.0,
                 rng: np.random.Generator | None = None) -> Tokens:
    """Tokens of samples centred at ``pose`` (B, 3) at rows ``steps`` (B,) of one scene.

    Args:
        cfg: the neighbourhood (``radius``, ``max_regions``) and the ``bins()`` of the classes.
        visible: "map" (everything hidden), "context" (regions beyond ``hide_radius`` visible),
            "random" (training draw, needs ``rng``) or a (B, K) bool array.
    """
    steps = np.asarray(steps, np.int64)
    if len(data.regions) == 0:
        b = len(steps)
        return Tokens(map_features=np.zeros((b, 1, MAP_FEATURES), np.float32),
                      agent_features=np.zeros((b, 1, AGENT_FEATURES), np.float32), mask=np.zeros((b, 1), bool),
                      query=np.zeros((b, 1), bool), present=np.zeros((b, 1), bool),
                      classes=np.zeros((b, 1, 5), np.int64), region_index=np.full((b, 1), -1, np.int64),
                      values=np.zeros((b, 1, 6), np.float32))
    index, mask = neighbourhood(data.regions, pose[:, :2], cfg.radius, cfg.max_regions)
    ridx = np.where(mask, index, 0)
    t = steps[:, None]
    agent, present, vals = data.occupancy.gather(t, ridx)
    present &= mask
    dist = np.hypot(*(data.regions.centre[ridx] - pose[:, None, :2]).transpose(2, 0, 1))
    if isinstance(visible, np.ndarray):
        vis = visible
    elif visible == "map":
        vis = np.zeros(mask.shape, bool)
    elif visible == "context":
        vis = visible_outside(dist, hide_radius)
    elif visible == "random":
        if rng is None:
            raise ValueError("visible='random' needs rng")
        vis = random_visibility(rng, dist)
    else:
        raise ValueError(f"unknown visibility {visible!r}")
    vis = vis & mask
    nxy, hd, sp, ln, wd = vals[..., :2], vals[..., 2], vals[..., 3], vals[..., 4], vals[..., 5]
    sig = data.signal[t, ridx]
    return Tokens(map_features=map_features(data.regions, index, mask, sig, pose, cfg.radius),
                  agent_features=agent_features(present, nxy, hd, sp, ln, wd, vis),
                  mask=mask, query=mask & ~vis, present=present,
                  classes=target_classes(cfg.bins(), nxy, hd, sp, ln, wd), region_index=np.where(mask, index, -1),
                  values=vals.astype(np.float32))


def concat_tokens(parts: Sequence[Tokens]) -> Tokens:
    """Concatenate token batches along B, padding K to the largest."""
    k = max(p.mask.shape[1] for p in parts)

    def pad(a: np.ndarray, value: float | int | bool) -> np.ndarray:
        widths = [(0, 0), (0, k - a.shape[1])] + [(0, 0)] * (a.ndim - 2)
        return np.pad(a, widths, constant_values=value)

    return Tokens(**{name: np.concatenate([pad(getattr(p, name), -1 if name == "region_index" else 0)
                                           for p in parts])
                     for name in ("map_features", "agent_features", "mask", "query", "present", "classes",
                                  "region_index", "values")})


def epoch_samples(scenes: Sequence[ScenePriorData], rng: np.random.Generator, per_step: int = 1
                  ) -> np.ndarray:
    """(N, 2) int64 (scene, centre row) pairs: ``per_step`` random centres at every step of every scene,
    shuffled."""
    out = []
    for si, d in enumerate(scenes):
        if len(d.centres) == 0:
            continue
        steps = d.centres[:, 0]
        # random key per centre, then the first per_step centres of every step
        order = np.lexsort((rng.random(len(steps)), steps))
        rank = np.arange(len(order)) - np.searchsorted(steps[order], steps[order])
        chosen = order[rank < per_step]
        out.append(np.stack([np.full(len(chosen), si), chosen], -1))
    samples = np.concatenate(out) if out else np.zeros((0, 2), np.int64)
    return samples[rng.permutation(len(samples))]


def batch_tokens(scenes: Sequence[ScenePriorData], samples: np.ndarray, cfg: TokenSettings, visible: str = "random",
                 rng: np.random.Generator | None = None, hide_radius: float = 15.0) -> Tokens:
    """Tokens for (scene, centre row) pairs (grouped by scene internally; order kept)."""
    parts = []
    order = []
    for si in np.unique(samples[:, 0]):
        rows = np.flatnonzero(samples[:, 0] == si)
        d = scenes[int(si)]
        c = samples[rows, 1]
        parts.append(scene_tokens(d, d.centres[c, 0], d.centre_pose[c], cfg, visible=visible, hide_radius=hide_radius,
                                  rng=rng))
        order.append(rows)
    tokens = concat_tokens(parts)
    inverse = np.argsort(np.concatenate(order))
    return Tokens(**{k: v[inverse] for k, v in vars(tokens).items()})


# ----------------------------------------------------------------------------- datasets on disk


def scene_files(data: str | Path) -> list[Path]:
    """The scene files of a dataset (``DATASET/scenes/*.npz``, see :mod:`coster_sumo.data.dataset`),
    a plain folder of ``.npz`` scenes, or one scene file."""
    p = Path(data)
    if p.is_file():
        return [p]
    files = ds.list_scenes(p)
    if not files:
        raise InputError(f"{p}: no scene files (expected {p}/scenes/*.npz)")
    return files


def split_files(data: str | Path, val_fraction: float = 0.1, seed: int = 0) -> tuple[list[Path], list[Path]]:
    """Train / held-out split of a dataset: :func:`coster_sumo.data.dataset.split` (by file name hash)."""
    return ds.split(scene_files(data), val_fraction, seed=seed)


def load_prepared(files: Iterable[Path], radius: float = NEIGHBOURHOOD_RADIUS, progress: bool = False
                  ) -> list[ScenePriorData]:
    """Load scene files, bring them to 2 Hz and prepare them."""
    files = list(files)
    it: Iterable[Path] = files
    if progress:
        from tqdm import tqdm

        it = tqdm(files, desc="preparing scenes", unit="scene")
    return [prepare_scene(at_prior_rate(load_scene(f)), radius=radius) for f in it]
