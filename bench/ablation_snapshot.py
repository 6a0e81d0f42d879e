"""Collision-time ablation of the snapshot stage: CSD and CPD for entropy / last / random, and the
adversaries' speeds at t_col against the traffic on their lane type (VDD at t_col), per network.

Usage: python bench/ablation_snapshot.py DATASET [--all] [--scenes N] [--womd FILE ...]
       [--methods entropy,last,random] [--draws K] [--models DIR] [--json OUT] [--plot OUT.png]
Held-out scenes of a `coster-sumo simulate` dataset (their SDC as target) plus optional WOMD files;
the shipped prior places the adversary; relative speed |v_target - v_adv| and impact angle (adversary
position in the target frame) of each snapshot feed CSD and CPD (coster_sumo.metrics). A scene's
network is its file name up to ``_r<run>``. VDD at t_col and its floor are those of ``eval scenarios``
(coster_sumo.batch.evaluate.snapshot_state_metrics), here on one snapshot per scene and rule, which
needs no SUMO run, so that a network can have hundreds of adversaries instead of twenty.
``--draws K`` places K adversaries per scene and rule (seeds i, i + N, ...; the collision time of
the entropy and last rules does not change between draws, the placement, speed and size do): more
adversaries per network lower the floor of VDD at t_col. The last three columns give a local reference
for the adversary's speed (VDD at t_col compares with every vehicle on the lane type, wherever it
is): how often the target moves at t_col, how many of the real vehicles within the prior's hidden
disc around it (15 m) stand, summed over the draws, and, over the disc's regions that real vehicles
other than the target occupy, how many of those stand against the prior's mean probability of the
stopped class there (adapted as the snapshot used it): whether the prior sees the standstill next
to the target at all. CSD and CPD use the first draw only; the
± after them is their bootstrap standard error (scenes resampled with replacement, ``BOOTSTRAP``
times).
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
from coster_sumo.converters.read import iter_scenes

from coster_sumo import metrics
from coster_sumo.batch.eval_metrics import snapshot_state_metrics
from coster_sumo.batch.evaluate import nominal_speeds_by_lane_type
from coster_sumo.batch.generator_summary import VariantRecord
from coster_sumo.core.scene import LaneType, Scene, resample
from coster_sumo.core.snapshot import AgentState
from coster_sumo.data.dataset import list_scenes, split
from coster_sumo.errors import NoSnapshot
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.infra import weights
from coster_sumo.method.collision_time import in_ellipse
from coster_sumo.method.snapshot import PlacementRequest, PriorMemo, prior_snapshot
from coster_sumo.prior.infer import load_prior, predict_scene

BOOTSTRAP = 500


def network_of(name: str) -> str:
    m = re.match(r"(.+?)_r\d+_", name)
    return m.group(1) if m else name


def stopped_near_moving(scene: Scene) -> tuple[int, int]:
    """(stopped, all) nominal vehicles inside the ellipse of a moving vehicle (the ellipse the snapshot
    places its adversary in), over the 2 Hz steps of a scene: the stopped share an adversary next
    to a moving target would have if it were drawn from the traffic around moving vehicles."""
    low = resample(scene, 2.0)
    tr = low.tracks
    speed = np.hypot(tr.vx, tr.vy)
    stopped = total = 0
    for t in range(low.num_steps):
        on = np.flatnonzero(tr.valid[:, t])
        for a in on[speed[on, t] >= 0.5]:
            others = on[on != a]
            inside = in_ellipse(np.stack([tr.x[others, t], tr.y[others, t]], -1), AgentState.from_tracks(tr, a, t))
            stopped += int(np.sum(speed[others[inside], t] < 0.5))
            total += int(inside.sum())
    return stopped, total


def plot_speeds(path: Path, nominal: dict[str, dict[str, np.ndarray]], records_by: dict[str, list[dict]]) -> None:
    """One panel per network: the share of nominal vehicles (every lane type) and of each rule's
    adversaries in speed classes (standstill, then 2 m/s steps), so that where VDD at t_col comes
    from can be seen."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = np.concatenate([[0.0, 0.5], np.arange(2.0, 42.0, 2.0)])  # [m/s]; the first class is a standstill
    fine = metrics.SPEED_BINS  # the nominal histograms' bins (0.5 m/s)
    nets = list(nominal)
    fig, axes = plt.subplots(1, len(nets), figsize=(4.2 * len(nets), 3.4), squeeze=False)
    for ax, net in zip(axes[0], nets, strict=True):
        hist = np.asarray(sum(nominal[net].values()), np.float64)
        coarse = np.array([hist[(fine[:-1] >= lo) & (fine[:-1] < hi)].sum() for lo, hi in zip(edges[:-1], edges[1:],
                                                                                            strict=True)])
        x = np.arange(len(coarse))
        ax.bar(x, coarse / max(coarse.sum(), 1.0), color="0.8", label="nominal traffic")
        for m, recs in records_by.items():
            adv = np.array([r["adversary_speed"] for r in recs if r["network"] == net])
            if len(adv):
                h, _ = np.histogram(np.clip(adv, 0, edges[-1] - 1e-6), bins=edges)
                ax.step(x, h / len(adv), where="mid", label=f"adversaries ({m})")
        ax.set_title(net)
        ax.set_xticks(x[::4], [f"{edges[i]:g}" for i in x[::4]])
        ax.set_xlabel("speed class from [m/s] (first: standing)")
    axes[0][0].set_ylabel("share")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--womd", type=Path, nargs="*", default=[])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--methods", default="entropy,last,random")
    ap.add_argument("--draws", type=int, default=1)
    ap.add_argument("--models", type=Path, default=None, help="models folder (default: the shipped one)")
    ap.add_argument("--plot", type=Path, default=None,
                    help="PNG: per network, the nominal speed distribution against the adversaries' at t_col")
    ap.add_argument("--all", action="store_true",
                    help="every scene of DATASET (a folder of held-out networks), not its held-out 10 %%")
    args = ap.parse_args()
    files = list_scenes(args.dataset)
    val = files if args.all else split(files, 0.1, 0)[1]
    picked = val[:: max(1, len(val) // args.scenes)][: args.scenes]  # evenly over the (sorted) networks
    scenes = [(network_of(p.stem), load_scene(p)) for p in picked]
    for f in args.womd:
        scenes.extend(("WOMD", s) for s in iter_scenes(f))
    model = weights.load_cached(weights.weights_path(weights.PRIOR, args.models), load_prior)
    nominal: dict[str, dict[str, np.ndarray]] = {}  # network -> lane type -> speed histogram
    for net, scene in scenes:
        for kind, hist in nominal_speeds_by_lane_type(scene).items():
            by = nominal.setdefault(net, {})
            by[kind] = by.get(kind, 0) + np.asarray(hist, np.float64)
    near_moving: dict[str, list[int]] = {}  # network -> [stopped, all] inside moving vehicles' ellipses
    for net, scene in scenes:
        st, n = stopped_near_moving(scene)
        near_moving.setdefault(net, [0, 0])[0] += st
        near_moving[net][1] += n
    table, per_network, records_by = {}, {}, {}
    for method in args.methods.split(","):
        rel, ang, records, ok = [], [], [], 0
        for i, (net, scene) in enumerate(scenes):
            low = resample(scene, 2.0)
            drivable = DrivableArea.from_road_map(scene.road_map)
            memo = PriorMemo()
            for d in range(args.draws):
                seed = i + d * len(scenes)
                try:
                    s = prior_snapshot(PlacementRequest(low, scene.sdc_index, np.random.default_rng(seed), drivable,
                                                        method, seed, memo=memo), model=model)
                except NoSnapshot:
                    continue
                if d == 0:
                    ok += 1
                    rel.append(float(metrics.relative_speed(s.target.velocity, s.adversary.velocity)))
                    ang.append(float(metrics.impact_angle_deg(np.array([s.target.x, s.target.y]), s.target.yaw,
                                                              np.array([s.adversary.x, s.adversary.y]))))
                kind = int(scene.road_map.lane_type_at(np.array([[s.adversary.x, s.adversary.y]]))[0])
                # the prior's probability of the stopped speed class in the region the adversary came
                # from, adapted to the scene's traffic as the snapshot used it
                at = (scene.sdc_index, s.t_index)
                pose = np.array([[low.tracks.x[at], low.tracks.y[at], low.tracks.heading[at]]])
                pred = predict_scene(model, memo.data, scene.sdc_index, steps=np.array([s.t_index]),
                                     heads=("speed",), pose=pose, calibrate=memo.adaptation or True)
                k = np.flatnonzero(pred.region_index[0] == s.region_id)
                p_stop = float(pred.probs["speed"][0, k[0], 0]) if len(k) else float("nan")
                # how much the scene's visible traffic moved the stopped class (1: not at all)
                class_w = memo.adaptation.class_weights if memo.adaptation is not None else {}
                w_stop = float(class_w["speed"][0]) if "speed" in class_w else float("nan")
                # the real vehicles around the target at t_col (within the prior's hidden disc): how
                # many of them stand, the local reference for the adversary's standstill share
                on = np.flatnonzero(low.tracks.valid[:, s.t_index])
                on = on[on != scene.sdc_index]
                near = np.hypot(low.tracks.x[on, s.t_index] - s.target.x,
                                low.tracks.y[on, s.t_index] - s.target.y) <= model.config.hide_radius
                near_speed = np.hypot(low.tracks.vx[on[near], s.t_index], low.tracks.vy[on[near], s.t_index])
                # the prior's P(stopped) where it places vehicles of the hidden disc that are really there
                # (other than the target), against how many of those stand: is it calibrated on
                # standstill next to the target, or does it miss the queues there too?
                occ = pred.query[0] & (pred.observed_agent[0] >= 0) & (pred.observed_agent[0] != scene.sdc_index)
                who = pred.observed_agent[0][occ]
                occ_speed = np.hypot(low.tracks.vx[who, s.t_index], low.tracks.vy[who, s.t_index])
                records.append({"network": net, "adversary_speed": s.adversary.speed, "p_stopped": p_stop,
                                "stopped_weight": w_stop, "target_speed": s.target.speed,
                                "near_target": int(near.sum()), "near_target_stopped": int(np.sum(near_speed < 0.5)),
                                "disc_occupied": int(occ.sum()), "disc_occupied_stopped": int(np.sum(occ_speed < 0.5)),
                                "disc_occupied_p_stopped": float(pred.probs["speed"][0][occ, 0].sum()),
                                "adversary_length": s.adversary.length, "adversary_width": s.adversary.width,
                                "adversary_lane_type": LaneType(kind).name})
        boot = np.random.default_rng(0).integers(0, len(rel), (BOOTSTRAP, len(rel)))  # scenes resampled
        rel_a, ang_a = np.asarray(rel), np.asarray(ang)
        table[method] = {"scenes": len(scenes), "snapshots": ok, "SUR": ok / len(scenes),
                         "CSD": metrics.collision_speed_diversity(rel),
                         "CSD_se": float(np.std([metrics.collision_speed_diversity(rel_a[b]) for b in boot])),
                         "CPD": metrics.collision_position_diversity(ang),
                         "CPD_se": float(np.std([metrics.collision_position_diversity(ang_a[b]) for b in boot])),
                         "relative_speeds": rel, "impact_angles": ang,
                         "CPD_circular": metrics.circular_std_deg(ang), "mean_relative_speed": float(np.mean(rel)),
                         "stopped_share": float(np.mean([r["adversary_speed"] < 0.5 for r in records]))}
        records_by[method] = records
        per_network[method] = {net: snapshot_state_metrics([VariantRecord.from_json(r) for r in records
                                                            if r["network"] == net], by)
                               for net, by in nominal.items()}
    print("| collision time | scenes | SUR | CSD [m/s] | CPD [deg] | circular CPD [deg] | mean rel. speed [m/s] | "
          "stopped adversaries |")
    print("|---|---|---|---|---|---|---|---|")
    for m, r in table.items():
        print(f"| {m} | {r['scenes']} | {r['SUR']:.3f} | {r['CSD']:.2f} ± {r['CSD_se']:.2f} | "
              f"{r['CPD']:.1f} ± {r['CPD_se']:.1f} | {r['CPD_circular']:.1f} | "
              f"{r['mean_relative_speed']:.2f} | {r['stopped_share']:.3f} |")
    print()
    print("| collision time | network | adversaries | VDD at t_col (floor) | sizes in class | "
          "stopped: nominal / near moving vehicles / prior's P(stopped) at the placed region / adversaries | "
          "p90 speed [m/s]: nominal / adversaries | stopped class's adaptation weight: median [quartiles] | "
          "target moving at t_col | vehicles within the hidden disc of the target at t_col: stopped / all | "
          "its occupied regions: stopped share / prior's mean P(stopped) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for m, nets in per_network.items():
        for net, r in nets.items():
            if r["VDD_tcol"] is None:
                continue
            hist = sum(nominal[net].values())  # every lane type; SPEED_BINS, the first is < 0.5 m/s
            p90 = metrics.SPEED_BINS[1 + int(np.searchsorted(np.cumsum(hist) / hist.sum(), 0.9))]
            mine = [x for x in records_by[m] if x["network"] == net]
            adv = np.array([x["adversary_speed"] for x in mine])
            p_stop = np.nanmean([x["p_stopped"] for x in mine])
            near = near_moving[net][0] / max(near_moving[net][1], 1)
            w = np.nanpercentile([x["stopped_weight"] for x in mine], [50, 25, 75])
            n_occupied = max(sum(x["disc_occupied"] for x in mine), 1)
            occupied_stopped = sum(x["disc_occupied_stopped"] for x in mine) / n_occupied
            occupied_p_stop = sum(x["disc_occupied_p_stopped"] for x in mine) / n_occupied
            print(f"| {m} | {net} | {len(adv)} | {r['VDD_tcol']:.3f} ({r['VDD_tcol_floor']:.3f}) | "
                  f"{r['size_in_class']:.3f} | {hist[0] / hist.sum():.2f} / {near:.2f} / {p_stop:.2f} / "
                  f"{np.mean(adv < 0.5):.2f} | "
                  f"{p90:.1f} / {np.percentile(adv, 90):.1f} | {w[0]:.2f} [{w[1]:.2f}, {w[2]:.2f}] | "
                  f"{np.mean([x['target_speed'] >= 0.5 for x in mine]):.2f} | "
                  f"{sum(x['near_target_stopped'] for x in mine)} / {sum(x['near_target'] for x in mine)} | "
                  f"{occupied_stopped:.2f} / {occupied_p_stop:.2f} |")
    if args.plot:
        plot_speeds(args.plot, nominal, records_by)
    if args.json:
        args.json.write_text(json.dumps({"table": table, "per_network": per_network,
                                         "stopped_near_moving": near_moving, "records": records_by,
                                         "nominal": {n: {k: np.asarray(h).tolist() for k, h in by.items()}
                                                     for n, by in nominal.items()}}, indent=1))


if __name__ == "__main__":
    main()
