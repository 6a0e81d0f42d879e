"""The learned time-reversed rollout of a pedestrian or cyclist (docs/method.md, "Pedestrian and
cyclist adversaries", rollout).

``models/rollout_<class>.pt`` is the rollout CVAE trained on that class's tracks only
(``coster-sumo train rollout --agent-class pedestrian|cyclist``, card ``models/rollout_vru.md``).
Where it is in the models folder, a VRU draw samples it backwards from the snapshot exactly as a
vehicle draw samples the vehicle CVAE (:func:`coster_sumo.rollout.sample.sample_trajectories`: the
last pose of every sample is the snapshot, so contact at t_col holds). The class's kinematic limits
then hold on what is kept: a sample whose 2 Hz speed, acceleration or turning leaves the limits is
**rejected**, not clipped. Clipping would move the earlier poses of a sample (the speed is
integrated backwards from the snapshot) and could break what made the sample plausible; rejecting
keeps the learned shapes as they are, and :func:`coster_sumo.method.vru.rollout.vru_rollout` checks
the densified plan of every representative again. Without the checkpoint the kinematic rollout
runs instead and the rollout's info says so.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coster_sumo.infra import weights
from coster_sumo.method.vru.classes import Kinematics, VruClass, within_limits

if TYPE_CHECKING:
    from coster_sumo.rollout.model import RolloutCVAE
    from coster_sumo.rollout.request import RolloutRequest

LEARNED_MAX_SAMPLES = 1000  # as many as a vehicle draw oversamples by default
KNOT_S = 0.5  # [s] the 2 Hz knots
YAW_RATE_TOLERANCE = 0.1  # [rad/s] finite differences of 2 Hz headings (a standing rider's heading jitters)


def class_checkpoint_name(vru: VruClass) -> str:
    """The file name of the class's learned rollout in a models folder."""
    return f"rollout_{vru.name}.pt"


def class_checkpoint(vru: VruClass, models_dir: str | Path | None) -> Path | None:
    """The class's learned rollout in ``models_dir`` (default: the shipped models), or None."""
    path = weights.models_folder(models_dir) / class_checkpoint_name(vru)
    return path if path.is_file() else None


def load_class_rollout(path: Path, vru: VruClass) -> RolloutCVAE:
    """The rollout model of ``path`` (loaded once per process); one error line when it models
    another class than ``vru``."""
    from coster_sumo.rollout.checkpoint import load_model, require_class

    return require_class(weights.load_cached(path, load_model), vru.name, path)


def within_turn_limits(vru: VruClass, kin: Kinematics) -> np.ndarray:
    """(N,) bool: every yaw rate of ``kin`` within the class's turning: a pedestrian turns on the spot
    up to its yaw-rate limit; a bicycle's yaw rate is also bounded by its tightest radius and its
    lateral acceleration at that speed (it cannot turn standing)."""
    rate = np.abs(kin.yaw_rate)  # (N, T-1)
    limit = np.full(rate.shape, vru.max_yaw_rate)
    if vru.min_turn_radius > 0.0:
        v = np.maximum(0.5 * (kin.speed[:, 1:] + kin.speed[:, :-1]), 1e-3)  # [m/s] over each interval
        limit = np.minimum(limit, v / vru.min_turn_radius)
        if vru.max_lateral_accel is not None:
            limit = np.minimum(limit, vru.max_lateral_accel / v)
    return np.all(rate <= limit + YAW_RATE_TOLERANCE, axis=1)  # type: ignore[no-any-return]


def within_class(vru: VruClass, knots: np.ndarray) -> np.ndarray:
    """(N,) bool: the 2 Hz knots (N, T, 3) keep the class's speed, acceleration and turning limits."""
    if knots.shape[1] < 2:
        return np.ones(len(knots), bool)
    kin = Kinematics.of(knots[..., :2], knots[..., 2], KNOT_S)
    return within_limits(vru, kin) & within_turn_limits(vru, kin)  # type: ignore[no-any-return]


def learned_knots(request: RolloutRequest, model: RolloutCVAE, horizon: int) -> np.ndarray:
    """(N, horizon + 1, 3) samples x, y [m], yaw [rad] of the learned rollout at 2 Hz, time order,
    the last one the snapshot exactly; N = the request's samples, at most :data:`LEARNED_MAX_SAMPLES`."""
    from coster_sumo.rollout.sample import sample_trajectories

    n = min(request.samples, LEARNED_MAX_SAMPLES)
    return sample_trajectories(model, request.scene_2hz, request.snapshot, n=n, seed=request.seed, horizon=horizon)
