"""Atomic file writes: write to a hidden temporary sibling, then rename over the target.

A reader (or a resumed batch) sees either the old file or the complete new one, never a half
written one; a crash leaves at most a hidden ``.NAME.PID.tmp*`` file behind. The temporary name
keeps the target's suffix, so libraries that append one (``numpy.savez`` adds ``.npz``) write to
the name we rename.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def temporary_sibling(path: Path) -> Path:
    """A hidden, process-unique name in ``path``'s folder ending in ``path``'s suffix."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed."""
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def json_default(o: Any) -> Any:
    """JSON for numpy scalars and arrays and paths (everything else as ``str``)."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def write_json(path: str | Path, obj: Any, indent: int | None = 1) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (numpy values become plain numbers)."""
    return write_text(path, json.dumps(obj, indent=indent, default=json_default))
