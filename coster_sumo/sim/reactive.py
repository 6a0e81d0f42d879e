"""Traffic that reacts: logged agents follow their log until the target's deviation reaches them.

In log replay nothing reacts to the target: a follower drives into a target that brakes. Here a
logged agent follows its log (moveToXY, or read straight from the log while nothing in SUMO needs
to see it) until the target's deviation from its nominal motion reaches it; from then on SUMO
drives it along its logged route with its vType's car-following model (Krauss by default, IDM
selectable), lane changes as SUMO makes them. The adversary never reacts: its plan is the
scenario. docs/gym.md explains it, with a picture.

When the deviation *reaches* an agent (:func:`reacting_agents`, evaluated every step once a
vehicle deviates):

- the target deviates when its centre is more than :data:`DEVIATION_M` from its logged centre at
  the same time, or its speed more than :data:`DEVIATION_SPEED_MPS` from the logged speed; an
  agent SUMO drives deviates the same way from its own log;
- an agent is reached when it is the target's follower or leader (in the target's route corridor,
  within :data:`FOLLOW_GAP_M` behind or :data:`LEAD_GAP_M` ahead), or when its logged path and a
  deviating vehicle's constant-velocity path would meet (boxes within :data:`CONFLICT_MARGIN_M`)
  within :data:`HORIZON_S`.

A target that holds its nominal motion never deviates, so nobody reacts and the episode is the
log's (``tests/sim/test_reactive.py``).

Where the agents live (:class:`ReactiveTraffic`): an agent is read from the log (no SUMO vehicle,
as :class:`~coster_sumo.sim.replay.LogTraffic`) until it has to be in SUMO: when it reacts, or when
it comes within :data:`SHADOW_RADIUS_M` of an agent that reacts (whose car-following model must see
it). In SUMO it follows its log by moveToXY until it reacts (one step later at the earliest: it is
first placed at its logged pose), then it is released to SUMO's driver model and never returns to
the log.
"""

from __future__ import annotations

import contextlib
import math
import tempfile
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coster_sumo.core.scene import ObjectType, Scene
from coster_sumo.formats.scene_folder import VTYPES, agent_sizes, vtype_for
from coster_sumo.sim.control import Departure
from coster_sumo.sim.corridor import PreparedPolyline
from coster_sumo.sim.states import VehicleStates, empty_states

if TYPE_CHECKING:
    from coster_sumo.core.scene import Tracks
    from coster_sumo.sim.replay import LogReplayer as LogReplayerLike
    from coster_sumo.sim.replay import LogTraffic
    from coster_sumo.sim.session import SumoSession

DEVIATION_M = 0.5  # [m] the target's centre this far from its logged centre: it deviates
DEVIATION_SPEED_MPS = 1.0  # [m/s] or its speed this far from its logged speed
FOLLOW_GAP_M = 60.0  # [m] an agent in the target's corridor up to this far behind is its follower
LEAD_GAP_M = 40.0  # [m] up to this far ahead, its leader
CORRIDOR_M = 2.0  # [m] half-width of the target's route corridor (lane centres 3-3.7 m apart)
CORRIDOR_HEADING_RAD = math.radians(45.0)  # travelling the corridor's way (not crossing it)
HORIZON_S = 3.0  # [s] paths that would meet within this time react
HORIZON_STEP_S = 0.5  # [s] sampling of that horizon
CONFLICT_MARGIN_M = 1.0  # [m] boxes this close (along and across) count as meeting
SHADOW_RADIUS_M = 60.0  # [m] logged agents this close to a reacting one are put into SUMO
CAR_FOLLOWING = ("Krauss", "IDM")
LANE_MATCH_M = 2.0  # [m] an agent is on a lane when its front is this close to the lane's centre line


@dataclass(frozen=True, slots=True)
class Pose:
    """A vehicle's state for the reaction test: centre (x, y) [m], yaw [rad], speed [m/s], length
    and width [m]."""

    x: float
    y: float
    yaw: float
    speed: float
    length: float
    width: float


def reacting_agents(scene: Scene, k: int, deviating: list[Pose], candidates: np.ndarray,
                    route: np.ndarray | PreparedPolyline | None = None, target: Pose | None = None,
                    sizes: tuple[np.ndarray, np.ndarray] | None = None, dt: float | None = None) -> np.ndarray:
    """Which of ``candidates`` the deviation of ``deviating`` reaches at log step ``k``.

    Args:
        scene: the log (the agents' logged paths).
        k: the log step now.
        deviating: the vehicles that deviate from their logs now (the target first, if it does).
        candidates: (A,) agent indices that may react (valid at ``k``, not the adversary, not
            reacting yet).
        route: (P, 2) [m] the target's route, for its corridor (None: no follower/leader test), or
            it prepared (a caller that asks every step prepares it once).
        target: the target's pose now (with ``route``).
        sizes: (A,) lengths and widths [m] of every agent (default :func:`agent_sizes`; a caller that
            asks every step passes them once computed).
        dt: [s] the log's step (default ``scene.dt``, a median over the log: a caller that asks every
            step passes it once computed).

    Returns:
        (A,) bool: reached.
    """
    tr = scene.tracks
    cand = np.asarray(candidates, np.int64)
    hit = np.zeros(len(cand), bool)
    if len(cand) == 0 or not deviating:
        return hit
    lengths, widths = sizes if sizes is not None else agent_sizes(scene)
    if route is not None and target is not None and len(route) >= 2:
        line = route if isinstance(route, PreparedPolyline) else PreparedPolyline(route)
        s_t, d_t, _ = line.project(np.array([target.x, target.y]))
        # a follower or leader is within the gap along the route and CORRIDOR_M of it, so (the chord no
        # longer than the arc) within this of the target: the others need no projection
        bound = max(FOLLOW_GAP_M, LEAD_GAP_M) + CORRIDOR_M + abs(float(d_t)) + 1e-6
        ax0, ay0 = tr.x[cand, k], tr.y[cand, k]
        close = np.flatnonzero(np.hypot(ax0 - target.x, ay0 - target.y) <= bound)
        if len(close):
            c_a = cand[close]
            s_a, d_a, seg = line.project(np.stack([ax0[close], ay0[close]], -1))
            rel = np.abs((tr.heading[c_a, k] - line.heading[seg] + np.pi) % (2 * np.pi) - np.pi)
            gap = s_a - float(s_t)
            in_corridor = (np.abs(d_a) <= CORRIDOR_M) & (rel <= CORRIDOR_HEADING_RAD)
            hit[close] |= in_corridor & (gap >= -FOLLOW_GAP_M) & (gap <= LEAD_GAP_M)
    horizon = np.arange(0.0, HORIZON_S + 1e-9, HORIZON_STEP_S)  # (H,)
    dt = scene.dt if dt is None else dt
    steps = np.minimum(k + np.round(horizon / dt).astype(np.int64), scene.num_steps - 1)  # (H,)
    grid = (cand[:, None], steps[None, :])
    ax, ay = tr.x[grid], tr.y[grid]  # (A, H)
    a_ok = tr.valid[grid]  # (A, H)
    l_cand, w_cand = lengths[cand], widths[cand]
    for p in deviating:
        c, s = math.cos(p.yaw), math.sin(p.yaw)
        px, py = p.x + p.speed * c * horizon, p.y + p.speed * s * horizon  # (H,)
        dx, dy = ax - px, ay - py  # (A, H) in the world frame
        along, across = np.abs(c * dx + s * dy), np.abs(-s * dx + c * dy)
        reach_l = 0.5 * (l_cand + p.length)[:, None] + CONFLICT_MARGIN_M  # (A, 1)
        reach_w = 0.5 * (w_cand + p.width)[:, None] + CONFLICT_MARGIN_M
        hit |= (a_ok & (along <= reach_l) & (across <= reach_w)).any(axis=1)
    return hit


def deviates(actual: Pose, scene: Scene, agent: int, k: int) -> bool:
    """Whether ``actual`` is off agent ``agent``'s logged motion at step ``k`` (False where the log has
    no state: nothing to compare)."""
    tr = scene.tracks
    if not (0 <= k < scene.num_steps) or not tr.valid[agent, k]:
        return False
    off = math.hypot(actual.x - float(tr.x[agent, k]), actual.y - float(tr.y[agent, k]))
    dv = abs(actual.speed - math.hypot(float(tr.vx[agent, k]), float(tr.vy[agent, k])))
    return off > DEVIATION_M or dv > DEVIATION_SPEED_MPS


def car_following_types(model: str) -> tuple[Path | None, str]:
    """The additional file declaring the replay's vTypes with ``model`` (None for Krauss, SUMO's
    default and the set's own ``vtypes.add.xml``) and the suffix of their ids."""
    if model not in CAR_FOLLOWING:
        raise ValueError(f"car_following must be one of {CAR_FOLLOWING}, not {model!r}")
    if model == "Krauss":
        return None, ""
    suffix = f"@{model.lower()}"
    rows = {v[0]: v for v in VTYPES.values()}
    lines = [f'    <vType id="{tid}{suffix}" vClass="{vclass}" guiShape="{shape}" length="{length}" '
             f'width="{width}" carFollowModel="{model}"/>' for tid, vclass, shape, length, width in rows.values()]
    path = Path(tempfile.gettempdir()) / f"coster_sumo_vtypes{suffix.replace('@', '_')}.add.xml"
    text = "<additional>\n" + "\n".join(lines) + "\n</additional>\n"
    if not path.is_file() or path.read_text() != text:
        tmp = path.with_suffix(f".{id(lines)}.tmp")
        tmp.write_text(text)
        tmp.replace(path)  # atomic: environments in other processes may read it now
    return path, suffix


class ReactiveTraffic:
    """The logged agents of one episode, reacting as the module docstring says.

    Per step: :meth:`before_step` (commands for the step that ends at log step ``k_next``), SUMO's
    step, then :meth:`states_at` (the agents still read from the log, to join SUMO's states) and
    :meth:`after_step` (who reacts from the next step on).

    Args:
        scene: the log, its first timestamp step 0 (the target's own track in it: its nominal motion).
        target: the target's id (driven by someone else; never put into SUMO here).
        exclude: agent ids never replayed (too far to matter).
        adversary: the adversary's id: it follows its plan, never reacts (None: none).
        scripted: more agents that follow their logs and never react (a Hard set's stopped vehicle).
        route: (P, 2) [m] the target's route, for its corridor.
        car_following: ``Krauss`` or ``IDM`` (the reacting agents' model).
    """

    def __init__(self, scene: Scene, target: str, exclude: set[str] | frozenset[str] = frozenset(),
                 adversary: str | None = None, route: np.ndarray | None = None,
                 car_following: str = "Krauss", log: LogTraffic | None = None,
                 scripted: Collection[str] = ()) -> None:
        from coster_sumo.sim.replay import LogTraffic

        self.scene = scene
        self.dt = scene.dt  # [s] once: a median over the log, asked for every step
        tr = scene.tracks
        self.target = tr.index_of(target)
        # the corridor test needs no finer route than every 2 m (the environment's is every 0.5 m)
        self.route = None if route is None else PreparedPolyline(np.asarray(route, np.float64).reshape(-1, 2)[::4])
        self._types_file, self._suffix = car_following_types(car_following)
        ids = [str(i) for i in tr.ids]
        in_log = np.array([i not in exclude and i != target for i in ids], bool)  # (A,)
        # ``log``: the same LogTraffic where the caller keeps one (read-only here)
        self.log = log if log is not None else LogTraffic(scene, exclude={*exclude, target})
        self.lengths, self.widths = (log.agent_lengths, log.agent_widths) if log is not None else agent_sizes(scene)
        self._row = np.cumsum(in_log) - 1  # agent index -> row of self.log
        # pedestrians stay on their logs (SUMO's car-following models drive vehicles) and are not put
        # into SUMO for the reacting vehicles to see
        self.replayed = in_log & (tr.object_type != int(ObjectType.PEDESTRIAN))
        fixed = {adversary, *scripted}
        self.may_react = self.replayed & np.array([i not in fixed for i in ids], bool)
        self.in_sumo: dict[int, str] = {}  # agent -> SUMO id while SUMO holds it
        self.released: set[int] = set()  # driven by SUMO (never back to the log)
        self.pending: set[int] = set()  # react from the next step on
        self.shadow: set[int] = set()  # to put into SUMO (log-driven) so that reacting ones see them
        self.unplaceable: set[int] = set()  # no lane under them: read from the log only
        self.reactions: list[tuple[str, float]] = []  # (agent id, time) in order
        self._deviating: list[Pose] = []  # the vehicles off their logs after the last step
        self._target_pose: Pose | None = None

    @property
    def additional_file(self) -> Path | None:
        """The vType file the SUMO session must load for this model (None: the set's own)."""
        return self._types_file

    def before_step(self, session: SumoSession, k_next: int) -> None:
        """Commands for the step that ends at log step ``k_next``: release the agents that react,
        move the others SUMO holds to their logged pose, put new ones into SUMO."""
        tr = self.scene.tracks
        for a in sorted(self.pending & set(self.in_sumo)):
            self._release(session, a, k_next)
        inside = 0 <= k_next < self.scene.num_steps
        if inside and self._deviating and k_next > 0:  # agents entering now, reached already
            entering = np.flatnonzero(self.may_react & tr.valid[:, k_next] & ~tr.valid[:, k_next - 1])
            entering = np.array([a for a in entering.tolist() if a not in self.in_sumo and a not in self.released
                                 and a not in self.unplaceable], np.int64)
            hit = reacting_agents(self.scene, k_next, self._deviating, entering, self.route, self._target_pose,
                                  (self.lengths, self.widths), self.dt)
            for a in entering[hit].tolist():
                self._insert(session, a, k_next)
        for a, sid in list(self.in_sumo.items()):
            if a in self.released:
                continue
            if not inside or not tr.valid[a, k_next]:
                session.remove_vehicle(self.in_sumo.pop(a))
                continue
            session.move_to_xy(sid, float(tr.x[a, k_next]), float(tr.y[a, k_next]), float(tr.heading[a, k_next]),
                               length=float(self.lengths[a]),
                               speed=float(math.hypot(tr.vx[a, k_next], tr.vy[a, k_next])))
        if inside:
            for a in sorted((self.pending | self.shadow) - set(self.in_sumo) - self.released - self.unplaceable):
                if tr.valid[a, k_next]:
                    self._place(session, a, k_next)

    def _place(self, session: SumoSession, a: int, k: int) -> None:
        """Add agent ``a`` to SUMO at its logged pose of step ``k`` (on the lane under its front)."""
        tr = self.scene.tracks
        x, y, h = float(tr.x[a, k]), float(tr.y[a, k]), float(tr.heading[a, k])
        length = float(self.lengths[a])
        vt = vtype_for(int(tr.object_type[a]))
        sid = str(tr.ids[a])
        # on SUMO's choice of edge, moved to its logged pose before the step (as the log replayer adds
        # agents without a staging lane); whether it is on a lane matters only when it is released
        session.add_vehicle(sid, length, float(self.widths[a]), vt[1], base_type=vt[0] + self._suffix)
        session.move_to_xy(sid, x, y, h, length=length, speed=float(math.hypot(tr.vx[a, k], tr.vy[a, k])))
        self.in_sumo[a] = sid

    def _insert(self, session: SumoSession, a: int, k: int) -> None:
        """Agent ``a`` enters at step ``k`` already reached: SUMO inserts it at its logged place and
        speed when that is safe (a reacting driver would not appear where it cannot stop), later if not."""
        tr = self.scene.tracks
        length = float(self.lengths[a])
        vt = vtype_for(int(tr.object_type[a]))
        under = _lane_under(session, tr, a, k, length, vt[1])
        if under is None:
            self.unplaceable.add(a)
            return
        edge, pos, lane = under
        sid = str(tr.ids[a])
        session.add_vehicle(sid, length, float(self.widths[a]), vt[1], base_type=vt[0] + self._suffix, remote=False,
                            departure=Departure([edge], lane=str(int(lane)),
                                                pos=f"{max(float(pos) - length, 0.0):.2f}",
                                                speed=f"{math.hypot(tr.vx[a, k], tr.vy[a, k]):.2f}"))
        last = int(np.flatnonzero(tr.valid[a])[-1])
        end = _lane_under(session, tr, a, last, length, vt[1])
        if end is not None and end[0] != edge:  # on to where its log ends
            with contextlib.suppress(Exception):
                session.api.vehicle.changeTarget(sid, end[0])
        self.in_sumo[a] = sid
        self.released.add(a)
        self.reactions.append((sid, float(self.scene.timestamps[k])))

    def _release(self, session: SumoSession, a: int, k: int) -> None:
        """Hand agent ``a`` to SUMO's driver model, routed along its logged path."""
        tr = self.scene.tracks
        sid = self.in_sumo[a]
        # where SUMO has it now (its logged pose of the last step): on a lane, or it stays on its log (a
        # vehicle handed to SUMO off every lane crashes libsumo's getters)
        under = _lane_under(session, tr, a, max(k - 1, 0), float(self.lengths[a]),
                            vtype_for(int(tr.object_type[a]))[1])
        self.pending.discard(a)
        if under is None:
            self.unplaceable.add(a)
            return
        ahead = np.flatnonzero(tr.valid[a])
        ahead = ahead[ahead >= k]
        poses = [(float(tr.x[a, j]), float(tr.y[a, j]), float(tr.heading[a, j]), float(self.lengths[a]))
                 for j in ahead[::-1][::5][:20]]  # heading for where its log ends, the end first
        # SUMO's route to where its log ends (on the lane-per-edge networks of converted scenes, the
        # logged lanes): asking SUMO for the lane under every logged pose costs about 4 ms a pose there
        session.release_vehicle(sid, poses)
        veh = session.api.vehicle
        try:  # a log faster than the lane's limit keeps its speed as its wish
            allowed = float(veh.getAllowedSpeed(sid))
            v = float(math.hypot(tr.vx[a, k], tr.vy[a, k]))
            if allowed > 0 and v > allowed:
                veh.setSpeedFactor(sid, v / allowed)
        except Exception:
            pass
        self.released.add(a)
        self.reactions.append((sid, float(self.scene.timestamps[min(k, self.scene.num_steps - 1)])))

    def states_at(self, k: int) -> VehicleStates:
        """The agents read from the log at step ``k`` (those SUMO does not hold)."""
        log = self.log
        if not 0 <= k < log.valid.shape[1]:
            return empty_states()
        keep = log.valid[:, k].copy()
        held = [int(self._row[a]) for a in (set(self.in_sumo) | self.released)]
        keep[held] = False
        r = np.flatnonzero(keep)
        return VehicleStates(ids=log.ids[r], x=log.x[r, k], y=log.y[r, k], yaw=log.yaw[r, k], speed=log.speed[r, k],
                             length=log.length[r], width=log.width[r], vclass=log.vclass[r], type_id=log.type_id[r])

    def after_step(self, k: int, states: VehicleStates, target: Pose | None) -> None:
        """Who reacts from the next step on, seen from the states after log step ``k``."""
        deviating: list[Pose] = []
        if target is not None and deviates(target, self.scene, self.target, k):
            deviating.append(target)
        if self.released:
            names = states.id_list()
            for a in self.released:
                sid = self.in_sumo.get(a)
                if sid is None or sid not in names:
                    continue
                i = names.index(sid)
                p = Pose(float(states.x[i]), float(states.y[i]), float(states.yaw[i]), float(states.speed[i]),
                         float(states.length[i]), float(states.width[i]))
                if deviates(p, self.scene, a, k) or not self.scene.tracks.valid[a, min(k, self.scene.num_steps - 1)]:
                    deviating.append(p)
        self._deviating, self._target_pose = deviating, target
        if not deviating or not 0 <= k < self.scene.num_steps:
            return
        tr = self.scene.tracks
        cand = np.flatnonzero(self.may_react & tr.valid[:, k])
        cand = np.array([a for a in cand.tolist() if a not in self.released and a not in self.pending
                         and a not in self.unplaceable], np.int64)
        hit = reacting_agents(self.scene, k, deviating, cand, self.route, target, (self.lengths, self.widths), self.dt)
        self.pending.update(cand[hit].tolist())
        reacting = sorted(self.pending | self.released)
        if reacting:  # what reacting agents must see: the logged agents around them, in SUMO
            ref = np.array([[p.x, p.y] for p in deviating[1:]] + [[tr.x[a, k], tr.y[a, k]] for a in self.pending])
            if len(ref):
                self.see_around(ref, k)

    def see_around(self, ref: np.ndarray, k: int) -> None:
        """Put the logged agents within :data:`SHADOW_RADIUS_M` of any of the points ``ref`` ((R, 2)
        [m]) at log step ``k`` into SUMO from the next step on (log-driven), so that a vehicle SUMO
        drives there sees them."""
        if not 0 <= k < self.scene.num_steps:
            return
        tr = self.scene.tracks
        ref = np.asarray(ref, np.float64).reshape(-1, 2)
        others = np.flatnonzero(self.replayed & tr.valid[:, k])
        d = np.hypot(tr.x[others, k][:, None] - ref[:, 0], tr.y[others, k][:, None] - ref[:, 1]).min(axis=1)
        self.shadow.update(others[d <= SHADOW_RADIUS_M].tolist())

    def remove_all(self, session: SumoSession) -> None:
        """Take every vehicle this traffic put into SUMO out again (the episode is over)."""
        for sid in self.in_sumo.values():
            session.remove_vehicle(sid)
        self.in_sumo.clear()


def _lane_under(session: SumoSession, tr: Tracks, a: int, k: int, length: float, vclass: str
                ) -> tuple[str, float, int] | None:
    """(edge, position [m], lane index) of the normal lane under agent ``a``'s front bumper at step ``k``,
    or None where there is none within :data:`LANE_MATCH_M` (off the lanes, or on a junction's
    internal lane)."""
    h = float(tr.heading[a, k])
    fx, fy = float(tr.x[a, k]) + 0.5 * length * math.cos(h), float(tr.y[a, k]) + 0.5 * length * math.sin(h)
    sim = session.api.simulation
    try:
        edge, pos, lane = sim.convertRoad(fx, fy, False, vclass)
        if not edge or str(edge).startswith(":"):
            return None
        lx, ly = sim.convert2D(str(edge), float(pos), int(lane))
    except Exception:  # no lane for its class nearby
        return None
    return (str(edge), float(pos), int(lane)) if math.hypot(lx - fx, ly - fy) <= LANE_MATCH_M else None


def replayer_for(config: str | Path, scene: Scene, target: str, handover: dict[str, float] | None = None,
                 traffic: str = "log", exclude: set[str] | frozenset[str] = frozenset()) -> LogReplayerLike:
    """The log replayer of a converted scene (``config``) for ``traffic`` ``log`` or ``reactive``
    (:func:`reactive_replayer`); ``exclude``: agents not replayed."""
    from coster_sumo.sim.replay import LogReplayer

    if traffic == "reactive":
        return reactive_replayer(config, scene, target, handover, exclude)
    return LogReplayer.for_config(config, scene, exclude=exclude, handover=handover)


def reactive_replayer(config: str | Path, scene: Scene, target: str, handover: dict[str, float] | None = None,
                      exclude: set[str] | frozenset[str] = frozenset()) -> LogReplayerLike:
    """The log replayer of a converted scene (``config``) whose agents react: each is handed to
    SUMO's driver (:meth:`LogReplayer.before_step`'s handover) once the target's deviation from its
    log reaches it (:func:`reacting_agents`). For ``coster-sumo run --traffic reactive``, where every
    logged agent is in SUMO already and the target is handed to a planner at the adversary's start."""
    from coster_sumo.sim.replay import LogReplayer

    class ReactiveReplayer(LogReplayer):
        def before_step(self, session: SumoSession, t_next: float) -> None:
            _react(self, session, target)
            super().before_step(session, t_next)

    return ReactiveReplayer.for_config(config, scene, exclude=exclude, handover=handover)


def _react(replayer: LogReplayerLike, session: SumoSession, target: str) -> None:
    """Hand over the agents the deviations of the last step reach (the adversary is not a logged agent)."""
    scene = replayer.scene
    tr = scene.tracks
    k = replayer.step_at(session.time)
    t_index = tr.index_of(target)
    sid = replayer.active.get(t_index)
    if k is None or sid is None or sid in session.hidden or not replayer.released:
        return  # only agents handed to SUMO (the target first) deviate from their logs
    # an agent handed to SUMO may have left the network (arrived, or removed after a collision)
    present = set(session.vehicle_ids()) - session.hidden
    released = [a for a in sorted(replayer.released) if replayer.active.get(a) in present]
    st = session.vehicle_states([replayer.active[a] for a in released])
    names = st.id_list()
    deviating: list[Pose] = []
    for a in released:
        if replayer.active[a] in names:
            i = names.index(replayer.active[a])
            p = Pose(float(st.x[i]), float(st.y[i]), float(st.yaw[i]), float(st.speed[i]), float(st.length[i]),
                     float(st.width[i]))
            if a == t_index or deviates(p, scene, a, k) or not tr.valid[a, k]:
                deviating.insert(0, p) if a == t_index else deviating.append(p)
    if not deviating:
        return
    cand = np.array([a for a in sorted(replayer.active) if a not in replayer.handover and a != t_index
                     and replayer.active[a] in present and tr.valid[a, k]
                     and int(tr.object_type[a]) != int(ObjectType.PEDESTRIAN)], np.int64)
    # the replayer's step is the log's to a millionth of a second: the horizon's offsets (multiples of
    # 0.5 s over a 0.1 s step) round to the same whole steps
    hit = reacting_agents(scene, k, deviating, cand, sizes=(replayer.lengths, replayer.widths), dt=replayer.dt)
    for a in cand[hit].tolist():
        replayer.handover[a] = float(session.time)
