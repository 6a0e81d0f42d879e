"""Collision time (docs/method.md step 3): the search window, the rules, and the entropy curve.

Everything works on a 2 Hz scene (:func:`coster_sumo.core.scene.resample`).

**Search window.** The collision step t_col is searched in [MARGIN_START, T - 1 - MARGIN_END]
(2 Hz steps, both edges excluded): the first ``MARGIN_START`` = 5 steps (2.5 s) are skipped so that
a backward rollout of useful length fits before the contact, and the last ``MARGIN_END`` = 5 steps
so that the pass shows what happens after it. Short scenes shrink both margins proportionally. The
target must be in the scene for the rollout horizon (5 s) before t_col and for ``AFTER_STEPS`` (5 s)
after it, or up to the scene's end: not in its last seconds before it leaves the network.

**Collision time** (``--collision-time``): ``entropy`` = the step of highest entropy of the mean
predicted velocity distribution of the regions inside the target's ellipse (needs the prior,
:mod:`coster_sumo.prior`); ``last`` = the last step of the window; ``random`` = a uniform step of
the window (seeded).

**Several collision times.** When the best collision time gives no usable plan, or a run asks for
several snapshots, the next best one at least :data:`SNAPSHOT_SEPARATION_STEPS` (2 s) away from
those taken is tried (:func:`around`); a scene is declared unusable after
:data:`COLLISION_TIMES` of them (:func:`coster_sumo.method.generation.plan_scenario`).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from coster_sumo.core.scene import Scene
from coster_sumo.core.snapshot import AgentState
from coster_sumo.errors import InputError, NoSnapshot
from coster_sumo.rollout.methods import HORIZON_STEPS

PRIOR_RATE_HZ = 2.0  # [1/s] the prior and the rollout work at 2 Hz
MARGIN_START = 5  # [2 Hz steps] skipped at the start of the window (a rollout must fit)
MARGIN_END = 5  # [2 Hz steps] skipped at the end
AFTER_STEPS = HORIZON_STEPS  # [2 Hz steps] the target stays in the network this long after t_col
COLLISION_TIMES = 3  # collision times tried (best first, 2 s apart) before a scene is declared unusable
SNAPSHOT_SEPARATION_STEPS = 4  # [2 Hz steps] the collision times of several snapshots lie 2 s apart or more
# a search window longer than this (5 min at 2 Hz) is searched coarse to fine (entropy_search); the
# shipped networks, the converted WOMD clips (9.1 s) and the held-out clips are far below it, so
# their curves, collision times and variants are computed exactly as over every step
LONG_WINDOW_STEPS = 600
COARSE_STRIDE = 10  # [2 Hz steps] (5 s) the coarse grid of a long window
FINE_CANDIDATES = 8  # the highest coarse steps searched at every step around them


def search_window(scene: Scene, target: int, exclude: Collection[int] = ()) -> np.ndarray:
    """2 Hz step indices where t_col may fall (see the module docstring), without ``exclude``."""
    n = scene.num_steps
    m0 = min(MARGIN_START, max(1, n // 4))
    m1 = min(MARGIN_END, max(0, n // 4))
    steps = np.arange(m0, n - m1)
    valid = scene.tracks.valid[target]
    since = np.concatenate([[0], np.cumsum(~valid)])  # invalid steps before each index
    # the target must be there for the whole approach before t_col (the rollout's horizon, cut at
    # the scene's start): an adversary that starts before the target exists can take the place the
    # target departs from; and for AFTER_STEPS after it (cut at the scene's end): a vehicle about
    # to leave the network is at the map's edge, where the prior sees half a neighbourhood, and a
    # contact there shows nothing of what follows (docs/method.md, collision time)
    ok = since[np.minimum(steps + AFTER_STEPS + 1, n)] - since[np.maximum(steps - HORIZON_STEPS, 0)] == 0
    if len(exclude):
        ok &= ~np.isin(steps, np.fromiter(exclude, np.int64))
    return steps[ok]



@dataclass(frozen=True)
class CollisionTimeRequest:
    """What a collision-time rule chooses from.

    Attributes:
        window: (W,) int 2 Hz step indices where t_col may fall (:func:`search_window`; never empty).
        rng: the generation's seeded generator.
        entropy: (num_steps,) [nats] the velocity entropy around the target (:func:`entropy_curve`,
            NaN outside the window), or None where no prior was asked.
    """

    window: np.ndarray
    rng: np.random.Generator
    entropy: np.ndarray | None = None


class CollisionTimeRule(Protocol):
    """A rule of ``--collision-time``: the 2 Hz step of t_col, one of ``request.window``."""

    def __call__(self, request: CollisionTimeRequest) -> int: ...


def _last_step(request: CollisionTimeRequest) -> int:
    return int(request.window[-1])


def _random_step(request: CollisionTimeRequest) -> int:
    return int(request.rng.choice(request.window))


def _highest_entropy(request: CollisionTimeRequest) -> int:
    window, entropy = request.window, request.entropy
    if entropy is None:
        raise ValueError("collision time 'entropy' needs the entropy curve")
    vals = np.where(np.isfinite(entropy[window]), entropy[window], -np.inf)
    if not np.isfinite(vals).any():
        raise NoSnapshot("no region near the target at any step of the window")
    return int(window[int(np.argmax(vals))])


# Collision-time rules: a new rule is one function and one line here; the CLI's --collision-time
# choices read this.
COLLISION_TIME_RULES: dict[str, CollisionTimeRule] = {
    "entropy": _highest_entropy,  # COSTER: the step of highest velocity entropy around the target
    "last": _last_step,  # ablation: the last step of the window
    "random": _random_step,  # ablation: a uniformly random step of the window
}


def choose_collision_time(window: np.ndarray, method: str, rng: np.random.Generator,
                          entropy: np.ndarray | None = None) -> int:
    """Pick t_col among ``window`` by the rule ``method`` of :data:`COLLISION_TIME_RULES`."""
    if len(window) == 0:
        raise NoSnapshot("the target is not valid inside the collision-time search window")
    rule = COLLISION_TIME_RULES.get(method)
    if rule is None:
        raise InputError(f"unknown collision-time method {method!r}; use one of {', '.join(COLLISION_TIME_RULES)}")
    return rule(CollisionTimeRequest(window, rng, entropy))


def around(t_index: int) -> range:
    """The 2 Hz steps closer than :data:`SNAPSHOT_SEPARATION_STEPS` to ``t_index``."""
    return range(t_index - SNAPSHOT_SEPARATION_STEPS + 1, t_index + SNAPSHOT_SEPARATION_STEPS)


def in_ellipse(points: np.ndarray, target: AgentState) -> np.ndarray:
    """(...) bool: points (..., 2) inside the target's ellipse (semi-axes 2 L along, 2 W across)."""
    d = np.asarray(points, float) - np.array([target.x, target.y])
    c, s = np.cos(target.yaw), np.sin(target.yaw)
    lon = c * d[..., 0] + s * d[..., 1]
    lat = -s * d[..., 0] + c * d[..., 1]
    return (lon / (2.0 * target.length)) ** 2 + (lat / (2.0 * target.width)) ** 2 <= 1.0


def velocity_entropy(pred: Any, ellipse: np.ndarray) -> np.ndarray:
    """(T,) entropy [nats] of the mean velocity distribution of the ellipse's regions per step.

    The velocity distribution of a region is the joint of its speed and heading heads (independent
    heads, so the joint is their outer product); the mean over the K regions in the ellipse is
    (1/K) sum_k p_speed_k (x) p_heading_k, and its entropy is computed exactly over all
    speed x heading cells. Steps with no region in the ellipse get NaN.
    """
    ps, ph = pred.probs["speed"], pred.probs["heading"]  # (T, K, S), (T, K, H)
    out = np.full(ellipse.shape[0], np.nan)
    for t in np.flatnonzero(ellipse.any(axis=1)):  # a few regions per step: one small product each
        ks = np.flatnonzero(ellipse[t])
        joint = ps[t, ks].astype(np.float64).T @ ph[t, ks].astype(np.float64) / len(ks)  # (S, H)
        p = joint[joint > 0]
        out[t] = -np.sum(p * np.log(p))
    return out


def target_pose(scene: Scene, target: int, steps: np.ndarray) -> np.ndarray:
    """(S, 3) the target's own x [m], y [m], heading [rad] at ``steps`` (the prior's frame: the
    target may be a cyclist, and the prior's data has no centre agent for it)."""
    tr = scene.tracks
    return np.stack([tr.x[target, steps], tr.y[target, steps], tr.heading[target, steps]], -1)


def entropy_curve(model: Any, data: Any, scene: Scene, target: int) -> np.ndarray:
    """(num_steps,) the velocity entropy [nats] around the target (NaN where not computed); the
    ``entropy`` rule picks its highest step (:func:`entropy_search`, which says where it is computed)."""
    return entropy_search(model, data, scene, target)[0]


def entropy_search(model: Any, data: Any, scene: Scene, target: int) -> tuple[np.ndarray, np.ndarray]:
    """The entropy curve (:func:`entropy_curve`) and the 2 Hz steps it was computed at.

    A search window of at most :data:`LONG_WINDOW_STEPS` steps: at every step of it. Steps a
    caller excludes are only not chosen, so the curve is computed once per scene and target.
    A longer one (a target that lives minutes in a city) coarse to fine: every
    :data:`COARSE_STRIDE` th step, then every step within a stride of the :data:`FINE_CANDIDATES`
    highest of those; the other steps stay NaN and are never chosen. The prior's cost is then that
    of about ``W / COARSE_STRIDE + FINE_CANDIDATES * 2 COARSE_STRIDE`` steps instead of ``W``.

    ``model``: the traffic prior; ``data``: its regions and agents of ``scene`` (2 Hz) near the
    target's path (:func:`coster_sumo.prior.data.prepare_scene`).
    """
    full = search_window(scene, target)
    curve = np.full(scene.num_steps, np.nan)
    if len(full) <= LONG_WINDOW_STEPS:
        curve[full] = _entropy_at(model, data, scene, target, full)
        return curve, full
    coarse = full[::COARSE_STRIDE]
    curve[coarse] = _entropy_at(model, data, scene, target, coarse)
    near = _near_best(curve, coarse, full)
    fine = np.setdiff1d(near[np.isnan(curve[near])], coarse)
    if len(fine):
        curve[fine] = _entropy_at(model, data, scene, target, fine)
    return curve, np.union1d(coarse, fine)


def candidate_steps(scene: Scene, target: int, curve: np.ndarray) -> np.ndarray:
    """The 2 Hz steps around the candidate collision times of :func:`entropy_search`'s ``curve``,
    where the prior's adaptation to the traffic is fitted (:func:`coster_sumo.method.snapshot.scene_adaptation`).

    A search window of at most :data:`LONG_WINDOW_STEPS` steps: all of it. A longer one: its steps
    within a stride of the :data:`FINE_CANDIDATES` highest coarse steps (the windows searched at
    every step, each coarse step in them included; at most ``FINE_CANDIDATES * (2 COARSE_STRIDE - 1)``
    steps, the traffic of the minutes where t_col and the next best times fall, not that of the
    whole life), or the coarse grid where none of it has a region in the target's ellipse.
    """
    full = search_window(scene, target)
    if len(full) <= LONG_WINDOW_STEPS:
        return full
    coarse = full[::COARSE_STRIDE]
    near = _near_best(curve, coarse, full)
    return near if len(near) else coarse


def _near_best(curve: np.ndarray, coarse: np.ndarray, full: np.ndarray) -> np.ndarray:
    """(S,) the steps of ``full`` within a stride of the :data:`FINE_CANDIDATES` highest finite
    values of ``curve`` at the ``coarse`` steps (sorted)."""
    vals = np.where(np.isfinite(curve[coarse]), curve[coarse], -np.inf)
    best = coarse[np.argsort(-vals, kind="stable")[:FINE_CANDIDATES]]
    best = best[np.isfinite(curve[best])]
    near = np.zeros(len(curve), bool)
    for b in best:
        near[max(0, b - COARSE_STRIDE + 1):b + COARSE_STRIDE] = True
    return full[near[full]]


def _entropy_at(model: Any, data: Any, scene: Scene, target: int, steps: np.ndarray) -> np.ndarray:
    """(len(steps),) the velocity entropy [nats] around the target at ``steps`` (NaN: no region in its ellipse)."""
    from coster_sumo.prior.infer import predict_scene

    velocity = predict_scene(model, data, target, steps=steps, heads=("speed", "heading"),
                             pose=target_pose(scene, target, steps), calibrate=False)  # the entropy reads the raw heads
    centres = velocity.regions.centre[np.maximum(velocity.region_index, 0)]  # (W, K, 2)
    ellipse = np.zeros(velocity.mask.shape, bool)
    for j, t in enumerate(steps):
        ellipse[j] = velocity.mask[j] & in_ellipse(centres[j], AgentState.from_tracks(scene.tracks, target, int(t)))
    return velocity_entropy(velocity, ellipse)
