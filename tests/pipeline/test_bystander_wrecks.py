"""Variants whose adversary ran into another vehicle before t_col in the simulation are dropped."""

from __future__ import annotations

from types import SimpleNamespace

from coster_sumo.sim.events import Event
from coster_sumo.sim.outcomes import drop_bystander_wrecks


def _hit(t: float, *ids: str) -> Event:
    return Event(time=t, kind="collision", vehicles=list(ids), positions=[[0.0, 0.0]] * len(ids))


def test_wrecks_before_t_col_are_dropped_even_when_the_target_hits_them():
    plans = [SimpleNamespace(vehicle_id=f"adversary{i}", t_col=404.1) for i in range(4)]
    contact = _hit(404.1, "veh400", "adversary0")
    results = [SimpleNamespace(contact=contact, events=[contact]),  # in contact: kept
               SimpleNamespace(contact=None, events=[_hit(403.3, "adversary1", "veh_mw574")]),  # wreck: dropped
               SimpleNamespace(contact=None, events=[_hit(404.5, "adversary2", "veh_mw573")]),  # after t_col: kept
               SimpleNamespace(contact=_hit(404.1, "veh400", "adversary3"),  # a wreck the target hit: dropped
                               events=[_hit(402.0, "adversary3", "veh9"), _hit(404.1, "veh400", "adversary3")])]
    planned = [SimpleNamespace(plans=plans[:2], info={}), SimpleNamespace(plans=plans[2:], info={"dropped": []})]
    out, kept = drop_bystander_wrecks(planned, results, "veh400")
    assert [p.vehicle_id for p in out[0].plans] == ["adversary0"]
    assert [p.vehicle_id for p in out[1].plans] == ["adversary2"]
    assert kept == [results[0], results[2]]
    assert out[0].info["dropped"] == [{"candidate": "adversary1",
                                       "reason": "ran into veh_mw574 at 403.3 s in the simulation, before t_col"}]
    assert out[1].info["dropped"] == [{"candidate": "adversary3",
                                       "reason": "ran into veh9 at 402.0 s in the simulation, before t_col"}]
