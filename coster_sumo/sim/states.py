"""Vehicle states read from SUMO at one step, in our frame (box centre, yaw CCW from +x)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True)
class VehicleStates:
    """State of every vehicle in the simulation at one step, in our frame.

    Attributes:
        ids: (N,) str SUMO vehicle ids.
        x: (N,) float64 [m] box centre.
        y: (N,) float64 [m] box centre.
        yaw: (N,) float64 [rad] counter-clockwise from +x, in (-pi, pi].
        speed: (N,) float64 [m/s] as SUMO reports it (longitudinal).
        length: (N,) float64 [m].
        width: (N,) float64 [m].
        vclass: (N,) str SUMO vehicle class ("passenger", "bicycle", ...).
        type_id: (N,) str SUMO vType id.
        names: the same ids as a Python list when whoever built the states had one (the session
            does), else None; read them with :meth:`id_list`.
    """

    ids: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    length: np.ndarray
    width: np.ndarray
    vclass: np.ndarray
    type_id: np.ndarray
    names: list[str] | None = field(default=None, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def vx(self) -> np.ndarray:
        """(N,) float64 [m/s] velocity along +x (speed along the heading)."""
        return self.speed * np.cos(self.yaw)

    @property
    def vy(self) -> np.ndarray:
        """(N,) float64 [m/s] velocity along +y."""
        return self.speed * np.sin(self.yaw)

    def id_list(self) -> list[str]:
        """The ids as a Python list (no conversion when :attr:`names` is set)."""
        return self.names if self.names is not None else self.ids.tolist()

    def index_of(self, veh_id: str) -> int:
        hits = np.flatnonzero(self.ids == veh_id)
        if len(hits) == 0:
            raise KeyError(veh_id)
        return int(hits[0])


def empty_states() -> VehicleStates:
    f = np.zeros(0, np.float64)
    s = np.zeros(0, dtype=str)
    return VehicleStates(ids=s, x=f, y=f, yaw=f, speed=f, length=f, width=f, vclass=s, type_id=s)


def concat_states(*parts: VehicleStates) -> VehicleStates:
    """The vehicles of ``parts``, in order, as one :class:`VehicleStates`."""
    parts = tuple(p for p in parts if len(p))
    if not parts:
        return empty_states()
    if len(parts) == 1:
        return parts[0]
    names = [n for p in parts for n in p.id_list()]
    return VehicleStates(**{f: np.concatenate([getattr(p, f) for p in parts])
                            for f in ("ids", "x", "y", "yaw", "speed", "length", "width", "vclass", "type_id")},
                         names=names)
