"""Planners: who drives the target during an injection pass.

A planner is any object with the three methods of :class:`Planner`; implement it in your own
module and pass ``--planner yourmodule:YourClass`` (the class is constructed without arguments).
The planner takes the target over when the adversary's plan starts (until then the target drives
as in the nominal pass, so the scene the adversary was planned on is the scene it meets): from that
step on the pass calls ``before_step`` every step with the time the step will reach, so a planner
that commands the target (``session.move_to_xy``, ``session.api.vehicle.setSpeed``...) does it for
that time.

Built-ins:
- ``replay``: the target follows its nominal trajectory exactly (moveToXY every step). With a
  replay target, contact happens at t_col by construction.
- ``sumo``: SUMO's own driver model keeps control of the target, so it may react to the adversary.
- ``policy:PATH``: a driving policy trained with ``coster-sumo policy train`` (``policy.zip``) drives
  the target as in the Gymnasium environment (:mod:`coster_sumo.sim.policy`).
- ``sumo:<model>``: the same with SUMO car-following model ``<model>`` (Krauss, IDM, EIDM, ACC,
  CACC, ...), set through a vType written to an additional file and given to the target when it
  departs (TraCI cannot change a type's car-following model at run time).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from coster_sumo.errors import InputError, not_found
from coster_sumo.sim.policy import make_policy_planner

if TYPE_CHECKING:
    from coster_sumo.core.plan import AdversaryPlan
    from coster_sumo.sim.session import SumoSession

CAR_FOLLOWING_MODELS = ("Krauss", "KraussPS", "KraussOrig1", "IDM", "IDMM", "EIDM", "ACC", "CACC", "W99",
                        "Wiedemann", "BKerner", "SmartSK", "Daniel1", "PWagner2009", "PWagner2010")


@runtime_checkable
class Planner(Protocol):
    """Drives the target vehicle of an injection pass."""

    name: str

    def additional_files(self, workdir: Path) -> list[Path]:
        """Files to add to SUMO's ``--additional-files`` before the session starts."""
        ...

    def setup(self, session: SumoSession, target_id: str) -> None:
        """Called once after the session has started."""
        ...

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        """Command the target for simulation time ``t_next``; ``present``: it is in the network."""
        ...


@runtime_checkable
class PlanAware(Protocol):
    """A planner that drives only part of the pass and needs the adversary's plan to know which
    (the policy planner: as long as its training episodes ran)."""

    def set_plan(self, plan: AdversaryPlan) -> None:
        """Called with the variant's plan before :meth:`Planner.setup`."""
        ...


class ReplayPlanner:
    """The target replays a recorded trajectory (10 Hz, our frame) with moveToXY.

    Args:
        times: (T,) [s] simulation times of the recording.
        x, y, yaw: (T,) centre [m] and heading [rad].
        speed: (T,) [m/s].
        valid: (T,) bool.
        length: [m] the target's length.
    """

    name = "replay"

    def __init__(self, times: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                 speed: np.ndarray, valid: np.ndarray, length: float) -> None:
        self.times = np.asarray(times, float)
        self.x, self.y, self.yaw, self.speed = x, y, yaw, speed
        self.valid = np.asarray(valid, bool)
        self.length = float(length)
        self.half_step = 0.5 * float(np.median(np.diff(self.times))) if len(self.times) > 1 else 0.05

    def additional_files(self, workdir: Path) -> list[Path]:
        return []

    def setup(self, session: SumoSession, target_id: str) -> None:
        pass

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if not present:
            return
        # nearest recorded step; WOMD timestamps are not exactly on SUMO's 0.1 s grid (ms jitter)
        k = min(max(int(np.searchsorted(self.times, t_next)), 1), len(self.times) - 1)  # scalars: no np.clip
        k = k - 1 if abs(self.times[k - 1] - t_next) <= abs(self.times[k] - t_next) else k
        if abs(self.times[k] - t_next) > self.half_step or not self.valid[k]:
            return  # outside the recording: SUMO drives it
        session.move_to_xy(target_id, float(self.x[k]), float(self.y[k]), float(self.yaw[k]),
                           self.length, speed=float(self.speed[k]))


class LoggedPlanner:
    """The target is one of the agents the log replayer of a converted scene already drives."""

    name = "replay"

    def additional_files(self, workdir: Path) -> list[Path]:
        return []

    def setup(self, session: SumoSession, target_id: str) -> None:
        pass

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        pass


class SumoPlanner:
    """SUMO's own driver (optionally with another car-following model) keeps the target."""

    def __init__(self, car_following_model: str | None = None) -> None:
        if car_following_model is not None and car_following_model not in CAR_FOLLOWING_MODELS:
            raise InputError(f"unknown SUMO car-following model {car_following_model!r}; "
                             f"choose one of {', '.join(CAR_FOLLOWING_MODELS)}")
        self.model = car_following_model
        self.name = "sumo" if car_following_model is None else f"sumo:{car_following_model}"
        self._type_id = f"coster_cf_{car_following_model}"
        self._switched = False

    def additional_files(self, workdir: Path) -> list[Path]:
        if self.model is None:
            return []
        path = Path(workdir) / f"{self._type_id}.add.xml"
        path.write_text(f'<additional>\n    <vType id="{self._type_id}" carFollowModel="{self.model}"/>\n'
                        "</additional>\n")
        return [path]

    def setup(self, session: SumoSession, target_id: str) -> None:
        self._switched = False

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if self.model is None or self._switched or not present:
            return
        veh = session.api.vehicle
        length, width = veh.getLength(target_id), veh.getWidth(target_id)
        vclass = veh.getVehicleClass(target_id)
        veh.setType(target_id, self._type_id)
        # keep the target's own size and class: only its driver changes
        veh.setLength(target_id, length)
        veh.setWidth(target_id, width)
        veh.setVehicleClass(target_id, vclass)
        self._switched = True


def _replay(arg: str | None, nominal: ReplayPlanner | None) -> Planner:
    if nominal is None:
        raise InputError("planner 'replay' needs the target's nominal trajectory")
    return nominal


def _sumo(arg: str | None, nominal: ReplayPlanner | None) -> Planner:
    return SumoPlanner(arg)


def _policy(arg: str | None, nominal: ReplayPlanner | None) -> Planner:
    # the policy loads stable-baselines3 (the rl extra) at its setup, and says so where it is missing
    return make_policy_planner(arg, nominal)


# Built-in planners (``--planner NAME[:ARG]``): (ARG or None, the target's nominal replay) -> planner.
# A new built-in is one function and one line; anything else of the form module:Class is imported.
PLANNERS: dict[str, Callable[[str | None, ReplayPlanner | None], Planner]] = {
    "replay": _replay,  # the target follows its nominal trajectory (contact at t_col by construction)
    "sumo": _sumo,  # SUMO's driver keeps the target; sumo:<carFollowModel> picks the model
    "policy": _policy,  # policy:PATH, a policy trained in coster_sumo/Scenario-v0 (coster_sumo.sim.policy)
}


def _planner_class(spec: str) -> type:
    """The class a ``module:Class`` or ``path/to/file.py:Class`` planner names.

    A module is looked for on the usual import path and then in the working directory (a console
    script does not put the working directory on ``sys.path``, so ``my_planner:Mine`` next to the
    user was not found without ``PYTHONPATH=.``); a file is loaded from its path.
    """
    where, _, cls_name = spec.rpartition(":")
    try:
        if where.endswith(".py"):
            path = Path(where)
            if not path.is_file():
                raise not_found(path)
            name = "coster_planner_" + "".join(c if c.isalnum() else "_" for c in str(path.resolve()))
            module = sys.modules.get(name)
            if module is None:
                loader = importlib.util.spec_from_file_location(name, path)
                if loader is None or loader.loader is None:
                    raise InputError(f"{path}: not a Python module")
                module = importlib.util.module_from_spec(loader)
                sys.modules[name] = module  # pickling and dataclasses look the module up by name
                loader.loader.exec_module(module)
        else:
            cwd = os.getcwd()
            if cwd not in sys.path:
                sys.path.append(cwd)  # after everything installed: it never shadows a package
            module = importlib.import_module(where)
        return getattr(module, cls_name)  # type: ignore[no-any-return]
    except (ImportError, AttributeError, SyntaxError) as exc:
        raise InputError(f"planner {spec!r}: cannot import ({exc})") from None


def make_planner(spec: str, replay: ReplayPlanner | None = None) -> Planner:
    """``replay`` | ``sumo`` | ``sumo:<carFollowModel>`` | ``policy:PATH`` | ``module:Class`` |
    ``path/to/file.py:Class`` (see :data:`PLANNERS`; a module is also found in the working directory)."""
    name, sep, arg = spec.partition(":")
    if name in PLANNERS:
        return PLANNERS[name](arg if sep else None, replay)
    if sep:
        cls = _planner_class(spec)
        planner = cls()
        if not isinstance(planner, Planner):
            raise InputError(f"planner {spec!r} lacks additional_files/setup/before_step")
        return planner
    raise InputError(f"unknown planner {spec!r}: use {', '.join(PLANNERS)}, sumo:<carFollowModel>, module:Class "
                     "or path/to/file.py:Class")


def check_planner(spec: str) -> None:
    """Raise :class:`InputError` when ``spec`` names no planner (before any work starts)."""
    dummy = ReplayPlanner(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.ones(1, bool), 4.5)
    make_planner(spec, dummy)
