"""The environment's scalar per-step checks give the general code's answers."""

from __future__ import annotations

import math

import numpy as np
import shapely

from coster_sumo.geometry import frames
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.gym.stepping import box_off_road, first_contact
from coster_sumo.sim.events import EventDetector
from coster_sumo.sim.states import VehicleStates


def _states(boxes: np.ndarray) -> VehicleStates:
    n = len(boxes)
    ids = np.array([f"v{i}" for i in range(n)])
    return VehicleStates(ids=ids, x=boxes[:, 0], y=boxes[:, 1], yaw=boxes[:, 2], speed=np.zeros(n),
                         length=boxes[:, 3], width=boxes[:, 4], vclass=ids, type_id=ids)


def test_first_contact_is_the_first_row_the_event_detector_finds_in_contact():
    rng = np.random.default_rng(0)
    found = 0
    for _ in range(300):
        n = int(rng.integers(1, 12))
        boxes = np.stack([rng.uniform(-8, 8, n), rng.uniform(-8, 8, n), rng.uniform(-4, 4, n),
                          rng.uniform(3, 6, n), rng.uniform(1.5, 2.5, n)], -1)
        target = np.array([[0.0, 0.0, rng.uniform(-4, 4), 4.5, 1.9]])
        st = _states(np.concatenate([target, boxes]))
        want = next((j - 1 for j in range(1, n + 1) if EventDetector._in_contact(st, 0, j)), -1)
        got = first_contact(tuple(target[0]), boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3], boxes[:, 4])
        assert got == want
        found += got >= 0
    assert 0 < found < 300  # both answers occur
    empty = np.zeros(0)
    assert first_contact((0.0, 0.0, 0.0, 4.5, 1.9), empty, empty, empty, empty, empty) == -1


def test_box_off_road_is_drivable_off_road():
    area = DrivableArea(geometry=shapely.box(0.0, 0.0, 50.0, 3.5))
    shapely.prepare(area.geometry)
    rng = np.random.default_rng(1)
    answers = set()
    for _ in range(300):
        box = (float(rng.uniform(-3, 53)), float(rng.uniform(-2, 5.5)), float(rng.uniform(-0.6, 0.6)), 4.5, 1.9)
        got = box_off_road(area, box)
        assert got == bool(area.off_road(*(np.float64(v) for v in box)))
        answers.add(got)
    assert answers == {True, False}


def test_scalar_frame_conversions_are_the_array_ones():
    rng = np.random.default_rng(2)
    cases = [(0.0, 0.0, 0.0, 4.5), (1.0, -2.0, math.pi, 5.0), (1.0, -2.0, -math.pi, 5.0), (3.0, 4.0, math.pi / 2, 4.0)]
    cases += [tuple(v) for v in np.stack([rng.uniform(-1e4, 1e4, 500), rng.uniform(-1e4, 1e4, 500),
                                          rng.uniform(-7, 7, 500), rng.uniform(1, 20, 500)], -1)]
    for x, y, yaw, length in cases:
        assert frames.to_sumo_scalar(x, y, yaw, length) == tuple(float(v) for v in frames.to_sumo(x, y, yaw, length))
    for angle in [0.0, 90.0, 180.0, 270.0, 359.999, *rng.uniform(0, 360, 500).tolist()]:
        want = frames.from_sumo(np.array([5.0]), np.array([-3.0]), np.array([angle]), np.array([4.5]))
        assert frames.from_sumo_scalar(5.0, -3.0, angle, 4.5) == tuple(float(v[0]) for v in want)
