"""Variants continued from held copies of the nominal pass play out as runs from ``begin``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.core.spec import GenerationConfig, InjectionSettings, ScenarioSpec
from coster_sumo.formats.targets import choose_target
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.generation import generate_variants
from coster_sumo.pipeline.scenario import nominal_scene
from coster_sumo.sim.hold import HeldStates
from coster_sumo.sim.inject import inject_variants

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.sumo


def _outcome(res, target_id: str, adv_id: str, since: float) -> dict:
    c = res.contact
    tr, ts = res.scene.tracks, res.scene.timestamps
    tracks = {}
    for vid in (target_id, adv_id):
        a = tr.index_of(vid)
        keep = tr.valid[a] & (ts > since + 1e-6)  # a held copy records from the step after its moment
        tracks[vid] = np.round(np.stack([ts[keep], tr.x[a, keep], tr.y[a, keep]], 1), 6)
    return {"contact": None if c is None else (round(c.time, 6), round(c.relative_speed, 6),
                                               round(c.impact_angle, 4)),
            "off_road": (res.adversary_off_road, res.target_off_road), "completed": res.route_completed,
            "arrived": res.target_arrived, "tracks": tracks}


@pytest.mark.parametrize(("network", "planner"), [("intersection", "replay"), ("arterial", "sumo"),
                                                  ("merge", "sumo:IDM")])
def test_same_seed_same_outcome_held_or_from_begin(tmp_path, network, planner):
    spec = ScenarioSpec(REPO / "networks" / network / f"{network}.sumocfg", seed=2)
    gen = GenerationConfig(init="random", rollout="cv", variants=3)
    from coster_sumo.sim.planners import make_planner

    extra = [] if planner == "replay" else make_planner(planner).additional_files(tmp_path)
    with HeldStates("ego", spacing_s=3.0) as held:
        scene, _ = nominal_scene(spec, hold=held, additional=extra)
        assert len(held.holders) >= 2
        target = choose_target(scene, None, spec.config)
        drivable = DrivableArea.from_road_map(scene.road_map)
        variants, _ = generate_variants(scene, target, spec.seed, gen, drivable)
        plans = [v.plan for v in variants]
        from_held = inject_variants(spec, scene, target, plans,
                                    InjectionSettings(planner, workers=2, workdir=tmp_path),
                                    drivable=drivable, held=held)
        times = [held.holder_before(p.t_start).time for p in plans]
    from_begin = inject_variants(spec, scene, target, plans, InjectionSettings(planner, workdir=tmp_path),
                                 drivable=drivable)
    _assert_same_outcomes(plans, times, from_held, from_begin)


def _assert_same_outcomes(plans, times, from_held, from_begin) -> None:  # noqa: ANN001
    """Every variant from a held copy equals its run from ``begin`` since the holder's time."""
    for plan, since, a, b in zip(plans, times, from_held, from_begin, strict=True):
        oa, ob = _outcome(a, "ego", plan.vehicle_id, since), _outcome(b, "ego", plan.vehicle_id, since)
        for vid in oa["tracks"]:
            assert np.array_equal(oa["tracks"][vid], ob["tracks"][vid]), vid
        assert {k: v for k, v in oa.items() if k != "tracks"} == {k: v for k, v in ob.items() if k != "tracks"}


@pytest.mark.parametrize(("network", "planner"), [("intersection", "replay"), ("merge", "sumo")])
def test_advanced_holder_gives_the_same_outcome(tmp_path, network, planner):
    """A holder advanced in the background (while adversaries are generated) is a run from ``begin``."""
    spec = ScenarioSpec(REPO / "networks" / network / f"{network}.sumocfg", seed=3)
    gen = GenerationConfig(init="random", rollout="cv", variants=2)
    with HeldStates("ego", spacing_s=1000.0, lead_s=0.0) as held:  # one holder, at the target's departure
        scene, _ = nominal_scene(spec, hold=held)
        assert len(held.holders) == 1
        target = choose_target(scene, None, spec.config)
        drivable = DrivableArea.from_road_map(scene.road_map)
        variants, _ = generate_variants(scene, target, spec.seed, gen, drivable)
        plans = [v.plan for v in variants]
        first = min(p.t_start for p in plans)
        new = held.advance(first - 0.45)
        assert new is not None and len(held.holders) == 2
        assert held.advance(first - 0.2) is None  # already within MIN_ADVANCE_S: nothing to gain
        from_held = inject_variants(spec, scene, target, plans,
                                    InjectionSettings(planner, workers=2, workdir=tmp_path),
                                    drivable=drivable, held=held)
        assert new.ready and first - 0.45 - 1e-6 <= new.time < first
        times = [held.holder_before(p.t_start).time for p in plans]
        assert times == [new.time] * len(plans)
    from_begin = inject_variants(spec, scene, target, plans, InjectionSettings(planner, workdir=tmp_path),
                                 drivable=drivable)
    _assert_same_outcomes(plans, times, from_held, from_begin)


class _FakeSession:
    """Enough of a session for :meth:`HeldStates.after_step`; the target runs from ``departs`` [s] on."""

    uses_traci, port, time = False, None, 0.0

    def __init__(self, departs: float = 0.0) -> None:
        self.departs = departs

    def vehicle_ids(self):
        return ("ego",) if self.time >= self.departs else ()


def _fake_holds(monkeypatch) -> tuple[list[float], list[float]]:  # noqa: ANN001
    """Holders that fork nothing: the times held and the times stopped, in order."""
    from coster_sumo.sim import hold

    made, stopped = [], []

    def fake_hold(self, session):
        made.append(session.time)
        self.holders.append(hold._Holder(session.time, -1, None))

    monkeypatch.setattr(hold.HeldStates, "_hold", fake_hold)
    monkeypatch.setattr(hold.HeldStates, "_stop", staticmethod(lambda h: stopped.append(h.time)))
    return made, stopped


def test_thinning_keeps_the_first_and_the_newest_holder(monkeypatch):
    """However long the target lives, a holder at its departure stays (any t_col comes after it)."""
    from coster_sumo.sim import hold

    made, stopped = _fake_holds(monkeypatch)
    held, sim = hold.HeldStates("ego", max_holders=4, spacing_s=1.0), _FakeSession()
    for k in range(1, 2000):
        sim.time = 100.0 + 0.1 * k
        held.after_step(sim)
        assert len(held.holders) <= 4
        assert held.holders[0].time == made[0]  # the departure's holder is never dropped
        assert held.holders[-1].time == made[-1]  # nor the newest
    assert len(made) > 10 and len(stopped) == len(made) - len(held.holders)


def test_rolling_holders_before_the_target_departs(monkeypatch):
    """Before the target departs two rolling holders stay, the older at least ``lead_s`` before it."""
    from coster_sumo.sim import hold

    made, stopped = _fake_holds(monkeypatch)
    held, sim = hold.HeldStates("ego", max_holders=3, spacing_s=1.0, lead_s=5.0), _FakeSession(departs=57.05)
    for k in range(1, 3000):
        sim.time = round(0.1 * k, 9)
        held.after_step(sim)
        lead = [h.time for h in held.holders if h.lead]
        assert len(lead) <= hold.LEAD_HOLDERS
    assert lead == [50.1, 55.1]  # rolling every 5 s from the first step; the thinning of the rest keeps them
    assert held.holder_before(57.1 - 5.0).time == 50.1  # an adversary that starts its horizon before departure
    assert min(h.time for h in held.holders if not h.lead) == 57.1
    assert len(stopped) == len(made) - len(held.holders)


@pytest.mark.parametrize("late_s", [0.0, 12.3])
def test_rolling_holders_start_shortly_before_the_planned_departure(monkeypatch, late_s):
    """With the planned departure known, holders roll from ``2 lead_s`` before it, not from the first
    step; inserted on time or later (``late_s``: SUMO delays an insertion, never advances it), the
    target still has a holder at least ``lead_s`` before its departure, and no vehicle list is read
    before that."""
    from coster_sumo.sim import hold

    made, _ = _fake_holds(monkeypatch)
    held, sim = hold.HeldStates("ego", max_holders=3, spacing_s=1.0, lead_s=5.0), _FakeSession(departs=57.05 + late_s)
    held.expect_departure(57.05)
    asked: list[float] = []
    ids = sim.vehicle_ids
    sim.vehicle_ids = lambda: asked.append(sim.time) or ids()
    for k in range(1, 3000):
        sim.time = round(0.1 * k, 9)
        held.after_step(sim)
    assert made[0] == 47.1 and min(asked) == 47.1  # 57.05 - 2 x 5 s, on the 0.1 s grid
    departed = 57.1 + late_s
    assert departed - held.holder_before(departed - 5.0).time <= 10.0 + 1e-9
    assert held.holder_before(departed - 5.0).lead


def test_variants_from_a_holder_made_before_the_target_departs(tmp_path):
    """A rolling holder from before the target's departure continues as a run from ``begin``."""
    spec = ScenarioSpec(REPO / "networks" / "intersection" / "intersection.sumocfg", seed=4)
    gen = GenerationConfig(init="random", rollout="cv", variants=2)
    with HeldStates("ego", spacing_s=1000.0, lead_s=0.7) as held:
        scene, _ = nominal_scene(spec, hold=held)
        lead = [h for h in held.holders if h.lead]
        assert len(lead) == 2 and lead[0].time < 2.0  # ego is planned to depart at 2 s
        for h in held.holders:  # only the rolling ones are left to continue from
            if not h.lead:
                held._stop(h)
        held.holders = lead
        target = choose_target(scene, None, spec.config)
        drivable = DrivableArea.from_road_map(scene.road_map)
        variants, _ = generate_variants(scene, target, spec.seed, gen, drivable)
        plans = [v.plan for v in variants]
        from_held = inject_variants(spec, scene, target, plans,
                                    InjectionSettings("replay", workers=2, workdir=tmp_path),
                                    drivable=drivable, held=held)
        times = [held.holder_before(p.t_start).time for p in plans]
        assert set(times) <= {h.time for h in lead}
    from_begin = inject_variants(spec, scene, target, plans, InjectionSettings("replay", workdir=tmp_path),
                                 drivable=drivable)
    _assert_same_outcomes(plans, times, from_held, from_begin)
