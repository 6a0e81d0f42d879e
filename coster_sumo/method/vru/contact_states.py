"""The learned speed and heading of a pedestrian or cyclist where it meets a vehicle.

A vehicle adversary's state at contact comes from the traffic prior, trained on vehicle tracks.
For a pedestrian or cyclist, :class:`ContactStates` holds what the class does where a vehicle can
reach it, counted on a corpus of scenes (``coster-sumo train vru-states``): at every 2 Hz step at
which an agent of the class moves (at least :data:`MOVING_MPS`) on the road surface or a crossing,
its speed and the angle between its heading and the nearest lane's direction, folded to [0, pi]
(0: along the lane, pi/2: across it, pi: against it). One 2-D histogram per class; a draw picks a
bin by its count and a point uniformly inside it. docs/method.md ("Pedestrian and cyclist
adversaries") says how the snapshot uses it and what the shipped file holds.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from coster_sumo.core.scene import Scene, resample
from coster_sumo.data.dataset import clip_window
from coster_sumo.errors import InputError
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import VRU_CLASSES, VruClass

MOVING_MPS = 0.3  # [m/s] slower, a heading says little (a waiting pedestrian turns on the spot)
SPEED_EDGES = np.round(np.arange(0.0, 10.0 + 1e-9, 0.1), 6)  # [m/s] up to the fastest class's limit
HEADING_EDGES = np.linspace(0.0, np.pi, 19)  # [rad] 10-degree bins
MIN_SAMPLES = 200  # a class with fewer counted steps is not drawn from (the rules apply instead)
STEP_HZ = 2.0  # the rollout's rate: neighbouring 10 Hz steps of one walk would count five times


@dataclass(frozen=True)
class ContactStates:
    """Per class, counts of (speed, heading to the lane) on the road surface.

    Attributes:
        counts: class name -> (len(SPEED_EDGES) - 1, len(HEADING_EDGES) - 1) int64 counts.
        meta: what was counted (scenes, steps per class, the settings above).
    """

    counts: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def has(self, name: str) -> bool:
        """Whether class ``name`` has enough counted steps to be drawn from."""
        c = self.counts.get(name)
        return c is not None and int(c.sum()) >= MIN_SAMPLES

    def draw(self, name: str, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(n,) speeds [m/s] and (n,) angles to the lane [rad, 0..pi] of class ``name``."""
        c = self.counts[name].astype(np.float64)
        flat = rng.choice(c.size, size=n, p=(c / c.sum()).ravel())
        i, j = np.unravel_index(flat, c.shape)
        speed = rng.uniform(SPEED_EDGES[i], SPEED_EDGES[i + 1])
        angle = rng.uniform(HEADING_EDGES[j], HEADING_EDGES[j + 1])
        return speed, angle

    def crossing_share(self, name: str) -> float:
        """Share of the class's counted steps at 50-130 degrees to the lane (the bins whose middle lies
        between 45 and 135 degrees)."""
        c = self.counts[name]
        mid = 0.5 * (HEADING_EDGES[:-1] + HEADING_EDGES[1:])
        across = (mid > np.pi / 4) & (mid < 3 * np.pi / 4)
        return float(c[:, across].sum() / max(c.sum(), 1))

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        arrays = {"speed_edges": SPEED_EDGES, "heading_edges": HEADING_EDGES, "meta": np.array(json.dumps(self.meta)),
                  **{f"counts_{k}": v for k, v in self.counts.items()}}
        np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> ContactStates:
        """The counts in ``path``; one :class:`InputError` line for a file that is not such counts."""
        try:
            return cls._read(path)
        except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: not a counts file of `coster-sumo train vru-states` ({exc})") from None

    @classmethod
    def _read(cls, path: str | Path) -> ContactStates:
        with np.load(path, allow_pickle=False) as z:
            same = np.array_equal(z["speed_edges"], SPEED_EDGES) and np.array_equal(z["heading_edges"], HEADING_EDGES)
            if not same:
                raise InputError(f"{path}: its bins are not this version's (train it again with "
                                 "`coster-sumo train vru-states`)")
            counts = {k[len("counts_"):]: z[k].astype(np.int64) for k in z.files if k.startswith("counts_")}
            return cls(counts=counts, meta=json.loads(str(z["meta"])))


def _lane_directions(scene: Scene) -> tuple[shapely.STRtree, np.ndarray] | None:
    """A tree of the map's lane segments and each segment's direction [rad] (None without lanes)."""
    cl = scene.road_map.lanes.centerline
    pts = cl.values
    # a segment joins point i to i + 1 of one lane: every point but each lane's last starts one
    first = np.ones(len(pts), bool)
    first[np.asarray(cl.offsets[1:], np.int64) - 1] = False
    i = np.flatnonzero(first[:-1]) if len(pts) else np.zeros(0, np.int64)
    if not len(i):
        return None
    a, b = pts[i], pts[i + 1]
    seg = shapely.linestrings(np.stack([a, b], axis=1))
    return shapely.STRtree(seg), np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])


@dataclass(frozen=True)
class _Samples:
    """Moving agents' steps on the road of one scene at :data:`STEP_HZ`: per step its agent's id,
    time [s], speed [m/s], angle to the nearest lane [rad] and object type."""

    ids: np.ndarray
    times: np.ndarray
    speed: np.ndarray
    angle: np.ndarray
    object_type: np.ndarray


def _road_samples(scene: Scene) -> _Samples | None:
    """Every pedestrian's and cyclist's moving steps on the road surface or a crossing of ``scene``
    (once per scene: one resample, one lane tree, one road surface for both classes)."""
    types = np.array([vru.object_type for vru in VRU_CLASSES.values()])
    agents = np.flatnonzero(np.isin(scene.tracks.object_type, types))
    lanes = _lane_directions(scene) if len(agents) else None
    if lanes is None:
        return None
    s = resample(scene, STEP_HZ)
    tr = s.tracks
    speed = np.hypot(tr.vx[agents], tr.vy[agents])
    keep = tr.valid[agents] & (speed >= MOVING_MPS)
    if not keep.any():
        return None
    row, step = np.nonzero(keep)
    xy = np.stack([tr.x[agents][keep], tr.y[agents][keep]], axis=-1)
    # the road surface and the crossings do not depend on the class (only the band beside the road does)
    area = ClassArea.build(VRU_CLASSES["pedestrian"], s.road_map, DrivableArea.from_road_map(s.road_map))
    on = area.on_road(xy)
    if not area.crossings.is_empty:
        on |= np.asarray(shapely.contains_xy(area.crossings, xy[:, 0], xy[:, 1]), bool)
    if not on.any():
        return None
    tree, direction = lanes
    nearest = tree.query_nearest(shapely.points(xy[on]), return_distance=False, all_matches=False)[1]
    angle = np.abs(np.angle(np.exp(1j * (tr.heading[agents][keep][on] - direction[nearest]))))
    a = agents[row[on]]
    return _Samples(ids=tr.ids[a], times=s.timestamps[step[on]], speed=speed[keep][on], angle=angle,
                    object_type=tr.object_type[a])


def scene_samples(scene: Scene, vru: VruClass) -> tuple[np.ndarray, np.ndarray]:
    """(speeds [m/s], angles to the nearest lane [rad, 0..pi]) of ``vru``'s moving agents on the road
    surface or a crossing in ``scene``, at :data:`STEP_HZ` (speeds above the class's limit left out)."""
    got = _road_samples(scene)
    if got is None:
        return np.zeros(0), np.zeros(0)
    m = (got.object_type == vru.object_type) & (got.speed <= vru.fast_max)
    return got.speed[m], got.angle[m]


def fit_contact_states(scenes: Iterable[Scene], progress: Callable[[Iterable[Scene]], Iterable[Scene]] | None = None,
                       source: str = "") -> ContactStates:
    """Count every class of :data:`VRU_CLASSES` over ``scenes`` (module docstring); an agent's step
    is counted once however many clips of its window
    (:func:`~coster_sumo.data.dataset.clip_window`) hold it."""
    shape = (len(SPEED_EDGES) - 1, len(HEADING_EDGES) - 1)
    counts = {name: np.zeros(shape, np.int64) for name in VRU_CLASSES}
    seen: set[tuple[str, str, float]] = set()
    n_scenes = 0
    for scene in progress(scenes) if progress is not None else scenes:
        n_scenes += 1
        got = _road_samples(scene)
        if got is None:
            continue
        window = clip_window(scene.scenario_id)
        keys = [(window, str(i), round(float(t), 3)) for i, t in zip(got.ids, got.times, strict=True)]
        new = np.array([k not in seen for k in keys], bool)
        seen.update(keys)
        for name, vru in VRU_CLASSES.items():
            m = new & (got.object_type == vru.object_type) & (got.speed <= vru.fast_max)
            if m.any():
                counts[name] += np.histogram2d(got.speed[m], got.angle[m],
                                               bins=[SPEED_EDGES, HEADING_EDGES])[0].astype(np.int64)
    meta = {"source": source, "scenes": n_scenes, "steps": {k: int(v.sum()) for k, v in counts.items()},
            "moving_mps": MOVING_MPS, "step_hz": STEP_HZ, "min_samples": MIN_SAMPLES}
    return ContactStates(counts=counts, meta=meta)
