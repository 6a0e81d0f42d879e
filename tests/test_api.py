"""The README's Python API example, run as written (with fewer samples)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.api import AdversaryController, SumoSession, plan_adversaries

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.sumo
def test_user_loop_drives_adversary_into_contact(monkeypatch):
    monkeypatch.chdir(REPO)
    cfg = "networks/intersection/intersection.sumocfg"
    planned = plan_adversaries(cfg, seed=0, samples=200, variants=2)
    plan = planned.plans[0]
    adversary = AdversaryController(plan)
    gap = []
    with SumoSession(cfg, seed=0) as sim:
        ego = planned.snapshot.target
        while sim.time < plan.t_col - 1e-6:
            adversary.before_step(sim, round(sim.time + sim.step_length, 9))
            sim.step()
        states = sim.vehicle_states()
        i = int(np.flatnonzero(states.ids == plan.vehicle_id)[0])
        gap.append(np.hypot(states.x[i] - planned.snapshot.adversary.x, states.y[i] - planned.snapshot.adversary.y))
    assert gap[0] < 1e-6  # at t_col the adversary is exactly in the snapshot state
    assert ego.length > 0 and os.path.exists(cfg)
