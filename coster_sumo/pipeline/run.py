"""``coster-sumo run``: the generation core, one injection pass per variant, and the outputs.

1. the nominal scene and the target come from :mod:`coster_sumo.pipeline.scenario`, the plans from
   :mod:`coster_sumo.method.generation`;
2. every plan is injected with :func:`coster_sumo.sim.inject.inject_variant` (same seed, so the
   traffic is the nominal one until the adversary appears);
3. everything is written into a hidden staging folder beside OUT and renamed into place at the
   end (:mod:`coster_sumo.infra.outdir`): an interrupted or failed run leaves no half-written OUT, an
   existing OUT is replaced only when coster-sumo wrote it and ``overwrite`` is set, and the OUT
   is locked while the run writes it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coster_sumo.avoidability.labels import ProofSettings, label_plans
from coster_sumo.core.results import RunResult, RunSummary, TargetEntry, TargetResult
from coster_sumo.core.snapshot import CollisionSnapshot
from coster_sumo.core.spec import GenerationConfig, InjectionSettings, LabelOptions, ScenarioSpec
from coster_sumo.errors import InputError, NoSnapshot, SumoError, not_found
from coster_sumo.exports.demand import EXPANSION_PROGRESS
from coster_sumo.formats.source import ScenarioSource
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.outdir import staged_output
from coster_sumo.infra.procs import torch_threads, usable_cores
from coster_sumo.infra.progress import Bars, progress_bar
from coster_sumo.method.collision_time import PRIOR_RATE_HZ
from coster_sumo.method.generation import DrawMemo, check_generation, label_and_keep, plan_scenarios
from coster_sumo.method.snapshot import SNAPSHOT_INITS
from coster_sumo.pipeline.outputs import OutputSettings, OverviewRenders, write_run_outputs
from coster_sumo.pipeline.scenario import NominalPass, nominal_pass
from coster_sumo.rollout.methods import HORIZON_STEPS, ROLLOUTS
from coster_sumo.sim.hold import HeldStates
from coster_sumo.sim.inject import (
    default_planner,
    inject_variants,
)
from coster_sumo.sim.outcomes import drop_bystander_wrecks, drop_failed_variants
from coster_sumo.sim.planners import check_planner, make_planner
from coster_sumo.sim.sumo_outputs import keep_nominal_outputs

ADVANCE_MARGIN_S = 0.5  # [s] a held copy advances to this long before the earliest adversary start


@dataclass(frozen=True)
class RunOptions:
    """Everything ``coster-sumo run`` takes (see ``coster-sumo run --help``), checked when it is made.

    A bad option is one :class:`InputError` line (exit code 2) raised here, before any work: the
    methods and their weights, the labels' options, the counts, the configuration and its window
    (resolved once into :attr:`source`), the planner, and an id for every one of several targets.
    """

    spec: ScenarioSpec
    out: Path
    generation: GenerationConfig = field(default_factory=GenerationConfig)
    planner: str | None = None
    traci: bool = False
    render: bool = True
    snapshots: int = 1  # collision snapshots (each with its variants) from the one nominal pass
    more_targets: tuple[str, ...] = ()  # further targets sharing the nominal pass (each its own folder)
    from_begin: bool = False  # every variant simulates from begin instead of a held copy of the nominal pass
    target_choice: tuple[dict[str, Any], ...] = ()  # how --targets N chose them (targets.Candidate.to_dict)
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)  # variants run at a time (held copies)
    overwrite: bool = False  # replace an earlier coster-sumo run output in ``out``
    timeout: float | None = None  # [s] wall clock per variant's injection pass (None: no limit)
    copy_outside: bool = False  # exports also copy the files the configuration names outside its folder
    reaction_time: float = 1.0  # [s] the reaction time each variant's avoidability label is stated for
    traffic: str = "log"  # log | reactive: a converted scene's agents (coster_sumo.sim.reactive)
    avoidable: str = "any"  # any | only: keep only variants the target could have avoided (avoidability.labels)
    started: float | None = None  # time.perf_counter() when the command began (None: when run() begins)
    source: ScenarioSource = field(init=False, repr=False, compare=False)  # ``spec`` resolved once
    labels: LabelOptions = field(init=False, repr=False, compare=False)  # reaction_time and avoidable, checked
    injection: InjectionSettings = field(init=False, repr=False, compare=False)  # how the variants are injected

    def __post_init__(self) -> None:
        check_generation(self.generation)
        object.__setattr__(self, "labels", LabelOptions(self.reaction_time, self.avoidable))
        if self.snapshots < 1:
            raise InputError(f"--snapshots must be >= 1, not {self.snapshots}")
        if not self.spec.config.is_file():
            raise not_found(self.spec.config)
        # a bad window is one line before any work
        object.__setattr__(self, "source", ScenarioSource.resolve(self.spec))
        if self.planner is not None:
            check_planner(self.planner)
        if self.traffic not in ("log", "reactive"):
            raise InputError(f"traffic must be log or reactive, not {self.traffic!r}")
        object.__setattr__(self, "injection", InjectionSettings(
            self.planner or default_planner(self.source.converted), traci=self.traci, workers=self.workers,
            timeout=self.timeout, traffic=self.traffic))
        if len(self.targets) > 1 and None in self.targets:
            raise InputError("with several targets every one needs an id (--target ID, repeated)")

    def to_json(self) -> dict[str, Any]:
        """The options as summary.json records them."""
        return {**self.spec.to_dict(), **self.generation.to_dict(), "out": str(self.out), "planner": self.planner,
                "traci": self.traci, "render": self.render, "snapshots": self.snapshots, "from_begin": self.from_begin,
                "reaction_time": self.reaction_time, "avoidable": self.avoidable,
                **({"more_targets": list(self.more_targets)} if self.more_targets else {}),
                **({"target_choice": list(self.target_choice)} if self.target_choice else {})}

    @property
    def targets(self) -> list[str | None]:
        """The targets in order (None: the default target), repeats dropped."""
        return list(dict.fromkeys((self.spec.target, *self.more_targets)))


def run(opts: RunOptions, bars: Bars = progress_bar) -> RunResult:
    r"""Run the whole pipeline; returns its result (summary.json in OUT is its JSON).

    ``bars`` shows the progress of the nominal pass, the generation and the variants
    (:func:`coster_sumo.infra.progress.bars`: ``bars(quiet=True)`` shows none).

    With several targets (``more_targets``) they share the nominal pass and its held copies; each
    gets its own folder ``OUT/<target>/`` laid out as a one-target OUT, and ``OUT/summary.json``
    lists them (a target without a scenario is listed with its reason; the others go on): the
    result is then a :class:`~coster_sumo.core.results.RunSummary` of their
    :class:`~coster_sumo.core.results.TargetResult`\ s.
    """
    source, spec, planner = opts.source, opts.spec, opts.injection.planner
    named = [str(t) for t in opts.targets if t is not None]
    timings: dict[str, float] = {}
    begun = time.perf_counter() if opts.started is None else opts.started
    with staged_output(opts.out, kind="run", inputs=source.inputs, overwrite=opts.overwrite) as staging:
        # an adversary appears up to its horizon before t_col, which may come right after the target departs
        held = (HeldStates(spec.target or "ego", lead_s=HORIZON_STEPS / PRIOR_RATE_HZ, more_targets=named[1:])
                if not (opts.from_begin or opts.traci) else None)
        try:
            t0 = time.perf_counter()
            timings["startup_s"] = t0 - begun  # imports, checks of the inputs, the output folder
            # a planner's own files (the vType of sumo:<model>) go into the nominal pass too: the held
            # copies of it must have them
            extra = ([] if source.converted or planner == "replay"
                     else make_planner(planner).additional_files(staging))
            with bars("nominal pass", "sim s") as bar, keep_nominal_outputs(staging / "sumo-outputs") as kept:
                nominal = nominal_pass(source, opts.targets, traci=opts.traci, hold=held, additional=extra, bar=bar)
            kept.write_listing()  # what the configuration would have written, and where it went
            timings["nominal_s"] = time.perf_counter() - t0 - nominal.drivable_s
            timings["drivable_s"] = nominal.drivable_s
            if len(named) <= 1:
                return _one_target(opts, nominal, spec.target, staging, opts.out, timings, bars)
            return _several_targets(opts, nominal, named, staging, timings, bars)
        finally:
            if held is not None:
                held.close()


def _several_targets(opts: RunOptions, nominal: NominalPass, named: list[str], staging: Path,
                     timings: dict[str, float], bars: Bars) -> RunSummary:
    """Every target of a run with several into its own folder of ``staging``, and the list of them
    (``staging/summary.json``)."""
    entries: list[TargetEntry] = []
    taken = {"summary.json"}
    for tid in named:
        folder = staging / target_folder(tid, taken)
        folder.mkdir()
        try:
            # its result says where publish puts it
            result = _one_target(opts, nominal, tid, folder, opts.out / folder.name, dict(timings), bars)
        except InputError as exc:  # this target has no scenario; the others go on
            shutil.rmtree(folder, ignore_errors=True)
            entries.append(TargetEntry(tid, error=str(exc)))
            continue
        plain = result.to_json()
        entries.append(TargetEntry(tid, folder.name, result=result,
                                   extra={**{k: plain[k] for k in _LISTED}, "failed_variants": len(result.failed)}))
    if not any(t.result is not None for t in entries):
        raise InputError("; ".join(str(t.error) for t in entries))
    summary = RunSummary(opts.out, str(opts.spec.config), tuple(entries), extra={
        **({"target_choice": list(opts.target_choice)} if opts.target_choice else {}),
        "nominal_until_s": float(nominal.scene.timestamps[-1]),
        "timings_s": {k: round(v, 3) for k, v in timings.items()}, "options": opts.to_json()})
    write_json(staging / "summary.json", summary.to_json())
    return summary


# what OUT/summary.json lists of each target of a run with several
_LISTED = ("t_col", "t_col_sim", "num_snapshots", "num_variants", "collision_rate", "off_road_rate",
           "impact_angle_spread_deg")


def target_folder(target_id: str, taken: set[str]) -> str:
    """The folder name of a target's outputs in a run with several: its id made file-name safe,
    with a suffix where that name is ``taken`` already (``a/b`` and ``a_b``); adds it to ``taken``."""
    base = re.sub(r"[^A-Za-z0-9._-]", "_", target_id).strip(".") or "target"
    name, k = base, 1
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def _one_target(opts: RunOptions, nominal: NominalPass, requested: str | None, out: Path, published: Path,
                timings: dict[str, float], bars: Bars) -> TargetResult:
    """Generation, the variants and the outputs (into ``out``, its ``summary.json`` last) of one target
    of the nominal scene; its result names ``published``, where ``out`` is renamed to."""
    spec, source = opts.spec, opts.source
    how, wanted = opts.injection, opts.labels  # the injection's settings, the labels' options
    scene, drivable, held = nominal.scene, nominal.drivable, nominal.held
    threads = generation_threads(opts.generation, held)
    target = nominal.target(requested)
    target_id = str(scene.tracks.ids[target])
    t0 = time.perf_counter()
    advance = _advance_held(held, threads)
    shared = DrawMemo(nominal.low)  # what every draw for this target computes once (--avoidable only draws again)
    try:
        # the CVAE's draws take seconds each: a bar that counts them, so the console is not silent
        with bars(f"generation ({target_id})", "draw") as bar:
            def drawn(snap: CollisionSnapshot) -> None:
                bar.set_postfix_str(f"t_col {snap.time:.1f} s", refresh=False)
                bar.update(1)
                if advance is not None:
                    advance(snap)

            # every core until a held copy advances beside (the prior's curves over the target's life
            # come first: 28.5 s on one thread, 22.1 s on two on A10KW, the same plans)
            with torch_threads(None if threads is None else usable_cores()):
                planned = plan_scenarios(scene, target, spec.seed, opts.generation, drivable, shared, opts.snapshots,
                                         on_snapshot=drawn)
    except NoSnapshot as exc:
        raise InputError(f"{spec.config}: no collision snapshot for target {target_id!r}: {exc}") from None
    timings["generation_s"] = time.perf_counter() - t0
    # the overviews are drawn on another core while the variants are labelled and simulated
    overviews = OverviewRenders(out, planned) if opts.render else None
    # every variant's avoidability, its escapes proven in SUMO (part of generation: docs/method.md step 8)

    def label(plans: list[Any]) -> list[Any]:
        # one step per plan's kinematic search, one for the escapes' replays in SUMO
        with bars("labels (escapes proven in SUMO last)", "step", total=len(plans) + 1) as bar:
            proof = ProofSettings(drivable, held, workers=how.workers, traci=how.traci, traffic=how.traffic)
            return label_plans(source, scene, target, plans, proof, reaction_time_s=wanted.reaction_time,
                               timings=timings, done=bar.update)

    planned, labels, tried = label_and_keep(planned, label, wanted, opts.generation.variants * opts.snapshots,
                                            seed=spec.seed, gen=opts.generation, drivable=drivable, memo=shared)
    if tried is not None:
        if not any(p.plans for p in planned):
            raise InputError(f"{spec.config}: none of the {tried.tried} variants for target {target_id!r} "
                             f"was avoidable at a reaction time of {wanted.reaction_time:g} s (--avoidable only)")
    labelled = timings.get("avoidability_s", 0.0) + timings.get("proof_s", 0.0)
    # the rest since generation: the overviews' fork, --avoidable only's further draws
    timings["labels_other_s"] = time.perf_counter() - t0 - timings["generation_s"] - labelled
    t0 = time.perf_counter()
    plans = [plan for p in planned for plan in p.plans]
    with bars("variants", "variant", total=len(plans)) as bar:
        outcomes = inject_variants(source, scene, target, plans, dataclasses.replace(how, workdir=out),
                                   drivable=drivable, held=held, done=bar.update)
    timings["injection_s"] = time.perf_counter() - t0
    planned, results = drop_failed_variants(planned, outcomes)
    planned, results = drop_bystander_wrecks(planned, results, target_id)
    if not any(p.plans for p in planned):
        failed = [f for p in planned for f in p.info.get("failed", [])]
        if failed and len(failed) == len(plans):
            raise SumoError(f"{spec.config}: the SUMO pass of every variant of target {target_id!r} failed "
                            f"(first: {failed[0]['reason']})")
        raise InputError(f"{spec.config}: every adversary of target {target_id!r} ran into another vehicle before "
                         "t_col in the simulation")
    kept = [labels[pl.vehicle_id] for p in planned for pl in p.plans]
    with bars("outputs", "variant", total=sum(len(p.plans) for p in planned)) as bar, _expansion_bar(bars):
        settings = OutputSettings(spec, how.planner, opts.render, opts.to_json(), copy_outside=opts.copy_outside,
                                  folder=published, avoidable_only=tried)
        return write_run_outputs(out, planned, results, kept, timings, settings, overviews=overviews, done=bar.update)


@contextlib.contextmanager
def _expansion_bar(bars: Bars) -> Iterator[None]:
    """Inside it, an export's flow expansion (a plain sumo run of the window, ``exports/demand.py``)
    shows a bar in simulated seconds, opened at its first report."""
    opened: list[Any] = []

    def show(done: float, total: float) -> None:
        if not opened:
            opened.append(bars("outputs: the flows expanded by sumo", "sim s", total=round(total, 1)))
        bar = opened[0]
        if round(done, 1) > bar.n:  # a step number cut between two reads shows less: skipped
            bar.update(round(done, 1) - bar.n)

    token = EXPANSION_PROGRESS.set(show)
    try:
        yield
    finally:
        EXPANSION_PROGRESS.reset(token)
        for bar in opened:
            bar.close()


def generation_threads(gen: GenerationConfig, held: HeldStates | None) -> int | None:
    """torch threads for the generation of a run once held copies of the nominal pass advance beside
    it (a drawn snapshot starts one, see :func:`_advance_held`): one core less than the process may
    use; None (torch's own choice) without held copies or without a model."""
    if held is None or not (SNAPSHOT_INITS[gen.init].weights or ROLLOUTS[gen.rollout].weights):
        return None
    return max(1, usable_cores() - 1)


def _advance_held(held: HeldStates | None, threads: int | None = None
                  ) -> Callable[[CollisionSnapshot], None] | None:
    """Once a collision time is drawn, a held copy starts simulating up to shortly before any of its
    adversaries can appear (in its own process, while this one generates them); torch then computes
    on ``threads`` (None: as it does), leaving that copy a core (torch's pool spin-waits for every
    thread, :func:`coster_sumo.infra.procs.torch_threads`)."""
    if held is None:
        return None

    def advance(snap: CollisionSnapshot) -> None:
        if threads is not None:
            import torch

            torch.set_num_threads(threads)
        held.advance(snap.time - HORIZON_STEPS / PRIOR_RATE_HZ - ADVANCE_MARGIN_S)

    return advance
