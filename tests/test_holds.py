"""The per-hold statistics of solvers/holds.py against their plain numpy definitions."""

import numpy as np
import pytest

from imucal_cli.solvers import holds


def _blocks(rng, k, odd_even):
    blocks = []
    for _ in range(k):
        if odd_even is None:
            n = int(rng.integers(1, 60))
        else:
            n = int(2 * rng.integers(1, 30) + odd_even)
        scale = rng.choice([0.3, 3.0, 100.0])
        decimals = int(rng.integers(0, 3))
        blocks.append(np.round(rng.normal(size=(n, 3)) * scale + [0, 0, 8192], decimals))
    return blocks


@pytest.mark.parametrize("odd_even", [None, 0, 1])
def test_medians_and_spread_equal_numpy_median(odd_even):
    rng = np.random.default_rng(7)
    for _ in range(100):
        blocks = _blocks(rng, int(rng.integers(1, 8)), odd_even)
        median, mad = holds.medians_and_spread(blocks)
        ref = np.array([np.median(b, axis=0) for b in blocks])
        pairs = zip(blocks, ref, strict=True)
        ref_mad = np.array([np.median(np.abs(b - m), axis=0) for b, m in pairs])
        assert np.array_equal(median, ref)  # bit for bit: the accuracy benches read the same
        assert np.array_equal(mad, ref_mad)
        assert median.shape == (len(blocks), 3)


def test_medians_and_spread_nan_hold_is_nan_others_unchanged():
    rng = np.random.default_rng(3)
    blocks = _blocks(rng, 3, None)
    blocks[1] = blocks[1].copy()
    blocks[1][0, 2] = np.nan
    median, mad = holds.medians_and_spread(blocks)
    assert np.isnan(median[1, 2]) and np.isnan(mad[1, 2])
    for k in (0, 2):
        assert np.array_equal(median[k], np.median(blocks[k], axis=0))


def test_medians_and_spread_leaves_blocks_untouched():
    rng = np.random.default_rng(5)
    data = np.round(rng.normal(size=(500, 3)) * 4)
    before = data.copy()
    holds.medians_and_spread([data[:200], data[250:431]])
    assert np.array_equal(data, before)


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


def test_medians_and_spread_of_integer_and_signed_zero_holds_as_numpy():
    blocks = [np.array([[3, -2, 7], [1, 5, -7], [2, 2, 0], [9, -1, 4]], dtype=np.int16),
              np.array([[-0.0, 1.0, -0.0], [-0.0, -3.0, 2.0]])]  # fmt: skip
    median, mad = holds.medians_and_spread(blocks)
    for k, b in enumerate(blocks):
        ref = np.median(b, axis=0)
        assert np.array_equal(median[k], ref)
        assert np.array_equal(np.signbit(median[k]), np.signbit(ref))
        assert np.array_equal(mad[k], np.median(np.abs(b - ref), axis=0))
