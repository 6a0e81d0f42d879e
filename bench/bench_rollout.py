"""Benchmark: oversampling 1000 adversary trajectories for one collision snapshot, batched vs a loop.

What is timed: :func:`coster_sumo.rollout.sample.sample_trajectories` for one snapshot, i.e. the
context (map chunks near the adversary, neighbours at every step) and one batched pass of the CVAE
with all N samples as the batch (goal: N = 1000 in <= 0.5 s). The comparison calls the same
function with ``n=1`` in a Python loop, which is what an unbatched implementation does, and the
ratio of the per-trajectory times is printed. The scene cache (map chunking) is built once
beforehand, as the pipeline does per scene. Also timed: K-means + vocabulary refinement
(:func:`~coster_sumo.rollout.sample.select_representatives`) of the 1000 samples.

The default scene is the synthetic four-way junction with extra agents copied in so that every step
has the full 32 neighbours (the most DSA work); weights are random (timing does not depend on
them) unless --checkpoint is given. The machine is shared: the run prints a matrix-product rate
measured in the same process, so that timings can be compared across loads.

Usage:
    python bench/bench_rollout.py [--scene FILE] [--checkpoint models/rollout.pt] [--samples 1000]
                                  [--vocab models/vocab.npz] [--hidden 256] [--loop 20] [--repeat 5]
                                  [--threads 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

import numpy as np
import torch

from coster_sumo.core.scene import Scene, Tracks, resample
from coster_sumo.core.snapshot import AgentState
from coster_sumo.data import synthetic
from coster_sumo.rollout import sample as S
from coster_sumo.rollout.data import build_cache
from coster_sumo.rollout.model import RolloutConfig, RolloutCVAE
from coster_sumo.rollout.vocab import MotionVocab, build_vocab


def busy_junction(extra: int = 40, seed: int = 0) -> Scene:
    """The synthetic four-way junction with ``extra`` copies of its agents, shifted by up to 40 m."""
    scene = synthetic.four_way_junction()
    tr = scene.tracks
    rng = np.random.default_rng(seed)
    src = rng.integers(0, tr.num_agents, extra)
    shift = rng.uniform(-40.0, 40.0, (extra, 2))
    fields = {}
    for f in dataclasses.fields(Tracks):
        v = getattr(tr, f.name)
        add = v[src]
        if f.name == "x":
            add = add + shift[:, :1]
        elif f.name == "y":
            add = add + shift[:, 1:]
        elif f.name == "ids":
            add = np.array([f"copy{i}" for i in range(extra)])
        fields[f.name] = np.concatenate([v, add])
    return dataclasses.replace(scene, tracks=Tracks(**fields)).validate()


def matmul_gflops() -> float:
    a, b = torch.randn(1000, 1024), torch.randn(1024, 768)
    a @ b
    t0 = time.perf_counter()
    for _ in range(10):
        a @ b
    return 10 * 2 * 1000 * 1024 * 768 / (time.perf_counter() - t0) / 1e9


def timed(fn, repeat: int) -> list[float]:  # type: ignore[no-untyped-def]
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=None, help="scene .npz / WOMD file (default: busy synthetic junction)")
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--vocab", default=None, help="motion vocabulary .npz (default: 384 tokens of random transitions)")
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--hidden", type=int, default=256, help="model width with random weights (%(default)s)")
    ap.add_argument("--no-dsa", action="store_true")
    ap.add_argument("--loop", type=int, default=20, help="calls of the n=1 loop (%(default)s)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (0 = torch default)")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.scene:
        from coster_sumo.converters.read import iter_scenes

        scene = next(iter(iter_scenes(args.scene)))
    else:
        scene = busy_junction()
    low = resample(scene, 2.0)
    if args.checkpoint:
        from coster_sumo.rollout.checkpoint import load_model

        model = load_model(args.checkpoint)
    else:
        torch.manual_seed(0)
        model = RolloutCVAE(RolloutConfig(hidden=args.hidden, use_dsa=not args.no_dsa)).eval()
    target = max(scene.sdc_index, 0)
    t_index = min(low.num_steps - 5, 14)
    tgt = AgentState.from_tracks(low.tracks, target, t_index)
    adv = AgentState(tgt.x - 4.0 * np.sin(tgt.yaw), tgt.y + 4.0 * np.cos(tgt.yaw), tgt.yaw - 0.4, 8.0, 4.6, 1.9)
    snap = (adv, t_index)
    cache = build_cache(low, model.cfg)
    n = args.samples
    gflops = matmul_gflops()

    def batched() -> np.ndarray:
        return S.sample_trajectories(model, low, snap, n=n, seed=0, cache=cache)

    trajs = batched()  # warm-up
    t_batch = timed(batched, args.repeat)

    def loop() -> None:
        for i in range(args.loop):
            S.sample_trajectories(model, low, snap, n=1, seed=i, cache=cache)

    loop()
    t_loop = timed(loop, max(1, args.repeat // 2))
    if args.vocab:
        vocab = MotionVocab.load(args.vocab)
    else:  # transitions of varied speed, drift and turn rate
        rng = np.random.default_rng(0)
        vocab = build_vocab(np.stack([rng.uniform(0, 12, 20_000), rng.normal(0, 0.3, 20_000),
                                      rng.normal(0, 0.1, 20_000)], -1), size=384)
    others = S.others_from_scene(low, t_index, trajs.shape[1] - 1)

    def select() -> None:
        S.select_representatives(trajs, 5, 0, vocab, None, others, size=(4.6, 1.9))

    select()  # warm-up (imports scikit-learn)
    t_select = timed(select, args.repeat)
    cfg = model.cfg
    med_b = statistics.median(t_batch)
    per_b = med_b / n
    per_l = statistics.median(t_loop) / args.loop
    params = sum(p.numel() for p in model.parameters())
    print(f"scene {low.scenario_id}: {low.tracks.num_agents} agents, {len(low.road_map.lanes)} lanes, "
          f"{len(cache.chunk_pts)} map chunks; horizon {trajs.shape[1] - 1} steps")
    print(f"model: hidden {cfg.hidden}, heads {cfg.heads}, DSA {cfg.use_dsa}, map every step {cfg.map_every_step}, "
          f"{params / 1e6:.2f} M parameters; torch {torch.__version__}, {torch.get_num_threads()} thread(s), "
          f"matmul {gflops:.0f} GFLOP/s now, load average {os.getloadavg()[0]:.1f}")
    print(f"batched: {n} samples in {med_b:.3f} s median (min {min(t_batch):.3f}, {args.repeat} runs) "
          f"= {1e3 * per_b:.3f} ms per trajectory")
    print(f"loop of n=1: {1e3 * per_l:.2f} ms per trajectory ({args.loop} calls)")
    print(f"ratio loop / batched per trajectory: {per_l / per_b:.1f}x")
    print(f"select_representatives (K-means K=5 + vocabulary {len(vocab)} tokens + overlap checks): "
          f"{statistics.median(t_select):.3f} s")
    print(f"goal <= 0.5 s for 1000 samples: {'met' if med_b * 1000 / n <= 0.5 else 'NOT met'}")


if __name__ == "__main__":
    main()
