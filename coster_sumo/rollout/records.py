"""What rollout training and evaluation report, as types: the per-epoch history of
``coster-sumo train rollout`` (in ``OUT.json``, ``OUT.state`` and the checkpoint's meta), the
training state it resumes from, and the errors of ``coster-sumo eval rollout``. ``to_json`` /
``to_dict`` give the keys those files have always had.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class DisplacementErrors:
    """Displacement errors of a method over ``num_contexts`` contexts, ``samples`` each.

    Attributes:
        min_ade, min_fde: [m] per context the smallest average / final displacement error over the
            samples (each minimised on its own), averaged over the contexts.
        avg_ade, avg_fde: [m] the same errors averaged over the samples instead.
    """

    min_ade: float
    min_fde: float
    avg_ade: float
    avg_fde: float
    num_contexts: int
    samples: int

    @classmethod
    def of(cls, ade: np.ndarray, fde: np.ndarray) -> DisplacementErrors:
        """From ``ade``, ``fde`` (R, S) per context and sample (:func:`~coster_sumo.metrics.ade_fde`)."""
        return cls(min_ade=float(ade.min(-1).mean()), min_fde=float(fde.min(-1).mean()), avg_ade=float(ade.mean()),
                   avg_fde=float(fde.mean()), num_contexts=int(ade.shape[0]), samples=int(ade.shape[1]))

    def to_json(self, prefix: str = "") -> dict[str, Any]:
        return {f"{prefix}minADE": self.min_ade, f"{prefix}minFDE": self.min_fde, f"{prefix}avgADE": self.avg_ade,
                f"{prefix}avgFDE": self.avg_fde, f"{prefix}num_contexts": self.num_contexts,
                f"{prefix}samples": self.samples}

    @classmethod
    def from_json(cls, d: dict[str, Any], prefix: str = "") -> DisplacementErrors:
        return cls(min_ade=d[f"{prefix}minADE"], min_fde=d[f"{prefix}minFDE"], avg_ade=d[f"{prefix}avgADE"],
                   avg_fde=d[f"{prefix}avgFDE"], num_contexts=d[f"{prefix}num_contexts"],
                   samples=d[f"{prefix}samples"])


@dataclass(frozen=True)
class GroupErrors:
    """minADE / minFDE [m] of one group of contexts: ``label`` of grouping ``group`` (e.g. the
    neighbour count bucket "1-3" of "neighbours")."""

    group: str
    label: str
    contexts: int
    min_ade: float
    min_fde: float

    def to_json(self) -> dict[str, Any]:
        return {self.group: self.label, "contexts": self.contexts, "minADE": self.min_ade, "minFDE": self.min_fde}


@dataclass(frozen=True)
class MethodErrors:
    """What ``eval rollout`` reports of one method: its errors, the wall time per trajectory [s] and,
    for the CVAE, the errors by neighbour count and by lane neighbour (None for the baselines)."""

    errors: DisplacementErrors
    time_per_trajectory_s: float
    by_neighbours: tuple[GroupErrors, ...] | None = None
    by_lane_neighbour: tuple[GroupErrors, ...] | None = None

    def to_json(self) -> dict[str, Any]:
        out = {**self.errors.to_json(), "time_per_trajectory_s": self.time_per_trajectory_s}
        if self.by_neighbours is not None:
            out["by_neighbours"] = [g.to_json() for g in self.by_neighbours]
        if self.by_lane_neighbour is not None:
            out["by_lane_neighbour"] = [g.to_json() for g in self.by_lane_neighbour]
        return out


@dataclass(frozen=True)
class RolloutEvaluation:
    """The scores of every method on the same ``num_examples`` contexts with a full
    ``horizon_steps`` past."""

    num_examples: int
    horizon_steps: int
    methods: dict[str, MethodErrors]

    def to_json(self) -> dict[str, Any]:
        return {"num_examples": self.num_examples, "horizon_steps": self.horizon_steps,
                "methods": {name: m.to_json() for name, m in self.methods.items()}}


@dataclass(frozen=True)
class ElboTerms:
    """The negative ELBO per valid step (nats) and its two terms, averaged over examples."""

    loss: float
    recon: float
    kl: float

    def to_json(self, prefix: str) -> dict[str, float]:
        return {f"{prefix}loss": self.loss, f"{prefix}recon": self.recon, f"{prefix}kl": self.kl}

    @classmethod
    def from_json(cls, d: dict[str, Any], prefix: str) -> ElboTerms:
        return cls(loss=d[f"{prefix}loss"], recon=d[f"{prefix}recon"], kl=d[f"{prefix}kl"])


@dataclass(frozen=True)
class EpochRecord:
    """One epoch of rollout training (1-based ``epoch``).

    Attributes:
        train: the ELBO terms over the epoch's training batches (with the weights of each step).
        val: the held-out ELBO terms after the epoch; None without held-out examples.
        val_errors: the held-out minADE / minFDE after the epoch; None without a held-out example
            with the full horizon.
        time_s: [s] wall time of the epoch, scoring included.
    """

    epoch: int
    train: ElboTerms
    time_s: float
    val: ElboTerms | None = None
    val_errors: DisplacementErrors | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"epoch": self.epoch, **self.train.to_json("train_")}
        if self.val is not None:
            out |= self.val.to_json("val_")
        if self.val_errors is not None:
            out |= self.val_errors.to_json("val_")
        out["time_s"] = self.time_s
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EpochRecord:
        return cls(epoch=int(d["epoch"]), train=ElboTerms.from_json(d, "train_"), time_s=d["time_s"],
                   val=ElboTerms.from_json(d, "val_") if "val_loss" in d else None,
                   val_errors=DisplacementErrors.from_json(d, "val_") if "val_minADE" in d else None)


RESUME_FORMAT = "coster-sumo-rollout-train"


@dataclass(frozen=True)
class RolloutTrainingState:
    """``OUT.state``: what a rollout training run needs to go on after ``epoch`` epochs.

    Attributes:
        model, optimizer: torch ``state_dict`` s of the model and the AdamW optimiser.
        config: the model's ``RolloutConfig.to_dict()``; train_config: ``asdict(TrainConfig)`` as
            saved (states of older versions lack the newer fields). Both None when absent.
        data: the dataset folder, resolved (None when absent).
    """

    epoch: int
    model: dict[str, Any]
    optimizer: dict[str, Any]
    config: dict[str, Any] | None
    train_config: dict[str, Any]
    data: str | None
    history: tuple[EpochRecord, ...]

    def to_dict(self) -> dict[str, Any]:
        """As ``torch.save`` writes it."""
        return {"format": RESUME_FORMAT, "epoch": self.epoch, "model": self.model, "optimizer": self.optimizer,
                "config": self.config, "train_config": self.train_config, "data": self.data,
                "history": [e.to_json() for e in self.history]}

    @classmethod
    def from_dict(cls, state: Any) -> RolloutTrainingState | None:
        """From what ``torch.load`` read; None when it is not a rollout training state."""
        if not isinstance(state, dict) or state.get("format") != RESUME_FORMAT:
            return None
        return cls(epoch=int(state.get("epoch", 0)), model=state.get("model", {}),
                   optimizer=state.get("optimizer", {}), config=state.get("config"),
                   train_config=dict(state.get("train_config", {})), data=state.get("data"),
                   history=tuple(EpochRecord.from_json(e) for e in state.get("history", [])))
