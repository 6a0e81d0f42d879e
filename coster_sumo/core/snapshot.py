"""Agent states and the collision snapshot: where and when the adversary touches the target."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import Tracks
from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import write_json


@dataclass(frozen=True, slots=True)
class AgentState:
    """One agent's state in our frame.

    Attributes:
        x, y: [m] box centre. yaw: [rad] CCW from +x. speed: [m/s] along yaw.
        length, width: [m].
    """

    x: float
    y: float
    yaw: float
    speed: float
    length: float
    width: float

    @property
    def velocity(self) -> np.ndarray:
        """(2,) [m/s]."""
        return self.speed * np.array([np.cos(self.yaw), np.sin(self.yaw)])

    @classmethod
    def from_tracks(cls, tracks: Tracks, agent: int, step: int) -> AgentState:
        return cls(x=float(tracks.x[agent, step]), y=float(tracks.y[agent, step]),
                   yaw=float(tracks.heading[agent, step]),
                   speed=float(np.hypot(tracks.vx[agent, step], tracks.vy[agent, step])),
                   length=float(tracks.length[agent, step]), width=float(tracks.width[agent, step]))


def _nan_to_none(values: Sequence[float]) -> list[float | None]:
    return [None if not np.isfinite(v) else float(v) for v in values]


@dataclass(frozen=True, slots=True)
class CollisionSnapshot:
    """Where and when the adversary touches the target (docs/method.md step 4).

    Attributes:
        scenario_id: the scene's id.
        target_id: the target's track id.
        t_index: the collision step in the 2 Hz scene.
        time: [s] scene time of that step.
        target: the target's state at ``time`` (from the scene).
        adversary: the adversary's state at ``time`` (in contact with the target).
        region_id: index of the prior region the placement came from (-1 for the random init).
        presence_prob: predicted presence probability of that region (nan when not from the prior).
        position_logprob: log-probability of the chosen position bin (nan when not from the prior).
        signed_distance: [m] box signed distance adversary-target (>= 0 and ~0 at contact).
        entropy: (num_2hz_steps,) entropy curve of the mean velocity distribution (nan = excluded).
        collision_time_method: "entropy" | "last" | "random" | "fixed".
        init_method: "snapshot" | "random".
        seed: the seed that produced it.
        adversary_class: ``vehicle``, ``pedestrian`` or ``cyclist`` (``--adversary``).
    """

    scenario_id: str
    target_id: str
    t_index: int
    time: float
    target: AgentState
    adversary: AgentState
    region_id: int = -1
    presence_prob: float = float("nan")
    position_logprob: float = float("nan")
    signed_distance: float = float("nan")
    entropy: tuple[float, ...] = ()
    collision_time_method: str = "entropy"
    init_method: str = "snapshot"
    seed: int = 0
    adversary_class: str = "vehicle"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        for k in ("presence_prob", "position_logprob", "signed_distance"):
            d[k] = _nan_to_none([d[k]])[0]
        d["entropy"] = _nan_to_none(self.entropy)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> CollisionSnapshot:
        d = dict(d)
        for k in ("presence_prob", "position_logprob", "signed_distance"):
            d[k] = float("nan") if d.get(k) is None else float(d[k])
        d["entropy"] = tuple(float("nan") if v is None else float(v) for v in d.get("entropy", ()))
        d["target"] = AgentState(**d["target"])
        d["adversary"] = AgentState(**d["adversary"])
        return cls(**d)

    def save(self, path: str | Path) -> Path:
        """Write JSON atomically. Floats are written with repr precision, so loading is lossless."""
        return write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> CollisionSnapshot:
        path = Path(path)
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{path}: not a collision snapshot ({exc})") from None
