"""Rollout checkpoints: ``{"format", "version", "config", "state_dict", "meta"}`` in one torch file.

Read with ``torch.load(weights_only=True)``: no pickled code runs. Every problem (missing file, not
a torch file, another kind of checkpoint, config keys this version does not know, weights that do
not fit the config) raises :class:`~coster_sumo.errors.InputError` with one line naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from coster_sumo.errors import InputError, not_found
from coster_sumo.infra.atomic import atomic_path
from coster_sumo.rollout.model import RolloutConfig, RolloutCVAE

FORMAT_NAME = "coster-sumo-rollout"
FORMAT_VERSION = 1


def atomic_torch_save(obj: Any, path: str | Path) -> Path:
    """torch.save to a temporary name, then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)
    return path


def save_checkpoint(model: RolloutCVAE, path: str | Path, meta: dict | None = None) -> Path:
    """Write the model's config and weights (and JSON-able ``meta``) atomically."""
    obj = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "config": model.cfg.to_dict(),
           "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, "meta": meta or {}}
    return atomic_torch_save(obj, path)


def read_torch_file(path: str | Path) -> Any:
    """``torch.load(weights_only=True)`` with one-line InputErrors."""
    path = Path(path)
    if not path.is_file():
        raise not_found(path, why="checkpoint")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds (UnpicklingError, RuntimeError, EOFError...)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a readable torch checkpoint ({first[:160]})") from None


def load_model(path: str | Path) -> RolloutCVAE:
    """The model of a checkpoint written by :func:`save_checkpoint`, in eval mode on the CPU."""
    return load_checkpoint(path)[0]


def load_checkpoint(path: str | Path) -> tuple[RolloutCVAE, dict]:
    """(model in eval mode on the CPU, meta) of a checkpoint written by :func:`save_checkpoint`."""
    path = Path(path)
    obj = read_torch_file(path)
    if not isinstance(obj, dict) or obj.get("format") != FORMAT_NAME:
        raise InputError(f"{path}: not a rollout checkpoint (format {FORMAT_NAME!r} expected)")
    if obj.get("version") != FORMAT_VERSION:
        raise InputError(f"{path}: rollout checkpoint version {obj.get('version')} is not supported "
                         f"(expected {FORMAT_VERSION})")
    if not isinstance(obj.get("config"), dict) or not isinstance(obj.get("state_dict"), dict):
        raise InputError(f"{path}: rollout checkpoint lacks its config or weights")
    try:
        cfg = RolloutConfig.from_dict(obj["config"])
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    model = RolloutCVAE(cfg)
    state = obj["state_dict"]
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    wrong = sorted(k for k in set(own) & set(state)
                   if not isinstance(state[k], torch.Tensor) or tuple(state[k].shape) != tuple(own[k].shape))
    if missing or unexpected or wrong:
        parts = []
        for name, keys in (("missing", missing), ("unexpected", unexpected), ("wrong shape", wrong)):
            if keys:
                parts.append(f"{len(keys)} {name} (e.g. {keys[0]})")
        raise InputError(f"{path}: weights do not match the rollout config: {'; '.join(parts)}")
    model.load_state_dict(state)
    meta = obj.get("meta", {})
    return model.eval(), meta if isinstance(meta, dict) else {}


def require_class(model: RolloutCVAE, agent_class: str, path: str | Path) -> RolloutCVAE:
    """``model`` (loaded from ``path``) when it models ``agent_class``'s tracks; else one error line."""
    if model.cfg.agent_class != agent_class:
        raise InputError(f"{path}: a {model.cfg.agent_class} rollout checkpoint where the {agent_class}'s was "
                         f"expected (train one with `coster-sumo train rollout --agent-class {agent_class}`)")
    return model
