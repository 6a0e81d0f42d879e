"""Walking persons (SUMO's ``person`` domain: not vehicles) read alongside a recording.

:func:`coster_sumo.sim.record.record` reads vehicles only. A :class:`PersonReader` is called after
every recorded step (chain it into ``record``'s ``after_step``) and reads every person in the
network then: one id list and three getters per person (position, angle, speed); length and width
once per person. :meth:`PersonReader.merge` appends them to the recorded scene as agents of type
``PEDESTRIAN`` (after the vehicles, by first appearance) and starts afresh for the next recording.
A run without pedestrians never makes one, so it pays nothing.

Frames as for vehicles (:mod:`coster_sumo.geometry.frames`): SUMO gives a walking person's front
and its walking direction; the track holds the box centre and the yaw.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene, Tracks
from coster_sumo.errors import InputError
from coster_sumo.geometry import frames


class PersonReader:
    """Every person's state at every step it is called for (see the module docstring).

    Attributes:
        times: [s] the simulation time of each call since the last :meth:`merge`.
        rows: per call, (person row indices (n,) int64, x (n,), y (n,), yaw (n,), speed (n,)) in our frame.
    """

    def __init__(self) -> None:
        self.times: list[float] = []
        self.rows: list[tuple[np.ndarray, ...]] = []
        self.index: dict[str, int] = {}  # person id -> row, by first appearance (since the last merge)
        self._size: dict[str, tuple[float, float]] = {}  # person id -> (length, width) [m]

    def __call__(self, session: Any, _states: Any = None) -> None:
        """Read the persons now in the network (``after_step``-shaped; never asks to stop)."""
        person = session.api.person
        ids = list(person.getIDList())
        self.times.append(session.time)
        if not ids:
            self.rows.append(())
            return
        size, index = self._size, self.index
        for p in ids:
            if p not in size:
                size[p] = (person.getLength(p), person.getWidth(p))
            if p not in index:
                index[p] = len(index)
        get_xy, get_angle, get_speed = person.getPosition, person.getAngle, person.getSpeed
        xy = np.array([get_xy(p) for p in ids], np.float64).reshape(-1, 2)  # (n, 2) front
        angle = np.array([get_angle(p) for p in ids], np.float64)
        speed = np.array([get_speed(p) for p in ids], np.float64)
        length = np.array([size[p][0] for p in ids], np.float64)
        cx, cy, yaw = frames.from_sumo(xy[:, 0], xy[:, 1], angle, length)
        rows = np.fromiter(map(index.__getitem__, ids), np.int64, len(ids))
        self.rows.append((rows, cx, cy, yaw, speed))

    def tracks(self) -> Tracks:
        """(persons, calls) tracks of the calls since the last :meth:`merge`, type ``PEDESTRIAN``."""
        num, steps = len(self.index), len(self.times)
        f = {k: np.zeros((num, steps), np.float64) for k in ("x", "y", "heading", "vx", "vy", "length", "width")}
        valid = np.zeros((num, steps), bool)
        ids = list(self.index)
        sizes = np.array([self._size[p] for p in ids], np.float64).reshape(-1, 2)  # (num, 2)
        for s, row in enumerate(self.rows):
            if not row:
                continue
            a, cx, cy, yaw, speed = row
            f["x"][a, s], f["y"][a, s], f["heading"][a, s] = cx, cy, yaw
            f["vx"][a, s], f["vy"][a, s] = speed * np.cos(yaw), speed * np.sin(yaw)
            f["length"][a, s], f["width"][a, s] = sizes[a, 0], sizes[a, 1]
            valid[a, s] = True
        return Tracks(ids=np.array(ids, dtype=str) if ids else np.zeros(0, dtype=str),
                      object_type=np.full(num, int(ObjectType.PEDESTRIAN), np.int8), valid=valid, **f)

    def merge(self, scene: Scene) -> Scene:
        """``scene`` with the persons read since the last merge appended to its agents; the reader
        is then empty. The reader must have been called once per recorded step of ``scene``."""
        if len(self.times) != scene.num_steps or (
                scene.num_steps and not np.allclose(self.times, scene.timestamps, atol=1e-6)):
            raise InputError(f"{scene.scenario_id}: persons read at {len(self.times)} steps, "
                             f"the scene has {scene.num_steps}")
        persons = self.tracks()
        self.times, self.rows, self.index = [], [], {}
        if persons.num_agents == 0:
            return scene
        tr = scene.tracks
        clash = set(tr.ids.tolist()) & set(persons.ids.tolist())
        if clash:
            raise InputError(f"{scene.scenario_id}: persons and vehicles share ids: {sorted(clash)[:3]}")
        both = {k: np.concatenate([getattr(tr, k), getattr(persons, k)])
                for k in ("ids", "object_type", "x", "y", "heading", "vx", "vy", "length", "width", "valid")}
        return dataclasses.replace(scene, tracks=Tracks(**both)).validate()
