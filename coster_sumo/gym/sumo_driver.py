"""The reference row "SUMO's driver": SUMO's own driver model drives the target of every episode.

``coster-sumo policy eval sumo SET`` (and :func:`coster_sumo.gym.train.evaluate` with ``policy="sumo"``)
drives the same episodes as a policy, with the target handed to SUMO: it enters as in every
episode (its first pose and speed, by moveToXY), and after that first step SUMO's driver model
drives it (the set's vType, Krauss: its speed mode, lane changes and speed factor SUMO's own),
routed to the edge under the end of its nominal route. Actions are ignored. Each step reads where
SUMO put it; its arc length and offset along the nominal route (route completion, the observation)
are its projection onto that route near where it was.

A driver model sees only vehicles that are in SUMO. With ``traffic="log"`` the others are then put
into SUMO and moved along their logs (the environment's ``traffic="sumo"``, the same episodes as
``log``: ``tests/gym_env/test_gym.py``); with ``traffic="reactive"`` the logged agents around the
target are put into SUMO as they come within :data:`~coster_sumo.sim.reactive.SHADOW_RADIUS_M`,
as around any vehicle that reacts. SUMO drives a vehicle on its lanes only: a target that starts
off them (inside a junction, where its lanes are internal, or more than
:data:`~coster_sumo.sim.reactive.LANE_MATCH_M` from a lane) keeps its first speed until a normal
lane lies under its front, and is handed over then; :attr:`SumoDriverEnv.kept_on_path` counts the
episodes that ended before that.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from coster_sumo.gym.env import ScenarioEnv
from coster_sumo.gym.stepping import sumo_box
from coster_sumo.sim.corridor import PreparedPolyline
from coster_sumo.sim.reactive import LANE_MATCH_M

BACK_M = 5.0  # [m] the projection looks this far behind the last arc length
AHEAD_M = 60.0  # [m] and this far ahead (6 s at 10 m/s per 0.1 s step is far more than a step goes)


class SumoDriverEnv(ScenarioEnv):
    """:class:`~coster_sumo.gym.env.ScenarioEnv` with SUMO's driver model driving the target (module docstring)."""

    def __init__(self, scenarios: Any, traffic: str = "log", **kwargs: Any) -> None:
        super().__init__(scenarios, traffic="sumo" if traffic == "log" else traffic, **kwargs)
        self.kept_on_path = 0  # episodes that ended before SUMO could drive (no lane under the target)

    def close(self) -> None:
        if self.entry is not None and not self.sumo_drives:
            self.kept_on_path += 1
            self.entry = None
        super().close()

    def _start(self, entry: Any) -> None:
        if self.entry is not None and not self.sumo_drives:
            self.kept_on_path += 1  # the last episode ended before SUMO could take it
        self.sumo_drives = False
        super()._start(entry)  # its first step puts the target in at its first pose
        self._route_line = PreparedPolyline(self.route.points)
        self._hand_over()

    def _hand_over(self) -> None:
        """Release the target to SUMO where a normal lane lies under it (else it goes on at constant
        speed and this is tried again after the next step)."""
        if not self._on_a_lane():
            return
        poses = []  # where its route ends, then a little before (the first one SUMO can route to)
        for back in (0.0, 5.0, 10.0, 20.0, 40.0):
            x, y, heading = self.route.pose(max(self.route.length_m - back, 0.0))
            poses.append((x, y, heading, self.length))
        self._session.release_vehicle(self.target_id, poses)
        self.sumo_drives = True

    def _on_a_lane(self) -> bool:
        """Whether a normal lane lies under the target's front bumper, within
        :data:`~coster_sumo.sim.reactive.LANE_MATCH_M`."""
        x, y, yaw = self._ego_pose()
        fx, fy = x + 0.5 * self.length * math.cos(yaw), y + 0.5 * self.length * math.sin(yaw)
        sim = self._session.api.simulation
        try:
            edge, pos, lane = sim.convertRoad(fx, fy, False, "passenger")
            if not edge or str(edge).startswith(":"):
                return False
            lx, ly = sim.convert2D(str(edge), float(pos), int(lane))
        except Exception:  # no lane for its class nearby
            return False
        return math.hypot(lx - fx, ly - fy) <= LANE_MATCH_M

    def _command(self, action: np.ndarray) -> float:
        if not self.sumo_drives:
            return super()._command(np.zeros(2, np.float32))
        self.accel = 0.0
        return self.d

    def _kinematic_step(self, d_target: float) -> None:
        if not self.sumo_drives:
            super()._kinematic_step(d_target)

    def _advance(self) -> None:
        if self.sumo_drives and self._reactive is not None:
            k = self._replayer.step_at(self._now())
            if k is not None:
                x, y, _ = self._ego_pose()
                self._reactive.see_around(np.array([[x, y]]), k)
        super()._advance()
        if self.sumo_drives:
            self._follow_sumo()
        elif self._added:
            self._hand_over()

    def _follow_sumo(self) -> None:
        """The target's arc length, offset and speed from where SUMO has it (gone: it arrived)."""
        box = sumo_box(self._session.api, self.target_id)
        if box is None:
            self.s = self.route.length_m
            return
        line = self._route_line
        cum = line.cum
        lo = max(int(np.searchsorted(cum, self.s - BACK_M)) - 1, 0)
        hi = min(int(np.searchsorted(cum, self.s + AHEAD_M)) + 1, len(line.points) - 1)
        near = PreparedPolyline(line.points[lo:hi + 1]) if hi > lo else line
        arc, lateral, _ = near.project(np.array([box[0], box[1]]))
        self.s = float(cum[lo] + arc) if hi > lo else float(arc)
        self.d = float(lateral)
        self.v = float(self._session.api.vehicle.getSpeed(self.target_id))
