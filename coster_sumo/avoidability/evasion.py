"""What a target can do to evade a generated collision, and what the search for it reports.

The vehicle classes' limits (:class:`ClassLimits`), the manoeuvres searched for each class and
their jerk-limited speed and smooth lateral profiles, the kind of a contact and when the adversary
becomes a threat, and the search's
results: an :class:`Escape` plan and a variant's :class:`Avoidability` (docs/method.md, "Step 8
Avoidability"). The search itself, which builds every candidate plan from these and checks it
against the scene, is :func:`coster_sumo.avoidability.search.assess`.

Times are simulation seconds, distances metres, accelerations m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coster_sumo.core.scene import ObjectType
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes, sat_overlap_depth

DT_S = 0.1  # [s] the plans' step (SUMO's step in the injection pass)
DEFAULT_REACTION_S = 1.0  # [s] a careful driver's reaction time: the one ``avoidable`` is stated for
JERK_MPS3 = 10.0  # [m/s^3] how fast braking or acceleration builds up
SWERVE_M = 1.0  # [m] a swerve inside the lane
LANE_CHANGE_M = 3.5  # [m] a change to the next lane


@dataclass(frozen=True)
class ClassLimits:
    """What a vehicle class can do (kinematic bicycle model with a friction limit).

    Attributes:
        name: the class.
        max_accel: [m/s^2] largest acceleration.
        emergency_decel: [m/s^2] largest deceleration; also the friction limit of the combined
            (longitudinal and lateral) acceleration.
        max_steer_rad: [rad] largest front-wheel angle.
        wheelbase_ratio: wheelbase as a share of the vehicle's length.
    """

    name: str
    max_accel: float
    emergency_decel: float
    max_steer_rad: float
    wheelbase_ratio: float

    def max_curvature(self, length_m: float) -> float:
        """[1/m] the tightest turn: tan(steer) / wheelbase."""
        return float(np.tan(self.max_steer_rad) / max(self.wheelbase_ratio * length_m, 0.5))


# SUMO's vType defaults for accel and emergencyDecel of these classes (docs/sumo.md §13); steering
# limits of ordinary road vehicles.
CLASS_LIMITS: dict[str, ClassLimits] = {
    "passenger": ClassLimits("passenger", 2.6, 9.0, np.radians(35.0), 0.6),
    "heavy": ClassLimits("heavy", 1.3, 7.0, np.radians(35.0), 0.55),
    "motorcycle": ClassLimits("motorcycle", 6.0, 10.0, np.radians(30.0), 0.65),
    "bicycle": ClassLimits("bicycle", 1.2, 7.0, np.radians(30.0), 0.65),
}
HEAVY_LENGTH_M = 7.5  # [m] a longer vehicle brakes like a truck or bus


def vehicle_class(object_type: int, length_m: float, width_m: float) -> ClassLimits:
    """The limits of a target from what the scene knows: its object type and its size."""
    if object_type == ObjectType.CYCLIST or width_m < 0.8:
        return CLASS_LIMITS["bicycle"]
    if width_m < 1.2:
        return CLASS_LIMITS["motorcycle"]
    if length_m >= HEAVY_LENGTH_M:
        return CLASS_LIMITS["heavy"]
    return CLASS_LIMITS["passenger"]


CONTACT_KINDS = ("rear_end_by_adversary", "into_vehicle_ahead", "side_swipe", "crossing", "head_on")


@dataclass(frozen=True)
class Motion:
    """A vehicle's box centre ``x``, ``y`` [m], heading ``yaw`` [rad] and ``speed`` [m/s], each a float
    (one moment) or a (K,) array (K moments), and its ``length`` and ``width`` [m]."""

    x: Any
    y: Any
    yaw: Any
    speed: Any
    length: float
    width: float


def contact_kind(target: Motion, adversary: Motion) -> str:
    """The kind of contact between the target and the adversary at t_col (both at that moment).

    By the angle between their headings: over 135 deg head-on, 45-135 deg crossing; under 45 deg
    (the same direction) by the side of the target the adversary touches, judged by which gap of
    the two centres, along or across the target, is closer to the touching distance: front (the
    target runs into a vehicle ahead), back (the adversary runs into the target) or side
    (side-swipe).
    """
    tx, ty, tyaw, tl, tw = target.x, target.y, target.yaw, target.length, target.width
    ax, ay, ayaw, al, aw = adversary.x, adversary.y, adversary.yaw, adversary.length, adversary.width
    rel = abs((ayaw - tyaw + np.pi) % (2 * np.pi) - np.pi)
    if rel > np.radians(135.0):
        return "head_on"
    if rel > np.radians(45.0):
        return "crossing"
    c, s = np.cos(tyaw), np.sin(tyaw)
    lon = (ax - tx) * c + (ay - ty) * s
    lat = -(ax - tx) * s + (ay - ty) * c
    lon_gap = abs(lon) - 0.5 * (tl + al)
    lat_gap = abs(lat) - 0.5 * (tw + aw)
    if lat_gap >= lon_gap:
        return "side_swipe"
    return "into_vehicle_ahead" if lon > 0 else "rear_end_by_adversary"


THREAT_LOOKAHEAD_S = 3.0  # [s] constant-velocity look-ahead that makes the adversary a threat


def threat_time(times: np.ndarray, target: Motion, adversary: Motion) -> float:
    """The first moment from the adversary's appearance at which it is a threat: both vehicles,
    extrapolated at their current velocities, overlap within :data:`THREAT_LOOKAHEAD_S`.

    Args:
        times: (K,) [s] from t_start to t_col; target: the target's nominal motion then ((K,) arrays);
            adversary: the same of the adversary's plan.
    """
    tx, ty, tyaw, tv, tl, tw = target.x, target.y, target.yaw, target.speed, target.length, target.width
    ax, ay, ayaw, av = adversary.x, adversary.y, adversary.yaw, adversary.speed
    al, aw = adversary.length, adversary.width
    tau = np.arange(0.0, THREAT_LOOKAHEAD_S + 1e-9, DT_S)  # (L,)
    t_box = make_boxes(tx[:, None] + tv[:, None] * np.cos(tyaw)[:, None] * tau,
                       ty[:, None] + tv[:, None] * np.sin(tyaw)[:, None] * tau, tyaw[:, None], tl, tw)
    a_box = make_boxes(ax[:, None] + av[:, None] * np.cos(ayaw)[:, None] * tau,
                       ay[:, None] + av[:, None] * np.sin(ayaw)[:, None] * tau, ayaw[:, None], al, aw)
    # in contact or touching: box_signed_distance <= 0. The SAT depth alone decides it where it is
    # positive (overlap) or clearly negative (a separating axis, so a gap of at least that much);
    # only the boxes about to touch need the exact distance
    depth = sat_overlap_depth(t_box, a_box)  # (K, L)
    hit = depth > 0.0
    close = ~hit & (depth > -1e-6)
    if close.any():
        hit[close] = box_signed_distance(t_box[close], a_box[close]) <= 0.0
    first = hit.any(axis=1)  # (K,)
    return float(times[np.argmax(first)]) if first.any() else float(times[-1])


@dataclass(frozen=True)
class Manoeuvre:
    """One evasive manoeuvre: a longitudinal and a lateral profile.

    Attributes:
        longitudinal: ``nominal`` (the nominal speeds), ``hold``, ``brake`` or ``accelerate``.
        accel: [m/s^2] the goal acceleration (negative when braking; 0 for nominal and hold).
        lateral_m: [m] final sideways shift of the path, > 0 to the left.
        lateral_accel: [m/s^2] the lateral acceleration the shift is planned with (0: none).
    """

    longitudinal: str
    accel: float
    lateral_m: float
    lateral_accel: float

    def describe(self) -> str:
        lon = {"nominal": "keep the nominal speed", "hold": "hold the speed",
               "brake": f"brake at {-self.accel:.1f} m/s^2", "accelerate": f"accelerate at {self.accel:.1f} m/s^2"}
        side = "" if self.lateral_m == 0 else (
            f", {'swerve' if abs(self.lateral_m) < LANE_CHANGE_M else 'change lane'} "
            f"{'left' if self.lateral_m > 0 else 'right'} {abs(self.lateral_m):.1f} m")
        return lon[self.longitudinal] + side


def manoeuvres(limits: ClassLimits) -> list[Manoeuvre]:
    """Every manoeuvre searched for a vehicle of ``limits``: 8 longitudinal x 9 lateral profiles."""
    e = limits.emergency_decel
    lon = [("nominal", 0.0), ("hold", 0.0), ("brake", -2.0), ("brake", -4.0), ("brake", -0.7 * e), ("brake", -e),
           ("accelerate", 0.5 * limits.max_accel), ("accelerate", limits.max_accel)]
    lat = [(0.0, 0.0)] + [(sign * d, a) for d in (SWERVE_M, LANE_CHANGE_M) for sign in (1.0, -1.0)
                          for a in (0.3 * e, 0.6 * e)]
    return [Manoeuvre(kind, acc, d, a) for kind, acc in lon for d, a in lat]


@dataclass
class Escape:
    """The least demanding escape found from one moment on.

    Attributes:
        t_act: [s] when the target starts to act.
        manoeuvre: what it does.
        times: (T,) [s] 10 Hz from the adversary's appearance to t_col + the horizon.
        x, y, yaw, speed: (T,) the target's plan (box centre [m], heading [rad], [m/s]).
        clearance_m: [m] smallest gap to any vehicle over the plan.
        peak_decel: [m/s^2] largest deceleration. peak_lateral_accel: [m/s^2]. peak_accel:
            [m/s^2] largest combined acceleration (what the escape demands).
        proven: None before the SUMO replay; then whether SUMO confirmed it (no contact, on road).
        proof: what the replay found.
        blocked_by: the vehicles the plan came closer to than the search allows, moving as in the
            nominal pass (empty for an escape the search found clear); SUMO's drivers of those
            vehicles react in the replay.
    """

    t_act: float
    manoeuvre: Manoeuvre
    times: np.ndarray = field(repr=False)
    x: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    yaw: np.ndarray = field(repr=False)
    speed: np.ndarray = field(repr=False)
    clearance_m: float
    peak_decel: float
    peak_lateral_accel: float
    peak_accel: float
    proven: bool | None = None
    proof: dict[str, Any] = field(default_factory=dict)
    blocked_by: tuple[str, ...] = ()

    def summary(self) -> dict[str, Any]:
        return {"t_act": round(self.t_act, 3), "manoeuvre": self.manoeuvre.describe(),
                "longitudinal": self.manoeuvre.longitudinal, "accel_goal": self.manoeuvre.accel,
                "lateral_m": self.manoeuvre.lateral_m, "clearance_m": round(self.clearance_m, 3),
                "peak_decel": round(self.peak_decel, 3), "peak_lateral_accel": round(self.peak_lateral_accel, 3),
                "peak_accel": round(self.peak_accel, 3), "min_speed": round(float(self.speed.min()), 3),
                "proven_in_sumo": self.proven, **({"proof": self.proof} if self.proof else {}),
                **({"blocked_by": list(self.blocked_by)} if self.blocked_by else {})}

    def csv(self) -> str:
        """The plan at 10 Hz: time [s], x, y [m] (box centre), yaw_deg, speed [m/s]."""
        lines = ["time,x,y,yaw_deg,speed"]
        lines += [f"{t:.2f},{x:.4f},{y:.4f},{np.degrees(h):.3f},{v:.4f}"
                  for t, x, y, h, v in zip(self.times, self.x, self.y, self.yaw, self.speed, strict=True)]
        return "\n".join(lines) + "\n"


@dataclass
class Avoidability:
    """Avoidability of one variant (docs/method.md, step 8).

    Attributes:
        t_col: [s]. t_appear: [s] the adversary's appearance. t_threat: [s] when it becomes a threat.
        contact_kind: one of :data:`CONTACT_KINDS`.
        vehicle_class: the target's class (its limits).
        last_moment_s: [s] before t_col, the latest moment from which an escape exists (None: none).
        escapes: reaction time [s] -> the least demanding escape acting at t_threat + reaction
            time or later (None where there is none).
        reaction_time_s: [s] the reaction time ``avoidable`` is stated for.
        candidates: how many plans were checked.
        blocked: plans clear of the adversary that only vehicles SUMO drives were in the way of,
            tried in SUMO where no escape was found (:func:`coster_sumo.avoidability.search.assess`); one that
            SUMO clears becomes the escape of every reaction time it acts late enough for.
    """

    t_col: float
    t_appear: float
    t_threat: float
    contact_kind: str
    vehicle_class: str
    last_moment_s: float | None
    escapes: dict[float, Escape | None]
    reaction_time_s: float = DEFAULT_REACTION_S
    candidates: int = 0
    blocked: list[Escape] = field(default_factory=list)

    def adopt_cleared(self) -> None:
        """After the proof: every reaction time without an escape takes the least demanding blocked
        plan SUMO cleared that acts at least that long after the threat."""
        cleared = sorted((e for e in self.blocked if e.proven), key=lambda e: (e.peak_accel, e.t_act))
        for r, e in self.escapes.items():
            if e is None:
                self.escapes[r] = next((b for b in cleared if b.t_act >= self.t_threat + r - 1e-6), None)

    @property
    def flipped_by_reacting_traffic(self) -> bool:
        """Avoidable only through a plan the search found blocked and SUMO's traffic cleared."""
        return self.flipped_at(self.reaction_time_s)

    def avoidable_at(self, reaction_s: float) -> bool:
        """An escape acting ``reaction_s`` after the threat or later that SUMO did not refute.

        A slower driver's escape serves a quicker one too, so the label is monotone in the
        reaction time.
        """
        return any(e is not None and e.proven is not False for r, e in self.escapes.items() if r >= reaction_s - 1e-9)

    @property
    def avoidable(self) -> bool:
        return self.avoidable_at(self.reaction_time_s)

    @property
    def escape(self) -> Escape | None:
        """The escape behind the label: the one proven in SUMO at the earliest reaction time not
        before the stated one (an escape left unproven because a later one cleared,
        :func:`~coster_sumo.avoidability.proof.prove_labels`, only where none is proven)."""
        late = [self.escapes[r] for r in sorted(self.escapes) if r >= self.reaction_time_s - 1e-9]
        return (next((e for e in late if e is not None and e.proven), None)
                or next((e for e in late if e is not None and e.proven is not False), None))

    def summary(self) -> dict[str, Any]:
        return {"avoidable": self.avoidable, "reaction_time_s": self.reaction_time_s,
                "avoidable_at": {f"{r:g}": self.avoidable_at(r) for r in sorted(self.escapes)},
                "contact_kind": self.contact_kind, "vehicle_class": self.vehicle_class,
                "t_col": round(self.t_col, 3), "t_appear": round(self.t_appear, 3), "t_threat": round(self.t_threat, 3),
                "threat_before_tcol_s": round(self.t_col - self.t_threat, 3),
                "last_moment_to_act_s": None if self.last_moment_s is None else round(self.last_moment_s, 3),
                "escapes": {f"{r:g}": (e.summary() if e is not None else None)
                            for r, e in sorted(self.escapes.items())},
                "candidates_checked": self.candidates,
                "blocked_escapes_tried_in_sumo": sum(e.proven is not None for e in self.blocked),
                "blocked_escapes_cleared_in_sumo": sum(bool(e.proven) for e in self.blocked),
                "flipped_by_reacting_traffic": self.flipped_by_reacting_traffic,
                "flipped_by_reacting_traffic_at": {f"{r:g}": self.flipped_at(r) for r in sorted(self.escapes)}}

    def flipped_at(self, reaction_s: float) -> bool:
        """Avoidable at ``reaction_s`` only through blocked plans SUMO's traffic cleared (an escape
        left unproven because a later one cleared counts as the search found it: clear)."""
        ok = [e for r, e in self.escapes.items() if r >= reaction_s - 1e-9 and e is not None and e.proven is not False]
        return bool(ok) and all(e.blocked_by for e in ok)


# ----------------------------------------------------------------------------- profiles

def speed_profiles(v0: float, a0: float, goal: np.ndarray, steps: int, v_cap: float) -> tuple[np.ndarray, np.ndarray]:
    """Jerk-limited speed profiles from (v0, a0) towards goal accelerations.

    Args:
        v0: [m/s], a0: [m/s^2] the target's state when it acts.
        goal: (P,) [m/s^2] goal accelerations (negative: braking).
        steps: T, the number of steps of DT_S after acting.
        v_cap: [m/s] acceleration stops here.

    Returns:
        speed (P, T+1) [m/s] from the moment of acting (index 0 = v0), accel (P, T+1) [m/s^2].
    """
    tau = np.arange(steps + 1) * DT_S  # (T+1,)
    # the acceleration moves from a0 to its goal at JERK_MPS3
    a = a0 + np.clip(goal[:, None] - a0, -JERK_MPS3 * tau, JERK_MPS3 * tau)  # (P, T+1)
    v = v0 + np.concatenate([np.zeros((len(goal), 1)), np.cumsum(0.5 * (a[:, 1:] + a[:, :-1]) * DT_S, axis=1)], 1)
    # a vehicle that brakes to a standstill stays there; one that accelerates stops at the cap
    stopped = np.maximum.accumulate(v <= 0.0, axis=1)
    capped = np.maximum.accumulate(v >= max(v_cap, v0), axis=1) & (goal[:, None] > 0)
    v = np.where(stopped, 0.0, np.where(capped, max(v_cap, v0), v))
    a = np.where(stopped | capped, 0.0, a)
    return v, a


def lateral_profile(tau: np.ndarray, shift_m: np.ndarray, lat_accel: np.ndarray) -> np.ndarray:
    """Sideways shift over time: a smooth change (zero sideways speed at both ends).

    d(tau) = D (u - sin(2 pi u) / (2 pi)), u = tau / tau_d, with tau_d chosen so that the peak of
    d'' (2 pi D / tau_d^2) equals ``lat_accel``.

    Args:
        tau: (T,) [s] time since acting; shift_m, lat_accel: (M,).

    Returns:
        (M, T) [m].
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        tau_d = np.where(lat_accel > 0, np.sqrt(2 * np.pi * np.abs(shift_m) / np.maximum(lat_accel, 1e-9)), 1.0)
    u = np.clip(tau[None, :] / tau_d[:, None], 0.0, 1.0)
    return shift_m[:, None] * (u - np.sin(2 * np.pi * u) / (2 * np.pi))
