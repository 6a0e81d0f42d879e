"""The snapshot init and the rollout a draw uses for its adversary class (``--adversary``).

``vehicle`` keeps the registries' methods (:data:`~coster_sumo.method.snapshot.SNAPSHOT_INITS`,
:data:`~coster_sumo.rollout.methods.ROLLOUTS`) untouched. ``pedestrian`` and ``cyclist`` take the
class's placement (:mod:`coster_sumo.method.vru.snapshot`; with ``--init snapshot`` its collision time reads
the prior's entropy, with ``--init random`` the random init's rule) and the class's kinematic rollout
(:func:`coster_sumo.method.vru.rollout.vru_rollout`): with ``--rollout cvae`` (the default) the class's
learned rollout when ``rollout_<class>.pt`` is in the models folder (:mod:`coster_sumo.method.vru.learned`),
else, and with any other ``--rollout``, the class's kinematic one (the rollout's info says which and why).
``any``: each draw picks one of the three classes uniformly with the generation's seeded generator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from coster_sumo.core.scene import RoadMap
from coster_sumo.core.snapshot import CollisionSnapshot
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.snapshot import SNAPSHOT_INITS, PlacementRequest, SnapshotInit
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import VEHICLE, VRU_CLASSES
from coster_sumo.method.vru.learned import class_checkpoint, class_checkpoint_name, load_class_rollout
from coster_sumo.method.vru.rollout import vru_rollout
from coster_sumo.method.vru.snapshot import vru_snapshot
from coster_sumo.rollout.methods import ROLLOUTS, Rollout
from coster_sumo.rollout.request import RolloutRequest, RolloutResult

ANY_CLASSES = ("vehicle", "cyclist", "pedestrian")


def class_area(name: str, road_map: RoadMap, drivable: DrivableArea, cache: dict[str, Any]) -> ClassArea:
    """The area of class ``name``, built once per ``cache`` (a draw memo's)."""
    area = cache.get(name)
    if area is None:
        area = cache[name] = ClassArea.build(VRU_CLASSES[name], road_map, drivable)
    return area  # type: ignore[no-any-return]


def draw_class(adversary: str, rng: np.random.Generator) -> str:
    """The class of one draw: ``adversary`` itself, or for ``any`` one drawn with ``rng``."""
    if adversary != "any":
        return adversary
    return str(ANY_CLASSES[int(rng.integers(len(ANY_CLASSES)))])


def methods_for(name: str, init: str, rollout: str, area: ClassArea | None) -> tuple[SnapshotInit, Rollout]:
    """The snapshot init and rollout of a draw of class ``name`` (module docstring)."""
    if name == VEHICLE or area is None:
        return SNAPSHOT_INITS[init], ROLLOUTS[rollout]
    vru = VRU_CLASSES[name]
    use_prior = init == "snapshot"

    def place(request: PlacementRequest) -> CollisionSnapshot:
        return vru_snapshot(request, vru, area, use_prior, init)

    def generate(request: RolloutRequest) -> RolloutResult:
        if rollout != "cvae":
            return vru_rollout(request, vru, area, note=f"--rollout {rollout}: the {vru.name}'s kinematic rollout")
        path = class_checkpoint(vru, request.models_dir)
        if path is None:
            return vru_rollout(request, vru, area, note=f"no {class_checkpoint_name(vru)} in the models folder: "
                               f"the {vru.name}'s kinematic rollout")
        return vru_rollout(request, vru, area, model=load_class_rollout(path, vru))

    return SnapshotInit(place), Rollout(generate)
