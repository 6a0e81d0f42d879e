"""One injection pass: restart the configuration, add the adversary, drive it, log events.

Order inside every simulation step (all commands are for the time the step reaches, t_next):
1. the log replayer (converted WOMD scenes) places every logged agent;
2. the planner commands the target (or leaves it to SUMO);
3. the adversary controller places the adversary (moveToXY, every step, docs/sumo.md §3);
4. SUMO steps; the pass is recorded into a Scene (all vehicles, signals);
5. events: our box check + SUMO's collision list + off-road (:mod:`coster_sumo.sim.events`).

The adversary is added when the plan starts (t_col - horizon) with its sampled length and width
as a private vehicle type, on the edge under its first position (docs/sumo.md §3: a first placement
off every lane can crash libsumo). It follows the plan exactly, arriving in the snapshot state at
t_col. After its first contact with any vehicle it is **frozen**: it stays at the contact pose at
zero speed until the end of the pass (a wreck, not a vehicle that drives on). If no contact
happens (the planner avoided it), it drives on along its lane (:class:`~coster_sumo.core.plan.AdversaryPlan`)
up to the labels' horizon, then SUMO's driver takes it over (:mod:`coster_sumo.sim.handover`).
"""

from __future__ import annotations

import functools
import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from coster_sumo.core.plan import AdversaryPlan, sim_time_of
from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import InjectionSettings, ScenarioSpec
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.infra.procs import ChildFailed, run_forked
from coster_sumo.sim import handover
from coster_sumo.sim.control import Departure
from coster_sumo.sim.events import Event, EventDetector
from coster_sumo.sim.hold import HeldStates
from coster_sumo.sim.placing import BASE_TYPES, edge_under
from coster_sumo.sim.planners import LoggedPlanner, PlanAware, Planner, ReplayPlanner, make_planner
from coster_sumo.sim.reactive import replayer_for
from coster_sumo.sim.record import SURROUNDINGS_RADIUS_M, Focus, record
from coster_sumo.sim.session import SumoSession, VehicleStates

ADVERSARY_COLOR = (220, 30, 30, 255)  # RGBA: red in sumo-gui
POST_CONTACT_S = 5.0  # [s] a pass goes on this long after the contact (the wreck, the target's reaction)
TIME_EPS = 1e-6  # [s]
POSE_BLOCK = 100  # steps of the adversary's plan sampled at once (10 s at 0.1 s)


class StepActor(Protocol):
    """Anything that commands vehicles before a step (e.g. the log replayer of converted scenes)."""

    def before_step(self, session: SumoSession, t_next: float) -> None: ...


class AdversaryController:
    """Drives the adversary along its plan with moveToXY; freezes it after its first contact.

    ``vehicle_id``: its id in SUMO (default the plan's).
    """

    def __init__(self, plan: AdversaryPlan, step_length: float = 0.1, freeze_at: float | None = None,
                 vehicle_id: str | None = None) -> None:
        self.plan = plan
        self.vehicle_id = plan.vehicle_id if vehicle_id is None else vehicle_id
        self.step_length = step_length
        # a log time jitters around SUMO's step grid: the first knot belongs to the step nearest to
        # it, which may come a few milliseconds before it
        self.first_step = sim_time_of(plan.t_start, step_length)
        self.freeze_at = freeze_at
        self.added = False
        self.frozen_pose: tuple[float, float, float] | None = None
        self.gone = self.released = False
        self._poses: dict[float, tuple[float, float, float, float]] = {}

    def before_step(self, session: SumoSession, t_next: float) -> None:
        if self.added and self.frozen_pose is None and not self.released and handover.due(self.plan, t_next):
            self.released = handover.hand_over(session, self.vehicle_id, self.plan)  # SUMO's driver from now on
        if self.gone or self.released or t_next < self.first_step - TIME_EPS:
            return
        vid = self.vehicle_id
        if self.frozen_pose is None and self.freeze_at is not None and t_next > self.freeze_at + TIME_EPS:
            xs, ys, yaws, _ = self.plan.sample(np.array([self.freeze_at]))
            self.frozen_pose = (float(xs[0]), float(ys[0]), float(yaws[0]))
        if self.frozen_pose is not None:
            x, y, yaw = self.frozen_pose
            session.move_to_xy(vid, x, y, yaw, self.plan.length, speed=0.0)
            return
        x, y, yaw, speed = self._pose(t_next)
        if not self.added:
            vclass, base = self.plan.vclass, BASE_TYPES.get(self.plan.vclass, "DEFAULT_VEHTYPE")  # docs/sumo.md
            session.add_vehicle(vid, self.plan.length, self.plan.width, vclass, base_type=base, color=ADVERSARY_COLOR,
                                departure=Departure(edge_under(session, x, y, yaw, self.plan.length, vclass)))
            self.added = True
        session.move_to_xy(vid, x, y, yaw, self.plan.length, speed=speed)

    def _pose(self, t_next: float) -> tuple[float, float, float, float]:
        """The plan's state at step time ``t_next``; sampled for the next :data:`POSE_BLOCK` steps at
        once (a spline call costs tens of microseconds, whatever the number of times it evaluates)."""
        pose = self._poses.get(t_next)
        if pose is None:
            times = [round(t_next + k * self.step_length, 9) for k in range(POSE_BLOCK)]
            xs, ys, yaws, speeds = self.plan.sample(np.array(times), lead=0.5 * self.step_length)
            self._poses = dict(zip(times, zip(xs.tolist(), ys.tolist(), yaws.tolist(), speeds.tolist(),
                                              strict=True), strict=True))
            pose = self._poses[t_next]
        return pose

    def on_events(self, states: VehicleStates, events: list[Event]) -> None:
        vid, free = self.vehicle_id, self.frozen_pose is None and not self.released  # SUMO's own: never frozen
        if free and any(e.kind == "collision" and vid in e.vehicles for e in events):
            i = int(np.flatnonzero(states.ids == vid)[0])
            self.frozen_pose = (float(states.x[i]), float(states.y[i]), float(states.yaw[i]))


@dataclass
class InjectionResult:
    """What one pass produced.

    Attributes:
        scene: the pass recorded at 10 Hz (all vehicles, the adversary included).
        events: every event, in time order.
        contact: the first adversary-target collision (our box check), or None.
        adversary_off_road: whether the adversary left the drivable area up to t_col (its
            trajectory; later off-road events of a missed contact's run-on stay in ``events``).
        target_off_road: whether the target left the drivable area at any step.
        target_arrived: the target reached the end of its route.
        route_completed: arrived, or still running at the window's end, without collision or
            off-road.
        min_ttc: [s] smallest time-to-collision of the target with the adversary before contact
            (constant-velocity extrapolation; inf when never closing).
        wall_time_s: [s] wall-clock time of the pass.
    """

    scene: Scene
    events: list[Event]
    contact: Event | None
    adversary_off_road: bool
    target_off_road: bool
    target_arrived: bool
    route_completed: bool
    min_ttc: float
    wall_time_s: float
    extra: dict[str, Any] = field(default_factory=dict)


def _ttc(states: VehicleStates, a: int, b: int) -> float:
    """Time until the bounding discs of vehicles ``a`` and ``b`` meet at constant velocity [s]: 0 when
    they already overlap, inf when never. Plain float math: this runs every step."""
    x, y, yaw, v = states.x, states.y, states.yaw, states.speed
    radius = 0.5 * (math.hypot(states.length[a], states.width[a]) + math.hypot(states.length[b], states.width[b]))
    px, py = float(x[b] - x[a]), float(y[b] - y[a])
    ya, yb = float(yaw[a]), float(yaw[b])
    dvx = float(v[b]) * math.cos(yb) - float(v[a]) * math.cos(ya)
    dvy = float(v[b]) * math.sin(yb) - float(v[a]) * math.sin(ya)
    aa = dvx * dvx + dvy * dvy
    bb = 2.0 * (px * dvx + py * dvy)
    cc = px * px + py * py - radius * radius
    if cc <= 0:
        return 0.0
    disc = bb * bb - 4 * aa * cc
    if aa <= 1e-12 or disc < 0 or bb >= 0:
        return float("inf")
    return (-bb - math.sqrt(disc)) / (2 * aa)


@dataclass(frozen=True)
class PassSettings:
    """How one injection pass runs and what it checks.

    Attributes:
        end: [s] the simulation time the pass ends at (at the latest).
        begin: [s] the simulation time it begins at (None: the configuration's).
        drivable: the drivable area for the off-road checks (None: none).
        actors: what commands vehicles before every step besides the planner and the adversary
            (the log replayer of a converted scene).
        detect_events: check events; without, and with ``freeze_at`` [s] (the first contact of a
            pass with detection), the adversary still becomes a wreck then, so the pass plays out
            the same (the overhead benchmark compares the two).
        surroundings_m: [m] record and check only the vehicles this close to the target (and the
            adversary wherever it is), and stop once the target has arrived; None: everything.
        post_contact_s: [s] stop this long after the adversary's first contact with the target, or
            after the later of its first contact with another vehicle (it stays there, a wreck) and
            t_col; None: run to ``end``.
        road: record the map and the signals with the vehicles (False: the vehicles only, for a
            reader that needs no more; see :func:`~coster_sumo.sim.record.record`).
    """

    end: float
    begin: float | None = None
    drivable: DrivableArea | None = None
    actors: tuple[StepActor, ...] = ()
    detect_events: bool = True
    freeze_at: float | None = None
    surroundings_m: float | None = None
    post_contact_s: float | None = None
    road: bool = True


def run_injection(config: str | Path, target_id: str, plan: AdversaryPlan | None, planner: Planner,
                  settings: PassSettings, *, seed: int | None, traci: bool = False,
                  workdir: Path | None = None) -> InjectionResult:
    """Run one pass of ``config`` from a fresh start with the adversary ``plan`` injected.

    ``plan=None`` runs the pass without an adversary (a nominal pass with the same planner). A fresh
    session of ``config`` (``seed``, libsumo or ``traci``, the planner's files written into
    ``workdir``) runs the pass that ``settings`` describe.
    """
    workdir = Path(workdir) if workdir is not None else Path(".")
    with SumoSession(config, seed=seed, begin=settings.begin, end=settings.end, traci=traci,
                     additional=planner.additional_files(workdir)) as session:
        return InjectionPass(session, target_id, plan, planner, settings).run()


def continue_injection(session: SumoSession, target_id: str, plan: AdversaryPlan | None, planner: Planner,
                       settings: PassSettings) -> InjectionResult:
    """The pass of :func:`run_injection` on a running session, from its current time on.

    The planner's additional files must already be loaded (a forked copy of a session started with
    them, see :mod:`coster_sumo.sim.hold`). Events are checked, and the pass recorded, from now on.
    """
    return InjectionPass(session, target_id, plan, planner, settings).run()


class InjectionPass:
    """One injection pass on a running session, from its current time on; its fields are its state.

    Every step: :meth:`before_step` (the actors, the planner once the adversary's plan starts, the
    adversary), SUMO steps, :meth:`after_step` (arrival, events, the wreck, the time to collision).
    """

    def __init__(self, session: SumoSession, target_id: str, plan: AdversaryPlan | None, planner: Planner,
                 settings: PassSettings) -> None:
        self.session, self.target_id, self.plan, self.planner, self.settings = (
            session, target_id, plan, planner, settings)
        self.adversary = (AdversaryController(plan, step_length=session.step_length, freeze_at=settings.freeze_at)
                          if plan is not None else None)
        self.adv_id = plan.vehicle_id if plan is not None else "__none__"
        # what nothing reacts to during the pass is checked in batches of 20 s (see EventDetector)
        self.detector = EventDetector(target_id, self.adv_id, settings.drivable, batch=200)
        self.takeover = plan.t_start if plan is not None else -math.inf  # [s] the planner drives the target from here
        self.arrived = False  # the target reached the end of its route
        self.min_ttc = math.inf  # [s] before the adversary's contact with the target
        self.event_s = 0.0  # [s] wall clock spent on events
        self.contact = False  # the adversary touched the target
        self.stop_after: float | None = None  # [s] the pass ends post_contact_s after this

    def run(self) -> InjectionResult:
        """Step to the end (or the stop after a contact), recording; the outcome."""
        t0 = _time.perf_counter()
        if self.plan is not None and isinstance(self.planner, PlanAware):
            self.planner.set_plan(self.plan)
        self.planner.setup(self.session, self.target_id)
        s = self.settings
        focus = None if s.surroundings_m is None else Focus(self.target_id, s.surroundings_m, extra_ids=(self.adv_id,))
        scene = record(self.session, begin=s.begin, end=s.end, before_step=self.before_step,
                       after_step=self.after_step, focus=focus, road=s.road)
        t_ev = _time.perf_counter()
        self.detector.flush()
        self.event_s += _time.perf_counter() - t_ev
        return self.result(scene, _time.perf_counter() - t0)

    def before_step(self, sess: SumoSession) -> None:
        t_next = round(sess.time + sess.step_length, 9)
        for actor in self.settings.actors:
            actor.before_step(sess, t_next)
        if t_next >= self.takeover - TIME_EPS:  # until the adversary appears the target drives as in the nominal pass
            self.planner.before_step(sess, self.target_id, t_next, self.target_id in sess.vehicle_ids())
        if self.adversary is not None:
            self.adversary.before_step(sess, t_next)

    def after_step(self, sess: SumoSession, states: VehicleStates) -> bool:
        """True: the pass is over (``post_contact_s`` after the contact)."""
        if self.target_id in sess.arrived_ids():
            self.arrived = True
        adversary = self.adversary
        if adversary is not None and adversary.added and self.adv_id in sess.arrived_ids():
            adversary.gone = True  # SUMO removed it (should not happen while we drive it)
        if not self.settings.detect_events:
            return False
        t_ev = _time.perf_counter()
        new = self.detector.check(sess.time, states, sess.collisions())
        if adversary is not None:
            post = self.settings.post_contact_s
            if post is not None and self.stop_after is not None and sess.time > self.stop_after + post + TIME_EPS:
                return True
            if new:
                self._on_events(adversary, sess.time, states, new)
            if adversary.added and not self.contact:
                tr, ar = self.detector.last_rows
                if tr >= 0 and ar >= 0:
                    self.min_ttc = min(self.min_ttc, _ttc(states, tr, ar))
        self.event_s += _time.perf_counter() - t_ev
        return False

    def _on_events(self, adversary: AdversaryController, now: float, states: VehicleStates,
                   new: list[Event]) -> None:
        """The adversary becomes a wreck at its first contact; the contact with the target starts
        the post-contact horizon."""
        adversary.on_events(states, new)
        if adversary.frozen_pose is not None:
            self.detector.settle_adversary()  # a wreck now: nothing reacts to its contacts
            if self.stop_after is None:
                # it hit something else first: the target may still run into the wreck
                # up to its collision time, after that nothing more of the scenario happens
                self.stop_after = max(now, adversary.plan.t_col)
        touched = any(e.kind == "collision" and self.adv_id in e.vehicles and self.target_id in e.vehicles
                      for e in new)
        if touched and not self.contact:
            self.stop_after = now
        self.contact = self.contact or touched

    def result(self, scene: Scene, wall_s: float) -> InjectionResult:
        """The outcome of the pass recorded as ``scene``."""
        detector, target_id, adv_id, plan = self.detector, self.target_id, self.adv_id, self.plan
        contact = detector.first("collision", adv_id, target_id)
        target_collided = any(e.kind == "collision" and target_id in e.vehicles for e in detector.events)
        # the adversary's own trajectory ends at t_col: where the planner avoided it, it drives on at
        # constant velocity (the module docstring), and leaving the road then is not the trajectory's
        plan_end = plan.t_col + 0.5 * self.session.step_length + 1e-6 if plan is not None else math.inf
        adv_off = any(e.kind == "off_road" and e.vehicles == [adv_id] and e.time <= plan_end for e in detector.events)
        tgt_off = detector.first("off_road", target_id) is not None
        in_scene = target_id in set(scene.tracks.ids.tolist())
        still_running = in_scene and bool(scene.tracks.valid[scene.tracks.index_of(target_id), -1])
        completed = (self.arrived or still_running) and not target_collided and not tgt_off
        return InjectionResult(scene=scene, events=list(detector.events), contact=contact,
                               adversary_off_road=adv_off, target_off_road=tgt_off,
                               target_arrived=self.arrived, route_completed=completed,
                               min_ttc=float(self.min_ttc) if contact is None else 0.0,
                               wall_time_s=wall_s, extra={"event_detection_s": float(self.event_s)})


# ----------------------------------------------------------------------------- one variant

def default_planner(converted: bool) -> str:
    """The planner when none is named: the log's own (``replay``) on converted scenes, SUMO's otherwise."""
    return "replay" if converted else "sumo"


def nominal_replay(scene: Scene, target: int) -> ReplayPlanner:
    """A planner that replays the target's nominal trajectory in ``scene``."""
    t = scene.tracks
    return ReplayPlanner(scene.timestamps, t.x[target], t.y[target], t.heading[target],
                         t.speed[target], t.valid[target], float(np.median(t.length[target][t.valid[target]])))


def inject_variant(scenario: ScenarioSpec | ScenarioSource, scene: Scene, target: int, plan: AdversaryPlan,
                   planner: str | InjectionSettings | None = None, *, drivable: DrivableArea | None = None,
                   driver: Planner | None = None) -> InjectionResult:
    """Inject one variant: the one place that decides who drives whom (every command goes through it).

    Who drives the target: the ``planner`` spec (default :func:`default_planner`), or the
    :class:`~coster_sumo.core.spec.InjectionSettings` that name it with the back end (``traci``) and
    the converted scene's ``traffic`` (and the ``workdir`` its planner's files go to).

    - Any SUMO configuration: the configuration's own traffic runs; ``replay`` moves the target
      along its nominal trajectory (:func:`nominal_replay`), ``sumo[:<model>]`` leaves it to SUMO's
      driver, ``module:Class`` to your planner.
    - A converted WOMD scene (:attr:`coster_sumo.formats.source.ScenarioSource.converted`): the log
      is the traffic, so the log replayer drives every logged agent. With ``replay`` it drives the
      target too, for the whole pass. With any other planner it drives the target until the
      adversary's plan starts and then hands it over: the planner commands it from then on, and
      SUMO's driver (``sumo``) continues from the logged pose along the road the target is on.

    ``scenario``: the spec, or its source resolved already. The pass runs from the spec's begin with
    its seed to the end of the nominal scene, or until the target has arrived, or :data:`POST_CONTACT_S`
    after the adversary's contact with the target (or after t_col, when the adversary hit another
    vehicle first and stays there). ``driver``: a planner object that replaces the one ``planner``
    names (a replay of another trajectory). On a SUMO configuration only the target's surroundings
    are recorded and checked (the converted scenes are small: everything is).
    """
    source = ScenarioSource.of(scenario)
    spec, converted, target_id = source.spec, source.converted, str(scene.tracks.ids[target])
    how = planner if isinstance(planner, InjectionSettings) else InjectionSettings(
        planner or default_planner(converted))
    planner_spec = how.planner
    actors: tuple[StepActor, ...] = ()
    if converted:
        handover = {} if planner_spec == "replay" and driver is None else {target_id: plan.t_start}
        actors = (replayer_for(spec.config, scene, target_id, handover, how.traffic),)
        if driver is None:
            driver = LoggedPlanner() if planner_spec == "replay" else make_planner(planner_spec)
    elif driver is None:
        driver = make_planner(planner_spec, nominal_replay(scene, target))
    settings = PassSettings(end=float(scene.timestamps[-1]) + 1e-9, begin=spec.begin, drivable=drivable,
                            actors=actors, surroundings_m=None if converted else SURROUNDINGS_RADIUS_M,
                            post_contact_s=POST_CONTACT_S)
    return run_injection(spec.config, target_id, plan, driver, settings, seed=spec.seed, traci=how.traci,
                         workdir=how.workdir)


@dataclass(frozen=True)
class HeldVariant:
    """What a forked copy of the nominal pass needs to run one variant (:func:`_continue_held`).

    Attributes:
        target_id: the target; plan: the adversary's plan; planner: the planner spec.
        nominal: the replay of the target's nominal trajectory (what ``replay`` and the planners
            that take one follow).
        settings: the pass's settings.
    """

    target_id: str
    plan: AdversaryPlan
    planner: str
    nominal: ReplayPlanner
    settings: PassSettings


def _continue_held(session: SumoSession, job: HeldVariant) -> InjectionResult:
    """A variant's pass in a forked copy of the nominal pass (runs inside :mod:`coster_sumo.sim.hold`)."""
    driver = make_planner(job.planner, job.nominal)
    return InjectionPass(session, job.target_id, job.plan, driver, job.settings).run()


@dataclass(frozen=True)
class VariantFailure:
    """A variant whose injection pass did not finish: SUMO crashed, it ran past the timeout, or it raised.

    Attributes:
        reason: one line, e.g. ``crashed (SIGSEGV)`` or ``timed out after 60 s (stopped)``.
    """

    reason: str


def inject_variants(scenario: ScenarioSpec | ScenarioSource, scene: Scene, target: int, plans: list[AdversaryPlan],
                    how: InjectionSettings, *, drivable: DrivableArea | None = None,
                    held: HeldStates | None = None,
                    done: Callable[[int], None] | None = None) -> list[InjectionResult | VariantFailure]:
    """:func:`inject_variant` for every plan, each in a process of its own; from held copies of
    the nominal pass where there are.

    With ``held`` (the nominal pass of a SUMO configuration run with it), each variant continues
    from the latest held moment before its adversary appears, up to ``how.workers`` at a time,
    instead of simulating from ``begin`` again; the outcome is the same (see
    :mod:`coster_sumo.sim.hold`). Events before that moment are the nominal pass's and are not
    checked again. The other variants run from ``begin`` in a forked child each. A variant whose
    pass crashes (a libsumo segfault), raises, or runs past ``how.timeout`` [s] comes back as a
    :class:`VariantFailure`; the others are not affected. ``done(n)`` is called as n more variants
    finish (progress).
    """
    source = ScenarioSource.of(scenario)
    planner_spec, traci, timeout = how.planner, how.traci, how.timeout
    # what every variant's pass shares: the target's nominal replay and the pass's settings
    target_id = str(scene.tracks.ids[target])
    nominal = nominal_replay(scene, target)
    settings = PassSettings(end=float(scene.timestamps[-1]) + 1e-9, drivable=drivable,
                            surroundings_m=SURROUNDINGS_RADIUS_M, post_contact_s=POST_CONTACT_S)
    results: list[InjectionResult | VariantFailure | None] = [None] * len(plans)
    groups: dict[int, list[int]] = {}  # the held copy each variant continues from (by its index)
    if held is not None and not source.converted and not traci:
        for i, plan in enumerate(plans):
            h = held.holder_before(plan.t_start - TIME_EPS)
            if h is not None:
                groups.setdefault(held.holders.index(h), []).append(i)
    for h_index, members in groups.items():
        jobs = [(_continue_held, HeldVariant(target_id, plans[i], planner_spec, nominal, settings)) for i in members]
        finished = held.run_each(held.holders[h_index], jobs, how.workers, timeout) if held is not None else []
        for i, (ok, value) in zip(members, finished, strict=True):
            results[i] = value if ok else VariantFailure(str(value))
        if done is not None:
            done(len(members))
    for i, plan in enumerate(plans):
        if results[i] is None:
            one = functools.partial(inject_variant, source, scene, target, plan, how, drivable=drivable)
            try:
                results[i] = run_forked(one, timeout=timeout)
            except ChildFailed as exc:
                results[i] = VariantFailure(str(exc))
            if done is not None:
                done(1)
    return [r for r in results if r is not None]
