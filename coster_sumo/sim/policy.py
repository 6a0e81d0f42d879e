"""A trained policy as a planner (``--planner policy:PATH``) for ``run``, ``regress`` and the API.

The policy (a stable-baselines3 ``policy.zip`` from ``coster-sumo policy train``) drives the target
exactly as in ``coster_sumo/Scenario-v0``: the same observation, the same action and kinematics
(:class:`coster_sumo.sim.driver.Driver`). Its route is the target's nominal trajectory. At takeover
(the first :meth:`before_step` with the target present, when the adversary's plan starts) the
target's pose and speed are read from SUMO and projected onto the route; from then on the planner
places the target with moveToXY every step and asks the policy for an action every 0.2 s. The
policy drives as long as its training episodes ran: to the route's end (the environment's
``completed``), and in a variant's pass to :data:`~coster_sumo.gym.build.AVOIDANCE_TAIL_S` after
t_col (a variant's episode ends there). Then SUMO's driver takes the target on along its SUMO route,
as it takes a replayed target where its recording ends and a missed adversary after the labels'
horizon: the policy never learnt to drive past them (the rest of a long route, say). The
observation is the one the policy was trained on, told by its size (``default``, ``avoidance`` or
``lidar``: :mod:`coster_sumo.gym.observe`); its time left runs to where the policy hands over (the
environment's runs to its episode's end).

Needs the nominal trajectory of the target, which ``run`` and ``regress`` give planners on SUMO
configurations (on converted WOMD scenes the built-in planners only).
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import project_points
from coster_sumo.infra.extras import require
from coster_sumo.sim.driver import STEP_S, Driver, Route

if TYPE_CHECKING:
    from coster_sumo.core.plan import AdversaryPlan
    from coster_sumo.sim.session import SumoSession

CONTROL_PERIOD_S = 0.2  # [s] as Scenario-v0's default


class NominalPath(Protocol):
    """The target's nominal trajectory as the policy reads it (a
    :class:`coster_sumo.sim.planners.ReplayPlanner` is one): per step of the nominal pass."""

    times: np.ndarray  # (T,) [s]
    x: np.ndarray  # (T,) [m] box centre
    y: np.ndarray  # (T,) [m]
    yaw: np.ndarray  # (T,) [rad]
    valid: np.ndarray  # (T,) bool


class PolicyPlanner(Driver):
    """Drives the target with a trained policy (see the module docstring).

    Args:
        path: the policy's ``.zip`` (stable-baselines3 PPO or TD3).
        nominal: the target's nominal trajectory (its route); None where the caller has none
            (``run`` asks a planner for its files before the nominal pass): then it cannot drive.
    """

    def __init__(self, path: str | Path, nominal: NominalPath | None) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"planner policy:{path}: no such policy file")
        self.name = f"policy:{self.path.name}"
        self.nominal = nominal
        self.substeps = max(1, int(round(CONTROL_PERIOD_S / STEP_S)))
        self._model: Any = None
        self.observation = "default"  # which observation the policy reads (its size tells, at setup)
        self._taken = False
        self._released = False
        self.until = math.inf  # [s] SUMO's driver takes the target after this (set_plan)
        self._count = 0
        self._d_target = 0.0

    def additional_files(self, workdir: Path) -> list[Path]:
        return []

    def set_plan(self, plan: AdversaryPlan) -> None:
        """Drive up to the end of the variant's episode (t_col + the episodes' tail)."""
        from coster_sumo.gym.hard import AVOIDANCE_TAIL_S

        self.until = float(plan.t_col) + AVOIDANCE_TAIL_S

    def setup(self, session: SumoSession, target_id: str) -> None:
        if self._model is None:
            require("rl", f"planner policy:{self.path}")
            self._model = load_model(self.path)
            self.observation = observation_of(self._model, self.path)
        self._taken = self._released = False
        self.target_id = target_id
        self.api = session.api

    def _take_over(self, session: SumoSession, target_id: str) -> None:
        n = self.nominal
        if n is None:
            raise InputError("planner policy:PATH needs the target's nominal trajectory, which converted WOMD "
                             "scenes do not give planners (use it on SUMO configurations)")
        ok = n.valid & (n.times >= session.time - 1e-6)
        self.route = Route(np.stack([n.x[ok], n.y[ok]], -1), float(n.yaw[ok][0]) if ok.any() else 0.0)
        st = session.vehicle_states([target_id])
        x, y, yaw, v = float(st.x[0]), float(st.y[0]), float(st.yaw[0]), float(st.speed[0])
        s, d, _ = project_points(np.array([x, y]), self.route.points)
        self.s, self.d, self.d_dot, self.v, self.accel = float(s), float(d), 0.0, v, 0.0
        self.length, self.width = float(st.length[0]), float(st.width[0])
        _, _, h = self.route.pose(self.s)
        del yaw, h  # the heading follows from the route and the lateral speed, as in the environment
        self._taken = True
        self._count = 0

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if not present or self._released:
            return
        if not self._taken:
            self._take_over(session, target_id)
        elif self.route_completed() or t_next > self.until + 1e-6:
            self._release(session, target_id)
            return
        if self._count % self.substeps == 0:
            self.states = session.vehicle_states()
            action = self._model.predict(self._observation(session.time), deterministic=True)[0]
            self._d_target = self._command(action)
        self._count += 1
        self._kinematic_step(self._d_target)
        x, y, yaw = self._ego_pose()
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            return
        session.move_to_xy(target_id, x, y, yaw, self.length, speed=self.v)


    def _release(self, session: SumoSession, target_id: str) -> None:
        """Hand the target to SUMO's driver at its route's end: on along its own SUMO route where it
        still stands on it, else routed to the edge where the nominal trajectory ended."""
        veh = session.api.vehicle
        ends: list[tuple[float, float, float, float]] = []
        if veh.getRouteIndex(target_id) < 0 or veh.getRoadID(target_id) not in veh.getRoute(target_id):
            n = self.nominal
            if n is not None and n.valid.any():
                last = int(np.flatnonzero(n.valid)[-1])
                ends = [(float(n.x[last]), float(n.y[last]), float(n.yaw[last]), self.length)]
        session.release_vehicle(target_id, ends)
        self._released = True

    def _observation(self, now: float) -> np.ndarray:
        if self.observation == "default":
            return self._observe()
        from coster_sumo.gym.observe import observe

        n = self.nominal
        end = float(n.times[n.valid][-1]) if n is not None and n.valid.any() else now
        # the episode the policy trained on ends at t_col + the tail in a variant: so does its time left
        # here (a whole life's would read as 20 s or more, which no 9.1 s training clip shows)
        return observe(self, self.observation, min(end, self.until) - now)


def observation_of(model: Any, path: Path) -> str:
    """The observation kind whose size is the policy's input (InputError: none has it)."""
    from coster_sumo.gym.observe import OBSERVATIONS

    size = int(np.prod(model.observation_space.shape))
    for kind, n in OBSERVATIONS.items():
        if n == size:
            return kind
    raise InputError(f"planner policy:{path}: its observation has {size} numbers, none of "
                     + ", ".join(f"{k} ({n})" for k, n in OBSERVATIONS.items()))


def make_policy_planner(arg: str | None, nominal: NominalPath | None) -> PolicyPlanner:
    """``policy:PATH`` (the :data:`coster_sumo.sim.planners.PLANNERS` entry)."""
    if not arg:
        raise InputError("planner policy:PATH needs the path of a policy.zip")
    return PolicyPlanner(arg, nominal)  # without the nominal trajectory it refuses at takeover


def learner_of(path: str | Path) -> str:
    """The learner that saved the policy ``path`` (an SB3 zip): ``td3`` or ``ppo``."""
    with zipfile.ZipFile(path) as z:
        data = json.loads(z.read("data").decode())
    module = str(data.get("policy_class", {}).get("__module__", ""))
    return "td3" if ".td3." in module else "ppo"


def load_model(path: str | Path, env: Any = None) -> Any:
    """The policy (or checkpoint) ``path``, as the learner that saved it, on ``env`` when given."""
    if learner_of(path) == "td3":
        from stable_baselines3 import TD3

        return TD3.load(path, env=env, device="cpu")
    from stable_baselines3 import PPO

    return PPO.load(path, env=env, device="cpu")
