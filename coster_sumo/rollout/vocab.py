"""Motion vocabulary (docs/method.md step 6): k-disks over 0.5 s transitions, and projection onto it.

A **transition** is the motion of a vehicle over one 2 Hz step, ``(dx, dy, dyaw)``: the later pose
in the body frame of the earlier one (x forward [m], y left [m], dyaw [rad]). The distance between
two transitions is the **mean box-corner error**: place a reference box (``length`` x ``width``) at
both resulting poses and average the distances between corresponding corners [m].

**k-disks** (as in Trajeglish): visit the transitions in a seeded random order; the first one not
yet within ``epsilon`` of a token becomes a token. ``epsilon`` is found by bisection so that about
``size`` tokens (never more) cover every transition of the nominal data.

**Projection** (:func:`project_backward`): a trajectory's last pose (the collision snapshot) is
kept exactly; going backwards, each earlier pose is the later refined pose moved back by the token
whose result lies closest (mean corner error) to the raw earlier pose. The result is a chain of
vocabulary transitions that ends exactly at the snapshot and follows the raw trajectory without
drifting from it.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene
from coster_sumo.errors import InputError
from coster_sumo.geometry.boxes import box_corners
from coster_sumo.infra.atomic import atomic_path

VOCAB_SIZE = 384
REF_LENGTH_M = 4.8  # [m] reference box of the corner error
REF_WIDTH_M = 2.0  # [m]
FORMAT_NAME = "coster-sumo-vocab"
FORMAT_VERSION = 1


def compose(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """pose (..., 3) moved by ``delta`` (..., 3) expressed in its body frame (broadcast)."""
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack([pose[..., 0] + c * delta[..., 0] - s * delta[..., 1],
                     pose[..., 1] + s * delta[..., 0] + c * delta[..., 1],
                     pose[..., 2] + delta[..., 2]], axis=-1)


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The transition from pose ``a`` to pose ``b`` (..., 3) in ``a``'s body frame."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    dyaw = np.angle(np.exp(1j * (b[..., 2] - a[..., 2])))
    return np.stack([c * dx + s * dy, -s * dx + c * dy, dyaw], axis=-1)


def invert(delta: np.ndarray) -> np.ndarray:
    """The transition that undoes ``delta`` (..., 3): compose(compose(p, d), invert(d)) == p."""
    c, s = np.cos(delta[..., 2]), np.sin(delta[..., 2])
    return np.stack([-(c * delta[..., 0] + s * delta[..., 1]), -(-s * delta[..., 0] + c * delta[..., 1]),
                     -delta[..., 2]], axis=-1)


def transition_error(d: np.ndarray, tokens: np.ndarray, length: float, width: float) -> np.ndarray:
    """Corner error between transitions ``d`` (n, 3) and ``tokens`` (V, 3) from a common origin: (n, V).

    Uses the corners' coordinates directly: (n, 8) vs (V, 8), mean over the 4 corner distances.
    """
    cd = box_corners(d[:, 0], d[:, 1], d[:, 2], length, width)  # (n, 4, 2)
    ct = box_corners(tokens[:, 0], tokens[:, 1], tokens[:, 2], length, width)  # (V, 4, 2)
    diff = cd[:, None] - ct[None]  # (n, V, 4, 2)
    return np.sqrt((diff**2).sum(-1)).mean(-1)


@dataclass(frozen=True)
class MotionVocab:
    """A motion vocabulary.

    Attributes:
        tokens: (V, 3) float64 transitions (dx [m], dy [m], dyaw [rad]) over ``dt_s``.
        length, width: [m] the reference box of the corner error.
        epsilon_m: [m] the k-disks radius.
        dt_s: [s] duration of a transition.
        meta: provenance and coverage (JSON-able).
    """

    tokens: np.ndarray
    length: float = REF_LENGTH_M
    width: float = REF_WIDTH_M
    epsilon_m: float = float("nan")
    dt_s: float = 0.5
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.tokens)

    def save(self, path: str | Path) -> Path:
        """Write one ``.npz`` atomically (no pickles)."""
        path = Path(path)
        header = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "length": self.length, "width": self.width,
                  "epsilon_m": self.epsilon_m, "dt_s": self.dt_s, "meta": self.meta}
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, tokens=self.tokens.astype(np.float64),
                                header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8))
        return path

    @classmethod
    def load(cls, path: str | Path) -> MotionVocab:
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                tokens = np.asarray(z["tokens"], np.float64)
                header = json.loads(z["header"].tobytes().decode())
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"{path}: not a motion vocabulary ({exc})") from None
        if header.get("format") != FORMAT_NAME or header.get("version") != FORMAT_VERSION:
            raise InputError(f"{path}: not a {FORMAT_NAME} v{FORMAT_VERSION} file")
        if tokens.ndim != 2 or tokens.shape[1] != 3 or len(tokens) == 0:
            raise InputError(f"{path}: tokens must be (V, 3), got {tokens.shape}")
        return cls(tokens=tokens, length=float(header["length"]), width=float(header["width"]),
                   epsilon_m=float(header["epsilon_m"]), dt_s=float(header["dt_s"]), meta=header.get("meta", {}))


def scene_transitions(scene: Scene, vehicles_only: bool = True) -> np.ndarray:
    """(n, 3) transitions between consecutive valid steps of every (vehicle) agent of a scene."""
    tr = scene.tracks
    pose = np.stack([tr.x, tr.y, tr.heading], axis=-1)  # (A, T, 3)
    ok = tr.valid[:, :-1] & tr.valid[:, 1:]
    if vehicles_only:
        ok &= (tr.object_type == ObjectType.VEHICLE)[:, None]
    d = relative(pose[:, :-1], pose[:, 1:])  # (A, T-1, 3)
    return d[ok]


def collect_transitions(scenes: Iterable[Scene], hz: float = 2.0) -> np.ndarray:
    """Transitions of all vehicles of ``scenes`` resampled to ``hz``: (n, 3)."""
    from coster_sumo.core.scene import resample

    parts = [scene_transitions(resample(s, hz)) for s in scenes]
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def _kdisks(points: np.ndarray, corners: np.ndarray, eps: float, order: np.ndarray, limit: int) -> list[int]:
    """Greedy cover: indices of tokens (at most ``limit`` + 1: stops as soon as it exceeds)."""
    flat = corners.reshape(len(points), -1)  # (n, 8)
    left = order.copy()  # uncovered points, in visiting order
    tokens: list[int] = []
    while len(left) and len(tokens) <= limit:
        i = int(left[0])
        tokens.append(i)
        diff = (flat[left] - flat[i]).reshape(len(left), 4, 2)
        err = np.sqrt((diff**2).sum(-1)).mean(-1)  # (remaining,)
        left = left[err > eps]
    return tokens


def build_vocab(transitions: np.ndarray, size: int = VOCAB_SIZE, seed: int = 0, length: float = REF_LENGTH_M,
                width: float = REF_WIDTH_M, max_points: int = 50_000, iterations: int = 20) -> MotionVocab:
    """k-disks vocabulary of at most ``size`` tokens covering ``transitions`` (n, 3).

    ``max_points`` transitions are drawn (seeded) when there are more; ``epsilon`` [m] is bisected
    (``iterations`` times) to the smallest radius whose cover has at most ``size`` tokens.
    """
    x = np.asarray(transitions, np.float64).reshape(-1, 3)
    x = x[np.all(np.isfinite(x), axis=1)]
    if len(x) == 0:
        raise InputError("no transitions to build a motion vocabulary from")
    rng = np.random.default_rng(seed)
    if len(x) > max_points:
        x = x[rng.choice(len(x), max_points, replace=False)]
    corners = box_corners(x[:, 0], x[:, 1], x[:, 2], length, width)  # (n, 4, 2)
    order = rng.permutation(len(x))
    lo, hi = 0.0, 1.0
    while len(_kdisks(x, corners, hi, order, size)) > size:
        hi *= 2.0
    best = _kdisks(x, corners, hi, order, size)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        toks = _kdisks(x, corners, mid, order, size)
        if len(toks) <= size:
            hi, best = mid, toks
        else:
            lo = mid
    tokens = x[best]
    err = transition_error(x[: min(len(x), 20_000)], tokens, length, width).min(axis=1)
    # coverage: nearest-token corner error of (up to 20 000 of) the transitions used
    meta = {"num_transitions": int(len(transitions)), "used_transitions": int(len(x)), "seed": seed,
            "coverage_mean_error_m": float(err.mean()), "coverage_p95_error_m": float(np.quantile(err, 0.95)),
            "coverage_max_error_m": float(err.max())}
    return MotionVocab(tokens=tokens, length=length, width=width, epsilon_m=float(hi), meta=meta)


def project_backward(traj: np.ndarray, vocab: MotionVocab, length: float | None = None,
                     width: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Snap every transition of trajectories onto the vocabulary, chaining back from the last pose.

    Args:
        traj: (R, T, 3) poses x, y, yaw in time order; the last (the snapshot) is kept exactly.
        vocab: the vocabulary.
        length, width: [m] the box of the corner error (default the vocabulary's reference box).

    Returns:
        refined (R, T, 3) with ``refined[:, -1] == traj[:, -1]`` bit for bit, and the largest corner
        error [m] between refined and raw poses of each trajectory, (R,).
    """
    traj = np.asarray(traj, np.float64)
    length = vocab.length if length is None else length
    width = vocab.width if width is None else width
    r, t, _ = traj.shape
    out = traj.copy()
    if t < 2 or r == 0:
        return out, np.zeros(r)
    back = invert(vocab.tokens)  # (V, 3)
    # corners of the box moved back by each token, in the frame of the later pose: (V, 4, 2)
    token_c = box_corners(back[:, 0], back[:, 1], back[:, 2], length, width)
    raw_c = box_corners(traj[..., 0], traj[..., 1], traj[..., 2], length, width)  # (R, T, 4, 2)
    worst = np.zeros(r)
    rows = np.arange(r)
    tx, ty = np.ascontiguousarray(token_c[..., 0].T), np.ascontiguousarray(token_c[..., 1].T)  # (4, V) each
    for k in range(t - 2, -1, -1):
        q = out[:, k + 1]  # (R, 3) the refined later pose
        c, s = np.cos(q[:, 2])[:, None], np.sin(q[:, 2])[:, None]
        rel = raw_c[:, k] - q[:, None, :2]  # (R, 4, 2) raw corners in q's frame:
        lx, ly = c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]  # (R, 4) each
        # mean corner distance, corner by corner on (R, V) planes: the same operations in the same
        # order as the mean over an (R, V, 4, 2) difference (bit for bit), without building it
        total = np.zeros((r, len(back)))
        for j in range(4):
            dx, dy = tx[j] - lx[:, j, None], ty[j] - ly[:, j, None]  # (R, V)
            total += np.sqrt(dx * dx + dy * dy)
        err = total / 4.0  # (R, V)
        best = np.argmin(err, axis=1)
        out[:, k] = compose(q, back[best])
        worst = np.maximum(worst, err[rows, best])
    return out, worst
