"""Joints of a SUMO net's connections: gaps and kinks measured on hand-written nets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coster_sumo.errors import InputError
from coster_sumo.formats.net_joints import max_curvature, measure_joints

# a lane a_0 ending at (10, 0), an internal lane :j_0_0 and a lane b_0 starting at (20, 0);
# {via_start} and {via_end} place the internal lane's ends
NET = """<net>
  <edge id="a" from="n0" to="j"><lane id="a_0" index="0" length="10" shape="0,0 10,0"/></edge>
  <edge id=":j_0" function="internal"><lane id=":j_0_0" index="0" length="10" shape="{via}"/></edge>
  <edge id="b" from="j" to="n1"><lane id="b_0" index="0" length="10" shape="20,0 30,0"/></edge>
  <connection from="a" to="b" fromLane="0" toLane="0" via=":j_0_0" dir="s" state="M"/>
  <connection from=":j_0" to="b" fromLane="0" toLane="0" dir="s" state="M"/>
</net>
"""


def _net(tmp_path, via: str):
    path = tmp_path / "t.net.xml"
    path.write_text(NET.format(via=via))
    return path


def test_joined_lanes_have_no_gap_and_no_kink(tmp_path):
    report = measure_joints(_net(tmp_path, "10,0 15,0 20,0"))
    assert [(j.from_lane, j.to_lane) for j in report.joints] == [("a_0", ":j_0_0"), (":j_0_0", "b_0")]
    assert report.gaps.max() == 0.0 and max(j.kink_rad for j in report.joints) < 1e-9
    summary = report.summary()
    assert summary["joints_over_tolerance"] == 0 and summary["internal_lanes"] == 1


def test_an_internal_lane_drawn_between_cut_lane_ends_leaves_gaps(tmp_path):
    # netconvert's internal lane from cut lane ends that were later lengthened again: 1.5 m short at
    # both ends, and it starts off the line by 1 m (a kink)
    report = measure_joints(_net(tmp_path, "8.5,1 21.5,0"))
    gaps = {(j.from_lane, j.to_lane): j.gap_m for j in report.joints}
    assert gaps[("a_0", ":j_0_0")] == pytest.approx(math.hypot(1.5, 1.0))
    assert gaps[(":j_0_0", "b_0")] == pytest.approx(1.5)
    assert report.summary()["joints_over_tolerance"] == 2
    assert report.summary()["max_kink_deg"] == pytest.approx(math.degrees(math.atan2(1.0, 13.0)), abs=1e-6)


def test_curvature_of_a_circle_is_one_over_its_radius():
    t = np.linspace(0.0, math.pi / 2, 400)
    arc = np.column_stack([10 * np.cos(t), 10 * np.sin(t)])  # radius 10 m
    assert max_curvature(arc) == pytest.approx(0.1, rel=0.01)
    assert max_curvature(np.array([[0.0, 0.0], [1.5, 0.0]])) == 0.0  # shorter than two chords


def test_unreadable_net_is_one_line(tmp_path):
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<net><edge")
    with pytest.raises(InputError, match="bad.net.xml: not a readable SUMO net"):
        measure_joints(bad)
