"""Rollouts (``--rollout``): how the adversary's approach is generated backwards from the snapshot.

A rollout takes the nominal scene at 2 Hz, the target, the snapshot and the drivable area and
returns adversary plans (2 Hz knots ending in the snapshot state), the oversampled trajectories for
pictures (or None) and an info dict. A new rollout is one function and one line in :data:`ROLLOUTS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.rollout.baselines import constant_velocity_backward
from coster_sumo.rollout.request import RolloutRequest, RolloutResult

HORIZON_STEPS = 10  # [2 Hz steps] 5 s of approach at most


class RolloutMethod(Protocol):
    """A rollout: (plans, samples_xy (N, T, 2) [m] or None, info) for one request."""

    def __call__(self, request: RolloutRequest) -> RolloutResult: ...


@dataclass(frozen=True)
class Rollout:
    """A rollout method of ``--rollout``.

    Attributes:
        generate: the method itself.
        weights: files it needs from the models folder.
        one_per_snapshot: it yields one trajectory per snapshot, so a batch that wants K variants
            draws K snapshots.
    """

    generate: RolloutMethod
    weights: tuple[str, ...] = ()
    one_per_snapshot: bool = False


def constant_velocity(request: RolloutRequest) -> RolloutResult:
    """Straight back along the snapshot heading at the snapshot speed, up to :data:`HORIZON_STEPS`."""
    snapshot = request.snapshot
    t = request.scene_2hz.timestamps
    h = min(HORIZON_STEPS, snapshot.t_index)
    times = t[snapshot.t_index - h: snapshot.t_index + 1]
    poses = constant_velocity_backward(snapshot.adversary, times - times[-1])  # (h+1, 3)
    return [AdversaryPlan.from_knots(times, poses, snapshot.adversary)], None, {"rollout": "constant_velocity"}


def cvae(request: RolloutRequest) -> RolloutResult:
    """COSTER: oversample the time-reversed CVAE, K-means, refine with the motion vocabulary."""
    from coster_sumo.rollout.sample import plan_variants

    return plan_variants(request)


ROLLOUTS: dict[str, Rollout] = {
    "cvae": Rollout(cvae, weights=("rollout.pt",)),
    "cv": Rollout(constant_velocity, one_per_snapshot=True),
}
