"""Training loop of the traffic prior: deterministic per seed, resumable, with held-out metrics.

Determinism: weights are initialised after ``torch.manual_seed(seed)``; the samples and the hidden
sets of epoch e come from ``numpy.random.default_rng([seed, e])``; nothing else is random (no
dropout). Training runs with ``torch.set_num_threads(threads)`` (1 by default: the same seed gives
the same weights bit for bit on the same machine). The held-out samples and their visibility are
fixed (``default_rng([seed, 10**6])``).

Resuming: after every epoch the full training state (weights, optimiser, epoch, history, best
weights) is written atomically to ``state_path``; a later run with the same output resumes from it,
so an interrupted run loses at most one epoch and ends with the same weights as an uninterrupted one
(when it resumes on the same thread count; it may resume on another, which reorders floating-point
sums).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import atomic_path, write_json
from coster_sumo.infra.devices import cpu_description, device_name, training_device
from coster_sumo.prior.bins import ATTRIBUTES
from coster_sumo.prior.data import ScenePriorData, batch_tokens, epoch_samples
from coster_sumo.prior.features import Tokens
from coster_sumo.prior.infer import save_prior
from coster_sumo.prior.model import PriorConfig, TrafficPrior
from coster_sumo.prior.records import HeldOutLoss, PriorEpoch, PriorTrainingState, PriorTrainMetrics


@dataclass
class TrainConfig:
    epochs: int = 20
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    grad_clip: float = 1.0
    centres_per_step: int = 1  # neighbourhood centres per scene step and epoch
    seed: int = 0
    threads: int = 1
    val_batches_max: int = 200  # cap on held-out batches evaluated per epoch


def _torch_batch(tok: Tokens, device: torch.device | str = "cpu") -> tuple[torch.Tensor, ...]:
    return tuple(torch.from_numpy(a).to(device) for a in (tok.map_features, tok.agent_features, tok.mask, tok.query,
                                                          tok.present, tok.classes))


@torch.no_grad()
def evaluate_loss(model: TrafficPrior, scenes: Sequence[ScenePriorData], samples: np.ndarray, batch_size: int,
                  seed: int, visible: str = "random") -> HeldOutLoss:
    """Held-out loss (the training objective) and per-head mean losses, for fixed samples."""
    model.eval()
    cfg = model.config
    rng = np.random.default_rng([seed, 10**6])
    sums: dict[str, float] = {}
    total, n_query = 0.0, 0.0
    for i in range(0, len(samples), batch_size):
        tok = batch_tokens(scenes, samples[i:i + batch_size], cfg,
                           visible=visible, rng=rng, hide_radius=cfg.hide_radius)
        mf, af, mask, query, present, classes = _torch_batch(tok, next(model.parameters()).device)
        h = model.encode_packed(mf, af, mask)  # (N, 2D)
        q, present, classes = query[mask], present[mask], classes[mask]
        total += float(model.loss(h, q, present, classes)) * max(int(q.sum()), 1)
        for k, v in model.attribute_losses(h, q, present, classes).items():
            sums[k] = sums.get(k, 0.0) + float(v)
        n_query += float(q.sum())
    n_q, n_p = max(sums.get("num_query", 0.0), 1.0), max(sums.get("num_present", 0.0), 1.0)
    return HeldOutLoss(loss=total / max(n_query, 1.0), presence_bce=sums.get("presence", 0.0) / n_q,
                       presence_rate=sums.get("num_present", 0.0) / n_q, num_query=sums.get("num_query", 0.0),
                       attribute_ce={a: sums.get(a, 0.0) / n_p for a in ATTRIBUTES})


def _lr_at(step: int, total: int, cfg: TrainConfig) -> float:
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    frac = (step - cfg.warmup_steps) / max(1, total - cfg.warmup_steps)
    return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(frac, 1.0)))


@dataclass
class _Progress:
    """What a run carries from epoch to epoch (and a training state holds): the epochs done, the
    best held-out score so far with its weights, and one record per epoch."""

    epoch: int = 0
    best: float = math.inf
    best_state: dict[str, torch.Tensor] | None = None
    history: list[PriorEpoch] = field(default_factory=list)


def _resumed(state_path: Path, mcfg: PriorConfig, tcfg: TrainConfig, model: TrafficPrior,
             opt: torch.optim.Optimizer, log: Callable[[str], None] | None) -> _Progress:
    """The progress of the training state at ``state_path``, loaded into ``model`` and ``opt``; a
    fresh start when it was written with other settings (said in the log)."""
    state = PriorTrainingState.from_dict(torch.load(state_path, map_location="cpu", weights_only=True))
    # the thread count only reorders floating-point sums: a run may resume on another one
    saved_tc = {**state.train_config, "threads": tcfg.threads}
    differ = [k for k, v in asdict(tcfg).items() if saved_tc.get(k) != v]
    if state.config != mcfg.to_dict():
        differ.insert(0, "model settings")
    if differ:
        if log:
            log(f"ignoring {state_path}: it was written with another configuration ({', '.join(differ)})")
        return _Progress()
    model.load_state_dict(state.model)
    opt.load_state_dict(state.optimizer)
    done = _Progress(state.epoch, state.best, state.best_model, list(state.history))
    if log:
        log(f"resuming from {state_path} after epoch {done.epoch}")
    return done


def _train_epoch(model: TrafficPrior, opt: torch.optim.Optimizer, train: Sequence[ScenePriorData],
                 tcfg: TrainConfig, dev: torch.device, epoch: int, steps_per_epoch: int, progress: bool) -> float:
    """One epoch (0-based) of ``tcfg.epochs``, ``steps_per_epoch`` batches each, over fresh samples of
    ``train``: the mean training loss per batch."""
    cfg = model.config
    total_steps = steps_per_epoch * tcfg.epochs
    rng = np.random.default_rng([tcfg.seed, epoch])
    samples = epoch_samples(train, rng, tcfg.centres_per_step)
    batches = range(0, len(samples), tcfg.batch_size)
    it = batches
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(batches, desc=f"epoch {epoch + 1}/{tcfg.epochs}", unit="batch", leave=False)
        it = bar
    model.train()
    run_loss, n = 0.0, 0
    for bi, i in enumerate(it):
        step = epoch * steps_per_epoch + bi
        for group in opt.param_groups:
            group["lr"] = _lr_at(step, total_steps, tcfg)
        tok = batch_tokens(train, samples[i:i + tcfg.batch_size], cfg,
                           visible="random", rng=rng, hide_radius=cfg.hide_radius)
        _, loss = model(*_torch_batch(tok, dev))
        assert loss is not None
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), tcfg.grad_clip)
        opt.step()
        run_loss += float(loss.detach())
        n += 1
        if bar is not None:
            bar.set_postfix(loss=f"{run_loss / n:.3f}")
    if bar is not None:
        bar.close()
    return run_loss / max(n, 1)


def _save_state(state_path: Path, mcfg: PriorConfig, tcfg: TrainConfig, model: TrafficPrior,
                opt: torch.optim.Optimizer, done: _Progress) -> None:
    """The training state after ``done.epoch`` epochs, written atomically."""
    state_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(state_path) as tmp:
        state = PriorTrainingState(config=mcfg.to_dict(), train_config=asdict(tcfg), model=model.state_dict(),
                                   optimizer=opt.state_dict(), epoch=done.epoch, best=done.best,
                                   best_model=done.best_state, history=tuple(done.history))
        torch.save(state.to_dict(), tmp)


def _write_best(model: TrafficPrior, output: Path, done: _Progress, train: Sequence[ScenePriorData],
                val: Sequence[ScenePriorData], tcfg: TrainConfig, dev: torch.device, meta: dict | None
                ) -> PriorTrainMetrics:
    """Load the best weights into ``model`` (on the CPU), write them to ``output`` and the metrics
    beside it; returns the metrics."""
    model.cpu()  # the checkpoint is the CPU's
    if done.best_state is not None:
        model.load_state_dict(done.best_state)
    best_epoch = next((e.epoch for e in reversed(done.history) if e.best), None)
    metrics = PriorTrainMetrics(
        best_epoch=best_epoch, best_score=done.best, history=done.history, num_train_scenes=len(train),
        num_val_scenes=len(val), train_config=asdict(tcfg), model_config=model.config.to_dict(),
        num_parameters=sum(p.numel() for p in model.parameters()), device=device_name(dev), cpu=cpu_description(),
        meta=meta or {})
    save_prior(model, output, metrics=metrics.to_json(history=False), meta=meta or {})
    write_json(output.with_suffix(".json"), metrics.to_json())
    return metrics


def train_prior(train: Sequence[ScenePriorData], val: Sequence[ScenePriorData], output: str | Path,
                model_config: PriorConfig | None = None, train_config: TrainConfig | None = None,
                state_path: str | Path | None = None, resume: bool = True, progress: bool = True,
                meta: dict | None = None, log: Callable[[str], None] | None = print, device: str = "cpu"
                ) -> PriorTrainMetrics:
    """Train the prior; write the best held-out checkpoint to ``output`` and metrics beside it
    (``output`` with suffix ``.json``). Returns the metrics.

    ``device``: where the model trains (:func:`coster_sumo.infra.devices.training_device`); the tokens are
    built on the CPU and moved there, the checkpoint is written for the CPU and the state is read
    onto it, so a run resumes on either device (the same numbers only on the same device)."""
    mcfg = model_config or PriorConfig()
    tcfg = train_config or TrainConfig()
    if not train:
        raise InputError("no training scenes")
    output = Path(output)
    state_path = Path(state_path) if state_path else output.with_name(output.name + ".state")
    dev = training_device(device)
    torch.set_num_threads(max(1, tcfg.threads))
    torch.manual_seed(tcfg.seed)
    model = TrafficPrior(mcfg).to(dev)  # before the optimiser, whose state then lives where the weights do
    opt = torch.optim.AdamW(model.parameters(), lr=tcfg.lr, weight_decay=tcfg.weight_decay)
    done = _Progress()
    if resume and state_path.is_file():
        done = _resumed(state_path, mcfg, tcfg, model, opt, log)
    # every epoch has the same number of samples (centres_per_step per scene step with a centre)
    num_samples = len(epoch_samples(train, np.random.default_rng(0), tcfg.centres_per_step))
    steps_per_epoch = max(1, math.ceil(num_samples / tcfg.batch_size))
    val_samples = epoch_samples(val, np.random.default_rng([tcfg.seed, 10**6 + 1]), 1) if val else None
    if val_samples is not None:
        val_samples = val_samples[: tcfg.val_batches_max * tcfg.batch_size]
    for epoch in range(done.epoch, tcfg.epochs):
        t0 = time.perf_counter()
        train_loss = _train_epoch(model, opt, train, tcfg, dev, epoch, steps_per_epoch, progress)
        record = PriorEpoch(epoch=epoch + 1, train_loss=train_loss, seconds=time.perf_counter() - t0)
        if val_samples is not None and len(val_samples):
            record = replace(record, val=evaluate_loss(model, val, val_samples, tcfg.batch_size, tcfg.seed))
        if record.score < done.best:
            done.best = record.score
            done.best_state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
            record = replace(record, best=True)
        done.history.append(record)
        done.epoch = epoch + 1
        _save_state(state_path, mcfg, tcfg, model, opt, done)
        if log:
            val_txt = f" val {record.val.loss:.4f}" if record.val is not None else ""
            log(f"epoch {epoch + 1}/{tcfg.epochs}: train {record.train_loss:.4f}{val_txt} ({record.seconds:.1f} s)")
    return _write_best(model, output, done, train, val, tcfg, dev, meta)
