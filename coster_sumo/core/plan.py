"""The adversary's plan: a 2 Hz trajectory ending in the collision snapshot, densified for SUMO.

The rollout produces knots at 2 Hz from ``t_start`` to ``t_col`` (the last knot is the snapshot
state, exactly). SUMO steps at 0.1 s, so the controller needs the state at every step:

- position: cubic spline through the knots in time, clamped at ``t_col`` to the snapshot velocity
  (so the adversary arrives at contact with the speed and direction the snapshot says) and natural
  at the start; the knots themselves are hit exactly;
- heading: the knots' headings, unwrapped, interpolated with a shape-preserving (PCHIP) spline, so
  turning never overshoots;
- after ``t_col`` (no knots): on along the road at the final speed, along ``road`` (the lane it is
  on, :mod:`coster_sumo.geometry.road_follow`); where the plan has no road, constant velocity along the final
  heading. The controller stops following the plan at the first contact, and hands the adversary
  to SUMO's driver :data:`HORIZON_AFTER_TCOL_S` after t_col (see :mod:`coster_sumo.sim.inject`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator

from coster_sumo.core.snapshot import AgentState
from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import write_json

# [s] after t_col: how long an escape must stay clear (the labels' horizon, docs/method.md step 8),
# and when SUMO's driver takes over an adversary that missed
HORIZON_AFTER_TCOL_S = 3.0
# what the position and heading splines are built from (:meth:`AdversaryPlan.replaced`)
_SPLINE_FIELDS = frozenset({"times", "x", "y", "yaw", "final_speed"})


def sim_time_of(t: float, step_length: float) -> float:
    """The simulation step nearest to ``t`` [s]: where SUMO's fixed step puts a log time.

    A converted WOMD scene's log times jitter around SUMO's grid by microseconds (some scenes by
    up to a few milliseconds); the adversary reaches the snapshot state at this step.
    """
    return round(round(t / step_length) * step_length, 9)


@dataclass(frozen=True)
class AdversaryPlan:
    """Knots of the adversary trajectory and its size.

    Attributes:
        times: (num_knots,) float64 [s] simulation times, increasing; the last is t_col.
        x, y: (num_knots,) float64 [m] box centre.
        yaw: (num_knots,) float64 [rad] CCW from +x.
        final_speed: [m/s] speed at t_col (the snapshot's).
        length, width: [m].
        vehicle_id: the SUMO id used when it is injected.
        road: (n, 2) [m] or None: the path it drives after t_col, from its centre at t_col
            (:func:`coster_sumo.geometry.road_follow.road_path`); None: straight on along its final heading.
        vclass: SUMO's vehicle class it is injected as: ``passenger`` (a vehicle adversary),
            ``pedestrian`` or ``bicycle`` (:mod:`coster_sumo.method.vru`).
    """

    times: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    final_speed: float
    length: float
    width: float
    vehicle_id: str = "adversary"
    road: np.ndarray | None = None
    vclass: str = "passenger"

    @property
    def t_start(self) -> float:
        return float(self.times[0])

    @property
    def t_col(self) -> float:
        return float(self.times[-1])

    @classmethod
    def from_knots(cls, times: np.ndarray, xy_yaw: np.ndarray, snapshot_state: AgentState,
                   vehicle_id: str = "adversary", vclass: str = "passenger") -> AdversaryPlan:
        """Build from (num_knots, 3) x, y, yaw; the last knot is replaced by the snapshot exactly."""
        k = np.array(xy_yaw, dtype=np.float64, copy=True)
        k[-1] = (snapshot_state.x, snapshot_state.y, snapshot_state.yaw)
        return cls(times=np.asarray(times, np.float64), x=k[:, 0], y=k[:, 1], yaw=k[:, 2],
                   final_speed=float(snapshot_state.speed), length=float(snapshot_state.length),
                   width=float(snapshot_state.width), vehicle_id=vehicle_id, vclass=vclass)

    def replaced(self, **changes: object) -> AdversaryPlan:
        """``dataclasses.replace(self, **changes)`` that keeps the splines already built where the
        knots and the final speed stay (a new id, a road after t_col): the same numbers, built once."""
        new = dataclasses.replace(self, **changes)  # type: ignore[arg-type]
        if "_splines" in self.__dict__ and not _SPLINE_FIELDS & changes.keys():
            new.__dict__["_splines"] = self.__dict__["_splines"]  # a cached_property's own slot
        return new

    @functools.cached_property
    def _splines(self) -> tuple[CubicSpline, CubicSpline, PchipInterpolator] | None:
        """x(t), y(t) clamped to the final velocity, yaw(t) shape-preserving; built once per plan."""
        if len(self.times) < 2:
            return None
        fin_v = self.final_speed * np.array([np.cos(self.yaw[-1]), np.sin(self.yaw[-1])])
        sx = CubicSpline(self.times, self.x, bc_type=((2, 0.0), (1, float(fin_v[0]))))
        sy = CubicSpline(self.times, self.y, bc_type=((2, 0.0), (1, float(fin_v[1]))))
        return sx, sy, PchipInterpolator(self.times, np.unwrap(self.yaw))

    def sample(self, t: np.ndarray, lead: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """State at times ``t`` (T,) [s]: centre x, y [m], yaw [rad], speed [m/s].

        Up to ``lead`` [s] before ``t_start`` the trajectory is continued backwards along its first
        piece (the simulation step nearest to a first knot that lies a few milliseconds after SUMO's
        grid comes just before it); earlier the values are those at ``t_start - lead`` (callers do
        not drive the vehicle then). After ``t_col`` the adversary continues at constant velocity.
        """
        t = np.asarray(t, np.float64)
        x = np.empty_like(t)
        y = np.empty_like(t)
        yaw = np.empty_like(t)
        speed = np.empty_like(t)
        fin_v = self.final_speed * np.array([np.cos(self.yaw[-1]), np.sin(self.yaw[-1])])
        inside = t <= self.t_col
        tc = np.clip(t[inside], self.t_start - max(lead, 0.0), self.t_col)
        splines = self._splines
        if splines is not None:
            sx, sy, syaw = splines
            x[inside], y[inside] = sx(tc), sy(tc)
            speed[inside] = np.hypot(sx(tc, 1), sy(tc, 1))
            yaw[inside] = syaw(tc)
        else:
            x[inside], y[inside], yaw[inside] = self.x[0], self.y[0], self.yaw[0]
            speed[inside] = self.final_speed
        after = ~inside
        dt = t[after] - self.t_col
        if self.road is not None and len(self.road) >= 2:
            x[after], y[after], yaw[after] = _along(self.road, self.final_speed * dt)
        else:
            x[after] = self.x[-1] + fin_v[0] * dt
            y[after] = self.y[-1] + fin_v[1] * dt
            yaw[after] = self.yaw[-1]
        speed[after] = self.final_speed
        return x, y, (yaw + np.pi) % (2 * np.pi) - np.pi, speed

    def to_dict(self) -> dict:
        return {"vehicle_id": self.vehicle_id, "length": self.length, "width": self.width,
                "final_speed": self.final_speed, "times": self.times.tolist(), "x": self.x.tolist(),
                "y": self.y.tolist(), "yaw": self.yaw.tolist(),
                **({"road": np.round(self.road, 3).tolist()} if self.road is not None else {}),
                **({"vclass": self.vclass} if self.vclass != "passenger" else {})}

    @classmethod
    def from_dict(cls, d: dict) -> AdversaryPlan:
        return cls(times=np.asarray(d["times"], float), x=np.asarray(d["x"], float),
                   y=np.asarray(d["y"], float), yaw=np.asarray(d["yaw"], float),
                   final_speed=float(d["final_speed"]), length=float(d["length"]),
                   width=float(d["width"]), vehicle_id=str(d.get("vehicle_id", "adversary")),
                   road=np.asarray(d["road"], float).reshape(-1, 2) if d.get("road") is not None else None,
                   vclass=str(d.get("vclass", "passenger")))

    def save(self, path: str | Path) -> Path:
        return write_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> AdversaryPlan:
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{path}: not an adversary plan ({exc})") from None


def _along(road: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre x, y [m] and heading [rad] at arc lengths ``s`` [m] along ``road`` (straight on past
    its end); the heading from the points 0.5 m either side (no jumps at the polyline's vertices)."""
    seg = np.hypot(*np.diff(road, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    end_dir = road[-1] - road[-2]
    end_dir = end_dir / max(float(np.hypot(*end_dir)), 1e-9)

    def at(q: np.ndarray) -> np.ndarray:
        inside = np.stack([np.interp(q, cum, road[:, 0]), np.interp(q, cum, road[:, 1])], -1)
        beyond = np.maximum(q - cum[-1], 0.0)[:, None]
        return inside + beyond * end_dir

    p = at(s)
    ahead, behind = at(s + 0.5), at(np.maximum(s - 0.5, 0.0))
    d = ahead - behind
    return p[:, 0], p[:, 1], np.arctan2(d[:, 1], d[:, 0])
