"""Baselines for the prior, fitted on the same training tokens as the model (numpy / scikit-learn).

Both condition only on a region's bucket (lane type x junction flag x signal category, 32 buckets,
:func:`coster_sumo.prior.features.token_buckets`); buckets with too few examples fall back to the
pooled statistics.

- :class:`MeanValueBaseline`: presence ~ Bernoulli(bucket's presence rate); attributes = the
  bucket's mean attribute vector (normalised x, y, relative heading, speed, length, width).
- :class:`GMMBaseline`: same presence; attributes sampled from a 5-component full-covariance
  Gaussian mixture fitted per bucket on the attribute vectors, clipped into the valid ranges.
"""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.mixture import GaussianMixture

from coster_sumo.prior.bins import AttributeBins
from coster_sumo.prior.features import NUM_BUCKETS

MIN_BUCKET_TOKENS = 50  # tokens before a bucket gets its own presence rate
MIN_BUCKET_AGENTS = 50  # present tokens before a bucket gets its own mean / mixture
PRIOR_STRENGTH = 20.0  # pseudo-count pulling bucket rates towards the pooled rate


def clip_values(values: np.ndarray, bins: AttributeBins) -> np.ndarray:
    """Clip (n, 6) attribute vectors into the ranges the prior can express."""
    lo = np.array([-0.5, -0.5, -bins.heading_range_rad, 0.0, 0.5, 0.3])
    hi = np.array([0.5, 0.5, bins.heading_range_rad, bins.max_speed, bins.max_length, bins.max_width])
    return np.clip(values, lo, hi)


class _PresenceRates:
    def _fit_presence(self, buckets: np.ndarray, present: np.ndarray) -> None:
        n = np.bincount(buckets, minlength=NUM_BUCKETS).astype(np.float64)
        k = np.bincount(buckets, weights=present.astype(np.float64), minlength=NUM_BUCKETS)
        self.pooled = float(k.sum() / max(n.sum(), 1.0))
        self.rate = (k + PRIOR_STRENGTH * self.pooled) / (n + PRIOR_STRENGTH)
        self.counts = n

    def presence(self, buckets: np.ndarray) -> np.ndarray:
        return self.rate[buckets]


class MeanValueBaseline(_PresenceRates):
    """Bucket presence rate and bucket mean attributes."""

    name = "mean_value"

    def fit(self, buckets: np.ndarray, present: np.ndarray, values: np.ndarray) -> MeanValueBaseline:
        """buckets (n,) int, present (n,) bool, values (n, 6) attributes of all tokens."""
        self._fit_presence(buckets, present)
        b, v = buckets[present], values[present]
        self.pooled_mean = v.mean(axis=0) if len(v) else np.zeros(6)
        self.mean = np.tile(self.pooled_mean, (NUM_BUCKETS, 1))
        for i in range(NUM_BUCKETS):
            sel = b == i
            if sel.sum() >= MIN_BUCKET_AGENTS:
                self.mean[i] = v[sel].mean(axis=0)
        return self

    def sample_values(self, buckets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(n, 6) attributes for tokens of the given buckets (deterministic)."""
        return self.mean[buckets]


class GMMBaseline(_PresenceRates):
    """Bucket presence rate and a per-bucket Gaussian mixture over the attribute vector."""

    name = "gmm"

    def __init__(self, bins: AttributeBins, components: int = 5, seed: int = 0) -> None:
        self.bins = bins
        self.components = components
        self.seed = seed

    def _fit_one(self, v: np.ndarray) -> GaussianMixture | None:
        if len(v) < 2:
            return None
        gmm = GaussianMixture(n_components=int(min(self.components, len(v))), covariance_type="full",
                              reg_covar=1e-4, random_state=self.seed, max_iter=200)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gmm.fit(v)
        return gmm

    def fit(self, buckets: np.ndarray, present: np.ndarray, values: np.ndarray) -> GMMBaseline:
        self._fit_presence(buckets, present)
        b, v = buckets[present], values[present]
        self.pooled_gmm = self._fit_one(v)
        self.gmms: dict[int, GaussianMixture] = {}
        for i in range(NUM_BUCKETS):
            sel = b == i
            if sel.sum() >= MIN_BUCKET_AGENTS:
                g = self._fit_one(v[sel])
                if g is not None:
                    self.gmms[i] = g
        return self

    def sample_values(self, buckets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        out = np.zeros((len(buckets), 6))
        for i in np.unique(buckets):
            sel = np.flatnonzero(buckets == i)
            gmm = self.gmms.get(int(i), self.pooled_gmm)
            if gmm is None:
                continue
            # GaussianMixture.sample draws with its own random_state: seed it from ours
            gmm.random_state = int(rng.integers(2**31 - 1))
            x, _ = gmm.sample(len(sel))
            out[sel] = x[rng.permutation(len(sel))]  # sample() returns rows grouped by component
        return clip_values(out, self.bins)
