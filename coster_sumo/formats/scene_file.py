"""The scene's own file: a :class:`~coster_sumo.core.scene.Scene` as one ``.npz``.

Every array of the scene's dataclasses is stored under its path of field names (``tracks/x``,
``road_map/lanes/centerline/values``); strings as fixed-width unicode, never pickled objects; the
scalars and ``meta`` in a JSON header with the format's version. Reading never unpickles, and a
damaged file is one :class:`~coster_sumo.errors.InputError` naming it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import Lanes, Polylines, Ragged, RoadMap, Scene, SignalStates, Tracks
from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import atomic_path

_FORMAT_VERSION = 1


def _flatten(prefix: str, obj: object, out: dict[str, np.ndarray]) -> None:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            _flatten(f"{prefix}{f.name}/", getattr(obj, f.name), out)
    elif isinstance(obj, np.ndarray):
        out[prefix.rstrip("/")] = obj


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write ``scene`` to one ``.npz`` (atomic: temporary name, then rename)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    _flatten("", scene, arrays)
    header = {"version": _FORMAT_VERSION, "scenario_id": scene.scenario_id, "sdc_index": scene.sdc_index,
              "current_time_index": scene.current_time_index, "source": scene.source, "meta": scene.meta}
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    for key, value in list(arrays.items()):
        if value.dtype.kind in "OU":  # store strings as fixed-width unicode, never pickled objects
            arrays[key] = value.astype(str)
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
    return path


def _build(cls: type, prefix: str, arrays: dict[str, np.ndarray]) -> object:
    kwargs = {}
    for f in dataclasses.fields(cls):
        key = f"{prefix}{f.name}"
        sub = _SUBTYPES.get((cls, f.name))
        if sub is not None:
            kwargs[f.name] = _build(sub, key + "/", arrays)
        elif key in arrays:
            kwargs[f.name] = arrays[key]
    return cls(**kwargs)


_SUBTYPES: dict[tuple[type, str], type] = {
    (Scene, "tracks"): Tracks, (Scene, "road_map"): RoadMap, (Scene, "signals"): SignalStates,
    (RoadMap, "lanes"): Lanes, (RoadMap, "road_lines"): Polylines, (RoadMap, "road_edges"): Polylines,
    (RoadMap, "crosswalks"): Polylines, (RoadMap, "junctions"): Polylines,
    (RoadMap, "stop_sign_lanes"): Ragged, (Polylines, "points"): Ragged,
    **{(Lanes, n): Ragged for n in ("centerline", "predecessors", "successors", "left_neighbors",
                                    "right_neighbors")},
}


def load_scene(path: str | Path) -> Scene:
    """Read a scene written by :func:`save_scene` (never unpickles; damaged files are one InputError)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except OSError as exc:
        raise InputError(f"{path}: not a scene file ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - BadZipFile, ValueError (pickled data), zlib.error, EOFError, ...
        raise InputError(f"{path}: not a scene file ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    if "__header__" not in arrays:
        raise InputError(f"{path}: not a scene file (no header)")
    try:
        header = json.loads(arrays.pop("__header__").tobytes().decode())
        if not isinstance(header, dict):
            raise ValueError("the header is not a JSON object")
        if header.get("version") != _FORMAT_VERSION:
            raise InputError(f"{path}: scene format version {header.get('version')} is not supported")
        parts = {name: _build(_SUBTYPES[(Scene, name)], name + "/", arrays)
                 for name in ("tracks", "road_map", "signals")}
        scene = Scene(scenario_id=str(header["scenario_id"]), timestamps=arrays["timestamps"],
                      sdc_index=int(header["sdc_index"]), current_time_index=int(header["current_time_index"]),
                      source=str(header["source"]), meta=dict(header.get("meta", {})),
                      **parts)  # type: ignore[arg-type]
        return scene.validate()
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if msg.startswith(f"{path}:") else f"{path}: {msg}") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, UnicodeDecodeError) as exc:
        what = f"missing {exc.args[0]!r}" if isinstance(exc, KeyError) and exc.args else \
            f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        raise InputError(f"{path}: damaged scene file ({what})") from None
