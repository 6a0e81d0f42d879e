"""The nominal scenario: the traffic a generation works on, and its target.

1. :class:`~coster_sumo.formats.source.ScenarioSource` (its own module, so that the simulation's layer can
   take it too): the spec resolved once (a converted WOMD scene's log, or a SUMO configuration and
   the [begin, end] of its run);
2. :func:`nominal_scene`: the nominal traffic at 10 Hz. A converted WOMD scene is its log
   (``scene.npz``, see :mod:`coster_sumo.formats.scene_folder`); any other configuration is
   simulated with libsumo and recorded with the spec's seed (the injection passes use the same);
3. :func:`nominal_pass`: for ``coster-sumo run``, the scene, its drivable area and each requested
   target chosen once (:func:`coster_sumo.formats.targets.choose_target`: the spec's target, else the SDC
   of a converted scene, else ``ego``), in one :class:`NominalPass` that the targets of a run share.

The generation itself is :mod:`coster_sumo.method.generation`.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import Scene, resample
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.data.dataset import crop_scene
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.formats.targets import OFF_ROAD_CLASSES, choose_target, config_demand, missing_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.collision_time import MARGIN_END, PRIOR_RATE_HZ
from coster_sumo.sim.hold import HeldStates

MAX_TARGET_LIFE_S = 3600.0  # [s] of the target's life a nominal pass records at most (then it stops)


def nominal_scene(scenario: ScenarioSpec | ScenarioSource, *, traci: bool = False, hold: HeldStates | None = None,
                  additional: Sequence[Path] = (), more_targets: Sequence[str] = (), bar: Any = None
                  ) -> tuple[Scene, bool]:
    """The nominal scene at 10 Hz and whether it is a converted WOMD scene (its log).

    ``scenario``: a spec, or a source resolved from it already.

    A SUMO configuration is recorded around the target only (see :data:`SURROUNDINGS_RADIUS_M`),
    the target at every step, the vehicles around it at the models' 2 Hz and interpolated between
    (:class:`~coster_sumo.sim.record.Focus`: what the models read is exactly what SUMO did);
    with ``hold`` the pass leaves held copies of itself for the variants (:mod:`coster_sumo.sim.hold`);
    ``additional`` files are loaded as the variants' passes will load them (a planner's vType);
    ``bar`` (a progress bar) moves along the simulation time to the window's end; ``more_targets`` are
    recorded like the target (one pass for several targets: the union of their surroundings, up to
    the arrival of the last of them).
    """
    source = ScenarioSource.of(scenario)
    if source.log is None:
        return _recorded(source, traci=traci, hold=hold, additional=additional, more_targets=more_targets,
                         bar=bar), False
    return load_scene(source.log), True


def _recorded(source: ScenarioSource, *, traci: bool, hold: HeldStates | None, additional: Sequence[Path],
              more_targets: Sequence[str], bar: Any) -> Scene:
    """:func:`nominal_scene` of a SUMO configuration: its pass recorded around the target(s), in a
    session of its own, opened here as the variants' passes open theirs."""
    from coster_sumo.exports.demand import recording_pass_routes
    from coster_sumo.sim.record import SURROUNDINGS_RADIUS_M, Focus, record
    from coster_sumo.sim.session import SumoSession
    from coster_sumo.sim.sumo_outputs import nominal_outputs

    spec, cfg = source.spec, source.spec.config

    assert source.window is not None  # a SUMO configuration's source has its window
    end = source.window[1]
    target = spec.target or "ego"
    wanted = list(dict.fromkeys((target, *more_targets)))
    demand = config_demand(cfg)  # seconds, where a pass that finds no target takes minutes
    if demand is not None:
        classes = {v: demand.vclass(v) for v in wanted}  # None: not in the demand
        if all(c is None for c in classes.values()):
            where = "in its demand (route and additional files)"
            if spec.target is None and not more_targets:
                raise InputError(f"{cfg}: no vehicle 'ego' {where}; pick a target with --target, e.g. "
                                 f"{', '.join(demand.examples([]))}, or let --targets N choose")
            which = (f"target {wanted[0]!r} is" if len(wanted) == 1 else
                     "none of the targets " + ", ".join(map(repr, wanted)) + " is")
            raise InputError(f"{cfg}: {which} not {where}; candidates: {', '.join(demand.examples(wanted))}")
        if all(c in OFF_ROAD_CLASSES for c in classes.values()):  # the prior places road vehicles
            v, c = next(iter(classes.items()))
            raise InputError(f"{cfg}: target {v!r} is a {c} vehicle (vClass of its vType); COSTER places road "
                             "vehicles around a road vehicle: pick one with --target, or --targets N")
        if hold is not None:
            planned = [demand.depart_s(v) for v in wanted]
            hold.expect_departure(None if None in planned else min(p for p in planned if p is not None))
    # recording goes on a little after the target arrives: the collision-time search keeps the last
    # MARGIN_END steps of a scene free, and they must not eat into the target's own lifetime
    tail_s = (MARGIN_END + 1) / PRIOR_RATE_HZ
    kept = nominal_outputs()  # the configuration's own outputs: into the command's folder, or a temporary one
    session = SumoSession(cfg, seed=spec.seed, begin=spec.begin, end=end, traci=traci, additional=list(additional),
                          sumo_outputs=None if kept is None else kept.folder)
    # where flows may insert the target, the exports take their members from this pass (exports/demand.py)
    routes = (recording_pass_routes(session, begin=spec.begin if spec.begin is not None else
                                    read_sumocfg(cfg).begin or 0.0)
              if demand is None or demand.flows else contextlib.nullcontext())
    with routes, session:
        if kept is not None:
            kept.redirects = session.redirects
        scene = record(session, begin=spec.begin, end=end, bar=bar,
                       after_step=None if hold is None else hold.after_step,
                       focus=Focus(target, SURROUNDINGS_RADIUS_M, tail_s=tail_s, surroundings_hz=PRIOR_RATE_HZ,
                                   more_targets=tuple(more_targets), max_life_s=MAX_TARGET_LIFE_S))
    ids = scene.tracks.ids.tolist()
    present = [ids.index(v) for v in wanted if v in ids]
    if present:  # regions and the drivable area cover its (their) surroundings only
        # every recorded vehicle stays: SUMO found it within the radius (of the target's front, not
        # its centre), and dropping a few would copy every track array of the pass
        return crop_scene(scene, SURROUNDINGS_RADIUS_M, present[0], agent_radius_m=np.inf,
                          more_targets=present[1:])
    # no target ever ran: the focused pass kept who did (and for how long), for the error
    pass_window = scene.meta.get("pass_window_s")
    if pass_window is None:
        raise InputError(f"{cfg}: the simulation recorded no step in [{spec.begin}, {end}]")
    window = f"{pass_window[0]:.1f}-{pass_window[1]:.1f} s"
    raise missing_target(cfg, list(dict.fromkeys((spec.target, *more_targets))), window, scene.meta["ran_s"])


@dataclass(frozen=True)
class NominalPass:
    """What the targets of a run share: the nominal scene (at 10 Hz, and at the models' 2 Hz for
    their draws, :class:`~coster_sumo.method.generation.DrawMemo`), its drivable area, the held copies
    of the pass (None: every variant simulates from the begin), and each requested target chosen once.

    Attributes:
        targets: requested id (None: the default target) -> its agent index in :attr:`scene`.
        missing: requested id -> why it has no target (the :class:`InputError` line), for the
            requested ids not in :attr:`targets`.
        drivable_s: [s] the drivable area took.
    """

    scene: Scene
    low: Scene
    drivable: DrivableArea
    held: HeldStates | None
    targets: dict[str | None, int]
    missing: dict[str | None, str]
    drivable_s: float = 0.0

    def target(self, requested: str | None) -> int:
        """The agent index of a requested target; :class:`InputError` (why it has none) otherwise."""
        if requested in self.missing:
            raise InputError(self.missing[requested])
        return self.targets[requested]


def nominal_pass(source: ScenarioSource, requested: Sequence[str | None], *, traci: bool = False,
                 hold: HeldStates | None = None, additional: Sequence[Path] = (), bar: Any = None) -> NominalPass:
    """:func:`nominal_scene` of ``source`` recorded for the ``requested`` targets (the first leads the
    pass, see ``more_targets`` there; ``hold`` is used for a SUMO configuration only), its drivable
    area, and every requested target chosen with :func:`choose_target`; ``bar`` (a progress bar)
    follows the simulation time of a recorded pass."""
    named = [str(t) for t in requested if t is not None]
    scene, _ = nominal_scene(source, traci=traci, hold=None if source.converted else hold, additional=additional,
                             more_targets=named[1:], bar=bar)
    targets: dict[str | None, int] = {}
    missing: dict[str | None, str] = {}
    for r in requested:
        try:
            targets[r] = choose_target(scene, r, source.spec.config)
        except InputError as exc:
            missing[r] = str(exc)
    t0 = time.perf_counter()
    drivable = DrivableArea.from_road_map(scene.road_map)
    drivable_s = time.perf_counter() - t0
    return NominalPass(scene, resample(scene, PRIOR_RATE_HZ), drivable, hold, targets, missing, drivable_s)
