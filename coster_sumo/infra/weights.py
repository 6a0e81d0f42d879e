"""Where model weights are found, and the one message for missing ones.

Shipped weights travel inside the installed package (``coster_sumo.models``, the repository's
``models/`` folder) and are located with :mod:`importlib.resources`, so the tool works from any
folder; ``--models DIR`` (``models_dir``) replaces the whole folder. :func:`load_cached` loads a
file once per version: a batch or an evaluation that asks again gets the same object back.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from coster_sumo.errors import InputError, not_found

T = TypeVar("T")

PRIOR = "prior.pt"
ROLLOUT = "rollout.pt"
ROLLOUT_NO_DSA = "rollout_nodsa.pt"
VOCAB = "vocab.npz"
# the learned rollouts of pedestrian and cyclist adversaries (optional: without them a VRU draw
# takes the class's kinematic rollout)
ROLLOUT_PEDESTRIAN = "rollout_pedestrian.pt"
ROLLOUT_CYCLIST = "rollout_cyclist.pt"
# the learned speed and heading of pedestrian and cyclist adversaries at contact (optional: without
# it the classes' rules draw them)
VRU_STATES = "vru_states.npz"
# what a models folder holds
WEIGHT_FILES = (PRIOR, ROLLOUT, ROLLOUT_NO_DSA, VOCAB, ROLLOUT_PEDESTRIAN, ROLLOUT_CYCLIST, VRU_STATES)

# what trains each file, for the "not found" message
_TRAIN_COMMAND = {PRIOR: "coster-sumo train prior --data DATASET -o {path}",
                  ROLLOUT: "coster-sumo train rollout --data DATASET -o {path}",
                  ROLLOUT_NO_DSA: "coster-sumo train rollout --no-dsa --data DATASET -o {path}",
                  VOCAB: "coster-sumo train vocab --data DATASET -o {path}",
                  ROLLOUT_PEDESTRIAN: "coster-sumo train rollout --agent-class pedestrian --data DATASET -o {path}",
                  ROLLOUT_CYCLIST: "coster-sumo train rollout --agent-class cyclist --data DATASET -o {path}",
                  VRU_STATES: "coster-sumo train vru-states --data DATASET -o {path}"}


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
        raise not_found(path, why=f"model weights: train them with `{train}` or pass --models DIR")
    return path


def missing_weights(names: tuple[str, ...], models_dir: str | Path | None = None) -> str | None:
    """The "not found" line of the first missing file among ``names``, or None when all exist."""
    for name in names:
        try:
            weights_path(name, models_dir)
        except InputError as exc:
            return str(exc)
    return None


_DIGESTS: dict[tuple[str, tuple[tuple[str, int, int], ...]], str] = {}


def weights_digest(models_dir: str | Path | None = None) -> str:
    """A short hash of the weights' contents in ``models_dir`` (default: the shipped ones).

    Batches key their saved work by it, so the same weights reached by another path (``--models
    ../m`` from another folder) resume instead of running again, and other weights at the same
    path do not reuse results made with the old ones.
    """
    import hashlib

    folder = models_folder(models_dir).resolve()
    files = [folder / n for n in WEIGHT_FILES if (folder / n).is_file()]
    stamp = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in files)
    key = (str(folder), stamp)
    if key not in _DIGESTS:
        h = hashlib.sha256()
        for f in files:
            h.update(f.name.encode() + b"\0")
            with f.open("rb") as fh:
                for chunk in iter(lambda: fh.read(1 << 20), b""):  # noqa: B023 - fh is this loop's
                    h.update(chunk)
        _DIGESTS[key] = h.hexdigest()[:16]
    return _DIGESTS[key]


_LOADED: dict[tuple[Any, str, int, int], Any] = {}


def load_cached(path: Path, loader: Callable[[Path], T]) -> T:
    """``loader(path)``, loaded once per file version and process (a batch asks again and again)."""
    st = path.stat()
    key = (loader, str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _LOADED:
        _LOADED[key] = loader(path)
    value: T = _LOADED[key]
    return value
