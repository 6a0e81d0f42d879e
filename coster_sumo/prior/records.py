"""What training the traffic prior reports, as types: the held-out loss of an epoch, one record per
epoch (``history`` in ``OUTPUT.json`` and ``OUTPUT.state``) and the metrics of a run (``OUTPUT.json``,
and without the history in the checkpoint). ``to_json`` gives the keys those files have always had.
"""

from __future__ import annotations

from dataclasses import dataclass, field
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
