"""coster-sumo: COSTER safety-critical scenario generation injected into SUMO.

Nothing here imports SUMO or torch: those are imported where they are used, so that
``import coster_sumo`` works (and fails clearly later) on a machine without them.
"""

from coster_sumo.errors import CosterError, InputError, SumoError
from coster_sumo.formats.scene_file import load_scene, save_scene
from coster_sumo.scene import (
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

__version__ = "0.1.0"

__all__ = [
    "CosterError", "InputError", "SumoError", "Lanes", "LaneType", "ObjectType", "Polylines", "Ragged",
    "RoadMap", "Scene", "SignalState", "SignalStates", "Tracks", "load_scene", "resample", "save_scene",
]
