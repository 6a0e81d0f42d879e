"""Recording a SUMO run into a Scene: tracks match SUMO's getters, signals match the state strings."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.core.scene import ObjectType, SignalState
from coster_sumo.formats.scene_file import load_scene, save_scene
from coster_sumo.formats.sumo_net import load_sumo_net
from coster_sumo.infra import sumo_install
from coster_sumo.sim.record import record, record_config
from coster_sumo.sim.session import SumoSession
from coster_sumo.sim.signals import LINK_STATE, SignalTable, link_state_to_signal

ROUTES = """<routes>
  <vType id="car" length="4.5" width="1.8"/>
  <vType id="bike" vClass="bicycle" length="1.8" width="0.6"/>
  <route id="north" edges="A0A1 A1A2"/>
  <route id="east" edges="A1B1 B1C1"/>
  <vehicle id="v1" type="car" route="north" depart="0"/>
  <vehicle id="ego" type="car" route="east" depart="1"/>
  <vehicle id="b1" type="bike" route="north" depart="2"/>
  <flow id="f" type="car" route="east" begin="3" end="20" period="4"/>
</routes>
"""


@pytest.fixture(scope="module")
def grid_cfg(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("rec")
    subprocess.run([sumo_install.binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
                    "-L", "2", "--default-junction-type", "traffic_light",
                    "-o", str(folder / "grid.net.xml")],
                   check=True, capture_output=True, env=sumo_install.subprocess_env())
    (folder / "grid.rou.xml").write_text(ROUTES)
    cfg = folder / "grid.sumocfg"
    cfg.write_text('<configuration><input><net-file value="grid.net.xml"/>'
                   '<route-files value="grid.rou.xml"/></input></configuration>\n')
    return cfg


def test_link_letters_map_to_signal_states():
    got = link_state_to_signal("GgyYrRusoO?")
    assert list(got) == [SignalState.GO, SignalState.GO, SignalState.CAUTION, SignalState.CAUTION,
                         SignalState.STOP, SignalState.STOP, SignalState.STOP, SignalState.FLASHING_STOP,
                         SignalState.FLASHING_CAUTION, SignalState.UNKNOWN, SignalState.UNKNOWN]


@pytest.mark.sumo
def test_recorded_tracks_match_sumo_getters(grid_cfg):
    seen: dict[float, dict[str, tuple[float, float, float, float, float]]] = {}

    def probe(sim: SumoSession, _states) -> None:
        veh = sim.api.vehicle
        seen[sim.time] = {v: (*veh.getPosition(v), veh.getAngle(v), veh.getSpeed(v), veh.getLength(v))
                          for v in veh.getIDList()}

    with SumoSession(grid_cfg, seed=5) as sim:
        scene = record(sim, end=25.0, after_step=probe)
    assert scene.source == "sumo" and scene.meta["seed"] == 5 and scene.meta["sumocfg"] == str(grid_cfg)
    assert scene.num_steps == 250
    np.testing.assert_allclose(scene.timestamps, 0.1 * np.arange(1, 251), atol=1e-9)
    tr = scene.tracks
    assert scene.sdc_index == tr.index_of("ego")
    assert tr.object_type[tr.index_of("b1")] == ObjectType.CYCLIST
    assert tr.object_type[tr.index_of("ego")] == ObjectType.VEHICLE
    assert {"f.0", "f.1", "f.2"} <= set(tr.ids)
    # b1 departs at 2 s: invalid before
    b1 = tr.index_of("b1")
    assert not tr.valid[b1, scene.timestamps < 1.95].any() and tr.valid[b1, -1]
    for s, t in enumerate(scene.timestamps):
        present = seen[t]
        assert set(tr.ids[tr.valid[:, s]]) == set(present)
        for vid, (fx, fy, angle, speed, length) in present.items():
            a = tr.index_of(vid)
            yaw = math.radians(90.0 - angle)
            assert tr.x[a, s] + 0.5 * length * math.cos(yaw) == pytest.approx(fx, abs=1e-9)
            assert tr.y[a, s] + 0.5 * length * math.sin(yaw) == pytest.approx(fy, abs=1e-9)
            assert math.hypot(tr.vx[a, s], tr.vy[a, s]) == pytest.approx(speed, abs=1e-9)
            assert tr.length[a, s] == length


@pytest.mark.sumo
def test_recorded_signals_match_state_strings(grid_cfg):
    states: list[dict[str, str]] = []
    with SumoSession(grid_cfg) as sim:
        scene = record(sim, end=45.0, after_step=lambda s, _: states.append(s.tls_states()))
    net = load_sumo_net(grid_cfg.parent / "grid.net.xml")
    lanes = scene.road_map.lanes
    sig = scene.signals
    assert len(sig.lane_index) > 0
    rows = {int(li): k for k, li in enumerate(sig.lane_index)}
    seen_values = set(np.unique(sig.state).tolist())
    assert {SignalState.GO, SignalState.CAUTION, SignalState.STOP} <= seen_values
    for links in net.signal_links.values():
        for link in links:
            via = rows[lanes.index_of(link.via_lane)]  # internal lane: exactly its link's state
            expected = [LINK_STATE[st[link.tls_id][link.link_index]] for st in states]
            assert list(sig.state[:, via]) == expected
            frm = rows[lanes.index_of(link.from_lane)]  # incoming lane: at least as permissive
            assert np.all((sig.state[:, frm] != SignalState.STOP) | (sig.state[:, via] == SignalState.STOP))
            # stop points sit on the stop line: start of the via lane, end of the incoming lane
            line = lanes.centerline
            np.testing.assert_allclose(sig.stop_point[via], line[lanes.index_of(link.via_lane)][0])
            np.testing.assert_allclose(sig.stop_point[frm], line[lanes.index_of(link.from_lane)][-1])


@pytest.mark.sumo
def test_only_internal_signal_lanes(grid_cfg):
    net = load_sumo_net(grid_cfg.parent / "grid.net.xml")
    both = SignalTable.build(net)
    internal = SignalTable.build(net, incoming_lanes=False)
    assert net.road_map.lanes.is_junction[internal.lane_index].all()
    assert len(both.lane_index) > len(internal.lane_index)


@pytest.mark.sumo
def test_window_and_callbacks_while_recording(grid_cfg, tmp_path):
    """Simulate and record [5, 8] s (SUMO's begin) while a callback drives an injected vehicle every step."""
    moved: list[float] = []

    def drive(sim: SumoSession) -> None:
        if "adv" not in sim.vehicle_ids() and not moved:
            sim.add_vehicle("adv", length=5.0, width=2.0)
        x0, y0 = sim.api.lane.getShape("B0B1_0")[0]
        y = y0 + 10.0 + 1.5 * len(moved)
        sim.move_to_xy("adv", x0, y, math.pi / 2)
        moved.append(y)

    scene = record_config(grid_cfg, begin=5.0, end=8.0, before_step=drive)
    assert scene.timestamps[0] == pytest.approx(5.1) and scene.timestamps[-1] == pytest.approx(8.0)
    assert scene.num_steps == 30 and len(moved) == 30
    adv = scene.tracks.index_of("adv")
    assert scene.tracks.valid[adv].all()
    np.testing.assert_allclose(scene.tracks.y[adv], moved, atol=1e-6)
    np.testing.assert_allclose(scene.tracks.speed[adv][1:], 15.0, atol=1e-6)  # 1.5 m per 0.1 s, uncapped
    back = load_scene(save_scene(scene, tmp_path / "s.npz"))
    np.testing.assert_array_equal(back.tracks.x, scene.tracks.x)
    assert back.meta == scene.meta


@pytest.mark.sumo
def test_after_step_can_stop_and_traci_records_the_same(grid_cfg):
    scenes = []
    for traci in (False, True):
        with SumoSession(grid_cfg, seed=2, traci=traci) as sim:
            scenes.append(record(sim, after_step=lambda s, _: s.time >= 12.0 - 1e-9))
    a, b = scenes
    assert a.num_steps == b.num_steps == 120
    order_a, order_b = np.argsort(a.tracks.ids), np.argsort(b.tracks.ids)
    np.testing.assert_array_equal(a.tracks.ids[order_a], b.tracks.ids[order_b])
    for f in ("x", "y", "heading", "vx", "valid"):
        np.testing.assert_array_equal(getattr(a.tracks, f)[order_a], getattr(b.tracks, f)[order_b])
    np.testing.assert_array_equal(a.signals.state, b.signals.state)


def test_a_recording_without_the_road_has_the_same_tracks(grid_cfg):
    """road=False (the proofs' passes): the net is not read; the vehicles are recorded as ever."""
    scenes = []
    for road in (True, False):
        with SumoSession(grid_cfg, seed=2) as sim:
            scenes.append(record(sim, end=8.0, road=road))
    full, bare = scenes
    assert len(full.road_map.lanes) > 0 and len(bare.road_map.lanes) == 0
    assert full.signals.state.shape[1] > 0 and bare.signals.state.shape == (bare.num_steps, 0)
    np.testing.assert_array_equal(full.tracks.ids, bare.tracks.ids)
    for f in ("x", "y", "heading", "vx", "vy", "valid"):
        np.testing.assert_array_equal(getattr(full.tracks, f), getattr(bare.tracks, f))


@pytest.mark.sumo
def test_run_to_the_end_of_the_demand(grid_cfg):
    scene = record_config(grid_cfg)
    assert scene.tracks.num_agents == 3 + 5  # v1, ego, b1 and the flow's 5 cars
    # the last step is the one in which the last vehicle arrived: nobody is left in it
    assert not scene.tracks.valid[:, -1].any() and scene.tracks.valid[:, -2].any()
    assert scene.timestamps[-1] > 20.0


@pytest.mark.sumo
def test_net_without_traffic_lights(tmp_path):
    net = tmp_path / "plain.net.xml"
    subprocess.run([sumo_install.binary("netgenerate"), "--grid", "--grid.number", "2", "--grid.length", "100",
                    "--default-junction-type", "priority", "-o", str(net)],
                   check=True, capture_output=True, env=sumo_install.subprocess_env())
    with SumoSession(net=net) as sim:
        scene = record(sim, end=sim.time + 20 * sim.step_length)
    assert scene.num_steps == 20 and scene.tracks.num_agents == 0
    assert scene.signals.state.shape == (20, 0) and scene.meta["sumocfg"] is None


@pytest.mark.parametrize("network,target", [("intersection", "ego"), ("arterial", "ego")])
def test_surroundings_at_2hz_give_the_models_exactly_what_sumo_did(network, target):
    """Focus.surroundings_hz: the 2 Hz steps the models read equal an every-step recording's; the
    target is read at every step; the steps in between are interpolated close to the truth."""
    from coster_sumo.core.scene import resample
    from coster_sumo.sim.record import Focus

    cfg = Path(__file__).resolve().parents[2] / "networks" / network / f"{network}.sumocfg"
    full = record_config(cfg, seed=0, end=60.0, focus=Focus(target, 200.0, tail_s=2.0))
    part = record_config(cfg, seed=0, end=60.0, focus=Focus(target, 200.0, tail_s=2.0, surroundings_hz=2.0))
    assert full.num_steps == part.num_steps > 100
    lo_full, lo_part = resample(full), resample(part)
    assert sorted(lo_full.tracks.ids) == sorted(lo_part.tracks.ids)
    ia = [list(lo_full.tracks.ids).index(v) for v in lo_part.tracks.ids]
    for field in ("x", "y", "heading", "vx", "vy", "length", "width", "valid"):
        assert np.array_equal(getattr(lo_full.tracks, field)[ia], getattr(lo_part.tracks, field)), field
    tf, tp = full.tracks.index_of(target), part.tracks.index_of(target)
    for field in ("x", "y", "heading", "valid"):
        assert np.array_equal(getattr(full.tracks, field)[tf], getattr(part.tracks, field)[tp]), field
    common = [v for v in part.tracks.ids if v in set(full.tracks.ids)]
    rf = [list(full.tracks.ids).index(v) for v in common]
    rp = [list(part.tracks.ids).index(v) for v in common]
    both = full.tracks.valid[rf] & part.tracks.valid[rp]
    err = np.hypot(full.tracks.x[rf] - part.tracks.x[rp], full.tracks.y[rf] - part.tracks.y[rp])[both]
    assert both.sum() >= 0.9 * full.tracks.valid.sum()  # only arrivals/departures between samples are lost
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.2


def test_a_focused_recording_stops_max_life_s_after_the_target_departs():
    """Focus.max_life_s bounds a pass whose target would run for days (the wheel's rail_demo ends at
    1,200,000 s): the recording stops that long after the departure and says so in its meta."""
    from coster_sumo.sim.record import Focus

    cfg = Path(__file__).resolve().parents[2] / "networks" / "intersection" / "intersection.sumocfg"
    full = record_config(cfg, seed=0, end=60.0, focus=Focus("ego", 100.0, tail_s=2.0))
    cut = record_config(cfg, seed=0, end=60.0, focus=Focus("ego", 100.0, tail_s=2.0, max_life_s=5.0))
    assert "cut_after_s" not in full.meta and cut.meta["cut_after_s"] == 5.0
    t0 = cut.timestamps[0]  # the step the target departed in
    assert cut.timestamps[-1] == pytest.approx(t0 + 5.0, abs=1e-6) and full.timestamps[-1] > t0 + 10.0
    n = cut.num_steps
    e = full.tracks.index_of("ego")
    assert np.array_equal(cut.tracks.x[cut.tracks.index_of("ego")], full.tracks.x[e, :n])
    # a target already running when the recording starts is bounded from that moment
    with SumoSession(cfg, seed=0, end=60.0) as sim:
        while "ego" not in sim.vehicle_ids():
            sim.step()
        sim.step()
        t0 = sim.time
        late = record(sim, end=60.0, focus=Focus("ego", 100.0, tail_s=2.0, max_life_s=5.0))
    assert late.meta["cut_after_s"] == 5.0 and late.timestamps[-1] == pytest.approx(t0 + 5.0, abs=1e-6)


def test_small_pages_switch_numpy_off_inside_and_restore_it_after():
    from coster_sumo.sim.record import _small_pages, hugepage_switch

    _set_madvise_hugepage = hugepage_switch()
    if _set_madvise_hugepage is None:
        pytest.skip("this numpy has no huge-page switch")
    original = _set_madvise_hugepage(True)
    for before in (True, False):
        _set_madvise_hugepage(before)
        with _small_pages():
            inside = _set_madvise_hugepage(False)  # returns the setting it replaces
        after = _set_madvise_hugepage(True)
        assert (inside, after) == (False, before)
    _set_madvise_hugepage(original)


@pytest.mark.sumo
def test_a_progress_bar_follows_the_simulation_time_to_the_end(grid_cfg):
    """The nominal pass's bar: its total is the window from the first step to ``end``, it moves
    once per simulated second, and it stands at the last whole second when the recording ends."""
    class Bar:  # what the pass uses of a tqdm bar
        total: float | None = None
        n = 0.0

        def update(self, k: float) -> None:
            moves.append(k)
            self.n += k

    bar = Bar()
    moves: list[float] = []
    with SumoSession(grid_cfg, seed=1, end=12.0) as session:
        scene = record(session, end=12.0, bar=bar)
    first = float(scene.timestamps[0])
    assert bar.total == pytest.approx(12.0 - first)
    assert moves and all(m >= 1.0 - 1e-9 for m in moves)
    assert 12.0 - first - 1.0 <= bar.n <= 12.0 - first + 1e-9


@pytest.mark.sumo
def test_a_quiet_progress_bar_is_still_moved_once_per_simulated_second(grid_cfg):
    """A quiet tqdm bar (``disable=True``) does not count what it is given: the pass must not call
    it on every one of its steps."""
    from tqdm import tqdm

    calls: list[float] = []
    bar = tqdm(disable=True)
    update = bar.update
    bar.update = lambda k: calls.append(k) or update(k)
    with SumoSession(grid_cfg, seed=1, end=12.0) as session:
        record(session, end=12.0, bar=bar)
    assert 1 <= len(calls) <= 12  # 119 steps of 0.1 s


def test_targets_after_the_first_get_ids_only_and_the_same_recording(monkeypatch):
    """Several targets: the queries around the ones after the first ask SUMO for ids only
    (``vehicles_near(values=False)``), and the vehicles that only those queries found are read with
    getters. The recording is the same, byte for byte, as with every query's values."""
    from coster_sumo.sim.record import Focus

    cfg = Path(__file__).resolve().parents[2] / "networks" / "arterial" / "arterial.sumocfg"
    targets = ("ego", "ew.0", "we.0", "pre_east.0")
    # a small radius: each target sees vehicles the others do not
    focus = Focus(targets[0], 40.0, tail_s=2.0, surroundings_hz=2.0, more_targets=targets[1:])
    asked: list[bool] = []
    lean = SumoSession.vehicles_near

    def counted(self, veh_id, radius_m, *, once=False, values=True):  # type: ignore[no-untyped-def]
        asked.append(values)
        return lean(self, veh_id, radius_m, once=once, values=values)

    monkeypatch.setattr(SumoSession, "vehicles_near", counted)
    got = record_config(cfg, seed=0, end=60.0, focus=focus)
    assert asked.count(False) > 20 and sum(t in set(got.tracks.ids) for t in targets) >= 3

    def full(self, veh_id, radius_m, *, once=False, values=True):  # type: ignore[no-untyped-def]
        return lean(self, veh_id, radius_m, once=once)  # every query with its values, as before

    monkeypatch.setattr(SumoSession, "vehicles_near", full)
    ref = record_config(cfg, seed=0, end=60.0, focus=focus)
    assert got.tracks.ids.tolist() == ref.tracks.ids.tolist()
    assert got.timestamps.tobytes() == ref.timestamps.tobytes()
    for field in ("x", "y", "heading", "vx", "vy", "length", "width", "valid"):
        assert getattr(got.tracks, field).tobytes() == getattr(ref.tracks, field).tobytes(), field
    # the ids-only queries found vehicles the first target's did not: those were read with getters
    first_only = Focus(targets[0], 40.0, tail_s=2.0, surroundings_hz=2.0)
    assert len(record_config(cfg, seed=0, end=60.0, focus=first_only).tracks.ids) < len(got.tracks.ids)
