"""Proof of an escape in SUMO: the target replays its escape plan in the variant's own pass.

An escape found by :mod:`coster_sumo.avoidability.search` is kinematic: the other vehicles follow their nominal
paths there, while in SUMO they react (to the adversary, and to a target that brakes or changes
lane). So every escape is replayed as the target's trajectory (moveToXY every step, the ``replay``
planner's mechanism) in the same injection pass as the variant: the same held moment of the
nominal pass, the same traffic, the adversary driven along its plan (frozen at a first contact, at
constant velocity after t_col), up to the escape's horizon after t_col. The escape is proven when
the target touches nobody (our box check, the ground truth of every pass) and stays on the road.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from coster_sumo.avoidability.evasion import Avoidability, Escape, Manoeuvre
from coster_sumo.avoidability.verdict import EscapeJob, Verdict, _joined, _verdict, verdict
from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan, sim_time_of
from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.sim.events import EventDetector
from coster_sumo.sim.hold import HeldStates
from coster_sumo.sim.inject import (
    TIME_EPS,
    AdversaryController,
    PassSettings,
    StepActor,
    continue_injection,
    edge_under,
    run_injection,
)
from coster_sumo.sim.planners import ReplayPlanner
from coster_sumo.sim.record import SURROUNDINGS_RADIUS_M, record
from coster_sumo.sim.session import SumoSession
from coster_sumo.sim.states import VehicleStates


def escape_planner(escape: Escape, length_m: float) -> ReplayPlanner:
    """The target's planner that drives the escape (box centres, 10 Hz) with moveToXY."""
    return ReplayPlanner(escape.times, escape.x, escape.y, escape.yaw, escape.speed,
                         np.ones(len(escape.times), bool), length_m)


@dataclass(frozen=True)
class HeldEscape:
    """What a forked copy of the nominal pass needs to replay one escape (:func:`_prove_held`).

    Attributes:
        job: the escape and its adversary's plan; target_id: the target; length_m: [m] its length.
        drivable: the drivable area (off-road events); end: [s] when the pass ends.
    """

    job: EscapeJob
    target_id: str
    length_m: float
    drivable: DrivableArea | None
    end: float


def _prove_held(session: Any, held: HeldEscape) -> Verdict:
    """One escape's pass in a forked copy of the nominal pass (runs inside :mod:`coster_sumo.sim.hold`)."""
    job = held.job
    settings = PassSettings(end=held.end, drivable=held.drivable, surroundings_m=SURROUNDINGS_RADIUS_M)
    res = continue_injection(session, held.target_id, job.plan, escape_planner(job.escape, held.length_m), settings)
    return verdict(res, held.target_id, job)


@dataclass(frozen=True)
class ProofSettings:
    """Where and how the escapes are replayed in SUMO (:func:`prove_labels`).

    Attributes:
        drivable: the drivable area for the off-road events (None: none are checked).
        held: held copies of the nominal pass to replay from (None: every replay from begin).
        workers: replays run at a time from the held copies.
        traci: a TraCI socket instead of libsumo.
        traffic: a converted scene's agents in the replays, ``log`` or ``reactive``.
        horizon_s: [s] each replay ends this long after t_col.
    """

    drivable: DrivableArea | None = None
    held: HeldStates | None = None
    workers: int = 1
    traci: bool = False
    traffic: str = "log"
    horizon_s: float = HORIZON_AFTER_TCOL_S

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise InputError(f"workers must be >= 1, not {self.workers}")
        if self.traffic not in ("log", "reactive"):
            raise InputError(f"traffic must be log or reactive, not {self.traffic!r}")
        if not self.horizon_s > 0:
            raise InputError(f"the proof's horizon must be > 0 s, not {self.horizon_s}")


def prove_escapes(scenario: ScenarioSpec | ScenarioSource, scene: Scene, target: int, jobs: list[EscapeJob],
                  proof: ProofSettings, *, together: bool = True) -> list[Verdict]:
    """Replay every escape in SUMO; one verdict (:func:`verdict`) per job, in order.

    From the held copy of the nominal pass before the adversary appears where there is one (as the
    variant's own pass), else from the configuration's begin with its seed; a converted WOMD scene's
    log drives every other agent and hands the target over to the escape when the adversary
    appears. Each pass ends ``horizon_s`` after t_col.

    On a converted scene nothing in SUMO reacts (the log moves every other agent, the plans move
    the adversary and the target), so with ``together`` every escape is replayed in one pass
    (:class:`_JointProof`), each by a copy of the target facing its own copy of the adversary; the
    verdicts are those of one pass per escape (``together=False``). ``traffic="reactive"``: the
    logged agents react to the escaping target (:mod:`coster_sumo.sim.reactive`); an escape that
    makes none react is a pass of the log and keeps its verdict from the joint pass, one that makes
    an agent react gets a pass of its own (:func:`joint_verdicts`).
    """
    drivable, held, traci, horizon_s = proof.drivable, proof.held, proof.traci, proof.horizon_s
    tr = scene.tracks
    target_id = str(tr.ids[target])
    length = float(np.median(tr.length[target][tr.valid[target]]))
    source = ScenarioSource.of(scenario)
    spec, converted = source.spec, source.converted
    out: list[Verdict | None] = [None] * len(jobs)
    groups: dict[int, list[int]] = {}
    if held is not None and not converted and not traci:
        for i, job in enumerate(jobs):
            h = held.holder_before(job.plan.t_start - TIME_EPS)
            if h is not None:
                groups.setdefault(held.holders.index(h), []).append(i)
    for h_index, members in groups.items():
        assert held is not None
        payloads = [(_prove_held, HeldEscape(jobs[i], target_id, length, drivable,
                                             end=jobs[i].plan.t_col + horizon_s + 1e-6)) for i in members]
        for i, (ok, v) in zip(members, held.run_each(held.holders[h_index], payloads, proof.workers), strict=True):
            # a copy SUMO crashed in (a pedestrian-class adversary moved onto a walking area of
            # fokr_bs_demo: SIGSEGV in the step) proves nothing: the escape stands refuted, the run goes on
            out[i] = v if ok else Verdict(False, f"SUMO failed replaying it: {v}")
    resumed: dict[int, tuple[float, Verdict]] = {}  # job -> (begin of its own pass, the joint pass's verdict before it)
    if converted and together and not traci and jobs:
        out = joint_verdicts(spec, scene, target, jobs, proof, resumed)
    for i, job in enumerate(jobs):
        if out[i] is not None:
            continue
        actors: tuple[StepActor, ...] = ()
        if converted:
            from coster_sumo.sim.reactive import replayer_for
            from coster_sumo.sim.replay import far_agents

            # logged agents that never come near the escape are left out: they are replayed, so they
            # react to nothing, and the verdict is about the target's contacts
            far = far_agents(scene.tracks, np.stack([job.escape.x, job.escape.y], -1), PROOF_RADIUS_M)
            actors = (replayer_for(spec.config, scene, target_id, {target_id: job.plan.t_start}, proof.traffic, far),)
        begin, head = resumed.get(i, (spec.begin, None))
        settings = PassSettings(end=job.plan.t_col + horizon_s + 1e-6, begin=begin, drivable=drivable,
                                actors=actors, surroundings_m=None if converted else SURROUNDINGS_RADIUS_M,
                                road=False)  # the verdict reads the tracks alone
        res = run_injection(spec.config, target_id, job.plan, escape_planner(job.escape, length), settings,
                            seed=spec.seed, traci=traci)
        out[i] = verdict(res, target_id, job) if head is None else _joined(head, verdict(res, target_id, job))
    return [v for v in out if v is not None]


def joint_verdicts(spec: ScenarioSpec, scene: Scene, target: int, jobs: list[EscapeJob],
                   proof: ProofSettings, resumed: dict[int, tuple[float, Verdict]] | None = None
                   ) -> list[Verdict | None]:
    """The verdicts of a converted scene's escapes from one joint pass (:class:`_JointProof`), None
    where the escape needs a pass of its own: in reactive traffic, one that makes a logged agent react.

    There an escape that makes nobody react is a pass of the log. Those that
    :func:`~coster_sumo.sim.quiet_escapes.reaches_no_one` tells in advance join the pass as in log
    traffic; the others join it watched (:class:`~coster_sumo.sim.quiet_escapes.ReactionWatch`), and
    one whose target copy would make an agent react leaves it at that step (its verdict None).

    ``resumed`` gains, for such a job, where its own pass may begin (:data:`RESUME_LEAD_S` before it
    left, on the log's step grid) and the joint pass's verdict on the steps before that: up to the
    first reaction nobody in its own pass deviates from the log, so those steps are the joint pass's
    (not where its adversary froze at a contact before then: that pass begins at the scene's begin)."""
    if proof.traffic == "log":
        return list(_JointProof(spec, scene, target, jobs, proof.drivable, proof.horizon_s).run())
    from coster_sumo.formats.scene_folder import agent_sizes
    from coster_sumo.sim.quiet_escapes import reaches_no_one

    sizes = agent_sizes(scene)
    watch = [i for i, job in enumerate(jobs) if not reaches_no_one(scene, target, job.escape, sizes=sizes)]
    joint = _JointProof(spec, scene, target, jobs, proof.drivable, proof.horizon_s, watch=watch)
    out = [None if i in joint.would_react else v for i, v in enumerate(joint.run())]
    if resumed is not None:
        resumed.update(joint.resumed)
    return out


class _JointProof:
    """Every escape of a converted scene in one SUMO pass from the configuration's begin.

    Job k adds two vehicles when its adversary appears: ``<target>#escape<k>``, which drives the
    escape (moveToXY, as the ``replay`` planner), and ``<adversary>#escape<k>``, driven by the
    injection's own :class:`~coster_sumo.sim.inject.AdversaryController` (frozen at a first contact).
    The log replays every other agent that comes near any escape, as in a pass of its own. Each job
    has its own :class:`~coster_sumo.sim.events.EventDetector`, which sees the logged agents and its
    two vehicles only: the copies of other jobs do not exist for it. Its two vehicles leave the
    network when its horizon ends.
    """

    def __init__(self, spec: ScenarioSpec, scene: Scene, target: int, jobs: list[EscapeJob],
                 drivable: DrivableArea | None, horizon_s: float, watch: Sequence[int] = ()) -> None:
        from coster_sumo.sim.quiet_escapes import ReactionWatch
        from coster_sumo.sim.replay import LogReplayer, far_agents

        self.spec, self.scene, self.jobs = spec, scene, jobs
        tr = scene.tracks
        self.target_id = str(tr.ids[target])
        self.length = float(np.median(tr.length[target][tr.valid[target]]))
        self.drivers = [escape_planner(j.escape, self.length) for j in jobs]
        self.target = target
        self.ids = [(f"{self.target_id}#escape{k}", f"{j.plan.vehicle_id}#escape{k}") for k, j in enumerate(jobs)]
        self.adversaries = [AdversaryController(j.plan, vehicle_id=a) for j, (_, a) in zip(jobs, self.ids, strict=True)]
        self.detectors = [EventDetector(t, a, drivable, batch=200) for t, a in self.ids]
        paths = np.concatenate([np.stack([j.escape.x, j.escape.y], -1) for j in jobs])
        far = far_agents(scene.tracks, paths, PROOF_RADIUS_M)
        self.replayer = LogReplayer.for_config(spec.config, scene, exclude=far | {self.target_id})
        step = round(scene.dt, 6)  # SUMO runs a converted scene at its log's step
        self.starts = [sim_time_of(j.plan.t_start, step) for j in jobs]
        self.ends = [j.plan.t_col + horizon_s + 1e-6 for j in jobs]
        self.copies = {v for pair in self.ids for v in pair}
        self.added: set[int] = set()
        self.removed: set[int] = set()
        # the jobs watched for a logged agent that would react (each leaves the pass at that step)
        self.watched = list(watch)
        self.watch = ReactionWatch(scene, target, [far_agents(tr, np.stack([jobs[k].escape.x, jobs[k].escape.y], -1),
                                                              PROOF_RADIUS_M) for k in self.watched],
                                   (self.replayer.lengths, self.replayer.widths), self.replayer.dt)
        self.would_react: set[int] = set()
        self.left_at: dict[int, float] = {}  # [s] when each of them left, its adversary not frozen then
        self.resumed: dict[int, tuple[float, Verdict]] = {}  # filled by run()

    def _live(self, k: int, t: float) -> bool:
        return self.starts[k] - TIME_EPS <= t <= self.ends[k] and k not in self.removed

    def before(self, session: SumoSession) -> None:
        t_next = round(session.time + session.step_length, 9)
        self.replayer.before_step(session, t_next)
        for k, (tid, aid) in enumerate(self.ids):
            if k in self.added and k not in self.removed and t_next > self.ends[k]:
                for vid in (tid, aid):
                    if vid in session.vehicle_ids():
                        session.remove_vehicle(vid)
                self.removed.add(k)
            if not self._live(k, t_next):
                continue
            if k not in self.added:
                esc = self.jobs[k].escape
                # the target's copy as the log's target is added (size, vType)
                self.replayer.add_as(session, self.target, tid, route_edges=edge_under(
                    session, float(esc.x[0]), float(esc.y[0]), float(esc.yaw[0]), self.length))
                self.added.add(k)
            self.drivers[k].before_step(session, tid, t_next, True)
            self.adversaries[k].before_step(session, t_next)

    def after(self, session: SumoSession, states: VehicleStates) -> bool:
        t = session.time
        names = states.id_list()
        self._watch(session, states, names)
        rows = {v: i for i, v in enumerate(names) if v in self.copies}
        base = [i for i, v in enumerate(names) if v not in self.copies]
        for k, (tid, aid) in enumerate(self.ids):
            if not self._live(k, t):
                continue
            own = sorted(base + [rows[v] for v in (tid, aid) if v in rows])
            sub = _take(states, own)
            new = self.detectors[k].check(t, sub)
            adversary = self.adversaries[k]
            if new and adversary.frozen_pose is None:
                adversary.on_events(sub, new)
                if adversary.frozen_pose is not None:
                    self.detectors[k].settle_adversary()
        # over once no job has a step left (each ended, or left the pass for one of its own)
        t_next = round(t + session.step_length, 9)
        return all(k in self.removed or t_next > end for k, end in enumerate(self.ends))

    def _watch(self, session: SumoSession, states: VehicleStates, names: list[str]) -> None:
        """Take out of the pass every watched job whose target copy would make a logged agent react now."""
        if not self.watched:  # log traffic, or every escape cleared in advance: nothing to do per step
            return
        t = session.time
        live = [(w, k) for w, k in enumerate(self.watched) if self._live(k, t) and self.ids[k][0] in names]
        k_log = self.replayer.step_at(t) if live else None
        if k_log is None:
            return
        from coster_sumo.sim.reactive import Pose

        in_sumo = set(names) - session.hidden
        present = np.zeros(self.scene.tracks.num_agents, bool)
        present[[a for a, sid in self.replayer.active.items() if sid in in_sumo]] = True
        for w, k in live:
            i = names.index(self.ids[k][0])
            pose = Pose(float(states.x[i]), float(states.y[i]), float(states.yaw[i]), float(states.speed[i]),
                        float(states.length[i]), float(states.width[i]))
            if self.watch.reacts(w, k_log, pose, present):
                self.would_react.add(k)
                if self.adversaries[k].frozen_pose is None:
                    self.left_at[k] = t
                self.removed.add(k)
                for vid in self.ids[k]:
                    if vid in names:
                        session.remove_vehicle(vid)

    def run(self) -> list[Verdict]:
        end = max(self.ends)
        with SumoSession(self.spec.config, seed=self.spec.seed, begin=self.spec.begin, end=end) as session:
            # the verdict reads the tracks alone: no map (reading the net costs more than the pass)
            rec = record(session, begin=self.spec.begin, end=end, before_step=self.before, after_step=self.after,
                         road=False)
        out = []
        origin = self.spec.begin if self.spec.begin is not None else float(self.scene.timestamps[0])
        step = round(self.scene.dt, 6)
        for k, (det, (tid, aid), job) in enumerate(zip(self.detectors, self.ids, self.jobs, strict=True)):
            det.flush()
            out.append(_verdict(det.events, rec, tid, aid, job))
            if k in self.left_at:
                begin = origin + max(0, round((self.left_at[k] - RESUME_LEAD_S - origin) / step)) * step
                # the step at ``begin`` in both: the own pass may not record its first state
                self.resumed[k] = (begin, _verdict(det.events, rec, tid, aid, job, before=begin + 0.5 * step))
        return out


def _take(states: VehicleStates, rows: list[int]) -> VehicleStates:
    """The vehicles of ``states`` at ``rows``, in that order."""
    idx = np.asarray(rows, np.int64)
    names = states.id_list()
    return VehicleStates(ids=states.ids[idx], x=states.x[idx], y=states.y[idx], yaw=states.yaw[idx],
                         speed=states.speed[idx], length=states.length[idx], width=states.width[idx],
                         vclass=states.vclass[idx], type_id=states.type_id[idx], names=[names[i] for i in rows])


# [m] a logged agent never this close to an escape's path cannot touch the target: the largest
# vehicles are under 25 m long, so two boxes in contact have centres under 15 m apart, and the path's
# points are at most a few metres apart
PROOF_RADIUS_M = 30.0
# [s] an escape's own reactive pass begins this long before its target copy left the joint pass: the
# logged agents, the copy and the adversary are placed by moveToXY every step before then, so SUMO has
# their poses and speeds of 10 steps before anyone reacts
RESUME_LEAD_S = 1.0


def prove_labels(scenario: ScenarioSpec | ScenarioSource, scene: Scene, target: int, plans: Sequence[AdversaryPlan],
                 labels: Sequence[Avoidability], proof: ProofSettings) -> None:
    """Replay the escapes of ``labels`` (one per plan of ``plans``) with :func:`prove_escapes` and
    mark each replayed one proven or refuted (``Escape.proven``, ``Escape.proof``). Equal escapes of
    one plan (the same act and manoeuvre at several reaction times) are replayed once and share the
    verdict. The blocked plans of a label (``Avoidability.blocked``) are replayed too, and one SUMO
    clears becomes an escape (:meth:`~coster_sumo.avoidability.evasion.Avoidability.adopt_cleared`).

    Where an escape may cost a SUMO pass of its own (every case but a converted scene in log
    traffic, whose escapes all share one joint pass), the escapes are replayed in rounds, the latest
    reaction time first (:func:`_next_to_prove`): a driver who may act later may also act earlier,
    so once one clears, the earlier reaction times' escapes need no replay (they stay unproven,
    ``proven=None``, and their labels stand on the later one)."""
    joint = ScenarioSource.of(scenario).converted and proof.traffic == "log" and not proof.traci
    while True:
        jobs: list[EscapeJob] = []
        owners: list[Escape] = []
        for plan, lab in zip(plans, labels, strict=True):
            for e in (_all_to_prove(lab) if joint else [_next_to_prove(lab)]):
                if e is not None:
                    jobs.append(EscapeJob(plan, e))
                    owners.append(e)
        if not jobs:
            break
        verdicts = prove_escapes(scenario, scene, target, jobs, proof)
        for e, v in zip(owners, verdicts, strict=True):
            e.proven, e.proof = v.ok, v.to_json()
        for lab in labels:
            _share_with_twins(lab)
        if joint:
            break
    for lab in labels:
        lab.adopt_cleared()
        _share_with_twins(lab)


def _all_to_prove(lab: Avoidability) -> list[Escape]:
    """Every escape and blocked plan of ``lab``, one of each equal group (one joint pass proves them)."""
    seen: set[tuple[float, Manoeuvre]] = set()
    out = []
    for e in [*lab.escapes.values(), *lab.blocked]:
        if e is not None and (key := _same_escape(e)) not in seen:
            seen.add(key)
            out.append(e)
    return out


def _next_to_prove(lab: Avoidability) -> Escape | None:
    """The one escape of ``lab`` to replay next, or None when its label is settled.

    From the latest reaction time down: where one is cleared (its escape proven, or a blocked plan
    SUMO cleared that acts late enough) every earlier reaction time is settled too; else its escape
    if not replayed yet, or, where the search found none, the least demanding untried blocked plan
    that acts late enough for it (:meth:`Avoidability.adopt_cleared`'s choice)."""
    blocked = sorted(lab.blocked, key=lambda b: (b.peak_accel, b.t_act))
    for r in sorted(lab.escapes, reverse=True):
        late_enough = [b for b in blocked if b.t_act >= lab.t_threat + r - 1e-6]
        e = lab.escapes[r]
        if (e is not None and e.proven) or (e is None and any(b.proven for b in late_enough)):
            return None
        if e is not None:
            if e.proven is None:
                return e
            continue
        nxt = next((b for b in late_enough if b.proven is None), None)
        if nxt is not None:
            return nxt
    return None


def _share_with_twins(lab: Avoidability) -> None:
    """An escape's equals (at other reaction times, or among the blocked plans) take its verdict."""
    both = [e for e in [*lab.escapes.values(), *lab.blocked] if e is not None]
    by_key = {_same_escape(e): e for e in both if e.proven is not None}
    for e in both:
        if e.proven is None and (twin := by_key.get(_same_escape(e))) is not None:
            e.proven, e.proof = twin.proven, twin.proof


def _same_escape(e: Escape) -> tuple[float, Manoeuvre]:
    """What makes two escapes of one plan the same: when the target acts, and how."""
    return round(e.t_act, 3), e.manoeuvre
