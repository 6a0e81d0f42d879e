"""Discretisation of the prior's agent attributes (numpy only).

Classes (defaults from the docs/method.md, Reference figures):
- position: 40 x 40 cells over the region's normalised frame [-0.5, 0.5]^2 (x across, y along);
  class = ix * 40 + iy;
- heading: 144 bins over [-heading_range, heading_range] of the heading relative to the region
  direction; the range defaults to 45 degrees, the assignment tolerance of
  :mod:`coster_sumo.prior.regions` (an agent further off is never assigned), i.e. 0.625 degrees a bin;
- speed: class 0 = stopped (< 0.5 m/s), classes 1..60 = log-spaced bins from 0.5 to 45 m/s
  (faster speeds fall in the last bin); the stopped class decodes to 0 m/s. 45 m/s (162 km/h)
  covers the corpus' freeways (p95 38.5 m/s on roads over 90 km/h); checkpoints trained with the
  first range (30 m/s, where every freeway speed above 28 m/s fell into the last bin and came
  back as 29.0 m/s, its centre) keep it in their stored config;
- length: 60 bins over [0, 15] m; width: 40 bins over [0, 4] m.
Values outside a range are clipped into its first or last bin; bins decode to their centres
(geometric centre for speed), except where a sampled speed is wanted (a snapshot's adversary):
:meth:`AttributeBins.speed_in_bin` draws it log-uniformly inside its bin. Centres alone give only
60 distinct speeds, 2 m/s apart at freeway speeds, a comb that no traffic's speeds look like.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ATTRIBUTES = ("position", "heading", "speed", "length", "width")


@dataclass(frozen=True)
class AttributeBins:
    position_bins: int = 40  # per axis
    heading_bins: int = 144
    heading_range_rad: float = float(np.pi / 4)
    speed_bins: int = 60  # plus the stopped class
    stopped_speed: float = 0.5  # [m/s]
    max_speed: float = 45.0  # [m/s]
    length_bins: int = 60
    max_length: float = 15.0  # [m]
    width_bins: int = 40
    max_width: float = 4.0  # [m]

    def num_classes(self) -> dict[str, int]:
        return {"position": self.position_bins ** 2, "heading": self.heading_bins,
                "speed": self.speed_bins + 1, "length": self.length_bins, "width": self.width_bins}

    # ------------------------------------------------------------------ value -> class

    @staticmethod
    def _uniform(v: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
        k = np.floor((np.asarray(v, np.float64) - lo) / (hi - lo) * n)
        return np.clip(k, 0, n - 1).astype(np.int64)

    def position_class(self, normalised_xy: np.ndarray) -> np.ndarray:
        """(..., 2) normalised region position -> (...) int64."""
        n = self.position_bins
        ix = self._uniform(normalised_xy[..., 0], -0.5, 0.5, n)
        iy = self._uniform(normalised_xy[..., 1], -0.5, 0.5, n)
        return ix * n + iy

    def heading_class(self, heading_rad: np.ndarray) -> np.ndarray:
        r = self.heading_range_rad
        return self._uniform(heading_rad, -r, r, self.heading_bins)

    def speed_edges(self) -> np.ndarray:
        """(speed_bins + 1,) [m/s] log-spaced edges of the moving classes."""
        return np.geomspace(self.stopped_speed, self.max_speed, self.speed_bins + 1)

    def speed_class(self, speed: np.ndarray) -> np.ndarray:
        s = np.asarray(speed, np.float64)
        k = np.searchsorted(self.speed_edges(), s, side="right")  # 0 below stopped_speed
        return np.clip(k, 0, self.speed_bins).astype(np.int64)

    def speed_in_bin(self, classes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Speeds [m/s] (S,) for speed classes (S,): 0 for the stopped class, otherwise log-uniform
        between the class's edges (one random number per class, stopped or not)."""
        e = self.speed_edges()
        k = np.asarray(classes, np.int64)
        lo, hi = np.log(e[np.clip(k - 1, 0, len(e) - 1)]), np.log(e[np.clip(k, 0, len(e) - 1)])
        v = np.exp(lo + rng.random(k.shape) * (hi - lo))
        return np.where(k == 0, 0.0, v)

    def length_class(self, length: np.ndarray) -> np.ndarray:
        return self._uniform(length, 0.0, self.max_length, self.length_bins)

    def width_class(self, width: np.ndarray) -> np.ndarray:
        return self._uniform(width, 0.0, self.max_width, self.width_bins)

    # ------------------------------------------------------------------ class -> value

    def position_centres(self) -> np.ndarray:
        """(position_bins ** 2, 2) normalised (x, y) of every position class."""
        n = self.position_bins
        c = -0.5 + (np.arange(n) + 0.5) / n
        ix, iy = np.meshgrid(c, c, indexing="ij")
        return np.stack([ix.ravel(), iy.ravel()], -1)

    def heading_centres(self) -> np.ndarray:
        r = self.heading_range_rad
        return -r + (np.arange(self.heading_bins) + 0.5) * (2 * r / self.heading_bins)

    def speed_centres(self) -> np.ndarray:
        e = self.speed_edges()
        return np.concatenate([[0.0], np.sqrt(e[:-1] * e[1:])])

    def length_centres(self) -> np.ndarray:
        return (np.arange(self.length_bins) + 0.5) * (self.max_length / self.length_bins)

    def width_centres(self) -> np.ndarray:
        return (np.arange(self.width_bins) + 0.5) * (self.max_width / self.width_bins)

    def centres(self, attribute: str) -> np.ndarray:
        """Bin centres of ``attribute`` (one of :data:`ATTRIBUTES`)."""
        return getattr(self, f"{attribute}_centres")()
