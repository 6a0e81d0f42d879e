"""What a corpus run writes for its card besides clips (``DATASET/stats/<run>.npz``, docs/corpus.md).

:class:`Sampler` samples every vehicle once per simulated second with SUMO's own values (speed,
acceleration, lateral speed, lane speed limit, class, size); :func:`clip_summary` and
:func:`clip_vru_seconds` summarise every clip written. :mod:`coster_sumo.batch.card` reads them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from coster_sumo.core.scene import ObjectType

STATS_EVERY = 10  # record steps between two statistics samples (1 Hz at 10 Hz)


class Sampler:
    """Per-vehicle samples once per simulated second (SUMO's own values), for the corpus card."""

    def __init__(self) -> None:
        self.step = 0
        self.cols: dict[str, list[Any]] = {k: [] for k in
                                           ("speed", "accel", "lat_speed", "limit", "length", "width", "vclass")}

    def __call__(self, session: Any, st: Any) -> None:
        self.step += 1
        if self.step % STATS_EVERY or len(st) == 0:
            return
        veh = session.api.vehicle
        ids = st.id_list()
        self.cols["speed"].append(st.speed.astype(np.float32))
        self.cols["accel"].append(np.array([veh.getAcceleration(v) for v in ids], np.float32))
        self.cols["lat_speed"].append(np.array([veh.getLateralSpeed(v) for v in ids], np.float32))
        lane_speed = session.api.lane.getMaxSpeed  # the lane's speed limit (not the vehicle's share of it)
        self.cols["limit"].append(np.array([lane_speed(veh.getLaneID(v)) if veh.getLaneID(v) else np.nan
                                            for v in ids], np.float32))
        self.cols["length"].append(st.length.astype(np.float32))
        self.cols["width"].append(st.width.astype(np.float32))
        self.cols["vclass"].append(st.vclass.astype(str))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: (np.concatenate(v) if v else np.zeros(0, np.float32)) for k, v in self.cols.items()}


def clip_summary(clip: Any) -> tuple[int, float, float, float]:
    """(agents, median speed of the moving vehicles [m/s], median lane speed limit [m/s], target
    mean speed [m/s]) of a clip. Moving: a vehicle that exceeds 0.5 m/s at some step (vehicles
    stopped all clip long, at a red light or parked, are left out); median over their mean speeds."""
    tr = clip.tracks
    speed = np.hypot(tr.vx, tr.vy)
    valid = tr.valid
    veh = tr.object_type == ObjectType.VEHICLE
    mean = np.where(valid.any(axis=1), np.sum(speed * valid, axis=1) / np.maximum(valid.sum(axis=1), 1), 0.0)
    moving = veh & valid.any(axis=1) & (np.where(valid, speed, 0.0).max(axis=1) > 0.5)
    med = float(np.median(mean[moving])) if moving.any() else 0.0
    limits = clip.road_map.lanes.speed_limit
    limit = float(np.median(limits)) if len(limits) else float("nan")
    return tr.num_agents, med, limit, float(mean[clip.sdc_index])


def clip_vru_seconds(clip: Any) -> tuple[float, float]:
    """([s] pedestrian, [s] cyclist) track time in a clip: valid steps times the step (0.1 s)."""
    tr = clip.tracks
    dt = float(np.median(np.diff(clip.timestamps))) if clip.num_steps > 1 else 0.0
    steps = tr.valid.sum(axis=1)
    return (float(steps[tr.object_type == ObjectType.PEDESTRIAN].sum() * dt),
            float(steps[tr.object_type == ObjectType.CYCLIST].sum() * dt))
