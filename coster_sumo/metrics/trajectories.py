"""Trajectory metrics of the models: displacement errors (ADE, FDE) and MMD."""

from __future__ import annotations

import numpy as np


def ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Average and final displacement error per sample.

    Args:
        pred: (..., num_samples, num_steps, 2) [m].
        truth: (..., num_steps, 2) [m].
        valid: (..., num_steps) bool or None.
    Returns: ade, fde each (..., num_samples); the final step is the last valid one.
    """
    err = np.linalg.norm(pred - truth[..., None, :, :], axis=-1)  # (..., S, T)
    if valid is None:
        valid = np.ones(truth.shape[:-1], bool)
    w = valid[..., None, :].astype(float)
    ade = (err * w).sum(-1) / np.maximum(w.sum(-1), 1.0)
    last = valid.shape[-1] - 1 - np.argmax(valid[..., ::-1], axis=-1)  # (...)
    fde = np.take_along_axis(err, np.broadcast_to(last[..., None, None], err.shape[:-1] + (1,)),
                             axis=-1)[..., 0]
    return ade, fde


def min_ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """minADE / minFDE over the samples axis (each minimised independently)."""
    ade, fde = ade_fde(pred, truth, valid)
    return ade.min(-1), fde.min(-1)


def avg_ade_fde(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """avgADE / avgFDE: mean over the samples axis."""
    ade, fde = ade_fde(pred, truth, valid)
    return ade.mean(-1), fde.mean(-1)


def mmd(x: np.ndarray, y: np.ndarray) -> float:
    """Biased MMD^2 estimate with one Gaussian kernel, bandwidth = mean pairwise squared distance.

    k(a, b) = exp(-|a - b|^2 / h), h = mean of |a - b|^2 over all pairs of the pooled samples.
    Args: x (n, d), y (m, d) (1-D inputs are treated as d = 1).
    """
    x = np.asarray(x, float).reshape(len(x), -1)
    y = np.asarray(y, float).reshape(len(y), -1)
    if len(x) == 0 or len(y) == 0:
        return float("nan")
    z = np.concatenate([x, y])
    sq = np.sum(z * z, axis=1)
    d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * z @ z.T, 0.0)
    h = d2.mean()
    if h <= 0:
        return 0.0
    k = np.exp(-d2 / h)
    n = len(x)
    return float(k[:n, :n].mean() + k[n:, n:].mean() - 2.0 * k[:n, n:].mean())
