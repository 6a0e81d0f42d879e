"""Every conversion between our frame and SUMO's, in one place.

Ours: box **centre**, heading in **radians counter-clockwise from +x**.
SUMO (``getPosition``, ``moveToXY``, ``getAngle``): **front-bumper centre**, angle in **degrees
clockwise from north** (0 = +y, 90 = +x). All functions broadcast over numpy arrays.
"""

from __future__ import annotations

import math

import numpy as np

ArrayLike = np.ndarray | float


def yaw_to_sumo_angle(yaw_rad: ArrayLike) -> np.ndarray:
    """Heading [rad, CCW from +x] -> SUMO angle [deg, CW from north] in [0, 360)."""
    return np.mod(90.0 - np.degrees(yaw_rad), 360.0)


def sumo_angle_to_yaw(angle_deg: ArrayLike) -> np.ndarray:
    """SUMO angle [deg, CW from north] -> heading [rad, CCW from +x] in (-pi, pi]."""
    return wrap_angle(np.radians(90.0 - np.asarray(angle_deg, dtype=np.float64)))


def wrap_angle(a: ArrayLike) -> np.ndarray:
    """Wrap radians to (-pi, pi]."""
    a = np.asarray(a, dtype=np.float64)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def centre_to_front(x: ArrayLike, y: ArrayLike, yaw_rad: ArrayLike, length: ArrayLike
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Box centre -> front-bumper centre [m]."""
    half = 0.5 * np.asarray(length, dtype=np.float64)
    return x + half * np.cos(yaw_rad), y + half * np.sin(yaw_rad)


def front_to_centre(x: ArrayLike, y: ArrayLike, yaw_rad: ArrayLike, length: ArrayLike
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Front-bumper centre -> box centre [m]."""
    half = 0.5 * np.asarray(length, dtype=np.float64)
    return x - half * np.cos(yaw_rad), y - half * np.sin(yaw_rad)


def to_sumo(x: ArrayLike, y: ArrayLike, yaw_rad: ArrayLike, length: ArrayLike
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre x, centre y, yaw) -> (front x, front y, SUMO angle)."""
    fx, fy = centre_to_front(x, y, yaw_rad, length)
    return fx, fy, yaw_to_sumo_angle(yaw_rad)


def from_sumo(fx: ArrayLike, fy: ArrayLike, angle_deg: ArrayLike, length: ArrayLike
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(front x, front y, SUMO angle) -> (centre x, centre y, yaw)."""
    yaw = sumo_angle_to_yaw(angle_deg)
    cx, cy = front_to_centre(fx, fy, yaw, length)
    return cx, cy, yaw


def to_sumo_scalar(x: float, y: float, yaw_rad: float, length: float) -> tuple[float, float, float]:
    """:func:`to_sumo` of one pose in plain floats (the same operations, without numpy's per-call cost)."""
    half = 0.5 * length
    return x + half * math.cos(yaw_rad), y + half * math.sin(yaw_rad), (90.0 - math.degrees(yaw_rad)) % 360.0


def from_sumo_scalar(fx: float, fy: float, angle_deg: float, length: float) -> tuple[float, float, float]:
    """:func:`from_sumo` of one pose in plain floats (the same operations, without numpy's per-call cost)."""
    yaw = math.pi - (math.pi - math.radians(90.0 - angle_deg)) % (2.0 * math.pi)
    half = 0.5 * length
    return fx - half * math.cos(yaw), fy - half * math.sin(yaw), yaw


MPH_TO_MPS = 0.44704  # [m/s per mph]
