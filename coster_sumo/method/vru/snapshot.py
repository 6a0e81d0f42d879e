"""The collision snapshot of a pedestrian or cyclist adversary (docs/method.md, "Pedestrian and
cyclist adversaries", snapshot).

The collision time is chosen as for a vehicle (the rule of ``--collision-time``; ``entropy`` reads
the traffic prior's velocity entropy around the target). At that time candidates of the class are
drawn around the target: a speed and a heading relative to the target's. With the traffic prior
(COSTER's init) and the shipped counts of the class (``models/vru_states.npz``,
:mod:`~coster_sumo.method.vru.contact_states`) both are drawn from what the class does on the road in
the corpus, the heading's angle to the target's direction turned towards the target's path; else
(``--init random``, or no counts) by the class's rules: a pedestrian mostly crosses the target's
path, a cyclist mostly rides along it, a speed from the class's literature distribution
(:meth:`~coster_sumo.method.vru.classes.VruClass.draw_speed`). Then a start beside or ahead of the target; each
is translated towards the target until the boxes touch (the vehicle placement's geometry). A
placement is kept when it lies in the class's area (:mod:`coster_sumo.method.vru.areas`), overlaps no other
agent and closes in on the target; among those, one is drawn with weight ``exp(-d / EDGE_SCALE_M)``
of its distance ``d`` to the road edge or a crossing: where a pedestrian or cyclist enters the
road, not in the middle of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coster_sumo.core.snapshot import AgentState, CollisionSnapshot
from coster_sumo.errors import NoSnapshot
from coster_sumo.method.collision_time import choose_collision_time, search_window
from coster_sumo.method.snapshot import Obstacles, PlacementRequest, _scene_prior, closing, contact_placements
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import VruClass
from coster_sumo.method.vru.contact_states import ContactStates

CANDIDATES = 400  # placements drawn per snapshot
EDGE_SCALE_M = 1.5  # [m] the weight's length scale: a placement this much further in is e times less likely
CROSSING_SHARE = {"pedestrian": 0.85, "cyclist": 0.3}  # share of candidates crossing the target's path
HEADING_SD_RAD = np.radians(15.0)  # spread around the crossing / along-path heading


def _headings(vru: VruClass, target_yaw: float, side: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N,) [rad] candidate headings: crossing from ``side`` (+1 left, -1 right) or along the target."""
    n = len(side)
    crossing = rng.random(n) < CROSSING_SHARE[vru.name]
    across = target_yaw - side * 0.5 * np.pi  # from the left moving right, and the reverse
    along = target_yaw + np.where(rng.random(n) < 0.8, 0.0, np.pi)  # mostly the target's direction
    return np.where(crossing, across, along) + rng.normal(0.0, HEADING_SD_RAD, n)


def learned_states(models_dir: str | Path | None, name: str) -> ContactStates | None:
    """The shipped (or ``models_dir``'s) counts when they hold class ``name``, else None."""
    from coster_sumo.infra import weights

    path = weights.weights_path(weights.VRU_STATES, models_dir, required=False)
    if not path.is_file():
        return None
    states = weights.load_cached(path, ContactStates.load)
    return states if states.has(name) else None


def draw_states(vru: VruClass, target_yaw: float, side: np.ndarray, rng: np.random.Generator,
                states: ContactStates | None) -> tuple[np.ndarray, np.ndarray]:
    """(N,) [rad] headings and (N,) [m/s] speeds of candidates starting on ``side``: learned from
    ``states``, else by the class's rules (module docstring)."""
    if states is None:
        return _headings(vru, target_yaw, side, rng), vru.draw_speed(rng, len(side))
    speed, angle = states.draw(vru.name, rng, len(side))
    # from the left (side +1) across is target_yaw - pi/2: towards the path, as the rules' crossing
    return target_yaw - side * angle, speed


def _starts(tgt: AgentState, side: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, 2) [m] start centres beside and ahead of the target (translated towards it afterwards)."""
    n = len(side)
    fwd = np.array([np.cos(tgt.yaw), np.sin(tgt.yaw)])
    left = np.array([-fwd[1], fwd[0]])
    along = rng.uniform(-0.3 * tgt.length, 0.5 * tgt.length + 4.0, n)
    across = side * (0.5 * tgt.width + rng.uniform(0.5, 6.0, n))
    return np.array([tgt.x, tgt.y]) + along[:, None] * fwd + across[:, None] * left


def collision_step(request: PlacementRequest, use_prior: bool) -> tuple[int, tuple[float, ...]]:
    """The 2 Hz collision step by the request's rule, and the entropy curve it read (empty without the prior)."""
    r = request
    window = search_window(r.scene, r.target, r.exclude)
    if len(window) == 0:
        raise NoSnapshot("the target is not valid inside the collision-time search window")
    rule, entropy = r.collision_time, None
    if use_prior and rule == "entropy":
        from coster_sumo.infra import weights
        from coster_sumo.method.snapshot import PriorMemo
        from coster_sumo.prior.infer import load_prior

        model = weights.load_cached(weights.weights_path(weights.PRIOR, r.models_dir), load_prior)
        _, entropy = _scene_prior(model, r.scene, r.target, r.memo if r.memo is not None else PriorMemo())
    elif rule == "entropy":
        rule = "last"  # the random init's rule, as for a vehicle
    t_col = choose_collision_time(window, rule, r.rng, entropy)
    return t_col, tuple(float(v) for v in entropy) if entropy is not None else ()


def vru_snapshot(request: PlacementRequest, vru: VruClass, area: ClassArea, use_prior: bool,
                 init_method: str) -> CollisionSnapshot:
    """A collision snapshot with a ``vru`` adversary (module docstring); :class:`NoSnapshot` when no
    placement at the chosen collision time is acceptable."""
    r, rng = request, request.rng
    t_col, entropy = collision_step(r, use_prior)
    tr = r.scene.tracks
    tgt = AgentState.from_tracks(tr, r.target, t_col)
    side = np.where(rng.random(CANDIDATES) < 0.5, 1.0, -1.0)
    states = learned_states(r.models_dir, vru.name) if use_prior else None
    heading, speed = draw_states(vru, tgt.yaw, side, rng, states)
    boxes, sd = contact_placements(tgt, heading, np.full(CANDIDATES, vru.length), np.full(CANDIDATES, vru.width),
                                   _starts(tgt, side, rng))
    ok = ~np.isnan(boxes).any(axis=1)
    obstacles = Obstacles.at_step(r.scene, t_col, [r.target])
    if len(obstacles.boxes) and ok.any():
        from coster_sumo.geometry.boxes import boxes_overlap

        ok[ok] = ~boxes_overlap(boxes[ok][:, None, :], obstacles.boxes[None, :, :]).any(axis=1)
    if ok.any():
        ok[ok] = area.contains(boxes[ok][:, :2])
    ok &= closing(np.nan_to_num(boxes), speed, tgt, r.strict)
    if not ok.any():
        raise NoSnapshot(f"no {vru.name} placement of {CANDIDATES} tries is in the {vru.name}'s area, free of "
                         "other agents and closing in on the target", t_index=t_col)
    cand = np.flatnonzero(ok)
    weight = np.exp(-area.edge_distance(boxes[cand, :2]) / EDGE_SCALE_M) + 1e-12
    k = int(rng.choice(cand, p=weight / weight.sum()))
    b = boxes[k]
    adv = AgentState(x=float(b[0]), y=float(b[1]), yaw=float(np.angle(np.exp(1j * b[2]))), speed=float(speed[k]),
                     length=vru.length, width=vru.width)
    return CollisionSnapshot(
        scenario_id=r.scene.scenario_id, target_id=str(tr.ids[r.target]), t_index=t_col,
        time=float(r.scene.timestamps[t_col]), target=tgt, adversary=adv, signed_distance=float(sd[k]),
        entropy=entropy, collision_time_method=r.collision_time, init_method=init_method, seed=r.seed,
        adversary_class=vru.name)
