"""The clearance tests of the avoidability search against the plain pairwise test they shortcut."""

from __future__ import annotations

import numpy as np
import pytest

from coster_sumo.avoidability.candidates import _unwrapped
from coster_sumo.avoidability.clearance import hits_adversary, too_close
from coster_sumo.geometry.boxes import make_boxes, sat_overlap_depth


def _every_pair(centres, yaws, size, o_box, o_valid, acted):
    """Every candidate box against every other vehicle's box at every step it exists after acting."""
    g_n, t_n = yaws.shape
    hit = np.zeros(g_n, bool)
    for g in range(g_n):
        for t in range(t_n):
            if not acted[g, t]:
                continue
            box = make_boxes(centres[g, t, 0:1], centres[g, t, 1:2], yaws[g, t:t + 1], *size)
            for o in np.flatnonzero(o_valid[:, t]):
                if sat_overlap_depth(box, o_box[o, t][None])[0] > 0.0:
                    hit[g] = True
    return hit


@pytest.mark.parametrize("seed", range(3, 11))
def test_too_close_is_the_pairwise_test(seed):
    """A bundle of candidate paths and vehicles around it, some within touching distance of its
    edge, some beyond it: the same answer as testing every pair (steps before acting included)."""
    rng = np.random.default_rng(seed)
    g_n, o_n, t_n = 30, 8, 10
    base = np.stack([np.linspace(0.0, 30.0, t_n), np.zeros(t_n)], -1)  # (T, 2) the bundle's middle
    centres = base[None] + rng.uniform(-2.0, 2.0, (g_n, t_n, 2))
    yaws = rng.normal(0.0, 0.2, (g_n, t_n))
    ox = base[None, :, 0] + rng.uniform(-12.0, 12.0, (o_n, t_n))
    oy = rng.choice([-1.0, 1.0], (o_n, 1)) * rng.uniform(4.0, 10.0, (o_n, t_n))  # beside the bundle
    o_box = make_boxes(ox, oy, rng.uniform(-np.pi, np.pi, (o_n, t_n)), rng.uniform(3.0, 12.0, (o_n, t_n)),
                       rng.uniform(1.5, 2.6, (o_n, t_n)))
    o_valid = rng.random((o_n, t_n)) < 0.8
    acted = np.arange(t_n)[None, :] >= rng.integers(0, t_n, g_n)[:, None]
    size = (5.0, 2.2)
    got = too_close(centres, yaws, size, o_box, o_valid, acted)
    want = _every_pair(centres, yaws, size, o_box, o_valid, acted)
    assert want.any() and not want.all()  # the case tests both answers
    np.testing.assert_array_equal(got, want)


def test_too_close_without_candidates_or_vehicles_nearby():
    o_box = make_boxes(np.full((1, 3), 500.0), np.zeros((1, 3)), np.zeros((1, 3)), np.full((1, 3), 4.5),
                       np.full((1, 3), 1.8))
    centres = np.zeros((2, 3, 2))
    assert not too_close(centres, np.zeros((2, 3)), (5.0, 2.0), o_box, np.ones((1, 3), bool),
                         np.ones((2, 3), bool)).any()
    assert too_close(np.zeros((0, 3, 2)), np.zeros((0, 3)), (5.0, 2.0), o_box, np.ones((1, 3), bool),
                     np.ones((0, 3), bool)).shape == (0,)


def test_unwrapped_is_numpy_unwrap():
    """Rows with and without jumps of pi or more: the same numbers as ``np.unwrap`` on every row."""
    rng = np.random.default_rng(3)
    yaw = np.cumsum(rng.normal(0.0, 0.3, (4, 5, 30)), -1)
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi  # wrapped: some rows now jump
    yaw[0] = np.linspace(-1.0, 1.0, 30)  # these never do
    np.testing.assert_array_equal(_unwrapped(yaw), np.unwrap(yaw, axis=-1))
    smooth = np.linspace(0.0, 2.0, 30)[None].repeat(3, 0)
    assert _unwrapped(smooth) is smooth


@pytest.mark.parametrize("seed", range(6))
def test_hits_adversary_is_the_pairwise_test(seed):
    """An adversary crossing a bundle of candidate paths: the same answer as testing every step."""
    rng = np.random.default_rng(seed)
    g_n, t_n = 40, 12
    base = np.stack([np.linspace(0.0, 30.0, t_n), np.zeros(t_n)], -1)
    centres = base[None] + rng.uniform(-4.0, 4.0, (g_n, t_n, 2))
    yaws = rng.normal(0.0, 0.3, (g_n, t_n))
    # across the bundle's middle, at the bundle's own pace
    adv_box = make_boxes(np.full(t_n, 15.0) + rng.uniform(-1.0, 1.0), np.linspace(-20.0, 20.0, t_n),
                         np.full(t_n, np.pi / 2), 4.6, 1.9)
    acted = np.arange(t_n)[None, :] >= rng.integers(0, t_n, g_n)[:, None]
    size = (5.0, 2.2)
    got = hits_adversary(centres, yaws, size, adv_box, acted)
    want = _every_pair(centres, yaws, size, adv_box[None], np.ones((1, t_n), bool), acted)
    assert want.any() and not want.all()
    np.testing.assert_array_equal(got, want)


def test_threat_time_is_the_signed_distance_rule():
    """The SAT shortcut in threat_time gives the first moment of the plain rule (the boxes,
    extrapolated at constant velocity, within signed distance 0), touching boxes included."""
    from coster_sumo.avoidability.evasion import DT_S, THREAT_LOOKAHEAD_S, Motion, threat_time
    from coster_sumo.geometry.boxes import box_signed_distance

    def plain(times, tgt, adv):
        tau = np.arange(0.0, THREAT_LOOKAHEAD_S + 1e-9, DT_S)

        def boxes(m):
            return make_boxes(m.x[:, None] + m.speed[:, None] * np.cos(m.yaw)[:, None] * tau,
                              m.y[:, None] + m.speed[:, None] * np.sin(m.yaw)[:, None] * tau,
                              m.yaw[:, None], m.length, m.width)

        hit = (box_signed_distance(boxes(tgt), boxes(adv)) <= 0.0).any(axis=1)
        return float(times[np.argmax(hit)]) if hit.any() else float(times[-1])

    k = 20
    times = np.arange(k) * 0.1
    tgt = Motion(np.zeros(k), np.zeros(k), np.zeros(k), np.full(k, 10.0), 4.0, 2.0)
    # side by side at the same speed, exactly touching (centres 2 m apart, half widths 1 m) from the
    # 6th moment on: the SAT depth is 0 there, and only the exact distance says "touching"
    touching = Motion(np.zeros(k), np.where(np.arange(k) >= 5, 2.0, 2.5), np.zeros(k), np.full(k, 10.0), 4.0, 2.0)
    assert threat_time(times, tgt, touching) == plain(times, tgt, touching) == times[5]
    rng = np.random.default_rng(5)
    found = set()
    for _ in range(40):  # an adversary crossing ahead: some pass in front, some hit
        adv = Motion(np.full(k, rng.uniform(20.0, 45.0)), rng.uniform(-30.0, -5.0) + np.arange(k) * 0.8,
                     np.full(k, np.pi / 2), np.full(k, 8.0), 4.5, 1.9)
        want = plain(times, tgt, adv)
        assert threat_time(times, tgt, adv) == want
        found.add(want < times[-1])
    assert found == {True, False}
