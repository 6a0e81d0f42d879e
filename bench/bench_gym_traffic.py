"""Surrounding traffic of an episode: replayed from the recorded pass, or driven by SUMO from a saved state?

    python bench/bench_gym_traffic.py [--lead 5] [--window 10]

For each shipped network (its configuration, seed 0, target ``ego``) the nominal pass is recorded
once, every vehicle at every 0.1 s step. An episode starts ``--lead`` s after the target departs and
lasts ``--window`` s. Three ways to get the traffic of that window, each timed and compared with
the recorded pass (largest centre distance over the vehicles within 50 m of the target, at every
step both have them):

- ``replay``: a fresh libsumo session on the net alone; every recorded vehicle that comes within
  80 m of the target's path is driven along its recording with moveToXY (what Scenario-v0 does; the
  target here replays too);
- ``state-api``: the pass saved with ``simulation.saveState`` at the start, then a fresh session of the
  configuration that ``loadState``s it and lets SUMO drive;
- ``state-rng``: the same with SUMO's own ``--save-state.rng`` state file (``--load-state`` at start).

It prints per mode the wall time of the window (start included; the fastest of ``--repeats``)
and the position error.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from coster_sumo.geometry.boxes import resample_polyline
from coster_sumo.sim.record import record_config
from coster_sumo.sim.session import SumoSession

REPO = Path(__file__).resolve().parents[1]
NEAR_M = 50.0  # [m] vehicles compared: within this distance of the target


def _positions(sess: SumoSession) -> dict[str, tuple[float, float]]:
    st = sess.vehicle_states()
    return {str(i): (float(x), float(y)) for i, x, y in zip(st.ids, st.x, st.y, strict=True)}


def _error(rec: dict[float, dict[str, tuple[float, float]]], got: dict[float, dict[str, tuple[float, float]]]
           ) -> tuple[float, int]:
    """Largest centre distance [m] over vehicles within NEAR_M of ego in the recording, and how many compared."""
    worst, n = 0.0, 0
    for t, now in got.items():
        ref = rec.get(t)
        if ref is None or "ego" not in ref:
            continue
        ex, ey = ref["ego"]
        for vid, (x, y) in ref.items():
            if vid == "ego" or np.hypot(x - ex, y - ey) > NEAR_M:
                continue
            if vid in now:
                worst = max(worst, float(np.hypot(now[vid][0] - x, now[vid][1] - y)))
            else:
                worst = max(worst, np.inf)
            n += 1
    return worst, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lead", type=float, default=5.0, help="[s] episode start after the target departs")
    ap.add_argument("--window", type=float, default=10.0, help="[s] episode length")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per mode (the fastest is printed)")
    args = ap.parse_args()
    from coster_sumo.gym.env import REPLAY_RADIUS_M, _far_agents
    from coster_sumo.gym.scenario_set import write_vtypes
    from coster_sumo.sim.replay import LogReplayer

    tmp = Path(tempfile.mkdtemp(prefix="bench_gym_traffic_"))
    write_vtypes(tmp)
    for name in ("intersection", "merge", "arterial"):
        cfg = REPO / "networks" / name / f"{name}.sumocfg"
        scene = record_config(cfg, seed=0, end=None)
        ts = scene.timestamps
        tr = scene.tracks
        e = tr.index_of("ego")
        t0 = float(np.round(ts[tr.valid[e]][0] + args.lead, 1))
        t1 = t0 + args.window
        rec: dict[float, dict[str, tuple[float, float]]] = {}
        for k, t in enumerate(ts):
            if t0 - 1e-6 <= t <= t1 + 1e-6:
                rec[round(float(t), 1)] = {str(tr.ids[a]): (float(tr.x[a, k]), float(tr.y[a, k]))
                                           for a in np.flatnonzero(tr.valid[:, k])}
        state = tmp / f"{name}.state.xml"
        with SumoSession(cfg, seed=0) as s:  # the prefix, to save the state at t0 (not timed)
            while s.time < t0 - 1e-6:
                s.step()
            s.api.simulation.saveState(str(state))
        rng_state = tmp / f"{name}.rng.state.xml"
        with SumoSession(cfg, seed=0, options={"--save-state.times": f"{t0:g}", "--save-state.files": str(rng_state),
                                               "--save-state.rng": "true", "--save-state.precision": "12"}) as s:
            while s.time < t0 + 0.05:
                s.step()
        out: dict[str, tuple[float, float, int]] = {}
        # what the scenario set holds: the vehicles near the target's path, from the episode's start
        import dataclasses

        k0 = int(np.argmin(np.abs(ts - t0)))
        k1 = int(np.argmin(np.abs(ts - t1))) + 1
        window = tr.select(steps=slice(0, k1))
        path_xy = resample_polyline(np.stack([window.x[e, window.valid[e]], window.y[e, window.valid[e]]], -1), 2.0)
        far = set(_far_agents(window, k0, path_xy, REPLAY_RADIUS_M))
        near = np.flatnonzero([str(i) not in far for i in tr.ids])
        sub = dataclasses.replace(scene, timestamps=ts[k0:k1], tracks=tr.select(agents=near, steps=np.arange(k0, k1)),
                                  signals=dataclasses.replace(scene.signals, state=scene.signals.state[k0:k1]))
        net = next(cfg.parent.glob("*.net.xml"))

        def start(mode: str, cfg: Path = cfg, net: Path = net, t0: float = t0, state: Path = state,
                  rng_state: Path = rng_state) -> SumoSession:
            if mode == "replay":
                return SumoSession(net=net, begin=round(t0 - 0.1, 6), step_length=0.1,
                                   additional=[tmp / "vtypes.add.xml"]).start()
            if mode == "state-api":
                sess = SumoSession(cfg, seed=0, begin=t0).start()
                sess.api.simulation.loadState(str(state))
                return sess
            return SumoSession(cfg, seed=0, begin=t0, options={"--load-state": str(rng_state)}).start()

        for mode in ("replay", "state-api", "state-rng"):
            best = np.inf
            for _ in range(args.repeats):  # the machine is shared: the fastest of a few
                w = time.perf_counter()
                got: dict[float, dict[str, tuple[float, float]]] = {}
                rep = LogReplayer(sub) if mode == "replay" else None
                with start(mode) as s:
                    while s.time < t1 - 1e-6:
                        if rep is not None:
                            rep.before_step(s, round(s.time + 0.1, 9))
                        s.step()
                        got[round(s.time, 1)] = _positions(s)
                best = min(best, time.perf_counter() - w)
            out[mode] = (best, *_error(rec, got))
        for mode, (wall, err, n) in out.items():
            print(f"{name:13s} {mode:10s} {args.window:4.0f} s simulated in {wall:6.3f} s wall "
                  f"({args.window / wall:6.1f} sim s/s); max centre error {err:7.3f} m over {n} vehicle-steps",
                  flush=True)


if __name__ == "__main__":
    main()
