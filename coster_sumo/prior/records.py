"""What training the traffic prior reports, as types: the held-out loss of an epoch, one record per
epoch (``history`` in ``OUTPUT.json`` and ``OUTPUT.state``) and the metrics of a run (``OUTPUT.json``,
and without the history in the checkpoint). ``to_json`` gives the keys those files have always had.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class HeldOutLoss:
    """The prior's loss on fixed held-out samples.

    Attributes:
        loss: the training objective per query token.
        presence_bce: presence binary cross-entropy per query token.
        presence_rate: share of the query tokens with an agent present.
        num_query: query tokens scored.
        attribute_ce: attribute -> cross-entropy per present query token (no label smoothing).
    """

    loss: float
    presence_bce: float
    presence_rate: float
    num_query: float
    attribute_ce: dict[str, float]

    def to_json(self) -> dict[str, float]:
        return {"loss": self.loss, "presence_bce": self.presence_bce, "presence_rate": self.presence_rate,
                "num_query": self.num_query, **{f"{a}_ce": v for a, v in self.attribute_ce.items()}}

    @classmethod
    def from_json(cls, d: dict[str, float]) -> HeldOutLoss:
        return cls(loss=d["loss"], presence_bce=d["presence_bce"], presence_rate=d["presence_rate"],
                   num_query=d["num_query"], attribute_ce={k[:-3]: v for k, v in d.items() if k.endswith("_ce")})


@dataclass(frozen=True)
class PriorEpoch:
    """One epoch of prior training (1-based ``epoch``): the mean training loss per batch, the wall
    time [s], the held-out loss (None without held-out scenes) and whether its score (held-out
    loss, else training loss) was the best so far."""

    epoch: int
    train_loss: float
    seconds: float
    val: HeldOutLoss | None = None
    best: bool = False

    @property
    def score(self) -> float:
        """What picks the best epoch: the held-out loss, or the training loss without held-out scenes."""
        return self.val.loss if self.val is not None else self.train_loss

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"epoch": self.epoch, "train_loss": self.train_loss, "seconds": self.seconds}
        if self.val is not None:
            out["val"] = self.val.to_json()
        if self.best:
            out["best"] = True
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PriorEpoch:
        return cls(epoch=int(d["epoch"]), train_loss=d["train_loss"], seconds=d["seconds"],
                   val=HeldOutLoss.from_json(d["val"]) if "val" in d else None, best=bool(d.get("best")))


@dataclass(frozen=True)
class PriorTrainMetrics:
    """What a prior training run reports.

    Attributes:
        best_epoch: the epoch whose weights the checkpoint holds (None when no epoch ran).
        best_score: its score (:attr:`PriorEpoch.score`).
        train_config, model_config: the settings, as their ``asdict`` / ``to_dict``.
        device: where it trained; cpu: the CPU's description.
        meta: what the caller adds (the command line, the data, file counts).
    """

    best_epoch: int | None
    best_score: float
    history: list[PriorEpoch]
    num_train_scenes: int
    num_val_scenes: int
    train_config: dict[str, Any]
    model_config: dict[str, Any]
    num_parameters: int
    device: str
    cpu: str
    meta: dict[str, Any] = field(default_factory=dict)

    def to_json(self, history: bool = True) -> dict[str, Any]:
        """The metrics (``history=False``: without the history, as the checkpoint holds them)."""
        out: dict[str, Any] = {"best_epoch": self.best_epoch, "best_score": self.best_score}
        if history:
            out["history"] = [e.to_json() for e in self.history]
        return out | {"num_train_scenes": self.num_train_scenes, "num_val_scenes": self.num_val_scenes,
                      "train_config": self.train_config, "model_config": self.model_config,
                      "num_parameters": self.num_parameters, "device": self.device, "cpu": self.cpu, **self.meta}


@dataclass(frozen=True)
class ReliabilityBin:
    """One equal-width bin [lo, hi) of predicted presence probabilities: how many predictions fell
    in it, their mean and how often an agent was there (both None for an empty bin)."""

    lo: float
    hi: float
    count: int
    mean_predicted: float | None = None
    observed: float | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"lo": self.lo, "hi": self.hi, "count": self.count}
        if self.mean_predicted is not None:
            out |= {"mean_predicted": self.mean_predicted, "observed": self.observed}
        return out


@dataclass(frozen=True)
class Calibration:
    """Calibration of ``count`` presence probabilities against what was there: expected calibration
    error, BCE, Brier score, the observed and predicted rates, the reliability bins, and the ROC AUC
    (None when every outcome is the same). All but ``count`` are None without predictions."""

    count: int
    ece: float | None = None
    bce: float | None = None
    brier: float | None = None
    rate_observed: float | None = None
    rate_predicted: float | None = None
    bins: tuple[ReliabilityBin, ...] = ()
    auc: float | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"count": self.count}
        if self.ece is not None:
            out |= {"ece": self.ece, "bce": self.bce, "brier": self.brier, "rate_observed": self.rate_observed,
                    "rate_predicted": self.rate_predicted, "reliability": [b.to_json() for b in self.bins]}
        if self.auc is not None:
            out["auc"] = self.auc
        return out


@dataclass(frozen=True)
class MethodMmd:
    """A method's MMD per attribute (attribute -> mean over the scored scenes; None when no scene was
    scored) and how many scenes were scored."""

    values: dict[str, float | None]
    scenes: int

    def to_json(self) -> dict[str, Any]:
        return {**self.values, "scenes": self.scenes}


@dataclass(frozen=True)
class TrafficScores:
    """The MMDs (method -> scores) in map mode and in the hidden disc (context mode), and the mean
    agent counts per scene (map mode) and in the hidden disc (name -> count)."""

    mmd: dict[str, MethodMmd]
    mmd_hidden_disc: dict[str, MethodMmd]
    agents_per_scene: dict[str, float]
    agents_in_hidden_disc: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        return {"mmd": _mmds(self.mmd), "mmd_hidden_disc": _mmds(self.mmd_hidden_disc),
                "agents_per_scene": self.agents_per_scene, "agents_in_hidden_disc": self.agents_in_hidden_disc}


def _mmds(scores: dict[str, MethodMmd]) -> dict[str, Any]:
    return {name: m.to_json() for name, m in scores.items()}


@dataclass(frozen=True)
class DensityOffset:
    """The presence offsets fitted per scene (context mode): their mean, range, and how many reached
    the limit."""

    mean: float
    min: float
    max: float
    at_limit: int


@dataclass(frozen=True)
class PriorEvaluation:
    """What ``coster-sumo eval prior`` reports (the module docstring of
    :mod:`coster_sumo.prior.evaluate` defines each number).

    Attributes:
        scores: with every agent; ``without_centre_agent``: the centre agent's own region left out.
        presence: mode or baseline -> calibration of its presence probabilities.
        density_offset: None when no scene was adapted.
        heldout_loss: mode ("map", "context") -> the training objective on the scenes; None without samples.
    """

    num_scenes: int
    mmd_estimator: str
    scores: TrafficScores
    presence: dict[str, Calibration]
    without_centre_agent: TrafficScores
    density_offset: DensityOffset | None = None
    heldout_loss: dict[str, HeldOutLoss] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"num_scenes": self.num_scenes, "mmd_estimator": self.mmd_estimator,
                               "mmd": _mmds(self.scores.mmd), "agents_per_scene": self.scores.agents_per_scene,
                               "presence": {k: c.to_json() for k, c in self.presence.items()},
                               "agents_in_hidden_disc": self.scores.agents_in_hidden_disc}
        if self.density_offset is not None:
            out["density_offset"] = asdict(self.density_offset)
        out["mmd_hidden_disc"] = _mmds(self.scores.mmd_hidden_disc)
        out["without_centre_agent"] = self.without_centre_agent.to_json()
        if self.heldout_loss is not None:
            out["heldout_loss"] = {mode: loss.to_json() for mode, loss in self.heldout_loss.items()}
        return out


@dataclass(frozen=True)
class PriorTrainingState:
    """``OUTPUT.state``: what prior training needs to go on after ``epoch`` epochs.

    Attributes:
        config: the model's ``PriorConfig.to_dict()``; train_config: ``asdict(TrainConfig)`` as saved.
        model, optimizer: torch ``state_dict`` s; best_model: the weights of the best epoch (None: none yet).
        best: the best score so far (:attr:`PriorEpoch.score`).
    """

    config: dict[str, Any] | None
    train_config: dict[str, Any]
    model: dict[str, Any]
    optimizer: dict[str, Any]
    epoch: int
    best: float
    best_model: dict[str, Any] | None
    history: tuple[PriorEpoch, ...]

    def to_dict(self) -> dict[str, Any]:
        """As ``torch.save`` writes it (the history as a JSON string: the file loads with ``weights_only``)."""
        return {"config": self.config, "train_config": self.train_config, "model": self.model,
                "optimizer": self.optimizer, "epoch": self.epoch, "best": self.best, "best_model": self.best_model,
                "history": json.dumps([e.to_json() for e in self.history])}

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> PriorTrainingState:
        return cls(config=state.get("config"), train_config=dict(state.get("train_config") or {}),
                   model=state.get("model", {}), optimizer=state.get("optimizer", {}), epoch=int(state.get("epoch", 0)),
                   best=float(state.get("best", math.inf)), best_model=state.get("best_model"),
                   history=tuple(PriorEpoch.from_json(e) for e in json.loads(state.get("history", "[]"))))
