"""Scores of driving policies over evaluation episodes, and bootstrap intervals over seeds and episodes.

Per episode (from the environment's last ``info``, :class:`coster_sumo.gym.train.EpisodeRecord`):

- **success** (the paper's route completion): the target completed its route with no collision and
  no off-road. An episode that ends by time with the whole route driven (a route shorter than the
  environment's minimum ends by time only) counts as completed too.
- **completion**: the fraction of the route driven before the episode ended (the old ``rcr``).
- **collision**: it ended in a collision with anyone; **collision_adversary**: with the variant's
  adversary; **off_road**: it ended off the drivable area.

A score is the mean of one of these over episodes: RCR (paper) = mean success, mean completion, CR
(anyone), CR (adversary), ORR.

Intervals: a policy arm has seeds x episodes values (every seed driven on the same episodes). The
bootstrap draws seeds with replacement and, independently, episodes with replacement (the same
episode draw for every seed, and for both arms of a difference: the arms are paired by episode),
and takes the mean over the drawn cells; the interval is the 2.5th and 97.5th percentiles of
:data:`BOOTSTRAP_SAMPLES` draws (seeded).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

BOOTSTRAP_SAMPLES = 10_000
CONFIDENCE = 0.95
COMPLETE_FRACTION = 1.0  # an episode that ends by time counts as completed when it drove this much of its route


def success(outcome: str, route_completion: float) -> bool:
    """The paper's route completion for one episode (module docstring)."""
    return outcome == "completed" or (outcome == "timeout" and route_completion >= COMPLETE_FRACTION)


EPISODE_SCORES: dict[str, Callable[[Any], float]] = {
    "rcr": lambda r: float(success(r.outcome, r.route_completion)),
    "mean_completion": lambda r: float(r.route_completion),
    "cr": lambda r: float(r.outcome == "collision"),
    "cr_adversary": lambda r: float(bool(r.collided_with_adversary)),
    "orr": lambda r: float(r.outcome == "off_road"),
}


def episode_values(rows: Sequence[Any], score: str) -> np.ndarray:
    """(E,) float64 the per-episode value of ``score`` (a key of :data:`EPISODE_SCORES`) for records
    with ``outcome``, ``route_completion`` and ``collided_with_adversary``."""
    f = EPISODE_SCORES[score]
    return np.array([f(r) for r in rows], np.float64)


@dataclass(frozen=True, slots=True)
class Interval:
    """A mean and its bootstrap interval."""

    mean: float
    low: float
    high: float

    def excludes_zero(self) -> bool:
        return self.low > 0.0 or self.high < 0.0

    def to_json(self) -> dict[str, float]:
        return {"mean": self.mean, "low": self.low, "high": self.high}


def _draws(shape: tuple[int, int], samples: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(B, S) seed draws and (B, E) episode draws."""
    s, e = shape
    return rng.integers(0, s, (samples, s)), rng.integers(0, e, (samples, e))


def _means(values: np.ndarray, seeds: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    """(B,) the mean of ``values`` (S, E) over each draw's seeds x episodes."""
    per_seed_episode = values[seeds]  # (B, S, E)
    return np.take_along_axis(per_seed_episode, np.broadcast_to(episodes[:, None, :], per_seed_episode.shape),
                              axis=2).mean(axis=(1, 2))


def _interval(mean: float, draws: np.ndarray) -> Interval:
    tail = 100 * (1 - CONFIDENCE) / 2
    lo, hi = np.percentile(draws, [tail, 100 - tail])
    return Interval(float(mean), float(lo), float(hi))


def bootstrap(values: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> Interval:
    """The mean of ``values`` (S seeds, E episodes) and its 95 % bootstrap interval over seeds and
    episodes (a 1-D array is one seed)."""
    v = np.atleast_2d(np.asarray(values, np.float64))
    if v.size == 0:
        raise ValueError("no episodes to score")
    seeds, episodes = _draws(v.shape, samples, np.random.default_rng(seed))
    return _interval(float(v.mean()), _means(v, seeds, episodes))


def bootstrap_difference(a: np.ndarray, b: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> Interval:
    """``mean(b) - mean(a)`` and its 95 % bootstrap interval: arms ``a`` (Sa, E) and ``b`` (Sb, E) on
    the same E episodes, the episode draw shared (paired), the seeds drawn per arm."""
    va, vb = np.atleast_2d(np.asarray(a, np.float64)), np.atleast_2d(np.asarray(b, np.float64))
    if va.shape[1] != vb.shape[1] or va.size == 0:
        raise ValueError(f"the arms must be scored on the same episodes: {va.shape[1]} against {vb.shape[1]}")
    rng = np.random.default_rng(seed)
    seeds_a, episodes = _draws(va.shape, samples, rng)
    seeds_b = rng.integers(0, vb.shape[0], (samples, vb.shape[0]))
    draws = _means(vb, seeds_b, episodes) - _means(va, seeds_a, episodes)
    return _interval(float(vb.mean() - va.mean()), draws)


def scores(rows: Sequence[Any]) -> dict[str, float]:
    """Every score of :data:`EPISODE_SCORES` over one policy's episodes."""
    return {name: float(episode_values(rows, name).mean()) if rows else float("nan") for name in EPISODE_SCORES}
