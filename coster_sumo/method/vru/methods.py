"""The snapshot init and the rollout a draw uses for its adversary class (``--adversary``).

``vehicle`` keeps the registries' methods (:data:`~coster_sumo.method.snapshot.SNAPSHOT_INITS`,
:data:`~coster_sumo.rollout.methods.ROLLOUTS`) untouched. ``pedestrian`` and ``cyclist`` take the
class's placement (:mod:`coster_sumo.method.vru.snapshot`; with ``--init snapshot`` its collision time reads
the prior's entropy, with ``--init random`` the random init's rule) and the class's kinematic rollout
(:func:`coster_sumo.method.vru.rollout.vru_rollout`): with ``--rollout cvae`` (the default) the class's
learned rollout when ``rollout_<class>.pt`` is in the models folder (:mod:`coster_sumo.method.vru.learned`),
else, and with any other ``--rollout``, the class's kinematic one (the rollout's info says which and why).
``any``: the regional traffic chooses the class (:func:`class_shares`): each draw picks vehicle,
cyclist or pedestrian with the shares in which the nominal pass's agents of each class travelled
near the target's path, every class kept at :data:`ANY_FLOOR` or more, with the generation's
seeded generator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from coster_sumo.core.scene import RoadMap, Scene
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
ANY_RADIUS_M = 30.0  # [m] the region of ``any``: agents' centres this close to the target's path count
ANY_FLOOR = 0.1  # every class keeps this share at least (a network without walkers still gets some)


def class_area(name: str, road_map: RoadMap, drivable: DrivableArea, cache: dict[str, Any]) -> ClassArea:
    """The area of class ``name``, built once per ``cache`` (a draw memo's)."""
    area = cache.get(name)
    if area is None:
        area = cache[name] = ClassArea.build(VRU_CLASSES[name], road_map, drivable)
    return area  # type: ignore[no-any-return]


def class_shares(scene: Scene, target: int) -> np.ndarray:
    """(3,) the probabilities of :data:`ANY_CLASSES` for ``any``: the shares of the agent-steps of
    the scene (every agent but the target, at every valid step) within :data:`ANY_RADIUS_M` of the
    target's path, per class (object types: CYCLIST, PEDESTRIAN, everything else a vehicle), mixed
    with :data:`ANY_FLOOR` per class (uniform where nobody travelled near the path)."""
    import shapely

    tr = scene.tracks
    mine = tr.valid[target]
    path = np.stack([tr.x[target, mine], tr.y[target, mine]], -1)
    counts = np.zeros(len(ANY_CLASSES))
    if len(path):
        line = shapely.LineString(path) if len(path) > 1 else shapely.Point(path[0])
        others = tr.valid.copy()
        others[target] = False
        agent, step = np.nonzero(others)
        near = shapely.dwithin(line, shapely.points(tr.x[agent, step], tr.y[agent, step]), ANY_RADIUS_M)
        kinds = tr.object_type[agent[near]]
        vru = {name: int(np.count_nonzero(kinds == VRU_CLASSES[name].object_type)) for name in VRU_CLASSES}
        counts = np.array([vru.get(c, len(kinds) - sum(vru.values())) for c in ANY_CLASSES], np.float64)
    shares = counts / counts.sum() if counts.sum() > 0 else np.full(len(ANY_CLASSES), 1.0 / len(ANY_CLASSES))
    return ANY_FLOOR + (1.0 - ANY_FLOOR * len(ANY_CLASSES)) * shares  # type: ignore[no-any-return]


def draw_class(adversary: str, rng: np.random.Generator, shares: np.ndarray | None = None) -> str:
    """The class of one draw: ``adversary`` itself, or for ``any`` one drawn with ``rng`` with
    probabilities ``shares`` (:func:`class_shares`; None: uniform)."""
    if adversary != "any":
        return adversary
    return str(ANY_CLASSES[int(rng.choice(len(ANY_CLASSES), p=shares))])


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
