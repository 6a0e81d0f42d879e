"""coster-sumo: COSTER safety-critical scenario generation injected into SUMO.

Nothing here imports SUMO or torch: those are imported where they are used, so that
``import coster_sumo`` works (and fails clearly later) on a machine without them. The scene types
and the scene file functions below are imported on first use (they bring numpy): the
``coster-sumo`` command hands its work to a running server (:mod:`coster_sumo.cli.client`) without
importing them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from coster_sumo.errors import CosterError, InputError, SumoError

if TYPE_CHECKING:
    from coster_sumo.core.scene import (
        Lanes,
        LaneType,
        ObjectType,
        Polylines,
        Ragged,
        RoadMap,
        Scene,
        SignalState,
        SignalStates,
        Tracks,
        resample,
    )
    from coster_sumo.formats.scene_file import load_scene, save_scene

__version__ = "0.1.0"

_LAZY = {**dict.fromkeys(("load_scene", "save_scene"), "coster_sumo.formats.scene_file"),
         **dict.fromkeys(("Lanes", "LaneType", "ObjectType", "Polylines", "Ragged", "RoadMap", "Scene",
                          "SignalState", "SignalStates", "Tracks", "resample"), "coster_sumo.core.scene")}

__all__ = [
    "CosterError", "InputError", "SumoError", "Lanes", "LaneType", "ObjectType", "Polylines", "Ragged",
    "RoadMap", "Scene", "SignalState", "SignalStates", "Tracks", "load_scene", "resample", "save_scene",
]


def __getattr__(name: str) -> Any:
    """The scene types and functions of ``__all__``, imported when first asked for."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'coster_sumo' has no attribute {name!r}")
