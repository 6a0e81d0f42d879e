"""Finding SUMO from the PyPI packages (never from a user-set SUMO_HOME) and importing it lazily."""

from __future__ import annotations

import functools
import importlib
import os
from pathlib import Path
from types import ModuleType

from coster_sumo.errors import SumoError

_FIX = "install it with: pip install 'eclipse-sumo==1.28.*' 'libsumo==1.28.*' sumolib traci"


@functools.cache
def sumo_home() -> Path:
    """The ``sumo`` package's SUMO_HOME (has bin/, tools/, data/)."""
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError:
        raise SumoError(f"SUMO is not installed: {_FIX}") from None
    return Path(sumo.SUMO_HOME)


def binary(name: str) -> str:
    """Absolute path of a SUMO binary (``sumo``, ``netconvert``, ``netgenerate``, ``duarouter``...)."""
    path = sumo_home() / "bin" / name
    if not path.exists():
        raise SumoError(f"SUMO binary {name!r} not found at {path}: {_FIX}")
    return str(path)


def tool(relpath: str) -> str:
    """Absolute path of a script under SUMO's tools/ (e.g. ``randomTrips.py``)."""
    path = sumo_home() / "tools" / relpath
    if not path.exists():
        raise SumoError(f"SUMO tool {relpath!r} not found at {path}: {_FIX}")
    return str(path)


def subprocess_env() -> dict[str, str]:
    """Environment for SUMO subprocesses: SUMO_HOME pointing at the package (tools need it)."""
    env = dict(os.environ)
    env["SUMO_HOME"] = str(sumo_home())
    return env


def import_libsumo() -> ModuleType:
    """``import libsumo`` with a clear error; sets SUMO_HOME to the package first (see docs/sumo.md §1)."""
    os.environ.setdefault("SUMO_HOME", str(sumo_home()))
    try:
        return importlib.import_module("libsumo")
    except ImportError:
        raise SumoError(f"libsumo is not installed: {_FIX}") from None


def import_traci() -> ModuleType:
    os.environ.setdefault("SUMO_HOME", str(sumo_home()))
    try:
        return importlib.import_module("traci")
    except ImportError:
        raise SumoError(f"traci is not installed: {_FIX}") from None


def import_sumolib() -> ModuleType:
    os.environ.setdefault("SUMO_HOME", str(sumo_home()))
    try:
        return importlib.import_module("sumolib")
    except ImportError:
        raise SumoError(f"sumolib is not installed: {_FIX}") from None
