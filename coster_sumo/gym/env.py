"""``coster_sumo/Scenario-v0``: drive the target of a scenario set's scenarios in SUMO.

Each :meth:`ScenarioEnv.reset` draws one scenario of the set (with the episode's seed), starts
SUMO (libsumo, in this process) at the scenario's start and replays every vehicle but the target
from the recorded pass, the adversary of a generated variant among them; the agent drives the
target. As nothing in SUMO reacts to replayed vehicles, their states are read from the recorded
pass (:class:`coster_sumo.sim.replay.LogTraffic`) while SUMO holds the target and runs the
signals; ``traffic="sumo"`` puts every vehicle into SUMO instead
(:class:`coster_sumo.sim.replay.LogReplayer`: moveToXY every step), with the same episodes.
docs/gym.md explains the choice of replay over SUMO-driven traffic, with the measurements.

Observation (``Box(-1, 1, (90,))``, float32; every entry scaled by a stated constant and clipped):

====== ============================================================================================
index  meaning (unit / scale)
====== ============================================================================================
0      speed [m/s] / 30
1      last commanded acceleration [m/s^2] / 8
2      lateral offset from the route [m] / 3.5 (> 0: left)
3      heading relative to the route [rad] / pi
4      route progress, fraction of the route
5      route left [m] / 100
6      allowed speed on the lane under the target [m/s] / 30 (0 off the lanes)
7      the target's length [m] / 10
8-15   route points 5, 10, 20 and 40 m ahead: (x, y) in the target's frame [m] / 50
16     distance to the next traffic light on the target's lane [m] / 100 (1: none within 100 m)
17     that light is red or yellow (1) or not / none (0)
18-89  the K = 8 nearest vehicles within 50 m, nearest first, 9 numbers each: present (0/1),
       x, y in the target's frame [m] / 50, relative velocity x, y in the target's frame
       [m/s] / 30, cos and sin of the relative heading, length [m] / 10, width [m] / 5
====== ============================================================================================

The adversary is one of the vehicles, not marked. The target's frame: origin at its box centre,
+x along its heading, +y to its left.

Action (``Box(-1, 1, (2,))``): ``a[0]`` the longitudinal acceleration (-1 -> -8 m/s^2, +1 -> +3
m/s^2, 0 -> keep speed); ``a[1]`` the lateral offset from the route the target steers to
(-1 -> 3.5 m right, +1 -> 3.5 m left, 0 -> on the route), reached at most at 2 m/s sideways (and at
most 0.3 of the speed, so a stopped car does not slide). The route is the target's own recorded
path, so ``(0, 0)`` drives it along its nominal path at constant speed.

Reward, per step: 0.1 per metre of route progress; -10 and the end at a collision (our box check,
with any vehicle); -5 and the end when the target leaves the drivable area; +5 and the end at the
end of the route (completion; a route shorter than 5 m, a target that waited, is not completed
early). The episode is truncated at the end of the scenario's replay.

``info``: ``scenario``, ``network``, ``kind`` (nominal / variant), ``time`` [s], ``outcome``
(``running``, ``collision``, ``off_road``, ``completed``, ``timeout``), ``collided_with`` (a vehicle
id or None), ``collided_with_adversary``, ``off_road``, ``completed``, ``route_completion``
(fraction), ``avoidable`` (None where unknown).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from coster_sumo.core.scene import Scene
from coster_sumo.errors import InputError
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.gym.scenario_set import ScenarioEntry, ScenarioSet
from coster_sumo.gym.stepping import box_off_road, first_contact, sumo_box
from coster_sumo.sim.control import Departure
from coster_sumo.sim.driver import NEIGHBOUR_RADIUS_M, STEP_S, Arrays6, Driver, Route
from coster_sumo.sim.states import concat_states

ROUTE_SLACK_S = 3.0
# [m] agents that never come this close to the target's route (its run-on included) are not replayed:
# the observation sees 50 m, the target strays at most MAX_OFFSET_M from the route, and a converted
# WOMD scene logs many agents far away (moveToXY costs ~50 us each on its network)
REPLAY_RADIUS_M = NEIGHBOUR_RADIUS_M + 30.0  # [s] the route ends where the target was this long before the replay ends

# scenarios (and networks' drivable areas) an environment keeps in memory: each loaded from disk once.
# 100 converted corpus clips with their drivable areas took 27 MB, so issue 61's largest set (10,119)
# about 3 GB; with 512 kept, a reset beyond them took 70 ms of CPU instead of 36 ms
CACHED_SCENARIOS = 16_384

TRAFFIC_MODES = ("log", "sumo", "reactive")
RANDOM_START_TAIL_S = 8.0  # [s] a random start leaves at least this much of the scenario (a route of 5 s)
REWARD_PER_M = 0.1
COLLISION_PENALTY = -10.0
OFF_ROAD_PENALTY = -5.0
COMPLETION_BONUS = 5.0


class ScenarioEnv(gymnasium.Env, Driver):
    """Drive the target of scenarios from a scenario set (module docstring: spaces, reward, info).

    Args:
        scenarios: the scenario set folder (``coster-sumo scenarios build``).
        split: ``train``, ``test`` or None (all).
        kind: ``nominal``, ``variant`` or None (all).
        networks: only these networks (None: all).
        scenario_ids: only these scenarios (overrides the filters above).
        control_period_s: [s] simulated time per :meth:`step` (a multiple of 0.1 s; collisions and
            off-road are checked every 0.1 s in between).
        order: ``random`` (a scenario drawn per reset with the episode's seed) or ``cycle`` (every
            scenario in turn, for evaluation; ``reset(seed=s)`` restarts the cycle at scenario
            ``s mod n``). ``reset(options={"scenario": ID})`` starts that scenario.
        traffic: ``log`` (default: the other vehicles' states read from the recorded pass; SUMO
            holds the target and runs the signals) or ``sumo`` (every vehicle put into SUMO and
            moved there by moveToXY each step). Both give the same episodes (``tests/gym_env/test_gym.py``);
            ``log`` costs no moveToXY per vehicle. ``reactive``: each agent follows its log until
            the target's deviation from its nominal motion reaches it, then SUMO drives it
            (:mod:`coster_sumo.sim.reactive`; the adversary never reacts).
        car_following: the reacting agents' car-following model, ``Krauss`` (SUMO's default) or ``IDM``.
        random_start: a nominal scenario's episode starts at a time drawn (with the episode's seed)
            uniformly between its start and :data:`RANDOM_START_TAIL_S` before its end, instead of at its
            start (variants always start at theirs: the adversary's timing is the scenario).
        observation: ``default`` (the 90 numbers above), ``avoidance`` (those and the vehicles ahead
            and behind in the route corridor: gap, closing speed, time to collision; time left) or
            ``lidar`` (the target's 18, the corridor's 9, 72 rays to 50 m): :mod:`coster_sumo.gym.observe`.
    """

    metadata: dict[str, Any] = {"render_modes": []}
    sumo_drives = False  # SUMO's driver model drives the target (:mod:`coster_sumo.gym.sumo_driver`)

    def __init__(self, scenarios: str | Path, split: str | None = None, kind: str | None = None,
                 networks: tuple[str, ...] | list[str] | None = None,
                 scenario_ids: tuple[str, ...] | list[str] | None = None, control_period_s: float = 0.2,
                 order: str = "random", traffic: str = "log", car_following: str = "Krauss",
                 random_start: bool = False, observation: str = "default") -> None:
        super().__init__()
        self.set = ScenarioSet.load(scenarios)
        if scenario_ids is not None:
            wanted = set(scenario_ids)
            self.entries = [e for e in self.set.entries if e.id in wanted]
        else:
            self.entries = self.set.select(split, kind, tuple(networks) if networks is not None else None)
        if not self.entries:
            raise InputError(f"{scenarios}: no scenario with split={split!r}, kind={kind!r}, networks={networks!r}")
        if order not in ("random", "cycle"):
            raise InputError(f"order must be 'random' or 'cycle', not {order!r}")
        if traffic not in TRAFFIC_MODES:
            raise InputError(f"traffic must be one of {TRAFFIC_MODES}, not {traffic!r}")
        from coster_sumo.sim.reactive import car_following_types

        self.traffic = traffic
        self.car_following = car_following
        self.random_start = random_start
        self._types_file, _ = car_following_types(car_following)  # checks the name in every mode
        self._reactive: Any = None  # ReactiveTraffic of the episode when traffic == "reactive"
        self.order = order
        self.substeps = max(1, int(round(control_period_s / STEP_S)))
        from coster_sumo.gym.observe import OBSERVATIONS

        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {tuple(OBSERVATIONS)}, not {observation!r}")
        self.observation = observation
        self.observation_space = spaces.Box(-1.0, 1.0, (OBSERVATIONS[observation],), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._session: Any = None
        self._traffic: Any = None  # LogTraffic when traffic == "log"
        self._session_net: Path | None = None  # the network the session has loaded
        self._sumo_target: str | None = None  # the target's id in SUMO once added
        self._t_shift = 0.0  # [s] SUMO's clock minus the scenario's
        # per scenario (CACHED_SCENARIOS at most): its scene
        self._scenes: dict[str, Scene] = {}
        # per scenario and start step: the agents too far to replay, the replayed part, LogTraffic (not kept
        # with random starts: a scenario has many)
        self._replays: dict[tuple[str, int], tuple[set[str], Scene, Any, Any]] = {}
        self._drivable: dict[Path, DrivableArea] = {}  # per network (a clip's variants share its network)
        self._next_index = 0
        self.entry: ScenarioEntry | None = None
        self._states: Any = None  # :attr:`states`, built when first read in log mode
        self._states_k: int | None = None  # the log step they are of
        self._signals_only = False
        self._others_now: Arrays6 | None = None  # log mode: _others() of the last step
        self._log_rows = np.zeros(0, np.int64)  # their rows in the log
        self._half_diagonal = np.zeros(0)  # log mode: 0.5 * hypot(length, width) per row of the log
        self.episodes = 0
        self.sim_steps = 0

    # ------------------------------------------------------------------------- episode

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if options and "scenario" in options:
            entry = next(e for e in self.entries if e.id == options["scenario"])
        elif self.order == "cycle":
            if seed is not None:  # a seeded reset restarts the cycle (at the seed's place in it)
                self._next_index = int(seed) % len(self.entries)
            entry = self.entries[self._next_index % len(self.entries)]
            self._next_index += 1
        else:
            entry = self.entries[int(self.np_random.integers(len(self.entries)))]
        self._start(entry)
        self.episodes += 1
        return self._observation(), self._info()

    def _start(self, entry: ScenarioEntry) -> None:
        from coster_sumo.sim.session import SumoSession

        self.entry = entry
        self.target_id = entry.target
        self.scene = scene = self._scene_of(entry)
        tr = scene.tracks
        ti = tr.index_of(entry.target)
        ts = scene.timestamps
        valid = tr.valid[ti]
        k0 = self._first_step(entry, ts, valid)
        self.length = float(np.median(tr.length[ti][valid]))
        self.width = float(np.median(tr.width[ti][valid]))
        # a variant's route goes on past the planned contact along the target's nominal path as far as its
        # episode allows (sets built before this ran 3 s past t_col: their routes end at the contact point)
        route_until = max(entry.t_end - ROUTE_SLACK_S, float(ts[k0]))
        keep = valid & (ts >= ts[k0] - 1e-6) & (ts <= route_until + 1e-6)
        self.route = Route(np.stack([tr.x[ti, keep], tr.y[ti, keep]], -1), float(tr.heading[ti, k0]))
        self.s = 0.0
        self.d = 0.0
        self.d_dot = 0.0
        self.v = float(np.hypot(tr.vx[ti, k0], tr.vy[ti, k0]))
        self.accel = 0.0
        self.t_end = float(ts[-1])
        self.outcome = "running"
        self.collided_with: str | None = None
        self.off_road = False
        begin = round((round(float(ts[k0]) / STEP_S) - 1) * STEP_S, 6)  # on SUMO's grid (WOMD times jitter)
        net = self.set.net_file(entry)
        sess = self._session
        # SUMO loads a network once for the episodes on it when nothing in it depends on SUMO's clock:
        # the log drives every signal (a converted scene) and SUMO holds the target only
        if (sess is not None and self.traffic in ("log", "reactive") and self._session_net == net
                and set(sess.tls_ids()) <= set(entry.tls)):
            if self._reactive is not None:
                self._reactive.remove_all(sess)
            if self._sumo_target is not None:
                sess.remove_vehicle(self._sumo_target)
                sess.step()  # gone before the next target comes (it may have the same id)
            self._t_shift = round(sess.time - begin, 6)
        else:
            if sess is not None:
                sess.close()
            extra = [self._types_file] if self._types_file is not None else []
            self._session = SumoSession(net=net, begin=begin, end=None, step_length=STEP_S, seed=0,
                                        additional=[self.set.vtypes_file, *extra]).start()
            self._session_net = net
            self._t_shift = 0.0
        self._sumo_target = None
        self.api = self._session.api
        far, replayed, log, replayer = self._replay_of(entry, scene, k0)
        self._replayer = replayer.restarted()  # the cached one is never stepped
        self._traffic = log if self.traffic == "log" else None
        if self._traffic is not None:
            self._half_diagonal = 0.5 * np.hypot(self._traffic.length, self._traffic.width)
        self._others_now = None
        self._reactive = None
        if self.traffic == "reactive":  # read from the log until the target's deviation reaches them
            from coster_sumo.sim.reactive import ReactiveTraffic

            self._reactive = ReactiveTraffic(replayed, entry.target, exclude=far, adversary=entry.adversary,
                                             route=self.route.points, car_following=self.car_following, log=log,
                                             scripted=entry.extra.get("scripted", ()))
        drivable = self._drivable.get(net)
        if drivable is None:
            drivable = DrivableArea.from_road_map(scene.road_map)
            if len(self._drivable) < CACHED_SCENARIOS:
                self._drivable[net] = drivable
        self._drivable_now = drivable
        self._signals_only = self.traffic != "sumo" and not self._replayer.drives_agents
        self._added = False
        self._advance()  # the first step shows the scenario's first state

    def _replay_of(self, entry: ScenarioEntry, scene: Scene, k0: int) -> tuple[set[str], Scene, Any, Any]:
        """The episode's agents too far to replay, the replayed scene from step ``k0``, its LogTraffic
        (None in mode sumo) and a LogReplayer never stepped (kept per scenario and start step)."""
        from coster_sumo.sim.replay import LogReplayer, LogTraffic, far_agents

        cached = self._replays.get((entry.id, k0))
        if cached is None:
            far = far_agents(scene.tracks, self.route.points[::4], REPLAY_RADIUS_M, from_step=k0)
            replayed = _from_step(scene, k0)
            log = LogTraffic(replayed, exclude={entry.target, *far}) if self.traffic != "sumo" else None
            # SUMO holds every agent in mode sumo; else the target alone (and the signals), the agents read
            # from the log
            every = set(scene.tracks.ids.tolist())
            replayer = LogReplayer(replayed, entry.tls, entry.staging_lane,
                                   exclude={entry.target, *far} if self.traffic == "sumo" else every)
            cached = (far, replayed, log, replayer)
            if len(self._replays) < CACHED_SCENARIOS and not self.random_start:
                self._replays[(entry.id, k0)] = cached
        return cached

    def _scene_of(self, entry: ScenarioEntry) -> Scene:
        """The replay scene of ``entry`` (kept for CACHED_SCENARIOS scenarios)."""
        scene = self._scenes.get(entry.id)
        if scene is None:
            scene = self.set.scene(entry)
            if len(self._scenes) < CACHED_SCENARIOS:
                self._scenes[entry.id] = scene
        return scene

    def _first_step(self, entry: ScenarioEntry, ts: np.ndarray, valid: np.ndarray) -> int:
        """The scene's step the episode starts at: the scenario's start, or with ``random_start`` a
        nominal scenario's drawn time; the target's first valid step if it is not there then."""
        t_first = entry.t_start
        if self.random_start and entry.kind == "nominal" and entry.t_end - RANDOM_START_TAIL_S > entry.t_start:
            t_first = float(self.np_random.uniform(entry.t_start, entry.t_end - RANDOM_START_TAIL_S))
        k0 = int(np.argmin(np.abs(ts - t_first)))
        return k0 if valid[k0] else int(np.flatnonzero(valid)[0])

    def _advance(self) -> None:
        """One SUMO step: replay the others, place the target, step, check events."""
        sess = self._session
        t_next = round(self._now() + STEP_S, 9)
        if self._signals_only:  # log mode: the replayer drives no agent, only the logged signals
            k_next = self._replayer.step_at(t_next)
            if k_next is not None:
                self._replayer.set_signals(sess, k_next)
        else:
            self._replayer.before_step(sess, t_next)
        if self._reactive is not None:
            k_next = self._replayer.step_at(t_next)
            if k_next is not None:
                self._reactive.before_step(sess, k_next)
        x, y, yaw = self._ego_pose()
        target = self.entry.target if self.entry is not None else "ego"
        if not self._added:
            self._add_target(target, x, y, yaw)
        if not self.sumo_drives:
            sess.move_to_xy(target, x, y, yaw, self.length, speed=self.v)
        sess.step()
        self.sim_steps += 1
        k = self._replayer.step_at(self._now())
        if self._traffic is not None:  # the states of every vehicle only when someone reads them
            self._states, self._states_k, self._others_now = None, k, None
            self._check_log_step(target, k)
            return
        st = sess.vehicle_states()
        if k is not None and self._reactive is not None:
            st = concat_states(st, self._reactive.states_at(k))
        self.states = st
        # the target's events only (the pass detector's checks of the adversary's other contacts and
        # its batching cost more than the rest of a step here): the same box test, the same area
        i = _row(st.id_list(), target)
        if i < 0:
            return
        box = (st.x.item(i), st.y.item(i), st.yaw.item(i), st.length.item(i), st.width.item(i))
        if self.collided_with is None:
            others = np.arange(len(st)) != i
            j = first_contact(box, st.x[others], st.y[others], st.yaw[others], st.length[others], st.width[others])
            if j >= 0:
                self.collided_with = str(st.ids[others][j])
        if not self.off_road:
            self.off_road = box_off_road(self._drivable_now, box)
        if self._reactive is not None and k is not None:
            from coster_sumo.sim.reactive import Pose

            self._reactive.after_step(k, st, Pose(box[0], box[1], box[2], self.v, self.length, self.width))

    def _check_log_step(self, target: str, k: int | None) -> None:
        """The target's contacts and off-road after a step of log mode: its box as SUMO has it, the
        others' boxes from the log at step ``k`` (in the order :attr:`states` lists them)."""
        box = sumo_box(self._session.api, target)
        if box is None:
            return
        if self.collided_with is None:
            x, y, yaw, _, length, width = self._others()
            j = first_contact(box, x, y, yaw, length, width, self._half_diagonal[self._log_rows])
            if j >= 0:
                self.collided_with = str(self._traffic.ids[self._log_rows[j]])
        if not self.off_road:
            self.off_road = box_off_road(self._drivable_now, box)

    def _others(self) -> Arrays6:
        """Log mode: the vehicles but the target are the log's at the last step (in :attr:`states`'
        order: SUMO holds the target alone), read without building :attr:`states`."""
        log, k = self._traffic, self._states_k
        if log is None:
            return super()._others()
        if self._others_now is None:
            if k is None or not 0 <= k < log.valid.shape[1]:
                self._log_rows = rows = np.zeros(0, np.int64)
            else:
                self._log_rows = rows = np.flatnonzero(log.valid[:, k])
            self._others_now = (log.x[rows, k], log.y[rows, k], log.yaw[rows, k], log.speed[rows, k],
                                log.length[rows], log.width[rows])
        return self._others_now

    @property
    def states(self) -> Any:  # type: ignore[override]
        """The vehicles after the last step (VehicleStates: SUMO's, then the log's); in log mode
        built when first read (before the next step: SUMO's state does not change in between)."""
        if self._states is None and self._session is not None:
            st = self._session.vehicle_states()
            k = self._states_k
            if k is not None and self._traffic is not None:
                st = concat_states(st, self._traffic.states_at(k))
            self._states = st
        return self._states

    @states.setter
    def states(self, value: Any) -> None:
        self._states = value

    def _add_target(self, target: str, x: float, y: float, yaw: float) -> None:
        """Put the target into SUMO, on the edge under its front bumper where there is one."""
        sess = self._session
        edges = None
        try:
            fx = x + 0.5 * self.length * math.cos(yaw)
            fy = y + 0.5 * self.length * math.sin(yaw)
            edge, _, _ = sess.api.simulation.convertRoad(fx, fy, False, "passenger")
            edges = [str(edge)] if edge and not str(edge).startswith(":") else None
        except Exception:  # no lane nearby: SUMO picks an edge, moveToXY places it anyway
            edges = None
        sess.add_vehicle(target, self.length, self.width, "passenger", departure=Departure(edges),
                         color=(40, 120, 255, 255))
        self._added = True
        self._sumo_target = target

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._session is None or self.entry is None:
            raise RuntimeError("call reset() before step()")
        d_target = self._command(action)
        s_before = self.s
        terminated = truncated = False
        for _ in range(self.substeps):
            self._kinematic_step(d_target)
            self._advance()
            if self.collided_with is not None:
                self.outcome, terminated = "collision", True
            elif self.off_road:
                self.outcome, terminated = "off_road", True
            elif self.route_completed():
                self.outcome, terminated = "completed", True
            elif self._now() >= self.t_end - 0.5 * STEP_S:  # the last logged step (WOMD times jitter)
                self.outcome, truncated = "timeout", True
            if terminated or truncated:
                break
        progress = min(self.s, self.route.length_m) - min(s_before, self.route.length_m)
        reward = REWARD_PER_M * progress
        if self.outcome == "collision":
            reward += COLLISION_PENALTY
        elif self.outcome == "off_road":
            reward += OFF_ROAD_PENALTY
        elif self.outcome == "completed":
            reward += COMPLETION_BONUS
        return self._observation(), float(reward), terminated, truncated, self._info()

    def _observation(self) -> np.ndarray:
        if self.observation == "default":
            return self._observe()
        from coster_sumo.gym.observe import observe

        return observe(self, self.observation, self.t_end - self._now())

    # ------------------------------------------------------------------------- observation

    def _info(self) -> dict[str, Any]:
        e = self.entry
        assert e is not None
        length = self.route.length_m
        done = self.outcome in ("completed",)
        return {"scenario": e.id, "network": e.network, "kind": e.kind, "time": self._now(),
                "outcome": self.outcome, "collided_with": self.collided_with,
                "collided_with_adversary": self.collided_with is not None and self.collided_with == e.adversary,
                "off_road": self.off_road, "completed": done,
                "route_completion": 1.0 if done or length <= 0 else float(min(self.s / length, 1.0)),
                "avoidable": e.avoidable,
                "reacting": len(self._reactive.released) if self._reactive is not None else 0}

    def _now(self) -> float:
        """[s] the scenario's time (SUMO's clock runs on over the episodes of a loaded network)."""
        return round(float(self._session.time) - self._t_shift, 9)

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None
        super().close()


def _row(ids: list[str], vid: str) -> int:
    """Row of ``vid`` in ``ids`` (-1: absent)."""
    try:
        return ids.index(vid)
    except ValueError:
        return -1


def _from_step(scene: Scene, k0: int) -> Scene:
    """``scene`` from step ``k0`` on (the replayer starts at its first timestamp)."""
    import dataclasses

    if k0 == 0:
        return scene
    tracks = scene.tracks.select(steps=slice(k0, None))
    signals = dataclasses.replace(scene.signals, state=scene.signals.state[k0:])
    return dataclasses.replace(scene, timestamps=scene.timestamps[k0:], tracks=tracks, signals=signals)
