"""What ``coster-sumo run`` writes into OUTDIR (documented in the README).

```
OUTDIR/
  summary.json            target, t_col, per-variant results, timings (units: s, m, m/s, deg)
  snapshot.json           the collision snapshot (CollisionSnapshot JSON)
  events.jsonl            one event per line, every variant ("variant" key)
  collisions.xml          SUMO-style collision list (our box check and SUMO's own)
  overview.png            map, agents at t_col, ellipse, all variants, heatmap of oversampled paths
  variants/<i>/trajectory.csv   time_s, vehicle, x_m, y_m, heading_deg, speed_mps of target and adversary (10 Hz)
  variants/<i>/trajectories.csv every vehicle of the pass (coster_sumo/exports/trajectories.py)
  variants/<i>/render.png       the variant
  variants/<i>/escape.csv       the target's escape, where its avoidability label has one (10 Hz;
                                coster_sumo/avoidability/labels.py)
  variants/<i>/export/          standalone: net, routes, variant.json (the plan), <name>.sumocfg and
                                traj.fcd.xml: `sumo -c` (or `coster-sumo replay`) plays it, adversary
                                included (coster_sumo/exports/sumo.py)
```

A run with several targets writes this layout into ``OUTDIR/<target>/`` for each and lists them
in ``OUTDIR/summary.json`` (see :func:`coster_sumo.pipeline.run.run`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo import metrics
from coster_sumo.avoidability.evasion import Avoidability, Escape
from coster_sumo.avoidability.labels import ESCAPE_FILE, attach_labels
from coster_sumo.core.plan import AdversaryPlan, sim_time_of
from coster_sumo.core.results import AvoidableOnly, SnapshotRecord, TargetMotion, TargetResult, VariantOutcome
from coster_sumo.core.scene import Scene
from coster_sumo.core.snapshot import AgentState, CollisionSnapshot
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError, SumoError
from coster_sumo.exports.trajectories import TRAJECTORIES_FILE, write_trajectories_csv
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.infra.atomic import json_default, write_json
from coster_sumo.infra.procs import die_with_parent
from coster_sumo.method.generation import PlannedScenario
from coster_sumo.method.vru.areas import off_class_area
from coster_sumo.method.vru.classes import class_of_vclass
from coster_sumo.pipeline import viz
from coster_sumo.rollout.data import STOPPED_MPS
from coster_sumo.sim.inject import InjectionResult

VARIANT_FILE = "variant.json"


# [m] a driven target this far from its nominal position at t_col was moved by its planner
TARGET_MOVED_M = 0.5


def variant_outcome(i: int, plan: AdversaryPlan, res: InjectionResult, target_id: str, t_col: float,
                    nominal: Scene | None = None, snapshot: int = 0) -> VariantOutcome:
    """Variant ``i`` (of ``snapshot``) as summary.json lists it; the contact offset is counted from
    t_col on SUMO's step grid.

    ``nominal``: the nominal scene, for the reason of a variant without contact (where the target
    was against where it would have been).
    """
    t_col_sim = sim_time_of(t_col, float(res.scene.meta.get("step_length") or 0.1))
    c = res.contact
    pair = {plan.vehicle_id, target_id}
    others = [e for e in res.events if e.kind == "collision" and set(e.vehicles) != pair]
    sumo_others = [e for e in res.events if e.kind == "sumo_collision" and set(e.vehicles) != pair]
    gap = closest_approach(res.scene, target_id, plan.vehicle_id)
    xs, ys, _, _ = plan.sample(np.arange(plan.t_start, plan.t_col + 1e-9, 0.1))
    off_road = res.adversary_off_road  # a pedestrian or cyclist: whether it left its class's area
    if plan.vclass != "passenger" and nominal is not None:
        off_road = off_class_area(plan, nominal)
    return VariantOutcome(
        i, adversary_id=plan.vehicle_id, adversary_class=class_of_vclass(plan.vclass),
        # what sets variants of one snapshot apart (their contact is the same by construction)
        plan_start_s=round(plan.t_start, 3), approach_m=round(float(np.hypot(np.diff(xs), np.diff(ys)).sum()), 1),
        collision=c is not None, collision_time=round(c.time, 3) if c else None,
        contact_offset_s=round(c.time - t_col_sim, 3) if c else None,
        relative_speed=c.relative_speed if c else None, impact_angle=c.impact_angle if c else None,
        no_contact_reason=None if c else no_contact_reason(plan, res, target_id, t_col, nominal, gap),
        closest_distance_m=round(gap[0], 2) if gap else None,
        adversary_off_road=off_road, target_off_road=res.target_off_road,
        route_completed=res.route_completed, target_arrived=res.target_arrived,
        min_ttc=res.min_ttc if np.isfinite(res.min_ttc) else None,
        other_collisions=len(others),
        other_collisions_list=tuple(f"{' vs '.join(e.vehicles)} at {e.time:.1f} s" for e in others),
        sumo_only_collisions=len(sumo_others),
        sumo_reported_contact=any(e.kind == "sumo_collision" and set(e.vehicles) == pair for e in res.events),
        wall_time_s=round(res.wall_time_s, 3), snapshot=snapshot, t_col=round(t_col, 3),
    )


def closest_approach(scene: Scene, a_id: str, b_id: str) -> tuple[float, float] | None:
    """(gap [m], time [s]) of the smallest box-to-box distance of two vehicles of a pass (negative:
    overlap depth), over the steps both are in it; None when they never are at once."""
    t = scene.tracks
    ids = t.ids.tolist()
    if a_id not in ids or b_id not in ids:
        return None
    a, b = ids.index(a_id), ids.index(b_id)
    both = np.flatnonzero(t.valid[a] & t.valid[b])
    if not len(both):
        return None
    box = [make_boxes(t.x[k, both], t.y[k, both], t.heading[k, both], t.length[k, both], t.width[k, both])
           for k in (a, b)]
    d = box_signed_distance(box[0], box[1])  # (steps,)
    j = int(np.argmin(d))
    return float(d[j]), float(scene.timestamps[both[j]])


def no_contact_reason(plan: AdversaryPlan, res: InjectionResult, target_id: str, t_col: float,
                      nominal: Scene | None, gap: tuple[float, float] | None) -> str:
    """One line: why the adversary of a pass never touched the target.

    In order: the adversary hit another vehicle first (it then stays there, frozen); the target
    was not in the simulation at t_col; the target was not where its nominal pass had it at t_col
    (its planner braked, sped up or swerved); else how close the two came.
    """
    first = next((e for e in res.events if e.kind == "collision" and plan.vehicle_id in e.vehicles
                  and target_id not in e.vehicles), None)
    close = f"closest {gap[0]:.1f} m apart at {gap[1]:.1f} s" if gap else "never in the simulation together"
    if first is not None and first.time <= t_col + 1e-6:
        other = next(v for v in first.vehicles if v != plan.vehicle_id)
        return f"the adversary hit {other} first, at {first.time:.1f} s, and stayed there; {close}"
    t = res.scene.tracks
    ids = t.ids.tolist()
    step = int(np.argmin(np.abs(res.scene.timestamps - t_col)))
    if target_id not in ids or not t.valid[ids.index(target_id), step]:
        return f"the target was no longer in the simulation at t_col ({t_col:.1f} s); {close}"
    if nominal is not None and target_id in nominal.tracks.ids.tolist():
        n = nominal.tracks
        k = n.index_of(target_id)
        ns = int(np.argmin(np.abs(nominal.timestamps - t_col)))
        if n.valid[k, ns]:
            a = ids.index(target_id)
            dx, dy = t.x[a, step] - n.x[k, ns], t.y[a, step] - n.y[k, ns]
            along = float(dx * np.cos(n.heading[k, ns]) + dy * np.sin(n.heading[k, ns]))
            across = float(-dx * np.sin(n.heading[k, ns]) + dy * np.cos(n.heading[k, ns]))
            if abs(along) >= TARGET_MOVED_M:
                how = "behind its nominal position at t_col (it braked)" if along < 0 else \
                    "ahead of its nominal position at t_col (it went faster)"
                return f"the target was {abs(along):.1f} m {how}; {close}"
            if abs(across) >= TARGET_MOVED_M:
                return f"the target was {abs(across):.1f} m to the side of its nominal position at t_col; {close}"
    if first is not None:
        other = next(v for v in first.vehicles if v != plan.vehicle_id)
        return f"the adversary hit {other} at {first.time:.1f} s; {close}"
    return f"the target kept its nominal path and the adversary missed it: {close}"


def trajectory_csv(path: Path, res: InjectionResult, ids: list[str]) -> None:
    t = res.scene.tracks
    lines = ["time_s,vehicle,x_m,y_m,heading_deg,speed_mps"]
    for vid in ids:
        if vid not in set(t.ids.tolist()):
            continue
        a = t.index_of(vid)
        for s in np.flatnonzero(t.valid[a]):
            lines.append(f"{res.scene.timestamps[s]:.2f},{vid},{t.x[a, s]:.4f},{t.y[a, s]:.4f},"
                         f"{np.degrees(t.heading[a, s]):.3f},{np.hypot(t.vx[a, s], t.vy[a, s]):.4f}")
    path.write_text("\n".join(lines) + "\n")


def collisions_xml(path: Path, results: list[InjectionResult]) -> None:
    """SUMO's collision-output layout, one element per collision event, plus a variant attribute."""
    root = ET.Element("collisions")
    for i, res in enumerate(results):
        for e in res.events:
            if e.kind not in ("collision", "sumo_collision") or len(e.vehicles) < 2:
                continue
            ET.SubElement(root, "collision", {
                "time": f"{e.time:.2f}", "type": str(e.detail.get("type", "collision")),
                "lane": str(e.detail.get("lane", "")), "collider": e.vehicles[1], "victim": e.vehicles[0],
                "source": "coster" if e.kind == "collision" else "sumo", "variant": str(i),
                **({"relativeSpeed": f"{e.relative_speed:.3f}"} if e.relative_speed is not None else {}),
                **({"impactAngle": f"{e.impact_angle:.2f}"} if e.impact_angle is not None else {})})
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="unicode", xml_declaration=True)


def export_variant(folder: Path, config: Path, plan: AdversaryPlan, meta: dict[str, Any],
                   result: InjectionResult, copy_outside: bool = False) -> Path:
    """Standalone SUMO export (:func:`coster_sumo.exports.sumo.write_sumo_export`) plus variant.json
    (the plan and ``meta``); return the new .sumocfg."""
    from coster_sumo.exports.sumo import write_sumo_export

    cfg, info = write_sumo_export(folder, config, result, plan, target_id=str(meta["target_id"]),
                                  planner=str(meta["planner"]), seed=meta.get("seed"), copy_outside=copy_outside)
    write_json(folder / VARIANT_FILE, {**meta, "export": info, "plan": plan.to_dict()})
    return cfg


def target_motion(scene: Scene, index: int) -> TargetMotion:
    """How the target moved in the nominal pass: seconds in the recording, seconds standing still
    (slower than the rollout's stopped flag, ``STOPPED_MPS``), metres driven. A target that stood still for most of
    its time sits in a jam or a gridlock of the configuration (its variants are then contacts with
    a standing vehicle)."""
    tr = scene.tracks
    valid = tr.valid[index]
    if valid.sum() < 2:
        return TargetMotion()
    dt = np.diff(scene.timestamps, append=scene.timestamps[-1])[valid]
    speed = np.hypot(tr.vx[index], tr.vy[index])[valid]
    xy = np.stack([tr.x[index][valid], tr.y[index][valid]], 1)
    return TargetMotion(in_window_s=round(float(dt.sum()), 2), stopped_s=round(float(dt[speed < STOPPED_MPS].sum()), 2),
                        distance_m=round(float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()), 1))


def render_driven(path: Path, i: int, plan: AdversaryPlan, res: InjectionResult, rec: VariantOutcome,
                  nominal: Scene, target: int, snapshot: CollisionSnapshot) -> None:
    """A variant's render as SUMO drove it: every vehicle at the contact (else at t_col) where the
    injection pass had it, the driven paths solid, the adversary's plan dashed; the title says so.
    Without the adversary or the target in the pass: its plan on the ``nominal`` scene, from its
    ``snapshot``."""
    target_id, t_col = str(nominal.tracks.ids[target]), snapshot.time
    xs, ys, _, _ = plan.sample(np.arange(plan.t_start, plan.t_col + 1e-9, 0.1))
    planned_xy = np.stack([xs, ys], 1)
    c = res.contact
    driven = res.scene
    ids = driven.tracks.ids.tolist()
    when = c.time if c else t_col
    step = int(np.argmin(np.abs(driven.timestamps - when)))
    what = (f"contact at {c.time:.1f} s, {c.relative_speed or 0.0:.1f} m/s, {round(c.impact_angle or 0.0):d} deg" if c
            else f"no contact ({rec.closest_distance_m} m at closest)")
    if target_id in ids and plan.vehicle_id in ids:
        a = ids.index(plan.vehicle_id)
        upto = driven.tracks.valid[a] & (driven.timestamps <= when + 1e-6)
        adv_xy = np.stack([driven.tracks.x[a, upto], driven.tracks.y[a, upto]], 1)
        if driven.tracks.valid[a, step] and len(adv_xy):
            at = f"{driven.timestamps[step]:.1f} s"
            marks = viz.AdversaryMarks(adv_xy, AgentState.from_tracks(driven.tracks, a, step),
                                       contact_xy=c.positions[1] if c else None, planned_xy=planned_xy,
                                       box_label=f"{_who(plan)} at {at}",
                                       adversary_class=class_of_vclass(plan.vclass))
            viz.render_variant(path, driven, ids.index(target_id), step,
                               f"variant {i} as driven in SUMO: {what}\nvehicles at {at}", marks)
            return
    # the pass lost the adversary or the target (it left early): the plan on the nominal scene, said so
    t_col_step = int(np.argmin(np.abs(nominal.timestamps - t_col)))
    viz.render_variant(path, nominal, target, t_col_step,
                       f"variant {i} as planned (not in the pass at {when:.1f} s): {what}",
                       viz.AdversaryMarks(planned_xy, snapshot.adversary, contact_xy=c.positions[1] if c else None,
                                          adversary_class=class_of_vclass(plan.vclass)))


def _who(plan: AdversaryPlan) -> str:
    """``adversary``, or ``pedestrian adversary`` / ``cyclist adversary``: how a render names it."""
    cls = class_of_vclass(plan.vclass)
    return "adversary" if cls == "vehicle" else f"{cls} adversary"


def _overview_name(k: int) -> str:
    return "overview.png" if k == 0 else f"overview_{k}.png"


def _plans_key(planned: Sequence[PlannedScenario]) -> tuple[tuple[str, ...], ...]:
    return tuple(tuple(plan.vehicle_id for plan in p.plans) for p in planned)


def _render_overview(out: Path, k: int, p: PlannedScenario, plans: Sequence[AdversaryPlan]) -> None:
    scene, snap = p.scene, p.snapshot
    t_col_step = int(np.argmin(np.abs(scene.timestamps - snap.time)))
    reps = [np.stack([q.x, q.y], 1) for q in plans]
    vru = snap.adversary_class != "vehicle"  # a VRU's box and class are drawn: a small box on a big map
    moment = viz.CollisionMoment(snap.time, t_col_step, snap.target, snap.adversary if vru else None,
                                 entropy=snap.entropy or None, times=p.scene_2hz.timestamps,
                                 adversary_class=snap.adversary_class)
    viz.render_overview(out / _overview_name(k), scene, p.target_index, moment, reps, p.samples_xy)


class _Drawing:
    """``draw()`` in a forked process, on another core, while this one goes on; where there is no
    ``fork`` nothing is drawn there (:meth:`wait` says so and the caller draws)."""

    def __init__(self, draw: Callable[[], None]) -> None:
        self.pid: int | None = None
        if not hasattr(os, "fork"):
            return
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the drawing process
            code = 1
            try:
                die_with_parent()
                draw()
                code = 0
            finally:
                os._exit(code)
        self.pid = pid

    def wait(self) -> bool:
        """Wait for the drawing; whether it drew everything."""
        if self.pid is None:
            return False
        _, status = os.waitpid(self.pid, 0)
        return os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0


class OverviewRenders:
    """The overview of every collision snapshot, drawn in a forked process while the variants are
    labelled and simulated: on a second core the drawing costs no wall time (about 0.4 s of the
    demo's 3 s through ``coster-sumo serve``). It draws the plans of its start; should a variant be
    left out later (its pass failed, ``--avoidable only``) or the drawing fail, :meth:`finish` draws
    the overview again here with the plans kept. Where there is no ``fork``, :meth:`finish` draws."""

    def __init__(self, out: Path, planned: Sequence[PlannedScenario]) -> None:
        self.drawn = _plans_key(planned)

        def draw() -> None:
            for k, p in enumerate(planned):
                _render_overview(out, k, p, p.plans)

        self.drawing = _Drawing(draw)

    def finish(self, out: Path, planned: Sequence[PlannedScenario]) -> None:
        """Wait for the drawing; draw again what it did not draw, or no longer shows the plans kept."""
        ok = self.drawing.wait()
        if not ok or _plans_key(planned) != self.drawn:
            for k, p in enumerate(planned):
                _render_overview(out, k, p, p.plans)


@dataclass(frozen=True)
class OutputSettings:
    """How a run's outputs are written, and what its summary records besides the variants.

    Attributes:
        spec: the run's scenario; planner: who drove the target (chosen already).
        render: draw the overviews and each variant's render.
        options: the run's options as summary.json records them.
        copy_outside: exports also copy the files the configuration names outside its folder.
        folder: where the caller renames the output folder to (None: where it is written).
        avoidable_only: what ``--avoidable only`` tried (None: not asked).
    """

    spec: ScenarioSpec
    planner: str
    render: bool
    options: dict[str, Any]
    copy_outside: bool = False
    folder: Path | None = None
    avoidable_only: AvoidableOnly | None = None

    def __post_init__(self) -> None:
        if not self.planner:
            raise InputError("the outputs of a run need the planner that drove its target")


def write_run_outputs(out: Path, planned: list[PlannedScenario], results: list[InjectionResult],
                      labels: Sequence[Avoidability], timings: dict[str, float], settings: OutputSettings, *,
                      overviews: OverviewRenders | None = None,
                      done: Callable[[int], object] | None = None) -> TargetResult:
    """Write everything of a run into ``out`` (the caller renames it into place, to ``settings.folder``:
    None, ``out`` itself), ``summary.json`` last; returns the target's result (``summary.json`` is its JSON).

    ``planned``: one entry per collision snapshot (``--snapshots``); ``results`` and ``labels``: one
    per plan, in the order of the snapshots' plans. Variants are numbered across snapshots.
    ``overviews``: the overviews started before the variants ran (None: drawn here); ``done(1)`` is
    called as each variant's files and export are written. ``timings`` gains ``outputs_s``.
    """
    spec, planner, render, options = settings.spec, settings.planner, settings.render, settings.options
    t0 = time.perf_counter()
    first = planned[0]
    scene, target = first.scene, first.target_index
    target_id = str(scene.tracks.ids[target])
    step = float(results[0].scene.meta.get("step_length") or 0.1) if results else 0.1
    with (out / "events.jsonl").open("w") as fh:
        for i, res in enumerate(results):
            for e in res.events:
                fh.write(json.dumps({"variant": i, **e.to_dict()}, default=json_default) + "\n")
    collisions_xml(out / "collisions.xml", results)
    # variant i: its snapshot's number and the snapshot, its plan, and its outcome
    jobs = [(k, p, plan) for k, p in enumerate(planned) for plan in p.plans]
    variants = [variant_outcome(i, plan, results[i], target_id, p.snapshot.time, scene, snapshot=k)
                for i, (k, p, plan) in enumerate(jobs)]
    for i in range(len(jobs)):
        (out / "variants" / str(i)).mkdir(parents=True)

    def draw_variants() -> None:
        for i, (_, p, plan) in enumerate(jobs):
            render_driven(out / "variants" / str(i) / "render.png", i, plan, results[i], variants[i], scene, target,
                          p.snapshot)

    # the renders are drawn on another core while the files and exports are written here
    drawing = _Drawing(draw_variants) if render else None
    for i, (_, _, plan) in enumerate(jobs):
        variants[i] = _write_variant(out / "variants" / str(i), plan, results[i], labels[i].escape, variants[i],
                                     target_id, float(scene.timestamps[-1]), settings)
        if done is not None:
            done(1)
    snapshots: list[SnapshotRecord] = []
    for k, p in enumerate(planned):
        p.snapshot.save(out / ("snapshot.json" if k == 0 else f"snapshot_{k}.json"))
        snapshots.append(_snapshot_record(k, p, [v for v in variants if v.snapshot == k], step))
    renders: list[str] = []
    if render:
        if overviews is None:
            for k, p in enumerate(planned):
                _render_overview(out, k, p, p.plans)
        else:
            overviews.finish(out, planned)
        if drawing is not None and not drawing.wait():
            draw_variants()
        renders = [_overview_name(k) for k in range(len(planned))] + [f"variants/{i}/render.png"
                                                                      for i in range(len(jobs))]
    snap0 = first.snapshot
    rates = run_metrics(variants)
    timings = {**timings, "outputs_s": time.perf_counter() - t0}
    result = TargetResult(
        settings.folder if settings.folder is not None else out, target_id, config=str(spec.config), planner=planner,
        seed=spec.seed, t_col=round(snap0.time, 3), num_snapshots=len(snapshots), num_variants=len(variants),
        collision_rate=rates["collision_rate"], off_road_rate=rates["off_road_rate"],
        impact_angle_spread_deg=rates["impact_angle_spread_deg"], variants=tuple(variants), snapshots=tuple(snapshots),
        scenario_id=scene.scenario_id, t_col_sim=sim_time_of(snap0.time, step), t_col_index_2hz=snap0.t_index,
        collision_time_method=snap0.collision_time_method, init_method=snap0.init_method,
        snapshot_signed_distance=round(snap0.signed_distance, 3), nominal_until_s=float(scene.timestamps[-1]),
        nominal_cut_after_s=scene.meta.get("cut_after_s") or None,
        target_motion=target_motion(scene, target), generation=first.info,
        timings_s={k: round(v, 3) for k, v in timings.items()}, options=options, renders=tuple(renders),
        # where the README documents it: how --targets N chose (also under options)
        target_choice=tuple(options["target_choice"]) if options.get("target_choice") else None,
        avoidable_only=settings.avoidable_only, adversary=str(options.get("adversary", "vehicle")))
    result = attach_labels(result, labels, [(plan, results[i]) for i, (_, _, plan) in enumerate(jobs)])
    write_json(out / "summary.json", result.to_json())
    return result


# summary.json's figures over a run's variants: key -> the metric of coster_sumo.metrics.REGISTRY
RUN_METRICS = {"collision_rate": "CR", "off_road_rate": "ORR", "impact_angle_spread_deg": "impact_angle_spread"}


def run_metrics(variants: Sequence[VariantOutcome]) -> dict[str, float | None]:
    """:data:`RUN_METRICS` of a run's variants, from the registry (None without variants)."""
    sample = metrics.MetricSample(tuple(v.run_outcome() for v in variants))
    return {key: metrics.compute(name, sample).value for key, name in RUN_METRICS.items()}


def _write_variant(vdir: Path, plan: AdversaryPlan, res: InjectionResult, escape: Escape | None,
                   rec: VariantOutcome, target_id: str, end: float, settings: OutputSettings) -> VariantOutcome:
    """A variant's files into its folder ``vdir``: trajectories, the target's ``escape`` (None: its
    label has none) and the plain-SUMO export of its pass up to ``end`` [s]; returns its record
    (``rec``) with the export's error, if any."""
    spec = settings.spec
    trajectory_csv(vdir / "trajectory.csv", res, [target_id, plan.vehicle_id])
    write_trajectories_csv(vdir / TRAJECTORIES_FILE, res.scene)
    if escape is not None:
        (vdir / ESCAPE_FILE).write_text(escape.csv())
    try:  # a variant whose export SUMO refuses keeps everything else; the reason is in its record
        export_variant(vdir / "export", spec.config, plan,
                       {"target_id": target_id, "planner": settings.planner, "seed": spec.seed,
                        "begin": spec.begin, "end": end}, res,
                       copy_outside=settings.copy_outside)
    except (SumoError, InputError) as exc:
        shutil.rmtree(vdir / "export", ignore_errors=True)
        return dataclasses.replace(rec, export_error=str(exc))
    return rec


def _snapshot_record(k: int, p: PlannedScenario, mine: list[VariantOutcome], step: float) -> SnapshotRecord:
    """Snapshot ``k``'s entry of summary.json (``mine``: its variants)."""
    snap, a = p.snapshot, p.snapshot.adversary
    return SnapshotRecord(
        k, t_col=round(snap.time, 3), t_col_sim=sim_time_of(snap.time, step), t_col_index_2hz=snap.t_index,
        collision_time_method=snap.collision_time_method, init_method=snap.init_method,
        signed_distance=round(snap.signed_distance, 3),
        adversary={"x": round(a.x, 3), "y": round(a.y, 3), "heading_deg": round(float(np.degrees(a.yaw)), 2),
                   "speed": round(a.speed, 3), "length": round(a.length, 3), "width": round(a.width, 3)},
        variants=tuple(r.variant for r in mine), generation=p.info,
        impact_angles_deg=tuple(r.impact_angle for r in mine if r.collision), adversary_class=snap.adversary_class)
