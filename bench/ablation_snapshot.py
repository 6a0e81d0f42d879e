"""Collision-time ablation of the snapshot stage: CSD and CPD for entropy / last / random.

Usage: python bench/ablation_snapshot.py DATASET [--all] [--scenes N] [--womd FILE ...] [--json OUT]
Held-out scenes of a `coster-sumo simulate` dataset (their SDC as target) plus optional WOMD files;
the shipped prior places the adversary; relative speed |v_target - v_adv| and impact angle (adversary
position in the target frame) of each snapshot feed CSD and CPD (coster_sumo.metrics).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from coster_sumo.converters.read import iter_scenes

from coster_sumo import metrics, weights
from coster_sumo.dataset import list_scenes, split
from coster_sumo.drivable import DrivableArea
from coster_sumo.prior.infer import load_prior
from coster_sumo.scene import load_scene, resample
from coster_sumo.snapshot import NoSnapshot, prior_snapshot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--womd", type=Path, nargs="*", default=[])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--all", action="store_true",
                    help="every scene of DATASET (a folder of held-out networks), not its held-out 10 %%")
    args = ap.parse_args()
    files = list_scenes(args.dataset)
    val = files if args.all else split(files, 0.1, 0)[1]
    picked = val[:: max(1, len(val) // args.scenes)][: args.scenes]  # evenly over the (sorted) networks
    scenes = [load_scene(p) for p in picked]
    for f in args.womd:
        scenes.extend(iter_scenes(f))
    model = weights.load_cached(weights.weights_path(weights.PRIOR), load_prior)
    table = {}
    for method in ("entropy", "last", "random"):
        rel, ang, ok = [], [], 0
        for i, scene in enumerate(scenes):
            low = resample(scene, 2.0)
            drivable = DrivableArea.from_road_map(scene.road_map)
            try:
                s = prior_snapshot(low, scene.sdc_index, np.random.default_rng(i), drivable, collision_time=method,
                                   seed=i, model=model)
            except NoSnapshot:
                continue
            ok += 1
            rel.append(float(metrics.relative_speed(s.target.velocity, s.adversary.velocity)))
            ang.append(float(metrics.impact_angle_deg(np.array([s.target.x, s.target.y]), s.target.yaw,
                                                      np.array([s.adversary.x, s.adversary.y]))))
        table[method] = {"scenes": len(scenes), "snapshots": ok, "SUR": ok / len(scenes),
                         "CSD": metrics.collision_speed_diversity(rel),
                         "CPD": metrics.collision_position_diversity(ang),
                         "CPD_circular": metrics.circular_std_deg(ang), "mean_relative_speed": float(np.mean(rel))}
    print("| collision time | scenes | SUR | CSD [m/s] | CPD [deg] | circular CPD [deg] | mean rel. speed [m/s] |")
    print("|---|---|---|---|---|---|---|")
    for m, r in table.items():
        print(f"| {m} | {r['scenes']} | {r['SUR']:.3f} | {r['CSD']:.2f} | {r['CPD']:.1f} | {r['CPD_circular']:.1f} | "
              f"{r['mean_relative_speed']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
