"""Scene sources of a batch, and the nominal scenes they stand for.

A source is a ``.sumocfg`` (``CFG@seed=3,begin=20,end=50,target=veh`` overrides; ``seeds`` makes
several scenes from one configuration), a folder (every ``.sumocfg`` below it, e.g. converted WOMD
scenes), or a text file listing sources. Each becomes a :class:`~coster_sumo.core.spec.ScenarioSpec`
with a readable, stable key; its nominal scene is recorded once and cached under that key.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coster_sumo.batch.executor import DEFAULT_TIMEOUT_S
from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_folder import converted_scene_file
from coster_sumo.infra.atomic import atomic_path


@dataclass(kw_only=True)
class BatchOptions:
    """What every batch command takes: its sources, output folder, and how tasks run."""

    sources: list[str]
    out: Path
    workers: int = 1
    executor: str = "local"  # "local" processes or "ray"
    timeout: float | None = DEFAULT_TIMEOUT_S  # [s] wall clock per task
    seed: int = 0
    seeds: int = 1
    begin: float | None = None
    end: float | None = None
    target: str | None = None
    models_dir: Path | None = None
    quiet: bool = False
    ray_address: str | None = None


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "x"


def _short_hash(obj: Any) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:8]


def generation_identity(generation: dict[str, Any]) -> dict[str, Any]:
    """What a generation config is, for a key: the weights by their contents, not by the path given."""
    from coster_sumo.infra.weights import weights_digest

    ident = dict(generation)
    if "models_dir" in ident:
        ident["models"] = weights_digest(ident.pop("models_dir"))
    return ident


def window_name(spec: ScenarioSpec) -> str:
    """``<config stem>_s<seed>[_b<begin>][_e<end>]``: the readable part of a scene's or a pass's key."""
    name = f"{slug(spec.config.stem)}_s{spec.seed}"
    if spec.begin is not None:
        name += f"_b{spec.begin:g}"
    if spec.end is not None:
        name += f"_e{spec.end:g}"
    return name


def scene_key(spec: ScenarioSpec, generation: dict[str, Any] | None = None) -> str:
    """A readable, stable, file-safe key: ``<config stem>_s<seed>[_b<begin>][_e<end>]_<hash>``."""
    ident = {"config": str(spec.config.resolve()), "seed": spec.seed, "begin": spec.begin, "end": spec.end,
             "target": spec.target, "generation": generation_identity(generation or {})}
    return f"{window_name(spec)}_{_short_hash(ident)}"


def _staged_or_exported(relative: Path) -> bool:
    """A configuration below a source folder that is no scene: inside a hidden folder (a staging
    folder of a convert or run that was stopped, ``.git``) or inside a run's ``export/``."""
    return any(part.startswith(".") or part == "export" for part in relative.parts)


def _parse_overrides(text: str, where: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        k, eq, v = item.partition("=")
        if not eq or k not in ("seed", "seeds", "begin", "end", "target"):
            raise InputError(f"{where}: bad override {item!r}; use seed=N, seeds=N, begin=S, end=S or target=ID")
        out[k] = v
    return out


def parse_sources(sources: Sequence[str | Path], *, seed: int = 0, seeds: int = 1, begin: float | None = None,
                  end: float | None = None, target: str | None = None) -> list[ScenarioSpec]:
    """Expand scene sources into scenes (module docstring); duplicates are dropped, order kept.

    ``CFG@seed=3`` fixes the seed; ``seeds=N`` (per source or the keyword) makes N scenes with seeds
    seed, seed+1, ...; ``begin``/``end`` [s] bound the window; ``target`` names the target vehicle.
    """
    specs: list[ScenarioSpec] = []

    def add(path: Path, ov: dict[str, str], where: str, depth: int) -> None:
        if depth > 8:
            raise InputError(f"{where}: source lists nest too deeply")
        if path.is_dir():
            cfgs = sorted(p for p in path.rglob("*.sumocfg") if not _staged_or_exported(p.relative_to(path)))
            if not cfgs:
                raise InputError(f"{path}: no .sumocfg below this folder")
            for c in cfgs:
                add(c, ov, where, depth + 1)
            return
        if not path.exists():
            raise InputError(f"{path}: no such scene source (a .sumocfg, a folder of scenes or a list file)")
        if path.suffix == ".sumocfg":
            try:
                s0 = int(ov["seed"]) if "seed" in ov else seed
                n = int(ov.get("seeds", seeds)) if "seed" not in ov else 1
                b = float(ov["begin"]) if "begin" in ov else begin
                e = float(ov["end"]) if "end" in ov else end
            except ValueError as exc:
                raise InputError(f"{where}: bad override value ({exc})") from None
            if n < 1:
                raise InputError(f"{where}: seeds must be >= 1")
            for i in range(n):
                specs.append(ScenarioSpec(path, s0 + i, b, e, ov.get("target", target)))
            return
        for ln_no, line in enumerate(path.read_text().splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if line:
                p_text, _, o_text = line.partition("@")
                sub = Path(p_text)
                sub = sub if sub.is_absolute() else path.parent / sub
                add(sub, {**ov, **_parse_overrides(o_text, f"{path}:{ln_no}")}, f"{path}:{ln_no}", depth + 1)

    for src in sources:
        text = str(src)
        p_text, _, o_text = text.partition("@")
        add(Path(p_text), _parse_overrides(o_text, text), text, 0)
    seen: set[ScenarioSpec] = set()
    unique = []
    for s in specs:
        if s not in seen:
            seen.add(s)
            unique.append(s)
    return unique


CONFIG_DIR = "config_dir"  # the payload key of a task's configuration folder (a folder that travels on Ray)


def config_files(config: Path) -> tuple[str, ...]:
    """The files of the configuration's folder a task needs to simulate it: the ``.sumocfg``, the
    files it names inside its folder, and a converted scene's log and lane map. A file the
    configuration names outside its folder is not among them: on a cluster it must exist on every
    worker at the same path."""
    from coster_sumo.formats.scene_folder import SCENE_FILES
    from coster_sumo.formats.sumocfg import read_sumocfg

    folder = Path(os.path.abspath(config)).parent
    names = [config.name]
    try:
        inputs = [p for paths in read_sumocfg(config).inputs().values() for p in paths]
    except InputError:
        inputs = []
    for p in inputs:
        with contextlib.suppress(ValueError):
            names.append(Path(os.path.abspath(p)).relative_to(folder).as_posix())
    if converted_scene_file(config) is not None:
        names += SCENE_FILES
    return tuple(dict.fromkeys(names))


def config_dir(spec: ScenarioSpec) -> str:
    """The payload value of :data:`CONFIG_DIR` for ``spec``: its configuration's folder."""
    return str(Path(os.path.abspath(spec.config)).parent)


def task_folders(spec: ScenarioSpec, **more: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """:attr:`~coster_sumo.batch.executor.Task.folders` of a task that simulates ``spec``: its
    configuration's folder (payload key :data:`CONFIG_DIR`) and the payload folders in ``more``."""
    return {CONFIG_DIR: config_files(spec.config), **more}


def located(spec: ScenarioSpec, payload: dict[str, Any]) -> ScenarioSpec:
    """``spec`` with its configuration where the task finds it: in the payload's configuration
    folder (a private copy on a Ray worker), else where the driver named it."""
    folder = payload.get(CONFIG_DIR)
    if not folder:
        return spec
    return dataclasses.replace(spec, config=Path(folder) / spec.config.name)


def nominal_for(spec: ScenarioSpec, cache_dir: Path) -> tuple[Scene, bool, Path]:
    """The nominal 10 Hz scene of ``spec`` (recorded once, cached as ``cache_dir/<key>.npz``)."""
    from coster_sumo.formats.scene_file import load_scene, save_scene
    from coster_sumo.pipeline.scenario import nominal_scene

    key = scene_key(spec)
    path = cache_dir / f"{key}.npz"
    converted = converted_scene_file(spec.config) is not None
    if path.exists():
        return load_scene(path), converted, path
    scene, converted = nominal_scene(spec)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        save_scene(scene, tmp)
    return scene, converted, path
