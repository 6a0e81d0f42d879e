"""Edits of a recorded scene for a scenario set: one more agent, a window of its steps.

A variant of a scenario set is its nominal pass with the adversary (a generated plan or a
hand-specified adversity) appended as one more agent, cropped to the episode's window
(:mod:`coster_sumo.gym.build`, :mod:`coster_sumo.gym.hard`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene, Tracks

Poses = tuple[np.ndarray, np.ndarray, np.ndarray]  # x [m], y [m], heading [rad], each (T,)


def append_agent(scene: Scene, agent_id: str, pose: Poses, speed: np.ndarray, valid: np.ndarray,
                 size: tuple[float, float], object_type: int = ObjectType.VEHICLE) -> Scene:
    """``scene`` with one more agent of ``size`` (length, width) [m] and WOMD ``object_type`` (the
    replay adds it with that type's vType: a pedestrian as a vehicle of class pedestrian); ``pose``,
    ``speed`` [m/s] and ``valid`` (T,) on the scene's timestamps."""
    x, y, yaw = pose
    tr = scene.tracks
    T = tr.num_steps

    def row(a: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.concatenate([a, v.reshape(1, T).astype(a.dtype)], axis=0)

    tracks = Tracks(ids=np.array([*tr.ids.tolist(), agent_id], dtype=str),  # widened to the longest id
                    object_type=np.append(tr.object_type, int(object_type)).astype(tr.object_type.dtype),
                    x=row(tr.x, x), y=row(tr.y, y), heading=row(tr.heading, yaw),
                    vx=row(tr.vx, speed * np.cos(yaw)), vy=row(tr.vy, speed * np.sin(yaw)),
                    length=row(tr.length, np.full(T, size[0])), width=row(tr.width, np.full(T, size[1])),
                    valid=row(tr.valid, valid))
    return dataclasses.replace(scene, tracks=tracks)


def crop_steps(scene: Scene, t0: float, t1: float) -> Scene:
    """The scene between SUMO times ``t0`` and ``t1`` [s] (both kept), agents never valid there dropped."""
    ts = scene.timestamps
    steps = np.flatnonzero((ts >= t0 - 1e-6) & (ts <= t1 + 1e-6))
    tracks = scene.tracks.select(steps=steps)
    keep = np.flatnonzero(tracks.valid.any(axis=1))
    tracks = tracks.select(agents=keep)
    signals = scene.signals
    signals = dataclasses.replace(signals, state=signals.state[steps] if signals.state.ndim == 2 else signals.state)
    return dataclasses.replace(scene, timestamps=ts[steps], tracks=tracks, signals=signals, current_time_index=0,
                               sdc_index=-1)
