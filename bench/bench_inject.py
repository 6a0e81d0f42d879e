"""Overhead of event detection and logging in an injection pass (goal: <= 5 % extra wall time).

Runs the same injection pass (networks/intersection, a random-offset snapshot, constant-velocity
plan, SUMO planner) with and without event detection, alternating, and prints the ratio of the
median wall times, the paired ratio of back-to-back runs and the share of the pass spent inside
detection. The pass without detection freezes the adversary at the contact time the detected pass
found, so both play out the same. Usage: python bench/bench_inject.py [--repeats N] [--config CFG]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.formats.targets import choose_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import plan_scenario
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim.inject import InjectionResult, PassSettings, run_injection
from coster_sumo.sim.planners import make_planner

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--config", type=Path, default=REPO / "networks/intersection/intersection.sumocfg")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--end", type=float, default=60.0)
    args = ap.parse_args()
    spec = ScenarioSpec(args.config, seed=1, end=args.end)
    scene, _ = nominal_scene(spec)
    target = choose_target(scene, None, args.config)
    drivable = DrivableArea.from_road_map(scene.road_map)
    planned = plan_scenario(scene, target, spec.seed, GenerationConfig(init="random", rollout="cv"), drivable)
    plan = planned.plans[0]
    target_id = str(scene.tracks.ids[target])

    def run(detect: bool, freeze_at: float | None = None) -> InjectionResult:
        return run_injection(args.config, target_id, plan, make_planner("sumo"),
                             PassSettings(end=float(scene.timestamps[-1]) + 1e-9, drivable=drivable,
                                          detect_events=detect, freeze_at=freeze_at),
                             seed=spec.seed, workdir=Path(tempfile.mkdtemp()))

    # the adversary becomes a wreck at its first contact; the pass without detection is told when,
    # so both passes play out the same and differ only by the detection and logging
    first = next((e for e in run(True).events if e.kind == "collision" and plan.vehicle_id in e.vehicles), None)
    freeze_at = first.time if first is not None else None
    print(f"first adversary contact: {'none' if first is None else f'{first.time:.1f} s with {first.vehicles}'}")
    times: dict[bool, list[float]] = {True: [], False: []}
    inside: list[float] = []
    paired: list[float] = []  # with / without of back-to-back runs: drift of the machine cancels
    for _ in range(args.repeats):
        for detect in (False, True):
            res = run(detect, None if detect else freeze_at)
            times[detect].append(res.wall_time_s)
            if detect:
                inside.append(res.extra["event_detection_s"] / res.wall_time_s)
                paired.append(times[True][-1] / times[False][-1])
    with_ev, without = statistics.median(times[True]), statistics.median(times[False])
    steps = scene.num_steps
    print(f"config {args.config.name}: {steps} steps, {scene.tracks.num_agents} vehicles, {args.repeats} repeats")
    print(f"median wall time without events: {without:.3f} s, with events: {with_ev:.3f} s")
    print(f"overhead ratio (with / without): {with_ev / without:.3f}  ({100 * (with_ev / without - 1):+.1f} %)")
    q = statistics.quantiles(paired, n=4) if len(paired) > 1 else [paired[0]] * 3
    print(f"paired ratio, median (quartiles): {statistics.median(paired):.3f} ({q[0]:.3f}-{q[2]:.3f})")
    print(f"time inside event detection, share of the pass (median): {100 * statistics.median(inside):.1f} %")


if __name__ == "__main__":
    main()
