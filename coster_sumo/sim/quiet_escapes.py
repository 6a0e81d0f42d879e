"""Whether an escape makes any logged agent react: decided before SUMO runs it, or watched while
a joint pass replays it.

In reactive traffic (:mod:`coster_sumo.sim.reactive`) an escape whose target makes nobody react is a
pass of the log, so the avoidability proof replays it with the others in one joint pass
(:func:`coster_sumo.avoidability.proof.prove_escapes`, docs/method.md step 8). :func:`reaches_no_one`
tells some in advance, on the safe side; :class:`ReactionWatch` tells the others during the joint
pass, with the reactive replayer's own test on the target copy's SUMO state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene
from coster_sumo.formats.scene_folder import agent_sizes
from coster_sumo.sim.reactive import CONFLICT_MARGIN_M, HORIZON_S, HORIZON_STEP_S, Pose, reacting_agents


class TimedPoses(Protocol):
    """A target's poses over time, (T,) each: times [s], centre x and y [m], yaw [rad], speed [m/s]
    (an :class:`~coster_sumo.avoidability.evasion.Escape` is one)."""

    times: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray


def reaches_no_one(scene: Scene, target: int, poses: TimedPoses, margin_m: float = 1.0,
                   sizes: tuple[np.ndarray, np.ndarray] | None = None) -> bool:
    """True where a target driven along ``poses`` makes no logged agent react in a pass of
    :func:`~coster_sumo.sim.reactive.reactive_replayer`: that pass is then the log's (every agent
    keeps to its log), and its outcome the same as in log replay.

    There the target counts as deviating from its handover on, and nobody else deviates before an
    agent has reacted, so the target's poses alone decide (the replayer's step test:
    :func:`~coster_sumo.sim.reactive.reacting_agents` without a route). Tested on the safe side:
    each pose against the log steps next to its time (the step before and after too), the target's
    box grown by ``margin_m`` on every side, every vehicle or cyclist of the log a candidate.
    ``sizes``: every agent's length and width [m] as the replayer has them (:func:`agent_sizes`;
    a caller with many escapes of one scene passes them once computed)."""
    tr = scene.tracks
    lengths, widths = sizes if sizes is not None else agent_sizes(scene)
    others = np.flatnonzero((np.arange(tr.num_agents) != target) & (tr.object_type != int(ObjectType.PEDESTRIAN)))
    if not len(others) or not len(poses.times):
        return True
    length = float(lengths[target]) + 2 * margin_m  # the target's size in SUMO: the replayer's
    width = float(widths[target]) + 2 * margin_m
    n = scene.num_steps
    near = np.clip(np.searchsorted(scene.timestamps, np.asarray(poses.times, np.float64)), 0, n - 1)
    # every (pose, log step next to its time) pair at once: reacting_agents' constant-velocity test
    pose = np.repeat(np.arange(len(near)), 3)  # (Q,)
    k = np.clip(np.repeat(near, 3) + np.tile([-1, 0, 1], len(near)), 0, n - 1)
    horizon = np.arange(0.0, HORIZON_S + 1e-9, HORIZON_STEP_S)  # (H,)
    steps = np.minimum(k[:, None] + np.round(horizon / round(scene.dt, 6)).astype(np.int64), n - 1)  # (Q, H)
    c, s = np.cos(np.asarray(poses.yaw, np.float64)[pose]), np.sin(np.asarray(poses.yaw, np.float64)[pose])  # (Q,)
    v = np.asarray(poses.speed, np.float64)[pose]
    px = np.asarray(poses.x, np.float64)[pose][:, None] + (v * c)[:, None] * horizon  # (Q, H)
    py = np.asarray(poses.y, np.float64)[pose][:, None] + (v * s)[:, None] * horizon
    reach_l = 0.5 * (lengths[others] + length) + CONFLICT_MARGIN_M  # (A,)
    reach_w = 0.5 * (widths[others] + width) + CONFLICT_MARGIN_M
    for a0 in range(0, len(others), 64):  # (64, Q, H) at a time
        rows = others[a0:a0 + 64]
        dx = tr.x[rows][:, steps] - px  # (B, Q, H)
        dy = tr.y[rows][:, steps] - py
        meet = ((np.abs(c[:, None] * dx + s[:, None] * dy) <= reach_l[a0:a0 + 64, None, None])
                & (np.abs(-s[:, None] * dx + c[:, None] * dy) <= reach_w[a0:a0 + 64, None, None])
                & tr.valid[rows][:, steps] & tr.valid[rows][:, k][:, :, None])
        if meet.any():
            return False
    return True


class ReactionWatch:
    """Watches target copies in a joint pass of the log for the first step at which the reactive
    replayer would hand a logged agent to SUMO, had the copy been the target of a pass of its own.

    That pass (:func:`~coster_sumo.sim.reactive.reactive_replayer`) tests, every step from the
    target's handover on, the target's SUMO state against the logged agents in SUMO there: valid at
    the log step, no pedestrians, none of the agents the pass leaves out (``far``: never near the
    escape). Until an agent reacts, the target is the only vehicle that deviates, and the pass is the
    log's; so a copy that never meets that test had the joint pass's outcome in a pass of its own,
    and one that meets it needs that pass. Here the same test runs on the copy's SUMO state at
    every step it is in the joint pass (from its appearance on: a step more than the pass tests).

    Args:
        scene: the log; target: the target's row in it.
        far: per watched copy, the agent ids its own pass would leave out.
        sizes: every agent's length and width [m] as the replayer has them; dt: [s] its step.
    """

    def __init__(self, scene: Scene, target: int, far: Sequence[set[str]], sizes: tuple[np.ndarray, np.ndarray],
                 dt: float) -> None:
        tr = scene.tracks
        self.scene, self.sizes, self.dt = scene, sizes, dt
        base = (np.arange(tr.num_agents) != target) & (tr.object_type != int(ObjectType.PEDESTRIAN))
        ids = tr.ids.astype(str)
        self.eligible = [base & ~np.isin(ids, sorted(f)) for f in far]  # (A,) each

    def reacts(self, copy: int, k: int, pose: Pose, present: np.ndarray) -> bool:
        """Whether a logged agent reacts to watched copy ``copy`` (its index in ``far``) at ``pose``,
        at log step ``k``, the agents in SUMO then being ``present`` ((A,) bool)."""
        tr = self.scene.tracks
        if not 0 <= k < self.scene.num_steps:
            return False
        cand = np.flatnonzero(self.eligible[copy] & present & tr.valid[:, k])
        return bool(len(cand)) and bool(reacting_agents(self.scene, k, [pose], cand, sizes=self.sizes,
                                                        dt=self.dt).any())
