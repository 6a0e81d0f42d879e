"""``coster-sumo scenarios build``: nominal scenes and generated variants into a scenario set.

For every source (a SUMO configuration or a converted WOMD scene) the nominal pass is recorded
once (:func:`coster_sumo.core.nominal_scene`); its scene is a nominal scenario (the episode starts
at the target's departure). Unless the method is ``nominal``, the generator then plans adversaries
against the target (:func:`coster_sumo.core.plan_scenarios`), and each kept plan becomes a variant:
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

from coster_sumo.errors import InputError
from coster_sumo.gym.scenario_set import MANIFEST, ScenarioEntry, write_manifest, write_vtypes
from coster_sumo.scene import ObjectType, Scene, Tracks, save_scene
from coster_sumo.spec import GenerationConfig


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
}

LEAD_S = 3.0  # [s] an episode of a variant starts this long before its adversary appears
HORIZON_S = 20.0  # [s] an episode of a nominal scene lasts at most this long from the target's departure
POST_COLLISION_S = 3.0  # [s] a variant's episode runs on this long after t_col (the agent may have slowed)


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
    progress: Callable[[str], None] | None = field(default=None, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {"sources": list(self.sources), "method": self.method, "seed": self.seed, "seeds": self.seeds,
                "target": self.target, "heldout": list(self.heldout), "snapshots": self.snapshots,
                "variants": self.variants, "samples": self.samples, "lead_s": self.lead_s,
                "horizon_s": self.horizon_s,
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


def _append_agent(scene: Scene, agent_id: str, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, speed: np.ndarray,
                  valid: np.ndarray, length: float, width: float) -> Scene:
    """``scene`` with one more (vehicle) agent; arrays (T,) on the scene's timestamps."""
    tr = scene.tracks
    T = tr.num_steps

    def row(a: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.concatenate([a, v.reshape(1, T).astype(a.dtype)], axis=0)

    tracks = Tracks(ids=np.array([*tr.ids.tolist(), agent_id], dtype=str),  # widened to the longest id
                    object_type=np.append(tr.object_type, ObjectType.VEHICLE).astype(tr.object_type.dtype),
                    x=row(tr.x, x), y=row(tr.y, y), heading=row(tr.heading, yaw),
                    vx=row(tr.vx, speed * np.cos(yaw)), vy=row(tr.vy, speed * np.sin(yaw)),
                    length=row(tr.length, np.full(T, length)), width=row(tr.width, np.full(T, width)),
                    valid=row(tr.valid, valid))
    return dataclasses.replace(scene, tracks=tracks)


def _crop_steps(scene: Scene, t0: float, t1: float) -> Scene:
    """The scene between SUMO times ``t0`` and ``t1`` [s] (both kept), agents never valid there dropped."""
    ts = scene.timestamps
    steps = np.flatnonzero((ts >= t0 - 1e-6) & (ts <= t1 + 1e-6))
    tracks = scene.tracks.select(steps=steps)
    keep = np.flatnonzero(tracks.valid.any(axis=1))
    tracks = tracks.select(agents=keep)
    signals = scene.signals
    signals = dataclasses.replace(signals, state=signals.state[steps] if signals.state.ndim == 2 else signals.state)
    return dataclasses.replace(scene, timestamps=ts[steps], tracks=tracks, signals=signals, current_time_index=0,
                               sdc_index=-1)


def build_set(opts: BuildOptions) -> dict[str, Any]:
    """Build (or resume) the scenario set ``opts.out``; returns the manifest's counts."""
    from coster_sumo.batch.sources import parse_sources
    from coster_sumo.core import check_generation, choose_target, nominal_scene, plan_scenarios
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.formats.scene_folder import LANE_MAP_FILE, converted_scene_file
    from coster_sumo.snapshot import NoSnapshot

    if opts.method not in METHODS:
        raise InputError(f"--method must be one of {', '.join(METHODS)}, not {opts.method!r}")
    method = METHODS[opts.method]
    gen = None
    if method.init is not None and method.rollout is not None:
        gen = GenerationConfig(init=method.init, rollout=method.rollout, samples=opts.samples,
                               variants=opts.variants, models_dir=opts.models_dir)
        check_generation(gen)
    specs = parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, target=opts.target)
    out = opts.out
    (out / "scenarios").mkdir(parents=True, exist_ok=True)
    (out / "nets").mkdir(exist_ok=True)
    write_vtypes(out)
    entries: list[ScenarioEntry] = []
    networks: dict[str, dict[str, Any]] = {}
    done_sources: set[str] = set()
    failed: list[dict[str, str]] = []
    if (out / MANIFEST).exists():  # resume
        old = json.loads((out / MANIFEST).read_text())
        if old.get("method") != opts.method:
            raise InputError(f"{out}: holds a {old.get('method')!r} set, not {opts.method!r}")
        entries = [ScenarioEntry.from_dict(d) for d in old.get("scenarios", [])]
        networks = dict(old.get("networks", {}))
        done_sources = set(old.get("options", {}).get("done_sources", []))
        failed = list(old.get("options", {}).get("failed", []))

    def say(text: str) -> None:
        if opts.progress is not None:
            opts.progress(text)

    for spec in specs:
        label = spec.label()
        if label in done_sources:
            continue
        net_name = network_name(spec.config)
        split = "test" if net_name in opts.heldout else "train"
        networks.setdefault(net_name, {"split": split, "sources": []})
        networks[net_name]["sources"].append(label)
        net_rel = f"nets/{net_name}.net.xml"
        if not (out / net_rel).exists():
            shutil.copyfile(_net_file(spec.config), out / net_rel)
        converted = converted_scene_file(spec.config) is not None
        staging, tls = None, {}
        if converted:
            lane_map = json.loads((spec.config.parent / LANE_MAP_FILE).read_text())
            staging, tls = lane_map.get("staging_lane"), lane_map.get("tls", {})
        try:
            scene, _ = nominal_scene(spec)
            target = choose_target(scene, spec.target, spec.config)
        except InputError as exc:
            failed.append({"source": label, "reason": str(exc)})
            done_sources.add(label)
            say(f"{label}: skipped ({exc})")
            continue
        tr = scene.tracks
        target_id = str(tr.ids[target])
        ts = scene.timestamps
        valid_t = ts[tr.valid[target]]
        base = f"{net_name}_s{spec.seed}_{target_id}".replace("/", "_").replace("#", "_")
        common: dict[str, Any] = {"network": net_name, "split": split, "source": label, "target": target_id,
                                  "net": net_rel, "staging_lane": staging, "tls": tls}
        t_dep, t_last = float(valid_t[0]), float(valid_t[-1])
        t_end = min(t_last, t_dep + opts.horizon_s)
        nominal = _crop_steps(scene, t_dep - 0.1, t_end)
        save_scene(nominal, out / "scenarios" / f"{base}_nominal.npz")
        new = [ScenarioEntry(id=f"{base}_nominal", kind="nominal", method="nominal", t_start=t_dep, t_end=t_end,
                             **common)]
        if gen is not None:
            drivable = DrivableArea.from_road_map(scene.road_map)
            try:
                planned = plan_scenarios(scene, target, spec.seed, gen, drivable, opts.snapshots)
            except NoSnapshot as exc:
                planned = []
                failed.append({"source": label, "reason": f"no snapshot: {exc}"})
            for k, p in enumerate(planned):
                plans = p.plans[:1] if method.one_per_snapshot else p.plans
                for j, plan in enumerate(plans):
                    t_start = max(t_dep, plan.t_start - opts.lead_s)
                    t_stop = min(t_last, plan.t_col + POST_COLLISION_S)
                    times = ts
                    xs, ys, yaws, speeds = plan.sample(times, lead=0.05)
                    valid = (times >= plan.t_start - 0.05) & (times <= t_stop + 1e-6)
                    with_adv = _append_agent(scene, plan.vehicle_id, xs, ys, yaws, speeds, valid,
                                             float(plan.length), float(plan.width))
                    sid = f"{base}_{opts.method}_k{k}_v{j}"
                    save_scene(_crop_steps(with_adv, t_start - 0.1, t_stop), out / "scenarios" / f"{sid}.npz")
                    new.append(ScenarioEntry(id=sid, kind="variant", method=opts.method, t_start=t_start,
                                             t_end=t_stop, t_col=float(plan.t_col), adversary=plan.vehicle_id,
                                             extra={"snapshot": k, "variant": j}, **common))
        entries.extend(new)
        done_sources.add(label)
        write_manifest(out, opts.method, opts.seed, entries, networks,
                       {**opts.to_json(), "done_sources": sorted(done_sources), "failed": failed})
        say(f"{label}: {len(new)} scenario(s) ({sum(e.kind == 'variant' for e in new)} variants)")
    write_manifest(out, opts.method, opts.seed, entries, networks,
                   {**opts.to_json(), "done_sources": sorted(done_sources), "failed": failed})
    return {"scenarios": len(entries), "variants": sum(e.kind == "variant" for e in entries),
            "networks": {n: v["split"] for n, v in networks.items()}, "failed": failed}


def parse_networks(text: Sequence[str]) -> tuple[str, ...]:
    """``--heldout a,b --heldout c`` -> (a, b, c)."""
    return tuple(n.strip() for t in text for n in t.split(",") if n.strip())
