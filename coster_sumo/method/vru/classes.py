"""Adversary classes (``--adversary``) and the kinematic limits of the vulnerable ones.

The figures are literature values and SUMO's own defaults; docs/method.md ("Pedestrian and cyclist
adversaries") says where each comes from. A variant is kept only if its trajectory stays inside
its class's limits (:func:`within_limits`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coster_sumo.core.scene import ObjectType
from coster_sumo.core.spec import ADVERSARY_CHOICES
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_folder import object_type_of_vclass

VEHICLE = "vehicle"


@dataclass(frozen=True)
class VruClass:
    """One vulnerable road user class.

    Attributes:
        name: ``pedestrian`` or ``cyclist`` (the ``--adversary`` value).
        vclass: SUMO's vehicle class the adversary is injected with.
        base_type: SUMO's default vType of that class (its colour and shape in sumo-gui).
        length, width: [m] the box.
        walk_mean, walk_sd: [m/s] the usual-speed normal the snapshot's speed is drawn from ...
        walk_min, walk_max: [m/s] ... truncated to this range;
        fast_share: the share drawn instead uniformly in (``walk_max``, ``fast_max``) (running, racing).
        fast_max: [m/s] the class's speed limit (no variant is faster at any point).
        max_accel, max_decel: [m/s^2] longitudinal limits.
        max_yaw_rate: [rad/s] turning limit (a pedestrian turns on the spot: a large value).
        max_lateral_accel: [m/s^2] curvature * speed^2 limit (a bicycle leans; a pedestrian: None).
        min_turn_radius: [m] a bicycle's tightest turn (0: turns on the spot).
        area_band: [m] how far beyond the road surface the class may be (sidewalk / verge / shoulder).
    """

    name: str
    vclass: str
    base_type: str
    length: float
    width: float
    walk_mean: float
    walk_sd: float
    walk_min: float
    walk_max: float
    fast_share: float
    fast_max: float
    max_accel: float
    max_decel: float
    max_yaw_rate: float
    max_lateral_accel: float | None
    min_turn_radius: float
    area_band: float

    @property
    def object_type(self) -> ObjectType:
        """The WOMD object type the class's agents are recorded as (pedestrian, cyclist)."""
        return object_type_of_vclass(self.vclass)

    def draw_speed(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n,) [m/s] speeds from the class's distribution (module docstring of docs/method.md)."""
        usual = np.clip(rng.normal(self.walk_mean, self.walk_sd, n), self.walk_min, self.walk_max)
        fast = rng.uniform(self.walk_max, self.fast_max, n)
        return np.where(rng.random(n) < self.fast_share, fast, usual)


PEDESTRIAN = VruClass(
    name="pedestrian", vclass="pedestrian", base_type="DEFAULT_PEDTYPE", length=0.5, width=0.5,
    walk_mean=1.4, walk_sd=0.25, walk_min=0.8, walk_max=2.0, fast_share=0.2, fast_max=3.5,
    max_accel=2.0, max_decel=3.0, max_yaw_rate=np.pi, max_lateral_accel=None, min_turn_radius=0.0,
    area_band=3.0)
CYCLIST = VruClass(
    name="cyclist", vclass="bicycle", base_type="DEFAULT_BIKETYPE", length=1.8, width=0.65,
    walk_mean=5.5, walk_sd=1.2, walk_min=3.0, walk_max=7.5, fast_share=0.1, fast_max=10.0,
    max_accel=1.5, max_decel=3.5, max_yaw_rate=1.0, max_lateral_accel=3.0, min_turn_radius=3.0,
    area_band=1.0)
VRU_CLASSES: dict[str, VruClass] = {"pedestrian": PEDESTRIAN, "cyclist": CYCLIST}
CLASS_OF_VCLASS = {"passenger": VEHICLE, "pedestrian": "pedestrian", "bicycle": "cyclist"}


def check_adversary(choice: str) -> None:
    """``--adversary``: one of :data:`ADVERSARY_CHOICES` (one error line otherwise)."""
    if choice not in ADVERSARY_CHOICES:
        raise InputError(f"--adversary must be one of {', '.join(ADVERSARY_CHOICES)}, not {choice!r}")


def class_of_vclass(vclass: str) -> str:
    """The adversary class (vehicle / pedestrian / cyclist) of a plan's SUMO vehicle class."""
    return CLASS_OF_VCLASS.get(vclass, VEHICLE)


@dataclass(frozen=True)
class Kinematics:
    """Speeds and accelerations of trajectories sampled at ``dt``: (N, T) speed [m/s],
    (N, T-1) longitudinal acceleration [m/s^2], (N, T-1) yaw rate [rad/s]."""

    speed: np.ndarray
    accel: np.ndarray
    yaw_rate: np.ndarray

    @classmethod
    def of(cls, xy: np.ndarray, yaw: np.ndarray, dt: float) -> Kinematics:
        """From centres (N, T, 2) [m] and headings (N, T) [rad] at a fixed step ``dt`` [s]."""
        step = np.diff(xy, axis=1)  # (N, T-1, 2)
        seg = np.hypot(step[..., 0], step[..., 1]) / dt  # (N, T-1)
        speed = np.concatenate([seg[:, :1], 0.5 * (seg[:, 1:] + seg[:, :-1]), seg[:, -1:]], axis=1)
        dyaw = np.angle(np.exp(1j * np.diff(yaw, axis=1)))
        return cls(speed, np.diff(speed, axis=1) / dt, dyaw / dt)


SPEED_TOLERANCE = 0.05  # [m/s] rounding of finite differences at 2 Hz
ACCEL_TOLERANCE = 0.1  # [m/s^2]


def within_limits(cls: VruClass, kin: Kinematics) -> np.ndarray:
    """(N,) bool: every speed, acceleration and deceleration of ``kin`` is within the class's limits."""
    ok = np.all(kin.speed <= cls.fast_max + SPEED_TOLERANCE, axis=1)
    ok &= np.all(kin.accel <= cls.max_accel + ACCEL_TOLERANCE, axis=1)
    ok &= np.all(kin.accel >= -cls.max_decel - ACCEL_TOLERANCE, axis=1)
    return ok
