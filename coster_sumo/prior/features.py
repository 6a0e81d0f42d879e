"""Region tokens for the prior (numpy only).

A prior *sample* is one scene at one step, centred on one agent (the target at inference, a random
vehicle in training): the regions within the neighbourhood radius of that agent, nearest first,
described in the centre agent's frame (origin at its position, x along its heading), which makes
the model invariant to the map's absolute coordinates and orientation.

What the model sees, and why training is not leakage
----------------------------------------------------
Each region token has two parts:

- map part (always given, :data:`MAP_FEATURES` = 19 values): q1 and q2 in the centre frame
  (divided by the radius), the region direction (cos, sin) in that frame, height / 5 m, lane type
  one-hot (4), junction flag, signal category one-hot (none, stop, caution, go) at that step, the
  centre's distance / radius, and the lane's speed limit / 30 m/s with a flag saying it is known
  (SUMO lanes always have one; a WOMD lane has one where its map gives it). Checkpoints trained before the speed
  limit existed read the first :data:`MAP_FEATURES_V1` = 17 only (``PriorConfig.map_features``);
- observed-agent part (:data:`AGENT_FEATURES` = 9 values): a *visible* flag, then for visible
  regions the occupancy (presence, normalised position, heading cos/sin, speed / 10, length / 5,
  width / 2); all zeros for hidden regions.

The model predicts presence and attributes of the *hidden* regions only, and the loss counts only
them. Each agent occupies at most one region (see :mod:`coster_sumo.prior.regions`), so hiding a region
hides its agent entirely: the prediction of a hidden region can use the map, the signals and the
agents in *other* (visible) regions through the context gating, never its own answer. Training
draws the hidden set at random per sample (:func:`random_visibility`): all regions hidden (the pure
map-and-signal prior), independent random regions hidden, or a disc around the centre agent hidden
with everything outside revealed. At inference the caller chooses between the first (``"map"``)
and the last (``"context"``: regions within a hide radius of the target hidden, the traffic
outside it given, :func:`visible_outside`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coster_sumo.geometry.boxes import to_local
from coster_sumo.prior.bins import AttributeBins
from coster_sumo.prior.regions import REGION_SPACING, Regions

MAP_FEATURES = 19
MAP_FEATURES_V1 = 17  # the map part before the speed limit was added
SPEED_LIMIT_SCALE = 30.0  # [m/s]
AGENT_FEATURES = 9
NUM_LANE_TYPES = 4
NUM_SIGNAL_CATEGORIES = 4
# slices of the map features
Q1, Q2, DIRECTION, HEIGHT = slice(0, 2), slice(2, 4), slice(4, 6), 6
LANE_TYPE, JUNCTION, SIGNAL, DISTANCE = slice(7, 11), 11, slice(12, 16), 16
SPEED_LIMIT, SPEED_LIMIT_KNOWN = 17, 18


@dataclass(frozen=True)
class Tokens:
    """Model inputs and targets for a batch of samples.

    Attributes:
        map_features: (B, K, MAP_FEATURES) float32.
        agent_features: (B, K, AGENT_FEATURES) float32 (zeros where hidden).
        mask: (B, K) bool, a real region (False = padding).
        query: (B, K) bool, hidden regions whose presence/attributes are to be predicted.
        present: (B, K) bool ground-truth presence.
        classes: (B, K, 5) int64 ground-truth classes (position, heading, speed, length, width);
            meaningful where present.
        region_index: (B, K) int64 index into the scene's regions, -1 for padding.
        values: (B, K, 6) float32 ground-truth attributes (normalised x, y, relative heading [rad],
            speed [m/s], length [m], width [m]); zeros where empty.
    """

    map_features: np.ndarray
    agent_features: np.ndarray
    mask: np.ndarray
    query: np.ndarray
    present: np.ndarray
    classes: np.ndarray
    region_index: np.ndarray
    values: np.ndarray


def map_features(regions: Regions, index: np.ndarray, mask: np.ndarray, signal: np.ndarray,
                 centre: np.ndarray, radius: float) -> np.ndarray:
    """Map part of the tokens.

    Args:
        regions: all regions of the scene.
        index: (B, K) region indices (-1 padding), mask: (B, K) bool.
        signal: (B, K) int signal category of each token's region at its step.
        centre: (B, 3) centre x, y [m], heading [rad].
        radius: neighbourhood radius [m] used for scaling.

    Returns:
        (B, K, MAP_FEATURES) float32, zeros at padding.
    """
    idx = np.where(mask, index, 0)
    origin = centre[:, None, :2]
    h = centre[:, None, 2]
    q1 = to_local(regions.q1[idx], origin, h) / radius
    q2 = to_local(regions.q2[idx], origin, h) / radius
    rel = regions.heading[idx] - h
    height = regions.height[idx] / REGION_SPACING
    lane_type = np.eye(NUM_LANE_TYPES)[np.clip(regions.lane_type[idx], 0, NUM_LANE_TYPES - 1)]
    sig = np.eye(NUM_SIGNAL_CATEGORIES)[np.clip(signal, 0, NUM_SIGNAL_CATEGORIES - 1)]
    dist = np.linalg.norm(0.5 * (q1 + q2), axis=-1)
    limit = np.zeros(idx.shape) if regions.speed_limit is None else regions.speed_limit[idx]
    feats = np.concatenate([q1, q2, np.cos(rel)[..., None], np.sin(rel)[..., None], height[..., None],
                            lane_type, regions.is_junction[idx][..., None], sig, dist[..., None],
                            (limit / SPEED_LIMIT_SCALE)[..., None], (limit > 0)[..., None]], axis=-1)
    return (feats * mask[..., None]).astype(np.float32)


def agent_features(present: np.ndarray, normalised_xy: np.ndarray, heading: np.ndarray,
                   speed: np.ndarray, length: np.ndarray, width: np.ndarray,
                   visible: np.ndarray) -> np.ndarray:
    """Observed-agent part of the tokens; all inputs (B, K) (normalised_xy (B, K, 2)).

    Returns:
        (B, K, AGENT_FEATURES) float32, zeros where not visible.
    """
    p = present.astype(np.float64)
    feats = np.concatenate([
        np.ones_like(p)[..., None], p[..., None], normalised_xy * p[..., None],
        (np.cos(heading) * p)[..., None], (np.sin(heading) * p)[..., None],
        (speed / 10.0 * p)[..., None], (length / 5.0 * p)[..., None], (width / 2.0 * p)[..., None],
    ], axis=-1)
    return (feats * visible[..., None]).astype(np.float32)


def target_classes(bins: AttributeBins, normalised_xy: np.ndarray, heading: np.ndarray, speed: np.ndarray,
                   length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """(..., 5) int64 classes (position, heading, speed, length, width) of the given attributes."""
    return np.stack([bins.position_class(normalised_xy), bins.heading_class(heading),
                     bins.speed_class(speed), bins.length_class(length), bins.width_class(width)], -1)


def random_visibility(rng: np.random.Generator, distance: np.ndarray,
                      disc_radius: tuple[float, float] = (5.0, 20.0)) -> np.ndarray:
    """(B, K) bool training visibility (see the module docstring).

    Per sample, one of three modes with probabilities 0.4 / 0.3 / 0.3: everything hidden;
    each region hidden independently with a probability drawn from [0.1, 0.9]; a disc around the
    centre agent hidden (radius drawn from ``disc_radius`` [m]) and everything else visible.

    Args:
        distance: (B, K) distance of each region centre from the sample's centre [m].
    """
    b, k = distance.shape
    mode = np.asarray(rng.choice(3, size=b, p=[0.4, 0.3, 0.3]))
    ratio = np.asarray(rng.uniform(0.1, 0.9, size=b))
    independent = rng.random((b, k)) >= ratio[:, None]
    disc = distance > np.asarray(rng.uniform(*disc_radius, size=b))[:, None]
    return np.where(mode[:, None] == 0, False, np.where(mode[:, None] == 1, independent, disc))


def visible_outside(distance: np.ndarray, hide_radius: float) -> np.ndarray:
    """(B, K) bool: reveal the regions farther than ``hide_radius`` [m] from the centre."""
    return np.asarray(distance) > hide_radius


def token_buckets(map_feats: np.ndarray) -> np.ndarray:
    """(...) int64 bucket of each token for the baselines: lane type x junction x signal category
    (4 x 2 x 4 = 32 buckets), decoded from the map features (..., MAP_FEATURES)."""
    lane = np.argmax(map_feats[..., LANE_TYPE], axis=-1)
    junction = (map_feats[..., JUNCTION] > 0.5).astype(np.int64)
    signal = np.argmax(map_feats[..., SIGNAL], axis=-1)
    return (lane * 2 + junction) * NUM_SIGNAL_CATEGORIES + signal


NUM_BUCKETS = NUM_LANE_TYPES * 2 * NUM_SIGNAL_CATEGORIES


def centre_frame_attributes(map_feats: np.ndarray, normalised_xy: np.ndarray, rel_heading: np.ndarray,
                            radius: float, region_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Agent position [m] (..., 2) and heading [rad] (...) in the sample's centre frame, from the
    token's map features and region-frame attributes."""
    q1 = map_feats[..., Q1] * radius
    q2 = map_feats[..., Q2] * radius
    d = q2 - q1
    unit = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    right = np.stack([unit[..., 1], -unit[..., 0]], -1)
    pos = q1 + (normalised_xy[..., 1:2] + 0.5) * d + normalised_xy[..., 0:1] * region_width * right
    heading = np.arctan2(map_feats[..., DIRECTION.start + 1], map_feats[..., DIRECTION.start]) + rel_heading
    return pos, np.arctan2(np.sin(heading), np.cos(heading))
