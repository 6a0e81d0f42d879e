"""What a rollout (``--rollout``, :mod:`coster_sumo.rollout.methods`) is asked for and what it returns.

Apart from the methods so that a method's own module (:func:`coster_sumo.rollout.sample.plan_variants`)
can take the request without importing the table of methods back.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.scene import Scene
from coster_sumo.core.snapshot import CollisionSnapshot
from coster_sumo.geometry.drivable import DrivableArea

RolloutResult = tuple[list[AdversaryPlan], "np.ndarray | None", dict[str, Any]]


@dataclass(frozen=True)
class RolloutRequest:
    """What a rollout is asked for: adversary plans that end in ``snapshot``.

    Attributes:
        scene_2hz: the nominal scene at 2 Hz.
        target: the target's agent index.
        snapshot: the collision snapshot the plans end in.
        drivable: the drivable area (None: no check).
        samples: trajectories to oversample; variants: representatives to keep (K).
        seed: the draw's seed; models_dir: the models folder (None: the shipped one).
    """

    scene_2hz: Scene
    target: int
    snapshot: CollisionSnapshot
    drivable: DrivableArea | None
    samples: int
    variants: int
    seed: int
    models_dir: Path | None = None
