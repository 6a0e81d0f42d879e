"""Benchmark: the traffic prior over a whole 91-step scene at 2 Hz (19 steps), batched vs per step.

What is timed: :func:`coster_sumo.prior.infer.predict_scene` around the target (the scene's SDC),
i.e. region construction and assignment, tokens of every step (regions within the model's
neighbourhood radius, 40 m, at most 256 nearest, of the target at that step) and one forward pass
with the 19 steps as the batch. The comparison loop prepares the scene once and then runs one
forward pass per step (tokens built per step as well), which is what an unbatched implementation
does. Weights are random (timing does not depend on them) unless --checkpoint is given.

Usage:
    python bench/bench_prior.py [--scene FILE] [--checkpoint models/prior.pt] [--repeat 5] [--threads 1]

FILE: a scene .npz, a WOMD .tfrecord or a ScenarioNet .pkl; default the synthetic four-way junction.
Prints the median wall time of each variant and their ratio (goal: batched <= 0.2 s).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from coster_sumo.core.scene import Scene
from coster_sumo.data import synthetic
from coster_sumo.prior.data import at_prior_rate, prepare_scene, scene_tokens
from coster_sumo.prior.infer import load_prior, predict_scene, predict_tokens
from coster_sumo.prior.model import PriorConfig, TrafficPrior

GOAL_S = 0.2


def _scene(path: str | None) -> Scene:
    if path is None:
        return synthetic.four_way_junction()
    from coster_sumo.converters.read import iter_scenes

    return next(iter(iter_scenes(path)))


def _median_time(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=None)
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--mode", choices=("context", "map"), default="context")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = load_prior(args.checkpoint) if args.checkpoint else TrafficPrior(PriorConfig()).eval()
    cfg = model.config
    scene = at_prior_rate(_scene(args.scene))
    target = scene.sdc_index if scene.sdc_index >= 0 else 0
    tr = scene.tracks
    steps = np.flatnonzero(tr.valid[target])

    def batched() -> None:
        predict_scene(model, scene, target, steps=steps, mode=args.mode, calibrate=False)

    def per_step() -> None:
        data = prepare_scene(scene, radius=cfg.radius, spacing=cfg.region_spacing, width=cfg.region_width,
                             crop=False)
        for t in steps:
            pose = np.array([[tr.x[target, t], tr.y[target, t], tr.heading[target, t]]])
            tok = scene_tokens(data, np.array([t]), pose, cfg,
                               visible=args.mode, hide_radius=cfg.hide_radius)
            predict_tokens(model, tok, only_query=True)

    pred = predict_scene(model, scene, target, steps=steps, mode=args.mode, calibrate=False)
    t_batched = _median_time(batched, args.repeat)
    t_loop = _median_time(per_step, args.repeat)
    print(f"scene {scene.scenario_id}: {len(steps)} steps at 2 Hz, {pred.mask.sum()} region tokens "
          f"({pred.mask.sum(axis=1).max()} max per step, radius {cfg.radius:.0f} m), torch threads {args.threads}")
    print(f"batched over steps : {t_batched * 1000:8.1f} ms  (goal <= {GOAL_S * 1000:.0f} ms: "
          f"{'met' if t_batched <= GOAL_S else 'NOT met'})")
    print(f"per-step loop      : {t_loop * 1000:8.1f} ms")
    print(f"ratio loop / batched: {t_loop / t_batched:.2f}x")


if __name__ == "__main__":
    main()
