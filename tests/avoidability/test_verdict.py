"""A proof's verdict reads the escape's window only: from the adversary's appearance to the escape's
last pose (t_col + the horizon), whichever pass it came from (coster_sumo.avoidability.proof)."""

from __future__ import annotations

import numpy as np

from coster_sumo.avoidability.evasion import Escape, Manoeuvre
from coster_sumo.avoidability.proof import EscapeJob, _verdict
from coster_sumo.core.plan import HORIZON_AFTER_TCOL_S, AdversaryPlan
from coster_sumo.data import synthetic
from coster_sumo.sim.events import Event


def _job() -> EscapeJob:
    times = np.round(np.arange(1.0, 3.7 + 1e-9, 0.5), 6)  # adversary from 1.0 s, t_col 3.7 s
    plan = AdversaryPlan(times=times, x=np.linspace(0, 20, len(times)), y=np.zeros(len(times)),
                         yaw=np.zeros(len(times)), final_speed=8.0, length=4.5, width=1.8)
    grid = np.round(np.arange(1.0, 3.7 + HORIZON_AFTER_TCOL_S + 1e-9, 0.1), 6)  # the search's grid
    zeros = np.zeros(len(grid))
    escape = Escape(t_act=2.0, manoeuvre=Manoeuvre("brake", -4.0, 0.0, 0.0), times=grid, x=zeros, y=zeros + 5.0,
                    yaw=zeros, speed=zeros, clearance_m=1.0, peak_decel=4.0, peak_lateral_accel=0.0, peak_accel=4.0)
    return EscapeJob(plan, escape)


def _off_road(t: float) -> Event:
    return Event(time=t, kind="off_road", vehicles=["ego"], positions=[[0.0, 5.0]])


def _contact(t: float) -> Event:
    return Event(time=t, kind="collision", vehicles=["ego", "car1"], positions=[[0.0, 5.0], [2.0, 5.0]])


def test_events_after_the_escapes_last_pose_or_before_the_adversary_do_not_refute_it():
    scene = synthetic.two_lane_road()  # no track of "ego": the verdict reads the events alone
    job = _job()
    end = 3.7 + HORIZON_AFTER_TCOL_S
    assert _verdict([_off_road(end + 0.1), _contact(0.5)], scene, "ego", "adversary", job).ok
    v = _verdict([_off_road(end)], scene, "ego", "adversary", job)  # the last pose still counts
    assert not v.ok and v.reason == f"left the road at {end:.1f} s"
    assert not _verdict([_contact(1.0)], scene, "ego", "adversary", job).ok  # from the appearance on
