"""Settings of the rollout CVAE and its input encoding (saved in every checkpoint; no torch here)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from coster_sumo.core.scene import ObjectType
from coster_sumo.errors import InputError

VEHICLE_CLASS = "vehicle"
# --agent-class -> the WOMD object type (coster_sumo.core.scene.ObjectType) of the tracks it learns
AGENT_CLASSES = {VEHICLE_CLASS: ObjectType.VEHICLE, "pedestrian": ObjectType.PEDESTRIAN,
                 "cyclist": ObjectType.CYCLIST}


@dataclass
class RolloutConfig:
    """Model and input-encoding settings (saved in every checkpoint).

    Attributes:
        hidden: width D of every embedding and of the recurrent state.
        heads: attention heads (D must be divisible by it).
        latent: size of each per-step latent z_k.
        posterior_hidden: width of the posterior GRU over the true reverse segment.
        max_horizon: [2 Hz steps] longest reconstruction (10 = 5 s); shorter when t_rev is early.
        use_dsa: dynamic surrounding attention (False: neighbours as at t_rev only).
        map_every_step: attend to the map again at every step (factored like DSA; cheap).
        max_neighbors, neighbor_radius_m: at most this many neighbours, within this distance of the
            sample at every step (masked per sample).
        neighbor_select_radius_m: [m] neighbours are chosen among agents this close to the t_rev
            position (larger than ``neighbor_radius_m``: samples move).
        max_map_chunks, map_radius_m: map chunks kept around the t_rev position.
        lane_spacing_m, chunk_vectors: lanes resampled every ``lane_spacing_m``, chunks of this many
            vectors.
        disp_scale: (3,) scale of the decoder's output, the correction of (dx [m], dy [m], dyaw [rad])
            to a constant-velocity step (see :meth:`RolloutCVAE.rollout`).
        pos_scale_m, vel_scale_mps: input normalisation.
        recon_sigma: (3,) fixed standard deviation of the Gaussian reconstruction term.
        kl_weight: weight of the KL term (1 = the ELBO).
        free_nats: per step, KL below this is not penalised (0 = the plain ELBO).
        best_of: K > 0 adds a best-of-K term to the training loss: K samples from the prior, and
            the smallest of their errors (mean over the valid steps plus the last valid step's
            distance, in metres) times ``best_of_weight``. The ELBO trains the prior to match the
            posterior one sample at a time; minADE / minFDE score the best of several prior
            samples, which this term rewards directly (0: the plain ELBO). Left out of
            :meth:`to_dict` at 0, like ``agent_class``.
        best_of_weight: [1/m] weight of the best-of-K term.
        agent_class: whose tracks the model learns and reconstructs: ``vehicle``, ``pedestrian`` or
            ``cyclist`` (:data:`AGENT_CLASSES`; one model per class). Left out of :meth:`to_dict`
            for ``vehicle``, so that vehicle checkpoints, training states and feature caches are
            what they were before the option existed (a config without it is a vehicle's).
    """

    hidden: int = 256
    heads: int = 8
    latent: int = 32
    posterior_hidden: int = 128
    max_horizon: int = 10
    use_dsa: bool = True
    map_every_step: bool = True
    max_neighbors: int = 32
    neighbor_radius_m: float = 50.0
    neighbor_select_radius_m: float = 80.0
    max_map_chunks: int = 128
    map_radius_m: float = 80.0
    lane_spacing_m: float = 2.0
    chunk_vectors: int = 5
    # scales: of the decoder's output, then of its inputs
    disp_scale: tuple[float, float, float] = (1.0, 0.3, 0.05)
    pos_scale_m: float = 20.0
    vel_scale_mps: float = 10.0
    recon_sigma: tuple[float, float, float] = (0.2, 0.1, 0.02)
    kl_weight: float = 1.0
    free_nats: float = 0.0
    agent_class: str = "vehicle"
    best_of: int = 0
    best_of_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.agent_class not in AGENT_CLASSES:
            raise InputError(f"rollout config: agent class {self.agent_class!r} is not one of "
                             f"{', '.join(AGENT_CLASSES)}")
        if not 0.0 < self.neighbor_radius_m <= self.neighbor_select_radius_m:
            raise InputError(f"rollout config: neighbour radius {self.neighbor_radius_m:g} m must be above 0 and "
                             f"at most the {self.neighbor_select_radius_m:g} m within which neighbours are kept")
        if self.hidden % self.heads:
            raise InputError(f"rollout config: hidden {self.hidden} is not divisible by heads {self.heads}")
        if self.max_horizon < 1:
            raise InputError("rollout config: max_horizon must be >= 1")
        if self.best_of < 0 or self.best_of_weight < 0:
            raise InputError("rollout config: best_of and best_of_weight must be at least 0")
        self.disp_scale = tuple(float(v) for v in self.disp_scale)  # type: ignore[assignment]
        self.recon_sigma = tuple(float(v) for v in self.recon_sigma)  # type: ignore[assignment]

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["disp_scale"] = list(self.disp_scale)
        d["recon_sigma"] = list(self.recon_sigma)
        if self.agent_class == VEHICLE_CLASS:
            del d["agent_class"]
        if not self.best_of:
            del d["best_of"], d["best_of_weight"]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RolloutConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise InputError (a mismatched checkpoint)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise InputError(f"unknown rollout config key(s): {', '.join(unknown)}")
        try:
            return cls(**d)
        except TypeError as exc:
            raise InputError(f"bad rollout config: {exc}") from None


# Settings that size no weight and leave each weight's meaning alone: a run that starts from a
# checkpoint's weights (``train rollout --init``) may change them. The radius only masks which of
# the cached neighbours (those within ``neighbor_select_radius_m``) dynamic surrounding attention
# sees; the KL weight and the reconstruction sigma only weigh the terms of the loss. The class only
# chooses the training tracks: a pedestrian model may start from a vehicle model's weights (at the
# vehicle's ``disp_scale``, which gives the decoder's output its meaning, see CLASS_SCALES).
FREE_ON_INIT = ("neighbor_radius_m", "kl_weight", "agent_class", "recon_sigma", "best_of", "best_of_weight")

# The output scales of each class's model (``--agent-class``; ``--disp-scale`` / ``--recon-sigma``
# override them). The decoder corrects a constant-velocity step by ``disp_scale * output`` and the
# reconstruction term weighs the correction's error by ``1 / recon_sigma``. Measured on the 2 Hz
# tracks of the pedestrian corpus (docs/method.md, "Pedestrian and cyclist adversaries"), the
# spread (sd) of the true reverse step around the constant-velocity step (dx, dy [m], dyaw [rad]) is
# 0.25 / 0.14 / 0.067 for vehicles, 0.079 / 0.071 / 0.10 for pedestrians and 0.093 / 0.069 / 0.054
# for cyclists. A pedestrian is slow and turns on the spot: its forward and sideways corrections
# are alike and small, its heading corrections are the largest of the three classes, and the
# vehicle's 0.02 rad heading sigma would make a pedestrian's turns at a corner (0.5 rad in a step)
# outweigh everything else in the loss. A cyclist is a slower vehicle: the vehicle's heading
# scales, forward and sideways ones at its speed.
CLASS_SCALES: dict[str, dict[str, tuple[float, float, float]]] = {
    VEHICLE_CLASS: {"disp_scale": (1.0, 0.3, 0.05), "recon_sigma": (0.2, 0.1, 0.02)},
    "pedestrian": {"disp_scale": (0.3, 0.3, 0.3), "recon_sigma": (0.05, 0.05, 0.05)},
    "cyclist": {"disp_scale": (0.5, 0.2, 0.05), "recon_sigma": (0.07, 0.05, 0.02)},
}
