"""Nominal pass: step a :class:`SumoSession` and record every vehicle and every signal into a Scene.

One recorded step per simulation step (10 Hz by default), taken **after** the step: the first
recorded timestamp is ``begin + step_length``. A focused recording may read the vehicles around its
target at a lower rate and interpolate between (:class:`Focus`, :func:`fill_between_samples`).
Vehicles come and go; ``Tracks.valid`` says when each one was in the network. Agents are ordered by
first appearance (first reading).

The signals of each recorded step: :mod:`coster_sumo.sim.signals`.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from coster_sumo.core.scene import Lanes, RoadMap, Scene, SignalStates, Tracks
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_folder import object_type_of_vclass
from coster_sumo.formats.sumo_net import SumoNet, load_sumo_net
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.sim.session import SumoSession, VehicleStates
from coster_sumo.sim.signals import SignalReader, SignalTable
from coster_sumo.sim.states import empty_states

BeforeStep = Callable[[SumoSession], None]
AfterStep = Callable[[SumoSession, VehicleStates], bool | None]


def net_file_of(session: SumoSession) -> Path:
    """The net file a session runs on (its ``net`` argument, else its config's net-file)."""
    if session.net is not None:
        return session.net
    if session.config is not None:
        nets = read_sumocfg(session.config).net_files
        if nets:
            return nets[0]
    raise InputError(f"{session.name}: cannot tell which net file it runs on; pass net=...")


# [m] what matters around a target: the vehicles recorded and checked, and the map kept (the prior
# looks 40 m around it, the rollout 80 m around the adversary, which starts up to 5 s of driving away)
SURROUNDINGS_RADIUS_M = 200.0


@dataclass(frozen=True)
class Focus:
    """Record one vehicle's surroundings instead of the whole network.

    Attributes:
        target_id: the vehicle that matters; nothing is recorded before it departs.
        radius_m: [m] vehicles this close to it are recorded (SUMO finds them).
        extra_ids: recorded whenever they are in the simulation, wherever they are (the adversary).
        until_arrival: stop stepping ``tail_s`` [s] after the target has arrived.
        more_targets: further vehicles recorded like ``target_id`` (``run --target A --target B``):
            the recording starts when the first of them departs, reads the surroundings of each
            one that runs, and with ``until_arrival`` stops ``tail_s`` after all have arrived.
        max_life_s: stop recording this long [s] after the (first) target departed (None: no
            limit); ``Scene.meta["cut_after_s"]`` then says so. A configuration may end weeks later
            (the wheel's ``rail_demo``: 1,200,000 s) with a target that never arrives.
        surroundings_hz: read the surroundings at this rate only [1/s] (None: every step). The
            target and ``extra_ids`` are read every step; the other vehicles at the recording's
            steps 0, k, 2k, ... (k = round(1 / (rate x step length))) and linearly interpolated in
            between where they were there at both ends (see :func:`fill_between_samples`).
    """

    target_id: str
    radius_m: float = 150.0
    extra_ids: tuple[str, ...] = ()
    until_arrival: bool = True
    tail_s: float = 0.0
    surroundings_hz: float | None = None
    more_targets: tuple[str, ...] = ()
    max_life_s: float | None = None

    @property
    def targets(self) -> tuple[str, ...]:
        """``target_id`` and ``more_targets``, without repeats."""
        return tuple(dict.fromkeys((self.target_id, *self.more_targets)))


def fill_between_samples(tracks: Tracks, times: np.ndarray, sampled: np.ndarray) -> None:
    """Fill, in place, the steps between consecutive sampled steps of the agents that were read
    only at sampled steps (``valid`` at both ends and at none in between): positions and velocities
    linearly in time, heading along the shorter arc, size from the earlier sample.

    An agent that departs or arrives between two samples appears late or leaves early (by less than
    the sampling interval); agents read every step are left as they are.
    """
    p = np.flatnonzero(sampled)
    valid = tracks.valid
    for a, b in zip(p[:-1], p[1:], strict=True):
        if b - a < 2:
            continue
        rows = np.flatnonzero(valid[:, a] & valid[:, b] & ~valid[:, a + 1:b].any(axis=1))
        if not len(rows):
            continue
        w = ((times[a + 1:b] - times[a]) / (times[b] - times[a]))[None, :]
        block = (rows[:, None], np.arange(a + 1, b)[None, :])
        for arr in (tracks.x, tracks.y, tracks.vx, tracks.vy):
            arr[block] = arr[rows, a, None] + (arr[rows, b, None] - arr[rows, a, None]) * w
        turn = np.angle(np.exp(1j * (tracks.heading[rows, b] - tracks.heading[rows, a])))
        tracks.heading[block] = np.angle(np.exp(1j * (tracks.heading[rows, a, None] + turn[:, None] * w)))
        tracks.length[block] = tracks.length[rows, a, None]
        tracks.width[block] = tracks.width[rows, a, None]
        valid[block] = True


class _FocusedReader:
    """What a focused recording (:class:`Focus`) reads after each step: the surroundings of the
    targets while any runs. Its fields are the state of the pass: who runs and who arrived, when
    the recording started and when it stops, and who ran before it started (for an error)."""

    def __init__(self, session: SumoSession, focus: Focus) -> None:
        self.focus = focus
        self.every = (max(1, int(round(1.0 / (focus.surroundings_hz * session.step_length))))
                      if focus.surroundings_hz else 1)
        self.eps = 1e-6 * session.step_length
        self.running = [v for v in focus.targets if v in set(session.vehicle_ids())]  # the focused ones now running
        self.arrived: set[str] = set()
        self.started = bool(self.running)  # the recording begins when its (first) vehicle departs
        self.end_at: float | None = None  # [s] when it stops (after the targets arrived)
        # [s] when it stops at the latest: max_life_s after the first departure (or now, if one runs already)
        self.cut_at = session.time + focus.max_life_s if self.started and focus.max_life_s else None
        self.cut = False
        self.ran_from: dict[str, float] = {}  # until a focused vehicle departs: who ran, from when to when [s]
        self.ran_until: dict[str, float] = {}

    def read(self, session: SumoSession, t: float, recorded: int) -> tuple[VehicleStates, bool] | None:
        """The states of this step (the one just taken, at ``t`` [s]) and whether they are the
        surroundings' (a sampled step; else the targets' only); None: the recording ends before it.
        ``recorded``: the steps recorded so far."""
        focus = self.focus
        arrived_now = session.arrived_ids()
        if not self.started:
            self.ran_from.update((v, t) for v in session.departed_ids() if v not in self.ran_from)
            self.ran_until.update((v, t) for v in arrived_now)
        gone = [v for v in self.running if v in arrived_now]
        if gone:
            self.arrived.update(gone)
            self.running = [v for v in self.running if v not in self.arrived]
            if focus.until_arrival and self.end_at is None and self.arrived.issuperset(focus.targets):
                self.end_at = t + focus.tail_s
        if self.end_at is not None and t > self.end_at + self.eps:
            return None
        if self.cut_at is not None and t > self.cut_at + self.eps:
            self.cut = True
            return None
        departed = session.departed_ids()
        self.running += [v for v in focus.targets if v in departed and v not in self.running]
        if self.running and not self.started and focus.max_life_s is not None:
            self.cut_at = t + focus.max_life_s
        self.started = self.started or bool(self.running)
        full = self.every == 1 or recorded % self.every == 0
        if not self.running:  # no target is (or any longer) in the network: nothing around them to read
            return empty_states(), full
        if full:
            once = self.every > 1
            near = session.vehicles_near(self.running[0], focus.radius_m, once=once)
            seen = set(near)
            for other in self.running[1:]:  # several targets: the union of their surroundings
                # mostly the same vehicles again: their ids only (the rest are read once, with getters)
                more = [v for v in session.vehicles_near(other, focus.radius_m, once=once, values=False)
                        if v not in seen]
                near += more
                seen.update(more)
        else:
            near = [v for v in self.running if v not in session.hidden]
        if focus.extra_ids:
            in_sim, present = set(session.vehicle_ids()), set(near)
            near += [v for v in focus.extra_ids if v not in present and v in in_sim and v not in session.hidden]
        return session.vehicle_states(near), full


@contextlib.contextmanager
def _small_pages() -> Iterator[None]:
    """numpy arrays allocated inside get the kernel's 4 KB pages, not huge pages.

    numpy advises huge pages (2 MB) for large arrays, so the first write anywhere in such a page
    commits and zeroes all 2 MB of it. A pass's tracks are mostly empty: every vehicle that came
    near the target has a row over all steps but is there for a short span of them (A10KW: 3,614
    vehicles x 14,000 steps, 5 % valid). With huge pages the rows' scattered writes commit the whole
    2.9 GB and took 6.2-6.7 s; with 4 KB pages they commit 0.27 GB and take 0.85-0.88 s
    (docs/performance.md). Reading a page never written costs nothing either way.
    """
    switch = hugepage_switch()
    if switch is None:  # a numpy without the switch: huge pages are its own business
        yield
        return
    previous = switch(False)
    try:
        yield
    finally:
        switch(previous)


def hugepage_switch() -> Callable[[bool], bool] | None:
    """numpy's switch for huge-page advice on large arrays (it returns the setting it replaces;
    ``numpy._core`` since numpy 2, ``numpy.core`` before), or None where numpy has none."""
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        switch = getattr(module, "_set_madvise_hugepage", None)
        if switch is not None:
            return cast(Callable[[bool], bool], switch)
    return None


class _Rows:
    """The recorded steps as they come (agents numbered by first appearance), and their tracks."""

    def __init__(self) -> None:
        self.agent: dict[str, int] = {}
        self.kinds: list[int] = []
        self.vclasses: dict[str, str] = {}
        self.times: list[float] = []
        self.rows: list[tuple[np.ndarray, VehicleStates]] = []
        self.signal_rows: list[np.ndarray] = []
        self.sampled: list[bool] = []  # per recorded step: were the surroundings read (not just the target)

    def add(self, t: float, st: VehicleStates, full: bool, signals: np.ndarray | None) -> None:
        agent = self.agent
        names = st.id_list()
        for i in [i for i, vid in enumerate(names) if vid not in agent]:  # first appearances
            if names[i] not in agent:
                agent[names[i]] = len(agent)
                self.kinds.append(int(object_type_of_vclass(str(st.vclass[i]))))
                self.vclasses[names[i]] = str(st.vclass[i])
        idx = np.fromiter(map(agent.__getitem__, names), np.int64, len(names))
        self.times.append(t)
        self.sampled.append(full)
        self.rows.append((idx, st))
        if signals is not None:
            self.signal_rows.append(signals)

    def signals(self, table: SignalTable) -> SignalStates:
        """The signal states of the recorded steps."""
        state = np.stack(self.signal_rows) if self.signal_rows else np.zeros((0, len(table.lane_index)), np.int8)
        return SignalStates(lane_index=table.lane_index, state=state, stop_point=table.stop_point)

    def tracks(self) -> Tracks:
        """(agents, steps) tracks of the recorded steps, filled between samples."""
        rows = self.rows
        num_agents, num_steps = len(self.agent), len(self.times)
        with _small_pages():
            arrays = {f: np.zeros((num_agents, num_steps), np.float64)
                      for f in ("x", "y", "heading", "vx", "vy", "length", "width")}
            valid = np.zeros((num_agents, num_steps), bool)
        if rows:  # one scatter per field over all steps (a city pass has ~10^4 steps)
            a_all = np.concatenate([idx for idx, _ in rows])
            s_all = np.repeat(np.arange(len(rows)), [len(idx) for idx, _ in rows])
            for field in ("x", "y", "length", "width"):
                arrays[field][a_all, s_all] = np.concatenate([getattr(st, field) for _, st in rows])
            yaw = np.concatenate([st.yaw for _, st in rows])
            speed = np.concatenate([st.speed for _, st in rows])
            arrays["heading"][a_all, s_all] = yaw
            arrays["vx"][a_all, s_all] = speed * np.cos(yaw)  # as VehicleStates.vx / vy
            arrays["vy"][a_all, s_all] = speed * np.sin(yaw)
            valid[a_all, s_all] = True
        ids = np.array(list(self.agent), dtype=str) if self.agent else np.zeros(0, dtype=str)
        tracks = Tracks(ids=ids, object_type=np.array(self.kinds, np.int8), valid=valid, **arrays)
        if not all(self.sampled):
            fill_between_samples(tracks, np.array(self.times, np.float64), np.array(self.sampled))
        return tracks


def record(session: SumoSession, *, end: float | None = None, begin: float | None = None,
           before_step: BeforeStep | None = None, after_step: AfterStep | None = None,
           focus: Focus | None = None, bar: Any = None, road: bool = True) -> Scene:
    """Step a running session and record it into a :class:`Scene` (``source="sumo"``).

    Stepping stops at the first of: the time reaches ``end`` [s] (default: the session's own
    ``end``); ``after_step`` returns True; no vehicle is running or waiting any more (only when no
    ``end`` bounds the run).
    Only steps whose time lies in [``begin``, ``end``] are recorded; earlier steps are simulated.

    Args:
        session: a started session; it is left running (the caller closes it). Its net is read
            with :func:`load_sumo_net` (cached); every incoming lane gets a signal state (see the
            module docstring).
        before_step: called before every simulation step, e.g. to ``move_to_xy`` an adversary.
        after_step: called after every step with the vehicle states just read; return True to stop.
        focus: record only the surroundings of one vehicle while it runs (see :class:`Focus`); the
            recording starts with the step it departs in (the steps before are simulated, not
            recorded) and has no step if it never departs. Then ``Scene.meta["ran_s"]`` gives every
            vehicle that ran in the pass, by id, with its time in the network [s], and
            ``meta["pass_window_s"]`` the first and last simulated time: what an error naming other
            targets needs, without a second pass.
        The scene's id is ``<config or net stem>_seed<seed>`` (``dataclasses.replace`` gives
        another, and more metadata).
        bar: a progress bar (tqdm-like) moved along the simulation time to ``end``.
        road: False records the vehicles only (no net read: it costs more than a short pass; an
            empty road map, no signals, no ``location_offset``), for readers of the tracks alone.
    """
    if not session.is_running:
        raise InputError(f"{session.name}: start the session before recording it")
    end = session.end if end is None else end
    if end is None and session.min_expected_number() == 0 and before_step is None:
        raise InputError(f"{session.name}: nothing to record (no vehicles expected); pass end=")
    net_path = net_file_of(session)
    net = load_sumo_net(net_path) if road else None
    table = SignalTable.build(net) if net is not None else None
    eps = 1e-6 * session.step_length
    rec = _Rows()
    reader = _FocusedReader(session, focus) if focus is not None else None
    signals = SignalReader(session, table) if table is not None else None
    steps, shown = 0, 0.0  # steps taken; [s] of simulation time the bar shows
    first_t: float | None = None
    t = session.time
    while True:
        if ((end is not None and session.time >= end - eps)
                or (end is None and steps > 0 and session.min_expected_number() == 0)):
            break
        if before_step is not None:
            before_step(session)
        t = session.step()
        first_t = t if first_t is None else first_t
        steps += 1
        if bar is not None and end is not None and t - first_t >= shown + 1.0:  # once per simulated second
            bar.total, done = round(max(end - first_t, 1.0), 1), round(t - first_t, 1)
            bar.update(done - shown)
            shown = done
        if reader is None:
            st, full = session.vehicle_states(), True
        else:
            read = reader.read(session, t, len(rec.times))
            if read is None:
                break
            st, full = read
        stop = bool(after_step(session, st)) if after_step is not None else False
        # a focused recording starts when its (first) vehicle departs
        if (reader is None or reader.started) and (begin is None or t >= begin - eps):
            rec.add(t, st, full, signals.read() if signals is not None else None)
        if stop:
            break

    info = _pass_meta(session, net, net_path, rec, reader, first_t, t)
    source_file = session.config or session.net or net_path
    sid = f"{Path(str(source_file)).name.split('.')[0]}_seed{session.seed}"
    sdc = rec.agent.get("ego", -1)
    road_map, signal_states = ((net.road_map, rec.signals(table)) if net is not None and table is not None
                               else (RoadMap(lanes=Lanes.empty()), SignalStates.empty(len(rec.times))))
    return Scene(scenario_id=sid, timestamps=np.array(rec.times, np.float64), tracks=rec.tracks(),
                 road_map=road_map, signals=signal_states, sdc_index=sdc, current_time_index=0,
                 source="sumo", meta=info).validate()


def _pass_meta(session: SumoSession, net: SumoNet | None, net_path: Path, rec: _Rows, reader: _FocusedReader | None,
               first_t: float | None, t: float) -> dict[str, Any]:
    """``Scene.meta`` of a recorded pass (the keys :func:`record` documents); ``first_t`` and ``t``:
    the first and last simulated time [s]."""
    times = rec.times
    info: dict[str, Any] = {
        "sumocfg": str(session.config) if session.config is not None else None,
        "net": str(net_path), "seed": session.seed, "backend": session.backend,
        "step_length": session.step_length,
        "begin": times[0] if times else None, "end": times[-1] if times else None,
        "vehicle_classes": rec.vclasses,  # id -> SUMO vClass when first seen (object_type keeps less)
    }
    if net is not None:
        info["location_offset"] = [float(v) for v in net.location_offset]
    if reader is not None and reader.cut:
        info["cut_after_s"] = reader.focus.max_life_s
    if reader is not None and not reader.started:
        info["ran_s"] = {v: round(reader.ran_until.get(v, t) - t0, 3) for v, t0 in reader.ran_from.items()}
        info["pass_window_s"] = [first_t, t] if first_t is not None else None
    return info


def record_config(config: str | Path, *, begin: float | None = None, end: float | None = None,
                  before_step: BeforeStep | None = None, after_step: AfterStep | None = None,
                  focus: Focus | None = None, **session_kwargs: Any) -> Scene:
    """Open a session on ``config``, record [begin, end], close it. See :func:`record`.

    ``begin`` and ``end`` [s] are SUMO's (absolute simulation times; None: the configuration's); the
    other keywords are the :class:`SumoSession`'s (``seed``, ``traci``, ``additional``...).
    """
    with SumoSession(config, begin=begin, end=end, **session_kwargs) as session:
        return record(session, begin=begin, end=end, before_step=before_step, after_step=after_step, focus=focus)
