from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.geometry import frames


@pytest.mark.parametrize(("yaw", "angle"), [(0.0, 90.0), (np.pi / 2, 0.0), (np.pi, 270.0),
                                            (-np.pi / 2, 180.0)])
def test_cardinal_directions(yaw, angle):
    assert frames.yaw_to_sumo_angle(yaw) == pytest.approx(angle)


def test_round_trip_random_states():
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1e4, 1e4, (2, 1000))
    yaw = rng.uniform(-np.pi, np.pi, 1000)
    length = rng.uniform(0.5, 20.0, 1000)
    fx, fy, ang = frames.to_sumo(x, y, yaw, length)
    assert np.all((ang >= 0) & (ang < 360))
    cx, cy, back = frames.from_sumo(fx, fy, ang, length)
    np.testing.assert_allclose(cx, x, atol=1e-9)
    np.testing.assert_allclose(cy, y, atol=1e-9)
    np.testing.assert_allclose(frames.wrap_angle(back - yaw), 0.0, atol=1e-12)


def test_front_bumper_is_ahead_of_centre():
    fx, fy = frames.centre_to_front(0.0, 0.0, np.pi / 2, 4.0)
    assert fx == pytest.approx(0.0, abs=1e-12)
    assert fy == pytest.approx(2.0)
