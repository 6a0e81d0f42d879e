"""Where model weights are found, and the one message for missing ones.

Shipped weights travel inside the installed package (``coster_sumo.models``, the repository's
``models/`` folder) and are located with :mod:`importlib.resources`, so the tool works from any
folder; ``--models DIR`` (``models_dir``) replaces the whole folder. Loaders are cached per file
version: a batch or an evaluation that asks again gets the same object back.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from coster_sumo.errors import InputError

if TYPE_CHECKING:
    from coster_sumo.prior.model import TrafficPrior
    from coster_sumo.rollout.model import RolloutCVAE
    from coster_sumo.rollout.vocab import MotionVocab

PRIOR = "prior.pt"
ROLLOUT = "rollout.pt"
ROLLOUT_NO_DSA = "rollout_nodsa.pt"
VOCAB = "vocab.npz"

# what trains each file, for the "not found" message
_TRAIN_COMMAND = {PRIOR: "coster-sumo train prior --data DATASET -o {path}",
                  ROLLOUT: "coster-sumo train rollout --data DATASET -o {path}",
                  ROLLOUT_NO_DSA: "coster-sumo train rollout --no-dsa --data DATASET -o {path}",
                  VOCAB: "coster-sumo train vocab --data DATASET -o {path}"}


def shipped_models_dir() -> Path:
    """The installed package's weights folder (the repository's ``models/`` in a checkout)."""
    return Path(str(resources.files("coster_sumo.models")))


def models_folder(models_dir: str | Path | None = None) -> Path:
    """``models_dir`` when given, else the shipped folder."""
    return Path(models_dir) if models_dir is not None else shipped_models_dir()


def weights_path(name: str, models_dir: str | Path | None = None, *, required: bool = True) -> Path:
    """``MODELS/name``; with ``required`` a missing file is one :class:`InputError` line saying how to fix it."""
    path = models_folder(models_dir) / name
    if required and not path.is_file():
        train = _TRAIN_COMMAND.get(name, "coster-sumo train ...").format(path=path)
        raise InputError(f"{path}: model weights not found (train them with `{train}` or pass --models DIR)")
    return path


def missing_weights(names: tuple[str, ...], models_dir: str | Path | None = None) -> str | None:
    """The "not found" line of the first missing file among ``names``, or None when all exist."""
    for name in names:
        try:
            weights_path(name, models_dir)
        except InputError as exc:
            return str(exc)
    return None


def _version(path: Path) -> tuple[str, int, int]:
    st = path.stat()
    return str(path.resolve()), st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=4)
def _prior(key: tuple[str, int, int]) -> Any:
    from coster_sumo.prior.infer import load_prior as load

    return load(key[0])


@functools.lru_cache(maxsize=4)
def _rollout(key: tuple[str, int, int]) -> Any:
    from coster_sumo.rollout.checkpoint import load_model

    return load_model(key[0])


@functools.lru_cache(maxsize=4)
def _vocab(key: tuple[str, int, int]) -> Any:
    from coster_sumo.rollout.vocab import MotionVocab

    return MotionVocab.load(key[0])


def load_prior(models_dir: str | Path | None = None, name: str = PRIOR) -> TrafficPrior:
    """The traffic prior ``MODELS/prior.pt`` (cached per file version)."""
    prior: TrafficPrior = _prior(_version(weights_path(name, models_dir)))
    return prior


def load_rollout(models_dir: str | Path | None = None, name: str = ROLLOUT) -> RolloutCVAE:
    """The rollout CVAE ``MODELS/rollout.pt`` (cached per file version)."""
    model: RolloutCVAE = _rollout(_version(weights_path(name, models_dir)))
    return model


def load_vocab(models_dir: str | Path | None = None) -> MotionVocab | None:
    """The motion vocabulary ``MODELS/vocab.npz``, or None when the folder has none (no refinement)."""
    path = weights_path(VOCAB, models_dir, required=False)
    if not path.is_file():
        return None
    vocab: MotionVocab = _vocab(_version(path))
    return vocab
