"""Policy scores (coster_sumo.gym.scores) against small cases computed by hand."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from coster_sumo.gym.scores import bootstrap, bootstrap_difference, episode_values, scores


def _row(outcome: str, completion: float, adversary: bool = False) -> SimpleNamespace:
    return SimpleNamespace(outcome=outcome, route_completion=completion, collided_with_adversary=adversary)


ROWS = [
    _row("completed", 1.0),
    _row("collision", 0.6, adversary=True),
    _row("collision", 0.3),  # a bystander
    _row("off_road", 0.5),
    _row("timeout", 1.0),  # a short route driven to its end: completed
    _row("timeout", 0.4),  # stopped on the way: not completed
]


def test_scores_of_six_episodes_by_hand():
    s = scores(ROWS)
    assert s["rcr"] == pytest.approx(2 / 6)  # the paper's: completed with no collision, no off-road
    assert s["mean_completion"] == pytest.approx((1.0 + 0.6 + 0.3 + 0.5 + 1.0 + 0.4) / 6)
    assert s["cr"] == pytest.approx(2 / 6)
    assert s["cr_adversary"] == pytest.approx(1 / 6)
    assert s["orr"] == pytest.approx(1 / 6)
    assert episode_values(ROWS, "rcr").tolist() == [1, 0, 0, 0, 1, 0]


def test_a_constant_score_has_a_point_interval():
    iv = bootstrap(np.ones((3, 10)))
    assert (iv.mean, iv.low, iv.high) == (1.0, 1.0, 1.0)
    d = bootstrap_difference(np.zeros((3, 10)), np.ones((2, 10)))
    assert (d.mean, d.low, d.high) == (1.0, 1.0, 1.0) and d.excludes_zero()


def test_two_episodes_one_seed():
    """Episodes (0, 1): a draw of two is (0, 0), (0, 1), (1, 0) or (1, 1), mean 0, 0.5, 0.5, 1 with
    probability 1/4 each: the 2.5th percentile is 0, the 97.5th 1."""
    iv = bootstrap(np.array([0.0, 1.0]), samples=4000)
    assert iv.mean == 0.5 and iv.low == 0.0 and iv.high == 1.0


def test_seeds_count_in_the_interval():
    """Two seeds, one scoring 0 and one 1 on every episode: drawing seeds gives (0, 0) and (1, 1) a
    quarter of the time each, so the interval spans [0, 1]; with the seeds alike it is a point."""
    spread = bootstrap(np.array([[0.0] * 5, [1.0] * 5]), samples=4000)
    assert spread.mean == 0.5 and spread.low == 0.0 and spread.high == 1.0


def test_a_paired_difference_is_narrower_than_the_arms():
    """Arm b scores what arm a scores plus one episode more in 20: paired by episode, the difference's
    interval is tight around 0.05 although each arm's own interval is wide."""
    rng = np.random.default_rng(1)
    a = (rng.random((1, 200)) < 0.5).astype(float)
    b = a.copy()
    b[0, np.flatnonzero(a[0] == 0)[:10]] = 1.0
    d = bootstrap_difference(a, b)
    assert d.mean == pytest.approx(0.05)
    assert d.excludes_zero() and d.high - d.low < 0.07
    own = bootstrap(a)
    assert own.high - own.low > 0.1


def test_arms_on_different_episodes_are_refused():
    with pytest.raises(ValueError, match="same episodes"):
        bootstrap_difference(np.zeros((1, 3)), np.zeros((1, 4)))
