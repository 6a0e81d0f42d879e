"""How the target moved in the nominal pass, and the note under a target that stood still."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coster_sumo.cli.commands.run import target_lines
from coster_sumo.core.results import TargetResult
from coster_sumo.data.synthetic import DT, NUM_STEPS, two_lane_road
from coster_sumo.pipeline.outputs import target_motion


def test_target_motion_counts_time_standing_and_distance() -> None:
    scene = two_lane_road()
    tr = scene.tracks
    moving = target_motion(scene, 0)  # sdc: 10 m/s the whole recording, clipped at the road's end
    assert moving.in_window_s == pytest.approx((NUM_STEPS - 1) * DT)
    assert moving.stopped_s == 0.0
    assert moving.distance_m == pytest.approx(float(np.hypot(np.diff(tr.x[0]), np.diff(tr.y[0])).sum()), abs=0.1)
    # "lead" stands still for its first half, then is gone
    half = NUM_STEPS // 2
    tr.x[1, :half] = tr.x[1, 0]
    tr.y[1, :half] = tr.y[1, 0]
    tr.vx[1, :half] = 0.0
    tr.vy[1, :half] = 0.0
    tr.valid[1, half:] = False
    still = target_motion(scene, 1)
    assert still.stopped_s == pytest.approx(still.in_window_s, abs=DT)
    assert still.in_window_s == pytest.approx(half * DT, abs=DT)
    assert still.distance_m == 0.0


def _summary(in_window: float, stopped: float) -> dict:
    return {"target": "veh24", "snapshots": [{"t_col": 49.1}], "collision_time_method": "entropy",
            "init_method": "snapshot", "planner": "replay", "variants": [],
            "target_motion": {"in_window_s": in_window, "stopped_s": stopped, "distance_m": 0.0}}


@pytest.mark.parametrize(("in_window", "stopped", "noted"),
                         [(1776.0, 1776.0, True), (100.0, 80.0, True), (100.0, 79.0, False),
                          (20.0, 20.0, False)])
def test_note_under_a_target_that_stood_still(in_window: float, stopped: float, noted: bool) -> None:
    lines = target_lines(TargetResult.from_json(_summary(in_window, stopped), Path("out")))
    notes = [line for line in lines if "note:" in line]
    assert bool(notes) == noted
    if noted:
        assert f"stood still for {stopped:.0f} s of its {in_window:.0f} s" in notes[0]


def test_summaries_without_motion_still_print() -> None:  # summaries written before target_motion existed
    summary = _summary(0.0, 0.0)
    del summary["target_motion"]
    assert target_lines(TargetResult.from_json(summary, Path("out")))[0].startswith("target veh24: t_col = 49.1 s")
