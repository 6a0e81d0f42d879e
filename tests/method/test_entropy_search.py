"""The collision-time search over a long life: coarse to fine, and exact over a short one."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from coster_sumo.method import collision_time as ct


def _curve(steps: np.ndarray) -> np.ndarray:
    """A made-up entropy: a broad hill with a narrow peak at step 1,234 on it, no region at 700-720."""
    s = np.asarray(steps, float)
    out = 1.0 - ((s - 1500.0) / 1500.0) ** 2 + 0.5 * np.exp(-(((s - 1234.0) / 3.0) ** 2))
    return np.where((s >= 700) & (s <= 720), np.nan, out)


@pytest.fixture
def fake_prior(monkeypatch):
    """``entropy_search`` on a scene of ``n`` 2 Hz steps whose target is valid from step 10 on,
    with the prior replaced by :func:`_curve`; returns the search and the steps the prior ran at."""
    asked: list[np.ndarray] = []

    def entropy_at(model, data, scene, target, steps):  # noqa: ARG001 - the prior's signature
        asked.append(np.asarray(steps))
        return _curve(steps)

    monkeypatch.setattr(ct, "_entropy_at", entropy_at)

    def search(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        monkeypatch.setattr(ct, "search_window", lambda scene, target, exclude=(): np.arange(10, n - 5))
        asked.clear()
        curve, searched = ct.entropy_search(None, None, SimpleNamespace(num_steps=n), 0)
        return curve, searched, np.concatenate(asked)

    return search


def test_a_short_life_is_searched_at_every_step(fake_prior):
    n = ct.LONG_WINDOW_STEPS + 15  # a window of exactly LONG_WINDOW_STEPS steps
    curve, searched, asked = fake_prior(n)
    window = np.arange(10, n - 5)
    assert len(window) == ct.LONG_WINDOW_STEPS
    np.testing.assert_array_equal(searched, window)
    np.testing.assert_array_equal(asked, window)  # one batch over the whole window, as before
    np.testing.assert_array_equal(curve[window], _curve(window))
    assert np.isnan(curve[:10]).all() and np.isnan(curve[n - 5:]).all()


def test_a_long_life_is_searched_coarse_to_fine_and_finds_the_peak(fake_prior):
    n = 2815  # 2,800 steps: a target living 1,400 s (veh400 on A10KW)
    curve, searched, asked = fake_prior(n)
    window = np.arange(10, n - 5)
    assert len(asked) == len(set(asked.tolist())) == len(searched)  # no step computed twice
    bound = -(-len(window) // ct.COARSE_STRIDE) + ct.FINE_CANDIDATES * (2 * ct.COARSE_STRIDE - 1)
    assert len(searched) <= bound < len(window) / 4
    np.testing.assert_array_equal(np.flatnonzero(~np.isnan(curve)), np.setdiff1d(searched, np.arange(700, 721)))
    exact = _curve(window)
    assert int(window[np.nanargmax(exact)]) == 1234 == int(np.nanargmax(curve))
    np.testing.assert_array_equal(curve[searched], _curve(searched))  # each computed step is the prior's value
    assert ct.choose_collision_time(window, "entropy", np.random.default_rng(0), curve) == 1234
