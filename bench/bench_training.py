"""Benchmark: rollout CVAE training throughput [examples/s], the previous recipe vs the current one,
measured in one run (interleaved repeats: both see the same machine load).

- **previous**: the model code of ``--baseline-ref`` (read from git; default the commit this
  work started from), the inputs of every batch built from the scenes
  (:meth:`~coster_sumo.rollout.data.ExampleSet.batch`), batch 64, one torch thread;
- **current**: this checkout's model, inputs read from the memory-mapped feature cache
  (:mod:`coster_sumo.rollout.cache`) with the next batch assembled by a background thread,
  batch 256, one torch thread per core (the training default); also timed with one torch thread
  (``current-1t``), which shows what the extra threads give on the machine as loaded now;
- **current-bf16**: the current recipe with ``--precision bf16`` (the forward pass under CPU
  autocast to bfloat16, weights and optimiser in float32).

What is timed: ``--steps`` optimiser steps of the training loop (batch inputs, forward, backward,
gradient clipping, AdamW), examples / wall seconds; both recipes start from the same weights. The
width and every other model setting are the shipped model's (``models/rollout.pt``, width 256 since 2026-11-24).
Building the scenes' examples (previous) and the feature cache (current) happen once before the
timing and are reported separately.

The traffic prior (``coster-sumo train prior``, unchanged) is timed the same way unless
``--no-prior``, as an experiment: **in-line** builds the tokens of each batch in the loop (what its
training does), **background** in the background thread (:func:`coster_sumo.infra.prefetch.prefetch`);
both at its training defaults (batch 32, one thread, default model) on up to 40 training scenes.

Usage:
    python bench/bench_training.py --data DATASET [--repeats 5] [--steps 3] [--profile] [--flops] [--width W]
                                   [--batch B] [--no-prior]

DATASET: a dataset folder (``coster-sumo simulate ... -o DATASET``); its training split is used.
``--profile`` also prints where the current recipe's step spends its time (torch.profiler).
``--flops`` counts the matrix-product work of one bf16 training step per example
(``torch.utils.flop_counter``: forward and backward), times a bf16 matrix product with the same
threads, and prints the throughput that work allows at that rate: the ceiling of any recipe that
keeps the model, whatever the data path. ``--width W`` times a fresh model of width ``W`` instead of
the shipped width (the other settings stay the shipped model's); ``--batch B`` sets the current
recipes' batch size.
Goal: >= 2000 examples/s for the current recipe on a 2-core machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as `coster-sumo train rollout` (set before torch loads)

import argparse  # noqa: E402 (after the environment)
import dataclasses
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np
import torch

from coster_sumo.infra import weights
from coster_sumo.infra.devices import cpu_description
from coster_sumo.infra.prefetch import prefetch
from coster_sumo.rollout import model as current_model
from coster_sumo.rollout.cache import cached_examples
from coster_sumo.rollout.checkpoint import load_model
from coster_sumo.rollout.train import TrainConfig, _tensors, load_examples, num_threads, split_scene_files

GOAL = 2000.0
BASELINE_REF = "6ac392f"  # the branch point of the fast-training work


def previous_model_module(ref: str) -> types.ModuleType | None:
    """coster_sumo/rollout/model.py as of git ``ref`` (None when git or the ref is unavailable)."""
    root = Path(__file__).resolve().parent.parent
    try:
        src = subprocess.run(["git", "show", f"{ref}:coster_sumo/rollout/model.py"], cwd=root, check=True,
                             capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    mod = types.ModuleType("previous_rollout_model")
    sys.modules[mod.__name__] = mod  # dataclasses look their module up
    exec(compile(src, f"{ref}:coster_sumo/rollout/model.py", "exec"), mod.__dict__)  # noqa: S102 (our own history)
    return mod


def quartiles(xs: list[float]) -> tuple[float, float, float]:
    q1, q2, q3 = np.percentile(xs, [25, 50, 75])
    return float(q1), float(q2), float(q3)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="dataset folder")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--steps", type=int, default=3, help="optimiser steps per timed window")
    ap.add_argument("--baseline-ref", default=BASELINE_REF, help="git ref of the previous model code")
    ap.add_argument("--cache-dir", default=None,
                    help="feature cache root (default: the training default, DATASET/.cache; 'temp': a new "
                         "temporary folder, to time the build)")
    ap.add_argument("--profile", action="store_true", help="profile one step of the current recipe")
    ap.add_argument("--flops", action="store_true",
                    help="count the matrix-product work per example and print the throughput it allows")
    ap.add_argument("--width", type=int, default=None, help="time a model of this width (default: the shipped one)")
    ap.add_argument("--batch", type=int, default=None,
                    help="batch size of the current recipes (default: the training default)")
    ap.add_argument("--no-prior", action="store_true", help="skip the prior")
    ap.add_argument("--prior-steps", type=int, default=4, help="prior optimiser steps per timed window")
    args = ap.parse_args()

    cfg = load_model(weights.weights_path(weights.ROLLOUT)).cfg
    if args.width:
        cfg = dataclasses.replace(cfg, hidden=args.width)
    cores = num_threads(0)
    new_t = TrainConfig(batch_size=args.batch) if args.batch else TrainConfig()
    old_bs, old_threads = 64, 1
    train_paths, _ = split_scene_files(args.data, 0.1, 0)
    print(f"model: shipped config, width {cfg.hidden}, heads {cfg.heads}, latent {cfg.latent}; "
          f"{len(train_paths)} training scenes; {cores} cores; torch {torch.__version__}")

    t0 = time.perf_counter()
    fresh = load_examples(train_paths, cfg, new_t.min_steps)
    t_fresh = time.perf_counter() - t0
    tmp = tempfile.TemporaryDirectory(prefix="bench-training-")
    root = Path(tmp.name) if args.cache_dir == "temp" else Path(args.cache_dir) if args.cache_dir else None
    t0 = time.perf_counter()
    cached = cached_examples(train_paths, cfg, new_t.min_steps, root=root)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    cached = cached_examples(train_paths, cfg, new_t.min_steps, root=root)
    t_reopen = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in cached.folder.iterdir())
    print(f"examples: {len(fresh)}; previous: scenes loaded and cut in {t_fresh:.1f} s; current: feature cache "
          f"{cached.folder} built (or found) in {t_build:.1f} s ({size / 1e6:.0f} MB, "
          f"{size / max(len(cached), 1) / 1e3:.1f} kB/example), reopened in {t_reopen:.2f} s")

    prev_mod = previous_model_module(args.baseline_ref)
    if prev_mod is None:
        print(f"note: git ref {args.baseline_ref} unavailable: the previous recipe runs the current model code")
        prev_mod = current_model
    torch.manual_seed(0)
    new_model = current_model.RolloutCVAE(cfg)
    old_model = prev_mod.RolloutCVAE(cfg)
    old_model.load_state_dict(new_model.state_dict())
    old_opt = torch.optim.AdamW(old_model.parameters(), lr=5e-4, weight_decay=new_t.weight_decay)
    new_opt = torch.optim.AdamW(new_model.parameters(), lr=new_t.lr, weight_decay=new_t.weight_decay)
    rng = np.random.default_rng(0)

    def train_steps(model, opt, batches, bf16: bool = False) -> int:  # type: ignore[no-untyped-def]
        n = 0
        for ctx, traj, mask in batches:
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):  # as train rollout --precision bf16
                res = model(ctx, traj, mask)
            opt.zero_grad(set_to_none=True)
            res.loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), new_t.grad_clip)
            opt.step()
            n += len(traj)
        return n

    def previous(steps: int) -> float:
        torch.set_num_threads(old_threads)
        rows = rng.permutation(len(fresh))[: old_bs * steps]
        t = time.perf_counter()
        n = train_steps(old_model, old_opt, (_tensors(fresh.batch(rows[i:i + old_bs], cfg))
                                             for i in range(0, len(rows), old_bs)))
        return n / (time.perf_counter() - t)

    def current(steps: int, threads: int = cores, bf16: bool = False) -> float:
        torch.set_num_threads(threads)
        bs = new_t.batch_size
        rows = rng.permutation(len(cached))[: bs * steps]
        t = time.perf_counter()
        n = train_steps(new_model, new_opt, prefetch(lambda part: _tensors(cached.batch(part, cfg)),
                                                     [rows[i:i + bs] for i in range(0, len(rows), bs)]), bf16)
        return n / (time.perf_counter() - t)

    previous(1)  # warm-up (allocator, first-call costs)
    current(1)
    current(1, bf16=True)
    res: dict[str, list[float]] = {"previous": [], "current": [], "current-1t": [], "current-bf16": []}
    for r in range(args.repeats):
        res["previous"].append(previous(args.steps))
        res["current"].append(current(args.steps))
        res["current-1t"].append(current(args.steps, 1))
        res["current-bf16"].append(current(args.steps, bf16=True))
        print(f"  repeat {r + 1}/{args.repeats}: previous {res['previous'][-1]:.0f}, current {res['current'][-1]:.0f}, "
              f"current-1t {res['current-1t'][-1]:.0f}, current-bf16 {res['current-bf16'][-1]:.0f} examples/s",
              flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nCVAE training throughput, width {cfg.hidden} ({args.repeats} interleaved repeats of {args.steps} "
          f"steps; load average {load:.1f}; CPU: {cpu_description()}):")
    print("recipe      batch threads  examples/s: median [q1, q3]")
    for name, bs, th in (("previous", old_bs, old_threads), ("current", new_t.batch_size, cores),
                         ("current-1t", new_t.batch_size, 1), ("current-bf16", new_t.batch_size, cores)):
        q1, q2, q3 = quartiles(res[name])
        print(f"{name:11s} {bs:5d} {th:7d}  {q2:8.0f} [{q1:.0f}, {q3:.0f}]")
    ratio = float(np.median(res["current"]) / np.median(res["previous"]))
    ratios = [c / p for c, p in zip(res["current"], res["previous"], strict=True)]
    rq1, _, rq3 = quartiles(ratios)
    ratio1 = float(np.median(res["current-1t"]) / np.median(res["previous"]))
    print(f"ratio current-1t / previous (same thread count): {ratio1:.2f}x")
    print(f"ratio current / previous: {ratio:.2f}x (per-repeat ratios: quartiles {rq1:.2f}-{rq3:.2f}); "
          f"goal {GOAL:.0f} examples/s: {'met' if np.median(res['current']) >= GOAL else 'NOT met'}")
    best = float(np.median(res["current-bf16"]))
    print(f"ratio current-bf16 / previous: {best / np.median(res['previous']):.2f}x, current-bf16 / current: "
          f"{best / np.median(res['current']):.2f}x; goal {GOAL:.0f} examples/s with bf16: "
          f"{'met' if best >= GOAL else 'NOT met'}")

    if args.profile:
        from torch.profiler import ProfilerActivity, profile

        torch.set_num_threads(cores)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            current(2)
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=20))
    if args.flops:
        flops_ceiling(new_model, cached, cfg, new_t.batch_size, cores, float(np.median(res["current-bf16"])))
    tmp.cleanup()
    if not args.no_prior:
        bench_prior(args)
    return 0


def matmul_rate(threads: int, repeats: int = 40) -> float:
    """FLOP/s of a 2048x512 by 512x512 bf16 matrix product on ``threads`` threads (best of 5 windows)."""
    torch.set_num_threads(threads)
    a, b = torch.randn(2048, 512, dtype=torch.bfloat16), torch.randn(512, 512, dtype=torch.bfloat16)
    for _ in range(5):
        a @ b
    best = 0.0
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(repeats):
            a @ b
        best = max(best, 2 * 2048 * 512 * 512 * repeats / (time.perf_counter() - t))
    return best


def flops_ceiling(model, cached, cfg, batch_size: int, cores: int, measured: float) -> None:  # type: ignore[no-untyped-def]
    """Print the matrix-product work per training example and the throughput it allows."""
    from torch.utils.flop_counter import FlopCounterMode

    ctx, traj, mask = _tensors(cached.batch(np.arange(min(batch_size, len(cached))), cfg))
    counter = FlopCounterMode(display=False)
    with counter:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            res = model(ctx, traj, mask)
        res.loss.backward()
    model.zero_grad(set_to_none=True)
    per_example = counter.get_total_flops() / len(traj)
    parts = {}
    for name, fn in (("forward", lambda: model(ctx, traj, mask)), ("encode", lambda: model.encode(ctx))):
        counter = FlopCounterMode(display=False)
        with counter, torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
            fn()
        parts[name] = counter.get_total_flops()
    rate = matmul_rate(cores)
    print(f"\nmatrix-product work of one bf16 training step (forward and backward), width {cfg.hidden}: "
          f"{per_example / 1e6:.0f} MFLOP per example; of the forward pass's, the context encoding (map chunks, "
          f"neighbours of every step: once per example) is {parts['encode'] / parts['forward']:.0%}, the step loop "
          f"the rest")
    print(f"bf16 matrix product (2048x512 @ 512x512) on {cores} thread(s): {rate / 1e9:.0f} GFLOP/s; "
          f"at that rate the work allows at most {rate / per_example:.0f} examples/s")
    print(f"current-bf16 at {measured:.0f} examples/s does {measured * per_example / 1e9:.0f} GFLOP/s of it "
          f"({measured * per_example / rate:.0%} of the product's rate); goal {GOAL:.0f} examples/s needs "
          f"{GOAL * per_example / 1e9:.0f} GFLOP/s")


def bench_prior(args: argparse.Namespace) -> None:
    from coster_sumo.prior.data import batch_tokens, load_prepared, split_files
    from coster_sumo.prior.model import PriorConfig, TrafficPrior
    from coster_sumo.prior.train import TrainConfig as PriorTrainConfig
    from coster_sumo.prior.train import _torch_batch

    tcfg = PriorTrainConfig()
    torch.set_num_threads(tcfg.threads)
    files, _ = split_files(args.data, 0.1)
    scenes = load_prepared(files[:40])
    cfg = PriorConfig()
    torch.manual_seed(0)
    model = TrafficPrior(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=tcfg.lr, weight_decay=tcfg.weight_decay)
    rng = np.random.default_rng(0)
    samples = np.concatenate([np.stack([np.full(len(d.centres), i), np.arange(len(d.centres))], -1)
                              for i, d in enumerate(scenes) if len(d.centres)])
    bs = tcfg.batch_size

    def run(background: bool) -> float:
        rows = samples[rng.permutation(len(samples))[: bs * args.prior_steps]]
        def make(i: int) -> tuple[torch.Tensor, ...]:
            return _torch_batch(batch_tokens(scenes, rows[i:i + bs], cfg,
                                             visible="random", rng=rng, hide_radius=cfg.hide_radius))

        starts = range(0, len(rows), bs)
        t = time.perf_counter()
        batches = prefetch(make, starts) if background else (make(i) for i in starts)
        n = 0
        for batch in batches:
            _, loss = model(*batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), tcfg.grad_clip)
            opt.step()
            n += len(batch[0])
        return n / (time.perf_counter() - t)

    run(False)
    run(True)
    res: dict[str, list[float]] = {"in-line": [], "background": []}
    for _ in range(args.repeats):
        res["in-line"].append(run(False))
        res["background"].append(run(True))
    print(f"\nprior training throughput ({len(scenes)} scenes, batch {bs}, {tcfg.threads} thread(s), "
          f"{args.repeats} interleaved repeats of {args.prior_steps} steps):")
    print("recipe      examples/s: median [q1, q3]")
    for name in ("in-line", "background"):
        q1, q2, q3 = quartiles(res[name])
        print(f"{name:11s} {q2:8.0f} [{q1:.0f}, {q3:.0f}]")
    print(f"ratio background / in-line: {np.median(res['background']) / np.median(res['in-line']):.2f}x")


if __name__ == "__main__":
    raise SystemExit(main())
