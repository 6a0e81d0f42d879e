"""When the adversary controller puts the adversary on its first knot."""

from __future__ import annotations

import numpy as np

from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.sim.inject import AdversaryController


class _Session:
    """Records the controller's calls instead of driving SUMO."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, float, float]] = []

    def add_vehicle(self, vid, length, width, vclass, base_type=None, departure=None, color=None):  # noqa: ANN001, ANN201
        self.calls.append(("add", 0.0, 0.0))

    def move_to_xy(self, vid, x, y, yaw, length, speed=None):  # noqa: ANN001, ANN201
        self.calls.append(("move", x, y))

    @property
    def api(self):  # noqa: ANN201
        raise RuntimeError("no SUMO here")


def _plan(t0: float) -> AdversaryPlan:
    times = t0 + 0.5 * np.arange(5)
    return AdversaryPlan(times=times, x=10.0 * np.arange(5), y=np.zeros(5), yaw=np.zeros(5), final_speed=20.0,
                         length=4.5, width=1.8, vehicle_id="adversary0")


def test_a_first_knot_a_few_ms_off_the_grid_starts_at_the_nearest_step():
    """A converted WOMD log's times jitter around SUMO's 0.1 s grid: a first knot at 1.70448 s
    belongs to the step ending at 1.7 s (where the exports and the contact offsets put it), not
    one step later."""
    ctl = AdversaryController(_plan(1.70448), step_length=0.1)
    s = _Session()
    ctl.before_step(s, 1.6)
    assert s.calls == []
    ctl.before_step(s, 1.7)
    assert s.calls[0][0] == "add" and s.calls[1][0] == "move"
    # 4.48 ms before the knot at 20 m/s: continued backwards along the plan, so that the pass
    # passes through the knot (an OpenSCENARIO polyline of the recording hits it within 1e-4 m)
    assert abs(s.calls[1][1] + 20.0 * 0.00448) < 1e-3 and s.calls[1][2] == 0.0


def test_a_first_knot_after_a_step_waits_for_the_nearest_step():
    ctl = AdversaryController(_plan(1.66), step_length=0.1)
    s = _Session()
    ctl.before_step(s, 1.6)  # 0.06 s before the knot: its step is the one ending at 1.7 s
    assert s.calls == []
    ctl.before_step(s, 1.7)
    assert s.calls[0][0] == "add" and s.calls[1][0] == "move"
    assert abs(s.calls[1][1] - 0.8) < 1e-9  # the plan 0.04 s past its first knot (20 m/s)
