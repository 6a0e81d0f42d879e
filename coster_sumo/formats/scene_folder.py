"""The converted-scene folder: what makes a folder "a converted WOMD scene", and its conventions.

``coster-sumo convert`` writes one folder per scenario: ``<id>.sumocfg`` with its net and routes,
``scene.npz`` (the logged scene, timestamps on SUMO's clock) and ``lane_map.json`` (WOMD lane id per
SUMO lane, and per traffic light the WOMD lane of every SUMO link index). A configuration is a
converted scene exactly when ``scene.npz`` and ``lane_map.json`` lie beside it; everything that asks
"is this a converted scene" asks :func:`converted_scene_file`.

What it means for a run: the log is the nominal traffic (no SUMO demand exists for its agents), and
every logged agent is driven from the log by moveToXY; the target follows its log too unless a
planner takes it over (see :mod:`coster_sumo.sim.inject`).
"""

from __future__ import annotations

import hashlib
import re
import warnings
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene, SignalState

SCENE_FILE = "scene.npz"
LANE_MAP_FILE = "lane_map.json"
# the isolated edge 1 km below a converted map where the log replay stages agents for one step
# (converters/to_sumo.py builds it); no export shows it
STAGING_EDGE = "coster_staging"
SCENE_FILES = (SCENE_FILE, LANE_MAP_FILE)
MIN_SIZE_M = 0.1  # [m] SUMO rejects zero-length types; WOMD zero-fills invalid sizes


MAX_FOLDER_NAME = 100  # characters kept of a scenario id (the file names add a suffix)
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def folder_name(scenario_id: str) -> str:
    """The folder (and file stem) name of a scenario: ``scenario_id`` itself when it is safe.

    Safe: not empty, only letters, digits, ``_ . -``, not starting with a dot (no ``..``, no hidden
    folder), at most :data:`MAX_FOLDER_NAME` characters. Real WOMD ids (16 hex digits) are kept as
    they are. Any other id becomes its safe characters (runs of the others replaced by ``_``) plus
    ``-`` and 8 hex digits of the id's SHA-1, so different ids keep different names.
    """
    sid = str(scenario_id)
    if sid and len(sid) <= MAX_FOLDER_NAME and not _UNSAFE.search(sid) and not sid.startswith("."):
        return sid
    digest = hashlib.sha1(sid.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    base = _UNSAFE.sub("_", sid).lstrip("._-")[:MAX_FOLDER_NAME - 9].rstrip(".")
    return f"{base}-{digest}" if base else f"scenario-{digest}"


def converted_scene_file(config: str | Path) -> Path | None:
    """``scene.npz`` of the converted scene ``config`` belongs to, or None for any other configuration."""
    folder = Path(config).parent
    return folder / SCENE_FILE if all((folder / f).is_file() for f in SCENE_FILES) else None


def is_converted_scene(folder: str | Path) -> bool:
    """True when ``folder`` holds a ``.sumocfg`` of a converted scene."""
    folder = Path(folder)
    return folder.is_dir() and any(converted_scene_file(c) is not None for c in folder.glob("*.sumocfg"))


# WOMD signal state -> SUMO link state letter (r red, y yellow, G protected green, g green that
# yields, o off-blinking (yield), O off (no signal)).
SUMO_SIGNAL_LETTER: dict[int, str] = {
    SignalState.UNKNOWN: "O", SignalState.ARROW_STOP: "r", SignalState.ARROW_CAUTION: "y",
    SignalState.ARROW_GO: "G", SignalState.STOP: "r", SignalState.CAUTION: "y", SignalState.GO: "g",
    SignalState.FLASHING_STOP: "r", SignalState.FLASHING_CAUTION: "o",
}

# WOMD object type -> (vType id in the converted .rou.xml, vClass, guiShape, default length [m],
# default width [m]). Pedestrians and cyclists are vehicles of class pedestrian / bicycle: SUMO's
# moveToXY drives vehicles, and the replay needs their exact boxes, not a pedestrian model.
VTYPES: dict[int, tuple[str, str, str, float, float]] = {
    ObjectType.VEHICLE: ("womd_vehicle", "passenger", "passenger", 4.5, 1.9),
    ObjectType.PEDESTRIAN: ("womd_pedestrian", "pedestrian", "pedestrian", 0.5, 0.5),
    ObjectType.CYCLIST: ("womd_cyclist", "bicycle", "bicycle", 1.8, 0.6),
    ObjectType.OTHER: ("womd_other", "passenger", "passenger", 4.5, 1.9),
    ObjectType.UNSET: ("womd_other", "passenger", "passenger", 4.5, 1.9),
}


def vtype_for(object_type: int) -> tuple[str, str, str, float, float]:
    """The :data:`VTYPES` row of a WOMD object type (unknown codes count as OTHER)."""
    return VTYPES.get(int(object_type), VTYPES[ObjectType.OTHER])


# SUMO vehicle class -> WOMD object type (everything else on wheels is a VEHICLE)
_OBJECT_TYPE_OF_VCLASS = {"bicycle": ObjectType.CYCLIST, "pedestrian": ObjectType.PEDESTRIAN,
                          "wheelchair": ObjectType.PEDESTRIAN}


def object_type_of_vclass(vclass: str) -> ObjectType:
    """The WOMD object type a SUMO vehicle class is recorded as (bicycle: CYCLIST, pedestrian and
    wheelchair: PEDESTRIAN, anything else: VEHICLE)."""
    return _OBJECT_TYPE_OF_VCLASS.get(vclass, ObjectType.VEHICLE)


def tls_state_strings(scene: Scene, tls: dict[str, dict]) -> dict[str, list[str]]:
    """Per traffic light, the SUMO state string at every step of the log.

    Args:
        scene: the logged scene (its ``signals``).
        tls: ``lane_map.json``'s ``"tls"``: per tls id ``{"links": [WOMD lane id or None, ...]}``,
            one entry per SUMO link index.

    Returns:
        tls id -> (num_steps,) list of state strings; links without a logged signal are ``O``.
    """
    per_lane = scene.signals.per_lane(len(scene.road_map.lanes))  # (T, num_lanes)
    col = {str(lid): i for i, lid in enumerate(scene.road_map.lanes.ids)}
    letters = np.array([SUMO_SIGNAL_LETTER.get(v, "O") for v in range(256)])
    out: dict[str, list[str]] = {}
    for tid, entry in tls.items():
        cols = np.array([col.get(str(lid), -1) if lid is not None else -1 for lid in entry["links"]],
                        np.int64)
        if len(cols) == 0:
            continue
        codes = per_lane[:, np.maximum(cols, 0)].astype(np.int64) % 256  # (T, L)
        chars = letters[codes]
        chars[:, cols < 0] = "O"
        out[tid] = ["".join(row) for row in chars]
    return out


def _valid_medians(values: np.ndarray, valid: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(A,) float64: each row's median over its valid steps (NaN where none is valid). A row whose valid
    values are all equal (a SUMO vehicle's size never changes) is that value, which is its median; the
    others go through ``np.nanmedian`` (slow per row: a reset of the environment asks for every agent)."""
    lo = np.where(valid, values, np.inf).min(axis=1)
    hi = np.where(valid, values, -np.inf).max(axis=1)
    constant = lo == hi
    med = np.where(constant, lo, np.nan).astype(np.float64)
    mixed = np.flatnonzero(seen & ~constant)
    if len(mixed):
        with warnings.catch_warnings():  # a row of non-finite sizes only: NaN, as below
            warnings.simplefilter("ignore", RuntimeWarning)
            med[mixed] = np.nanmedian(np.where(valid[mixed], values[mixed], np.nan), axis=1).astype(np.float64)
    return med


def agent_sizes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(num_agents,) length and width [m]: the median over valid steps (SUMO's size is fixed)."""
    tr = scene.tracks
    valid = tr.valid
    seen = np.any(valid, axis=1)
    defaults = np.array([vtype_for(int(t))[3:5] for t in tr.object_type], np.float64).reshape(-1, 2)
    sizes = []
    for values, default in ((tr.length, defaults[:, 0]), (tr.width, defaults[:, 1])):
        med = _valid_medians(values, valid, seen)
        med[(valid & ~np.isfinite(values)).any(axis=1)] = np.nan  # a non-finite logged size: as np.median gives
        sizes.append(np.where(seen, med, default))
    lengths, widths = sizes
    bad_l = ~np.isfinite(lengths) | (lengths < MIN_SIZE_M)
    bad_w = ~np.isfinite(widths) | (widths < MIN_SIZE_M)
    lengths[bad_l] = MIN_SIZE_M
    widths[bad_w] = MIN_SIZE_M
    return lengths, widths
