"""Log replay of a converted WOMD scene in SUMO, and a plain run of any SUMO configuration.

Replay: SUMO steps the converted scene at the log's step length; every logged agent is added when
its state first becomes valid, driven every step through ``moveToXY`` with SUMO's own control off
(:meth:`SumoSession.move_to_xy`), removed when its state becomes invalid (and added again, under
``<id>#<k>``, if it comes back). Traffic lights follow the logged signal states through the link
mapping the converter wrote (``lane_map.json``). After each step the positions SUMO reports are read
back and converted front-bumper -> box centre; the centre error against the log over every valid
state is the replay's fidelity figure.

Staging: a vehicle whose very first placement is off every lane crashes SUMO in its outputs (FCD)
and in some getters (docs/sumo.md §3), and logged agents often start off the lanes (parked cars,
pedestrians). So every agent is added one step before it first appears, on an isolated staging lane
the converter puts 1 km below the map, and moved to its logged pose in the next step. While parked
there it is in ``SumoSession.hidden``: recordings and event checks do not see it.

Time: the converter shifts the log onto SUMO's clock so that the first log step has a staging step
before it: ``scene.npz``'s timestamps are SUMO times (``SumoSession.time`` after the step that
shows them; ``scene.meta["sumo_time_offset_s"]`` = SUMO time - WOMD time, 2 steps = 0.2 s for a
WOMD log starting at 0). SUMO's FCD output labels the same state one step earlier (``time - dt``).

Nothing SUMO-specific is imported at module import time.
"""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import Scene, Tracks
from coster_sumo.errors import InputError, not_found
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.formats.scene_folder import (
    LANE_MAP_FILE,
    SCENE_FILE,
    agent_sizes,
    converted_scene_file,
    tls_state_strings,
    vtype_for,
)
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.sim.control import Departure
from coster_sumo.sim.session import SumoSession
from coster_sumo.sim.states import VehicleStates, empty_states

STAGING_SPACING_M = 25.0  # [m] between agents parked on the staging lane (longer than any vehicle)
TIME_EPS_S = 1e-6  # [s] two simulation times this close are the same step
_FAR_BLOCK = 256  # agents looked up at once by far_agents (a city pass has thousands of rows of 10^4 steps)


@dataclass(slots=True)
class ReplayOptions:
    """How to run a replay.

    Attributes:
        end: [s] stop at this simulation time (None: the configuration's end / the log's end).
        fcd_output: SUMO ``--fcd-output`` file (None: none).
        traci: use a TraCI socket instead of libsumo.
        progress: called with (step, num_steps) after every step (for progress bars).
    """

    end: float | None = None
    fcd_output: str | Path | None = None
    traci: bool = False
    progress: Callable[[int, int], None] | None = None


def _session(cfg: Path, opts: ReplayOptions, end: float | None = None) -> SumoSession:
    options = {"--fcd-output": str(Path(opts.fcd_output).resolve())} if opts.fcd_output else {}
    return SumoSession(cfg, end=opts.end if end is None else end, options=options, traci=opts.traci)


def _staging_slots(sim: SumoSession, lane_id: str | None) -> np.ndarray | None:
    """(k, 2) points along the staging lane, STAGING_SPACING_M apart (None: the net has none)."""
    if not lane_id:
        return None
    try:
        shape = np.asarray(sim.api.lane.getShape(lane_id), np.float64)
    except Exception:  # an older conversion without a staging lane
        return None
    a, b = shape[0], shape[-1]
    length = float(np.hypot(*(b - a)))
    s = np.arange(STAGING_SPACING_M, length - STAGING_SPACING_M, STAGING_SPACING_M)
    if len(s) == 0:
        return None
    return a + (s / length)[:, None] * (b - a)


def far_agents(tracks: Tracks, path: np.ndarray, radius_m: float, from_step: int = 0) -> set[str]:
    """Ids of the agents whose valid positions from step ``from_step`` on all lie farther than
    ``radius_m`` from every point of ``path`` (P, 2) [m] (time aside: conservative). Agents without a
    valid position there are not listed (a replay never adds them).

    A replay may leave such agents out where nothing closer matters (the proof of an escape, an
    environment's observation radius): they react to nothing and cannot touch the path.

    Every valid position is looked up at once in a k-d tree of the path's points (its nearest point
    within a hair more than ``radius_m``, then measured against ``radius_m`` itself); an agent with a
    position that is not finite is far (no distance to it is under the radius)."""
    from scipy.spatial import cKDTree

    path = np.asarray(path, np.float64).reshape(-1, 2)
    seen = tracks.valid[:, from_step:].any(axis=1)
    near = np.zeros(tracks.num_agents, bool)
    broken = np.zeros(tracks.num_agents, bool)
    tree = cKDTree(path) if len(path) else None
    for a0 in range(0, tracks.num_agents if tree is not None else 0, _FAR_BLOCK):
        agent, step = np.nonzero(tracks.valid[a0:a0 + _FAR_BLOCK, from_step:])
        if not len(agent):
            continue
        agent += a0
        step += from_step
        pts = np.stack([tracks.x[agent, step], tracks.y[agent, step]], -1)
        finite = np.isfinite(pts).all(-1)
        dist, _ = tree.query(pts[finite], distance_upper_bound=radius_m * (1.0 + 1e-9) + 1e-9)  # type: ignore[union-attr]
        near[agent[finite][dist <= radius_m]] = True
        broken[agent[~finite]] = True
    # a broken log value (NaN) puts no point of the agent near the path: far, as measured one by one
    return {str(i) for i in tracks.ids[seen & (~near | broken)]}


class LogReplayer:
    """Drives every logged agent of a converted scene (a :class:`~coster_sumo.sim.inject.StepActor`).

    Call :meth:`before_step` with the simulation time the coming step ends at (``t_next``); at the
    log step whose timestamp is ``t_next`` it removes agents that became invalid, moves every valid
    one to its logged pose, stages the agents that appear at the next log step, and sets the
    logged signal states.

    Args:
        scene: the converted scene (``scene.npz``: timestamps already on SUMO's clock).
        tls: ``lane_map.json["tls"]`` (per tls id, the WOMD lane of each link index).
        staging_lane: the converted network's staging lane (None: agents are added in place).
        exclude: agent ids not to drive at all.
        handover: agent id -> time [s] from which the log stops driving it and hands it to SUMO (a
            planner takes the target over this way); it is not removed when its log ends.
    """

    def __init__(self, scene: Scene, tls: dict[str, dict] | None = None, staging_lane: str | None = None,
                 exclude: set[str] | frozenset[str] = frozenset(),
                 handover: dict[str, float] | None = None) -> None:
        self.scene = scene
        self.dt = round(scene.dt, 6)  # [s] the log's step (SUMO's step length must match it)
        tr = scene.tracks
        self.lengths, self.widths = agent_sizes(scene)
        keep = np.array([str(i) not in exclude for i in tr.ids], bool)
        self.valid = tr.valid & keep[:, None]  # (A, T)
        self.tls_states = tls_state_strings(scene, tls or {})
        self.staging_lane = staging_lane
        self.active: dict[int, str] = {}  # agent index -> SUMO id while it is in the simulation
        self.appearances = np.zeros(tr.num_agents, np.int64)
        self.tls_changes = 0
        self._tls_last: dict[str, str] = {}
        self._slots: np.ndarray | None = None
        self._slot = 0
        self._staging_checked = False
        self.handover = {tr.index_of(a): float(t) for a, t in (handover or {}).items()}
        self.released: set[int] = set()

    def restarted(self) -> LogReplayer:
        """A replayer of the same log from its start, sharing this one's read-only arrays (agents'
        sizes, validity, signal strings): what a new one of the same arguments is, without their cost
        (an environment replays a scenario many times)."""
        new = copy.copy(self)
        new.active, new.released, new._tls_last = {}, set(), {}
        new.handover = dict(self.handover)
        new.appearances = np.zeros_like(self.appearances)
        new.tls_changes, new._slot, new._slots, new._staging_checked = 0, 0, None, False
        return new

    @classmethod
    def for_config(cls, config: str | Path, scene: Scene | None = None,
                   exclude: set[str] | frozenset[str] = frozenset(),
                   handover: dict[str, float] | None = None) -> LogReplayer:
        """The replayer of the converted scene whose ``.sumocfg`` is ``config``."""
        folder = Path(config).parent
        if scene is None:
            scene = load_scene(folder / SCENE_FILE)
        try:
            lane_map = json.loads((folder / LANE_MAP_FILE).read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{folder / LANE_MAP_FILE}: cannot read the lane mapping ({exc})") from None
        return cls(scene, lane_map.get("tls", {}), lane_map.get("staging_lane"), exclude, handover)

    def step_at(self, t: float) -> int | None:
        """Index of the log step at simulation time ``t`` [s], or None outside the log.

        Steps are on the regular grid ``timestamps[0] + k * dt`` (WOMD timestamps jitter by a few
        microseconds; SUMO's step is exact).
        """
        ts = self.scene.timestamps
        if len(ts) == 0:
            return None
        dt = self.dt
        k = int(round((t - ts[0]) / dt))
        return k if 0 <= k < len(ts) and abs(t - ts[0] - k * dt) < 0.25 * dt else None

    def add_as(self, sim: SumoSession, a: int, sid: str, route_edges: list[str] | None = None) -> None:
        """Add vehicle ``sid`` with logged agent ``a``'s length, width and vType (the log does not
        drive it: a replayed agent's own copy is :meth:`before_step`'s)."""
        vt = vtype_for(int(self.scene.tracks.object_type[a]))
        sim.add_vehicle(sid, float(self.lengths[a]), float(self.widths[a]), vt[1], base_type=vt[0],
                        departure=Departure(route_edges))

    def _add(self, sim: SumoSession, a: int) -> str:
        tr = self.scene.tracks
        n = int(self.appearances[a])
        sid = str(tr.ids[a]) if n == 0 else f"{tr.ids[a]}#{n}"
        self.appearances[a] += 1
        self.add_as(sim, a, sid)
        self.active[a] = sid
        if not self._staging_checked:
            self._slots = _staging_slots(sim, self.staging_lane)
            self._staging_checked = True
        if self._slots is not None:  # park it on the staging lane until its first logged step
            x, y = self._slots[self._slot % len(self._slots)]
            self._slot += 1
            sim.move_to_xy(sid, float(x), float(y), 0.0, length=float(self.lengths[a]))
        # not in the scene until its first logged step (without a staging lane SUMO has put it at the
        # start of some edge for this one step)
        sim.hidden.add(sid)
        return sid

    def before_step(self, session: SumoSession, t_next: float) -> None:
        """Command every logged agent (and the signals) for the step that ends at ``t_next`` [s]."""
        tr = self.scene.tracks
        for a, t_hand in self.handover.items():
            placed = a in self.active and self.active[a] not in session.hidden  # at a logged pose, not staged
            if a not in self.released and placed and t_next > t_hand + TIME_EPS_S:
                ahead = np.flatnonzero(tr.valid[a])[::-1][::5]  # heading for where the log ends
                session.release_vehicle(self.active[a], [(float(tr.x[a, k]), float(tr.y[a, k]),
                                                          float(tr.heading[a, k]), float(self.lengths[a]))
                                                         for k in ahead[:20]])
                self.released.add(a)
        k = self.step_at(t_next)
        if k is not None:
            valid = self.valid[:, k].copy()
            valid[list(self.released)] = False
            # those in SUMO that the log no longer has (not every agent the log lacks: most never came)
            for a in [a for a in self.active if not valid[a] and a not in self.released]:
                session.remove_vehicle(self.active.pop(a))
            for a in np.flatnonzero(valid).tolist():
                sid = self.active.get(a) or self._add(session, a)  # not staged: added in place
                session.hidden.discard(sid)  # at its logged pose after this step
                session.move_to_xy(sid, float(tr.x[a, k]), float(tr.y[a, k]), float(tr.heading[a, k]),
                                   length=float(self.lengths[a]),
                                   speed=float(np.hypot(tr.vx[a, k], tr.vy[a, k])))
            self.set_signals(session, k)
        nxt = self.step_at(t_next + self.dt)
        if nxt is not None:  # stage the agents that appear at the next log step
            for a in np.flatnonzero(self.valid[:, nxt]).tolist():
                if a not in self.active:
                    self._add(session, a)

    def set_signals(self, session: SumoSession, k: int) -> None:
        """Give SUMO the logged signal states of log step ``k`` (only those that changed).

        All that :meth:`before_step` does for a replayer that drives no agent (every one excluded:
        the environment reads them from the log); such a caller may call this alone."""
        for tid, seq in self.tls_states.items():
            if self._tls_last.get(tid) != seq[k]:
                session.set_tls_state(tid, seq[k])
                self._tls_last[tid] = seq[k]
                self.tls_changes += 1

    @property
    def drives_agents(self) -> bool:
        """Whether :meth:`before_step` has agents to drive or a handover to make (else only signals)."""
        return bool(self.handover) or bool(self.valid.any())


class LogTraffic:
    """The logged agents as states read straight from the log, without putting them into SUMO.

    Where nothing in SUMO reacts to them (every agent driven by moveToXY, as in a replay), SUMO
    would report exactly the logged poses, sizes and speeds that :class:`LogReplayer` gives it
    (``tests/gym_env/test_gym.py`` compares the two); reading them here skips a moveToXY per agent and
    step (about 50 us each on a converted network). An agent is present at the steps where the log
    has it valid, under its log id, with :func:`agent_sizes`' length and width.

    Args:
        scene: the logged scene (its first timestamp is step 0).
        exclude: agent ids left out (the target, agents too far to matter).
    """

    def __init__(self, scene: Scene, exclude: set[str] | frozenset[str] = frozenset()) -> None:
        tr = scene.tracks
        keep = np.array([str(i) not in exclude for i in tr.ids], bool)
        rows = np.flatnonzero(keep)
        lengths, widths = agent_sizes(scene)
        self.agent_lengths, self.agent_widths = lengths, widths  # (every agent of the scene,)
        self.valid = tr.valid[rows]  # (A, T)
        self.x, self.y, self.yaw = tr.x[rows], tr.y[rows], (tr.heading[rows] + np.pi) % (2 * np.pi) - np.pi
        self.speed = np.hypot(tr.vx[rows], tr.vy[rows])
        self.length, self.width = lengths[rows].astype(np.float64), widths[rows].astype(np.float64)
        vt = [vtype_for(int(tr.object_type[a])) for a in rows]
        self.ids = np.array([str(tr.ids[a]) for a in rows], dtype=str)
        self.vclass = np.array([v[1] for v in vt], dtype=str)
        self.type_id = np.array([v[0] for v in vt], dtype=str)

    def states_at(self, k: int) -> VehicleStates:
        """The agents present at log step ``k`` (none outside the log)."""
        if not 0 <= k < self.valid.shape[1]:
            return empty_states()
        a = np.flatnonzero(self.valid[:, k])
        return VehicleStates(ids=self.ids[a], x=self.x[a, k], y=self.y[a, k], yaw=self.yaw[a, k],
                             speed=self.speed[a, k], length=self.length[a], width=self.width[a],
                             vclass=self.vclass[a], type_id=self.type_id[a])


def replay_scene(cfg: str | Path, opts: ReplayOptions | None = None) -> dict:
    """Replay a converted scene (the folder of ``cfg``); returns the summary dict (see README)."""
    opts = opts or ReplayOptions()
    cfg = Path(cfg)
    t0 = time.perf_counter()
    replayer = LogReplayer.for_config(cfg)
    scene = replayer.scene
    tr = scene.tracks
    dt = replayer.dt
    t_first = float(scene.timestamps[0])
    t_last = t_first + (scene.num_steps - 1) * dt
    end = min(opts.end, t_last) if opts.end is not None else t_last
    num_steps = max(0, int(round((end - t_first) / dt)) + 1)
    err_sum, err_max, n_err = 0.0, 0.0, 0
    worst = ("", -1)
    collisions: set[tuple[str, str]] = set()
    t_sim = time.perf_counter()
    with _session(cfg, opts, end=end + TIME_EPS_S) as sim:
        while sim.time < end - TIME_EPS_S:
            replayer.before_step(sim, round(sim.time + dt, 9))
            sim.step()
            k = replayer.step_at(sim.time)
            if k is None:
                continue
            for c in sim.collisions():
                collisions.add((c["collider"], c["victim"]))
            agents = np.array([a for a in np.flatnonzero(tr.valid[:, k]).tolist() if a in replayer.active],
                              np.int64)
            if len(agents):
                states = sim.vehicle_states([replayer.active[int(a)] for a in agents])
                err = np.hypot(states.x - tr.x[agents, k], states.y - tr.y[agents, k])
                err_sum += float(err.sum())
                n_err += len(err)
                j = int(np.argmax(err))
                if err[j] > err_max:
                    err_max = float(err[j])
                    worst = (str(tr.ids[agents[j]]), k)
            if opts.progress is not None:
                opts.progress(k + 1, num_steps)
    sim_s = time.perf_counter() - t_sim
    return {
        "config": str(cfg), "scenario_id": scene.scenario_id, "mode": "replay",
        "backend": "traci" if opts.traci else "libsumo",
        "steps": num_steps, "step_length_s": dt, "end_s": end,
        "log_time_offset_s": scene.meta.get("sumo_time_offset_s"),
        "agents": int(np.sum(np.any(tr.valid[:, :num_steps], axis=1))),
        "valid_states_compared": n_err,
        "centre_error_max_m": err_max, "centre_error_mean_m": err_sum / n_err if n_err else 0.0,
        "worst": {"agent": worst[0], "step": worst[1]},
        "traffic_lights": len(replayer.tls_states), "tls_state_changes": replayer.tls_changes,
        "sumo_collision_pairs": len(collisions),
        "fcd_output": str(opts.fcd_output) if opts.fcd_output else None,
        "wall_s": round(time.perf_counter() - t0, 4), "sim_s": round(sim_s, 4),
        "steps_per_s": round(num_steps / max(sim_s, 1e-9), 1),
    }


def run_config(cfg: str | Path, opts: ReplayOptions | None = None) -> dict:
    """Run a plain SUMO configuration to its end (``opts.end``, else the configuration's ``<end>``,
    where ``sumo -c`` stops too; an exported variant's wreck and parked agents never leave) or
    until no vehicle is left; returns a summary dict."""
    opts = opts or ReplayOptions()
    cfg = Path(cfg)
    t0 = time.perf_counter()
    steps = 0
    seen: set[str] = set()
    end = opts.end if opts.end is not None else read_sumocfg(cfg).end
    with _session(cfg, opts, end=end) as sim:
        while sim.min_expected_number() > 0 and (end is None or sim.time < end - 1e-9):
            sim.step()
            steps += 1
            seen.update(sim.departed_ids())
            if opts.progress is not None:
                opts.progress(steps, 0)
        end_time = sim.time
    wall = time.perf_counter() - t0
    return {"config": str(cfg), "mode": "run", "backend": "traci" if opts.traci else "libsumo",
            "steps": steps, "end_s": end_time, "vehicles": len(seen),
            "fcd_output": str(opts.fcd_output) if opts.fcd_output else None,
            "wall_s": round(wall, 4), "steps_per_s": round(steps / max(wall, 1e-9), 1)}


def replay(cfg: str | Path, opts: ReplayOptions | None = None) -> dict:
    """Replay a converted scene, or just run a plain configuration."""
    cfg = Path(cfg)
    if not cfg.is_file():
        raise not_found(cfg)
    if converted_scene_file(cfg) is not None:
        return replay_scene(cfg, opts)
    return run_config(cfg, opts)
