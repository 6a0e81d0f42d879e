"""Training of the rollout CVAE: ``coster-sumo train rollout --data DATASET -o models/rollout.pt``.

Examples: every agent of the model's class (``RolloutConfig.agent_class``, ``--agent-class``:
vehicles by default, or pedestrians, or cyclists) of every scene (resampled to 2 Hz) at every t_rev with at least
``min_steps`` valid steps before it, the horizon ``min(max_horizon, t_rev)`` (shorter segments are
masked: the model learns the adaptive horizon). Scenes are split into training and held-out sets
by :func:`coster_sumo.data.dataset.split` (hash of the file name), never examples of one scene across
both.

Deterministic per seed (same thread count): the model initialisation, the example order and the
latent noise of epoch ``e`` depend only on ``(seed, e)``. After every epoch the checkpoint
(``OUT``), the metrics (``OUT`` with suffix ``.json``) and a training state (``OUT.state``:
weights, optimiser state, history) are written atomically. Rerunning the same command resumes from
the state (``--restart`` ignores it), also to more epochs than first asked for, and gives the same
weights as an uninterrupted run (on the same thread count); a state from other data or settings is
an error that names them.

Speed (the recipe since the fast-training change; see ``bench/bench_training.py``): the inputs of
every example are built once per corpus into memory-mapped arrays (:mod:`coster_sumo.rollout.cache`,
in ``DATASET/.cache`` unless ``--cache-dir``; ``--no-cache`` builds them per batch as before), the
next batch is assembled by a background thread while the current one trains, torch uses every core
(``--threads 0``) and batches are larger (256). The larger batch takes a larger learning rate
(1e-3 = 5e-4 x sqrt(256 / 64)) reached by a linear warm-up over the first ``warmup_steps`` steps;
``--batch-size 64 --lr 5e-4 --warmup-steps 0 --threads 1`` is the previous recipe.

``--precision bf16`` runs the training forward pass under CPU autocast to bfloat16: on CPUs with
AVX-512 BF16 or AMX matrix products run several times faster, while the weights, the gradients,
the optimiser state, the integrated pose, the latent statistics and the KL stay float32, and
validation runs in float32. On a CPU without them bfloat16 runs in software, several times slower
than float32: the run prints a warning line (:func:`coster_sumo.infra.devices.slow_bf16_warning`) and
trains anyway. Not the default: the shipped checkpoints were trained in float32, and a run resumes
only in the precision it started in. The metrics record the CPU (``cpu``) next to the device.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import platform
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.devices import cpu_description, device_name, slow_bf16_warning, training_device
from coster_sumo.infra.prefetch import prefetch
from coster_sumo.rollout.cache import CachedExamples, cached_examples
from coster_sumo.rollout.checkpoint import atomic_torch_save, load_checkpoint, read_torch_file, save_checkpoint
from coster_sumo.rollout.config import FREE_ON_INIT
from coster_sumo.rollout.data import ExampleSet, build_examples, to_tensors
from coster_sumo.rollout.evaluate import cvae_errors
from coster_sumo.rollout.model import RolloutConfig, RolloutCVAE
from coster_sumo.rollout.records import ElboTerms, EpochRecord, RolloutTrainingState

PRECISIONS = ("fp32", "bf16")


@dataclass
class TrainConfig:
    """Optimisation settings (``coster-sumo train rollout --help``).

    Attributes:
        epochs: passes over the training examples (or ``examples_per_epoch`` of them).
        batch_size: contexts per step.
        lr, weight_decay, grad_clip: AdamW and gradient-norm clipping.
        warmup_steps: the learning rate rises linearly from ``lr / warmup_steps`` to ``lr`` over the
            first optimiser steps of the run (0: constant ``lr``).
        seed: drives everything random.
        val_fraction: share of scene files held out.
        examples_per_epoch: 0 = all training examples every epoch; else a seeded subset per epoch.
        min_steps: [2 Hz steps] least valid past for an example.
        eval_samples: samples per context for minADE / minFDE.
        max_val_examples: held-out examples scored per epoch (seeded subset).
        threads: torch CPU threads (0 = one per core). The same seed and thread count give the
            same weights; a run may be resumed on another thread count (then it is no longer
            bit-identical to an uninterrupted one).
        lr_drop_epoch: from this epoch on (1-based) the learning rate is ``lr x lr_drop_factor``
            (0: never). A run at a constant rate whose held-out error has stopped falling but
            jumps from epoch to epoch is resumed with a drop after its last epoch: a drop that
            only concerns epochs not yet run is not a change of the run's settings (see
            :func:`resume_conflicts`).
        lr_drop_factor: see ``lr_drop_epoch``.
        precision: "fp32", or "bf16": the training forward pass and loss run under CPU autocast
            to bfloat16 (matrix products in bfloat16; weights, gradients and the optimiser state
            stay float32; validation in float32). On CPUs with AVX-512 BF16 the matrix products
            run about 4.7x faster (docs and numbers: ``bench/RESULTS.md``, training throughput).
        init: "" (weights drawn from ``seed``), or the sha256 of the checkpoint whose weights the run
            starts from (:func:`train_rollout`'s ``init``): a continuation of a finished run whose
            training state is gone, or fine-tuning shipped weights on other traffic. The optimiser
            starts afresh (the warm-up applies again).
    """

    epochs: int = 20
    batch_size: int = 256
    lr: float = 1e-3
    warmup_steps: int = 50
    weight_decay: float = 1e-5
    grad_clip: float = 5.0
    seed: int = 0
    val_fraction: float = 0.1
    examples_per_epoch: int = 20_000
    min_steps: int = 2
    eval_samples: int = 5
    max_val_examples: int = 500
    threads: int = 0
    lr_drop_epoch: int = 0
    lr_drop_factor: float = 0.1
    precision: str = "fp32"
    init: str = ""


def split_scene_files(data: str | Path, val_fraction: float, seed: int) -> tuple[list[Path], list[Path]]:
    """Training and held-out scene files of a dataset folder (see :mod:`coster_sumo.data.dataset`)."""
    from coster_sumo.data.dataset import list_scenes, split

    paths = list_scenes(data)
    if not paths:
        raise InputError(f"{data}: no scenes (expected DATASET/scenes/*.npz)")
    train, val = split(paths, val_fraction, seed=0)  # the split is a property of the dataset, not of a run
    if not train:  # tiny datasets: keep at least one training scene
        train, val = val[:1], val[1:]
    return train, val


Examples = ExampleSet | CachedExamples


def load_examples(paths: Sequence[Path], cfg: RolloutConfig, min_steps: int, quiet: bool = True,
                  what: str = "scenes") -> ExampleSet:
    scenes = (load_scene(p) for p in tqdm(paths, desc=f"loading {what}", disable=quiet, leave=False))
    return build_examples(scenes, cfg, min_steps=min_steps)


def load_cached_examples(paths: Sequence[Path], cfg: RolloutConfig, min_steps: int, cache_dir: str | Path | None,
                         quiet: bool = True, what: str = "scenes") -> CachedExamples:
    """The examples of ``paths`` from their feature cache (built on first use, see
    :mod:`coster_sumo.rollout.cache`)."""
    def progress(it, total):  # type: ignore[no-untyped-def]
        return tqdm(it, total=total, desc=f"encoding {what} (once)", disable=quiet, leave=False)

    return cached_examples(paths, cfg, min_steps, root=cache_dir, progress=progress)


def num_threads(requested: int) -> int:
    """``requested`` torch threads, 0 = one per core available to this process."""
    if requested > 0:
        return requested
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def learning_rate(step: int, tcfg: TrainConfig, epoch: int = 0) -> float:
    """The learning rate of optimiser step ``step`` (0-based, counted over the whole run) in
    ``epoch`` (0-based)."""
    if tcfg.warmup_steps > 0 and step < tcfg.warmup_steps:
        return tcfg.lr * (step + 1) / tcfg.warmup_steps
    if 0 < tcfg.lr_drop_epoch <= epoch + 1:
        return tcfg.lr * tcfg.lr_drop_factor
    return tcfg.lr


# TrainConfig fields that may differ between a training state and the command that resumes it.
# The thread count changes only the order of floating-point sums: a run resumed on another
# number of threads (or another machine) goes on, but is no longer bit-identical to one that was
# never interrupted.
_FREE_ON_RESUME = ("epochs", "lr_drop_epoch", "lr_drop_factor", "threads")


def resume_conflicts(saved: dict[str, Any], now: TrainConfig, epochs_done: int) -> list[str]:
    """The settings in which a training state with settings ``saved`` that ran ``epochs_done``
    epochs differs from what ``now`` would have done up to there, as ``name saved -> now``. Free
    to differ: the number of epochs, the thread count, and a learning-rate drop that neither of
    them had reached by then (both schedules agree so far). Empty: the state can be resumed."""
    saved = {"warmup_steps": 0, "lr_drop_epoch": 0, "lr_drop_factor": 0.1, "precision": "fp32", "init": "",
             **saved}  # older states
    cur = dataclasses.asdict(now)
    out = [f"{k} {saved.get(k)!r} -> {v!r}" for k, v in cur.items()
           if k not in _FREE_ON_RESUME and saved.get(k) != v]
    drops = [(int(t["lr_drop_epoch"]), float(t["lr_drop_factor"])) for t in (saved, cur)]
    if drops[0] != drops[1] and not all(e == 0 or e > epochs_done for e, _ in drops):
        out.append(f"learning-rate drop (epoch, factor) {drops[0]} -> {drops[1]}, "
                   f"after {epochs_done} epochs had run")
    return out


def _epoch_rows(n: int, tcfg: TrainConfig, epoch: int) -> np.ndarray:
    rng = np.random.default_rng([tcfg.seed, epoch])
    order = rng.permutation(n)
    if tcfg.examples_per_epoch > 0:
        order = order[: tcfg.examples_per_epoch]
    return order


def _tensors(batch: dict[str, np.ndarray], device: torch.device | str = "cpu"
             ) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    t = to_tensors(batch, device)
    traj, mask = t.pop("traj"), t.pop("step_mask")
    t.pop("origin")
    return t, traj, mask


@torch.no_grad()
def validation_loss(model: RolloutCVAE, examples: Examples, rows: np.ndarray, batch_size: int, seed: int
                    ) -> ElboTerms:
    """Posterior ELBO terms on ``rows`` (per valid step, averaged over examples)."""
    model.eval()
    gen = torch.Generator().manual_seed(seed)
    loss = recon = kl = 0.0
    count = 0
    for start in range(0, len(rows), batch_size):
        ctx, traj, mask = _tensors(examples.batch(rows[start:start + batch_size], model.cfg), model.device)
        out = model(ctx, traj, mask, generator=gen)
        k = len(traj)
        assert out.loss is not None and out.recon is not None and out.kl is not None
        loss += float(out.loss) * k
        recon += float(out.recon) * k
        kl += float(out.kl) * k
        count += k
    n = max(count, 1)
    return ElboTerms(loss=loss / n, recon=recon / n, kl=kl / n)


def state_path(out: Path) -> Path:
    """The training state beside checkpoint ``out``."""
    return out.with_name(out.name + ".state")


def _metrics_path(out: Path) -> Path:
    return out.with_suffix(".json")


@dataclass(frozen=True)
class _Run:
    """What every epoch of one :func:`train_rollout` call reads: the settings, where the model trains,
    the example sets and the held-out rows it scores (``val_rows`` for the ELBO, ``ade_rows``, full
    horizon only, for minADE / minFDE)."""

    data: str  # the dataset folder, resolved
    out: Path
    cfg: RolloutConfig
    tcfg: TrainConfig
    dev: torch.device
    train_paths: list[Path]
    val_paths: list[Path]
    train_set: Examples
    val_set: Examples
    val_rows: np.ndarray
    ade_rows: np.ndarray
    init: str | Path | None
    command: str | None
    cpu: str
    t_start: float
    quiet: bool


def _start_weights(init: str | Path, cfg: RolloutConfig, tcfg: TrainConfig
                   ) -> tuple[dict[str, torch.Tensor], TrainConfig]:
    """The weights of checkpoint ``init`` and ``tcfg`` with its sha256; a checkpoint of other model
    settings (but for :data:`FREE_ON_INIT`) is refused before any data is read."""
    start, _ = load_checkpoint(init)
    want, have = cfg.to_dict(), start.cfg.to_dict()
    diff = sorted(k for k, v in want.items() if have.get(k) != v and k not in FREE_ON_INIT)
    if diff:
        raise InputError(f"{init}: its model settings differ from this run's ({', '.join(diff)}); "
                         "give the same --hidden/--heads/--latent/--no-dsa/... as it was trained with")
    with open(init, "rb") as f:
        return start.state_dict(), dataclasses.replace(tcfg, init=hashlib.file_digest(f, "sha256").hexdigest())


def _example_sets(train_paths: list[Path], val_paths: list[Path], cfg: RolloutConfig, tcfg: TrainConfig,
                  cache: bool, cache_dir: str | Path | None, quiet: bool) -> tuple[Examples, Examples]:
    """The training and held-out examples, from the feature cache or built in memory."""
    if not cache:
        return (load_examples(train_paths, cfg, tcfg.min_steps, quiet, "training scenes"),
                load_examples(val_paths, cfg, tcfg.min_steps, quiet, "held-out scenes"))
    train_set = load_cached_examples(train_paths, cfg, tcfg.min_steps, cache_dir, quiet, "training scenes")
    val_set = (load_cached_examples(val_paths, cfg, tcfg.min_steps, cache_dir, quiet, "held-out scenes")
               if val_paths else load_examples(val_paths, cfg, tcfg.min_steps))  # none held out: empty
    return train_set, val_set


def _scored_rows(val_set: Examples, cfg: RolloutConfig, tcfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """The held-out rows scored every epoch: a seeded subset for the ELBO and one of the examples
    with the full horizon for minADE / minFDE."""
    g = torch.Generator().manual_seed(tcfg.seed + 7919)
    val_rows = torch.randperm(len(val_set), generator=g).numpy()[: tcfg.max_val_examples]
    full = np.flatnonzero(val_set.index[:, 3] == cfg.max_horizon) if len(val_set) else np.zeros(0, np.int64)
    ade_rows = full[torch.randperm(len(full), generator=g).numpy()[: tcfg.max_val_examples]]
    return val_rows, ade_rows


def _resume(rpath: Path, run: _Run, model: RolloutCVAE, opt: torch.optim.Optimizer) -> tuple[list[EpochRecord], int]:
    """Load the training state ``rpath`` into ``model`` and ``opt``: its history and the epochs done.
    A state of other data or settings is an error that names them."""
    state = RolloutTrainingState.from_dict(read_torch_file(rpath))
    if state is None:
        raise InputError(f"{rpath}: not a rollout training state")
    conflicts = resume_conflicts(state.train_config, run.tcfg, state.epoch)
    if state.config != run.cfg.to_dict():
        conflicts.insert(0, "the model settings")
    if state.data != run.data:
        conflicts.insert(0, f"data {state.data} -> {run.data}")
    if conflicts:
        raise InputError(f"{rpath}: the run to resume used other data or settings ({'; '.join(conflicts)}); "
                         "start afresh with --restart (or write to another -o)")
    model.load_state_dict(state.model)
    opt.load_state_dict(state.optimizer)
    return list(state.history), state.epoch


def _train_epoch(run: _Run, model: RolloutCVAE, opt: torch.optim.Optimizer, epoch: int, steps_per_epoch: int
                 ) -> ElboTerms:
    """One pass over the epoch's training rows: the mean loss, reconstruction and KL per example."""
    tcfg, cfg, dev = run.tcfg, run.cfg, run.dev
    model.train()
    torch.manual_seed(tcfg.seed * 1_000_003 + epoch)
    rows = _epoch_rows(len(run.train_set), tcfg, epoch)
    batches = range(0, len(rows), tcfg.batch_size)
    loss = recon = kl = 0.0
    seen = 0
    # the next batch is assembled by a background thread while this one trains
    ahead = prefetch(lambda part: _tensors(run.train_set.batch(part, cfg), dev),
                     [rows[start:start + tcfg.batch_size] for start in batches])
    bar = tqdm(ahead, total=len(batches), desc=f"epoch {epoch + 1}/{tcfg.epochs}", disable=run.quiet, leave=False)
    for bi, (ctx, traj, mask) in enumerate(bar):
        for group in opt.param_groups:
            group["lr"] = learning_rate(epoch * steps_per_epoch + bi, tcfg, epoch)
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=tcfg.precision == "bf16"):
            res = model(ctx, traj, mask)
        assert res.loss is not None and res.recon is not None and res.kl is not None
        opt.zero_grad(set_to_none=True)
        res.loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), tcfg.grad_clip)
        opt.step()
        k = len(traj)
        loss += float(res.loss.detach()) * k
        recon += float(res.recon) * k
        kl += float(res.kl) * k
        seen += k
        bar.set_postfix(loss=f"{loss / seen:.3f}", kl=f"{kl / seen:.3f}")
    n = max(seen, 1)
    return ElboTerms(loss=loss / n, recon=recon / n, kl=kl / n)


def _epoch(run: _Run, model: RolloutCVAE, opt: torch.optim.Optimizer, epoch: int, steps_per_epoch: int
           ) -> EpochRecord:
    """Train ``epoch`` (0-based), then score the held-out ELBO terms and minADE / minFDE."""
    t_epoch = time.perf_counter()
    tcfg = run.tcfg
    train = _train_epoch(run, model, opt, epoch, steps_per_epoch)
    val = val_errors = None
    if len(run.val_rows):
        val = validation_loss(model, run.val_set, run.val_rows, tcfg.batch_size, tcfg.seed + epoch)
    if len(run.ade_rows):
        val_errors = cvae_errors(model, run.val_set, run.ade_rows, tcfg.eval_samples, seed=tcfg.seed,
                                 batch_size=tcfg.batch_size).errors
    return EpochRecord(epoch=epoch + 1, train=train, val=val, val_errors=val_errors,
                       time_s=time.perf_counter() - t_epoch)


def _save_epoch(run: _Run, model: RolloutCVAE, opt: torch.optim.Optimizer, history: list[EpochRecord]) -> None:
    """The checkpoint and the training state after the last epoch of ``history``."""
    entry = history[-1].to_json()
    epochs = history[-1].epoch
    meta = {"data": run.data, "epochs": epochs, "seed": run.tcfg.seed,
            "train_config": dataclasses.asdict(run.tcfg), "last": entry}
    save_checkpoint(model, run.out, meta=meta)
    state = RolloutTrainingState(epoch=epochs, model=model.state_dict(), optimizer=opt.state_dict(),
                                 config=run.cfg.to_dict(), train_config=dataclasses.asdict(run.tcfg), data=run.data,
                                 history=tuple(history))
    atomic_torch_save(state.to_dict(), state_path(run.out))


def _run_metrics(run: _Run, model: RolloutCVAE, history: list[EpochRecord]) -> dict[str, Any]:
    """The metrics of the run so far (written to ``OUT.json`` after every epoch)."""
    return {
        "format": "coster-sumo-rollout-metrics", "data": run.data,
        "scenes": {"train": len(run.train_paths), "val": len(run.val_paths)},
        "examples": {"train": len(run.train_set), "val": len(run.val_set), "val_scored": int(len(run.val_rows)),
                     "val_full_horizon_scored": int(len(run.ade_rows))},
        "config": run.cfg.to_dict(), "train_config": dataclasses.asdict(run.tcfg),
        "init": None if run.init is None else str(Path(run.init).resolve()),
        "parameters": sum(p.numel() for p in model.parameters()),
        "epochs": [e.to_json() for e in history], "final": history[-1].to_json(),
        "wall_time_s": time.perf_counter() - run.t_start, "torch": torch.__version__,
        "threads": torch.get_num_threads(), "machine": platform.machine(), "cpu": run.cpu,
        "device": device_name(run.dev),
        "command": run.command if run.command is not None else " ".join(sys.argv),
        "units": {"ADE/FDE": "m", "loss": "negative ELBO per valid step (nats)", "time_s": "s"},
    }


def train_rollout(data: str | Path, out: str | Path, cfg: RolloutConfig | None = None,
                  tcfg: TrainConfig | None = None, *, resume: bool = True, quiet: bool = False,
                  command: str | None = None, cache: bool = True, cache_dir: str | Path | None = None,
                  init: str | Path | None = None, device: str = "cpu") -> dict[str, Any]:
    """Train (or resume training) and write the checkpoint, metrics and resume file.

    ``cache``: read the examples from the feature cache (under ``cache_dir``, default
    ``DATASET/.cache``); False builds them per batch (slow; the same numbers).
    ``init``: a rollout checkpoint to start from instead of freshly drawn weights; its config must
    be ``cfg`` but for the settings in :data:`~coster_sumo.rollout.config.FREE_ON_INIT` (checked
    before any data is read). Its sha256 goes into ``tcfg.init``, so that a
    training state resumes only with the same starting weights.
    ``device``: where the model trains (:func:`coster_sumo.infra.devices.training_device`: "cpu", "cuda", "cuda:N" or
    "auto"); batches are assembled on the CPU and moved there. Checkpoints hold CPU tensors and
    training states are read onto the CPU, so a run started on one device resumes on another
    (with the same numbers only on the same device). Not part of ``tcfg``: it does not change the
    recipe. On a GPU ``--precision bf16`` autocasts there.

    Returns:
        The metrics dictionary also written to ``OUT.json``.
    """
    cfg = cfg or RolloutConfig()
    tcfg = tcfg or TrainConfig()
    if tcfg.precision not in PRECISIONS:
        raise InputError(f"precision {tcfg.precision!r}: use one of {', '.join(PRECISIONS)}")
    out = Path(out)
    dev = training_device(device)
    cpu = cpu_description()
    slow = slow_bf16_warning(dev, tcfg.precision)
    if slow:
        print(slow, file=sys.stderr)
    torch.set_num_threads(num_threads(tcfg.threads))
    t_start = time.perf_counter()
    start_weights = None
    if init is not None:
        start_weights, tcfg = _start_weights(init, cfg, tcfg)
    train_paths, val_paths = split_scene_files(data, tcfg.val_fraction, tcfg.seed)
    train_set, val_set = _example_sets(train_paths, val_paths, cfg, tcfg, cache, cache_dir, quiet)
    if len(train_set) == 0:
        raise InputError(f"{data}: no training examples (no {cfg.agent_class} with {tcfg.min_steps} valid past steps)")
    torch.manual_seed(tcfg.seed)
    model = RolloutCVAE(cfg)
    if start_weights is not None:
        model.load_state_dict(start_weights)
    model.to(dev)  # before the optimiser, whose state then lives where the weights do
    opt = torch.optim.AdamW(model.parameters(), lr=tcfg.lr, weight_decay=tcfg.weight_decay)
    run = _Run(str(Path(data).resolve()), out, cfg, tcfg, dev, train_paths, val_paths, train_set, val_set,
               *_scored_rows(val_set, cfg, tcfg), init, command, cpu, t_start, quiet)
    history: list[EpochRecord] = []
    first_epoch = 0
    if resume and state_path(out).is_file():
        history, first_epoch = _resume(state_path(out), run, model, opt)
    metrics: dict[str, Any] = {}
    steps_per_epoch = math.ceil(len(_epoch_rows(len(train_set), tcfg, 0)) / tcfg.batch_size)
    for epoch in range(first_epoch, tcfg.epochs):
        history.append(_epoch(run, model, opt, epoch, steps_per_epoch))
        _save_epoch(run, model, opt, history)
        metrics = _run_metrics(run, model, history)
        write_json(_metrics_path(out), metrics)
        if not quiet:
            shown = {k: round(v, 4) for k, v in history[-1].to_json().items() if isinstance(v, float)}
            print(f"epoch {epoch + 1}: {shown}", file=sys.stderr)
    if not metrics:  # nothing left to do (resumed a finished run)
        mp = _metrics_path(out)
        metrics = json.loads(mp.read_text()) if mp.is_file() else {"epochs": [e.to_json() for e in history]}
    return metrics
