"""One nominal pass per configuration, window and seed in a batch, whatever the number of targets.

A scene's key holds its target (:func:`~coster_sumo.batch.sources.scene_key`), so each target of a
configuration would record a nominal pass of its own. Where a batch has two or more named targets
of one configuration, window and seed, they share one pass instead, recorded as ``coster-sumo run
--target A --target B`` records it (:func:`coster_sumo.pipeline.scenario.nominal_scene` with the first
target leading and the others as ``more_targets``: the union of their surroundings). A pass task
writes it as ``<plans>/<pass key>.npz`` before any of the group's generation tasks starts; each of
them reads it (on Ray the file travels through the object store with the task, as every file a
task names in :attr:`~coster_sumo.batch.executor.Task.folders`). The file stays in the batch's
folder: a batch that is stopped and started again reads it and records no pass again. The pass
key holds every target of the group in order, so adding a target to a batch records a new pass.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from coster_sumo.batch.executor import Task
from coster_sumo.batch.sources import CONFIG_DIR, _short_hash, config_dir, located, task_folders, window_name
from coster_sumo.core.scene import Scene
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.formats.scene_folder import converted_scene_file
from coster_sumo.infra.atomic import atomic_path, write_json

PASS_FILE = "pass_file"  # the payload key of a generation task that reads a shared pass


def pass_key(specs: Sequence[ScenarioSpec]) -> str:
    """A readable, stable, file-safe key of the pass ``specs`` share (one configuration, window and
    seed; their targets in order): ``pass_<config stem>_s<seed>[_b<begin>][_e<end>]_<n>t_<hash>``."""
    s = specs[0]
    name = f"pass_{window_name(s)}"
    ident = {"config": str(s.config.resolve()), "seed": s.seed, "begin": s.begin, "end": s.end,
             "targets": [t.target for t in specs]}
    return f"{name}_{len(specs)}t_{_short_hash(ident)}"


def shared_passes(keys: Mapping[str, ScenarioSpec]) -> dict[str, list[str]]:
    """Pass key -> the scene keys that share it: the scenes with a named target, grouped by
    configuration, window and seed, where a group has two or more (a lone target keeps a pass of
    its own, as before; so does a scene without a named target)."""
    groups: dict[tuple[str, int, float | None, float | None], list[str]] = {}
    for key, s in keys.items():
        if s.target is not None:
            groups.setdefault((str(s.config.resolve()), s.seed, s.begin, s.end), []).append(key)
    return {pass_key([keys[k] for k in ks]): ks for ks in groups.values() if len(ks) > 1}


def pass_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Task: the nominal pass of ``payload["targets"]`` (the first leads) -> ``<plans>/<pass key>.npz``,
    and beside it ``<pass key>.json`` (its targets and how long it took). Records nothing when the
    ``.npz`` is there already."""
    from coster_sumo.formats.scene_file import save_scene
    from coster_sumo.pipeline.scenario import nominal_scene

    plans_dir, key = Path(payload["plans_dir"]), payload["pass_key"]
    path = plans_dir / f"{key}.npz"
    if path.exists():
        return {"pass_key": key, "recorded": False}
    t0 = time.perf_counter()
    spec = located(ScenarioSpec.from_dict(payload["spec"]), payload)
    targets = [str(t) for t in payload["targets"]]
    scene, _ = nominal_scene(spec, more_targets=targets[1:])
    plans_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        save_scene(scene, tmp)
    write_json(plans_dir / f"{key}.json", {"pass_key": key, "spec": spec.to_dict(), "targets": targets,
                                           "scene_file": path.name, "end": float(scene.timestamps[-1]),
                                           "pass_s": round(time.perf_counter() - t0, 3)})
    return {"pass_key": key, "recorded": True}


def pass_task_for(key: str, specs: Sequence[ScenarioSpec], plans_dir: Path) -> Task:
    """The task that records the pass ``specs`` share (:func:`pass_key`), with the configuration's
    folder named so that it runs on a Ray worker without a disk shared with OUT."""
    lead = specs[0]
    return Task(f"pass__{key}", pass_task,
                {"pass_key": key, "spec": lead.to_dict(), "targets": [s.target for s in specs],
                 "plans_dir": str(plans_dir), CONFIG_DIR: config_dir(lead)},
                kind="pass", folders=task_folders(lead, plans_dir=()))


def shared_nominal(spec: ScenarioSpec, plans_dir: Path, pass_file: str) -> tuple[Scene, bool, Path]:
    """The nominal scene a generation task reads from a shared pass (what
    :func:`~coster_sumo.batch.sources.nominal_for` returns for a pass of its own)."""
    from coster_sumo.formats.scene_file import load_scene

    path = plans_dir / pass_file
    return load_scene(path), converted_scene_file(spec.config) is not None, path


def recorded_pass(plans_dir: Path, key: str) -> bool:
    """Whether the pass ``key`` is in ``plans_dir`` already (a batch stopped after recording it)."""
    return (plans_dir / f"{key}.npz").exists()



class SharedPasses:
    """The shared passes of a batch's scenes (``keys``: scene key -> spec; the passes are written
    into ``folder``) and the scenes waiting for theirs to be recorded."""

    def __init__(self, keys: Mapping[str, ScenarioSpec], folder: Path) -> None:
        self.keys, self.folder = keys, folder
        self.groups = shared_passes(keys)  # pass key -> the scenes (targets) that share it
        self.pass_of = {k: pk for pk, ks in self.groups.items() for k in ks}
        self.waiting: dict[str, list[str]] = {}  # pass key -> the scenes that go on once it is recorded

    def pass_file(self, key: str) -> str | None:
        """The file of the pass scene ``key`` shares (in :attr:`folder`); None: a pass of its own."""
        return f"{self.pass_of[key]}.npz" if key in self.pass_of else None

    def wait(self, key: str) -> bool:
        """Whether scene ``key`` must wait for its shared pass (then it is queued for it): the pass
        is shared and not recorded yet."""
        pk = self.pass_of.get(key)
        if pk is None or recorded_pass(self.folder, pk):
            return False
        self.waiting.setdefault(pk, []).append(key)
        return True

    def tasks(self) -> list[Task]:
        """A task per pass some scene waits for."""
        return [pass_task_for(pk, [self.keys[k] for k in self.groups[pk]], self.folder) for pk in self.waiting]

    def released(self, task: Task) -> list[str]:
        """The scenes that waited for the pass of ``task`` (a :func:`pass_task`), now finished."""
        return self.waiting.get(task.payload["pass_key"], [])

    @property
    def waiting_scenes(self) -> int:
        return sum(map(len, self.waiting.values()))
