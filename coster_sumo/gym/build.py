"""``coster-sumo scenarios build``: nominal scenes and generated variants into a scenario set.

For every source (a SUMO configuration or a converted WOMD scene) the nominal pass is recorded
once (:func:`coster_sumo.pipeline.scenario.nominal_scene`); its scene is a nominal scenario (the episode starts
at the target's departure). Unless the method is ``nominal``, the generator then plans adversaries
against the target (:func:`coster_sumo.method.generation.plan_scenarios`), and each kept plan becomes a variant:
the same recorded pass with the adversary's plan sampled at 10 Hz as one more agent, the episode
starting ``lead_s`` before the adversary appears. Adversarial sets keep the nominal scenes too
(the paper trains on adversarial scenes mixed with nominal ones).

The set is written incrementally: the manifest is rewritten after every source, and a source the
manifest already lists is skipped, so an interrupted build resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.geometry.boxes import make_boxes, sat_overlap_depth
from coster_sumo.gym.hard import AVOIDANCE_TAIL_S, hard_variants
from coster_sumo.gym.scenario_set import MANIFEST, ScenarioEntry, SetNetwork, write_manifest, write_vtypes
from coster_sumo.gym.scene_edit import append_agent, crop_steps


@dataclass(frozen=True)
class Method:
    """A generator of a scenario set: a snapshot init and a rollout, and how many plans to keep."""

    init: str | None  # None: no adversaries (nominal only)
    rollout: str | None
    one_per_snapshot: bool = False  # keep the first plan of each snapshot only


METHODS: dict[str, Method] = {
    "nominal": Method(None, None),
    "coster": Method("snapshot", "cvae"),  # every variant of each snapshot (the paper's augmentation)
    "coster-one-per-snapshot": Method("snapshot", "cvae", one_per_snapshot=True),
    "random-cvae": Method("random", "cvae"),  # a random contact pose instead of the prior's
    "snapshot-cv": Method("snapshot", "cv"),  # the prior's snapshot, constant-velocity approach
    # hand-specified adversities no generator here makes (a leader braking hard, a cut-in) and the
    # nominal scene's criticality score, for an evaluation set independent of every generator
    "hard": Method(None, None),
}

LEAD_S = 3.0  # [s] an episode of a variant starts this long before its adversary appears
HORIZON_S = 20.0  # [s] an episode of a nominal scene lasts at most this long from the target's departure
TTC_HORIZON_S = 5.0  # [s] criticality's time-to-collision looks this far ahead
POST_COLLISION_S = AVOIDANCE_TAIL_S + 3.0  # [s] after t_col: the route goes on 5 s past it (it ends 3 s early)


@dataclass
class BuildOptions:
    """What ``coster-sumo scenarios build`` takes."""

    sources: list[str]
    out: Path
    method: str = "coster"
    seed: int = 0
    seeds: int = 1
    target: str | None = None
    heldout: tuple[str, ...] = ()  # networks of the test split
    snapshots: int = 2  # collision snapshots per scene
    variants: int = 5  # variants per snapshot (K)
    samples: int = 1000
    models_dir: Path | None = None
    lead_s: float = LEAD_S
    horizon_s: float = HORIZON_S
    quiet: bool = False
    traffic: str = "log"  # a converted source's agents in the labels' escape proof (coster_sumo.sim.reactive)
    adversary: str = "vehicle"  # the adversaries' class (coster-sumo run --adversary)
    progress: Callable[[str], None] | None = field(default=None, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {"sources": list(self.sources), "method": self.method, "seed": self.seed, "seeds": self.seeds,
                "target": self.target, "heldout": list(self.heldout), "snapshots": self.snapshots,
                "variants": self.variants, "samples": self.samples, "lead_s": self.lead_s,
                "horizon_s": self.horizon_s, "traffic": self.traffic, "adversary": self.adversary,
                "models_dir": str(self.models_dir) if self.models_dir is not None else None}


def network_name(config: Path) -> str:
    """The network a source belongs to: a converted scene's folder, else the configuration's net file stem."""
    from coster_sumo.formats.scene_folder import converted_scene_file
    from coster_sumo.formats.sumocfg import read_sumocfg

    if converted_scene_file(config) is not None:
        return config.parent.name
    nets = read_sumocfg(config).inputs().get("net-file", [])
    return Path(nets[0]).name.split(".")[0] if nets else config.stem


def _net_file(config: Path) -> Path:
    from coster_sumo.formats.sumocfg import read_sumocfg

    nets = read_sumocfg(config).inputs().get("net-file", [])
    if not nets:
        raise InputError(f"{config}: names no net file")
    return Path(nets[0])


@dataclass
class _SetProgress:
    """What the manifest of a set being built holds so far (rewritten after every source)."""

    entries: list[ScenarioEntry] = field(default_factory=list)
    networks: dict[str, SetNetwork] = field(default_factory=dict)
    done_sources: set[str] = field(default_factory=set)
    failed: list[dict[str, str]] = field(default_factory=list)

    @classmethod
    def of(cls, out: Path, method: str) -> _SetProgress:
        """The progress of the set at ``out`` (empty: a new set); a set of another method is an error."""
        if not (out / MANIFEST).exists():
            return cls()
        old = json.loads((out / MANIFEST).read_text())
        if old.get("method") != method:
            raise InputError(f"{out}: holds a {old.get('method')!r} set, not {method!r}")
        return cls(entries=[ScenarioEntry.from_dict(d) for d in old.get("scenarios", [])],
                   networks={n: SetNetwork.from_json(v) for n, v in old.get("networks", {}).items()},
                   done_sources=set(old.get("options", {}).get("done_sources", [])),
                   failed=list(old.get("options", {}).get("failed", [])))

    def write(self, opts: BuildOptions) -> None:  # the manifest, with the progress in its options
        write_manifest(opts.out, opts.method, opts.seed, self.entries, self.networks,
                       {**opts.to_json(), "done_sources": sorted(self.done_sources), "failed": self.failed})


@dataclass(frozen=True)
class _Source:
    """One source's recorded nominal pass and target, shared by all its scenarios: ``base`` names their
    files, ``common`` holds their manifest fields, ``t_dep`` / ``t_last`` [s] when the target is valid."""

    spec: ScenarioSpec
    scene: Scene
    target: int
    base: str
    common: dict[str, Any]
    t_dep: float
    t_last: float


def _register_source(opts: BuildOptions, spec: ScenarioSpec, progress: _SetProgress) -> dict[str, Any]:
    """Enter the source's network in the set (its net file copied once); the manifest fields that
    every scenario of the source shares (the target still None)."""
    from coster_sumo.formats.scene_folder import LANE_MAP_FILE, converted_scene_file

    label = spec.label()
    net_name = network_name(spec.config)
    split = "test" if net_name in opts.heldout else "train"
    net = progress.networks.get(net_name, SetNetwork(split))
    progress.networks[net_name] = dataclasses.replace(net, sources=(*net.sources, label))
    net_rel = f"nets/{net_name}.net.xml"
    if not (opts.out / net_rel).exists():
        shutil.copyfile(_net_file(spec.config), opts.out / net_rel)
    staging, tls = None, {}
    if converted_scene_file(spec.config) is not None:
        lane_map = json.loads((spec.config.parent / LANE_MAP_FILE).read_text())
        staging, tls = lane_map.get("staging_lane"), lane_map.get("tls", {})
    return {"network": net_name, "split": split, "source": label, "target": None, "net": net_rel,
            "staging_lane": staging, "tls": tls}


def _nominal_entry(opts: BuildOptions, src: _Source) -> ScenarioEntry:
    """Write the nominal scenario (from the target's departure, at most ``horizon_s`` long)."""
    t_end = min(src.t_last, src.t_dep + opts.horizon_s)
    save_scene(crop_steps(src.scene, src.t_dep - 0.1, t_end), opts.out / "scenarios" / f"{src.base}_nominal.npz")
    return ScenarioEntry(id=f"{src.base}_nominal", kind="nominal", method="nominal", t_start=src.t_dep, t_end=t_end,
                         extra={"criticality": criticality(src.scene, src.target)}, **src.common)


def _generated_entries(opts: BuildOptions, method: Method, gen: GenerationConfig, src: _Source,
                       failed: list[dict[str, str]]) -> list[ScenarioEntry]:
    """The generator's variants of the source (none, and a line in ``failed``, without a snapshot): each
    the nominal pass with the adversary's plan as one more agent."""
    from coster_sumo.avoidability.labels import ProofSettings, label_plans
    from coster_sumo.errors import NoSnapshot
    from coster_sumo.formats.scene_folder import object_type_of_vclass
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method.generation import DrawMemo, plan_scenarios

    drivable = DrivableArea.from_road_map(src.scene.road_map)
    try:
        planned = plan_scenarios(src.scene, src.target, src.spec.seed, gen, drivable, DrawMemo.of(src.scene),
                                 opts.snapshots)
    except NoSnapshot as exc:
        planned = []
        failed.append({"source": src.spec.label(), "reason": f"no snapshot: {exc}"})
    new, ts = [], src.scene.timestamps
    for k, p in enumerate(planned):
        plans = p.plans[:1] if method.one_per_snapshot else p.plans
        proof = ProofSettings(drivable, traffic=opts.traffic)  # could the target have avoided each contact
        labels = label_plans(src.spec, src.scene, src.target, plans, proof) if plans else []  # info["avoidable"]
        for j, (plan, lab) in enumerate(zip(plans, labels, strict=True)):
            t_start = max(src.t_dep, plan.t_start - opts.lead_s)
            t_stop = min(src.t_last, plan.t_col + POST_COLLISION_S)
            xs, ys, yaws, speeds = plan.sample(ts, lead=0.05)
            valid = (ts >= plan.t_start - 0.05) & (ts <= t_stop + 1e-6)
            with_adv = append_agent(src.scene, plan.vehicle_id, (xs, ys, yaws), speeds, valid,
                                    (float(plan.length), float(plan.width)), object_type_of_vclass(plan.vclass))
            sid = f"{src.base}_{opts.method}_k{k}_v{j}"
            save_scene(crop_steps(with_adv, t_start - 0.1, t_stop), opts.out / "scenarios" / f"{sid}.npz")
            new.append(ScenarioEntry(id=sid, kind="variant", method=opts.method, t_start=t_start, t_end=t_stop,
                                     t_col=float(plan.t_col), adversary=plan.vehicle_id, avoidable=lab.avoidable,
                                     extra={"snapshot": k, "variant": j, "contact": lab.contact_kind,
                                            "last_moment_s": lab.last_moment_s, "vclass": plan.vclass}, **src.common))
    return new


def build_set(opts: BuildOptions) -> dict[str, Any]:
    """Build (or resume) the scenario set ``opts.out``; returns the manifest's counts."""
    from coster_sumo.batch.sources import parse_sources
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.method.generation import check_generation
    from coster_sumo.pipeline.scenario import nominal_scene

    if opts.method not in METHODS or opts.traffic not in ("log", "reactive"):
        raise InputError(f"--method must be one of {', '.join(METHODS)} and --traffic log or reactive, not "
                         f"{opts.method!r}, {opts.traffic!r}")
    method = METHODS[opts.method]
    gen = None
    if method.init is not None and method.rollout is not None:
        gen = GenerationConfig(init=method.init, rollout=method.rollout, samples=opts.samples,
                               variants=opts.variants, models_dir=opts.models_dir, adversary=opts.adversary)
        check_generation(gen)
    specs = parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, target=opts.target)
    out = opts.out
    (out / "scenarios").mkdir(parents=True, exist_ok=True)
    (out / "nets").mkdir(exist_ok=True)
    write_vtypes(out)
    progress = _SetProgress.of(out, opts.method)
    say: Callable[[str], None] = opts.progress or (lambda text: None)
    for spec in specs:
        label = spec.label()
        if label in progress.done_sources:
            continue
        common = _register_source(opts, spec, progress)
        try:
            scene, _ = nominal_scene(spec)
            target = choose_target(scene, spec.target, spec.config)
        except InputError as exc:
            progress.failed.append({"source": label, "reason": str(exc)})
            progress.done_sources.add(label)
            say(f"{label}: skipped ({exc})")
            continue
        target_id = str(scene.tracks.ids[target])
        valid_t = scene.timestamps[scene.tracks.valid[target]]
        base = f"{common['network']}_s{spec.seed}_{target_id}".replace("/", "_").replace("#", "_")
        src = _Source(spec, scene, target, base, {**common, "target": target_id}, float(valid_t[0]),
                      float(valid_t[-1]))
        new = [_nominal_entry(opts, src)]
        if opts.method == "hard":
            new.extend(hard_variants(out, scene, target, src.base, src.common, src.t_dep, src.t_last,
                                      opts.horizon_s))
        if gen is not None:
            new.extend(_generated_entries(opts, method, gen, src, progress.failed))
        progress.entries.extend(new)
        progress.done_sources.add(label)
        progress.write(opts)
        say(f"{label}: {len(new)} scenario(s) ({sum(e.kind == 'variant' for e in new)} variants)")
    progress.write(opts)
    return {"scenarios": len(progress.entries), "variants": sum(e.kind == "variant" for e in progress.entries),
            "networks": {n: v.split for n, v in progress.networks.items()}, "failed": progress.failed}


def criticality(scene: Scene, target: int) -> dict[str, float]:
    """A SafeShift-like criticality of the target's nominal scene, from the log alone.

    ``min_ttc_s``: smallest time-to-collision with any agent within 50 m, every 0.5 s of the log:
    the first look-ahead (0.1 s steps up to 5 s) at which the two oriented boxes, moved at their
    logged velocities, overlap (inf: none); ``max_decel``: the target's hardest braking [m/s^2]
    (speed differences over 0.5 s);
    ``conflicts``: agents whose path crosses the target's within 2 m with a time gap under 3 s;
    ``score``: 1 / max(min TTC, 0.5) + max decel / 4 + conflicts (larger is more critical).
    """
    tr = scene.tracks
    ts = scene.timestamps
    v = tr.valid[target]
    speed = np.hypot(tr.vx[target], tr.vy[target])
    k = np.flatnonzero(v)
    lag = 5  # 0.5 s at 10 Hz
    decel = float(max(0.0, np.max((speed[k[:-lag]] - speed[k[lag:]]) / (ts[k[lag:]] - ts[k[:-lag]])))) \
        if len(k) > lag else 0.0
    min_ttc = np.inf
    conflicts = 0
    tx, ty = tr.x[target], tr.y[target]
    tau = np.arange(0.0, TTC_HORIZON_S + 1e-9, 0.1)  # [s] look-ahead at constant velocity
    steps = np.flatnonzero(v)[::5]  # every 0.5 s of the target's log
    for a in range(tr.num_agents):
        if a == target:
            continue
        both = steps[tr.valid[a, steps]]
        both = both[np.hypot(tr.x[a, both] - tx[both], tr.y[a, both] - ty[both]) < 50.0]
        if len(both):
            # oriented boxes moved at their logged velocities: the first look-ahead at which they overlap
            boxes = [make_boxes(tr.x[i, both][:, None] + tr.vx[i, both][:, None] * tau,
                                tr.y[i, both][:, None] + tr.vy[i, both][:, None] * tau,
                                tr.heading[i, both][:, None], tr.length[i, both][:, None],
                                tr.width[i, both][:, None]) for i in (target, a)]
            hit = sat_overlap_depth(boxes[0], boxes[1]) > 0.0  # (steps, taus)
            if hit.any():
                min_ttc = min(min_ttc, float(tau[np.argmax(hit, axis=1)[hit.any(axis=1)]].min()))
        pa = np.stack([tr.x[a, tr.valid[a]], tr.y[a, tr.valid[a]]], -1)[::5]
        pt = np.stack([tx[v], ty[v]], -1)[::5]
        if len(pa) and len(pt):
            d = np.hypot(*(pa[:, None, :] - pt[None, :, :]).transpose(2, 0, 1))
            i, j = np.unravel_index(np.argmin(d), d.shape)
            if d[i, j] < 2.0 and abs(ts[tr.valid[a]][::5][i] - ts[v][::5][j]) < 3.0:
                conflicts += 1
    score = 1.0 / max(min_ttc, 0.5) + decel / 4.0 + conflicts
    return {"min_ttc_s": float(min_ttc), "max_decel": decel, "conflicts": float(conflicts), "score": float(score)}


def parse_networks(text: Sequence[str]) -> tuple[str, ...]:
    """``--heldout a,b --heldout c`` -> (a, b, c)."""
    return tuple(n.strip() for t in text for n in t.split(",") if n.strip())
