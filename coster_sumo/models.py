"""Where shipped weights live, and how a missing one is reported."""

from __future__ import annotations

from pathlib import Path

from coster_sumo.errors import InputError

SHIPPED_MODELS = Path(__file__).resolve().parent.parent / "models"


def model_path(name: str, models_dir: Path | None = None) -> Path:
    """``models_dir / name`` (default: the repository's ``models/``), checked to exist."""
    folder = Path(models_dir) if models_dir is not None else SHIPPED_MODELS
    path = folder / name
    if not path.exists():
        raise InputError(f"{path}: model weights not found (train them with `coster-sumo train ...` "
                         "or pass --models DIR)")
    return path
