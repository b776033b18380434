"""The per-hold statistics of solvers/holds.py against their plain numpy definitions."""

import numpy as np
import pytest

from imucal_cli.solvers import holds


def _reference_trend(t, b, cov, limit):
    """The trend test written out for one hold (the definition in solvers/holds.py)."""
    if len(t) < 3 or t[-1] <= t[0]:
        return np.zeros(b.shape[1]), 0.0, False
    tc = t - t.mean()
    stt = tc @ tc
    slope = tc @ (b - b.mean(axis=0)) / stt
    chi2 = slope @ np.linalg.solve(cov / stt, slope)
    change = slope * (t[-1] - t[0])
    size = np.sqrt(change @ np.linalg.solve(cov, change))
    return change, chi2, bool(chi2 > limit and size > holds.TREND_MIN_SIGMAS)


def test_trends_of_many_holds_equal_each_hold_alone():
    rng = np.random.default_rng(11)
    cov = np.array([[4.0, 0.3, 0.1], [0.3, 3.0, -0.2], [0.1, -0.2, 5.0]])
    times, blocks = [], []
    for k in range(40):
        n = int(rng.integers(1, 200))
        t = 0.01 * np.arange(n) + k
        drift = rng.choice([0.0, 0.5, 30.0]) * rng.normal(size=3)  # raw units per s
        times.append(t)
        blocks.append(rng.multivariate_normal(np.zeros(3), cov, n) + np.outer(t - k, drift))
    limit = holds.trend_limit(3, len(blocks))
    found = holds.trends(times, blocks, cov, len(blocks))
    moved = 0
    for t, b, tr in zip(times, blocks, found, strict=True):
        change, chi2, is_moved = _reference_trend(t, b, cov, limit)
        np.testing.assert_allclose(tr.change, change, rtol=1e-12, atol=1e-12)
        assert tr.chi2 == pytest.approx(chi2, rel=1e-10, abs=1e-12)
        assert tr.moved == is_moved
        assert holds.trend(t, b, cov, len(blocks)).moved == is_moved
        moved += is_moved
    assert 0 < moved < len(blocks)  # both outcomes exercised
